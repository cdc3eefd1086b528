//! [`RemoteRangeReader`]: one remote object read by byte ranges (a brick
//! store over S3, GCS, Azure or HTTP), on the source's own runtime.

use super::*;

/// A [`RangeReader`] over one remote object (see the crate's
/// documentation). Opening asks for the object's size (one `HEAD`); reads
/// are ranged `GET`s, several ranges at once coalesced by object_store
/// (neighbours less than 1 MiB apart become one request). Every returned
/// range is checked for its length.
pub struct RemoteRangeReader {
    url: String,
    store: Arc<dyn ObjectStore>,
    path: ObjectPath,
    len: u64,
    etag: Option<String>,
    deadline: Duration,
    runtime: Runtime,
    traffic: Arc<Traffic>,
    gap: u64,
}

impl fmt::Debug for RemoteRangeReader {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("RemoteRangeReader")
            .field("url", &self.url)
            .field("len", &self.len)
            .field("etag", &self.etag)
            .finish()
    }
}

impl RemoteRangeReader {
    /// Opens `url` (configured by `opts`): starts the reader's runtime and
    /// asks for the object's size. A missing object is
    /// [`RemoteError::Missing`].
    pub fn open(url: &str, opts: &RemoteOptions) -> Result<RemoteRangeReader, RemoteError> {
        let (store, path) = object_store_for(url, opts)?;
        let runtime = start_runtime(url, opts)?;
        let mut reader = RemoteRangeReader {
            url: url.to_owned(),
            store,
            path,
            len: 0,
            etag: None,
            deadline: opts.deadline(),
            runtime,
            traffic: Arc::default(),
            gap: opts.coalesce_gap,
        };
        let (store, path) = (reader.store.clone(), reader.path.clone());
        reader.traffic.count(0);
        let meta = reader.run(async move { store.head(&path).await })?;
        reader.len = meta.size;
        reader.etag = meta.e_tag;
        Ok(reader)
    }

    /// The URL.
    pub fn url(&self) -> &str {
        &self.url
    }

    /// The object's size in bytes (asked for at open).
    pub fn object_len(&self) -> u64 {
        self.len
    }

    /// The object's ETag at open, if the server sent one.
    pub fn etag(&self) -> Option<&str> {
        self.etag.as_deref()
    }

    /// Requests and bytes fetched so far, the `HEAD` at open included.
    pub fn fetched(&self) -> Fetched {
        self.traffic.get()
    }

    fn run<T: Send + 'static>(
        &self,
        f: impl Future<Output = object_store::Result<T>> + Send + 'static,
    ) -> Result<T, RemoteError> {
        run_on(&self.runtime, &self.url, self.deadline, f)
    }

    fn check_bounds(&self, offset: u64, len: u64) -> Result<Range<u64>, RemoteError> {
        match offset.checked_add(len) {
            Some(end) if end <= self.len => Ok(offset..end),
            _ => Err(RemoteError::OutOfBounds {
                url: self.url.clone(),
                offset,
                len,
                object_len: self.len,
            }),
        }
    }

    fn check_len(&self, offset: u64, expected: usize, actual: usize) -> Result<(), RemoteError> {
        if expected != actual {
            return Err(RemoteError::WrongLength {
                url: self.url.clone(),
                offset,
                expected: expected as u64,
                actual: actual as u64,
            });
        }
        Ok(())
    }

    /// Reads `range` of the object (typed errors; the [`RangeReader`]
    /// methods wrap them in I/O errors).
    pub fn read_range(&self, buf: &mut [u8], offset: u64) -> Result<(), RemoteError> {
        if buf.is_empty() {
            return Ok(());
        }
        let range = self.check_bounds(offset, buf.len() as u64)?;
        let (store, path) = (self.store.clone(), self.path.clone());
        let traffic = self.traffic.clone();
        let bytes = self.run(async move {
            let b = store.get_range(&path, range).await?;
            traffic.count(b.len() as u64);
            Ok(b)
        })?;
        self.check_len(offset, buf.len(), bytes.len())?;
        buf.copy_from_slice(&bytes);
        Ok(())
    }

    /// Reads several ranges: neighbours coalesced, the rest fetched
    /// concurrently.
    pub fn read_many(&self, ranges: &mut [RangeRead<'_>]) -> Result<(), RemoteError> {
        self.read_many_until(ranges, None)
    }

    /// [`read_many`](Self::read_many), aborted with
    /// [`RemoteError::Cancelled`] when `cancel` is cancelled before the
    /// bytes arrive (within a few milliseconds; the requests are dropped).
    pub fn read_many_cancellable(
        &self,
        ranges: &mut [RangeRead<'_>],
        cancel: &CancelToken,
    ) -> Result<(), RemoteError> {
        self.read_many_until(ranges, Some(cancel))
    }

    fn read_many_until(
        &self,
        ranges: &mut [RangeRead<'_>],
        cancel: Option<&CancelToken>,
    ) -> Result<(), RemoteError> {
        let mut wanted = Vec::with_capacity(ranges.len());
        for r in ranges.iter() {
            if !r.buf.is_empty() {
                wanted.push(self.check_bounds(r.offset, r.buf.len() as u64)?);
            }
        }
        if wanted.is_empty() {
            return Ok(());
        }
        let (store, path) = (self.store.clone(), self.path.clone());
        let got = run_until(
            &self.runtime,
            &self.url,
            self.deadline,
            get_ranges_counted(store, path, wanted, self.traffic.clone(), self.gap),
            cancel,
        )?;
        let mut got = got.into_iter();
        for r in ranges.iter_mut().filter(|r| !r.buf.is_empty()) {
            let bytes = got.next().unwrap_or_default();
            self.check_len(r.offset, r.buf.len(), bytes.len())?;
            r.buf.copy_from_slice(&bytes);
        }
        Ok(())
    }
}

impl RangeReader for RemoteRangeReader {
    fn len(&self) -> io::Result<u64> {
        Ok(self.len)
    }

    fn read_exact_at(&self, buf: &mut [u8], offset: u64) -> io::Result<()> {
        Ok(self.read_range(buf, offset)?)
    }

    fn read_ranges(&self, ranges: &mut [RangeRead<'_>]) -> io::Result<()> {
        Ok(self.read_many(ranges)?)
    }

    fn read_ranges_cancellable(
        &self,
        ranges: &mut [RangeRead<'_>],
        cancel: &CancelToken,
    ) -> io::Result<()> {
        Ok(self.read_many_cancellable(ranges, cancel)?)
    }

    fn is_remote(&self) -> bool {
        true
    }
}
