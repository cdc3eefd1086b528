//! Robust at the edges of the device and of the input: a device whose limits are
//! below what a setting needs gives a typed error naming the limit (never a wgpu
//! validation panic: the default uncaptured-error handler would panic here), a
//! bad host depth view is refused, and non-finite or degenerate cameras, frames
//! and settings are typed errors before any GPU work.

use brickray::{
    Camera, FrameDesc, HostDepthError, OutOfCoreConfig, PrepareError, Projection, RenderError,
    TransferFunction, Viewport, VolumeFrame, VolumeRenderer,
};
use brickray_harness::{GpuContext, Offscreen, WANTED_FEATURES, draw_frame, shared_gpu};
use glam::{Mat4, Vec3};
use std::sync::Arc;

/// A device whose limits are the adapter's, changed by `f`.
fn device_with(f: impl FnOnce(&mut wgpu::Limits)) -> GpuContext {
    GpuContext::with_limits(WANTED_FEATURES, |mut l| {
        f(&mut l);
        l
    })
    .expect("a device with lowered limits")
}

#[track_caller]
fn expect_limit<T: std::fmt::Debug>(r: Result<T, RenderError>, limit: &str) {
    match r {
        Err(RenderError::LowDeviceLimit {
            limit: l,
            required,
            available,
        }) if l == limit => {
            assert!(required > available, "{limit}: {required} <= {available}");
        }
        other => panic!("expected LowDeviceLimit({limit}), got {other:?}"),
    }
}

fn new_renderer(g: &GpuContext) -> Result<VolumeRenderer, RenderError> {
    VolumeRenderer::new(&g.device, brickray_harness::target_desc())
}

fn sphere() -> brickray::Volume {
    brickray_core::synthetic::sphere(32)
}

fn procedural(brick: u32) -> Arc<dyn brickray::BrickSource> {
    Arc::new(brickray::store::ProceduralSource::fractal_noise([1024; 3], brick, 1).unwrap())
}

#[test]
fn limits_below_the_kernels_needs_are_typed_errors_at_creation() {
    type Lower = fn(&mut wgpu::Limits);
    let cases: [(&str, Lower); 7] = [
        // The composite samples the ray caster's colour and depth.
        ("max_sampled_textures_per_shader_stage", |l| {
            l.max_sampled_textures_per_shader_stage = 1
        }),
        ("max_bind_groups", |l| l.max_bind_groups = 2),
        ("max_storage_textures_per_shader_stage", |l| {
            l.max_storage_textures_per_shader_stage = 2
        }),
        ("max_compute_invocations_per_workgroup", |l| {
            l.max_compute_invocations_per_workgroup = 32
        }),
        ("max_compute_workgroup_size_x", |l| {
            l.max_compute_workgroup_size_x = 4
        }),
        ("max_uniform_buffer_binding_size", |l| {
            l.max_uniform_buffer_binding_size = 128
        }),
        ("max_texture_dimension_2d", |l| {
            l.max_texture_dimension_2d = 0
        }),
    ];
    for (limit, f) in cases {
        let g = device_with(f);
        expect_limit(new_renderer(&g), limit);
    }
}

