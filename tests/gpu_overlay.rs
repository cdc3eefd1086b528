//! A label map over the image it segments, in one ray, on a real wgpu device
//! (lavapipe in CI), against the CPU reference's overlay
//! (`brickray_core::overlay`, `ReferenceOptions::overlay`):
//!
//! * two volumes on different grids and placements (a coarser, anisotropic,
//!   shifted label map that covers part of the image and reaches past it),
//!   both modes (colour, mask), nearest and smooth label boundaries, the
//!   image in core and out of core at its finest level, and iso surfaces and
//!   MIP maxima tinted in colour mode: >= 45 dB PSNR;
//! * the shared label maps over the images they segment (the Brodmann atlas
//!   over the Colin27 MRI, the nuclei over their fluorescence), in core:
//!   >= 45 dB;
//! * an overlay that is not a label map, or over a label map, is refused
//!   with a typed error; removing it draws the image alone again.
//!
//! Images are marched at the reference's step (1/8 voxel), as for label maps
//! alone (`gpu_labels.rs`): a label boundary is a step in the data.

use brickray::core::labels::{LabelTable, label_volume};
use brickray::{
    Camera, FrameDesc, LabelOverlay, OutOfCoreConfig, OverlayError, OverlayMode, OverlayStyle,
    RenderError, RenderMode, RenderSettings, TransferFunction, Volume, VolumeData, VolumeDesc,
    VolumeFrame, VolumeRenderer, overlay_transform,
};
use brickray_harness::predict::draw;
use brickray_harness::{Offscreen, draw_until_settled, shared_gpu as gpu, target_desc};
use brickray_reference::{ReferenceOptions, assert_close, compare, render_reference};
use glam::{Mat4, Vec3};
use std::sync::Arc;

const SIZE: u32 = 128;
const MIN_DB: f64 = 45.0;

fn settings(smooth_labels: bool) -> RenderSettings {
    RenderSettings {
        mode: RenderMode::Dvr,
        step_factor: brickray_reference::DEFAULT_STEP_FACTOR,
        smooth_labels,
        ..Default::default()
    }
}

/// A 40x36x32 u16 image: two soft blobs and a faint shell.
fn image() -> Volume {
    let d = [40u32, 36, 32];
    let mut v = Vec::with_capacity((d[0] * d[1] * d[2]) as usize);
    for z in 0..d[2] {
        for y in 0..d[1] {
            for x in 0..d[0] {
                let p = Vec3::new(x as f32, y as f32, z as f32) / Vec3::new(40.0, 36.0, 32.0);
                let a = (-(p - Vec3::new(0.35, 0.4, 0.5)).length_squared() * 30.0).exp();
                let b = (-(p - Vec3::new(0.7, 0.6, 0.45)).length_squared() * 45.0).exp();
                let r = (p - Vec3::splat(0.5)).length();
                let shell = (-((r - 0.42) * 25.0).powi(2)).exp() * 0.3;
                v.push(((a + b + shell).min(1.0) * 60000.0) as u16);
            }
        }
    }
    let desc = VolumeDesc {
        dims: d,
        dtype: brickray::DType::U16,
        spacing: [1.0, 1.0, 1.2],
        value_range: [0.0, 60000.0],
        kind: brickray::VolumeKind::Intensity,
    };
    Volume::new(desc, VolumeData::U16(v)).unwrap()
}

/// A 20x24x12 u8 label map of slabs and a ball: ids 1..=4 by x quarter
/// (background 0 in the first), 9 inside a ball.
fn labels() -> Volume {
    let d = [20u32, 24, 12];
    let mut v = Vec::with_capacity((d[0] * d[1] * d[2]) as usize);
    for z in 0..d[2] {
        for y in 0..d[1] {
            for x in 0..d[0] {
                let p = Vec3::new(x as f32 + 0.5, y as f32 + 0.5, z as f32 + 0.5)
                    / Vec3::new(20.0, 24.0, 12.0);
                let id = if (p - Vec3::new(0.6, 0.5, 0.5)).length() < 0.22 {
                    9
                } else {
                    (x * 4 / d[0]) as u8
                };
                v.push(id);
            }
        }
    }
    label_volume(d, [2.0, 1.5, 3.0], VolumeData::U8(v)).unwrap()
}

