//! A virtual volume whose bricks are computed on demand.
//!
//! The field is defined top-down, as an inverse Haar-like cascade, so that every
//! level is *exactly* the [`Filter::Average`](crate::Filter::Average) of the next
//! finer one, at any size, without evaluating the finest level:
//!
//! * level 0 (at most `brick^3` voxels) is smooth value noise
//!   ([`brickray_core::synthetic::fractal_noise`]) mapped to 16..=240
//!   ([`ProceduralSource::fractal_noise`]), or concentric shells in a ball in
//!   air of exactly 0 ([`ProceduralSource::sphere_shells`]);
//! * a level-`j` voxel `c` with parent `p = c / 2` (level `j-1`, value `v`) has the
//!   value `v + sx*Ax + sy*Ay + sz*Az`, where `s = +1` for an even index and `-1`
//!   for an odd one along that axis, and `A` are integer displacements hashed from
//!   `(seed, j, p, axis)`, of amplitude `amp_j = 48 * 0.75^j`, limited to
//!   `min(v, 255 - v) / 3` so values stay in `0..=255`. An axis along which the
//!   parent has only one child (odd level size, clamped) gets `A = 0`.
//!
//! The eight (edge-clamped) children of a parent then sum to exactly `8 v`, so the
//! rounded average is `v`: inner nodes equal the filter of their children. A
//! voxel's value is reached from its level-0 ancestor in `level` steps, and a
//! brick costs about `8/7` of its stored voxels in evaluations.
//!
//! `min`/`max` of a node come without evaluating it: the brick's footprint on a
//! level a few steps coarser (about 3^3 voxels) is evaluated and widened by the
//! largest displacement the remaining levels can add (`sum 3 * ceil(amp_j)`), then
//! clamped to 0..=255. That bound covers the node's stored voxels and its whole
//! subtree, like the store's subtree ranges. A value of 0 or 255 leaves no room
//! for displacements, so a footprint that is all 0 (or all 255) is exact: the
//! node is `Uniform(0)` (or `Uniform(255)`).

use crate::error::StoreError;
use brickray_core::synthetic::fractal_noise;
use brickray_core::{
    BrickError, BrickSource, DType, NodeInfo, NodeKey, NodeKind, OctreeLayout, VolumeDesc,
};

/// A procedural u8 volume (see the module docs) implementing [`BrickSource`].
#[derive(Debug, Clone)]
pub struct ProceduralSource {
    layout: OctreeLayout,
    seed: u64,
    field: Field,
    /// Per level: displacement amplitude (integer bound) applied to reach it.
    amp: Vec<i32>,
    /// Per level: largest total displacement from a voxel of this level to any
    /// finer descendant.
    reach: Vec<i32>,
}

/// The coarse (level-0) field the cascade starts from.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Field {
    /// Value noise in 16..=240.
    Noise,
    /// Concentric shells in a ball, exact 0 (air) outside it.
    Shells,
}

/// The options every procedural volume checks: dimensions, brick and apron.
pub(crate) fn check_options(dims: [u64; 3], brick: u32, apron: u32) -> Result<(), StoreError> {
    brickray_core::volume::voxel_count(dims).map_err(|e| StoreError::BadOption {
        option: "dims",
        reason: e.to_string(),
    })?;
    if brick == 0 || brick > crate::format::MAX_BRICK {
        return Err(StoreError::BadOption {
            option: "brick",
            reason: "must be in 1..=512".into(),
        });
    }
    if apron > crate::format::MAX_APRON {
        return Err(StoreError::BadOption {
            option: "apron",
            reason: "must be in 0..=16".into(),
        });
    }
    Ok(())
}

fn mix(mut h: u64) -> u64 {
    h ^= h >> 30;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 27;
    h = h.wrapping_mul(0x94D0_49BB_1331_11EB);
    h ^ (h >> 31)
}

