//! One frame of the manager, as a sequence of named phases over small
//! structs: [`poll`](BrickManager::poll) what the loader finished,
//! [`refine`](BrickManager::refine_cut) the cut, choose what is
//! [`displayed`](BrickManager::display) (fades), make it
//! [`resident`](BrickManager::place) (pin, allocate, lend octants, floor),
//! turn the fades into [`slots`](BrickManager::fade_slots),
//! [`request`](BrickManager::request) what is missing, and count the
//! [`stats`](BrickManager::frame_stats).

use super::{BrickManager, Env, FadeSlot, FramePlan, FrameStats, PhaseTimes, Upload};
use crate::cpu_cache::CpuCache;
use crate::fade::Displayed;
use crate::failures::FetchKind;
use crate::loader::BrickRequest;
use crate::pool::{BrickPool, PoolError};
use crate::refine::{NodeClass, RefineParams, Refinement, SplitFilter, Views, refine};
use crate::upload::UploadBudget;
use brickray_core::{
    CutLeaf, EmptyReason, LeafKind, LodMetric, NodeKey, NodeMap, NodeSet, RenderMode,
    TransferFunction,
};
use std::time::Instant;

/// Frames per second assumed for fades in milliseconds when a frame gives no
/// time ([`FrameInput::time`]).
pub const UNTIMED_FRAME_RATE: f64 = 60.0;

/// What one frame of planning takes.
#[derive(Debug, Clone, Copy)]
pub struct FrameInput<'a> {
    /// The geometry of the frame's views.
    pub views: &'a Views,
    /// Changes whenever the views or the classification change
    /// ([`RefineParams::generation`]).
    pub generation: u64,
    /// The frame number: must not decrease from call to call; bricks the
    /// returned cut uses are pinned in the pool for that frame.
    pub frame: u64,
    /// Render mode (decides emptiness).
    pub mode: RenderMode,
    /// Transfer function (decides DVR transparency).
    pub tf: &'a TransferFunction,
    /// Channel styles of a multi-channel volume (empty for one channel).
    pub channels: &'a [brickray_core::ChannelStyle],
    /// The host's time of this frame in seconds (any origin, non-decreasing):
    /// fades in milliseconds advance by the difference to the last frame's.
    /// `None`: by `1 / UNTIMED_FRAME_RATE` seconds (no clock is read).
    pub time: Option<f64>,
}

/// Milliseconds between successive calls (the phases' times).
struct Lap(Instant);

impl Lap {
    fn start() -> Lap {
        Lap(Instant::now())
    }

    /// Milliseconds since the last call (or the start).
    fn next(&mut self) -> f64 {
        let now = Instant::now();
        let ms = (now - self.0).as_secs_f64() * 1e3;
        self.0 = now;
        ms
    }
}

/// The cut placed in the pool: every leaf with its slot where it has one.
struct Placed {
    cut: Vec<CutLeaf>,
    uploads: Vec<Upload>,
    /// Fades of octants drawn from their parent's brick.
    borrowed: Vec<FadeSlot>,
    /// Working-set bricks already on the GPU.
    resident: u32,
    /// Parents that lend their brick and have it on the GPU.
    lenders_drawn: u32,
    allocation_failures: u32,
    /// The floor's loads (bricks, then metadata), asked for after
    /// refinement's.
    floor_requests: (Vec<BrickRequest>, Vec<(NodeKey, f32)>),
}

/// What [`BrickManager::refine_cut`] says of its refinement: the key it was
/// made under (`None`: not reusable), whether it was reused or evolved from
/// the last cut (then never reused; `provisional`: the greedy order may
/// give another cut), and the upload budget as it left it.
struct Memo {
    key: Option<super::MemoKey>,
    reused: bool,
    evolved: bool,
    provisional: bool,
    budget: UploadBudget,
}

/// What the frame asked of the loader.
struct Requested {
    bricks: u32,
    metadata: u32,
}

