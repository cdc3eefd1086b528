//! Error-aware refinement ([`LodMetric::VisibleError`], here mostly without
//! measured weights: the rank by projected size times expected error) over
//! synthetic metadata: a ramp along x whose nodes record error bounds.

use super::tests::{assert_exact_cover, ball_layout};
use super::*;
use brickray_core::{BinStats, ERROR_BINS, NodeError, TfErrorTable, node_pixel_error};
#[allow(unused_imports)]
use brickray_core::{Camera, NodeKind, RenderMode, TransferFunction, VolumeFrame};
use proptest::prelude::*;
use std::collections::HashMap;

/// Metadata of a ramp `value = x` (normalized) whose nodes carry error bounds
/// that shrink with the level (`dev` fraction `rough * 2^-level` of the range,
/// varied per node by `seed`); counts its reads.
pub(super) struct RampSource {
    pub(super) layout: OctreeLayout,
    pub(super) rough: f64,
    pub(super) seed: u64,
    pub(super) reads: usize,
}

impl RampSource {
    fn info(&mut self, key: NodeKey) -> NodeInfo {
        self.reads += 1;
        let (o, side) = key.unit_box();
        let scale = self.layout.volume_scale();
        let (lo, hi) = (
            (o[0] / scale[0]).min(1.0),
            ((o[0] + side) / scale[0]).min(1.0),
        );
        let (min, max) = (lo as f32, hi as f32);
        let mut h = (self.seed ^ ((key.x as u64) << 40 ^ (key.y as u64) << 20 ^ key.z as u64))
            .wrapping_mul(0x9E37_79B9_7F4A_7C15)
            | 1;
        let finest = self.layout.levels - 1;
        let mut bins = [BinStats::default(); ERROR_BINS];
        if key.level < finest {
            for st in bins.iter_mut() {
                h ^= h << 13;
                h ^= h >> 7;
                h ^= h << 17;
                let r = (h % 1000) as f64 / 1000.0;
                let count = 1 + h % 50;
                let dev = self.rough * r * 0.5f64.powi(key.level as i32);
                *st = BinStats {
                    count,
                    dev,
                    sum_sq: count as f64 * (0.3 * dev) * (0.3 * dev),
                };
            }
        }
        NodeInfo {
            kind: NodeKind::Data,
            min,
            max: max.max(min + 1e-3),
            error: Some(NodeError::encode(
                &bins,
                min as f64,
                max.max(min + 1e-3) as f64,
            )),
            parent_error: None,
            channels: Default::default(),
            channel_errors: None,
        }
    }
}

/// All bricks resident; metadata from a cache filled once from the source.
pub(super) struct Cached {
    pub(super) meta: HashMap<NodeKey, NodeInfo>,
}

impl RefineEnv for Cached {
    fn node(&mut self, key: NodeKey) -> MetaState {
        self.meta
            .get(&key)
            .cloned()
            .map_or(MetaState::Pending, |i| MetaState::Known(i.into()))
    }
    fn data(&mut self, _key: NodeKey) -> DataState {
        DataState::OnGpu
    }
}

pub(super) fn cache_all(src: &mut RampSource) -> HashMap<NodeKey, NodeInfo> {
    let mut m = HashMap::new();
    let mut stack = vec![NodeKey::ROOT];
    while let Some(k) = stack.pop() {
        if !src.layout.in_volume(k) {
            continue;
        }
        m.insert(k, src.info(k));
        if k.level + 1 < src.layout.levels {
            stack.extend(k.children());
        }
    }
    m
}

fn refine_with(
    layout: &OctreeLayout,
    env: &mut Cached,
    cam: &Camera,
    tf: &TransferFunction,
    metric: LodMetric,
) -> Refinement {
    refine_limited(layout, env, cam, tf, metric, 1.0, u32::MAX)
}

