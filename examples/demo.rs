//! The demo: streams a volume far larger than its GPU brick pool out of core,
//! renders a short orbit to PNG files and prints a stats line per frame.
//!
//! ```text
//! cargo run -p brickray --example demo -- [--volume vol.json|vol.nrrd] [--in-core]
//!     [--frames N] [--size PX] [--pool-mib M] [--out DIR]
//! ```
//! With no `--volume` it renders a procedural 4096^3 fractal-noise volume (64 GiB
//! of u8 voxels, never stored anywhere) through a 64 MiB pool, so it needs no data.
//! With `--volume` it builds a brick store of the file next to the output and
//! streams that (or, with `--in-core`, uploads the file whole).

use brickray::{
    Camera, FrameDesc, OutOfCoreConfig, RenderMode, RenderSettings, Shading, TransferFunction,
    VolumeFrame, VolumeRenderer,
};
use brickray_harness::{GpuContext, Offscreen};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

const USAGE: &str = "Usage: demo [--volume FILE.json|FILE.nrrd] [--in-core] [--frames N] [--size PX] [--pool-mib M] [--out DIR]
  --volume FILE  a volume to build into a brick store and stream (default: procedural 4096^3)
  --in-core      upload --volume whole instead
  --frames N     frames of the orbit (default 12)
  --size PX      image side (default 256)
  --pool-mib M   GPU brick pool in MiB (default 64)
  --out DIR      where the PNGs go (default out/demo)";

struct Args {
    volume: Option<PathBuf>,
    in_core: bool,
    frames: u32,
    size: u32,
    pool_mib: u64,
    out: PathBuf,
}

fn parse() -> Result<Args, Box<dyn std::error::Error>> {
    let mut a = Args {
        volume: None,
        in_core: false,
        frames: 12,
        size: 256,
        pool_mib: 64,
        out: "out/demo".into(),
    };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        let mut val = || it.next().ok_or_else(|| format!("{arg} needs a value"));
        match arg.as_str() {
            "--volume" => a.volume = Some(val()?.into()),
            "--in-core" => a.in_core = true,
            "--frames" => a.frames = val()?.parse()?,
            "--size" => a.size = val()?.parse()?,
            "--pool-mib" => a.pool_mib = val()?.parse()?,
            "--out" => a.out = val()?.into(),
            "-h" | "--help" => {
                println!("{USAGE}");
                std::process::exit(0);
            }
            _ => return Err(format!("unknown argument {arg}").into()),
        }
    }
    Ok(a)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = parse()?;
    std::fs::create_dir_all(&args.out)?;
    let gpu = GpuContext::new()?;
    println!("adapter: {}", gpu.describe());
    let mut renderer = VolumeRenderer::new(&gpu.device, brickray_harness::target_desc())?;
    let config = OutOfCoreConfig {
        gpu_budget_bytes: args.pool_mib << 20,
        ..Default::default()
    };
    let (frame, tf, mode) = match &args.volume {
        None => {
            let dims = [4096u64; 3];
            let source = Arc::new(brickray::store::ProceduralSource::fractal_noise(
                dims, 32, 2,
            )?);
            let l = brickray::BrickSource::layout(&*source).clone();
            println!(
                "volume: procedural fractal noise {dims:?} u8 ({:.0} GiB virtual), {} levels of {}^3 bricks; GPU pool {} MiB",
                (dims[0] * dims[1] * dims[2]) as f64 / (1u64 << 30) as f64,
                l.levels,
                l.brick,
                args.pool_mib
            );
            let frame = VolumeFrame::centered([4096; 3], [1.0; 3]);
            renderer.set_volume_source(&gpu.device, &gpu.queue, source, config)?;
            let tf = TransferFunction::from_points(
                &[
                    (0.45, [0.1, 0.3, 0.8, 0.0]),
                    (0.6, [0.3, 0.7, 1.0, 0.05]),
                    (0.75, [1.0, 0.9, 0.6, 0.6]),
                ],
                256,
            );
            (frame, tf, RenderMode::Dvr)
        }
        Some(path) => {
            let mut reader = brickray::io::open(path)?;
            let d = reader.desc().clone();
            println!(
                "volume: {} {:?} {} spacing {:?} range {:?}",
                path.display(),
                d.dims,
                d.dtype.name(),
                d.spacing,
                d.value_range
            );
            let frame = VolumeFrame::centered(d.dims, d.spacing);
            if args.in_core {
                renderer.set_volume(&gpu.device, &gpu.queue, &reader.read_volume()?)?;
            } else {
                let store = args
                    .out
                    .join(format!("volume.{}", brickray::store::EXTENSION));
                let t = Instant::now();
                let report = brickray::store::build(&mut *reader, &store, &Default::default())?;
                println!(
                    "built {} in {:.1} s: {report:?}",
                    store.display(),
                    t.elapsed().as_secs_f64()
                );
                renderer.set_volume_source(
                    &gpu.device,
                    &gpu.queue,
                    Arc::new(brickray::store::open(&store)?),
                    config,
                )?;
            }
            let tf = TransferFunction::from_points(
                &[
                    (0.2, [0.8, 0.5, 0.4, 0.0]),
                    (0.35, [0.9, 0.7, 0.6, 0.03]),
                    (0.6, [1.0, 1.0, 0.9, 0.5]),
                ],
                256,
            );
            (frame, tf, RenderMode::Dvr)
        }
    };
    renderer.set_transfer_function(&gpu.device, &gpu.queue, &tf)?;
    let target = Offscreen::new(&gpu.device, args.size, args.size);
    let settings = RenderSettings {
        mode,
        shading: Shading {
            enabled: true,
            ..Default::default()
        },
        ..Default::default()
    };
    for i in 0..args.frames {
        let yaw = 0.6 + i as f32 * std::f32::consts::TAU / args.frames.max(1) as f32 * 0.25;
        let camera = Camera::orbit(frame.center(), 1.9, yaw, 0.35);
        let t = Instant::now();
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        let desc = FrameDesc {
            camera,
            frame,
            viewport: brickray::Viewport::full(args.size, args.size),
            settings,
            host_depth: None,
            time: None,
        };
        renderer.prepare(&gpu.device, &gpu.queue, &mut enc, &desc)?;
        {
            let mut pass = target.pass(&mut enc, true);
            renderer.render(&mut pass)?;
        }
        gpu.submit_wait(enc);
        let ms = t.elapsed().as_secs_f64() * 1e3;
        let path = args.out.join(format!("frame_{i:02}.png"));
        image::save_buffer(
            &path,
            &target.read_color(&gpu),
            args.size,
            args.size,
            image::ExtendedColorType::Rgba8,
        )?;
        match renderer.stats().out_of_core {
            Some(s) => println!(
                "frame {i:2}: {ms:7.1} ms | working set {:4} bricks, pool {:4}/{:4} slots | uploaded {:6.2} MiB | in flight {:4} | cpu hit {:.2} | refine {:.1} ms, index {} words{}",
                s.cache.working_set_bricks,
                s.cache.pool_occupied,
                s.cache.pool_slots,
                s.cache.upload_bytes as f64 / (1 << 20) as f64,
                s.cache.requests_in_flight,
                s.cache.cpu_hit_rate,
                s.refine_ms,
                s.index_words,
                if s.converged { " | converged" } else { "" }
            ),
            None => println!(
                "frame {i:2}: {ms:7.1} ms (in core, {} MiB on the GPU)",
                renderer.volume_bytes() >> 20
            ),
        }
    }
    println!(
        "wrote {} PNG files to {}",
        args.frames,
        std::fs::canonicalize(&args.out)?.display()
    );
    Ok(())
}
