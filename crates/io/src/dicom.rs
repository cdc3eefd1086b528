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

/// The header fields of one image file.
#[derive(Debug, Clone)]
struct SliceHeader {
    file: PathBuf,
    series: String,
    description: String,
    modality: String,
    rows: u32,
    cols: u32,
    bits_allocated: u16,
    bits_stored: u16,
    signed: bool,
    samples: u16,
    frames: u32,
    position: [f64; 3],
    orientation: [f64; 6],
    pixel_spacing: [f64; 2],
    slope: f64,
    inter: f64,
    ts: String,
}

fn dec_err(path: &Path, e: impl std::fmt::Display) -> IoError {
    IoError::decode(path, "DICOM", e)
}

fn get_str(obj: &DefaultDicomObject, tag: Tag) -> Option<String> {
    obj.element_opt(tag)
        .ok()
        .flatten()
        .and_then(|e| e.to_str().ok())
        .map(|s| s.trim().trim_end_matches('\0').to_owned())
}

fn get_f64s(obj: &DefaultDicomObject, tag: Tag) -> Option<Vec<f64>> {
    obj.element_opt(tag)
        .ok()
        .flatten()
        .and_then(|e| e.to_multi_float64().ok())
}

fn get_u32(obj: &DefaultDicomObject, tag: Tag) -> Option<u32> {
    obj.element_opt(tag)
        .ok()
        .flatten()
        .and_then(|e| e.to_int::<u32>().ok())
}

/// Checks that no element length in a DICOM file (up to and including the
/// pixel data's) runs past the end of the file, walking the element headers
/// (meta group explicit VR little endian; the data set implicit or explicit
/// VR little endian; sequences and items are descended into). A forged
/// length would otherwise make the parser allocate and zero up to 4 GiB.
/// Files with the DICM magic only; other files are left to the parser.
fn check_lengths(file: &Path, b: &[u8]) -> Result<Option<u32>, IoError> {
    if b.len() < 132 || &b[128..132] != b"DICM" {
        return Ok(None);
    }
    let implicit_ds = meta_transfer_syntax(b).as_deref() == Some("1.2.840.10008.1.2");
    if meta_transfer_syntax(b).is_some_and(|u| u.starts_with("1.2.840.10008.1.2.1.99")) {
        return Ok(None); // deflated: the data set is not walkable here
    }
    let bad = |at: usize, len: u64| IoError::Truncated {
        path: file.to_owned(),
        expected: at as u64 + len,
        actual: b.len() as u64,
    };
    let mut i = 132;
    while i + 8 <= b.len() {
        let group = u16::from_le_bytes([b[i], b[i + 1]]);
        let elem = u16::from_le_bytes([b[i + 2], b[i + 3]]);
        let explicit = group == 0x0002 || !implicit_ds;
        let (len, head) = if group == 0xFFFE {
            // item and delimiters: always a 4-byte length
            (
                u32::from_le_bytes([b[i + 4], b[i + 5], b[i + 6], b[i + 7]]),
                8,
            )
        } else if explicit {
            let vr = [b[i + 4], b[i + 5]];
            const VRS: [&[u8; 2]; 34] = [
                b"AE", b"AS", b"AT", b"CS", b"DA", b"DS", b"DT", b"FL", b"FD", b"IS", b"LO", b"LT",
                b"OB", b"OD", b"OF", b"OL", b"OV", b"OW", b"PN", b"SH", b"SL", b"SQ", b"SS", b"ST",
                b"SV", b"TM", b"UC", b"UI", b"UL", b"UN", b"UR", b"US", b"UT", b"UV",
            ];
            if !VRS.contains(&&vr) {
                return Err(IoError::header(
                    file,
                    format!(
                        "unknown value representation {:?} at byte {i}",
                        String::from_utf8_lossy(&vr)
                    ),
                ));
            }
            let long = matches!(
                &vr,
                b"OB"
                    | b"OW"
                    | b"OF"
                    | b"SQ"
                    | b"UT"
                    | b"UN"
                    | b"OD"
                    | b"OL"
                    | b"OV"
                    | b"SV"
                    | b"UV"
                    | b"UC"
                    | b"UR"
            );
            if long {
                if i + 12 > b.len() {
                    return Err(bad(i, 12));
                }
                (
                    u32::from_le_bytes([b[i + 8], b[i + 9], b[i + 10], b[i + 11]]),
                    12,
                )
            } else {
                (u16::from_le_bytes([b[i + 6], b[i + 7]]) as u32, 8)
            }
        } else {
            (
                u32::from_le_bytes([b[i + 4], b[i + 5], b[i + 6], b[i + 7]]),
                8,
            )
        };
        let body = i + head;
        let is_sq = explicit && group != 0xFFFE && &b[i + 4..i + 6] == b"SQ";
        if len == u32::MAX || is_sq || (group == 0xFFFE && elem == 0xE000) {
            // undefined length, a sequence or an item: walk into it (its
            // content is elements or items whose lengths are checked in turn)
            if len != u32::MAX && body as u64 + len as u64 > b.len() as u64 {
                return Err(bad(body, len as u64));
            }
            i = body;
            continue;
        }
        if body as u64 + len as u64 > b.len() as u64 {
            return Err(bad(body, len as u64));
        }
        if group == 0x7FE0 && elem == 0x0010 {
            return Ok(Some(len));
        }
        i = body + len as usize;
    }
    Ok(None)
}

