//! Helpers of the format tests: the fixtures in `../shared/data/formats/`
//! and the raw volumes they decode to.
#![allow(dead_code)]

use brickray_io::{self as io, VolumeReader};
use std::path::PathBuf;

/// `../shared/data/formats`, or `None` (the test reports itself skipped;
/// never under `CI=true`, where the harness panics instead).
pub(crate) fn formats_dir() -> Option<PathBuf> {
    brickray_harness::shared_data_dir().map(|d| d.join("formats"))
}

/// The raw volume (bytes, spacing, dims, dtype name) named by a shared sidecar.
pub(crate) struct Truth {
    pub(crate) bytes: Vec<u8>,
    pub(crate) desc: brickray_core::VolumeDesc,
    pub(crate) json: serde_json::Value,
}

pub(crate) fn truth(name: &str) -> Truth {
    let json = brickray_harness::shared_volume(name).expect("shared data present");
    let mut r = io::RawReader::open_sidecar(&json).expect("truth sidecar opens");
    let v = r.read_volume().expect("truth volume reads");
    let sc = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    Truth {
        bytes: v.data().as_bytes().to_vec(),
        desc: v.desc().clone(),
        json: sc,
    }
}

/// Reads the whole volume through `read_slices` in slabs of `slab` slices
/// (as the store builder does).
pub(crate) fn read_by_slabs(r: &mut dyn VolumeReader, slab: u32) -> Vec<u8> {
    let d = r.desc().clone();
    let slice = d.dims[0] as usize * d.dims[1] as usize * d.dtype.size();
    let mut out = vec![0u8; slice * d.dims[2] as usize];
    let mut z = 0;
    while z < d.dims[2] {
        let z1 = (z + slab).min(d.dims[2]);
        r.read_slices(z, z1, &mut out[z as usize * slice..z1 as usize * slice])
            .unwrap_or_else(|e| panic!("slab {z}..{z1}: {e}"));
        z = z1;
    }
    out
}

/// Asserts voxel-for-voxel equality, naming the first differing voxel.
pub(crate) fn assert_same_voxels(got: &[u8], want: &Truth, what: &str) {
    assert_eq!(got.len(), want.bytes.len(), "{what}: byte length");
    if got != want.bytes.as_slice() {
        let n = want.desc.dtype.size();
        let i = got
            .chunks(n)
            .zip(want.bytes.chunks(n))
            .position(|(a, b)| a != b)
            .unwrap();
        let [nx, ny, _] = want.desc.dims.map(|v| v as usize);
        panic!(
            "{what}: voxel ({}, {}, {}) differs",
            i % nx,
            (i / nx) % ny,
            i / (nx * ny)
        );
    }
}

/// Spacing equal to the sidecar's within f32 rounding.
pub(crate) fn assert_spacing(got: [f32; 3], want: [f32; 3], what: &str) {
    for a in 0..3 {
        assert!(
            (got[a] - want[a]).abs() <= 1e-5 * want[a].abs().max(1.0),
            "{what}: spacing {got:?}, sidecar says {want:?}"
        );
    }
}
