//! Refinement that evolves the last frame's cut instead of rebuilding it
//! from the root ([`evolve`]), under [`LodMetric::Geometric`] only.
//!
//! A camera that moves a little changes a small part of the cut (0.2% of its
//! leaves a frame along the `host` benchmark's path), while the greedy
//! refinement ([`refine`](super::refine)) classifies the children of every
//! node it visits, every frame. Evolving starts from the last cut and pays,
//! for the nodes that did not change, only their projected size and frustum
//! test (geometry, no cache lookups); it classifies the children of a node
//! only where the node may now split, and the metadata of a split only
//! where it may now merge:
//!
//! 1. Each leaf is revisited: a data leaf now outside the view becomes a
//!    culled leaf, a culled leaf now in view is classified again (with its
//!    brick if it holds visible data; where that brick is not available its
//!    parent's subtree collapses into the parent, as the greedy order would
//!    not have split the parent).
//! 2. The split nodes are revisited from the top: one now outside the view
//!    collapses into a culled leaf, one the visibility feedback hides now
//!    ([`RefineEnv::may_split`]), or within the tolerance whose split costs
//!    bricks (more than one child holds visible data), collapses into a
//!    leaf with its own brick. Split nodes whose children are all leaves are
//!    the candidates to merge, lowest priority first.
//! 3. Data leaves above the tolerance (and the leaves this frame made) are
//!    visited highest priority first exactly as the greedy order visits a
//!    node (uniform, finest, hidden by the feedback, children pending or
//!    failed, bricks missing: requested; within the tolerance only splits
//!    that cost no brick). A split that needs more room than the cut has
//!    merges candidates of lower priority to make it (the split and merge
//!    queues of ROAM, Duchaineau et al. 1997); once no candidate is lower,
//!    the cut is balanced, and the nodes visited after that only request
//!    their children's bricks, up to the frame's prefetch.
//!
//! With a tolerance that binds before the pool and the upload budget (every
//! split the rule wants fits), the result is the greedy refinement's cut,
//! leaf for leaf (`evolve_tests`: a proptest over camera paths), since that
//! cut is then a fixed function of each node's own state: a node splits when
//! its parent did and its own projected size, class and bricks say so, and
//! a node's projected size is never above its parent's. Where the pool binds,
//! the greedy order fills the last slots by a global priority order that an
//! evolving cut only approaches, so the caller hands a view that stops to
//! the greedy refinement (`BrickManager`): the cut at convergence, and the
//! image, are the greedy's.
//!
//! [`evolve`] returns `None` where it does not apply (another metric,
//! lookahead, a last cut that waits for its root or holds octants) or where
//! the cut needs what only the greedy order decides (a brick of the last cut
//! no longer available, a collapse whose node has no brick): the caller then
//! refines from the root.

use super::rank::{Classified, Unknown, classify, known_info, visible_under};
use super::split::{ChildBricks, NEARLY_FULL, known_children, request_meta};
use super::{
    DataState, LoadRequest, MetaClass, NodeClass, RefineEnv, RefineParams, RefinedLeaf, Refinement,
    empty_leaf,
};
use crate::upload::UploadBudget;
use brickray_core::{EmptyReason, LodMetric, NodeKey, NodeMap, NodeSet, OctreeLayout};
use std::cmp::{Ordering, Reverse};
use std::collections::BinaryHeap;

/// Most nodes visited after the cut balanced (the pool binds), for their
/// children's bricks (prefetch). The greedy order visits nodes until a
/// frame's prefetch (thousands of bricks at a cut of 20,000) is counted,
/// most of them in CPU memory already, at a few milliseconds a frame; a
/// moving view changes a few dozen leaves a frame, and the 256 best nodes
/// after the balance are the splits of its next frames. (Every
/// `EVOLVED_FRAMES_MAX`-th frame, and a view that stops, prefetch in full.)
pub(crate) const PREFETCH_VISITS: u32 = 256;

