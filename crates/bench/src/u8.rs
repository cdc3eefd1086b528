//! The `u8` suite: the cost and the accuracy of exact u8 interpolation.
//!
//! The shared T1 MRI (256^3 u8), in core, rendered by two renderers that differ
//! only in `RendererOptions::u8_filtering`: `Exact` (16-bit texels, R16Unorm,
//! filtered exactly) and `Fast` (R8Unorm, which lavapipe and GPUs filter in 8-bit
//! fixed point). Three scenes (shaded translucent DVR, an isosurface, MIP) with the
//! default switches. Timing: `--size` (512) px, frames of the two interleaved
//! round by round (`--rounds`, 5), median of `prepare + submit + wait`. Accuracy:
//! PSNR of each against the CPU reference (f64, exact trilinear) at 192 px, at the
//! default step and at the reference's step (where both take the same samples and
//! only the interpolation differs).
//!
//! `cargo run --release -p brickray-bench -- u8 [--size PX] [--rounds N]`

use crate::report::{RunInfo, Timing, interleave};
use crate::runner::{Runner, round2};
use brickray_core::{Camera, RenderMode, RenderSettings, Shading, TransferFunction, VolumeFrame};
use brickray_harness::{GpuContext, Offscreen, draw_frame};
use brickray_reference::{DEFAULT_STEP_FACTOR, ReferenceOptions, compare, render_reference};
use brickray_render::{FrameDesc, RendererOptions, U8Filtering, VolumeRenderer};
use serde::Serialize;

/// The suite's options.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Image side in pixels.
    #[arg(long, default_value_t = 512, value_parser = crate::image_side)]
    size: u32,
    /// Interleaved rounds.
    #[arg(long, default_value_t = 5, value_parser = crate::at_least_one::<usize>)]
    rounds: usize,
}

/// One scene: exact against 8-bit (fast) filtering.
#[derive(Debug, Serialize)]
pub(crate) struct Row {
    /// dvr, iso or mip.
    scene: &'static str,
    exact: Timing,
    fast: Timing,
    /// Exact wall time over fast.
    exact_over_fast: f64,
    /// Against the reference at the scene's step (192 px).
    psnr_exact_db: f64,
    psnr_fast_db: f64,
    /// Against the reference at the reference's own step.
    psnr_same_step_exact_db: f64,
    psnr_same_step_fast_db: f64,
}

/// The suite's JSON line.
#[derive(Debug, Serialize)]
pub(crate) struct U8Result {
    #[serde(flatten)]
    run: RunInfo,
    rows: Vec<Row>,
    /// The largest exact over fast ratio.
    exact_over_fast_worst: f64,
}

