//! DICOM series (dicom-rs: `dicom-object`, `dicom-pixeldata` with its pure
//! Rust codecs only).
//!
//! * a folder is searched recursively; files that are not DICOM images are
//!   skipped; the images are grouped by SeriesInstanceUID. With several
//!   series the one with the most slices is read unless
//!   [`ReadOptions::series`] names another (by UID or by its index in
//!   [`crate::list`]'s order);
//! * slices are ordered by ImagePositionPatient projected on the slice normal
//!   (the cross product of ImageOrientationPatient's row and column
//!   directions), never by file name or InstanceNumber;
//! * the slice spacing comes from the positions (not SliceThickness); a gap
//!   of more than 1.5 times the median gap is a missing slice (an error), and
//!   spacing that varies by more than 1% is reported in the notes; slices
//!   offset along the rows or columns (a gantry tilt) are reported, and the
//!   [`Placement`] (LPS+ mm) carries the real slice direction;
//! * RescaleSlope / RescaleIntercept are applied (CT Hounsfield units stored
//!   exactly as i16 when they fit);
//! * transfer syntaxes: implicit and explicit VR little endian, deflated, RLE
//!   lossless, JPEG baseline/extended/lossless and JPEG 2000 (pure Rust
//!   decoders); any other is an [`IoError::UnsupportedTransferSyntax`] naming
//!   the file and the syntax, before any pixel is read.

use crate::slab::desc_range;
use crate::{
    Claim, Entry, EntryKind, Format, IoError, Placement, Probe, ReadOptions, Registry,
    SampleConverter, SourceType, VolumeReader, check_slab,
};
use brickray_core::VolumeDesc;
use dicom_dictionary_std::tags;
use dicom_object::{DefaultDicomObject, OpenFileOptions, Tag};
use dicom_pixeldata::PixelDecoder;
use dicom_transfer_syntax_registry::{TransferSyntaxIndex, TransferSyntaxRegistry};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

mod header;

use header::{
    Pixels, SliceHeader, check_frame, check_lengths, check_syntax, dec_err, decode_rle, parse,
    read_header, read_part10,
};

/// Every regular file under `dir`, recursively, in path order.
fn walk(dir: &Path, out: &mut Vec<PathBuf>, depth: u32) -> Result<(), IoError> {
    if depth > 32 {
        return Ok(());
    }
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| IoError::io(dir, e))?
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .collect();
    entries.sort();
    for p in entries {
        let Ok(md) = std::fs::symlink_metadata(&p) else {
            continue;
        };
        if md.is_dir() {
            walk(&p, out, depth + 1)?;
        } else if md.is_file() {
            out.push(p);
        }
    }
    Ok(())
}

/// One series found in a folder.
#[derive(Debug, Clone)]
struct Series {
    uid: String,
    slices: Vec<SliceHeader>,
}

/// Groups the DICOM images under `path` (a folder, or one file: its folder) by
/// series, the largest first.
fn scan_series(path: &Path) -> Result<(PathBuf, Vec<Series>, Option<String>), IoError> {
    let md = std::fs::metadata(path).map_err(|e| IoError::io(path, e))?;
    let (root, only) = if md.is_dir() {
        (path.to_owned(), None)
    } else {
        let h = read_header(path)?.ok_or_else(|| IoError::header(path, "not a DICOM image"))?;
        let dir = path
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."))
            .to_owned();
        (dir, Some(h.series))
    };
    let mut files = Vec::new();
    walk(&root, &mut files, 0)?;
    let mut groups: BTreeMap<String, Vec<SliceHeader>> = BTreeMap::new();
    for f in files {
        if let Some(h) = read_header(&f)? {
            groups.entry(h.series.clone()).or_default().push(h);
        }
    }
    if groups.is_empty() {
        return Err(IoError::UnknownFormat {
            path: path.to_owned(),
            tried: "DICOM: no DICOM image in the folder".into(),
        });
    }
    let mut series: Vec<Series> = groups
        .into_iter()
        .map(|(uid, slices)| Series { uid, slices })
        .collect();
    series.sort_by(|a, b| b.slices.len().cmp(&a.slices.len()).then(a.uid.cmp(&b.uid)));
    Ok((root, series, only))
}

