//! OME-Zarr images over HTTP, what goes over the network: each shard index
//! once with a suffix range, shared chunks fetched once, metadata of many
//! nodes read together, cancelled batches abort their requests, decoded
//! chunks cached within a budget, and a second visit through the disk cache
//! sends only metadata requests. Requests are counted by the in-test HTTP
//! server (`dir_server`).
#![allow(missing_docs)]

mod common;
mod dir_server;
mod zarr_support;

use brickray_core::{BrickError, BrickSource, NodeKey};
use brickray_io::ReadOptions;
use brickray_io::zarr::ZarrBrickSource;
use brickray_remote::RemoteOptions;
use dir_server::{Act, Seen, serve_dir};
use std::path::PathBuf;
use std::time::Duration;
use zarr_support::*;

/// Over the network the metadata of many nodes is read at once (each node
/// on a thread of its own, as the loader asks for a brick's children), equal
/// to the local reader's, and a chunk (or shard index) that several nodes
/// share is fetched once: one thread fetches it while the others wait.
#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn nodes_read_together_equal_the_local_ones_and_fetch_each_range_once() {
    let Some(data) = data() else { return };
    let server = serve_dir(&data, 404, |_, _| Act::Serve);
    for name in IMAGES {
        let (local, remote) = pair(&data.join(name), &server.url(name), &opts());
        let before = server.count();
        let wanted: Vec<NodeKey> = keys(&local).into_iter().filter(|k| k.level <= 2).collect();
        let got = remote.nodes(&wanted);
        assert_eq!(got.len(), wanted.len());
        for (k, r) in wanted.iter().zip(got) {
            assert_eq!(r.unwrap(), local.node(*k).unwrap(), "{name}: node {k:?}");
        }
        let seen = server.seen()[before..].to_vec();
        assert!(!seen.is_empty(), "{name}: nothing fetched");
        let mut distinct: Vec<&Seen> = seen.iter().collect();
        distinct.sort();
        distinct.dedup();
        assert_eq!(
            distinct.len(),
            seen.len(),
            "{name}: a range fetched twice by {} nodes read together",
            wanted.len()
        );
    }
}

/// A batch of bricks cancelled while its chunk requests are in flight gives
/// up without their answers (the loader cancels a batch the view left) and
/// fails every brick as cancelled.
#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn a_batch_cancelled_in_flight_aborts_its_chunk_requests() {
    let Some(data) = data() else { return };
    // Every chunk or shard read (not metadata) is answered after 5 s.
    let server = serve_dir(&data, 404, |_, path| {
        if path.contains("/c/") {
            Act::Stall(5000)
        } else {
            Act::Serve
        }
    });
    let (local, remote) = pair(&data.join(SHARDED), &server.url(SHARDED), &opts());
    let finest = local.layout().levels - 1;
    let keys: Vec<NodeKey> = keys(&local)
        .into_iter()
        .filter(|k| k.level == finest && local.layout().in_volume(*k))
        .take(4)
        .collect();
    assert_eq!(keys.len(), 4);
    let brick = local.layout().brick_bytes();
    let mut bufs = vec![vec![0u8; brick]; keys.len()];
    let mut outs: Vec<&mut [u8]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
    let cancel = brickray_core::CancelToken::new();
    let c = cancel.clone();
    let canceller = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(200));
        c.cancel();
    });
    let started = std::time::Instant::now();
    let results = remote.read_bricks(&keys, &mut outs, &cancel);
    let took = started.elapsed();
    canceller.join().unwrap();
    for (k, r) in keys.iter().zip(&results) {
        assert!(
            matches!(r, Err(BrickError::Cancelled { key }) if key == k),
            "{k:?}: {r:?}"
        );
    }
    // It did not wait for the stalled answers (5 s, and the reader's
    // retries after them).
    assert!(took < Duration::from_secs(4), "gave up after {took:?}");
    assert!(
        server.seen().iter().any(|s| s.1.contains("/c/")),
        "no chunk was requested before the cancel"
    );
}

#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn each_shard_index_is_fetched_once_with_a_suffix_range() {
    let Some(data) = data() else { return };
    let server = serve_dir(&data, 404, |_, _| Act::Serve);
    let (local, remote) = pair(&data.join(SHARDED), &server.url(SHARDED), &opts());
    assert_same(&local, &remote);
    let seen = server.seen();
    // The shards: the level folders' chunk keys (not metadata).
    let shards: Vec<&Seen> = seen
        .iter()
        .filter(|s| s.1.contains("/c/") && s.0 == "GET")
        .collect();
    assert!(!shards.is_empty());
    // 2 x 4 x 4 inner chunks per shard of 32 x 128 x 128 in 16 x 32 x 32:
    // 32 entries of 16 bytes and a crc32c.
    let index = format!("bytes=-{}", 32 * 16 + 4);
    let mut paths: Vec<&str> = shards.iter().map(|s| s.1.as_str()).collect();
    paths.sort();
    paths.dedup();
    let on_disk: Vec<PathBuf> = ["s0", "s1"]
        .iter()
        .flat_map(|l| walk(&data.join(SHARDED).join(l).join("c")))
        .collect();
    assert_eq!(paths.len(), on_disk.len(), "every shard read: {paths:?}");
    for p in &paths {
        let suffix: Vec<_> = shards
            .iter()
            .filter(|s| s.1 == *p && s.2.as_deref().is_some_and(|r| r.starts_with("bytes=-")))
            .collect();
        assert_eq!(suffix.len(), 1, "{p}: index reads {suffix:?}");
        assert_eq!(suffix[0].2.as_deref(), Some(index.as_str()), "{p}");
        // everything else read from a shard is a bounded range of its data
        for s in shards.iter().filter(|s| s.1 == *p) {
            let r = s.2.as_deref().unwrap_or("");
            assert!(r.starts_with("bytes="), "{p}: a whole-shard read {s:?}");
        }
    }
    assert!(seen.iter().all(|s| s.0 == "GET"), "{seen:?}");
    // With the whole image within the chunk cache's budget, no range of any
    // object is asked for twice (metadata, indices, inner chunks).
    let mut distinct: Vec<(&str, Option<&str>)> = seen
        .iter()
        .map(|s| (s.1.as_str(), s.2.as_deref()))
        .collect();
    distinct.sort();
    distinct.dedup();
    assert_eq!(distinct.len(), seen.len(), "a range fetched twice");
    eprintln!(
        "{SHARDED}: {} requests for {} shards ({} index reads)",
        seen.len(),
        paths.len(),
        paths.len()
    );
}

