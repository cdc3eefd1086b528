//! Format version 2's per-node error bounds and version 3's parent-error
//! records: the bounds hold (drawing a node instead of the finest data, or a
//! node's region from its parent's brick, never changes a sample by more than
//! the recorded bound says), version 4 round trip, version-1, -2 and -3
//! stores still open, corrupt error sections are typed errors.
#![allow(missing_docs)]

mod common;

use brickray_core::{
    BrickSource, DType, NodeKey, NodeKind, RenderMode, TfErrorTable, TransferFunction,
    node_tf_error,
};
use brickray_store::{BuildOptions, ERROR_ENTRY_LEN, Filter, StoreError, build, open};
use common::*;
use proptest::prelude::*;
use std::path::Path;

const HEADER_LEN: usize = 128;
const ENTRY_LEN: usize = 48;

/// Trilinear, clamp-to-edge, voxel `k` at coordinate `k`.
fn trilinear(vol: &[f32], d: [u32; 3], p: [f64; 3]) -> f64 {
    let mut i0 = [0usize; 3];
    let mut i1 = [0usize; 3];
    let mut f = [0f64; 3];
    for a in 0..3 {
        let m = (d[a] - 1) as f64;
        let q = p[a].clamp(0.0, m);
        let fl = q.floor();
        i0[a] = fl as usize;
        i1[a] = (i0[a] + 1).min(d[a] as usize - 1);
        f[a] = q - fl;
    }
    let at = |x: usize, y: usize, z: usize| vol[x + d[0] as usize * (y + d[1] as usize * z)] as f64;
    let mut s = 0.0;
    for c in 0..8 {
        let (x, wx) = if c & 1 == 0 {
            (i0[0], 1.0 - f[0])
        } else {
            (i1[0], f[0])
        };
        let (y, wy) = if c & 2 == 0 {
            (i0[1], 1.0 - f[1])
        } else {
            (i1[1], f[1])
        };
        let (z, wz) = if c & 4 == 0 {
            (i0[2], 1.0 - f[2])
        } else {
            (i1[2], f[2])
        };
        s += wx * wy * wz * at(x, y, z);
    }
    s
}

/// The opacity-weighted classified sample.
fn classify(tf: &TransferFunction, v: f64) -> [f64; 4] {
    let c = tf.lookup(v);
    [c[3], c[3] * c[0], c[3] * c[1], c[3] * c[2]]
}

