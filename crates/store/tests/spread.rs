//! The spread section (format version 7): a store built with
//! `BuildOptions::spread` serves each coarse voxel's spread
//! (`BrickSource::read_spread`) bit for bit as the in-memory reference
//! (`brickray_core::SpreadSource`) computes it; stores without it read
//! zeros; damage is a typed error.
#![allow(missing_docs)]

mod common;

use brickray_core::{
    BrickError, BrickSource, DType, NodeKey, SpreadSource, Volume, VolumeData, VolumeKind,
};
use brickray_store::{BuildOptions, Filter, Store, StoreError, build, open};
use common::*;
use proptest::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::Arc;

const FLAGS: usize = 30;
const FLAG_SPREAD: u8 = 64;

/// A volume of `dims` whose values mix a smooth field, noise and a constant
/// block (so that some coarse bricks spread nowhere and have no payload).
fn noisy_volume(dims: [u32; 3], dtype: DType, seed: u64) -> Vec<u8> {
    let base = decode(dtype, &test_volume(dims, dtype, seed));
    let mut h = seed.wrapping_mul(0x2545_F491_4F6C_DD1D) | 1;
    let v: Vec<f32> = base
        .iter()
        .enumerate()
        .map(|(i, &x)| {
            h ^= h << 13;
            h ^= h >> 7;
            h ^= h << 17;
            // Half the voxels get extra noise of the dtype's scale.
            if i % 2 == 0 || x == base[0] {
                return x;
            }
            let n = (h % 1000) as f32 / 1000.0;
            match dtype {
                DType::U8 => (x + n * 60.0).clamp(0.0, 255.0).round(),
                DType::U16 => (x + n * 9000.0).clamp(0.0, 65535.0).round(),
                DType::I16 => (x + n * 3000.0).clamp(-32768.0, 32767.0).round(),
                _ => x + n * 0.5,
            }
        })
        .collect();
    encode(dtype, &v)
}

/// The volume `reader` holds, as `SpreadSource` takes it.
fn volume_of(r: &MemReader) -> Volume {
    Volume::new(
        r.desc.clone(),
        VolumeData::from_le_bytes(r.desc.dtype, &r.bytes),
    )
    .unwrap()
}

struct Built {
    plain: PathBuf,
    spread: PathBuf,
    volume: Volume,
}

/// Builds `reader`'s volume twice into `dir`: without and with spreads.
fn build_both(dir: &Path, name: &str, reader: &MemReader, opts: &BuildOptions) -> Built {
    let plain = dir.join(format!("{name}.brs"));
    let spread = dir.join(format!("{name}.spread.brs"));
    let r = build(&mut reader.clone(), &plain, opts).unwrap();
    assert!(!r.spread && r.spread_bytes == 0);
    let o = BuildOptions {
        spread: true,
        ..opts.clone()
    };
    let r = build(&mut reader.clone(), &spread, &o).unwrap();
    assert!(r.spread);
    assert_eq!(r.file_bytes, std::fs::metadata(&spread).unwrap().len());
    Built {
        plain,
        spread,
        volume: volume_of(reader),
    }
}

/// Every node of the octree cube that overlaps the volume, and one past
/// each level's grid where the cube has room (outside the volume: zeros).
fn keys(store: &Store) -> Vec<NodeKey> {
    let lay = store.layout();
    let mut out: Vec<NodeKey> = store.nodes().map(|r| r.key).collect();
    for l in 0..lay.levels {
        let g = store.grid(l).unwrap();
        let n = lay.nodes_per_axis(l);
        if (g[0] as u64) < n[0] {
            out.push(NodeKey::new(l, g[0], 0, 0));
        }
    }
    out
}

fn spreads(src: &dyn BrickSource, key: NodeKey) -> Vec<u16> {
    let side = src.layout().stored_side() as usize;
    let mut out = vec![0x1234u16; side * side * side];
    src.read_spread(key, &mut out).unwrap();
    out
}

