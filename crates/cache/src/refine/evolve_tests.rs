//! The evolving refinement against the greedy order ([`super::evolve`]).

use super::tests::{assert_exact_cover, ball_info, ball_layout};
use super::*;
use brickray_core::{Camera, NodeSet, Projection, VolumeFrame};
use glam::Vec3;
use proptest::prelude::*;

/// The ball's metadata, every brick of levels up to `loaded` on the GPU
/// and the deeper ones missing; the nodes under `hidden` may not split (as
/// the visibility feedback hides them).
struct Loaded {
    layout: OctreeLayout,
    loaded: u8,
    hidden: Option<NodeKey>,
}

impl RefineEnv for Loaded {
    fn may_split(&mut self, key: NodeKey) -> bool {
        self.hidden
            .is_none_or(|h| !std::iter::successors(Some(key), |p| p.parent()).any(|p| p == h))
    }
    fn node(&mut self, key: NodeKey) -> MetaState {
        MetaState::Known(ball_info(&self.layout, key).into())
    }
    fn data(&mut self, key: NodeKey) -> DataState {
        match key.level <= self.loaded {
            true => DataState::OnGpu,
            false => DataState::Missing,
        }
    }
}

struct Scene {
    layout: OctreeLayout,
    frame: VolumeFrame,
    tf: TransferFunction,
    mode: RenderMode,
    tolerance: f32,
    slots: u32,
}

impl Scene {
    fn params<'a>(&'a self, views: &'a Views) -> RefineParams<'a> {
        RefineParams {
            views,
            generation: 0,
            mode: self.mode,
            tf: &self.tf,
            channels: &[],
            tolerance_px: self.tolerance,
            metric: LodMetric::Geometric,
            max_data_leaves: self.slots,
            max_requests: 256,
            max_prefetch: 256,
            brick_upload_bytes: 1000,
            lookahead: false,
        }
    }

    fn views(&self, cam: &Camera) -> Views {
        Views::one(ViewGeometry::new(&self.layout, cam, 1.3, 400, &self.frame))
    }

    fn greedy(&self, cam: &Camera, env: &mut dyn RefineEnv) -> Refinement {
        let views = self.views(cam);
        refine(
            &self.layout,
            &self.params(&views),
            env,
            &mut UploadBudget::new(u64::MAX),
        )
    }

    /// `last` evolved to `cam`; `hiding`: the feedback hid nodes in the
    /// last frame or hides some in this one (so the leaves within the
    /// tolerance are visited again, as the manager does).
    fn evolved(
        &self,
        cam: &Camera,
        env: &mut dyn RefineEnv,
        last: &Refinement,
        hiding: bool,
    ) -> Refinement {
        let views = self.views(cam);
        let b = &last.blocked;
        let waiting = b.missing_data + b.missing_meta + b.upload_budget > 0 || hiding;
        let (r, provisional) = evolve(
            &self.layout,
            &self.params(&views),
            env,
            &mut UploadBudget::new(u64::MAX),
            &last.leaves,
            waiting,
        )
        .expect("the last cut can be evolved");
        // Where the tolerance binds (an unbounded pool and upload budget),
        // never provisional: the greedy order's cut.
        assert!(self.slots != u32::MAX || !provisional);
        r
    }
}

fn sorted_leaves(r: &Refinement) -> Vec<(NodeKey, NodeClass, u32, bool)> {
    let mut v: Vec<_> = r
        .leaves
        .iter()
        .map(|l| (l.key, l.class, l.priority.to_bits(), l.needs_upload))
        .collect();
    v.sort_by_key(|l| l.0);
    v
}

fn sorted_requests(r: &Refinement) -> Vec<(NodeKey, u32)> {
    let mut v: Vec<_> = r
        .requests
        .iter()
        .map(|q| (q.key, q.priority.to_bits()))
        .collect();
    v.sort();
    v
}

fn mode() -> impl Strategy<Value = RenderMode> {
    prop_oneof![
        Just(RenderMode::Dvr),
        Just(RenderMode::Mip),
        (0.0f32..1.0).prop_map(|v| RenderMode::Iso {
            value: v,
            color: [1.0; 3]
        }),
    ]
}

/// A node whose subtree the feedback hides (or none): the root, or one 1-3
/// levels down.
fn hidden() -> impl Strategy<Value = Option<NodeKey>> {
    prop::option::of(prop::collection::vec(0u8..8, 0..4))
        .prop_map(|path| path.map(|p| p.iter().fold(NodeKey::ROOT, |k, &i| k.child(i))))
}

