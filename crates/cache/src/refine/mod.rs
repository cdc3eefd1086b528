//! View- and transfer-function-dependent refinement (Gobbetti et al. 2008, sect. 4).
//!
//! Each frame the cut is rebuilt from the root: a max-heap of the cut's refinable
//! nodes, keyed by their screen error, is refined greedily. The screen error is
//! the projected screen-space size of their voxels ([`LodMetric::Geometric`]),
//! or the node's error in the image under the current mode and transfer
//! function, in 8-bit levels x pixels ([`LodMetric::VisibleError`],
//! `brickray_core::lod`: its measured visible weight, or before that its
//! projected size, times its recorded error; from metadata only, so a new
//! transfer function re-prioritises without reading anything). Terminal nodes are those outside
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
//! Classification uses node metadata only, through each node's class
//! ([`RefineEnv::meta_class`]; the metadata itself, [`RefineEnv::node`], only
//! for the nodes a load request or an error-aware rank needs); no brick is
//! read and refinement never calls the source: it only says what to request. At most
//! `min(max_data_leaves, max_requests)` bricks ([`requests_per_frame`]) and
//! [`MAX_META_REQUESTS_PER_FRAME`] metadata reads are requested per frame,
//! highest priority first.
//!
//! With [`RefineParams::lookahead`] a split that waits for its children's
//! bricks also requests, at each such child's own priority (below its
//! parent's, so after every brick a split waits for), the bricks of the
//! children's children the child would split into: those of a child whose
//! screen error is above the tolerance, that is not uniform, not at the
//! finest level and that the visibility feedback lets split, classified
//! (frustum, emptiness, transparency) as any child is. When they arrive with
//! or soon after the child's, the next level splits a round trip earlier.

mod evolve;
#[cfg(test)]
mod evolve_tests;
#[cfg(test)]
mod fault_tests;
mod geometry;
mod greedy;
#[cfg(test)]
mod lod_tests;
#[cfg(test)]
mod lookahead_tests;
mod octant;
#[cfg(test)]
mod octant_tests;
#[cfg(test)]
mod prefetch_tests;
pub use octant::{MAX_DEMOTIONS, OCTANT_HYSTERESIS, OctantMemory};
mod rank;
#[cfg(test)]
mod retry_tests;
mod split;
#[cfg(test)]
pub(crate) mod tests;

pub(crate) use evolve::evolve;
pub use geometry::{ViewGeometry, Views, is_visible, lod_voxel_world};
use rank::Unknown;

use crate::upload::UploadBudget;
use brickray_core::{
    EmptyReason, LodMetric, NodeInfo, NodeKey, NodeKind, OctreeLayout, RenderMode, TransferFunction,
};
use std::sync::Arc;

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
#[derive(Debug, Clone, PartialEq)]
pub enum MetaState {
    /// Known (shared with the metadata cache: refinement looks up every
    /// child of every node it visits, and a copy of a `NodeInfo`, with its
    /// error records, is about 250 bytes).
    Known(Arc<NodeInfo>),
    /// Not known yet (refinement requests it).
    Pending,
    /// Its read failed (and is not yet due for a retry).
    Failed,
}

/// What a node's metadata says under the frame's mode and transfer function,
/// without the view ([`RefineEnv::meta_class`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MetaClass {
    /// Holds no data.
    Empty,
    /// Holds data, all of it invisible under the mode and transfer function.
    Invisible,
    /// Holds visible data (`uniform`: of one value).
    Data {
        /// The node is of one value.
        uniform: bool,
    },
    /// Its metadata is not known yet.
    Pending,
    /// Its metadata read failed (and is not yet due for a retry).
    Failed,
}

impl MetaClass {
    /// The class of known metadata, `visible` deciding a node that holds
    /// data.
    pub fn of(info: &NodeInfo, visible: &dyn Fn(&NodeInfo) -> bool) -> MetaClass {
        if info.kind == NodeKind::Empty {
            MetaClass::Empty
        } else if !visible(info) {
            MetaClass::Invisible
        } else {
            MetaClass::Data {
                uniform: matches!(info.kind, NodeKind::Uniform(_)),
            }
        }
    }
}

/// What refinement needs to know about the world outside it. Neither method may
/// block: the answers come from caches.
pub trait RefineEnv {
    /// Node metadata, as far as it is known.
    fn node(&mut self, key: NodeKey) -> MetaState;
    /// The class of `key`'s metadata, `visible` being the frame's test of a
    /// node that holds data (the same function of the mode, transfer
    /// function and channels for a whole frame). Refinement asks it of every
    /// child of every node it visits and needs the metadata itself only for
    /// the children it keeps, so an environment may keep the classes of its
    /// nodes from frame to frame until their metadata or the classification
    /// changes (the manager does, per group of siblings). By default the
    /// class of [`node`](Self::node)'s answer.
    fn meta_class(&mut self, key: NodeKey, visible: &dyn Fn(&NodeInfo) -> bool) -> MetaClass {
        match self.node(key) {
            MetaState::Known(info) => MetaClass::of(&info, visible),
            MetaState::Pending => MetaClass::Pending,
            MetaState::Failed => MetaClass::Failed,
        }
    }
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
    /// True when the filter answers as no filter would (every node may
    /// split, every weight 1, nothing measured), whatever happened since
    /// the last frame: a converged refinement may then be reused
    /// (`BrickManager::update`). False by default.
    fn is_inert(&self) -> bool {
        false
    }
}

/// The views and the knobs of one refinement.
#[derive(Debug, Clone, Copy)]
pub struct RefineParams<'a> {
    /// The geometry of the frame's views (built once per frame; a node is
    /// refined as finely as the view that needs it most).
    pub views: &'a Views,
    /// Changes whenever the views or the classification (mode, transfer
    /// function) change: what refinement remembers from frame to frame
    /// ([`OctantMemory`]) holds for one generation.
    pub generation: u64,
    /// Render mode (decides emptiness).
    pub mode: RenderMode,
    /// Transfer function (decides DVR transparency).
    pub tf: &'a TransferFunction,
    /// Channel styles of a multi-channel volume (empty for one channel:
    /// then `tf` classifies).
    pub channels: &'a [brickray_core::ChannelStyle],
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
    /// Most bricks a nearly full cut prefetches: once fewer than seven
    /// bricks of room are left, the data children not on the GPU of the
    /// nodes visited (split or not) are counted, and when they reach this,
    /// a node whose split cannot fit by its children's metadata stays a
    /// leaf without its children being classified or requested. The
    /// manager takes the frame's request cap, or the CPU cache's room beyond
    /// the cut if that is smaller. `u32::MAX`: no bound.
    pub max_prefetch: u32,
    /// Bytes one brick upload costs against the frame's upload budget.
    pub brick_upload_bytes: u64,
    /// Also request the bricks one level past a split that waits for its
    /// children's (those of children that would split in turn): a source
    /// whose every level costs a round trip converges in about half the
    /// round trips ([`Lookahead`](crate::Lookahead)).
    pub lookahead: bool,
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
    /// ([`LodMetric::Geometric`]), or its error in the image in 8-bit levels
    /// x pixels ([`LodMetric::VisibleError`]); 0 for culled and empty leaves
    /// and when not finite.
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
#[derive(Debug, Clone, PartialEq)]
pub struct LoadRequest {
    /// The node.
    pub key: NodeKey,
    /// Higher first.
    pub priority: f32,
    /// Its metadata.
    pub info: Arc<NodeInfo>,
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
    match greedy::Greedy::root(layout, params, env, budget) {
        Ok(mut g) => {
            g.run();
            g.finish()
        }
        Err(done) => done,
    }
}
