//! NIfTI-1 and NIfTI-2 (<https://nifti.nimh.nih.gov/nifti-1>,
//! <https://nifti.nimh.nih.gov/nifti-2>): single files (`.nii`, `.nii.gz`) and
//! header/image pairs (`.hdr` + `.img`), either byte order.
//!
//! Read by hand rather than with the `nifti` crate: that crate (0.18) parses
//! NIfTI-1 headers only, and hands volumes over as whole ndarrays, where the
//! builder needs z-slabs streamed from a seek in the uncompressed file. The
//! header is two fixed C structs (348 and 540 bytes); every field used is
//! checked here and a lying header is a typed error.
//!
//! * sample types u8, i8, u16, i16, u32, i32, f32, f64 (converted as
//!   [`crate::SampleConverter`] states); complex, RGB and 64-bit integers are
//!   refused;
//! * `scl_slope` / `scl_inter` applied (slope 0 means no scaling, per the
//!   standard);
//! * the sform (when `sform_code > 0`), else the qform (`qform_code > 0`), else
//!   the voxel sizes, as the [`Placement`] (RAS+ millimetres), so anatomy is
//!   shown as acquired, not mirrored;
//! * 4D files: one time point ([`ReadOptions::time`], first by default); a 5th
//!   dimension (vectors) is refused;
//! * uncompressed data read lazily (each slab by a seek); gzip decoded
//!   forward, once per pass.

use crate::slab::{ByteStream, desc_range, scan_converted};
use crate::{
    Claim, Format, IoError, Placement, Probe, ReadOptions, Registry, SampleConverter, SourceType,
    VolumeReader, check_slab, open_regular, resolve_data_file,
};
use brickray_core::VolumeDesc;
use std::io::Read;
use std::path::{Path, PathBuf};

/// A parsed NIfTI header (both versions).
#[derive(Debug, Clone, PartialEq)]
pub struct NiftiHeader {
    /// 1 or 2.
    pub version: u8,
    /// The header's byte order.
    pub big_endian: bool,
    /// `dim[0..8]`.
    pub dim: [i64; 8],
    /// `pixdim[0..8]`.
    pub pixdim: [f64; 8],
    /// NIfTI datatype code.
    pub datatype: i16,
    /// Bits per voxel.
    pub bitpix: i16,
    /// Byte offset of the data (in the `.nii`; 0 in a `.img`).
    pub vox_offset: f64,
    /// Scale slope (0: none).
    pub scl_slope: f64,
    /// Scale intercept.
    pub scl_inter: f64,
    /// qform code.
    pub qform_code: i32,
    /// sform code.
    pub sform_code: i32,
    /// Quaternion b, c, d.
    pub quatern: [f64; 3],
    /// qform offsets.
    pub qoffset: [f64; 3],
    /// sform rows.
    pub srow: [[f64; 4]; 3],
    /// Single file (`n+1`/`n+2`) rather than a header/image pair (`ni1`/`ni2`).
    pub single_file: bool,
}

struct Fields<'a> {
    b: &'a [u8],
    be: bool,
}

impl Fields<'_> {
    fn bytes<const N: usize>(&self, at: usize) -> [u8; N] {
        let mut a = [0u8; N];
        a.copy_from_slice(&self.b[at..at + N]);
        if self.be {
            a.reverse();
        }
        a
    }
    fn i16(&self, at: usize) -> i16 {
        i16::from_le_bytes(self.bytes(at))
    }
    fn i32(&self, at: usize) -> i32 {
        i32::from_le_bytes(self.bytes(at))
    }
    fn i64(&self, at: usize) -> i64 {
        i64::from_le_bytes(self.bytes(at))
    }
    fn f32(&self, at: usize) -> f64 {
        f32::from_le_bytes(self.bytes(at)) as f64
    }
    fn f64(&self, at: usize) -> f64 {
        f64::from_le_bytes(self.bytes(at))
    }
}

