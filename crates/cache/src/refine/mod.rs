//! View- and transfer-function-dependent refinement (Gobbetti et al. 2008, sect. 4).
//!
//! Each frame the cut is rebuilt from the root: a max-heap of the cut's refinable
//! nodes, keyed by their screen error, is refined greedily. The screen error is
//! the projected screen-space size of their voxels ([`LodMetric::Geometric`]),
//! or that size times the node's recorded error under the current mode and
//! transfer function, in 8-bit levels ([`LodMetric::ErrorAware`],
//! `brickray_core::lod`; from metadata only, so a new transfer function
//! re-prioritises without reading anything). Terminal nodes are those outside
//! the view frustum, empty or invisible under the current mode and transfer
//! function, uniform, at the finest level, already within the tolerance (or
//! error budget), or whose screen error is not finite (a non-finite camera or
//! frame). A node is split only when the metadata
//! of its children is known (missing metadata is requested), the bricks of all its
//! visible children are on the GPU or in CPU memory (missing ones are requested
//! with the parent's priority times its [`ViewGeometry::centre_weight`] and its
//! [`RefineEnv::request_weight`]: the centre of the image and what rays asked
//! for load first), none of them failed, the pool has slots for them
//! and the frame's upload budget can take those not yet on the GPU.
//!
//! Under the error-aware metrics the heap ranks a split by its screen error
//! per brick it adds (its children that need data, less its own brick), once
//! its children's metadata is known: the order changes, the stop test does not.
//!
//! Classification uses node metadata only ([`RefineEnv::node`]); no brick is read
//! and refinement never calls the source: it only says what to request. At most
//! `min(max_data_leaves, max_requests)` bricks ([`requests_per_frame`]) and
//! [`MAX_META_REQUESTS_PER_FRAME`] metadata reads are requested per frame,
//! highest priority first.

#[cfg(test)]
mod fault_tests;
mod geometry;
#[cfg(test)]
mod lod_tests;
mod octant;
#[cfg(test)]
mod octant_tests;
pub use octant::{MAX_DEMOTIONS, OCTANT_HYSTERESIS, OctantMemory};
mod rank;
#[cfg(test)]
pub(crate) mod tests;

pub use geometry::{ViewGeometry, is_visible, lod_voxel_world};
use rank::{Classified, HeapItem, ScreenError, UNCLASSIFIED, Unknown, classify, classify_children};

use crate::upload::UploadBudget;
use brickray_core::{
    Camera, EmptyReason, LodMetric, NodeInfo, NodeKey, NodeKind, OctreeLayout, RenderMode,
    TransferFunction, VolumeFrame,
};
use std::collections::BinaryHeap;

/// Bricks a frame may request at least (when the pool has the slots), whatever
/// the upload budget.
pub const MIN_REQUESTS_PER_FRAME: u32 = 256;
/// Frames of the upload budget a frame's requests may cover.
pub const REQUESTED_UPLOAD_FRAMES: u64 = 4;

/// The most bricks one frame requests: what the pool can hold (`slots`), and
/// no more than [`REQUESTED_UPLOAD_FRAMES`] frames of uploads (at least
/// [`MIN_REQUESTS_PER_FRAME`]), so a view that wants thousands of bricks keeps
/// the loader busy without queueing work it cannot upload soon (a fixed cap of
/// 256 kept uploads at 11 of 16 MiB a frame and slowed a jump's convergence from
/// 17 to 23 frames), and a degenerate view requests a bounded amount.
pub fn requests_per_frame(slots: u32, upload_bytes_per_frame: u64, brick_bytes: u64) -> u32 {
    let by_uploads =
        REQUESTED_UPLOAD_FRAMES.saturating_mul(upload_bytes_per_frame) / brick_bytes.max(1);
    slots.min(by_uploads.clamp(MIN_REQUESTS_PER_FRAME as u64, u32::MAX as u64) as u32)
}

/// Most metadata reads requested in one frame.
pub const MAX_META_REQUESTS_PER_FRAME: u32 = 1024;

