//! Scalar volumes held in memory.

use thiserror::Error;

/// Largest number of voxels along one axis that brickray accepts (2^24).
pub const MAX_DIM: u32 = 1 << 24;

/// The sample type of a volume. Multi-byte types are little-endian on disk.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub enum DType {
    /// Unsigned 8-bit.
    U8,
    /// Unsigned 16-bit.
    U16,
    /// Signed 16-bit.
    I16,
    /// 32-bit IEEE float.
    F32,
    /// Unsigned 32-bit: label ids ([`VolumeKind::Labels`]); an intensity
    /// volume of this type is read as f32 (exact up to 2^24).
    U32,
}

impl DType {
    /// Bytes per voxel.
    pub fn size(self) -> usize {
        match self {
            DType::U8 => 1,
            DType::U16 | DType::I16 => 2,
            DType::F32 | DType::U32 => 4,
        }
    }

    /// Parses the names used by the JSON sidecars (`u8`, `u16`, `i16`, `f32`) and
    /// their common aliases (`uint8`, `uchar`, `float`, ...).
    pub fn parse(name: &str) -> Option<DType> {
        match name.trim().to_ascii_lowercase().as_str() {
            "u8" | "uint8" | "uchar" | "unsigned char" | "uint8_t" => Some(DType::U8),
            "u16" | "uint16" | "ushort" | "unsigned short" | "uint16_t" => Some(DType::U16),
            "i16" | "int16" | "short" | "signed short" | "int16_t" => Some(DType::I16),
            "f32" | "float32" | "float" => Some(DType::F32),
            "u32" | "uint32" | "uint" | "unsigned int" | "uint32_t" => Some(DType::U32),
            _ => None,
        }
    }

    /// Decodes little-endian samples of this type to f32 (a trailing partial
    /// sample is ignored).
    pub fn decode_le(self, bytes: &[u8]) -> Vec<f32> {
        match self {
            DType::U8 => bytes.iter().map(|&x| x as f32).collect(),
            DType::U16 => bytes
                .chunks_exact(2)
                .map(|c| u16::from_le_bytes([c[0], c[1]]) as f32)
                .collect(),
            DType::I16 => bytes
                .chunks_exact(2)
                .map(|c| i16::from_le_bytes([c[0], c[1]]) as f32)
                .collect(),
            DType::F32 => bytes
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
            DType::U32 => bytes
                .chunks_exact(4)
                .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]) as f32)
                .collect(),
        }
    }

    /// True for the integer types a label volume may have (u8, u16, u32).
    pub fn holds_labels(self) -> bool {
        matches!(self, DType::U8 | DType::U16 | DType::U32)
    }

    /// The short name (`u8`, `u16`, `i16`, `f32`).
    pub fn name(self) -> &'static str {
        match self {
            DType::U8 => "u8",
            DType::U16 => "u16",
            DType::I16 => "i16",
            DType::F32 => "f32",
            DType::U32 => "u32",
        }
    }
}

/// Errors describing a volume that cannot be represented.
#[derive(Debug, Error, Clone, PartialEq)]
#[non_exhaustive]
pub enum VolumeError {
    /// A dimension is zero or larger than [`MAX_DIM`], or the voxel count overflows.
    #[error(
        "invalid volume dimensions {dims:?}: each must be in 1..={max} and the voxel count must fit in memory"
    )]
    BadDims {
        /// The offending dimensions.
        dims: [u64; 3],
        /// The largest accepted dimension.
        max: u32,
    },
    /// The data length does not match the dimensions and sample type.
    #[error("volume data holds {actual} bytes but dims {dims:?} of {dtype:?} need {expected}")]
    SizeMismatch {
        /// Dimensions.
        dims: [u32; 3],
        /// Sample type.
        dtype: DType,
        /// Bytes needed.
        expected: u64,
        /// Bytes given.
        actual: u64,
    },
    /// A float volume holds NaN or infinite samples.
    #[error("{count} non-finite (NaN or Inf) samples, first at voxel {first:?}")]
    NonFinite {
        /// Number of NaN/Inf samples.
        count: u64,
        /// Voxel coordinates of the first one.
        first: [u32; 3],
    },
    /// A voxel spacing is not a positive finite number.
    #[error("invalid voxel spacing {0:?}: each must be finite and > 0")]
    BadSpacing([f32; 3]),
    /// A label volume whose samples are not unsigned integers.
    #[error(
        "a label volume must hold u8, u16 or u32 ids, not {0:?} (u64 labels are not supported: convert them to u32 ids)"
    )]
    LabelType(DType),
}

