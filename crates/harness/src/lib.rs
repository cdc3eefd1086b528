//! Support for brickray's tests, examples and benchmarks. Not part of the library
//! API: the library never creates an adapter or a device; this crate does, for
//! programs that have no host application.
//!
//! * [`GpuContext::new`] picks an adapter: a real GPU when there is one, else a
//!   software one (Mesa's lavapipe). It honours `WGPU_BACKEND` (e.g. `vulkan`, `gl`)
//!   and `WGPU_ADAPTER_NAME` (a case-insensitive substring of the adapter's name).
//!   With no adapter at all it fails with [`GpuError::NoAdapter`], whose message
//!   names the package to install.
//! * [`Offscreen`] is a colour + depth target pair with read-back helpers.
//! * [`GpuTimer`] times the ray-cast pass with GPU timestamps where the device
//!   has them.
//! * [`shared_data_dir`] finds `../shared/data` and decides whether a test that
//!   needs it may skip.

pub mod channels;
mod counting;
pub use counting::CountingSource;
pub mod predict;
pub mod scenes;
pub mod soak;
pub mod stand_in;
mod timing;

pub use timing::{GpuTimer, TimedFrame, draw_frame_timed};

use std::path::PathBuf;
use thiserror::Error;

/// Errors creating a GPU context.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum GpuError {
    /// No adapter was found.
    #[error(
        "no GPU adapter found{filter}. On Debian/Ubuntu without a GPU install the software Vulkan driver: \
         `sudo apt-get install -y mesa-vulkan-drivers libvulkan1` (scripts/test.sh and scripts/demo.sh \
         install it when run as root or with password-less sudo)"
    )]
    NoAdapter {
        /// A note on the filters in effect.
        filter: String,
    },
    /// The adapter refused the device.
    #[error("the adapter {adapter} refused a device: {source}")]
    Device {
        /// Adapter name.
        adapter: String,
        /// wgpu's error.
        #[source]
        source: wgpu::RequestDeviceError,
    },
}

/// An instance, adapter, device and queue for headless work.
#[derive(Debug)]
pub struct GpuContext {
    /// The instance.
    pub instance: wgpu::Instance,
    /// The adapter.
    pub adapter: wgpu::Adapter,
    /// The device, with the optional features brickray benefits from enabled when
    /// the adapter has them.
    pub device: wgpu::Device,
    /// The queue.
    pub queue: wgpu::Queue,
}

/// Optional features brickray uses when present
/// ([`brickray_render::OPTIONAL_FEATURES`], timestamp queries among them).
pub const WANTED_FEATURES: wgpu::Features = {
    let mut features = wgpu::Features::TIMESTAMP_QUERY;
    let mut i = 0;
    while i < brickray_render::OPTIONAL_FEATURES.len() {
        features = features.union(brickray_render::OPTIONAL_FEATURES[i].feature);
        i += 1;
    }
    features
};

impl GpuContext {
    /// Picks an adapter (see the crate docs) and creates a device.
    pub fn new() -> Result<GpuContext, GpuError> {
        GpuContext::with_features(WANTED_FEATURES)
    }

    /// Like [`GpuContext::new`], enabling only `features` of [`WANTED_FEATURES`]
    /// (the others are left off even when the adapter has them: tests use this to
    /// exercise the fallbacks for missing features).
    pub fn with_features(wanted: wgpu::Features) -> Result<GpuContext, GpuError> {
        GpuContext::with_limits(wanted, |adapter| adapter)
    }

