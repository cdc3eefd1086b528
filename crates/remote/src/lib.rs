//! Range readers over object storage and HTTP(S) for brickray.
//!
//! [`RemoteRangeReader`] implements [`brickray_core::RangeReader`] over the
//! Apache [`object_store`] crate: `s3://bucket/key` (AWS S3 and any
//! S3-compatible endpoint), `gs://bucket/key`, `az://container/key` and
//! `http(s)://host/path`. Each reader owns one small tokio runtime (two
//! worker threads, `brickray-remote`); a caller's thread hands each read to
//! the runtime and waits on a channel, so no runtime thread ever blocks and
//! the reader may be called from any thread (a brick loader's) but not from
//! inside one of its own tasks.
//!
//! Configuration follows the usual conventions ([`RemoteOptions`]): the
//! `AWS_*`, `GOOGLE_*` and `AZURE_*` environment variables object_store reads,
//! an explicit endpoint, anonymous (unsigned) requests for public buckets,
//! plain HTTP only when [`RemoteOptions::allow_http`] is set. Requests time
//! out and are retried with exponential backoff (object_store's `RetryConfig`,
//! defaults in [`RemoteOptions::default`]). Every failure is a typed
//! [`RemoteError`] carrying the URL and the cause; through the
//! [`RangeReader`] seam it travels inside an
//! [`std::io::Error`] (see [`RemoteError::from_io`]).

use brickray_core::{CancelToken, RangeRead, RangeReader};
use object_store::path::Path as ObjectPath;
use object_store::{ClientOptions, ObjectStore, ObjectStoreExt, RetryConfig};
use std::fmt;
use std::future::Future;
use std::io;
use std::ops::Range;
use std::sync::Arc;
use std::time::Duration;
use thiserror::Error;

pub use object_store;

mod disk_cache;
mod object_cache;
mod objects;
mod range_reader;
mod runtime;
pub use disk_cache::{DEFAULT_DISK_CACHE_BYTES, DiskCacheConfig, DiskCacheStats, DiskCached};
pub use object_cache::DiskCachedObjects;
pub use objects::RemoteObjects;
pub use range_reader::RemoteRangeReader;
use runtime::{Runtime, run_on, run_until, start_runtime};

/// Requests sent and bytes received by a reader so far (retries inside one
/// request not counted): what a benchmark compares with the bytes a view
/// needed. Several ranges read at once count the requests they were
/// coalesced into.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Fetched {
    /// Requests (`HEAD` and ranged `GET`).
    pub requests: u64,
    /// Body bytes received.
    pub bytes: u64,
}

/// The counters behind [`Fetched`], shared with the reader's tasks.
#[derive(Debug, Default)]
struct Traffic {
    requests: std::sync::atomic::AtomicU64,
    bytes: std::sync::atomic::AtomicU64,
}

impl Traffic {
    fn count(&self, bytes: u64) {
        use std::sync::atomic::Ordering::Relaxed;
        self.requests.fetch_add(1, Relaxed);
        self.bytes.fetch_add(bytes, Relaxed);
    }

    fn count_bytes(&self, bytes: u64) {
        self.bytes
            .fetch_add(bytes, std::sync::atomic::Ordering::Relaxed);
    }

    fn get(&self) -> Fetched {
        use std::sync::atomic::Ordering::Relaxed;
        Fetched {
            requests: self.requests.load(Relaxed),
            bytes: self.bytes.load(Relaxed),
        }
    }
}

/// Fetches `ranges` of `path` as object_store's `get_ranges` does
/// (neighbours less than `gap` bytes apart coalesced into one request, the
/// rest concurrent), counting each request and its bytes in `traffic`.
async fn get_ranges_counted(
    store: Arc<dyn ObjectStore>,
    path: ObjectPath,
    ranges: Vec<Range<u64>>,
    traffic: Arc<Traffic>,
    gap: u64,
) -> object_store::Result<Vec<bytes::Bytes>> {
    object_store::coalesce_ranges(
        &ranges,
        |r| {
            let (store, path, traffic) = (store.clone(), path.clone(), traffic.clone());
            async move {
                let b = store.get_range(&path, r).await?;
                traffic.count(b.len() as u64);
                Ok(b)
            }
        },
        gap,
    )
    .await
}