/// A node in the split or merge queue, by priority (ties: the smaller key
/// first, as in the greedy order's heap).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Candidate {
    priority: f64,
    key: NodeKey,
}
impl Eq for Candidate {}
impl PartialOrd for Candidate {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Candidate {
    fn cmp(&self, other: &Self) -> Ordering {
        self.priority
            .total_cmp(&other.priority)
            .then_with(|| other.key.cmp(&self.key))
    }
}

/// A leaf of the evolving cut.
#[derive(Debug, Clone, Copy)]
struct Leaf {
    class: NodeClass,
    /// Its projected voxel size (data leaves).
    priority: f64,
}

/// Why an evolving refinement handed the frame back.
struct GiveUp;

struct Evolve<'p, 'a, 'e> {
    layout: &'p OctreeLayout,
    params: &'p RefineParams<'a>,
    env: &'e mut dyn RefineEnv,
    budget: &'e mut UploadBudget,
    threshold: f64,
    cut: NodeMap<Leaf>,
    /// Leaves made this frame, in the order made (the output lists the last
    /// cut's surviving leaves in their order, then these).
    made: Vec<NodeKey>,
    /// Data leaves.
    data_leaves: i64,
    splits: BinaryHeap<Candidate>,
    merges: BinaryHeap<Reverse<Candidate>>,
    /// Leaves whose upload this frame was charged when they were made.
    charged: NodeSet,
    /// Where the bricks looked up this frame are.
    states: NodeMap<DataState>,
    out: Refinement,
    /// Bricks not on the GPU among the data children of the nodes visited
    /// while the cut was nearly full (the greedy order's prefetch).
    prefetched: u32,
    /// `(p, gain)`: merging every candidate below priority `p` would give
    /// back at most `gain` bricks (learnt when a split of priority `p` found
    /// too little; the split queue goes down in priority, and a merge
    /// candidate added later is of a split's priority, above what follows).
    gain_below: Option<(f64, i64)>,
    /// The cut may differ from the greedy order's: the pool refused a
    /// split, a merge made room, or a split node was kept for want of its
    /// brick (module docs).
    provisional: bool,
}

/// Evolves the cut `last` (a refinement of an earlier frame under the same
/// layout, mode, transfer function and channels) to the views of `params`.
/// `recheck_within`: metadata arrived since `last` was made, or a split of
/// `last` waited for metadata or bricks, so the leaves within the tolerance
/// are visited again, as the greedy order visits them every frame (a split
/// that costs no brick may have become known, or may request what it
/// waits for). With the refinement, whether it is provisional: the pool
/// refused a split, a merge made room or a split node was kept for want of
/// its brick, so the greedy order may give another cut (where it is not,
/// the greedy order's cut is this one). `None` where it does not apply
/// (module docs).
pub(crate) fn evolve(
    layout: &OctreeLayout,
    params: &RefineParams<'_>,
    env: &mut dyn RefineEnv,
    budget: &mut UploadBudget,
    last: &[RefinedLeaf],
    recheck_within: bool,
) -> Option<(Refinement, bool)> {
    if !matches!(params.metric, LodMetric::Geometric) || params.lookahead || last.is_empty() {
        return None;
    }
    let mut e = Evolve {
        layout,
        params,
        env,
        budget,
        threshold: params.tolerance_px.max(0.0) as f64,
        cut: NodeMap::default(),
        made: Vec::new(),
        data_leaves: 0,
        splits: BinaryHeap::new(),
        merges: BinaryHeap::new(),
        charged: NodeSet::default(),
        states: NodeMap::default(),
        out: Refinement::default(),
        prefetched: 0,
        gain_below: None,
        provisional: false,
    };
    e.cut.reserve(last.len() + last.len() / 8);
    for l in last {
        match l.class {
            NodeClass::Data => e.data_leaves += 1,
            NodeClass::Empty(EmptyReason::Empty | EmptyReason::Invisible | EmptyReason::Culled) => {
            }
            NodeClass::Empty(_) | NodeClass::Borrowed => return None,
        }
        e.cut.insert(
            l.key,
            Leaf {
                class: l.class,
                priority: 0.0,
            },
        );
    }
    if e.cut.len() != last.len() {
        return None;
    }
    e.revisit_leaves(last, recheck_within).ok()?;
    e.revisit_splits().ok()?;
    e.split_and_merge();
    e.make_room().ok()?;
    let provisional = e.provisional;
    e.finish(last).ok().map(|r| (r, provisional))
}

