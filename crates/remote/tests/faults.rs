//! Faults between the remote reader and an HTTP server, on loopback: an
//! in-test server that answers ranges and injects latency, 503 and 429
//! bursts, connection resets, truncated and stalled bodies and wrong
//! `Content-Range`s. Every read either returns the exact bytes (after
//! retries) or a typed error within its deadline: never wrong bytes, never a
//! hang. Needs no external server (runs in a plain `cargo test`).
#![allow(missing_docs)]

mod common;

use brickray_core::RangeReader;
use brickray_remote::{RemoteError, RemoteOptions, RemoteRangeReader};
use brickray_store::{Store, StoreError};
use common::*;
use std::io::{BufReader, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

/// What the server does with one GET (HEADs are always answered).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Act {
    Serve,
    Delay(u64),
    Status(u16),
    Reset,
    Truncate,
    Stall,
    WrongRange,
}

struct Server {
    port: u16,
    gets: Arc<AtomicUsize>,
    stop: Arc<AtomicBool>,
}

impl Drop for Server {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        let _ = TcpStream::connect(("127.0.0.1", self.port));
    }
}

/// Serves `bytes` as `/s.brs`; `plan(n)` decides the n-th GET.
fn serve(bytes: Vec<u8>, plan: impl Fn(usize) -> Act + Send + Sync + 'static) -> Server {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let gets = Arc::new(AtomicUsize::new(0));
    let stop = Arc::new(AtomicBool::new(false));
    let (g, s) = (gets.clone(), stop.clone());
    let bytes = Arc::new(bytes);
    let plan = Arc::new(plan);
    std::thread::spawn(move || {
        for conn in listener.incoming() {
            if s.load(Ordering::SeqCst) {
                break;
            }
            let Ok(conn) = conn else { continue };
            let (bytes, plan, g, s) = (bytes.clone(), plan.clone(), g.clone(), s.clone());
            std::thread::spawn(move || {
                let _ = handle(conn, &bytes, &*plan, &g, &s);
            });
        }
    });
    Server { port, gets, stop }
}

fn handle(
    conn: TcpStream,
    bytes: &[u8],
    plan: &(dyn Fn(usize) -> Act + Send + Sync),
    gets: &AtomicUsize,
    stop: &AtomicBool,
) -> std::io::Result<()> {
    let mut reader = BufReader::new(conn.try_clone()?);
    let mut out = conn;
    loop {
        let Some(Request {
            method,
            path,
            range,
        }) = read_request(&mut reader)?
        else {
            return Ok(());
        };
        let len = bytes.len();
        if path != "/s.brs" {
            write!(out, "HTTP/1.1 404 Not Found\r\nContent-Length: 0\r\n\r\n")?;
            continue;
        }
        let common = "Accept-Ranges: bytes\r\nETag: \"v1\"\r\nLast-Modified: Thu, 01 Jan 2026 00:00:00 GMT\r\n";
        if method == "HEAD" {
            write!(
                out,
                "HTTP/1.1 200 OK\r\n{common}Content-Length: {len}\r\n\r\n"
            )?;
            continue;
        }
        let act = plan(gets.fetch_add(1, Ordering::SeqCst));
        let (start, end) = match range.as_deref().and_then(|r| r.strip_prefix("bytes=")) {
            Some(r) => {
                let (a, b) = r.split_once('-').unwrap_or(("", ""));
                match (a.parse::<usize>(), b.parse::<usize>()) {
                    (Ok(a), Ok(b)) => (a, (b + 1).min(len)),
                    (Ok(a), Err(_)) => (a, len),
                    (Err(_), Ok(n)) => (len.saturating_sub(n), len),
                    _ => (0, len),
                }
            }
            None => (0, len),
        };
        if start >= end {
            write!(
                out,
                "HTTP/1.1 416 Range Not Satisfiable\r\nContent-Range: bytes */{len}\r\nContent-Length: 0\r\n\r\n"
            )?;
            continue;
        }
        let body = &bytes[start..end];
        let head = |out: &mut TcpStream, cr: String, n: usize| {
            write!(
                out,
                "HTTP/1.1 206 Partial Content\r\n{common}Content-Range: {cr}\r\nContent-Length: {n}\r\n\r\n"
            )
        };
        let cr = format!("bytes {start}-{}/{len}", end - 1);
        match act {
            Act::Serve | Act::Delay(_) => {
                if let Act::Delay(ms) = act {
                    std::thread::sleep(Duration::from_millis(ms));
                }
                head(&mut out, cr, body.len())?;
                out.write_all(body)?;
            }
            Act::Status(code) => {
                write!(
                    out,
                    "HTTP/1.1 {code} Busy\r\nRetry-After: 0\r\nContent-Length: 0\r\nConnection: close\r\n\r\n"
                )?;
                return Ok(());
            }
            Act::Reset => {
                // Close without an answer (the client sees the connection end).
                return out.shutdown(std::net::Shutdown::Both);
            }
            Act::Truncate => {
                head(&mut out, cr, body.len())?;
                out.write_all(&body[..body.len() / 2])?;
                out.flush()?;
                return out.shutdown(std::net::Shutdown::Both);
            }
            Act::Stall => {
                head(&mut out, cr, body.len())?;
                out.write_all(&body[..body.len() / 3])?;
                out.flush()?;
                while !stop.load(Ordering::SeqCst) {
                    std::thread::sleep(Duration::from_millis(50));
                }
                return Ok(());
            }
            Act::WrongRange => {
                // The right length, but announced as other bytes.
                let shifted = format!("bytes {}-{}/{len}", start + 1, end);
                head(&mut out, shifted, body.len())?;
                out.write_all(body)?;
            }
        }
        out.flush()?;
    }
}

