//! The out-of-core backend (Gobbetti et al. 2008): a [`BrickManager`] plans each
//! frame's cut and its uploads of bricks its loader threads already prepared
//! (texels, sub-cell ranges, range); this owns their GPU side (the brick atlas,
//! one preallocated 3D texture of slots; the slot table; the sub-cell table; the
//! index buffer, the octree with ropes over the cut) and group 2 over them.
//! `update` only writes prepared rows.

mod feedback_loop;

use super::feedback::{FeedbackStats, UsageFeedback, UsageFrame};
use super::occlusion::{OcclusionFeedback, OcclusionStats};
use super::{VolumeBackend, check_stage_limits, volume_layout_entries, volume_sampler};
use crate::desc::FrameDesc;
use crate::encoding::{self, U8Filtering};
use crate::error::{PrepareError, RenderError};
use crate::gpu::{self, GrowBuffer, Uniform};
use crate::kernels::KernelKind;
use brickray_cache::{
    BrickManager, CacheConfig, FadeSlot, FrameStats as CacheStats, GpuFormat, RetryPolicy,
    StreamError, Upload,
};
use brickray_core::{BrickSource, NodeKey, OctreeLayout, TransferFunction, VolumeFrame};
use brickray_visibility::{
    VisibilityConfig, VisibilityCounts, VisibilityPolicy, VisibilityState, VisibleWeights,
};
use feedback_loop::Filter;
use std::sync::Arc;
use std::time::Instant;

/// Read-only storage buffers of group 2: slots, sub-cells, index.
pub(crate) const READ_ONLY_STORAGE: u32 = 3;
/// Storage buffers of group 2: the read-only ones and the usage counters
/// (read-write, binding 6).
pub(crate) const STORAGE_BUFFERS: u32 = READ_ONLY_STORAGE + 1;
/// The binding of the usage counters (`shaders/feedback.wgsl`).
pub(crate) const USAGE_BINDING: u32 = 6;
/// The binding of the stop-depth texture (`shaders/feedback.wgsl`).
pub(crate) const STOP_DEPTH_BINDING: u32 = 7;
/// Storage textures of group 2: the stop depth.
pub(crate) const STORAGE_TEXTURES: u32 = 1;
/// Most occlusion queries per frame (the query set's size).
pub(crate) const QUERIES_PER_FRAME: u32 = 1024;
/// The smallest tile side the scheduler splits to.
const MIN_TILE_PX: u32 = 16;

/// The layout of group 2 out of core: the shared volume entries and the
/// read-write usage counters.
pub(crate) fn layout_entries() -> Vec<wgpu::BindGroupLayoutEntry> {
    let mut e = volume_layout_entries(READ_ONLY_STORAGE);
    e.push(wgpu::BindGroupLayoutEntry {
        binding: USAGE_BINDING,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only: false },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    });
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

/// What the out-of-core path did in the last frame.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct OutOfCoreStats {
    /// The cache's view: working set, pool occupancy, uploads, hit rates,
    /// requests in flight, residency counts, failures.
    pub cache: CacheStats,
    /// Words of the encoded index.
    pub index_words: u32,
    /// Milliseconds spent refining (the manager's update).
    pub refine_ms: f64,
    /// Milliseconds spent writing prepared bricks and tables.
    pub upload_ms: f64,
    /// Milliseconds spent encoding and writing the index.
    pub encode_ms: f64,
    /// True when another frame of this view would not change the image: nothing
    /// in flight or pending, and no brick the view needs has failed
    /// (`cache.converged()`).
    pub converged: bool,
    /// Data leaves of the cut per octree level (level 0 = root; levels past 15
    /// are counted in 15).
    pub data_leaves_per_level: [u32; 16],
    /// The visibility policy in force.
    pub policy: VisibilityPolicy,
    /// The cut's data leaves by visibility (all unobserved without culling).
    pub visibility: VisibilityCounts,
    /// The usage feedback's read-back counters.
    pub feedback: FeedbackStats,
    /// The occlusion queries' schedule and read-back counters.
    pub occlusion: OcclusionStats,
}

