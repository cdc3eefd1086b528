//! Support for the isosurface prediction buffer's tests and benchmark: the
//! procedural scenes (nested surfaces; an occluder that slides in front of the
//! surface in view), one frame drawn and read back, and the error measures
//! against the full traversal's image of the same frame.

use crate::{GpuContext, Offscreen};
use brickray_core::{DType, Volume, VolumeData, VolumeDesc};
use brickray_render::{FrameDesc, PrepareError, VolumeRenderer};

/// A colour channel off by more than this many levels makes a pixel wrong.
pub const WRONG_LEVELS: u8 = 2;

fn f32_volume(n: u32, f: impl Fn([f32; 3]) -> f32) -> Volume {
    let mut data = Vec::with_capacity((n * n * n) as usize);
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                // Voxel centres over [-1, 1]^3.
                let p = [x, y, z].map(|i| (i as f32 + 0.5) / n as f32 * 2.0 - 1.0);
                data.push(f(p).clamp(0.0, 1.0));
            }
        }
    }
    let desc = VolumeDesc {
        dims: [n; 3],
        dtype: DType::F32,
        spacing: [1.0; 3],
        value_range: [0.0, 1.0],
        kind: Default::default(),
    };
    Volume::new(desc, VolumeData::F32(data)).expect("valid by construction")
}

/// A smooth ball: 0.5 on the sphere of `radius` about `c`, rising inwards over
/// `width` (all in [-1, 1] units).
fn ball(p: [f32; 3], c: [f32; 3], radius: f32, width: f32) -> f32 {
    let d = ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt();
    0.5 + (radius - d) / width
}

/// Nested surfaces: three concentric shells (isovalue 0.5 at radii 0.85, 0.6
/// and 0.35), with the octant x, y, z > 0 cut away so the inner shells show
/// through, and depth jumps from shell to shell at the cut's edges.
pub fn nested_shells(n: u32) -> Volume {
    let w = 4.0 / n as f32;
    f32_volume(n, |p| {
        let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        // Distance to the nearest shell of half-thickness 0.06.
        let shell = [0.85f32, 0.6, 0.35]
            .iter()
            .map(|s| 0.06 - (r - s).abs())
            .fold(f32::MIN, f32::max);
        let cut = p[0] > 0.0 && p[1] > 0.0 && p[2] > 0.0;
        if cut { 0.0 } else { 0.5 + shell / w }
    })
}

/// The failure scene: a large ball at the centre and a small ball in front of
/// it along +z (the side an orbit at yaw 0 looks from). As the camera orbits,
/// the small ball slides across pixels whose rays last hit the large one,
/// farther than any local search reaches.
pub fn occluder_scene(n: u32) -> Volume {
    let w = 3.0 / n as f32;
    f32_volume(n, |p| {
        ball(p, [0.0, 0.0, -0.2], 0.55, w).max(ball(p, [0.0, 0.1, 0.72], 0.16, w))
    })
}

/// One frame drawn and read back.
#[derive(Debug, Clone)]
pub struct FrameResult {
    /// RGBA8, row-major.
    pub color: Vec<u8>,
    /// Volume samples per ray.
    pub samples: Vec<u32>,
    /// Per-pixel traversal class codes (`TraversalClass`), when predicting.
    pub classes: Option<Vec<u32>>,
    /// Wall time of prepare, submit and wait (ms).
    pub ms: f64,
    /// The ray-cast pass's own time by GPU timestamps (ms), when drawn
    /// with a timer ([`draw_timed`]).
    pub gpu_ms: Option<f64>,
}

/// Reads `size` bytes at `offset` of a `COPY_SRC` buffer (blocking).
pub fn read_buffer(gpu: &GpuContext, src: &wgpu::Buffer, offset: u64, size: u64) -> Vec<u8> {
    let buf = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("brickray-harness buffer readback"),
        size,
        usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: false,
    });
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    enc.copy_buffer_to_buffer(src, offset, &buf, 0, size);
    gpu.submit_wait(enc);
    let slice = buf.slice(..);
    slice.map_async(wgpu::MapMode::Read, |_| {});
    let _ = gpu.device.poll(wgpu::PollType::wait_indefinitely());
    let out = slice
        .get_mapped_range()
        .expect("mapped after wait")
        .to_vec();
    buf.unmap();
    out
}

fn words(b: &[u8]) -> Vec<u32> {
    b.chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

/// Draws one frame (timed: prepare, submit, wait) and reads back its colour,
/// sample counts and, when it predicted, traversal classes.
pub fn draw(
    gpu: &GpuContext,
    renderer: &mut VolumeRenderer,
    target: &Offscreen,
    desc: &FrameDesc<'_>,
) -> Result<FrameResult, PrepareError> {
    draw_timed(gpu, renderer, target, desc, None)
}

/// [`draw`], timing the ray-cast pass with `timer` when given
/// ([`FrameResult::gpu_ms`]).
pub fn draw_timed(
    gpu: &GpuContext,
    renderer: &mut VolumeRenderer,
    target: &Offscreen,
    desc: &FrameDesc<'_>,
    timer: Option<&crate::GpuTimer>,
) -> Result<FrameResult, PrepareError> {
    let crate::TimedFrame {
        stats, ms, gpu_ms, ..
    } = crate::draw_frame_timed(gpu, renderer, target, desc, Some(wgpu::Color::BLACK), timer)?;
    let color = target.read_color(gpu);
    let samples = sample_counts(gpu, renderer);
    let classes = match (stats.prediction, renderer.prediction_classes()) {
        (Some(_), Some((buf, off, size))) => Some(words(&read_buffer(gpu, buf, off, size))),
        _ => None,
    };
    Ok(FrameResult {
        color,
        samples,
        classes,
        ms,
        gpu_ms,
    })
}

/// The volume samples each ray took in `renderer`'s last prepared frame
/// (`VolumeRenderer::sample_count_texture`, read back after the frame was
/// submitted and waited on); empty before any frame.
pub fn sample_counts(gpu: &GpuContext, renderer: &VolumeRenderer) -> Vec<u32> {
    renderer
        .sample_count_texture()
        .map(|t| words(&crate::read_texture(gpu, t, 4, wgpu::TextureAspect::All)))
        .unwrap_or_default()
}

/// Share of pixels whose colour differs by more than [`WRONG_LEVELS`] in any
/// channel (RGBA8 images of one size).
pub fn wrong_share(a: &[u8], b: &[u8]) -> f64 {
    assert_eq!(a.len(), b.len(), "images differ in size");
    let wrong = a
        .chunks_exact(4)
        .zip(b.chunks_exact(4))
        .filter(|(p, q)| {
            p.iter()
                .zip(q.iter())
                .any(|(x, y)| x.abs_diff(*y) > WRONG_LEVELS)
        })
        .count();
    wrong as f64 / (a.len() / 4) as f64
}

/// Mean volume samples per ray over rays that took any.
pub fn samples_per_ray(samples: &[u32]) -> f64 {
    let (n, s) = samples
        .iter()
        .filter(|&&s| s > 0)
        .fold((0u64, 0u64), |(n, s), &x| (n + 1, s + x as u64));
    if n == 0 { 0.0 } else { s as f64 / n as f64 }
}