#[test]
fn limits_below_a_backends_needs_are_typed_errors() {
    // In core: 4 storage buffers per stage (TF, prediction history,
    // macro-cell ranges, skip distances; the TF's prefix sums are a table
    // texture).
    let g = device_with(|l| l.max_storage_buffers_per_shader_stage = 3);
    let mut r = new_renderer(&g).unwrap();
    expect_limit(
        r.set_volume(&g.device, &g.queue, &sphere()),
        "max_storage_buffers_per_shader_stage",
    );
    // Out of core: 13 sampled textures (the 8 every kernel has, the spread
    // and gradient atlases, and the slot, sub-cell and index tables), where
    // in core needs 9.
    let g = device_with(|l| l.max_sampled_textures_per_shader_stage = 12);
    let mut r = new_renderer(&g).unwrap();
    r.set_volume(&g.device, &g.queue, &sphere()).unwrap();
    expect_limit(
        r.set_volume_source(
            &g.device,
            &g.queue,
            procedural(32),
            OutOfCoreConfig::default(),
        ),
        "max_sampled_textures_per_shader_stage",
    );
    // At least 9 sampled textures for every kernel: 8 shared, and a
    // multi-channel volume's stacked TF tables, the in-core volume's
    // gradients, or out of core the atlases and tables.
    let g = device_with(|l| l.max_sampled_textures_per_shader_stage = 8);
    let mut r = new_renderer(&g).unwrap();
    expect_limit(
        r.set_volume(&g.device, &g.queue, &sphere()),
        "max_sampled_textures_per_shader_stage",
    );
    let two = brickray::ChannelVolume::new(vec![sphere(), sphere()]).unwrap();
    expect_limit(
        r.set_channel_volume(&g.device, &g.queue, &two),
        "max_sampled_textures_per_shader_stage",
    );
    expect_limit(
        r.set_volume_source(
            &g.device,
            &g.queue,
            procedural(32),
            OutOfCoreConfig::default(),
        ),
        "max_sampled_textures_per_shader_stage",
    );
    // Streamed channels: 4 storage buffers (out of core's 3: TF, prediction
    // history, usage counters; and the channels' classification) and 6
    // uniform buffers; one channel streams with one fewer of each.
    type Lower = fn(&mut wgpu::Limits);
    let below: [(&str, Lower); 2] = [
        ("max_storage_buffers_per_shader_stage", |l| {
            l.max_storage_buffers_per_shader_stage = 3
        }),
        ("max_uniform_buffers_per_shader_stage", |l| {
            l.max_uniform_buffers_per_shader_stage = 5
        }),
    ];
    for (limit, set) in below {
        let g = device_with(set);
        let mut r = new_renderer(&g).unwrap();
        let channels = brickray::ChannelSource::new(vec![procedural(32), procedural(32)]).unwrap();
        expect_limit(
            r.set_volume_source(
                &g.device,
                &g.queue,
                Arc::new(channels),
                OutOfCoreConfig::default(),
            ),
            limit,
        );
        r.set_volume_source(
            &g.device,
            &g.queue,
            procedural(32),
            OutOfCoreConfig::default(),
        )
        .unwrap();
    }
    // A volume beyond the 3D texture limit.
    let g = device_with(|l| l.max_texture_dimension_3d = 16);
    let mut r = new_renderer(&g).unwrap();
    assert!(matches!(
        r.set_volume(&g.device, &g.queue, &sphere()),
        Err(RenderError::VolumeTooLarge { limit: 16, .. })
    ));
}

#[test]
fn tables_beyond_the_storage_binding_limit_are_typed_errors() {
    let g = device_with(|l| l.max_storage_buffer_binding_size = 2048);
    let mut r = new_renderer(&g).unwrap();
    // 256 RGBA entries are 4 KiB; 64 are 1 KiB.
    expect_limit(
        r.set_transfer_function(&g.device, &g.queue, &TransferFunction::ramp(0.1, 0.9, 0.5)),
        "max_storage_buffer_binding_size",
    );
    let small = TransferFunction::from_points(&[(0.1, [1.0; 4])], 64);
    r.set_transfer_function(&g.device, &g.queue, &small)
        .unwrap();
    // Small bricks and a large pool: the usage counters (8 B a slot; the
    // slot, sub-cell and index tables are textures) exceed the binding.
    let config = OutOfCoreConfig {
        gpu_budget_bytes: 4 << 20,
        ..Default::default()
    };
    expect_limit(
        r.set_volume_source(&g.device, &g.queue, procedural(8), config),
        "max_storage_buffer_binding_size",
    );
}

