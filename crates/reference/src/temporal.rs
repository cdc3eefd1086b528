//! Temporal stability along a camera path: what a moving camera sees change
//! from frame to frame beyond what the full-resolution reference itself does
//! along the same path (motion itself does not count). See docs/stability.md.
//!
//! For frames `R_t` (rendered) and `F_t` (reference), RGBA8 of one size, RGB
//! channels, `t >= 1`:
//!
//! * **flicker** `(t) = mean |(R_t - R_{t-1}) - (F_t - F_{t-1})|` in 8-bit units:
//!   the change of the error image `E_t = R_t - F_t`. 0 on a static path, ~0
//!   when the rendering moves like the reference. Reported as the mean and the
//!   99th percentile over the frames;
//! * **change excess** in dB: `10 log10((mean_t MSE(R_t - R_{t-1}) + eps) /
//!   (mean_t MSE(F_t - F_{t-1}) + eps))`, `eps` = [`CHANGE_EPS`]: how much more
//!   (positive) or less the rendering changes per frame than the reference;
//! * **pops**: the image is cut into `tile x tile` regions; a pop is a frame `t`
//!   where some region's mean absolute error against the reference changes by
//!   more than `pop_threshold` (8-bit units) from frame `t - 1`. A level switch
//!   (a step in the error) is one pop; a one-frame spike that goes back is two
//!   (on and off).

use thiserror::Error;

/// Floor added to the mean squared changes of the dB ratio (8-bit units
/// squared), so that two static paths compare as 0 dB.
pub const CHANGE_EPS: f64 = 1e-3;

/// Knobs of [`temporal_stability`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TemporalOptions {
    /// Side of the square regions pops are counted over (pixels, >= 1).
    pub tile: u32,
    /// A region's error change (mean absolute, 8-bit units) above which a frame
    /// counts as a pop.
    pub pop_threshold: f64,
}

impl Default for TemporalOptions {
    /// 16 x 16 tiles, 8 units.
    fn default() -> Self {
        TemporalOptions {
            tile: 16,
            pop_threshold: 8.0,
        }
    }
}

/// The temporal stability of a rendered path against its reference.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TemporalReport {
    /// Frames compared (pairs of consecutive frames: `frames - 1` of them).
    pub frames: usize,
    /// Mean over frame pairs of the flicker (8-bit units).
    pub flicker_mean: f64,
    /// 99th percentile over frame pairs of the flicker (8-bit units).
    pub flicker_p99: f64,
    /// The rendering's per-frame change over the reference's, in dB.
    pub change_excess_db: f64,
    /// Mean absolute per-frame change of the rendering (8-bit units).
    pub change_mean: f64,
    /// Mean absolute per-frame change of the reference (8-bit units).
    pub reference_change_mean: f64,
    /// Frames with a pop.
    pub pops: usize,
    /// Their indices (`t`, the later frame of the pair).
    pub pop_frames: Vec<usize>,
    /// Largest change of a region's error between two frames (8-bit units).
    pub max_tile_jump: f64,
}

/// Inputs [`temporal_stability`] cannot compare.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[non_exhaustive]
pub enum TemporalError {
    /// The rendered and reference paths have different lengths.
    #[error("{rendered} rendered frames for {reference} reference frames")]
    Length {
        /// Rendered frames.
        rendered: usize,
        /// Reference frames.
        reference: usize,
    },
    /// A frame is not `width * height` RGBA8 pixels.
    #[error("frame {index} has {bytes} bytes, {expected} expected")]
    Size {
        /// The frame.
        index: usize,
        /// Its bytes.
        bytes: usize,
        /// `width * height * 4`.
        expected: usize,
    },
    /// A tile of 0 pixels or a threshold not finite or negative.
    #[error("tile must be >= 1 and pop_threshold finite >= 0")]
    Options,
}

fn p99(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    let i = ((v.len() as f64 * 0.99).ceil() as usize).clamp(1, v.len()) - 1;
    v[i]
}