/// Compares every node's spreads of the store at `path` with the reference
/// built over `plain` (bit for bit); returns how many voxels spread.
fn check_against_reference(b: &Built, what: &str) -> usize {
    let plain = open(&b.plain).unwrap();
    let store = open(&b.spread).unwrap();
    assert!(
        store.has_spread() && BrickSource::has_spread(&store),
        "{what}"
    );
    assert!(!plain.has_spread(), "{what}");
    assert_eq!(store.version(), 7);
    let reference = SpreadSource::new(Arc::new(plain), &b.volume).unwrap();
    let finest = store.levels() - 1;
    let mut spreading = 0;
    for key in keys(&store) {
        let got = spreads(&store, key);
        let want = spreads(&reference, key);
        if got != want {
            let i = got.iter().zip(&want).position(|(a, b)| a != b).unwrap();
            panic!(
                "{what}: node {key:?} voxel {i}: {:#06x} ({}) against the reference's {:#06x} ({})",
                got[i],
                half::f16::from_bits(got[i]),
                want[i],
                half::f16::from_bits(want[i])
            );
        }
        if key.level == finest {
            assert!(got.iter().all(|&s| s == 0), "{what}: {key:?}");
        }
        spreading += got.iter().filter(|&&s| s != 0).count();
    }
    spreading
}

/// (a) Random volumes of every intensity dtype, odd dims, isotropic and
/// anisotropic pyramids of non-cubic voxels, bricks of 8 and 16, aprons of 1
/// and 2: every node's spreads equal the in-memory reference's bits exactly.
/// Exactly, not within an ulp: the builder mixes the same f64 moments in the
/// same order (x fastest, then y, then z, clamped and repeated children
/// included) as `MomentGrid::downsample`, and rounds the same f64 spread to
/// f32 then to a half float.
#[test]
fn every_node_s_spreads_equal_the_in_memory_reference() {
    let dir = tempfile::tempdir().unwrap();
    // Dims, dtype, brick, apron, anisotropic, spacing.
    type Case = ([u32; 3], DType, u32, u32, bool, [f32; 3]);
    let cases: &[Case] = &[
        ([37, 20, 9], DType::U8, 8, 1, false, [1.0, 0.5, 2.0]),
        ([37, 20, 9], DType::U16, 8, 2, true, [1.0, 0.5, 2.0]),
        ([37, 20, 9], DType::I16, 16, 1, true, [0.8, 0.8, 3.0]),
        ([37, 20, 9], DType::F32, 16, 2, false, [1.0, 1.0, 1.0]),
        ([21, 40, 33], DType::I16, 8, 2, false, [1.0, 0.5, 2.0]),
        ([21, 40, 33], DType::U8, 8, 1, true, [0.5, 0.5, 2.5]),
        ([50, 9, 17], DType::F32, 8, 1, true, [1.0, 4.0, 1.0]),
        ([50, 9, 17], DType::U16, 16, 2, true, [0.3, 1.0, 1.0]),
    ];
    for (n, &(dims, dtype, brick, apron, anisotropic, spacing)) in cases.iter().enumerate() {
        let mut r = MemReader::new(dims, dtype, noisy_volume(dims, dtype, n as u64 + 1));
        r.desc.spacing = spacing;
        let opts = BuildOptions {
            brick,
            apron,
            anisotropic,
            ..BuildOptions::default()
        };
        let b = build_both(dir.path(), &format!("c{n}"), &r, &opts);
        let what = format!("{dims:?} {dtype:?} brick {brick} apron {apron} aniso {anisotropic}");
        let lay = open(&b.spread).unwrap().layout().clone();
        if anisotropic {
            assert!(!lay.is_isotropic(), "{what}: an anisotropic pyramid");
        }
        let spreading = check_against_reference(&b, &what);
        assert!(spreading > 0, "{what}: nothing spreads");
    }
}

