//! A streamed volume the host owns ([`StreamedVolume`]): one brick source,
//! its caches, loader and planner (`brickray_cache::Streamer`), and the GPU
//! objects every view of it shares: the brick atlas, the slot and sub-cell
//! tables, the out-of-core parameters and the index over the frame's cut. The
//! host creates it once and hands it to every renderer that draws it, as
//! glyphon's `TextAtlas` is handed to its text renderers; the renderers'
//! `prepare` plans it once per frame for all the views that draw it
//! ([`crate::VolumeRenderer::prepare_views`]). A clone is another handle to
//! the same volume. The pool's GPU objects and the writes of a plan into
//! them are `volume/pool.rs`; this file plans and hands the views what they
//! bind.

use crate::encoding::{self, U8Filtering};
use crate::error::{PrepareError, RenderError};
use crate::gpu::{TableTexture, Uniform};
use crate::planner::Planner;
use brickray_cache::{
    GpuFormat, OutOfCoreConfig, StreamError, StreamFrame, StreamPlan, StreamStats, Streamer,
};
use brickray_core::{BrickSource, NodeKey, OctreeLayout};
use brickray_index::Splits;
use parking_lot::{Mutex, MutexGuard};
use std::sync::Arc;
use std::time::Instant;

mod pool;
use pool::Pool;
pub(crate) use pool::SlotInfo;

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

/// What one plan of the volume gave the views that draw it.
#[derive(Debug, Clone)]
pub(crate) struct Planned {
    pub(crate) plan: StreamPlan,
    /// Words of the encoded index.
    pub(crate) index_words: u32,
    /// Bytes written (bricks, tables, index).
    pub(crate) bytes: u64,
    pub(crate) refine_ms: f64,
    pub(crate) upload_ms: f64,
    pub(crate) encode_ms: f64,
}

/// How a streamed volume stores and plans: chosen at creation.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct VolumeOptions {
    /// How u8 volumes are stored and filtered.
    pub u8_filtering: U8Filtering,
    /// Plan in the background: a worker thread of the volume's own plans
    /// the next frame (refinement, placement, index) while the current one
    /// renders, and `prepare` only applies the latest plan, so the render
    /// thread's cost no longer grows with the cut. A camera move shows one
    /// frame later; the image at convergence is the same. Off by default
    /// (frames planned in `prepare`, deterministic frame by frame). Either
    /// way a frame whose views and classification are those of a converged
    /// plan is not planned again: it draws that plan.
    pub background_planning: bool,
    /// Whether to keep each atlas texel's gradient on the GPU, made from
    /// every brick as it is uploaded, so that shaded DVR reads one texel per
    /// sample instead of six ([`GpuFormat::gradients`];
    /// docs/rendering-model.md, *Shading*). They take 8 bytes per stored
    /// voxel of the GPU budget, so the pool holds fewer bricks (a slot of
    /// t-byte texels costs about (t + 8) / t as much: 5x for 2-byte texels).
    /// By default they are kept when the budget holds every brick of the
    /// volume with them ([`KeepGradients::WhenEveryBrickFits`]). A
    /// multi-channel volume or a label map keeps none.
    pub gradients: KeepGradients,
}

/// Whether a streamed volume keeps its texels' gradients
/// ([`VolumeOptions::gradients`]); [`StreamedVolume::keeps_gradients`] says
/// what was decided.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum KeepGradients {
    /// When the GPU budget ([`OutOfCoreConfig::gpu_budget_bytes`] when the
    /// volume is made) holds a slot, with its gradients, for every brick of
    /// every level ([`GpuFormat::holds_every_brick`]): the pool then never
    /// evicts for room, so the gradients cost no brick a cut could use. A
    /// volume that streams (larger than its budget) shades by six reads.
    #[default]
    WhenEveryBrickFits,
    /// Always: the pool holds fewer bricks, so a cut that needs more than
    /// it holds stays coarser (a trade of bricks for shading time).
    Always,
    /// Never: six reads per shaded sample.
    Never,
}

