//! The manager's queries, failure handling, set-up read and runtime setters.

use super::{BrickManager, Residency, ResidencyCounts};

/// What [`BrickManager::configure`] rebuilt.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Reconfigured {
    /// The pool bookkeeping (a GPU budget or floor change): every slot is
    /// forgotten and the renderer must recreate its atlas and slot tables
    /// (sized by [`BrickManager::pool`]) before the next update, which
    /// uploads the working set again.
    pub pool: bool,
    /// The loader (a thread-count change).
    pub loader: bool,
}
use crate::config::{ConfigError, GpuFormat, MIN_RESIDENT_BRICKS, OutOfCoreConfig};
use crate::cpu_cache::CpuCache;
use crate::failures::{FetchKind, StreamError};
use crate::loader::worker::{children_in_volume, fetch_brick, fetch_meta, fetch_metas};
use crate::loader::{LoadError, Loader, LoaderConfig};
use crate::pool::BrickPool;
use crate::prepared::{PreparedBrick, Preparer};
use crate::upload::UploadBudget;
use brickray_core::{BrickSource, NodeInfo, NodeKey, NodeKind, OctreeLayout};
use crossbeam_channel::{RecvTimeoutError, Sender};
use std::sync::Arc;
use std::time::Instant;

/// What set-up reads from the source ([`BrickManager::preload_root`]), on a
/// thread of its own.
#[derive(Clone)]
struct SetupReads {
    source: Arc<dyn BrickSource>,
    preparer: Arc<Preparer>,
    /// The root's metadata, when known.
    root: Option<NodeInfo>,
    /// The root's brick is in a cache.
    has_brick: bool,
    /// The root's children in the volume whose metadata is not known.
    children: Vec<NodeKey>,
}

/// One step of the set-up reads, sent as it happens.
enum SetupRead {
    /// A read begins (what a deadline that passes names).
    Start(FetchKind, NodeKey),
    Meta(NodeKey, Box<Result<NodeInfo, LoadError>>),
    Brick(Result<PreparedBrick, LoadError>),
}

impl SetupReads {
    /// Reads the root's metadata, its brick, then its children's metadata
    /// (in one [`BrickSource::nodes`](brickray_core::BrickSource::nodes) call),
    /// sending each result as it comes; stops at a failure of the root, or
    /// when set-up no longer listens (its deadline passed).
    fn run(&self, tx: &Sender<SetupRead>) {
        let key = NodeKey::ROOT;
        let source = self.source.as_ref();
        let info = match self.root.clone() {
            Some(info) => info,
            None => {
                if tx.send(SetupRead::Start(FetchKind::Metadata, key)).is_err() {
                    return;
                }
                let r = fetch_meta(source, key);
                let info = r.as_ref().ok().cloned();
                match (tx.send(SetupRead::Meta(key, Box::new(r))), info) {
                    (Ok(()), Some(info)) => info,
                    _ => return,
                }
            }
        };
        if matches!(info.kind, NodeKind::Empty) {
            return;
        }
        if !self.has_brick {
            if tx.send(SetupRead::Start(FetchKind::Brick, key)).is_err() {
                return;
            }
            let r = fetch_brick(source, &self.preparer, key, &info);
            let ok = r.is_ok();
            if tx.send(SetupRead::Brick(r)).is_err() || !ok {
                return;
            }
        }
        if matches!(info.kind, NodeKind::Uniform(_)) {
            return;
        }
        // The children in one call (a source over the network reads them
        // together).
        let Some(&first) = self.children.first() else {
            return;
        };
        if tx
            .send(SetupRead::Start(FetchKind::Metadata, first))
            .is_err()
        {
            return;
        }
        for (c, r) in fetch_metas(source, &self.children) {
            if tx.send(SetupRead::Meta(c, Box::new(r))).is_err() {
                return;
            }
        }
    }
}

impl BrickManager {
    /// The residency of a node's brick, `None` when it is nowhere.
    pub fn residency(&self, key: NodeKey) -> Option<Residency> {
        if self.pool.contains(key) {
            Some(Residency::OnGpu)
        } else if self.cpu.contains(key) {
            Some(Residency::InCpu)
        } else if self.failures.is_failed(FetchKind::Brick, key) {
            Some(Residency::Failed)
        } else if self.loader.is_loading(FetchKind::Brick, key) {
            Some(Residency::Loading)
        } else if self.loader.is_queued(FetchKind::Brick, key) {
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
            requested: self.loader.queued(FetchKind::Brick) as u32,
            loading: self.loader.loading(FetchKind::Brick) as u32,
            in_cpu: self.cpu.len() as u32 - in_cpu,
            on_gpu,
            failed: self.failures.counts().bricks_failed,
        }
    }