impl NiftiHeader {
    /// Parses a header from its first bytes (at least 348 for NIfTI-1, 540 for
    /// NIfTI-2); `path` names it in errors.
    pub fn parse(path: &Path, b: &[u8]) -> Result<NiftiHeader, IoError> {
        if b.len() < 348 {
            return Err(IoError::Truncated {
                path: path.to_owned(),
                expected: 348,
                actual: b.len() as u64,
            });
        }
        let le = i32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        let be = i32::from_be_bytes([b[0], b[1], b[2], b[3]]);
        let (version, big_endian) = match (le, be) {
            (348, _) => (1, false),
            (_, 348) => (1, true),
            (540, _) => (2, false),
            (_, 540) => (2, true),
            _ => {
                return Err(IoError::header(
                    path,
                    format!("sizeof_hdr is {le}, not 348 (NIfTI-1) or 540 (NIfTI-2)"),
                ));
            }
        };
        let f = Fields { b, be: big_endian };
        if version == 1 {
            let magic = &b[344..348];
            let single_file = match magic {
                b"n+1\0" => true,
                b"ni1\0" => false,
                _ => {
                    return Err(IoError::header(
                        path,
                        format!("bad NIfTI-1 magic {magic:?}"),
                    ));
                }
            };
            let mut dim = [0i64; 8];
            let mut pixdim = [0f64; 8];
            for i in 0..8 {
                dim[i] = f.i16(40 + 2 * i) as i64;
                pixdim[i] = f.f32(76 + 4 * i);
            }
            let mut srow = [[0f64; 4]; 3];
            for (r, row) in srow.iter_mut().enumerate() {
                for (c, v) in row.iter_mut().enumerate() {
                    *v = f.f32(280 + 16 * r + 4 * c);
                }
            }
            Ok(NiftiHeader {
                version,
                big_endian,
                dim,
                pixdim,
                datatype: f.i16(70),
                bitpix: f.i16(72),
                vox_offset: f.f32(108),
                scl_slope: f.f32(112),
                scl_inter: f.f32(116),
                qform_code: f.i16(252) as i32,
                sform_code: f.i16(254) as i32,
                quatern: [f.f32(256), f.f32(260), f.f32(264)],
                qoffset: [f.f32(268), f.f32(272), f.f32(276)],
                srow,
                single_file,
            })
        } else {
            if b.len() < 540 {
                return Err(IoError::Truncated {
                    path: path.to_owned(),
                    expected: 540,
                    actual: b.len() as u64,
                });
            }
            let magic = &b[4..12];
            let single_file = match &magic[..4] {
                b"n+2\0" => true,
                b"ni2\0" => false,
                _ => {
                    return Err(IoError::header(
                        path,
                        format!("bad NIfTI-2 magic {magic:?}"),
                    ));
                }
            };
            let mut dim = [0i64; 8];
            let mut pixdim = [0f64; 8];
            for i in 0..8 {
                dim[i] = f.i64(16 + 8 * i);
                pixdim[i] = f.f64(104 + 8 * i);
            }
            let mut srow = [[0f64; 4]; 3];
            for (r, row) in srow.iter_mut().enumerate() {
                for (c, v) in row.iter_mut().enumerate() {
                    *v = f.f64(400 + 32 * r + 8 * c);
                }
            }
            Ok(NiftiHeader {
                version,
                big_endian,
                dim,
                pixdim,
                datatype: f.i16(12),
                bitpix: f.i16(14),
                vox_offset: f.i64(168) as f64,
                scl_slope: f.f64(176),
                scl_inter: f.f64(184),
                qform_code: f.i32(344),
                sform_code: f.i32(348),
                quatern: [f.f64(352), f.f64(360), f.f64(368)],
                qoffset: [f.f64(376), f.f64(384), f.f64(392)],
                srow,
                single_file,
            })
        }
    }

    /// The header's size in bytes.
    pub fn size(&self) -> u64 {
        if self.version == 1 { 348 } else { 540 }
    }

    /// The sample type, or the refusal naming it.
    pub fn source_type(&self, path: &Path) -> Result<SourceType, IoError> {
        let (t, bits) = match self.datatype {
            2 => (SourceType::U8, 8),
            4 => (SourceType::I16, 16),
            8 => (SourceType::I32, 32),
            16 => (SourceType::F32, 32),
            64 => (SourceType::F64, 64),
            256 => (SourceType::I8, 8),
            512 => (SourceType::U16, 16),
            768 => (SourceType::U32, 32),
            other => {
                let name = match other {
                    1 => "binary",
                    32 => "complex64",
                    128 => "rgb24",
                    1024 => "int64",
                    1280 => "uint64",
                    1536 => "float128",
                    1792 => "complex128",
                    2048 => "complex256",
                    2304 => "rgba32",
                    _ => "unknown",
                };
                return Err(IoError::UnknownDType {
                    path: path.to_owned(),
                    name: format!("NIfTI datatype {other} ({name})"),
                });
            }
        };
        if self.bitpix != bits {
            return Err(IoError::header(
                path,
                format!(
                    "bitpix {} does not match datatype {}",
                    self.bitpix, self.datatype
                ),
            ));
        }
        Ok(t)
    }

