//! Level-2 cache: prepared bricks in system memory, LRU within a byte budget.

use crate::prepared::PreparedBrick;
use brickray_core::{NodeKey, NodeMap};

/// No neighbour (the end of the recency list).
const NIL: u32 = u32::MAX;

/// A cached brick.
#[derive(Debug)]
struct Entry {
    key: NodeKey,
    data: PreparedBrick,
}

/// A slot's place in the recency list, by slot index. The links live apart
/// from the entries, 8 bytes a slot: marking a brick used rewrites three
/// slots' links, and in a table of links they stay in the processor's caches
/// where the entries do not (refinement marks every data child it finds in
/// CPU memory, every frame).
#[derive(Debug, Clone, Copy)]
struct Link {
    /// The next older entry.
    prev: u32,
    /// The next newer entry.
    next: u32,
}

/// Prepared bricks keyed by [`NodeKey`], evicted least-recently-used first once
/// their total size ([`PreparedBrick::bytes`]) exceeds the byte budget.
///
/// The most recently inserted brick is always kept, even when it alone exceeds the
/// budget, so a cache smaller than one brick still makes progress.
///
/// Recency is a doubly linked list through the entries' slots: marking a brick
/// used, inserting and evicting are O(1) and allocate nothing once the slots
/// exist (refinement marks every brick it finds in CPU memory, every frame).
#[derive(Debug)]
pub struct CpuCache {
    budget: u64,
    bytes: u64,
    map: NodeMap<u32>,
    /// Entries by slot; `None` slots are listed in `free`.
    slots: Vec<Option<Entry>>,
    /// Recency links by slot (a free slot's are stale).
    links: Vec<Link>,
    free: Vec<u32>,
    /// The least and the most recently used entry.
    oldest: u32,
    newest: u32,
    hits: u64,
    misses: u64,
    evictions: u64,
    /// Bumped whenever a brick comes or goes (not when one is used).
    changes: u64,
}

impl CpuCache {
    /// An empty cache holding at most `budget_bytes` of brick data.
    pub fn new(budget_bytes: u64) -> CpuCache {
        CpuCache {
            budget: budget_bytes,
            bytes: 0,
            map: NodeMap::default(),
            slots: Vec::new(),
            links: Vec::new(),
            free: Vec::new(),
            oldest: NIL,
            newest: NIL,
            hits: 0,
            misses: 0,
            evictions: 0,
            changes: 0,
        }
    }

    /// A count that changes whenever a brick is inserted or removed (not
    /// when one is looked up or touched): equal counts, the same bricks.
    pub fn changes(&self) -> u64 {
        self.changes
    }

    fn entry(&mut self, i: u32) -> &mut Entry {
        self.slots[i as usize]
            .as_mut()
            .expect("listed slots hold entries")
    }

    /// Takes slot `i` out of the recency list.
    fn unlink(&mut self, i: u32) {
        let Link { prev, next } = self.links[i as usize];
        if prev == NIL {
            self.oldest = next;
        } else {
            self.links[prev as usize].next = next;
        }
        if next == NIL {
            self.newest = prev;
        } else {
            self.links[next as usize].prev = prev;
        }
    }

    /// Puts slot `i` at the newest end of the recency list.
    fn push_newest(&mut self, i: u32) {
        let newest = self.newest;
        self.links[i as usize] = Link {
            prev: newest,
            next: NIL,
        };
        if newest == NIL {
            self.oldest = i;
        } else {
            self.links[newest as usize].next = i;
        }
        self.newest = i;
    }

    /// Looks a brick up, counting a hit or a miss and marking it most recently used.
    pub fn get(&mut self, key: NodeKey) -> Option<PreparedBrick> {
        if !self.lookup(key) {
            return None;
        }
        self.peek(key).cloned()
    }

    /// Whether the brick is cached, counting a hit or a miss and marking it
    /// most recently used, without copying it out.
    pub fn lookup(&mut self, key: NodeKey) -> bool {
        let found = self.touch(key);
        if found {
            self.hits += 1;
        } else {
            self.misses += 1;
        }
        found
    }

    /// Marks a brick most recently used without counting a hit or miss; returns
    /// whether it is cached.
    pub fn touch(&mut self, key: NodeKey) -> bool {
        match self.map.get(&key) {
            Some(&i) => {
                if i != self.newest {
                    self.unlink(i);
                    self.push_newest(i);
                }
                true
            }
            None => false,
        }
    }

