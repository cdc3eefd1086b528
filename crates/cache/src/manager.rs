//! The per-frame façade: [`BrickManager::update`] polls the loader, refines the
//! cut, assigns pool slots, schedules uploads within the budget and re-submits the
//! wanted loads. The renderer uploads the listed bricks into its atlas and encodes
//! the cut.

use crate::cpu_cache::{BrickBytes, CpuCache};
use crate::loader::{LoadError, Loader, LoaderConfig};
use crate::pool::{BrickPool, PoolError, PoolLimits, SlotId};
use crate::refine::{
    DataState, EmptyReason, NodeClass, RefineEnv, RefineParams, SplitBlocks, refine,
};
use crate::upload::UploadBudget;
use brickray_core::{
    BrickSource, Camera, NodeInfo, NodeKey, OctreeLayout, RenderMode, TransferFunction, VolumeFrame,
};
use std::collections::HashMap;
use std::sync::Arc;
use thiserror::Error;

/// Errors creating a [`BrickManager`].
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum CacheError {
    /// The GPU pool cannot be sized.
    #[error(transparent)]
    Pool(#[from] PoolError),
    /// A loader thread could not be started.
    #[error("cannot start a loader thread: {0}")]
    Spawn(#[source] std::io::Error),
}

/// Budgets and knobs of a [`BrickManager`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ManagerConfig {
    /// System memory for decompressed bricks (level-2 cache).
    pub cpu_budget_bytes: usize,
    /// GPU memory for the brick pool.
    pub gpu_budget_bytes: u64,
    /// Device limit on a 3D texture dimension.
    pub max_texture_dim_3d: u32,
    /// Bytes uploaded per frame (at least one split or one brick always goes).
    pub upload_budget_bytes: u64,
    /// Screen-space error tolerance in pixels per voxel (default 1).
    pub tolerance_px: f32,
    /// Loader threads.
    pub loader: LoaderConfig,
}

impl Default for ManagerConfig {
    fn default() -> Self {
        ManagerConfig {
            cpu_budget_bytes: 512 << 20,
            gpu_budget_bytes: 256 << 20,
            max_texture_dim_3d: 2048,
            upload_budget_bytes: 16 << 20,
            tolerance_px: 1.0,
            loader: LoaderConfig::default(),
        }
    }
}

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
    /// Its load failed; the error is kept ([`BrickManager::failure`]).
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

/// What a leaf of the cut holds for the renderer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LeafKind {
    /// Nothing to sample here.
    Empty(EmptyReason),
    /// Sample the brick in this pool slot (resident or uploaded this frame).
    Data {
        /// The slot.
        slot: SlotId,
    },
}

/// One leaf of the frame's cut.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CutLeaf {
    /// The node.
    pub key: NodeKey,
    /// What it holds.
    pub kind: LeafKind,
    /// Projected voxel size in pixels (0 for empty leaves).
    pub priority: f32,
}

impl CutLeaf {
    /// The pool slot of a data leaf.
    pub fn slot(&self) -> Option<SlotId> {
        match self.kind {
            LeafKind::Data { slot } => Some(slot),
            LeafKind::Empty(_) => None,
        }
    }
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
    /// The brick (`stored_side^3` samples, x fastest).
    pub data: BrickBytes,
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
    /// Pool slots.
    pub pool_slots: u32,
    /// Occupied pool slots.
    pub pool_occupied: u32,
    /// Bricks scheduled for upload.
    pub upload_bricks: u32,
    /// Bytes scheduled for upload.
    pub upload_bytes: u64,
    /// Working-set bricks already on the GPU / working-set bricks (this frame; 1 if none).
    pub gpu_hit_rate: f64,
    /// Lookups of bricks not on the GPU found in CPU memory (cumulative; 1 if none).
    pub cpu_hit_rate: f64,
    /// Requests queued or being read.
    pub requests_in_flight: u32,
    /// Nodes requested this frame.
    pub requested_this_frame: u32,
    /// Nodes per residency state.
    pub residency: ResidencyCounts,
    /// Why nodes were not split.
    pub blocked: SplitBlocks,
    /// Data leaves left empty because the pool had no unpinned slot (only when the
    /// same frame number is planned twice).
    pub allocation_failures: u32,
}

