//! How volume samples are stored in GPU textures, without any GPU API: the texel
//! format chosen for a dtype and what the device offers, the linear map from the
//! texel value a filtered fetch returns to the normalized (transfer-function)
//! value, and the conversion of little-endian samples into texels.
//!
//! `normalized = texel * scale + offset`, where `texel` is the value the GPU's
//! (filtered) fetch returns: `stored / 255` for R8Unorm, `stored / 65535` for
//! R16Unorm, the stored value itself for the float formats.

use crate::volume::DType;
use std::borrow::Cow;

/// A single-channel texel format (the GPU-free twin of the renderer's formats).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TexelFormat {
    /// 8-bit unsigned normalized.
    R8Unorm,
    /// 16-bit unsigned normalized (needs [`TexelCaps::norm16`]).
    R16Unorm,
    /// IEEE half float (always filterable).
    R16Float,
    /// IEEE single float (filterable only with [`TexelCaps::float32_filterable`]).
    R32Float,
}

impl TexelFormat {
    /// Bytes per texel.
    pub fn bytes(self) -> u32 {
        match self {
            TexelFormat::R8Unorm => 1,
            TexelFormat::R16Unorm | TexelFormat::R16Float => 2,
            TexelFormat::R32Float => 4,
        }
    }
}

/// What the device offers beyond the baseline formats.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash)]
pub struct TexelCaps {
    /// R16Unorm can be sampled (wgpu `TEXTURE_FORMAT_16BIT_NORM`).
    pub norm16: bool,
    /// R32Float can be sampled with linear filtering (wgpu `FLOAT32_FILTERABLE`).
    pub float32_filterable: bool,
}

/// How u8 volumes are stored.
///
/// Many GPUs interpolate 8-bit normalized textures with 8-bit (or coarser)
/// fractional weights, so a filtered R8Unorm fetch can differ from exact
/// trilinear interpolation by up to half a level. `Exact` stores u8 samples in a
/// 16-bit format whose filtering is precise (twice the memory); `Fast` keeps
/// R8Unorm.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash)]
pub enum U8Filtering {
    /// R16Unorm (`raw * 257`) when the device has it, else R16Float holding the
    /// raw integer (exact in f16 for 0..=255).
    #[default]
    Exact,
    /// R8Unorm: half the memory, the device's 8-bit filtering precision.
    Fast,
}

/// How samples of a dtype are stored in a texture: the format and the map from
/// texel value to normalized value (`texel * scale + offset`). Exact formats are
/// preferred (R16Unorm or R16Float for u8 with [`U8Filtering::Exact`], R8Unorm
/// with `Fast`, R16Unorm for u16 and offset i16, filterable R32Float for f32);
/// without the optional features the fallback is R16Float of the normalized value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SampleEncoding {
    /// The texel format.
    pub format: TexelFormat,
    /// `normalized = texel * scale + offset`.
    pub scale: f32,
    /// See [`scale`](Self::scale).
    pub offset: f32,
    dtype: DType,
    value_range: [f32; 2],
    /// The fallback half-float texel holds the raw sample (label ids), not
    /// the normalized value.
    raw_f16: bool,
}

