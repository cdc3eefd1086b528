//! The `raw` suite: brickray's per-sample cost against the device's rate.
//!
//! The yardstick is a minimal kernel (raw.wgsl) with brickray's rays and sample
//! positions, an R8Unorm 3D texture, the transfer function read per sample and
//! front-to-back accumulation, and nothing else: no traversal, no skipping, no
//! early termination. Its samples per second are what the device allows. It runs
//! with the TF as a filtered texture (opacity corrected once per entry) and as a
//! storage buffer interpolated by hand.
//!
//! Beside it, brickray renders the same view in core and out of core (a store of
//! the same volume at the finest level, converged first), each in brute force
//! (no ERT, no ESS: the same samples as the yardstick), with the default switches
//! and with ERT alone (skipping off). The volume is the shared T1 MRI (256^3 u8),
//! stored as R8Unorm in every variant (`U8Filtering::Fast`, the yardstick's
//! format); modes DVR, shaded DVR, isosurface and MIP; `--size` (512) px, step
//! `--step` (0.5) voxel, variants interleaved round by round (`--rounds`, 3), each
//! time the median of `prepare + submit + wait` (the yardstick: dispatch + wait).
//!
//! Samples are counted per ray and, as SIMD hardware runs them, per group of 8
//! neighbouring rays of a row costing its longest ray's samples 8 times
//! ("lane-bound"): early termination and skipping save samples of single rays,
//! but a group runs as long as its longest ray.
//!
//! Times are the median over rounds of both wall time and the process's CPU
//! time (lavapipe rasterises on threads of this process); rates and ratios use
//! CPU time, which moves far less than wall time when other work shares the
//! machine (`*_wall` figures give the wall-time versions of the main ratios).
//!
//! Reports per mode: samples per ray and ms of every variant; the useful rate
//! ratio (brickray brute-force samples per second / the yardstick's, in core and
//! out of core); the rate per sample taken with the default switches relative to
//! brute force; out of core / in core with the default switches; default /
//! skipping off.
//!
//! `cargo run --release -p brickray-bench -- raw [--size PX] [--rounds N] [--step S]
//! [--modes dvr,dvr_shaded,iso,mip]`

mod kernel;

use crate::report::{RunInfo, interleave};
use crate::runner::{Runner, finest_ooc_renderer, median, round2};
use brickray_core::{
    Accel, Camera, RenderMode, RenderSettings, Shading, TransferFunction, VolumeFrame,
};
use brickray_harness::{GpuContext, target_desc};
use brickray_render::{RendererOptions, U8Filtering, VolumeRenderer};
use kernel::{MODES, RawKernel};
use serde::Serialize;

/// The suite's options.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Image side in pixels.
    #[arg(long, default_value_t = 512, value_parser = crate::image_side)]
    size: u32,
    /// Interleaved rounds.
    #[arg(long, default_value_t = 3, value_parser = crate::at_least_one::<usize>)]
    rounds: usize,
    /// Step in voxels.
    #[arg(long, default_value_t = 0.5)]
    step: f32,
    /// Modes, comma-separated, of dvr, dvr_shaded, iso, mip.
    #[arg(long, default_value = "dvr,dvr_shaded,iso,mip")]
    modes: String,
}

/// One variant in one mode.
#[derive(Debug, Serialize)]
pub(crate) struct VariantRow {
    /// raw_tex, raw_buf (the minimal kernel), in_/ooc_ brute, default, noskip.
    variant: &'static str,
    /// Median wall and process CPU time, ms.
    ms: f64,
    cpu_ms: f64,
    /// Median time of the ray-cast pass by GPU timestamps (null without,
    /// and for the minimal kernel).
    gpu_ms: Option<f64>,
    samples_per_pixel: f64,
    lane_samples_per_pixel: f64,
}

/// Rates per sample (samples per CPU ms) as ratios, one mode.
#[derive(Debug, Serialize)]
pub(crate) struct Ratios {
    /// In core brute force (out of core brute force; the minimal kernel
    /// with a buffer TF) against the minimal kernel.
    useful_rate_ratio: f64,
    useful_rate_ratio_ooc: f64,
    buffer_tf_rate_ratio: f64,
    /// Default accelerations against brute force, per sample and per
    /// lane-bound sample; in core and out of core.
    accel_rate_per_sample: f64,
    accel_rate_per_sample_ooc: f64,
    accel_lane_rate: f64,
    accel_lane_rate_ooc: f64,
    /// CPU time ratios: out of core over in core (default, brute), default
    /// over no skipping (in core, out of core).
    ooc_vs_incore: f64,
    ooc_vs_incore_brute: f64,
    default_vs_noskip: f64,
    default_vs_noskip_ooc: f64,
    /// The useful rate and the out-of-core ratio by wall time.
    useful_rate_ratio_wall: f64,
    ooc_vs_incore_wall: f64,
}

/// One mode.
#[derive(Debug, Serialize)]
pub(crate) struct ModeResult {
    mode: &'static str,
    variants: Vec<VariantRow>,
    ratios: Ratios,
}

