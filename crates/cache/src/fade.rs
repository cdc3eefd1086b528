//! Level-of-detail transitions without popping: GPU-free bookkeeping of the
//! fades between the cut refinement wants and the cut that is drawn.
//!
//! Refinement rebuilds the cut every frame; a region whose level changes would
//! switch from its old brick to its new one in one frame (a *pop*). Instead the
//! *displayed* cut keeps the finer side of every change as leaves and pairs each
//! with its *fallback*, the ancestor brick on the coarser side, and a weight of
//! that fallback: the renderer samples both bricks at the same point and mixes
//! the values by the weight (docs/stability.md).
//!
//! * **split** (a leaf of the last displayed cut is refined into finer leaves):
//!   each new data leaf fades in from that old leaf: fallback weight 1 → 0;
//! * **merge** (finer displayed leaves are replaced by their ancestor): the old
//!   leaves stay in the displayed cut, fading toward the ancestor (0 → 1); when
//!   all of them reach 1 the ancestor is drawn alone;
//! * a change of mind mid-fade reverses the weight from where it is;
//! * a region that was not drawn before (entering the frustum, made visible by
//!   the transfer function) or becomes empty switches at once.
//!
//! Weights move by one step per frame toward their target: `1/n` for
//! [`FadeDuration::Frames`]`(n)`, `dt / duration` for [`FadeDuration::Millis`]
//! but at least `1/`[`MAX_FADE_FRAMES`], so a fade always ends. The bricks a
//! fade needs (the displayed leaves and their fallbacks) are the ones the
//! manager pins in the pool for the frame; nothing here touches the pool.

use crate::refine::{NodeClass, RefinedLeaf};
use brickray_core::{NodeKey, NodeMap, NodeSet};
use std::collections::{HashMap, HashSet};

/// How long a level-of-detail transition lasts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FadeDuration {
    /// This many frames (deterministic; at least 1).
    Frames(u32),
    /// This many milliseconds of frame time (the host's timestamps, or the
    /// manager's clock), never more than [`MAX_FADE_FRAMES`] frames.
    Millis(f32),
}

impl Default for FadeDuration {
    /// 120 ms.
    fn default() -> Self {
        FadeDuration::Millis(120.0)
    }
}

/// Most frames a fade lasts whatever the frame time (a stalled or frozen clock
/// still ends every fade).
pub const MAX_FADE_FRAMES: u32 = 64;

impl FadeDuration {
    /// The weight step of one frame lasting `dt_s` seconds, in `(0, 1]`.
    pub fn step(&self, dt_s: f64) -> f32 {
        let min = 1.0 / MAX_FADE_FRAMES as f32;
        match *self {
            FadeDuration::Frames(n) => 1.0 / n.max(1) as f32,
            FadeDuration::Millis(ms) => {
                if ms.is_nan() || ms <= 0.0 || !ms.is_finite() {
                    return 1.0;
                }
                let s = (dt_s.max(0.0) * 1e3 / ms as f64) as f32;
                if s.is_finite() {
                    s.clamp(min, 1.0)
                } else {
                    1.0
                }
            }
        }
    }

    /// True when the value is usable: frames `>= 1`, milliseconds finite `>= 0`.
    pub fn is_valid(&self) -> bool {
        match *self {
            FadeDuration::Frames(n) => n >= 1,
            FadeDuration::Millis(ms) => ms.is_finite() && ms >= 0.0,
        }
    }
}

/// One leaf being faded: it is drawn as `mix(own, fallback, weight)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fade {
    /// The displayed (finer) leaf.
    pub leaf: NodeKey,
    /// Its fallback: an ancestor whose brick is sampled at the same point.
    pub ancestor: NodeKey,
    /// Weight of the fallback in `[0, 1]`.
    pub weight: f32,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct State {
    ancestor: NodeKey,
    weight: f32,
    /// 0 (split: fading in) or 1 (merge: fading out toward the ancestor).
    target: f32,
}

