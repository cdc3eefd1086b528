//! The pool's size: how many slots a GPU budget buys within the device's 3D
//! texture limit, and the slot grid that lays them out in the atlas, capped
//! at a slot for every brick of the volume.

/// Plain-integer inputs that size the pool.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PoolLimits {
    /// Bytes of GPU memory the pool may use.
    pub budget_bytes: u64,
    /// Bytes one slot costs: its texels in the texture format used plus the
    /// renderer's per-slot side tables ([`GpuFormat::slot_bytes`](crate::GpuFormat::slot_bytes)).
    pub slot_bytes: u64,
    /// Stored voxels per brick side, apron included (`OctreeLayout::stored_side()`).
    pub stored_side: u32,
    /// Device limit on a 3D texture dimension (`max_texture_dimension_3d`).
    pub max_dim: u32,
    /// The most slots the pool can use: a slot for every brick of the volume
    /// ([`GpuFormat::pool_limits`](crate::GpuFormat::pool_limits) sets it;
    /// `u64::MAX` for no cap). A budget beyond it buys nothing, so the grid
    /// stops at the fewest slots that cover it.
    pub max_slots: u64,
}

impl PoolLimits {
    /// The slot grid `[sx, sy, sz]`: each axis `<= max_dim / stored_side`, the
    /// product `<= budget / slot_bytes` and as large as possible, or, where
    /// the budget holds more than [`max_slots`](Self::max_slots), the fewest
    /// slots `>= max_slots`; among equal products the most cube-like. `None`
    /// when not one slot fits.
    pub fn grid(&self) -> Option<[u32; 3]> {
        if self.slot_bytes == 0 || self.stored_side == 0 {
            return None;
        }
        let n = self.budget_bytes / self.slot_bytes;
        let m = (self.max_dim / self.stored_side) as u64;
        if n == 0 || m == 0 {
            return None;
        }
        if self.max_slots < n
            && let Some(g) = covering_grid(self.max_slots, m)
            && g.iter().product::<u64>() <= n
        {
            return Some(g.map(|v| v as u32));
        }
        Some(largest_grid(n, m).map(|v| v as u32))
    }
}

/// The grid `[sx, sy, sz]` (each axis `<= m`) with the largest product
/// `<= n`; among equally large grids the most cube-like.
fn largest_grid(n: u64, m: u64) -> [u64; 3] {
    let m3 = m.saturating_mul(m).saturating_mul(m);
    if n >= m3 {
        return [m; 3];
    }
    // Search sz <= sy <= sx; score = (product, -max extent).
    let mut best = [1u64, 1, 1];
    let mut best_score = (1u64, u64::MAX);
    let mut sz = 1u64;
    while sz <= m && sz * sz * sz <= n {
        let mut sy = sz;
        while sy <= m && sz * sy * sy <= n {
            let sx = (n / (sz * sy)).min(m);
            if sx >= sy {
                let p = sx * sy * sz;
                if p > best_score.0 || (p == best_score.0 && sx < best_score.1) {
                    best = [sx, sy, sz];
                    best_score = (p, sx);
                }
            }
            sy += 1;
        }
        sz += 1;
    }
    best
}

