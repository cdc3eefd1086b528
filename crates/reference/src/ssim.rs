//! The structural similarity index (SSIM, Wang, Bovik, Sheikh and Simoncelli
//! 2004) of two 8-bit images, on their luma.
//!
//! As the paper defines it: an 11 x 11 Gaussian window (sigma 1.5), constants
//! `C1 = (0.01 L)^2` and `C2 = (0.03 L)^2` for the dynamic range `L = 255`, the
//! local index averaged over every window that lies inside the image (no
//! padding). Luma is Rec. 709 (`0.2126 R + 0.7152 G + 0.0722 B`) of the RGB
//! channels; alpha is ignored, as [`psnr`](crate::psnr) ignores it.

/// Radius of the Gaussian window (11 x 11).
const RADIUS: usize = 5;
/// Standard deviation of the window, pixels.
const SIGMA: f64 = 1.5;

/// The normalised 1D Gaussian weights of the window.
fn weights() -> [f64; 2 * RADIUS + 1] {
    let mut w = [0.0; 2 * RADIUS + 1];
    for (i, wi) in w.iter_mut().enumerate() {
        let x = i as f64 - RADIUS as f64;
        *wi = (-x * x / (2.0 * SIGMA * SIGMA)).exp();
    }
    let s: f64 = w.iter().sum();
    w.map(|x| x / s)
}

/// Luma of an RGBA8 (`w * h * 4`) or RGB8 (`w * h * 3`) buffer.
fn luma(buf: &[u8], width: usize, height: usize) -> Vec<f64> {
    let n = width * height;
    let stride = if buf.len() == n * 4 {
        4
    } else {
        assert_eq!(
            buf.len(),
            n * 3,
            "ssim: {} bytes is neither a {width}x{height} RGBA8 nor RGB8 image",
            buf.len()
        );
        3
    };
    buf.chunks_exact(stride)
        .map(|p| 0.2126 * p[0] as f64 + 0.7152 * p[1] as f64 + 0.0722 * p[2] as f64)
        .collect()
}

/// `f` filtered by the separable window over the valid region: an
/// `(w - 2R) x (h - 2R)` image.
fn filter(f: &[f64], width: usize, height: usize, w: &[f64]) -> Vec<f64> {
    let (ow, oh) = (width - 2 * RADIUS, height - 2 * RADIUS);
    // Rows first (full height, valid width), then columns.
    let mut rows = vec![0.0; ow * height];
    for y in 0..height {
        let line = &f[y * width..(y + 1) * width];
        for x in 0..ow {
            rows[y * ow + x] = w.iter().zip(&line[x..]).map(|(a, b)| a * b).sum();
        }
    }
    let mut out = vec![0.0; ow * oh];
    for y in 0..oh {
        for x in 0..ow {
            out[y * ow + x] = w
                .iter()
                .enumerate()
                .map(|(k, a)| a * rows[(y + k) * ow + x])
                .sum();
        }
    }
    out
}

