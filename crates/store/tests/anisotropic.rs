//! Anisotropic pyramids: stores built with `BuildOptions::anisotropic` halve the
//! finer axes first, record their split masks in the header, and read back
//! brick for brick against a reference pyramid that averages along the halved
//! axes only.

mod common;

use brickray_core::{ALL_AXES, DType, NodeKey, OctreeLayout};
use brickray_store::{BuildOptions, Filter, build, open};
use common::*;

fn aniso(brick: u32, apron: u32, filter: Filter) -> BuildOptions {
    BuildOptions {
        brick,
        apron,
        filter,
        anisotropic: true,
        ..BuildOptions::default()
    }
}

fn reader(dims: [u32; 3], dtype: DType, spacing: [f32; 3], bytes: Vec<u8>) -> MemReader {
    let mut r = MemReader::new(dims, dtype, bytes);
    r.desc.spacing = spacing;
    r
}

/// Builds, opens and checks every node against the reference pyramid.
fn roundtrip(r: &mut MemReader, o: &BuildOptions) -> OctreeLayout {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("v.brs");
    let report = build(r, &out, o).unwrap();
    let store = open(&out).unwrap();
    assert_eq!(store.layout(), &report.layout);
    let want = OctreeLayout::anisotropic(r.desc.clone(), o.brick, o.apron);
    assert_eq!(store.layout(), &want);
    let levels = reference_levels(store.layout(), decode(r.desc.dtype, &r.bytes), o.filter);
    check_source(&store, &levels, o.empty_below);
    store.layout().clone()
}

/// For integer dtypes the average over a level that halves `k` axes is the
/// rounded mean of the `2^k` distinct fine voxels (the builder reads a kept
/// axis's voxel twice; this checks that against the plain mean).
fn check_plain_means(layout: &OctreeLayout, finest: &[f32]) {
    let levels = reference_levels(layout, finest.to_vec(), Filter::Average);
    for l in 0..layout.levels as usize - 1 {
        let m = layout.split_mask(l as u8);
        let f = [0, 1, 2].map(|a| if m & (1 << a) != 0 { 2usize } else { 1 });
        let fd = layout.level_dims(l as u8 + 1).map(|d| d as usize);
        let cd = layout.level_dims(l as u8).map(|d| d as usize);
        for k in 0..cd[2] {
            for j in 0..cd[1] {
                for i in 0..cd[0] {
                    let mut vals = Vec::new();
                    for dz in 0..f[2] {
                        for dy in 0..f[1] {
                            for dx in 0..f[0] {
                                let x = (f[0] * i + dx).min(fd[0] - 1);
                                let y = (f[1] * j + dy).min(fd[1] - 1);
                                let z = (f[2] * k + dz).min(fd[2] - 1);
                                vals.push(levels[l + 1][x + fd[0] * (y + fd[1] * z)] as i64);
                            }
                        }
                    }
                    let n = vals.len() as i64;
                    let mean = (vals.iter().sum::<i64>() + n / 2).div_euclid(n);
                    assert_eq!(
                        levels[l][i + cd[0] * (j + cd[1] * k)] as i64,
                        mean,
                        "level {l} voxel {i},{j},{k}"
                    );
                }
            }
        }
    }
}

#[test]
fn synthetic_thick_slices_all_dtypes() {
    // 0.5 x 0.5 x 4: x and y are halved three times before z.
    let dims = [70, 45, 11];
    for (i, dtype) in [DType::U8, DType::U16, DType::I16, DType::F32]
        .into_iter()
        .enumerate()
    {
        let bytes = test_volume(dims, dtype, 20 + i as u64);
        for o in [aniso(8, 2, Filter::Average), aniso(4, 1, Filter::Max)] {
            let mut r = reader(dims, dtype, [0.5, 0.5, 4.0], bytes.clone());
            let l = roundtrip(&mut r, &o);
            assert!(!l.is_isotropic());
            assert_eq!(l.split_mask(l.levels - 2), 0b011);
        }
    }
    let bytes = test_volume(dims, DType::U16, 5);
    let l = OctreeLayout::anisotropic(
        reader(dims, DType::U16, [0.5, 0.5, 4.0], bytes.clone()).desc,
        8,
        2,
    );
    check_plain_means(&l, &decode(DType::U16, &bytes));
}

#[test]
fn synthetic_z_fine_and_mixed_masks() {
    // z finest (z alone halved first), and 1 x 1.5 x 4 (x, y, then x alone).
    for (dims, spacing, masks) in [
        ([9, 13, 90], [3.0, 3.0, 0.4], vec![7, 7, 4, 4, 4]),
        ([50, 33, 20], [1.0, 1.5, 4.0], vec![7, 7, 7, 1, 3]),
    ] {
        let bytes = test_volume(dims, DType::I16, 3);
        let mut r = reader(dims, DType::I16, spacing, bytes.clone());
        let l = roundtrip(&mut r, &aniso(4, 2, Filter::Average));
        assert_eq!(l.split_masks(), masks);
        check_plain_means(&l, &decode(DType::I16, &bytes));
    }
}

