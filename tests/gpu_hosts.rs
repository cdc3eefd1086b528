//! Hosts as they are: any projection (standard, reversed-Z, infinite far) with
//! any near plane, host-depth compositing in both depth conventions, MSAA passes
//! and viewport sub-rectangles.
//!
//! Thresholds: GPU vs CPU reference >= 45 dB PSNR for the projection sweep (the
//! issue's bar; an f32 inverse view-projection scored 38 dB at near = 1e-3 and
//! 21 dB at 1e-4), >= 40 dB for host-depth compositing (as in core); MSAA and
//! sub-rectangle renders equal the plain render (>= 60 dB, in practice
//! identical).

use brickray::{
    Camera, DepthConvention, FrameDesc, RenderMode, RenderSettings, Shading, TransferFunction,
    Viewport, Volume, VolumeFrame, VolumeRenderer,
};
use brickray_harness::{HostQuad, Offscreen, ct, draw_frame, shared_gpu as gpu};
use brickray_reference::{ReferenceOptions, assert_close, render_reference};
use glam::Vec3;

fn head_ct() -> Option<Volume> {
    let path = brickray_harness::shared_volume("invesalius_cranium_ct")?;
    Some(brickray::io::read_volume(path).expect("head CT reads"))
}

const SHADED: Shading = Shading {
    enabled: true,
    ambient: 0.3,
    diffuse: 0.7,
    specular: 0.2,
    shininess: 24.0,
};

/// The projections of the sweep: `(name, convention, infinite far)`.
const PROJECTIONS: [(&str, DepthConvention, bool); 4] = [
    ("standard", DepthConvention::Standard, false),
    ("reversed", DepthConvention::ReversedZ, false),
    ("standard_infinite", DepthConvention::Standard, true),
    ("reversed_infinite", DepthConvention::ReversedZ, true),
];

fn render(r: &mut VolumeRenderer, desc: &FrameDesc<'_>) -> Vec<u8> {
    let g = gpu();
    let vp = desc.viewport;
    let target = Offscreen::with(&g.device, vp.width, vp.height, 1, desc.camera.depth);
    draw_frame(g, r, &target, desc, Some(wgpu::Color::BLACK)).expect("frame");
    target.read_color(g)
}

/// The same view through every projection, with near planes from 1e-1 down to
/// 1e-6 of the volume's size: the image does not depend on them.
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
fn every_projection_and_near_plane_matches_the_reference() {
    let Some(vol) = head_ct() else { return };
    let g = gpu();
    let d = vol.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let size_world = frame.world_size().max_element();
    let size = 96;
    let cases = ct::scenes();
    let mut r = VolumeRenderer::new(&g.device, brickray_harness::target_desc()).unwrap();
    r.set_volume(&g.device, &g.queue, &vol).unwrap();
    let mut worst = f64::INFINITY;
    for (mode_name, mode, tf) in cases {
        r.set_transfer_function(&g.device, &g.queue, &tf).unwrap();
        let settings = RenderSettings {
            mode,
            shading: SHADED,
            ..Default::default()
        };
        let base = Camera::orbit(frame.center(), 2.0, 0.5, 0.3);
        // The model's colour does not depend on the near plane or the depth
        // convention (samples lie at the same points from the box entry), so one
        // reference serves the whole sweep.
        let reference = render_reference(
            &vol,
            &frame,
            &tf,
            &base,
            &settings,
            &ReferenceOptions::new(size, size),
        )
        .to_rgba8([0.0; 3]);
        for (proj, depth, infinite) in PROJECTIONS {
            for exp in 1..=6 {
                let camera = Camera {
                    near: size_world * 10f32.powi(-exp),
                    far: if infinite { f32::INFINITY } else { base.far },
                    depth,
                    ..base
                };
                let desc = FrameDesc {
                    settings,
                    ..FrameDesc::new(camera, frame, size, size)
                };
                let img = render(&mut r, &desc);
                let name = format!("projection_{mode_name}_{proj}_near1e-{exp}");
                let cmp = assert_close(&name, &img, &reference, size, size, 45.0)
                    .unwrap_or_else(|e| panic!("{e}"));
                eprintln!("{name}: {cmp}");
                worst = worst.min(cmp.psnr_db);
            }
        }
    }
    eprintln!("projection sweep: worst PSNR {worst:.1} dB");
}