/// The file's spread table: (offset, len, crc) per node-table entry, and
/// where it starts.
fn spread_table(b: &[u8]) -> (usize, Vec<(u64, u32, u32)>) {
    let u64_at = |o: usize| u64::from_le_bytes(b[o..o + 8].try_into().unwrap());
    let count = u64_at(72) as usize;
    let mut at = (u64_at(80) + u64_at(88)) as usize;
    if b[FLAGS] & 4 != 0 {
        at += count * brickray_store::ERROR_ENTRY_LEN;
    }
    if b[FLAGS] & 8 != 0 {
        at += count * brickray_store::ERROR_ENTRY_LEN + 4;
    }
    let entries = (0..count)
        .map(|i| {
            let e = &b[at + 16 * i..at + 16 * (i + 1)];
            (
                u64::from_le_bytes(e[0..8].try_into().unwrap()),
                u32::from_le_bytes(e[8..12].try_into().unwrap()),
                u32::from_le_bytes(e[12..16].try_into().unwrap()),
            )
        })
        .collect();
    (at, entries)
}

fn reseal_header(b: &mut [u8]) {
    let crc = crc32fast::hash(&b[..124]);
    b[124..128].copy_from_slice(&crc.to_le_bytes());
}

fn small(dir: &Path) -> Built {
    let dims = [37, 20, 9];
    let r = MemReader::new(dims, DType::U16, noisy_volume(dims, DType::U16, 7));
    let opts = BuildOptions {
        brick: 8,
        apron: 2,
        ..BuildOptions::default()
    };
    build_both(dir, "small", &r, &opts)
}

/// (d) With and without spreads the builds write the same value payloads,
/// node table and error sections: only the header (flag, table offset and
/// checksum), the spread payloads between the value payloads and the table,
/// and the spread table after the parent-error section differ.
#[test]
fn spreads_leave_the_values_and_the_node_table_as_they_were() {
    let dir = tempfile::tempdir().unwrap();
    let b = small(dir.path());
    let (p, s) = (
        std::fs::read(&b.plain).unwrap(),
        std::fs::read(&b.spread).unwrap(),
    );
    let u64_at = |b: &[u8], o: usize| u64::from_le_bytes(b[o..o + 8].try_into().unwrap());
    assert_eq!(u32::from_le_bytes(p[8..12].try_into().unwrap()), 7);
    assert_eq!(p[FLAGS] & FLAG_SPREAD, 0);
    assert_eq!(s[FLAGS], p[FLAGS] | FLAG_SPREAD);
    // The value payloads: the same bytes, the same payload_bytes.
    let values = u64_at(&p, 96) as usize;
    assert_eq!(u64_at(&s, 96) as usize, values);
    assert_eq!(u64_at(&p, 80) as usize, 128 + values);
    assert_eq!(p[..128 + values][128..], s[128..128 + values]);
    // The node table and the error sections: the same bytes after the
    // spread payloads.
    let spread_bytes = (u64_at(&s, 80) - u64_at(&p, 80)) as usize;
    assert!(spread_bytes > 0);
    let (at, entries) = spread_table(&s);
    assert_eq!(p[128 + values..], s[128 + values + spread_bytes..at]);
    // The header's other fields (byte 30 holds the flags, 80..88 the table offset).
    for r in [12..30, 31..80, 88..124] {
        assert_eq!(p[r.clone()], s[r.clone()], "header bytes {r:?}");
    }
    // The spread table ends the file with its CRC; its payloads tile the
    // spread payloads.
    assert_eq!(s.len(), at + 16 * entries.len() + 4);
    let crc = u32::from_le_bytes(s[s.len() - 4..].try_into().unwrap());
    assert_eq!(crc, crc32fast::hash(&s[at..s.len() - 4]));
    let mut spans: Vec<(u64, u32)> = entries
        .iter()
        .filter(|e| e.1 > 0)
        .map(|e| (e.0, e.1))
        .collect();
    spans.sort();
    let mut end = (128 + values) as u64;
    for (o, l) in spans {
        assert_eq!(o, end);
        end += l as u64;
    }
    assert_eq!(end, u64_at(&s, 80));
    // Both open with the same nodes and bricks.
    let (ps, ss) = (open(&b.plain).unwrap(), open(&b.spread).unwrap());
    assert_eq!(ps.payload_bytes(), ss.payload_bytes());
    assert_eq!(ss.spread_bytes(), spread_bytes as u64);
    let bb = ps.layout().brick_bytes();
    let (mut x, mut y) = (vec![0u8; bb], vec![0u8; bb]);
    for rec in ps.nodes() {
        assert_eq!(ss.info(rec.key).unwrap(), rec.info);
        ps.read(rec.key, &mut x).unwrap();
        ss.read(rec.key, &mut y).unwrap();
        assert_eq!(x, y);
    }
    // The same build twice: the same file.
    let again = dir.path().join("again.brs");
    let r = MemReader::new(
        [37, 20, 9],
        DType::U16,
        noisy_volume([37, 20, 9], DType::U16, 7),
    );
    let o = BuildOptions {
        brick: 8,
        apron: 2,
        spread: true,
        ..BuildOptions::default()
    };
    build(&mut r.clone(), &again, &o).unwrap();
    assert_eq!(std::fs::read(&again).unwrap(), s);
}

