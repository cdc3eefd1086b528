//! Opening a store, as phases: the [`header`] (magic, version, checksum,
//! reserved bytes), the octree [`layout`] it describes, the extents of its
//! [`Sections`] against the file's length, and the node [`table`]. Every
//! read goes through [`RangeReader`], the byte-range seam: a local file, bytes
//! in memory, or a range reader over object storage or HTTP. Opening takes
//! two reads: the header, then everything after the payload (the node table,
//! the error sections and the placement record, which end the file) in one
//! range.

use crate::Filter;
use crate::error::StoreError;
use crate::errsec::ERROR_ENTRY_LEN;
use crate::format::{
    ENTRY_LEN, Entry, FLAG_ERRORS, FLAG_LABELS, FLAG_PARENT_ERRORS, FLAG_PLACEMENT,
    FLAG_SPLIT_MASKS, FLAG_SPREAD, FLAG_THRESHOLD, HEADER_LEN, Header, KIND_DATA, KIND_EMPTY,
    KIND_UNIFORM, MAGIC, MAX_APRON, MAX_BRICK, MAX_BRICK_BYTES, MAX_SPLIT_MASKS, MIN_VERSION,
    PLACEMENT_LEN, PLACEMENT_VERSION, SPREAD_ENTRY_LEN, SPREAD_VERSION, SpreadEntry, TableGeometry,
    VERSION, dtype_from_code, filter_from_code, packed_masks,
};
use crate::reader::{bad, max_compressed};
use crate::sample::representable;
use brickray_core::{NodeKey, OctreeLayout, RangeReader, VolumeDesc, VolumeKind};
use std::path::Path;

/// Phase 1: the header, checked: long enough, the magic, a known version,
/// its checksum, reserved bytes zero, its length.
pub(crate) fn header(
    file: &dyn RangeReader,
    path: &Path,
    file_len: u64,
) -> Result<(Header, [u8; HEADER_LEN]), StoreError> {
    let mut hb = [0u8; HEADER_LEN];
    if file_len < HEADER_LEN as u64 {
        return Err(StoreError::Truncated {
            path: path.to_owned(),
            section: "header",
            needed: HEADER_LEN as u64,
            actual: file_len,
        });
    }
    file.read_exact_at(&mut hb, 0)
        .map_err(|e| StoreError::io(path, e))?;
    if hb[..8] != MAGIC {
        return Err(StoreError::NotAStore {
            path: path.to_owned(),
        });
    }
    let (stored, computed) = Header::checksums(&hb);
    let h = Header::decode(&hb);
    if !(MIN_VERSION..=VERSION).contains(&h.version) {
        return Err(StoreError::UnsupportedVersion {
            path: path.to_owned(),
            version: h.version,
        });
    }
    if stored != computed {
        return Err(StoreError::HeaderChecksum {
            path: path.to_owned(),
            stored,
            computed,
        });
    }
    // Reserved bytes are zero, but for the split masks of an anisotropic
    // pyramid (3 bits per level but the finest, in 108..120) and, from
    // version 2, the error section's CRC (120..124, zero without it).
    let masks_used = if h.flags & FLAG_SPLIT_MASKS != 0 {
        (3 * h.levels.saturating_sub(1) as u32).min(96)
    } else {
        0
    };
    if (h.version < 2 && hb[120..124].iter().any(|&b| b != 0))
        || packed_masks(&hb).checked_shr(masks_used).unwrap_or(0) != 0
        || (h.flags & FLAG_SPLIT_MASKS != 0 && h.levels as usize > MAX_SPLIT_MASKS + 1)
    {
        return Err(bad(path, "reserved", "non-zero"));
    }
    if h.header_len != HEADER_LEN as u32 {
        return Err(bad(
            path,
            "header_len",
            format!("{} (expected {HEADER_LEN})", h.header_len),
        ));
    }
    Ok((h, hb))
}

/// The flags a version knows.
fn known_flags(version: u32) -> u8 {
    let v5 = FLAG_THRESHOLD | FLAG_SPLIT_MASKS | FLAG_ERRORS | FLAG_PARENT_ERRORS | FLAG_LABELS;
    match version {
        v if v >= SPREAD_VERSION => v5 | FLAG_PLACEMENT | FLAG_SPREAD,
        v if v >= PLACEMENT_VERSION => v5 | FLAG_PLACEMENT,
        5 => v5,
        3 | 4 => FLAG_THRESHOLD | FLAG_SPLIT_MASKS | FLAG_ERRORS | FLAG_PARENT_ERRORS,
        2 => FLAG_THRESHOLD | FLAG_SPLIT_MASKS | FLAG_ERRORS,
        _ => FLAG_THRESHOLD | FLAG_SPLIT_MASKS,
    }
}