/// A host quad in front occludes the volume; the volume occludes a host quad
/// behind it; a quad drawn after the volume is depth-tested against it. The GPU
/// image equals the CPU reference given the host's depth, composited over the
/// host's colour, in both depth conventions.
#[test]
fn host_depth_composites_both_ways() {
    for convention in [DepthConvention::Standard, DepthConvention::ReversedZ] {
        host_depth_case(convention);
    }
}

fn host_depth_case(convention: DepthConvention) {
    let g = gpu();
    let vol = brickray_core::synthetic::sphere(48);
    let tf = TransferFunction::ramp(0.1, 0.5, 0.5);
    let size = 96u32;
    let frame = VolumeFrame::centered(vol.dims(), [1.0; 3]);
    let camera = Camera {
        depth: convention,
        ..Camera::orbit(frame.center(), 2.0, 0.0, 0.0)
    };
    let settings = RenderSettings {
        mode: RenderMode::Iso {
            value: 0.5,
            color: [0.8, 0.8, 0.8],
        },
        ..Default::default()
    };
    let vp = camera.view_proj(1.0);
    // Clip depths of points in front of and behind the volume centre.
    let depth_of = |z: f32| {
        let c = vp * Vec3::new(0.0, 0.0, z).extend(1.0);
        c.z / c.w
    };
    let (d_front, d_back) = (depth_of(0.45), depth_of(-0.1));
    let quads = HostQuad::with(&g.device, 1, convention);
    let target = Offscreen::with(&g.device, size, size, 1, convention);
    let mut r = VolumeRenderer::new(&g.device, brickray_harness::target_desc()).unwrap();
    r.set_volume(&g.device, &g.queue, &vol).unwrap();
    r.set_transfer_function(&g.device, &g.queue, &tf).unwrap();
    // Pass 1: the host's opaque geometry.
    let mut enc = g.device.create_command_encoder(&Default::default());
    {
        let mut pass = target.pass(&mut enc, true);
        let red = [1.0, 0.0, 0.0, 1.0];
        quads.draw(&g.device, &mut pass, [-1.0, -1.0, -0.2, 1.0], d_front, red);
        let blue = [0.0, 0.0, 1.0, 1.0];
        quads.draw(&g.device, &mut pass, [0.2, -1.0, 1.0, 1.0], d_back, blue);
    }
    g.submit_wait(enc);
    let host_rgba = target.read_color(g);
    let host_depth = target.read_depth(g);
    // Pass 2: the volume, with the host's depth.
    let desc = FrameDesc {
        settings,
        host_depth: Some(&target.depth_view),
        ..FrameDesc::new(camera, frame, size, size)
    };
    draw_frame(g, &mut r, &target, &desc, None).unwrap();
    let gpu_rgba = target.read_color(g);
    let gpu_depth = target.read_depth(g);
    // The reference: the volume with the host's depth, over the host's colour.
    let img = render_reference(
        &vol,
        &frame,
        &tf,
        &camera,
        &settings,
        &ReferenceOptions::new(size, size).with_host_depth(&host_depth),
    );
    let mut expected = host_rgba.clone();
    for (i, p) in img.color.iter().enumerate() {
        for k in 0..3 {
            let host = host_rgba[4 * i + k] as f32 / 255.0;
            expected[4 * i + k] =
                ((p[k] + (1.0 - p[3]) * host).clamp(0.0, 1.0) * 255.0).round() as u8;
        }
    }
    let name = format!("host_depth_{convention:?}");
    let cmp = assert_close(&name, &gpu_rgba, &expected, size, size, 40.0)
        .unwrap_or_else(|e| panic!("{e}"));
    eprintln!("{name}: {cmp}");
    // Both ways, explicitly: the centre row shows red (front quad) on the left,
    // the volume in the middle, and blue beyond the sphere on the right.
    let px = |x: u32, y: u32| &gpu_rgba[(4 * (y * size + x)) as usize..][..3];
    let mid = size / 2;
    assert_eq!(px(5, mid), [255, 0, 0], "{name}: front quad must occlude");
    assert!(
        px(mid, mid)[0] > 100 && px(mid, mid)[2] > 100,
        "{name}: volume visible"
    );
    assert_eq!(px(size - 3, mid), [0, 0, 255], "{name}: back quad visible");
    let sphere_right = (mid..size)
        .rev()
        .find(|&x| px(x, mid) != [0, 0, 255])
        .unwrap();
    assert!(
        sphere_right > (size as f32 * 0.6) as u32,
        "{name}: the volume must cover the back quad"
    );
    // Depth written: the nearer of host and volume, everywhere.
    let nearer = |a: f32, b: f32| convention.nearer(a, b);
    for i in 0..(size * size) as usize {
        assert_eq!(
            nearer(gpu_depth[i], host_depth[i]),
            gpu_depth[i],
            "{name}: depth must never move back"
        );
        assert!(
            (gpu_depth[i] - nearer(img.depth[i], host_depth[i])).abs() < 2e-3
                || img.color[i][3] < 0.5,
            "{name}: pixel {i}: depth {} vs reference {}",
            gpu_depth[i],
            img.depth[i]
        );
    }
    // Geometry drawn after the volume is hidden where the volume is in front.
    let mut enc = g.device.create_command_encoder(&Default::default());
    {
        let mut pass = target.pass(&mut enc, false);
        let green = [0.0, 1.0, 0.0, 1.0];
        quads.draw(
            &g.device,
            &mut pass,
            [-0.2, -0.1, 0.2, 0.1],
            depth_of(0.0),
            green,
        );
    }
    g.submit_wait(enc);
    let after = target.read_color(g);
    let c = &after[(4 * (mid * size + mid)) as usize..][..3];
    assert_ne!(
        c,
        [0, 255, 0],
        "{name}: a quad behind the surface must be hidden"
    );
}