#[test]
fn banded_build_matches_reference() {
    // A memory bound that forces y-bands on the finest level.
    let dims = [96, 96, 12];
    let bytes = test_volume(dims, DType::U16, 11);
    let mut r = reader(dims, DType::U16, [0.5, 0.5, 3.0], bytes);
    let o = BuildOptions {
        memory_bound: 600 << 10,
        ..aniso(8, 2, Filter::Average)
    };
    let dir = tempfile::tempdir().unwrap();
    let report = build(&mut r, &dir.path().join("v.brs"), &o).unwrap();
    assert!(report.banded_levels > 0, "{report:?}");
    roundtrip(&mut r, &o);
}

#[test]
fn isotropic_volumes_build_the_same_file() {
    // Near-isotropic spacing: the anisotropic switch changes nothing, byte for byte.
    let dims = [37, 21, 13];
    let bytes = test_volume(dims, DType::U16, 2);
    let dir = tempfile::tempdir().unwrap();
    let mut files = Vec::new();
    for anisotropic in [false, true] {
        let mut r = reader(dims, DType::U16, [1.0, 1.2, 0.9], bytes.clone());
        let out = dir.path().join(format!("{anisotropic}.brs"));
        let o = BuildOptions {
            anisotropic,
            ..BuildOptions {
                brick: 8,
                ..BuildOptions::default()
            }
        };
        build(&mut r, &out, &o).unwrap();
        files.push(std::fs::read(&out).unwrap());
    }
    assert_eq!(files[0], files[1]);
    // And the same volume without the switch but with thick slices stays isotropic.
    let mut r = reader(dims, DType::U16, [1.0, 1.0, 5.0], bytes);
    let out = dir.path().join("iso.brs");
    build(
        &mut r,
        &out,
        &BuildOptions {
            brick: 8,
            ..BuildOptions::default()
        },
    )
    .unwrap();
    let s = open(&out).unwrap();
    assert!(s.layout().is_isotropic());
    assert!(s.layout().split_masks().iter().all(|m| *m == ALL_AXES));
}

#[test]
fn damaged_split_masks_are_typed_errors() {
    let dims = [70, 45, 11];
    let bytes = test_volume(dims, DType::U8, 1);
    let mut r = reader(dims, DType::U8, [0.5, 0.5, 4.0], bytes);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("v.brs");
    build(&mut r, &out, &aniso(8, 2, Filter::Average)).unwrap();
    let good = std::fs::read(&out).unwrap();
    let patch = |f: &dyn Fn(&mut Vec<u8>)| {
        let mut b = good.clone();
        f(&mut b);
        let crc = crc32fast::hash(&b[..124]);
        b[124..128].copy_from_slice(&crc.to_le_bytes());
        let p = dir.path().join("bad.brs");
        std::fs::write(&p, &b).unwrap();
        open(&p).map(|_| ()).unwrap_err().to_string()
    };
    // A zero mask (level 1).
    let e = patch(&|b| b[108] &= !0b111_000);
    assert!(e.contains("split_masks"), "{e}");
    // Bits past the last mask.
    let e = patch(&|b| b[119] = 0x80);
    assert!(e.contains("reserved"), "{e}");
    // Masks that do not cover the volume (all x only).
    let e = patch(&|b| {
        b[108..120].fill(0);
        b[108] = 0b001_001;
    });
    assert!(e.contains("split_masks") || e.contains("levels"), "{e}");
    // The flag cleared: the dims imply another level count.
    let e = patch(&|b| b[30] &= !2);
    assert!(e.contains("reserved") || e.contains("levels"), "{e}");
}

#[test]
fn head_ct_at_thick_slices_round_trips() {
    let Some(dir) = shared_data() else { return };
    let json = dir.join("invesalius_cranium_ct/invesalius_cranium_ct.json");
    let vol = brickray_io::read_volume(&json).unwrap();
    let d = vol.desc().clone();
    // Keep every third slice: 0.957 x 0.957 x 4.5 mm.
    let slice = d.dims[0] as usize * d.dims[1] as usize * 2;
    let all = vol.data().as_bytes();
    let nz = d.dims[2].div_ceil(3);
    let bytes: Vec<u8> = (0..nz as usize)
        .flat_map(|z| all[3 * z * slice..(3 * z + 1) * slice].iter().copied())
        .collect();
    let dims = [d.dims[0], d.dims[1], nz];
    let mut r = reader(
        dims,
        DType::I16,
        [d.spacing[0], d.spacing[1], d.spacing[2] * 3.0],
        bytes,
    );
    let l = roundtrip(&mut r, &aniso(32, 2, Filter::Average));
    assert_eq!(l.split_masks(), vec![ALL_AXES, 0b011, 0b011]);
    assert_eq!(l.levels, 4);
    // The root is one brick of 32 x 32 x 18 voxels of 7.7 x 7.7 x 9 mm.
    assert_eq!(l.level_dims(0), [32, 32, 18]);
    assert_eq!(l.children(NodeKey::new(2, 1, 1, 0)).len(), 4);
}