impl BrickManager {
    /// Plans one frame: polls the loader, refines the cut over the frame's
    /// views (splitting only nodes `filter` allows: nodes hidden in the
    /// previous frames stay leaves at their level and request nothing),
    /// assigns pool slots, schedules uploads within the budget and re-submits
    /// the wanted loads. Never blocks on I/O and never calls the source.
    pub fn update(
        &mut self,
        input: &FrameInput<'_>,
        filter: Option<&mut dyn SplitFilter>,
    ) -> FramePlan {
        let now = self.clock.now();
        let mut lap = Lap::start();
        let mut phases = PhaseTimes::default();
        self.poll(input.frame, now);
        phases.poll_ms = lap.next();
        let (refined, memo) = self.refine_cut(input, filter);
        phases.refine_ms = lap.next();
        let shown = self.display(&refined, input.time);
        phases.display_ms = lap.next();
        let mut placed = self.place(&shown, input.frame);
        let mut fades = self.fade_slots(&shown);
        phases.place_ms = lap.next();
        let requested = self.request(&refined, &mut placed);
        phases.request_ms = lap.next();
        fades.append(&mut placed.borrowed);
        let mut stats = self.frame_stats(input.frame, &refined, &placed, &fades, &requested);
        phases.stats_ms = lap.next();
        stats.phases = phases;
        stats.refine_reused = memo.reused;
        stats.refine_evolved = memo.evolved;
        stats.cut_provisional = memo.provisional;
        let plan = FramePlan {
            cut: placed.cut,
            uploads: placed.uploads,
            fades,
            refined: refined
                .leaves
                .iter()
                .filter(|l| matches!(l.class, NodeClass::Data | NodeClass::Borrowed))
                .map(|l| l.key)
                .collect(),
            stats,
        };
        // A converged frame's refinement serves the next frames for as long
        // as nothing it read changes (what changes them is in the key).
        self.refine_memo = match memo.key {
            Some(key) if plan.stats.converged() && !memo.evolved => Some(super::RefineMemo {
                key,
                refined,
                budget: memo.budget,
            }),
            _ => None,
        };
        plan
    }

    /// Phase 1: what the loader finished (metadata, bricks, failures) goes
    /// into the caches; failures due for a retry wake.
    fn poll(&mut self, frame: u64, now: Instant) {
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
    }

    /// Phase 2: refinement over the caches (never the source), or the last
    /// converged frame's refinement where nothing it read has changed
    /// ([`super::MemoKey`]; in debug builds the refinement is made again and
    /// compared).
    fn refine_cut(
        &mut self,
        input: &FrameInput<'_>,
        mut filter: Option<&mut dyn SplitFilter>,
    ) -> (Refinement, Memo) {
        let max_data_leaves = self.cut_slots();
        let max_requests = crate::refine::requests_per_frame(
            self.pool.slot_count(),
            self.config.upload_budget_bytes,
            self.brick_bytes,
        );
        // A full cut prefetches at most a frame's requests, and no more than
        // the CPU cache holds beside the cut: a prefetch that outgrew it
        // would be evicted and requested again, frame after frame.
        let cpu_room = (self.cpu.budget() / self.brick_bytes.max(1))
            .saturating_sub(max_data_leaves as u64)
            .min(u32::MAX as u64) as u32;
        let params = RefineParams {
            views: input.views,
            generation: input.generation,
            mode: input.mode,
            tf: input.tf,
            channels: input.channels,
            tolerance_px: self.config.tolerance_px,
            metric: self.config.lod_metric,
            max_data_leaves,
            max_requests,
            max_prefetch: max_requests.min(max_data_leaves).min(cpu_room),
            brick_upload_bytes: self.brick_bytes,
            lookahead: self.config.lookahead.applies(self.remote),
        };
        self.octants.begin(&params);
        let same = self.classified.as_ref().is_some_and(|c| {
            c.mode == input.mode && c.tf == *input.tf && c.channels == input.channels
        });
        if !same {
            // (Stamp 0 means "none": after 2^32 - 1 changes it wraps to 1.)
            self.class_stamp = self.class_stamp.checked_add(1).unwrap_or(1);
            self.classified = Some(super::Classification {
                mode: input.mode,
                tf: input.tf.clone(),
                channels: input.channels.to_vec(),
            });
        }
        // Reusable only where refinement reads nothing but the key: an inert
        // filter, no visible weights, no failures (whose retries come due
        // with time).
        let inert = filter.as_ref().is_none_or(|f| f.is_inert());
        let key =
            (inert && !self.config.lod_metric.uses_visible_weights() && self.failures.is_empty())
                .then(|| super::MemoKey {
                    generation: input.generation,
                    class_stamp: self.class_stamp,
                    meta: self.meta.changes(),
                    cpu: self.cpu.changes(),
                    pool: self.pool.changes(),
                });
        let reused = match (&self.refine_memo, key) {
            (Some(m), Some(k)) if m.key == k => Some((m.refined.clone(), m.budget)),
            _ => None,
        };
        let memo = |reused: bool, evolved: Option<bool>, budget: UploadBudget| Memo {
            key,
            reused,
            evolved: evolved.is_some(),
            provisional: evolved == Some(true),
            budget,
        };
        let mut budget = self.budget;
        if let Some((refined, kept)) = reused {
            #[cfg(debug_assertions)]
            {
                let again = self.refine_with(&params, filter, &mut budget);
                assert_eq!(again, refined, "a reused refinement differs from a new one");
                assert_eq!(budget, kept, "a reused refinement's upload budget differs");
            }
            self.budget = kept;
            self.octants.end(&refined, &self.layout);
            self.note_cut(input.generation, &refined, false, inert);
            return (refined, memo(true, None, kept));
        }
        // (A reborrow: the filter serves the refinement from the root if
        // evolving does not apply.)
        let reborrowed = filter.as_mut().map(|f| &mut **f as &mut dyn SplitFilter);
        if let Some((refined, provisional)) = self.evolved(&params, reborrowed, inert, &mut budget)
        {
            self.budget = budget;
            self.octants.end(&refined, &self.layout);
            self.note_cut(input.generation, &refined, true, inert);
            return (refined, memo(false, Some(provisional), budget));
        }
        let mut budget = self.budget;
        let refined = self.refine_with(&params, filter, &mut budget);
        self.budget = budget;
        self.octants.end(&refined, &self.layout);
        self.note_cut(input.generation, &refined, false, inert);
        (refined, memo(false, None, budget))
    }