/// `range[3]` of a borrowed slot's row ([`FadeSlot::borrowed`]): above 1,
/// ooc.wgsl draws the leaf from the ancestor alone, at the ancestor's step.
const BORROWED_WEIGHT: f32 = 2.0;

/// `struct SlotInfo` of ooc.wgsl: one row of the slot table. `offset[3]`
/// (levels up to the fade fallback, 0: none), `range[2]` (the fallback's slot)
/// and `range[3]` (its weight) carry a level-of-detail fade ([`FadeSlot`]).
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
    pub(crate) splits: [u32; 4],
}

/// The pool's GPU side, sized by the pool's slot grid: the atlas and the
/// per-slot tables (recreated when the GPU budget changes).
struct Pool {
    atlas: wgpu::Texture,
    atlas_view: wgpu::TextureView,
    atlas_bytes: u64,
    slots: wgpu::Buffer,
    slots_cpu: Vec<SlotInfo>,
    slots_dirty: bool,
    sub_cells: wgpu::Buffer,
    /// Slots whose rows carry a fade (cleared before the next frame's fades).
    faded: Vec<u32>,
    /// Usage counters per slot and their read-back ring.
    feedback: UsageFeedback,
}

impl Pool {
    fn new(
        device: &wgpu::Device,
        manager: &BrickManager,
        format: wgpu::TextureFormat,
    ) -> Result<Pool, RenderError> {
        let gpu = manager.gpu_format();
        let dims = manager.pool().atlas_dims();
        let atlas = gpu::texture(
            device,
            &wgpu::TextureDescriptor {
                label: Some("brickray-render brick atlas"),
                size: wgpu::Extent3d {
                    width: dims[0],
                    height: dims[1],
                    depth_or_array_layers: dims[2],
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
            dims.iter().map(|&d| d as u64).product::<u64>() * gpu.encoding.texel_bytes() as u64;
        let slot_count = manager.pool().slot_count().max(1) as usize;
        let rows = Pool::rows(manager);
        let slots = Pool::slot_table(device, rows)?;
        let sub_cells = gpu::storage_buffer(
            device,
            "brickray-render brick sub-cell table",
            slot_count as u64 * (gpu.sub_cells_per_axis as u64).pow(3) * 8,
        )?;
        let feedback = UsageFeedback::new(device, rows as u32, manager.layout())?;
        Ok(Pool {
            feedback,
            atlas_view: atlas.create_view(&Default::default()),
            atlas,
            atlas_bytes,
            slots,
            slots_cpu: vec![bytemuck::Zeroable::zeroed(); rows],
            slots_dirty: true,
            sub_cells,
            faded: Vec::new(),
        })
    }

    /// Rows of the slot table and the usage counters `manager` needs: one a
    /// pool slot, and past them the borrowed slots of octant-granular cuts
    /// (drawn from an ancestor's brick; no atlas space, no sub-cells), only
    /// under `LodMetric::VisibleOctants`.
    fn rows(manager: &BrickManager) -> usize {
        manager.pool().slot_count().max(1) as usize + manager.borrowed_slots() as usize
    }

    fn slot_table(device: &wgpu::Device, rows: usize) -> Result<wgpu::Buffer, RenderError> {
        gpu::storage_buffer(
            device,
            "brickray-render brick slot table",
            (rows * std::mem::size_of::<SlotInfo>()) as u64,
        )
    }

    /// Grows the slot table and the usage counters to what `manager` needs
    /// now (a switch to octant-granular cuts at run time); the atlas and the
    /// pool's slots stay. True when they were recreated (the bind group must
    /// be rebuilt; read-backs in flight are dropped).
    fn ensure_rows(
        &mut self,
        device: &wgpu::Device,
        manager: &BrickManager,
    ) -> Result<bool, RenderError> {
        let rows = Pool::rows(manager);
        if rows <= self.slots_cpu.len() {
            return Ok(false);
        }
        let slots = Pool::slot_table(device, rows)?;
        let feedback = UsageFeedback::new(device, rows as u32, manager.layout())?;
        self.slots = slots;
        self.feedback = feedback;
        self.slots_cpu.resize(rows, bytemuck::Zeroable::zeroed());
        self.slots_dirty = true;
        Ok(true)
    }
}

/// The GPU side of an out-of-core volume.
pub(crate) struct OutOfCore {
    manager: BrickManager,
    layout: OctreeLayout,
    format: wgpu::TextureFormat,
    pool: Pool,
    sampler: wgpu::Sampler,
    params: Uniform<OocParams>,
    index: GrowBuffer,
    group_layout: wgpu::BindGroupLayout,
    bind_group: wgpu::BindGroup,
    frame: u64,
    stats: OutOfCoreStats,
    frame_of_world: VolumeFrame,
    policy: VisibilityPolicy,
    visibility: VisibilityState,
    /// What the image shows of each node (the usage feedback's weights), for
    /// `LodMetric::VisibleError`.
    weights: VisibleWeights,
    /// The view the weights' memory (splits, collapses) is about.
    weights_view: Option<feedback_loop::WeightsView>,
    /// `(slot, node)` of the current cut's data leaves.
    leaves: Vec<(u32, NodeKey)>,
    /// True when the last frame's cut differed from the one before.
    cut_changed: bool,
    occlusion: OcclusionFeedback,
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
        config: CacheConfig,
        u8: U8Filtering,
    ) -> Result<OutOfCore, RenderError> {
        check_stage_limits(device, STORAGE_BUFFERS)?;
        gpu::need(
            "max_storage_textures_per_shader_stage",
            (crate::frame::OUTPUT_FORMATS.len() as u32 + STORAGE_TEXTURES) as u64,
            device.limits().max_storage_textures_per_shader_stage as u64,
        )?;
        let layout = source.layout().clone();
        let gpu_format = GpuFormat::for_layout(
            &layout,
            encoding::caps(device),
            u8,
            std::mem::size_of::<SlotInfo>() as u32,
            device.limits().max_texture_dimension_3d,
        );
        let format = encoding::wgpu_format(gpu_format.encoding.format);
        // Validates the configuration against the layout and the texel format,
        // and sizes the pool within the 3D texture limit, before any GPU object.
        let mut manager = BrickManager::new(source, frame, config, gpu_format)?;
        // The root is read now (set-up time, not the frame path), so the first
        // frame already shows a coarse image.
        manager.preload_root()?;
        let pool = Pool::new(device, &manager, format)?;
        let index = GrowBuffer::new(device, "brickray-render octree index", 1 << 12)?;
        let params = Uniform::new(device, "brickray-render out-of-core params")?;
        let group_layout = gpu::scoped(device, "brickray-render out-of-core layout", || {
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("brickray-render out of core"),
                entries: &layout_entries(),
            })
        })?;
        let sampler = volume_sampler(device)?;
        let occlusion = OcclusionFeedback::new(device, QUERIES_PER_FRAME)?;
        let bind_group = GroupParts {
            layout: &group_layout,
            params: &params.buffer,
            atlas: &pool.atlas_view,
            sampler: &sampler,
            slots: &pool.slots,
            sub_cells: &pool.sub_cells,
            index: &index.buffer,
            usage: &pool.feedback.usage,
            stop: occlusion.stop_view(),
        }
        .bind_group(device)?;
        let weights = VisibleWeights::new(&layout);
        let mut ooc = OutOfCore {
            manager,
            layout,
            format,
            pool,
            sampler,
            params,
            index,
            group_layout,
            bind_group,
            frame: 0,
            stats: OutOfCoreStats::default(),
            frame_of_world: frame,
            policy: VisibilityPolicy::None,
            visibility: VisibilityState::new(VisibilityConfig::default()),
            weights,
            weights_view: None,
            leaves: Vec::new(),
            cut_changed: false,
            occlusion,
        };
        let layout = ooc.layout.clone();
        ooc.visibility.set_layout(&layout);
        ooc.write_params(queue);
        Ok(ooc)
    }

