//! Reading a store's payloads: value bricks one by one and in batches
//! (coalesced ranges), spread bricks, decoding and checking them against
//! the node table, reopening the file after a failed read; and the store as
//! a [`BrickSource`].

use super::Store;
use crate::error::{Mismatch, StoreError};
use crate::format::HEADER_LEN;
use crate::format::{KIND_DATA, KIND_EMPTY, KIND_UNIFORM, SpreadEntry, payload_crc};
use crate::sample::{fill, first_nan, stats_dyn};
use brickray_core::{
    BrickError, BrickSource, CancelToken, NodeInfo, NodeKey, OctreeLayout, RangeRead, RangeReader,
};
use brickray_io::FileKind;
use std::fs::File;
use std::sync::Arc;

impl Store {
    /// Writes node `key`'s spread per stored voxel into `out`
    /// (`stored_side^3` half-float bits, x fastest, apron included, laid out
    /// as [`read`](Self::read)'s samples): the standard deviation of the
    /// normalized values of the finest voxels each voxel stands for
    /// ([`BrickSource::read_spread`]). Zeros at the finest level, for a node
    /// wholly outside the volume, for a node whose spreads are all 0 and in a
    /// store without spreads. The payload's checksum is verified
    /// ([`StoreError::PayloadChecksum`]), its decoded size
    /// ([`StoreError::Decode`]) and every spread a non-negative half float
    /// that is not NaN ([`StoreError::Decode`]). A failed read reopens the
    /// store's path as [`read`](Self::read) does.
    pub fn read_spread(&self, key: NodeKey, out: &mut [u16]) -> Result<(), StoreError> {
        let n = (self.layout.stored_side() as usize).pow(3);
        if out.len() != n {
            return Err(StoreError::BufferSize {
                expected: n * 2,
                actual: out.len() * 2,
            });
        }
        let e = self.check_key(key)?;
        let entry = match (&self.spread, e.and_then(|e| self.geo.index(e.key()))) {
            (Some(table), Some(i)) => table.get(i).copied().unwrap_or_default(),
            _ => SpreadEntry::default(),
        };
        if entry.len == 0 {
            out.fill(0);
            return Ok(());
        }
        // `len` was bounded by the lz4 bound of one spread brick at open.
        let mut payload = vec![0u8; entry.len as usize];
        let file = self.file();
        match self.read_payload(file.as_ref(), key, entry.offset, entry.crc, &mut payload) {
            Err(_) if self.reopened(&file) => self.read_payload(
                self.file().as_ref(),
                key,
                entry.offset,
                entry.crc,
                &mut payload,
            )?,
            r => r?,
        }
        let mut raw = vec![0u8; n * 2];
        decode_payload(key, &payload, &mut raw)?;
        for (o, b) in out.iter_mut().zip(raw.chunks_exact(2)) {
            let bits = u16::from_le_bytes([b[0], b[1]]);
            // A spread is >= 0 (sign bit clear) and never NaN (exponent all
            // ones with a non-zero mantissa); infinity is a spread past the
            // half floats' range.
            if bits > 0x7c00 {
                return Err(StoreError::Decode {
                    key,
                    reason: format!("spread bits {bits:#06x} are not a spread"),
                });
            }
            *o = bits;
        }
        Ok(())
    }

    /// The node's compressed payload (checksum verified), `None` for nodes without one.
    pub fn read_compressed(&self, key: NodeKey) -> Result<Option<Vec<u8>>, StoreError> {
        let Some(e) = self.check_key(key)? else {
            return Ok(None);
        };
        if e.kind != KIND_DATA {
            return Ok(None);
        }
        // `len` was bounded by the brick size and the file at open.
        let mut buf = vec![0u8; e.len as usize];
        let file = self.file();
        match self.read_payload(file.as_ref(), key, e.offset, e.crc, &mut buf) {
            // Read again from the file reopened at the store's path.
            Err(_) if self.reopened(&file) => {
                self.read_payload(self.file().as_ref(), key, e.offset, e.crc, &mut buf)?
            }
            r => r?,
        }
        Ok(Some(buf))
    }

