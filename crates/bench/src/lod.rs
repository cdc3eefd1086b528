//! The `lod` suite: error-aware vs geometric level of detail at equal working
//! sets.
//!
//! Each scene's volume is built into a brick store (format version 2, with
//! per-node error bounds) and drawn out of core at `--size` px (256) on the
//! adapter, converged, for a sweep of geometric tolerances (px) and a sweep of
//! error budgets (8-bit levels x px, `brickray_core::LodMetric`). Each point
//! gives the working set (data leaves of the converged cut, and their bytes)
//! and the PSNR of the image against the CPU reference (f64, exact trilinear,
//! the finest data). The comparison is at equal working sets: each error-aware
//! point's PSNR minus the geometric curve's PSNR interpolated (linearly in
//! log bricks) at the same brick count, where the geometric sweep covers it,
//! one point per distinct working set.
//! A third sweep ranks by the strict bound (`LodMetric::ErrorBound`), reported
//! apart.
//!
//! `cargo run --release -p brickray-bench -- lod [--size PX] [--scenes a,b] [--brick N]
//! [--policy none|rayguided|occlusion]` (visibility feedback under both rules; its
//! points converge over rendered frames, so that the feedback arrives)
//!
//! `--by budget` compares the two orders under a brick budget instead (GPU-free):
//! each scene's cut is refined on the CPU with every brick available, limited
//! only by a budget of data leaves (10% to 100% of the finest cut, the GPU
//! pool's capacity), split in priority order (geometric: projected voxel size;
//! error-aware: projected size x expected error, `LodMetric::ErrorAware` at
//! threshold 0), resampled as the out-of-core kernel samples it
//! (`crate::cut`), and rendered by the f64 reference; PSNR against the
//! reference render of the finest cut. The gain at a budget is the error-aware
//! PSNR minus the geometric (a cut never exceeds its budget; the error-aware
//! one may stay below it where nodes have no expected error). A third order,
//! "visible", ranks by what the image shows of each node
//! (`RefineEnv::visible_weight`, measured on the CPU from the finest data by
//! `crate::visible`) times its per-sample expected error
//! (`LodMetric::VisibleError` at threshold 0); its gain over the
//! geometric order is reported beside the error-aware one.
//!
//! `--by oracle` (`crate::oracle`) ranks by each node's exact cost to the
//! image instead, on the pareto suite's scenes: the ceiling of any order.
//!
//! Scenes: `mri` (shared T1 MRI, shaded DVR), `ct` (shared head CT,
//! translucent DVR), `ct_iso` (head CT, bone isosurface), `ml` (Marschner-Lobb
//! 128^3, DVR with a sharp band; `--ml-side` voxels per side, as the pareto
//! suite's procedural volumes, which `--by oracle` draws).

use crate::runner::{Runner, round2};
use crate::{Figures, arg};
use brickray_core::{
    BrickSource, Camera, LodMetric, RenderMode, RenderSettings, Shading, TransferFunction, Volume,
    VolumeFrame,
};
use brickray_harness::{GpuContext, ct};
use brickray_reference::{ReferenceOptions, compare, render_reference};
use brickray_render::{OutOfCoreConfig, VolumeRenderer};
use serde_json::json;
use std::sync::Arc;

/// One converged out-of-core image under one refinement rule.
pub(crate) struct LodPoint {
    /// Data leaves of the converged cut (the working set).
    pub(crate) bricks: u32,
    /// Their bytes as the source stores them.
    pub(crate) bytes: u64,
    /// The image (RGBA8, `size x size`).
    pub(crate) rgba: Vec<u8>,
    /// Frames to converge.
    pub(crate) frames: usize,
}

