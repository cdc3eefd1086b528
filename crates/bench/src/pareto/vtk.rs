//! The `vtk` suite: brickray against VTK's volume mappers at equal error.
//!
//! On the shared head CT and T1 MRI (the pareto suite's scenes and transfer
//! functions) in DVR, shaded DVR and MIP, it renders one view with brickray
//! (out of core at the default tolerance, and in core) and with VTK's CPU
//! fixed-point ray caster and its OpenGL GPU ray caster (`pip install vtk`;
//! the script `vtk_render.py` beside this file, run by `python3`), each at
//! the same sample steps, and compares every image with the f64 reference
//! (the pareto suite's, cached the same way). VTK gets the scene as brickray
//! defines it: the volume's voxel centres placed where brickray's lie, the
//! transfer function's entries as points on the raw values, opacity per the
//! same reference length, the same camera, the headlight's Blinn-Phong
//! weights, trilinear interpolation, a black background. The rounds
//! alternate: one round of every brickray configuration (interleaved as the
//! pareto suite does), then one VTK run (each mapper and step: an untimed
//! render, then a timed one to completion), so both see the same drift.
//!
//! What decides: for each VTK point, the fastest brickray configuration at
//! least as close to the reference, as a time ratio (below 1: brickray is
//! faster at equal or better error; null where no brickray configuration is
//! as close). Output: a CSV of every point, one SVG chart per scene (time
//! against PSNR, brickray's front drawn) and, last, the figures as JSON.

use super::configs::{Config, DEFAULT_KEY, RendererKey, base_settings};
use super::scenes::{Scene, scenes};
use super::{Images, chart, front, measure, reference_image};
use crate::runner::{Runner, finite_db, median, round2};
use brickray_core::{DType, RenderMode, RenderSettings, TransferFunction};
use brickray_harness::GpuContext;
use brickray_reference::psnr;
use serde::Serialize;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The renderer VTK runs, written next to the scene files.
const SCRIPT: &str = include_str!("vtk_render.py");

/// The suite's options.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Image side in pixels.
    #[arg(long, default_value_t = 512, value_parser = crate::image_side)]
    size: u32,
    /// Interleaved rounds (brickray, then VTK, per round).
    #[arg(long, default_value_t = 3, value_parser = crate::at_least_one::<usize>)]
    rounds: usize,
    /// Volumes, comma-separated, of ct and mri (default both).
    #[arg(long, value_delimiter = ',')]
    scenes: Vec<String>,
    /// Modes, comma-separated, of dvr, dvr_shaded and mip (default all).
    #[arg(long, value_delimiter = ',')]
    modes: Vec<String>,
    /// Sample steps in voxels, for brickray and VTK alike.
    #[arg(long, value_delimiter = ',', default_value = "0.25,0.5,1,1.5,2,3,4")]
    steps: Vec<f32>,
    /// Further steps in voxels that brickray alone draws (its front may
    /// reach the error of VTK's coarsest images at a coarser step; VTK's
    /// points stay at `--steps`); `--own-steps` with no value: none.
    #[arg(long, value_delimiter = ',', num_args = 0.., default_value = "6,8", value_parser = crate::sample_step)]
    own_steps: Vec<f32>,
    /// The Python interpreter with the `vtk` package.
    #[arg(long, default_value = "python3")]
    python: String,
    /// Where the CSV, the scene files and VTK's images go (the references
    /// are cached here too).
    #[arg(long, default_value = "target/vtk")]
    out: PathBuf,
    /// Where the SVG charts go.
    #[arg(long, default_value = "docs/charts/vtk")]
    charts: PathBuf,
    /// Rays per pixel side of the reference.
    #[arg(long, default_value_t = 2, value_parser = crate::at_least_one::<u32>)]
    supersample: u32,
    /// Interior voxels per brick side of the stores.
    #[arg(long, default_value_t = 32, value_parser = crate::at_least_one::<u32>)]
    brick: u32,
    /// Also brickray in core with pre-integrated DVR at each step (DVR
    /// modes only; `in_core_preint` configurations).
    #[arg(long)]
    preint: bool,
    /// Also brickray in core at each step with early ray termination at
    /// each of these thresholds instead of the default 0.99 (DVR modes
    /// only; `in_core_ert` configurations, valued `<step>, ert
    /// <threshold>`), comma-separated, each in (0, 1].
    #[arg(long, value_delimiter = ',', value_parser = ert_threshold)]
    ert: Vec<f32>,
    /// Also brickray at each step with DVR's step growing as the ray's
    /// transmittance falls (`Accel::adaptive_step`; DVR modes only), in
    /// core and out of core (`in_core_adaptive`, `out_of_core_adaptive`).
    #[arg(long)]
    adaptive: bool,
}

