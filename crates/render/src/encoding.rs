//! How volume samples are stored in GPU textures. The GPU-free choice and
//! conversion (`SampleEncoding`) is brickray-core's `texel` module; this maps it
//! to wgpu formats and reads the device's capabilities.

pub use brickray_core::U8Filtering;
pub(crate) use brickray_core::{SampleEncoding, TexelCaps, TexelFormat};

/// The wgpu format of a texel format.
pub(crate) fn wgpu_format(f: TexelFormat) -> wgpu::TextureFormat {
    match f {
        TexelFormat::R8Unorm => wgpu::TextureFormat::R8Unorm,
        TexelFormat::R16Unorm => wgpu::TextureFormat::R16Unorm,
        TexelFormat::R16Float => wgpu::TextureFormat::R16Float,
        TexelFormat::R32Float => wgpu::TextureFormat::R32Float,
    }
}

/// The wgpu format of `lanes` lanes (1, 2 or 4) of a texel format: what
/// packs a multi-channel volume's channels into one texel (the same feature
/// makes every lane count of a format filterable).
pub(crate) fn wgpu_format_lanes(f: TexelFormat, lanes: usize) -> wgpu::TextureFormat {
    use wgpu::TextureFormat as F;
    match (f, lanes) {
        (_, 1) => wgpu_format(f),
        (TexelFormat::R8Unorm, 2) => F::Rg8Unorm,
        (TexelFormat::R16Unorm, 2) => F::Rg16Unorm,
        (TexelFormat::R16Float, 2) => F::Rg16Float,
        (TexelFormat::R32Float, 2) => F::Rg32Float,
        (TexelFormat::R8Unorm, _) => F::Rgba8Unorm,
        (TexelFormat::R16Unorm, _) => F::Rgba16Unorm,
        (TexelFormat::R16Float, _) => F::Rgba16Float,
        (TexelFormat::R32Float, _) => F::Rgba32Float,
    }
}

/// What the device offers for volume textures.
pub(crate) fn caps(device: &wgpu::Device) -> TexelCaps {
    let f = device.features();
    TexelCaps {
        norm16: f.contains(wgpu::Features::TEXTURE_FORMAT_16BIT_NORM),
        float32_filterable: f.contains(wgpu::Features::FLOAT32_FILTERABLE),
    }
}