    /// The last frame's cut evolved to a moving view
    /// ([`OutOfCoreConfig::evolve`](crate::OutOfCoreConfig::evolve)), where
    /// that applies: the view changed since the last frame and the
    /// classification did not, no failures, and fewer than
    /// [`EVOLVED_FRAMES_MAX`](super::EVOLVED_FRAMES_MAX) frames evolved in a
    /// row. `None`: refine from the root.
    fn evolved(
        &mut self,
        params: &RefineParams<'_>,
        filter: Option<&mut dyn SplitFilter>,
        inert: bool,
        budget: &mut UploadBudget,
    ) -> Option<(Refinement, bool)> {
        let last = self.last_cut.as_ref()?;
        let applies = self.config.evolve
            && self.failures.is_empty()
            && last.generation != params.generation
            && last.class_stamp == self.class_stamp
            && last.evolved < super::EVOLVED_FRAMES_MAX;
        if !applies {
            return None;
        }
        // The leaves within the tolerance are visited again (as the greedy
        // order visits every leaf) where what kept one a leaf may have
        // changed: a split waited, metadata arrived, or the feedback hid
        // nodes in that frame or hides some in this one.
        let recheck = last.waiting || last.meta != self.meta.changes() || !(inert && last.inert);
        let leaves = std::mem::take(&mut self.last_cut.as_mut()?.leaves);
        self.with_env(filter, |layout, env| {
            crate::refine::evolve(layout, params, env, budget, &leaves, recheck)
        })
    }

    /// Keeps `refined` as the cut the next frame may evolve (nothing where
    /// no frame can: a copy of the cut a frame is not paid for nothing).
    fn note_cut(&mut self, generation: u64, refined: &Refinement, evolved: bool, inert: bool) {
        if !self.config.evolve || !matches!(self.config.lod_metric, LodMetric::Geometric) {
            self.last_cut = None;
            return;
        }
        let evolved = match (evolved, &self.last_cut) {
            (true, Some(l)) => l.evolved + 1,
            _ => 0,
        };
        let mut leaves = self.last_cut.take().map(|l| l.leaves).unwrap_or_default();
        leaves.clear();
        leaves.extend_from_slice(&refined.leaves);
        self.last_cut = Some(super::LastCut {
            generation,
            class_stamp: self.class_stamp,
            meta: self.meta.changes(),
            leaves,
            waiting: refined.blocked.missing_data
                + refined.blocked.missing_meta
                + refined.blocked.upload_budget
                > 0,
            inert,
            evolved,
        });
    }

