//! The layout of a kernel's group 2 (the volume's bindings) and the
//! per-stage binding counts both ray casters need, checked against the
//! device before anything is created: what the backends, the shared streamed
//! volume and `required_limits` all read.

use crate::error::RenderError;
use crate::gpu;

/// Storage buffers of the in-core group 2: the macro-cell ranges and skip
/// distances.
pub(crate) const INCORE_STORAGE_BUFFERS: u32 = 2;

/// The clamp-to-edge sampler of a volume texture: linear for intensities,
/// nearest for label maps (a label id is never interpolated).
pub(crate) fn volume_sampler(
    device: &wgpu::Device,
    labels: bool,
) -> Result<wgpu::Sampler, RenderError> {
    let filter = if labels {
        wgpu::FilterMode::Nearest
    } else {
        wgpu::FilterMode::Linear
    };
    gpu::scoped(device, "brickray-render volume sampler", || {
        device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("brickray-render volume"),
            address_mode_u: wgpu::AddressMode::ClampToEdge,
            address_mode_v: wgpu::AddressMode::ClampToEdge,
            address_mode_w: wgpu::AddressMode::ClampToEdge,
            mag_filter: filter,
            min_filter: filter,
            ..Default::default()
        })
    })
}

/// A compute kernel's filterable float 3D texture at `binding` (a volume, an
/// atlas, the spreads, the gradients).
pub(crate) fn texture_3d_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable: true },
            view_dimension: wgpu::TextureViewDimension::D3,
            multisampled: false,
        },
        count: None,
    }
}

/// A compute kernel's table at `binding` (a `TableTexture`, read with
/// `textureLoad`).
pub(crate) fn table_entry(
    binding: u32,
    sample_type: wgpu::TextureSampleType,
) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Texture {
            sample_type,
            view_dimension: wgpu::TextureViewDimension::D2,
            multisampled: false,
        },
        count: None,
    }
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
        texture_3d_entry(1),
        wgpu::BindGroupLayoutEntry {
            binding: 2,
            visibility: c,
            ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
            count: None,
        },
    ];
    for i in 0..storage {
        e.push(gpu::storage_entry(3 + i, true));
    }
    e
}

/// Per-stage bindings of a kernel besides group 2's storage buffers: the
/// transfer function's entries and the prediction history; uniforms of
/// frame, prediction, TF, volume and overlay; the sampled volume, host
/// depth, the TF's prefix sums (a table texture), corrected table,
/// pre-integrated table and spread table, and the overlay's labels and
/// table; the volume and TF samplers.
pub(crate) const STORAGE_OUTSIDE_VOLUME: u32 = 2;
pub(crate) const UNIFORM_BUFFERS: u32 = 5;
pub(crate) const SAMPLED_TEXTURES: u32 = 8;
/// Sampled textures of the multi-channel kernels: one more, their channels'
/// stacked TF tables (`backend/channels.rs`, `backend/ooc_channels.rs`).
pub(crate) const CHANNEL_SAMPLED_TEXTURES: u32 = SAMPLED_TEXTURES + 1;
/// Sampled textures of the multi-channel out-of-core kernel: four more,
/// its channels' stacked TF tables and the three out-of-core tables.
pub(crate) const OOC_CHANNEL_SAMPLED_TEXTURES: u32 = SAMPLED_TEXTURES + 1 + OOC_TABLES;
/// Sampled textures of the in-core kernel: one more, the per-voxel gradients
/// (`backend/gradients.rs`).
pub(crate) const INCORE_SAMPLED_TEXTURES: u32 = SAMPLED_TEXTURES + 1;
/// The out-of-core tables in textures: slots, sub-cells, index.
pub(crate) const OOC_TABLES: u32 = 3;
/// Sampled textures of the single-channel out-of-core kernel: five more,
/// the spread and gradient atlases and the three tables.
pub(crate) const OOC_SAMPLED_TEXTURES: u32 = SAMPLED_TEXTURES + 2 + OOC_TABLES;
/// Uniform buffers of the multi-channel out-of-core kernel: one more, its
/// channels' parameters (`backend/ooc_channels.rs`).
pub(crate) const CHANNEL_UNIFORM_BUFFERS: u32 = UNIFORM_BUFFERS + 1;
pub(crate) const SAMPLERS: u32 = 2;
/// The most storage buffers group 2 holds: a multi-channel volume in core
/// (the macro-cell ranges and skip distances, the channels' TF entries; out
/// of core group 2 holds the usage counters and, with channels, their TF
/// entries).
pub(crate) const MAX_VOLUME_STORAGE: u32 = INCORE_STORAGE_BUFFERS + 1;

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
        gpu::need(limit, required as u64, available as u64)?;
    }
    Ok(())
}

