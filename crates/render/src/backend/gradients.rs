//! Per-voxel gradients of an in-core volume, computed once on the GPU
//! (`shaders/gradients.wgsl`) when a shaded DVR frame first needs them, so
//! that the kernel shades a sample with one filtered read instead of six
//! (`GRADIENTS` in modes.wgsl; docs/rendering-model.md, *Shading*).

use crate::error::RenderError;
use crate::gpu::{self, Uniform};

/// How the in-core kernel takes the gradient that shades a DVR sample
/// ([`RendererOptions::gradients`](crate::RendererOptions::gradients)).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum GradientSource {
    /// One filtered read of per-voxel gradients made once on the GPU, the
    /// first time a shaded DVR frame is prepared (8 bytes a voxel, counted in
    /// the volume's resident bytes; volumes whose gradients would pass 1 GiB
    /// keep six reads; so does a volume whose gradients the device refused,
    /// after that frame's typed error). The same gradient as six reads within
    /// half-float rounding (75-80 dB between the images,
    /// `tests/gpu_gradients.rs`).
    #[default]
    Precomputed,
    /// Six reads of the volume per shaded sample (the central difference of
    /// the trilinear field), nothing kept.
    SixReads,
}

/// The compute module.
pub(crate) const WGSL: &str = include_str!("../../shaders/gradients.wgsl");

/// The gradients' texel: x, y, z and an unused fourth lane, half floats
/// (filterable everywhere, and a write-only storage format in WebGPU core).
pub(crate) const FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;

/// Bytes of one gradient texel.
pub(crate) const TEXEL_BYTES: u64 = 8;

/// The most bytes of gradients an in-core volume keeps (a 512^3 volume's are
/// exactly this); a larger volume is shaded by six reads per sample.
pub(crate) const MAX_BYTES: u64 = 1 << 30;

/// `struct GradientParams` of gradients.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct GradientParams {
    pub(crate) dims: [u32; 3],
    pub(crate) value_scale: f32,
    pub(crate) value_offset: f32,
    pub(crate) pad0: f32,
    pub(crate) pad1: f32,
    pub(crate) pad2: f32,
}

/// The pass's bindings: the volume (0), its parameters (1), the gradients
/// written (2).
pub(crate) fn layout_entries() -> Vec<wgpu::BindGroupLayoutEntry> {
    vec![
        crate::group2::texture_3d_entry(0),
        gpu::uniform_entry::<GradientParams>(1),
        wgpu::BindGroupLayoutEntry {
            binding: 2,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::StorageTexture {
                access: wgpu::StorageTextureAccess::WriteOnly,
                format: FORMAT,
                view_dimension: wgpu::TextureViewDimension::D3,
            },
            count: None,
        },
    ]
}

/// The bytes of the gradients of a `dims` volume.
pub(crate) fn bytes(dims: [u32; 3]) -> u64 {
    dims.iter().map(|&d| d as u64).product::<u64>() * TEXEL_BYTES
}

/// Whether a `dims` volume keeps gradients on `device`: within [`MAX_BYTES`]
/// and with a storage texture for the pass.
pub(crate) fn fit(device: &wgpu::Device, dims: [u32; 3]) -> bool {
    bytes(dims) <= MAX_BYTES && device.limits().max_storage_textures_per_shader_stage >= 1
}

/// Creates the gradients of the volume `volume` (`dims` voxels, normalized
/// as `texel * scale + offset`; [`fit`] checked) and records the pass that
/// fills them into `encoder`. Returns the texture.
pub(crate) fn compute(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    encoder: &mut wgpu::CommandEncoder,
    volume: &wgpu::TextureView,
    dims: [u32; 3],
    scale_offset: [f32; 2],
) -> Result<wgpu::Texture, RenderError> {
    let label = "brickray-render gradients";
    let texture = gpu::texture_3d(
        device,
        dims,
        FORMAT,
        wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::STORAGE_BINDING,
        label,
    )?;
    let mut params = Uniform::<GradientParams>::new(device, "brickray-render gradient params")?;
    params.write(
        queue,
        GradientParams {
            dims,
            value_scale: scale_offset[0],
            value_offset: scale_offset[1],
            pad0: 0.0,
            pad1: 0.0,
            pad2: 0.0,
        },
    );
    let out = texture.create_view(&Default::default());
    let (pipeline, bind_group) = gpu::scoped(device, label, || {
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some(label),
            entries: &layout_entries(),
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(label),
            source: wgpu::ShaderSource::Wgsl(WGSL.into()),
        });
        let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some(label),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(label),
            layout: Some(&pl),
            module: &module,
            entry_point: Some("main"),
            compilation_options: Default::default(),
            cache: None,
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(label),
            layout: &layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::TextureView(volume),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: params.buffer.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::TextureView(&out),
                },
            ],
        });
        (pipeline, bind_group)
    })?;
    let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
        label: Some(label),
        timestamp_writes: None,
    });
    pass.set_pipeline(&pipeline);
    pass.set_bind_group(0, &bind_group, &[]);
    pass.dispatch_workgroups(
        dims[0].div_ceil(gpu::WORKGROUP[0]),
        dims[1].div_ceil(gpu::WORKGROUP[1]),
        dims[2],
    );
    Ok(texture)
}
