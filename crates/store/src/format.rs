//! On-disk layout: the header and node-table entries (see `docs/store-format.md`).

use crate::Filter;
use brickray_core::{DType, NodeKey, OctreeLayout};

/// The file's first eight bytes.
pub const MAGIC: [u8; 8] = *b"BRKSTORE";
/// The format version this crate writes (it also reads [`MIN_VERSION`]..=this).
/// Version 2 adds the optional per-node error section, version 3 the
/// parent-error section after it, version 4 binds each payload's checksum to
/// its node (`docs/store-format.md`, "Payload checksums"), version 5 adds
/// label stores (a header flag, u32 samples, the mode filter), version 6 the
/// optional placement record at the end of the file (the volume's
/// voxel-to-world affine and its space, [`brickray_io::Placement`]),
/// version 7 the optional spread section (each coarse voxel's spread, for
/// the renderers' spread model: header flag bit 6). Every build writes the
/// newest version; the flags say which optional sections it holds.
pub const VERSION: u32 = 7;
/// The first format version with the spread section ([`FLAG_SPREAD`]).
pub(crate) const SPREAD_VERSION: u32 = 7;
/// The first format version with the placement record ([`FLAG_PLACEMENT`]).
pub(crate) const PLACEMENT_VERSION: u32 = 6;
/// The first format version whose payload checksums cover the node's key.
pub(crate) const KEYED_CRC_VERSION: u32 = 4;
/// The oldest format version this crate reads (version 1: no error section).
pub const MIN_VERSION: u32 = 1;
/// Bytes of the header.
pub const HEADER_LEN: usize = 128;
/// Bytes of one node-table entry.
pub const ENTRY_LEN: usize = 48;
/// Largest accepted brick side (interior voxels).
pub const MAX_BRICK: u32 = 512;
/// Largest accepted apron width.
pub const MAX_APRON: u32 = 16;
/// Largest accepted stored brick, in bytes.
pub const MAX_BRICK_BYTES: usize = 256 << 20;

pub(crate) const KIND_EMPTY: u8 = 0;
pub(crate) const KIND_UNIFORM: u8 = 1;
pub(crate) const KIND_DATA: u8 = 2;

pub(crate) fn dtype_code(d: DType) -> u8 {
    match d {
        DType::U8 => 0,
        DType::U16 => 1,
        DType::I16 => 2,
        DType::U32 => 4,
        _ => 3,
    }
}

pub(crate) fn dtype_from_code(c: u8) -> Option<DType> {
    Some(match c {
        0 => DType::U8,
        1 => DType::U16,
        2 => DType::I16,
        3 => DType::F32,
        4 => DType::U32,
        _ => return None,
    })
}

pub(crate) fn filter_code(f: Filter) -> u8 {
    match f {
        Filter::Average => 0,
        Filter::Max => 1,
        Filter::Mode => 2,
    }
}

pub(crate) fn filter_from_code(c: u8) -> Option<Filter> {
    Some(match c {
        0 => Filter::Average,
        1 => Filter::Max,
        2 => Filter::Mode,
        _ => return None,
    })
}

/// The checksum of data node `key`'s compressed `payload` in a store of
/// format `version`: from version 4 the CRC-32 of the key (level as one byte,
/// then x, y, z as little-endian u32) followed by the payload, so a payload
/// moved to another node fails its checksum; before, the CRC-32 of the
/// payload alone.
pub(crate) fn payload_crc(version: u32, key: NodeKey, payload: &[u8]) -> u32 {
    if version < KEYED_CRC_VERSION {
        return crc32fast::hash(payload);
    }
    let mut h = crc32fast::Hasher::new();
    h.update(&[key.level]);
    for p in [key.x, key.y, key.z] {
        h.update(&p.to_le_bytes());
    }
    h.update(payload);
    h.finalize()
}