    fn write_params(&mut self, queue: &wgpu::Queue) {
        let l = &self.layout;
        let enc = self.manager.gpu_format().encoding;
        let params = OocParams {
            dims: l.volume.dims.map(|d| d as f32),
            value_scale: enc.scale,
            octree_scale: l.volume_scale().map(|s| s as f32),
            value_offset: enc.offset,
            atlas_size: self.manager.pool().atlas_dims().map(|d| d as f32),
            finest_level: (l.levels - 1) as u32,
            brick: l.brick,
            apron: l.apron,
            stored_side: l.stored_side(),
            sub_cells: self.manager.gpu_format().sub_cells_per_axis,
            splits: {
                let [lo, hi] = brickray_index::Splits::from_layout(l).gpu_words();
                [lo, hi, 0, 0]
            },
        };
        self.params.write(queue, params);
    }

    fn rebuild_bind_group(&mut self, device: &wgpu::Device) -> Result<(), RenderError> {
        self.bind_group = GroupParts {
            layout: &self.group_layout,
            params: &self.params.buffer,
            atlas: &self.pool.atlas_view,
            sampler: &self.sampler,
            slots: &self.pool.slots,
            sub_cells: &self.pool.sub_cells,
            index: &self.index.buffer,
            usage: &self.pool.feedback.usage,
            stop: self.occlusion.stop_view(),
        }
        .bind_group(device)?;
        Ok(())
    }