#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn decoded_chunks_are_cached_within_the_budget() {
    let Some(data) = data() else { return };
    let server = serve_dir(&data, 404, |_, _| Act::Serve);
    for name in [SHARDED, "cryoet_tomo_v04.ome.zarr"] {
        let (local, remote) = pair(&data.join(name), &server.url(name), &opts());
        let keys = keys(&local);
        let mut b = vec![0u8; remote.layout().brick_bytes()];
        for &k in &keys {
            remote.read_brick(k, &mut b).unwrap();
        }
        let s = remote.image().chunk_cache_stats();
        assert!(s.bytes <= s.budget && s.chunks > 0, "{s:?}");
        // Everything read again: from the cache, not one request.
        let before = server.count();
        for &k in &keys {
            remote.read_brick(k, &mut b).unwrap();
        }
        assert_eq!(server.count(), before, "{name}: requests on a second pass");
        let again = remote.image().chunk_cache_stats();
        assert!(again.hits > s.hits && again.misses == s.misses, "{again:?}");
        // A budget of one small chunk: kept within it, still exact.
        let budget = 64 << 10;
        remote.image().set_chunk_cache_budget(budget);
        let mut a = vec![0u8; local.layout().brick_bytes()];
        let with_data: Vec<NodeKey> = keys
            .iter()
            .rev()
            .copied()
            .filter(|&k| local.node(k).is_ok_and(|n| n.min != n.max))
            .take(40)
            .collect();
        assert!(
            with_data.len() > 8,
            "{name}: {} bricks with data",
            with_data.len()
        );
        for &k in &with_data {
            local.read_brick(k, &mut a).unwrap();
            remote.read_brick(k, &mut b).unwrap();
            assert!(a == b, "{name}: brick {k:?} with a small cache");
            assert!(remote.image().chunk_cache_stats().bytes <= budget);
        }
        assert!(
            server.count() > before,
            "{name}: a small cache fetched nothing"
        );
    }
}

/// With a disk cache (`RemoteOptions::disk_cache`) a second visit of an
/// image reads its chunks, shard indices and absent keys from the disk:
/// over the network it sends only the metadata requests, and every brick
/// is the local reader's.
#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn a_second_visit_through_the_disk_cache_fetches_only_the_metadata() {
    let Some(data) = data() else { return };
    let server = serve_dir(&data, 404, |_, _| Act::Serve);
    let cache = tempfile::tempdir().unwrap();
    let o = RemoteOptions {
        disk_cache: Some(brickray_remote::DiskCacheConfig {
            dir: cache.path().to_owned(),
            max_bytes: 1 << 30,
        }),
        ..opts()
    };
    let is_metadata = |s: &Seen| {
        let name = s.1.rsplit('/').next().unwrap_or("");
        ["zarr.json", ".zattrs", ".zarray", ".zgroup", ".zmetadata"].contains(&name)
    };
    for name in [SHARDED, "cryoet_tomo_v04.ome.zarr"] {
        let mut requests = Vec::new();
        for visit in 0..2 {
            let before = server.count();
            let remote = brickray_store::open_zarr_url(
                &server.url(name),
                &o,
                &ReadOptions::default(),
                32,
                2,
            )
            .unwrap_or_else(|e| panic!("{name}: {e}"));
            // The local reader with the remote one's value range (both
            // convert alike).
            let range = Some(remote.layout().volume.value_range);
            let local =
                ZarrBrickSource::open(&data.join(name), &ReadOptions::default(), 32, 2, range)
                    .unwrap();
            assert_same(&local, &remote);
            let seen = server.seen()[before..].to_vec();
            let data_requests = seen.iter().filter(|s| !is_metadata(s)).count();
            eprintln!(
                "{name}, visit {visit}: {} requests, {data_requests} for samples",
                seen.len()
            );
            requests.push((seen.len(), data_requests));
        }
        assert!(
            requests[0].1 > 0,
            "{name}: the first visit fetched no samples"
        );
        assert_eq!(requests[1].1, 0, "{name}: the second visit fetched samples");
        assert!(requests[1].0 < requests[0].0);
    }
}