    /// The brick, if cached, without touching it or counting.
    pub fn peek(&self, key: NodeKey) -> Option<&PreparedBrick> {
        let i = *self.map.get(&key)?;
        self.slots[i as usize].as_ref().map(|e| &e.data)
    }

    /// True when the brick is cached (no LRU update, no counting).
    pub fn contains(&self, key: NodeKey) -> bool {
        self.map.contains_key(&key)
    }

    /// Inserts (or replaces) a brick as most recently used, then evicts the least
    /// recently used others until the total fits the budget. Returns the evicted keys.
    pub fn insert(&mut self, key: NodeKey, data: PreparedBrick) -> Vec<NodeKey> {
        self.remove(key);
        self.bytes += data.bytes();
        let entry = Entry { key, data };
        let i = match self.free.pop() {
            Some(i) => {
                self.slots[i as usize] = Some(entry);
                i
            }
            None => {
                self.slots.push(Some(entry));
                self.links.push(Link {
                    prev: NIL,
                    next: NIL,
                });
                (self.slots.len() - 1) as u32
            }
        };
        self.map.insert(key, i);
        self.push_newest(i);
        self.changes += 1;
        self.evict_to_budget()
    }

    /// Changes the budget; shrinking evicts least recently used bricks (all but
    /// the newest) until the total fits. Returns the evicted keys.
    pub fn set_budget(&mut self, budget_bytes: u64) -> Vec<NodeKey> {
        self.budget = budget_bytes;
        self.evict_to_budget()
    }

    fn evict_to_budget(&mut self) -> Vec<NodeKey> {
        let mut evicted = Vec::new();
        while self.bytes > self.budget && self.map.len() > 1 && self.oldest != NIL {
            let victim = self.entry(self.oldest).key;
            self.remove(victim);
            self.evictions += 1;
            evicted.push(victim);
        }
        evicted
    }

    /// Removes a brick; returns it if it was cached.
    pub fn remove(&mut self, key: NodeKey) -> Option<PreparedBrick> {
        let i = self.map.remove(&key)?;
        self.unlink(i);
        let e = self.slots[i as usize].take()?;
        self.free.push(i);
        self.changes += 1;
        self.bytes -= e.data.bytes();
        Some(e.data)
    }

    /// Keys from least to most recently used.
    pub fn lru_order(&self) -> Vec<NodeKey> {
        let mut out = Vec::with_capacity(self.map.len());
        let mut i = self.oldest;
        while let Some(e) = self.slots.get(i as usize).and_then(Option::as_ref) {
            out.push(e.key);
            i = self.links[i as usize].next;
        }
        out
    }

    /// Number of cached bricks.
    pub fn len(&self) -> usize {
        self.map.len()
    }

    /// True when nothing is cached.
    pub fn is_empty(&self) -> bool {
        self.map.is_empty()
    }

    /// Bytes of cached brick data.
    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    /// The byte budget.
    pub fn budget(&self) -> u64 {
        self.budget
    }

    /// Counted lookups that found their brick.
    pub fn hits(&self) -> u64 {
        self.hits
    }

    /// Counted lookups that did not.
    pub fn misses(&self) -> u64 {
        self.misses
    }

    /// Bricks evicted for space so far.
    pub fn evictions(&self) -> u64 {
        self.evictions
    }

