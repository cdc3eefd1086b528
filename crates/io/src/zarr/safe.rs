//! What stands between an OME-Zarr store on disk and zarrs: a read-only store
//! that refuses anything but regular files and byte ranges outside a file,
//! and chunk codecs whose decoders cannot allocate more than the chunk's
//! geometry allows.
//!
//! * [`SafeStore`] replaces zarrs' `FilesystemStore` for reading: a FIFO or a
//!   device in place of a metadata file or a chunk is refused before it is
//!   opened (opening a FIFO blocks), and a byte range that does not lie in
//!   the file (a forged shard index) is refused before a buffer is allocated
//!   for it (the filesystem store allocates the range's length first).
//! * [`SafeStore::objects`] reads the same keys through an
//!   [`ObjectReader`] (an image over HTTP or in a bucket): a missing object
//!   (404, or the 403 S3 answers for one) is a missing key, read as the
//!   fill value; each shard's index is fetched once, with a suffix range
//!   (the index and the shard's length in one request), checked, and kept
//!   (at most [`INDEX_CACHE_BYTES`]), so zarrs' own reads of it cost nothing.
//! * [`install`] registers bounded variants of the `zstd`, `gzip` and
//!   `blosc` codecs with zarrs (they take precedence over its own, for every
//!   array zarrs opens in the process; encoding is unchanged). Each decodes
//!   into at most the size the chunk's geometry gives (its shape times the
//!   sample size, passed down the codec chain), so a 16-byte zstd frame that
//!   declares 1 TiB of content, a gzip bomb or a blosc header declaring
//!   2 GiB is a decode error instead of an allocation that aborts the
//!   process. Zarr v2 arrays are re-created from their v3 form so that their
//!   compressors go through these codecs too.

use crate::IoError;
use brickray_core::{ObjectReader, ObjectSpan};
use parking_lot::Mutex;
use std::borrow::Cow;
use std::collections::{HashMap, VecDeque};
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Once};
use zarrs::array::codec::api::{
    BytesToBytesCodecTraits, Codec, CodecError, CodecMetadataOptions, CodecOptions, CodecTraits,
    CodecTraitsV3, PartialDecoderCapability, PartialEncoderCapability, RecommendedConcurrency,
};
use zarrs::array::{ArrayBytesRaw, BytesRepresentation};
use zarrs::metadata::Configuration;
use zarrs::metadata::v3::MetadataV3;
use zarrs::plugin::{ExtensionName, PluginCreateError, ZarrVersion};
use zarrs::storage::byte_range::{ByteRange, ByteRangeIterator, InvalidByteRangeError};
use zarrs::storage::{Bytes, MaybeBytesIterator, ReadableStorageTraits, StorageError, StoreKey};

/// The largest decoded chunk (or shard index) read: 1 GiB. A chunk whose
/// geometry says more is refused when the array is opened.
pub(crate) const MAX_CHUNK_BYTES: u64 = 1 << 30;

/// Most bytes of shard indices a store over an [`ObjectReader`] keeps (the
/// oldest go first).
pub(crate) const INDEX_CACHE_BYTES: u64 = 64 << 20;

/// Where a [`SafeStore`]'s keys live.
#[derive(Debug)]
enum Backend {
    /// Files under the root folder.
    Local,
    /// Objects read by key (over HTTP, in a bucket).
    Objects(Arc<dyn ObjectReader>),
}

/// Shard indices fetched from an [`ObjectReader`], checked, by key: one
/// slot per key, locked while its index is fetched (so that two readers of
/// one shard fetch its index once).
#[derive(Debug, Default)]
struct IndexCache {
    map: HashMap<String, Arc<Mutex<Option<Arc<Fetched>>>>>,
    /// Keys with a fetched index, oldest first, and their cost.
    order: VecDeque<(String, u64)>,
    bytes: u64,
}

/// Metadata objects (`zarr.json`, `.zarray`, `.zattrs`, `.zgroup`) read from
/// an [`ObjectReader`] (`None`: missing), so that zarrs' reads of them cost
/// no second request.
type MetaCache = HashMap<String, Option<Vec<u8>>>;

