//! Transfer functions: normalized value (0..1) to RGBA.
//!
//! A [`TransferFunction`] is a table of `N` RGBA entries spanning normalized values
//! 0..1; a lookup clamps the value to 0..1 and interpolates linearly between the
//! two nearest entries (entry `i` sits at `i / (N - 1)`). Colours are straight
//! (not premultiplied). Opacity is defined per *reference length*, one voxel of the
//! smallest spacing; renderers correct it to their step with
//! [`corrected_alpha`].
//!
//! The opacity prefix-sum table ([`TransferFunction::is_transparent`], Gobbetti et
//! al. 2008, sect. 4) answers "can any value in `[min, max]` be visible?" in O(1):
//! a lookup of a value in that range interpolates only entries
//! `floor(min*(N-1)) ..= ceil(max*(N-1))`, so the range is transparent exactly when
//! that run of entries has no non-zero alpha.

mod model;
mod preint;
pub mod spread;
mod table;

pub use model::{ColorPoint, OpacityPoint, TABLE_ENTRIES, TfFileError, TfModel, TfPreset};
pub use preint::{
    FINE as PREINT_FINE, PREINT_MIN_SIZE, PreintTable, Preintegrator, SEGMENT_PIECES, TAU_MAX,
    join_pieces, segment_values,
};
pub use spread::{SPREAD_ROWS, SpreadTable};
pub use table::{CorrectedTable, MIN_WIDTH as TABLE_MIN_WIDTH};

/// A 1D RGBA transfer function.
#[derive(Debug, Clone, PartialEq)]
pub struct TransferFunction {
    entries: Vec<[f32; 4]>,
    /// `prefix[i]` = number of entries `j < i` with alpha > 0.
    prefix: Vec<u32>,
}

/// Opacity `alpha` defined per reference length, corrected for a step of
/// `step / reference` reference lengths: `1 - (1 - alpha)^(step/reference)`.
#[inline]
pub fn corrected_alpha(alpha: f64, step_over_reference: f64) -> f64 {
    1.0 - (1.0 - alpha.clamp(0.0, 1.0)).powf(step_over_reference)
}

/// A transfer function that cannot be built as given.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum TfError {
    /// Fewer than two entries (or control points: at least one is needed).
    #[error("a transfer function needs at least {min} entries, got {len}")]
    TooFew {
        /// Entries given.
        len: usize,
        /// Entries needed.
        min: usize,
    },
    /// More entries than [`TransferFunction::MAX_ENTRIES`].
    #[error("a transfer function holds at most {max} entries, got {len}")]
    TooMany {
        /// Entries given.
        len: usize,
        /// The maximum.
        max: usize,
    },
    /// An entry (or a control point's position) is NaN or infinite.
    #[error("transfer-function entry {index} component {component} is not finite")]
    NotFinite {
        /// The entry or control point.
        index: usize,
        /// 0..4 = r, g, b, a; 4 = a control point's position.
        component: usize,
    },
}

impl TransferFunction {
    /// Most entries a table may have (256 KiB of RGBA f32 on the GPU, well
    /// inside WebGPU's default storage-binding limit).
    pub const MAX_ENTRIES: usize = 1 << 14;

    /// Builds a table from entries, refusing what [`Self::from_entries`] would
    /// repair: fewer than 2 or more than [`Self::MAX_ENTRIES`] entries, or a NaN
    /// or infinite component. Finite components are clamped to 0..1.
    pub fn try_from_entries(entries: Vec<[f32; 4]>) -> Result<TransferFunction, TfError> {
        if entries.len() < 2 {
            return Err(TfError::TooFew {
                len: entries.len(),
                min: 2,
            });
        }
        if entries.len() > Self::MAX_ENTRIES {
            return Err(TfError::TooMany {
                len: entries.len(),
                max: Self::MAX_ENTRIES,
            });
        }
        for (index, e) in entries.iter().enumerate() {
            if let Some(component) = e.iter().position(|c| !c.is_finite()) {
                return Err(TfError::NotFinite { index, component });
            }
        }
        Ok(TransferFunction::from_entries(entries))
    }