/// [`refine_with`] at a tolerance and a cap of data leaves, over any source.
pub(super) fn refine_limited(
    layout: &OctreeLayout,
    env: &mut dyn RefineEnv,
    cam: &Camera,
    tf: &TransferFunction,
    metric: LodMetric,
    tolerance_px: f32,
    max_data_leaves: u32,
) -> Refinement {
    let frame = VolumeFrame::centered(layout.volume.dims, [1.0; 3]);
    let params = RefineParams {
        views: &Views::one(ViewGeometry::new(layout, cam, 1.0, 256, &frame)),
        generation: 0,
        mode: RenderMode::Dvr,
        tf,
        channels: &[],
        tolerance_px,
        metric,
        max_data_leaves,
        max_requests: u32::MAX,
        max_prefetch: u32::MAX,
        brick_upload_bytes: 1,
        lookahead: false,
    };
    let mut b = UploadBudget::new(u64::MAX / 4);
    b.begin_frame();
    refine(layout, &params, env, &mut b)
}

/// A step in opacity and colour at `edge`, flat on both sides.
fn step_tf(edge: f32) -> TransferFunction {
    TransferFunction::from_points(
        &[
            (0.0, [1.0, 1.0, 1.0, 0.2]),
            (edge - 0.01, [1.0, 1.0, 1.0, 0.2]),
            (edge + 0.01, [1.0, 0.3, 0.1, 0.9]),
            (1.0, [1.0, 0.3, 0.1, 0.9]),
        ],
        256,
    )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    /// With everything resident and no visible weights measured, no leaf that
    /// could be split stays coarser than the budget: its projected voxel size
    /// times 255 x its expected error under the TF is within the budget.
    #[test]
    fn never_coarsens_a_node_over_the_budget(
        seed in any::<u64>(),
        rough in 0.0f64..0.5,
        budget in 0.0f32..400.0,
        dist in 1.2f32..6.0,
        yaw in 0.0f32..std::f32::consts::TAU,
        entries in proptest::collection::vec(proptest::array::uniform4(0.0f32..1.0), 2..10),
    ) {
        let layout = ball_layout(64);
        let mut src = RampSource { layout: layout.clone(), rough, seed, reads: 0 };
        let mut env = Cached { meta: cache_all(&mut src) };
        let tf = TransferFunction::from_entries(entries);
        let frame = VolumeFrame::centered(layout.volume.dims, [1.0; 3]);
        let cam = Camera::orbit(frame.center(), dist, yaw, 0.3);
        let metric = LodMetric::VisibleError { budget };
        let r = refine_with(&layout, &mut env, &cam, &tf, metric);
        let keys: Vec<NodeKey> = r.leaves.iter().map(|l| l.key).collect();
        assert_exact_cover(&keys, layout.levels);
        let geo = ViewGeometry::new(&layout, &cam, 1.0, 256, &frame);
        let table = TfErrorTable::new(&tf);
        let finest = layout.levels - 1;
        for l in &r.leaves {
            if l.class != NodeClass::Data || l.key.level >= finest {
                continue;
            }
            let info = env.meta[&l.key].clone();
            let e = node_pixel_error(&info, l.key.level, RenderMode::Dvr, &table, &layout)
                .unwrap();
            let px = geo.voxel_pixels(l.key);
            prop_assert!(
                px * 255.0 * e <= budget as f64 * (1.0 + 1e-6) + 1e-9,
                "{:?}: {px} px x {} levels > budget {budget}", l.key, 255.0 * e
            );
        }
        prop_assert_eq!(r.blocked, SplitBlocks::default());
    }

    /// Under a brick budget the per-brick order (children classified once,
    /// kept for the split, refused splits retried) still yields an exact
    /// cover within the budget, with or without visible weights, and fills
    /// the budget as far as whole splits allow: every leaf left unsplit
    /// (above the error budget of 0, nothing else blocking) would add more
    /// bricks than the budget has left.
    #[test]
    fn per_brick_order_keeps_the_cut_whole_and_within_the_brick_budget(
        seed in any::<u64>(),
        rough in 0.05f64..0.5,
        bricks in 1u32..200,
        visible in any::<bool>(),
        dist in 1.2f32..6.0,
        yaw in 0.0f32..std::f32::consts::TAU,
        entries in proptest::collection::vec(proptest::array::uniform4(0.0f32..1.0), 2..10),
    ) {
        let layout = ball_layout(64);
        let mut src = RampSource { layout: layout.clone(), rough, seed, reads: 0 };
        let meta = cache_all(&mut src);
        let tf = TransferFunction::from_entries(entries);
        let frame = VolumeFrame::centered(layout.volume.dims, [1.0; 3]);
        let cam = Camera::orbit(frame.center(), dist, yaw, 0.3);
        let scale = layout.volume_scale();
        let metric = LodMetric::VisibleError { budget: 0.0 };
        let mut env: Box<dyn RefineEnv> = if visible {
            Box::new(Seen { inner: Cached { meta: meta.clone() }, scale })
        } else {
            Box::new(Cached { meta: meta.clone() })
        };
        let r = refine_limited(&layout, env.as_mut(), &cam, &tf, metric, 0.0, bricks);
        let keys: Vec<NodeKey> = r.leaves.iter().map(|l| l.key).collect();
        assert_exact_cover(&keys, layout.levels);
        prop_assert!(r.data_leaves <= bricks.max(1), "{} > {bricks}", r.data_leaves);
        prop_assert_eq!(r.data_leaves as usize, r.leaves.iter().filter(|l| l.class == NodeClass::Data).count());
        // Every leaf that wants splitting (positive priority, above the
        // finest level) stayed because its split adds more bricks than the
        // budget has left.
        let geo = ViewGeometry::new(&layout, &cam, 1.0, 256, &frame);
        let left = bricks.saturating_sub(r.data_leaves);
        for l in &r.leaves {
            if l.class != NodeClass::Data || l.key.level + 1 >= layout.levels || l.priority <= 0.0 {
                continue;
            }
            let data = layout
                .children(l.key)
                .iter()
                .filter(|c| {
                    layout.in_volume(**c)
                        && !geo.culled(**c)
                        && is_visible(&meta[*c], RenderMode::Dvr, &tf, &[], &layout)
                })
                .count() as u32;
            prop_assert!(
                data.saturating_sub(1) > left,
                "{:?} (priority {}) adds {} bricks, {left} left", l.key, l.priority, data.saturating_sub(1)
            );
        }
    }
}