fn sphere_scene() -> (Volume, TransferFunction, VolumeFrame, Camera) {
    let vol = brickray_core::synthetic::sphere(48);
    let tf = TransferFunction::from_points(
        &[(0.2, [0.3, 0.6, 1.0, 0.0]), (0.9, [1.0, 0.8, 0.5, 0.6])],
        256,
    );
    let frame = VolumeFrame::centered(vol.dims(), [1.0; 3]);
    let camera = Camera::orbit(frame.center(), 1.8, 0.6, 0.3);
    (vol, tf, frame, camera)
}

/// A 4-sample host pass: every sample of a pixel receives the pixel's ray
/// result, so the resolved image equals the single-sampled one.
#[test]
fn msaa_host_pass_renders_the_same_pixels() {
    let g = gpu();
    let (vol, tf, frame, camera) = sphere_scene();
    let size = 64;
    let mut desc = FrameDesc::new(camera, frame, size, size);
    desc.settings.shading = SHADED;
    let mut plain = VolumeRenderer::new(&g.device, brickray_harness::target_desc()).unwrap();
    let msaa_targets = brickray_harness::target_desc().with_samples(4);
    let mut msaa = VolumeRenderer::new(&g.device, msaa_targets).unwrap();
    for r in [&mut plain, &mut msaa] {
        r.set_volume(&g.device, &g.queue, &vol).unwrap();
        r.set_transfer_function(&g.device, &g.queue, &tf).unwrap();
    }
    let one = render(&mut plain, &desc);
    let target = Offscreen::with(&g.device, size, size, 4, DepthConvention::Standard);
    draw_frame(g, &mut msaa, &target, &desc, Some(wgpu::Color::BLACK)).unwrap();
    let four = target.read_color(g);
    assert!(
        four.chunks_exact(4).any(|p| p[0] > 20),
        "MSAA image is black"
    );
    let cmp = assert_close("msaa", &four, &one, size, size, 60.0).unwrap_or_else(|e| panic!("{e}"));
    eprintln!("msaa: {cmp}");
}

