//! The soak: thousands of frames of an out-of-core volume far larger than its
//! pool, with every feature of the out-of-core path at work: a random camera
//! each frame (jumps, inside the volume, extreme zoom, every depth
//! convention); DVR, iso with the prediction buffer, and MIP; visibility
//! feedback from both the ray caster's usage counts and occlusion queries;
//! level-of-detail fades. Process memory is sampled as it goes, and [`FeatureFrames`]
//! counts the frames in which each feature was active. Shared by
//! `brickray-bench soak` (10,000 frames) and the CI test (1,000 frames).

use crate::{GpuContext, Offscreen, draw_frame};
use brickray_core::{
    Camera, DepthConvention, Projection, RenderMode, RenderSettings, TransferFunction, VolumeFrame,
};
use brickray_render::{FrameDesc, OutOfCoreConfig, Prediction, VisibilityPolicy, VolumeRenderer};
use glam::Vec3;
use std::panic::AssertUnwindSafe;
use std::sync::Arc;
use std::time::Instant;

/// What a soak renders.
#[derive(Debug, Clone, Copy)]
pub struct SoakConfig {
    /// Frames to render.
    pub frames: usize,
    /// Viewport side in pixels.
    pub size: u32,
    /// Side of the procedural volume in voxels.
    pub volume: u64,
    /// GPU pool budget.
    pub gpu_budget_bytes: u64,
    /// CPU cache budget.
    pub cpu_budget_bytes: u64,
    /// Sample process memory every this many frames.
    pub sample_every: usize,
    /// Seed of the camera path.
    pub seed: u64,
    /// The isosurface prediction buffer on iso frames (`None`: off).
    pub prediction: Option<Prediction>,
    /// Visibility feedback.
    pub visibility: VisibilityPolicy,
}

impl Default for SoakConfig {
    /// The soak: 10,000 frames at 64x64 of a 65536^3 volume through a
    /// 64 MiB pool and a 32 MiB CPU cache, memory every 250 frames; the
    /// prediction buffer on iso frames, visibility from usage counts and
    /// occlusion queries, fades of the default 120 ms.
    fn default() -> Self {
        SoakConfig {
            frames: 10_000,
            size: 64,
            volume: 65536,
            gpu_budget_bytes: 64 << 20,
            cpu_budget_bytes: 32 << 20,
            sample_every: 250,
            seed: 0x5eed_b71c,
            prediction: Some(Prediction::PAPER),
            visibility: VisibilityPolicy::Both,
        }
    }
}

/// Frames in which each feature of the soak was at work.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FeatureFrames {
    /// Frames drawn without error (the share's denominator).
    pub frames: usize,
    /// DVR frames.
    pub dvr: usize,
    /// Isosurface frames.
    pub iso: usize,
    /// MIP frames.
    pub mip: usize,
    /// Frames with reversed-Z depth.
    pub reversed_z: usize,
    /// Frames that predicted (`FrameStats::prediction`: iso frames with the
    /// prediction buffer on).
    pub prediction: usize,
    /// Frames whose cut held leaves visibility feedback had observed
    /// (visible or invisible).
    pub visibility: usize,
    /// Frames whose cut held leaves observed invisible (refinement culls
    /// them).
    pub culled: usize,
    /// Frames that issued occlusion queries.
    pub occlusion_queries: usize,
    /// Frames that applied a usage-count read-back.
    pub usage_feedback: usize,
    /// Frames with leaves fading between levels of detail.
    pub fades: usize,
    /// Frames that uploaded bricks.
    pub uploads: usize,
}

impl FeatureFrames {
    /// `count` as a share of the frames drawn.
    pub fn share(&self, count: usize) -> f64 {
        count as f64 / self.frames.max(1) as f64
    }

