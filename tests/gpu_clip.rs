//! The clip box (`RenderSettings::clip`): the volume cut by an axis-aligned box
//! in texture space, in core and out of core, against the CPU reference with
//! the same clip.
//!
//! Thresholds: GPU vs CPU reference >= 40 dB PSNR (8-bit RGB over black, as in
//! `gpu_incore`); the clip must change the image (the unclipped GPU image
//! scores below 30 dB against the clipped one).

use brickray::{
    Camera, ClipBox, FrameDesc, OutOfCoreConfig, RenderMode, RenderSettings, TransferFunction,
    Volume, VolumeFrame, VolumeRenderer,
};
use brickray_harness::{Offscreen, draw_frame, draw_until_settled, shared_gpu as gpu, target_desc};
use brickray_reference::{ReferenceOptions, assert_close, psnr, render_reference};

const SIZE: u32 = 96;
const CLIP: ClipBox = ClipBox {
    min: [0.0, 0.0, 0.35],
    max: [0.7, 1.0, 1.0],
};

fn view(vol: &Volume, mode: RenderMode, clip: ClipBox) -> FrameDesc<'static> {
    let d = vol.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    FrameDesc {
        settings: RenderSettings {
            mode,
            clip,
            ..Default::default()
        },
        ..FrameDesc::new(
            Camera::orbit(frame.center(), 2.0, 0.5, 0.3),
            frame,
            SIZE,
            SIZE,
        )
    }
}

fn tf() -> TransferFunction {
    TransferFunction::from_points(
        &[(0.2, [0.3, 0.6, 1.0, 0.0]), (0.6, [1.0, 0.8, 0.5, 0.6])],
        256,
    )
}

fn in_core(vol: &Volume, desc: &FrameDesc<'_>) -> Vec<u8> {
    let g = gpu();
    let mut r = VolumeRenderer::new(&g.device, target_desc()).unwrap();
    r.set_volume(&g.device, &g.queue, vol).unwrap();
    r.set_transfer_function(&g.device, &g.queue, &tf()).unwrap();
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    draw_frame(g, &mut r, &target, desc, Some(wgpu::Color::BLACK)).unwrap();
    target.read_color(g)
}

fn out_of_core(vol: &Volume, desc: &FrameDesc<'_>) -> Vec<u8> {
    let g = gpu();
    let dir = tempfile::tempdir().unwrap();
    let source = brickray_harness::store_of(vol, &dir.path().join("vol.brs"));
    let mut r = VolumeRenderer::new(&g.device, target_desc()).unwrap();
    let config = OutOfCoreConfig {
        tolerance_px: 0.0,
        ..Default::default()
    };
    r.set_volume_source(&g.device, &g.queue, source, config)
        .unwrap();
    r.set_transfer_function(&g.device, &g.queue, &tf()).unwrap();
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let settled = draw_until_settled(g, &mut r, &target, desc, 300).unwrap();
    assert!(settled.is_some(), "out of core did not converge");
    target.read_color(g)
}

fn reference(vol: &Volume, desc: &FrameDesc<'_>) -> Vec<u8> {
    render_reference(
        vol,
        &desc.frame,
        &tf(),
        &desc.camera,
        &desc.settings,
        &ReferenceOptions::new(SIZE, SIZE),
    )
    .to_rgba8([0.0; 3])
}

#[test]
fn clip_box_matches_the_reference_in_core_and_out_of_core() {
    // The isosurface on a ball: on Marschner-Lobb the cut face crosses its
    // many shells almost tangentially, where a ray starting on the face is
    // inside or outside by rounding (the reference in f64, the GPU in f32).
    let ml = brickray::core::synthetic::marschner_lobb(48);
    let ball = brickray::core::synthetic::sphere(48);
    let iso = RenderMode::Iso {
        value: 0.5,
        color: [0.9, 0.8, 0.7],
    };
    // The ball's half facing the camera is cut away: rays enter it through
    // the cut face.
    let half = ClipBox {
        min: [0.0; 3],
        max: [0.5, 1.0, 1.0],
    };
    for (name, mode, vol, clip) in [
        ("dvr", RenderMode::Dvr, &ml, CLIP),
        ("iso", iso, &ball, half),
        ("mip", RenderMode::Mip, &ml, CLIP),
    ] {
        let clipped = view(vol, mode, clip);
        let cpu = reference(vol, &clipped);
        for (path, img) in [
            ("in_core", in_core(vol, &clipped)),
            ("out_of_core", out_of_core(vol, &clipped)),
        ] {
            let label = format!("clip_{name}_{path}");
            let cmp = assert_close(&label, &img, &cpu, SIZE, SIZE, 40.0)
                .unwrap_or_else(|e| panic!("{e}"));
            eprintln!("{label}: {cmp}");
        }
        let whole = in_core(vol, &view(vol, mode, ClipBox::FULL));
        let db = psnr(&whole, &cpu);
        assert!(
            db < 30.0,
            "{name}: the clip changed too little ({db:.1} dB)"
        );
    }
}

/// A clip box outside 0..1 or inverted is refused before any GPU work.
#[test]
fn bad_clip_boxes_are_refused() {
    let g = gpu();
    let vol = brickray::core::synthetic::sphere(16);
    let mut r = VolumeRenderer::new(&g.device, target_desc()).unwrap();
    r.set_volume(&g.device, &g.queue, &vol).unwrap();
    r.set_transfer_function(&g.device, &g.queue, &tf()).unwrap();
    for clip in [
        ClipBox {
            min: [0.5, 0.0, 0.0],
            max: [0.4, 1.0, 1.0],
        },
        ClipBox {
            min: [-0.1, 0.0, 0.0],
            max: [1.0; 3],
        },
    ] {
        let desc = view(&vol, RenderMode::Dvr, clip);
        let mut enc = g.device.create_command_encoder(&Default::default());
        let e = r.prepare(&g.device, &g.queue, &mut enc, &desc).unwrap_err();
        assert!(matches!(e, brickray::PrepareError::Settings(_)), "{e}");
    }
}