    /// Checks the transform [`affine`](Self::affine) uses: the sform's rows
    /// (when `sform_code > 0`) or the qform's quaternion and offsets (when
    /// `qform_code > 0`) must be finite, and the voxel axes they give must
    /// span space (no zero column, a non-zero determinant): a placement that
    /// cannot be drawn is a typed error, never read as something else.
    pub fn check_affine(&self, path: &Path) -> Result<(), IoError> {
        let form = if self.sform_code > 0 {
            if self.srow.iter().flatten().any(|v| !v.is_finite()) {
                return Err(IoError::header(
                    path,
                    format!("the sform holds a non-finite number: {:?}", self.srow),
                ));
            }
            "sform"
        } else if self.qform_code > 0 {
            if self
                .quatern
                .iter()
                .chain(&self.qoffset)
                .any(|v| !v.is_finite())
            {
                return Err(IoError::header(
                    path,
                    format!(
                        "the qform holds a non-finite number: quatern {:?}, qoffset {:?}",
                        self.quatern, self.qoffset
                    ),
                ));
            }
            "qform"
        } else {
            return Ok(());
        };
        let a = self.affine();
        let norms = [0, 1, 2].map(|c| a[..3].iter().map(|row| row[c] * row[c]).sum::<f64>().sqrt());
        if let Some(c) = norms.iter().position(|n| !(n.is_finite() && *n > 0.0)) {
            return Err(IoError::header(
                path,
                format!("the {form} maps voxel axis {c} to no direction (a zero column)"),
            ));
        }
        let det = a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
            - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
            + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
        let scale: f64 = norms.iter().product();
        if !(det.is_finite() && det.abs() > 1e-9 * scale) {
            return Err(IoError::header(
                path,
                format!("the {form}'s voxel axes do not span space (determinant {det})"),
            ));
        }
        Ok(())
    }

    /// The voxel-to-world affine (RAS+ mm): sform, else qform, else scaling.
    pub fn affine(&self) -> [[f64; 4]; 4] {
        let mut a = [[0.0; 4]; 4];
        a[3][3] = 1.0;
        if self.sform_code > 0 {
            a[..3].copy_from_slice(&self.srow);
            return a;
        }
        let dx = [self.pixdim[1], self.pixdim[2], self.pixdim[3]];
        if self.qform_code > 0 {
            let [b, c, d] = self.quatern;
            let a2 = 1.0 - (b * b + c * c + d * d);
            let (qa, qb, qc, qd) = if a2 < 1e-7 {
                // a 180 degree rotation: renormalise (b, c, d), a = 0
                let n = (b * b + c * c + d * d).sqrt().max(f64::MIN_POSITIVE);
                (0.0, b / n, c / n, d / n)
            } else {
                (a2.sqrt(), b, c, d)
            };
            let r = [
                [
                    qa * qa + qb * qb - qc * qc - qd * qd,
                    2.0 * (qb * qc - qa * qd),
                    2.0 * (qb * qd + qa * qc),
                ],
                [
                    2.0 * (qb * qc + qa * qd),
                    qa * qa + qc * qc - qb * qb - qd * qd,
                    2.0 * (qc * qd - qa * qb),
                ],
                [
                    2.0 * (qb * qd - qa * qc),
                    2.0 * (qc * qd + qa * qb),
                    qa * qa + qd * qd - qc * qc - qb * qb,
                ],
            ];
            let qfac = if self.pixdim[0] < 0.0 { -1.0 } else { 1.0 };
            let s = [dx[0], dx[1], dx[2] * qfac];
            for i in 0..3 {
                for j in 0..3 {
                    a[i][j] = r[i][j] * s[j];
                }
                a[i][3] = self.qoffset[i];
            }
            return a;
        }
        for i in 0..3 {
            a[i][i] = dx[i];
        }
        a
    }
}

/// Streams a NIfTI volume.
#[derive(Debug)]
pub struct NiftiReader {
    path: PathBuf,
    data_path: PathBuf,
    header: NiftiHeader,
    conv: SampleConverter,
    desc: VolumeDesc,
    /// Byte offset of the chosen time point in the decoded data.
    t_offset: u64,
    stream: ByteStream,
    buf: Vec<u8>,
    warnings: Vec<String>,
}

fn is_gz(p: &Path) -> bool {
    p.extension().is_some_and(|e| e.eq_ignore_ascii_case("gz"))
}