/// Checks dimensions and returns the voxel count.
pub fn voxel_count(dims: [u64; 3]) -> Result<u64, VolumeError> {
    let bad = || VolumeError::BadDims { dims, max: MAX_DIM };
    if dims.iter().any(|&d| d == 0 || d > MAX_DIM as u64) {
        return Err(bad());
    }
    dims[0]
        .checked_mul(dims[1])
        .and_then(|v| v.checked_mul(dims[2]))
        .filter(|&v| v <= (1u64 << 48))
        .ok_or_else(bad)
}

/// What a volume's samples are: intensities (a scalar field, filtered and
/// classified by a transfer function) or labels (integer ids of a
/// segmentation: never filtered or averaged; drawn through a label table,
/// [`crate::labels::LabelTable`]).
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum VolumeKind {
    /// A scalar field (CT, MRI, microscopy, simulation).
    #[default]
    Intensity,
    /// A segmentation: each voxel holds a label id (u8, u16 or u32).
    Labels,
}

impl VolumeKind {
    /// Parses `intensity`/`image`/`scalar` and `labels`/`label`/`segmentation`.
    pub fn parse(name: &str) -> Option<VolumeKind> {
        match name.trim().to_ascii_lowercase().as_str() {
            "intensity" | "image" | "scalar" => Some(VolumeKind::Intensity),
            "labels" | "label" | "segmentation" | "labelmap" | "label map" => {
                Some(VolumeKind::Labels)
            }
            _ => None,
        }
    }

    /// True for [`VolumeKind::Labels`].
    pub fn is_labels(self) -> bool {
        self == VolumeKind::Labels
    }
}

/// Describes a volume: its grid, sample type, spacing and value range.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct VolumeDesc {
    /// Voxels along x, y, z (x fastest in memory).
    pub dims: [u32; 3],
    /// Sample type.
    pub dtype: DType,
    /// Physical size of a voxel along x, y, z (any unit, the same on each axis).
    pub spacing: [f32; 3],
    /// The range that maps to normalized value 0..1 (transfer-function space).
    /// For labels, [`crate::labels::label_value_range`]: label `i` maps to
    /// entry `i` of the label table.
    pub value_range: [f32; 2],
    /// Intensities or labels (absent in older sidecars and stores:
    /// intensity).
    #[serde(default)]
    pub kind: VolumeKind,
}

impl VolumeDesc {
    /// Validates dims, spacing and range, and that a label volume has an
    /// integer type.
    pub fn validate(&self) -> Result<(), VolumeError> {
        voxel_count(self.dims.map(u64::from))?;
        if self.spacing.iter().any(|s| !s.is_finite() || *s <= 0.0) {
            return Err(VolumeError::BadSpacing(self.spacing));
        }
        if self.kind.is_labels() && !self.dtype.holds_labels() {
            return Err(VolumeError::LabelType(self.dtype));
        }
        Ok(())
    }

    /// Number of voxels.
    pub fn voxel_count(&self) -> u64 {
        self.dims.iter().map(|&d| d as u64).product()
    }

    /// Size of the raw sample data in bytes.
    pub fn byte_len(&self) -> u64 {
        self.voxel_count() * self.dtype.size() as u64
    }

    /// Physical extent `dims * spacing`.
    pub fn extent(&self) -> glam::Vec3 {
        glam::Vec3::from_array(self.spacing) * glam::UVec3::from_array(self.dims).as_vec3()
    }

    /// Maps a raw sample value to transfer-function space (0..1 over `value_range`).
    #[inline]
    pub fn normalize(&self, raw: f32) -> f32 {
        let [lo, hi] = self.value_range;
        let span = hi - lo;
        if span > 0.0 { (raw - lo) / span } else { 0.0 }
    }
}