/// Reads one file's header (up to the pixel data). `Ok(None)`: not a DICOM
/// image (no pixel geometry): skipped.
fn read_header(file: &Path) -> Result<Option<SliceHeader>, IoError> {
    let md = crate::regular_file_metadata(file)?;
    if md.len() < 132 {
        return Ok(None);
    }
    // Only DICOM Part 10 files (preamble, "DICM", meta group) are read: their
    // transfer syntax is checked, then every element length, before the
    // parser sees them.
    let bytes = std::fs::read(file).map_err(|e| IoError::io(file, e))?;
    if &bytes[128..132] != b"DICM" {
        return Ok(None);
    }
    let Some(ts) = meta_transfer_syntax(&bytes) else {
        return Err(IoError::header(
            file,
            "no TransferSyntaxUID in the file meta group",
        ));
    };
    check_syntax(file, &ts)?;
    check_lengths(file, &bytes)?;
    drop(bytes);
    let obj = match OpenFileOptions::new()
        .read_until(tags::PIXEL_DATA)
        .open_file(file)
    {
        Ok(o) => o,
        Err(e) => {
            // A DICOM file (it has the magic) that dicom-object cannot parse:
            // an unknown transfer syntax is named, anything else reported.
            let head = std::fs::read(file).map_err(|e| IoError::io(file, e))?;
            if head.len() < 132 || &head[128..132] != b"DICM" {
                return Ok(None);
            }
            if let Some(uid) = meta_transfer_syntax(&head) {
                check_syntax(file, &uid)?;
            }
            return Err(dec_err(file, e));
        }
    };
    let (Some(rows), Some(cols)) = (get_u32(&obj, tags::ROWS), get_u32(&obj, tags::COLUMNS)) else {
        return Ok(None);
    };
    let bad = |msg: &str| IoError::header(file, msg.to_owned());
    let position = get_f64s(&obj, tags::IMAGE_POSITION_PATIENT)
        .filter(|v| v.len() == 3 && v.iter().all(|x| x.is_finite()))
        .ok_or_else(|| bad("no usable ImagePositionPatient (3 numbers)"))?;
    let orientation = get_f64s(&obj, tags::IMAGE_ORIENTATION_PATIENT)
        .filter(|v| v.len() == 6 && v.iter().all(|x| x.is_finite()))
        .ok_or_else(|| bad("no usable ImageOrientationPatient (6 numbers)"))?;
    let pixel_spacing = get_f64s(&obj, tags::PIXEL_SPACING)
        .filter(|v| v.len() == 2 && v.iter().all(|x| x.is_finite() && *x > 0.0))
        .unwrap_or_else(|| vec![1.0, 1.0]);
    let bits_allocated = get_u32(&obj, tags::BITS_ALLOCATED).unwrap_or(16) as u16;
    Ok(Some(SliceHeader {
        file: file.to_owned(),
        series: get_str(&obj, tags::SERIES_INSTANCE_UID).unwrap_or_default(),
        description: get_str(&obj, tags::SERIES_DESCRIPTION).unwrap_or_default(),
        modality: get_str(&obj, tags::MODALITY).unwrap_or_default(),
        rows,
        cols,
        bits_allocated,
        bits_stored: get_u32(&obj, tags::BITS_STORED).unwrap_or(bits_allocated as u32) as u16,
        signed: get_u32(&obj, tags::PIXEL_REPRESENTATION).unwrap_or(0) == 1,
        samples: get_u32(&obj, tags::SAMPLES_PER_PIXEL).unwrap_or(1) as u16,
        frames: get_str(&obj, tags::NUMBER_OF_FRAMES)
            .and_then(|s| s.parse().ok())
            .unwrap_or(1),
        position: [position[0], position[1], position[2]],
        orientation: [
            orientation[0],
            orientation[1],
            orientation[2],
            orientation[3],
            orientation[4],
            orientation[5],
        ],
        pixel_spacing: [pixel_spacing[0], pixel_spacing[1]],
        slope: get_f64s(&obj, tags::RESCALE_SLOPE)
            .and_then(|v| v.first().copied())
            .filter(|s| s.is_finite() && *s != 0.0)
            .unwrap_or(1.0),
        inter: get_f64s(&obj, tags::RESCALE_INTERCEPT)
            .and_then(|v| v.first().copied())
            .filter(|s| s.is_finite())
            .unwrap_or(0.0),
        ts: obj
            .meta()
            .transfer_syntax()
            .trim_end_matches('\0')
            .to_owned(),
    }))
}

