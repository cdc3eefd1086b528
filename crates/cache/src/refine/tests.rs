use super::*;
#[allow(unused_imports)]
use brickray_core::{Camera, NodeKind, RenderMode, TransferFunction, VolumeFrame};
use brickray_core::{DType, Projection, VolumeDesc};
use glam::Vec3;
use proptest::prelude::*;
use std::collections::HashSet;

/// A ball: raw value `clamp(1 - 2 |p - c|, 0, 1)` over texture space; nodes
/// wholly outside the ball are `Empty`.
pub(crate) fn ball_info(layout: &OctreeLayout, key: NodeKey) -> NodeInfo {
    let scale = layout.volume_scale();
    let (o, side) = key.unit_box();
    let mut near2 = 0.0;
    let mut far2 = 0.0;
    for a in 0..3 {
        let lo = (o[a] / scale[a]).min(1.0);
        let hi = ((o[a] + side) / scale[a]).min(1.0);
        let n = (0.5f64.clamp(lo, hi) - 0.5).abs();
        let f = (lo - 0.5).abs().max((hi - 0.5).abs());
        near2 += n * n;
        far2 += f * f;
    }
    let max = (1.0 - 2.0 * near2.sqrt()).max(0.0) as f32;
    let min = (1.0 - 2.0 * far2.sqrt()).max(0.0) as f32;
    let kind = if max <= 0.0 {
        NodeKind::Empty
    } else {
        NodeKind::Data
    };
    NodeInfo {
        kind,
        min,
        max,
        error: None,
        parent_error: None,
        channels: Default::default(),
        channel_errors: None,
    }
}

pub(crate) fn ball_layout(dim: u32) -> OctreeLayout {
    let desc = VolumeDesc {
        dims: [dim; 3],
        dtype: DType::U8,
        spacing: [1.0; 3],
        value_range: [0.0, 1.0],
        kind: Default::default(),
    };
    OctreeLayout::new(desc, 8, 1)
}

/// Every brick available in CPU memory; metadata from the ball.
struct AllInCpu {
    layout: OctreeLayout,
    on_gpu: HashSet<NodeKey>,
    meta_reads: usize,
}

impl RefineEnv for AllInCpu {
    fn node(&mut self, key: NodeKey) -> MetaState {
        self.meta_reads += 1;
        MetaState::Known(ball_info(&self.layout, key).into())
    }
    fn data(&mut self, key: NodeKey) -> DataState {
        if self.on_gpu.contains(&key) {
            DataState::OnGpu
        } else {
            DataState::InCpu
        }
    }
}

pub(crate) fn assert_exact_cover(leaves: &[NodeKey], levels: u8) {
    let set: HashSet<NodeKey> = leaves.iter().copied().collect();
    assert_eq!(set.len(), leaves.len(), "duplicate leaves");
    for l in leaves {
        let mut p = l.parent();
        while let Some(k) = p {
            assert!(
                !set.contains(&k),
                "{k:?} and its descendant {l:?} are both leaves"
            );
            p = k.parent();
        }
        assert!(l.level < levels);
    }
    let deepest = levels as u32 - 1;
    let total: u128 = leaves
        .iter()
        .map(|l| 1u128 << (3 * (deepest - l.level as u32)))
        .sum();
    assert_eq!(
        total,
        1u128 << (3 * deepest),
        "leaves do not cover the cube"
    );
}

pub(super) struct Setup {
    pub(super) layout: OctreeLayout,
    pub(super) frame: VolumeFrame,
    pub(super) tf: TransferFunction,
}

pub(super) fn setup() -> Setup {
    let layout = ball_layout(64);
    let frame = VolumeFrame::centered([64; 3], [1.0; 3]);
    Setup {
        layout,
        frame,
        tf: TransferFunction::ramp(0.0, 1.0, 1.0),
    }
}

