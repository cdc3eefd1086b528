//! Encoding: rope targets, boundary NULLs, layout, stats, invalid cuts, speed.

mod common;

use brickray_core::brick::NodeKey;
use brickray_index::format::{
    LEAF_RECORD_WORDS, MAX_LEVEL, NULL, TAG_DATA, TAG_EMPTY, TAG_INNER, decode_rope, node_ptr,
    node_tag,
};
use brickray_index::{CutError, CutLeaf, EmptyReason, EncodedIndex, LeafKind, encode_cut};
use common::{Rng, random_cut, shuffle, uniform_cut};
use proptest::prelude::*;
use std::collections::HashMap;

/// Faces in encoding order: (axis, step).
const FACES: [(usize, i64); 6] = [(0, -1), (0, 1), (1, -1), (1, 1), (2, -1), (2, 1)];

/// The rope of `leaf` across `face`, decoded: `None` = NULL, else the target's key.
fn rope_target(index: &EncodedIndex, leaf: NodeKey, face: usize) -> Option<NodeKey> {
    let w = index.words();
    let node = index.node_index(leaf).expect("leaf in tree");
    let word = w[node as usize];
    assert_ne!(node_tag(word), TAG_INNER, "{leaf:?} is a leaf");
    let (target, level) = decode_rope(w[node_ptr(word) as usize + 1 + face])?;
    let key = index.node_key(target).expect("rope points at a node");
    assert_eq!(key.level, level, "rope level field");
    Some(key)
}

/// The rope target by definition (section 5.1): the same-level node across the
/// face if it exists in the tree (leaf or inner), else the coarser leaf that
/// contains it; NULL on the cube boundary.
fn expected_target(
    leaves: &HashMap<NodeKey, LeafKind>,
    index: &EncodedIndex,
    leaf: NodeKey,
    face: usize,
) -> Option<NodeKey> {
    let (axis, step) = FACES[face];
    let mut p = [leaf.x as i64, leaf.y as i64, leaf.z as i64];
    p[axis] += step;
    let n = 1i64 << leaf.level;
    if p[axis] < 0 || p[axis] >= n {
        return None;
    }
    let same = NodeKey::new(leaf.level, p[0] as u32, p[1] as u32, p[2] as u32);
    if index.node_index(same).is_some() {
        return Some(same);
    }
    let mut k = same;
    while let Some(parent) = k.parent() {
        k = parent;
        if leaves.contains_key(&k) {
            return Some(k);
        }
    }
    panic!("no leaf contains {same:?}");
}

fn check_all_ropes(cut: &[CutLeaf]) {
    let index = encode_cut(cut.iter().copied()).unwrap();
    let map: HashMap<_, _> = cut.iter().map(|l| (l.key, l.kind)).collect();
    for &CutLeaf {
        key: leaf, kind, ..
    } in cut
    {
        let node = index.node_index(leaf).unwrap();
        let word = index.words()[node as usize];
        let record = node_ptr(word) as usize;
        match kind {
            LeafKind::Empty(_) => {
                assert_eq!(node_tag(word), TAG_EMPTY);
                assert_eq!(index.words()[record], NULL);
            }
            LeafKind::Data { slot } => {
                assert_eq!(node_tag(word), TAG_DATA);
                assert_eq!(index.words()[record], slot);
            }
        }
        for face in 0..6 {
            let got = rope_target(&index, leaf, face);
            let want = expected_target(&map, &index, leaf, face);
            assert_eq!(got, want, "leaf {leaf:?} face {face}");
            if let Some(t) = got {
                assert!(t.level <= leaf.level, "ropes never point to finer nodes");
            }
        }
    }
}

#[test]
fn root_only_cut() {
    let index = encode_cut([CutLeaf::data(NodeKey::ROOT, 42)]).unwrap();
    assert_eq!(
        index.words(),
        &[(TAG_DATA << 30) | 1, 42, NULL, NULL, NULL, NULL, NULL, NULL]
    );
    let s = index.stats();
    assert_eq!(
        (
            s.nodes,
            s.inner_nodes,
            s.leaves,
            s.data_leaves,
            s.empty_leaves,
            s.words
        ),
        (1, 0, 1, 1, 0, 8)
    );
    assert_eq!(s.bytes(), 32);
}

