//! One level of the build's pyramid: the rolling window of its xy-slices, the
//! brick slabs cut from it, and the 2x filter that feeds the next coarser level
//! (or a raw file of it, when building in bands).

use super::Ctx;
use crate::error::StoreError;
use crate::format::{Entry, KIND_DATA, KIND_EMPTY, KIND_UNIFORM, VERSION, payload_crc};
use crate::sample::{Sample, range_dyn, with_sample};
use crate::{Filter, NO_ENTRY_LEVEL};
use brickray_core::{Moments, NodeKey, OctreeLayout};
use rayon::prelude::*;
use std::collections::VecDeque;
use std::io::Write;
use std::os::unix::fs::FileExt;
use std::path::Path;
/// The rolling window of one level's slices.
pub(super) struct LevelBuf {
    pub(super) level: u8,
    pub(super) dims: [u32; 3],
    pub(super) grid: [u32; 3],
    /// `slices[i]` is level slice `base + i`.
    pub(super) slices: VecDeque<Vec<u8>>,
    /// `moments[i]` is the moments of level slice `base + i` (a level above
    /// the finest in a build that records spreads; else empty).
    pub(super) moments: VecDeque<Vec<Moments>>,
    /// Dropped moment slices, reused.
    pub(super) moment_pool: Vec<Vec<Moments>>,
    /// Dropped slice buffers, reused (avoids page faults on fresh allocations).
    pub(super) pool: Vec<Vec<u8>>,
    pub(super) pool_cap: usize,
    pub(super) base: u32,
    pub(super) next_slab: u32,
    pub(super) next_down: u32,
    /// The slices hold level rows `row0..row0 + nrows` (all rows when streaming).
    pub(super) row0: u32,
    pub(super) nrows: u32,
    /// Brick rows (y) this pass cuts.
    pub(super) by: (u32, u32),
    /// The axes the filter to the next coarser level halves (the layout's split
    /// mask of that level); an axis not halved is copied through.
    pub(super) halve: [bool; 3],
}

impl LevelBuf {
    pub(super) fn new(layout: &OctreeLayout, level: u8, per: u32) -> LevelBuf {
        let dims = layout.level_dims(level);
        let mask = if level > 0 {
            layout.split_mask(level - 1)
        } else {
            brickray_core::ALL_AXES
        };
        LevelBuf {
            halve: std::array::from_fn(|a| mask & (1 << a) != 0),
            level,
            dims,
            grid: dims.map(|d| d.div_ceil(layout.brick)),
            slices: VecDeque::new(),
            pool: Vec::new(),
            moments: VecDeque::new(),
            moment_pool: Vec::new(),
            pool_cap: per as usize,
            base: 0,
            next_slab: 0,
            next_down: 0,
            row0: 0,
            nrows: dims[1],
            by: (0, dims[1].div_ceil(layout.brick)),
        }
    }

    /// A slice buffer of `len` bytes (contents unspecified).
    pub(super) fn take_buffer(&mut self, len: usize) -> Vec<u8> {
        let mut b = self.pool.pop().unwrap_or_default();
        b.resize(len, 0);
        b
    }

    pub(super) fn received(&self) -> u32 {
        self.base + self.slices.len() as u32
    }

    pub(super) fn slice(&self, z: u32) -> &[u8] {
        &self.slices[(z - self.base) as usize]
    }

