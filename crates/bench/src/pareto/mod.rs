//! The `pareto` suite: speed against accuracy, one chart per volume and mode.
//!
//! For each scene (a volume, its transfer function and a mode) it renders one
//! view with a set of configurations: the defaults, and one knob at a time swept
//! around them (step, pre-integration, the adaptive step, geometric and visible-error
//! level-of-detail budgets, early-termination threshold, the u8
//! interpolation, the visibility policy, in core instead of out of core), and
//! the geometric, visible-error and octant orders under equal brick budgets
//! (10-90% of the finest cut: equal working sets by construction). Each
//! configuration gets its own renderer state (a renderer per cache setting,
//! converged before timing); frames are interleaved round by round over all the
//! configurations (the machine's speed drifts), each round starting at another
//! configuration, and each time is the median of `prepare + submit + wait`.
//! Each configuration's converged image is compared with the f64 CPU
//! reference at a step of 1/8 voxel with 2 x 2 supersampling: PSNR, mean FLIP
//! and SSIM; and, for the level of detail's own error, PSNR against the
//! finest cut's image from the same renderer. Working set: the cut's data
//! bricks on the GPU and their bytes.
//!
//! Output: a CSV of every point, two SVG charts per scene (time against PSNR,
//! the front, the default marked; PSNR against the working set of the
//! level-of-detail sweeps) and, as the last line, the figures as JSON.

mod chart;
mod configs;
mod front;
mod gains;
pub(crate) mod scenes;
pub(crate) mod vtk;

use crate::runner::{Runner, finite_db, median, round2};
use brickray_core::{RenderMode, TransferFunction};
use brickray_harness::GpuContext;
use brickray_reference::{ReferenceOptions, mean_flip, psnr, render_reference, ssim};
use brickray_render::{OutOfCoreConfig, RendererOptions, VolumeRenderer};
pub(crate) use configs::base_settings;
use configs::{Config, RendererKey, configs};
use gains::{adaptive_vs_plain, brick_budget_gain, lod_gain, preint_gain};
use scenes::Scene;
pub(crate) use scenes::scenes;
use serde::Serialize;

/// Voxels per side of the procedural volumes, by default.
pub(crate) const ML_SIDE: u32 = 128;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::sync::Arc;

/// What a configuration measured.
#[derive(Debug, Clone, Default)]
struct Measured {
    ms: f64,
    cpu_ms: f64,
    samples_per_ray: f64,
    bricks: u32,
    bytes: u64,
    psnr_db: f64,
    /// PSNR against the finest cut's image from the same renderer and
    /// settings: the level of detail's own error, without the pixel aliasing
    /// and sampling error every configuration shares against the reference.
    psnr_lod_db: f64,
    mse: f64,
    flip: f64,
    ssim: f64,
}

/// The suite's options.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Image side in pixels.
    #[arg(long, default_value_t = 512, value_parser = crate::image_side)]
    size: u32,
    /// Interleaved rounds.
    #[arg(long, default_value_t = 3, value_parser = crate::at_least_one::<usize>)]
    rounds: usize,
    /// Volumes, comma-separated, of ct, ct5, mri, nuclei, ml, noise (default all).
    #[arg(long, value_delimiter = ',')]
    scenes: Vec<String>,
    /// Voxels per side of the procedural volumes.
    #[arg(long, default_value_t = ML_SIDE, value_parser = crate::at_least_one::<u32>)]
    ml_side: u32,
    /// Where the CSV and the cached reference images go.
    #[arg(long, default_value = "target/pareto")]
    out: PathBuf,
    /// Where the SVG charts go.
    #[arg(long, default_value = "docs/charts/pareto")]
    charts: PathBuf,
    /// Rays per pixel side of the reference.
    #[arg(long, default_value_t = 2, value_parser = crate::at_least_one::<u32>)]
    supersample: u32,
    /// Knobs swept, comma-separated (default all; the defaults always run):
    /// step, preint, adaptive, lod_geometric, lod_visible, bricks_geometric,
    /// bricks_visible, bricks_octants, ert, u8_filtering, visibility,
    /// in_core.
    #[arg(long, value_delimiter = ',')]
    knobs: Vec<String>,
    /// Interior voxels per brick side of the stores.
    #[arg(long, default_value_t = 32, value_parser = crate::at_least_one::<u32>)]
    brick: u32,
}