/// Phase 2: the volume and octree the header describes, every field in its
/// range (dtype, filter, flags, dims, spacing, ranges, brick, apron, split
/// masks, levels), and the filter of its inner nodes.
pub(crate) fn layout(h: &Header, path: &Path) -> Result<(OctreeLayout, Filter), StoreError> {
    let dtype = dtype_from_code(h.dtype)
        .ok_or_else(|| bad(path, "dtype", format!("unknown code {}", h.dtype)))?;
    let filter = filter_from_code(h.filter)
        .ok_or_else(|| bad(path, "filter", format!("unknown code {}", h.filter)))?;
    if h.flags & !known_flags(h.version) != 0 {
        return Err(bad(path, "flags", format!("unknown bits {:#x}", h.flags)));
    }
    let labels = h.flags & FLAG_LABELS != 0;
    if h.flags & FLAG_SPREAD != 0 && (labels || filter != Filter::Average) {
        return Err(bad(
            path,
            "flags",
            format!("spreads in a store of the {filter:?} filter (spreads need the average)"),
        ));
    }
    if labels && filter != Filter::Mode {
        return Err(bad(
            path,
            "filter",
            format!("{filter:?} in a label store (label stores are filtered by the mode)"),
        ));
    }
    let desc = VolumeDesc {
        dims: h.dims,
        dtype,
        spacing: h.spacing,
        value_range: h.value_range,
        kind: if labels {
            VolumeKind::Labels
        } else {
            VolumeKind::Intensity
        },
    };
    if let Err(e) = desc.validate()
        && labels
    {
        return Err(bad(path, "dtype", e.to_string()));
    }
    if let Err(e) = brickray_core::volume::voxel_count(h.dims.map(u64::from)) {
        return Err(bad(path, "dims", e.to_string()));
    }
    if h.spacing.iter().any(|s| !s.is_finite() || *s <= 0.0) {
        return Err(bad(path, "spacing", format!("{:?}", h.spacing)));
    }
    if h.value_range.iter().any(|v| !v.is_finite()) {
        return Err(bad(path, "value_range", format!("{:?}", h.value_range)));
    }
    if h.data_range.iter().any(|v| !v.is_finite()) || h.data_range[0] > h.data_range[1] {
        return Err(bad(path, "data_range", format!("{:?}", h.data_range)));
    }
    if !h.empty_below.is_finite() {
        return Err(bad(path, "empty_below", format!("{}", h.empty_below)));
    }
    if h.brick == 0 || h.brick > MAX_BRICK {
        return Err(bad(
            path,
            "brick",
            format!("{} (must be in 1..={MAX_BRICK})", h.brick),
        ));
    }
    if h.apron > MAX_APRON {
        return Err(bad(
            path,
            "apron",
            format!("{} (must be in 0..={MAX_APRON})", h.apron),
        ));
    }
    let layout = if h.flags & FLAG_SPLIT_MASKS != 0 {
        OctreeLayout::with_split_masks(desc, h.brick, h.apron, &h.split_masks)
            .map_err(|e| bad(path, "split_masks", e.to_string()))?
    } else {
        OctreeLayout::new(desc, h.brick, h.apron)
    };
    if layout.levels != h.levels {
        return Err(bad(
            path,
            "levels",
            format!("{} (dims and brick imply {})", h.levels, layout.levels),
        ));
    }
    if layout.brick_bytes() > MAX_BRICK_BYTES {
        return Err(bad(
            path,
            "brick",
            format!("stored brick of {} bytes", layout.brick_bytes()),
        ));
    }
    Ok((layout, filter))
}

/// Phase 3: where the node table, the error sections, the spread table and
/// the placement record lie; they must end exactly at the file's end.
pub(crate) struct Sections {
    /// Where the value payloads end (the spread payloads start; the table's
    /// offset without the spread section).
    pub(crate) values_end: u64,
    /// Bytes of the spread table, entries and CRC (0 without it).
    pub(crate) spread_len: u64,
    /// Where the spread table ends (the placement record starts).
    pub(crate) spread_end: u64,
    /// Bytes of the error section's entries (0 without it).
    pub(crate) errors_len: u64,
    /// Bytes of the parent-error section, entries and CRC (0 without it).
    pub(crate) parent_len: u64,
    /// Where the node table ends (the error section starts).
    pub(crate) table_end: u64,
    /// Where the error section ends (the parent-error section starts).
    pub(crate) errors_end: u64,
    /// Where the parent-error section ends (the placement record starts).
    pub(crate) parent_end: u64,
    /// Bytes of the placement record (0 without it).
    pub(crate) placement_len: u64,
}