/// The classification of one node under a view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum NodeClass {
    /// Needs no brick.
    Empty(EmptyReason),
    /// Needs its brick.
    Data,
    /// Drawn from its parent's brick (an octant-granular cut,
    /// [`LodMetric::VisibleOctants`]): needs the parent's brick, not its own.
    Borrowed,
}

/// Where a node's brick is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DataState {
    /// In a GPU pool slot.
    OnGpu,
    /// In the CPU cache (not on the GPU).
    InCpu,
    /// Neither; may be queued or loading.
    Missing,
    /// Its load failed (and is not yet due for a retry).
    Failed,
}

/// What is known of a node's metadata.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MetaState {
    /// Known.
    Known(NodeInfo),
    /// Not known yet (refinement requests it).
    Pending,
    /// Its read failed (and is not yet due for a retry).
    Failed,
}

/// What refinement needs to know about the world outside it. Neither method may
/// block: the answers come from caches.
pub trait RefineEnv {
    /// Node metadata, as far as it is known.
    fn node(&mut self, key: NodeKey) -> MetaState;
    /// Where the node's brick is.
    fn data(&mut self, key: NodeKey) -> DataState;
    /// Whether `key`, which refinement would split, may be split: false for a
    /// node the visibility feedback marked invisible in the previous frames
    /// (`brickray-visibility`). Such a node stays a leaf at its level (its brick
    /// is available: its parent's split required it) and requests nothing.
    /// Every node by default.
    fn may_split(&mut self, key: NodeKey) -> bool {
        let _ = key;
        true
    }
    /// How strongly the image asks for `key`'s detail (for example from the
    /// pixels its brick showed, [`SplitFilter::request_weight`]): the priority
    /// of the load requests for its children is multiplied by it (with the
    /// node's [`ViewGeometry::centre_weight`]). It orders loads, never decides
    /// the cut. 1 by default.
    fn request_weight(&mut self, key: NodeKey) -> f64 {
        let _ = key;
        1.0
    }
    /// How much of `key` the image shows, where the renderer measured it: the
    /// transmittance-weighted length of the rays through the node, summed over
    /// pixels, in finest voxels (an isosurface ray counts its length up to its
    /// hit, a MIP ray only its length through the node holding its maximum).
    /// Under [`LodMetric::VisibleError`] a node that has it is ranked by
    /// it times its per-sample expected error ([`node_visible_error`](brickray_core::node_visible_error)),
    /// the linearised change of the image, instead of by its projected voxel
    /// size times its pixel error. `None` (not measured) by default.
    fn visible_weight(&mut self, key: NodeKey) -> Option<f64> {
        let _ = key;
        None
    }
    /// Under [`LodMetric::VisibleOctants`]: whether `key` had its own brick in
    /// the previous frame's cut ([`OctantMemory::held`]). False by default.
    fn held(&mut self, key: NodeKey) -> bool {
        let _ = key;
        false
    }
    /// Under [`LodMetric::VisibleOctants`]: false for a node that may not get
    /// its own brick again in this view ([`OctantMemory::may_promote`]).
    /// Every node by default.
    fn may_promote(&mut self, key: NodeKey) -> bool {
        let _ = key;
        true
    }
}

/// Visibility as refinement sees it: whether a node may be split (see
/// [`RefineEnv::may_split`]). The renderer implements it over its feedback.
pub trait SplitFilter {
    /// False for a node that must not be split this frame.
    fn may_split(&mut self, key: NodeKey) -> bool;
    /// How strongly the image asks for `key`'s detail ([`RefineEnv::request_weight`]);
    /// 1 by default.
    fn request_weight(&mut self, key: NodeKey) -> f64 {
        let _ = key;
        1.0
    }
    /// What the image shows of `key` ([`RefineEnv::visible_weight`]); `None`
    /// (not measured) by default.
    fn visible_weight(&mut self, key: NodeKey) -> Option<f64> {
        let _ = key;
        None
    }
}

