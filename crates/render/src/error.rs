//! Errors of the render crate, one enum per phase. No variant carries only a
//! string: each names what failed with structured fields.

use brickray_core::{CameraError, FrameError, SettingsError, SliceError, WindowError};
use thiserror::Error;

/// What kind of error wgpu reported inside one of the library's error scopes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum GpuErrorKind {
    /// A validation error (a limit or rule the library's checks missed: a bug).
    Validation,
    /// The device ran out of memory.
    OutOfMemory,
    /// An internal error of the implementation.
    Internal,
}

/// Errors creating a renderer, setting its volume or transfer function, or
/// drawing.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum RenderError {
    /// The volume does not fit the device's 3D texture limit.
    #[error(
        "volume dims {dims:?} exceed the device's max 3D texture dimension {limit}; use the out-of-core path"
    )]
    VolumeTooLarge {
        /// The volume's dimensions.
        dims: [u32; 3],
        /// `max_texture_dimension_3d`.
        limit: u32,
    },
    /// A setting or resource needs more than a device limit allows.
    #[error("needs {limit} >= {required}, but the device allows {available}")]
    LowDeviceLimit {
        /// The `wgpu::Limits` field.
        limit: &'static str,
        /// What was asked.
        required: u64,
        /// The device's value.
        available: u64,
    },
    /// The device's graphics API cannot run the library's kernels.
    #[error("the {backend:?} backend cannot run brickray's ray casters: {reason}")]
    UnsupportedBackend {
        /// The device's backend (`wgpu::Device::adapter_info`).
        backend: wgpu::Backend,
        /// What it lacks.
        reason: &'static str,
    },
    /// The target format cannot be rendered to with blending.
    #[error("target format {0:?} is not a blendable colour format")]
    BadTargetFormat(wgpu::TextureFormat),
    /// The depth format has no depth aspect.
    #[error("depth format {0:?} has no depth aspect")]
    BadDepthFormat(wgpu::TextureFormat),
    /// The sample count is not supported for the target formats.
    #[error("sample count {count} is not supported for {format:?}")]
    BadSampleCount {
        /// The format that refuses it.
        format: wgpu::TextureFormat,
        /// The sample count asked for.
        count: u32,
    },
    /// The volume's value range (what maps to the transfer function's 0..1)
    /// is not finite, or its width is not: every sample would normalize to
    /// NaN or to one value.
    #[error("the volume's value range {0:?} is not a finite range")]
    BadValueRange([f32; 2]),
    /// The out-of-core cache refused its configuration or could not start.
    #[error(transparent)]
    Cache(#[from] brickray_cache::CacheError),
    /// The out-of-core configuration is not usable (a budget too small for the
    /// texel format, a NaN tolerance, too many loader threads, ...).
    #[error(transparent)]
    OutOfCoreConfig(#[from] brickray_cache::ConfigError),
    /// The brick source failed at set-up (reading the root).
    #[error(transparent)]
    Stream(#[from] brickray_cache::StreamError),
    /// The frame's cut could not be encoded as an index.
    #[error(transparent)]
    Index(#[from] brickray_index::CutError),
    /// The transfer function is not usable.
    #[error(transparent)]
    TransferFunction(#[from] brickray_core::TfError),
    /// A label map over the image cannot be drawn (not a label map, over a
    /// label map, a singular placement, an opacity outside 0..1).
    #[error(transparent)]
    Overlay(#[from] brickray_core::OverlayError),
    /// A multi-channel volume, or its styles, that cannot be drawn
    /// ([`crate::VolumeRenderer::set_channel_volume`]).
    #[error(transparent)]
    Channels(#[from] brickray_core::ChannelError),
    /// wgpu reported an error creating one of the library's objects (caught by an
    /// error scope, never a panic in the host).
    #[error("wgpu {kind:?} error creating {what}: {message}")]
    Gpu {
        /// The object.
        what: &'static str,
        /// The kind of error.
        kind: GpuErrorKind,
        /// wgpu's description.
        message: String,
    },
    /// The operation needs an optional device feature the device was not
    /// created with ([`crate::OPTIONAL_FEATURES`]).
    #[error("{what} need {feature:?}, which the device was not created with")]
    MissingFeature {
        /// The feature.
        feature: wgpu::Features,
        /// What needs it.
        what: &'static str,
    },
    /// The ray-cast pass cannot write its timestamps into this query set
    /// ([`crate::VolumeRenderer::set_pass_timestamps`]): it is not of type
    /// timestamp, an index is not below its count, or the two indices are
    /// equal.
    #[error(
        "the pass timestamps need a Timestamp query set and two distinct indices below its count; \
         got a {ty:?} set of {count} with beginning {beginning} and end {end}"
    )]
    BadTimestampQuery {
        /// The query set's type.
        ty: wgpu::QueryType,
        /// Its number of queries.
        count: u32,
        /// The index of the pass's beginning.
        beginning: u32,
        /// The index of the pass's end.
        end: u32,
    },
    /// The operation needs an out-of-core volume.
    #[error("no out-of-core volume is set")]
    NotOutOfCore,
    /// `render` was called before a successful `prepare`.
    #[error("render called before prepare")]
    NotPrepared,
}

/// What is wrong with the host depth view handed to `prepare`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
#[non_exhaustive]
pub enum HostDepthError {
    /// Its texture lacks `TEXTURE_BINDING` usage.
    #[error("the host depth texture needs TEXTURE_BINDING usage (has {0:?})")]
    NotBindable(wgpu::TextureUsages),
    /// Its format has no depth aspect (a colour view).
    #[error("the host depth view's format {0:?} is not a depth format")]
    NotDepth(wgpu::TextureFormat),
    /// It is multisampled (resolve or copy the depth into a single-sampled
    /// texture first).
    #[error("the host depth texture has {0} samples; a single-sampled one is needed")]
    Multisampled(u32),
    /// It is smaller than the viewport's extent.
    #[error("the host depth texture is {size:?}, smaller than the viewport's extent {needed:?}")]
    TooSmall {
        /// Its size.
        size: [u32; 2],
        /// The viewport's right and bottom edges.
        needed: [u32; 2],
    },
}

/// Errors from [`crate::VolumeRenderer::prepare`].
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum PrepareError {
    /// No volume has been set.
    #[error("no volume set: call set_volume or set_volume_source first")]
    NoVolume,
    /// No transfer function has been set.
    #[error("no transfer function set: call set_transfer_function first")]
    NoTransferFunction,
    /// A multi-channel volume is drawn without styles.
    #[error("no channel styles set: call set_channel_styles first")]
    NoChannelStyles,
    /// More pixels queued for picking than one frame reads back.
    #[error("{requested} pixels queued for picking: at most {max} a frame")]
    TooManyPicks {
        /// Pixels queued.
        requested: usize,
        /// Most a frame picks.
        max: usize,
    },
    /// The viewport is empty or larger than the device's 2D texture limit.
    #[error("viewport {width}x{height} is empty or exceeds the device limit {limit}")]
    BadViewport {
        /// Width.
        width: u32,
        /// Height.
        height: u32,
        /// `max_texture_dimension_2d`.
        limit: u32,
    },
    /// The viewport's right or bottom edge overflows or lies past the
    /// largest 2D target the device can create (no target holds it).
    #[error(
        "viewport at ({x}, {y}) of {width}x{height} reaches past {limit}, the device's largest target",
        x = viewport.x,
        y = viewport.y,
        width = viewport.width,
        height = viewport.height
    )]
    ViewportOutOfRange {
        /// The viewport.
        viewport: crate::desc::Viewport,
        /// `max_texture_dimension_2d`.
        limit: u32,
    },
    /// The frame description's volume frame is for a volume of other dims
    /// than the volume drawn (its rays would sample the wrong place).
    #[error("the frame places a volume of {frame:?} voxels, but the volume drawn has {volume:?}")]
    FrameDoesNotFit {
        /// `FrameDesc::frame.dims`.
        frame: [u32; 3],
        /// The dims of the volume drawn.
        volume: [u32; 3],
    },
    /// The camera cannot form an image.
    #[error(transparent)]
    Camera(#[from] CameraError),
    /// The volume frame cannot place the volume.
    #[error(transparent)]
    Frame(#[from] FrameError),
    /// A render setting is out of range.
    #[error(transparent)]
    Settings(#[from] SettingsError),
    /// The host depth view cannot be used.
    #[error(transparent)]
    HostDepth(#[from] HostDepthError),
    /// Creating or updating GPU resources failed.
    #[error(transparent)]
    Render(#[from] RenderError),
    /// The renderer's slice view cannot be drawn in this frame (a NaN or
    /// degenerate plane, a bad slab).
    #[error(transparent)]
    Slice(#[from] SliceError),
    /// The intensity window cannot map the volume's values (a degenerate
    /// value range, or a window narrower than f32 resolves).
    #[error(transparent)]
    Window(#[from] WindowError),
    /// Two 3D views of one streamed volume prepared together differ in
    /// render mode or transfer function (the views planned together share
    /// the classification; slice views agree with any).
    #[error(
        "views {first} and {other} draw one streamed volume with different modes or transfer functions"
    )]
    ViewsDisagree {
        /// The first view drawing the volume (index into the views).
        first: usize,
        /// The view that differs.
        other: usize,
    },
}