    /// Statistics of the last frame.
    pub(crate) fn stats(&self) -> OutOfCoreStats {
        self.stats
    }

    /// The brick manager (tolerance, budgets, failures).
    pub(crate) fn manager_mut(&mut self) -> &mut BrickManager {
        &mut self.manager
    }

    /// Sets where refinement's visibility comes from. Switching forgets what
    /// was observed (every node visible again).
    pub(crate) fn set_visibility_policy(&mut self, policy: VisibilityPolicy) {
        if policy != self.policy {
            self.visibility.clear();
            self.policy = policy;
        }
    }

    /// Sets the threshold and hold of the visibility state.
    pub(crate) fn set_visibility_config(&mut self, config: VisibilityConfig) {
        self.visibility.set_config(config);
    }

    /// The latest usage counts read back (whatever the policy).
    pub(crate) fn last_usage(&self) -> Option<&UsageFrame> {
        self.pool.feedback.last.as_ref()
    }

    /// Changes the GPU budget: the pool is re-planned (every slot forgotten)
    /// and the atlas and slot tables recreated at the new size; the next frames
    /// upload the working set again.
    pub(crate) fn set_gpu_budget(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        bytes: u64,
    ) -> Result<(), RenderError> {
        self.manager.set_gpu_budget(bytes)?;
        self.pool = Pool::new(device, &self.manager, self.format)?;
        // Slots are forgotten: so are the observations made through them.
        self.visibility.clear();
        self.weights.clear();
        self.write_params(queue);
        self.rebuild_bind_group(device)
    }

    /// The first failure (metadata or brick read) since the last call, with the
    /// count of further ones.
    pub(crate) fn take_error(&mut self) -> Option<StreamError> {
        self.manager.take_error()
    }

    /// Sets the retry policy of failed bricks (`None`: only on request).
    pub(crate) fn set_retry_policy(&mut self, p: Option<RetryPolicy>) -> Result<(), RenderError> {
        Ok(self.manager.set_retry_policy(p)?)
    }

