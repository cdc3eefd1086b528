//! Bookkeeping of the GPU brick pool: a 3D texture atlas cut into a grid of
//! equally sized slots, one brick each, with frame-stamped LRU eviction.
//!
//! No GPU object lives here; the renderer owns the texture and uploads the bricks
//! this bookkeeping assigns to slots.

use brickray_core::{NodeKey, NodeMap};
use thiserror::Error;

mod limits;
pub use limits::PoolLimits;

/// Index of a slot in the pool, `0..slot_count()`.
pub type SlotId = u32;

/// Errors from the brick pool.
#[derive(Debug, Error, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum PoolError {
    /// The budget and device limits leave room for no slot at all.
    #[error(
        "brick pool has no slot: budget {budget_bytes} B for slots of {slot_bytes} B \
         ({stored_side}^3 voxels) within a max 3D texture dimension of {max_dim}"
    )]
    NoSlots {
        /// The pool budget in bytes.
        budget_bytes: u64,
        /// Bytes of one slot.
        slot_bytes: u64,
        /// Stored voxels per brick side.
        stored_side: u32,
        /// Largest 3D texture dimension.
        max_dim: u32,
    },
    /// Every slot holds a brick used in the current frame.
    #[error("all {slots} brick-pool slots are in use by frame {frame}")]
    Full {
        /// Number of slots.
        slots: u32,
        /// The current frame.
        frame: u64,
    },
}

#[derive(Debug, Clone, Copy)]
struct Slot {
    key: Option<NodeKey>,
    frame: u64,
    tick: u64,
    /// Pinned for good (the coarse floor): never an eviction candidate.
    pinned: bool,
    /// Neighbours in the eviction order ([`NIL`] at either end, and for a slot
    /// not in it: free or pinned for good).
    prev: SlotId,
    next: SlotId,
}

/// No slot (the ends of the eviction order).
const NIL: SlotId = SlotId::MAX;

/// The result of [`BrickPool::allocate`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Allocation {
    /// The slot now holding the node.
    pub slot: SlotId,
    /// True when the node was already resident (nothing to upload).
    pub resident: bool,
    /// The node whose brick was evicted to make room, if any.
    pub evicted: Option<NodeKey>,
}

/// Slot allocation over a fixed grid with LRU eviction that never evicts a slot
/// stamped with the current frame.
#[derive(Debug)]
pub struct BrickPool {
    grid: [u32; 3],
    stored_side: u32,
    slots: Vec<Slot>,
    map: NodeMap<SlotId>,
    /// The eviction order: the occupied slots not pinned for good, a list
    /// linked through the slots by increasing `tick` (every stamp moves its
    /// slot to the tail, in constant time), the least recently used at the
    /// head.
    head: SlotId,
    tail: SlotId,
    free: Vec<SlotId>,
    tick: u64,
    evictions: u64,
    /// Bumped whenever a node gets or loses a slot.
    changes: u64,
    pinned: u32,
}

impl BrickPool {
    /// A pool sized by `limits`.
    pub fn new(limits: PoolLimits) -> Result<BrickPool, PoolError> {
        let grid = limits.grid().ok_or(PoolError::NoSlots {
            budget_bytes: limits.budget_bytes,
            slot_bytes: limits.slot_bytes,
            stored_side: limits.stored_side,
            max_dim: limits.max_dim,
        })?;
        Ok(BrickPool::with_grid(grid, limits.stored_side))
    }

    /// A pool with an explicit slot grid (each axis >= 1).
    pub fn with_grid(grid: [u32; 3], stored_side: u32) -> BrickPool {
        let grid = grid.map(|g| g.max(1));
        let n = grid.iter().product::<u32>();
        BrickPool {
            grid,
            stored_side,
            slots: vec![
                Slot {
                    key: None,
                    frame: 0,
                    tick: 0,
                    pinned: false,
                    prev: NIL,
                    next: NIL,
                };
                n as usize
            ],
            map: NodeMap::default(),
            head: NIL,
            tail: NIL,
            free: (0..n).rev().collect(),
            tick: 0,
            evictions: 0,
            changes: 0,
            pinned: 0,
        }
    }

