//! The `prediction` suite: the isosurface prediction buffer (Braley et al.;
//! docs/prediction.md) against the full traversal, in core or (`--backend ooc`)
//! out of core.
//!
//! Out of core, each scene is built into a brick store (default options:
//! 32-voxel bricks) and drawn at its finest level (`tolerance_px` 0), so the
//! images are those of the in-core path up to the bricks' seams; every
//! renderer first settles on the path's first view without prediction (the
//! whole volume stays in view along the paths, so the cut stays the same),
//! then switches its prediction on. Frames where a renderer's cut was not
//! settled are counted (`unsettled_frames`).
//!
//! Variants, interleaved frame by frame (the order rotates each frame): `full`
//! (no prediction: the reference), `paper` (alpha 10, kappa 0.5), `ess`
//! (+ empty-space skipping in the sparse traversal), `reproj` (+ reprojection),
//! `reproj_ess` (both), `guard` (+ the first-hit guard) and `all` (all three). Every variant's image is compared with the full
//! traversal's image of the same frame: wrong pixels (a channel off by more
//! than 2 levels; mean and max share over frames) and PSNR. Time is
//! `prepare + submit + wait` wall time; speedups are ratios of the summed
//! times of the same frames.
//!
//! Paths: the paper's 360-degree orbit on the head CT, the shared MRI and a
//! procedural volume of nested surfaces; the failure path (a small ball slides
//! in front of the large one in view, then the camera stops) with per-frame
//! wrong pixels and the frames until they are gone; a translation + zoom path.

use crate::runner::{finite_db, round2};
use brickray_core::{
    Accel, Camera, RenderMode, RenderSettings, TransferFunction, Volume, VolumeFrame,
};
use brickray_harness::predict::{self, FrameResult};
use brickray_harness::{GpuContext, Offscreen, ct};
use brickray_reference::psnr;
use brickray_render::{FrameDesc, Prediction, TraversalClass, VolumeRenderer};
use glam::Vec3;
use serde::Serialize;
use std::collections::BTreeMap;

/// `(name, prediction)` of every variant; `full` first. `kappa`: the sparse
/// step's (the paper's 0.5 unless `--kappa` says otherwise).
fn variants(kappa: f32) -> Vec<(&'static str, Option<Prediction>)> {
    let p = Prediction {
        kappa,
        ..Prediction::PAPER
    };
    vec![
        ("full", None),
        ("paper", Some(p)),
        (
            "ess",
            Some(Prediction {
                sparse_ess: true,
                ..p
            }),
        ),
        (
            "reproj",
            Some(Prediction {
                reproject: true,
                ..p
            }),
        ),
        (
            "reproj_ess",
            Some(Prediction {
                reproject: true,
                sparse_ess: true,
                ..p
            }),
        ),
        ("guard", Some(Prediction { guard: true, ..p })),
        (
            "all",
            Some(Prediction {
                guard: true,
                sparse_ess: true,
                reproject: true,
                ..p
            }),
        ),
    ]
}

struct Scene {
    name: &'static str,
    vol: Volume,
    isovalue: f32,
}

/// Where the suite's volumes live: a 3D texture, or brick stores in a
/// temporary directory drawn out of core.
enum Backend {
    InCore,
    OutOfCore(tempfile::TempDir),
}

impl Backend {
    fn parse(name: &str) -> Result<Backend, String> {
        match name {
            "incore" => Ok(Backend::InCore),
            "ooc" => Ok(Backend::OutOfCore(
                tempfile::tempdir().map_err(|e| e.to_string())?,
            )),
            _ => Err(format!("--backend {name}: expected incore or ooc")),
        }
    }

