//! [`RemoteObjects`]: the objects under one remote root (an OME-Zarr
//! image's folder), read by key, on the same runtime, retries, deadline and
//! counters as [`RemoteRangeReader`](crate::RemoteRangeReader).

use crate::{
    Fetched, RemoteError, RemoteOptions, Runtime, Traffic, get_ranges_counted, object_store_for,
    run_on, run_until, start_runtime,
};
use brickray_core::CancelToken;
use object_store::path::Path as ObjectPath;
use object_store::{ObjectStore, ObjectStoreExt};
use std::fmt;
use std::io;
use std::ops::Range;
use std::sync::Arc;
use std::time::Duration;

/// The objects under one remote root, read by key (an
/// [`ObjectReader`](brickray_core::ObjectReader)): an OME-Zarr image's
/// folder in a bucket (`s3://bucket/path/image.zarr`) or at a URL
/// (`https://host/path/image.zarr`). Opening sends no request; each read is
/// one ranged `GET` (several ranges of one object: coalesced by
/// object_store), retried and bounded by the deadline as
/// [`RemoteRangeReader`](crate::RemoteRangeReader)'s. A missing object (404, or the 403 S3 answers for
/// a missing key) reads as `None`.
pub struct RemoteObjects {
    url: String,
    store: Arc<dyn ObjectStore>,
    /// The root's path in the store (`""` for an HTTP root).
    prefix: String,
    deadline: Duration,
    runtime: Runtime,
    reads: std::sync::atomic::AtomicU64,
    traffic: Arc<Traffic>,
    gap: u64,
}

impl fmt::Debug for RemoteObjects {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("RemoteObjects")
            .field("url", &self.url)
            .finish()
    }
}

impl RemoteObjects {
    /// The objects under `url` (a folder: `s3://bucket/dir/image.zarr`,
    /// `https://host/dir/image.zarr`; a trailing `/` is ignored), configured
    /// by `opts`. Starts the runtime; sends no request.
    pub fn open(url: &str, opts: &RemoteOptions) -> Result<RemoteObjects, RemoteError> {
        let root = url.trim_end_matches('/');
        // The store and path of an object in the folder: its parent is the
        // root's path.
        let (store, probe) =
            object_store_for(&format!("{root}/zarr.json"), opts).map_err(|e| match e {
                RemoteError::BadUrl { reason, .. } => RemoteError::BadUrl {
                    url: url.to_owned(),
                    reason,
                },
                other => other,
            })?;
        let prefix = probe
            .as_ref()
            .strip_suffix("zarr.json")
            .unwrap_or("")
            .trim_end_matches('/')
            .to_owned();
        Ok(RemoteObjects {
            url: root.to_owned(),
            store,
            prefix,
            deadline: opts.deadline(),
            runtime: start_runtime(url, opts)?,
            reads: std::sync::atomic::AtomicU64::new(0),
            traffic: Arc::default(),
            gap: opts.coalesce_gap,
        })
    }

    /// The root's URL (without a trailing `/`).
    pub fn url(&self) -> &str {
        &self.url
    }

