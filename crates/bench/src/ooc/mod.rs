//! The `ooc` suite: the out-of-core path (Gobbetti et al. 2008) against the
//! in-core renderer, its output sensitivity, and streaming along a camera path.
//!
//! * (a) Head CT, shaded DVR with the default accelerations (ERT + ESS), opaque
//!   bone and translucent soft-tissue TFs: a brick store of the volume rendered
//!   out of core at the finest level (`tolerance_px = 0`), converged first, against
//!   the in-core renderer with the same switches and step. Frames of the two are
//!   interleaved round by round; each time is the median over rounds of
//!   `prepare + submit + wait` wall time. Reports the time ratio OOC / in core and
//!   the PSNR of the OOC image against the in-core one.
//! * (b) Output sensitivity: the procedural fractal-noise source at 256^3, 4096^3
//!   and 65536^3 in the same `VolumeFrame::centered` box, the same view, TF and
//!   tolerance (1 px), each converged, then timed round-robin. Reports working-set
//!   bricks, ms per frame, samples per ray, the levels of the converged cut, and
//!   the ratios largest / smallest.
//! * (c) A scripted camera path over a large virtual volume with a realistic budget
//!   (GPU 256 MiB, upload 16 MiB per frame): a slow orbit, a jump to a close-up of
//!   another region held still while it streams in, then slow motion again. Reports
//!   per-frame wall time, frames to converge after the jump, median, p99 and
//!   p99 / median; run with exact (default) and 8-bit u8 texels, whose pool holds
//!   twice the bricks. `--path-hold N` (25) and `--path-gpu-mib M` (256) change
//!   the hold and the pool.

mod path;
mod sensitivity;

use crate::report::{RunInfo, Timing, interleave};
use crate::runner::{Runner, finest_ooc_renderer, finite_db, median, quantile, round2};
use brickray_cache::refine::{DataState, MetaState, NodeClass, RefineEnv, RefineParams};
use brickray_core::{
    Accel, BrickSource, Camera, NodeKey, RenderMode, RenderSettings, Shading, TransferFunction,
    VolumeFrame,
};
use brickray_harness::{GpuContext, ct, target_desc as targets};
use brickray_render::{
    OutOfCoreConfig, OutOfCoreStats, RendererOptions, U8Filtering, VolumeRenderer,
};
use glam::Vec3;
use serde::Serialize;
use std::sync::Arc;
use std::time::Instant;

/// Brick side and apron of the procedural sources (those of the store's default).
const BRICK: u32 = 32;
const APRON: u32 = 2;
/// Sizes of part (b): the 256^3, 4096^3 and 65536^3, plus 512^3, about
/// pixel resolution at the view of part (b).
const SIZES: [u64; 4] = [256, 512, 4096, 65536];
/// The volume size whose voxel is the TF's opacity reference length.
const TF_REFERENCE_DIMS: u64 = 256;
/// The same for the camera path of part (c): 16x denser than part (b), so that
/// rays of the close-up terminate early (with the opacity of part (b) a
/// close-up ray crosses the whole box at the fine step of the near bricks, and
/// one 256x256 frame takes about 17 s on lavapipe).
const PATH_TF_REFERENCE_DIMS: u64 = 4096;

/// The suite's options.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Image side in pixels.
    #[arg(long, default_value_t = 512, value_parser = crate::image_side)]
    size: u32,
    /// Interleaved rounds.
    #[arg(long, default_value_t = 3, value_parser = crate::at_least_one::<usize>)]
    rounds: usize,
    /// Parts to run: any of a (vs in core), b (output sensitivity), c (camera path).
    #[arg(long, default_value = "abc", value_parser = crate::ooc_parts)]
    parts: String,
    /// Image side of the camera path.
    #[arg(long, default_value_t = 256, value_parser = crate::image_side)]
    path_size: u32,
    /// Voxels per side of the path's procedural volume.
    #[arg(long, default_value_t = 65536)]
    path_dims: u64,
    /// Frames each path view is held.
    #[arg(long, default_value_t = 25)]
    path_hold: usize,
    /// GPU pool of the path, MiB.
    #[arg(long, default_value_t = 256)]
    path_gpu_mib: u64,
}