fn pick<'a>(
    path: &Path,
    series: &'a [Series],
    wanted: Option<&str>,
) -> Result<(usize, &'a Series), IoError> {
    let Some(w) = wanted else {
        return Ok((0, &series[0]));
    };
    if let Some(i) = series.iter().position(|s| s.uid == w) {
        return Ok((i, &series[i]));
    }
    if let Ok(i) = w.parse::<usize>()
        && i < series.len()
    {
        return Ok((i, &series[i]));
    }
    Err(IoError::NoSuchChoice {
        path: path.to_owned(),
        what: "series",
        wanted: w.to_owned(),
        available: series
            .iter()
            .enumerate()
            .map(|(i, s)| format!("{i}: {} ({} files)", s.uid, s.slices.len()))
            .collect::<Vec<_>>()
            .join(", "),
    })
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// Streams a DICOM series, one file per slice.
#[derive(Debug)]
pub struct DicomReader {
    path: PathBuf,
    uid: String,
    slices: Vec<SliceHeader>,
    convs: Vec<SampleConverter>,
    desc: VolumeDesc,
    placement: Placement,
    notes: Vec<String>,
    warnings: Vec<String>,
    entries: Vec<Entry>,
    buf: Vec<u8>,
}

impl DicomReader {
    /// Opens the series in a folder (see the module documentation), or the
    /// series of one file among its folder's files. Every slice is decoded
    /// once (one at a time) for the value range and to prove it decodable.
    pub fn open(path: &Path, opts: &ReadOptions) -> Result<DicomReader, IoError> {
        let (root, series, only) = scan_series(path)?;
        let wanted = opts.series.as_deref().or(only.as_deref());
        let (index, s) = pick(path, &series, wanted)?;
        let entries = series
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let h = &s.slices[0];
                Entry {
                    kind: EntryKind::Series,
                    id: s.uid.clone(),
                    summary: format!(
                        "#{i}: {} files, {}x{}, {} {:?}",
                        s.slices.len(),
                        h.cols,
                        h.rows,
                        h.modality,
                        h.description
                    ),
                    default: i == index,
                }
            })
            .collect();
        let mut notes = Vec::new();
        if series.len() > 1 {
            notes.push(format!(
                "{} series in the folder; reading #{index} {} ({} files)",
                series.len(),
                s.uid,
                s.slices.len()
            ));
        }
        let mut warnings = Vec::new();
        let mut slices = s.slices.clone();
        let first = slices[0].clone();
        for h in &slices {
            if h.pixel_spacing.is_some() != first.pixel_spacing.is_some()
                || h.pixel_spacing
                    .zip(first.pixel_spacing)
                    .is_some_and(|(a, b)| (0..2).any(|k| (a[k] - b[k]).abs() > 1e-4 * b[k]))
            {
                return Err(IoError::Inconsistent {
                    path: root.clone(),
                    file: h.file.clone(),
                    msg: format!(
                        "PixelSpacing {:?} differs from the series' first slice's {:?}",
                        h.pixel_spacing, first.pixel_spacing
                    ),
                });
            }
            let same = h.rows == first.rows
                && h.cols == first.cols
                && h.bits_allocated == first.bits_allocated
                && h.signed == first.signed;
            if !same {
                return Err(IoError::Inconsistent {
                    path: root.clone(),
                    file: h.file.clone(),
                    msg: format!(
                        "{}x{} {}-bit slice in a series of {}x{} {}-bit slices ({})",
                        h.cols,
                        h.rows,
                        h.bits_allocated,
                        first.cols,
                        first.rows,
                        first.bits_allocated,
                        first.file.display()
                    ),
                });
            }
            if h.orientation
                .iter()
                .zip(first.orientation.iter())
                .any(|(a, b)| (a - b).abs() > 1e-4)
            {
                return Err(IoError::Inconsistent {
                    path: root.clone(),
                    file: h.file.clone(),
                    msg: "ImageOrientationPatient differs from the series' first slice".into(),
                });
            }
            if h.samples != 1 {
                return Err(IoError::unsupported(
                    &h.file,
                    format!("{} samples per pixel (colour)", h.samples),
                ));
            }
            if h.frames != 1 {
                return Err(IoError::unsupported(
                    &h.file,
                    format!("a multi-frame image ({} frames)", h.frames),
                ));
            }
            check_syntax(&h.file, &h.ts)?;
        }
        let o = first.orientation;
        let row = [o[0], o[1], o[2]];
        let col = [o[3], o[4], o[5]];
        let normal = cross(row, col);
        if dot(normal, normal) < 0.5 {
            return Err(IoError::header(
                &first.file,
                "ImageOrientationPatient's directions are not orthonormal",
            ));
        }
        slices.sort_by(|a, b| dot(a.position, normal).total_cmp(&dot(b.position, normal)));
        let n = slices.len();
        let mut slice_step = 1.0;
        let mut slice_vec = [normal[0], normal[1], normal[2]];
        if n > 1 {
            let gaps: Vec<f64> = slices
                .windows(2)
                .map(|w| dot(sub(w[1].position, w[0].position), normal))
                .collect();
            let mut sorted = gaps.clone();
            sorted.sort_by(f64::total_cmp);
            let median = sorted[sorted.len() / 2];
            for (k, g) in gaps.iter().enumerate() {
                if *g < 1e-3 * median.max(1e-6) {
                    return Err(IoError::Inconsistent {
                        path: root.clone(),
                        file: slices[k + 1].file.clone(),
                        msg: format!(
                            "two slices at the same position (with {})",
                            slices[k].file.display()
                        ),
                    });
                }
                if *g > 1.5 * median {
                    return Err(IoError::Inconsistent {
                        path: root.clone(),
                        file: slices[k + 1].file.clone(),
                        msg: format!(
                            "a slice is missing before this one: gap {g:.3} mm after {}, \
                             the series' median gap is {median:.3} mm",
                            slices[k].file.display()
                        ),
                    });
                }
            }
            let total = dot(sub(slices[n - 1].position, slices[0].position), normal);
            slice_step = total / (n - 1) as f64;
            let spread = gaps
                .iter()
                .map(|g| (g - slice_step).abs())
                .fold(0.0, f64::max);
            if spread > 0.01 * slice_step {
                notes.push(format!(
                    "non-uniform slice spacing: gaps from {:.4} to {:.4} mm; the mean {slice_step:.4} mm is used",
                    sorted[0],
                    sorted[sorted.len() - 1]
                ));
            }
            let d = sub(slices[n - 1].position, slices[0].position);
            slice_vec = d.map(|x| x / (n - 1) as f64);
            let along = dot(d, normal);
            let off = sub(d, normal.map(|x| x * along));
            let tilt = (dot(off, off).sqrt() / along.abs()).atan().to_degrees();
            if tilt > 0.01 {
                notes.push(format!(
                    "gantry tilt: slices are offset {tilt:.2} degrees from the slice normal; \
                     the placement carries the sheared slice direction, spacing is along the normal"
                ));
            }
        }
        // Pixel spacing: [row spacing (between rows, along columns), column spacing].
        let (dx, dy) = match first.pixel_spacing {
            Some([row, col]) => (col, row),
            None => {
                warnings.push(format!(
                    "no PixelSpacing in the series ({} and the others): 1 mm x 1 mm assumed",
                    first.file.display()
                ));
                (1.0, 1.0)
            }
        };
        let spacing = [dx as f32, dy as f32, slice_step.abs() as f32];
        let mut affine = [[0.0; 4]; 4];
        for a in 0..3 {
            affine[a][0] = row[a] * dx;
            affine[a][1] = col[a] * dy;
            affine[a][2] = slice_vec[a];
            affine[a][3] = slices[0].position[a];
        }
        affine[3][3] = 1.0;
        let src = match (first.bits_allocated, first.signed) {
            (8, false) => SourceType::U8,
            (8, true) => SourceType::I8,
            (16, false) => SourceType::U16,
            (16, true) => SourceType::I16,
            (32, false) => SourceType::U32,
            (32, true) => SourceType::I32,
            (b, s) => {
                return Err(IoError::UnknownDType {
                    path: first.file.clone(),
                    name: format!("DICOM BitsAllocated {b}, signed {s}"),
                });
            }
        };
        let dims64 = [first.cols as u64, first.rows as u64, n as u64];
        brickray_core::volume::voxel_count(dims64).map_err(|e| IoError::volume(&root, e))?;
        let same_rescale = slices
            .iter()
            .all(|h| h.slope == first.slope && h.inter == first.inter);
        let mut r = DicomReader {
            path: root.clone(),
            uid: s.uid.clone(),
            convs: slices
                .iter()
                .map(|h| SampleConverter::choose(src, false, h.slope, h.inter, None))
                .collect(),
            slices,
            desc: VolumeDesc {
                dims: dims64.map(|v| v as u32),
                dtype: brickray_core::DType::F32,
                spacing,
                value_range: [0.0, 1.0],
                kind: Default::default(),
            },
            placement: Placement {
                affine,
                space: "LPS",
            },
            notes,
            warnings,
            entries,
            buf: Vec::new(),
        };
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for z in 0..n {
            r.decode(z)?;
            let conv = r.convs[z];
            for c in r.buf.chunks_exact(conv.src.size()) {
                let v = conv.value(c);
                lo = lo.min(v);
                hi = hi.max(v);
            }
            if !(lo.is_finite() && hi.is_finite()) {
                // integer samples rescaled beyond f64's range
                return Err(IoError::SampleOverflow {
                    path: r.slices[z].file.clone(),
                    lo,
                    hi,
                });
            }
        }
        let dst = if same_rescale {
            SampleConverter::choose(src, false, first.slope, first.inter, Some([lo, hi])).dst
        } else {
            r.notes
                .push("RescaleSlope/Intercept vary per slice: stored as f32".into());
            brickray_core::DType::F32
        };
        for c in &mut r.convs {
            c.dst = dst;
        }
        r.desc.dtype = dst;
        r.desc.value_range = desc_range(&root, [lo, hi])?;
        r.notes.push(format!("samples: {}", r.convs[0].describe()));
        r.desc.validate().map_err(|e| IoError::volume(&root, e))?;
        Ok(r)
    }

    /// The series read (its SeriesInstanceUID).
    pub fn series_uid(&self) -> &str {
        &self.uid
    }

    /// Every series in the folder (the one read marked default).
    pub fn entries(&self) -> &[Entry] {
        &self.entries
    }

    /// Decodes slice `z` into `self.buf` (little-endian source samples, the
    /// bits above BitsStored masked or sign-extended).
    fn decode(&mut self, z: usize) -> Result<(), IoError> {
        let h = &self.slices[z];
        // no slice is larger than 2^28 pixels
        if h.rows as u64 * h.cols as u64 > 1 << 28 {
            return Err(IoError::header(
                &h.file,
                format!("{}x{} pixels per slice", h.cols, h.rows),
            ));
        }
        let want = h.rows as u64 * h.cols as u64 * (h.bits_allocated as u64).div_ceil(8);
        let bytes = read_part10(&h.file)?
            .ok_or_else(|| IoError::header(&h.file, "no longer a DICOM file (no DICM magic)"))?;
        let mut rle = None;
        match check_lengths(&h.file, &bytes)? {
            // native pixel data must hold the whole image before a decoder
            // allocates for it
            Some(Pixels::Native(len)) if (len as u64) < want => {
                return Err(IoError::Truncated {
                    path: h.file.clone(),
                    expected: want,
                    actual: len as u64,
                });
            }
            // encapsulated: the compressed stream's own header must declare
            // the header's image before a decoder allocates for it
            Some(Pixels::Encapsulated(frags)) => {
                let frame: Vec<u8> = frags
                    .iter()
                    .flat_map(|r| &bytes[r.clone()])
                    .copied()
                    .collect();
                check_frame(h, &frame)?;
                if h.ts == "1.2.840.10008.1.2.5" {
                    rle = Some(frame);
                }
            }
            _ => {}
        }
        let obj = parse(&h.file, &bytes, None)?;
        drop(bytes);
        let ts = obj.meta().transfer_syntax().trim_end_matches('\0');
        check_syntax(&h.file, ts)?;
        if ts != h.ts {
            return Err(IoError::Inconsistent {
                path: self.path.clone(),
                file: h.file.clone(),
                msg: format!("transfer syntax {ts} where the header scan read {}", h.ts),
            });
        }
        let want = want as usize;
        if let Some(frame) = rle {
            decode_rle(h, &frame, &mut self.buf)?;
        } else {
            // A panic in a decoder (a bug of its own on hostile input) is
            // contained as a decode error naming the file, where panics
            // unwind (the default); the data set is local, nothing outlives it.
            let decoded = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                let px = obj.decode_pixel_data().map_err(|e| dec_err(&h.file, e))?;
                let data = px.frame_data(0).map_err(|e| dec_err(&h.file, e))?;
                Ok::<Vec<u8>, IoError>(data.to_vec())
            }));
            let data = match decoded {
                Ok(r) => r?,
                Err(p) => {
                    let msg = p
                        .downcast_ref::<String>()
                        .cloned()
                        .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                        .unwrap_or_default();
                    return Err(dec_err(&h.file, format!("the pixel decoder failed: {msg}")));
                }
            };
            self.buf = data;
        }
        if self.buf.len() != want {
            return Err(IoError::Truncated {
                path: h.file.clone(),
                expected: want as u64,
                actual: self.buf.len() as u64,
            });
        }
        let (bits, stored, signed) = (h.bits_allocated, h.bits_stored, h.signed);
        if bits == 16 && stored > 0 && stored < 16 {
            let shift = 16 - stored;
            for c in self.buf.chunks_exact_mut(2) {
                let v = u16::from_le_bytes([c[0], c[1]]);
                let v = if signed {
                    (((v << shift) as i16) >> shift) as u16
                } else {
                    v & ((1u16 << stored) - 1)
                };
                c.copy_from_slice(&v.to_le_bytes());
            }
        }
        Ok(())
    }
}

