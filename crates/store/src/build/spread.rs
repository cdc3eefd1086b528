//! The spread section of a build (format version 7): each coarse voxel's
//! spread, the standard deviation of the normalized values of the finest
//! voxels it stands for (`brickray_core::moments`).
//!
//! The moments `E[x]` and `E[x^2]` of the normalized values travel up the
//! level pipeline beside the values: every level above the finest keeps a
//! window of moment slices (one [`Moments`], two f64, per voxel) in step with
//! its value slices. The finest level holds none: its filter step takes each
//! child's moments from its value (`x`, `x^2`). Each coarser slice is the
//! mixture of its 2x2x2 children in the order and with the edge rule of the
//! value filter ([`Moments::mix`], the clamped and repeated children
//! included), in f64 as [`brickray_core::MomentGrid::downsample`] computes
//! them, so the spreads equal those of [`brickray_core::SpreadSource`] bit
//! for bit. A coarse node's spread brick is cut from its level's moment
//! slices with the value bricks' apron and clamp rule, each voxel's
//! `sqrt(max(0, E[x^2] - E[x]^2))` rounded to f32 then to a half float,
//! lz4-compressed; a brick of zeros has no payload. The payloads go to a
//! temporary file beside the output while the values stream, and are copied
//! after the value payloads when these are done, so the value payloads and
//! the node table are those of a build without spreads. A banded level
//! writes the next coarser level's moments beside its values into a
//! [`MomentFile`], which the remaining levels read back with them.

use super::level::LevelBuf;
use crate::error::StoreError;
use crate::format::{SpreadEntry, VERSION, payload_crc};
use crate::partial::PartialFile;
use crate::sample::{Sample, with_sample};
use brickray_core::{Moments, NodeKey, OctreeLayout};
use rayon::prelude::*;
use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom, Write};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

/// Bytes of one uncompressed spread brick: `stored_side^3` half floats.
pub(crate) fn spread_brick_bytes(layout: &OctreeLayout) -> usize {
    (layout.stored_side() as usize).pow(3) * 2
}

/// Bytes of the moment windows of a streaming pass over levels `0..=top`,
/// `slices` slices each: every level above the finest has moments (level
/// `top` too when it is not the finest: a banded build's remaining levels).
pub(super) fn window_bytes(layout: &OctreeLayout, top: u8, slices: u64) -> u64 {
    let end = (top + 1).min(layout.levels.saturating_sub(1));
    (0..end)
        .map(|l| {
            let d = layout.level_dims(l);
            d[0] as u64 * d[1] as u64 * std::mem::size_of::<Moments>() as u64
        })
        .sum::<u64>()
        .saturating_mul(slices)
}

/// Where a build's spread payloads go until the value payloads are done,
/// and the spread table's entries (offsets relative to the first spread
/// payload).
pub(super) struct SpreadSink {
    file: PartialFile,
    w: BufWriter<File>,
    /// One per node-table entry, offsets from the start of the spread region.
    pub(super) entries: Vec<SpreadEntry>,
    /// Bytes written so far.
    pub(super) len: u64,
    /// Uncompressed bytes of the spread bricks with a payload.
    pub(super) raw: u64,
}

impl SpreadSink {
    pub(super) fn new(out: &Path, nodes: usize) -> Result<SpreadSink, StoreError> {
        let file = PartialFile::create(out)?;
        let handle = file
            .file()
            .try_clone()
            .map_err(|e| StoreError::io(file.path(), e))?;
        Ok(SpreadSink {
            w: BufWriter::with_capacity(1 << 20, handle),
            file,
            entries: vec![SpreadEntry::default(); nodes],
            len: 0,
            raw: 0,
        })
    }

    fn path(&self) -> PathBuf {
        self.file.path().to_owned()
    }

    /// Appends node `index`'s payload (`key`'s spread brick, compressed).
    pub(super) fn push(
        &mut self,
        index: usize,
        key: NodeKey,
        payload: &[u8],
        raw: usize,
    ) -> Result<(), StoreError> {
        self.w
            .write_all(payload)
            .map_err(|e| StoreError::io(&self.path(), e))?;
        if let Some(slot) = self.entries.get_mut(index) {
            *slot = SpreadEntry {
                offset: self.len,
                len: payload.len() as u32,
                crc: payload_crc(VERSION, key, payload),
            };
        }
        self.len += payload.len() as u64;
        self.raw += raw as u64;
        Ok(())
    }

