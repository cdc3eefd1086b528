//! What [`BrickManager::update`](super::BrickManager::update) returns: the
//! frame's plan (cut and uploads) and its statistics.

use crate::failures::FailureCounts;
use crate::pool::SlotId;
use crate::prepared::PreparedBrick;
use crate::refine::SplitBlocks;
use brickray_core::{CutLeaf, NodeKey};

/// Where a node's brick is, the most GPU-ward state first.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Residency {
    /// Queued for loading.
    Requested,
    /// Being read (or read and awaiting the next update).
    Loading,
    /// In the CPU cache, not on the GPU.
    InCpu,
    /// In a GPU pool slot.
    OnGpu,
    /// Its load failed and is not yet due for a retry; the error is kept
    /// ([`BrickManager::failure`](super::BrickManager::failure)).
    Failed,
}

/// Number of nodes per residency state.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ResidencyCounts {
    /// Queued.
    pub requested: u32,
    /// Being read.
    pub loading: u32,
    /// In CPU memory only.
    pub in_cpu: u32,
    /// On the GPU.
    pub on_gpu: u32,
    /// Failed.
    pub failed: u32,
}

/// A brick to copy into the atlas this frame, before drawing.
#[derive(Debug, Clone)]
pub struct Upload {
    /// The node.
    pub key: NodeKey,
    /// Its slot.
    pub slot: SlotId,
    /// Voxel offset of the slot in the atlas.
    pub atlas_offset: [u32; 3],
    /// The prepared brick: texels for the atlas, sub-cell ranges for the slot's
    /// rows of the sub-cell table, the node's range for its slot-table row.
    pub brick: PreparedBrick,
}

/// Statistics of one frame.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FrameStats {
    /// The frame.
    pub frame: u64,
    /// Leaves of the cut.
    pub leaves: u32,
    /// Leaves holding a brick (the GPU working set).
    pub working_set_bricks: u32,
    /// Pool slots: as many as the GPU budget holds, at most a slot for
    /// every brick of the volume ([`brick_count`](crate::brick_count)).
    pub pool_slots: u32,
    /// Bytes of the GPU budget one pool slot costs
    /// ([`GpuFormat::slot_bytes`](crate::GpuFormat::slot_bytes)): what a
    /// budget of `n` slots takes.
    pub pool_slot_bytes: u64,
    /// Occupied pool slots.
    pub pool_occupied: u32,
    /// Bricks scheduled for upload.
    pub upload_bricks: u32,
    /// Bytes scheduled for upload ([`PreparedBrick::bytes`] summed).
    pub upload_bytes: u64,
    /// Working-set bricks already on the GPU / working-set bricks (this frame; 1 if none).
    pub gpu_hit_rate: f64,
    /// Lookups of bricks not on the GPU found in CPU memory (cumulative; 1 if none).
    pub cpu_hit_rate: f64,
    /// Brick requests queued or being read.
    pub requests_in_flight: u32,
    /// Bricks requested this frame.
    pub requested_this_frame: u32,
    /// Requests cancelled so far because the view stopped wanting them:
    /// `[queued (bricks and metadata), in flight (the bricks of the batches
    /// aborted)]` ([`Loader::cancelled`](crate::Loader::cancelled)).
    pub cancelled: [u64; 2],
    /// Metadata requests queued or being read.
    pub metadata_in_flight: u32,
    /// Metadata reads requested this frame.
    pub metadata_requested_this_frame: u32,
    /// Nodes whose metadata is held (bounded: the least recently used are
    /// forgotten beyond a capacity that scales with the CPU budget).
    pub metadata_known: u32,
    /// Metadata entries forgotten so far.
    pub metadata_evicted: u64,
    /// Nodes per residency state.
    pub residency: ResidencyCounts,
    /// Why nodes were not split.
    pub blocked: SplitBlocks,
    /// Data leaves left empty because the pool had no unpinned slot (only when the
    /// same frame number is planned twice).
    pub allocation_failures: u32,
    /// Nodes this frame's cut needs whose metadata or brick failed (children of a
    /// split refused for it, or the root): the image is degraded there.
    pub failed_needed: u32,
    /// Failed reads, current and cumulative, per kind.
    pub failures: FailureCounts,
    /// Leaves of the drawn cut fading between levels ([`FramePlan::fades`]).
    pub fading: u32,
    /// Leaves of the drawn cut with no brick where the data is not known to be
    /// empty (`Empty(NotLoaded | Failed)`): pixels there show nothing at any
    /// level. With the coarse floor resident this stays 0.
    pub holes: u32,
    /// Floor bricks resident and pinned for good.
    pub floor_pinned: u32,
    /// Where the frame's planning went ([`BrickManager::update`](super::BrickManager::update)'s
    /// phases, wall time).
    pub phases: PhaseTimes,
    /// The frame drew the last converged frame's refinement again, nothing
    /// it read having changed since (no new views, classification,
    /// metadata, CPU or pool contents; an inert visibility filter, a
    /// metric without visible weights, no failures): the refine phase then
    /// costs a copy of the cut.
    pub refine_reused: bool,
    /// The cut was evolved from the last frame's instead of refined from
    /// the root (a moving view, [`OutOfCoreConfig::evolve`](crate::OutOfCoreConfig::evolve)).
    pub refine_evolved: bool,
    /// The cut was evolved where the refinement from the root may give
    /// another (the pool refused a split, a merge made room, or a split node
    /// was kept for want of its brick): not converged, so that a still view
    /// is refined from the root. An evolved cut that is not provisional is
    /// the one refined from the root would give.
    pub cut_provisional: bool,
}

