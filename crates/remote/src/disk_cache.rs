//! An optional local disk cache of fetched ranges ([`DiskCached`]): a
//! second visit of a remote volume reads from the disk what the first
//! fetched.
//!
//! * **What is cached.** Each range a reader fetched, by its offset and
//!   length, in a folder of the object's own under the cache's root. The
//!   folder's name is a hash of the object's identity: its URL, its ETag
//!   and its length ([`DiskCached::new`]), so an object replaced on the
//!   server (a new ETag) starts a new folder and the old one ages out.
//!   Without an ETag the length alone tells versions apart; a brick store's
//!   payload checksums still catch bytes of another version.
//! * **Validated.** Each entry ends in the CRC-32 of its bytes; an entry
//!   whose length or checksum is wrong (a torn or corrupt file) is deleted
//!   and fetched again.
//! * **Bounded.** The root's total is kept below `max_bytes`: past it the
//!   least recently used entries (by modification time, refreshed on each
//!   hit) are deleted until it is 90% full.
//! * **Shared by processes.** An entry is written to a temporary file and
//!   renamed into place, so a reader never sees half of one; two processes
//!   that fetch the same range both write it and one rename wins; an entry
//!   another process evicts is a miss. Nothing is locked.

use brickray_core::{CancelToken, RangeRead, RangeReader};
use parking_lot::Mutex;
use std::fs;
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::SystemTime;

/// Where the cache lives and how large it may grow.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DiskCacheConfig {
    /// The cache's root folder (created when missing).
    pub dir: PathBuf,
    /// Most bytes the root may hold, entries of every object together.
    pub max_bytes: u64,
}

/// Default [`DiskCacheConfig::max_bytes`]: 1 GiB.
pub const DEFAULT_DISK_CACHE_BYTES: u64 = 1 << 30;

impl DiskCacheConfig {
    /// From `BRICKRAY_CACHE_DIR` (the root; no cache when unset or empty)
    /// and `BRICKRAY_CACHE_MAX_MB` (the bound in MiB, default 1024).
    pub fn from_env() -> Option<DiskCacheConfig> {
        let dir = std::env::var_os("BRICKRAY_CACHE_DIR").filter(|d| !d.is_empty())?;
        let max_bytes = std::env::var("BRICKRAY_CACHE_MAX_MB")
            .ok()
            .and_then(|m| m.trim().parse::<u64>().ok())
            .map_or(DEFAULT_DISK_CACHE_BYTES, |m| m << 20);
        Some(DiskCacheConfig {
            dir: dir.into(),
            max_bytes,
        })
    }
}

/// Hits and misses of a [`DiskCached`] reader.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DiskCacheStats {
    /// Ranges read from the disk.
    pub hits: u64,
    /// Ranges fetched from the inner reader (and written to the disk).
    pub misses: u64,
    /// Entries found torn or corrupt (deleted, fetched again).
    pub corrupt: u64,
}

/// A [`RangeReader`] that keeps what `inner` fetched on the local disk
/// (see the module's documentation).
#[derive(Debug)]
pub struct DiskCached<R> {
    inner: R,
    entries: Entries,
}

/// One object's folder of entries under a cache root: validated loads,
/// atomic saves, the root's bound, and the counts of hits and misses
/// (shared by [`DiskCached`] and [`DiskCachedObjects`](crate::DiskCachedObjects)).
#[derive(Debug)]
pub(crate) struct Entries {
    root: PathBuf,
    dir: PathBuf,
    max_bytes: u64,
    /// Bytes the root holds, as this reader last counted them.
    used: Mutex<u64>,
    hits: AtomicU64,
    misses: AtomicU64,
    corrupt: AtomicU64,
}

