//! A store whose file is deleted and restored while it is open: reads fail
//! while the file is gone, and succeed again once it is back (the store
//! reopens its path), never reading a different file put in its place.
#![allow(missing_docs)]

mod common;

use brickray_core::{BrickSource, DType, NodeKind};
use brickray_store::{BuildOptions, StoreError, build, open};
use common::*;
use std::path::Path;

fn build_store(path: &Path, seed: u64) {
    let dims = [40u32, 36, 30];
    let mut r = MemReader::new(dims, DType::U16, test_volume(dims, DType::U16, seed));
    let opts = BuildOptions {
        brick: 8,
        apron: 1,
        ..BuildOptions::default()
    };
    build(&mut r, path, &opts).unwrap();
}

/// Truncates the file in place (the open store's inode loses its bytes), then
/// removes it: what a careless copy over the file, or a disk that drops it,
/// leaves the store with.
fn delete(path: &Path) {
    std::fs::OpenOptions::new()
        .write(true)
        .truncate(true)
        .open(path)
        .unwrap();
    std::fs::remove_file(path).unwrap();
}

#[test]
fn reads_recover_once_the_file_is_restored() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("v.brs");
    build_store(&path, 1);
    let backup = dir.path().join("backup");
    std::fs::copy(&path, &backup).unwrap();
    let other = dir.path().join("other.brs");
    build_store(&other, 2);

    let store = open(&path).unwrap();
    let keys: Vec<_> = store
        .nodes()
        .filter(|n| n.info.kind == NodeKind::Data)
        .map(|n| n.key)
        .collect();
    assert!(keys.len() > 10);
    let mut buf = vec![0u8; store.layout().brick_bytes()];
    let originals: Vec<Vec<u8>> = keys
        .iter()
        .map(|&k| {
            store.read(k, &mut buf).unwrap();
            buf.clone()
        })
        .collect();

    // Gone: every read fails, with a typed error.
    delete(&path);
    for &k in &keys {
        let e = store.read(k, &mut buf).unwrap_err();
        assert!(
            matches!(
                e,
                StoreError::NodeIo { .. } | StoreError::PayloadChecksum { .. }
            ),
            "{k:?}: {e}"
        );
        assert!(store.read_brick(k, &mut buf).is_err());
    }

    // Another store in its place is never read.
    std::fs::copy(&other, &path).unwrap();
    for &k in &keys {
        assert!(
            store.read(k, &mut buf).is_err(),
            "{k:?} read from another store"
        );
    }

    // Restored: the same reads succeed and give the same bricks.
    std::fs::remove_file(&path).unwrap();
    std::fs::copy(&backup, &path).unwrap();
    for (&k, want) in keys.iter().zip(&originals) {
        store.read_brick(k, &mut buf).unwrap();
        assert_eq!(&buf, want, "{k:?}");
    }
    // From every thread at once, after another loss and restore.
    delete(&path);
    std::fs::copy(&backup, &path).unwrap();
    std::thread::scope(|s| {
        for t in 0..4 {
            let (store, keys, originals) = (&store, &keys, &originals);
            s.spawn(move || {
                let mut buf = vec![0u8; store.layout().brick_bytes()];
                for (i, (&k, want)) in keys.iter().zip(originals).enumerate() {
                    if i % 4 == t {
                        store.read(k, &mut buf).unwrap();
                        assert_eq!(&buf, want, "{k:?}");
                    }
                }
            });
        }
    });
}
