//! Volume input: round trips through the raw + JSON sidecar and NRRD readers and
//! the shared data sets. Bad input is in `io_bad_input.rs`.

mod common;

use brickray_core::DType;
use brickray_io::{self as io, IoError, NrrdReader, RawReader, VolumeReader};
use common::*;
use tempfile::TempDir;

// ---------------------------------------------------------------------------
// Round trips.

#[test]
fn raw_sidecar_round_trip_every_dtype() {
    let dir = TempDir::new().unwrap();
    for (k, dtype) in DTYPES.into_iter().enumerate() {
        let (le, values) = samples(dtype, DIMS, k as u32);
        // value range from the data
        let name = format!("v_{}", dtype.name());
        let json = write_sidecar(
            dir.path(),
            &name,
            sidecar_json(dtype.name(), DIMS.map(u64::from), SPACING),
            &le,
        );
        let vol = io::read_volume(&json).unwrap();
        check_volume(&vol, dtype, DIMS, SPACING, &le, &values);
        assert_eq!(vol.desc().value_range, data_range(&values));
        // opened through the .raw name too
        let vol2 = io::read_volume(dir.path().join(format!("{name}.raw"))).unwrap();
        assert_eq!(vol2, vol);
        // declared value range and an explicit "file" with another name
        let mut j = sidecar_json(dtype.name(), DIMS.map(u64::from), SPACING);
        j["value_range"] = serde_json::json!([-5.0, 70000.0]);
        j["file"] = serde_json::json!(format!("{name}.raw"));
        let json = write(
            &dir.path().join(format!("other_{name}.json")),
            j.to_string().as_bytes(),
        );
        let vol = io::read_volume(&json).unwrap();
        check_volume(&vol, dtype, DIMS, SPACING, &le, &values);
        assert_eq!(vol.desc().value_range, [-5.0, 70000.0]);
    }
    // no spacing: isotropic 1; aliases of dtype names accepted
    let (le, values) = samples(DType::U16, DIMS, 9);
    let json = write_sidecar(
        dir.path(),
        "alias",
        serde_json::json!({ "dims": DIMS, "dtype": "uint16" }),
        &le,
    );
    let vol = io::read_volume(&json).unwrap();
    check_volume(&vol, DType::U16, DIMS, [1.0; 3], &le, &values);
}

