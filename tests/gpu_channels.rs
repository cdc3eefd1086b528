//! Multi-channel volumes on a real wgpu device (lavapipe in CI), in core,
//! against the CPU reference's channel compositing
//! (`brickray_reference::render_channels_reference`, `brickray_core::channels`):
//!
//! * 2 and 4 u16 channels (blobs in different places over a shared faint
//!   shell), each in its own colour and window: DVR, shaded DVR, MIP and
//!   per-channel isosurfaces >= 45 dB PSNR;
//! * one channel equals today's single-channel image of that channel (the
//!   in-core kernel with the same transfer function): >= 60 dB;
//! * a hidden channel gives the image of the others (>= 60 dB) with the
//!   same samples as the volume without it (its regions are skipped as
//!   empty), and empty-space skipping skips only what is transparent in
//!   every visible channel: with it off the image is the same (>= 60 dB)
//!   and more samples are taken;
//! * the shared confocal nuclei (u16) with two transformed copies of it (a
//!   mirrored and a shifted one) as three channels: >= 45 dB in every mode
//!   (`brickray_harness::channels`, the `channels` bench's volumes);
//! * the shared nuclei as four channels written as an OME-Zarr with `omero`
//!   colours and windows, read back by `read_channels` and drawn with the
//!   file's styles: >= 45 dB in every mode;
//! * slices and slabs of channels against `render_channel_slice`: >= 45 dB;
//! * a label map over the channels (colour and mask), in DVR, iso, MIP and
//!   a slice, against the reference's overlay: >= 45 dB;
//! * the shared nuclei label map over the nuclei as three channels: >= 45 dB;
//! * typed errors: styles that do not match, no styles; warming up compiles
//!   the channel pipelines.
//!
//! Images are marched at step 1/2 in both renderers: what is compared is
//! the compositing, not the discretisation.

#[path = "channel_support.rs"]
mod channel_support;

use brickray::core::channels::{ChannelStyle, ChannelVolume};
use brickray::{
    Camera, ChannelError, FrameDesc, PrepareError, RenderError, RenderMode, RenderSettings,
    SliceAxis, SliceView, TransferFunction, Volume, VolumeData, VolumeFrame, VolumeRenderer,
};
use brickray_harness::predict::draw;
use brickray_harness::{Offscreen, shared_gpu as gpu, target_desc};
use brickray_reference::{ReferenceOptions, assert_close, compare, render_channels_reference};
use glam::Vec3;

const SIZE: u32 = 96;
const MIN_DB: f64 = 45.0;
const STEP: f32 = 0.5;

use brickray_harness::channels::COLORS;

use brickray_harness::channels::{
    blob_channel as channel, blob_channels as channels, blob_styles as styles,
};

fn modes() -> Vec<(&'static str, RenderSettings)> {
    brickray_harness::channels::modes(STEP, 0.45)
}

fn frame_of(v: &Volume) -> VolumeFrame {
    VolumeFrame::centered(v.dims(), v.desc().spacing)
}

fn renderer(vol: &ChannelVolume, styles: &[ChannelStyle]) -> VolumeRenderer {
    let g = gpu();
    let mut r = VolumeRenderer::new(&g.device, target_desc()).unwrap();
    r.set_channel_volume(&g.device, &g.queue, vol).unwrap();
    r.set_channel_styles(styles).unwrap();
    r
}

/// The GPU's and the reference's image of `vol` in every mode, each at
/// least `MIN_DB` apart; returns the smallest PSNR.
fn check(name: &str, vol: &ChannelVolume, styles: &[ChannelStyle], camera: Camera) -> f64 {
    let g = gpu();
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let mut r = renderer(vol, styles);
    channel_support::check_channel_modes(
        &format!("channels {name}"),
        &mut r,
        vol,
        styles,
        camera,
        SIZE,
        STEP,
        MIN_DB,
        200,
        |r, desc| draw(g, r, &target, desc).unwrap().color,
    )
}

#[test]
fn two_and_four_channels_match_the_reference() {
    let camera = Camera::orbit(Vec3::ZERO, 2.3, 0.6, 0.35);
    for n in [2, 4] {
        let vol = ChannelVolume::new(channels(n)).unwrap();
        check(&format!("{n} channels"), &vol, &styles(n), camera);
    }
}

