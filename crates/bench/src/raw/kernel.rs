//! The yardstick kernel of the `raw` suite (raw.wgsl): its pipelines, its
//! resources and one timed dispatch.

use brickray_core::{Camera, Volume, VolumeFrame};
use brickray_harness::GpuContext;
use glam::DVec3;
use std::time::Instant;

/// The kernel's WGSL.
pub(crate) const SOURCE: &str = include_str!("raw.wgsl");

/// `struct Raw` of raw.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct RawUniforms {
    eye: [f32; 3],
    near: f32,
    fwd: [f32; 3],
    dt: f32,
    right: [f32; 3],
    persp: f32,
    up: [f32; 3],
    isovalue: f32,
    size: [u32; 2],
    refine_steps: u32,
    value_scale: f32,
    dims: [f32; 3],
    tf_count: f32,
    value_offset: f32,
    pad: [f32; 3],
}

/// Kernel modes (`MODE` of raw.wgsl).
pub(crate) const MODES: [(&str, u32); 4] = [("dvr", 0), ("dvr_shaded", 1), ("iso", 2), ("mip", 3)];

/// The yardstick: one pipeline per mode and TF read, over one R8Unorm volume.
pub(crate) struct RawKernel {
    /// `[mode][0 texture TF, 1 storage TF]`.
    pipelines: Vec<[wgpu::ComputePipeline; 2]>,
    layout: wgpu::BindGroupLayout,
    volume: wgpu::TextureView,
    sampler: wgpu::Sampler,
    uniforms: wgpu::Buffer,
    out: wgpu::TextureView,
    counts: wgpu::Buffer,
    readback: wgpu::Buffer,
    size: u32,
    value_scale: f32,
    value_offset: f32,
    dims: [u32; 3],
    bind_group: Option<wgpu::BindGroup>,
    tf_count: f32,
}

