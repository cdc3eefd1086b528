//! The out-of-core backend (Gobbetti et al. 2008): a [`BrickManager`] plans each
//! frame's cut and uploads; this owns their GPU side (the brick atlas, one
//! preallocated 3D texture of slots; the per-slot table; the sub-cell table; the
//! index buffer, the octree with ropes over the cut) and group 2 over them.

use super::{VolumeBackend, check_stage_limits, volume_layout_entries, volume_sampler};
use crate::desc::FrameDesc;
use crate::encoding::{self, SampleEncoding, U8Filtering};
use crate::error::{PrepareError, RenderError};
use crate::gpu::{self, GrowBuffer, Uniform};
use crate::kernels::KernelKind;
use brickray_cache::{BrickManager, FrameStats as CacheStats, LeafKind, ManagerConfig};
use brickray_core::{BrickSource, OctreeLayout, TransferFunction, VolumeFrame};
use std::sync::Arc;
use std::time::Instant;

/// Storage buffers of group 2: slots, sub-cells, index.
const STORAGE_BUFFERS: u32 = 3;

/// Budgets and tolerances of the out-of-core path.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OutOfCoreConfig {
    /// System memory for decompressed bricks (the level-2 cache).
    pub cpu_budget_bytes: usize,
    /// GPU memory for the brick atlas.
    pub gpu_budget_bytes: u64,
    /// Bytes uploaded per frame (at least one refinement always goes).
    pub upload_budget_bytes: u64,
    /// Screen-space error tolerance: a brick is refined while one of its voxels
    /// covers more than this many pixels (0 = always the finest level).
    pub tolerance_px: f32,
    /// Loader threads.
    pub loader_threads: usize,
}

impl Default for OutOfCoreConfig {
    fn default() -> Self {
        OutOfCoreConfig {
            cpu_budget_bytes: 512 << 20,
            gpu_budget_bytes: 256 << 20,
            upload_budget_bytes: 16 << 20,
            tolerance_px: 1.0,
            loader_threads: 2,
        }
    }
}

/// What the out-of-core path did in the last frame.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct OutOfCoreStats {
    /// The cache's view: working set, pool occupancy, uploads, hit rates,
    /// requests in flight, residency counts.
    pub cache: CacheStats,
    /// Words of the encoded index.
    pub index_words: u32,
    /// Milliseconds spent refining (the manager's update).
    pub refine_ms: f64,
    /// Milliseconds spent writing prepared bricks and tables.
    pub upload_ms: f64,
    /// Milliseconds spent encoding and writing the index.
    pub encode_ms: f64,
    /// True when nothing is in flight or pending: the image will not change for
    /// this view.
    pub converged: bool,
    /// Data leaves of the cut per octree level (level 0 = root; levels past 15
    /// are counted in 15).
    pub data_leaves_per_level: [u32; 16],
}

/// Sub-cells per brick axis for empty-space skipping inside bricks: cells of
/// about 8 voxels, as the in-core macro cells.
pub(crate) fn sub_cells_per_axis(brick: u32) -> u32 {
    brick.div_ceil(8).max(1)
}

/// Normalized min/max of each of a brick's `n^3` sub-cells (x fastest).
pub(crate) fn sub_cell_ranges(layout: &OctreeLayout, bytes: &[u8], n: u32) -> Vec<[f32; 2]> {
    let side = layout.stored_side() as usize;
    let (b, a) = (layout.brick as f64, layout.apron as i64);
    let d = &layout.volume;
    let vals: Vec<f32> = d
        .dtype
        .decode_le(bytes)
        .into_iter()
        .map(|raw| d.normalize(raw))
        .collect();
    if vals.len() < side * side * side {
        return vec![[f32::NEG_INFINITY, f32::INFINITY]; (n * n * n) as usize];
    }
    let span = |j: u32| -> (usize, usize) {
        let lo = ((j as f64 * b / n as f64 - 0.5).floor() as i64 + a).clamp(0, side as i64 - 1);
        let hi = (((j + 1) as f64 * b / n as f64 - 0.5).floor() as i64 + 1 + a)
            .clamp(0, side as i64 - 1);
        (lo as usize, hi as usize)
    };
    let mut out = Vec::with_capacity((n * n * n) as usize);
    for jz in 0..n {
        let (z0, z1) = span(jz);
        for jy in 0..n {
            let (y0, y1) = span(jy);
            for jx in 0..n {
                let (x0, x1) = span(jx);
                let mut m = [f32::INFINITY, f32::NEG_INFINITY];
                for z in z0..=z1 {
                    for y in y0..=y1 {
                        let row = (z * side + y) * side;
                        for &v in &vals[row + x0..=row + x1] {
                            m = [m[0].min(v), m[1].max(v)];
                        }
                    }
                }
                out.push(m);
            }
        }
    }
    out
}

