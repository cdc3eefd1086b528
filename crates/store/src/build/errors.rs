//! The error section of a build (format version 2): per node and per bin of
//! its value range, the bound on `|finest voxel - coarse voxel|`, the typical
//! (RMS) deviation and the bin's share of the node's voxels
//! (`brickray_core::lod`, `docs/store-format.md`).
//!
//! Computed after the payloads are written, from them: one pass over the
//! finest-level bricks fills, for every voxel of every coarser level, the
//! min, max, sum and sum of squares of the finest voxels of its footprint
//! (composed level by level over its children: 2x2x2, or 2 along only the
//! axes the level halves in an anisotropic pyramid); then every coarser
//! node's brick is decoded and each of its interior voxels `C` (`0..=brick`
//! per axis, clamped) gets `dev = max(hi - C, C - lo)` over the 3x3x3
//! neighbourhood of its footprint and the mean square of `F - C` over its own
//! footprint. The arrays take 32 bytes per coarse voxel (about 32/7 of the
//! finest voxel count in bytes, plus 8 bytes per voxel of one level for the
//! neighbourhood pass); when that exceeds the build's memory bound the section
//! is left out (the store then behaves like a version-1 store for refinement).

use crate::error::StoreError;
use crate::format::{Entry, KIND_DATA, KIND_UNIFORM, TableGeometry};
use crate::sample::{Sample, with_sample};
use brickray_core::lod::bin_of;
use brickray_core::{BinStats, ERROR_BINS, NodeError, NodeKey, OctreeLayout};
use rayon::prelude::*;
use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::Path;

/// Bytes the error pass needs for `layout` (see the module documentation).
pub(super) fn memory_needed(layout: &OctreeLayout) -> u64 {
    let finest = layout.levels.saturating_sub(1);
    let voxels = |l: u8| {
        layout
            .level_dims(l)
            .iter()
            .map(|&d| d as u64)
            .product::<u64>()
    };
    let all: u64 = (0..finest).map(voxels).sum();
    let biggest = if finest > 0 { voxels(finest - 1) } else { 0 };
    all.saturating_mul(std::mem::size_of::<Acc>() as u64)
        .saturating_add(biggest.saturating_mul(8))
}

/// What a coarse voxel's footprint of finest voxels holds.
#[derive(Debug, Clone, Copy)]
struct Acc {
    lo: f32,
    hi: f32,
    n: u32,
    s1: f64,
    s2: f64,
}

impl Acc {
    const EMPTY: Acc = Acc {
        lo: f32::INFINITY,
        hi: f32::NEG_INFINITY,
        n: 0,
        s1: 0.0,
        s2: 0.0,
    };
    fn add(&mut self, o: &Acc) {
        self.lo = self.lo.min(o.lo);
        self.hi = self.hi.max(o.hi);
        self.n += o.n;
        self.s1 += o.s1;
        self.s2 += o.s2;
    }
    /// Mean square of `F - c` over the footprint.
    fn mean_sq(&self, c: f64) -> f64 {
        if self.n == 0 {
            return 0.0;
        }
        let n = self.n as f64;
        (self.s2 / n - 2.0 * c * self.s1 / n + c * c).max(0.0)
    }
}

/// One level's footprints.
struct Level {
    dims: [u32; 3],
    acc: Vec<Acc>,
}

impl Level {
    fn idx(&self, x: u32, y: u32, z: u32) -> usize {
        x as usize + self.dims[0] as usize * (y as usize + self.dims[1] as usize * z as usize)
    }
}

