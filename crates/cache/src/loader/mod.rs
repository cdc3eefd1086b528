//! Asynchronous loader: worker threads read node metadata and bricks from a
//! [`BrickSource`] (metadata first, then bricks, each in priority order) and
//! prepare each brick for the GPU; the render thread only submits requests and
//! polls completions, never waiting on I/O.
//!
//! A request is *queued* until a worker takes it, then *loading* until
//! [`Loader::poll`] collects the result: a prepared brick goes into the
//! [`CpuCache`], metadata and errors are returned in the [`PollReport`]. Queued
//! requests can be re-prioritised and cancelled; a read in progress always runs
//! to completion. A source over the network asks for batches
//! ([`BrickSource::batch_size`]): a thread then takes up to that many queued
//! bricks at once, the highest priorities first, and reads them in one
//! [`BrickSource::read_bricks`] call (about one round trip for all); a batch
//! none of whose bricks the view still wants is cancelled in flight (its
//! requests aborted, its bricks reported as cancelled, not failed). Every
//! call into the source is guarded by `catch_unwind`.

mod queue;
#[cfg(test)]
mod tests;
pub(crate) mod worker;

use crate::config::MAX_LOADER_THREADS;
use crate::cpu_cache::CpuCache;
use crate::failures::FetchKind;
use crate::prepared::Preparer;
use brickray_core::{BrickError, BrickSource, NodeInfo, NodeKey};
use crossbeam_channel::Receiver;
use queue::{Job, JobSet};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use thiserror::Error;
use worker::{Completion, Shared};

/// How long dropping a [`Loader`] waits for its threads to exit before it
/// detaches those still blocked in the source.
pub const SHUTDOWN_WAIT: Duration = Duration::from_millis(100);

/// Why a node's metadata or brick could not be read.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum LoadError {
    /// The source reported an error.
    #[error(transparent)]
    Source(#[from] BrickError),
    /// The source panicked.
    #[error("brick source panicked reading {key:?}: {message}")]
    Panicked {
        /// The node.
        key: NodeKey,
        /// The panic message, when it was a string.
        message: String,
    },
    /// The read was cancelled in flight: the view stopped wanting the brick
    /// (not a failure; nothing is retried or reported).
    #[error("the read of {key:?} was cancelled")]
    Cancelled {
        /// The node.
        key: NodeKey,
    },
    /// The source did not answer within the set-up deadline
    /// ([`OutOfCoreConfig::setup_deadline`](crate::OutOfCoreConfig::setup_deadline)).
    #[error(
        "the source did not answer for the {kind} of {key:?} within the set-up deadline of {deadline:?}"
    )]
    TimedOut {
        /// The node.
        key: NodeKey,
        /// What was being read.
        kind: FetchKind,
        /// The deadline that passed.
        deadline: Duration,
    },
}

/// Loader configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LoaderConfig {
    /// Worker threads (clamped to `1..=`[`MAX_LOADER_THREADS`]).
    pub workers: usize,
    /// Most bricks being read at once (taken by a thread, result not yet
    /// polled); at least 1 ([`Loader::set_max_in_flight`]).
    pub max_in_flight: usize,
}

impl Default for LoaderConfig {
    /// 2 threads, no bound on bricks in flight beyond threads x batch.
    fn default() -> Self {
        LoaderConfig {
            workers: 2,
            max_in_flight: usize::MAX,
        }
    }
}

/// A brick to load.
#[derive(Debug, Clone, PartialEq)]
pub struct BrickRequest {
    /// The node.
    pub key: NodeKey,
    /// Higher goes first.
    pub priority: f32,
    /// The node's metadata (its range goes into the prepared brick).
    pub info: Arc<NodeInfo>,
    /// Also read the metadata of the node's children (inside the volume) in the
    /// same job, right after the brick (delivered first), so that a later split
    /// of the node seldom waits for it; it counts as metadata in flight meanwhile.
    pub children_meta: bool,
}

/// What a request did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RequestOutcome {
    /// Newly queued.
    Queued,
    /// Was already queued; its priority is updated.
    Reprioritized,
    /// A worker is reading it (or its result awaits `poll`).
    Loading,
}

/// The outcome of one [`Loader::poll`].
#[derive(Debug, Default)]
pub struct PollReport {
    /// Bricks that arrived and went into the CPU cache.
    pub loaded: Vec<NodeKey>,
    /// Metadata that arrived (requested, or read along with a parent's brick).
    pub metadata: Vec<(NodeKey, NodeInfo)>,
    /// Reads that failed.
    pub failed: Vec<(FetchKind, NodeKey, LoadError)>,
    /// Bricks the CPU cache evicted to make room.
    pub evicted: Vec<NodeKey>,
    /// Bricks whose read was cancelled in flight (no longer wanted): neither
    /// loaded nor failed.
    pub cancelled: Vec<NodeKey>,
}

