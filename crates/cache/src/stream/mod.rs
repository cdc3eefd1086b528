//! The out-of-core planner, free of any GPU API: [`Streamer`] owns the brick
//! manager (caches, loader, pool bookkeeping, fades, octant memory), the
//! visibility state, the visible weights and the convergence rule. Each frame
//! it takes the frame's views, the classification and the feedback the
//! renderer read back, and returns a [`StreamPlan`]: the cut, the uploads, the
//! fades, the occlusion boxes to query per view, the statistics and whether
//! the view has converged. The renderer executes the plan (atlas, tables,
//! index, read-back rings, occlusion pass) and nothing it does decides what
//! to load.
//!
//! Several views of one volume (a stereo pair, a 3D view beside slice views)
//! are planned together: one cut holds each node at the finest level any view
//! needs, each brick is loaded once, and what each view's rays observed feeds
//! one visibility state (a node is visible when any view sees it) and one set
//! of visible weights.

mod feedback;
mod occlusion;
#[cfg(test)]
mod tests;

pub use feedback::{QueryResult, UsageFrame, ViewFeedback};
pub use occlusion::{MAX_QUERIES_PER_FRAME, MIN_TILE_PX, QueryBatch, QuerySchedule};

use crate::config::{ConfigError, GpuFormat, OutOfCoreConfig};
use crate::failures::StreamError;
use crate::manager::{
    BrickManager, CacheError, FadeSlot, FrameInput, FrameStats, Reconfigured, Upload,
};
use crate::pool::BrickPool;
use crate::refine::Views;
use brickray_core::{
    BrickSource, CutLeaf, FrameView, NodeKey, OctreeLayout, RenderMode, TransferFunction,
    ViewGenerations,
};
use brickray_visibility::{VisibilityCounts, VisibilityPolicy, VisibilityState, VisibleWeights};
use std::sync::Arc;

/// What decides which bricks a view shows and how: today the render mode
/// with its transfer function (DVR), isovalue or MIP.
#[derive(Debug, Clone, Copy)]
pub struct Classification<'a> {
    /// The render mode.
    pub mode: RenderMode,
    /// The transfer function.
    pub tf: &'a TransferFunction,
    /// A multi-channel volume's channel styles (empty for one channel):
    /// a node is visible when a visible channel shows in it
    /// ([`brickray_core::channels::node_visible`]); `tf_generation` then
    /// changes with them.
    pub channels: &'a [brickray_core::ChannelStyle],
    /// Bumped by the transfer function's owner whenever it changes: what
    /// the planner remembers of a view holds for one generation (the
    /// function itself is never compared or cloned).
    pub tf_generation: u64,
}

/// One frame for the planner.
#[derive(Debug, Clone, Copy)]
pub struct StreamFrame<'a> {
    /// The views drawing the volume this frame (at least one).
    pub views: &'a [FrameView],
    /// The classification, shared by the views.
    pub classification: Classification<'a>,
    /// The feedback read back since the last frame, one entry per view
    /// (missing entries: nothing read back).
    pub feedback: &'a [ViewFeedback],
    /// The host's time of the frame in seconds (fades in milliseconds);
    /// `None`: frames 1/60 s apart ([`crate::UNTIMED_FRAME_RATE`]).
    pub time: Option<f64>,
}

/// What the planner decided for one frame.
#[derive(Debug, Clone, Default)]
pub struct StreamPlan {
    /// The frame number (feedback rendered from this plan is stamped with it).
    pub frame: u64,
    /// Leaves covering the octree cube; encode it as it is.
    pub cut: Vec<CutLeaf>,
    /// Bricks to copy into the atlas before drawing.
    pub uploads: Vec<Upload>,
    /// Rows of the per-slot table that carry a fade or draw a borrowed octant.
    pub fades: Vec<FadeSlot>,
    /// `(slot, node)` of the cut's data leaves: what the usage counters of
    /// this frame are read back against.
    pub leaves: Vec<(u32, NodeKey)>,
    /// Occlusion queries per view, in the order of the views (empty batches
    /// when the policy queries nothing).
    pub queries: Vec<QueryBatch>,
    /// True when the kernel must measure visible weights.
    pub measures_weights: bool,
    /// Statistics.
    pub stats: StreamStats,
}