/// Voxel storage, one variant per [`DType`].
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum VolumeData {
    /// u8 samples.
    U8(Vec<u8>),
    /// u16 samples.
    U16(Vec<u16>),
    /// i16 samples.
    I16(Vec<i16>),
    /// f32 samples.
    F32(Vec<f32>),
    /// u32 samples (label ids).
    U32(Vec<u32>),
}

impl VolumeData {
    /// The sample type.
    pub fn dtype(&self) -> DType {
        match self {
            VolumeData::U8(_) => DType::U8,
            VolumeData::U16(_) => DType::U16,
            VolumeData::I16(_) => DType::I16,
            VolumeData::F32(_) => DType::F32,
            VolumeData::U32(_) => DType::U32,
        }
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        match self {
            VolumeData::U8(v) => v.len(),
            VolumeData::U16(v) => v.len(),
            VolumeData::I16(v) => v.len(),
            VolumeData::F32(v) => v.len(),
            VolumeData::U32(v) => v.len(),
        }
    }

    /// True when there are no samples.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Sample `i` as f32.
    #[inline]
    pub fn get(&self, i: usize) -> f32 {
        match self {
            VolumeData::U8(v) => v[i] as f32,
            VolumeData::U16(v) => v[i] as f32,
            VolumeData::I16(v) => v[i] as f32,
            VolumeData::F32(v) => v[i],
            VolumeData::U32(v) => v[i] as f32,
        }
    }

    /// Sample `i` as an integer label id (exact for u8, u16 and u32; other
    /// types are rounded and clamped to `0..=u32::MAX`).
    #[inline]
    pub fn label(&self, i: usize) -> u32 {
        match self {
            VolumeData::U8(v) => v[i] as u32,
            VolumeData::U16(v) => v[i] as u32,
            VolumeData::U32(v) => v[i],
            VolumeData::I16(v) => v[i].max(0) as u32,
            VolumeData::F32(v) => v[i].round().clamp(0.0, u32::MAX as f32) as u32,
        }
    }

    /// The samples as little-endian bytes (the in-memory layout on LE hosts).
    pub fn as_bytes(&self) -> &[u8] {
        match self {
            VolumeData::U8(v) => v,
            VolumeData::U16(v) => bytemuck::cast_slice(v),
            VolumeData::I16(v) => bytemuck::cast_slice(v),
            VolumeData::F32(v) => bytemuck::cast_slice(v),
            VolumeData::U32(v) => bytemuck::cast_slice(v),
        }
    }

    /// Decodes little-endian bytes. `bytes.len()` must be a multiple of the size.
    pub fn from_le_bytes(dtype: DType, bytes: &[u8]) -> VolumeData {
        match dtype {
            DType::U8 => VolumeData::U8(bytes.to_vec()),
            DType::U16 => VolumeData::U16(
                bytes
                    .chunks_exact(2)
                    .map(|c| u16::from_le_bytes([c[0], c[1]]))
                    .collect(),
            ),
            DType::I16 => VolumeData::I16(
                bytes
                    .chunks_exact(2)
                    .map(|c| i16::from_le_bytes([c[0], c[1]]))
                    .collect(),
            ),
            DType::F32 => VolumeData::F32(
                bytes
                    .chunks_exact(4)
                    .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                    .collect(),
            ),
            DType::U32 => VolumeData::U32(
                bytes
                    .chunks_exact(4)
                    .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                    .collect(),
            ),
        }
    }

    /// Smallest and largest sample (NaN ignored); `None` if empty.
    pub fn min_max(&self) -> Option<(f32, f32)> {
        fn mm<T: Copy + Into<f32>>(v: &[T]) -> Option<(f32, f32)> {
            let mut it = v.iter().map(|&x| x.into()).filter(|x: &f32| !x.is_nan());
            let first = it.next()?;
            Some(it.fold((first, first), |(a, b), x| (a.min(x), b.max(x))))
        }
        match self {
            VolumeData::U8(v) => mm(v),
            VolumeData::U16(v) => mm(v),
            VolumeData::I16(v) => mm(v),
            VolumeData::F32(v) => mm(v),
            VolumeData::U32(v) => {
                let lo = v.iter().min()?;
                let hi = v.iter().max()?;
                Some((*lo as f32, *hi as f32))
            }
        }
    }
}

