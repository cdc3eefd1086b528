//! The composite draw: blends the ray caster's premultiplied colour over the
//! host's and writes its depth, in the host's pass (sample count, depth format
//! and depth convention of the host).

use crate::desc::{TargetDesc, Viewport};
use crate::error::RenderError;
use crate::frame::Outputs;
use crate::gpu::{self, Uniform};
use crate::shaders;
use brickray_core::DepthConvention;

/// `struct Composite` of composite.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct CompositeUniforms {
    pub(crate) origin: [u32; 2],
    pub(crate) pad: [u32; 2],
}

/// Owner of the composite pipelines (one per depth convention when the host's
/// pass has depth) and of their bind group over the frame's outputs.
#[derive(Debug)]
pub(crate) struct Compositor {
    layout: wgpu::BindGroupLayout,
    /// Standard (`LessEqual`) and reversed-Z (`GreaterEqual`); the same pipeline
    /// twice without a depth attachment.
    pipelines: [wgpu::RenderPipeline; 2],
    uniform: Uniform<CompositeUniforms>,
    /// The bind group and the outputs generation it holds.
    bind_group: Option<(wgpu::BindGroup, u64)>,
}

fn tex_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::FRAGMENT,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable: false },
            view_dimension: wgpu::TextureViewDimension::D2,
            multisampled: false,
        },
        count: None,
    }
}

/// Checks that the host's targets can be drawn into as described.
pub(crate) fn check_targets(device: &wgpu::Device, t: &TargetDesc) -> Result<(), RenderError> {
    let features = device.features();
    let color = t.color_format.guaranteed_format_features(features);
    if !color
        .flags
        .contains(wgpu::TextureFormatFeatureFlags::BLENDABLE)
    {
        return Err(RenderError::BadTargetFormat(t.color_format));
    }
    if let Some(d) = t.depth_format.filter(|d| !d.has_depth_aspect()) {
        return Err(RenderError::BadDepthFormat(d));
    }
    let formats = std::iter::once(t.color_format).chain(t.depth_format);
    for format in formats {
        let f = format.guaranteed_format_features(features);
        if !f.flags.sample_count_supported(t.sample_count) {
            return Err(RenderError::BadSampleCount {
                format,
                count: t.sample_count,
            });
        }
    }
    Ok(())
}

impl Compositor {
    pub(crate) fn new(device: &wgpu::Device, t: &TargetDesc) -> Result<Compositor, RenderError> {
        check_targets(device, t)?;
        let limits = device.limits();
        gpu::need(
            "max_sampled_textures_per_shader_stage",
            2,
            limits.max_sampled_textures_per_shader_stage as u64,
        )?;
        let label = Some("brickray-render composite");
        let layout = gpu::scoped(device, "brickray-render composite layout", || {
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label,
                entries: &[
                    tex_entry(0),
                    tex_entry(1),
                    wgpu::BindGroupLayoutEntry {
                        binding: 2,
                        visibility: wgpu::ShaderStages::FRAGMENT,
                        ty: wgpu::BindingType::Buffer {
                            ty: wgpu::BufferBindingType::Uniform,
                            has_dynamic_offset: false,
                            min_binding_size: None,
                        },
                        count: None,
                    },
                ],
            })
        })?;
        let module = gpu::scoped(device, "brickray-render composite.wgsl", || {
            device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label,
                source: wgpu::ShaderSource::Wgsl(shaders::COMPOSITE.into()),
            })
        })?;
        let pipeline_layout = gpu::scoped(device, "brickray-render composite", || {
            device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label,
                bind_group_layouts: &[Some(&layout)],
                immediate_size: 0,
            })
        })?;
        let pipeline = |compare| {
            gpu::scoped(device, "brickray-render composite pipeline", || {
                device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                    label,
                    layout: Some(&pipeline_layout),
                    vertex: wgpu::VertexState {
                        module: &module,
                        entry_point: Some("vs_main"),
                        compilation_options: Default::default(),
                        buffers: &[],
                    },
                    primitive: wgpu::PrimitiveState::default(),
                    depth_stencil: t.depth_format.map(|format| wgpu::DepthStencilState {
                        format,
                        depth_write_enabled: Some(true),
                        depth_compare: Some(compare),
                        stencil: Default::default(),
                        bias: Default::default(),
                    }),
                    multisample: wgpu::MultisampleState {
                        count: t.sample_count,
                        ..Default::default()
                    },
                    fragment: Some(wgpu::FragmentState {
                        module: &module,
                        entry_point: Some(if t.depth_format.is_some() {
                            "fs_main"
                        } else {
                            "fs_color"
                        }),
                        compilation_options: Default::default(),
                        targets: &[Some(wgpu::ColorTargetState {
                            format: t.color_format,
                            blend: Some(wgpu::BlendState::PREMULTIPLIED_ALPHA_BLENDING),
                            write_mask: wgpu::ColorWrites::ALL,
                        })],
                    }),
                    multiview_mask: None,
                    cache: None,
                })
            })
        };
        let pipelines = [
            pipeline(wgpu::CompareFunction::LessEqual)?,
            pipeline(wgpu::CompareFunction::GreaterEqual)?,
        ];
        Ok(Compositor {
            layout,
            pipelines,
            uniform: Uniform::new(device, "brickray-render composite uniforms")?,
            bind_group: None,
        })
    }

    /// Writes the viewport origin and rebuilds the bind group when the outputs
    /// changed; returns the bytes written.
    pub(crate) fn update(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        outputs: &Outputs,
        viewport: Viewport,
    ) -> Result<u64, RenderError> {
        let written = self.uniform.write(
            queue,
            CompositeUniforms {
                origin: [viewport.x, viewport.y],
                pad: [0; 2],
            },
        );
        if self
            .bind_group
            .as_ref()
            .is_none_or(|(_, g)| *g != outputs.generation)
        {
            let bg = gpu::scoped(device, "brickray-render composite bind group", || {
                device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("brickray-render composite"),
                    layout: &self.layout,
                    entries: &[
                        wgpu::BindGroupEntry {
                            binding: 0,
                            resource: wgpu::BindingResource::TextureView(&outputs.color),
                        },
                        wgpu::BindGroupEntry {
                            binding: 1,
                            resource: wgpu::BindingResource::TextureView(&outputs.depth),
                        },
                        wgpu::BindGroupEntry {
                            binding: 2,
                            resource: self.uniform.buffer.as_entire_binding(),
                        },
                    ],
                })
            })?;
            self.bind_group = Some((bg, outputs.generation));
        }
        Ok(written)
    }

    /// Records the draw into the host's pass over `viewport`.
    pub(crate) fn draw(
        &self,
        pass: &mut wgpu::RenderPass<'_>,
        viewport: Viewport,
        convention: DepthConvention,
    ) -> Result<(), RenderError> {
        let (bg, _) = self.bind_group.as_ref().ok_or(RenderError::NotPrepared)?;
        let pipeline = match convention {
            DepthConvention::ReversedZ => &self.pipelines[1],
            _ => &self.pipelines[0],
        };
        pass.set_viewport(
            viewport.x as f32,
            viewport.y as f32,
            viewport.width as f32,
            viewport.height as f32,
            0.0,
            1.0,
        );
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, bg, &[]);
        pass.draw(0..3, 0..1);
        Ok(())
    }
}