    /// The compressed payloads of several nodes (checksums verified), `None`
    /// for nodes without one, in the order of `keys`: one
    /// [`RangeReader::read_ranges`] call, which a reader over the network
    /// turns into few requests (neighbouring payloads coalesced). A batch
    /// that fails is read again node by node (so a store opened from a path
    /// reopens it as [`read_compressed`](Self::read_compressed) does), and
    /// the first error is returned.
    pub fn read_compressed_many(
        &self,
        keys: &[NodeKey],
    ) -> Result<Vec<Option<Vec<u8>>>, StoreError> {
        self.read_compressed_batch(keys, None)
    }

    /// [`read_compressed_many`](Self::read_compressed_many), given up with
    /// [`StoreError::Cancelled`] (no node-by-node retry) when `cancel` is
    /// cancelled before the payloads arrive.
    fn read_compressed_batch(
        &self,
        keys: &[NodeKey],
        cancel: Option<&CancelToken>,
    ) -> Result<Vec<Option<Vec<u8>>>, StoreError> {
        let mut entries = Vec::with_capacity(keys.len());
        for &key in keys {
            entries.push(self.check_key(key)?.filter(|e| e.kind == KIND_DATA));
        }
        // `len` was bounded by the brick size and the file at open.
        let mut out: Vec<Option<Vec<u8>>> = entries
            .iter()
            .map(|e| e.map(|e| vec![0u8; e.len as usize]))
            .collect();
        let file = self.file();
        let batch = {
            let mut reads: Vec<RangeRead<'_>> = entries
                .iter()
                .zip(out.iter_mut())
                .filter_map(|(e, b)| {
                    Some(RangeRead {
                        offset: e.as_ref()?.offset,
                        buf: b.as_mut()?,
                    })
                })
                .collect();
            match cancel {
                Some(c) => file.read_ranges_cancellable(&mut reads, c),
                None => file.read_ranges(&mut reads),
            }
        };
        if batch.is_err() && cancel.is_some_and(CancelToken::is_cancelled) {
            return Err(StoreError::Cancelled);
        }
        let checked = batch.is_ok()
            && keys
                .iter()
                .zip(&entries)
                .zip(&out)
                .all(|((&key, e), b)| match (e, b) {
                    (Some(e), Some(b)) => payload_crc(self.version, key, b) == e.crc,
                    _ => true,
                });
        if !checked {
            return keys.iter().map(|&k| self.read_compressed(k)).collect();
        }
        Ok(out)
    }

    /// The file reads go to.
    fn file(&self) -> Arc<dyn RangeReader> {
        self.file.read().unwrap_or_else(|p| p.into_inner()).clone()
    }

    /// Reads `key`'s payload (a value or a spread payload) at `offset` into
    /// `buf` from `file` and checks it against its checksum `crc`.
    fn read_payload(
        &self,
        file: &dyn RangeReader,
        key: NodeKey,
        offset: u64,
        crc: u32,
        buf: &mut [u8],
    ) -> Result<(), StoreError> {
        file.read_exact_at(buf, offset)
            .map_err(|source| StoreError::NodeIo { key, source })?;
        let computed = payload_crc(self.version, key, buf);
        if computed != crc {
            return Err(StoreError::PayloadChecksum {
                key,
                stored: crc,
                computed,
            });
        }
        Ok(())
    }

