//! What a loader thread does, and the guarded calls into the source that
//! [`BrickManager::preload_root`](crate::BrickManager::preload_root) shares: every
//! `node()` and `read_brick()` runs inside `catch_unwind`.

use super::LoadError;
use super::queue::{Job, JobKey, Queue};
use crate::failures::FetchKind;
use crate::prepared::{PreparedBrick, Preparer};
use brickray_core::{BrickError, BrickSource, CancelToken, NodeInfo, NodeKey, OctreeLayout};
use crossbeam_channel::Sender;
use parking_lot::{Condvar, Mutex};
use std::panic::AssertUnwindSafe;
use std::sync::Arc;

/// State shared by the loader and its threads. A thread owns an `Arc` of it (and
/// of the source and preparer), so one still blocked in a read after the loader
/// is gone touches nothing freed.
#[derive(Debug, Default)]
pub(crate) struct Shared {
    pub(crate) queue: Mutex<Queue>,
    pub(crate) wake: Condvar,
    /// Threads not yet exited.
    pub(crate) live: Mutex<usize>,
    pub(crate) exited: Condvar,
}

/// A finished job (or, for `Nodes`, several: a brick job's second half, or a
/// batch of metadata jobs).
#[derive(Debug)]
pub(crate) enum Completion {
    Meta {
        key: NodeKey,
        result: Box<Result<NodeInfo, LoadError>>,
    },
    Brick {
        key: NodeKey,
        result: Result<PreparedBrick, LoadError>,
    },
    /// Metadata of several nodes in one call: a brick's children, read by the
    /// brick's job right after the brick (claimed as loading before the brick
    /// was sent, so nobody requests them again meanwhile), or a batch of
    /// metadata jobs from a source read in batches.
    Nodes(Vec<(NodeKey, Result<NodeInfo, LoadError>)>),
}

impl Completion {
    /// The jobs it completes.
    pub(crate) fn keys(&self) -> Vec<JobKey> {
        match self {
            Completion::Meta { key, .. } => vec![(FetchKind::Metadata, *key)],
            Completion::Brick { key, .. } => vec![(FetchKind::Brick, *key)],
            Completion::Nodes(c) => c.iter().map(|c| (FetchKind::Metadata, c.0)).collect(),
        }
    }
}

/// Runs `f`, turning a panic into [`LoadError::Panicked`].
pub(crate) fn catching<T>(
    key: NodeKey,
    f: impl FnOnce() -> Result<T, BrickError>,
) -> Result<T, LoadError> {
    match std::panic::catch_unwind(AssertUnwindSafe(f)) {
        Ok(r) => r.map_err(LoadError::from),
        Err(payload) => Err(LoadError::Panicked {
            key,
            message: panic_message(payload.as_ref()),
        }),
    }
}

/// A panic's message, when it was a string.
fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_default()
}

/// A node's metadata, panics caught.
pub(crate) fn fetch_meta(source: &dyn BrickSource, key: NodeKey) -> Result<NodeInfo, LoadError> {
    catching(key, || source.node(key))
}

/// Several nodes' metadata in one [`BrickSource::nodes`] call, one result
/// per key. When the call panics, or answers for other keys than asked, the
/// nodes are read one by one, so a panic fails only its own node.
pub(crate) fn fetch_metas(
    source: &dyn BrickSource,
    keys: &[NodeKey],
) -> Vec<(NodeKey, Result<NodeInfo, LoadError>)> {
    match std::panic::catch_unwind(AssertUnwindSafe(|| source.nodes(keys))) {
        Ok(results) if results.len() == keys.len() => keys
            .iter()
            .zip(results)
            .map(|(&key, r)| (key, r.map_err(LoadError::from)))
            .collect(),
        _ => keys.iter().map(|&k| (k, fetch_meta(source, k))).collect(),
    }
}

/// A node's brick, read and prepared, panics caught.
pub(crate) fn fetch_brick(
    source: &dyn BrickSource,
    prep: &Preparer,
    key: NodeKey,
    info: &NodeInfo,
) -> Result<PreparedBrick, LoadError> {
    catching(key, || {
        let mut buf = vec![0u8; prep.raw_bytes()];
        source.read_brick(key, &mut buf)?;
        prep.prepare_from(source, key, &buf, info)
    })
}