/// A scalar volume in memory, x fastest, then y, then z.
#[derive(Debug, Clone, PartialEq)]
pub struct Volume {
    desc: VolumeDesc,
    data: VolumeData,
}

impl Volume {
    /// Builds a volume, checking dims, spacing, data length and (for f32) that every
    /// sample is finite.
    pub fn new(desc: VolumeDesc, data: VolumeData) -> Result<Volume, VolumeError> {
        desc.validate()?;
        let expected = desc.voxel_count();
        if data.dtype() != desc.dtype || data.len() as u64 != expected {
            return Err(VolumeError::SizeMismatch {
                dims: desc.dims,
                dtype: desc.dtype,
                expected: expected * desc.dtype.size() as u64,
                actual: (data.len() * data.dtype().size()) as u64,
            });
        }
        if let VolumeData::F32(v) = &data {
            let mut count = 0u64;
            let mut first = None;
            for (i, x) in v.iter().enumerate() {
                if !x.is_finite() {
                    count += 1;
                    first.get_or_insert(i);
                }
            }
            if let Some(i) = first {
                let [nx, ny, _] = desc.dims.map(|d| d as usize);
                let first = [
                    (i % nx) as u32,
                    ((i / nx) % ny) as u32,
                    (i / (nx * ny)) as u32,
                ];
                return Err(VolumeError::NonFinite { count, first });
            }
        }
        Ok(Volume { desc, data })
    }

    /// Builds a volume whose value range is the data's min..max.
    pub fn with_data_range(
        dims: [u32; 3],
        spacing: [f32; 3],
        data: VolumeData,
    ) -> Result<Volume, VolumeError> {
        let dtype = data.dtype();
        let (lo, hi) = data.min_max().unwrap_or((0.0, 1.0));
        let hi = if hi > lo { hi } else { lo + 1.0 };
        Volume::new(
            VolumeDesc {
                dims,
                dtype,
                spacing,
                value_range: [lo, hi],
                kind: VolumeKind::Intensity,
            },
            data,
        )
    }

    /// The description.
    pub fn desc(&self) -> &VolumeDesc {
        &self.desc
    }

    /// Replaces the value range used for normalization.
    pub fn set_value_range(&mut self, range: [f32; 2]) {
        self.desc.value_range = range;
    }

    /// The samples.
    pub fn data(&self) -> &VolumeData {
        &self.data
    }

    /// Dimensions.
    pub fn dims(&self) -> [u32; 3] {
        self.desc.dims
    }

    /// Raw sample at integer coordinates, clamped to the grid (clamp-to-edge).
    #[inline]
    pub fn voxel_clamped(&self, x: i64, y: i64, z: i64) -> f32 {
        let [nx, ny, nz] = self.desc.dims.map(|d| d as i64);
        let x = x.clamp(0, nx - 1);
        let y = y.clamp(0, ny - 1);
        let z = z.clamp(0, nz - 1);
        self.data.get((x + nx * (y + ny * z)) as usize)
    }

    /// Normalized (transfer-function space) sample at integer coordinates, clamped.
    #[inline]
    pub fn voxel_normalized(&self, x: i64, y: i64, z: i64) -> f32 {
        self.desc.normalize(self.voxel_clamped(x, y, z))
    }

    /// The normalized value of the voxel nearest to continuous voxel
    /// coordinates `p` (voxel centres at integers; clamp-to-edge), as a GPU
    /// texture read with a nearest sampler: how label maps are sampled.
    pub fn sample_nearest(&self, p: [f64; 3]) -> f64 {
        let i = p.map(|c| (c + 0.5).floor() as i64);
        let raw = self.voxel_clamped(i[0], i[1], i[2]) as f64;
        let [lo, hi] = self.desc.value_range.map(f64::from);
        if hi > lo { (raw - lo) / (hi - lo) } else { 0.0 }
    }