/// Runs `check` on the four blob channels in core, seen from the tests'
/// camera, with the draw of a `SIZE` px target.
fn on_four_channels(
    check: impl FnOnce(
        &mut VolumeRenderer,
        &ChannelVolume,
        &[ChannelStyle],
        Camera,
        &mut channel_support::Draw<'_>,
    ),
) {
    let g = gpu();
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let vol = ChannelVolume::new(channels(4)).unwrap();
    let mut r = renderer(&vol, &styles(4));
    let camera = Camera::orbit(Vec3::ZERO, 2.3, 0.6, 0.35);
    let mut draw =
        |r: &mut VolumeRenderer, desc: &FrameDesc<'_>| draw(g, r, &target, desc).unwrap().color;
    check(&mut r, &vol, &styles(4), camera, &mut draw);
}

/// MIP refines each channel's peaks between samples
/// (`channel_support::check_channel_mip_at_a_coarse_step`, four channels at a
/// step of 2 voxels): the GPU against its twin >= 62 dB, and against the
/// fine reference at least 8 dB closer than the samples' maxima alone.
#[test]
fn channel_mip_refines_each_maximum_between_samples() {
    on_four_channels(|r, vol, styles, camera, draw| {
        let label = "four channels";
        channel_support::check_channel_mip_at_a_coarse_step(
            label, r, vol, styles, camera, SIZE, draw,
        );
    });
}

/// DVR's step doubles as the mixture's transmittance falls
/// (`channel_support::check_channel_adaptive_step`, four channels at a step
/// of 1 voxel): the GPU against its twin >= 55 dB, and 10 dB closer to it
/// than to the fixed step's reference.
#[test]
fn channel_dvr_takes_the_adaptive_step() {
    on_four_channels(|r, vol, styles, camera, draw| {
        let label = "four channels";
        channel_support::check_channel_adaptive_step(
            label, r, vol, styles, camera, SIZE, 1.0, 55.0, draw,
        );
    });
}

/// One channel drawn as a channel volume is the single-channel renderer's
/// image of it with the same transfer function (and isovalue).
#[test]
fn one_channel_is_the_single_channel_image() {
    let g = gpu();
    let vol = channel([0.4, 0.5, 0.5], 1.0);
    let frame = frame_of(&vol);
    let camera = Camera::orbit(Vec3::ZERO, 2.3, 0.6, 0.35);
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let style = ChannelStyle::window(COLORS[0], [0.08, 0.7], 0.6).with_isovalue(0.45);
    let mut multi = renderer(
        &ChannelVolume::new(vec![vol.clone()]).unwrap(),
        std::slice::from_ref(&style),
    );
    let mut single = VolumeRenderer::new(&g.device, target_desc()).unwrap();
    single.set_volume(&g.device, &g.queue, &vol).unwrap();
    single
        .set_transfer_function(&g.device, &g.queue, &style.tf)
        .unwrap();
    for (mode, mut settings) in modes() {
        if let RenderMode::Iso { .. } = settings.mode {
            settings.mode = RenderMode::Iso {
                value: style.isovalue,
                color: style.iso_color(),
            };
        }
        let desc = FrameDesc {
            settings,
            ..FrameDesc::new(camera, frame, SIZE, SIZE)
        };
        let a = draw(g, &mut multi, &target, &desc).unwrap().color;
        let b = draw(g, &mut single, &target, &desc).unwrap().color;
        let c = compare(&a, &b, SIZE, SIZE);
        eprintln!(
            "one channel {mode}: {:.1} dB, max {}",
            c.psnr_db, c.max_abs_diff
        );
        assert!(c.psnr_db >= 60.0, "one channel {mode}: {c:?}");
    }
}

