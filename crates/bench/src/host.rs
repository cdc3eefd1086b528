//! The `host` suite: what the render thread pays per frame out of core.
//!
//! A procedural 4096^3 volume of concentric shells (bricks of 16) is drawn at
//! a large viewport with a brick budget that sets the cut's size (about 1k, 5k,
//! 20k and 50k bricks). After the start view converged, the camera turns a
//! little every frame along a path; each frame's `prepare` is timed on the
//! render thread (wall time: it never waits for I/O or the GPU), with its
//! parts as the renderer reports them: planning (`refine_ms`: the streamer's
//! frame), writing uploads and tables (`upload_ms`) and encoding the index
//! (`encode_ms`), and planning's own phases as the brick manager times them
//! (`brickray_cache::PhaseTimes`). The path's frames are planned, not ray cast (their GPU work
//! is recorded and dropped): the host's cost does not depend on the ray cast,
//! and lavapipe takes seconds for one 1024^2 frame of a large cut. Each cut
//! runs twice, planned in `prepare` (inline) and in the background
//! (`VolumeOptions::background_planning`: a worker plans while the frame
//! renders; `prepare` applies the latest plan), the two paths interleaved;
//! the background path runs at 60 Hz (a host's frames), so that the worker's
//! plans arrive within it (each row counts the plans its path applied and
//! those that evolved the last cut).
//! The JSON keys without a suffix (`host_ms_median_20k`, `host_ms_p99_20k`,
//! `plan_ms_median_20k`) are the background path's: what the render thread
//! pays when planning runs off it, and the planning it no longer pays;
//! `_inline` keys are the same frames planned in `prepare`.
//! With `--culling`, the path is also drawn, ray cast at `--culling-size`,
//! under ray-guided visibility (its feedback needs the frames rendered).
//! Before the path the converged start view is held still for
//! `STATIC_FRAMES` frames (`prepare`'s time and the frames that applied a
//! new plan), and, for the inline rows, a GPU-free `Streamer` over the same
//! volume is held still as long (its `plan` time and whether it reused the
//! converged refinement), then plans every frame of the path (its `plan`
//! time and the share of its cut that changed from frame to frame),
//! evolving its cut from frame to frame (`OutOfCoreConfig::evolve`), beside
//! a second streamer that refines each frame from the root (their times,
//! and how far apart their cuts are).
//!
//! `cargo run --release -p brickray-bench -- host [--size 1024] [--frames 60]
//! [--cuts 1000,5000,20000,50000] [--culling] [--culling-size 256]`

use crate::runner::{Runner, median, quantile, round2};
use brickray_core::{Camera, RenderSettings, VolumeFrame};
use brickray_harness::GpuContext;
use brickray_render::{OutOfCoreConfig, VisibilityPolicy, VolumeRenderer};
use serde::Serialize;
use std::sync::Arc;
use std::time::Instant;

/// Voxels per side of the volume.
const DIMS: u64 = 4096;
/// Interior voxels per brick side.
const BRICK: u32 = 16;

/// What one path measured.
struct PathTimes {
    host_ms: Vec<f64>,
    plan_ms: Vec<f64>,
    upload_ms: Vec<f64>,
    encode_ms: Vec<f64>,
    /// The planning's phases ([`brickray_cache::PhaseTimes`]) of each frame.
    phases: Vec<brickray_cache::PhaseTimes>,
    working_set: u32,
    converge_frames: usize,
    /// The converged start view held still before the path: `prepare`'s
    /// wall time per frame, and the frames that applied a new plan.
    static_host_ms: Vec<f64>,
    static_plans: usize,
    /// The plans the path's frames applied, and how many of them evolved
    /// the last cut (`FrameStats::refine_evolved`).
    path_plans: usize,
    path_plans_evolved: usize,
}

/// A frame at 60 Hz: the background path's pace.
const FRAME_60HZ: std::time::Duration = std::time::Duration::from_micros(16_667);

/// Frames the converged start view is held still before the path.
const STATIC_FRAMES: usize = 20;

/// The median of each of planning's phases, ms.
#[derive(Debug, Serialize)]
pub(crate) struct PhaseMedians {
    poll: f64,
    refine: f64,
    display: f64,
    place: f64,
    request: f64,
    stats: f64,
}

