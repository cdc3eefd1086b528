//! The level-of-detail path cases of the stability suite: a fly-through and a
//! zoom from far away to inside a procedural volume, rendered out of core with
//! level-of-detail fades on and off, each frame compared with the CPU f64
//! reference at full resolution along the same path
//! (`brickray_reference::temporal_stability`, docs/stability.md).
//!
//! Library functions: [`cases`] runs them, [`figures`] sums them up for the
//! suite's JSON line.

use brickray_core::{Camera, RenderMode, RenderSettings, TransferFunction, Volume, VolumeFrame};
use brickray_harness::{GpuContext, Offscreen, draw_frame, draw_until_settled, target_desc};
use brickray_reference::{
    ReferenceOptions, TemporalOptions, TemporalReport, render_reference, temporal_stability,
};
use brickray_render::{FadeDuration, FrameDesc, OutOfCoreConfig, VolumeRenderer};
use glam::Vec3;
use serde::Serialize;
use std::sync::Arc;

/// Knobs of the path cases.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PathOptions {
    /// Image side in pixels.
    pub(crate) size: u32,
    /// Volume side in voxels.
    pub(crate) dims: u32,
    /// Brick side of the store.
    pub(crate) brick: u32,
    /// Frames per path.
    pub(crate) frames: usize,
    /// Fade length with fades on (frames: deterministic).
    pub(crate) fade_frames: u32,
    /// Pop threshold (mean absolute error change of a 16x16 tile, 8-bit units).
    pub(crate) pop_threshold: f64,
    /// Pause after each frame, letting the loader threads work (ms).
    pub(crate) pause_ms: u64,
    /// Screen-space tolerance of refinement (pixels per voxel; larger: coarser
    /// levels, larger level switches).
    pub(crate) tolerance_px: f32,
}

impl Default for PathOptions {
    fn default() -> Self {
        PathOptions {
            size: 128,
            dims: 128,
            brick: 16,
            frames: 48,
            fade_frames: 6,
            pop_threshold: 8.0,
            pause_ms: 10,
            tolerance_px: 4.0,
        }
    }
}

/// One path rendered one way.
#[derive(Debug, Clone)]
pub(crate) struct Run {
    /// The temporal stability against the reference.
    pub(crate) temporal: TemporalReport,
    /// Most holes (leaves without a brick) in a frame of the path.
    pub(crate) holes_max: u32,
    /// Frames with a fade in progress.
    pub(crate) fading_frames: usize,
}

/// One case: fades on and off.
#[derive(Debug, Clone)]
pub(crate) struct CaseResult {
    /// Its name.
    pub(crate) name: &'static str,
    /// With fades.
    pub(crate) fades: Run,
    /// Without.
    pub(crate) no_fades: Run,
}

/// A 8-bit fractal-noise volume (detail at every level, so level changes
/// show).
pub(crate) fn noise_volume(n: u32) -> Volume {
    brickray_harness::scenes::noise_volume(n)
}

/// The transfer function of the cases.
pub(crate) fn noise_tf() -> TransferFunction {
    TransferFunction::ramp(0.5, 0.8, 0.5)
}

/// The cameras of the named paths (`fly`: straight into the volume and
/// through it; `zoom`: from far away to inside), `frames` each.
pub(crate) fn paths(frames: usize) -> Vec<(&'static str, Vec<Camera>)> {
    let n = frames.max(2);
    let s = |i: usize| i as f32 / (n - 1) as f32;
    let fly = (0..n)
        .map(|i| {
            let eye = Vec3::new(0.12, 0.07, 3.0 - 3.2 * s(i));
            Camera {
                eye,
                target: eye + Vec3::new(0.05, 0.0, -1.0),
                near: 0.01,
                ..Camera::orbit(Vec3::ZERO, 1.0, 0.0, 0.0)
            }
        })
        .collect();
    let zoom = (0..n)
        .map(|i| {
            // Geometric: the same relative step every frame.
            let d = 8.0 * (0.35f32 / 8.0).powf(s(i));
            Camera {
                near: 0.01,
                ..Camera::orbit(Vec3::ZERO, d, 0.6, 0.35)
            }
        })
        .collect();
    vec![("fly-through", fly), ("zoom-in", zoom)]
}