/// The view and the knobs of one refinement.
#[derive(Debug, Clone, Copy)]
pub struct RefineParams<'a> {
    /// The camera.
    pub camera: &'a Camera,
    /// Viewport width / height.
    pub aspect: f32,
    /// Viewport height in pixels.
    pub viewport_height_px: u32,
    /// The volume's placement in the world.
    pub volume_frame: &'a VolumeFrame,
    /// Render mode (decides emptiness).
    pub mode: RenderMode,
    /// Transfer function (decides DVR transparency).
    pub tf: &'a TransferFunction,
    /// Screen-space error tolerance: a node whose voxels project to at most this
    /// many pixels is not refined (default 1). The rule of
    /// [`LodMetric::Geometric`], and of error-aware refinement over a source
    /// without error bounds.
    pub tolerance_px: f32,
    /// The refinement rule (see [`LodMetric`]).
    pub metric: LodMetric,
    /// Most leaves needing a brick (the pool's slot count).
    pub max_data_leaves: u32,
    /// Most bricks to request this frame ([`requests_per_frame`]).
    pub max_requests: u32,
    /// Bytes one brick upload costs against the frame's upload budget.
    pub brick_upload_bytes: u64,
}

/// One leaf of a refined cut (the manager turns it into a
/// [`CutLeaf`](brickray_core::CutLeaf) once slots are assigned).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RefinedLeaf {
    /// The node.
    pub key: NodeKey,
    /// Whether it needs its brick.
    pub class: NodeClass,
    /// Its screen error: projected voxel size in pixels
    /// ([`LodMetric::Geometric`]), times its error in 8-bit levels
    /// ([`LodMetric::ErrorAware`]); 0 for culled and empty leaves and when not
    /// finite.
    pub priority: f32,
    /// True when the brick is needed and not on the GPU (an upload this frame).
    pub needs_upload: bool,
}

/// Counts of refusals to split, by reason.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SplitBlocks {
    /// Children's metadata not known yet (requested).
    pub missing_meta: u32,
    /// Children's data not in memory yet.
    pub missing_data: u32,
    /// A child's data or metadata failed to load.
    pub failed: u32,
    /// Not enough pool slots.
    pub pool_full: u32,
    /// Upload budget of the frame spent.
    pub upload_budget: u32,
    /// Invisible under the visibility feedback ([`RefineEnv::may_split`]).
    pub invisible: u32,
}

/// A brick refinement wants loaded.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoadRequest {
    /// The node.
    pub key: NodeKey,
    /// Higher first.
    pub priority: f32,
    /// Its metadata.
    pub info: NodeInfo,
}

/// The result of [`refine`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Refinement {
    /// Leaves covering the octree cube, each point in exactly one.
    pub leaves: Vec<RefinedLeaf>,
    /// Bricks to load, highest priority first.
    pub requests: Vec<LoadRequest>,
    /// Metadata to read, with priorities, highest first.
    pub meta_requests: Vec<(NodeKey, f32)>,
    /// Why nodes were not split.
    pub blocked: SplitBlocks,
    /// Leaves needing a brick.
    pub data_leaves: u32,
    /// Nodes the cut needs (children of a wanted split, or the root) whose
    /// metadata or brick failed: the image is degraded there.
    pub failed_needed: u32,
}

/// The view geometry of `params`.
fn view_geometry(layout: &OctreeLayout, params: &RefineParams<'_>) -> ViewGeometry {
    ViewGeometry::new(
        layout,
        params.camera,
        params.aspect,
        params.viewport_height_px,
        params.volume_frame,
    )
}

/// A leaf that needs no brick.
fn empty_leaf(key: NodeKey, reason: EmptyReason) -> RefinedLeaf {
    RefinedLeaf {
        key,
        class: NodeClass::Empty(reason),
        priority: 0.0,
        needs_upload: false,
    }
}