    fn name(&self) -> &'static str {
        match self {
            Backend::InCore => "incore",
            Backend::OutOfCore(_) => "ooc",
        }
    }

    /// A renderer of the scene's volume (out of core: its store, built once,
    /// at the finest level).
    fn renderer(&self, gpu: &GpuContext, scene: &Scene) -> Result<VolumeRenderer, String> {
        match self {
            Backend::InCore => {
                let mut r = VolumeRenderer::new(&gpu.device, brickray_harness::target_desc())
                    .map_err(|e| e.to_string())?;
                r.set_volume(&gpu.device, &gpu.queue, &scene.vol)
                    .map_err(|e| e.to_string())?;
                Ok(r)
            }
            Backend::OutOfCore(dir) => {
                let path = dir.path().join(format!("{}.brs", scene.name));
                let source: std::sync::Arc<dyn brickray_core::BrickSource> = if path.exists() {
                    std::sync::Arc::new(brickray_store::open(&path).map_err(|e| e.to_string())?)
                } else {
                    brickray_harness::store_of(&scene.vol, &path)
                };
                crate::runner::finest_ooc_renderer(gpu, source, Default::default())
            }
        }
    }
}

fn iso(value: f32, accel: Accel) -> RenderSettings {
    RenderSettings {
        mode: RenderMode::Iso {
            value,
            color: [0.9, 0.85, 0.75],
        },
        accel,
        ..Default::default()
    }
}

/// The accelerations of a run: the renderer's default (ERT and ESS: the full
/// traversal skips empty macro cells) or none (the paper's full traversal).
fn accel_of(name: &str) -> Accel {
    if name == "brute" {
        Accel::BRUTE_FORCE
    } else {
        Accel::default()
    }
}

/// Per-frame figures of one variant along a path.
#[derive(Default, Clone)]
struct Track {
    ms: Vec<f64>,
    /// The ray-cast pass by GPU timestamps, where the device has them.
    gpu_ms: Vec<f64>,
    wrong: Vec<f64>,
    psnr: Vec<f64>,
    samples: Vec<f64>,
    /// Wrong pixels by the traversal class that drew them (summed over frames).
    wrong_by_class: [u64; 6],
    /// Frames drawn while this renderer's cut was not settled (out of core).
    unsettled: usize,
}

/// One variant along one path.
#[derive(Debug, Clone, Serialize)]
pub(crate) struct Summary {
    /// full, paper, guard, ... (`variants()`).
    variant: &'static str,
    /// Mean ms per frame, and `full`'s total time over this variant's.
    ms: f64,
    /// Mean ray-cast pass time by GPU timestamps (null without).
    gpu_ms: Option<f64>,
    speedup: f64,
    samples_per_ray: f64,
    /// Pixels that differ from `full`'s image, % of the image: mean and
    /// largest over the frames.
    wrong_mean_pct: f64,
    wrong_max_pct: f64,
    /// The smallest PSNR against `full` over the frames.
    psnr_min_db: f64,
    /// Frames identical to `full`'s.
    frames_exact: usize,
    /// Frames drawn while the cut was not settled (out of core).
    unsettled_frames: usize,
    /// Wrong pixels by the traversal class that drew them (summed over
    /// frames; classes with none left out).
    wrong_px_by_class: BTreeMap<String, u64>,
}

/// One orbit.
#[derive(Debug, Serialize)]
pub(crate) struct OrbitResult {
    /// head_ct, mri or nested_shells.
    scene: &'static str,
    /// default or brute (the accelerations).
    accel: &'static str,
    variants: Vec<Summary>,
    /// Traversal classes of the paper variant's last predicted frame, %.
    paper_classes_pct: Option<BTreeMap<String, f64>>,
}

/// The failure path.
#[derive(Debug, Serialize)]
pub(crate) struct FailureResult {
    variants: Vec<Summary>,
    /// Frames after the camera stopped until the paper variant's wrong
    /// pixels are gone (null: never within the path).
    recovery_frames_paper: Option<usize>,
}

/// The suite's options.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Image side in pixels.
    #[arg(long, default_value_t = 256, value_parser = crate::image_side)]
    size: u32,
    /// Frames of each orbit.
    #[arg(long, default_value_t = 120, value_parser = crate::at_least_one::<usize>)]
    frames: usize,
    /// Write the failure path's chart (SVG) here.
    #[arg(long)]
    chart: Option<String>,
    /// Write the traversal-class image (PNG) here.
    #[arg(long)]
    classes_png: Option<String>,
    /// Sparse traversal's kappa (default the paper's 0.5).
    #[arg(long, default_value_t = Prediction::PAPER.kappa)]
    kappa: f32,
    /// 1: also time full traversal without empty-space skipping.
    #[arg(long, default_value_t = 1)]
    brute: u32,
    /// `incore` or `ooc`: brick stores drawn out of core at the finest level.
    #[arg(long, default_value = "incore")]
    backend: String,
}

