//! The loader's job queue: metadata jobs first, then bricks, each by priority
//! (descending) then FIFO, with an index for re-prioritising and cancelling.

use crate::failures::FetchKind;
use brickray_core::{CancelToken, NodeInfo, NodeKey};
use rustc_hash::{FxHashMap, FxHashSet};
use std::collections::BTreeMap;

/// A job's identity: one of each kind per node.
pub(crate) type JobKey = (FetchKind, NodeKey);

/// A set of job keys (hashed with FxHash, as node maps are: the wanted set
/// is rebuilt and looked up every frame).
pub(crate) type JobSet = FxHashSet<JobKey>;

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

/// Two jobs that do the same work: the same node and kind, and for bricks
/// the same metadata (shared, or equal) and children's metadata flag.
fn same_job(a: &Job, b: &Job) -> bool {
    match (a, b) {
        (Job::Meta(x), Job::Meta(y)) => x == y,
        (
            Job::Brick {
                key: k1,
                info: i1,
                children_meta: c1,
            },
            Job::Brick {
                key: k2,
                info: i2,
                children_meta: c2,
            },
        ) => k1 == k2 && c1 == c2 && (std::sync::Arc::ptr_eq(i1, i2) || i1 == i2),
        _ => false,
    }
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
    queued: FxHashMap<JobKey, QueueKey>,
    /// Taken by a worker, result not yet polled.
    loading: JobSet,
    /// Of those, brick jobs (the budget in flight counts them on every
    /// take).
    loading_bricks: usize,
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
    /// A job queued again unchanged, at the same priority, keeps its place
    /// (the wanted set is submitted every frame, mostly the same jobs).
    pub(crate) fn push(&mut self, job: Job, priority: f32) -> bool {
        let jk = job.key();
        if let Some(&qk) = self.queued.get(&jk) {
            let same = queue_key(jk.0, priority, qk.seq) == qk
                && self.order.get(&qk).is_some_and(|j| same_job(j, &job));
            if same {
                return true;
            }
        }
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

    /// Marks a job loading.
    fn start_loading(&mut self, jk: JobKey) {
        if self.loading.insert(jk) && jk.0 == FetchKind::Brick {
            self.loading_bricks += 1;
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
        self.start_loading(jk);
        Some(job)
    }

    /// Takes the first job within the budget of bricks in flight: a
    /// metadata job always, a brick job only while fewer than
    /// `max_in_flight` bricks are being read.
    pub(crate) fn pop_within_budget(&mut self) -> Option<Job> {
        let (_, first) = self.order.first_key_value()?;
        if matches!(first, Job::Brick { .. }) && self.loading_bricks >= self.max_in_flight.max(1) {
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
            .saturating_sub(self.loading_bricks);
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
    pub(crate) fn cancel_unwanted_batches(&mut self, keep: &JobSet) -> usize {
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
                self.start_loading(jk);
                claimed.push(k);
            }
        }
        claimed
    }

    pub(crate) fn done(&mut self, jk: JobKey) {
        if self.loading.remove(&jk) && jk.0 == FetchKind::Brick {
            self.loading_bricks -= 1;
        }
    }

    pub(crate) fn is_queued(&self, jk: JobKey) -> bool {
        self.queued.contains_key(&jk)
    }

    pub(crate) fn is_loading(&self, jk: JobKey) -> bool {
        self.loading.contains(&jk)
    }

    /// Queued job keys not in `keep`.
    pub(crate) fn stale(&self, keep: &JobSet) -> Vec<JobKey> {
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
        match kind {
            FetchKind::Brick => self.loading_bricks,
            FetchKind::Metadata => self.loading.len() - self.loading_bricks,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use brickray_core::NodeKind;
    use std::sync::Arc;

    fn info(max: f32) -> Arc<NodeInfo> {
        Arc::new(NodeInfo {
            kind: NodeKind::Data,
            min: 0.0,
            max,
            error: None,
            parent_error: None,
            channels: Default::default(),
            channel_errors: None,
        })
    }

    proptest::proptest! {
        /// Against a list of queued jobs with their priorities and
        /// submission numbers: every take is the model's first (metadata,
        /// then priority descending, then the earliest submission, which a
        /// job queued again unchanged at its priority keeps), the job taken
        /// is the one last queued, and the counts of jobs loading by kind
        /// follow takes, claims and completions.
        #[test]
        fn takes_follow_a_model_of_the_queue(
            ops in proptest::collection::vec((0u8..6, 0u32..5, 0u8..3, proptest::bool::ANY), 1..200),
        ) {
            let mut q = Queue { max_in_flight: 3, ..Default::default() };
            // (job, priority, submission) of each queued job.
            let mut model: Vec<(Job, f32, u64)> = Vec::new();
            let mut loading: std::collections::HashSet<JobKey> = Default::default();
            let mut n = 0u64;
            let infos = [info(1.0), info(2.0)];
            let first = |m: &Vec<(Job, f32, u64)>| {
                m.iter()
                    .enumerate()
                    .min_by(|a, b| {
                        let key = |e: &(Job, f32, u64)| {
                            (matches!(e.0, Job::Brick { .. }), std::cmp::Reverse(e.1.to_bits()), e.2)
                        };
                        key(a.1).cmp(&key(b.1))
                    })
                    .map(|(i, _)| i)
            };
            for (op, x, p, flag) in ops {
                let key = NodeKey::new(3, x, 0, 0);
                let priority = f32::from(p);
                match op {
                    0 | 1 => {
                        let job = if op == 0 {
                            Job::Meta(key)
                        } else {
                            Job::Brick { key, info: infos[usize::from(flag)].clone(), children_meta: flag }
                        };
                        let jk = job.key();
                        let i = model.iter().position(|e| e.0.key() == jk);
                        let kept = i.is_some_and(|i| model[i].1 == priority && model[i].0 == job);
                        proptest::prop_assert_eq!(q.push(job.clone(), priority), i.is_some());
                        if !kept {
                            if let Some(i) = i {
                                model.remove(i);
                            }
                            n += 1;
                            model.push((job, priority, n));
                        }
                    }
                    2 => {
                        let jk = (if flag { FetchKind::Brick } else { FetchKind::Metadata }, key);
                        let i = model.iter().position(|e| e.0.key() == jk);
                        proptest::prop_assert_eq!(q.cancel(jk), i.is_some());
                        if let Some(i) = i {
                            model.remove(i);
                        }
                    }
                    3 => {
                        let budget_full = loading.iter().filter(|k| k.0 == FetchKind::Brick).count() >= 3;
                        let want = first(&model).filter(|&i| {
                            !(matches!(model[i].0, Job::Brick { .. }) && budget_full)
                        });
                        let got = q.pop_within_budget();
                        proptest::prop_assert_eq!(got.as_ref(), want.map(|i| &model[i].0));
                        if let Some(i) = want {
                            loading.insert(model.remove(i).0.key());
                        }
                    }
                    4 => {
                        let jk = (if flag { FetchKind::Brick } else { FetchKind::Metadata }, key);
                        q.done(jk);
                        loading.remove(&jk);
                    }
                    _ => {
                        let claimed = q.claim_metadata(&[key]);
                        let jk = (FetchKind::Metadata, key);
                        proptest::prop_assert_eq!(claimed.is_empty(), loading.contains(&jk));
                        // (Metadata already loading is left as it is, queued or not.)
                        if !loading.contains(&jk) {
                            if let Some(i) = model.iter().position(|e| e.0.key() == jk) {
                                model.remove(i);
                            }
                            loading.insert(jk);
                        }
                    }
                }
                for kind in [FetchKind::Metadata, FetchKind::Brick] {
                    proptest::prop_assert_eq!(
                        q.loading_count(kind),
                        loading.iter().filter(|k| k.0 == kind).count()
                    );
                    proptest::prop_assert_eq!(
                        q.queued_count(kind),
                        model.iter().filter(|e| e.0.key().0 == kind).count()
                    );
                }
            }
        }
    }
}
