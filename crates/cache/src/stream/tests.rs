//! The planner on the CPU with scripted feedback: what needed a GPU to test
//! (ray-guided culling, occlusion scheduling, visible weights) and the
//! configuration path.

use super::*;
use crate::config::OutOfCoreConfig;
use crate::test_source::{TestSource, test_gpu};
use brickray_core::{Camera, LodMetric, VolumeFrame};
use brickray_visibility::{VisibilityConfig, VisibilityPolicy};
use glam::Vec3;
use std::collections::{HashMap, HashSet, VecDeque};
use std::time::{Duration, Instant};

/// Frames between rendering a plan and its read-back reaching the planner,
/// as the renderer's rings deliver them.
const DELAY: u64 = 2;

/// What the scripted "GPU" reports for a leaf: rays (usage), visible weight,
/// occlusion samples.
type Script = dyn Fn(NodeKey) -> (u32, f64, u32);

/// A planner over a ball with scripted feedback, delivered `DELAY` frames
/// after the plan it is about.
struct Rig {
    src: Arc<TestSource>,
    streamer: Streamer,
    placement: VolumeFrame,
    tf: TransferFunction,
    /// Read-backs in flight per view: (frame, feedback).
    in_flight: Vec<VecDeque<(u64, ViewFeedback)>>,
}

impl Rig {
    fn new(dim: u32, config: OutOfCoreConfig) -> Rig {
        Rig::over(TestSource::new(dim), config)
    }

    fn over(src: TestSource, config: OutOfCoreConfig) -> Rig {
        let dim = src.layout.volume.dims[0];
        let src = Arc::new(src);
        let mut streamer =
            Streamer::new(src.clone(), config, test_gpu(&src.layout)).expect("streamer");
        streamer.preload_root().expect("root");
        Rig {
            placement: VolumeFrame::centered([dim; 3], [1.0; 3]),
            tf: TransferFunction::ramp(0.05, 1.0, 0.5),
            in_flight: Vec::new(),
            src,
            streamer,
        }
    }

    fn view(&self, camera: Camera) -> FrameView {
        FrameView::new(camera, self.placement, [128, 128])
    }

    /// Plans one frame of `views`, then "renders" it: the script's feedback
    /// for each view is queued for delivery `DELAY` frames later.
    fn step(&mut self, views: &[FrameView], script: &Script) -> StreamPlan {
        self.in_flight.resize_with(views.len(), VecDeque::new);
        let next = self.streamer.next_frame();
        let feedback: Vec<ViewFeedback> = self
            .in_flight
            .iter_mut()
            .map(|q| {
                let mut f = ViewFeedback::default();
                while q.front().is_some_and(|(frame, _)| frame + DELAY <= next) {
                    let (_, v) = q.pop_front().expect("front");
                    f.usage.extend(v.usage);
                    f.queries.extend(v.queries);
                }
                f
            })
            .collect();
        let plan = self.streamer.plan(&StreamFrame {
            views,
            classification: Classification {
                mode: RenderMode::Dvr,
                tf: &self.tf,
                channels: &[],
                tf_generation: 1,
            },
            feedback: &feedback,
            time: None,
        });
        for (v, q) in self.in_flight.iter_mut().enumerate() {
            let usage = UsageFrame {
                frame: plan.frame,
                counts: plan.leaves.iter().map(|&(_, k)| (k, script(k).0)).collect(),
                weights: plan.leaves.iter().map(|&(_, k)| script(k).1).collect(),
            };
            let queries = plan.queries[v]
                .keys
                .iter()
                .map(|&key| QueryResult {
                    frame: plan.frame,
                    key,
                    samples: script(key).2,
                })
                .collect();
            q.push_back((
                plan.frame,
                ViewFeedback {
                    usage: vec![usage],
                    queries,
                },
            ));
        }
        plan
    }

    /// Steps until the planner says the views converged (after at least the
    /// frames the feedback takes to arrive: a changed script is seen only
    /// then); returns the plans.
    fn converge(&mut self, views: &[FrameView], script: &Script) -> Vec<StreamPlan> {
        let t = Instant::now();
        let mut plans = Vec::new();
        loop {
            let plan = self.step(views, script);
            let done = plan.stats.converged && plans.len() as u64 > DELAY;
            plans.push(plan);
            if done {
                return plans;
            }
            assert!(
                t.elapsed() < Duration::from_secs(20),
                "no convergence: {:?}",
                plans.last().map(|p| p.stats)
            );
            std::thread::sleep(Duration::from_millis(1));
        }
    }
}

