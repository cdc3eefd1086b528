//! Error-aware level of detail: what drawing a node instead of the finest data
//! can change, recorded per node ([`NodeError`], store format version 2), and
//! what that costs under a render mode and transfer function ([`TfErrorTable`]).
//!
//! # The recorded bound
//!
//! A node's value range `[min, max]` ([`NodeInfo`]) is cut into
//! [`ERROR_BINS`] equal bins. For each coarse voxel `C` of the node (the voxels
//! its samples interpolate: interior `0..=brick` per axis) the bound is
//! `dev(C) = max |F - C|` over the finest-level voxels `F` of the footprints of
//! `C` and of its 26 neighbours at its level (the finest voxels any trilinear
//! sample at the finest level reads where `C` has a non-zero weight). Bin `b`
//! records whether some `C` falls in it (`occupied`) and the largest `dev(C)`
//! of those (`dev`, rounded up to 1/65535 of `max - min`).
//!
//! Then for any point `p` of the node, with `c(p)` the coarse sample and
//! `f(p)` the finest-level sample (both trilinear, clamp-to-edge): every
//! coarse voxel `C_k` with a non-zero weight satisfies `|f(p) - C_k| <=
//! dev(C_k)`, so `f(p)` lies in every widened bin
//! `W_b = [bin_lo(b) - dev_b, bin_hi(b) + dev_b]` of those voxels, and `c(p)`
//! lies between the smallest and largest `C_k`; hence both `c(p)` and `f(p)`
//! lie in **one** widened bin (the one whose lower end is lowest, if `c < f`;
//! the highest otherwise). So the change of anything computed from the sample
//! value alone is at most its oscillation (max - min) over the widened bins of
//! the occupied bins. The bound is against the finest level, so it holds for
//! a node drawn instead of any refinement of it. It does not bound gradients
//! (shading).
//!
//! # The expected error
//!
//! The worst case over 27 footprints is rarely much below a node's value
//! range, so each bin also records its typical deviation (`rms`: the RMS of
//! `F - C` over each coarse voxel's own footprint) and its share of the
//! node's voxels (`weight`). [`node_tf_error_expected`] and
//! [`node_pixel_error`] (what [`LodMetric::VisibleError`] ranks a node by
//! before the renderer has measured its visible weight) use them;
//! [`node_tf_error`] is the bound.

use crate::{NodeInfo, NodeKind, OctreeLayout, RenderMode, TransferFunction};

/// How refinement decides that a node is fine enough (`docs/cache.md`).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum LodMetric {
    /// A node is refined while one of its voxels projects to more than the
    /// tolerance in pixels, whatever the data and transfer function do there.
    #[default]
    Geometric,
    /// A node is refined while its error in the image exceeds `budget`, in
    /// 8-bit levels x pixels. The error is what the image shows of the node
    /// where the renderer measured that: its *visible weight*
    /// `w`, the transmittance-weighted length in finest voxels of every
    /// pixel's ray through it (an isosurface ray's up to its hit), summed over
    /// pixels, times 255 x its per-sample expected error
    /// ([`node_visible_error`]: the mean change of a sample): the node's summed
    /// change of the image, linearised, in 8-bit levels x pixels. It is
    /// divided by `brick^2` so that for a fully visible node whose voxels
    /// project to 1 px it is that mean change per pixel; a nearer node ranks
    /// higher by the extra pixels it covers, a half-hidden one lower by its
    /// transmittance, a hidden one (weight 0) is never split.
    ///
    /// Nodes without a measured weight (the first frames of a view, in-core
    /// rendering, refinement on the CPU without weights) are ranked by their
    /// projected voxel size (pixels) times their expected pixel error under
    /// the current mode and transfer function ([`node_pixel_error`]: 255 x
    /// the share-weighted change of the opacity-weighted classified sample,
    /// accumulated over the node's depth in DVR): 16 lets a voxel covering
    /// one pixel err by 16/255, or one covering 4 pixels by 4/255; 255
    /// refines a node of full-scale error to 1 px, like the geometric rule at
    /// 1 px. A flat transfer-function region or smooth data costs nothing and
    /// coarsens freely. Sources without error records (a version-1 store, the
    /// procedural source) fall back to [`LodMetric::Geometric`]. A host that
    /// plans with no ray caster's feedback (a GPU-free streamer) gets that
    /// rank throughout; its streamer's convergence then waits for weights
    /// that never come, so it reads the cache's own convergence instead.
    ///
    /// The rank without weights was once a metric of its own (`ErrorAware`,
    /// and `ErrorBound` with the strict bound [`node_tf_error`]); at equal
    /// bricks it was never ahead of both this order and
    /// [`LodMetric::VisibleOctants`] on the pareto scenes, and 1.3-3.4 dB
    /// behind them in the median (docs/accuracy.md), so it is only this
    /// fallback now.
    VisibleError {
        /// The error budget (finite, `>= 0`).
        budget: f32,
    },
    /// Ranked like [`LodMetric::VisibleError`], but the cut is refined one
    /// octant at a time (`docs/cache.md`, "Octant-granular cuts"): a split
    /// node keeps its brick, its children are drawn from it until each gets
    /// its own brick, in order of its visible weight times the error of
    /// drawing it from its parent's brick. A brick then goes to the octant
    /// that shows error, not to all the children of a node at once; the
    /// parent's brick stays in the working set while a child is drawn from
    /// it. Out of core only (the in-core renderer has no cut).
    VisibleOctants {
        /// The error budget (finite, `>= 0`).
        budget: f32,
    },
}

