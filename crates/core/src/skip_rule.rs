//! When empty-space skipping pays: each rule is the least share of cells a
//! frame's rays are certain to skip (in core, of the volume's macro cells,
//! [`MacroCellGrid`]; out of core, of the sub-cells of the bricks a frame
//! draws) at which skipping is used, by sample step ([`ShareByStep`]), each
//! measured on lavapipe with `brickray-bench skipping` (docs/benchmarks.md,
//! *skipping*). Below it the tests cost more than the samples they save;
//! the image is the same either way.

use crate::macrocell::MacroCellGrid;

/// A skip rule's least share by sample step: anchors `(step, share)`, the
/// step in voxels, in increasing step, each measured on lavapipe. Between two
/// anchors the share is interpolated linearly in `log2(step)`; below the
/// first and above the last it is the end's. A share of 1 skips only where
/// every cell can be skipped.
///
/// Why it depends on the step: a rule that tests each cell it enters pays a
/// test per cell whatever the step, and saves the samples the cell would
/// have taken, fewer at a coarser step; from a step of a few voxels on, a
/// ray tests a cell at nearly every sample (`brickray-bench skipping
/// --step S`, docs/benchmarks.md, *skipping*).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShareByStep(pub &'static [(f32, f64)]);

impl ShareByStep {
    /// The least share at a sample step of `step` voxels.
    pub fn at(&self, step: f32) -> f64 {
        let a = self.0;
        let Some(&(first, first_share)) = a.first() else {
            return 0.0;
        };
        // At or below the first anchor (NaN too).
        if step.partial_cmp(&first) != Some(std::cmp::Ordering::Greater) {
            return first_share;
        }
        for w in a.windows(2) {
            let ((s0, v0), (s1, v1)) = (w[0], w[1]);
            if step <= s1 {
                let x = f64::from((step / s0).log2() / (s1 / s0).log2());
                return v0 + (v1 - v0) * x;
            }
        }
        a[a.len() - 1].1
    }

    /// Whether a rule skips at `share` and `step`.
    pub fn pays(&self, share: f64, step: f32) -> bool {
        share >= self.at(step)
    }
}

/// The least [`MacroCellGrid::mip_skip_share`] at which MIP's empty-space
/// skipping is used in core, by step. Measured on lavapipe (`brickray-bench
/// skipping --step S`, docs/benchmarks.md): at 1/2 voxel skipping cost
/// 1.31-1.72x the frame on the five volumes whose share is 0.00-0.14
/// (fractal noise, Marschner-Lobb, the head CT, the nuclei, the cryo-ET
/// tomogram), took 0.88x on the Colin27 MRI (0.34) and 1.05-1.06x on the
/// other T1 MRI (0.52); at 1 voxel it cost 1.07-1.27x on the five and took
/// 0.91x and 0.99x on the two MRIs; from 2 voxels on it cost on all seven
/// (1.12-1.31x at 2, 1.11-1.26x at 4). A test of a macro cell costs about
/// as much as ten samples there, so skipping pays only where it removes
/// most of the samples, and a coarse step leaves few to remove.
pub const MIP_SKIP_SHARE_MIN: ShareByStep = ShareByStep(&[(0.5, 0.25), (1.0, 0.3), (2.0, 1.0)]);

/// Whether MIP's empty-space skipping pays on a volume with these macro
/// cells at a sample step of `step` voxels ([`MIP_SKIP_SHARE_MIN`]).
pub fn mip_skipping_pays(grid: &MacroCellGrid, step: f32) -> bool {
    MIP_SKIP_SHARE_MIN.pays(grid.mip_skip_share(), step)
}

/// The least share of macro cells transparent through the transfer
/// function at which unshaded DVR's empty-space skipping is used in core,
/// whatever the step; shaded DVR has its own
/// ([`DVR_SHADED_SKIP_SHARE_MIN`]). Measured on lavapipe (`brickray-bench
/// skipping`, docs/benchmarks.md: ramps opaque from 0, 0.3 and 0.6 of the
/// range on seven volumes): where no cell is transparent skipping cost
/// 1.14-1.45x the frame; at shares of 0.188 and 0.231 it cost 1.02-1.22x in
/// three runs of 2026-12-07 (0.97-1.00x in the first run, 2026-12-06), and
/// from 0.357 on it broke even or paid (0.84-1.00x at 0.357, 0.20-0.90x
/// above).
/// In core DVR skips a run of empty cells with one test (skip distances),
/// so a coarser step costs it less than the rules that test every cell, and
/// the threshold stays at every step (unshaded frames at 4 voxels cost
/// 1.04-1.16x up to a share of 0.52, frames of 5-20 ms at 256 x 256, within
/// this machine's noise of each other).
pub const DVR_SKIP_SHARE_MIN: ShareByStep = ShareByStep(&[(0.5, 0.3)]);