/// Hiding a channel gives the image of the others, and lets empty-space
/// skipping skip what only that channel showed (fewer samples); with
/// skipping off the samples do not change.
#[test]
fn a_hidden_channel_is_absent_and_skipped() {
    let g = gpu();
    let all = channels(3);
    let camera = Camera::orbit(Vec3::ZERO, 2.3, 0.6, 0.35);
    let frame = frame_of(&all[0]);
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let three = ChannelVolume::new(all.clone()).unwrap();
    let two = ChannelVolume::new(vec![all[0].clone(), all[2].clone()]).unwrap();
    let mut s3 = styles(3);
    s3[1] = s3[1].clone().visible(false);
    let s2 = vec![styles(3)[0].clone(), styles(3)[2].clone()];
    let mut hidden = renderer(&three, &s3);
    let mut without = renderer(&two, &s2);
    let mut shown = renderer(&three, &styles(3));
    for (mode, settings) in modes() {
        let desc = FrameDesc {
            settings,
            ..FrameDesc::new(camera, frame, SIZE, SIZE)
        };
        let h = draw(g, &mut hidden, &target, &desc).unwrap();
        let w = draw(g, &mut without, &target, &desc).unwrap();
        let s = draw(g, &mut shown, &target, &desc).unwrap();
        let c = compare(&h.color, &w.color, SIZE, SIZE);
        eprintln!("hidden {mode}: {:.1} dB against the two others", c.psnr_db);
        assert!(c.psnr_db >= 60.0, "hidden {mode}: {c:?}");
        assert!(
            compare(&h.color, &s.color, SIZE, SIZE).psnr_db < 40.0,
            "{mode}: the hidden channel changed nothing"
        );
        let total = |v: &[u32]| v.iter().map(|&x| x as u64).sum::<u64>();
        let (sh, sw) = (total(&h.samples), total(&w.samples));
        eprintln!("{mode}: samples hidden {sh}, without {sw}");
        // Early termination ends rays sooner with more channels shown, so
        // the counts of hidden and shown are not ordered; a hidden channel
        // must be skipped exactly as an absent one.
        assert_eq!(
            sh, sw,
            "{mode}: a hidden channel is skipped as an absent one"
        );
        // Skipping off: every sample in the box is taken, visible or not.
        let off = FrameDesc {
            settings: RenderSettings {
                accel: brickray::core::Accel {
                    empty_space_skipping: false,
                    ..settings.accel
                },
                ..settings
            },
            ..desc.clone()
        };
        let ho = draw(g, &mut hidden, &target, &off).unwrap();
        assert!(total(&ho.samples) > sh, "{mode}: skipping skipped nothing");
        let c = compare(&ho.color, &h.color, SIZE, SIZE);
        assert!(
            c.psnr_db >= 60.0,
            "{mode}: skipping changed the image: {c:?}"
        );
    }
}

#[test]
fn styles_and_missing_styles_are_typed_errors() {
    let g = gpu();
    let vol = ChannelVolume::new(channels(2)).unwrap();
    let frame = frame_of(&vol.channels()[0]);
    let target = Offscreen::new(&g.device, 32, 32);
    let mut r = VolumeRenderer::new(&g.device, target_desc()).unwrap();
    r.set_channel_volume(&g.device, &g.queue, &vol).unwrap();
    let desc = FrameDesc::new(Camera::orbit(Vec3::ZERO, 2.3, 0.6, 0.35), frame, 32, 32);
    assert!(matches!(
        draw(g, &mut r, &target, &desc),
        Err(PrepareError::NoChannelStyles)
    ));
    assert!(matches!(
        r.set_channel_styles(&styles(3)),
        Err(RenderError::Channels(ChannelError::StyleCount {
            styles: 3,
            channels: 2
        }))
    ));
    r.set_channel_styles(&styles(2)).unwrap();
    // Warming up compiles the multi-channel kernel's pipelines.
    let all: Vec<RenderSettings> = modes().into_iter().map(|(_, s)| s).collect();
    r.warm_up(&g.device, &all).unwrap();
    draw(g, &mut r, &target, &desc).unwrap();
    // A single-channel volume set after channels needs its TF again.
    let tf = TransferFunction::ramp(0.1, 0.8, 0.5);
    r.set_volume(&g.device, &g.queue, &vol.channels()[0])
        .unwrap();
    r.set_transfer_function(&g.device, &g.queue, &tf).unwrap();
    draw(g, &mut r, &target, &desc).unwrap();
}

/// The shared confocal nuclei (u16, 256x256x60) with transformed copies of
/// it (mirrored in x; its values shifted by a quarter of the range) as three
/// channels (`brickray_harness::channels`, also the `channels` bench's).
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
fn shared_nuclei_as_three_channels_match_the_reference() {
    let Some(vol) = brickray_harness::channels::nuclei_channels(3) else {
        return;
    };
    let camera = Camera::orbit(Vec3::ZERO, 2.0, 0.5, 0.6);
    let worst = check(
        "nuclei x3",
        &vol,
        &brickray_harness::channels::nuclei_styles(3),
        camera,
    );
    eprintln!("nuclei x3: worst {worst:.1} dB");
}

/// Slice views of channels against the reference's (`render_channel_slice`):
/// an axial plane, an oblique plane, and slabs by maximum and mean; a
/// hidden channel is absent.
#[test]
fn channel_slices_match_the_reference() {
    let g = gpu();
    let vol = ChannelVolume::new(channels(3)).unwrap();
    let mut r = renderer(&vol, &styles(3));
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    channel_support::check_channel_slices(
        "channel slice",
        &mut r,
        &vol,
        &styles(3),
        SIZE,
        MIN_DB,
        300,
        |r, desc| draw(g, r, &target, desc).unwrap().color,
    );
}

