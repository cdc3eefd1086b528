//! Anisotropic pyramids: per-level split masks of the brick octree.
//!
//! The isotropic octree ([`OctreeLayout::new`]) halves all three axes at every
//! level. An anisotropic layout ([`OctreeLayout::anisotropic`]) halves, going
//! from the finest level up, only the axes whose voxel side is more than
//! `sqrt(2)` times smaller than the largest side, until the voxel is
//! near-isotropic (every side within `sqrt(2)` of the largest); from there it
//! halves all axes (the rule of OME-Zarr and Neuroglancer multiscale pyramids).
//! Bricks stay cubic in voxels, so a level that halves `k` axes gives its nodes
//! `2^k` children, and node positions along axis `a` at level `l` run over
//! `0..2^H_a(l)`, `H_a(l)` being the number of levels above `l` that halve `a`.
//!
//! **Split mask** of level `l` (3 bits: bit 0 = x, 1 = y, 2 = z): the axes halved
//! between level `l` and level `l + 1`, i.e. the axes along which a node of level
//! `l` is split into its children (0 for the finest level). **Child index**: the
//! bits of `i` in `0..2^popcount(mask)` enumerate the split axes in the order x,
//! y, z (lowest bit first); with all axes split this is today's octant index
//! (bit 0 = +x, bit 1 = +y, bit 2 = +z).

use crate::brick::{NodeKey, OctreeLayout};
use crate::volume::VolumeDesc;
use thiserror::Error;

/// The split mask that halves every axis.
pub const ALL_AXES: u8 = 0b111;

/// Most levels a layout may have.
pub const MAX_LEVELS: u8 = 32;

/// A voxel side is halved while it is below the largest side divided by this.
const HALVE_BELOW: f64 = std::f64::consts::SQRT_2;

/// An invalid set of split masks.
#[derive(Debug, Clone, Error, PartialEq, Eq)]
#[non_exhaustive]
pub enum LayoutError {
    /// A mask is 0 or has bits beyond the three axes.
    #[error("split mask {mask:#05b} of level {level} is not in 1..=7")]
    BadMask {
        /// The level.
        level: u8,
        /// The mask.
        mask: u8,
    },
    /// More masks than levels allowed.
    #[error("{count} split masks: at most {max}")]
    TooManyLevels {
        /// Masks given.
        count: usize,
        /// Most allowed (`MAX_LEVELS - 1`).
        max: usize,
    },
    /// The masks' halvings do not cover the volume with one root brick, or
    /// cover it with levels to spare.
    #[error(
        "split masks halve the axes {halvings:?} times: they do not fit dims {dims:?} with bricks of {brick}"
    )]
    Coverage {
        /// Halvings per axis.
        halvings: [u32; 3],
        /// The volume's dims.
        dims: [u32; 3],
        /// Interior voxels per brick side.
        brick: u32,
    },
}

/// The split masks of the anisotropic pyramid of a `dims` grid with voxel
/// `spacing` and bricks of `brick` interior voxels, root level first (one mask
/// per level but the finest). Going up from the finest level, each level halves
/// the axes whose current voxel side is below `largest / sqrt(2)`, or all axes
/// when there is none, until one brick covers the volume. Non-finite or
/// non-positive spacings count as 1.
pub fn anisotropic_split_masks(dims: [u32; 3], spacing: [f32; 3], brick: u32) -> Vec<u8> {
    let brick = brick.max(1) as u64;
    let mut side: [f64; 3] = spacing.map(|s| {
        if s.is_finite() && s > 0.0 {
            s as f64
        } else {
            1.0
        }
    });
    let mut h = [0u32; 3];
    let fits = |h: &[u32; 3]| (0..3).all(|a| h[a] >= 63 || brick << h[a] >= dims[a].max(1) as u64);
    let mut masks = Vec::new();
    while !fits(&h) {
        let largest = side.iter().fold(0.0f64, |m, s| m.max(*s));
        let mut mask = 0u8;
        // Past MAX_LEVELS / 2 levels (absurd spacing ratios) halve all axes so
        // the level count stays bounded.
        if masks.len() < (MAX_LEVELS / 2) as usize {
            for (a, s) in side.iter().enumerate() {
                if s * HALVE_BELOW < largest {
                    mask |= 1 << a;
                }
            }
        }
        if mask == 0 {
            mask = ALL_AXES;
        }
        for a in 0..3 {
            if mask & (1 << a) != 0 {
                side[a] *= 2.0;
                h[a] += 1;
            }
        }
        masks.push(mask);
    }
    masks.reverse();
    masks
}