/// What went wrong reading a remote object. Every variant names the URL.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum RemoteError {
    /// The URL cannot be parsed or names no supported store.
    #[error("{url}: {reason}")]
    BadUrl {
        /// The URL as given.
        url: String,
        /// What is wrong.
        reason: String,
    },
    /// The URL or the endpoint is plain `http://` and plain HTTP was not
    /// allowed.
    #[error(
        "{url}: plain HTTP ({endpoint}) is not allowed; allow it explicitly \
         (RemoteOptions::allow_http, --allow-http, or AWS_ALLOW_HTTP=true)"
    )]
    HttpNotAllowed {
        /// The URL.
        url: String,
        /// The plain-HTTP address.
        endpoint: String,
    },
    /// The store could not be configured (an unknown option key, a missing
    /// bucket or region, ...).
    #[error("{url}: configuration: {source}")]
    Config {
        /// The URL.
        url: String,
        /// object_store's error.
        #[source]
        source: object_store::Error,
    },
    /// The object does not exist: the server answered 404, or 403, which S3
    /// answers for a missing key when the caller may not list the bucket.
    #[error("{url}: not found{}: {source}", if *.denied { " (403: missing, or access denied)" } else { "" })]
    Missing {
        /// The URL.
        url: String,
        /// The server answered 403 rather than 404.
        denied: bool,
        /// object_store's error.
        #[source]
        source: object_store::Error,
    },
    /// The request lacked valid credentials (401, or no credentials found).
    #[error(
        "{url}: authentication failed: {source}; set credentials the usual way \
         (S3: AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY, with AWS_SESSION_TOKEN for \
         temporary ones; GCS: GOOGLE_SERVICE_ACCOUNT or GOOGLE_APPLICATION_CREDENTIALS; \
         Azure: AZURE_STORAGE_ACCOUNT_NAME and AZURE_STORAGE_ACCOUNT_KEY), or read a \
         public bucket anonymously (RemoteOptions::anonymous, --anonymous)"
    )]
    Auth {
        /// The URL.
        url: String,
        /// object_store's error.
        #[source]
        source: object_store::Error,
    },
    /// A request failed after its retries (a timeout, 5xx or 429 answers, a
    /// reset connection, a body cut short), or the server's answer was
    /// refused (a wrong `Content-Range`).
    #[error("{url}: request failed: {source}")]
    Request {
        /// The URL.
        url: String,
        /// object_store's error, with the retries made.
        #[source]
        source: object_store::Error,
    },
    /// The whole read, retries included, took longer than its deadline.
    #[error("{url}: no answer within {deadline:?} (retries included)")]
    Deadline {
        /// The URL.
        url: String,
        /// The deadline.
        deadline: Duration,
    },
    /// The caller cancelled the read before its bytes arrived (a brick the
    /// view no longer wants); its requests were aborted.
    #[error("{url}: the read was cancelled")]
    Cancelled {
        /// The URL.
        url: String,
    },
    /// The server returned another number of bytes than the range asked for.
    #[error("{url}: range {offset}+{expected} returned {actual} bytes")]
    WrongLength {
        /// The URL.
        url: String,
        /// The range's first byte.
        offset: u64,
        /// Bytes asked for.
        expected: u64,
        /// Bytes received.
        actual: u64,
    },
    /// A range ends past the object.
    #[error("{url}: range {offset}+{len} ends past the object's {object_len} bytes")]
    OutOfBounds {
        /// The URL.
        url: String,
        /// The range's first byte.
        offset: u64,
        /// Its length.
        len: u64,
        /// The object's length.
        object_len: u64,
    },
    /// The reader's runtime could not be started or is gone.
    #[error("{url}: runtime: {reason}")]
    Runtime {
        /// The URL.
        url: String,
        /// What happened.
        reason: String,
    },
}

impl RemoteError {
    /// The URL the error concerns.
    pub fn url(&self) -> &str {
        match self {
            RemoteError::BadUrl { url, .. }
            | RemoteError::HttpNotAllowed { url, .. }
            | RemoteError::Config { url, .. }
            | RemoteError::Missing { url, .. }
            | RemoteError::Auth { url, .. }
            | RemoteError::Request { url, .. }
            | RemoteError::Deadline { url, .. }
            | RemoteError::Cancelled { url }
            | RemoteError::WrongLength { url, .. }
            | RemoteError::OutOfBounds { url, .. }
            | RemoteError::Runtime { url, .. } => url,
        }
    }

