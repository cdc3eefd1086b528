//! Sample conversion shared by the readers: the sample types files hold
//! ([`SourceType`]) into the four brickray stores ([`DType`]), with a linear
//! rescale (NIfTI's `scl_slope`/`scl_inter`, DICOM's RescaleSlope/Intercept).
//!
//! The rules (also in `docs/formats.md`):
//! * without a rescale, u8, u16, i16 and f32 are kept; i8 widens to i16
//!   (exact); u32, i32 narrow to u16 or i16 when the data's range fits
//!   (exact), else to f32 (exact up to 2^24); f64 rounds to f32;
//! * with an integer rescale (slope and intercept whole numbers) the rescaled
//!   values are whole: they are stored as i16, or u16, when the rescaled range
//!   of the data fits (exact: CT's Hounsfield units), else as f32;
//! * any other rescale gives f32.

use brickray_core::DType;

/// A sample type as stored in a file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum SourceType {
    /// Unsigned 8-bit.
    U8,
    /// Signed 8-bit.
    I8,
    /// Unsigned 16-bit.
    U16,
    /// Signed 16-bit.
    I16,
    /// Unsigned 32-bit.
    U32,
    /// Signed 32-bit.
    I32,
    /// 32-bit float.
    F32,
    /// 64-bit float.
    F64,
}

impl SourceType {
    /// Bytes per sample.
    pub fn size(self) -> usize {
        match self {
            SourceType::U8 | SourceType::I8 => 1,
            SourceType::U16 | SourceType::I16 => 2,
            SourceType::U32 | SourceType::I32 | SourceType::F32 => 4,
            SourceType::F64 => 8,
        }
    }

    /// Short name (`"u16"`).
    pub fn name(self) -> &'static str {
        match self {
            SourceType::U8 => "u8",
            SourceType::I8 => "i8",
            SourceType::U16 => "u16",
            SourceType::I16 => "i16",
            SourceType::U32 => "u32",
            SourceType::I32 => "i32",
            SourceType::F32 => "f32",
            SourceType::F64 => "f64",
        }
    }

    /// Whether the type holds only whole numbers.
    pub fn is_integer(self) -> bool {
        !matches!(self, SourceType::F32 | SourceType::F64)
    }

    /// The store type that holds this type exactly without conversion, if any.
    fn native(self) -> Option<DType> {
        match self {
            SourceType::U8 => Some(DType::U8),
            SourceType::U16 => Some(DType::U16),
            SourceType::I16 => Some(DType::I16),
            SourceType::F32 => Some(DType::F32),
            _ => None,
        }
    }
}

/// Converts samples of a [`SourceType`] (either byte order), rescaled by
/// `value * slope + inter`, into little-endian samples of a [`DType`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SampleConverter {
    /// The file's sample type.
    pub src: SourceType,
    /// The file's byte order.
    pub big_endian: bool,
    /// Rescale slope.
    pub slope: f64,
    /// Rescale intercept.
    pub inter: f64,
    /// The store type written.
    pub dst: DType,
}

fn is_whole(x: f64) -> bool {
    x.is_finite() && x.fract() == 0.0
}

impl SampleConverter {
    /// Whether the rescale changes values.
    pub fn rescales(&self) -> bool {
        self.slope != 1.0 || self.inter != 0.0
    }

    /// Whether the conversion needs the data's (rescaled) range to choose its
    /// target ([`SampleConverter::choose`]).
    pub fn needs_range(src: SourceType, slope: f64, inter: f64) -> bool {
        let identity = slope == 1.0 && inter == 0.0;
        if identity {
            matches!(src, SourceType::U32 | SourceType::I32)
        } else {
            src.is_integer() && is_whole(slope) && is_whole(inter)
        }
    }

    /// Chooses the store type by the rules in the module documentation.
    /// `range` is the rescaled data's min..max, when known (needed where
    /// [`needs_range`](Self::needs_range) says).
    pub fn choose(
        src: SourceType,
        big_endian: bool,
        slope: f64,
        inter: f64,
        range: Option<[f64; 2]>,
    ) -> SampleConverter {
        let identity = slope == 1.0 && inter == 0.0;
        let fits = |lo: f64, hi: f64| range.is_some_and(|[a, b]| a >= lo && b <= hi);
        let dst = if identity && let Some(d) = src.native() {
            d
        } else if identity && src == SourceType::I8 {
            DType::I16
        } else if identity && src == SourceType::F64 {
            DType::F32
        } else if src.is_integer() && is_whole(slope) && is_whole(inter) {
            if identity && src == SourceType::U32 && fits(0.0, 65535.0) {
                DType::U16
            } else if fits(-32768.0, 32767.0) {
                DType::I16
            } else if fits(0.0, 65535.0) {
                DType::U16
            } else {
                DType::F32
            }
        } else {
            DType::F32
        };
        SampleConverter {
            src,
            big_endian,
            slope,
            inter,
            dst,
        }
    }