impl LodMetric {
    /// The error budget of an error-aware metric (`None` for the geometric one).
    pub fn budget(self) -> Option<f32> {
        match self {
            LodMetric::Geometric => None,
            LodMetric::VisibleError { budget } | LodMetric::VisibleOctants { budget } => {
                Some(budget)
            }
        }
    }

    /// Whether refinement ranks by the renderer's measured visible weights
    /// ([`LodMetric::VisibleError`], [`LodMetric::VisibleOctants`]).
    pub fn uses_visible_weights(self) -> bool {
        matches!(
            self,
            LodMetric::VisibleError { .. } | LodMetric::VisibleOctants { .. }
        )
    }
}

pub use crate::node_error::{BinStats, DEV_SCALE, ERROR_BINS, NodeError, bin_of};

/// Range minima and maxima of a transfer function's entries (a sparse table),
/// for the oscillation of a lookup over a value interval in O(1).
#[derive(Debug, Clone)]
pub struct TfErrorTable {
    tf: TransferFunction,
    /// `levels[k][i]`: per channel (min, max) of entries `i .. i + 2^k`.
    levels: Vec<Vec<[[f32; 2]; 4]>>,
}

impl TfErrorTable {
    /// The table of `tf`.
    pub fn new(tf: &TransferFunction) -> TfErrorTable {
        let e = tf.entries();
        let mut levels = vec![
            e.iter()
                .map(|c| std::array::from_fn(|k| [c[k], c[k]]))
                .collect::<Vec<[[f32; 2]; 4]>>(),
        ];
        let mut w = 1usize;
        while 2 * w <= e.len() {
            let prev = &levels[levels.len() - 1];
            let next = (0..=e.len() - 2 * w)
                .map(|i| {
                    let (a, b) = (prev[i], prev[i + w]);
                    std::array::from_fn(|k| [a[k][0].min(b[k][0]), a[k][1].max(b[k][1])])
                })
                .collect();
            levels.push(next);
            w *= 2;
        }
        TfErrorTable {
            tf: tf.clone(),
            levels,
        }
    }

    /// The transfer function.
    pub fn tf(&self) -> &TransferFunction {
        &self.tf
    }

    /// Per channel (min, max) of the lookup over the normalized interval
    /// `[a, b]` (clamped to 0..1, in either order): the end points and every
    /// entry between them (lookups interpolate linearly between entries).
    pub fn range(&self, a: f64, b: f64) -> [[f64; 2]; 4] {
        let (a, b) = if a <= b { (a, b) } else { (b, a) };
        let (a, b) = (clamp01(a), clamp01(b));
        let (la, lb) = (self.tf.lookup(a), self.tf.lookup(b));
        let mut r: [[f64; 2]; 4] = std::array::from_fn(|k| [la[k].min(lb[k]), la[k].max(lb[k])]);
        let n1 = (self.tf.len() - 1) as f64;
        let i0 = (a * n1).ceil() as usize;
        let i1 = ((b * n1).floor() as usize).min(self.tf.len() - 1);
        if i0 <= i1 {
            let len = i1 - i0 + 1;
            let k = (usize::BITS - 1 - len.leading_zeros()) as usize;
            let (x, y) = (self.levels[k][i0], self.levels[k][i1 + 1 - (1 << k)]);
            for c in 0..4 {
                r[c][0] = r[c][0].min(x[c][0].min(y[c][0]) as f64);
                r[c][1] = r[c][1].max(x[c][1].max(y[c][1]) as f64);
            }
        }
        r
    }

