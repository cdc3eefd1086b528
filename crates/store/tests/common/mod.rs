//! Test helpers: an in-memory reader, a naive reference pyramid and a checker.
#![allow(dead_code, unreachable_pub, missing_docs)]

use brickray_core::{BrickSource, DType, NodeKey, NodeKind, VolumeDesc};
use brickray_io::{IoError, VolumeReader};
use brickray_store::Filter;
use std::path::{Path, PathBuf};

/// A volume in memory as LE bytes.
#[derive(Debug, Clone)]
pub struct MemReader {
    pub desc: VolumeDesc,
    pub bytes: Vec<u8>,
    pub path: PathBuf,
    /// Fail when asked for a slice at or past this z (simulates an interruption).
    pub fail_at: Option<u32>,
}

impl MemReader {
    pub fn new(dims: [u32; 3], dtype: DType, bytes: Vec<u8>) -> MemReader {
        assert_eq!(
            bytes.len(),
            dims.iter().map(|&d| d as usize).product::<usize>() * dtype.size()
        );
        let (lo, hi) = if bytes.is_empty() {
            (0.0, 1.0)
        } else {
            range(dtype, &bytes)
        };
        let desc = VolumeDesc {
            dims,
            dtype,
            spacing: [1.0, 0.5, 2.0],
            value_range: [lo, hi.max(lo + 1.0)],
            kind: Default::default(),
        };
        MemReader {
            desc,
            bytes,
            path: PathBuf::from("<memory>"),
            fail_at: None,
        }
    }
}

pub fn range(dtype: DType, bytes: &[u8]) -> (f32, f32) {
    let v = decode(dtype, bytes);
    v.iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        })
}

impl VolumeReader for MemReader {
    fn desc(&self) -> &VolumeDesc {
        &self.desc
    }
    fn read_slices(&mut self, z0: u32, z1: u32, out: &mut [u8]) -> Result<(), IoError> {
        if self.fail_at.is_some_and(|f| z1 > f) {
            return Err(IoError::BadSlab { z0, z1, depth: 0 });
        }
        let slice = (self.desc.dims[0] * self.desc.dims[1]) as usize * self.desc.dtype.size();
        out.copy_from_slice(&self.bytes[z0 as usize * slice..z1 as usize * slice]);
        Ok(())
    }
    fn path(&self) -> &Path {
        &self.path
    }
}

pub fn decode(dtype: DType, b: &[u8]) -> Vec<f32> {
    dtype.decode_le(b)
}

pub fn encode(dtype: DType, v: &[f32]) -> Vec<u8> {
    let mut out = Vec::with_capacity(v.len() * dtype.size());
    for &x in v {
        match dtype {
            DType::U8 => out.push(x as u8),
            DType::U16 => out.extend_from_slice(&(x as u16).to_le_bytes()),
            DType::I16 => out.extend_from_slice(&(x as i16).to_le_bytes()),
            DType::U32 => out.extend_from_slice(&(x as u32).to_le_bytes()),
            _ => out.extend_from_slice(&x.to_le_bytes()),
        }
    }
    out
}

/// A deterministic test volume with smooth regions, constant regions and noise.
pub fn test_volume(dims: [u32; 3], dtype: DType, seed: u64) -> Vec<u8> {
    let mut v = Vec::with_capacity(dims.iter().map(|&d| d as usize).product());
    let mut h = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                h ^= h << 13;
                h ^= h >> 7;
                h ^= h << 17;
                let noise = (h % 7) as f32;
                // A constant block (uniform bricks) where x < dims/3.
                let val = if x * 3 < dims[0] {
                    5.0
                } else {
                    ((x as f32 * 0.37).sin() + (y as f32 * 0.21).cos() + z as f32 * 0.05) * 40.0
                        + 100.0
                        + noise
                };
                v.push(match dtype {
                    DType::U8 => val.clamp(0.0, 255.0).round(),
                    DType::U16 => (val * 200.0).clamp(0.0, 65535.0).round(),
                    DType::I16 => (val * 50.0 - 6000.0).round(),
                    _ => val * 0.013 - 0.7,
                });
            }
        }
    }
    encode(dtype, &v)
}