/// One volume and mode: its default configuration and the front.
#[derive(Debug, Serialize)]
pub(crate) struct SceneRow {
    /// volume_mode, e.g. ct_dvr.
    scene: String,
    default_ms: f64,
    default_psnr_db: f64,
    default_bricks: u64,
    /// Whether the default is within 5% of the front (all configurations;
    /// out-of-core configurations only).
    default_on_front: bool,
    default_on_out_of_core_front: bool,
    /// The configurations on the front, as knob=value.
    front: Vec<String>,
}

/// The suite's JSON line. Gains are medians over the scenes, dB (null
/// where no scene had them).
#[derive(Debug, Serialize)]
pub(crate) struct ParetoResult {
    size: u32,
    rounds: usize,
    brick: u32,
    default_on_front_all: bool,
    default_on_out_of_core_front_all: bool,
    visible_error_gain_db_at_equal_bricks: Option<f64>,
    visible_error_gain_db_at_equal_brick_budget: Option<f64>,
    visible_error_gain_db_at_equal_brick_budget_vs_finest: Option<f64>,
    octant_gain_db_at_equal_brick_budget: Option<f64>,
    octant_gain_db_at_equal_brick_budget_vs_finest: Option<f64>,
    preintegration_gain_db_at_step_2: Option<f64>,
    /// The adaptive step at the default step against plain sampling there
    /// (DVR scenes, medians): time over plain time, and PSNR gained.
    adaptive_step_time_ratio: Option<f64>,
    adaptive_step_psnr_gain_db: Option<f64>,
    /// The anisotropic CT's bricks at the default 1 px (DVR).
    anisotropic_ct_bricks_at_1px: Option<u64>,
    scenes: Vec<SceneRow>,
}