/// Per-tile mean absolute RGB error of `a` against `b`.
fn tile_errors(a: &[u8], b: &[u8], width: u32, height: u32, tile: u32) -> Vec<f64> {
    let tx = width.div_ceil(tile) as usize;
    let ty = height.div_ceil(tile) as usize;
    let mut sum = vec![0u64; tx * ty];
    let mut n = vec![0u64; tx * ty];
    for y in 0..height as usize {
        for x in 0..width as usize {
            let p = (y * width as usize + x) * 4;
            let t = (y / tile as usize) * tx + x / tile as usize;
            for k in 0..3 {
                sum[t] += a[p + k].abs_diff(b[p + k]) as u64;
            }
            n[t] += 3;
        }
    }
    sum.iter()
        .zip(&n)
        .map(|(s, n)| *s as f64 / (*n).max(1) as f64)
        .collect()
}

/// Compares a rendered camera path with its reference (module docs).
pub fn temporal_stability(
    rendered: &[Vec<u8>],
    reference: &[Vec<u8>],
    width: u32,
    height: u32,
    options: TemporalOptions,
) -> Result<TemporalReport, TemporalError> {
    if rendered.len() != reference.len() {
        return Err(TemporalError::Length {
            rendered: rendered.len(),
            reference: reference.len(),
        });
    }
    if options.tile == 0 || !options.pop_threshold.is_finite() || options.pop_threshold < 0.0 {
        return Err(TemporalError::Options);
    }
    let expected = width as usize * height as usize * 4;
    for (index, f) in rendered.iter().chain(reference).enumerate() {
        if f.len() != expected {
            return Err(TemporalError::Size {
                index: index % rendered.len().max(1),
                bytes: f.len(),
                expected,
            });
        }
    }
    let mut report = TemporalReport {
        frames: rendered.len(),
        ..Default::default()
    };
    if rendered.len() < 2 || expected == 0 {
        return Ok(report);
    }
    let channels = (expected / 4 * 3) as f64;
    let mut flicker = Vec::with_capacity(rendered.len() - 1);
    let (mut msr, mut msf, mut mar, mut maf) = (0.0, 0.0, 0.0, 0.0);
    let mut prev_tiles = tile_errors(&rendered[0], &reference[0], width, height, options.tile);
    for t in 1..rendered.len() {
        let (r0, r1, f0, f1) = (
            &rendered[t - 1],
            &rendered[t],
            &reference[t - 1],
            &reference[t],
        );
        let (mut fl, mut sr, mut sf, mut ar, mut af) = (0i64, 0i64, 0i64, 0i64, 0i64);
        for p in (0..expected).step_by(4) {
            for k in p..p + 3 {
                let dr = r1[k] as i64 - r0[k] as i64;
                let df = f1[k] as i64 - f0[k] as i64;
                fl += (dr - df).abs();
                sr += dr * dr;
                sf += df * df;
                ar += dr.abs();
                af += df.abs();
            }
        }
        flicker.push(fl as f64 / channels);
        msr += sr as f64 / channels;
        msf += sf as f64 / channels;
        mar += ar as f64 / channels;
        maf += af as f64 / channels;
        let tiles = tile_errors(r1, f1, width, height, options.tile);
        let jump = tiles
            .iter()
            .zip(&prev_tiles)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        report.max_tile_jump = report.max_tile_jump.max(jump);
        if jump > options.pop_threshold {
            report.pops += 1;
            report.pop_frames.push(t);
        }
        prev_tiles = tiles;
    }
    let n = (rendered.len() - 1) as f64;
    report.flicker_mean = flicker.iter().sum::<f64>() / n;
    report.flicker_p99 = p99(&mut flicker);
    report.change_excess_db = 10.0 * ((msr / n + CHANGE_EPS) / (msf / n + CHANGE_EPS)).log10();
    report.change_mean = mar / n;
    report.reference_change_mean = maf / n;
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: u32 = 32;
    const H: u32 = 32;

    /// A smooth image with a bright square at `x0`.
    fn scene(x0: i32) -> Vec<u8> {
        let mut v = vec![0u8; (W * H * 4) as usize];
        for y in 0..H as i32 {
            for x in 0..W as i32 {
                let p = ((y * W as i32 + x) * 4) as usize;
                let inside = (x - x0).abs() < 5 && (y - 16).abs() < 5;
                let g = (x * 4 + y * 2) as u8;
                v[p] = if inside { 250 } else { g };
                v[p + 1] = g / 2;
                v[p + 2] = 40;
                v[p + 3] = 255;
            }
        }
        v
    }

    fn offset(img: &[u8], region: (u32, u32), d: i16) -> Vec<u8> {
        let mut v = img.to_vec();
        for y in region.1..region.1 + 16 {
            for x in region.0..region.0 + 16 {
                let p = ((y * W + x) * 4) as usize;
                for c in &mut v[p..p + 3] {
                    *c = (*c as i16 + d).clamp(0, 255) as u8;
                }
            }
        }
        v
    }

    #[test]
    fn a_static_path_scores_zero() {
        let f: Vec<Vec<u8>> = (0..6).map(|_| scene(10)).collect();
        // A constant error (a coarser but steady rendering) does not count.
        let r: Vec<Vec<u8>> = f.iter().map(|i| offset(i, (0, 0), 30)).collect();
        let rep = temporal_stability(&r, &f, W, H, TemporalOptions::default()).unwrap();
        assert_eq!(rep.flicker_mean, 0.0);
        assert_eq!(rep.flicker_p99, 0.0);
        assert_eq!(rep.change_excess_db, 0.0);
        assert_eq!(rep.pops, 0);
    }

    #[test]
    fn pure_motion_matching_the_reference_scores_about_zero() {
        let f: Vec<Vec<u8>> = (0..12).map(|t| scene(4 + 2 * t)).collect();
        let r = f.clone();
        let rep = temporal_stability(&r, &f, W, H, TemporalOptions::default()).unwrap();
        assert!(rep.reference_change_mean > 1.0, "the path moves");
        assert_eq!(rep.flicker_mean, 0.0);
        assert!(rep.change_excess_db.abs() < 1e-9);
        assert_eq!(rep.pops, 0);
    }

    #[test]
    fn an_injected_level_switch_is_counted_exactly_once() {
        let f: Vec<Vec<u8>> = (0..12).map(|t| scene(4 + 2 * t)).collect();
        // From frame 5 on one region is rendered 40 units brighter (a level
        // switch at that frame).
        let r: Vec<Vec<u8>> = f
            .iter()
            .enumerate()
            .map(|(t, i)| {
                if t >= 5 {
                    offset(i, (16, 0), 40)
                } else {
                    i.clone()
                }
            })
            .collect();
        let rep = temporal_stability(&r, &f, W, H, TemporalOptions::default()).unwrap();
        assert_eq!(rep.pops, 1);
        assert_eq!(rep.pop_frames, vec![5]);
        assert!(rep.flicker_p99 > 0.0 && rep.change_excess_db > 0.0);
        // The same switch spread over 8 frames (a fade) stays under the
        // threshold.
        let r: Vec<Vec<u8>> = f
            .iter()
            .enumerate()
            .map(|(t, i)| offset(i, (16, 0), 5 * (t as i16 - 4).clamp(0, 8)))
            .collect();
        let rep = temporal_stability(&r, &f, W, H, TemporalOptions::default()).unwrap();
        assert_eq!(rep.pops, 0, "{rep:?}");
    }

    #[test]
    fn bad_input_is_a_typed_error() {
        let f = vec![scene(3); 3];
        assert!(matches!(
            temporal_stability(&f[..2], &f, W, H, TemporalOptions::default()),
            Err(TemporalError::Length { .. })
        ));
        assert!(matches!(
            temporal_stability(
                &[vec![0u8; 3]],
                &[vec![0u8; 3]],
                W,
                H,
                TemporalOptions::default()
            ),
            Err(TemporalError::Size { .. })
        ));
        let bad = TemporalOptions {
            tile: 0,
            ..Default::default()
        };
        assert_eq!(
            temporal_stability(&f, &f, W, H, bad),
            Err(TemporalError::Options)
        );
    }
}
