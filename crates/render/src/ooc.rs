//! The out-of-core path (Gobbetti et al. 2008): a [`BrickManager`] plans each
//! frame's cut and uploads; this module owns their GPU side — the brick atlas (one
//! preallocated 3D texture of slots), the per-slot table, and the index buffer
//! (the octree with ropes over the cut) — and the ray-cast pipeline that walks it.

use crate::error::RenderError;
use crate::gpu_volume::SampleEncoding;
use brickray_cache::{BrickManager, FrameStats as CacheStats, LeafKind, ManagerConfig};
use brickray_core::{BrickSource, OctreeLayout, TransferFunction, VolumeFrame};
use std::sync::Arc;
use std::time::Instant;

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
    /// Milliseconds spent converting and writing bricks.
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

/// Normalized min/max of each of a brick's `n^3` sub-cells (x fastest). Cell `j`
/// covers the brick-local edge coordinates `[j B/n, (j+1) B/n]` (B interior
/// voxels); a trilinear sample there reads voxel centres `floor(e - 0.5)` and the
/// next, so the range covers those, offset by the apron and clamped to the brick.
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
        // A malformed brick: never skip it.
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

#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
struct SlotInfo {
    offset: [f32; 4],
    range: [f32; 4],
}

/// The GPU side of an out-of-core volume.
pub(crate) struct OocVolume {
    pub(crate) manager: BrickManager,
    pub(crate) layout: OctreeLayout,
    source: Arc<dyn BrickSource>,
    atlas: wgpu::Texture,
    pub(crate) atlas_view: wgpu::TextureView,
    pub(crate) atlas_dims: [u32; 3],
    pub(crate) encoding: SampleEncoding,
    pub(crate) slots: wgpu::Buffer,
    slots_cpu: Vec<SlotInfo>,
    /// Sub-cell ranges of every slot (`sub_n^3` per slot).
    pub(crate) sub_cells: wgpu::Buffer,
    pub(crate) sub_n: u32,
    slots_dirty: bool,
    pub(crate) index: crate::GrowBuffer,
    frame: u64,
    pub(crate) stats: OutOfCoreStats,
    frame_of_world: VolumeFrame,
}

impl std::fmt::Debug for OocVolume {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OocVolume")
            .field("dims", &self.layout.volume.dims)
            .field("levels", &self.layout.levels)
            .field("atlas_dims", &self.atlas_dims)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl OocVolume {
    pub(crate) fn new(
        device: &wgpu::Device,
        source: Arc<dyn BrickSource>,
        frame: VolumeFrame,
        config: OutOfCoreConfig,
    ) -> Result<OocVolume, RenderError> {
        let layout = source.layout().clone();
        let limits = device.limits();
        let encoding = SampleEncoding::choose(
            layout.volume.dtype,
            layout.volume.value_range,
            device.features(),
        );
        let manager = BrickManager::new(
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
        )
        .map_err(|e| RenderError::OutOfCore(e.to_string()))?;
        let mut manager = manager;
        // The root is read now (set-up time, not the frame path), so the first
        // frame already shows a coarse image.
        manager
            .preload_root()
            .map_err(|e| RenderError::OutOfCore(e.to_string()))?;
        let atlas_dims = manager.pool().atlas_dims();
        let atlas = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("brickray-render brick atlas"),
            size: wgpu::Extent3d {
                width: atlas_dims[0],
                height: atlas_dims[1],
                depth_or_array_layers: atlas_dims[2],
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D3,
            format: encoding.format,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        let slot_count = manager.pool().slot_count() as usize;
        let slots_size = (slot_count.max(1) * std::mem::size_of::<SlotInfo>()) as u64;
        let slots = crate::storage_buffer(device, "brick slot table", slots_size)?;
        let sub_n = sub_cells_per_axis(layout.brick);
        let sub_size = (slot_count.max(1) as u64) * (sub_n as u64).pow(3) * 8;
        let sub_cells = crate::storage_buffer(device, "brick sub-cell table", sub_size)?;
        Ok(OocVolume {
            manager,
            layout,
            source,
            atlas_view: atlas.create_view(&Default::default()),
            atlas,
            atlas_dims,
            encoding,
            slots,
            slots_cpu: vec![
                SlotInfo {
                    offset: [0.0; 4],
                    range: [0.0; 4]
                };
                slot_count.max(1)
            ],
            slots_dirty: true,
            sub_cells,
            sub_n,
            index: crate::GrowBuffer::new(device, "brickray-render octree index", 1 << 12),
            frame: 0,
            stats: OutOfCoreStats::default(),
            frame_of_world: frame,
        })
    }

    /// Plans the frame, uploads what the plan says, encodes the index. Returns the
    /// bytes written and whether the index buffer was reallocated.
    pub(crate) fn update(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        desc: &crate::FrameDesc<'_>,
        tf: &TransferFunction,
    ) -> Result<(u64, bool), RenderError> {
        let (world, camera) = (desc.frame, &desc.camera);
        let (width, height, mode) = (desc.width, desc.height, desc.settings.mode);
        if world != self.frame_of_world {
            self.manager.set_volume_frame(world);
            self.frame_of_world = world;
        }
        self.frame += 1;
        let t = Instant::now();
        let plan = self.manager.update(
            camera,
            width as f32 / height as f32,
            height,
            self.frame,
            mode,
            tf,
        );
        let refine_ms = t.elapsed().as_secs_f64() * 1e3;

        let t = Instant::now();
        let side = self.layout.stored_side();
        let bpp = self.encoding.texel_bytes();
        let mut bytes = 0u64;
        for up in &plan.uploads {
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
            bytes += (self.slots_cpu.len() * std::mem::size_of::<SlotInfo>()) as u64;
            self.slots_dirty = false;
        }
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
        let index = brickray_index::encode_cut(&leaves)
            .map_err(|e| RenderError::OutOfCore(e.to_string()))?;
        let words = index.words();
        let (written, grew) = self.index.write(device, queue, bytemuck::cast_slice(words));
        bytes += written;
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
        Ok((bytes, grew))
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
            // A point in brick-local edge coordinates [0, B]^3.
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
