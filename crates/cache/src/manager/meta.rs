//! Node metadata known to the manager, bounded: entries not used for the
//! longest are forgotten once there are more than the capacity (a random
//! camera over a 65536^3 volume meets new nodes every frame; an unbounded map
//! grew by about 8 kB a frame). A forgotten entry is fetched again by the loader
//! when a view needs it; the root is never forgotten.

use crate::refine::MetaClass;
use brickray_core::{NodeInfo, NodeKey, NodeMap};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

/// Up to eight nodes stored together: those whose coordinates differ only in
/// their lowest bit (an octree node's siblings). Refinement looks up every
/// child of each node it visits, eight in a row: with one map slot per group
/// those lookups touch one slot instead of eight scattered ones (the map
/// outgrows the processor's caches at cuts of thousands of bricks, and each
/// lookup was two or three cache misses).
#[derive(Debug, Default)]
struct Group {
    infos: [Option<Arc<NodeInfo>>; 8],
    /// The frame a member was last used in (atomic so lookups need only
    /// `&self`); a group is kept or forgotten whole.
    used: AtomicU64,
    /// The known members' classes under one classification
    /// ([`MetaCache::class`]): its stamp in the high 32 bits (0: none), then
    /// three bits per member (`CLASS_*`). Cleared when a member's metadata
    /// arrives.
    classes: AtomicU64,
}

/// A member's class in [`Group::classes`]: `CLASS_EMPTY`,
/// `CLASS_INVISIBLE`, `CLASS_DATA`, with `CLASS_UNIFORM` added to data.
const CLASS_EMPTY: u64 = 1;
const CLASS_INVISIBLE: u64 = 2;
const CLASS_DATA: u64 = 3;
const CLASS_UNIFORM: u64 = 4;

fn encode_class(c: MetaClass) -> u64 {
    match c {
        MetaClass::Empty => CLASS_EMPTY,
        MetaClass::Invisible => CLASS_INVISIBLE,
        MetaClass::Data { uniform } => CLASS_DATA | if uniform { CLASS_UNIFORM } else { 0 },
        // (Only known metadata is classed.)
        MetaClass::Pending | MetaClass::Failed => 0,
    }
}

fn decode_class(bits: u64) -> MetaClass {
    match bits & 3 {
        CLASS_EMPTY => MetaClass::Empty,
        CLASS_INVISIBLE => MetaClass::Invisible,
        _ => MetaClass::Data {
            uniform: bits & CLASS_UNIFORM != 0,
        },
    }
}

/// The group of `key` (the same level, each coordinate halved) and its
/// place in it: together a bijection of node keys, whatever the layout's
/// split masks.
fn group_of(key: NodeKey) -> (NodeKey, usize) {
    let group = NodeKey::new(key.level, key.x >> 1, key.y >> 1, key.z >> 1);
    (group, key.child_index() as usize)
}

/// Metadata by node, LRU by frame of last use within a capacity.
#[derive(Debug)]
pub(crate) struct MetaCache {
    map: NodeMap<Group>,
    /// Entries held (nodes, not groups).
    len: usize,
    frame: u64,
    capacity: usize,
    evicted: u64,
    /// Entries inserted (new or replaced) so far.
    inserted: u64,
}

impl MetaCache {
    /// What one entry costs in memory, about: its share of a group's slot in
    /// the map, and its shared `NodeInfo` (with the two reference counts).
    pub(crate) const ENTRY_BYTES: usize =
        (std::mem::size_of::<NodeKey>() + std::mem::size_of::<Group>() + 1) / 4
            + 2 * std::mem::size_of::<usize>()
            + std::mem::size_of::<NodeInfo>();

    /// A cache of at most `capacity` entries (at least 64).
    pub(crate) fn new(capacity: usize) -> MetaCache {
        MetaCache {
            map: NodeMap::default(),
            len: 0,
            frame: 0,
            capacity: capacity.max(64),
            evicted: 0,
            inserted: 0,
        }
    }

    /// Starts a frame: lookups from now on mark entries as used in `frame`.
    pub(crate) fn begin_frame(&mut self, frame: u64) {
        self.frame = frame;
    }