    /// Whether the object is missing (404, or S3's 403).
    pub fn is_missing(&self) -> bool {
        matches!(self, RemoteError::Missing { .. })
    }

    /// The remote error inside an I/O error returned through the
    /// [`RangeReader`] seam (or a store error's source), if it is one.
    pub fn from_io(e: &io::Error) -> Option<&RemoteError> {
        e.get_ref()?.downcast_ref::<RemoteError>()
    }

    fn of(url: &str, e: object_store::Error) -> RemoteError {
        let url = url.to_owned();
        match e {
            object_store::Error::NotFound { .. } => RemoteError::Missing {
                url,
                denied: false,
                source: e,
            },
            object_store::Error::PermissionDenied { .. } => RemoteError::Missing {
                url,
                denied: true,
                source: e,
            },
            object_store::Error::Unauthenticated { .. } => RemoteError::Auth { url, source: e },
            object_store::Error::UnknownConfigurationKey { .. }
            | object_store::Error::InvalidPath { .. } => RemoteError::Config { url, source: e },
            _ => RemoteError::Request { url, source: e },
        }
    }

    fn io_kind(&self) -> io::ErrorKind {
        match self {
            RemoteError::Missing { .. } => io::ErrorKind::NotFound,
            RemoteError::Auth { .. } => io::ErrorKind::PermissionDenied,
            RemoteError::Deadline { .. } => io::ErrorKind::TimedOut,
            RemoteError::Cancelled { .. } => io::ErrorKind::Interrupted,
            RemoteError::WrongLength { .. } | RemoteError::OutOfBounds { .. } => {
                io::ErrorKind::UnexpectedEof
            }
            RemoteError::BadUrl { .. }
            | RemoteError::HttpNotAllowed { .. }
            | RemoteError::Config { .. } => io::ErrorKind::InvalidInput,
            _ => io::ErrorKind::Other,
        }
    }
}

impl From<RemoteError> for io::Error {
    fn from(e: RemoteError) -> io::Error {
        io::Error::new(e.io_kind(), e)
    }
}

/// How to reach remote objects. `Default` reads no environment beyond what
/// object_store's builders read (`AWS_*`, `GOOGLE_*`, `AZURE_*`); see
/// [`RemoteOptions::from_env`] for brickray's own variables.
#[derive(Debug, Clone, PartialEq)]
pub struct RemoteOptions {
    /// An S3-compatible endpoint (`https://minio.example:9000`), instead of
    /// AWS's (object_store also reads `AWS_ENDPOINT_URL`). Requests are
    /// path-style (`endpoint/bucket/key`).
    pub endpoint: Option<String>,
    /// The S3 region (else `AWS_REGION` / `AWS_DEFAULT_REGION`, else
    /// `us-east-1`).
    pub region: Option<String>,
    /// Unsigned requests, for public buckets: no credentials are looked for.
    pub anonymous: bool,
    /// Allow plain `http://` URLs and endpoints (off: only HTTPS).
    pub allow_http: bool,
    /// More object_store configuration keys (`aws_access_key_id`,
    /// `google_service_account`, `azure_storage_account_name`, ...), for the
    /// URL's store.
    pub config: Vec<(String, String)>,
    /// Longest a single request may take, body included (30 s).
    pub timeout: Duration,
    /// Longest a connection may take to open (5 s).
    pub connect_timeout: Duration,
    /// Longest a response body may stall between two chunks (10 s).
    pub read_timeout: Duration,
    /// Retries of a failed request: timeouts, 5xx, 429, reset connections
    /// (5).
    pub max_retries: usize,
    /// No retry starts later than this after the first attempt (60 s).
    pub retry_timeout: Duration,
    /// The first backoff between retries (100 ms); it doubles up to
    /// [`max_backoff`](Self::max_backoff) (5 s), with jitter.
    pub init_backoff: Duration,
    /// The largest backoff between retries.
    pub max_backoff: Duration,
    /// Worker threads of the reader's runtime (2).
    pub worker_threads: usize,
    /// Ranges of one read of several ([`RangeReader::read_ranges`]) less
    /// than this many bytes apart are fetched as one request, the bytes
    /// between them included ([`DEFAULT_COALESCE_GAP`]). Larger saves
    /// requests and costs bytes: object_store's own 1 MiB fetched 4.3-4.9x
    /// the bytes of the bricks a streamed MRI needed (docs/remote.md).
    pub coalesce_gap: u64,
    /// A local disk cache of fetched ranges for the stores opened with
    /// these options (`brickray_store::open_url`), `None`: no cache
    /// ([`DiskCached`]).
    pub disk_cache: Option<DiskCacheConfig>,
}

