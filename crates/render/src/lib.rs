//! The wgpu ray caster of brickray and its [`VolumeRenderer`] API.
//!
//! `VolumeRenderer` is middleware in the style of glyphon and egui-wgpu: it takes a
//! `&wgpu::Device`, a `&wgpu::Queue` and the host's target formats; it never
//! requests an adapter, never submits, and never waits on the GPU.
//!
//! Per frame:
//! 1. [`VolumeRenderer::prepare`] writes uniforms and records the ray-cast compute
//!    pass into the host's command encoder. Rays stop at the host's opaque depth
//!    when the host passes it.
//! 2. [`VolumeRenderer::render`] records one fullscreen draw into the host's render
//!    pass: it blends the premultiplied volume colour over the host's colour and
//!    writes depth, so geometry drawn later composites correctly too.
//!
//! The ray-casting model (spaces, sampling, opacity correction, shading, modes) is
//! specified in `docs/rendering-model.md`; the CPU reference in
//! `brickray-reference` implements the same model and is the accuracy oracle.

mod error;
mod gpu_volume;
mod ooc;
pub mod shaders;

pub use error::{PrepareError, RenderError};
pub use ooc::{OutOfCoreConfig, OutOfCoreStats};

use brickray_core::{
    BrickSource, Camera, RenderMode, RenderSettings, TransferFunction, Volume, VolumeFrame,
};
use glam::{Mat3, Mat4};
use gpu_volume::GpuVolume;
use ooc::OocVolume;
use std::sync::Arc;

/// The host's render targets that [`VolumeRenderer::render`] draws into.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct TargetDesc {
    /// Colour attachment format (must be blendable).
    pub color_format: wgpu::TextureFormat,
    /// Depth attachment format of the host's pass, or `None` for a pass without one.
    pub depth_format: Option<wgpu::TextureFormat>,
}

/// One frame's view of the volume.
#[derive(Debug, Clone)]
pub struct FrameDesc<'a> {
    /// The camera.
    pub camera: Camera,
    /// Placement of the volume in the world.
    pub frame: VolumeFrame,
    /// Viewport width in pixels (the size of the host's attachments).
    pub width: u32,
    /// Viewport height in pixels.
    pub height: u32,
    /// Mode, shading, accelerations, step.
    pub settings: RenderSettings,
    /// The host's opaque depth (a depth texture view with `TEXTURE_BINDING` usage,
    /// `width x height`, single-sampled). Rays stop there.
    pub host_depth: Option<&'a wgpu::TextureView>,
}

/// What `prepare` did.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FrameStats {
    /// Rays cast.
    pub rays: u64,
    /// Bytes written to the GPU this frame (uniforms, transfer function).
    pub uploaded_bytes: u64,
}

/// Everything the renderer knows about its last frame.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RendererStats {
    /// What the last `prepare` did.
    pub frame: FrameStats,
    /// The out-of-core path's figures (working set, pool occupancy, bytes
    /// uploaded, CPU and GPU cache hit rates, requests in flight, frame phases);
    /// `None` in core.
    pub out_of_core: Option<OutOfCoreStats>,
}

/// Upper bound of samples along one ray (a guard, not a quality setting).
const MAX_STEPS: u32 = 1 << 20;
/// Upper bound of index leaves visited by one ray out of core (a guard).
const MAX_LEAVES: u32 = 1 << 16;

#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    inv_view_proj: [[f32; 4]; 4],
    view_proj: [[f32; 4]; 4],
    inv_model: [[f32; 4]; 4],
    normal_mat: [[f32; 4]; 4],
    dims: [f32; 4],
    value_map: [f32; 4],
    iso: [f32; 4],
    shade: [f32; 4],
    misc: [f32; 4],
    size: [u32; 4],
    cells: [u32; 4],
    limits: [u32; 4],
    octree: [f32; 4],
    bricks: [u32; 4],
    atlas: [f32; 4],
}

/// A storage buffer that grows geometrically and is rewritten only on change.
#[derive(Debug)]
pub(crate) struct GrowBuffer {
    label: &'static str,
    buffer: wgpu::Buffer,
    contents: Vec<u8>,
}

