//! The `visibility` suite: what visibility feedback (docs/visibility.md) takes
//! out of the working set, at what cost in image and latency.
//!
//! Scenes: the head CT (256 x 256 x 108 i16, bricks of `--head-brick`, 32 by
//! default) with the opaque bone
//! TF, the translucent soft-tissue TF and the bone isosurface (400 HU), all
//! shaded; a procedural volume of concentric shells in a ball
//! (`ProceduralSource::sphere_shells`, `--shell-dims`, default 4096^3) under an
//! opaque TF, so its outer shell hides the rest. Policies: none and ray-guided
//! (occlusion queries are reported when the renderer supports them). Each
//! policy has its own renderer and source; their frames are interleaved, policy
//! by policy, along one scripted camera path:
//!
//! 1. hold the start view until every policy converged (at most `--hold`
//!    frames);
//! 2. turn half way round the volume in `--turn` frames, revealing the side
//!    hidden so far;
//! 3. hold the view from behind until every policy converged;
//! 4. jump back to the start view and hold until every policy converged.
//!
//! Per policy: working-set bricks along the path (median, peak), bytes
//! uploaded, frames to converge at the start view, ms per frame (`prepare +
//! submit + wait`, median) and host ms per frame (`prepare` alone, median),
//! working set / oracle, PSNR of the converged images (start and back views)
//! against those of no culling, and the disocclusion latency: frames from
//! reaching the back view until its image is within 50 dB of the unculled
//! converged one (`disocc`), and the same after a final jump back to the start
//! view in one frame, which reveals the side hidden from behind at once
//! (`jump`; frames until within 50 dB of the unculled start image). The oracle (start view): the unculled converged cut's data
//! leaves that at least one ray reaches (the renderer's own usage counts: the
//! bricks whose samples the image uses at the needed level), and the smallest
//! hole-free cut holding them (every ancestor split, its other non-empty
//! children kept as leaves). Timings are wall times on a shared machine:
//! compare the ratios within one run, not across runs.

use brickray_core::{
    BrickSource, Camera, NodeKey, RenderSettings, Shading, TransferFunction, Volume, VolumeFrame,
};
use brickray_harness::{GpuContext, Offscreen, ct, target_desc as targets};
use brickray_render::{
    FrameDesc, OutOfCoreConfig, OutOfCoreStats, VisibilityPolicy, VolumeRenderer,
};
mod report;

use report::{SceneResult, headline, report, write_chart};
use serde::Serialize;
use std::collections::HashSet;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// PSNR above which a frame counts as the converged image.
const SAME_DB: f64 = 50.0;

struct Scene {
    name: &'static str,
    /// "opaque" or "translucent" for the headline figures.
    kind: &'static str,
    source: Arc<dyn Fn() -> Result<Arc<dyn BrickSource>, String>>,
    frame: VolumeFrame,
    tf: TransferFunction,
    settings: RenderSettings,
    distance: f32,
}

/// Working set along the path per policy, for one scene's chart.
type Chart = (String, Vec<(String, Vec<f64>)>);
/// One host frame: (wall ms, prepare ms, ray-cast pass ms by timestamps, bytes uploaded,
/// image when read).
type FrameOut = (f64, f64, Option<f64>, u64, Option<Vec<u8>>);

/// What one policy did on one scene.
#[derive(Default)]
struct Track {
    working: Vec<f64>,
    uploaded: u64,
    ms: Vec<f64>,
    host_ms: Vec<f64>,
    gpu_ms: Vec<f64>,
    converge_start: Option<usize>,
    start: Option<(Vec<u8>, OutOfCoreStats)>,
    back: Option<(Vec<u8>, OutOfCoreStats)>,
    back_frames: Vec<Vec<u8>>,
    jump_frames: Vec<Vec<u8>>,
    oracle_usage: Option<Vec<(NodeKey, u32)>>,
}

struct Runner<'a> {
    gpu: &'a GpuContext,
    target: Offscreen,
    size: u32,
    /// Times the ray-cast pass where the device has timestamps.
    timer: Option<brickray_harness::GpuTimer>,
}

