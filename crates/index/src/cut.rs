//! Cut validation and encoding: a set of leaves tiling the unit cube becomes the
//! octree with neighbour pointers (ropes) of Gobbetti et al. 2008, section 5.1,
//! encoded as `u32` words (see [`crate::format`]).

use crate::format::{
    LEAF_RECORD_WORDS, MAX_LEVEL, MAX_NODES, MAX_WORDS, NULL, Splits, TAG_DATA, TAG_EMPTY,
    TAG_INNER, node_word, rope_word,
};
use brickray_core::brick::{CutLeaf, NodeKey};
use std::borrow::Borrow;
use thiserror::Error;

/// Why a cut cannot be encoded.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[non_exhaustive]
pub enum CutError {
    /// A leaf is deeper than [`MAX_LEVEL`].
    #[error("leaf {key:?} is deeper than the maximum level {max}")]
    LevelTooDeep {
        /// The leaf.
        key: NodeKey,
        /// The deepest level accepted.
        max: u8,
    },
    /// A leaf's position is outside `0..2^level` (per axis `0..2^halvings` with
    /// split masks).
    #[error("leaf {key:?} lies outside the unit cube")]
    PositionOutOfRange {
        /// The leaf.
        key: NodeKey,
    },
    /// Two leaves overlap: `outer` contains or equals `inner`.
    #[error("leaves {outer:?} and {inner:?} overlap")]
    Overlap {
        /// The coarser (or equal) leaf.
        outer: NodeKey,
        /// The finer (or equal) leaf.
        inner: NodeKey,
    },
    /// The region of `missing` is not covered by any leaf (the first such node in
    /// breadth-first order; the root for an empty cut).
    #[error("the cut leaves a gap: node {missing:?} is not covered")]
    Gap {
        /// A node whose region no leaf covers.
        missing: NodeKey,
    },
    /// The encoding would exceed the format's pointer fields.
    #[error("the index would need {nodes} nodes / {words} words, more than the format addresses")]
    TooLarge {
        /// Nodes needed.
        nodes: usize,
        /// Words needed.
        words: usize,
    },
}

/// Size figures of an encoded index.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct IndexStats {
    /// Octree nodes (inner and leaves).
    pub nodes: u32,
    /// Inner nodes.
    pub inner_nodes: u32,
    /// Leaves (`empty_leaves + data_leaves`).
    pub leaves: u32,
    /// Empty leaves.
    pub empty_leaves: u32,
    /// Data leaves.
    pub data_leaves: u32,
    /// Deepest leaf level.
    pub max_level: u8,
    /// Encoded words (`nodes + 7 * leaves`).
    pub words: u32,
}

impl IndexStats {
    /// Encoded size in bytes.
    pub fn bytes(&self) -> usize {
        self.words as usize * 4
    }
}

/// An encoded octree with ropes, ready to upload as a storage buffer.
#[derive(Debug, Clone, PartialEq)]
pub struct EncodedIndex {
    words: Vec<u32>,
    keys: Vec<NodeKey>,
    stats: IndexStats,
    splits: Splits,
}

impl EncodedIndex {
    /// The encoded words (upload these; `bytemuck::cast_slice` gives the bytes).
    pub fn words(&self) -> &[u32] {
        &self.words
    }

    /// Takes the encoded words.
    pub fn into_words(self) -> Vec<u32> {
        self.words
    }

    /// Size figures.
    pub fn stats(&self) -> IndexStats {
        self.stats
    }

    /// The key of node `index` (node indices are the ones in node and rope words).
    pub fn node_key(&self, index: u32) -> Option<NodeKey> {
        self.keys.get(index as usize).copied()
    }

    /// The split masks the index was encoded with.
    pub fn splits(&self) -> Splits {
        self.splits
    }