impl SampleEncoding {
    /// The encoding of `dtype` samples whose `value_range` maps to 0..1, on a
    /// device offering `caps`, u8 samples stored as `u8_filtering` says.
    pub fn choose(
        dtype: DType,
        value_range: [f32; 2],
        caps: TexelCaps,
        u8_filtering: U8Filtering,
    ) -> SampleEncoding {
        let [lo, span] = lo_span(value_range);
        let (format, scale, offset) = match dtype {
            DType::U8 => match (u8_filtering, caps.norm16) {
                (U8Filtering::Fast, _) => (TexelFormat::R8Unorm, 255.0 / span, -lo / span),
                (U8Filtering::Exact, true) => (TexelFormat::R16Unorm, 255.0 / span, -lo / span),
                (U8Filtering::Exact, false) => (TexelFormat::R16Float, 1.0 / span, -lo / span),
            },
            DType::U16 if caps.norm16 => (TexelFormat::R16Unorm, 65535.0 / span, -lo / span),
            DType::I16 if caps.norm16 => (
                TexelFormat::R16Unorm,
                65535.0 / span,
                (-32768.0 - lo) / span,
            ),
            DType::F32 if caps.float32_filterable => {
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
            raw_f16: false,
        }
    }

    /// The encoding of label ids ([`crate::VolumeKind::Labels`], value range
    /// [`crate::labels::label_value_range`]), exact on every device and read
    /// at the nearest texel: u8 ids as R8Unorm, u16 and u32 ids as a half
    /// float holding the id (exact below 2048, the ids a label table draws).
    pub fn for_labels(dtype: DType) -> SampleEncoding {
        let value_range = crate::labels::label_value_range();
        let [lo, span] = lo_span(value_range);
        let (format, scale) = match dtype {
            DType::U8 => (TexelFormat::R8Unorm, 255.0 / span),
            _ => (TexelFormat::R16Float, 1.0 / span),
        };
        SampleEncoding {
            format,
            scale,
            offset: -lo / span,
            dtype,
            value_range,
            raw_f16: true,
        }
    }

    /// The encoding of a volume: [`for_labels`](Self::for_labels) for label
    /// volumes, else [`choose`](Self::choose).
    pub fn for_volume(
        desc: &crate::VolumeDesc,
        caps: TexelCaps,
        u8_filtering: U8Filtering,
    ) -> SampleEncoding {
        if desc.kind.is_labels() {
            Self::for_labels(desc.dtype)
        } else {
            Self::choose(desc.dtype, desc.value_range, caps, u8_filtering)
        }
    }

    /// The sample type this encoding converts.
    pub fn dtype(&self) -> DType {
        self.dtype
    }

    /// The raw value range mapped to 0..1.
    pub fn value_range(&self) -> [f32; 2] {
        self.value_range
    }

    /// Bytes per texel.
    pub fn texel_bytes(&self) -> u32 {
        self.format.bytes()
    }

    /// The normalized value of a texel value (`texel * scale + offset`).
    pub fn normalized(&self, texel: f32) -> f32 {
        texel * self.scale + self.offset
    }

    /// Converts little-endian samples of the dtype into texels of the format
    /// (borrowed when the bytes already are the texels). A trailing partial sample
    /// is ignored.
    pub fn encode<'a>(&self, bytes: &'a [u8]) -> Cow<'a, [u8]> {
        let [lo, span] = lo_span(self.value_range);
        let n = self.dtype.size();
        match (self.dtype, self.format) {
            (DType::U8, TexelFormat::R8Unorm)
            | (DType::U16, TexelFormat::R16Unorm)
            | (DType::F32, TexelFormat::R32Float) => Cow::Borrowed(&bytes[..bytes.len() / n * n]),
            (DType::U8, TexelFormat::R16Unorm) => Cow::Owned(
                bytes
                    .iter()
                    .flat_map(|&v| (v as u16 * 257).to_le_bytes())
                    .collect(),
            ),
            (DType::U8, _) => {
                // The raw integer as a half float (exact for 0..=255).
                let table: [[u8; 2]; 256] =
                    std::array::from_fn(|v| f16_bits(v as f32).to_le_bytes());
                Cow::Owned(bytes.iter().flat_map(|&v| table[v as usize]).collect())
            }
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
                            DType::U8 => c[0] as f32,
                            DType::U32 => u32::from_le_bytes([c[0], c[1], c[2], c[3]]) as f32,
                        };
                        let texel = if self.raw_f16 { raw } else { (raw - lo) / span };
                        f16_bits(texel).to_le_bytes()
                    })
                    .collect(),
            ),
        }
    }
}

/// `[lo, span]` of a value range; a degenerate range spans 1.
fn lo_span([lo, hi]: [f32; 2]) -> [f32; 2] {
    [lo, if hi > lo { hi - lo } else { 1.0 }]
}

