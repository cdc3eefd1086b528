//! Indexes of anisotropic octrees (split masks): the encoder with a variable
//! child count and the CPU twin against brute force, over random masks, cuts,
//! points and rays.

mod common;

use brickray_core::brick::NodeKey;
use brickray_index::{
    CutLeaf, DIR_EPSILON, EmptyReason, LeafHit, NodeBox, Ray, Splits, TraversalStatus, encode_cut,
    encode_cut_with, locate_leaf_with, traverse, traverse_with,
};
use common::{Rng, random_cut};
use glam::Vec3;
use std::collections::{HashMap, HashSet, VecDeque};

fn random_splits(rng: &mut Rng, levels: usize) -> (Splits, Vec<u8>) {
    let masks: Vec<u8> = (0..levels).map(|_| 1 + rng.below(7) as u8).collect();
    (Splits::from_masks(&masks).unwrap(), masks)
}

/// The root refined breadth first with the splits' child counts.
fn random_aniso_cut(rng: &mut Rng, splits: Splits, max_depth: u8, p: f64) -> Vec<CutLeaf> {
    let mut queue = VecDeque::from([NodeKey::ROOT]);
    let mut leaves = Vec::new();
    let mut slot = 0;
    while let Some(k) = queue.pop_front() {
        if k.level < max_depth
            && leaves.len() + queue.len() < 3000
            && (k.level == 0 || rng.chance(p))
        {
            for i in 0..splits.child_count(k.level as u32) {
                queue.push_back(splits.child(k, i));
            }
        } else if rng.chance(0.6) {
            slot += 1;
            leaves.push(CutLeaf::data(k, slot));
        } else {
            leaves.push(CutLeaf::empty(k, EmptyReason::Empty));
        }
    }
    leaves
}

/// Brute force: the leaves whose box holds `p` (half-open boxes).
fn leaves_at(cut: &[CutLeaf], splits: Splits, p: [f64; 3]) -> Vec<NodeKey> {
    cut.iter()
        .filter(|l| {
            let (lo, size) = splits.unit_box(l.key);
            (0..3).all(|a| lo[a] <= p[a] && p[a] < lo[a] + size[a])
        })
        .map(|l| l.key)
        .collect()
}

#[test]
fn masks_pack_and_the_octree_is_all_axes() {
    assert_eq!(Splits::from_masks(&[]), Some(Splits::ALL));
    assert_eq!(Splits::from_masks(&[7, 7, 7]), Some(Splits::ALL));
    assert_eq!(Splits::from_masks(&[0]), None);
    assert_eq!(Splits::from_masks(&[8]), None);
    let s = Splits::from_masks(&[7, 3, 4]).unwrap();
    assert_eq!((s.mask(0), s.mask(1), s.mask(2), s.mask(3)), (7, 3, 4, 7));
    assert_eq!((s.child_count(1), s.child_count(2)), (4, 2));
    assert_eq!(s.halvings(3), [2, 2, 2]);
    assert_eq!(s.halvings(2), [2, 2, 1]);
    assert_eq!(
        s.child(NodeKey::new(1, 1, 0, 1), 3),
        NodeKey::new(2, 3, 1, 1)
    );
    assert_eq!(
        s.child(NodeKey::new(2, 3, 1, 1), 1),
        NodeKey::new(3, 3, 1, 3)
    );
}

#[test]
fn octree_cuts_encode_the_same_with_all_splits() {
    let mut rng = Rng(7);
    for _ in 0..50 {
        let cut = random_cut(&mut rng, 5, 0.4, 0.5, 2000);
        let a = encode_cut(&cut).unwrap();
        let b = encode_cut_with(&cut, Splits::ALL).unwrap();
        assert_eq!(a.words(), b.words());
    }
}

#[test]
fn encoder_and_lookup_match_brute_force() {
    let mut rng = Rng(11);
    for case in 0..200 {
        let (splits, masks) = random_splits(&mut rng, 6);
        let cut = random_aniso_cut(&mut rng, splits, 6, 0.35);
        let index = encode_cut_with(&cut, splits)
            .unwrap_or_else(|e| panic!("case {case} masks {masks:?}: {e}"));
        let st = index.stats();
        assert_eq!(st.leaves as usize, cut.len());
        // Every leaf is findable by key, and its node word's record holds its slot.
        for l in &cut {
            let n = index.node_index(l.key).expect("leaf in the index");
            assert_eq!(index.node_key(n), Some(l.key));
        }
        // Points: the twin's descent finds the one leaf brute force finds.
        let slots: HashMap<NodeKey, Option<u32>> = cut.iter().map(|l| (l.key, l.slot())).collect();
        for _ in 0..64 {
            let p = [rng.f64(), rng.f64(), rng.f64()];
            let want = leaves_at(&cut, splits, p);
            assert_eq!(want.len(), 1, "masks {masks:?}: point {p:?} in {want:?}");
            let pf = Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32);
            let pd = pf.to_array().map(f64::from);
            let want = leaves_at(&cut, splits, pd)[0];
            let (leaf, word) =
                locate_leaf_with(index.words(), splits, NodeBox::ROOT, pf, Vec3::ONE).unwrap();
            assert_eq!(leaf.key_with(splits), want, "masks {masks:?} point {pf:?}");
            let (lo, size) = splits.unit_box(want);
            assert_eq!(leaf.box_min.to_array().map(f64::from), lo);
            assert_eq!(leaf.box_size.to_array().map(f64::from), size);
            let is_data =
                brickray_index::format::node_tag(word) == brickray_index::format::TAG_DATA;
            assert_eq!(is_data, slots[&want].is_some());
        }
        // Overlaps and gaps are still refused.
        let mut bad = cut.clone();
        bad.push(CutLeaf::empty(NodeKey::ROOT, EmptyReason::Empty));
        assert!(encode_cut_with(&bad, splits).is_err());
        let mut gap = cut.clone();
        if gap.len() > 1 {
            gap.remove(rng.below(gap.len() as u64) as usize);
            assert!(encode_cut_with(&gap, splits).is_err());
        }
    }
}