/// FNV-1a, 64 bits: a stable name for an object's folder.
pub(crate) fn fnv1a(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

/// Every entry under `root`: (modification time, path, bytes).
fn entries(root: &Path) -> Vec<(SystemTime, PathBuf, u64)> {
    let mut out = Vec::new();
    let Ok(objects) = fs::read_dir(root) else {
        return out;
    };
    for object in objects.flatten() {
        let Ok(files) = fs::read_dir(object.path()) else {
            continue;
        };
        for f in files.flatten() {
            let Ok(md) = f.metadata() else { continue };
            let name = f.file_name();
            let name = name.to_string_lossy();
            if md.is_file() && !name.contains(".tmp") && name != "identity" {
                let t = md.modified().unwrap_or(SystemTime::UNIX_EPOCH);
                out.push((t, f.path(), md.len()));
            }
        }
    }
    out
}

impl Entries {
    /// The folder of the object named by `identity` under `config.dir`.
    pub(crate) fn new(identity: &str, config: &DiskCacheConfig) -> io::Result<Entries> {
        let dir = config
            .dir
            .join(format!("{:016x}", fnv1a(identity.as_bytes())));
        fs::create_dir_all(&dir)?;
        let id = dir.join("identity");
        if !id.exists() {
            // For a person looking into the cache; never read back.
            let _ = fs::write(&id, identity);
        }
        let used = entries(&config.dir).iter().map(|e| e.2).sum();
        Ok(Entries {
            root: config.dir.clone(),
            dir,
            max_bytes: config.max_bytes,
            used: Mutex::new(used),
            hits: AtomicU64::new(0),
            misses: AtomicU64::new(0),
            corrupt: AtomicU64::new(0),
        })
    }

    pub(crate) fn stats(&self) -> DiskCacheStats {
        DiskCacheStats {
            hits: self.hits.load(Ordering::Relaxed),
            misses: self.misses.load(Ordering::Relaxed),
            corrupt: self.corrupt.load(Ordering::Relaxed),
        }
    }

    pub(crate) fn dir(&self) -> &Path {
        &self.dir
    }

    /// The bytes of entry `name` if a valid one is there (its trailing
    /// CRC-32 checked; `len`, when given, its length), counted as a hit;
    /// a torn or corrupt one is deleted and counted.
    pub(crate) fn load(&self, name: &str, len: Option<usize>) -> Option<Vec<u8>> {
        let path = self.dir.join(name);
        let mut bytes = fs::read(&path).ok()?;
        let n = bytes.len().checked_sub(4);
        let valid = n.is_some_and(|n| {
            len.is_none_or(|l| l == n) && crc32fast::hash(&bytes[..n]).to_le_bytes() == bytes[n..]
        });
        if !valid {
            self.corrupt.fetch_add(1, Ordering::Relaxed);
            let _ = fs::remove_file(&path);
            return None;
        }
        bytes.truncate(bytes.len() - 4);
        // Recently used: keep it longest.
        if let Ok(f) = fs::File::options().append(true).open(&path) {
            let _ = f.set_modified(SystemTime::now());
        }
        self.hits.fetch_add(1, Ordering::Relaxed);
        Some(bytes)
    }

    /// Writes entry `name` holding `bytes`, counted as a miss (best effort:
    /// a full disk or a read-only folder leaves the read uncached, never
    /// failed).
    pub(crate) fn save(&self, name: &str, bytes: &[u8]) {
        static SEQ: AtomicU64 = AtomicU64::new(0);
        self.misses.fetch_add(1, Ordering::Relaxed);
        let path = self.dir.join(name);
        let tmp = self.dir.join(format!(
            "{name}.tmp.{}.{}",
            std::process::id(),
            SEQ.fetch_add(1, Ordering::Relaxed)
        ));
        let written = (|| -> io::Result<()> {
            let mut f = fs::File::create(&tmp)?;
            f.write_all(bytes)?;
            f.write_all(&crc32fast::hash(bytes).to_le_bytes())?;
            drop(f);
            fs::rename(&tmp, &path)
        })();
        if written.is_err() {
            let _ = fs::remove_file(&tmp);
            return;
        }
        let over = {
            let mut used = self.used.lock();
            *used += bytes.len() as u64 + 4;
            *used > self.max_bytes
        };
        if over {
            self.evict();
        }
    }

    /// Deletes the least recently used entries of the whole root until it
    /// holds 90% of the bound (counted afresh: other processes write too).
    fn evict(&self) {
        let mut all = entries(&self.root);
        let mut total: u64 = all.iter().map(|e| e.2).sum();
        all.sort();
        let target = self.max_bytes / 10 * 9;
        for (_, path, len) in all {
            if total <= target {
                break;
            }
            if fs::remove_file(&path).is_ok() {
                total -= len;
            }
        }
        *self.used.lock() = total;
    }
}

impl<R: RangeReader> DiskCached<R> {
    /// Caches `inner`, the object named by `identity` (its URL, ETag and
    /// length: what changes when the object does), under `config.dir`.
    pub fn new(inner: R, identity: &str, config: &DiskCacheConfig) -> io::Result<DiskCached<R>> {
        Ok(DiskCached {
            inner,
            entries: Entries::new(identity, config)?,
        })
    }

    /// The reader it caches.
    pub fn inner(&self) -> &R {
        &self.inner
    }

    /// Hits, misses and corrupt entries so far.
    pub fn stats(&self) -> DiskCacheStats {
        self.entries.stats()
    }

    /// The object's folder.
    pub fn dir(&self) -> &Path {
        self.entries.dir()
    }

    /// Reads `ranges`: hits from the disk, the misses in one call of
    /// `fetch` (then saved).
    fn read_with(
        &self,
        ranges: &mut [RangeRead<'_>],
        fetch: impl FnOnce(&mut [RangeRead<'_>]) -> io::Result<()>,
    ) -> io::Result<()> {
        let name = |offset: u64, len: usize| format!("{offset}-{len}");
        let mut misses: Vec<RangeRead<'_>> = Vec::new();
        for r in ranges.iter_mut() {
            let hit = !r.buf.is_empty()
                && self
                    .entries
                    .load(&name(r.offset, r.buf.len()), Some(r.buf.len()))
                    .map(|b| r.buf.copy_from_slice(&b))
                    .is_some();
            if !hit {
                misses.push(RangeRead {
                    offset: r.offset,
                    buf: &mut *r.buf,
                });
            }
        }
        if misses.is_empty() {
            return Ok(());
        }
        fetch(&mut misses)?;
        for m in &misses {
            if !m.buf.is_empty() {
                self.entries.save(&name(m.offset, m.buf.len()), m.buf);
            }
        }
        Ok(())
    }
}

impl<R: RangeReader> RangeReader for DiskCached<R> {
    fn len(&self) -> io::Result<u64> {
        self.inner.len()
    }

    fn read_exact_at(&self, buf: &mut [u8], offset: u64) -> io::Result<()> {
        self.read_with(&mut [RangeRead { offset, buf }], |m| {
            self.inner.read_ranges(m)
        })
    }

    fn read_ranges(&self, ranges: &mut [RangeRead<'_>]) -> io::Result<()> {
        self.read_with(ranges, |m| self.inner.read_ranges(m))
    }

    fn read_ranges_cancellable(
        &self,
        ranges: &mut [RangeRead<'_>],
        cancel: &CancelToken,
    ) -> io::Result<()> {
        self.read_with(ranges, |m| self.inner.read_ranges_cancellable(m, cancel))
    }

    fn is_remote(&self) -> bool {
        self.inner.is_remote()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use brickray_core::MemRangeReader;
    use proptest::prelude::*;
    use std::sync::Arc;

    /// Counts the reads that reach the "network".
    #[derive(Debug)]
    struct Counting(MemRangeReader, AtomicU64);

    impl RangeReader for Counting {
        fn len(&self) -> io::Result<u64> {
            self.0.len()
        }
        fn read_exact_at(&self, buf: &mut [u8], offset: u64) -> io::Result<()> {
            self.1.fetch_add(1, Ordering::Relaxed);
            self.0.read_exact_at(buf, offset)
        }
    }

    fn bytes(n: usize) -> Vec<u8> {
        (0..n).map(|i| (i * 7 + i / 251) as u8).collect()
    }

    fn config(dir: &Path, max_bytes: u64) -> DiskCacheConfig {
        DiskCacheConfig {
            dir: dir.to_owned(),
            max_bytes,
        }
    }

    fn cached(data: &[u8], dir: &Path, max: u64, id: &str) -> DiskCached<Counting> {
        let inner = Counting(MemRangeReader::new(data.to_vec()), AtomicU64::new(0));
        DiskCached::new(inner, id, &config(dir, max)).unwrap()
    }

    #[test]
    fn a_second_visit_reads_from_the_disk() {
        let dir = tempfile::tempdir().unwrap();
        let data = bytes(10_000);
        let first = cached(&data, dir.path(), 1 << 20, "u\ne1\n10000");
        let mut a = [0u8; 100];
        let mut b = [0u8; 50];
        let mut ranges = [
            RangeRead {
                offset: 10,
                buf: &mut a,
            },
            RangeRead {
                offset: 5000,
                buf: &mut b,
            },
        ];
        first.read_ranges(&mut ranges).unwrap();
        assert_eq!(&a[..], &data[10..110]);
        assert_eq!(&b[..], &data[5000..5050]);
        assert_eq!(first.inner().1.load(Ordering::Relaxed), 2);
        // Another reader (a second process, a second visit) of the same
        // object: no read reaches the network.
        let second = cached(&data, dir.path(), 1 << 20, "u\ne1\n10000");
        let mut c = [0u8; 100];
        second.read_exact_at(&mut c, 10).unwrap();
        assert_eq!(c, a);
        assert_eq!(second.inner().1.load(Ordering::Relaxed), 0);
        assert_eq!(second.stats().hits, 1);
        // A new ETag is another object: fetched again.
        let replaced = cached(&data, dir.path(), 1 << 20, "u\ne2\n10000");
        replaced.read_exact_at(&mut c, 10).unwrap();
        assert_eq!(replaced.inner().1.load(Ordering::Relaxed), 1);
    }

    #[test]
    fn a_corrupt_or_torn_entry_is_fetched_again() {
        let dir = tempfile::tempdir().unwrap();
        let data = bytes(1000);
        let c = cached(&data, dir.path(), 1 << 20, "x");
        let mut a = [0u8; 64];
        c.read_exact_at(&mut a, 100).unwrap();
        let entry = c.dir().join("100-64");
        let mut raw = fs::read(&entry).unwrap();
        raw[3] ^= 0xff;
        fs::write(&entry, &raw).unwrap();
        let mut b = [0u8; 64];
        c.read_exact_at(&mut b, 100).unwrap();
        assert_eq!(&b[..], &data[100..164]);
        assert_eq!(c.stats().corrupt, 1);
        // Torn: cut short.
        fs::write(&entry, &raw[..10]).unwrap();
        c.read_exact_at(&mut b, 100).unwrap();
        assert_eq!(&b[..], &data[100..164]);
        assert_eq!(c.stats().corrupt, 2);
        assert_eq!(c.inner().1.load(Ordering::Relaxed), 3);
    }

    #[test]
    fn the_cache_stays_within_its_bound() {
        let dir = tempfile::tempdir().unwrap();
        let data = bytes(100_000);
        let c = cached(&data, dir.path(), 10_000, "x");
        let mut buf = [0u8; 1000];
        for i in 0..50 {
            c.read_exact_at(&mut buf, i * 1000).unwrap();
            let total: u64 = entries(dir.path()).iter().map(|e| e.2).sum();
            assert!(total <= 10_000, "{total} bytes after {i} reads");
        }
        // The most recent reads are the ones kept.
        let before = c.inner().1.load(Ordering::Relaxed);
        c.read_exact_at(&mut buf, 49_000).unwrap();
        assert_eq!(c.inner().1.load(Ordering::Relaxed), before);
    }

    #[test]
    fn two_processes_sharing_the_cache_read_right() {
        // Two readers on one folder (as two processes), racing on the same
        // ranges from several threads each.
        let dir = tempfile::tempdir().unwrap();
        let data = bytes(50_000);
        let a = Arc::new(cached(&data, dir.path(), 30_000, "x"));
        let b = Arc::new(cached(&data, dir.path(), 30_000, "x"));
        std::thread::scope(|s| {
            for t in 0..8 {
                let c = if t % 2 == 0 { a.clone() } else { b.clone() };
                let data = &data;
                s.spawn(move || {
                    let mut buf = vec![0u8; 700];
                    for i in 0..200u64 {
                        let off = (i * 977 + t * 131) % 49_000;
                        c.read_exact_at(&mut buf, off).unwrap();
                        assert_eq!(&buf[..], &data[off as usize..off as usize + 700]);
                    }
                });
            }
        });
        assert_eq!(a.stats().corrupt + b.stats().corrupt, 0);
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 32, ..ProptestConfig::default() })]

        /// Any reads through the cache, twice, read what the object holds.
        #[test]
        fn reads_through_the_cache_equal_the_object(
            reads in proptest::collection::vec((0u64..4000, 0usize..300), 1..20),
            max in 500u64..20_000,
        ) {
            let dir = tempfile::tempdir().unwrap();
            let data = bytes(4300);
            let c = cached(&data, dir.path(), max, "p");
            for _ in 0..2 {
                for &(off, len) in &reads {
                    let mut buf = vec![0u8; len];
                    c.read_exact_at(&mut buf, off).unwrap();
                    prop_assert_eq!(&buf[..], &data[off as usize..off as usize + len]);
                }
            }
        }
    }
}