impl GrowBuffer {
    pub(crate) fn new(device: &wgpu::Device, label: &'static str, size: u64) -> GrowBuffer {
        let buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: size.max(16),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        GrowBuffer {
            label,
            buffer,
            contents: Vec::new(),
        }
    }

    /// Writes `data`; returns (bytes written, whether the buffer was reallocated).
    pub(crate) fn write(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        data: &[u8],
    ) -> (u64, bool) {
        if data == self.contents.as_slice() {
            return (0, false);
        }
        let mut grown = false;
        if data.len() as u64 > self.buffer.size() {
            let size = (data.len() as u64).next_power_of_two();
            *self = GrowBuffer::new(device, self.label, size);
            grown = true;
        }
        queue.write_buffer(&self.buffer, 0, data);
        self.contents = data.to_vec();
        (data.len() as u64, grown)
    }
}

/// Per-viewport outputs of the ray-cast pass.
#[derive(Debug)]
struct FrameTargets {
    width: u32,
    height: u32,
    color: wgpu::TextureView,
    depth: wgpu::TextureView,
    samples: wgpu::Texture,
    samples_view: wgpu::TextureView,
    composite_bg: wgpu::BindGroup,
}

/// The volume renderer. See the crate docs for the frame protocol.
#[derive(Debug)]
pub struct VolumeRenderer {
    targets: TargetDesc,
    raycast: RaycastKernel,
    composite: wgpu::RenderPipeline,
    composite_bgl: wgpu::BindGroupLayout,
    sampler: wgpu::Sampler,
    uniform: wgpu::Buffer,
    last_params: Option<Params>,
    tf: GrowBuffer,
    tf_prefix: GrowBuffer,
    tf_len: u32,
    tf_cpu: Option<TransferFunction>,
    volume: Option<GpuVolume>,
    ooc: Option<OocVolume>,
    /// The out-of-core kernel, created on first use.
    ooc_kernel: Option<RaycastKernel>,
    dummy_depth: wgpu::TextureView,
    frame_targets: Option<FrameTargets>,
    /// The ray-cast bind group and the host depth view it was built with.
    raycast_bg: Option<(wgpu::BindGroup, Option<wgpu::TextureView>)>,
    prepared: bool,
    last_frame: FrameStats,
}

/// A `STORAGE | COPY_DST` buffer of `size` bytes, or a typed error when it would
/// exceed the device's storage-binding limit. `what` names it in the error and
/// in its `brickray-render` label.
pub(crate) fn storage_buffer(
    device: &wgpu::Device,
    what: &'static str,
    size: u64,
) -> Result<wgpu::Buffer, RenderError> {
    let limit = device.limits().max_storage_buffer_binding_size;
    if size > limit {
        return Err(RenderError::LowDeviceLimit {
            what,
            required: size,
            limit,
        });
    }
    Ok(device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(&format!("brickray-render {what}")),
        size: size.max(16),
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    }))
}

fn storage_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only: true },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// Bindings shared by the in-core and out-of-core ray casters (binding 5 holds the
/// macro-cell ranges in core and the brick slot table out of core).
fn raycast_layout_entries() -> Vec<wgpu::BindGroupLayoutEntry> {
    let c = wgpu::ShaderStages::COMPUTE;
    vec![
        wgpu::BindGroupLayoutEntry {
            binding: 0,
            visibility: c,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: false,
                min_binding_size: wgpu::BufferSize::new(std::mem::size_of::<Params>() as u64),
            },
            count: None,
        },
        wgpu::BindGroupLayoutEntry {
            binding: 1,
            visibility: c,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable: true },
                view_dimension: wgpu::TextureViewDimension::D3,
                multisampled: false,
            },
            count: None,
        },
        wgpu::BindGroupLayoutEntry {
            binding: 2,
            visibility: c,
            ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
            count: None,
        },
        storage_entry(3),
        storage_entry(4),
        storage_entry(5),
        wgpu::BindGroupLayoutEntry {
            binding: 6,
            visibility: c,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Depth,
                view_dimension: wgpu::TextureViewDimension::D2,
                multisampled: false,
            },
            count: None,
        },
        wgpu::BindGroupLayoutEntry {
            binding: 7,
            visibility: c,
            ty: wgpu::BindingType::StorageTexture {
                access: wgpu::StorageTextureAccess::WriteOnly,
                format: wgpu::TextureFormat::Rgba16Float,
                view_dimension: wgpu::TextureViewDimension::D2,
            },
            count: None,
        },
        wgpu::BindGroupLayoutEntry {
            binding: 8,
            visibility: c,
            ty: wgpu::BindingType::StorageTexture {
                access: wgpu::StorageTextureAccess::WriteOnly,
                format: wgpu::TextureFormat::R32Float,
                view_dimension: wgpu::TextureViewDimension::D2,
            },
            count: None,
        },
        wgpu::BindGroupLayoutEntry {
            binding: 9,
            visibility: c,
            ty: wgpu::BindingType::StorageTexture {
                access: wgpu::StorageTextureAccess::WriteOnly,
                format: wgpu::TextureFormat::R32Uint,
                view_dimension: wgpu::TextureViewDimension::D2,
            },
            count: None,
        },
    ]
}

