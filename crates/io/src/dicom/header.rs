//! One DICOM file: its header fields, read and length-checked before
//! dicom-object parses it, and its transfer syntax checked against the
//! decoders this build has.

use super::*;
use dicom_object::file::ReadPreamble;
use std::io::Read;
use std::ops::Range;
/// The header fields of one image file.
#[derive(Debug, Clone)]
pub(super) struct SliceHeader {
    pub(super) file: PathBuf,
    pub(super) series: String,
    pub(super) description: String,
    pub(super) modality: String,
    pub(super) rows: u32,
    pub(super) cols: u32,
    pub(super) bits_allocated: u16,
    pub(super) bits_stored: u16,
    pub(super) signed: bool,
    pub(super) samples: u16,
    pub(super) frames: u32,
    pub(super) position: [f64; 3],
    pub(super) orientation: [f64; 6],
    /// `None`: the file states no PixelSpacing (read as 1 mm, with a warning).
    pub(super) pixel_spacing: Option<[f64; 2]>,
    pub(super) slope: f64,
    pub(super) inter: f64,
    pub(super) ts: String,
}

pub(super) fn dec_err(path: &Path, e: impl std::fmt::Display) -> IoError {
    IoError::decode(path, "DICOM", e)
}

pub(super) fn get_str(obj: &DefaultDicomObject, tag: Tag) -> Option<String> {
    obj.element_opt(tag)
        .ok()
        .flatten()
        .and_then(|e| e.to_str().ok())
        .map(|s| s.trim().trim_end_matches('\0').to_owned())
}

pub(super) fn get_f64s(obj: &DefaultDicomObject, tag: Tag) -> Option<Vec<f64>> {
    obj.element_opt(tag)
        .ok()
        .flatten()
        .and_then(|e| e.to_multi_float64().ok())
}

pub(super) fn get_u32(obj: &DefaultDicomObject, tag: Tag) -> Option<u32> {
    obj.element_opt(tag)
        .ok()
        .flatten()
        .and_then(|e| e.to_int::<u32>().ok())
}

/// The numbers of a decimal-string element: `Ok(None)` when it is absent or
/// empty; an error naming the element when it is present but holds anything
/// other than `n` finite numbers (`n = 0`: any count but none).
pub(super) fn get_numbers(
    file: &Path,
    obj: &DefaultDicomObject,
    tag: Tag,
    name: &str,
    n: usize,
) -> Result<Option<Vec<f64>>, IoError> {
    let Some(e) = obj.element_opt(tag).ok().flatten() else {
        return Ok(None);
    };
    let text = e.to_str().map(|s| s.trim().to_owned()).unwrap_or_default();
    if text.trim_matches(['\\', '\0', ' ']).is_empty() {
        return Ok(None);
    }
    match e.to_multi_float64() {
        Ok(v) if (n == 0 || v.len() == n) && !v.is_empty() && v.iter().all(|x| x.is_finite()) => {
            Ok(Some(v))
        }
        _ => Err(IoError::header(
            file,
            format!(
                "{name} is {text:?}, not {} finite number(s)",
                if n == 0 {
                    "some".to_owned()
                } else {
                    n.to_string()
                }
            ),
        )),
    }
}

/// Where a file's pixel data lies, as the element walk found it.
#[derive(Debug, Clone, PartialEq)]
pub(super) enum Pixels {
    /// Native pixel data: the element's length.
    Native(u32),
    /// Encapsulated pixel data (undefined length, a compressed transfer
    /// syntax): the byte ranges of its fragments, after the basic offset table.
    Encapsulated(Vec<Range<usize>>),
}

/// Checks that no element length in a DICOM file (up to and including the
/// pixel data's) runs past the end of the file, walking the element headers
/// (meta group explicit VR little endian; the data set implicit or explicit
/// VR little endian; sequences and items are descended into). A forged
/// length would otherwise make the parser allocate and zero up to 4 GiB.
/// Encapsulated pixel data (undefined length) is walked as what it is: a
/// basic offset table and fragments, each an item whose length is checked,
/// ended by a sequence delimiter. Files with the DICM magic only; other
/// files are left to the parser.
pub(super) fn check_lengths(file: &Path, b: &[u8]) -> Result<Option<Pixels>, IoError> {
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
        if group == 0x7FE0 && elem == 0x0010 && len == u32::MAX {
            return fragments(file, b, body).map(|f| Some(Pixels::Encapsulated(f)));
        }
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
            return Ok(Some(Pixels::Native(len)));
        }
        i = body + len as usize;
    }
    Ok(None)
}

