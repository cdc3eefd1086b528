//! A store read over HTTP (the Range server of scripts/test-servers) and S3
//! (moto), against the local file. The servers' addresses come from
//! BRICKRAY_TEST_HTTP and BRICKRAY_TEST_S3, which scripts/test.sh sets; the
//! tests are ignored in a plain `cargo test` and run with
//! `cargo test -p brickray-remote -- --ignored` (failing, not skipping, when
//! CI=true and an address is missing).
#![allow(missing_docs)]

mod common;

use brickray_core::{BrickSource, RangeReader};
use brickray_remote::{RemoteError, RemoteOptions, RemoteRangeReader};
use brickray_store::{Store, StoreError, open_url};
use common::*;

const NEEDS_HTTP: &str =
    "needs BRICKRAY_TEST_HTTP (a Range HTTP server; scripts/test.sh starts one)";
const NEEDS_S3: &str = "needs BRICKRAY_TEST_S3 (an S3 server, moto; scripts/test.sh starts one)";

fn remote_error(e: &StoreError) -> &RemoteError {
    match e {
        StoreError::Io { source, .. } => {
            RemoteError::from_io(source).unwrap_or_else(|| panic!("not a remote error: {e}"))
        }
        other => panic!("not an I/O error: {other}"),
    }
}

#[test]
#[ignore = "needs BRICKRAY_TEST_HTTP (a Range HTTP server; scripts/test.sh starts one)"]
fn http_store_equals_the_local_file_brick_for_brick() {
    let Some(http) = server("BRICKRAY_TEST_HTTP") else {
        return eprintln!("{NEEDS_HTTP}");
    };
    let dir = tempfile::tempdir().unwrap();
    let (path, bytes) = small_store(dir.path());
    let url = format!("{http}/{}/small.brs", unique("http"));
    let opts = loopback(None);
    upload(&url, &opts, &bytes);
    let local = Store::open(&path).unwrap();
    let remote = open_url(&url, &opts).unwrap();
    assert_eq!(remote.path().to_string_lossy(), url);
    assert_same_store(&local, &remote);
    // The reader itself: its length, and the last bytes (the table's end).
    let r = RemoteRangeReader::open(&url, &opts).unwrap();
    assert_eq!(r.len().unwrap(), bytes.len() as u64);
    let mut tail = [0u8; 100];
    r.read_exact_at(&mut tail, bytes.len() as u64 - 100)
        .unwrap();
    assert_eq!(&tail[..], &bytes[bytes.len() - 100..]);
    // What it fetched: the HEAD at open and that range.
    assert_eq!(
        r.fetched(),
        brickray_remote::Fetched {
            requests: 2,
            bytes: 100
        }
    );
    // Neighbouring ranges are one request; one far away (more than 1 MiB
    // on) would be another, here the object is small: one.
    let (mut a, mut b) = ([0u8; 64], [0u8; 32]);
    let mut ranges = [
        brickray_core::RangeRead {
            offset: 200,
            buf: &mut a,
        },
        brickray_core::RangeRead {
            offset: 300,
            buf: &mut b,
        },
    ];
    r.read_ranges(&mut ranges).unwrap();
    assert_eq!(&a[..], &bytes[200..264]);
    assert_eq!(&b[..], &bytes[300..332]);
    let f = r.fetched();
    assert_eq!(f.requests, 3, "{f:?}");
    // The coalesced request spans both ranges and the gap between.
    assert_eq!(f.bytes, 100 + 132, "{f:?}");
    assert!(r.is_remote());
    // A store over the network reads bricks in batches.
    assert_eq!(remote.batch_size(), brickray_store::STORE_BATCH);
}