/// The shared state behind a [`StreamedVolume`].
pub(crate) struct Shared {
    pub(crate) planner: Planner,
    /// What does not change for the volume, or changes only with
    /// `configure`: read without the planner's lock.
    pub(crate) layout: OctreeLayout,
    gpu: GpuFormat,
    config: OutOfCoreConfig,
    /// Rows of the slot table and usage counters the last plan needs.
    pub(crate) slot_rows: u32,
    /// The last applied plan's statistics.
    stats: StreamStats,
    pub(crate) format: wgpu::TextureFormat,
    pool: Pool,
    pub(crate) params: Uniform<OocParams>,
    pub(crate) index: TableTexture,
    pub(crate) sampler: wgpu::Sampler,
    splits: Splits,
    /// Bumped whenever an object a view's bind group holds is recreated.
    pub(crate) generation: u64,
}

impl Shared {
    /// The atlas, slot table, sub-cell table, index and parameters, as the
    /// views' bind groups hold them.
    pub(crate) fn bound(&self) -> Bound<'_> {
        Bound {
            params: &self.params.buffer,
            atlas: &self.pool.atlas_view,
            spread: &self.pool.spread_view,
            gradients: &self.pool.gradients_view,
            sampler: &self.sampler,
            slots: &self.pool.slots.view,
            sub_cells: &self.pool.sub_cells.view,
            index: &self.index.view,
        }
    }

    /// True when the index is an octree (every level splits every axis).
    pub(crate) fn is_octree(&self) -> bool {
        self.splits == Splits::ALL
    }

    /// How the atlas stores the volume.
    pub(crate) fn gpu_format(&self) -> &GpuFormat {
        &self.gpu
    }

    /// Of the sub-cells of the bricks in `leaves` (`(slot, node)`), the
    /// share MIP's skipping is certain to skip within each brick
    /// (`brickray_core::MIP_SKIP_SHARE_MIN_BRICKS`); `None` for a
    /// multi-channel volume, and 0 for no bricks.
    pub(crate) fn mip_skip_share(&self, leaves: &[(u32, NodeKey)]) -> Option<f64> {
        self.pool.mip_skip_share(leaves)
    }

    /// True when DVR's skip rule applies to frames of `mode`: DVR of a
    /// single-channel intensity volume (multi-channel volumes and label maps
    /// always skip).
    pub(crate) fn needs_dvr_rule(&self, mode: brickray_core::RenderMode) -> bool {
        matches!(mode, brickray_core::RenderMode::Dvr) && self.pool.counts_dvr_cells()
    }

    /// Of the sub-cells of the bricks in `leaves` (`(slot, node)`), the
    /// share transparent through `tf` (of generation `generation`); `None`
    /// where the rule does not apply ([`Self::needs_dvr_rule`]).
    pub(crate) fn dvr_transparent_share(
        &mut self,
        leaves: &[(u32, NodeKey)],
        tf: &brickray_core::TransferFunction,
        generation: u64,
    ) -> Option<f64> {
        self.pool.dvr_transparent_share(leaves, tf, generation)
    }

    /// True when the kernel must measure visible weights (the metric ranks
    /// by them).
    pub(crate) fn measures_weights(&self) -> bool {
        self.config.lod_metric.uses_visible_weights()
    }

    fn write_params(&mut self, queue: &wgpu::Queue, atlas_dims: [u32; 3]) {
        let l = &self.layout;
        let gpu = &self.gpu;
        let params = OocParams {
            dims: l.volume.dims.map(|d| d as f32),
            value_scale: gpu.encoding.scale,
            octree_scale: l.volume_scale().map(|s| s as f32),
            value_offset: gpu.encoding.offset,
            atlas_size: atlas_dims.map(|d| d as f32),
            finest_level: (l.levels - 1) as u32,
            brick: l.brick,
            apron: l.apron,
            stored_side: l.stored_side(),
            sub_cells: gpu.sub_cells_per_axis,
            splits: {
                let [lo, hi] = self.splits.gpu_words();
                [lo, hi, 0, 0]
            },
        };
        self.params.write(queue, params);
    }

    /// Plans the frame for its views (or takes the background planner's
    /// latest plan), writes what the plan uploads and the index over its
    /// cut; `None` when no new plan is to be applied this frame (the views
    /// draw the last one). The feedback is what `Planner::add_feedback` kept.
    /// Where the volume keeps gradients, they are made when `shaded_dvr` (a
    /// view draws shaded DVR), for every brick that has none yet.
    pub(crate) fn plan(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        frame: &StreamFrame<'_>,
        shaded_dvr: bool,
    ) -> Result<Option<Planned>, PrepareError> {
        let side = self.layout.stored_side();
        let scale_offset = [self.gpu.encoding.scale, self.gpu.encoding.offset];
        let Some(reply) = self.planner.plan(frame) else {
            self.pool.record_gradients(
                device,
                queue,
                encoder,
                &[],
                shaded_dvr,
                side,
                scale_offset,
            )?;
            return Ok(None);
        };
        if self.pool.ensure_rows(device, reply.slot_rows as usize)? {
            self.generation += 1;
        }
        self.slot_rows = reply.slot_rows;
        let t = Instant::now();
        let bpp = self.gpu.texel_bytes();
        let plan = reply.plan;
        let mut bytes = self
            .pool
            .write(queue, &plan.uploads, &plan.fades, side, bpp);
        self.pool.record_gradients(
            device,
            queue,
            encoder,
            &plan.uploads,
            shaded_dvr,
            side,
            scale_offset,
        )?;
        let words = reply.words.map_err(RenderError::from)?;
        let (written, grew) = self
            .index
            .write(device, queue, bytemuck::cast_slice(&words))?;
        bytes += written;
        if grew {
            self.generation += 1;
        }
        let upload_ms = t.elapsed().as_secs_f64() * 1e3;
        self.stats = plan.stats;
        Ok(Some(Planned {
            index_words: words.len() as u32,
            plan,
            bytes,
            refine_ms: reply.plan_ms,
            upload_ms,
            encode_ms: reply.encode_ms,
        }))
    }
}