/// `struct SlotInfo` of ooc.wgsl: one row of the slot table.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct SlotInfo {
    pub(crate) offset: [f32; 4],
    pub(crate) range: [f32; 4],
}

/// `struct OocParams` of ooc.wgsl.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct OocParams {
    pub(crate) dims: [f32; 3],
    pub(crate) value_scale: f32,
    pub(crate) octree_scale: [f32; 3],
    pub(crate) value_offset: f32,
    pub(crate) atlas_size: [f32; 3],
    pub(crate) finest_level: u32,
    pub(crate) brick: u32,
    pub(crate) apron: u32,
    pub(crate) stored_side: u32,
    pub(crate) sub_cells: u32,
}

/// The GPU side of an out-of-core volume.
pub(crate) struct OutOfCore {
    manager: BrickManager,
    layout: OctreeLayout,
    source: Arc<dyn BrickSource>,
    encoding: SampleEncoding,
    format: wgpu::TextureFormat,
    atlas: wgpu::Texture,
    atlas_view: wgpu::TextureView,
    atlas_bytes: u64,
    sampler: wgpu::Sampler,
    params: Uniform<OocParams>,
    slots: wgpu::Buffer,
    slots_cpu: Vec<SlotInfo>,
    slots_dirty: bool,
    sub_cells: wgpu::Buffer,
    sub_n: u32,
    index: GrowBuffer,
    group_layout: wgpu::BindGroupLayout,
    bind_group: wgpu::BindGroup,
    frame: u64,
    stats: OutOfCoreStats,
    frame_of_world: VolumeFrame,
}

