//! Volume input: round trips through the raw + JSON sidecar and NRRD readers, typed
//! errors for every kind of bad input, a mutation fuzz, and the shared data sets.

use brickray_core::io::{self, IoError, NrrdReader, RawReader, VolumeReader};
use brickray_core::{DType, Volume, VolumeError};
use flate2::Compression;
use flate2::write::GzEncoder;
use std::io::Write;
use std::path::{Path, PathBuf};
use tempfile::TempDir;

const DTYPES: [DType; 4] = [DType::U8, DType::U16, DType::I16, DType::F32];
const DIMS: [u32; 3] = [7, 5, 3];
const SPACING: [f32; 3] = [0.5, 1.25, 3.0];

// ---------------------------------------------------------------------------
// Helpers: deterministic data and writers for both formats.

/// Deterministic samples: little-endian bytes and their values.
fn samples(dtype: DType, dims: [u32; 3], seed: u32) -> (Vec<u8>, Vec<f32>) {
    let n = dims.iter().product::<u32>() as usize;
    let mut state = seed.wrapping_mul(2_654_435_761).wrapping_add(12345);
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        state
    };
    let mut bytes = Vec::with_capacity(n * dtype.size());
    let mut values = Vec::with_capacity(n);
    for _ in 0..n {
        let r = next();
        match dtype {
            DType::U8 => {
                let v = r as u8;
                bytes.push(v);
                values.push(v as f32);
            }
            DType::U16 => {
                let v = r as u16;
                bytes.extend_from_slice(&v.to_le_bytes());
                values.push(v as f32);
            }
            DType::I16 => {
                let v = r as i16;
                bytes.extend_from_slice(&v.to_le_bytes());
                values.push(v as f32);
            }
            DType::F32 => {
                let v = (r as i32) as f32 / 1.0e6;
                bytes.extend_from_slice(&v.to_le_bytes());
                values.push(v);
            }
            _ => unreachable!(),
        }
    }
    (bytes, values)
}

fn f32_bytes(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

fn data_range(values: &[f32]) -> [f32; 2] {
    let lo = values.iter().copied().fold(f32::INFINITY, f32::min);
    let hi = values.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    if hi > lo { [lo, hi] } else { [lo, lo + 1.0] }
}

fn nrrd_type(dtype: DType) -> &'static str {
    match dtype {
        DType::U8 => "uchar",
        DType::U16 => "ushort",
        DType::I16 => "short",
        DType::F32 => "float",
        _ => unreachable!(),
    }
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut enc = GzEncoder::new(Vec::new(), Compression::default());
    enc.write_all(bytes).unwrap();
    enc.finish().unwrap()
}

fn to_big_endian(dtype: DType, le: &[u8]) -> Vec<u8> {
    let mut b = le.to_vec();
    b.chunks_exact_mut(dtype.size()).for_each(|c| c.reverse());
    b
}

fn write(path: &Path, bytes: &[u8]) -> PathBuf {
    std::fs::write(path, bytes).unwrap();
    path.to_owned()
}

/// Writes `name.raw` and a sidecar `name.json` built from `json` (a JSON object).
fn write_sidecar(dir: &Path, name: &str, json: serde_json::Value, raw: &[u8]) -> PathBuf {
    write(&dir.join(format!("{name}.raw")), raw);
    write(
        &dir.join(format!("{name}.json")),
        json.to_string().as_bytes(),
    )
}

fn sidecar_json(dtype: &str, dims: [u64; 3], spacing: [f32; 3]) -> serde_json::Value {
    serde_json::json!({ "dims": dims, "dtype": dtype, "spacing": spacing, "byte_order": "little" })
}

/// The header fields (after the magic) of a 3D NRRD.
fn nrrd_fields(dtype: DType, dims: [u32; 3], encoding: &str, big: bool) -> String {
    format!(
        "type: {}\ndimension: 3\nsizes: {} {} {}\nencoding: {encoding}\nendian: {}\nspacings: {} {} {}\n",
        nrrd_type(dtype),
        dims[0],
        dims[1],
        dims[2],
        if big { "big" } else { "little" },
        SPACING[0],
        SPACING[1],
        SPACING[2],
    )
}

/// Writes an attached NRRD: magic, `fields`, a blank line, then `payload`.
fn write_attached(dir: &Path, name: &str, fields: &str, payload: &[u8]) -> PathBuf {
    let mut b = format!("NRRD0004\n# written by the brickray tests\n{fields}\n").into_bytes();
    b.extend_from_slice(payload);
    write(&dir.join(format!("{name}.nrrd")), &b)
}

/// Writes a detached `name.nhdr` pointing at `name.data`.
fn write_detached(dir: &Path, name: &str, fields: &str, payload: &[u8]) -> PathBuf {
    write(&dir.join(format!("{name}.data")), payload);
    let h = format!("NRRD0004\n{fields}data file: {name}.data\n");
    write(&dir.join(format!("{name}.nhdr")), h.as_bytes())
}

fn check_volume(
    vol: &Volume,
    dtype: DType,
    dims: [u32; 3],
    spacing: [f32; 3],
    le: &[u8],
    values: &[f32],
) {
    let d = vol.desc();
    assert_eq!(d.dims, dims);
    assert_eq!(d.dtype, dtype);
    assert_eq!(vol.data().dtype(), dtype);
    assert_eq!(d.spacing, spacing);
    assert_eq!(vol.data().as_bytes(), le, "sample bytes differ");
    let [nx, ny, nz] = dims.map(i64::from);
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let i = (x + nx * (y + ny * z)) as usize;
                assert_eq!(
                    vol.voxel_clamped(x, y, z).to_bits(),
                    values[i].to_bits(),
                    "voxel {x},{y},{z}"
                );
            }
        }
    }
}

fn err_of(path: &Path) -> IoError {
    match io::read_volume(path) {
        Ok(v) => panic!("{}: expected an error, read {:?}", path.display(), v.desc()),
        Err(e) => e,
    }
}

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
    let p = write(&dir.path().join("x.tiff"), b"II*\0");
    assert!(matches!(io::open(&p), Err(IoError::Unsupported { .. })));
    let p = write(&dir.path().join("noext"), b"");
    assert!(matches!(io::open(&p), Err(IoError::Unsupported { .. })));
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
// Bad input: typed errors, never a panic.