    /// The node index of `key`, if the node exists in the tree (leaf or inner).
    pub fn node_index(&self, key: NodeKey) -> Option<u32> {
        if key.level > MAX_LEVEL {
            return None;
        }
        let h = Halvings::new(self.splits);
        let mut node = 0u32;
        for d in 0..key.level {
            let word = *self.words.get(node as usize)?;
            if crate::format::node_tag(word) != TAG_INNER {
                return None;
            }
            node = crate::format::node_ptr(word) + h.child_index(key, d);
        }
        (self.keys.get(node as usize) == Some(&key)).then_some(node)
    }
}

/// Per-level halvings of a [`Splits`], for O(1) key arithmetic.
struct Halvings {
    splits: Splits,
    h: [[u32; 3]; MAX_LEVEL as usize + 2],
}

impl Halvings {
    fn new(splits: Splits) -> Halvings {
        let mut h = [[0u32; 3]; MAX_LEVEL as usize + 2];
        for l in 1..h.len() {
            let m = splits.mask(l as u32 - 1);
            h[l] = std::array::from_fn(|a| h[l - 1][a] + ((m >> a) & 1));
        }
        Halvings { splits, h }
    }

    /// Index, among the children of its level-`d` ancestor, of the level-`d+1`
    /// ancestor of `key`.
    fn child_index(&self, key: NodeKey, d: u8) -> u32 {
        let m = self.splits.mask(d as u32);
        let hk = self.h[key.level as usize];
        let hd = self.h[d as usize + 1];
        let p = [key.x, key.y, key.z];
        let (mut ci, mut bit) = (0u32, 0u32);
        for a in 0..3 {
            if m & (1 << a) != 0 {
                ci |= ((p[a] >> (hk[a] - hd[a])) & 1) << bit;
                bit += 1;
            }
        }
        ci
    }

    /// The level-`level` ancestor of `key`.
    fn ancestor(&self, key: NodeKey, level: u8) -> NodeKey {
        let hk = self.h[key.level as usize];
        let hl = self.h[level as usize];
        NodeKey::new(
            level,
            key.x >> (hk[0] - hl[0]),
            key.y >> (hk[1] - hl[1]),
            key.z >> (hk[2] - hl[2]),
        )
    }

    /// Whether `key`'s position lies in `0..2^halvings` per axis.
    fn in_range(&self, key: NodeKey) -> bool {
        let h = self.h[key.level as usize];
        [key.x, key.y, key.z]
            .iter()
            .zip(h)
            .all(|(&p, h)| (p as u64) < (1u64 << h))
    }
}

const NONE: u32 = u32::MAX;
const UNSET: u8 = 0;
const LEAF: u8 = 1;
const INNER: u8 = 2;

#[derive(Clone, Copy)]
struct ArenaNode {
    first_child: u32,
    state: u8,
    /// The brick slot of a data leaf.
    slot: Option<u32>,
}

const UNSET_NODE: ArenaNode = ArenaNode {
    first_child: NONE,
    state: UNSET,
    slot: None,
};

/// Validates a cut and encodes it. `leaves` yields [`CutLeaf`]s or references to
/// them (`encode_cut(&plan.cut)` with `cut: Vec<CutLeaf>`). Only each leaf's key
/// and slot matter: the [`EmptyReason`](brickray_core::brick::EmptyReason) of an
/// empty leaf and the priority are ignored.
///
/// `leaves` must tile the unit cube exactly: every point in exactly one leaf. The
/// result does not depend on the order of `leaves` (nodes are numbered breadth
/// first, children in child-index order). Runs in `O(sum of leaf levels)`.
pub fn encode_cut<I>(leaves: I) -> Result<EncodedIndex, CutError>
where
    I: IntoIterator,
    I::Item: Borrow<CutLeaf>,
{
    encode_cut_with(leaves, Splits::ALL)
}