/// (b) A store built without spreads, and a version-6 file, have no
/// spreads and read zeros; the spread flag in a version-6 header is refused.
#[test]
fn stores_without_spreads_read_zeros() {
    let dir = tempfile::tempdir().unwrap();
    let b = small(dir.path());
    let p = std::fs::read(&b.plain).unwrap();
    let mut v6 = p.clone();
    v6[8..12].copy_from_slice(&6u32.to_le_bytes());
    reseal_header(&mut v6);
    let v6_path = dir.path().join("v6.brs");
    std::fs::write(&v6_path, &v6).unwrap();
    for (path, version) in [(&b.plain, 7), (&v6_path, 6)] {
        let s = open(path).unwrap();
        assert_eq!(s.version(), version);
        assert!(!s.has_spread() && !BrickSource::has_spread(&s));
        assert_eq!(s.spread_bytes(), 0);
        for key in keys(&s) {
            assert!(spreads(&s, key).iter().all(|&x| x == 0), "{key:?}");
        }
    }
    // Version 6 does not know the flag: with it (and the section) the
    // header is refused, never read as spreads.
    let mut bad = std::fs::read(&b.spread).unwrap();
    bad[8..12].copy_from_slice(&6u32.to_le_bytes());
    reseal_header(&mut bad);
    let bad_path = dir.path().join("bad6.brs");
    std::fs::write(&bad_path, &bad).unwrap();
    assert!(matches!(
        open(&bad_path),
        Err(StoreError::BadHeader { field: "flags", .. })
    ));
}