/// The children of a node: up to eight keys, in child-index order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Children {
    keys: [NodeKey; 8],
    len: u8,
}

impl std::ops::Deref for Children {
    type Target = [NodeKey];
    fn deref(&self) -> &[NodeKey] {
        &self.keys[..self.len as usize]
    }
}

impl<'a> IntoIterator for &'a Children {
    type Item = &'a NodeKey;
    type IntoIter = std::slice::Iter<'a, NodeKey>;
    fn into_iter(self) -> Self::IntoIter {
        self.keys[..self.len as usize].iter()
    }
}

impl OctreeLayout {
    /// The anisotropic layout of a volume: split masks from its dims and spacing
    /// ([`anisotropic_split_masks`]). A volume whose voxels are near-isotropic
    /// (every side within `sqrt(2)` of the largest) gets exactly
    /// [`OctreeLayout::new`]'s layout.
    pub fn anisotropic(volume: VolumeDesc, brick: u32, apron: u32) -> OctreeLayout {
        let masks = anisotropic_split_masks(volume.dims, volume.spacing, brick);
        let mut layout = OctreeLayout::new(volume, brick, apron);
        layout.levels = masks.len() as u8 + 1;
        layout.splits = if masks.iter().all(|m| *m == ALL_AXES) {
            Vec::new()
        } else {
            masks
        };
        layout
    }

    /// The layout with explicit split masks (root level first, one per level but
    /// the finest), as a store header records them. All-axes masks give
    /// [`OctreeLayout::new`]'s layout; masks that do not cover the volume with one
    /// root brick, or that leave a level with all axes already covered, are an
    /// error.
    pub fn with_split_masks(
        volume: VolumeDesc,
        brick: u32,
        apron: u32,
        masks: &[u8],
    ) -> Result<OctreeLayout, LayoutError> {
        if masks.len() >= MAX_LEVELS as usize {
            return Err(LayoutError::TooManyLevels {
                count: masks.len(),
                max: MAX_LEVELS as usize - 1,
            });
        }
        for (l, m) in masks.iter().enumerate() {
            if *m == 0 || *m > ALL_AXES {
                return Err(LayoutError::BadMask {
                    level: l as u8,
                    mask: *m,
                });
            }
        }
        let mut layout = OctreeLayout::new(volume, brick, apron);
        layout.levels = masks.len() as u8 + 1;
        layout.splits = if masks.iter().all(|m| *m == ALL_AXES) {
            Vec::new()
        } else {
            masks.to_vec()
        };
        let b = layout.brick as u64;
        let h = layout.halvings(layout.levels - 1);
        let dims = layout.volume.dims;
        let covers = |h: [u32; 3]| (0..3).all(|a| b << h[a] >= dims[a].max(1) as u64);
        // Covered, and not already covered without the root level.
        let m0 = layout.split_mask(0);
        let tight =
            layout.levels == 1 || !covers(std::array::from_fn(|a| h[a] - ((m0 >> a) & 1) as u32));
        if !covers(h) || !tight {
            return Err(LayoutError::Coverage {
                halvings: h,
                dims,
                brick: layout.brick,
            });
        }
        Ok(layout)
    }

    /// True when every level halves all three axes (the octree of
    /// [`OctreeLayout::new`]).
    pub fn is_isotropic(&self) -> bool {
        self.splits.is_empty()
    }

    /// The split masks, root level first, one per level but the finest.
    pub fn split_masks(&self) -> Vec<u8> {
        (0..self.levels.saturating_sub(1))
            .map(|l| self.split_mask(l))
            .collect()
    }

    /// The axes halved between `level` and `level + 1` (bit 0 = x, 1 = y, 2 = z):
    /// the axes along which a node of `level` is split; 0 at and below the
    /// finest level.
    pub fn split_mask(&self, level: u8) -> u8 {
        if level.saturating_add(1) >= self.levels {
            0
        } else if self.splits.is_empty() {
            ALL_AXES
        } else {
            self.splits[level as usize]
        }
    }

