//! Asynchronous brick loader: worker threads read bricks from a [`BrickSource`] in
//! priority order; the render thread only submits requests and polls completions,
//! never waiting on I/O.
//!
//! A request is *queued* (Requested) until a worker takes it, then *loading* until
//! [`Loader::poll`] collects the result: a brick goes into the [`CpuCache`], an
//! error is kept as the node's failure. Queued requests can be re-prioritised and
//! cancelled; a read in progress always runs to completion.

use crate::cpu_cache::{BrickBytes, CpuCache};
use brickray_core::{BrickError, BrickSource, NodeKey};
use crossbeam_channel::{Receiver, Sender};
use parking_lot::{Condvar, Mutex};
use std::collections::{BTreeMap, HashMap, HashSet};
use std::panic::AssertUnwindSafe;
use std::sync::Arc;
use std::thread::JoinHandle;
use thiserror::Error;

/// Why a node could not be loaded.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum LoadError {
    /// The source reported an error (reading the brick or its metadata).
    #[error(transparent)]
    Source(#[from] BrickError),
    /// The source panicked while reading.
    #[error("brick source panicked reading {key:?}: {message}")]
    Panicked {
        /// The node.
        key: NodeKey,
        /// The panic message, when it was a string.
        message: String,
    },
}

/// Loader configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LoaderConfig {
    /// Worker threads (at least 1).
    pub workers: usize,
}

impl Default for LoaderConfig {
    fn default() -> Self {
        LoaderConfig { workers: 2 }
    }
}

/// A request's place in the queue: priority descending, then FIFO.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
struct QueueKey {
    /// `!total-order bits` of the priority so that higher priorities sort first.
    neg_priority: u32,
    seq: u64,
}

fn queue_key(priority: f32, seq: u64) -> QueueKey {
    // Map f32 to u32 preserving total order, then invert.
    let b = priority.to_bits();
    let ordered = if b & 0x8000_0000 != 0 {
        !b
    } else {
        b | 0x8000_0000
    };
    QueueKey {
        neg_priority: !ordered,
        seq,
    }
}

#[derive(Debug, Default)]
struct Queue {
    order: BTreeMap<QueueKey, NodeKey>,
    queued: HashMap<NodeKey, QueueKey>,
    /// Taken by a worker, result not yet polled.
    loading: HashSet<NodeKey>,
    seq: u64,
    shutdown: bool,
}

impl Queue {
    fn push(&mut self, key: NodeKey, priority: f32) {
        if let Some(old) = self.queued.remove(&key) {
            self.order.remove(&old);
        }
        self.seq += 1;
        let qk = queue_key(priority, self.seq);
        self.order.insert(qk, key);
        self.queued.insert(key, qk);
    }

    fn cancel(&mut self, key: NodeKey) -> bool {
        match self.queued.remove(&key) {
            Some(qk) => {
                self.order.remove(&qk);
                true
            }
            None => false,
        }
    }

    fn pop(&mut self) -> Option<NodeKey> {
        let (_, key) = self.order.pop_first()?;
        self.queued.remove(&key);
        self.loading.insert(key);
        Some(key)
    }
}

#[derive(Debug)]
struct Shared {
    queue: Mutex<Queue>,
    wake: Condvar,
}

type Completion = (NodeKey, Result<BrickBytes, LoadError>);

/// What [`Loader::request`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RequestOutcome {
    /// Newly queued.
    Queued,
    /// Was already queued; its priority is updated.
    Reprioritized,
    /// A worker is reading it (or its result awaits `poll`).
    Loading,
    /// Its last load failed; not retried until [`Loader::retry`].
    Failed,
}

/// The outcome of one [`Loader::poll`].
#[derive(Debug, Default, Clone, PartialEq, Eq)]
pub struct PollReport {
    /// Bricks that arrived and went into the CPU cache.
    pub loaded: Vec<NodeKey>,
    /// Nodes whose load failed.
    pub failed: Vec<NodeKey>,
    /// Bricks the CPU cache evicted to make room.
    pub evicted: Vec<NodeKey>,
}

/// Worker threads reading bricks in priority order. Dropping it stops the workers
/// (reads in progress finish first) and joins them.
pub struct Loader {
    shared: Arc<Shared>,
    workers: Vec<JoinHandle<()>>,
    done: Receiver<Completion>,
    failed: HashMap<NodeKey, Arc<LoadError>>,
    brick_bytes: usize,
    loaded_total: u64,
}