    /// Like [`Self::from_points`], refusing non-finite positions or colours, no
    /// point at all, and `n` outside `2..=MAX_ENTRIES`.
    pub fn try_from_points(
        points: &[(f32, [f32; 4])],
        n: usize,
    ) -> Result<TransferFunction, TfError> {
        if points.is_empty() {
            return Err(TfError::TooFew { len: 0, min: 1 });
        }
        if n < 2 {
            return Err(TfError::TooFew { len: n, min: 2 });
        }
        if n > Self::MAX_ENTRIES {
            return Err(TfError::TooMany {
                len: n,
                max: Self::MAX_ENTRIES,
            });
        }
        for (index, (x, c)) in points.iter().enumerate() {
            if !x.is_finite() {
                return Err(TfError::NotFinite {
                    index,
                    component: 4,
                });
            }
            if let Some(component) = c.iter().position(|v| !v.is_finite()) {
                return Err(TfError::NotFinite { index, component });
            }
        }
        Ok(TransferFunction::from_points(points, n))
    }

    /// Builds a table from entries, repairing what it must: fewer than 2 entries
    /// are padded, non-finite components become 0 and all are clamped to 0..1.
    /// Use [`Self::try_from_entries`] to refuse such input instead.
    pub fn from_entries(entries: Vec<[f32; 4]>) -> TransferFunction {
        let mut entries = entries;
        if entries.is_empty() {
            entries.push([0.0; 4]);
        }
        if entries.len() == 1 {
            entries.push(entries[0]);
        }
        for e in &mut entries {
            for c in e.iter_mut() {
                *c = if c.is_finite() {
                    c.clamp(0.0, 1.0)
                } else {
                    0.0
                };
            }
        }
        let mut prefix = Vec::with_capacity(entries.len() + 1);
        prefix.push(0);
        let mut n = 0;
        for e in &entries {
            if e[3] > 0.0 {
                n += 1;
            }
            prefix.push(n);
        }
        TransferFunction { entries, prefix }
    }

    /// Samples piecewise-linear control points `(value, rgba)` (values in 0..1,
    /// sorted or not) into a table of `n` entries. Outside the first and last point
    /// the end colours are held.
    pub fn from_points(points: &[(f32, [f32; 4])], n: usize) -> TransferFunction {
        let mut pts: Vec<(f32, [f32; 4])> = points.to_vec();
        pts.sort_by(|a, b| a.0.total_cmp(&b.0));
        let n = n.max(2);
        let entries = (0..n)
            .map(|i| {
                let x = i as f32 / (n - 1) as f32;
                match pts.iter().position(|p| p.0 >= x) {
                    None => pts.last().map(|p| p.1).unwrap_or([0.0; 4]),
                    Some(0) => pts[0].1,
                    Some(j) => {
                        let (x0, c0) = pts[j - 1];
                        let (x1, c1) = pts[j];
                        let f = if x1 > x0 { (x - x0) / (x1 - x0) } else { 1.0 };
                        std::array::from_fn(|k| c0[k] + (c1[k] - c0[k]) * f)
                    }
                }
            })
            .collect();
        TransferFunction::from_entries(entries)
    }

    /// A grey ramp: transparent up to `lo`, linearly rising to `(1,1,1,alpha)` at `hi`.
    pub fn ramp(lo: f32, hi: f32, alpha: f32) -> TransferFunction {
        TransferFunction::from_points(
            &[(lo, [1.0, 1.0, 1.0, 0.0]), (hi, [1.0, 1.0, 1.0, alpha])],
            256,
        )
    }

    /// The entries.
    pub fn entries(&self) -> &[[f32; 4]] {
        &self.entries
    }

    /// The opacity prefix-sum table (`len() + 1` counts).
    pub fn prefix(&self) -> &[u32] {
        &self.prefix
    }

    /// Number of entries.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Always false (a table has at least two entries).
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Looks up a normalized value (clamped to 0..1), interpolating in f64.
    pub fn lookup(&self, v: f64) -> [f64; 4] {
        let n = self.entries.len();
        let x = v.clamp(0.0, 1.0) * (n - 1) as f64;
        let i = (x.floor() as usize).min(n - 1);
        let j = (i + 1).min(n - 1);
        let f = x - i as f64;
        let (a, b) = (self.entries[i], self.entries[j]);
        std::array::from_fn(|k| a[k] as f64 + (b[k] as f64 - a[k] as f64) * f)
    }

