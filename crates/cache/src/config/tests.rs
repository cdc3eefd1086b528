//! Validation of the configuration and the GPU format.

use super::*;
use crate::refine::tests::ball_layout;

fn gpu(layout: &OctreeLayout) -> GpuFormat {
    GpuFormat::for_layout(
        layout,
        TexelCaps {
            norm16: true,
            float32_filterable: false,
        },
        U8Filtering::Exact,
        32,
        2048,
    )
}

#[test]
fn defaults_are_valid_and_sizes_count_the_format() {
    let layout = ball_layout(64);
    let g = gpu(&layout);
    assert_eq!(OutOfCoreConfig::default().validate(&layout, &g), Ok(()));
    // 10^3 voxels as R16Unorm, one sub-cell, one 32-byte slot row.
    assert_eq!(g.prepared_brick_bytes(&layout), Ok(2000 + 8));
    assert_eq!(g.slot_bytes(&layout), Ok(2000 + 8 + 32));
    let fast = GpuFormat::for_layout(&layout, TexelCaps::default(), U8Filtering::Fast, 0, 64);
    assert_eq!(fast.slot_bytes(&layout), Ok(1000 + 8));
    // Kept gradients: 8 bytes a stored voxel on the GPU, none in the CPU
    // cache or the uploads; the same budget holds fewer slots.
    let kept = GpuFormat {
        gradients: true,
        ..g
    };
    assert_eq!(kept.prepared_brick_bytes(&layout), Ok(2000 + 8));
    assert_eq!(kept.slot_bytes(&layout), Ok(2000 + 8 + 32 + 8000));
    let slots = |f: &GpuFormat| {
        let l = f.pool_limits(&layout, 1 << 20).unwrap();
        l.grid().unwrap().iter().map(|&a| a as u64).product::<u64>()
    };
    assert!(
        slots(&kept) * 4 < slots(&g),
        "{} {}",
        slots(&kept),
        slots(&g)
    );
}

#[test]
fn every_violation_is_a_typed_error() {
    let layout = ball_layout(64);
    let g = gpu(&layout);
    let ok = OutOfCoreConfig::default();
    let check = |c: OutOfCoreConfig| c.validate(&layout, &g);
    for value in [f32::NAN, -0.5, f32::INFINITY] {
        let e = check(OutOfCoreConfig {
            tolerance_px: value,
            ..ok
        });
        assert!(matches!(e, Err(ConfigError::Tolerance { .. })), "{value}");
        for metric in [
            LodMetric::VisibleError { budget: value },
            LodMetric::VisibleOctants { budget: value },
        ] {
            let e = check(OutOfCoreConfig {
                lod_metric: metric,
                ..ok
            });
            assert!(
                matches!(e, Err(ConfigError::ErrorBudget { .. })),
                "{metric:?}"
            );
        }
    }
    assert_eq!(
        check(OutOfCoreConfig {
            brick_budget: Some(0),
            ..ok
        }),
        Err(ConfigError::BrickBudget { value: 0 })
    );
    for budget in [None, Some(1), Some(u32::MAX)] {
        assert_eq!(
            check(OutOfCoreConfig {
                brick_budget: budget,
                ..ok
            }),
            Ok(()),
            "{budget:?}"
        );
    }
    for threads in [0, MAX_LOADER_THREADS + 1, 2000] {
        assert_eq!(
            check(OutOfCoreConfig {
                loader_threads: threads,
                ..ok
            }),
            Err(ConfigError::LoaderThreads {
                threads,
                max: MAX_LOADER_THREADS
            })
        );
    }
    assert_eq!(
        check(OutOfCoreConfig {
            cpu_budget_bytes: 8 * 2008,
            ..ok
        }),
        Err(ConfigError::CpuBudgetTooSmall {
            budget_bytes: 8 * 2008,
            brick_bytes: 2008,
            bricks: 8,
            needed: 9
        })
    );
    assert_eq!(
        check(OutOfCoreConfig {
            cpu_budget_bytes: 9 * 2008,
            gpu_budget_bytes: 9 * 2040,
            ..ok
        }),
        Ok(())
    );
    let e = check(OutOfCoreConfig {
        gpu_budget_bytes: 8 * 2040 + 2039,
        ..ok
    });
    assert!(
        matches!(
            e,
            Err(ConfigError::GpuBudgetTooSmall {
                slots: 8,
                slot_bytes: 2040,
                needed: 9,
                ..
            })
        ),
        "{e:?}"
    );
    // The device limit caps the grid: 2 slots per axis at most.
    let small_dim = GpuFormat {
        max_texture_dim_3d: 29,
        ..g
    };
    let e = ok.validate(&layout, &small_dim);
    assert!(
        matches!(e, Err(ConfigError::GpuBudgetTooSmall { slots: 8, .. })),
        "{e:?}"
    );
    assert!(e.unwrap_err().to_string().contains("8 pool slots"));
    for (initial, max, factor) in [
        (Duration::ZERO, Duration::from_secs(1), 2.0),
        (Duration::from_secs(2), Duration::from_secs(1), 2.0),
    ] {
        let e = check(OutOfCoreConfig {
            retry: Some(RetryPolicy {
                initial,
                max,
                factor,
            }),
            ..ok
        });
        assert_eq!(e, Err(ConfigError::RetryDelays { initial, max }));
    }
    for factor in [f32::NAN, 0.5, f32::INFINITY] {
        let retry = Some(RetryPolicy {
            factor,
            ..RetryPolicy::default()
        });
        let e = check(OutOfCoreConfig { retry, ..ok });
        assert!(matches!(e, Err(ConfigError::RetryFactor { .. })));
    }
    assert_eq!(check(OutOfCoreConfig { retry: None, ..ok }), Ok(()));
    assert_eq!(
        check(OutOfCoreConfig {
            setup_deadline: Duration::ZERO,
            ..ok
        }),
        Err(ConfigError::SetupDeadline {
            value: Duration::ZERO
        })
    );
    assert_eq!(ok.setup_deadline, DEFAULT_SETUP_DEADLINE);
}