    /// The slot grid `[sx, sy, sz]`.
    pub fn grid(&self) -> [u32; 3] {
        self.grid
    }

    /// Number of slots.
    pub fn slot_count(&self) -> u32 {
        self.slots.len() as u32
    }

    /// Occupied slots.
    pub fn occupied(&self) -> u32 {
        self.map.len() as u32
    }

    /// Stored voxels per brick side.
    pub fn stored_side(&self) -> u32 {
        self.stored_side
    }

    /// Voxel size of the atlas texture, `grid * stored_side`.
    pub fn atlas_dims(&self) -> [u32; 3] {
        self.grid.map(|g| g * self.stored_side)
    }

    /// Voxel offset of a slot's brick inside the atlas.
    pub fn slot_offset(&self, slot: SlotId) -> [u32; 3] {
        let [sx, sy, _] = self.grid;
        [slot % sx, (slot / sx) % sy, slot / (sx * sy)].map(|c| c * self.stored_side)
    }

    /// The slot holding `key`, if resident.
    pub fn slot_of(&self, key: NodeKey) -> Option<SlotId> {
        self.map.get(&key).copied()
    }

    /// The node held by a slot.
    pub fn key_of(&self, slot: SlotId) -> Option<NodeKey> {
        self.slots.get(slot as usize).and_then(|s| s.key)
    }

    /// True when the node is resident.
    pub fn contains(&self, key: NodeKey) -> bool {
        self.map.contains_key(&key)
    }

    /// True when the slot was used in `frame`.
    pub fn is_pinned(&self, slot: SlotId, frame: u64) -> bool {
        self.slots
            .get(slot as usize)
            .is_some_and(|s| s.key.is_some() && s.frame == frame)
    }

    /// Bricks evicted so far.
    pub fn evictions(&self) -> u64 {
        self.evictions
    }

    /// A count that changes whenever a node gets or loses a slot (not when
    /// one is touched or pinned): equal counts, the same residents.
    pub fn changes(&self) -> u64 {
        self.changes
    }

    /// Takes an occupied slot out of the eviction order.
    fn unlink(&mut self, slot: SlotId) {
        let Slot { prev, next, .. } = self.slots[slot as usize];
        match prev {
            NIL => self.head = next,
            p => self.slots[p as usize].next = next,
        }
        match next {
            NIL => self.tail = prev,
            n => self.slots[n as usize].prev = prev,
        }
        let s = &mut self.slots[slot as usize];
        (s.prev, s.next) = (NIL, NIL);
    }

    /// Puts a slot into the eviction order after every slot of a smaller
    /// tick: at the tail when its tick is the newest (every stamp), else
    /// found from the tail (a slot unpinned for good).
    fn link(&mut self, slot: SlotId) {
        let tick = self.slots[slot as usize].tick;
        let mut prev = self.tail;
        while prev != NIL && self.slots[prev as usize].tick > tick {
            prev = self.slots[prev as usize].prev;
        }
        let next = match prev {
            NIL => std::mem::replace(&mut self.head, slot),
            p => std::mem::replace(&mut self.slots[p as usize].next, slot),
        };
        match next {
            NIL => self.tail = slot,
            n => self.slots[n as usize].prev = slot,
        }
        let s = &mut self.slots[slot as usize];
        (s.prev, s.next) = (prev, next);
    }

    fn stamp(&mut self, slot: SlotId, frame: u64) {
        self.tick += 1;
        let pinned = self.slots[slot as usize].pinned;
        if !pinned {
            self.unlink(slot);
        }
        let s = &mut self.slots[slot as usize];
        s.tick = self.tick;
        s.frame = s.frame.max(frame);
        if !pinned {
            self.link(slot);
        }
    }

    /// Pins a resident node for good: its slot is never evicted (until
    /// [`unpin`](Self::unpin), [`evict`](Self::evict) or [`clear`](Self::clear)).
    /// Returns its slot, `None` when not resident.
    pub fn pin(&mut self, key: NodeKey) -> Option<SlotId> {
        let slot = self.slot_of(key)?;
        let s = &mut self.slots[slot as usize];
        if !s.pinned {
            s.pinned = true;
            self.pinned += 1;
            self.unlink(slot);
        }
        Some(slot)
    }

