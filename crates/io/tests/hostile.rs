//! Hostile files, built by the tests from small generated volumes: FIFOs in
//! place of any file a reader opens, forged geometry, and values a reader
//! must refuse (or warn about) instead of replacing them silently.
#![cfg(all(
    feature = "nifti",
    feature = "tiff",
    feature = "dicom",
    feature = "zarr"
))]

mod fixtures;

use brickray_io::{self as io, FileKind, IoError, ReadOptions, VolumeReader};
use fixtures::{DIMS, ZARR_CODECS, ZarrCodec};
use std::path::Path;
use tempfile::TempDir;

/// Opens and reads a volume whole; the reader's warnings with it.
fn read(path: &Path) -> Result<(Vec<u8>, Vec<String>), IoError> {
    let mut r = io::open(path)?;
    let v = r.read_volume()?;
    Ok((v.data().as_bytes().to_vec(), r.warnings()))
}

/// The generated volume as stored (u16 little-endian).
fn want_u16() -> Vec<u8> {
    fixtures::le16(&fixtures::volume_u16())
}

#[test]
fn generated_zarr_images_decode_with_every_codec() {
    for codec in ZARR_CODECS {
        let d = TempDir::new().unwrap();
        let root = d.path().join("g.ome.zarr");
        fixtures::zarr(&root, codec);
        let mut r = io::open(&root).unwrap_or_else(|e| panic!("{codec:?}: {e}"));
        assert_eq!(r.desc().dims, DIMS, "{codec:?}");
        assert_eq!(r.desc().spacing, [0.5, 0.75, 2.0], "{codec:?}");
        assert!(r.warnings().is_empty(), "{codec:?}: {:?}", r.warnings());
        let v = r.read_volume().unwrap();
        assert!(
            v.data().as_bytes() == want_u16(),
            "{codec:?}: voxels differ"
        );
    }
}

// ---------------------------------------------------------------------------
// FIFOs and device nodes in place of any file a reader opens.

#[cfg(unix)]
mod fifos {
    use super::*;

    fn mkfifo(path: &Path) {
        let _ = std::fs::remove_file(path);
        let st = std::process::Command::new("mkfifo")
            .arg(path)
            .status()
            .unwrap();
        assert!(st.success(), "mkfifo failed");
    }

