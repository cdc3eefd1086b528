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
use brickray_core::{
    Accel, Camera, RenderMode, RenderSettings, Shading, TransferFunction, Volume, VolumeFrame,
};
use brickray_harness::{GpuContext, Offscreen, ct};
use brickray_render::{FrameDesc, VolumeRenderer};
use serde_json::json;
use std::time::Instant;

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

struct Bench<'a> {
    gpu: &'a GpuContext,
    renderer: VolumeRenderer,
    target: Offscreen,
    frame: VolumeFrame,
    camera: Camera,
    size: u32,
}

impl Bench<'_> {
    /// One frame: returns (ms, RGBA8, mean samples per entering ray).
    fn frame(
        &mut self,
        settings: RenderSettings,
        read: bool,
    ) -> Result<(f64, Vec<u8>, f64), String> {
        let g = self.gpu;
        let t0 = Instant::now();
        let mut enc = g.device.create_command_encoder(&Default::default());
        let desc = FrameDesc {
            camera: self.camera,
            frame: self.frame,
            viewport: brickray_render::Viewport::full(self.size, self.size),
            settings,
            host_depth: None,
        };
        self.renderer
            .prepare(&g.device, &g.queue, &mut enc, &desc)
            .map_err(|e| e.to_string())?;
        {
            let mut pass = self.target.pass(&mut enc, true);
            self.renderer.render(&mut pass).map_err(|e| e.to_string())?;
        }
        g.submit_wait(enc);
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        if !read {
            return Ok((ms, Vec::new(), 0.0));
        }
        let rgba = self.target.read_color(g);
        let tex = self
            .renderer
            .sample_count_texture()
            .ok_or("no sample counts")?;
        let counts = brickray_harness::read_texture(g, tex, 4, wgpu::TextureAspect::All);
        let counts: Vec<u32> = counts
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        let entering: Vec<u32> = counts.iter().copied().filter(|&c| c > 0).collect();
        let mean = entering.iter().map(|&c| c as f64).sum::<f64>() / entering.len().max(1) as f64;
        Ok((ms, rgba, mean))
    }
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

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
    let mut bench = Bench {
        gpu: &gpu,
        renderer,
        target: Offscreen::new(&gpu.device, size, size),
        frame,
        camera: Camera::orbit(frame.center(), 2.0, 0.5, 0.3),
        size,
    };
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
        bench
            .renderer
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
            let (_, rgba, s) = bench.frame(settings(accel), true)?;
            images.push(rgba);
            samples.push(s);
        }
        // Timing: rounds of all variants, the order rotated each round.
        let mut times = vec![Vec::new(); VARIANTS.len()];
        for r in 0..rounds {
            for k in 0..VARIANTS.len() {
                let i = (k + r) % VARIANTS.len();
                let (ms, _, _) = bench.frame(settings(VARIANTS[i].1), false)?;
                times[i].push(ms);
            }
        }
        let ms: Vec<f64> = times.iter_mut().map(|t| median(t)).collect();
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
                fig.insert(
                    format!("psnr_{name}_{scene}_db"),
                    json!(if psnr.is_finite() {
                        round2(psnr)
                    } else {
                        999.0
                    }),
                );
            }
        }
    }
    fig.insert(
        "psnr_min_db".into(),
        json!(if psnr_min.is_finite() {
            round2(psnr_min)
        } else {
            999.0
        }),
    );
    fig.insert("image_size".into(), json!(size));
    fig.insert("rounds".into(), json!(rounds));
    fig.insert("adapter".into(), json!(gpu.adapter.get_info().name));
    Ok(fig)
}

fn round2(x: f64) -> f64 {
    (x * 100.0).round() / 100.0
}
