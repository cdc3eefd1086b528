//! The coarse floor and the fades through the manager: no hole under a tiny
//! pool and CPU cache while the camera circles; fades keep every drawn leaf
//! and fallback resident and end.

use super::tests::{brick_bytes, check_plan, config, manager, slot_bytes};
use super::*;
use crate::fade::FadeDuration;
use crate::test_source::TestSource;
#[allow(unused_imports)]
use brickray_core::{Camera, RenderMode, TransferFunction, VolumeFrame};
use glam::Vec3;
use std::time::Duration;

/// Circles (and dives in and out) with a pool of `slots` slots and a CPU cache
/// of nine bricks; returns (most holes in a frame once the root was drawn,
/// frames with fades, the manager).
fn circle(floor_slots: u32, fade: Option<FadeDuration>, slots: u64) -> (u32, u32, BrickManager) {
    let src = Arc::new(TestSource::new(128));
    let mut m = manager(
        &src,
        OutOfCoreConfig {
            gpu_budget_bytes: slots * slot_bytes(&src),
            cpu_budget_bytes: 9 * brick_bytes(&src),
            floor_slots,
            fade,
            ..config()
        },
    );
    let tf = TransferFunction::ramp(0.1, 1.0, 0.5);
    let (mut holes_max, mut fading, mut drawn) = (0, 0, false);
    for frame in 1..=400u64 {
        let a = frame as f32 * 0.05;
        let d = 0.9 + 0.7 * (frame as f32 * 0.031).sin();
        let cam = Camera::orbit(Vec3::ZERO, d, a, 0.3 * a.cos());
        let plan = m.update_view(&cam, 1.0, 128, frame, RenderMode::Dvr, &tf);
        check_plan(&m, &plan);
        drawn |= plan.stats.holes == 0;
        if drawn {
            holes_max = holes_max.max(plan.stats.holes);
        }
        fading += (plan.stats.fading > 0) as u32;
        std::thread::sleep(Duration::from_millis(1));
    }
    (holes_max, fading, m)
}

#[test]
fn the_floor_prevents_holes_under_a_tiny_pool_while_circling() {
    let (holes, _, m) = circle(crate::DEFAULT_FLOOR_SLOTS, None, 40);
    assert!(!m.floor().is_empty());
    assert_eq!(holes, 0, "a frame had a leaf without a brick");
    let (no_floor, _, _) = circle(0, None, 40);
    eprintln!("holes_max with the floor {holes}, without {no_floor}");
}

#[test]
fn fades_under_a_tiny_pool_keep_every_leaf_drawable() {
    let (holes, fading, _) = circle(
        crate::DEFAULT_FLOOR_SLOTS,
        Some(FadeDuration::Frames(6)),
        48,
    );
    assert_eq!(holes, 0);
    assert!(fading > 0, "the path never faded");
}

#[test]
fn floor_nodes_fit_the_pool() {
    let src = Arc::new(TestSource::new(128));
    let l = &src.layout;
    for slots in [9u32, 12, 36, 40, 100, 1000] {
        let f = super::lod::floor_nodes(l, slots, crate::DEFAULT_FLOOR_SLOTS);
        assert!(f.len() as u32 <= slots / 4);
        assert!(slots - f.len() as u32 >= crate::MIN_RESIDENT_BRICKS);
        // Whole levels, top down.
        let deepest = f.iter().map(|k| k.level).max();
        if let Some(d) = deepest {
            let n: usize = (0..=d).map(|lv| 1usize << (3 * lv as usize)).sum();
            assert_eq!(f.len(), n);
        }
    }
    assert_eq!(super::lod::floor_nodes(l, 1000, 0), vec![]);
}