impl std::fmt::Debug for OutOfCore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OutOfCore")
            .field("dims", &self.layout.volume.dims)
            .field("levels", &self.layout.levels)
            .field("format", &self.format)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl OutOfCore {
    pub(crate) fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        source: Arc<dyn BrickSource>,
        frame: VolumeFrame,
        config: OutOfCoreConfig,
        u8: U8Filtering,
    ) -> Result<OutOfCore, RenderError> {
        check_stage_limits(device, STORAGE_BUFFERS)?;
        let layout = source.layout().clone();
        let limits = device.limits();
        let encoding = SampleEncoding::choose(
            layout.volume.dtype,
            layout.volume.value_range,
            encoding::caps(device),
            u8,
        );
        let format = encoding::wgpu_format(encoding.format);
        let mut manager = BrickManager::new(
            source.clone(),
            frame,
            ManagerConfig {
                cpu_budget_bytes: config.cpu_budget_bytes,
                gpu_budget_bytes: config.gpu_budget_bytes,
                max_texture_dim_3d: limits.max_texture_dimension_3d,
                upload_budget_bytes: config.upload_budget_bytes,
                tolerance_px: config.tolerance_px,
                loader: brickray_cache::LoaderConfig {
                    workers: config.loader_threads.max(1),
                },
            },
        )?;
        // The root is read now (set-up time, not the frame path), so the first
        // frame already shows a coarse image.
        manager.preload_root()?;
        let atlas_dims = manager.pool().atlas_dims();
        let atlas = gpu::texture(
            device,
            &wgpu::TextureDescriptor {
                label: Some("brickray-render brick atlas"),
                size: wgpu::Extent3d {
                    width: atlas_dims[0],
                    height: atlas_dims[1],
                    depth_or_array_layers: atlas_dims[2],
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D3,
                format,
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                view_formats: &[],
            },
        )?;
        let atlas_bytes =
            atlas_dims.iter().map(|&d| d as u64).product::<u64>() * encoding.texel_bytes() as u64;
        let slot_count = manager.pool().slot_count().max(1) as usize;
        let slots = gpu::storage_buffer(
            device,
            "brickray-render brick slot table",
            (slot_count * std::mem::size_of::<SlotInfo>()) as u64,
        )?;
        let sub_n = sub_cells_per_axis(layout.brick);
        let sub_cells = gpu::storage_buffer(
            device,
            "brickray-render brick sub-cell table",
            slot_count as u64 * (sub_n as u64).pow(3) * 8,
        )?;
        let index = GrowBuffer::new(device, "brickray-render octree index", 1 << 12)?;
        let mut params = Uniform::new(device, "brickray-render out-of-core params")?;
        let sc = layout.volume_scale();
        params.write(
            queue,
            OocParams {
                dims: layout.volume.dims.map(|d| d as f32),
                value_scale: encoding.scale,
                octree_scale: sc.map(|s| s as f32),
                value_offset: encoding.offset,
                atlas_size: atlas_dims.map(|d| d as f32),
                finest_level: (layout.levels - 1) as u32,
                brick: layout.brick,
                apron: layout.apron,
                stored_side: layout.stored_side(),
                sub_cells: sub_n,
            },
        );
        let group_layout = gpu::scoped(device, "brickray-render out-of-core layout", || {
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("brickray-render out of core"),
                entries: &volume_layout_entries(STORAGE_BUFFERS),
            })
        })?;
        let sampler = volume_sampler(device)?;
        let atlas_view = atlas.create_view(&Default::default());
        let parts = GroupParts {
            layout: &group_layout,
            params: &params.buffer,
            atlas: &atlas_view,
            sampler: &sampler,
            slots: &slots,
            sub_cells: &sub_cells,
            index: &index.buffer,
        };
        let bind_group = parts.bind_group(device)?;
        Ok(OutOfCore {
            manager,
            layout,
            source,
            encoding,
            format,
            atlas,
            atlas_view,
            atlas_bytes,
            sampler,
            params,
            slots,
            slots_cpu: vec![
                SlotInfo {
                    offset: [0.0; 4],
                    range: [0.0; 4]
                };
                slot_count
            ],
            slots_dirty: true,
            sub_cells,
            sub_n,
            index,
            group_layout,
            bind_group,
            frame: 0,
            stats: OutOfCoreStats::default(),
            frame_of_world: frame,
        })
    }

    /// Statistics of the last frame.
    pub(crate) fn stats(&self) -> OutOfCoreStats {
        self.stats
    }

    /// The brick manager (budgets, tolerance, failures).
    pub(crate) fn manager_mut(&mut self) -> &mut BrickManager {
        &mut self.manager
    }

    /// Writes this frame's uploads: texels into the atlas, sub-cell ranges and
    /// slot rows into their tables. Returns the bytes written.
    fn write_uploads(&mut self, queue: &wgpu::Queue, uploads: &[brickray_cache::Upload]) -> u64 {
        let side = self.layout.stored_side();
        let bpp = self.encoding.texel_bytes();
        let mut bytes = 0u64;
        for up in uploads {
            let texels = self.encoding.encode(&up.data);
            queue.write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture: &self.atlas,
                    mip_level: 0,
                    origin: wgpu::Origin3d {
                        x: up.atlas_offset[0],
                        y: up.atlas_offset[1],
                        z: up.atlas_offset[2],
                    },
                    aspect: wgpu::TextureAspect::All,
                },
                &texels,
                wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(side * bpp),
                    rows_per_image: Some(side),
                },
                wgpu::Extent3d {
                    width: side,
                    height: side,
                    depth_or_array_layers: side,
                },
            );
            bytes += texels.len() as u64;
            let range = match self.source.node(up.key) {
                Ok(info) => {
                    let d = &self.layout.volume;
                    let (a, b) = (d.normalize(info.min), d.normalize(info.max));
                    [a.min(b), a.max(b)]
                }
                // Unknown: never skip it.
                Err(_) => [f32::NEG_INFINITY, f32::INFINITY],
            };
            let cells = sub_cell_ranges(&self.layout, &up.data, self.sub_n);
            let cell_bytes: &[u8] = bytemuck::cast_slice(&cells);
            queue.write_buffer(
                &self.sub_cells,
                up.slot as u64 * cell_bytes.len() as u64,
                cell_bytes,
            );
            bytes += cell_bytes.len() as u64;
            if let Some(s) = self.slots_cpu.get_mut(up.slot as usize) {
                let o = up.atlas_offset;
                *s = SlotInfo {
                    offset: [o[0] as f32, o[1] as f32, o[2] as f32, 0.0],
                    range: [range[0], range[1], 0.0, 0.0],
                };
                self.slots_dirty = true;
            }
        }
        if self.slots_dirty {
            queue.write_buffer(&self.slots, 0, bytemuck::cast_slice(&self.slots_cpu));
            bytes += std::mem::size_of_val(self.slots_cpu.as_slice()) as u64;
            self.slots_dirty = false;
        }
        bytes
    }
}

