//! The in-core volume on the GPU: one 3D texture plus the macro-cell ranges.

use crate::error::RenderError;
use brickray_core::{DType, MacroCellGrid, Volume};
use std::borrow::Cow;

/// Macro-cell size in voxels for empty-space skipping.
pub(crate) const CELL: u32 = 8;

/// A volume resident on the GPU.
#[derive(Debug)]
pub(crate) struct GpuVolume {
    pub(crate) view: wgpu::TextureView,
    pub(crate) format: wgpu::TextureFormat,
    /// `normalized = texel * scale + offset`.
    pub(crate) scale: f32,
    pub(crate) offset: f32,
    pub(crate) dims: [u32; 3],
    pub(crate) cells: [u32; 3],
    pub(crate) cell_ranges: wgpu::Buffer,
    pub(crate) bytes: u64,
}

/// How samples of a dtype are stored in a GPU texture: the format and the map
/// from texel value to normalized value (`texel * scale + offset`). Exact formats
/// are preferred (R8Unorm, R16Unorm, filterable R32Float); without the optional
/// features the fallback is R16Float of the normalized value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct SampleEncoding {
    pub(crate) format: wgpu::TextureFormat,
    pub(crate) scale: f32,
    pub(crate) offset: f32,
    dtype: DType,
    value_range: [f32; 2],
}

impl SampleEncoding {
    pub(crate) fn choose(
        dtype: DType,
        value_range: [f32; 2],
        features: wgpu::Features,
    ) -> SampleEncoding {
        let [lo, hi] = value_range;
        let span = if hi > lo { hi - lo } else { 1.0 };
        let norm16 = features.contains(wgpu::Features::TEXTURE_FORMAT_16BIT_NORM);
        let f32filt = features.contains(wgpu::Features::FLOAT32_FILTERABLE);
        let (format, scale, offset) = match dtype {
            DType::U8 => (wgpu::TextureFormat::R8Unorm, 255.0 / span, -lo / span),
            DType::U16 if norm16 => (wgpu::TextureFormat::R16Unorm, 65535.0 / span, -lo / span),
            DType::I16 if norm16 => (
                wgpu::TextureFormat::R16Unorm,
                65535.0 / span,
                (-32768.0 - lo) / span,
            ),
            DType::F32 if f32filt => (wgpu::TextureFormat::R32Float, 1.0 / span, -lo / span),
            _ => (wgpu::TextureFormat::R16Float, 1.0, 0.0),
        };
        SampleEncoding {
            format,
            scale,
            offset,
            dtype,
            value_range,
        }
    }

    /// Bytes per texel.
    pub(crate) fn texel_bytes(&self) -> u32 {
        self.format.block_copy_size(None).unwrap_or(1)
    }

    /// Converts little-endian samples of the dtype into texels of the format.
    pub(crate) fn encode<'a>(&self, bytes: &'a [u8]) -> Cow<'a, [u8]> {
        let [lo, hi] = self.value_range;
        let span = if hi > lo { hi - lo } else { 1.0 };
        let n = self.dtype.size();
        match (self.dtype, self.format) {
            (DType::U8, _)
            | (DType::U16, wgpu::TextureFormat::R16Unorm)
            | (DType::F32, wgpu::TextureFormat::R32Float) => Cow::Borrowed(bytes),
            (DType::I16, wgpu::TextureFormat::R16Unorm) => Cow::Owned(
                bytes
                    .chunks_exact(2)
                    .flat_map(|c| {
                        ((i16::from_le_bytes([c[0], c[1]]) as i32 + 32768) as u16).to_le_bytes()
                    })
                    .collect(),
            ),
            _ => Cow::Owned(
                bytes
                    .chunks_exact(n)
                    .flat_map(|c| {
                        let raw = match self.dtype {
                            DType::U16 => u16::from_le_bytes([c[0], c[1]]) as f32,
                            DType::I16 => i16::from_le_bytes([c[0], c[1]]) as f32,
                            DType::F32 => f32::from_le_bytes([c[0], c[1], c[2], c[3]]),
                            _ => c[0] as f32,
                        };
                        f16_bits((raw - lo) / span).to_le_bytes()
                    })
                    .collect(),
            ),
        }
    }
}