fn run(
    s: &Setup,
    cam: &Camera,
    mode: RenderMode,
    tf: &TransferFunction,
    slots: u32,
    budget: u64,
) -> Refinement {
    let mut env = AllInCpu {
        layout: s.layout.clone(),
        on_gpu: HashSet::new(),
        meta_reads: 0,
    };
    let params = RefineParams {
        views: &Views::one(ViewGeometry::new(&s.layout, cam, 1.0, 512, &s.frame)),
        generation: 0,
        mode,
        tf,
        channels: &[],
        tolerance_px: 1.0,
        metric: brickray_core::LodMetric::Geometric,
        max_data_leaves: slots,
        max_requests: u32::MAX,
        max_prefetch: u32::MAX,
        brick_upload_bytes: s.layout.brick_bytes() as u64,
        lookahead: false,
    };
    let mut b = UploadBudget::new(budget);
    refine(&s.layout, &params, &mut env, &mut b)
}

pub(super) fn keys(r: &Refinement) -> Vec<NodeKey> {
    r.leaves.iter().map(|l| l.key).collect()
}

fn count(r: &Refinement, class: NodeClass) -> usize {
    r.leaves.iter().filter(|l| l.class == class).count()
}

#[test]
fn close_view_refines_to_finest_far_view_stays_coarse() {
    let s = setup();
    let near = Camera::orbit(Vec3::ZERO, 1.5, 0.3, 0.2);
    let r = run(&s, &near, RenderMode::Dvr, &s.tf, 10_000, u64::MAX);
    assert_exact_cover(&keys(&r), s.layout.levels);
    assert!(
        r.leaves
            .iter()
            .any(|l| l.key.level == s.layout.levels - 1 && l.class == NodeClass::Data)
    );
    assert_eq!(r.data_leaves as usize, count(&r, NodeClass::Data));
    let far = Camera::orbit(Vec3::ZERO, 400.0, 0.3, 0.2);
    let r = run(&s, &far, RenderMode::Dvr, &s.tf, 10_000, u64::MAX);
    assert_eq!(keys(&r), vec![NodeKey::ROOT]);
    assert!(r.leaves[0].needs_upload);
}

#[test]
fn frustum_culling_drops_offscreen_nodes() {
    let s = setup();
    // Looking away from the volume: everything culled at the root.
    let mut away = Camera::orbit(Vec3::ZERO, 2.0, 0.0, 0.0);
    away.target = away.eye * 2.0;
    let r = run(&s, &away, RenderMode::Dvr, &s.tf, 10_000, u64::MAX);
    assert_eq!(r.leaves.len(), 1);
    assert_eq!(r.leaves[0].class, NodeClass::Empty(EmptyReason::Culled));
    // Close up on one corner: many culled leaves, and no culled leaf projects on screen.
    let cam = Camera {
        target: Vec3::splat(0.4),
        ..Camera::orbit(Vec3::ZERO, 0.0, 0.0, 0.0)
    };
    let cam = Camera {
        eye: Vec3::new(0.4, 0.4, 1.0),
        ..cam
    };
    let r = run(&s, &cam, RenderMode::Mip, &s.tf, 10_000, u64::MAX);
    assert_exact_cover(&keys(&r), s.layout.levels);
    let culled: Vec<_> = r
        .leaves
        .iter()
        .filter(|l| l.class == NodeClass::Empty(EmptyReason::Culled))
        .collect();
    assert!(!culled.is_empty());
    let geo = ViewGeometry::new(&s.layout, &cam, 1.0, 512, &s.frame);
    let vp = cam.view_proj(1.0).as_dmat4();
    for l in culled {
        // Sample the box densely: no point projects inside the clip volume.
        let c = geo.world_corners(l.key);
        for t in 0..125 {
            let f = [
                (t % 5) as f64 / 4.0,
                ((t / 5) % 5) as f64 / 4.0,
                (t / 25) as f64 / 4.0,
            ];
            let p = c[0] + (c[1] - c[0]) * f[0] + (c[2] - c[0]) * f[1] + (c[4] - c[0]) * f[2];
            let q = vp * p.extend(1.0);
            let inside = q.x.abs() <= q.w && q.y.abs() <= q.w && q.z >= 0.0 && q.z <= q.w;
            assert!(!inside, "culled {:?} is visible at {p:?}", l.key);
        }
    }
    assert!(count(&r, NodeClass::Data) > 0);
}

