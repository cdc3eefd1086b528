//! The error sections of a label store: per node, the share of the finest
//! voxels of its region whose label differs from the node's voxel covering
//! them (`brickray_core::labels::changed_share` per node), and the same share
//! when its region is drawn from its parent's brick; each held in a
//! [`NodeError`] as [`NodeError::from_label_share`] (`docs/store-format.md`).
//!
//! Every level is decoded from the written bricks into one dense array of
//! ids (4 bytes per voxel of every level, about 4.6 bytes per finest voxel);
//! when that exceeds the build's memory bound the sections are left out and
//! the store refines by geometry. A coarse voxel `x` of level `l` covers the
//! finest voxels `x * s ..(x + 1) * s` per axis, `s` the product of the
//! levels' split ratios below it (the mode pyramid's children).

use super::errors::{ErrorSections, brick_values};
use crate::NO_ENTRY_LEVEL;
use crate::error::StoreError;
use crate::format::{Entry, TableGeometry};
use brickray_core::{NodeError, OctreeLayout};
use rayon::prelude::*;
use std::fs::File;
use std::path::Path;

/// Bytes the pass needs for `layout`.
pub(super) fn memory_needed(layout: &OctreeLayout) -> u64 {
    (0..layout.levels)
        .map(|l| {
            layout
                .level_dims(l)
                .iter()
                .map(|&d| d as u64)
                .product::<u64>()
        })
        .sum::<u64>()
        .saturating_mul(4)
}

/// A node's table index, its decoded brick and whether it holds one.
type Decoded = (usize, Vec<f32>, bool);

/// One level's ids, x fastest.
struct Ids {
    dims: [u32; 3],
    ids: Vec<u32>,
}

impl Ids {
    fn at(&self, x: u32, y: u32, z: u32) -> u32 {
        self.ids
            [x as usize + self.dims[0] as usize * (y as usize + self.dims[1] as usize * z as usize)]
    }
}

/// The label error sections of every node (table order), or `None` when the
/// pass would exceed `memory_bound`.
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
    let n = entries.len();
    let mut errors = vec![NodeError::default(); n];
    let mut parent_errors = vec![NodeError::default(); n];
    let levels = layout.levels;
    let finest = levels - 1;
    let b = layout.brick;
    let a = layout.apron as usize;
    let side = layout.stored_side() as usize;
    // Decode every level.
    let mut pyramid = Vec::with_capacity(levels as usize);
    for l in 0..levels {
        let dims = layout.level_dims(l);
        let mut ids = vec![0u32; dims.iter().map(|&d| d as usize).product()];
        let first = geo.first[l as usize] as usize;
        let end = geo.first.get(l as usize + 1).map_or(n, |&f| f as usize);
        let bricks: Vec<Result<Decoded, StoreError>> = entries[first..end]
            .par_iter()
            .enumerate()
            .map_init(Vec::new, |raw, (i, e)| {
                let mut vals = Vec::new();
                let has = brick_values(file, path, layout, e, raw, &mut vals)?;
                Ok((first + i, vals, has))
            })
            .collect();
        for r in bricks {
            let (i, vals, has) = r?;
            let e = &entries[i];
            if e.level == NO_ENTRY_LEVEL {
                continue;
            }
            let key = e.key();
            for k in 0..b.min(dims[2].saturating_sub(key.z * b)) {
                for j in 0..b.min(dims[1].saturating_sub(key.y * b)) {
                    for i in 0..b.min(dims[0].saturating_sub(key.x * b)) {
                        let v = if has {
                            vals[(k as usize + a) * side * side
                                + (j as usize + a) * side
                                + i as usize
                                + a]
                        } else {
                            e.min
                        };
                        let (x, y, z) = (key.x * b + i, key.y * b + j, key.z * b + k);
                        ids[x as usize
                            + dims[0] as usize * (y as usize + dims[1] as usize * z as usize)] =
                            v as u32;
                    }
                }
            }
        }
        pyramid.push(Ids { dims, ids });
    }
    // Per level, finest voxels per coarse voxel along each axis.
    let scale: Vec<[u32; 3]> = (0..levels)
        .map(|l| {
            std::array::from_fn(|axis| {
                (l..finest)
                    .map(|m| 1 + ((layout.split_mask(m) >> axis) & 1) as u32)
                    .product()
            })
        })
        .collect();
    let fine = &pyramid[finest as usize];
    let fd = fine.dims;
    // The share of node `e`'s finest voxels whose label differs from level
    // `l`'s voxel covering them.
    let share = |e: &Entry, l: u8| -> f64 {
        let key = e.key();
        let s = scale[key.level as usize];
        let c = &pyramid[l as usize];
        let cs = scale[l as usize];
        let lo = [key.x * b * s[0], key.y * b * s[1], key.z * b * s[2]];
        let hi: [u32; 3] =
            std::array::from_fn(|ax| ((([key.x, key.y, key.z][ax] + 1) * b) * s[ax]).min(fd[ax]));
        let (mut changed, mut count) = (0u64, 0u64);
        for z in lo[2]..hi[2] {
            for y in lo[1]..hi[1] {
                for x in lo[0]..hi[0] {
                    count += 1;
                    if fine.at(x, y, z) != c.at(x / cs[0], y / cs[1], z / cs[2]) {
                        changed += 1;
                    }
                }
            }
        }
        if count == 0 {
            0.0
        } else {
            changed as f64 / count as f64
        }
    };
    let out: Vec<(NodeError, NodeError)> = entries
        .par_iter()
        .map(|e| {
            if e.level == NO_ENTRY_LEVEL {
                return (NodeError::default(), NodeError::default());
            }
            let own = if e.level < finest {
                NodeError::from_label_share(share(e, e.level))
            } else {
                NodeError::default()
            };
            let parent = if e.level > 0 {
                NodeError::from_label_share(share(e, e.level - 1))
            } else {
                NodeError::default()
            };
            (own, parent)
        })
        .collect();
    for (i, (own, parent)) in out.into_iter().enumerate() {
        errors[i] = own;
        parent_errors[i] = parent;
    }
    Ok(Some(ErrorSections {
        errors,
        parent_errors,
    }))
}