    /// Makes a pinned node evictable again (least recently used first).
    pub fn unpin(&mut self, key: NodeKey) {
        if let Some(slot) = self.slot_of(key) {
            let s = &mut self.slots[slot as usize];
            if s.pinned {
                s.pinned = false;
                self.pinned -= 1;
                self.link(slot);
            }
        }
    }

    /// True when `key` is resident and pinned for good.
    pub fn is_pinned_for_good(&self, key: NodeKey) -> bool {
        self.slot_of(key)
            .is_some_and(|s| self.slots[s as usize].pinned)
    }

    /// Slots pinned for good.
    pub fn pinned_count(&self) -> u32 {
        self.pinned
    }

    /// Marks a resident node used in `frame` (pinning it for that frame) and
    /// returns its slot.
    pub fn touch(&mut self, key: NodeKey, frame: u64) -> Option<SlotId> {
        let slot = self.slot_of(key)?;
        self.stamp(slot, frame);
        Some(slot)
    }

    /// A slot for `key`, used in `frame`: its current slot when resident, else a
    /// free slot, else the least recently used slot not used in `frame` (whose node
    /// is evicted). `Err(Full)` when every slot is pinned by `frame`.
    pub fn allocate(&mut self, key: NodeKey, frame: u64) -> Result<Allocation, PoolError> {
        if let Some(slot) = self.touch(key, frame) {
            return Ok(Allocation {
                slot,
                resident: true,
                evicted: None,
            });
        }
        let (slot, evicted) = if let Some(slot) = self.free.pop() {
            (slot, None)
        } else {
            // Ticks and frames grow together, so the oldest tick has the oldest frame.
            let slot = self.head;
            if slot == NIL || self.slots[slot as usize].frame >= frame {
                return Err(PoolError::Full {
                    slots: self.slot_count(),
                    frame,
                });
            }
            self.unlink(slot);
            let old = self.slots[slot as usize].key.take();
            if let Some(old) = old {
                self.map.remove(&old);
                self.evictions += 1;
            }
            (slot, old)
        };
        self.changes += 1;
        let s = &mut self.slots[slot as usize];
        s.key = Some(key);
        s.frame = frame;
        self.tick += 1;
        s.tick = self.tick;
        self.link(slot);
        self.map.insert(key, slot);
        Ok(Allocation {
            slot,
            resident: false,
            evicted,
        })
    }

    /// Frees the slot of `key`; returns it.
    pub fn evict(&mut self, key: NodeKey) -> Option<SlotId> {
        let slot = self.map.remove(&key)?;
        if self.slots[slot as usize].pinned {
            self.slots[slot as usize].pinned = false;
            self.pinned -= 1;
        } else {
            self.unlink(slot);
        }
        let s = &mut self.slots[slot as usize];
        s.key = None;
        self.free.push(slot);
        self.changes += 1;
        Some(slot)
    }

    /// Frees every slot.
    pub fn clear(&mut self) {
        let keys: Vec<NodeKey> = self.map.keys().copied().collect();
        for k in keys {
            self.evict(k);
        }
    }

    /// Resident nodes and their slots (unordered).
    pub fn resident(&self) -> impl Iterator<Item = (NodeKey, SlotId)> + '_ {
        self.map.iter().map(|(k, s)| (*k, *s))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::collections::HashSet;

    fn k(i: u32) -> NodeKey {
        NodeKey::new(5, i, 0, 0)
    }

    #[test]
    fn slot_offsets_tile_the_atlas() {
        let p = BrickPool::with_grid([3, 2, 2], 10);
        assert_eq!(p.atlas_dims(), [30, 20, 20]);
        let offs: HashSet<[u32; 3]> = (0..p.slot_count()).map(|s| p.slot_offset(s)).collect();
        assert_eq!(offs.len(), 12);
        assert!(
            offs.iter()
                .all(|o| (0..3).all(|a| o[a] + 10 <= p.atlas_dims()[a]))
        );
        assert_eq!(p.slot_offset(4), [10, 10, 0]);
    }

