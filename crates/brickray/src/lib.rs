//! brickray: explore massive scalar volumes in any wgpu application by single-pass
//! GPU ray casting.
//!
//! This facade re-exports what a host uses:
//! * the renderer ([`VolumeRenderer`]: takes `&Device`, `&Queue` and target
//!   formats; `prepare` records GPU work, `render` draws into the host's pass
//!   and writes depth), streamed volumes the host owns ([`StreamedVolume`])
//!   and their settings, frame descriptions and statistics, at the top level;
//! * [`core`]: volumes, transfer functions, cameras, settings, the brick
//!   vocabulary;
//! * [`io`]: volume input: the `VolumeReader` seam, the format registry and the
//!   readers (raw + JSON, NRRD, and by feature NIfTI, TIFF, DICOM, OME-Zarr);
//! * [`store`]: the brick-octree file format, its builder and reader, and the
//!   procedural source of virtual volumes (with feature `remote`, stores
//!   and OME-Zarr images over S3, GCS, Azure and HTTP(S): `store::open_url`,
//!   `store::open_zarr_url`, `store::open_source_any`);
//! * `remote` (feature `remote`): range readers over object storage and
//!   HTTP(S), their options and typed errors;
//! * [`cache`]: the GPU-free out-of-core planner ([`cache::Streamer`]) and its
//!   vocabulary, for hosts that plan on the CPU (a twin of what a renderer
//!   streams, a custom executor).
//!
//! The workspace's other crates (the caches' and the index's internals, the
//! shaders) are the library's own.

#[doc(inline)]
pub use brickray_core as core;
#[doc(inline)]
pub use brickray_io as io;
/// Range readers over object storage and HTTP(S) (feature `remote`).
#[cfg(feature = "remote")]
pub use brickray_remote as remote;
#[doc(inline)]
pub use brickray_store as store;

/// The GPU-free out-of-core planner and its vocabulary (`brickray-cache`).
pub mod cache {
    pub use brickray_cache::{
        Classification, ConfigError, CutLeaf, EmptyReason, FadeDuration, FrameStats, GpuFormat,
        LeafKind, Lookahead, OutOfCoreConfig, QueryBatch, QueryResult, QuerySchedule, Residency,
        ResidencyCounts, RetryPolicy, StreamError, StreamFrame, StreamPlan, StreamStats, Streamer,
        UsageFrame, ViewFeedback, brick_count,
    };
}

pub use brickray_core::{
    Accel, Camera, CameraError, ClipBox, DType, DepthConvention, FrameError, LodMetric, Projection,
    RenderMode, RenderSettings, SettingsError, Shading, TfError, TransferFunction, Volume,
    VolumeData, VolumeDesc, VolumeFrame, VolumeKind,
};
pub use brickray_core::{BrickSource, NodeKey, OctreeLayout};
pub use brickray_core::{ChannelError, ChannelSource, ChannelStyle, ChannelVolume};
pub use brickray_core::{
    LabelError, LabelOverlay, LabelStyle, LabelTable, OverlayError, OverlayMode, OverlayStyle,
    overlay_transform,
};
pub use brickray_core::{SpreadError, SpreadSource};
pub use brickray_render::{
    ColorMap, CtPreset, Intensity, Slab, SlabMode, SliceAxis, SliceError, SliceGeometry, SliceView,
    Window, WindowError,
};
pub use brickray_render::{
    ConfigError, FadeDuration, FrameDesc, FrameStats, GpuErrorKind, GradientSource, HostDepthError,
    KeepGradients, OPTIONAL_FEATURES, OptionalFeature, OutOfCoreConfig, OutOfCoreStats,
    PassTimestamps, PrepareError, RenderError, RendererOptions, RendererStats, RetryPolicy,
    SkipRule, StreamError, StreamedVolume, TargetDesc, U8Filtering, Viewport, VolumeOptions,
    VolumeRenderer, optional_features, required_limits,
};
pub use brickray_render::{
    FeedbackStats, OcclusionStats, UsageFrame, VisibilityConfig, VisibilityCounts, VisibilityPolicy,
};
pub use brickray_render::{MAX_PICKS, Pick, PickPoint};
pub use brickray_render::{
    Prediction, PredictionCounts, PredictionError, PredictionFrame, TraversalClass,
};
pub use wgpu;

/// The README's code, compiled as doc tests (the embedding program is complete).
#[cfg(doctest)]
#[doc = include_str!("../../../README.md")]
pub struct ReadmeDoctests;