/// (a) One TF and accelerations, in core against out of core at the finest level.
#[derive(Debug, Serialize)]
pub(crate) struct HeadRow {
    /// opaque or translucent.
    scene: &'static str,
    /// ert_ess (the default, the measured figure) or ert (a diagnostic).
    accel: &'static str,
    incore: Timing,
    ooc: Timing,
    /// Out-of-core wall time over in-core.
    time_ratio: f64,
    samples_per_ray_incore: f64,
    samples_per_ray_ooc: f64,
    /// The out-of-core image against the in-core one.
    psnr_db: f64,
    working_set_bricks: u64,
    frames_to_converge: usize,
}

/// The suite's JSON line.
#[derive(Debug, Serialize)]
pub(crate) struct OocResult {
    #[serde(flatten)]
    run: RunInfo,
    path_image_size: u32,
    path_volume_dims: u64,
    /// (a), head CT: rows, then the worst default ratio and PSNR (null when
    /// the part did not run).
    head: Vec<HeadRow>,
    finest_vs_incore_time_ratio: Option<f64>,
    psnr_finest_vs_incore_db: Option<f64>,
    /// (b), output sensitivity from the far and the close view.
    sensitivity: Vec<sensitivity::Sensitivity>,
    /// (c), the camera path with exact and 8-bit texels.
    path: Vec<path::PathResult>,
    /// The exact path's p99 over median frame time and frames to converge
    /// after the jump (null when part c did not run or did not converge).
    p99_over_median: Option<f64>,
    frames_to_converge_after_jump: Option<usize>,
}

pub(crate) fn run(args: &Args) -> Result<OocResult, String> {
    let (size, rounds, path_size, path_dims) =
        (args.size, args.rounds, args.path_size, args.path_dims);
    let parts = &args.parts;
    let gpu = GpuContext::new().map_err(|e| e.to_string())?;
    println!("adapter: {}", gpu.describe());
    println!(
        "image {size}x{size}; {rounds} interleaved rounds; path {path_size}x{path_size} over {path_dims}^3"
    );
    let t = Instant::now();
    let (mut head, mut volume) = (Vec::new(), "procedural noise");
    if parts.contains('a') {
        (head, volume) = part_a(&gpu, size, rounds)?;
    }
    let mut sensitivity = Vec::new();
    if parts.contains('b') {
        // The primary view: far enough that a 256^3 voxel covers at most about a
        // pixel (orbit distance 3.6, box side 1, 40 degree field of view at 512 px),
        // so every size is drawn at the resolution the image needs.
        sensitivity.push(sensitivity::part_b(
            &gpu,
            size,
            rounds,
            3.6 * size as f32 / 512.0,
            "far",
        )?);
        // A closer view, where 256^3 is below pixel resolution (1.4 px a voxel)
        // and the larger volumes legitimately refine further.
        sensitivity.push(sensitivity::part_b(&gpu, size, rounds, 2.0, "close")?);
    }
    let mut paths = Vec::new();
    if parts.contains('c') {
        let path = path::PathOptions {
            size: path_size,
            dims: path_dims,
            hold: args.path_hold,
            gpu_mib: args.path_gpu_mib,
        };
        paths.push(path::part_c(&gpu, path, U8Filtering::Exact)?);
        // The same path with 8-bit texels: the pool then holds twice the bricks
        // and uploads carry half the bytes (the memory cost of exact u8).
        paths.push(path::part_c(&gpu, path, U8Filtering::Fast)?);
    }
    println!("\nsuite wall time: {:.0} s", t.elapsed().as_secs_f64());
    let defaults = || head.iter().filter(|r| r.accel == "ert_ess");
    let worst_ratio = defaults().map(|r| r.time_ratio).reduce(f64::max);
    let worst_psnr = defaults().map(|r| r.psnr_db).reduce(f64::min);
    Ok(OocResult {
        run: RunInfo::new(&gpu, size, rounds, volume),
        path_image_size: path_size,
        path_volume_dims: path_dims,
        finest_vs_incore_time_ratio: worst_ratio,
        psnr_finest_vs_incore_db: worst_psnr,
        head,
        sensitivity,
        p99_over_median: paths.first().map(|p| p.p99_over_median),
        frames_to_converge_after_jump: paths.first().and_then(|p| p.frames_to_converge_after_jump),
        path: paths,
    })
}

