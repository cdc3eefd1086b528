//! The loader's job queue: metadata jobs first, then bricks, each by priority
//! (descending) then FIFO, with an index for re-prioritising and cancelling.

use crate::failures::FetchKind;
use brickray_core::{CancelToken, NodeInfo, NodeKey};
use std::collections::{BTreeMap, HashMap, HashSet};

/// A job's identity: one of each kind per node.
pub(crate) type JobKey = (FetchKind, NodeKey);

/// What a worker does.
// (Queued by value; boxing the brick job would allocate per request.)
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Job {
    /// Read a node's metadata.
    Meta(NodeKey),
    /// Read and prepare a node's brick; with `children_meta`, also read the
    /// metadata of its children inside the volume.
    Brick {
        key: NodeKey,
        info: std::sync::Arc<NodeInfo>,
        children_meta: bool,
    },
}

impl Job {
    pub(crate) fn key(&self) -> JobKey {
        match *self {
            Job::Meta(key) => (FetchKind::Metadata, key),
            Job::Brick { key, .. } => (FetchKind::Brick, key),
        }
    }
}

/// A job's place in the queue: metadata before bricks, priority descending,
/// then FIFO.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
struct QueueKey {
    /// 0 for metadata, 1 for bricks.
    class: u8,
    /// `!total-order bits` of the priority so that higher priorities sort first.
    neg_priority: u32,
    seq: u64,
}

fn queue_key(kind: FetchKind, priority: f32, seq: u64) -> QueueKey {
    // Map f32 to u32 preserving total order, then invert.
    let b = priority.to_bits();
    let ordered = if b & 0x8000_0000 != 0 {
        !b
    } else {
        b | 0x8000_0000
    };
    QueueKey {
        class: match kind {
            FetchKind::Metadata => 0,
            FetchKind::Brick => 1,
        },
        neg_priority: !ordered,
        seq,
    }
}

#[derive(Debug, Default)]
pub(crate) struct Queue {
    order: BTreeMap<QueueKey, Job>,
    queued: HashMap<JobKey, QueueKey>,
    /// Taken by a worker, result not yet polled.
    loading: HashSet<JobKey>,
    seq: u64,
    pub(crate) shutdown: bool,
    /// Brick batches being read, each with the token that aborts it.
    in_flight: Vec<(u64, CancelToken, Vec<NodeKey>)>,
    next_batch: u64,
    /// Most bricks being read at once (taken, result not polled); at least 1.
    pub(crate) max_in_flight: usize,
    /// Requests cancelled so far: queued ones dropped, in-flight ones aborted.
    pub(crate) cancelled_queued: u64,
    pub(crate) cancelled_in_flight: u64,
}

impl Queue {
    /// Queues (or re-prioritises) a job; returns whether it was queued before.
    pub(crate) fn push(&mut self, job: Job, priority: f32) -> bool {
        let jk = job.key();
        let was = self.cancel(jk);
        self.seq += 1;
        let qk = queue_key(jk.0, priority, self.seq);
        self.order.insert(qk, job);
        self.queued.insert(jk, qk);
        was
    }

    pub(crate) fn cancel(&mut self, jk: JobKey) -> bool {
        match self.queued.remove(&jk) {
            Some(qk) => {
                self.order.remove(&qk);
                true
            }
            None => false,
        }
    }

    /// Drops every queued job.
    pub(crate) fn clear(&mut self) {
        self.order.clear();
        self.queued.clear();
    }

    /// Takes the first job, marking it loading.
    pub(crate) fn pop(&mut self) -> Option<Job> {
        let (_, job) = self.order.pop_first()?;
        let jk = job.key();
        self.queued.remove(&jk);
        self.loading.insert(jk);
        Some(job)
    }

    /// Takes the first job within the budget of bricks in flight: a
    /// metadata job always, a brick job only while fewer than
    /// `max_in_flight` bricks are being read.
    pub(crate) fn pop_within_budget(&mut self) -> Option<Job> {
        let (_, first) = self.order.first_key_value()?;
        if matches!(first, Job::Brick { .. })
            && self.loading_count(FetchKind::Brick) >= self.max_in_flight.max(1)
        {
            return None;
        }
        self.pop()
    }