impl RawKernel {
    pub(crate) fn new(gpu: &GpuContext, vol: &Volume, size: u32) -> Result<RawKernel, String> {
        let brickray_core::VolumeData::U8(bytes) = vol.data() else {
            return Err("the raw kernel samples an R8Unorm texture: a u8 volume".into());
        };
        let dev = &gpu.device;
        let dims = vol.dims();
        let tex = dev.create_texture(&wgpu::TextureDescriptor {
            label: Some("raw volume"),
            size: wgpu::Extent3d {
                width: dims[0],
                height: dims[1],
                depth_or_array_layers: dims[2],
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D3,
            format: wgpu::TextureFormat::R8Unorm,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        gpu.queue.write_texture(
            tex.as_image_copy(),
            bytes,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(dims[0]),
                rows_per_image: Some(dims[1]),
            },
            tex.size(),
        );
        let sampler = dev.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("raw linear"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        let entry = |binding, ty| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty,
            count: None,
        };
        let tex_entry = |d| wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable: true },
            view_dimension: d,
            multisampled: false,
        };
        let buf = |ty| wgpu::BindingType::Buffer {
            ty,
            has_dynamic_offset: false,
            min_binding_size: None,
        };
        let layout = dev.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("raw"),
            entries: &[
                entry(0, buf(wgpu::BufferBindingType::Uniform)),
                entry(1, tex_entry(wgpu::TextureViewDimension::D3)),
                entry(
                    2,
                    wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                ),
                entry(3, tex_entry(wgpu::TextureViewDimension::D2)),
                entry(4, buf(wgpu::BufferBindingType::Storage { read_only: true })),
                entry(
                    5,
                    wgpu::BindingType::StorageTexture {
                        access: wgpu::StorageTextureAccess::WriteOnly,
                        format: wgpu::TextureFormat::Rgba16Float,
                        view_dimension: wgpu::TextureViewDimension::D2,
                    },
                ),
                entry(
                    6,
                    buf(wgpu::BufferBindingType::Storage { read_only: false }),
                ),
            ],
        });
        let pl = dev.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("raw"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let module = dev.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("raw.wgsl"),
            source: wgpu::ShaderSource::Wgsl(SOURCE.into()),
        });
        let pipelines = MODES
            .iter()
            .map(|&(_, mode)| {
                [true, false].map(|texture| {
                    dev.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                        label: Some("raw"),
                        layout: Some(&pl),
                        module: &module,
                        entry_point: Some("main"),
                        compilation_options: wgpu::PipelineCompilationOptions {
                            constants: &[
                                ("MODE", mode as f64),
                                ("TF_TEXTURE", if texture { 1.0 } else { 0.0 }),
                            ],
                            ..Default::default()
                        },
                        cache: None,
                    })
                })
            })
            .collect();
        let out = dev
            .create_texture(&wgpu::TextureDescriptor {
                label: Some("raw out"),
                size: wgpu::Extent3d {
                    width: size,
                    height: size,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: wgpu::TextureFormat::Rgba16Float,
                usage: wgpu::TextureUsages::STORAGE_BINDING,
                view_formats: &[],
            })
            .create_view(&Default::default());
        let count_bytes = size as u64 * size as u64 * 4;
        let counts = dev.create_buffer(&wgpu::BufferDescriptor {
            label: Some("raw counts"),
            size: count_bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let readback = dev.create_buffer(&wgpu::BufferDescriptor {
            label: Some("raw counts readback"),
            size: count_bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let uniforms = dev.create_buffer(&wgpu::BufferDescriptor {
            label: Some("raw uniforms"),
            size: std::mem::size_of::<RawUniforms>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let value_offset = vol.desc().normalize(0.0);
        Ok(RawKernel {
            pipelines,
            layout,
            volume: tex.create_view(&Default::default()),
            sampler,
            uniforms,
            out,
            counts,
            readback,
            size,
            value_scale: vol.desc().normalize(255.0) - value_offset,
            value_offset,
            dims,
            bind_group: None,
            tf_count: 0.0,
        })
    }

    /// Sets the transfer function: `entries` (brickray's corrected table, one
    /// row: opacity already corrected to the step) as a filtered `Rgba16Float`
    /// row and as a storage buffer.
    pub(crate) fn set_tf(&mut self, gpu: &GpuContext, entries: &[[f32; 4]]) {
        let dev = &gpu.device;
        let n = entries.len() as u32;
        let tex = dev.create_texture(&wgpu::TextureDescriptor {
            label: Some("raw tf"),
            size: wgpu::Extent3d {
                width: n,
                height: 1,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba16Float,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        let halfs: Vec<u16> = entries
            .iter()
            .flatten()
            .map(|&x| half::f16::from_f32(x).to_bits())
            .collect();
        gpu.queue.write_texture(
            tex.as_image_copy(),
            bytemuck::cast_slice(&halfs),
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(n * 8),
                rows_per_image: None,
            },
            tex.size(),
        );
        let buffer = dev.create_buffer(&wgpu::BufferDescriptor {
            label: Some("raw tf buffer"),
            size: n as u64 * 16,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        gpu.queue
            .write_buffer(&buffer, 0, bytemuck::cast_slice(entries));
        let view = tex.create_view(&Default::default());
        self.bind_group = Some(dev.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("raw"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: self.uniforms.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&self.volume),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::Sampler(&self.sampler),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: wgpu::BindingResource::TextureView(&view),
                },
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: buffer.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 5,
                    resource: wgpu::BindingResource::TextureView(&self.out),
                },
                wgpu::BindGroupEntry {
                    binding: 6,
                    resource: self.counts.as_entire_binding(),
                },
            ],
        }));
        self.tf_count = n as f32;
    }

    /// Sets the view: brickray's rays (`Camera::rays`, origin on the near plane)
    /// in texture space, and its sample spacing. The volume's frame must scale
    /// uniformly (a cube of voxels with equal spacing), so that texture-space
    /// distances are world distances times one factor.
    pub(crate) fn set_view(
        &self,
        gpu: &GpuContext,
        camera: &Camera,
        frame: &VolumeFrame,
        step_factor: f32,
        isovalue: f32,
        refine_steps: u32,
    ) -> Result<(), String> {
        let rays = camera.rays(1.0);
        let inv = frame.model.as_dmat4().inverse();
        let scales = [DVec3::X, DVec3::Y, DVec3::Z].map(|a| inv.transform_vector3(a).length());
        if (scales[0] - scales[1]).abs() > 1e-9 * scales[0]
            || (scales[0] - scales[2]).abs() > 1e-9 * scales[0]
        {
            return Err("the raw kernel needs a uniformly scaled volume frame".into());
        }
        let tex = |v: DVec3| inv.transform_vector3(v).as_vec3().to_array();
        let dt = step_factor as f64 * frame.voxel_world as f64 * scales[0];
        let u = RawUniforms {
            eye: inv.transform_point3(rays.eye).as_vec3().to_array(),
            near: rays.near as f32,
            fwd: tex(rays.fwd),
            dt: dt as f32,
            right: tex(rays.right),
            persp: if rays.perspective { 1.0 } else { 0.0 },
            up: tex(rays.up),
            isovalue,
            size: [self.size; 2],
            refine_steps,
            value_scale: self.value_scale,
            dims: self.dims.map(|d| d as f32),
            tf_count: self.tf_count,
            value_offset: self.value_offset,
            pad: [0.0; 3],
        };
        gpu.queue
            .write_buffer(&self.uniforms, 0, bytemuck::bytes_of(&u));
        Ok(())
    }

    /// One dispatch, submitted and waited for: wall ms, the process's CPU ms,
    /// and with `count` the samples of all rays and their SIMD lane-bound count
    /// (read back, not timed).
    pub(crate) fn run(
        &self,
        gpu: &GpuContext,
        mode: usize,
        texture_tf: bool,
        count: bool,
    ) -> (f64, f64, u64, u64) {
        let bind_group = self.bind_group.as_ref().expect("set_tf first");
        let cpu0 = crate::runner::process_cpu_ms();
        let t = Instant::now();
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            pass.set_pipeline(&self.pipelines[mode][usize::from(!texture_tf)]);
            pass.set_bind_group(0, bind_group, &[]);
            let groups = self.size.div_ceil(8);
            pass.dispatch_workgroups(groups, groups, 1);
        }
        gpu.submit_wait(enc);
        let ms = t.elapsed().as_secs_f64() * 1e3;
        let cpu_ms = crate::runner::process_cpu_ms() - cpu0;
        if !count {
            return (ms, cpu_ms, 0, 0);
        }
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(&self.counts, 0, &self.readback, 0, None);
        gpu.submit_wait(enc);
        let slice = self.readback.slice(..);
        slice.map_async(wgpu::MapMode::Read, |_| {});
        let _ = gpu.device.poll(wgpu::PollType::wait_indefinitely());
        let counts: Vec<u32> = {
            let data = slice.get_mapped_range().expect("mapped counts");
            data.chunks_exact(4)
                .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect()
        };
        self.readback.unmap();
        let total = counts.iter().map(|&c| c as u64).sum();
        (
            ms,
            cpu_ms,
            total,
            crate::runner::lane_samples(&counts, self.size as usize),
        )
    }
}

#[cfg(test)]
mod tests {
    /// The kernel is valid WGSL and its uniform struct matches the Rust side in
    /// size (the permutations are override constants of one module; every run of
    /// the suite compiles all eight pipelines).
    #[test]
    fn raw_kernel_validates() {
        let module = naga::front::wgsl::parse_str(super::SOURCE).expect("parse raw.wgsl");
        naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::all(),
        )
        .validate(&module)
        .expect("validate raw.wgsl");
        let span = module
            .types
            .iter()
            .find_map(|(_, t)| match (&t.name, &t.inner) {
                (Some(n), naga::TypeInner::Struct { span, .. }) if n == "Raw" => Some(*span),
                _ => None,
            })
            .expect("struct Raw");
        assert_eq!(span as usize, std::mem::size_of::<super::RawUniforms>());
        let overrides: Vec<_> = module
            .overrides
            .iter()
            .filter_map(|(_, o)| o.name.clone())
            .collect();
        assert_eq!(overrides, ["MODE", "TF_TEXTURE"]);
    }
}