    /// After a read from `failed` failed: reopens the store's path when it
    /// was opened from one and the file there is this store (its length and
    /// header bytes), and reads go to it from then on. True when reads go to
    /// another file than `failed` now (reopened here or by another thread).
    fn reopened(&self, failed: &Arc<dyn RangeReader>) -> bool {
        if !self.reopen {
            return false;
        }
        let mut current = self.file.write().unwrap_or_else(|p| p.into_inner());
        if !Arc::ptr_eq(&current, failed) {
            return true;
        }
        let same = || -> Option<File> {
            // Never open a FIFO or a device (opening a FIFO blocks).
            let md = std::fs::metadata(&self.path).ok()?;
            if FileKind::of(md.file_type()).is_some() || md.len() != self.file_len {
                return None;
            }
            let f = File::open(&self.path).ok()?;
            let mut hb = [0u8; HEADER_LEN];
            RangeReader::read_exact_at(&f, &mut hb, 0).ok()?;
            (hb == self.header && f.metadata().ok()?.len() == self.file_len).then_some(f)
        };
        match same() {
            Some(f) => {
                *current = Arc::new(f);
                true
            }
            None => false,
        }
    }

    /// Reads the node's stored brick into `out` (`layout().brick_bytes()` bytes),
    /// verifying its checksum.
    pub fn read(&self, key: NodeKey, out: &mut [u8]) -> Result<(), StoreError> {
        let expected = self.layout.brick_bytes();
        if out.len() != expected {
            return Err(StoreError::BufferSize {
                expected,
                actual: out.len(),
            });
        }
        let e = self.check_key(key)?;
        let dtype = self.layout.dtype();
        match e {
            None => fill(dtype, self.data_range[0], out),
            Some(e) if e.kind == KIND_UNIFORM => fill(dtype, e.value, out),
            Some(e) if e.kind == KIND_EMPTY => fill(dtype, self.data_range[0], out),
            Some(_) => {
                let payload = self.read_compressed(key)?.unwrap_or_default();
                self.decode(key, &payload, out)?;
            }
        }
        Ok(())
    }

    /// Reads several nodes' bricks, each as [`read`](Self::read) does, with
    /// one result per key: the data nodes' payloads in one
    /// [`read_compressed_many`](Self::read_compressed_many) (a reader over
    /// the network coalesces neighbours); when that batch fails, each node is
    /// read on its own, so one bad node fails only itself. When `cancel` is
    /// cancelled before the payloads arrive every node fails with
    /// [`StoreError::Cancelled`].
    pub fn read_many(
        &self,
        keys: &[NodeKey],
        outs: &mut [&mut [u8]],
        cancel: &CancelToken,
    ) -> Vec<Result<(), StoreError>> {
        let data: Vec<NodeKey> = keys
            .iter()
            .copied()
            .filter(|&k| matches!(self.check_key(k), Ok(Some(e)) if e.kind == KIND_DATA))
            .collect();
        let payloads = match self.read_compressed_batch(&data, Some(cancel)) {
            Ok(p) => p,
            Err(StoreError::Cancelled) => {
                // Nodes without a payload need no read.
                return keys
                    .iter()
                    .zip(outs.iter_mut())
                    .map(|(&k, out)| {
                        if data.contains(&k) {
                            Err(StoreError::Cancelled)
                        } else {
                            self.read(k, out)
                        }
                    })
                    .collect();
            }
            Err(_) => {
                return keys
                    .iter()
                    .zip(outs.iter_mut())
                    .map(|(&k, out)| self.read(k, out))
                    .collect();
            }
        };
        let mut payloads = data.into_iter().zip(payloads);
        let mut next = payloads.next();
        keys.iter()
            .zip(outs.iter_mut())
            .map(|(&key, out)| match next.take() {
                Some((k, payload)) if k == key => {
                    next = payloads.next();
                    if out.len() != self.layout.brick_bytes() {
                        return Err(StoreError::BufferSize {
                            expected: self.layout.brick_bytes(),
                            actual: out.len(),
                        });
                    }
                    self.decode(key, &payload.unwrap_or_default(), out)
                }
                other => {
                    next = other;
                    self.read(key, out)
                }
            })
            .collect()
    }