    /// Bound on the change of the opacity-weighted classified sample
    /// `(a, a*r, a*g, a*b)` between any two values of the normalized interval
    /// `[a, b]`: `osc(alpha) + max(alpha) * max osc(colour)`
    /// (`|a1 c1 - a2 c2| <= |a1 - a2| c1 + a2 |c1 - c2|`, colours in 0..1).
    pub fn classified_change(&self, a: f64, b: f64) -> f64 {
        let r = self.range(a, b);
        let osc = |c: usize| r[c][1] - r[c][0];
        let colour = osc(0).max(osc(1)).max(osc(2));
        osc(3) + r[3][1].max(0.0) * colour
    }
}

fn clamp01(v: f64) -> f64 {
    if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) }
}

/// A data node's error record and range, for the error functions below.
struct NodeBins<'a> {
    err: NodeError,
    min: f64,
    max: f64,
    layout: &'a OctreeLayout,
}

impl<'a> NodeBins<'a> {
    /// `Err` holds the answer without bins: `None` when the node records no
    /// error bound, 0 for a node without data of its own (uniform, empty).
    fn of(info: &NodeInfo, layout: &'a OctreeLayout) -> Result<NodeBins<'a>, Option<f64>> {
        let err = info.error.ok_or(None)?;
        if info.kind != NodeKind::Data {
            return Err(Some(0.0));
        }
        Ok(NodeBins {
            err,
            min: info.min as f64,
            max: info.max as f64,
            layout,
        })
    }

    /// A raw value on the volume's 0..1 scale (0 for a flat value range).
    fn norm(&self, v: f64) -> f64 {
        let [lo, hi] = self.layout.volume.value_range;
        let span = hi as f64 - lo as f64;
        if span > 0.0 {
            (v - lo as f64) / span
        } else {
            0.0
        }
    }

    fn occupied(&self) -> impl Iterator<Item = usize> + '_ {
        (0..ERROR_BINS).filter(|&b| self.err.is_occupied(b))
    }

    /// Bin `b` widened by `d` (raw units), on the 0..1 scale.
    fn widened(&self, b: usize, d: f64) -> (f64, f64) {
        let (lo, hi) = self.err.widened_by(b, self.min, self.max, d);
        (self.norm(lo), self.norm(hi))
    }

    /// A label node's error (a label store's records hold the share `s` of
    /// the node's finest voxels whose label changes,
    /// [`NodeError::label_share`]): with `c` the largest change of the
    /// classified sample among the labels of the node's id range
    /// ([`TfErrorTable::classified_change`]; 0 when they are all hidden), DVR
    /// reads `c` when `s > 0` as the bound and `s * c` as the typical error;
    /// iso reads 1 when `s > 0`; MIP reads `s`.
    fn label_error(&self, mode: RenderMode, table: &TfErrorTable, which: Deviation) -> f64 {
        let s = self.err.label_share();
        if s <= 0.0 {
            return 0.0;
        }
        match mode {
            RenderMode::Dvr => {
                let c = table.classified_change(self.norm(self.min), self.norm(self.max));
                match which {
                    Deviation::Bound => c,
                    Deviation::Typical => s * c,
                }
            }
            RenderMode::Iso { .. } => 1.0,
            _ => s,
        }
    }

    /// Whether the isovalue lies in some bin widened by its `d(b)` (a bin that
    /// does not deviate cannot move the crossing).
    fn iso_in_a_bin(&self, value: f32, d: impl Fn(usize) -> f64) -> bool {
        self.occupied().any(|b| {
            let (a, c) = self.widened(b, d(b));
            let (a, c) = if a <= c { (a, c) } else { (c, a) };
            self.err.dev[b] > 0 && a <= value as f64 && value as f64 <= c
        })
    }
}

/// An error in 0..=1 (NaN, from a degenerate record, counts as full scale).
fn unit(e: f64) -> f64 {
    if e.is_nan() { 1.0 } else { e.clamp(0.0, 1.0) }
}

