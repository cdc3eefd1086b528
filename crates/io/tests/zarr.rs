//! OME-Zarr: both fixtures (0.4 with blosc, 0.5 with zstd) decode at level 0
//! voxel for voxel to their raw volumes with the sidecar's spacing; levels are
//! listed and selectable; a missing chunk reads as the fill value and a
//! corrupt one is a typed error; the streamed BrickSource's finest bricks
//! equal those of a store built from the raw volume.
#![cfg(feature = "zarr")]

mod formats_common;

use brickray_core::{BrickSource, NodeKey, NodeKind};
use brickray_io::zarr::ZarrBrickSource;
use brickray_io::{self as io, EntryKind, IoError, ReadOptions};
use formats_common::*;
use std::path::{Path, PathBuf};
use tempfile::TempDir;

fn fixture(name: &str) -> Option<PathBuf> {
    formats_dir().map(|d| d.join("ome-zarr").join(name))
}

const CASES: [(&str, &str); 2] = [
    ("cryoet_tomo_v04.ome.zarr", "cryoet_tomo"),
    ("pycortex_s1_t1_v05.ome.zarr", "pycortex_s1_t1_mri"),
];

#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn fixtures_decode_at_the_finest_level() {
    for (store, raw) in CASES {
        let Some(p) = fixture(store) else { return };
        let t = truth(raw);
        let mut r = io::open(&p).unwrap_or_else(|e| panic!("{store}: {e}"));
        assert_eq!(r.format(), "OME-Zarr");
        assert_eq!(r.desc().dims, t.desc.dims, "{store}");
        assert_eq!(r.desc().dtype, t.desc.dtype, "{store}");
        assert_spacing(r.desc().spacing, t.desc.spacing, store);
        assert_same_voxels(&read_by_slabs(r.as_mut(), 20), &t, store);
        assert_eq!(r.desc().value_range, t.desc.value_range, "{store}");
        let pl = r.placement().unwrap();
        assert_eq!(
            pl.voxel_to_world([1.0, 2.0, 3.0]),
            [1.0, 2.0, 3.0],
            "{store}"
        );
    }
}

#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn levels_are_listed_and_selectable() {
    let Some(p) = fixture("pycortex_s1_t1_v05.ome.zarr") else {
        return;
    };
    let list = io::list(&p, &ReadOptions::default()).unwrap();
    let levels: Vec<_> = list.iter().filter(|e| e.kind == EntryKind::Level).collect();
    assert!(levels.len() >= 3, "{list:?}");
    assert!(levels[0].default);
    // level 1: y and x halved, z kept, spacing doubled in x and y
    let mut r = io::open_with(&p, &ReadOptions::default().level(Some(1))).unwrap();
    assert_eq!(r.desc().dims, [128, 128, 256]);
    assert_eq!(r.desc().spacing, [2.0, 2.0, 1.0]);
    let v = r.read_volume().unwrap();
    assert_eq!(v.dims(), [128, 128, 256]);
    let e = io::open_with(&p, &ReadOptions::default().level(Some(99)))
        .err()
        .unwrap();
    assert!(
        matches!(e, IoError::NoSuchChoice { what: "level", .. }),
        "{e}"
    );
    let e = io::open_with(&p, &ReadOptions::default().channel(Some(1)))
        .err()
        .unwrap();
    assert!(
        matches!(
            e,
            IoError::NoSuchChoice {
                what: "channel",
                ..
            }
        ),
        "{e}"
    );
}

fn copy_dir(src: &Path, dst: &Path) {
    std::fs::create_dir_all(dst).unwrap();
    for e in std::fs::read_dir(src).unwrap() {
        let e = e.unwrap();
        let to = dst.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &to);
        } else {
            std::fs::copy(e.path(), &to).unwrap();
            let mut perm = std::fs::metadata(&to).unwrap().permissions();
            #[allow(clippy::permissions_set_readonly_false)]
            perm.set_readonly(false);
            std::fs::set_permissions(&to, perm).unwrap();
        }
    }
}

