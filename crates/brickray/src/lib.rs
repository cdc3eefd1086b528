//! brickray: explore massive scalar volumes in any wgpu application by single-pass
//! GPU ray casting.
//!
//! This facade re-exports the public API of the workspace's crates:
//! * [`core`]: volumes and their readers, transfer functions, cameras, settings;
//! * [`render`]: the [`VolumeRenderer`] middleware (takes `&Device`, `&Queue` and
//!   target formats; `prepare` records GPU work, `render` draws into the host's
//!   pass and writes depth).

pub use brickray_core as core;
pub use brickray_render as render;

pub use brickray_core::{
    Accel, Camera, DType, Projection, RenderMode, RenderSettings, Shading, TransferFunction, Volume, VolumeDesc,
    VolumeFrame, io,
};
pub use brickray_render::{FrameDesc, FrameStats, PrepareError, RenderError, TargetDesc, VolumeRenderer};
pub use wgpu;