impl PhaseMedians {
    fn of(phases: &[brickray_cache::PhaseTimes]) -> PhaseMedians {
        // (Not rounded: a phase of a small cut takes microseconds.)
        let m = |f: fn(&brickray_cache::PhaseTimes) -> f64| {
            median(&phases.iter().map(f).collect::<Vec<f64>>())
        };
        PhaseMedians {
            poll: m(|p| p.poll_ms),
            refine: m(|p| p.refine_ms),
            display: m(|p| p.display_ms),
            place: m(|p| p.place_ms),
            request: m(|p| p.request_ms),
            stats: m(|p| p.stats_ms),
        }
    }
}

fn config(cut: u32, policy: VisibilityPolicy) -> OutOfCoreConfig {
    // A stored brick of 20^3 u8 texels is at most 16 KB (R16) plus its
    // sub-cells and row: room for the cut, its fades and the floor.
    // The CPU cache holds the bricks refinement asks for beyond the budget
    // (children of nodes it would split next) without evicting the cut's.
    let slot = 20u64.pow(3) * 2 + 1024;
    let slots = cut as u64 * 13 / 10 + 256;
    OutOfCoreConfig {
        tolerance_px: 0.0,
        brick_budget: Some(cut),
        gpu_budget_bytes: slots * slot,
        cpu_budget_bytes: 4 * slots * slot,
        upload_budget_bytes: 64 << 20,
        visibility: policy,
        ..Default::default()
    }
}

fn renderer(
    gpu: &GpuContext,
    cut: u32,
    policy: VisibilityPolicy,
    background: bool,
) -> Result<(VolumeRenderer, VolumeFrame), String> {
    let src = brickray_store::ProceduralSource::sphere_shells([DIMS; 3], BRICK, 2)
        .map_err(|e| e.to_string())?;
    let frame = VolumeFrame::centered([DIMS as u32; 3], [1.0; 3]);
    let options = brickray_render::RendererOptions {
        background_planning: background,
        ..Default::default()
    };
    let mut r = VolumeRenderer::with_options(&gpu.device, brickray_harness::target_desc(), options)
        .map_err(|e| e.to_string())?;
    r.set_volume_source(&gpu.device, &gpu.queue, Arc::new(src), config(cut, policy))
        .map_err(|e| e.to_string())?;
    let tf = brickray_core::TransferFunction::ramp(0.3, 0.9, 0.3);
    r.set_transfer_function(&gpu.device, &gpu.queue, &tf)
        .map_err(|e| e.to_string())?;
    Ok((r, frame))
}

fn camera(frame: &VolumeFrame, i: usize) -> Camera {
    Camera::orbit(frame.center(), 1.4, 0.5 + 0.004 * i as f32, 0.3)
}