/// A shard's index as fetched (`None`: the shard is missing) and the
/// shard's length.
#[derive(Debug)]
struct Fetched {
    index: Option<(Vec<u8>, u64)>,
}

/// A read-only store over a folder: regular files only, byte ranges checked
/// against the file's size. The first refusal is kept ([`SafeStore::take_error`])
/// so that the reader reports it as the typed error it is, not as the text
/// zarrs wraps it in.
///
/// The shards of a sharded array are checked whole before zarrs reads any
/// part of them: every entry of the shard index must be empty or point
/// inside the file (zarrs adds offset and length unchecked: a forged index
/// panics it, or makes it allocate the length).
#[derive(Debug)]
pub(crate) struct SafeStore {
    root: PathBuf,
    backend: Backend,
    indices: Mutex<IndexCache>,
    meta: Mutex<MetaCache>,
    refused: Mutex<Option<IoError>>,
    /// Per sharded array (its key prefix, `s0/`), the layout of its shards'
    /// index.
    shards: Mutex<Vec<(String, ShardIndex)>>,
}

/// Where a shard's index lies and how long it is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct ShardIndex {
    /// Entries (inner chunks per shard), 16 bytes each.
    pub(crate) entries: u64,
    /// Bytes after the entries (4: a crc32c).
    pub(crate) trailer: u64,
    /// The index is at the end of the shard (else at its start).
    pub(crate) at_end: bool,
}

impl SafeStore {
    pub(crate) fn new(root: &Path) -> SafeStore {
        SafeStore {
            root: root.to_owned(),
            backend: Backend::Local,
            indices: Mutex::new(IndexCache::default()),
            meta: Mutex::new(MetaCache::new()),
            refused: Mutex::new(None),
            shards: Mutex::new(Vec::new()),
        }
    }

    /// A store over the objects of `reader` (its location names them in
    /// errors).
    pub(crate) fn objects(reader: Arc<dyn ObjectReader>) -> SafeStore {
        SafeStore {
            root: PathBuf::from(reader.location()),
            backend: Backend::Objects(reader),
            indices: Mutex::new(IndexCache::default()),
            meta: Mutex::new(MetaCache::new()),
            refused: Mutex::new(None),
            shards: Mutex::new(Vec::new()),
        }
    }

    /// Whether the keys are files of a local folder (which can be listed).
    pub(crate) fn is_local(&self) -> bool {
        matches!(self.backend, Backend::Local)
    }

    /// The root (a folder, or the objects' location as a path).
    pub(crate) fn root(&self) -> &Path {
        &self.root
    }

    /// A metadata object's JSON (`key`: `zarr.json`, `s0/.zarray`, ...);
    /// `Ok(None)` when it does not exist. At most 1 MiB; locally, regular
    /// files only.
    pub(crate) fn json(&self, key: &str) -> Result<Option<serde_json::Value>, IoError> {
        let path = self.root.join(key);
        let reader = match &self.backend {
            Backend::Local => return super::read_json(&path),
            Backend::Objects(r) => r,
        };
        let Some(b) = self.meta_object(&**reader, key, &path)? else {
            return Ok(None);
        };
        serde_json::from_slice(&b)
            .map(Some)
            .map_err(|e| IoError::header(&path, e.to_string()))
    }

    /// Reads the metadata objects `keys` at once (over an object reader:
    /// concurrently, each on a thread of its own, so that an image's levels
    /// cost one round trip, not one each); the later [`json`](Self::json)
    /// calls find them. Errors are left for those calls to meet; local
    /// files need no warming.
    pub(crate) fn prefetch_json(&self, keys: &[String]) {
        let Backend::Objects(reader) = &self.backend else {
            return;
        };
        std::thread::scope(|scope| {
            for key in keys {
                let path = self.root.join(key);
                scope.spawn(move || {
                    let _ = self.meta_object(&**reader, key, &path);
                });
            }
        });
    }

    /// Declares the array at `prefix` (`s0/`) sharded, its shards indexed as
    /// `index` says.
    pub(crate) fn add_sharded(&self, prefix: String, index: ShardIndex) {
        self.shards.lock().push((prefix, index));
    }