/// Which deviation of a bin widens it when a node's error is read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Deviation {
    /// The recorded bound (the largest deviation): [`node_tf_error`].
    Bound,
    /// The typical (RMS) deviation: [`node_tf_error_expected`].
    Typical,
}

/// The error of drawing a node, each occupied bin widened by `which`
/// deviation (see the two public functions for what each mode reads).
fn tf_error(
    info: &NodeInfo,
    mode: RenderMode,
    table: &TfErrorTable,
    layout: &OctreeLayout,
    which: Deviation,
) -> Option<f64> {
    let n = match NodeBins::of(info, layout) {
        Ok(n) => n,
        Err(e) => return e,
    };
    if layout.volume.kind.is_labels() {
        return Some(unit(n.label_error(mode, table, which)));
    }
    let dev = |b| match which {
        Deviation::Bound => n.err.deviation(b, n.min, n.max),
        Deviation::Typical => n.err.typical_deviation(b, n.min, n.max),
    };
    let e = match mode {
        RenderMode::Dvr => n
            .occupied()
            .map(|b| {
                let (lo, hi) = n.widened(b, dev(b));
                table.classified_change(lo, hi)
            })
            .fold(0.0, f64::max),
        RenderMode::Iso { value, .. } => {
            if n.iso_in_a_bin(value, dev) {
                1.0
            } else {
                0.0
            }
        }
        RenderMode::Mip => {
            let [vlo, vhi] = layout.volume.value_range;
            let span = (vhi as f64 - vlo as f64).abs().max(f64::MIN_POSITIVE);
            match which {
                Deviation::Bound => n.err.max_deviation(n.min, n.max) / span,
                Deviation::Typical => {
                    n.occupied().map(|b| n.err.share(b) * dev(b)).sum::<f64>() / span
                }
            }
        }
    };
    Some(unit(e))
}

/// The error of drawing a node instead of the finest data, as the image sees
/// it, in 0..=1, from its metadata only; `None` when the node records no
/// error bound (a version-1 store, a source without error data).
///
/// * DVR: the largest change of the opacity-weighted classified sample
///   ([`TfErrorTable::classified_change`]) over the widened bins of the
///   occupied bins: a flat transfer-function region costs 0, a sharp edge up
///   to 1;
/// * iso-surface: 1 when the isovalue lies in a widened bin (the crossing may
///   move or vanish), else 0;
/// * MIP: the largest deviation, as a fraction of the value range.
///
/// Uniform and empty nodes have no error of their own here (0); the refiner
/// decides about them as before.
pub fn node_tf_error(
    info: &NodeInfo,
    mode: RenderMode,
    table: &TfErrorTable,
    layout: &OctreeLayout,
) -> Option<f64> {
    tf_error(info, mode, table, layout, Deviation::Bound)
}

/// The *expected* error of drawing a node instead of the finest data, in
/// 0..=1, from its metadata only (`None` without error data): like
/// [`node_tf_error`], but each occupied bin is widened by its typical (RMS)
/// deviation instead of its largest. Not a bound: a guide to where
/// refinement pays most, which error-aware refinement
/// ([`LodMetric::VisibleError`], through [`node_pixel_error`] where a node's
/// visible weight is not measured) ranks nodes by.
///
/// * DVR: `max_b change(bin_b +- rms_b)` of the opacity-weighted classified
///   sample (the worst bin, not weighted by its share: a few visible voxels in
///   a node of transparent ones are what the image shows);
/// * iso-surface: 1 when a bin's RMS-widened range holds the isovalue (and
///   its deviation is not zero), else 0 (weighting by the bins' shares lost
///   up to 11 dB on the head CT's bone surface: docs/benchmarks.md);
/// * MIP: the share-weighted RMS deviation as a fraction of the value range.
pub fn node_tf_error_expected(
    info: &NodeInfo,
    mode: RenderMode,
    table: &TfErrorTable,
    layout: &OctreeLayout,
) -> Option<f64> {
    tf_error(info, mode, table, layout, Deviation::Typical)
}