#[test]
fn one_split_layout_and_ropes() {
    let cut: Vec<_> = NodeKey::ROOT
        .children()
        .into_iter()
        .map(|k| CutLeaf::data(k, 10 + k.child_index() as u32))
        .collect();
    let index = encode_cut(cut.clone()).unwrap();
    let w = index.words();
    assert_eq!(w.len(), 9 + 8 * LEAF_RECORD_WORDS as usize);
    assert_eq!(w[0], TAG_INNER << 30 | 1, "root points to children at 1..9");
    for i in 0..8u32 {
        assert_eq!(index.node_key(1 + i), Some(NodeKey::ROOT.child(i as u8)));
        // Leaf records in breadth-first order after the node words.
        assert_eq!(w[1 + i as usize], (TAG_DATA << 30) | (9 + 7 * i));
        assert_eq!(w[9 + 7 * i as usize], 10 + i);
    }
    // Child 0 (-x,-y,-z corner): -faces NULL, +faces to siblings 1, 2, 4.
    let c0 = NodeKey::ROOT.child(0);
    assert_eq!(rope_target(&index, c0, 0), None);
    assert_eq!(rope_target(&index, c0, 1), Some(NodeKey::ROOT.child(1)));
    assert_eq!(rope_target(&index, c0, 2), None);
    assert_eq!(rope_target(&index, c0, 3), Some(NodeKey::ROOT.child(2)));
    assert_eq!(rope_target(&index, c0, 4), None);
    assert_eq!(rope_target(&index, c0, 5), Some(NodeKey::ROOT.child(4)));
    // Rope word = level 1 << 27 | node index.
    let rec0 = node_ptr(w[1]) as usize;
    assert_eq!(w[rec0 + 2], (1 << 27) | 2);
    check_all_ropes(&cut);
}

#[test]
fn mixed_levels_ropes_point_to_same_level_inner_or_coarser_leaf() {
    // Root split; child 0 split again; child 1's child 0 split again (level 3).
    let c0 = NodeKey::ROOT.child(0);
    let c1 = NodeKey::ROOT.child(1);
    let c10 = c1.child(0);
    let mut cut = Vec::new();
    for k in NodeKey::ROOT.children() {
        if k != c0 && k != c1 {
            cut.push(CutLeaf::empty(k, EmptyReason::Empty));
        }
    }
    cut.extend(
        c0.children()
            .map(|k| CutLeaf::data(k, k.child_index() as u32)),
    );
    for k in c1.children() {
        if k != c10 {
            cut.push(CutLeaf::empty(k, EmptyReason::Culled));
        }
    }
    cut.extend(c10.children().map(|k| CutLeaf::data(k, 100)));
    let index = encode_cut(cut.clone()).unwrap();
    let g = |l, x, y, z| NodeKey::new(l, x, y, z);
    // Fine leaf (2,1,0,0) in child 0, +x: the same-level node (2,2,0,0) = c10 exists (inner).
    assert_eq!(rope_target(&index, g(2, 1, 0, 0), 1), Some(c10));
    // (2,1,1,0) +x: (2,2,1,0) is a leaf of c1 -> same level.
    assert_eq!(rope_target(&index, g(2, 1, 1, 0), 1), Some(g(2, 2, 1, 0)));
    // Level-3 leaf (3,4,0,0) -x: same-level (3,3,0,0) does not exist -> coarser leaf (2,1,0,0).
    assert_eq!(rope_target(&index, g(3, 4, 0, 0), 0), Some(g(2, 1, 0, 0)));
    // (3,5,1,1) +y: (3,5,2,1) missing -> leaf (2,2,1,0); +x: (3,6,1,1) missing -> (2,3,0,0).
    assert_eq!(rope_target(&index, g(3, 5, 1, 1), 3), Some(g(2, 2, 1, 0)));
    assert_eq!(rope_target(&index, g(3, 5, 1, 1), 1), Some(g(2, 3, 0, 0)));
    // Level-1 leaf (1,0,1,0) -y: same-level (1,0,0,0) = c0 is inner -> c0.
    assert_eq!(rope_target(&index, g(1, 0, 1, 0), 2), Some(c0));
    // Boundary faces are NULL.
    assert_eq!(rope_target(&index, g(3, 4, 0, 0), 2), None);
    assert_eq!(rope_target(&index, g(3, 4, 0, 0), 4), None);
    assert_eq!(rope_target(&index, g(1, 1, 1, 1), 1), None);
    check_all_ropes(&cut);
    let s = index.stats();
    assert_eq!(
        (s.inner_nodes, s.leaves, s.max_level),
        (4, 6 + 8 + 7 + 8, 3)
    );
    assert_eq!(s.nodes, 1 + 4 * 8);
    assert_eq!(s.words, s.nodes + 7 * s.leaves);
}