/// An early-termination threshold in (0, 1].
fn ert_threshold(s: &str) -> Result<f32, String> {
    let t: f32 = s.parse().map_err(|e| format!("{s}: {e}"))?;
    if t > 0.0 && t <= 1.0 {
        Ok(t)
    } else {
        Err(format!("{s}: a threshold lies in (0, 1]"))
    }
}

/// One VTK point: a mapper at a step.
#[derive(Debug, Clone, Serialize)]
pub(crate) struct VtkPoint {
    /// `cpu` (fixed point) or `gpu` (OpenGL).
    mapper: String,
    step: f32,
    /// Median over the rounds.
    ms: f64,
    psnr_db: f64,
    /// The fastest brickray configuration at least as close to the
    /// reference, over this point's time (null: none is as close).
    brickray_time_ratio: Option<f64>,
    /// That configuration, as `in_core`/`out_of_core` and step.
    brickray_config: Option<String>,
    /// The same among the out-of-core configurations.
    out_of_core_time_ratio: Option<f64>,
}

/// One brickray configuration's point.
#[derive(Debug, Clone, Serialize)]
pub(crate) struct OurPoint {
    /// `in_core` or `out_of_core`, and the step.
    config: String,
    #[serde(skip)]
    in_core: bool,
    ms: f64,
    psnr_db: f64,
}

/// The fastest of `ours` (those in core or not, if `in_core` says) whose
/// PSNR is at least `db`.
fn fastest_as_close(ours: &[OurPoint], db: f64, in_core: Option<bool>) -> Option<&OurPoint> {
    ours.iter()
        .filter(|p| in_core.is_none_or(|c| p.in_core == c) && p.psnr_db >= db)
        .min_by(|a, b| a.ms.total_cmp(&b.ms))
}

/// One scene and mode.
#[derive(Debug, Serialize)]
pub(crate) struct VtkScene {
    scene: String,
    /// brickray's points.
    brickray: Vec<OurPoint>,
    vtk: Vec<VtkPoint>,
    /// The first render of each VTK mapper (set-up: gradients, textures), ms.
    vtk_setup_ms: SetupMs,
    /// Whether every VTK point has a brickray configuration at least as
    /// close to the reference and at most as slow.
    brickray_at_or_below_vtk: bool,
}

/// The suite's JSON line.
#[derive(Debug, Serialize)]
pub(crate) struct VtkResult {
    size: u32,
    rounds: usize,
    adapter: String,
    vtk_version: String,
    /// Over every scene.
    brickray_at_or_below_vtk_all: bool,
    /// The largest time ratio over every VTK point of every scene (null if
    /// some point had no brickray configuration as close).
    worst_time_ratio: Option<f64>,
    scenes: Vec<VtkScene>,
}

/// Each VTK mapper's first render (set-up), ms.
type SetupMs = Vec<(String, f64)>;

/// What one VTK run printed.
#[derive(Debug, serde::Deserialize)]
struct VtkRun {
    vtk: String,
    results: Vec<VtkEntry>,
}

#[derive(Debug, serde::Deserialize)]
struct VtkEntry {
    mapper: String,
    step: Option<f32>,
    #[serde(default)]
    ms: Vec<f64>,
    image: Option<PathBuf>,
    setup_ms: Option<f64>,
}

