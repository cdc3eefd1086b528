//! The in-core backend: the whole volume in one 3D texture plus its min/max
//! macro-cell grid (Krueger and Westermann 2003), and its group 2.

use super::VolumeBackend;
use super::gradients;
use super::readback::{Outcome, Submission};
use crate::encoding::{self, SampleEncoding, U8Filtering};
use crate::error::RenderError;
use crate::gpu::{self, Uniform};
use crate::group2::{
    INCORE_SAMPLED_TEXTURES as SAMPLED_TEXTURES, INCORE_STORAGE_BUFFERS as STORAGE_BUFFERS,
    check_stage_limits, volume_layout_entries, volume_sampler,
};
use crate::kernels::KernelKind;
use brickray_core::{MacroCellGrid, RenderMode, TransferFunction, Volume};

/// Macro-cell size in voxels for empty-space skipping.
pub(crate) const CELL: u32 = 8;

/// The largest jump of the skip distances, in cells: bounds the host's work
/// when the transfer function or isovalue changes (O(cells * SKIP_CAP)).
pub(crate) const SKIP_CAP: u32 = 8;

/// What the skip distances were computed for.
#[derive(Debug, Clone, Copy, PartialEq)]
enum SkipKey {
    /// DVR: cells transparent through the TF of this generation.
    Dvr(u64),
    /// Iso: cells whose values all lie below this isovalue.
    Iso(f32),
}

/// `struct VolumeParams` of incore.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct VolumeParams {
    pub(crate) dims: [f32; 3],
    pub(crate) value_scale: f32,
    pub(crate) cells: [u32; 3],
    pub(crate) cell_size: u32,
    pub(crate) value_offset: f32,
    pub(crate) pad0: f32,
    pub(crate) pad1: f32,
    pub(crate) pad2: f32,
}

/// A volume resident on the GPU.
#[derive(Debug)]
pub(crate) struct InCore {
    layout: wgpu::BindGroupLayout,
    bind_group: wgpu::BindGroup,
    /// What group 2 binds besides the gradients (rebound when they are made).
    parts: Parts,
    /// The per-voxel gradients (`backend/gradients.rs`), once a shaded DVR
    /// frame asked for them; `Unavailable` where they do not fit.
    gradients: GradientState,
    format: wgpu::TextureFormat,
    bytes: u64,
    /// The min/max grid, kept to derive skip distances for each TF / isovalue.
    grid: MacroCellGrid,
    skip_key: Option<SkipKey>,
    labels: bool,
    /// The share of macro cells MIP's skipping is certain to skip
    /// (`MacroCellGrid::mip_skip_share`, compared with
    /// `brickray_core::MIP_SKIP_SHARE_MIN` at the frame's step); `None`:
    /// always skip (`SkipRule::Always`).
    mip_share: Option<f64>,
    /// When DVR skips, and the share of macro cells transparent through the
    /// current transfer function (found with the skip distances, `update`;
    /// compared with the frame's rule, `brickray_core::dvr_skip_share_min`,
    /// shaded or not); `None`: always
    /// skip (`SkipRule::Always`, or a label map's hidden labels).
    dvr_rule: crate::SkipRule,
    dvr_share: Option<f64>,
}

/// Group 2's resources other than the gradients.
#[derive(Debug)]
struct Parts {
    params: Uniform<VolumeParams>,
    view: wgpu::TextureView,
    sampler: wgpu::Sampler,
    cell_ranges: wgpu::Buffer,
    skip: wgpu::Buffer,
    dims: [u32; 3],
    /// normalized = texel * scale + offset.
    scale_offset: [f32; 2],
}

/// The gradients of an in-core volume.
#[derive(Debug)]
enum GradientState {
    /// Not asked for yet: group 2 binds a 1x1x1 stand-in.
    NotMade,
    /// Made and bound (the texture is owned here; group 2 holds its view);
    /// `run` watches the host encoder the pass that fills it went into (a
    /// dropped one's pass is recorded again).
    Made {
        texture: wgpu::Texture,
        run: Submission,
    },
    /// Turned off, a label map, or too large (`gradients::fit`).
    Unavailable,
}

/// The binding of the gradients in group 2 (incore.wgsl).
pub(crate) const GRADIENT_BINDING: u32 = 5;

/// The layout of the in-core group 2: the volume entries, the macro cells'
/// ranges and skip distances, and the gradients.
pub(crate) fn layout_entries() -> Vec<wgpu::BindGroupLayoutEntry> {
    let mut e = volume_layout_entries(STORAGE_BUFFERS);
    e.push(crate::group2::texture_3d_entry(GRADIENT_BINDING));
    e
}