impl Sections {
    pub(crate) fn of(
        h: &Header,
        geo: &TableGeometry,
        path: &Path,
        file_len: u64,
    ) -> Result<Sections, StoreError> {
        if h.node_count != geo.count {
            return Err(bad(
                path,
                "node_count",
                format!("{} (geometry implies {})", h.node_count, geo.count),
            ));
        }
        let overflow = |field| bad(path, field, "overflow");
        let table_len = geo
            .count
            .checked_mul(ENTRY_LEN as u64)
            .ok_or_else(|| overflow("node_count"))?;
        if h.table_len != table_len {
            return Err(bad(
                path,
                "table_len",
                format!("{} (expected {table_len})", h.table_len),
            ));
        }
        if h.table_offset < HEADER_LEN as u64 {
            return Err(bad(
                path,
                "table_offset",
                format!("{} overlaps the header", h.table_offset),
            ));
        }
        let has_spread = h.flags & FLAG_SPREAD != 0;
        // With the spread section the spread payloads lie between the value
        // payloads and the table.
        let payload_room = h.table_offset - HEADER_LEN as u64;
        if if has_spread {
            h.payload_bytes > payload_room
        } else {
            h.payload_bytes != payload_room
        } {
            return Err(bad(
                path,
                "payload_bytes",
                format!(
                    "{} (table offset implies {})",
                    h.payload_bytes,
                    h.table_offset - HEADER_LEN as u64
                ),
            ));
        }
        let has_errors = h.flags & FLAG_ERRORS != 0;
        let errors_len = if has_errors {
            geo.count
                .checked_mul(ERROR_ENTRY_LEN as u64)
                .ok_or_else(|| overflow("node_count"))?
        } else {
            0
        };
        let has_parent_errors = h.flags & FLAG_PARENT_ERRORS != 0;
        if has_parent_errors && !has_errors {
            return Err(bad(
                path,
                "flags",
                "the parent-error section without the error section",
            ));
        }
        // Its entries, then their CRC.
        let parent_len = if has_parent_errors { errors_len + 4 } else { 0 };
        if !has_errors && h.errors_crc != 0 {
            return Err(bad(
                path,
                "errors_crc",
                "set without the error section's flag",
            ));
        }
        let table_end = h
            .table_offset
            .checked_add(table_len)
            .ok_or_else(|| overflow("table_offset"))?;
        let errors_end = table_end
            .checked_add(errors_len)
            .ok_or_else(|| overflow("node_count"))?;
        let parent_end = errors_end
            .checked_add(parent_len)
            .ok_or_else(|| overflow("node_count"))?;
        // The spread table (version 7): its entries, then their CRC.
        let spread_len = if has_spread {
            geo.count
                .checked_mul(SPREAD_ENTRY_LEN as u64)
                .and_then(|n| n.checked_add(4))
                .ok_or_else(|| overflow("node_count"))?
        } else {
            0
        };
        let spread_end = parent_end
            .checked_add(spread_len)
            .ok_or_else(|| overflow("node_count"))?;
        // The placement record (version 6) ends the file.
        let placement_len = if h.flags & FLAG_PLACEMENT != 0 {
            PLACEMENT_LEN as u64
        } else {
            0
        };
        let end = spread_end
            .checked_add(placement_len)
            .ok_or_else(|| overflow("node_count"))?;
        if end > file_len {
            return Err(StoreError::Truncated {
                path: path.to_owned(),
                section: if table_end > file_len {
                    "node table"
                } else if errors_end > file_len {
                    "error section"
                } else if parent_end > file_len {
                    "parent-error section"
                } else if spread_end > file_len {
                    "spread table"
                } else {
                    "placement record"
                },
                needed: end,
                actual: file_len,
            });
        }
        if end < file_len {
            return Err(bad(
                path,
                "table_offset",
                format!("the store ends at {end} but the file holds {file_len} bytes"),
            ));
        }
        Ok(Sections {
            values_end: HEADER_LEN as u64 + h.payload_bytes,
            spread_len,
            spread_end,
            errors_len,
            parent_len,
            table_end,
            errors_end,
            parent_end,
            placement_len,
        })
    }
}

