//! Round trips: every voxel of every node equals the reference pyramid.
#![allow(missing_docs)]

mod common;

use brickray_core::{BrickSource, DType, NodeKey, NodeKind};
use brickray_store::{BuildOptions, Filter, StoreError, build, open};
use common::*;
use proptest::prelude::*;

fn opts(brick: u32, apron: u32, filter: Filter) -> BuildOptions {
    BuildOptions {
        brick,
        apron,
        filter,
        ..BuildOptions::default()
    }
}

fn roundtrip(dims: [u32; 3], dtype: DType, o: &BuildOptions, seed: u64) {
    let bytes = test_volume(dims, dtype, seed);
    roundtrip_bytes(dims, dtype, bytes, o);
}

fn roundtrip_bytes(dims: [u32; 3], dtype: DType, bytes: Vec<u8>, o: &BuildOptions) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("v.brs");
    let mut r = MemReader::new(dims, dtype, bytes.clone());
    let report = build(&mut r, &out, o).unwrap();
    let store = open(&out).unwrap();
    assert_eq!(store.layout(), &report.layout);
    assert_eq!(store.desc(), &r.desc);
    assert_eq!(store.file_len(), report.file_bytes);
    let levels = reference_levels(store.layout(), decode(dtype, &bytes), o.filter);
    check_source(&store, &levels, o.empty_below);
    // Only the store file is left in the directory.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
}

#[test]
fn tiny_1x1x1() {
    for dtype in [DType::U8, DType::U16, DType::I16, DType::F32] {
        roundtrip([1, 1, 1], dtype, &BuildOptions::default(), 1);
        roundtrip([1, 1, 1], dtype, &opts(1, 2, Filter::Average), 1);
    }
}

#[test]
fn odd_257x129x67_u8() {
    roundtrip([257, 129, 67], DType::U8, &BuildOptions::default(), 7);
}

#[test]
fn odd_sizes_all_dtypes_and_filters() {
    for (i, dtype) in [DType::U8, DType::U16, DType::I16, DType::F32]
        .into_iter()
        .enumerate()
    {
        roundtrip([37, 21, 13], dtype, &opts(8, 2, Filter::Average), i as u64);
        roundtrip([19, 40, 9], dtype, &opts(4, 1, Filter::Max), i as u64);
    }
}

#[test]
fn anisotropic_and_flat() {
    roundtrip([200, 3, 1], DType::U16, &opts(16, 2, Filter::Average), 3);
    roundtrip([1, 1, 150], DType::I16, &opts(8, 3, Filter::Average), 4);
    roundtrip([64, 64, 2], DType::U8, &opts(32, 0, Filter::Average), 5);
}

#[test]
fn uniform_bricks_have_no_payload_and_threshold_empties() {
    let dims = [48, 40, 24];
    let bytes = test_volume(dims, DType::U8, 9);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("v.brs");
    let mut r = MemReader::new(dims, DType::U8, bytes.clone());
    build(&mut r, &out, &opts(8, 2, Filter::Average)).unwrap();
    let store = open(&out).unwrap();
    let s = store.stats();
    assert!(s.uniform > 0, "the constant block gives uniform bricks");
    for rec in store.nodes() {
        if matches!(rec.info.kind, NodeKind::Uniform(_)) {
            assert_eq!(rec.payload_len, 0);
        }
    }
    // Threshold above the constant block value (5): those nodes become empty.
    let o = BuildOptions {
        empty_below: Some(6.0),
        ..opts(8, 2, Filter::Average)
    };
    roundtrip_bytes(dims, DType::U8, bytes, &o);
    let mut r = MemReader::new(dims, DType::U8, test_volume(dims, DType::U8, 9));
    build(&mut r, &out, &o).unwrap();
    let store = open(&out).unwrap();
    let s = store.stats();
    assert!(s.empty > 0 && s.uniform == 0, "{s:?}");
    assert_eq!(store.empty_below(), Some(6.0));
}

