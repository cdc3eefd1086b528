//! The checks both multi-channel GPU test files run (in core and
//! streamed): every render mode against
//! `brickray_reference::render_channels_reference`, and an axial and an
//! oblique slice and an axial slab (maximum and mean) of three channels,
//! with channel 0 shown then hidden, against
//! `brickray_reference::render_channel_slice`.

use brickray::core::channels::{ChannelStyle, ChannelVolume};
use brickray::{Camera, FrameDesc, SliceAxis, SliceView, VolumeFrame, VolumeRenderer};
use brickray_reference::{ReferenceOptions, assert_close, render_channels_reference};
use glam::Vec3;

/// The draw the channel checks' callers hand them: the renderer under
/// test's frame (RGBA8).
pub(crate) type Draw<'a> = dyn FnMut(&mut VolumeRenderer, &FrameDesc<'_>) -> Vec<u8> + 'a;

/// Draws every case with `draw` (the renderer's settled frame) and checks
/// it against the reference at `min_db`; `min_lit`: the least pixels the
/// reference must light (a slice that missed the blobs proves nothing).
#[allow(clippy::too_many_arguments)]
pub(crate) fn check_channel_slices(
    label: &str,
    r: &mut VolumeRenderer,
    vol: &ChannelVolume,
    styles: &[ChannelStyle],
    size: u32,
    min_db: f64,
    min_lit: usize,
    mut draw: impl FnMut(&mut VolumeRenderer, &FrameDesc<'_>) -> Vec<u8>,
) {
    let d = vol.channels()[0].desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let plane = SliceView::orthogonal(SliceAxis::Axial, 13.0, &frame, 1.0).unwrap();
    let cases = [
        ("axial", plane),
        (
            "oblique",
            SliceView::with_normal([20.0, 18.0, 15.0], [1.0, -1.0, 2.0], 0.8).unwrap(),
        ),
        ("slab max", plane.with_slab(6.0, brickray::SlabMode::Max)),
        ("slab mean", plane.with_slab(6.0, brickray::SlabMode::Mean)),
    ];
    let mut s = styles.to_vec();
    for hidden in [false, true] {
        if hidden {
            s[0] = s[0].clone().visible(false);
            r.set_channel_styles(&s).unwrap();
        }
        for (name, view) in cases {
            r.set_slice(Some(view));
            let camera = Camera::orbit(Vec3::ZERO, 2.3, 0.6, 0.35);
            let desc = FrameDesc::new(camera, frame, size, size);
            let got = draw(r, &desc);
            let want =
                brickray_reference::render_channel_slice(vol, &frame, &view, &s, None, size, size)
                    .unwrap()
                    .to_rgba8([0.0; 3]);
            let lit = want
                .chunks_exact(4)
                .filter(|p| p[0].max(p[1]).max(p[2]) > 40)
                .count();
            assert!(lit > min_lit, "{name}: the reference slice is nearly black");
            let name = format!("{label} {name}, channel 0 hidden {hidden}");
            let c = assert_close(&name, &got, &want, size, size, min_db)
                .unwrap_or_else(|e| panic!("{e}"));
            eprintln!("{name}: {:.1} dB", c.psnr_db);
        }
    }
    r.set_slice(None);
}

/// Draws `vol` through `styles` from `camera` in every mode of
/// `brickray_harness::channels::modes` (step `step`, isovalue 0.45) with
/// `draw` and checks each against the reference at `min_db`; `min_lit`: the
/// least pixels the reference must cover. Returns the smallest PSNR.
#[allow(clippy::too_many_arguments)]
pub(crate) fn check_channel_modes(
    label: &str,
    r: &mut VolumeRenderer,
    vol: &ChannelVolume,
    styles: &[ChannelStyle],
    camera: Camera,
    size: u32,
    step: f32,
    min_db: f64,
    min_lit: usize,
    mut draw: impl FnMut(&mut VolumeRenderer, &FrameDesc<'_>) -> Vec<u8>,
) -> f64 {
    let d = vol.channels()[0].desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let mut worst = f64::INFINITY;
    for (mode, settings) in brickray_harness::channels::modes(step, 0.45) {
        let desc = FrameDesc {
            settings,
            ..FrameDesc::new(camera, frame, size, size)
        };
        let got = draw(r, &desc);
        let opts = ReferenceOptions::new(size, size).with_step_factor(step);
        let want = render_channels_reference(vol, &frame, styles, &camera, &settings, &opts)
            .to_rgba8([0.0; 3]);
        assert!(
            want.chunks_exact(4).filter(|p| p[3] > 20).count() > min_lit,
            "{label} {mode}: the reference image is nearly empty"
        );
        let c = assert_close(&format!("{label} {mode}"), &got, &want, size, size, min_db)
            .unwrap_or_else(|e| panic!("{e}"));
        eprintln!("{label} {mode}: {:.1} dB", c.psnr_db);
        worst = worst.min(c.psnr_db);
    }
    worst
}

/// MIP refines each visible channel's maximum and runner-up between
/// samples, as a single channel's (docs/rendering-model.md, *Channels*):
/// `vol` through `styles` at a step of 2 voxels, drawn with `draw`, against
/// the reference at the same step, refining (its twin): >= 62 dB; and
/// against the fine reference (1/8 voxel): at least 8 dB closer than the
/// reference at step 2 without refinement (the samples' maxima alone).
pub(crate) fn check_channel_mip_at_a_coarse_step(
    label: &str,
    r: &mut VolumeRenderer,
    vol: &ChannelVolume,
    styles: &[ChannelStyle],
    camera: Camera,
    size: u32,
    draw: impl FnMut(&mut VolumeRenderer, &FrameDesc<'_>) -> Vec<u8>,
) {
    let settings = brickray::RenderSettings {
        mode: brickray::RenderMode::Mip,
        step_factor: 2.0,
        ..Default::default()
    };
    let (got, reference) = drawn_and_reference(r, vol, styles, camera, size, settings, draw);
    let at_step = ReferenceOptions::new(size, size).with_step_factor(2.0);
    let fine = reference(&ReferenceOptions::new(size, size));
    let psnr = brickray_reference::psnr;
    let twin = psnr(&got, &reference(&at_step));
    let refined = psnr(&got, &fine);
    let samples_only = psnr(&reference(&at_step.with_mip_refinement(false)), &fine);
    eprintln!(
        "{label}, MIP at step 2: vs its twin {twin:.2} dB; vs the fine reference {refined:.2} dB, the samples' maxima alone {samples_only:.2} dB"
    );
    assert!(twin >= 62.0, "{label}: {twin:.2} dB against the twin");
    assert!(
        refined >= samples_only + 8.0,
        "{label}: refined {refined:.2} dB, samples alone {samples_only:.2} dB"
    );
}

/// DVR's adaptive step in the multi-channel kernels
/// (`Accel::adaptive_step`: the step doubles as the mixture's transmittance
/// falls to 1/4 and 1/16): `vol` through `styles` at `step`, without
/// termination (the reference does not terminate), drawn with `draw`,
/// against its twin (the reference with the adaptive step) at >= `min_db`,
/// and at least 10 dB closer to it than to the reference that keeps its
/// step (a kernel that ignored the setting draws the latter). Returns the
/// two PSNRs.
#[allow(clippy::too_many_arguments)]
pub(crate) fn check_channel_adaptive_step(
    label: &str,
    r: &mut VolumeRenderer,
    vol: &ChannelVolume,
    styles: &[ChannelStyle],
    camera: Camera,
    size: u32,
    step: f32,
    min_db: f64,
    draw: impl FnMut(&mut VolumeRenderer, &FrameDesc<'_>) -> Vec<u8>,
) -> (f64, f64) {
    let settings = brickray::RenderSettings {
        step_factor: step,
        accel: brickray::Accel {
            early_termination: None,
            adaptive_step: true,
            ..Default::default()
        },
        ..Default::default()
    };
    let (got, reference) = drawn_and_reference(r, vol, styles, camera, size, settings, draw);
    let fixed = ReferenceOptions::new(size, size).with_step_factor(step);
    let twin = brickray_reference::psnr(&got, &reference(&fixed.with_adaptive_step(true)));
    let kept = brickray_reference::psnr(&got, &reference(&fixed));
    eprintln!(
        "{label}, DVR with the adaptive step at {step} voxel: vs its twin {twin:.2} dB, vs the fixed step {kept:.2} dB"
    );
    assert!(twin >= min_db, "{label}: {twin:.2} dB against the twin");
    assert!(
        twin >= kept + 10.0,
        "{label}: {twin:.2} dB against the twin, {kept:.2} against the fixed step"
    );
    (twin, kept)
}

/// `vol` through `styles` from `camera` at `size` px with `settings`, drawn
/// by the renderer under test (`draw`), and the reference's image of the
/// same under the options it is given.
#[allow(clippy::too_many_arguments)]
fn drawn_and_reference<'a>(
    r: &mut VolumeRenderer,
    vol: &'a ChannelVolume,
    styles: &'a [ChannelStyle],
    camera: Camera,
    size: u32,
    settings: brickray::RenderSettings,
    mut draw: impl FnMut(&mut VolumeRenderer, &FrameDesc<'_>) -> Vec<u8>,
) -> (Vec<u8>, impl Fn(&ReferenceOptions) -> Vec<u8> + 'a) {
    let d = vol.channels()[0].desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let desc = FrameDesc {
        settings,
        ..FrameDesc::new(camera, frame, size, size)
    };
    let got = draw(r, &desc);
    let reference = move |opts: &ReferenceOptions| {
        render_channels_reference(vol, &frame, styles, &camera, &settings, opts).to_rgba8([0.0; 3])
    };
    (got, reference)
}
