//! The min/max macro-cell grid for empty-space skipping (Krueger-Westermann 2003).
//!
//! Cell `c` (size `C` voxels) covers continuous voxel coordinates `p` with
//! `p + 0.5` in `[c*C, (c+1)*C]` (voxel centres at integers). A trilinear sample
//! there reads voxels `c*C - 1 ..= c*C + C` (clamped to the grid), and the cell's
//! range covers exactly those, so "the TF is transparent over `[min, max]`" proves
//! every sample inside the cell is transparent.
//!
//! [`sub_cell_ranges`] is the brick analogue for the out-of-core path: the
//! min/max of each of a brick's `n^3` sub-cells, computed from the brick's stored
//! samples (apron included). When skipping pays is decided in
//! [`crate::skip_rule`].

use crate::brick::OctreeLayout;
use crate::volume::{DType, Volume};

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

    /// The Chebyshev distance of every cell to the nearest cell that is not
    /// `empty` (0 for those; at most `cap`), x fastest: a ray in a cell of
    /// distance `d > 0` may jump past the cube of cells within `d - 1` of it,
    /// all of which are empty (proximity clouds: one test skips a run of empty
    /// cells). Separable in three passes, O(cells * cap). Cells outside the grid
    /// count as empty (rays leave the volume there).
    pub fn empty_distance(&self, empty: impl Fn([f32; 2]) -> bool, cap: u32) -> Vec<u32> {
        let empty: Vec<bool> = self.ranges.iter().map(|&r| empty(r)).collect();
        empty_distance(self.dims, &empty, cap)
    }

    /// The share of cells transparent through `tf` (DVR skips them; what
    /// [`dvr_skip_share_min`](crate::skip_rule::dvr_skip_share_min) is
    /// compared with; 0 for an empty grid).
    pub fn transparent_share(&self, tf: &crate::TransferFunction) -> f64 {
        let transparent = self
            .ranges
            .iter()
            .filter(|r| tf.is_transparent(r[0], r[1]))
            .count();
        transparent as f64 / self.ranges.len().max(1) as f64
    }

    /// The share of cells that MIP's skipping is certain to skip, over rays
    /// along each axis in both directions, one per column of cells
    /// ([`mip_skip_counts`]; 0 for an empty grid). What
    /// [`mip_skipping_pays`](crate::skip_rule::mip_skipping_pays) decides from.
    pub fn mip_skip_share(&self) -> f64 {
        let [skipped, all] = mip_skip_counts(self.dims, &self.ranges);
        if all == 0 {
            0.0
        } else {
            skipped as f64 / all as f64
        }
    }
}

/// Of a grid of `dims` cells with these normalized `[min, max]` ranges (x
/// fastest), `[skipped, all]`: the cells that MIP's skipping is certain to
/// skip over rays along each axis in both directions, one per column of
/// cells, and the cells those rays cross. A ray skips a cell whose maximum
/// is at most its running maximum, and after sampling a cell its running
/// maximum is at least that cell's minimum (so `skipped` is a lower bound
/// on what skipping saves). Ranges missing from a short slice count as
/// never skipped.
pub fn mip_skip_counts(dims: [u32; 3], ranges: &[[f32; 2]]) -> [u64; 2] {
    let n = dims.map(|d| d as usize);
    let idx = |c: [usize; 3]| (c[2] * n[1] + c[1]) * n[0] + c[0];
    let (mut skipped, mut all) = (0u64, 0u64);
    for axis in 0..3 {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        for reverse in [false, true] {
            for i in 0..n[u] {
                for j in 0..n[v] {
                    let mut running = f32::NEG_INFINITY;
                    for k in 0..n[axis] {
                        let mut c = [0usize; 3];
                        c[axis] = if reverse { n[axis] - 1 - k } else { k };
                        c[u] = i;
                        c[v] = j;
                        let [lo, hi] = ranges
                            .get(idx(c))
                            .copied()
                            .unwrap_or([f32::NEG_INFINITY, f32::INFINITY]);
                        all += 1;
                        if hi <= running {
                            skipped += 1;
                        } else {
                            running = running.max(lo);
                        }
                    }
                }
            }
        }
    }
    [skipped, all]
}

