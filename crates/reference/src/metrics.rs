//! Image metrics: PSNR, mean FLIP, maximum difference, and test helpers that write
//! the images they compare.

use std::path::{Path, PathBuf};

use crate::save_rgba8_png;

/// How much the difference image amplifies `|actual - expected|`.
const DIFF_GAIN: u32 = 8;

/// Peak signal-to-noise ratio in dB of two RGBA8 images over their RGB channels
/// (alpha is ignored), for the 8-bit peak 255:
/// `10 log10(255^2 / MSE)`. Infinite when the RGB channels are equal (and for
/// empty images).
///
/// # Panics
/// If the buffers differ in length or are not a whole number of RGBA8 pixels.
pub fn psnr(a: &[u8], b: &[u8]) -> f64 {
    assert_eq!(a.len(), b.len(), "psnr: images differ in size");
    assert_eq!(a.len() % 4, 0, "psnr: not an RGBA8 buffer");
    let mut sum = 0u64;
    for (pa, pb) in a.chunks_exact(4).zip(b.chunks_exact(4)) {
        for k in 0..3 {
            let d = pa[k].abs_diff(pb[k]) as u64;
            sum += d * d;
        }
    }
    if sum == 0 {
        return f64::INFINITY;
    }
    let mse = sum as f64 / (a.len() / 4 * 3) as f64;
    10.0 * (255.0f64 * 255.0 / mse).log10()
}

/// Largest absolute difference over the RGB channels of two RGBA8 images.
///
/// # Panics
/// If the buffers differ in length.
pub fn max_abs_diff(a: &[u8], b: &[u8]) -> u8 {
    assert_eq!(a.len(), b.len(), "max_abs_diff: images differ in size");
    a.chunks_exact(4)
        .zip(b.chunks_exact(4))
        .flat_map(|(pa, pb)| (0..3).map(move |k| pa[k].abs_diff(pb[k])))
        .max()
        .unwrap_or(0)
}

/// The RGB8 bytes of an RGBA8 (`w * h * 4` bytes) or RGB8 (`w * h * 3`) buffer.
fn rgb8(buf: &[u8], width: u32, height: u32, what: &str) -> Vec<u8> {
    let n = width as usize * height as usize;
    if buf.len() == n * 4 {
        buf.chunks_exact(4)
            .flat_map(|p| [p[0], p[1], p[2]])
            .collect()
    } else if buf.len() == n * 3 {
        buf.to_vec()
    } else {
        panic!(
            "{what}: {} bytes is neither a {width}x{height} RGBA8 nor RGB8 image",
            buf.len()
        );
    }
}

/// The FLIP error map of `test` against `reference` (both RGB8).
fn flip_map(test: &[u8], reference: &[u8], width: u32, height: u32) -> nv_flip::FlipImageFloat {
    let r = nv_flip::FlipImageRgb8::with_data(width, height, reference);
    let t = nv_flip::FlipImageRgb8::with_data(width, height, test);
    nv_flip::flip(r, t, nv_flip::DEFAULT_PIXELS_PER_DEGREE)
}

/// Mean FLIP error (NVIDIA's perceptual difference, 0 = identical .. 1) of image
/// `a` against reference image `b`, both treated as sRGB, at the default 67 pixels
/// per degree. Accepts RGBA8 (alpha dropped) or RGB8 buffers of
/// `width x height`. 0 for empty images.
///
/// # Panics
/// If a buffer is neither `width * height * 4` nor `width * height * 3` bytes.
pub fn mean_flip(a: &[u8], b: &[u8], width: u32, height: u32) -> f32 {
    let (ta, tb) = (
        rgb8(a, width, height, "mean_flip"),
        rgb8(b, width, height, "mean_flip"),
    );
    if width == 0 || height == 0 {
        return 0.0;
    }
    if ta == tb {
        return 0.0;
    }
    nv_flip::FlipPool::from_image(&flip_map(&ta, &tb, width, height)).mean()
}

/// Differences between an actual and an expected RGBA8 image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageComparison {
    /// [`psnr`] in dB (infinite when equal).
    pub psnr_db: f64,
    /// [`mean_flip`] of actual against expected.
    pub mean_flip: f32,
    /// [`max_abs_diff`] over RGB.
    pub max_abs_diff: u8,
}

impl std::fmt::Display for ImageComparison {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "PSNR {:.2} dB, mean FLIP {:.4}, max |diff| {}",
            self.psnr_db, self.mean_flip, self.max_abs_diff
        )
    }
}

/// Compares two RGBA8 images of `width x height` (`actual` against the reference
/// `expected`).
///
/// # Panics
/// If a buffer is not `width * height * 4` bytes.
pub fn compare(actual: &[u8], expected: &[u8], width: u32, height: u32) -> ImageComparison {
    let n = width as usize * height as usize * 4;
    assert!(
        actual.len() == n && expected.len() == n,
        "compare: expected two {width}x{height} RGBA8 buffers ({n} bytes), got {} and {}",
        actual.len(),
        expected.len()
    );
    ImageComparison {
        psnr_db: psnr(actual, expected),
        mean_flip: mean_flip(actual, expected, width, height),
        max_abs_diff: max_abs_diff(actual, expected),
    }
}

