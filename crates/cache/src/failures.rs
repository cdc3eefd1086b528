//! Failed reads: kept per node and kind, counted, surfaced once
//! ([`StreamError`]), and retried after an exponential back-off measured on an
//! injectable [`Clock`].

use crate::config::RetryPolicy;
use crate::loader::LoadError;
use brickray_core::NodeKey;
use std::collections::HashMap;
use std::sync::Arc;
use std::time::Instant;
use thiserror::Error;

/// What was read from the source.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum FetchKind {
    /// A node's metadata (`BrickSource::node`).
    Metadata,
    /// A node's brick (`BrickSource::read_brick`).
    Brick,
}

impl std::fmt::Display for FetchKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            FetchKind::Metadata => "metadata",
            FetchKind::Brick => "brick",
        })
    }
}

/// The time source of retry back-offs (injectable so tests need not sleep).
pub trait Clock: Send + Sync + std::fmt::Debug {
    /// Now.
    fn now(&self) -> Instant;
}

/// [`Instant::now`].
#[derive(Debug, Clone, Copy, Default)]
pub struct SystemClock;

impl Clock for SystemClock {
    fn now(&self) -> Instant {
        Instant::now()
    }
}

/// A failure surfaced by [`BrickManager::take_error`](crate::BrickManager::take_error):
/// the first failure since the last call, and how many more followed it.
#[derive(Debug, Clone, Error)]
#[error("reading the {kind} of node {key:?} failed: {error}{}", more_suffix(*.more))]
pub struct StreamError {
    /// The node.
    pub key: NodeKey,
    /// What failed to be read.
    pub kind: FetchKind,
    /// Why.
    #[source]
    pub error: Arc<LoadError>,
    /// Further failures (any node, any kind) since this one, not reported
    /// separately.
    pub more: u64,
}

fn more_suffix(more: u64) -> String {
    if more == 0 {
        String::new()
    } else {
        format!(" (and {more} more failures)")
    }
}

/// Failure counts.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FailureCounts {
    /// Nodes whose metadata is failed now (not yet due for a retry).
    pub metadata_failed: u32,
    /// Nodes whose brick is failed now (not yet due for a retry).
    pub bricks_failed: u32,
    /// Metadata reads that failed, since the manager was created.
    pub metadata_errors: u64,
    /// Brick reads that failed, since the manager was created.
    pub brick_errors: u64,
    /// Of those, reads where the source panicked.
    pub panics: u64,
}

#[derive(Debug, Clone)]
struct Record {
    error: Arc<LoadError>,
    /// Consecutive failures (reset by an explicit retry).
    attempts: u32,
    retry_at: Option<Instant>,
    /// The back-off has passed (or a retry was asked for): the node may be
    /// requested again; the record stays to count consecutive failures.
    due: bool,
}

/// Failure bookkeeping of a manager.
#[derive(Debug, Default)]
pub(crate) struct Failures {
    records: HashMap<(FetchKind, NodeKey), Record>,
    policy: Option<RetryPolicy>,
    unreported: Option<StreamError>,
    counts: FailureCounts,
}

impl Failures {
    pub(crate) fn new(policy: Option<RetryPolicy>) -> Failures {
        Failures {
            policy,
            ..Failures::default()
        }
    }

    pub(crate) fn set_policy(&mut self, policy: Option<RetryPolicy>) {
        self.policy = policy;
    }

    /// Records a failed read at `now`; returns it as a [`StreamError`]. When
    /// `surface`, it becomes (or adds to) the error [`take_error`](Self::take_error)
    /// returns. A failure of a node already failed (and not yet due: a second job
    /// that was under way, e.g. a metadata read along with a parent's brick) is
    /// counted but neither lengthens the back-off nor is surfaced again.
    pub(crate) fn record(
        &mut self,
        kind: FetchKind,
        key: NodeKey,
        error: LoadError,
        now: Instant,
        surface: bool,
    ) -> StreamError {
        match kind {
            FetchKind::Metadata => self.counts.metadata_errors += 1,
            FetchKind::Brick => self.counts.brick_errors += 1,
        }
        if matches!(error, LoadError::Panicked { .. }) {
            self.counts.panics += 1;
        }
        let error = Arc::new(error);
        let e = StreamError {
            key,
            kind,
            error: error.clone(),
            more: 0,
        };
        let rec = self.records.entry((kind, key)).or_insert(Record {
            error: error.clone(),
            attempts: 0,
            retry_at: None,
            due: true,
        });
        if !rec.due {
            return e;
        }
        rec.error = error;
        rec.attempts = rec.attempts.saturating_add(1);
        rec.due = false;
        rec.retry_at = self
            .policy
            .and_then(|p| now.checked_add(p.delay(rec.attempts)));
        if surface {
            match &mut self.unreported {
                Some(first) => first.more += 1,
                None => self.unreported = Some(e.clone()),
            }
        }
        e
    }

    /// A read succeeded: the node's failure (if any) is forgotten.
    pub(crate) fn succeeded(&mut self, kind: FetchKind, key: NodeKey) {
        self.records.remove(&(kind, key));
    }

    /// Marks every failure whose back-off has passed as due; returns how many.
    pub(crate) fn wake(&mut self, now: Instant) -> usize {
        let mut n = 0;
        for r in self.records.values_mut() {
            if !r.due && r.retry_at.is_some_and(|t| t <= now) {
                r.due = true;
                n += 1;
            }
        }
        n
    }