/// (c) A flipped byte of a spread payload fails that node's spreads with
/// `BrickError::Corrupt` (its checksum), nobody else's; a flipped byte of
/// the spread table fails the open (`SpreadChecksum`), a truncated file too
/// (`Truncated`); a wrong buffer is `BufferSize`, a key outside the octree
/// `OutOfRange`.
#[test]
fn damaged_spreads_are_typed_errors() {
    let dir = tempfile::tempdir().unwrap();
    let b = small(dir.path());
    let s = std::fs::read(&b.spread).unwrap();
    let store = open(&b.spread).unwrap();
    let (at, entries) = spread_table(&s);
    let geo: Vec<NodeKey> = store.nodes().map(|r| r.key).collect();
    let (victim, e) = entries
        .iter()
        .enumerate()
        .find(|(_, e)| e.1 > 0)
        .map(|(i, e)| (geo[i], *e))
        .unwrap();
    let other = entries
        .iter()
        .enumerate()
        .rfind(|(_, e)| e.1 > 0)
        .map(|(i, _)| geo[i])
        .unwrap();
    assert_ne!(victim, other);
    let side = store.layout().stored_side() as usize;
    for at_byte in [0, e.1 as usize / 2, e.1 as usize - 1] {
        let mut bad = s.clone();
        bad[e.0 as usize + at_byte] ^= 0x40;
        let p = dir.path().join("flipped.brs");
        std::fs::write(&p, &bad).unwrap();
        let st = open(&p).unwrap();
        let mut out = vec![0u16; side * side * side];
        match BrickSource::read_spread(&st, victim, &mut out) {
            Err(BrickError::Corrupt { key, .. }) => assert_eq!(key, victim),
            r => panic!("byte {at_byte}: {r:?}"),
        }
        assert!(matches!(
            st.read_spread(victim, &mut out),
            Err(StoreError::PayloadChecksum { .. })
        ));
        assert_eq!(spreads(&st, other), spreads(&store, other));
    }
    // The spread table.
    let mut bad = s.clone();
    bad[at + 9] ^= 1;
    let p = dir.path().join("table.brs");
    std::fs::write(&p, &bad).unwrap();
    assert!(matches!(open(&p), Err(StoreError::SpreadChecksum { .. })));
    // Truncated: in the spread table, and in the spread payloads.
    for cut in [1, 17, s.len() - at] {
        let p = dir.path().join("short.brs");
        std::fs::write(&p, &s[..s.len() - cut]).unwrap();
        match open(&p) {
            Err(StoreError::Truncated { section, .. }) => {
                assert_eq!(section, "spread table", "cut {cut}")
            }
            r => panic!("cut {cut}: {:?}", r.map(|_| ())),
        }
    }
    // Buffers and keys.
    let mut short = vec![0u16; 7];
    assert!(matches!(
        BrickSource::read_spread(&store, NodeKey::ROOT, &mut short),
        Err(BrickError::BufferSize { expected, actual: 14 }) if expected == side * side * side * 2
    ));
    let mut out = vec![0u16; side * side * side];
    let past = NodeKey::new(store.levels(), 0, 0, 0);
    assert!(matches!(
        BrickSource::read_spread(&store, past, &mut out),
        Err(BrickError::OutOfRange { .. })
    ));
}

/// A forged spread payload (its checksum recomputed) whose half floats are
/// negative is refused as not a spread; an entry pointed at another node's
/// payload overlaps it at open.
#[test]
fn forged_spreads_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let b = small(dir.path());
    let s = std::fs::read(&b.spread).unwrap();
    let store = open(&b.spread).unwrap();
    let (at, entries) = spread_table(&s);
    let keys: Vec<NodeKey> = store.nodes().map(|r| r.key).collect();
    let datas: Vec<usize> = (0..entries.len()).filter(|&i| entries[i].1 > 0).collect();
    assert!(datas.len() >= 2);
    // Node `datas[0]`'s spreads negated and recompressed in place of its
    // payload (the spread payloads after it, the table and the sections
    // moved by the difference), every checksum recomputed.
    let i = datas[0];
    let (off, len, _) = entries[i];
    let (off, len) = (off as usize, len as usize);
    let side = store.layout().stored_side() as usize;
    let mut raw = vec![0u8; side * side * side * 2];
    brickray_store::decode_payload(keys[i], &s[off..off + len], &mut raw).unwrap();
    for c in raw.chunks_exact_mut(2) {
        c[1] |= 0x80;
    }
    let forged = lz4_flex::block::compress(&raw);
    let delta = forged.len() as i64 - len as i64;
    let mut bad = [&s[..off], &forged[..], &s[off + len..]].concat();
    let shift = |v: u64| (v as i64 + delta) as u64;
    let table_offset = u64::from_le_bytes(bad[80..88].try_into().unwrap());
    bad[80..88].copy_from_slice(&shift(table_offset).to_le_bytes());
    let at2 = shift(at as u64) as usize;
    for (k, e) in entries.iter().enumerate() {
        let eo = at2 + 16 * k;
        if k == i {
            let mut h = crc32fast::Hasher::new();
            h.update(&[keys[i].level]);
            for p in [keys[i].x, keys[i].y, keys[i].z] {
                h.update(&p.to_le_bytes());
            }
            h.update(&forged);
            bad[eo + 8..eo + 12].copy_from_slice(&(forged.len() as u32).to_le_bytes());
            bad[eo + 12..eo + 16].copy_from_slice(&h.finalize().to_le_bytes());
        } else if e.1 > 0 && e.0 as usize > off {
            bad[eo..eo + 8].copy_from_slice(&shift(e.0).to_le_bytes());
        }
    }
    let n = bad.len() - 4;
    let t = crc32fast::hash(&bad[at2..n]);
    bad[n..].copy_from_slice(&t.to_le_bytes());
    reseal_header(&mut bad);
    let p = dir.path().join("negative.brs");
    std::fs::write(&p, &bad).unwrap();
    let st = open(&p).unwrap();
    let mut out = vec![0u16; side * side * side];
    assert!(matches!(
        st.read_spread(keys[i], &mut out),
        Err(StoreError::Decode { .. })
    ));
    assert!(matches!(
        BrickSource::read_spread(&st, keys[i], &mut out),
        Err(BrickError::Corrupt { .. })
    ));
    assert_eq!(
        spreads(&st, keys[datas[1]]),
        spreads(&store, keys[datas[1]])
    );
    // Node `datas[1]` pointed at `datas[0]`'s payload.
    let mut bad = s.clone();
    let (j, k) = (datas[0], datas[1]);
    let (src, dst) = (at + 16 * j, at + 16 * k);
    let copy = bad[src..src + 16].to_vec();
    bad[dst..dst + 16].copy_from_slice(&copy);
    let n = bad.len() - 4;
    let t = crc32fast::hash(&bad[at..n]);
    bad[n..].copy_from_slice(&t.to_le_bytes());
    let p = dir.path().join("overlap.brs");
    std::fs::write(&p, &bad).unwrap();
    assert!(matches!(
        open(&p),
        Err(StoreError::PayloadOverlap { .. } | StoreError::PayloadGap { .. })
    ));
    // A payload at the finest level.
    let mut bad = s.clone();
    let leaf = keys
        .iter()
        .position(|k| k.level == store.levels() - 1)
        .unwrap();
    let (src, dst) = (at + 16 * j, at + 16 * leaf);
    let copy = bad[src..src + 16].to_vec();
    bad[dst..dst + 16].copy_from_slice(&copy);
    let n = bad.len() - 4;
    let t = crc32fast::hash(&bad[at..n]);
    bad[n..].copy_from_slice(&t.to_le_bytes());
    let p = dir.path().join("leaf.brs");
    std::fs::write(&p, &bad).unwrap();
    assert!(matches!(
        open(&p),
        Err(StoreError::BadNode {
            field: "spread",
            ..
        })
    ));
}