pub(crate) fn run(args: &Args) -> Result<U8Result, String> {
    let (size, rounds) = (args.size, args.rounds);
    // The shared volume, or a procedural stand-in in a clone without it.
    let (vol, volume) = brickray_harness::stand_in::mri_or_phantom()?;
    println!("volume: {volume}");
    let gpu = GpuContext::new().map_err(|e| e.to_string())?;
    println!("adapter: {}", gpu.describe());
    println!(
        "volume: T1 MRI {:?} u8; timing at {size}x{size}, {rounds} interleaved rounds",
        vol.dims()
    );
    let d = vol.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let camera = Camera::orbit(frame.center(), 2.0, 0.7, 0.35);
    let targets = brickray_harness::target_desc();
    let mut renderers = Vec::new();
    for (name, u8_filtering) in [("exact", U8Filtering::Exact), ("fast", U8Filtering::Fast)] {
        let options = RendererOptions {
            u8_filtering,
            ..Default::default()
        };
        let mut r = VolumeRenderer::with_options(&gpu.device, targets, options)
            .map_err(|e| e.to_string())?;
        r.set_volume(&gpu.device, &gpu.queue, &vol)
            .map_err(|e| e.to_string())?;
        println!(
            "  {name}: {:?}, {} MiB",
            r.volume_format(),
            r.volume_bytes() >> 20
        );
        renderers.push((name, r));
    }
    let scenes: [(&'static str, RenderSettings, TransferFunction); 3] = [
        (
            "dvr",
            RenderSettings {
                mode: RenderMode::Dvr,
                shading: Shading {
                    enabled: true,
                    ..Default::default()
                },
                ..Default::default()
            },
            TransferFunction::from_points(
                &[
                    (0.15, [0.2, 0.4, 1.0, 0.0]),
                    (0.3, [0.3, 0.7, 1.0, 0.05]),
                    (0.5, [1.0, 0.8, 0.4, 0.15]),
                    (0.9, [1.0, 1.0, 1.0, 0.6]),
                ],
                256,
            ),
        ),
        (
            "iso",
            RenderSettings {
                mode: RenderMode::Iso {
                    value: 0.3,
                    color: [0.9, 0.8, 0.7],
                },
                ..Default::default()
            },
            TransferFunction::ramp(0.0, 1.0, 1.0),
        ),
        (
            "mip",
            RenderSettings {
                mode: RenderMode::Mip,
                ..Default::default()
            },
            TransferFunction::ramp(0.2, 0.9, 1.0),
        ),
    ];
    let big = Runner::new(&gpu, size)?;
    let small_size = 192;
    let small = Offscreen::new(&gpu.device, small_size, small_size);
    let mut rows = Vec::new();
    println!(
        "| scene | exact ms | fast ms | exact / fast | PSNR exact / fast (dB) | same-step PSNR exact / fast (dB) |"
    );
    println!("|---|---:|---:|---:|---:|---:|");
    let mut worst_ratio: f64 = 0.0;
    for (scene, settings, tf) in &scenes {
        let scene = *scene;
        for (_, r) in renderers.iter_mut() {
            r.set_transfer_function(&gpu.device, &gpu.queue, tf)
                .map_err(|e| e.to_string())?;
        }
        // Warm-up (pipeline compilation), then interleaved rounds.
        for (_, r) in renderers.iter_mut() {
            big.frame(r, camera, frame, *settings, false)?;
        }
        let shots = interleave(rounds, renderers.len(), |i| {
            big.frame(&mut renderers[i].1, camera, frame, *settings, false)
        })?;
        let times: Vec<Timing> = shots.iter().map(|t| Timing::of(t)).collect();
        let ms: Vec<f64> = times.iter().map(|t| t.ms).collect();
        // Accuracy against the reference, at the default step and at its own.
        let mut psnr = Vec::new();
        for step in [settings.step_factor, DEFAULT_STEP_FACTOR] {
            let s = RenderSettings {
                step_factor: step,
                ..*settings
            };
            let reference = render_reference(
                &vol,
                &frame,
                tf,
                &camera,
                &s,
                &ReferenceOptions::new(small_size, small_size),
            )
            .to_rgba8([0.0; 3]);
            for (_, r) in renderers.iter_mut() {
                let desc = FrameDesc {
                    settings: s,
                    ..FrameDesc::new(camera, frame, small_size, small_size)
                };
                draw_frame(&gpu, r, &small, &desc, Some(wgpu::Color::BLACK))
                    .map_err(|e| e.to_string())?;
                let img = small.read_color(&gpu);
                psnr.push(compare(&img, &reference, small_size, small_size).psnr_db);
            }
        }
        let ratio = ms[0] / ms[1];
        worst_ratio = worst_ratio.max(ratio);
        println!(
            "| {scene} | {:.1} | {:.1} | {ratio:.3} | {:.2} / {:.2} | {:.2} / {:.2} |",
            ms[0], ms[1], psnr[0], psnr[1], psnr[2], psnr[3]
        );
        rows.push(Row {
            scene,
            exact: times[0],
            fast: times[1],
            exact_over_fast: round2(ratio),
            psnr_exact_db: round2(psnr[0]),
            psnr_fast_db: round2(psnr[1]),
            psnr_same_step_exact_db: round2(psnr[2]),
            psnr_same_step_fast_db: round2(psnr[3]),
        });
    }
    Ok(U8Result {
        run: RunInfo::new(&gpu, size, rounds, volume),
        rows,
        exact_over_fast_worst: round2(worst_ratio),
    })
}
