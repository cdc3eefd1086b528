//! DICOM: the shared CT series decodes voxel for voxel to its raw volume (HU,
//! i16, spacing from positions); a folder with two series and shuffled names;
//! a missing slice, mixed sizes and an unknown transfer syntax are typed
//! errors naming the file.
#![cfg(feature = "dicom")]

mod formats_common;

use brickray_core::DType;
use brickray_io::{self as io, EntryKind, IoError, ReadOptions};
use dicom_core::{DataElement, PrimitiveValue, VR};
use dicom_dictionary_std::tags;
use formats_common::*;
use std::path::{Path, PathBuf};
use tempfile::TempDir;

fn fixture() -> Option<PathBuf> {
    formats_dir().map(|d| d.join("dicom/cranium_ct"))
}

fn files(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    v.sort();
    v
}

/// The fixture's files in position order (z of ImagePositionPatient: the
/// series is axial).
fn by_position(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<(f64, PathBuf)> = files(dir)
        .into_iter()
        .map(|f| {
            let o = dicom_object::open_file(&f).unwrap();
            let p = o.element(tags::IMAGE_POSITION_PATIENT).unwrap();
            (p.to_multi_float64().unwrap()[2], f)
        })
        .collect();
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    v.into_iter().map(|(_, f)| f).collect()
}

/// Copies `src` to `dst`, setting `tag` to `value` (a string element).
fn copy_with(src: &Path, dst: &Path, edits: &[(dicom_core::Tag, VR, PrimitiveValue)]) {
    let mut obj = dicom_object::open_file(src).unwrap();
    for (tag, vr, v) in edits {
        obj.put(DataElement::new(*tag, *vr, v.clone()));
    }
    obj.write_to_file(dst).unwrap();
}

#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn ct_series_fixture_decodes_in_hounsfield_units() {
    let Some(dir) = fixture() else { return };
    let t = truth("invesalius_cranium_ct");
    let mut r = io::open(&dir).unwrap();
    assert_eq!(r.format(), "DICOM");
    assert_eq!(r.desc().dims, t.desc.dims);
    assert_eq!(r.desc().dtype, DType::I16);
    assert_spacing(r.desc().spacing, t.desc.spacing, "dicom");
    assert_eq!(r.input_files().len(), 108);
    assert_same_voxels(&read_by_slabs(r.as_mut(), 10), &t, "dicom");
    assert_eq!(r.desc().value_range, t.desc.value_range);
    let pl = r.placement().unwrap();
    assert_eq!(pl.space, "LPS");
    // slice k lies k * 1.5 mm along the normal from slice 0
    let p0 = pl.voxel_to_world([0.0, 0.0, 0.0]);
    let p9 = pl.voxel_to_world([0.0, 0.0, 9.0]);
    let d = ((p9[0] - p0[0]).powi(2) + (p9[1] - p0[1]).powi(2) + (p9[2] - p0[2]).powi(2)).sqrt();
    assert!((d - 13.5).abs() < 1e-3, "9 slices span {d} mm");
    // An axial series: rows toward the patient's left, columns toward
    // posterior, slices toward the head.
    assert_eq!(pl.orientation().expect("anatomical").code(), "LPS");
}

#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn two_series_with_shuffled_names() {
    let Some(dir) = fixture() else { return };
    let t = truth("invesalius_cranium_ct");
    let d = TempDir::new().unwrap();
    let src = by_position(&dir);
    // the 30 lowest slices become a second series in a subfolder, the other
    // 78 stay; every name scrambled, so neither names nor directory order
    // tell the slice order
    let sub = d.path().join("nested/deeper");
    std::fs::create_dir_all(&sub).unwrap();
    for (k, f) in src.iter().enumerate() {
        let name = format!("x{:03}", (k * 71) % 108);
        if k < 30 {
            copy_with(
                f,
                &sub.join(&name),
                &[(
                    tags::SERIES_INSTANCE_UID,
                    VR::UI,
                    PrimitiveValue::from("1.2.3.4.5.999"),
                )],
            );
        } else {
            std::fs::copy(f, d.path().join(name)).unwrap();
        }
    }
    let list = io::list(d.path(), &ReadOptions::default()).unwrap();
    assert_eq!(list.len(), 2, "{list:?}");
    assert!(list.iter().all(|e| e.kind == EntryKind::Series));
    assert!(list[0].default && !list[1].default, "{list:?}");
    assert_eq!(list[1].id, "1.2.3.4.5.999");
    let slice = 256 * 256 * 2;
    // default: the largest, raw slices 30..108
    let mut r = io::open(d.path()).unwrap();
    assert_eq!(r.desc().dims[2], 78);
    assert!(
        read_by_slabs(r.as_mut(), 20) == t.bytes[30 * slice..],
        "series A differs"
    );
    // the small one, selected by UID and by index: raw slices 0..30
    for sel in ["1.2.3.4.5.999", "1"] {
        let mut r =
            io::open_with(d.path(), &ReadOptions::default().series(Some(sel.into()))).unwrap();
        assert_eq!(r.desc().dims[2], 30, "{sel}");
        assert!(
            read_by_slabs(r.as_mut(), 30) == t.bytes[..30 * slice],
            "{sel}: series B differs"
        );
    }
    let e = io::open_with(d.path(), &ReadOptions::default().series(Some("7".into())))
        .err()
        .unwrap();
    assert!(
        matches!(e, IoError::NoSuchChoice { what: "series", .. }),
        "{e}"
    );
}