    /// Reads issued so far (one per [`get`](Self::get), one per batch of
    /// [`get_ranges`](Self::get_ranges)), retries not counted.
    pub fn reads(&self) -> u64 {
        self.reads.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Requests and bytes fetched so far.
    pub fn fetched(&self) -> Fetched {
        self.traffic.get()
    }

    /// The store path and URL of `key`; a key that leaves the root (`..`,
    /// `.`, an empty segment) is refused.
    fn locate(&self, key: &str) -> Result<(ObjectPath, String), RemoteError> {
        let url = format!("{}/{key}", self.url);
        if key.is_empty()
            || key
                .split('/')
                .any(|c| c.is_empty() || c == "." || c == ".." || c.contains('\\'))
        {
            return Err(RemoteError::BadUrl {
                url,
                reason: "the key leaves the root".into(),
            });
        }
        let full = if self.prefix.is_empty() {
            key.to_owned()
        } else {
            format!("{}/{key}", self.prefix)
        };
        let path = ObjectPath::parse(&full).map_err(|e| RemoteError::BadUrl {
            url: url.clone(),
            reason: e.to_string(),
        })?;
        Ok((path, url))
    }

    /// `span` of the object `key` and the object's length; `None` when it
    /// is missing (404, or S3's 403). The bytes returned are checked against
    /// the span (a server that answers another range is an error).
    pub fn get(
        &self,
        key: &str,
        span: brickray_core::ObjectSpan,
    ) -> Result<Option<(Vec<u8>, u64)>, RemoteError> {
        use brickray_core::ObjectSpan;
        use object_store::{GetOptions, GetRange};
        let (path, url) = self.locate(key)?;
        let range = match span {
            ObjectSpan::All => None,
            ObjectSpan::At { len: 0, offset } => {
                // no bytes: the object's length (a HEAD) says whether the
                // empty range lies in it
                self.reads
                    .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let store = self.store.clone();
                let p = path.clone();
                self.traffic.count(0);
                let size = match run_on(&self.runtime, &url, self.deadline, async move {
                    store.head(&p).await
                }) {
                    Ok(m) => m.size,
                    Err(e) if e.is_missing() => return Ok(None),
                    Err(e) => return Err(e),
                };
                if offset > size {
                    return Err(RemoteError::OutOfBounds {
                        url,
                        offset,
                        len: 0,
                        object_len: size,
                    });
                }
                return Ok(Some((Vec::new(), size)));
            }
            ObjectSpan::At { offset, len } => {
                let end = offset
                    .checked_add(len)
                    .ok_or_else(|| RemoteError::OutOfBounds {
                        url: url.clone(),
                        offset,
                        len,
                        object_len: u64::MAX,
                    })?;
                Some(GetRange::Bounded(offset..end))
            }
            ObjectSpan::Suffix(n) => Some(GetRange::Suffix(n)),
        };
        self.reads
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let store = self.store.clone();
        let traffic = self.traffic.clone();
        let cancel = CancelToken::current();
        let got = run_until(
            &self.runtime,
            &url,
            self.deadline,
            async move {
                let options = GetOptions {
                    range,
                    ..GetOptions::default()
                };
                traffic.count(0);
                let r = store.get_opts(&path, options).await?;
                let (size, got) = (r.meta.size, r.range.clone());
                let bytes = r.bytes().await?;
                traffic.count_bytes(bytes.len() as u64);
                Ok((bytes, size, got))
            },
            cancel.as_ref(),
        );
        let (bytes, size, got) = match got {
            Ok(x) => x,
            Err(e) if e.is_missing() => return Ok(None),
            Err(e) => return Err(e),
        };
        let expected = match span {
            ObjectSpan::All => 0..size,
            ObjectSpan::At { offset, len } => offset..offset + len,
            ObjectSpan::Suffix(n) => size.saturating_sub(n)..size,
        };
        if expected.end > size {
            return Err(RemoteError::OutOfBounds {
                url,
                offset: expected.start,
                len: expected.end - expected.start,
                object_len: size,
            });
        }
        if got != expected || bytes.len() as u64 != expected.end - expected.start {
            return Err(RemoteError::WrongLength {
                url,
                offset: expected.start,
                expected: expected.end - expected.start,
                actual: bytes.len() as u64,
            });
        }
        Ok(Some((bytes.to_vec(), size)))
    }

    /// Several ranges of the object `key` (coalesced by object_store);
    /// `None` when it is missing.
    pub fn get_ranges(
        &self,
        key: &str,
        ranges: &[Range<u64>],
    ) -> Result<Option<Vec<Vec<u8>>>, RemoteError> {
        let (path, url) = self.locate(key)?;
        if ranges.iter().any(|r| r.start > r.end) {
            return Err(RemoteError::BadUrl {
                url,
                reason: "a range ends before it starts".into(),
            });
        }
        self.reads
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let store = self.store.clone();
        let wanted = ranges.to_vec();
        let traffic = self.traffic.clone();
        let got = match run_until(
            &self.runtime,
            &url,
            self.deadline,
            get_ranges_counted(store, path, wanted, traffic, self.gap),
            CancelToken::current().as_ref(),
        ) {
            Ok(g) => g,
            Err(e) if e.is_missing() => return Ok(None),
            Err(e) => return Err(e),
        };
        if got.len() != ranges.len() {
            return Err(RemoteError::WrongLength {
                url,
                offset: 0,
                expected: ranges.len() as u64,
                actual: got.len() as u64,
            });
        }
        let mut out = Vec::with_capacity(ranges.len());
        for (r, b) in ranges.iter().zip(got) {
            if b.len() as u64 != r.end - r.start {
                return Err(RemoteError::WrongLength {
                    url,
                    offset: r.start,
                    expected: r.end - r.start,
                    actual: b.len() as u64,
                });
            }
            out.push(b.to_vec());
        }
        Ok(Some(out))
    }
}

impl brickray_core::ObjectReader for RemoteObjects {
    fn location(&self) -> &str {
        &self.url
    }

    fn read_object(
        &self,
        key: &str,
        span: brickray_core::ObjectSpan,
    ) -> io::Result<Option<(Vec<u8>, u64)>> {
        Ok(self.get(key, span)?)
    }

    fn read_object_ranges(
        &self,
        key: &str,
        ranges: &[Range<u64>],
    ) -> io::Result<Option<Vec<Vec<u8>>>> {
        Ok(self.get_ranges(key, ranges)?)
    }
}