/// [`DVR_SKIP_SHARE_MIN`] for shaded DVR, whose samples cost two to three
/// times an unshaded one's: where no cell is transparent skipping cost
/// 1.11-1.27x the frame, from a share of 0.188 on it broke even or paid
/// (0.86-0.95x at 0.188 in three runs; the tomogram at 0.231 0.95-1.12x in
/// four; 0.14-0.81x from 0.357 on). At 1, 2 and 4 voxels shaded frames paid or
/// broke even from a share of 0.19 on (but the tomogram at 0.231 and 4
/// voxels, 1.11x).
pub const DVR_SHADED_SKIP_SHARE_MIN: ShareByStep = ShareByStep(&[(0.5, 0.15)]);

/// The in-core DVR rule of a shaded or an unshaded frame.
pub fn dvr_skip_share_min(shaded: bool) -> ShareByStep {
    match shaded {
        true => DVR_SHADED_SKIP_SHARE_MIN,
        false => DVR_SKIP_SHARE_MIN,
    }
}

/// The least share of sub-cells certain to be skipped, counted within each
/// brick of an out-of-core cut ([`mip_skip_counts`](crate::macrocell::mip_skip_counts) over a brick's
/// sub-cells, the running maximum starting afresh at each brick, summed
/// over the cut's bricks), at which MIP's empty-space skipping is used out
/// of core, by step. Within a brick the count is a lower bound of the
/// volume-wide one (a ray enters each brick knowing nothing of the last),
/// but it separates the same volumes (`brickray-bench skipping`, bricks of
/// 32 at the finest level, docs/benchmarks.md): fractal noise 0.028,
/// Marschner-Lobb 0.000, the head CT 0.005, the nuclei 0.001 and the cryo-ET
/// tomogram 0.003, where out-of-core skipping cost 1.03-1.39x the frame on
/// lavapipe at 1/2 voxel (1.06-1.29x at 1 and 2, 1.10-1.22x at 4), against
/// the pycortex T1 MRI 0.391 and the Colin27 MRI 0.305, where it took
/// 0.61-0.79x at 1/2 voxel and 0.83-0.96x at 1 and 2; at 4 voxels it took
/// 0.94x and cost 1.07x there, and cost the pycortex MRI 1.12x in the `raw`
/// suite's view (`brickray-bench raw --step 4 --size 384`), 1.07x at 8.
/// Those figures are of per-sample tests. Out of core MIP now walks a data
/// leaf's sub-cells once as the ray enters it (`leaf_span` in ooc.wgsl, the
/// running maximum at the leaf's entry); measured again so (2026-12-08, one
/// run at each step) the two MRIs took 0.63-0.64x at 1/2 voxel, 0.72-0.73x
/// at 1, 0.85-0.93x at 2 and 0.90x and 1.06x at 4, while the five low
/// shares no longer sort by cost: the head CT (0.005) took 0.83-0.91x up to
/// 2 voxels and fractal noise (0.028) 0.92-0.93x up to 1 voxel but 1.37x at
/// 2, where the tomogram (0.003) cost 1.08-1.28x and Marschner-Lobb 1.13-1.20x
/// at every step. The thresholds were kept: nothing between 0.028 and 0.305
/// was measured, and no lower threshold separates those five.
pub const MIP_SKIP_SHARE_MIN_BRICKS: ShareByStep =
    ShareByStep(&[(0.5, 0.1), (2.0, 0.1), (4.0, 1.0)]);

/// The least share of sub-cells transparent through the transfer function,
/// over the bricks a frame draws, at which unshaded DVR's empty-space
/// skipping is used out of core (`SkipRule::WherePays` in brickray-render),
/// by step; shaded DVR has its own ([`DVR_SHADED_SKIP_SHARE_MIN_BRICKS`]).
/// Out of core a ray that skips walks a data leaf's sub-cells once as it
/// enters the leaf and samples from the first that can contribute to the
/// last (`leaf_span` in ooc.wgsl), so skipping costs a walk per leaf rather
/// than a test per sub-cell. Measured on lavapipe (`brickray-bench skipping
/// --step S`, 2026-12-08, one run at each of 1/2, 1, 2 and 4 voxels:
/// ramps opaque from 0, 0.3 and 0.6 on seven volumes, bricks of 32 at the
/// finest level): where no sub-cell is transparent skipping cost up to
/// 1.12x the frame at 1/2 voxel (0.85-1.12x), 1.15x at 1, 1.32x at 2 and
/// 1.34x at 4; at 1/2 voxel it paid at every share measured above 0, from
/// 0.188 (0.73-0.97x, 0.38-0.58x from 0.644); at 1 voxel from 0.188 as well
/// but 1.07x at 0.278 and 1.03x at 0.467; at 2 voxels it cost or broke even
/// up to 0.467 (0.92-1.20x) and paid from 0.498 (0.69-0.93x); at 4 voxels
/// it cost up to 0.498 (1.01-1.20x, but 0.78x at 0.388) and paid from 0.644
/// (0.74-0.98x). No step beyond 4 voxels was measured (the last anchor's
/// share holds there). Before the walk (per-sample tests in the sample
/// loop, which cost 1.5x where no test was taken) the anchors were 0.55,
/// 0.76 and 1 at 1, 2 and 4 voxels.
pub const DVR_SKIP_SHARE_MIN_BRICKS: ShareByStep =
    ShareByStep(&[(1.0, 0.15), (2.0, 0.5), (4.0, 0.6)]);