impl Runner<'_> {
    /// One host frame ([`FrameOut`]).
    fn frame(
        &self,
        r: &mut VolumeRenderer,
        scene: &Scene,
        camera: Camera,
        read: bool,
    ) -> Result<FrameOut, String> {
        let g = self.gpu;
        let timed = self
            .timer
            .as_ref()
            .is_some_and(|t| r.set_pass_timestamps(&g.device, Some(t.writes())).is_ok());
        let t0 = Instant::now();
        let mut enc = g.device.create_command_encoder(&Default::default());
        let desc = FrameDesc {
            camera,
            frame: scene.frame,
            viewport: brickray_render::Viewport::full(self.size, self.size),
            settings: scene.settings,
            host_depth: None,
            time: Some(brickray_harness::host_time()),
        };
        let fs = r.prepare(&g.device, &g.queue, &mut enc, &desc);
        let host = t0.elapsed().as_secs_f64() * 1e3;
        if timed {
            let _ = r.set_pass_timestamps(&g.device, None);
        }
        let fs = fs.map_err(|e| e.to_string())?;
        {
            let mut pass = self.target.pass(&mut enc, true);
            r.render(&mut pass).map_err(|e| e.to_string())?;
        }
        let timer = self.timer.as_ref().filter(|_| timed);
        if let Some(t) = timer {
            t.resolve(&mut enc);
        }
        g.submit_wait(enc);
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        let gpu_ms = timer.and_then(|t| t.read_ms(g));
        let img = read.then(|| self.target.read_color(g));
        Ok((ms, host, gpu_ms, fs.uploaded_bytes, img))
    }
}

fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn r2(x: f64) -> f64 {
    (x * 100.0).round() / 100.0
}

/// The suite's options.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Scenes, comma-separated, of head, shells.
    #[arg(long, default_value = "head,shells")]
    scenes: String,
    /// Image side of the head CT scenes.
    #[arg(long, default_value_t = 256, value_parser = crate::image_side)]
    size: u32,
    /// Brick side of the head CT's store.
    #[arg(long, default_value_t = 32)]
    head_brick: u32,
    /// Image side of the shells scene.
    #[arg(long, default_value_t = 512, value_parser = crate::image_side)]
    shell_size: u32,
    /// Voxels per side of the shells volume.
    #[arg(long, default_value_t = 4096)]
    shell_dims: u64,
    /// Most frames each view is held.
    #[arg(long, default_value_t = 120, value_parser = crate::at_least_one::<usize>)]
    hold: usize,
    /// Frames of the half turn.
    #[arg(long, default_value_t = 12, value_parser = crate::at_least_one::<usize>)]
    turn: usize,
    /// Write the working-set chart (SVG) here.
    #[arg(long)]
    svg: Option<String>,
    /// GPU pool budget per renderer in MiB (the unculled run must not be
    /// capped by it, or the cut is measured against a pool-limited baseline).
    #[arg(long, default_value_t = 1024)]
    gpu_mib: u64,
    /// CPU brick cache budget per renderer in MiB.
    #[arg(long, default_value_t = 512)]
    cpu_mib: u64,
    /// Only the start view: working set, oracle and image, no turn.
    #[arg(long)]
    start_only: bool,
    /// Policies, comma-separated, of rayguided, occlusion, both (none, the
    /// baseline, always runs).
    #[arg(long, default_value = "none,rayguided,occlusion,both")]
    policies: String,
}

/// The suite's JSON line.
#[derive(Debug, Serialize)]
pub(crate) struct VisibilityResult {
    image_size: u32,
    shell_image_size: u32,
    shell_dims: u64,
    adapter: String,
    scenes: Vec<SceneResult>,
    /// The smallest cut over the scenes of a kind, per policy (null when
    /// not run).
    cut_opaque_occlusion: Option<f64>,
    cut_opaque_rayguided: Option<f64>,
    cut_translucent_occlusion: Option<f64>,
    cut_translucent_rayguided: Option<f64>,
    /// On opaque scenes, the worst over scenes of each scene's best culled
    /// policy's oracle ratios.
    oracle_ratio_best: Option<f64>,
    oracle_cut_ratio_best: Option<f64>,
    /// The lowest PSNR of a culled policy, the longest disocclusion.
    psnr_min_culled_db: Option<f64>,
    disocclusion_frames_max: Option<usize>,
}

