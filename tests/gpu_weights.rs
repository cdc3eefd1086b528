//! GPU tests of the visible weights (docs/visibility.md): the out-of-core
//! kernel sums, per brick, the transmittance-weighted length of the rays
//! through it, and `LodMetric::VisibleError` refines by it.
//!
//! The kernel measures them only under `VisibleError` (a pipeline override);
//! the noise source has no error bounds, so its cut is the geometric one at
//! tolerance 0 all the same. Weights are checked per data leaf against sums
//! on the CPU:
//! * MIP: each ray counts its chord through the leaf that holds its maximum
//!   only, against the CPU twin `brickray_reference::visible_weights` (the
//!   test states its thresholds);
//! * DVR with a constant opacity `a` per voxel: the integral of `(1 - a)^l`
//!   over the analytic chord of every pixel's ray through the leaf's box,
//!   with `l` the distance marched from the ray's entry.
//!
//! DVR thresholds: every leaf within 3% of its exact sum, plus 1 voxel x
//! pixel; the total within 1.5%. Measured on lavapipe: largest leaf error
//! 0.17%, total 0.12%. The error sources are the fixed point (1/4 voxel of
//! the leaf's level per ray and brick), the trapezoid over each brick
//! (`(1 - a)^l` is not linear) and the step: a few tenths of a percent each.
//!
//! Refinement: on opaque shells (256^3, bricks of 32, stored with error
//! bounds), `VisibleError` with budget 0 keeps what no ray reaches coarse (it
//! weighs 0): the converged working set is below 75% of the geometric rule's
//! at tolerance 0 (measured: 283 of 408 bricks, 69%); parents split although
//! no ray reaches any of their data children are at most 2% of its bricks
//! (measured: 2, against 18 for the geometric rule, which must show at least
//! 10 for the test to mean anything); the image matches at >= 50 dB
//! (measured: 71-74 dB). The baseline was the error-aware rank without
//! weights at budget 0 until that metric was removed; it measured the same
//! 408 bricks and 18 hidden splits.

use brickray::core::LodMetric;
use brickray::{
    Camera, FrameDesc, NodeKey, OctreeLayout, OutOfCoreConfig, OutOfCoreStats, RenderMode,
    RenderSettings, TransferFunction, VolumeFrame, VolumeRenderer,
};
use brickray_harness::{
    Offscreen, draw_frame, shared_gpu as gpu, store_of, target_desc as targets,
};
use brickray_reference::psnr;
use std::collections::HashMap;
use std::sync::Arc;

const SIZE: u32 = 96;
const DIM: u64 = 128;

/// A volume of `dim^3` voxels placed where one of `DIM^3` unit voxels is.
fn world(dim: u64) -> VolumeFrame {
    VolumeFrame::centered([dim as u32; 3], [DIM as f32 / dim as f32; 3])
}

fn camera() -> Camera {
    Camera::orbit(world(DIM).center(), 1.7, 0.6, 0.35)
}

fn renderer(
    source: Arc<dyn brickray::BrickSource>,
    metric: LodMetric,
    tf: &TransferFunction,
) -> VolumeRenderer {
    let g = gpu();
    let mut r = VolumeRenderer::new(&g.device, targets()).unwrap();
    let config = OutOfCoreConfig {
        tolerance_px: 0.0,
        lod_metric: metric,
        upload_budget_bytes: 1 << 30,
        ..Default::default()
    };
    r.set_volume_source(&g.device, &g.queue, source, config)
        .unwrap();
    r.set_transfer_function(&g.device, &g.queue, tf).unwrap();
    r
}

fn frame(r: &mut VolumeRenderer, dim: u64, settings: RenderSettings) -> (Vec<u8>, OutOfCoreStats) {
    let g = gpu();
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let desc = FrameDesc {
        camera: camera(),
        frame: world(dim),
        viewport: brickray::Viewport::full(SIZE, SIZE),
        settings,
        host_depth: None,
        time: None,
    };
    draw_frame(g, r, &target, &desc, Some(wgpu::Color::BLACK)).expect("frame");
    (target.read_color(g), r.stats().out_of_core.unwrap())
}