/// Decoded samples of a node's stored brick as f32 (`None` for empty nodes).
pub(super) fn brick_values(
    file: &File,
    path: &Path,
    layout: &OctreeLayout,
    e: &Entry,
    raw: &mut Vec<u8>,
    out: &mut Vec<f32>,
) -> Result<bool, StoreError> {
    let n = layout.stored_side().pow(3) as usize;
    out.resize(n, 0.0);
    match e.kind {
        KIND_UNIFORM => {
            out.fill(e.value);
            Ok(true)
        }
        KIND_DATA => {
            let mut c = vec![0u8; e.len as usize];
            file.read_exact_at(&mut c, e.offset)
                .map_err(|err| StoreError::io(path, err))?;
            raw.resize(layout.brick_bytes(), 0);
            match lz4_flex::block::decompress_into(&c, raw) {
                Ok(k) if k == raw.len() => {}
                _ => {
                    return Err(StoreError::Decode {
                        key: e.key(),
                        reason: "payload does not decompress to a brick".into(),
                    });
                }
            }
            let size = layout.dtype().size();
            with_sample!(layout.dtype(), T => {
                for (v, s) in out.iter_mut().zip(raw.chunks_exact(size)) {
                    *v = T::read(s).to_f32();
                }
            });
            Ok(true)
        }
        _ => Ok(false),
    }
}

/// The two error sections, one entry per node in table order.
pub(super) struct ErrorSections {
    /// Each node's own error (its brick against the finest level).
    pub(super) errors: Vec<NodeError>,
    /// The error of drawing each node's region from its parent's brick,
    /// binned over the parent's range (zero for the root; format version 3).
    pub(super) parent_errors: Vec<NodeError>,
}