pub(crate) fn run(args: &Args) -> Result<VisibilityResult, String> {
    let (size, hold, turn, gpu_mib, cpu_mib, start_only) = (
        args.size,
        args.hold,
        args.turn,
        args.gpu_mib,
        args.cpu_mib,
        args.start_only,
    );
    let (shell_dims, shell_size) = (args.shell_dims, args.shell_size);
    let scenes_arg = &args.scenes;
    let svg = args.svg.clone();
    let gpu = GpuContext::new().map_err(|e| e.to_string())?;
    println!("adapter: {}", gpu.describe());
    // `--policies none,rayguided,...` restricts the run (none always runs: it
    // is the baseline every figure is relative to).
    let wanted = &args.policies;
    let want = |p: VisibilityPolicy| wanted.split(',').any(|w| w.trim() == p.name());
    let mut policies = vec![VisibilityPolicy::None];
    if want(VisibilityPolicy::RayGuided) {
        policies.push(VisibilityPolicy::RayGuided);
    }
    for p in [VisibilityPolicy::OcclusionQueries, VisibilityPolicy::Both] {
        if !want(p) {
            continue;
        }
        if supported(&gpu, p) {
            policies.push(p);
        } else {
            println!(
                "policy {} not supported by this renderer: not run",
                p.name()
            );
        }
    }
    let mut scenes = Vec::new();
    if scenes_arg.contains("head") {
        scenes.extend(head_scenes(args.head_brick)?);
    }
    if scenes_arg.contains("shells") {
        scenes.push(shells_scene(shell_dims));
    }
    let mut results = Vec::new();
    let mut chart: Vec<Chart> = Vec::new();
    let t = Instant::now();
    for scene in &scenes {
        let px = if scene.name == "shells" {
            shell_size
        } else {
            size
        };
        let runner = Runner {
            gpu: &gpu,
            target: Offscreen::new(&gpu.device, px, px),
            size: px,
            timer: brickray_harness::GpuTimer::new(&gpu),
        };
        println!(
            "\n{} ({px}x{px}): hold <= {hold}, turn {turn} frames, hold <= {hold}",
            scene.name
        );
        let tracks = run_scene(
            &runner,
            scene,
            &policies,
            (hold, turn, (gpu_mib, cpu_mib), start_only),
        )?;
        results.push(report(scene, &policies, &tracks)?);
        chart.push((
            format!("{} ({px}x{px})", scene.name),
            policies
                .iter()
                .zip(&tracks)
                .map(|(p, t)| (p.name().to_string(), t.working.clone()))
                .collect(),
        ));
    }
    let h = headline(&results);
    println!("\nheadline: {h:?}");
    if let Some(path) = svg {
        write_chart(&path, &chart)?;
        println!("chart: {path}");
    }
    println!("\nsuite wall time: {:.0} s", t.elapsed().as_secs_f64());
    Ok(VisibilityResult {
        image_size: size,
        shell_image_size: shell_size,
        shell_dims,
        adapter: gpu.adapter.get_info().name,
        scenes: results,
        cut_opaque_occlusion: h.cuts[0],
        cut_opaque_rayguided: h.cuts[1],
        cut_translucent_occlusion: h.cuts[2],
        cut_translucent_rayguided: h.cuts[3],
        oracle_ratio_best: h.oracle_ratio_best,
        oracle_cut_ratio_best: h.oracle_cut_ratio_best,
        psnr_min_culled_db: h.psnr_min,
        disocclusion_frames_max: h.disocclusion_max,
    })
}

