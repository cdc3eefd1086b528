//! Shared helpers of the integration tests: a tiny deterministic RNG and random cuts.
#![allow(dead_code, unreachable_pub)]

use brickray_core::brick::NodeKey;
use brickray_index::{CutLeaf, EmptyReason};
use std::collections::VecDeque;

/// SplitMix64.
#[derive(Debug, Clone)]
pub struct Rng(pub u64);

impl Rng {
    pub fn u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn f64(&mut self) -> f64 {
        (self.u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.f64()
    }
    /// Uniform integer in [0, n).
    pub fn below(&mut self, n: u64) -> u64 {
        self.u64() % n
    }
    pub fn chance(&mut self, p: f64) -> bool {
        self.f64() < p
    }
}

/// A random cut: the root refined breadth first, each node at `level < max_depth`
/// with probability `p_refine`, while the leaf count stays within `budget`.
pub fn random_cut(
    rng: &mut Rng,
    max_depth: u8,
    p_refine: f64,
    p_data: f64,
    budget: usize,
) -> Vec<CutLeaf> {
    let mut queue = VecDeque::from([NodeKey::ROOT]);
    let mut leaves = Vec::new();
    let mut count = 1usize;
    let mut slot = 0u32;
    while let Some(k) = queue.pop_front() {
        // The root is always refined (when allowed), so that cuts are not trivial.
        if k.level < max_depth && count + 7 <= budget && (k.level == 0 || rng.chance(p_refine)) {
            count += 7;
            queue.extend(k.children());
        } else {
            leaves.push(if rng.chance(p_data) {
                slot += 1;
                CutLeaf::data(k, slot * 3 + 1)
            } else {
                CutLeaf::empty(k, EmptyReason::Empty)
            });
        }
    }
    leaves
}

/// A uniform cut at `level`.
pub fn uniform_cut(level: u8) -> Vec<CutLeaf> {
    let n = 1u32 << level;
    let mut v = Vec::new();
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                v.push(CutLeaf::data(NodeKey::new(level, x, y, z), v.len() as u32));
            }
        }
    }
    v
}

/// Fisher-Yates.
pub fn shuffle<T>(rng: &mut Rng, v: &mut [T]) {
    for i in (1..v.len()).rev() {
        let j = rng.below(i as u64 + 1) as usize;
        v.swap(i, j);
    }
}
