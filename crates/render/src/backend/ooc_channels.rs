//! A view's classification of a streamed multi-channel volume
//! (`shaders/ooc_channels.wgsl`): the `chan` uniform (each channel's texel
//! scale and offset, where its TF entries, prefix sums and table rows lie)
//! and the stacked tables and entries of [`ClassTables`], in group 2 beside
//! the out-of-core bindings. The volume's atlas packs every channel of a
//! brick in one texel; this is only how one view classifies them.

use super::channels::ClassTables;
use crate::error::RenderError;
use crate::gpu::{self, Uniform};
use crate::group2::{CHANNEL_UNIFORM_BUFFERS, OOC_CHANNEL_STORAGE_BUFFERS, check_stage_limits};
use brickray_cache::GpuFormat;
use brickray_core::channels::{self, ChannelStyle};

/// The `chan` uniform's binding.
const PARAMS_BINDING: u32 = 8;
/// The stacked tables' binding.
const TABLE_BINDING: u32 = 9;
/// The header, entries and prefix sums' binding.
const ENTRIES_BINDING: u32 = 10;

/// `struct OocChannelParams` of ooc_channels.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct OocChannelParams {
    pub(crate) scale: [f32; 4],
    pub(crate) offset: [f32; 4],
    pub(crate) tf_count: [f32; 4],
    pub(crate) tf_offset: [u32; 4],
    pub(crate) prefix_offset: [u32; 4],
    pub(crate) table_rows: f32,
    pub(crate) table_width: f32,
    pub(crate) pad0: f32,
    pub(crate) pad1: f32,
}

/// The out-of-core group 2 with the channels' classification.
pub(crate) fn layout_entries() -> Vec<wgpu::BindGroupLayoutEntry> {
    let c = wgpu::ShaderStages::COMPUTE;
    let mut e = crate::group2::ooc_layout_entries();
    e.push(wgpu::BindGroupLayoutEntry {
        binding: PARAMS_BINDING,
        visibility: c,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    });
    e.push(wgpu::BindGroupLayoutEntry {
        binding: TABLE_BINDING,
        visibility: c,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable: true },
            view_dimension: wgpu::TextureViewDimension::D2,
            multisampled: false,
        },
        count: None,
    });
    e.push(gpu::storage_entry(ENTRIES_BINDING, true));
    e
}

/// The per-stage limits this kernel needs: the out-of-core kernel's, one
/// more storage buffer and uniform, and its own sampled textures.
pub(crate) fn check_limits(device: &wgpu::Device) -> Result<(), RenderError> {
    check_stage_limits(device, OOC_CHANNEL_STORAGE_BUFFERS)?;
    let l = device.limits();
    gpu::need(
        "max_sampled_textures_per_shader_stage",
        crate::group2::OOC_CHANNEL_SAMPLED_TEXTURES as u64,
        l.max_sampled_textures_per_shader_stage as u64,
    )?;
    gpu::need(
        "max_uniform_buffers_per_shader_stage",
        CHANNEL_UNIFORM_BUFFERS as u64,
        l.max_uniform_buffers_per_shader_stage as u64,
    )
}

/// One view's classification of the channels.
#[derive(Debug)]
pub(crate) struct OocChannels {
    count: usize,
    params: Uniform<OocChannelParams>,
    base: OocChannelParams,
    class: ClassTables,
}

impl OocChannels {
    /// For a volume stored as `gpu` says (its channels' encodings); the
    /// uniform is written at the first [`update`](Self::update).
    pub(crate) fn new(device: &wgpu::Device, gpu: &GpuFormat) -> Result<OocChannels, RenderError> {
        check_limits(device)?;
        let count = gpu.channel_count as usize;
        let enc = &gpu.channel_encodings;
        let base = OocChannelParams {
            scale: std::array::from_fn(|c| if c < count { enc[c].scale } else { 0.0 }),
            offset: std::array::from_fn(|c| if c < count { enc[c].offset } else { 0.0 }),
            tf_count: [2.0; 4],
            tf_offset: [0; 4],
            prefix_offset: [0; 4],
            table_rows: 1.0,
            table_width: 2.0,
            pad0: 0.0,
            pad1: 0.0,
        };
        let params = Uniform::new(device, "brickray-render out-of-core channel params")?;
        Ok(OocChannels {
            count,
            params,
            base,
            class: ClassTables::new(device, count)?,
        })
    }

    /// Channels of the volume.
    pub(crate) fn count(&self) -> usize {
        self.count
    }

    /// Keeps the classification current: `styles` (of `generation`) for
    /// `step_factor` with `rows` step lengths. Returns the bytes written and
    /// whether group 2 must be rebuilt.
    pub(crate) fn update(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        styles: &[ChannelStyle],
        generation: u64,
        step_factor: f32,
        rows: u32,
    ) -> Result<(u64, bool), RenderError> {
        channels::validate_styles(styles, self.count)?;
        let Some((written, layout, rebind)) =
            self.class
                .update(device, queue, styles, generation, step_factor, rows)?
        else {
            return Ok((0, false));
        };
        let p = OocChannelParams {
            tf_count: layout.tf_count,
            tf_offset: layout.tf_offset,
            prefix_offset: layout.prefix_offset,
            table_rows: rows as f32,
            table_width: layout.width,
            ..self.base
        };
        Ok((written + self.params.write(queue, p), rebind))
    }

    /// Group 2's entries for the classification.
    pub(crate) fn entries(&self) -> [wgpu::BindGroupEntry<'_>; 3] {
        [
            wgpu::BindGroupEntry {
                binding: PARAMS_BINDING,
                resource: self.params.buffer.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: TABLE_BINDING,
                resource: wgpu::BindingResource::TextureView(&self.class.table.1),
            },
            wgpu::BindGroupEntry {
                binding: ENTRIES_BINDING,
                resource: self.class.entries.buffer.as_entire_binding(),
            },
        ]
    }
}
