//! Faults while streaming, end to end through `VolumeRenderer`: a source whose
//! metadata or reads fail, panic or hang never makes `prepare` fail or panic;
//! failures are surfaced once, keep `wants_redraw` true while the image needs
//! them, and are retried (on request and after a back-off) once the source is
//! repaired; dropping the renderer returns promptly whatever the loader does;
//! budgets change at run time.

use brickray::core::{BrickError, NodeInfo, OctreeLayout};
use brickray::{
    BrickSource, Camera, FrameDesc, NodeKey, OutOfCoreConfig, RetryPolicy, TransferFunction,
    VolumeFrame, VolumeRenderer,
};
use brickray_harness::{Offscreen, draw_frame, shared_gpu as gpu};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

/// What the faulty source does for the nodes it breaks (every node below the
/// root here, so the image needs them).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Fault {
    None,
    Error,
    Panic,
    Hang,
}

struct FaultySource {
    inner: brickray::store::ProceduralSource,
    metadata: Mutex<Fault>,
    reads: Mutex<Fault>,
    hang: (Mutex<bool>, Condvar),
    hung: AtomicU32,
}

impl FaultySource {
    fn new() -> Arc<FaultySource> {
        Arc::new(FaultySource {
            inner: brickray::store::ProceduralSource::fractal_noise([256; 3], 32, 1).unwrap(),
            metadata: Mutex::new(Fault::None),
            reads: Mutex::new(Fault::None),
            hang: (Mutex::new(false), Condvar::new()),
            hung: AtomicU32::new(0),
        })
    }

    fn apply(&self, fault: Fault, key: NodeKey) -> Result<(), BrickError> {
        if key.level == 0 {
            return Ok(());
        }
        match fault {
            Fault::None => Ok(()),
            Fault::Error => Err(BrickError::Io {
                key,
                source: std::io::Error::other("injected"),
            }),
            Fault::Panic => panic!("injected panic reading {key:?}"),
            Fault::Hang => {
                self.hung.fetch_add(1, Ordering::SeqCst);
                let (lock, cv) = &self.hang;
                let mut released = lock.lock().unwrap();
                while !*released {
                    released = cv.wait(released).unwrap();
                }
                Ok(())
            }
        }
    }

    fn release(&self) {
        *self.hang.0.lock().unwrap() = true;
        self.hang.1.notify_all();
    }
}

impl BrickSource for FaultySource {
    fn layout(&self) -> &OctreeLayout {
        self.inner.layout()
    }

    fn node(&self, key: NodeKey) -> Result<NodeInfo, BrickError> {
        let fault = *self.metadata.lock().unwrap();
        self.apply(fault, key)?;
        self.inner.node(key)
    }

    fn read_brick(&self, key: NodeKey, out: &mut [u8]) -> Result<(), BrickError> {
        let fault = *self.reads.lock().unwrap();
        self.apply(fault, key)?;
        self.inner.read_brick(key, out)
    }
}

fn setup(
    source: Arc<FaultySource>,
    retry: Option<RetryPolicy>,
) -> (VolumeRenderer, FrameDesc<'static>) {
    let g = gpu();
    let frame = VolumeFrame::centered([256; 3], [1.0; 3]);
    let mut r = VolumeRenderer::new(&g.device, brickray_harness::target_desc()).unwrap();
    let config = OutOfCoreConfig {
        tolerance_px: 0.0,
        retry,
        ..Default::default()
    };
    r.set_volume_source(&g.device, &g.queue, source, config)
        .unwrap();
    let tf = TransferFunction::ramp(0.3, 0.8, 0.3);
    r.set_transfer_function(&g.device, &g.queue, &tf).unwrap();
    let camera = Camera::orbit(frame.center(), 1.8, 0.5, 0.3);
    (r, FrameDesc::new(camera, frame, 64, 64))
}