/// Several nodes' bricks in one [`BrickSource::read_bricks`] call, each
/// prepared; one result per key. A panic fails the whole batch.
pub(crate) fn fetch_bricks(
    source: &dyn BrickSource,
    prep: &Preparer,
    jobs: &[(NodeKey, NodeInfo)],
    cancel: &CancelToken,
) -> Vec<Result<PreparedBrick, LoadError>> {
    let keys: Vec<NodeKey> = jobs.iter().map(|j| j.0).collect();
    let mut bufs = vec![vec![0u8; prep.raw_bytes()]; jobs.len()];
    let read = std::panic::catch_unwind(AssertUnwindSafe(|| {
        let mut outs: Vec<&mut [u8]> = bufs.iter_mut().map(|b| b.as_mut_slice()).collect();
        source.read_bricks(&keys, &mut outs, cancel)
    }));
    match read {
        Ok(results) if results.len() == jobs.len() => results
            .into_iter()
            .zip(jobs)
            .zip(&bufs)
            .map(|((r, (key, info)), buf)| match r {
                Ok(()) => catching(*key, || prep.prepare_from(source, *key, buf, info)),
                // Whatever the source says of a cancelled read, nobody wants it.
                Err(_) if cancel.is_cancelled() => Err(LoadError::Cancelled { key: *key }),
                Err(e) => Err(LoadError::from(e)),
            })
            .collect(),
        // A source that answered for other keys than asked: each on its own.
        Ok(_) => jobs
            .iter()
            .map(|(key, info)| fetch_brick(source, prep, *key, info))
            .collect(),
        Err(payload) => {
            let message = panic_message(payload.as_ref());
            jobs.iter()
                .map(|&(key, _)| {
                    Err(LoadError::Panicked {
                        key,
                        message: message.clone(),
                    })
                })
                .collect()
        }
    }
}

/// `key`'s children inside the volume (none at the finest level).
pub(crate) fn children_in_volume(layout: &OctreeLayout, key: NodeKey) -> Vec<NodeKey> {
    if key.level.saturating_add(1) >= layout.levels {
        return Vec::new();
    }
    layout
        .children(key)
        .iter()
        .copied()
        .filter(|c| layout.in_volume(*c))
        .collect()
}

/// Decrements the live-thread count when a thread ends, however it ends.
struct ExitGuard(Arc<Shared>);

impl Drop for ExitGuard {
    fn drop(&mut self) {
        *self.0.live.lock() -= 1;
        self.0.exited.notify_all();
    }
}

/// A loader thread: takes jobs until shutdown.
pub(crate) fn worker(
    shared: Arc<Shared>,
    source: Arc<dyn BrickSource>,
    prep: Arc<Preparer>,
    tx: Sender<Completion>,
) {
    let _guard = ExitGuard(shared.clone());
    // (Guarded like every call into the source: a panic means no batches.)
    let batch = std::panic::catch_unwind(AssertUnwindSafe(|| source.batch_size()))
        .unwrap_or(1)
        .clamp(1, MAX_BATCH);
    loop {
        let (job, more) = {
            let mut q = shared.queue.lock();
            loop {
                if q.shutdown {
                    return;
                }
                if let Some(job) = q.pop_within_budget() {
                    let more = match job {
                        Job::Brick { .. } if batch > 1 => q.pop_more_bricks(batch - 1),
                        Job::Meta(_) if batch > 1 => q.pop_more_meta(batch - 1),
                        _ => Vec::new(),
                    };
                    break (job, more);
                }
                shared.wake.wait(&mut q);
            }
        };
        if batch > 1 && matches!(job, Job::Brick { .. }) {
            let jobs: Vec<Job> = std::iter::once(job).chain(more).collect();
            if !brick_batch(&shared, source.as_ref(), &prep, &tx, &jobs) {
                return;
            }
            continue;
        }
        if batch > 1 && matches!(job, Job::Meta(_)) {
            // Metadata in one call, as a brick's children are read.
            let keys: Vec<NodeKey> = std::iter::once(job)
                .chain(more)
                .filter_map(|j| match j {
                    Job::Meta(key) => Some(key),
                    Job::Brick { .. } => None,
                })
                .collect();
            if tx
                .send(Completion::Nodes(fetch_metas(source.as_ref(), &keys)))
                .is_err()
            {
                return;
            }
            continue;
        }
        let done = match job {
            Job::Meta(key) => Completion::Meta {
                key,
                result: Box::new(fetch_meta(source.as_ref(), key)),
            },
            Job::Brick {
                key,
                info,
                children_meta,
            } => {
                let result = fetch_brick(source.as_ref(), &prep, key, &info);
                if !deliver(
                    &shared,
                    source.as_ref(),
                    &prep,
                    &tx,
                    key,
                    children_meta,
                    result,
                ) {
                    return;
                }
                continue;
            }
        };
        // The loader is gone: stop.
        if tx.send(done).is_err() {
            return;
        }
    }
}