    /// Runs `f` on a thread; fails if it has not returned within 10 s, after
    /// unblocking a reader stuck opening `fifo` (by opening its other end),
    /// so that a regression fails instead of hanging the suite.
    fn within<T: Send + 'static>(fifo: &Path, f: impl FnOnce() -> T + Send + 'static) -> T {
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let _ = tx.send(f());
        });
        match rx.recv_timeout(std::time::Duration::from_secs(10)) {
            Ok(v) => v,
            Err(_) => {
                let other_end = fifo.to_owned();
                std::thread::spawn(move || {
                    let _ = std::fs::OpenOptions::new().write(true).open(&other_end);
                });
                panic!("blocked on the FIFO {}", fifo.display());
            }
        }
    }

    fn assert_refused(r: Result<(Vec<u8>, Vec<String>), IoError>, fifo: &Path, what: &str) {
        match r {
            Err(IoError::NotRegularFile { path, kind }) => {
                assert_eq!(path, fifo, "{what}");
                assert_eq!(kind, FileKind::Fifo, "{what}");
            }
            Err(e) => panic!("{what}: {e:?}, not NotRegularFile"),
            Ok(_) => panic!("{what}: opened"),
        }
    }

    /// `mkfifo` in place of `zarr.json`, `.zarray`, `.zattrs` or a chunk
    /// once hung `brickray-store info`.
    #[test]
    fn ome_zarr_metadata_and_chunk_fifos_are_refused() {
        let d = TempDir::new().unwrap();
        let cases: [(ZarrCodec, &str); 6] = [
            (ZarrCodec::Zstd, "zarr.json"),
            (ZarrCodec::Zstd, "s0/zarr.json"),
            (ZarrCodec::Zstd, "s0/c/1/0/1"),
            (ZarrCodec::V2Blosc, ".zattrs"),
            (ZarrCodec::V2Blosc, "s0/.zarray"),
            (ZarrCodec::V2Blosc, "s0/1.0.1"),
        ];
        for (i, (codec, file)) in cases.into_iter().enumerate() {
            let root = d.path().join(format!("f{i}.ome.zarr"));
            fixtures::zarr(&root, codec);
            let fifo = root.join(file);
            assert!(fifo.exists(), "{codec:?} has no {file}");
            mkfifo(&fifo);
            let p = root.clone();
            let r = within(&fifo, move || read(&p));
            assert_refused(r, &fifo, &format!("{codec:?} {file}"));
            // the streamed source too
            if !file.contains("zarr.json") && !file.starts_with('.') && !file.ends_with(".zarray") {
                let p = root.clone();
                let r = within(&fifo, move || {
                    io::zarr::ZarrBrickSource::open(&p, &ReadOptions::default(), 4, 1, None)
                        .map(|_| (Vec::new(), Vec::new()))
                });
                assert_refused(r, &fifo, &format!("{codec:?} {file}, streamed"));
            }
        }
    }

    #[test]
    fn nifti_tiff_and_dicom_fifos_are_refused() {
        let d = TempDir::new().unwrap();
        for name in ["a.nii", "b.nii.gz", "c.tif", "d.dcm"] {
            let fifo = d.path().join(name);
            mkfifo(&fifo);
            let p = fifo.clone();
            let r = within(&fifo, move || read(&p));
            assert_refused(r, &fifo, name);
        }
        // the image of a header/image pair
        let hdr = fixtures::nifti();
        let mut h = hdr[..348].to_vec();
        h[344..348].copy_from_slice(b"ni1\0");
        h[108..112].copy_from_slice(&0f32.to_le_bytes());
        fixtures::write(&d.path().join("p.hdr"), &h);
        let img = d.path().join("p.img");
        mkfifo(&img);
        let p = d.path().join("p.hdr");
        let r = within(&img, move || read(&p));
        assert_refused(r, &img, "p.img");
        // a FIFO among a DICOM series' files is not a slice: skipped, the
        // series reads
        let s = d.path().join("series");
        fixtures::dicom_series(&s, fixtures::Syntax::Explicit);
        mkfifo(&s.join("zz.dcm"));
        let p = s.clone();
        let r = within(&s.join("zz.dcm"), move || read(&p));
        assert!(r.is_ok(), "{r:?}");
    }
}

// ---------------------------------------------------------------------------
// Forged OME-Zarr geometry and transforms.

/// Rewrites a JSON file through `edit`.
fn edit_json(path: &Path, edit: impl FnOnce(&mut serde_json::Value)) {
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
    edit(&mut v);
    std::fs::write(path, v.to_string()).unwrap();
}

/// A chunk shape forged to [2^31]^3 once read as a volume of fill values.
#[test]
fn forged_chunk_shape_is_a_typed_error() {
    for (codec, shape) in [
        (
            ZarrCodec::Zstd,
            serde_json::json!([2147483648u64, 2147483648u64, 2147483648u64]),
        ),
        (
            ZarrCodec::Raw,
            serde_json::json!([4, 2147483648u64, 2147483648u64]),
        ),
        (
            ZarrCodec::V2Zstd,
            serde_json::json!([2147483648u64, 2147483648u64, 2147483648u64]),
        ),
    ] {
        let d = TempDir::new().unwrap();
        let root = d.path().join("c.ome.zarr");
        fixtures::zarr(&root, codec);
        let meta = fixtures::zarr_array_meta(&root);
        edit_json(&meta, |v| {
            if v.get("zarr_format") == Some(&serde_json::json!(2)) {
                v["chunks"] = shape.clone();
            } else {
                v["chunk_grid"]["configuration"]["chunk_shape"] = shape.clone();
            }
        });
        match read(&root) {
            Ok(_) => panic!("{codec:?}: chunks {shape} opened"),
            Err(e) => assert!(
                matches!(&e, IoError::BadHeader { msg, .. } if msg.contains("chunks")),
                "{codec:?}: {e:?}"
            ),
        }
    }
    // sharding: inner chunks forged, and an index of 2^40 entries
    for inner in [
        serde_json::json!([2147483648u64, 2147483648u64, 2147483648u64]),
        serde_json::json!([1, 1, 1]),
    ] {
        let d = TempDir::new().unwrap();
        let root = d.path().join("s.ome.zarr");
        fixtures::zarr(&root, ZarrCodec::Sharded);
        let meta = fixtures::zarr_array_meta(&root);
        edit_json(&meta, |v| {
            v["codecs"][0]["configuration"]["chunk_shape"] = inner.clone();
            if inner[0] == 1 {
                v["shape"] = serde_json::json!([1 << 14, 1 << 14, 1 << 14]);
                v["chunk_grid"]["configuration"]["chunk_shape"] =
                    serde_json::json!([1 << 14, 1 << 14, 1 << 14]);
            }
        });
        let e = read(&root).expect_err("forged sharding opened");
        assert!(matches!(&e, IoError::BadHeader { .. }), "{inner}: {e:?}");
    }
}