fn config() -> OutOfCoreConfig {
    OutOfCoreConfig {
        cpu_budget_bytes: 8 << 20,
        gpu_budget_bytes: 4 << 20,
        upload_budget_bytes: 1 << 30,
        tolerance_px: 0.0,
        fade: None,
        ..OutOfCoreConfig::default()
    }
}

/// A camera looking at the ball from `+x`.
fn camera(yaw: f32) -> Camera {
    Camera::orbit(Vec3::ZERO, 1.8, yaw, 0.2)
}

/// The far half (`x` above the middle) of the octree cube: a node wholly in it.
fn far_half(key: NodeKey) -> bool {
    let (o, _) = key.unit_box();
    key.level > 0 && o[0] >= 0.5
}

fn data_leaves(plan: &StreamPlan) -> Vec<NodeKey> {
    plan.leaves.iter().map(|l| l.1).collect()
}

/// Ray-guided culling: once the feedback says the far half shows no ray,
/// its nodes are not refined past the level they were seen at and request
/// nothing; when it shows again (disocclusion), it refines to the finest
/// level.
#[test]
fn ray_guided_culling_keeps_hidden_bricks_out_and_brings_them_back() {
    let mut rig = Rig::new(
        64,
        OutOfCoreConfig {
            visibility: VisibilityPolicy::RayGuided,
            ..config()
        },
    );
    let finest = rig.streamer.layout().levels - 1;
    let views = [rig.view(camera(0.3))];
    let hidden: &Script = &|k| {
        if far_half(k) {
            (0, 0.0, 0)
        } else {
            (500, 1.0, 500)
        }
    };
    let plans = rig.converge(&views, hidden);
    let last = plans.last().expect("a plan");
    let leaves = data_leaves(last);
    assert!(
        leaves
            .iter()
            .filter(|k| far_half(**k))
            .all(|k| k.level <= 1),
        "a hidden node was refined: {:?}",
        leaves
            .iter()
            .filter(|k| far_half(**k) && k.level > 1)
            .collect::<Vec<_>>()
    );
    assert!(leaves.iter().any(|k| !far_half(*k) && k.level == finest));
    // Settled: hidden nodes request nothing.
    assert_eq!(last.stats.cache.requested_this_frame, 0);
    let culled = leaves.len();

    // Disocclusion: everything shows; the far half refines fully.
    let all: &Script = &|_| (500, 1.0, 500);
    let plans = rig.converge(&views, all);
    let leaves = data_leaves(plans.last().expect("a plan"));
    assert!(leaves.iter().any(|k| far_half(*k) && k.level == finest));
    assert!(leaves.len() > culled, "{} <= {culled}", leaves.len());
    // Without feedback the same view needs as many bricks as the disoccluded one.
    let mut none = Rig::new(64, config());
    let reference = data_leaves(none.converge(&views, all).last().expect("plan"));
    assert_eq!(
        leaves.iter().copied().collect::<HashSet<_>>(),
        reference.into_iter().collect::<HashSet<_>>()
    );
}

/// Occlusion scheduling: with a few queries per frame, every data leaf of a
/// settled cut (all on screen, none reaching behind the eye) is queried
/// within the rotation's period, and results that say "hidden" cull.
#[test]
fn occlusion_queries_cover_every_leaf_within_their_period() {
    let mut rig = Rig::new(
        64,
        OutOfCoreConfig {
            visibility: VisibilityPolicy::OcclusionQueries,
            visibility_config: VisibilityConfig {
                queries_per_frame: 5,
                ..VisibilityConfig::default()
            },
            tolerance_px: 4.0,
            ..config()
        },
    );
    let views = [rig.view(camera(0.3))];
    let visible: &Script = &|_| (1, 1.0, 100);
    let plans = rig.converge(&views, visible);
    let last = plans.last().expect("a plan");
    let leaves: HashSet<NodeKey> = data_leaves(last).into_iter().collect();
    let period = last.queries[0].schedule.period as usize;
    assert!(period > 1, "the budget should force a rotation: {period}");
    assert!(leaves.len() > 5);
    let mut seen = HashSet::new();
    for _ in 0..period {
        let plan = rig.step(&views, visible);
        assert_eq!(data_leaves(&plan).len(), leaves.len(), "the cut moved");
        assert!(plan.queries[0].keys.len() <= 5);
        assert_eq!(plan.queries[0].keys.len(), plan.queries[0].boxes.len());
        seen.extend(plan.queries[0].keys.iter().copied());
    }
    assert_eq!(seen, leaves, "leaves not queried within {period} frames");
    // The visibility state holds a leaf at least through the rotation.
    assert!(rig.streamer.visibility().config().hold_frames >= period as u32);
    // Queries answering "no sample passed" cull the far half: a leaf seen
    // visible stays so for the hold (one rotation), so within two rotations
    // and the read-back delay every far leaf is found hidden.
    let hidden: &Script = &|k| {
        if far_half(k) {
            (1, 1.0, 0)
        } else {
            (1, 1.0, 100)
        }
    };
    let mut last = None;
    for _ in 0..2 * period + DELAY as usize + 1 {
        last = Some(rig.step(&views, hidden));
    }
    let last = last.expect("plan");
    let counts = last.stats.visibility;
    let far = |keys: &mut dyn Iterator<Item = NodeKey>| keys.filter(|k| far_half(*k)).count();
    let (before, after) = (
        far(&mut leaves.iter().copied()),
        far(&mut data_leaves(&last).into_iter()),
    );
    assert!(counts.invisible > 0, "{counts:?}");
    assert!(after < before, "hidden leaves kept: {after} of {before}");
}