#[test]
#[ignore = "needs BRICKRAY_TEST_HTTP (a Range HTTP server; scripts/test.sh starts one)"]
fn http_errors_are_typed_and_name_the_url() {
    let Some(http) = server("BRICKRAY_TEST_HTTP") else {
        return eprintln!("{NEEDS_HTTP}");
    };
    let opts = loopback(None);
    // A missing object: 404, typed as missing, the URL in the message.
    let url = format!("{http}/{}/absent.brs", unique("missing"));
    let e = open_url(&url, &opts).unwrap_err();
    let r = remote_error(&e);
    assert!(r.is_missing(), "{r}");
    assert_eq!(r.url(), url);
    assert!(e.to_string().contains(&url), "{e}");
    // Plain HTTP not allowed: refused before any request.
    let e = open_url(&url, &RemoteOptions::default()).unwrap_err();
    assert!(
        matches!(remote_error(&e), RemoteError::HttpNotAllowed { .. }),
        "{e}"
    );

    // A truncated store: the parser's typed error, never a panic.
    let dir = tempfile::tempdir().unwrap();
    let (_, bytes) = small_store(dir.path());
    let cut = format!("{http}/{}/cut.brs", unique("cut"));
    upload(&cut, &opts, &bytes[..bytes.len() - 7]);
    match open_url(&cut, &opts) {
        Err(StoreError::BadHeader { .. } | StoreError::Truncated { .. }) => {}
        other => panic!("{other:?}"),
    }
    // Not a store at all.
    let junk = format!("{http}/{}/junk.brs", unique("junk"));
    upload(&junk, &opts, &[7u8; 300]);
    assert!(matches!(
        open_url(&junk, &opts),
        Err(StoreError::NotAStore { .. })
    ));
    // Ranges past the object's end: typed, before any request.
    let r = RemoteRangeReader::open(&junk, &opts).unwrap();
    let mut b = [0u8; 10];
    let e = r.read_range(&mut b, 295).unwrap_err();
    assert!(
        matches!(
            e,
            RemoteError::OutOfBounds {
                object_len: 300,
                ..
            }
        ),
        "{e}"
    );
    let e = r.read_exact_at(&mut b, u64::MAX - 3).unwrap_err();
    assert_eq!(e.kind(), std::io::ErrorKind::UnexpectedEof);
    // A store replaced under the reader by shorter bytes: the read fails
    // with a typed error, never returns other bytes.
    upload(&junk, &opts, &[9u8; 100]);
    let e = r.read_range(&mut b, 200).unwrap_err();
    assert!(
        matches!(
            e,
            RemoteError::Request { .. } | RemoteError::WrongLength { .. }
        ),
        "{e}"
    );
}

#[test]
#[ignore = "needs BRICKRAY_TEST_S3 (an S3 server, moto; scripts/test.sh starts one)"]
fn s3_store_equals_the_local_file_signed_and_anonymous() {
    let Some(s3) = server("BRICKRAY_TEST_S3") else {
        return eprintln!("{NEEDS_S3}");
    };
    let bucket = unique("brickray").to_ascii_lowercase();
    create_bucket(&s3, &bucket, false);
    let dir = tempfile::tempdir().unwrap();
    let (path, bytes) = small_store(dir.path());
    let url = format!("s3://{bucket}/stores/small.brs");
    let signed = s3_signed(&s3);
    upload(&url, &signed, &bytes);
    let local = Store::open(&path).unwrap();
    let remote = open_url(&url, &signed).unwrap();
    assert_same_store(&local, &remote);
    // Without credentials (unsigned requests): a private bucket answers 403,
    // typed as missing (S3 does not say whether the key exists); a public
    // bucket serves the same store.
    let anonymous = RemoteOptions {
        anonymous: true,
        ..loopback(Some(&s3))
    };
    let e = open_url(&url, &anonymous).unwrap_err();
    assert!(
        matches!(remote_error(&e), RemoteError::Missing { denied: true, .. }),
        "{e}"
    );
    let public = unique("public").to_ascii_lowercase();
    create_bucket(&s3, &public, true);
    let url = format!("s3://{public}/small.brs");
    upload(&url, &signed, &bytes);
    let remote = open_url(&url, &anonymous).unwrap();
    assert_same_store(&local, &remote);
    // The endpoint must be allowed to be plain HTTP.
    let e = open_url(
        &url,
        &RemoteOptions {
            allow_http: false,
            ..signed.clone()
        },
    )
    .unwrap_err();
    assert!(
        matches!(remote_error(&e), RemoteError::HttpNotAllowed { .. }),
        "{e}"
    );
}

#[test]
#[ignore = "needs BRICKRAY_TEST_S3 (an S3 server, moto; scripts/test.sh starts one)"]
fn s3_missing_keys_and_buckets_are_typed_missing() {
    let Some(s3) = server("BRICKRAY_TEST_S3") else {
        return eprintln!("{NEEDS_S3}");
    };
    let bucket = unique("brickray").to_ascii_lowercase();
    create_bucket(&s3, &bucket, false);
    let signed = s3_signed(&s3);
    for url in [
        format!("s3://{bucket}/no/such.brs"),
        format!("s3://{}/x.brs", unique("nobucket").to_ascii_lowercase()),
    ] {
        let e = open_url(&url, &signed).unwrap_err();
        let r = remote_error(&e);
        assert!(r.is_missing(), "{url}: {r}");
        assert_eq!(r.url(), url);
    }
    // A truncated object on S3: the parser's typed error.
    let dir = tempfile::tempdir().unwrap();
    let (_, bytes) = small_store(dir.path());
    let cut = format!("s3://{bucket}/cut.brs");
    upload(&cut, &signed, &bytes[..bytes.len() / 2]);
    match open_url(&cut, &signed) {
        Err(StoreError::BadHeader { .. } | StoreError::Truncated { .. }) => {}
        other => panic!("{other:?}"),
    }
}