/// [`encode_cut`] for an anisotropic octree: a node of level `l` has
/// `2^popcount(splits.mask(l))` children, consecutive, in child-index order
/// (`docs/index-format.md`). With [`Splits::ALL`] this is `encode_cut`.
pub fn encode_cut_with<I>(leaves: I, splits: Splits) -> Result<EncodedIndex, CutError>
where
    I: IntoIterator,
    I::Item: Borrow<CutLeaf>,
{
    let arena = insert(leaves, splits)?;
    let n = number(&arena, splits)?;
    let words = write_words(&arena, &n, splits);
    Ok(EncodedIndex {
        words,
        keys: n.keys,
        stats: n.stats,
        splits,
    })
}

/// Step 1: every leaf inserted into an arena octree; children are allocated
/// in blocks (8, or fewer along unsplit axes) when a node is first
/// subdivided. Overlaps, out-of-range keys and too-deep or too-large cuts are
/// refused here.
fn insert<I>(leaves: I, splits: Splits) -> Result<Vec<ArenaNode>, CutError>
where
    I: IntoIterator,
    I::Item: Borrow<CutLeaf>,
{
    let hv = Halvings::new(splits);
    let leaves = leaves.into_iter();
    let mut arena: Vec<ArenaNode> = Vec::with_capacity(leaves.size_hint().0 * 8 / 7 + 8);
    arena.push(UNSET_NODE);
    for leaf in leaves {
        let CutLeaf { key, kind, .. } = *leaf.borrow();
        if key.level > MAX_LEVEL {
            return Err(CutError::LevelTooDeep {
                key,
                max: MAX_LEVEL,
            });
        }
        if !hv.in_range(key) {
            return Err(CutError::PositionOutOfRange { key });
        }
        let mut cur = 0usize;
        for d in 0..key.level {
            match arena[cur].state {
                LEAF => {
                    return Err(CutError::Overlap {
                        outer: hv.ancestor(key, d),
                        inner: key,
                    });
                }
                UNSET => {
                    arena[cur].state = INNER;
                    arena[cur].first_child = arena.len() as u32;
                    let n = splits.child_count(d as u32) as usize;
                    arena.resize(arena.len() + n, UNSET_NODE);
                }
                _ => {}
            }
            let ci = hv.child_index(key, d);
            cur = (arena[cur].first_child + ci) as usize;
        }
        match arena[cur].state {
            LEAF => {
                return Err(CutError::Overlap {
                    outer: key,
                    inner: key,
                });
            }
            INNER => {
                return Err(CutError::Overlap {
                    outer: key,
                    inner: leaf_below(&arena, cur, key, splits),
                });
            }
            _ => {
                arena[cur].state = LEAF;
                arena[cur].slot = kind.slot();
            }
        }
        if arena.len() > MAX_NODES {
            return Err(CutError::TooLarge {
                nodes: arena.len(),
                words: 0,
            });
        }
    }
    Ok(arena)
}

/// A leaf inserted below the inner arena node `a` (of `key`): the first in
/// child order.
fn leaf_below(arena: &[ArenaNode], mut a: usize, key: NodeKey, splits: Splits) -> NodeKey {
    let mut below = key;
    while arena[a].state == INNER {
        let fc = arena[a].first_child as usize;
        let n = splits.child_count(below.level as u32) as usize;
        let ci = (0..n).find(|&i| arena[fc + i].state != UNSET).unwrap_or(0);
        a = fc + ci;
        below = splits.child(below, ci as u32);
    }
    below
}

/// The arena numbered breadth first.
struct Numbered {
    /// `order[q]` is the arena node numbered `q`.
    order: Vec<u32>,
    /// The key of node `q`.
    keys: Vec<NodeKey>,
    /// The number of node `q`'s first child (`NONE` for a leaf).
    first_child: Vec<u32>,
    stats: IndexStats,
}