/// The reference pyramid: level volumes coarse (0) to fine, as f32 values.
pub fn reference_levels(
    layout: &brickray_core::OctreeLayout,
    finest: Vec<f32>,
    filter: Filter,
) -> Vec<Vec<f32>> {
    let n = layout.levels as usize;
    let mut levels = vec![Vec::new(); n];
    levels[n - 1] = finest;
    for l in (0..n - 1).rev() {
        let fd = layout.level_dims(l as u8 + 1).map(|d| d as usize);
        let cd = layout.level_dims(l as u8).map(|d| d as usize);
        let fine = &levels[l + 1];
        // Axes this step halves; a kept axis reads the same fine voxel twice.
        let m = layout.split_mask(l as u8);
        let f = [0, 1, 2].map(|a| if m & (1 << a) != 0 { 2 } else { 1 });
        let mut out = Vec::with_capacity(cd[0] * cd[1] * cd[2]);
        for k in 0..cd[2] {
            for j in 0..cd[1] {
                for i in 0..cd[0] {
                    let mut v = [0f32; 8];
                    let mut c = 0;
                    for dz in 0..2 {
                        for dy in 0..2 {
                            for dx in 0..2 {
                                let x = (f[0] * i + dx * (f[0] - 1)).min(fd[0] - 1);
                                let y = (f[1] * j + dy * (f[1] - 1)).min(fd[1] - 1);
                                let z = (f[2] * k + dz * (f[2] - 1)).min(fd[2] - 1);
                                v[c] = fine[x + fd[0] * (y + fd[1] * z)];
                                c += 1;
                            }
                        }
                    }
                    out.push(filter_ref(layout.dtype(), filter, v));
                }
            }
        }
        levels[l] = out;
    }
    levels
}

pub fn filter_ref(dtype: DType, filter: Filter, v: [f32; 8]) -> f32 {
    match filter {
        Filter::Max => v.iter().copied().fold(f32::NEG_INFINITY, f32::max),
        Filter::Mode => brickray_core::labels::mode_of(&mut v.map(|x| x as u32)) as f32,
        _ => match dtype {
            DType::F32 => (v.iter().map(|&x| x as f64).sum::<f64>() / 8.0) as f32,
            _ => {
                let s: i64 = v.iter().map(|&x| x as i64).sum();
                (s + 4).div_euclid(8) as f32
            }
        },
    }
}

/// The expected stored brick of `key` from the reference level volume.
pub fn expected_brick(
    layout: &brickray_core::OctreeLayout,
    level: &[f32],
    key: NodeKey,
) -> Vec<f32> {
    let d = layout.level_dims(key.level).map(|d| d as i64);
    let b = layout.brick as i64;
    let a = layout.apron as i64;
    let s = layout.stored_side() as i64;
    let o = [key.x, key.y, key.z].map(|c| c as i64 * b - a);
    let mut out = Vec::with_capacity((s * s * s) as usize);
    for k in 0..s {
        for j in 0..s {
            for i in 0..s {
                let x = (o[0] + i).clamp(0, d[0] - 1);
                let y = (o[1] + j).clamp(0, d[1] - 1);
                let z = (o[2] + k).clamp(0, d[2] - 1);
                out.push(level[(x + d[0] * (y + d[1] * z)) as usize]);
            }
        }
    }
    out
}

