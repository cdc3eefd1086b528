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
use parking_lot::Mutex;
use std::borrow::Cow;
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
            refused: Mutex::new(None),
            shards: Mutex::new(Vec::new()),
        }
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

    /// Checks every entry of a shard's index against the shard's size.
    fn check_shard(
        &self,
        path: &Path,
        file: &mut std::fs::File,
        size: u64,
        ix: ShardIndex,
    ) -> Result<(), StorageError> {
        let bad = |msg: String| self.refuse(IoError::decode(path, "OME-Zarr", msg));
        let len = ix
            .entries
            .checked_mul(16)
            .and_then(|l| l.checked_add(ix.trailer))
            .filter(|&l| l <= size)
            .ok_or_else(|| {
                bad(format!(
                    "a {size}-byte shard cannot hold its index of {} entries",
                    ix.entries
                ))
            })?;
        let start = if ix.at_end { size - len } else { 0 };
        let index = read_range(file, start, len).map_err(|e| self.refuse(IoError::io(path, e)))?;
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