/// The items of encapsulated pixel data starting at byte `i`: the basic
/// offset table (dropped) and the fragments, up to the sequence delimiter.
fn fragments(file: &Path, b: &[u8], mut i: usize) -> Result<Vec<Range<usize>>, IoError> {
    let mut items = Vec::new();
    loop {
        let Some(h) = b.get(i..i + 8) else {
            return Err(IoError::Truncated {
                path: file.to_owned(),
                expected: i as u64 + 8,
                actual: b.len() as u64,
            });
        };
        let group = u16::from_le_bytes([h[0], h[1]]);
        let elem = u16::from_le_bytes([h[2], h[3]]);
        let len = u32::from_le_bytes([h[4], h[5], h[6], h[7]]);
        match (group, elem) {
            (0xFFFE, 0xE000) if len != u32::MAX => {
                let end = (i + 8) as u64 + len as u64;
                if end > b.len() as u64 {
                    return Err(IoError::Truncated {
                        path: file.to_owned(),
                        expected: end,
                        actual: b.len() as u64,
                    });
                }
                items.push(i + 8..end as usize);
                i = end as usize;
            }
            (0xFFFE, 0xE0DD) => break,
            _ => {
                return Err(IoError::header(
                    file,
                    format!(
                        "encapsulated pixel data: ({group:04X},{elem:04X}) of length {len} \
                         at byte {i} where an item or the sequence delimiter belongs"
                    ),
                ));
            }
        }
    }
    if items.len() < 2 {
        return Err(IoError::header(
            file,
            "encapsulated pixel data without a fragment (only the offset table)",
        ));
    }
    items.remove(0);
    Ok(items)
}

/// Largest DICOM file read whole: one slice of at most 2^28 pixels of 4
/// bytes, with room for its header.
const MAX_FILE: u64 = (1 << 30) + (64 << 20);

/// The bytes of a DICOM Part 10 file (128-byte preamble and `DICM`), read
/// whole; `Ok(None)` when the file is not one (only its first 132 bytes are
/// read then). Regular files only: a FIFO is refused before it is opened.
pub(super) fn read_part10(file: &Path) -> Result<Option<Vec<u8>>, IoError> {
    let mut f = crate::open_regular(file)?;
    let len = f.metadata().map_err(|e| IoError::io(file, e))?.len();
    if len < 132 {
        return Ok(None);
    }
    let mut bytes = vec![0u8; 132];
    if let Err(e) = f.read_exact(&mut bytes) {
        return match e.kind() {
            std::io::ErrorKind::UnexpectedEof => Ok(None),
            _ => Err(IoError::io(file, e)),
        };
    }
    if &bytes[128..132] != b"DICM" {
        return Ok(None);
    }
    if len > MAX_FILE {
        return Err(IoError::unsupported(
            file,
            format!("a DICOM file of {len} bytes (one slice is at most {MAX_FILE})"),
        ));
    }
    f.take(MAX_FILE - 132)
        .read_to_end(&mut bytes)
        .map_err(|e| IoError::io(file, e))?;
    Ok(Some(bytes))
}

/// Parses the data set of a Part 10 file held in memory (its lengths
/// checked first by [`check_lengths`]), up to `until` if given.
pub(super) fn parse(
    file: &Path,
    bytes: &[u8],
    until: Option<Tag>,
) -> Result<DefaultDicomObject, IoError> {
    let mut o = OpenFileOptions::new().read_preamble(ReadPreamble::Always);
    if let Some(t) = until {
        o = o.read_until(t);
    }
    o.from_reader(bytes).map_err(|e| {
        // an unknown transfer syntax is named, anything else reported
        match meta_transfer_syntax(bytes).map(|uid| check_syntax(file, &uid)) {
            Some(Err(named)) => named,
            _ => dec_err(file, e),
        }
    })
}