fn supported(gpu: &GpuContext, p: VisibilityPolicy) -> bool {
    let Ok(mut r) = VolumeRenderer::new(&gpu.device, targets()) else {
        return false;
    };
    let src = match brickray_store::ProceduralSource::sphere_shells([64; 3], 32, 2) {
        Ok(s) => Arc::new(s),
        Err(_) => return false,
    };
    r.set_volume_source(&gpu.device, &gpu.queue, src, OutOfCoreConfig::default())
        .is_ok()
        && crate::runner::configure(gpu, &r, |c| c.visibility = p).is_ok()
}

fn head_scenes(brick: u32) -> Result<Vec<Scene>, String> {
    let path = brickray_harness::shared_volume("invesalius_cranium_ct")
        .ok_or("the visibility suite needs ../shared/data/invesalius_cranium_ct")?;
    let vol: Volume = brickray_io::read_volume(&path).map_err(|e| e.to_string())?;
    let d = vol.desc().clone();
    let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
    let store_path = dir.path().join("head.brs");
    crate::runner::build_store(vol, brick, &store_path)?;
    // The store is opened once per renderer; the directory lives as long as
    // the closure.
    let dir = Arc::new(dir);
    let open: Arc<dyn Fn() -> Result<Arc<dyn BrickSource>, String>> = Arc::new(move || {
        let _keep = &dir;
        Ok(
            Arc::new(brickray_store::open(&store_path).map_err(|e| e.to_string())?)
                as Arc<dyn BrickSource>,
        )
    });
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let shaded = RenderSettings {
        shading: Shading {
            enabled: true,
            ..Default::default()
        },
        ..Default::default()
    };
    let [(_, _, translucent), (_, _, bone), (_, iso_mode, iso_tf), _] = ct::scenes();
    Ok(vec![
        Scene {
            name: "head_opaque",
            kind: "opaque",
            source: open.clone(),
            frame,
            tf: bone,
            settings: shaded,
            distance: 2.0,
        },
        Scene {
            name: "head_translucent",
            kind: "translucent",
            source: open.clone(),
            frame,
            tf: translucent,
            settings: shaded,
            distance: 2.0,
        },
        Scene {
            name: "head_iso",
            kind: "opaque",
            source: open,
            frame,
            tf: iso_tf,
            settings: RenderSettings {
                mode: iso_mode,
                ..shaded
            },
            distance: 2.0,
        },
    ])
}

fn shells_scene(dims: u64) -> Scene {
    Scene {
        name: "shells",
        kind: "opaque",
        source: Arc::new(move || {
            Ok(Arc::new(
                brickray_store::ProceduralSource::sphere_shells([dims; 3], 32, 2)
                    .map_err(|e| e.to_string())?,
            ) as Arc<dyn BrickSource>)
        }),
        frame: VolumeFrame::centered([dims as u32; 3], [1.0; 3]),
        tf: TransferFunction::from_points(
            &[(0.15, [0.9, 0.8, 0.7, 0.0]), (0.22, [0.9, 0.8, 0.7, 1.0])],
            256,
        ),
        settings: RenderSettings::default(),
        distance: 1.8,
    }
}

fn camera(scene: &Scene, turn: f32) -> Camera {
    Camera::orbit(scene.frame.center(), scene.distance, 0.5 + turn, 0.3)
}

