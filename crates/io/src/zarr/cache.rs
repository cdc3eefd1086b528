//! Decoded chunks kept within a byte budget, least recently used first out.

use parking_lot::{Condvar, Mutex};
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

/// A chunk one thread is loading; others that want it wait for it.
#[derive(Debug, Default)]
struct Flight {
    done: Mutex<bool>,
    cv: Condvar,
}

impl Flight {
    fn wait(&self) {
        let mut done = self.done.lock();
        while !*done {
            self.cv.wait(&mut done);
        }
    }
}

/// Ends a flight however its load ends (a panic included), waking those
/// that wait.
struct Landing<'c> {
    cache: &'c ChunkCache,
    key: &'c ChunkKey,
}

impl Drop for Landing<'_> {
    fn drop(&mut self) {
        if let Some(f) = self.cache.inner.lock().flights.remove(self.key) {
            *f.done.lock() = true;
            f.cv.notify_all();
        }
    }
}

#[derive(Debug, Default)]
struct Inner {
    map: HashMap<ChunkKey, (Arc<Vec<u8>>, u64)>,
    flights: HashMap<ChunkKey, Arc<Flight>>,
    lru: BTreeMap<u64, ChunkKey>,
    tick: u64,
    bytes: u64,
    hits: u64,
    misses: u64,
    budget: u64,
}

impl Inner {
    /// The chunk if held, counted as a hit and made the most recently used.
    fn hit(&mut self, key: &ChunkKey) -> Option<Arc<Vec<u8>>> {
        let tick = self.tick + 1;
        let (v, old) = self.map.get_mut(key)?;
        let (v, old_tick) = (v.clone(), std::mem::replace(old, tick));
        self.tick = tick;
        self.lru.remove(&old_tick);
        self.lru.insert(tick, key.clone());
        self.hits += 1;
        Some(v)
    }

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
    #[cfg(test)]
    pub(crate) fn get(&self, key: &ChunkKey) -> Option<Arc<Vec<u8>>> {
        let mut g = self.inner.lock();
        let v = g.hit(key);
        if v.is_none() {
            g.misses += 1;
        }
        v
    }

    /// The chunk if held (a hit); a chunk not held is not counted (its
    /// [`get_or_load`](Self::get_or_load) counts it).
    pub(crate) fn held(&self, key: &ChunkKey) -> Option<Arc<Vec<u8>>> {
        self.inner.lock().hit(key)
    }

    /// The chunk: held (a hit), or loaded by `load` (a miss) and kept. One
    /// thread loads a chunk at a time: another that wants it meanwhile waits
    /// and takes what it kept (a hit), or loads it itself when the first load
    /// failed or kept nothing (a chunk over a quarter of the budget), so the
    /// neighbouring bricks and nodes read together fetch a chunk they share
    /// once.
    pub(crate) fn get_or_load<E>(
        &self,
        key: &ChunkKey,
        load: impl FnOnce() -> Result<Arc<Vec<u8>>, E>,
    ) -> Result<Arc<Vec<u8>>, E> {
        let flight = {
            let mut g = self.inner.lock();
            if let Some(v) = g.hit(key) {
                return Ok(v);
            }
            g.misses += 1;
            match g.flights.get(key) {
                Some(f) => Some(f.clone()),
                None => {
                    g.flights.insert(key.clone(), Arc::default());
                    None
                }
            }
        };
        if let Some(f) = flight {
            f.wait();
            let mut g = self.inner.lock();
            if let Some(v) = g.hit(key) {
                // Counted as a miss above; it was served.
                g.misses -= 1;
                return Ok(v);
            }
            drop(g);
            return load();
        }
        let _landing = Landing { cache: self, key };
        let v = load()?;
        self.insert(key.clone(), v.clone());
        Ok(v)
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

    #[test]
    fn a_chunk_wanted_by_many_threads_at_once_is_loaded_once() {
        use std::sync::atomic::{AtomicUsize, Ordering};
        let c = ChunkCache::new(1 << 20);
        let loads = AtomicUsize::new(0);
        let key = (0usize, vec![3u64]);
        std::thread::scope(|s| {
            for _ in 0..8 {
                s.spawn(|| {
                    let v = c
                        .get_or_load(&key, || {
                            loads.fetch_add(1, Ordering::SeqCst);
                            std::thread::sleep(std::time::Duration::from_millis(100));
                            Ok::<_, ()>(Arc::new(vec![7u8; 10]))
                        })
                        .unwrap();
                    assert_eq!(v[0], 7);
                });
            }
        });
        assert_eq!(loads.load(Ordering::SeqCst), 1);
        let st = c.stats();
        assert_eq!((st.hits, st.misses, st.chunks), (7, 1, 1));
    }

    #[test]
    fn a_failed_or_panicked_load_leaves_the_others_to_load_it() {
        let c = ChunkCache::new(1 << 20);
        let key = (1usize, vec![0u64]);
        // A panic in the load ends its flight: the next caller is not left
        // waiting and loads it.
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            c.get_or_load(&key, || -> Result<Arc<Vec<u8>>, ()> { panic!("decoder") })
        }));
        assert!(r.is_err());
        assert_eq!(
            c.get_or_load(&key, || Err::<Arc<Vec<u8>>, _>("down")),
            Err("down")
        );
        let v = c.get_or_load(&key, || Ok::<_, ()>(Arc::new(vec![1u8])));
        assert_eq!(*v.unwrap(), vec![1u8]);
        assert!(c.inner.lock().flights.is_empty());
    }
}