    /// Cuts every ready brick slab, filters every ready coarser slice into
    /// `sink`, and drops slices no longer needed.
    pub(super) fn process<W: Write>(
        &mut self,
        ctx: &mut Ctx,
        mut sink: Sink<'_>,
        w: &mut W,
    ) -> Result<(), StoreError> {
        let b = ctx.layout.brick;
        let a = ctx.layout.apron;
        let nz = self.dims[2];
        while self.next_slab < self.grid[2] {
            let need = ((self.next_slab as u64 + 1) * b as u64 + a as u64).min(nz as u64) as u32;
            if self.received() < need {
                break;
            }
            self.emit_slab(ctx, w)?;
            self.next_slab += 1;
        }
        let has_parent = !matches!(sink, Sink::None);
        if has_parent {
            let pdims = ctx.layout.level_dims(self.level - 1);
            let size = ctx.layout.dtype().size();
            while self.next_down < pdims[2] {
                let need = if self.halve[2] {
                    (2 * self.next_down + 2).min(nz)
                } else {
                    self.next_down + 1
                };
                if self.received() < need {
                    break;
                }
                match &mut sink {
                    Sink::Level(p) => {
                        let mut s = p.take_buffer(pdims[0] as usize * pdims[1] as usize * size);
                        self.downsample(ctx, self.next_down, pdims, (0, pdims[1]), &mut s);
                        p.slices.push_back(s);
                        if ctx.spread.is_some() {
                            let mut m = p.take_moments(pdims[0] as usize * pdims[1] as usize);
                            let rows = (0, pdims[1]);
                            self.downsample_moments(
                                &ctx.layout,
                                self.next_down,
                                pdims,
                                rows,
                                &mut m,
                            );
                            p.moments.push_back(m);
                        }
                    }
                    Sink::File {
                        file,
                        path,
                        rows,
                        buf,
                        moments,
                    } => {
                        let (j0, j1) = *rows;
                        buf.resize((j1 - j0) as usize * pdims[0] as usize * size, 0);
                        self.downsample(ctx, self.next_down, pdims, (j0, j1), buf);
                        let off = ((self.next_down as u64 * pdims[1] as u64 + j0 as u64)
                            * pdims[0] as u64)
                            * size as u64;
                        file.write_all_at(buf, off)
                            .map_err(|e| StoreError::io(path, e))?;
                        // The same rows' moments (a build that records spreads).
                        if let Some(mo) = moments {
                            let n = (j1 - j0) as usize * pdims[0] as usize;
                            mo.buf.resize(n, Moments::default());
                            self.downsample_moments(
                                &ctx.layout,
                                self.next_down,
                                pdims,
                                (j0, j1),
                                mo.buf,
                            );
                            mo.file.write_rows(self.next_down, j0, mo.buf, mo.bytes)?;
                        }
                    }
                    Sink::None => {}
                }
                self.next_down += 1;
            }
        }
        // Keep what the next slab and the next coarser slice need.
        let keep_slab = (self.next_slab as u64 * b as u64).saturating_sub(a as u64);
        let keep_slab = if self.next_slab >= self.grid[2] {
            u64::MAX
        } else {
            keep_slab
        };
        let coarse_nz = if self.halve[2] {
            self.dims[2].div_ceil(2)
        } else {
            self.dims[2]
        };
        let keep_down = if has_parent && self.next_down < coarse_nz {
            self.next_down as u64 * if self.halve[2] { 2 } else { 1 }
        } else {
            u64::MAX
        };
        let keep = keep_slab.min(keep_down);
        while !self.slices.is_empty() && (self.base as u64) < keep {
            if let Some(b) = self.slices.pop_front()
                && self.pool.len() < self.pool_cap
            {
                self.pool.push(b);
            }
            if let Some(m) = self.moments.pop_front()
                && self.moment_pool.len() < self.pool_cap
            {
                self.moment_pool.push(m);
            }
            self.base += 1;
        }
        Ok(())
    }

    /// The two slices of this level that coarser slice `k` is filtered
    /// from: `2k` and `2k+1` (the last slice twice at an odd end), or `k`
    /// twice when z is not halved.
    pub(super) fn source_slices(&self, k: u32) -> (u32, u32) {
        if self.halve[2] {
            (2 * k, (2 * k + 1).min(self.dims[2] - 1))
        } else {
            (k, k)
        }
    }

    /// Rows `rows` of level slice `k` of the coarser level, filtered from
    /// slices `2k`, `2k+1` (slice `k` alone when z is not halved).
    pub(super) fn downsample(
        &self,
        ctx: &Ctx,
        k: u32,
        pdims: [u32; 3],
        rows: (u32, u32),
        out: &mut [u8],
    ) {
        let (z0, z1) = self.source_slices(k);
        let (s0, s1) = (self.slice(z0), self.slice(z1));
        let dtype = ctx.layout.dtype();
        let g = Geom {
            nx: self.dims[0] as usize,
            ny: self.dims[1] as usize,
            row0: self.row0 as usize,
            px: pdims[0] as usize,
            rows: (rows.0 as usize, rows.1 as usize),
            halve_x: self.halve[0],
            halve_y: self.halve[1],
        };
        debug_assert_eq!(out.len(), g.px * (g.rows.1 - g.rows.0) * dtype.size());
        with_sample!(dtype, T => downsample_slice::<T>(s0, s1, &g, ctx.filter, out));
    }

