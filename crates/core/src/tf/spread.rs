//! Classification of a value *distribution*: the transfer function convolved
//! with a truncated Gaussian (Younesy, Möller and Carr 2006).
//!
//! A coarse voxel of the brick pyramid stands for many finest voxels. Drawing it
//! as the TF of their mean pulls a voxel that mixes bone and soft tissue below a
//! sharp ramp; it should be drawn as the mean of what its finest voxels look like
//! under the TF. With the mean `v` and the standard deviation `s` of those values
//! (normalized units, [`crate::moments`]) the model approximates their
//! distribution by a Gaussian `N(v, s)` **truncated** to `[v - 3 s, v + 3 s]`
//! (a value beyond 0 or 1 classifies as the TF's end, as every lookup clamps)
//! and classifies with the averages, under
//! that density, of the *premultiplied* colour and of the opacity at the
//! reference length:
//!
//! `alpha(v, s) = E[a(x)]`, `colour(v, s) = E[rgb(x) a(x)] / E[a(x)]` (straight,
//! so the renderers correct and premultiply it exactly as a TF colour; where
//! `E[a] = 0` the colour is `E[rgb(x)]`).
//!
//! `s = 0` is the TF itself. The step correction is applied after the average
//! (`1 - (1 - alpha)^step`), as for every other sample.
//!
//! **The table** ([`SpreadTable`]): `rows` sigma rows, row `r` at
//! `s_r = SIGMA_MAX * (r / (rows - 1))^2` (dense at small spreads: 32 rows put
//! row 1 at 5.2e-4, about 0.13 of an 8-bit level), and the corrected table's
//! columns ([`TransferFunction::table_width`]). A lookup is bilinear in (value
//! column, sigma row coordinate `(rows - 1) sqrt(s / SIGMA_MAX)`), except that
//! row 0 is the exact TF lookup, so a voxel whose spread is 0 (every voxel of the
//! finest level) is classified exactly as without the model.
//!
//! **Empty-space skipping** stays conservative with a widened range
//! ([`TransferFunction::is_transparent_spread`]): a texel of row `r` at column
//! `c` averages the TF over `[c - 3 s_r, c + 3 s_r]` only, so if the TF is
//! transparent over `[min - w, max + w]`, `w = 3 s_R + 1 / (width - 1)` with
//! `R` the row at or above the largest spread, every lookup of a value in
//! `[min, max]` with a spread up to that one reads only zero-opacity texels.
//! When the range covers every finest voxel that the interpolated coarse voxels
//! stand for, the spread is at most `(max - min) / 2` (Popoviciu's inequality on
//! variances), which is the bound to pass when no stored maximum is known.

use super::{TransferFunction, corrected_alpha};

/// The largest standard deviation of values in 0..1 (half the range).
pub const SIGMA_MAX: f64 = 0.5;
/// Gaussians are truncated at this many standard deviations.
pub const TRUNCATE: f64 = 3.0;
/// Default sigma rows of a [`SpreadTable`].
pub const SPREAD_ROWS: u32 = 32;

/// The spread of row `r` of a table of `rows` rows.
pub fn spread_row_sigma(r: u32, rows: u32) -> f64 {
    let rows = rows.max(2);
    let t = r.min(rows - 1) as f64 / (rows - 1) as f64;
    SIGMA_MAX * t * t
}

/// The continuous row coordinate of spread `sigma` (clamped to the table).
pub fn spread_row_coord(sigma: f64, rows: u32) -> f64 {
    let rows = rows.max(2);
    if sigma.is_nan() || sigma <= 0.0 {
        return 0.0;
    }
    ((rows - 1) as f64 * (sigma.min(SIGMA_MAX) / SIGMA_MAX).sqrt()).min((rows - 1) as f64)
}