/// Draws up to `frames` frames (never failing), returning whether the renderer
/// stopped wanting redraws.
fn settle(r: &mut VolumeRenderer, desc: &FrameDesc<'_>, frames: usize) -> bool {
    let g = gpu();
    let target = Offscreen::new(&g.device, 64, 64);
    for _ in 0..frames {
        draw_frame(g, r, &target, desc, None).expect("prepare never fails on streaming faults");
        if !r.wants_redraw() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    false
}

#[test]
fn failing_and_panicking_sources_are_surfaced_then_retried() {
    for (what, fault) in [
        ("read error", Fault::Error),
        ("read panic", Fault::Panic),
        ("metadata error", Fault::Error),
        ("metadata panic", Fault::Panic),
    ] {
        let source = FaultySource::new();
        let target = if what.starts_with("read") {
            &source.reads
        } else {
            &source.metadata
        };
        *target.lock().unwrap() = fault;
        let (mut r, desc) = setup(source.clone(), None);
        // The image needs the failed nodes: it never settles, but every frame
        // renders (at the root's level) and one error is surfaced.
        assert!(
            !settle(&mut r, &desc, 40),
            "{what}: degraded image reported converged"
        );
        let stats = r.stats().out_of_core.unwrap();
        assert!(
            !stats.converged && stats.cache.degraded(),
            "{what}: {stats:?}"
        );
        let volume = r.streamed_volume().expect("out of core").clone();
        let e = volume.take_streaming_error().expect("one error surfaced");
        eprintln!("{what}: {e}");
        assert!(
            volume.take_streaming_error().is_none(),
            "{what}: surfaced twice"
        );
        // Repaired, then retried on request: the view completes.
        *target.lock().unwrap() = Fault::None;
        volume.retry_failed_bricks();
        assert!(settle(&mut r, &desc, 300), "{what}: never recovered");
        assert!(r.stats().out_of_core.unwrap().converged);
    }
}

#[test]
fn failed_bricks_are_retried_after_a_back_off() {
    let source = FaultySource::new();
    *source.reads.lock().unwrap() = Fault::Error;
    let policy = RetryPolicy {
        initial: Duration::from_millis(50),
        max: Duration::from_millis(200),
        factor: 2.0,
    };
    let (mut r, desc) = setup(source.clone(), Some(policy));
    assert!(!settle(&mut r, &desc, 10));
    *source.reads.lock().unwrap() = Fault::None;
    // No API call: the back-off retries on its own.
    assert!(settle(&mut r, &desc, 300), "never retried");
}

#[test]
fn drop_returns_promptly_while_a_read_hangs() {
    let source = FaultySource::new();
    *source.reads.lock().unwrap() = Fault::Hang;
    let (mut r, desc) = setup(source.clone(), None);
    let g = gpu();
    let target = Offscreen::new(&g.device, 64, 64);
    let t = Instant::now();
    while source.hung.load(Ordering::SeqCst) == 0 {
        draw_frame(g, &mut r, &target, &desc, None).unwrap();
        assert!(t.elapsed() < Duration::from_secs(10), "no read started");
    }
    // Frames go on while reads hang (the render thread never waits on I/O).
    let t = Instant::now();
    for _ in 0..5 {
        draw_frame(g, &mut r, &target, &desc, None).unwrap();
    }
    assert!(t.elapsed() < Duration::from_secs(5));
    let t = Instant::now();
    drop(r);
    let dropped = t.elapsed();
    source.release();
    assert!(dropped < Duration::from_secs(2), "drop took {dropped:?}");
}

#[test]
fn budgets_and_tolerance_change_at_run_time() {
    let source = FaultySource::new();
    let (mut r, desc) = setup(source, None);
    assert!(settle(&mut r, &desc, 300));
    let before = r.stats().out_of_core.unwrap();
    let bytes = r.volume_bytes();
    // A smaller pool: the atlas is recreated and the view completes again with
    // at most as many bricks as it holds.
    let g = gpu();
    brickray_harness::configure(g, &r, |c| c.gpu_budget_bytes = 16 << 20).unwrap();
    assert!(r.volume_bytes() < bytes);
    assert!(settle(&mut r, &desc, 300));
    let after = r.stats().out_of_core.unwrap();
    assert!(after.cache.working_set_bricks <= after.cache.pool_slots);
    // A coarser tolerance needs fewer bricks.
    brickray_harness::configure(gpu(), &r, |c| c.tolerance_px = 4.0).unwrap();
    assert!(settle(&mut r, &desc, 300));
    let coarse = r.stats().out_of_core.unwrap();
    assert!(coarse.cache.working_set_bricks < before.cache.working_set_bricks);
    // Bad values are typed errors, the renderer keeps working.
    assert!(brickray_harness::configure(gpu(), &r, |c| c.tolerance_px = f32::NAN).is_err());
    assert!(brickray_harness::configure(gpu(), &r, |c| c.tolerance_px = -1.0).is_err());
    assert!(brickray_harness::configure(gpu(), &r, |c| c.cpu_budget_bytes = 1).is_err());
    assert!(brickray_harness::configure(g, &r, |c| c.gpu_budget_bytes = 1).is_err());
    brickray_harness::configure(gpu(), &r, |c| c.upload_budget_bytes = 1 << 20).unwrap();
    assert!(settle(&mut r, &desc, 300));
}
