//! Test helpers: a small store built from a synthetic volume, the servers'
//! addresses, uploads.
#![allow(dead_code, unreachable_pub, missing_docs)]

use brickray_core::{BrickSource, NodeKey};
use brickray_remote::RemoteOptions;
use brickray_store::{BuildOptions, Store, build};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

/// Builds a store (a 40^3 Marschner-Lobb volume in 8^3 bricks, error
/// sections included) into `dir`; returns its path and bytes.
pub fn small_store(dir: &Path) -> (PathBuf, Vec<u8>) {
    let vol = brickray_core::synthetic::marschner_lobb(40);
    let mut reader = brickray_io::MemoryReader::new(vol, "memory");
    let out = dir.join("small.brs");
    let o = BuildOptions {
        brick: 8,
        apron: 1,
        ..BuildOptions::default()
    };
    build(&mut reader, &out, &o).unwrap();
    let bytes = std::fs::read(&out).unwrap();
    (out, bytes)
}

/// The server address in `var` (set by scripts/test.sh). `None` (the test
/// returns) when unset, but a panic when `CI=true`: CI starts the servers, so
/// a test must never skip there.
pub fn server(var: &str) -> Option<String> {
    match std::env::var(var) {
        Ok(v) if !v.is_empty() => Some(v.trim_end_matches('/').to_owned()),
        _ if std::env::var("CI").is_ok_and(|v| v == "true") => {
            panic!("CI=true but {var} is unset (scripts/test.sh starts the test servers)")
        }
        _ => {
            eprintln!("skipping: {var} is unset (run through scripts/test.sh)");
            None
        }
    }
}

/// A name no other test (or run) uses.
pub fn unique(prefix: &str) -> String {
    static N: AtomicU64 = AtomicU64::new(0);
    let t = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos();
    format!(
        "{prefix}-{}-{t}-{}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    )
}

/// Options for the loopback servers: plain HTTP allowed, short retries.
pub fn loopback(endpoint: Option<&str>) -> RemoteOptions {
    RemoteOptions {
        allow_http: true,
        endpoint: endpoint.map(str::to_owned),
        region: Some("us-east-1".into()),
        max_retries: 3,
        init_backoff: Duration::from_millis(20),
        max_backoff: Duration::from_millis(200),
        retry_timeout: Duration::from_secs(10),
        timeout: Duration::from_secs(10),
        read_timeout: Duration::from_secs(5),
        ..RemoteOptions::default()
    }
}

/// Signed S3 requests with moto's accepted test credentials.
pub fn s3_signed(endpoint: &str) -> RemoteOptions {
    RemoteOptions {
        config: vec![
            ("aws_access_key_id".into(), "testing".into()),
            ("aws_secret_access_key".into(), "testing".into()),
        ],
        ..loopback(Some(endpoint))
    }
}

/// Uploads `bytes` to `url` (`brickray_remote::put_object`).
pub fn upload(url: &str, opts: &RemoteOptions, bytes: &[u8]) {
    brickray_remote::put_object(url, opts, bytes.to_vec())
        .unwrap_or_else(|e| panic!("upload to {url}: {e}"));
}

/// Creates an S3 bucket on `endpoint` with one unsigned request (moto
/// accepts it; object_store has no bucket API). A public bucket (canned ACL
/// `public-read`) answers unsigned reads.
pub fn create_bucket(endpoint: &str, bucket: &str, public: bool) {
    use std::io::{Read, Write};
    let host = endpoint.trim_start_matches("http://");
    let mut s = std::net::TcpStream::connect(host).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    let acl = if public {
        "x-amz-acl: public-read\r\n"
    } else {
        ""
    };
    write!(
        s,
        "PUT /{bucket} HTTP/1.1\r\nHost: {host}\r\n{acl}Content-Length: 0\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut resp = String::new();
    let _ = s.read_to_string(&mut resp);
    assert!(
        resp.starts_with("HTTP/1.1 200"),
        "create bucket {bucket}: {resp}"
    );
}

/// Asserts that `remote` holds the same store as `local`: the header's
/// figures, the node table, every brick byte for byte and every compressed
/// payload (one batch read, coalesced by the remote reader).
pub fn assert_same_store(local: &Store, remote: &Store) {
    assert_eq!(local.file_len(), remote.file_len());
    assert_eq!(local.version(), remote.version());
    assert_eq!(local.layout(), remote.layout());
    assert_eq!(local.data_range(), remote.data_range());
    let ln: Vec<_> = local.nodes().collect();
    let rn: Vec<_> = remote.nodes().collect();
    assert_eq!(ln, rn, "node tables differ");
    assert!(ln.len() > 8, "a store of {} nodes tests little", ln.len());
    let mut a = vec![0u8; local.layout().brick_bytes()];
    let mut b = vec![0u8; remote.layout().brick_bytes()];
    let mut data = 0;
    for n in &ln {
        BrickSource::read_brick(local, n.key, &mut a).unwrap();
        b.fill(0xA5);
        BrickSource::read_brick(remote, n.key, &mut b).unwrap();
        assert!(a == b, "brick {:?} differs", n.key);
        data += usize::from(n.payload_len > 0);
    }
    assert!(data > 4, "only {data} bricks with a payload");
    let keys: Vec<NodeKey> = ln.iter().map(|n| n.key).collect();
    let many = remote.read_compressed_many(&keys).unwrap();
    for (k, p) in keys.iter().zip(&many) {
        assert_eq!(&local.read_compressed(*k).unwrap(), p, "payload {k:?}");
    }
}

/// One HTTP/1.1 request line and its headers, as the in-test servers read
/// them: the method, the path and the `Range` header's value.
pub struct Request {
    pub method: String,
    pub path: String,
    pub range: Option<String>,
}

/// Reads the next request from a connection; `None` when the client closed
/// it.
pub fn read_request(reader: &mut impl std::io::BufRead) -> std::io::Result<Option<Request>> {
    let mut line = String::new();
    if reader.read_line(&mut line)? == 0 {
        return Ok(None);
    }
    let method = line.split_whitespace().next().unwrap_or("").to_owned();
    let path = line.split_whitespace().nth(1).unwrap_or("").to_owned();
    let mut range = None;
    loop {
        let mut h = String::new();
        if reader.read_line(&mut h)? == 0 {
            return Ok(None);
        }
        let h = h.trim_end();
        if h.is_empty() {
            break;
        }
        if let Some((k, v)) = h.split_once(':')
            && k.eq_ignore_ascii_case("range")
        {
            range = Some(v.trim().to_owned());
        }
    }
    Ok(Some(Request {
        method,
        path,
        range,
    }))
}