/// Forges the shape of level `s0` (z, y, x) and its fill value.
fn forge_shape(root: &Path, shape: [u64; 3], fill: u16) {
    edit_json(&fixtures::zarr_array_meta(root), |v| {
        v["shape"] = serde_json::json!(shape);
        v["fill_value"] = serde_json::json!(fill);
    });
}

/// A shape forged huge over the few small chunks of an image: [2^31]^3 is
/// refused at once; 2^16 per axis (2^48 voxels, within what a volume may
/// have) opens, its range scanned from the chunks stored (and the fill value
/// of those that are not) in an instant. Before, the scan read the declared
/// voxels in slabs of whole slices: 8 GiB for the first one (the process
/// aborted where that could not be had), and then 2^48 voxels of fill.
/// Served as bricks, its single level would make the root read all 2^48
/// voxels: refused at open.
#[test]
fn forged_huge_shape_is_refused_or_scanned_in_bounded_time() {
    for codec in ZARR_CODECS {
        let d = TempDir::new().unwrap();
        let root = d.path().join("h.ome.zarr");
        fixtures::zarr(&root, codec);
        forge_shape(&root, [1 << 31; 3], 0);
        let t = std::time::Instant::now();
        let e = io::open(&root).map(|_| ()).expect_err("[2^31]^3 opened");
        assert!(matches!(e, IoError::Volume { .. }), "{codec:?}: {e:?}");
        assert!(io::zarr::ZarrBrickSource::open(&root, &Default::default(), 16, 1, None).is_err());
        assert!(
            t.elapsed().as_secs_f64() < 2.0,
            "{codec:?}: {:?}",
            t.elapsed()
        );

        forge_shape(&root, [1 << 16; 3], 4000);
        let t = std::time::Instant::now();
        let r = io::open(&root).unwrap_or_else(|e| panic!("{codec:?}: {e}"));
        assert_eq!(r.desc().dims, [1 << 16; 3], "{codec:?}");
        // The stored samples (0..=2999) and the fill value of the chunks
        // that are not stored.
        assert_eq!(r.desc().value_range, [0.0, 4000.0], "{codec:?}");
        let e = io::zarr::ZarrBrickSource::open(&root, &Default::default(), 16, 1, None)
            .map(|_| ())
            .expect_err("a root brick of 2^48 voxels");
        assert!(
            matches!(&e, IoError::Unsupported { what, .. } if what.contains("too few levels")),
            "{codec:?}: {e:?}"
        );
        let took = t.elapsed();
        assert!(took.as_secs_f64() < 2.0, "{codec:?}: scanned in {took:?}");
    }
}

/// The scan reads the chunks stored and the fill value of a chunk that is
/// not: the range it finds is the range of the voxels read, for every codec.
#[test]
fn a_missing_chunk_counts_with_its_fill_value() {
    for codec in ZARR_CODECS {
        let d = TempDir::new().unwrap();
        let root = d.path().join("m.ome.zarr");
        let chunks = fixtures::zarr(&root, codec);
        let [nx, ny, nz] = DIMS.map(u64::from);
        forge_shape(&root, [nz, ny, nx], 4000);
        for missing in [false, true] {
            if missing {
                std::fs::remove_file(&chunks[chunks.len() / 2]).unwrap();
            }
            let mut r = io::open(&root).unwrap_or_else(|e| panic!("{codec:?}: {e}"));
            let v = r.read_volume().unwrap();
            let (lo, hi) = v
                .data()
                .as_bytes()
                .chunks_exact(2)
                .map(|b| u16::from_le_bytes([b[0], b[1]]))
                .fold((u16::MAX, 0), |(a, b), s| (a.min(s), b.max(s)));
            assert_eq!(hi == 4000, missing, "{codec:?}");
            let want = if lo == hi {
                [lo as f32, lo as f32 + 1.0]
            } else {
                [lo as f32, hi as f32]
            };
            assert_eq!(r.desc().value_range, want, "{codec:?} missing {missing}");
        }
    }
}