/// What a view's group 2 binds of the shared volume.
pub(crate) struct Bound<'a> {
    pub(crate) params: &'a wgpu::Buffer,
    pub(crate) atlas: &'a wgpu::TextureView,
    /// The spread atlas (a 1x1x1 stand-in without spreads).
    pub(crate) spread: &'a wgpu::TextureView,
    /// The gradient atlas (a 1x1x1 stand-in without gradients).
    pub(crate) gradients: &'a wgpu::TextureView,
    pub(crate) sampler: &'a wgpu::Sampler,
    /// The slot and sub-cell tables (`TableTexture`s, Rgba32Float and
    /// Rg32Float).
    pub(crate) slots: &'a wgpu::TextureView,
    pub(crate) sub_cells: &'a wgpu::TextureView,
    /// The index's words (`TableTexture`, R32Uint).
    pub(crate) index: &'a wgpu::TextureView,
}

/// A streamed (out-of-core) volume the host owns and hands to every renderer
/// that draws it (see the module documentation). Out-of-core settings live
/// here, in one [`OutOfCoreConfig`] applied with [`configure`](Self::configure).
#[derive(Clone)]
pub struct StreamedVolume {
    shared: Arc<Mutex<Shared>>,
}

impl std::fmt::Debug for StreamedVolume {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = self.shared.lock();
        f.debug_struct("StreamedVolume")
            .field("dims", &s.layout.volume.dims)
            .field("levels", &s.layout.levels)
            .field("format", &s.format)
            .finish_non_exhaustive()
    }
}