fn volume(dims: [u32; 3], dtype: DType, seed: u64, smooth: f32) -> Vec<u8> {
    let n = dims.iter().map(|&d| d as usize).product::<usize>();
    let mut h = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut v = Vec::with_capacity(n);
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                h ^= h << 13;
                h ^= h >> 7;
                h ^= h << 17;
                let noise = (h % 1000) as f32 / 1000.0;
                let wave = ((x as f32 * 0.7).sin() + (y as f32 * 0.4).cos() + z as f32 * 0.1) / 3.0
                    * 0.5
                    + 0.5;
                let t = smooth * wave + (1.0 - smooth) * noise;
                v.push(match dtype {
                    DType::U8 => (t * 255.0).round().clamp(0.0, 255.0),
                    _ => t * 3.0 - 1.0,
                });
            }
        }
    }
    encode(dtype, &v)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 20, ..ProptestConfig::default() })]

    /// For random volumes, transfer functions and points of every coarser
    /// node, the classified coarse and finest samples differ by at most the
    /// node's DVR error (both placements of coarse voxels: centre at
    /// `k * f` and at `(k + 1/2) * f - 1/2` finest voxels, `f` the level's
    /// voxel factor per axis), in isotropic octrees and in the anisotropic
    /// pyramids of thick-slice volumes.
    #[test]
    fn drawing_a_node_never_exceeds_its_bound(
        dims in proptest::array::uniform3(1u32..14),
        f32_data in any::<bool>(),
        seed in any::<u64>(),
        smooth in 0.0f32..1.0,
        brick in 2u32..6,
        apron in 1u32..3,
        max_filter in any::<bool>(),
        entries in proptest::collection::vec(proptest::array::uniform4(0.0f32..1.0), 2..12),
        pts in proptest::collection::vec(proptest::array::uniform3(0.0f64..1.0), 12),
        slice in prop_oneof![Just(1.0f32), Just(2.0), Just(5.0)],
    ) {
        let dtype = if f32_data { DType::F32 } else { DType::U8 };
        let dir = tempfile::tempdir().unwrap();
        let bytes = volume(dims, dtype, seed, smooth);
        let mut r = MemReader::new(dims, dtype, bytes.clone());
        // Thick slices: an anisotropic pyramid (the finer axes halve first).
        let anisotropic = slice != 1.0;
        r.desc.spacing = [1.0, 1.0, slice];
        let out = dir.path().join("v.brs");
        let filter = if max_filter { Filter::Max } else { Filter::Average };
        let o = BuildOptions { brick, apron, filter, anisotropic, ..BuildOptions::default() };
        let report = build(&mut r, &out, &o).unwrap();
        prop_assert!(report.errors);
        let store = open(&out).unwrap();
        prop_assert!(store.has_errors());
        let layout = store.layout().clone();
        let levels = reference_levels(&layout, decode(dtype, &bytes), filter);
        let tf = TransferFunction::from_entries(entries);
        let table = TfErrorTable::new(&tf);
        let finest = layout.levels - 1;
        let fd = layout.level_dims(finest);
        for rec in store.nodes() {
            let key = rec.key;
            if key.level >= finest || rec.info.kind != NodeKind::Data {
                continue;
            }
            let bound = node_tf_error(&rec.info, RenderMode::Dvr, &table, &layout).unwrap();
            let scale = layout.voxel_factor(key.level);
            let ld = layout.level_dims(key.level);
            for p in &pts {
                // A point of the node's region (level coordinates), inside the level volume.
                let q: [f64; 3] = std::array::from_fn(|a| {
                    let lo = ([key.x, key.y, key.z][a] * brick) as f64;
                    let hi = (lo + brick as f64).min((ld[a] - 1) as f64);
                    lo + (hi - lo).max(0.0) * p[a]
                });
                let c = trilinear(&levels[key.level as usize], ld, q);
                let cv = classify(&tf, layout.volume.normalize(c as f32) as f64);
                for centred in [false, true] {
                    let fq: [f64; 3] = std::array::from_fn(|a| {
                        if centred { (q[a] + 0.5) * scale[a] - 0.5 } else { q[a] * scale[a] }
                    });
                    let f = trilinear(&levels[finest as usize], fd, fq);
                    let fv = classify(&tf, layout.volume.normalize(f as f32) as f64);
                    for ch in 0..4 {
                        prop_assert!(
                            (cv[ch] - fv[ch]).abs() <= bound + 1e-5,
                            "node {key:?} point {q:?} channel {ch}: coarse {c} fine {f}, change {} > bound {bound}",
                            (cv[ch] - fv[ch]).abs()
                        );
                    }
                    // The raw deviation bound itself.
                    let err = rec.info.error.unwrap();
                    let dmax = err.max_deviation(rec.info.min as f64, rec.info.max as f64);
                    let spread = rec.info.max as f64 - rec.info.min as f64;
                    prop_assert!((f - c).abs() <= dmax + 1e-4 * (1.0 + spread), "raw change {} > {dmax}", (f - c).abs());
                }
            }
        }
        // The parent-error records (format version 3): drawing a node's
        // region from its parent's brick never changes a sample by more than
        // the node's record says (raw deviation, over the parent's range).
        for rec in store.nodes() {
            let key = rec.key;
            let Some(parent) = layout.parent(key) else {
                prop_assert!(rec.info.parent_error.is_none());
                continue;
            };
            let pinfo = store.info(parent).unwrap();
            if pinfo.kind != NodeKind::Data || rec.info.kind == NodeKind::Empty {
                continue;
            }
            let pe = rec.info.parent_error.expect("a parent-error record");
            let dmax = pe.max_deviation(pinfo.min as f64, pinfo.max as f64);
            let spread = pinfo.max as f64 - pinfo.min as f64;
            let scale = layout.voxel_factor(parent.level);
            let pd = layout.level_dims(parent.level);
            let m = layout.split_mask(parent.level);
            for p in &pts {
                // A point of the node's region in the parent's level coordinates.
                let q: [f64; 3] = std::array::from_fn(|a| {
                    let r = 1 + ((m >> a) & 1) as u32;
                    let lo = ([key.x, key.y, key.z][a] * brick) as f64 / r as f64;
                    let hi = (lo + brick as f64 / r as f64).min((pd[a] - 1) as f64);
                    lo + (hi - lo).max(0.0) * p[a]
                });
                if q.iter().zip(pd).any(|(v, d)| *v > (d - 1) as f64) {
                    continue;
                }
                let c = trilinear(&levels[parent.level as usize], pd, q);
                for centred in [false, true] {
                    let fq: [f64; 3] = std::array::from_fn(|a| {
                        if centred { (q[a] + 0.5) * scale[a] - 0.5 } else { q[a] * scale[a] }
                    });
                    let f = trilinear(&levels[finest as usize], fd, fq);
                    prop_assert!(
                        (f - c).abs() <= dmax + 1e-4 * (1.0 + spread),
                        "node {key:?} from {parent:?} point {q:?}: raw change {} > {dmax}",
                        (f - c).abs()
                    );
                }
            }
        }
    }
}