/// Everything group 2 binds.
struct GroupParts<'a> {
    layout: &'a wgpu::BindGroupLayout,
    params: &'a wgpu::Buffer,
    atlas: &'a wgpu::TextureView,
    sampler: &'a wgpu::Sampler,
    slots: &'a wgpu::Buffer,
    sub_cells: &'a wgpu::Buffer,
    index: &'a wgpu::Buffer,
}

impl GroupParts<'_> {
    fn bind_group(&self, device: &wgpu::Device) -> Result<wgpu::BindGroup, RenderError> {
        gpu::scoped(device, "brickray-render out-of-core bind group", || {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("brickray-render out of core"),
                layout: self.layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: self.params.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: wgpu::BindingResource::TextureView(self.atlas),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: wgpu::BindingResource::Sampler(self.sampler),
                    },
                    wgpu::BindGroupEntry {
                        binding: 3,
                        resource: self.slots.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 4,
                        resource: self.sub_cells.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 5,
                        resource: self.index.as_entire_binding(),
                    },
                ],
            })
        })
    }
}

impl VolumeBackend for OutOfCore {
    fn kind(&self) -> KernelKind {
        KernelKind::OutOfCore
    }

    fn layout(&self) -> &wgpu::BindGroupLayout {
        &self.group_layout
    }

    fn bind_group(&self) -> &wgpu::BindGroup {
        &self.bind_group
    }

    /// Plans the frame, uploads what the plan says, encodes the index.
    fn update(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        desc: &FrameDesc<'_>,
        tf: &TransferFunction,
    ) -> Result<u64, PrepareError> {
        if desc.frame != self.frame_of_world {
            self.manager.set_volume_frame(desc.frame);
            self.frame_of_world = desc.frame;
        }
        self.frame += 1;
        let vp = desc.viewport;
        let t = Instant::now();
        let plan = self.manager.update(
            &desc.camera,
            vp.aspect() as f32,
            vp.height,
            self.frame,
            desc.settings.mode,
            tf,
        );
        let refine_ms = t.elapsed().as_secs_f64() * 1e3;

        let t = Instant::now();
        let mut bytes = self.write_uploads(queue, &plan.uploads);
        let upload_ms = t.elapsed().as_secs_f64() * 1e3;

        let t = Instant::now();
        let leaves: Vec<(brickray_core::NodeKey, brickray_index::LeafKind)> = plan
            .cut
            .iter()
            .map(|l| {
                let kind = match l.kind {
                    LeafKind::Data { slot } => brickray_index::LeafKind::Data { slot },
                    _ => brickray_index::LeafKind::Empty,
                };
                (l.key, kind)
            })
            .collect();
        let index = brickray_index::encode_cut(&leaves).map_err(RenderError::from)?;
        let words = index.words();
        let (written, grew) = self
            .index
            .write(device, queue, bytemuck::cast_slice(words))?;
        bytes += written;
        if grew {
            self.bind_group = GroupParts {
                layout: &self.group_layout,
                params: &self.params.buffer,
                atlas: &self.atlas_view,
                sampler: &self.sampler,
                slots: &self.slots,
                sub_cells: &self.sub_cells,
                index: &self.index.buffer,
            }
            .bind_group(device)?;
        }
        let encode_ms = t.elapsed().as_secs_f64() * 1e3;

        let mut per_level = [0u32; 16];
        for l in &plan.cut {
            if matches!(l.kind, LeafKind::Data { .. }) {
                per_level[(l.key.level as usize).min(15)] += 1;
            }
        }
        let s = plan.stats;
        let converged =
            s.requests_in_flight == 0 && s.upload_bricks == 0 && s.requested_this_frame == 0;
        self.stats = OutOfCoreStats {
            cache: s,
            index_words: words.len() as u32,
            refine_ms,
            upload_ms,
            encode_ms,
            converged,
            data_leaves_per_level: per_level,
        };
        Ok(bytes)
    }

