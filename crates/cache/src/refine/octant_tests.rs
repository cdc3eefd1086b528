//! Octant-granular refinement ([`LodMetric::VisibleOctants`]) over the
//! synthetic ramp of `lod_tests`.

use super::lod_tests::{Cached, RampSource, Seen, cache_all, refine_limited};
use super::tests::{assert_exact_cover, ball_layout};
use super::*;
#[allow(unused_imports)]
use brickray_core::{Camera, NodeKind, RenderMode, TransferFunction, VolumeFrame};
use proptest::prelude::*;
use std::collections::{HashMap, HashSet};

fn ramp(seed: u64) -> (OctreeLayout, HashMap<NodeKey, NodeInfo>) {
    let layout = ball_layout(64);
    let mut src = RampSource {
        layout: layout.clone(),
        rough: 0.3,
        seed,
        reads: 0,
    };
    let meta = cache_all(&mut src);
    (layout, meta)
}

fn full_tf() -> TransferFunction {
    TransferFunction::from_points(
        &[(0.0, [0.1, 0.2, 0.9, 0.0]), (1.0, [0.9, 0.6, 0.1, 0.8])],
        256,
    )
}

/// The bricks an octant cut draws: leaves with their own brick and the
/// parents of borrowed leaves.
fn working_set(r: &Refinement, layout: &OctreeLayout) -> HashSet<NodeKey> {
    let mut set = HashSet::new();
    for l in &r.leaves {
        match l.class {
            NodeClass::Data => {
                set.insert(l.key);
            }
            NodeClass::Borrowed => {
                set.insert(layout.parent(l.key).expect("a borrowed leaf has a parent"));
            }
            NodeClass::Empty(_) => {}
        }
    }
    set
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// Whatever the view, budget and data: the leaves tile the cube exactly,
    /// the bricks drawn (own leaves and lenders) are what refinement counted
    /// and fit the budget, and a lender is never itself a leaf.
    #[test]
    fn octant_cuts_tile_the_cube_within_the_budget(
        seed in 0u64..1000,
        budget in 1u32..200,
        dist in 1.2f32..4.0,
        yaw in 0.0f32..6.2,
        seen in any::<bool>(),
    ) {
        let (layout, meta) = ramp(seed);
        let frame = VolumeFrame::centered(layout.volume.dims, [1.0; 3]);
        let cam = Camera::orbit(frame.center(), dist, yaw, 0.3);
        let metric = LodMetric::VisibleOctants { budget: 0.0 };
        let tf = full_tf();
        let r = if seen {
            let mut env = Seen { inner: Cached { meta }, scale: layout.volume_scale() };
            refine_limited(&layout, &mut env, &cam, &tf, metric, 0.0, budget)
        } else {
            refine_limited(&layout, &mut Cached { meta }, &cam, &tf, metric, 0.0, budget)
        };
        let keys: Vec<NodeKey> = r.leaves.iter().map(|l| l.key).collect();
        assert_exact_cover(&keys, layout.levels);
        let set = working_set(&r, &layout);
        prop_assert_eq!(set.len() as u32, r.data_leaves);
        prop_assert!(r.data_leaves <= budget);
        let leaves: HashSet<NodeKey> = keys.iter().copied().collect();
        for l in r.leaves.iter().filter(|l| l.class == NodeClass::Borrowed) {
            prop_assert!(!leaves.contains(&layout.parent(l.key).unwrap()));
        }
    }
}

/// At the same brick budget, octant refinement reaches finer levels where
/// the image looks (the visible half) than per-node refinement, which must
/// give a split all the children's bricks at once; and it gives the hidden
/// half no brick of its own below the root's children (they are drawn from
/// their parents). The test can fail: per-node refinement is the baseline.
#[test]
fn octants_spend_bricks_where_the_image_looks() {
    let (layout, meta) = ramp(5);
    let frame = VolumeFrame::centered(layout.volume.dims, [1.0; 3]);
    let cam = Camera::orbit(frame.center(), 2.0, 0.4, 0.2);
    let tf = full_tf();
    let scale = layout.volume_scale();
    let run = |metric| {
        let mut env = Seen {
            inner: Cached { meta: meta.clone() },
            scale,
        };
        refine_limited(&layout, &mut env, &cam, &tf, metric, 0.0, 40)
    };
    let per_node = run(LodMetric::VisibleError { budget: 0.0 });
    let octants = run(LodMetric::VisibleOctants { budget: 0.0 });
    let deepest_own = |r: &Refinement| {
        r.leaves
            .iter()
            .filter(|l| l.class == NodeClass::Data)
            .map(|l| l.key.level)
            .max()
            .unwrap_or(0)
    };
    assert!(
        deepest_own(&octants) > deepest_own(&per_node),
        "octants {} levels, per node {}",
        deepest_own(&octants),
        deepest_own(&per_node)
    );
    for k in working_set(&octants, &layout) {
        let (o, _) = k.unit_box();
        assert!(
            k.level <= 1 || o[0] / scale[0] < 0.5,
            "{k:?}: a brick in the hidden half"
        );
    }
    assert!(
        octants
            .leaves
            .iter()
            .any(|l| l.class == NodeClass::Borrowed),
        "nothing drawn from a parent"
    );
}