/// The refinement of a frame whose root cannot be classified: its metadata
/// is requested, or its failure counted.
fn unknown_root(u: Unknown) -> Refinement {
    let mut out = Refinement::default();
    let root = NodeKey::ROOT;
    match u {
        Unknown::Pending => {
            out.leaves.push(empty_leaf(root, EmptyReason::NotLoaded));
            out.meta_requests.push((root, f32::MAX));
            out.blocked.missing_meta += 1;
        }
        Unknown::Failed => {
            out.leaves.push(empty_leaf(root, EmptyReason::Failed));
            out.blocked.failed += 1;
            out.failed_needed += 1;
        }
    }
    out
}

/// Refines the octree of `layout` for one frame. `budget` is the frame's upload
/// budget (already started); bricks of split children not on the GPU are charged
/// to it, as is the root when it is the only leaf and not on the GPU.
pub fn refine(
    layout: &OctreeLayout,
    params: &RefineParams<'_>,
    env: &mut dyn RefineEnv,
    budget: &mut UploadBudget,
) -> Refinement {
    if matches!(params.metric, LodMetric::VisibleOctants { .. }) {
        return octant::refine_octants(layout, params, env, budget);
    }
    let geo = view_geometry(layout, params);
    let brick_bytes = params.brick_upload_bytes;
    let finest = layout.levels.saturating_sub(1);
    let max_requests = params.max_data_leaves.min(params.max_requests) as usize;
    let max_meta = MAX_META_REQUESTS_PER_FRAME as usize;
    let mut out = Refinement::default();
    let mut heap = BinaryHeap::new();

    let root = NodeKey::ROOT;
    let screen: ScreenError;
    let root_info = match classify(root, layout, params, &geo, env) {
        Ok(Classified {
            class: NodeClass::Empty(r),
            ..
        }) => {
            out.leaves.push(empty_leaf(root, r));
            return out;
        }
        Ok(c) => {
            let se = ScreenError::new(params, c.info.as_ref(), layout);
            let priority = se.priority(
                geo.voxel_pixels(root),
                env.visible_weight(root),
                root,
                c.info.as_ref(),
                params,
                layout,
            );
            heap.push(HeapItem {
                order: priority,
                priority,
                classified: None,
                key: root,
                uniform: c.uniform,
                charged: false,
            });
            screen = se;
            c.info
        }
        Err(u) => return unknown_root(u),
    };
    out.data_leaves = 1;
    if params.max_data_leaves == 0 {
        out.leaves.push(empty_leaf(root, EmptyReason::NotLoaded));
        out.data_leaves = 0;
        out.blocked.pool_full += 1;
        return out;
    }
    // The root's brick is wanted first (it is charged to the upload budget only if
    // it ends up a leaf).
    if let (DataState::Missing, Some(info)) = (env.data(root), root_info) {
        out.requests.push(LoadRequest {
            key: root,
            priority: f32::MAX,
            info,
        });
    }

    let tol = screen.threshold;
    // Nodes that stay leaves and need their brick: (key, priority).
    let mut finals: Vec<(NodeKey, f64)> = Vec::new();
    // Splits the upload budget refused. The budget may be held by speculative
    // charges (children charged at their parent's split) that come back when
    // those children split into bricks already on the GPU; the refused splits
    // are retried once the heap is empty, as long as a round still splits
    // something (each node splits at most once, so this ends).
    let mut deferred: Vec<HeapItem> = Vec::new();
    // Children's classifications of the nodes ranked per brick.
    let mut arena: Vec<[Classified; 8]> = Vec::new();
    // Splits the pool refused, retried the same way: a later split whose
    // children are all empty or invisible gives its brick back (nodes within
    // the tolerance, which pop last, do that), and the refused node, of higher
    // priority, may then fit.
    // With each, the bricks its split adds: only those that now fit are
    // retried.
    let mut pool_deferred: Vec<(HeapItem, u32)> = Vec::new();
    let mut split_since_retry = false;
    loop {
        if heap.is_empty() {
            let room = params.max_data_leaves.saturating_sub(out.data_leaves);
            let fits = |d: &(HeapItem, u32)| d.1 <= room;
            if (deferred.is_empty() && !pool_deferred.iter().any(fits)) || !split_since_retry {
                break;
            }
            split_since_retry = false;
            heap.extend(deferred.drain(..));
            let (retry, keep): (Vec<_>, Vec<_>) = pool_deferred.drain(..).partition(fits);
            pool_deferred = keep;
            heap.extend(retry.into_iter().map(|d| d.0));
        }
        let Some(item) = heap.pop() else { break };
        let HeapItem {
            priority,
            key,
            uniform,
            charged,
            ..
        } = item;
        // A non-finite size (a non-finite camera or frame) is never refined.
        if uniform || key.level >= finest || !priority.is_finite() {
            finals.push((key, priority));
            continue;
        }
        // Within the tolerance (or error budget): a node still splits when the
        // split costs no brick, i.e. at most one child needs data (the others
        // are empty, invisible under the mode or outside the view), so the cut
        // gets finer without growing; otherwise it stays.
        let within = priority <= tol;
        // Hidden in the previous frames: stays at its level, requests nothing.
        if !env.may_split(key) {
            if !within {
                out.blocked.invisible += 1;
            }
            finals.push((key, priority));
            continue;
        }
        let children = layout.children(key);
        let n = children.len();
        // Error-aware refinement ranks a split by the error it removes per
        // brick it adds (a node whose split needs one more brick before one
        // that needs seven): once the children are known, the node goes back
        // into the heap at its priority over those bricks, and splits when it
        // comes out again. Only the order changes, so under a tolerance (or
        // error budget) the cut is the same; under a brick budget the bricks
        // go where they buy the most error. Unknown children leave the order
        // as it is (the split below requests them).
        if !within
            && item.classified.is_none()
            && screen.table.is_some()
            && let Some(classes) = classify_children(&children, layout, params, &geo, env)
        {
            let data = classes[..n]
                .iter()
                .filter(|c| c.class == NodeClass::Data)
                .count() as u32;
            arena.push(classes);
            heap.push(HeapItem {
                order: priority / f64::from(data.saturating_sub(1).max(1)),
                classified: Some(arena.len() as u32 - 1),
                ..item
            });
            continue;
        }
        if within {
            // Free only if at most one child needs data: stop at the second
            // (most nodes of a dense region stop after two or three children).
            // A node that is free by this count is classified in full below.
            // By metadata alone (the frustum test, the costly part, is left
            // to the split: a culled child counts as data here).
            let (mut data, mut failed) = (0, false);
            let mut pending: Vec<NodeKey> = Vec::new();
            for &c in children.iter() {
                if !layout.in_volume(c) {
                    continue;
                }
                match env.node(c) {
                    MetaState::Known(info) => {
                        if info.kind != NodeKind::Empty
                            && is_visible(&info, params.mode, params.tf, layout)
                        {
                            data += 1;
                        }
                    }
                    MetaState::Pending => pending.push(c),
                    MetaState::Failed => failed = true,
                }
                if data > 1 {
                    break;
                }
            }
            if data > 1 || failed || !pending.is_empty() {
                // Known once the metadata arrives: asked for after every
                // wanted split's (the heap pops those first).
                if data <= 1 && !failed {
                    for c in pending {
                        if out.meta_requests.len() < max_meta {
                            out.meta_requests.push((c, priority as f32));
                        }
                    }
                }
                finals.push((key, priority));
                continue;
            }
        }
        // Classify the children (a node ranked per brick has them already).
        let mut classes = [UNCLASSIFIED; 8];
        let (mut pending, mut failed) = (Vec::new(), 0u32);
        if let Some(i) = item.classified {
            classes = arena[i as usize];
        } else {
            for (i, &c) in children.iter().enumerate() {
                match classify(c, layout, params, &geo, env) {
                    Ok(cl) => classes[i] = cl,
                    Err(Unknown::Pending) => pending.push(c),
                    Err(Unknown::Failed) => failed += 1,
                }
            }
        }
        if failed > 0 {
            out.blocked.failed += 1;
            out.failed_needed += failed;
            finals.push((key, priority));
            continue;
        }
        if !pending.is_empty() {
            for c in pending {
                if out.meta_requests.len() < max_meta {
                    out.meta_requests.push((c, priority as f32));
                }
            }
            out.blocked.missing_meta += 1;
            finals.push((key, priority));
            continue;
        }
        let data: Vec<usize> = (0..n)
            .filter(|&i| classes[i].class == NodeClass::Data)
            .collect();
        let states: Vec<DataState> = data.iter().map(|&i| env.data(children[i])).collect();
        let failed = states.iter().filter(|s| **s == DataState::Failed).count() as u32;
        if failed > 0 {
            out.blocked.failed += 1;
            out.failed_needed += failed;
            finals.push((key, priority));
            continue;
        }
        let missing: Vec<usize> = data
            .iter()
            .zip(&states)
            .filter(|(_, s)| **s == DataState::Missing)
            .map(|(i, _)| *i)
            .collect();
        if !missing.is_empty() {
            // What rays asked for, and the centre of the image, load first.
            let order = priority * env.request_weight(key) * geo.centre_weight(key);
            for i in missing {
                if let Some(info) = classes[i].info {
                    out.requests.push(LoadRequest {
                        key: children[i],
                        priority: order as f32,
                        info,
                    });
                }
            }
            out.blocked.missing_data += 1;
            finals.push((key, priority));
            continue;
        }
        if out.data_leaves - 1 + data.len() as u32 > params.max_data_leaves {
            pool_deferred.push((item, data.len() as u32 - 1));
            continue;
        }
        // A split node charged at its parent's split is not uploaded after all.
        let uploads = states.iter().filter(|s| **s == DataState::InCpu).count() as u64;
        let release = if charged { brick_bytes } else { 0 };
        if uploads > 0 && !budget.try_exchange(release, uploads * brick_bytes) {
            deferred.push(item);
            continue;
        }
        split_since_retry = true;
        out.data_leaves = out.data_leaves - 1 + data.len() as u32;
        if uploads == 0 && charged {
            budget.release(brick_bytes);
        }
        let mut state = states.iter();
        for i in 0..n {
            match classes[i].class {
                NodeClass::Empty(r) => out.leaves.push(empty_leaf(children[i], r)),
                // (classify never borrows.)
                NodeClass::Data | NodeClass::Borrowed => {
                    let priority = screen.priority(
                        geo.voxel_pixels(children[i]),
                        env.visible_weight(children[i]),
                        children[i],
                        classes[i].info.as_ref(),
                        params,
                        layout,
                    );
                    heap.push(HeapItem {
                        order: priority,
                        priority,
                        classified: None,
                        key: children[i],
                        uniform: classes[i].uniform,
                        charged: state.next() == Some(&DataState::InCpu),
                    })
                }
            }
        }
    }

    // Highest (weighted) priority first, then the frame's cap: the weights
    // choose which bricks are asked for, not only their order.
    out.requests
        .sort_by(|a, b| b.priority.total_cmp(&a.priority).then(a.key.cmp(&b.key)));
    out.requests.truncate(max_requests);
    for item in deferred {
        out.blocked.upload_budget += 1;
        finals.push((item.key, item.priority));
    }
    for (item, _) in pool_deferred {
        out.blocked.pool_full += 1;
        finals.push((item.key, item.priority));
    }
    for (key, priority) in finals {
        let state = env.data(key);
        let available = match state {
            DataState::OnGpu => true,
            // Split children were charged when split; the root, if a leaf, is the
            // only leaf, so nothing else was charged and the reservation succeeds.
            DataState::InCpu => key != root || budget.try_reserve(brick_bytes),
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
                // Only the root can get here: other nodes are split only when
                // their brick is available.
                out.failed_needed += 1;
                EmptyReason::Failed
            } else {
                EmptyReason::NotLoaded
            };
            out.leaves.push(empty_leaf(key, reason));
        }
    }
    out
}
