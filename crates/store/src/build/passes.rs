//! How the levels are built within the memory bound: the plan (all levels
//! in one streaming pass, or the top level alone in y-bands of brick rows)
//! and the two passes that carry it out (see the module above and
//! `docs/store-format.md`).

use super::level::{LevelBuf, MomentOut, Sink};
use super::spread::{self, MomentFile};
use super::{Ctx, Progress};
use crate::error::StoreError;
use brickray_core::OctreeLayout;
use brickray_io::VolumeReader;
use std::io::Write;
use std::path::Path;

/// How the remaining levels are built.
#[derive(Debug, Clone, Copy)]
pub(super) enum Plan {
    /// All levels `0..=top` in one streaming pass, reading `per` slices a step.
    Stream { per: u32, need: u64 },
    /// Level `top` alone, `band_bricks` brick rows per pass.
    Bands { band_bricks: u32, need: u64 },
}

impl Plan {
    pub(super) fn need(&self) -> u64 {
        match *self {
            Plan::Stream { need, .. } | Plan::Bands { need, .. } => need,
        }
    }
}

/// Slices read per step for slices of `bytes` (at most ~8 MiB, at most a brick).
fn per_step(bytes: u64, brick: u32) -> u32 {
    ((8u64 << 20) / bytes.max(1)).clamp(1, brick as u64) as u32
}

/// Rows a band of `band_bricks` brick rows starting at brick row `by0` holds.
fn band_rows(layout: &OctreeLayout, ny: u32, by0: u32, by1: u32) -> (u32, u32) {
    let b = layout.brick as u64;
    let a = layout.apron as u64;
    let lo = (by0 as u64 * b).saturating_sub(a);
    let hi = (by1 as u64 * b + a.max(1)).min(ny as u64);
    (lo as u32, hi as u32)
}

/// Bytes one streaming pass over levels `0..=top` needs, the moment windows
/// of a build that records spreads included.
fn stream_need(layout: &OctreeLayout, top: u8, fixed: u64, spread: bool) -> u64 {
    let d = layout.level_dims(top);
    let size = layout.dtype().size() as u64;
    let slice = d[0] as u64 * d[1] as u64 * size;
    let side = layout.stored_side() as u64;
    let per = per_step(slice, layout.brick);
    // Rolling windows: brick + 2 apron + 2 slices per level plus the slices read
    // in one step and as many recycled buffers; levels shrink 4x.
    let window = side + 2 + 2 * per as u64;
    let values = if layout.is_isotropic() {
        window * slice * 4 / 3
    } else {
        // An anisotropic pyramid's levels need not shrink 4x: sum them.
        let all: u64 = (0..=top)
            .map(|l| {
                let d = layout.level_dims(l);
                d[0] as u64 * d[1] as u64 * size
            })
            .sum();
        window * all
    };
    // The moments (16 bytes a voxel) of every level that has them.
    let moments = if spread {
        spread::window_bytes(layout, top, window)
    } else {
        0
    };
    values.saturating_add(moments).saturating_add(fixed)
}

/// Chooses how to build levels `0..=top` within `bound` bytes (with the
/// moment windows of a build that records spreads).
pub(super) fn plan(
    layout: &OctreeLayout,
    top: u8,
    bound: u64,
    fixed: u64,
    spread: bool,
) -> Result<Plan, StoreError> {
    let d = layout.level_dims(top);
    let size = layout.dtype().size() as u64;
    let slice = d[0] as u64 * d[1] as u64 * size;
    let side = layout.stored_side() as u64;
    let per = per_step(slice, layout.brick);
    let need = stream_need(layout, top, fixed, spread);
    if need <= bound || top == 0 {
        return if need <= bound {
            Ok(Plan::Stream { per, need })
        } else {
            Err(StoreError::MemoryBound {
                needed: need,
                bound,
                slab: side * slice,
            })
        };
    }
    // Bands: one full input slice to read into, the band window, one band of
    // coarser rows; with spreads the coarser rows' moments (and their
    // bytes), and when `top` is not the finest level its band's moment
    // window and the bytes one band slice of them is read through.
    let gy = d[1].div_ceil(layout.brick);
    let finest = top + 1 == layout.levels;
    let band_need = |bb: u32| {
        let (lo, hi) = band_rows(layout, d[1], 0, bb.min(gy));
        let voxels = (hi - lo) as u64 * d[0] as u64;
        let band = voxels * size;
        let per = per_step(band, layout.brick) as u64;
        let window = side + 2 + 2 * per;
        let moments = match (spread, finest) {
            (false, _) => 0,
            (true, true) => 2 * voxels * 16,
            (true, false) => (window + 3) * voxels * 16,
        };
        slice + window * band + band / 2 + moments + fixed
    };
    let mut lo = 1u32;
    if band_need(lo) > bound {
        return Err(StoreError::MemoryBound {
            needed: band_need(lo),
            bound,
            slab: side * slice,
        });
    }
    let mut hi = gy;
    while lo < hi {
        let mid = (lo + hi).div_ceil(2);
        if band_need(mid) <= bound {
            lo = mid
        } else {
            hi = mid - 1
        }
    }
    Ok(Plan::Bands {
        band_bricks: lo,
        need: band_need(lo),
    })
}

