//! Label stores: built by the mode of the children whatever the filter asked,
//! recorded as labels, and every node equal to the reference mode pyramid
//! (so no coarse node holds a label the data lacks).
#![allow(missing_docs)]

mod common;

use brickray_core::{BrickSource, DType, VolumeKind};
use brickray_store::{BuildOptions, Filter, build, open};
use common::*;
use proptest::prelude::*;
use std::collections::BTreeSet;

/// Label ids in runs along x (segments), a few ids, some large for u32.
fn label_bytes(dims: [u32; 3], dtype: DType, ids: &[u32], seed: u64) -> Vec<u8> {
    let n = dims.iter().map(|&d| d as usize).product::<usize>();
    let mut h = seed | 1;
    let mut cur = ids[0];
    let mut v = Vec::with_capacity(n);
    for _ in 0..n {
        h ^= h << 13;
        h ^= h >> 7;
        h ^= h << 17;
        if h.is_multiple_of(4) {
            cur = ids[(h >> 9) as usize % ids.len()];
        }
        v.push(cur as f32);
    }
    encode(dtype, &v)
}

fn label_reader(dims: [u32; 3], dtype: DType, bytes: Vec<u8>) -> MemReader {
    let mut r = MemReader::new(dims, dtype, bytes);
    r.desc.kind = VolumeKind::Labels;
    r.desc.value_range = brickray_core::labels::label_value_range();
    r
}

fn check_label_store(dims: [u32; 3], dtype: DType, ids: &[u32], seed: u64, brick: u32) {
    let bytes = label_bytes(dims, dtype, ids, seed);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("labels.brs");
    let mut r = label_reader(dims, dtype, bytes.clone());
    // Asked for the average: a label map is filtered by the mode anyway.
    let o = BuildOptions {
        brick,
        apron: 1,
        filter: Filter::Average,
        ..BuildOptions::default()
    };
    let report = build(&mut r, &out, &o).unwrap();
    assert!(report.errors, "label stores record the label error");
    let store = open(&out).unwrap();
    assert_eq!(store.desc().kind, VolumeKind::Labels);
    assert_eq!(store.filter(), Filter::Mode);
    assert_eq!(store.version(), 7);
    let levels = reference_levels(store.layout(), decode(dtype, &bytes), Filter::Mode);
    check_source(&store, &levels, None);
    check_label_errors(&store, &levels);
    // Every level read back whole equals the reference pyramid's.
    for (l, level) in levels.iter().enumerate() {
        let v = brickray_core::level_volume(&store, l as u8).unwrap();
        assert_eq!(v.dims(), store.layout().level_dims(l as u8));
        assert_eq!(v.desc().kind, VolumeKind::Labels);
        let ids: Vec<f32> = (0..v.data().len())
            .map(|i| v.data().label(i) as f32)
            .collect();
        assert_eq!(&ids, level, "level {l}");
        // It covers the finest box, with less than one coarse voxel over.
        for ax in 0..3 {
            let (dl, sl) = (v.dims()[ax] as f32, v.desc().spacing[ax]);
            let fine = dims[ax] as f32 * store.desc().spacing[ax];
            assert!(
                dl * sl >= fine && (dl - 1.0) * sl < fine,
                "level {l} axis {ax}: {:?} x {:?} for {dims:?}",
                v.dims(),
                v.desc().spacing
            );
        }
    }
    // A pick on the streamed map names the finest voxel's label.
    // (Ids past the label table's are fine here: nothing is drawn.)
    let volume = brickray_core::Volume::new(
        brickray_core::VolumeDesc {
            dims,
            dtype,
            spacing: [1.0; 3],
            value_range: brickray_core::labels::label_value_range(),
            kind: VolumeKind::Labels,
        },
        brickray_core::VolumeData::from_le_bytes(dtype, &bytes),
    )
    .unwrap();
    let mut h = seed | 1;
    for _ in 0..50 {
        let tex = [0, 1, 2].map(|_| {
            h ^= h << 13;
            h ^= h >> 7;
            h ^= h << 17;
            (h % 10_000) as f64 / 10_000.0
        });
        assert_eq!(
            brickray_core::labels::label_at_source(&store, tex).unwrap(),
            brickray_core::labels::label_at(&volume, tex),
            "at {tex:?}"
        );
    }
    // No level holds a label the finest lacks.
    let finest: BTreeSet<u32> = levels.last().unwrap().iter().map(|&v| v as u32).collect();
    for (l, level) in levels.iter().enumerate() {
        for v in level {
            assert!(finest.contains(&(*v as u32)), "level {l} holds {v}");
        }
    }
    let mut buf = vec![0u8; store.layout().brick_bytes()];
    store
        .read_brick(brickray_core::NodeKey::ROOT, &mut buf)
        .unwrap();
    for v in decode(dtype, &buf) {
        assert!(finest.contains(&(v as u32)), "root brick holds {v}");
    }
}

