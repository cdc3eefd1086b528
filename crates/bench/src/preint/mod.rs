//! The `preint` suite: what pre-integrated DVR (`RenderSettings::preintegrated`)
//! costs and buys.
//!
//! * CPU: building the pre-integrated table (256 x 256 per step length) against
//!   the corrected table, median of 3.
//! * GPU, in core, the shared head CT (soft-tissue TF), DVR and shaded DVR at
//!   steps of 0.5 and 2 voxels: plain and pre-integrated frames interleaved
//!   round by round (order rotated), each variant's time the median over rounds
//!   of `prepare + submit + wait`; printed as the ratio pre-integrated / plain.
//! * Quality, synthetic: a ball with a narrow-spike TF (the GPU tests' scene),
//!   PSNR of plain and pre-integrated GPU images against the exact integral
//!   (CPU reference at 1/16 voxel) at steps of 0.5 to 4 voxels.
//! * Quality on the `pareto` suite's scenes ([`scenes`]): every step from 1/8
//!   to 4, shaded and not, GPU and CPU reference, against the exact integral.

use crate::report::{RunInfo, Timing, interleave};
use crate::runner::{Runner, finite_db, median, round2};
use brickray_core::{Camera, RenderSettings, Shading, VolumeFrame};
use brickray_harness::{GpuContext, ct};
use brickray_reference::{ReferenceOptions, psnr, render_reference};
use brickray_render::VolumeRenderer;
use serde::Serialize;
use std::time::Instant;

mod scenes;

/// The suite's options.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Image side in pixels of the timed frames.
    #[arg(long, default_value_t = 256, value_parser = crate::image_side)]
    size: u32,
    /// Interleaved rounds.
    #[arg(long, default_value_t = 5, value_parser = crate::at_least_one::<usize>)]
    rounds: usize,
    /// Image side in pixels of the scenes' quality images.
    #[arg(long, default_value_t = 64, value_parser = crate::image_side)]
    quality_size: u32,
    /// The pareto scenes compared, comma-separated, of ml, noise, ct, ct5,
    /// mri, nuclei (default all).
    #[arg(long, value_delimiter = ',')]
    scenes: Vec<String>,
    /// The exact integral's step is 1 / this many voxels.
    #[arg(long, default_value_t = 64, value_parser = crate::at_least_one::<u32>)]
    exact_div: u32,
    /// Draw the scenes' GPU images without early ray termination (the
    /// default terminates at 0.99, as the library does); the exact integral
    /// never terminates.
    #[arg(long)]
    no_termination: bool,
}

/// Plain against pre-integrated DVR on the head CT, one mode and step.
#[derive(Debug, Serialize)]
pub(crate) struct CostRow {
    /// dvr or dvr_shaded.
    mode: &'static str,
    step: f32,
    plain: Timing,
    preint: Timing,
    /// Pre-integrated wall time over plain.
    ratio: f64,
    /// The pre-integrated image against the plain one.
    psnr_preint_vs_plain_db: f64,
}

/// The spike scene at one step: PSNR against the exact integral.
#[derive(Debug, Serialize)]
pub(crate) struct SpikeRow {
    step: f32,
    psnr_plain_db: f64,
    psnr_preint_db: f64,
}

/// The suite's JSON line.
#[derive(Debug, Serialize)]
pub(crate) struct PreintResult {
    #[serde(flatten)]
    run: RunInfo,
    /// CPU time of the opacity-corrected table (one row) and of the
    /// pre-integrated table with 1 and 8 layers, ms.
    ms_corrected_table: f64,
    ms_preint_table_1_layers: f64,
    ms_preint_table_8_layers: f64,
    cost: Vec<CostRow>,
    /// The largest pre-integrated over plain ratio.
    worst_ratio: f64,
    spike: Vec<SpikeRow>,
    /// The pareto scenes, every step and shading ([`scenes::rows`]).
    scenes: Vec<scenes::SceneRow>,
    /// Shared scenes left out (no `../shared`).
    scenes_missing: Vec<String>,
    /// The scenes' GPU images were drawn without early ray termination.
    scenes_unterminated: bool,
    /// The smallest and the median pre-integrated minus plain PSNR over the
    /// scene rows (GPU), dB; `preint_never_loses` when the smallest is >= 0.
    preint_gain_db_min: f64,
    preint_gain_db_median: f64,
    preint_never_loses: bool,
}

/// DVR at `step`, plain or pre-integrated, shaded or not.
fn dvr(step: f32, preintegrated: bool, shaded: bool) -> RenderSettings {
    RenderSettings {
        step_factor: step,
        preintegrated,
        shading: Shading {
            enabled: shaded,
            ..Default::default()
        },
        ..Default::default()
    }
}

