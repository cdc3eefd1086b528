//! The per-frame façade: [`BrickManager::update`] polls the loader, refines the
//! cut, assigns pool slots, schedules uploads within the budget and re-submits the
//! wanted loads. The renderer uploads the listed prepared bricks into its atlas
//! and encodes the cut. Nothing here calls the source except
//! [`BrickManager::preload_root`] (set-up time).

mod control;
mod lod;
mod meta;

use meta::MetaCache;
mod stats;
#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_config;
#[cfg(test)]
mod tests_faults;
#[cfg(test)]
mod tests_lod;

pub use lod::FadeSlot;
pub use stats::{FramePlan, FrameStats, Residency, ResidencyCounts, Upload};

use crate::config::{CacheConfig, ConfigError, GpuFormat};
use crate::cpu_cache::CpuCache;
use crate::fade::Fader;
use crate::failures::{Clock, Failures, FetchKind, SystemClock};
use crate::loader::{BrickRequest, Loader, LoaderConfig};
use crate::pool::{BrickPool, PoolError};
use crate::prepared::Preparer;
use crate::refine::{
    DataState, MetaState, NodeClass, OctantMemory, RefineEnv, RefineParams, SplitFilter, refine,
};
use crate::upload::UploadBudget;
use brickray_core::{
    BrickSource, Camera, CutLeaf, EmptyReason, LeafKind, LodMetric, NodeInfo, NodeKey, NodeKind,
    OctreeLayout, RenderMode, TransferFunction, VolumeFrame,
};
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
    volume_frame: VolumeFrame,
    config: CacheConfig,
    gpu: GpuFormat,
    preparer: Arc<Preparer>,
    brick_bytes: u64,
    meta: MetaCache,
    cpu: CpuCache,
    pool: BrickPool,
    loader: Loader,
    budget: UploadBudget,
    failures: Failures,
    clock: Arc<dyn Clock>,
    /// Level-of-detail fades between the refined and the displayed cut.
    fader: Fader,
    /// Octant refinement's memory of the view (`LodMetric::VisibleOctants`).
    octants: OctantMemory,
    /// The coarse floor's nodes (pinned for good once resident).
    floor: Vec<NodeKey>,
    /// Host time of the next update, if given.
    frame_time: Option<f64>,
    /// Time of the last update (fades).
    last_fade_time: Option<f64>,
    /// Origin of clock-based fade time.
    epoch: std::time::Instant,
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

/// Metadata entries kept per prepared brick the CPU budget holds (at least
/// 16,384): the nodes a view meets while refining down to its bricks, with room
/// for the views before it. About 48 bytes an entry, under 4% of the budget.
const META_PER_BRICK: u64 = 64;

fn meta_capacity(cpu_budget_bytes: u64, brick_bytes: u64) -> usize {
    (META_PER_BRICK * (cpu_budget_bytes / brick_bytes.max(1))).clamp(16_384, 1 << 24) as usize
}

/// Refinement's view of the manager: caches only, never the source.
struct Env<'a, 'f> {
    meta: &'a MetaCache,
    failures: &'a Failures,
    cpu: &'a mut CpuCache,
    pool: &'a BrickPool,
    filter: Option<&'f mut dyn SplitFilter>,
    octants: &'a OctantMemory,
}

impl RefineEnv for Env<'_, '_> {
    fn node(&mut self, key: NodeKey) -> MetaState {
        match self.meta.get(key) {
            Some(info) => MetaState::Known(info),
            None if self.failures.is_failed(FetchKind::Metadata, key) => MetaState::Failed,
            None => MetaState::Pending,
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
        } else if self.cpu.get(key).is_some() {
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
    /// A manager over `source`, placed in the world by `volume_frame`, preparing
    /// bricks for a device storing `gpu`. Validates `config` against the layout and
    /// `gpu` ([`CacheConfig::validate`]). Reads nothing: the root's metadata and
    /// brick arrive through the loader, or at once with
    /// [`preload_root`](Self::preload_root).
    pub fn new(
        source: Arc<dyn BrickSource>,
        volume_frame: VolumeFrame,
        config: CacheConfig,
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
            },
        )
        .map_err(CacheError::Spawn)?;
        let floor = lod::floor_nodes(&layout, pool.slot_count(), config.floor_slots);
        Ok(BrickManager {
            fader: Fader::for_layout(&layout),
            octants: OctantMemory::default(),
            floor,
            frame_time: None,
            last_fade_time: None,
            epoch: std::time::Instant::now(),
            source,
            layout,
            volume_frame,
            meta: MetaCache::new(meta_capacity(config.cpu_budget_bytes, brick_bytes)),
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
        })
    }