/// What the renderer does this frame.
#[derive(Debug, Clone, Default)]
pub struct FramePlan {
    /// Leaves covering the octree cube (each point in exactly one).
    pub cut: Vec<CutLeaf>,
    /// Bricks to upload before drawing.
    pub uploads: Vec<Upload>,
    /// Statistics.
    pub stats: FrameStats,
}

impl FramePlan {
    /// The cut as `(node, slot)` pairs, `None` for empty leaves: the form the
    /// spatial-index encoder takes.
    pub fn leaves(&self) -> impl Iterator<Item = (NodeKey, Option<SlotId>)> + '_ {
        self.cut.iter().map(|l| (l.key, l.slot()))
    }
}

/// Drives the caches, the loader and refinement for a renderer.
pub struct BrickManager {
    source: Arc<dyn BrickSource>,
    layout: OctreeLayout,
    volume_frame: VolumeFrame,
    config: ManagerConfig,
    meta: HashMap<NodeKey, Option<NodeInfo>>,
    cpu: CpuCache,
    pool: BrickPool,
    loader: Loader,
    budget: UploadBudget,
}

impl std::fmt::Debug for BrickManager {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BrickManager")
            .field("layout", &self.layout)
            .field("config", &self.config)
            .field("cpu", &self.cpu)
            .field("pool", &self.pool)
            .field("loader", &self.loader)
            .finish_non_exhaustive()
    }
}

struct Env<'a> {
    source: &'a dyn BrickSource,
    meta: &'a mut HashMap<NodeKey, Option<NodeInfo>>,
    cpu: &'a mut CpuCache,
    pool: &'a BrickPool,
    loader: &'a mut Loader,
}

impl RefineEnv for Env<'_> {
    fn node(&mut self, key: NodeKey) -> Option<NodeInfo> {
        if let Some(m) = self.meta.get(&key) {
            return *m;
        }
        let m = match self.source.node(key) {
            Ok(info) => Some(info),
            Err(e) => {
                self.loader.mark_failed(key, LoadError::Source(e));
                None
            }
        };
        self.meta.insert(key, m);
        m
    }

    fn data(&mut self, key: NodeKey) -> DataState {
        if self.pool.contains(key) {
            self.cpu.touch(key);
            DataState::OnGpu
        } else if self.cpu.get(key).is_some() {
            DataState::InCpu
        } else if self.loader.failure(key).is_some() {
            DataState::Failed
        } else {
            DataState::Missing
        }
    }
}

impl BrickManager {
    /// A manager over `source`, placed in the world by `volume_frame`.
    pub fn new(
        source: Arc<dyn BrickSource>,
        volume_frame: VolumeFrame,
        config: ManagerConfig,
    ) -> Result<BrickManager, CacheError> {
        let layout = source.layout().clone();
        let pool = BrickPool::new(PoolLimits {
            budget_bytes: config.gpu_budget_bytes,
            brick_bytes: layout.brick_bytes() as u64,
            stored_side: layout.stored_side(),
            max_dim: config.max_texture_dim_3d,
        })?;
        let loader = Loader::new(source.clone(), config.loader).map_err(CacheError::Spawn)?;
        Ok(BrickManager {
            source,
            layout,
            volume_frame,
            meta: HashMap::new(),
            cpu: CpuCache::new(config.cpu_budget_bytes),
            pool,
            loader,
            budget: UploadBudget::new(config.upload_budget_bytes),
            config,
        })
    }