/// Reads one file's header (up to the pixel data). `Ok(None)`: not a DICOM
/// image (no pixel geometry): skipped.
pub(super) fn read_header(file: &Path) -> Result<Option<SliceHeader>, IoError> {
    // Only DICOM Part 10 files (preamble, "DICM", meta group) are read: their
    // transfer syntax is checked, then every element length, before the
    // parser sees them.
    let Some(bytes) = read_part10(file)? else {
        return Ok(None);
    };
    let Some(ts) = meta_transfer_syntax(&bytes) else {
        return Err(IoError::header(
            file,
            "no TransferSyntaxUID in the file meta group",
        ));
    };
    check_syntax(file, &ts)?;
    check_lengths(file, &bytes)?;
    let obj = parse(file, &bytes, Some(tags::PIXEL_DATA))?;
    drop(bytes);
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
    // Absent: 1 mm with a warning (the customary fallback); present but not
    // two positive finite numbers: an error, never a silent 1.
    let pixel_spacing = match get_numbers(file, &obj, tags::PIXEL_SPACING, "PixelSpacing", 2)? {
        None => None,
        Some(v) if v.iter().all(|x| *x > 0.0) => Some([v[0], v[1]]),
        Some(v) => {
            return Err(IoError::header(
                file,
                format!("PixelSpacing is {v:?}, not two positive numbers"),
            ));
        }
    };
    let slope = match get_numbers(file, &obj, tags::RESCALE_SLOPE, "RescaleSlope", 0)? {
        None => 1.0,
        Some(v) if v[0] != 0.0 => v[0],
        Some(_) => {
            return Err(bad(
                "RescaleSlope is 0: every sample would be the intercept",
            ));
        }
    };
    let inter = get_numbers(file, &obj, tags::RESCALE_INTERCEPT, "RescaleIntercept", 0)?
        .map_or(0.0, |v| v[0]);
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
        pixel_spacing,
        slope,
        inter,
        ts: obj
            .meta()
            .transfer_syntax()
            .trim_end_matches('\0')
            .to_owned(),
    }))
}

/// Checks the first bytes of a frame's compressed stream before a decoder
/// sees it: the image size and sample count it declares must be the
/// header's (a decoder allocates for the size its stream declares: a forged
/// JPEG or JPEG 2000 header could otherwise make it allocate gigabytes), and
/// an RLE header's segment table must fit the frame.
pub(super) fn check_frame(h: &SliceHeader, frame: &[u8]) -> Result<(), IoError> {
    let file = &h.file;
    let bad = |msg: String| IoError::header(file, msg);
    let bytes_per_sample = (h.bits_allocated as usize).div_ceil(8);
    match h.ts.as_str() {
        // RLE Lossless: a 64-byte header of 16 little-endian u32: the number
        // of segments (one per byte of each sample) and their offsets.
        "1.2.840.10008.1.2.5" => {
            let n_expected = h.samples as usize * bytes_per_sample;
            let Some(head) = frame.get(..64) else {
                return Err(bad(format!(
                    "RLE frame of {} bytes has no 64-byte header",
                    frame.len()
                )));
            };
            let word = |k: usize| {
                u32::from_le_bytes([
                    head[4 * k],
                    head[4 * k + 1],
                    head[4 * k + 2],
                    head[4 * k + 3],
                ]) as usize
            };
            let n = word(0);
            if n != n_expected {
                return Err(bad(format!(
                    "RLE header declares {n} segments, {n_expected} expected"
                )));
            }
            let mut prev = 63;
            for k in 1..=n {
                let off = word(k);
                if off <= prev || off >= frame.len() {
                    return Err(bad(format!(
                        "RLE segment {k} starts at byte {off} of a {}-byte frame",
                        frame.len()
                    )));
                }
                prev = off;
            }
            Ok(())
        }
        // JPEG (baseline, extended, lossless): the SOF marker.
        "1.2.840.10008.1.2.4.50"
        | "1.2.840.10008.1.2.4.51"
        | "1.2.840.10008.1.2.4.57"
        | "1.2.840.10008.1.2.4.70" => {
            let (x, y, nf) = jpeg_sof(frame).map_err(|m| bad(format!("JPEG stream: {m}")))?;
            if (x, y, nf) != (h.cols, h.rows, h.samples as u32) {
                return Err(bad(format!(
                    "the JPEG stream is {x}x{y} with {nf} components, the header says {}x{} with {}",
                    h.cols, h.rows, h.samples
                )));
            }
            Ok(())
        }
        // JPEG 2000 (and High-Throughput JPEG 2000): the SIZ marker.
        "1.2.840.10008.1.2.4.90"
        | "1.2.840.10008.1.2.4.91"
        | "1.2.840.10008.1.2.4.201"
        | "1.2.840.10008.1.2.4.202"
        | "1.2.840.10008.1.2.4.203" => {
            let (x, y, c) = j2k_siz(frame).map_err(|m| bad(format!("JPEG 2000 stream: {m}")))?;
            if (x, y, c) != (h.cols, h.rows, h.samples as u32) {
                return Err(bad(format!(
                    "the JPEG 2000 stream is {x}x{y} with {c} components, the header says {}x{} with {}",
                    h.cols, h.rows, h.samples
                )));
            }
            Ok(())
        }
        _ => Ok(()),
    }
}