    /// Copies the payloads into `w` (the store, positioned at `start`) and
    /// makes the entries' offsets absolute; the temporary file is removed.
    pub(super) fn finish<W: Write>(
        mut self,
        w: &mut W,
        start: u64,
        store: &Path,
    ) -> Result<Vec<SpreadEntry>, StoreError> {
        let path = self.path();
        self.w.flush().map_err(|e| StoreError::io(&path, e))?;
        let mut f = self
            .w
            .into_inner()
            .map_err(|e| StoreError::io(&path, e.into_error()))?;
        f.seek(SeekFrom::Start(0))
            .map_err(|e| StoreError::io(&path, e))?;
        let copied = std::io::copy(&mut (&mut f).take(self.len), w).map_err(|e| {
            // The read or the write: name the store, which is what fills up.
            StoreError::io(store, e)
        })?;
        if copied != self.len {
            return Err(StoreError::io(
                &path,
                std::io::Error::new(
                    std::io::ErrorKind::UnexpectedEof,
                    "the spread payloads' temporary file is shorter than written",
                ),
            ));
        }
        for e in &mut self.entries {
            if e.len > 0 {
                e.offset += start;
            }
        }
        drop(self.file);
        Ok(self.entries)
    }
}

impl LevelBuf {
    /// Rows `rows` of level slice `k` of the coarser level's moments,
    /// filtered from this level's slices `2k`, `2k+1` (slice `k` alone when
    /// z is not halved): from its moment slices, or at the finest level from
    /// its values.
    pub(super) fn downsample_moments(
        &self,
        layout: &OctreeLayout,
        k: u32,
        pdims: [u32; 3],
        rows: (u32, u32),
        out: &mut [Moments],
    ) {
        let (z0, z1) = self.source_slices(k);
        let (nx, ny) = (self.dims[0] as usize, self.dims[1] as usize);
        let (px, row0, j0) = (pdims[0] as usize, self.row0 as usize, rows.0 as usize);
        let (hx, hy) = (self.halve[0], self.halve[1]);
        let pair = |halve: bool, i: usize, n: usize| {
            if halve {
                ((2 * i).min(n - 1), (2 * i + 1).min(n - 1))
            } else {
                (i, i)
            }
        };
        debug_assert_eq!(out.len(), px * (rows.1 - rows.0) as usize);
        let out_rows = out.par_chunks_mut(px).with_min_len(8).enumerate();
        if self.level + 1 == layout.levels {
            // The finest level: each child's moments from its value.
            let (s0, s1) = (self.slice(z0), self.slice(z1));
            let desc = &layout.volume;
            with_sample!(layout.dtype(), T => out_rows.for_each(|(jj, orow)| {
                let sz = T::SIZE;
                let (y0, y1) = pair(hy, j0 + jj, ny);
                let (y0, y1) = (y0 - row0, y1 - row0);
                let at = |s: &[u8], x: usize, y: usize| {
                    let v = desc.normalize(T::read(&s[(y * nx + x) * sz..]).to_f32());
                    Moments::of_value(v as f64)
                };
                for (i, o) in orow.iter_mut().enumerate() {
                    let (x0, x1) = pair(hx, i, nx);
                    // Order: x fastest, then y, then z (the value filter's).
                    *o = Moments::mix(&[
                        at(s0, x0, y0),
                        at(s0, x1, y0),
                        at(s0, x0, y1),
                        at(s0, x1, y1),
                        at(s1, x0, y0),
                        at(s1, x1, y0),
                        at(s1, x0, y1),
                        at(s1, x1, y1),
                    ]);
                }
            }));
        } else {
            let (m0, m1) = (self.moment_slice(z0), self.moment_slice(z1));
            out_rows.for_each(|(jj, orow)| {
                let (y0, y1) = pair(hy, j0 + jj, ny);
                let (y0, y1) = (y0 - row0, y1 - row0);
                let (r00, r01) = (&m0[y0 * nx..][..nx], &m0[y1 * nx..][..nx]);
                let (r10, r11) = (&m1[y0 * nx..][..nx], &m1[y1 * nx..][..nx]);
                for (i, o) in orow.iter_mut().enumerate() {
                    let (x0, x1) = pair(hx, i, nx);
                    *o = Moments::mix(&[
                        r00[x0], r00[x1], r01[x0], r01[x1], r10[x0], r10[x1], r11[x0], r11[x1],
                    ]);
                }
            });
        }
    }

    /// This level's moment slice `z`.
    pub(super) fn moment_slice(&self, z: u32) -> &[Moments] {
        &self.moments[(z - self.base) as usize]
    }