/// The planner's statistics of one frame.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StreamStats {
    /// The cache's view: working set, pool occupancy, uploads, hit rates,
    /// requests in flight, residency counts, failures.
    pub cache: FrameStats,
    /// True when another frame of these views would not change the image:
    /// nothing in flight or pending, no brick the views need has failed, and
    /// the feedback (where a policy or the metric uses it) observed every
    /// leaf and no longer changes the cut.
    pub converged: bool,
    /// Data leaves of the cut per octree level (level 0 = root; levels past
    /// 15 are counted in 15).
    pub data_leaves_per_level: [u32; 16],
    /// The visibility policy in force.
    pub policy: VisibilityPolicy,
    /// The cut's data leaves by visibility (all unobserved without culling).
    pub visibility: VisibilityCounts,
    /// True when this frame's cut differs from the previous frame's.
    pub cut_changed: bool,
    /// The occlusion schedule, summed over the views.
    pub queries: QuerySchedule,
}

/// How much more an inner node of the cut weighs for refinement than a leaf
/// (`VisibleWeights::ranked_weight`, which also holds the weight a node split
/// with while the view stays): a split node collapses only once its priority
/// falls below half the error budget.
pub const WEIGHT_HYSTERESIS: f64 = 2.0;

/// The out-of-core planner of one volume (see the module documentation).
pub struct Streamer {
    manager: BrickManager,
    visibility: VisibilityState,
    weights: VisibleWeights,
    views: ViewGenerations,
    /// The classification last planned with (mode, transfer-function
    /// generation).
    classification: Option<(RenderMode, u64)>,
    /// Bumped when the views or the classification change.
    generation: u64,
    /// The generation the weights' memory of a view is about.
    weights_generation: Option<u64>,
    frame: u64,
    leaves: Vec<(u32, NodeKey)>,
    stats: StreamStats,
}