fn run_scene(
    runner: &Runner<'_>,
    scene: &Scene,
    policies: &[VisibilityPolicy],
    (hold, turn, (gpu_mib, cpu_mib), start_only): (usize, usize, (u64, u64), bool),
) -> Result<Vec<Track>, String> {
    let g = runner.gpu;
    let mut rs = Vec::new();
    for &p in policies {
        let mut r = VolumeRenderer::new(&g.device, targets()).map_err(|e| e.to_string())?;
        r.set_volume_source(
            &g.device,
            &g.queue,
            (scene.source)()?,
            OutOfCoreConfig {
                gpu_budget_bytes: gpu_mib << 20,
                cpu_budget_bytes: cpu_mib << 20,
                ..Default::default()
            },
        )
        .map_err(|e| e.to_string())?;
        r.set_transfer_function(&g.device, &g.queue, &scene.tf)
            .map_err(|e| e.to_string())?;
        crate::runner::configure(g, &r, |c| c.visibility = p)?;
        rs.push(r);
    }
    let mut tracks: Vec<Track> = policies.iter().map(|_| Track::default()).collect();
    let step = |r: &mut VolumeRenderer, t: &mut Track, cam: Camera, read: bool| {
        let (ms, host, gpu_ms, bytes, img) = runner.frame(r, scene, cam, read)?;
        let s = r.stats().out_of_core.ok_or("not out of core")?;
        t.working.push(s.cache.working_set_bricks as f64);
        t.uploaded += bytes;
        t.ms.push(ms);
        t.host_ms.push(host);
        t.gpu_ms.extend(gpu_ms);
        Ok::<_, String>((s, img))
    };
    // 1. The start view, until every policy converged.
    let start = camera(scene, 0.0);
    let mut done = vec![false; policies.len()];
    for f in 1..=hold {
        for (i, (r, t)) in rs.iter_mut().zip(tracks.iter_mut()).enumerate() {
            let (s, _) = step(r, t, start, false)?;
            if s.converged && !done[i] {
                done[i] = true;
                t.converge_start = Some(f);
            }
        }
        if done.iter().all(|d| *d) {
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    // A few more frames: converged images and the usage of the converged cut.
    for (r, t) in rs.iter_mut().zip(tracks.iter_mut()) {
        for _ in 0..4 {
            step(r, t, start, false)?;
        }
        let (s, img) = step(r, t, start, true)?;
        let c = &s.cache;
        println!(
            "  converged start: {} bricks, pool {} slots ({} occupied), splits blocked: {:?}",
            c.working_set_bricks, c.pool_slots, c.pool_occupied, c.blocked
        );
        t.start = Some((img.unwrap_or_default(), s));
        t.oracle_usage = r.last_usage().map(|u| u.counts.clone());
    }
    if start_only {
        return Ok(tracks);
    }
    // 2. The half turn.
    for k in 1..=turn {
        let cam = camera(scene, std::f32::consts::PI * k as f32 / turn as f32);
        for (r, t) in rs.iter_mut().zip(tracks.iter_mut()) {
            step(r, t, cam, false)?;
        }
    }
    // 3. The back view, until every policy converged; images kept for the
    // disocclusion latency.
    let back = camera(scene, std::f32::consts::PI);
    let mut done = vec![false; policies.len()];
    for _ in 1..=hold {
        for (i, (r, t)) in rs.iter_mut().zip(tracks.iter_mut()).enumerate() {
            if done[i] {
                step(r, t, back, false)?;
                continue;
            }
            let (s, img) = step(r, t, back, true)?;
            t.back_frames.push(img.unwrap_or_default());
            if s.converged {
                done[i] = true;
            }
        }
        if done.iter().all(|d| *d) {
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    for (r, t) in rs.iter_mut().zip(tracks.iter_mut()) {
        let (s, img) = step(r, t, back, true)?;
        let c = &s.cache;
        println!(
            "  back view: {} bricks, pool {} slots ({} occupied), splits blocked: {:?}, converged {}",
            c.working_set_bricks, c.pool_slots, c.pool_occupied, c.blocked, s.converged
        );
        t.back = Some((img.unwrap_or_default(), s));
    }
    // 4. A jump back to the start view in one frame: the side hidden from
    // behind is revealed at once; frames kept for its latency.
    let mut done = vec![false; policies.len()];
    for _ in 1..=hold {
        for (i, (r, t)) in rs.iter_mut().zip(tracks.iter_mut()).enumerate() {
            if done[i] {
                continue;
            }
            let (s, img) = step(r, t, start, true)?;
            t.jump_frames.push(img.unwrap_or_default());
            done[i] = s.converged;
        }
        if done.iter().all(|d| *d) {
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    Ok(tracks)
}