    /// Decompresses the payload of data node `key` (from
    /// [`read_compressed`](Self::read_compressed)) into `out` and checks the
    /// brick against the node's table entry, like [`read`](Self::read): every
    /// sample within the node's `[min, max]` (NaN never is), the smallest equal
    /// to the recorded `value`, a leaf's largest equal to its `max`, and not all
    /// equal (such a node is stored as uniform). A payload that belongs to
    /// another node, or a forged one, fails with [`StoreError::BrickMismatch`]
    /// even when its checksum was recomputed. One pass over the samples, no
    /// allocation.
    pub fn decode(&self, key: NodeKey, payload: &[u8], out: &mut [u8]) -> Result<(), StoreError> {
        decode_payload(key, payload, out)?;
        let e = match self.check_key(key)? {
            Some(e) if e.kind == KIND_DATA => e,
            _ => return Ok(()),
        };
        let dtype = self.layout.dtype();
        let mismatch = |mismatch| Err(StoreError::BrickMismatch { key, mismatch });
        let (lo, hi, nan) = stats_dyn(dtype, out);
        if nan {
            return mismatch(Mismatch::NotANumber {
                index: first_nan(dtype, out).unwrap_or(0),
            });
        }
        if lo < e.min || hi > e.max {
            return mismatch(Mismatch::OutOfRange {
                min: e.min,
                max: e.max,
                found_min: lo,
                found_max: hi,
            });
        }
        if lo != e.value {
            return mismatch(Mismatch::Smallest {
                recorded: e.value,
                found: lo,
            });
        }
        if key.level + 1 == self.layout.levels && hi != e.max {
            return mismatch(Mismatch::LeafMax {
                recorded: e.max,
                found: hi,
            });
        }
        if lo == hi {
            return mismatch(Mismatch::Uniform { value: lo });
        }
        Ok(())
    }
}

/// Decompresses one lz4 brick payload into `out`, which it must fill exactly.
/// This checks the size only; [`Store::decode`] (and [`Store::read`]) also
/// check the brick against its node's table entry.
pub fn decode_payload(key: NodeKey, payload: &[u8], out: &mut [u8]) -> Result<(), StoreError> {
    match lz4_flex::block::decompress_into(payload, out) {
        Ok(n) if n == out.len() => Ok(()),
        Ok(n) => Err(StoreError::Decode {
            key,
            reason: format!("decoded {n} bytes, expected {}", out.len()),
        }),
        Err(e) => Err(StoreError::Decode {
            key,
            reason: e.to_string(),
        }),
    }
}

impl BrickSource for Store {
    fn layout(&self) -> &OctreeLayout {
        &self.layout
    }

    fn node(&self, key: NodeKey) -> Result<NodeInfo, BrickError> {
        self.info(key).map_err(|e| e.into_brick_error(key))
    }

    fn read_brick(&self, key: NodeKey, out: &mut [u8]) -> Result<(), BrickError> {
        self.read(key, out).map_err(|e| e.into_brick_error(key))
    }

    /// [`STORE_BATCH`] bricks per call over the network, 1 from a local file.
    fn batch_size(&self) -> usize {
        if self.file().is_remote() {
            STORE_BATCH
        } else {
            1
        }
    }

    fn read_bricks(
        &self,
        keys: &[NodeKey],
        outs: &mut [&mut [u8]],
        cancel: &CancelToken,
    ) -> Vec<Result<(), BrickError>> {
        self.read_many(keys, outs, cancel)
            .into_iter()
            .zip(keys)
            .map(|(r, &key)| r.map_err(|e| e.into_brick_error(key)))
            .collect()
    }

    fn has_spread(&self) -> bool {
        Store::has_spread(self)
    }

    fn read_spread(&self, key: NodeKey, out: &mut [u16]) -> Result<(), BrickError> {
        Store::read_spread(self, key, out).map_err(|e| e.into_brick_error(key))
    }
}

/// Bricks a store read over the network fetches per call
/// ([`BrickSource::batch_size`]): their payloads go out as one
/// [`RangeReader::read_ranges`], neighbours coalesced into one request, the
/// rest concurrent, so a batch costs about one round trip.
pub const STORE_BATCH: usize = 16;
