//! Faults while streaming: metadata only from the loader, failures counted and
//! surfaced once, a prompt drop, retries, `converged`, bounded work.

use super::tests::{ManualClock, config, converge, manager, manager_with_clock};
use super::*;
use crate::loader::LoadError;
use crate::refine::MIN_REQUESTS_PER_FRAME;
use crate::test_source::TestSource;
use brickray_core::BrickError;
#[allow(unused_imports)]
use brickray_core::{Camera, RenderMode, TransferFunction, VolumeFrame};
use glam::Vec3;
use std::time::{Duration, Instant};

const BAD: NodeKey = NodeKey {
    level: 1,
    x: 1,
    y: 1,
    z: 1,
};

fn cam() -> Camera {
    Camera::orbit(Vec3::ZERO, 1.6, 0.4, 0.3)
}

fn tf() -> TransferFunction {
    TransferFunction::ramp(0.1, 1.0, 0.5)
}

/// Converges (settles) the test view; returns the plan.
fn settle(m: &mut BrickManager, frame: &mut u64) -> FramePlan {
    converge(m, frame, &cam(), RenderMode::Mip, &tf(), |_, _| {})
}

/// Updates a few frames with `clock` moved by `step` before each.
fn frames(m: &mut BrickManager, frame: &mut u64, clock: &ManualClock, step: Duration, n: u32) {
    for _ in 0..n {
        clock.advance(step);
        *frame += 1;
        m.update_view(&cam(), 1.0, 128, *frame, RenderMode::Mip, &tf());
        std::thread::sleep(Duration::from_millis(2));
    }
}

#[test]
fn update_never_calls_the_source_on_the_render_thread() {
    let mut src = TestSource::new(64);
    // A slow metadata source (5 ms per call) must not slow the frames down:
    // no metadata call happens on this thread.
    src.meta_delay = Duration::from_millis(5);
    let src = Arc::new(src);
    let me = std::thread::current().id();
    let mut m = manager(&src, config());
    let mut frame = 0;
    let plan = settle(&mut m, &mut frame);
    assert!(plan.stats.working_set_bricks > 8);
    assert!(src.meta_reads.load(std::sync::atomic::Ordering::Relaxed) > 8);
    assert_eq!(src.calls_on(me), 0);
    // `preload_root` is set-up time: it waits for its reads (on a thread of
    // its own, under its deadline), and updates still read nothing here.
    let mut m = manager(&src, config());
    let before = src.calls().len();
    m.preload_root().unwrap();
    assert_eq!(
        src.calls().len() - before,
        1 + 1 + 8,
        "root metadata, root brick, children"
    );
    assert_eq!(m.residency(NodeKey::ROOT), Some(Residency::InCpu));
    settle(&mut m, &mut 0);
    assert_eq!(src.calls_on(me), 0);
}

/// Set-up waits for the source at most `setup_deadline`: a root whose
/// metadata or brick does not come back by then fails set-up with a typed
/// error naming the deadline, promptly; the read still blocked finishes
/// later into nothing, and the manager streams normally once the source
/// answers. A child's metadata past the deadline is left to the loader.
#[test]
fn set_up_fails_at_its_deadline_when_the_source_does_not_answer() {
    let deadline = Duration::from_millis(150);
    let child = NodeKey::new(1, 0, 0, 0);
    for (kind, gated) in [
        (FetchKind::Metadata, NodeKey::ROOT),
        (FetchKind::Brick, NodeKey::ROOT),
        (FetchKind::Metadata, child),
    ] {
        let mut src = TestSource::new(64);
        match kind {
            FetchKind::Metadata => src.meta_gate_key = Some(gated),
            FetchKind::Brick => src.gate_key = Some(gated),
        }
        let src = Arc::new(src);
        let m = manager(
            &src,
            OutOfCoreConfig {
                setup_deadline: deadline,
                ..config()
            },
        );
        // (On a thread of the test's, so that a set-up still blocked fails
        // the test instead of hanging it.)
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut m = m;
            let t = Instant::now();
            let r = m.preload_root();
            let _ = tx.send((m, r, t.elapsed()));
        });
        let Ok((mut m, r, took)) = rx.recv_timeout(Duration::from_secs(5)) else {
            src.open_gate();
            panic!("{kind} {gated:?}: set-up still blocked after 5 s");
        };
        assert!(
            took >= deadline,
            "{kind} {gated:?}: returned after {took:?}"
        );
        if gated == child {
            r.unwrap();
            assert_eq!(m.residency(NodeKey::ROOT), Some(Residency::InCpu));
            assert!(m.metadata(child).is_none());
        } else {
            let e = r.unwrap_err();
            assert_eq!((e.key, e.kind), (NodeKey::ROOT, kind));
            assert!(
                matches!(
                    *e.error,
                    LoadError::TimedOut { key: NodeKey::ROOT, kind: k, deadline: d }
                        if k == kind && d == deadline
                ),
                "{e}"
            );
            assert!(e.to_string().contains("150ms"), "{e}");
            assert!(m.failure(NodeKey::ROOT).is_some());
        }
        // The source answers now: the blocked read ends into nothing, and
        // the manager (the root retried) converges.
        src.open_gate();
        std::thread::sleep(Duration::from_millis(20));
        m.retry_failed();
        let plan = settle(&mut m, &mut 0);
        assert!(
            plan.stats.converged() && plan.cut.len() > 8,
            "{kind} {gated:?}"
        );
    }
}