/// Decoded header fields (unvalidated).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Header {
    pub(crate) version: u32,
    pub(crate) header_len: u32,
    pub(crate) dims: [u32; 3],
    pub(crate) dtype: u8,
    pub(crate) filter: u8,
    pub(crate) flags: u8,
    pub(crate) levels: u8,
    pub(crate) brick: u32,
    pub(crate) apron: u32,
    pub(crate) spacing: [f32; 3],
    pub(crate) value_range: [f32; 2],
    pub(crate) data_range: [f32; 2],
    pub(crate) empty_below: f32,
    pub(crate) node_count: u64,
    pub(crate) table_offset: u64,
    pub(crate) table_len: u64,
    pub(crate) payload_bytes: u64,
    pub(crate) table_crc: u32,
    /// Split masks of an anisotropic pyramid, root level first (one per level
    /// but the finest; empty without [`FLAG_SPLIT_MASKS`]).
    pub(crate) split_masks: Vec<u8>,
    /// CRC-32 of the error section (version 2, flag [`FLAG_ERRORS`]; else 0).
    /// The section's length is implied: `node_count * ERROR_ENTRY_LEN`.
    pub(crate) errors_crc: u32,
}

/// Header flag (version 5, bit 4): the volume is a label map
/// ([`brickray_core::VolumeKind::Labels`]).
pub(crate) const FLAG_LABELS: u8 = 16;
/// Header flag (version 6, bit 5): the placement record ends the file
/// ([`PLACEMENT_LEN`] bytes after every other section; `crate::placement`).
pub(crate) const FLAG_PLACEMENT: u8 = 32;
/// Bytes of the placement record (format version 6): the first three rows
/// of the row-major voxel-to-world affine (12 x f64), the space code (u8),
/// three reserved zero bytes, then the CRC-32 of the record's first 100
/// bytes (see `docs/store-format.md`).
pub const PLACEMENT_LEN: usize = 104;
/// Header flag (version 7, bit 6): the store records each coarse voxel's
/// spread: the spread payloads follow the value payloads (bytes
/// `HEADER_LEN + payload_bytes .. table_offset`) and the spread table
/// ([`SPREAD_ENTRY_LEN`] bytes per node-table entry, then its CRC-32)
/// follows the parent-error section (see `docs/store-format.md`).
pub(crate) const FLAG_SPREAD: u8 = 64;
/// Bytes of one spread-table entry (format version 7): the payload's offset
/// (u64), its length (u32) and its checksum (u32); all zero for a node whose
/// spreads are all 0 (every finest-level node).
pub const SPREAD_ENTRY_LEN: usize = 16;
/// Header flag: the empty threshold is set.
pub(crate) const FLAG_THRESHOLD: u8 = 1;
/// Header flag: the octree is an anisotropic pyramid whose split masks are
/// packed at [`SPLIT_MASKS_AT`] (3 bits per level, root level in the lowest
/// bits). Without it every level halves all axes.
pub(crate) const FLAG_SPLIT_MASKS: u8 = 2;
/// Offset and length of the packed split masks in the header (reserved bytes).
pub(crate) const SPLIT_MASKS_AT: std::ops::Range<usize> = 108..120;
/// Most split masks the header holds (`12 * 8 / 3`).
pub(crate) const MAX_SPLIT_MASKS: usize = 32;

/// Packs split masks into `SPLIT_MASKS_AT` (the caller checks the count).
fn pack_masks(masks: &[u8]) -> u128 {
    masks
        .iter()
        .take(MAX_SPLIT_MASKS)
        .enumerate()
        .fold(0u128, |p, (l, m)| p | (((*m & 7) as u128) << (3 * l)))
}

/// The packed bits of `SPLIT_MASKS_AT`.
pub(crate) fn packed_masks(b: &[u8]) -> u128 {
    let mut a = [0u8; 16];
    a[..12].copy_from_slice(&b[SPLIT_MASKS_AT]);
    u128::from_le_bytes(a)
}
/// Header flag (version 2, bit 2): the error section follows the node table.
pub(crate) const FLAG_ERRORS: u8 = 4;
/// Where the error section's CRC is in the header (version 2).
pub(crate) const ERRORS_CRC_AT: std::ops::Range<usize> = 120..124;
/// Header flag (version 3, bit 3, only with [`FLAG_ERRORS`]): the
/// parent-error section follows the error section: one entry per node of
/// the same layout (the error of drawing the node's region from its
/// parent's brick), then the CRC-32 of those entries.
pub(crate) const FLAG_PARENT_ERRORS: u8 = 8;

fn u32_at(b: &[u8], o: usize) -> u32 {
    u32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]])
}
fn f32_at(b: &[u8], o: usize) -> f32 {
    f32::from_bits(u32_at(b, o))
}
fn u64_at(b: &[u8], o: usize) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[o..o + 8]);
    u64::from_le_bytes(a)
}