    /// The index layout of `key`'s shard, if it is one.
    fn shard_of(&self, key: &str) -> Option<ShardIndex> {
        let name = key.rsplit('/').next().unwrap_or(key);
        if matches!(name, "zarr.json" | ".zarray" | ".zattrs" | ".zgroup") {
            return None;
        }
        self.shards
            .lock()
            .iter()
            .find(|(p, _)| key.starts_with(p.as_str()))
            .map(|(_, i)| *i)
    }

    /// A metadata object's bytes (`None`: missing), fetched once: its last
    /// 1 MiB + 1 byte, which is the whole object when it is shorter, and its
    /// length says whether it is longer, in one request.
    fn meta_object(
        &self,
        reader: &dyn ObjectReader,
        key: &str,
        path: &Path,
    ) -> Result<Option<Vec<u8>>, IoError> {
        if let Some(m) = self.meta.lock().get(key) {
            return Ok(m.clone());
        }
        let cap = crate::MAX_HEADER as u64;
        let got = reader
            .read_object(key, ObjectSpan::Suffix(cap + 1))
            .map_err(|e| IoError::io(path, e))?;
        let bytes = match got {
            None => None,
            Some((_, len)) if len > cap => {
                return Err(IoError::header(path, "metadata longer than 1 MiB"));
            }
            Some((b, _)) => Some(b),
        };
        self.meta.lock().insert(key.to_owned(), bytes.clone());
        Ok(bytes)
    }

    /// The index's length in bytes (entries and trailer), if the shard of
    /// `size` bytes (`None`: not known yet) can hold it.
    fn index_len(
        &self,
        path: &Path,
        size: Option<u64>,
        ix: ShardIndex,
    ) -> Result<u64, StorageError> {
        ix.entries
            .checked_mul(16)
            .and_then(|l| l.checked_add(ix.trailer))
            .filter(|&l| size.is_none_or(|s| l <= s))
            .ok_or_else(|| {
                self.refuse(IoError::decode(
                    path,
                    "OME-Zarr",
                    format!(
                        "a {}-byte shard cannot hold its index of {} entries",
                        size.unwrap_or(0),
                        ix.entries
                    ),
                ))
            })
    }

    /// Checks every entry of a shard's index (its bytes) against the
    /// shard's size.
    fn check_index(
        &self,
        path: &Path,
        index: &[u8],
        size: u64,
        ix: ShardIndex,
    ) -> Result<(), StorageError> {
        let bad = |msg: String| self.refuse(IoError::decode(path, "OME-Zarr", msg));
        let len = index.len() as u64;
        let start = if ix.at_end { size - len } else { 0 };
        // the data lies outside the index
        let (lo, hi) = if ix.at_end { (0, start) } else { (len, size) };
        for (k, e) in index[..(len - ix.trailer) as usize]
            .chunks_exact(16)
            .enumerate()
        {
            let off = u64::from_le_bytes([e[0], e[1], e[2], e[3], e[4], e[5], e[6], e[7]]);
            let n = u64::from_le_bytes([e[8], e[9], e[10], e[11], e[12], e[13], e[14], e[15]]);
            if off == u64::MAX && n == u64::MAX {
                continue; // an empty inner chunk
            }
            if off < lo || off.checked_add(n).is_none_or(|end| end > hi) {
                return Err(bad(format!(
                    "shard index entry {k} points at {n} bytes at offset {off}, \
                     outside the shard's data (bytes {lo}..{hi})"
                )));
            }
        }
        Ok(())
    }

    /// Checks every entry of a shard's index against the shard's size.
    fn check_shard(
        &self,
        path: &Path,
        file: &mut std::fs::File,
        size: u64,
        ix: ShardIndex,
    ) -> Result<(), StorageError> {
        let len = self.index_len(path, Some(size), ix)?;
        let start = if ix.at_end { size - len } else { 0 };
        let index = read_range(file, start, len).map_err(|e| self.refuse(IoError::io(path, e)))?;
        self.check_index(path, &index, size, ix)
    }

