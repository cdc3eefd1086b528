//! The out-of-core backend (Gobbetti et al. 2008): one renderer's view of a
//! [`StreamedVolume`]. The volume's planner (`brickray_cache::Streamer`)
//! decides the cut, the uploads, the fades and the occlusion queries; the
//! volume owns what every view shares (the brick atlas, slot and sub-cell
//! tables, the index); this owns what is one view's: group 2 over the shared
//! objects and its own, the per-row usage counters and their read-back ring
//! (`feedback.rs`), and the stop-depth texture and occlusion pass
//! (`occlusion.rs`). It decides nothing: it reads back, and executes plans.

use super::feedback::{FeedbackStats, UsageFeedback};
use super::occlusion::{OcclusionFeedback, OcclusionStats};
use super::{VolumeBackend, check_stage_limits, volume_layout_entries};
use crate::error::RenderError;
use crate::gpu;
use crate::kernels::KernelKind;
use crate::volume::{Bound, Planned, StreamedVolume};
use brickray_cache::{
    FrameStats as CacheStats, MAX_QUERIES_PER_FRAME, QueryBatch, UsageFrame, ViewFeedback,
};
use brickray_core::NodeKey;
use brickray_visibility::{VisibilityCounts, VisibilityPolicy};

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

/// The per-stage limits the out-of-core kernel needs.
pub(crate) fn check_limits(device: &wgpu::Device) -> Result<(), RenderError> {
    check_stage_limits(device, STORAGE_BUFFERS)?;
    gpu::need(
        "max_storage_textures_per_shader_stage",
        (crate::frame::OUTPUT_FORMATS.len() as u32 + STORAGE_TEXTURES) as u64,
        device.limits().max_storage_textures_per_shader_stage as u64,
    )
}

/// What the out-of-core path did in the last frame.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct OutOfCoreStats {
    /// The cache's view: working set, pool occupancy, uploads, hit rates,
    /// requests in flight, residency counts, failures.
    pub cache: CacheStats,
    /// Words of the encoded index.
    pub index_words: u32,
    /// Milliseconds spent planning (the streamer's frame).
    pub refine_ms: f64,
    /// Milliseconds spent writing prepared bricks and tables.
    pub upload_ms: f64,
    /// Milliseconds spent encoding and writing the index.
    pub encode_ms: f64,
    /// True when another frame of this view would not change the image: nothing
    /// in flight or pending, and no brick the view needs has failed
    /// (`cache.converged()`), and the feedback settled.
    pub converged: bool,
    /// Data leaves of the cut per octree level (level 0 = root; levels past 15
    /// are counted in 15).
    pub data_leaves_per_level: [u32; 16],
    /// The visibility policy in force.
    pub policy: VisibilityPolicy,
    /// The cut's data leaves by visibility (all unobserved without culling).
    pub visibility: VisibilityCounts,
    /// This view's usage feedback's read-back counters.
    pub feedback: FeedbackStats,
    /// This view's occlusion queries' schedule and read-back counters.
    pub occlusion: OcclusionStats,
}

/// One renderer's view of a streamed volume.
pub(crate) struct OutOfCore {
    volume: StreamedVolume,
    group_layout: wgpu::BindGroupLayout,
    bind_group: wgpu::BindGroup,
    /// The volume's generation the bind group holds.
    bound: u64,
    feedback: UsageFeedback,
    occlusion: OcclusionFeedback,
    /// The plan this view draws: its frame and `(slot, node)` data leaves.
    frame: u64,
    leaves: Vec<(u32, NodeKey)>,
    queries: bool,
    levels: u8,
    format: wgpu::TextureFormat,
    stats: OutOfCoreStats,
}