    /// One line: each feature's frames and share.
    pub fn describe(&self) -> String {
        let f = |name: &str, n: usize| format!("{name} {n} ({:.0}%)", 100.0 * self.share(n));
        [
            f("dvr", self.dvr),
            f("iso", self.iso),
            f("mip", self.mip),
            f("reversed-z", self.reversed_z),
            f("prediction", self.prediction),
            f("visibility", self.visibility),
            f("culled", self.culled),
            f("occlusion queries", self.occlusion_queries),
            f("usage feedback", self.usage_feedback),
            f("fades", self.fades),
            f("uploads", self.uploads),
        ]
        .join(", ")
            + &format!(" of {} frames", self.frames)
    }
}

/// What a soak measured.
#[derive(Debug, Clone, Default)]
pub struct SoakReport {
    /// `(frame, resident set size in bytes)` every `sample_every` frames.
    pub rss: Vec<(usize, u64)>,
    /// Wall time of each frame (`prepare + submit + wait`), ms.
    pub frame_ms: Vec<f64>,
    /// Volume samples the rays of each frame took (the work of the frame).
    pub samples: Vec<u64>,
    /// Frames whose `prepare` returned an error.
    pub errors: usize,
    /// Frames that panicked (caught).
    pub panics: usize,
    /// The first error or panic message.
    pub first_failure: Option<String>,
    /// Frames in which each feature was active.
    pub features: FeatureFrames,
}

fn median(v: &[f64]) -> f64 {
    percentile(v, 0.5)
}

/// The `p` quantile (nearest rank) of `v`; 0 for an empty slice.
pub fn percentile(v: &[f64], p: f64) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s[((s.len() - 1) as f64 * p).round() as usize]
}

impl SoakReport {
    /// RSS at the first sample at or after `frame`.
    pub fn rss_at(&self, frame: usize) -> u64 {
        self.rss
            .iter()
            .find(|(f, _)| *f >= frame)
            .or(self.rss.last())
            .map_or(0, |s| s.1)
    }

    /// RSS growth from the sample at `from` to the last one, in percent.
    pub fn rss_growth_pct(&self, from: usize) -> f64 {
        let a = self.rss_at(from) as f64;
        let b = self.rss.last().map_or(0, |s| s.1) as f64;
        if a > 0.0 { 100.0 * (b - a) / a } else { 0.0 }
    }

    /// Median frame time of the last `n` frames over that of the first `n`.
    pub fn drift(&self, n: usize) -> f64 {
        let n = n.min(self.frame_ms.len() / 2).max(1);
        let first = median(&self.frame_ms[..n]);
        let last = median(&self.frame_ms[self.frame_ms.len() - n..]);
        if first > 0.0 { last / first } else { 0.0 }
    }

    /// Frames over `factor` times the median frame time. With a random camera
    /// this counts the views that are legitimately expensive too (a MIP ray
    /// through a finely refined 65536^3 volume takes thousands of samples, a
    /// view of nothing none).
    pub fn slow_frames(&self, factor: f64) -> usize {
        let m = median(&self.frame_ms);
        self.frame_ms.iter().filter(|&&t| t > factor * m).count()
    }

    /// Stalls, as `(frame, ms, samples)`: frames over `factor` times both the
    /// median frame time and what their own work predicts (their samples times the median time per
    /// sample). These are the frames where the system, not the view, was slow:
    /// compilation, blocking I/O, memory pressure, a leak.
    pub fn stalls(&self, factor: f64) -> Vec<(usize, f64, u64)> {
        let m = median(&self.frame_ms);
        let per_sample: Vec<f64> = self
            .frame_ms
            .iter()
            .zip(&self.samples)
            .filter(|(_, s)| **s > 0)
            .map(|(t, s)| t / *s as f64)
            .collect();
        let k = median(&per_sample);
        self.frame_ms
            .iter()
            .zip(&self.samples)
            .enumerate()
            .filter(|(_, (t, s))| **t > factor * m.max(k * **s as f64))
            .map(|(i, (t, s))| (i, *t, *s))
            .collect()
    }