/// The index grows with the cut: its table texture outgrows its first rows
/// and is made again with more (the views' bind groups with it), never a
/// validation error. (Its bound is `max_texture_dimension_2d` rows of 2048
/// words, at least 4M words: beyond what a test builds; the storage buffer
/// it used to be had a binding limit a test could reach, and
/// `tables_beyond_the_storage_binding_limit_are_typed_errors` still checks
/// the usage counters'.)
#[test]
fn an_index_outgrowing_its_table_keeps_drawing() {
    let frame = VolumeFrame::centered([1024; 3], [1.0; 3]);
    let config = OutOfCoreConfig {
        gpu_budget_bytes: 1 << 20,
        tolerance_px: 0.0,
        upload_budget_bytes: 1 << 30,
        ..Default::default()
    };
    let tf = TransferFunction::from_points(&[(0.3, [1.0, 1.0, 1.0, 0.0]), (0.6, [1.0; 4])], 64);
    // Close up: many culled (empty) leaves per data leaf.
    let camera = Camera::orbit(frame.center(), 0.7, 0.4, 0.3);
    let desc = FrameDesc::new(camera, frame, 96, 96);
    let g = shared_gpu();
    let mut r = new_renderer(g).unwrap();
    r.set_volume_source(&g.device, &g.queue, procedural(8), config)
        .unwrap();
    r.set_transfer_function(&g.device, &g.queue, &tf).unwrap();
    let target = Offscreen::new(&g.device, 96, 96);
    let mut most = 0;
    for _ in 0..300 {
        draw_frame(g, &mut r, &target, &desc, None).unwrap();
        most = most.max(r.stats().out_of_core.unwrap().index_words);
        if !r.wants_redraw() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    assert!(!r.wants_redraw(), "the cut did not converge");
    // The first table holds 4096 words (two rows).
    assert!(most > 4096, "index of {most} words");
}

#[test]
fn viewports_beyond_the_device_are_refused() {
    let g = device_with(|l| l.max_compute_workgroups_per_dimension = 4);
    let mut r = new_renderer(&g).unwrap();
    r.set_volume(&g.device, &g.queue, &sphere()).unwrap();
    r.set_transfer_function(&g.device, &g.queue, &TransferFunction::ramp(0.1, 0.9, 0.5))
        .unwrap();
    let frame = VolumeFrame::centered([32; 3], [1.0; 3]);
    let camera = Camera::orbit(frame.center(), 2.0, 0.0, 0.0);
    let mut enc = g.device.create_command_encoder(&Default::default());
    // 32 px = 4 workgroups fits, 40 px = 5 does not.
    r.prepare(
        &g.device,
        &g.queue,
        &mut enc,
        &FrameDesc::new(camera, frame, 32, 32),
    )
    .unwrap();
    assert!(matches!(
        r.prepare(
            &g.device,
            &g.queue,
            &mut enc,
            &FrameDesc::new(camera, frame, 40, 32)
        ),
        Err(PrepareError::BadViewport { .. })
    ));
}

fn ready_renderer() -> (&'static GpuContext, VolumeRenderer, VolumeFrame) {
    let g = shared_gpu();
    let mut r = new_renderer(g).unwrap();
    r.set_volume(&g.device, &g.queue, &sphere()).unwrap();
    r.set_transfer_function(&g.device, &g.queue, &TransferFunction::ramp(0.1, 0.9, 0.5))
        .unwrap();
    (g, r, VolumeFrame::centered([32; 3], [1.0; 3]))
}

#[test]
fn bad_host_depth_views_are_refused() {
    let (g, mut r, frame) = ready_renderer();
    let camera = Camera::orbit(frame.center(), 2.0, 0.0, 0.0);
    let make = |format, usage, samples| {
        g.device
            .create_texture(&wgpu::TextureDescriptor {
                label: Some("test host depth"),
                size: wgpu::Extent3d {
                    width: 32,
                    height: 32,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: samples,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage,
                view_formats: &[],
            })
            .create_view(&Default::default())
    };
    let attach = wgpu::TextureUsages::RENDER_ATTACHMENT;
    let bind = wgpu::TextureUsages::TEXTURE_BINDING;
    let no_binding = make(wgpu::TextureFormat::Depth32Float, attach, 1);
    let colour = make(wgpu::TextureFormat::Rgba8Unorm, attach | bind, 1);
    let msaa = make(wgpu::TextureFormat::Depth32Float, attach | bind, 4);
    let mut enc = g.device.create_command_encoder(&Default::default());
    let mut check = |view: &wgpu::TextureView, ok: fn(&HostDepthError) -> bool| {
        let desc = FrameDesc {
            host_depth: Some(view),
            ..FrameDesc::new(camera, frame, 32, 32)
        };
        match r.prepare(&g.device, &g.queue, &mut enc, &desc) {
            Err(PrepareError::HostDepth(e)) if ok(&e) => {}
            other => panic!("expected a host depth error, got {other:?}"),
        }
    };
    check(&no_binding, |e| matches!(e, HostDepthError::NotBindable(_)));
    check(&colour, |e| matches!(e, HostDepthError::NotDepth(_)));
    check(&msaa, |e| matches!(e, HostDepthError::Multisampled(4)));
}

#[test]
fn non_finite_or_degenerate_frames_are_refused_before_gpu_work() {
    let (g, mut r, frame) = ready_renderer();
    let ok = Camera::orbit(frame.center(), 2.0, 0.3, 0.2);
    let cameras = [
        Camera {
            eye: Vec3::NAN,
            ..ok
        },
        Camera {
            target: ok.eye,
            ..ok
        },
        Camera {
            up: ok.target - ok.eye,
            ..ok
        },
        Camera {
            projection: Projection::Perspective { fov_y: 0.0 },
            ..ok
        },
        Camera {
            projection: Projection::Perspective { fov_y: f32::NAN },
            ..ok
        },
        Camera { near: 0.0, ..ok },
        Camera { far: ok.near, ..ok },
        Camera {
            projection: Projection::Orthographic { height: 0.0 },
            ..ok
        },
        Camera {
            projection: Projection::Orthographic { height: 1.0 },
            far: f32::INFINITY,
            ..ok
        },
    ];
    let mut enc = g.device.create_command_encoder(&Default::default());
    for camera in cameras {
        let desc = FrameDesc::new(camera, frame, 16, 16);
        assert!(
            matches!(
                r.prepare(&g.device, &g.queue, &mut enc, &desc),
                Err(PrepareError::Camera(_))
            ),
            "{camera:?} must be refused"
        );
    }
    let singular = VolumeFrame {
        model: Mat4::ZERO,
        ..frame
    };
    let desc = FrameDesc::new(ok, singular, 16, 16);
    assert!(matches!(
        r.prepare(&g.device, &g.queue, &mut enc, &desc),
        Err(PrepareError::Frame(_))
    ));
    let mut desc = FrameDesc::new(ok, frame, 16, 16);
    for bad in [1e-6, f32::NAN, -1.0] {
        desc.settings.step_factor = bad;
        assert!(matches!(
            r.prepare(&g.device, &g.queue, &mut enc, &desc),
            Err(PrepareError::Settings(_))
        ));
    }
    desc.settings = Default::default();
    desc.settings.mode = brickray::RenderMode::Iso {
        value: f32::NAN,
        color: [1.0; 3],
    };
    assert!(matches!(
        r.prepare(&g.device, &g.queue, &mut enc, &desc),
        Err(PrepareError::Settings(_))
    ));
    // Nothing was recorded: a refused frame leaves `render` refusing too.
    let target = Offscreen::new(&g.device, 16, 16);
    let mut e2 = g.device.create_command_encoder(&Default::default());
    let mut pass = target.pass(&mut e2, true);
    assert!(matches!(r.render(&mut pass), Err(RenderError::NotPrepared)));
    drop(pass);
    // A finite but absurd eye (1e30 away): accepted, and every ray's work is
    // bounded (by the box's diagonal over the step), so the frame ends.
    let far_eye = Camera {
        eye: Vec3::new(1e30, 0.0, 0.0),
        ..ok
    };
    draw_frame(
        g,
        &mut r,
        &target,
        &FrameDesc::new(far_eye, frame, 16, 16),
        None,
    )
    .unwrap();
    // Out-of-core knobs on an in-core renderer are typed errors.
    assert!(matches!(
        brickray_harness::configure(g, &r, |c| c.tolerance_px = 1.0),
        Err(RenderError::NotOutOfCore)
    ));
    // A viewport of zero pixels.
    let desc = FrameDesc {
        viewport: Viewport::full(0, 16),
        ..FrameDesc::new(ok, frame, 16, 16)
    };
    assert!(matches!(
        r.prepare(&g.device, &g.queue, &mut enc, &desc),
        Err(PrepareError::BadViewport { .. })
    ));
}