/// Visible weights: under `VisibleError` with a brick budget the bricks go
/// where the measured weights say the image shows the volume.
#[test]
fn visible_weights_order_refinement() {
    let budget = 40;
    // (Weights rank only nodes with error records, as a store's have.)
    let mut src = TestSource::new(64);
    src.errors = true;
    let mut rig = Rig::over(
        src,
        OutOfCoreConfig {
            lod_metric: LodMetric::VisibleError { budget: 0.0 },
            brick_budget: Some(budget),
            ..config()
        },
    );
    let views = [rig.view(camera(0.3))];
    // The near half shows 50 times what the far half does.
    let weights: &Script = &|k| {
        let (_, side) = k.unit_box();
        let v = side * side * side;
        if far_half(k) {
            (10, v, 10)
        } else {
            (10, 50.0 * v, 10)
        }
    };
    let plans = rig.converge(&views, weights);
    let last = plans.last().expect("plan");
    assert!(last.measures_weights);
    let leaves = data_leaves(last);
    assert!(leaves.len() as u32 <= budget);
    let depth = |far: bool| -> u32 {
        leaves
            .iter()
            .filter(|k| far_half(**k) == far && k.level > 0)
            .map(|k| k.level as u32)
            .sum()
    };
    let (near, far) = (depth(false), depth(true));
    assert!(near > 2 * far, "near {near} far {far}: {leaves:?}");
    // Mirrored weights mirror the cut (a new planner: within one view the
    // weights a node split with hold it split, by design).
    let mut src = TestSource::new(64);
    src.errors = true;
    let mut rig = Rig::over(
        src,
        OutOfCoreConfig {
            lod_metric: LodMetric::VisibleError { budget: 0.0 },
            brick_budget: Some(budget),
            ..config()
        },
    );
    let mirrored: &Script = &|k| {
        let (_, side) = k.unit_box();
        let v = side * side * side;
        if far_half(k) {
            (10, 50.0 * v, 10)
        } else {
            (10, v, 10)
        }
    };
    let plans = rig.converge(&views, mirrored);
    let leaves = data_leaves(plans.last().expect("plan"));
    let depth = |far: bool| -> u32 {
        leaves
            .iter()
            .filter(|k| far_half(**k) == far && k.level > 0)
            .map(|k| k.level as u32)
            .sum()
    };
    assert!(depth(true) > 2 * depth(false), "{leaves:?}");
}

/// Keys the planner has uploaded since `from` (plans of later frames).
fn uploaded(plans: &[StreamPlan]) -> Vec<NodeKey> {
    plans
        .iter()
        .flat_map(|p| p.uploads.iter().map(|u| u.key))
        .collect()
}