/// Converges the start view, then times `frames` frames of the path.
fn path(
    run: &Runner<'_>,
    r: &mut VolumeRenderer,
    frame: VolumeFrame,
    frames: usize,
    draw: bool,
    background: bool,
) -> Result<PathTimes, String> {
    let settings = RenderSettings::default();
    let mut converge_frames = 0;
    for i in 1..=600 {
        if draw {
            run.frame(r, camera(&frame, 0), frame, settings, false)?;
        } else {
            run.plan(r, camera(&frame, 0), frame, settings)?;
        }
        converge_frames = i;
        if r.stats().out_of_core.is_some_and(|s| s.converged) && !r.wants_redraw() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    let mut t = PathTimes {
        host_ms: Vec::new(),
        plan_ms: Vec::new(),
        upload_ms: Vec::new(),
        encode_ms: Vec::new(),
        phases: Vec::new(),
        working_set: 0,
        converge_frames,
        static_host_ms: Vec::new(),
        static_plans: 0,
        path_plans: 0,
        path_plans_evolved: 0,
    };
    let mut planned = r.stats().out_of_core.map(|s| s.cache.frame);
    for _ in 0..STATIC_FRAMES {
        // (A pause, so that a background worker could plan between frames.)
        std::thread::sleep(std::time::Duration::from_millis(30));
        let (host_ms, s) = timed_frame(run, r, frame, camera(&frame, 0), draw)?;
        t.static_host_ms.push(host_ms);
        t.static_plans += usize::from(planned != Some(s.cache.frame));
        planned = Some(s.cache.frame);
    }
    for i in 1..=frames {
        let start = Instant::now();
        let (host_ms, s) = timed_frame(run, r, frame, camera(&frame, i), draw)?;
        // In the background the path runs at 60 Hz, as a host's frames
        // would: unpaced, its undrawn frames passed before the worker
        // delivered a plan, and the row's planning time was the last plan
        // before the path (until 2026-12-07).
        if background {
            std::thread::sleep(FRAME_60HZ.saturating_sub(start.elapsed()));
        }
        t.host_ms.push(host_ms);
        t.plan_ms.push(s.refine_ms);
        t.upload_ms.push(s.upload_ms);
        t.encode_ms.push(s.encode_ms);
        t.phases.push(s.cache.phases);
        t.working_set = s.cache.working_set_bricks;
        if planned != Some(s.cache.frame) {
            t.path_plans += 1;
            t.path_plans_evolved += usize::from(s.cache.refine_evolved);
            planned = Some(s.cache.frame);
        }
    }
    Ok(t)
}

/// One frame of `cam`: `prepare`'s wall time on the render thread, ms, and
/// the frame's out-of-core statistics. Drawn when `draw`; otherwise the
/// recorded ray cast is dropped and the queued writes flushed.
fn timed_frame(
    run: &Runner<'_>,
    r: &mut VolumeRenderer,
    frame: VolumeFrame,
    cam: Camera,
    draw: bool,
) -> Result<(f64, brickray_render::OutOfCoreStats), String> {
    let g = run.gpu;
    let mut enc = g.device.create_command_encoder(&Default::default());
    let desc = brickray_render::FrameDesc {
        settings: RenderSettings::default(),
        time: Some(brickray_harness::host_time()),
        ..brickray_render::FrameDesc::new(cam, frame, run.size, run.size)
    };
    let t0 = Instant::now();
    r.prepare(&g.device, &g.queue, &mut enc, &desc)
        .map_err(|e| e.to_string())?;
    let host_ms = t0.elapsed().as_secs_f64() * 1e3;
    if draw {
        let mut pass = run.target.pass(&mut enc, true);
        r.render(&mut pass).map_err(|e| e.to_string())?;
        drop(pass);
        g.submit_wait(enc);
    } else {
        drop(enc);
        g.submit_wait(g.device.create_command_encoder(&Default::default()));
    }
    let s = r.stats().out_of_core.ok_or("not out of core")?;
    Ok((host_ms, s))
}

/// A GPU-free streamer's frames of a converged view held still, then along
/// the path.
struct StreamerAlone {
    plan_ms: f64,
    refine_ms: f64,
    reused_share: f64,
    /// Along the path: `plan`'s wall time and its refine phase, ms medians
    /// (and the refine phase's 99th percentile), and the median share of the
    /// cut that changed from the frame before (leaves added plus leaves
    /// gone, over the cut's leaves).
    path_plan_ms: f64,
    path_refine_ms: f64,
    path_refine_ms_p99: f64,
    path_cut_change: f64,
    /// The share of the path's frames whose cut was evolved.
    path_evolved_share: f64,
    /// The streamer that refines from the root on the same frames.
    path_exact_plan_ms: f64,
    path_exact_refine_ms: f64,
    path_exact_refine_ms_p99: f64,
    /// The evolved cut against the one refined from the root on the same
    /// frame: leaves in one and not the other, over the latter's leaves.
    path_differs_from_exact_median: f64,
    path_differs_from_exact_max: f64,
}

/// Converges two `Streamer`s (no renderer) over the suite's volume at the
/// start view of a `cut`-brick budget and a `size` viewport, one evolving a
/// moving view's cut (`OutOfCoreConfig::evolve`, the default) and one
/// refining every frame from the root; calls the evolving one's `plan`
/// [`STATIC_FRAMES`] times with the same frame, then both once per frame of
/// the path, in alternating order.
fn streamer_alone(cut: u32, size: u32, frames: usize) -> Result<StreamerAlone, String> {
    let make = |evolve: bool| {
        let src = brickray_store::ProceduralSource::sphere_shells([DIMS; 3], BRICK, 2)
            .map_err(|e| e.to_string())?;
        let config = OutOfCoreConfig {
            evolve,
            ..config(cut, VisibilityPolicy::None)
        };
        crate::runner::gpu_free_streamer(Arc::new(src), config, false)
    };
    let (mut s, mut exact) = (make(true)?, make(false)?);
    let frame = VolumeFrame::centered([DIMS as u32; 3], [1.0; 3]);
    let tf = brickray_core::TransferFunction::ramp(0.3, 0.9, 0.3);
    let plan_at = |s: &mut brickray_cache::Streamer, i: usize| {
        let view = brickray_core::FrameView::new(camera(&frame, i), frame, [size, size]);
        let t0 = Instant::now();
        let p = s.plan(&brickray_cache::StreamFrame {
            views: std::slice::from_ref(&view),
            classification: brickray_cache::Classification {
                mode: brickray_core::RenderMode::Dvr,
                tf: &tf,
                channels: &[],
                tf_generation: 0,
            },
            feedback: &[],
            time: None,
        });
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        let leaves: brickray_core::NodeSet = p.cut.iter().map(|l| l.key).collect();
        (ms, p.stats, leaves)
    };
    for s in [&mut s, &mut exact] {
        let converged = (0..2000).any(|_| {
            let done = plan_at(s, 0).1.converged;
            if !done {
                std::thread::sleep(std::time::Duration::from_millis(5));
            }
            done
        });
        if !converged {
            return Err(format!("a streamer of {cut} bricks did not converge"));
        }
    }
    let (mut plan_ms, mut refine_ms, mut reused) = (Vec::new(), Vec::new(), 0);
    let mut before = Default::default();
    for _ in 0..STATIC_FRAMES {
        let (ms, st, leaves) = plan_at(&mut s, 0);
        plan_ms.push(ms);
        refine_ms.push(st.cache.phases.refine_ms);
        reused += usize::from(st.cache.refine_reused);
        before = leaves;
    }
    let mut path = PathSide::default();
    let mut exact_path = PathSide::default();
    let (mut evolved, mut differ) = (0, Vec::new());
    for i in 1..=frames {
        let (a, b) = match i % 2 {
            0 => (plan_at(&mut s, i), plan_at(&mut exact, i)),
            _ => {
                let b = plan_at(&mut exact, i);
                (plan_at(&mut s, i), b)
            }
        };
        evolved += usize::from(a.1.cache.refine_evolved);
        differ.push(cut_change(&b.2, &a.2));
        path.push(&a);
        exact_path.push(&b);
        path.change.push(cut_change(&before, &a.2));
        before = a.2;
    }
    Ok(StreamerAlone {
        plan_ms: median(&plan_ms),
        refine_ms: median(&refine_ms),
        reused_share: reused as f64 / STATIC_FRAMES as f64,
        path_plan_ms: median(&path.plan_ms),
        path_refine_ms: median(&path.refine_ms),
        path_refine_ms_p99: quantile(&path.refine_ms, 0.99),
        path_cut_change: median(&path.change),
        path_evolved_share: evolved as f64 / frames.max(1) as f64,
        path_exact_plan_ms: median(&exact_path.plan_ms),
        path_exact_refine_ms: median(&exact_path.refine_ms),
        path_exact_refine_ms_p99: quantile(&exact_path.refine_ms, 0.99),
        path_differs_from_exact_median: median(&differ),
        path_differs_from_exact_max: differ.iter().copied().fold(0.0, f64::max),
    })
}

/// One streamer's frames along the path.
#[derive(Default)]
struct PathSide {
    plan_ms: Vec<f64>,
    refine_ms: Vec<f64>,
    change: Vec<f64>,
}

impl PathSide {
    fn push(&mut self, frame: &(f64, brickray_cache::StreamStats, brickray_core::NodeSet)) {
        self.plan_ms.push(frame.0);
        self.refine_ms.push(frame.1.cache.phases.refine_ms);
    }
}

/// The share of a cut that changed from the cut `before`: leaves added plus
/// leaves gone, over the new cut's leaves (an empty new cut: their count).
fn cut_change(before: &brickray_core::NodeSet, after: &brickray_core::NodeSet) -> f64 {
    let added = after.iter().filter(|k| !before.contains(*k)).count();
    let gone = before.iter().filter(|k| !after.contains(*k)).count();
    match after.len() {
        0 => (added + gone) as f64,
        n => (added + gone) as f64 / n as f64,
    }
}

/// A brick budget: at least 1.
fn cut_size(s: &str) -> Result<u32, String> {
    crate::at_least_one::<u32>(s.trim())
}

/// The suite's options.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Viewport side in pixels.
    #[arg(long, default_value_t = 1024, value_parser = crate::image_side)]
    size: u32,
    /// Path frames timed per cut.
    #[arg(long, default_value_t = 60, value_parser = crate::at_least_one::<usize>)]
    frames: usize,
    /// Brick budgets setting the cut sizes, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "1000,5000,20000,50000", value_parser = cut_size)]
    cuts: Vec<u32>,
    /// Also draw the path under ray-guided visibility.
    #[arg(long)]
    culling: bool,
    /// Viewport side of the drawn (culling) path.
    #[arg(long, default_value_t = 256, value_parser = crate::image_side)]
    culling_size: u32,
}