pub(crate) fn run(o: &Args) -> Result<ParetoResult, String> {
    let scenes = scenes(&o.scenes, o.ml_side)?;
    let gpu = GpuContext::new().map_err(|e| e.to_string())?;
    println!("adapter: {}", gpu.describe());
    println!(
        "image {0}x{0}; {1} interleaved rounds; reference: step 1/8 voxel, {2}x{2} rays per pixel",
        o.size, o.rounds, o.supersample
    );
    std::fs::create_dir_all(&o.out).map_err(|e| format!("{}: {e}", o.out.display()))?;
    std::fs::create_dir_all(&o.charts).map_err(|e| format!("{}: {e}", o.charts.display()))?;
    let run = Runner::new(&gpu, o.size)?;
    let mut csv = String::from(
        "volume,mode,knob,value,ms,cpu_ms,samples_per_ray,bricks,bytes,psnr_db,mean_flip,ssim,on_front,default_within_5pct,psnr_vs_finest_db\n",
    );
    let (mut all_on_front, mut all_on_ooc_front) = (true, true);
    let mut per_scene = Vec::new();
    let (mut visible_gains, mut preint_gains) = (Vec::new(), Vec::new());
    let (mut adaptive_ratios, mut adaptive_gains) = (Vec::new(), Vec::new());
    let (mut budget_gains, mut budget_lod_gains) = (Vec::new(), Vec::new());
    let (mut octant_gains, mut octant_lod_gains) = (Vec::new(), Vec::new());
    let mut aniso_bricks = None;
    for scene in &scenes {
        let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
        let path = dir.path().join("v.brs");
        scene.build_store(o.brick, &path)?;
        let store: Arc<dyn brickray_core::BrickSource> =
            Arc::new(brickray_store::open(&path).map_err(|e| e.to_string())?);
        for (mode_name, mode, tf) in &scene.modes {
            let name = format!("{}_{}", scene.name, mode_name);
            let (finest, finest_rgba) = finest_cut(&run, scene, store.clone(), tf, *mode)?;
            let cfgs: Vec<Config> = configs(
                *mode,
                scene.volume.desc().dtype == brickray_core::DType::U8,
                finest,
            )
            .into_iter()
            .filter(|c| {
                c.knob == "default" || o.knobs.is_empty() || o.knobs.iter().any(|k| k == c.knob)
            })
            .collect();
            let reference = reference(scene, *mode, tf, o)?;
            let images = Images {
                reference: &reference,
                finest: &finest_rgba,
            };
            let m = measure(
                &run,
                scene,
                store.clone(),
                tf,
                &cfgs,
                images,
                o.rounds,
                &mut || Ok(()),
            )?;
            let pts: Vec<(f64, f64)> = m.iter().map(|x| (x.ms, x.mse)).collect();
            let on = front::front(&pts);
            let default_ok = front::within(&pts, 0, 0.05);
            all_on_front &= default_ok;
            // The same among the out-of-core configurations only (the path a
            // volume too large for one texture takes).
            let ooc_pts: Vec<(f64, f64)> = cfgs
                .iter()
                .zip(&pts)
                .filter(|(c, _)| !c.key.in_core)
                .map(|(_, p)| *p)
                .collect();
            let default_ooc_ok = front::within(&ooc_pts, 0, 0.05);
            all_on_ooc_front &= default_ooc_ok;
            println!("\n{name}: {} configurations", cfgs.len());
            println!(
                "  {:<14} {:>9} {:>9} {:>8} {:>7} {:>8} {:>7} {:>7} {:>6} front",
                "knob", "value", "ms", "samples", "bricks", "PSNR", "FLIP", "SSIM", ""
            );
            for (i, (c, x)) in cfgs.iter().zip(&m).enumerate() {
                let f = on.contains(&i);
                println!(
                    "  {:<14} {:>9} {:>9.1} {:>8.1} {:>7} {:>8.2} {:>7.4} {:>7.4} {:>6}",
                    c.knob,
                    c.value,
                    x.ms,
                    x.samples_per_ray,
                    x.bricks,
                    x.psnr_db,
                    x.flip,
                    x.ssim,
                    if f { "*" } else { "" }
                );
                let _ = writeln!(
                    csv,
                    "{},{},{},{},{:.3},{:.3},{:.2},{},{},{:.3},{:.5},{:.5},{},{},{:.3}",
                    scene.name,
                    mode_name,
                    c.knob,
                    c.value,
                    x.ms,
                    x.cpu_ms,
                    x.samples_per_ray,
                    x.bricks,
                    x.bytes,
                    x.psnr_db,
                    x.flip,
                    x.ssim,
                    f,
                    i == 0 && default_ok,
                    x.psnr_lod_db.min(99.0)
                );
            }
            println!(
                "  default within 5% of the front: {default_ok}; of the out-of-core front: {default_ooc_ok}"
            );
            let chart_pts: Vec<chart::ChartPoint<'_>> = cfgs
                .iter()
                .zip(&m)
                .map(|(c, x)| chart::ChartPoint {
                    knob: c.knob,
                    ms: x.ms,
                    psnr_db: x.psnr_db,
                    bricks: if c.key.in_core { 0.0 } else { x.bricks as f64 },
                })
                .collect();
            for (axis, file, what) in [
                (
                    chart::Axis::Time,
                    format!("{name}.svg"),
                    "time against error",
                ),
                (
                    chart::Axis::Bricks,
                    format!("{name}_bricks.svg"),
                    "working set against error",
                ),
            ] {
                let svg = o.charts.join(file);
                let title = format!(
                    "{} {}: {what} ({}x{} px)",
                    scene.name, mode_name, o.size, o.size
                );
                chart::draw(&svg, &title, axis, &chart_pts, &on, 0)?;
                println!("  chart: {}", svg.display());
            }
            if let Some(g) = lod_gain(&cfgs, &m, "lod_visible") {
                println!("  visible-error LOD over geometric at equal bricks: {g:+.2} dB");
                visible_gains.push(g);
            }
            for (knob, order, gains, lod_gains) in [
                (
                    "bricks_visible",
                    "visible-error",
                    &mut budget_gains,
                    &mut budget_lod_gains,
                ),
                (
                    "bricks_octants",
                    "octant-granular visible-error",
                    &mut octant_gains,
                    &mut octant_lod_gains,
                ),
            ] {
                if let Some((g, gl)) = brick_budget_gain(&cfgs, &m, knob) {
                    println!(
                        "  {order} order over geometric order at equal brick budgets: {g:+.2} dB \
                         against the reference, {gl:+.2} dB against the finest cut"
                    );
                    gains.push(g);
                    lod_gains.push(gl);
                }
            }
            if let Some(g) = preint_gain(&cfgs, &m) {
                println!("  pre-integration at step 2: {g:+.2} dB");
                preint_gains.push(g);
            }
            for step in [0.25f32, 0.5, 1.0, 2.0] {
                if let Some((r, g)) = adaptive_vs_plain(&cfgs, &m, step) {
                    println!("  adaptive step at {step} voxel: {r:.2}x the time, {g:+.2} dB");
                    if step == base_settings(*mode).step_factor {
                        adaptive_ratios.push(r);
                        adaptive_gains.push(g);
                    }
                }
            }
            let d = &m[0];
            if scene.anisotropic && *mode_name == "dvr" {
                aniso_bricks = Some(d.bricks);
            }
            per_scene.push(SceneRow {
                scene: name,
                default_ms: round2(d.ms),
                default_psnr_db: finite_db(d.psnr_db),
                default_bricks: d.bricks as u64,
                default_on_front: default_ok,
                default_on_out_of_core_front: default_ooc_ok,
                front: on
                    .iter()
                    .map(|&i| format!("{}={}", cfgs[i].knob, cfgs[i].value))
                    .collect(),
            });
        }
    }
    let csv_path = o.out.join("pareto.csv");
    std::fs::write(&csv_path, csv).map_err(|e| format!("{}: {e}", csv_path.display()))?;
    println!("\ndata: {}", csv_path.display());
    // Each gain's median over the scenes (null where no scene had it).
    let med = |gains: &[f64]| (!gains.is_empty()).then(|| round2(median(gains)));
    Ok(ParetoResult {
        size: o.size,
        rounds: o.rounds,
        brick: o.brick,
        default_on_front_all: all_on_front,
        default_on_out_of_core_front_all: all_on_ooc_front,
        visible_error_gain_db_at_equal_bricks: med(&visible_gains),
        visible_error_gain_db_at_equal_brick_budget: med(&budget_gains),
        visible_error_gain_db_at_equal_brick_budget_vs_finest: med(&budget_lod_gains),
        octant_gain_db_at_equal_brick_budget: med(&octant_gains),
        octant_gain_db_at_equal_brick_budget_vs_finest: med(&octant_lod_gains),
        preintegration_gain_db_at_step_2: med(&preint_gains),
        adaptive_step_time_ratio: med(&adaptive_ratios),
        adaptive_step_psnr_gain_db: med(&adaptive_gains),
        anisotropic_ct_bricks_at_1px: aniso_bricks.map(|b| b as u64),
        scenes: per_scene,
    })
}