/// How far beyond a range of values a lookup with a spread of at most
/// `sigma_max` can read through a [`SpreadTable`] of `width` columns and
/// `rows` rows: the Gaussian's reach at the row at or above `sigma_max`,
/// and one column (the bilinear lookup's neighbour). 0 for `sigma_max <= 0`.
/// A range widened by it on both sides bounds every texel such a lookup
/// reads ([`TransferFunction::is_transparent_spread`]; the renderers widen
/// their sub-cell ranges by it).
pub fn spread_reach(sigma_max: f32, width: u32, rows: u32) -> f64 {
    if sigma_max.is_nan() || sigma_max <= 0.0 {
        return 0.0;
    }
    let row = spread_row_coord(sigma_max as f64, rows).ceil() as u32;
    TRUNCATE * spread_row_sigma(row, rows) + 1.0 / (width.max(2) - 1) as f64
}

/// The TF convolved with truncated Gaussians: `rows` rows of `width` RGBA
/// texels (straight colour, opacity at the reference length), row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct SpreadTable {
    /// Columns (values 0..1 at `i / (width - 1)`).
    pub width: u32,
    /// Sigma rows (row `r` at [`spread_row_sigma`]).
    pub rows: u32,
    /// `rows * width` texels, row 0 (the TF itself) first.
    pub texels: Vec<[f32; 4]>,
}

impl TransferFunction {
    /// The classification of values distributed as `N(v, sigma)` truncated to
    /// `[v - 3 sigma, v + 3 sigma]` (module docs): straight
    /// colour and reference opacity, in f64, by composite Simpson quadrature
    /// with at least four nodes per sigma and per TF interval, or 128 per
    /// sigma where intervals are shorter. `sigma <= 0` (or
    /// NaN) is the plain [`Self::lookup`].
    pub fn convolved(&self, v: f64, sigma: f64) -> [f64; 4] {
        let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
        if sigma.is_nan() || sigma <= 0.0 {
            return self.lookup(v);
        }
        self.convolve_kernel(v, &self.spread_kernel(sigma))
    }

    /// The quadrature of a spread `sigma > 0`: Simpson nodes as (offset from
    /// the value, weight), the same for every value, so a table row computes
    /// its weights once.
    fn spread_kernel(&self, sigma: f64) -> Vec<(f64, f64)> {
        let sigma = sigma.min(SIGMA_MAX);
        // Not clipped to 0..1: mass beyond an end classifies as that end (the
        // lookup clamps), so a linear TF maps a symmetric density to its mean
        // even next to 0 or 1; renormalizing a clipped Gaussian instead moved
        // its mean inwards (0.1 of opacity on a volume of noisy zeros).
        let reach = TRUNCATE * sigma;
        let interval = 1.0 / (self.len() - 1) as f64;
        // Four nodes per sigma, and per TF interval while that is at least
        // sigma / 128 (a wide Gaussian over a long TF: 768 nodes, not one per
        // quarter interval; `quadrature_matches_a_fine_rule` bounds the cost).
        let h = (sigma / 4.0).min((interval / 4.0).max(sigma / 128.0));
        let mut n = ((2.0 * reach / h).ceil() as usize).clamp(2, 8192);
        n += n % 2;
        let dx = 2.0 * reach / n as f64;
        let inv = 1.0 / (2.0 * sigma * sigma);
        (0..=n)
            .map(|k| {
                let off = if k == n {
                    reach
                } else {
                    -reach + k as f64 * dx
                };
                let simpson = if k == 0 || k == n {
                    1.0
                } else if k % 2 == 1 {
                    4.0
                } else {
                    2.0
                };
                (off, simpson * (-off * off * inv).exp())
            })
            .collect()
    }

    /// The classification of `v` under a [`Self::spread_kernel`].
    fn convolve_kernel(&self, v: f64, kernel: &[(f64, f64)]) -> [f64; 4] {
        // Sums of w, w*a, w*rgb*a, w*rgb.
        let mut acc = [0.0f64; 8];
        for &(off, w) in kernel {
            let c = self.lookup(v + off);
            acc[0] += w;
            acc[1] += w * c[3];
            for i in 0..3 {
                acc[2 + i] += w * c[i] * c[3];
                acc[5 + i] += w * c[i];
            }
        }
        let alpha = acc[1] / acc[0];
        let colour: [f64; 3] = if acc[1] > 0.0 {
            std::array::from_fn(|i| (acc[2 + i] / acc[1]).clamp(0.0, 1.0))
        } else {
            std::array::from_fn(|i| (acc[5 + i] / acc[0]).clamp(0.0, 1.0))
        };
        [colour[0], colour[1], colour[2], alpha.clamp(0.0, 1.0)]
    }

