//! A brick source with spreads ([`SpreadSource`]): another source's bricks,
//! and the spread of each coarse voxel computed in memory from the finest
//! level ([`MomentGrid`]), for volumes that fit in memory.

use super::MomentGrid;
use crate::{
    BrickError, BrickSource, CancelToken, NodeInfo, NodeKey, OctreeLayout, Volume, VolumeKind,
};
use std::sync::Arc;
use thiserror::Error;

/// Why a [`SpreadSource`] could not be made.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum SpreadError {
    /// The volume is not the source's finest level.
    #[error("the volume does not match the source: {what} is {volume}, the source's {source_has}")]
    Mismatch {
        /// What differs (dims, dtype, value range).
        what: &'static str,
        /// The volume's.
        volume: String,
        /// The source's.
        source_has: String,
    },
    /// Label maps have no spread (their levels are the mode of their
    /// children, and a label id has no mean).
    #[error("a label map has no spread")]
    Labels,
    /// Channel volumes are not supported.
    #[error("a channel volume has no spread (one per channel is not supported)")]
    Channels,
    /// A level of the moments' pyramid does not have the dims the layout
    /// gives it (a layout this pyramid rule does not describe).
    #[error("level {level} of the spread pyramid has dims {grid:?}, the layout {layout:?}")]
    Level {
        /// The level.
        level: u8,
        /// The pyramid's dims.
        grid: [u32; 3],
        /// The layout's.
        layout: [u32; 3],
    },
}

/// `inner`'s bricks with the spread of every coarse voxel
/// ([`BrickSource::read_spread`]), computed once from the finest level held
/// in memory: `E[x]` and `E[x^2]` carried up the pyramid with the layout's
/// split masks and the store's edge rule ([`MomentGrid::downsample`]). The
/// spreads are kept as half floats, two bytes per coarse voxel (about a
/// seventh of the finest level's voxels for an octree); the finest level's
/// is 0. Building it reads every voxel once and holds the finest level's
/// moments (16 bytes a voxel) while it runs.
pub struct SpreadSource {
    inner: Arc<dyn BrickSource>,
    /// Per level (root first): its dims and spreads as half-float bits, x
    /// fastest; empty at the finest level.
    levels: Vec<([u32; 3], Vec<u16>)>,
}

impl std::fmt::Debug for SpreadSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SpreadSource")
            .field("layout", self.inner.layout())
            .finish_non_exhaustive()
    }
}

impl SpreadSource {
    /// `inner`'s bricks with spreads computed from `finest`, the volume
    /// `inner` stores (same dims, dtype and value range).
    pub fn new(inner: Arc<dyn BrickSource>, finest: &Volume) -> Result<SpreadSource, SpreadError> {
        let layout = inner.layout().clone();
        let (v, d) = (&layout.volume, finest.desc());
        if layout.is_channel_volume() {
            return Err(SpreadError::Channels);
        }
        if v.kind.is_labels() || d.kind != VolumeKind::Intensity {
            return Err(SpreadError::Labels);
        }
        let mismatch = |what, a: String, b: String| {
            Err(SpreadError::Mismatch {
                what,
                volume: a,
                source_has: b,
            })
        };
        if d.dims != v.dims {
            return mismatch("dims", format!("{:?}", d.dims), format!("{:?}", v.dims));
        }
        if d.dtype != v.dtype {
            return mismatch("dtype", format!("{:?}", d.dtype), format!("{:?}", v.dtype));
        }
        if d.value_range.map(f32::to_bits) != v.value_range.map(f32::to_bits) {
            return mismatch(
                "value range",
                format!("{:?}", d.value_range),
                format!("{:?}", v.value_range),
            );
        }
        let finest_level = layout.levels.saturating_sub(1);
        let mut levels = vec![([0u32; 3], Vec::new()); layout.levels as usize];
        levels[finest_level as usize].0 = v.dims;
        let mut grid = MomentGrid::from_volume(finest);
        for level in (0..finest_level).rev() {
            grid = grid.downsample(layout.split_mask(level));
            if grid.dims() != layout.level_dims(level) {
                return Err(SpreadError::Level {
                    level,
                    grid: grid.dims(),
                    layout: layout.level_dims(level),
                });
            }
            let bits = grid
                .sigmas()
                .into_iter()
                .map(|s| half::f16::from_f32(s).to_bits())
                .collect();
            levels[level as usize] = (grid.dims(), bits);
        }
        Ok(SpreadSource { inner, levels })
    }

    /// The source whose bricks this one serves.
    pub fn inner(&self) -> &Arc<dyn BrickSource> {
        &self.inner
    }
}

impl BrickSource for SpreadSource {
    fn layout(&self) -> &OctreeLayout {
        self.inner.layout()
    }

    fn node(&self, key: NodeKey) -> Result<NodeInfo, BrickError> {
        self.inner.node(key)
    }

    fn nodes(&self, keys: &[NodeKey]) -> Vec<Result<NodeInfo, BrickError>> {
        self.inner.nodes(keys)
    }

    fn read_brick(&self, key: NodeKey, out: &mut [u8]) -> Result<(), BrickError> {
        self.inner.read_brick(key, out)
    }

    fn batch_size(&self) -> usize {
        self.inner.batch_size()
    }

    fn read_bricks(
        &self,
        keys: &[NodeKey],
        outs: &mut [&mut [u8]],
        cancel: &CancelToken,
    ) -> Vec<Result<(), BrickError>> {
        self.inner.read_bricks(keys, outs, cancel)
    }

    fn has_spread(&self) -> bool {
        true
    }