/// Worker threads reading metadata and bricks in priority order. Dropping it
/// drops every queued request and returns within about [`SHUTDOWN_WAIT`]: threads
/// still blocked in the source then are detached and exit when their call
/// returns, touching only state they share by `Arc`.
pub struct Loader {
    shared: Arc<Shared>,
    workers: Vec<JoinHandle<()>>,
    done: Receiver<Completion>,
    loaded_total: u64,
}

impl std::fmt::Debug for Loader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Loader")
            .field("workers", &self.workers.len())
            .field("queued_bricks", &self.queued(FetchKind::Brick))
            .field("loading_bricks", &self.loading(FetchKind::Brick))
            .field("queued_metadata", &self.queued(FetchKind::Metadata))
            .finish_non_exhaustive()
    }
}

impl Loader {
    /// Starts `config.workers` threads reading from `source` and preparing with
    /// `preparer`. Fails only when the OS refuses a thread.
    pub fn new(
        source: Arc<dyn BrickSource>,
        preparer: Arc<Preparer>,
        config: LoaderConfig,
    ) -> std::io::Result<Loader> {
        let shared = Arc::new(Shared::default());
        shared.queue.lock().max_in_flight = config.max_in_flight;
        let (tx, rx) = crossbeam_channel::unbounded();
        let mut loader = Loader {
            shared,
            workers: Vec::new(),
            done: rx,
            loaded_total: 0,
        };
        for i in 0..config.workers.clamp(1, MAX_LOADER_THREADS) {
            let shared = loader.shared.clone();
            let (source, prep, tx) = (source.clone(), preparer.clone(), tx.clone());
            *shared.live.lock() += 1;
            // On error `loader` drops here, which stops the threads started so far.
            let spawned = std::thread::Builder::new()
                .name(format!("brickray-loader-{i}"))
                .spawn({
                    let shared = shared.clone();
                    move || worker::worker(shared, source, prep, tx)
                });
            match spawned {
                Ok(handle) => loader.workers.push(handle),
                Err(e) => {
                    *shared.live.lock() -= 1;
                    return Err(e);
                }
            }
        }
        Ok(loader)
    }

    fn push(&self, job: Job, priority: f32) -> RequestOutcome {
        let mut q = self.shared.queue.lock();
        if q.is_loading(job.key()) {
            return RequestOutcome::Loading;
        }
        let was = q.push(job, priority);
        drop(q);
        self.shared.wake.notify_one();
        if was {
            RequestOutcome::Reprioritized
        } else {
            RequestOutcome::Queued
        }
    }

    /// Requests a node's metadata (metadata goes before any brick).
    pub fn request_metadata(&self, key: NodeKey, priority: f32) -> RequestOutcome {
        self.push(Job::Meta(key), priority)
    }

    /// Requests a brick. Re-requesting a queued brick updates its priority. Does
    /// not check the CPU cache: the caller asks only for what it lacks.
    pub fn request_brick(&self, request: BrickRequest) -> RequestOutcome {
        self.push(
            Job::Brick {
                key: request.key,
                info: request.info,
                children_meta: request.children_meta,
            },
            request.priority,
        )
    }

    /// Replaces the wanted set: queues or re-prioritises every listed request,
    /// cancels every queued one not listed, and aborts every batch in flight
    /// none of whose bricks is listed (a source that reads in batches,
    /// [`BrickSource::batch_size`]). Returns how many queued requests were
    /// cancelled.
    pub fn submit(&self, metadata: &[(NodeKey, f32)], bricks: &[BrickRequest]) -> usize {
        let jobs: Vec<(Job, f32)> = metadata
            .iter()
            .map(|&(k, p)| (Job::Meta(k), p))
            .chain(bricks.iter().map(|r| {
                let job = Job::Brick {
                    key: r.key,
                    info: r.info.clone(),
                    children_meta: r.children_meta,
                };
                (job, r.priority)
            }))
            .collect();
        let keep: JobSet = jobs.iter().map(|(j, _)| j.key()).collect();
        let mut q = self.shared.queue.lock();
        let stale = q.stale(&keep);
        for jk in &stale {
            q.cancel(*jk);
        }
        q.cancelled_queued += stale.len() as u64;
        q.cancel_unwanted_batches(&keep);
        let mut added = 0;
        for (job, p) in jobs {
            if !q.is_loading(job.key()) {
                q.push(job, p);
                added += 1;
            }
        }
        drop(q);
        for _ in 0..added.min(self.workers.len()) {
            self.shared.wake.notify_one();
        }
        stale.len()
    }