/// The TransferSyntaxUID (0002,0010) of a file's meta group, found by its
/// explicit VR little endian encoding.
fn meta_transfer_syntax(bytes: &[u8]) -> Option<String> {
    let end = bytes.len().min(4096);
    let i = bytes[..end]
        .windows(6)
        .position(|w| w == b"\x02\x00\x10\x00UI")?;
    let len = u16::from_le_bytes([*bytes.get(i + 6)?, *bytes.get(i + 7)?]) as usize;
    let v = bytes.get(i + 8..i + 8 + len)?;
    Some(
        String::from_utf8_lossy(v)
            .trim_end_matches(['\0', ' '])
            .to_owned(),
    )
}

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
        let mut slices = s.slices.clone();
        let first = slices[0].clone();
        for h in &slices {
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
        let (dx, dy) = (first.pixel_spacing[1], first.pixel_spacing[0]);
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
            },
            placement: Placement {
                affine,
                space: "LPS",
            },
            notes,
            entries,
            buf: Vec::new(),
        };
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for z in 0..n {
            r.decode(z)?;
            if let Some([a, b]) = r.convs[z].range(&r.buf) {
                lo = lo.min(a);
                hi = hi.max(b);
            }
        }
        if lo > hi {
            lo = 0.0;
            hi = 0.0;
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
        r.desc.value_range = desc_range([lo, hi]);
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
        let bytes = std::fs::read(&h.file).map_err(|e| IoError::io(&h.file, e))?;
        let pixel_len = check_lengths(&h.file, &bytes)?;
        drop(bytes);
        let want = h.rows as u64 * h.cols as u64 * (h.bits_allocated as u64).div_ceil(8);
        // native (unencapsulated) pixel data must hold the whole image before
        // a decoder allocates for it; no slice is larger than 2^28 pixels
        if h.rows as u64 * h.cols as u64 > 1 << 28 {
            return Err(IoError::header(
                &h.file,
                format!("{}x{} pixels per slice", h.cols, h.rows),
            ));
        }
        if let Some(len) = pixel_len.filter(|&l| l != u32::MAX)
            && (len as u64) < want
        {
            return Err(IoError::Truncated {
                path: h.file.clone(),
                expected: want,
                actual: len as u64,
            });
        }
        let obj = dicom_object::open_file(&h.file).map_err(|e| dec_err(&h.file, e))?;
        let ts = obj.meta().transfer_syntax().trim_end_matches('\0');
        check_syntax(&h.file, ts)?;
        let px = obj.decode_pixel_data().map_err(|e| dec_err(&h.file, e))?;
        let data = px.frame_data(0).map_err(|e| dec_err(&h.file, e))?;
        let want = want as usize;
        if data.len() != want {
            return Err(IoError::Truncated {
                path: h.file.clone(),
                expected: want as u64,
                actual: data.len() as u64,
            });
        }
        self.buf.clear();
        self.buf.extend_from_slice(data);
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

/// Refuses a transfer syntax that cannot be decoded here, naming the file.
fn check_syntax(file: &Path, uid: &str) -> Result<(), IoError> {
    let refuse = |name: &str| IoError::UnsupportedTransferSyntax {
        path: file.to_owned(),
        uid: uid.to_owned(),
        name: name.to_owned(),
    };
    // Explicit VR big endian (retired): pixel bytes would need swapping by VR.
    if uid == "1.2.840.10008.1.2.2" {
        return Err(refuse("Explicit VR Big Endian (retired)"));
    }
    match TransferSyntaxRegistry.get(uid) {
        None => Err(refuse("unknown")),
        Some(ts) if !ts.can_decode_all() => Err(refuse(ts.name())),
        Some(_) => Ok(()),
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