/// Default [`RemoteOptions::coalesce_gap`]: 16 KiB, about one compressed
/// brick of 32^3 u8 voxels.
pub const DEFAULT_COALESCE_GAP: u64 = 16 << 10;

impl Default for RemoteOptions {
    fn default() -> Self {
        RemoteOptions {
            endpoint: None,
            region: None,
            anonymous: false,
            allow_http: false,
            config: Vec::new(),
            timeout: Duration::from_secs(30),
            connect_timeout: Duration::from_secs(5),
            read_timeout: Duration::from_secs(10),
            max_retries: 5,
            retry_timeout: Duration::from_secs(60),
            init_backoff: Duration::from_millis(100),
            max_backoff: Duration::from_secs(5),
            worker_threads: 2,
            coalesce_gap: DEFAULT_COALESCE_GAP,
            disk_cache: None,
        }
    }
}

fn env_true(name: &str) -> bool {
    std::env::var(name)
        .is_ok_and(|v| matches!(v.to_ascii_lowercase().as_str(), "1" | "true" | "yes"))
}

impl RemoteOptions {
    /// The defaults, with `AWS_ALLOW_HTTP=true` (or `BRICKRAY_ALLOW_HTTP=1`)
    /// allowing plain HTTP, `AWS_SKIP_SIGNATURE=true` (or
    /// `AWS_NO_SIGN_REQUEST=true`) asking for anonymous requests,
    /// `AWS_ENDPOINT_URL` as the endpoint, and `BRICKRAY_CACHE_DIR` (with
    /// `BRICKRAY_CACHE_MAX_MB`) as a disk cache ([`DiskCacheConfig::from_env`]).
    pub fn from_env() -> RemoteOptions {
        RemoteOptions {
            endpoint: std::env::var("AWS_ENDPOINT_URL")
                .or_else(|_| std::env::var("AWS_ENDPOINT"))
                .ok()
                .filter(|e| !e.is_empty()),
            anonymous: env_true("AWS_SKIP_SIGNATURE") || env_true("AWS_NO_SIGN_REQUEST"),
            allow_http: env_true("AWS_ALLOW_HTTP") || env_true("BRICKRAY_ALLOW_HTTP"),
            disk_cache: DiskCacheConfig::from_env(),
            ..RemoteOptions::default()
        }
    }

    /// Longest one read may take, retries included: past it the read fails
    /// with [`RemoteError::Deadline`] whatever the server does.
    pub fn deadline(&self) -> Duration {
        self.retry_timeout + self.timeout + self.max_backoff
    }

    fn client(&self) -> ClientOptions {
        ClientOptions::new()
            .with_allow_http(self.allow_http)
            .with_timeout(self.timeout)
            .with_connect_timeout(self.connect_timeout)
            .with_read_timeout(self.read_timeout)
    }

    fn retry(&self) -> RetryConfig {
        RetryConfig {
            backoff: object_store::BackoffConfig {
                init_backoff: self.init_backoff,
                max_backoff: self.max_backoff,
                base: 2.0,
            },
            max_retries: self.max_retries,
            retry_timeout: self.retry_timeout,
        }
    }
}