/// Spreads are refused where they mean nothing (label maps, the max
/// filter), before anything is written.
#[test]
fn spreads_are_refused_where_they_mean_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("v.brs");
    let dims = [20u32, 20, 20];
    let mut labels = MemReader::new(dims, DType::U8, noisy_volume(dims, DType::U8, 3));
    labels.desc.kind = VolumeKind::Labels;
    let spread = BuildOptions {
        brick: 8,
        spread: true,
        ..BuildOptions::default()
    };
    assert!(matches!(
        build(&mut labels, &out, &spread),
        Err(StoreError::BadOption {
            option: "spread",
            ..
        })
    ));
    let mut r = MemReader::new(dims, DType::U8, noisy_volume(dims, DType::U8, 3));
    let max = BuildOptions {
        filter: Filter::Max,
        ..spread.clone()
    };
    assert!(matches!(
        build(&mut r, &out, &max),
        Err(StoreError::BadOption {
            option: "spread",
            ..
        })
    ));
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

/// A banded build (slices too large for one streaming pass within the
/// memory bound: the finest level and, since the moment windows take 16
/// bytes a coarse voxel, coarser levels too, built in y-bands through
/// temporary files of the coarser level's values and moments) records the
/// spreads of the streamed build, bit for bit, and leaves no temporary
/// behind; its nodes and bricks are those of the build without spreads
/// (which bands fewer levels, so writes its payloads in another order).
#[test]
fn a_banded_build_records_the_same_spreads() {
    let dir = tempfile::tempdir().unwrap();
    // Dims, dtype, brick, apron, anisotropic, memory bound.
    type Case = ([u32; 3], DType, u32, u32, bool, u64);
    let cases: &[Case] = &[
        ([200, 300, 20], DType::U8, 8, 2, false, 1_500_000),
        ([150, 260, 13], DType::I16, 8, 1, false, 900_000),
        ([170, 230, 11], DType::F32, 8, 2, true, 2_500_000),
    ];
    for (n, &(dims, dtype, brick, apron, anisotropic, bound)) in cases.iter().enumerate() {
        let what = format!("{dims:?} {dtype:?} bound {bound}");
        let mut r = MemReader::new(dims, dtype, noisy_volume(dims, dtype, n as u64 + 11));
        r.desc.spacing = [1.0, 0.8, 1.7];
        let streamed = BuildOptions {
            brick,
            apron,
            anisotropic,
            spread: true,
            ..BuildOptions::default()
        };
        let banded = BuildOptions {
            memory_bound: bound,
            ..streamed.clone()
        };
        let (sp, bp, pp) = (
            dir.path().join(format!("s{n}.brs")),
            dir.path().join(format!("b{n}.brs")),
            dir.path().join(format!("p{n}.brs")),
        );
        assert_eq!(
            build(&mut r.clone(), &sp, &streamed).unwrap().banded_levels,
            0
        );
        let report = build(&mut r.clone(), &bp, &banded).unwrap();
        assert!(
            report.banded_levels >= 1 && report.spread,
            "{what}: {report:?}"
        );
        let plain = BuildOptions {
            spread: false,
            ..banded.clone()
        };
        let p = build(&mut r.clone(), &pp, &plain).unwrap();
        assert!(p.banded_levels >= 1, "{what}");
        let (s, b) = (open(&sp).unwrap(), open(&bp).unwrap());
        assert!(b.has_spread());
        let reference = SpreadSource::new(Arc::new(open(&pp).unwrap()), &volume_of(&r)).unwrap();
        for key in keys(&s) {
            let want = spreads(&reference, key);
            assert_eq!(spreads(&b, key), want, "{what}: banded {key:?}");
            assert_eq!(spreads(&s, key), want, "{what}: streamed {key:?}");
        }
        // The moment windows band more levels than the build without
        // spreads needs: the payloads' order differs, not the bricks.
        assert!(report.banded_levels > p.banded_levels, "{what}");
        let pl = open(&pp).unwrap();
        let bytes = pl.layout().brick_bytes();
        let (mut x, mut y) = (vec![0u8; bytes], vec![0u8; bytes]);
        for rec in pl.nodes() {
            assert_eq!(b.info(rec.key).unwrap(), rec.info, "{what}");
            pl.read(rec.key, &mut x).unwrap();
            b.read(rec.key, &mut y).unwrap();
            assert_eq!(x, y, "{what}: {:?}", rec.key);
        }
    }
    // Nothing but the stores.
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        3 * cases.len()
    );
}