/// Renders `cameras` out of core (fades `fade`) after settling at the first;
/// returns the frames (RGBA8), the most holes in a frame and the frames fading.
#[allow(clippy::too_many_arguments)]
fn render_path(
    gpu: &GpuContext,
    source: Arc<dyn brickray_core::BrickSource>,
    frame: VolumeFrame,
    tf: &TransferFunction,
    settings: RenderSettings,
    cameras: &[Camera],
    fade: Option<FadeDuration>,
    opt: &PathOptions,
) -> Result<(Vec<Vec<u8>>, u32, usize), String> {
    let e = |e: brickray_render::RenderError| e.to_string();
    let mut r = VolumeRenderer::new(&gpu.device, target_desc()).map_err(e)?;
    let config = OutOfCoreConfig {
        fade,
        tolerance_px: opt.tolerance_px,
        ..Default::default()
    };
    r.set_volume_source(&gpu.device, &gpu.queue, source, config)
        .map_err(e)?;
    r.set_transfer_function(&gpu.device, &gpu.queue, tf)
        .map_err(e)?;
    let target = Offscreen::new(&gpu.device, opt.size, opt.size);
    let desc = |camera: Camera| FrameDesc {
        settings,
        ..FrameDesc::new(camera, frame, opt.size, opt.size)
    };
    draw_until_settled(gpu, &mut r, &target, &desc(cameras[0]), 400)
        .map_err(|e| e.to_string())?
        .ok_or("the first view did not settle")?;
    let (mut images, mut holes, mut fading) = (Vec::new(), 0u32, 0usize);
    for cam in cameras {
        draw_frame(gpu, &mut r, &target, &desc(*cam), Some(wgpu::Color::BLACK))
            .map_err(|e| e.to_string())?;
        images.push(target.read_color(gpu));
        let s = r.stats().out_of_core.ok_or("not out of core")?;
        holes = holes.max(s.cache.holes);
        fading += (s.cache.fading > 0) as usize;
        std::thread::sleep(std::time::Duration::from_millis(opt.pause_ms));
    }
    Ok((images, holes, fading))
}

/// Runs the path cases (DVR), fades on (`FadeDuration::Frames(fade_frames)`)
/// and off, against the CPU reference of every frame.
pub(crate) fn cases(gpu: &GpuContext, opt: &PathOptions) -> Result<Vec<CaseResult>, String> {
    let vol = noise_volume(opt.dims);
    let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
    let path = dir.path().join("noise.brs");
    let mut reader = brickray_io::MemoryReader::new(vol.clone(), "memory");
    let build = brickray_store::BuildOptions {
        brick: opt.brick,
        ..Default::default()
    };
    brickray_store::build(&mut reader, &path, &build).map_err(|e| e.to_string())?;
    let source: Arc<dyn brickray_core::BrickSource> =
        Arc::new(brickray_store::open(&path).map_err(|e| e.to_string())?);
    let frame = VolumeFrame::centered([opt.dims; 3], [1.0; 3]);
    let tf = noise_tf();
    let settings = RenderSettings {
        mode: RenderMode::Dvr,
        ..Default::default()
    };
    let topt = TemporalOptions {
        tile: 16,
        pop_threshold: opt.pop_threshold,
    };
    let mut out = Vec::new();
    for (name, cams) in paths(opt.frames) {
        let reference: Vec<Vec<u8>> = cams
            .iter()
            .map(|c| {
                render_reference(
                    &vol,
                    &frame,
                    &tf,
                    c,
                    &settings,
                    &ReferenceOptions::new(opt.size, opt.size),
                )
                .to_rgba8([0.0; 3])
            })
            .collect();
        let run = |fade| -> Result<Run, String> {
            let (images, holes_max, fading_frames) =
                render_path(gpu, source.clone(), frame, &tf, settings, &cams, fade, opt)?;
            let temporal = temporal_stability(&images, &reference, opt.size, opt.size, topt)
                .map_err(|e| e.to_string())?;
            Ok(Run {
                temporal,
                holes_max,
                fading_frames,
            })
        };
        let fades = run(Some(FadeDuration::Frames(opt.fade_frames)))?;
        let no_fades = run(None)?;
        out.push(CaseResult {
            name,
            fades,
            no_fades,
        });
    }
    Ok(out)
}

/// Bound of the cases with fades: the change excess in dB.
pub(crate) const EXCESS_DB_BOUND: f64 = 0.5;