/// (a) Out of core at the finest level vs in core, head CT.
/// Its rows, and the name of the volume drawn.
fn part_a(
    gpu: &GpuContext,
    size: u32,
    rounds: usize,
) -> Result<(Vec<HeadRow>, &'static str), String> {
    // The shared volume, or a procedural stand-in in a clone without it.
    let (vol, volume) = brickray_harness::stand_in::head_ct_or_phantom()?;
    println!("volume: {volume}");
    let d = vol.desc().clone();
    println!(
        "\n(a) finest level out of core vs in core: head CT {:?} {} spacing {:?}",
        d.dims,
        d.dtype.name(),
        d.spacing
    );
    let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
    let store_path = dir.path().join("head.brs");
    let t = Instant::now();
    let mut reader = brickray_io::MemoryReader::new(vol.clone(), "memory");
    brickray_store::build(
        &mut reader,
        &store_path,
        &brickray_store::BuildOptions::default(),
    )
    .map_err(|e| e.to_string())?;
    let source: Arc<dyn BrickSource> =
        Arc::new(brickray_store::open(&store_path).map_err(|e| e.to_string())?);
    println!(
        "  store built in {:.1} s ({} levels, bricks {}+2x{})",
        t.elapsed().as_secs_f64(),
        source.layout().levels,
        source.layout().brick,
        source.layout().apron
    );
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let camera = Camera::orbit(frame.center(), 2.0, 0.5, 0.3);
    let mut incore = VolumeRenderer::new(&gpu.device, targets()).map_err(|e| e.to_string())?;
    incore
        .set_volume(&gpu.device, &gpu.queue, &vol)
        .map_err(|e| e.to_string())?;
    let mut ooc = finest_ooc_renderer(gpu, source, RendererOptions::default())?;
    let run = Runner::new(gpu, size)?;
    let settings = |accel| RenderSettings {
        mode: RenderMode::Dvr,
        shading: Shading {
            enabled: true,
            ..Default::default()
        },
        accel,
        ..Default::default()
    };
    let scenes: [(&'static str, TransferFunction); 2] =
        [("opaque", ct::bone()), ("translucent", ct::soft_tissue())];
    // The default switches (ERT + ESS) are the measured figure; ERT alone (no
    // ESS in either renderer) is a diagnostic separating the coarser empty-space
    // skipping of the out-of-core path (whole bricks) from per-sample costs.
    let variants: [(&'static str, Accel); 2] = [
        ("ert_ess", Accel::default()),
        (
            "ert",
            Accel {
                empty_space_skipping: false,
                ..Accel::default()
            },
        ),
    ];
    println!(
        "  {:<12} {:<8} {:>7} {:>10} {:>10} {:>7} {:>9} {:>9} {:>8} {:>7}",
        "TF",
        "accel",
        "bricks",
        "incore ms",
        "ooc ms",
        "ratio",
        "smp/ray i",
        "smp/ray o",
        "PSNR dB",
        "frames"
    );
    let mut rows = Vec::new();
    for &(scene, ref tf) in &scenes {
        incore
            .set_transfer_function(&gpu.device, &gpu.queue, tf)
            .expect("transfer function");
        ooc.set_transfer_function(&gpu.device, &gpu.queue, tf)
            .expect("transfer function");
        let (frames, stats) =
            run.converge(&mut ooc, camera, frame, settings(variants[0].1), 400)?;
        let frames = frames.ok_or_else(|| format!("(a) {scene}: not converged: {stats:?}"))?;
        // Quality and samples: one read frame per renderer and variant.
        let mut shots = Vec::new();
        for (_, accel) in variants {
            let a = run.frame(&mut incore, camera, frame, settings(accel), true)?;
            let b = run.frame(&mut ooc, camera, frame, settings(accel), true)?;
            shots.push((a, b));
        }
        let stats = ooc.stats().out_of_core.ok_or("not out of core")?;
        // Timing: rounds over (renderer, variant), the order rotated each round.
        let times = interleave(rounds, 2 * variants.len(), |i| {
            let accel = variants[i / 2].1;
            let renderer = if i % 2 == 0 { &mut incore } else { &mut ooc };
            run.frame(renderer, camera, frame, settings(accel), false)
        })?;
        for (v, (name, _)) in variants.iter().enumerate() {
            let (a, b) = &shots[v];
            let (ti, to) = (Timing::of(&times[2 * v]), Timing::of(&times[2 * v + 1]));
            let (mi, mo) = (ti.ms, to.ms);
            let ratio = mo / mi;
            let psnr = brickray_reference::psnr(&b.rgba, &a.rgba);
            println!(
                "  {scene:<12} {name:<8} {:>7} {mi:>10.1} {mo:>10.1} {ratio:>6.2}x {:>9.1} {:>9.1} {:>8.2} {frames:>7}",
                stats.cache.working_set_bricks, a.samples, b.samples, psnr
            );
            rows.push(HeadRow {
                scene,
                accel: name,
                incore: ti,
                ooc: to,
                time_ratio: round2(ratio),
                samples_per_ray_incore: round2(a.samples),
                samples_per_ray_ooc: round2(b.samples),
                psnr_db: finite_db(psnr),
                working_set_bricks: stats.cache.working_set_bricks as u64,
                frames_to_converge: frames,
            });
        }
        println!(
            "  {:<21} ooc host side: refine {:.2} ms, upload {:.2} ms, index {:.2} ms ({} words)",
            "", stats.refine_ms, stats.upload_ms, stats.encode_ms, stats.index_words
        );
    }
    let worst_ratio = rows
        .iter()
        .filter(|r| r.accel == "ert_ess")
        .map(|r| r.time_ratio)
        .fold(0.0, f64::max);
    println!(
        "  worst ratio {worst_ratio:.2}x (bound 1.5x, goal 1.2x): {}",
        verdict(worst_ratio, 1.5, 1.2)
    );
    Ok((rows, volume))
}

fn verdict(x: f64, bound: f64, goal: f64) -> &'static str {
    if x <= goal {
        "goal met"
    } else if x <= bound {
        "bound met, goal missed"
    } else {
        "BOUND MISSED"
    }
}

/// The TF of the procedural volumes.
fn noise_tf() -> TransferFunction {
    TransferFunction::from_points(
        &[(0.45, [0.2, 0.5, 1.0, 0.0]), (0.7, [1.0, 0.8, 0.5, 0.3])],
        256,
    )
}

/// [`noise_tf`] with its opacity per world length held at that of a
/// `reference_dims`^3 volume in the same box. The renderer defines opacity per finest voxel, so the unchanged TF
/// makes a 65536^3 volume in the same box 256x denser (nearly opaque), which
/// changes the image and the sample counts (ERT), not just the data size.
fn noise_tf_world(dims: u64, reference_dims: u64) -> TransferFunction {
    let k = reference_dims as f64 / dims as f64;
    TransferFunction::from_entries(
        noise_tf()
            .entries()
            .iter()
            .map(|e| {
                [
                    e[0],
                    e[1],
                    e[2],
                    brickray_core::tf::corrected_alpha(e[3] as f64, k) as f32,
                ]
            })
            .collect(),
    )
}

fn noise_source(dims: u64) -> Result<Arc<dyn BrickSource>, String> {
    Ok(Arc::new(
        brickray_store::ProceduralSource::fractal_noise([dims; 3], BRICK, APRON)
            .map_err(|e| e.to_string())?,
    ))
}