/// A store over a range reader (as over the network) reads its spreads
/// through it.
#[test]
fn spreads_read_through_a_range_reader() {
    let dir = tempfile::tempdir().unwrap();
    let b = small(dir.path());
    let bytes = std::fs::read(&b.spread).unwrap();
    let mem = Store::open_with(
        brickray_store::MemRangeReader::new(bytes),
        "https://example.invalid/s.brs",
    )
    .unwrap();
    let file = open(&b.spread).unwrap();
    assert!(mem.has_spread());
    for key in keys(&file) {
        assert_eq!(spreads(&mem, key), spreads(&file, key));
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]
    /// Any small volume, dtype, brick, apron and pyramid: the store's
    /// spreads are the reference's, bit for bit.
    #[test]
    fn spreads_match_the_reference_on_any_small_volume(
        dims in (1u32..24, 1u32..24, 1u32..24),
        dtype in prop::sample::select(vec![DType::U8, DType::U16, DType::I16, DType::F32]),
        seed in 0u64..1000,
        brick in prop::sample::select(vec![4u32, 8]),
        apron in 0u32..3,
        anisotropic in any::<bool>(),
        sz in prop::sample::select(vec![1.0f32, 2.0, 3.5]),
    ) {
        let dims = [dims.0, dims.1, dims.2];
        let mut r = MemReader::new(dims, dtype, noisy_volume(dims, dtype, seed));
        r.desc.spacing = [1.0, 0.7, sz];
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("p.brs");
        let o = BuildOptions { brick, apron, anisotropic, spread: true, ..BuildOptions::default() };
        build(&mut r.clone(), &out, &o).unwrap();
        let store = Arc::new(open(&out).unwrap());
        prop_assert!(store.has_spread());
        let reference = SpreadSource::new(store.clone(), &volume_of(&r)).unwrap();
        for key in keys(&store) {
            prop_assert_eq!(spreads(store.as_ref(), key), spreads(&reference, key), "{:?}", key);
        }
    }
}