/// The wall time of each phase of one [`BrickManager::update`](super::BrickManager::update),
/// in milliseconds.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PhaseTimes {
    /// What the loader finished, into the caches.
    pub poll_ms: f64,
    /// Refinement of the cut.
    pub refine_ms: f64,
    /// The displayed cut (fades).
    pub display_ms: f64,
    /// Residency: pins, slots, octants lent, the floor, and the fades' slots.
    pub place_ms: f64,
    /// The loads wanted, to the loader.
    pub request_ms: f64,
    /// The statistics (and the metadata map's trim).
    pub stats_ms: f64,
}

impl PhaseTimes {
    /// The phases' sum.
    pub fn total_ms(&self) -> f64 {
        self.poll_ms
            + self.refine_ms
            + self.display_ms
            + self.place_ms
            + self.request_ms
            + self.stats_ms
    }
}

impl FrameStats {
    /// True when another frame of the same view would not change the image:
    /// nothing requested or in flight (bricks or metadata), nothing uploaded or
    /// waiting for upload budget, no split waiting for data or metadata, and no
    /// node the cut needs has failed ([`degraded`](Self::degraded) is false). A
    /// degraded image is not converged: a retry (automatic after the back-off, or
    /// [`BrickManager::retry_failed`](super::BrickManager::retry_failed)) may
    /// still change it. Nor is a provisional cut
    /// ([`cut_provisional`](Self::cut_provisional)): the next frame of the
    /// same view refines from the root, which may change it.
    pub fn converged(&self) -> bool {
        self.settled() && !self.degraded() && !self.cut_provisional
    }

    /// True when the cut needs nodes whose metadata or brick failed.
    pub fn degraded(&self) -> bool {
        self.failed_needed > 0
    }

    /// True when nothing is loading or pending (failures aside).
    pub fn settled(&self) -> bool {
        self.requested_this_frame == 0
            && self.requests_in_flight == 0
            && self.metadata_requested_this_frame == 0
            && self.metadata_in_flight == 0
            && self.upload_bricks == 0
            && self.blocked.missing_data == 0
            && self.blocked.missing_meta == 0
            && self.fading == 0
            // Refinement retries splits refused on charges given back later in
            // the frame, so a refusal means the budget is really spent: the next
            // frame uploads and splits more.
            && self.blocked.upload_budget == 0
    }
}

/// What the renderer does this frame.
#[derive(Debug, Clone, Default)]
pub struct FramePlan {
    /// Leaves covering the octree cube (each point in exactly one); give it to
    /// `brickray_index::encode_cut` as it is.
    pub cut: Vec<CutLeaf>,
    /// Bricks to upload before drawing (the cut's, fallbacks' and floor's).
    pub uploads: Vec<Upload>,
    /// Leaves of `cut` fading from or toward an ancestor's brick: the
    /// renderer writes them to its per-slot fade table.
    pub fades: Vec<super::FadeSlot>,
    /// The data leaves of the cut refinement chose this frame, before fades
    /// (`cut` shows a change of level while it fades; this is the decision).
    pub refined: Vec<NodeKey>,
    /// Statistics.
    pub stats: FrameStats,
}

impl FramePlan {
    /// The cut as `(node, slot)` pairs, `None` for empty leaves.
    pub fn leaves(&self) -> impl Iterator<Item = (NodeKey, Option<SlotId>)> + '_ {
        self.cut.iter().map(|l| (l.key, l.slot()))
    }
}
