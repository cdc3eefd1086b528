//! The fade bookkeeping on random sequences of cuts: the displayed cut tiles,
//! every drawn brick was resident or available, weights are monotone and reach
//! their target within the configured frames, and fallbacks pinned in a pool
//! are never evicted while they fade.

use super::*;
use crate::pool::BrickPool;
use crate::refine::tests::assert_exact_cover;
use brickray_core::EmptyReason;
use proptest::prelude::*;

const LEVELS: u8 = 5;

fn leaf(key: NodeKey, data: bool) -> RefinedLeaf {
    RefinedLeaf {
        key,
        class: if data {
            NodeClass::Data
        } else {
            NodeClass::Empty(EmptyReason::Empty)
        },
        priority: 1.0,
        needs_upload: false,
    }
}

/// A random tiling: `bits` decide splits and data (a deterministic walk).
fn tiling(bits: &[u8], max_level: u8) -> Vec<RefinedLeaf> {
    let mut out = Vec::new();
    let mut i = 0usize;
    let mut next = || {
        let b = bits.get(i % bits.len().max(1)).copied().unwrap_or(0);
        i += 1;
        b
    };
    let mut stack = vec![NodeKey::ROOT];
    while let Some(k) = stack.pop() {
        let b = next();
        if k.level < max_level && b % 3 != 0 {
            stack.extend(k.children());
        } else {
            out.push(leaf(k, b % 5 != 4));
        }
    }
    out
}

fn keys(l: &[RefinedLeaf]) -> Vec<NodeKey> {
    l.iter().map(|l| l.key).collect()
}

fn data(l: &[RefinedLeaf]) -> HashSet<NodeKey> {
    l.iter().filter(|l| is_data(l)).map(|l| l.key).collect()
}

fn is_ancestor(a: NodeKey, mut k: NodeKey) -> bool {
    while let Some(p) = k.parent() {
        if p == a {
            return true;
        }
        k = p;
    }
    false
}

/// Runs `cuts`, each for `hold` frames, checking the per-frame invariants;
/// returns the fader.
fn run(cuts: &[Vec<RefinedLeaf>], hold: usize, step: f32) -> Fader {
    let mut f = Fader::new();
    // Bricks resident after the last frame (drawn or pinned as fallbacks).
    let mut resident: HashSet<NodeKey> = HashSet::new();
    let mut last: HashMap<NodeKey, (NodeKey, f32)> = HashMap::new();
    for cut in cuts {
        for frame in 0..hold {
            let d = f.advance(cut, Some(step));
            assert_exact_cover(&keys(&d.leaves), LEVELS);
            let available: HashSet<NodeKey> = resident.union(&data(cut)).copied().collect();
            let drawn = data(&d.leaves);
            for k in drawn.iter().chain(d.fallbacks().iter()) {
                assert!(available.contains(k), "{k:?} drawn without a brick");
            }
            let mut now = HashMap::new();
            for fade in &d.fades {
                assert!(drawn.contains(&fade.leaf));
                assert!(is_ancestor(fade.ancestor, fade.leaf));
                assert!((0.0..=1.0).contains(&fade.weight));
                // Same input, same pair: monotone toward the target.
                if let (true, Some(&(a, w))) = (frame > 0, last.get(&fade.leaf))
                    && a == fade.ancestor
                {
                    let merge = !data(cut).contains(&fade.leaf);
                    if merge {
                        assert!(fade.weight >= w, "merge weight fell");
                    } else {
                        assert!(fade.weight <= w, "split weight rose");
                    }
                }
                now.insert(fade.leaf, (fade.ancestor, fade.weight));
            }
            last = now;
            resident = drawn
                .union(&d.fallbacks().into_iter().collect())
                .copied()
                .collect();
        }
    }
    f
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(128))]

    #[test]
    fn fades_keep_a_drawable_tiling_and_end(
        seeds in prop::collection::vec(prop::collection::vec(any::<u8>(), 1..40), 1..6),
        n in 1u32..8,
        hold in 1usize..4,
    ) {
        let step = FadeDuration::Frames(n).step(0.0);
        let cuts: Vec<_> = seeds.iter().map(|b| tiling(b, LEVELS - 2)).collect();
        let mut f = run(&cuts, hold, step);
        // Held long enough, every fade ends within the configured frames and
        // the refined cut is drawn as it is.
        let last = cuts.last().unwrap();
        for _ in 0..n {
            f.advance(last, Some(step));
        }
        let d = f.advance(last, Some(step));
        prop_assert!(d.fades.is_empty());
        prop_assert_eq!(f.active(), 0);
        prop_assert_eq!(keys(&d.leaves), keys(last));
    }

    #[test]
    fn millis_steps_stay_in_range(ms in 0.0f32..10_000.0, dt in 0.0f64..1.0) {
        let s = FadeDuration::Millis(ms).step(dt);
        prop_assert!(s >= 1.0 / MAX_FADE_FRAMES as f32 && s <= 1.0);
    }

    /// The manager's pinning, on a pool just large enough: drawn leaves and
    /// fallbacks touched first, then the new ones allocated; a fallback is
    /// never evicted while its fade lasts.
    #[test]
    fn pinned_fallbacks_are_never_evicted(
        seeds in prop::collection::vec(prop::collection::vec(any::<u8>(), 1..40), 2..6),
        n in 2u32..6,
    ) {
        let cuts: Vec<_> = seeds.iter().map(|b| tiling(b, 3)).collect();
        let mut pool = BrickPool::with_grid([600, 1, 1], 1);
        let mut f = Fader::new();
        let mut frame = 0u64;
        for cut in &cuts {
            for _ in 0..3 {
                frame += 1;
                let d = f.advance(cut, Some(1.0 / n as f32));
                let need: Vec<NodeKey> = data(&d.leaves).into_iter().chain(d.fallbacks()).collect();
                let mut missing = Vec::new();
                for k in &need {
                    if pool.touch(*k, frame).is_none() {
                        missing.push(*k);
                    }
                }
                for k in missing {
                    let a = pool.allocate(k, frame).unwrap();
                    prop_assert!(!a.evicted.is_some_and(|e| need.contains(&e)));
                }
                for fade in &d.fades {
                    prop_assert!(pool.contains(fade.ancestor));
                    prop_assert!(pool.contains(fade.leaf));
                }
            }
        }
    }
}