    /// Like [`GpuContext::with_features`], with the device's limits chosen by
    /// `limits` from the adapter's (tests use this to create devices below what
    /// a setting needs).
    pub fn with_limits(
        wanted: wgpu::Features,
        limits: impl FnOnce(wgpu::Limits) -> wgpu::Limits,
    ) -> Result<GpuContext, GpuError> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let backends = wgpu::Backends::from_env().unwrap_or(wgpu::Backends::all());
        let mut adapters = pollster::block_on(instance.enumerate_adapters(backends));
        let name = std::env::var("WGPU_ADAPTER_NAME")
            .ok()
            .map(|s| s.to_lowercase());
        if let Some(n) = &name {
            adapters.retain(|a| a.get_info().name.to_lowercase().contains(n.as_str()));
        }
        let rank = |a: &wgpu::Adapter| {
            let info = a.get_info();
            let ty = match info.device_type {
                wgpu::DeviceType::DiscreteGpu => 0,
                wgpu::DeviceType::IntegratedGpu => 1,
                wgpu::DeviceType::VirtualGpu => 2,
                wgpu::DeviceType::Cpu => 3,
                wgpu::DeviceType::Other => 4,
            };
            // Prefer Vulkan, then the others (GL's software path is much slower).
            let backend = if info.backend == wgpu::Backend::Vulkan {
                0
            } else {
                1
            };
            (ty, backend)
        };
        adapters.sort_by_key(rank);
        let Some(adapter) = adapters.into_iter().next() else {
            let mut filter = String::new();
            if let Ok(b) = std::env::var("WGPU_BACKEND") {
                filter += &format!(" (WGPU_BACKEND={b})");
            }
            if let Some(n) = name {
                filter += &format!(" (WGPU_ADAPTER_NAME={n})");
            }
            return Err(GpuError::NoAdapter { filter });
        };
        let features = adapter.features() & WANTED_FEATURES & wanted;
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("brickray-harness"),
            required_features: features,
            required_limits: limits(adapter.limits()),
            ..Default::default()
        }))
        .map_err(|source| GpuError::Device {
            adapter: adapter.get_info().name,
            source,
        })?;
        Ok(GpuContext {
            instance,
            adapter,
            device,
            queue,
        })
    }

    /// One line describing the adapter.
    pub fn describe(&self) -> String {
        let i = self.adapter.get_info();
        format!(
            "{} ({:?}, {:?}, driver {} {})",
            i.name, i.backend, i.device_type, i.driver, i.driver_info
        )
    }

    /// Submits and waits (tests and benchmarks only: never in a frame path).
    pub fn submit_wait(&self, encoder: wgpu::CommandEncoder) {
        self.queue.submit([encoder.finish()]);
        let _ = self.device.poll(wgpu::PollType::wait_indefinitely());
    }
}

/// One device shared by every test of a test binary (created on first use;
/// panics with the install hint when there is no adapter).
pub fn shared_gpu() -> &'static GpuContext {
    static GPU: std::sync::OnceLock<GpuContext> = std::sync::OnceLock::new();
    GPU.get_or_init(|| {
        let g = GpuContext::new().unwrap_or_else(|e| panic!("{e}"));
        eprintln!("adapter: {}", g.describe());
        g
    })
}

/// Prepares one frame and composites it into `target` in a pass that clears to
/// `clear` first (or loads, with `None`), then submits and waits: a host's frame,
/// for tests and benches.
pub fn draw_frame(
    gpu: &GpuContext,
    renderer: &mut brickray_render::VolumeRenderer,
    target: &Offscreen,
    desc: &brickray_render::FrameDesc<'_>,
    clear: Option<wgpu::Color>,
) -> Result<brickray_render::FrameStats, brickray_render::PrepareError> {
    draw_frame_timed(gpu, renderer, target, desc, clear, None).map(|f| f.stats)
}