#[test]
fn nrrd_round_trip_every_dtype_encoding_layout_and_endianness() {
    let dir = TempDir::new().unwrap();
    for (k, dtype) in DTYPES.into_iter().enumerate() {
        let (le, values) = samples(dtype, DIMS, 100 + k as u32);
        for encoding in ["raw", "gzip"] {
            for big in [false, true] {
                let mut payload = if big {
                    to_big_endian(dtype, &le)
                } else {
                    le.clone()
                };
                if encoding == "gzip" {
                    payload = gzip(&payload);
                }
                let fields = nrrd_fields(dtype, DIMS, encoding, big);
                for detached in [false, true] {
                    let name = format!("{}_{encoding}_{big}_{detached}", dtype.name());
                    let path = if detached {
                        write_detached(dir.path(), &name, &fields, &payload)
                    } else {
                        write_attached(dir.path(), &name, &fields, &payload)
                    };
                    let vol = io::read_volume(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
                    check_volume(&vol, dtype, DIMS, SPACING, &le, &values);
                    assert_eq!(vol.desc().value_range, data_range(&values), "{name}");
                }
                // declared min/max
                let fields = format!("{fields}min: -3\nmax: 1e5\n");
                let path = write_attached(
                    dir.path(),
                    &format!("mm_{}_{encoding}_{big}", dtype.name()),
                    &fields,
                    &payload,
                );
                let vol = io::read_volume(&path).unwrap();
                check_volume(&vol, dtype, DIMS, SPACING, &le, &values);
                assert_eq!(vol.desc().value_range, [-3.0, 1e5]);
            }
        }
    }
}

#[test]
fn nrrd_spacing_from_space_directions_and_4d_leading_axis() {
    let dir = TempDir::new().unwrap();
    let (le, values) = samples(DType::I16, DIMS, 7);
    let base = "type: short\nencoding: raw\nendian: little\nspace: left-posterior-superior\n";
    // axis-aligned and oblique direction vectors: spacing is each vector's length
    let f = format!(
        "{base}dimension: 3\nsizes: 7 5 3\nspace directions: (0.5,0,0) (0,0,-1.25) (0,3,0)\n"
    );
    let vol = io::read_volume(write_attached(dir.path(), "dirs", &f, &le)).unwrap();
    check_volume(&vol, DType::I16, DIMS, SPACING, &le, &values);
    let f = format!(
        "{base}dimension: 3\nsizes: 7 5 3\nspace directions: (0.6,0.8,0) (0,0,2) (-1.2, 0, 1.6)\n"
    );
    let vol = io::read_volume(write_attached(dir.path(), "oblique", &f, &le)).unwrap();
    for (a, b) in vol.desc().spacing.iter().zip([1.0f32, 2.0, 2.0]) {
        assert!((a - b).abs() < 1e-6, "{:?}", vol.desc().spacing);
    }
    // 4D with a leading axis of size 1: "none" direction, "nan" spacing
    let f = format!(
        "{base}dimension: 4\nsizes: 1 7 5 3\nspace directions: none (0.5,0,0) (0,1.25,0) (0,0,3)\n"
    );
    let vol = io::read_volume(write_attached(dir.path(), "dirs4", &f, &le)).unwrap();
    check_volume(&vol, DType::I16, DIMS, SPACING, &le, &values);
    let f = format!("{base}dimension: 4\nsizes: 1 7 5 3\nspacings: nan 0.5 1.25 3\n");
    let vol = io::read_volume(write_attached(dir.path(), "sp4", &f, &le)).unwrap();
    check_volume(&vol, DType::I16, DIMS, SPACING, &le, &values);
    // no spacing at all: isotropic; key/value pairs and comments are ignored
    let f = format!("{base}dimension: 3\nsizes: 7 5 3\n# comment\nmodality:=CT\n");
    let vol = io::read_volume(write_attached(dir.path(), "nosp", &f, &le)).unwrap();
    check_volume(&vol, DType::I16, DIMS, [1.0; 3], &le, &values);
    // proportions: the physical extent follows the spacing
    let vol = io::read_volume(dir.path().join("dirs.nrrd")).unwrap();
    assert_eq!(vol.desc().extent().to_array(), [3.5, 6.25, 9.0]);
}

/// Reads slabs of every size in increasing order and in a scrambled order.
fn check_slabs(r: &mut dyn VolumeReader, le: &[u8]) {
    let d = r.desc().clone();
    let slice = (d.dims[0] * d.dims[1]) as usize * d.dtype.size();
    let nz = d.dims[2];
    for step in 1..=nz {
        let mut z = 0;
        while z < nz {
            let z1 = (z + step).min(nz);
            let mut out = vec![0u8; (z1 - z) as usize * slice];
            r.read_slices(z, z1, &mut out).unwrap();
            assert_eq!(
                out,
                &le[z as usize * slice..z1 as usize * slice],
                "slab {z}..{z1}"
            );
            z = z1;
        }
    }
    let order = [
        (nz - 1, nz),
        (0, 1),
        (nz / 2, nz),
        (1, nz),
        (0, nz),
        (nz - 1, nz),
        (0, 0),
        (nz, nz),
    ];
    for (z0, z1) in order {
        let mut out = vec![0u8; (z1 - z0) as usize * slice];
        r.read_slices(z0, z1, &mut out).unwrap();
        assert_eq!(
            out,
            &le[z0 as usize * slice..z1 as usize * slice],
            "slab {z0}..{z1}"
        );
    }
    // beyond the volume, reversed
    let mut out = vec![0u8; slice];
    assert!(
        matches!(r.read_slices(nz, nz + 1, &mut out), Err(IoError::BadSlab { z0, z1, depth }) if z0 == nz && z1 == nz + 1 && depth == nz)
    );
    let mut none: Vec<u8> = Vec::new();
    assert!(matches!(
        r.read_slices(2, 1, &mut none),
        Err(IoError::BadSlab { .. })
    ));
    assert!(matches!(
        r.read_slices(0, u32::MAX, &mut none),
        Err(IoError::BadSlab { .. })
    ));
    // the reader still works afterwards
    let mut all = vec![0u8; le.len()];
    r.read_slices(0, nz, &mut all).unwrap();
    assert_eq!(all, le);
}

#[test]
fn slab_reads_in_and_out_of_order_match() {
    let dir = TempDir::new().unwrap();
    let dims = [6, 4, 9];
    for dtype in [DType::U16, DType::F32] {
        let (le, _) = samples(dtype, dims, 3);
        let json = write_sidecar(
            dir.path(),
            "s",
            sidecar_json(dtype.name(), dims.map(u64::from), [1.0; 3]),
            &le,
        );
        check_slabs(&mut RawReader::open_sidecar(&json).unwrap(), &le);
        let fields = nrrd_fields(dtype, dims, "raw", true);
        let p = write_attached(dir.path(), "s_raw", &fields, &to_big_endian(dtype, &le));
        check_slabs(&mut NrrdReader::open(&p).unwrap(), &le);
        let fields = nrrd_fields(dtype, dims, "gzip", false);
        let p = write_detached(dir.path(), "s_gz", &fields, &gzip(&le));
        check_slabs(&mut NrrdReader::open(&p).unwrap(), &le);
        let fields = nrrd_fields(dtype, dims, "gzip", true);
        let p = write_attached(
            dir.path(),
            "s_gz_be",
            &fields,
            &gzip(&to_big_endian(dtype, &le)),
        );
        check_slabs(io::open(&p).unwrap().as_mut(), &le);
    }
}

#[test]
fn open_dispatches_on_extension() {
    let dir = TempDir::new().unwrap();
    // a truncated TIFF: the TIFF reader's typed error, or no reader without it
    let p = write(&dir.path().join("x.tiff"), b"II*\0");
    let e = io::open(&p).err().expect("a 4-byte TIFF is refused");
    if cfg!(feature = "tiff") {
        assert!(
            matches!(&e, IoError::Decode { path, .. } if path == &p),
            "{e}"
        );
    } else {
        assert!(
            matches!(&e, IoError::UnknownFormat { path, .. } if path == &p),
            "{e}"
        );
    }
    let p = write(&dir.path().join("noext"), b"");
    assert!(matches!(io::open(&p), Err(IoError::UnknownFormat { .. })));
    let p = write(&dir.path().join("x.xyz"), b"hello");
    assert!(matches!(io::open(&p), Err(IoError::UnknownFormat { .. })));
    // upper-case extensions
    let (le, _) = samples(DType::U8, DIMS, 1);
    let p = write_attached(
        dir.path(),
        "up",
        &nrrd_fields(DType::U8, DIMS, "raw", false),
        &le,
    );
    let up = dir.path().join("UP.NRRD");
    std::fs::rename(&p, &up).unwrap();
    assert_eq!(io::read_volume(&up).unwrap().data().as_bytes(), le);
}

// ---------------------------------------------------------------------------
// The shared data sets.

#[test]
fn shared_data_sets_open_as_declared() {
    let Some(root) = shared_data_root() else {
        return;
    };
    let mut seen = 0;
    let mut entries: Vec<_> = std::fs::read_dir(&root)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    entries.sort();
    for dir in entries.into_iter().filter(|p| p.is_dir()) {
        let name = dir.file_name().unwrap().to_str().unwrap().to_owned();
        let json = dir.join(format!("{name}.json"));
        // `formats/` holds the same volumes in other file formats (no sidecar).
        if !json.is_file() {
            continue;
        }
        let sc: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        let dims: Vec<u32> = sc["dims"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_u64().unwrap() as u32)
            .collect();
        let spacing: Vec<f32> = sc["spacing"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap() as f32)
            .collect();
        let range: Vec<f32> = sc["value_range"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap() as f32)
            .collect();
        let dtype = DType::parse(sc["dtype"].as_str().unwrap()).unwrap();

        let mut r = io::open(&json).unwrap_or_else(|e| panic!("{name}: {e}"));
        let desc = r.desc().clone();
        assert_eq!(desc.dims.as_slice(), dims, "{name}");
        assert_eq!(desc.dtype, dtype, "{name}");
        assert_eq!(desc.spacing.as_slice(), spacing, "{name}");
        assert_eq!(desc.value_range.as_slice(), range, "{name}");
        assert_eq!(desc.byte_len(), sc["bytes"].as_u64().unwrap(), "{name}");
        // stream it slab by slab: every sample finite and within the declared range
        let slice = (desc.dims[0] * desc.dims[1]) as usize * dtype.size();
        let mut buf = vec![0u8; 16 * slice];
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        let mut z = 0;
        while z < desc.dims[2] {
            let z1 = (z + 16).min(desc.dims[2]);
            let out = &mut buf[..(z1 - z) as usize * slice];
            r.read_slices(z, z1, out).unwrap();
            let (a, b, bad) = io::scan_range(dtype, out);
            assert_eq!(bad, None, "{name}: non-finite sample");
            lo = lo.min(a);
            hi = hi.max(b);
            z = z1;
        }
        assert!(
            range[0] <= lo && hi <= range[1],
            "{name}: data {lo}..{hi} outside {range:?}"
        );
        seen += 1;
    }
    assert!(seen >= 4, "expected the four shared volumes, found {seen}");
}
