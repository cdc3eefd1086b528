//! Byte-range reads: the seam between a format's parser and where its bytes
//! live (a local file, memory, object storage or an HTTP server).
//!
//! A [`RangeReader`] knows its length and reads one range or several; the
//! brick store's parser and reader go through it only. Local files implement
//! it with positional reads (`pread` on unix, `seek_read` on Windows),
//! [`MemRangeReader`] holds the bytes in memory, and `brickray-remote` reads
//! ranges over the network.

use std::fmt;
use std::io;
use std::sync::Arc;

/// A flag a reader polls to give up a read that nobody wants any more (a
/// brick the view left while its request was in flight). Clones share the
/// flag; cancelling is permanent.
#[derive(Debug, Clone, Default)]
pub struct CancelToken(Arc<std::sync::atomic::AtomicBool>);

impl CancelToken {
    /// A token not cancelled.
    pub fn new() -> CancelToken {
        CancelToken::default()
    }

    /// Cancels every read watching this token (or a clone of it).
    pub fn cancel(&self) {
        self.0.store(true, std::sync::atomic::Ordering::Release);
    }

    /// Whether [`cancel`](Self::cancel) was called.
    pub fn is_cancelled(&self) -> bool {
        self.0.load(std::sync::atomic::Ordering::Acquire)
    }

    /// Runs `f` with this token as the thread's [`current`](Self::current)
    /// one (the previous restored after, however `f` ends): a read deep in a
    /// call chain that carries no token (an object a format library asks
    /// for) aborts on it. A thread `f` starts does not inherit it; pass
    /// [`current`](Self::current) on.
    pub fn scope<T>(&self, f: impl FnOnce() -> T) -> T {
        struct Restore(Option<CancelToken>);
        impl Drop for Restore {
            fn drop(&mut self) {
                CURRENT.with(|c| *c.borrow_mut() = self.0.take());
            }
        }
        let _restore = Restore(CURRENT.with(|c| c.replace(Some(self.clone()))));
        f()
    }

    /// The token of the innermost [`scope`](Self::scope) running on this
    /// thread, if any.
    pub fn current() -> Option<CancelToken> {
        CURRENT.with(|c| c.borrow().clone())
    }
}

thread_local! {
    static CURRENT: std::cell::RefCell<Option<CancelToken>> = const { std::cell::RefCell::new(None) };
}

/// One range to read: `buf.len()` bytes at `offset`.
#[derive(Debug)]
pub struct RangeRead<'a> {
    /// The first byte's offset.
    pub offset: u64,
    /// Where the bytes go; its length is the range's.
    pub buf: &'a mut [u8],
}

/// Positional reads of an immutable sequence of bytes. Any number of threads
/// may read at once. A read either fills its buffer with exactly the bytes at
/// its offset or fails: a non-empty range that ends past [`len`](Self::len)
/// is an error (`UnexpectedEof`), never a short read. An empty range reads
/// nothing and succeeds.
pub trait RangeReader: Send + Sync + fmt::Debug {
    /// The length in bytes.
    fn len(&self) -> io::Result<u64>;

    /// Whether there are no bytes.
    fn is_empty(&self) -> io::Result<bool> {
        Ok(self.len()? == 0)
    }

    /// Fills `buf` with the bytes at `offset` (an error if they are not all
    /// there).
    fn read_exact_at(&self, buf: &mut [u8], offset: u64) -> io::Result<()>;