/// The switches compiled into a ray-cast pipeline as WGSL override constants, so
/// each pipeline carries only the code of its mode (on lavapipe the specialised
/// out-of-core shader runs 1.5x faster than one that branches on the mode).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
struct Variant {
    mode: u32,
    ert: bool,
    ess: bool,
    shade: bool,
}

impl Variant {
    fn of(s: &RenderSettings) -> Variant {
        let mode = match s.mode {
            RenderMode::Dvr => 0,
            RenderMode::Iso { .. } => 1,
            RenderMode::Mip => 2,
            _ => 0,
        };
        Variant {
            mode,
            ert: s.accel.early_termination.is_some(),
            ess: s.accel.empty_space_skipping,
            shade: s.shading.enabled,
        }
    }
}

/// A ray-cast shader, its bindings, and its pipelines per [`Variant`] (compiled
/// on first use).
#[derive(Debug)]
struct RaycastKernel {
    label: &'static str,
    module: wgpu::ShaderModule,
    bgl: wgpu::BindGroupLayout,
    layout: wgpu::PipelineLayout,
    pipelines: std::collections::HashMap<Variant, wgpu::ComputePipeline>,
}

impl RaycastKernel {
    /// The in-core kernel, or (`ooc`) the out-of-core one: the shared bindings
    /// plus the index (10) and the brick sub-cells (11).
    fn new(device: &wgpu::Device, ooc: bool) -> RaycastKernel {
        let mut entries = raycast_layout_entries();
        if ooc {
            entries.push(storage_entry(10));
            entries.push(storage_entry(11));
        }
        let label = if ooc {
            "brickray-render raycast ooc"
        } else {
            "brickray-render raycast"
        };
        let bgl = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some(label),
            entries: &entries,
        });
        let (name, src) = if ooc {
            ("brickray-render raycast_ooc.wgsl", shaders::raycast_ooc())
        } else {
            (
                "brickray-render raycast_incore.wgsl",
                shaders::raycast_incore(),
            )
        };
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(name),
            source: wgpu::ShaderSource::Wgsl(src.into()),
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some(label),
            bind_group_layouts: &[Some(&bgl)],
            immediate_size: 0,
        });
        RaycastKernel {
            label,
            module,
            bgl,
            layout,
            pipelines: Default::default(),
        }
    }

    fn pipeline(&mut self, device: &wgpu::Device, v: Variant) -> &wgpu::ComputePipeline {
        let (label, module, layout) = (self.label, &self.module, &self.layout);
        self.pipelines.entry(v).or_insert_with(|| {
            let b = |x: bool| if x { 1.0 } else { 0.0 };
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(label),
                layout: Some(layout),
                module,
                entry_point: Some("main"),
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants: &[
                        ("MODE", v.mode as f64),
                        ("ERT", b(v.ert)),
                        ("ESS", b(v.ess)),
                        ("SHADE", b(v.shade)),
                    ],
                    ..Default::default()
                },
                cache: None,
            })
        })
    }
}

