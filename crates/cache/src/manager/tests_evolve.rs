//! A moving view's cut evolved from the last frame's
//! ([`OutOfCoreConfig::evolve`]) against the cut refined from the root.

use super::tests::{check_plan, config, manager};
use super::*;
use crate::test_source::TestSource;
use brickray_core::{Camera, LeafKind, RenderMode, TransferFunction};
use glam::Vec3;
use std::time::{Duration, Instant};

/// The cut's nodes and what each holds (slots aside: two managers give the
/// same brick different slots).
fn nodes(plan: &FramePlan) -> Vec<(NodeKey, bool)> {
    let mut v: Vec<_> = plan
        .cut
        .iter()
        .map(|l| (l.key, matches!(l.kind, LeafKind::Data { .. })))
        .collect();
    v.sort();
    v
}

/// Visibility feedback as refinement sees it: the subtree under the key
/// may not split.
struct Hide(NodeKey);

impl SplitFilter for Hide {
    fn may_split(&mut self, key: NodeKey) -> bool {
        !std::iter::successors(Some(key), |p| p.parent()).any(|p| p == self.0)
    }
}

/// One frame of `cam` (DVR), under `hide` where given.
fn plan(m: &mut BrickManager, cam: &Camera, frame: u64, hide: Option<NodeKey>) -> FramePlan {
    let tf = TransferFunction::ramp(0.1, 1.0, 0.5);
    let mut filter = hide.map(Hide);
    let filter = filter.as_mut().map(|f| f as &mut dyn SplitFilter);
    let p = m.update_view_filtered(cam, 1.0, 128, frame, RenderMode::Dvr, &tf, filter);
    check_plan(m, &p);
    p
}

/// Frames of `cam` until nothing is loading or pending; none evolved.
fn settle(m: &mut BrickManager, frame: &mut u64, cam: &Camera, hide: Option<NodeKey>) -> FramePlan {
    let t = Instant::now();
    loop {
        *frame += 1;
        let p = plan(m, cam, *frame, hide);
        assert!(!p.stats.refine_evolved, "a still view evolved");
        if p.stats.settled() {
            return p;
        }
        assert!(t.elapsed() < Duration::from_secs(10), "{:?}", p.stats);
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// Two managers over one source, one evolving a moving view's cut and one
/// refining it from the root, along the same path (under `hide`, where
/// given, from the path's tenth frame on): every plan of the evolving one
/// is whole, it evolves the moving frames but every
/// [`EVOLVED_FRAMES_MAX`]-th and never counts an evolved cut as converged,
/// and once the view stops both converge to the same cut. The provisional
/// frames evolved (a provisional cut never counts as converged).
fn evolve_then_stop(config: OutOfCoreConfig, dim: u32, hide: Option<NodeKey>) -> usize {
    let src = Arc::new(TestSource::new(dim));
    let mut evolving = manager(&src, config);
    let mut exact = manager(
        &src,
        OutOfCoreConfig {
            evolve: false,
            ..config
        },
    );
    let cam = |i: usize| Camera::orbit(Vec3::ZERO, 1.3, 0.4 + 0.01 * i as f32, 0.3);
    let mut frame = 0;
    settle(&mut evolving, &mut frame, &cam(0), None);
    settle(&mut exact, &mut frame, &cam(0), None);
    let moves = EVOLVED_FRAMES_MAX as usize + 8;
    let (mut evolved, mut from_root, mut provisional) = (Vec::new(), 0, 0);
    for i in 1..=moves {
        frame += 1;
        let hidden = hide.filter(|_| i >= 10);
        let p = plan(&mut evolving, &cam(i), frame, hidden);
        match p.stats.refine_evolved {
            true => evolved.push(i),
            false => from_root += 1,
        }
        // A provisional cut never converged: the still view after it is
        // refined from the root, so a planner that stops planning converged
        // views plans it.
        assert!(p.stats.refine_evolved || !p.stats.cut_provisional);
        if p.stats.cut_provisional {
            assert!(!p.stats.converged(), "a provisional cut converged");
            provisional += 1;
        }
        let q = plan(&mut exact, &cam(i), frame, hidden);
        assert!(!q.stats.refine_evolved);
    }
    // Every moving frame but the one after EVOLVED_FRAMES_MAX in a row.
    assert_eq!(from_root, 1, "frames evolved: {evolved:?}");
    assert_eq!(evolved.len(), moves - 1);
    let a = settle(&mut evolving, &mut frame, &cam(moves), hide);
    let b = settle(&mut exact, &mut frame, &cam(moves), hide);
    assert_eq!(nodes(&a), nodes(&b));
    assert_eq!(a.refined, b.refined);
    provisional
}

/// Budgets that hold every brick of the test volume: the tolerance binds.
fn ample() -> OutOfCoreConfig {
    OutOfCoreConfig {
        gpu_budget_bytes: 16 << 20,
        cpu_budget_bytes: 32 << 20,
        ..config()
    }
}

#[test]
fn a_moving_view_evolves_and_a_still_one_converges_to_the_same_cut_where_the_tolerance_binds() {
    // (Where the tolerance binds an evolved cut is the greedy one: never
    // provisional.)
    let provisional = evolve_then_stop(ample(), 64, None);
    assert_eq!(provisional, 0);
}

#[test]
fn a_moving_view_evolves_and_a_still_one_converges_to_the_same_cut_where_the_pool_binds() {
    let provisional = evolve_then_stop(
        OutOfCoreConfig {
            tolerance_px: 0.0,
            brick_budget: Some(60),
            ..config()
        },
        128,
        None,
    );
    assert!(provisional > 0, "the pool never bound");
}

/// With a subtree hidden by the feedback from the path's tenth frame on
/// (the octant the camera looks at: what it held split collapses).
#[test]
fn a_moving_view_evolves_under_visibility_feedback_and_converges_to_the_same_cut() {
    let provisional = evolve_then_stop(ample(), 64, Some(NodeKey::ROOT.child(7)));
    assert_eq!(provisional, 0);
}
