//! What the stability cases share: volumes with a CPU twin for the reference,
//! a slow source, renderers, image measures and charts.

use brickray_core::{
    BrickError, BrickSource, Camera, NodeInfo, NodeKey, OctreeLayout, RenderSettings,
    TransferFunction, Volume, VolumeFrame,
};
use brickray_harness::{GpuContext, target_desc};
use brickray_render::{OutOfCoreConfig, RenderError, VolumeRenderer};
use brickray_store::ProceduralSource;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

/// `e.to_string()`, for `map_err`.
pub(crate) fn s<E: std::fmt::Display>(e: E) -> String {
    e.to_string()
}

/// A u8 volume of `dims` voxels from `data` (x fastest), value range 0..255.
pub(crate) fn u8_volume(dims: [u32; 3], data: Vec<u8>) -> Result<Volume, String> {
    brickray_harness::scenes::u8_volume(dims, data).map_err(s)
}

/// The finest-level box `lo .. lo + n` of a procedural source as a volume (the
/// CPU reference's twin of the bricks the renderer streams).
pub(crate) fn region_volume(
    src: &ProceduralSource,
    lo: [u64; 3],
    n: [u64; 3],
) -> Result<Volume, String> {
    let finest = src.layout().levels - 1;
    let hi = [0, 1, 2].map(|a| lo[a] + n[a] - 1);
    let data = src.region(finest, lo, hi).map_err(s)?;
    u8_volume(n.map(|v| v as u32), data)
}

/// Fractal noise of `dims^3` in bricks of `brick` (apron 2): the source and the
/// whole finest level as a volume.
pub(crate) fn noise(dims: u64, brick: u32) -> Result<(Volume, Arc<ProceduralSource>), String> {
    let src = ProceduralSource::fractal_noise([dims; 3], brick, 2).map_err(s)?;
    let vol = region_volume(&src, [0; 3], [dims; 3])?;
    Ok((vol, Arc::new(src)))
}

/// The reference image (8-bit RGBA over black) at `step` voxels.
pub(crate) fn reference(
    vol: &Volume,
    frame: &VolumeFrame,
    tf: &TransferFunction,
    camera: &Camera,
    settings: &RenderSettings,
    size: u32,
    step: f32,
) -> Vec<u8> {
    let opts = brickray_reference::ReferenceOptions::new(size, size).with_step_factor(step);
    brickray_reference::render_reference(vol, frame, tf, camera, settings, &opts).to_rgba8([0.0; 3])
}

/// Brightest RGB channel of pixel `i`.
fn peak(img: &[u8], i: usize) -> u8 {
    img[4 * i].max(img[4 * i + 1]).max(img[4 * i + 2])
}

/// Reference pixels at least this bright (of 255) count as "something here".
pub(crate) const HOLE_REF_MIN: u8 = 24;
/// Image pixels at most this bright count as "nothing drawn".
pub(crate) const HOLE_IMG_MAX: u8 = 2;

/// Hole pixels: drawn from no level (at most [`HOLE_IMG_MAX`]) where the
/// reference shows something (at least [`HOLE_REF_MIN`]).
pub(crate) fn holes(img: &[u8], reference: &[u8]) -> u64 {
    (0..img.len() / 4)
        .filter(|&i| peak(reference, i) >= HOLE_REF_MIN && peak(img, i) <= HOLE_IMG_MAX)
        .count() as u64
}

/// Mean absolute difference of the RGB channels, in 8-bit levels.
pub(crate) fn mean_abs_diff(a: &[u8], b: &[u8]) -> f64 {
    let mut sum = 0u64;
    let mut n = 0u64;
    for (pa, pb) in a.chunks_exact(4).zip(b.chunks_exact(4)) {
        for c in 0..3 {
            sum += (pa[c] as i32 - pb[c] as i32).unsigned_abs() as u64;
            n += 1;
        }
    }
    sum as f64 / n.max(1) as f64
}

/// PSNR (dB, 999 when equal) and mean FLIP of `img` against `reference`.
pub(crate) fn quality(img: &[u8], reference: &[u8], size: u32) -> (f64, f64) {
    let p = crate::runner::finite_db(brickray_reference::psnr(img, reference));
    let f = brickray_reference::mean_flip(img, reference, size, size) as f64;
    (p, (f * 1e4).round() / 1e4)
}

/// A renderer given its volume by `attach`, then `tf`.
fn renderer_with(
    gpu: &GpuContext,
    tf: &TransferFunction,
    attach: impl FnOnce(&mut VolumeRenderer) -> Result<(), RenderError>,
) -> Result<VolumeRenderer, String> {
    let mut r = VolumeRenderer::new(&gpu.device, target_desc()).map_err(s)?;
    attach(&mut r).map_err(s)?;
    r.set_transfer_function(&gpu.device, &gpu.queue, tf)
        .map_err(s)?;
    Ok(r)
}

/// An in-core renderer of `vol` with `tf`.
pub(crate) fn incore(
    gpu: &GpuContext,
    vol: &Volume,
    tf: &TransferFunction,
) -> Result<VolumeRenderer, String> {
    renderer_with(gpu, tf, |r| r.set_volume(&gpu.device, &gpu.queue, vol))
}

/// An out-of-core renderer of `source` with `config` and `tf`.
pub(crate) fn ooc(
    gpu: &GpuContext,
    source: Arc<dyn BrickSource>,
    config: OutOfCoreConfig,
    tf: &TransferFunction,
) -> Result<VolumeRenderer, String> {
    renderer_with(gpu, tf, |r| {
        r.set_volume_source(&gpu.device, &gpu.queue, source, config)
    })
}