/// The encoder reads only each leaf's key and slot: why a leaf is empty and its
/// priority change nothing, and it takes the cache's cut as it is (`&[CutLeaf]`).
#[test]
fn empty_reason_and_priority_are_ignored() {
    let mut rng = Rng(11);
    let cut = random_cut(&mut rng, 4, 0.5, 0.5, 2000);
    let reasons = [
        EmptyReason::Empty,
        EmptyReason::Invisible,
        EmptyReason::Culled,
        EmptyReason::NotLoaded,
        EmptyReason::Failed,
    ];
    let varied: Vec<CutLeaf> = cut
        .iter()
        .enumerate()
        .map(|(i, l)| CutLeaf {
            kind: match l.kind {
                LeafKind::Empty(_) => LeafKind::Empty(reasons[i % reasons.len()]),
                data => data,
            },
            priority: i as f32 * 0.5,
            ..*l
        })
        .collect();
    assert_ne!(cut, varied);
    assert!(cut.iter().any(|l| !l.kind.is_data()));
    assert_eq!(encode_cut(&cut).unwrap(), encode_cut(&varied).unwrap());
}

#[test]
fn encoding_is_independent_of_input_order() {
    let mut rng = Rng(7);
    let cut = random_cut(&mut rng, 5, 0.5, 0.5, 3000);
    let a = encode_cut(cut.clone()).unwrap();
    let mut shuffled = cut.clone();
    shuffle(&mut rng, &mut shuffled);
    let b = encode_cut(shuffled).unwrap();
    assert_eq!(a, b);
}

#[test]
fn invalid_cuts_are_typed_errors() {
    let r = NodeKey::ROOT;
    let e = |k: NodeKey| CutLeaf::empty(k, EmptyReason::Empty);
    assert_eq!(
        encode_cut(Vec::<CutLeaf>::new()),
        Err(CutError::Gap { missing: r })
    );
    // One child missing.
    let cut: Vec<_> = r
        .children()
        .into_iter()
        .filter(|k| k.child_index() != 5)
        .map(e)
        .collect();
    assert_eq!(
        encode_cut(cut),
        Err(CutError::Gap {
            missing: r.child(5)
        })
    );
    // A deeper gap.
    let mut cut: Vec<_> = r.children().into_iter().skip(1).map(e).collect();
    cut.extend(r.child(0).children().into_iter().take(7).map(e));
    assert_eq!(
        encode_cut(cut),
        Err(CutError::Gap {
            missing: r.child(0).child(7)
        })
    );
    // Duplicate leaf.
    let mut cut: Vec<_> = r.children().into_iter().map(e).collect();
    cut.push(CutLeaf::data(r.child(3), 1));
    assert_eq!(
        encode_cut(cut),
        Err(CutError::Overlap {
            outer: r.child(3),
            inner: r.child(3)
        })
    );
    // Leaf inside an earlier coarser leaf.
    let mut cut: Vec<_> = r.children().into_iter().map(e).collect();
    cut.push(e(r.child(2).child(6).child(1)));
    assert_eq!(
        encode_cut(cut),
        Err(CutError::Overlap {
            outer: r.child(2),
            inner: r.child(2).child(6).child(1)
        })
    );
    // Coarser leaf after a finer one.
    let mut cut: Vec<_> = r.child(4).children().into_iter().map(e).collect();
    cut.push(e(r.child(4)));
    assert_eq!(
        encode_cut(cut),
        Err(CutError::Overlap {
            outer: r.child(4),
            inner: r.child(4).child(0)
        })
    );
    // Root plus anything.
    assert!(matches!(
        encode_cut([e(r), e(r.child(1))]),
        Err(CutError::Overlap { .. })
    ));
    // Bad levels and positions.
    let deep = NodeKey::new(MAX_LEVEL + 1, 0, 0, 0);
    assert_eq!(
        encode_cut([e(deep)]),
        Err(CutError::LevelTooDeep {
            key: deep,
            max: MAX_LEVEL
        })
    );
    let outside = NodeKey::new(2, 4, 0, 0);
    assert_eq!(
        encode_cut([e(outside)]),
        Err(CutError::PositionOutOfRange { key: outside })
    );
    let outside = NodeKey::new(0, 0, 0, 1);
    assert_eq!(
        encode_cut([e(outside)]),
        Err(CutError::PositionOutOfRange { key: outside })
    );
    // Messages render.
    let msg = encode_cut(Vec::<CutLeaf>::new()).unwrap_err().to_string();
    assert!(msg.contains("gap"), "{msg}");
}

