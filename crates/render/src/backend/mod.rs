//! The volume backends behind one seam: each owns group 2 of its kernel (the
//! volume's textures, tables and uniforms, and their bind group) and updates it
//! per frame. In core the volume is one 3D texture; out of core a brick atlas fed
//! by the cache and walked through the octree-with-ropes index.

pub(crate) mod feedback;
pub(crate) mod incore;
pub(crate) mod occlusion;
pub(crate) mod ooc;
mod readback;

pub use feedback::FeedbackStats;
pub(crate) use incore::InCore;
pub use occlusion::OcclusionStats;
pub(crate) use ooc::OutOfCore;
pub use ooc::OutOfCoreStats;

use crate::error::RenderError;
use crate::kernels::KernelKind;

/// What every backend does for the coordinator.
pub(crate) trait VolumeBackend: std::fmt::Debug {
    /// The kernel that samples this backend.
    fn kind(&self) -> KernelKind;
    /// The layout of group 2 (the kernel's pipeline layout is built from it).
    fn layout(&self) -> &wgpu::BindGroupLayout;
    /// Group 2.
    fn bind_group(&self) -> &wgpu::BindGroup;
    /// Records what must precede the ray-cast pass (out of core: clearing the
    /// usage counters).
    fn before_pass(&mut self, encoder: &mut wgpu::CommandEncoder) {
        let _ = encoder;
    }
    /// Records what follows the ray-cast pass (out of core: copying the usage
    /// counters into the read-back ring).
    fn after_pass(&mut self, queue: &wgpu::Queue, encoder: &mut wgpu::CommandEncoder) {
        let _ = (queue, encoder);
    }
    /// True when the kernel must measure the visible weights
    /// (`shaders/feedback.wgsl`; out of core under `LodMetric::VisibleError`).
    fn measures_weights(&self) -> bool {
        false
    }
    /// Most index leaves one ray may visit (0 in core).
    fn max_leaves(&self) -> u32;
    /// Step lengths the kernel samples with (rows of the corrected TF table):
    /// one in core, one per octree level out of core (the step doubles a level).
    fn step_lengths(&self) -> u32;
    /// True when another frame of the same view would change the image.
    fn wants_redraw(&self) -> bool;
    /// The texture format the samples are stored in.
    fn texel_format(&self) -> wgpu::TextureFormat;
    /// Bytes of volume data resident on the GPU.
    fn resident_bytes(&self) -> u64;
}

/// The backend in use.
#[derive(Debug)]
pub(crate) enum Backend {
    InCore(InCore),
    OutOfCore(Box<OutOfCore>),
}

impl Backend {
    pub(crate) fn get(&self) -> &dyn VolumeBackend {
        match self {
            Backend::InCore(b) => b,
            Backend::OutOfCore(b) => b.as_ref(),
        }
    }

    pub(crate) fn get_mut(&mut self) -> &mut dyn VolumeBackend {
        match self {
            Backend::InCore(b) => b,
            Backend::OutOfCore(b) => b.as_mut(),
        }
    }

    pub(crate) fn out_of_core(&self) -> Option<&OutOfCore> {
        match self {
            Backend::OutOfCore(b) => Some(b),
            Backend::InCore(_) => None,
        }
    }
}

/// The linear, clamp-to-edge sampler of a volume texture.
pub(crate) fn volume_sampler(device: &wgpu::Device) -> Result<wgpu::Sampler, RenderError> {
    crate::gpu::scoped(device, "brickray-render volume sampler", || {
        device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("brickray-render volume"),
            address_mode_u: wgpu::AddressMode::ClampToEdge,
            address_mode_v: wgpu::AddressMode::ClampToEdge,
            address_mode_w: wgpu::AddressMode::ClampToEdge,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        })
    })
}

/// Layout entries shared by both backends' group 2: the uniform (0), the volume
/// texture (1), its sampler (2), then `storage` read-only storage buffers
/// (3, 4, ...).
pub(crate) fn volume_layout_entries(storage: u32) -> Vec<wgpu::BindGroupLayoutEntry> {
    let c = wgpu::ShaderStages::COMPUTE;
    let mut e = vec![
        wgpu::BindGroupLayoutEntry {
            binding: 0,
            visibility: c,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: false,
                min_binding_size: None,
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
    ];
    for i in 0..storage {
        e.push(wgpu::BindGroupLayoutEntry {
            binding: 3 + i,
            visibility: c,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only: true },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        });
    }
    e
}

/// Per-stage bindings of a kernel besides group 2's storage buffers: the
/// transfer function's 2 storage buffers and the prediction history; uniforms
/// of frame, prediction, TF and volume; the
/// sampled volume, host depth, corrected TF table and pre-integrated table; the volume and TF
/// samplers.
pub(crate) const STORAGE_OUTSIDE_VOLUME: u32 = 3;
pub(crate) const UNIFORM_BUFFERS: u32 = 4;
pub(crate) const SAMPLED_TEXTURES: u32 = 4;
pub(crate) const SAMPLERS: u32 = 2;
/// The most storage buffers group 2 holds (out of core: slots, sub-cells,
/// index, usage counters).
pub(crate) const MAX_VOLUME_STORAGE: u32 = ooc::STORAGE_BUFFERS;

/// Checks the per-stage binding counts of a kernel whose group 2 has `storage`
/// storage buffers.
pub(crate) fn check_stage_limits(device: &wgpu::Device, storage: u32) -> Result<(), RenderError> {
    let l = device.limits();
    let checks = [
        (
            "max_storage_buffers_per_shader_stage",
            storage + STORAGE_OUTSIDE_VOLUME,
            l.max_storage_buffers_per_shader_stage,
        ),
        (
            "max_uniform_buffers_per_shader_stage",
            UNIFORM_BUFFERS,
            l.max_uniform_buffers_per_shader_stage,
        ),
        (
            "max_sampled_textures_per_shader_stage",
            SAMPLED_TEXTURES,
            l.max_sampled_textures_per_shader_stage,
        ),
        (
            "max_samplers_per_shader_stage",
            SAMPLERS,
            l.max_samplers_per_shader_stage,
        ),
    ];
    for (limit, required, available) in checks {
        crate::gpu::need(limit, required as u64, available as u64)?;
    }
    Ok(())
}
