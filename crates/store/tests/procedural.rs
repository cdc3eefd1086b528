//! The procedural source: exact filtering, conservative bounds, huge volumes.
#![allow(missing_docs)]

mod common;

use brickray_core::{BrickSource, DType, NodeKey, NodeKind};
use brickray_io::VolumeReader;
use brickray_store::{BuildOptions, Filter, ProceduralSource, StoreError, build, open};
use common::*;

/// The finest level of a small procedural volume as f32 values.
fn finest(src: &ProceduralSource) -> Vec<f32> {
    let lay = src.layout();
    let d = lay.level_dims(lay.levels - 1).map(|d| d as u64 - 1);
    src.region(lay.levels - 1, [0; 3], d)
        .unwrap()
        .into_iter()
        .map(f32::from)
        .collect()
}

#[test]
fn inner_nodes_equal_the_filter_of_their_children() {
    for (dims, brick, apron) in [
        ([45u64, 30, 19], 4u32, 2u32),
        ([64, 64, 64], 8, 2),
        ([33, 1, 7], 2, 1),
        ([1, 1, 1], 32, 2),
    ] {
        let src = ProceduralSource::fractal_noise(dims, brick, apron).unwrap();
        let lay = src.layout().clone();
        let levels = reference_levels(&lay, finest(&src), Filter::Average);
        // Every level computed top-down equals the filtered finest level.
        for l in 0..lay.levels {
            let d = lay.level_dims(l).map(|d| d as u64 - 1);
            let got: Vec<f32> = src
                .region(l, [0; 3], d)
                .unwrap()
                .into_iter()
                .map(f32::from)
                .collect();
            assert_eq!(got, levels[l as usize], "{dims:?} level {l}");
        }
        // Bricks, aprons and conservative min/max.
        check_source(&src, &levels, None);
    }
}

#[test]
fn sphere_shells_exact_and_uniform_air() {
    for (dims, brick, apron) in [
        ([64u64, 64, 64], 4u32, 2u32),
        ([45, 30, 19], 4, 1),
        ([70, 70, 40], 8, 2),
    ] {
        let src = ProceduralSource::sphere_shells(dims, brick, apron).unwrap();
        let lay = src.layout().clone();
        let levels = reference_levels(&lay, finest(&src), Filter::Average);
        check_source(&src, &levels, None);
        let leaf = lay.levels - 1;
        let uniform = (0..1u32 << leaf)
            .flat_map(|z| (0..1u32 << leaf).map(move |y| (y, z)))
            .flat_map(|(y, z)| (0..1u32 << leaf).map(move |x| NodeKey::new(leaf, x, y, z)))
            .filter(|k| lay.in_volume(*k))
            .filter(|k| matches!(src.node(*k).unwrap().kind, NodeKind::Uniform(_)))
            .count();
        // The ball is sized by the octree cube: cubic volumes have air corners.
        if dims[0] == dims[1] && dims[1] == dims[2] {
            assert!(uniform > 0, "{dims:?}: no uniform air bricks");
        }
    }
    // At 65536^3 the corners are air, found without evaluating bricks.
    let src = ProceduralSource::sphere_shells([65536; 3], 32, 2).unwrap();
    let mut buf = vec![0u8; src.layout().brick_bytes()];
    for key in [
        NodeKey::new(3, 0, 0, 0),
        NodeKey::new(11, 0, 0, 0),
        NodeKey::new(11, 2047, 5, 2047),
    ] {
        let info = src.node(key).unwrap();
        assert_eq!(info.kind, NodeKind::Uniform(0.0), "{key:?}");
        src.read_brick(key, &mut buf).unwrap();
        assert!(buf.iter().all(|&v| v == 0));
    }
    let centre = NodeKey::new(11, 1024, 1024, 1024);
    assert_eq!(src.node(centre).unwrap().kind, NodeKind::Data);
}