    /// Refines over the caches (never the source), charging `budget`.
    fn refine_with(
        &mut self,
        params: &RefineParams<'_>,
        filter: Option<&mut dyn SplitFilter>,
        budget: &mut UploadBudget,
    ) -> Refinement {
        self.with_env(filter, |layout, env| refine(layout, params, env, budget))
    }

    /// Runs `f` over refinement's view of the caches (never the source).
    fn with_env<R>(
        &mut self,
        filter: Option<&mut dyn SplitFilter>,
        f: impl FnOnce(&brickray_core::OctreeLayout, &mut dyn crate::refine::RefineEnv) -> R,
    ) -> R {
        let mut env = Env {
            meta: &self.meta,
            failures: &self.failures,
            cpu: &mut self.cpu,
            pool: &self.pool,
            filter,
            octants: &self.octants,
            class_stamp: self.class_stamp,
        };
        f(&self.layout, &mut env)
    }

    /// Phase 3: the displayed cut, the refined one with level changes fading
    /// (`crate::fade`). If its bricks, their fallbacks and the floor do not
    /// fit in the pool, the fades are dropped (the refined cut always fits).
    /// Octant-granular cuts and label maps are drawn as they are (no fades: a
    /// fade mixes the values of two levels, which would invent label ids).
    fn display(&mut self, refined: &Refinement, time: Option<f64>) -> Displayed {
        let octants = matches!(self.config.lod_metric, LodMetric::VisibleOctants { .. });
        let labels = self.layout.volume.kind.is_labels();
        let dt = self.fade_dt(time);
        let step = self
            .config
            .fade
            .filter(|_| !octants && !labels)
            .map(|d| d.step(dt));
        let shown = self.fader.advance(&refined.leaves, step);
        if shown.fades.is_empty() {
            return shown;
        }
        let mut need: NodeSet = shown
            .leaves
            .iter()
            .filter(|l| l.class == NodeClass::Data)
            .map(|l| l.key)
            .collect();
        need.extend(shown.fallbacks());
        need.extend(self.floor.iter().copied());
        if need.len() > self.pool.slot_count() as usize {
            return self.fader.advance(&refined.leaves, None);
        }
        shown
    }

    /// The time step of this frame for the fades, in seconds.
    fn fade_dt(&mut self, time: Option<f64>) -> f64 {
        let Some(t) = time else {
            self.last_fade_time = None;
            return 1.0 / UNTIMED_FRAME_RATE;
        };
        let dt = self.last_fade_time.map_or(0.0, |l| (t - l).max(0.0));
        self.last_fade_time = Some(t);
        if dt.is_finite() { dt } else { 0.0 }
    }

    /// Phase 4: the displayed cut placed in the pool. What is resident is
    /// pinned first, so that the allocations after it can only evict bricks
    /// this frame does not use; then the missing leaves and fallbacks get
    /// slots, parents lend their bricks to octants, and the floor is kept.
    fn place(&mut self, shown: &Displayed, frame: u64) -> Placed {
        let mut placed = Placed {
            cut: Vec::with_capacity(shown.leaves.len()),
            uploads: Vec::new(),
            borrowed: Vec::new(),
            resident: 0,
            lenders_drawn: 0,
            allocation_failures: 0,
            floor_requests: (Vec::new(), Vec::new()),
        };
        let mut pending = Vec::new();
        // Octants drawn from their parent's brick (index in `cut`), and the
        // parents lending their bricks, with their slots once known.
        let mut borrowed = Vec::new();
        let mut lenders: NodeMap<Option<u32>> = NodeMap::default();
        for l in &shown.leaves {
            let kind = match l.class {
                NodeClass::Empty(r) => LeafKind::Empty(r),
                NodeClass::Borrowed => {
                    if let Some(p) = self.layout.parent(l.key) {
                        lenders
                            .entry(p)
                            .or_insert_with(|| self.pool.touch(p, frame));
                    }
                    borrowed.push(placed.cut.len());
                    LeafKind::Empty(EmptyReason::NotLoaded)
                }
                NodeClass::Data => match self.pool.touch(l.key, frame) {
                    Some(slot) => {
                        placed.resident += 1;
                        LeafKind::Data { slot }
                    }
                    None => {
                        pending.push(placed.cut.len());
                        LeafKind::Empty(EmptyReason::NotLoaded)
                    }
                },
            };
            placed.cut.push(CutLeaf {
                key: l.key,
                kind,
                priority: l.priority,
            });
        }
        let pending_fallbacks: Vec<NodeKey> = shown
            .fallbacks()
            .into_iter()
            .filter(|&a| self.pool.touch(a, frame).is_none())
            .collect();
        for i in pending {
            let key = placed.cut[i].key;
            if let Some(slot) = self.assign(&mut placed, key, frame) {
                placed.cut[i].kind = LeafKind::Data { slot };
            }
        }
        for a in pending_fallbacks {
            // A merge's target is a refined leaf, so it is available; a split's
            // ancestor was drawn last frame, so it is resident.
            self.assign(&mut placed, a, frame);
        }
        self.lend(&mut placed, lenders, &borrowed, frame);
        let floor = self.floor_step(frame);
        placed.uploads.extend(floor.uploads);
        placed.floor_requests = (floor.requests, floor.meta_requests);
        placed
    }

