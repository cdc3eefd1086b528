//! Errors of the render crate, one enum per phase.

use thiserror::Error;

/// Errors creating a renderer or setting its volume.
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
    /// A buffer would exceed a device limit.
    #[error("{what} needs {required} bytes but the device allows {limit}")]
    LowDeviceLimit {
        /// What needed it.
        what: &'static str,
        /// Bytes needed.
        required: u64,
        /// The device's limit.
        limit: u64,
    },
    /// The target format cannot be rendered to with blending.
    #[error("target format {0:?} is not a blendable colour format")]
    BadTargetFormat(wgpu::TextureFormat),
    /// The depth format has no depth aspect.
    #[error("depth format {0:?} has no depth aspect")]
    BadDepthFormat(wgpu::TextureFormat),
    /// The out-of-core machinery failed (pool sizing, loader threads, index).
    #[error("out-of-core path: {0}")]
    OutOfCore(String),
    /// `render` was called before a successful `prepare`.
    #[error("render called before prepare")]
    NotPrepared,
}

/// Errors from [`crate::VolumeRenderer::prepare`].
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum PrepareError {
    /// No volume has been set.
    #[error("no volume set: call set_volume first")]
    NoVolume,
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
    /// A setting is out of range.
    #[error("invalid setting: {0}")]
    BadSetting(String),
    /// The out-of-core path failed this frame.
    #[error(transparent)]
    Render(#[from] RenderError),
}