/// Draws frames of one view until the renderer no longer wants a redraw (out of
/// core: every brick the view needs arrived), at most `max_frames`. Returns the
/// frames drawn, or `None` when it did not settle.
pub fn draw_until_settled(
    gpu: &GpuContext,
    renderer: &mut brickray_render::VolumeRenderer,
    target: &Offscreen,
    desc: &brickray_render::FrameDesc<'_>,
    max_frames: usize,
) -> Result<Option<usize>, brickray_render::PrepareError> {
    for i in 1..=max_frames {
        draw_frame(gpu, renderer, target, desc, Some(wgpu::Color::BLACK))?;
        if !renderer.wants_redraw() {
            return Ok(Some(i));
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    Ok(None)
}

/// Builds a brick store of `vol` (default options) at `path` and opens it.
pub fn store_of(
    vol: &brickray_core::Volume,
    path: &std::path::Path,
) -> std::sync::Arc<dyn brickray_core::BrickSource> {
    let mut reader = brickray_io::MemoryReader::new(vol.clone(), "memory");
    brickray_store::build(&mut reader, path, &brickray_store::BuildOptions::default())
        .expect("build the brick store");
    std::sync::Arc::new(brickray_store::open(path).expect("open the brick store"))
}

/// The GPU bytes of a streamed volume's atlases per atlas texel (the
/// texels', and the spreads' and gradients' where it keeps them).
pub fn atlas_bytes_per_texel(v: &brickray_render::StreamedVolume) -> u64 {
    let texels = v.inspect(|s| {
        s.pool()
            .atlas_dims()
            .iter()
            .map(|&d| d as u64)
            .product::<u64>()
    });
    v.resident_bytes() / texels.max(1)
}

/// Of the sub-cells of `source`'s finest bricks, the share MIP's skipping is
/// certain to skip within each brick (`brickray_core::mip_skip_counts` per
/// brick, summed): what the out-of-core renderer decides MIP's skipping from
/// once its cut is the finest level (`MIP_SKIP_SHARE_MIN_BRICKS`).
pub fn finest_bricks_mip_share(source: &dyn brickray_core::BrickSource) -> Result<f64, String> {
    use brickray_core::{NodeKey, mip_skip_counts, sub_cell_ranges, sub_cells_per_axis};
    let layout = source.layout();
    let level = layout.levels.saturating_sub(1);
    let cells = sub_cells_per_axis(layout.brick);
    let grid = layout.level_dims(level).map(|d| d.div_ceil(layout.brick));
    let mut counts = [0u64; 2];
    let mut bytes = vec![0u8; layout.brick_bytes()];
    for z in 0..grid[2] {
        for y in 0..grid[1] {
            for x in 0..grid[0] {
                let key = NodeKey::new(level, x, y, z);
                source
                    .read_brick(key, &mut bytes)
                    .map_err(|e| e.to_string())?;
                let c = mip_skip_counts([cells; 3], &sub_cell_ranges(layout, &bytes, cells));
                counts = [counts[0] + c[0], counts[1] + c[1]];
            }
        }
    }
    Ok(counts[0] as f64 / counts[1].max(1) as f64)
}

/// A colour (`Rgba8Unorm`) and depth (`Depth32Float`) target pair, as a host
/// application would have, with read-back. With `samples > 1` the attachments
/// are multisampled and the colour resolves into [`Offscreen::color`].
#[derive(Debug)]
pub struct Offscreen {
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
    /// Colour texture (single-sampled: the resolve target of an MSAA pass).
    pub color: wgpu::Texture,
    /// Colour view.
    pub color_view: wgpu::TextureView,
    /// Depth texture (sampleable when single-sampled, so it can be handed to
    /// `prepare`).
    pub depth: wgpu::Texture,
    /// Depth view.
    pub depth_view: wgpu::TextureView,
    /// The multisampled colour attachment, when `samples > 1`.
    pub msaa_view: Option<wgpu::TextureView>,
    /// The depth value a clearing pass writes (1 standard, 0 reversed-Z).
    pub clear_depth: f32,
}

/// Colour format of [`Offscreen`].
pub const COLOR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;
/// Depth format of [`Offscreen`].
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// The host's clock for frame descriptions (`FrameDesc::time`): seconds since
/// the first call in this process, as a host would pass its frame time (fades
/// in milliseconds advance with it).
pub fn host_time() -> f64 {
    static START: std::sync::OnceLock<std::time::Instant> = std::sync::OnceLock::new();
    START
        .get_or_init(std::time::Instant::now)
        .elapsed()
        .as_secs_f64()
}

/// Changes the configuration of the streamed volume `r` draws
/// ([`brickray_render::StreamedVolume::edit`]); `NotOutOfCore` in core.
pub fn configure(
    gpu: &GpuContext,
    r: &brickray_render::VolumeRenderer,
    f: impl FnOnce(&mut brickray_render::OutOfCoreConfig),
) -> Result<(), brickray_render::RenderError> {
    r.streamed_volume()
        .ok_or(brickray_render::RenderError::NotOutOfCore)?
        .edit(&gpu.device, &gpu.queue, f)
}

/// The renderer's view of [`Offscreen`]'s targets (single-sampled colour and
/// depth).
pub fn target_desc() -> brickray_render::TargetDesc {
    brickray_render::TargetDesc::new(COLOR_FORMAT).with_depth(DEPTH_FORMAT)
}

impl Offscreen {
    /// Creates single-sampled targets cleared to depth 1 (standard depth).
    pub fn new(device: &wgpu::Device, width: u32, height: u32) -> Offscreen {
        Offscreen::with(
            device,
            width,
            height,
            1,
            brickray_core::DepthConvention::Standard,
        )
    }

    /// Creates targets with `samples` per pixel for a host using `depth`'s
    /// convention (cleared to its far value).
    pub fn with(
        device: &wgpu::Device,
        width: u32,
        height: u32,
        samples: u32,
        depth: brickray_core::DepthConvention,
    ) -> Offscreen {
        let make = |label, format, samples, usage| {
            device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: wgpu::Extent3d {
                    width,
                    height,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: samples,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage,
                view_formats: &[],
            })
        };
        let usage = wgpu::TextureUsages::RENDER_ATTACHMENT
            | wgpu::TextureUsages::TEXTURE_BINDING
            | wgpu::TextureUsages::COPY_SRC;
        let color = make("brickray-harness colour", COLOR_FORMAT, 1, usage);
        let depth_usage = if samples > 1 {
            wgpu::TextureUsages::RENDER_ATTACHMENT
        } else {
            usage
        };
        let depth_tex = make("brickray-harness depth", DEPTH_FORMAT, samples, depth_usage);
        let msaa_view = (samples > 1).then(|| {
            make(
                "brickray-harness msaa colour",
                COLOR_FORMAT,
                samples,
                wgpu::TextureUsages::RENDER_ATTACHMENT,
            )
            .create_view(&Default::default())
        });
        let color_view = color.create_view(&Default::default());
        let depth_view = depth_tex.create_view(&Default::default());
        Offscreen {
            width,
            height,
            color,
            color_view,
            depth: depth_tex,
            depth_view,
            msaa_view,
            clear_depth: depth.far_value(),
        }
    }

    /// Begins a render pass on both targets; `clear` clears colour to black and
    /// depth to its far value, else both are loaded.
    pub fn pass<'e>(
        &self,
        encoder: &'e mut wgpu::CommandEncoder,
        clear: bool,
    ) -> wgpu::RenderPass<'e> {
        self.pass_clear(encoder, clear.then_some(wgpu::Color::BLACK))
    }

    /// Begins a render pass; `clear` clears colour to it and depth to its far
    /// value, `None` loads both. An MSAA pass resolves into [`Offscreen::color`].
    pub fn pass_clear<'e>(
        &self,
        encoder: &'e mut wgpu::CommandEncoder,
        clear: Option<wgpu::Color>,
    ) -> wgpu::RenderPass<'e> {
        let (view, resolve_target) = match &self.msaa_view {
            Some(m) => (m, Some(&self.color_view)),
            None => (&self.color_view, None),
        };
        encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("brickray-harness pass"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view,
                depth_slice: None,
                resolve_target,
                ops: wgpu::Operations {
                    load: match clear {
                        Some(c) => wgpu::LoadOp::Clear(c),
                        None => wgpu::LoadOp::Load,
                    },
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &self.depth_view,
                depth_ops: Some(wgpu::Operations {
                    load: match clear {
                        Some(_) => wgpu::LoadOp::Clear(self.clear_depth),
                        None => wgpu::LoadOp::Load,
                    },
                    store: wgpu::StoreOp::Store,
                }),
                stencil_ops: None,
            }),
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        })
    }

    /// Reads the colour target back as tightly packed RGBA8.
    pub fn read_color(&self, gpu: &GpuContext) -> Vec<u8> {
        read_texture(gpu, &self.color, 4, wgpu::TextureAspect::All)
    }

    /// Reads the depth target back.
    pub fn read_depth(&self, gpu: &GpuContext) -> Vec<f32> {
        let bytes = read_texture(gpu, &self.depth, 4, wgpu::TextureAspect::DepthOnly);
        bytes
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect()
    }
}

