//! The demo: streams a volume far larger than its GPU brick pool out of core,
//! renders a camera path to PNG files and prints a stats line per frame.
//!
//! ```text
//! cargo run -p brickray --example demo -- [--volume vol.json|vol.nrrd] [--in-core]
//!     [--frames N] [--size PX] [--pool-mib M] [--out DIR]
//! ```
//! With no `--volume` it renders a procedural 4096^3 Mandelbulb (64 GiB of u8
//! voxels, computed on demand and never stored anywhere) through a 64 MiB pool,
//! so it needs no data, and flies from the whole volume down to a patch of its
//! surface a few dozen voxels across: the level of detail follows the camera,
//! and the last frames wait until every brick the view needs has arrived.
//! With `--volume` it builds a brick store of the file next to the output and
//! streams that (or, with `--in-core`, uploads the file whole) along an orbit.

use brickray::{
    Camera, FrameDesc, OutOfCoreConfig, RenderMode, RenderSettings, Shading, TargetDesc,
    TransferFunction, VolumeFrame, VolumeRenderer,
};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

const USAGE: &str = "Usage: demo [--volume FILE.json|FILE.nrrd] [--in-core] [--frames N] [--size PX] [--pool-mib M] [--out DIR]
  --volume FILE  a volume to build into a brick store and stream (default: a procedural 4096^3 Mandelbulb)
  --in-core      upload --volume whole instead
  --frames N     frames of the camera path (default 16)
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
        frames: 16,
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
    if a.frames == 0 || a.size == 0 {
        return Err("--frames and --size must be at least 1".into());
    }
    Ok(a)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = parse()?;
    std::fs::create_dir_all(&args.out)?;
    let gpu = Gpu::new()?;
    println!("adapter: {}", gpu.adapter);
    let targets = TargetDesc::new(COLOR).with_depth(DEPTH);
    let mut renderer = VolumeRenderer::new(&gpu.device, targets)?;
    let config = OutOfCoreConfig {
        gpu_budget_bytes: args.pool_mib << 20,
        ..Default::default()
    };
    let (frame, tf, mode) = match &args.volume {
        None => {
            let side = 4096u64;
            let source = Arc::new(brickray::store::MandelbulbSource::new(side, 32, 2)?);
            let l = brickray::BrickSource::layout(&*source).clone();
            println!(
                "volume: procedural Mandelbulb {side}^3 u8 ({:.0} GiB virtual), {} levels of {}^3 bricks; GPU pool {} MiB",
                (side * side * side) as f64 / (1u64 << 30) as f64,
                l.levels,
                l.brick,
                args.pool_mib
            );
            let frame = VolumeFrame::centered([side as u32; 3], [1.0; 3]);
            renderer.set_volume_source(&gpu.device, &gpu.queue, source, config)?;
            // Opaque within the surface band, ivory; the shading draws the folds.
            let tf = TransferFunction::from_points(
                &[
                    (0.08, [0.85, 0.7, 0.55, 0.0]),
                    (0.3, [0.95, 0.88, 0.75, 0.9]),
                    (1.0, [1.0, 0.97, 0.92, 1.0]),
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
    let target = Target::new(&gpu.device, args.size);
    let settings = RenderSettings {
        mode,
        shading: Shading {
            enabled: true,
            ..Default::default()
        },
        ..Default::default()
    };
    let path = CameraPath::new(&frame, args.volume.is_none(), args.frames);
    // Out of core, the first view is held while its bricks arrive (up to
    // HOLD_START frames), then the path runs, then its last view is held (up
    // to as many frames as the path has).
    const HOLD_START: u32 = 8;
    let last = args.frames - 1;
    let (mut view, mut held, mut i) = (0u32, 0u32, 0u32);
    loop {
        let camera = path.camera(view);
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
            let mut pass = target.pass(&mut enc);
            renderer.render(&mut pass)?;
        }
        let pixels = target.read_rgba(&gpu, enc)?;
        let ms = t.elapsed().as_secs_f64() * 1e3;
        let file = args.out.join(format!("frame_{i:02}.png"));
        image::save_buffer(
            &file,
            &pixels,
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
        i += 1;
        let arriving = renderer.wants_redraw();
        if view == 0 && view < last && arriving && held < HOLD_START {
            held += 1;
        } else if view < last {
            (view, held) = (view + 1, 0);
        } else if arriving && held < args.frames {
            held += 1;
        } else {
            break;
        }
    }
    println!(
        "wrote {i} PNG files to {}",
        std::fs::canonicalize(&args.out)?.display()
    );
    Ok(())
}

/// The demo's camera: for the Mandelbulb, a flight from the whole volume to a
/// patch of its surface about 230 voxels high (a voxel per pixel at the
/// default size), the distance shrinking by the same factor every frame; for
/// a file, a quarter orbit.
struct CameraPath {
    frames: u32,
    centre: glam::Vec3,
    /// Where the flight ends, and the unit direction it looks from.
    zoom: Option<(glam::Vec3, glam::Vec3)>,
    /// One voxel in world units.
    voxel: f32,
}

impl CameraPath {
    const START: f32 = 1.9;

    fn new(frame: &VolumeFrame, bulb: bool, frames: u32) -> CameraPath {
        let from = glam::DVec3::new(0.55, 0.45, 0.7).normalize();
        let zoom = bulb
            .then(|| brickray::store::MandelbulbSource::surface_point(from.to_array(), 1e-4))
            .flatten()
            .map(|u| {
                let p = frame
                    .model
                    .transform_point3(glam::Vec3::from_array(u.map(|c| c as f32)));
                (p, from.as_vec3())
            });
        let voxel = frame.voxel_world;
        CameraPath {
            frames: frames.max(1),
            centre: frame.center(),
            zoom,
            voxel,
        }
    }

    fn camera(&self, i: u32) -> Camera {
        let t = i as f32 / (self.frames - 1).max(1) as f32;
        match self.zoom {
            Some((surface, dir)) => {
                let end = 320.0 * self.voxel;
                let distance = Self::START * (end / Self::START).powf(t);
                // The target slides to the surface point as the distance shrinks.
                let s = (Self::START - distance) / (Self::START - end);
                let target = self.centre.lerp(surface, s.clamp(0.0, 1.0));
                Camera {
                    eye: target + dir * distance,
                    target,
                    up: glam::Vec3::Y,
                    projection: brickray::Projection::Perspective {
                        fov_y: 40f32.to_radians(),
                    },
                    near: distance * 0.05,
                    far: distance + 2.0,
                    depth: brickray::DepthConvention::Standard,
                }
            }
            None => Camera::orbit(self.centre, Self::START, 0.6 + t * 1.2, 0.35),
        }
    }
}

/// The colour and depth formats the demo renders into.
const COLOR: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
const DEPTH: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// The demo's device: any adapter (Mesa's lavapipe where there is no GPU),
/// with the limits brickray needs and the optional features it can use.
struct Gpu {
    adapter: String,
    device: wgpu::Device,
    queue: wgpu::Queue,
}

impl Gpu {
    fn new() -> Result<Gpu, Box<dyn std::error::Error>> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let adapter = pollster::block_on(instance.request_adapter(&Default::default()))?;
        let info = adapter.get_info();
        let (device, queue) =
            pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
                required_limits: brickray::required_limits().using_resolution(adapter.limits()),
                required_features: adapter.features() & brickray::optional_features(),
                ..Default::default()
            }))?;
        Ok(Gpu {
            adapter: format!("{} ({:?})", info.name, info.backend),
            device,
            queue,
        })
    }
}

