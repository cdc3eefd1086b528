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

use crate::runner::{Runner, finest_ooc_renderer, median, round2};
use crate::{Figures, arg};
use brickray_core::{
    Accel, Camera, RenderMode, RenderSettings, Shading, TransferFunction, VolumeFrame,
};
use brickray_harness::{GpuContext, target_desc};
use brickray_render::{RendererOptions, U8Filtering, VolumeRenderer};
use kernel::{MODES, RawKernel};
use serde_json::json;

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

pub(crate) fn run(args: &[String]) -> Result<Figures, String> {
    let size: u32 = arg(args, "--size", 512)?;
    let rounds: usize = arg(args, "--rounds", 3)?.max(1);
    let step: f32 = arg(args, "--step", 0.5)?;
    let only: String = arg(args, "--modes", "dvr,dvr_shaded,iso,mip".to_string())?;
    let path = brickray_harness::shared_volume("pycortex_s1_t1_mri")
        .ok_or("the raw suite needs ../shared/data/pycortex_s1_t1_mri")?;
    let vol = brickray_io::read_volume(&path).map_err(|e| e.to_string())?;
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
    let mut fig = Figures::new();
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
        // One counted frame per variant (also the warm-up), then timed rounds.
        let mut samples = [0u64; VARIANTS.len()];
        let mut lanes = [0u64; VARIANTS.len()];
        let mut one = |i: usize, count: bool| -> Result<(f64, f64, u64, u64), String> {
            let v = VARIANTS[i];
            match v {
                "raw_tex" | "raw_buf" => Ok(raw.run(&gpu, m, v == "raw_tex", count)),
                _ => {
                    let r = if v.starts_with("in_") {
                        &mut incore
                    } else {
                        &mut ooc
                    };
                    let shot =
                        run.frame(r, camera, frame, settings(m, step, accel_of(v)), count)?;
                    Ok((shot.ms, shot.cpu_ms, shot.total_samples, shot.lane_samples))
                }
            }
        };
        for i in 0..VARIANTS.len() {
            (_, _, samples[i], lanes[i]) = one(i, true)?;
        }
        let mut wall = vec![Vec::new(); VARIANTS.len()];
        let mut cpu = vec![Vec::new(); VARIANTS.len()];
        for round in 0..rounds {
            for k in 0..VARIANTS.len() {
                let i = (k + round) % VARIANTS.len();
                let (w, c, _, _) = one(i, false)?;
                wall[i].push(w);
                cpu[i].push(c);
            }
        }
        let wall: Vec<f64> = wall.iter().map(|t| median(t)).collect();
        // Rates and ratios from the process's CPU time: on this shared 2-core
        // machine wall time moved by up to 2x between variants of one round.
        let ms: Vec<f64> = cpu.iter().map(|t| median(t)).collect();
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
            fig.insert(format!("ms_{v}_{mode}"), json!(round2(wall[i])));
            fig.insert(format!("cpu_ms_{v}_{mode}"), json!(round2(ms[i])));
            fig.insert(
                format!("samples_per_pixel_{v}_{mode}"),
                json!(round2(samples[i] as f64 / rays)),
            );
        }
        let ix = |name: &str| VARIANTS.iter().position(|v| *v == name).expect("variant");
        let entries = [
            ("useful_rate_ratio", rate(ix("in_brute")) / rate(0)),
            ("useful_rate_ratio_ooc", rate(ix("ooc_brute")) / rate(0)),
            ("buffer_tf_rate_ratio", rate(ix("raw_buf")) / rate(0)),
            (
                "accel_rate_per_sample",
                rate(ix("in_default")) / rate(ix("in_brute")),
            ),
            (
                "accel_rate_per_sample_ooc",
                rate(ix("ooc_default")) / rate(ix("ooc_brute")),
            ),
            (
                "accel_lane_rate",
                lane_rate(ix("in_default")) / lane_rate(ix("in_brute")),
            ),
            (
                "accel_lane_rate_ooc",
                lane_rate(ix("ooc_default")) / lane_rate(ix("ooc_brute")),
            ),
            (
                "ooc_vs_incore",
                ms[ix("ooc_default")] / ms[ix("in_default")],
            ),
            (
                "ooc_vs_incore_brute",
                ms[ix("ooc_brute")] / ms[ix("in_brute")],
            ),
            (
                "default_vs_noskip",
                ms[ix("in_default")] / ms[ix("in_noskip")],
            ),
            (
                "default_vs_noskip_ooc",
                ms[ix("ooc_default")] / ms[ix("ooc_noskip")],
            ),
            (
                "useful_rate_ratio_wall",
                samples[ix("in_brute")] as f64
                    / wall[ix("in_brute")]
                    / (samples[0] as f64 / wall[0]),
            ),
            (
                "ooc_vs_incore_wall",
                wall[ix("ooc_default")] / wall[ix("in_default")],
            ),
        ];
        print!("  {mode}:");
        for (name, value) in entries {
            print!(" {name} {value:.3};");
            fig.insert(
                format!("{name}_{mode}"),
                json!((value * 1000.0).round() / 1000.0),
            );
        }
        println!();
    }
    fig.insert("image_size".into(), json!(size));
    fig.insert("step_voxels".into(), json!(step));
    fig.insert("rounds".into(), json!(rounds));
    fig.insert("adapter".into(), json!(gpu.adapter.get_info().name));
    Ok(fig)
}