/// The image's frame and the label map's, in one world: the labels cover a
/// shifted, stretched box that reaches past the image on two sides.
fn frames(img: &Volume) -> (VolumeFrame, VolumeFrame) {
    let d = img.desc();
    let image = VolumeFrame::centered(d.dims, d.spacing);
    let box_in_image = Mat4::from_translation(Vec3::new(0.1, -0.15, 0.05))
        * Mat4::from_scale(Vec3::new(0.75, 1.3, 0.8));
    let labels = VolumeFrame::new(image.model * box_in_image, labels().dims());
    (image, labels)
}

fn tf() -> TransferFunction {
    TransferFunction::from_points(
        &[
            (0.05, [0.9, 0.9, 0.9, 0.0]),
            (0.25, [0.9, 0.85, 0.8, 0.08]),
            (1.0, [1.0, 1.0, 1.0, 0.5]),
        ],
        256,
    )
}

fn reference(
    img: &Volume,
    frame: &VolumeFrame,
    camera: &Camera,
    overlay: &LabelOverlay<'_>,
    smooth: bool,
) -> Vec<u8> {
    render_reference(
        img,
        frame,
        &tf(),
        camera,
        &settings(smooth),
        &ReferenceOptions::new(SIZE, SIZE).with_overlay(overlay),
    )
    .to_rgba8([0.0; 3])
}

fn store(vol: &Volume, dir: &std::path::Path) -> Arc<dyn brickray::core::BrickSource> {
    let path = dir.join("image.brs");
    let mut reader = brickray::io::MemoryReader::new(vol.clone(), "memory");
    let options = brickray::store::BuildOptions {
        brick: 16,
        ..Default::default()
    };
    brickray::store::build(&mut reader, &path, &options).unwrap();
    Arc::new(brickray::store::open(&path).unwrap())
}

/// Renderers of `img` with the test's TF: in core, and out of core from a
/// store in `dir` at its finest level.
fn renderers(img: &Volume, dir: &std::path::Path) -> [VolumeRenderer; 2] {
    let g = gpu();
    let mut incore = VolumeRenderer::new(&g.device, target_desc()).unwrap();
    incore.set_volume(&g.device, &g.queue, img).unwrap();
    let mut ooc = VolumeRenderer::new(&g.device, target_desc()).unwrap();
    let config = OutOfCoreConfig {
        tolerance_px: 0.0,
        upload_budget_bytes: 1 << 30,
        ..Default::default()
    };
    ooc.set_volume_source(&g.device, &g.queue, store(img, dir), config)
        .unwrap();
    for r in [&mut incore, &mut ooc] {
        r.set_transfer_function(&g.device, &g.queue, &tf()).unwrap();
    }
    [incore, ooc]
}