#[test]
fn raw_size_must_match_dims_and_dtype() {
    let dir = TempDir::new().unwrap();
    for dtype in DTYPES {
        let (le, _) = samples(dtype, DIMS, 2);
        let need = le.len() as u64;
        let j = sidecar_json(dtype.name(), DIMS.map(u64::from), SPACING);
        let short = write_sidecar(dir.path(), "short", j.clone(), &le[..le.len() - 1]);
        assert!(
            matches!(err_of(&short), IoError::SizeMismatch { expected, actual, .. } if expected == need && actual == need - 1)
        );
        let mut long = le.clone();
        long.extend_from_slice(&[0; 4]);
        let long = write_sidecar(dir.path(), "long", j.clone(), &long);
        assert!(
            matches!(err_of(&long), IoError::SizeMismatch { expected, actual, .. } if expected == need && actual == need + 4)
        );
        let empty = write_sidecar(dir.path(), "empty", j, &[]);
        assert!(matches!(
            err_of(&empty),
            IoError::SizeMismatch { actual: 0, .. }
        ));
    }
}

#[test]
fn sidecar_errors_are_typed() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let (le, _) = samples(DType::U8, DIMS, 2);
    let case = |name: &str, json: serde_json::Value| err_of(&write_sidecar(d, name, json, &le));
    for ty in ["f64", "double", "int32", "u32", "", "u 8"] {
        let e = case("ty", sidecar_json(ty, [7, 5, 3], SPACING));
        assert!(
            matches!(&e, IoError::UnknownDType { name, .. } if name == ty),
            "{ty}: {e}"
        );
    }
    // names are trimmed and case-insensitive
    assert!(
        io::read_volume(write_sidecar(
            d,
            "ok",
            sidecar_json(" U8 ", [7, 5, 3], SPACING),
            &le
        ))
        .is_ok()
    );
    for dims in [
        [0, 5, 3],
        [7, 0, 3],
        [7, 5, 0],
        [1 << 30, 1, 1],
        [1, 1 << 30, 1],
        [1 << 24, 1 << 24, 1 << 24],
    ] {
        let e = case("dims", sidecar_json("u8", dims, SPACING));
        assert!(
            matches!(
                e,
                IoError::Volume {
                    source: VolumeError::BadDims { .. },
                    ..
                }
            ),
            "{dims:?}: {e}"
        );
    }
    // u64 overflow of the product, and dims beyond u32
    let e = case(
        "dims",
        serde_json::json!({ "dims": [u64::MAX, u64::MAX, 2], "dtype": "u8" }),
    );
    assert!(
        matches!(
            e,
            IoError::Volume {
                source: VolumeError::BadDims { .. },
                ..
            }
        ),
        "{e}"
    );
    let e = case(
        "dims",
        serde_json::json!({ "dims": [1u64 << 33, 1, 1], "dtype": "u8" }),
    );
    assert!(
        matches!(
            e,
            IoError::Volume {
                source: VolumeError::BadDims { .. },
                ..
            }
        ),
        "{e}"
    );
    for dims in [
        serde_json::json!([7, 5]),
        serde_json::json!([7, 5, 3, 1]),
        serde_json::json!([]),
    ] {
        let e = case("ndims", serde_json::json!({ "dims": dims, "dtype": "u8" }));
        assert!(matches!(e, IoError::BadHeader { .. }), "{dims}: {e}");
    }
    for dims in [
        serde_json::json!([7, -5, 3]),
        serde_json::json!([7.5, 5, 3]),
        serde_json::json!("7x5x3"),
    ] {
        let e = case(
            "baddims",
            serde_json::json!({ "dims": dims, "dtype": "u8" }),
        );
        assert!(matches!(e, IoError::BadHeader { .. }), "{dims}: {e}");
    }
    for sp in [[1.0, -1.0, 1.0], [0.0, 1.0, 1.0], [1.0, 1.0, -0.0]] {
        let e = case("sp", sidecar_json("u8", [7, 5, 3], sp));
        assert!(
            matches!(
                e,
                IoError::Volume {
                    source: VolumeError::BadSpacing(_),
                    ..
                }
            ),
            "{sp:?}: {e}"
        );
    }
    let e = case(
        "sp2",
        serde_json::json!({ "dims": [7, 5, 3], "dtype": "u8", "spacing": [1.0, 1.0] }),
    );
    assert!(matches!(e, IoError::BadHeader { .. }), "{e}");
    for vr in [
        serde_json::json!([1.0, 1.0]),
        serde_json::json!([2.0, 1.0]),
        serde_json::json!([1.0]),
    ] {
        let mut j = sidecar_json("u8", [7, 5, 3], SPACING);
        j["value_range"] = vr;
        assert!(matches!(case("vr", j), IoError::BadHeader { .. }));
    }
    let mut j = sidecar_json("u16", [7, 5, 3], SPACING);
    j["byte_order"] = serde_json::json!("big");
    assert!(matches!(case("bo", j), IoError::Unsupported { .. }));
    // malformed JSON: syntax, NaN literal, missing fields, wrong top-level type
    for text in [
        "{ \"dims\": [7, 5, 3], \"dtype\": \"u8\"",
        "{ \"dims\": [7, 5, 3], \"dtype\": \"u8\", \"spacing\": [NaN, 1, 1] }",
        "{ \"dtype\": \"u8\" }",
        "{ \"dims\": [7, 5, 3] }",
        "[7, 5, 3]",
        "",
        "\u{feff}{}",
    ] {
        let p = write(&d.join("m.json"), text.as_bytes());
        assert!(matches!(err_of(&p), IoError::BadHeader { .. }), "{text:?}");
    }
    let p = write(&d.join("bin.json"), &[0xff, 0xfe, b'{', b'}']);
    assert!(matches!(
        err_of(&p),
        IoError::Io { .. } | IoError::BadHeader { .. }
    ));
    // missing files
    assert!(matches!(err_of(&d.join("absent.json")), IoError::Io { .. }));
    let mut j = sidecar_json("u8", [7, 5, 3], SPACING);
    j["file"] = serde_json::json!("absent.raw");
    let p = write(&d.join("nofile.json"), j.to_string().as_bytes());
    assert!(matches!(err_of(&p), IoError::Io { path, .. } if path.ends_with("absent.raw")));
}