/// A viewport inside a larger target (an egui paint callback's rectangle): the
/// pixels inside equal a render of the viewport's size, those outside are left
/// alone, and host depth is read at the viewport's pixels.
#[test]
fn viewport_sub_rectangle_renders_the_right_pixels() {
    let g = gpu();
    let (vol, tf, frame, camera) = sphere_scene();
    let mut r = VolumeRenderer::new(&g.device, brickray_harness::target_desc()).unwrap();
    r.set_volume(&g.device, &g.queue, &vol).unwrap();
    r.set_transfer_function(&g.device, &g.queue, &tf).unwrap();
    let (w, h) = (64u32, 48u32);
    let clear = wgpu::Color {
        r: 0.0,
        g: 0.0,
        b: 0.5,
        a: 1.0,
    };
    let alone = Offscreen::new(&g.device, w, h);
    draw_frame(
        g,
        &mut r,
        &alone,
        &FrameDesc::new(camera, frame, w, h),
        Some(clear),
    )
    .unwrap();
    let full = alone.read_color(g);
    let (tw, th) = (100u32, 80u32);
    let vp = Viewport {
        x: 21,
        y: 13,
        width: w,
        height: h,
    };
    let target = Offscreen::new(&g.device, tw, th);
    let desc = FrameDesc {
        viewport: vp,
        ..FrameDesc::new(camera, frame, w, h)
    };
    draw_frame(g, &mut r, &target, &desc, Some(clear)).unwrap();
    let img = target.read_color(g);
    let at = |x: u32, y: u32| &img[(4 * (y * tw + x)) as usize..][..4];
    let mut inside = Vec::with_capacity((w * h * 4) as usize);
    for y in 0..th {
        for x in 0..tw {
            let in_x = (vp.x..vp.x + w).contains(&x);
            let in_y = (vp.y..vp.y + h).contains(&y);
            if in_x && in_y {
                inside.extend_from_slice(at(x, y));
            } else {
                assert_eq!(
                    at(x, y),
                    [0, 0, 128, 255],
                    "pixel ({x}, {y}) outside the viewport"
                );
            }
        }
    }
    assert!(
        inside.chunks_exact(4).any(|p| p[0] > 20),
        "the volume is missing"
    );
    let cmp =
        assert_close("viewport", &inside, &full, w, h, 60.0).unwrap_or_else(|e| panic!("{e}"));
    eprintln!("viewport: {cmp}");
    // Host depth is read at the viewport's pixels: a quad in front of the
    // volume over the target's left half hides the volume there.
    let quads = HostQuad::new(&g.device);
    let mut enc = g.device.create_command_encoder(&Default::default());
    let edge_px = 50u32;
    let edge_ndc = 2.0 * edge_px as f32 / tw as f32 - 1.0;
    {
        let mut pass = target.pass(&mut enc, true);
        quads.draw(
            &g.device,
            &mut pass,
            [-1.0, -1.0, edge_ndc, 1.0],
            0.01,
            [1.0, 0.0, 0.0, 1.0],
        );
    }
    g.submit_wait(enc);
    let desc = FrameDesc {
        host_depth: Some(&target.depth_view),
        ..desc
    };
    draw_frame(g, &mut r, &target, &desc, None).unwrap();
    let img = target.read_color(g);
    let at = |x: u32, y: u32| &img[(4 * (y * tw + x)) as usize..][..3];
    let mid_y = vp.y + h / 2;
    for x in vp.x..edge_px {
        assert_eq!(
            at(x, mid_y),
            [255, 0, 0],
            "pixel ({x}, {mid_y}) behind the host quad"
        );
    }
    let visible = (edge_px..vp.x + w)
        .filter(|&x| at(x, mid_y)[1] > 30)
        .count();
    assert!(visible > 5, "the volume must show right of the quad");
    // A host depth smaller than the viewport's extent is refused.
    let small = Offscreen::new(&g.device, 40, 40);
    let desc = FrameDesc {
        host_depth: Some(&small.depth_view),
        ..desc
    };
    let mut enc = g.device.create_command_encoder(&Default::default());
    assert!(matches!(
        r.prepare(&g.device, &g.queue, &mut enc, &desc),
        Err(brickray::PrepareError::HostDepth(
            brickray::HostDepthError::TooSmall { .. }
        ))
    ));
}

/// A streamed volume's view of a 128^3 procedural volume, a 64x64 frame of
/// it, and a target.
fn streamed_scene() -> (VolumeRenderer, FrameDesc<'static>, Offscreen) {
    let g = gpu();
    let source = brickray::store::ProceduralSource::fractal_noise([128; 3], 32, 1).unwrap();
    let frame = VolumeFrame::centered([128; 3], [1.0; 3]);
    let camera = Camera::orbit(frame.center(), 1.8, 0.5, 0.3);
    let mut r = VolumeRenderer::new(&g.device, brickray_harness::target_desc()).unwrap();
    r.set_volume_source(
        &g.device,
        &g.queue,
        std::sync::Arc::new(source),
        brickray::OutOfCoreConfig::default(),
    )
    .unwrap();
    let tf = TransferFunction::ramp(0.3, 0.8, 0.3);
    r.set_transfer_function(&g.device, &g.queue, &tf).unwrap();
    let target = Offscreen::new(&g.device, 64, 64);
    (r, FrameDesc::new(camera, frame, 64, 64), target)
}

