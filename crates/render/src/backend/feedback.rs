//! Ray-guided usage feedback (docs/visibility.md): the out-of-core kernel counts,
//! per slot-table row, the rays that reached the row's brick before
//! terminating, and sums their transmittance-weighted length through it, the
//! brick's visible weight (`shaders/feedback.wgsl`). This owns one view's
//! counters and their read-back ring (`readback.rs`): before the ray-cast
//! pass the counters are cleared; after it they are copied, with a frame
//! stamp, into a free ring entry; a later frame reads them, never waiting,
//! and hands them to the planner.

use super::readback::{ReadbackRing, RingStats};
use crate::error::RenderError;
use crate::gpu;
use brickray_cache::UsageFrame;
use brickray_core::NodeKey;

/// Read-back buffers in flight at most.
pub(crate) const RING: usize = 4;

/// Words per slot-table row: the ray count and the visible weight.
const WORDS_PER_SLOT: u64 = 2;

/// The fixed-point scale of the visible weight (`WEIGHT_SCALE` in
/// `shaders/feedback.wgsl`).
const WEIGHT_SCALE: f64 = 4.0;

/// Counters of the feedback path.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FeedbackStats {
    /// Frames whose counts were read back and applied.
    pub frames_applied: u64,
    /// Read-backs discarded: the stamp said the frame's commands never ran
    /// (the host dropped or reordered the encoder) or mapping failed.
    pub frames_discarded: u64,
    /// Frames that found no free ring entry (no copy recorded).
    pub frames_skipped: u64,
    /// Frames between rendering and applying, of the last applied read-back.
    pub last_latency_frames: u64,
}

impl From<RingStats> for FeedbackStats {
    fn from(s: RingStats) -> Self {
        FeedbackStats {
            frames_applied: s.applied,
            frames_discarded: s.discarded,
            frames_skipped: s.skipped,
            last_latency_frames: s.last_latency,
        }
    }
}

pub(crate) struct UsageFeedback {
    /// Two `u32` words per slot-table row (group 2, binding 6): rays, weight.
    pub(crate) usage: wgpu::Buffer,
    rows: u32,
    /// Per level, the finest voxels of one of the level's voxels along the
    /// ray (the kernel's step multiple: the weights' unit).
    level_voxels: Vec<f64>,
    /// Each entry remembers the `(slot, node)` leaves of its frame.
    ring: ReadbackRing<Vec<(u32, NodeKey)>>,
    /// The latest counts read back.
    pub(crate) last: Option<UsageFrame>,
}

impl UsageFeedback {
    pub(crate) fn new(
        device: &wgpu::Device,
        rows: u32,
        layout: &brickray_core::OctreeLayout,
    ) -> Result<UsageFeedback, RenderError> {
        let rows = rows.max(1);
        let bytes = rows as u64 * 4 * WORDS_PER_SLOT;
        let level_voxels = (0..layout.levels)
            .map(|l| {
                layout
                    .voxel_factor(l)
                    .into_iter()
                    .fold(f64::INFINITY, f64::min)
            })
            .collect();
        let usage = gpu::buffer(
            device,
            "brickray-render usage counters",
            bytes,
            wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
        )?;
        Ok(UsageFeedback {
            usage,
            rows,
            level_voxels,
            ring: ReadbackRing::new(device, "brickray-render usage read-back", RING, bytes)?,
            last: None,
        })
    }

    /// Rows of the counters.
    pub(crate) fn rows(&self) -> u32 {
        self.rows
    }

    /// The ring's counters.
    pub(crate) fn stats(&self) -> FeedbackStats {
        self.ring.stats.into()
    }

    /// The counts of every frame whose read-back completed, oldest first
    /// (`frame`: the frame about to be planned). Never waits.
    pub(crate) fn poll(&mut self, frame: u64) -> Vec<UsageFrame> {
        let level_voxels = &self.level_voxels;
        let out: Vec<UsageFrame> = self
            .ring
            .poll(frame, |entry_frame, leaves, payload| {
                let words: &[u32] = bytemuck::cast_slice(payload);
                let word = |slot: u32, i: u64| {
                    words
                        .get((slot as u64 * WORDS_PER_SLOT + i) as usize)
                        .copied()
                        .unwrap_or(0)
                };
                UsageFrame {
                    frame: entry_frame,
                    counts: leaves
                        .iter()
                        .map(|&(slot, key)| (key, word(slot, 0)))
                        .collect(),
                    weights: leaves
                        .iter()
                        .map(|&(slot, key)| {
                            let unit = level_voxels.get(key.level as usize).copied().unwrap_or(1.0);
                            word(slot, 1) as f64 / WEIGHT_SCALE * unit
                        })
                        .collect(),
                }
            })
            .into_iter()
            .map(|(_, u)| u)
            .collect();
        if let Some(l) = out.last() {
            self.last = Some(l.clone());
        }
        out
    }

    /// Before the ray-cast pass: zeroes the counters.
    pub(crate) fn before_pass(&self, encoder: &mut wgpu::CommandEncoder) {
        encoder.clear_buffer(&self.usage, 0, None);
    }

    /// After the ray-cast pass of `frame`: copies the stamp and the counters
    /// into a free ring entry, remembering the frame's `(slot, node)` leaves.
    pub(crate) fn after_pass(
        &mut self,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        frame: u64,
        leaves: &[(u32, NodeKey)],
    ) {
        let (usage, bytes) = (&self.usage, self.rows as u64 * 4 * WORDS_PER_SLOT);
        self.ring
            .record(queue, encoder, frame, leaves.to_vec(), |enc, dst, at| {
                enc.copy_buffer_to_buffer(usage, 0, dst, at, bytes);
            });
    }
}