    fn read_spread(&self, key: NodeKey, out: &mut [u16]) -> Result<(), BrickError> {
        let layout = self.inner.layout();
        let side = layout.stored_side() as usize;
        if out.len() != side * side * side {
            return Err(BrickError::BufferSize {
                expected: side * side * side * 2,
                actual: out.len() * 2,
            });
        }
        let Some((dims, bits)) = self.levels.get(key.level as usize) else {
            return Err(BrickError::OutOfRange { key });
        };
        if bits.is_empty() || !layout.in_volume(key) {
            out.fill(0);
            return Ok(());
        }
        let (b, a) = (layout.brick as i64, layout.apron as i64);
        let origin = [key.x, key.y, key.z].map(|c| c as i64 * b - a);
        let at = |axis: usize, i: usize| (origin[axis] + i as i64).clamp(0, dims[axis] as i64 - 1);
        let (nx, ny) = (dims[0] as i64, dims[1] as i64);
        for k in 0..side {
            let z = at(2, k);
            for j in 0..side {
                let y = at(1, j);
                let row = &mut out[(k * side + j) * side..][..side];
                for (i, o) in row.iter_mut().enumerate() {
                    *o = bits[(at(0, i) + nx * (y + ny * z)) as usize];
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{DType, VolumeData, VolumeDesc};

    /// A brick source over a volume's finest level only, enough for the
    /// spread's geometry (its bricks are never read here).
    struct Bare(OctreeLayout);

    impl BrickSource for Bare {
        fn layout(&self) -> &OctreeLayout {
            &self.0
        }
        fn node(&self, key: NodeKey) -> Result<NodeInfo, BrickError> {
            Err(BrickError::OutOfRange { key })
        }
        fn read_brick(&self, key: NodeKey, _: &mut [u8]) -> Result<(), BrickError> {
            Err(BrickError::OutOfRange { key })
        }
    }

    fn volume(dims: [u32; 3], f: impl Fn(u32, u32, u32) -> u8) -> Volume {
        let mut data = Vec::new();
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    data.push(f(x, y, z));
                }
            }
        }
        Volume::new(
            VolumeDesc {
                dims,
                spacing: [1.0; 3],
                dtype: DType::U8,
                value_range: [0.0, 255.0],
                kind: VolumeKind::Intensity,
            },
            VolumeData::U8(data),
        )
        .unwrap()
    }

    fn spread_of(src: &SpreadSource, key: NodeKey) -> Vec<f32> {
        let side = src.layout().stored_side() as usize;
        let mut out = vec![7u16; side * side * side];
        src.read_spread(key, &mut out).unwrap();
        out.iter()
            .map(|&b| half::f16::from_bits(b).to_f32())
            .collect()
    }

    /// A checkerboard of 0 and 255: every coarse voxel of the first coarse
    /// level mixes four of each, spread 0.5; the finest level's is 0; the
    /// bricks' apron clamps to the level's edge.
    #[test]
    fn a_checkerboard_spreads_half_the_range_at_every_coarse_level() {
        let vol = volume(
            [16, 16, 16],
            |x, y, z| if (x + y + z) % 2 == 0 { 0 } else { 255 },
        );
        let layout = OctreeLayout::new(vol.desc().clone(), 8, 1);
        let src = SpreadSource::new(Arc::new(Bare(layout.clone())), &vol).unwrap();
        assert!(src.has_spread());
        let root = spread_of(&src, NodeKey::ROOT);
        assert!(root.iter().all(|&s| (s - 0.5).abs() < 1e-3), "{root:?}");
        let finest = NodeKey {
            level: 1,
            x: 1,
            y: 0,
            z: 1,
        };
        assert!(spread_of(&src, finest).iter().all(|&s| s == 0.0));
    }

    /// A volume whose halves differ: the coarse voxels on the boundary
    /// spread, the others do not, at the positions the store cuts (apron
    /// voxels clamped to the level's edge).
    #[test]
    fn spreads_sit_where_the_store_cuts_the_brick() {
        let vol = volume([16, 16, 16], |x, _, _| if x < 7 { 0 } else { 255 });
        let layout = OctreeLayout::new(vol.desc().clone(), 8, 1);
        let src = SpreadSource::new(Arc::new(Bare(layout.clone())), &vol).unwrap();
        let side = layout.stored_side() as usize;
        let root = spread_of(&src, NodeKey::ROOT);
        for k in 0..side {
            for j in 0..side {
                for i in 0..side {
                    // Stored voxel i is level voxel i - 1 (apron 1), clamped.
                    let x = (i as i64 - 1).clamp(0, 7);
                    let s = root[(k * side + j) * side + i];
                    // Level voxel 3 covers finest 6 (0) and 7 (255).
                    let want = if x == 3 { 0.5 } else { 0.0 };
                    assert!((s - want).abs() < 1e-3, "voxel {i} {j} {k}: {s}");
                }
            }
        }
    }

    #[test]
    fn a_volume_that_is_not_the_source_s_is_refused() {
        let vol = volume([16, 16, 16], |_, _, _| 3);
        let other = volume([16, 16, 15], |_, _, _| 3);
        let layout = OctreeLayout::new(vol.desc().clone(), 8, 1);
        let e = SpreadSource::new(Arc::new(Bare(layout)), &other).unwrap_err();
        assert!(
            matches!(e, SpreadError::Mismatch { what: "dims", .. }),
            "{e}"
        );
    }

    #[test]
    fn a_wrong_buffer_is_an_error() {
        let vol = volume([16, 16, 16], |_, _, _| 3);
        let layout = OctreeLayout::new(vol.desc().clone(), 8, 1);
        let src = SpreadSource::new(Arc::new(Bare(layout)), &vol).unwrap();
        let mut out = vec![0u16; 3];
        assert!(matches!(
            src.read_spread(NodeKey::ROOT, &mut out),
            Err(BrickError::BufferSize { .. })
        ));
    }
}