    /// Number of children of a node of `level`: `2^popcount(split_mask(level))`
    /// (1 at the finest level, which has none: see [`OctreeLayout::children`]).
    pub fn child_count(&self, level: u8) -> u32 {
        1 << self.split_mask(level).count_ones()
    }

    /// Per axis, the number of levels above `level` that halve it (`level` per
    /// axis in the isotropic octree).
    pub fn halvings(&self, level: u8) -> [u32; 3] {
        if self.splits.is_empty() {
            return [level as u32; 3];
        }
        let mut h = [0u32; 3];
        for l in 0..level.min(self.levels.saturating_sub(1)) {
            let m = self.split_mask(l);
            for (a, ha) in h.iter_mut().enumerate() {
                *ha += ((m >> a) & 1) as u32;
            }
        }
        h
    }

    /// Node positions per axis at `level`: `2^halvings(level)`.
    pub fn nodes_per_axis(&self, level: u8) -> [u64; 3] {
        self.halvings(level).map(|h| 1u64 << h)
    }

    /// Finest-level voxels per side of the octree box, per axis.
    pub fn cube_voxels_axes(&self) -> [u64; 3] {
        let b = self.brick as u64;
        self.halvings(self.levels - 1).map(|h| b << h)
    }

    /// Finest-level voxels per voxel of `level`, per axis (powers of two).
    pub fn voxel_factor(&self, level: u8) -> [f64; 3] {
        let finest = self.halvings(self.levels - 1);
        let here = self.halvings(level.min(self.levels - 1));
        std::array::from_fn(|a| (1u64 << (finest[a] - here[a])) as f64)
    }

    /// Child `i` of `key` (`i < child_count(key.level)`; see the module docs for
    /// the numbering). Equals [`NodeKey::child`] in the isotropic octree.
    pub fn child(&self, key: NodeKey, i: u8) -> NodeKey {
        let m = self.split_mask(key.level);
        let mut p = [key.x, key.y, key.z];
        let mut bit = 0;
        for (a, pa) in p.iter_mut().enumerate() {
            if m & (1 << a) != 0 {
                *pa = *pa * 2 + ((i >> bit) & 1) as u32;
                bit += 1;
            }
        }
        NodeKey::new(key.level + 1, p[0], p[1], p[2])
    }

    /// The children of `key` in child-index order (none at the finest level).
    pub fn children(&self, key: NodeKey) -> Children {
        let mut keys = [key; 8];
        let len = if key.level + 1 >= self.levels {
            0
        } else {
            let n = self.child_count(key.level);
            for i in 0..n {
                keys[i as usize] = self.child(key, i as u8);
            }
            n as u8
        };
        Children { keys, len }
    }

    /// The parent of `key`, `None` for the root.
    pub fn parent(&self, key: NodeKey) -> Option<NodeKey> {
        if key.level == 0 {
            return None;
        }
        let m = self.split_mask(key.level - 1);
        let mut p = [key.x, key.y, key.z];
        for (a, pa) in p.iter_mut().enumerate() {
            if m & (1 << a) != 0 {
                *pa /= 2;
            }
        }
        Some(NodeKey::new(key.level - 1, p[0], p[1], p[2]))
    }

    /// Index of `key` among its parent's children (0 for the root).
    pub fn child_index(&self, key: NodeKey) -> u8 {
        if key.level == 0 {
            return 0;
        }
        let m = self.split_mask(key.level - 1);
        let p = [key.x, key.y, key.z];
        let mut i = 0u8;
        let mut bit = 0;
        for (a, pa) in p.iter().enumerate() {
            if m & (1 << a) != 0 {
                i |= ((pa & 1) as u8) << bit;
                bit += 1;
            }
        }
        i
    }

    /// The node's box in octree unit-box coordinates: `(min corner, size)` per
    /// axis.
    pub fn unit_box(&self, key: NodeKey) -> ([f64; 3], [f64; 3]) {
        let n = self.nodes_per_axis(key.level);
        let p = [key.x, key.y, key.z];
        let size: [f64; 3] = std::array::from_fn(|a| 1.0 / n[a] as f64);
        (std::array::from_fn(|a| p[a] as f64 * size[a]), size)
    }
}

#[cfg(test)]
#[path = "pyramid_tests.rs"]
mod tests;
