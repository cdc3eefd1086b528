//! The `spread` suite: coarse levels classified with their spread
//! (`docs/rendering-model.md`, *Coarse levels*) against the TF of their
//! values, out of core: frame time (interleaved) and PSNR against in core
//! at the finest level.
//!
//! Volumes: the shared head CT under the bone ramp, the same at
//! 4.5 mm slices (every third slice, anisotropic store) and the T1 MRI under
//! the pareto suite's TF (procedural stand-ins where `../shared/data` is
//! absent). Each is built into a store without spreads and one with them
//! (`BuildOptions::spread`, format version 7; the build times of both are
//! reported, and the in-memory [`SpreadSource`]'s). At
//! each tolerance both renderers converge (no fades), then their frames are
//! timed round by round (`--rounds`, 5) at `--size` (256) px, orbit camera
//! at distance 2 (azimuth 0.5, elevation 0.3), default switches, unshaded.
//! Beside the times, what each cut costs in bytes: a GPU-free streamer at
//! the same view converges over each store and sums the prepared bytes it
//! uploads (`upload_mb_*`) and the CPU cache's bytes at convergence
//! (`cpu_mb_*`); bricks of the finest level carry no spread (the kernel
//! never reads it), so a mostly-finest cut costs little more with spreads.
//!
//! `cargo run --release -p brickray-bench -- spread [--size PX] [--rounds N] [--tolerances 1,2,4]`

use crate::report::{RunInfo, Timing, interleave};
use crate::runner::{Runner, round2};
use brickray_core::{
    BrickSource, Camera, RenderSettings, SpreadSource, TransferFunction, Volume, VolumeFrame,
};
use brickray_harness::{GpuContext, ct};
use brickray_reference::psnr;
use brickray_render::{OutOfCoreConfig, VolumeRenderer};
use serde::Serialize;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

/// The suite's options.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Image side in pixels.
    #[arg(long, default_value_t = 256, value_parser = crate::image_side)]
    size: u32,
    /// Interleaved rounds.
    #[arg(long, default_value_t = 5, value_parser = crate::at_least_one::<usize>)]
    rounds: usize,
    /// Screen-space tolerances (px) of the cuts compared.
    #[arg(long, value_delimiter = ',', default_values_t = [1.0f32, 2.0, 4.0])]
    tolerances: Vec<f32>,
}

/// One volume at one tolerance: the same cut drawn with and without spreads.
#[derive(Debug, Serialize)]
pub(crate) struct Row {
    volume: &'static str,
    tolerance_px: f32,
    /// Data bricks of the converged cut (the same for both).
    bricks: u32,
    plain: Timing,
    spread: Timing,
    /// Spread wall time over plain.
    spread_over_plain: f64,
    /// Prepared bytes a streamer at the same view uploads until it
    /// converges, and its CPU cache then, MB, without and with spreads.
    upload_mb_plain: f64,
    upload_mb_spread: f64,
    cpu_mb_plain: f64,
    cpu_mb_spread: f64,
    /// Against in core at the finest level.
    psnr_plain_db: f64,
    psnr_spread_db: f64,
    /// Spread PSNR less plain PSNR.
    gain_db: f64,
}

/// One volume's set-up costs.
#[derive(Debug, Serialize)]
pub(crate) struct Setup {
    volume: &'static str,
    /// Building its store without spreads, and with them.
    build_ms: f64,
    build_spread_ms: f64,
    /// File sizes of the two stores.
    store_bytes: u64,
    store_spread_bytes: u64,
    /// Computing its spreads in memory ([`SpreadSource::new`]).
    spreads_ms: f64,
    /// Building its TF's spread table (32 rows, the GPU's width).
    table_ms: f64,
}

/// The suite's JSON line.
#[derive(Debug, Serialize)]
pub(crate) struct SpreadResult {
    #[serde(flatten)]
    run: RunInfo,
    rows: Vec<Row>,
    setup: Vec<Setup>,
    /// The largest spread over plain ratio.
    spread_over_plain_worst: f64,
    /// Mean gain over the rows whose plain image is below 45 dB (a coarse
    /// level is drawn); null when none is.
    gain_db_mean_coarse: Option<f64>,
}

fn ooc_renderer(
    gpu: &GpuContext,
    source: Arc<dyn BrickSource>,
    tf: &TransferFunction,
    tolerance_px: f32,
) -> Result<VolumeRenderer, String> {
    let mut r = VolumeRenderer::new(&gpu.device, brickray_harness::target_desc())
        .map_err(|e| e.to_string())?;
    let config = OutOfCoreConfig {
        tolerance_px,
        upload_budget_bytes: 1 << 30,
        fade: None,
        ..Default::default()
    };
    r.set_volume_source(&gpu.device, &gpu.queue, source, config)
        .map_err(|e| e.to_string())?;
    r.set_transfer_function(&gpu.device, &gpu.queue, tf)
        .map_err(|e| e.to_string())?;
    Ok(r)
}

