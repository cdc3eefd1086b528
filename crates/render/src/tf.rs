//! Group 1 of every ray-cast kernel: the transfer function's entries, its
//! opacity prefix sums and their count, with their bind group.

use crate::error::RenderError;
use crate::gpu::{self, GrowBuffer, Uniform};
use brickray_core::TransferFunction;

/// `struct TfInfo` of common.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct TfInfo {
    pub(crate) count: f32,
    pub(crate) pad0: f32,
    pub(crate) pad1: f32,
    pub(crate) pad2: f32,
}

/// Owner of group 1.
#[derive(Debug)]
pub(crate) struct TfTables {
    layout: wgpu::BindGroupLayout,
    entries: GrowBuffer,
    prefix: GrowBuffer,
    info: Uniform<TfInfo>,
    bind_group: Option<wgpu::BindGroup>,
    current: Option<TransferFunction>,
}

fn entry(binding: u32, ty: wgpu::BufferBindingType) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

/// Group 1's layout: entries (0), prefix sums (1), info (2).
pub(crate) fn layout_entries() -> [wgpu::BindGroupLayoutEntry; 3] {
    let storage = wgpu::BufferBindingType::Storage { read_only: true };
    [
        entry(0, storage),
        entry(1, storage),
        entry(2, wgpu::BufferBindingType::Uniform),
    ]
}

impl TfTables {
    pub(crate) fn new(device: &wgpu::Device) -> Result<TfTables, RenderError> {
        let layout = gpu::scoped(device, "brickray-render tf layout", || {
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("brickray-render transfer function"),
                entries: &layout_entries(),
            })
        })?;
        Ok(TfTables {
            layout,
            entries: GrowBuffer::new(device, "brickray-render tf", 16)?,
            prefix: GrowBuffer::new(device, "brickray-render tf prefix", 16)?,
            info: Uniform::new(device, "brickray-render tf info")?,
            bind_group: None,
            current: None,
        })
    }

    pub(crate) fn layout(&self) -> &wgpu::BindGroupLayout {
        &self.layout
    }

    /// The transfer function set last.
    pub(crate) fn current(&self) -> Option<&TransferFunction> {
        self.current.as_ref()
    }

    pub(crate) fn bind_group(&self) -> Option<&wgpu::BindGroup> {
        self.bind_group.as_ref()
    }

    /// Uploads `tf` (only what changed); returns the bytes written.
    pub(crate) fn set(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        tf: &TransferFunction,
    ) -> Result<u64, RenderError> {
        if self.current.as_ref() == Some(tf) {
            return Ok(0);
        }
        if tf.len() > TransferFunction::MAX_ENTRIES {
            return Err(brickray_core::TfError::TooMany {
                len: tf.len(),
                max: TransferFunction::MAX_ENTRIES,
            }
            .into());
        }
        let (a, grew_a) = self
            .entries
            .write(device, queue, bytemuck::cast_slice(tf.entries()))?;
        let (b, grew_b) = self
            .prefix
            .write(device, queue, bytemuck::cast_slice(tf.prefix()))?;
        let c = self.info.write(
            queue,
            TfInfo {
                count: tf.len() as f32,
                pad0: 0.0,
                pad1: 0.0,
                pad2: 0.0,
            },
        );
        if grew_a || grew_b || self.bind_group.is_none() {
            self.bind_group = Some(gpu::scoped(
                device,
                "brickray-render tf bind group",
                || {
                    device.create_bind_group(&wgpu::BindGroupDescriptor {
                        label: Some("brickray-render transfer function"),
                        layout: &self.layout,
                        entries: &[
                            wgpu::BindGroupEntry {
                                binding: 0,
                                resource: self.entries.buffer.as_entire_binding(),
                            },
                            wgpu::BindGroupEntry {
                                binding: 1,
                                resource: self.prefix.buffer.as_entire_binding(),
                            },
                            wgpu::BindGroupEntry {
                                binding: 2,
                                resource: self.info.buffer.as_entire_binding(),
                            },
                        ],
                    })
                },
            )?);
        }
        self.current = Some(tf.clone());
        Ok(a + b + c)
    }
}