impl VolumeReader for DicomReader {
    fn desc(&self) -> &VolumeDesc {
        &self.desc
    }

    fn format(&self) -> &'static str {
        "DICOM"
    }

    fn path(&self) -> &Path {
        &self.path
    }

    fn input_files(&self) -> Vec<PathBuf> {
        self.slices.iter().map(|h| h.file.clone()).collect()
    }

    fn placement(&self) -> Option<Placement> {
        Some(self.placement)
    }

    fn notes(&self) -> Vec<String> {
        self.notes.clone()
    }

    fn warnings(&self) -> Vec<String> {
        self.warnings.clone()
    }

    fn read_slices(&mut self, z0: u32, z1: u32, out: &mut [u8]) -> Result<(), IoError> {
        let slice = check_slab(&self.desc, z0, z1, out)? as usize;
        for z in z0..z1 {
            self.decode(z as usize)?;
            let o = (z - z0) as usize * slice;
            self.convs[z as usize].convert(&self.buf, &mut out[o..o + slice]);
        }
        Ok(())
    }
}

#[derive(Debug)]
struct DicomFormat;

impl Format for DicomFormat {
    fn name(&self) -> &'static str {
        "DICOM"
    }
    fn expects(&self) -> &'static str {
        "a folder of .dcm files (searched recursively), or one of them"
    }
    fn claims(&self, probe: &Probe) -> Claim {
        if probe.is_dir() {
            // any folder that no other format claims (TIFF slices, OME-Zarr)
            return Claim::Fallback;
        }
        if probe.ext == "dcm" || probe.ext == "dicom" {
            return Claim::ByName;
        }
        if probe.head.len() >= 132 && &probe.head[128..132] == b"DICM" {
            return Claim::ByContent;
        }
        Claim::No
    }
    fn open(&self, path: &Path, opts: &ReadOptions) -> Result<Box<dyn VolumeReader>, IoError> {
        Ok(Box::new(DicomReader::open(path, opts)?))
    }
    fn list(&self, path: &Path, opts: &ReadOptions) -> Result<Vec<Entry>, IoError> {
        let (_, series, only) = scan_series(path)?;
        let wanted = opts.series.as_deref().or(only.as_deref());
        let (index, _) = pick(path, &series, wanted)?;
        Ok(series
            .iter()
            .enumerate()
            .map(|(i, s)| Entry {
                kind: EntryKind::Series,
                id: s.uid.clone(),
                summary: format!("#{i}: {} files", s.slices.len()),
                default: i == index,
            })
            .collect())
    }
}

pub(crate) fn register(r: &mut Registry) {
    r.register(std::sync::Arc::new(DicomFormat));
}
