//! Node metadata known to the manager, bounded: entries not used for the
//! longest are forgotten once there are more than the capacity (a random
//! camera over a 65536^3 volume meets new nodes every frame; an unbounded map
//! grew by about 8 kB a frame). A forgotten entry is fetched again by the loader
//! when a view needs it; the root is never forgotten.

use brickray_core::{NodeInfo, NodeKey, NodeMap};
use std::sync::atomic::{AtomicU64, Ordering};

#[derive(Debug)]
struct Entry {
    info: NodeInfo,
    /// The frame it was last used in (atomic so lookups need only `&self`).
    used: AtomicU64,
}

/// Metadata by node, LRU by frame of last use within a capacity.
#[derive(Debug)]
pub(crate) struct MetaCache {
    map: NodeMap<Entry>,
    frame: u64,
    capacity: usize,
    evicted: u64,
}

impl MetaCache {
    /// A cache of at most `capacity` entries (at least 64).
    pub(crate) fn new(capacity: usize) -> MetaCache {
        MetaCache {
            map: NodeMap::default(),
            frame: 0,
            capacity: capacity.max(64),
            evicted: 0,
        }
    }

    /// Starts a frame: lookups from now on mark entries as used in `frame`.
    pub(crate) fn begin_frame(&mut self, frame: u64) {
        self.frame = frame;
    }

    /// The node's metadata, marking it used this frame.
    pub(crate) fn get(&self, key: NodeKey) -> Option<NodeInfo> {
        let e = self.map.get(&key)?;
        e.used.store(self.frame, Ordering::Relaxed);
        Some(e.info.clone())
    }

    /// True when the node's metadata is known (not marking it used).
    pub(crate) fn contains(&self, key: NodeKey) -> bool {
        self.map.contains_key(&key)
    }

    /// Records a node's metadata as used this frame.
    pub(crate) fn insert(&mut self, key: NodeKey, info: NodeInfo) {
        self.map.insert(
            key,
            Entry {
                info,
                used: AtomicU64::new(self.frame),
            },
        );
    }

    /// Forgets the entries used longest ago, down to three quarters of the
    /// capacity, once there are more than the capacity (amortised O(1) per
    /// insert). Entries used this frame and the root are kept.
    pub(crate) fn trim(&mut self) {
        if self.map.len() <= self.capacity {
            return;
        }
        let target = self.capacity * 3 / 4;
        let mut ages: Vec<u64> = self
            .map
            .values()
            .map(|e| e.used.load(Ordering::Relaxed))
            .collect();
        let k = self.map.len() - target;
        let (_, cut, _) = ages.select_nth_unstable(k - 1);
        let cut = (*cut).min(self.frame.saturating_sub(1));
        let before = self.map.len();
        self.map
            .retain(|key, e| *key == NodeKey::ROOT || e.used.load(Ordering::Relaxed) > cut);
        self.evicted += (before - self.map.len()) as u64;
    }

    /// Changes the capacity (applied at the next trim).
    pub(crate) fn set_capacity(&mut self, capacity: usize) {
        self.capacity = capacity.max(64);
    }

    /// Entries held.
    pub(crate) fn len(&self) -> usize {
        self.map.len()
    }

    /// Entries forgotten so far.
    pub(crate) fn evicted(&self) -> u64 {
        self.evicted
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use brickray_core::NodeKind;

    fn info() -> NodeInfo {
        NodeInfo {
            kind: NodeKind::Data,
            min: 0.0,
            max: 1.0,
            error: None,
            parent_error: None,
            channels: Default::default(),
            channel_errors: None,
        }
    }

    #[test]
    fn stays_within_capacity_and_keeps_what_is_used() {
        let mut m = MetaCache::new(100);
        m.insert(NodeKey::ROOT, info());
        let hot = NodeKey::new(3, 1, 2, 3);
        for frame in 1..=50u64 {
            m.begin_frame(frame);
            for x in 0..20u32 {
                m.insert(NodeKey::new(10, x + 20 * frame as u32, 0, 0), info());
            }
            if frame == 1 {
                m.insert(hot, info());
            }
            assert!(m.get(hot).is_some(), "frame {frame}");
            m.trim();
            assert!(m.len() <= 100, "{}", m.len());
            assert!(m.contains(NodeKey::ROOT));
        }
        assert!(m.evicted() > 800);
        // The newest entries are kept, the oldest forgotten.
        assert!(m.contains(NodeKey::new(10, 20 * 50, 0, 0)));
        assert!(!m.contains(NodeKey::new(10, 20, 0, 0)));
    }
}