impl Header {
    /// Encodes the header, checksum included.
    pub(crate) fn encode(&self) -> [u8; HEADER_LEN] {
        let mut b = [0u8; HEADER_LEN];
        b[0..8].copy_from_slice(&MAGIC);
        b[8..12].copy_from_slice(&self.version.to_le_bytes());
        b[12..16].copy_from_slice(&self.header_len.to_le_bytes());
        for a in 0..3 {
            b[16 + 4 * a..20 + 4 * a].copy_from_slice(&self.dims[a].to_le_bytes());
        }
        b[28] = self.dtype;
        b[29] = self.filter;
        b[30] = self.flags;
        b[31] = self.levels;
        b[32..36].copy_from_slice(&self.brick.to_le_bytes());
        b[36..40].copy_from_slice(&self.apron.to_le_bytes());
        for a in 0..3 {
            b[40 + 4 * a..44 + 4 * a].copy_from_slice(&self.spacing[a].to_le_bytes());
        }
        b[52..56].copy_from_slice(&self.value_range[0].to_le_bytes());
        b[56..60].copy_from_slice(&self.value_range[1].to_le_bytes());
        b[60..64].copy_from_slice(&self.data_range[0].to_le_bytes());
        b[64..68].copy_from_slice(&self.data_range[1].to_le_bytes());
        b[68..72].copy_from_slice(&self.empty_below.to_le_bytes());
        b[72..80].copy_from_slice(&self.node_count.to_le_bytes());
        b[80..88].copy_from_slice(&self.table_offset.to_le_bytes());
        b[88..96].copy_from_slice(&self.table_len.to_le_bytes());
        b[96..104].copy_from_slice(&self.payload_bytes.to_le_bytes());
        b[104..108].copy_from_slice(&self.table_crc.to_le_bytes());
        if self.flags & FLAG_SPLIT_MASKS != 0 {
            b[SPLIT_MASKS_AT].copy_from_slice(&pack_masks(&self.split_masks).to_le_bytes()[..12]);
        }
        b[ERRORS_CRC_AT].copy_from_slice(&self.errors_crc.to_le_bytes());
        let crc = crc32fast::hash(&b[..124]);
        b[124..128].copy_from_slice(&crc.to_le_bytes());
        b
    }

    /// Decodes the fields of `b` (at least `HEADER_LEN` bytes); magic and checksum
    /// are checked by the caller.
    pub(crate) fn decode(b: &[u8]) -> Header {
        Header {
            version: u32_at(b, 8),
            header_len: u32_at(b, 12),
            dims: [u32_at(b, 16), u32_at(b, 20), u32_at(b, 24)],
            dtype: b[28],
            filter: b[29],
            flags: b[30],
            levels: b[31],
            brick: u32_at(b, 32),
            apron: u32_at(b, 36),
            spacing: [f32_at(b, 40), f32_at(b, 44), f32_at(b, 48)],
            value_range: [f32_at(b, 52), f32_at(b, 56)],
            data_range: [f32_at(b, 60), f32_at(b, 64)],
            empty_below: f32_at(b, 68),
            node_count: u64_at(b, 72),
            table_offset: u64_at(b, 80),
            table_len: u64_at(b, 88),
            payload_bytes: u64_at(b, 96),
            table_crc: u32_at(b, 104),
            split_masks: if b[30] & FLAG_SPLIT_MASKS != 0 {
                let p = packed_masks(b);
                (0..(b[31].saturating_sub(1) as usize).min(MAX_SPLIT_MASKS))
                    .map(|l| ((p >> (3 * l)) & 7) as u8)
                    .collect()
            } else {
                Vec::new()
            },
            errors_crc: u32_at(b, ERRORS_CRC_AT.start),
        }
    }

    /// The stored header checksum and the checksum of bytes `0..124`.
    pub(crate) fn checksums(b: &[u8]) -> (u32, u32) {
        (u32_at(b, 124), crc32fast::hash(&b[..124]))
    }
}

/// One node-table entry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Entry {
    pub(crate) level: u8,
    pub(crate) kind: u8,
    pub(crate) pos: [u32; 3],
    pub(crate) min: f32,
    pub(crate) max: f32,
    /// The uniform value (uniform nodes), else the fill value.
    pub(crate) value: f32,
    pub(crate) len: u32,
    pub(crate) offset: u64,
    pub(crate) crc: u32,
}