pub(crate) fn run(o: &Args) -> Result<VtkResult, String> {
    check_python(&o.python)?;
    let wanted: Vec<String> = if o.scenes.is_empty() {
        vec!["ct".into(), "mri".into()]
    } else {
        o.scenes.clone()
    };
    if let Some(s) = wanted.iter().find(|s| *s != "ct" && *s != "mri") {
        return Err(format!("{s}: the vtk suite draws ct and mri"));
    }
    let modes = ["dvr", "dvr_shaded", "mip"];
    if let Some(m) = o.modes.iter().find(|m| !modes.contains(&m.as_str())) {
        return Err(format!("{m}: modes are dvr, dvr_shaded and mip"));
    }
    let scenes = scenes(&wanted, super::ML_SIDE)?;
    let gpu = GpuContext::new().map_err(|e| e.to_string())?;
    println!("adapter: {}", gpu.describe());
    println!(
        "image {0}x{0}; {1} rounds, brickray then VTK in each; steps {2:?} voxels (brickray also {3:?}); reference: step 1/8 voxel, {4}x{4} rays per pixel",
        o.size, o.rounds, o.steps, o.own_steps, o.supersample
    );
    std::fs::create_dir_all(&o.out).map_err(|e| format!("{}: {e}", o.out.display()))?;
    std::fs::create_dir_all(&o.charts).map_err(|e| format!("{}: {e}", o.charts.display()))?;
    let script = o.out.join("vtk_render.py");
    std::fs::write(&script, SCRIPT).map_err(|e| format!("{}: {e}", script.display()))?;
    let run = Runner::new(&gpu, o.size)?;
    let mut csv = String::from("volume,mode,renderer,step,ms,psnr_db\n");
    let mut rows = Vec::new();
    let mut version = String::new();
    for scene in &scenes {
        let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
        let path = dir.path().join("v.brs");
        scene.build_store(o.brick, &path)?;
        let store: Arc<dyn brickray_core::BrickSource> =
            Arc::new(brickray_store::open(&path).map_err(|e| e.to_string())?);
        let raw = o.out.join(format!("{}.raw", scene.name));
        std::fs::write(&raw, scene.volume.data().as_bytes())
            .map_err(|e| format!("{}: {e}", raw.display()))?;
        for mode_name in modes {
            if !o.modes.is_empty() && !o.modes.iter().any(|m| m == mode_name) {
                continue;
            }
            let (mode, tf) = scene_mode(scene, mode_name)?;
            let mut base = base_settings(mode);
            base.shading.enabled = mode_name == "dvr_shaded";
            let name = format!("{}_{mode_name}", scene.name);
            let tag = if mode_name == "dvr" {
                "dvr_flat"
            } else {
                mode_name
            };
            let reference = reference_image(scene, &tf, &base, tag, o.size, o.supersample, &o.out)?;
            let cfgs = brickray_configs(base, &our_steps(o), o.preint, &o.ert, o.adaptive);
            let scene_json = o.out.join(format!("{name}.json"));
            let prefix = o.out.join(&name);
            let desc = vtk_scene(scene, &tf, &base, &raw, o, &prefix);
            std::fs::write(&scene_json, desc.to_string())
                .map_err(|e| format!("{}: {e}", scene_json.display()))?;
            let mut vtk_runs = Vec::new();
            let mut between = || -> Result<(), String> {
                vtk_runs.push(run_vtk(&o.python, &script, &scene_json)?);
                Ok(())
            };
            let images = Images {
                reference: &reference,
                finest: &reference,
            };
            let m = measure(
                &run,
                scene,
                store.clone(),
                &tf,
                &cfgs,
                images,
                o.rounds,
                &mut between,
            )?;
            version = vtk_runs.last().map(|r| r.vtk.clone()).unwrap_or_default();
            let ours: Vec<OurPoint> = cfgs
                .iter()
                .zip(&m)
                .map(|(c, x)| OurPoint {
                    config: format!("{} {}", c.knob, c.value),
                    in_core: c.key.in_core,
                    ms: x.ms,
                    psnr_db: x.psnr_db,
                })
                .collect();
            let (vtk, setup) = vtk_points(&vtk_runs, &reference, o.size, &ours)?;
            println!("\n{name}");
            println!("  {:<22} {:>10} {:>8}", "renderer, step", "ms", "PSNR");
            for p in &ours {
                let (c, ms, db) = (&p.config, p.ms, p.psnr_db);
                println!("  {c:<22} {ms:>10.1} {db:>8.2}");
                let _ = writeln!(
                    csv,
                    "{},{mode_name},brickray {c},,{ms:.3},{db:.3}",
                    scene.name
                );
            }
            for p in &vtk {
                let ratio = p
                    .brickray_time_ratio
                    .map_or("none as close".to_string(), |r| {
                        format!(
                            "brickray {:.2}x ({}); out of core {}",
                            r,
                            p.brickray_config.as_deref().unwrap_or(""),
                            p.out_of_core_time_ratio
                                .map_or("none as close".to_string(), |r| format!("{r:.2}x"))
                        )
                    });
                println!(
                    "  {:<22} {:>10.1} {:>8.2}   {ratio}",
                    format!("VTK {} {}", p.mapper, p.step),
                    p.ms,
                    p.psnr_db
                );
                let _ = writeln!(
                    csv,
                    "{},{mode_name},vtk {},{},{:.3},{:.3}",
                    scene.name, p.mapper, p.step, p.ms, p.psnr_db
                );
            }
            for (mapper, ms) in &setup {
                println!("  VTK {mapper} first render (set-up): {ms:.1} ms");
            }
            let ok = vtk
                .iter()
                .all(|p| p.brickray_time_ratio.is_some_and(|r| r <= 1.0));
            println!("  brickray at or below every VTK point: {ok}");
            draw(o, &name, &cfgs, &m, &vtk)?;
            rows.push(VtkScene {
                scene: name,
                brickray: ours
                    .into_iter()
                    .map(|p| OurPoint {
                        ms: round2(p.ms),
                        psnr_db: finite_db(p.psnr_db),
                        ..p
                    })
                    .collect(),
                vtk,
                vtk_setup_ms: setup,
                brickray_at_or_below_vtk: ok,
            });
        }
    }
    let csv_path = o.out.join("vtk.csv");
    std::fs::write(&csv_path, csv).map_err(|e| format!("{}: {e}", csv_path.display()))?;
    println!("\ndata: {}", csv_path.display());
    let ratios: Vec<Option<f64>> = rows
        .iter()
        .flat_map(|r| r.vtk.iter().map(|p| p.brickray_time_ratio))
        .collect();
    let worst = ratios
        .iter()
        .try_fold(0.0f64, |w, r| r.map(|r| w.max(r)))
        .map(round2);
    Ok(VtkResult {
        size: o.size,
        rounds: o.rounds,
        adapter: gpu.describe(),
        vtk_version: version,
        brickray_at_or_below_vtk_all: rows.iter().all(|r| r.brickray_at_or_below_vtk),
        worst_time_ratio: worst,
        scenes: rows,
    })
}