fn small_store(dir: &Path) -> (std::path::PathBuf, Vec<u8>) {
    let dims = [12, 10, 7];
    let mut r = MemReader::new(dims, DType::U8, test_volume(dims, DType::U8, 11));
    let out = dir.join("small.brs");
    let o = BuildOptions {
        brick: 4,
        apron: 1,
        ..BuildOptions::default()
    };
    build(&mut r, &out, &o).unwrap();
    let b = std::fs::read(&out).unwrap();
    (out, b)
}

fn u64_at(b: &[u8], o: usize) -> u64 {
    u64::from_le_bytes(b[o..o + 8].try_into().unwrap())
}

fn reseal_header(b: &mut [u8]) {
    let crc = crc32fast::hash(&b[..124]);
    b[124..128].copy_from_slice(&crc.to_le_bytes());
}

fn error_section(b: &[u8]) -> std::ops::Range<usize> {
    let end = (u64_at(b, 80) + u64_at(b, 88)) as usize;
    let len = u64_at(b, 88) as usize / ENTRY_LEN * ERROR_ENTRY_LEN;
    end..end + len
}

/// The parent-error section's entries (its CRC follows them).
fn parent_section(b: &[u8]) -> std::ops::Range<usize> {
    error_section(b).end..b.len() - 4
}

/// The same store as format version 2: no parent-error section (and
/// payload checksums over the payload alone, as before version 4).
fn as_version2(b: &[u8]) -> Vec<u8> {
    let mut v = as_version3(b)[..error_section(b).end].to_vec();
    v[8..12].copy_from_slice(&2u32.to_le_bytes());
    v[30] &= !8;
    reseal_header(&mut v);
    v
}

fn reseal_errors(b: &mut [u8]) {
    let r = error_section(b);
    let crc = crc32fast::hash(&b[r]);
    b[120..124].copy_from_slice(&crc.to_le_bytes());
    reseal_header(b);
}

/// The same store as format version 1: no error section, version 1, flag
/// and error fields cleared.
fn as_version1(b: &[u8]) -> Vec<u8> {
    let mut v = as_version3(b)[..error_section(b).start].to_vec();
    v[8..12].copy_from_slice(&1u32.to_le_bytes());
    v[30] &= !12;
    v[108..124].fill(0);
    reseal_header(&mut v);
    v
}

fn open_bytes(dir: &Path, name: &str, b: &[u8]) -> Result<brickray_store::Store, StoreError> {
    let p = dir.join(name);
    std::fs::write(&p, b).unwrap();
    open(&p)
}

