//! The disk cache of an OME-Zarr image read over the network
//! ([`DiskCachedObjects`]): what [`DiskCached`](crate::DiskCached) is to a
//! store's one object, for a folder of objects read by key.
//!
//! * **Entries** live in the image's folder under the cache's root, named by
//!   a hash of the key and the span read (the whole object, a range, or a
//!   suffix: a shard's index; the ranges read together, each by its own),
//!   each ending in its CRC-32 like a store's; a
//!   key that does not exist (a chunk never written: the fill value) is
//!   cached as absent, so a second visit does not ask again.
//! * **Metadata is never cached**: `zarr.json`, `.zattrs`, `.zarray`,
//!   `.zgroup` and `.zmetadata` are always fetched, so opening reads the
//!   image's current description.
//! * **Identity**: the image's URL and a hash of its root metadata
//!   ([`DiskCachedObjects::for_image`]): an image whose metadata changes
//!   starts a new folder and the old one ages out. Chunks rewritten in place
//!   under unchanged metadata are not detected (object stores give chunks no
//!   version an open could check without a request per chunk; a sharded
//!   array's crc32c index codec, where present, still checks the index).
//! * Bounded, validated and shared by processes as the store's cache is
//!   (crate::DiskCached's module documentation).

use crate::disk_cache::{Entries, fnv1a};
use crate::{DiskCacheConfig, DiskCacheStats};
use brickray_core::{ObjectReader, ObjectSpan};
use std::io;
use std::ops::Range;
use std::path::Path;

/// Keys that describe an image rather than hold its samples: never cached.
const METADATA: [&str; 5] = ["zarr.json", ".zattrs", ".zarray", ".zgroup", ".zmetadata"];

fn is_metadata(key: &str) -> bool {
    let name = key.rsplit('/').next().unwrap_or(key);
    METADATA.contains(&name)
}

/// An [`ObjectReader`] that keeps what `inner` fetched on the local disk
/// (see the module's documentation).
#[derive(Debug)]
pub struct DiskCachedObjects<O> {
    inner: O,
    entries: Entries,
}

/// An entry's name: the key's hash and the span.
fn entry_name(key: &str, span: ObjectSpan) -> String {
    let k = fnv1a(key.as_bytes());
    match span {
        ObjectSpan::All => format!("o{k:016x}-all"),
        ObjectSpan::At { offset, len } => format!("o{k:016x}-{offset}-{len}"),
        ObjectSpan::Suffix(n) => format!("o{k:016x}-suffix{n}"),
    }
}

/// A cached answer of `read_object`: absent (`0`), or present (`1`), the
/// object's length (u64 LE) and the bytes.
fn encode(answer: &Option<(Vec<u8>, u64)>) -> Vec<u8> {
    match answer {
        None => vec![0],
        Some((bytes, len)) => {
            let mut v = Vec::with_capacity(9 + bytes.len());
            v.push(1);
            v.extend_from_slice(&len.to_le_bytes());
            v.extend_from_slice(bytes);
            v
        }
    }
}

/// The answer an entry holds, or `None` when it is not one.
fn decode(mut v: Vec<u8>) -> Option<Option<(Vec<u8>, u64)>> {
    match v.first()? {
        0 if v.len() == 1 => Some(None),
        1 if v.len() >= 9 => {
            let len = u64::from_le_bytes(v[1..9].try_into().ok()?);
            v.drain(..9);
            Some(Some((v, len)))
        }
        _ => None,
    }
}

impl<O: ObjectReader> DiskCachedObjects<O> {
    /// Caches `inner`, the image named by `identity` (what changes when the
    /// image does), under `config.dir`.
    pub fn new(inner: O, identity: &str, config: &DiskCacheConfig) -> io::Result<Self> {
        Ok(DiskCachedObjects {
            inner,
            entries: Entries::new(identity, config)?,
        })
    }

    /// Caches the OME-Zarr image `inner` reads: its identity is its
    /// location and a hash of its root metadata (`zarr.json`, or for zarr
    /// v2 `.zattrs` and `.zgroup`), fetched here: one small request for a
    /// v3 image, three for a v2 one.
    pub fn for_image(inner: O, config: &DiskCacheConfig) -> io::Result<Self> {
        let mut identity = inner.location().to_string();
        for key in ["zarr.json", ".zattrs", ".zgroup"] {
            if let Some((bytes, _)) = inner.read_object(key, ObjectSpan::All)? {
                identity += &format!("\n{key} {:016x}", fnv1a(&bytes));
                if key == "zarr.json" {
                    // A v3 image: its root metadata is this one document.
                    break;
                }
            }
        }
        DiskCachedObjects::new(inner, &identity, config)
    }

    /// The reader it caches.
    pub fn inner(&self) -> &O {
        &self.inner
    }

    /// Hits, misses and corrupt entries so far.
    pub fn stats(&self) -> DiskCacheStats {
        self.entries.stats()
    }

    /// The image's folder.
    pub fn dir(&self) -> &Path {
        self.entries.dir()
    }
}

impl<O: ObjectReader> ObjectReader for DiskCachedObjects<O> {
    fn location(&self) -> &str {
        self.inner.location()
    }

    fn read_object(&self, key: &str, span: ObjectSpan) -> io::Result<Option<(Vec<u8>, u64)>> {
        if is_metadata(key) {
            return self.inner.read_object(key, span);
        }
        let name = entry_name(key, span);
        if let Some(answer) = self.entries.load(&name, None).and_then(decode) {
            return Ok(answer);
        }
        let answer = self.inner.read_object(key, span)?;
        self.entries.save(&name, &encode(&answer));
        Ok(answer)
    }

    fn read_object_ranges(
        &self,
        key: &str,
        ranges: &[Range<u64>],
    ) -> io::Result<Option<Vec<Vec<u8>>>> {
        if is_metadata(key) {
            return self.inner.read_object_ranges(key, ranges);
        }
        let k = fnv1a(key.as_bytes());
        let name = |r: &Range<u64>| format!("r{k:016x}-{}-{}", r.start, r.end);
        let mut out: Vec<Option<Vec<u8>>> = ranges
            .iter()
            .map(|r| {
                let want = usize::try_from(r.end.saturating_sub(r.start)).ok()?;
                self.entries.load(&name(r), Some(want))
            })
            .collect();
        let missed: Vec<usize> = (0..ranges.len()).filter(|&i| out[i].is_none()).collect();
        if !missed.is_empty() {
            let wanted: Vec<Range<u64>> = missed.iter().map(|&i| ranges[i].clone()).collect();
            let Some(fetched) = self.inner.read_object_ranges(key, &wanted)? else {
                return Ok(None);
            };
            for (&i, bytes) in missed.iter().zip(fetched) {
                self.entries.save(&name(&ranges[i]), &bytes);
                out[i] = Some(bytes);
            }
        }
        Ok(Some(
            out.into_iter().map(|b| b.unwrap_or_default()).collect(),
        ))
    }
}

#[cfg(test)]
mod tests;