    /// Exact trilinear interpolation of the normalized value at continuous voxel
    /// coordinates `p` where voxel centers sit at integers (`p = (0,0,0)` is the
    /// center of the first voxel). Clamp-to-edge outside the grid, as a GPU
    /// texture with `ClampToEdge` does. Computed in f64.
    pub fn sample_trilinear(&self, p: [f64; 3]) -> f64 {
        let f = p.map(|c| c.floor());
        let t = [p[0] - f[0], p[1] - f[1], p[2] - f[2]];
        let i = f.map(|c| c as i64);
        let mut acc = 0.0f64;
        for dz in 0..2 {
            let wz = if dz == 0 { 1.0 - t[2] } else { t[2] };
            for dy in 0..2 {
                let wy = if dy == 0 { 1.0 - t[1] } else { t[1] };
                for dx in 0..2 {
                    let wx = if dx == 0 { 1.0 - t[0] } else { t[0] };
                    let w = wx * wy * wz;
                    if w != 0.0 {
                        acc += w * self.voxel_clamped(i[0] + dx, i[1] + dy, i[2] + dz) as f64;
                    }
                }
            }
        }
        let [lo, hi] = self.desc.value_range.map(f64::from);
        if hi > lo { (acc - lo) / (hi - lo) } else { 0.0 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_bad_dims_and_sizes() {
        assert!(matches!(
            voxel_count([0, 1, 1]),
            Err(VolumeError::BadDims { .. })
        ));
        assert!(matches!(
            voxel_count([1 << 25, 1, 1]),
            Err(VolumeError::BadDims { .. })
        ));
        assert!(matches!(
            voxel_count([1 << 24, 1 << 24, 1 << 24]),
            Err(VolumeError::BadDims { .. })
        ));
        let desc = VolumeDesc {
            dims: [2, 2, 2],
            dtype: DType::U8,
            spacing: [1.0; 3],
            value_range: [0.0, 255.0],
            kind: Default::default(),
        };
        assert!(matches!(
            Volume::new(desc.clone(), VolumeData::U8(vec![0; 7])),
            Err(VolumeError::SizeMismatch {
                expected: 8,
                actual: 7,
                ..
            })
        ));
        let mut bad = desc.clone();
        bad.spacing = [1.0, f32::NAN, 1.0];
        assert!(matches!(
            Volume::new(bad, VolumeData::U8(vec![0; 8])),
            Err(VolumeError::BadSpacing(_))
        ));
    }

    #[test]
    fn rejects_non_finite_floats() {
        let desc = VolumeDesc {
            dims: [2, 2, 1],
            dtype: DType::F32,
            spacing: [1.0; 3],
            value_range: [0.0, 1.0],
            kind: Default::default(),
        };
        let err = Volume::new(
            desc,
            VolumeData::F32(vec![0.0, 1.0, f32::INFINITY, f32::NAN]),
        )
        .unwrap_err();
        assert_eq!(
            err,
            VolumeError::NonFinite {
                count: 2,
                first: [0, 1, 0]
            }
        );
    }

    #[test]
    fn trilinear_is_exact_on_linear_fields() {
        let dims = [5u32, 4, 3];
        let mut v = Vec::new();
        for z in 0..3 {
            for y in 0..4 {
                for x in 0..5 {
                    v.push((x + 2 * y + 3 * z) as f32);
                }
            }
        }
        let desc = VolumeDesc {
            dims,
            dtype: DType::F32,
            spacing: [1.0; 3],
            value_range: [0.0, 1.0],
            kind: Default::default(),
        };
        let vol = Volume::new(desc, VolumeData::F32(v)).unwrap();
        let s = vol.sample_trilinear([1.25, 2.5, 0.75]);
        assert!((s - (1.25 + 5.0 + 2.25)).abs() < 1e-12);
        // clamp to edge
        assert_eq!(vol.sample_trilinear([-3.0, 0.0, 0.0]), 0.0);
    }
}