#[test]
fn empty_and_invisible_nodes_are_terminal() {
    let s = setup();
    let cam = Camera::orbit(Vec3::ZERO, 1.5, 0.3, 0.2);
    // Fully transparent TF: the root is invisible and nothing is requested.
    let clear = TransferFunction::ramp(1.0, 1.0, 0.0);
    let r = run(&s, &cam, RenderMode::Dvr, &clear, 10_000, u64::MAX);
    assert_eq!(r.leaves.len(), 1);
    assert_eq!(r.leaves[0].class, NodeClass::Empty(EmptyReason::Invisible));
    assert!(r.requests.is_empty());
    // MIP: only the Empty corners of the ball are terminal-empty, none invisible.
    let r = run(&s, &cam, RenderMode::Mip, &s.tf, 10_000, u64::MAX);
    assert!(count(&r, NodeClass::Empty(EmptyReason::Empty)) > 0);
    assert_eq!(count(&r, NodeClass::Empty(EmptyReason::Invisible)), 0);
    // Iso at 0.9: only nodes reaching 0.9 (near the centre) hold data.
    let iso = RenderMode::Iso {
        value: 0.9,
        color: [1.0; 3],
    };
    let r = run(&s, &cam, iso, &s.tf, 10_000, u64::MAX);
    assert_exact_cover(&keys(&r), s.layout.levels);
    for l in &r.leaves {
        let info = ball_info(&s.layout, l.key);
        match l.class {
            NodeClass::Data => assert!(info.min <= 0.9 && 0.9 <= info.max, "{l:?}"),
            NodeClass::Empty(EmptyReason::Invisible) => {
                assert!(!(info.min <= 0.9 && 0.9 <= info.max))
            }
            _ => {}
        }
    }
    assert!(count(&r, NodeClass::Empty(EmptyReason::Invisible)) > 0);
}

#[test]
fn tiny_pool_gives_coarser_complete_cut() {
    let s = setup();
    let cam = Camera::orbit(Vec3::ZERO, 1.5, 0.3, 0.2);
    let big = run(&s, &cam, RenderMode::Mip, &s.tf, 10_000, u64::MAX);
    for slots in [1u32, 3, 8, 20] {
        let r = run(&s, &cam, RenderMode::Mip, &s.tf, slots, u64::MAX);
        assert_exact_cover(&keys(&r), s.layout.levels);
        assert!(r.data_leaves <= slots);
        assert!(r.data_leaves < big.data_leaves);
        assert!(r.blocked.pool_full > 0);
    }
    let r = run(&s, &cam, RenderMode::Mip, &s.tf, 0, u64::MAX);
    assert_eq!(r.leaves[0].class, NodeClass::Empty(EmptyReason::NotLoaded));
}

#[test]
fn upload_budget_limits_splits_but_progresses() {
    let s = setup();
    let cam = Camera::orbit(Vec3::ZERO, 1.5, 0.3, 0.2);
    let r = run(&s, &cam, RenderMode::Mip, &s.tf, 10_000, 0);
    assert_exact_cover(&keys(&r), s.layout.levels);
    // Only the first split is let through (progress), whatever its size.
    assert_eq!(r.leaves.len(), 8);
    assert!(r.leaves.iter().all(|l| l.key.level == 1 && l.needs_upload));
    assert!(r.blocked.upload_budget > 0);
    // Larger budgets: more splits, and the bricks uploaded (leaves not on the
    // GPU; split nodes charged at their parent's split are given back) stay
    // within the budget once past the first split.
    let brick = s.layout.brick_bytes() as u64;
    let mut last = r.leaves.len();
    for n in [16u64, 22, 40, 100] {
        let r = run(&s, &cam, RenderMode::Mip, &s.tf, 10_000, n * brick);
        assert_exact_cover(&keys(&r), s.layout.levels);
        let uploads = r.leaves.iter().filter(|l| l.needs_upload).count() as u64;
        assert!(uploads <= n, "{uploads} > {n}");
        assert!(uploads + 8 > n, "budget {n} underused: {uploads}");
        assert!(r.leaves.len() >= last);
        last = r.leaves.len();
    }
}