#[test]
fn format_mismatches_and_overflows_are_typed_errors() {
    let layout = ball_layout(64);
    let g = gpu(&layout);
    let ok = OutOfCoreConfig::default();
    let mut other = layout.clone();
    other.volume.dtype = DType::U16;
    assert!(matches!(
        ok.validate(&other, &g),
        Err(ConfigError::EncodingMismatch { .. })
    ));
    let mut range = layout.clone();
    range.volume.value_range = [0.0, 2.0];
    assert!(matches!(
        ok.validate(&range, &g),
        Err(ConfigError::EncodingMismatch { .. })
    ));
    for per_axis in [0, layout.brick + 1] {
        let e = ok.validate(
            &layout,
            &GpuFormat {
                sub_cells_per_axis: per_axis,
                ..g
            },
        );
        assert_eq!(
            e,
            Err(ConfigError::SubCells {
                per_axis,
                max: layout.brick
            })
        );
    }
    let mut huge = layout.clone();
    huge.brick = u32::MAX - 1;
    assert_eq!(
        ok.validate(&huge, &g),
        Err(ConfigError::SizeOverflow {
            quantity: SizeQuantity::StoredSide
        })
    );
    huge.brick = 1 << 22;
    huge.apron = 0;
    assert!(matches!(
        ok.validate(
            &huge,
            &GpuFormat {
                sub_cells_per_axis: 1,
                ..g
            }
        ),
        Err(ConfigError::SizeOverflow { .. })
    ));
}

#[test]
fn retry_delays_grow_and_saturate() {
    let p = RetryPolicy::default();
    let secs: Vec<u64> = (1..=9).map(|n| p.delay(n).as_secs()).collect();
    assert_eq!(secs, vec![1, 2, 4, 8, 16, 32, 60, 60, 60]);
    assert_eq!(p.delay(0), p.delay(1));
    assert_eq!(p.delay(u32::MAX), Duration::from_secs(60));
    let flat = RetryPolicy { factor: 1.0, ..p };
    assert_eq!(flat.delay(50), Duration::from_secs(1));
}

#[test]
fn bad_fade_durations_are_typed_errors() {
    let layout = ball_layout(64);
    let g = gpu(&layout);
    for bad in [
        FadeDuration::Frames(0),
        FadeDuration::Millis(f32::NAN),
        FadeDuration::Millis(-1.0),
        FadeDuration::Millis(f32::INFINITY),
    ] {
        let c = OutOfCoreConfig {
            fade: Some(bad),
            ..OutOfCoreConfig::default()
        };
        // NaN != NaN: compare the variant, then the value as printed.
        match c.validate(&layout, &g) {
            Err(ConfigError::Fade { value }) => {
                assert_eq!(format!("{value:?}"), format!("{bad:?}"))
            }
            other => panic!("{bad:?}: {other:?}"),
        }
    }
    for good in [
        None,
        Some(FadeDuration::Frames(1)),
        Some(FadeDuration::Millis(0.0)),
    ] {
        let c = OutOfCoreConfig {
            fade: good,
            ..OutOfCoreConfig::default()
        };
        assert_eq!(c.validate(&layout, &g), Ok(()));
    }
}