/// IEEE half from f32, round to nearest even.
pub fn f16_bits(x: f32) -> u16 {
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

/// f32 from IEEE half bits (exact).
pub fn f16_to_f32(h: u16) -> f32 {
    let sign = if h & 0x8000 != 0 { -1.0f32 } else { 1.0 };
    let exp = ((h >> 10) & 0x1f) as i32;
    let man = (h & 0x3ff) as f32;
    match exp {
        0 => sign * man * 2f32.powi(-24),
        31 if man == 0.0 => sign * f32::INFINITY,
        31 => f32::NAN,
        _ => sign * (1.0 + man / 1024.0) * 2f32.powi(exp - 15),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn f16_conversion_matches_known_values() {
        assert_eq!(f16_bits(0.0), 0);
        assert_eq!(f16_bits(1.0), 0x3c00);
        assert_eq!(f16_bits(0.5), 0x3800);
        assert_eq!(f16_bits(-2.0), 0xc000);
        assert_eq!(f16_bits(65504.0), 0x7bff);
        assert_eq!(f16_bits(1.0e9), 0x7c00);
        assert_eq!(f16_bits(0.333_333_34), 0x3555);
        for h in [0u16, 0x3c00, 0x3800, 0xc000, 0x7bff, 0x3555, 0x0001, 0x03ff] {
            assert_eq!(f16_bits(f16_to_f32(h)), h);
        }
        for v in 0..=2048u32 {
            assert_eq!(f16_to_f32(f16_bits(v as f32)), v as f32, "{v}");
        }
    }

    /// The value a filtered fetch of texel `i` of `texels` returns.
    fn texel_value(format: TexelFormat, texels: &[u8], i: usize) -> f32 {
        let b = format.bytes() as usize;
        let c = &texels[i * b..(i + 1) * b];
        match format {
            TexelFormat::R8Unorm => c[0] as f32 / 255.0,
            TexelFormat::R16Unorm => u16::from_le_bytes([c[0], c[1]]) as f32 / 65535.0,
            TexelFormat::R16Float => f16_to_f32(u16::from_le_bytes([c[0], c[1]])),
            TexelFormat::R32Float => f32::from_le_bytes([c[0], c[1], c[2], c[3]]),
        }
    }

    /// Raw test values of a dtype, as f32 and as little-endian bytes.
    fn raw_values(dtype: DType) -> (Vec<f32>, Vec<u8>) {
        let vals: Vec<f32> = match dtype {
            DType::U8 => (0..=255).map(|v| v as f32).collect(),
            DType::U16 => [0u32, 1, 2, 255, 256, 1000, 4095, 32767, 32768, 65534, 65535]
                .iter()
                .map(|&v| v as f32)
                .collect(),
            DType::I16 => [-32768i32, -32767, -1000, -1, 0, 1, 1000, 32766, 32767]
                .iter()
                .map(|&v| v as f32)
                .collect(),
            DType::F32 => vec![
                -1000.0, -3.25, -1.0, 0.0, 0.1, 0.5, 1.0, 7.75, 999.0, 1000.0,
            ],
            DType::U32 => [0u32, 1, 2, 255, 256, 1000, 2047, 4095, 65535, 1 << 20]
                .iter()
                .map(|&v| v as f32)
                .collect(),
        };
        let bytes = vals
            .iter()
            .flat_map(|&v| match dtype {
                DType::U8 => vec![v as u8],
                DType::U16 => (v as u16).to_le_bytes().to_vec(),
                DType::I16 => (v as i16).to_le_bytes().to_vec(),
                DType::F32 => v.to_le_bytes().to_vec(),
                DType::U32 => (v as u32).to_le_bytes().to_vec(),
            })
            .collect();
        (vals, bytes)
    }

    fn ranges(dtype: DType) -> Vec<[f32; 2]> {
        match dtype {
            DType::U8 => vec![[0.0, 255.0], [10.0, 200.0]],
            DType::U16 => vec![[0.0, 65535.0], [100.0, 4095.0]],
            DType::I16 => vec![[-32768.0, 32767.0], [-1024.0, 3071.0]],
            DType::F32 => vec![[-1000.0, 1000.0], [0.0, 1.0]],
            DType::U32 => vec![[0.0, 1048576.0], [0.0, 2047.0]],
        }
    }

    /// Label ids round-trip exactly (to f32 rounding of the map) to
    /// `id / (LABEL_TABLE_ENTRIES - 1)`, the centre of their table entry, in
    /// every label type.
    #[test]
    fn label_ids_encode_exactly() {
        let n = crate::labels::LABEL_TABLE_ENTRIES as u32;
        for dtype in [DType::U8, DType::U16, DType::U32] {
            let top = if dtype == DType::U8 { 256 } else { n };
            let bytes: Vec<u8> = (0..top)
                .flat_map(|id| match dtype {
                    DType::U8 => vec![id as u8],
                    DType::U16 => (id as u16).to_le_bytes().to_vec(),
                    _ => id.to_le_bytes().to_vec(),
                })
                .collect();
            let enc = SampleEncoding::for_labels(dtype);
            let texels = enc.encode(&bytes);
            for id in 0..top {
                let got = enc.normalized(texel_value(enc.format, &texels, id as usize));
                let want = id as f64 / (n - 1) as f64;
                // Well within half an entry (0.5 / 2047 = 2.4e-4).
                assert!(
                    (got as f64 - want).abs() < 1e-6,
                    "{dtype:?} id {id}: {got} vs {want}"
                );
            }
        }
    }

    /// Every dtype x caps x u8 mode: raw values round-trip through the texels to
    /// the normalized value within the format's precision, exactly (up to f32
    /// rounding of the map) for u8 in either mode, u16/i16 in R16Unorm and f32 in
    /// R32Float; to f16 precision in the R16Float fallback of the normalized value.
    #[test]
    fn every_encoding_round_trips_to_the_normalized_value() {
        let all_caps = [(false, false), (true, false), (false, true), (true, true)].map(
            |(norm16, float32_filterable)| TexelCaps {
                norm16,
                float32_filterable,
            },
        );
        for dtype in [DType::U8, DType::U16, DType::I16, DType::F32, DType::U32] {
            let (vals, bytes) = raw_values(dtype);
            for range in ranges(dtype) {
                for caps in all_caps {
                    for mode in [U8Filtering::Exact, U8Filtering::Fast] {
                        let enc = SampleEncoding::choose(dtype, range, caps, mode);
                        let expected_format = match dtype {
                            DType::U8 => match (mode, caps.norm16) {
                                (U8Filtering::Fast, _) => TexelFormat::R8Unorm,
                                (U8Filtering::Exact, true) => TexelFormat::R16Unorm,
                                (U8Filtering::Exact, false) => TexelFormat::R16Float,
                            },
                            DType::U16 | DType::I16 if caps.norm16 => TexelFormat::R16Unorm,
                            DType::F32 if caps.float32_filterable => TexelFormat::R32Float,
                            _ => TexelFormat::R16Float,
                        };
                        assert_eq!(enc.format, expected_format, "{dtype:?} {caps:?} {mode:?}");
                        let texels = enc.encode(&bytes);
                        assert_eq!(texels.len(), vals.len() * enc.texel_bytes() as usize);
                        // Exact formats: the map's own f32 rounding only.
                        let exact = dtype == DType::U8 || enc.format != TexelFormat::R16Float;
                        for (i, &raw) in vals.iter().enumerate() {
                            let want = (raw as f64 - range[0] as f64)
                                / (range[1] as f64 - range[0] as f64);
                            let texel = texel_value(enc.format, &texels, i);
                            let got = enc.normalized(texel) as f64;
                            // The map's terms may cancel (offset i16 over a narrow
                            // range): f32 rounding is relative to the larger term.
                            let terms = (texel * enc.scale).abs().max(enc.offset.abs());
                            let tol = if exact {
                                4.0 * f32::EPSILON as f64 * (terms as f64).max(1.0)
                            } else {
                                // Half a unit in the last place of f16.
                                want.abs().max(2f64.powi(-14)) * 2f64.powi(-11)
                            };
                            assert!(
                                (got - want).abs() <= tol,
                                "{dtype:?} {range:?} {caps:?} {mode:?} raw {raw}: {got} != {want}"
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn u8_exact_keeps_distinct_levels_and_fast_borrows() {
        let caps = TexelCaps::default();
        let bytes: Vec<u8> = (0..=255).collect();
        let fast = SampleEncoding::choose(DType::U8, [0.0, 255.0], caps, U8Filtering::Fast);
        assert!(matches!(fast.encode(&bytes), Cow::Borrowed(_)));
        assert_eq!(fast.texel_bytes(), 1);
        let exact = SampleEncoding::choose(DType::U8, [0.0, 255.0], caps, U8Filtering::Exact);
        assert_eq!(exact.format, TexelFormat::R16Float);
        assert_eq!(exact.texel_bytes(), 2);
        let t = exact.encode(&bytes);
        // The stored value is the raw integer itself.
        for v in 0..256 {
            assert_eq!(
                f16_to_f32(u16::from_le_bytes([t[2 * v], t[2 * v + 1]])),
                v as f32
            );
        }
        let caps = TexelCaps {
            norm16: true,
            float32_filterable: false,
        };
        let n16 = SampleEncoding::choose(DType::U8, [0.0, 255.0], caps, U8Filtering::Exact);
        assert_eq!((n16.scale, n16.offset), (fast.scale, fast.offset));
        let t = n16.encode(&[0, 1, 255]);
        assert_eq!(&t[..], &[0, 0, 1, 1, 255, 255]);
        // A trailing partial sample is ignored.
        let u16e = SampleEncoding::choose(DType::U16, [0.0, 1.0], caps, U8Filtering::Exact);
        assert_eq!(u16e.encode(&[1, 2, 3]).len(), 2);
    }
}