    /// The entry range `[i0, i1]` a lookup of any value in `[min, max]` reads.
    fn entry_range(&self, min: f32, max: f32) -> (usize, usize) {
        let n1 = (self.entries.len() - 1) as f32;
        let lo = if min.is_nan() {
            0.0
        } else {
            min.clamp(0.0, 1.0)
        };
        let hi = if max.is_nan() {
            1.0
        } else {
            max.clamp(0.0, 1.0)
        };
        let i0 = (lo * n1).floor() as usize;
        let i1 = ((hi * n1).ceil() as usize).min(self.entries.len() - 1);
        (i0.min(i1), i1)
    }

    /// True when every value in the normalized range `[min, max]` maps to zero
    /// opacity. O(1).
    pub fn is_transparent(&self, min: f32, max: f32) -> bool {
        let (i0, i1) = self.entry_range(min, max);
        self.prefix[i1 + 1] == self.prefix[i0]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn strict_constructors_refuse_bad_input() {
        assert_eq!(
            TransferFunction::try_from_entries(vec![[0.0; 4]]),
            Err(TfError::TooFew { len: 1, min: 2 })
        );
        assert_eq!(
            TransferFunction::try_from_entries(vec![[0.0; 4], [0.0, f32::NAN, 0.0, 0.0]]),
            Err(TfError::NotFinite {
                index: 1,
                component: 1
            })
        );
        assert!(matches!(
            TransferFunction::try_from_entries(vec![[0.0; 4]; TransferFunction::MAX_ENTRIES + 1]),
            Err(TfError::TooMany { .. })
        ));
        assert_eq!(
            TransferFunction::try_from_points(&[(f32::NAN, [1.0; 4])], 16),
            Err(TfError::NotFinite {
                index: 0,
                component: 4
            })
        );
        assert!(TransferFunction::try_from_points(&[(0.5, [1.0; 4])], 1).is_err());
        let ok =
            TransferFunction::try_from_points(&[(0.2, [1.0, 0.0, 0.0, 0.0]), (0.8, [2.0; 4])], 64)
                .unwrap();
        assert_eq!(
            ok,
            TransferFunction::from_points(&[(0.2, [1.0, 0.0, 0.0, 0.0]), (0.8, [2.0; 4])], 64)
        );
    }

    #[test]
    fn ramp_lookup_and_transparency() {
        let tf = TransferFunction::ramp(0.5, 1.0, 1.0);
        assert_eq!(tf.lookup(0.25)[3], 0.0);
        assert!((tf.lookup(1.0)[3] - 1.0).abs() < 1e-9);
        assert!(tf.is_transparent(0.0, 0.4));
        assert!(!tf.is_transparent(0.0, 0.6));
        assert!(!tf.is_transparent(0.9, 2.0));
    }

    proptest! {
        /// The O(1) classification agrees with brute-force lookups over the range.
        #[test]
        fn prefix_classification_is_exact(
            alphas in prop::collection::vec(prop_oneof![Just(0.0f32), 0.0f32..1.0], 2..40),
            a in -0.2f32..1.2, b in -0.2f32..1.2,
        ) {
            let tf = TransferFunction::from_entries(alphas.iter().map(|&x| [1.0, 1.0, 1.0, x]).collect());
            let (lo, hi) = if a <= b { (a, b) } else { (b, a) };
            let transparent = tf.is_transparent(lo, hi);
            // Brute force: dense samples over [lo, hi] (plus both ends).
            let mut any = false;
            for k in 0..=2000 {
                let v = lo as f64 + (hi as f64 - lo as f64) * k as f64 / 2000.0;
                if tf.lookup(v)[3] > 0.0 { any = true; }
            }
            // Conservative: a visible sample implies "not transparent".
            if any { prop_assert!(!transparent); }
            // Exact up to the sampling density: "not transparent" implies some
            // entry in the read run is non-zero.
            if !transparent {
                let (i0, i1) = tf.entry_range(lo, hi);
                prop_assert!(tf.entries()[i0..=i1].iter().any(|e| e[3] > 0.0));
            }
        }
    }
}
