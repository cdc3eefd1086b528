//! The error section of format version 2: one [`NodeError`] per node-table
//! entry, in table order, after the node table (see `docs/store-format.md`).

use crate::error::StoreError;
use crate::format::{Header, TableGeometry};
use brickray_core::{ERROR_BINS, NodeError};
use std::path::Path;

/// Bytes of one error entry: `occupied` (u16), reserved (u16, zero), then
/// `ERROR_BINS` u16 each of `dev`, `rms` and `weight`.
pub const ERROR_ENTRY_LEN: usize = 4 + 3 * 2 * ERROR_BINS;

pub(crate) fn encode(e: &NodeError, b: &mut [u8]) {
    b[..ERROR_ENTRY_LEN].fill(0);
    b[0..2].copy_from_slice(&e.occupied.to_le_bytes());
    for (k, arr) in [&e.dev, &e.rms, &e.weight].into_iter().enumerate() {
        for (i, d) in arr.iter().enumerate() {
            let o = 4 + 2 * (k * ERROR_BINS + i);
            b[o..o + 2].copy_from_slice(&d.to_le_bytes());
        }
    }
}

/// The entry and its reserved field.
pub(crate) fn decode(b: &[u8]) -> (NodeError, u16) {
    let u16_at = |o: usize| u16::from_le_bytes([b[o], b[o + 1]]);
    let e = NodeError {
        occupied: u16_at(0),
        dev: std::array::from_fn(|i| u16_at(4 + 2 * i)),
        rms: std::array::from_fn(|i| u16_at(4 + 2 * (ERROR_BINS + i))),
        weight: std::array::from_fn(|i| u16_at(4 + 2 * (2 * ERROR_BINS + i))),
    };
    (e, u16_at(2))
}

/// Encodes the whole section.
pub(crate) fn encode_all(errors: &[NodeError]) -> Vec<u8> {
    let mut out = vec![0u8; errors.len() * ERROR_ENTRY_LEN];
    for (e, b) in errors.iter().zip(out.chunks_exact_mut(ERROR_ENTRY_LEN)) {
        encode(e, b);
    }
    out
}

/// Reads and validates the section at `offset` (its length and presence were
/// checked against the header and the file size by the caller).
pub(crate) fn read(
    section: &[u8],
    path: &Path,
    h: &Header,
    geo: &TableGeometry,
) -> Result<Vec<NodeError>, StoreError> {
    read_with(section, path, h.errors_crc, geo)
}

/// Validates the parent-error section (its entries, then their CRC-32; its
/// length checked by the caller).
pub(crate) fn read_parent(
    section: &[u8],
    path: &Path,
    geo: &TableGeometry,
) -> Result<Vec<NodeError>, StoreError> {
    let split = section.len().saturating_sub(4);
    let (entries, c) = section.split_at(split);
    let stored = <[u8; 4]>::try_from(c).map_or(0, u32::from_le_bytes);
    read_with(entries, path, stored, geo)
}

fn read_with(
    b: &[u8],
    path: &Path,
    stored: u32,
    geo: &TableGeometry,
) -> Result<Vec<NodeError>, StoreError> {
    let crc = crc32fast::hash(b);
    if crc != stored {
        return Err(StoreError::ErrorsChecksum {
            path: path.to_owned(),
            stored,
            computed: crc,
        });
    }
    let mut out = Vec::with_capacity(geo.count as usize);
    for (i, c) in b.chunks_exact(ERROR_ENTRY_LEN).enumerate() {
        let (e, reserved) = decode(c);
        if reserved != 0 {
            return Err(StoreError::BadNode {
                path: path.to_owned(),
                key: geo.key(i as u64),
                field: "error reserved",
                reason: "non-zero".into(),
            });
        }
        out.push(e);
    }
    Ok(out)
}