impl Evolve<'_, '_, '_> {
    fn culled(&self, key: NodeKey) -> bool {
        self.params.views.culled(key)
    }

    /// `key`'s class under this frame's views, without its metadata.
    fn classify(&mut self, key: NodeKey) -> Result<Classified, Unknown> {
        classify(
            key,
            self.layout,
            self.params,
            self.params.views,
            self.env,
            false,
        )
    }

    fn priority(&self, key: NodeKey) -> f64 {
        self.params.views.voxel_pixels(key)
    }

    fn room(&self) -> i64 {
        self.params.max_data_leaves as i64 - self.data_leaves
    }

    /// Where `key`'s brick is (looked up once a frame).
    fn data(&mut self, key: NodeKey) -> DataState {
        if let Some(s) = self.states.get(&key) {
            return *s;
        }
        let s = self.env.data(key);
        self.states.insert(key, s);
        s
    }

    /// Whether `key` (a data node) can be a leaf with its brick this frame,
    /// charging its upload when it is in CPU memory only.
    fn take_brick(&mut self, key: NodeKey) -> bool {
        match self.data(key) {
            DataState::OnGpu => true,
            DataState::InCpu if self.charged.contains(&key) => true,
            DataState::InCpu => {
                let ok = self.budget.try_reserve(self.params.brick_upload_bytes);
                if ok {
                    self.charged.insert(key);
                }
                ok
            }
            DataState::Missing | DataState::Failed => false,
        }
    }

    fn insert(&mut self, key: NodeKey, class: NodeClass, priority: f64) {
        if class == NodeClass::Data {
            self.data_leaves += 1;
        }
        self.cut.insert(key, Leaf { class, priority });
        self.made.push(key);
    }

    /// Removes every leaf under `key` (an inner node of the cut).
    fn remove_under(&mut self, key: NodeKey) {
        for &c in &self.layout.children(key) {
            match self.cut.remove(&c) {
                Some(l) => {
                    if l.class == NodeClass::Data {
                        self.data_leaves -= 1;
                    }
                    if self.charged.remove(&c) {
                        self.budget.release(self.params.brick_upload_bytes);
                    }
                }
                None => self.remove_under(c),
            }
        }
    }

    /// Step 1 (module docs): each leaf of the last cut under this frame's
    /// views.
    fn revisit_leaves(&mut self, last: &[RefinedLeaf], recheck: bool) -> Result<(), GiveUp> {
        let mut collapse = Vec::new();
        // (Heapified once: a push each costs more at tens of thousands.)
        let mut splits = Vec::with_capacity(last.len());
        for l in last {
            let key = l.key;
            match l.class {
                NodeClass::Data if self.culled(key) => {
                    self.data_leaves -= 1;
                    self.cut
                        .insert(key, leaf(NodeClass::Empty(EmptyReason::Culled)));
                }
                NodeClass::Data => {
                    let p = self.priority(key);
                    if let Some(leaf) = self.cut.get_mut(&key) {
                        leaf.priority = p;
                    }
                    if p > self.threshold || recheck {
                        splits.push(Candidate { priority: p, key });
                    }
                }
                NodeClass::Empty(EmptyReason::Culled) if !self.culled(key) => {
                    match self.classify(key) {
                        Ok(Classified {
                            class: NodeClass::Data,
                            ..
                        }) => {
                            if self.take_brick(key) {
                                let p = self.priority(key);
                                self.data_leaves += 1;
                                self.cut.insert(
                                    key,
                                    Leaf {
                                        class: NodeClass::Data,
                                        priority: p,
                                    },
                                );
                                splits.push(Candidate { priority: p, key });
                            } else {
                                collapse.push(self.layout.parent(key).ok_or(GiveUp)?);
                            }
                        }
                        Ok(c) => {
                            self.cut.insert(key, leaf(c.class));
                        }
                        Err(_) => collapse.push(self.layout.parent(key).ok_or(GiveUp)?),
                    }
                }
                _ => {}
            }
        }
        self.splits = BinaryHeap::from(splits);
        for p in collapse {
            // A parent collapsed already (as a sibling's, or under an
            // ancestor collapsed before it) is a leaf or inside one.
            if self.inside_leaf(p) {
                continue;
            }
            self.collapse_to_data(p)?;
        }
        Ok(())
    }

    /// Whether `key` is a leaf of the cut or lies under one.
    fn inside_leaf(&self, key: NodeKey) -> bool {
        let mut k = Some(key);
        while let Some(n) = k {
            if self.cut.contains_key(&n) {
                return true;
            }
            k = self.layout.parent(n);
        }
        false
    }

    /// Collapses the inner node `key` into a leaf with its brick (which must
    /// be available; else the frame goes back to the greedy order).
    fn collapse_to_data(&mut self, key: NodeKey) -> Result<(), GiveUp> {
        let class = self.classify(key).map_err(|_| GiveUp)?;
        if class.class != NodeClass::Data || !self.take_brick(key) {
            return Err(GiveUp);
        }
        self.remove_under(key);
        let p = self.priority(key);
        self.insert(key, NodeClass::Data, p);
        self.splits.push(Candidate { priority: p, key });
        Ok(())
    }

    /// Step 2 (module docs): the split nodes of the cut, from the top.
    fn revisit_splits(&mut self) -> Result<(), GiveUp> {
        // The split nodes, with how many of their children are leaves.
        let mut inner: NodeMap<u8> = NodeMap::default();
        inner.reserve(self.cut.len() / 4);
        for k in self.cut.keys() {
            let Some(parent) = self.layout.parent(*k) else {
                continue;
            };
            let n = inner.entry(parent).or_insert(0);
            *n += 1;
            if *n > 1 {
                continue;
            }
            let mut p = self.layout.parent(parent);
            while let Some(a) = p {
                if inner.contains_key(&a) {
                    break;
                }
                inner.insert(a, 0);
                p = self.layout.parent(a);
            }
        }
        let mut order: Vec<(NodeKey, u8)> = inner.into_iter().collect();
        order.sort_unstable_by_key(|n| n.0);
        // Split nodes under a leaf made in this pass or the last step.
        let mut gone = NodeSet::default();
        for (key, leaf_children) in order {
            if let Some(p) = self.layout.parent(key)
                && (gone.contains(&p) || self.cut.contains_key(&p))
            {
                gone.insert(key);
                continue;
            }
            if self.cut.contains_key(&key) {
                gone.insert(key);
                continue;
            }
            if self.culled(key) {
                self.remove_under(key);
                self.insert(key, NodeClass::Empty(EmptyReason::Culled), 0.0);
                continue;
            }
            let p = self.priority(key);
            // Hidden by the feedback (`RefineEnv::may_split`): a leaf at its
            // level, visited as one (and counted) in step 3.
            if !self.env.may_split(key) {
                self.collapse_or_keep(key, p, true);
                continue;
            }
            if p <= self.threshold && !self.costs_no_brick(key, None) {
                self.collapse_or_keep(key, p, false);
                continue;
            }
            if leaf_children as usize == self.layout.children(key).len() {
                self.merges.push(Reverse(Candidate { priority: p, key }));
            }
        }
        Ok(())
    }

    /// Collapses the split node `key` (of priority `p`) into a leaf with
    /// its brick (to be `visited` in step 3: a node the feedback hides is
    /// counted there), or, while that brick is not available, keeps it
    /// split (finer than the rule asks: provisional) and requests it.
    fn collapse_or_keep(&mut self, key: NodeKey, p: f64, visited: bool) {
        if !self.take_brick(key) {
            self.provisional = true;
            self.request_own(key, p);
            return;
        }
        self.remove_under(key);
        self.insert(key, NodeClass::Data, p);
        if visited {
            self.splits.push(Candidate { priority: p, key });
        }
    }

    /// Requests `key`'s own brick where it is missing.
    fn request_own(&mut self, key: NodeKey, priority: f64) {
        if self.data(key) != DataState::Missing {
            return;
        }
        if let Some(info) = known_info(self.env, key) {
            self.out.requests.push(LoadRequest {
                key,
                priority: priority as f32,
                info,
            });
        }
    }

    /// Whether every child of the inner node `key` is a leaf.
    fn mergeable(&self, key: NodeKey) -> bool {
        self.layout
            .children(key)
            .iter()
            .all(|c| self.cut.contains_key(c))
    }

    /// Within the tolerance a node splits only when the split costs no
    /// brick: at most one child holds visible data by its metadata (the
    /// greedy order's rule). A child whose metadata is pending or failed
    /// leaves that unknown (false); with `request_at`, pending metadata is
    /// asked for at that priority when only it is in the way.
    fn costs_no_brick(&mut self, key: NodeKey, request_at: Option<f64>) -> bool {
        let visible = visible_under(self.params, self.layout);
        let (mut data, mut failed, mut pending) = (0, false, Vec::new());
        for &c in &self.layout.children(key) {
            if !self.layout.in_volume(c) {
                continue;
            }
            match self.env.meta_class(c, &visible) {
                MetaClass::Empty | MetaClass::Invisible => {}
                MetaClass::Data { .. } => data += 1,
                MetaClass::Pending => pending.push(c),
                MetaClass::Failed => failed = true,
            }
            if data > 1 {
                return false;
            }
        }
        if let Some(p) = request_at
            && !failed
        {
            request_meta(&mut self.out, &pending, p);
        }
        !failed && pending.is_empty()
    }

    /// Step 3 (module docs): the split queue against the merge queue.
    fn split_and_merge(&mut self) {
        let finest = self.layout.levels.saturating_sub(1);
        // Visits after the cut balanced: bounded by the frame's prefetch.
        let after_balance_max = self
            .params
            .max_prefetch
            .min(self.params.max_requests)
            .min(PREFETCH_VISITS);
        let mut balanced = false;
        let mut after_balance = 0u32;
        while let Some(Candidate { priority: p, key }) = self.splits.pop() {
            match self.cut.get(&key) {
                Some(l) if l.class == NodeClass::Data && l.priority.total_cmp(&p).is_eq() => {}
                _ => continue,
            }
            if balanced {
                if after_balance >= after_balance_max || self.prefetched >= self.params.max_prefetch
                {
                    break;
                }
                after_balance += 1;
            }
            if key.level >= finest || !p.is_finite() {
                continue;
            }
            let visible = visible_under(self.params, self.layout);
            if !matches!(
                self.env.meta_class(key, &visible),
                MetaClass::Data { uniform: false }
            ) {
                continue;
            }
            let within = p <= self.threshold;
            if !self.env.may_split(key) {
                if !within {
                    self.out.blocked.invisible += 1;
                }
                continue;
            }
            if within && !self.costs_no_brick(key, Some(p)) {
                continue;
            }
            let children = self.layout.children(key);
            let (layout, params) = (self.layout, self.params);
            let known =
                known_children(&children, layout, params, self.env, false, p, &mut self.out);
            if let Some(classes) = known {
                self.split(key, p, &classes, &mut balanced);
            }
        }
    }

    /// Splits the data leaf `key` when its children's bricks are available
    /// (else they are requested), the cut has room (merging candidates of
    /// lower priority to make it) and the upload budget takes them;
    /// `balanced` is set once a split found no room.
    fn split(&mut self, key: NodeKey, p: f64, classes: &[Classified; 8], balanced: &mut bool) {
        let children = self.layout.children(key);
        let bricks = ChildBricks::of(&children, classes, |c| self.data(c));
        let prefetch = bricks.prefetch(self.room() < NEARLY_FULL as i64);
        let failed = bricks.count(DataState::Failed);
        if failed > 0 {
            self.out.blocked.failed += 1;
            self.out.failed_needed += failed;
            return;
        }
        if bricks.count(DataState::Missing) > 0 {
            let order = p * self.env.request_weight(key) * self.params.views.centre_weight(key);
            bricks.request_missing(&children, classes, order, self.env, &mut self.out);
            self.out.blocked.missing_data += 1;
            self.prefetched = self.prefetched.saturating_add(prefetch);
            return;
        }
        let data = bricks.data();
        let cost = data.len() as i64 - 1;
        if self.room() < cost && !self.merge_for(key, p, cost) {
            self.out.blocked.pool_full += 1;
            self.prefetched = self.prefetched.saturating_add(prefetch);
            *balanced = true;
            self.provisional = true;
            return;
        }
        let bytes = self.params.brick_upload_bytes;
        let uploads = bricks.count(DataState::InCpu) as u64;
        let charged = self.charged.contains(&key);
        let release = if charged { bytes } else { 0 };
        if uploads > 0 && !self.budget.try_exchange(release, uploads * bytes) {
            self.out.blocked.upload_budget += 1;
            self.provisional = true;
            return;
        }
        if charged {
            if uploads == 0 {
                self.budget.release(bytes);
            }
            self.charged.remove(&key);
        }
        self.cut.remove(&key);
        self.data_leaves -= 1;
        let mut state = bricks.states().iter();
        for (i, &c) in children.iter().enumerate() {
            match classes[i].class {
                NodeClass::Data => {
                    let cp = self.priority(c);
                    if state.next() == Some(&DataState::InCpu) {
                        self.charged.insert(c);
                    }
                    self.insert(c, NodeClass::Data, cp);
                    self.splits.push(Candidate {
                        priority: cp,
                        key: c,
                    });
                }
                class => self.insert(c, class, 0.0),
            }
        }
        self.merges.push(Reverse(Candidate { priority: p, key }));
    }

    /// Makes `cost` bricks of room for splitting `key` (of priority `p`) by
    /// merging candidates of lower priority whose bricks are available
    /// (never `key`'s parent), lowest first, when together they give back
    /// enough (else none is merged: a split the greedy order found no room
    /// for keeps the smaller splits that filled the room after it). True
    /// when the room is there.
    fn merge_for(&mut self, key: NodeKey, p: f64, cost: i64) -> bool {
        let parent = self.layout.parent(key);
        let need = cost - self.room();
        if self
            .gain_below
            .is_some_and(|(below, gain)| p <= below && gain < need)
        {
            return false;
        }
        let (mut taken, mut kept, mut gain) = (Vec::new(), Vec::new(), 0);
        while gain < need {
            let Some(Reverse(m)) = self.merges.pop() else {
                break;
            };
            if m.priority.total_cmp(&p).is_ge() {
                kept.push(m);
                break;
            }
            // (A candidate that is a leaf now, or has a split child, is stale.)
            if self.cut.contains_key(&m.key) || !self.mergeable(m.key) {
                continue;
            }
            let gives = self.data_children(m.key) - 1;
            let available = matches!(self.data(m.key), DataState::OnGpu | DataState::InCpu);
            if Some(m.key) == parent || gives <= 0 || !available {
                kept.push(m);
                continue;
            }
            gain += gives;
            taken.push(m);
        }
        if gain >= need {
            self.provisional = true;
            for m in taken.drain(..) {
                if !self.merge(m.key) {
                    kept.push(m);
                }
            }
        } else {
            self.gain_below = Some((p, gain));
        }
        self.merges
            .extend(taken.into_iter().chain(kept).map(Reverse));
        self.room() >= cost
    }

    /// The data leaves among the children of `key`.
    fn data_children(&self, key: NodeKey) -> i64 {
        self.layout
            .children(key)
            .iter()
            .filter(|c| self.cut.get(c).is_some_and(|l| l.class == NodeClass::Data))
            .count() as i64
    }

    /// Merges the inner node `key` into a leaf with its brick, when it is
    /// still a candidate (every child a leaf) and its brick is available.
    fn merge(&mut self, key: NodeKey) -> bool {
        if self.cut.contains_key(&key) || !self.mergeable(key) || !self.take_brick(key) {
            return false;
        }
        self.remove_under(key);
        let p = self.priority(key);
        self.insert(key, NodeClass::Data, p);
        true
    }

    /// A cut with more data leaves than the pool's slots (the slots shrank,
    /// or leaves came into view) merges its lowest candidates until it fits.
    fn make_room(&mut self) -> Result<(), GiveUp> {
        while self.room() < 0 {
            self.provisional = true;
            let Reverse(m) = self.merges.pop().ok_or(GiveUp)?;
            self.merge(m.key);
        }
        Ok(())
    }

    /// The refinement: every leaf with its brick's state, the requests in
    /// priority order within the frame's cap.
    fn finish(mut self, last: &[RefinedLeaf]) -> Result<Refinement, GiveUp> {
        let mut leaves = Vec::with_capacity(self.cut.len());
        let made = std::mem::take(&mut self.made);
        // (Each leaf leaves the map as it is listed: a node made twice, or
        // gone and made again, is listed once.)
        for key in last.iter().map(|l| l.key).chain(made) {
            let Some(l) = self.cut.remove(&key) else {
                continue;
            };
            match l.class {
                NodeClass::Data => {
                    let state = match self.states.get(&key) {
                        Some(s) => *s,
                        None => self.env.data(key),
                    };
                    let needs_upload = match state {
                        DataState::OnGpu => false,
                        DataState::InCpu if self.charged.contains(&key) => true,
                        DataState::InCpu => {
                            if !self.budget.try_reserve(self.params.brick_upload_bytes) {
                                return Err(GiveUp);
                            }
                            true
                        }
                        DataState::Missing | DataState::Failed => return Err(GiveUp),
                    };
                    leaves.push(RefinedLeaf {
                        key,
                        class: NodeClass::Data,
                        priority: if l.priority.is_finite() {
                            l.priority as f32
                        } else {
                            0.0
                        },
                        needs_upload,
                    });
                }
                NodeClass::Empty(r) => leaves.push(empty_leaf(key, r)),
                NodeClass::Borrowed => return Err(GiveUp),
            }
        }
        let max_requests = self.params.max_data_leaves.min(self.params.max_requests) as usize;
        let out = &mut self.out;
        out.requests
            .sort_by(|a, b| b.priority.total_cmp(&a.priority).then(a.key.cmp(&b.key)));
        // (A brick asked for twice, as a child and as a merge's own, once.)
        let mut asked = NodeSet::default();
        out.requests.retain(|r| asked.insert(r.key));
        out.requests.truncate(max_requests);
        out.data_leaves = self.data_leaves.max(0) as u32;
        out.leaves = leaves;
        Ok(self.out)
    }
}

fn leaf(class: NodeClass) -> Leaf {
    Leaf {
        class,
        priority: 0.0,
    }
}