#[test]
fn a_split_waits_for_metadata_and_bricks_bring_their_childrens() {
    let child = NodeKey::new(1, 0, 0, 0);
    let mut src = TestSource::new(64);
    src.meta_gate_key = Some(child);
    let src = Arc::new(src);
    let mut m = manager(&src, config());
    let mut frame = 0;
    let t = Instant::now();
    // The root arrives; its split waits for the held child's metadata.
    let held = loop {
        frame += 1;
        let plan = m.update_view(&cam(), 1.0, 128, frame, RenderMode::Mip, &tf());
        if plan.stats.blocked.missing_meta > 0 && plan.cut[0].kind.is_data() {
            break plan;
        }
        assert!(t.elapsed() < Duration::from_secs(5), "{:?}", plan.stats);
        std::thread::sleep(Duration::from_millis(1));
    };
    assert_eq!(held.cut.len(), 1);
    assert!(held.stats.metadata_in_flight > 0);
    assert!(!held.stats.converged() && !held.stats.settled());
    src.open_gate();
    let plan = settle(&mut m, &mut frame);
    assert!(plan.stats.converged() && plan.cut.len() > 8);

    // After `preload_root` (the root's children's metadata included) every
    // brick job brings its children's metadata, claimed as in flight before the
    // brick is delivered: no node's metadata is read twice.
    let src = Arc::new(TestSource::new(64));
    let mut m = manager(&src, config());
    m.preload_root().unwrap();
    let mut frame = 0;
    let plan = converge(
        &mut m,
        &mut frame,
        &cam(),
        RenderMode::Mip,
        &tf(),
        |_, _| {},
    );
    assert!(plan.stats.converged() && plan.cut.len() > 8);
    let reads = src.calls_of(FetchKind::Metadata);
    let unique: std::collections::HashSet<NodeKey> = reads.iter().copied().collect();
    assert_eq!(unique.len(), reads.len(), "metadata read twice");
    // Every leaf inside the volume has known metadata.
    for l in &plan.cut {
        assert!(m.metadata(l.key).is_some() || !m.layout().in_volume(l.key));
    }
}

#[test]
fn failures_and_panics_of_metadata_and_bricks_are_counted_and_surfaced_once() {
    for (kind, panics) in [
        (FetchKind::Metadata, false),
        (FetchKind::Metadata, true),
        (FetchKind::Brick, false),
        (FetchKind::Brick, true),
    ] {
        let src = Arc::new(TestSource::new(64));
        if panics {
            src.panic_on(kind, BAD);
        } else {
            src.fail(kind, BAD);
        }
        let mut m = manager(&src, config());
        let mut frame = 0;
        let plan = settle(&mut m, &mut frame);
        let s = plan.stats;
        assert!(s.degraded() && !s.converged(), "{kind} {panics}: {s:?}");
        assert_eq!(s.failed_needed, 1);
        assert_eq!(plan.cut.len(), 1, "the root cannot split");
        let f = s.failures;
        match kind {
            FetchKind::Metadata => assert!(f.metadata_errors >= 1 && f.metadata_failed == 1),
            FetchKind::Brick => assert!(f.brick_errors >= 1 && f.bricks_failed == 1),
        }
        assert_eq!(f.panics >= 1, panics);
        let e = m.take_error().expect("one error surfaced");
        assert_eq!((e.key, e.kind), (BAD, kind));
        assert_eq!(
            matches!(*e.error, LoadError::Panicked { .. }),
            panics,
            "{e}"
        );
        assert!(m.take_error().is_none());
        assert!(m.failure(BAD).is_some());
    }
}