/// A new transfer function moves the refinement to where its edge is, from
/// cached metadata only: no source read.
#[test]
fn a_new_tf_reprioritises_without_reading_the_source() {
    let layout = ball_layout(64);
    let mut src = RampSource {
        layout: layout.clone(),
        rough: 0.3,
        seed: 7,
        reads: 0,
    };
    let mut env = Cached {
        meta: cache_all(&mut src),
    };
    let reads = src.reads;
    let frame = VolumeFrame::centered(layout.volume.dims, [1.0; 3]);
    let cam = Camera::orbit(frame.center(), 2.5, 0.0, 0.0);
    let metric = LodMetric::VisibleError { budget: 64.0 };
    // Mean level of the data leaves whose x range is near `x`.
    let depth_near = |r: &Refinement, x: f64| {
        let geo = ViewGeometry::new(&layout, &cam, 1.0, 256, &frame);
        let ls: Vec<f64> = r
            .leaves
            .iter()
            .filter(|l| l.class == NodeClass::Data)
            .filter(|l| {
                let (lo, hi) = geo.tex_box(l.key);
                lo.x <= x && x <= hi.x
            })
            .map(|l| l.key.level as f64)
            .collect();
        ls.iter().sum::<f64>() / ls.len().max(1) as f64
    };
    let a = refine_with(&layout, &mut env, &cam, &step_tf(0.25), metric);
    let b = refine_with(&layout, &mut env, &cam, &step_tf(0.75), metric);
    assert_eq!(src.reads, reads, "refinement read the source");
    assert!(a.meta_requests.is_empty() && b.meta_requests.is_empty());
    assert!(
        depth_near(&a, 0.25) > depth_near(&b, 0.25) + 0.5,
        "edge at 0.25: {} vs {}",
        depth_near(&a, 0.25),
        depth_near(&b, 0.25)
    );
    assert!(
        depth_near(&b, 0.75) > depth_near(&a, 0.75) + 0.5,
        "edge at 0.75: {} vs {}",
        depth_near(&b, 0.75),
        depth_near(&a, 0.75)
    );
    // Far from either edge the TF is flat: both stay coarse there, and coarser
    // than the geometric rule at 1 px.
    let g = refine_with(
        &layout,
        &mut env,
        &cam,
        &step_tf(0.25),
        LodMetric::Geometric,
    );
    assert!(g.data_leaves > a.data_leaves && g.data_leaves > b.data_leaves);
    assert!(depth_near(&a, 0.9) < depth_near(&g, 0.9));
}

