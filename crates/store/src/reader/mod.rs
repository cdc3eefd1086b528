//! The store reader: validated open, thread-safe positional brick reads.

use crate::Filter;
use crate::error::{Mismatch, StoreError};
use crate::errsec;
use crate::format::{
    Entry, FLAG_THRESHOLD, HEADER_LEN, KIND_DATA, KIND_EMPTY, KIND_UNIFORM, SpreadEntry,
    TableGeometry, payload_crc,
};
use crate::opening;
use crate::sample::{fill, first_nan, stats_dyn};
use brickray_core::{
    BrickError, BrickSource, CancelToken, NodeError, NodeInfo, NodeKey, NodeKind, OctreeLayout,
    RangeRead, RangeReader, VolumeDesc,
};
use brickray_io::{FileKind, Placement};
use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::{Arc, RwLock};

/// Opens a store file, validating its header and node table.
pub fn open(path: impl AsRef<Path>) -> Result<Store, StoreError> {
    Store::open(path)
}

/// An open brick store. Reads are positional (`pread`), so any number of threads
/// may read bricks concurrently (they share the file behind a read lock, taken
/// only to clone a handle).
///
/// A store opened from a path ([`Store::open`]) survives its file being
/// replaced: when a payload read fails (an I/O error, or a checksum that does
/// not match, as on a file truncated, deleted and restored), it reopens its
/// path once and, if the file there is the same store (the same length and
/// header bytes, so the same table and section checksums), reads from it
/// instead; a different file is never read, the read fails.
#[derive(Debug)]
pub struct Store {
    path: PathBuf,
    file: RwLock<Arc<dyn RangeReader>>,
    /// The header's bytes as opened (what a reopened file must hold).
    header: [u8; HEADER_LEN],
    /// Reopen `path` after a failed read (stores opened from a path).
    reopen: bool,
    layout: OctreeLayout,
    geo: TableGeometry,
    entries: Vec<Entry>,
    filter: Filter,
    empty_below: Option<f32>,
    data_range: [f32; 2],
    file_len: u64,
    payload_bytes: u64,
    /// Per table entry (format version 2 with the error section).
    errors: Option<Vec<NodeError>>,
    /// The parent-error section (format version 3), table order.
    parent_errors: Option<Vec<NodeError>>,
    /// The spread table (format version 7), table order.
    spread: Option<Vec<SpreadEntry>>,
    /// The placement record (format version 6).
    placement: Option<Placement>,
    version: u32,
}

/// One node's table record.
#[derive(Debug, Clone, PartialEq)]
pub struct NodeRecord {
    /// The node.
    pub key: NodeKey,
    /// Its metadata.
    pub info: NodeInfo,
    /// Compressed payload bytes (0 for empty and uniform nodes).
    pub payload_len: u32,
}

/// Counts over a store's node table.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StoreStats {
    /// Per level: (nodes in the table, data, uniform, empty).
    pub per_level: Vec<[u64; 4]>,
    /// Nodes with a payload.
    pub data: u64,
    /// Uniform nodes.
    pub uniform: u64,
    /// Empty nodes (in the table).
    pub empty: u64,
    /// Bytes of payload referenced by the table.
    pub payload_bytes: u64,
    /// Uncompressed bytes of the bricks with a payload.
    pub raw_payload_bytes: u64,
}

pub(crate) fn bad(path: &Path, field: &'static str, reason: impl Into<String>) -> StoreError {
    StoreError::BadHeader {
        path: path.to_owned(),
        field,
        reason: reason.into(),
    }
}

/// Largest lz4 block a brick of `n` bytes can compress to.
pub(crate) fn max_compressed(n: usize) -> u64 {
    lz4_flex::block::get_maximum_output_size(n) as u64
}

impl Store {
    /// Opens a store file (see [`open`]). A path that is not a regular file (a
    /// FIFO, a device, a directory) is refused from its metadata, before it is
    /// opened: opening a FIFO would block. A path named as a build's temporary
    /// (`.<name>.brickray-partial.<pid>-<seq>`, or a link to one) is refused
    /// by its name ([`StoreError::PartialBuild`]): a build in progress or
    /// killed, whatever it holds.
    pub fn open(path: impl AsRef<Path>) -> Result<Store, StoreError> {
        let path = path.as_ref();
        let temporary = |p: &Path| {
            p.file_name()
                .is_some_and(|n| crate::partial::temporary_pid(n).is_some())
        };
        if temporary(path) || std::fs::canonicalize(path).is_ok_and(|c| temporary(&c)) {
            return Err(StoreError::PartialBuild {
                path: path.to_owned(),
            });
        }
        let md = std::fs::metadata(path).map_err(|e| StoreError::io(path, e))?;
        if let Some(kind) = FileKind::of(md.file_type()) {
            return Err(StoreError::NotRegularFile {
                path: path.to_owned(),
                kind,
            });
        }
        let file = File::open(path).map_err(|e| StoreError::io(path, e))?;
        let mut store = Store::from_file(file, path)?;
        store.reopen = true;
        Ok(store)
    }