impl std::fmt::Debug for Loader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Loader")
            .field("workers", &self.workers.len())
            .field("queued", &self.queued())
            .field("loading", &self.loading())
            .field("failed", &self.failed.len())
            .finish()
    }
}

impl Loader {
    /// Starts `config.workers` threads (at least one) reading from `source`.
    /// Fails only when the OS refuses a thread.
    pub fn new(source: Arc<dyn BrickSource>, config: LoaderConfig) -> std::io::Result<Loader> {
        let shared = Arc::new(Shared {
            queue: Mutex::new(Queue::default()),
            wake: Condvar::new(),
        });
        let (tx, rx) = crossbeam_channel::unbounded();
        let brick_bytes = source.layout().brick_bytes();
        let mut loader = Loader {
            shared,
            workers: Vec::new(),
            done: rx,
            failed: HashMap::new(),
            brick_bytes,
            loaded_total: 0,
        };
        for i in 0..config.workers.max(1) {
            let shared = loader.shared.clone();
            let source = source.clone();
            let tx = tx.clone();
            // On error `loader` drops here, which stops and joins the threads started so far.
            let handle = std::thread::Builder::new()
                .name(format!("brickray-loader-{i}"))
                .spawn(move || worker(&shared, source.as_ref(), &tx, brick_bytes))?;
            loader.workers.push(handle);
        }
        Ok(loader)
    }

    /// Requests a node with a priority (higher first). Re-requesting a queued node
    /// updates its priority. Does not check the CPU cache: the caller asks only for
    /// what it lacks.
    pub fn request(&self, key: NodeKey, priority: f32) -> RequestOutcome {
        if self.failed.contains_key(&key) {
            return RequestOutcome::Failed;
        }
        let mut q = self.shared.queue.lock();
        if q.loading.contains(&key) {
            return RequestOutcome::Loading;
        }
        let was = q.queued.contains_key(&key);
        q.push(key, priority);
        drop(q);
        self.shared.wake.notify_one();
        if was {
            RequestOutcome::Reprioritized
        } else {
            RequestOutcome::Queued
        }
    }

    /// Replaces the wanted set: queues or re-prioritises every listed node and
    /// cancels every queued node not listed. Returns how many were cancelled.
    pub fn submit(&self, wanted: &[(NodeKey, f32)]) -> usize {
        let wanted: Vec<(NodeKey, f32)> = wanted
            .iter()
            .copied()
            .filter(|(k, _)| !self.failed.contains_key(k))
            .collect();
        let keep: HashSet<NodeKey> = wanted.iter().map(|w| w.0).collect();
        let mut q = self.shared.queue.lock();
        let stale: Vec<NodeKey> = q
            .queued
            .keys()
            .filter(|k| !keep.contains(k))
            .copied()
            .collect();
        for k in &stale {
            q.cancel(*k);
        }
        let mut added = 0;
        for (k, p) in wanted {
            if !q.loading.contains(&k) {
                q.push(k, p);
                added += 1;
            }
        }
        drop(q);
        for _ in 0..added.min(self.workers.len()) {
            self.shared.wake.notify_one();
        }
        stale.len()
    }

    /// Cancels a queued request; returns whether it was queued.
    pub fn cancel(&self, key: NodeKey) -> bool {
        self.shared.queue.lock().cancel(key)
    }

    /// Collects finished loads without blocking: bricks go into `cache`, errors are
    /// kept as failures.
    pub fn poll(&mut self, cache: &mut CpuCache) -> PollReport {
        let mut report = PollReport::default();
        let done: Vec<Completion> = self.done.try_iter().collect();
        if done.is_empty() {
            return report;
        }
        {
            let mut q = self.shared.queue.lock();
            for (k, _) in &done {
                q.loading.remove(k);
            }
        }
        for (key, res) in done {
            match res {
                Ok(data) => {
                    self.loaded_total += 1;
                    report.evicted.extend(cache.insert(key, data));
                    report.loaded.push(key);
                }
                Err(e) => {
                    self.failed.insert(key, Arc::new(e));
                    report.failed.push(key);
                }
            }
        }
        report
    }

    /// Records a failure found outside the loader (e.g. reading node metadata).
    pub fn mark_failed(&mut self, key: NodeKey, error: LoadError) {
        self.cancel(key);
        self.failed.insert(key, Arc::new(error));
    }

    /// Forgets a node's failure so it can be requested again; returns the error.
    pub fn retry(&mut self, key: NodeKey) -> Option<Arc<LoadError>> {
        self.failed.remove(&key)
    }

    /// The error of a failed node.
    pub fn failure(&self, key: NodeKey) -> Option<&Arc<LoadError>> {
        self.failed.get(&key)
    }

