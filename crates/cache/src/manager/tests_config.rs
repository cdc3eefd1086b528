//! Validation at construction and the runtime setters.

use super::tests::{brick_bytes, check_plan, config, converge, manager, slot_bytes};
use super::*;
use crate::config::RetryPolicy;
use crate::test_source::{TestSource, test_gpu};
#[allow(unused_imports)]
use brickray_core::{Camera, RenderMode, TransferFunction, VolumeFrame};
use glam::Vec3;
use std::time::{Duration, Instant};

fn try_new(src: &Arc<TestSource>, config: OutOfCoreConfig) -> Result<BrickManager, CacheError> {
    BrickManager::new(src.clone(), config, test_gpu(&src.layout))
}

#[test]
fn new_rejects_unusable_configs() {
    let src = Arc::new(TestSource::new(64));
    let err = |c: OutOfCoreConfig| match try_new(&src, c) {
        Err(CacheError::Config(e)) => e,
        other => panic!("expected a config error, got {other:?}"),
    };
    let ok = config();
    assert!(matches!(
        err(OutOfCoreConfig {
            tolerance_px: f32::NAN,
            ..ok
        }),
        ConfigError::Tolerance { .. }
    ));
    // 2000 threads would have started 2000 threads; now they are refused.
    assert!(matches!(
        err(OutOfCoreConfig {
            loader_threads: 2000,
            ..ok
        }),
        ConfigError::LoaderThreads { threads: 2000, .. }
    ));
    // A CPU cache of 8 bricks could never hold the root and its 8 children.
    assert!(matches!(
        err(OutOfCoreConfig {
            cpu_budget_bytes: 8 * brick_bytes(&src),
            ..ok
        }),
        ConfigError::CpuBudgetTooSmall { bricks: 8, .. }
    ));
    assert!(matches!(
        err(OutOfCoreConfig {
            gpu_budget_bytes: 5 * slot_bytes(&src),
            ..ok
        }),
        ConfigError::GpuBudgetTooSmall { slots: 5, .. }
    ));
    // A format for another volume.
    let mut other = src.layout.clone();
    other.volume.value_range = [0.0, 255.0];
    let e = BrickManager::new(src.clone(), ok, test_gpu(&other));
    assert!(matches!(
        e,
        Err(CacheError::Config(ConfigError::EncodingMismatch { .. }))
    ));
}

/// Nine prepared bricks are enough for the root and its children to be in
/// memory together, so the root splits.
#[test]
fn a_cpu_cache_of_nine_bricks_splits_the_root() {
    let src = Arc::new(TestSource::new(64));
    let mut m = manager(
        &src,
        OutOfCoreConfig {
            cpu_budget_bytes: 9 * brick_bytes(&src),
            ..config()
        },
    );
    let cam = Camera::orbit(Vec3::ZERO, 1.6, 0.4, 0.3);
    let tf = TransferFunction::ramp(0.1, 1.0, 0.5);
    let t = Instant::now();
    for frame in 1.. {
        let plan = m.update_view(&cam, 1.0, 128, frame, RenderMode::Mip, &tf);
        check_plan(&m, &plan);
        if plan.cut.iter().any(|l| l.key.level > 0 && l.kind.is_data()) {
            break;
        }
        assert!(t.elapsed() < Duration::from_secs(10), "{:?}", plan.stats);
        std::thread::sleep(Duration::from_millis(1));
    }
}