/// brickray's steps: VTK's, then the further ones not among them.
fn our_steps(o: &Args) -> Vec<f32> {
    let mut steps = o.steps.clone();
    for s in &o.own_steps {
        if !steps.contains(s) {
            steps.push(*s);
        }
    }
    steps
}

/// Stops early, with the command to run, when the interpreter lacks `vtk`.
fn check_python(python: &str) -> Result<(), String> {
    let ok = std::process::Command::new(python)
        .args(["-c", "import vtk, numpy"])
        .output()
        .is_ok_and(|o| o.status.success());
    if ok {
        Ok(())
    } else {
        Err(format!(
            "the vtk suite needs VTK's Python package: {python} -m pip install vtk"
        ))
    }
}

/// The mode and TF of a scene's DVR or MIP (the pareto suite's).
fn scene_mode(scene: &Scene, mode_name: &str) -> Result<(RenderMode, TransferFunction), String> {
    let want = if mode_name == "mip" { "mip" } else { "dvr" };
    scene
        .modes
        .iter()
        .find(|(n, ..)| *n == want)
        .map(|(_, m, tf)| (*m, tf.clone()))
        .ok_or_else(|| format!("{} has no {want}", scene.name))
}

/// brickray's configurations: out of core at the default tolerance, and in
/// core, at each step; shaded DVR also out of core from the gradients the
/// streamed volume keeps (`out_of_core_gradients`, as VTK's mappers keep
/// theirs); with `preint` (DVR only), in core pre-integrated too; for each
/// threshold of `erts` (DVR only), in core terminating there; with
/// `adaptive` (DVR only), in core and out of core with the adaptive step.
fn brickray_configs(
    base: RenderSettings,
    steps: &[f32],
    preint: bool,
    erts: &[f32],
    adaptive: bool,
) -> Vec<Config> {
    let in_core = RendererKey {
        in_core: true,
        ..DEFAULT_KEY
    };
    let kept = RendererKey {
        gradients: true,
        ..DEFAULT_KEY
    };
    let dvr = matches!(base.mode, RenderMode::Dvr);
    let shaded = dvr && base.shading.enabled;
    let preint = preint && dvr;
    let adaptive = adaptive && dvr;
    let mut out: Vec<Config> = [
        ("out_of_core", DEFAULT_KEY, false, false, true),
        ("out_of_core_gradients", kept, false, false, shaded),
        ("in_core", in_core, false, false, true),
        ("in_core_preint", in_core, true, false, preint),
        ("in_core_adaptive", in_core, false, true, adaptive),
        ("out_of_core_adaptive", DEFAULT_KEY, false, true, adaptive),
    ]
    .into_iter()
    .filter(|c| c.4)
    .flat_map(|(knob, key, preintegrated, adaptive_step, _)| {
        steps.iter().map(move |&step| {
            let mut settings = RenderSettings {
                step_factor: step,
                preintegrated,
                ..base
            };
            settings.accel.adaptive_step = adaptive_step;
            Config {
                knob,
                value: format!("{step}"),
                key,
                settings,
            }
        })
    })
    .collect();
    for &t in erts.iter().filter(|_| dvr) {
        out.extend(steps.iter().map(|&step| {
            let mut settings = RenderSettings {
                step_factor: step,
                ..base
            };
            settings.accel.early_termination = Some(t);
            Config {
                knob: "in_core_ert",
                value: format!("{step}, ert {t}"),
                key: in_core,
                settings,
            }
        }));
    }
    out
}