    /// Opens a store from an open file; `path` names it in errors. The file must
    /// be a regular file.
    pub fn from_file(file: File, path: &Path) -> Result<Store, StoreError> {
        let md = file.metadata().map_err(|e| StoreError::io(path, e))?;
        if let Some(kind) = FileKind::of(md.file_type()) {
            return Err(StoreError::NotRegularFile {
                path: path.to_owned(),
                kind,
            });
        }
        Store::from_reader(Box::new(file), md.len(), path)
    }

    /// Opens a store from any range reader (a local file, bytes in memory,
    /// or a range reader over object storage or HTTP); `name` names it in
    /// errors (a path or a URL). Takes the reader's length, then validates
    /// the header, the sections' extents against the length, the node
    /// table, the error sections and the placement record, in that order.
    /// Two reads: the header, then the metadata after the payload in one
    /// range.
    pub fn open_with(
        reader: impl RangeReader + 'static,
        name: impl Into<PathBuf>,
    ) -> Result<Store, StoreError> {
        let name = name.into();
        let len = reader.len().map_err(|e| StoreError::io(&name, e))?;
        Store::from_reader(Box::new(reader), len, &name)
    }

    /// Opens a store from any range reader of `len` bytes; `path` names it in
    /// errors. Validates the header, the sections' extents against `len`, the
    /// node table, the error sections and the placement record, in that order.
    pub fn from_reader(
        file: Box<dyn RangeReader>,
        len: u64,
        path: &Path,
    ) -> Result<Store, StoreError> {
        let (h, header) = opening::header(file.as_ref(), path, len)?;
        let (layout, filter) = opening::layout(&h, path)?;
        let geo =
            TableGeometry::new(&layout).ok_or_else(|| bad(path, "dims", "node count overflows"))?;
        let sec = opening::Sections::of(&h, &geo, path, len)?;
        let tail = opening::tail(file.as_ref(), path, &h, len)?;
        let entries = opening::table(&tail, path, &h, &geo, &layout)?;
        opening::ranges(path, &h, &geo, &layout, &entries)?;
        // The value payloads tile theirs (up to the spread payloads, or the
        // table without them).
        let spans = entries
            .iter()
            .filter(|e| e.kind == KIND_DATA)
            .map(|e| (e.offset, e.len as u64, e.key()));
        opening::check_tiling(path, spans, HEADER_LEN as u64, sec.values_end)?;
        // The sections as offsets into the tail (phase 3 checked that they
        // follow each other to its end).
        let at = |o: u64| (o - h.table_offset) as usize;
        let errors = if sec.errors_len > 0 {
            let b = &tail[at(sec.table_end)..at(sec.errors_end)];
            Some(errsec::read(b, path, &h, &geo)?)
        } else {
            None
        };
        let parent_errors = if sec.parent_len > 0 {
            let b = &tail[at(sec.errors_end)..at(sec.parent_end)];
            Some(errsec::read_parent(b, path, &geo)?)
        } else {
            None
        };
        let spread = if sec.spread_len > 0 {
            let b = &tail[at(sec.parent_end)..at(sec.spread_end)];
            Some(opening::spread_table(b, path, &h, &sec, &geo, &layout)?)
        } else {
            None
        };
        let placement = if sec.placement_len > 0 {
            Some(crate::placement::decode(&tail[at(sec.spread_end)..], path)?)
        } else {
            None
        };
        Ok(Store {
            errors,
            parent_errors,
            spread,
            placement,
            version: h.version,
            path: path.to_owned(),
            file: RwLock::new(Arc::from(file)),
            header,
            reopen: false,
            layout,
            geo,
            entries,
            filter,
            empty_below: (h.flags & FLAG_THRESHOLD != 0).then_some(h.empty_below),
            data_range: h.data_range,
            file_len: len,
            payload_bytes: h.payload_bytes,
        })
    }

    /// The file's format version (1 to [`VERSION`](crate::format::VERSION)).
    pub fn version(&self) -> u32 {
        self.version
    }

    /// Where the volume lies in the world, as the file the store was built
    /// from said ([`brickray_io::VolumeReader::placement`]: NIfTI's
    /// qform/sform, DICOM's patient position and orientation, OME-Zarr's
    /// transformations), bit for bit. `None` for a store built from an input
    /// that does not say, and for every store before format version 6. Read
    /// at open with the rest of the metadata (no request of its own).
    pub fn placement(&self) -> Option<Placement> {
        self.placement
    }

    /// Whether the store records per-node error bounds (`NodeInfo::error`).
    pub fn has_errors(&self) -> bool {
        self.errors.is_some()
    }

    /// Whether the store records each coarse voxel's spread (format version
    /// 7, built with [`BuildOptions::spread`](crate::BuildOptions::spread)):
    /// [`read_spread`](Self::read_spread) returns them. False for every store
    /// before version 7 and for builds without the option.
    pub fn has_spread(&self) -> bool {
        self.spread.is_some()
    }

    /// Bytes of the spread payloads (0 without spreads).
    pub fn spread_bytes(&self) -> u64 {
        self.spread
            .as_ref()
            .map_or(0, |s| s.iter().map(|e| e.len as u64).sum())
    }

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