#[test]
fn max_level_leaf_is_accepted() {
    // A chain of refinements down to MAX_LEVEL along the -x-y-z corner.
    let mut cut = Vec::new();
    let mut k = NodeKey::ROOT;
    while k.level < MAX_LEVEL {
        for c in k.children().into_iter().skip(1) {
            cut.push(CutLeaf::empty(c, EmptyReason::Invisible));
        }
        k = k.child(0);
    }
    cut.push(CutLeaf::data(k, 9));
    let index = encode_cut(cut.clone()).unwrap();
    assert_eq!(index.stats().max_level, MAX_LEVEL);
    check_all_ropes(&cut);
}

#[test]
fn encodes_100k_leaves_fast() {
    // Level 5 uniform (32768 leaves), every third leaf refined: ~98k leaves.
    let mut cut = Vec::new();
    for (i, l) in uniform_cut(5).into_iter().enumerate() {
        if i % 3 == 0 {
            cut.extend(l.key.children().map(|c| CutLeaf::new(c, l.kind)));
        } else {
            cut.push(l);
        }
    }
    assert!(cut.len() > 95_000);
    let mut best = f64::MAX;
    let mut index = None;
    for _ in 0..5 {
        let t = std::time::Instant::now();
        index = Some(encode_cut(cut.iter().copied()).unwrap());
        best = best.min(t.elapsed().as_secs_f64());
    }
    let s = index.unwrap().stats();
    eprintln!(
        "encode: {} leaves, {} nodes, {} words ({} KiB) in {:.2} ms",
        s.leaves,
        s.nodes,
        s.words,
        s.bytes() / 1024,
        best * 1e3
    );
    assert_eq!(s.leaves as usize, cut.len());
    // Generous bound (shared CI machine); release builds take a few ms.
    assert!(best < 0.25, "encoding took {best} s");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// Every rope of every leaf of random cuts matches the definition.
    #[test]
    fn ropes_match_definition(seed in any::<u64>(), depth in 0u8..=6, p_refine in 0.1f64..0.9, p_data in 0.0f64..1.0) {
        let mut rng = Rng(seed);
        let cut = random_cut(&mut rng, depth, p_refine, p_data, 2000);
        check_all_ropes(&cut);
    }

    /// Dropping a leaf is a gap; duplicating one is an overlap; never a panic.
    #[test]
    fn damaged_random_cuts_are_rejected(seed in any::<u64>(), depth in 1u8..=5) {
        let mut rng = Rng(seed);
        let cut = random_cut(&mut rng, depth, 0.6, 0.5, 2000);
        if cut.len() > 1 {
            let mut missing = cut.clone();
            let i = rng.below(cut.len() as u64) as usize;
            missing.remove(i);
            let gap = matches!(encode_cut(missing), Err(CutError::Gap { .. }));
            prop_assert!(gap);
            let mut dup = cut.clone();
            dup.push(cut[i]);
            shuffle(&mut rng, &mut dup);
            let overlap = matches!(encode_cut(dup), Err(CutError::Overlap { .. }));
            prop_assert!(overlap);
            // A child of a leaf (or the parent of a leaf) added.
            let mut extra = cut.clone();
            let CutLeaf { key: k, kind, .. } = cut[i];
            extra.push(CutLeaf::new(if k.level < MAX_LEVEL { k.child(0) } else { k.parent().unwrap() }, kind));
            shuffle(&mut rng, &mut extra);
            let overlap = matches!(encode_cut(extra), Err(CutError::Overlap { .. }));
            prop_assert!(overlap);
        }
    }
}