    /// A shard's index over an [`ObjectReader`]: fetched once (at the end,
    /// a suffix range: the index and the shard's length in one request),
    /// checked, and kept; `index: None` when the shard is missing.
    fn shard_index(
        &self,
        reader: &dyn ObjectReader,
        key: &str,
        path: &Path,
        ix: ShardIndex,
    ) -> Result<Arc<Fetched>, StorageError> {
        let slot = self
            .indices
            .lock()
            .map
            .entry(key.to_owned())
            .or_default()
            .clone();
        let mut held = slot.lock();
        if let Some(f) = &*held {
            return Ok(f.clone());
        }
        let len = self.index_len(path, None, ix)?;
        let span = if ix.at_end {
            ObjectSpan::Suffix(len)
        } else {
            ObjectSpan::At { offset: 0, len }
        };
        let got = match reader.read_object(key, span) {
            Ok(g) => g,
            // a shard shorter than an index at its start
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => {
                self.index_len(path, Some(0), ix)?;
                return Err(self.refuse(IoError::io(path, e)));
            }
            Err(e) => return Err(self.refuse(IoError::io(path, e))),
        };
        let fetched = Arc::new(Fetched {
            index: match got {
                None => None,
                Some((bytes, size)) => {
                    self.index_len(path, Some(size), ix)?;
                    self.check_index(path, &bytes, size, ix)?;
                    Some((bytes, size))
                }
            },
        });
        *held = Some(fetched.clone());
        drop(held);
        let mut c = self.indices.lock();
        c.bytes += len;
        c.order.push_back((key.to_owned(), len));
        while c.bytes > INDEX_CACHE_BYTES {
            let Some((old, cost)) = c.order.pop_front() else {
                break;
            };
            c.map.remove(&old);
            c.bytes = c.bytes.saturating_sub(cost);
        }
        Ok(fetched)
    }

    /// [`ReadableStorageTraits::get_partial_many`] over an [`ObjectReader`].
    fn objects_get<'a>(
        &'a self,
        reader: &dyn ObjectReader,
        key: &StoreKey,
        byte_ranges: ByteRangeIterator<'a>,
    ) -> Result<MaybeBytesIterator<'a>, StorageError> {
        let path = self.path(key)?;
        let k = key.as_str();
        let ranges: Vec<ByteRange> = byte_ranges.collect();
        let io = |e: std::io::Error| self.refuse(IoError::io(&path, e));
        let (size, index) = if let Some(ix) = self.shard_of(k) {
            let f = self.shard_index(reader, k, &path, ix)?;
            match &f.index {
                None => return Ok(None),
                Some((index, size)) => (*size, Some((index.clone(), ix))),
            }
        } else if let ([ByteRange::FromStart(0, None)], Some(m)) =
            (ranges.as_slice(), self.meta.lock().get(k).cloned())
        {
            // metadata already read
            let Some(bytes) = m else { return Ok(None) };
            let out: Vec<Result<Bytes, StorageError>> = vec![Ok(Bytes::from(bytes))];
            return Ok(Some(Box::new(out.into_iter())));
        } else if let [ByteRange::FromStart(0, None)] = ranges.as_slice() {
            // a whole chunk or metadata object: one request
            let Some((bytes, _)) = reader.read_object(k, ObjectSpan::All).map_err(io)? else {
                return Ok(None);
            };
            let out: Vec<Result<Bytes, StorageError>> = vec![Ok(Bytes::from(bytes))];
            return Ok(Some(Box::new(out.into_iter())));
        } else {
            // ranges of an unsharded object: its length first
            match reader.read_object(k, ObjectSpan::Suffix(1)).map_err(io)? {
                None => return Ok(None),
                Some((_, size)) => (size, None),
            }
        };
        // Each range as offset..end within the object; the index itself
        // from the cache.
        let mut out: Vec<Option<Result<Bytes, StorageError>>> = Vec::with_capacity(ranges.len());
        let mut wanted = Vec::new();
        for (i, range) in ranges.iter().enumerate() {
            let (start, len) = match *range {
                ByteRange::FromStart(start, None) => (start, size.checked_sub(start)),
                ByteRange::FromStart(start, Some(len)) => (start, Some(len)),
                ByteRange::Suffix(len) => (size.saturating_sub(len), Some(len)),
            };
            let Some(len) = len.filter(|&l| start.checked_add(l).is_some_and(|end| end <= size))
            else {
                out.push(Some(Err(StorageError::from(InvalidByteRangeError::new(
                    *range, size,
                )))));
                continue;
            };
            if let Some((ixb, ix)) = &index {
                let at = if ix.at_end {
                    size - ixb.len() as u64
                } else {
                    0
                };
                if start == at && len == ixb.len() as u64 {
                    out.push(Some(Ok(Bytes::from(ixb.clone()))));
                    continue;
                }
            }
            out.push(None);
            wanted.push((i, start..start + len));
        }
        if !wanted.is_empty() {
            let rs: Vec<std::ops::Range<u64>> = wanted.iter().map(|(_, r)| r.clone()).collect();
            let Some(got) = reader.read_object_ranges(k, &rs).map_err(io)? else {
                // gone between the index and the data
                return Ok(None);
            };
            for ((i, _), b) in wanted.iter().zip(got) {
                out[*i] = Some(Ok(Bytes::from(b)));
            }
        }
        let out: Vec<Result<Bytes, StorageError>> = out
            .into_iter()
            .map(|o| o.unwrap_or_else(|| Err(StorageError::Other("a range not read".into()))))
            .collect();
        Ok(Some(Box::new(out.into_iter())))
    }

    /// The typed error behind the last refused read, if any.
    pub(crate) fn take_error(&self) -> Option<IoError> {
        self.refused.lock().take()
    }

    fn refuse(&self, e: IoError) -> StorageError {
        let msg = e.to_string();
        let mut r = self.refused.lock();
        if r.is_none() {
            *r = Some(e);
        }
        StorageError::Other(msg)
    }

    /// The file of a key: inside the folder (no `..`, no absolute path).
    fn path(&self, key: &StoreKey) -> Result<PathBuf, StorageError> {
        let k = key.as_str();
        if k.split('/')
            .any(|c| c == ".." || c == "." || c.contains('\\'))
            || k.starts_with('/')
        {
            return Err(self.refuse(IoError::header(
                &self.root,
                format!("store key {k:?} leaves the store"),
            )));
        }
        Ok(self.root.join(k))
    }

    /// The file's metadata if it exists (`None`: missing), refusing
    /// anything but a regular file.
    fn regular(&self, path: &Path) -> Result<Option<std::fs::Metadata>, StorageError> {
        match std::fs::metadata(path) {
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(e) if e.raw_os_error() == Some(20) => Ok(None), // ENOTDIR: a parent is a file
            Err(e) => Err(self.refuse(IoError::io(path, e))),
            Ok(md) => match crate::FileKind::of(md.file_type()) {
                None => Ok(Some(md)),
                Some(kind) => Err(self.refuse(IoError::NotRegularFile {
                    path: path.to_owned(),
                    kind,
                })),
            },
        }
    }
}

