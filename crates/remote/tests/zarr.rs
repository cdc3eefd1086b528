//! OME-Zarr images read over HTTP as brick sources, against the local
//! reader of the same folders (the shared copies in
//! `../shared/data/formats/ome-zarr/`: zarr v2, zarr v3, and v3 sharded).
//!
//! The tests here serve the folders from an in-test HTTP server on loopback
//! that counts every request (and can answer 403 for a missing key, or
//! inject faults), so they run in a plain `cargo test`. The tests against
//! the Range HTTP server and moto of scripts/test.sh are in `servers.rs`'s
//! pattern: ignored here, run by the script's second pass.
#![allow(missing_docs)]

mod common;
mod dir_server;
mod zarr_support;

use brickray_core::{BrickError, BrickSource, NodeKey};
use brickray_io::ReadOptions;
use brickray_io::zarr::ZarrBrickSource;
use brickray_remote::{RemoteError, RemoteObjects, RemoteOptions};
use common::*;
use dir_server::{Act, serve_dir};
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;
use zarr_support::*;

#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn zarr_over_http_equals_the_local_reader_brick_for_brick() {
    let Some(data) = data() else { return };
    let server = serve_dir(&data, 404, |_, _| Act::Serve);
    for name in IMAGES {
        let (local, remote) = pair(&data.join(name), &server.url(name), &opts());
        let n = assert_same(&local, &remote);
        assert!(n > 8, "{name}: only {n} bricks with data");
        assert_same_batched(&local, &remote);
        assert_eq!(local.image().version(), remote.image().version());
        assert_eq!(local.placement(), remote.placement());
    }
    // The object reads sent no HEAD (no size requests).
    let heads = server.seen().iter().filter(|s| s.0 == "HEAD").count();
    assert_eq!(heads, 0, "{:?}", server.seen());
}

/// Copies a folder tree.
fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let (src, dst) = (e.path(), to.join(e.file_name()));
        if src.is_dir() {
            copy_tree(&src, &dst);
        } else {
            std::fs::copy(&src, &dst).unwrap();
        }
    }
}

#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn a_missing_chunk_404_or_403_reads_as_the_fill_value() {
    let Some(data) = data() else { return };
    let dir = tempfile::tempdir().unwrap();
    // A shard of the sharded image and a chunk of the v2 image removed.
    let sharded = dir.path().join(SHARDED);
    copy_tree(&data.join(SHARDED), &sharded);
    std::fs::remove_file(sharded.join("s0/c/0/0/0")).unwrap();
    let v2 = dir.path().join("cryoet_tomo_v04.ome.zarr");
    copy_tree(&data.join("cryoet_tomo_v04.ome.zarr"), &v2);
    std::fs::remove_file(v2.join("s0/0/0/0")).unwrap();
    for status in [404, 403] {
        let server = serve_dir(dir.path(), status, |_, _| Act::Serve);
        for (root, name) in [(&sharded, SHARDED), (&v2, "cryoet_tomo_v04.ome.zarr")] {
            // The local reader of the same (damaged) copy reads fill values.
            let (local, remote) = pair(root, &server.url(name), &opts());
            assert_same(&local, &remote);
            // and the removed chunk made a difference to the first brick of
            // the finest level
            let whole = ZarrBrickSource::open(
                &data.join(name),
                &ReadOptions::default(),
                32,
                2,
                Some(local.layout().volume.value_range),
            )
            .unwrap();
            let finest = local.layout().levels - 1;
            let k = NodeKey {
                level: finest,
                x: 0,
                y: 0,
                z: 0,
            };
            let mut a = vec![0u8; local.layout().brick_bytes()];
            let mut b = a.clone();
            whole.read_brick(k, &mut a).unwrap();
            remote.read_brick(k, &mut b).unwrap();
            assert!(a != b, "{name}: the missing chunk changed nothing");
        }
        let missing = server
            .seen()
            .iter()
            .filter(|s| s.1.ends_with("/s0/c/0/0/0") || s.1.ends_with("/s0/0/0/0"))
            .count();
        assert!(
            missing >= 2,
            "{status}: the missing keys were not asked for"
        );
    }
}

