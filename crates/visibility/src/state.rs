//! Per-node visibility with the feedback delay, propagated to the root.

use brickray_core::{NodeKey, NodeMap, NodeSet};

/// The knobs of [`VisibilityState`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct VisibilityConfig {
    /// A leaf observed with fewer visible pixels than this is invisible (the
    /// paper's threshold: 4).
    pub threshold_px: u32,
    /// A leaf stays visible while it was seen visible within this many frames
    /// of its latest observation (hysteresis: with occlusion queries rotating
    /// over `N` frames this must be at least `N`, so a leaf not queried this
    /// frame keeps its state).
    pub hold_frames: u32,
    /// Occlusion queries per frame (the screen-tile scheduler's budget; the
    /// renderer caps it at its query set's size, 1024).
    pub queries_per_frame: u32,
}

impl Default for VisibilityConfig {
    fn default() -> Self {
        VisibilityConfig {
            threshold_px: 4,
            hold_frames: 4,
            queries_per_frame: 1024,
        }
    }
}

/// What is known of one data leaf of the current cut.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct LeafVis {
    /// The frame it became a leaf of the cut (observations of earlier frames
    /// are about another cut and are ignored).
    entered: u64,
    /// The latest frame it was observed in (visible or not).
    observed: Option<u64>,
    /// The latest frame it was observed visible in (at least the threshold).
    visible: Option<u64>,
    /// The latest frame it showed any pixel in (propagation uses it).
    reached: Option<u64>,
    /// Pixels of its latest observation.
    pixels: u32,
    /// It became a leaf by collapsing, invisible.
    collapsed: bool,
}

/// Counts of the current cut's data leaves by visibility.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct VisibilityCounts {
    /// Observed and visible.
    pub visible: u32,
    /// Observed and invisible.
    pub invisible: u32,
    /// Not observed since they entered the cut (treated as visible).
    pub unobserved: u32,
}

/// The visibility of the nodes of the current cut (Gobbetti et al. 2008,
/// section 6).
///
/// Each frame, after refinement, [`set_cut`](Self::set_cut) gives it the cut's
/// data leaves: leaves kept from the previous cut keep what was observed of
/// them, new ones start unobserved. Observations ([`observe`](Self::observe))
/// arrive later, tagged with the frame they were rendered in; one about a frame
/// before the leaf entered the cut is ignored. [`visible`](Self::visible)
/// answers for any node:
///
/// * a leaf of the cut: visible until an observation says otherwise, then
///   visible iff it was seen visible within `hold_frames` of its latest
///   observation;
/// * an inner node of the cut: visible iff a data leaf below it is visible or
///   showed at least one pixel (leaf visibility propagated to the root), or it
///   has no data leaf below it (nothing was observed there). Propagating "any
///   pixel" rather than the threshold keeps a node whose children each show
///   fewer pixels than the threshold, but together more, from collapsing and
///   splitting again every few frames;
/// * a leaf that was an inner node of the previous cut (collapsed, because it
///   was invisible) inherits its invisibility: it counts as observed
///   invisible in the frame it became a leaf, so it does not split again until
///   an observation shows it (without this, a collapsed node would be
///   unobserved, hence visible, split, be found invisible, collapse, ...);
/// * a collapsed node that then shows as a leaf (rays crossing only its empty
///   children reach its coarser brick, whose data is smeared over them) is
///   marked *bounced* and stays split while it remains in the cut, even when
///   none of its children shows: otherwise it would collapse and split again
///   every few frames;
/// * any other node (not yet met): visible.
///
/// Refinement splits only visible nodes, so an invisible node stays a leaf at
/// the level it has (its brick is available: its parent's split required it)
/// and posts no load request. Nothing here decays with time: without feedback
/// (a host that stopped submitting) the state simply stays as it is.
#[derive(Debug, Clone, Default)]
pub struct VisibilityState {
    config: VisibilityConfig,
    leaves: NodeMap<LeafVis>,
    /// Propagated visibility of the inner nodes of the cut.
    inner: NodeMap<bool>,
    /// Nodes that collapsed as invisible and then showed as leaves: they stay
    /// split while they are in the cut (see the type's documentation).
    bounced: NodeSet,
    dirty: bool,
    /// The octree of an anisotropic pyramid, whose parents halve only some
    /// axes (`None`: every level halves all axes).
    pyramid: Option<brickray_core::OctreeLayout>,
}

