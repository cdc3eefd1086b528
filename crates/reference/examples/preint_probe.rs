//! Pre-integration against the plain sum, both against the exact integral
//! (step 1/16), in the CPU reference alone: Marschner-Lobb 64^3 with the
//! `pareto` suite's transfer function, 64 x 64, unshaded and shaded, steps 0.5
//! and 2 (docs/accuracy.md).
//!
//! `cargo run --release -p brickray-reference --example preint_probe`

use brickray_core::{Camera, RenderSettings, Shading, TransferFunction, VolumeFrame, synthetic};
use brickray_reference::{ReferenceOptions, psnr, render_reference};

fn main() {
    let vol = synthetic::marschner_lobb(64);
    let tf = TransferFunction::from_points(
        &[
            (0.45, [0.2, 0.4, 0.9, 0.0]),
            (0.5, [0.9, 0.9, 0.9, 0.6]),
            (0.55, [0.9, 0.5, 0.2, 0.0]),
        ],
        512,
    );
    let d = vol.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let camera = Camera::orbit(frame.center(), 2.0, 0.5, 0.3);
    let opts = ReferenceOptions::new(64, 64);
    for shaded in [false, true] {
        let settings = RenderSettings {
            shading: Shading {
                enabled: shaded,
                ..Default::default()
            },
            ..Default::default()
        };
        let img = |o: &ReferenceOptions<'_>| {
            render_reference(&vol, &frame, &tf, &camera, &settings, o).to_rgba8([0.0; 3])
        };
        let exact = img(&opts.exact_integral());
        for step in [0.5f32, 2.0] {
            let plain = img(&opts.with_step_factor(step));
            let pre = img(&opts.with_step_factor(step).with_preintegration(true));
            println!(
                "shaded {shaded} step {step}: plain {:.2} dB, pre-integrated {:.2} dB (against the exact integral)",
                psnr(&plain, &exact),
                psnr(&pre, &exact)
            );
        }
    }
}