impl StreamedVolume {
    /// A volume streamed from `source` (a brick-octree file store, an
    /// OME-Zarr image, a procedural source) with `config`, stored and planned
    /// as `options` say. Validates the configuration
    /// against the source and the device, sizes the pool within the device's
    /// limits and reads the root (set-up time, not the frame path), so the
    /// first frame already shows a coarse image. Creates no GPU object when a
    /// check fails. Waits for the source at most
    /// [`OutOfCoreConfig::setup_deadline`] (30 s by default): a root that does not
    /// come back by then is [`RenderError::Stream`] with
    /// [`LoadError::TimedOut`](brickray_cache::LoadError::TimedOut).
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        source: Arc<dyn BrickSource>,
        config: OutOfCoreConfig,
        options: VolumeOptions,
    ) -> Result<StreamedVolume, RenderError> {
        crate::group2::check_ooc_limits(device)?;
        let layout = source.layout().clone();
        if layout.is_channel_volume() {
            crate::backend::ooc_channels::check_limits(device)?;
        }
        let mut gpu_format = GpuFormat::for_layout(
            &layout,
            encoding::caps(device),
            options.u8_filtering,
            std::mem::size_of::<SlotInfo>() as u32,
            device.limits().max_texture_dimension_3d,
        );
        // Spreads classify coarse levels of a single-channel intensity
        // volume (a label map's levels are modes; channels carry none).
        gpu_format.spread =
            source.has_spread() && !layout.is_channel_volume() && !layout.volume.kind.is_labels();
        // Gradients shade a single-channel intensity volume.
        gpu_format.gradients = !layout.is_channel_volume()
            && !layout.volume.kind.is_labels()
            && match options.gradients {
                KeepGradients::Always => true,
                KeepGradients::Never => false,
                KeepGradients::WhenEveryBrickFits => GpuFormat {
                    gradients: true,
                    ..gpu_format
                }
                .holds_every_brick(&layout, config.gpu_budget_bytes),
            };
        let format =
            encoding::wgpu_format_lanes(gpu_format.encoding.format, gpu_format.lanes() as usize);
        let mut streamer = Streamer::new(source, config, gpu_format)?;
        streamer.preload_root()?;
        let pool = Pool::new(device, &streamer, format)?;
        let atlas_dims = streamer.pool().atlas_dims();
        let slot_rows = streamer.slot_rows();
        let splits = Splits::from_layout(&layout);
        let planner = Planner::new(streamer, splits, options.background_planning)
            .map_err(|e| RenderError::from(brickray_cache::CacheError::Spawn(e)))?;
        let mut shared = Shared {
            pool,
            params: Uniform::new(device, "brickray-render out-of-core params")?,
            index: TableTexture::new(
                device,
                "brickray-render octree index",
                wgpu::TextureFormat::R32Uint,
                1 << 12,
            )?,
            sampler: crate::group2::volume_sampler(device, layout.volume.kind.is_labels())?,
            splits,
            generation: 0,
            format,
            planner,
            layout,
            gpu: gpu_format,
            config,
            slot_rows,
            stats: StreamStats::default(),
        };
        shared.write_params(queue, atlas_dims);
        Ok(StreamedVolume {
            shared: Arc::new(Mutex::new(shared)),
        })
    }

    pub(crate) fn lock(&self) -> MutexGuard<'_, Shared> {
        self.shared.lock()
    }

    /// True when the volume keeps its texels' gradients
    /// ([`VolumeOptions::gradients`], as decided when it was made).
    pub fn keeps_gradients(&self) -> bool {
        self.lock().gpu.gradients
    }

    /// True when `other` is a handle to the same volume.
    pub fn same(&self, other: &StreamedVolume) -> bool {
        Arc::ptr_eq(&self.shared, &other.shared)
    }

    /// Applies an out-of-core configuration: validated whole first (nothing
    /// changes on error), then only what differs is rebuilt. Budgets other
    /// than the GPU's, the LOD metric and tolerance, fades, retry and the
    /// visibility policy and its settings take effect at the next frame and
    /// upload nothing again; a loader-thread change restarts the loader; a
    /// GPU budget or floor change recreates the atlas and its tables, and the
    /// next frames upload the working set again.
    pub fn configure(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        config: OutOfCoreConfig,
    ) -> Result<(), RenderError> {
        let mut guard = self.shared.lock();
        let s = &mut *guard;
        if s.config == config {
            return Ok(());
        }
        // (Waits for a plan in progress in the background.)
        let streamer = s.planner.streamer.clone();
        let mut st = streamer.lock();
        let old = *st.config();
        let r = st.configure(config)?;
        if r.pool {
            // (The pool's size is within the 3D texture limit by the
            // planner's own check; its tables may still exceed a buffer
            // limit: then the old configuration is put back.)
            let pool = match Pool::new(device, &st, s.format) {
                Ok(pool) => pool,
                Err(e) => {
                    st.configure(old)?;
                    s.pool = Pool::new(device, &st, s.format)?;
                    s.slot_rows = st.slot_rows();
                    s.generation += 1;
                    s.planner.pool_rebuilt();
                    let dims = st.pool().atlas_dims();
                    drop(st);
                    s.write_params(queue, dims);
                    return Err(e);
                }
            };
            s.pool = pool;
            s.slot_rows = st.slot_rows();
            s.generation += 1;
            s.planner.pool_rebuilt();
            let dims = st.pool().atlas_dims();
            drop(st);
            s.write_params(queue, dims);
        } else {
            s.planner.reconfigured();
        }
        s.config = config;
        Ok(())
    }

    /// [`configure`](Self::configure) with the configuration in force
    /// changed by `f`: `volume.edit(device, queue, |c| c.tolerance_px = 2.0)`.
    pub fn edit(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        f: impl FnOnce(&mut OutOfCoreConfig),
    ) -> Result<(), RenderError> {
        let mut c = self.config();
        f(&mut c);
        self.configure(device, queue, c)
    }

    /// The configuration in force.
    pub fn config(&self) -> OutOfCoreConfig {
        self.shared.lock().config
    }

    /// The planner's statistics of the last plan applied.
    pub fn stats(&self) -> StreamStats {
        self.shared.lock().stats
    }

    /// True when another frame of the same views would change the image
    /// (bricks still arriving or being refined, or a plan in progress in the
    /// background).
    pub fn wants_redraw(&self) -> bool {
        self.shared.lock().planner.wants_redraw()
    }

    fn streamer(&self) -> Arc<Mutex<Streamer>> {
        self.shared.lock().planner.streamer.clone()
    }

    /// Forgets every failed brick so it is requested again when the views
    /// need it (after the source was repaired).
    pub fn retry_failed_bricks(&self) {
        self.streamer().lock().retry_failed();
    }

    /// The first streaming failure (a brick or its metadata could not be
    /// read) since the last call, with the count of further ones, so a viewer
    /// shows one message, not thousands. Failures never fail `prepare`: the
    /// image stays at a coarser level there and `wants_redraw` stays true.
    pub fn take_streaming_error(&self) -> Option<StreamError> {
        self.streamer().lock().take_error()
    }

    /// The octree layout of the source.
    pub fn layout(&self) -> OctreeLayout {
        self.shared.lock().layout.clone()
    }

    /// The texture format of the atlas.
    pub fn texel_format(&self) -> wgpu::TextureFormat {
        self.shared.lock().format
    }

    /// Bytes of the atlas.
    pub fn resident_bytes(&self) -> u64 {
        self.shared.lock().pool.atlas_bytes
    }

    /// Reads the planner's state (the brick manager's residency and
    /// failures, the visibility state, the visible weights): diagnostics.
    pub fn inspect<R>(&self, f: impl FnOnce(&Streamer) -> R) -> R {
        f(&self.streamer().lock())
    }
}