/// The suite's JSON line.
#[derive(Debug, Serialize)]
pub(crate) struct RawResult {
    #[serde(flatten)]
    run: RunInfo,
    step_voxels: f32,
    modes: Vec<ModeResult>,
}

/// The variants, in the order of the table.
const VARIANTS: [&str; 8] = [
    "raw_tex",
    "raw_buf",
    "in_brute",
    "ooc_brute",
    "in_default",
    "ooc_default",
    "in_noskip",
    "ooc_noskip",
];

const ISOVALUE: f32 = 0.3;

/// One run of a variant: wall ms, CPU ms, ray-cast pass ms by timestamps,
/// samples and lane-bound samples (when counted).
type Run = (f64, f64, Option<f64>, u64, u64);
const REFINE_STEPS: u32 = 6;

fn settings(mode: usize, step: f32, accel: Accel) -> RenderSettings {
    RenderSettings {
        mode: if mode == 2 {
            RenderMode::Iso {
                value: ISOVALUE,
                color: [0.9, 0.8, 0.7],
            }
        } else if mode == 3 {
            RenderMode::Mip
        } else {
            RenderMode::Dvr
        },
        shading: Shading {
            enabled: mode == 1,
            ..Default::default()
        },
        step_factor: step,
        iso_refine_steps: REFINE_STEPS,
        accel,
        ..Default::default()
    }
}

fn accel_of(variant: &str) -> Accel {
    if variant.ends_with("brute") {
        Accel::BRUTE_FORCE
    } else if variant.ends_with("noskip") {
        Accel {
            empty_space_skipping: false,
            ..Accel::default()
        }
    } else {
        Accel::default()
    }
}