fn ms_of(f: impl Fn()) -> f64 {
    let mut t = Vec::new();
    for _ in 0..3 {
        let t0 = Instant::now();
        f();
        t.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    median(&t)
}

pub(crate) fn run(args: &Args) -> Result<PreintResult, String> {
    let (rounds, size) = (args.rounds, args.size);

    // CPU table builds.
    let soft = ct::soft_tissue();
    let corrected = ms_of(|| {
        std::hint::black_box(soft.corrected_table(0.5, 1, 8192));
    });
    println!(
        "CPU tables ({} threads):",
        std::thread::available_parallelism().map_or(1, |n| n.get())
    );
    println!("  corrected table, 1 row: {corrected:.2} ms");
    let mut table_ms = [0.0; 2];
    for (ms_out, layers) in table_ms.iter_mut().zip([1u32, 8]) {
        let ms = ms_of(|| {
            std::hint::black_box(soft.preintegrated_table(0.5, layers, 256));
        });
        println!("  pre-integrated table, 256x256 x {layers} layer(s): {ms:.1} ms");
        *ms_out = round2(ms);
    }

    let gpu = GpuContext::new().map_err(|e| e.to_string())?;
    println!("adapter: {}", gpu.describe());

    // GPU cost on the head CT.
    // The shared volume, or a procedural stand-in in a clone without it.
    let (vol, volume) = brickray_harness::stand_in::head_ct_or_phantom()?;
    println!("volume: {volume}");
    let d = vol.desc();
    println!(
        "head CT {:?}, soft tissue, {size}x{size}, {rounds} interleaved rounds",
        d.dims
    );
    let mut r = VolumeRenderer::new(&gpu.device, brickray_harness::target_desc())
        .map_err(|e| e.to_string())?;
    r.set_volume(&gpu.device, &gpu.queue, &vol)
        .map_err(|e| e.to_string())?;
    r.set_transfer_function(&gpu.device, &gpu.queue, &soft)
        .map_err(|e| e.to_string())?;
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let camera = Camera::orbit(frame.center(), 2.0, 0.5, 0.3);
    let run = Runner::new(&gpu, size)?;
    println!(
        "  {:<16} {:>5} {:>10} {:>10} {:>7} {:>14}",
        "mode", "step", "plain ms", "preint ms", "ratio", "PSNR vs plain"
    );
    let mut worst_ratio = 0.0f64;
    let mut cost = Vec::new();
    for shaded in [false, true] {
        for step in [0.5f32, 2.0] {
            let settings = |preintegrated| dvr(step, preintegrated, shaded);
            // Warm-up (pipelines, tables) and the images.
            let mut images = Vec::new();
            for p in [false, true] {
                images.push(run.frame(&mut r, camera, frame, settings(p), true)?.rgba);
            }
            let shots = interleave(rounds, 2, |i| {
                run.frame(&mut r, camera, frame, settings(i == 1), false)
            })?;
            let (plain_t, pre_t) = (Timing::of(&shots[0]), Timing::of(&shots[1]));
            let (plain, pre) = (plain_t.ms, pre_t.ms);
            let ratio = pre / plain;
            worst_ratio = worst_ratio.max(ratio);
            let db = psnr(&images[1], &images[0]);
            let mode = if shaded { "dvr_shaded" } else { "dvr" };
            println!(
                "  {mode:<16} {step:>5} {plain:>10.1} {pre:>10.1} {ratio:>6.2}x {db:>11.2} dB"
            );
            cost.push(CostRow {
                mode,
                step,
                plain: plain_t,
                preint: pre_t,
                ratio: round2(ratio),
                psnr_preint_vs_plain_db: finite_db(db),
            });
        }
    }

    // Quality on the spike scene.
    let ball = brickray_core::synthetic::sphere(64);
    let bd = ball.desc();
    let bframe = VolumeFrame::centered(bd.dims, bd.spacing);
    let bcam = Camera::orbit(bframe.center(), 2.0, 0.5, 0.3);
    let tf = brickray_harness::scenes::spike_tf();
    let q = 96;
    let mut rb = VolumeRenderer::new(&gpu.device, brickray_harness::target_desc())
        .map_err(|e| e.to_string())?;
    rb.set_volume(&gpu.device, &gpu.queue, &ball)
        .map_err(|e| e.to_string())?;
    rb.set_transfer_function(&gpu.device, &gpu.queue, &tf)
        .map_err(|e| e.to_string())?;
    let qrun = Runner::new(&gpu, q)?;
    let base = RenderSettings::default();
    let exact = render_reference(
        &ball,
        &bframe,
        &tf,
        &bcam,
        &base,
        &ReferenceOptions::new(q, q).exact_integral(),
    )
    .to_rgba8([0.0; 3]);
    println!("spike ball 64^3, {q}x{q}, PSNR vs the exact integral (1/16 voxel):");
    println!("  {:>5} {:>9} {:>9}", "step", "plain", "preint");
    let mut spike = Vec::new();
    for step in [0.5f32, 1.0, 2.0, 4.0] {
        let mut db = [0.0; 2];
        for (i, p) in [false, true].into_iter().enumerate() {
            let s = RenderSettings {
                step_factor: step,
                preintegrated: p,
                ..base
            };
            db[i] = psnr(&qrun.frame(&mut rb, bcam, bframe, s, true)?.rgba, &exact);
        }
        println!("  {step:>5} {:>6.2} dB {:>6.2} dB", db[0], db[1]);
        spike.push(SpikeRow {
            step,
            psnr_plain_db: finite_db(db[0]),
            psnr_preint_db: finite_db(db[1]),
        });
    }
    let (scene_rows, scenes_missing) = scenes::rows(
        &gpu,
        &args.scenes,
        args.quality_size,
        args.exact_div,
        args.no_termination,
    )?;
    let gains: Vec<f64> = scene_rows.iter().map(|r| r.gpu_gain_db()).collect();
    let gain_min = gains.iter().copied().fold(f64::INFINITY, f64::min);
    println!(
        "pre-integrated minus plain over {} rows: min {gain_min:+.2} dB, median {:+.2} dB",
        gains.len(),
        median(&gains)
    );
    Ok(PreintResult {
        run: RunInfo::new(&gpu, size, rounds, volume),
        preint_gain_db_min: finite_db(gain_min),
        preint_gain_db_median: finite_db(median(&gains)),
        preint_never_loses: gain_min >= 0.0,
        scenes: scene_rows,
        scenes_missing,
        scenes_unterminated: args.no_termination,
        ms_corrected_table: round2(corrected),
        ms_preint_table_1_layers: table_ms[0],
        ms_preint_table_8_layers: table_ms[1],
        cost,
        worst_ratio: round2(worst_ratio),
        spike,
    })
}