fn opts() -> RemoteOptions {
    RemoteOptions {
        max_retries: 4,
        init_backoff: Duration::from_millis(5),
        max_backoff: Duration::from_millis(40),
        retry_timeout: Duration::from_secs(5),
        timeout: Duration::from_secs(3),
        read_timeout: Duration::from_millis(400),
        ..loopback(None)
    }
}

/// Reads ranges of every size through `url` and checks each against
/// `bytes`: Ok means the exact bytes; an error must be a typed remote error.
/// Returns (reads that succeeded, reads that failed).
fn read_all(url: &str, o: &RemoteOptions, bytes: &[u8]) -> (usize, usize) {
    let r = match RemoteRangeReader::open(url, o) {
        Ok(r) => r,
        Err(e) => {
            assert_eq!(e.url(), url);
            return (0, 1);
        }
    };
    assert_eq!(r.len().unwrap(), bytes.len() as u64);
    let (mut ok, mut failed) = (0, 0);
    let n = bytes.len() as u64;
    for (off, len) in [
        (0, 128),
        (n - 1, 1),
        (n / 3, 4096.min(n / 2)),
        (17, 1000),
        (n - 300, 300),
    ] {
        let mut b = vec![0u8; len as usize];
        let t = Instant::now();
        match r.read_range(&mut b, off) {
            Ok(()) => {
                assert!(
                    b == bytes[off as usize..(off + len) as usize],
                    "wrong bytes at {off}+{len}"
                );
                ok += 1;
            }
            Err(e) => {
                assert_eq!(e.url(), url);
                failed += 1;
            }
        }
        assert!(t.elapsed() <= o.deadline(), "a read took {:?}", t.elapsed());
    }
    (ok, failed)
}

fn store_bytes() -> (tempfile::TempDir, Store, Vec<u8>) {
    let dir = tempfile::tempdir().unwrap();
    let (path, bytes) = small_store(dir.path());
    let store = Store::open(&path).unwrap();
    (dir, store, bytes)
}

#[test]
fn transient_faults_are_retried_to_the_exact_bytes() {
    let (_dir, local, bytes) = store_bytes();
    type Plan = Box<dyn Fn(usize) -> Act + Send + Sync>;
    let plans: Vec<(&str, Plan)> = vec![
        ("latency", Box::new(|n| Act::Delay(5 + (n as u64 * 7) % 25))),
        (
            "503 then 429 bursts",
            Box::new(|n| match n % 3 {
                0 => Act::Status(503),
                1 => Act::Status(429),
                _ => Act::Serve,
            }),
        ),
        (
            "resets",
            Box::new(|n| if n % 2 == 0 { Act::Reset } else { Act::Serve }),
        ),
    ];
    for (name, plan) in plans {
        let srv = serve(bytes.clone(), plan);
        let url = format!("http://127.0.0.1:{}/s.brs", srv.port);
        let o = opts();
        let (ok, failed) = read_all(&url, &o, &bytes);
        assert_eq!((ok, failed), (5, 0), "{name}");
        // The whole store through the faults: the same bricks.
        let remote = Store::open_with(RemoteRangeReader::open(&url, &o).unwrap(), url.clone())
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_same_store(&local, &remote);
        // Retries are bounded: at most 1 + max_retries GETs a read.
        let gets = srv.gets.load(Ordering::SeqCst);
        assert!(gets > 0, "{name}");
        eprintln!("{name}: {gets} GETs");
    }
}