/// A camera path: a start orbit and four small moves of it (turns, a dolly
/// and a pan), and a jump to an unrelated view last.
fn path() -> impl Strategy<Value = Vec<Camera>> {
    (
        0.0f32..6.3,
        -1.2f32..1.2,
        0.4f32..6.0,
        any::<bool>(),
        -0.4f32..0.4,
        prop::collection::vec((-0.05f32..0.05, -0.05f32..0.05, -0.1f32..0.1), 4),
        (0.0f32..6.3, -1.2f32..1.2, 0.4f32..6.0),
    )
        .prop_map(|(yaw, pitch, dist, ortho, off, moves, jump)| {
            let cam = |yaw: f32, pitch: f32, dist: f32, off: f32| {
                let mut c = Camera::orbit(Vec3::splat(off), dist, yaw, pitch);
                if ortho {
                    c.projection = Projection::Orthographic { height: dist };
                }
                c
            };
            let mut cams = vec![cam(yaw, pitch, dist, off)];
            let (mut y, mut p, mut d, mut o) = (yaw, pitch, dist, off);
            for (dy, dp, dd) in moves {
                y += dy;
                p += dp;
                d *= 1.0 + dd;
                o += dy;
                cams.push(cam(y, p, d, o));
            }
            cams.push(cam(jump.0, jump.1, jump.2, 0.0));
            cams
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    /// Where the tolerance binds before the pool and the upload budget, each
    /// frame of a camera path evolved from the last is the greedy order's
    /// cut, leaf for leaf (class, priority, upload), with the same requests
    /// and the same refusals, including with the deeper bricks missing,
    /// after a jump, and with a subtree the feedback hides that changes
    /// from frame to frame.
    #[test]
    fn where_the_tolerance_binds_the_evolved_cut_is_the_greedy_one(
        cams in path(),
        mode in mode(),
        tolerance in 0.5f32..4.0,
        dim in prop_oneof![Just(40u32), Just(64), Just(100)],
        loaded in 1u8..8,
        hidden in prop::collection::vec(hidden(), 6),
    ) {
        let scene = Scene {
            layout: ball_layout(dim),
            frame: VolumeFrame::centered([dim; 3], [1.0; 3]),
            tf: TransferFunction::ramp(0.3, 1.0, 0.5),
            mode,
            tolerance,
            slots: u32::MAX,
        };
        let mut env = Loaded { layout: scene.layout.clone(), loaded, hidden: hidden[0] };
        let mut last = scene.greedy(&cams[0], &mut env);
        for (cam, hidden) in cams[1..].iter().zip(&hidden[1..]) {
            let hiding = env.hidden.is_some() || hidden.is_some();
            env.hidden = *hidden;
            let greedy = scene.greedy(cam, &mut env);
            let evolved = scene.evolved(cam, &mut env, &last, hiding);
            assert_exact_cover(&tests::keys(&evolved), scene.layout.levels);
            prop_assert_eq!(sorted_leaves(&evolved), sorted_leaves(&greedy));
            prop_assert_eq!(sorted_requests(&evolved), sorted_requests(&greedy));
            prop_assert_eq!(evolved.blocked, greedy.blocked);
            prop_assert_eq!(evolved.data_leaves, greedy.data_leaves);
            last = evolved;
        }
    }
}

/// The largest priority among data leaves the rule would still split
/// (not at the finest level): the screen error the cut leaves.
fn worst_leaf(r: &Refinement, layout: &OctreeLayout) -> f32 {
    r.leaves
        .iter()
        .filter(|l| l.class == NodeClass::Data && l.key.level + 1 < layout.levels)
        .map(|l| l.priority)
        .fold(0.0, f32::max)
}

/// Where the pool binds, the greedy order fills its last slots by a global
/// priority order that an evolving cut only approaches: along a turning
/// camera (30 frames, each evolved from the last) the evolved cut stays a
/// whole cut within the pool, its largest leaf screen error stays the greedy
/// cut's (measured 1.000-1.010x) and its leaves differ from the greedy
/// cut's by a few per cent (measured 0-11% after 30 frames, the most at the
/// fastest turn). Bounds: 1.02x and 15%.
#[test]
fn where_the_pool_binds_the_evolved_cut_stays_near_the_greedy_one() {
    for (dim, slots, step) in [
        (200u32, 400u32, 0.004f32),
        (400, 3000, 0.03),
        (200, 1000, 0.1),
    ] {
        let scene = Scene {
            layout: ball_layout(dim),
            frame: VolumeFrame::centered([dim; 3], [1.0; 3]),
            tf: TransferFunction::ramp(0.3, 1.0, 0.5),
            mode: RenderMode::Dvr,
            tolerance: 0.0,
            slots,
        };
        let mut env = Loaded {
            layout: scene.layout.clone(),
            loaded: u8::MAX,
            hidden: None,
        };
        let cam = |i: usize| Camera::orbit(Vec3::ZERO, 1.4, 0.5 + step * i as f32, 0.3);
        let mut last = scene.greedy(&cam(0), &mut env);
        for i in 1..=30 {
            let greedy = scene.greedy(&cam(i), &mut env);
            let evolved = scene.evolved(&cam(i), &mut env, &last, false);
            assert_exact_cover(&tests::keys(&evolved), scene.layout.levels);
            assert!(evolved.data_leaves <= slots);
            assert!(
                greedy.data_leaves as f64 > 0.95 * slots as f64,
                "the pool binds"
            );
            let g: NodeSet = greedy.leaves.iter().map(|l| l.key).collect();
            let e: NodeSet = evolved.leaves.iter().map(|l| l.key).collect();
            let differ = g.symmetric_difference(&e).count() as f64 / g.len() as f64;
            let worst = worst_leaf(&evolved, &scene.layout) / worst_leaf(&greedy, &scene.layout);
            assert!(differ <= 0.15, "{dim} {slots} {step}, frame {i}: {differ}");
            assert!(worst <= 1.02, "{dim} {slots} {step}, frame {i}: {worst}");
            last = evolved;
        }
    }
}