impl ReadableStorageTraits for SafeStore {
    fn get_partial_many<'a>(
        &'a self,
        key: &StoreKey,
        byte_ranges: ByteRangeIterator<'a>,
    ) -> Result<MaybeBytesIterator<'a>, StorageError> {
        if let Backend::Objects(r) = &self.backend {
            return self.objects_get(&**r, key, byte_ranges);
        }
        let path = self.path(key)?;
        if self.regular(&path)?.is_none() {
            return Ok(None);
        }
        let mut file = crate::open_regular(&path).map_err(|e| self.refuse(e))?;
        let size = file
            .metadata()
            .map_err(|e| self.refuse(IoError::io(&path, e)))?
            .len();
        if let Some(ix) = self.shard_of(key.as_str()) {
            self.check_shard(&path, &mut file, size, ix)?;
        }
        let mut out = Vec::new();
        for range in byte_ranges {
            let (start, len) = match range {
                ByteRange::FromStart(start, None) => (start, size.checked_sub(start)),
                ByteRange::FromStart(start, Some(len)) => (start, Some(len)),
                ByteRange::Suffix(len) => (size.saturating_sub(len), Some(len)),
            };
            let Some(len) = len.filter(|&l| start.checked_add(l).is_some_and(|end| end <= size))
            else {
                out.push(Err(StorageError::from(InvalidByteRangeError::new(
                    range, size,
                ))));
                continue;
            };
            out.push(read_range(&mut file, start, len).map_err(|e| {
                self.refuse(if e.kind() == std::io::ErrorKind::UnexpectedEof {
                    IoError::Truncated {
                        path: path.clone(),
                        expected: start + len,
                        actual: size,
                    }
                } else {
                    IoError::io(&path, e)
                })
            }));
        }
        Ok(Some(Box::new(out.into_iter())))
    }

    fn size_key(&self, key: &StoreKey) -> Result<Option<u64>, StorageError> {
        let path = self.path(key)?;
        if let Backend::Objects(r) = &self.backend {
            return Ok(r
                .read_object(key.as_str(), ObjectSpan::Suffix(1))
                .map_err(|e| self.refuse(IoError::io(&path, e)))?
                .map(|(_, len)| len));
        }
        Ok(self.regular(&path)?.map(|md| md.len()))
    }

    fn supports_get_partial(&self) -> bool {
        true
    }
}