/// Reads through the fault-injecting proxies (scripts/test-servers/
/// fault_proxy.py: latency, 503, 429, resets, truncated and stalled bodies,
/// in a fixed cycle): every brick either equals the local file's or fails
/// with a typed error, each read within its deadline; most reads recover.
#[test]
#[ignore = "needs BRICKRAY_TEST_HTTP(_FAULTY) and BRICKRAY_TEST_S3(_FAULTY) (scripts/test.sh starts them)"]
fn reads_through_a_faulty_proxy_are_exact_or_typed_never_wrong() {
    let (Some(http), Some(http_faulty), Some(s3), Some(s3_faulty)) = (
        server("BRICKRAY_TEST_HTTP"),
        server("BRICKRAY_TEST_HTTP_FAULTY"),
        server("BRICKRAY_TEST_S3"),
        server("BRICKRAY_TEST_S3_FAULTY"),
    ) else {
        return eprintln!("{NEEDS_HTTP}; {NEEDS_S3}");
    };
    let dir = tempfile::tempdir().unwrap();
    let (path, bytes) = small_store(dir.path());
    let local = Store::open(&path).unwrap();
    let faulty = |o: RemoteOptions| RemoteOptions {
        max_retries: 6,
        timeout: std::time::Duration::from_secs(5),
        read_timeout: std::time::Duration::from_millis(300),
        retry_timeout: std::time::Duration::from_secs(20),
        ..o
    };
    // Uploaded to the servers directly, read through the proxies.
    let name = unique("faulty");
    let direct = format!("{http}/{name}/small.brs");
    upload(&direct, &loopback(None), &bytes);
    let bucket = name.to_ascii_lowercase();
    create_bucket(&s3, &bucket, false);
    let s3_url = format!("s3://{bucket}/small.brs");
    upload(&s3_url, &s3_signed(&s3), &bytes);
    let cases = [
        (
            format!("{http_faulty}/{name}/small.brs"),
            faulty(loopback(None)),
        ),
        (s3_url, faulty(s3_signed(&s3_faulty))),
    ];
    for (url, opts) in cases {
        let t = std::time::Instant::now();
        let remote = match open_url(&url, &opts) {
            Ok(s) => s,
            Err(e) => {
                // Typed, never a hang; a rerun meets other faults.
                assert!(
                    t.elapsed() <= opts.deadline() * 3,
                    "{url}: {:?}",
                    t.elapsed()
                );
                remote_error(&e);
                panic!("{url}: open failed through the proxy after its retries: {e}");
            }
        };
        assert_eq!(
            local.nodes().collect::<Vec<_>>(),
            remote.nodes().collect::<Vec<_>>()
        );
        let mut a = vec![0u8; local.layout().brick_bytes()];
        let mut b = a.clone();
        let (mut ok, mut failed) = (0usize, 0usize);
        for n in local.nodes() {
            local.read(n.key, &mut a).unwrap();
            let t = std::time::Instant::now();
            match remote.read(n.key, &mut b) {
                Ok(()) => {
                    assert!(a == b, "{url}: brick {:?} differs", n.key);
                    ok += 1;
                }
                Err(StoreError::NodeIo { source, .. }) => {
                    assert!(RemoteError::from_io(&source).is_some(), "{source}");
                    failed += 1;
                }
                Err(e) => panic!("{url}: {:?}: untyped failure {e}", n.key),
            }
            assert!(
                t.elapsed() <= opts.deadline(),
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
#[ignore = "needs BRICKRAY_TEST_HTTP and BRICKRAY_TEST_HTTP_SLOW (a proxy delaying every request; scripts/test.sh starts both)"]
fn a_cancelled_read_gives_up_before_its_answer() {
    use brickray_core::{CancelToken, RangeRead};
    use std::sync::Arc;
    let (Some(http), Some(slow)) = (
        server("BRICKRAY_TEST_HTTP"),
        server("BRICKRAY_TEST_HTTP_SLOW"),
    ) else {
        return eprintln!("{NEEDS_HTTP}");
    };
    let dir = tempfile::tempdir().unwrap();
    let (_path, bytes) = small_store(dir.path());
    let name = unique("cancel");
    upload(&format!("{http}/{name}/small.brs"), &loopback(None), &bytes);
    // Every request through the slow proxy is answered after 300 ms.
    let url = format!("{slow}/{name}/small.brs");
    let reader = Arc::new(RemoteRangeReader::open(&url, &loopback(None)).unwrap());
    let read = |cancel_after: Option<std::time::Duration>| {
        let cancel = CancelToken::new();
        let (r, c) = (reader.clone(), cancel.clone());
        let t = std::thread::spawn(move || {
            let mut buf = [0u8; 64];
            let mut ranges = [RangeRead {
                offset: 100,
                buf: &mut buf,
            }];
            r.read_many_cancellable(&mut ranges, &c).map(|()| buf)
        });
        if let Some(after) = cancel_after {
            std::thread::sleep(after);
            cancel.cancel();
        }
        t.join().unwrap()
    };
    // Cancelled 50 ms in: it gives up (an answer would come at 300 ms).
    match read(Some(std::time::Duration::from_millis(50))) {
        Err(RemoteError::Cancelled { url: u }) => assert_eq!(u, url),
        other => panic!("{other:?}"),
    }
    // Not cancelled: the same read completes with the bytes.
    assert_eq!(read(None).unwrap()[..], bytes[100..164]);
    // A store's batch cancelled in flight fails its data bricks as
    // cancelled, and nodes without a payload still read.
    let store = Arc::new(Store::open_with(reader.clone(), &url).unwrap());
    let keys: Vec<brickray_core::NodeKey> = store.nodes().map(|n| n.key).collect();
    let cancel = CancelToken::new();
    let (s, c, k) = (store.clone(), cancel.clone(), keys.clone());
    let t = std::thread::spawn(move || {
        let brick = s.layout().brick_bytes();
        let mut bufs = vec![vec![0u8; brick]; k.len()];
        let mut outs: Vec<&mut [u8]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
        s.read_bricks(&k, &mut outs, &c)
    });
    std::thread::sleep(std::time::Duration::from_millis(50));
    cancel.cancel();
    let results = t.join().unwrap();
    for (key, r) in keys.iter().zip(&results) {
        if store.record(*key).unwrap().payload_len > 0 {
            assert!(
                matches!(r, Err(brickray_core::BrickError::Cancelled { .. })),
                "{key:?}: {r:?}"
            );
        } else {
            assert!(r.is_ok(), "{key:?}: {r:?}");
        }
    }
}

#[test]
#[ignore = "needs BRICKRAY_TEST_HTTP (a Range HTTP server; scripts/test.sh starts one)"]
fn a_second_visit_reads_the_disk_cache_not_the_network() {
    use brickray_remote::{DiskCacheConfig, DiskCached};
    let Some(http) = server("BRICKRAY_TEST_HTTP") else {
        return eprintln!("{NEEDS_HTTP}");
    };
    let dir = tempfile::tempdir().unwrap();
    let (path, bytes) = small_store(dir.path());
    let url = format!("{http}/{}/small.brs", unique("cache"));
    upload(&url, &loopback(None), &bytes);
    let config = DiskCacheConfig {
        dir: dir.path().join("cache"),
        max_bytes: 64 << 20,
    };
    let local = Store::open(&path).unwrap();
    // Through open_url with the cache configured: the same store.
    let opts = RemoteOptions {
        disk_cache: Some(config.clone()),
        ..loopback(None)
    };
    assert_same_store(&local, &open_url(&url, &opts).unwrap());
    // A second visit: only the size request (which validates the cache
    // against the object's ETag and length) reaches the server.
    let visit = || {
        let reader = RemoteRangeReader::open(&url, &loopback(None)).unwrap();
        let id = format!(
            "{url}\n{}\n{}",
            reader.etag().unwrap_or(""),
            reader.object_len()
        );
        let cached = std::sync::Arc::new(DiskCached::new(reader, &id, &config).unwrap());
        let store = Store::open_with(cached.clone(), &url).unwrap();
        assert_same_store(&local, &store);
        (cached.inner().fetched(), cached.stats())
    };
    let (fetched, stats) = visit();
    assert_eq!(fetched.requests, 1, "{fetched:?} {stats:?}");
    assert_eq!(stats.misses, 0, "{stats:?}");
    assert!(stats.hits > 2, "{stats:?}");
}