/// Exact (f64) segments of the ray through each leaf box.
fn oracle(cut: &[CutLeaf], splits: Splits, ray: &Ray) -> Vec<(NodeKey, f64, f64)> {
    let o = ray.origin.to_array().map(f64::from);
    let d = ray.dir.to_array().map(|c| {
        if c.abs() < DIR_EPSILON {
            0.0
        } else {
            f64::from(c)
        }
    });
    let mut out = Vec::new();
    'leaves: for l in cut {
        let (lo, size) = splits.unit_box(l.key);
        let (mut t0, mut t1) = (f64::from(ray.t_min), f64::from(ray.t_max));
        for a in 0..3 {
            let hi = lo[a] + size[a];
            if d[a] == 0.0 {
                if !(lo[a] <= o[a] && o[a] < hi) {
                    continue 'leaves;
                }
            } else {
                let ta = (lo[a] - o[a]) / d[a];
                let tb = (hi - o[a]) / d[a];
                t0 = t0.max(ta.min(tb));
                t1 = t1.min(ta.max(tb));
            }
        }
        if t1 > t0 {
            out.push((l.key, t0, t1));
        }
    }
    out.sort_by(|a, b| a.1.total_cmp(&b.1));
    out
}

#[test]
fn traversal_matches_brute_force() {
    const TINY: f64 = 2e-5;
    let mut rng = Rng(3);
    let mut rays = 0u64;
    let mut hits = 0u64;
    for _ in 0..150 {
        let (splits, masks) = random_splits(&mut rng, 6);
        let cut = random_aniso_cut(&mut rng, splits, 6, 0.35);
        let index = encode_cut_with(&cut, splits).unwrap();
        for r in 0..100 {
            let origin = Vec3::new(
                rng.range(-0.5, 1.5) as f32,
                rng.range(-0.5, 1.5) as f32,
                rng.range(-0.5, 1.5) as f32,
            );
            // Through a random point of the cube.
            let target = Vec3::new(rng.f64() as f32, rng.f64() as f32, rng.f64() as f32);
            let mut dir = target - origin;
            // Some axis-aligned and planar rays.
            if r % 5 == 0 {
                dir[rng.below(3) as usize] = 0.0;
            }
            if r % 7 == 0 {
                let a = rng.below(3) as usize;
                dir = Vec3::ZERO;
                dir[a] = if rng.chance(0.5) { 1.0 } else { -1.0 };
            }
            let ray = Ray::new(origin, dir);
            let want = oracle(&cut, splits, &ray);
            let mut it = traverse_with(index.words(), splits, ray, 10_000);
            let got: Vec<LeafHit> = it.by_ref().collect();
            assert_eq!(
                it.status(),
                TraversalStatus::Finished,
                "masks {masks:?} ray {ray:?}"
            );
            rays += 1;
            hits += got.len() as u64;
            let by_key: HashMap<NodeKey, (f64, f64)> =
                want.iter().map(|&(k, a, b)| (k, (a, b))).collect();
            let mut seen = HashSet::new();
            let mut last = f64::NEG_INFINITY;
            for (i, h) in got.iter().enumerate() {
                let k = h.leaf.key_with(splits);
                assert!(seen.insert(k), "{k:?} twice");
                if i > 0 {
                    assert!((h.t_enter - got[i - 1].t_exit).abs() <= 1e-5);
                }
                let (t0, t1) = (f64::from(h.t_enter), f64::from(h.t_exit));
                match by_key.get(&k) {
                    Some(&(a, b)) => {
                        let tol = |t: f64| 5e-5 * t.abs().max(1.0);
                        assert!(
                            (t0 - a).abs() <= tol(a) && (t1 - b).abs() <= tol(b),
                            "masks {masks:?} {k:?}: [{t0}, {t1}] vs [{a}, {b}]"
                        );
                        assert!(a > last, "order");
                        last = a;
                    }
                    None => assert!(t1 - t0 <= TINY, "masks {masks:?}: {k:?} not pierced"),
                }
            }
            for &(k, a, b) in &want {
                assert!(
                    seen.contains(&k) || b - a <= TINY,
                    "masks {masks:?}: missing {k:?}"
                );
            }
        }
    }
    eprintln!("{rays} rays, {hits} leaves");
    assert!(hits > rays);
}

#[test]
fn octree_traversal_is_unchanged_with_all_splits() {
    let mut rng = Rng(5);
    for _ in 0..30 {
        let cut = random_cut(&mut rng, 5, 0.4, 0.5, 2000);
        let index = encode_cut(&cut).unwrap();
        for _ in 0..50 {
            let ray = Ray::new(
                Vec3::new(
                    rng.range(-0.5, 1.5) as f32,
                    rng.range(-0.5, 1.5) as f32,
                    -0.5,
                ),
                Vec3::new(
                    rng.range(-1.0, 1.0) as f32,
                    rng.range(-1.0, 1.0) as f32,
                    1.0,
                ),
            );
            let a: Vec<LeafHit> = traverse(index.words(), ray, 10_000).collect();
            let b: Vec<LeafHit> = traverse_with(index.words(), Splits::ALL, ray, 10_000).collect();
            assert_eq!(a, b);
        }
    }
}