/// Checks every node of `src` against the reference pyramid: bricks equal,
/// min/max conservative (own voxels and subtree), kinds consistent.
pub fn check_source(src: &dyn BrickSource, levels: &[Vec<f32>], threshold: Option<f32>) {
    let layout = src.layout().clone();
    let dtype = layout.dtype();
    let mut buf = vec![0u8; layout.brick_bytes()];
    for l in (0..layout.levels).rev() {
        let n = layout.nodes_per_axis(l).map(|n| n as u32);
        let ld = layout.level_dims(l);
        let g = ld.map(|d| d.div_ceil(layout.brick));
        for z in 0..n[2].min(g[2] + 1) {
            for y in 0..n[1].min(g[1] + 1) {
                for x in 0..n[0].min(g[0] + 1) {
                    let key = NodeKey::new(l, x, y, z);
                    let info = src.node(key).unwrap();
                    src.read_brick(key, &mut buf).unwrap();
                    if !layout.in_volume(key) {
                        assert_eq!(info.kind, NodeKind::Empty, "{key:?}");
                        continue;
                    }
                    let want = expected_brick(&layout, &levels[l as usize], key);
                    let (lo, hi) = want
                        .iter()
                        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| {
                            (a.min(v), b.max(v))
                        });
                    assert!(
                        info.min <= lo && info.max >= hi,
                        "{key:?}: [{}, {}] does not cover [{lo}, {hi}]",
                        info.min,
                        info.max
                    );
                    if l + 1 < layout.levels {
                        for &c in layout.children(key).iter() {
                            if layout.in_volume(c) {
                                let ci = src.node(c).unwrap();
                                assert!(
                                    info.min <= ci.min && info.max >= ci.max,
                                    "{key:?} range does not cover child {c:?}"
                                );
                            }
                        }
                    }
                    match info.kind {
                        NodeKind::Empty => {
                            let t = threshold.expect("empty in-volume node without a threshold");
                            assert!(info.max < t, "{key:?} empty but max {} >= {t}", info.max);
                        }
                        NodeKind::Uniform(v) => {
                            assert!(
                                want.iter().all(|&w| w == v),
                                "{key:?} uniform {v} but voxels differ"
                            );
                            assert_eq!(decode(dtype, &buf), want, "{key:?}");
                        }
                        NodeKind::Data => {
                            let got = decode(dtype, &buf);
                            if got != want {
                                let i = got.iter().zip(&want).position(|(a, b)| a != b).unwrap();
                                panic!(
                                    "{key:?}: stored voxel {i} is {} expected {}",
                                    got[i], want[i]
                                );
                            }
                        }
                    }
                }
            }
        }
    }
}

/// `../shared/data` next to the workspace, or `None` (FAILS when CI=true).
pub fn shared_data() -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    if p.is_dir() {
        return Some(p);
    }
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!(
            "shared data not found at {} (required when CI=true)",
            p.display()
        );
    }
    eprintln!("skipping: shared data not found at {}", p.display());
    None
}

// ---------------------------------------------------------------------------
// Store bytes, as a forger edits them (offsets from docs/store-format.md).

fn le_u64(b: &[u8], o: usize) -> u64 {
    u64::from_le_bytes(b[o..o + 8].try_into().unwrap())
}

/// File offsets of the node table's entries.
pub fn entry_offsets(b: &[u8]) -> Vec<usize> {
    let off = le_u64(b, 80) as usize;
    (off..off + le_u64(b, 88) as usize).step_by(48).collect()
}

/// The compressed payload of the entry at file offset `eo`.
pub fn entry_payload(b: &[u8], eo: usize) -> &[u8] {
    let len = u32::from_le_bytes(b[eo + 28..eo + 32].try_into().unwrap()) as usize;
    let off = le_u64(b, eo + 32) as usize;
    &b[off..off + len]
}

/// A payload checksum of format version 4 for the entry at file offset
/// `eo`: CRC-32 of the node's key (level byte, then x, y, z as LE u32: the
/// entry's bytes 0 and 4..16) followed by the payload.
pub fn keyed_crc(b: &[u8], eo: usize, payload: &[u8]) -> u32 {
    let mut h = crc32fast::Hasher::new();
    h.update(&b[eo..eo + 1]);
    h.update(&b[eo + 4..eo + 16]);
    h.update(payload);
    h.finalize()
}

/// Recomputes the node table's checksum, then the header's.
pub fn reseal_table_and_header(b: &mut [u8]) {
    let off = le_u64(b, 80) as usize;
    let len = le_u64(b, 88) as usize;
    let crc = crc32fast::hash(&b[off..off + len]);
    b[104..108].copy_from_slice(&crc.to_le_bytes());
    let crc = crc32fast::hash(&b[..124]);
    b[124..128].copy_from_slice(&crc.to_le_bytes());
}

/// An intensity store of version 4 or later (keyed checksums) as format
/// version 3 wrote it: the version field 3 and each payload's checksum over
/// its payload alone.
pub fn as_version3(b: &[u8]) -> Vec<u8> {
    assert!(u32::from_le_bytes(b[8..12].try_into().unwrap()) >= 4);
    let mut v = b.to_vec();
    v[8..12].copy_from_slice(&3u32.to_le_bytes());
    for eo in entry_offsets(b) {
        if b[eo + 1] == 2 {
            let crc = crc32fast::hash(entry_payload(b, eo));
            v[eo + 40..eo + 44].copy_from_slice(&crc.to_le_bytes());
        }
    }
    reseal_table_and_header(&mut v);
    v
}