    /// Fills every range's buffer. The default reads them one after the
    /// other; a reader over the network fetches them concurrently and
    /// coalesces neighbours into one request. Fails as a whole: on an error
    /// the buffers' contents are unspecified.
    fn read_ranges(&self, ranges: &mut [RangeRead<'_>]) -> io::Result<()> {
        for r in ranges {
            self.read_exact_at(r.buf, r.offset)?;
        }
        Ok(())
    }

    /// [`read_ranges`](Self::read_ranges), given up (an error) when `cancel`
    /// is cancelled before the bytes arrive. The default ignores the token: a
    /// local read is over before anyone could cancel it; a reader over the
    /// network aborts its requests.
    fn read_ranges_cancellable(
        &self,
        ranges: &mut [RangeRead<'_>],
        cancel: &CancelToken,
    ) -> io::Result<()> {
        let _ = cancel;
        self.read_ranges(ranges)
    }

    /// Whether a read costs a round trip, so that a caller gains by batching
    /// ranges into one [`read_ranges`](Self::read_ranges) call (a reader over
    /// the network); `false` (the default) for local files and memory.
    fn is_remote(&self) -> bool {
        false
    }
}

impl<T: RangeReader + ?Sized> RangeReader for Arc<T> {
    fn len(&self) -> io::Result<u64> {
        (**self).len()
    }
    fn read_exact_at(&self, buf: &mut [u8], offset: u64) -> io::Result<()> {
        (**self).read_exact_at(buf, offset)
    }
    fn read_ranges(&self, ranges: &mut [RangeRead<'_>]) -> io::Result<()> {
        (**self).read_ranges(ranges)
    }
    fn is_remote(&self) -> bool {
        (**self).is_remote()
    }
    fn read_ranges_cancellable(
        &self,
        ranges: &mut [RangeRead<'_>],
        cancel: &CancelToken,
    ) -> io::Result<()> {
        (**self).read_ranges_cancellable(ranges, cancel)
    }
}

impl<T: RangeReader + ?Sized> RangeReader for Box<T> {
    fn len(&self) -> io::Result<u64> {
        (**self).len()
    }
    fn read_exact_at(&self, buf: &mut [u8], offset: u64) -> io::Result<()> {
        (**self).read_exact_at(buf, offset)
    }
    fn read_ranges(&self, ranges: &mut [RangeRead<'_>]) -> io::Result<()> {
        (**self).read_ranges(ranges)
    }
    fn is_remote(&self) -> bool {
        (**self).is_remote()
    }
    fn read_ranges_cancellable(
        &self,
        ranges: &mut [RangeRead<'_>],
        cancel: &CancelToken,
    ) -> io::Result<()> {
        (**self).read_ranges_cancellable(ranges, cancel)
    }
}

impl RangeReader for std::fs::File {
    fn len(&self) -> io::Result<u64> {
        Ok(self.metadata()?.len())
    }

    #[cfg(unix)]
    fn read_exact_at(&self, buf: &mut [u8], offset: u64) -> io::Result<()> {
        std::os::unix::fs::FileExt::read_exact_at(self, buf, offset)
    }

    #[cfg(windows)]
    fn read_exact_at(&self, mut buf: &mut [u8], mut offset: u64) -> io::Result<()> {
        use std::os::windows::fs::FileExt;
        while !buf.is_empty() {
            match self.seek_read(buf, offset) {
                Ok(0) => return Err(io::ErrorKind::UnexpectedEof.into()),
                Ok(n) => {
                    buf = &mut buf[n..];
                    offset += n as u64;
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        Ok(())
    }

    // Neither unix nor Windows: a file behind a lock, seek then read.
    #[cfg(not(any(unix, windows)))]
    fn read_exact_at(&self, buf: &mut [u8], offset: u64) -> io::Result<()> {
        use std::io::{Read, Seek, SeekFrom};
        static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
        let _guard = LOCK.lock().unwrap_or_else(|p| p.into_inner());
        let mut f = self;
        f.seek(SeekFrom::Start(offset))?;
        f.read_exact(buf)
    }
}

/// A part of one object read by an [`ObjectReader`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ObjectSpan {
    /// The whole object.
    All,
    /// `len` bytes from `offset` (a range past the object's end is an error).
    At {
        /// The first byte.
        offset: u64,
        /// Bytes wanted.
        len: u64,
    },
    /// The last `n` bytes (the whole object when it is shorter), in one
    /// request: a zarr shard's index, read without asking the size first.
    Suffix(u64),
}

/// Objects under one root (a folder of a bucket, a URL's directory) read by
/// key: the seam between a multi-file format (OME-Zarr) and where its
/// objects live. A missing object is `Ok(None)`, not an error, so that a
/// reader can apply the format's rule for it (zarr: the fill value).
pub trait ObjectReader: Send + Sync + fmt::Debug {
    /// Where the objects live (a URL), for messages.
    fn location(&self) -> &str;

    /// The bytes of `span` of the object `key` (relative to the root,
    /// `/`-separated) and the object's whole length; `None` when the object
    /// does not exist.
    fn read_object(&self, key: &str, span: ObjectSpan) -> io::Result<Option<(Vec<u8>, u64)>>;

    /// Several ranges (`offset..end`) of one object; `None` when it does not
    /// exist. The default reads them one after the other; a reader over the
    /// network fetches them concurrently and coalesces neighbours.
    fn read_object_ranges(
        &self,
        key: &str,
        ranges: &[std::ops::Range<u64>],
    ) -> io::Result<Option<Vec<Vec<u8>>>> {
        let mut out = Vec::with_capacity(ranges.len());
        for r in ranges {
            let span = ObjectSpan::At {
                offset: r.start,
                len: r.end.saturating_sub(r.start),
            };
            match self.read_object(key, span)? {
                Some((b, _)) => out.push(b),
                None => return Ok(None),
            }
        }
        Ok(Some(out))
    }
}

/// Bytes in memory as a [`RangeReader`] (tests, and stores fetched whole).
#[derive(Clone)]
pub struct MemRangeReader {
    bytes: Arc<[u8]>,
}

impl MemRangeReader {
    /// Reads from `bytes`.
    pub fn new(bytes: impl Into<Arc<[u8]>>) -> MemRangeReader {
        MemRangeReader {
            bytes: bytes.into(),
        }
    }

    /// The bytes.
    pub fn bytes(&self) -> &[u8] {
        &self.bytes
    }
}

impl fmt::Debug for MemRangeReader {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("MemRangeReader")
            .field("len", &self.bytes.len())
            .finish()
    }
}

impl RangeReader for MemRangeReader {
    fn len(&self) -> io::Result<u64> {
        Ok(self.bytes.len() as u64)
    }

    fn read_exact_at(&self, buf: &mut [u8], offset: u64) -> io::Result<()> {
        if buf.is_empty() {
            return Ok(());
        }
        let src = usize::try_from(offset)
            .ok()
            .and_then(|start| self.bytes.get(start..start.checked_add(buf.len())?))
            .ok_or_else(|| {
                io::Error::new(
                    io::ErrorKind::UnexpectedEof,
                    format!(
                        "range {offset}+{} ends past the {} bytes held",
                        buf.len(),
                        self.bytes.len()
                    ),
                )
            })?;
        buf.copy_from_slice(src);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Objects in memory by key.
    #[derive(Debug)]
    struct Objects(std::collections::HashMap<&'static str, Vec<u8>>);

    impl ObjectReader for Objects {
        fn location(&self) -> &str {
            "memory"
        }
        fn read_object(&self, key: &str, span: ObjectSpan) -> io::Result<Option<(Vec<u8>, u64)>> {
            let Some(b) = self.0.get(key) else {
                return Ok(None);
            };
            let n = b.len() as u64;
            let (lo, hi) = match span {
                ObjectSpan::All => (0, n),
                ObjectSpan::At { offset, len } => (offset, offset.saturating_add(len)),
                ObjectSpan::Suffix(k) => (n.saturating_sub(k), n),
            };
            if hi > n {
                return Err(io::ErrorKind::UnexpectedEof.into());
            }
            Ok(Some((b[lo as usize..hi as usize].to_vec(), n)))
        }
    }

    #[test]
    fn object_ranges_default_to_one_read_each_and_missing_is_none() {
        let o = Objects([("a", bytes(100))].into_iter().collect());
        let got = o
            .read_object_ranges("a", &[3..9, 90..100, 5..5])
            .unwrap()
            .unwrap();
        assert_eq!(
            got,
            vec![bytes(100)[3..9].to_vec(), bytes(100)[90..].to_vec(), vec![]]
        );
        assert!(o.read_object_ranges("b", &[0..1, 2..3]).unwrap().is_none());
        assert!(o.read_object_ranges("a", &[0..1, 95..101]).is_err());
        let (tail, len) = o
            .read_object("a", ObjectSpan::Suffix(500))
            .unwrap()
            .unwrap();
        assert_eq!((tail, len), (bytes(100), 100));
    }
    use proptest::prelude::*;

    fn bytes(n: usize) -> Vec<u8> {
        (0..n).map(|i| (i * 7 + i / 251) as u8).collect()
    }

    proptest! {
        #[test]
        fn mem_and_file_agree_on_every_range(
            n in 0usize..4096,
            ranges in proptest::collection::vec((0u64..5000, 0usize..700), 1..12),
        ) {
            let data = bytes(n);
            let mem = MemRangeReader::new(data.clone());
            let dir = tempfile::tempdir().unwrap();
            let path = dir.path().join("bytes");
            std::fs::write(&path, &data).unwrap();
            let file = std::fs::File::open(&path).unwrap();
            prop_assert_eq!(mem.len().unwrap(), n as u64);
            prop_assert_eq!(RangeReader::len(&file).unwrap(), n as u64);
            for &(off, len) in &ranges {
                let mut a = vec![0xAA; len];
                let mut b = vec![0x55; len];
                let ra = mem.read_exact_at(&mut a, off);
                let rb = RangeReader::read_exact_at(&file, &mut b, off);
                let inside = len == 0 || off as usize + len <= n;
                prop_assert_eq!(ra.is_ok(), inside);
                prop_assert_eq!(rb.is_ok(), inside);
                if inside && len > 0 {
                    prop_assert_eq!(&a[..], &data[off as usize..off as usize + len]);
                    prop_assert_eq!(&a, &b);
                } else if !inside {
                    prop_assert_eq!(ra.unwrap_err().kind(), io::ErrorKind::UnexpectedEof);
                    prop_assert_eq!(rb.unwrap_err().kind(), io::ErrorKind::UnexpectedEof);
                }
            }
            // Several ranges at once: all inside, the same bytes; one outside, an error.
            let mut bufs: Vec<Vec<u8>> = ranges.iter().map(|&(_, l)| vec![0; l]).collect();
            let mut reads: Vec<RangeRead<'_>> = ranges
                .iter()
                .zip(bufs.iter_mut())
                .map(|(&(offset, _), buf)| RangeRead { offset, buf })
                .collect();
            let all_inside = ranges.iter().all(|&(o, l)| l == 0 || o as usize + l <= n);
            prop_assert_eq!(mem.read_ranges(&mut reads).is_ok(), all_inside);
            if all_inside {
                for (&(o, l), b) in ranges.iter().zip(&bufs).filter(|(r, _)| r.1 > 0) {
                    prop_assert_eq!(&b[..], &data[o as usize..o as usize + l]);
                }
            }
        }
    }

    #[test]
    fn offsets_past_usize_are_errors_not_panics() {
        let mem = MemRangeReader::new(vec![1u8; 8]);
        let mut b = [0u8; 4];
        assert!(mem.read_exact_at(&mut b, u64::MAX).is_err());
        assert!(mem.read_exact_at(&mut b, u64::MAX - 2).is_err());
        assert!(mem.read_exact_at(&mut [], u64::MAX).is_ok());
        assert!(mem.read_exact_at(&mut b, 5).is_err());
        mem.read_exact_at(&mut b, 4).unwrap();
        assert_eq!(b, [1; 4]);
    }

    #[test]
    fn a_cancel_scope_nests_and_is_restored_however_it_ends() {
        assert!(CancelToken::current().is_none());
        let (outer, inner) = (CancelToken::new(), CancelToken::new());
        outer.scope(|| {
            inner.cancel();
            let seen = inner.scope(|| CancelToken::current().unwrap().is_cancelled());
            assert!(seen);
            // back to the outer token (not cancelled)
            assert!(!CancelToken::current().unwrap().is_cancelled());
            // a panic inside a scope restores it too
            let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                inner.scope(|| panic!("read failed"))
            }));
            assert!(r.is_err());
            assert!(!CancelToken::current().unwrap().is_cancelled());
            // another thread does not see it
            std::thread::scope(|s| {
                s.spawn(|| assert!(CancelToken::current().is_none()));
            });
        });
        assert!(CancelToken::current().is_none());
    }
}