#[test]
fn setters_validate_and_apply() {
    let src = Arc::new(TestSource::new(64));
    let (slot, brick) = (slot_bytes(&src), brick_bytes(&src));
    let mut m = manager(&src, config());
    let cam = Camera::orbit(Vec3::ZERO, 1.6, 0.4, 0.3);
    let tf = TransferFunction::ramp(0.1, 1.0, 0.5);
    let mut frame = 0;
    let fine = converge(&mut m, &mut frame, &cam, RenderMode::Mip, &tf, |_, _| {});

    // Tolerance: refused when not finite or negative; a larger one coarsens.
    for bad in [f32::NAN, -1.0, f32::INFINITY] {
        assert!(matches!(
            m.set_tolerance_px(bad),
            Err(ConfigError::Tolerance { .. })
        ));
    }
    assert_eq!(m.config().tolerance_px, 1.0);
    m.set_tolerance_px(4.0).unwrap();
    let coarse = converge(&mut m, &mut frame, &cam, RenderMode::Mip, &tf, |_, _| {});
    assert!(coarse.stats.working_set_bricks < fine.stats.working_set_bricks);
    m.set_tolerance_px(1.0).unwrap();

    // CPU budget: at least nine bricks; shrinking evicts at once.
    assert!(m.cpu_cache().bytes() > 12 * brick);
    assert!(matches!(
        m.set_cpu_budget(8 * brick),
        Err(ConfigError::CpuBudgetTooSmall { .. })
    ));
    m.set_cpu_budget(12 * brick).unwrap();
    assert!(m.cpu_cache().bytes() <= 12 * brick);
    assert_eq!(m.config().cpu_budget_bytes, 12 * brick);
    m.set_cpu_budget(4 << 20).unwrap();

    // GPU budget: at least nine slots; the pool is rebuilt and reported.
    let e = m.set_gpu_budget(8 * slot);
    assert!(
        matches!(e, Err(ConfigError::GpuBudgetTooSmall { slots: 8, .. })),
        "{e:?}"
    );
    assert!(m.pool().occupied() > 0, "a refused change keeps the pool");
    let dims = m.set_gpu_budget(30 * slot).unwrap();
    assert_eq!(dims, m.pool().atlas_dims());
    assert!((9..=30).contains(&m.pool().slot_count()));
    assert_eq!(m.pool().occupied(), 0);
    // The next frames upload the (smaller) working set into the new pool.
    let plan = converge(&mut m, &mut frame, &cam, RenderMode::Mip, &tf, |_, p| {
        assert!(p.stats.working_set_bricks <= p.stats.pool_slots);
    });
    assert!(plan.stats.working_set_bricks > 0);
    assert_eq!(plan.stats.pool_slots, m.pool().slot_count());

    // Upload budget: one brick per frame (a split may exceed it once).
    m.set_upload_budget(brick).unwrap();
    m.set_gpu_budget(1 << 20).unwrap();
    converge(&mut m, &mut frame, &cam, RenderMode::Mip, &tf, |_, p| {
        assert!(p.uploads.len() <= 8);
    });

    // Retry policy.
    let bad = RetryPolicy {
        factor: 0.5,
        ..RetryPolicy::default()
    };
    assert!(matches!(
        m.set_retry_policy(Some(bad)),
        Err(ConfigError::RetryFactor { .. })
    ));
    m.set_retry_policy(None).unwrap();
    assert_eq!(m.config().retry, None);
}

#[test]
fn the_metadata_map_stays_within_a_sixteenth_of_the_cpu_budget() {
    // (An entry holds the node's error records: far more than the 48 bytes
    // the map was once sized for, MetaCache::ENTRY_BYTES.)
    for budget in [256u64 << 20, 512 << 20, 4 << 30] {
        let cap = super::meta_capacity(budget) as u64;
        assert!(
            cap * MetaCache::ENTRY_BYTES as u64 <= budget / 16,
            "{budget}: {cap}"
        );
        assert!(
            cap * MetaCache::ENTRY_BYTES as u64 > budget / 17,
            "{budget}: {cap}"
        );
    }
    // A small budget still keeps the floor.
    assert_eq!(super::meta_capacity(1 << 20), 16_384);
}

/// A GPU budget beyond a slot for every brick of the volume is not
/// allocated, and such a pool, fades on, still refines to the finest level
/// (a pool that holds every brick keeps nothing back for the floor and the
/// fades; before, the cut was left short by both).
#[test]
fn a_roomy_budget_stops_at_a_slot_per_brick_and_refines_fully() {
    let src = Arc::new(TestSource::new(32));
    let bricks = crate::brick_count(&src.layout);
    let mut m = manager(
        &src,
        OutOfCoreConfig {
            gpu_budget_bytes: 1 << 30,
            tolerance_px: 0.0,
            fade: Some(crate::FadeDuration::Frames(2)),
            ..config()
        },
    );
    let slots = m.pool().slot_count() as u64;
    assert!(
        (bricks..bricks + 8).contains(&slots),
        "{slots} slots for {bricks} bricks (1 GiB holds {})",
        (1u64 << 30) / slot_bytes(&src)
    );
    let cam = Camera::orbit(Vec3::ZERO, 1.6, 0.4, 0.3);
    let tf = TransferFunction::ramp(0.1, 1.0, 0.5);
    let mut frame = 0;
    let plan = converge(&mut m, &mut frame, &cam, RenderMode::Mip, &tf, |_, _| {});
    let finest = src.layout.levels - 1;
    let data: Vec<u8> = plan
        .cut
        .iter()
        .filter(|l| l.kind.is_data())
        .map(|l| l.key.level)
        .collect();
    assert!(
        !data.is_empty() && data.iter().all(|&l| l == finest),
        "data leaves' levels {data:?}, {:?}",
        plan.stats
    );
}