/// The error entries of every node (table order), or `None` when the pass
/// would exceed `memory_bound`.
pub(super) fn compute(
    file: &File,
    path: &Path,
    layout: &OctreeLayout,
    geo: &TableGeometry,
    entries: &[Entry],
    memory_bound: u64,
) -> Result<Option<ErrorSections>, StoreError> {
    if memory_needed(layout) > memory_bound {
        return Ok(None);
    }
    let mut errors = vec![NodeError::default(); entries.len()];
    let mut parent_errors = vec![NodeError::default(); entries.len()];
    let levels = layout.levels;
    if levels < 2 {
        return Ok(Some(ErrorSections {
            errors,
            parent_errors,
        }));
    }
    let finest = levels - 1;
    let b = layout.brick;
    let a = layout.apron as usize;
    let side = layout.stored_side() as usize;
    let fdims = layout.level_dims(finest);

    let mut pyramid: Vec<Level> = (0..finest)
        .map(|l| {
            let dims = layout.level_dims(l);
            let n = dims.iter().map(|&d| d as usize).product();
            Level {
                dims,
                acc: vec![Acc::EMPTY; n],
            }
        })
        .collect();
    // Level finest-1 from the finest bricks (their interior voxels): per leaf,
    // a dense block of the parent voxels it touches, in parallel; merged
    // serially, 256 leaves at a time.
    // Per axis, 2 where the level above halves it, else 1 (an anisotropic
    // pyramid halves only the finer axes first).
    let ratio = |l: u8| -> [u32; 3] {
        let m = layout.split_mask(l);
        std::array::from_fn(|a| 1 + ((m >> a) & 1) as u32)
    };
    {
        let parent = &mut pyramid[finest as usize - 1];
        let pd = parent.dims;
        let r = ratio(finest - 1);
        let first = geo.first[finest as usize] as usize;
        for group in entries[first..].chunks(256) {
            let per_leaf: Vec<Result<Vec<(usize, Acc)>, StoreError>> = group
                .par_iter()
                .map_init(
                    || (Vec::new(), Vec::new()),
                    |(raw, vals), e| {
                        let key = e.key();
                        let has = brick_values(file, path, layout, e, raw, vals)?;
                        let (x0, y0, z0) = (key.x * b, key.y * b, key.z * b);
                        let p0 = [x0 / r[0], y0 / r[1], z0 / r[2]];
                        let n: [usize; 3] = std::array::from_fn(|i| (b / r[i] + 2) as usize);
                        let mut acc = vec![Acc::EMPTY; n[0] * n[1] * n[2]];
                        for k in 0..b.min(fdims[2].saturating_sub(z0)) {
                            for j in 0..b.min(fdims[1].saturating_sub(y0)) {
                                for i in 0..b.min(fdims[0].saturating_sub(x0)) {
                                    // Empty leaves: their range (never drawn).
                                    let (lo, hi) = if has {
                                        let s = vals[(k as usize + a) * side * side
                                            + (j as usize + a) * side
                                            + i as usize
                                            + a];
                                        (s, s)
                                    } else {
                                        (e.min, e.max)
                                    };
                                    let q = ((x0 + i) / r[0] - p0[0]) as usize
                                        + n[0]
                                            * (((y0 + j) / r[1] - p0[1]) as usize
                                                + n[1] * ((z0 + k) / r[2] - p0[2]) as usize);
                                    let v = lo as f64;
                                    acc[q].add(&Acc {
                                        lo,
                                        hi,
                                        n: 1,
                                        s1: v,
                                        s2: v * v,
                                    });
                                }
                            }
                        }
                        let mut out = Vec::new();
                        for (q, c) in acc.iter().enumerate() {
                            if c.n == 0 {
                                continue;
                            }
                            let (qx, qy, qz) = (q % n[0], (q / n[0]) % n[1], q / (n[0] * n[1]));
                            let p = (p0[0] as usize + qx)
                                + pd[0] as usize
                                    * ((p0[1] as usize + qy)
                                        + pd[1] as usize * (p0[2] as usize + qz));
                            out.push((p, *c));
                        }
                        Ok(out)
                    },
                )
                .collect();
            for r in per_leaf {
                for (p, c) in r? {
                    parent.acc[p].add(&c);
                }
            }
        }
    }
    // Coarser levels: the children that exist (an odd edge has one; an axis
    // the level does not halve has one).
    for l in (0..finest - 1).rev() {
        let r = ratio(l);
        let (coarse, fine) = pyramid.split_at_mut(l as usize + 1);
        let (c, f) = (&mut coarse[l as usize], &fine[0]);
        let cd = c.dims;
        let fd = f.dims;
        let nxy = cd[0] as usize * cd[1] as usize;
        c.acc
            .par_chunks_mut(nxy)
            .enumerate()
            .for_each(|(z, slice)| {
                for y in 0..cd[1] {
                    for x in 0..cd[0] {
                        let mut s = Acc::EMPTY;
                        for dz in 0..r[2] {
                            for dy in 0..r[1] {
                                for dx in 0..r[0] {
                                    let (fx, fy, fz) =
                                        (r[0] * x + dx, r[1] * y + dy, r[2] * z as u32 + dz);
                                    if fx < fd[0] && fy < fd[1] && fz < fd[2] {
                                        s.add(&f.acc[f.idx(fx, fy, fz)]);
                                    }
                                }
                            }
                        }
                        slice[x as usize + cd[0] as usize * y as usize] = s;
                    }
                }
            });
    }
    // Per coarser level: the 3x3x3 neighbourhood, then each node's bins.
    for l in 0..finest {
        let level = &pyramid[l as usize];
        let ext = neighbourhood(level);
        let first = geo.first[l as usize] as usize;
        let end = geo
            .first
            .get(l as usize + 1)
            .map_or(entries.len(), |&n| n as usize);
        let out: Vec<Result<NodeErrors, StoreError>> = entries[first..end]
            .par_iter()
            .map_init(
                || (Vec::new(), Vec::new()),
                |(raw, vals), e| node_error(file, path, layout, e, level, &ext, raw, vals),
            )
            .collect();
        for (i, r) in out.into_iter().enumerate() {
            let (own, octants) = r?;
            errors[first + i] = own;
            for (c, err) in octants {
                if let Some(ci) = geo.index(c) {
                    parent_errors[ci] = err;
                }
            }
        }
    }
    Ok(Some(ErrorSections {
        errors,
        parent_errors,
    }))
}