/// The displayed cut of one frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Displayed {
    /// Leaves tiling the octree cube (refined leaves, with merges still fading
    /// replaced by the leaves they replace).
    pub leaves: Vec<RefinedLeaf>,
    /// Fading leaves with their fallbacks (leaves among `leaves`).
    pub fades: Vec<Fade>,
}

impl Displayed {
    /// The fallbacks that are not displayed leaves themselves (bricks to keep
    /// resident and pinned for the frame), without repeats.
    pub fn fallbacks(&self) -> Vec<NodeKey> {
        let mut seen = HashSet::new();
        self.fades
            .iter()
            .map(|f| f.ancestor)
            .filter(|a| seen.insert(*a))
            .collect()
    }
}

/// The fade state carried from frame to frame.
#[derive(Debug, Default, Clone)]
pub struct Fader {
    /// The octree's layout when its levels may split fewer than three axes
    /// (an anisotropic pyramid: parents follow its split masks); `None`: an
    /// octree.
    layout: Option<brickray_core::OctreeLayout>,
    /// The last displayed cut.
    prev: Vec<RefinedLeaf>,
    /// Active fades by displayed leaf.
    states: NodeMap<State>,
}

fn is_data(l: &RefinedLeaf) -> bool {
    l.class == NodeClass::Data
}

impl Fader {
    /// No history: the next cut is drawn as it is.
    pub fn new() -> Fader {
        Fader::default()
    }

    /// No history, over `layout` (parents follow its split masks).
    pub fn for_layout(layout: &brickray_core::OctreeLayout) -> Fader {
        Fader {
            layout: (!layout.is_isotropic()).then(|| layout.clone()),
            ..Fader::default()
        }
    }

    /// The parent of `key` in the layout.
    fn parent(&self, key: NodeKey) -> Option<NodeKey> {
        match &self.layout {
            Some(l) => l.parent(key),
            None => key.parent(),
        }
    }

    /// Forgets the history and every fade (the next cut switches at once).
    pub fn clear(&mut self) {
        self.prev.clear();
        self.states.clear();
    }

    /// Fades in progress.
    pub fn active(&self) -> usize {
        self.states.len()
    }

    /// Cancels the fade of `leaf` (its fallback could not be made resident):
    /// a split leaf is drawn alone at once; a merge's leaves, likewise, until
    /// the fallback is there.
    pub fn cancel(&mut self, leaf: NodeKey) {
        if let Some(s) = self.states.get_mut(&leaf) {
            if s.target == 0.0 {
                self.states.remove(&leaf);
            } else {
                s.weight = 0.0;
            }
        }
    }

    /// The displayed cut for the refined cut `refined` (a tiling), advancing
    /// every fade by `step` (`None`: fades off, the refined cut is drawn as it
    /// is and every fade ends).
    pub fn advance(&mut self, refined: &[RefinedLeaf], step: Option<f32>) -> Displayed {
        let Some(step) = step.filter(|s| *s > 0.0) else {
            self.clear();
            self.prev = refined.to_vec();
            return Displayed {
                leaves: refined.to_vec(),
                fades: Vec::new(),
            };
        };
        let step = step.min(1.0);
        let prev_data: NodeSet = self
            .prev
            .iter()
            .filter(|l| is_data(l))
            .map(|l| l.key)
            .collect();
        let under = self.drawn_under(refined);
        let mut states: NodeMap<State> = NodeMap::default();
        let mut out = Displayed::default();
        for (i, n) in refined.iter().enumerate() {
            if !is_data(n) {
                out.leaves.push(*n);
            } else if prev_data.contains(&n.key) {
                // Drawn before: a fade in progress goes on toward the leaf.
                if let Some(mut s) = self.states.get(&n.key).copied() {
                    s.target = 0.0;
                    states.insert(n.key, s);
                }
                out.leaves.push(*n);
            } else if let Some(state) = self.split_from(n.key, &prev_data) {
                states.insert(n.key, state);
                out.leaves.push(*n);
            } else {
                let inside = under.get(&i).map(Vec::as_slice).unwrap_or(&[]);
                self.merge(n, inside, step, &mut states, &mut out.leaves);
            }
        }
        // Advance the splits and the reversals (merges advanced above).
        states.retain(|_, s| {
            if s.target == 0.0 {
                s.weight = (s.weight - step).max(0.0);
                s.weight > 0.0
            } else {
                true
            }
        });
        for l in &out.leaves {
            if let Some(s) = states.get(&l.key) {
                out.fades.push(Fade {
                    leaf: l.key,
                    ancestor: s.ancestor,
                    weight: s.weight,
                });
            }
        }
        self.states = states;
        self.prev = out.leaves.clone();
        out
    }