/// `len` bytes at `start` of a file (the range lies in the file).
fn read_range(f: &mut std::fs::File, start: u64, len: u64) -> std::io::Result<Bytes> {
    use std::io::{Seek, SeekFrom};
    let len = usize::try_from(len).map_err(|_| std::io::Error::other("range too long"))?;
    f.seek(SeekFrom::Start(start))?;
    let mut buf = vec![0u8; len];
    f.read_exact(&mut buf)?;
    Ok(Bytes::from(buf))
}

// ---------------------------------------------------------------------------
// Bounded codecs.

/// Which codec a [`Bounded`] wraps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Zstd,
    Gzip,
    Blosc,
}

/// A zarrs bytes-to-bytes codec whose decoding is bounded by the decoded
/// size the chunk's geometry gives; everything else is the wrapped codec's.
#[derive(Debug)]
struct Bounded {
    kind: Kind,
    inner: Arc<dyn BytesToBytesCodecTraits>,
}

fn limit_of(decoded: &BytesRepresentation) -> u64 {
    decoded
        .size()
        .unwrap_or(MAX_CHUNK_BYTES)
        .min(MAX_CHUNK_BYTES)
}

fn too_large(what: &str, declared: u64, limit: u64) -> CodecError {
    CodecError::Other(format!(
        "{what} declares {declared} decoded bytes, the chunk holds {limit}"
    ))
}

impl Bounded {
    fn decode_zstd(encoded: &[u8], limit: u64) -> Result<Vec<u8>, CodecError> {
        // A frame that declares its content size is checked before anything
        // is allocated for it; the decoder then writes into at most `limit`
        // bytes whatever the frames say (one without a declared size too).
        if let Ok(Some(declared)) = zstd::zstd_safe::get_frame_content_size(encoded)
            && declared > limit
        {
            return Err(too_large("a zstd frame", declared, limit));
        }
        let cap = usize::try_from(limit).map_err(|_| too_large("a zstd frame", limit, limit))?;
        let mut d =
            zstd::bulk::Decompressor::new().map_err(|e| CodecError::Other(e.to_string()))?;
        d.decompress(encoded, cap)
            .map_err(|e| CodecError::Other(format!("zstd: {e} (at most {limit} bytes expected)")))
    }

    fn decode_gzip(encoded: &[u8], limit: u64) -> Result<Vec<u8>, CodecError> {
        let mut out = Vec::new();
        flate2::read::GzDecoder::new(encoded)
            .take(limit + 1)
            .read_to_end(&mut out)
            .map_err(|e| CodecError::Other(format!("gzip: {e}")))?;
        if out.len() as u64 > limit {
            return Err(CodecError::Other(format!(
                "gzip: the stream decodes to more than the chunk's {limit} bytes"
            )));
        }
        Ok(out)
    }

    /// Checks a blosc header (16 bytes: version, flags, type size, then the
    /// decoded, block and compressed sizes) before the C decoder sees it.
    fn check_blosc(encoded: &[u8], limit: u64) -> Result<(), CodecError> {
        let Some(h) = encoded.get(..16) else {
            return Err(CodecError::Other(format!(
                "blosc: {} bytes, shorter than the header",
                encoded.len()
            )));
        };
        let word = |i: usize| u32::from_le_bytes([h[i], h[i + 1], h[i + 2], h[i + 3]]) as u64;
        let (nbytes, blocksize, cbytes) = (word(4), word(8), word(12));
        if nbytes > limit {
            return Err(too_large("a blosc header", nbytes, limit));
        }
        if cbytes != encoded.len() as u64 {
            return Err(CodecError::Other(format!(
                "blosc: the header says {cbytes} compressed bytes, the chunk holds {}",
                encoded.len()
            )));
        }
        if nbytes > 0 && (blocksize == 0 || blocksize > nbytes.max(1 << 16)) {
            return Err(CodecError::Other(format!(
                "blosc: block size {blocksize} for {nbytes} bytes"
            )));
        }
        Ok(())
    }
}