/// Copies a 2D texture to a buffer and maps it (blocking: tests and benches only).
pub fn read_texture(
    gpu: &GpuContext,
    tex: &wgpu::Texture,
    bpp: u32,
    aspect: wgpu::TextureAspect,
) -> Vec<u8> {
    let (w, h) = (tex.width(), tex.height());
    let row = (w * bpp).div_ceil(256) * 256;
    let buf = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("brickray-harness readback"),
        size: row as u64 * h as u64,
        usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: false,
    });
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    enc.copy_texture_to_buffer(
        wgpu::TexelCopyTextureInfo {
            texture: tex,
            mip_level: 0,
            origin: wgpu::Origin3d::ZERO,
            aspect,
        },
        wgpu::TexelCopyBufferInfo {
            buffer: &buf,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(row),
                rows_per_image: Some(h),
            },
        },
        wgpu::Extent3d {
            width: w,
            height: h,
            depth_or_array_layers: 1,
        },
    );
    gpu.submit_wait(enc);
    let slice = buf.slice(..);
    slice.map_async(wgpu::MapMode::Read, |_| {});
    let _ = gpu.device.poll(wgpu::PollType::wait_indefinitely());
    let data = slice.get_mapped_range().expect("buffer mapped after wait");
    let mut out = Vec::with_capacity((w * h * bpp) as usize);
    for y in 0..h as usize {
        out.extend_from_slice(&data[y * row as usize..y * row as usize + (w * bpp) as usize]);
    }
    drop(data);
    buf.unmap();
    out
}