/// Decodes one RLE Lossless frame (DICOM PS3.5 Annex G) of a single-sample
/// image into little-endian samples: one PackBits segment per byte of the
/// sample, most significant first, each of exactly rows x columns bytes.
/// Read here rather than by dicom-pixeldata, whose RLE decoder indexes past
/// a segment that decodes short (a panic the mutation suite found). The
/// header was checked by [`check_frame`].
pub(super) fn decode_rle(h: &SliceHeader, frame: &[u8], out: &mut Vec<u8>) -> Result<(), IoError> {
    let bps = (h.bits_allocated as usize).div_ceil(8);
    let n = h.rows as usize * h.cols as usize;
    let bad = |msg: String| IoError::decode(&h.file, "DICOM RLE", msg);
    if h.samples != 1 || !(1..=4).contains(&bps) {
        return Err(bad(format!(
            "{} samples of {} bits",
            h.samples, h.bits_allocated
        )));
    }
    let offset = |k: usize| -> usize {
        u32::from_le_bytes([
            frame[4 * k],
            frame[4 * k + 1],
            frame[4 * k + 2],
            frame[4 * k + 3],
        ]) as usize
    };
    out.clear();
    out.resize(n * bps, 0);
    let mut seg = Vec::with_capacity(n);
    for k in 0..bps {
        let start = offset(k + 1);
        let end = if k + 1 < bps {
            offset(k + 2)
        } else {
            frame.len()
        };
        let src = frame
            .get(start..end)
            .ok_or_else(|| bad(format!("segment {k} at bytes {start}..{end}")))?;
        seg.clear();
        let mut i = 0;
        while seg.len() < n && i < src.len() {
            let c = src[i] as i8;
            i += 1;
            if c >= 0 {
                let m = c as usize + 1;
                let lit = src
                    .get(i..i + m)
                    .ok_or_else(|| bad(format!("segment {k}: a literal run past its end")))?;
                seg.extend_from_slice(lit);
                i += m;
            } else if c != -128 {
                let &v = src
                    .get(i)
                    .ok_or_else(|| bad(format!("segment {k}: a replicate run past its end")))?;
                seg.extend(std::iter::repeat_n(v, (1 - c as isize) as usize));
                i += 1;
            }
        }
        if seg.len() < n {
            return Err(bad(format!(
                "segment {k} decodes to {} bytes, the image has {n} pixels",
                seg.len()
            )));
        }
        // segment 0 holds the most significant bytes
        let byte = bps - 1 - k;
        for (p, &v) in seg[..n].iter().enumerate() {
            out[p * bps + byte] = v;
        }
    }
    Ok(())
}