/// Reads up to `n` leading (decoded) bytes of a file.
fn read_head(path: &Path, n: u64) -> Result<Vec<u8>, IoError> {
    let f = open_regular(path)?;
    let mut head = Vec::new();
    let r = if is_gz(path) {
        flate2::read::GzDecoder::new(std::io::BufReader::new(f))
            .take(n)
            .read_to_end(&mut head)
    } else {
        f.take(n).read_to_end(&mut head)
    };
    r.map_err(|e| match e.kind() {
        std::io::ErrorKind::InvalidInput | std::io::ErrorKind::InvalidData => {
            IoError::decode(path, "gzip", e)
        }
        _ => IoError::io(path, e),
    })?;
    Ok(head)
}

impl NiftiReader {
    // dims, pixdim and spacing are indexed together by axis
    #[allow(clippy::needless_range_loop)]
    /// Opens a `.nii`, `.nii.gz`, `.hdr` (with its `.img`) or `.img` (with its
    /// `.hdr`). Scans the data once (bounded memory) for its value range and
    /// for NaN/Inf, which also proves that it is all there.
    pub fn open(path: &Path, opts: &ReadOptions) -> Result<NiftiReader, IoError> {
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        let header_path = if ext == "img" {
            path.with_extension("hdr")
        } else {
            path.to_owned()
        };
        let head = read_head(&header_path, 540)?;
        let h = NiftiHeader::parse(&header_path, &head)?;
        let src = h.source_type(&header_path)?;
        let bad = |msg: String| IoError::header(&header_path, msg);
        let ndim = h.dim[0];
        if !(1..=7).contains(&ndim) {
            return Err(bad(format!("dim[0] is {ndim}, not 1..7")));
        }
        let mut d = [1i64; 7];
        for i in 0..ndim as usize {
            d[i] = h.dim[i + 1];
            if d[i] < 1 {
                return Err(bad(format!("dim[{}] is {}", i + 1, d[i])));
            }
        }
        if d[4..].iter().any(|&v| v > 1) {
            return Err(IoError::unsupported(
                &header_path,
                format!(
                    "a 5D+ NIfTI (dim {:?}): vectors or tensors per voxel",
                    &d[..ndim as usize]
                ),
            ));
        }
        let dims64 = [d[0] as u64, d[1] as u64, d[2] as u64];
        brickray_core::volume::voxel_count(dims64).map_err(|e| IoError::volume(&header_path, e))?;
        let dims = dims64.map(|v| v as u32);
        let times = d[3] as u64;
        let t = opts.time.unwrap_or(0);
        if t >= times {
            return Err(IoError::NoSuchChoice {
                path: header_path.clone(),
                what: "time point",
                wanted: t.to_string(),
                available: format!("0..{times}"),
            });
        }
        let mut spacing = [0f32; 3];
        for i in 0..3 {
            let p = if i < ndim as usize {
                h.pixdim[i + 1].abs()
            } else {
                1.0
            };
            if !(p.is_finite() && p > 0.0) {
                return Err(bad(format!(
                    "pixdim[{}] is {}, not a voxel size",
                    i + 1,
                    h.pixdim[i + 1]
                )));
            }
            spacing[i] = p as f32;
        }
        h.check_affine(&header_path)?;
        let mut warnings = Vec::new();
        // slope 0: no rescale (the standard's rule); a slope that is not
        // finite is read as none too (as other NIfTI readers do), but said
        let (slope, inter) = if h.scl_slope == 0.0 {
            (1.0, 0.0)
        } else if !h.scl_slope.is_finite() {
            warnings.push(format!(
                "scl_slope is {}: read as no rescale (slope 1, intercept 0)",
                h.scl_slope
            ));
            (1.0, 0.0)
        } else {
            (h.scl_slope, h.scl_inter)
        };
        if !inter.is_finite() {
            return Err(bad(format!("scl_inter is {inter}")));
        }
        let (data_path, offset) = if h.single_file {
            if header_path
                .extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("hdr"))
            {
                return Err(bad("a .hdr with the single-file magic n+1/n+2".into()));
            }
            let off = h.vox_offset;
            if !(off.is_finite() && off >= h.size() as f64 && off < 1e15) {
                return Err(bad(format!("vox_offset {off} lies inside the header")));
            }
            (header_path.clone(), off as u64)
        } else {
            let name = header_path.with_extension("img");
            let name = name.file_name().map(PathBuf::from).unwrap_or_default();
            (resolve_data_file(&header_path, &name, opts)?, 0)
        };
        let vol_bytes = dims64.iter().product::<u64>() * src.size() as u64;
        let total = vol_bytes.saturating_mul(times);
        let gz = is_gz(&data_path);
        if !gz {
            let len = crate::regular_file_metadata(&data_path)?.len();
            if len < offset.saturating_add(total) {
                return Err(IoError::Truncated {
                    path: data_path,
                    expected: offset.saturating_add(total),
                    actual: len,
                });
            }
        }
        let t_offset = t
            .checked_mul(vol_bytes)
            .ok_or_else(|| bad(format!("time point {t} of {vol_bytes}-byte volumes")))?;
        let mut stream = ByteStream::new(&data_path, offset, total, gz);
        let probe = SampleConverter::choose(src, h.big_endian, slope, inter, None);
        let range = scan_converted(&data_path, &probe, dims, &mut |pos, buf| {
            stream.read_at(t_offset + pos, buf)
        })?;
        // gzip: on to the trailer, so that its CRC and length are checked
        stream.verify_to_end()?;
        let conv = SampleConverter::choose(src, h.big_endian, slope, inter, Some(range));
        let desc = VolumeDesc {
            dims,
            dtype: conv.dst,
            spacing,
            value_range: desc_range(&header_path, range)?,
            kind: Default::default(),
        };
        desc.validate()
            .map_err(|e| IoError::volume(&header_path, e))?;
        Ok(NiftiReader {
            path: header_path,
            data_path,
            header: h,
            conv,
            desc,
            t_offset,
            stream,
            buf: Vec::new(),
            warnings,
        })
    }

    /// The parsed header.
    pub fn header(&self) -> &NiftiHeader {
        &self.header
    }
}

