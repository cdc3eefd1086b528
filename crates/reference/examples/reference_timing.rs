//! Times one reference render: a 256 x 256 DVR image of a 256 x 256 x 108 u16
//! volume (CT-like spacing) at step 1/8.
//!
//! `cargo run -p brickray-reference --example reference_timing [--release] [-- out.png]`

use std::time::Instant;

use brickray_core::{
    Camera, RenderMode, RenderSettings, TransferFunction, Volume, VolumeData, VolumeFrame,
};
use brickray_reference::{ReferenceOptions, render_reference};

fn main() {
    let dims = [256u32, 256, 108];
    let spacing = [0.957f32, 0.957, 1.5];
    let t = Instant::now();
    let mut data = Vec::with_capacity((dims[0] * dims[1] * dims[2]) as usize);
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let p = [
                    x as f32 / 256.0 - 0.5,
                    y as f32 / 256.0 - 0.5,
                    z as f32 / 108.0 - 0.5,
                ];
                let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                let shell = (-((r - 0.35) * 30.0).powi(2)).exp();
                let waves = 0.5
                    + 0.5
                        * (x as f32 * 0.11).sin()
                        * (y as f32 * 0.07).sin()
                        * (z as f32 * 0.19).sin();
                let v = (0.6 * shell + 0.4 * waves * (r < 0.3) as u8 as f32).clamp(0.0, 1.0);
                data.push((v * 4095.0) as u16);
            }
        }
    }
    let vol = Volume::with_data_range(dims, spacing, VolumeData::U16(data)).expect("valid volume");
    eprintln!("volume built in {:.2?}", t.elapsed());
    let frame = VolumeFrame::centered(dims, spacing);
    let tf = TransferFunction::from_points(
        &[
            (0.2, [0.9, 0.5, 0.3, 0.0]),
            (0.45, [0.9, 0.8, 0.6, 0.05]),
            (1.0, [1.0, 1.0, 1.0, 0.6]),
        ],
        256,
    );
    let camera = Camera::orbit(frame.center(), 2.2, 0.6, 0.4);
    let opts = ReferenceOptions::new(256, 256);
    for shaded in [false, true] {
        let mut settings = RenderSettings {
            mode: RenderMode::Dvr,
            ..Default::default()
        };
        settings.shading.enabled = shaded;
        let t = Instant::now();
        let img = render_reference(&vol, &frame, &tf, &camera, &settings, &opts);
        let secs = t.elapsed().as_secs_f64();
        let covered = img.color.iter().filter(|c| c[3] > 0.0).count();
        println!(
            "DVR{} 256x256 of 256x256x108 at step 1/8: {secs:.2} s on {} threads ({covered} pixels covered)",
            if shaded { " shaded" } else { "" },
            rayon::current_num_threads()
        );
        if let Some(path) = std::env::args().nth(1) {
            let path = if shaded {
                path.replace(".png", "-shaded.png")
            } else {
                path
            };
            img.save_png(&path, [0.0; 3]).expect("write png");
        }
    }
}