#[test]
fn version_7_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let (path, b) = small_store(dir.path());
    assert_eq!(u32::from_le_bytes(b[8..12].try_into().unwrap()), 7);
    assert_eq!(b[30] & 12, 12, "error and parent-error flags");
    let s = open(&path).unwrap();
    assert_eq!(s.version(), 7);
    // Each payload's checksum covers its node's key (version 4).
    let data: Vec<usize> = entry_offsets(&b)
        .into_iter()
        .filter(|&eo| b[eo + 1] == 2)
        .collect();
    assert!(!data.is_empty());
    for &eo in &data {
        let stored = u32::from_le_bytes(b[eo + 40..eo + 44].try_into().unwrap());
        assert_eq!(stored, keyed_crc(&b, eo, entry_payload(&b, eo)));
        assert_ne!(stored, crc32fast::hash(entry_payload(&b, eo)));
    }
    // A version-3 store (payload checksums over the payload alone) still
    // opens and reads the same bricks; a version-4 checksum in a version-3
    // store, or the reverse, is a checksum error.
    let v3b = as_version3(&b);
    let v3 = open_bytes(dir.path(), "v3.brs", &v3b).unwrap();
    assert_eq!(v3.version(), 3);
    let bb = s.layout().brick_bytes();
    let (mut x, mut y) = (vec![0u8; bb], vec![0u8; bb]);
    for rec in s.nodes() {
        assert_eq!(v3.info(rec.key).unwrap(), rec.info);
        v3.read(rec.key, &mut x).unwrap();
        s.read(rec.key, &mut y).unwrap();
        assert_eq!(x, y);
    }
    for (bytes, version) in [(&b, 3u32), (&v3b, 4)] {
        let mut m = bytes.clone();
        m[8..12].copy_from_slice(&version.to_le_bytes());
        reseal_table_and_header(&mut m);
        let st = open_bytes(dir.path(), "mixed.brs", &m).unwrap();
        let key = st.nodes().find(|r| r.payload_len > 0).unwrap().key;
        assert!(
            matches!(
                st.read(key, &mut x),
                Err(StoreError::PayloadChecksum { key: k, .. }) if k == key
            ),
            "version {version} with the other version's checksums"
        );
    }
    assert!(s.has_errors());
    let n = s.nodes().count();
    assert_eq!(error_section(&b).len(), n * ERROR_ENTRY_LEN);
    assert_eq!(parent_section(&b).len(), n * ERROR_ENTRY_LEN);
    assert_eq!(
        u32::from_le_bytes(b[b.len() - 4..].try_into().unwrap()),
        crc32fast::hash(&b[parent_section(&b)])
    );
    // Every node below a data parent records what drawing it from the
    // parent's brick costs; the root has none.
    let mut some_parent_error = false;
    for rec in s.nodes() {
        match s.layout().parent(rec.key) {
            None => assert_eq!(rec.info.parent_error, None),
            Some(p) => {
                let e = rec.info.parent_error.expect("a parent-error entry");
                if s.info(p).unwrap().kind != NodeKind::Data {
                    assert_eq!(e.occupied, 0, "{:?}", rec.key);
                }
                some_parent_error |= e.dev.iter().any(|&d| d > 0);
            }
        }
    }
    assert!(some_parent_error);
    // A version-2 store (the section and its flag removed) still opens,
    // with the same error records and no parent-error records.
    let v2 = open_bytes(dir.path(), "v2.brs", &as_version2(&b)).unwrap();
    assert_eq!(v2.version(), 2);
    for rec in s.nodes() {
        let i = v2.info(rec.key).unwrap();
        assert_eq!((i.error, i.parent_error), (rec.info.error, None));
    }
    assert_eq!(b[108..120], [0u8; 12], "reserved");
    assert_eq!(
        u32::from_le_bytes(b[120..124].try_into().unwrap()),
        crc32fast::hash(&b[error_section(&b)])
    );
    let finest = s.levels() - 1;
    let mut some_error = false;
    for rec in s.nodes() {
        let e = rec.info.error.expect("every node has an error entry");
        if rec.key.level == finest || rec.info.kind == NodeKind::Empty {
            assert_eq!(e.occupied, 0, "{:?}", rec.key);
        } else {
            assert_ne!(e.occupied, 0, "{:?}", rec.key);
        }
        some_error |= e.dev.iter().any(|&d| d > 0);
        // The typical deviation never exceeds the bound; shares sum to 1.
        for b in 0..brickray_core::ERROR_BINS {
            assert!(e.rms[b] <= e.dev[b], "{:?} bin {b}", rec.key);
            if !e.is_occupied(b) {
                assert_eq!((e.dev[b], e.rms[b], e.weight[b]), (0, 0, 0));
            }
        }
        if e.occupied != 0 {
            let total: f64 = (0..brickray_core::ERROR_BINS).map(|b| e.share(b)).sum();
            assert!(
                (total - 1.0).abs() < 1e-3,
                "{:?}: shares sum to {total}",
                rec.key
            );
        }
        // Through the BrickSource too.
        assert_eq!(s.node(rec.key).unwrap().error, Some(e));
    }
    assert!(some_error, "a noisy volume has coarse error somewhere");
    // Byte-identical on a rebuild (deterministic).
    let dir2 = tempfile::tempdir().unwrap();
    let (_, b2) = small_store(dir2.path());
    assert_eq!(b, b2);
}