/// The per-sample error [`LodMetric::VisibleError`] weighs a node's visible
/// weight by, in 0..=1; `None` when the node records no error bound.
///
/// * DVR: the change of the opacity-weighted classified sample that a sample
///   of the node typically undergoes, averaged over its coarse voxels: each
///   occupied bin contributes its share of the voxels times the change over
///   the bin widened by its typical deviation `s` times `s / (w + 2 s)` (`w`
///   the bin's width): the chance that a value of the bin moved by `s` crosses
///   a given point of the widened bin. A node with a sharp transfer-function
///   edge in a bin few of its voxels occupy then ranks below one whose every
///   voxel sits on a slope, where [`node_tf_error_expected`] (the worst bin)
///   ranks them alike. Never above [`node_tf_error_expected`].
/// * iso-surface: 1 when the isovalue lies in a bin widened by its deviation
///   *bound*, else 0 ([`node_tf_error`]'s rule). The bound covers the footprints of the node's
///   neighbours (docs/store-format.md, "Deviation"), where the hit's
///   refinement and its gradient read across the node's faces: a node next
///   to the surface changes the image though its own typical values never
///   reach the isovalue.
/// * MIP: as [`node_tf_error_expected`].
pub fn node_visible_error(
    info: &NodeInfo,
    mode: RenderMode,
    table: &TfErrorTable,
    layout: &OctreeLayout,
) -> Option<f64> {
    if !matches!(mode, RenderMode::Dvr) {
        return match mode {
            RenderMode::Iso { .. } => node_tf_error(info, mode, table, layout),
            _ => node_tf_error_expected(info, mode, table, layout),
        };
    }
    let n = match NodeBins::of(info, layout) {
        Ok(n) => n,
        Err(e) => return e,
    };
    if layout.volume.kind.is_labels() {
        return Some(unit(n.label_error(mode, table, Deviation::Typical)));
    }
    let width = (n.max - n.min).max(0.0) / ERROR_BINS as f64;
    let e: f64 = n
        .occupied()
        .map(|b| {
            let s = n.err.typical_deviation(b, n.min, n.max);
            if s <= 0.0 {
                return 0.0;
            }
            let (lo, hi) = n.widened(b, s);
            n.err.share(b) * table.classified_change(lo, hi) * s / (width + 2.0 * s)
        })
        .sum();
    Some(unit(e))
}