fn feedback_applied(r: &VolumeRenderer) -> u64 {
    r.stats().out_of_core.unwrap().feedback.frames_applied
}

/// A host that prepares one streamed view two or three times into one
/// encoder before submitting it (a redraw before the submit, say) submits
/// without a panic: no read-back buffer is mapped while an encoder not yet
/// submitted copies into it. The usage feedback keeps arriving, in these
/// frames and in ordinary ones after them.
#[test]
fn several_prepares_into_one_encoder_out_of_core() {
    let g = gpu();
    for prepares in [2, 3] {
        let (mut r, desc, target) = streamed_scene();
        for _ in 0..12 {
            let mut enc = g.device.create_command_encoder(&Default::default());
            for _ in 0..prepares {
                r.prepare(&g.device, &g.queue, &mut enc, &desc).unwrap();
            }
            {
                let mut pass = target.pass(&mut enc, true);
                r.render(&mut pass).unwrap();
            }
            g.submit_wait(enc);
        }
        let applied = feedback_applied(&r);
        assert!(
            applied >= 8,
            "{prepares} prepares: {applied} read-backs applied"
        );
        for _ in 0..4 {
            draw_frame(g, &mut r, &target, &desc, None).unwrap();
        }
        assert!(
            feedback_applied(&r) >= applied + 3,
            "{prepares} prepares: feedback stopped"
        );
    }
}

/// Planned in `prepare` (the default), a converged view whose camera and
/// classification stay is not planned again: its frames draw the converged
/// plan (the same image, no new plan applied) until the camera moves.
#[test]
fn a_converged_static_view_is_not_planned_again() {
    let g = gpu();
    let (mut r, desc, target) = streamed_scene();
    let settled = brickray_harness::draw_until_settled(g, &mut r, &target, &desc, 200).unwrap();
    assert!(settled.is_some(), "not converged");
    let planned = |r: &VolumeRenderer| r.stats().out_of_core.unwrap().cache.frame;
    let (frame, image) = (planned(&r), target.read_color(g));
    for _ in 0..3 {
        draw_frame(g, &mut r, &target, &desc, Some(wgpu::Color::BLACK)).unwrap();
        assert_eq!(
            planned(&r),
            frame,
            "a static converged view was planned again"
        );
        assert!(!r.wants_redraw());
    }
    assert!(target.read_color(g) == image, "the image changed");
    let moved = FrameDesc {
        camera: Camera::orbit(desc.frame.center(), 1.8, 0.6, 0.3),
        ..desc
    };
    draw_frame(g, &mut r, &target, &moved, Some(wgpu::Color::BLACK)).unwrap();
    assert!(planned(&r) > frame, "a moved camera was not planned");
}

/// Encoders the host drops without submitting them hold no read-back entry
/// for ever: after more dropped frames than the read-back rings hold, the
/// feedback still arrives.
#[test]
fn dropped_encoders_do_not_exhaust_the_read_back_rings() {
    let g = gpu();
    let (mut r, desc, target) = streamed_scene();
    for _ in 0..3 {
        draw_frame(g, &mut r, &target, &desc, None).unwrap();
    }
    for _ in 0..10 {
        let mut enc = g.device.create_command_encoder(&Default::default());
        r.prepare(&g.device, &g.queue, &mut enc, &desc).unwrap();
        drop(enc);
    }
    let applied = feedback_applied(&r);
    for _ in 0..6 {
        draw_frame(g, &mut r, &target, &desc, None).unwrap();
    }
    let fb = r.stats().out_of_core.unwrap().feedback;
    eprintln!("feedback: {fb:?}");
    assert!(fb.frames_applied >= applied + 4, "feedback stopped: {fb:?}");
}