impl VolumeRenderer {
    /// Creates the pipelines for the host's targets.
    pub fn new(device: &wgpu::Device, targets: TargetDesc) -> Result<VolumeRenderer, RenderError> {
        let blendable = targets
            .color_format
            .guaranteed_format_features(device.features())
            .flags
            .contains(wgpu::TextureFormatFeatureFlags::BLENDABLE);
        if !blendable {
            return Err(RenderError::BadTargetFormat(targets.color_format));
        }
        if let Some(d) = targets.depth_format.filter(|d| !d.has_depth_aspect()) {
            return Err(RenderError::BadDepthFormat(d));
        }
        let mut raycast = RaycastKernel::new(device, false);
        // The default variant is compiled up front, the others on first use.
        raycast.pipeline(device, Variant::of(&RenderSettings::default()));

        let tex_entry = |binding| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::FRAGMENT,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable: false },
                view_dimension: wgpu::TextureViewDimension::D2,
                multisampled: false,
            },
            count: None,
        };
        let composite_bgl = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("brickray-render composite"),
            entries: &[tex_entry(0), tex_entry(1)],
        });
        let composite_module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("brickray-render composite.wgsl"),
            source: wgpu::ShaderSource::Wgsl(shaders::COMPOSITE.into()),
        });
        let composite_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("brickray-render composite"),
            bind_group_layouts: &[Some(&composite_bgl)],
            immediate_size: 0,
        });
        let composite = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("brickray-render composite"),
            layout: Some(&composite_layout),
            vertex: wgpu::VertexState {
                module: &composite_module,
                entry_point: Some("vs_main"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: targets.depth_format.map(|format| wgpu::DepthStencilState {
                format,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::LessEqual),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: wgpu::MultisampleState::default(),
            fragment: Some(wgpu::FragmentState {
                module: &composite_module,
                entry_point: Some(if targets.depth_format.is_some() {
                    "fs_main"
                } else {
                    "fs_color"
                }),
                compilation_options: Default::default(),
                targets: &[Some(wgpu::ColorTargetState {
                    format: targets.color_format,
                    blend: Some(wgpu::BlendState::PREMULTIPLIED_ALPHA_BLENDING),
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            multiview_mask: None,
            cache: None,
        });
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("brickray-render volume"),
            address_mode_u: wgpu::AddressMode::ClampToEdge,
            address_mode_v: wgpu::AddressMode::ClampToEdge,
            address_mode_w: wgpu::AddressMode::ClampToEdge,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        let uniform = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("brickray-render params"),
            size: std::mem::size_of::<Params>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let dummy_depth = device
            .create_texture(&wgpu::TextureDescriptor {
                label: Some("brickray-render no host depth"),
                size: wgpu::Extent3d {
                    width: 1,
                    height: 1,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: wgpu::TextureFormat::Depth32Float,
                usage: wgpu::TextureUsages::TEXTURE_BINDING,
                view_formats: &[],
            })
            .create_view(&Default::default());
        Ok(VolumeRenderer {
            targets,
            raycast,
            composite,
            composite_bgl,
            sampler,
            uniform,
            last_params: None,
            tf: GrowBuffer::new(device, "brickray-render tf", 256 * 16),
            tf_prefix: GrowBuffer::new(device, "brickray-render tf prefix", 257 * 4),
            tf_len: 0,
            tf_cpu: None,
            volume: None,
            ooc: None,
            ooc_kernel: None,
            dummy_depth,
            frame_targets: None,
            raycast_bg: None,
            prepared: false,
            last_frame: FrameStats::default(),
        })
    }

    /// The targets this renderer draws into.
    pub fn targets(&self) -> TargetDesc {
        self.targets
    }

    /// Uploads a volume into one 3D texture (the in-core path) and builds its
    /// macro-cell grid. Fails with [`RenderError::VolumeTooLarge`] when a dimension
    /// exceeds the device's 3D texture limit.
    pub fn set_volume(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        volume: &Volume,
    ) -> Result<(), RenderError> {
        self.volume = Some(GpuVolume::upload(device, queue, volume)?);
        self.ooc = None;
        self.raycast_bg = None;
        Ok(())
    }

    /// Switches to the out-of-core path over a brick source (a brick-octree file
    /// store or a procedural source): bricks stream in asynchronously, a coarse
    /// image appears at once and sharpens over frames. `frame` places the volume
    /// in the world (as later passed in [`FrameDesc::frame`]).
    pub fn set_volume_source(
        &mut self,
        device: &wgpu::Device,
        source: Arc<dyn BrickSource>,
        frame: VolumeFrame,
        config: OutOfCoreConfig,
    ) -> Result<(), RenderError> {
        if self.ooc_kernel.is_none() {
            let mut k = RaycastKernel::new(device, true);
            k.pipeline(device, Variant::of(&RenderSettings::default()));
            self.ooc_kernel = Some(k);
        }
        self.ooc = Some(OocVolume::new(device, source, frame, config)?);
        self.volume = None;
        self.raycast_bg = None;
        Ok(())
    }

    /// Statistics of the last frame.
    pub fn stats(&self) -> RendererStats {
        RendererStats {
            frame: self.last_frame,
            out_of_core: self.out_of_core_stats(),
        }
    }

    /// Statistics of the out-of-core path's last frame (`None` in core).
    pub fn out_of_core_stats(&self) -> Option<OutOfCoreStats> {
        self.ooc.as_ref().map(|o| o.stats)
    }

    /// The GPU texture format chosen for the volume, if one is set.
    pub fn volume_format(&self) -> Option<wgpu::TextureFormat> {
        self.volume.as_ref().map(|v| v.format)
    }

    /// Bytes of volume data resident on the GPU.
    pub fn volume_bytes(&self) -> u64 {
        self.volume.as_ref().map_or(0, |v| v.bytes)
    }

    /// Sets the transfer function (and its opacity prefix-sum table). Written to the
    /// GPU only when it changed.
    pub fn set_transfer_function(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        tf: &TransferFunction,
    ) -> u64 {
        let entries: &[u8] = bytemuck::cast_slice(tf.entries());
        let (a, grew_a) = self.tf.write(device, queue, entries);
        let (b, grew_b) = self
            .tf_prefix
            .write(device, queue, bytemuck::cast_slice(tf.prefix()));
        if grew_a || grew_b {
            self.raycast_bg = None;
        }
        self.tf_len = tf.len() as u32;
        self.tf_cpu = Some(tf.clone());
        a + b
    }

    fn ensure_targets(&mut self, device: &wgpu::Device, width: u32, height: u32) {
        if self
            .frame_targets
            .as_ref()
            .is_some_and(|t| t.width == width && t.height == height)
        {
            return;
        }
        let make = |label, format, extra| {
            device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: wgpu::Extent3d {
                    width,
                    height,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage: wgpu::TextureUsages::STORAGE_BINDING
                    | wgpu::TextureUsages::TEXTURE_BINDING
                    | extra,
                view_formats: &[],
            })
        };
        let none = wgpu::TextureUsages::empty();
        let color = make(
            "brickray-render ray colour",
            wgpu::TextureFormat::Rgba16Float,
            none,
        )
        .create_view(&Default::default());
        let depth = make(
            "brickray-render ray depth",
            wgpu::TextureFormat::R32Float,
            none,
        )
        .create_view(&Default::default());
        let samples = make(
            "brickray-render ray samples",
            wgpu::TextureFormat::R32Uint,
            wgpu::TextureUsages::COPY_SRC,
        );
        let samples_view = samples.create_view(&Default::default());
        let composite_bg = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("brickray-render composite"),
            layout: &self.composite_bgl,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::TextureView(&color),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&depth),
                },
            ],
        });
        self.frame_targets = Some(FrameTargets {
            width,
            height,
            color,
            depth,
            samples,
            samples_view,
            composite_bg,
        });
        self.raycast_bg = None;
    }

    /// Writes this frame's uniforms and records the ray-cast compute pass into
    /// `encoder`. Out of core it first plans the frame (refinement, requests to the
    /// loader, uploads within the budget, index encoding); it never waits for I/O
    /// or the GPU. The host submits the encoder, then records [`Self::render`] into
    /// its pass (in the same or a later submission).
    pub fn prepare(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        frame: &FrameDesc<'_>,
    ) -> Result<FrameStats, PrepareError> {
        if self.volume.is_none() && self.ooc.is_none() {
            return Err(PrepareError::NoVolume);
        }
        let limit = device.limits().max_texture_dimension_2d;
        if frame.width == 0 || frame.height == 0 || frame.width > limit || frame.height > limit {
            return Err(PrepareError::BadViewport {
                width: frame.width,
                height: frame.height,
                limit,
            });
        }
        let s = &frame.settings;
        if !(s.step_factor.is_finite() && s.step_factor > 0.0) {
            return Err(PrepareError::BadSetting(format!(
                "step_factor {} must be > 0",
                s.step_factor
            )));
        }
        if self.tf_cpu.is_none() || self.tf_len < 2 {
            return Err(PrepareError::BadSetting("no transfer function set".into()));
        }
        self.ensure_targets(device, frame.width, frame.height);
        let mut uploaded = 0;
        if let (Some(ooc), Some(tf)) = (self.ooc.as_mut(), self.tf_cpu.as_ref()) {
            let (bytes, grew) = ooc.update(device, queue, frame, tf)?;
            uploaded += bytes;
            if grew {
                self.raycast_bg = None;
            }
        }
        let params = self.params(frame);
        if self.last_params != Some(params) {
            queue.write_buffer(&self.uniform, 0, bytemuck::bytes_of(&params));
            self.last_params = Some(params);
            uploaded += std::mem::size_of::<Params>() as u64;
        }
        let host = frame.host_depth.cloned();
        if self.raycast_bg.as_ref().is_none_or(|(_, h)| *h != host) {
            let t = self.frame_targets.as_ref().expect("ensured above");
            let depth_view = host.as_ref().unwrap_or(&self.dummy_depth);
            let (layout, volume_view, table, index) =
                match (&self.volume, &self.ooc, &self.ooc_kernel) {
                    (_, Some(o), Some(k)) => (
                        &k.bgl,
                        &o.atlas_view,
                        &o.slots,
                        Some((&o.index.buffer, &o.sub_cells)),
                    ),
                    (Some(v), _, _) => (&self.raycast.bgl, &v.view, &v.cell_ranges, None),
                    _ => return Err(PrepareError::NoVolume),
                };
            let mut entries = vec![
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: self.uniform.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(volume_view),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::Sampler(&self.sampler),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: self.tf.buffer.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: self.tf_prefix.buffer.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 5,
                    resource: table.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 6,
                    resource: wgpu::BindingResource::TextureView(depth_view),
                },
                wgpu::BindGroupEntry {
                    binding: 7,
                    resource: wgpu::BindingResource::TextureView(&t.color),
                },
                wgpu::BindGroupEntry {
                    binding: 8,
                    resource: wgpu::BindingResource::TextureView(&t.depth),
                },
                wgpu::BindGroupEntry {
                    binding: 9,
                    resource: wgpu::BindingResource::TextureView(&t.samples_view),
                },
            ];
            if let Some((index, sub_cells)) = index {
                entries.push(wgpu::BindGroupEntry {
                    binding: 10,
                    resource: index.as_entire_binding(),
                });
                entries.push(wgpu::BindGroupEntry {
                    binding: 11,
                    resource: sub_cells.as_entire_binding(),
                });
            }
            let bg = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("brickray-render raycast"),
                layout,
                entries: &entries,
            });
            self.raycast_bg = Some((bg, host));
        }
        let (bg, _) = self.raycast_bg.as_ref().expect("set above");
        let variant = Variant::of(&frame.settings);
        let pipeline = match (&self.ooc, &mut self.ooc_kernel) {
            (Some(_), Some(k)) => k.pipeline(device, variant),
            _ => self.raycast.pipeline(device, variant),
        };
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("brickray-render raycast"),
                timestamp_writes: None,
            });
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, bg, &[]);
            pass.dispatch_workgroups(frame.width.div_ceil(8), frame.height.div_ceil(8), 1);
        }
        self.prepared = true;
        Ok(FrameStats {
            rays: frame.width as u64 * frame.height as u64,
            uploaded_bytes: uploaded,
        })
    }

    fn params(&self, frame: &FrameDesc<'_>) -> Params {
        let s = &frame.settings;
        let aspect = frame.width as f32 / frame.height as f32;
        let vp = frame.camera.view_proj(aspect);
        let model = frame.frame.model;
        let normal = Mat3::from_mat4(model).inverse().transpose();
        let iso = match s.mode {
            RenderMode::Iso { value, color } => [value, color[0], color[1], color[2]],
            _ => [0.0; 4],
        };
        // Mode, ERT, ESS and shading are compiled into the pipeline (Variant);
        // only the host-depth flag is dynamic.
        let flags = if frame.host_depth.is_some() { 32 } else { 0 };
        let voxel_world = frame.frame.voxel_world;
        let finest = self
            .ooc
            .as_ref()
            .map_or(0, |o| (o.layout.levels - 1) as u32);
        let (dims, scale, offset, cells, octree, bricks, atlas) = match (&self.ooc, &self.volume) {
            (Some(o), _) => {
                let l = &o.layout;
                let sc = l.volume_scale();
                let a = o.atlas_dims;
                (
                    l.volume.dims,
                    o.encoding.scale,
                    o.encoding.offset,
                    [0; 4],
                    [sc[0] as f32, sc[1] as f32, sc[2] as f32, 0.0],
                    [l.brick, l.apron, l.stored_side(), o.sub_n],
                    [a[0] as f32, a[1] as f32, a[2] as f32, 0.0],
                )
            }
            (None, Some(v)) => (
                v.dims,
                v.scale,
                v.offset,
                [v.cells[0], v.cells[1], v.cells[2], gpu_volume::CELL],
                [0.0; 4],
                [0; 4],
                [0.0; 4],
            ),
            (None, None) => ([1; 3], 1.0, 0.0, [0; 4], [0.0; 4], [0; 4], [0.0; 4]),
        };
        Params {
            inv_view_proj: vp.inverse().to_cols_array_2d(),
            view_proj: vp.to_cols_array_2d(),
            inv_model: model.inverse().to_cols_array_2d(),
            normal_mat: Mat4::from_mat3(normal).to_cols_array_2d(),
            dims: [dims[0] as f32, dims[1] as f32, dims[2] as f32, voxel_world],
            value_map: [
                scale,
                offset,
                self.tf_len as f32,
                s.step_factor * voxel_world,
            ],
            iso,
            shade: [
                s.shading.ambient,
                s.shading.diffuse,
                s.shading.specular,
                s.shading.shininess,
            ],
            misc: [
                s.accel.early_termination.unwrap_or(2.0),
                s.depth_opacity,
                s.step_factor,
                0.0,
            ],
            size: [frame.width, frame.height, flags, s.iso_refine_steps],
            cells,
            limits: [MAX_STEPS, MAX_LEAVES, finest, 0],
            octree,
            bricks,
            atlas,
        }
    }

    /// Diagnostics for benchmarks and tests: an `R32Uint` texture (the viewport's
    /// size, `COPY_SRC`) holding the volume samples each ray took in the last
    /// prepared frame (march and iso refinement; gradient taps excluded).
    pub fn sample_count_texture(&self) -> Option<&wgpu::Texture> {
        self.frame_targets.as_ref().map(|t| &t.samples)
    }

    /// Records the composite draw into the host's pass: premultiplied blending over
    /// the host's colour and, when the pass has a depth attachment, the volume's
    /// depth (the host's depth where the volume put none).
    pub fn render(&self, pass: &mut wgpu::RenderPass<'_>) -> Result<(), RenderError> {
        let t = self
            .frame_targets
            .as_ref()
            .filter(|_| self.prepared)
            .ok_or(RenderError::NotPrepared)?;
        pass.set_pipeline(&self.composite);
        pass.set_bind_group(0, &t.composite_bg, &[]);
        pass.draw(0..3, 0..1);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn params_layout_is_16_byte_aligned() {
        assert_eq!(std::mem::size_of::<Params>() % 16, 0);
    }
}