/// Min of `lo` and max of `hi` over each voxel's 3x3x3 neighbourhood (clamped).
fn neighbourhood(src: &Level) -> (Vec<f32>, Vec<f32>) {
    let d = src.dims;
    let mut lo: Vec<f32> = src.acc.iter().map(|c| c.lo).collect();
    let mut hi: Vec<f32> = src.acc.iter().map(|c| c.hi).collect();
    let strides = [1usize, d[0] as usize, d[0] as usize * d[1] as usize];
    for axis in 0..3 {
        let n = d[axis] as usize;
        let st = strides[axis];
        let (plo, phi) = (lo.clone(), hi.clone());
        lo.par_iter_mut()
            .zip(hi.par_iter_mut())
            .enumerate()
            .for_each(|(i, (l, h))| {
                let c = (i / st) % n;
                if c > 0 {
                    *l = l.min(plo[i - st]);
                    *h = h.max(phi[i - st]);
                }
                if c + 1 < n {
                    *l = l.min(plo[i + st]);
                    *h = h.max(phi[i + st]);
                }
            });
    }
    (lo, hi)
}

/// A node's own error record and its children's parent-error records.
type NodeErrors = (NodeError, Vec<(NodeKey, NodeError)>);

#[allow(clippy::too_many_arguments)]
fn node_error(
    file: &File,
    path: &Path,
    layout: &OctreeLayout,
    e: &Entry,
    level: &Level,
    ext: &(Vec<f32>, Vec<f32>),
    raw: &mut Vec<u8>,
    vals: &mut Vec<f32>,
) -> Result<NodeErrors, StoreError> {
    if !brick_values(file, path, layout, e, raw, vals)? {
        return Ok((NodeError::default(), Vec::new()));
    }
    let key: NodeKey = e.key();
    let b = layout.brick as i64;
    let a = layout.apron as i64;
    let side = layout.stored_side() as usize;
    let d = level.dims.map(|v| v as i64);
    let (min, max) = (e.min as f64, e.max as f64);
    let mut bins = [BinStats::default(); ERROR_BINS];
    // Per child (octant): the same statistics over the coarse voxels its
    // region interpolates, binned over this node's range.
    let children = layout.children(key);
    let mut child_bins = vec![[BinStats::default(); ERROR_BINS]; children.len()];
    let mask = layout.split_mask(key.level);
    // Interior voxels 0..=brick (the high one is the first apron voxel).
    let hi_i = b.min(b + a - 1).max(0);
    // The children's halves meet at `brick / 2` of this node's voxels: the
    // low half interpolates voxels up to its ceiling, the high one from its
    // floor.
    let (low_end, high_start) = ((b + 1) / 2, b / 2);
    for k in 0..=hi_i {
        let z = (key.z as i64 * b + k).clamp(0, d[2] - 1) as u32;
        for j in 0..=hi_i {
            let y = (key.y as i64 * b + j).clamp(0, d[1] - 1) as u32;
            for i in 0..=hi_i {
                let x = (key.x as i64 * b + i).clamp(0, d[0] - 1) as u32;
                let c = vals
                    [(k + a) as usize * side * side + (j + a) as usize * side + (i + a) as usize]
                    as f64;
                let p = level.idx(x, y, z);
                let dev = (ext.1[p] as f64 - c).max(c - ext.0[p] as f64).max(0.0);
                let sq = level.acc[p].mean_sq(c);
                let bin = bin_of(c, min, max);
                let add = |st: &mut BinStats| {
                    st.count += 1;
                    st.dev = st.dev.max(dev);
                    st.sum_sq += sq;
                };
                add(&mut bins[bin]);
                // The children whose half of each split axis interpolates
                // the voxel (the middle ones in both halves).
                for (ci, cb) in child_bins.iter_mut().enumerate() {
                    let (mut bit, mut inside) = (0, true);
                    for (axis, v) in [i, j, k].into_iter().enumerate() {
                        if mask & (1 << axis) == 0 {
                            continue;
                        }
                        let high = (ci >> bit) & 1 == 1;
                        bit += 1;
                        inside &= if high { v >= high_start } else { v <= low_end };
                    }
                    if inside {
                        add(&mut cb[bin]);
                    }
                }
            }
        }
    }
    let own = NodeError::encode(&bins, min, max);
    let octants = children
        .iter()
        .zip(&child_bins)
        .map(|(c, cb)| (*c, NodeError::encode(cb, min, max)))
        .collect();
    Ok((own, octants))
}