impl Parts {
    /// Group 2 with `gradients` bound.
    fn bind(
        &self,
        device: &wgpu::Device,
        layout: &wgpu::BindGroupLayout,
        gradients: &wgpu::TextureView,
    ) -> Result<wgpu::BindGroup, RenderError> {
        gpu::scoped(device, "brickray-render in-core bind group", || {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("brickray-render in core"),
                layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: self.params.buffer.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: wgpu::BindingResource::TextureView(&self.view),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: wgpu::BindingResource::Sampler(&self.sampler),
                    },
                    wgpu::BindGroupEntry {
                        binding: 3,
                        resource: self.cell_ranges.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 4,
                        resource: self.skip.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: GRADIENT_BINDING,
                        resource: wgpu::BindingResource::TextureView(gradients),
                    },
                ],
            })
        })
    }
}

impl InCore {
    /// Uploads `vol` (in slabs of at most 64 MiB) and its macro-cell grid.
    pub(crate) fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        vol: &Volume,
        u8: U8Filtering,
        want_gradients: bool,
        mip_skipping: crate::SkipRule,
        dvr_rule: crate::SkipRule,
    ) -> Result<InCore, RenderError> {
        check_stage_limits(device, STORAGE_BUFFERS)?;
        gpu::need(
            "max_sampled_textures_per_shader_stage",
            SAMPLED_TEXTURES as u64,
            device.limits().max_sampled_textures_per_shader_stage as u64,
        )?;
        let dims = vol.dims();
        let limit = device.limits().max_texture_dimension_3d;
        if dims.iter().any(|&d| d > limit) {
            return Err(RenderError::VolumeTooLarge { dims, limit });
        }
        let desc = vol.desc();
        let enc = SampleEncoding::for_volume(desc, encoding::caps(device), u8);
        let (texture, bytes) =
            gpu::volume_texture(device, queue, vol, &enc, "brickray-render volume")?;
        let format = texture.format();
        let grid = MacroCellGrid::build(vol, CELL);
        let ranges: &[u8] = bytemuck::cast_slice(&grid.ranges);
        let cell_ranges = gpu::storage_buffer(
            device,
            "brickray-render macro-cell ranges",
            ranges.len() as u64,
        )?;
        queue.write_buffer(&cell_ranges, 0, ranges);
        let skip = gpu::storage_buffer(
            device,
            "brickray-render macro-cell skip distances",
            grid.ranges.len() as u64 * 4,
        )?;
        let mut params = Uniform::<VolumeParams>::new(device, "brickray-render volume params")?;
        params.write(
            queue,
            VolumeParams {
                dims: dims.map(|d| d as f32),
                value_scale: enc.scale,
                cells: grid.dims,
                cell_size: CELL,
                value_offset: enc.offset,
                pad0: 0.0,
                pad1: 0.0,
                pad2: 0.0,
            },
        );
        let labels = desc.kind.is_labels();
        let sampler = volume_sampler(device, labels)?;
        let layout = gpu::scoped(device, "brickray-render in-core layout", || {
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("brickray-render in core"),
                entries: &layout_entries(),
            })
        })?;
        let parts = Parts {
            params,
            view: texture.create_view(&Default::default()),
            sampler,
            cell_ranges,
            skip,
            dims,
            scale_offset: [enc.scale, enc.offset],
        };
        let stand_in = gpu::sampled_3d(
            device,
            [1; 3],
            gradients::FORMAT,
            "brickray-render gradients stand-in",
        )?;
        let bind_group = parts.bind(device, &layout, &stand_in.create_view(&Default::default()))?;
        let gradients = if labels || !want_gradients || !gradients::fit(device, dims) {
            GradientState::Unavailable
        } else {
            GradientState::NotMade
        };
        Ok(InCore {
            layout,
            bind_group,
            parts,
            gradients,
            format,
            bytes,
            skip_key: None,
            labels,
            mip_share: (mip_skipping == crate::SkipRule::WherePays).then(|| grid.mip_skip_share()),
            dvr_rule,
            dvr_share: None,
            grid,
        })
    }
}