impl VolumeReader for NiftiReader {
    fn desc(&self) -> &VolumeDesc {
        &self.desc
    }

    fn format(&self) -> &'static str {
        if self.header.version == 1 {
            "NIfTI-1"
        } else {
            "NIfTI-2"
        }
    }

    fn path(&self) -> &Path {
        &self.path
    }

    fn input_files(&self) -> Vec<PathBuf> {
        let mut v = vec![self.path.clone()];
        if self.data_path != self.path {
            v.push(self.data_path.clone());
        }
        v
    }

    fn placement(&self) -> Option<Placement> {
        Some(Placement {
            affine: self.header.affine(),
            space: "RAS",
        })
    }

    fn notes(&self) -> Vec<String> {
        let mut n = vec![format!("samples: {}", self.conv.describe())];
        let form = if self.header.sform_code > 0 {
            "sform"
        } else if self.header.qform_code > 0 {
            "qform"
        } else {
            "voxel sizes only (no qform or sform)"
        };
        n.push(format!("placement from the {form}"));
        n
    }

    fn warnings(&self) -> Vec<String> {
        self.warnings.clone()
    }

    fn read_slices(&mut self, z0: u32, z1: u32, out: &mut [u8]) -> Result<(), IoError> {
        check_slab(&self.desc, z0, z1, out)?;
        let slice = self.desc.dims[0] as u64 * self.desc.dims[1] as u64;
        let n = self.conv.src.size();
        let start = self.t_offset + z0 as u64 * slice * n as u64;
        if self.conv.is_copy() {
            return self.stream.read_at(start, out);
        }
        self.buf.resize((z1 - z0) as usize * slice as usize * n, 0);
        self.stream.read_at(start, &mut self.buf)?;
        self.conv.convert(&self.buf, out);
        Ok(())
    }
}

#[derive(Debug)]
struct NiftiFormat;

impl Format for NiftiFormat {
    fn name(&self) -> &'static str {
        "NIfTI"
    }
    fn expects(&self) -> &'static str {
        ".nii, .nii.gz, .hdr/.img"
    }
    fn claims(&self, probe: &Probe) -> Claim {
        match probe.ext.as_str() {
            "nii" | "nii.gz" | "hdr" | "img" => Claim::ByName,
            _ => {
                let h = &probe.head;
                let magic1 = h.len() >= 348 && matches!(&h[344..348], b"n+1\0" | b"ni1\0");
                let magic2 = h.len() >= 12 && matches!(&h[4..8], b"n+2\0" | b"ni2\0");
                if magic1 || magic2 {
                    Claim::ByContent
                } else {
                    Claim::No
                }
            }
        }
    }
    fn open(&self, path: &Path, opts: &ReadOptions) -> Result<Box<dyn VolumeReader>, IoError> {
        Ok(Box::new(NiftiReader::open(path, opts)?))
    }
}

pub(crate) fn register(r: &mut Registry) {
    r.register(std::sync::Arc::new(NiftiFormat));
}
