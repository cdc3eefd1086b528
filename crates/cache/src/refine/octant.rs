//! Octant-granular refinement ([`LodMetric::VisibleOctants`]): a refined
//! node keeps its brick and its children are drawn from it
//! ([`NodeClass::Borrowed`]) until each gets its own brick, one at a time.
//!
//! The cut is grown from the root: every node with its own brick is split at
//! once (a split costs nothing: its data children are drawn from its brick),
//! and its data children become candidates, ranked by their visible weight
//! times the error of drawing them from their parent's brick (the child's
//! parent-error record, `NodeInfo::parent_error`, or the parent's own where
//! the source has none; [`ScreenError::priority`] with the child's weight,
//! the parent's projected voxel size times it where no weight is measured). The best
//! candidate gets its own brick when it is on the GPU or in CPU memory (else
//! it is requested), the pool has room and the upload budget takes it; it
//! costs one brick, none when it is the last of its parent's children drawn
//! from the parent (the parent's brick then draws nothing). Refinement stops
//! at the error budget, the brick budget or the heap's end. A node hidden in
//! the previous frames ([`RefineEnv::may_split`]) is not given its brick. A
//! candidate that had its own brick in the previous frame ranks
//! [`OCTANT_HYSTERESIS`] times higher, and one that lost it
//! [`MAX_DEMOTIONS`] times in the view is not given it again
//! ([`OctantMemory`]): the cut settles.
//!
//! The root's brick must be available before anything is drawn (it is
//! requested first). Everything else follows [`refine`](super::refine):
//! metadata and bricks are requested, never read, failures are counted.

use super::rank::{HeapItem, ScreenError, Unknown, classify, drawn_from};
use super::{
    DataState, LoadRequest, MAX_META_REQUESTS_PER_FRAME, NodeClass, RefineEnv, RefineParams,
    RefinedLeaf, Refinement, Views, empty_leaf, unknown_root,
};
use crate::upload::UploadBudget;
use brickray_core::{EmptyReason, NodeInfo, NodeKey, NodeMap, NodeSet, OctreeLayout};
use std::collections::BinaryHeap;
use std::sync::Arc;

/// How much more a candidate that had its own brick in the previous frame
/// ranks ([`RefineEnv::held`]): it loses its brick only to a candidate that
/// ranks more than this much higher. The weights it is ranked by depend on
/// the cut (an octant drawn from its own brick shows other detail, and a MIP
/// ray's maximum moves), so without it a budget-limited cut can alternate
/// between two states forever (measured: a 2-frame cycle on MIP shells).
pub const OCTANT_HYSTERESIS: f64 = 2.0;

/// Times a node may lose its own brick within one view before it is drawn
/// from its parent for the rest of the view ([`RefineEnv::may_promote`]).
pub const MAX_DEMOTIONS: u32 = 3;

/// What octant refinement remembers from frame to frame within one view (the
/// views and the classification, one [`RefineParams::generation`]): the nodes
/// that had their own brick, and how often each lost it. GPU-free; the
/// manager keeps one.
#[derive(Debug, Clone, Default)]
pub struct OctantMemory {
    view: Option<u64>,
    held: NodeSet,
    demotions: NodeMap<u32>,
}

impl OctantMemory {
    /// Starts a frame of `params`' view: a different view forgets everything.
    pub fn begin(&mut self, params: &RefineParams<'_>) {
        let view = params.generation;
        if self.view != Some(view) {
            self.held.clear();
            self.demotions.clear();
            self.view = Some(view);
        }
    }

    /// Whether `key` had its own brick in the previous frame.
    pub fn held(&self, key: NodeKey) -> bool {
        self.held.contains(&key)
    }

    /// False once `key` lost its own brick [`MAX_DEMOTIONS`] times in this view.
    pub fn may_promote(&self, key: NodeKey) -> bool {
        self.demotions.get(&key).copied().unwrap_or(0) < MAX_DEMOTIONS
    }

    /// Ends the frame with its refined cut: the nodes that got their own
    /// brick (data leaves, and every ancestor of a leaf: each was given its
    /// brick and split, whether it still lends it or not), and a demotion
    /// for each node that had one and is now drawn from its parent.
    pub fn end(&mut self, r: &Refinement, layout: &OctreeLayout) {
        let mut held = NodeSet::default();
        for l in &r.leaves {
            match l.class {
                NodeClass::Data => {
                    held.insert(l.key);
                }
                NodeClass::Borrowed => {
                    if self.held.contains(&l.key) {
                        *self.demotions.entry(l.key).or_insert(0) += 1;
                    }
                }
                NodeClass::Empty(_) => {}
            }
            let mut a = layout.parent(l.key);
            while let Some(p) = a {
                if !held.insert(p) {
                    break;
                }
                a = layout.parent(p);
            }
        }
        self.held = held;
    }
}

fn finite(p: f64) -> f32 {
    if p.is_finite() { p as f32 } else { 0.0 }
}