/// IEEE half from f32, round to nearest even (values here are in a modest range).
fn f16_bits(x: f32) -> u16 {
    let b = x.to_bits();
    let sign = ((b >> 16) & 0x8000) as u16;
    let exp = ((b >> 23) & 0xff) as i32;
    let man = b & 0x7f_ffff;
    if exp == 0xff {
        return sign | 0x7c00 | if man != 0 { 0x200 } else { 0 };
    }
    let e = exp - 127 + 15;
    if e >= 31 {
        return sign | 0x7c00;
    }
    if e <= 0 {
        if e < -10 {
            return sign;
        }
        let m = man | 0x80_0000;
        let shift = (14 - e) as u32;
        let half = 1u32 << (shift - 1);
        let rounded = (m + half - 1 + ((m >> shift) & 1)) >> shift;
        return sign | rounded as u16;
    }
    let rounded = man + 0xfff + ((man >> 13) & 1);
    let (e, m) = if rounded & 0x80_0000 != 0 {
        (e + 1, 0)
    } else {
        (e, rounded >> 13)
    };
    if e >= 31 {
        return sign | 0x7c00;
    }
    sign | ((e as u16) << 10) | m as u16
}

impl GpuVolume {
    pub(crate) fn upload(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        vol: &Volume,
    ) -> Result<GpuVolume, RenderError> {
        let dims = vol.dims();
        let limit = device.limits().max_texture_dimension_3d;
        if dims.iter().any(|&d| d > limit) {
            return Err(RenderError::VolumeTooLarge { dims, limit });
        }
        let enc =
            SampleEncoding::choose(vol.desc().dtype, vol.desc().value_range, device.features());
        let (format, scale, offset) = (enc.format, enc.scale, enc.offset);
        let bytes = enc.encode(vol.data().as_bytes());
        let texture = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("brickray-render volume"),
            size: wgpu::Extent3d {
                width: dims[0],
                height: dims[1],
                depth_or_array_layers: dims[2],
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D3,
            format,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        let bpp = enc.texel_bytes();
        let row = dims[0] * bpp;
        let slice = row as usize * dims[1] as usize;
        // Upload in slabs of at most 64 MiB so staging memory stays bounded.
        let per = ((64usize << 20) / slice.max(1)).clamp(1, dims[2] as usize) as u32;
        let mut z = 0;
        while z < dims[2] {
            let z1 = (z + per).min(dims[2]);
            queue.write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture: &texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d { x: 0, y: 0, z },
                    aspect: wgpu::TextureAspect::All,
                },
                &bytes[z as usize * slice..z1 as usize * slice],
                wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(row),
                    rows_per_image: Some(dims[1]),
                },
                wgpu::Extent3d {
                    width: dims[0],
                    height: dims[1],
                    depth_or_array_layers: z1 - z,
                },
            );
            z = z1;
        }
        let grid = MacroCellGrid::build(vol, CELL);
        let ranges: &[u8] = bytemuck::cast_slice(&grid.ranges);
        let cell_ranges = crate::storage_buffer(device, "macro-cell ranges", ranges.len() as u64)?;
        queue.write_buffer(&cell_ranges, 0, ranges);
        Ok(GpuVolume {
            view: texture.create_view(&wgpu::TextureViewDescriptor::default()),
            format,
            scale,
            offset,
            dims,
            cells: grid.dims,
            cell_ranges,
            bytes: bytes.len() as u64,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::f16_bits;

    #[test]
    fn f16_conversion_matches_known_values() {
        assert_eq!(f16_bits(0.0), 0);
        assert_eq!(f16_bits(1.0), 0x3c00);
        assert_eq!(f16_bits(0.5), 0x3800);
        assert_eq!(f16_bits(-2.0), 0xc000);
        assert_eq!(f16_bits(65504.0), 0x7bff);
        assert_eq!(f16_bits(1.0e9), 0x7c00);
        assert_eq!(f16_bits(0.333_333_34), 0x3555);
    }
}
