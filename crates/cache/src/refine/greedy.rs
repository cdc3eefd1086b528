//! Per-node greedy refinement ([`refine`](super::refine) under every metric
//! but `VisibleOctants`), as phases over one state: the
//! [`root`](Greedy::root) is classified and queued, then each node popped in
//! priority order is [`visited`](Greedy::visit): a terminal node stays a
//! leaf, a node within the tolerance splits only when the split is
//! [`free`](Greedy::free_within), its children are
//! [`classified`](Greedy::children), and the [`split`](Greedy::split) happens
//! when their bricks are available and the pool and the upload budget take
//! them; [`finish`](Greedy::finish) turns what stayed into leaves.

use super::rank::{
    Classified, HeapItem, ScreenError, Unknown, classify, classify_children, known_info,
    visible_under,
};
use super::split::{ChildBricks, NEARLY_FULL, known_children, request_meta};
use super::{
    DataState, LoadRequest, MetaClass, NodeClass, RefineEnv, RefineParams, RefinedLeaf, Refinement,
    empty_leaf, unknown_root,
};
use crate::upload::UploadBudget;
use brickray_core::{EmptyReason, NodeKey, OctreeLayout};
use std::collections::BinaryHeap;

pub(super) struct Greedy<'p, 'a, 'e> {
    layout: &'p OctreeLayout,
    params: &'p RefineParams<'a>,
    env: &'e mut dyn RefineEnv,
    budget: &'e mut UploadBudget,
    screen: ScreenError,
    out: Refinement,
    heap: BinaryHeap<HeapItem>,
    /// Nodes that stay leaves and need their brick: (key, priority).
    finals: Vec<(NodeKey, f64)>,
    /// Splits the upload budget refused. The budget may be held by
    /// speculative charges (children charged at their parent's split) that
    /// come back when those children split into bricks already on the GPU;
    /// the refused splits are retried once the heap is empty, as long as a
    /// round still splits something (each node splits at most once, so this
    /// ends).
    deferred: Vec<HeapItem>,
    /// Children's classifications of the nodes ranked per brick.
    arena: Vec<[Classified; 8]>,
    /// Splits the pool refused, retried the same way: a later split whose
    /// children are all empty or invisible gives its brick back (nodes within
    /// the tolerance, which pop last, do that), and the refused node, of
    /// higher priority, may then fit. With each, the bricks its split adds:
    /// only those that now fit are retried.
    pool_deferred: Vec<(HeapItem, u32)>,
    split_since_retry: bool,
    /// Bricks not on the GPU among the data children of the nodes visited
    /// while the cut was nearly full ([`NEARLY_FULL`]): what those nodes
    /// prefetch, bounded by [`RefineParams::max_prefetch`].
    prefetched: u32,
}

/// What a child's metadata alone says of its data
/// ([`Greedy::child_data`]).
enum ChildData {
    Data,
    None,
    Pending,
    Failed,
}

impl<'p, 'a, 'e> Greedy<'p, 'a, 'e> {
    /// Classifies and queues the root; `Err` holds the whole refinement when
    /// the root is all there is (empty, unknown, or no room for a brick).
    pub(super) fn root(
        layout: &'p OctreeLayout,
        params: &'p RefineParams<'a>,
        env: &'e mut dyn RefineEnv,
        budget: &'e mut UploadBudget,
    ) -> Result<Self, Refinement> {
        let root = NodeKey::ROOT;
        let mut out = Refinement::default();
        let c = match classify(root, layout, params, params.views, env, true) {
            Ok(Classified {
                class: NodeClass::Empty(r),
                ..
            }) => {
                out.leaves.push(empty_leaf(root, r));
                return Err(out);
            }
            Ok(c) => c,
            Err(u) => return Err(unknown_root(u)),
        };
        let screen = ScreenError::new(params, c.info.as_deref(), layout);
        let priority = screen.priority(
            params.views.voxel_pixels(root),
            env.visible_weight(root),
            root,
            c.info.as_deref(),
            params,
            layout,
        );
        if params.max_data_leaves == 0 {
            out.leaves.push(empty_leaf(root, EmptyReason::NotLoaded));
            out.blocked.pool_full += 1;
            return Err(out);
        }
        out.data_leaves = 1;
        // The root's brick is wanted first (it is charged to the upload
        // budget only if it ends up a leaf).
        if let (DataState::Missing, Some(info)) = (env.data(root), c.info) {
            out.requests.push(LoadRequest {
                key: root,
                priority: f32::MAX,
                info,
            });
        }
        let mut heap = BinaryHeap::new();
        heap.push(HeapItem {
            order: priority,
            priority,
            classified: None,
            key: root,
            uniform: c.uniform,
            charged: false,
        });
        Ok(Greedy {
            layout,
            params,
            env,
            budget,
            screen,
            out,
            heap,
            finals: Vec::new(),
            deferred: Vec::new(),
            arena: Vec::new(),
            pool_deferred: Vec::new(),
            split_since_retry: false,
            prefetched: 0,
        })
    }