fn nrrd_err(dir: &Path, fields: &str, payload: &[u8]) -> IoError {
    err_of(&write_attached(dir, "e", fields, payload))
}

#[test]
fn nrrd_header_errors_are_typed() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let (le, _) = samples(DType::U8, DIMS, 2);
    let ok = "type: uchar\ndimension: 3\nsizes: 7 5 3\nencoding: raw\n";
    assert!(io::read_volume(write_attached(d, "ok", ok, &le)).is_ok());
    let without = |key: &str| {
        ok.lines()
            .filter(|l| !l.starts_with(key))
            .map(|l| format!("{l}\n"))
            .collect::<String>()
    };
    for key in ["type", "sizes", "encoding", "dimension"] {
        let e = nrrd_err(d, &without(key), &le);
        assert!(matches!(e, IoError::BadHeader { .. }), "{key}: {e}");
    }
    // no magic; empty file; magic only
    for bytes in [
        &b"NRRX0004\ntype: uchar\n\n"[..],
        b"",
        b"NRRD0004",
        b"\xff\xfeNRRD0004\n",
    ] {
        let p = write(&d.join("m.nrrd"), bytes);
        assert!(matches!(err_of(&p), IoError::BadHeader { .. }), "{bytes:?}");
    }
    let p = write(&d.join("m.nrrd"), b"NRRD0004\n");
    assert!(matches!(err_of(&p), IoError::BadHeader { .. }));
    for ty in [
        "double",
        "int32",
        "int",
        "uint",
        "long long",
        "block",
        "char",
    ] {
        let f = ok.replace("uchar", ty);
        assert!(
            matches!(nrrd_err(d, &f, &le), IoError::UnknownDType { name, .. } if name == ty),
            "{ty}"
        );
    }
    for enc in ["ascii", "text", "bzip2", "hex", "zstd"] {
        let f = ok.replace("encoding: raw", &format!("encoding: {enc}"));
        assert!(
            matches!(nrrd_err(d, &f, &le), IoError::Unsupported { .. }),
            "{enc}"
        );
    }
    // 2D, 5D and 4D with a non-trivial leading axis
    for (dim, sizes) in [(2, "7 15"), (5, "1 1 7 5 3"), (4, "3 7 5 1"), (1, "105")] {
        let f = ok
            .replace("dimension: 3", &format!("dimension: {dim}"))
            .replace("sizes: 7 5 3", &format!("sizes: {sizes}"));
        assert!(
            matches!(nrrd_err(d, &f, &le), IoError::Unsupported { .. }),
            "{dim}D"
        );
    }
    // sizes not matching dimension, not numbers
    for sizes in ["7 5", "7 5 3 1", "7 -5 3", "7 five 3", "7 5 3.0", ""] {
        let f = ok.replace("sizes: 7 5 3", &format!("sizes: {sizes}"));
        assert!(
            matches!(nrrd_err(d, &f, &le), IoError::BadHeader { .. }),
            "{sizes:?}"
        );
    }
    for dim in ["three", "-3", ""] {
        let f = ok.replace("dimension: 3", &format!("dimension: {dim}"));
        assert!(
            matches!(nrrd_err(d, &f, &le), IoError::BadHeader { .. }),
            "{dim:?}"
        );
    }
    // zero and absurd dims
    for sizes in [
        "0 5 3",
        "7 5 0",
        "1073741824 1 1",
        "16777216 16777216 16777216",
        "18446744073709551615 2 2",
    ] {
        let f = ok.replace("sizes: 7 5 3", &format!("sizes: {sizes}"));
        let e = nrrd_err(d, &f, &le);
        assert!(
            matches!(
                e,
                IoError::Volume {
                    source: VolumeError::BadDims { .. },
                    ..
                }
            ),
            "{sizes}: {e}"
        );
    }
    let e = nrrd_err(
        d,
        &ok.replace("sizes: 7 5 3", "sizes: 99999999999999999999999 1 1"),
        &le,
    );
    assert!(matches!(e, IoError::BadHeader { .. }), "{e}");
    // bad spacing: negative, zero, NaN, Inf, wrong count, zero direction, garbage
    for sp in [
        "spacings: 1 -1 1",
        "spacings: 0 1 1",
        "spacings: 1 nan 1",
        "spacings: inf 1 1",
        "space directions: (1,0,0) (0,0,0) (0,0,1)",
    ] {
        let e = nrrd_err(d, &format!("{ok}{sp}\n"), &le);
        assert!(
            matches!(
                e,
                IoError::Volume {
                    source: VolumeError::BadSpacing(_),
                    ..
                }
            ),
            "{sp}: {e}"
        );
    }
    for sp in [
        "spacings: 1 1",
        "spacings: 1 1 1 1",
        "spacings: a b c",
        "space directions: (1,0,0) (0,1,0)",
        "space directions: (1,0) (0,1,0) (0,0,1)",
        "space directions: (1,x,0) (0,1,0) (0,0,1)",
        "space directions: none (0,1,0) (0,0,1)",
    ] {
        let e = nrrd_err(d, &format!("{ok}{sp}\n"), &le);
        assert!(matches!(e, IoError::BadHeader { .. }), "{sp}: {e}");
    }
    // unparsable line, byte skip, line skip, multi-file data
    assert!(matches!(
        nrrd_err(d, &format!("{ok}what is this\n"), &le),
        IoError::BadHeader { .. }
    ));
    for skip in ["byte skip: 4", "byte skip: -1", "line skip: 2"] {
        assert!(
            matches!(
                nrrd_err(d, &format!("{ok}{skip}\n"), &le),
                IoError::Unsupported { .. }
            ),
            "{skip}"
        );
    }
    assert_eq!(
        io::read_volume(write_attached(
            d,
            "bs0",
            &format!("{ok}byte skip: 0\n"),
            &le
        ))
        .unwrap()
        .data()
        .as_bytes(),
        le
    );
    let p = write(
        &d.join("list.nhdr"),
        format!("NRRD0004\n{ok}data file: LIST\na.raw\n").as_bytes(),
    );
    assert!(matches!(err_of(&p), IoError::Unsupported { .. }));
    let p = write(
        &d.join("fmt.nhdr"),
        format!("NRRD0004\n{ok}data file: s%03d.raw 0 2 1\n").as_bytes(),
    );
    assert!(matches!(err_of(&p), IoError::Unsupported { .. }));
    // detached header naming a file that does not exist
    let p = write(
        &d.join("nodata.nhdr"),
        format!("NRRD0004\n{ok}data file: absent.raw\n").as_bytes(),
    );
    assert!(matches!(err_of(&p), IoError::Io { path, .. } if path.ends_with("absent.raw")));
    let p = write(&d.join("nodata.nhdr"), format!("NRRD0004\n{ok}").as_bytes());
    assert!(matches!(err_of(&p), IoError::Truncated { actual: 0, .. }));
}

