//! What the OME-Zarr tests share: the shared images, the client's options,
//! the octree's keys, and the local reader against the remote one.
#![allow(dead_code)]

use crate::common::*;
use brickray_core::{BrickSource, NodeKey};
use brickray_io::ReadOptions;
use brickray_io::zarr::ZarrBrickSource;
use brickray_remote::{RemoteObjects, RemoteOptions};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

pub(crate) const IMAGES: [&str; 3] = [
    "cryoet_tomo_v04.ome.zarr",
    "pycortex_s1_t1_v05.ome.zarr",
    "cells3d_nuclei_sharded_v05.ome.zarr",
];
pub(crate) const SHARDED: &str = "cells3d_nuclei_sharded_v05.ome.zarr";

/// The shared OME-Zarr folder (the tests that need it are ignored, with the
/// reason, when `../shared/data` is absent; with `CI=true` they run and fail
/// without it).
pub(crate) fn data() -> Option<PathBuf> {
    let d = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/formats/ome-zarr");
    if d.join(SHARDED).is_dir() {
        return Some(d);
    }
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!(
            "CI=true but the shared OME-Zarr data is missing at {}",
            d.display()
        );
    }
    eprintln!("skipping: no shared data at {}", d.display());
    None
}

pub(crate) fn opts() -> RemoteOptions {
    RemoteOptions {
        max_retries: 4,
        init_backoff: Duration::from_millis(5),
        max_backoff: Duration::from_millis(40),
        ..loopback(None)
    }
}

/// Every node key of the octree, coarse to fine.
pub(crate) fn keys(src: &dyn BrickSource) -> Vec<NodeKey> {
    let levels = src.layout().levels;
    let mut v = Vec::new();
    for level in 0..levels {
        let n = 1u32 << level;
        for z in 0..n {
            for y in 0..n {
                for x in 0..n {
                    v.push(NodeKey { level, x, y, z });
                }
            }
        }
    }
    v
}

/// The local reader of `dir` and the remote one of `url`, with the local
/// value range (so both convert alike).
pub(crate) fn pair(dir: &Path, url: &str, o: &RemoteOptions) -> (ZarrBrickSource, ZarrBrickSource) {
    let local = ZarrBrickSource::open(dir, &ReadOptions::default(), 32, 2, None).unwrap();
    let range = local.layout().volume.value_range;
    let objects = Arc::new(RemoteObjects::open(url, o).unwrap());
    let remote =
        ZarrBrickSource::open_objects(objects, &ReadOptions::default(), 32, 2, Some(range))
            .unwrap_or_else(|e| panic!("{url}: {e}"));
    (local, remote)
}

/// Asserts every node and brick of `remote` equals `local`'s; returns the
/// number of bricks with data.
pub(crate) fn assert_same(local: &ZarrBrickSource, remote: &ZarrBrickSource) -> usize {
    assert_eq!(local.layout(), remote.layout());
    let mut a = vec![0u8; local.layout().brick_bytes()];
    let mut b = a.clone();
    let mut data = 0;
    for k in keys(local) {
        let (nl, nr) = (local.node(k).unwrap(), remote.node(k).unwrap());
        assert_eq!(nl, nr, "node {k:?}");
        local.read_brick(k, &mut a).unwrap();
        b.fill(0xA5);
        remote.read_brick(k, &mut b).unwrap();
        assert!(a == b, "brick {k:?} differs");
        data += usize::from(nl.min != nl.max);
    }
    data
}

/// Over the network the image reads bricks in batches (each brick on a
/// thread of its own), equal to the local reader's one by one.
pub(crate) fn assert_same_batched(local: &ZarrBrickSource, remote: &ZarrBrickSource) {
    assert_eq!(local.batch_size(), 1);
    assert_eq!(remote.batch_size(), brickray_io::zarr::ZARR_BATCH);
    let brick = local.layout().brick_bytes();
    let all = keys(local);
    for batch in all.chunks(remote.batch_size()) {
        let mut bufs = vec![vec![0xA5u8; brick]; batch.len()];
        let mut outs: Vec<&mut [u8]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
        let results = remote.read_bricks(batch, &mut outs, &brickray_core::CancelToken::new());
        let mut a = vec![0u8; brick];
        for ((k, r), b) in batch.iter().zip(results).zip(&bufs) {
            r.unwrap();
            local.read_brick(*k, &mut a).unwrap();
            assert!(&a == b, "brick {k:?} differs in a batch");
        }
    }
    // A cancelled batch reads nothing.
    let cancel = brickray_core::CancelToken::new();
    cancel.cancel();
    let mut bufs = vec![vec![0u8; brick]; 2];
    let mut outs: Vec<&mut [u8]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
    let r = remote.read_bricks(&all[..2], &mut outs, &cancel);
    assert!(
        r.iter()
            .all(|r| matches!(r, Err(brickray_core::BrickError::Cancelled { .. }))),
        "{r:?}"
    );
}

pub(crate) fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut v = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            v.extend(walk(&p));
        } else {
            v.push(p);
        }
    }
    v
}