/// Builds levels `0..=top` from the level-`top` volume in one streaming pass.
pub(super) fn run_stream<W: Write>(
    ctx: &mut Ctx,
    input: &mut dyn VolumeReader,
    moments_in: Option<&MomentFile>,
    top: u8,
    per: u32,
    w: &mut W,
    pb: &Progress<'_>,
) -> Result<(), StoreError> {
    let layout = ctx.layout.clone();
    let mut levels: Vec<LevelBuf> = (0..=top).map(|l| LevelBuf::new(&layout, l, per)).collect();
    let finest = top as usize;
    let d = layout.level_dims(top);
    let slice_bytes = d[0] as usize * d[1] as usize * layout.dtype().size();
    let full = top + 1 == layout.levels;
    let mut bytes = Vec::new();
    let mut z = 0;
    while z < d[2] {
        let z1 = (z + per).min(d[2]);
        for zi in z..z1 {
            let mut s = levels[finest].take_buffer(slice_bytes);
            input.read_slices(zi, zi + 1, &mut s)?;
            levels[finest].slices.push_back(s);
            // Level `top`'s moments, when it is not the finest level.
            if let Some(mf) = moments_in {
                let mut m = levels[finest].take_moments(0);
                mf.read_rows(zi, (0, d[1]), &mut m, &mut bytes)?;
                levels[finest].moments.push_back(m);
            }
        }
        z = z1;
        for l in (0..=finest).rev() {
            let (coarse, fine) = levels.split_at_mut(l);
            let sink = match coarse.last_mut() {
                Some(p) => Sink::Level(p),
                None => Sink::None,
            };
            fine[0].process(ctx, sink, w)?;
        }
        if full {
            pb.set_position(z as u64 * d[0] as u64 * d[1] as u64);
        }
    }
    Ok(())
}

/// The temporary files of one banded level.
pub(super) struct Files<'a> {
    /// The level `top - 1` volume, written.
    pub(super) values: &'a std::fs::File,
    /// Its path.
    pub(super) path: &'a Path,
    /// Level `top`'s moments (spreads recorded, `top` not the finest level).
    pub(super) moments_in: Option<&'a MomentFile>,
    /// Level `top - 1`'s moments, written (spreads recorded).
    pub(super) moments_out: Option<&'a MomentFile>,
}

/// Builds level `top` in bands of `band_bricks` brick rows (one pass over the
/// input each), writing the level `top - 1` volume (and its moments) to
/// `files`.
pub(super) fn run_bands<W: Write>(
    ctx: &mut Ctx,
    input: &mut dyn VolumeReader,
    top: u8,
    band_bricks: u32,
    files: Files<'_>,
    w: &mut W,
    pb: &Progress<'_>,
) -> Result<(), StoreError> {
    let layout = ctx.layout.clone();
    let d = layout.level_dims(top);
    let pd = layout.level_dims(top - 1);
    let size = layout.dtype().size();
    let gy = d[1].div_ceil(layout.brick);
    let bands = gy.div_ceil(band_bricks);
    let full = top + 1 == layout.levels;
    let mut slice = vec![0u8; d[0] as usize * d[1] as usize * size];
    let mut out_rows = Vec::new();
    let (mut moment_rows, mut moment_bytes) = (Vec::new(), Vec::new());
    for band in 0..bands {
        let by0 = band * band_bricks;
        let by1 = (by0 + band_bricks).min(gy);
        let (r0, r1) = band_rows(&layout, d[1], by0, by1);
        // Coarser rows this band filters: every row whose source rows start here.
        let b = layout.brick as u64;
        let hy = if layout.split_mask(top - 1) & 2 != 0 {
            2
        } else {
            1
        };
        let j0 = ((by0 as u64 * b).div_ceil(hy)).min(pd[1] as u64) as u32;
        let j1 = if by1 == gy {
            pd[1]
        } else {
            ((by1 as u64 * b).div_ceil(hy)).min(pd[1] as u64) as u32
        };
        let row_bytes = d[0] as usize * size;
        let band_bytes = (r1 - r0) as usize * row_bytes;
        let per = per_step(band_bytes as u64, layout.brick);
        let mut lb = LevelBuf::new(&layout, top, per);
        lb.row0 = r0;
        lb.nrows = r1 - r0;
        lb.by = (by0, by1);
        let mut z = 0;
        while z < d[2] {
            let z1 = (z + per).min(d[2]);
            for zi in z..z1 {
                input.read_slices(zi, zi + 1, &mut slice)?;
                let mut s = lb.take_buffer(band_bytes);
                s.copy_from_slice(&slice[r0 as usize * row_bytes..r1 as usize * row_bytes]);
                lb.slices.push_back(s);
                if let Some(mf) = files.moments_in {
                    let mut m = lb.take_moments(0);
                    mf.read_rows(zi, (r0, r1), &mut m, &mut moment_bytes)?;
                    lb.moments.push_back(m);
                }
            }
            z = z1;
            let sink = if j1 > j0 {
                Sink::File {
                    file: files.values,
                    path: files.path,
                    rows: (j0, j1),
                    buf: &mut out_rows,
                    moments: files.moments_out.map(|file| MomentOut {
                        file,
                        buf: &mut moment_rows,
                        bytes: &mut moment_bytes,
                    }),
                }
            } else {
                Sink::None
            };
            lb.process(ctx, sink, w)?;
            if full {
                let done = (band as u64 * d[2] as u64 + z as u64) * layout.volume.voxel_count();
                pb.set_position(done / (bands as u64 * d[2] as u64));
            }
        }
    }
    Ok(())
}