    /// Writes this frame's uploads, prepared by the loader threads: texels into
    /// the atlas, sub-cell ranges and slot rows into their tables. Returns the
    /// bytes written.
    fn write_uploads(
        &mut self,
        queue: &wgpu::Queue,
        uploads: &[Upload],
        fades: &[FadeSlot],
    ) -> u64 {
        let side = self.layout.stored_side();
        let bpp = self.manager.gpu_format().encoding.texel_bytes();
        let pool = &mut self.pool;
        let mut bytes = 0u64;
        for up in uploads {
            let b = &up.brick;
            queue.write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture: &pool.atlas,
                    mip_level: 0,
                    origin: wgpu::Origin3d {
                        x: up.atlas_offset[0],
                        y: up.atlas_offset[1],
                        z: up.atlas_offset[2],
                    },
                    aspect: wgpu::TextureAspect::All,
                },
                &b.texels,
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
            let cells: &[u8] = bytemuck::cast_slice(&b.sub_cells);
            queue.write_buffer(&pool.sub_cells, up.slot as u64 * cells.len() as u64, cells);
            bytes += (b.texels.len() + cells.len()) as u64;
            if let Some(s) = pool.slots_cpu.get_mut(up.slot as usize) {
                let o = up.atlas_offset;
                *s = SlotInfo {
                    offset: [o[0] as f32, o[1] as f32, o[2] as f32, 0.0],
                    range: [b.range[0], b.range[1], 0.0, 0.0],
                };
                pool.slots_dirty = true;
            }
        }
        // Fades: last frame's cleared, this frame's set (after the uploads,
        // which reset their slots' rows).
        for slot in std::mem::take(&mut pool.faded) {
            if let Some(s) = pool.slots_cpu.get_mut(slot as usize) {
                s.offset[3] = 0.0;
                s.range[2] = 0.0;
                s.range[3] = 0.0;
                pool.slots_dirty = true;
            }
        }
        for f in fades {
            // A borrowed slot's row is its ancestor's (offset, range), drawn
            // from the ancestor alone: weight 2 tells ooc.wgsl.
            if f.borrowed
                && let Some(&lender) = pool.slots_cpu.get(f.fallback as usize)
                && let Some(s) = pool.slots_cpu.get_mut(f.slot as usize)
            {
                *s = lender;
                s.offset[3] = f.levels_up as f32;
                s.range[2] = f.fallback as f32;
                s.range[3] = BORROWED_WEIGHT;
                pool.faded.push(f.slot);
                pool.slots_dirty = true;
                continue;
            }
            if let Some(s) = pool.slots_cpu.get_mut(f.slot as usize) {
                s.offset[3] = f.levels_up as f32;
                s.range[2] = f.fallback as f32;
                s.range[3] = f.weight;
                pool.faded.push(f.slot);
                pool.slots_dirty = true;
            }
        }
        if pool.slots_dirty {
            queue.write_buffer(&pool.slots, 0, bytemuck::cast_slice(&pool.slots_cpu));
            bytes += std::mem::size_of_val(pool.slots_cpu.as_slice()) as u64;
            pool.slots_dirty = false;
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
    usage: &'a wgpu::Buffer,
    stop: &'a wgpu::TextureView,
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
                    wgpu::BindGroupEntry {
                        binding: USAGE_BINDING,
                        resource: self.usage.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: STOP_DEPTH_BINDING,
                        resource: wgpu::BindingResource::TextureView(self.stop),
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
        if self.occlusion.resize(device, [vp.width, vp.height])? {
            self.rebuild_bind_group(device)?;
        }
        // Read-backs of earlier frames (never waits).
        let weighted = self.measures_weights();
        self.observe_feedback(desc, tf, weighted);
        let mut filter = Filter {
            visibility: self.policy.culls().then_some(&mut self.visibility),
            weights: weighted.then_some(&mut self.weights),
        };
        let filter: Option<&mut dyn brickray_cache::SplitFilter> = Some(&mut filter);
        let plan = self.manager.update_filtered(
            &desc.camera,
            vp.aspect() as f32,
            vp.height,
            self.frame,
            desc.settings.mode,
            tf,
            filter,
        );
        let leaves: Vec<(u32, NodeKey)> = plan
            .cut
            .iter()
            .filter_map(|l| l.slot().map(|s| (s, l.key)))
            .collect();
        self.cut_changed = leaves != self.leaves;
        self.leaves = leaves;
        self.note_cut(queue, desc, &plan.refined, weighted);
        if self.pool.ensure_rows(device, &self.manager)? {
            self.rebuild_bind_group(device)?;
        }
        let refine_ms = t.elapsed().as_secs_f64() * 1e3;

        let t = Instant::now();
        let mut bytes = self.write_uploads(queue, &plan.uploads, &plan.fades);
        let upload_ms = t.elapsed().as_secs_f64() * 1e3;

        let t = Instant::now();
        let index = brickray_index::encode_cut_with(
            &plan.cut,
            brickray_index::Splits::from_layout(&self.layout),
        )
        .map_err(RenderError::from)?;
        let words = index.words();
        let (written, grew) = self
            .index
            .write(device, queue, bytemuck::cast_slice(words))?;
        bytes += written;
        if grew {
            self.rebuild_bind_group(device)?;
        }
        let encode_ms = t.elapsed().as_secs_f64() * 1e3;

        let mut per_level = [0u32; 16];
        for l in plan.cut.iter().filter(|l| l.kind.is_data()) {
            per_level[(l.key.level as usize).min(15)] += 1;
        }
        let visibility = self.visibility.counts();
        // With culling, the view has converged only once every leaf was
        // observed and the feedback no longer changes the cut.
        // So has the weighted order, once every leaf's weight was observed.
        let (leaves, weighed) = self.weights.counts();
        let fed_back = self.policy.culls() || weighted;
        let vis_settled = (!self.policy.culls() || visibility.unobserved == 0)
            && (!weighted || weighed == leaves)
            && !(fed_back && self.cut_changed);
        self.stats = OutOfCoreStats {
            cache: plan.stats,
            index_words: words.len() as u32,
            refine_ms,
            upload_ms,
            encode_ms,
            converged: plan.stats.converged() && vis_settled,
            data_leaves_per_level: per_level,
            policy: self.policy,
            visibility,
            feedback: self.pool.feedback.stats,
            occlusion: self.occlusion.stats,
        };
        Ok(bytes)
    }

    fn before_pass(&mut self, encoder: &mut wgpu::CommandEncoder) {
        self.pool.feedback.before_pass(encoder);
    }

    fn after_pass(&mut self, queue: &wgpu::Queue, encoder: &mut wgpu::CommandEncoder) {
        self.pool
            .feedback
            .after_pass(queue, encoder, self.frame, &self.leaves);
        if self.policy.occlusion_queries() {
            self.occlusion.record(queue, encoder, self.frame);
        }
    }

    fn measures_weights(&self) -> bool {
        self.manager.config().lod_metric.uses_visible_weights()
    }

    fn max_leaves(&self) -> u32 {
        // A ray crosses at most about 3 * 2^finest leaves of the finest level,
        // plus zero-length visits at edges: a guard, not a quality setting.
        let finest = (self.layout.levels - 1).min(20) as u32;
        (3u64 << finest).saturating_add(1024).min(1 << 20) as u32
    }

    fn step_lengths(&self) -> u32 {
        self.layout.levels as u32
    }

    fn wants_redraw(&self) -> bool {
        !self.stats.converged
    }

    fn texel_format(&self) -> wgpu::TextureFormat {
        self.format
    }

    fn resident_bytes(&self) -> u64 {
        self.pool.atlas_bytes
    }
}