#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn faults_give_the_exact_bricks_or_a_typed_error_never_a_hang() {
    let Some(data) = data() else { return };
    // Transient: every 4th GET a 503, a reset or a truncated body.
    let server = serve_dir(&data, 404, |n, _| match n % 12 {
        3 => Act::Status(503),
        7 => Act::Reset,
        11 => Act::Truncate,
        _ => Act::Serve,
    });
    for name in [SHARDED, "pycortex_s1_t1_v05.ome.zarr"] {
        let (local, remote) = pair(&data.join(name), &server.url(name), &opts());
        assert_same(&local, &remote);
    }
    // Persistent: every chunk read fails (metadata served): typed errors
    // naming the URL, within the deadline.
    let server = serve_dir(&data, 404, |_, path| {
        if path.contains("/c/") {
            Act::Status(500)
        } else {
            Act::Serve
        }
    });
    let o = RemoteOptions {
        max_retries: 2,
        retry_timeout: Duration::from_secs(3),
        ..opts()
    };
    let url = server.url(SHARDED);
    let objects = Arc::new(RemoteObjects::open(&url, &o).unwrap());
    let t = std::time::Instant::now();
    let remote =
        ZarrBrickSource::open_objects(objects, &ReadOptions::default(), 32, 2, Some([0.0, 1.0]))
            .unwrap();
    let mut b = vec![0u8; remote.layout().brick_bytes()];
    let k = NodeKey {
        level: 0,
        x: 0,
        y: 0,
        z: 0,
    };
    match remote.read_brick(k, &mut b) {
        Err(BrickError::Io { source, .. }) => {
            let e = RemoteError::from_io(&source).unwrap_or_else(|| panic!("untyped: {source}"));
            assert!(matches!(e, RemoteError::Request { .. }), "{e}");
            assert!(e.url().starts_with(&url), "{e}");
        }
        other => panic!("{other:?}"),
    }
    assert!(t.elapsed() < o.deadline() * 2, "{:?}", t.elapsed());
}

#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn image_urls_are_told_from_store_urls() {
    let Some(data) = data() else { return };
    let dir = tempfile::tempdir().unwrap();
    // An image in a folder whose name does not say so, and a folder of
    // plain zarr metadata without multiscales.
    copy_tree(&data.join(SHARDED), &dir.path().join("image"));
    std::fs::create_dir_all(dir.path().join("plain")).unwrap();
    std::fs::write(
        dir.path().join("plain/zarr.json"),
        br#"{"zarr_format": 3, "node_type": "group", "attributes": {}}"#,
    )
    .unwrap();
    let server = serve_dir(dir.path(), 404, |_, _| Act::Serve);
    let o = opts();
    assert!(brickray_store::is_zarr_url(&server.url("image"), &o));
    assert!(brickray_store::is_zarr_url(&server.url("image/"), &o));
    assert!(!brickray_store::is_zarr_url(&server.url("plain"), &o));
    assert!(!brickray_store::is_zarr_url(&server.url("absent"), &o));
    let before = server.count();
    // By name, without a request.
    assert!(brickray_store::is_zarr_url(&server.url("x.ome.zarr"), &o));
    assert!(!brickray_store::is_zarr_url(&server.url("x.brs"), &o));
    assert_eq!(server.count(), before);
    // The folder streams as the local image.
    let (local, remote) = pair(&data.join(SHARDED), &server.url("image"), &o);
    assert_same(&local, &remote);
}

#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn bad_urls_and_keys_are_typed_errors() {
    let o = opts();
    assert!(matches!(
        RemoteObjects::open("ftp://h/x.zarr", &o),
        Err(RemoteError::BadUrl { .. })
    ));
    let r = RemoteObjects::open("http://127.0.0.1:1/x.zarr/", &o).unwrap();
    assert_eq!(r.url(), "http://127.0.0.1:1/x.zarr");
    for key in ["../secret", "a//b", "", "./a"] {
        assert!(
            matches!(
                r.get(key, brickray_core::ObjectSpan::All),
                Err(RemoteError::BadUrl { .. })
            ),
            "{key}"
        );
    }
    let s3 = RemoteObjects::open(
        "s3://bucket/dir/img.zarr",
        &RemoteOptions {
            anonymous: true,
            endpoint: Some("http://127.0.0.1:1".into()),
            region: Some("us-east-1".into()),
            ..o.clone()
        },
    )
    .unwrap();
    assert_eq!(s3.url(), "s3://bucket/dir/img.zarr");
    // A root that serves no image: a typed error, not a panic.
    let Some(data) = data() else { return };
    let server = serve_dir(&data, 404, |_, _| Act::Serve);
    let objects = Arc::new(RemoteObjects::open(&server.url("nothing.zarr"), &o).unwrap());
    assert!(matches!(
        ZarrBrickSource::open_objects(objects, &ReadOptions::default(), 32, 2, None),
        Err(brickray_io::IoError::UnknownFormat { .. })
    ));
}