impl std::fmt::Debug for OutOfCore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OutOfCore")
            .field("volume", &self.volume)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl OutOfCore {
    /// A view of `volume`.
    pub(crate) fn new(
        device: &wgpu::Device,
        volume: StreamedVolume,
    ) -> Result<OutOfCore, RenderError> {
        check_limits(device)?;
        let group_layout = gpu::scoped(device, "brickray-render out-of-core layout", || {
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("brickray-render out of core"),
                entries: &layout_entries(),
            })
        })?;
        let occlusion = OcclusionFeedback::new(device, MAX_QUERIES_PER_FRAME)?;
        let (feedback, bind_group, bound, levels, format) = {
            let s = volume.lock();
            let layout = s.streamer.layout();
            let feedback = UsageFeedback::new(device, s.streamer.slot_rows(), layout)?;
            let bind_group = bind_group(device, &group_layout, &s.bound(), &feedback, &occlusion)?;
            (feedback, bind_group, s.generation, layout.levels, s.format)
        };
        Ok(OutOfCore {
            volume,
            group_layout,
            bind_group,
            bound,
            feedback,
            occlusion,
            frame: 0,
            leaves: Vec::new(),
            queries: false,
            levels,
            format,
            stats: OutOfCoreStats::default(),
        })
    }

    /// The volume this view draws.
    pub(crate) fn volume(&self) -> &StreamedVolume {
        &self.volume
    }

    /// What was read back for this view since the last frame (never waits);
    /// `frame` is the frame about to be planned.
    pub(crate) fn poll(&mut self, frame: u64) -> ViewFeedback {
        ViewFeedback {
            usage: self.feedback.poll(frame),
            queries: self.occlusion.poll(frame),
        }
    }

    /// Takes this frame's plan of the volume: sizes the counters and the
    /// stop depth, rebuilds group 2 when an object it holds was recreated,
    /// and writes this view's occlusion boxes.
    pub(crate) fn apply(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        planned: &Planned,
        queries: &QueryBatch,
        viewport: [u32; 2],
    ) -> Result<(), RenderError> {
        let s = self.volume.lock();
        let mut rebuild = self.occlusion.resize(device, viewport)? || s.generation != self.bound;
        let rows = s.streamer.slot_rows();
        if rows != self.feedback.rows() {
            // (Read-backs in flight are dropped with the old counters.)
            self.feedback = UsageFeedback::new(device, rows, s.streamer.layout())?;
            rebuild = true;
        }
        if rebuild {
            self.bind_group = bind_group(
                device,
                &self.group_layout,
                &s.bound(),
                &self.feedback,
                &self.occlusion,
            )?;
            self.bound = s.generation;
        }
        drop(s);
        let plan = &planned.plan;
        self.frame = plan.frame;
        self.leaves.clone_from(&plan.leaves);
        self.queries = plan.stats.policy.occlusion_queries();
        if self.queries {
            self.occlusion.write(queue, queries);
        }
        let st = &plan.stats;
        self.stats = OutOfCoreStats {
            cache: st.cache,
            index_words: planned.index_words,
            refine_ms: planned.refine_ms,
            upload_ms: planned.upload_ms,
            encode_ms: planned.encode_ms,
            converged: st.converged,
            data_leaves_per_level: st.data_leaves_per_level,
            policy: st.policy,
            visibility: st.visibility,
            feedback: self.feedback.stats(),
            occlusion: self.occlusion.stats(),
        };
        Ok(())
    }

    /// Statistics of the last frame.
    pub(crate) fn stats(&self) -> OutOfCoreStats {
        self.stats
    }

    /// The latest usage counts read back (whatever the policy).
    pub(crate) fn last_usage(&self) -> Option<&UsageFrame> {
        self.feedback.last.as_ref()
    }
}

/// Group 2 of one view: the volume's shared objects and the view's own.
fn bind_group(
    device: &wgpu::Device,
    layout: &wgpu::BindGroupLayout,
    v: &Bound<'_>,
    feedback: &UsageFeedback,
    occlusion: &OcclusionFeedback,
) -> Result<wgpu::BindGroup, RenderError> {
    gpu::scoped(device, "brickray-render out-of-core bind group", || {
        device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("brickray-render out of core"),
            layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: v.params.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(v.atlas),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::Sampler(v.sampler),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: v.slots.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: v.sub_cells.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 5,
                    resource: v.index.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: USAGE_BINDING,
                    resource: feedback.usage.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: STOP_DEPTH_BINDING,
                    resource: wgpu::BindingResource::TextureView(occlusion.stop_view()),
                },
            ],
        })
    })
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

    fn before_pass(&mut self, encoder: &mut wgpu::CommandEncoder) {
        self.feedback.before_pass(encoder);
    }

    fn after_pass(&mut self, queue: &wgpu::Queue, encoder: &mut wgpu::CommandEncoder) {
        self.feedback
            .after_pass(queue, encoder, self.frame, &self.leaves);
        if self.queries {
            self.occlusion.record(queue, encoder, self.frame);
        }
    }

    fn measures_weights(&self) -> bool {
        self.volume.lock().streamer.measures_weights()
    }

    fn max_leaves(&self) -> u32 {
        // A ray crosses at most about 3 * 2^finest leaves of the finest level,
        // plus zero-length visits at edges: a guard, not a quality setting.
        let finest = (self.levels - 1).min(20) as u32;
        (3u64 << finest).saturating_add(1024).min(1 << 20) as u32
    }

    fn step_lengths(&self) -> u32 {
        self.levels as u32
    }

    fn wants_redraw(&self) -> bool {
        !self.stats.converged
    }

    fn texel_format(&self) -> wgpu::TextureFormat {
        self.format
    }

    fn resident_bytes(&self) -> u64 {
        self.volume.resident_bytes()
    }
}