/// The grid `[sx, sy, sz]` (each axis `<= m`) with the smallest product
/// `>= need`; among equally small grids the most cube-like. `None` when
/// `m^3 < need`.
fn covering_grid(need: u64, m: u64) -> Option<[u64; 3]> {
    let need = need.max(1);
    let mut best: Option<([u64; 3], (u64, u64))> = None;
    // Every grid from here on holds at least sz * sy^2 slots.
    let beaten = |best: &Option<([u64; 3], (u64, u64))>, least: u64| {
        best.is_some_and(|(_, (p, _))| least > p)
    };
    for sz in 1..=m {
        if beaten(&best, sz * sz * sz) {
            break;
        }
        for sy in sz..=m {
            if beaten(&best, sz * sy * sy) {
                break;
            }
            let sx = need.div_ceil(sz * sy).max(sy);
            if sx > m {
                continue;
            }
            let score = (sx * sy * sz, sx);
            if best.is_none_or(|(_, b)| score < b) {
                best = Some(([sx, sy, sz], score));
            }
            if sz * sy >= need {
                break;
            }
        }
    }
    best.map(|(g, _)| g)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pool::{BrickPool, PoolError};
    use proptest::prelude::*;

    #[test]
    fn grid_respects_budget_and_max_dim() {
        let l = PoolLimits {
            budget_bytes: 100 * 1000,
            slot_bytes: 1000,
            stored_side: 10,
            max_dim: 2048,
            max_slots: u64::MAX,
        };
        let g = l.grid().unwrap();
        assert_eq!(g.iter().product::<u32>(), 100);
        assert!(g.iter().all(|&a| a * 10 <= 2048));
        // Axis limit 4 => at most 64 slots even with a huge budget.
        let l = PoolLimits {
            budget_bytes: 1 << 40,
            slot_bytes: 1000,
            stored_side: 10,
            max_dim: 40,
            max_slots: u64::MAX,
        };
        assert_eq!(l.grid(), Some([4, 4, 4]));
        // 7 slots, axis limit 2 => best product 6 (or fewer), never above 8.
        let l = PoolLimits {
            budget_bytes: 7000,
            slot_bytes: 1000,
            stored_side: 10,
            max_dim: 20,
            max_slots: u64::MAX,
        };
        let g = l.grid().unwrap();
        assert_eq!(g.iter().product::<u32>(), 4);
        assert!(g.iter().all(|&a| a <= 2));
        let l = PoolLimits {
            budget_bytes: 999,
            slot_bytes: 1000,
            stored_side: 10,
            max_dim: 2048,
            max_slots: u64::MAX,
        };
        assert!(matches!(BrickPool::new(l), Err(PoolError::NoSlots { .. })));
    }

    /// A budget that holds more slots than the volume has bricks is not
    /// allocated beyond them.
    #[test]
    fn grid_stops_at_the_slots_the_volume_can_use() {
        let l = PoolLimits {
            budget_bytes: 1 << 30,
            slot_bytes: 1000,
            stored_side: 36,
            max_dim: 2048,
            max_slots: 72,
        };
        let g = l.grid().unwrap();
        assert_eq!(g.iter().product::<u32>(), 72, "{g:?}");
        // 73 is prime and above the texture's 56 slots an axis: 74 slots.
        let l73 = PoolLimits { max_slots: 73, ..l };
        assert_eq!(l73.grid().unwrap().iter().product::<u32>(), 74);
        // Uncapped, the same budget takes every slot the texture allows.
        let l = PoolLimits {
            max_slots: u64::MAX,
            ..l
        };
        assert_eq!(l.grid(), Some([56, 56, 56]));
    }

    proptest! {
        /// The grid against every grid of a small texture: its product is the
        /// smallest at or above `max_slots` that the budget holds, else the
        /// largest the budget holds; every axis within the texture.
        #[test]
        fn grid_matches_an_exhaustive_search(
            n in 1u64..2000,
            m in 1u64..14,
            cap in 1u64..2500,
        ) {
            let l = PoolLimits {
                budget_bytes: n * 10,
                slot_bytes: 10,
                stored_side: 3,
                max_dim: (m * 3) as u32,
                max_slots: cap,
            };
            let g = l.grid().unwrap();
            prop_assert!(g.iter().all(|&a| a >= 1 && a as u64 <= m));
            let p = g.iter().map(|&a| a as u64).product::<u64>();
            let products: Vec<u64> = (1..=m)
                .flat_map(|x| (1..=m).flat_map(move |y| (1..=m).map(move |z| x * y * z)))
                .filter(|&q| q <= n)
                .collect();
            let covering = products.iter().copied().filter(|&q| q >= cap).min();
            let want = match covering {
                Some(q) if cap < n => q,
                _ => products.iter().copied().max().unwrap(),
            };
            prop_assert_eq!(p, want);
        }
    }
}