impl ExtensionName for Bounded {
    fn name(&self, version: ZarrVersion) -> Option<Cow<'static, str>> {
        self.inner.name(version)
    }
}

impl CodecTraits for Bounded {
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }

    fn configuration(
        &self,
        version: ZarrVersion,
        options: &CodecMetadataOptions,
    ) -> Option<Configuration> {
        self.inner.configuration(version, options)
    }

    fn partial_decoder_capability(&self) -> PartialDecoderCapability {
        // decoded whole, through `decode` (the default partial decoder)
        let mut c = self.inner.partial_decoder_capability();
        c.partial_decode = false;
        c
    }

    fn partial_encoder_capability(&self) -> PartialEncoderCapability {
        self.inner.partial_encoder_capability()
    }
}

impl BytesToBytesCodecTraits for Bounded {
    fn into_dyn(self: Arc<Self>) -> Arc<dyn BytesToBytesCodecTraits> {
        self
    }

    fn recommended_concurrency(
        &self,
        decoded_representation: &BytesRepresentation,
    ) -> Result<RecommendedConcurrency, CodecError> {
        self.inner.recommended_concurrency(decoded_representation)
    }

    fn encoded_representation(
        &self,
        decoded_representation: &BytesRepresentation,
    ) -> BytesRepresentation {
        self.inner.encoded_representation(decoded_representation)
    }

    fn encode<'a>(
        &self,
        decoded_value: ArrayBytesRaw<'a>,
        options: &CodecOptions,
    ) -> Result<ArrayBytesRaw<'a>, CodecError> {
        self.inner.encode(decoded_value, options)
    }

    fn decode<'a>(
        &self,
        encoded_value: ArrayBytesRaw<'a>,
        decoded_representation: &BytesRepresentation,
        options: &CodecOptions,
    ) -> Result<ArrayBytesRaw<'a>, CodecError> {
        let limit = limit_of(decoded_representation);
        match self.kind {
            Kind::Zstd => Ok(Cow::Owned(Bounded::decode_zstd(&encoded_value, limit)?)),
            Kind::Gzip => Ok(Cow::Owned(Bounded::decode_gzip(&encoded_value, limit)?)),
            Kind::Blosc => {
                Bounded::check_blosc(&encoded_value, limit)?;
                self.inner
                    .decode(encoded_value, decoded_representation, options)
            }
        }
    }
}

fn wrap(kind: Kind, codec: Codec) -> Result<Codec, PluginCreateError> {
    match codec {
        Codec::BytesToBytes(inner) => Ok(Codec::BytesToBytes(Arc::new(Bounded { kind, inner }))),
        other => Ok(other),
    }
}

/// Registers the bounded codecs with zarrs (once per process).
pub(crate) fn install() {
    use zarrs::array::codec::api::{CodecRuntimePluginV3, register_codec_v3};
    use zarrs::array::codec::{BloscCodec, GzipCodec, ZstdCodec};
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        let _ = register_codec_v3(CodecRuntimePluginV3::new(
            |name: &str| name == "zstd",
            |m: &MetadataV3| wrap(Kind::Zstd, <ZstdCodec as CodecTraitsV3>::create(m)?),
        ));
        let _ = register_codec_v3(CodecRuntimePluginV3::new(
            |name: &str| name == "gzip",
            |m: &MetadataV3| wrap(Kind::Gzip, <GzipCodec as CodecTraitsV3>::create(m)?),
        ));
        let _ = register_codec_v3(CodecRuntimePluginV3::new(
            |name: &str| name == "blosc",
            |m: &MetadataV3| wrap(Kind::Blosc, <BloscCodec as CodecTraitsV3>::create(m)?),
        ));
    });
}