/// The store and the object's path for `url`.
pub fn object_store_for(
    url: &str,
    opts: &RemoteOptions,
) -> Result<(Arc<dyn ObjectStore>, ObjectPath), RemoteError> {
    let bad = |reason: String| RemoteError::BadUrl {
        url: url.to_owned(),
        reason,
    };
    let config = |source| RemoteError::Config {
        url: url.to_owned(),
        source,
    };
    let parsed = url::Url::parse(url).map_err(|e| bad(e.to_string()))?;
    let plain = |addr: &str| -> Result<(), RemoteError> {
        if addr.to_ascii_lowercase().starts_with("http://") && !opts.allow_http {
            return Err(RemoteError::HttpNotAllowed {
                url: url.to_owned(),
                endpoint: addr.to_owned(),
            });
        }
        Ok(())
    };
    let key = |p: &str| -> Result<ObjectPath, RemoteError> {
        let p = p.trim_start_matches('/');
        if p.is_empty() || p.ends_with('/') {
            return Err(bad(
                "names no object (the path is empty or ends with /)".into()
            ));
        }
        ObjectPath::from_url_path(p).map_err(|e| bad(e.to_string()))
    };
    let host = || {
        parsed
            .host_str()
            .filter(|h| !h.is_empty())
            .map(str::to_owned)
            .ok_or_else(|| bad("no bucket (the URL's host)".into()))
    };
    match parsed.scheme() {
        "s3" | "s3a" => {
            use object_store::aws::{AmazonS3Builder, AmazonS3ConfigKey};
            let mut b = AmazonS3Builder::from_env()
                .with_bucket_name(host()?)
                .with_client_options(opts.client())
                .with_retry(opts.retry())
                .with_skip_signature(opts.anonymous);
            let endpoint = opts
                .endpoint
                .clone()
                .or_else(|| std::env::var("AWS_ENDPOINT_URL").ok())
                .or_else(|| std::env::var("AWS_ENDPOINT").ok())
                .filter(|e| !e.is_empty());
            if let Some(e) = &endpoint {
                plain(e)?;
                b = b.with_endpoint(e).with_virtual_hosted_style_request(false);
            }
            if let Some(r) = &opts.region {
                b = b.with_region(r);
            }
            for (k, v) in &opts.config {
                let key: AmazonS3ConfigKey = k.parse().map_err(config)?;
                b = b.with_config(key, v);
            }
            let path = key(parsed.path())?;
            Ok((Arc::new(b.build().map_err(config)?), path))
        }
        "gs" => {
            use object_store::gcp::{GoogleCloudStorageBuilder, GoogleConfigKey};
            let mut b = GoogleCloudStorageBuilder::from_env()
                .with_bucket_name(host()?)
                .with_client_options(opts.client())
                .with_retry(opts.retry())
                .with_skip_signature(opts.anonymous);
            for (k, v) in &opts.config {
                let key: GoogleConfigKey = k.parse().map_err(config)?;
                b = b.with_config(key, v);
            }
            let path = key(parsed.path())?;
            Ok((Arc::new(b.build().map_err(config)?), path))
        }
        "az" | "azure" => {
            use object_store::azure::{AzureConfigKey, MicrosoftAzureBuilder};
            let mut b = MicrosoftAzureBuilder::from_env()
                .with_container_name(host()?)
                .with_client_options(opts.client())
                .with_retry(opts.retry())
                .with_skip_signature(opts.anonymous);
            if let Some(e) = &opts.endpoint {
                plain(e)?;
                b = b.with_endpoint(e.clone());
            }
            for (k, v) in &opts.config {
                let key: AzureConfigKey = k.parse().map_err(config)?;
                b = b.with_config(key, v);
            }
            let path = key(parsed.path())?;
            Ok((Arc::new(b.build().map_err(config)?), path))
        }
        "http" | "https" => {
            plain(url)?;
            if parsed.query().is_some() || parsed.fragment().is_some() {
                return Err(bad("a query or fragment is not supported".into()));
            }
            // The store is the URL's directory; the object its last segment.
            let full = parsed.as_str();
            let cut = full.rfind('/').map_or(full.len(), |i| i + 1);
            let (base, name) = full.split_at(cut);
            if parsed.path() == "/" || name.is_empty() {
                return Err(bad(
                    "names no object (the path is empty or ends with /)".into()
                ));
            }
            // The directory without its trailing `/` (object_store appends
            // the key's segments to the URL's: `dir/` would give `dir//key`).
            let base = if parsed.path().rfind('/') == Some(0) {
                base
            } else {
                base.strip_suffix('/').unwrap_or(base)
            };
            let store = object_store::http::HttpBuilder::new()
                .with_url(base)
                .with_client_options(opts.client())
                .with_retry(opts.retry())
                .build()
                .map_err(config)?;
            Ok((Arc::new(store), key(name)?))
        }
        other => Err(bad(format!(
            "unsupported scheme `{other}` (s3://, gs://, az://, http://, https://)"
        ))),
    }
}