#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn missing_chunk_is_fill_corrupt_chunk_is_an_error() {
    let Some(p) = fixture("pycortex_s1_t1_v05.ome.zarr") else {
        return;
    };
    let t = truth("pycortex_s1_t1_mri");
    let d = TempDir::new().unwrap();
    let z = d.path().join("x.ome.zarr");
    copy_dir(&p, &z);
    // chunk (z=1, y=2, x=0) of s0 removed: voxels 64..128 x 128..192 x 0..64 read 0
    std::fs::remove_file(z.join("s0/c/1/2/0")).unwrap();
    let mut r = io::open(&z).unwrap();
    let got = read_by_slabs(r.as_mut(), 64);
    for zz in 0..256usize {
        for y in 0..256usize {
            let row = (zz * 256 + y) * 256;
            for x in (0..256usize).step_by(7) {
                let inside = (64..128).contains(&zz) && (128..192).contains(&y) && x < 64;
                let want = if inside { 0 } else { t.bytes[row + x] };
                assert_eq!(got[row + x], want, "voxel ({x}, {y}, {zz})");
            }
        }
    }
    // a corrupt chunk: an error naming the level, no panic
    std::fs::write(z.join("s0/c/0/0/0"), b"not zstd at all").unwrap();
    let e = io::open(&z).err().expect("corrupt chunk refused");
    assert!(
        matches!(&e, IoError::Decode { path, .. } if path.ends_with("s0")),
        "{e}"
    );
    // a corrupt blosc chunk in the v0.4 store
    let Some(p4) = fixture("cryoet_tomo_v04.ome.zarr") else {
        return;
    };
    let z4 = d.path().join("y.ome.zarr");
    copy_dir(&p4, &z4);
    std::fs::write(z4.join("s0/0/0/0"), [0u8; 40]).unwrap();
    let e = io::open(&z4).err().expect("corrupt blosc chunk refused");
    assert!(matches!(&e, IoError::Decode { .. }), "{e}");
    // no multiscales
    std::fs::write(z4.join(".zattrs"), b"{}").unwrap();
    let e = io::open(&z4).err().unwrap();
    assert!(matches!(&e, IoError::BadHeader { .. }), "{e}");
}

#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn streamed_bricks_equal_the_built_store_at_the_finest_level() {
    let Some(p) = fixture("cryoet_tomo_v04.ome.zarr") else {
        return;
    };
    let json = brickray_harness::shared_volume("cryoet_tomo").unwrap();
    let vol = io::read_volume(&json).unwrap();
    let dir = TempDir::new().unwrap();
    let store = brickray_harness::store_of(&vol, &dir.path().join("tomo.brs"));
    let lay = store.layout().clone();
    let src =
        ZarrBrickSource::open(&p, &ReadOptions::default(), lay.brick, lay.apron, None).unwrap();
    assert_eq!(src.layout(), &lay);
    let fin = lay.levels - 1;
    let n = 1u32 << fin;
    let mut a = vec![0u8; lay.brick_bytes()];
    let mut b = vec![0u8; lay.brick_bytes()];
    let mut compared = 0;
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                let key = NodeKey::new(fin, x, y, z);
                let (ia, ib) = (store.node(key).unwrap(), src.node(key).unwrap());
                assert_eq!(
                    ia.kind == NodeKind::Empty,
                    ib.kind == NodeKind::Empty,
                    "{key:?}"
                );
                if ia.kind == NodeKind::Empty {
                    continue;
                }
                store.read_brick(key, &mut a).unwrap();
                src.read_brick(key, &mut b).unwrap();
                assert!(a == b, "brick {key:?} differs");
                assert_eq!((ia.min, ia.max), (ib.min, ib.max), "{key:?}");
                compared += 1;
            }
        }
    }
    assert!(compared >= 8, "{compared} bricks compared");
    // every level answers (pyramid level plus filtering along z)
    for l in 0..fin {
        let info = src.node(NodeKey::new(l, 0, 0, 0)).unwrap();
        assert!(info.min <= info.max);
        src.read_brick(NodeKey::new(l, 0, 0, 0), &mut b).unwrap();
    }
}