/// [`ooc`] keeping no gradients whatever the budget (`KeepGradients::Never`):
/// a pool's slots then cost the same under every budget, so a budget can be
/// sized in slots.
pub(crate) fn ooc_without_gradients(
    gpu: &GpuContext,
    source: Arc<dyn BrickSource>,
    config: OutOfCoreConfig,
    tf: &TransferFunction,
) -> Result<VolumeRenderer, String> {
    let options = brickray_render::VolumeOptions {
        gradients: brickray_render::KeepGradients::Never,
        ..Default::default()
    };
    let v = brickray_render::StreamedVolume::new(&gpu.device, &gpu.queue, source, config, options)
        .map_err(s)?;
    renderer_with(gpu, tf, |r| r.set_streamed_volume(&gpu.device, &v))
}

/// A source that sleeps `delay` before every brick read (a slow disk or
/// network) and counts the reads.
pub(crate) struct SlowSource {
    pub(crate) inner: Arc<dyn BrickSource>,
    pub(crate) delay: Duration,
    pub(crate) reads: AtomicU64,
}

impl SlowSource {
    pub(crate) fn new(inner: Arc<dyn BrickSource>, delay: Duration) -> SlowSource {
        SlowSource {
            inner,
            delay,
            reads: AtomicU64::new(0),
        }
    }
}

impl BrickSource for SlowSource {
    fn layout(&self) -> &OctreeLayout {
        self.inner.layout()
    }

    fn node(&self, key: NodeKey) -> Result<NodeInfo, BrickError> {
        self.inner.node(key)
    }

    fn read_brick(&self, key: NodeKey, out: &mut [u8]) -> Result<(), BrickError> {
        std::thread::sleep(self.delay);
        self.reads.fetch_add(1, Ordering::Relaxed);
        self.inner.read_brick(key, out)
    }
}

pub(crate) use crate::chart::Series;

/// One series per named variant, its points taken in the same order.
pub(crate) fn named_series<T>(names: &[(&str, T)], points: Vec<Vec<(f64, f64)>>) -> Vec<Series> {
    names
        .iter()
        .zip(points)
        .map(|((n, _), p)| Series {
            name: n.to_string(),
            points: p,
        })
        .collect()
}

/// A line chart (SVG) at `dir/file`; `log2_x` puts x on a log2 axis. Does
/// nothing when `dir` is empty or there is nothing to draw.
pub(crate) fn line_chart(
    dir: &str,
    file: &str,
    title: &str,
    x_desc: &str,
    y_desc: &str,
    series: &[Series],
    log2_x: bool,
) -> Result<(), String> {
    if dir.is_empty() || series.iter().all(|s| s.points.is_empty()) {
        return Ok(());
    }
    let path = std::path::Path::new(dir).join(file);
    let mut panel = crate::chart::Panel::new(
        title,
        x_desc,
        y_desc,
        series
            .iter()
            .map(|s| Series {
                name: s.name.clone(),
                points: s.points.clone(),
            })
            .collect(),
    );
    panel.log2_x = log2_x;
    crate::chart::draw(&path, 800, 480, &[panel])?;
    println!("  wrote {}", path.display());
    Ok(())
}

/// A GPU-free twin of the renderer's planning (a `Streamer` over the same
/// source, configuration and cameras, root preloaded as the renderer does)
/// that checks every planned cut for holes: leaves that want data and hold
/// none (`Empty(NotLoaded)`, `Empty(Failed)`, data leaves without a slot,
/// allocation failures), and leaves that do not tile the octree cube.
pub(crate) struct CutCheck {
    streamer: brickray_cache::Streamer,
    placement: VolumeFrame,
    levels: u8,
}

impl CutCheck {
    pub(crate) fn new(
        source: Arc<dyn BrickSource>,
        frame: VolumeFrame,
        config: OutOfCoreConfig,
    ) -> Result<CutCheck, String> {
        let layout = source.layout().clone();
        let streamer = crate::runner::gpu_free_streamer(source, config, false)?;
        Ok(CutCheck {
            streamer,
            placement: frame,
            levels: layout.levels,
        })
    }

    /// Plans one frame; returns its hole leaves.
    pub(crate) fn plan(
        &mut self,
        camera: &Camera,
        size: u32,
        mode: brickray_core::RenderMode,
        tf: &TransferFunction,
    ) -> u64 {
        use brickray_core::{EmptyReason, LeafKind};
        let views = [brickray_core::FrameView::new(
            *camera,
            self.placement,
            [size, size],
        )];
        let plan = self.streamer.plan(&brickray_cache::StreamFrame {
            views: &views,
            classification: brickray_cache::Classification {
                mode,
                tf,
                channels: &[],
                tf_generation: 0,
            },
            feedback: &[],
            time: None,
        });
        let mut holes = plan.stats.cache.allocation_failures as u64;
        // Each leaf covers 8^(levels - 1 - level) finest-level cells.
        let mut covered: u128 = 0;
        for leaf in &plan.cut {
            covered += 1u128 << (3 * (self.levels - 1 - leaf.key.level) as u32);
            if matches!(
                leaf.kind,
                LeafKind::Empty(EmptyReason::NotLoaded) | LeafKind::Empty(EmptyReason::Failed)
            ) {
                holes += 1;
            }
        }
        if covered != 1u128 << (3 * (self.levels - 1) as u32) {
            holes += 1;
        }
        holes
    }
}

/// Pixels dark in `img` (at most [`HOLE_IMG_MAX`]) but lit in `reference`
/// (at least [`HOLE_REF_MIN`]): holes when the cut is at the finest level;
/// with coarser levels also detail the coarse data lacks (a diagnostic).
pub(crate) fn dark(img: &[u8], reference: &[u8]) -> u64 {
    holes(img, reference)
}