/// The suite's summary of each case: it holds when, with fades, no frame pops,
/// the change excess is within [`EXCESS_DB_BOUND`] and no frame has a hole.
pub(crate) fn summaries(results: &[CaseResult], opt: &PathOptions) -> Vec<super::Case> {
    results
        .iter()
        .map(|c| {
            let (on, off) = (&c.fades.temporal, &c.no_fades.temporal);
            let holes = c.fades.holes_max.max(c.no_fades.holes_max);
            super::Case {
                name: c.name,
                varied: format!(
                    "LOD fades of {} frames vs off along the path (tolerance {} px)",
                    opt.fade_frames, opt.tolerance_px
                ),
                fails: format!(
                    "without fades: {} pops (largest 16x16 tile error jump {:.1})",
                    off.pops, off.max_tile_jump
                ),
                by: format!(
                    "with fades: {} pops (jump {:.1}), change excess {:+.3} dB",
                    on.pops, on.max_tile_jump, on.change_excess_db
                ),
                shipped: "fades on by default (120 ms)".into(),
                bound: format!("pops with fades 0, change excess <= {EXCESS_DB_BOUND} dB, holes 0"),
                holds: on.pops == 0 && on.change_excess_db <= EXCESS_DB_BOUND && holes == 0,
                holes_max: holes as u64,
                fig: super::figures(&PathSummary {
                    excess_db_fades: on.change_excess_db,
                    excess_db_no_fades: off.change_excess_db,
                    pops_fades: on.pops,
                    pops_no_fades: off.pops,
                    holes_max: holes,
                }),
            }
        })
        .collect()
}

/// One LOD path with or without fades.
#[derive(Debug, Serialize)]
pub(crate) struct PathRow {
    /// The path's name.
    path: &'static str,
    fades: bool,
    /// How much more the image changes frame to frame than the
    /// reference's own change, dB.
    excess_db: f64,
    flicker_mean: f64,
    flicker_p99: f64,
    pops: usize,
    pop_frames: Vec<usize>,
    max_tile_jump: f64,
    change_mean: f64,
    reference_change_mean: f64,
    holes_max: u32,
    fading_frames: usize,
}

/// One LOD path's summary figures.
#[derive(Debug, Serialize)]
struct PathSummary {
    excess_db_fades: f64,
    excess_db_no_fades: f64,
    pops_fades: usize,
    pops_no_fades: usize,
    holes_max: u32,
}

/// The LOD paths (case 9).
#[derive(Debug, Serialize)]
pub(crate) struct PathFigures {
    rows: Vec<PathRow>,
    /// The largest excess over the paths, with and without fades, dB.
    temporal_excess_db_fades: f64,
    temporal_excess_db_no_fades: f64,
    /// Pops summed over the paths, with and without fades.
    pops_fades: usize,
    pops_no_fades: usize,
    pub(super) holes_max: u32,
}

/// Prints the cases and returns their figures: per path and fades, and
/// over the paths the largest change excess in dB with and without fades,
/// the pops summed and the most hole pixels.
pub(crate) fn figures(results: &[CaseResult]) -> PathFigures {
    let mut rows = Vec::new();
    println!(
        "{:<12} {:>6} {:>10} {:>9} {:>9} {:>5} {:>6} {:>6}",
        "case", "fades", "excess dB", "flick mu", "flick p99", "pops", "holes", "fading"
    );
    let (mut ex_f, mut ex_n) = (f64::NEG_INFINITY, f64::NEG_INFINITY);
    let (mut pops_f, mut pops_n, mut holes) = (0usize, 0usize, 0u32);
    for c in results {
        for (on, r) in [("on", &c.fades), ("off", &c.no_fades)] {
            let t = &r.temporal;
            println!(
                "{:<12} {:>6} {:>10.3} {:>9.3} {:>9.3} {:>5} {:>6} {:>6}",
                c.name,
                on,
                t.change_excess_db,
                t.flicker_mean,
                t.flicker_p99,
                t.pops,
                r.holes_max,
                r.fading_frames
            );
            rows.push(PathRow {
                path: c.name,
                fades: on == "on",
                excess_db: t.change_excess_db,
                flicker_mean: t.flicker_mean,
                flicker_p99: t.flicker_p99,
                pops: t.pops,
                pop_frames: t.pop_frames.clone(),
                max_tile_jump: t.max_tile_jump,
                change_mean: t.change_mean,
                reference_change_mean: t.reference_change_mean,
                holes_max: r.holes_max,
                fading_frames: r.fading_frames,
            });
        }
        ex_f = ex_f.max(c.fades.temporal.change_excess_db);
        ex_n = ex_n.max(c.no_fades.temporal.change_excess_db);
        pops_f += c.fades.temporal.pops;
        pops_n += c.no_fades.temporal.pops;
        holes = holes.max(c.fades.holes_max).max(c.no_fades.holes_max);
    }
    PathFigures {
        rows,
        temporal_excess_db_fades: ex_f,
        temporal_excess_db_no_fades: ex_n,
        pops_fades: pops_f,
        pops_no_fades: pops_n,
        holes_max: holes,
    }
}