/// Reads the metadata that follows the payload: from the table's offset to
/// the end of the file (phase 3 checked that the sections end it exactly),
/// in one range.
pub(crate) fn tail(
    file: &dyn RangeReader,
    path: &Path,
    h: &Header,
    file_len: u64,
) -> Result<Vec<u8>, StoreError> {
    // Bounded by the file's length (phase 3), which the reader reported.
    let mut tail = vec![0u8; (file_len - h.table_offset) as usize];
    file.read_exact_at(&mut tail, h.table_offset)
        .map_err(|e| StoreError::io(path, e))?;
    Ok(tail)
}

/// Where the value payloads end: the table's offset, or with the spread
/// section (version 7) where the spread payloads start (phase 3 checked it
/// is no further than the table's offset).
fn values_end(h: &Header) -> u64 {
    HEADER_LEN as u64 + h.payload_bytes
}

/// Phase 4: the node table, the first bytes of the [`tail`] (its length
/// checked in phase 3), its CRC verified and every entry checked
/// ([`entry`]).
pub(crate) fn table(
    tail: &[u8],
    path: &Path,
    h: &Header,
    geo: &TableGeometry,
    layout: &OctreeLayout,
) -> Result<Vec<Entry>, StoreError> {
    let table_len = (geo.count * ENTRY_LEN as u64) as usize;
    let table = tail.get(..table_len).ok_or_else(|| StoreError::Truncated {
        path: path.to_owned(),
        section: "node table",
        needed: h.table_offset + table_len as u64,
        actual: h.table_offset + tail.len() as u64,
    })?;
    let crc = crc32fast::hash(table);
    if crc != h.table_crc {
        return Err(StoreError::TableChecksum {
            path: path.to_owned(),
            stored: h.table_crc,
            computed: crc,
        });
    }
    let max_len = max_compressed(layout.brick_bytes());
    table
        .chunks_exact(ENTRY_LEN)
        .enumerate()
        .map(|(i, b)| entry(path, geo, layout, values_end(h), max_len, i, b))
        .collect()
}

/// Phase 5: the ranges nest as the builder writes them: the header's
/// `data_range` is the root's subtree range, and every node's subtree range
/// lies within its parent's. (A forged `data_range` would otherwise let
/// empty nodes and nodes outside the volume read outside every recorded
/// range.)
pub(crate) fn ranges(
    path: &Path,
    h: &Header,
    geo: &TableGeometry,
    layout: &OctreeLayout,
    entries: &[Entry],
) -> Result<(), StoreError> {
    let root = geo.index(NodeKey::ROOT).and_then(|i| entries.get(i));
    if root.is_none_or(|r| [r.min, r.max] != h.data_range) {
        return Err(bad(
            path,
            "data_range",
            format!(
                "{:?} is not the root's range {:?}",
                h.data_range,
                root.map(|r| [r.min, r.max])
            ),
        ));
    }
    for e in entries {
        let key = e.key();
        let Some(p) = layout
            .parent(key)
            .and_then(|p| geo.index(p))
            .and_then(|i| entries.get(i))
        else {
            continue;
        };
        if e.min < p.min || e.max > p.max {
            return Err(StoreError::BadNode {
                path: path.to_owned(),
                key,
                field: "min/max",
                reason: format!(
                    "[{}, {}] outside the parent {:?}'s range [{}, {}]",
                    e.min,
                    e.max,
                    p.key(),
                    p.min,
                    p.max
                ),
            });
        }
    }
    Ok(())
}

/// One table entry, checked: its position, reserved bytes, range, value, and
/// payload fields by kind.
fn entry(
    path: &Path,
    geo: &TableGeometry,
    layout: &OctreeLayout,
    values_end: u64,
    max_len: u64,
    i: usize,
    b: &[u8],
) -> Result<Entry, StoreError> {
    let dtype = layout.volume.dtype;
    let key = geo.key(i as u64);
    let (e, reserved) = Entry::decode(b);
    let node = |field: &'static str, reason: String| StoreError::BadNode {
        path: path.to_owned(),
        key,
        field,
        reason,
    };
    if e.key() != key {
        return Err(node("position", format!("entry names {:?}", e.key())));
    }
    if reserved != [0; 6] {
        return Err(node("reserved", "non-zero".into()));
    }
    if !(e.min.is_finite() && e.max.is_finite() && e.min <= e.max) {
        return Err(node("min/max", format!("[{}, {}]", e.min, e.max)));
    }
    if !representable(dtype, e.value) {
        return Err(node(
            "value",
            format!("{} is not a {} sample", e.value, dtype.name()),
        ));
    }
    match e.kind {
        KIND_EMPTY | KIND_UNIFORM => {
            if e.len != 0 || e.offset != 0 || e.crc != 0 {
                return Err(node(
                    "payload",
                    "payload fields set on a node without payload".into(),
                ));
            }
            if e.kind == KIND_UNIFORM && !(e.min <= e.value && e.value <= e.max) {
                return Err(node(
                    "value",
                    format!("{} outside [{}, {}]", e.value, e.min, e.max),
                ));
            }
        }
        KIND_DATA => {
            if e.len == 0 || e.len as u64 > max_len {
                return Err(node("len", format!("{} (must be in 1..={max_len})", e.len)));
            }
            let pend = e.offset.checked_add(e.len as u64);
            if e.offset < HEADER_LEN as u64 || pend.is_none_or(|p| p > values_end) {
                return Err(node(
                    "offset",
                    format!("{}+{} outside the payload section", e.offset, e.len),
                ));
            }
        }
        k => return Err(node("kind", format!("unknown kind {k}"))),
    }
    Ok(e)
}

