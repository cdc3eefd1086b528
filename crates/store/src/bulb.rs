//! A virtual Mandelbulb: a recognisable shape with detail at every scale,
//! computed on demand at any size (the demo's and the viewer's default scene).
//!
//! The octree cube maps to `[-1.25, 1.25]^3` of the power-8 Mandelbulb
//! (White and Nylander, 2009). A voxel's value is a solid with a soft surface:
//! `v = inner * clamp(1 - d / w, 0, 1)`, where `d` is the bulb's distance
//! estimate at the voxel's centre (`0.5 ln r * r / |dz|` after the orbit
//! escapes), `w` is 1.5 voxels *of the voxel's level* (so every level is a
//! band-limited version of the next finer one, not a point sample of it), and
//! `inner` in `96..=255` follows the orbit's closest approach to the origin (an
//! orbit trap), so a transfer function can colour the folds.
//!
//! A node is `Uniform(0)` when the distance estimate at its centre exceeds
//! twice its half-diagonal plus its level's band (the estimate is within a
//! factor of about 2 of the true distance), or when it lies wholly outside
//! the ball of radius `2^(1/7)` that holds the set (exact; tests check the
//! bounds on every node of a small volume); every other node is data over
//! `0..=255`. Evaluating a
//! voxel costs a few hundred nanoseconds, a 36^3 brick a few milliseconds.

use crate::error::StoreError;
use brickray_core::{
    BrickError, BrickSource, DType, NodeInfo, NodeKey, NodeKind, OctreeLayout, VolumeDesc,
};

/// Half the side of the bulb's box: the octree cube spans `[-EXTENT, EXTENT]^3`.
const EXTENT: f64 = 1.25;
/// The power of the iteration `z -> z^8 + c`.
const POWER: f64 = 8.0;
/// Iterations before a point counts as inside.
const ITERATIONS: u32 = 12;
/// Escape radius.
const BAILOUT: f64 = 2.0;
/// Every orbit from farther than this from the origin escapes (`|z^8 + c| >
/// |c|^8 - |c| > |c|` when `|c|^7 > 2`), so the set lies within it.
const SET_RADIUS: f64 = 1.104_089_513_673_812_3; // 2^(1/7)
/// The surface band, in voxels of the voxel's level.
const BAND_VOXELS: f64 = 1.5;

/// A procedural u8 Mandelbulb (see the module docs) implementing [`BrickSource`].
#[derive(Debug, Clone)]
pub struct MandelbulbSource {
    layout: OctreeLayout,
}

/// The distance estimate at `c` (bulb coordinates) and the orbit trap in 0..1
/// (0: the orbit came close to the origin).
pub(crate) fn estimate(c: [f64; 3]) -> (f64, f64) {
    let mut z = c;
    let mut dr = 1.0f64;
    let mut r = 0.0f64;
    let mut trap = f64::MAX;
    for _ in 0..ITERATIONS {
        r = (z[0] * z[0] + z[1] * z[1] + z[2] * z[2]).sqrt();
        trap = trap.min(r);
        if r > BAILOUT {
            break;
        }
        let theta = (z[2] / r.max(1e-300)).clamp(-1.0, 1.0).acos();
        let phi = z[1].atan2(z[0]);
        dr = r.powf(POWER - 1.0) * POWER * dr + 1.0;
        let zr = r.powf(POWER);
        let (st, ct) = (theta * POWER).sin_cos();
        let (sp, cp) = (phi * POWER).sin_cos();
        z = [zr * st * cp + c[0], zr * st * sp + c[1], zr * ct + c[2]];
    }
    let d = if r > BAILOUT {
        0.5 * r.ln() * r / dr
    } else {
        0.0
    };
    (d.max(0.0), trap.min(1.0))
}

impl MandelbulbSource {
    /// A Mandelbulb in a cube of `side` voxels (`1..=2^24`, e.g. 4096 for
    /// 64 GiB of u8 voxels that are never stored), in bricks of `brick` voxels
    /// with `apron`.
    pub fn new(side: u64, brick: u32, apron: u32) -> Result<MandelbulbSource, StoreError> {
        crate::procedural::check_options([side; 3], brick, apron)?;
        let desc = VolumeDesc {
            dims: [side as u32; 3],
            dtype: DType::U8,
            spacing: [1.0; 3],
            value_range: [0.0, 255.0],
            kind: Default::default(),
        };
        Ok(MandelbulbSource {
            layout: OctreeLayout::new(desc, brick, apron),
        })
    }

    /// The surface band's width at `level`, in bulb coordinates.
    fn band(&self, level: u8) -> f64 {
        let d = self.layout.level_dims(level)[0].max(1) as f64;
        BAND_VOXELS * 2.0 * EXTENT / d
    }