    /// `(median, p99)` frame time of each block of `block` frames.
    pub fn blocks(&self, block: usize) -> Vec<(f64, f64)> {
        self.frame_ms
            .chunks(block.max(1))
            .map(|c| (median(c), percentile(c, 0.99)))
            .collect()
    }
}

/// The process's resident set size in bytes (Linux; 0 elsewhere).
pub fn rss_bytes() -> u64 {
    std::fs::read_to_string("/proc/self/statm")
        .ok()
        .and_then(|s| s.split_whitespace().nth(1)?.parse::<u64>().ok())
        .map_or(0, |pages| pages * 4096)
}

/// A small deterministic generator (xorshift64*), so the path is the same on
/// every run.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f32 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        ((self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 40) as f32) / (1u64 << 24) as f32
    }

    fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.next()
    }

    fn unit(&mut self) -> Vec3 {
        Vec3::new(
            self.range(-1.0, 1.0),
            self.range(-1.0, 1.0),
            self.range(-1.0, 1.0),
        )
        .normalize_or(Vec3::X)
    }
}

/// A random camera: an orbit at any distance (60%), inside the volume (20%), or
/// an extreme zoom (20%); any depth convention, sometimes an infinite far plane.
/// (Yaws span 0..6.283, about a turn: the literal is part of the recorded path.)
#[allow(clippy::approx_constant)]
fn random_camera(rng: &mut Rng, centre: Vec3) -> Camera {
    let pick = rng.next();
    let mut c = if pick < 0.6 {
        Camera::orbit(
            centre,
            rng.range(0.55, 4.0),
            rng.range(0.0, 6.283),
            rng.range(-1.4, 1.4),
        )
    } else if pick < 0.8 {
        let eye = centre + rng.unit() * rng.range(0.0, 0.45);
        Camera {
            eye,
            target: eye + rng.unit(),
            ..Camera::orbit(centre, 1.0, 0.0, 0.0)
        }
    } else {
        let mut c = Camera::orbit(
            centre + rng.unit() * 0.3,
            rng.range(1.0, 6.0),
            rng.range(0.0, 6.283),
            rng.range(-1.2, 1.2),
        );
        c.projection = Projection::Perspective {
            fov_y: rng.range(0.2, 3.0).to_radians(),
        };
        c
    };
    c.near = rng.range(1e-4, 1e-2);
    if rng.next() < 0.3 {
        c.far = f32::INFINITY;
    }
    if rng.next() < 0.5 {
        c.depth = DepthConvention::ReversedZ;
    }
    if rng.next() < 0.1 {
        c.far = c.far.min(20.0);
        c.projection = Projection::Orthographic {
            height: rng.range(0.01, 2.0),
        };
    }
    c
}

fn modes_list() -> [RenderMode; 3] {
    [
        RenderMode::Dvr,
        RenderMode::Iso {
            value: 0.62,
            color: [0.9, 0.8, 0.7],
        },
        RenderMode::Mip,
    ]
}