/// The refinement state of one frame.
struct Octants<'p, 'a> {
    layout: &'p OctreeLayout,
    params: &'p RefineParams<'a>,
    geo: &'p Views,
    screen: ScreenError,
    out: Refinement,
    heap: BinaryHeap<HeapItem>,
    /// Nodes with their own brick that draw some children: how many.
    open: NodeMap<u32>,
    /// Candidates the full cut could not take that were requested or are in
    /// CPU memory: its prefetch ([`RefineParams::max_prefetch`]).
    prefetched: u32,
}

impl Octants<'_, '_> {
    /// `key` has its own brick: split it (its data children become
    /// candidates drawn from it), or keep it a leaf (uniform, finest,
    /// children unknown or failed).
    fn expand(
        &mut self,
        env: &mut dyn RefineEnv,
        key: NodeKey,
        info: Arc<NodeInfo>,
        uniform: bool,
        priority: f64,
        needs_upload: bool,
    ) {
        let finest = self.layout.levels.saturating_sub(1);
        let leaf = RefinedLeaf {
            key,
            class: NodeClass::Data,
            priority: finite(priority),
            needs_upload,
        };
        if uniform || key.level >= finest {
            self.out.leaves.push(leaf);
            return;
        }
        let children = self.layout.children(key);
        let mut classes = Vec::with_capacity(children.len());
        let (mut pending, mut failed) = (Vec::new(), 0u32);
        for &c in children.iter() {
            match classify(c, self.layout, self.params, self.geo, env, true) {
                Ok(cl) => classes.push(cl),
                Err(Unknown::Pending) => pending.push(c),
                Err(Unknown::Failed) => failed += 1,
            }
        }
        if failed > 0 {
            self.out.blocked.failed += 1;
            self.out.failed_needed += failed;
            self.out.leaves.push(leaf);
            return;
        }
        if !pending.is_empty() {
            for c in pending {
                if self.out.meta_requests.len() < MAX_META_REQUESTS_PER_FRAME as usize {
                    self.out.meta_requests.push((c, finite(priority)));
                }
            }
            self.out.blocked.missing_meta += 1;
            self.out.leaves.push(leaf);
            return;
        }
        let mut drawn = 0;
        for (&c, cl) in children.iter().zip(&classes) {
            match cl.class {
                NodeClass::Empty(r) => self.out.leaves.push(empty_leaf(c, r)),
                _ => {
                    drawn += 1;
                    // The error of drawing `c` from `key`'s brick (`c`'s
                    // parent-error record, over `key`'s range; `key`'s own
                    // record where the source has none), seen through what
                    // the image shows of `c`.
                    let drawn_from = drawn_from(&info, cl.info.as_deref());
                    let hold = if env.held(c) { OCTANT_HYSTERESIS } else { 1.0 };
                    let p = hold
                        * self.screen.priority(
                            self.geo.voxel_pixels(key),
                            env.visible_weight(c),
                            key,
                            Some(&drawn_from),
                            self.params,
                            self.layout,
                        );
                    self.heap.push(HeapItem {
                        order: p,
                        priority: p,
                        classified: None,
                        key: c,
                        uniform: cl.uniform,
                        charged: false,
                    });
                }
            }
        }
        if drawn == 0 {
            // Every child empty, invisible or culled: the brick draws nothing.
            self.out.data_leaves -= 1;
        } else {
            self.open.insert(key, drawn);
        }
    }
}

/// [`refine`](super::refine) under [`LodMetric::VisibleOctants`](brickray_core::LodMetric::VisibleOctants).
pub(super) fn refine_octants(
    layout: &OctreeLayout,
    params: &RefineParams<'_>,
    env: &mut dyn RefineEnv,
    budget: &mut UploadBudget,
) -> Refinement {
    let geo = params.views;
    let (root_info, uniform, root_upload) = match root(layout, params, env, budget) {
        Ok(r) => r,
        Err(done) => return done,
    };
    let screen = ScreenError::new(params, Some(&root_info), layout);
    let root = NodeKey::ROOT;
    let root_priority = screen.priority(
        geo.voxel_pixels(root),
        env.visible_weight(root),
        root,
        Some(&root_info),
        params,
        layout,
    );
    let mut s = Octants {
        layout,
        params,
        geo,
        screen,
        out: Refinement {
            data_leaves: 1,
            ..Default::default()
        },
        heap: BinaryHeap::new(),
        open: NodeMap::default(),
        prefetched: 0,
    };
    s.expand(env, root, root_info, uniform, root_priority, root_upload);
    // Candidates that stay drawn from their parent's brick.
    let mut borrowed: Vec<(NodeKey, f64)> = Vec::new();
    while let Some(item) = s.heap.pop() {
        if !s.promote(env, budget, &item) {
            borrowed.push((item.key, item.priority));
        }
    }
    s.finish(borrowed)
}