/// DVR, the geometric order at tolerance 0 (only the limits stop it), no
/// pool, request or prefetch limit, bricks of one upload byte.
pub(super) fn dvr_params<'a>(s: &'a Setup, views: &'a Views) -> RefineParams<'a> {
    RefineParams {
        views,
        generation: 0,
        mode: RenderMode::Dvr,
        tf: &s.tf,
        channels: &[],
        tolerance_px: 0.0,
        metric: brickray_core::LodMetric::Geometric,
        max_data_leaves: u32::MAX,
        max_requests: u32::MAX,
        max_prefetch: u32::MAX,
        brick_upload_bytes: 1,
        lookahead: false,
    }
}

/// MIP at 512 px, 1 px tolerance, no pool or request limit.
pub(super) fn mip_params<'a>(s: &'a Setup, views: &'a Views) -> RefineParams<'a> {
    RefineParams {
        views,
        generation: 0,
        mode: RenderMode::Mip,
        tf: &s.tf,
        channels: &[],
        tolerance_px: 1.0,
        metric: brickray_core::LodMetric::Geometric,
        max_data_leaves: 10_000,
        max_requests: u32::MAX,
        max_prefetch: u32::MAX,
        brick_upload_bytes: s.layout.brick_bytes() as u64,
        lookahead: false,
    }
}

#[test]
fn tf_change_reclassifies_from_metadata_only() {
    let s = setup();
    let cam = Camera::orbit(Vec3::ZERO, 1.5, 0.3, 0.2);
    let a = run(
        &s,
        &cam,
        RenderMode::Dvr,
        &TransferFunction::ramp(0.0, 0.2, 1.0),
        10_000,
        u64::MAX,
    );
    let b = run(
        &s,
        &cam,
        RenderMode::Dvr,
        &TransferFunction::ramp(0.7, 1.0, 1.0),
        10_000,
        u64::MAX,
    );
    assert_exact_cover(&keys(&b), s.layout.levels);
    assert!(b.data_leaves < a.data_leaves);
    assert!(
        count(&b, NodeClass::Empty(EmptyReason::Invisible))
            > count(&a, NodeClass::Empty(EmptyReason::Invisible))
    );
}