#[test]
fn aprons_equal_neighbour_voxels() {
    let dims = [70, 50, 40];
    let o = opts(16, 2, Filter::Average);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("v.brs");
    let mut r = MemReader::new(dims, DType::U16, test_volume(dims, DType::U16, 2));
    build(&mut r, &out, &o).unwrap();
    let store = open(&out).unwrap();
    let lay = store.layout().clone();
    let s = lay.stored_side() as usize;
    let (a, b) = (lay.apron as usize, lay.brick as usize);
    let leaf = lay.levels - 1;
    let read = |k: NodeKey| {
        let mut buf = vec![0u8; lay.brick_bytes()];
        store.read(k, &mut buf).unwrap();
        decode(DType::U16, &buf)
    };
    let at = |v: &[f32], i: usize, j: usize, k: usize| v[i + s * (j + s * k)];
    // +x neighbour: apron voxels a+b..a+b+a of brick x are voxels a..2a of brick x+1.
    let (p, q) = (
        read(NodeKey::new(leaf, 1, 1, 1)),
        read(NodeKey::new(leaf, 2, 1, 1)),
    );
    for k in 0..s {
        for j in 0..s {
            for t in 0..a {
                assert_eq!(at(&p, a + b + t, j, k), at(&q, a + t, j, k));
                assert_eq!(at(&q, t, j, k), at(&p, b + t, j, k));
            }
        }
    }
    // +z neighbour.
    let q = read(NodeKey::new(leaf, 1, 1, 2));
    for j in 0..s {
        for i in 0..s {
            for t in 0..a {
                assert_eq!(at(&p, i, j, a + b + t), at(&q, i, j, a + t));
            }
        }
    }
}

#[test]
fn interrupted_build_leaves_no_store() {
    let dims = [40, 40, 40];
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("v.brs");
    let mut r = MemReader::new(dims, DType::U8, test_volume(dims, DType::U8, 1));
    r.fail_at = Some(25);
    let err = build(&mut r, &out, &opts(8, 2, Filter::Average)).unwrap_err();
    assert!(matches!(err, StoreError::Input(_)), "{err}");
    assert!(!out.exists());
    assert_eq!(
        std::fs::read_dir(dir.path()).unwrap().count(),
        0,
        "temporary file left behind"
    );
}

#[test]
fn non_finite_input_is_refused() {
    let dims = [20, 10, 9];
    let mut v = decode(DType::F32, &test_volume(dims, DType::F32, 1));
    v[20 * 10 * 7 + 13] = f32::NAN;
    let mut r = MemReader::new(dims, DType::F32, encode(DType::F32, &v));
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("v.brs");
    let err = build(&mut r, &out, &opts(4, 2, Filter::Average)).unwrap_err();
    assert!(matches!(err, StoreError::NonFinite { .. }), "{err}");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

#[test]
fn memory_bound_is_enforced() {
    let dims = [512, 512, 4];
    let mut r = MemReader::new(dims, DType::U8, vec![0; 512 * 512 * 4]);
    let o = BuildOptions {
        memory_bound: 300 << 10,
        ..BuildOptions::default()
    };
    let dir = tempfile::tempdir().unwrap();
    let err = build(&mut r, &dir.path().join("v.brs"), &o).unwrap_err();
    assert!(matches!(err, StoreError::MemoryBound { .. }), "{err}");
}

#[test]
fn banded_build_under_a_tight_memory_bound() {
    // Slices too large for one streaming pass under the bound: the finest
    // levels are built in y-bands through temporary level files.
    for (dims, dtype, brick, apron, bound) in [
        ([200u32, 300, 50], DType::U8, 8u32, 2u32, 1_500_000u64),
        ([130, 257, 33], DType::I16, 8, 1, 1_500_000),
        ([64, 190, 21], DType::F32, 4, 0, 900_000),
        ([97, 250, 19], DType::U16, 6, 3, 1_200_000),
    ] {
        let bytes = test_volume(dims, dtype, 3);
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("v.brs");
        let mut r = MemReader::new(dims, dtype, bytes.clone());
        let o = BuildOptions {
            memory_bound: bound,
            ..opts(brick, apron, Filter::Average)
        };
        let report = build(&mut r, &out, &o).unwrap();
        assert!(report.banded_levels >= 1, "{dims:?}: {report:?}");
        assert!(report.buffer_estimate <= bound);
        let store = open(&out).unwrap();
        let levels = reference_levels(store.layout(), decode(dtype, &bytes), Filter::Average);
        check_source(&store, &levels, None);
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            1,
            "temporary files left"
        );
    }
}

#[test]
fn concurrent_reads_agree() {
    let dims = [90, 70, 50];
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("v.brs");
    let mut r = MemReader::new(dims, DType::I16, test_volume(dims, DType::I16, 5));
    build(&mut r, &out, &opts(8, 2, Filter::Average)).unwrap();
    let store = open(&out).unwrap();
    let keys: Vec<NodeKey> = store.nodes().map(|n| n.key).collect();
    let bb = store.layout().brick_bytes();
    let serial: Vec<Vec<u8>> = keys
        .iter()
        .map(|&k| {
            let mut b = vec![0u8; bb];
            store.read_brick(k, &mut b).unwrap();
            b
        })
        .collect();
    std::thread::scope(|s| {
        for t in 0..4 {
            let (store, keys, serial) = (&store, &keys, &serial);
            s.spawn(move || {
                let mut b = vec![0u8; bb];
                for (i, &k) in keys.iter().enumerate().skip(t).step_by(3) {
                    store.read_brick(k, &mut b).unwrap();
                    assert_eq!(b, serial[i]);
                }
            });
        }
    });
}

