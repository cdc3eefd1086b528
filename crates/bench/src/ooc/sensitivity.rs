//! Part (b) of the `ooc` suite: output sensitivity over the procedural source.

use super::*;
use crate::runner::Shot;

/// Treats every brick as resident: refinement then yields the cut the view
/// converges to (with unlimited uploads), whose levels we count.
struct AllResident<'a>(&'a dyn BrickSource);

impl RefineEnv for AllResident<'_> {
    fn node(&mut self, key: NodeKey) -> MetaState {
        self.0.node(key).map_or(MetaState::Failed, |i| {
            MetaState::Known(std::sync::Arc::new(i))
        })
    }
    fn data(&mut self, _key: NodeKey) -> DataState {
        DataState::OnGpu
    }
}

/// Data leaves per level of the converged cut of a view.
fn cut_levels(
    source: &dyn BrickSource,
    camera: &Camera,
    frame: &VolumeFrame,
    size: u32,
    tf: &TransferFunction,
    tolerance_px: f32,
    max_data_leaves: u32,
) -> Vec<u32> {
    let layout = source.layout().clone();
    let params = RefineParams {
        views: &brickray_cache::Views::one(brickray_cache::refine::ViewGeometry::new(
            &layout, camera, 1.0, size, frame,
        )),
        generation: 0,
        mode: RenderMode::Dvr,
        tf,
        channels: &[],
        tolerance_px,
        metric: brickray_core::LodMetric::Geometric,
        max_data_leaves,
        max_requests: u32::MAX,
        max_prefetch: u32::MAX,
        brick_upload_bytes: layout.brick_bytes() as u64,
        lookahead: false,
    };
    let mut budget = brickray_cache::UploadBudget::new(u64::MAX / 4);
    budget.begin_frame();
    let cut =
        brickray_cache::refine::refine(&layout, &params, &mut AllResident(source), &mut budget);
    let mut per_level = vec![0u32; layout.levels as usize];
    for l in &cut.leaves {
        if l.class == NodeClass::Data {
            per_level[l.key.level as usize] += 1;
        }
    }
    per_level
}

