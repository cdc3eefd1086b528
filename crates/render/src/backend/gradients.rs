//! Per-voxel gradients computed on the GPU (`shaders/gradients.wgsl`), so
//! that the kernels shade a sample with one filtered read instead of six
//! (`GRADIENTS` in modes.wgsl; docs/rendering-model.md, *Shading*): of an
//! in-core volume once, when a shaded DVR frame first needs them; of a
//! streamed volume that keeps them (`VolumeOptions::gradients`), for each
//! brick as it is uploaded into the atlas.

use crate::error::RenderError;
use crate::gpu::{self, Uniform};

/// How the in-core kernel takes the gradient that shades a DVR sample
/// ([`RendererOptions::gradients`](crate::RendererOptions::gradients)). Out
/// of core the streamed volume decides: six reads, or one read of the
/// gradients it keeps with
/// [`VolumeOptions::gradients`](crate::VolumeOptions::gradients).
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
/// written (2), the boxes' origins (3).
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
        gpu::storage_entry(3, true),
    ]
}

/// Boxes one dispatch covers at most: its z runs over their slices (within
/// WebGPU's 65,535 workgroups a dimension for boxes of up to 36 texels), and
/// each dispatch's origins start at a multiple of 256 bytes (the storage
/// binding's offset alignment).
fn boxes_per_dispatch(box_depth: u32, max_workgroups: u32, align: u32) -> usize {
    let by_dispatch = (max_workgroups / box_depth.max(1)).max(1) as usize;
    let per_align = (align as usize / ORIGIN_BYTES).max(1);
    (by_dispatch / per_align * per_align).max(per_align)
}

/// Bytes of one box's origin (`vec4<u32>`).
const ORIGIN_BYTES: usize = 16;

/// The gradients pass (gradients.wgsl): its pipeline, parameters and the
/// boxes' origins, kept by their owner (the in-core volume makes one once,
/// a streamed volume keeps one for its uploads).
pub(crate) struct GradientPass {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
    params: Uniform<GradientParams>,
    origins: gpu::GrowBuffer,
}

impl std::fmt::Debug for GradientPass {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GradientPass").finish_non_exhaustive()
    }
}

impl GradientPass {
    pub(crate) fn new(device: &wgpu::Device) -> Result<GradientPass, RenderError> {
        let label = "brickray-render gradients";
        let (layout, pipeline) =
            gpu::single_group_pipeline(device, label, &layout_entries(), WGSL)?;
        Ok(GradientPass {
            layout,
            pipeline,
            params: Uniform::new(device, "brickray-render gradient params")?,
            origins: gpu::GrowBuffer::new(device, "brickray-render gradient boxes", 256)?,
        })
    }

    /// Records into `encoder` the passes that fill `out` with the gradients
    /// of `source` (normalized as `texel * scale + offset`) over the boxes of
    /// `dims` texels at `origins` (the same texels in both textures).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn record(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        source: &wgpu::TextureView,
        out: &wgpu::TextureView,
        dims: [u32; 3],
        scale_offset: [f32; 2],
        origins: &[[u32; 3]],
    ) -> Result<(), RenderError> {
        if origins.is_empty() {
            return Ok(());
        }
        self.params.write(
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
        let words: Vec<[u32; 4]> = origins.iter().map(|o| [o[0], o[1], o[2], 0]).collect();
        self.origins
            .write(device, queue, bytemuck::cast_slice(&words))?;
        let l = device.limits();
        let per = boxes_per_dispatch(
            dims[2],
            l.max_compute_workgroups_per_dimension,
            l.min_storage_buffer_offset_alignment,
        );
        let label = "brickray-render gradients";
        let groups = gpu::scoped(device, label, || {
            (0..origins.len())
                .step_by(per)
                .map(|first| {
                    let n = per.min(origins.len() - first);
                    let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
                        label: Some(label),
                        layout: &self.layout,
                        entries: &[
                            wgpu::BindGroupEntry {
                                binding: 0,
                                resource: wgpu::BindingResource::TextureView(source),
                            },
                            wgpu::BindGroupEntry {
                                binding: 1,
                                resource: self.params.buffer.as_entire_binding(),
                            },
                            wgpu::BindGroupEntry {
                                binding: 2,
                                resource: wgpu::BindingResource::TextureView(out),
                            },
                            wgpu::BindGroupEntry {
                                binding: 3,
                                resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                                    buffer: &self.origins.buffer,
                                    offset: (first * ORIGIN_BYTES) as u64,
                                    size: wgpu::BufferSize::new((n * ORIGIN_BYTES) as u64),
                                }),
                            },
                        ],
                    });
                    (group, n as u32)
                })
                .collect::<Vec<_>>()
        })?;
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some(label),
            timestamp_writes: None,
        });
        pass.set_pipeline(&self.pipeline);
        for (group, n) in &groups {
            pass.set_bind_group(0, group, &[]);
            pass.dispatch_workgroups(
                dims[0].div_ceil(gpu::WORKGROUP[0]),
                dims[1].div_ceil(gpu::WORKGROUP[1]),
                dims[2] * n,
            );
        }
        Ok(())
    }
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
    let texture = storage_3d(device, dims, "brickray-render gradients")?;
    let out = texture.create_view(&Default::default());
    record(device, queue, encoder, volume, &out, dims, scale_offset)?;
    Ok(texture)
}

/// Records into `encoder` the pass that fills `out` with the gradients of the
/// whole volume `volume` (as [`compute`]).
pub(crate) fn record(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    encoder: &mut wgpu::CommandEncoder,
    volume: &wgpu::TextureView,
    out: &wgpu::TextureView,
    dims: [u32; 3],
    scale_offset: [f32; 2],
) -> Result<(), RenderError> {
    GradientPass::new(device)?.record(
        device,
        queue,
        encoder,
        volume,
        out,
        dims,
        scale_offset,
        &[[0; 3]],
    )
}

/// A texture of gradients that the pass writes and the kernels sample.
pub(crate) fn storage_3d(
    device: &wgpu::Device,
    dims: [u32; 3],
    label: &'static str,
) -> Result<wgpu::Texture, RenderError> {
    gpu::texture_3d(
        device,
        dims,
        FORMAT,
        wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::STORAGE_BINDING,
        label,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each dispatch's boxes stay within the workgroup limit and start at an
    /// aligned offset.
    #[test]
    fn dispatches_fit_the_limits() {
        for (depth, max, align) in [
            (36u32, 65_535u32, 256u32),
            (20, 65_535, 256),
            (36, 1000, 64),
            (1, 65_535, 256),
        ] {
            let per = boxes_per_dispatch(depth, max, align);
            assert!(
                per as u64 * depth as u64 <= max as u64,
                "{depth} {max} {align}: {per}"
            );
            assert_eq!(per * ORIGIN_BYTES % align as usize, 0);
            assert!(per * ORIGIN_BYTES >= align as usize);
        }
    }
}