#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn missing_slice_mixed_sizes_and_unknown_syntax_are_refused() {
    let Some(dir) = fixture() else { return };
    let src = by_position(&dir);
    // a missing slice: the file at position 50 removed
    let d = TempDir::new().unwrap();
    for (k, f) in src.iter().enumerate() {
        if k != 50 {
            std::fs::copy(f, d.path().join(f.file_name().unwrap())).unwrap();
        }
    }
    let e = io::open(d.path()).err().expect("missing slice refused");
    let next = d.path().join(src[51].file_name().unwrap());
    assert!(
        matches!(&e, IoError::Inconsistent { file, msg, .. } if file == &next && msg.contains("missing")),
        "{e}"
    );

    // mixed sizes: one file claims 128 columns
    let d = TempDir::new().unwrap();
    for f in &src[..10] {
        std::fs::copy(f, d.path().join(f.file_name().unwrap())).unwrap();
    }
    let odd = d.path().join("odd.dcm");
    copy_with(
        &src[10],
        &odd,
        &[(tags::COLUMNS, VR::US, PrimitiveValue::from(128u16))],
    );
    let e = io::open(d.path()).err().expect("mixed sizes refused");
    assert!(
        matches!(&e, IoError::Inconsistent { file, .. } if file == &odd),
        "{e}"
    );

    // an unknown transfer syntax (same length as the real one, patched in place)
    let d = TempDir::new().unwrap();
    for f in &src[..5] {
        std::fs::copy(f, d.path().join(f.file_name().unwrap())).unwrap();
    }
    let mut bytes = std::fs::read(&src[5]).unwrap();
    let uid = b"1.2.840.10008.1.2.1\0";
    let at = bytes
        .windows(uid.len())
        .position(|w| w == uid)
        .expect("explicit VR LE file");
    bytes[at..at + uid.len()].copy_from_slice(b"1.2.840.10008.1.9.9\0");
    let bad = d.path().join("bad_syntax.dcm");
    std::fs::write(&bad, &bytes).unwrap();
    let e = io::open(d.path()).err().expect("unknown syntax refused");
    assert!(
        matches!(&e, IoError::UnsupportedTransferSyntax { path, uid, .. } if path == &bad && uid == "1.2.840.10008.1.9.9"),
        "{e}"
    );

    // a truncated file: an error naming it, never a panic
    let d = TempDir::new().unwrap();
    for f in &src[..5] {
        std::fs::copy(f, d.path().join(f.file_name().unwrap())).unwrap();
    }
    let bytes = std::fs::read(&src[5]).unwrap();
    let cut = d.path().join("cut.dcm");
    std::fs::write(&cut, &bytes[..bytes.len() - 5000]).unwrap();
    let e = io::open(d.path()).err().expect("truncated file refused");
    assert!(e.to_string().contains("cut.dcm"), "{e}");
}

// ---------------------------------------------------------------------------
// Encapsulated pixel data (RLE, JPEG, JPEG 2000) and hostile headers.

mod fixtures;

