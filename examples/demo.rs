//! The demo: renders a volume to PNG files with the in-core GPU ray caster.
//!
//! `cargo run --release --example demo -- [volume.json|volume.nrrd] [--out DIR]`
//! With no volume it renders a generated one (Marschner-Lobb), so it needs no data.

use brickray::{
    Accel, Camera, FrameDesc, RenderMode, RenderSettings, Shading, TargetDesc, TransferFunction,
    VolumeFrame, VolumeRenderer,
};
use brickray_harness::{GpuContext, Offscreen};
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let mut input = None;
    let mut out = PathBuf::from("out/demo");
    let mut size = 512u32;
    while let Some(a) = args.next() {
        match a.as_str() {
            "--out" => out = PathBuf::from(args.next().ok_or("--out needs a directory")?),
            "--size" => size = args.next().ok_or("--size needs a number")?.parse()?,
            _ => input = Some(PathBuf::from(a)),
        }
    }
    std::fs::create_dir_all(&out)?;
    let gpu = GpuContext::new()?;
    println!("adapter: {}", gpu.describe());
    let volume = match &input {
        Some(p) => brickray::io::read_volume(p)?,
        None => brickray_core::synthetic::marschner_lobb(128),
    };
    let d = volume.desc();
    println!(
        "volume: {:?} {} spacing {:?} range {:?}",
        d.dims,
        d.dtype.name(),
        d.spacing,
        d.value_range
    );
    let mut renderer = VolumeRenderer::new(
        &gpu.device,
        TargetDesc {
            color_format: brickray_harness::COLOR_FORMAT,
            depth_format: Some(brickray_harness::DEPTH_FORMAT),
        },
    )?;
    renderer.set_volume(&gpu.device, &gpu.queue, &volume)?;
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let target = Offscreen::new(&gpu.device, size, size);
    let tf = TransferFunction::from_points(
        &[
            (0.0, [0.0, 0.0, 0.0, 0.0]),
            (0.35, [0.9, 0.5, 0.3, 0.0]),
            (0.6, [1.0, 0.8, 0.6, 0.05]),
            (1.0, [1.0, 1.0, 1.0, 0.6]),
        ],
        256,
    );
    renderer.set_transfer_function(&gpu.device, &gpu.queue, &tf);
    let shading = Shading {
        enabled: true,
        ..Default::default()
    };
    let modes = [
        ("dvr", RenderMode::Dvr),
        (
            "iso",
            RenderMode::Iso {
                value: 0.5,
                color: [0.9, 0.85, 0.75],
            },
        ),
        ("mip", RenderMode::Mip),
    ];
    for (name, mode) in modes {
        let camera = Camera::orbit(frame.center(), 2.2, 0.6, 0.35);
        let settings = RenderSettings {
            mode,
            shading,
            accel: Accel::default(),
            ..Default::default()
        };
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        let t0 = std::time::Instant::now();
        let desc = FrameDesc {
            camera,
            frame,
            width: size,
            height: size,
            settings,
            host_depth: None,
        };
        renderer.prepare(&gpu.device, &gpu.queue, &mut enc, &desc)?;
        {
            let mut pass = target.pass(&mut enc, true);
            renderer.render(&mut pass)?;
        }
        gpu.submit_wait(enc);
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        let rgba = target.read_color(&gpu);
        let path = out.join(format!("{name}.png"));
        image::save_buffer(&path, &rgba, size, size, image::ExtendedColorType::Rgba8)?;
        println!("{name}: {ms:.1} ms -> {}", path.display());
    }
    println!("wrote PNGs to {}", out.display());
    Ok(())
}