    #[test]
    fn lru_eviction_skips_current_frame_and_full_is_err() {
        let mut p = BrickPool::with_grid([2, 1, 1], 4);
        let a = p.allocate(k(0), 1).unwrap();
        let b = p.allocate(k(1), 1).unwrap();
        assert_ne!(a.slot, b.slot);
        assert!(!a.resident && a.evicted.is_none());
        // Both pinned by frame 1.
        assert_eq!(
            p.allocate(k(2), 1),
            Err(PoolError::Full { slots: 2, frame: 1 })
        );
        // Frame 2: touch k1, so k0 is the LRU victim.
        p.touch(k(1), 2);
        let c = p.allocate(k(2), 2).unwrap();
        assert_eq!(c.evicted, Some(k(0)));
        assert_eq!(c.slot, a.slot);
        assert!(p.allocate(k(1), 2).unwrap().resident);
        assert!(p.allocate(k(3), 2).is_err());
        assert_eq!(p.occupied(), 2);
        assert_eq!(p.evict(k(1)), Some(b.slot));
        assert_eq!(p.allocate(k(3), 2).unwrap().slot, b.slot);
    }

    proptest! {
        /// Random frames of random accesses: a slot touched or allocated in the
        /// current frame is never taken away within that frame; the mapping stays a
        /// bijection; Full only when all slots are pinned.
        #[test]
        fn never_evicts_current_frame(
            frames in prop::collection::vec(prop::collection::vec(0u32..20, 0..12), 1..30),
            n_slots in 1u32..8,
        ) {
            let mut p = BrickPool::with_grid([n_slots, 1, 1], 2);
            for (f, accesses) in frames.iter().enumerate() {
                let frame = f as u64 + 1;
                let mut used: NodeMap<SlotId> = NodeMap::default();
                for &i in accesses {
                    let key = k(i);
                    match p.allocate(key, frame) {
                        Ok(a) => {
                            if let Some(e) = a.evicted { prop_assert!(!used.contains_key(&e)); }
                            if let Some(&s) = used.get(&key) { prop_assert_eq!(s, a.slot); prop_assert!(a.resident); }
                            used.insert(key, a.slot);
                        }
                        Err(PoolError::Full { .. }) => {
                            prop_assert!(used.len() as u32 == n_slots);
                        }
                        Err(e) => prop_assert!(false, "{e}"),
                    }
                    // Everything used this frame is still resident where it was.
                    for (&key, &s) in &used {
                        prop_assert_eq!(p.slot_of(key), Some(s));
                        prop_assert!(p.is_pinned(s, frame));
                    }
                    let slots: HashSet<SlotId> = p.resident().map(|r| r.1).collect();
                    prop_assert_eq!(slots.len() as u32, p.occupied());
                }
            }
        }
    }

    impl BrickPool {
        /// The eviction order from the head, walked both ways (they must
        /// agree).
        fn eviction_order(&self) -> Vec<SlotId> {
            let mut forward = Vec::new();
            let mut s = self.head;
            while s != NIL {
                forward.push(s);
                s = self.slots[s as usize].next;
            }
            let mut backward = Vec::new();
            let mut s = self.tail;
            while s != NIL {
                backward.push(s);
                s = self.slots[s as usize].prev;
            }
            backward.reverse();
            assert_eq!(forward, backward);
            forward
        }
    }

    /// A model of the pool: slots as (key, frame, tick, pinned for good), the
    /// victim found by scanning for the smallest tick among the occupied
    /// slots not pinned for good.
    #[derive(Default)]
    struct Model {
        slots: Vec<Option<(NodeKey, u64, u64, bool)>>,
        free: Vec<SlotId>,
        tick: u64,
    }

    impl Model {
        fn new(n: u32) -> Model {
            Model {
                slots: vec![None; n as usize],
                free: (0..n).rev().collect(),
                tick: 0,
            }
        }

        fn slot_of(&self, key: NodeKey) -> Option<SlotId> {
            (0..self.slots.len() as u32)
                .find(|&i| self.slots[i as usize].is_some_and(|s| s.0 == key))
        }

        fn touch(&mut self, key: NodeKey, frame: u64) -> Option<SlotId> {
            let i = self.slot_of(key)?;
            self.tick += 1;
            let s = self.slots[i as usize].as_mut().unwrap();
            (s.1, s.2) = (s.1.max(frame), self.tick);
            Some(i)
        }