    /// Visits nodes in priority order until nothing more can split.
    pub(super) fn run(&mut self) {
        while let Some(item) = self.next() {
            self.visit(item);
        }
    }

    /// The next node to visit: the heap's best, or, once it is empty, the
    /// splits refused for the upload budget or the pool that may now pass
    /// (while the last round split something).
    fn next(&mut self) -> Option<HeapItem> {
        if self.heap.is_empty() {
            let room = self
                .params
                .max_data_leaves
                .saturating_sub(self.out.data_leaves);
            let fits = |d: &(HeapItem, u32)| d.1 <= room;
            if (self.deferred.is_empty() && !self.pool_deferred.iter().any(fits))
                || !self.split_since_retry
            {
                return None;
            }
            self.split_since_retry = false;
            self.heap.extend(self.deferred.drain(..));
            let (retry, keep): (Vec<_>, Vec<_>) = self.pool_deferred.drain(..).partition(fits);
            self.pool_deferred = keep;
            self.heap.extend(retry.into_iter().map(|d| d.0));
        }
        self.heap.pop()
    }

    /// One node: it stays a leaf, goes back into the heap ranked per brick,
    /// or splits.
    fn visit(&mut self, item: HeapItem) {
        let (key, priority) = (item.key, item.priority);
        let finest = self.layout.levels.saturating_sub(1);
        // A non-finite size (a non-finite camera or frame) is never refined.
        if item.uniform || key.level >= finest || !priority.is_finite() {
            self.finals.push((key, priority));
            return;
        }
        // The cut is (nearly) full and the prefetch is spent: a node whose
        // split cannot fit by its children's metadata stays a leaf,
        // unclassified (without this, each frame of a full cut classified
        // every child of every such node, and requested their bricks
        // without end once they outgrew the CPU cache).
        if self.prefetch_spent() && !self.may_fit(key) {
            self.out.blocked.pool_full += 1;
            self.finals.push((key, priority));
            return;
        }
        // Within the tolerance (or error budget): a node still splits when the
        // split costs no brick, i.e. at most one child needs data (the others
        // are empty, invisible under the mode or outside the view), so the cut
        // gets finer without growing; otherwise it stays.
        let within = priority <= self.screen.threshold;
        // Hidden in the previous frames: stays at its level, requests nothing.
        if !self.env.may_split(key) {
            if !within {
                self.out.blocked.invisible += 1;
            }
            self.finals.push((key, priority));
            return;
        }
        let children = self.layout.children(key);
        if !within && item.classified.is_none() && self.rank_per_brick(&item, &children) {
            return;
        }
        if within && !self.free_within(key, priority, &children) {
            return;
        }
        if let Some(classes) = self.children(&item, &children) {
            self.split(item, &children, &classes);
        }
    }

    /// Error-aware refinement ranks a split by the error it removes per
    /// brick it adds (a node whose split needs one more brick before one that
    /// needs seven): once the children are known, the node goes back into the
    /// heap at its priority over those bricks, and splits when it comes out
    /// again. Only the order changes, so under a tolerance (or error budget)
    /// the cut is the same; under a brick budget the bricks go where they buy
    /// the most error. Unknown children leave the order as it is (the split
    /// requests them). True when the node went back.
    fn rank_per_brick(&mut self, item: &HeapItem, children: &[NodeKey]) -> bool {
        if self.screen.table.is_none() {
            return false;
        }
        let Some(classes) = classify_children(
            children,
            self.layout,
            self.params,
            self.params.views,
            self.env,
            self.screen.needs_info(),
        ) else {
            return false;
        };
        let data = classes[..children.len()]
            .iter()
            .filter(|c| c.class == NodeClass::Data)
            .count() as u32;
        self.arena.push(classes);
        self.heap.push(HeapItem {
            order: item.priority / f64::from(data.saturating_sub(1).max(1)),
            classified: Some(self.arena.len() as u32 - 1),
            ..*item
        });
        true
    }

    /// Within the tolerance, a split is free only if at most one child needs
    /// data: stop at the second (most nodes of a dense region stop after two
    /// or three children). By metadata alone (the frustum test, the costly
    /// part, is left to the split: a culled child counts as data here). True
    /// when the node may go on to split; otherwise it stays a leaf (its
    /// children's missing metadata asked for after every wanted split's).
    fn free_within(&mut self, key: NodeKey, priority: f64, children: &[NodeKey]) -> bool {
        let (mut data, mut failed) = (0, false);
        let mut pending: Vec<NodeKey> = Vec::new();
        for &c in children {
            match self.child_data(c) {
                ChildData::Data => data += 1,
                ChildData::None => {}
                ChildData::Pending => pending.push(c),
                ChildData::Failed => failed = true,
            }
            if data > 1 {
                break;
            }
        }
        if data <= 1 && !failed && pending.is_empty() {
            return true;
        }
        if data <= 1 && !failed {
            self.request_meta(&pending, priority);
        }
        self.finals.push((key, priority));
        false
    }