/// Most bricks one batch carries, whatever the source asks.
pub(crate) const MAX_BATCH: usize = 64;

/// Reads a batch of brick jobs in one call and delivers each; false when
/// the thread should stop.
fn brick_batch(
    shared: &Shared,
    source: &dyn BrickSource,
    prep: &Preparer,
    tx: &Sender<Completion>,
    jobs: &[Job],
) -> bool {
    let wanted: Vec<(NodeKey, Arc<NodeInfo>, bool)> = jobs
        .iter()
        .filter_map(|j| match j {
            Job::Brick {
                key,
                info,
                children_meta,
            } => Some((*key, info.clone(), *children_meta)),
            Job::Meta(_) => None,
        })
        .collect();
    let pairs: Vec<(NodeKey, NodeInfo)> = wanted
        .iter()
        .map(|(k, i, _)| (*k, NodeInfo::clone(i)))
        .collect();
    let (id, cancel) = shared
        .queue
        .lock()
        .begin_batch(pairs.iter().map(|p| p.0).collect());
    let results = fetch_bricks(source, prep, &pairs, &cancel);
    shared.queue.lock().end_batch(id);
    // Every brick first, then the children's metadata of each.
    let mut claimed = Vec::new();
    for ((key, _, children_meta), result) in wanted.into_iter().zip(results) {
        match send_brick(shared, prep, tx, key, children_meta, result) {
            Some(c) => claimed.push(c),
            None => return false,
        }
    }
    claimed
        .into_iter()
        .all(|c| send_children(shared, source, tx, c))
}

/// Sends a brick's result, then (when asked and the brick arrived) reads and
/// sends its children's metadata; false when the thread should stop.
fn deliver(
    shared: &Shared,
    source: &dyn BrickSource,
    prep: &Preparer,
    tx: &Sender<Completion>,
    key: NodeKey,
    children_meta: bool,
    result: Result<PreparedBrick, LoadError>,
) -> bool {
    match send_brick(shared, prep, tx, key, children_meta, result) {
        Some(claimed) => send_children(shared, source, tx, claimed),
        None => false,
    }
}

/// Sends a brick's result; returns the children whose metadata it claimed
/// (when asked and the brick arrived), `None` when the thread should stop.
fn send_brick(
    shared: &Shared,
    prep: &Preparer,
    tx: &Sender<Completion>,
    key: NodeKey,
    children_meta: bool,
    result: Result<PreparedBrick, LoadError>,
) -> Option<Vec<NodeKey>> {
    // Claim the children's metadata before the brick is delivered, so that a
    // split of the node finds it in flight, not missing.
    let claimed = if children_meta && result.is_ok() {
        shared
            .queue
            .lock()
            .claim_metadata(&children_in_volume(prep.layout(), key))
    } else {
        Vec::new()
    };
    // The brick goes first: a slow or hung metadata call must not hold it
    // back.
    tx.send(Completion::Brick { key, result }).ok()?;
    Some(claimed)
}

/// Reads and sends the metadata of claimed children; false when the thread
/// should stop.
fn send_children(
    shared: &Shared,
    source: &dyn BrickSource,
    tx: &Sender<Completion>,
    claimed: Vec<NodeKey>,
) -> bool {
    if claimed.is_empty() {
        return true;
    }
    if shared.queue.lock().shutdown {
        return false;
    }
    tx.send(Completion::Nodes(fetch_metas(source, &claimed)))
        .is_ok()
}