/// OME-Zarr scales of `"NaN"` or of the wrong length were silently 1.
#[test]
fn ome_zarr_bad_scales_are_typed_errors() {
    let bad = [
        serde_json::json!([{"type": "scale", "scale": ["NaN", 0.75, 0.5]}]),
        serde_json::json!([{"type": "scale", "scale": [0.75, 0.5]}]),
        serde_json::json!([{"type": "scale", "scale": [1.0, 1.0, 1.0, 1.0]}]),
        serde_json::json!([{"type": "scale", "scale": [2.0, 0.75, 0.5]}, {"type": "translation", "translation": [0, "x", 0]}]),
        serde_json::json!([{"type": "scale", "scale": [2.0, 0.0, 0.5]}]),
        serde_json::json!([{"type": "scale", "scale": [2.0, -1.0, 0.5]}]),
        serde_json::json!([{"type": "scale"}]),
        serde_json::json!("scale"),
    ];
    for (i, t) in bad.iter().enumerate() {
        for codec in [ZarrCodec::Zstd, ZarrCodec::V2Blosc] {
            let d = TempDir::new().unwrap();
            let root = d.path().join("t.ome.zarr");
            fixtures::zarr(&root, codec);
            let group = if codec == ZarrCodec::Zstd {
                root.join("zarr.json")
            } else {
                root.join(".zattrs")
            };
            edit_json(&group, |v| {
                let ms = if codec == ZarrCodec::Zstd {
                    &mut v["attributes"]["ome"]["multiscales"][0]
                } else {
                    &mut v["multiscales"][0]
                };
                ms["datasets"][0]["coordinateTransformations"] = t.clone();
            });
            match read(&root) {
                Ok(_) => panic!("case {i} {t} ({codec:?}) opened"),
                Err(e) => assert!(matches!(&e, IoError::BadHeader { .. }), "case {i}: {e:?}"),
            }
        }
    }
    // no scale at all: the customary 1, with a warning the caller sees
    let d = TempDir::new().unwrap();
    let root = d.path().join("t.ome.zarr");
    fixtures::zarr(&root, ZarrCodec::Zstd);
    edit_json(&root.join("zarr.json"), |v| {
        let ds = &mut v["attributes"]["ome"]["multiscales"][0]["datasets"][0];
        ds.as_object_mut()
            .unwrap()
            .remove("coordinateTransformations");
    });
    let r = io::open(&root).unwrap();
    assert_eq!(r.desc().spacing, [1.0; 3]);
    let w = r.warnings();
    assert!(w.len() == 1 && w[0].contains("no scale"), "{w:?}");
}

// ---------------------------------------------------------------------------
// NIfTI: gzip integrity, sform, rescale.

#[test]
fn nifti_gz_with_a_wrong_crc_or_length_is_a_typed_error() {
    let d = TempDir::new().unwrap();
    let base = fixtures::nifti();
    // stored (level 0) deflate blocks: a flipped data byte decodes, only the
    // CRC tells
    let gz = fixtures::gzip(&base, 0);
    let n = gz.len();
    let p = d.path().join("v.nii.gz");
    fixtures::write(&p, &gz);
    assert!(read(&p).is_ok());
    let data_byte = gz
        .windows(4)
        .position(|w| w == [b'n', b'+', b'1', 0])
        .unwrap()
        + 4
        + 4
        + 10;
    for (what, at) in [
        ("a data byte", data_byte),
        ("the CRC", n - 8),
        ("the length", n - 4),
    ] {
        let mut b = gz.clone();
        b[at] ^= 0x10;
        fixtures::write(&p, &b);
        match read(&p) {
            Ok(_) => panic!("{what} flipped: opened"),
            Err(e) => assert!(
                matches!(&e, IoError::Decode { format: "gzip", .. }),
                "{what}: {e:?}"
            ),
        }
    }
}