/// Keeps `[A-Za-z0-9._-]`, replaces anything else by `_`.
fn file_stem(name: &str) -> String {
    let s: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || "._-".contains(c) {
                c
            } else {
                '_'
            }
        })
        .collect();
    if s.is_empty() { "image".to_owned() } else { s }
}

/// Writes `<name>-actual.png`, `<name>-expected.png`, `<name>-diff.png`
/// (`|actual - expected|` amplified 8x, opaque) and `<name>-flip.png` (the FLIP
/// error map, magma colours) into `out_dir`; returns the paths written.
fn write_report(
    name: &str,
    actual: &[u8],
    expected: &[u8],
    width: u32,
    height: u32,
    out_dir: &Path,
) -> Result<Vec<PathBuf>, String> {
    let stem = file_stem(name);
    let path = |suffix: &str| out_dir.join(format!("{stem}-{suffix}.png"));
    let diff: Vec<u8> = actual
        .chunks_exact(4)
        .zip(expected.chunks_exact(4))
        .flat_map(|(a, e)| {
            let d = |k: usize| (a[k].abs_diff(e[k]) as u32 * DIFF_GAIN).min(255) as u8;
            [d(0), d(1), d(2), 255]
        })
        .collect();
    let mut written = Vec::new();
    let mut save = |p: PathBuf, rgba: &[u8]| -> Result<(), String> {
        save_rgba8_png(&p, rgba, width, height).map_err(|e| e.to_string())?;
        written.push(p);
        Ok(())
    };
    save(path("actual"), actual)?;
    save(path("expected"), expected)?;
    save(path("diff"), &diff)?;
    if width > 0 && height > 0 {
        let map = flip_map(
            &rgb8(actual, width, height, "flip"),
            &rgb8(expected, width, height, "flip"),
            width,
            height,
        );
        let rgb = map.apply_color_lut(&nv_flip::magma_lut()).to_vec();
        let rgba: Vec<u8> = rgb
            .chunks_exact(3)
            .flat_map(|p| [p[0], p[1], p[2], 255])
            .collect();
        save(path("flip"), &rgba)?;
    }
    Ok(written)
}

/// Compares `actual` against `expected` (RGBA8, `width x height`) and writes
/// `<name>-actual.png`, `<name>-expected.png`, `<name>-diff.png` (absolute RGB
/// difference amplified 8x) and `<name>-flip.png` (FLIP error map) into `out_dir`
/// (created if missing; characters outside `[A-Za-z0-9._-]` in `name` become `_`).
/// A failure to write is reported on stderr and does not hide the comparison.
///
/// # Panics
/// If a buffer is not `width * height * 4` bytes.
pub fn compare_and_report(
    name: &str,
    actual_rgba8: &[u8],
    expected_rgba8: &[u8],
    width: u32,
    height: u32,
    out_dir: impl AsRef<Path>,
) -> ImageComparison {
    let cmp = compare(actual_rgba8, expected_rgba8, width, height);
    if let Err(e) = write_report(
        name,
        actual_rgba8,
        expected_rgba8,
        width,
        height,
        out_dir.as_ref(),
    ) {
        eprintln!("compare_and_report({name}): {e}");
    }
    cmp
}

/// Where [`assert_close`] writes the images of a failed comparison: the
/// `BRICKRAY_TEST_OUTPUT` environment variable if set, else
/// `<temp dir>/brickray-test-output`.
pub fn test_output_dir() -> PathBuf {
    std::env::var_os("BRICKRAY_TEST_OUTPUT")
        .filter(|s| !s.is_empty())
        .map(PathBuf::from)
        .unwrap_or_else(|| std::env::temp_dir().join("brickray-test-output"))
}