/// The scene's f64 reference image (RGBA8 over black) with the mode's base
/// settings, cached under `o.out` by scene, mode, size and supersampling.
fn reference(
    scene: &Scene,
    mode: RenderMode,
    tf: &TransferFunction,
    o: &Args,
) -> Result<Vec<u8>, String> {
    let tag = match mode {
        RenderMode::Dvr => "dvr".to_string(),
        RenderMode::Iso { value, .. } => format!("iso{value}"),
        RenderMode::Mip => "mip".to_string(),
        _ => "other".to_string(),
    };
    reference_image(
        scene,
        tf,
        &base_settings(mode),
        &tag,
        o.size,
        o.supersample,
        &o.out,
    )
}

/// The scene's f64 reference image (RGBA8 over black) with `settings`,
/// cached in `out` by scene, `tag` (what names the settings), size and
/// supersampling.
fn reference_image(
    scene: &Scene,
    tf: &TransferFunction,
    settings: &brickray_core::RenderSettings,
    tag: &str,
    size: u32,
    supersample: u32,
    out: &std::path::Path,
) -> Result<Vec<u8>, String> {
    let path = out.join(format!(
        "ref_{}_{}_{}_ss{}_{}.rgba",
        scene.name,
        tag,
        size,
        supersample,
        cache_tag(scene, tf)
    ));
    if let Ok(b) = std::fs::read(&path)
        && b.len() == (size * size * 4) as usize
    {
        return Ok(b);
    }
    let t = std::time::Instant::now();
    let img = render_reference(
        &scene.volume,
        &scene.frame,
        tf,
        &scene.camera,
        settings,
        &ReferenceOptions::new(size, size).with_supersample(supersample),
    );
    let rgba = img.to_rgba8([0.0; 3]);
    println!(
        "reference {} {tag}: {:.1} s",
        scene.name,
        t.elapsed().as_secs_f64()
    );
    std::fs::write(&path, &rgba).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(rgba)
}

