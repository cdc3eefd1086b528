//! Ray-guided usage feedback (docs/visibility.md): the out-of-core kernel counts,
//! per pool slot, the rays that reached the slot's brick before terminating,
//! and sums their transmittance-weighted length through it, the brick's
//! visible weight (`shaders/feedback.wgsl`). This owns the counters and a ring of read-back
//! buffers, and never blocks: before the ray-cast pass the counters are
//! cleared; after it they are copied, with a frame stamp, into a free ring
//! entry; at the next `poll` (the host has submitted the frame by then) the
//! entry is mapped with `map_async`, and once wgpu reports it mapped (during
//! any later `submit` or `poll` of the host) its counts are handed to the
//! visibility state. Nothing here calls `poll` or waits. A frame that finds no
//! free entry (the host's GPU is more than [`RING`] frames behind) records no
//! copy and loses only that frame's feedback.

use super::readback::{COPIED, FREE, Polled, STAMP_BYTES, poll_entry};
use crate::error::RenderError;
use crate::gpu;
use brickray_core::NodeKey;
use std::sync::Arc;
use std::sync::atomic::{AtomicU8, Ordering};

/// Read-back buffers in flight at most.
pub(crate) const RING: usize = 4;

/// Words per pool slot: the ray count and the visible weight.
const WORDS_PER_SLOT: u64 = 2;

/// The fixed-point scale of the visible weight (`WEIGHT_SCALE` in
/// `shaders/feedback.wgsl`).
const WEIGHT_SCALE: f64 = 4.0;

struct Entry {
    buffer: wgpu::Buffer,
    state: Arc<AtomicU8>,
    /// The frame whose counts it holds.
    frame: u64,
    /// `(slot, node)` of that frame's data leaves.
    leaves: Vec<(u32, NodeKey)>,
}

/// One frame's counts, as read back.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct UsageFrame {
    /// The frame (the out-of-core backend's frame counter) they were rendered in.
    pub frame: u64,
    /// Rays that reached each data leaf of that frame's cut.
    pub counts: Vec<(NodeKey, u32)>,
    /// The visible weight of each of those leaves, in the order of `counts`:
    /// the transmittance-weighted length of the rays through it, in finest
    /// voxels, summed over pixels (what `LodMetric::VisibleError` ranks by).
    /// The kernel measures them only under that metric: 0 otherwise.
    pub weights: Vec<f64>,
}

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

pub(crate) struct UsageFeedback {
    /// Two `u32` words per pool slot (group 2, binding 6): rays, weight.
    pub(crate) usage: wgpu::Buffer,
    stamp: wgpu::Buffer,
    slots: u32,
    /// Per level, the finest voxels of one of the level's voxels along the
    /// ray (the kernel's step multiple: the weights' unit).
    level_voxels: Vec<f64>,
    ring: Vec<Entry>,
    pub(crate) stats: FeedbackStats,
    /// The latest counts read back.
    pub(crate) last: Option<UsageFrame>,
}

impl UsageFeedback {
    pub(crate) fn new(
        device: &wgpu::Device,
        slots: u32,
        layout: &brickray_core::OctreeLayout,
    ) -> Result<UsageFeedback, RenderError> {
        let slots = slots.max(1);
        let bytes = slots as u64 * 4 * WORDS_PER_SLOT;
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
        let stamp = gpu::buffer(
            device,
            "brickray-render usage stamp",
            STAMP_BYTES,
            wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
        )?;
        let mut ring = Vec::with_capacity(RING);
        for _ in 0..RING {
            ring.push(Entry {
                buffer: gpu::buffer(
                    device,
                    "brickray-render usage read-back",
                    STAMP_BYTES + bytes,
                    wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                )?,
                state: Arc::new(AtomicU8::new(FREE)),
                frame: 0,
                leaves: Vec::new(),
            });
        }
        Ok(UsageFeedback {
            usage,
            stamp,
            slots,
            level_voxels,
            ring,
            stats: FeedbackStats::default(),
            last: None,
        })
    }

    /// Starts mapping the entries copied in frames before `frame` (submitted
    /// by now) and returns the counts of every entry whose mapping completed,
    /// oldest first. Never waits.
    pub(crate) fn poll(&mut self, frame: u64) -> Vec<UsageFrame> {
        let mut out = Vec::new();
        let level_voxels = &self.level_voxels;
        for e in &mut self.ring {
            let leaves = &e.leaves;
            let polled = poll_entry(&e.buffer, &e.state, e.frame, frame, |payload| {
                let words: &[u32] = bytemuck::cast_slice(payload);
                let word = |slot: u32, i: u64| {
                    words
                        .get((slot as u64 * WORDS_PER_SLOT + i) as usize)
                        .copied()
                        .unwrap_or(0)
                };
                let counts = leaves
                    .iter()
                    .map(|&(slot, key)| (key, word(slot, 0)))
                    .collect();
                let weights = leaves
                    .iter()
                    .map(|&(slot, key)| {
                        let unit = level_voxels.get(key.level as usize).copied().unwrap_or(1.0);
                        word(slot, 1) as f64 / WEIGHT_SCALE * unit
                    })
                    .collect();
                (counts, weights)
            });
            match polled {
                Polled::Read((counts, weights)) => {
                    self.stats.frames_applied += 1;
                    self.stats.last_latency_frames = frame - e.frame;
                    out.push(UsageFrame {
                        frame: e.frame,
                        counts,
                        weights,
                    });
                }
                Polled::Discarded => self.stats.frames_discarded += 1,
                Polled::Pending => {}
            }
        }
        out.sort_by_key(|u| u.frame);
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
        let Some(e) = self
            .ring
            .iter_mut()
            .find(|e| e.state.load(Ordering::Acquire) == FREE)
        else {
            self.stats.frames_skipped += 1;
            return;
        };
        // The stamp lands in the buffer when the host submits; if this frame's
        // encoder never runs, or runs after the next frame's stamp, the copy
        // carries another stamp and is discarded.
        let stamp = [frame as u32, (frame >> 32) as u32, 0, 0];
        queue.write_buffer(&self.stamp, 0, bytemuck::cast_slice(&stamp));
        encoder.copy_buffer_to_buffer(&self.stamp, 0, &e.buffer, 0, STAMP_BYTES);
        encoder.copy_buffer_to_buffer(
            &self.usage,
            0,
            &e.buffer,
            STAMP_BYTES,
            self.slots as u64 * 4 * WORDS_PER_SLOT,
        );
        e.frame = frame;
        e.leaves.clear();
        e.leaves.extend_from_slice(leaves);
        e.state.store(COPIED, Ordering::Release);
    }
}
