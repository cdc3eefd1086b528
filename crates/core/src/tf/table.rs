//! The transfer function as the GPU kernels read it: a 2D table of RGBA with the
//! opacity already corrected to the sampling step, one row per step length in use
//! (in core one; out of core one per octree level, whose step doubles per level,
//! as Gobbetti et al. 2008 precompute a 2D TF with the level as second axis).
//! Kernels read it with hardware linear filtering instead of interpolating by
//! hand and computing a `pow` per sample.
//!
//! Row `r` corrects to `step_factor * 2^r` reference lengths. The columns sample
//! the TF's piecewise-linear function at `width` evenly spaced values 0..1, with
//! `width >= MIN_WIDTH` chosen so that every entry of the TF falls on a column
//! (`width - 1` a multiple of `len - 1`) while that fits the device's limit:
//! between columns the table interpolates the *corrected* opacity, where the exact
//! model corrects the interpolated one; `docs/rendering-model.md` states the
//! difference, and the CPU reference keeps the exact model.

use super::{TransferFunction, corrected_alpha};

/// The least columns of a table (a TF of fewer entries is resampled onto at least
/// this many, so that filtering hardware's 8-bit weights span a small interval).
pub const MIN_WIDTH: u32 = 256;

/// A corrected table: `rows` rows of `width` RGBA texels, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct CorrectedTable {
    /// Columns (values 0..1 at `i / (width - 1)`).
    pub width: u32,
    /// Rows (row `r` corrected to `step_factor * 2^r` reference lengths).
    pub rows: u32,
    /// `rows * width` straight-colour RGBA texels, row 0 first.
    pub texels: Vec<[f32; 4]>,
}

impl TransferFunction {
    /// Columns of the corrected table for a device whose 2D textures hold at most
    /// `max_width` texels a row: the TF's entries themselves when there are at
    /// least [`MIN_WIDTH`] (resampled down to `max_width` beyond it), else the
    /// smallest multiple subdivision of its intervals reaching [`MIN_WIDTH`].
    pub fn table_width(&self, max_width: u32) -> u32 {
        let max_width = max_width.max(2);
        let n = self.len() as u32;
        let w = if n >= MIN_WIDTH {
            n
        } else {
            let intervals = n - 1;
            intervals * (MIN_WIDTH - 1).div_ceil(intervals) + 1
        };
        w.min(max_width)
    }

    /// The corrected table: `rows` rows, row `r` with the opacity corrected to
    /// `step_factor * 2^r` reference lengths, [`Self::table_width`] columns.
    pub fn corrected_table(&self, step_factor: f32, rows: u32, max_width: u32) -> CorrectedTable {
        self.corrected_table_of_width(step_factor, rows, self.table_width(max_width))
    }

    /// [`Self::corrected_table`] with `width` columns (at least 2): what
    /// several TFs stacked in one texture share (a multi-channel volume's,
    /// [`crate::channels`], at the widest of their widths).
    pub fn corrected_table_of_width(
        &self,
        step_factor: f32,
        rows: u32,
        width: u32,
    ) -> CorrectedTable {
        let width = width.max(2);
        let rows = rows.max(1);
        let base: Vec<[f64; 4]> = (0..width)
            .map(|i| self.lookup(i as f64 / (width - 1) as f64))
            .collect();
        let mut texels = Vec::with_capacity((rows * width) as usize);
        for r in 0..rows {
            let exponent = step_factor as f64 * (r as f64).exp2();
            texels.extend(base.iter().map(|c| {
                [
                    c[0] as f32,
                    c[1] as f32,
                    c[2] as f32,
                    corrected_alpha(c[3], exponent) as f32,
                ]
            }));
        }
        CorrectedTable {
            width,
            rows,
            texels,
        }
    }
}

impl CorrectedTable {
    /// What a filtering lookup of row `row` at value `v` returns when the
    /// interpolation is exact (the table's own model; hardware adds weight
    /// quantisation).
    pub fn lookup(&self, row: u32, v: f64) -> [f64; 4] {
        let w = self.width as usize;
        let x = v.clamp(0.0, 1.0) * (w - 1) as f64;
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

    fn exact(tf: &TransferFunction, v: f64, exponent: f64) -> [f64; 4] {
        let c = tf.lookup(v);
        [c[0], c[1], c[2], corrected_alpha(c[3], exponent)]
    }

    #[test]
    fn width_keeps_every_entry_on_a_column() {
        let tf = TransferFunction::from_points(&[(0.2, [1.0; 4]), (0.4, [0.0; 4])], 5);
        let w = tf.table_width(8192);
        assert!(w >= MIN_WIDTH);
        assert_eq!((w - 1) % 4, 0);
        assert_eq!(TransferFunction::ramp(0.0, 1.0, 1.0).table_width(8192), 256);
        let big = TransferFunction::from_entries(vec![[0.5; 4]; 10000]);
        assert_eq!(big.table_width(8192), 8192);
    }

    proptest! {
        /// At every column the table equals the exact model (correction after
        /// interpolation), in every row, to f32 precision; between columns it
        /// differs by at most the second-order term the module docs describe,
        /// bounded here by the alpha step between neighbouring columns.
        #[test]
        fn table_matches_the_exact_model(
            alphas in proptest::collection::vec(0.0f32..=1.0, 2..40),
            step in 0.05f32..4.0,
            rows in 1u32..6,
            v in 0.0f64..=1.0,
        ) {
            let n = alphas.len();
            let tf = TransferFunction::from_entries(
                alphas.iter().map(|&a| [a, 1.0 - a, 0.5, a]).collect());
            let t = tf.corrected_table(step, rows, 8192);
            prop_assert_eq!(t.texels.len(), (t.width * t.rows) as usize);
            for r in 0..t.rows {
                let e = step as f64 * (r as f64).exp2();
                for i in (0..t.width).step_by(7) {
                    let x = i as f64 / (t.width - 1) as f64;
                    let (a, b) = (t.lookup(r, x), exact(&tf, x, e));
                    for k in 0..4 {
                        prop_assert!((a[k] - b[k]).abs() < 1e-5, "row {} col {} ch {}: {} vs {}", r, i, k, a[k], b[k]);
                    }
                }
                // Between columns: the corrected opacity of a column interval.
                let w = (t.width - 1) as f64;
                let i = (v * w).floor().min(w - 1.0);
                let lo = exact(&tf, i / w, e)[3];
                let hi = exact(&tf, (i + 1.0) / w, e)[3];
                let (a, b) = (t.lookup(r, v)[3], exact(&tf, v, e)[3]);
                prop_assert!((a - b).abs() <= (hi - lo).abs() + 1e-5,
                    "n {} row {} v {}: table {} exact {}", n, r, v, a, b);
            }
        }
    }
}

#[cfg(test)]
mod hardware {
    use super::*;