/// A source without error bounds: error-aware refinement is the geometric rule
/// (at the tolerance, whatever the error budget).
#[test]
fn without_error_bounds_it_is_geometric() {
    let layout = ball_layout(64);
    let mut src = RampSource {
        layout: layout.clone(),
        rough: 0.3,
        seed: 1,
        reads: 0,
    };
    let mut meta = cache_all(&mut src);
    for v in meta.values_mut() {
        v.error = None;
    }
    let mut env = Cached { meta };
    let frame = VolumeFrame::centered(layout.volume.dims, [1.0; 3]);
    let cam = Camera::orbit(frame.center(), 2.0, 0.4, 0.2);
    let tf = step_tf(0.5);
    let g = refine_with(&layout, &mut env, &cam, &tf, LodMetric::Geometric);
    let e = refine_with(
        &layout,
        &mut env,
        &cam,
        &tf,
        LodMetric::VisibleError { budget: 3.0 },
    );
    assert_eq!(g, e);
}

/// A transfer function flat over the whole value range: no node's error can
/// show, so error-aware refinement keeps the root (priority 0, whatever the
/// budget), where the geometric rule refines the view to 1 px; an edge in the
/// transfer function makes it refine again, from the same cached metadata.
#[test]
fn a_flat_tf_coarsens_freely() {
    let layout = ball_layout(64);
    let mut src = RampSource {
        layout: layout.clone(),
        rough: 0.3,
        seed: 3,
        reads: 0,
    };
    let mut env = Cached {
        meta: cache_all(&mut src),
    };
    let reads = src.reads;
    let frame = VolumeFrame::centered(layout.volume.dims, [1.0; 3]);
    let cam = Camera::orbit(frame.center(), 2.0, 0.4, 0.2);
    let flat = TransferFunction::from_points(
        &[(0.0, [0.8, 0.5, 0.3, 0.4]), (1.0, [0.8, 0.5, 0.3, 0.4])],
        256,
    );
    let metric = LodMetric::VisibleError { budget: 0.0 };
    let r = refine_with(&layout, &mut env, &cam, &flat, metric);
    let data: Vec<&RefinedLeaf> = r
        .leaves
        .iter()
        .filter(|l| l.class == NodeClass::Data)
        .collect();
    assert_eq!(data.len(), 1, "{:?}", r.leaves);
    assert_eq!((data[0].key, data[0].priority), (NodeKey::ROOT, 0.0));
    let g = refine_with(&layout, &mut env, &cam, &flat, LodMetric::Geometric);
    assert!(
        g.data_leaves > 8,
        "geometric: {} data leaves",
        g.data_leaves
    );
    let e = refine_with(&layout, &mut env, &cam, &step_tf(0.5), metric);
    assert!(e.data_leaves > 8, "edge: {} data leaves", e.data_leaves);
    assert_eq!(src.reads, reads, "refinement read the source");
}