    /// A description for the reader's notes, e.g. `"u16 * 1 + -1024 -> i16"`.
    pub fn describe(&self) -> String {
        if self.rescales() {
            format!(
                "{} * {} + {} -> {}",
                self.src.name(),
                self.slope,
                self.inter,
                self.dst.name()
            )
        } else {
            format!("{} -> {}", self.src.name(), self.dst.name())
        }
    }

    /// Whether the conversion is a plain copy (same type, little-endian, no rescale).
    pub fn is_copy(&self) -> bool {
        !self.rescales()
            && self.src.native() == Some(self.dst)
            && (!self.big_endian || self.src.size() == 1)
    }

    /// One source sample (exactly `src.size()` bytes), rescaled.
    #[inline]
    pub fn value(&self, b: &[u8]) -> f64 {
        let v = self.raw_value(b);
        if self.rescales() {
            v * self.slope + self.inter
        } else {
            v
        }
    }

    #[inline]
    fn raw_value(&self, b: &[u8]) -> f64 {
        macro_rules! get {
            ($t:ty, $n:expr) => {{
                // a short slice (a caller's mistake) reads as zero-padded
                let mut a = [0u8; $n];
                let k = b.len().min($n);
                a[..k].copy_from_slice(&b[..k]);
                if self.big_endian {
                    <$t>::from_be_bytes(a) as f64
                } else {
                    <$t>::from_le_bytes(a) as f64
                }
            }};
        }
        match self.src {
            SourceType::U8 => b.first().copied().unwrap_or(0) as f64,
            SourceType::I8 => b.first().copied().unwrap_or(0) as i8 as f64,
            SourceType::U16 => get!(u16, 2),
            SourceType::I16 => get!(i16, 2),
            SourceType::U32 => get!(u32, 4),
            SourceType::I32 => get!(i32, 4),
            SourceType::F32 => get!(f32, 4),
            SourceType::F64 => get!(f64, 8),
        }
    }