#[test]
fn nrrd_header_limit_and_non_text() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let ok = "type: uchar\ndimension: 3\nsizes: 7 5 3\nencoding: raw\n";
    // many comment lines past 1 MiB
    let comments =
        "# padding padding padding padding padding padding\n".repeat((1 << 20) / 50 + 10);
    let e = nrrd_err(d, &format!("{ok}{comments}"), &[0; 105]);
    assert!(matches!(e, IoError::BadHeader { .. }), "{e}");
    // one endless line without a newline, after the magic and in the magic
    let mut b = b"NRRD0004\ntype: ".to_vec();
    b.extend(std::iter::repeat_n(b'a', 3 << 20));
    let p = write(&d.join("long.nrrd"), &b);
    assert!(matches!(err_of(&p), IoError::BadHeader { .. }));
    let mut b = b"NRRD0004".to_vec();
    b.extend(std::iter::repeat_n(b'4', 3 << 20));
    let p = write(&d.join("long.nrrd"), &b);
    assert!(matches!(err_of(&p), IoError::BadHeader { .. }));
    // non-UTF-8 bytes in a field and in a comment
    for bad in [&b"type: \xff\xfe\n"[..], b"# caf\xe9\n", b"\x80\n"] {
        let mut b = b"NRRD0004\n".to_vec();
        b.extend_from_slice(bad);
        b.extend_from_slice(ok.as_bytes());
        b.extend_from_slice(b"\n");
        b.extend_from_slice(&[0; 105]);
        let p = write(&d.join("bin.nrrd"), &b);
        assert!(matches!(err_of(&p), IoError::BadHeader { .. }), "{bad:?}");
    }
    // CRLF line ends are accepted
    let (le, _) = samples(DType::U8, DIMS, 4);
    let mut b = b"NRRD0004\r\n".to_vec();
    b.extend_from_slice(ok.replace('\n', "\r\n").as_bytes());
    b.extend_from_slice(b"\r\n");
    b.extend_from_slice(&le);
    let p = write(&d.join("crlf.nrrd"), &b);
    assert_eq!(io::read_volume(&p).unwrap().data().as_bytes(), le);
}

#[test]
fn nrrd_truncated_data_is_typed() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    for dtype in DTYPES {
        let (le, _) = samples(dtype, DIMS, 5);
        let need = le.len() as u64;
        for detached in [false, true] {
            let fields = nrrd_fields(dtype, DIMS, "raw", false);
            for cut in [0, 1, le.len() / 2, le.len() - 1] {
                let p = if detached {
                    write_detached(d, "t", &fields, &le[..cut])
                } else {
                    write_attached(d, "t", &fields, &le[..cut])
                };
                let e = err_of(&p);
                assert!(
                    matches!(e, IoError::Truncated { expected, actual, .. } if expected == need && actual == cut as u64),
                    "{e}"
                );
            }
            // trailing bytes after the data are tolerated (NRRD readers skip them)
            let mut more = le.clone();
            more.extend_from_slice(b"trailer");
            let p = if detached {
                write_detached(d, "t", &fields, &more)
            } else {
                write_attached(d, "t", &fields, &more)
            };
            assert_eq!(io::read_volume(&p).unwrap().data().as_bytes(), le);
        }
    }
}

#[test]
fn nrrd_truncated_and_corrupt_gzip_are_typed() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let dims = [16, 16, 8];
    for dtype in [DType::U8, DType::F32] {
        let (le, _) = samples(dtype, dims, 6);
        let gz = gzip(&le);
        let fields = nrrd_fields(dtype, dims, "gzip", false);
        let with_range = format!("{fields}min: -1e9\nmax: 1e9\n");
        for f in [&fields, &with_range] {
            // cut inside the gzip header, the deflate data and the CRC/length trailer
            for cut in [
                0,
                5,
                10,
                11,
                gz.len() / 3,
                gz.len() / 2,
                gz.len() - 9,
                gz.len() - 8,
                gz.len() - 4,
                gz.len() - 1,
            ] {
                let p = write_detached(d, "g", f, &gz[..cut]);
                let e = err_of(&p);
                assert!(
                    matches!(e, IoError::Truncated { .. }),
                    "cut {cut}/{}: {e}",
                    gz.len()
                );
                let p = write_attached(d, "g", f, &gz[..cut]);
                assert!(matches!(err_of(&p), IoError::Truncated { .. }), "cut {cut}");
            }
            // a stream that decodes to fewer bytes than announced
            let p = write_attached(d, "short", f, &gzip(&le[..le.len() - 4]));
            let e = err_of(&p);
            assert!(
                matches!(e, IoError::Truncated { expected, actual, .. } if expected == le.len() as u64 && actual == le.len() as u64 - 4),
                "{e}"
            );
            // not gzip at all, bad magic, bad CRC, bad length
            let p = write_attached(d, "raw_as_gz", f, &le);
            assert!(matches!(err_of(&p), IoError::BadHeader { .. }));
            let mut bad = gz.clone();
            bad[0] ^= 0xff;
            assert!(matches!(
                err_of(&write_attached(d, "c", f, &bad)),
                IoError::BadHeader { .. }
            ));
            let n = bad.len();
            for i in [n - 8, n - 5, n - 4, n - 1] {
                let mut bad = gz.clone();
                bad[i] ^= 0x55;
                let e = err_of(&write_attached(d, "c", f, &bad));
                assert!(
                    matches!(e, IoError::BadHeader { .. }),
                    "trailer byte {i}: {e}"
                );
            }
            // corrupt deflate bytes: an error (corrupt or short), never wrong data
            for i in (12..n - 8).step_by((n / 7).max(1)) {
                let mut bad = gz.clone();
                bad[i] ^= 0xa5;
                let e = err_of(&write_attached(d, "c", f, &bad));
                assert!(
                    matches!(e, IoError::BadHeader { .. } | IoError::Truncated { .. }),
                    "byte {i}: {e}"
                );
            }
        }
    }
}