impl InCore {
    /// Keeps the skip distances current for the frame's mode: the volume was
    /// uploaded at set-up; only they follow the TF (DVR, `tf` of generation
    /// `tf_generation`) or the isovalue (kept current whatever the switches,
    /// since the prediction buffer's sparse traversal skips with them too).
    /// Returns the bytes written.
    pub(crate) fn update(
        &mut self,
        queue: &wgpu::Queue,
        mode: RenderMode,
        tf: &TransferFunction,
        tf_generation: u64,
    ) -> u64 {
        let key = match mode {
            RenderMode::Iso { value, .. } => SkipKey::Iso(value),
            RenderMode::Mip => return 0,
            _ => SkipKey::Dvr(tf_generation),
        };
        if self.skip_key == Some(key) {
            return 0;
        }
        let d = match key {
            SkipKey::Dvr(_) => {
                let d = self
                    .grid
                    .empty_distance(|r| tf.is_transparent(r[0], r[1]), SKIP_CAP);
                // The share of transparent cells decides whether DVR skips
                // (label maps: hidden labels, always).
                let rule = self.dvr_rule == crate::SkipRule::WherePays && !self.labels;
                self.dvr_share = rule.then(|| self.grid.transparent_share(tf));
                d
            }
            SkipKey::Iso(iso) => self.grid.empty_distance(|r| r[1] < iso, SKIP_CAP),
        };
        let bytes: &[u8] = bytemuck::cast_slice(&d);
        queue.write_buffer(&self.parts.skip, 0, bytes);
        self.skip_key = Some(key);
        bytes.len() as u64
    }
}

impl InCore {
    /// Makes the per-voxel gradients when `wanted` (a shaded DVR frame) and
    /// not made yet: the texture, the pass that fills it recorded into
    /// `encoder` ahead of the frame's, and group 2 bound again. (A volume
    /// whose gradients do not fit, `gradients::fit`, was marked unavailable
    /// at set-up and keeps six reads per sample.) They are an acceleration:
    /// where the device refuses them (out of memory, say) the error is
    /// returned for this frame and the volume keeps six reads from then on,
    /// so the next frame draws. If the host dropped the encoder the pass went
    /// into, the next frame that wants them records the pass again.
    pub(crate) fn prepare_gradients(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        wanted: bool,
    ) -> Result<(), RenderError> {
        let p = &self.parts;
        match &mut self.gradients {
            _ if !wanted => Ok(()),
            GradientState::Made { texture, run } if run.outcome() == Outcome::Dropped => {
                let view = texture.create_view(&Default::default());
                let recorded = gradients::record(
                    device,
                    queue,
                    encoder,
                    &p.view,
                    &view,
                    p.dims,
                    p.scale_offset,
                );
                *run = match recorded {
                    Ok(()) => Submission::watch(encoder),
                    Err(_) => Submission::dropped(),
                };
                recorded
            }
            GradientState::NotMade => {
                self.gradients = GradientState::Unavailable;
                let texture =
                    gradients::compute(device, queue, encoder, &p.view, p.dims, p.scale_offset)?;
                let view = texture.create_view(&Default::default());
                self.bind_group = p.bind(device, &self.layout, &view)?;
                self.bytes += gradients::bytes(p.dims);
                self.gradients = GradientState::Made {
                    texture,
                    run: Submission::watch(encoder),
                };
                Ok(())
            }
            _ => Ok(()),
        }
    }
}

impl VolumeBackend for InCore {
    /// Made, or to be made by the first shaded DVR frame before its pass
    /// (`prepare_gradients`), so that `warm_up` compiles the kernel that
    /// frame uses.
    fn gradients(&self) -> bool {
        !matches!(self.gradients, GradientState::Unavailable)
    }

    fn mip_skipping(&self, step: f32) -> bool {
        self.mip_share
            .is_none_or(|share| brickray_core::MIP_SKIP_SHARE_MIN.pays(share, step))
    }

    fn dvr_skipping(&self, step: f32, shaded: bool) -> bool {
        let rule = brickray_core::dvr_skip_share_min(shaded);
        self.dvr_share.is_none_or(|share| rule.pays(share, step))
    }

    fn kind(&self) -> KernelKind {
        KernelKind::InCore
    }

    fn layout(&self) -> &wgpu::BindGroupLayout {
        &self.layout
    }

    fn bind_group(&self) -> &wgpu::BindGroup {
        &self.bind_group
    }

    fn max_leaves(&self) -> u32 {
        0
    }

    fn labels(&self) -> bool {
        self.labels
    }

    fn step_lengths(&self) -> u32 {
        1
    }

    fn wants_redraw(&self) -> bool {
        false
    }

    fn texel_format(&self) -> wgpu::TextureFormat {
        self.format
    }

    fn resident_bytes(&self) -> u64 {
        self.bytes
    }
}