/// One cut size, planned inline or in the background, culled or not.
#[derive(Debug, Serialize)]
pub(crate) struct Row {
    /// The brick budget that sets the cut's size.
    budget: u32,
    /// Planned on a worker (the viewer's way) or inline in `prepare`.
    background: bool,
    /// Drawn under ray-guided culling at `culling_size`.
    culled: bool,
    /// `prepare`'s wall time on the render thread, ms: median and p99.
    host_ms_median: f64,
    host_ms_p99: f64,
    /// Planning (wherever it ran), uploads and index encoding, ms medians.
    plan_ms_median: f64,
    plan_ms_p99: f64,
    upload_ms_median: f64,
    encode_ms_median: f64,
    /// The brick manager's phases within planning, ms medians (in the
    /// background: of the plans the path's frames applied).
    phase_ms_median: PhaseMedians,
    /// The plans the path's frames applied (each frame's inline; in the
    /// background, those the worker finished in time), and how many of
    /// them evolved the last cut.
    path_plans: usize,
    path_plans_evolved: usize,
    /// Bricks in the working set at the end, and frames to converge.
    working_set: u64,
    converge_frames: usize,
    /// The converged start view held still (`STATIC_FRAMES` frames before
    /// the path): `prepare`'s wall time, ms median, and the frames that
    /// applied a new plan.
    static_host_ms_median: f64,
    static_plans: usize,
    /// The same held still through a GPU-free `Streamer` alone, its
    /// `plan` called every frame (as a host with its own GPU side would):
    /// `plan`'s wall time and its refine phase, ms medians, and the share
    /// of frames that reused the converged refinement
    /// (`FrameStats::refine_reused`). Inline rows only (null in the others).
    streamer_static_plan_ms_median: Option<f64>,
    streamer_static_refine_ms_median: Option<f64>,
    streamer_static_reused_share: Option<f64>,
    /// The same streamer then planning every frame of the path, evolving
    /// its cut (`OutOfCoreConfig::evolve`): `plan`'s wall time and its
    /// refine phase, ms medians (and the refine phase's 99th percentile),
    /// the median share of the cut's leaves that changed from one frame to
    /// the next (added plus gone, over the cut), and the share of frames
    /// evolved. Inline rows only.
    streamer_path_plan_ms_median: Option<f64>,
    streamer_path_refine_ms_median: Option<f64>,
    streamer_path_cut_change_median: Option<f64>,
    streamer_path_refine_ms_p99: Option<f64>,
    streamer_path_evolved_share: Option<f64>,
    /// A second streamer refining every frame of the path from the root
    /// (`evolve: false`), planned on the same frames in alternating order:
    /// its `plan` and refine times, and how far the evolved cut is from its
    /// cut (leaves in one and not the other over its leaves: median and
    /// largest over the path). Inline rows only.
    streamer_path_exact_plan_ms_median: Option<f64>,
    streamer_path_exact_refine_ms_median: Option<f64>,
    streamer_path_exact_refine_ms_p99: Option<f64>,
    streamer_path_differs_from_exact_median: Option<f64>,
    streamer_path_differs_from_exact_max: Option<f64>,
}

