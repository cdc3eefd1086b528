//! How volume samples are stored in GPU textures. The GPU-free choice and
//! conversion (`SampleEncoding`) is brickray-core's `texel` module; this maps it
//! to wgpu formats and reads the device's capabilities.

pub use texel::U8Filtering;
pub(crate) use texel::{SampleEncoding, TexelCaps, TexelFormat};

/// The wgpu format of a texel format.
pub(crate) fn wgpu_format(f: TexelFormat) -> wgpu::TextureFormat {
    match f {
        TexelFormat::R8Unorm => wgpu::TextureFormat::R8Unorm,
        TexelFormat::R16Unorm => wgpu::TextureFormat::R16Unorm,
        TexelFormat::R16Float => wgpu::TextureFormat::R16Float,
        TexelFormat::R32Float => wgpu::TextureFormat::R32Float,
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

/// Stand-in for `brickray_core::texel` until it lands (same API).
mod texel {
    use brickray_core::DType;
    use std::borrow::Cow;

    /// Texel formats a volume may be stored in.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
    pub(crate) enum TexelFormat {
        R8Unorm,
        R16Unorm,
        R16Float,
        R32Float,
    }

    impl TexelFormat {
        pub(crate) fn bytes(self) -> u32 {
            match self {
                TexelFormat::R8Unorm => 1,
                TexelFormat::R16Unorm | TexelFormat::R16Float => 2,
                TexelFormat::R32Float => 4,
            }
        }
    }

    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub(crate) struct TexelCaps {
        pub(crate) norm16: bool,
        pub(crate) float32_filterable: bool,
    }

    /// How u8 volumes are stored and filtered.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
    pub enum U8Filtering {
        /// In 16 bits (R16Unorm, else R16Float), so trilinear filtering is exact
        /// to the rendering model.
        #[default]
        Exact,
        /// In 8 bits (R8Unorm): half the memory, but the hardware filters 8-bit
        /// formats in 8-bit fixed point, so interpolated values snap to levels.
        Fast,
    }

    #[derive(Debug, Clone, Copy, PartialEq)]
    pub(crate) struct SampleEncoding {
        pub(crate) format: TexelFormat,
        pub(crate) scale: f32,
        pub(crate) offset: f32,
        dtype: DType,
        value_range: [f32; 2],
    }

    impl SampleEncoding {
        pub(crate) fn choose(
            dtype: DType,
            value_range: [f32; 2],
            caps: TexelCaps,
            u8: U8Filtering,
        ) -> SampleEncoding {
            let [lo, hi] = value_range;
            let span = if hi > lo { hi - lo } else { 1.0 };
            let (format, scale, offset) = match (dtype, u8) {
                (DType::U8, U8Filtering::Fast) => (TexelFormat::R8Unorm, 255.0 / span, -lo / span),
                (DType::U8, _) if caps.norm16 => (TexelFormat::R16Unorm, 255.0 / span, -lo / span),
                (DType::U8, _) => (TexelFormat::R16Float, 1.0 / span, -lo / span),
                (DType::U16, _) if caps.norm16 => {
                    (TexelFormat::R16Unorm, 65535.0 / span, -lo / span)
                }
                (DType::I16, _) if caps.norm16 => (
                    TexelFormat::R16Unorm,
                    65535.0 / span,
                    (-32768.0 - lo) / span,
                ),
                (DType::F32, _) if caps.float32_filterable => {
                    (TexelFormat::R32Float, 1.0 / span, -lo / span)
                }
                _ => (TexelFormat::R16Float, 1.0, 0.0),
            };
            SampleEncoding {
                format,
                scale,
                offset,
                dtype,
                value_range,
            }
        }

        pub(crate) fn texel_bytes(&self) -> u32 {
            self.format.bytes()
        }

        pub(crate) fn encode<'a>(&self, bytes: &'a [u8]) -> Cow<'a, [u8]> {
            let [lo, hi] = self.value_range;
            let span = if hi > lo { hi - lo } else { 1.0 };
            let n = self.dtype.size();
            match (self.dtype, self.format) {
                (DType::U8, TexelFormat::R8Unorm)
                | (DType::U16, TexelFormat::R16Unorm)
                | (DType::F32, TexelFormat::R32Float) => Cow::Borrowed(bytes),
                (DType::U8, TexelFormat::R16Unorm) => Cow::Owned(
                    bytes
                        .iter()
                        .flat_map(|&b| (b as u16 * 257).to_le_bytes())
                        .collect(),
                ),
                (DType::U8, TexelFormat::R16Float) => Cow::Owned(
                    bytes
                        .iter()
                        .flat_map(|&b| f16_bits(b as f32).to_le_bytes())
                        .collect(),
                ),
                (DType::I16, TexelFormat::R16Unorm) => Cow::Owned(
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

    /// IEEE half from f32, round to nearest even.
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
}