    /// The node's metadata, marking it used this frame.
    pub(crate) fn get(&self, key: NodeKey) -> Option<Arc<NodeInfo>> {
        let (group, i) = group_of(key);
        let g = self.map.get(&group)?;
        let info = g.infos[i].clone()?;
        g.used.store(self.frame, Ordering::Relaxed);
        Some(info)
    }

    /// The class of the node's metadata under the classification `stamp`
    /// (non-zero; the caller gives a new one whenever `visible` changes),
    /// marking it used this frame; `None` when not known. The classes of a
    /// group's members are computed together, once per stamp and arrival
    /// of metadata: refinement asks for the classes of every child of every
    /// node it visits, frame after frame, and reads the metadata itself
    /// only for the children it keeps.
    pub(crate) fn class(
        &self,
        key: NodeKey,
        stamp: u32,
        visible: &dyn Fn(&NodeInfo) -> bool,
    ) -> Option<MetaClass> {
        let (group, i) = group_of(key);
        let g = self.map.get(&group)?;
        g.infos[i].as_ref()?;
        g.used.store(self.frame, Ordering::Relaxed);
        let mut classes = g.classes.load(Ordering::Relaxed);
        if (classes >> 32) as u32 != stamp {
            classes = u64::from(stamp) << 32;
            for (m, info) in g.infos.iter().enumerate() {
                if let Some(info) = info {
                    classes |= encode_class(MetaClass::of(info, visible)) << (3 * m);
                }
            }
            g.classes.store(classes, Ordering::Relaxed);
        }
        Some(decode_class(classes >> (3 * i)))
    }

    /// True when the node's metadata is known (not marking it used).
    pub(crate) fn contains(&self, key: NodeKey) -> bool {
        let (group, i) = group_of(key);
        self.map.get(&group).is_some_and(|g| g.infos[i].is_some())
    }

    /// Records a node's metadata as used this frame.
    pub(crate) fn insert(&mut self, key: NodeKey, info: NodeInfo) {
        let (group, i) = group_of(key);
        let g = self.map.entry(group).or_default();
        if g.infos[i].replace(Arc::new(info)).is_none() {
            self.len += 1;
        }
        g.classes.store(0, Ordering::Relaxed);
        g.used.store(self.frame, Ordering::Relaxed);
        self.inserted += 1;
    }

    /// Forgets the groups used longest ago, down to three quarters of the
    /// capacity in entries, once there are more than the capacity (amortised
    /// O(log n) per insert). Groups used this frame and the root's are kept.
    pub(crate) fn trim(&mut self) {
        if self.len <= self.capacity {
            return;
        }
        let target = self.capacity * 3 / 4;
        let mut ages: Vec<(u64, usize)> = self
            .map
            .values()
            .map(|g| {
                let n = g.infos.iter().filter(|i| i.is_some()).count();
                (g.used.load(Ordering::Relaxed), n)
            })
            .collect();
        ages.sort_unstable();
        // The age at which forgetting every group up to it frees enough.
        let need = self.len - target;
        let mut freed = 0;
        let mut cut = 0;
        for (age, n) in ages {
            freed += n;
            cut = age;
            if freed >= need {
                break;
            }
        }
        let cut = cut.min(self.frame.saturating_sub(1));
        let (root, _) = group_of(NodeKey::ROOT);
        let mut removed = 0;
        self.map.retain(|key, g| {
            let keep = *key == root || g.used.load(Ordering::Relaxed) > cut;
            if !keep {
                removed += g.infos.iter().filter(|i| i.is_some()).count();
            }
            keep
        });
        self.len -= removed;
        self.evicted += removed as u64;
    }

    /// Changes the capacity (applied at the next trim).
    pub(crate) fn set_capacity(&mut self, capacity: usize) {
        self.capacity = capacity.max(64);
    }

    /// Entries held.
    pub(crate) fn len(&self) -> usize {
        self.len
    }

    /// Entries forgotten so far.
    pub(crate) fn evicted(&self) -> u64 {
        self.evicted
    }