/// Where the shared real volumes live (`<workspace>/../shared/data`), or `None`
/// when absent. Panics when absent and `CI=true`: CI always has them, so a test
/// must never silently skip there.
pub fn shared_data_dir() -> Option<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data");
    if dir.is_dir() {
        return Some(dir);
    }
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!(
            "CI=true but the shared data directory {} is missing",
            dir.display()
        );
    }
    eprintln!(
        "skipping: shared data not found at {} (a user's clone has no ../shared)",
        dir.display()
    );
    None
}

/// The sidecar path of a shared dataset, e.g. `shared_volume("invesalius_cranium_ct")`.
pub fn shared_volume(name: &str) -> Option<PathBuf> {
    shared_data_dir().map(|d| d.join(name).join(format!("{name}.json")))
}

/// Where tests write their images: `<workspace>/target/test-images`.
pub fn test_output_dir() -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../target/test-images");
    let _ = std::fs::create_dir_all(&dir);
    dir
}

/// Draws opaque screen rectangles at a constant depth: a stand-in for a host
/// application's geometry in tests and demos (`crates/harness/shaders/host_quad.wgsl`).
#[derive(Debug)]
pub struct HostQuad {
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
}

impl HostQuad {
    /// Creates the pipeline for [`Offscreen`]'s single-sampled formats and
    /// standard depth.
    pub fn new(device: &wgpu::Device) -> HostQuad {
        HostQuad::with(device, 1, brickray_core::DepthConvention::Standard)
    }

    /// Creates the pipeline for [`Offscreen`]'s formats with `samples` per pixel,
    /// depth-tested in `depth`'s convention (`Less` or `Greater`).
    pub fn with(
        device: &wgpu::Device,
        samples: u32,
        depth: brickray_core::DepthConvention,
    ) -> HostQuad {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("brickray-harness host_quad.wgsl"),
            source: wgpu::ShaderSource::Wgsl(include_str!("../shaders/host_quad.wgsl").into()),
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("brickray-harness quad"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            }],
        });
        let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("brickray-harness quad"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("brickray-harness quad"),
            layout: Some(&pl),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_main"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState {
                topology: wgpu::PrimitiveTopology::TriangleStrip,
                ..Default::default()
            },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(true),
                depth_compare: Some(match depth {
                    brickray_core::DepthConvention::ReversedZ => wgpu::CompareFunction::Greater,
                    _ => wgpu::CompareFunction::Less,
                }),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: wgpu::MultisampleState {
                count: samples,
                ..Default::default()
            },
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs_main"),
                compilation_options: Default::default(),
                targets: &[Some(wgpu::ColorTargetState {
                    format: COLOR_FORMAT,
                    blend: None,
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            multiview_mask: None,
            cache: None,
        });
        HostQuad { pipeline, layout }
    }

    /// Draws a rectangle `rect = [x0, y0, x1, y1]` (NDC) at clip `depth` with an
    /// opaque `color` into `pass`.
    pub fn draw(
        &self,
        device: &wgpu::Device,
        pass: &mut wgpu::RenderPass<'_>,
        rect: [f32; 4],
        depth: f32,
        color: [f32; 4],
    ) {
        let mut data = [0f32; 12];
        data[..4].copy_from_slice(&rect);
        data[4..8].copy_from_slice(&color);
        data[8] = depth;
        let bytes: Vec<u8> = data.iter().flat_map(|f| f.to_le_bytes()).collect();
        let buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("brickray-harness quad"),
            size: bytes.len() as u64,
            usage: wgpu::BufferUsages::UNIFORM,
            mapped_at_creation: true,
        });
        buffer
            .slice(..)
            .get_mapped_range_mut()
            .expect("mapped at creation")
            .copy_from_slice(&bytes);
        buffer.unmap();
        let bg = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("brickray-harness quad"),
            layout: &self.layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: buffer.as_entire_binding(),
            }],
        });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &bg, &[]);
        pass.draw(0..4, 0..1);
    }
}

/// Transfer-function presets for the head CT (`invesalius_cranium_ct`, Hounsfield
/// units over the value range -1024..2986), shared by tests, benches and demos.
pub mod ct {
    use brickray_core::TransferFunction;

