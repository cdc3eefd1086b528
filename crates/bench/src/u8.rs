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

use crate::runner::median;
use crate::{Figures, arg};
use brickray_core::{Camera, RenderMode, RenderSettings, Shading, TransferFunction, VolumeFrame};
use brickray_harness::{GpuContext, Offscreen, draw_frame};
use brickray_reference::{DEFAULT_STEP_FACTOR, ReferenceOptions, compare, render_reference};
use brickray_render::{FrameDesc, RendererOptions, U8Filtering, VolumeRenderer};
use serde_json::json;
use std::time::Instant;

pub(crate) fn run(args: &[String]) -> Result<Figures, String> {
    let size: u32 = arg(args, "--size", 512)?;
    let rounds: usize = arg(args, "--rounds", 5)?;
    let path = brickray_harness::shared_volume("pycortex_s1_t1_mri")
        .ok_or("the u8 suite needs ../shared/data/pycortex_s1_t1_mri")?;
    let vol = brickray_io::read_volume(&path).map_err(|e| e.to_string())?;
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
    let scenes = [
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
    let big = Offscreen::new(&gpu.device, size, size);
    let small_size = 192;
    let small = Offscreen::new(&gpu.device, small_size, small_size);
    let mut fig = Figures::new();
    println!(
        "| scene | exact ms | fast ms | exact / fast | PSNR exact / fast (dB) | same-step PSNR exact / fast (dB) |"
    );
    println!("|---|---:|---:|---:|---:|---:|");
    let mut worst_ratio: f64 = 0.0;
    for (scene, settings, tf) in &scenes {
        for (_, r) in renderers.iter_mut() {
            r.set_transfer_function(&gpu.device, &gpu.queue, tf)
                .map_err(|e| e.to_string())?;
        }
        let desc = FrameDesc {
            settings: *settings,
            ..FrameDesc::new(camera, frame, size, size)
        };
        // Warm-up (pipeline compilation), then interleaved rounds.
        let mut times = vec![Vec::new(); renderers.len()];
        for round in 0..=rounds {
            for k in 0..renderers.len() {
                let i = (k + round) % renderers.len();
                let t = Instant::now();
                draw_frame(
                    &gpu,
                    &mut renderers[i].1,
                    &big,
                    &desc,
                    Some(wgpu::Color::BLACK),
                )
                .map_err(|e| e.to_string())?;
                if round > 0 {
                    times[i].push(t.elapsed().as_secs_f64() * 1e3);
                }
            }
        }
        let ms: Vec<f64> = times.iter().map(|t| median(t)).collect();
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
        fig.insert(format!("ms_exact_{scene}"), json!(ms[0]));
        fig.insert(format!("ms_fast_{scene}"), json!(ms[1]));
        fig.insert(format!("exact_over_fast_{scene}"), json!(ratio));
        fig.insert(format!("psnr_exact_{scene}_db"), json!(psnr[0]));
        fig.insert(format!("psnr_fast_{scene}_db"), json!(psnr[1]));
        fig.insert(format!("psnr_same_step_exact_{scene}_db"), json!(psnr[2]));
        fig.insert(format!("psnr_same_step_fast_{scene}_db"), json!(psnr[3]));
    }
    fig.insert("exact_over_fast_worst".into(), json!(worst_ratio));
    fig.insert("image_size".into(), json!(size));
    fig.insert("rounds".into(), json!(rounds));
    fig.insert("adapter".into(), json!(gpu.adapter.get_info().name));
    Ok(fig)
}