#[test]
fn overlays_on_different_grids_match_the_reference() {
    let g = gpu();
    let img = image();
    let lab = labels();
    let (frame, lframe) = frames(&img);
    let mut table = LabelTable::default();
    table.set_opacity(9, 1.0);
    let camera = Camera::orbit(frame.center(), 2.2, 0.7, 0.35);
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let dir = tempfile::tempdir().unwrap();
    let [mut incore, mut ooc] = renderers(&img, dir.path());

    // The image alone, to show the overlay changes the picture.
    let plain = FrameDesc {
        settings: settings(false),
        ..FrameDesc::new(camera, frame, SIZE, SIZE)
    };
    let alone = draw(g, &mut incore, &target, &plain).unwrap().color;

    for (mode, opacity) in [(OverlayMode::Color, 0.8), (OverlayMode::Mask, 1.0)] {
        let overlay = LabelOverlay {
            labels: &lab,
            image_to_labels: overlay_transform(&frame, &lframe),
            table: &table,
            style: OverlayStyle { mode, opacity },
        };
        incore
            .set_overlay(&g.device, &g.queue, Some(&overlay))
            .unwrap();
        ooc.set_overlay(&g.device, &g.queue, Some(&overlay))
            .unwrap();
        for smooth in [false, true] {
            let expected = reference(&img, &frame, &camera, &overlay, smooth);
            let desc = FrameDesc {
                settings: settings(smooth),
                ..plain.clone()
            };
            let name = format!(
                "overlay_{mode:?}_{}",
                if smooth { "smooth" } else { "nearest" }
            );
            let got = draw(g, &mut incore, &target, &desc).unwrap().color;
            let cmp = assert_close(
                &format!("{name}_incore"),
                &got,
                &expected,
                SIZE,
                SIZE,
                MIN_DB,
            )
            .unwrap_or_else(|e| panic!("{e}"));
            let change = compare(&alone, &expected, SIZE, SIZE);
            eprintln!("{name}_incore: {cmp}; the image alone vs the overlay: {change}");
            assert!(
                change.psnr_db < 35.0,
                "{name}: the overlay barely changes the image ({change})"
            );
            draw_until_settled(g, &mut ooc, &target, &desc, 300)
                .unwrap()
                .expect("out of core settles");
            let got = target.read_color(g);
            let cmp = assert_close(&format!("{name}_ooc"), &got, &expected, SIZE, SIZE, MIN_DB)
                .unwrap_or_else(|e| panic!("{e}"));
            eprintln!("{name}_ooc_finest: {cmp}");
        }
    }

    // Iso surfaces and MIP maxima tinted by the label under them (colour
    // mode), in core and out of core.
    let overlay = LabelOverlay {
        labels: &lab,
        image_to_labels: overlay_transform(&frame, &lframe),
        table: &table,
        style: OverlayStyle {
            mode: OverlayMode::Color,
            opacity: 1.0,
        },
    };
    incore
        .set_overlay(&g.device, &g.queue, Some(&overlay))
        .unwrap();
    ooc.set_overlay(&g.device, &g.queue, Some(&overlay))
        .unwrap();
    for (name, mode) in [
        (
            "iso",
            RenderMode::Iso {
                value: 0.3,
                color: [0.9, 0.9, 0.85],
            },
        ),
        ("mip", RenderMode::Mip),
    ] {
        let s = RenderSettings {
            mode,
            ..settings(false)
        };
        let expected = render_reference(
            &img,
            &frame,
            &tf(),
            &camera,
            &s,
            &ReferenceOptions::new(SIZE, SIZE).with_overlay(&overlay),
        )
        .to_rgba8([0.0; 3]);
        let desc = FrameDesc {
            settings: s,
            ..plain.clone()
        };
        let got = draw(g, &mut incore, &target, &desc).unwrap().color;
        let label = format!("overlay_{name}_incore");
        let cmp = assert_close(&label, &got, &expected, SIZE, SIZE, MIN_DB)
            .unwrap_or_else(|e| panic!("{e}"));
        let untinted = render_reference(
            &img,
            &frame,
            &tf(),
            &camera,
            &s,
            &ReferenceOptions::new(SIZE, SIZE),
        )
        .to_rgba8([0.0; 3]);
        let change = compare(&untinted, &expected, SIZE, SIZE);
        eprintln!("{label}: {cmp}; untinted vs tinted: {change}");
        assert!(change.psnr_db < 35.0, "{name}: the tint shows ({change})");
        draw_until_settled(g, &mut ooc, &target, &desc, 300)
            .unwrap()
            .expect("out of core settles");
        let label = format!("overlay_{name}_ooc_finest");
        let cmp = assert_close(&label, &target.read_color(g), &expected, SIZE, SIZE, MIN_DB)
            .unwrap_or_else(|e| panic!("{e}"));
        eprintln!("{label}: {cmp}");
    }

    // Removing the overlay draws the image alone again.
    incore.set_overlay(&g.device, &g.queue, None).unwrap();
    assert_eq!(incore.overlay_style(), None);
    let again = draw(g, &mut incore, &target, &plain).unwrap().color;
    assert_eq!(again, alone, "without the overlay the image is as before");
}