    /// Sets the most bricks being read at once (at least 1); threads waiting
    /// for room wake.
    pub fn set_max_in_flight(&self, bricks: usize) {
        self.shared.queue.lock().max_in_flight = bricks.max(1);
        self.shared.wake.notify_all();
    }

    /// Cancels a queued request; returns whether it was queued.
    pub fn cancel(&self, kind: FetchKind, key: NodeKey) -> bool {
        self.shared.queue.lock().cancel((kind, key))
    }

    /// Collects finished jobs without blocking: bricks go into `cache`; metadata
    /// and errors are reported.
    pub fn poll(&mut self, cache: &mut CpuCache) -> PollReport {
        let mut report = PollReport::default();
        let done: Vec<Completion> = self.done.try_iter().collect();
        if done.is_empty() {
            return report;
        }
        {
            let mut q = self.shared.queue.lock();
            for c in &done {
                for jk in c.keys() {
                    q.done(jk);
                }
            }
        }
        // Room in the budget of bricks in flight: threads waiting for it go on.
        self.shared.wake.notify_all();
        let meta = |report: &mut PollReport, key, result| match result {
            Ok(info) => report.metadata.push((key, info)),
            Err(e) => report.failed.push((FetchKind::Metadata, key, e)),
        };
        for c in done {
            match c {
                Completion::Meta { key, result } => meta(&mut report, key, *result),
                Completion::Brick { key, result } => match result {
                    Ok(brick) => {
                        self.loaded_total += 1;
                        report.evicted.extend(cache.insert(key, brick));
                        report.loaded.push(key);
                    }
                    Err(LoadError::Cancelled { .. }) => report.cancelled.push(key),
                    Err(e) => report.failed.push((FetchKind::Brick, key, e)),
                },
                Completion::Nodes(nodes) => {
                    for (c, r) in nodes {
                        meta(&mut report, c, r);
                    }
                }
            }
        }
        report
    }

    /// True when the request is queued.
    pub fn is_queued(&self, kind: FetchKind, key: NodeKey) -> bool {
        self.shared.queue.lock().is_queued((kind, key))
    }

    /// True when a worker is reading it or its result awaits `poll`.
    pub fn is_loading(&self, kind: FetchKind, key: NodeKey) -> bool {
        self.shared.queue.lock().is_loading((kind, key))
    }

    /// Queued requests of a kind.
    pub fn queued(&self, kind: FetchKind) -> usize {
        self.shared.queue.lock().queued_count(kind)
    }

    /// Requests of a kind being read or awaiting `poll`.
    pub fn loading(&self, kind: FetchKind) -> usize {
        self.shared.queue.lock().loading_count(kind)
    }

    /// Requests cancelled so far: `(queued, in flight)`. A queued request
    /// (brick or metadata) is cancelled when the wanted set drops it; a
    /// batch in flight when it drops every brick of the batch (counted per
    /// brick).
    pub fn cancelled(&self) -> (u64, u64) {
        let q = self.shared.queue.lock();
        (q.cancelled_queued, q.cancelled_in_flight)
    }

    /// Bricks delivered by `poll` so far.
    pub fn loaded_total(&self) -> u64 {
        self.loaded_total
    }

    /// Number of worker threads.
    pub fn workers(&self) -> usize {
        self.workers.len()
    }
}

impl Drop for Loader {
    fn drop(&mut self) {
        {
            let mut q = self.shared.queue.lock();
            q.shutdown = true;
            q.clear();
        }
        self.shared.wake.notify_all();
        let deadline = Instant::now() + SHUTDOWN_WAIT;
        {
            let mut live = self.shared.live.lock();
            while *live > 0 {
                if self
                    .shared
                    .exited
                    .wait_until(&mut live, deadline)
                    .timed_out()
                {
                    break;
                }
            }
        }
        for w in self.workers.drain(..) {
            if w.is_finished() {
                // A worker only ends by returning; source panics are caught.
                let _ = w.join();
            }
            // Otherwise it is blocked in the source: dropping the handle detaches
            // it; it exits when the call returns (the channel is closed, the
            // queue says shutdown).
        }
    }
}