#[test]
fn version_1_stores_still_open() {
    let dir = tempfile::tempdir().unwrap();
    let (path, b) = small_store(dir.path());
    let v2 = open(&path).unwrap();
    let v1 = open_bytes(dir.path(), "v1.brs", &as_version1(&b)).unwrap();
    assert_eq!(v1.version(), 1);
    assert!(!v1.has_errors());
    let bb = v1.layout().brick_bytes();
    let (mut x, mut y) = (vec![0u8; bb], vec![0u8; bb]);
    for rec in v2.nodes() {
        let i1 = v1.info(rec.key).unwrap();
        assert_eq!(i1.error, None);
        assert_eq!(
            (i1.kind, i1.min, i1.max),
            (rec.info.kind, rec.info.min, rec.info.max)
        );
        v1.read(rec.key, &mut x).unwrap();
        v2.read(rec.key, &mut y).unwrap();
        assert_eq!(x, y);
    }
    // A version-1 header may not carry the error flag or fields.
    let mut bad = as_version1(&b);
    bad[30] |= 4;
    reseal_header(&mut bad);
    assert!(matches!(
        open_bytes(dir.path(), "bad.brs", &bad),
        Err(StoreError::BadHeader { field: "flags", .. })
    ));
    let mut bad = as_version1(&b);
    bad[121] = 1;
    reseal_header(&mut bad);
    assert!(matches!(
        open_bytes(dir.path(), "bad.brs", &bad),
        Err(StoreError::BadHeader {
            field: "reserved",
            ..
        })
    ));
    // A version-2 header may not carry the parent-error flag.
    let mut bad = as_version2(&b);
    bad[30] |= 8;
    reseal_header(&mut bad);
    assert!(matches!(
        open_bytes(dir.path(), "bad.brs", &bad),
        Err(StoreError::BadHeader { field: "flags", .. })
    ));
    // Version 8 is not read.
    let mut bad = b.clone();
    bad[8..12].copy_from_slice(&8u32.to_le_bytes());
    reseal_header(&mut bad);
    assert!(matches!(
        open_bytes(dir.path(), "bad.brs", &bad),
        Err(StoreError::UnsupportedVersion { version: 8, .. })
    ));
    // The label flag is version 5's: a version-4 header may not carry it.
    let mut bad = b.clone();
    bad[8..12].copy_from_slice(&4u32.to_le_bytes());
    bad[30] |= 16;
    reseal_header(&mut bad);
    assert!(matches!(
        open_bytes(dir.path(), "bad.brs", &bad),
        Err(StoreError::BadHeader { field: "flags", .. })
    ));
}