// ---------------------------------------------------------------------------
// Against the test servers of scripts/test.sh (ignored in a plain `cargo
// test`; run by the script's second pass, failing when CI=true and an
// address is missing).

/// Uploads the image folder `dir` under `url` (one object per file).
fn upload_image(dir: &Path, url: &str, o: &RemoteOptions) -> usize {
    let files = walk(dir);
    for f in &files {
        let rel = f
            .strip_prefix(dir)
            .unwrap()
            .to_string_lossy()
            .replace('\\', "/");
        upload(&format!("{url}/{rel}"), o, &std::fs::read(f).unwrap());
    }
    files.len()
}

#[test]
#[ignore = "needs BRICKRAY_TEST_HTTP and BRICKRAY_TEST_S3 (scripts/test.sh starts them)"]
fn zarr_from_the_http_server_and_s3_equals_the_local_reader() {
    let (Some(http), Some(s3)) = (server("BRICKRAY_TEST_HTTP"), server("BRICKRAY_TEST_S3")) else {
        return;
    };
    let Some(data) = data() else { return };
    let name = unique("zarr");
    let bucket = name.to_ascii_lowercase();
    create_bucket(&s3, &bucket, false);
    for image in IMAGES {
        let dir = data.join(image);
        let http_url = format!("{http}/{name}/{image}");
        upload_image(&dir, &http_url, &loopback(None));
        let s3_url = format!("s3://{bucket}/images/{image}");
        upload_image(&dir, &s3_url, &s3_signed(&s3));
        for (url, o) in [(http_url, loopback(None)), (s3_url, s3_signed(&s3))] {
            assert!(brickray_store::is_zarr_url(&url, &o), "{url}");
            let (local, remote) = pair(&dir, &url, &o);
            let n = assert_same(&local, &remote);
            assert!(n > 8, "{url}: only {n} bricks with data");
            // The store-level entry point: the default brick, the value
            // range from the coarsest level (a warning says so).
            let src =
                brickray_store::open_zarr_url(&url, &o, &ReadOptions::default(), 32, 2).unwrap();
            assert_eq!(src.layout().volume.dims, local.layout().volume.dims);
            assert!(
                src.warnings().iter().any(|w| w.contains("coarsest level")),
                "{url}: {:?}",
                src.warnings()
            );
        }
    }
    // A key missing in a private bucket read anonymously is a 403: the
    // image's metadata cannot be read, a typed error (not a fill value).
    let anon = RemoteOptions {
        anonymous: true,
        ..loopback(Some(&s3))
    };
    let url = format!("s3://{bucket}/images/{SHARDED}");
    match brickray_store::open_zarr_url(&url, &anon, &ReadOptions::default(), 32, 2) {
        Err(e @ brickray_store::StoreError::Input(brickray_io::IoError::UnknownFormat { .. })) => {
            assert!(e.to_string().contains("access denied"), "{e}");
        }
        Err(e) => panic!("{url}: {e}"),
        Ok(_) => panic!("{url}: a private bucket opened anonymously"),
    }
    // A chunk removed from the S3 copy reads as the fill value, exactly as
    // the local reader of a copy without it.
    let tmp = tempfile::tempdir().unwrap();
    let damaged = tmp.path().join(SHARDED);
    copy_tree(&data.join(SHARDED), &damaged);
    std::fs::remove_file(damaged.join("s0/c/0/0/0")).unwrap();
    let s3_url = format!("s3://{bucket}/damaged/{SHARDED}");
    upload_image(&damaged, &s3_url, &s3_signed(&s3));
    let (local, remote) = pair(&damaged, &s3_url, &s3_signed(&s3));
    assert_same(&local, &remote);
}

