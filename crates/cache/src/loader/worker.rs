//! What a loader thread does, and the guarded calls into the source that
//! [`BrickManager::preload_root`](crate::BrickManager::preload_root) shares: every
//! `node()` and `read_brick()` runs inside `catch_unwind`.

use super::LoadError;
use super::queue::{Job, JobKey, Queue};
use crate::failures::FetchKind;
use crate::prepared::{PreparedBrick, Preparer};
use brickray_core::{BrickError, BrickSource, NodeInfo, NodeKey, OctreeLayout};
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

/// A finished job (or, for `Children`, the second half of a brick job).
#[derive(Debug)]
pub(crate) enum Completion {
    Meta {
        key: NodeKey,
        result: Result<NodeInfo, LoadError>,
    },
    Brick {
        key: NodeKey,
        result: Result<PreparedBrick, LoadError>,
    },
    /// Metadata of a brick's children, read by the brick's job right after the
    /// brick (claimed as loading before the brick was sent, so nobody requests
    /// them again meanwhile).
    Children(Vec<(NodeKey, Result<NodeInfo, LoadError>)>),
}

impl Completion {
    /// The jobs it completes.
    pub(crate) fn keys(&self) -> Vec<JobKey> {
        match self {
            Completion::Meta { key, .. } => vec![(FetchKind::Metadata, *key)],
            Completion::Brick { key, .. } => vec![(FetchKind::Brick, *key)],
            Completion::Children(c) => c.iter().map(|c| (FetchKind::Metadata, c.0)).collect(),
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
        Err(payload) => {
            let message = payload
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            Err(LoadError::Panicked { key, message })
        }
    }
}

/// A node's metadata, panics caught.
pub(crate) fn fetch_meta(source: &dyn BrickSource, key: NodeKey) -> Result<NodeInfo, LoadError> {
    catching(key, || source.node(key))
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
        Ok(prep.prepare(&buf, info))
    })
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
    loop {
        let job = {
            let mut q = shared.queue.lock();
            loop {
                if q.shutdown {
                    return;
                }
                if let Some(job) = q.pop() {
                    break job;
                }
                shared.wake.wait(&mut q);
            }
        };
        let done = match job {
            Job::Meta(key) => Completion::Meta {
                key,
                result: fetch_meta(source.as_ref(), key),
            },
            Job::Brick {
                key,
                info,
                children_meta,
            } => {
                let result = fetch_brick(source.as_ref(), &prep, key, &info);
                // Claim the children's metadata before the brick is delivered, so
                // that a split of the node finds it in flight, not missing.
                let claimed = if children_meta && result.is_ok() {
                    shared
                        .queue
                        .lock()
                        .claim_metadata(&children_in_volume(prep.layout(), key))
                } else {
                    Vec::new()
                };
                // The brick goes first: a slow or hung metadata call must not
                // hold it back.
                if tx.send(Completion::Brick { key, result }).is_err() {
                    return;
                }
                if claimed.is_empty() {
                    continue;
                }
                let mut children = Vec::with_capacity(claimed.len());
                for c in claimed {
                    if shared.queue.lock().shutdown {
                        return;
                    }
                    children.push((c, fetch_meta(source.as_ref(), c)));
                }
                Completion::Children(children)
            }
        };
        // The loader is gone: stop.
        if tx.send(done).is_err() {
            return;
        }
    }
}