impl std::fmt::Debug for Streamer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Streamer")
            .field("manager", &self.manager)
            .field("frame", &self.frame)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl Streamer {
    /// A planner over `source`, preparing bricks for a device storing `gpu`
    /// (validates `config`; reads nothing).
    pub fn new(
        source: Arc<dyn BrickSource>,
        config: OutOfCoreConfig,
        gpu: GpuFormat,
    ) -> Result<Streamer, CacheError> {
        let manager = BrickManager::new(source, config, gpu)?;
        let layout = manager.layout().clone();
        let mut visibility = VisibilityState::new(config.visibility_config);
        visibility.set_layout(&layout);
        Ok(Streamer {
            weights: VisibleWeights::new(&layout),
            visibility,
            manager,
            views: ViewGenerations::default(),
            classification: None,
            generation: 0,
            weights_generation: None,
            frame: 0,
            leaves: Vec::new(),
            stats: StreamStats::default(),
        })
    }

    /// Reads the root's metadata and brick now (set-up time, blocking on the
    /// source) so the first frame already shows a coarse image
    /// ([`BrickManager::preload_root`]).
    pub fn preload_root(&mut self) -> Result<(), StreamError> {
        self.manager.preload_root()
    }

    /// The frame the next [`plan`](Self::plan) will have: read-backs copied
    /// in earlier frames were submitted by now.
    pub fn next_frame(&self) -> u64 {
        self.frame + 1
    }

    /// Plans one frame (see [`StreamPlan`]). Never blocks on I/O and never
    /// calls the source.
    pub fn plan(&mut self, f: &StreamFrame<'_>) -> StreamPlan {
        self.frame += 1;
        let frame = self.frame;
        let generation = self.note_generation(f);
        let weighted = self.measures_weights();
        self.observe(f.feedback, weighted);
        let views = Views::of(self.manager.layout(), f.views);
        let policy = self.manager.config().visibility;
        let plan = {
            let mut filter = feedback::Filter {
                visibility: policy.culls().then_some(&mut self.visibility),
                weights: weighted.then_some(&mut self.weights),
            };
            let input = FrameInput {
                views: &views,
                generation,
                frame,
                mode: f.classification.mode,
                tf: f.classification.tf,
                channels: f.classification.channels,
                time: f.time,
            };
            self.manager.update(&input, Some(&mut filter))
        };
        let leaves: Vec<(u32, NodeKey)> = plan
            .cut
            .iter()
            .filter_map(|l| l.slot().map(|s| (s, l.key)))
            .collect();
        let cut_changed = leaves != self.leaves;
        self.leaves = leaves;
        self.note_cut(&plan.refined, weighted);
        let queries = self.schedule_queries(&views, f.views);
        self.stats = self.frame_stats(&plan.cut, plan.stats, cut_changed, weighted, &queries);
        StreamPlan {
            frame,
            cut: plan.cut,
            uploads: plan.uploads,
            fades: plan.fades,
            leaves: self.leaves.clone(),
            queries,
            measures_weights: weighted,
            stats: self.stats,
        }
    }

    /// Notes the frame's views and classification; returns the generation
    /// refinement's memories hold for, and forgets the weights' memory of
    /// another view.
    fn note_generation(&mut self, f: &StreamFrame<'_>) -> u64 {
        let before = self.views.current();
        let views = self.views.note(f.views);
        let class = (f.classification.mode, f.classification.tf_generation);
        if views != before || self.classification != Some(class) || self.generation == 0 {
            self.generation += 1;
            self.classification = Some(class);
        }
        if self.weights_generation != Some(self.generation) {
            // What split nodes showed as leaves, and how often nodes
            // collapsed, hold for their view only.
            self.weights.forget_view();
            self.weights_generation = Some(self.generation);
        }
        self.generation
    }

    /// The statistics of the frame and the convergence rule: with culling,
    /// the views have converged only once every leaf was observed and the
    /// feedback no longer changes the cut; so has the weighted order, once
    /// every leaf's weight was observed.
    fn frame_stats(
        &self,
        cut: &[CutLeaf],
        cache: FrameStats,
        cut_changed: bool,
        weighted: bool,
        queries: &[QueryBatch],
    ) -> StreamStats {
        let policy = self.manager.config().visibility;
        let mut per_level = [0u32; 16];
        for l in cut.iter().filter(|l| l.kind.is_data()) {
            per_level[(l.key.level as usize).min(15)] += 1;
        }
        let visibility = self.visibility.counts();
        let (leaves, weighed) = self.weights.counts();
        let fed_back = policy.culls() || weighted;
        let settled = (!policy.culls() || visibility.unobserved == 0)
            && (!weighted || weighed == leaves)
            && !(fed_back && cut_changed);
        StreamStats {
            cache,
            converged: cache.converged() && settled,
            data_leaves_per_level: per_level,
            policy,
            visibility,
            cut_changed,
            queries: queries
                .iter()
                .fold(QuerySchedule::default(), |a, q| a.add(&q.schedule)),
        }
    }

    /// True when the ray caster must measure visible weights (the metric
    /// ranks by them).
    pub fn measures_weights(&self) -> bool {
        self.manager.config().lod_metric.uses_visible_weights()
    }

    /// Applies a configuration ([`BrickManager::configure`]: validated whole,
    /// only what changed is rebuilt). A visibility-policy change forgets what
    /// was observed; a metric or brick-budget change starts a new view for
    /// the weights; a pool rebuild forgets the observations made through its
    /// slots.
    pub fn configure(&mut self, config: OutOfCoreConfig) -> Result<Reconfigured, ConfigError> {
        let old = *self.manager.config();
        let out = self.manager.configure(config)?;
        if config.visibility != old.visibility {
            self.visibility.clear();
        }
        if config.visibility_config != old.visibility_config {
            self.visibility.set_config(config.visibility_config);
        }
        if config.lod_metric != old.lod_metric || config.brick_budget != old.brick_budget {
            self.weights_generation = None;
        }
        if out.pool {
            self.visibility.clear();
            self.weights.clear();
            self.leaves.clear();
        }
        Ok(out)
    }

    /// The configuration in force.
    pub fn config(&self) -> &OutOfCoreConfig {
        self.manager.config()
    }

    /// The statistics of the last frame.
    pub fn stats(&self) -> StreamStats {
        self.stats
    }

    /// True when another frame of the same views would change the image.
    pub fn wants_redraw(&self) -> bool {
        !self.stats.converged
    }

    /// The octree layout.
    pub fn layout(&self) -> &OctreeLayout {
        self.manager.layout()
    }

    /// What the device stores per slot.
    pub fn gpu_format(&self) -> &GpuFormat {
        self.manager.gpu_format()
    }

    /// The pool bookkeeping (slot grid, atlas size, slot offsets).
    pub fn pool(&self) -> &BrickPool {
        self.manager.pool()
    }

    /// Rows of the renderer's slot table and usage counters: one per pool
    /// slot, then the borrowed slots of octant-granular cuts
    /// ([`BrickManager::borrowed_slots`]).
    pub fn slot_rows(&self) -> u32 {
        self.manager.pool().slot_count().max(1) + self.manager.borrowed_slots()
    }

    /// The brick manager (residency, failures, caches).
    pub fn manager(&self) -> &BrickManager {
        &self.manager
    }

    /// The first streaming failure since the last call, with the count of
    /// further ones ([`BrickManager::take_error`]).
    pub fn take_error(&mut self) -> Option<StreamError> {
        self.manager.take_error()
    }

    /// Forgets every failed brick so it is requested again when the view
    /// needs it (after the source was repaired).
    pub fn retry_failed(&mut self) {
        self.manager.retry_failed();
    }

    /// The visibility state (diagnostics and tests).
    pub fn visibility(&self) -> &VisibilityState {
        &self.visibility
    }

    /// The visible weights (diagnostics and tests).
    pub fn weights(&self) -> &VisibleWeights {
        &self.weights
    }
}
