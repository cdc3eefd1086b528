//! Refinement with metadata not yet known or failed, failed bricks, non-finite
//! views and the per-frame request caps.

use super::tests::{assert_exact_cover, ball_info, keys, setup};
use super::*;
use brickray_core::Projection;
#[allow(unused_imports)]
use brickray_core::{Camera, NodeKind, RenderMode, TransferFunction, VolumeFrame};
use glam::{Mat4, Vec3};
use std::collections::HashSet;

/// Metadata known only for `known` (or everything), failed for `meta_failed`;
/// bricks missing from level `missing_from` on (else in CPU memory), failed for
/// `data_failed`.
struct Scripted {
    layout: OctreeLayout,
    known: Option<HashSet<NodeKey>>,
    meta_failed: HashSet<NodeKey>,
    missing_from: u8,
    data_failed: HashSet<NodeKey>,
    meta_calls: usize,
}

impl Scripted {
    fn new(layout: &OctreeLayout) -> Scripted {
        Scripted {
            layout: layout.clone(),
            known: None,
            meta_failed: HashSet::new(),
            missing_from: u8::MAX,
            data_failed: HashSet::new(),
            meta_calls: 0,
        }
    }
}

impl RefineEnv for Scripted {
    fn node(&mut self, key: NodeKey) -> MetaState {
        self.meta_calls += 1;
        if self.meta_failed.contains(&key) {
            MetaState::Failed
        } else if self.known.as_ref().is_none_or(|k| k.contains(&key)) {
            MetaState::Known(ball_info(&self.layout, key).into())
        } else {
            MetaState::Pending
        }
    }
    fn data(&mut self, key: NodeKey) -> DataState {
        if self.data_failed.contains(&key) {
            DataState::Failed
        } else if key.level >= self.missing_from {
            DataState::Missing
        } else {
            DataState::InCpu
        }
    }
}

fn refine_with(env: &mut Scripted, cam: &Camera, slots: u32) -> Refinement {
    let s = setup();
    refine_in(env, cam, &s.frame, 1.0, slots)
}

fn refine_in(
    env: &mut Scripted,
    cam: &Camera,
    frame: &VolumeFrame,
    aspect: f32,
    slots: u32,
) -> Refinement {
    let s = setup();
    let params = RefineParams {
        views: &Views::one(ViewGeometry::new(&s.layout, cam, aspect, 512, frame)),
        generation: 0,
        mode: RenderMode::Mip,
        tf: &s.tf,
        channels: &[],
        tolerance_px: 1.0,
        metric: brickray_core::LodMetric::Geometric,
        max_data_leaves: slots,
        max_requests: MIN_REQUESTS_PER_FRAME,
        max_prefetch: u32::MAX,
        brick_upload_bytes: 1000,
        lookahead: false,
    };
    let mut b = UploadBudget::new(u64::MAX);
    let r = refine(&s.layout, &params, env, &mut b);
    assert_exact_cover(&keys(&r), s.layout.levels);
    r
}

fn close() -> Camera {
    Camera::orbit(Vec3::ZERO, 1.5, 0.3, 0.2)
}

#[test]
fn unknown_metadata_is_requested_and_blocks_the_split() {
    let s = setup();
    let mut env = Scripted::new(&s.layout);
    // Nothing known: the root waits for its metadata, first in line.
    env.known = Some(HashSet::new());
    let r = refine_with(&mut env, &close(), 1000);
    assert_eq!(r.leaves.len(), 1);
    assert_eq!(r.leaves[0].class, NodeClass::Empty(EmptyReason::NotLoaded));
    assert_eq!(r.meta_requests, vec![(NodeKey::ROOT, f32::MAX)]);
    assert!(r.requests.is_empty());
    assert_eq!(r.blocked.missing_meta, 1);
    // The root known: it is a data leaf and its children's metadata is wanted,
    // at the root's priority.
    env.known = Some(HashSet::from([NodeKey::ROOT]));
    let r = refine_with(&mut env, &close(), 1000);
    assert_eq!(keys(&r), vec![NodeKey::ROOT]);
    assert_eq!(r.leaves[0].class, NodeClass::Data);
    let wanted: Vec<NodeKey> = r.meta_requests.iter().map(|m| m.0).collect();
    assert_eq!(wanted, NodeKey::ROOT.children().to_vec());
    assert!(r.meta_requests.iter().all(|m| m.1 == r.leaves[0].priority));
    assert_eq!(
        (r.blocked.missing_meta, r.blocked.failed, r.failed_needed),
        (1, 0, 0)
    );
    // Everything known: the split goes through.
    env.known = None;
    let r = refine_with(&mut env, &close(), 1000);
    assert!(r.leaves.len() > 8 && r.meta_requests.is_empty());
    assert_eq!(r.blocked.missing_meta, 0);
}