    /// What a child's metadata alone says of its data: none outside the
    /// volume, when empty or invisible under the mode and transfer function;
    /// unknown while its metadata is pending or failed.
    fn child_data(&mut self, c: NodeKey) -> ChildData {
        if !self.layout.in_volume(c) {
            return ChildData::None;
        }
        match self
            .env
            .meta_class(c, &visible_under(self.params, self.layout))
        {
            MetaClass::Data { .. } => ChildData::Data,
            MetaClass::Empty | MetaClass::Invisible => ChildData::None,
            MetaClass::Pending => ChildData::Pending,
            MetaClass::Failed => ChildData::Failed,
        }
    }

    /// The bricks of room the cut has left.
    fn room(&self) -> u32 {
        self.params
            .max_data_leaves
            .saturating_sub(self.out.data_leaves)
    }

    /// True when the cut is nearly full and the nodes visited since have
    /// prefetched [`RefineParams::max_prefetch`] bricks.
    fn prefetch_spent(&self) -> bool {
        self.room() < NEARLY_FULL && self.prefetched >= self.params.max_prefetch
    }

    /// Whether `key`'s split may fit in the cut's room, by its children's
    /// metadata alone: at most `room + 1` of them inside the volume are
    /// neither empty nor invisible (a culled child counts, the frustum test
    /// being left to the split), and none is unknown. Stops at the first
    /// child past that.
    fn may_fit(&mut self, key: NodeKey) -> bool {
        let limit = self.room() + 1;
        let mut data = 0;
        for &c in &self.layout.children(key) {
            match self.child_data(c) {
                ChildData::Data => data += 1,
                ChildData::None => {}
                ChildData::Pending | ChildData::Failed => return false,
            }
            if data > limit {
                return false;
            }
        }
        true
    }

    fn request_meta(&mut self, keys: &[NodeKey], priority: f64) {
        request_meta(&mut self.out, keys, priority);
    }

    /// The children's classification (a node ranked per brick has it
    /// already); `None` when a child's metadata is pending (requested) or
    /// failed: the node stays a leaf.
    fn children(&mut self, item: &HeapItem, children: &[NodeKey]) -> Option<[Classified; 8]> {
        if let Some(i) = item.classified {
            return Some(self.arena[i as usize].clone());
        }
        let with_info = self.screen.needs_info();
        let classes = known_children(
            children,
            self.layout,
            self.params,
            self.env,
            with_info,
            item.priority,
            &mut self.out,
        );
        if classes.is_none() {
            self.finals.push((item.key, item.priority));
        }
        classes
    }

    /// Splits `item` when its data children's bricks are available (else
    /// they are requested, the centre of the image and what rays asked for
    /// first), none failed, the pool has slots and the upload budget takes
    /// those not on the GPU; the children join the heap.
    fn split(&mut self, item: HeapItem, children: &[NodeKey], classes: &[Classified; 8]) {
        let (key, priority) = (item.key, item.priority);
        let env = &mut *self.env;
        let bricks = ChildBricks::of(children, classes, |c| env.data(c));
        // What this node prefetches if its split waits or does not fit.
        let prefetch = bricks.prefetch(self.room() < NEARLY_FULL);
        let failed = bricks.count(DataState::Failed);
        if failed > 0 {
            self.out.blocked.failed += 1;
            self.out.failed_needed += failed;
            self.finals.push((key, priority));
            return;
        }
        let data = bricks.data();
        if bricks.count(DataState::Missing) > 0 {
            let order =
                priority * self.env.request_weight(key) * self.params.views.centre_weight(key);
            bricks.request_missing(children, classes, order, self.env, &mut self.out);
            self.out.blocked.missing_data += 1;
            self.prefetched = self.prefetched.saturating_add(prefetch);
            self.finals.push((key, priority));
            if self.params.lookahead {
                for &i in data {
                    self.look_ahead(children[i], &classes[i]);
                }
            }
            return;
        }
        if self.out.data_leaves - 1 + data.len() as u32 > self.params.max_data_leaves {
            self.prefetched = self.prefetched.saturating_add(prefetch);
            self.pool_deferred.push((item, data.len() as u32 - 1));
            return;
        }
        // A split node charged at its parent's split is not uploaded after all.
        let brick_bytes = self.params.brick_upload_bytes;
        let uploads = bricks.count(DataState::InCpu) as u64;
        let release = if item.charged { brick_bytes } else { 0 };
        if uploads > 0 && !self.budget.try_exchange(release, uploads * brick_bytes) {
            self.deferred.push(item);
            return;
        }
        self.split_since_retry = true;
        self.out.data_leaves = self.out.data_leaves - 1 + data.len() as u32;
        if uploads == 0 && item.charged {
            self.budget.release(brick_bytes);
        }
        let mut state = bricks.states().iter();
        for (i, &c) in children.iter().enumerate() {
            match classes[i].class {
                NodeClass::Empty(r) => self.out.leaves.push(empty_leaf(c, r)),
                // (classify never borrows.)
                NodeClass::Data | NodeClass::Borrowed => {
                    let priority = self.screen.priority(
                        self.params.views.voxel_pixels(c),
                        self.env.visible_weight(c),
                        c,
                        classes[i].info.as_deref(),
                        self.params,
                        self.layout,
                    );
                    self.heap.push(HeapItem {
                        order: priority,
                        priority,
                        classified: None,
                        key: c,
                        uniform: classes[i].uniform,
                        charged: state.next() == Some(&DataState::InCpu),
                    })
                }
            }
        }
    }