/// The suite's JSON line.
#[derive(Debug, Serialize)]
pub(crate) struct PredictionResult {
    size: u32,
    backend: &'static str,
    kappa: f32,
    frames: usize,
    orbit: Vec<OrbitResult>,
    failure: FailureResult,
    /// The translation + zoom path on the first scene.
    translate_zoom: Vec<Summary>,
    /// On the first scene's orbit: the paper variant's speedup over full
    /// (with default accelerations, and with brute force), and its mean
    /// wrong pixels, %.
    speedup_paper: f64,
    speedup_paper_vs_brute: f64,
    wrong_pixels_mean_paper_orbit: f64,
    /// The fastest variant exact on every orbit and the failure path.
    best_exact: &'static str,
    speedup_best_exact: f64,
    /// The largest wrong pixels on the failure path, %: paper and guard.
    wrong_pixels_max_paper: f64,
    wrong_pixels_max_guarded: f64,
    recovery_frames_paper: Option<usize>,
}

impl Track {
    fn summary(&self, variant: &'static str, full: &Track) -> Summary {
        let n = self.ms.len().max(1) as f64;
        let sum = |v: &[f64]| v.iter().sum::<f64>();
        let finite: Vec<f64> = self
            .psnr
            .iter()
            .copied()
            .filter(|x| x.is_finite())
            .collect();
        Summary {
            variant,
            ms: round2(sum(&self.ms) / n),
            gpu_ms: (!self.gpu_ms.is_empty())
                .then(|| round2(sum(&self.gpu_ms) / self.gpu_ms.len() as f64)),
            speedup: round2(sum(&full.ms) / sum(&self.ms)),
            samples_per_ray: round2(sum(&self.samples) / n),
            wrong_mean_pct: (sum(&self.wrong) / n * 1e4).round() / 1e2,
            wrong_max_pct: (self.wrong.iter().copied().fold(0.0, f64::max) * 1e4).round() / 1e2,
            psnr_min_db: finite_db(finite.iter().copied().fold(f64::INFINITY, f64::min)),
            frames_exact: self.wrong.iter().filter(|&&w| w == 0.0).count(),
            unsettled_frames: self.unsettled,
            wrong_px_by_class: TraversalClass::ALL
                .iter()
                .filter(|(_, c)| self.wrong_by_class[*c as usize] > 0)
                .map(|(n, c)| {
                    (
                        n.trim_start_matches("TRAVERSAL_").to_lowercase(),
                        self.wrong_by_class[*c as usize],
                    )
                })
                .collect(),
        }
    }
}