#[test]
#[ignore = "needs BRICKRAY_TEST_HTTP(_FAULTY) and BRICKRAY_TEST_S3(_FAULTY) (scripts/test.sh starts them)"]
fn zarr_through_a_faulty_proxy_is_exact_or_typed_never_wrong() {
    let (Some(http), Some(http_faulty), Some(s3), Some(s3_faulty)) = (
        server("BRICKRAY_TEST_HTTP"),
        server("BRICKRAY_TEST_HTTP_FAULTY"),
        server("BRICKRAY_TEST_S3"),
        server("BRICKRAY_TEST_S3_FAULTY"),
    ) else {
        return;
    };
    let Some(data) = data() else { return };
    let faulty = |o: RemoteOptions| RemoteOptions {
        max_retries: 6,
        timeout: Duration::from_secs(5),
        read_timeout: Duration::from_millis(300),
        retry_timeout: Duration::from_secs(20),
        ..o
    };
    let name = unique("zarr-faulty");
    let bucket = name.to_ascii_lowercase();
    create_bucket(&s3, &bucket, false);
    let dir = data.join(SHARDED);
    upload_image(&dir, &format!("{http}/{name}/{SHARDED}"), &loopback(None));
    let s3_url = format!("s3://{bucket}/{SHARDED}");
    upload_image(&dir, &s3_url, &s3_signed(&s3));
    let local = ZarrBrickSource::open(&dir, &ReadOptions::default(), 32, 2, None).unwrap();
    let range = local.layout().volume.value_range;
    for (url, o) in [
        (
            format!("{http_faulty}/{name}/{SHARDED}"),
            faulty(loopback(None)),
        ),
        (s3_url, faulty(s3_signed(&s3_faulty))),
    ] {
        let t = std::time::Instant::now();
        let objects = Arc::new(RemoteObjects::open(&url, &o).unwrap());
        let remote =
            ZarrBrickSource::open_objects(objects, &ReadOptions::default(), 32, 2, Some(range))
                .unwrap_or_else(|e| panic!("{url}: open failed after its retries: {e}"));
        let (mut ok, mut failed) = (0usize, 0usize);
        let mut a = vec![0u8; local.layout().brick_bytes()];
        let mut b = a.clone();
        for k in keys(&local) {
            local.read_brick(k, &mut a).unwrap();
            let t = std::time::Instant::now();
            match remote.read_brick(k, &mut b) {
                Ok(()) => {
                    assert!(a == b, "{url}: brick {k:?} differs");
                    ok += 1;
                }
                Err(BrickError::Io { source, .. }) => {
                    assert!(RemoteError::from_io(&source).is_some(), "{source}");
                    failed += 1;
                }
                Err(e) => panic!("{url}: {k:?}: untyped failure {e}"),
            }
            assert!(
                t.elapsed() <= o.deadline(),
                "{url}: a read took {:?}",
                t.elapsed()
            );
        }
        eprintln!(
            "{url}: {ok} bricks exact, {failed} failed typed, {:?}",
            t.elapsed()
        );
        assert!(
            ok > 10 * failed.max(1) || failed == 0,
            "{url}: {ok} ok, {failed} failed"
        );
    }
}