    /// The spread table: `rows` sigma rows (at least 2) of
    /// [`Self::table_width`]`(max_width)` columns.
    pub fn spread_table(&self, rows: u32, max_width: u32) -> SpreadTable {
        let width = self.table_width(max_width);
        let rows = rows.max(2);
        let mut texels = Vec::with_capacity((rows * width) as usize);
        // Row 0 is the TF itself.
        texels.extend(
            (0..width).map(|i| self.lookup(i as f64 / (width - 1) as f64).map(|x| x as f32)),
        );
        for r in 1..rows {
            let kernel = self.spread_kernel(spread_row_sigma(r, rows));
            texels.extend((0..width).map(|i| {
                let v = i as f64 / (width - 1) as f64;
                self.convolve_kernel(v, &kernel).map(|x| x as f32)
            }));
        }
        SpreadTable {
            width,
            rows,
            texels,
        }
    }

    /// True when every value in `[min, max]` with a spread of at most
    /// `sigma_max` classifies to zero opacity through a [`SpreadTable`] of
    /// `width` columns and `rows` rows (module docs: the range widened by the
    /// Gaussian's reach at the row at or above `sigma_max`, and one column).
    /// With `sigma_max = 0` it is [`Self::is_transparent`]. O(1).
    pub fn is_transparent_spread(
        &self,
        min: f32,
        max: f32,
        sigma_max: f32,
        width: u32,
        rows: u32,
    ) -> bool {
        if sigma_max.is_nan() || sigma_max <= 0.0 {
            return self.is_transparent(min, max);
        }
        let reach = spread_reach(sigma_max, width, rows);
        // Round the widened range outwards in f32.
        let lo = (min as f64 - reach) as f32 - f32::EPSILON;
        let hi = (max as f64 + reach) as f32 + f32::EPSILON;
        self.is_transparent(lo, hi)
    }
}

impl SpreadTable {
    /// The table as a GPU would read it out of core: `levels` layers, layer
    /// `e` with every opacity corrected to `step_factor * 2^e` reference
    /// lengths *after* the spread's average (the model's order), layer-major,
    /// then row, then column. Layer `e`, row 0 is row `e` of the corrected
    /// table ([`TransferFunction::corrected_table`]) of the same TF and width
    /// (exactly where the columns fall on the TF's entries, else to f32
    /// rounding). Not used by the GPU renderers yet.
    pub fn corrected_layers(&self, step_factor: f32, levels: u32) -> Vec<[f32; 4]> {
        let levels = levels.max(1);
        let mut out = Vec::with_capacity(self.texels.len() * levels as usize);
        for e in 0..levels {
            let exponent = step_factor as f64 * (e as f64).exp2();
            out.extend(self.texels.iter().map(|c| {
                [
                    c[0],
                    c[1],
                    c[2],
                    corrected_alpha(c[3] as f64, exponent) as f32,
                ]
            }));
        }
        out
    }

    /// The model's classification of value `v` with spread `sigma` (straight
    /// colour, reference opacity): bilinear in (column, sigma row coordinate),
    /// with row 0 read as the exact `tf.lookup(v)` (`tf` must be the table's
    /// own TF). `sigma = 0` returns `tf.lookup(v)` exactly.
    pub fn lookup(&self, tf: &TransferFunction, v: f64, sigma: f64) -> [f64; 4] {
        let y = spread_row_coord(sigma, self.rows);
        if y <= 0.0 {
            return tf.lookup(v);
        }
        let r0 = (y.floor() as u32).min(self.rows - 1);
        let r1 = (r0 + 1).min(self.rows - 1);
        let f = y - r0 as f64;
        let a = if r0 == 0 {
            tf.lookup(v)
        } else {
            self.row_lookup(r0, v)
        };
        let b = self.row_lookup(r1, v);
        std::array::from_fn(|k| a[k] + (b[k] - a[k]) * f)
    }