/// The shared CT series in RLE Lossless and JPEG 2000 Lossless (the same
/// slices as `cranium_ct`) decode voxel for voxel to the raw volume.
#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn encapsulated_series_decode_voxel_for_voxel() {
    let Some(dir) = formats_dir() else { return };
    let list: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("dicom/truth_compressed.json")).unwrap())
            .unwrap();
    let folders = list["folders"].as_object().unwrap();
    for want in ["cranium_ct_rle", "cranium_ct_j2k"] {
        assert!(folders.contains_key(want), "{want} not in {list}");
    }
    for (folder, raw) in folders {
        let name = Path::new(raw.as_str().unwrap()).file_stem().unwrap();
        let t = truth(name.to_str().unwrap());
        let mut r =
            io::open(dir.join("dicom").join(folder)).unwrap_or_else(|e| panic!("{folder}: {e}"));
        assert_eq!(r.format(), "DICOM");
        assert_eq!(r.desc().dims, t.desc.dims, "{folder}");
        assert_eq!(r.desc().dtype, DType::I16, "{folder}");
        assert_spacing(r.desc().spacing, t.desc.spacing, folder);
        assert_eq!(r.input_files().len(), 108, "{folder}");
        assert_same_voxels(&read_by_slabs(r.as_mut(), 10), &t, folder);
        assert_eq!(r.desc().value_range, t.desc.value_range, "{folder}");
    }
}

/// A series generated here in each syntax (RLE encoded by the test) reads
/// as the volume it was made from, in Hounsfield units.
#[test]
fn generated_series_decode_in_every_syntax() {
    for syntax in [
        fixtures::Syntax::Explicit,
        fixtures::Syntax::Implicit,
        fixtures::Syntax::Rle,
    ] {
        let d = TempDir::new().unwrap();
        fixtures::dicom_series(d.path(), syntax);
        let mut r = io::open(d.path()).unwrap_or_else(|e| panic!("{syntax:?}: {e}"));
        assert_eq!(r.desc().dims, fixtures::DIMS, "{syntax:?}");
        assert_eq!(r.desc().dtype, DType::I16, "{syntax:?}");
        assert_eq!(r.desc().spacing, [0.5, 0.5, 1.5], "{syntax:?}");
        let got = read_by_slabs(r.as_mut(), 3);
        let want: Vec<u8> = fixtures::volume_u16()
            .iter()
            .flat_map(|&v| (v as i16 - 1024).to_le_bytes())
            .collect();
        assert!(got == want, "{syntax:?}: voxels differ");
    }
}

/// JPEG baseline (encoded by dicom-pixeldata here) decodes within the
/// encoder's loss.
#[test]
fn generated_jpeg_baseline_series_decodes() {
    let d = TempDir::new().unwrap();
    for z in 0..fixtures::DIMS[2] {
        fixtures::dicom_jpeg_slice(&d.path().join(format!("j{z}.dcm")), z);
    }
    let mut r = io::open(d.path()).unwrap();
    assert_eq!(r.desc().dims, fixtures::DIMS);
    assert_eq!(r.desc().dtype, DType::U8);
    let got = read_by_slabs(r.as_mut(), 4);
    let [nx, ny, _] = fixtures::DIMS;
    let mut worst = 0i32;
    for (i, &g) in got.iter().enumerate() {
        let i = i as u32;
        let want = fixtures::jpeg_sample(i % nx, (i / nx) % ny, i / (nx * ny));
        worst = worst.max((g as i32 - want as i32).abs());
    }
    assert!(worst <= 12, "JPEG error up to {worst}");
}

/// A folder with the encapsulated slices: the header walk once refused them
/// as `unknown value representation` at the offset table; a damaged
/// fragment, item or offset table is a typed error naming the file.
#[test]
fn forged_encapsulated_pixel_data_is_a_typed_error() {
    let d = TempDir::new().unwrap();
    let files = fixtures::dicom_series(d.path(), fixtures::Syntax::Rle);
    let base = std::fs::read(&files[1]).unwrap();
    // the RLE header: 2 segments, the first at 64
    let at = base
        .windows(8)
        .position(|w| w == [2, 0, 0, 0, 64, 0, 0, 0])
        .expect("RLE header");
    type Edit = Box<dyn Fn(&mut Vec<u8>)>;
    let cases: Vec<(&str, Edit)> = vec![
        ("segment count", Box::new(move |b| b[at] = 9)),
        (
            "segment offset",
            Box::new(move |b| b[at + 4..at + 8].copy_from_slice(&u32::MAX.to_le_bytes())),
        ),
        ("truncated", Box::new(move |b| b.truncate(at + 20))),
        (
            "item length",
            Box::new(move |b| b[at - 4..at].copy_from_slice(&u32::MAX.to_le_bytes())),
        ),
        ("item tag", Box::new(move |b| b[at - 8] = 0)),
    ];
    for (what, edit) in cases {
        let mut b = base.clone();
        edit(&mut b);
        std::fs::write(&files[1], &b).unwrap();
        let e = io::open(d.path())
            .err()
            .unwrap_or_else(|| panic!("{what}: opened"));
        assert!(e.to_string().contains("s1.dcm"), "{what}: {e}");
    }
}