#[test]
fn non_finite_f32_is_typed_in_both_readers() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let (_, mut values) = samples(DType::F32, DIMS, 8);
    // first bad voxel at (3, 2, 1) = index 3 + 7 * (2 + 5 * 1) = 52
    values[52] = f32::NAN;
    values[60] = f32::INFINITY;
    values[104] = f32::NEG_INFINITY;
    let le = f32_bytes(&values);
    let is_nonfinite = |e: &IoError| {
        matches!(
            e,
            IoError::Volume {
                source: VolumeError::NonFinite {
                    count: 3,
                    first: [3, 2, 1]
                },
                ..
            }
        )
    };
    for declared in [false, true] {
        let mut j = sidecar_json("f32", DIMS.map(u64::from), SPACING);
        if declared {
            j["value_range"] = serde_json::json!([0.0, 1.0]);
        }
        let e = err_of(&write_sidecar(d, "nan", j, &le));
        assert!(is_nonfinite(&e), "sidecar declared={declared}: {e}");
        let range = if declared { "min: 0\nmax: 1\n" } else { "" };
        for encoding in ["raw", "gzip"] {
            for big in [false, true] {
                let mut payload = if big {
                    to_big_endian(DType::F32, &le)
                } else {
                    le.clone()
                };
                if encoding == "gzip" {
                    payload = gzip(&payload);
                }
                let f = format!("{}{range}", nrrd_fields(DType::F32, DIMS, encoding, big));
                let e = err_of(&write_attached(d, "nan", &f, &payload));
                assert!(
                    is_nonfinite(&e),
                    "nrrd {encoding} big={big} declared={declared}: {e}"
                );
            }
        }
    }
    // a single NaN in the very last voxel
    let (_, mut values) = samples(DType::F32, DIMS, 8);
    *values.last_mut().unwrap() = f32::NAN;
    let le = f32_bytes(&values);
    let e = err_of(&write_sidecar(
        d,
        "last",
        sidecar_json("f32", DIMS.map(u64::from), SPACING),
        &le,
    ));
    assert!(
        matches!(
            e,
            IoError::Volume {
                source: VolumeError::NonFinite {
                    count: 1,
                    first: [6, 4, 2]
                },
                ..
            }
        ),
        "{e}"
    );
    // integer types never hold non-finite values: 0xFFFF is a valid u16/i16 sample
    let e = io::read_volume(write_sidecar(
        d,
        "ff",
        sidecar_json("u16", DIMS.map(u64::from), SPACING),
        &vec![0xff; 210],
    ));
    assert_eq!(e.unwrap().desc().value_range, [65535.0, 65536.0]);
}

#[test]
fn non_finite_count_spans_the_whole_volume() {
    // Larger than one scan chunk (1 MiB): the count is over all of it.
    let dir = TempDir::new().unwrap();
    let dims = [128u32, 128, 40];
    let n = dims.iter().product::<u32>() as usize;
    let mut values = vec![0.5f32; n];
    let bad = [n / 2 + 3, n / 2 + 4, n - 1, 300_000, 600_000];
    for &i in &bad {
        values[i] = f32::NAN;
    }
    let le = f32_bytes(&values);
    let first = 300_000u32;
    let first = [first % 128, (first / 128) % 128, first / (128 * 128)];
    let ok = |e: &IoError| matches!(e, IoError::Volume { source: VolumeError::NonFinite { count: 5, first: f }, .. } if *f == first);
    let e = err_of(&write_sidecar(
        dir.path(),
        "big",
        sidecar_json("f32", dims.map(u64::from), [1.0; 3]),
        &le,
    ));
    assert!(ok(&e), "{e}");
    let f = nrrd_fields(DType::F32, dims, "gzip", false);
    let e = err_of(&write_attached(dir.path(), "big", &f, &gzip(&le)));
    assert!(ok(&e), "{e}");
}