pub(crate) fn run(args: &Args) -> Result<RawResult, String> {
    let (size, rounds, step, only) = (args.size, args.rounds, args.step, &args.modes);
    // The shared volume, or a procedural stand-in in a clone without it.
    let (vol, volume) = brickray_harness::stand_in::mri_or_phantom()?;
    println!("volume: {volume}");
    let gpu = GpuContext::new().map_err(|e| e.to_string())?;
    println!("adapter: {}", gpu.describe());
    let d = vol.desc().clone();
    println!(
        "volume: T1 MRI {:?} {}; {size}x{size}, step {step} voxel, {rounds} interleaved rounds",
        d.dims,
        d.dtype.name()
    );
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let camera = Camera::orbit(frame.center(), 2.0, 0.7, 0.35);
    let options = RendererOptions {
        u8_filtering: U8Filtering::Fast,
        ..Default::default()
    };
    let mut incore = VolumeRenderer::with_options(&gpu.device, target_desc(), options)
        .map_err(|e| e.to_string())?;
    incore
        .set_volume(&gpu.device, &gpu.queue, &vol)
        .map_err(|e| e.to_string())?;
    let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
    let source = brickray_harness::store_of(&vol, &dir.path().join("mri.brs"));
    let mut ooc = finest_ooc_renderer(&gpu, source, options)?;
    let mut raw = RawKernel::new(&gpu, &vol, size)?;
    let run = Runner::new(&gpu, size)?;
    let dvr_tf = TransferFunction::from_points(
        &[
            (0.15, [0.2, 0.4, 1.0, 0.0]),
            (0.3, [0.3, 0.7, 1.0, 0.05]),
            (0.5, [1.0, 0.8, 0.4, 0.15]),
            (0.9, [1.0, 1.0, 1.0, 0.6]),
        ],
        256,
    );
    let mip_tf = TransferFunction::ramp(0.2, 0.9, 1.0);
    let mut modes = Vec::new();
    println!(
        "\n| mode | variant | samples/ray | lane-bound samples/ray | wall ms | CPU ms | Msamples/CPU s | rate / yardstick | lane-bound rate / yardstick |\n|---|---|---:|---:|---:|---:|---:|---:|---:|"
    );
    for (m, &(mode, _)) in MODES.iter().enumerate() {
        if !only.split(',').any(|o| o == mode) {
            continue;
        }
        let tf = if m == 3 { &mip_tf } else { &dvr_tf };
        for r in [&mut incore, &mut ooc] {
            r.set_transfer_function(&gpu.device, &gpu.queue, tf)
                .map_err(|e| e.to_string())?;
        }
        // MIP maps the maximum through the TF uncorrected.
        let table = tf.corrected_table(if m == 3 { 1.0 } else { step }, 1, 8192);
        raw.set_tf(&gpu, &table.texels);
        raw.set_view(&gpu, &camera, &frame, step, ISOVALUE, REFINE_STEPS)?;
        let (frames, stats) = run.converge(
            &mut ooc,
            camera,
            frame,
            settings(m, step, Accel::default()),
            400,
        )?;
        frames.ok_or_else(|| format!("{mode}: out of core did not converge: {stats:?}"))?;
        if let Some(share) = stats.dvr_transparent_share {
            println!(
                "| {mode} | (out of core: the drawn bricks' sub-cells transparent through the TF, {share:.3}; DVR skips from {:.3} at this step, shaded from {:.3}) | | | | | | | |",
                brickray_core::DVR_SKIP_SHARE_MIN_BRICKS.at(step),
                brickray_core::DVR_SHADED_SKIP_SHARE_MIN_BRICKS.at(step)
            );
        }
        // One counted frame per variant (also the warm-up), then timed rounds.
        let mut samples = [0u64; VARIANTS.len()];
        let mut lanes = [0u64; VARIANTS.len()];
        let mut one =
            |i: usize, count: bool| -> Result<(f64, f64, Option<f64>, u64, u64), String> {
                let v = VARIANTS[i];
                match v {
                    "raw_tex" | "raw_buf" => {
                        let (w, c, n, l) = raw.run(&gpu, m, v == "raw_tex", count);
                        Ok((w, c, None, n, l))
                    }
                    _ => {
                        let r = if v.starts_with("in_") {
                            &mut incore
                        } else {
                            &mut ooc
                        };
                        let shot =
                            run.frame(r, camera, frame, settings(m, step, accel_of(v)), count)?;
                        Ok((
                            shot.ms,
                            shot.cpu_ms,
                            shot.gpu_ms,
                            shot.total_samples,
                            shot.lane_samples,
                        ))
                    }
                }
            };
        for i in 0..VARIANTS.len() {
            (_, _, _, samples[i], lanes[i]) = one(i, true)?;
        }
        let times = interleave(rounds, VARIANTS.len(), |i| one(i, false))?;
        let of = |f: &dyn Fn(&Run) -> f64| -> Vec<f64> {
            times
                .iter()
                .map(|t| median(&t.iter().map(f).collect::<Vec<_>>()))
                .collect()
        };
        let wall = of(&|t| t.0);
        // Rates and ratios from the process's CPU time: on this shared 2-core
        // machine wall time moved by up to 2x between variants of one round.
        let ms = of(&|t| t.1);
        let gpu: Vec<Option<f64>> = times
            .iter()
            .map(|t| {
                let g: Vec<f64> = t.iter().filter_map(|x| x.2).collect();
                (!g.is_empty()).then(|| round2(median(&g)))
            })
            .collect();
        let mut variants = Vec::new();
        let rays = size as f64 * size as f64;
        let rate = |i: usize| samples[i] as f64 / ms[i];
        let lane_rate = |i: usize| lanes[i] as f64 / ms[i];
        for (i, v) in VARIANTS.iter().enumerate() {
            println!(
                "| {mode} | {v} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.3} | {:.3} |",
                samples[i] as f64 / rays,
                lanes[i] as f64 / rays,
                wall[i],
                ms[i],
                rate(i) / 1e3,
                rate(i) / rate(0),
                lane_rate(i) / lane_rate(0)
            );
            variants.push(VariantRow {
                variant: v,
                ms: round2(wall[i]),
                cpu_ms: round2(ms[i]),
                gpu_ms: gpu[i],
                samples_per_pixel: round2(samples[i] as f64 / rays),
                lane_samples_per_pixel: round2(lanes[i] as f64 / rays),
            });
        }
        let ix = |name: &str| VARIANTS.iter().position(|v| *v == name).expect("variant");
        let r3 = |x: f64| (x * 1000.0).round() / 1000.0;
        let ratios = Ratios {
            useful_rate_ratio: r3(rate(ix("in_brute")) / rate(0)),
            useful_rate_ratio_ooc: r3(rate(ix("ooc_brute")) / rate(0)),
            buffer_tf_rate_ratio: r3(rate(ix("raw_buf")) / rate(0)),
            accel_rate_per_sample: r3(rate(ix("in_default")) / rate(ix("in_brute"))),
            accel_rate_per_sample_ooc: r3(rate(ix("ooc_default")) / rate(ix("ooc_brute"))),
            accel_lane_rate: r3(lane_rate(ix("in_default")) / lane_rate(ix("in_brute"))),
            accel_lane_rate_ooc: r3(lane_rate(ix("ooc_default")) / lane_rate(ix("ooc_brute"))),
            ooc_vs_incore: r3(ms[ix("ooc_default")] / ms[ix("in_default")]),
            ooc_vs_incore_brute: r3(ms[ix("ooc_brute")] / ms[ix("in_brute")]),
            default_vs_noskip: r3(ms[ix("in_default")] / ms[ix("in_noskip")]),
            default_vs_noskip_ooc: r3(ms[ix("ooc_default")] / ms[ix("ooc_noskip")]),
            useful_rate_ratio_wall: r3(samples[ix("in_brute")] as f64
                / wall[ix("in_brute")]
                / (samples[0] as f64 / wall[0])),
            ooc_vs_incore_wall: r3(wall[ix("ooc_default")] / wall[ix("in_default")]),
        };
        println!("  {mode}: {ratios:?}");
        modes.push(ModeResult {
            mode,
            variants,
            ratios,
        });
    }
    Ok(RawResult {
        run: RunInfo::new(&gpu, size, rounds, volume),
        step_voxels: step,
        modes,
    })
}