/// [`MacroCellGrid::empty_distance`] of a grid of `dims` cells whose
/// emptiness is given per cell (x fastest): what several grids over one
/// volume share (a multi-channel volume's cell is empty when it is in every
/// channel, [`crate::channels`]).
pub fn empty_distance(dims: [u32; 3], empty: &[bool], cap: u32) -> Vec<u32> {
    let [cx, cy, cz] = dims.map(|d| d as usize);
    let idx = |x: usize, y: usize, z: usize| (z * cy + y) * cx + x;
    let cap = cap.max(1);
    let mut d: Vec<u32> = empty.iter().map(|&e| if e { cap } else { 0 }).collect();
    // One pass along an axis: d'(p) = min over q on p's line within cap of
    // max(|p - q|, d(q)), the L-infinity distance transform's separable step.
    let pass = |d: &Vec<u32>, n: usize, at: &dyn Fn(usize, usize) -> usize, lines: usize| {
        let mut out = d.clone();
        for line in 0..lines {
            for p in 0..n {
                let mut best = d[at(line, p)];
                let lo = p.saturating_sub(cap as usize);
                let hi = (p + cap as usize).min(n - 1);
                for q in lo..=hi {
                    let v = d[at(line, q)].max(p.abs_diff(q) as u32);
                    best = best.min(v);
                }
                out[at(line, p)] = best;
            }
        }
        out
    };
    d = pass(&d, cx, &|l, p| idx(p, l % cy, l / cy), cy * cz);
    d = pass(&d, cy, &|l, p| idx(l % cx, p, l / cx), cx * cz);
    d = pass(&d, cz, &|l, p| idx(l % cx, l / cx, p), cx * cy);
    d
}

/// Sub-cells per brick axis for empty-space skipping inside bricks: cells of
/// about 8 voxels, as the in-core macro cells.
pub fn sub_cells_per_axis(brick: u32) -> u32 {
    brick.div_ceil(8).max(1)
}

/// Normalized min/max of each of a brick's `n^3` sub-cells (x fastest). `bytes`
/// is the brick as stored (`stored_side^3` little-endian samples of the layout's
/// dtype, apron included). Cell `j` covers the brick-local edge coordinates
/// `[j B/n, (j+1) B/n]` (B interior voxels); a trilinear sample there reads voxel
/// centres `floor(e - 0.5)` and the next, so the range covers those, offset by the
/// apron and clamped to the brick. A malformed brick (too short) or `n == 0`
/// gives ranges that never skip (`[-inf, inf]`, at least one cell).
pub fn sub_cell_ranges(layout: &OctreeLayout, bytes: &[u8], n: u32) -> Vec<[f32; 2]> {
    let side = layout.stored_side() as usize;
    let d = &layout.volume;
    let cells = (n.max(1) as usize).pow(3);
    if n == 0 || side == 0 || bytes.len() / d.dtype.size() < side * side * side {
        return vec![[f32::NEG_INFINITY, f32::INFINITY]; cells];
    }
    // A range that never changes: every value normalizes to 0.
    let [lo, hi] = d.value_range;
    let span = hi - lo;
    if span.is_nan() || span <= 0.0 {
        return vec![[0.0, 0.0]; cells];
    }
    // The extents of the raw values, read in place (the loader threads
    // prepare every brick through here, and a decoded copy of each was a
    // fresh allocation whose pages the kernel zeroed), normalized after:
    // `normalize` is non-decreasing, so it maps each extent to the extent
    // of the normalized values exactly (NaN, skipped by `min` and `max`,
    // either way).
    // Integers: each row's extent in the integers, converted once
    // (the conversion is non-decreasing too).
    fn ints<const W: usize, T: Ord + Copy>(
        bytes: &[u8],
        decode: impl Fn([u8; W]) -> T,
        to_f32: impl Fn(T) -> f32,
    ) -> impl Fn(usize, usize) -> [f32; 2] {
        move |a, b| {
            let mut it = bytes[a * W..(b + 1) * W]
                .chunks_exact(W)
                .map(|c| decode(c.try_into().expect("W bytes")));
            let first = it.next().expect("a row holds a voxel");
            let (lo, hi) = it.fold((first, first), |(lo, hi), v| (lo.min(v), hi.max(v)));
            [to_f32(lo), to_f32(hi)]
        }
    }
    let raw = match d.dtype {
        DType::U8 => sub_cell_extents(layout, n, ints::<1, u8>(bytes, |b| b[0], f32::from)),
        DType::U16 => sub_cell_extents(
            layout,
            n,
            ints::<2, u16>(bytes, u16::from_le_bytes, f32::from),
        ),
        DType::I16 => sub_cell_extents(
            layout,
            n,
            ints::<2, i16>(bytes, i16::from_le_bytes, f32::from),
        ),
        DType::U32 => sub_cell_extents(
            layout,
            n,
            ints::<4, u32>(bytes, u32::from_le_bytes, |v| v as f32),
        ),
        DType::F32 => sub_cell_extents(layout, n, |a, b| {
            bytes[a * 4..(b + 1) * 4]
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .fold([f32::INFINITY, f32::NEG_INFINITY], |m, v| {
                    [m[0].min(v), m[1].max(v)]
                })
        }),
    };
    raw.into_iter()
        .map(|[a, b]| [d.normalize(a), d.normalize(b)])
        .collect()
}