/// Converges a GPU-free streamer over `source` at the view and tolerance of
/// a row (the renderer's spread switch, u16 texels, no fades, no upload
/// cap); returns the prepared bytes it uploaded and its CPU cache's bytes,
/// in MB.
fn converged_bytes(
    source: Arc<dyn BrickSource>,
    tf: &TransferFunction,
    tolerance_px: f32,
    view: brickray_core::FrameView,
) -> Result<(f64, f64), String> {
    let spread = source.has_spread();
    let config = OutOfCoreConfig {
        tolerance_px,
        upload_budget_bytes: 1 << 30,
        fade: None,
        ..Default::default()
    };
    let mut streamer = crate::runner::gpu_free_streamer(source, config, spread)?;
    let mut uploaded = 0u64;
    for _ in 0..2000 {
        let plan = streamer.plan(&brickray_cache::StreamFrame {
            views: std::slice::from_ref(&view),
            classification: brickray_cache::Classification {
                mode: brickray_core::RenderMode::Dvr,
                tf,
                channels: &[],
                tf_generation: 0,
            },
            feedback: &[],
            time: None,
        });
        uploaded += plan.uploads.iter().map(|u| u.brick.bytes()).sum::<u64>();
        if plan.stats.converged {
            let cpu = streamer.manager().cpu_cache().bytes();
            return Ok((uploaded as f64 / 1e6, cpu as f64 / 1e6));
        }
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    Err("the streamer did not converge".into())
}

pub(crate) fn run(args: &Args) -> Result<SpreadResult, String> {
    let (size, rounds) = (args.size, args.rounds);
    let (ct_vol, ct_name) = brickray_harness::stand_in::head_ct_or_phantom()?;
    let (mri, mri_name) = brickray_harness::stand_in::mri_or_phantom()?;
    let ct5 = ct::every_third_slice(&ct_vol).ok_or("the head CT is not i16")?;
    let gpu = GpuContext::new().map_err(|e| e.to_string())?;
    println!("adapter: {}", gpu.describe());
    println!("volumes: {ct_name}, {mri_name}; {size} px, {rounds} interleaved rounds");
    let runner = Runner::new(&gpu, size)?;
    let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
    let volumes: [(&'static str, &Volume, TransferFunction, bool); 3] = [
        ("ct", &ct_vol, ct::bone_ramp(), false),
        ("ct5", &ct5, ct::bone_ramp(), true),
        ("mri", &mri, brickray_harness::scenes::mri_tf(), false),
    ];
    let settings = RenderSettings::default();
    let (mut rows, mut setup) = (Vec::new(), Vec::new());
    println!(
        "| volume | px | bricks | plain ms | spread ms | spread / plain | PSNR plain / spread (dB) | gain | uploaded MB plain / spread | CPU cache MB plain / spread |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for (name, vol, tf, anisotropic) in volumes {
        let d = vol.desc();
        let frame = VolumeFrame::centered(d.dims, d.spacing);
        let camera = Camera::orbit(frame.center(), 2.0, 0.5, 0.3);
        let build = |path: &Path, spread: bool| -> Result<(Arc<dyn BrickSource>, f64), String> {
            let mut reader = brickray_io::MemoryReader::new(vol.clone(), name);
            let options = brickray_store::BuildOptions {
                anisotropic,
                spread,
                ..Default::default()
            };
            let t0 = Instant::now();
            brickray_store::build(&mut reader, path, &options).map_err(|e| e.to_string())?;
            let ms = t0.elapsed().as_secs_f64() * 1e3;
            let store = brickray_store::open(path).map_err(|e| e.to_string())?;
            Ok((Arc::new(store), ms))
        };
        let (path, spread_path) = (
            dir.path().join(format!("{name}.brs")),
            dir.path().join(format!("{name}_spread.brs")),
        );
        let (plain, build_ms) = build(&path, false)?;
        let (spread, build_spread_ms) = build(&spread_path, true)?;
        if !spread.has_spread() {
            return Err(format!("{name}: the store built with spreads has none"));
        }
        let size = |p: &Path| std::fs::metadata(p).map(|m| m.len()).unwrap_or(0);
        let t0 = Instant::now();
        SpreadSource::new(plain.clone(), vol).map_err(|e| e.to_string())?;
        let spreads_ms = t0.elapsed().as_secs_f64() * 1e3;
        let t0 = Instant::now();
        let max_width = gpu.device.limits().max_texture_dimension_2d;
        let _ = tf.spread_table(brickray_core::tf::SPREAD_ROWS, max_width);
        let table_ms = t0.elapsed().as_secs_f64() * 1e3;
        setup.push(Setup {
            volume: name,
            build_ms: round2(build_ms),
            build_spread_ms: round2(build_spread_ms),
            store_bytes: size(&path),
            store_spread_bytes: size(&spread_path),
            spreads_ms: round2(spreads_ms),
            table_ms: round2(table_ms),
        });
        let mut incore = VolumeRenderer::new(&gpu.device, brickray_harness::target_desc())
            .map_err(|e| e.to_string())?;
        incore
            .set_volume(&gpu.device, &gpu.queue, vol)
            .map_err(|e| e.to_string())?;
        incore
            .set_transfer_function(&gpu.device, &gpu.queue, &tf)
            .map_err(|e| e.to_string())?;
        let finest = runner
            .frame(&mut incore, camera, frame, settings, true)?
            .rgba;
        for &tol in &args.tolerances {
            let mut rs = [
                ooc_renderer(&gpu, plain.clone(), &tf, tol)?,
                ooc_renderer(&gpu, spread.clone(), &tf, tol)?,
            ];
            let mut images = Vec::new();
            for r in rs.iter_mut() {
                let mut img = Vec::new();
                for _ in 0..100 {
                    img = runner.frame(r, camera, frame, settings, true)?.rgba;
                    if !r.wants_redraw() {
                        break;
                    }
                    std::thread::sleep(std::time::Duration::from_millis(5));
                }
                if r.wants_redraw() {
                    return Err(format!("{name} at {tol} px: not converged"));
                }
                images.push(img);
            }
            let bricks = rs[0]
                .stats()
                .out_of_core
                .map_or(0, |s| s.cache.working_set_bricks);
            let shots = interleave(rounds, 2, |i| {
                runner.frame(&mut rs[i], camera, frame, settings, false)
            })?;
            let t: Vec<Timing> = shots.iter().map(|s| Timing::of(s)).collect();
            let (pp, ps) = (psnr(&images[0], &finest), psnr(&images[1], &finest));
            let ratio = t[1].ms / t[0].ms;
            let view = brickray_core::FrameView::new(camera, frame, [args.size; 2]);
            let (up_p, cpu_p) = converged_bytes(plain.clone(), &tf, tol, view)?;
            let (up_s, cpu_s) = converged_bytes(spread.clone(), &tf, tol, view)?;
            println!(
                "| {name} | {tol} | {bricks} | {:.1} | {:.1} | {ratio:.3} | {pp:.2} / {ps:.2} | {:+.2} | {up_p:.1} / {up_s:.1} | {cpu_p:.1} / {cpu_s:.1} |",
                t[0].ms,
                t[1].ms,
                ps - pp
            );
            rows.push(Row {
                volume: name,
                tolerance_px: tol,
                bricks,
                plain: t[0],
                spread: t[1],
                spread_over_plain: round2(ratio),
                upload_mb_plain: round2(up_p),
                upload_mb_spread: round2(up_s),
                cpu_mb_plain: round2(cpu_p),
                cpu_mb_spread: round2(cpu_s),
                psnr_plain_db: round2(pp),
                psnr_spread_db: round2(ps),
                gain_db: round2(ps - pp),
            });
        }
    }
    for s in &setup {
        println!(
            "{}: store built in {:.0} ms ({} B), with spreads {:.0} ms ({} B); spreads in memory {:.0} ms; spread table {:.0} ms",
            s.volume,
            s.build_ms,
            s.store_bytes,
            s.build_spread_ms,
            s.store_spread_bytes,
            s.spreads_ms,
            s.table_ms
        );
    }
    let coarse: Vec<f64> = rows
        .iter()
        .filter(|r| r.psnr_plain_db < 45.0)
        .map(|r| r.gain_db)
        .collect();
    let worst = rows
        .iter()
        .map(|r| r.spread_over_plain)
        .fold(0.0f64, f64::max);
    Ok(SpreadResult {
        run: RunInfo::new(&gpu, size, rounds, ct_name),
        rows,
        setup,
        spread_over_plain_worst: round2(worst),
        gain_db_mean_coarse: (!coarse.is_empty())
            .then(|| round2(coarse.iter().sum::<f64>() / coarse.len() as f64)),
    })
}