#[test]
fn store_built_from_the_finest_level_matches() {
    let src = ProceduralSource::fractal_noise([50, 37, 29], 8, 2).unwrap();
    let lay = src.layout().clone();
    let bytes: Vec<u8> = finest(&src).into_iter().map(|v| v as u8).collect();
    let dims = lay.volume.dims;
    let mut r = MemReader::new(dims, DType::U8, bytes);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("p.brick");
    build(
        &mut r,
        &out,
        &BuildOptions {
            brick: 8,
            apron: 2,
            ..BuildOptions::default()
        },
    )
    .unwrap();
    let store = open(&out).unwrap();
    assert_eq!(store.layout().levels, lay.levels);
    let (mut a, mut b) = (vec![0u8; lay.brick_bytes()], vec![0u8; lay.brick_bytes()]);
    for rec in store.nodes() {
        store.read_brick(rec.key, &mut a).unwrap();
        src.read_brick(rec.key, &mut b).unwrap();
        assert_eq!(a, b, "{:?}", rec.key);
        let p = src.node(rec.key).unwrap();
        assert!(
            p.min <= rec.info.min && p.max >= rec.info.max,
            "{:?}",
            rec.key
        );
    }
    let _ = r.desc();
}

#[test]
fn huge_virtual_volume_65536_cubed() {
    let src = ProceduralSource::fractal_noise([65536; 3], 32, 2).unwrap();
    let lay = src.layout().clone();
    assert_eq!(lay.levels, 12);
    let mut buf = vec![0u8; lay.brick_bytes()];
    let mut h = 0x2545_F491_4F6C_DD1Du64;
    let mut rnd = |n: u64| {
        h ^= h << 13;
        h ^= h >> 7;
        h ^= h << 17;
        h % n
    };
    let t = std::time::Instant::now();
    for l in 0..lay.levels {
        for _ in 0..4 {
            let n = 1u64 << l;
            let key = NodeKey::new(l, rnd(n) as u32, rnd(n) as u32, rnd(n) as u32);
            let info = src.node(key).unwrap();
            assert_eq!(info.kind, NodeKind::Data);
            src.read_brick(key, &mut buf).unwrap();
            assert!(
                buf.iter()
                    .all(|&v| (v as f32) >= info.min && (v as f32) <= info.max),
                "{key:?}"
            );
        }
        // Exact filtering at random voxels of this level.
        if l + 1 < lay.levels {
            let d = lay.level_dims(l).map(u64::from);
            let fd = lay.level_dims(l + 1).map(u64::from);
            for _ in 0..20 {
                let p = [rnd(d[0]), rnd(d[1]), rnd(d[2])];
                let lo = p.map(|c| 2 * c);
                let hi = [0, 1, 2].map(|a| (2 * p[a] + 1).min(fd[a] - 1));
                let kids = src.region(l + 1, lo, hi).unwrap();
                let mut v = [0f32; 8];
                let mut c = 0;
                for dz in 0..2 {
                    for dy in 0..2 {
                        for dx in 0..2 {
                            let q = [dx, dy, dz].map(|o: u64| o);
                            let i = [0, 1, 2].map(|a| (lo[a] + q[a]).min(hi[a]) - lo[a]);
                            let n = [0, 1, 2].map(|a| hi[a] - lo[a] + 1);
                            v[c] = kids[(i[0] + n[0] * (i[1] + n[1] * i[2])) as usize] as f32;
                            c += 1;
                        }
                    }
                }
                assert_eq!(
                    src.voxel(l, p).unwrap() as f32,
                    filter_ref(DType::U8, Filter::Average, v),
                    "level {l} voxel {p:?}"
                );
            }
        }
    }
    assert!(t.elapsed().as_secs_f64() < 20.0);
    // Outside the octree.
    assert!(src.node(NodeKey::new(12, 0, 0, 0)).is_err());
}