impl ProceduralSource {
    /// Fractal noise over `dims` voxels (each in `1..=2^24`, at most `2^48` voxels,
    /// e.g. `[65536; 3]`), in bricks of `brick` voxels with `apron`.
    pub fn fractal_noise(
        dims: [u64; 3],
        brick: u32,
        apron: u32,
    ) -> Result<ProceduralSource, StoreError> {
        ProceduralSource::with_seed(dims, brick, apron, 0x5EED_B41C)
    }

    /// Concentric shells (values 60, 120, 200) in a ball of 0.45 times the
    /// octree cube's side, centred in the volume, in air of exactly 0, with the
    /// same cascade of fine detail inside. Nodes wholly in the air are
    /// `Uniform(0)`, found by [`BrickSource::node`] without evaluating them,
    /// so empty-space skipping can be tested at any scale.
    pub fn sphere_shells(
        dims: [u64; 3],
        brick: u32,
        apron: u32,
    ) -> Result<ProceduralSource, StoreError> {
        let mut s = ProceduralSource::with_seed(dims, brick, apron, 0x5E11_5EED)?;
        s.field = Field::Shells;
        Ok(s)
    }

    /// [`fractal_noise`](Self::fractal_noise) with a chosen seed.
    pub fn with_seed(
        dims: [u64; 3],
        brick: u32,
        apron: u32,
        seed: u64,
    ) -> Result<ProceduralSource, StoreError> {
        check_options(dims, brick, apron)?;
        let desc = VolumeDesc {
            dims: dims.map(|d| d as u32),
            dtype: DType::U8,
            spacing: [1.0; 3],
            value_range: [0.0, 255.0],
            kind: Default::default(),
        };
        let layout = OctreeLayout::new(desc, brick, apron);
        let n = layout.levels as usize;
        let amp: Vec<i32> = (0..n)
            .map(|j| {
                if j == 0 {
                    0
                } else {
                    (48.0 * 0.75f64.powi(j as i32)).ceil() as i32
                }
            })
            .collect();
        let mut reach = vec![0i32; n];
        for j in (0..n.saturating_sub(1)).rev() {
            reach[j] = reach[j + 1] + 3 * amp[j + 1];
        }
        Ok(ProceduralSource {
            layout,
            seed,
            amp,
            reach,
            field: Field::Noise,
        })
    }

    fn root_value(&self, p: [u64; 3]) -> i32 {
        if self.field == Field::Shells {
            let d = self.layout.level_dims(0);
            let r2: f64 = (0..3)
                .map(|a| {
                    // Unit coordinates of the octree cube, so the ball is round
                    // in voxels whatever the volume's shape.
                    let c = d[a] as f64 * 0.5;
                    let u = (p[a] as f64 + 0.5 - c) / self.layout.brick as f64;
                    u * u
                })
                .sum();
            let r = r2.sqrt() * 2.0;
            if r > 0.9 {
                return 0;
            }
            return [60, 120, 200][(r * 10.0) as usize % 3];
        }
        let period = (self.layout.brick as f64 / 2.0).max(2.0);
        let q = p.map(|c| c as f64 + (self.seed % 977) as f64);
        let n = fractal_noise(q, period, 3);
        (16.0 + 224.0 * n).round().clamp(16.0, 240.0) as i32
    }

    fn displacement(&self, level: u8, parent: [u64; 3], axis: usize, v: i32) -> i32 {
        let amp = self.amp[level as usize];
        if amp == 0 {
            return 0;
        }
        let h = mix(self.seed
            ^ mix(parent[0].wrapping_add((level as u64) << 56))
            ^ mix(parent[1]
                .wrapping_mul(0x9E37_79B9_7F4A_7C15)
                .wrapping_add(axis as u64))
            ^ mix(parent[2]
                .wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
                .wrapping_add(17)));
        let lim = v.min(255 - v) / 3;
        let a = (h % (2 * amp as u64 + 1)) as i32 - amp;
        a.clamp(-lim, lim)
    }

