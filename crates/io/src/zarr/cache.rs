//! Decoded chunks kept within a byte budget, least recently used first out.

use parking_lot::Mutex;
use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;

/// The default budget of an image's decoded-chunk cache: 256 MiB.
pub const CHUNK_CACHE_BYTES: u64 = 256 << 20;

/// What an image's decoded-chunk cache holds and has done.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ChunkCacheStats {
    /// Chunk reads answered from the cache.
    pub hits: u64,
    /// Chunk reads that decoded (and, remotely, fetched) the chunk.
    pub misses: u64,
    /// Decoded bytes held.
    pub bytes: u64,
    /// Chunks held.
    pub chunks: usize,
    /// The budget: `bytes` never exceeds it.
    pub budget: u64,
}

/// A chunk: its level and its unit indices (every array axis).
pub(crate) type ChunkKey = (usize, Vec<u64>);

#[derive(Debug, Default)]
struct Inner {
    map: HashMap<ChunkKey, (Arc<Vec<u8>>, u64)>,
    lru: BTreeMap<u64, ChunkKey>,
    tick: u64,
    bytes: u64,
    hits: u64,
    misses: u64,
    budget: u64,
}

impl Inner {
    fn evict_to(&mut self, budget: u64) {
        while self.bytes > budget {
            let Some((_, key)) = self.lru.pop_first() else {
                break;
            };
            if let Some((v, _)) = self.map.remove(&key) {
                self.bytes -= v.len() as u64;
            }
        }
    }
}

/// Decoded chunks by [`ChunkKey`], at most `budget` bytes of them; a chunk
/// larger than a quarter of the budget is used once and not kept.
#[derive(Debug)]
pub(crate) struct ChunkCache {
    inner: Mutex<Inner>,
}

impl ChunkCache {
    pub(crate) fn new(budget: u64) -> ChunkCache {
        ChunkCache {
            inner: Mutex::new(Inner {
                budget,
                ..Inner::default()
            }),
        }
    }

    /// The chunk if held (counted as a hit or a miss).
    pub(crate) fn get(&self, key: &ChunkKey) -> Option<Arc<Vec<u8>>> {
        let mut g = self.inner.lock();
        let tick = g.tick + 1;
        let Some((v, old)) = g.map.get_mut(key) else {
            g.misses += 1;
            return None;
        };
        let (v, old_tick) = (v.clone(), std::mem::replace(old, tick));
        g.tick = tick;
        g.lru.remove(&old_tick);
        g.lru.insert(tick, key.clone());
        g.hits += 1;
        Some(v)
    }

    /// Keeps a decoded chunk (evicting the least recently used to fit).
    pub(crate) fn insert(&self, key: ChunkKey, value: Arc<Vec<u8>>) {
        let mut g = self.inner.lock();
        let n = value.len() as u64;
        if n > g.budget / 4 || g.map.contains_key(&key) {
            return;
        }
        let budget = g.budget;
        g.evict_to(budget - n);
        g.tick += 1;
        let tick = g.tick;
        g.lru.insert(tick, key.clone());
        g.map.insert(key, (value, tick));
        g.bytes += n;
    }

    /// Changes the budget (dropping chunks to fit; 0 keeps none).
    pub(crate) fn set_budget(&self, budget: u64) {
        let mut g = self.inner.lock();
        g.budget = budget;
        g.evict_to(budget);
    }

    pub(crate) fn stats(&self) -> ChunkCacheStats {
        let g = self.inner.lock();
        ChunkCacheStats {
            hits: g.hits,
            misses: g.misses,
            bytes: g.bytes,
            chunks: g.map.len(),
            budget: g.budget,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_budget_holds_and_the_least_recently_used_goes_first() {
        let c = ChunkCache::new(400);
        let k = |i: u64| (0usize, vec![i]);
        for i in 0..4 {
            c.insert(k(i), Arc::new(vec![i as u8; 100]));
        }
        assert_eq!(c.stats().bytes, 400);
        // 0 used again: 1 is the oldest now
        assert_eq!(c.get(&k(0)).unwrap()[0], 0);
        c.insert(k(4), Arc::new(vec![4; 100]));
        let s = c.stats();
        assert_eq!((s.bytes, s.chunks), (400, 4));
        assert!(c.get(&k(1)).is_none());
        assert!(c.get(&k(0)).is_some() && c.get(&k(4)).is_some());
        // too large for the budget: not kept
        c.insert(k(9), Arc::new(vec![0; 101]));
        assert!(c.get(&k(9)).is_none());
        let s = c.stats();
        assert_eq!((s.hits, s.misses), (3, 2));
        c.set_budget(150);
        assert!(c.stats().bytes <= 150);
        c.set_budget(0);
        assert_eq!(c.stats().chunks, 0);
    }
}