/// A short hash of what the reference depends on besides name and mode (the
/// volume's description and the TF's table), so a changed scene is re-rendered.
fn cache_tag(scene: &Scene, tf: &TransferFunction) -> String {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    format!("{:?}{:?}", scene.volume.desc(), scene.camera).hash(&mut h);
    for c in tf.entries() {
        for x in c {
            x.to_bits().hash(&mut h);
        }
    }
    format!("{:016x}", h.finish())
}

/// The images a configuration's image is compared with (RGBA8, the suite's
/// size).
#[derive(Clone, Copy)]
struct Images<'a> {
    /// The f64 CPU reference.
    reference: &'a [u8],
    /// The finest cut's (tolerance 0), drawn by the renderer with the base
    /// settings.
    finest: &'a [u8],
}

/// Builds one renderer per distinct key, converges each on the view, then times
/// every configuration over interleaved rounds and reads its image;
/// `between` runs after each round (another renderer timed in turn).
#[allow(clippy::too_many_arguments)]
fn measure(
    run: &Runner<'_>,
    scene: &Scene,
    store: Arc<dyn brickray_core::BrickSource>,
    tf: &TransferFunction,
    cfgs: &[Config],
    images: Images<'_>,
    rounds: usize,
    between: &mut dyn FnMut() -> Result<(), String>,
) -> Result<Vec<Measured>, String> {
    let reference = images.reference;
    let gpu = run.gpu;
    let mut keys: Vec<RendererKey> = Vec::new();
    for c in cfgs {
        if !keys.contains(&c.key) {
            keys.push(c.key);
        }
    }
    let brick_bytes = store.layout().brick_bytes() as u64;
    let mut renderers = Vec::new();
    for k in &keys {
        let mut r = VolumeRenderer::with_options(
            &gpu.device,
            brickray_harness::target_desc(),
            RendererOptions {
                u8_filtering: k.u8_filtering,
                ..Default::default()
            },
        )
        .map_err(|e| e.to_string())?;
        if k.in_core {
            r.set_volume(&gpu.device, &gpu.queue, &scene.volume)
                .map_err(|e| e.to_string())?;
        } else {
            let config = OutOfCoreConfig {
                tolerance_px: k.tolerance_px,
                lod_metric: k.metric,
                brick_budget: k.brick_budget,
                upload_budget_bytes: 1 << 30,
                ..Default::default()
            };
            let options = brickray_render::VolumeOptions {
                u8_filtering: k.u8_filtering,
                gradients: crate::runner::keep_gradients(k.gradients),
                ..Default::default()
            };
            let v = brickray_render::StreamedVolume::new(
                &gpu.device,
                &gpu.queue,
                store.clone(),
                config,
                options,
            )
            .map_err(|e| e.to_string())?;
            r.set_streamed_volume(&gpu.device, &v)
                .map_err(|e| e.to_string())?;
            crate::runner::configure(gpu, &r, |c| c.visibility = k.policy)?;
        }
        r.set_transfer_function(&gpu.device, &gpu.queue, tf)
            .map_err(|e| e.to_string())?;
        renderers.push(r);
    }
    let slot = |c: &Config| keys.iter().position(|k| *k == c.key).expect("key listed");
    // Converge: render (visibility feedback needs ray-cast frames) until the
    // cut is settled, at least a few frames so read-backs arrive.
    for c in cfgs {
        let r = &mut renderers[slot(c)];
        if c.key.in_core {
            continue;
        }
        let mut settled = false;
        for i in 0..400 {
            run.frame(r, scene.camera, scene.frame, c.settings, false)?;
            let s = r.stats().out_of_core.ok_or("not out of core")?;
            if s.converged && i >= 8 {
                settled = true;
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        if !settled {
            println!(
                "  warning: {}={} did not converge in 400 frames",
                c.knob, c.value
            );
        }
    }
    let mut times = vec![Vec::new(); cfgs.len()];
    let mut cpu = vec![Vec::new(); cfgs.len()];
    // Each round starts at another configuration, so a position effect in the
    // round (the first frames after a pause run slower) falls on each in turn.
    let n = cfgs.len();
    for round in 0..rounds {
        for j in 0..n {
            let i = (j + round * n / rounds) % n;
            let c = &cfgs[i];
            let r = &mut renderers[slot(c)];
            // One untimed frame absorbs a settings change (tables, pipelines).
            run.frame(r, scene.camera, scene.frame, c.settings, false)?;
            let s = run.frame(r, scene.camera, scene.frame, c.settings, false)?;
            times[i].push(s.ms);
            cpu[i].push(s.cpu_ms);
        }
        between()?;
    }
    let (w, h) = (run.size, run.size);
    let mut out = Vec::new();
    for (i, c) in cfgs.iter().enumerate() {
        let r = &mut renderers[slot(c)];
        let shot = run.frame(r, scene.camera, scene.frame, c.settings, true)?;
        let bricks = r
            .stats()
            .out_of_core
            .map_or(0, |s| s.cache.working_set_bricks);
        let bytes = if c.key.in_core {
            scene.volume.desc().byte_len()
        } else {
            bricks as u64 * brick_bytes
        };
        let p = psnr(&shot.rgba, reference);
        let psnr_lod_db = psnr(&shot.rgba, images.finest);
        out.push(Measured {
            ms: median(&times[i]),
            cpu_ms: median(&cpu[i]),
            samples_per_ray: shot.samples,
            bricks,
            bytes,
            psnr_db: p,
            psnr_lod_db,
            mse: 255.0f64.powi(2) / 10f64.powf(p / 10.0),
            flip: mean_flip(&shot.rgba, reference, w, h) as f64,
            ssim: ssim(&shot.rgba, reference, w, h),
        });
    }
    Ok(out)
}

/// The data bricks of the finest cut (tolerance 0, geometric) of a scene's
/// mode, what the brick-budget sweeps take fractions of, and its image with
/// the base settings.
fn finest_cut(
    run: &Runner<'_>,
    scene: &Scene,
    store: Arc<dyn brickray_core::BrickSource>,
    tf: &TransferFunction,
    mode: RenderMode,
) -> Result<(u32, Vec<u8>), String> {
    let gpu = run.gpu;
    let mut r = VolumeRenderer::new(&gpu.device, brickray_harness::target_desc())
        .map_err(|e| e.to_string())?;
    r.set_volume_source(
        &gpu.device,
        &gpu.queue,
        store,
        OutOfCoreConfig {
            tolerance_px: 0.0,
            upload_budget_bytes: 1 << 30,
            ..Default::default()
        },
    )
    .map_err(|e| e.to_string())?;
    r.set_transfer_function(&gpu.device, &gpu.queue, tf)
        .map_err(|e| e.to_string())?;
    let settings = base_settings(mode);
    let (frames, stats) = run.converge(&mut r, scene.camera, scene.frame, settings, 400)?;
    frames.ok_or_else(|| format!("the finest cut did not converge: {stats:?}"))?;
    let shot = run.frame(&mut r, scene.camera, scene.frame, settings, true)?;
    Ok((stats.cache.working_set_bricks, shot.rgba))
}