/// The head CT of the shared data (4 levels, i16, an anisotropic pyramid of
/// its 0.96 x 0.96 x 1.5 mm voxels too): every node's spreads equal the
/// reference's bits.
#[test]
fn the_head_ct_s_spreads_equal_the_reference() {
    let Some(data) = shared_data() else { return };
    let json = data.join("invesalius_cranium_ct/invesalius_cranium_ct.json");
    let volume = brickray_io::read_volume(&json).unwrap();
    let dir = tempfile::tempdir().unwrap();
    for anisotropic in [false, true] {
        let out = dir.path().join("ct.brs");
        let o = BuildOptions {
            anisotropic,
            spread: true,
            ..BuildOptions::default()
        };
        brickray_store::build_file(&json, &out, &o).unwrap();
        let store = Arc::new(open(&out).unwrap());
        assert!(store.has_spread() && store.levels() >= 3);
        let reference = SpreadSource::new(store.clone(), &volume).unwrap();
        for key in keys(&store) {
            assert_eq!(
                spreads(store.as_ref(), key),
                spreads(&reference, key),
                "{key:?}"
            );
        }
    }
}

/// Every byte of the spread payloads and of the spread table flipped in turn
/// (a bounded sweep of what the fuzz target does): never a panic; a store
/// that opens answers every node's spreads with zeros-or-the-original or a
/// typed error, and a flip inside a node's spread payload fails that node.
#[test]
fn every_flipped_spread_byte_is_caught() {
    let dir = tempfile::tempdir().unwrap();
    let b = small(dir.path());
    let s = std::fs::read(&b.spread).unwrap();
    let store = open(&b.spread).unwrap();
    let keys: Vec<NodeKey> = store.nodes().map(|r| r.key).collect();
    let want: Vec<Vec<u16>> = keys.iter().map(|&k| spreads(&store, k)).collect();
    let (at, entries) = spread_table(&s);
    let values_end = 128 + u64::from_le_bytes(s[96..104].try_into().unwrap()) as usize;
    let table_offset = u64::from_le_bytes(s[80..88].try_into().unwrap()) as usize;
    let side = store.layout().stored_side() as usize;
    let p = dir.path().join("flip.brs");
    let positions = (values_end..table_offset).chain(at..s.len());
    let mut caught = 0;
    for pos in positions {
        let mut bad = s.clone();
        bad[pos] ^= 0x21;
        std::fs::write(&p, &bad).unwrap();
        let Ok(st) = open(&p) else {
            caught += 1;
            continue;
        };
        assert!(pos < at, "a flip in the spread table at {pos} opens");
        let owner = entries
            .iter()
            .position(|e| e.1 > 0 && (e.0 as usize..e.0 as usize + e.1 as usize).contains(&pos))
            .unwrap();
        let mut out = vec![0u16; side * side * side];
        for (i, &k) in keys.iter().enumerate() {
            match BrickSource::read_spread(&st, k, &mut out) {
                Ok(()) => {
                    assert_ne!(i, owner, "flip at {pos}");
                    assert_eq!(out, want[i]);
                }
                Err(BrickError::Corrupt { .. }) => assert_eq!(i, owner, "flip at {pos}"),
                Err(e) => panic!("flip at {pos}: {e}"),
            }
        }
        caught += 1;
    }
    assert!(caught > 100);
}