/// The bindings of the out-of-core tables (`TableTexture`s read with
/// `textureLoad`; `shaders/ooc_volume.wgsl`): the slot table (Rgba32Float),
/// the sub-cell ranges (Rg32Float) and the index's words (R32Uint).
pub(crate) const SLOTS_BINDING: u32 = 3;
pub(crate) const SUB_CELLS_BINDING: u32 = 4;
pub(crate) const INDEX_BINDING: u32 = 5;
/// Storage buffers of group 2 out of core: the usage counters (read-write,
/// binding 6).
pub(crate) const OOC_STORAGE_BUFFERS: u32 = 1;
/// Storage buffers of group 2 of the multi-channel out-of-core kernel: the
/// out-of-core ones and the channels' classification.
pub(crate) const OOC_CHANNEL_STORAGE_BUFFERS: u32 = OOC_STORAGE_BUFFERS + 1;
/// The binding of the usage counters (`shaders/feedback.wgsl`).
pub(crate) const USAGE_BINDING: u32 = 6;
/// The binding of the stop-depth texture (`shaders/feedback.wgsl`).
pub(crate) const STOP_DEPTH_BINDING: u32 = 7;
/// Storage textures of group 2: the stop depth.
pub(crate) const STORAGE_TEXTURES: u32 = 1;
/// The binding of the spread atlas (`shaders/ooc.wgsl`; single-channel
/// volumes out of core).
pub(crate) const SPREAD_BINDING: u32 = 11;
/// The binding of the gradient atlas (`shaders/ooc.wgsl`; single-channel
/// volumes out of core).
pub(crate) const OOC_GRADIENT_BINDING: u32 = 12;

/// The layout of group 2 of the single-channel out-of-core kernel: the
/// out-of-core entries, the spread atlas and the gradient atlas.
pub(crate) fn ooc_single_layout_entries() -> Vec<wgpu::BindGroupLayoutEntry> {
    let mut e = ooc_layout_entries();
    e.push(texture_3d_entry(SPREAD_BINDING));
    e.push(texture_3d_entry(OOC_GRADIENT_BINDING));
    e
}

/// The layout of group 2 out of core: the shared volume entries and the
/// read-write usage counters.
pub(crate) fn ooc_layout_entries() -> Vec<wgpu::BindGroupLayoutEntry> {
    let mut e = volume_layout_entries(0);
    let float = wgpu::TextureSampleType::Float { filterable: false };
    e.push(table_entry(SLOTS_BINDING, float));
    e.push(table_entry(SUB_CELLS_BINDING, float));
    e.push(table_entry(INDEX_BINDING, wgpu::TextureSampleType::Uint));
    e.push(gpu::storage_entry(USAGE_BINDING, false));
    e.push(wgpu::BindGroupLayoutEntry {
        binding: STOP_DEPTH_BINDING,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::StorageTexture {
            access: wgpu::StorageTextureAccess::WriteOnly,
            format: wgpu::TextureFormat::R32Float,
            view_dimension: wgpu::TextureViewDimension::D2,
        },
        count: None,
    });
    e
}

/// The per-stage limits the out-of-core kernel needs.
pub(crate) fn check_ooc_limits(device: &wgpu::Device) -> Result<(), RenderError> {
    check_stage_limits(device, OOC_STORAGE_BUFFERS)?;
    gpu::need(
        "max_sampled_textures_per_shader_stage",
        OOC_SAMPLED_TEXTURES as u64,
        device.limits().max_sampled_textures_per_shader_stage as u64,
    )?;
    gpu::need(
        "max_storage_textures_per_shader_stage",
        (crate::frame::OUTPUT_FORMATS.len() as u32 + STORAGE_TEXTURES) as u64,
        device.limits().max_storage_textures_per_shader_stage as u64,
    )
}