    /// Per refined leaf (its index), the last displayed leaves strictly
    /// inside it (their indices in `prev`).
    fn drawn_under(&self, refined: &[RefinedLeaf]) -> HashMap<usize, Vec<usize>> {
        let refined_keys: NodeMap<usize> = refined
            .iter()
            .enumerate()
            .map(|(i, l)| (l.key, i))
            .collect();
        let mut under: HashMap<usize, Vec<usize>> = HashMap::new();
        for (j, d) in self.prev.iter().enumerate() {
            // A leaf of both cuts lies strictly inside none of the refined
            // leaves (they tile the cube without overlap): its ancestors are
            // not walked (most leaves of a moving view's cut stay).
            if refined_keys.contains_key(&d.key) {
                continue;
            }
            let mut p = self.parent(d.key);
            while let Some(k) = p {
                if let Some(&i) = refined_keys.get(&k) {
                    under.entry(i).or_default().push(j);
                    break;
                }
                p = self.parent(k);
            }
        }
        under
    }

    /// A split: the fade of `key` from the nearest ancestor drawn as a data
    /// leaf last frame, `None` when there is none.
    fn split_from(&self, key: NodeKey, prev_data: &NodeSet) -> Option<State> {
        let mut p = self.parent(key);
        while let Some(a) = p {
            if prev_data.contains(&a) {
                // `a` was drawn as mix(a, a0, w). Start from whichever of
                // mix(n, a, 1) = a and mix(n, a0, w) is nearer to it: the jump
                // is at most half a level's difference, w (a0 - a) or
                // (1 - w) (n - a).
                return Some(match self.states.get(&a) {
                    Some(s) if s.target == 0.0 && s.weight > 0.5 => State {
                        ancestor: s.ancestor,
                        weight: s.weight,
                        target: 0.0,
                    },
                    _ => State {
                        ancestor: a,
                        weight: 1.0,
                        target: 0.0,
                    },
                });
            }
            p = self.parent(a);
        }
        None
    }

    /// A merge (finer data leaves, `inside`, were drawn in `n`): they stay
    /// displayed, fading toward `n`, until all of them reach it; then `n` is
    /// drawn alone. A leaf drawn where nothing was drawn before (no finer
    /// data leaf inside) shows at once.
    fn merge(
        &self,
        n: &RefinedLeaf,
        inside: &[usize],
        step: f32,
        states: &mut NodeMap<State>,
        leaves: &mut Vec<RefinedLeaf>,
    ) {
        if !inside.iter().any(|&j| is_data(&self.prev[j])) {
            leaves.push(*n);
            return;
        }
        let group: Vec<(RefinedLeaf, State)> = inside
            .iter()
            .map(|&j| {
                let d = self.prev[j];
                let weight = if is_data(&d) {
                    let old = match self.states.get(&d.key) {
                        Some(s) if s.ancestor == n.key => s.weight,
                        _ => 0.0,
                    };
                    (old + step).min(1.0)
                } else {
                    1.0
                };
                let s = State {
                    ancestor: n.key,
                    weight,
                    target: 1.0,
                };
                (d, s)
            })
            .collect();
        let done = group
            .iter()
            .filter(|(d, _)| is_data(d))
            .all(|(_, s)| s.weight >= 1.0);
        if done {
            leaves.push(*n);
            return;
        }
        for (d, s) in group {
            if is_data(&d) {
                states.insert(d.key, s);
            }
            leaves.push(d);
        }
    }
}

#[cfg(test)]
#[path = "fade_tests.rs"]
mod tests;
