//! The store reader: validated open, thread-safe positional brick reads.

use crate::Filter;
use crate::error::StoreError;
use crate::errsec;
use crate::format::{
    Entry, FLAG_THRESHOLD, HEADER_LEN, KIND_DATA, KIND_UNIFORM, SpreadEntry, TableGeometry,
};
use crate::opening;
use brickray_core::{
    NodeError, NodeInfo, NodeKey, NodeKind, OctreeLayout, RangeReader, VolumeDesc,
};
use brickray_io::{FileKind, Placement};
use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::{Arc, RwLock};

mod payloads;
pub use payloads::{STORE_BATCH, decode_payload};

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
}
