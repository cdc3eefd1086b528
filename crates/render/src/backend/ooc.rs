//! The out-of-core backend (Gobbetti et al. 2008): one renderer's view of a
//! [`StreamedVolume`]. The volume's planner (`brickray_cache::Streamer`)
//! decides the cut, the uploads, the fades and the occlusion queries; the
//! volume owns what every view shares (the brick atlas, slot and sub-cell
//! tables, the index); this owns what is one view's: group 2 over the shared
//! objects and its own, the per-row usage counters and their read-back ring
//! (`feedback.rs`), and the stop-depth texture and occlusion pass
//! (`occlusion.rs`). It decides nothing: it reads back, and executes plans.

use super::VolumeBackend;
use super::feedback::UsageFeedback;
use super::occlusion::OcclusionFeedback;
use super::ooc_channels::OocChannels;
use crate::desc::OutOfCoreStats;
use crate::error::RenderError;
use crate::gpu;
use crate::group2::{
    INDEX_BINDING, OOC_GRADIENT_BINDING, SLOTS_BINDING, SPREAD_BINDING, STOP_DEPTH_BINDING,
    SUB_CELLS_BINDING, USAGE_BINDING, check_ooc_limits,
};
use crate::kernels::KernelKind;
use crate::volume::{Bound, Planned, StreamedVolume};
use brickray_cache::{MAX_QUERIES_PER_FRAME, QueryBatch, UsageFrame, ViewFeedback};
use brickray_core::NodeKey;

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
    /// A multi-channel volume's classification (ooc_channels.wgsl).
    channels: Option<OocChannels>,
    /// When MIP skips empty space ([`crate::SkipRule`]).
    mip_policy: crate::SkipRule,
    /// The share of the plan's bricks' sub-cells MIP's skipping is certain
    /// to skip within their brick, compared with
    /// `brickray_core::MIP_SKIP_SHARE_MIN_BRICKS` at the frame's step;
    /// `None`: always skip (the policy, or a multi-channel volume).
    mip_share: Option<f64>,
    /// When DVR skips empty space ([`crate::SkipRule`]).
    dvr_policy: crate::SkipRule,
    /// The share of the plan's bricks' sub-cells transparent through the
    /// transfer function, compared with the frame's rule at its step
    /// (`brickray_core::dvr_skip_share_min_bricks`, shaded or not);
    /// `None`: always test them (the policy, a multi-channel volume, a label
    /// map).
    dvr_share: Option<f64>,
    /// Whether a leaf of the plan applied last fades (its slot's row
    /// mixes in an ancestor's brick; a borrowed octant does not).
    fades: bool,
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
        mip_policy: crate::SkipRule,
        dvr_policy: crate::SkipRule,
    ) -> Result<OutOfCore, RenderError> {
        check_ooc_limits(device)?;
        let channels = {
            let s = volume.lock();
            match s.layout.is_channel_volume() {
                true => Some(OocChannels::new(device, s.gpu_format())?),
                false => None,
            }
        };
        let entries = match channels {
            Some(_) => super::ooc_channels::layout_entries(),
            None => crate::group2::ooc_single_layout_entries(),
        };
        let group_layout = gpu::scoped(device, "brickray-render out-of-core layout", || {
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("brickray-render out of core"),
                entries: &entries,
            })
        })?;
        let occlusion = OcclusionFeedback::new(device, MAX_QUERIES_PER_FRAME)?;
        let (feedback, bind_group, bound, levels, format) = {
            let s = volume.lock();
            let layout = &s.layout;
            let feedback = UsageFeedback::new(device, s.slot_rows, layout)?;
            let bind_group = bind_group(
                device,
                &group_layout,
                &s.bound(),
                &feedback,
                &occlusion,
                channels.as_ref(),
            )?;
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
            channels,
            mip_policy,
            mip_share: None,
            dvr_policy,
            dvr_share: None,
            fades: true,
        })
    }

    /// Channels of a channel volume, `None` for a plain one.
    pub(crate) fn channel_count(&self) -> Option<usize> {
        self.channels.as_ref().map(OocChannels::count)
    }

    /// Keeps a multi-channel volume's classification current for the frame
    /// (`styles` of `generation`, one table row per level and `extra_rows`
    /// more for the adaptive step's doublings); rebuilds group 2 when an
    /// object it holds was recreated. Returns the bytes written.
    pub(crate) fn update_channels(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        styles: &[brickray_core::ChannelStyle],
        generation: u64,
        step_factor: f32,
        extra_rows: u32,
    ) -> Result<u64, RenderError> {
        let rows = self.levels as u32 + extra_rows;
        let Some(c) = self.channels.as_mut() else {
            return Ok(0);
        };
        let (written, rebind) = c.update(device, queue, styles, generation, step_factor, rows)?;
        if rebind {
            let s = self.volume.lock();
            self.bind_group = bind_group(
                device,
                &self.group_layout,
                &s.bound(),
                &self.feedback,
                &self.occlusion,
                self.channels.as_ref(),
            )?;
        }
        Ok(written)
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
    /// and writes this view's occlusion boxes. `dvr_tf`: the transfer
    /// function and its generation when the views draw DVR of a
    /// single-channel intensity volume (the DVR skip rule's input).
    pub(crate) fn apply(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        planned: &Planned,
        queries: &QueryBatch,
        viewport: [u32; 2],
        dvr_tf: Option<(&brickray_core::TransferFunction, u64)>,
    ) -> Result<(), RenderError> {
        let mut s = self.volume.lock();
        let mut rebuild = self.occlusion.resize(device, viewport)? || s.generation != self.bound;
        let rows = s.slot_rows;
        if rows != self.feedback.rows() {
            // (Read-backs in flight are dropped with the old counters.)
            self.feedback = UsageFeedback::new(device, rows, &s.layout)?;
            rebuild = true;
        }
        if rebuild {
            self.bind_group = bind_group(
                device,
                &self.group_layout,
                &s.bound(),
                &self.feedback,
                &self.occlusion,
                self.channels.as_ref(),
            )?;
            self.bound = s.generation;
        }
        let plan = &planned.plan;
        // MIP skips where the plan's bricks say it pays (a sum over the
        // cut's slots; the image is the same either way, only the time
        // differs), or always as the policy or a multi-channel volume asks.
        self.mip_share = match self.mip_policy {
            crate::SkipRule::Always => None,
            crate::SkipRule::WherePays => s.mip_skip_share(&plan.leaves),
        };
        // DVR tests sub-cells only where enough of the plan's bricks' are
        // transparent (`DVR_SKIP_SHARE_MIN_BRICKS`, shaded
        // `DVR_SHADED_SKIP_SHARE_MIN_BRICKS`): with fewer, the tests
        // cost more than the samples they save (the image is the same
        // either way).
        let share = dvr_tf
            .and_then(|(tf, generation)| s.dvr_transparent_share(&plan.leaves, tf, generation));
        self.dvr_share = share.filter(|_| self.dvr_policy == crate::SkipRule::WherePays);
        let gradients_kept = s.gpu_format().gradients;
        drop(s);
        self.fades = plan.fades.iter().any(|f| !f.borrowed);
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
            dvr_transparent_share: share,
            gradients_kept,
        };
        Ok(())
    }

    /// Statistics of the last plan applied, with the read-backs' counts as
    /// they stand (a converged view's frames apply no new plan, and its
    /// read-backs go on).
    pub(crate) fn stats(&self) -> OutOfCoreStats {
        OutOfCoreStats {
            feedback: self.feedback.stats(),
            occlusion: self.occlusion.stats(),
            ..self.stats
        }
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
    channels: Option<&OocChannels>,
) -> Result<wgpu::BindGroup, RenderError> {
    gpu::scoped(device, "brickray-render out-of-core bind group", || {
        let mut entries = vec![
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
                binding: SLOTS_BINDING,
                resource: wgpu::BindingResource::TextureView(v.slots),
            },
            wgpu::BindGroupEntry {
                binding: SUB_CELLS_BINDING,
                resource: wgpu::BindingResource::TextureView(v.sub_cells),
            },
            wgpu::BindGroupEntry {
                binding: INDEX_BINDING,
                resource: wgpu::BindingResource::TextureView(v.index),
            },
            wgpu::BindGroupEntry {
                binding: USAGE_BINDING,
                resource: feedback.usage.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: STOP_DEPTH_BINDING,
                resource: wgpu::BindingResource::TextureView(occlusion.stop_view()),
            },
        ];
        match channels {
            Some(c) => entries.extend(c.entries()),
            None => entries.extend([
                wgpu::BindGroupEntry {
                    binding: SPREAD_BINDING,
                    resource: wgpu::BindingResource::TextureView(v.spread),
                },
                wgpu::BindGroupEntry {
                    binding: OOC_GRADIENT_BINDING,
                    resource: wgpu::BindingResource::TextureView(v.gradients),
                },
            ]),
        }
        device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("brickray-render out of core"),
            layout,
            entries: &entries,
        })
    })
}