/// The scene as VTK's script reads it: brickray's voxel centres in world
/// coordinates (the frame's model applied to texture coordinates of voxel
/// centres), the TF's entries at raw values, opacity per `voxel_world`.
fn vtk_scene(
    scene: &Scene,
    tf: &TransferFunction,
    settings: &RenderSettings,
    raw: &Path,
    o: &Args,
    prefix: &Path,
) -> serde_json::Value {
    let d = scene.volume.desc();
    let dims = d.dims;
    let model = scene.frame.model;
    let at = |u: glam::Vec3| model.transform_point3(u);
    let half = glam::Vec3::from_array(dims.map(|n| 0.5 / n as f32));
    let origin = at(half);
    let spacing: Vec<f32> = (0..3)
        .map(|i| model.col(i).truncate().length() / dims[i] as f32)
        .collect();
    let [lo, hi] = d.value_range;
    let n = tf.entries().len();
    let points: Vec<[f32; 5]> = tf
        .entries()
        .iter()
        .enumerate()
        .map(|(i, e)| {
            let v = lo + (hi - lo) * i as f32 / (n - 1) as f32;
            [v, e[0], e[1], e[2], e[3]]
        })
        .collect();
    let cam = scene.camera;
    let fov_y = match cam.projection {
        brickray_core::Projection::Perspective { fov_y } => fov_y.to_degrees(),
        brickray_core::Projection::Orthographic { .. } => 40.0,
    };
    let dtype = match d.dtype {
        DType::U8 => "u8",
        DType::U16 => "u16",
        DType::I16 => "i16",
        _ => "f32",
    };
    let s = settings.shading;
    serde_json::json!({
        "raw": raw,
        "dtype": dtype,
        "dims": dims,
        "origin": origin.to_array(),
        "spacing": spacing,
        "tf": points,
        "opacity_unit": scene.frame.voxel_world,
        "mode": if matches!(settings.mode, RenderMode::Mip) { "mip" } else { "dvr" },
        "shade": s.enabled,
        "shading": {"ambient": s.ambient, "diffuse": s.diffuse, "specular": s.specular, "shininess": s.shininess},
        "eye": cam.eye.to_array(),
        "target": cam.target.to_array(),
        "up": cam.up.to_array(),
        "fov_y_deg": fov_y,
        "size": o.size,
        "steps": o.steps,
        "frames": 1,
        "mappers": ["cpu", "gpu"],
        "out_prefix": prefix,
    })
}