#[test]
fn nifti_sform_with_nan_or_a_zero_column_is_a_typed_error() {
    let d = TempDir::new().unwrap();
    let base = fixtures::nifti();
    let p = d.path().join("s.nii");
    // srow_x[0] NaN; column 1 (srow_*[1]) all zero; column 0 zero
    let cases: [(&str, &[(usize, f32)]); 4] = [
        ("NaN", &[(0, f32::NAN)]),
        ("infinite offset", &[(3, f32::INFINITY)]),
        ("zero column j", &[(5, 0.0)]),
        ("zero column i", &[(0, 0.0)]),
    ];
    for (what, edits) in cases {
        let mut b = base.clone();
        for &(k, v) in edits {
            let at = fixtures::NIFTI_SROW + 4 * k;
            b[at..at + 4].copy_from_slice(&v.to_le_bytes());
        }
        fixtures::write(&p, &b);
        match read(&p) {
            Ok(_) => panic!("sform {what}: opened"),
            Err(e) => assert!(matches!(&e, IoError::BadHeader { .. }), "{what}: {e:?}"),
        }
    }
    // the qform, when it places the volume: NaN quaternion or offset
    for (what, at) in [("quatern_b", 256usize), ("qoffset_x", 268)] {
        let mut b = base.clone();
        b[254..256].copy_from_slice(&0i16.to_le_bytes()); // no sform
        b[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
        fixtures::write(&p, &b);
        let e = read(&p)
            .err()
            .unwrap_or_else(|| panic!("qform {what} NaN opened"));
        assert!(matches!(&e, IoError::BadHeader { .. }), "{what}: {e:?}");
    }
}

#[test]
fn nifti_non_finite_scl_slope_is_read_as_no_rescale_with_a_warning() {
    let d = TempDir::new().unwrap();
    let mut b = fixtures::nifti();
    b[112..116].copy_from_slice(&f32::NAN.to_le_bytes());
    let p = fixtures::write(&d.path().join("s.nii"), &b);
    let (bytes, w) = read(&p).unwrap();
    assert!(bytes == want_u16());
    assert!(w.len() == 1 && w[0].contains("scl_slope"), "{w:?}");
    // a slope that takes the samples beyond f32: refused
    b[112..116].copy_from_slice(&f32::MAX.to_le_bytes());
    fixtures::write(&p, &b);
    let e = read(&p).expect_err("overflowing rescale opened");
    assert!(matches!(&e, IoError::SampleOverflow { .. }), "{e:?}");
}

// ---------------------------------------------------------------------------
// TIFF sizes, DICOM spacing warnings, raw sidecars.

#[test]
fn tiff_sizes_nan_or_negative_are_typed_errors() {
    let d = TempDir::new().unwrap();
    let p = d.path().join("t.tif");
    let ome = |x: &str, z: &str, sizes: &str| {
        format!(
            r#"<?xml version="1.0"?><OME><Image><Pixels DimensionOrder="XYCZT" {sizes} PhysicalSizeX="{x}" PhysicalSizeY="0.5" PhysicalSizeZ="{z}" Type="uint16"/></Image></OME>"#
        )
    };
    let good_sizes = r#"SizeX="8" SizeY="6" SizeZ="4" SizeC="1" SizeT="1""#;
    let bad: Vec<(String, String)> = vec![
        (
            "ImageJ spacing NaN".into(),
            "ImageJ=1.53\nimages=4\nslices=4\nspacing=NaN\nunit=micron\n".into(),
        ),
        (
            "ImageJ spacing negative".into(),
            "ImageJ=1.53\nimages=4\nslices=4\nspacing=-2\nunit=micron\n".into(),
        ),
        (
            "ImageJ spacing 0".into(),
            "ImageJ=1.53\nimages=4\nslices=4\nspacing=0\nunit=micron\n".into(),
        ),
        (
            "ImageJ slices negative".into(),
            "ImageJ=1.53\nimages=4\nslices=-4\nspacing=2\nunit=micron\n".into(),
        ),
        ("OME PhysicalSizeX NaN".into(), ome("NaN", "2", good_sizes)),
        (
            "OME PhysicalSizeX negative".into(),
            ome("-0.5", "2", good_sizes),
        ),
        ("OME PhysicalSizeZ 0".into(), ome("0.5", "0", good_sizes)),
        (
            "OME SizeZ negative".into(),
            ome(
                "0.5",
                "2",
                r#"SizeX="8" SizeY="6" SizeZ="-4" SizeC="1" SizeT="1""#,
            ),
        ),
        (
            "OME SizeC NaN".into(),
            ome(
                "0.5",
                "2",
                r#"SizeX="8" SizeY="6" SizeZ="4" SizeC="NaN" SizeT="1""#,
            ),
        ),
    ];
    for (what, desc) in &bad {
        fixtures::write(&p, &fixtures::tiff(Some((desc.as_str(), 2.0, 2.0)), None));
        match read(&p) {
            Ok(_) => panic!("{what}: opened"),
            Err(e) => assert!(matches!(&e, IoError::BadHeader { .. }), "{what}: {e:?}"),
        }
    }
    // the good ones read, with their spacing and no warning
    for desc in [
        "ImageJ=1.53\nimages=4\nslices=4\nspacing=2\nunit=micron\n".to_owned(),
        ome("0.5", "2", good_sizes),
    ] {
        fixtures::write(&p, &fixtures::tiff(Some((desc.as_str(), 2.0, 2.0)), None));
        let r = io::open(&p).unwrap();
        assert_eq!(r.desc().spacing, [0.5, 0.5, 2.0], "{desc}");
        assert!(r.warnings().is_empty(), "{:?}", r.warnings());
    }
    // ImageJ with a zero x resolution: 1 assumed, with a warning
    let desc = "ImageJ=1.53\nimages=4\nslices=4\nspacing=2\nunit=micron\n";
    fixtures::write(&p, &fixtures::tiff(Some((desc, 0.0, 2.0)), None));
    let r = io::open(&p).unwrap();
    assert_eq!(r.desc().spacing, [1.0, 0.5, 2.0]);
    assert!(
        r.warnings().iter().any(|w| w.contains("XResolution")),
        "{:?}",
        r.warnings()
    );
    // no metadata at all: 1, 1, 1 with a warning (or the caller's spacing)
    fixtures::write(&p, &fixtures::tiff(None, None));
    let r = io::open(&p).unwrap();
    assert_eq!(r.desc().spacing, [1.0; 3]);
    assert!(
        r.warnings().iter().any(|w| w.contains("no spacing")),
        "{:?}",
        r.warnings()
    );
    let r = io::open_with(&p, &ReadOptions::default().spacing(Some([0.5, 0.5, 3.0]))).unwrap();
    assert_eq!(r.desc().spacing, [0.5, 0.5, 3.0]);
    assert!(r.warnings().is_empty(), "{:?}", r.warnings());
}

#[test]
fn dicom_without_pixel_spacing_reads_at_1_mm_with_a_warning() {
    use dicom_dictionary_std::tags;
    let d = TempDir::new().unwrap();
    for z in 0..DIMS[2] {
        fixtures::dicom_slice(
            &d.path().join(format!("s{z}.dcm")),
            z,
            fixtures::Syntax::Explicit,
            &|o| {
                o.remove_element(tags::PIXEL_SPACING);
            },
        );
    }
    let r = io::open(d.path()).unwrap();
    assert_eq!(r.desc().spacing, [1.0, 1.0, 1.5]);
    let w = r.warnings();
    assert!(w.len() == 1 && w[0].contains("PixelSpacing"), "{w:?}");
}

/// A sidecar whose `file` is itself, exactly as long as its dims say, so
/// that only the self-reference is wrong (it once built a store of its own
/// JSON text).
fn self_sidecar(name: &str) -> String {
    let mut l = 40;
    loop {
        let s = format!(r#"{{"dims": [{l}, 1, 1], "dtype": "u8", "file": {name:?}}}"#);
        if s.len() <= l {
            return format!("{s}{}", " ".repeat(l - s.len()));
        }
        l += 1;
    }
}

#[test]
fn raw_sidecar_naming_itself_is_a_typed_error() {
    let d = TempDir::new().unwrap();
    std::fs::create_dir_all(d.path().join("sub")).unwrap();
    let json = d.path().join("self.json");
    for name in ["self.json", "./self.json", "sub/../self.json"] {
        std::fs::write(&json, self_sidecar(name)).unwrap();
        match io::read_volume(&json) {
            Ok(v) => panic!("{name}: opened {:?}", v.desc()),
            Err(e) => assert!(
                matches!(&e, IoError::BadHeader { msg, .. } if msg.contains("itself")),
                "{name}: {e:?}"
            ),
        }
    }
    // a hard link to the sidecar is the same file
    #[cfg(unix)]
    {
        std::fs::write(&json, self_sidecar("link.raw")).unwrap();
        std::fs::hard_link(&json, d.path().join("link.raw")).unwrap();
        let e = io::read_volume(&json).expect_err("hard link opened");
        assert!(
            matches!(&e, IoError::BadHeader { msg, .. } if msg.contains("itself")),
            "{e:?}"
        );
    }
}

// ---------------------------------------------------------------------------
// A careless host: values a caller passes are checked, never a panic.

#[test]
fn read_slices_with_a_wrong_buffer_is_a_typed_error() {
    let d = TempDir::new().unwrap();
    let p = fixtures::write(&d.path().join("v.nii"), &fixtures::nifti());
    let mut r = io::open(&p).unwrap();
    let slice = (DIMS[0] * DIMS[1] * 2) as usize;
    for (z0, z1, len) in [(0, 1, slice - 1), (0, 2, slice), (1, 1, 1), (0, 1, 0)] {
        let mut buf = vec![0u8; len];
        let e = r
            .read_slices(z0, z1, &mut buf)
            .expect_err("wrong buffer read");
        assert!(
            matches!(e, IoError::SlabBuffer { .. }),
            "{z0}..{z1}, {len}: {e:?}"
        );
    }
    let v = r.read_volume().unwrap();
    let mut m = io::MemoryReader::new(v, "mem");
    let mut buf = vec![0u8; 3];
    let e = m
        .read_slices(0, 1, &mut buf)
        .expect_err("wrong buffer read");
    assert!(matches!(e, IoError::SlabBuffer { .. }), "{e:?}");
}

#[test]
fn sample_converter_with_slices_of_the_wrong_length_does_not_panic() {
    use io::{SampleConverter, SourceType};
    for src in [SourceType::U8, SourceType::U16, SourceType::F64] {
        let c = SampleConverter::choose(src, false, 1.0, 0.0, None);
        let _ = c.value(&[]);
        let _ = c.value(&[1]);
        let mut out = [0u8; 3];
        c.convert(&[1, 2, 3, 4, 5], &mut out);
        c.convert(&[1], &mut out);
    }
}

#[test]
fn zarr_brick_source_refuses_bricks_it_cannot_lay_out() {
    let d = TempDir::new().unwrap();
    let root = d.path().join("b.ome.zarr");
    fixtures::zarr(&root, ZarrCodec::Raw);
    for (brick, apron) in [(0, 0), (8, u32::MAX), (u32::MAX, 1), (8, 9)] {
        let e = io::zarr::ZarrBrickSource::open(&root, &ReadOptions::default(), brick, apron, None)
            .err()
            .unwrap_or_else(|| panic!("brick {brick}, apron {apron} opened"));
        assert!(matches!(e, IoError::Unsupported { .. }), "{e:?}");
    }
    let z = io::zarr::OmeZarr::open(&root).unwrap();
    assert_eq!(z.level_dims(0), Some([8, 6, 4]));
    assert_eq!(z.level_dims(7), None);
}

/// Found by the mutation suite: a flat volume of large values (9e9) got a
/// value range of zero width (lo + 1 rounds back to lo in f32), which a
/// renderer divides by. The range is strictly increasing now.
#[test]
fn flat_volume_of_large_values_has_a_range_of_positive_width() {
    let d = TempDir::new().unwrap();
    for inter in [8_936_756_000f32, -3.0e38, 3.0e38, f32::MAX / 2.0] {
        let mut b = fixtures::nifti();
        let n = b.len();
        b[352..n].fill(0);
        b[112..116].copy_from_slice(&1f32.to_le_bytes());
        b[116..120].copy_from_slice(&inter.to_le_bytes());
        let p = fixtures::write(&d.path().join("f.nii"), &b);
        let r = io::open(&p).unwrap();
        let [lo, hi] = r.desc().value_range;
        assert!(
            lo.is_finite() && hi.is_finite() && lo < hi,
            "{inter}: {lo}..{hi}"
        );
    }
    // raw f32 samples, through the other scan
    let json = d.path().join("r.json");
    std::fs::write(
        d.path().join("r.raw"),
        [9.0e9f32; 8].map(f32::to_le_bytes).concat(),
    )
    .unwrap();
    std::fs::write(&json, r#"{"dims": [2, 2, 2], "dtype": "f32"}"#).unwrap();
    let r = io::open(&json).unwrap();
    let [lo, hi] = r.desc().value_range;
    assert!(lo < hi, "{lo}..{hi}");
}