/// [`DVR_SKIP_SHARE_MIN_BRICKS`] for shaded DVR, whose samples cost two to
/// three times an unshaded one's, so that skipping pays from fewer
/// transparent sub-cells. Measured as the unshaded rule (2026-12-08, the
/// streamed volume's default gradients kept per brick): where no sub-cell
/// is transparent skipping cost up to 1.08x the frame at 1/2 voxel, 1.13x
/// at 1, 1.19x at 2 and 1.27x at 4; at 1/2, 1 and 2 voxels it paid or
/// broke even at every share measured above 0, from 0.188 (0.62-0.92x at
/// 1/2 voxel; 1.00x at 0.278 and 1.04x at 0.467 at 2 voxels); at 4 voxels
/// it cost 1.10x at 0.188, broke even at 0.253 and 0.467 (1.00-1.01x) and
/// paid at the other shares from 0.278 on (0.65-0.97x). Before the walk
/// the anchors were 0.29, 0.55, 0.76 and 1 at 1/2, 1, 2 and 4 voxels.
pub const DVR_SHADED_SKIP_SHARE_MIN_BRICKS: ShareByStep = ShareByStep(&[(2.0, 0.15), (4.0, 0.25)]);

/// The out-of-core DVR rule of a shaded or an unshaded frame.
pub fn dvr_skip_share_min_bricks(shaded: bool) -> ShareByStep {
    match shaded {
        true => DVR_SHADED_SKIP_SHARE_MIN_BRICKS,
        false => DVR_SKIP_SHARE_MIN_BRICKS,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A rule's threshold is its anchors' at their steps, the ends' beyond
    /// them, and in between linear in log2(step): halfway from 1 to 4
    /// voxels is 2.
    #[test]
    fn a_threshold_follows_its_anchors() {
        let t = ShareByStep(&[(1.0, 0.2), (4.0, 0.8)]);
        assert_eq!(t.at(1.0), 0.2);
        assert_eq!(t.at(4.0), 0.8);
        assert_eq!(t.at(0.25), 0.2);
        assert_eq!(t.at(16.0), 0.8);
        assert!((t.at(2.0) - 0.5).abs() < 1e-9);
        assert!(t.pays(0.5, 1.5) && !t.pays(0.5, 3.0));
        assert_eq!(ShareByStep(&[]).at(1.0), 0.0);
        assert_eq!(ShareByStep(&[(0.5, 0.3)]).at(8.0), 0.3);
        // NaN takes the first anchor's.
        assert_eq!(t.at(f32::NAN), 0.2);
    }

    /// The shipped rules: anchors in increasing step with shares in 0..=1,
    /// each threshold never falling as the step grows (a coarser step saves
    /// fewer samples per cell tested), and the MIP rules (in core a test as
    /// the ray enters each cell) skipping nothing but all-empty volumes at
    /// the coarsest step measured.
    #[test]
    fn the_shipped_rules_rise_with_the_step() {
        for rule in [
            MIP_SKIP_SHARE_MIN,
            DVR_SKIP_SHARE_MIN,
            DVR_SHADED_SKIP_SHARE_MIN,
            MIP_SKIP_SHARE_MIN_BRICKS,
            DVR_SKIP_SHARE_MIN_BRICKS,
            DVR_SHADED_SKIP_SHARE_MIN_BRICKS,
        ] {
            assert!(rule.0.windows(2).all(|w| w[0].0 < w[1].0), "{rule:?}");
            assert!(
                rule.0.iter().all(|a| (0.0..=1.0).contains(&a.1)),
                "{rule:?}"
            );
            let mut last = 0.0;
            for i in 0..=64 {
                let v = rule.at(1.0 / 64.0 * 2f32.powf(i as f32 * 10.0 / 64.0));
                assert!(v >= last, "{rule:?}");
                last = v;
            }
        }
        for rule in [MIP_SKIP_SHARE_MIN, MIP_SKIP_SHARE_MIN_BRICKS] {
            assert_eq!(rule.at(16.0), 1.0, "{rule:?}");
        }
    }
}
