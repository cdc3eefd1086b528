//! The min/max macro-cell grid for empty-space skipping (Krueger-Westermann 2003).
//!
//! Cell `c` (size `C` voxels) covers continuous voxel coordinates `p` with
//! `p + 0.5` in `[c*C, (c+1)*C]` (voxel centres at integers). A trilinear sample
//! there reads voxels `c*C - 1 ..= c*C + C` (clamped to the grid), and the cell's
//! range covers exactly those, so "the TF is transparent over `[min, max]`" proves
//! every sample inside the cell is transparent.

use crate::volume::Volume;

/// Normalized min/max per macro cell.
#[derive(Debug, Clone, PartialEq)]
pub struct MacroCellGrid {
    /// Cell size in voxels.
    pub cell: u32,
    /// Cells along x, y, z.
    pub dims: [u32; 3],
    /// `[min, max]` per cell, normalized, x fastest.
    pub ranges: Vec<[f32; 2]>,
}

impl MacroCellGrid {
    /// Builds the grid for a volume. O(voxels).
    pub fn build(vol: &Volume, cell: u32) -> MacroCellGrid {
        let cell = cell.max(1);
        let vd = vol.dims();
        let dims = vd.map(|d| d.div_ceil(cell));
        // Per-axis reduction: first reduce x into cells, then y, then z, with the
        // one-voxel overlap on each side.
        let span = |c: u32, n: u32| -> (u32, u32) {
            let lo = (c * cell).saturating_sub(1);
            let hi = (c * cell + cell).min(n - 1);
            (lo, hi)
        };
        let [nx, ny, nz] = vd.map(|d| d as usize);
        let [cx, cy, cz] = dims.map(|d| d as usize);
        // Stage 1: over x.
        let mut sx = vec![[f32::INFINITY, f32::NEG_INFINITY]; cx * ny * nz];
        for z in 0..nz {
            for y in 0..ny {
                let row = (z * ny + y) * nx;
                for c in 0..cx {
                    let (lo, hi) = span(c as u32, vd[0]);
                    let mut m = [f32::INFINITY, f32::NEG_INFINITY];
                    for x in lo..=hi {
                        let v = vol.data().get(row + x as usize);
                        m = [m[0].min(v), m[1].max(v)];
                    }
                    sx[(z * ny + y) * cx + c] = m;
                }
            }
        }
        // Stage 2: over y.
        let mut sy = vec![[f32::INFINITY, f32::NEG_INFINITY]; cx * cy * nz];
        for z in 0..nz {
            for c in 0..cy {
                let (lo, hi) = span(c as u32, vd[1]);
                for x in 0..cx {
                    let mut m = [f32::INFINITY, f32::NEG_INFINITY];
                    for y in lo..=hi {
                        let v = sx[(z * ny + y as usize) * cx + x];
                        m = [m[0].min(v[0]), m[1].max(v[1])];
                    }
                    sy[(z * cy + c) * cx + x] = m;
                }
            }
        }
        // Stage 3: over z, normalizing.
        let desc = vol.desc();
        let mut ranges = vec![[0.0; 2]; cx * cy * cz];
        for c in 0..cz {
            let (lo, hi) = span(c as u32, vd[2]);
            for y in 0..cy {
                for x in 0..cx {
                    let mut m = [f32::INFINITY, f32::NEG_INFINITY];
                    for z in lo..=hi {
                        let v = sy[(z as usize * cy + y) * cx + x];
                        m = [m[0].min(v[0]), m[1].max(v[1])];
                    }
                    ranges[(c * cy + y) * cx + x] = [desc.normalize(m[0]), desc.normalize(m[1])];
                }
            }
        }
        MacroCellGrid { cell, dims, ranges }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::volume::{DType, VolumeData, VolumeDesc};
    use proptest::prelude::*;

    proptest! {
        /// Every trilinear sample inside a cell lies within the cell's range.
        #[test]
        fn ranges_are_conservative(
            dims in (1u32..12, 1u32..12, 1u32..12),
            cell in 1u32..6,
            seed in any::<u64>(),
            probes in prop::collection::vec((0.0f64..1.0, 0.0f64..1.0, 0.0f64..1.0), 50),
        ) {
            let dims = [dims.0, dims.1, dims.2];
            let n = (dims[0] * dims[1] * dims[2]) as usize;
            let mut s = seed | 1;
            let data: Vec<u8> = (0..n).map(|_| { s ^= s << 13; s ^= s >> 7; s ^= s << 17; s as u8 }).collect();
            let desc = VolumeDesc { dims, dtype: DType::U8, spacing: [1.0; 3], value_range: [0.0, 255.0] };
            let vol = Volume::new(desc, VolumeData::U8(data)).unwrap();
            let g = MacroCellGrid::build(&vol, cell);
            for (fx, fy, fz) in probes {
                // A point in texture space, mapped to voxel coords p = u*dims - 0.5.
                let p = [fx * dims[0] as f64 - 0.5, fy * dims[1] as f64 - 0.5, fz * dims[2] as f64 - 0.5];
                let c: Vec<usize> = (0..3).map(|a| (((p[a] + 0.5) / cell as f64).floor() as usize).min(g.dims[a] as usize - 1)).collect();
                let r = g.ranges[(c[2] * g.dims[1] as usize + c[1]) * g.dims[0] as usize + c[0]];
                let v = vol.sample_trilinear(p) as f32;
                prop_assert!(v >= r[0] - 1e-6 && v <= r[1] + 1e-6, "{v} not in {r:?}");
            }
        }
    }
}