/// A pool holds every brick when its slots cover each level's nodes over the
/// volume (a non-cubic volume counts only the nodes its box meets), and not
/// at a budget one slot short.
#[test]
fn a_pool_holds_every_brick_when_its_slots_cover_every_level() {
    let cube = ball_layout(64);
    // 8^3 + 4^3 + 2^3 + 1 bricks of 8 voxels.
    assert_eq!(brick_count(&cube), 585);
    let flat = OctreeLayout::new(
        brickray_core::VolumeDesc {
            dims: [64, 64, 20],
            ..cube.volume.clone()
        },
        8,
        1,
    );
    // 8x8x3 + 4x4x2 + 2x2x1 + 1x1x1 (the levels' dims 64x64x20, 32x32x10,
    // 16x16x5, 8x8x3).
    assert_eq!(brick_count(&flat), 192 + 32 + 4 + 1);
    let kept = GpuFormat {
        gradients: true,
        ..gpu(&cube)
    };
    let slot = kept.slot_bytes(&cube).unwrap();
    for (layout, bricks) in [(&cube, 585u64), (&flat, 229)] {
        // The smallest budget whose grid has a slot per brick holds them;
        // one slot's bytes less does not.
        let fits = (bricks..4 * bricks)
            .map(|n| n * slot)
            .find(|&b| {
                let g = kept.pool_limits(layout, b).unwrap().grid().unwrap();
                g.iter().map(|&a| a as u64).product::<u64>() >= bricks
            })
            .unwrap();
        assert!(
            kept.holds_every_brick(layout, fits),
            "{bricks} bricks at {fits} B"
        );
        assert!(
            !kept.holds_every_brick(layout, fits - slot),
            "{bricks} bricks at {} B",
            fits - slot
        );
    }
    // No pool at all: false, not an error.
    assert!(!kept.holds_every_brick(&cube, 0));
}

/// The pool sizes docs/cache.md quotes for the shared volumes' stores
/// (bricks of 32, apron 2, 16-bit texels, a 2048 texture limit): a budget
/// beyond a slot for every brick is not allocated. Printed with
/// `cargo test -p brickray-cache --lib shared_volumes_pools -- --nocapture`.
#[test]
fn shared_volumes_pools_stop_at_their_bricks() {
    use brickray_core::{DType, VolumeDesc};
    let volume = |dims, dtype, value_range| VolumeDesc {
        dims,
        dtype,
        spacing: [1.0; 3],
        value_range,
        kind: Default::default(),
    };
    let cases = [
        (
            "T1 MRI",
            volume([256; 3], DType::U8, [0.0, 248.0]),
            585,
            585,
        ),
        (
            "head CT",
            volume([256, 256, 108], DType::I16, [-1024.0, 2986.0]),
            293,
            294,
        ),
    ];
    let mib = |slots: u64, bytes: u64| (slots * bytes) as f64 / f64::from(1 << 20);
    for (name, desc, bricks, slots) in cases {
        let layout = OctreeLayout::new(desc, 32, 2);
        assert_eq!(brick_count(&layout), bricks, "{name}");
        for (gradients, budget) in [(false, 256u64 << 20), (true, 1 << 30)] {
            let mut g = gpu(&layout);
            g.gradients = gradients;
            let l = g.pool_limits(&layout, budget).unwrap();
            let capped = l.grid().unwrap().iter().map(|&a| a as u64).product::<u64>();
            let whole = PoolLimits {
                max_slots: u64::MAX,
                ..l
            }
            .grid()
            .unwrap()
            .iter()
            .map(|&a| a as u64)
            .product::<u64>();
            println!(
                "{name}, gradients {gradients}, {} MiB: {bricks} bricks, slot {} B: {whole} slots \
                 ({:.1} MiB) without the cap, {capped} ({:.1} MiB) with it",
                budget >> 20,
                l.slot_bytes,
                mib(whole, l.slot_bytes),
                mib(capped, l.slot_bytes)
            );
            assert_eq!(capped, slots, "{name}, gradients {gradients}");
            assert!(
                whole > capped,
                "{name}: the budget holds more than the volume"
            );
        }
    }
}