        fn order(&self) -> Vec<SlotId> {
            let mut v: Vec<(u64, SlotId)> = (0..self.slots.len() as u32)
                .filter_map(|i| match self.slots[i as usize] {
                    Some((_, _, tick, false)) => Some((tick, i)),
                    _ => None,
                })
                .collect();
            v.sort();
            v.into_iter().map(|(_, i)| i).collect()
        }

        fn allocate(&mut self, key: NodeKey, frame: u64) -> Result<Allocation, PoolError> {
            if let Some(slot) = self.touch(key, frame) {
                return Ok(Allocation {
                    slot,
                    resident: true,
                    evicted: None,
                });
            }
            let full = PoolError::Full {
                slots: self.slots.len() as u32,
                frame,
            };
            let (slot, evicted) = match self.free.pop() {
                Some(i) => (i, None),
                None => {
                    let &i = self.order().first().ok_or(full.clone())?;
                    let old = self.slots[i as usize].unwrap();
                    if old.1 >= frame {
                        return Err(full);
                    }
                    (i, Some(old.0))
                }
            };
            self.tick += 1;
            self.slots[slot as usize] = Some((key, frame, self.tick, false));
            Ok(Allocation {
                slot,
                resident: false,
                evicted,
            })
        }
    }

    proptest! {
        /// Allocations, touches, evictions and pins for good against the
        /// model: the same slots, residency and victims, and the linked
        /// eviction order equal to the model's order by tick.
        #[test]
        fn matches_a_model_of_the_eviction_order(
            ops in prop::collection::vec((0u8..6, 0u32..10), 1..300),
            n_slots in 1u32..7,
        ) {
            let mut p = BrickPool::with_grid([n_slots, 1, 1], 2);
            let mut m = Model::new(n_slots);
            let mut frame = 1u64;
            for (op, i) in ops {
                let key = k(i);
                match op {
                    0 | 1 => prop_assert_eq!(p.allocate(key, frame), m.allocate(key, frame)),
                    2 => prop_assert_eq!(p.touch(key, frame), m.touch(key, frame)),
                    3 => {
                        let slot = m.slot_of(key);
                        if let Some(i) = slot {
                            m.slots[i as usize] = None;
                            m.free.push(i);
                        }
                        prop_assert_eq!(p.evict(key), slot);
                    }
                    4 => {
                        let slot = m.slot_of(key);
                        if let Some(i) = slot {
                            m.slots[i as usize].as_mut().unwrap().3 = true;
                        }
                        prop_assert_eq!(p.pin(key), slot);
                    }
                    _ => {
                        if i % 2 == 0 {
                            if let Some(i) = m.slot_of(key) {
                                m.slots[i as usize].as_mut().unwrap().3 = false;
                            }
                            p.unpin(key);
                        } else {
                            frame += 1;
                        }
                    }
                }
                prop_assert_eq!(p.eviction_order(), m.order());
                let pinned = m.slots.iter().flatten().filter(|s| s.3).count() as u32;
                prop_assert_eq!(p.pinned_count(), pinned);
                prop_assert_eq!(p.occupied(), m.slots.iter().flatten().count() as u32);
            }
        }
    }

    #[test]
    fn pinned_slots_are_never_evicted() {
        let mut p = BrickPool::with_grid([3, 1, 1], 1);
        p.allocate(k(0), 1).unwrap();
        assert_eq!(p.pin(k(0)), Some(0).map(|_| p.slot_of(k(0)).unwrap()));
        assert_eq!(p.pinned_count(), 1);
        for f in 2..20u64 {
            let a = p.allocate(k(f as u32), f).unwrap();
            assert_ne!(a.evicted, Some(k(0)));
            assert!(p.contains(k(0)));
        }
        // Every other slot pinned by the frame: full, the floor stays.
        p.allocate(k(100), 30).unwrap();
        p.allocate(k(101), 30).unwrap();
        assert!(matches!(
            p.allocate(k(102), 30),
            Err(PoolError::Full { .. })
        ));
        p.unpin(k(0));
        assert_eq!(p.pinned_count(), 0);
        assert_eq!(p.allocate(k(102), 31).unwrap().evicted, Some(k(0)));
    }
}