#[test]
fn overlays_that_cannot_be_drawn_are_refused() {
    let g = gpu();
    let img = image();
    let lab = labels();
    let table = LabelTable::default();
    let mut r = VolumeRenderer::new(&g.device, target_desc()).unwrap();
    r.set_volume(&g.device, &g.queue, &img).unwrap();
    let good = LabelOverlay {
        labels: &lab,
        image_to_labels: glam::DMat4::IDENTITY,
        table: &table,
        style: OverlayStyle::default(),
    };
    let not_labels = LabelOverlay {
        labels: &img,
        ..good
    };
    let err = r.set_overlay(&g.device, &g.queue, Some(&not_labels));
    assert!(
        matches!(err, Err(RenderError::Overlay(OverlayError::NotLabels))),
        "{err:?}"
    );
    let singular = LabelOverlay {
        image_to_labels: glam::DMat4::ZERO,
        ..good
    };
    let err = r.set_overlay(&g.device, &g.queue, Some(&singular));
    assert!(
        matches!(err, Err(RenderError::Overlay(OverlayError::BadTransform))),
        "{err:?}"
    );
    let err = r.set_overlay_style(
        &g.queue,
        OverlayStyle {
            opacity: f32::NAN,
            ..Default::default()
        },
    );
    assert!(
        matches!(err, Err(RenderError::Overlay(OverlayError::BadOpacity(_)))),
        "{err:?}"
    );
    // Over a label map.
    r.set_volume(&g.device, &g.queue, &lab).unwrap();
    let err = r.set_overlay(&g.device, &g.queue, Some(&good));
    assert!(
        matches!(err, Err(RenderError::Overlay(OverlayError::ImageIsLabels))),
        "{err:?}"
    );
    assert_eq!(r.overlay_bytes(), 0, "nothing was uploaded");
}

/// A shared image and the label map that segments it (same grid).
fn shared_pair(image: &str, labels: &str) -> Option<(Volume, Volume)> {
    let dir = brickray_harness::shared_data_dir()?;
    let read =
        |p: std::path::PathBuf| brickray::io::read_volume(&p).unwrap_or_else(|e| panic!("{e}"));
    let img = read(dir.join(image).join(format!("{image}.json")));
    let lab = read(
        dir.join("labels")
            .join(labels)
            .join(format!("{labels}.json")),
    );
    assert!(lab.desc().kind.is_labels());
    assert_eq!(img.dims(), lab.dims(), "the shared pairs share a grid");
    Some((img, lab))
}