impl VisibilityState {
    /// An empty state: every node visible.
    pub fn new(config: VisibilityConfig) -> VisibilityState {
        VisibilityState {
            config,
            ..Default::default()
        }
    }

    /// Sets the octree the cut's keys belong to: an anisotropic pyramid's
    /// parents come from its split masks (`OctreeLayout::parent`). An octree
    /// (every level halving all axes) needs no call.
    pub fn set_layout(&mut self, layout: &brickray_core::OctreeLayout) {
        self.pyramid = (!layout.is_isotropic()).then(|| layout.clone());
        self.dirty = true;
    }

    fn parent(&self, key: NodeKey) -> Option<NodeKey> {
        match &self.pyramid {
            Some(l) => l.parent(key),
            None => key.parent(),
        }
    }

    /// The configuration.
    pub fn config(&self) -> VisibilityConfig {
        self.config
    }

    /// Changes the configuration (takes effect at the next query).
    pub fn set_config(&mut self, config: VisibilityConfig) {
        self.config = config;
        self.dirty = true;
    }

    /// Forgets everything (every node visible again).
    pub fn clear(&mut self) {
        self.leaves.clear();
        self.inner.clear();
        self.bounced.clear();
        self.dirty = false;
    }

    /// The data leaves of the cut planned for `frame`. Leaves already in the
    /// previous cut keep their observations; new ones start unobserved.
    pub fn set_cut(&mut self, frame: u64, data_leaves: impl IntoIterator<Item = NodeKey>) {
        self.propagate();
        let mut next = NodeMap::with_capacity_and_hasher(self.leaves.len(), Default::default());
        for key in data_leaves {
            let v = self.leaves.get(&key).copied().unwrap_or_else(|| {
                // A collapsed inner node found invisible stays invisible.
                let collapsed_hidden = self.inner.get(&key) == Some(&false);
                LeafVis {
                    entered: frame,
                    observed: collapsed_hidden.then_some(frame),
                    visible: None,
                    reached: None,
                    pixels: 0,
                    collapsed: collapsed_hidden,
                }
            });
            next.insert(key, v);
        }
        self.leaves = next;
        self.dirty = true;
    }

    /// Records that `key` showed `pixels` visible pixels (occlusion query
    /// samples passed, or rays that reached its brick) in the frame `frame`.
    /// Returns false when the observation was ignored: `key` is not a data leaf
    /// of the cut, or became one after `frame`.
    pub fn observe(&mut self, frame: u64, key: NodeKey, pixels: u32) -> bool {
        let threshold = self.config.threshold_px;
        let Some(l) = self.leaves.get_mut(&key) else {
            return false;
        };
        if frame < l.entered {
            return false;
        }
        let latest = |x: Option<u64>| Some(x.map_or(frame, |o| o.max(frame)));
        if l.observed.is_none_or(|o| frame >= o) {
            l.pixels = pixels;
        }
        l.observed = latest(l.observed);
        if pixels >= threshold {
            l.visible = latest(l.visible);
            if l.collapsed {
                self.bounced.insert(key);
            }
        }
        if pixels > 0 {
            l.reached = latest(l.reached);
        }
        self.dirty = true;
        true
    }

    /// Seen at `seen` within the hold of the latest observation (or never
    /// observed).
    fn recent(&self, l: &LeafVis, seen: Option<u64>) -> bool {
        match (l.observed, seen) {
            (None, _) => true,
            (Some(_), None) => false,
            (Some(o), Some(v)) => v.saturating_add(self.config.hold_frames as u64) >= o,
        }
    }

