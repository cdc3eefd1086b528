//! GPU timestamps of the ray-cast pass (`VolumeRenderer::set_pass_timestamps`,
//! `brickray_harness::GpuTimer`) on a real wgpu device (lavapipe in CI):
//!
//! * where the device has `TIMESTAMP_QUERY`, the kernel's time of a small
//!   in-core frame is positive and within the frame's wall time
//!   (`prepare + submit + wait`);
//! * on a device without it, `GpuTimer::new` is `None` and handing the
//!   renderer a query set is a typed `MissingFeature` error;
//! * a query set that is not of timestamp type, an index past its count and
//!   equal indices are typed `BadTimestampQuery` errors, which leave the
//!   renderer drawing as before (no wgpu validation error: the default
//!   handler would panic).
//!
//! The adapter's features are printed (`--nocapture`). Without an adapter the
//! tests skip, except with `CI=true`, where they fail.

use brickray::{
    Camera, FrameDesc, PassTimestamps, RenderError, TransferFunction, VolumeFrame, VolumeRenderer,
};
use brickray_harness::{GpuContext, GpuError, GpuTimer, Offscreen, WANTED_FEATURES, draw_frame};
use std::time::Instant;

const SIZE: u32 = 64;

/// The device every test here uses (with the wanted features the adapter
/// has), `None` to skip when there is no adapter outside CI.
fn gpu() -> Option<&'static GpuContext> {
    static GPU: std::sync::OnceLock<Option<GpuContext>> = std::sync::OnceLock::new();
    GPU.get_or_init(|| match GpuContext::new() {
        Ok(g) => {
            eprintln!("adapter: {}", g.describe());
            eprintln!("adapter features: {:?}", g.adapter.features());
            eprintln!(
                "TIMESTAMP_QUERY: adapter {}, device {}; timestamp period {} ns",
                g.adapter
                    .features()
                    .contains(wgpu::Features::TIMESTAMP_QUERY),
                g.device
                    .features()
                    .contains(wgpu::Features::TIMESTAMP_QUERY),
                g.queue.get_timestamp_period()
            );
            Some(g)
        }
        Err(e @ GpuError::NoAdapter { .. }) => {
            if std::env::var("CI").is_ok_and(|v| v == "true") {
                panic!("CI=true but {e}");
            }
            eprintln!("skipping: {e}");
            None
        }
        Err(e) => panic!("{e}"),
    })
    .as_ref()
}

/// A renderer of a 32^3 noise volume and the frame that shows it at 64x64.
fn scene(g: &GpuContext) -> (VolumeRenderer, FrameDesc<'static>) {
    let vol = brickray_harness::scenes::noise_volume(32);
    let mut r = VolumeRenderer::new(&g.device, brickray_harness::target_desc()).unwrap();
    r.set_volume(&g.device, &g.queue, &vol).unwrap();
    r.set_transfer_function(&g.device, &g.queue, &TransferFunction::ramp(0.3, 0.9, 0.5))
        .unwrap();
    let frame = VolumeFrame::centered(vol.dims(), [1.0; 3]);
    let camera = Camera::orbit(frame.center(), 2.0, 0.5, 0.3);
    (r, FrameDesc::new(camera, frame, SIZE, SIZE))
}

fn has_timestamps(g: &GpuContext) -> bool {
    g.device
        .features()
        .contains(wgpu::Features::TIMESTAMP_QUERY)
}

fn query_set(g: &GpuContext, ty: wgpu::QueryType, count: u32) -> wgpu::QuerySet {
    g.device.create_query_set(&wgpu::QuerySetDescriptor {
        label: Some("gpu_timestamps test"),
        ty,
        count,
    })
}

#[track_caller]
fn expect_missing(r: Result<(), RenderError>) {
    match r {
        Err(RenderError::MissingFeature { feature, .. })
            if feature == wgpu::Features::TIMESTAMP_QUERY => {}
        other => panic!("expected MissingFeature(TIMESTAMP_QUERY), got {other:?}"),
    }
}

#[track_caller]
fn expect_bad(r: Result<(), RenderError>, beginning: u32, end: u32) {
    match r {
        Err(RenderError::BadTimestampQuery {
            beginning: b,
            end: e,
            ..
        }) if (b, e) == (beginning, end) => {}
        other => panic!("expected BadTimestampQuery({beginning}, {end}), got {other:?}"),
    }
}