/// Draws `cameras` with every variant, interleaved; returns one track per
/// variant (in `variants()` order) and the classes of the last predicted frame
/// of the `paper` variant.
fn run_path(
    gpu: &GpuContext,
    scene: &Scene,
    size: u32,
    cameras: &[Camera],
    accel: Accel,
    kappa: f32,
    backend: &Backend,
) -> Result<(Vec<Track>, Option<FrameResult>), String> {
    let d = scene.vol.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let vs = variants(kappa);
    let mut rs = Vec::new();
    for (_, p) in &vs {
        let mut r = backend.renderer(gpu, scene)?;
        r.set_transfer_function(
            &gpu.device,
            &gpu.queue,
            &TransferFunction::ramp(0.0, 1.0, 1.0),
        )
        .map_err(|e| e.to_string())?;
        let t = Offscreen::new(&gpu.device, size, size);
        // Settle on the first view (out of core: load its cut), then predict
        // from frame 0 of the path.
        let first = FrameDesc {
            settings: iso(scene.isovalue, accel),
            ..FrameDesc::new(cameras[0], frame, size, size)
        };
        brickray_harness::draw_until_settled(gpu, &mut r, &t, &first, 400)
            .map_err(|e| e.to_string())?
            .ok_or("the renderer did not settle on the first view")?;
        r.set_prediction(*p).map_err(|e| e.to_string())?;
        // Compile the pipeline before the timed frames.
        r.warm_up(&gpu.device, &[iso(scene.isovalue, accel)])
            .map_err(|e| e.to_string())?;
        rs.push((r, t));
    }
    let mut tracks = vec![Track::default(); vs.len()];
    let timer = brickray_harness::GpuTimer::new(gpu);
    let mut last_paper = None;
    for (i, cam) in cameras.iter().enumerate() {
        let desc = FrameDesc {
            settings: iso(scene.isovalue, accel),
            ..FrameDesc::new(*cam, frame, size, size)
        };
        let mut shots: Vec<Option<FrameResult>> = vec![None; vs.len()];
        for j in 0..vs.len() {
            let k = (i + j) % vs.len();
            let (r, t) = &mut rs[k];
            shots[k] = Some(
                predict::draw_timed(gpu, r, t, &desc, timer.as_ref()).map_err(|e| e.to_string())?,
            );
            if r.stats().out_of_core.is_some_and(|s| !s.converged) {
                tracks[k].unsettled += 1;
            }
        }
        let shots: Vec<FrameResult> = shots.into_iter().map(Option::unwrap).collect();
        for (k, s) in shots.iter().enumerate() {
            let t = &mut tracks[k];
            t.ms.push(s.ms);
            t.gpu_ms.extend(s.gpu_ms);
            t.wrong
                .push(predict::wrong_share(&s.color, &shots[0].color));
            t.psnr.push(psnr(&s.color, &shots[0].color));
            t.samples.push(predict::samples_per_ray(&s.samples));
            if let Some(c) = &s.classes {
                let wrong = s.color.chunks_exact(4).zip(shots[0].color.chunks_exact(4));
                for (class, (p, q)) in c.iter().zip(wrong) {
                    let off = p
                        .iter()
                        .zip(q)
                        .any(|(x, y)| x.abs_diff(*y) > predict::WRONG_LEVELS);
                    if off && (*class as usize) < 6 {
                        t.wrong_by_class[*class as usize] += 1;
                    }
                }
            }
        }
        if i % 10 != 0 {
            last_paper = Some(shots[1].clone());
        }
    }
    Ok((tracks, last_paper))
}

fn orbit(center: Vec3, distance: f32, frames: usize) -> Vec<Camera> {
    (0..frames)
        .map(|i| {
            let yaw = std::f32::consts::TAU * i as f32 / frames as f32;
            Camera::orbit(center, distance, yaw, 0.3)
        })
        .collect()
}

fn class_share(r: &FrameResult) -> Option<BTreeMap<String, f64>> {
    let c = r.classes.as_ref()?;
    let mut m = BTreeMap::new();
    for (name, class) in TraversalClass::ALL {
        let n = c.iter().filter(|&&x| x == class as u32).count();
        m.insert(
            name.trim_start_matches("TRAVERSAL_").to_lowercase(),
            round2(100.0 * n as f64 / c.len() as f64),
        );
    }
    Some(m)
}

fn save_classes(r: &FrameResult, size: u32, path: &str) -> Result<(), String> {
    let c = r.classes.as_ref().ok_or("no classes")?;
    let rgba: Vec<u8> = c
        .iter()
        .flat_map(|&k| {
            let [r, g, b] = TraversalClass::from_code(k).map_or([255, 0, 255], |c| c.debug_color());
            [r, g, b, 255]
        })
        .collect();
    brickray_reference::save_rgba8_png(path, &rgba, size, size).map_err(|e| e.to_string())
}