#[test]
fn a_split_fades_in_over_the_configured_frames() {
    let root = vec![leaf(NodeKey::ROOT, true)];
    let kids: Vec<_> = NodeKey::ROOT.children().map(|k| leaf(k, true)).to_vec();
    let mut f = Fader::new();
    let step = FadeDuration::Frames(4).step(0.0);
    assert!(f.advance(&root, Some(step)).fades.is_empty());
    let mut w = Vec::new();
    for _ in 0..4 {
        let d = f.advance(&kids, Some(step));
        assert_eq!(keys(&d.leaves), keys(&kids));
        w.push(d.fades.first().map_or(0.0, |f| f.weight));
        assert!(d.fades.iter().all(|f| f.ancestor == NodeKey::ROOT));
    }
    assert_eq!(w, vec![0.75, 0.5, 0.25, 0.0]);
    assert_eq!(f.active(), 0);
}

#[test]
fn a_merge_keeps_the_children_until_faded() {
    let root = vec![leaf(NodeKey::ROOT, true)];
    let kids: Vec<_> = NodeKey::ROOT.children().map(|k| leaf(k, true)).to_vec();
    let mut f = Fader::new();
    f.advance(&kids, Some(0.5));
    let d = f.advance(&root, Some(0.5));
    assert_eq!(keys(&d.leaves), keys(&kids));
    assert!(
        d.fades
            .iter()
            .all(|f| f.weight == 0.5 && f.ancestor == NodeKey::ROOT)
    );
    let d = f.advance(&root, Some(0.5));
    assert_eq!(keys(&d.leaves), vec![NodeKey::ROOT]);
    assert!(d.fades.is_empty());
}

#[test]
fn a_reversed_split_fades_back_from_where_it_was() {
    let root = vec![leaf(NodeKey::ROOT, true)];
    let kids: Vec<_> = NodeKey::ROOT.children().map(|k| leaf(k, true)).to_vec();
    let mut f = Fader::new();
    f.advance(&root, Some(0.25));
    assert_eq!(f.advance(&kids, Some(0.25)).fades[0].weight, 0.75);
    assert_eq!(f.advance(&kids, Some(0.25)).fades[0].weight, 0.5);
    // Back out: the children stay, fading toward the root from 0.5.
    let d = f.advance(&root, Some(0.25));
    assert_eq!(keys(&d.leaves), keys(&kids));
    assert!(
        d.fades
            .iter()
            .all(|f| f.weight == 0.75 && f.ancestor == NodeKey::ROOT)
    );
    assert_eq!(
        keys(&f.advance(&root, Some(0.25)).leaves),
        vec![NodeKey::ROOT]
    );
}

#[test]
fn fades_off_switch_at_once() {
    let root = vec![leaf(NodeKey::ROOT, true)];
    let kids: Vec<_> = NodeKey::ROOT.children().map(|k| leaf(k, true)).to_vec();
    let mut f = Fader::new();
    f.advance(&root, None);
    let d = f.advance(&kids, None);
    assert!(d.fades.is_empty());
    assert_eq!(keys(&d.leaves), keys(&kids));
}
