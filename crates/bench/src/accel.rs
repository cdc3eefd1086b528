//! The `accel` suite: Krueger-Westermann accelerations on the in-core ray caster.
//!
//! Renders the shared head CT at 512x512 with an opaque bone TF and a
//! semi-transparent soft-tissue TF (shaded DVR), plus an isosurface, each with
//! brute force, ERT, ESS and both. Variants are interleaved round by round (the
//! machine's speed drifts) and each one's time is the median over rounds of
//! `prepare + submit + wait` wall time. Reports samples per ray (mean over the
//! rays that enter the volume), ms per frame, speedups over brute force and PSNR
//! against the brute-force image.

use crate::Figures;
use crate::runner::{Runner, finite_db, median, round2};
use brickray_core::{
    Accel, Camera, RenderMode, RenderSettings, Shading, TransferFunction, Volume, VolumeFrame,
};
use brickray_harness::{GpuContext, ct};
use brickray_render::VolumeRenderer;
use serde_json::json;

const VARIANTS: [(&str, Accel); 4] = [
    ("brute", Accel::BRUTE_FORCE),
    ("ert", Accel::ERT_ONLY),
    ("ess", Accel::ESS_ONLY),
    (
        "ert_ess",
        Accel {
            early_termination: Some(0.99),
            empty_space_skipping: true,
        },
    ),
];

pub(crate) fn run(args: &[String]) -> Result<Figures, String> {
    let rounds: usize = args
        .iter()
        .position(|a| a == "--rounds")
        .and_then(|i| args.get(i + 1))
        .map(|s| s.parse().map_err(|_| "bad --rounds"))
        .transpose()?
        .unwrap_or(5);
    let size: u32 = args
        .iter()
        .position(|a| a == "--size")
        .and_then(|i| args.get(i + 1))
        .map(|s| s.parse().map_err(|_| "bad --size"))
        .transpose()?
        .unwrap_or(512);
    let path = brickray_harness::shared_volume("invesalius_cranium_ct")
        .ok_or("the accel suite needs ../shared/data/invesalius_cranium_ct")?;
    let vol: Volume = brickray_io::read_volume(&path).map_err(|e| e.to_string())?;
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
    let scenes: [(&str, TransferFunction, RenderMode); 3] = [
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
    let mut fig = Figures::new();
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
        let mut times = vec![Vec::new(); VARIANTS.len()];
        for r in 0..rounds {
            for k in 0..VARIANTS.len() {
                let i = (k + r) % VARIANTS.len();
                let shot =
                    run.frame(&mut renderer, camera, frame, settings(VARIANTS[i].1), false)?;
                times[i].push(shot.ms);
            }
        }
        let ms: Vec<f64> = times.iter().map(|t| median(t)).collect();
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
            fig.insert(format!("ms_{name}_{scene}"), json!(round2(ms[i])));
            fig.insert(
                format!("samples_per_ray_{name}_{scene}"),
                json!(round2(samples[i])),
            );
            if i > 0 {
                fig.insert(format!("speedup_{name}_{scene}"), json!(round2(speedup)));
                fig.insert(format!("psnr_{name}_{scene}_db"), json!(finite_db(psnr)));
            }
        }
    }
    fig.insert("psnr_min_db".into(), json!(finite_db(psnr_min)));
    fig.insert("image_size".into(), json!(size));
    fig.insert("rounds".into(), json!(rounds));
    fig.insert("adapter".into(), json!(gpu.adapter.get_info().name));
    Ok(fig)
}