    /// The min and max of the rescaled values of `src` (whole samples only),
    /// skipping non-finite values; `None` when there is none.
    pub fn range(&self, src: &[u8]) -> Option<[f64; 2]> {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for c in src.chunks_exact(self.src.size()) {
            let v = self.value(c);
            if v.is_finite() {
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
        (lo <= hi).then_some([lo, hi])
    }

    /// Converts whole source samples into `out` (little-endian `dst`), whose
    /// length must be `src.len() / src.size() * dst.size()`. Out-of-range
    /// values saturate (they cannot occur when the target was chosen from the
    /// data's range); floats round to nearest for integer targets.
    pub fn convert(&self, src: &[u8], out: &mut [u8]) {
        if self.is_copy() {
            // lengths that disagree (a caller's mistake) copy what both hold
            let n = src.len().min(out.len());
            out[..n].copy_from_slice(&src[..n]);
            return;
        }
        let n = self.src.size();
        let m = self.dst.size();
        for (c, o) in src.chunks_exact(n).zip(out.chunks_exact_mut(m)) {
            let v = self.value(c);
            match self.dst {
                DType::U8 => o[0] = v.round() as u8,
                DType::U16 => o.copy_from_slice(&(v.round() as u16).to_le_bytes()),
                DType::I16 => o.copy_from_slice(&(v.round() as i16).to_le_bytes()),
                _ => o.copy_from_slice(&(v as f32).to_le_bytes()),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ct_rescale_gives_exact_i16() {
        let c = SampleConverter::choose(
            SourceType::U16,
            false,
            1.0,
            -1024.0,
            Some([-1024.0, 3000.0]),
        );
        assert_eq!(c.dst, DType::I16);
        let src: Vec<u8> = [0u16, 1024, 4024]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let mut out = vec![0u8; 6];
        c.convert(&src, &mut out);
        let got: Vec<i16> = out
            .chunks(2)
            .map(|c| i16::from_le_bytes([c[0], c[1]]))
            .collect();
        assert_eq!(got, [-1024, 0, 3000]);
    }

    #[test]
    fn targets_follow_the_rules() {
        let t =
            |src, slope, inter, range| SampleConverter::choose(src, true, slope, inter, range).dst;
        assert_eq!(t(SourceType::U8, 1.0, 0.0, None), DType::U8);
        assert_eq!(t(SourceType::I8, 1.0, 0.0, None), DType::I16);
        assert_eq!(t(SourceType::F64, 1.0, 0.0, None), DType::F32);
        assert_eq!(
            t(SourceType::I32, 1.0, 0.0, Some([-5.0, 70000.0])),
            DType::F32
        );
        assert_eq!(
            t(SourceType::U32, 1.0, 0.0, Some([0.0, 60000.0])),
            DType::U16
        );
        assert_eq!(t(SourceType::U16, 0.5, 0.0, Some([0.0, 1.0])), DType::F32);
        assert_eq!(
            t(SourceType::U16, 2.0, 0.0, Some([0.0, 100000.0])),
            DType::F32
        );
    }

    #[test]
    fn big_endian_and_scaled_floats() {
        let c = SampleConverter::choose(SourceType::I16, true, 0.5, 1.0, None);
        assert_eq!(c.dst, DType::F32);
        let mut out = [0u8; 4];
        c.convert(&(-4i16).to_be_bytes(), &mut out);
        assert_eq!(f32::from_le_bytes(out), -1.0);
    }
}

/// Sample bytes at an offset in a file, plain or gzip-compressed, read at any
/// position: a plain file seeks; a gzip stream decodes forward (reopened when
/// asked for an earlier position), so reading in increasing order is one pass.
/// (NIfTI's.)
#[cfg(feature = "nifti")]
#[derive(Debug)]
pub(crate) struct ByteStream {
    path: std::path::PathBuf,
    offset: u64,
    /// The sample bytes announced (for errors).
    total: u64,
    gzip: bool,
    plain: Option<std::fs::File>,
    gz: Option<(
        flate2::read::GzDecoder<std::io::BufReader<std::fs::File>>,
        u64,
    )>,
}

#[cfg(feature = "nifti")]
impl ByteStream {
    /// The stream of `total` bytes at `offset` in `path` (decoded bytes for gzip).
    pub(crate) fn new(path: &std::path::Path, offset: u64, total: u64, gzip: bool) -> ByteStream {
        ByteStream {
            path: path.to_owned(),
            offset,
            total,
            gzip,
            plain: None,
            gz: None,
        }
    }

    fn truncated(&self, actual: u64) -> crate::IoError {
        crate::IoError::Truncated {
            path: self.path.clone(),
            expected: self.total,
            actual,
        }
    }

    fn map_err(&self, e: std::io::Error, pos: u64) -> crate::IoError {
        match e.kind() {
            std::io::ErrorKind::UnexpectedEof => self.truncated(pos),
            std::io::ErrorKind::InvalidInput | std::io::ErrorKind::InvalidData => {
                crate::IoError::decode(&self.path, "gzip", e)
            }
            _ => crate::IoError::io(&self.path, e),
        }
    }

    /// Fills `out` from decoded byte `start`.
    pub(crate) fn read_at(&mut self, start: u64, out: &mut [u8]) -> Result<(), crate::IoError> {
        use std::io::{Read, Seek, SeekFrom};
        if !self.gzip {
            if self.plain.is_none() {
                self.plain = Some(crate::open_regular(&self.path)?);
            }
            let f = self.plain.as_mut().expect("opened above");
            let r = f
                .seek(SeekFrom::Start(self.offset.saturating_add(start)))
                .and_then(|_| f.read_exact(out));
            let len = f.metadata().map(|m| m.len()).unwrap_or(0);
            return r.map_err(|e| self.map_err(e, len.saturating_sub(self.offset)));
        }
        // gzip: decoded positions count from the stream's start (header
        // included, for a .nii.gz), so the offset is skipped by decoding
        let start = self.offset.saturating_add(start);
        if self.gz.as_ref().is_none_or(|(_, pos)| *pos > start) {
            let f = crate::open_regular(&self.path)?;
            self.gz = Some((flate2::read::GzDecoder::new(std::io::BufReader::new(f)), 0));
        }
        let (mut gz, mut pos) = self.gz.take().expect("set above");
        let skip = start - pos;
        let copied = std::io::copy(&mut gz.by_ref().take(skip), &mut std::io::sink())
            .map_err(|e| self.map_err(e, pos.saturating_sub(self.offset)))?;
        pos += copied;
        if copied < skip {
            return Err(self.truncated(pos.saturating_sub(self.offset)));
        }
        let mut filled = 0;
        while filled < out.len() {
            match gz.read(&mut out[filled..]) {
                Ok(0) => return Err(self.truncated(pos + filled as u64 - self.offset)),
                Ok(n) => filled += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(self.map_err(e, pos + filled as u64 - self.offset)),
            }
        }
        self.gz = Some((gz, pos + filled as u64));
        Ok(())
    }
}

#[cfg(feature = "nifti")]
impl ByteStream {
    /// For gzip, decodes the rest of the stream from where the last read
    /// stopped, so that the CRC and the length in the gzip trailer are
    /// checked: a damaged stream whose data still decodes (a flipped byte in
    /// a stored block) is a [`crate::IoError::Decode`], not a wrong voxel.
    /// Nothing to do for a plain file.
    pub(crate) fn verify_to_end(&mut self) -> Result<(), crate::IoError> {
        use std::io::Read;
        if !self.gzip {
            return Ok(());
        }
        let (mut gz, pos) = match self.gz.take() {
            Some(g) => g,
            None => {
                let f = crate::open_regular(&self.path)?;
                (flate2::read::GzDecoder::new(std::io::BufReader::new(f)), 0)
            }
        };
        let mut buf = [0u8; 1 << 14];
        loop {
            match gz.read(&mut buf) {
                Ok(0) => return Ok(()),
                Ok(_) => {}
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => {
                    return Err(match e.kind() {
                        std::io::ErrorKind::UnexpectedEof => crate::IoError::decode(
                            &self.path,
                            "gzip",
                            "the stream ends before its trailer (CRC and length)",
                        ),
                        std::io::ErrorKind::InvalidInput | std::io::ErrorKind::InvalidData => {
                            crate::IoError::decode(&self.path, "gzip", e)
                        }
                        _ => self.map_err(e, pos),
                    });
                }
            }
        }
    }
}

/// Reads source bytes at a decoded position into a buffer.
#[cfg(feature = "nifti")]
pub(crate) type SlabRead<'a> = dyn FnMut(u64, &mut [u8]) -> Result<(), crate::IoError> + 'a;

/// One bounded-memory pass over `n` samples of `conv.src` read through
/// `read(start, buf)`: the rescaled min..max, or the volume error for the first
/// non-finite sample (voxel coordinates in `dims`).
#[cfg(feature = "nifti")]
pub(crate) fn scan_converted(
    path: &std::path::Path,
    conv: &SampleConverter,
    dims: [u32; 3],
    read: &mut SlabRead<'_>,
) -> Result<[f64; 2], crate::IoError> {
    const CHUNK: u64 = 1 << 20;
    let size = conv.src.size() as u64;
    let n = dims.iter().map(|&d| d as u64).product::<u64>();
    let total = n * size;
    let step = (CHUNK / size * size).max(size);
    let mut buf = vec![0u8; step.min(total) as usize];
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut bad: Option<(u64, u64)> = None;
    let mut pos = 0u64;
    while pos < total {
        let want = (total - pos).min(step) as usize;
        let chunk = &mut buf[..want];
        read(pos, chunk)?;
        for (i, c) in chunk.chunks_exact(size as usize).enumerate() {
            let v = conv.value(c);
            if v.is_finite() {
                lo = lo.min(v);
                hi = hi.max(v);
            } else {
                let e = bad.get_or_insert((pos / size + i as u64, 0));
                e.1 += 1;
            }
        }
        pos += want as u64;
    }
    if let Some((i, count)) = bad {
        let [nx, ny, _] = dims.map(u64::from);
        let first = [
            (i % nx) as u32,
            ((i / nx) % ny) as u32,
            (i / (nx * ny)) as u32,
        ];
        return Err(crate::IoError::volume(
            path,
            brickray_core::VolumeError::NonFinite { count, first },
        ));
    }
    Ok([lo, hi])
}

/// The value range stored in a [`brickray_core::VolumeDesc`]: `[lo, hi]` as
/// f32, widened to `lo..lo+1` when flat. A range beyond f32's (a rescale that
/// overflows, f64 samples of 1e39) is [`crate::IoError::SampleOverflow`]: the
/// samples would be stored as infinity.
pub(crate) fn desc_range(path: &std::path::Path, r: [f64; 2]) -> Result<[f32; 2], crate::IoError> {
    let lo = r[0] as f32;
    let hi = r[1] as f32;
    if !(lo.is_finite() && hi.is_finite()) {
        return Err(crate::IoError::SampleOverflow {
            path: path.to_owned(),
            lo: r[0],
            hi: r[1],
        });
    }
    Ok(widen_flat(lo, hi))
}

/// A finite range made strictly increasing: a flat one becomes `lo..lo+1`;
/// beyond 2^24, where adding 1 rounds back to `lo` (values of 9e9 once gave
/// a range of zero width), `lo` and the next f32 up (or down, at f32's end).
pub(crate) fn widen_flat(mut lo: f32, mut hi: f32) -> [f32; 2] {
    if hi <= lo {
        hi = lo + 1.0;
    }
    if hi <= lo {
        hi = lo.next_up();
        if !hi.is_finite() {
            hi = lo;
            lo = lo.next_down();
        }
    }
    [lo, hi]
}