    /// The value of a level voxel (no bounds check).
    fn value(&self, level: u8, p: [u64; 3]) -> u8 {
        let d = self.layout.level_dims(level);
        let c: [f64; 3] =
            std::array::from_fn(|a| ((p[a] as f64 + 0.5) / d[a] as f64 - 0.5) * 2.0 * EXTENT);
        let (de, trap) = estimate(c);
        let inner = 96.0 + 159.0 * (1.0 - trap);
        let v = inner * (1.0 - de / self.band(level)).clamp(0.0, 1.0);
        v.round().clamp(0.0, 255.0) as u8
    }

    /// Values of level `level` voxels in the box `lo..=hi` (x fastest), each
    /// inside the level volume ([`StoreError::RegionOutOfRange`]).
    pub fn region(&self, level: u8, lo: [u64; 3], hi: [u64; 3]) -> Result<Vec<u8>, StoreError> {
        let dims = (level < self.layout.levels).then(|| self.layout.level_dims(level));
        let inside = dims.is_some_and(|d| (0..3).all(|a| lo[a] <= hi[a] && hi[a] < d[a] as u64));
        let voxels: u128 = (0..3)
            .map(|a| hi[a].saturating_sub(lo[a]) as u128 + 1)
            .product();
        if !inside {
            return Err(StoreError::RegionOutOfRange {
                level,
                lo,
                hi,
                level_dims: dims,
            });
        }
        let max = crate::ProceduralSource::MAX_REGION_VOXELS;
        if voxels > max as u128 {
            return Err(StoreError::RegionTooLarge {
                voxels: u64::try_from(voxels).unwrap_or(u64::MAX),
                max,
            });
        }
        Ok(self.region_unchecked(level, lo, hi))
    }

    fn region_unchecked(&self, level: u8, lo: [u64; 3], hi: [u64; 3]) -> Vec<u8> {
        let mut out = Vec::with_capacity(
            (0..3)
                .map(|a| (hi[a] - lo[a] + 1) as usize)
                .product::<usize>(),
        );
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                for x in lo[0]..=hi[0] {
                    out.push(self.value(level, [x, y, z]));
                }
            }
        }
        out
    }

    /// A point on the bulb's surface seen from direction `from` (a unit vector
    /// pointing from the centre towards the viewer), in texture coordinates
    /// (`[0,1]^3` over the volume), found by sphere tracing the distance
    /// estimate inwards from the box's edge to within `eps` (bulb units).
    pub fn surface_point(from: [f64; 3], eps: f64) -> Option<[f64; 3]> {
        let n = (from[0] * from[0] + from[1] * from[1] + from[2] * from[2]).sqrt();
        if !(n.is_finite() && n > 0.0) {
            return None;
        }
        let dir = from.map(|c| -c / n);
        let start = from.map(|c| c / n * EXTENT * 1.7);
        let mut t = 0.0;
        for _ in 0..2000 {
            let p: [f64; 3] = std::array::from_fn(|a| start[a] + dir[a] * t);
            let (d, _) = estimate(p);
            if d < eps {
                return Some(p.map(|c| c / (2.0 * EXTENT) + 0.5));
            }
            t += d * 0.5;
            if t > 2.0 * EXTENT * 1.7 {
                return None;
            }
        }
        None
    }

    fn check(&self, key: NodeKey) -> Result<bool, BrickError> {
        crate::procedural::check_key(&self.layout, key)
    }
}

impl BrickSource for MandelbulbSource {
    fn layout(&self) -> &OctreeLayout {
        &self.layout
    }

    fn node(&self, key: NodeKey) -> Result<NodeInfo, BrickError> {
        let uniform = |kind| NodeInfo {
            kind,
            min: 0.0,
            max: 0.0,
            error: None,
            parent_error: None,
            channels: Default::default(),
            channel_errors: None,
        };
        if !self.check(key)? {
            return Ok(uniform(NodeKind::Empty));
        }
        // The node's cube (with its apron) in bulb coordinates.
        let (corner, side) = key.unit_box();
        let apron = self.layout.apron as f64 / self.layout.brick as f64 * side;
        let centre = corner.map(|c| (c + side * 0.5 - 0.5) * 2.0 * EXTENT);
        let half_diagonal = (side * 0.5 + apron) * 2.0 * EXTENT * 3f64.sqrt();
        let band = self.band(key.level);
        // Outside the ball of radius 2^(1/7) every orbit escapes, so the set
        // lies inside it and the band reaches one band beyond it: a box
        // whose nearest point is farther is air, exactly.
        let lo = corner.map(|c| (c - apron - 0.5) * 2.0 * EXTENT);
        let hi = corner.map(|c| (c + side + apron - 0.5) * 2.0 * EXTENT);
        let nearest: f64 = (0..3)
            .map(|a| (lo[a].max(0.0) + (-hi[a]).max(0.0)).powi(2))
            .sum::<f64>()
            .sqrt();
        if nearest > SET_RADIUS + band {
            return Ok(uniform(NodeKind::Uniform(0.0)));
        }
        let (d, _) = estimate(centre);
        if d > 2.0 * (half_diagonal + band) {
            return Ok(uniform(NodeKind::Uniform(0.0)));
        }
        Ok(NodeInfo {
            kind: NodeKind::Data,
            min: 0.0,
            max: 255.0,
            error: None,
            parent_error: None,
            channels: Default::default(),
            channel_errors: None,
        })
    }