#[test]
fn forged_sizes_fail_fast_without_allocating() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let t = std::time::Instant::now();
    // beyond the voxel-count limit: rejected from the header alone
    let e = nrrd_err(
        d,
        "type: float\ndimension: 3\nsizes: 100000 100000 100000\nencoding: gzip\n",
        &gzip(&[0; 64]),
    );
    assert!(
        matches!(
            e,
            IoError::Volume {
                source: VolumeError::BadDims { .. },
                ..
            }
        ),
        "{e}"
    );
    let e = nrrd_err(
        d,
        "type: float\ndimension: 3\nsizes: 100000 100000 100000\nencoding: raw\n",
        &[0; 64],
    );
    assert!(
        matches!(
            e,
            IoError::Volume {
                source: VolumeError::BadDims { .. },
                ..
            }
        ),
        "{e}"
    );
    // within the limit but 40 GB (a 40 GB slice!) announced over a few bytes: the
    // size check (raw) and the bounded-memory scan (gzip) find the data missing
    let e = nrrd_err(
        d,
        "type: float\ndimension: 3\nsizes: 100000 100000 1\nencoding: raw\n",
        &[0; 64],
    );
    assert!(
        matches!(
            e,
            IoError::Truncated {
                expected: 40_000_000_000,
                actual: 64,
                ..
            }
        ),
        "{e}"
    );
    let e = nrrd_err(
        d,
        "type: float\ndimension: 3\nsizes: 100000 100000 1\nencoding: gzip\n",
        &gzip(&[0; 64]),
    );
    assert!(
        matches!(
            e,
            IoError::Truncated {
                expected: 40_000_000_000,
                actual: 64,
                ..
            }
        ),
        "{e}"
    );
    let e = nrrd_err(
        d,
        "type: float\ndimension: 3\nsizes: 100000 100000 1\nencoding: gzip\nmin: 0\nmax: 1\n",
        &gzip(&[0; 64]),
    );
    assert!(matches!(e, IoError::Truncated { .. }), "{e}");
    let e = err_of(&write_sidecar(
        d,
        "forged",
        sidecar_json("f32", [100_000, 100_000, 1], [1.0; 3]),
        &[0; 64],
    ));
    assert!(
        matches!(
            e,
            IoError::SizeMismatch {
                expected: 40_000_000_000,
                actual: 64,
                ..
            }
        ),
        "{e}"
    );
    assert!(t.elapsed().as_secs_f64() < 2.0, "took {:?}", t.elapsed());
}

// ---------------------------------------------------------------------------
// Safety: FIFOs and other non-regular files, data files outside the header's
// folder, non-finite declared ranges.

fn mkfifo(path: &Path) {
    let st = std::process::Command::new("mkfifo")
        .arg(path)
        .status()
        .unwrap();
    assert!(st.success(), "mkfifo failed");
}