    /// The node's metadata, if known.
    pub fn metadata(&self, key: NodeKey) -> Option<NodeInfo> {
        self.meta.get(key).map(|i| (*i).clone())
    }

    /// The error that made a node fail (its brick, else its metadata), while it
    /// is failed (not yet due for a retry).
    pub fn failure(&self, key: NodeKey) -> Option<Arc<LoadError>> {
        self.failures
            .error(FetchKind::Brick, key)
            .or_else(|| self.failures.error(FetchKind::Metadata, key))
            .cloned()
    }

    /// The first failure since the last call (naming the node and what failed),
    /// with the number of failures after it: one message to show, not thousands.
    pub fn take_error(&mut self) -> Option<StreamError> {
        self.failures.take_error()
    }

    /// Makes every failed node wanted again at once (restarting its back-off).
    pub fn retry_failed(&mut self) {
        self.failures.retry_all();
    }

    /// Makes one node's failures (metadata and brick) wanted again at once;
    /// returns whether it had any.
    pub fn retry(&mut self, key: NodeKey) -> bool {
        self.failures.retry(key)
    }

    /// Forgets every GPU slot (e.g. after the atlas was recreated); the next update
    /// uploads the working set again.
    pub fn clear_gpu(&mut self) {
        self.pool.clear();
        self.fader.clear();
    }

    /// Reads the root's metadata and brick (and its children's metadata)
    /// synchronously, so the very first frame already shows a coarse image and
    /// can request the next level. Meant for set-up time, not the frame path: it
    /// blocks on the source, for at most [`OutOfCoreConfig::setup_deadline`]: the
    /// reads run on a thread of their own, and when the root's metadata or
    /// brick has not come back by the deadline, set-up fails with
    /// [`LoadError::TimedOut`] (what the thread reads later is dropped).
    /// Children whose metadata has not come back by then are left to the
    /// loader. A failure (or panic) of the root is returned and kept like any
    /// failure (retried after the back-off); a child's failure is kept and
    /// surfaced by [`take_error`](Self::take_error).
    pub fn preload_root(&mut self) -> Result<(), StreamError> {
        let key = NodeKey::ROOT;
        let deadline = self.config.setup_deadline;
        let started = Instant::now();
        let now = self.clock.now();
        let reads = SetupReads {
            source: self.source.clone(),
            preparer: self.preparer.clone(),
            root: self.meta.get(key).map(|i| (*i).clone()),
            has_brick: self.cpu.contains(key) || self.pool.contains(key),
            children: children_in_volume(&self.layout, key)
                .into_iter()
                .filter(|c| !self.meta.contains(*c))
                .collect(),
        };
        let (tx, rx) = crossbeam_channel::unbounded();
        let inline = reads.clone();
        let thread_tx = tx.clone();
        let spawned = std::thread::Builder::new()
            .name("brickray-setup".into())
            .spawn(move || reads.run(&thread_tx));
        if spawned.is_err() {
            // No thread to be had: read here, without a deadline.
            inline.run(&tx);
        }
        drop(tx);
        let mut reading = (FetchKind::Metadata, key);
        loop {
            let left = deadline.saturating_sub(started.elapsed());
            let read = match rx.recv_timeout(left) {
                Ok(read) => read,
                Err(RecvTimeoutError::Disconnected) => return Ok(()),
                // The root and its brick are in; the children's metadata
                // still missing is the loader's to read.
                Err(RecvTimeoutError::Timeout) if reading.1 != key => return Ok(()),
                Err(RecvTimeoutError::Timeout) => {
                    let (kind, key) = reading;
                    let e = LoadError::TimedOut {
                        key,
                        kind,
                        deadline,
                    };
                    return Err(self.failures.record(kind, key, e, now, false));
                }
            };
            match read {
                SetupRead::Start(kind, k) => reading = (kind, k),
                SetupRead::Meta(k, r) => match *r {
                    Ok(info) => {
                        self.meta.insert(k, info);
                        self.failures.succeeded(FetchKind::Metadata, k);
                    }
                    Err(e) => {
                        let err = self
                            .failures
                            .record(FetchKind::Metadata, k, e, now, k != key);
                        if k == key {
                            return Err(err);
                        }
                    }
                },
                SetupRead::Brick(Ok(brick)) => {
                    self.cpu.insert(key, brick);
                    self.failures.succeeded(FetchKind::Brick, key);
                }
                SetupRead::Brick(Err(e)) => {
                    return Err(self.failures.record(FetchKind::Brick, key, e, now, false));
                }
            }
        }
    }