fn check_shared(name: &str, img: &Volume, lab: &Volume, tf: &TransferFunction) {
    let g = gpu();
    let d = img.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let lframe = VolumeFrame::centered(lab.dims(), lab.desc().spacing);
    let table = LabelTable::default();
    let overlay = LabelOverlay {
        labels: lab,
        image_to_labels: overlay_transform(&frame, &lframe),
        table: &table,
        style: OverlayStyle {
            mode: OverlayMode::Color,
            opacity: 1.0,
        },
    };
    let camera = Camera::orbit(frame.center(), 2.2, 0.8, 0.45);
    let expected = render_reference(
        img,
        &frame,
        tf,
        &camera,
        &settings(false),
        &ReferenceOptions::new(SIZE, SIZE).with_overlay(&overlay),
    )
    .to_rgba8([0.0; 3]);
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let mut r = VolumeRenderer::new(&g.device, target_desc()).unwrap();
    r.set_volume(&g.device, &g.queue, img).unwrap();
    r.set_transfer_function(&g.device, &g.queue, tf).unwrap();
    r.set_overlay(&g.device, &g.queue, Some(&overlay)).unwrap();
    let desc = FrameDesc {
        settings: settings(false),
        ..FrameDesc::new(camera, frame, SIZE, SIZE)
    };
    let got = draw(g, &mut r, &target, &desc).unwrap().color;
    let cmp = assert_close(
        &format!("overlay_{name}"),
        &got,
        &expected,
        SIZE,
        SIZE,
        MIN_DB,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    eprintln!("overlay_{name}_incore: {cmp}");
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
fn brodmann_over_its_mri_matches_reference() {
    let Some((img, lab)) = shared_pair("mricron_ch2_mri", "mricron_brodmann_labels") else {
        return;
    };
    let tf = TransferFunction::from_points(
        &[
            (0.15, [0.8, 0.8, 0.8, 0.0]),
            (0.35, [0.9, 0.9, 0.9, 0.05]),
            (0.7, [1.0, 1.0, 1.0, 0.3]),
        ],
        256,
    );
    check_shared("brodmann", &img, &lab, &tf);
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
fn nuclei_over_their_fluorescence_match_reference() {
    let Some((img, lab)) = shared_pair("cells3d_nuclei_fluo", "cells3d_nuclei_labels") else {
        return;
    };
    let tf = TransferFunction::from_points(
        &[(0.1, [0.3, 0.9, 0.4, 0.0]), (0.5, [0.6, 1.0, 0.6, 0.3])],
        256,
    );
    check_shared("nuclei", &img, &lab, &tf);
}

/// Slice views with a label map over the image: each pixel takes the label
/// under its slab's front sample, in colour and mask modes, axial and
/// oblique, in core and out of core at the finest level, against the
/// reference's slices (`render_slice_with_overlay`).
#[test]
fn slices_with_an_overlay_match_the_reference() {
    use brickray::{ColorMap, Intensity, SliceAxis, SliceView, Window};
    let g = gpu();
    let img = image();
    let lab = labels();
    let (frame, lframe) = frames(&img);
    let table = LabelTable::default();
    let grey = Intensity::new(Window::from_min_max(0.0, 60000.0).unwrap(), ColorMap::Grey);
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let dir = tempfile::tempdir().unwrap();
    let [mut incore, mut ooc] = renderers(&img, dir.path());
    let desc = FrameDesc::new(
        Camera::orbit(frame.center(), 2.0, 0.3, 0.2),
        frame,
        SIZE,
        SIZE,
    );
    let views = [
        (
            "axial",
            SliceView::orthogonal(SliceAxis::Axial, 15.0, &frame, 1.0).unwrap(),
        ),
        (
            "oblique",
            SliceView::with_normal([20.0, 18.0, 16.0], [1.0, 2.0, 3.0], 1.0).unwrap(),
        ),
    ];
    for (mode, opacity) in [(OverlayMode::Color, 0.8), (OverlayMode::Mask, 1.0)] {
        let overlay = LabelOverlay {
            labels: &lab,
            image_to_labels: overlay_transform(&frame, &lframe),
            table: &table,
            style: OverlayStyle { mode, opacity },
        };
        for r in [&mut incore, &mut ooc] {
            r.set_overlay(&g.device, &g.queue, Some(&overlay)).unwrap();
            r.set_intensity(Some(grey));
        }
        for (name, view) in views {
            let expected = brickray_reference::render_slice_with_overlay(
                &img,
                &frame,
                &view,
                &grey,
                Some(&overlay),
                SIZE,
                SIZE,
            )
            .unwrap()
            .to_rgba8([0.0; 3]);
            let plain = brickray_reference::render_slice(&img, &frame, &view, &grey, SIZE, SIZE)
                .unwrap()
                .to_rgba8([0.0; 3]);
            let change = compare(&plain, &expected, SIZE, SIZE);
            assert!(
                change.psnr_db < 35.0,
                "{name} {mode:?}: the labels show ({change})"
            );
            for (path, r) in [("incore", &mut incore), ("ooc", &mut ooc)] {
                r.set_slice(Some(view));
                draw_until_settled(g, r, &target, &desc, 300)
                    .unwrap()
                    .expect("settles");
                let label = format!("overlay_slice_{name}_{mode:?}_{path}");
                let cmp =
                    assert_close(&label, &target.read_color(g), &expected, SIZE, SIZE, MIN_DB)
                        .unwrap_or_else(|e| panic!("{e}"));
                eprintln!("{label}: {cmp}; without the labels: {change}");
            }
        }
    }
}