    /// [`RefineParams::lookahead`](super::RefineParams::lookahead): the
    /// bricks child `c` (classified as data) would split into, when it would
    /// split, requested at its own priority; their missing metadata asked
    /// for.
    fn look_ahead(&mut self, c: NodeKey, class: &Classified) {
        let finest = self.layout.levels.saturating_sub(1);
        if class.uniform || c.level >= finest || !self.env.may_split(c) {
            return;
        }
        let priority = self.screen.priority(
            self.params.views.voxel_pixels(c),
            self.env.visible_weight(c),
            c,
            class.info.as_deref(),
            self.params,
            self.layout,
        );
        if !priority.is_finite() || priority <= self.screen.threshold {
            return;
        }
        let order = priority * self.env.request_weight(c) * self.params.views.centre_weight(c);
        let mut pending = Vec::new();
        for &g in self.layout.children(c).iter() {
            match classify(
                g,
                self.layout,
                self.params,
                self.params.views,
                self.env,
                false,
            ) {
                Ok(Classified {
                    class: NodeClass::Data,
                    ..
                }) if self.env.data(g) == DataState::Missing => {
                    if let Some(info) = known_info(self.env, g) {
                        self.out.requests.push(LoadRequest {
                            key: g,
                            priority: order as f32,
                            info,
                        });
                    }
                }
                Err(Unknown::Pending) => pending.push(g),
                _ => {}
            }
        }
        self.request_meta(&pending, priority);
    }

    /// The requests in priority order within the frame's cap, and every
    /// node that stayed as a leaf: with its brick when it is available,
    /// else empty (not loaded, or failed).
    pub(super) fn finish(mut self) -> Refinement {
        let max_requests = self.params.max_data_leaves.min(self.params.max_requests) as usize;
        let out = &mut self.out;
        // Highest (weighted) priority first, then the frame's cap: the weights
        // choose which bricks are asked for, not only their order.
        out.requests
            .sort_by(|a, b| b.priority.total_cmp(&a.priority).then(a.key.cmp(&b.key)));
        out.requests.truncate(max_requests);
        for item in self.deferred.drain(..) {
            out.blocked.upload_budget += 1;
            self.finals.push((item.key, item.priority));
        }
        for (item, _) in self.pool_deferred.drain(..) {
            out.blocked.pool_full += 1;
            self.finals.push((item.key, item.priority));
        }
        let root = NodeKey::ROOT;
        let brick_bytes = self.params.brick_upload_bytes;
        for (key, priority) in self.finals {
            let state = self.env.data(key);
            let available = match state {
                DataState::OnGpu => true,
                // Split children were charged when split; the root, if a leaf,
                // is the only leaf, so nothing else was charged and the
                // reservation succeeds.
                DataState::InCpu => key != root || self.budget.try_reserve(brick_bytes),
                DataState::Missing | DataState::Failed => false,
            };
            if available {
                out.leaves.push(RefinedLeaf {
                    key,
                    class: NodeClass::Data,
                    priority: if priority.is_finite() {
                        priority as f32
                    } else {
                        0.0
                    },
                    needs_upload: state == DataState::InCpu,
                });
            } else {
                out.data_leaves -= 1;
                let reason = if state == DataState::Failed {
                    // Only the root can get here: other nodes are split only
                    // when their brick is available.
                    out.failed_needed += 1;
                    EmptyReason::Failed
                } else {
                    EmptyReason::NotLoaded
                };
                out.leaves.push(empty_leaf(key, reason));
            }
        }
        self.out
    }
}