    /// Cuts, classifies, compresses and writes the bricks of slab `next_slab`.
    pub(super) fn emit_slab<W: Write>(&self, ctx: &mut Ctx, w: &mut W) -> Result<(), StoreError> {
        let bz = self.next_slab;
        let [gx, _, _] = self.grid;
        let (by_start, gy) = self.by;
        let bb = ctx.layout.brick_bytes() as u64;
        // Spread bricks of the levels above the finest, when recorded.
        let spread = ctx.spread.is_some() && self.level + 1 < ctx.layout.levels;
        let sb = if spread {
            super::spread::spread_brick_bytes(&ctx.layout)
        } else {
            0
        };
        let rows_per_group = (ctx.group_cap / ((bb + sb as u64) * gx as u64).max(1)).max(1) as u32;
        let mut by0 = by_start;
        while by0 < gy {
            let by1 = (by0 + rows_per_group).min(gy);
            let keys: Vec<NodeKey> = (by0..by1)
                .flat_map(|by| (0..gx).map(move |bx| (bx, by)))
                .map(|(bx, by)| NodeKey::new(self.level, bx, by, bz))
                .collect();
            let shared: &Ctx = ctx;
            type Cut = (Entry, Option<Vec<u8>>, Option<Vec<u8>>);
            let results: Vec<Cut> = keys
                .par_iter()
                .map_init(
                    || (vec![0u8; bb as usize], vec![0u8; sb]),
                    |(buf, sbuf), &key| {
                        let (e, p) = self.cut_brick(shared, key, buf);
                        let s = if spread {
                            self.cut_spread(&shared.layout, key, sbuf)
                        } else {
                            None
                        };
                        (e, p, s)
                    },
                )
                .collect();
            if let Some((e, _, _)) = results
                .iter()
                .find(|(e, _, _)| !(e.min.is_finite() && e.max.is_finite()))
            {
                return Err(StoreError::NonFinite { key: e.key() });
            }
            for (mut e, payload, spread_payload) in results {
                if let Some(p) = payload {
                    e.offset = ctx.offset;
                    e.len = p.len() as u32;
                    e.crc = payload_crc(VERSION, e.key(), &p);
                    w.write_all(&p)
                        .map_err(|err| StoreError::io(&ctx.path, err))?;
                    ctx.offset += p.len() as u64;
                    ctx.raw_payload += bb;
                }
                if self.level + 1 == ctx.layout.levels {
                    ctx.data_range[0] = ctx.data_range[0].min(e.min);
                    ctx.data_range[1] = ctx.data_range[1].max(e.max);
                }
                let i = ctx.geo.index(e.key()).unwrap_or(usize::MAX);
                if let (Some(p), Some(sink)) = (spread_payload, ctx.spread.as_mut()) {
                    sink.push(i, e.key(), &p, sb)?;
                }
                if let Some(slot) = ctx.entries.get_mut(i) {
                    *slot = e;
                }
            }
            by0 = by1;
        }
        Ok(())
    }

    /// Cuts one brick into `buf` and returns its entry and compressed payload.
    pub(super) fn cut_brick(
        &self,
        ctx: &Ctx,
        key: NodeKey,
        buf: &mut [u8],
    ) -> (Entry, Option<Vec<u8>>) {
        let lay = &ctx.layout;
        let size = lay.dtype().size();
        let side = lay.stored_side() as i64;
        let a = lay.apron as i64;
        let b = lay.brick as i64;
        let [nx, ny, nz] = self.dims.map(|d| d as i64);
        let x0 = key.x as i64 * b - a;
        let y0 = key.y as i64 * b - a;
        let z0 = key.z as i64 * b - a;
        // x range of the row that lies inside the level volume.
        let in_lo = x0.max(0);
        let in_hi = (x0 + side).min(nx);
        let row = side as usize * size;
        for k in 0..side {
            let z = (z0 + k).clamp(0, nz - 1) as u32;
            let sl = self.slice(z);
            for j in 0..side {
                let y = (y0 + j).clamp(0, ny - 1) as usize - self.row0 as usize;
                let src_row = &sl[y * nx as usize * size..(y + 1) * nx as usize * size];
                let dst = &mut buf[((k * side + j) as usize) * row..][..row];
                // Left clamp.
                let left = (in_lo - x0) as usize;
                for i in 0..left {
                    dst[i * size..(i + 1) * size].copy_from_slice(&src_row[..size]);
                }
                let mid = (in_hi - in_lo).max(0) as usize;
                dst[left * size..(left + mid) * size].copy_from_slice(
                    &src_row[in_lo as usize * size..(in_lo as usize + mid) * size],
                );
                let last = &src_row[(nx as usize - 1) * size..nx as usize * size];
                for i in left + mid..side as usize {
                    dst[i * size..(i + 1) * size].copy_from_slice(last);
                }
            }
        }
        let (mut lo, mut hi) = range_dyn(lay.dtype(), buf);
        if lay.dtype() == brickray_core::DType::F32
            && buf
                .chunks_exact(4)
                .any(|c| !f32::from_le_bytes([c[0], c[1], c[2], c[3]]).is_finite())
        {
            (lo, hi) = (f32::NAN, f32::NAN);
        }
        let uniform = lo == hi;
        // Subtree range: own voxels and the children's ranges.
        let (mut smin, mut smax) = (lo, hi);
        if key.level + 1 < lay.levels {
            for &c in lay.children(key).iter() {
                if let Some(e) = ctx.geo.index(c).and_then(|i| ctx.entries.get(i))
                    && e.level != NO_ENTRY_LEVEL
                {
                    smin = smin.min(e.min);
                    smax = smax.max(e.max);
                }
            }
        }
        let mut e = Entry {
            level: key.level,
            kind: KIND_DATA,
            pos: [key.x, key.y, key.z],
            min: smin,
            max: smax,
            value: lo,
            len: 0,
            offset: 0,
            crc: 0,
        };
        if ctx.empty_below.is_some_and(|t| smax < t) {
            e.kind = KIND_EMPTY;
            return (e, None);
        }
        if uniform {
            e.kind = KIND_UNIFORM;
            return (e, None);
        }
        let payload = lz4_flex::block::compress(buf);
        (e, Some(payload))
    }
}