/// Runs a soak; `progress` is called after each frame with the frame number and
/// its time.
pub fn run(
    gpu: &GpuContext,
    config: SoakConfig,
    mut progress: impl FnMut(usize, f64),
) -> Result<SoakReport, String> {
    let dims = [config.volume; 3];
    let source = Arc::new(
        brickray_store::ProceduralSource::fractal_noise(dims, 32, 2).map_err(|e| e.to_string())?,
    );
    let frame = VolumeFrame::centered(dims.map(|d| d as u32), [1.0; 3]);
    let mut renderer =
        VolumeRenderer::new(&gpu.device, crate::target_desc()).map_err(|e| e.to_string())?;
    let ooc = OutOfCoreConfig {
        gpu_budget_bytes: config.gpu_budget_bytes,
        cpu_budget_bytes: config.cpu_budget_bytes,
        visibility: config.visibility,
        ..Default::default()
    };
    renderer
        .set_volume_source(&gpu.device, &gpu.queue, source, ooc)
        .map_err(|e| e.to_string())?;
    let tf = TransferFunction::from_points(
        &[(0.5, [0.2, 0.5, 1.0, 0.0]), (0.75, [1.0, 0.8, 0.5, 0.05])],
        256,
    );
    renderer
        .set_transfer_function(&gpu.device, &gpu.queue, &tf)
        .map_err(|e| e.to_string())?;
    renderer
        .set_prediction(config.prediction)
        .map_err(|e| e.to_string())?;
    // Pipelines compile at set-up, as a viewer would, not in the first frames.
    let all: Vec<RenderSettings> = modes_list()
        .iter()
        .map(|&mode| RenderSettings {
            mode,
            ..Default::default()
        })
        .collect();
    renderer
        .warm_up(&gpu.device, &all)
        .map_err(|e| e.to_string())?;
    // One target per depth convention (cleared to its far value).
    let targets = [DepthConvention::Standard, DepthConvention::ReversedZ]
        .map(|d| Offscreen::with(&gpu.device, config.size, config.size, 1, d));
    let mut rng = Rng(config.seed | 1);
    let mut report = SoakReport::default();
    let modes = modes_list();
    let mut usage_applied = 0;
    for i in 0..config.frames {
        let camera = random_camera(&mut rng, frame.center());
        let mode = modes[(rng.next() * 3.0) as usize % 3];
        let settings = RenderSettings {
            mode,
            ..Default::default()
        };
        let target = &targets[(camera.depth == DepthConvention::ReversedZ) as usize];
        let desc = FrameDesc {
            settings,
            ..FrameDesc::new(camera, frame, config.size, config.size)
        };
        let t = Instant::now();
        let result = std::panic::catch_unwind(AssertUnwindSafe(|| {
            draw_frame(gpu, &mut renderer, target, &desc, Some(wgpu::Color::BLACK))
        }));
        let ms = t.elapsed().as_secs_f64() * 1e3;
        match result {
            Ok(Ok(stats)) => {
                let f = &mut report.features;
                f.frames += 1;
                match mode {
                    RenderMode::Dvr => f.dvr += 1,
                    RenderMode::Iso { .. } => f.iso += 1,
                    _ => f.mip += 1,
                }
                f.reversed_z += (camera.depth == DepthConvention::ReversedZ) as usize;
                f.prediction += stats.prediction.is_some() as usize;
                if let Some(o) = renderer.stats().out_of_core {
                    let v = o.visibility;
                    f.visibility += (v.visible + v.invisible > 0) as usize;
                    f.culled += (v.invisible > 0) as usize;
                    f.occlusion_queries += (o.occlusion.queries > 0) as usize;
                    f.usage_feedback += (o.feedback.frames_applied > usage_applied) as usize;
                    usage_applied = o.feedback.frames_applied;
                    f.fades += (o.cache.fading > 0) as usize;
                    f.uploads += (o.cache.upload_bricks > 0) as usize;
                }
            }
            Ok(Err(e)) => {
                report.errors += 1;
                report
                    .first_failure
                    .get_or_insert_with(|| format!("frame {i}: {e}"));
            }
            Err(p) => {
                report.panics += 1;
                let msg = p
                    .downcast_ref::<&str>()
                    .map(|s| s.to_string())
                    .or_else(|| p.downcast_ref::<String>().cloned())
                    .unwrap_or_default();
                report
                    .first_failure
                    .get_or_insert_with(|| format!("frame {i}: panic {msg}"));
            }
        }
        report.frame_ms.push(ms);
        let samples = renderer.sample_count_texture().map_or(0, |t| {
            crate::read_texture(gpu, t, 4, wgpu::TextureAspect::All)
                .chunks_exact(4)
                .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]) as u64)
                .sum()
        });
        report.samples.push(samples);
        if (i + 1) % config.sample_every == 0 || i + 1 == config.frames {
            report.rss.push((i + 1, rss_bytes()));
        }
        progress(i, ms);
    }
    Ok(report)
}