    /// Plans one frame. `frame` must not decrease from call to call; bricks used by
    /// the returned cut are pinned in the pool for that frame. Never blocks on I/O.
    pub fn update(
        &mut self,
        camera: &Camera,
        aspect: f32,
        viewport_height_px: u32,
        frame: u64,
        mode: RenderMode,
        tf: &TransferFunction,
    ) -> FramePlan {
        self.loader.poll(&mut self.cpu);
        self.budget.begin_frame();
        let params = RefineParams {
            camera,
            aspect,
            viewport_height_px,
            volume_frame: &self.volume_frame,
            mode,
            tf,
            tolerance_px: self.config.tolerance_px,
            max_data_leaves: self.pool.slot_count(),
        };
        let refined = {
            let mut env = Env {
                source: self.source.as_ref(),
                meta: &mut self.meta,
                cpu: &mut self.cpu,
                pool: &self.pool,
                loader: &mut self.loader,
            };
            refine(&self.layout, &params, &mut env, &mut self.budget)
        };

        // Pin what is resident first, so that allocations below can only evict
        // bricks this frame does not use.
        let mut cut = Vec::with_capacity(refined.leaves.len());
        let mut pending = Vec::new();
        let mut resident = 0u32;
        for l in &refined.leaves {
            let kind = match l.class {
                NodeClass::Empty(r) => LeafKind::Empty(r),
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
        let mut uploads = Vec::with_capacity(pending.len());
        let mut allocation_failures = 0u32;
        for i in pending {
            let key = cut[i].key;
            let Some(data) = self.cpu.peek(key).cloned() else {
                continue;
            };
            match self.pool.allocate(key, frame) {
                Ok(a) => {
                    cut[i].kind = LeafKind::Data { slot: a.slot };
                    uploads.push(Upload {
                        key,
                        slot: a.slot,
                        atlas_offset: self.pool.slot_offset(a.slot),
                        data,
                    });
                }
                // Refinement keeps data leaves within the slot count, so this only
                // happens when `frame` repeats and an earlier plan of the same frame
                // pinned other slots; the leaf then stays empty for this frame.
                Err(PoolError::Full { .. } | PoolError::NoSlots { .. }) => allocation_failures += 1,
            }
        }

        // Loads wanted this frame; queued ones no longer wanted are dropped.
        self.loader.submit(&refined.requests);

        let working = cut
            .iter()
            .filter(|l| matches!(l.kind, LeafKind::Data { .. }))
            .count() as u32;
        let residency = self.residency_counts();
        let stats = FrameStats {
            frame,
            leaves: cut.len() as u32,
            working_set_bricks: working,
            pool_slots: self.pool.slot_count(),
            pool_occupied: self.pool.occupied(),
            upload_bricks: uploads.len() as u32,
            upload_bytes: uploads.iter().map(|u| u.data.len() as u64).sum(),
            gpu_hit_rate: if working == 0 {
                1.0
            } else {
                resident as f64 / working as f64
            },
            cpu_hit_rate: self.cpu.hit_rate(),
            requests_in_flight: residency.requested + residency.loading,
            requested_this_frame: refined.requests.len() as u32,
            residency,
            blocked: refined.blocked,
            allocation_failures,
        };
        FramePlan {
            cut,
            uploads,
            stats,
        }
    }

    /// The residency of a node's brick, `None` when it is nowhere.
    pub fn residency(&self, key: NodeKey) -> Option<Residency> {
        if self.pool.contains(key) {
            Some(Residency::OnGpu)
        } else if self.cpu.contains(key) {
            Some(Residency::InCpu)
        } else if self.loader.failure(key).is_some() {
            Some(Residency::Failed)
        } else if self.loader.is_loading(key) {
            Some(Residency::Loading)
        } else if self.loader.is_queued(key) {
            Some(Residency::Requested)
        } else {
            None
        }
    }

    /// Nodes per residency state (each node counted once, in its most GPU-ward state).
    pub fn residency_counts(&self) -> ResidencyCounts {
        let on_gpu = self.pool.occupied();
        let in_cpu = self
            .pool
            .resident()
            .filter(|(k, _)| self.cpu.contains(*k))
            .count() as u32;
        ResidencyCounts {
            requested: self.loader.queued() as u32,
            loading: self.loader.loading() as u32,
            in_cpu: self.cpu.len() as u32 - in_cpu,
            on_gpu,
            failed: self.loader.failed_count() as u32,
        }
    }

    /// The error that made a node fail.
    pub fn failure(&self, key: NodeKey) -> Option<Arc<LoadError>> {
        self.loader.failure(key).cloned()
    }

    /// Forgets every failure so the nodes are requested again when wanted.
    pub fn retry_failed(&mut self) {
        let keys: Vec<NodeKey> = self.loader.failures().map(|(k, _)| k).collect();
        for k in keys {
            self.loader.retry(k);
            self.meta.remove(&k);
        }
    }

    /// Forgets every GPU slot (e.g. after the atlas was recreated); the next update
    /// uploads the working set again.
    pub fn clear_gpu(&mut self) {
        self.pool.clear();
    }

    /// Reads the root brick synchronously into the CPU cache, so the very first
    /// frame already shows a coarse image. Meant for set-up time, not the frame
    /// path (it blocks on one brick read).
    pub fn preload_root(&mut self) -> Result<(), brickray_core::BrickError> {
        let key = NodeKey::ROOT;
        let info = self.source.node(key)?;
        self.meta.insert(key, Some(info));
        if matches!(info.kind, brickray_core::NodeKind::Empty) {
            return Ok(());
        }
        let mut buf = vec![0u8; self.layout.brick_bytes()];
        self.source.read_brick(key, &mut buf)?;
        self.cpu.insert(key, buf.into());
        Ok(())
    }

    /// Moves the volume in the world.
    pub fn set_volume_frame(&mut self, frame: VolumeFrame) {
        self.volume_frame = frame;
    }

    /// Sets the screen-space error tolerance (pixels per voxel).
    pub fn set_tolerance_px(&mut self, tolerance_px: f32) {
        self.config.tolerance_px = tolerance_px;
    }

    /// The octree layout.
    pub fn layout(&self) -> &OctreeLayout {
        &self.layout
    }

    /// The configuration.
    pub fn config(&self) -> &ManagerConfig {
        &self.config
    }

    /// The pool bookkeeping (slot grid, atlas size, slot offsets).
    pub fn pool(&self) -> &BrickPool {
        &self.pool
    }

    /// The CPU cache.
    pub fn cpu_cache(&self) -> &CpuCache {
        &self.cpu
    }

    /// The loader.
    pub fn loader(&self) -> &Loader {
        &self.loader
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::refine::tests::assert_exact_cover;
    use crate::test_source::{TestSource, fill_byte};
    use brickray_core::BrickError;
    use glam::Vec3;
    use proptest::prelude::*;
    use std::collections::HashSet;
    use std::sync::atomic::Ordering;
    use std::time::{Duration, Instant};

    fn manager(src: &Arc<TestSource>, config: ManagerConfig) -> BrickManager {
        let dims = src.layout.volume.dims;
        BrickManager::new(src.clone(), VolumeFrame::centered(dims, [1.0; 3]), config).unwrap()
    }

    fn config() -> ManagerConfig {
        ManagerConfig {
            cpu_budget_bytes: 4 << 20,
            gpu_budget_bytes: 1 << 20,
            ..ManagerConfig::default()
        }
    }

    /// Checks a plan's invariants against the manager's pool.
    fn check_plan(m: &BrickManager, plan: &FramePlan) {
        let keys: Vec<NodeKey> = plan.cut.iter().map(|l| l.key).collect();
        assert_exact_cover(&keys, m.layout().levels);
        let mut slots = HashSet::new();
        for l in &plan.cut {
            if let LeafKind::Data { slot } = l.kind {
                assert!(slots.insert(slot), "slot {slot} used twice");
                assert_eq!(m.pool().key_of(slot), Some(l.key));
                assert!(m.pool().is_pinned(slot, plan.stats.frame));
            }
        }
        assert_eq!(slots.len() as u32, plan.stats.working_set_bricks);
        for u in &plan.uploads {
            assert!(slots.contains(&u.slot));
            assert_eq!(m.pool().key_of(u.slot), Some(u.key));
            assert_eq!(u.atlas_offset, m.pool().slot_offset(u.slot));
            assert!(u.data.iter().all(|&b| b == fill_byte(u.key)));
        }
    }

    /// Updates until a frame neither requests nor uploads anything and no load is
    /// in flight; returns the last plan and the frame count.
    fn converge(
        m: &mut BrickManager,
        frame: &mut u64,
        cam: &Camera,
        mode: RenderMode,
        tf: &TransferFunction,
        mut each: impl FnMut(&BrickManager, &FramePlan),
    ) -> FramePlan {
        let t = Instant::now();
        loop {
            *frame += 1;
            let plan = m.update(cam, 1.0, 128, *frame, mode, tf);
            check_plan(m, &plan);
            each(m, &plan);
            if plan.uploads.is_empty()
                && plan.stats.requested_this_frame == 0
                && plan.stats.requests_in_flight == 0
            {
                return plan;
            }
            assert!(
                t.elapsed() < Duration::from_secs(10),
                "no convergence: {:?}",
                plan.stats
            );
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    #[test]
    fn converges_to_a_complete_resident_cut() {
        let src = Arc::new(TestSource::new(64));
        let mut m = manager(&src, config());
        let cam = Camera::orbit(Vec3::ZERO, 1.6, 0.4, 0.3);
        let tf = TransferFunction::ramp(0.1, 1.0, 0.5);
        let mut frame = 0;
        let first = m.update(&cam, 1.0, 128, 1, RenderMode::Dvr, &tf);
        frame += 1;
        // Nothing loaded yet: the root is wanted and the cut is still complete.
        assert_eq!(first.cut.len(), 1);
        assert_eq!(first.cut[0].kind, LeafKind::Empty(EmptyReason::NotLoaded));
        assert!(first.uploads.is_empty());
        let plan = converge(&mut m, &mut frame, &cam, RenderMode::Dvr, &tf, |_, _| {});
        assert!(plan.stats.working_set_bricks > 8);
        assert!(plan.cut.iter().any(|l| l.key.level >= 2));
        assert_eq!(plan.stats.gpu_hit_rate, 1.0);
        let r = plan.stats.residency;
        assert_eq!(r.on_gpu, m.pool().occupied());
        assert_eq!(r.requested + r.loading + r.failed, 0);
        for l in &plan.cut {
            if matches!(l.kind, LeafKind::Data { .. }) {
                assert_eq!(m.residency(l.key), Some(Residency::OnGpu));
            }
        }
        // Root and children loaded together: the root was split before it was ever
        // needed on the GPU.
        assert_eq!(m.residency(NodeKey::ROOT), Some(Residency::InCpu));
        // A static view keeps the same cut and uploads nothing.
        frame += 1;
        let again = m.update(&cam, 1.0, 128, frame, RenderMode::Dvr, &tf);
        assert_eq!(again.cut, plan.cut);
        assert!(again.uploads.is_empty());
    }

    #[test]
    fn tf_and_isovalue_changes_reclassify_without_reads() {
        let src = Arc::new(TestSource::new(64));
        let mut m = manager(&src, config());
        let cam = Camera::orbit(Vec3::ZERO, 1.6, 0.4, 0.3);
        let mut frame = 0;
        let wide = TransferFunction::ramp(0.0, 0.3, 0.5);
        let a = converge(&mut m, &mut frame, &cam, RenderMode::Dvr, &wide, |_, _| {});
        let reads = src.reads().len();
        let metas = src.meta_reads.load(Ordering::Relaxed);
        // A TF that hides the outer shell only coarsens or hides nodes already known.
        let narrow = TransferFunction::ramp(0.8, 1.0, 0.5);
        frame += 1;
        let b = m.update(&cam, 1.0, 128, frame, RenderMode::Dvr, &narrow);
        check_plan(&m, &b);
        let invisible = |p: &FramePlan| {
            p.cut
                .iter()
                .filter(|l| l.kind == LeafKind::Empty(EmptyReason::Invisible))
                .count()
        };
        assert!(invisible(&b) > invisible(&a));
        assert!(b.stats.working_set_bricks < a.stats.working_set_bricks);
        assert!(b.uploads.is_empty());
        assert_eq!(b.stats.requested_this_frame, 0);
        assert_eq!(src.reads().len(), reads);
        assert_eq!(
            src.meta_reads.load(Ordering::Relaxed),
            metas,
            "metadata is cached"
        );
        // Isovalue changes likewise.
        frame += 1;
        let iso = m.update(
            &cam,
            1.0,
            128,
            frame,
            RenderMode::Iso {
                value: 0.95,
                color: [1.0; 3],
            },
            &wide,
        );
        check_plan(&m, &iso);
        assert!(invisible(&iso) > 0);
        assert_eq!(src.reads().len(), reads);
        // Back to the first TF: the same cut, all still resident.
        frame += 1;
        let back = m.update(&cam, 1.0, 128, frame, RenderMode::Dvr, &wide);
        assert_eq!(back.cut, a.cut);
        assert!(back.uploads.is_empty());
    }

    #[test]
    fn planning_the_same_frame_twice_does_not_panic() {
        let src = Arc::new(TestSource::new(64));
        let brick = src.layout.brick_bytes() as u64;
        let mut m = manager(
            &src,
            ManagerConfig {
                gpu_budget_bytes: 12 * brick,
                ..config()
            },
        );
        let tf = TransferFunction::ramp(0.1, 1.0, 0.5);
        let a = Camera::orbit(Vec3::ZERO, 1.6, 0.4, 0.3);
        let mut frame = 0;
        converge(&mut m, &mut frame, &a, RenderMode::Mip, &tf, |_, _| {});
        // Same frame number, other view: pins of both plans add up.
        let b = Camera::orbit(Vec3::ZERO, 1.6, 2.5, -0.3);
        for _ in 0..50 {
            let plan = m.update(&b, 1.0, 128, frame, RenderMode::Mip, &tf);
            let keys: Vec<NodeKey> = plan.leaves().map(|l| l.0).collect();
            assert_exact_cover(&keys, m.layout().levels);
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    #[test]
    fn failed_loads_are_reported_and_the_cut_stays_complete() {
        let mut src = TestSource::new(64);
        let bad = NodeKey::new(1, 1, 1, 1);
        src.failing.insert(bad);
        let src = Arc::new(src);
        let mut m = manager(&src, config());
        let cam = Camera::orbit(Vec3::ZERO, 1.6, 0.4, 0.3);
        let tf = TransferFunction::ramp(0.1, 1.0, 0.5);
        let mut frame = 0;
        let plan = converge(&mut m, &mut frame, &cam, RenderMode::Mip, &tf, |_, _| {});
        assert_eq!(m.residency(bad), Some(Residency::Failed));
        assert!(matches!(
            m.failure(bad).as_deref(),
            Some(LoadError::Source(BrickError::Io { .. }))
        ));
        assert_eq!(plan.stats.residency.failed, 1);
        assert!(plan.stats.blocked.failed > 0);
        // The root cannot split without its child: it stays the only leaf.
        assert_eq!(plan.cut.len(), 1);
        assert!(matches!(plan.cut[0].kind, LeafKind::Data { .. }));
    }

    #[test]
    fn tiny_pool_gives_a_coarser_complete_cut() {
        let src = Arc::new(TestSource::new(64));
        let brick = src.layout.brick_bytes() as u64;
        let mut m = manager(
            &src,
            ManagerConfig {
                gpu_budget_bytes: 9 * brick,
                ..config()
            },
        );
        assert_eq!(m.pool().slot_count(), 9);
        let cam = Camera::orbit(Vec3::ZERO, 1.6, 0.4, 0.3);
        let tf = TransferFunction::ramp(0.1, 1.0, 0.5);
        let mut frame = 0;
        let plan = converge(&mut m, &mut frame, &cam, RenderMode::Mip, &tf, |_, p| {
            assert!(p.stats.working_set_bricks <= 9);
        });
        assert!(plan.stats.working_set_bricks >= 1);
        assert!(plan.stats.blocked.pool_full > 0);
        assert!(plan.stats.pool_occupied <= 9);
    }

    #[test]
    fn upload_budget_makes_progress_every_frame() {
        let src = Arc::new(TestSource::new(64));
        let brick = src.layout.brick_bytes() as u64;
        let mut m = manager(
            &src,
            ManagerConfig {
                upload_budget_bytes: brick,
                ..config()
            },
        );
        let cam = Camera::orbit(Vec3::ZERO, 1.6, 0.4, 0.3);
        let tf = TransferFunction::ramp(0.1, 1.0, 0.5);
        let mut frame = 0;
        let mut uploaded = 0;
        let plan = converge(&mut m, &mut frame, &cam, RenderMode::Mip, &tf, |_, p| {
            // One brick fits the budget; a split (up to 8 bricks) may exceed it once.
            assert!(p.uploads.len() <= 8);
            assert!(p.stats.upload_bytes <= 8 * brick);
            uploaded += p.uploads.len();
        });
        assert!(uploaded as u32 >= plan.stats.working_set_bricks);
        assert!(plan.stats.working_set_bricks > 8);
    }

    #[test]
    fn moving_camera_with_small_pool_never_reuses_a_slot_within_a_frame() {
        let mut src = TestSource::new(64);
        src.delay = Duration::from_millis(1);
        let src = Arc::new(src);
        let brick = src.layout.brick_bytes() as u64;
        let mut m = manager(
            &src,
            ManagerConfig {
                gpu_budget_bytes: 40 * brick,
                cpu_budget_bytes: 60 * brick as usize,
                ..config()
            },
        );
        let tf = TransferFunction::ramp(0.1, 1.0, 0.5);
        let t = Instant::now();
        let mut frame = 0u64;
        while frame < 150 || (m.pool().evictions() == 0 && t.elapsed() < Duration::from_secs(10)) {
            frame += 1;
            let yaw = frame as f32 * 0.07;
            let cam = Camera::orbit(
                Vec3::new(0.2 * yaw.sin(), 0.0, 0.0),
                0.9 + 0.5 * (yaw * 0.5).cos(),
                yaw,
                0.3,
            );
            let plan = m.update(&cam, 1.3, 128, frame, RenderMode::Dvr, &tf);
            check_plan(&m, &plan);
            assert!(plan.stats.pool_occupied <= 40);
            assert!(m.cpu_cache().bytes() <= 60 * brick as usize);
            std::thread::sleep(Duration::from_millis(1));
        }
        assert!(m.pool().evictions() > 0);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(12))]
        /// Random camera paths, pool sizes and modes: every plan tiles the cube,
        /// uses each slot once, pins its slots and stays within the pool.
        #[test]
        fn plans_stay_valid_along_random_paths(
            path in prop::collection::vec((0.0f32..6.3, -1.4f32..1.4, 0.4f32..4.0), 2..6),
            slots in 1u64..60,
            iso in prop::option::of(0.0f32..1.0),
        ) {
            let src = Arc::new(TestSource::new(64));
            let brick = src.layout.brick_bytes() as u64;
            let mut m = manager(&src, ManagerConfig { gpu_budget_bytes: slots * brick, upload_budget_bytes: 4 * brick, ..config() });
            let tf = TransferFunction::ramp(0.2, 1.0, 0.5);
            let mode = iso.map_or(RenderMode::Dvr, |value| RenderMode::Iso { value, color: [1.0; 3] });
            let mut frame = 0u64;
            for (yaw, pitch, dist) in path {
                let cam = Camera::orbit(Vec3::ZERO, dist, yaw, pitch);
                for _ in 0..6 {
                    frame += 1;
                    let plan = m.update(&cam, 1.5, 96, frame, mode, &tf);
                    check_plan(&m, &plan);
                    prop_assert!(plan.stats.working_set_bricks as u64 <= slots);
                    prop_assert_eq!(plan.stats.allocation_failures, 0);
                    std::thread::sleep(Duration::from_micros(300));
                }
            }
        }
    }
}