/// The expected error a node adds to a pixel, in 0..=1: for DVR the
/// per-sample [`node_tf_error_expected`] accumulated over the node's depth
/// along a ray, `brick * 2^(levels - 1 - level)` finest voxels (opacity is per
/// voxel length, so a change of the classified sample of `e` over `n` voxels
/// changes the composited pixel by up to about `n * e` while that is small),
/// capped at 1; for iso-surfaces and MIP, where one sample decides the pixel,
/// the per-sample error itself. What [`LodMetric::VisibleError`] ranks a node
/// by while its visible weight is not measured.
pub fn node_pixel_error(
    info: &NodeInfo,
    level: u8,
    mode: RenderMode,
    table: &TfErrorTable,
    layout: &OctreeLayout,
) -> Option<f64> {
    let e = node_tf_error_expected(info, mode, table, layout)?;
    Some(match mode {
        RenderMode::Dvr => {
            let finest = layout.levels.saturating_sub(1);
            let depth = layout.brick as f64 * 2f64.powi((finest - level.min(finest)) as i32);
            (e * depth).min(1.0)
        }
        _ => e,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// The sparse table agrees with a scan of the lookup.
        #[test]
        fn range_matches_a_scan(
            entries in proptest::collection::vec(proptest::array::uniform4(0.0f32..1.0), 2..40),
            a in 0.0f64..1.0, b in 0.0f64..1.0,
        ) {
            let tf = TransferFunction::from_entries(entries);
            let t = TfErrorTable::new(&tf);
            let r = t.range(a, b);
            let (lo, hi) = if a <= b { (a, b) } else { (b, a) };
            for i in 0..=200 {
                let v = tf.lookup(lo + (hi - lo) * i as f64 / 200.0);
                for c in 0..4 {
                    prop_assert!(v[c] >= r[c][0] - 1e-6 && v[c] <= r[c][1] + 1e-6);
                }
            }
            // Tight: the end points are attained.
            let la = tf.lookup(lo);
            for c in 0..4 {
                prop_assert!(r[c][0] <= la[c] && la[c] <= r[c][1]);
            }
        }

        /// Encoding rounds up and stays within the node's range.
        #[test]
        fn encoding_never_underestimates(d in 0.0f64..300.0, min in -100.0f64..100.0, span in 0.001f64..500.0) {
            let mut bins = [BinStats::default(); ERROR_BINS];
            bins[3] = BinStats { count: 5, dev: d, sum_sq: 5.0 * d * d * 0.25 };
            let e = NodeError::encode(&bins, min, min + span);
            prop_assert!(e.typical_deviation(3, min, min + span) >= (d * 0.5).min(span) * (1.0 - 1e-12));
            prop_assert_eq!(e.weight[3], DEV_SCALE);
            prop_assert!(e.is_occupied(3) && !e.is_occupied(2));
            prop_assert!(e.deviation(3, min, min + span) >= d.min(span) * (1.0 - 1e-12));
        }
    }

    /// A 128^3 f32 volume over 0..1 in bricks of 32 (levels 0..=2).
    fn layout() -> OctreeLayout {
        OctreeLayout::new(
            crate::VolumeDesc {
                dims: [128; 3],
                dtype: crate::DType::F32,
                spacing: [1.0; 3],
                value_range: [0.0, 1.0],
                kind: Default::default(),
            },
            32,
            2,
        )
    }

    /// A data node over `[min, max]` whose every bin is occupied, with
    /// deviation `dev` and typical deviation `rms` (fractions of its range).
    fn node(min: f64, max: f64, dev: f64, rms: f64) -> NodeInfo {
        node_with(min, max, [10; ERROR_BINS], dev, rms)
    }

    proptest! {
        /// Where the transfer function is flat over a node's values (widened
        /// by its deviations), drawing the node coarse changes nothing the
        /// image sees: its expected pixel error, and its bound, are 0 in DVR,
        /// whatever its data error.
        #[test]
        fn a_flat_tf_region_costs_nothing(
            colour in proptest::array::uniform4(0.0f32..1.0),
            min in 0.05f64..0.5, width in 0.01f64..0.3,
            dev in 0.0f64..1.0, rms in 0.0f64..1.0, level in 0u8..2,
        ) {
            let layout = layout();
            // Flat from 0.4 below the node's range to 0.4 above it (more
            // than any widening), then a jump.
            let (a, b) = (min - 0.4, min + width + 0.4);
            let mut pts = vec![(a.max(0.0) as f32, colour), (b.min(1.0) as f32, colour)];
            if a > 0.0 {
                pts.insert(0, (0.0, [1.0, 0.0, 0.0, 1.0]));
            }
            if b < 1.0 {
                pts.push((1.0, [0.0, 1.0, 0.0, 0.0]));
            }
            let table = TfErrorTable::new(&TransferFunction::from_points(&pts, 256));
            let info = node(min, min + width, dev, rms.min(dev));
            let e = node_pixel_error(&info, level, RenderMode::Dvr, &table, &layout).unwrap();
            prop_assert!(e <= 1e-6, "pixel error {e}");
            let bound = node_tf_error(&info, RenderMode::Dvr, &table, &layout).unwrap();
            prop_assert!(bound <= 1e-6, "bound {bound}");
        }
    }

    /// A label node's error is the share of its voxels whose label changes
    /// times the largest change among its labels' classified samples: zero
    /// where nothing changes or every label of its id range is hidden; the
    /// bound is the change itself.
    #[test]
    fn label_nodes_read_the_share_of_changed_labels() {
        let layout = OctreeLayout::new(
            crate::VolumeDesc {
                dims: [64; 3],
                dtype: crate::DType::U8,
                spacing: [1.0; 3],
                value_range: crate::labels::label_value_range(),
                kind: crate::VolumeKind::Labels,
            },
            16,
            1,
        );
        let mut labels = crate::LabelTable::default();
        labels.set_opacity(3, 1.0);
        labels.set_color(3, [1.0, 0.0, 0.0]);
        labels.set_opacity(4, 0.2);
        let table = TfErrorTable::new(&labels.to_transfer_function());
        let node = |min: f32, max: f32, share: f64| NodeInfo {
            kind: NodeKind::Data,
            min,
            max,
            error: Some(NodeError::from_label_share(share)),
            parent_error: None,
            channels: Default::default(),
            channel_errors: None,
        };
        let dvr = RenderMode::Dvr;
        let n = node(3.0, 4.0, 0.25);
        let c = table.classified_change(3.0 / 2047.0, 4.0 / 2047.0);
        assert!(c > 0.5, "labels 3 and 4 differ: {c}");
        let typical = node_tf_error_expected(&n, dvr, &table, &layout).unwrap();
        assert!(
            (typical - 0.25 * c).abs() < 1e-4,
            "{typical} vs {}",
            0.25 * c
        );
        assert_eq!(node_tf_error(&n, dvr, &table, &layout), Some(unit(c)));
        let visible = node_visible_error(&n, dvr, &table, &layout).unwrap();
        assert!((visible - typical).abs() < 1e-12);
        // Nothing changes: no error.
        let same = node(3.0, 4.0, 0.0);
        assert_eq!(node_tf_error(&same, dvr, &table, &layout), Some(0.0));
        // Every label of the range hidden: no error.
        let mut hidden = labels.clone();
        hidden.show_only(&[9]);
        let table = TfErrorTable::new(&hidden.to_transfer_function());
        assert_eq!(node_tf_error(&n, dvr, &table, &layout), Some(0.0));
        // The share round-trips to 1/65535.
        for s in [0.0, 1e-6, 0.3, 1.0] {
            let r = NodeError::from_label_share(s).label_share();
            assert!(r >= s && r <= s + 1.0 / 65535.0, "{s} -> {r}");
        }
    }

    /// Under one transfer function, a node whose values straddle a sharp edge
    /// outranks a node of the same level and the same data error whose values
    /// lie on a gentle linear ramp; both outrank a node in a flat region.
    #[test]
    fn a_sharp_edge_outranks_a_smooth_ramp() {
        let layout = layout();
        let tf = TransferFunction::from_points(
            &[
                (0.0, [1.0, 1.0, 1.0, 0.0]),
                (0.5, [1.0, 1.0, 1.0, 0.1]),
                (0.74, [1.0, 1.0, 1.0, 0.1]),
                (0.76, [1.0, 0.4, 0.2, 0.9]),
                (1.0, [1.0, 0.4, 0.2, 0.9]),
            ],
            256,
        );
        let table = TfErrorTable::new(&tf);
        let edge = node(0.7, 0.8, 0.1, 0.05);
        let ramp = node(0.2, 0.3, 0.1, 0.05);
        let flat = node(0.55, 0.65, 0.1, 0.05);
        for level in 0..2 {
            let e = |n: &NodeInfo| {
                node_pixel_error(n, level, RenderMode::Dvr, &table, &layout).unwrap()
            };
            let (e_edge, e_ramp, e_flat) = (e(&edge), e(&ramp), e(&flat));
            assert!(
                e_edge > 2.0 * e_ramp && e_ramp > 0.0 && e_flat == 0.0,
                "level {level}: edge {e_edge}, ramp {e_ramp}, flat {e_flat}"
            );
        }
    }

    /// A data node over `[min, max]` with bin `b` holding `count[b]` coarse
    /// voxels at deviation `dev` and typical deviation `rms` (fractions of the
    /// range).
    fn node_with(min: f64, max: f64, count: [u64; ERROR_BINS], dev: f64, rms: f64) -> NodeInfo {
        let span = max - min;
        let bins = count.map(|c| BinStats {
            count: c,
            dev: if c > 0 { dev * span } else { 0.0 },
            sum_sq: c as f64 * (rms * span).powi(2),
        });
        NodeInfo {
            kind: NodeKind::Data,
            min: min as f32,
            max: max as f32,
            error: Some(NodeError::encode(&bins, min, max)),
            parent_error: None,
            channels: Default::default(),
            channel_errors: None,
        }
    }

    proptest! {
        /// The visible order's per-sample error is a mean where the expected
        /// error is the worst bin's, so in DVR it never exceeds it; on
        /// isosurfaces it flags every node the expected error flags (its
        /// bins are widened by the bound, never less than the typical
        /// deviation); in MIP the two agree.
        #[test]
        fn the_visible_error_is_a_mean_of_the_expected(
            entries in proptest::collection::vec(proptest::array::uniform4(0.0f32..1.0), 2..24),
            count in proptest::array::uniform16(0u64..6),
            min in 0.0f64..0.9, width in 0.0f64..0.5,
            dev in 0.0f64..0.5, rms in 0.0f64..0.5, iso in 0.0f32..1.0,
        ) {
            prop_assume!(count.iter().any(|&c| c > 0));
            let layout = layout();
            let table = TfErrorTable::new(&TransferFunction::from_entries(entries));
            let info = node_with(min, (min + width).min(1.0), count, dev, rms.min(dev));
            let iso = RenderMode::Iso { value: iso, color: [1.0; 3] };
            for mode in [RenderMode::Dvr, iso, RenderMode::Mip] {
                let v = node_visible_error(&info, mode, &table, &layout).unwrap();
                let e = node_tf_error_expected(&info, mode, &table, &layout).unwrap();
                prop_assert!((0.0..=1.0).contains(&v), "{mode:?}: {v}");
                match mode {
                    RenderMode::Dvr => prop_assert!(v <= e + 1e-12, "visible {v} > expected {e}"),
                    RenderMode::Iso { .. } => prop_assert!(v >= e, "visible {v} < expected {e}"),
                    RenderMode::Mip => prop_assert_eq!(v, e),
                }
            }
        }
    }

    /// A node with a few voxels on a sharp transfer-function edge and the rest
    /// where it is flat changes a typical sample less than a node whose every
    /// voxel lies on a gentle slope: the visible order ranks it lower, where
    /// the worst bin (the expected error) ranks it higher.
    #[test]
    fn a_few_voxels_on_an_edge_weigh_less_than_all_on_a_slope() {
        let layout = layout();
        let tf = TransferFunction::from_points(
            &[
                (0.0, [1.0, 1.0, 1.0, 0.0]),
                (0.3, [1.0, 1.0, 1.0, 0.0]),
                (0.7, [1.0, 1.0, 1.0, 0.4]),
                (0.795, [1.0, 1.0, 1.0, 0.4]),
                (0.805, [1.0, 1.0, 1.0, 1.0]),
                (1.0, [1.0, 1.0, 1.0, 1.0]),
            ],
            1024,
        );
        let table = TfErrorTable::new(&tf);
        // Values 0.7..0.81: 1 voxel in 100 in the top bin, on the edge at 0.8.
        let mut few = [0u64; ERROR_BINS];
        few[0] = 99;
        few[15] = 1;
        let edge = node_with(0.7, 0.81, few, 0.02, 0.01);
        // Values 0.4..0.6, all on the slope (0.1 opacity per 0.1 of value).
        let slope = node_with(0.4, 0.6, [10; ERROR_BINS], 0.02, 0.01);
        let v = |n: &NodeInfo| node_visible_error(n, RenderMode::Dvr, &table, &layout).unwrap();
        let e = |n: &NodeInfo| node_tf_error_expected(n, RenderMode::Dvr, &table, &layout).unwrap();
        assert!(
            e(&edge) > e(&slope),
            "expected: edge {} slope {}",
            e(&edge),
            e(&slope)
        );
        assert!(
            v(&edge) < v(&slope),
            "visible: edge {} slope {}",
            v(&edge),
            v(&slope)
        );
        assert!(v(&edge) > 0.0);
    }

    /// A node whose typical values stay clear of the isovalue but whose bound
    /// (which covers its neighbours' footprints, where the hit's gradient
    /// reads) reaches it counts in the visible order, not in the expected
    /// error.
    #[test]
    fn a_node_next_to_the_surface_counts() {
        let layout = layout();
        let table = TfErrorTable::new(&TransferFunction::ramp(0.0, 1.0, 1.0));
        let near = node(0.2, 0.4, 0.5, 0.01);
        let iso = RenderMode::Iso {
            value: 0.48,
            color: [1.0; 3],
        };
        assert_eq!(
            node_tf_error_expected(&near, iso, &table, &layout),
            Some(0.0)
        );
        assert_eq!(node_visible_error(&near, iso, &table, &layout), Some(1.0));
        let far = node(0.2, 0.4, 0.1, 0.01);
        assert_eq!(node_visible_error(&far, iso, &table, &layout), Some(0.0));
    }

    #[test]
    fn bins_cover_the_range() {
        assert_eq!(bin_of(0.0, 0.0, 16.0), 0);
        assert_eq!(bin_of(15.99, 0.0, 16.0), 15);
        assert_eq!(bin_of(16.0, 0.0, 16.0), 15);
        assert_eq!(bin_of(1.0, 1.0, 1.0), 0);
        assert_eq!(bin_of(f64::NAN, 0.0, 1.0), 0);
    }
}