/// Phase 7 (version 7, flag bit 6): the spread table, its CRC verified and
/// every entry checked: all zero at the finest level and for a node whose
/// spreads are all 0; else a length within the lz4 bound of one spread brick
/// and a payload within the spread payloads `values_end..table_offset`,
/// which the payloads must tile exactly, as the value payloads tile theirs.
pub(crate) fn spread_table(
    section: &[u8],
    path: &Path,
    h: &Header,
    sec: &Sections,
    geo: &TableGeometry,
    layout: &OctreeLayout,
) -> Result<Vec<SpreadEntry>, StoreError> {
    let (entries, c) = section.split_at(section.len().saturating_sub(4));
    let stored = <[u8; 4]>::try_from(c).map_or(0, u32::from_le_bytes);
    let computed = crc32fast::hash(entries);
    if computed != stored {
        return Err(StoreError::SpreadChecksum {
            path: path.to_owned(),
            stored,
            computed,
        });
    }
    let finest = layout.levels.saturating_sub(1);
    let max_len = max_compressed(crate::build::spread_brick_bytes(layout));
    let mut out = Vec::with_capacity(geo.count as usize);
    for (i, b) in entries.chunks_exact(SPREAD_ENTRY_LEN).enumerate() {
        let e = SpreadEntry::decode(b);
        let key = geo.key(i as u64);
        let node = |reason: String| StoreError::BadNode {
            path: path.to_owned(),
            key,
            field: "spread",
            reason,
        };
        if e.len == 0 || key.level == finest {
            if e != SpreadEntry::default() {
                return Err(node(if e.len == 0 {
                    "offset or checksum set without a payload".into()
                } else {
                    "a payload at the finest level".into()
                }));
            }
        } else if e.len as u64 > max_len {
            return Err(node(format!("len {} (must be in 1..={max_len})", e.len)));
        } else if e.offset < sec.values_end
            || e.offset
                .checked_add(e.len as u64)
                .is_none_or(|p| p > h.table_offset)
        {
            return Err(node(format!(
                "{}+{} outside the spread payloads {}..{}",
                e.offset, e.len, sec.values_end, h.table_offset
            )));
        }
        out.push(e);
    }
    let spans = out
        .iter()
        .enumerate()
        .filter(|(_, e)| e.len > 0)
        .map(|(i, e)| (e.offset, e.len as u64, geo.key(i as u64)));
    check_tiling(path, spans, sec.values_end, h.table_offset)?;
    Ok(out)
}

/// Checks that `spans` (offset, length, node) tile `start..end` exactly, as
/// the builder writes payloads: a gap is a payload whose reference was
/// removed or moved, an overlap two nodes sharing bytes.
pub(crate) fn check_tiling(
    path: &Path,
    spans: impl Iterator<Item = (u64, u64, NodeKey)>,
    start: u64,
    end: u64,
) -> Result<(), StoreError> {
    let mut spans: Vec<(u64, u64, NodeKey)> = spans.collect();
    // Stable: equal spans stay in table order.
    spans.sort_by_key(|s| (s.0, s.1));
    let mut at = start;
    let mut prev: Option<NodeKey> = None;
    for (off, len, key) in spans {
        if off > at {
            return Err(StoreError::PayloadGap {
                path: path.to_owned(),
                start: at,
                end: off,
            });
        }
        if off < at {
            return Err(StoreError::PayloadOverlap {
                path: path.to_owned(),
                key,
                other: prev.unwrap_or(key),
            });
        }
        at = off + len;
        prev = Some(key);
    }
    if at < end {
        return Err(StoreError::PayloadGap {
            path: path.to_owned(),
            start: at,
            end,
        });
    }
    Ok(())
}
