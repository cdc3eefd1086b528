//! What the host tells the renderer: its targets, each frame's view, and what it
//! reads back: statistics.

use crate::backend::{FeedbackStats, OcclusionStats};
use brickray_cache::FrameStats as CacheStats;
use brickray_core::{Camera, RenderSettings, VolumeFrame};
use brickray_visibility::{VisibilityCounts, VisibilityPolicy};

/// The host's render targets that [`crate::VolumeRenderer::render`] draws into.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct TargetDesc {
    /// Colour attachment format (must be blendable).
    pub color_format: wgpu::TextureFormat,
    /// Depth attachment format of the host's pass, or `None` for a pass without one.
    pub depth_format: Option<wgpu::TextureFormat>,
    /// Samples per pixel of the host's attachments (1, or 4 for a typical MSAA
    /// pass). Every sample of a pixel receives the pixel's ray result.
    pub sample_count: u32,
}

impl TargetDesc {
    /// A single-sampled colour target without depth.
    pub fn new(color_format: wgpu::TextureFormat) -> TargetDesc {
        TargetDesc {
            color_format,
            depth_format: None,
            sample_count: 1,
        }
    }

    /// With a depth attachment of `format`.
    pub fn with_depth(self, format: wgpu::TextureFormat) -> TargetDesc {
        TargetDesc {
            depth_format: Some(format),
            ..self
        }
    }

    /// With `count` samples per pixel.
    pub fn with_samples(self, count: u32) -> TargetDesc {
        TargetDesc {
            sample_count: count,
            ..self
        }
    }
}

/// A rectangle of the host's target, in pixels (origin at the top left).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Viewport {
    /// Left edge.
    pub x: u32,
    /// Top edge.
    pub y: u32,
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
}

impl Viewport {
    /// The whole of a `width x height` target.
    pub fn full(width: u32, height: u32) -> Viewport {
        Viewport {
            x: 0,
            y: 0,
            width,
            height,
        }
    }

    /// `width / height`.
    pub fn aspect(&self) -> f64 {
        self.width as f64 / self.height.max(1) as f64
    }
}

/// One frame's view of the volume.
///
/// The depth convention (standard or reversed-Z, finite or infinite far plane)
/// is the camera's ([`Camera::depth`], [`Camera::far`]): depth read from
/// `host_depth` and written by `render` follows it, and the composite's depth
/// test is `LessEqual` (standard) or `GreaterEqual` (reversed-Z).
#[derive(Debug, Clone)]
pub struct FrameDesc<'a> {
    /// The camera.
    pub camera: Camera,
    /// Placement of the volume in the world.
    pub frame: VolumeFrame,
    /// Where in the host's target the volume is drawn (its aspect ratio is the
    /// camera's). `render` sets the pass's viewport to it.
    pub viewport: Viewport,
    /// Mode, shading, accelerations, step.
    pub settings: RenderSettings,
    /// The host's opaque depth: a single-sampled depth texture view with
    /// `TEXTURE_BINDING` usage covering the viewport (the same texture the host's
    /// pass uses, drawn before `prepare`'s work runs). Rays stop there.
    pub host_depth: Option<&'a wgpu::TextureView>,
    /// The host's time of this frame in seconds (any origin, non-decreasing):
    /// level-of-detail fades given in milliseconds advance by the time since
    /// the last frame. `None`: frames 1/60 s apart. No clock is read on the
    /// frame path.
    pub time: Option<f64>,
}

impl FrameDesc<'_> {
    /// A frame over the whole of a `width x height` target with default settings
    /// and no host depth.
    pub fn new(camera: Camera, frame: VolumeFrame, width: u32, height: u32) -> FrameDesc<'static> {
        FrameDesc {
            camera,
            frame,
            viewport: Viewport::full(width, height),
            settings: RenderSettings::default(),
            host_depth: None,
            time: None,
        }
    }
}

/// What `prepare` did.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FrameStats {
    /// Rays cast.
    pub rays: u64,
    /// Bytes written to the GPU this frame (uniforms, bricks, tables, index).
    pub uploaded_bytes: u64,
    /// What the isosurface prediction buffer did (`None`: the frame did not
    /// predict).
    pub prediction: Option<crate::PredictionFrame>,
    /// The frame's ray cast skipped empty space: the settings asked for it
    /// and the mode's skip rule chose it ([`crate::SkipRule`]; the image is
    /// the same either way).
    pub empty_space_skipping: bool,
}

/// Everything the renderer knows about its last frame.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RendererStats {
    /// What the last `prepare` did.
    pub frame: FrameStats,
    /// The out-of-core path's figures (working set, pool occupancy, bytes
    /// uploaded, CPU and GPU cache hit rates, requests in flight, frame phases);
    /// `None` in core.
    pub out_of_core: Option<OutOfCoreStats>,
}

/// What the out-of-core path did in the last frame.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct OutOfCoreStats {
    /// The cache's view: working set, pool occupancy, uploads, hit rates,
    /// requests in flight, residency counts, failures.
    pub cache: CacheStats,
    /// Words of the encoded index.
    pub index_words: u32,
    /// Milliseconds spent planning (the streamer's frame).
    pub refine_ms: f64,
    /// Milliseconds spent writing prepared bricks and tables.
    pub upload_ms: f64,
    /// Milliseconds spent encoding and writing the index.
    pub encode_ms: f64,
    /// True when another frame of this view would not change the image: nothing
    /// in flight or pending, and no brick the view needs has failed
    /// (`cache.converged()`), and the feedback settled.
    pub converged: bool,
    /// Data leaves of the cut per octree level (level 0 = root; levels past 15
    /// are counted in 15).
    pub data_leaves_per_level: [u32; 16],
    /// The visibility policy in force.
    pub policy: VisibilityPolicy,
    /// The cut's data leaves by visibility (all unobserved without culling).
    pub visibility: VisibilityCounts,
    /// This view's usage feedback's read-back counters.
    pub feedback: FeedbackStats,
    /// This view's occlusion queries' schedule and read-back counters.
    pub occlusion: OcclusionStats,
    /// DVR of a single-channel intensity volume: the share of the sub-cells
    /// of the bricks the plan draws that are transparent through the
    /// transfer function, what its skip rule compares with
    /// `brickray_core::dvr_skip_share_min_bricks` at the frame's step
    /// ([`crate::SkipRule`]);
    /// `None` otherwise.
    pub dvr_transparent_share: Option<f64>,
    /// The streamed volume keeps its texels' gradients, so shaded DVR reads
    /// one texel per sample ([`crate::VolumeOptions::gradients`], as decided
    /// when the volume was made; [`crate::StreamedVolume::keeps_gradients`]).
    pub gradients_kept: bool,
}