    fn read_brick(&self, key: NodeKey, out: &mut [u8]) -> Result<(), BrickError> {
        crate::procedural::read_u8_brick(&self.layout, key, out, |l, lo, hi| {
            self.region_unchecked(l, lo, hi)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every node's recorded range holds every value of its stored brick, and
    /// nodes recorded as uniform are: the distance bound never hides the
    /// surface (every node of a 128^3 bulb in bricks of 16, 4 levels).
    #[test]
    fn node_ranges_hold_their_bricks() {
        let s = MandelbulbSource::new(128, 16, 1).unwrap();
        let l = s.layout().clone();
        let (mut uniform, mut data) = (0, 0);
        let mut buf = vec![0u8; l.brick_bytes()];
        for level in 0..l.levels {
            let n = 1u32 << level;
            for z in 0..n {
                for y in 0..n {
                    for x in 0..n {
                        let key = NodeKey { level, x, y, z };
                        let info = s.node(key).unwrap();
                        s.read_brick(key, &mut buf).unwrap();
                        let (mn, mx) = buf
                            .iter()
                            .fold((255u8, 0u8), |(a, b), &v| (a.min(v), b.max(v)));
                        assert!(
                            info.min <= mn as f32 && mx as f32 <= info.max,
                            "{key:?}: {info:?} but the brick holds {mn}..={mx}"
                        );
                        match info.kind {
                            NodeKind::Data => data += 1,
                            _ => uniform += 1,
                        }
                    }
                }
            }
        }
        // The bound is useful: a good share of the nodes is known to be air.
        assert!(
            uniform * 3 > data,
            "{uniform} uniform nodes, {data} with data"
        );
    }

    /// The shape is there: the centre is inside, the corners are air, and
    /// coarse levels agree with the finest where they overlap the surface.
    #[test]
    fn the_bulb_is_solid_inside_and_air_outside() {
        let s = MandelbulbSource::new(256, 32, 2).unwrap();
        let finest = s.layout().levels - 1;
        assert!(s.region(finest, [128; 3], [128; 3]).unwrap()[0] >= 96);
        assert_eq!(s.region(finest, [0; 3], [0; 3]).unwrap()[0], 0);
        assert_eq!(s.region(finest, [255; 3], [255; 3]).unwrap()[0], 0);
        // The share of solid voxels is about the same at two levels.
        let solid = |level: u8| {
            let d = s.layout().level_dims(level)[0] as u64 - 1;
            let v = s.region(level, [0; 3], [d; 3]).unwrap();
            v.iter().filter(|&&x| x >= 48).count() as f64 / v.len() as f64
        };
        let (a, b) = (solid(finest), solid(finest - 1));
        assert!(
            a > 0.05 && (a - b).abs() < 0.3 * a,
            "solid share {a} vs {b}"
        );
    }

    #[test]
    fn bad_regions_and_sizes_are_typed_errors() {
        let s = MandelbulbSource::new(64, 16, 1).unwrap();
        assert!(matches!(
            s.region(0, [0; 3], [64; 3]),
            Err(StoreError::RegionOutOfRange { .. })
        ));
        assert!(matches!(
            s.region(9, [0; 3], [0; 3]),
            Err(StoreError::RegionOutOfRange { .. })
        ));
        assert!(MandelbulbSource::new(0, 16, 1).is_err());
        assert!(MandelbulbSource::new(64, 0, 1).is_err());
        let mut small = vec![0u8; 3];
        assert!(matches!(
            s.read_brick(NodeKey::ROOT, &mut small),
            Err(BrickError::BufferSize { .. })
        ));
    }

    #[test]
    fn a_surface_point_lies_on_the_surface() {
        let p = MandelbulbSource::surface_point([0.3, 0.4, 0.8], 1e-4).unwrap();
        assert!(p.iter().all(|c| (0.0..=1.0).contains(c)));
        let c = p.map(|u| (u - 0.5) * 2.0 * EXTENT);
        assert!(estimate(c).0 < 1e-4);
        assert!(MandelbulbSource::surface_point([0.0; 3], 1e-4).is_none());
    }
}