#[test]
fn many_failures_surface_as_one_error() {
    let src = Arc::new(TestSource::new(64));
    for c in NodeKey::ROOT.children() {
        src.fail(FetchKind::Brick, c);
    }
    let mut m = manager(&src, config());
    let mut frame = 0;
    let plan = settle(&mut m, &mut frame);
    assert_eq!(plan.stats.failed_needed, 8);
    assert_eq!(plan.stats.failures.brick_errors, 8);
    let e = m.take_error().unwrap();
    assert_eq!(e.more, 7);
    assert!(e.to_string().contains("and 7 more"), "{e}");
    assert!(m.take_error().is_none());
    // Failing again after a retry surfaces again, once.
    m.retry_failed();
    settle(&mut m, &mut frame);
    assert_eq!(m.take_error().map(|e| e.more), Some(7));
}

#[test]
fn drop_returns_while_a_read_hangs() {
    let hung = NodeKey::new(1, 0, 0, 0);
    let mut src = TestSource::new(64);
    src.gate_key = Some(hung);
    let src = Arc::new(src);
    let mut m = manager(&src, config());
    let t = Instant::now();
    let mut frame = 0;
    while m.residency(hung) != Some(Residency::Loading) {
        frame += 1;
        m.update_view(&cam(), 1.0, 128, frame, RenderMode::Mip, &tf());
        assert!(t.elapsed() < Duration::from_secs(5));
        std::thread::sleep(Duration::from_millis(1));
    }
    let t = Instant::now();
    drop(m);
    // Bounded wait for liveness: the drop waits SHUTDOWN_WAIT, not for the read.
    assert!(t.elapsed() < Duration::from_secs(5));
    assert!(Arc::strong_count(&src) > 1, "the hung read still runs");
    src.open_gate();
    let t = Instant::now();
    while Arc::strong_count(&src) > 1 {
        assert!(
            t.elapsed() < Duration::from_secs(5),
            "the thread never let go"
        );
        std::thread::sleep(Duration::from_millis(1));
    }
}

#[test]
fn restored_nodes_load_after_the_back_off_without_any_call() {
    for kind in [FetchKind::Brick, FetchKind::Metadata] {
        let src = Arc::new(TestSource::new(64));
        src.fail(kind, BAD);
        let (mut m, clock) = manager_with_clock(&src, config());
        let mut frame = 0;
        assert!(settle(&mut m, &mut frame).stats.degraded());
        src.restore(BAD);
        // Before the back-off (1 s) nothing is retried.
        frames(&mut m, &mut frame, &clock, Duration::from_millis(100), 9);
        let s = settle(&mut m, &mut frame).stats;
        assert!(s.degraded(), "{kind}: retried too early");
        // Past it the node is requested again, loads, and the image converges.
        clock.advance(Duration::from_millis(100));
        let plan = settle(&mut m, &mut frame);
        assert!(plan.stats.converged(), "{kind}: {:?}", plan.stats);
        assert!(plan.cut.len() > 8);
        assert!(m.failure(BAD).is_none());
    }
}

#[test]
fn retry_and_retry_failed_act_at_once() {
    let other = NodeKey::new(1, 0, 0, 0);
    let src = Arc::new(TestSource::new(64));
    src.fail(FetchKind::Brick, BAD);
    src.fail(FetchKind::Brick, other);
    let mut m = manager(&src, config());
    let mut frame = 0;
    assert_eq!(settle(&mut m, &mut frame).stats.failed_needed, 2);
    src.restore(BAD);
    src.restore(other);
    // One node: only it is no longer failed (the clock never moves); its
    // sibling still blocks the split, so it is not even requested.
    assert!(m.retry(BAD));
    assert!(!m.retry(NodeKey::new(1, 0, 1, 0)));
    let s = settle(&mut m, &mut frame).stats;
    assert_eq!(s.failed_needed, 1);
    assert!(m.failure(BAD).is_none() && m.failure(other).is_some());
    // All of them.
    m.retry_failed();
    let plan = settle(&mut m, &mut frame);
    assert!(plan.stats.converged(), "{:?}", plan.stats);
}