/// The sharded fixture (zarr v3 sharding, index at the end of each shard,
/// zstd inner chunks) decodes voxel for voxel at level 0: every shard index
/// is checked against its shard before zarrs reads it.
#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn sharded_fixture_decodes_at_the_finest_level() {
    let Some(p) = fixture("cells3d_nuclei_sharded_v05.ome.zarr") else {
        return;
    };
    let t = truth("cells3d_nuclei_fluo");
    let mut r = io::open(&p).unwrap();
    assert_eq!(r.desc().dims, t.desc.dims);
    assert_eq!(r.desc().dtype, t.desc.dtype);
    assert_same_voxels(&read_by_slabs(r.as_mut(), 16), &t, "sharded");
    assert!(r.warnings().is_empty(), "{:?}", r.warnings());
}

/// An image with a `labels/` group: the group lists its label image, which
/// opens as a label map (kind, label value range, ids unchanged, in a whole
/// read and streamed) with the colours of its `image-label`; the image
/// itself stays an intensity image.
#[test]
fn label_images_of_an_ome_zarr_open_as_label_maps() {
    let dir = tempfile::tempdir().unwrap();
    let image = dir.path().join("cells.ome.zarr");
    let dims = [70u32, 5, 4];
    let n = (dims[0] * dims[1] * dims[2]) as usize;
    let pixels: Vec<u8> = (0..n).map(|i| (i * 7 % 250) as u8).collect();
    let ids: Vec<u8> = (0..n).map(|i| [0u8, 1, 2, 7][i % 4]).collect();
    let spacing = [1.0, 1.0, 2.0];
    let img = brickray_core::Volume::new(
        brickray_core::VolumeDesc {
            dims,
            dtype: brickray_core::DType::U8,
            spacing,
            value_range: [0.0, 255.0],
            kind: Default::default(),
        },
        brickray_core::VolumeData::U8(pixels.clone()),
    )
    .unwrap();
    io::zarr::write_ome_zarr(&image, &img, None).unwrap();
    let labels = brickray_core::labels::label_volume(
        dims,
        spacing,
        brickray_core::VolumeData::U8(ids.clone()),
    )
    .unwrap();
    let mut colours = brickray_core::LabelTable::default();
    colours.set_color(7, [1.0, 0.0, 0.0]);
    colours.set_opacity(7, 128.0 / 255.0);
    io::zarr::add_ome_zarr_labels(&image, "nuclei", &labels, (&colours, &[7])).unwrap();
    // A hostile name in the list is skipped.
    let list = image.join("labels/.zattrs");
    std::fs::write(&list, r#"{"labels": ["nuclei", "../escape", ""]}"#).unwrap();
    let label_dir = image.join("labels/nuclei");
    assert!(io::zarr::add_ome_zarr_labels(&image, "../x", &labels, (&colours, &[])).is_err());
    let img = brickray_io::zarr::OmeZarr::open(&image).unwrap();
    assert!(!img.is_labels());
    assert_eq!(img.label_groups().unwrap(), vec!["nuclei".to_string()]);
    assert!(img.label_table().is_none());
    let intensity = brickray_io::read_volume(&image).unwrap();
    assert!(!intensity.desc().kind.is_labels());
    assert_eq!(
        intensity.data().as_bytes(),
        &pixels[..],
        "the writer round-trips"
    );
    assert_eq!(intensity.desc().spacing, spacing);

    let lab = brickray_io::zarr::OmeZarr::open(&label_dir).unwrap();
    assert!(lab.is_labels());
    assert!(lab.label_groups().unwrap().is_empty());
    let table = lab.label_table().unwrap();
    let rgba = table.rgba(7);
    assert_eq!(&rgba[..3], &[1.0, 0.0, 0.0]);
    assert!((rgba[3] - 128.0 / 255.0).abs() < 1e-6);
    let vol = brickray_io::read_volume(&label_dir).unwrap();
    assert!(vol.desc().kind.is_labels());
    assert_eq!(
        vol.desc().value_range,
        brickray_core::labels::label_value_range()
    );
    assert_eq!(vol.data().as_bytes(), &ids[..]);
    let src = ZarrBrickSource::open(&label_dir, &ReadOptions::default(), 8, 1, None).unwrap();
    assert!(src.layout().volume.kind.is_labels());
}