/// From a file to the image: the shared nuclei as four channels written as
/// a multi-channel OME-Zarr with `omero` colours and windows, read back by
/// `read_channels` (every voxel equal), drawn with the file's styles, in
/// every mode against the reference (>= 45 dB).
#[test]
#[cfg(feature = "zarr")]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
fn a_four_channel_ome_zarr_is_drawn_with_its_omero_styles() {
    use brickray::io::ChannelInfo;
    let Some(vol) = brickray_harness::channels::nuclei_channels(4) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("nuclei4.ome.zarr");
    let info: Vec<ChannelInfo> = (0..4)
        .map(|c| ChannelInfo {
            label: Some(format!("c{c}")),
            color: Some(COLORS[c]),
            window: Some([8000.0 + 2000.0 * c as f32, 40000.0]),
            active: true,
        })
        .collect();
    brickray::io::zarr::write_ome_zarr_channels(&root, &vol, &info).unwrap();
    let read = brickray::io::read_channels(&root, &Default::default()).unwrap();
    assert_eq!(read.volume.len(), 4);
    for (a, b) in read.volume.channels().iter().zip(vol.channels()) {
        assert_eq!(a.data(), b.data());
    }
    let styles = read.styles();
    // The file's colours (stored as "RRGGBB": within a byte) and windows
    // (normalized by each channel's range: transparent at the start).
    for ((s, i), v) in styles.iter().zip(&info).zip(read.volume.channels()) {
        let c = s.iso_color();
        for k in 0..3 {
            assert!((c[k] - i.color.unwrap()[k]).abs() <= 1.0 / 255.0, "{c:?}");
        }
        // Opacity rises linearly over the window, normalized by the
        // channel's own range, to the default opacity.
        let [lo, hi] = i.window.unwrap().map(|w| v.desc().normalize(w) as f64);
        for x in [0.05, 0.2, 0.4, 0.7, 0.95] {
            let want = brickray::io::DEFAULT_CHANNEL_OPACITY as f64
                * ((x - lo) / (hi - lo)).clamp(0.0, 1.0);
            let got = s.tf.lookup(x)[3];
            assert!((got - want).abs() < 2e-3, "{x}: {got} against {want}");
        }
    }
    let camera = Camera::orbit(Vec3::ZERO, 2.0, 0.5, 0.6);
    let worst = check("nuclei x4 from OME-Zarr", &read.volume, &styles, camera);
    eprintln!("nuclei x4 from OME-Zarr: worst {worst:.1} dB");
}

/// A 20x18x16 u8 label map: label 1 in the lower x half, 3 in a ball, 0
/// elsewhere.
fn label_map() -> Volume {
    let d = [20u32, 18, 16];
    let mut ids = Vec::with_capacity((d[0] * d[1] * d[2]) as usize);
    for z in 0..d[2] {
        for y in 0..d[1] {
            for x in 0..d[0] {
                let p = (Vec3::new(x as f32, y as f32, z as f32) + 0.5)
                    / Vec3::new(d[0] as f32, d[1] as f32, d[2] as f32);
                ids.push(if (p - Vec3::new(0.7, 0.6, 0.5)).length() < 0.25 {
                    3u8
                } else if p.x < 0.45 {
                    1
                } else {
                    0
                });
            }
        }
    }
    brickray::core::labels::label_volume(d, [1.0; 3], VolumeData::U8(ids)).unwrap()
}