fn levels_text(per_level: &[u32]) -> String {
    per_level
        .iter()
        .enumerate()
        .filter(|(_, n)| **n > 0)
        .map(|(l, n)| format!("L{l}:{n}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// (b) One volume size.
#[derive(Debug, Serialize)]
pub(crate) struct SizeRow {
    dims: u64,
    #[serde(flatten)]
    time: Timing,
    working_set_bricks: u64,
    samples_per_ray: f64,
    frames_to_converge: usize,
}

/// (b) The largest size against a smaller one.
#[derive(Debug, Serialize)]
pub(crate) struct SizeRatio {
    /// The smaller size.
    vs_dims: u64,
    time_ratio: f64,
    bricks_ratio: f64,
}

/// (b) Output sensitivity from one view.
#[derive(Debug, Serialize)]
pub(crate) struct Sensitivity {
    /// far (a voxel of 256^3 about a pixel) or close.
    view: &'static str,
    distance: f32,
    sizes: Vec<SizeRow>,
    /// The largest size against each smaller one, the smallest first.
    ratios: Vec<SizeRatio>,
}

/// (b) Output sensitivity over the procedural source, from an orbit camera at
/// `distance` (world units; the box's longest side is 1), the view named
/// `view`.
pub(super) fn part_b(
    gpu: &GpuContext,
    size: u32,
    rounds: usize,
    distance: f32,
    view: &'static str,
) -> Result<Sensitivity, String> {
    let suffix = view;
    println!(
        "\n(b{suffix}) output sensitivity: procedural fractal noise (bricks {BRICK}+2x{APRON}), same view (orbit at distance {distance}), tolerance 1 px,"
    );
    println!(
        "  TF opacity per world length of the {TF_REFERENCE_DIMS}^3 voxel (the same image at every size)"
    );
    let settings = RenderSettings::default();
    let run = Runner::new(gpu, size)?;
    let config = OutOfCoreConfig {
        gpu_budget_bytes: 1 << 30,
        upload_budget_bytes: 1 << 30,
        ..Default::default()
    };
    struct Entry {
        dims: u64,
        frame: VolumeFrame,
        renderer: VolumeRenderer,
        source: Arc<dyn BrickSource>,
        frames: usize,
        stats: OutOfCoreStats,
        samples: f64,
        times: Vec<Shot>,
    }
    let mut entries = Vec::new();
    let mut camera = None;
    for dims in SIZES {
        let source = noise_source(dims)?;
        let frame = VolumeFrame::centered([dims as u32; 3], [1.0; 3]);
        let cam = *camera.get_or_insert_with(|| Camera::orbit(frame.center(), distance, 0.5, 0.3));
        let mut renderer =
            VolumeRenderer::new(&gpu.device, targets()).map_err(|e| e.to_string())?;
        renderer
            .set_volume_source(&gpu.device, &gpu.queue, source.clone(), config)
            .map_err(|e| e.to_string())?;
        renderer
            .set_transfer_function(
                &gpu.device,
                &gpu.queue,
                &noise_tf_world(dims, TF_REFERENCE_DIMS),
            )
            .expect("transfer function");
        let t = Instant::now();
        let (frames, stats) = run.converge(&mut renderer, cam, frame, settings, 600)?;
        let frames = frames.ok_or_else(|| format!("(b) {dims}^3: not converged: {stats:?}"))?;
        println!(
            "  {dims}^3: converged in {frames} frames, {:.1} s",
            t.elapsed().as_secs_f64()
        );
        let shot = run.frame(&mut renderer, cam, frame, settings, true)?;
        let stats = renderer.stats().out_of_core.ok_or("not out of core")?;
        entries.push(Entry {
            dims,
            frame,
            renderer,
            source,
            frames,
            stats,
            samples: shot.samples,
            times: Vec::new(),
        });
    }
    let camera = camera.ok_or("no camera")?;
    let n = entries.len();
    let shots = interleave(rounds, n, |i| {
        let e = &mut entries[i];
        run.frame(&mut e.renderer, camera, e.frame, settings, false)
    })?;
    for (e, t) in entries.iter_mut().zip(shots) {
        e.times = t;
    }
    println!(
        "  {:>8} {:>7} {:>8} {:>8} {:>9} {:>8} {:>7}  cut levels (data leaves per level)",
        "dims", "levels", "bricks", "leaves", "ms/frame", "smp/ray", "frames"
    );
    let mut ms = Vec::new();
    let mut bricks = Vec::new();
    let mut sizes = Vec::new();
    for e in &entries {
        let time = Timing::of(&e.times);
        let m = time.ms;
        let per_level = cut_levels(
            e.source.as_ref(),
            &camera,
            &e.frame,
            size,
            &noise_tf_world(e.dims, TF_REFERENCE_DIMS),
            config.tolerance_px,
            e.stats.cache.pool_slots,
        );
        println!(
            "  {:>8} {:>7} {:>8} {:>8} {:>9.1} {:>8.1} {:>7}  {}",
            format!("{}^3", e.dims),
            e.source.layout().levels,
            e.stats.cache.working_set_bricks,
            e.stats.cache.leaves,
            m,
            e.samples,
            e.frames,
            levels_text(&per_level)
        );
        sizes.push(SizeRow {
            dims: e.dims,
            time,
            working_set_bricks: e.stats.cache.working_set_bricks as u64,
            samples_per_ray: round2(e.samples),
            frames_to_converge: e.frames,
        });
        ms.push(m);
        bricks.push(e.stats.cache.working_set_bricks as f64);
    }
    let n = entries.len() - 1;
    let time_ratio = ms[n] / ms[0];
    let bricks_ratio = bricks[n] / bricks[0].max(1.0);
    println!(
        "  {}^3 / {}^3: time {time_ratio:.2}x ({}), bricks {bricks_ratio:.2}x ({}) [bound 2x, goal 1.5x]",
        entries[n].dims,
        entries[0].dims,
        verdict(time_ratio, 2.0, 1.5),
        verdict(bricks_ratio, 2.0, 1.5)
    );
    let mut ratios = Vec::new();
    for i in 0..n {
        let (t, b) = (ms[n] / ms[i], bricks[n] / bricks[i].max(1.0));
        if i > 0 {
            println!(
                "  {}^3 / {}^3: time {t:.2}x, bricks {b:.2}x",
                entries[n].dims, entries[i].dims
            );
        }
        ratios.push(SizeRatio {
            vs_dims: entries[i].dims,
            time_ratio: round2(t),
            bricks_ratio: round2(b),
        });
    }
    Ok(Sensitivity {
        view,
        distance,
        sizes,
        ratios,
    })
}
