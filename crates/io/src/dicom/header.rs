//! One DICOM file: its header fields, read and length-checked before
//! dicom-object parses it, and its transfer syntax checked against the
//! decoders this build has.

use super::*;
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
    pub(super) pixel_spacing: [f64; 2],
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

/// Checks that no element length in a DICOM file (up to and including the
/// pixel data's) runs past the end of the file, walking the element headers
/// (meta group explicit VR little endian; the data set implicit or explicit
/// VR little endian; sequences and items are descended into). A forged
/// length would otherwise make the parser allocate and zero up to 4 GiB.
/// Files with the DICM magic only; other files are left to the parser.
pub(super) fn check_lengths(file: &Path, b: &[u8]) -> Result<Option<u32>, IoError> {
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
pub(super) fn read_header(file: &Path) -> Result<Option<SliceHeader>, IoError> {
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