/// Geometry of one downsampling step.
pub(super) struct Geom {
    /// Fine level width and height.
    nx: usize,
    ny: usize,
    /// First fine row held in the slices.
    row0: usize,
    /// Coarse width.
    px: usize,
    /// Coarse rows to compute.
    rows: (usize, usize),
    /// Whether x and y are halved (else each coarse voxel takes one fine column
    /// or row, read twice).
    halve_x: bool,
    halve_y: bool,
}

pub(super) fn downsample_slice<T: Sample>(
    s0: &[u8],
    s1: &[u8],
    g: &Geom,
    filter: Filter,
    out: &mut [u8],
) {
    let sz = T::SIZE;
    let (nx, ny, px) = (g.nx, g.ny, g.px);
    let row = |s: &'_ [u8], y: usize| -> std::ops::Range<usize> {
        let _ = s;
        (y - g.row0) * nx * sz..(y - g.row0 + 1) * nx * sz
    };
    let rows = out.par_chunks_mut(px * sz).with_min_len(8);
    rows.enumerate().for_each(|(jj, orow)| {
        let j = g.rows.0 + jj;
        let (y0, y1) = if g.halve_y {
            ((2 * j).min(ny - 1), (2 * j + 1).min(ny - 1))
        } else {
            (j, j)
        };
        let r = [
            &s0[row(s0, y0)],
            &s0[row(s0, y1)],
            &s1[row(s1, y0)],
            &s1[row(s1, y1)],
        ];
        for i in 0..px {
            let (x0, x1) = if g.halve_x {
                ((2 * i).min(nx - 1) * sz, (2 * i + 1).min(nx - 1) * sz)
            } else {
                (i * sz, i * sz)
            };
            // Order: x fastest, then y, then z.
            let v = [
                T::read(&r[0][x0..]),
                T::read(&r[0][x1..]),
                T::read(&r[1][x0..]),
                T::read(&r[1][x1..]),
                T::read(&r[2][x0..]),
                T::read(&r[2][x1..]),
                T::read(&r[3][x0..]),
                T::read(&r[3][x1..]),
            ];
            T::filter(v, filter).write(&mut orow[i * sz..]);
        }
    });
}

/// Where a level's filtered slices go.
pub(super) enum Sink<'a> {
    /// Nowhere (the root level).
    None,
    /// The next coarser level's window.
    Level(&'a mut LevelBuf),
    /// Rows `rows` of each coarser slice, into a raw file of the coarser level
    /// (and their moments into a file of its moments, when recorded).
    File {
        file: &'a std::fs::File,
        path: &'a Path,
        rows: (u32, u32),
        buf: &'a mut Vec<u8>,
        moments: Option<MomentOut<'a>>,
    },
}

/// Where a banded level's filtered moments go, and the buffers they pass
/// through.
pub(super) struct MomentOut<'a> {
    pub(super) file: &'a super::spread::MomentFile,
    pub(super) buf: &'a mut Vec<Moments>,
    pub(super) bytes: &'a mut Vec<u8>,
}