    /// Gives `key` a slot and schedules the upload of its brick from CPU
    /// memory; `None` when it is not there or the pool has no unpinned slot.
    fn assign(&mut self, placed: &mut Placed, key: NodeKey, frame: u64) -> Option<u32> {
        allocate(&mut self.pool, &self.cpu, placed, key, frame)
    }

    /// Octants drawn from their parent's brick: each lending parent gets a
    /// slot (refinement gave a lender its brick only when it was on the GPU
    /// or in CPU memory, and charged its upload), and each octant a borrowed
    /// slot past the pool's that draws from it.
    fn lend(
        &mut self,
        placed: &mut Placed,
        lenders: NodeMap<Option<u32>>,
        borrowed: &[usize],
        frame: u64,
    ) {
        let mut lent: Vec<(NodeKey, Option<u32>)> = lenders.into_iter().collect();
        lent.sort_by_key(|l| l.0);
        for (p, slot) in &mut lent {
            if slot.is_none() {
                *slot = self.assign(placed, *p, frame);
            } else {
                placed.resident += 1;
            }
        }
        let lent: NodeMap<Option<u32>> = lent.into_iter().collect();
        let base = self.pool.slot_count();
        let rows = self.borrowed_slots();
        for (n, &i) in borrowed.iter().enumerate().take(rows as usize) {
            let key = placed.cut[i].key;
            let lender = self
                .layout
                .parent(key)
                .and_then(|p| lent.get(&p).copied().flatten().map(|s| (p, s)));
            if let Some((p, fallback)) = lender {
                let slot = base + n as u32;
                placed.cut[i].kind = LeafKind::Data { slot };
                placed.borrowed.push(FadeSlot {
                    slot,
                    fallback,
                    levels_up: (key.level - p.level) as u32,
                    weight: 1.0,
                    borrowed: true,
                });
            }
        }
        placed.lenders_drawn = lent.values().filter(|s| s.is_some()).count() as u32;
    }

    /// Phase 5: each fading leaf with its slot and its fallback's; a fade
    /// whose bricks are not both resident is cancelled.
    ///
    /// A fading leaf's slot in the cut is its pool slot (`place` gave the
    /// cut's data leaves theirs and pinned them; fades are never of octants
    /// drawn from a parent's brick), so the pool is asked for the fading
    /// leaves alone rather than the cut mapped whole.
    fn fade_slots(&mut self, shown: &Displayed) -> Vec<FadeSlot> {
        let mut fades = Vec::with_capacity(shown.fades.len());
        for f in &shown.fades {
            match (self.pool.slot_of(f.leaf), self.pool.slot_of(f.ancestor)) {
                (Some(slot), Some(fallback)) => fades.push(FadeSlot {
                    slot,
                    fallback,
                    levels_up: (f.leaf.level - f.ancestor.level) as u32,
                    weight: f.weight,
                    borrowed: false,
                }),
                _ => self.fader.cancel(f.leaf),
            }
        }
        fades
    }

