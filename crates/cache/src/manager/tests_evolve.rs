//! A moving view's cut evolved from the last frame's
//! ([`OutOfCoreConfig::evolve`]) against the cut refined from the root.

use super::tests::{check_plan, config, converge, manager};
use super::*;
use crate::test_source::TestSource;
use brickray_core::{Camera, LeafKind, RenderMode, TransferFunction};
use glam::Vec3;

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

/// Two managers over one source, one evolving a moving view's cut and one
/// refining it from the root, along the same path: every plan of the
/// evolving one is whole, it evolves the moving frames but every
/// [`EVOLVED_FRAMES_MAX`]-th, and once the view stops both converge to the
/// same cut.
fn evolve_then_stop(config: OutOfCoreConfig, dim: u32) {
    let src = Arc::new(TestSource::new(dim));
    let mut evolving = manager(&src, config);
    let mut exact = manager(
        &src,
        OutOfCoreConfig {
            evolve: false,
            ..config
        },
    );
    let tf = TransferFunction::ramp(0.1, 1.0, 0.5);
    let cam = |i: usize| Camera::orbit(Vec3::ZERO, 1.3, 0.4 + 0.01 * i as f32, 0.3);
    let mut frame = 0;
    converge(
        &mut evolving,
        &mut frame,
        &cam(0),
        RenderMode::Dvr,
        &tf,
        |_, _| {},
    );
    converge(
        &mut exact,
        &mut frame,
        &cam(0),
        RenderMode::Dvr,
        &tf,
        |_, _| {},
    );
    let moves = EVOLVED_FRAMES_MAX as usize + 8;
    let (mut evolved, mut from_root) = (Vec::new(), 0);
    for i in 1..=moves {
        frame += 1;
        let p = evolving.update_view(&cam(i), 1.0, 128, frame, RenderMode::Dvr, &tf);
        check_plan(&evolving, &p);
        match p.stats.refine_evolved {
            // (Never converged: the still view after it refines from the
            // root, so a planner that stops planning converged views
            // plans it.)
            true => {
                assert!(!p.stats.converged(), "an evolved cut converged");
                evolved.push(i);
            }
            false => from_root += 1,
        }
        let q = exact.update_view(&cam(i), 1.0, 128, frame, RenderMode::Dvr, &tf);
        assert!(!q.stats.refine_evolved);
    }
    // Every moving frame but the one after EVOLVED_FRAMES_MAX in a row.
    assert_eq!(from_root, 1, "frames evolved: {evolved:?}");
    assert_eq!(evolved.len(), moves - 1);
    let a = converge(
        &mut evolving,
        &mut frame,
        &cam(moves),
        RenderMode::Dvr,
        &tf,
        |_, p| {
            assert!(!p.stats.refine_evolved, "a still view evolved");
        },
    );
    let b = converge(
        &mut exact,
        &mut frame,
        &cam(moves),
        RenderMode::Dvr,
        &tf,
        |_, _| {},
    );
    assert_eq!(nodes(&a), nodes(&b));
    assert_eq!(a.refined, b.refined);
}

#[test]
fn a_moving_view_evolves_and_a_still_one_converges_to_the_same_cut_where_the_tolerance_binds() {
    evolve_then_stop(
        OutOfCoreConfig {
            gpu_budget_bytes: 16 << 20,
            cpu_budget_bytes: 32 << 20,
            ..config()
        },
        64,
    );
}

#[test]
fn a_moving_view_evolves_and_a_still_one_converges_to_the_same_cut_where_the_pool_binds() {
    evolve_then_stop(
        OutOfCoreConfig {
            tolerance_px: 0.0,
            brick_budget: Some(60),
            ..config()
        },
        128,
    );
}