    /// Makes a node's failures (both kinds) due now, restarting their back-off;
    /// returns whether it had any.
    pub(crate) fn retry(&mut self, key: NodeKey) -> bool {
        let mut any = false;
        for kind in [FetchKind::Metadata, FetchKind::Brick] {
            if let Some(r) = self.records.get_mut(&(kind, key)) {
                r.due = true;
                r.attempts = 0;
                any = true;
            }
        }
        any
    }

    /// Makes every failure due now, restarting the back-offs.
    pub(crate) fn retry_all(&mut self) {
        for r in self.records.values_mut() {
            r.due = true;
            r.attempts = 0;
        }
    }

    /// True while the node's read of `kind` is failed and not yet due.
    pub(crate) fn is_failed(&self, kind: FetchKind, key: NodeKey) -> bool {
        self.records.get(&(kind, key)).is_some_and(|r| !r.due)
    }

    /// The error of a failed (not yet due) read.
    pub(crate) fn error(&self, kind: FetchKind, key: NodeKey) -> Option<&Arc<LoadError>> {
        self.records
            .get(&(kind, key))
            .filter(|r| !r.due)
            .map(|r| &r.error)
    }

    /// The first failure since the last call, with the count of those after it.
    pub(crate) fn take_error(&mut self) -> Option<StreamError> {
        self.unreported.take()
    }

    /// True when no read is recorded as failed (due for a retry or not).
    pub(crate) fn is_empty(&self) -> bool {
        self.records.is_empty()
    }

    /// Failure counts (current and cumulative).
    pub(crate) fn counts(&self) -> FailureCounts {
        let mut c = self.counts;
        for ((kind, _), r) in &self.records {
            if !r.due {
                match kind {
                    FetchKind::Metadata => c.metadata_failed += 1,
                    FetchKind::Brick => c.bricks_failed += 1,
                }
            }
        }
        c
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use brickray_core::BrickError;
    use std::time::Duration;

    fn io(key: NodeKey) -> LoadError {
        LoadError::Source(BrickError::Io {
            key,
            source: std::io::Error::other("gone"),
        })
    }

    #[test]
    fn backs_off_exponentially_and_forgets_on_success() {
        let k = NodeKey::new(1, 0, 1, 0);
        let t0 = Instant::now();
        let mut f = Failures::new(Some(RetryPolicy::default()));
        f.record(FetchKind::Brick, k, io(k), t0, true);
        assert!(f.is_failed(FetchKind::Brick, k));
        assert!(!f.is_failed(FetchKind::Metadata, k));
        assert_eq!(f.wake(t0 + Duration::from_millis(999)), 0);
        assert_eq!(f.wake(t0 + Duration::from_secs(1)), 1);
        assert!(!f.is_failed(FetchKind::Brick, k));
        assert!(f.error(FetchKind::Brick, k).is_none());
        // Second consecutive failure: 2 s.
        let t1 = t0 + Duration::from_secs(1);
        f.record(FetchKind::Brick, k, io(k), t1, true);
        assert_eq!(f.wake(t1 + Duration::from_millis(1999)), 0);
        assert_eq!(f.wake(t1 + Duration::from_secs(2)), 1);
        f.succeeded(FetchKind::Brick, k);
        // After a success the back-off starts over.
        f.record(FetchKind::Brick, k, io(k), t1, true);
        assert_eq!(f.wake(t1 + Duration::from_secs(1)), 1);
        let c = f.counts();
        assert_eq!((c.brick_errors, c.bricks_failed), (3, 0));
    }

    #[test]
    fn a_duplicate_failure_neither_lengthens_the_back_off_nor_surfaces() {
        let k = NodeKey::new(2, 0, 1, 0);
        let t0 = Instant::now();
        let mut f = Failures::new(Some(RetryPolicy::default()));
        f.record(FetchKind::Metadata, k, io(k), t0, true);
        f.record(FetchKind::Metadata, k, io(k), t0, true);
        assert_eq!(f.take_error().map(|e| e.more), Some(0));
        assert_eq!(f.wake(t0 + Duration::from_secs(1)), 1);
        assert_eq!(f.counts().metadata_errors, 2);
    }

    #[test]
    fn surfaces_the_first_failure_once_and_counts_the_rest() {
        let t0 = Instant::now();
        let mut f = Failures::new(None);
        let keys: Vec<NodeKey> = (0..5).map(|x| NodeKey::new(3, x, 0, 0)).collect();
        for &k in &keys {
            f.record(FetchKind::Metadata, k, io(k), t0, true);
        }
        f.record(
            FetchKind::Brick,
            keys[0],
            LoadError::Panicked {
                key: keys[0],
                message: "boom".into(),
            },
            t0,
            true,
        );
        let e = f.take_error().unwrap();
        assert_eq!((e.key, e.kind, e.more), (keys[0], FetchKind::Metadata, 5));
        let msg = e.to_string();
        assert!(
            msg.contains("metadata") && msg.contains("and 5 more"),
            "{msg}"
        );
        assert!(f.take_error().is_none());
        // Without a policy nothing becomes due on its own.
        assert_eq!(f.wake(t0 + Duration::from_secs(1 << 30)), 0);
        let c = f.counts();
        assert_eq!(
            (
                c.metadata_failed,
                c.bricks_failed,
                c.metadata_errors,
                c.panics
            ),
            (5, 1, 5, 1)
        );
        assert!(f.retry(keys[0]));
        assert!(!f.retry(NodeKey::ROOT));
        assert_eq!(f.counts().metadata_failed, 4);
        f.retry_all();
        assert_eq!(f.counts().metadata_failed, 0);
        // Unsurfaced records do not touch the pending error.
        f.record(FetchKind::Brick, keys[1], io(keys[1]), t0, false);
        assert!(f.take_error().is_none());
    }
}