/// Mean SSIM of image `a` against `b` (RGBA8 or RGB8, `width x height`): 1 for
/// identical images, lower (down to -1) as structure, contrast or luminance
/// differ. Images smaller than the 11 x 11 window compare pixel by pixel with the
/// window reduced to one pixel (so identical images still score 1).
///
/// # Panics
/// If a buffer is neither `width * height * 4` nor `width * height * 3` bytes, or
/// the two differ in length.
pub fn ssim(a: &[u8], b: &[u8], width: u32, height: u32) -> f64 {
    assert_eq!(a.len(), b.len(), "ssim: images differ in size");
    let (width, height) = (width as usize, height as usize);
    let (x, y) = (luma(a, width, height), luma(b, width, height));
    if width * height == 0 {
        return 1.0;
    }
    let (c1, c2) = ((0.01f64 * 255.0).powi(2), (0.03f64 * 255.0).powi(2));
    let index = |mx: f64, my: f64, sxx: f64, syy: f64, sxy: f64| {
        ((2.0 * mx * my + c1) * (2.0 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
    };
    if width <= 2 * RADIUS || height <= 2 * RADIUS {
        let s: f64 = x
            .iter()
            .zip(&y)
            .map(|(&p, &q)| index(p, q, 0.0, 0.0, 0.0))
            .sum();
        return s / (width * height) as f64;
    }
    let w = weights();
    let prod = |p: &[f64], q: &[f64]| -> Vec<f64> { p.iter().zip(q).map(|(a, b)| a * b).collect() };
    let mx = filter(&x, width, height, &w);
    let my = filter(&y, width, height, &w);
    let mxx = filter(&prod(&x, &x), width, height, &w);
    let myy = filter(&prod(&y, &y), width, height, &w);
    let mxy = filter(&prod(&x, &y), width, height, &w);
    let n = mx.len();
    let sum: f64 = (0..n)
        .map(|i| {
            let (ux, uy) = (mx[i], my[i]);
            index(ux, uy, mxx[i] - ux * ux, myy[i] - uy * uy, mxy[i] - ux * uy)
        })
        .sum();
    sum / n as f64
}

#[cfg(test)]
mod tests {
    use super::ssim;
    use proptest::prelude::*;

    fn grey(v: &[u8]) -> Vec<u8> {
        v.iter().flat_map(|&g| [g, g, g, 255]).collect()
    }

    /// A deterministic textured image.
    fn texture(w: usize, h: usize) -> Vec<u8> {
        let v: Vec<u8> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                (128.0 + 100.0 * (x * 0.7).sin() * (y * 0.45).cos()) as u8
            })
            .collect();
        grey(&v)
    }

    #[test]
    fn identical_images_score_one() {
        let a = texture(40, 30);
        assert!((ssim(&a, &a, 40, 30) - 1.0).abs() < 1e-12);
        let small = texture(5, 4);
        assert!((ssim(&small, &small, 5, 4) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn a_flat_image_against_texture_scores_low() {
        let a = texture(48, 48);
        let flat = grey(&[128; 48 * 48]);
        let s = ssim(&flat, &a, 48, 48);
        assert!(s < 0.1, "{s}");
    }

    #[test]
    fn structure_counts_more_than_a_small_brightness_shift() {
        let a = texture(48, 48);
        let shifted: Vec<u8> = a
            .chunks_exact(4)
            .flat_map(|p| {
                let g = p[0].saturating_add(4);
                [g, g, g, 255]
            })
            .collect();
        let mut noisy = a.clone();
        for (i, p) in noisy.chunks_exact_mut(4).enumerate() {
            let d: i16 = if (i * 7919) % 3 == 0 { 24 } else { -24 };
            let g = (p[0] as i16 + d).clamp(0, 255) as u8;
            p[..3].copy_from_slice(&[g, g, g]);
        }
        let (s_shift, s_noise) = (ssim(&shifted, &a, 48, 48), ssim(&noisy, &a, 48, 48));
        assert!(s_shift > 0.98, "{s_shift}");
        assert!(s_noise < s_shift - 0.1, "{s_noise} vs {s_shift}");
    }

    proptest! {
        /// Symmetric and at most 1.
        #[test]
        fn symmetric_and_bounded(seed in any::<u64>(), w in 1usize..24, h in 1usize..24) {
            let mut s = seed | 1;
            let mut next = || { s ^= s << 13; s ^= s >> 7; s ^= s << 17; (s >> 24) as u8 };
            let a: Vec<u8> = (0..w * h * 4).map(|_| next()).collect();
            let b: Vec<u8> = (0..w * h * 4).map(|_| next()).collect();
            let (ab, ba) = (ssim(&a, &b, w as u32, h as u32), ssim(&b, &a, w as u32, h as u32));
            prop_assert!((ab - ba).abs() < 1e-9);
            prop_assert!((-1.0 - 1e-12..=1.0 + 1e-12).contains(&ab));
        }
    }
}