    /// Applies a configuration: the whole of it is validated first
    /// ([`OutOfCoreConfig::validate`]; on error nothing changes), then only what
    /// differs from the current one is rebuilt. A tolerance, metric, brick
    /// budget, fade, retry, upload budget or visibility change takes effect at
    /// the next update and rebuilds nothing; a CPU budget change resizes the
    /// CPU cache (evicting the least recently used); a loader-thread change
    /// restarts the loader (loads in flight are asked for again); a GPU
    /// budget or floor change rebuilds the pool bookkeeping (every slot
    /// forgotten; the renderer recreates its atlas, [`Reconfigured::pool`]).
    pub fn configure(&mut self, config: OutOfCoreConfig) -> Result<Reconfigured, ConfigError> {
        config.validate(&self.layout, &self.gpu)?;
        let old = self.config;
        let mut out = Reconfigured::default();
        // Refinement's knobs change (and a new pool counts its changes
        // from 0): no earlier refinement is reused or evolved.
        self.refine_memo = None;
        self.last_cut = None;
        if config.gpu_budget_bytes != old.gpu_budget_bytes || config.floor_slots != old.floor_slots
        {
            let limits = self
                .gpu
                .pool_limits(&self.layout, config.gpu_budget_bytes)?;
            let pool = BrickPool::new(limits).map_err(|_| ConfigError::GpuBudgetTooSmall {
                budget_bytes: config.gpu_budget_bytes,
                slot_bytes: limits.slot_bytes,
                stored_side: limits.stored_side,
                max_texture_dim_3d: limits.max_dim,
                slots: 0,
                needed: MIN_RESIDENT_BRICKS,
            })?;
            self.pool = pool;
            out.pool = true;
        }
        if config.loader_threads != old.loader_threads {
            self.loader = Loader::new(
                self.source.clone(),
                self.preparer.clone(),
                LoaderConfig {
                    workers: config.loader_threads,
                    max_in_flight: super::bricks_in_flight(&config, &self.layout),
                },
            )
            .map_err(|e| ConfigError::LoaderStart {
                reason: e.to_string(),
            })?;
            out.loader = true;
        }
        if config.max_bytes_in_flight != old.max_bytes_in_flight {
            self.loader
                .set_max_in_flight(super::bricks_in_flight(&config, &self.layout));
        }
        if config.upload_budget_bytes != old.upload_budget_bytes {
            self.budget = UploadBudget::new(config.upload_budget_bytes);
        }
        if config.cpu_budget_bytes != old.cpu_budget_bytes {
            self.cpu.set_budget(config.cpu_budget_bytes);
            self.meta
                .set_capacity(super::meta_capacity(config.cpu_budget_bytes));
        }
        if config.retry != old.retry {
            self.failures.set_policy(config.retry);
        }
        self.config = config;
        if out.pool {
            self.reset_floor();
        }
        Ok(out)
    }

    /// The octree layout.
    pub fn layout(&self) -> &OctreeLayout {
        &self.layout
    }

    /// The configuration (as changed by the setters).
    pub fn config(&self) -> &OutOfCoreConfig {
        &self.config
    }

    /// What the device stores per slot.
    pub fn gpu_format(&self) -> &GpuFormat {
        &self.gpu
    }

    /// The pool bookkeeping (slot grid, atlas size, slot offsets).
    pub fn pool(&self) -> &BrickPool {
        &self.pool
    }

    /// Borrowed slots a plan may use past the pool's: slot ids
    /// `pool().slot_count()..` name the octants of an octant-granular cut
    /// drawn from their parent's brick ([`FadeSlot::borrowed`](super::FadeSlot::borrowed)),
    /// rows of the renderer's slot table with no atlas space. Eight per slot
    /// under [`LodMetric::VisibleOctants`](brickray_core::LodMetric::VisibleOctants)
    /// (a parent lends its brick to at most its eight children, and at most
    /// every slot lends), none under the other metrics.
    pub fn borrowed_slots(&self) -> u32 {
        if matches!(
            self.config.lod_metric,
            brickray_core::LodMetric::VisibleOctants { .. }
        ) {
            self.pool.slot_count().saturating_mul(8)
        } else {
            0
        }
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