#[test]
fn back_off_doubles_per_node() {
    let src = Arc::new(TestSource::new(64));
    src.fail(FetchKind::Brick, BAD);
    let (mut m, clock) = manager_with_clock(&src, config());
    let mut frame = 0;
    settle(&mut m, &mut frame);
    let tries = || src.reads().iter().filter(|k| **k == BAD).count();
    assert_eq!(tries(), 1);
    // 1 s after the first failure: retried, fails again.
    clock.advance(Duration::from_secs(1));
    settle(&mut m, &mut frame);
    assert_eq!(tries(), 2);
    // Now the back-off is 2 s: one second is not enough.
    clock.advance(Duration::from_secs(1));
    settle(&mut m, &mut frame);
    assert_eq!(tries(), 2);
    clock.advance(Duration::from_secs(1));
    settle(&mut m, &mut frame);
    assert_eq!(tries(), 3);
    assert!(matches!(
        m.failure(BAD).as_deref(),
        Some(LoadError::Source(BrickError::Io { .. }))
    ));
    // Without a policy nothing is retried on its own.
    m.set_retry_policy(None).unwrap();
    m.retry_failed();
    settle(&mut m, &mut frame);
    assert_eq!(tries(), 4);
    clock.advance(Duration::from_secs(3600));
    settle(&mut m, &mut frame);
    assert_eq!(tries(), 4);
}

/// Once `converged()` holds, further frames of the same view change nothing.
#[test]
fn converged_means_another_frame_changes_nothing() {
    let mut src = TestSource::new(64);
    src.delay = Duration::from_millis(2);
    let src = Arc::new(src);
    let mut m = manager(&src, config());
    let mut frame = 0;
    let mut pending_seen = false;
    let t = Instant::now();
    let done = loop {
        frame += 1;
        let plan = m.update_view(&cam(), 1.0, 128, frame, RenderMode::Mip, &tf());
        let s = plan.stats;
        if s.requests_in_flight > 0 || s.upload_bricks > 0 || s.metadata_in_flight > 0 {
            assert!(!s.converged());
            pending_seen = true;
        }
        if s.converged() {
            break plan;
        }
        assert!(t.elapsed() < Duration::from_secs(10), "{s:?}");
        std::thread::sleep(Duration::from_millis(1));
    };
    assert!(pending_seen);
    for _ in 0..5 {
        std::thread::sleep(Duration::from_millis(3));
        frame += 1;
        let plan = m.update_view(&cam(), 1.0, 128, frame, RenderMode::Mip, &tf());
        assert_eq!(plan.cut, done.cut);
        assert!(plan.uploads.is_empty() && plan.stats.converged());
    }
}

#[test]
fn non_finite_cameras_and_huge_pools_request_boundedly() {
    let src = Arc::new(TestSource::new(64));
    let mut m = manager(&src, config());
    let nan = Camera {
        eye: Vec3::splat(f32::NAN),
        ..cam()
    };
    for frame in 1..40 {
        let plan = m.update_view(&nan, f32::NAN, 128, frame, RenderMode::Dvr, &tf());
        assert_eq!(plan.cut.len(), 1);
        // The root, and the coarse floor's nodes (loaded whatever the view).
        let floor = m.floor().len() as u32;
        assert!(plan.stats.requested_this_frame <= 1 + floor);
        assert!(plan.stats.metadata_requested_this_frame <= 1 + floor);
        std::thread::sleep(Duration::from_millis(1));
    }
    // A finite close-up with a large pool: at most the cap per frame.
    let src = Arc::new(TestSource::new(256));
    let mut m = manager(
        &src,
        OutOfCoreConfig {
            gpu_budget_bytes: 64 << 20,
            cpu_budget_bytes: 64 << 20,
            // Uploads of about 30 prepared bricks a frame: four frames of them
            // are fewer than the floor, so the cap is the floor.
            upload_budget_bytes: 60 * src.layout.brick_bytes() as u64,
            ..config()
        },
    );
    let slots = m.pool().slot_count();
    assert!(slots > MIN_REQUESTS_PER_FRAME);
    let close = Camera::orbit(Vec3::ZERO, 0.6, 0.4, 0.3);
    let (mut most, mut total) = (0, 0u64);
    // The close-up wants far more bricks than the cap (the refine-level test
    // shows the cap binding); here every frame of a streaming run stays within it.
    for frame in 1..=60u64 {
        let plan = m.update_view(&close, 1.0, 1024, frame, RenderMode::Mip, &tf());
        let n = plan.stats.requested_this_frame;
        assert!(n <= MIN_REQUESTS_PER_FRAME, "{n} requests in frame {frame}");
        most = most.max(n);
        total += n as u64;
        std::thread::sleep(Duration::from_millis(1));
    }
    assert!(
        most > 100 && total > MIN_REQUESTS_PER_FRAME as u64,
        "{most} {total}"
    );
}