impl VolumeBackend for OutOfCore {
    fn kind(&self) -> KernelKind {
        match self.channels {
            Some(_) => KernelKind::OutOfCoreChannels,
            None => KernelKind::OutOfCore,
        }
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
        self.volume.lock().measures_weights()
    }

    fn labels(&self) -> bool {
        self.volume.lock().layout.volume.kind.is_labels()
    }

    fn mip_skipping(&self, step: f32) -> bool {
        self.mip_share
            .is_none_or(|share| brickray_core::MIP_SKIP_SHARE_MIN_BRICKS.pays(share, step))
    }

    fn dvr_skipping(&self, step: f32, shaded: bool) -> bool {
        let rule = brickray_core::dvr_skip_share_min_bricks(shaded);
        self.dvr_share.is_none_or(|share| rule.pays(share, step))
    }

    fn fades(&self) -> bool {
        self.fades
    }

    fn octree(&self) -> bool {
        self.volume.lock().is_octree()
    }

    fn spread(&self) -> bool {
        self.volume.lock().gpu_format().spread
    }

    fn gradients(&self) -> bool {
        self.volume.lock().gpu_format().gradients
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
        // (In the background, also while a plan is in flight.)
        !self.stats.converged || self.volume.wants_redraw()
    }

    fn texel_format(&self) -> wgpu::TextureFormat {
        self.format
    }

    fn resident_bytes(&self) -> u64 {
        self.volume.resident_bytes()
    }
}
