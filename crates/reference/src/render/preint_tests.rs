//! The pre-integrated and exact-integral modes of the reference.

use brickray_core::synthetic;

use super::*;
use crate::psnr;

/// A narrow opacity spike (0.47..0.53, peak 0.8 at 0.5) in an otherwise clear TF.
pub(crate) fn spike_tf() -> TransferFunction {
    TransferFunction::from_points(
        &[
            (0.47, [1.0, 0.6, 0.2, 0.0]),
            (0.5, [1.0, 0.9, 0.5, 0.8]),
            (0.53, [0.3, 0.6, 1.0, 0.0]),
        ],
        1024,
    )
}

fn scene(n: u32) -> (Volume, VolumeFrame, Camera) {
    let vol = synthetic::sphere(n);
    let d = vol.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let camera = Camera::orbit(frame.center(), 2.0, 0.5, 0.3);
    (vol, frame, camera)
}

/// Through a constant field every segment is the corrected single sample, so
/// pre-integrated and plain images agree to f64 rounding.
#[test]
fn constant_field_gives_the_plain_image() {
    let vol = Volume::new(
        brickray_core::VolumeDesc {
            dims: [8; 3],
            dtype: brickray_core::DType::F32,
            spacing: [1.0; 3],
            value_range: [0.0, 1.0],
        },
        brickray_core::VolumeData::F32(vec![0.5; 512]),
    )
    .unwrap();
    let tf = spike_tf();
    let frame = VolumeFrame::centered([8; 3], [1.0; 3]);
    let camera = Camera::orbit(frame.center(), 2.0, 0.5, 0.3);
    let s = RenderSettings::default();
    let opts = ReferenceOptions::new(24, 24).with_step_factor(0.7);
    let plain = render_reference(&vol, &frame, &tf, &camera, &s, &opts);
    let pre = render_reference(
        &vol,
        &frame,
        &tf,
        &camera,
        &s,
        &opts.with_preintegration(true),
    );
    let mut worst = 0.0f64;
    for (a, b) in plain.color.iter().zip(&pre.color) {
        for k in 0..4 {
            worst = worst.max((a[k] - b[k]).abs() as f64);
        }
    }
    assert!(
        plain.color.iter().any(|c| c[3] > 0.5),
        "the slab is visible"
    );
    assert!(worst < 1e-6, "{worst}");
}

/// At a step of 2 voxels through a narrow spike, plain sampling misses most of
/// it (wood-grain rings) and pre-integration does not: PSNR against the exact
/// integral, shaded and unshaded, gains >= 3 dB, and the plain image is itself
/// measurably off (< 35 dB), so the comparison can fail.
#[test]
fn preintegration_is_closer_to_the_exact_integral() {
    let (vol, frame, camera) = scene(48);
    let tf = spike_tf();
    for shaded in [false, true] {
        let mut s = RenderSettings::default();
        s.shading.enabled = shaded;
        let opts = ReferenceOptions::new(64, 64);
        let img = |o: &ReferenceOptions| {
            render_reference(&vol, &frame, &tf, &camera, &s, o).to_rgba8([0.0; 3])
        };
        let exact = img(&opts.exact_integral());
        let plain = img(&opts.with_step_factor(2.0));
        let pre = img(&opts.with_step_factor(2.0).with_preintegration(true));
        let (p_plain, p_pre) = (psnr(&plain, &exact), psnr(&pre, &exact));
        println!(
            "reference, shaded {shaded}, step 2: plain {p_plain:.2} dB, pre-integrated {p_pre:.2} dB vs exact"
        );
        assert!(
            p_plain < 35.0,
            "the plain image is not measurably off: {p_plain}"
        );
        assert!(
            p_pre >= p_plain + 3.0,
            "plain {p_plain}, pre-integrated {p_pre}"
        );
    }
}