    /// `hits / (hits + misses)`, 1 when nothing was looked up.
    pub fn hit_rate(&self) -> f64 {
        let n = self.hits + self.misses;
        if n == 0 {
            1.0
        } else {
            self.hits as f64 / n as f64
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn k(i: u32) -> NodeKey {
        NodeKey::new(3, i, 0, 0)
    }

    fn b(n: usize) -> PreparedBrick {
        PreparedBrick {
            texels: vec![0u8; n].into(),
            sub_cells: Vec::new().into(),
            range: [0.0, 1.0],
            spread: None,
        }
    }

    #[test]
    fn lru_order_and_budget() {
        let mut c = CpuCache::new(300);
        assert!(c.insert(k(0), b(100)).is_empty());
        assert!(c.insert(k(1), b(100)).is_empty());
        assert!(c.insert(k(2), b(100)).is_empty());
        assert_eq!(c.lru_order(), vec![k(0), k(1), k(2)]);
        // Using 0 makes 1 the oldest.
        assert!(c.get(k(0)).is_some());
        assert_eq!(c.lru_order(), vec![k(1), k(2), k(0)]);
        assert_eq!(c.insert(k(3), b(100)), vec![k(1)]);
        assert_eq!(c.bytes(), 300);
        assert!(!c.contains(k(1)));
        // A large brick evicts several.
        assert_eq!(c.insert(k(4), b(250)), vec![k(2), k(0), k(3)]);
        assert_eq!(c.len(), 1);
        assert_eq!(c.hits(), 1);
        assert!(c.get(k(1)).is_none());
        assert_eq!(c.misses(), 1);
        assert!((c.hit_rate() - 0.5).abs() < 1e-12);
    }

    #[test]
    fn bytes_count_texels_and_sub_cells() {
        let mut c = CpuCache::new(1000);
        let brick = PreparedBrick {
            sub_cells: vec![[0.0, 1.0]; 8].into(),
            ..b(100)
        };
        c.insert(k(0), brick);
        assert_eq!(c.bytes(), 164);
    }

    #[test]
    fn shrinking_the_budget_evicts_lru_first() {
        let mut c = CpuCache::new(1000);
        for i in 0..5 {
            c.insert(k(i), b(100));
        }
        c.get(k(0));
        assert_eq!(c.set_budget(250), vec![k(1), k(2), k(3)]);
        assert_eq!(c.lru_order(), vec![k(4), k(0)]);
        assert_eq!((c.bytes(), c.budget()), (200, 250));
        // Growing evicts nothing.
        assert!(c.set_budget(10_000).is_empty());
    }

    #[test]
    fn oversized_brick_is_kept_alone() {
        let mut c = CpuCache::new(10);
        c.insert(k(0), b(5));
        assert_eq!(c.insert(k(1), b(50)), vec![k(0)]);
        assert!(c.contains(k(1)));
        assert_eq!(c.bytes(), 50);
    }

    #[test]
    fn replace_and_remove_keep_byte_count() {
        let mut c = CpuCache::new(1000);
        c.insert(k(0), b(10));
        c.insert(k(0), b(20));
        assert_eq!(c.bytes(), 20);
        assert_eq!(c.len(), 1);
        assert_eq!(c.remove(k(0)).map(|d| d.bytes()), Some(20));
        assert_eq!(c.bytes(), 0);
        assert!(c.is_empty());
    }

    proptest! {
        /// Against a model: the byte total never exceeds the budget (unless a single
        /// brick does), the evicted brick is always the least recently used.
        #[test]
        fn matches_lru_model(ops in prop::collection::vec((0u32..12, 1usize..60, 0u8..5), 1..200)) {
            let budget = 150usize;
            let mut c = CpuCache::new(budget as u64);
            let mut model: Vec<(NodeKey, usize)> = Vec::new(); // oldest first
            for (i, size, op) in ops {
                let key = k(i);
                let pos = model.iter().position(|e| e.0 == key);
                if op < 2 {
                    // A counted lookup, copying the brick out or not.
                    let hit = if op == 0 { c.get(key).is_some() } else { c.lookup(key) };
                    prop_assert_eq!(hit, pos.is_some());
                    if let Some(p) = pos { let e = model.remove(p); model.push(e); }
                } else if op == 2 {
                    let removed = c.remove(key).map(|d| d.bytes() as usize);
                    prop_assert_eq!(removed, pos.map(|p| model.remove(p).1));
                } else {
                    let evicted = c.insert(key, b(size));
                    model.retain(|e| e.0 != key);
                    model.push((key, size));
                    let mut expect = Vec::new();
                    while model.iter().map(|e| e.1).sum::<usize>() > budget && model.len() > 1 {
                        expect.push(model.remove(0).0);
                    }
                    prop_assert_eq!(evicted, expect);
                }
                prop_assert_eq!(c.lru_order(), model.iter().map(|e| e.0).collect::<Vec<_>>());
                prop_assert_eq!(c.bytes(), model.iter().map(|e| e.1 as u64).sum::<u64>());
            }
        }
    }
}