    /// A filtering lookup as hardware does it: texels stored as f16, the weight
    /// quantised to 8 fractional bits (the coarsest WebGPU devices use).
    fn filtered(t: &CorrectedTable, row: u32, v: f64) -> [f64; 4] {
        let w = t.width as usize;
        let x = v.clamp(0.0, 1.0) * (w - 1) as f64;
        let i = (x.floor() as usize).min(w - 1);
        let j = (i + 1).min(w - 1);
        let f = ((x - i as f64) * 256.0).round() / 256.0;
        let q = |c: f32| half::f16::from_f32(c).to_f64();
        let row = &t.texels[row as usize * w..][..w];
        std::array::from_fn(|k| q(row[i][k]) + (q(row[j][k]) - q(row[i][k])) * f)
    }

    /// The worst opacity and colour error of filtered table reads against the
    /// exact model (interpolate, then correct), over a fine sweep of values in
    /// `[0, v_max]`.
    fn worst(tf: &TransferFunction, step: f32, rows: u32, v_max: f64) -> (f64, f64) {
        let t = tf.corrected_table(step, rows, 8192);
        let (mut ea, mut ec) = (0.0f64, 0.0f64);
        for r in 0..rows {
            let e = step as f64 * (r as f64).exp2();
            for s in 0..=20_000 {
                let v = v_max * s as f64 / 20_000.0;
                let c = tf.lookup(v);
                let h = filtered(&t, r, v);
                ea = ea.max((h[3] - corrected_alpha(c[3], e)).abs());
                for k in 0..3 {
                    ec = ec.max((h[k] - c[k]).abs());
                }
            }
        }
        (ea, ec)
    }

    fn soft() -> TransferFunction {
        TransferFunction::from_points(
            &[
                (0.15, [0.2, 0.4, 1.0, 0.0]),
                (0.3, [0.3, 0.7, 1.0, 0.05]),
                (0.5, [1.0, 0.8, 0.4, 0.15]),
                (0.9, [1.0, 1.0, 1.0, 0.6]),
            ],
            256,
        )
    }

    /// The error the table adds over the exact lookup, for transfer functions
    /// whose opacity stays below 0.99: at most 1e-3 in opacity and colour (a
    /// quarter of an 8-bit level), at steps of 1/4 to 4 reference lengths.
    /// Printed for docs/rendering-model.md.
    #[test]
    fn filtered_table_error_is_below_a_quarter_of_an_8_bit_level() {
        let tfs = [
            ("soft ramp, 256 entries", soft()),
            (
                "opaque step, 4096 entries",
                TransferFunction::from_points(
                    &[(0.55, [0.9, 0.9, 0.8, 0.0]), (0.6, [1.0, 1.0, 0.9, 0.98])],
                    4096,
                ),
            ),
            (
                "grey ramp to 0.95, 2 entries",
                TransferFunction::ramp(0.0, 1.0, 0.95),
            ),
        ];
        for (name, tf) in &tfs {
            for step in [0.25f32, 0.5, 1.0, 4.0] {
                let (ea, ec) = worst(tf, step, 3, 1.0);
                println!(
                    "{name}, step {step}: width {}, worst opacity error {ea:.2e}, colour {ec:.2e}",
                    tf.table_width(8192)
                );
                assert!(ea < 1e-3 && ec < 1e-3, "{name} step {step}: {ea} {ec}");
            }
        }
    }

    /// Where the opacity reaches 1 and the step is below the reference length,
    /// `1 - (1 - a)^e` is steep and the table's interpolation of corrected
    /// opacity departs from the exact model, but only within the last few column
    /// intervals before the opacity reaches 1 (measured: 0.12 in the last, 3e-3
    /// in the one before, below 1e-3 from four intervals away).
    #[test]
    fn opacity_one_departs_only_in_the_last_interval() {
        let tf = TransferFunction::ramp(0.0, 1.0, 1.0);
        let w = tf.table_width(8192) as f64;
        let (near, _) = worst(&tf, 0.25, 1, 1.0);
        let (away, _) = worst(&tf, 0.25, 1, 1.0 - 4.0 / (w - 1.0));
        println!(
            "grey ramp to 1, step 0.25: worst opacity error {near:.3} in the last interval, {away:.2e} four intervals away"
        );
        assert!(near > 1e-2, "the steep case is real: {near}");
        assert!(away < 1e-3, "{away}");
    }
}
