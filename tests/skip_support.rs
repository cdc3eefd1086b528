//! What the empty-space skipping tests of both backends share: their frame,
//! and the check of a skip rule's decision from the samples and images of
//! four frames.

use brickray::{Camera, FrameDesc, RenderMode, RenderSettings, Volume, VolumeFrame};

/// The default sample step, in voxels, the skipping tests draw at.
pub(crate) const STEP: f32 = 0.5;

/// The skipping tests' frame: `vol` centred, the orbit camera of the pareto
/// suite, ERT at 0.99, skipping as `ess` says, at a step of `step` voxels.
pub(crate) fn skip_frame(
    vol: &Volume,
    mode: RenderMode,
    ess: bool,
    size: u32,
    step: f32,
) -> FrameDesc<'static> {
    let d = vol.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let camera = Camera::orbit(frame.center(), 2.0, 0.5, 0.3);
    FrameDesc {
        settings: RenderSettings {
            mode,
            step_factor: step,
            accel: brickray::Accel {
                early_termination: Some(0.99),
                empty_space_skipping: ess,
                adaptive_step: false,
            },
            ..Default::default()
        },
        ..FrameDesc::new(camera, frame, size, size)
    }
}

/// Checks a skip rule's decision from four frames' samples per ray and
/// images: the rule without and with skipping asked for, then
/// `SkipRule::Always` without and with. Every image equals the first;
/// `Always` takes fewer than `always_below` times its samples without
/// skipping; the rule, where it `pays`, fewer than `rule_below` times, and
/// elsewhere exactly as many.
pub(crate) fn check_rule_decision(
    label: &str,
    samples: &[f64],
    images: &[Vec<u8>],
    pays: bool,
    always_below: f64,
    rule_below: f64,
) {
    for img in &images[1..] {
        assert_eq!(
            brickray_reference::psnr(img, &images[0]),
            f64::INFINITY,
            "{label}: identical"
        );
    }
    assert!(
        samples[3] < always_below * samples[2],
        "{label}: always skips"
    );
    if pays {
        assert!(
            samples[1] < rule_below * samples[0],
            "{label}: the rule skips"
        );
    } else {
        assert_eq!(samples[1], samples[0], "{label}: the rule does not skip");
    }
}
