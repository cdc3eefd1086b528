//! Owner of group 3: a label map drawn over the image in the same ray
//! (`shaders/overlay.wgsl`; the model is `brickray_core::overlay`). Without
//! an overlay the group binds a one-texel stand-in, so every kernel has the
//! same four groups.

use crate::error::RenderError;
use crate::gpu::{self, Uniform};
use brickray_core::labels::label_value_range;
use brickray_core::{LABEL_TABLE_ENTRIES, LabelOverlay, LabelTable, OverlayStyle, SampleEncoding};

/// `struct OverlayParams` of overlay.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct OverlayParams {
    pub(crate) image_to_labels: [f32; 16],
    pub(crate) dims: [f32; 3],
    pub(crate) id_scale: f32,
    pub(crate) id_offset: f32,
    pub(crate) opacity: f32,
    pub(crate) pad0: f32,
    pub(crate) pad1: f32,
}

/// The label table: straight colour and opacity per id, one Rgba32Float
/// texel each (a 2048 x 1 texture).
type Table = [[f32; 4]; LABEL_TABLE_ENTRIES];

/// What is drawn over the image, while an overlay is set.
#[derive(Debug)]
struct Drawn {
    /// Kept alive with the bind group.
    _texture: wgpu::Texture,
    bytes: u64,
    style: OverlayStyle,
}

/// Group 3's layout, uniforms and bind group.
#[derive(Debug)]
pub(crate) struct OverlayState {
    layout: wgpu::BindGroupLayout,
    params: Uniform<OverlayParams>,
    table: wgpu::Texture,
    bind_group: wgpu::BindGroup,
    drawn: Option<Drawn>,
}

/// Group 3's layout entries (overlay.wgsl).
pub(crate) fn layout_entries() -> [wgpu::BindGroupLayoutEntry; 3] {
    let c = wgpu::ShaderStages::COMPUTE;
    let uniform = |binding| wgpu::BindGroupLayoutEntry {
        binding,
        visibility: c,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    };
    [
        uniform(0),
        wgpu::BindGroupLayoutEntry {
            binding: 1,
            visibility: c,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable: false },
                view_dimension: wgpu::TextureViewDimension::D3,
                multisampled: false,
            },
            count: None,
        },
        wgpu::BindGroupLayoutEntry {
            binding: 2,
            visibility: c,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable: false },
                view_dimension: wgpu::TextureViewDimension::D2,
                multisampled: false,
            },
            count: None,
        },
    ]
}

fn table_bytes(table: &LabelTable) -> Vec<u8> {
    let t: Table = std::array::from_fn(|i| table.rgba(i as u32));
    bytemuck::cast_slice(&t).to_vec()
}

/// Writes `table` into the table texture; returns the bytes written.
fn write_table(queue: &wgpu::Queue, texture: &wgpu::Texture, table: &LabelTable) -> u64 {
    let bytes = table_bytes(table);
    queue.write_texture(
        texture.as_image_copy(),
        &bytes,
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(bytes.len() as u32),
            rows_per_image: Some(1),
        },
        texture.size(),
    );
    bytes.len() as u64
}