/// Writes `bytes` as the object at `url` (configured by `opts`): one `PUT`
/// (object_store's `put`, retried as reads are). What a tool uses to publish
/// a store it built, and the benchmarks to fill a bucket.
pub fn put_object(url: &str, opts: &RemoteOptions, bytes: Vec<u8>) -> Result<(), RemoteError> {
    let (store, path) = object_store_for(url, opts)?;
    let runtime = start_runtime(url, opts)?;
    run_on(&runtime, url, opts.deadline(), async move {
        store.put(&path, bytes.into()).await.map(|_| ())
    })
}

/// Whether `s` names a remote object (a URL with a scheme this crate
/// reads), rather than a local path.
pub fn is_url(s: &str) -> bool {
    let lower = s.to_ascii_lowercase();
    [
        "s3://", "s3a://", "gs://", "az://", "azure://", "http://", "https://",
    ]
    .iter()
    .any(|p| lower.starts_with(p))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn err(url: &str, opts: &RemoteOptions) -> RemoteError {
        object_store_for(url, opts).expect_err("an error")
    }

    #[test]
    fn urls_are_checked_before_any_request() {
        let o = RemoteOptions::default();
        assert!(matches!(
            err("ftp://host/x", &o),
            RemoteError::BadUrl { .. }
        ));
        assert!(matches!(err("not a url", &o), RemoteError::BadUrl { .. }));
        assert!(matches!(
            err("s3://bucket/", &o),
            RemoteError::BadUrl { .. }
        ));
        assert!(matches!(
            err("https://host/dir/", &o),
            RemoteError::BadUrl { .. }
        ));
        assert!(matches!(
            err("https://host/a?b=c", &o),
            RemoteError::BadUrl { .. }
        ));
        match err("http://127.0.0.1:1/a.brs", &o) {
            RemoteError::HttpNotAllowed { url, .. } => assert_eq!(url, "http://127.0.0.1:1/a.brs"),
            e => panic!("{e}"),
        }
        let s3 = RemoteOptions {
            endpoint: Some("http://127.0.0.1:1".into()),
            ..RemoteOptions::default()
        };
        assert!(matches!(
            err("s3://b/k.brs", &s3),
            RemoteError::HttpNotAllowed { .. }
        ));
        let unknown = RemoteOptions {
            config: vec![("no_such_key".into(), "1".into())],
            anonymous: true,
            ..RemoteOptions::default()
        };
        assert!(matches!(
            err("s3://b/k.brs", &unknown),
            RemoteError::Config { .. }
        ));
        // Allowed: the store builds, and the key is the URL's path.
        let ok = RemoteOptions {
            allow_http: true,
            anonymous: true,
            region: Some("us-east-1".into()),
            ..s3
        };
        let (_, p) = object_store_for("s3://b/dir/k%20x.brs", &ok).unwrap();
        assert_eq!(p.as_ref(), "dir/k x.brs");
        let (_, p) = object_store_for("http://127.0.0.1:1/d/e/f.brs", &ok).unwrap();
        assert_eq!(p.as_ref(), "f.brs");
    }

    #[test]
    fn an_unreachable_server_is_a_typed_error_within_the_deadline() {
        // A port nothing listens on: connection refused, retried, reported.
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let port = listener.local_addr().unwrap().port();
        drop(listener);
        let o = RemoteOptions {
            allow_http: true,
            max_retries: 2,
            init_backoff: Duration::from_millis(10),
            max_backoff: Duration::from_millis(20),
            retry_timeout: Duration::from_secs(5),
            ..RemoteOptions::default()
        };
        let url = format!("http://127.0.0.1:{port}/x.brs");
        let t = std::time::Instant::now();
        let e = RemoteRangeReader::open(&url, &o).unwrap_err();
        assert!(t.elapsed() < o.deadline(), "{:?}", t.elapsed());
        assert_eq!(e.url(), url);
        assert!(matches!(e, RemoteError::Request { .. }), "{e}");
        let io: io::Error = e.into();
        assert!(RemoteError::from_io(&io).is_some());
    }

    #[test]
    fn is_url_tells_urls_from_paths() {
        assert!(is_url("s3://b/k"));
        assert!(is_url("HTTPS://h/k"));
        assert!(is_url("gs://b/k"));
        assert!(!is_url("/data/x.brs"));
        assert!(!is_url("x.brs"));
        assert!(!is_url("C:\\x.brs"));
    }
}