/// The largest spread of each of a brick's `n^3` sub-cells (x fastest), over
/// the same voxels as [`sub_cell_ranges`]: `spread` is the brick's spread per
/// stored voxel as half-float bits ([`crate::BrickSource::read_spread`]). A
/// malformed brick (too short) or a NaN spread gives `inf` (widened without
/// bound: never skipped).
pub fn sub_cell_spreads(layout: &OctreeLayout, spread: &[u16], n: u32) -> Vec<f32> {
    let side = layout.stored_side() as usize;
    if n == 0 || side == 0 || spread.len() < side * side * side {
        return vec![f32::INFINITY; (n.max(1) as usize).pow(3)];
    }
    sub_cell_extents(layout, n, |a, b| {
        spread[a..=b]
            .iter()
            .map(|&h| {
                let s = half::f16::from_bits(h).to_f32();
                if s.is_nan() { f32::INFINITY } else { s }
            })
            .fold([f32::INFINITY, f32::NEG_INFINITY], |m, v| {
                [m[0].min(v), m[1].max(v)]
            })
    })
    .into_iter()
    .map(|m| m[1].max(0.0))
    .collect()
}

/// `[min, max]` over each sub-cell's voxels, from `row(a, b)`: the
/// `[min, max]` of stored voxels `a..=b` (x fastest; one row of a cell).
fn sub_cell_extents(
    layout: &OctreeLayout,
    n: u32,
    row: impl Fn(usize, usize) -> [f32; 2],
) -> Vec<[f32; 2]> {
    let side = layout.stored_side() as usize;
    let cells = (n.max(1) as usize).pow(3);
    let (b, a) = (layout.brick as f64, layout.apron as i64);
    let span = |j: u32| -> (usize, usize) {
        let lo = ((j as f64 * b / n as f64 - 0.5).floor() as i64 + a).clamp(0, side as i64 - 1);
        let hi = (((j + 1) as f64 * b / n as f64 - 0.5).floor() as i64 + 1 + a)
            .clamp(0, side as i64 - 1);
        (lo as usize, hi as usize)
    };
    let mut out = Vec::with_capacity(cells);
    for jz in 0..n {
        let (z0, z1) = span(jz);
        for jy in 0..n {
            let (y0, y1) = span(jy);
            for jx in 0..n {
                let (x0, x1) = span(jx);
                let mut m = [f32::INFINITY, f32::NEG_INFINITY];
                for z in z0..=z1 {
                    for y in y0..=y1 {
                        let at = (z * side + y) * side;
                        let r = row(at + x0, at + x1);
                        m = [m[0].min(r[0]), m[1].max(r[1])];
                    }
                }
                // NaN samples (f32 volumes) make `min`/`max` skip them; a cell of
                // only NaN stays inverted: never skip it.
                if m[0] > m[1] {
                    m = [f32::NEG_INFINITY, f32::INFINITY];
                }
                out.push(m);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::volume::{VolumeData, VolumeDesc};
    use proptest::prelude::*;

    /// A constant grid: each axis ray samples its first cell and is certain
    /// to skip the rest; cells spanning the whole range skip nothing.
    #[test]
    fn mip_skip_share_of_simple_grids() {
        let n = 5u32;
        let cells = (n * n * n) as usize;
        let constant = MacroCellGrid {
            cell: 8,
            dims: [n; 3],
            ranges: vec![[0.3, 0.3]; cells],
        };
        assert!((constant.mip_skip_share() - 0.8).abs() < 1e-12);
        let wide = MacroCellGrid {
            ranges: vec![[0.0, 1.0]; cells],
            ..constant.clone()
        };
        assert_eq!(wide.mip_skip_share(), 0.0);
        let none = MacroCellGrid {
            dims: [0; 3],
            ranges: Vec::new(),
            ..constant
        };
        assert_eq!(none.mip_skip_share(), 0.0);
    }

    /// The counts behind the share: a brick's 2 x 2 x 2 sub-cells, a bright
    /// one in a corner of dim ones. Rays along each axis cross 48 cells (4
    /// columns x 2 directions x 3 axes, 2 cells each); a dim cell is skipped
    /// only after the bright one, in its column and one direction (one per
    /// axis: 3), not after another dim one (its maximum 0.2 is above the
    /// running 0.1); a slice too short never skips.
    #[test]
    fn mip_skip_counts_of_a_brick() {
        let mut ranges = vec![[0.1f32, 0.2]; 8];
        ranges[0] = [0.9, 1.0];
        let [skipped, all] = mip_skip_counts([2; 3], &ranges);
        assert_eq!(all, 48);
        assert_eq!(skipped, 3);
        assert_eq!(mip_skip_counts([2; 3], &ranges[..1]), [0, 48]);
    }

    proptest! {
        /// The share lies in 0..1, and widening cells' ranges (a lower
        /// minimum, a higher maximum) never raises it: it counts only skips
        /// the ranges make certain.
        #[test]
        fn mip_skip_share_falls_as_ranges_widen(
            dims in proptest::array::uniform3(1u32..6),
            seed in proptest::collection::vec((0.0f32..1.0, 0.0f32..0.3), 216),
            widen in proptest::collection::vec((0.0f32..0.2, 0.0f32..0.2), 216),
        ) {
            let n = (dims[0] * dims[1] * dims[2]) as usize;
            let ranges: Vec<[f32; 2]> = seed[..n].iter().map(|&(v, w)| [v, v + w]).collect();
            let grid = MacroCellGrid { cell: 8, dims, ranges };
            let share = grid.mip_skip_share();
            prop_assert!((0.0..=1.0).contains(&share));
            let wider = MacroCellGrid {
                ranges: grid
                    .ranges
                    .iter()
                    .zip(&widen)
                    .map(|(r, &(a, b))| [r[0] - a, r[1] + b])
                    .collect(),
                ..grid.clone()
            };
            prop_assert!(wider.mip_skip_share() <= share);
        }

        /// The separable transform equals the brute-force Chebyshev distance to
        /// the nearest non-empty cell (capped), and the cube a jump skips holds
        /// only empty cells.
        #[test]
        fn empty_distance_is_the_chebyshev_distance(
            dims in proptest::array::uniform3(1u32..7),
            seed in proptest::collection::vec(0.0f32..1.0, 343),
            cap in 1u32..5,
        ) {
            let n = (dims[0] * dims[1] * dims[2]) as usize;
            let ranges: Vec<[f32; 2]> = seed[..n].iter().map(|&v| [v, v]).collect();
            let grid = MacroCellGrid { cell: 8, dims, ranges };
            let empty = |r: [f32; 2]| r[1] < 0.8;
            let d = grid.empty_distance(empty, cap);
            let [cx, cy, cz] = dims.map(|v| v as i64);
            let at = |x: i64, y: i64, z: i64| ((z * cy + y) * cx + x) as usize;
            for z in 0..cz {
                for y in 0..cy {
                    for x in 0..cx {
                        let mut best = cap as i64;
                        for qz in 0..cz {
                            for qy in 0..cy {
                                for qx in 0..cx {
                                    if !empty(grid.ranges[at(qx, qy, qz)]) {
                                        let m = (x - qx).abs().max((y - qy).abs()).max((z - qz).abs());
                                        best = best.min(m);
                                    }
                                }
                            }
                        }
                        let got = d[at(x, y, z)] as i64;
                        prop_assert_eq!(got, best, "cell {:?}", (x, y, z));
                        // The skipped cube [c - (d - 1), c + d) is empty.
                        for qz in (z - got + 1).max(0)..(z + got).min(cz) {
                            for qy in (y - got + 1).max(0)..(y + got).min(cy) {
                                for qx in (x - got + 1).max(0)..(x + got).min(cx) {
                                    prop_assert!(empty(grid.ranges[at(qx, qy, qz)]));
                                }
                            }
                        }
                    }
                }
            }
        }
    }

    /// Every trilinear sample inside a brick's sub-cell lies within its range.
    #[test]
    fn sub_cell_ranges_are_conservative() {
        let desc = VolumeDesc {
            dims: [64; 3],
            dtype: DType::U8,
            spacing: [1.0; 3],
            value_range: [0.0, 255.0],
            kind: Default::default(),
        };
        let layout = OctreeLayout::new(desc, 16, 2);
        let side = layout.stored_side() as usize;
        let mut seed = 0x2545_f491_u32;
        let bytes: Vec<u8> = (0..side * side * side)
            .map(|_| {
                seed ^= seed << 13;
                seed ^= seed >> 17;
                seed ^= seed << 5;
                seed as u8
            })
            .collect();
        let n = sub_cells_per_axis(layout.brick);
        assert_eq!(n, 2);
        let r = sub_cell_ranges(&layout, &bytes, n);
        assert_eq!(r.len(), 8);
        let val = |x: usize, y: usize, z: usize| bytes[(z * side + y) * side + x] as f64 / 255.0;
        let (b, a) = (layout.brick as f64, layout.apron as f64);
        for i in 0..4000 {
            // A point in brick-local edge coordinates [0, B]^3.
            let e: Vec<f64> = (0..3)
                .map(|k| ((i * 7919 + k * 104_729) % 10_007) as f64 / 10_007.0 * b)
                .collect();
            let p: Vec<f64> = e.iter().map(|c| c - 0.5 + a).collect();
            let f: Vec<usize> = p.iter().map(|c| c.floor() as usize).collect();
            let t: Vec<f64> = p.iter().zip(&f).map(|(c, f)| c - *f as f64).collect();
            let mut v = 0.0;
            for dz in 0..2 {
                for dy in 0..2 {
                    for dx in 0..2 {
                        let w = (if dx == 0 { 1.0 - t[0] } else { t[0] })
                            * (if dy == 0 { 1.0 - t[1] } else { t[1] })
                            * (if dz == 0 { 1.0 - t[2] } else { t[2] });
                        v += w * val(f[0] + dx, f[1] + dy, f[2] + dz);
                    }
                }
            }
            let j: Vec<u32> = e
                .iter()
                .map(|c| ((c / (b / n as f64)).floor() as u32).min(n - 1))
                .collect();
            let c = r[((j[2] * n + j[1]) * n + j[0]) as usize];
            assert!(
                v as f32 >= c[0] - 1e-6 && v as f32 <= c[1] + 1e-6,
                "sample {v} outside {c:?}"
            );
        }
        // The ranges are normalized.
        assert!(r.iter().all(|c| c[0] >= 0.0 && c[1] <= 1.0));
    }

    proptest! {
        /// The ranges read in place are those of the decoded, normalized
        /// values (the model: decode the brick, normalize each value, take
        /// each sub-cell's extent), bit for bit, in every dtype, over value
        /// ranges that map every value to 0 and f32 bricks with NaN and
        /// infinities.
        #[test]
        fn ranges_read_in_place_are_the_decoded_ones(
            dtype in prop::sample::select(vec![DType::U8, DType::U16, DType::I16, DType::F32, DType::U32]),
            range in prop::sample::select(vec![[0.0f32, 255.0], [-1024.0, 3071.0], [5.0, 5.0], [1.0, -1.0], [-1e6, 1e9]]),
            apron in 0u32..3,
            bytes_seed in any::<u64>(),
            special in 0u32..4,
        ) {
            let desc = VolumeDesc {
                dims: [24; 3],
                dtype,
                spacing: [1.0; 3],
                value_range: range,
                kind: Default::default(),
            };
            let layout = OctreeLayout::new(desc, 8, apron);
            let side = layout.stored_side() as usize;
            let size = dtype.size();
            let mut seed = bytes_seed | 1;
            let mut bytes: Vec<u8> = (0..side * side * side * size)
                .map(|_| {
                    seed ^= seed << 13;
                    seed ^= seed >> 7;
                    seed ^= seed << 17;
                    seed as u8
                })
                .collect();
            if dtype == DType::F32 {
                // Finite values of a moderate size, some NaN or infinite.
                for (i, c) in bytes.chunks_exact_mut(4).enumerate() {
                    let v = match (i as u32 + special) % 97 {
                        0 => f32::NAN,
                        1 => f32::INFINITY,
                        2 => f32::NEG_INFINITY,
                        _ => (u32::from_le_bytes([c[0], c[1], c[2], c[3]]) % 100_000) as f32 - 50_000.0,
                    };
                    c.copy_from_slice(&v.to_le_bytes());
                }
            }
            for n in [1u32, 2, 3] {
                let vals: Vec<f32> = dtype
                    .decode_le(&bytes)
                    .into_iter()
                    .map(|raw| layout.volume.normalize(raw))
                    .collect();
                let want = sub_cell_extents(&layout, n, |a, b| {
                    vals[a..=b].iter().fold([f32::INFINITY, f32::NEG_INFINITY], |m, &v| [m[0].min(v), m[1].max(v)])
                });
                let got = sub_cell_ranges(&layout, &bytes, n);
                let bits = |r: &[[f32; 2]]| r.iter().map(|m| m.map(f32::to_bits)).collect::<Vec<_>>();
                prop_assert_eq!(bits(&got), bits(&want), "n = {}", n);
            }
        }
    }

    #[test]
    fn malformed_bricks_are_never_skipped() {
        let desc = VolumeDesc {
            dims: [16; 3],
            dtype: DType::U16,
            spacing: [1.0; 3],
            value_range: [0.0, 1.0],
            kind: Default::default(),
        };
        let layout = OctreeLayout::new(desc, 8, 1);
        let all = [f32::NEG_INFINITY, f32::INFINITY];
        assert_eq!(sub_cell_ranges(&layout, &[0; 10], 2), vec![all; 8]);
        assert_eq!(sub_cell_ranges(&layout, &[0; 2000], 0), vec![all]);
        assert_eq!(sub_cells_per_axis(0), 1);
        assert_eq!(sub_cells_per_axis(32), 4);
    }

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
            let desc = VolumeDesc { dims, dtype: DType::U8, spacing: [1.0; 3], value_range: [0.0, 255.0], kind: Default::default() };
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
