//! Pre-integrated against plain DVR on the `pareto` suite's scenes at every
//! step from 1/8 to 4 voxels, shaded and not: PSNR of each image against the
//! exact integral (the CPU reference at a step of 1/64 voxel, fine enough to
//! tell the two apart at 1/8), for the GPU in core and for the CPU reference's
//! own model.

use crate::pareto::{ML_SIDE, scenes::scenes};
use crate::runner::{Runner, finite_db};
use brickray_core::{RenderMode, RenderSettings};
use brickray_harness::GpuContext;
use brickray_reference::{ReferenceOptions, psnr, render_reference};
use brickray_render::VolumeRenderer;
use serde::Serialize;

/// The steps compared, in voxels.
pub(crate) const STEPS: [f32; 6] = [0.125, 0.25, 0.5, 1.0, 2.0, 4.0];

/// One scene, shading and step: PSNR against the exact integral.
#[derive(Debug, Serialize)]
pub(crate) struct SceneRow {
    scene: &'static str,
    shaded: bool,
    step: f32,
    gpu_plain_db: f64,
    gpu_preint_db: f64,
    cpu_plain_db: f64,
    cpu_preint_db: f64,
}

impl SceneRow {
    /// Pre-integrated minus plain on the GPU, dB.
    pub(crate) fn gpu_gain_db(&self) -> f64 {
        self.gpu_preint_db - self.gpu_plain_db
    }
}

/// The rows of the scenes `wanted` (all when empty) that are present (the
/// shared ones are left out, and named in the second list, where `../shared`
/// is missing), images `size` pixels on a side, the exact integral at
/// `1 / exact_div` voxel; the GPU's images without early ray termination
/// when `unterminated`.
pub(crate) fn rows(
    gpu: &GpuContext,
    wanted: &[String],
    size: u32,
    exact_div: u32,
    unterminated: bool,
) -> Result<(Vec<SceneRow>, Vec<String>), String> {
    let run = Runner::new(gpu, size)?;
    let (mut out, mut missing) = (Vec::new(), Vec::new());
    println!(
        "pareto scenes' DVR, {size}x{size}, PSNR against the exact integral (1/{exact_div} voxel), plain / pre-integrated{}:",
        if unterminated {
            ", no early termination"
        } else {
            ""
        }
    );
    println!(
        "  {:<7} {:<7} {}",
        "scene",
        "shaded",
        STEPS.map(|s| format!("{s:>21}")).join("")
    );
    let names = ["ml", "noise", "ct", "ct5", "mri", "nuclei"];
    for name in names
        .into_iter()
        .filter(|n| wanted.is_empty() || wanted.iter().any(|w| w == n))
    {
        let scene = match scenes(&[name.to_string()], ML_SIDE) {
            Ok(mut s) => s.remove(0),
            Err(e) => {
                println!("  {name}: left out ({e})");
                missing.push(name.to_string());
                continue;
            }
        };
        let Some((_, _, tf)) = scene.modes.iter().find(|m| matches!(m.1, RenderMode::Dvr)) else {
            continue;
        };
        let mut r = VolumeRenderer::new(&gpu.device, brickray_harness::target_desc())
            .map_err(|e| e.to_string())?;
        r.set_volume(&gpu.device, &gpu.queue, &scene.volume)
            .map_err(|e| e.to_string())?;
        r.set_transfer_function(&gpu.device, &gpu.queue, tf)
            .map_err(|e| e.to_string())?;
        for shaded in [false, true] {
            let settings = |step, preintegrated| {
                let mut s = super::dvr(step, preintegrated, shaded);
                if unterminated {
                    s.accel.early_termination = None;
                }
                s
            };
            let cpu = |o: ReferenceOptions<'_>, s: &RenderSettings| {
                render_reference(&scene.volume, &scene.frame, tf, &scene.camera, s, &o)
                    .to_rgba8([0.0; 3])
            };
            let opts = ReferenceOptions::new(size, size);
            let exact = cpu(
                opts.with_step_factor(1.0 / exact_div as f32),
                &settings(1.0, false),
            );
            let mut line = format!("  {:<7} {:<7}", scene.name, shaded);
            for step in STEPS {
                let mut db = [0.0f64; 4];
                for (i, p) in [false, true].into_iter().enumerate() {
                    let s = settings(step, p);
                    let shot = run.frame(&mut r, scene.camera, scene.frame, s, true)?;
                    db[i] = psnr(&shot.rgba, &exact);
                    let o = opts.with_step_factor(step).with_preintegration(p);
                    db[2 + i] = psnr(&cpu(o, &s), &exact);
                }
                line += &format!("  {:>6.2}/{:>6.2} ({:+.2})", db[0], db[1], db[1] - db[0]);
                out.push(SceneRow {
                    scene: scene.name,
                    shaded,
                    step,
                    gpu_plain_db: finite_db(db[0]),
                    gpu_preint_db: finite_db(db[1]),
                    cpu_plain_db: finite_db(db[2]),
                    cpu_preint_db: finite_db(db[3]),
                });
            }
            println!("{line}");
        }
    }
    Ok((out, missing))
}