/// The kernel's own time is positive and within the frame's wall time;
/// without the feature there is no timer and a foreign query set is refused.
#[test]
fn kernel_time_is_within_the_frame_wall_time() {
    let Some(g) = gpu() else { return };
    let (mut r, desc) = scene(g);
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let Some(timer) = GpuTimer::new(g) else {
        assert!(!has_timestamps(g));
        eprintln!("the device has no TIMESTAMP_QUERY: no kernel time");
        // A query set from elsewhere (the device cannot make a timestamp one).
        let foreign = PassTimestamps {
            query_set: query_set(g, wgpu::QueryType::Occlusion, 2),
            beginning: 0,
            end: 1,
        };
        expect_missing(r.set_pass_timestamps(&g.device, Some(foreign)));
        assert!(r.pass_timestamps().is_none());
        draw_frame(g, &mut r, &target, &desc, Some(wgpu::Color::BLACK)).unwrap();
        return;
    };
    r.set_pass_timestamps(&g.device, Some(timer.writes()))
        .unwrap();
    assert_eq!(r.pass_timestamps(), Some(&timer.writes()));
    // The first frame compiles the kernel in `prepare`; the later ones do not.
    let mut kernels = Vec::new();
    for frame in 0..4 {
        let start = Instant::now();
        let mut enc = g.device.create_command_encoder(&Default::default());
        r.prepare(&g.device, &g.queue, &mut enc, &desc).unwrap();
        {
            let mut pass = target.pass(&mut enc, true);
            r.render(&mut pass).unwrap();
        }
        timer.resolve(&mut enc);
        g.submit_wait(enc);
        let wall_ms = start.elapsed().as_secs_f64() * 1e3;
        let kernel_ms = timer.read_ms(g).expect("the timestamps read back");
        eprintln!("frame {frame}: kernel {kernel_ms:.3} ms, wall {wall_ms:.3} ms");
        assert!(
            kernel_ms >= 0.0,
            "frame {frame}: kernel time {kernel_ms} ms"
        );
        kernels.push(kernel_ms);
        // The clocks differ (GPU ticks, host Instant): a small margin.
        assert!(
            kernel_ms <= wall_ms * 1.05 + 0.5,
            "frame {frame}: kernel {kernel_ms} ms longer than the frame's {wall_ms} ms"
        );
    }
    // Lavapipe's timestamps now and then read about 0 for a frame while
    // other processes load the machine (1 frame of 24 with three suites
    // running at once): a frame that measures nothing is allowed, four are
    // not.
    assert!(kernels.iter().any(|&k| k > 0.1), "{kernels:?}");
    // Off again: the pass writes no timestamps and the frame still draws.
    r.set_pass_timestamps(&g.device, None).unwrap();
    assert!(r.pass_timestamps().is_none());
    draw_frame(g, &mut r, &target, &desc, Some(wgpu::Color::BLACK)).unwrap();
    let image = target.read_color(g);
    assert!(
        image.chunks_exact(4).any(|p| p[0] > 10),
        "the image is black"
    );
}

/// A device created without `TIMESTAMP_QUERY` (whatever the adapter has)
/// has no timer, and a query set handed to its renderer (one of the shared
/// device's, which is foreign to it) is a typed error.
#[test]
fn a_device_without_timestamps_refuses_them() {
    let Some(shared) = gpu() else { return };
    let g = GpuContext::with_features(WANTED_FEATURES - wgpu::Features::TIMESTAMP_QUERY)
        .expect("a device without timestamp queries");
    assert!(!has_timestamps(&g));
    assert!(GpuTimer::new(&g).is_none());
    let (mut r, desc) = scene(&g);
    let foreign = match GpuTimer::new(shared) {
        Some(t) => t.writes(),
        None => PassTimestamps {
            query_set: query_set(&g, wgpu::QueryType::Occlusion, 2),
            beginning: 0,
            end: 1,
        },
    };
    expect_missing(r.set_pass_timestamps(&g.device, Some(foreign)));
    assert!(r.pass_timestamps().is_none());
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    draw_frame(&g, &mut r, &target, &desc, Some(wgpu::Color::BLACK)).unwrap();
}

/// Query sets and indices the pass cannot write are typed errors that
/// change nothing; the renderer keeps the timestamps it had.
#[test]
fn bad_timestamp_queries_are_typed_errors() {
    let Some(g) = gpu() else { return };
    let (mut r, desc) = scene(g);
    let occlusion = PassTimestamps {
        query_set: query_set(g, wgpu::QueryType::Occlusion, 2),
        beginning: 0,
        end: 1,
    };
    let Some(timer) = GpuTimer::new(g) else {
        // The feature is checked first.
        expect_missing(r.set_pass_timestamps(&g.device, Some(occlusion)));
        eprintln!("the device has no TIMESTAMP_QUERY: only MissingFeature checked");
        return;
    };
    match r.set_pass_timestamps(&g.device, Some(occlusion)) {
        Err(RenderError::BadTimestampQuery {
            ty: wgpu::QueryType::Occlusion,
            count: 2,
            ..
        }) => {}
        other => panic!("expected BadTimestampQuery of an occlusion set, got {other:?}"),
    }
    r.set_pass_timestamps(&g.device, Some(timer.writes()))
        .unwrap();
    let good = timer.writes();
    for (beginning, end) in [(0, 2), (2, 1), (7, u32::MAX), (1, 1)] {
        let bad = PassTimestamps {
            beginning,
            end,
            ..good.clone()
        };
        expect_bad(r.set_pass_timestamps(&g.device, Some(bad)), beginning, end);
        assert_eq!(
            r.pass_timestamps(),
            Some(&good),
            "a refusal changes nothing"
        );
    }
    // Any two distinct indices inside the set will do.
    let reversed = PassTimestamps {
        beginning: 1,
        end: 0,
        ..good.clone()
    };
    r.set_pass_timestamps(&g.device, Some(reversed)).unwrap();
    r.set_pass_timestamps(&g.device, Some(good)).unwrap();
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let mut enc = g.device.create_command_encoder(&Default::default());
    r.prepare(&g.device, &g.queue, &mut enc, &desc).unwrap();
    timer.resolve(&mut enc);
    {
        let mut pass = target.pass(&mut enc, true);
        r.render(&mut pass).unwrap();
    }
    g.submit_wait(enc);
    assert!(timer.read_ms(g).is_some_and(|ms| ms >= 0.0));
}
