//! Helpers shared by the volume-input tests: deterministic data and writers for
//! both formats, and checks of what a reader returns.
#![allow(dead_code)]

use brickray_core::{DType, Volume};
use brickray_io::{self as io, IoError};
use flate2::Compression;
use flate2::write::GzEncoder;
use std::io::Write;
use std::path::{Path, PathBuf};

pub(crate) const DTYPES: [DType; 4] = [DType::U8, DType::U16, DType::I16, DType::F32];
pub(crate) const DIMS: [u32; 3] = [7, 5, 3];
pub(crate) const SPACING: [f32; 3] = [0.5, 1.25, 3.0];

// ---------------------------------------------------------------------------
// Helpers: deterministic data and writers for both formats.

/// Deterministic samples: little-endian bytes and their values.
pub(crate) fn samples(dtype: DType, dims: [u32; 3], seed: u32) -> (Vec<u8>, Vec<f32>) {
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

pub(crate) fn f32_bytes(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

pub(crate) fn data_range(values: &[f32]) -> [f32; 2] {
    let lo = values.iter().copied().fold(f32::INFINITY, f32::min);
    let hi = values.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    if hi > lo { [lo, hi] } else { [lo, lo + 1.0] }
}

pub(crate) fn nrrd_type(dtype: DType) -> &'static str {
    match dtype {
        DType::U8 => "uchar",
        DType::U16 => "ushort",
        DType::I16 => "short",
        DType::F32 => "float",
        _ => unreachable!(),
    }
}

pub(crate) fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut enc = GzEncoder::new(Vec::new(), Compression::default());
    enc.write_all(bytes).unwrap();
    enc.finish().unwrap()
}

pub(crate) fn to_big_endian(dtype: DType, le: &[u8]) -> Vec<u8> {
    let mut b = le.to_vec();
    b.chunks_exact_mut(dtype.size()).for_each(|c| c.reverse());
    b
}

pub(crate) fn write(path: &Path, bytes: &[u8]) -> PathBuf {
    std::fs::write(path, bytes).unwrap();
    path.to_owned()
}

/// Writes `name.raw` and a sidecar `name.json` built from `json` (a JSON object).
pub(crate) fn write_sidecar(
    dir: &Path,
    name: &str,
    json: serde_json::Value,
    raw: &[u8],
) -> PathBuf {
    write(&dir.join(format!("{name}.raw")), raw);
    write(
        &dir.join(format!("{name}.json")),
        json.to_string().as_bytes(),
    )
}

pub(crate) fn sidecar_json(dtype: &str, dims: [u64; 3], spacing: [f32; 3]) -> serde_json::Value {
    serde_json::json!({ "dims": dims, "dtype": dtype, "spacing": spacing, "byte_order": "little" })
}

/// The header fields (after the magic) of a 3D NRRD.
pub(crate) fn nrrd_fields(dtype: DType, dims: [u32; 3], encoding: &str, big: bool) -> String {
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
pub(crate) fn write_attached(dir: &Path, name: &str, fields: &str, payload: &[u8]) -> PathBuf {
    let mut b = format!("NRRD0004\n# written by the brickray tests\n{fields}\n").into_bytes();
    b.extend_from_slice(payload);
    write(&dir.join(format!("{name}.nrrd")), &b)
}

/// Writes a detached `name.nhdr` pointing at `name.data`.
pub(crate) fn write_detached(dir: &Path, name: &str, fields: &str, payload: &[u8]) -> PathBuf {
    write(&dir.join(format!("{name}.data")), payload);
    let h = format!("NRRD0004\n{fields}data file: {name}.data\n");
    write(&dir.join(format!("{name}.nhdr")), h.as_bytes())
}

pub(crate) fn check_volume(
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

pub(crate) fn err_of(path: &Path) -> IoError {
    match io::read_volume(path) {
        Ok(v) => panic!("{}: expected an error, read {:?}", path.display(), v.desc()),
        Err(e) => e,
    }
}

/// The error of opening an NRRD with `fields` and `payload` in `dir`.
pub(crate) fn nrrd_err(dir: &Path, fields: &str, payload: &[u8]) -> IoError {
    err_of(&write_attached(dir, "e", fields, payload))
}

/// `../shared/data`, or `None` (the caller returns) when it is absent; with
/// `CI=true` its absence fails the test.
#[allow(dead_code)]
pub(crate) fn shared_data_root() -> Option<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    if !root.is_dir() {
        let msg = format!("shared data directory {} is missing", root.display());
        if std::env::var("CI").as_deref() == Ok("true") {
            panic!("{msg}");
        }
        eprintln!("skipping: {msg}");
        return None;
    }
    Some(root)
}