/// Frames until converged (at most `max`), then until the usage read back is
/// of a frame drawn converged: the image and its stats.
fn converge(
    r: &mut VolumeRenderer,
    dim: u64,
    settings: RenderSettings,
    max: u64,
) -> (Vec<u8>, OutOfCoreStats) {
    // The out-of-core backend counts frames from 1, as the read-backs do.
    let mut since = None;
    for f in 1..=max {
        let (img, s) = frame(r, dim, settings);
        since = if s.converged { since.or(Some(f)) } else { None };
        if since.is_some_and(|c| r.last_usage().is_some_and(|u| u.frame >= c)) {
            return (img, s);
        }
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    panic!("not converged in {max} frames: {:?}", r.stats().out_of_core);
}

/// The exact weight of every data leaf: over the pixels' rays, the integral
/// of `trans(l)` (`l`: finest voxels from the ray's entry into the volume)
/// over the ray's chord through the leaf's box.
fn exact(
    layout: &OctreeLayout,
    keys: &[NodeKey],
    trans_integral: impl Fn(f64, f64) -> f64,
) -> HashMap<NodeKey, f64> {
    let frame = world(layout.volume.dims[0] as u64);
    let rays = camera().rays(1.0);
    let inv_model = frame.model.as_dmat4().inverse();
    let voxel = frame.voxel_world as f64;
    let scale = layout.volume_scale();
    let boxes: Vec<(NodeKey, [f64; 3], [f64; 3])> = keys
        .iter()
        .map(|&k| {
            let (o, s) = layout.unit_box(k);
            let lo = std::array::from_fn(|a| (o[a] / scale[a]).min(1.0));
            let hi = std::array::from_fn(|a| ((o[a] + s[a]) / scale[a]).min(1.0));
            (k, lo, hi)
        })
        .collect();
    let mut out: HashMap<NodeKey, f64> = keys.iter().map(|&k| (k, 0.0)).collect();
    for py in 0..SIZE {
        for px in 0..SIZE {
            let ray = rays.pixel_ray(&inv_model, px as f64, py as f64, SIZE, SIZE);
            let Some((t0, _)) = ray.clip_unit_box() else {
                continue;
            };
            for (k, lo, hi) in &boxes {
                if let Some((a, b)) = ray.clip_box(*lo, *hi) {
                    let (a, b) = ((a - t0) / voxel, (b - t0) / voxel);
                    *out.get_mut(k).unwrap() += trans_integral(a, b);
                }
            }
        }
    }
    out
}

/// Compares the last read-back weights with the exact ones: the largest
/// relative leaf error and the total's.
fn compare(
    r: &VolumeRenderer,
    layout: &OctreeLayout,
    trans_integral: impl Fn(f64, f64) -> f64,
) -> (f64, f64) {
    let u = r.last_usage().expect("usage read back");
    let keys: Vec<NodeKey> = u.counts.iter().map(|c| c.0).collect();
    assert!(keys.len() >= 8, "{} leaves", keys.len());
    let want = exact(layout, &keys, trans_integral);
    let (mut worst, mut got_sum, mut want_sum) = (0.0f64, 0.0, 0.0);
    for (&(k, _), &w) in u.counts.iter().zip(&u.weights) {
        let e = want[&k];
        got_sum += w;
        want_sum += e;
        worst = worst.max((w - e).abs() / e.max(1.0));
        assert!(
            (w - e).abs() <= 0.03 * e + 1.0,
            "leaf {k:?}: weight {w:.1}, exact {e:.1}"
        );
    }
    (worst, (got_sum - want_sum).abs() / want_sum)
}

fn noise() -> (Arc<brickray::store::ProceduralSource>, OctreeLayout) {
    let s = brickray::store::ProceduralSource::fractal_noise([DIM; 3], 32, 2).expect("noise");
    let layout = brickray::BrickSource::layout(&s).clone();
    (Arc::new(s), layout)
}

/// MIP: each ray counts its length through the leaf that holds its maximum
/// only. Compared per leaf with the CPU twin (`brickray_reference::
/// visible_weights`, f64, on the same voxels at the same step): the weights
/// may differ where a ray's two largest samples lie in different leaves and
/// within the GPU's rounding of each other, so the test bounds the sum of the
/// per-leaf differences (2% of the total; measured on lavapipe: 0.25%) and
/// the total (1%; measured 0.20%), and checks that the rule is not the
/// chords' (measured: the chord sum is 3.6x the total; asked: at least 2x).
#[test]
fn mip_weights_go_to_each_ray_s_maximum() {
    let (source, layout) = noise();
    let finest = layout.levels - 1;
    let data = source
        .region(finest, [0; 3], [DIM - 1; 3])
        .expect("noise voxels");
    let volume =
        brickray::core::Volume::new(layout.volume.clone(), brickray::core::VolumeData::U8(data))
            .expect("noise volume");
    let tf = TransferFunction::ramp(0.0, 1.0, 1.0);
    let mut r = renderer(source, LodMetric::VisibleError { budget: 0.0 }, &tf);
    let mut settings = RenderSettings {
        mode: RenderMode::Mip,
        ..RenderSettings::default()
    };
    // MIP's termination at the largest value would cut rays short; its
    // skipping of whole bricks below the running maximum stays on (such a
    // brick cannot hold the maximum).
    settings.accel.early_termination = None;
    converge(&mut r, DIM, settings, 200);
    let u = r.last_usage().expect("usage read back");
    assert!(u.counts.iter().all(|c| c.0.level == finest), "finest cut");
    let cpu = brickray_reference::visible_weights(
        &volume,
        &layout,
        &world(DIM),
        &tf,
        &camera(),
        RenderMode::Mip,
        SIZE,
    );
    let chords = exact(
        &layout,
        &u.counts.iter().map(|c| c.0).collect::<Vec<_>>(),
        |a, b| b - a,
    );
    let (mut diff, mut got, mut want, mut chord) = (0.0, 0.0, 0.0, 0.0);
    for (&(k, _), &w) in u.counts.iter().zip(&u.weights) {
        let e = cpu.get(&k).copied().unwrap_or(0.0);
        diff += (w - e).abs();
        got += w;
        want += e;
        chord += chords[&k];
    }
    eprintln!(
        "MIP: per-leaf differences {:.3}% of the total, total {:.3}%, chords {:.2}x the total",
        100.0 * diff / want,
        100.0 * (got - want).abs() / want,
        chord / want
    );
    assert!(want > 0.0);
    assert!(diff <= 0.02 * want, "per-leaf differences {diff} of {want}");
    assert!(
        (got - want).abs() <= 0.01 * want,
        "total {got} against {want}"
    );
    assert!(chord >= 2.0 * want, "chords {chord}, total {want}");
}

#[test]
fn dvr_weights_follow_the_transmittance() {
    let (source, layout) = noise();
    let a = 0.005f64;
    let tf = TransferFunction::from_points(
        &[
            (0.0, [0.5, 0.5, 0.5, a as f32]),
            (1.0, [0.5, 0.5, 0.5, a as f32]),
        ],
        256,
    );
    let mut r = renderer(source, LodMetric::VisibleError { budget: 0.0 }, &tf);
    let mut settings = RenderSettings::default();
    settings.accel.early_termination = None;
    settings.shading.enabled = false;
    converge(&mut r, DIM, settings, 200);
    // The integral of (1 - a)^l from l = x to y.
    let k = -(1.0 - a).ln();
    let (worst, total) = compare(&r, &layout, |x, y| ((-k * x).exp() - (-k * y).exp()) / k);
    eprintln!(
        "DVR: largest leaf error {:.3}%, total {:.3}%",
        worst * 100.0,
        total * 100.0
    );
    assert!(total <= 0.015, "total error {total}");
}

/// The shells (256^3, bricks of 32), stored with their error bounds in `dir`
/// (a procedural source has none, and error-aware refinement then falls back
/// to the geometric rule).
fn shells_store(dir: &tempfile::TempDir) -> Arc<dyn brickray::BrickSource> {
    let p = brickray::store::ProceduralSource::sphere_shells([2 * DIM; 3], 32, 2).unwrap();
    let layout = brickray::BrickSource::layout(&p).clone();
    let data = p
        .region(layout.levels - 1, [0; 3], [2 * DIM - 1; 3])
        .unwrap();
    let vol = brickray::Volume::new(layout.volume, brickray::core::VolumeData::U8(data)).unwrap();
    // Default options: bricks of 32 with an apron of 2, error bounds recorded.
    store_of(&vol, &dir.path().join("shells.brs"))
}

/// Semi-transparent shells under `VisibleError` at a budget where bricks are
/// traded: a brick's detail changes what the rays see of the bricks behind it,
/// so the weights and the cut form a loop. With the hysteresis of
/// `VisibleWeights::ranked_weight` the cut settles (measured: converged at
/// frame 10, 202 bricks); without it, it cycled between 159 and 174 bricks
/// for as long as it ran. Threshold: converged within 60 frames, then 30
/// frames with the same cut.
#[test]
fn visible_error_settles_when_the_cut_changes_what_rays_see() {
    let dir = tempfile::tempdir().unwrap();
    let tf = TransferFunction::from_points(
        &[
            (0.15, [0.9, 0.8, 0.7, 0.0]),
            (0.22, [0.9, 0.8, 0.7, 0.05]),
            (0.5, [0.9, 0.3, 0.2, 0.3]),
        ],
        256,
    );
    let mut r = renderer(
        shells_store(&dir),
        LodMetric::VisibleError { budget: 1020.0 },
        &tf,
    );
    let settings = RenderSettings::default();
    let mut seen = Vec::new();
    let at = (1..=60).find(|_| {
        let (_, s) = frame(&mut r, 2 * DIM, settings);
        seen.push(s.data_leaves_per_level.iter().sum::<u32>());
        s.converged
    });
    let at = at.unwrap_or_else(|| panic!("not converged in 60 frames: bricks {seen:?}"));
    let bricks = *seen.last().unwrap();
    for i in 0..30 {
        let (_, s) = frame(&mut r, 2 * DIM, settings);
        let b = s.data_leaves_per_level.iter().sum::<u32>();
        assert!(
            s.converged && b == bricks,
            "frame {}: {b} bricks after {bricks}",
            at + 1 + i
        );
    }
    eprintln!("converged at frame {at}, {bricks} bricks");
}

/// Parents in `r`'s last read-back cut split although no ray reached any of
/// their data children (each child's ray count is 0: counts are measured
/// under every metric, weights only under `VisibleError`), and the cut's data
/// leaves.
fn hidden_splits(r: &VolumeRenderer) -> (usize, usize) {
    let u = r.last_usage().expect("usage read back");
    let mut parents: HashMap<NodeKey, (u32, u32)> = HashMap::new();
    for &(k, c) in &u.counts {
        if let Some(p) = k.parent() {
            let e = parents.entry(p).or_default();
            e.0 += 1;
            e.1 += c;
        }
    }
    let hidden = parents.values().filter(|(n, c)| *n >= 2 && *c == 0).count();
    (hidden, u.counts.len())
}

#[test]
fn visible_error_keeps_what_no_ray_reaches_coarse() {
    let dir = tempfile::tempdir().unwrap();
    let shells = shells_store(&dir);
    let shells = || shells.clone();
    let tf = TransferFunction::from_points(
        &[(0.15, [0.9, 0.8, 0.7, 0.0]), (0.22, [0.9, 0.8, 0.7, 1.0])],
        256,
    );
    let settings = RenderSettings::default();
    // Tolerance 0: the geometric rule refines everything it sees to the
    // finest level, hidden or not.
    let mut all = renderer(shells(), LodMetric::Geometric, &tf);
    let (a_img, _) = converge(&mut all, 2 * DIM, settings, 300);
    let mut seen = renderer(shells(), LodMetric::VisibleError { budget: 0.0 }, &tf);
    let (s_img, _) = converge(&mut seen, 2 * DIM, settings, 300);
    let p = psnr(&a_img, &s_img);
    let ((ah, ab), (sh, sb)) = (hidden_splits(&all), hidden_splits(&seen));
    eprintln!(
        "geometric: {ab} bricks, {ah} hidden splits; visible-error: {sb} bricks ({:.0}%), {sh} hidden splits; {p:.1} dB",
        100.0 * sb as f64 / ab as f64
    );
    assert!((sb as f64) < 0.75 * ab as f64, "{sb} of {ab} bricks");
    assert!(
        ah >= 10,
        "the geometric rule split only {ah} hidden parents"
    );
    assert!(sh * 50 <= sb, "{sh} hidden splits in {sb} bricks");
    assert!(p >= 50.0, "{p} dB");
}

/// Switching to `VisibleError` at run time: the read-backs of frames drawn
/// before the switch hold no weights (their pipelines did not measure them)
/// and must not count as "no ray reaches anything", which would collapse the
/// cut for a few frames (`VisibleWeights` ignores observations of frames
/// before a leaf entered its cut, and its cut starts at the switch).
/// Threshold: no frame after the switch draws fewer than half the bricks the
/// switched view converges to (measured: 408 for 5 frames, then 283).
#[test]
fn switching_to_visible_error_never_collapses_the_cut() {
    let dir = tempfile::tempdir().unwrap();
    let tf = TransferFunction::from_points(
        &[(0.15, [0.9, 0.8, 0.7, 0.0]), (0.22, [0.9, 0.8, 0.7, 1.0])],
        256,
    );
    let settings = RenderSettings::default();
    let mut r = renderer(shells_store(&dir), LodMetric::Geometric, &tf);
    converge(&mut r, 2 * DIM, settings, 300);
    brickray_harness::configure(gpu(), &r, |c| {
        c.lod_metric = LodMetric::VisibleError { budget: 0.0 }
    })
    .unwrap();
    let mut seen = Vec::new();
    for _ in 0..40 {
        let (_, s) = frame(&mut r, 2 * DIM, settings);
        seen.push(s.data_leaves_per_level.iter().sum::<u32>());
    }
    let (_, s) = converge(&mut r, 2 * DIM, settings, 300);
    let settled = s.data_leaves_per_level.iter().sum::<u32>();
    let least = *seen.iter().min().unwrap();
    eprintln!("after the switch: {seen:?}; settled at {settled}");
    assert!(
        least * 2 >= settled,
        "{least} bricks after the switch, {settled} settled"
    );
}

/// The head CT's bone surface under `VisibleError` and a brick budget of 78
/// bricks of 16 (10% of its finest cut), at 128 px: the scene where the
/// `pareto` suite's cut never settled. A node's rays run through its empty
/// children while it is a leaf, so it weighs more as a leaf than its data
/// children do once split: it split, ranked by their small sum, collapsed to
/// give its bricks to other nodes, and split again (period 3 frames, for as
/// long as it ran: 400 frames). `VisibleWeights::may_split` stops a node that
/// collapsed `MAX_COLLAPSES` times in a view from splitting again in it.
/// Measured: settled within 16-27 frames and kept 78 bricks; with the rule
/// off (a `may_split` that always allows) not converged in 150 frames. Threshold:
/// converged within 150 frames, then 30 frames with the same cut, within the
/// budget.
#[test]
fn visible_error_settles_under_a_brick_budget_on_the_bone_surface() {
    bone_surface_settles(LodMetric::VisibleError { budget: 0.0 }, 78);
}

/// The same scene with octant-granular cuts (`LodMetric::VisibleOctants`) at
/// 156 bricks: a node given its brick whose children all got theirs lends
/// to none, and was not remembered as holding one, so losing it was not a
/// demotion and the cut alternated between two states forever (measured at
/// 128 px: none of the nine budgets of the `pareto` suite's bone surface
/// settled in 400 frames; with every ancestor of the cut's leaves counted as
/// holding its brick, all nine did). Threshold as above.
#[test]
fn octant_cuts_settle_under_a_brick_budget_on_the_bone_surface() {
    bone_surface_settles(LodMetric::VisibleOctants { budget: 0.0 }, 156);
}

fn bone_surface_settles(metric: LodMetric, budget: u32) {
    let Some(path) = brickray_harness::shared_volume("invesalius_cranium_ct") else {
        return;
    };
    let vol = brickray_io::read_volume(&path).expect("read the head CT");
    let dir = tempfile::tempdir().unwrap();
    let store = dir.path().join("ct16.brs");
    let mut reader = brickray_io::MemoryReader::new(vol.clone(), "memory");
    let options = brickray_store::BuildOptions {
        brick: 16,
        ..Default::default()
    };
    brickray_store::build(&mut reader, &store, &options).expect("build the store");
    let source: Arc<dyn brickray::BrickSource> =
        Arc::new(brickray_store::open(&store).expect("open the store"));
    let [_, _, (_, mode, tf), _] = brickray_harness::ct::scenes();
    let d = vol.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let g = gpu();
    let mut r = VolumeRenderer::new(&g.device, targets()).unwrap();
    let config = OutOfCoreConfig {
        tolerance_px: 0.0,
        lod_metric: metric,
        brick_budget: Some(budget),
        upload_budget_bytes: 1 << 30,
        ..Default::default()
    };
    r.set_volume_source(&g.device, &g.queue, source, config)
        .unwrap();
    r.set_transfer_function(&g.device, &g.queue, &tf).unwrap();
    let desc = FrameDesc {
        camera: Camera::orbit(frame.center(), 2.0, 0.5, 0.3),
        frame,
        viewport: brickray::Viewport::full(128, 128),
        settings: RenderSettings {
            mode,
            ..RenderSettings::default()
        },
        host_depth: None,
        time: None,
    };
    let target = Offscreen::new(&g.device, 128, 128);
    let mut step = || {
        draw_frame(g, &mut r, &target, &desc, Some(wgpu::Color::BLACK)).expect("frame");
        std::thread::sleep(std::time::Duration::from_millis(5));
        let s = r.stats().out_of_core.unwrap();
        (
            s.converged,
            s.data_leaves_per_level,
            s.cache.working_set_bricks,
        )
    };
    let mut seen = Vec::new();
    let at = (1..=150).find(|_| {
        let (converged, _, bricks) = step();
        seen.push(bricks);
        converged
    });
    let at = at.unwrap_or_else(|| {
        panic!(
            "not converged in 150 frames; last bricks {:?}",
            &seen[seen.len() - 12..]
        )
    });
    let (_, cut, bricks) = step();
    for i in 0..30 {
        let (converged, levels, _) = step();
        assert!(
            converged && levels == cut,
            "frame {}: cut per level {levels:?} after {cut:?}",
            at + 2 + i
        );
    }
    assert!(bricks <= budget, "{bricks} bricks");
    eprintln!("settled at frame {at}, {bricks} bricks");
}