#[test]
fn failed_metadata_or_bricks_block_splits_and_count_as_needed() {
    let s = setup();
    let c = NodeKey::ROOT.child(3);
    for failed_meta in [true, false] {
        let mut env = Scripted::new(&s.layout);
        if failed_meta {
            env.meta_failed.insert(c);
        } else {
            env.data_failed.insert(c);
        }
        let r = refine_with(&mut env, &close(), 1000);
        // The root cannot split without its child: a degraded, coarse cut.
        assert_eq!(keys(&r), vec![NodeKey::ROOT]);
        assert_eq!(r.leaves[0].class, NodeClass::Data);
        assert_eq!((r.blocked.failed, r.failed_needed), (1, 1));
        assert!(r.requests.is_empty() && r.meta_requests.is_empty());
    }
    // The root itself failed.
    let mut env = Scripted::new(&s.layout);
    env.meta_failed.insert(NodeKey::ROOT);
    let r = refine_with(&mut env, &close(), 1000);
    assert_eq!(r.leaves[0].class, NodeClass::Empty(EmptyReason::Failed));
    assert_eq!((r.failed_needed, r.data_leaves), (1, 0));
    let mut env = Scripted::new(&s.layout);
    env.data_failed.insert(NodeKey::ROOT);
    // A far view keeps the root a leaf: its brick is needed and failed.
    let far = Camera::orbit(Vec3::ZERO, 400.0, 0.3, 0.2);
    let r = refine_with(&mut env, &far, 1000);
    assert_eq!(r.leaves[0].class, NodeClass::Empty(EmptyReason::Failed));
    assert_eq!((r.failed_needed, r.data_leaves), (1, 0));
    // Close up the root is split (its children are there): nothing is degraded.
    let r = refine_with(&mut env, &close(), 1000);
    assert!(r.leaves.len() > 8);
    assert_eq!(r.failed_needed, 0);
}

/// A non-finite camera, aspect, viewport or frame neither loops nor requests:
/// the projected size is not finite, so nothing is refined.
#[test]
fn non_finite_views_request_at_most_the_root() {
    let s = setup();
    let nan = f32::NAN;
    let base = close();
    let mut cams = vec![
        Camera {
            eye: Vec3::splat(nan),
            ..base
        },
        Camera {
            eye: Vec3::new(f32::INFINITY, 0.0, 1.0),
            ..base
        },
        Camera {
            target: Vec3::splat(nan),
            ..base
        },
        Camera {
            near: nan,
            far: nan,
            ..base
        },
    ];
    for fov_y in [nan, 0.0, f32::INFINITY] {
        cams.push(Camera {
            projection: Projection::Perspective { fov_y },
            ..base
        });
    }
    for height in [nan, 0.0, f32::INFINITY] {
        cams.push(Camera {
            projection: Projection::Orthographic { height },
            ..base
        });
    }
    let bad_frame = VolumeFrame {
        model: Mat4::from_scale(Vec3::splat(nan)),
        ..s.frame
    };
    let mut views: Vec<(Camera, VolumeFrame, f32)> =
        cams.into_iter().map(|c| (c, s.frame, 1.0)).collect();
    views.push((base, bad_frame, 1.0));
    views.push((base, s.frame, nan));
    for (cam, frame, aspect) in views {
        // Worst case: no brick in memory.
        let mut env = Scripted::new(&s.layout);
        env.missing_from = 0;
        let r = refine_in(&mut env, &cam, &frame, aspect, 10_000);
        assert!(
            r.requests.len() <= 1,
            "{cam:?}: {} requests",
            r.requests.len()
        );
        assert!(r.meta_requests.len() <= 8, "{cam:?}");
        assert!(
            env.meta_calls <= 9,
            "{cam:?}: {} metadata lookups",
            env.meta_calls
        );
        assert!(r.leaves.iter().all(|l| l.priority.is_finite()));
    }
}

#[test]
fn requests_per_frame_are_capped_by_slots_and_the_constant() {
    let s = setup();
    // Bricks of levels 0..3 in memory, level 3 missing: 64 level-2 splits each
    // want up to 8 bricks.
    for (slots, cap) in [(10_000, MIN_REQUESTS_PER_FRAME), (100, 100), (20, 20)] {
        let mut env = Scripted::new(&s.layout);
        env.missing_from = 3;
        let r = refine_with(&mut env, &close(), slots);
        assert_eq!(r.requests.len() as u32, cap, "{slots} slots");
        let unique: HashSet<NodeKey> = r.requests.iter().map(|q| q.key).collect();
        assert_eq!(unique.len(), r.requests.len());
        // Highest priority first.
        assert!(
            r.requests
                .windows(2)
                .all(|w| w[0].priority >= w[1].priority)
        );
        assert!(r.blocked.missing_data as usize * 8 >= r.requests.len());
    }
}

#[test]
fn the_request_cap_follows_the_pool_and_the_upload_budget() {
    // The pool bounds it; else four frames of uploads, at least the floor.
    assert_eq!(requests_per_frame(100, 1 << 30, 1000), 100);
    assert_eq!(
        requests_per_frame(100_000, 1 << 10, 1000),
        MIN_REQUESTS_PER_FRAME
    );
    assert_eq!(requests_per_frame(100_000, 16 << 20, 46_656), 1438);
    assert_eq!(requests_per_frame(100_000, u64::MAX, 0), 100_000);
    assert_eq!(requests_per_frame(0, 1 << 20, 1000), 0);
}
