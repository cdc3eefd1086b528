//! The `accel` suite: Krueger-Westermann accelerations on the in-core ray caster.
//!
//! Renders the shared head CT at 512x512 with an opaque bone TF and a
//! semi-transparent soft-tissue TF (shaded DVR), plus an isosurface, each with
//! brute force, ERT, ESS and both. Variants are interleaved round by round (the
//! machine's speed drifts) and each one's time is the median over rounds of
//! `prepare + submit + wait` wall time. Reports samples per ray (mean over the
//! rays that enter the volume), ms per frame, speedups over brute force and PSNR
//! against the brute-force image.

use crate::report::{RunInfo, Timing, interleave};
use crate::runner::{Runner, finite_db, round2};
use brickray_core::{
    Accel, Camera, RenderMode, RenderSettings, Shading, TransferFunction, VolumeFrame,
};
use brickray_harness::{GpuContext, ct};
use brickray_render::VolumeRenderer;
use serde::Serialize;

const VARIANTS: [(&str, Accel); 4] = [
    ("brute", Accel::BRUTE_FORCE),
    ("ert", Accel::ERT_ONLY),
    ("ess", Accel::ESS_ONLY),
    (
        "ert_ess",
        Accel {
            early_termination: Some(0.99),
            empty_space_skipping: true,
            adaptive_step: false,
        },
    ),
];

/// The suite's options.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Interleaved rounds.
    #[arg(long, default_value_t = 5, value_parser = crate::at_least_one::<usize>)]
    rounds: usize,
    /// Image side in pixels.
    #[arg(long, default_value_t = 512, value_parser = crate::image_side)]
    size: u32,
}

/// One variant of one scene.
#[derive(Debug, Serialize)]
pub(crate) struct Row {
    /// opaque, translucent or iso.
    scene: &'static str,
    /// brute, ert, ess or ert_ess.
    variant: &'static str,
    /// Mean samples per ray over the rays that enter the volume.
    samples_per_ray: f64,
    #[serde(flatten)]
    time: Timing,
    /// Brute force's wall time over this variant's.
    speedup: f64,
    /// Against the brute-force image (999 where identical).
    psnr_db: f64,
}

/// The suite's JSON line.
#[derive(Debug, Serialize)]
pub(crate) struct AccelResult {
    #[serde(flatten)]
    run: RunInfo,
    rows: Vec<Row>,
    /// The smallest PSNR of an accelerated variant against brute force.
    psnr_min_db: f64,
    /// The largest speedup of ERT and ESS together over brute force.
    speedup_ert_ess_max: f64,
}

pub(crate) fn run(args: &Args) -> Result<AccelResult, String> {
    let (rounds, size) = (args.rounds, args.size);
    // The shared volume, or a procedural stand-in in a clone without it.
    let (vol, volume) = brickray_harness::stand_in::head_ct_or_phantom()?;
    println!("volume: {volume}");
    let gpu = GpuContext::new().map_err(|e| e.to_string())?;
    println!("adapter: {}", gpu.describe());
    let d = vol.desc();
    println!(
        "volume: head CT {:?} {} spacing {:?}; image {size}x{size}; {rounds} interleaved rounds",
        d.dims,
        d.dtype.name(),
        d.spacing
    );
    let mut renderer = VolumeRenderer::new(&gpu.device, brickray_harness::target_desc())
        .map_err(|e| e.to_string())?;
    renderer
        .set_volume(&gpu.device, &gpu.queue, &vol)
        .map_err(|e| e.to_string())?;
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let camera = Camera::orbit(frame.center(), 2.0, 0.5, 0.3);
    let run = Runner::new(&gpu, size)?;
    let shading = Shading {
        enabled: true,
        ..Default::default()
    };
    let scenes: [(&'static str, TransferFunction, RenderMode); 3] = [
        ("opaque", ct::bone(), RenderMode::Dvr),
        ("translucent", ct::soft_tissue(), RenderMode::Dvr),
        (
            "iso",
            ct::bone(),
            RenderMode::Iso {
                value: ct::hu(400.0),
                color: [0.9, 0.85, 0.75],
            },
        ),
    ];
    let mut rows = Vec::new();
    let mut psnr_min = f64::INFINITY;
    for (scene, tf, mode) in &scenes {
        renderer
            .set_transfer_function(&gpu.device, &gpu.queue, tf)
            .expect("transfer function");
        let settings = |accel| RenderSettings {
            mode: *mode,
            shading,
            accel,
            ..Default::default()
        };
        // Warm-up and quality pass: one frame per variant, read back.
        let mut images = Vec::new();
        let mut samples = Vec::new();
        for (_, accel) in VARIANTS {
            let shot = run.frame(&mut renderer, camera, frame, settings(accel), true)?;
            images.push(shot.rgba);
            samples.push(shot.samples);
        }
        // Timing: rounds of all variants, the order rotated each round.
        let shots = interleave(rounds, VARIANTS.len(), |i| {
            run.frame(&mut renderer, camera, frame, settings(VARIANTS[i].1), false)
        })?;
        let times: Vec<Timing> = shots.iter().map(|t| Timing::of(t)).collect();
        let ms: Vec<f64> = times.iter().map(|t| t.ms).collect();
        println!("\n{scene} ({mode:?}):");
        println!(
            "  {:<8} {:>12} {:>10} {:>9} {:>10}",
            "variant", "samples/ray", "ms/frame", "speedup", "PSNR dB"
        );
        for (i, (name, _)) in VARIANTS.iter().enumerate() {
            let psnr = brickray_reference::psnr(&images[i], &images[0]);
            if i > 0 {
                psnr_min = psnr_min.min(psnr);
            }
            let speedup = ms[0] / ms[i];
            println!(
                "  {name:<8} {:>12.1} {:>10.1} {:>8.2}x {:>10.2}",
                samples[i], ms[i], speedup, psnr
            );
            rows.push(Row {
                scene,
                variant: name,
                samples_per_ray: round2(samples[i]),
                time: times[i],
                speedup: round2(speedup),
                psnr_db: finite_db(psnr),
            });
        }
    }
    let speedup_ert_ess_max = rows
        .iter()
        .filter(|r| r.variant == "ert_ess")
        .map(|r| r.speedup)
        .fold(0.0, f64::max);
    Ok(AccelResult {
        run: RunInfo::new(&gpu, size, rounds, volume),
        rows,
        psnr_min_db: finite_db(psnr_min),
        speedup_ert_ess_max,
    })
}