/// A square offscreen colour and depth target, read back after each frame.
struct Target {
    size: u32,
    color: wgpu::Texture,
    color_view: wgpu::TextureView,
    depth_view: wgpu::TextureView,
}

impl Target {
    fn new(device: &wgpu::Device, size: u32) -> Target {
        let texture = |format, usage| {
            device.create_texture(&wgpu::TextureDescriptor {
                label: Some("demo target"),
                size: wgpu::Extent3d {
                    width: size,
                    height: size,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage: wgpu::TextureUsages::RENDER_ATTACHMENT | usage,
                view_formats: &[],
            })
        };
        let color = texture(COLOR, wgpu::TextureUsages::COPY_SRC);
        let depth = texture(DEPTH, wgpu::TextureUsages::TEXTURE_BINDING);
        Target {
            size,
            color_view: color.create_view(&Default::default()),
            depth_view: depth.create_view(&Default::default()),
            color,
        }
    }

    /// A pass that clears colour to black and depth to 1 (standard depth).
    fn pass<'e>(&self, encoder: &'e mut wgpu::CommandEncoder) -> wgpu::RenderPass<'e> {
        let store = wgpu::StoreOp::Store;
        encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("demo pass"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &self.color_view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                    store,
                },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &self.depth_view,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Clear(1.0),
                    store,
                }),
                stencil_ops: None,
            }),
            ..Default::default()
        })
    }

    /// Submits the frame's work and reads the colour back (tightly packed RGBA).
    fn read_rgba(
        &self,
        gpu: &Gpu,
        mut encoder: wgpu::CommandEncoder,
    ) -> Result<Vec<u8>, Box<dyn std::error::Error>> {
        let row = (4 * self.size).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
        let buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("demo read-back"),
            size: (row * self.size) as u64,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let dst = wgpu::TexelCopyBufferInfo {
            buffer: &buffer,
            layout: wgpu::TexelCopyBufferLayout {
                bytes_per_row: Some(row),
                ..Default::default()
            },
        };
        encoder.copy_texture_to_buffer(self.color.as_image_copy(), dst, self.color.size());
        gpu.queue.submit([encoder.finish()]);
        buffer.slice(..).map_async(wgpu::MapMode::Read, |_| {});
        gpu.device.poll(wgpu::PollType::wait_indefinitely())?;
        let data = buffer.slice(..).get_mapped_range()?;
        Ok(data
            .chunks(row as usize)
            .flat_map(|r| &r[..4 * self.size as usize])
            .copied()
            .collect())
    }
}