/// [`Cached`] with the renderer's measure of what the image shows of each node
/// ([`RefineEnv::visible_weight`]): here the half `x < 1/2` of the volume, in
/// proportion to a node's volume; the other half is hidden (weight 0).
pub(super) struct Seen {
    pub(super) inner: Cached,
    pub(super) scale: [f64; 3],
}

impl RefineEnv for Seen {
    fn node(&mut self, key: NodeKey) -> MetaState {
        self.inner.node(key)
    }
    fn data(&mut self, key: NodeKey) -> DataState {
        self.inner.data(key)
    }
    fn visible_weight(&mut self, key: NodeKey) -> Option<f64> {
        let (o, side) = key.unit_box();
        let (lo, hi) = (o[0] / self.scale[0], (o[0] + side) / self.scale[0]);
        let seen = (hi.min(0.5) - lo).max(0.0) / (hi - lo);
        // About what a 256 px view of a 64-voxel volume measures: pixels x
        // ray length (finest voxels) in proportion to the node's volume.
        Some(seen * side.powi(3) * 256.0 * 256.0 * 64.0)
    }
}

/// Under a brick budget, error-aware refinement with visible weights spends
/// the bricks on the half the image shows: no node of the hidden half is split
/// (so no brick below level 1 lies there), while the same budget without the
/// weights splits nodes in both halves (the test can fail). Only the order
/// changes: the cut stays an exact cover within the budget.
#[test]
fn visible_weights_keep_hidden_nodes_coarse() {
    let layout = ball_layout(64);
    let mut src = RampSource {
        layout: layout.clone(),
        rough: 0.3,
        seed: 5,
        reads: 0,
    };
    let meta = cache_all(&mut src);
    let frame = VolumeFrame::centered(layout.volume.dims, [1.0; 3]);
    let cam = Camera::orbit(frame.center(), 2.0, 0.4, 0.2);
    // Colour and opacity change over the whole range: every node has error.
    let tf = TransferFunction::from_points(
        &[(0.0, [0.1, 0.2, 0.9, 0.0]), (1.0, [0.9, 0.6, 0.1, 0.8])],
        256,
    );
    let scale = layout.volume_scale();
    let hidden_splits = |r: &Refinement| {
        r.leaves
            .iter()
            .filter(|l| l.key.level >= 2)
            .filter(|l| {
                let (o, _) = l.key.parent().unwrap().unit_box();
                o[0] / scale[0] >= 0.5
            })
            .count()
    };
    let metric = LodMetric::VisibleError { budget: 0.0 };
    let run =
        |env: &mut dyn RefineEnv, metric| refine_limited(&layout, env, &cam, &tf, metric, 0.0, 120);
    let plain = run(&mut Cached { meta: meta.clone() }, metric);
    let mut seen_env = Seen {
        inner: Cached { meta: meta.clone() },
        scale,
    };
    let seen = run(&mut seen_env, metric);
    // With an error budget instead of a brick budget, no hidden node splits
    // either, and the seen half still refines; without the weights the same
    // budget splits hidden nodes.
    let metric = LodMetric::VisibleError { budget: 64.0 };
    let unweighted = refine_limited(
        &layout,
        &mut Cached { meta: meta.clone() },
        &cam,
        &tf,
        metric,
        0.0,
        u32::MAX,
    );
    assert!(hidden_splits(&unweighted) > 0);
    let budgeted = refine_limited(&layout, &mut seen_env, &cam, &tf, metric, 0.0, u32::MAX);
    assert_eq!(hidden_splits(&budgeted), 0, "{:?}", budgeted.leaves);
    assert!(budgeted.leaves.iter().any(|l| l.key.level >= 2));
    for r in [&plain, &seen] {
        let keys: Vec<NodeKey> = r.leaves.iter().map(|l| l.key).collect();
        assert_exact_cover(&keys, layout.levels);
        assert!(r.data_leaves <= 120, "{} data leaves", r.data_leaves);
    }
    assert!(seen.data_leaves > 64, "{} data leaves", seen.data_leaves);
    assert!(
        hidden_splits(&plain) > 0,
        "the unweighted cut never split the hidden half"
    );
    assert_eq!(hidden_splits(&seen), 0, "{:?}", seen.leaves);
}