/// An octant whose brick is not in memory stays drawn from its parent and
/// is requested; the root must be available before anything is drawn.
#[test]
fn missing_octants_are_requested_and_drawn_from_their_parent() {
    struct RootOnly {
        inner: Cached,
        root_missing: bool,
    }
    impl RefineEnv for RootOnly {
        fn node(&mut self, key: NodeKey) -> MetaState {
            self.inner.node(key)
        }
        fn data(&mut self, key: NodeKey) -> DataState {
            if key == NodeKey::ROOT && !self.root_missing {
                DataState::OnGpu
            } else {
                DataState::Missing
            }
        }
    }
    let (layout, meta) = ramp(7);
    let frame = VolumeFrame::centered(layout.volume.dims, [1.0; 3]);
    let cam = Camera::orbit(frame.center(), 2.0, 0.4, 0.2);
    let tf = full_tf();
    let metric = LodMetric::VisibleOctants { budget: 0.0 };
    let mut env = RootOnly {
        inner: Cached { meta: meta.clone() },
        root_missing: false,
    };
    let r = refine_limited(&layout, &mut env, &cam, &tf, metric, 0.0, 100);
    assert_eq!(r.data_leaves, 1);
    assert!(!r.leaves.is_empty());
    assert!(
        r.leaves
            .iter()
            .all(|l| l.class == NodeClass::Borrowed && l.key.level == 1)
    );
    let asked: HashSet<NodeKey> = r.requests.iter().map(|q| q.key).collect();
    assert_eq!(
        asked,
        r.leaves.iter().map(|l| l.key).collect::<HashSet<_>>()
    );
    let mut env = RootOnly {
        inner: Cached { meta },
        root_missing: true,
    };
    let r = refine_limited(&layout, &mut env, &cam, &tf, metric, 0.0, 100);
    assert_eq!(r.leaves.len(), 1);
    assert_eq!(r.leaves[0].class, NodeClass::Empty(EmptyReason::NotLoaded));
    assert_eq!(r.requests[0].key, NodeKey::ROOT);
}

/// The memory counts a demotion when a node that had its own brick is drawn
/// from its parent, stops promoting it after `MAX_DEMOTIONS`, and forgets
/// everything when the view changes.
#[test]
fn octant_memory_counts_demotions_per_view() {
    let layout = ball_layout(64);
    let frame = VolumeFrame::centered(layout.volume.dims, [1.0; 3]);
    let tf = full_tf();
    let cam = Camera::orbit(frame.center(), 2.0, 0.4, 0.2);
    let views = Views::one(ViewGeometry::new(&layout, &cam, 1.0, 64, &frame));
    fn params<'a>(views: &'a Views, generation: u64, tf: &'a TransferFunction) -> RefineParams<'a> {
        RefineParams {
            views,
            generation,
            mode: RenderMode::Dvr,
            tf,
            channels: &[],
            tolerance_px: 0.0,
            metric: LodMetric::VisibleOctants { budget: 0.0 },
            max_data_leaves: 8,
            max_requests: 8,
            max_prefetch: u32::MAX,
            brick_upload_bytes: 1,
            lookahead: false,
        }
    }
    let c = NodeKey::ROOT.child(3);
    let leaf = |key, class| RefinedLeaf {
        key,
        class,
        priority: 1.0,
        needs_upload: false,
    };
    let own = Refinement {
        leaves: vec![leaf(c, NodeClass::Data)],
        ..Default::default()
    };
    let lent = Refinement {
        leaves: vec![leaf(c, NodeClass::Borrowed)],
        ..Default::default()
    };
    let mut m = OctantMemory::default();
    for i in 0..MAX_DEMOTIONS {
        m.begin(&params(&views, 1, &tf));
        assert!(m.may_promote(c), "demotion {i}");
        m.end(&own, &layout);
        // `c` and its ancestor, split to give `c` its brick.
        assert!(m.held(c) && m.held(NodeKey::ROOT));
        m.begin(&params(&views, 1, &tf));
        m.end(&lent, &layout);
        // Drawn from the root: the root holds its brick, `c` does not.
        assert!(m.held(NodeKey::ROOT) && !m.held(c));
    }
    assert!(!m.may_promote(c));
    // A moved camera: a new generation.
    m.begin(&params(&views, 2, &tf));
    assert!(m.may_promote(c) && !m.held(NodeKey::ROOT));
    // A node that got its brick but lends it to none of its children (all of
    // them have their own) is held too: losing it is a demotion.
    let d = c.child(5);
    let deeper = Refinement {
        leaves: vec![leaf(d.child(0), NodeClass::Data)],
        ..Default::default()
    };
    m.end(&deeper, &layout);
    assert!(m.held(d) && m.held(c));
    let lent_d = Refinement {
        leaves: vec![leaf(d, NodeClass::Borrowed)],
        ..Default::default()
    };
    m.begin(&params(&views, 2, &tf));
    m.end(&lent_d, &layout);
    m.end(&deeper, &layout);
    m.end(&lent_d, &layout);
    m.end(&deeper, &layout);
    m.end(&lent_d, &layout);
    assert!(!m.may_promote(d));
}