impl Entry {
    pub(crate) fn key(&self) -> NodeKey {
        NodeKey::new(self.level, self.pos[0], self.pos[1], self.pos[2])
    }

    pub(crate) fn encode(&self, b: &mut [u8]) {
        b[..ENTRY_LEN].fill(0);
        b[0] = self.level;
        b[1] = self.kind;
        for a in 0..3 {
            b[4 + 4 * a..8 + 4 * a].copy_from_slice(&self.pos[a].to_le_bytes());
        }
        b[16..20].copy_from_slice(&self.min.to_le_bytes());
        b[20..24].copy_from_slice(&self.max.to_le_bytes());
        b[24..28].copy_from_slice(&self.value.to_le_bytes());
        b[28..32].copy_from_slice(&self.len.to_le_bytes());
        b[32..40].copy_from_slice(&self.offset.to_le_bytes());
        b[40..44].copy_from_slice(&self.crc.to_le_bytes());
    }

    pub(crate) fn decode(b: &[u8]) -> (Entry, [u8; 6]) {
        let e = Entry {
            level: b[0],
            kind: b[1],
            pos: [u32_at(b, 4), u32_at(b, 8), u32_at(b, 12)],
            min: f32_at(b, 16),
            max: f32_at(b, 20),
            value: f32_at(b, 24),
            len: u32_at(b, 28),
            offset: u64_at(b, 32),
            crc: u32_at(b, 40),
        };
        (e, [b[2], b[3], b[44], b[45], b[46], b[47]])
    }
}

/// One spread-table entry (format version 7): where a coarse node's
/// compressed spread brick lies. All zero: every spread of the node is 0.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(crate) struct SpreadEntry {
    pub(crate) offset: u64,
    pub(crate) len: u32,
    pub(crate) crc: u32,
}

impl SpreadEntry {
    pub(crate) fn encode(&self, b: &mut [u8]) {
        b[0..8].copy_from_slice(&self.offset.to_le_bytes());
        b[8..12].copy_from_slice(&self.len.to_le_bytes());
        b[12..16].copy_from_slice(&self.crc.to_le_bytes());
    }

    pub(crate) fn decode(b: &[u8]) -> SpreadEntry {
        SpreadEntry {
            offset: u64_at(b, 0),
            len: u32_at(b, 8),
            crc: u32_at(b, 12),
        }
    }
}

/// Bricks per axis at each level, and the index of each level's first entry in
/// the node table (entries are ordered by level, then z, y, x).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct TableGeometry {
    pub(crate) grid: Vec<[u32; 3]>,
    pub(crate) first: Vec<u64>,
    pub(crate) count: u64,
}

impl TableGeometry {
    /// `None` when the count overflows u64.
    pub(crate) fn new(layout: &OctreeLayout) -> Option<TableGeometry> {
        let mut grid = Vec::with_capacity(layout.levels as usize);
        let mut first = Vec::with_capacity(layout.levels as usize);
        let mut count = 0u64;
        for l in 0..layout.levels {
            let d = layout.level_dims(l);
            let g = d.map(|n| n.div_ceil(layout.brick));
            first.push(count);
            let n = (g[0] as u64)
                .checked_mul(g[1] as u64)?
                .checked_mul(g[2] as u64)?;
            count = count.checked_add(n)?;
            grid.push(g);
        }
        Some(TableGeometry { grid, first, count })
    }

    /// The table index of `key`, `None` when the node is outside the volume.
    pub(crate) fn index(&self, key: NodeKey) -> Option<usize> {
        let g = self.grid.get(key.level as usize)?;
        if key.x >= g[0] || key.y >= g[1] || key.z >= g[2] {
            return None;
        }
        let i = key.x as u64 + g[0] as u64 * (key.y as u64 + g[1] as u64 * key.z as u64);
        Some((self.first[key.level as usize] + i) as usize)
    }

    /// The key of table index `i` (must be < count).
    pub(crate) fn key(&self, i: u64) -> NodeKey {
        let l = self.first.partition_point(|&f| f <= i) - 1;
        let g = self.grid[l];
        let r = i - self.first[l];
        let x = r % g[0] as u64;
        let y = (r / g[0] as u64) % g[1] as u64;
        let z = r / (g[0] as u64 * g[1] as u64);
        NodeKey::new(l as u8, x as u32, y as u32, z as u32)
    }
}