#[test]
fn persistent_faults_fail_typed_within_the_deadline() {
    let (_dir, _local, bytes) = store_bytes();
    let o = opts();
    for (name, act) in [
        ("503", Act::Status(503)),
        ("429", Act::Status(429)),
        ("reset", Act::Reset),
        ("stalled body", Act::Stall),
        ("truncated body", Act::Truncate),
    ] {
        let srv = serve(bytes.clone(), move |_| act);
        let url = format!("http://127.0.0.1:{}/s.brs", srv.port);
        let r = RemoteRangeReader::open(&url, &o).unwrap();
        let mut b = vec![0u8; 5000];
        let t = Instant::now();
        let e = r.read_range(&mut b, 1000).unwrap_err();
        let took = t.elapsed();
        assert!(took <= o.deadline(), "{name}: {took:?}");
        assert!(
            matches!(
                e,
                RemoteError::Request { .. } | RemoteError::Deadline { .. }
            ),
            "{name}: {e}"
        );
        assert_eq!(e.url(), url);
        let gets = srv.gets.load(Ordering::SeqCst);
        assert!(
            (1..=1 + o.max_retries).contains(&gets),
            "{name}: {gets} GETs for one read with {} retries",
            o.max_retries
        );
        // Through the store: a typed error, never a brick.
        match Store::open_with(RemoteRangeReader::open(&url, &o).unwrap(), url.clone()) {
            Err(StoreError::Io { source, .. }) => {
                assert!(RemoteError::from_io(&source).is_some(), "{name}")
            }
            other => panic!("{name}: {other:?}"),
        }
        eprintln!("{name}: failed after {took:?}, {gets} GETs: {e}");
    }
}

#[test]
fn a_wrong_content_range_is_refused_never_read() {
    let (_dir, _local, bytes) = store_bytes();
    let srv = serve(bytes.clone(), |_| Act::WrongRange);
    let url = format!("http://127.0.0.1:{}/s.brs", srv.port);
    let (ok, failed) = read_all(&url, &opts(), &bytes);
    assert_eq!((ok, failed), (0, 5));
}

#[test]
fn a_truncated_body_now_and_then_never_yields_wrong_bytes() {
    let (_dir, local, bytes) = store_bytes();
    let srv = serve(bytes.clone(), |n| {
        if n % 2 == 0 {
            Act::Truncate
        } else {
            Act::Serve
        }
    });
    let url = format!("http://127.0.0.1:{}/s.brs", srv.port);
    let o = opts();
    let (ok, failed) = read_all(&url, &o, &bytes);
    assert_eq!(ok + failed, 5);
    // Through the store: each brick equals the local one, or fails typed.
    if let Ok(remote) = Store::open_with(RemoteRangeReader::open(&url, &o).unwrap(), url.clone()) {
        let mut a = vec![0u8; local.layout().brick_bytes()];
        let mut b = a.clone();
        for n in local.nodes() {
            local.read(n.key, &mut a).unwrap();
            if remote.read(n.key, &mut b).is_ok() {
                assert!(a == b, "brick {:?}", n.key);
            }
        }
    }
}

#[test]
fn a_missing_object_is_missing() {
    let srv = serve(vec![1, 2, 3], |_| Act::Serve);
    let url = format!("http://127.0.0.1:{}/other.brs", srv.port);
    let e = RemoteRangeReader::open(&url, &opts()).unwrap_err();
    assert!(e.is_missing(), "{e}");
    let io: std::io::Error = e.into();
    assert_eq!(io.kind(), std::io::ErrorKind::NotFound);
}

#[test]
fn opening_takes_two_gets_and_a_batch_of_payloads_is_coalesced() {
    let (_dir, local, bytes) = store_bytes();
    let srv = serve(bytes.clone(), |_| Act::Serve);
    let url = format!("http://127.0.0.1:{}/s.brs", srv.port);
    let remote =
        Store::open_with(RemoteRangeReader::open(&url, &opts()).unwrap(), url.clone()).unwrap();
    // A HEAD (not counted), the header, then the table and error sections.
    assert_eq!(srv.gets.load(Ordering::SeqCst), 2);
    let keys: Vec<_> = local.nodes().map(|n| n.key).collect();
    let with_payload = local.nodes().filter(|n| n.payload_len > 0).count();
    let many = remote.read_compressed_many(&keys).unwrap();
    let batch_gets = srv.gets.load(Ordering::SeqCst) - 2;
    // The payloads tile less than 1 MiB: object_store merges them into one
    // request.
    assert!(bytes.len() < 1 << 20);
    assert_eq!(
        batch_gets, 1,
        "{with_payload} payloads in {batch_gets} GETs"
    );
    for (k, p) in keys.iter().zip(&many) {
        assert_eq!(&local.read_compressed(*k).unwrap(), p);
    }
    // One by one: a GET each.
    for k in &keys {
        remote.read_compressed(*k).unwrap();
    }
    assert_eq!(srv.gets.load(Ordering::SeqCst) - 3, with_payload);
}