/// Runs `f` on a thread; fails if it has not returned within 20 s, after
/// unblocking a reader stuck opening `fifo` (by opening its other end), so a
/// regression fails instead of hanging the suite.
fn within<T: Send + 'static>(fifo: &Path, f: impl FnOnce() -> T + Send + 'static) -> T {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    match rx.recv_timeout(std::time::Duration::from_secs(20)) {
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

fn is_not_regular(e: &Result<Volume, IoError>, path: &Path, kind: io::FileKind) -> bool {
    matches!(e, Err(IoError::NotRegularFile { path: p, kind: k }) if p == path && *k == kind)
}

#[test]
fn fifos_and_directories_are_refused_fast() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let t = std::time::Instant::now();
    let (le, _) = samples(DType::U8, DIMS, 3);
    let ok = "type: uchar\ndimension: 3\nsizes: 7 5 3\nencoding: raw\n";
    // The sidecar, the NRRD header: FIFOs.
    for name in ["f.json", "f.nrrd", "f.nhdr"] {
        let fifo = d.join(name);
        mkfifo(&fifo);
        let p = fifo.clone();
        let r = within(&fifo, move || io::read_volume(&p));
        assert!(
            is_not_regular(&r, &fifo, io::FileKind::Fifo),
            "{name}: {r:?}"
        );
    }
    // `.raw` opens its sidecar: a FIFO named `g.json` beside `g.raw`.
    write(&d.join("g.raw"), &le);
    mkfifo(&d.join("g.json"));
    let p = d.join("g.raw");
    let r = within(&d.join("g.json"), move || io::read_volume(&p));
    assert!(
        is_not_regular(&r, &d.join("g.json"), io::FileKind::Fifo),
        "{r:?}"
    );
    // The raw data file named by a sidecar, with and without a declared range.
    for (i, range) in [None, Some([0.0, 255.0])].into_iter().enumerate() {
        let data = d.join(format!("fifo{i}.raw"));
        mkfifo(&data);
        let mut j = sidecar_json("u8", [7, 5, 3], SPACING);
        j["file"] = serde_json::json!(format!("fifo{i}.raw"));
        if let Some(r) = range {
            j["value_range"] = serde_json::json!(r);
        }
        let json = write(&d.join(format!("r{i}.json")), j.to_string().as_bytes());
        let r = within(&data, move || io::read_volume(&json));
        assert!(is_not_regular(&r, &data, io::FileKind::Fifo), "{r:?}");
    }
    // A detached NRRD's data file, raw and gzip.
    for enc in ["raw", "gzip"] {
        let data = d.join(format!("{enc}.data"));
        mkfifo(&data);
        let f = ok.replace("encoding: raw", &format!("encoding: {enc}"));
        let h = write(
            &d.join(format!("{enc}.nhdr")),
            format!("NRRD0004\n{f}data file: {enc}.data\n").as_bytes(),
        );
        let r = within(&data, move || io::read_volume(&h));
        assert!(
            is_not_regular(&r, &data, io::FileKind::Fifo),
            "{enc}: {r:?}"
        );
    }
    // Directories.
    std::fs::create_dir(d.join("dir.json")).unwrap();
    let r = io::read_volume(d.join("dir.json"));
    assert!(
        is_not_regular(&r, &d.join("dir.json"), io::FileKind::Directory),
        "{r:?}"
    );
    std::fs::create_dir(d.join("dir.data")).unwrap();
    let h = write(
        &d.join("dd.nhdr"),
        format!("NRRD0004\n{ok}data file: dir.data\n").as_bytes(),
    );
    let r = io::read_volume(&h);
    assert!(
        is_not_regular(&r, &d.join("dir.data"), io::FileKind::Directory),
        "{r:?}"
    );
    // The low-level constructor too.
    let data = d.join("fifo0.raw");
    let desc = brickray_core::VolumeDesc {
        dims: DIMS,
        dtype: DType::U8,
        spacing: [1.0; 3],
        value_range: [0.0, 1.0],
    };
    let p = data.clone();
    let r = within(&data, move || RawReader::new(p, 0, desc).map(|_| ()));
    assert!(
        matches!(&r, Err(IoError::NotRegularFile { path, kind: io::FileKind::Fifo }) if path == &data),
        "{r:?}"
    );
    assert!(t.elapsed().as_secs_f64() < 10.0, "took {:?}", t.elapsed());
}

#[test]
fn data_files_outside_the_headers_folder_are_refused() {
    let top = TempDir::new().unwrap();
    let d = top.path().join("vol");
    std::fs::create_dir(&d).unwrap();
    std::fs::create_dir(d.join("sub")).unwrap();
    let (le, _) = samples(DType::U8, DIMS, 4);
    // The "secret" outside the folder, of exactly the announced size.
    let secret = write(&top.path().join("secret.raw"), &le);
    std::os::unix::fs::symlink(&secret, d.join("escape.raw")).unwrap();
    write(&d.join("sub").join("in.raw"), &le);
    let outside = |name: &str| -> Vec<String> {
        vec![
            "../secret.raw".to_owned(),
            secret.display().to_string(),
            "sub/../../secret.raw".to_owned(),
            "escape.raw".to_owned(),
            format!("../vol/{name}"),
        ]
    };
    let refused = |e: &IoError, header: &Path| matches!(e, IoError::OutsideDir { path, .. } if path == header);
    // Sidecars.
    for (i, f) in outside("in.raw").iter().enumerate() {
        let mut j = sidecar_json("u8", [7, 5, 3], SPACING);
        j["file"] = serde_json::json!(f);
        let json = write(&d.join(format!("o{i}.json")), j.to_string().as_bytes());
        if f.starts_with("../vol/") {
            // Leaves the folder by name but comes back into it: resolves inside.
            write(&d.join("in.raw"), &le);
            assert_eq!(io::read_volume(&json).unwrap().data().as_bytes(), le);
            continue;
        }
        let e = err_of(&json);
        assert!(refused(&e, &json), "{f}: {e}");
        assert!(
            e.to_string().contains(f.trim_start_matches("sub/"))
                || e.to_string().contains("secret"),
            "{e}"
        );
        // Allowed explicitly.
        let opts = io::ReadOptions::default().allow_outside_dir(true);
        let v = RawReader::open_sidecar_with(&json, &opts)
            .unwrap()
            .read_volume()
            .unwrap();
        assert_eq!(v.data().as_bytes(), le);
        let v = io::open_with(&json, &opts).unwrap().read_volume().unwrap();
        assert_eq!(v.data().as_bytes(), le);
    }
    // A subfolder is inside.
    let mut j = sidecar_json("u8", [7, 5, 3], SPACING);
    j["file"] = serde_json::json!("sub/in.raw");
    let json = write(&d.join("sub.json"), j.to_string().as_bytes());
    assert_eq!(io::read_volume(&json).unwrap().data().as_bytes(), le);
    // NRRD detached data files.
    let ok = "type: uchar\ndimension: 3\nsizes: 7 5 3\nencoding: raw\n";
    for (i, f) in outside("in.raw").iter().enumerate() {
        let h = write(
            &d.join(format!("o{i}.nhdr")),
            format!("NRRD0004\n{ok}data file: {f}\n").as_bytes(),
        );
        if f.starts_with("../vol/") {
            assert_eq!(io::read_volume(&h).unwrap().data().as_bytes(), le);
            continue;
        }
        let e = err_of(&h);
        assert!(refused(&e, &h), "{f}: {e}");
        let opts = io::ReadOptions::default().allow_outside_dir(true);
        let v = NrrdReader::open_with(&h, &opts)
            .unwrap()
            .read_volume()
            .unwrap();
        assert_eq!(v.data().as_bytes(), le);
    }
    let h = write(
        &d.join("sub.nhdr"),
        format!("NRRD0004\n{ok}data file: sub/in.raw\n").as_bytes(),
    );
    assert_eq!(io::read_volume(&h).unwrap().data().as_bytes(), le);
}

#[test]
fn non_finite_declared_ranges_and_spacings_are_typed() {
    let dir = TempDir::new().unwrap();
    let d = dir.path();
    let (le, _) = samples(DType::U8, DIMS, 5);
    let ok = "type: uchar\ndimension: 3\nsizes: 7 5 3\nencoding: raw\n";
    for (min, max) in [
        ("nan", "1"),
        ("0", "nan"),
        ("-inf", "1"),
        ("0", "inf"),
        ("0", "1e39"),
    ] {
        let e = nrrd_err(d, &format!("{ok}min: {min}\nmax: {max}\n"), &le);
        let bad = if min == "0" { "max" } else { "min" };
        assert!(
            matches!(e, IoError::NonFiniteValue { field, value, .. } if field == bad && !value.is_finite()),
            "{min} {max}: {e}"
        );
        let e = nrrd_err(d, &format!("{ok}old min: {min}\nold max: {max}\n"), &le);
        assert!(
            matches!(e, IoError::NonFiniteValue { field, .. } if field == format!("old {bad}")),
            "old {min} {max}: {e}"
        );
    }
    for (min, max) in [("zero", "1"), ("0", "")] {
        let e = nrrd_err(d, &format!("{ok}min: {min}\nmax: {max}\n"), &le);
        assert!(
            matches!(e, IoError::BadHeader { .. }),
            "{min:?} {max:?}: {e}"
        );
    }
    // A flat declared range (min == max, a constant volume) falls back to the data.
    let v = io::read_volume(write_attached(
        d,
        "flat",
        &format!("{ok}min: 3\nmax: 3\n"),
        &le,
    ))
    .unwrap();
    assert!(v.desc().value_range[0] < v.desc().value_range[1]);
    // Spacings that overflow f32 are infinite: typed.
    for sp in [
        "spacings: 1e39 1 1",
        "space directions: (1e39,0,0) (0,1,0) (0,0,1)",
    ] {
        let e = nrrd_err(d, &format!("{ok}{sp}\n"), &le);
        assert!(
            matches!(
                e,
                IoError::Volume {
                    source: VolumeError::BadSpacing(_),
                    ..
                }
            ),
            "{sp}: {e}"
        );
    }
    // Sidecars: JSON has no NaN literal, but 1e39 overflows f32 to infinity.
    let mut j = sidecar_json("u8", [7, 5, 3], SPACING);
    j["spacing"] = serde_json::json!([1.0, 1e39, 1.0]);
    let e = err_of(&write_sidecar(d, "sp", j, &le));
    assert!(
        matches!(
            e,
            IoError::Volume {
                source: VolumeError::BadSpacing(_),
                ..
            }
        ),
        "{e}"
    );
    for vr in [
        serde_json::json!([0.0, 1e39]),
        serde_json::json!([-1e39, 0.0]),
    ] {
        let mut j = sidecar_json("u8", [7, 5, 3], SPACING);
        j["value_range"] = vr.clone();
        let e = err_of(&write_sidecar(d, "vr", j, &le));
        assert!(
            matches!(e, IoError::NonFiniteValue { field: "value_range", value, .. } if value.is_infinite()),
            "{vr}: {e}"
        );
    }
}

// ---------------------------------------------------------------------------
// Fuzz: mutated headers and data never panic and never allocate absurdly.

mod fuzz {
    use super::*;
    use proptest::prelude::*;

    #[derive(Debug, Clone)]
    enum Mutation {
        Flip(usize, u8),
        Truncate(usize),
        InsertLine(usize, String),
        Replace(usize, u8),
    }

    fn mutation() -> impl Strategy<Value = Mutation> {
        prop_oneof![
            (any::<usize>(), 0u8..8).prop_map(|(i, b)| Mutation::Flip(i, b)),
            any::<usize>().prop_map(Mutation::Truncate),
            (
                any::<usize>(),
                prop_oneof![
                    Just("sizes: 100000 100000 100000".to_owned()),
                    Just("sizes: 65536 65536 1".to_owned()),
                    Just("dimension: 4".to_owned()),
                    Just("type: double".to_owned()),
                    Just("encoding: gzip".to_owned()),
                    Just("endian: big".to_owned()),
                    Just("spacings: nan nan nan".to_owned()),
                    Just("space directions: (0,0,0) (1,1,1) none".to_owned()),
                    Just("data file: /nonexistent".to_owned()),
                    Just("\"dims\": [4294967295, 4294967295, 4294967295],".to_owned()),
                    Just("\"dims\": [65536, 65536, 1],".to_owned()),
                    "[ -~]{0,40}",
                ]
            )
                .prop_map(|(i, s)| Mutation::InsertLine(i, s)),
            (any::<usize>(), any::<u8>()).prop_map(|(i, b)| Mutation::Replace(i, b)),
        ]
    }

    fn apply(mut b: Vec<u8>, muts: &[Mutation]) -> Vec<u8> {
        for m in muts {
            if b.is_empty() {
                break;
            }
            match m {
                Mutation::Flip(i, bit) => {
                    let n = b.len();
                    b[i % n] ^= 1 << bit;
                }
                Mutation::Truncate(i) => {
                    let n = b.len();
                    b.truncate(i % n);
                }
                Mutation::InsertLine(i, s) => {
                    // at a line start
                    let n = b.len();
                    let mut at = i % n;
                    while at > 0 && b[at - 1] != b'\n' {
                        at -= 1;
                    }
                    let line = format!("{s}\n");
                    b.splice(at..at, line.into_bytes());
                }
                Mutation::Replace(i, v) => {
                    let n = b.len();
                    b[i % n] = *v;
                }
            }
        }
        b
    }

    fn check(path: &Path) {
        // Either outcome is fine; a panic or an abort on allocation fails the test.
        if let Ok(v) = io::read_volume(path) {
            let desc = v.desc();
            assert!(desc.byte_len() <= 1 << 20, "{desc:?}");
            assert!(desc.spacing.iter().all(|s| s.is_finite() && *s > 0.0));
            assert!(desc.value_range[0] < desc.value_range[1]);
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 160, failure_persistence: None, ..ProptestConfig::default() })]

        #[test]
        fn mutated_nrrd_never_panics(muts in proptest::collection::vec(mutation(), 1..4), gz in any::<bool>(), f32s in any::<bool>()) {
            let dir = TempDir::new().unwrap();
            let dtype = if f32s { DType::F32 } else { DType::I16 };
            let (le, _) = samples(dtype, [5, 4, 3], 11);
            let payload = if gz { gzip(&le) } else { le.clone() };
            let fields = format!("{}min: -10\nmax: 10\n", nrrd_fields(dtype, [5, 4, 3], if gz { "gzip" } else { "raw" }, false));
            let mut b = format!("NRRD0004\n{fields}\n").into_bytes();
            b.extend_from_slice(&payload);
            let p = write(&dir.path().join("f.nrrd"), &apply(b, &muts));
            check(&p);
            // the same mutations on a detached header
            let h = format!("NRRD0004\n{fields}data file: f.data\n").into_bytes();
            write(&dir.path().join("f.data"), &payload);
            let p = write(&dir.path().join("f.nhdr"), &apply(h, &muts));
            check(&p);
        }

        #[test]
        fn mutated_sidecar_never_panics(muts in proptest::collection::vec(mutation(), 1..4)) {
            let dir = TempDir::new().unwrap();
            let (le, _) = samples(DType::U16, [5, 4, 3], 12);
            write(&dir.path().join("s.raw"), &le);
            let j = serde_json::to_string_pretty(&serde_json::json!({
                "dims": [5, 4, 3], "dtype": "u16", "spacing": [1.0, 2.0, 0.5],
                "file": "s.raw", "byte_order": "little", "value_range": [0.0, 65535.0]
            })).unwrap();
            let p = write(&dir.path().join("s.json"), &apply(j.into_bytes(), &muts));
            check(&p);
        }
    }
}

// ---------------------------------------------------------------------------
// The shared data sets.

#[test]
fn shared_data_sets_open_as_declared() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    if !root.is_dir() {
        let msg = format!("shared data directory {} is missing", root.display());
        if std::env::var("CI").as_deref() == Ok("true") {
            panic!("{msg}");
        }
        eprintln!("skipping: {msg}");
        return;
    }
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