    /// All failed nodes.
    pub fn failures(&self) -> impl Iterator<Item = (NodeKey, &Arc<LoadError>)> {
        self.failed.iter().map(|(k, e)| (*k, e))
    }

    /// True when the node is queued.
    pub fn is_queued(&self, key: NodeKey) -> bool {
        self.shared.queue.lock().queued.contains_key(&key)
    }

    /// True when a worker is reading the node or its result awaits `poll`.
    pub fn is_loading(&self, key: NodeKey) -> bool {
        self.shared.queue.lock().loading.contains(&key)
    }

    /// Queued requests.
    pub fn queued(&self) -> usize {
        self.shared.queue.lock().queued.len()
    }

    /// Reads in progress or awaiting `poll`.
    pub fn loading(&self) -> usize {
        self.shared.queue.lock().loading.len()
    }

    /// Failed nodes.
    pub fn failed_count(&self) -> usize {
        self.failed.len()
    }

    /// Bricks delivered by `poll` so far.
    pub fn loaded_total(&self) -> u64 {
        self.loaded_total
    }

    /// Bytes of one brick.
    pub fn brick_bytes(&self) -> usize {
        self.brick_bytes
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
            q.order.clear();
            q.queued.clear();
        }
        self.shared.wake.notify_all();
        for w in self.workers.drain(..) {
            // A worker only ends by returning; a panic was already caught per read.
            let _ = w.join();
        }
    }
}