    /// Replaces the clock that times retry back-offs (tests use a manual one).
    pub fn set_clock(&mut self, clock: Arc<dyn Clock>) {
        self.clock = clock;
    }

    /// Plans one frame. `frame` must not decrease from call to call; bricks used by
    /// the returned cut are pinned in the pool for that frame. Never blocks on I/O
    /// and never calls the source.
    pub fn update(
        &mut self,
        camera: &Camera,
        aspect: f32,
        viewport_height_px: u32,
        frame: u64,
        mode: RenderMode,
        tf: &TransferFunction,
    ) -> FramePlan {
        self.update_filtered(camera, aspect, viewport_height_px, frame, mode, tf, None)
    }

    /// [`update`](Self::update) with visibility: refinement splits only nodes
    /// `filter` allows (nodes hidden in the previous frames stay leaves at
    /// their level and request nothing).
    #[allow(clippy::too_many_arguments)]
    pub fn update_filtered(
        &mut self,
        camera: &Camera,
        aspect: f32,
        viewport_height_px: u32,
        frame: u64,
        mode: RenderMode,
        tf: &TransferFunction,
        filter: Option<&mut dyn SplitFilter>,
    ) -> FramePlan {
        let now = self.clock.now();
        self.meta.begin_frame(frame);
        let report = self.loader.poll(&mut self.cpu);
        for (key, info) in report.metadata {
            self.meta.insert(key, info);
            self.failures.succeeded(FetchKind::Metadata, key);
        }
        for key in report.loaded {
            self.failures.succeeded(FetchKind::Brick, key);
        }
        for (kind, key, error) in report.failed {
            self.failures.record(kind, key, error, now, true);
        }
        self.failures.wake(now);
        self.budget.begin_frame();
        let params = RefineParams {
            camera,
            aspect,
            viewport_height_px,
            volume_frame: &self.volume_frame,
            mode,
            tf,
            tolerance_px: self.config.tolerance_px,
            metric: self.config.lod_metric,
            max_data_leaves: self.cut_slots(),
            max_requests: crate::refine::requests_per_frame(
                self.pool.slot_count(),
                self.config.upload_budget_bytes,
                self.brick_bytes,
            ),
            brick_upload_bytes: self.brick_bytes,
        };
        self.octants.begin(&params);
        let refined = {
            let mut env = Env {
                meta: &self.meta,
                failures: &self.failures,
                cpu: &mut self.cpu,
                pool: &self.pool,
                filter,
                octants: &self.octants,
            };
            refine(&self.layout, &params, &mut env, &mut self.budget)
        };
        self.octants.end(&refined, &self.layout);

        // The displayed cut: the refined one, with level changes fading
        // (crate::fade). If its bricks, their fallbacks and the floor do not fit
        // in the pool, the fades are dropped (the refined cut always fits).
        // Octant-granular cuts are drawn as they are (no fades).
        let octants = matches!(self.config.lod_metric, LodMetric::VisibleOctants { .. });
        let step = self
            .config
            .fade
            .filter(|_| !octants)
            .map(|d| d.step(self.fade_dt(now)));
        let mut shown = self.fader.advance(&refined.leaves, step);
        if !shown.fades.is_empty() {
            let mut need: std::collections::HashSet<NodeKey> = shown
                .leaves
                .iter()
                .filter(|l| l.class == NodeClass::Data)
                .map(|l| l.key)
                .collect();
            need.extend(shown.fallbacks());
            need.extend(self.floor.iter().copied());
            if need.len() > self.pool.slot_count() as usize {
                shown = self.fader.advance(&refined.leaves, None);
            }
        }

        // Pin what is resident first, so that allocations below can only evict
        // bricks this frame does not use.
        let mut cut = Vec::with_capacity(shown.leaves.len());
        let mut pending = Vec::new();
        let mut resident = 0u32;
        // Octants drawn from their parent's brick (index in `cut`), and the
        // parents lending their bricks, with their slots once known.
        let mut borrowed = Vec::new();
        let mut lenders: std::collections::HashMap<NodeKey, Option<u32>> =
            std::collections::HashMap::new();
        for l in &shown.leaves {
            let kind = match l.class {
                NodeClass::Empty(r) => LeafKind::Empty(r),
                NodeClass::Borrowed => {
                    if let Some(p) = self.layout.parent(l.key) {
                        lenders
                            .entry(p)
                            .or_insert_with(|| self.pool.touch(p, frame));
                    }
                    borrowed.push(cut.len());
                    LeafKind::Empty(EmptyReason::NotLoaded)
                }
                NodeClass::Data => match self.pool.touch(l.key, frame) {
                    Some(slot) => {
                        resident += 1;
                        LeafKind::Data { slot }
                    }
                    None => {
                        pending.push(cut.len());
                        LeafKind::Empty(EmptyReason::NotLoaded)
                    }
                },
            };
            cut.push(CutLeaf {
                key: l.key,
                kind,
                priority: l.priority,
            });
        }
        let fallbacks = shown.fallbacks();
        let mut pending_fallbacks = Vec::new();
        for &a in &fallbacks {
            if self.pool.touch(a, frame).is_none() {
                pending_fallbacks.push(a);
            }
        }
        let mut uploads = Vec::with_capacity(pending.len());
        let mut allocation_failures = 0u32;
        let mut assign = |pool: &mut BrickPool, cpu: &CpuCache, key: NodeKey| {
            let brick = cpu.peek(key).cloned()?;
            match pool.allocate(key, frame) {
                Ok(a) => {
                    uploads.push(Upload {
                        key,
                        slot: a.slot,
                        atlas_offset: pool.slot_offset(a.slot),
                        brick,
                    });
                    Some(a.slot)
                }
                // Refinement keeps data leaves within the slot count, so this only
                // happens when `frame` repeats and an earlier plan of the same frame
                // pinned other slots; the leaf then stays empty for this frame.
                Err(PoolError::Full { .. } | PoolError::NoSlots { .. }) => {
                    allocation_failures += 1;
                    None
                }
            }
        };
        for i in pending {
            if let Some(slot) = assign(&mut self.pool, &self.cpu, cut[i].key) {
                cut[i].kind = LeafKind::Data { slot };
            }
        }
        for a in pending_fallbacks {
            // A merge's target is a refined leaf, so it is available; a split's
            // ancestor was drawn last frame, so it is resident.
            assign(&mut self.pool, &self.cpu, a);
        }
        // Refinement gave a lender its brick only when it was on the GPU or
        // in CPU memory (and charged its upload).
        let mut lent: Vec<(NodeKey, Option<u32>)> = lenders.into_iter().collect();
        lent.sort_by_key(|l| l.0);
        for (p, slot) in &mut lent {
            if slot.is_none() {
                *slot = assign(&mut self.pool, &self.cpu, *p);
            } else {
                resident += 1;
            }
        }
        let lent: std::collections::HashMap<NodeKey, Option<u32>> = lent.into_iter().collect();
        let mut borrowed_fades = Vec::with_capacity(borrowed.len());
        let base = self.pool.slot_count();
        for (n, &i) in borrowed.iter().enumerate() {
            let key = cut[i].key;
            if n as u32 >= self.borrowed_slots() {
                break;
            }
            let lender = self
                .layout
                .parent(key)
                .and_then(|p| lent.get(&p).copied().flatten().map(|s| (p, s)));
            if let Some((p, fallback)) = lender {
                let slot = base + n as u32;
                cut[i].kind = LeafKind::Data { slot };
                borrowed_fades.push(FadeSlot {
                    slot,
                    fallback,
                    levels_up: (key.level - p.level) as u32,
                    weight: 1.0,
                    borrowed: true,
                });
            }
        }
        let lenders_drawn = lent.values().filter(|s| s.is_some()).count() as u32;
        let floor = self.floor_step(frame);
        uploads.extend(floor.uploads);
        let slot_of: std::collections::HashMap<NodeKey, u32> = cut
            .iter()
            .filter_map(|l| l.slot().map(|s| (l.key, s)))
            .collect();
        let mut fades = Vec::with_capacity(shown.fades.len());
        for f in &shown.fades {
            match (slot_of.get(&f.leaf), self.pool.slot_of(f.ancestor)) {
                (Some(&slot), Some(fallback)) => fades.push(FadeSlot {
                    slot,
                    fallback,
                    levels_up: (f.leaf.level - f.ancestor.level) as u32,
                    weight: f.weight,
                    borrowed: false,
                }),
                _ => self.fader.cancel(f.leaf),
            }
        }
        let holes = cut
            .iter()
            .filter(|l| {
                matches!(
                    l.kind,
                    LeafKind::Empty(EmptyReason::NotLoaded | EmptyReason::Failed)
                )
            })
            .count() as u32;

        // Loads wanted this frame; queued ones no longer wanted are dropped. A
        // brick job also reads its children's metadata unless all of it is known.
        let mut bricks: Vec<BrickRequest> = refined
            .requests
            .iter()
            .map(|r| BrickRequest {
                key: r.key,
                priority: r.priority,
                info: r.info,
                children_meta: self.children_meta_missing(r.key, &r.info),
            })
            .collect();
        let mut meta_requests = refined.meta_requests.clone();
        if !floor.requests.is_empty() || !floor.meta_requests.is_empty() {
            let known: std::collections::HashSet<NodeKey> = bricks.iter().map(|b| b.key).collect();
            bricks.extend(
                floor
                    .requests
                    .into_iter()
                    .filter(|r| !known.contains(&r.key)),
            );
            let known: std::collections::HashSet<NodeKey> =
                meta_requests.iter().map(|m| m.0).collect();
            meta_requests.extend(
                floor
                    .meta_requests
                    .into_iter()
                    .filter(|m| !known.contains(&m.0)),
            );
        }
        self.loader.submit(&meta_requests, &bricks);

        fades.extend(borrowed_fades);
        // Bricks drawn: data leaves with their own slot, and lenders.
        let working = cut
            .iter()
            .filter(|l| l.slot().is_some_and(|s| s < base))
            .count() as u32
            + lenders_drawn;
        let residency = self.residency_counts();
        self.meta.trim();
        let stats = FrameStats {
            frame,
            leaves: cut.len() as u32,
            working_set_bricks: working,
            pool_slots: self.pool.slot_count(),
            pool_occupied: self.pool.occupied(),
            upload_bricks: uploads.len() as u32,
            upload_bytes: uploads.iter().map(|u| u.brick.bytes()).sum(),
            gpu_hit_rate: if working == 0 {
                1.0
            } else {
                resident as f64 / working as f64
            },
            cpu_hit_rate: self.cpu.hit_rate(),
            requests_in_flight: residency.requested + residency.loading,
            requested_this_frame: bricks.len() as u32,
            metadata_in_flight: (self.loader.queued(FetchKind::Metadata)
                + self.loader.loading(FetchKind::Metadata)) as u32,
            metadata_requested_this_frame: meta_requests.len() as u32,
            metadata_known: self.meta.len() as u32,
            metadata_evicted: self.meta.evicted(),
            residency,
            blocked: refined.blocked,
            allocation_failures,
            failed_needed: refined.failed_needed,
            failures: self.failures.counts(),
            // (Borrowed leaves are drawn as they are, not fading.)
            fading: fades.iter().filter(|f| !f.borrowed).count() as u32,
            holes,
            floor_pinned: self.floor_pinned(),
        };
        FramePlan {
            cut,
            uploads,
            fades,
            refined: refined
                .leaves
                .iter()
                .filter(|l| matches!(l.class, NodeClass::Data | NodeClass::Borrowed))
                .map(|l| l.key)
                .collect(),
            stats,
        }
    }

    /// Most data leaves refinement may use: the pool less the floor and, with
    /// fades on, an eighth of it for the bricks fades keep (fallbacks, merged
    /// leaves still fading); at most the brick budget.
    fn cut_slots(&self) -> u32 {
        let n = self.pool.slot_count();
        let fades = if self.config.fade.is_some() { n / 8 } else { 0 };
        let pool = n.saturating_sub(self.floor.len() as u32 + fades).max(1);
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
