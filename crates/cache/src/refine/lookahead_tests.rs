//! Refinement with [`RefineParams::lookahead`]: bricks one level past a
//! split that waits, requested over a source whose every level costs a
//! round trip.

use super::tests::{Setup, ball_info, keys, mip_params, setup};
use super::*;
use brickray_core::Camera;
use glam::Vec3;
use std::collections::HashSet;

/// Bricks of `loaded` in CPU memory, every other brick missing; metadata
/// from the ball.
struct Streaming {
    layout: OctreeLayout,
    loaded: HashSet<NodeKey>,
}

impl RefineEnv for Streaming {
    fn node(&mut self, key: NodeKey) -> MetaState {
        MetaState::Known(ball_info(&self.layout, key).into())
    }
    fn data(&mut self, key: NodeKey) -> DataState {
        if self.loaded.contains(&key) {
            DataState::InCpu
        } else {
            DataState::Missing
        }
    }
}

/// Frames until nothing more is requested when every frame's requests
/// arrive by the next (one round trip per frame), the final cut, and every
/// brick requested on the way.
fn stream_until_converged(
    s: &Setup,
    cam: &Camera,
    lookahead: bool,
) -> (usize, Vec<NodeKey>, HashSet<NodeKey>) {
    let views = Views::one(ViewGeometry::new(&s.layout, cam, 1.0, 512, &s.frame));
    let params = RefineParams {
        lookahead,
        ..mip_params(s, &views)
    };
    let mut env = Streaming {
        layout: s.layout.clone(),
        loaded: HashSet::new(),
    };
    let mut requested = HashSet::new();
    for frame in 1..64 {
        let mut b = UploadBudget::new(u64::MAX);
        let r = refine(&s.layout, &params, &mut env, &mut b);
        if r.requests.is_empty() {
            let mut cut = keys(&r);
            cut.sort();
            return (frame, cut, requested);
        }
        for q in &r.requests {
            requested.insert(q.key);
            env.loaded.insert(q.key);
        }
    }
    panic!("no convergence in 64 frames");
}

/// Looking one level ahead draws the same cut in fewer round trips, and
/// requests no brick that the cut's own splits would not have requested on
/// the way (the prediction uses the split's own test).
#[test]
fn lookahead_converges_in_fewer_round_trips_to_the_same_cut() {
    let s = setup();
    for cam in [
        Camera::orbit(Vec3::ZERO, 1.5, 0.3, 0.2),
        Camera::orbit(Vec3::ZERO, 30.0, -0.8, 0.4),
    ] {
        let (frames, cut, requested) = stream_until_converged(&s, &cam, false);
        let (ahead_frames, ahead_cut, ahead_requested) = stream_until_converged(&s, &cam, true);
        println!(
            "{frames} frames without lookahead, {ahead_frames} with; {} and {} bricks requested",
            requested.len(),
            ahead_requested.len()
        );
        assert_eq!(cut, ahead_cut);
        assert!(
            cut.iter().any(|k| k.level >= 2),
            "the view must refine past level 1: {cut:?}"
        );
        assert!(
            ahead_frames < frames,
            "{ahead_frames} frames with lookahead, {frames} without"
        );
        assert!(
            ahead_requested.is_subset(&requested),
            "asked ahead for bricks never needed: {:?}",
            ahead_requested.difference(&requested).collect::<Vec<_>>()
        );
    }
}

/// A child within the tolerance would not split: nothing past it is asked
/// for (a far view whose root alone is wanted requests nothing ahead).
#[test]
fn lookahead_asks_nothing_past_children_that_would_not_split() {
    let s = setup();
    // Far enough that level 1 is within the tolerance, close enough that the
    // root is not.
    let views_at = |d: f32| {
        Views::one(ViewGeometry::new(
            &s.layout,
            &Camera::orbit(Vec3::ZERO, d, 0.3, 0.2),
            1.0,
            512,
            &s.frame,
        ))
    };
    let mut found = false;
    for d in [20.0f32, 30.0, 45.0, 60.0, 90.0, 130.0] {
        let views = views_at(d);
        let params = RefineParams {
            lookahead: true,
            ..mip_params(&s, &views)
        };
        let mut env = Streaming {
            layout: s.layout.clone(),
            loaded: [NodeKey::ROOT].into_iter().collect(),
        };
        let r = refine(
            &s.layout,
            &params,
            &mut env,
            &mut UploadBudget::new(u64::MAX),
        );
        let levels: HashSet<u8> = r.requests.iter().map(|q| q.key.level).collect();
        if levels == [1u8].into_iter().collect() {
            found = true;
        }
        assert!(r.requests.iter().all(|q| q.key.level <= 2), "{levels:?}");
    }
    assert!(found, "no distance wanted level 1 alone");
}
