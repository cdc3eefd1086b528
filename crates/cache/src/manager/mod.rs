//! The per-frame façade: [`BrickManager::update`] polls the loader, refines the
//! cut, assigns pool slots, schedules uploads within the budget and re-submits the
//! wanted loads. The renderer uploads the listed prepared bricks into its atlas
//! and encodes the cut. Nothing here calls the source except
//! [`BrickManager::preload_root`] (set-up time).

mod control;
mod frame;
mod lod;
mod meta;

use meta::MetaCache;
mod stats;
#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_config;
#[cfg(test)]
mod tests_evolve;
#[cfg(test)]
mod tests_faults;
#[cfg(test)]
mod tests_lod;

pub use control::Reconfigured;
pub use frame::{FrameInput, UNTIMED_FRAME_RATE};
pub use lod::FadeSlot;
pub use stats::{FramePlan, FrameStats, PhaseTimes, Residency, ResidencyCounts, Upload};

use crate::config::{ConfigError, GpuFormat, OutOfCoreConfig};
use crate::cpu_cache::CpuCache;
use crate::fade::Fader;
use crate::failures::{Clock, Failures, FetchKind, SystemClock};
use crate::loader::{Loader, LoaderConfig};
use crate::pool::{BrickPool, PoolError};
use crate::prepared::Preparer;
use crate::refine::{DataState, MetaClass, MetaState, OctantMemory, RefineEnv, SplitFilter};
use crate::upload::UploadBudget;
use brickray_core::{BrickSource, NodeInfo, NodeKey, NodeKind, OctreeLayout};
use std::sync::Arc;
use thiserror::Error;

/// Errors creating a [`BrickManager`].
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum CacheError {
    /// The configuration or GPU format is not usable.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The GPU pool cannot be sized.
    #[error(transparent)]
    Pool(#[from] PoolError),
    /// A loader thread could not be started.
    #[error("cannot start a loader thread: {0}")]
    Spawn(#[source] std::io::Error),
}

/// Drives the caches, the loader and refinement for a renderer.
pub struct BrickManager {
    source: Arc<dyn BrickSource>,
    layout: OctreeLayout,
    config: OutOfCoreConfig,
    gpu: GpuFormat,
    preparer: Arc<Preparer>,
    brick_bytes: u64,
    /// Every brick of the volume ([`crate::brick_count`]): a pool with this
    /// many slots holds any cut with its floor and fades.
    bricks: u64,
    meta: MetaCache,
    cpu: CpuCache,
    pool: BrickPool,
    loader: Loader,
    budget: UploadBudget,
    failures: Failures,
    clock: Arc<dyn Clock>,
    /// The source is read in batches (over the network): what
    /// [`Lookahead::Remote`](crate::Lookahead::Remote) asks.
    remote: bool,
    /// Level-of-detail fades between the refined and the displayed cut.
    fader: Fader,
    /// Octant refinement's memory of the view (`LodMetric::VisibleOctants`).
    octants: OctantMemory,
    /// The coarse floor's nodes (pinned for good once resident).
    floor: Vec<NodeKey>,
    /// The host's time of the last update (fades), when it gave one.
    last_fade_time: Option<f64>,
    /// The classification the metadata's kept classes are under
    /// ([`MetaCache::class`]): a new stamp whenever the mode, transfer
    /// function or channel styles change.
    class_stamp: u32,
    classified: Option<Classification>,
    /// The last converged frame's refinement, reused while nothing it read
    /// has changed ([`RefineMemo`]).
    refine_memo: Option<RefineMemo>,
    /// The last frame's cut, which a moving view's next refinement evolves
    /// ([`OutOfCoreConfig::evolve`](crate::OutOfCoreConfig::evolve)).
    last_cut: Option<LastCut>,
}

/// The most frames in a row that evolve the last cut
/// ([`OutOfCoreConfig::evolve`](crate::OutOfCoreConfig::evolve)); the next
/// moving frame is refined from the root. Where the pool binds, an evolving
/// cut drifts from the greedy order's by a few per cent of its leaves over
/// tens of frames (docs/cache.md): the root's refinement every 32 frames
/// (about half a second at 60 Hz) bounds that, at the cost of one greedy
/// refinement among 32.
pub const EVOLVED_FRAMES_MAX: u32 = 32;

/// A frame's refined cut, as the next frame's evolving refinement needs it.
#[derive(Debug)]
struct LastCut {
    generation: u64,
    class_stamp: u32,
    /// The metadata cache's change count when it was refined.
    meta: u64,
    leaves: Vec<crate::refine::RefinedLeaf>,
    /// A split waited for metadata, bricks or upload budget.
    waiting: bool,
    /// The visibility filter was inert (hid nothing).
    inert: bool,
    /// Frames evolved in a row up to it (0: refined from the root).
    evolved: u32,
}

/// What a refinement read that a later frame can see change: the views and
/// classification (`generation`, `class_stamp`) and the metadata, CPU cache
/// and pool contents (their change counts). Equal keys under an inert
/// filter, a metric without visible weights and no failures: the same
/// refinement.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct MemoKey {
    generation: u64,
    class_stamp: u32,
    meta: u64,
    cpu: u64,
    pool: u64,
}

/// A converged frame's refinement and the upload budget as it left it.
#[derive(Debug)]
struct RefineMemo {
    key: MemoKey,
    refined: crate::refine::Refinement,
    budget: UploadBudget,
}

/// What decides whether a node holding data is visible.
#[derive(Debug, Clone, PartialEq)]
struct Classification {
    mode: brickray_core::RenderMode,
    tf: brickray_core::TransferFunction,
    channels: Vec<brickray_core::ChannelStyle>,
}

impl std::fmt::Debug for BrickManager {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BrickManager")
            .field("layout", &self.layout)
            .field("config", &self.config)
            .field("gpu", &self.gpu)
            .field("cpu", &self.cpu)
            .field("pool", &self.pool)
            .field("loader", &self.loader)
            .finish_non_exhaustive()
    }
}