    /// A count that changes whenever an entry is inserted or forgotten (not
    /// when one is read): equal counts, the same metadata.
    pub(crate) fn changes(&self) -> u64 {
        self.inserted + self.evicted
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

    fn info_of(key: NodeKey) -> NodeInfo {
        NodeInfo {
            min: key.x as f32,
            max: key.y as f32 + key.z as f32 * 1000.0,
            ..info()
        }
    }

    /// A node of kind `k` (0 empty, 1 uniform, 2 data) with values up to `max`.
    fn classed_info(k: u8, max: f32) -> NodeInfo {
        NodeInfo {
            kind: match k {
                0 => NodeKind::Empty,
                1 => NodeKind::Uniform(max),
                _ => NodeKind::Data,
            },
            max,
            ..info()
        }
    }

    proptest::proptest! {
        /// The kept classes are those of the metadata held now under the
        /// classification asked for: across new metadata for a member
        /// (inserted after its group's classes were kept), classifications
        /// changed and changed back under new stamps, and trims.
        #[test]
        fn kept_classes_follow_metadata_and_stamps(
            ops in proptest::collection::vec((0u8..4, 0u32..4, 0u32..2, 0u8..3, 0u8..4), 1..300),
        ) {
            let mut m = MetaCache::new(64);
            let mut model: std::collections::HashMap<NodeKey, NodeInfo> = Default::default();
            // The classification: visible when max > threshold; a new stamp
            // each time the threshold changes.
            let (mut threshold, mut stamp) = (0u8, 1u32);
            for (op, x, y, k, t) in ops {
                let key = NodeKey::new(4, x, y, 0);
                match op {
                    0 => {
                        let info = classed_info(k, f32::from(t));
                        m.insert(key, info.clone());
                        model.insert(key, info);
                    }
                    1 if t != threshold => {
                        threshold = t;
                        stamp += 1;
                    }
                    2 => {
                        m.trim();
                        model.retain(|k, _| m.contains(*k));
                    }
                    _ => {}
                }
                let visible = |i: &NodeInfo| i.max > f32::from(threshold);
                let want = model.get(&key).map(|i| MetaClass::of(i, &visible));
                proptest::prop_assert_eq!(m.class(key, stamp, &visible), want);
            }
        }
    }

    proptest::proptest! {
        /// Against a map of single entries: what is held, found and counted,
        /// across frames and trims; a trim keeps the root and what this frame
        /// used, and counts what it forgets.
        #[test]
        fn matches_a_map_of_entries(
            ops in proptest::collection::vec((0u8..4, 0u8..3, 0u32..6, 0u32..6, 0u32..3), 1..400),
            capacity in 64usize..120,
        ) {
            let mut m = MetaCache::new(capacity);
            let mut model = std::collections::HashMap::new();
            let mut used_now = std::collections::HashSet::new();
            let mut frame = 0;
            m.insert(NodeKey::ROOT, info_of(NodeKey::ROOT));
            model.insert(NodeKey::ROOT, ());
            for (op, level, x, y, z) in ops {
                let key = NodeKey::new(level, x, y, z);
                match op {
                    0 | 1 => {
                        m.insert(key, info_of(key));
                        model.insert(key, ());
                        used_now.insert(key);
                    }
                    2 => {
                        let got = m.get(key);
                        proptest::prop_assert_eq!(got.is_some(), model.contains_key(&key));
                        if let Some(i) = got {
                            proptest::prop_assert_eq!(&*i, &info_of(key));
                            used_now.insert(key);
                        }
                    }
                    _ => {
                        let before = m.len();
                        let evicted = m.evicted();
                        m.trim();
                        model.retain(|k, _| m.contains(*k));
                        proptest::prop_assert_eq!(m.evicted() - evicted, (before - m.len()) as u64);
                        proptest::prop_assert!(m.contains(NodeKey::ROOT));
                        for k in &used_now {
                            proptest::prop_assert!(m.contains(*k), "{:?} used this frame", k);
                        }
                        if before > capacity {
                            proptest::prop_assert!(m.len() <= capacity || m.len() <= used_now.len() * 8 + 8);
                        }
                        frame += 1;
                        m.begin_frame(frame);
                        used_now.clear();
                    }
                }
                proptest::prop_assert_eq!(m.len(), model.len());
                proptest::prop_assert_eq!(m.contains(key), model.contains_key(&key));
            }
        }
    }
}