/// Every node's recorded error is the share of the finest voxels of its
/// region whose label differs from the reference mode pyramid's voxel of the
/// node's level covering them (0 at the finest level), and its parent error
/// the same share against its parent's level (0 at the root); both rounded
/// up to 1/65535.
fn check_label_errors(store: &brickray_store::Store, levels: &[Vec<f32>]) {
    let layout = store.layout();
    let finest = layout.levels as usize - 1;
    let fd = layout.level_dims(finest as u8);
    let b = layout.brick;
    let share = |key: brickray_core::NodeKey, l: usize| -> f64 {
        let cd = layout.level_dims(l as u8);
        let s = 1u32 << (finest - key.level as usize);
        let cs = 1u32 << (finest - l);
        let p = [key.x, key.y, key.z];
        let (mut changed, mut count) = (0u64, 0u64);
        for z in p[2] * b * s..((p[2] + 1) * b * s).min(fd[2]) {
            for y in p[1] * b * s..((p[1] + 1) * b * s).min(fd[1]) {
                for x in p[0] * b * s..((p[0] + 1) * b * s).min(fd[0]) {
                    let f = levels[finest][(x + fd[0] * (y + fd[1] * z)) as usize];
                    let (cx, cy, cz) = (x / cs, y / cs, z / cs);
                    let c = levels[l][(cx + cd[0] * (cy + cd[1] * cz)) as usize];
                    count += 1;
                    changed += (f != c) as u64;
                }
            }
        }
        if count == 0 {
            0.0
        } else {
            changed as f64 / count as f64
        }
    };
    let q = 1.0 / 65535.0;
    let mut nonzero = 0;
    for rec in store.nodes() {
        let key = rec.key;
        let l = key.level as usize;
        let own = if l < finest { share(key, l) } else { 0.0 };
        let got = rec.info.error.expect("an error record").label_share();
        assert!(
            got >= own && got <= own + q,
            "{key:?}: recorded {got}, share {own}"
        );
        nonzero += (own > 0.0) as usize;
        if l == 0 {
            assert_eq!(rec.info.parent_error, None, "the root has no parent");
            continue;
        }
        let parent = share(key, l - 1);
        let got = rec
            .info
            .parent_error
            .expect("a parent-error record")
            .label_share();
        assert!(
            got >= parent && got <= parent + q,
            "{key:?}: recorded parent {got}, share {parent}"
        );
    }
    // (A map of one label changes nothing anywhere.)
    let one_label = levels[finest].iter().all(|&v| v == levels[finest][0]);
    assert!(
        one_label || finest == 0 || nonzero > 0,
        "some node changes labels"
    );
}

#[test]
fn label_stores_of_every_label_type() {
    check_label_store([37, 20, 9], DType::U8, &[0, 7, 9, 200], 1, 8);
    check_label_store([16, 33, 17], DType::U16, &[0, 1, 2, 3, 60_000], 2, 8);
    check_label_store([21, 21, 21], DType::U32, &[0, 5, 4_000_000_000, 77], 3, 4);
}

#[test]
fn float_label_maps_are_refused() {
    let dims = [4, 4, 4];
    let mut r = label_reader(dims, DType::F32, encode(DType::F32, &[1.0; 64]));
    let dir = tempfile::tempdir().unwrap();
    let err = build(&mut r, &dir.path().join("x.brs"), &BuildOptions::default()).unwrap_err();
    assert!(err.to_string().contains("label"), "{err}");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(12))]
    #[test]
    fn label_pyramids_keep_labels(
        dims in prop::array::uniform3(1u32..24),
        ids in prop::collection::btree_set(0u32..70_000, 1..5),
        seed in any::<u64>(),
    ) {
        let ids: Vec<u32> = ids.into_iter().collect();
        check_label_store(dims, DType::U32, &ids, seed, 4);
    }
}