    /// Largest box [`region`](Self::region) evaluates, in voxels.
    pub const MAX_REGION_VOXELS: u64 = 1 << 27;

    /// Values of level `level` voxels in the box `lo..=hi`, x fastest. The box
    /// must be non-empty (`lo <= hi` on each axis), inside the level volume
    /// ([`StoreError::RegionOutOfRange`]) and hold at most
    /// [`MAX_REGION_VOXELS`](Self::MAX_REGION_VOXELS)
    /// ([`StoreError::RegionTooLarge`]).
    pub fn region(&self, level: u8, lo: [u64; 3], hi: [u64; 3]) -> Result<Vec<u8>, StoreError> {
        self.check_region(level, lo, hi)?;
        Ok(self.region_u8(level, lo, hi))
    }

    fn check_region(&self, level: u8, lo: [u64; 3], hi: [u64; 3]) -> Result<(), StoreError> {
        let dims = (level < self.layout.levels).then(|| self.layout.level_dims(level));
        let inside = dims.is_some_and(|d| (0..3).all(|a| lo[a] <= hi[a] && hi[a] < d[a] as u64));
        if !inside {
            return Err(StoreError::RegionOutOfRange {
                level,
                lo,
                hi,
                level_dims: dims,
            });
        }
        // Each extent is at most 2^24 here: the product fits in u128.
        let voxels: u128 = (0..3).map(|a| (hi[a] - lo[a] + 1) as u128).product();
        if voxels > Self::MAX_REGION_VOXELS as u128 {
            return Err(StoreError::RegionTooLarge {
                voxels: u64::try_from(voxels).unwrap_or(u64::MAX),
                max: Self::MAX_REGION_VOXELS,
            });
        }
        Ok(())
    }

    /// [`region`](Self::region) without the checks (callers pass boxes inside
    /// the level volume).
    fn region_u8(&self, level: u8, lo: [u64; 3], hi: [u64; 3]) -> Vec<u8> {
        self.region_i32(level, lo, hi)
            .into_iter()
            .map(|v| v as u8)
            .collect()
    }

    fn region_i32(&self, level: u8, lo: [u64; 3], hi: [u64; 3]) -> Vec<i32> {
        let n = [0, 1, 2].map(|a| (hi[a] - lo[a] + 1) as usize);
        let mut out = Vec::with_capacity(n[0] * n[1] * n[2]);
        if level == 0 {
            for z in lo[2]..=hi[2] {
                for y in lo[1]..=hi[1] {
                    for x in lo[0]..=hi[0] {
                        out.push(self.root_value([x, y, z]));
                    }
                }
            }
            return out;
        }
        let plo = lo.map(|c| c / 2);
        let phi = hi.map(|c| c / 2);
        let pn = [0, 1, 2].map(|a| (phi[a] - plo[a] + 1) as usize);
        let parent = self.region_i32(level - 1, plo, phi);
        let dims = self.layout.level_dims(level).map(u64::from);
        // Per parent voxel: the three displacements.
        let mut disp = Vec::with_capacity(parent.len());
        let mut i = 0;
        for pz in plo[2]..=phi[2] {
            for py in plo[1]..=phi[1] {
                for px in plo[0]..=phi[0] {
                    let v = parent[i];
                    let pp = [px, py, pz];
                    let d: [i32; 3] = std::array::from_fn(|a| {
                        if 2 * pp[a] + 1 < dims[a] {
                            self.displacement(level, pp, a, v)
                        } else {
                            0
                        }
                    });
                    disp.push(d);
                    i += 1;
                }
            }
        }
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                let prow = ((z / 2 - plo[2]) as usize * pn[1] + (y / 2 - plo[1]) as usize) * pn[0];
                let sy = if y & 1 == 0 { 1 } else { -1 };
                let sz = if z & 1 == 0 { 1 } else { -1 };
                for x in lo[0]..=hi[0] {
                    let pi = prow + (x / 2 - plo[0]) as usize;
                    let sx = if x & 1 == 0 { 1 } else { -1 };
                    let d = disp[pi];
                    out.push(parent[pi] + sx * d[0] + sy * d[1] + sz * d[2]);
                }
            }
        }
        out
    }

    /// The value of one level voxel (coordinates inside the level volume, else
    /// [`StoreError::RegionOutOfRange`]).
    pub fn voxel(&self, level: u8, p: [u64; 3]) -> Result<u8, StoreError> {
        Ok(self.region(level, p, p)?[0])
    }

    fn check(&self, key: NodeKey) -> Result<bool, BrickError> {
        check_key(&self.layout, key)
    }
}