    fn leaf_visible(&self, l: &LeafVis) -> bool {
        self.recent(l, l.visible)
    }

    fn propagate(&mut self) {
        if !self.dirty {
            return;
        }
        self.inner.clear();
        let leaves: Vec<(NodeKey, bool)> = self
            .leaves
            .iter()
            .map(|(k, l)| (*k, self.recent(l, l.reached) || self.leaf_visible(l)))
            .collect();
        for (key, vis) in leaves {
            let mut p = self.parent(key);
            while let Some(a) = p {
                let e = self.inner.entry(a).or_insert(false);
                if *e && !vis {
                    // Already visible, and so are its ancestors; nothing to add.
                    break;
                }
                *e |= vis;
                p = match &self.pyramid {
                    Some(l) => l.parent(a),
                    None => a.parent(),
                };
            }
        }
        let (inner, leaves) = (&self.inner, &self.leaves);
        self.bounced
            .retain(|k| inner.contains_key(k) || leaves.contains_key(k));
        self.dirty = false;
    }

    /// Whether refinement may split `key` (see the type's documentation).
    pub fn visible(&mut self, key: NodeKey) -> bool {
        if let Some(l) = self.leaves.get(&key) {
            return self.leaf_visible(l);
        }
        self.propagate();
        self.inner.get(&key).copied().unwrap_or(true) || self.bounced.contains(&key)
    }

    /// Pixels the latest observation of `key`, a data leaf of the cut, found
    /// (`None` for any other node or a leaf not observed yet).
    pub fn pixels(&self, key: NodeKey) -> Option<u32> {
        self.leaves
            .get(&key)
            .and_then(|l| l.observed.map(|_| l.pixels))
    }

    /// Counts of the cut's data leaves by visibility.
    pub fn counts(&self) -> VisibilityCounts {
        let mut c = VisibilityCounts::default();
        for l in self.leaves.values() {
            match (l.observed.is_some(), self.leaf_visible(l)) {
                (false, _) => c.unobserved += 1,
                (true, true) => c.visible += 1,
                (true, false) => c.invisible += 1,
            }
        }
        c
    }