/// A label map over three channels, in colour and mask modes: DVR (shaded
/// too), iso, MIP and an axial slice against the reference's overlay.
#[test]
fn overlays_over_channels_match_the_reference() {
    let g = gpu();
    let all = channels(3);
    let vol = ChannelVolume::new(all.clone()).unwrap();
    let frame = frame_of(&all[0]);
    let labels = label_map();
    let table = brickray::LabelTable::default();
    let lframe = VolumeFrame::centered(labels.dims(), [1.0; 3]);
    let s = styles(3);
    let mut r = renderer(&vol, &s);
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let camera = Camera::orbit(Vec3::ZERO, 2.3, 0.6, 0.35);
    let plain = {
        let desc = FrameDesc {
            settings: modes()[0].1,
            ..FrameDesc::new(camera, frame, SIZE, SIZE)
        };
        draw(g, &mut r, &target, &desc).unwrap().color
    };
    for (mode, opacity) in [
        (brickray::OverlayMode::Color, 0.8),
        (brickray::OverlayMode::Mask, 1.0),
    ] {
        let overlay = brickray::LabelOverlay {
            labels: &labels,
            // The label map's box, stretched over the image's.
            image_to_labels: brickray::overlay_transform(&frame, &lframe),
            table: &table,
            style: brickray::OverlayStyle { mode, opacity },
        };
        r.set_overlay(&g.device, &g.queue, Some(&overlay)).unwrap();
        let opts = ReferenceOptions::new(SIZE, SIZE)
            .with_step_factor(STEP)
            .with_overlay(&overlay);
        for (name, settings) in modes() {
            // A mask applies to DVR; colour tints iso and MIP too.
            if mode == brickray::OverlayMode::Mask && !name.starts_with("dvr") {
                continue;
            }
            let desc = FrameDesc {
                settings,
                ..FrameDesc::new(camera, frame, SIZE, SIZE)
            };
            let got = draw(g, &mut r, &target, &desc).unwrap().color;
            let want = render_channels_reference(&vol, &frame, &s, &camera, &settings, &opts)
                .to_rgba8([0.0; 3]);
            let name = format!("overlay {mode:?} {name}");
            let c = assert_close(&name, &got, &want, SIZE, SIZE, MIN_DB)
                .unwrap_or_else(|e| panic!("{e}"));
            eprintln!("{name}: {:.1} dB", c.psnr_db);
            if name.ends_with("dvr") {
                let d = compare(&got, &plain, SIZE, SIZE).psnr_db;
                assert!(d < 40.0, "{name}: the overlay changed little ({d:.1} dB)");
            }
        }
        let view = SliceView::orthogonal(SliceAxis::Axial, 13.0, &frame, 1.0).unwrap();
        r.set_slice(Some(view));
        let desc = FrameDesc::new(camera, frame, SIZE, SIZE);
        let got = draw(g, &mut r, &target, &desc).unwrap().color;
        let want = brickray_reference::render_channel_slice(
            &vol,
            &frame,
            &view,
            &s,
            Some(&overlay),
            SIZE,
            SIZE,
        )
        .unwrap()
        .to_rgba8([0.0; 3]);
        let name = format!("overlay {mode:?} slice");
        let c =
            assert_close(&name, &got, &want, SIZE, SIZE, MIN_DB).unwrap_or_else(|e| panic!("{e}"));
        eprintln!("{name}: {:.1} dB", c.psnr_db);
        r.set_slice(None);
    }
    r.set_overlay(&g.device, &g.queue, None).unwrap();
}

/// The shared nuclei label map (u32, on the fluorescence's grid) over the
/// nuclei as three channels, colour mode, DVR: against the reference's
/// overlay (>= 45 dB).
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
fn shared_nuclei_labels_over_three_channels_match_the_reference() {
    let Some(vol) = brickray_harness::channels::nuclei_channels(3) else {
        return;
    };
    let Some(dir) = brickray_harness::shared_data_dir() else {
        return;
    };
    let name = "cells3d_nuclei_labels";
    let labels =
        brickray::io::read_volume(dir.join("labels").join(name).join(format!("{name}.json")))
            .unwrap_or_else(|e| panic!("{e}"));
    assert!(labels.desc().kind.is_labels());
    let g = gpu();
    let d = vol.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let lframe = VolumeFrame::centered(labels.dims(), labels.desc().spacing);
    let table = brickray::LabelTable::default();
    let overlay = brickray::LabelOverlay {
        labels: &labels,
        image_to_labels: brickray::overlay_transform(&frame, &lframe),
        table: &table,
        style: brickray::OverlayStyle {
            mode: brickray::OverlayMode::Color,
            opacity: 0.7,
        },
    };
    let s = brickray_harness::channels::nuclei_styles(3);
    let mut r = renderer(&vol, &s);
    r.set_overlay(&g.device, &g.queue, Some(&overlay)).unwrap();
    let camera = Camera::orbit(Vec3::ZERO, 2.0, 0.5, 0.6);
    let settings = modes()[0].1;
    let desc = FrameDesc {
        settings,
        ..FrameDesc::new(camera, frame, SIZE, SIZE)
    };
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let got = draw(g, &mut r, &target, &desc).unwrap().color;
    let opts = ReferenceOptions::new(SIZE, SIZE)
        .with_step_factor(STEP)
        .with_overlay(&overlay);
    let want =
        render_channels_reference(&vol, &frame, &s, &camera, &settings, &opts).to_rgba8([0.0; 3]);
    let c = assert_close(
        "nuclei labels over 3 channels",
        &got,
        &want,
        SIZE,
        SIZE,
        MIN_DB,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    eprintln!("nuclei labels over 3 channels: {:.1} dB", c.psnr_db);
}