/// A key of a procedural volume: an error outside the octree, `false` for a
/// node outside the volume.
pub(crate) fn check_key(layout: &OctreeLayout, key: NodeKey) -> Result<bool, BrickError> {
    let n = 1u64 << key.level.min(63);
    if key.level >= layout.levels || [key.x, key.y, key.z].iter().any(|&p| p as u64 >= n) {
        return Err(BrickError::OutOfRange { key });
    }
    Ok(layout.in_volume(key))
}

/// Fills `out` with `key`'s stored u8 brick, gathered from `region(level, lo,
/// hi)` (the values of its footprint, x fastest), or with zeros for a node
/// outside the volume.
pub(crate) fn read_u8_brick(
    layout: &OctreeLayout,
    key: NodeKey,
    out: &mut [u8],
    region: impl FnOnce(u8, [u64; 3], [u64; 3]) -> Vec<u8>,
) -> Result<(), BrickError> {
    let expected = layout.brick_bytes();
    if out.len() != expected {
        return Err(BrickError::BufferSize {
            expected,
            actual: out.len(),
        });
    }
    if !check_key(layout, key)? {
        out.fill(0);
        return Ok(());
    }
    let fp = layout.brick_footprint(key);
    let vals = region(key.level, fp.0, fp.1);
    let mut o = 0;
    layout.gather_brick(key, fp, |i| {
        out[o] = vals[i];
        o += 1;
    });
    Ok(())
}

impl BrickSource for ProceduralSource {
    fn layout(&self) -> &OctreeLayout {
        &self.layout
    }

    fn node(&self, key: NodeKey) -> Result<NodeInfo, BrickError> {
        if !self.check(key)? {
            return Ok(NodeInfo {
                kind: NodeKind::Empty,
                min: 0.0,
                max: 0.0,
                error: None,
                parent_error: None,
                channels: Default::default(),
                channel_errors: None,
            });
        }
        let (lo, hi) = self.layout.brick_footprint(key);
        // Step up until the footprint is about 3 voxels a side.
        let mut m = key.level;
        let (mut lo, mut hi) = (lo, hi);
        while m > 0 && (0..3).any(|a| hi[a] - lo[a] > 2) {
            m -= 1;
            lo = lo.map(|c| c / 2);
            hi = hi.map(|c| c / 2);
        }
        let vals = self.region_i32(m, lo, hi);
        let (mn, mx) = vals
            .iter()
            .fold((i32::MAX, i32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
        // 0 and 255 have no room for displacements: such a region is exact.
        if mn == mx && (mn == 0 || mn == 255) {
            return Ok(NodeInfo {
                kind: NodeKind::Uniform(mn as f32),
                min: mn as f32,
                max: mn as f32,
                error: None,
                parent_error: None,
                channels: Default::default(),
                channel_errors: None,
            });
        }
        let r = self.reach[m as usize];
        Ok(NodeInfo {
            kind: NodeKind::Data,
            min: (mn - r).max(0) as f32,
            max: (mx + r).min(255) as f32,
            error: None,
            parent_error: None,
            channels: Default::default(),
            channel_errors: None,
        })
    }

    fn read_brick(&self, key: NodeKey, out: &mut [u8]) -> Result<(), BrickError> {
        read_u8_brick(&self.layout, key, out, |l, lo, hi| {
            self.region_u8(l, lo, hi)
        })
    }
}