    /// After a brick job was taken: takes up to `more` further brick jobs
    /// from the front of the queue (the next in priority order), marking
    /// them loading, within the budget of bricks in flight; stops at a
    /// metadata job.
    pub(crate) fn pop_more_bricks(&mut self, more: usize) -> Vec<Job> {
        let room = self
            .max_in_flight
            .max(1)
            .saturating_sub(self.loading_count(FetchKind::Brick));
        let more = more.min(room);
        let mut jobs = Vec::new();
        while jobs.len() < more {
            match self.order.first_key_value() {
                Some((_, Job::Brick { .. })) => jobs.extend(self.pop()),
                _ => break,
            }
        }
        jobs
    }

    /// Up to `more` further metadata jobs, while they are next in order (a
    /// batch of metadata for a source read in batches; metadata is never held
    /// back by the budget in flight).
    pub(crate) fn pop_more_meta(&mut self, more: usize) -> Vec<Job> {
        let mut jobs = Vec::new();
        while jobs.len() < more {
            match self.order.first_key_value() {
                Some((_, Job::Meta(_))) => jobs.extend(self.pop()),
                _ => break,
            }
        }
        jobs
    }

    /// Registers a batch being read; returns its id and its token.
    pub(crate) fn begin_batch(&mut self, keys: Vec<NodeKey>) -> (u64, CancelToken) {
        self.next_batch += 1;
        let token = CancelToken::new();
        self.in_flight.push((self.next_batch, token.clone(), keys));
        (self.next_batch, token)
    }

    /// The batch's read returned.
    pub(crate) fn end_batch(&mut self, id: u64) {
        self.in_flight.retain(|b| b.0 != id);
    }

    /// Cancels every batch in flight none of whose bricks is in `keep`;
    /// returns how many bricks they carried.
    pub(crate) fn cancel_unwanted_batches(&mut self, keep: &HashSet<JobKey>) -> usize {
        let mut n = 0;
        for (_, token, keys) in &self.in_flight {
            if !token.is_cancelled() && !keys.iter().any(|&k| keep.contains(&(FetchKind::Brick, k)))
            {
                token.cancel();
                n += keys.len();
            }
        }
        self.cancelled_in_flight += n as u64;
        n
    }

    /// Marks the metadata of `keys` loading for a brick job that reads it (a
    /// queued metadata job of one of them is taken over); returns those claimed,
    /// i.e. all but those already being read.
    pub(crate) fn claim_metadata(&mut self, keys: &[NodeKey]) -> Vec<NodeKey> {
        let mut claimed = Vec::with_capacity(keys.len());
        for &k in keys {
            let jk = (FetchKind::Metadata, k);
            if !self.loading.contains(&jk) {
                self.cancel(jk);
                self.loading.insert(jk);
                claimed.push(k);
            }
        }
        claimed
    }

    pub(crate) fn done(&mut self, jk: JobKey) {
        self.loading.remove(&jk);
    }

    pub(crate) fn is_queued(&self, jk: JobKey) -> bool {
        self.queued.contains_key(&jk)
    }

    pub(crate) fn is_loading(&self, jk: JobKey) -> bool {
        self.loading.contains(&jk)
    }

    /// Queued job keys not in `keep`.
    pub(crate) fn stale(&self, keep: &HashSet<JobKey>) -> Vec<JobKey> {
        self.queued
            .keys()
            .filter(|k| !keep.contains(k))
            .copied()
            .collect()
    }

    pub(crate) fn queued_count(&self, kind: FetchKind) -> usize {
        self.queued.keys().filter(|k| k.0 == kind).count()
    }

    pub(crate) fn loading_count(&self, kind: FetchKind) -> usize {
        self.loading.iter().filter(|k| k.0 == kind).count()
    }
}