/// `Ok(comparison)` when `actual` is within `min_psnr_db` of `expected` (RGBA8,
/// `width x height`; PSNR over RGB). Otherwise writes the actual, expected, diff and
/// FLIP images into [`test_output_dir`] (only on failure) and returns a message
/// with the metrics and the files written. Size mismatches are errors, not panics.
pub fn assert_close(
    name: &str,
    actual: &[u8],
    expected: &[u8],
    width: u32,
    height: u32,
    min_psnr_db: f64,
) -> Result<ImageComparison, String> {
    let n = width as usize * height as usize * 4;
    if actual.len() != n || expected.len() != n {
        return Err(format!(
            "{name}: expected two {width}x{height} RGBA8 buffers ({n} bytes), got actual {} and expected {} bytes",
            actual.len(),
            expected.len()
        ));
    }
    let cmp = compare(actual, expected, width, height);
    if cmp.psnr_db >= min_psnr_db {
        return Ok(cmp);
    }
    let dir = test_output_dir();
    let files = match write_report(name, actual, expected, width, height, &dir) {
        Ok(files) => {
            format!(
                "wrote {}",
                files
                    .iter()
                    .map(|p| p.display().to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        }
        Err(e) => format!("could not write the images: {e}"),
    };
    Err(format!(
        "{name}: {cmp}, below the required PSNR {min_psnr_db:.2} dB; {files}"
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn img(w: u32, h: u32, f: impl Fn(usize) -> u8) -> Vec<u8> {
        (0..(w * h * 4) as usize).map(f).collect()
    }

    #[test]
    fn psnr_by_hand() {
        let a = img(2, 2, |i| (i * 37 % 200) as u8);
        assert_eq!(psnr(&a, &a), f64::INFINITY);
        // Alpha is ignored.
        let mut b = a.clone();
        b[3] ^= 0xff;
        assert_eq!(psnr(&a, &b), f64::INFINITY);
        // One channel off by 10 among 2 * 2 * 3 = 12: MSE = 100 / 12.
        b[5] += 10;
        let expected = 10.0 * (255.0f64 * 255.0 / (100.0 / 12.0)).log10();
        assert!((psnr(&a, &b) - expected).abs() < 1e-12);
        assert!((expected - 38.9226).abs() < 1e-3, "{expected}");
        // Every channel off by 1: MSE = 1, PSNR = 20 log10(255) = 48.13 dB.
        let c: Vec<u8> = a.iter().map(|x| x + 1).collect();
        assert!((psnr(&a, &c) - 20.0 * 255f64.log10()).abs() < 1e-12);
        // Black vs white: 0 dB.
        assert!(psnr(&img(3, 1, |_| 0), &img(3, 1, |_| 255)).abs() < 1e-12);
        assert_eq!(max_abs_diff(&a, &b), 10);
        assert_eq!(max_abs_diff(&a, &c), 1);
    }

    #[test]
    fn flip_identical_is_zero_and_differences_are_not() {
        let (w, h) = (24u32, 16u32);
        let a = img(w, h, |i| {
            if i % 4 == 3 {
                255
            } else {
                ((i / 4) % 7 * 30 + i % 4 * 10) as u8
            }
        });
        assert_eq!(mean_flip(&a, &a, w, h), 0.0);
        // Through the library as well (not the equality shortcut).
        let rgb = rgb8(&a, w, h, "t");
        assert_eq!(
            nv_flip::FlipPool::from_image(&flip_map(&rgb, &rgb, w, h)).mean(),
            0.0
        );
        // RGB8 input is accepted.
        assert_eq!(mean_flip(&rgb, &a, w, h), 0.0);
        let mut b = a.clone();
        for p in b.chunks_exact_mut(4).skip(50).take(40) {
            p[0] = 255 - p[0];
        }
        let small = mean_flip(&b, &a, w, h);
        let inverted: Vec<u8> = a
            .iter()
            .enumerate()
            .map(|(i, &x)| if i % 4 == 3 { x } else { 255 - x })
            .collect();
        let large = mean_flip(&inverted, &a, w, h);
        assert!(
            small > 0.0 && small < large && large <= 1.0,
            "{small} {large}"
        );
    }

    #[test]
    fn report_and_assert_close() {
        let (w, h) = (8u32, 6u32);
        let a = img(w, h, |i| if i % 4 == 3 { 255 } else { (i * 5 % 256) as u8 });
        let mut b = a.clone();
        b[0] = b[0].wrapping_add(40);
        let dir = tempfile::tempdir().unwrap();
        let cmp = compare_and_report("case/one", &b, &a, w, h, dir.path());
        assert!(cmp.psnr_db.is_finite() && cmp.mean_flip > 0.0);
        assert_eq!(cmp.max_abs_diff, 40);
        for s in ["actual", "expected", "diff", "flip"] {
            let p = dir.path().join(format!("case_one-{s}.png"));
            assert!(p.exists(), "{}", p.display());
        }
        let diff = image::open(dir.path().join("case_one-diff.png"))
            .unwrap()
            .into_rgba8();
        assert_eq!(diff.get_pixel(0, 0).0, [255, 0, 0, 255]);

        assert_eq!(
            assert_close("same", &a, &a, w, h, 100.0).unwrap().psnr_db,
            f64::INFINITY
        );
        assert!(assert_close("near", &b, &a, w, h, 20.0).is_ok());
        let err = assert_close("brickray-reference-selftest", &b, &a, w, h, 60.0).unwrap_err();
        assert!(
            err.contains("brickray-reference-selftest-diff.png"),
            "{err}"
        );
        assert!(
            assert_close("size", &a[4..], &a, w, h, 20.0)
                .unwrap_err()
                .contains("RGBA8")
        );
    }
}