impl OverlayState {
    /// The layout and the stand-in (no overlay).
    pub(crate) fn new(device: &wgpu::Device) -> Result<Self, RenderError> {
        // Its own bindings, before any object (the kernels' whole count is
        // checked with their group 2: `group2::check_stage_limits`).
        let l = device.limits();
        gpu::need(
            "max_sampled_textures_per_shader_stage",
            2,
            l.max_sampled_textures_per_shader_stage as u64,
        )?;
        gpu::need(
            "max_uniform_buffers_per_shader_stage",
            1,
            l.max_uniform_buffers_per_shader_stage as u64,
        )?;
        let layout = gpu::scoped(device, "brickray-render overlay layout", || {
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("brickray-render overlay"),
                entries: &layout_entries(),
            })
        })?;
        let params = Uniform::<OverlayParams>::new(device, "brickray-render overlay params")?;
        let table = gpu::texture(
            device,
            &wgpu::TextureDescriptor {
                label: Some("brickray-render overlay table"),
                size: wgpu::Extent3d {
                    width: LABEL_TABLE_ENTRIES as u32,
                    height: 1,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: wgpu::TextureFormat::Rgba32Float,
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                view_formats: &[],
            },
        )?;
        let stand_in = gpu::texture(
            device,
            &wgpu::TextureDescriptor {
                label: Some("brickray-render no overlay"),
                size: wgpu::Extent3d {
                    width: 1,
                    height: 1,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D3,
                format: wgpu::TextureFormat::R8Unorm,
                usage: wgpu::TextureUsages::TEXTURE_BINDING,
                view_formats: &[],
            },
        )?;
        let bind_group = Self::bind(device, &layout, &params, &table, &stand_in)?;
        Ok(OverlayState {
            layout,
            params,
            table,
            bind_group,
            drawn: None,
        })
    }

    fn bind(
        device: &wgpu::Device,
        layout: &wgpu::BindGroupLayout,
        params: &Uniform<OverlayParams>,
        table: &wgpu::Texture,
        texture: &wgpu::Texture,
    ) -> Result<wgpu::BindGroup, RenderError> {
        let view = texture.create_view(&Default::default());
        let table = table.create_view(&Default::default());
        gpu::scoped(device, "brickray-render overlay bind group", || {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("brickray-render overlay"),
                layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: params.buffer.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: wgpu::BindingResource::TextureView(&view),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: wgpu::BindingResource::TextureView(&table),
                    },
                ],
            })
        })
    }

    /// Uploads `o`'s label map, table and placement (checked by the caller),
    /// or removes the overlay (`None`).
    pub(crate) fn set(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        o: Option<&LabelOverlay<'_>>,
    ) -> Result<(), RenderError> {
        let Some(o) = o else {
            self.drawn = None;
            return Ok(());
        };
        let enc = SampleEncoding::for_labels(o.labels.desc().dtype);
        let (texture, bytes) = gpu::volume_texture(
            device,
            queue,
            o.labels,
            &enc,
            "brickray-render overlay labels",
        )?;
        let [lo, hi] = label_value_range();
        let span = hi - lo;
        self.params.write(
            queue,
            OverlayParams {
                image_to_labels: o.image_to_labels.as_mat4().to_cols_array(),
                dims: o.labels.dims().map(|d| d as f32),
                id_scale: enc.scale * span,
                id_offset: enc.offset * span + lo,
                opacity: o.style.opacity,
                pad0: 0.0,
                pad1: 0.0,
            },
        );
        write_table(queue, &self.table, o.table);
        self.bind_group = Self::bind(device, &self.layout, &self.params, &self.table, &texture)?;
        self.drawn = Some(Drawn {
            _texture: texture,
            bytes,
            style: o.style,
        });
        Ok(())
    }

    /// Rewrites the label table (colours, visibility, selection, hover) of
    /// the overlay drawn. Returns the bytes written (0 without an overlay).
    pub(crate) fn set_table(&mut self, queue: &wgpu::Queue, table: &LabelTable) -> u64 {
        if self.drawn.is_none() {
            return 0;
        }
        write_table(queue, &self.table, table)
    }

    /// Sets the style of the overlay drawn (checked by the caller).
    pub(crate) fn set_style(&mut self, queue: &wgpu::Queue, style: OverlayStyle) {
        if let Some(d) = self.drawn.as_mut() {
            d.style = style;
            if let Some(mut p) = self.params.last() {
                p.opacity = style.opacity;
                self.params.write(queue, p);
            }
        }
    }

    /// The style of the overlay drawn, `None` without one.
    pub(crate) fn style(&self) -> Option<OverlayStyle> {
        self.drawn.as_ref().map(|d| d.style)
    }

    /// Bytes of the label map's texture (0 without an overlay).
    pub(crate) fn bytes(&self) -> u64 {
        self.drawn.as_ref().map_or(0, |d| d.bytes)
    }

    pub(crate) fn layout(&self) -> &wgpu::BindGroupLayout {
        &self.layout
    }

    pub(crate) fn bind_group(&self) -> &wgpu::BindGroup {
        &self.bind_group
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The label table is one texel row of 2048 RGBA floats.
    #[test]
    fn the_table_is_one_vec4_per_label() {
        assert_eq!(std::mem::size_of::<Table>(), LABEL_TABLE_ENTRIES * 16);
        assert_eq!(
            table_bytes(&LabelTable::default()).len(),
            LABEL_TABLE_ENTRIES * 16
        );
    }

    /// Label ids come back from both encodings exactly.
    #[test]
    fn ids_decode_from_both_label_encodings() {
        let [lo, hi] = label_value_range();
        for dtype in [brickray_core::DType::U8, brickray_core::DType::U32] {
            let enc = SampleEncoding::for_labels(dtype);
            let (scale, offset) = (enc.scale * (hi - lo), enc.offset * (hi - lo) + lo);
            let ids: &[u32] = if dtype == brickray_core::DType::U8 {
                &[0, 1, 7, 200, 255]
            } else {
                &[0, 1, 7, 1000, 2047]
            };
            for &id in ids {
                let texel = if dtype == brickray_core::DType::U8 {
                    id as f32 / 255.0
                } else {
                    id as f32
                };
                assert_eq!(
                    (texel * scale + offset).round() as u32,
                    id,
                    "{dtype:?} {id}"
                );
            }
        }
    }
}