/// A viewport whose far edge overflows `u32` (x = u32::MAX - 8) or lies past
/// the largest target the device can create is a typed error at `prepare`,
/// and `render` then draws nothing and does not panic.
#[test]
fn viewport_offsets_past_any_target_are_typed_errors() {
    let g = gpu();
    let (vol, tf, frame, camera) = sphere_scene();
    let mut r = VolumeRenderer::new(&g.device, brickray_harness::target_desc()).unwrap();
    r.set_volume(&g.device, &g.queue, &vol).unwrap();
    r.set_transfer_function(&g.device, &g.queue, &tf).unwrap();
    let limit = g.device.limits().max_texture_dimension_2d;
    let target = Offscreen::new(&g.device, 64, 64);
    let cases = [
        (u32::MAX - 8, 0),
        (0, u32::MAX - 8),
        (limit - 32, 0),
        (0, limit),
    ];
    for (x, y) in cases {
        let desc = FrameDesc {
            viewport: Viewport {
                x,
                y,
                width: 64,
                height: 64,
            },
            ..FrameDesc::new(camera, frame, 64, 64)
        };
        let mut enc = g.device.create_command_encoder(&Default::default());
        let got = r.prepare(&g.device, &g.queue, &mut enc, &desc);
        assert!(
            matches!(got, Err(brickray::PrepareError::ViewportOutOfRange { .. })),
            "({x}, {y}): {got:?}"
        );
        {
            let mut pass = target.pass(&mut enc, true);
            assert!(matches!(
                r.render(&mut pass),
                Err(brickray::RenderError::NotPrepared)
            ));
        }
        g.submit_wait(enc);
    }
    // The largest viewport that fits still renders.
    let desc = FrameDesc {
        viewport: Viewport {
            x: limit - 64,
            y: 0,
            width: 64,
            height: 64,
        },
        ..FrameDesc::new(camera, frame, 64, 64)
    };
    let mut enc = g.device.create_command_encoder(&Default::default());
    r.prepare(&g.device, &g.queue, &mut enc, &desc).unwrap();
}

/// A frame description whose volume frame has other dims than the volume
/// drawn (in core and out of core) is a typed error at `prepare`, not an
/// empty image; a volume whose value range is not finite is refused by
/// `set_volume`. `render` then draws nothing and does not panic.
#[test]
fn frames_and_volumes_that_do_not_fit_are_typed_errors() {
    let g = gpu();
    let (vol, tf, frame, camera) = sphere_scene();
    let target = Offscreen::new(&g.device, 64, 64);
    let mut r = VolumeRenderer::new(&g.device, brickray_harness::target_desc()).unwrap();
    r.set_volume(&g.device, &g.queue, &vol).unwrap();
    r.set_transfer_function(&g.device, &g.queue, &tf).unwrap();
    let mismatched = |r: &mut VolumeRenderer, frame: VolumeFrame, volume: [u32; 3]| {
        let desc = FrameDesc::new(camera, frame, 64, 64);
        let mut enc = g.device.create_command_encoder(&Default::default());
        let got = r.prepare(&g.device, &g.queue, &mut enc, &desc);
        assert!(
            matches!(
                got,
                Err(brickray::PrepareError::FrameDoesNotFit { frame: f, volume: v })
                    if f == frame.dims && v == volume
            ),
            "{:?} over {volume:?}: {got:?}",
            frame.dims
        );
        {
            let mut pass = target.pass(&mut enc, true);
            assert!(matches!(
                r.render(&mut pass),
                Err(brickray::RenderError::NotPrepared)
            ));
        }
        g.submit_wait(enc);
    };
    mismatched(&mut r, VolumeFrame::centered([64; 3], [1.0; 3]), vol.dims());
    mismatched(
        &mut r,
        VolumeFrame::centered([48, 48, 47], [1.0; 3]),
        vol.dims(),
    );
    // The matching frame still draws.
    draw_frame(
        g,
        &mut r,
        &target,
        &FrameDesc::new(camera, frame, 64, 64),
        None,
    )
    .unwrap();
    // Out of core.
    let (mut s, desc, _) = streamed_scene();
    mismatched(&mut s, VolumeFrame::centered([256; 3], [1.0; 3]), [128; 3]);
    draw_frame(g, &mut s, &target, &desc, None).unwrap();
    // Value ranges that normalize every sample to NaN or to one value.
    for range in [
        [f32::NAN, 1.0],
        [0.0, f32::NAN],
        [0.0, f32::INFINITY],
        [f32::NEG_INFINITY, 1.0],
        [-3e38, 3e38],
    ] {
        let mut bad = vol.clone();
        bad.set_value_range(range);
        let got = r.set_volume(&g.device, &g.queue, &bad);
        assert!(
            matches!(got, Err(brickray::RenderError::BadValueRange { .. })),
            "{range:?}: {got:?}"
        );
    }
}