    fn max_leaves(&self) -> u32 {
        // A ray crosses at most about 3 * 2^finest leaves of the finest level,
        // plus zero-length visits at edges: a guard, not a quality setting.
        let finest = (self.layout.levels - 1).min(20) as u32;
        (3u64 << finest).saturating_add(1024).min(1 << 20) as u32
    }

    fn wants_redraw(&self) -> bool {
        !self.stats.converged
    }

    fn texel_format(&self) -> wgpu::TextureFormat {
        self.format
    }

    fn resident_bytes(&self) -> u64 {
        self.atlas_bytes
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use brickray_core::{DType, VolumeDesc};

    /// Every trilinear sample inside a sub-cell lies within its range.
    #[test]
    fn sub_cell_ranges_are_conservative() {
        let desc = VolumeDesc {
            dims: [64; 3],
            dtype: DType::U8,
            spacing: [1.0; 3],
            value_range: [0.0, 255.0],
        };
        let layout = OctreeLayout::new(desc, 16, 2);
        let side = layout.stored_side() as usize;
        let mut seed = 0x2545_f491_u32;
        let bytes: Vec<u8> = (0..side * side * side)
            .map(|_| {
                seed ^= seed << 13;
                seed ^= seed >> 17;
                seed ^= seed << 5;
                seed as u8
            })
            .collect();
        let n = sub_cells_per_axis(layout.brick);
        assert_eq!(n, 2);
        let r = sub_cell_ranges(&layout, &bytes, n);
        let val = |x: usize, y: usize, z: usize| bytes[(z * side + y) * side + x] as f64 / 255.0;
        let (b, a) = (layout.brick as f64, layout.apron as f64);
        for i in 0..4000 {
            let e: Vec<f64> = (0..3)
                .map(|k| ((i * 7919 + k * 104_729) % 10_007) as f64 / 10_007.0 * b)
                .collect();
            let p: Vec<f64> = e.iter().map(|c| c - 0.5 + a).collect();
            let f: Vec<usize> = p.iter().map(|c| c.floor() as usize).collect();
            let t: Vec<f64> = p.iter().zip(&f).map(|(c, f)| c - *f as f64).collect();
            let mut v = 0.0;
            for dz in 0..2 {
                for dy in 0..2 {
                    for dx in 0..2 {
                        let w = (if dx == 0 { 1.0 - t[0] } else { t[0] })
                            * (if dy == 0 { 1.0 - t[1] } else { t[1] })
                            * (if dz == 0 { 1.0 - t[2] } else { t[2] });
                        v += w * val(f[0] + dx, f[1] + dy, f[2] + dz);
                    }
                }
            }
            let j: Vec<u32> = e
                .iter()
                .map(|c| ((c / (b / n as f64)).floor() as u32).min(n - 1))
                .collect();
            let c = r[((j[2] * n + j[1]) * n + j[0]) as usize];
            assert!(
                v as f32 >= c[0] - 1e-6 && v as f32 <= c[1] + 1e-6,
                "sample {v} outside {c:?}"
            );
        }
    }
}