/// PixelSpacing NaN, negative, 0 or of the wrong count is a typed error,
/// never a silent 1; so are a RescaleSlope of 0 or NaN and an intercept NaN.
#[test]
fn invalid_pixel_spacing_and_rescale_are_typed_errors() {
    for (tag, value) in [
        (tags::PIXEL_SPACING, "NaN\\0.5"),
        (tags::PIXEL_SPACING, "-0.5\\0.5"),
        (tags::PIXEL_SPACING, "0\\0"),
        (tags::PIXEL_SPACING, "0.5"),
        (tags::PIXEL_SPACING, "inf\\0.5"),
        (tags::RESCALE_SLOPE, "0"),
        (tags::RESCALE_SLOPE, "NaN"),
        (tags::RESCALE_INTERCEPT, "NaN"),
        (tags::RESCALE_INTERCEPT, "abc"),
    ] {
        let d = TempDir::new().unwrap();
        fixtures::dicom_series(d.path(), fixtures::Syntax::Explicit);
        fixtures::dicom_slice(
            &d.path().join("s2.dcm"),
            2,
            fixtures::Syntax::Explicit,
            &|o| {
                o.put(DataElement::new(tag, VR::DS, PrimitiveValue::from(value)));
            },
        );
        match io::open(d.path()) {
            Ok(r) => panic!("{tag} {value:?} opened with spacing {:?}", r.desc().spacing),
            Err(e) => assert!(
                matches!(&e, IoError::BadHeader { path, .. } if path.ends_with("s2.dcm")),
                "{tag} {value:?}: {e}"
            ),
        }
    }
}

/// A RescaleIntercept of 1e39 (finite in the file, infinite as f32) is
/// refused at open: the samples would be stored as +inf.
#[test]
fn rescale_beyond_f32_is_refused_at_open() {
    for (slope, inter) in [("1", "1e39"), ("1e300", "0"), ("-1e39", "0")] {
        let d = TempDir::new().unwrap();
        for z in 0..fixtures::DIMS[2] {
            fixtures::dicom_slice(
                &d.path().join(format!("s{z}.dcm")),
                z,
                fixtures::Syntax::Explicit,
                &|o| {
                    o.put(DataElement::new(
                        tags::RESCALE_INTERCEPT,
                        VR::DS,
                        PrimitiveValue::from(inter),
                    ));
                    o.put(DataElement::new(
                        tags::RESCALE_SLOPE,
                        VR::DS,
                        PrimitiveValue::from(slope),
                    ));
                },
            );
        }
        match io::open(d.path()) {
            Ok(r) => panic!(
                "slope {slope}, intercept {inter}: opened, range {:?}",
                r.desc().value_range
            ),
            Err(e) => assert!(format!("{e:?}").starts_with("SampleOverflow"), "{e:?}"),
        }
    }
}

/// Found by the mutation suite: an RLE segment that decodes to fewer bytes
/// than the image has pixels made dicom-pixeldata's RLE decoder index past
/// its buffer (a panic). The frame is decoded here now: a typed error.
#[test]
fn rle_segment_decoding_short_is_a_typed_error() {
    let d = TempDir::new().unwrap();
    let files = fixtures::dicom_series(d.path(), fixtures::Syntax::Rle);
    let mut b = std::fs::read(&files[1]).unwrap();
    let at = b
        .windows(8)
        .position(|w| w == [2, 0, 0, 0, 64, 0, 0, 0])
        .expect("RLE header");
    let seg2 = u32::from_le_bytes(b[at + 8..at + 12].try_into().unwrap()) as usize;
    // the second segment: one literal byte, then no-op runs to its end
    let end = b.len() - 8; // the sequence delimiter follows the fragment
    b[at + seg2] = 0x00;
    b[at + seg2 + 1] = 0x05;
    for x in &mut b[at + seg2 + 2..end] {
        *x = 0x80;
    }
    std::fs::write(&files[1], &b).unwrap();
    let e = io::open(d.path()).err().expect("short segment opened");
    assert!(
        matches!(&e, IoError::Decode { path, .. } if path.ends_with("s1.dcm")),
        "{e:?}"
    );
}