/// The metadata map holds at most this share of the CPU budget (1/16, by
/// [`MetaCache::ENTRY_BYTES`], at least 16,384 entries): at the default
/// 512 MiB about 110,000 nodes, the nodes a view meets while refining down to
/// a cut of thousands of bricks (each visited node's eight children), with room
/// for the views before it. (It was 64 entries per prepared brick, sized for
/// entries of 48 bytes; with the error records an entry is about 300 bytes, and
/// over bricks of 16 the map could outgrow the budget itself.)
const META_BUDGET_DIVISOR: u64 = 16;

/// [`OutOfCoreConfig::max_bytes_in_flight`] in stored bricks of `layout`
/// (at least 1).
fn bricks_in_flight(config: &OutOfCoreConfig, layout: &OctreeLayout) -> usize {
    let brick = layout.brick_bytes().max(1) as u64;
    (config.max_bytes_in_flight / brick).clamp(1, usize::MAX as u64) as usize
}

fn meta_capacity(cpu_budget_bytes: u64) -> usize {
    (cpu_budget_bytes / META_BUDGET_DIVISOR / MetaCache::ENTRY_BYTES as u64).clamp(16_384, 1 << 24)
        as usize
}

/// Refinement's view of the manager: caches only, never the source.
struct Env<'a, 'f> {
    meta: &'a MetaCache,
    failures: &'a Failures,
    cpu: &'a mut CpuCache,
    pool: &'a BrickPool,
    filter: Option<&'f mut dyn SplitFilter>,
    octants: &'a OctantMemory,
    /// The frame's classification stamp ([`MetaCache::class`]).
    class_stamp: u32,
}

impl RefineEnv for Env<'_, '_> {
    fn node(&mut self, key: NodeKey) -> MetaState {
        match self.meta.get(key) {
            Some(info) => MetaState::Known(info),
            None if self.failures.is_failed(FetchKind::Metadata, key) => MetaState::Failed,
            None => MetaState::Pending,
        }
    }

    fn meta_class(&mut self, key: NodeKey, visible: &dyn Fn(&NodeInfo) -> bool) -> MetaClass {
        match self.meta.class(key, self.class_stamp, visible) {
            Some(class) => class,
            None if self.failures.is_failed(FetchKind::Metadata, key) => MetaClass::Failed,
            None => MetaClass::Pending,
        }
    }

    fn data(&mut self, key: NodeKey) -> DataState {
        if self.pool.contains(key) {
            // Not touched in the CPU cache: a brick on the GPU has its copy
            // there, so its CPU copy ages and goes before the bricks that are
            // only in CPU memory (those loaded for a split still waiting for its
            // other children, or waiting for upload budget). Touching it made
            // those the least recently used whenever the working set outgrew
            // the CPU cache, and the split never happened.
            DataState::OnGpu
        } else if self.cpu.lookup(key) {
            DataState::InCpu
        } else if self.failures.is_failed(FetchKind::Brick, key) {
            DataState::Failed
        } else {
            DataState::Missing
        }
    }