    /// Row `row` at value `v`, linear between columns.
    pub fn row_lookup(&self, row: u32, v: f64) -> [f64; 4] {
        let w = self.width as usize;
        let x = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) } * (w - 1) as f64;
        let i = (x.floor() as usize).min(w - 1);
        let j = (i + 1).min(w - 1);
        let f = x - i as f64;
        let row = &self.texels[row.min(self.rows - 1) as usize * w..][..w];
        std::array::from_fn(|k| row[i][k] as f64 + (row[j][k] as f64 - row[i][k] as f64) * f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn sigma_zero_is_the_tf_and_rows_are_dense_at_small_spreads() {
        let tf = TransferFunction::ramp(0.3, 0.6, 0.8);
        let t = tf.spread_table(SPREAD_ROWS, 8192);
        for k in 0..=100 {
            let v = k as f64 / 100.0;
            assert_eq!(t.lookup(&tf, v, 0.0), tf.lookup(v));
            assert_eq!(tf.convolved(v, 0.0), tf.lookup(v));
        }
        assert!(spread_row_sigma(1, SPREAD_ROWS) < 6e-4);
        assert_eq!(spread_row_sigma(SPREAD_ROWS - 1, SPREAD_ROWS), SIGMA_MAX);
        for r in 0..SPREAD_ROWS {
            let y = spread_row_coord(spread_row_sigma(r, SPREAD_ROWS), SPREAD_ROWS);
            assert!((y - r as f64).abs() < 1e-9);
        }
    }

    #[test]
    fn a_step_is_smoothed_to_the_gaussian_fraction_above_it() {
        // Opacity 0 below 0.5, 1 above (a 4096-entry step): at v = 0.5 half the
        // mass is above; at v = 0.5 - sigma about 16% (truncated at 3 sigma).
        let n = 4096;
        let tf = TransferFunction::from_entries(
            (0..n)
                .map(|i| {
                    let a = if i >= n / 2 { 1.0 } else { 0.0 };
                    [1.0, 0.5, 0.25, a]
                })
                .collect(),
        );
        let s = 0.05;
        let mid = tf.convolved(0.5, s);
        assert!((mid[3] - 0.5).abs() < 0.01, "{mid:?}");
        assert!((mid[0] - 1.0).abs() < 1e-9 && (mid[1] - 0.5).abs() < 1e-9);
        let below = tf.convolved(0.5 - s, s)[3];
        // Phi(-1) renormalized to the 3-sigma truncation: 0.1573 / 0.9973.
        assert!((below - 0.1577).abs() < 0.01, "{below}");
        assert_eq!(tf.convolved(0.5 - 3.2 * s, s)[3], 0.0);
    }

    /// The quadrature against a brute-force rule (trapezoid, 200001 nodes
    /// over the truncated Gaussian) on a 4096-entry opacity step and a
    /// 512-entry two-ramp TF, over values and spreads from row 1 to 0.5:
    /// within 2e-3 (prints the largest difference).
    #[test]
    fn quadrature_matches_a_fine_rule() {
        let fine = |tf: &TransferFunction, v: f64, s: f64| -> [f64; 4] {
            let n = 200_000;
            let (a, b) = (v - TRUNCATE * s, v + TRUNCATE * s);
            let mut acc = [0.0f64; 5];
            for k in 0..=n {
                let x = a + (b - a) * k as f64 / n as f64;
                let w = if k == 0 || k == n { 0.5 } else { 1.0 }
                    * (-(x - v) * (x - v) / (2.0 * s * s)).exp();
                let c = tf.lookup(x);
                acc[0] += w;
                acc[1] += w * c[3];
                for i in 0..3 {
                    acc[2 + i] += w * c[i] * c[3];
                }
            }
            let al = acc[1] / acc[0];
            [acc[2] / acc[0], acc[3] / acc[0], acc[4] / acc[0], al]
        };
        let step = TransferFunction::from_entries(
            (0..4096)
                .map(|i| [1.0, 0.5, 0.25, if i >= 2048 { 0.9 } else { 0.0 }])
                .collect(),
        );
        let ramps = TransferFunction::from_points(
            &[
                (0.3, [0.8, 0.5, 0.4, 0.0]),
                (0.31, [0.9, 0.8, 0.7, 0.02]),
                (0.35, [1.0, 0.95, 0.85, 0.5]),
                (0.7, [0.2, 0.4, 1.0, 0.1]),
            ],
            512,
        );
        let mut worst = 0.0f64;
        for tf in [&step, &ramps] {
            for r in [1, 2, 4, 8, 16, 31] {
                let s = spread_row_sigma(r, SPREAD_ROWS);
                for k in 0..=20 {
                    let v = k as f64 / 20.0;
                    let ours = tf.convolved(v, s);
                    let want = fine(tf, v, s);
                    // Compare premultiplied colour and opacity.
                    for i in 0..3 {
                        worst = worst.max((ours[i] * ours[3] - want[i]).abs());
                    }
                    worst = worst.max((ours[3] - want[3]).abs());
                }
            }
        }
        println!("largest difference from the fine rule: {worst:.2e}");
        assert!(worst < 2e-3, "{worst}");
    }

    #[test]
    fn corrected_layers_correct_after_the_average() {
        let tf = TransferFunction::ramp(0.3, 0.6, 0.8);
        let t = tf.spread_table(8, 8192);
        let layers = t.corrected_layers(0.5, 3);
        let (w, r) = (t.width as usize, t.rows as usize);
        assert_eq!(layers.len(), 3 * r * w);
        let plain = tf.corrected_table(0.5, 3, 8192);
        assert_eq!(plain.width, t.width);
        for e in 0..3 {
            // Spread 0: exactly the corrected table's row.
            assert_eq!(&layers[e * r * w..][..w], &plain.texels[e * w..][..w]);
            // A spread row: the averaged opacity, corrected.
            let texel = layers[(e * r + 5) * w + 100];
            let reference = t.texels[5 * w + 100];
            let want = corrected_alpha(reference[3] as f64, 0.5 * (e as f64).exp2()) as f32;
            assert_eq!(texel[3], want);
            assert_eq!(texel[..3], reference[..3]);
        }
    }

    proptest! {
        /// The widened skip test is conservative: where it says transparent,
        /// every table lookup of a value in the range with a spread up to the
        /// bound has zero opacity (values and spreads swept densely, bilinear
        /// lookups between rows and columns included).
        #[test]
        fn widened_skip_is_conservative(
            alphas in prop::collection::vec(prop_oneof![3 => Just(0.0f32), 1 => 0.0f32..1.0], 2..24),
            a in 0.0f32..1.0, b in 0.0f32..1.0, sigma_max in 0.0f32..0.3,
        ) {
            let tf = TransferFunction::from_entries(alphas.iter().map(|&x| [1.0, 1.0, 1.0, x]).collect());
            let t = tf.spread_table(16, 8192);
            let (lo, hi) = if a <= b { (a, b) } else { (b, a) };
            if tf.is_transparent_spread(lo, hi, sigma_max, t.width, t.rows) {
                for i in 0..=64 {
                    let v = lo as f64 + (hi - lo) as f64 * i as f64 / 64.0;
                    for j in 0..=16 {
                        let s = sigma_max as f64 * j as f64 / 16.0;
                        let c = t.lookup(&tf, v, s);
                        prop_assert!(c[3] == 0.0, "v {v} s {s} alpha {}", c[3]);
                        prop_assert!(tf.convolved(v, s)[3] == 0.0);
                    }
                }
            }
            // With no spread it is exactly the plain test.
            prop_assert_eq!(tf.is_transparent_spread(lo, hi, 0.0, t.width, t.rows), tf.is_transparent(lo, hi));
        }
    }
}