/// Draws `renderer` (out of core over its source) under `metric` with the
/// geometric `tolerance_px`, converged, and reads the image back. The
/// renderer is reused across calls: only the refinement rule changes.
#[allow(clippy::too_many_arguments)]
pub(crate) fn lod_point(
    run: &Runner<'_>,
    renderer: &mut VolumeRenderer,
    camera: Camera,
    frame: VolumeFrame,
    settings: RenderSettings,
    metric: LodMetric,
    tolerance_px: f32,
    brick_bytes: u64,
    rendered: bool,
) -> Result<LodPoint, String> {
    crate::runner::configure(run.gpu, renderer, |c| {
        c.lod_metric = metric;
        c.tolerance_px = tolerance_px;
    })?;
    // Rendered frames (not only planned ones) when visibility feedback is on,
    // so that its read-backs arrive.
    let frames = if !rendered {
        let (frames, stats) = run.converge(renderer, camera, frame, settings, 400)?;
        frames.ok_or_else(|| format!("not converged: {stats:?}"))?
    } else {
        let mut done = None;
        for i in 1..=400 {
            run.frame(renderer, camera, frame, settings, false)?;
            if renderer.stats().out_of_core.is_some_and(|s| s.converged) && i >= 8 {
                done = Some(i);
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        done.ok_or_else(|| format!("not converged: {:?}", renderer.stats().out_of_core))?
    };
    let shot = run.frame(renderer, camera, frame, settings, true)?;
    let stats = renderer.stats().out_of_core.ok_or("not out of core")?;
    let bricks = stats.cache.working_set_bricks;
    Ok(LodPoint {
        bricks,
        bytes: bricks as u64 * brick_bytes,
        rgba: shot.rgba,
        frames,
    })
}

struct Scene {
    name: &'static str,
    vol: Volume,
    settings: RenderSettings,
    tf: TransferFunction,
}

fn mri_dvr() -> Result<Scene, String> {
    let path = brickray_harness::shared_volume("pycortex_s1_t1_mri")
        .ok_or("the lod suite needs ../shared/data/pycortex_s1_t1_mri")?;
    Ok(Scene {
        name: "mri",
        vol: brickray_io::read_volume(&path).map_err(|e| e.to_string())?,
        settings: RenderSettings {
            mode: RenderMode::Dvr,
            shading: Shading {
                enabled: true,
                ..Default::default()
            },
            ..Default::default()
        },
        // The u8 suite's DVR scene.
        tf: TransferFunction::from_points(
            &[
                (0.15, [0.2, 0.4, 1.0, 0.0]),
                (0.3, [0.3, 0.7, 1.0, 0.05]),
                (0.5, [1.0, 0.8, 0.4, 0.15]),
                (0.9, [1.0, 1.0, 1.0, 0.6]),
            ],
            256,
        ),
    })
}

fn ct_scene(iso: bool) -> Result<Scene, String> {
    let path = brickray_harness::shared_volume("invesalius_cranium_ct")
        .ok_or("the lod suite needs ../shared/data/invesalius_cranium_ct")?;
    let vol = brickray_io::read_volume(&path).map_err(|e| e.to_string())?;
    let [(_, _, translucent), _, (_, iso_mode, iso_tf), _] = ct::scenes();
    Ok(if iso {
        Scene {
            name: "ct_iso",
            vol,
            settings: RenderSettings {
                mode: iso_mode,
                ..Default::default()
            },
            tf: iso_tf,
        }
    } else {
        Scene {
            name: "ct",
            vol,
            settings: RenderSettings {
                mode: RenderMode::Dvr,
                shading: Shading {
                    enabled: true,
                    ..Default::default()
                },
                ..Default::default()
            },
            tf: translucent,
        }
    })
}

fn ml_scene(side: u32) -> Scene {
    Scene {
        name: "ml",
        vol: brickray_core::synthetic::marschner_lobb(side),
        settings: RenderSettings {
            mode: RenderMode::Dvr,
            ..Default::default()
        },
        // A sharp opaque band around the classic 0.5 isovalue over a faint haze.
        tf: TransferFunction::from_points(
            &[
                (0.0, [0.2, 0.3, 0.8, 0.0]),
                (0.45, [0.2, 0.3, 0.8, 0.01]),
                (0.48, [1.0, 0.7, 0.3, 0.5]),
                (0.52, [1.0, 0.7, 0.3, 0.5]),
                (0.55, [0.2, 0.3, 0.8, 0.01]),
                (1.0, [0.2, 0.3, 0.8, 0.01]),
            ],
            256,
        ),
    }
}

/// PSNR of the geometric curve at `bricks` (linear in log bricks), `None`
/// outside its range (equal brick counts keep the best PSNR).
pub(crate) fn interpolate(curve: &[(f64, f64)], bricks: f64) -> Option<f64> {
    let mut c: Vec<(f64, f64)> = curve.to_vec();
    c.sort_by(|a, b| a.0.total_cmp(&b.0));
    // Equal brick counts: keep the best PSNR.
    c.dedup_by(|b, a| {
        if a.0 == b.0 {
            a.1 = a.1.max(b.1);
            true
        } else {
            false
        }
    });
    for w in c.windows(2) {
        let ((b0, p0), (b1, p1)) = (w[0], w[1]);
        if b0 <= bricks && bricks <= b1 {
            if b1 == b0 {
                return Some(p0.max(p1));
            }
            let t = (bricks.ln() - b0.ln()) / (b1.ln() - b0.ln());
            return Some(p0 + t * (p1 - p0));
        }
    }
    c.iter().find(|p| p.0 == bricks).map(|p| p.1)
}

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// A scene by name (`ml` with `ml_side` voxels per side).
fn scene(name: &str, ml_side: u32) -> Result<Scene, String> {
    match name {
        "mri" => mri_dvr(),
        "ct" => ct_scene(false),
        "ct_iso" => ct_scene(true),
        "ml" => Ok(ml_scene(ml_side)),
        other => Err(format!("unknown scene {other}")),
    }
}

/// Prints a scene's median gain over the budgets and records it as
/// `<scene>_<key>_median_gain_db`; returns it.
fn scene_median(fig: &mut Figures, scene: &str, label: &str, key: &str, gains: &[f64]) -> f64 {
    let m = median(&mut gains.to_vec());
    println!(
        "  {scene}: {label} gain {m:.2} dB over {} budgets (gains {:?})",
        gains.len(),
        gains.iter().map(|g| round2(*g)).collect::<Vec<_>>()
    );
    fig.insert(format!("{scene}_{key}_median_gain_db"), round2(m).into());
    m
}

/// `--by budget`: the geometric and the error-aware order under the same
/// brick budgets (module docs).
fn budget_run(size: u32, brick: u32, scenes: &str, ml_side: u32) -> Result<Figures, String> {
    use crate::cut::{CutView, cut_volume};
    let fractions = [1.0, 0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1];
    println!(
        "lod by budget: {size}x{size}, bricks {brick}+2x2, budgets {fractions:?} of the finest cut"
    );
    let mut fig = Figures::new();
    let mut all = Vec::new();
    let mut vall = Vec::new();
    for name in scenes.split(',') {
        let scene = scene(name, ml_side)?;
        let d = scene.vol.desc().clone();
        let frame = VolumeFrame::centered(d.dims, d.spacing);
        let camera = Camera::orbit(frame.center(), 2.0, 0.7, 0.35);
        let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
        let store_path = dir.path().join("v.brs");
        // The finest data, for the visible weights (the store takes the volume).
        let data = scene.vol.clone();
        crate::runner::build_store(scene.vol, brick, &store_path)?;
        let store = brickray_store::open(&store_path).map_err(|e| e.to_string())?;
        let view = CutView {
            store: &store,
            tf: &scene.tf,
            mode: scene.settings.mode,
            camera: &camera,
            frame: &frame,
            size,
            visible: None,
        };
        let weights = brickray_reference::visible_weights(
            &data,
            store.layout(),
            &frame,
            &scene.tf,
            &camera,
            scene.settings.mode,
            size,
        );
        let seen = CutView {
            visible: Some(&weights),
            ..view
        };
        let opts = ReferenceOptions::new(size, size);
        let draw = |v: &Volume| {
            render_reference(v, &frame, &scene.tf, &camera, &scene.settings, &opts)
                .to_rgba8([0.0; 3])
        };
        let (finest, n, _) = cut_volume(&view, 0.0, u32::MAX / 2, LodMetric::Geometric)?;
        let reference = draw(&finest);
        println!(
            "\n{}: {:?} {:?}, {:?}; finest cut {n} bricks",
            scene.name, d.dims, d.dtype, scene.settings.mode
        );
        println!(
            "  {:>7} {:>17} {:>17} {:>17} {:>8} {:>8}",
            "budget",
            "geometric b / dB",
            "error-aware b / dB",
            "visible b / dB",
            "gain dB",
            "vis gain"
        );
        let mut gains = Vec::new();
        let mut vgains = Vec::new();
        let mut rows = Vec::new();
        for f in fractions {
            let budget = ((n as f64 * f).round() as u32).max(1);
            let one = |view: &CutView<'_>, metric| -> Result<(u32, f64), String> {
                let (v, bricks, _) = cut_volume(view, 0.0, budget, metric)?;
                let p = brickray_reference::psnr(&draw(&v), &reference);
                Ok((bricks, p.min(99.0)))
            };
            let (gb, gp) = one(&view, LodMetric::Geometric)?;
            let (eb, ep) = one(&view, LodMetric::ErrorAware { budget: 0.0 })?;
            let (vb, vp) = one(&seen, LodMetric::VisibleError { budget: 0.0 })?;
            let gain = ep - gp;
            let vgain = vp - gp;
            println!(
                "  {budget:>7} {gb:>7} / {gp:>7.2} {eb:>7} / {ep:>7.2} {vb:>7} / {vp:>7.2} {gain:>8.2} {vgain:>8.2}"
            );
            // Budgets where both cuts are the finest data say nothing.
            if gp < 99.0 || ep < 99.0 {
                gains.push(gain);
            }
            if gp < 99.0 || vp < 99.0 {
                vgains.push(vgain);
            }
            rows.push(
                json!({"budget": budget, "geometric_bricks": gb, "geometric_psnr_db": round2(gp),
                "error_aware_bricks": eb, "error_aware_psnr_db": round2(ep),
                "visible_bricks": vb, "visible_psnr_db": round2(vp)}),
            );
        }
        vall.push(scene_median(
            &mut fig,
            scene.name,
            "visibility-weighted median",
            "budget_visible",
            &vgains,
        ));
        all.push(scene_median(
            &mut fig, scene.name, "median", "budget", &gains,
        ));
        fig.insert(format!("{}_budget_points", scene.name), rows.into());
    }
    let m = median(&mut all);
    println!(
        "\nall scenes: median of the scenes' median gains {m:.2} dB under equal brick budgets"
    );
    fig.insert(
        "error_aware_gain_db_at_equal_budget".into(),
        round2(m).into(),
    );
    let vm = median(&mut vall);
    println!(
        "all scenes: visibility-weighted, median of the scenes' median gains {vm:.2} dB under equal brick budgets"
    );
    fig.insert(
        "visible_error_aware_gain_db_at_equal_budget".into(),
        round2(vm).into(),
    );
    Ok(fig)
}

pub(crate) fn run(args: &[String]) -> Result<Figures, String> {
    let size: u32 = arg(args, "--size", 256)?;
    let brick: u32 = arg(args, "--brick", 32)?;
    let scenes: String = arg(args, "--scenes", "mri,ct,ml".to_string())?;
    let ml_side: u32 = arg(args, "--ml-side", crate::pareto::ML_SIDE)?;
    match arg(args, "--by", "knob".to_string())?.as_str() {
        "knob" => {}
        "budget" => return budget_run(size, brick, &scenes, ml_side),
        "oracle" => {
            let o = crate::oracle::OracleOptions::parse(args, size, brick, &scenes, ml_side)?;
            return crate::oracle::run(&o);
        }
        other => return Err(format!("--by {other}: knob, budget or oracle")),
    }
    let policy = match arg(args, "--policy", "none".to_string())?.as_str() {
        "none" => brickray_render::VisibilityPolicy::None,
        "rayguided" => brickray_render::VisibilityPolicy::RayGuided,
        "occlusion" => brickray_render::VisibilityPolicy::OcclusionQueries,
        other => return Err(format!("--policy {other}: none, rayguided or occlusion")),
    };
    // Both sweeps in steps of sqrt(2): tolerances 0 and 0.5..16 px, budgets
    // 2..8192 (8-bit levels x px).
    let tolerances: Vec<f32> = std::iter::once(0.0)
        .chain((0..11).map(|k| 0.5 * 2f32.powf(k as f32 / 2.0)))
        .collect();
    let budgets: Vec<f32> = (0..25).map(|k| 2.0 * 2f32.powf(k as f32 / 2.0)).collect();
    let gpu = GpuContext::new().map_err(|e| e.to_string())?;
    println!("adapter: {}", gpu.describe());
    println!(
        "lod: {size}x{size}, bricks {brick}+2x2, geometric tolerances {tolerances:?} px vs error budgets {budgets:?} (8-bit levels x px)"
    );
    let run = Runner::new(&gpu, size)?;
    let mut fig = Figures::new();
    let mut all_gains = Vec::new();
    for name in scenes.split(',') {
        let scene = scene(name, ml_side)?;
        let d = scene.vol.desc().clone();
        let frame = VolumeFrame::centered(d.dims, d.spacing);
        let camera = Camera::orbit(frame.center(), 2.0, 0.7, 0.35);
        let t = std::time::Instant::now();
        let reference = render_reference(
            &scene.vol,
            &frame,
            &scene.tf,
            &camera,
            &scene.settings,
            &ReferenceOptions::new(size, size),
        )
        .to_rgba8([0.0; 3]);
        println!(
            "\n{}: {:?} {:?}, {:?}; reference in {:.1} s",
            scene.name,
            d.dims,
            d.dtype,
            scene.settings.mode,
            t.elapsed().as_secs_f64()
        );
        let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
        let store_path = dir.path().join("v.brs");
        let report = crate::runner::build_store(scene.vol, brick, &store_path)?;
        if !report.errors {
            return Err("the store has no error section".into());
        }
        let store = brickray_store::open(&store_path).map_err(|e| e.to_string())?;
        let brick_bytes = store.layout().brick_bytes() as u64;
        println!(
            "  store: {} nodes, {} data, built in {:.1} s",
            report.nodes, report.data_nodes, report.seconds
        );
        let source: Arc<dyn BrickSource> = Arc::new(store);
        let mut renderer = VolumeRenderer::new(&gpu.device, brickray_harness::target_desc())
            .map_err(|e| e.to_string())?;
        renderer
            .set_volume_source(
                &gpu.device,
                &gpu.queue,
                source,
                OutOfCoreConfig {
                    gpu_budget_bytes: 1 << 30,
                    upload_budget_bytes: 1 << 30,
                    ..Default::default()
                },
            )
            .map_err(|e| e.to_string())?;
        renderer
            .set_transfer_function(&gpu.device, &gpu.queue, &scene.tf)
            .map_err(|e| e.to_string())?;
        crate::runner::configure(&gpu, &renderer, |c| c.visibility = policy)?;
        println!(
            "  {:>10} {:>9} {:>7} {:>9} {:>9} {:>7}",
            "metric", "budget", "bricks", "MiB", "PSNR dB", "frames"
        );
        let mut geo = Vec::new();
        let mut err = Vec::new();
        let mut bound = Vec::new();
        let mut points = Vec::new();
        let sweeps = tolerances
            .iter()
            .map(|&t| ("geometric", LodMetric::Geometric, t, t))
            .chain(
                budgets
                    .iter()
                    .map(|&b| ("error", LodMetric::ErrorAware { budget: b }, 1.0, b)),
            )
            .chain(
                budgets
                    .iter()
                    .step_by(2)
                    .map(|&b| ("bound", LodMetric::ErrorBound { budget: b }, 1.0, b)),
            );
        for (label, metric, tol, knob) in sweeps {
            let p = lod_point(
                &run,
                &mut renderer,
                camera,
                frame,
                scene.settings,
                metric,
                tol,
                brick_bytes,
                policy != brickray_render::VisibilityPolicy::None,
            )?;
            let psnr = compare(&p.rgba, &reference, size, size).psnr_db.min(99.0);
            println!(
                "  {label:>10} {knob:>9.2} {:>7} {:>9.1} {psnr:>9.2} {:>7}",
                p.bricks,
                p.bytes as f64 / (1 << 20) as f64,
                p.frames
            );
            match label {
                "geometric" => geo.push((p.bricks as f64, psnr)),
                "error" => err.push((p.bricks as f64, psnr)),
                _ => bound.push((p.bricks as f64, psnr)),
            }
            points.push(
                json!({"metric": label, "knob": knob, "bricks": p.bricks, "psnr_db": round2(psnr)}),
            );
        }
        // One point per distinct working set (a budget sweep repeats the
        // coarsest and finest cuts many times).
        let distinct = |v: &[(f64, f64)]| {
            let mut v = v.to_vec();
            v.sort_by(|a, b| a.0.total_cmp(&b.0));
            v.dedup_by(|b, a| a.0 == b.0);
            v
        };
        let (err, bound) = (distinct(&err), distinct(&bound));
        let mut gains: Vec<f64> = err
            .iter()
            .filter_map(|&(b, p)| interpolate(&geo, b).map(|g| p - g))
            .collect();
        let matched = gains.len();
        all_gains.extend(gains.iter().copied());
        let med = median(&mut gains);
        println!(
            "  {}: error-aware minus geometric PSNR at equal bricks: median {med:.2} dB over {matched} matched distinct working sets (gains {:?})",
            scene.name,
            gains.iter().map(|g| round2(*g)).collect::<Vec<_>>()
        );
        let mut bgains: Vec<f64> = bound
            .iter()
            .filter_map(|&(b, p)| interpolate(&geo, b).map(|g| p - g))
            .collect();
        let bmed = median(&mut bgains);
        println!(
            "  {}: strict-bound rule minus geometric: median {bmed:.2} dB over {} matched points",
            scene.name,
            bgains.len()
        );
        fig.insert(
            format!("{}_bound_median_gain_db", scene.name),
            json!(round2(bmed)),
        );
        fig.insert(format!("{}_median_gain_db", scene.name), json!(round2(med)));
        fig.insert(format!("{}_matched_points", scene.name), json!(matched));
        fig.insert(format!("{}_points", scene.name), json!(points));
    }
    let med = median(&mut all_gains);
    println!("\nall scenes: median gain {med:.2} dB at equal working set (target >= 3 dB)");
    fig.insert("median_gain_db".into(), json!(round2(med)));
    fig.insert("image_size".into(), json!(size));
    fig.insert("brick".into(), json!(brick));
    fig.insert("adapter".into(), json!(gpu.adapter.get_info().name));
    Ok(fig)
}

#[cfg(test)]
mod tests {
    use super::interpolate;

    #[test]
    fn interpolation_is_linear_in_log_bricks_and_bounded() {
        let c = [(10.0, 20.0), (100.0, 40.0), (1000.0, 50.0)];
        assert_eq!(interpolate(&c, 5.0), None);
        assert_eq!(interpolate(&c, 2000.0), None);
        assert!((interpolate(&c, 10.0f64.powf(1.5)).unwrap() - 30.0).abs() < 1e-9);
        assert_eq!(interpolate(&c, 1000.0), Some(50.0));
    }
}