    /// The file's path (or the name it was opened with: a URL for a remote
    /// store).
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The octree geometry.
    pub fn layout(&self) -> &OctreeLayout {
        &self.layout
    }

    /// The volume's description.
    pub fn desc(&self) -> &VolumeDesc {
        &self.layout.volume
    }

    /// Number of levels.
    pub fn levels(&self) -> u8 {
        self.layout.levels
    }

    /// The filter the inner nodes were built with.
    pub fn filter(&self) -> Filter {
        self.filter
    }

    /// The empty threshold the store was built with.
    pub fn empty_below(&self) -> Option<f32> {
        self.empty_below
    }

    /// Smallest and largest voxel of the volume.
    pub fn data_range(&self) -> [f32; 2] {
        self.data_range
    }

    /// Size of the file in bytes.
    pub fn file_len(&self) -> u64 {
        self.file_len
    }

    /// Bytes of the value payloads (the payload section; in a store with
    /// spreads the spread payloads follow them: [`spread_bytes`](Self::spread_bytes)).
    pub fn payload_bytes(&self) -> u64 {
        self.payload_bytes
    }

    /// Bricks per axis at `level` (nodes outside this grid are wholly outside the volume).
    pub fn grid(&self, level: u8) -> Option<[u32; 3]> {
        self.geo.grid.get(level as usize).copied()
    }

    fn check_key(&self, key: NodeKey) -> Result<Option<&Entry>, StoreError> {
        if key.level >= self.layout.levels {
            return Err(StoreError::OutOfRange { key });
        }
        let n = self.layout.nodes_per_axis(key.level);
        if [key.x, key.y, key.z]
            .iter()
            .zip(n)
            .any(|(&p, n)| p as u64 >= n)
        {
            return Err(StoreError::OutOfRange { key });
        }
        Ok(self.geo.index(key).and_then(|i| self.entries.get(i)))
    }

    fn info_of(&self, e: Option<&Entry>) -> NodeInfo {
        let error = e.and_then(|e| {
            let i = self.geo.index(e.key())?;
            self.errors.as_ref()?.get(i).copied()
        });
        let parent_error = e.filter(|e| e.key().level > 0).and_then(|e| {
            let i = self.geo.index(e.key())?;
            self.parent_errors.as_ref()?.get(i).copied()
        });
        match e {
            None => NodeInfo {
                kind: NodeKind::Empty,
                min: self.data_range[0],
                max: self.data_range[0],
                error: None,
                parent_error: None,
                channels: Default::default(),
                channel_errors: None,
            },
            Some(e) => NodeInfo {
                kind: match e.kind {
                    KIND_DATA => NodeKind::Data,
                    KIND_UNIFORM => NodeKind::Uniform(e.value),
                    _ => NodeKind::Empty,
                },
                min: e.min,
                max: e.max,
                error,
                parent_error,
                channels: Default::default(),
                channel_errors: None,
            },
        }
    }

    /// Metadata of a node: `Empty` for nodes wholly outside the volume.
    pub fn info(&self, key: NodeKey) -> Result<NodeInfo, StoreError> {
        Ok(self.info_of(self.check_key(key)?))
    }

    /// The node's table record.
    pub fn record(&self, key: NodeKey) -> Result<NodeRecord, StoreError> {
        let e = self.check_key(key)?;
        Ok(NodeRecord {
            key,
            info: self.info_of(e),
            payload_len: e.map_or(0, |e| e.len),
        })
    }

    /// The children of `key` that overlap the volume, with their metadata
    /// (empty for leaves).
    pub fn children(&self, key: NodeKey) -> Result<Vec<NodeRecord>, StoreError> {
        self.check_key(key)?;
        if key.level + 1 >= self.layout.levels {
            return Ok(Vec::new());
        }
        self.layout
            .children(key)
            .iter()
            .copied()
            .filter(|c| self.geo.index(*c).is_some())
            .map(|c| self.record(c))
            .collect()
    }

    /// Every node in the table (all nodes that overlap the volume), coarse to fine.
    pub fn nodes(&self) -> impl Iterator<Item = NodeRecord> + '_ {
        self.entries.iter().map(|e| NodeRecord {
            key: e.key(),
            info: self.info_of(Some(e)),
            payload_len: e.len,
        })
    }

    /// Counts over the node table.
    pub fn stats(&self) -> StoreStats {
        let mut s = StoreStats {
            per_level: vec![[0; 4]; self.layout.levels as usize],
            ..Default::default()
        };
        let bb = self.layout.brick_bytes() as u64;
        for e in &self.entries {
            let pl = &mut s.per_level[e.level as usize];
            pl[0] += 1;
            match e.kind {
                KIND_DATA => {
                    pl[1] += 1;
                    s.data += 1;
                    s.payload_bytes += e.len as u64;
                    s.raw_payload_bytes += bb;
                }
                KIND_UNIFORM => {
                    pl[2] += 1;
                    s.uniform += 1;
                }
                _ => {
                    pl[3] += 1;
                    s.empty += 1;
                }
            }
        }
        s
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