    /// Hounsfield units to the head CT's normalized value.
    pub fn hu(v: f32) -> f32 {
        (v + 1024.0) / 4010.0
    }

    /// Issue 35's bone ramp: opacity 0 at 100 HU, 0.02 at 150, 0.5 at 300
    /// (coarse levels that average bone with soft tissue fall down it).
    pub fn bone_ramp() -> TransferFunction {
        TransferFunction::from_points(
            &[
                (hu(100.0), [0.8, 0.5, 0.4, 0.0]),
                (hu(150.0), [0.9, 0.8, 0.7, 0.02]),
                (hu(300.0), [1.0, 0.95, 0.85, 0.5]),
            ],
            512,
        )
    }

    /// Opaque bone: transparent below 250 HU, opaque from 600 HU.
    pub fn bone() -> TransferFunction {
        TransferFunction::from_points(
            &[
                (hu(250.0), [0.9, 0.85, 0.75, 0.0]),
                (hu(600.0), [1.0, 0.95, 0.85, 1.0]),
            ],
            512,
        )
    }

    /// The head CT's standard scenes: translucent and opaque DVR, the bone
    /// isosurface (400 HU) and MIP, as `(name, mode, TF)`.
    pub fn scenes() -> [(&'static str, brickray_core::RenderMode, TransferFunction); 4] {
        use brickray_core::RenderMode;
        [
            ("dvr_translucent", RenderMode::Dvr, soft_tissue()),
            ("dvr_opaque", RenderMode::Dvr, bone()),
            (
                "iso",
                RenderMode::Iso {
                    value: hu(400.0),
                    color: [0.9, 0.85, 0.75],
                },
                bone(),
            ),
            (
                "mip",
                RenderMode::Mip,
                TransferFunction::ramp(hu(-200.0), hu(1500.0), 1.0),
            ),
        ]
    }

    /// An i16 volume with every third slice kept (the slices 3 times
    /// thicker): the shared head CT becomes 256 x 256 x 36 at 0.957 x 0.957
    /// x 4.5 mm, a thick-slice CT. `None` for another sample type.
    pub fn every_third_slice(full: &brickray_core::Volume) -> Option<brickray_core::Volume> {
        use brickray_core::{Volume, VolumeData, VolumeDesc};
        let d = full.desc().clone();
        let VolumeData::I16(all) = full.data() else {
            return None;
        };
        let slice = d.dims[0] as usize * d.dims[1] as usize;
        let nz = d.dims[2].div_ceil(3);
        let thick: Vec<i16> = (0..nz as usize)
            .flat_map(|z| all[3 * z * slice..(3 * z + 1) * slice].iter().copied())
            .collect();
        let desc = VolumeDesc {
            dims: [d.dims[0], d.dims[1], nz],
            spacing: [d.spacing[0], d.spacing[1], d.spacing[2] * 3.0],
            ..d
        };
        Volume::new(desc, VolumeData::I16(thick)).ok()
    }

    /// Semi-transparent soft tissue with faint bone.
    pub fn soft_tissue() -> TransferFunction {
        TransferFunction::from_points(
            &[
                (hu(-500.0), [0.6, 0.3, 0.2, 0.0]),
                (hu(-100.0), [0.8, 0.5, 0.4, 0.02]),
                (hu(150.0), [0.9, 0.6, 0.5, 0.03]),
                (hu(300.0), [1.0, 1.0, 0.9, 0.0]),
                (hu(500.0), [1.0, 1.0, 0.95, 0.3]),
            ],
            512,
        )
    }
}

#[cfg(test)]
mod tests {
    /// The no-adapter message names commands and scripts that exist.
    #[test]
    fn no_adapter_message_names_existing_scripts() {
        let msg = super::GpuError::NoAdapter {
            filter: String::new(),
        }
        .to_string();
        assert!(
            msg.contains("apt-get install -y mesa-vulkan-drivers"),
            "{msg}"
        );
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let scripts: Vec<&str> = msg
            .split(|c: char| c.is_whitespace() || c == '`' || c == '(' || c == ')')
            .filter(|w| w.contains("scripts/"))
            .collect();
        assert!(!scripts.is_empty(), "{msg}");
        for s in scripts {
            let path = root.join(s.trim_start_matches("./"));
            assert!(path.is_file(), "{msg} names {s}, which does not exist");
        }
    }
}