    /// A moment slice buffer of `len` voxels (contents unspecified).
    pub(super) fn take_moments(&mut self, len: usize) -> Vec<Moments> {
        let mut b = self.moment_pool.pop().unwrap_or_default();
        b.resize(len, Moments::default());
        b
    }

    /// Cuts node `key`'s spread brick into `buf` (`stored_side^3` half
    /// floats, little-endian) and compresses it; `None` when every spread is
    /// 0 (the node has no spread payload).
    pub(super) fn cut_spread(
        &self,
        layout: &OctreeLayout,
        key: NodeKey,
        buf: &mut [u8],
    ) -> Option<Vec<u8>> {
        let side = layout.stored_side() as i64;
        let (a, b) = (layout.apron as i64, layout.brick as i64);
        let [nx, ny, nz] = self.dims.map(|d| d as i64);
        let origin = [key.x, key.y, key.z].map(|c| c as i64 * b - a);
        let mut any = false;
        let mut o = 0;
        for k in 0..side {
            let sl = self.moment_slice((origin[2] + k).clamp(0, nz - 1) as u32);
            for j in 0..side {
                let y = (origin[1] + j).clamp(0, ny - 1) - self.row0 as i64;
                let row = &sl[(y * nx) as usize..][..nx as usize];
                for i in 0..side {
                    let x = (origin[0] + i).clamp(0, nx - 1);
                    let s = half::f16::from_f32(row[x as usize].sigma() as f32).to_bits();
                    any |= s != 0;
                    buf[o..o + 2].copy_from_slice(&s.to_le_bytes());
                    o += 2;
                }
            }
        }
        any.then(|| lz4_flex::block::compress(buf))
    }
}

/// Bytes of one voxel's moments in a [`MomentFile`]: `E[x]`, then `E[x^2]`,
/// as little-endian f64.
const MOMENT_BYTES: usize = 16;

/// The moments of a level volume in a temporary raw file, slice after
/// slice, x fastest ([`MOMENT_BYTES`] a voxel): what a banded level writes
/// for the next coarser one beside its values' raw file, and what that
/// level's build reads back.
pub(super) struct MomentFile {
    file: PartialFile,
    dims: [u32; 3],
}

impl MomentFile {
    /// A file for the moments of a level of `dims`, beside `out`.
    pub(super) fn create(out: &Path, dims: [u32; 3]) -> Result<MomentFile, StoreError> {
        let file = PartialFile::create(out)?;
        let len = dims.iter().map(|&d| d as u64).product::<u64>() * MOMENT_BYTES as u64;
        file.file()
            .set_len(len)
            .map_err(|e| StoreError::io(file.path(), e))?;
        Ok(MomentFile { file, dims })
    }

    fn offset(&self, z: u32, y: u32) -> u64 {
        (z as u64 * self.dims[1] as u64 + y as u64) * self.dims[0] as u64 * MOMENT_BYTES as u64
    }

    /// Rows `rows` of slice `z` into `out` (resized), through `bytes`.
    pub(super) fn read_rows(
        &self,
        z: u32,
        rows: (u32, u32),
        out: &mut Vec<Moments>,
        bytes: &mut Vec<u8>,
    ) -> Result<(), StoreError> {
        let n = (rows.1 - rows.0) as usize * self.dims[0] as usize;
        bytes.resize(n * MOMENT_BYTES, 0);
        self.file
            .file()
            .read_exact_at(bytes, self.offset(z, rows.0))
            .map_err(|e| StoreError::io(self.file.path(), e))?;
        out.resize(n, Moments::default());
        for (m, b) in out.iter_mut().zip(bytes.chunks_exact(MOMENT_BYTES)) {
            let f = |o: usize| f64::from_le_bytes(b[o..o + 8].try_into().unwrap_or([0; 8]));
            *m = Moments {
                mean: f(0),
                mean_sq: f(8),
            };
        }
        Ok(())
    }

    /// Writes `m`, rows `rows.0..` of slice `z`, through `bytes`.
    pub(super) fn write_rows(
        &self,
        z: u32,
        row: u32,
        m: &[Moments],
        bytes: &mut Vec<u8>,
    ) -> Result<(), StoreError> {
        bytes.clear();
        for v in m {
            bytes.extend_from_slice(&v.mean.to_le_bytes());
            bytes.extend_from_slice(&v.mean_sq.to_le_bytes());
        }
        self.file
            .file()
            .write_all_at(bytes, self.offset(z, row))
            .map_err(|e| StoreError::io(self.file.path(), e))
    }
}
