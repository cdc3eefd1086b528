//! brickray: explore massive scalar volumes in any wgpu application by single-pass
//! GPU ray casting.
//!
//! This facade re-exports the public API of the workspace's crates:
//! * [`core`]: volumes, transfer functions, cameras, settings;
//! * [`io`]: volume input: the `VolumeReader` seam, the format registry and the
//!   readers (raw + JSON, NRRD, NIfTI, TIFF, DICOM, OME-Zarr);
//! * [`store`]: the brick-octree file format, its builder and reader, and the
//!   procedural source of virtual volumes;
//! * [`cache`]: CPU and GPU brick caches, the asynchronous loader, refinement;
//! * [`index`]: the octree-with-ropes index over a cut, and the CPU twin of the
//!   GPU traversal;
//! * [`render`]: the [`VolumeRenderer`] middleware (takes `&Device`, `&Queue` and
//!   target formats; `prepare` records GPU work, `render` draws into the host's
//!   pass and writes depth).

pub use brickray_cache as cache;
pub use brickray_core as core;
pub use brickray_index as index;
pub use brickray_io as io;
pub use brickray_render as render;
pub use brickray_store as store;

pub use brickray_core::{
    Accel, Camera, CameraError, ClipBox, DType, DepthConvention, FrameError, LodMetric, Projection,
    RenderMode, RenderSettings, SettingsError, Shading, TfError, TransferFunction, Volume,
    VolumeDesc, VolumeFrame,
};
pub use brickray_core::{BrickSource, NodeKey, OctreeLayout};
pub use brickray_render::{
    ConfigError, FadeDuration, FrameDesc, FrameStats, GpuErrorKind, HostDepthError,
    OutOfCoreConfig, OutOfCoreStats, PrepareError, RenderError, RendererOptions, RendererStats,
    RetryPolicy, StreamError, StreamedVolume, TargetDesc, U8Filtering, Viewport, VolumeRenderer,
    required_limits,
};
pub use brickray_render::{
    FeedbackStats, UsageFrame, VisibilityConfig, VisibilityCounts, VisibilityPolicy,
};
pub use brickray_render::{Prediction, PredictionError, PredictionFrame, TraversalClass};
pub use wgpu;

/// The README's code, compiled as doc tests (the embedding program is complete).
#[cfg(doctest)]
#[doc = include_str!("../../../README.md")]
pub struct ReadmeDoctests;