/// The root, which must have its own brick before anything is drawn: its
/// metadata, whether it is uniform and whether its brick is uploaded this
/// frame; `Err` holds the whole refinement when the root is all there is.
fn root(
    layout: &OctreeLayout,
    params: &RefineParams<'_>,
    env: &mut dyn RefineEnv,
    budget: &mut UploadBudget,
) -> Result<(Arc<NodeInfo>, bool, bool), Refinement> {
    let mut out = Refinement::default();
    let root = NodeKey::ROOT;
    let root_class =
        classify(root, layout, params, params.views, env, true).map_err(unknown_root)?;
    let (NodeClass::Data, Some(root_info)) = (root_class.class, root_class.info) else {
        let reason = match root_class.class {
            NodeClass::Empty(r) => r,
            _ => EmptyReason::Empty,
        };
        out.leaves.push(empty_leaf(root, reason));
        return Err(out);
    };
    if params.max_data_leaves == 0 {
        out.leaves.push(empty_leaf(root, EmptyReason::NotLoaded));
        out.blocked.pool_full += 1;
        return Err(out);
    }
    let upload = match env.data(root) {
        DataState::OnGpu => false,
        DataState::InCpu if budget.try_reserve(params.brick_upload_bytes) => true,
        DataState::InCpu => {
            out.leaves.push(empty_leaf(root, EmptyReason::NotLoaded));
            out.blocked.upload_budget += 1;
            return Err(out);
        }
        DataState::Missing => {
            out.leaves.push(empty_leaf(root, EmptyReason::NotLoaded));
            out.requests.push(LoadRequest {
                key: root,
                priority: f32::MAX,
                info: root_info,
            });
            out.blocked.missing_data += 1;
            return Err(out);
        }
        DataState::Failed => {
            out.leaves.push(empty_leaf(root, EmptyReason::Failed));
            out.blocked.failed += 1;
            out.failed_needed += 1;
            return Err(out);
        }
    };
    Ok((root_info, root_class.uniform, upload))
}

impl Octants<'_, '_> {
    /// Gives the candidate `item` its own brick (and makes its children
    /// candidates) when its rank beats the error budget, it may split and be
    /// promoted, its brick is on the GPU or in CPU memory (else it is
    /// requested), the pool has room and the upload budget takes it. False
    /// when it stays drawn from its parent.
    fn promote(
        &mut self,
        env: &mut dyn RefineEnv,
        budget: &mut UploadBudget,
        item: &HeapItem,
    ) -> bool {
        let (c, priority) = (item.key, item.priority);
        let parent = self.layout.parent(c).expect("a candidate has a parent");
        if !priority.is_finite() || priority <= self.screen.threshold {
            return false;
        }
        if !env.may_split(c) || !env.may_promote(c) {
            self.out.blocked.invisible += 1;
            return false;
        }
        // The last child drawn from its parent frees the parent's brick.
        let frees = self.open.get(&parent) == Some(&1);
        let cost = u32::from(!frees);
        // The cut cannot take it: what it asks for is prefetch, bounded as
        // in greedy refinement (`RefineParams::max_prefetch`).
        let full = self.out.data_leaves + cost > self.params.max_data_leaves;
        if full && self.prefetched >= self.params.max_prefetch {
            self.out.blocked.pool_full += 1;
            return false;
        }
        let super::MetaState::Known(info) = env.node(c) else {
            return false;
        };
        let state = env.data(c);
        if full && matches!(state, DataState::Missing | DataState::InCpu) {
            self.prefetched += 1;
        }
        match state {
            DataState::Failed => {
                self.out.blocked.failed += 1;
                return false;
            }
            DataState::Missing => {
                let order = priority * env.request_weight(parent) * self.geo.centre_weight(parent);
                self.out.requests.push(LoadRequest {
                    key: c,
                    priority: order as f32,
                    info,
                });
                self.out.blocked.missing_data += 1;
                return false;
            }
            DataState::OnGpu | DataState::InCpu => {}
        }
        if full {
            self.out.blocked.pool_full += 1;
            return false;
        }
        let upload = state == DataState::InCpu;
        if upload && !budget.try_reserve(self.params.brick_upload_bytes) {
            self.out.blocked.upload_budget += 1;
            return false;
        }
        if let Some(n) = self.open.get_mut(&parent) {
            *n -= 1;
            if *n == 0 {
                self.open.remove(&parent);
            }
        }
        self.out.data_leaves += cost;
        // Its own rank, for its children's requests and its leaf.
        let own = self.screen.priority(
            self.geo.voxel_pixels(c),
            env.visible_weight(c),
            c,
            Some(&info),
            self.params,
            self.layout,
        );
        self.expand(env, c, info, item.uniform, own, upload);
        true
    }

    /// The refinement: the borrowed candidates as leaves, every leaf in key
    /// order (the same cut is the same list, and its borrowed slots, numbered
    /// in cut order, the same, whatever order the heap took), the requests
    /// in priority order within the frame's cap.
    fn finish(self, borrowed: Vec<(NodeKey, f64)>) -> Refinement {
        let max_requests = self.params.max_data_leaves.min(self.params.max_requests) as usize;
        let mut out = self.out;
        for (c, priority) in borrowed {
            out.leaves.push(RefinedLeaf {
                key: c,
                class: NodeClass::Borrowed,
                priority: finite(priority),
                needs_upload: false,
            });
        }
        out.leaves.sort_by_key(|l| l.key);
        out.requests
            .sort_by(|a, b| b.priority.total_cmp(&a.priority).then(a.key.cmp(&b.key)));
        out.requests.truncate(max_requests);
        out
    }
}