/// Metadata where every node above the finest level records the same error,
/// so that the visible weights alone rank nodes; `sparse` has only two of its
/// eight children holding data (the others empty).
struct PerBrick {
    sparse: NodeKey,
    weights: HashMap<NodeKey, f64>,
}

impl RefineEnv for PerBrick {
    fn node(&mut self, key: NodeKey) -> MetaState {
        let bins: [BinStats; ERROR_BINS] = std::array::from_fn(|_| BinStats {
            count: 10,
            dev: 0.1,
            sum_sq: 10.0 * 0.05 * 0.05,
        });
        let empty = key.level == 2
            && key.parent() == Some(self.sparse)
            && key != self.sparse.child(0)
            && key != self.sparse.child(7);
        MetaState::Known(
            NodeInfo {
                kind: if empty {
                    NodeKind::Empty
                } else {
                    NodeKind::Data
                },
                min: 0.0,
                max: 1.0,
                error: (key.level < 2).then(|| NodeError::encode(&bins, 0.0, 1.0)),
                parent_error: None,
                channels: Default::default(),
                channel_errors: None,
            }
            .into(),
        )
    }
    fn data(&mut self, _key: NodeKey) -> DataState {
        DataState::OnGpu
    }
    fn visible_weight(&mut self, key: NodeKey) -> Option<f64> {
        Some(self.weights.get(&key).copied().unwrap_or(1.0))
    }
}

/// Error-aware refinement under a brick budget ranks a split by its priority
/// per brick it adds: with room for one more split after the root's, a node
/// whose split adds one brick (two children with data) goes before one of
/// higher priority whose split adds seven, as long as its priority per brick
/// is higher (60 over 1 against 100 over 7), and after it once it is not (10
/// over 1 against 100 over 7). Ranked by priority alone (as before the
/// per-brick order) the dense node would split first in both cases.
#[test]
fn splits_are_ranked_per_brick_they_add() {
    let layout = ball_layout(32); // levels 0..=2, bricks of 8
    let frame = VolumeFrame::centered(layout.volume.dims, [1.0; 3]);
    let cam = Camera::orbit(frame.center(), 2.0, 0.4, 0.2);
    let tf = TransferFunction::from_points(
        &[(0.0, [0.1, 0.2, 0.9, 0.1]), (1.0, [0.9, 0.6, 0.1, 0.8])],
        256,
    );
    let (sparse, dense) = (NodeKey::new(1, 0, 0, 0), NodeKey::new(1, 1, 1, 1));
    let split = |r: &Refinement, k: NodeKey| r.leaves.iter().all(|l| l.key != k);
    let run = |sparse_weight: f64, metric| {
        let mut env = PerBrick {
            sparse,
            weights: HashMap::from([
                (NodeKey::ROOT, 1000.0),
                (sparse, sparse_weight),
                (dense, 100.0),
            ]),
        };
        // The root's 8 children, then room for 7 more bricks.
        let r = refine_limited(&layout, &mut env, &cam, &tf, metric, 0.0, 15);
        let keys: Vec<NodeKey> = r.leaves.iter().map(|l| l.key).collect();
        assert_exact_cover(&keys, layout.levels);
        assert!(r.data_leaves <= 15, "{} data leaves", r.data_leaves);
        (split(&r, sparse), split(&r, dense))
    };
    let metric = LodMetric::VisibleError { budget: 0.0 };
    // 60 per brick against 100/7: the sparse node first, and then the dense
    // one no longer fits (9 + 7 > 15).
    assert_eq!(run(60.0, metric), (true, false));
    // 10 per brick against 100/7: the dense node first (15 bricks), then no
    // room for the sparse one.
    assert_eq!(run(10.0, metric), (false, true));
}