/// Changing the tolerance, the LOD metric, the fade or the visibility policy
/// uploads no brick that is already resident; changing the GPU budget
/// rebuilds the pool (and the next frames upload the working set again).
#[test]
fn configuration_changes_upload_nothing_resident() {
    let mut rig = Rig::new(
        64,
        OutOfCoreConfig {
            tolerance_px: 2.0,
            ..config()
        },
    );
    let views = [rig.view(camera(0.3))];
    let all: &Script = &|_| (500, 1.0, 500);
    rig.converge(&views, all);
    type Change = Box<dyn Fn(&mut OutOfCoreConfig)>;
    let changes: Vec<(&str, Change)> = vec![
        ("tolerance", Box::new(|c| c.tolerance_px = 0.5)),
        (
            "metric",
            Box::new(|c| c.lod_metric = LodMetric::VisibleError { budget: 0.0 }),
        ),
        (
            "fade",
            Box::new(|c| c.fade = Some(crate::FadeDuration::Frames(3))),
        ),
        (
            "visibility",
            Box::new(|c| c.visibility = VisibilityPolicy::RayGuided),
        ),
        ("coarser", Box::new(|c| c.tolerance_px = 8.0)),
        (
            "back",
            Box::new(|c| {
                *c = OutOfCoreConfig {
                    tolerance_px: 2.0,
                    ..config()
                }
            }),
        ),
    ];
    for (what, change) in changes {
        let resident: HashSet<NodeKey> = rig.streamer.pool().resident().map(|(k, _)| k).collect();
        let slots = rig.streamer.pool().slot_count();
        let mut c = *rig.streamer.config();
        change(&mut c);
        let r = rig.streamer.configure(c).expect(what);
        assert!(!r.pool, "{what}: the pool was rebuilt");
        assert_eq!(rig.streamer.pool().slot_count(), slots);
        let plans = rig.converge(&views, all);
        let again: Vec<NodeKey> = uploaded(&plans)
            .into_iter()
            .filter(|k| resident.contains(k))
            .collect();
        assert!(again.is_empty(), "{what}: re-uploaded {again:?}");
    }
    // The GPU budget: the pool is rebuilt, the working set uploaded again.
    let resident: HashSet<NodeKey> = rig.streamer.pool().resident().map(|(k, _)| k).collect();
    let c = OutOfCoreConfig {
        gpu_budget_bytes: 2 << 20,
        ..*rig.streamer.config()
    };
    assert!(rig.streamer.configure(c).expect("budget").pool);
    assert_eq!(rig.streamer.pool().occupied(), 0);
    let plans = rig.converge(&views, all);
    assert!(uploaded(&plans).iter().any(|k| resident.contains(k)));
    // A refused configuration changes nothing.
    let bad = OutOfCoreConfig {
        tolerance_px: f32::NAN,
        ..*rig.streamer.config()
    };
    assert!(rig.streamer.configure(bad).is_err());
    assert_eq!(rig.streamer.config().tolerance_px, 2.0);
}

/// The deepest level at which `cut` covers `key`'s region: every leaf of a
/// per-view cut must be matched or refined in the cut of several views.
fn covered_at(cut: &HashMap<NodeKey, ()>, key: NodeKey) -> bool {
    // `key` itself, or a descendant of it, is in the combined cut: no
    // ancestor of `key` is a leaf there.
    let mut a = key.parent();
    while let Some(p) = a {
        if cut.contains_key(&p) {
            return false;
        }
        a = p.parent();
    }
    true
}

/// Two views of one volume (a stereo pair; a perspective view and an
/// orthographic one along an axis) refine one cut that holds each region at
/// the finest level either view needs alone, and read each brick once.
#[test]
fn two_views_refine_one_cut_that_satisfies_both() {
    let cases: [(&str, [Camera; 2]); 2] = [
        (
            "stereo",
            [
                Camera::orbit(Vec3::new(-0.03, 0.0, 0.0), 1.2, 0.3, 0.2),
                Camera::orbit(Vec3::new(0.03, 0.0, 0.0), 1.2, 0.3, 0.2),
            ],
        ),
        (
            "3d + orthogonal",
            [
                Camera::orbit(Vec3::ZERO, 1.1, 0.9, 0.3),
                Camera {
                    projection: brickray_core::Projection::Orthographic { height: 0.5 },
                    ..Camera::orbit(Vec3::new(0.2, 0.0, 0.0), 3.0, 0.0, 0.0)
                },
            ],
        ),
    ];
    let all: &Script = &|_| (500, 1.0, 500);
    for (name, cams) in cases {
        let cfg = OutOfCoreConfig {
            tolerance_px: 1.0,
            ..config()
        };
        let mut both = Rig::new(64, cfg);
        let views = [both.view(cams[0]), both.view(cams[1])];
        let plans = both.converge(&views, all);
        let cut: HashMap<NodeKey, ()> = plans
            .last()
            .expect("plan")
            .cut
            .iter()
            .map(|l| (l.key, ()))
            .collect();
        let reads = both.src.reads();
        let unique: HashSet<NodeKey> = reads.iter().copied().collect();
        assert_eq!(reads.len(), unique.len(), "{name}: a brick read twice");
        for v in &views {
            let mut alone = Rig::new(64, cfg);
            let plans = alone.converge(&[*v], all);
            let fine = data_leaves(plans.last().expect("plan"));
            assert!(!fine.is_empty());
            for k in fine {
                assert!(
                    covered_at(&cut, k),
                    "{name}: {k:?} is coarser in the shared cut"
                );
            }
        }
    }
}