#[test]
#[cfg_attr(no_shared_data, ignore = "needs ../shared/data/formats (absent)")]
fn a_forged_shard_index_or_huge_metadata_is_a_typed_error() {
    let Some(data) = data() else { return };
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join(SHARDED);
    copy_tree(&data.join(SHARDED), &root);
    // The first entry of a shard's index points past the shard (the crc32c
    // after the entries rewritten to match, so only the bounds check can
    // refuse it).
    let shard = root.join("s0/c/0/0/0");
    let mut b = std::fs::read(&shard).unwrap();
    let n = b.len();
    let at = n - (32 * 16 + 4);
    b[at..at + 8].copy_from_slice(&(n as u64 * 2).to_le_bytes());
    let crc = crc32c(&b[at..n - 4]);
    b[n - 4..].copy_from_slice(&crc.to_le_bytes());
    std::fs::write(&shard, &b).unwrap();
    let server = serve_dir(dir.path(), 404, |_, _| Act::Serve);
    let objects = Arc::new(RemoteObjects::open(&server.url(SHARDED), &opts()).unwrap());
    let remote =
        ZarrBrickSource::open_objects(objects, &ReadOptions::default(), 32, 2, Some([0.0, 1.0]))
            .unwrap();
    let finest = remote.layout().levels - 1;
    let k = NodeKey {
        level: finest,
        x: 0,
        y: 0,
        z: 0,
    };
    let mut out = vec![0u8; remote.layout().brick_bytes()];
    match remote.read_brick(k, &mut out) {
        Err(BrickError::Corrupt { reason, .. }) => {
            assert!(reason.contains("outside the shard"), "{reason}")
        }
        other => panic!("{other:?}"),
    }
    // A group metadata object over 1 MiB: refused, not parsed.
    let big = dir.path().join("big.zarr");
    std::fs::create_dir_all(&big).unwrap();
    std::fs::write(big.join("zarr.json"), vec![b' '; (1 << 20) + 10]).unwrap();
    let objects = Arc::new(RemoteObjects::open(&server.url("big.zarr"), &opts()).unwrap());
    match ZarrBrickSource::open_objects(objects, &ReadOptions::default(), 32, 2, None) {
        Err(brickray_io::IoError::BadHeader { msg, .. }) => assert!(msg.contains("1 MiB"), "{msg}"),
        other => panic!("{other:?}"),
    }
}

/// CRC-32C (Castagnoli), bitwise.
fn crc32c(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0x82F6_3B78
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// A multi-channel OME-Zarr over HTTP reads as the same channels, voxel for
/// voxel, with the same `omero` metadata (colours, windows, labels, active)
/// as the local folder (`read_zarr_channels_url` against `read_channels`).
#[test]
fn multi_channel_zarr_over_http_equals_the_local_read() {
    use brickray_core::channels::ChannelVolume;
    use brickray_core::{Volume, VolumeData, VolumeDesc};
    use brickray_io::ChannelInfo;
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("cells.ome.zarr");
    let dims = [20u32, 18, 9];
    let n = (dims[0] * dims[1] * dims[2]) as usize;
    let channel = |k: u16| {
        let data: Vec<u16> = (0..n)
            .map(|i| (i as u16).wrapping_mul(7 + k) % 3000)
            .collect();
        let desc = VolumeDesc {
            dims,
            dtype: brickray_core::DType::U16,
            spacing: [1.0, 1.0, 2.0],
            value_range: [0.0, 2999.0],
            kind: Default::default(),
        };
        Volume::new(desc, VolumeData::U16(data)).unwrap()
    };
    let vol = ChannelVolume::new(vec![channel(0), channel(5)]).unwrap();
    let info = vec![
        ChannelInfo {
            label: Some("nuclei".into()),
            color: Some([0.0, 1.0, 0.0]),
            window: Some([100.0, 2000.0]),
            active: true,
        },
        ChannelInfo {
            label: Some("membrane".into()),
            color: Some([1.0, 0.0, 1.0]),
            window: Some([50.0, 900.0]),
            active: false,
        },
    ];
    brickray_io::zarr::write_ome_zarr_channels(&root, &vol, &info).unwrap();
    let server = serve_dir(dir.path(), 404, |_, _| Act::Serve);
    let read = ReadOptions::default();
    let remote =
        brickray_store::read_zarr_channels_url(&server.url("cells.ome.zarr"), &opts(), &read)
            .unwrap();
    let local = brickray_io::read_channels(&root, &read).unwrap();
    assert_eq!(remote.volume, local.volume);
    assert_eq!(remote.info, local.info);
    assert_eq!(remote.volume.len(), 2);
    for (c, v) in remote.volume.channels().iter().enumerate() {
        assert_eq!(v.data(), vol.channels()[c].data(), "channel {c}");
    }
    assert_eq!(remote.info[1].label.as_deref(), Some("membrane"));
    assert!(!remote.styles()[1].visible);
    // A channel the image does not have is a typed error, as locally.
    let bad = ReadOptions::default().channels(Some(vec![2]));
    assert!(
        brickray_store::read_zarr_channels_url(&server.url("cells.ome.zarr"), &opts(), &bad)
            .is_err()
    );
}