pub(crate) fn run(args: &Args) -> Result<PredictionResult, String> {
    let (size, frames, kappa) = (args.size, args.frames, args.kappa);
    let chart = args.chart.clone().unwrap_or_default();
    let classes_png = args.classes_png.clone().unwrap_or_default();
    let brute = args.brute == 1;
    let backend = Backend::parse(&args.backend)?;
    let gpu = GpuContext::new().map_err(|e| e.to_string())?;
    println!("adapter: {}", gpu.describe());
    println!(
        "image {size}x{size}; orbit of {frames} frames; kappa {kappa}; {} ; variants interleaved frame by frame",
        backend.name()
    );
    let mut scenes = Vec::new();
    if let Some(p) = brickray_harness::shared_volume("invesalius_cranium_ct") {
        let vol = brickray_io::read_volume(&p).map_err(|e| e.to_string())?;
        scenes.push(Scene {
            name: "head_ct",
            vol,
            isovalue: ct::hu(400.0),
        });
    } else {
        println!("head CT absent: skipped");
    }
    if let Some(p) = brickray_harness::shared_volume("pycortex_s1_t1_mri") {
        let vol = brickray_io::read_volume(&p).map_err(|e| e.to_string())?;
        scenes.push(Scene {
            name: "mri",
            vol,
            isovalue: 0.3,
        });
    } else {
        println!("MRI absent: skipped");
    }
    scenes.push(Scene {
        name: "nested_shells",
        vol: predict::nested_shells(128),
        isovalue: 0.5,
    });
    let names: Vec<&'static str> = variants(kappa).iter().map(|v| v.0).collect();
    let mut orbit_results = Vec::new();
    let mut speedup_paper = 0.0;
    let mut speedup_paper_brute = 0.0;
    let mut wrong_mean_paper = 0.0;
    let mut exact_orbit = vec![true; names.len()];
    let mut speed_ct = vec![0.0; names.len()];
    let accels: &[&str] = if brute {
        &["default", "brute"]
    } else {
        &["default"]
    };
    for &accel_name in accels {
        for scene in &scenes {
            let d = scene.vol.desc();
            let frame = VolumeFrame::centered(d.dims, d.spacing);
            let accel = accel_of(accel_name);
            let (tracks, last) = run_path(
                &gpu,
                scene,
                size,
                &orbit(frame.center(), 2.0, frames),
                accel,
                kappa,
                &backend,
            )?;
            let default = accel_name == "default";
            println!(
                "\norbit, {} {:?} isovalue {:.4}, accelerations {accel_name}:",
                scene.name, d.dims, scene.isovalue
            );
            let mut summaries = Vec::new();
            let mut paper_classes_pct = None;
            for (k, t) in tracks.iter().enumerate() {
                let s = t.summary(names[k], &tracks[0]);
                println!("  {:6} {s:?}", names[k]);
                if default && t.wrong.iter().any(|&w| w > 0.0) {
                    exact_orbit[k] = false;
                }
                if default && scene.name == scenes[0].name {
                    speed_ct[k] = s.speedup;
                }
                if scene.name == scenes[0].name && k == 1 {
                    if default {
                        speedup_paper = s.speedup;
                        wrong_mean_paper = s.wrong_mean_pct;
                    } else {
                        speedup_paper_brute = s.speedup;
                    }
                }
                summaries.push(s);
            }
            if let Some(l) = &last {
                let c = class_share(l);
                println!(
                    "  paper, traversal classes of its last predicted frame (% of pixels): {c:?}"
                );
                paper_classes_pct = c;
                if !classes_png.is_empty() && default && scene.name == scenes[0].name {
                    save_classes(l, size, &classes_png)?;
                    println!("  wrote {classes_png}");
                }
            }
            orbit_results.push(OrbitResult {
                scene: scene.name,
                accel: accel_name,
                variants: summaries,
                paper_classes_pct,
            });
        }
    }

    // The failure path: the small ball slides in front of the large one for
    // `moving` frames, then the camera stops.
    let moving = 24;
    let still = 15;
    let occ = Scene {
        name: "occluder",
        vol: predict::occluder_scene(128),
        isovalue: 0.5,
    };
    let d = occ.vol.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let cams: Vec<Camera> = (0..moving + still)
        .map(|i| {
            let yaw = -0.9 + 0.06 * i.min(moving - 1) as f32;
            Camera::orbit(frame.center(), 2.2, yaw, 0.1)
        })
        .collect();
    let (tracks, _) = run_path(&gpu, &occ, size, &cams, Accel::default(), kappa, &backend)?;
    println!("\nfailure path (occluder; camera moves {moving} frames, then stops {still}):");
    let mut fail = Vec::new();
    for (k, t) in tracks.iter().enumerate() {
        println!("  {:6} {:?}", names[k], t.summary(names[k], &tracks[0]));
        let pct: Vec<String> = t
            .wrong
            .iter()
            .map(|w| format!("{:.2}", 100.0 * w))
            .collect();
        println!("         wrong % per frame: {}", pct.join(" "));
        fail.push(t.summary(names[k], &tracks[0]));
    }
    // Frames after the camera stopped until the paper's wrong pixels are gone.
    let recovery_paper = tracks[1].wrong[moving..].iter().position(|&w| w == 0.0);
    let failure = FailureResult {
        variants: fail,
        recovery_frames_paper: recovery_paper,
    };
    let exact_fail: Vec<bool> = tracks
        .iter()
        .map(|t| t.wrong.iter().all(|&w| w == 0.0))
        .collect();
    if !chart.is_empty() {
        use crate::chart::{Panel, Series};
        let panel = |title: &str, ys: &dyn Fn(&Track) -> Vec<f64>| {
            let mut p = Panel::new(
                title,
                "frame",
                "",
                tracks
                    .iter()
                    .zip(&names)
                    .map(|(t, n)| Series::indexed(*n, ys(t)))
                    .collect(),
            );
            p.y_from_zero = true;
            p.marker_x = Some(moving as f64);
            p
        };
        crate::chart::draw(
            std::path::Path::new(&chart),
            900,
            320,
            &[
                panel("ms per frame (prepare + submit + wait)", &|t| t.ms.clone()),
                panel("wrong pixels (% of the image, vs full traversal)", &|t| {
                    t.wrong.iter().map(|w| 100.0 * w).collect()
                }),
            ],
        )?;
        println!("wrote {chart}");
    }
    let wrong_max =
        |k: usize| (tracks[k].wrong.iter().copied().fold(0.0, f64::max) * 1e4).round() / 1e2;

    // Translation + zoom on the first scene: what reprojection keeps of the
    // coherence that the paper's per-pixel prediction loses.
    let scene = &scenes[0];
    let d = scene.vol.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let c = frame.center();
    let n = frames.min(60);
    let cams: Vec<Camera> = (0..n)
        .map(|i| {
            let f = i as f32 / n as f32;
            let mut cam = Camera::orbit(c, 2.4 - 0.8 * f, 0.5, 0.25);
            let shift = Vec3::new(0.25 * f - 0.1, 0.1 * f, 0.0);
            cam.eye += shift;
            cam.target += shift;
            cam
        })
        .collect();
    let (tracks, _) = run_path(&gpu, scene, size, &cams, Accel::default(), kappa, &backend)?;
    println!("\ntranslation + zoom, {} ({n} frames):", scene.name);
    let mut translate_zoom = Vec::new();
    for (k, t) in tracks.iter().enumerate() {
        let s = t.summary(names[k], &tracks[0]);
        println!("  {:6} {s:?}", names[k]);
        translate_zoom.push(s);
    }

    // The fastest variant (on the first scene's orbit) whose wrong pixels stay
    // at 0 on the orbits and the failure path; `full` itself is exact.
    let best_exact = (0..names.len())
        .filter(|&k| exact_orbit[k] && exact_fail[k])
        .max_by(|&a, &b| speed_ct[a].total_cmp(&speed_ct[b]))
        .unwrap_or(0);
    println!(
        "\nbest exact variant: {} ({}x)",
        names[best_exact], speed_ct[best_exact]
    );
    let guard = names
        .iter()
        .position(|n| *n == "guard")
        .expect("a guard variant");
    Ok(PredictionResult {
        size,
        backend: backend.name(),
        kappa,
        frames,
        orbit: orbit_results,
        failure,
        translate_zoom,
        speedup_paper,
        speedup_paper_vs_brute: speedup_paper_brute,
        wrong_pixels_mean_paper_orbit: wrong_mean_paper,
        best_exact: names[best_exact],
        speedup_best_exact: speed_ct[best_exact],
        wrong_pixels_max_paper: wrong_max(1),
        wrong_pixels_max_guarded: wrong_max(guard),
        recovery_frames_paper: recovery_paper,
    })
}