fn worker(shared: &Shared, source: &dyn BrickSource, tx: &Sender<Completion>, brick_bytes: usize) {
    loop {
        let key = {
            let mut q = shared.queue.lock();
            loop {
                if q.shutdown {
                    return;
                }
                if let Some(k) = q.pop() {
                    break k;
                }
                shared.wake.wait(&mut q);
            }
        };
        let res = std::panic::catch_unwind(AssertUnwindSafe(|| {
            let mut buf = vec![0u8; brick_bytes];
            source
                .read_brick(key, &mut buf)
                .map(|()| BrickBytes::from(buf))
        }));
        let res = match res {
            Ok(r) => r.map_err(LoadError::from),
            Err(payload) => {
                let message = payload
                    .downcast_ref::<&str>()
                    .map(|s| s.to_string())
                    .or_else(|| payload.downcast_ref::<String>().cloned())
                    .unwrap_or_default();
                Err(LoadError::Panicked { key, message })
            }
        };
        // The receiver lives until every worker is joined; ignore a closed channel.
        let _ = tx.send((key, res));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_source::{TestSource, fill_byte};
    use std::time::{Duration, Instant};

    fn k(level: u8, x: u32) -> NodeKey {
        NodeKey::new(level, x, 0, 0)
    }

    /// Polls until `done` holds, failing after 5 s.
    fn poll_until(
        loader: &mut Loader,
        cache: &mut CpuCache,
        mut done: impl FnMut(&Loader, &CpuCache) -> bool,
    ) {
        let t = Instant::now();
        while !done(loader, cache) {
            loader.poll(cache);
            assert!(
                t.elapsed() < Duration::from_secs(5),
                "timed out: {loader:?}"
            );
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    #[test]
    fn delivers_into_cpu_cache() {
        let src = Arc::new(TestSource::new(64));
        let mut loader = Loader::new(src.clone(), LoaderConfig { workers: 2 }).unwrap();
        let mut cache = CpuCache::new(1 << 20);
        let keys: Vec<NodeKey> = (0..4).map(|x| k(2, x)).collect();
        for (i, key) in keys.iter().enumerate() {
            assert_eq!(loader.request(*key, i as f32), RequestOutcome::Queued);
        }
        poll_until(&mut loader, &mut cache, |l, c| {
            keys.iter().all(|k| c.contains(*k)) && l.loading() == 0
        });
        for key in &keys {
            let b = cache.peek(*key).unwrap();
            assert_eq!(b.len(), src.layout.brick_bytes());
            assert!(b.iter().all(|&v| v == fill_byte(*key)));
        }
        assert_eq!(loader.loaded_total(), 4);
        assert_eq!(loader.queued(), 0);
    }

    #[test]
    fn prioritises_and_reprioritises() {
        let mut src = TestSource::new(64);
        let gate = k(1, 0);
        src.gate_key = Some(gate);
        let src = Arc::new(src);
        let mut loader = Loader::new(src.clone(), LoaderConfig { workers: 1 }).unwrap();
        let mut cache = CpuCache::new(1 << 20);
        loader.request(gate, 100.0);
        poll_until(&mut loader, &mut cache, |l, _| l.is_loading(gate));
        // The single worker is held by the gate: everything below is ordered.
        for x in 0..6 {
            loader.request(k(3, x), x as f32);
        }
        assert_eq!(loader.request(k(3, 0), 10.0), RequestOutcome::Reprioritized);
        assert_eq!(loader.request(gate, 1.0), RequestOutcome::Loading);
        assert_eq!(loader.queued(), 6);
        src.open_gate();
        poll_until(&mut loader, &mut cache, |l, _| {
            l.queued() == 0 && l.loading() == 0
        });
        let xs: Vec<u32> = src.reads().iter().skip(1).map(|k| k.x).collect();
        assert_eq!(xs, vec![0, 5, 4, 3, 2, 1]);
    }

    #[test]
    fn submit_cancels_what_is_no_longer_wanted() {
        let mut src = TestSource::new(64);
        let gate = k(1, 0);
        src.gate_key = Some(gate);
        let src = Arc::new(src);
        let mut loader = Loader::new(src.clone(), LoaderConfig { workers: 1 }).unwrap();
        let mut cache = CpuCache::new(1 << 20);
        loader.request(gate, 100.0);
        poll_until(&mut loader, &mut cache, |l, _| l.is_loading(gate));
        let wanted: Vec<(NodeKey, f32)> = (0..6).map(|x| (k(3, x), 1.0)).collect();
        assert_eq!(loader.submit(&wanted), 0);
        // Next frame only two are still wanted (one with a new priority).
        assert_eq!(loader.submit(&[(k(3, 4), 1.0), (k(3, 1), 5.0)]), 4);
        assert!(loader.cancel(k(3, 4)));
        assert!(!loader.cancel(k(3, 4)));
        src.open_gate();
        poll_until(&mut loader, &mut cache, |l, _| {
            l.queued() == 0 && l.loading() == 0
        });
        assert_eq!(src.reads(), vec![gate, k(3, 1)]);
        assert!(cache.contains(k(3, 1)) && !cache.contains(k(3, 4)));
    }

    #[test]
    fn failures_are_kept_not_panics() {
        let mut src = TestSource::new(64);
        src.failing.insert(k(2, 1));
        src.panicking.insert(k(2, 2));
        let src = Arc::new(src);
        let mut loader = Loader::new(src.clone(), LoaderConfig { workers: 2 }).unwrap();
        let mut cache = CpuCache::new(1 << 20);
        for x in 0..3 {
            loader.request(k(2, x), 1.0);
        }
        poll_until(&mut loader, &mut cache, |l, _| {
            l.failed_count() == 2 && l.loading() == 0 && l.queued() == 0
        });
        assert!(cache.contains(k(2, 0)));
        assert!(matches!(
            loader.failure(k(2, 1)).map(|e| &**e),
            Some(LoadError::Source(BrickError::Io { .. }))
        ));
        assert!(matches!(
            loader.failure(k(2, 2)).map(|e| &**e),
            Some(LoadError::Panicked { .. })
        ));
        // Failed nodes are not re-queued until retried.
        assert_eq!(loader.request(k(2, 1), 1.0), RequestOutcome::Failed);
        assert!(loader.retry(k(2, 1)).is_some());
        assert_eq!(loader.request(k(2, 1), 1.0), RequestOutcome::Queued);
        // The workers survived the panic.
        loader.request(k(2, 3), 1.0);
        poll_until(&mut loader, &mut cache, |_, c| c.contains(k(2, 3)));
    }

    #[test]
    fn drop_with_loads_in_flight_ends_cleanly() {
        let mut src = TestSource::new(128);
        src.delay = Duration::from_millis(10);
        let src = Arc::new(src);
        let loader = Loader::new(src.clone(), LoaderConfig { workers: 3 }).unwrap();
        let wanted: Vec<(NodeKey, f32)> = (0..256)
            .map(|x| (NodeKey::new(4, x % 16, x / 16, 0), x as f32))
            .collect();
        loader.submit(&wanted);
        let t = Instant::now();
        while loader.loading() == 0 {
            assert!(t.elapsed() < Duration::from_secs(5));
            std::thread::yield_now();
        }
        let t = Instant::now();
        drop(loader);
        // Only reads already started finish: a few delays, not 256 / 3 of them.
        assert!(t.elapsed() < Duration::from_secs(2));
        assert!(src.reads().len() < 256);
        // The source is no longer shared with any thread.
        assert_eq!(Arc::strong_count(&src), 1);
    }
}