    fn may_split(&mut self, key: NodeKey) -> bool {
        self.filter.as_mut().is_none_or(|f| f.may_split(key))
    }

    fn request_weight(&mut self, key: NodeKey) -> f64 {
        self.filter.as_mut().map_or(1.0, |f| f.request_weight(key))
    }

    fn visible_weight(&mut self, key: NodeKey) -> Option<f64> {
        self.filter.as_mut().and_then(|f| f.visible_weight(key))
    }

    fn held(&mut self, key: NodeKey) -> bool {
        self.octants.held(key)
    }

    fn may_promote(&mut self, key: NodeKey) -> bool {
        self.octants.may_promote(key)
    }
}

impl BrickManager {
    /// A manager over `source`, preparing bricks for a device storing `gpu`. Validates `config` against the layout and
    /// `gpu` ([`OutOfCoreConfig::validate`]). Reads nothing: the root's metadata and
    /// brick arrive through the loader, or at once with
    /// [`preload_root`](Self::preload_root).
    pub fn new(
        source: Arc<dyn BrickSource>,
        config: OutOfCoreConfig,
        gpu: GpuFormat,
    ) -> Result<BrickManager, CacheError> {
        let layout = source.layout().clone();
        config.validate(&layout, &gpu)?;
        let pool = BrickPool::new(gpu.pool_limits(&layout, config.gpu_budget_bytes)?)?;
        let preparer = Arc::new(Preparer::new(&layout, &gpu)?);
        let brick_bytes = gpu.prepared_brick_bytes(&layout)?;
        let loader = Loader::new(
            source.clone(),
            preparer.clone(),
            LoaderConfig {
                workers: config.loader_threads,
                max_in_flight: bricks_in_flight(&config, &layout),
            },
        )
        .map_err(CacheError::Spawn)?;
        let floor = lod::floor_nodes(&layout, pool.slot_count(), config.floor_slots);
        // A source that panics here is not remote; its reads fail typed later.
        let remote = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| source.batch_size()))
            .is_ok_and(|b| b > 1);
        Ok(BrickManager {
            fader: Fader::for_layout(&layout),
            octants: OctantMemory::default(),
            floor,
            last_fade_time: None,
            class_stamp: 0,
            classified: None,
            refine_memo: None,
            last_cut: None,
            bricks: crate::brick_count(&layout),
            source,
            layout,
            meta: MetaCache::new(meta_capacity(config.cpu_budget_bytes)),
            cpu: CpuCache::new(config.cpu_budget_bytes),
            pool,
            loader,
            budget: UploadBudget::new(config.upload_budget_bytes),
            failures: Failures::new(config.retry),
            config,
            gpu,
            preparer,
            brick_bytes,
            clock: Arc::new(SystemClock),
            remote,
        })
    }

    /// Replaces the clock that times retry back-offs (tests use a manual one).
    pub fn set_clock(&mut self, clock: Arc<dyn Clock>) {
        self.clock = clock;
    }

    /// Most data leaves refinement may use: the pool less the floor and, with
    /// fades on, an eighth of it for the bricks fades keep (fallbacks, merged
    /// leaves still fading); at most the brick budget. A pool with a slot for
    /// every brick of the volume (the most it is given,
    /// [`GpuFormat::pool_limits`]) keeps nothing back: the floor, the fades
    /// and any cut are bricks of the volume, each with its own slot.
    fn cut_slots(&self) -> u32 {
        let n = self.pool.slot_count();
        let fades = if self.config.fade.is_some() { n / 8 } else { 0 };
        let pool = if n as u64 >= self.bricks {
            n
        } else {
            n.saturating_sub(self.floor.len() as u32 + fades).max(1)
        };
        self.config
            .brick_budget
            .map_or(pool, |b| pool.min(b.max(1)))
    }

    /// True when some child of `key` inside the volume has no known metadata (and
    /// the node can be split at all).
    pub(crate) fn children_meta_missing(&self, key: NodeKey, info: &NodeInfo) -> bool {
        !matches!(info.kind, NodeKind::Uniform(_))
            && key.level.saturating_add(1) < self.layout.levels
            && self
                .layout
                .children(key)
                .iter()
                .any(|c| self.layout.in_volume(*c) && !self.meta.contains(*c))
    }
}