#[test]
fn corrupt_error_sections_are_typed_errors() {
    let dir = tempfile::tempdir().unwrap();
    let (_, b) = small_store(dir.path());
    let sec = error_section(&b);
    // A flipped byte: checksum.
    let mut bad = b.clone();
    bad[sec.start + 7] ^= 0x40;
    assert!(matches!(
        open_bytes(dir.path(), "c.brs", &bad),
        Err(StoreError::ErrorsChecksum { .. })
    ));
    // A non-zero reserved field, checksum recomputed: names the node.
    let mut bad = b.clone();
    bad[sec.start + 3 * ERROR_ENTRY_LEN + 2] = 1;
    reseal_errors(&mut bad);
    assert!(matches!(
        open_bytes(dir.path(), "c.brs", &bad),
        Err(StoreError::BadNode {
            field: "error reserved",
            ..
        })
    ));
    // Truncated anywhere inside either section: typed.
    for keep in [1, ERROR_ENTRY_LEN, sec.len() - 1] {
        let bad = &b[..sec.start + keep];
        assert!(
            matches!(
                open_bytes(dir.path(), "c.brs", bad),
                Err(StoreError::Truncated {
                    section: "error section",
                    ..
                })
            ),
            "keep {keep}"
        );
    }
    for cut in [1, 4, ERROR_ENTRY_LEN, sec.len() + 3] {
        let bad = &b[..b.len() - cut];
        assert!(
            matches!(
                open_bytes(dir.path(), "c.brs", bad),
                Err(StoreError::Truncated {
                    section: "parent-error section",
                    ..
                })
            ),
            "cut {cut}"
        );
    }
    // A flipped byte in the parent-error section, or its CRC: checksum.
    for at in [parent_section(&b).start + 9, b.len() - 2] {
        let mut bad = b.clone();
        bad[at] ^= 0x10;
        assert!(matches!(
            open_bytes(dir.path(), "c.brs", &bad),
            Err(StoreError::ErrorsChecksum { .. })
        ));
    }
    // The parent-error flag without the error section's: refused.
    let mut bad = b.clone();
    bad[30] &= !4;
    bad[120..124].fill(0);
    reseal_header(&mut bad);
    assert!(matches!(
        open_bytes(dir.path(), "c.brs", &bad),
        Err(StoreError::BadHeader { field: "flags", .. })
    ));
    // Trailing bytes after it.
    let mut bad = b.clone();
    bad.push(0);
    assert!(open_bytes(dir.path(), "c.brs", &bad).is_err());
    // The section's flag cleared with the section present: the file is
    // longer than the store; its CRC without the flag: refused.
    let mut bad = b.clone();
    bad[30] &= !4;
    reseal_header(&mut bad);
    assert!(matches!(
        open_bytes(dir.path(), "c.brs", &bad),
        Err(StoreError::BadHeader { .. })
    ));
    let mut bad = b[..sec.start].to_vec();
    bad[30] &= !12;
    reseal_header(&mut bad);
    assert!(matches!(
        open_bytes(dir.path(), "c.brs", &bad),
        Err(StoreError::BadHeader {
            field: "errors_crc",
            ..
        })
    ));
    // Reserved header bytes 108..120 of version 2.
    let mut bad = b.clone();
    bad[110] = 1;
    reseal_header(&mut bad);
    assert!(matches!(
        open_bytes(dir.path(), "c.brs", &bad),
        Err(StoreError::BadHeader {
            field: "reserved",
            ..
        })
    ));
    // Without the section (flag and fields cleared, bytes removed): a valid
    // version-2 store without error bounds.
    let mut ok = b[..sec.start].to_vec();
    ok[30] &= !12;
    ok[120..124].fill(0);
    reseal_header(&mut ok);
    let s = open_bytes(dir.path(), "ok.brs", &ok).unwrap();
    assert_eq!(s.version(), 7);
    assert!(!s.has_errors());
    let _ = (HEADER_LEN, ENTRY_LEN, NodeKey::ROOT);
}