/// Step 2: breadth-first numbering; the children of a node are consecutive
/// in both numberings. A gap (an unset node) and an index past
/// [`MAX_WORDS`] are refused here.
fn number(arena: &[ArenaNode], splits: Splits) -> Result<Numbered, CutError> {
    let nodes = arena.len();
    let mut order: Vec<u32> = Vec::with_capacity(nodes);
    let mut keys: Vec<NodeKey> = Vec::with_capacity(nodes);
    let mut first_child: Vec<u32> = vec![NONE; nodes];
    order.push(0);
    keys.push(NodeKey::ROOT);
    let mut stats = IndexStats::default();
    let mut q = 0usize;
    while q < order.len() {
        let a = &arena[order[q] as usize];
        match a.state {
            UNSET => return Err(CutError::Gap { missing: keys[q] }),
            INNER => {
                first_child[q] = order.len() as u32;
                let key = keys[q];
                for i in 0..splits.child_count(key.level as u32) {
                    order.push(a.first_child + i);
                    keys.push(splits.child(key, i));
                }
                stats.inner_nodes += 1;
            }
            _ => {
                stats.leaves += 1;
                match a.slot {
                    None => stats.empty_leaves += 1,
                    Some(_) => stats.data_leaves += 1,
                }
                stats.max_level = stats.max_level.max(keys[q].level);
            }
        }
        q += 1;
    }
    debug_assert_eq!(order.len(), nodes);
    let words_len = nodes + LEAF_RECORD_WORDS as usize * stats.leaves as usize;
    if words_len > MAX_WORDS {
        return Err(CutError::TooLarge {
            nodes,
            words: words_len,
        });
    }
    stats.nodes = nodes as u32;
    stats.words = words_len as u32;
    Ok(Numbered {
        order,
        keys,
        first_child,
        stats,
    })
}

/// Step 3: the words. Neighbours of every node (same-level node if it
/// exists, else the coarser leaf containing it), top-down in O(1) per face:
/// a child's neighbour across an inner face is its sibling; across an outer
/// face it is the parent's neighbour if that is a leaf, else that
/// neighbour's mirrored child. Along an axis the node is not split along,
/// both of a child's faces are outer faces and the neighbour's child has the
/// same index.
fn write_words(arena: &[ArenaNode], n: &Numbered, splits: Splits) -> Vec<u32> {
    let nodes = arena.len();
    let (keys, first_child) = (&n.keys, &n.first_child);
    let mut neigh: Vec<[u32; 6]> = vec![[NULL; 6]; nodes];
    let mut words: Vec<u32> = vec![0; n.stats.words as usize];
    let mut record = nodes as u32;
    for q in 0..nodes {
        let fc = first_child[q];
        if fc != NONE {
            words[q] = node_word(TAG_INNER, fc);
            let pn = neigh[q];
            let m = splits.mask(keys[q].level as u32);
            for ci in 0..splits.child_count(keys[q].level as u32) {
                let mut cn = [NULL; 6];
                for (face, slot) in cn.iter_mut().enumerate() {
                    let axis = face as u32 / 2;
                    let positive = face & 1 == 1;
                    let split = m & (1 << axis) != 0;
                    // This axis's bit in the child index (its rank among the split axes).
                    let rank = (m & ((1 << axis) - 1)).count_ones();
                    let bit = (ci >> rank) & 1;
                    let mirrored = if split { ci ^ (1 << rank) } else { ci };
                    *slot = if split && positive == (bit == 0) {
                        fc + mirrored
                    } else {
                        let m = pn[face];
                        if m == NULL {
                            NULL
                        } else if first_child[m as usize] != NONE {
                            first_child[m as usize] + mirrored
                        } else {
                            m
                        }
                    };
                }
                neigh[(fc + ci) as usize] = cn;
            }
        } else {
            let a = &arena[n.order[q] as usize];
            let (tag, data) = match a.slot {
                None => (TAG_EMPTY, NULL),
                Some(slot) => (TAG_DATA, slot),
            };
            words[q] = node_word(tag, record);
            let r = record as usize;
            words[r] = data;
            for face in 0..6 {
                let m = neigh[q][face];
                words[r + 1 + face] = if m == NULL {
                    NULL
                } else {
                    rope_word(m, keys[m as usize].level)
                };
            }
            record += LEAF_RECORD_WORDS;
        }
    }
    words
}