#[test]
fn metadata_queries() {
    let dims = [100, 30, 20];
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("v.brs");
    let mut r = MemReader::new(dims, DType::U8, test_volume(dims, DType::U8, 5));
    build(&mut r, &out, &opts(16, 2, Filter::Average)).unwrap();
    let store = open(&out).unwrap();
    assert_eq!(store.levels(), 4); // 16 * 2^3 = 128 >= 100
    let root = store.children(NodeKey::ROOT).unwrap();
    // Only children that overlap the volume: x halves both, y and z low half only.
    assert_eq!(root.len(), 2);
    assert!(store.children(NodeKey::new(3, 0, 0, 0)).unwrap().is_empty());
    assert!(matches!(
        store.info(NodeKey::new(4, 0, 0, 0)),
        Err(StoreError::OutOfRange { .. })
    ));
    assert!(matches!(
        store.info(NodeKey::new(1, 2, 0, 0)),
        Err(StoreError::OutOfRange { .. })
    ));
    assert_eq!(
        store.info(NodeKey::new(1, 0, 1, 0)).unwrap().kind,
        NodeKind::Empty
    );
    let mut small = vec![0u8; 3];
    assert!(matches!(
        store.read(NodeKey::ROOT, &mut small),
        Err(StoreError::BufferSize { .. })
    ));
    let s = store.stats();
    assert_eq!(s.per_level.len(), 4);
    assert_eq!(s.per_level[3][0], 7 * 2 * 2);
}

#[test]
fn shared_data_volumes_round_trip() {
    let Some(dir) = shared_data() else { return };
    let tmp = tempfile::tempdir().unwrap();
    for name in [
        "invesalius_cranium_ct",
        "pycortex_s1_t1_mri",
        "cells3d_nuclei_fluo",
        "cryoet_tomo",
    ] {
        let json = dir.join(name).join(format!("{name}.json"));
        let out = tmp.path().join(format!("{name}.brick"));
        let report = brickray_store::build_file(&json, &out, &BuildOptions::default()).unwrap();
        let vol = brickray_core::read_volume(&json).unwrap();
        let store = open(&out).unwrap();
        assert_eq!(store.desc(), vol.desc());
        let levels = reference_levels(
            store.layout(),
            decode(vol.desc().dtype, vol.data().as_bytes()),
            Filter::Average,
        );
        check_source(&store, &levels, None);
        eprintln!(
            "{name}: {} nodes, {} data, {} uniform, compression {:.2}x",
            report.nodes,
            report.data_nodes,
            report.uniform_nodes,
            report.input_bytes as f64 / report.payload_bytes.max(1) as f64
        );
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]
    #[test]
    fn random_dims_and_bricks(
        nx in 1u32..40, ny in 1u32..40, nz in 1u32..40,
        brick in 1u32..13, apron in 0u32..4,
        dt in 0usize..4, max in any::<bool>(), seed in any::<u64>(),
    ) {
        let dtype = [DType::U8, DType::U16, DType::I16, DType::F32][dt];
        let filter = if max { Filter::Max } else { Filter::Average };
        roundtrip([nx, ny, nz], dtype, &opts(brick, apron, filter), seed);
    }

    #[test]
    fn random_dims_banded(
        nx in 8u32..90, ny in 30u32..120, nz in 1u32..20,
        brick in 2u32..9, apron in 0u32..4,
        dt in 0usize..4, bound_kib in 40u64..400, seed in any::<u64>(),
    ) {
        let dtype = [DType::U8, DType::U16, DType::I16, DType::F32][dt];
        let dims = [nx, ny, nz];
        let bytes = test_volume(dims, dtype, seed);
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("v.brs");
        let mut r = MemReader::new(dims, dtype, bytes.clone());
        let o = BuildOptions { memory_bound: bound_kib << 10, ..opts(brick, apron, Filter::Average) };
        match build(&mut r, &out, &o) {
            Err(StoreError::MemoryBound { .. }) => {}
            Err(e) => panic!("{e}"),
            Ok(report) => {
                prop_assert!(report.buffer_estimate <= o.memory_bound);
                let store = open(&out).unwrap();
                let levels = reference_levels(store.layout(), decode(dtype, &bytes), Filter::Average);
                check_source(&store, &levels, None);
            }
        }
        prop_assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), usize::from(out.exists()));
    }
}