    /// Data leaves of the cut.
    pub fn leaves(&self) -> usize {
        self.leaves.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn cfg() -> VisibilityConfig {
        VisibilityConfig {
            threshold_px: 4,
            hold_frames: 2,
            queries_per_frame: 64,
        }
    }

    #[test]
    fn unobserved_and_unknown_nodes_are_visible() {
        let mut s = VisibilityState::new(cfg());
        let leaf = NodeKey::ROOT.child(3);
        s.set_cut(1, [leaf]);
        assert!(s.visible(leaf));
        assert!(s.visible(NodeKey::ROOT));
        assert!(s.visible(NodeKey::ROOT.child(5).child(1)));
        assert_eq!(s.counts().unobserved, 1);
    }

    #[test]
    fn pixels_are_the_latest_observation_of_a_leaf() {
        let mut s = VisibilityState::new(cfg());
        let a = NodeKey::ROOT.child(0);
        s.set_cut(5, [a]);
        assert_eq!(s.pixels(a), None);
        assert_eq!(s.pixels(NodeKey::ROOT), None);
        s.observe(6, a, 40);
        assert_eq!(s.pixels(a), Some(40));
        // A late observation of an older frame does not replace a newer one.
        s.observe(5, a, 7);
        assert_eq!(s.pixels(a), Some(40));
        s.observe(7, a, 0);
        assert_eq!(s.pixels(a), Some(0));
        // A leaf that re-enters the cut starts over.
        s.set_cut(8, [a.child(1)]);
        s.set_cut(9, [a]);
        assert_eq!(s.pixels(a), None);
    }

    #[test]
    fn threshold_delay_and_stale_observations() {
        let mut s = VisibilityState::new(cfg());
        let a = NodeKey::ROOT.child(0);
        let b = NodeKey::ROOT.child(1);
        s.set_cut(5, [a, b]);
        // An observation of a frame before the leaves entered is about another cut.
        assert!(!s.observe(4, a, 0));
        assert!(s.visible(a));
        assert!(s.observe(5, a, 3)); // below the threshold of 4
        assert!(!s.visible(a));
        assert!(s.observe(5, b, 4));
        assert!(s.visible(b));
        assert!(s.visible(NodeKey::ROOT));
        // b seen visible at 5, invisible at 6 and 7: held for 2 frames.
        s.observe(6, b, 0);
        s.observe(7, b, 0);
        assert!(s.visible(b));
        s.observe(8, b, 0);
        assert!(!s.visible(b));
        // a, reached by 3 rays at 5 (below the threshold), still keeps the root.
        assert!(s.visible(NodeKey::ROOT));
        s.observe(8, a, 0);
        assert!(!s.visible(NodeKey::ROOT));
        // Late, out-of-order observations never move the latest back.
        s.observe(5, b, 100);
        assert!(!s.visible(b));
        // A node not in the cut is not observed.
        assert!(!s.observe(8, NodeKey::ROOT, 100));
    }

    #[test]
    fn anisotropic_pyramid_parents_follow_the_split_masks() {
        use brickray_core::{DType, OctreeLayout, VolumeDesc};
        // Masks (root first) xyz, xy, xy: level-2 nodes share z with their parent.
        let layout = OctreeLayout::anisotropic(
            VolumeDesc {
                dims: [128, 128, 40],
                dtype: DType::U8,
                spacing: [1.0, 1.0, 4.0],
                value_range: [0.0, 1.0],
                kind: Default::default(),
            },
            32,
            1,
        );
        assert_eq!(layout.split_masks(), vec![7, 3, 3]);
        let mut s = VisibilityState::new(cfg());
        s.set_layout(&layout);
        let a = NodeKey::new(1, 1, 1, 1);
        let kids = layout.children(a);
        assert_eq!(kids.len(), 4);
        // Its children hidden: `a` is hidden, while its z = 0 sibling (the
        // octree parent of these keys) is not touched.
        s.set_cut(1, kids.iter().copied());
        for c in kids.iter() {
            s.observe(1, *c, 0);
        }
        assert!(!s.visible(a));
        assert!(s.visible(NodeKey::new(1, 1, 1, 0)));
        s.observe(2, kids[3], 100);
        assert!(s.visible(a));
        assert!(s.visible(NodeKey::ROOT));
    }

    #[test]
    fn a_collapsed_hidden_node_stays_invisible_until_observed() {
        let mut s = VisibilityState::new(cfg());
        let a = NodeKey::ROOT.child(0);
        s.set_cut(1, a.children());
        for c in a.children() {
            s.observe(1, c, 0);
        }
        assert!(!s.visible(a));
        // Refinement collapses it: a new leaf, but observed invisible.
        s.set_cut(2, [a]);
        assert!(!s.visible(a));
        assert_eq!(s.counts().invisible, 1);
        s.observe(3, a, 9);
        assert!(s.visible(a));
        // Children each below the threshold but reached keep the parent visible.
        s.set_cut(4, a.children());
        for c in a.children() {
            s.observe(4, c, 1);
        }
        assert!(!s.visible(a.child(0)));
        assert!(s.visible(a));
    }

    #[test]
    fn a_node_that_bounces_stays_split() {
        let mut s = VisibilityState::new(cfg());
        let a = NodeKey::ROOT.child(0);
        s.set_cut(1, a.children());
        for c in a.children() {
            s.observe(1, c, 0);
        }
        assert!(!s.visible(a));
        s.set_cut(2, [a]);
        // The coarser brick shows (rays through its empty children).
        s.observe(2, a, 10);
        assert!(s.visible(a));
        s.set_cut(3, a.children());
        for c in a.children() {
            s.observe(3, c, 0);
        }
        // Children hidden again, but it stays split.
        assert!(s.visible(a));
        // Out of the cut, the mark goes.
        s.set_cut(4, [NodeKey::ROOT]);
        s.set_cut(5, a.children());
        for c in a.children() {
            s.observe(5, c, 0);
        }
        assert!(!s.visible(a));
    }

    #[test]
    fn a_leaf_kept_by_the_next_cut_keeps_its_state_a_new_one_starts_over() {
        let mut s = VisibilityState::new(cfg());
        let a = NodeKey::ROOT.child(0);
        s.set_cut(1, [a]);
        s.observe(1, a, 0);
        assert!(!s.visible(a));
        s.set_cut(2, [a]);
        assert!(!s.visible(a));
        // a split, then collapsed again: a fresh leaf, visible until observed.
        s.set_cut(3, a.children());
        s.set_cut(4, [a]);
        assert!(s.visible(a));
        assert!(!s.observe(3, a, 0));
        assert!(s.visible(a));
    }

    /// A random cut: the root split recursively, each node split with the
    /// given choices (depth-first), at most to level 4.
    fn random_cut(splits: &[bool]) -> Vec<NodeKey> {
        let mut leaves = Vec::new();
        let mut stack = vec![NodeKey::ROOT];
        let mut i = 0;
        while let Some(k) = stack.pop() {
            let split = k.level < 4 && splits.get(i).copied().unwrap_or(false);
            i += 1;
            if split {
                stack.extend(k.children());
            } else {
                leaves.push(k);
            }
        }
        leaves
    }

    fn ancestors(k: NodeKey) -> impl Iterator<Item = NodeKey> {
        std::iter::successors(k.parent(), |p| p.parent())
    }

    proptest! {
        /// An inner node is visible iff a data leaf below it is; observing a
        /// leaf visible never makes any node invisible (monotone).
        #[test]
        fn propagation_is_the_or_of_the_leaves_and_monotone(
            splits in proptest::collection::vec(any::<bool>(), 1..200),
            data in proptest::collection::vec(any::<bool>(), 1..600),
            pixels in proptest::collection::vec(0u32..8, 1..600),
            flip in any::<proptest::sample::Index>(),
        ) {
            let cut = random_cut(&splits);
            let data_leaves: Vec<NodeKey> = cut
                .iter()
                .enumerate()
                .filter(|(i, _)| data[i % data.len()])
                .map(|(_, k)| *k)
                .collect();
            let mut s = VisibilityState::new(cfg());
            s.set_cut(1, data_leaves.iter().copied());
            for (i, k) in data_leaves.iter().enumerate() {
                s.observe(1, *k, pixels[i % pixels.len()]);
            }
            let mut inner = std::collections::HashSet::new();
            for k in &cut {
                inner.extend(ancestors(*k));
            }
            let before: Vec<(NodeKey, bool)> =
                inner.iter().map(|n| (*n, s.visible(*n))).collect();
            for (n, vis) in &before {
                let below: Vec<usize> = (0..data_leaves.len())
                    .filter(|&i| ancestors(data_leaves[i]).any(|a| a == *n))
                    .collect();
                // Propagation: any pixel (the threshold applies to leaves).
                let any = below.iter().any(|&i| pixels[i % pixels.len()] > 0);
                prop_assert_eq!(*vis, any || below.is_empty(), "node {:?}", n);
            }
            if !data_leaves.is_empty() {
                let l = data_leaves[flip.index(data_leaves.len())];
                s.observe(1, l, 100);
                prop_assert!(s.visible(l));
                for (n, vis) in before {
                    prop_assert!(!vis || s.visible(n), "{:?} became invisible", n);
                }
                for a in ancestors(l) {
                    prop_assert!(s.visible(a));
                }
            }
        }
    }
}