/// Runs the VTK script on one scene file.
fn run_vtk(python: &str, script: &Path, scene: &Path) -> Result<VtkRun, String> {
    let out = std::process::Command::new(python)
        .arg(script)
        .arg(scene)
        .output()
        .map_err(|e| format!("{python}: {e}"))?;
    if !out.status.success() {
        return Err(format!(
            "VTK's script failed on {}: {}",
            scene.display(),
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    let stdout = String::from_utf8_lossy(&out.stdout);
    let line = stdout
        .lines()
        .rev()
        .find(|l| l.starts_with('{'))
        .ok_or("VTK's script printed no result")?;
    serde_json::from_str(line).map_err(|e| format!("VTK's result: {e}"))
}

/// VTK's points (median time over the runs, PSNR of the last run's image)
/// with the brickray configuration that matches each, and each mapper's
/// set-up time (median of the runs' first renders).
fn vtk_points(
    runs: &[VtkRun],
    reference: &[u8],
    size: u32,
    ours: &[OurPoint],
) -> Result<(Vec<VtkPoint>, SetupMs), String> {
    let last = runs.last().ok_or("VTK never ran")?;
    let mut points = Vec::new();
    let mut setup = Vec::new();
    for e in &last.results {
        if e.setup_ms.is_some() {
            let all: Vec<f64> = runs
                .iter()
                .flat_map(|r| r.results.iter())
                .filter(|x| x.mapper == e.mapper)
                .filter_map(|x| x.setup_ms)
                .collect();
            setup.push((e.mapper.clone(), round2(median(&all))));
            continue;
        }
        let (Some(step), Some(image)) = (e.step, &e.image) else {
            continue;
        };
        let times: Vec<f64> = runs
            .iter()
            .flat_map(|r| r.results.iter())
            .filter(|x| x.mapper == e.mapper && x.step == Some(step))
            .flat_map(|x| x.ms.iter().copied())
            .collect();
        let rgba = std::fs::read(image).map_err(|x| format!("{}: {x}", image.display()))?;
        if rgba.len() != (size * size * 4) as usize {
            return Err(format!(
                "{}: not a {size}x{size} RGBA8 image",
                image.display()
            ));
        }
        let ms = median(&times);
        let db = psnr(&rgba, reference);
        let best = fastest_as_close(ours, db, None);
        points.push(VtkPoint {
            mapper: e.mapper.clone(),
            step,
            ms: round2(ms),
            psnr_db: finite_db(db),
            brickray_time_ratio: best.map(|b| round2(b.ms / ms)),
            brickray_config: best.map(|b| b.config.clone()),
            out_of_core_time_ratio: fastest_as_close(ours, db, Some(false))
                .map(|b| round2(b.ms / ms)),
        });
    }
    Ok((points, setup))
}

/// The scene's chart: brickray's points and front, VTK's points.
fn draw(
    o: &Args,
    name: &str,
    cfgs: &[Config],
    m: &[super::Measured],
    vtk: &[VtkPoint],
) -> Result<(), String> {
    let mut pts: Vec<chart::ChartPoint<'_>> = cfgs
        .iter()
        .zip(m)
        .map(|(c, x)| chart::ChartPoint {
            knob: match (c.key.in_core, c.settings.preintegrated, c.key.gradients) {
                _ if c.knob == "in_core_ert" => "brickray in core, other termination",
                _ if c.knob == "in_core_adaptive" => "brickray in core, adaptive step",
                _ if c.knob == "out_of_core_adaptive" => "brickray out of core, adaptive step",
                (true, false, _) => "brickray in core",
                (true, true, _) => "brickray in core, pre-integrated",
                (false, _, false) => "brickray out of core",
                (false, _, true) => "brickray out of core, gradients kept",
            },
            ms: x.ms,
            psnr_db: x.psnr_db,
            bricks: 0.0,
        })
        .collect();
    let ours: Vec<(f64, f64)> = m.iter().map(|x| (x.ms, x.mse)).collect();
    let on = front::front(&ours);
    for p in vtk {
        pts.push(chart::ChartPoint {
            knob: if p.mapper == "cpu" {
                "VTK fixed point (CPU)"
            } else {
                "VTK GPU ray cast (OpenGL)"
            },
            ms: p.ms,
            psnr_db: p.psnr_db,
            bricks: 0.0,
        });
    }
    // The default (out of core, step 0.5) is marked, when swept.
    let default = cfgs
        .iter()
        .position(|c| !c.key.in_core && c.settings.step_factor == 0.5)
        .unwrap_or(0);
    let svg = o.charts.join(format!("{name}.svg"));
    let title = format!(
        "{name}: brickray and VTK, time against error ({0}x{0} px)",
        o.size
    );
    chart::draw(&svg, &title, chart::Axis::Time, &pts, &on, default)?;
    println!("  chart: {}", svg.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(clap::Parser)]
    struct Cli {
        #[command(flatten)]
        args: Args,
    }

    #[test]
    fn brickray_alone_draws_the_further_steps() {
        use clap::Parser;
        let o = Cli::parse_from(["vtk", "--steps", "1,4"]).args;
        assert_eq!(o.steps, [1.0, 4.0]);
        assert_eq!(our_steps(&o), [1.0, 4.0, 6.0, 8.0]);
        let o = Cli::parse_from(["vtk", "--steps", "1,4", "--own-steps", "4,5"]).args;
        assert_eq!(our_steps(&o), [1.0, 4.0, 5.0]);
        let o = Cli::parse_from(["vtk", "--steps", "1,4", "--own-steps"]).args;
        assert_eq!(our_steps(&o), [1.0, 4.0]);
        assert!(Cli::try_parse_from(["vtk", "--own-steps", "32"]).is_err());
    }

    #[test]
    fn other_terminations_are_in_core_dvr_at_every_step() {
        let steps = [0.5f32, 2.0];
        let dvr = base_settings(RenderMode::Dvr);
        let cfgs = brickray_configs(dvr, &steps, false, &[0.95, 0.9], false);
        let ert: Vec<&Config> = cfgs.iter().filter(|c| c.knob == "in_core_ert").collect();
        assert_eq!(ert.len(), 4);
        assert!(ert.iter().all(|c| c.key.in_core));
        assert_eq!(ert[1].value, "2, ert 0.95");
        assert_eq!(ert[1].settings.step_factor, 2.0);
        assert_eq!(ert[2].settings.accel.early_termination, Some(0.9));
        // The others keep the default termination; MIP gets none.
        assert!(
            cfgs.iter().filter(|c| c.knob != "in_core_ert").all(|c| c
                .settings
                .accel
                .early_termination
                == dvr.accel.early_termination)
        );
        let mip = base_settings(RenderMode::Mip);
        assert!(
            brickray_configs(mip, &steps, false, &[0.9], true)
                .iter()
                .all(|c| c.knob != "in_core_ert")
        );
        assert!(ert_threshold("0").is_err() && ert_threshold("1.5").is_err());
        assert_eq!(ert_threshold("0.9"), Ok(0.9));
    }

    #[test]
    fn adaptive_steps_are_dvr_in_both_backends_at_every_step() {
        let steps = [0.5f32, 2.0];
        let dvr = base_settings(RenderMode::Dvr);
        let cfgs = brickray_configs(dvr, &steps, false, &[], true);
        let adaptive: Vec<&Config> = cfgs
            .iter()
            .filter(|c| c.settings.accel.adaptive_step)
            .collect();
        assert_eq!(adaptive.len(), 4);
        assert_eq!(adaptive.iter().filter(|c| c.key.in_core).count(), 2);
        assert!(adaptive.iter().all(|c| c.knob.ends_with("_adaptive")));
        assert_eq!(adaptive[1].settings.step_factor, 2.0);
        let mip = base_settings(RenderMode::Mip);
        assert!(
            brickray_configs(mip, &steps, false, &[], true)
                .iter()
                .all(|c| !c.settings.accel.adaptive_step)
        );
    }

    fn p(config: &str, in_core: bool, ms: f64, psnr_db: f64) -> OurPoint {
        OurPoint {
            config: config.into(),
            in_core,
            ms,
            psnr_db,
        }
    }

    #[test]
    fn the_match_is_the_fastest_at_least_as_close() {
        let ours = [
            p("out_of_core 0.5", false, 180.0, 45.7),
            p("out_of_core 2", false, 84.0, 30.6),
            p("in_core 1", true, 67.0, 41.9),
            p("in_core 2", true, 43.0, 30.6),
        ];
        let b = fastest_as_close(&ours, 35.0, None).unwrap();
        assert_eq!(b.config, "in_core 1");
        assert_eq!(
            fastest_as_close(&ours, 35.0, Some(false)).unwrap().config,
            "out_of_core 0.5"
        );
        // Equal PSNR counts as close; none is as close as 50 dB.
        assert_eq!(
            fastest_as_close(&ours, 30.6, None).unwrap().config,
            "in_core 2"
        );
        assert!(fastest_as_close(&ours, 50.0, None).is_none());
    }
}