fn arb_camera() -> impl Strategy<Value = Camera> {
    (
        0.0f32..6.3,
        -1.5f32..1.5,
        0.3f32..20.0,
        any::<bool>(),
        0.1f32..3.0,
        -0.6f32..0.6,
    )
        .prop_map(|(yaw, pitch, dist, ortho, h, off)| {
            let mut c = Camera::orbit(Vec3::splat(off), dist, yaw, pitch);
            if ortho {
                c.projection = Projection::Orthographic { height: h };
            }
            c
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]
    /// Every point of the octree cube is in exactly one leaf, for any camera,
    /// mode, tolerance and pool size; data leaves never exceed the pool.
    #[test]
    fn cut_covers_cube_exactly(
        cam in arb_camera(),
        slots in 1u32..300,
        tol in 0.5f32..4.0,
        mode in prop_oneof![Just(RenderMode::Dvr), Just(RenderMode::Mip), (0.0f32..1.0).prop_map(|v| RenderMode::Iso { value: v, color: [1.0; 3] })],
        dim in prop_oneof![Just(40u32), Just(64), Just(100)],
    ) {
        let layout = ball_layout(dim);
        let frame = VolumeFrame::centered([dim; 3], [1.0; 3]);
        let tf = TransferFunction::ramp(0.3, 1.0, 0.5);
        let mut env = AllInCpu { layout: layout.clone(), on_gpu: HashSet::new(), meta_reads: 0 };
        let params = RefineParams { views: &Views::one(ViewGeometry::new(&layout, &cam, 1.3, 400, &frame)),
        generation: 0, mode, tf: &tf, channels: &[], tolerance_px: tol, metric: brickray_core::LodMetric::Geometric, max_data_leaves: slots, max_requests: MIN_REQUESTS_PER_FRAME, max_prefetch: u32::MAX, brick_upload_bytes: 1000, lookahead: false };
        let mut b = UploadBudget::new(u64::MAX);
        let r = refine(&layout, &params, &mut env, &mut b);
        assert_exact_cover(&keys(&r), layout.levels);
        prop_assert!(r.data_leaves <= slots);
        prop_assert!(r.requests.len() as u32 <= slots.min(MIN_REQUESTS_PER_FRAME));
        prop_assert_eq!(r.data_leaves as usize, count(&r, NodeClass::Data));
        for l in &r.leaves {
            if l.class == NodeClass::Data {
                prop_assert!(layout.in_volume(l.key));
            }
        }
    }
}

/// The ball with the bricks of levels <= `loaded` in CPU memory (the rest
/// missing), and every node under `hidden` invisible.
struct Hidden {
    inner: AllInCpu,
    loaded: u8,
    hidden: NodeKey,
    asked: Vec<NodeKey>,
}

fn under(k: NodeKey, a: NodeKey) -> bool {
    std::iter::successors(Some(k), |p| p.parent()).any(|p| p == a)
}

impl RefineEnv for Hidden {
    fn node(&mut self, key: NodeKey) -> MetaState {
        self.inner.node(key)
    }
    fn data(&mut self, key: NodeKey) -> DataState {
        if key.level <= self.loaded {
            DataState::InCpu
        } else {
            DataState::Missing
        }
    }
    fn may_split(&mut self, key: NodeKey) -> bool {
        self.asked.push(key);
        !under(key, self.hidden)
    }
}

#[test]
fn invisible_nodes_stay_at_their_level_and_request_nothing() {
    let s = setup();
    let cam = Camera::orbit(Vec3::ZERO, 1.5, 0.3, 0.2);
    let hidden = NodeKey::ROOT.child(0).child(7);
    for loaded in [1u8, 2, 3, 8] {
        let mut env = Hidden {
            inner: AllInCpu {
                layout: s.layout.clone(),
                on_gpu: HashSet::new(),
                meta_reads: 0,
            },
            loaded,
            hidden,
            asked: Vec::new(),
        };
        let views = Views::one(ViewGeometry::new(&s.layout, &cam, 1.0, 512, &s.frame));
        let params = dvr_params(&s, &views);
        let mut b = UploadBudget::new(u64::MAX);
        let r = refine(&s.layout, &params, &mut env, &mut b);
        assert_exact_cover(&keys(&r), s.layout.levels);
        // No request below the hidden node (its own brick is its visible
        // parent's request); nothing under it split.
        assert!(
            r.requests
                .iter()
                .all(|q| !under(q.key, hidden) || q.key == hidden),
            "{loaded}"
        );
        assert!(
            r.leaves
                .iter()
                .all(|l| !under(l.key, hidden) || l.key == hidden)
        );
        // Never a hole: the hidden node, once reached, is a data leaf.
        if loaded >= hidden.level {
            let h = r.leaves.iter().find(|l| l.key == hidden).expect("a leaf");
            assert_eq!(h.class, NodeClass::Data);
            assert!(r.blocked.invisible >= 1);
        }
        // Elsewhere refinement proceeds: with everything loaded, leaves deeper
        // than the hidden node exist.
        if loaded == 8 {
            assert!(r.leaves.iter().any(|l| l.key.level > hidden.level));
            assert!(env.asked.contains(&hidden));
        }
    }
}

/// Nothing in memory but the root; `favoured`'s detail is asked for 100 times
/// more strongly than any other node's.
struct Favour {
    layout: OctreeLayout,
    favoured: NodeKey,
}

impl RefineEnv for Favour {
    fn node(&mut self, key: NodeKey) -> MetaState {
        MetaState::Known(ball_info(&self.layout, key).into())
    }
    fn data(&mut self, key: NodeKey) -> DataState {
        if key.level == 0 {
            DataState::OnGpu
        } else {
            DataState::Missing
        }
    }
    fn request_weight(&mut self, key: NodeKey) -> f64 {
        if key == self.favoured { 100.0 } else { 1.0 }
    }
}

/// The request weight orders the load requests and nothing else: the cut is
/// the same whatever it is.
#[test]
fn request_weight_orders_loads_not_the_cut() {
    let s = setup();
    let cam = Camera::orbit(Vec3::ZERO, 1.5, 0.3, 0.2);
    let views = Views::one(ViewGeometry::new(&s.layout, &cam, 1.0, 512, &s.frame));
    let params = mip_params(&s, &views);
    let run = |favoured: NodeKey| {
        let mut env = Favour {
            layout: s.layout.clone(),
            favoured,
        };
        refine(
            &s.layout,
            &params,
            &mut env,
            &mut UploadBudget::new(u64::MAX),
        )
    };
    // The root splits into its children, whose bricks are all wanted.
    let plain = run(NodeKey {
        level: 9,
        x: 0,
        y: 0,
        z: 0,
    });
    assert!(plain.requests.len() > 1);
    for r in &plain.requests {
        assert_eq!(r.key.level, 1);
    }
    let favoured = run(NodeKey::ROOT);
    assert_eq!(keys(&favoured), keys(&plain));
    for (a, b) in favoured.requests.iter().zip(&plain.requests) {
        assert_eq!(a.key, b.key);
        assert!((a.priority / b.priority - 100.0).abs() < 1e-3);
    }
}

/// A node within the tolerance still splits when at most one child needs
/// data: the cut gets finer and never grows. On the ball's iso-surface at 0.9
/// (values >= 0.9 only within 0.05 of the centre) every node around the centre
/// has one data child down to the finest level, so a view whose tolerance
/// stops refinement at level 1 or 2 (its voxels project to less than the
/// tolerance there) still draws the 8 finest bricks around the centre once
/// the root splits; and no data leaf of any view is left above the finest
/// level with fewer than two data children.
#[test]
fn splits_that_cost_no_brick_are_taken_within_the_tolerance() {
    let s = setup();
    let iso = RenderMode::Iso {
        value: 0.9,
        color: [1.0; 3],
    };
    let finest = s.layout.levels - 1;
    for (dist, tolerance) in [(1.5, 1.0), (4.0, 6.0), (4.0, 12.0), (30.0, 1.0)] {
        let cam = Camera::orbit(Vec3::ZERO, dist, 0.3, 0.2);
        let mut env = AllInCpu {
            layout: s.layout.clone(),
            on_gpu: HashSet::new(),
            meta_reads: 0,
        };
        let params = RefineParams {
            views: &Views::one(ViewGeometry::new(&s.layout, &cam, 1.0, 512, &s.frame)),
            generation: 0,
            mode: iso,
            tf: &s.tf,
            channels: &[],
            tolerance_px: tolerance,
            metric: brickray_core::LodMetric::Geometric,
            max_data_leaves: 10_000,
            max_requests: u32::MAX,
            max_prefetch: u32::MAX,
            brick_upload_bytes: s.layout.brick_bytes() as u64,
            lookahead: false,
        };
        let r = refine(
            &s.layout,
            &params,
            &mut env,
            &mut UploadBudget::new(u64::MAX),
        );
        assert_exact_cover(&keys(&r), s.layout.levels);
        for l in r.leaves.iter().filter(|l| l.class == NodeClass::Data) {
            if l.key.level == finest {
                continue;
            }
            let holding = s
                .layout
                .children(l.key)
                .iter()
                .filter(|&&c| {
                    let i = ball_info(&s.layout, c);
                    i.kind == NodeKind::Data && i.min <= 0.9 && 0.9 <= i.max
                })
                .count();
            assert!(
                holding >= 2,
                "{:?} stays coarse with {holding} data children (distance {dist}, tolerance {tolerance})",
                l.key
            );
        }
        // The root has eight data children (the centre is their common
        // corner); below it the split never grows the cut.
        if r.data_leaves > 1 {
            assert_eq!(r.data_leaves, 8, "distance {dist}, tolerance {tolerance}");
            assert!(
                r.leaves
                    .iter()
                    .filter(|l| l.class == NodeClass::Data)
                    .all(|l| l.key.level == finest)
            );
        }
    }
}

/// Refinement time on large cuts of a dense volume (the ball at 2048^3,
/// bricks of 8: every node holds data), printed; see them with
/// `cargo test --release -p brickray-cache refine_time -- --nocapture`
/// (docs/cache.md, "free split", quotes them). It asserts what every cut must
/// satisfy, never a time.
#[test]
fn refine_time_on_dense_cuts() {
    let layout = ball_layout(2048);
    let frame = VolumeFrame::centered([2048; 3], [1.0; 3]);
    let tf = TransferFunction::ramp(0.0, 1.0, 1.0);
    for dist in [1.5f32, 3.0, 6.0] {
        let cam = Camera::orbit(Vec3::ZERO, dist, 0.3, 0.2);
        let params = RefineParams {
            views: &Views::one(ViewGeometry::new(&layout, &cam, 1.0, 1024, &frame)),
            generation: 0,
            mode: RenderMode::Dvr,
            tf: &tf,
            channels: &[],
            tolerance_px: 1.0,
            metric: brickray_core::LodMetric::Geometric,
            max_data_leaves: 100_000,
            max_requests: u32::MAX,
            max_prefetch: u32::MAX,
            brick_upload_bytes: layout.brick_bytes() as u64,
            lookahead: false,
        };
        let mut env = AllInCpu {
            layout: layout.clone(),
            on_gpu: HashSet::new(),
            meta_reads: 0,
        };
        let t = std::time::Instant::now();
        let r = refine(&layout, &params, &mut env, &mut UploadBudget::new(u64::MAX));
        let ms = t.elapsed().as_secs_f64() * 1e3;
        eprintln!(
            "distance {dist}: {} leaves, {} data, {ms:.1} ms, {} metadata reads",
            r.leaves.len(),
            r.data_leaves,
            env.meta_reads
        );
        assert_exact_cover(&keys(&r), layout.levels);
        assert!(r.data_leaves <= 100_000);
    }
}

/// Bricks wholly outside the view's clip box are culled: a clip box over one
/// half of the ball needs no brick of the other half, and fewer bricks than
/// the whole ball; the cut still tiles the cube.
#[test]
fn nodes_outside_the_clip_box_need_no_brick() {
    let layout = ball_layout(64);
    let frame = VolumeFrame::centered([64; 3], [1.0; 3]);
    let tf = TransferFunction::ramp(0.05, 1.0, 0.5);
    let cam = Camera::orbit(frame.center(), 1.8, 0.5, 0.3);
    let cut = |clip: brickray_core::ClipBox| {
        let view = brickray_core::FrameView::new(cam, frame, [256, 256]).with_clip(clip);
        let views = Views::of(&layout, &[view]);
        let params = RefineParams {
            views: &views,
            generation: 0,
            mode: RenderMode::Dvr,
            tf: &tf,
            channels: &[],
            tolerance_px: 0.0,
            metric: brickray_core::LodMetric::Geometric,
            max_data_leaves: 10_000,
            max_requests: u32::MAX,
            max_prefetch: u32::MAX,
            brick_upload_bytes: 1,
            lookahead: false,
        };
        let mut env = AllInCpu {
            layout: layout.clone(),
            on_gpu: HashSet::new(),
            meta_reads: 0,
        };
        let r = refine(&layout, &params, &mut env, &mut UploadBudget::new(u64::MAX));
        assert_exact_cover(&keys(&r), layout.levels);
        r
    };
    let whole = cut(brickray_core::ClipBox::FULL);
    let half = brickray_core::ClipBox {
        min: [0.0; 3],
        max: [0.4, 1.0, 1.0],
    };
    let clipped = cut(half);
    let geo = ViewGeometry::new(&layout, &cam, 1.0, 256, &frame);
    for l in clipped.leaves.iter().filter(|l| l.class == NodeClass::Data) {
        let (lo, _) = geo.tex_box(l.key);
        assert!(lo.x <= 0.4, "{:?} lies outside the clip box", l.key);
    }
    assert!(
        clipped.data_leaves * 2 <= whole.data_leaves,
        "{} of {} bricks",
        clipped.data_leaves,
        whole.data_leaves
    );
    assert!(
        clipped
            .leaves
            .iter()
            .any(|l| l.class == NodeClass::Empty(EmptyReason::Culled))
    );
}