/// The suite's JSON line.
#[derive(Debug, Serialize)]
pub(crate) struct HostResult {
    size: u32,
    frames: usize,
    adapter: String,
    rows: Vec<Row>,
    /// The unculled background row at a budget of 20,000 (null when not run).
    host_ms_median_20k: Option<f64>,
    host_ms_p99_20k: Option<f64>,
    plan_ms_median_20k: Option<f64>,
}

pub(crate) fn run(args: &Args) -> Result<HostResult, String> {
    let (size, frames, culling, culling_size) =
        (args.size, args.frames, args.culling, args.culling_size);
    let cuts = &args.cuts;
    let gpu = GpuContext::new().map_err(|e| e.to_string())?;
    println!("adapter: {}", gpu.describe());
    println!(
        "host: {DIMS}^3 shells, bricks of {BRICK}, {size}x{size}, {frames} path frames per cut \
         (planned, not ray cast); prepare's wall time on the render thread"
    );
    println!(
        "  {:>7} {:>8} {:>9} {:>8} {:>8} {:>8} {:>9} {:>7}",
        "budget", "bricks", "host med", "host p99", "plan med", "plan p99", "upload med", "index"
    );
    let mut rows = Vec::new();
    let mut variants = vec![(VisibilityPolicy::None, size, false)];
    if culling {
        variants.push((VisibilityPolicy::RayGuided, culling_size, true));
    }
    for (policy, px, draw) in variants {
        let run = Runner::new(&gpu, px)?;
        for &cut in cuts {
            for background in [false, true] {
                let (mut r, frame) = renderer(&gpu, cut, policy, background)?;
                let t = path(&run, &mut r, frame, frames, draw, background)?;
                println!(
                    "  {:>7} {:>8} {:>9.2} {:>8.2} {:>8.2} {:>8.2} {:>9.2} {:>7.2}{}",
                    cut,
                    t.working_set,
                    median(&t.host_ms),
                    quantile(&t.host_ms, 0.99),
                    median(&t.plan_ms),
                    quantile(&t.plan_ms, 0.99),
                    median(&t.upload_ms),
                    median(&t.encode_ms),
                    match (draw, background) {
                        (true, _) => format!(" ({} px, ray-guided, drawn)", px),
                        (false, true) => " (background)".to_string(),
                        (false, false) => " (inline)".to_string(),
                    }
                );
                let p = PhaseMedians::of(&t.phases);
                println!(
                    "           planning's phases, median ms: refine {:.2}, place {:.2}, \
                     request {:.2}, display {:.2}, poll {:.2}, stats {:.2}",
                    p.refine, p.place, p.request, p.display, p.poll, p.stats
                );
                println!(
                    "           held still: prepare {:.3} ms (median), {} of {STATIC_FRAMES} frames planned; \
                     the path applied {} plans, {} of them evolved",
                    median(&t.static_host_ms),
                    t.static_plans,
                    t.path_plans,
                    t.path_plans_evolved
                );
                let alone = match (background, draw) {
                    (false, false) => Some(streamer_alone(cut, size, frames)?),
                    _ => None,
                };
                if let Some(a) = &alone {
                    println!(
                        "           a GPU-free streamer held still: plan {:.3} ms, refine {:.3} ms (medians), \
                         refinement reused in {:.0}% of {STATIC_FRAMES} frames",
                        a.plan_ms,
                        a.refine_ms,
                        100.0 * a.reused_share
                    );
                    println!(
                        "           the same streamer along the path: plan {:.3} ms, refine {:.3} ms (medians; \
                         refine p99 {:.3}), {:.2}% of the cut's leaves changed per frame (median), \
                         {:.0}% of frames evolved",
                        a.path_plan_ms,
                        a.path_refine_ms,
                        a.path_refine_ms_p99,
                        100.0 * a.path_cut_change,
                        100.0 * a.path_evolved_share
                    );
                    println!(
                        "           one refining from the root on the same frames: plan {:.3} ms, refine {:.3} ms \
                         (medians; refine p99 {:.3}); the evolved cut differs from it by {:.2}% of its leaves \
                         (median; {:.2}% at most)",
                        a.path_exact_plan_ms,
                        a.path_exact_refine_ms,
                        a.path_exact_refine_ms_p99,
                        100.0 * a.path_differs_from_exact_median,
                        100.0 * a.path_differs_from_exact_max
                    );
                }
                // (The GPU-free streamers' figures: inline unculled rows only.)
                let of = |f: fn(&StreamerAlone) -> f64| alone.as_ref().map(f);
                rows.push(Row {
                    budget: cut,
                    background,
                    culled: draw,
                    host_ms_median: round2(median(&t.host_ms)),
                    host_ms_p99: round2(quantile(&t.host_ms, 0.99)),
                    plan_ms_median: round2(median(&t.plan_ms)),
                    plan_ms_p99: round2(quantile(&t.plan_ms, 0.99)),
                    upload_ms_median: round2(median(&t.upload_ms)),
                    encode_ms_median: round2(median(&t.encode_ms)),
                    phase_ms_median: p,
                    path_plans: t.path_plans,
                    path_plans_evolved: t.path_plans_evolved,
                    working_set: t.working_set as u64,
                    converge_frames: t.converge_frames,
                    static_host_ms_median: median(&t.static_host_ms),
                    static_plans: t.static_plans,
                    streamer_static_plan_ms_median: of(|a| a.plan_ms),
                    streamer_static_refine_ms_median: of(|a| a.refine_ms),
                    streamer_static_reused_share: of(|a| a.reused_share),
                    streamer_path_plan_ms_median: of(|a| a.path_plan_ms),
                    streamer_path_refine_ms_median: of(|a| a.path_refine_ms),
                    streamer_path_cut_change_median: of(|a| a.path_cut_change),
                    streamer_path_refine_ms_p99: of(|a| a.path_refine_ms_p99),
                    streamer_path_evolved_share: of(|a| a.path_evolved_share),
                    streamer_path_exact_plan_ms_median: of(|a| a.path_exact_plan_ms),
                    streamer_path_exact_refine_ms_median: of(|a| a.path_exact_refine_ms),
                    streamer_path_exact_refine_ms_p99: of(|a| a.path_exact_refine_ms_p99),
                    streamer_path_differs_from_exact_median: of(|a| {
                        a.path_differs_from_exact_median
                    }),
                    streamer_path_differs_from_exact_max: of(|a| a.path_differs_from_exact_max),
                });
            }
        }
    }
    let at_20k = rows
        .iter()
        .find(|r| r.budget == 20_000 && r.background && !r.culled);
    Ok(HostResult {
        size,
        frames,
        adapter: gpu.describe(),
        host_ms_median_20k: at_20k.map(|r| r.host_ms_median),
        host_ms_p99_20k: at_20k.map(|r| r.host_ms_p99),
        plan_ms_median_20k: at_20k.map(|r| r.plan_ms_median),
        rows,
    })
}

#[cfg(test)]
mod tests {
    use super::cut_change;
    use brickray_core::{NodeKey, NodeSet};

    fn set(keys: &[(u8, u32)]) -> NodeSet {
        keys.iter()
            .map(|&(l, x)| NodeKey::new(l, x, 0, 0))
            .collect()
    }

    #[test]
    fn the_cut_change_counts_leaves_added_and_gone() {
        let a = set(&[(1, 0), (1, 1), (2, 4), (2, 5)]);
        assert_eq!(cut_change(&a, &a), 0.0);
        // A leaf replaced by two: one gone, two added, over the new five.
        let b = set(&[(1, 0), (1, 1), (2, 4), (3, 10), (3, 11)]);
        assert_eq!(cut_change(&a, &b), 3.0 / 5.0);
        assert_eq!(cut_change(&NodeSet::default(), &NodeSet::default()), 0.0);
        assert_eq!(cut_change(&a, &NodeSet::default()), 4.0);
    }
}