    /// Phase 6: the loads wanted this frame (refinement's, then the floor's)
    /// go to the loader; queued ones no longer wanted are dropped. A brick
    /// job also reads its children's metadata unless all of it is known.
    fn request(&mut self, refined: &Refinement, placed: &mut Placed) -> Requested {
        let mut bricks: Vec<BrickRequest> = refined
            .requests
            .iter()
            .map(|r| BrickRequest {
                key: r.key,
                priority: r.priority,
                info: r.info.clone(),
                children_meta: self.children_meta_missing(r.key, &r.info),
            })
            .collect();
        let mut meta_requests = refined.meta_requests.clone();
        let (floor_bricks, floor_meta) = std::mem::take(&mut placed.floor_requests);
        let known: NodeSet = bricks.iter().map(|b| b.key).collect();
        bricks.extend(floor_bricks.into_iter().filter(|r| !known.contains(&r.key)));
        let known: NodeSet = meta_requests.iter().map(|m| m.0).collect();
        meta_requests.extend(floor_meta.into_iter().filter(|m| !known.contains(&m.0)));
        self.loader.submit(&meta_requests, &bricks);
        Requested {
            bricks: bricks.len() as u32,
            metadata: meta_requests.len() as u32,
        }
    }

    /// Phase 7: the frame's statistics.
    fn frame_stats(
        &mut self,
        frame: u64,
        refined: &Refinement,
        placed: &Placed,
        fades: &[FadeSlot],
        requested: &Requested,
    ) -> FrameStats {
        let base = self.pool.slot_count();
        let cut = &placed.cut;
        let holes = cut
            .iter()
            .filter(|l| {
                matches!(
                    l.kind,
                    LeafKind::Empty(EmptyReason::NotLoaded | EmptyReason::Failed)
                )
            })
            .count() as u32;
        // Bricks drawn: data leaves with their own slot, and lenders.
        let working = cut
            .iter()
            .filter(|l| l.slot().is_some_and(|s| s < base))
            .count() as u32
            + placed.lenders_drawn;
        let residency = self.residency_counts();
        self.meta.trim();
        FrameStats {
            frame,
            leaves: cut.len() as u32,
            working_set_bricks: working,
            pool_slots: self.pool.slot_count(),
            pool_slot_bytes: self.gpu.slot_bytes(&self.layout).unwrap_or(0),
            pool_occupied: self.pool.occupied(),
            upload_bricks: placed.uploads.len() as u32,
            upload_bytes: placed.uploads.iter().map(|u| u.brick.bytes()).sum(),
            gpu_hit_rate: if working == 0 {
                1.0
            } else {
                placed.resident as f64 / working as f64
            },
            cpu_hit_rate: self.cpu.hit_rate(),
            requests_in_flight: residency.requested + residency.loading,
            requested_this_frame: requested.bricks,
            cancelled: self.loader.cancelled().into(),
            metadata_in_flight: (self.loader.queued(FetchKind::Metadata)
                + self.loader.loading(FetchKind::Metadata)) as u32,
            metadata_requested_this_frame: requested.metadata,
            metadata_known: self.meta.len() as u32,
            metadata_evicted: self.meta.evicted(),
            residency,
            blocked: refined.blocked,
            allocation_failures: placed.allocation_failures,
            failed_needed: refined.failed_needed,
            failures: self.failures.counts(),
            // (Borrowed leaves are drawn as they are, not fading.)
            fading: fades.iter().filter(|f| !f.borrowed).count() as u32,
            holes,
            floor_pinned: self.floor_pinned(),
            // (Set by `update` once this phase is timed too.)
            phases: PhaseTimes::default(),
            refine_reused: false,
            refine_evolved: false,
            cut_provisional: false,
        }
    }
}

/// Gives `key` a slot of `pool` and schedules the upload of its prepared
/// brick from `cpu`; `None` when it is not in CPU memory or no slot is free.
fn allocate(
    pool: &mut BrickPool,
    cpu: &CpuCache,
    placed: &mut Placed,
    key: NodeKey,
    frame: u64,
) -> Option<u32> {
    let brick = cpu.peek(key).cloned()?;
    match pool.allocate(key, frame) {
        Ok(a) => {
            placed.uploads.push(Upload {
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
            placed.allocation_failures += 1;
            None
        }
    }
}