/// Width, height and component count of a JPEG stream's frame header.
fn jpeg_sof(b: &[u8]) -> Result<(u32, u32, u32), String> {
    if !b.starts_with(&[0xFF, 0xD8]) {
        return Err("no start-of-image marker".into());
    }
    let mut i = 2;
    loop {
        // markers may be preceded by fill bytes 0xFF
        while b.get(i) == Some(&0xFF) && b.get(i + 1) == Some(&0xFF) {
            i += 1;
        }
        let (Some(&0xFF), Some(&m)) = (b.get(i), b.get(i + 1)) else {
            return Err(format!("no marker at byte {i}"));
        };
        i += 2;
        match m {
            0x01 | 0xD0..=0xD7 => continue,
            0xD9 | 0xDA => return Err("no frame header before the scan".into()),
            _ => {}
        }
        let Some(l) = b.get(i..i + 2) else {
            return Err("truncated marker segment".into());
        };
        let len = u16::from_be_bytes([l[0], l[1]]) as usize;
        if len < 2 || i + len > b.len() {
            return Err(format!("marker segment of length {len} at byte {i}"));
        }
        let is_sof = matches!(m, 0xC0..=0xCF) && !matches!(m, 0xC4 | 0xC8 | 0xCC);
        if is_sof {
            let s = &b[i + 2..i + len];
            if s.len() < 6 {
                return Err("short frame header".into());
            }
            let y = u16::from_be_bytes([s[1], s[2]]) as u32;
            let x = u16::from_be_bytes([s[3], s[4]]) as u32;
            let nf = s[5] as u32;
            if s.len() < 6 + 3 * nf as usize {
                return Err("short frame header".into());
            }
            return Ok((x, y, nf));
        }
        i += len;
    }
}

/// Width, height and component count of a JPEG 2000 codestream's SIZ
/// marker (a raw codestream, or one inside JP2 boxes); also refuses tilings
/// and subsamplings a decoder would choke on.
fn j2k_siz(b: &[u8]) -> Result<(u32, u32, u32), String> {
    let at = b
        .windows(4)
        .take(4096)
        .position(|w| w == [0xFF, 0x4F, 0xFF, 0x51])
        .ok_or("no codestream header (SOC, SIZ)")?;
    let s = &b[at + 4..];
    let u32_at = |k: usize| -> Result<u64, String> {
        s.get(k..k + 4)
            .map(|v| u32::from_be_bytes([v[0], v[1], v[2], v[3]]) as u64)
            .ok_or_else(|| "truncated SIZ marker".to_owned())
    };
    let u16_at = |k: usize| -> Result<u64, String> {
        s.get(k..k + 2)
            .map(|v| u16::from_be_bytes([v[0], v[1]]) as u64)
            .ok_or_else(|| "truncated SIZ marker".to_owned())
    };
    // Lsiz, Rsiz, Xsiz, Ysiz, XOsiz, YOsiz, XTsiz, YTsiz, XTOsiz, YTOsiz, Csiz
    let (xs, ys, xo, yo) = (u32_at(4)?, u32_at(8)?, u32_at(12)?, u32_at(16)?);
    let (xt, yt, xto, yto) = (u32_at(20)?, u32_at(24)?, u32_at(28)?, u32_at(32)?);
    let c = u16_at(36)?;
    if xs <= xo || ys <= yo {
        return Err(format!("image area {xs}x{ys} at offset {xo}, {yo}"));
    }
    if xt == 0 || yt == 0 || xto > xo || yto > yo || xto + xt <= xo || yto + yt <= yo {
        return Err(format!("tiles of {xt}x{yt} at {xto}, {yto}"));
    }
    let tiles = (xs - xto).div_ceil(xt) * (ys - yto).div_ceil(yt);
    if tiles > 1 << 16 {
        return Err(format!("{tiles} tiles"));
    }
    if c == 0 || c > 4 {
        return Err(format!("{c} components"));
    }
    for k in 0..c as usize {
        let p = 38 + 3 * k;
        let prec = s.get(p).ok_or("truncated SIZ marker")? & 0x7F;
        let (dx, dy) = (s.get(p + 1), s.get(p + 2));
        if prec >= 32 || dx != Some(&1) || dy != Some(&1) {
            return Err(format!(
                "component {k}: {} bits, subsampling {dx:?} x {dy:?}",
                prec as u32 + 1
            ));
        }
    }
    Ok(((xs - xo) as u32, (ys - yo) as u32, c as u32))
}

/// The TransferSyntaxUID (0002,0010) of a file's meta group, found by its
/// explicit VR little endian encoding.
pub(super) fn meta_transfer_syntax(bytes: &[u8]) -> Option<String> {
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

/// Refuses a transfer syntax that cannot be decoded here, naming the file.
pub(super) fn check_syntax(file: &Path, uid: &str) -> Result<(), IoError> {
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