#[test]
fn non_cubic_virtual_volume_has_empty_outside_nodes() {
    let src = ProceduralSource::fractal_noise([4096, 1000, 3], 16, 2).unwrap();
    let lay = src.layout();
    assert_eq!(
        src.node(NodeKey::new(1, 0, 1, 0)).unwrap().kind,
        NodeKind::Empty
    );
    assert_eq!(
        src.node(NodeKey::new(1, 1, 0, 0)).unwrap().kind,
        NodeKind::Data
    );
    assert!(ProceduralSource::fractal_noise([0, 1, 1], 16, 2).is_err());
    let _ = lay;
}

#[test]
fn degenerate_regions_and_options_are_typed_errors() {
    let src = ProceduralSource::fractal_noise([64, 40, 20], 8, 2).unwrap();
    let levels = src.layout().levels;
    assert_eq!(levels, 4);
    let d = src.layout().level_dims(3).map(u64::from);
    let out_of_range =
        |r: Result<Vec<u8>, StoreError>| matches!(r, Err(StoreError::RegionOutOfRange { .. }));
    // hi < lo on each axis (used to overflow and panic), past the level
    // volume, a level the octree does not have, u64::MAX corners.
    for a in 0..3 {
        let mut lo = [5u64; 3];
        let hi = [5u64; 3];
        lo[a] = 6;
        assert!(out_of_range(src.region(3, lo, hi)), "axis {a}");
        let mut hi = [0u64; 3];
        hi[a] = d[a];
        assert!(out_of_range(src.region(3, [0; 3], hi)), "axis {a}");
        let mut hi = [0u64; 3];
        hi[a] = u64::MAX;
        assert!(out_of_range(src.region(3, [0; 3], hi)), "axis {a}");
    }
    assert!(out_of_range(src.region(levels, [0; 3], [0; 3])));
    assert!(out_of_range(src.region(u8::MAX, [0; 3], [0; 3])));
    assert!(matches!(
        src.voxel(3, d),
        Err(StoreError::RegionOutOfRange {
            level: 3,
            level_dims: Some([64, 40, 20]),
            ..
        })
    ));
    assert!(matches!(
        src.voxel(9, [0; 3]),
        Err(StoreError::RegionOutOfRange {
            level_dims: None,
            ..
        })
    ));
    // The largest corner voxel and the whole finest level are fine.
    assert!(src.voxel(3, d.map(|x| x - 1)).is_ok());
    assert_eq!(
        src.region(3, [0; 3], d.map(|x| x - 1)).unwrap().len(),
        64 * 40 * 20
    );
    // Too large a box: a typed error, not an allocation failure.
    let huge = ProceduralSource::fractal_noise([65536; 3], 32, 2).unwrap();
    let l = huge.layout().levels - 1;
    assert!(matches!(
        huge.region(l, [0; 3], [65535; 3]),
        Err(StoreError::RegionTooLarge { voxels, max }) if voxels == 1 << 48 && max == ProceduralSource::MAX_REGION_VOXELS
    ));
    // Degenerate constructor options.
    for (dims, brick, apron) in [
        ([0u64, 1, 1], 16u32, 2u32),
        ([1, 1, 1 << 25], 16, 2),
        ([1 << 24; 3], 16, 2),
        ([u64::MAX, 2, 2], 16, 2),
        ([8, 8, 8], 0, 2),
        ([8, 8, 8], 513, 2),
        ([8, 8, 8], 8, 17),
        ([8, 8, 8], u32::MAX, u32::MAX),
    ] {
        for r in [
            ProceduralSource::fractal_noise(dims, brick, apron),
            ProceduralSource::sphere_shells(dims, brick, apron),
            ProceduralSource::with_seed(dims, brick, apron, 7),
        ] {
            assert!(
                matches!(r, Err(StoreError::BadOption { .. })),
                "{dims:?} {brick} {apron}: {r:?}"
            );
        }
    }
    // An apron wider than the brick is valid (the apron clamps at the edges
    // like any sample): brick 1, apron 16.
    let wide = ProceduralSource::fractal_noise([5, 3, 2], 1, 16).unwrap();
    let lay = wide.layout().clone();
    let levels = reference_levels(&lay, finest(&wide), Filter::Average);
    check_source(&wide, &levels, None);
}
