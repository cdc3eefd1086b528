//! A ring of read-back buffers, each a 16-byte frame stamp then a payload,
//! mapped asynchronously and read when ready, never waited for: what the
//! usage feedback and the occlusion queries share.
//!
//! After a pass, [`ReadbackRing::record`] copies the stamp and the payload
//! into a free entry (a frame that finds none loses only its own read-back:
//! the host's GPU is more than the ring's length behind) and asks the
//! encoder to map the entry once the host submits it
//! (`CommandEncoder::map_buffer_on_submit`). The mapping therefore never
//! starts while an encoder that copies into the entry is still unsubmitted,
//! however many frames the host prepares into one encoder. Once wgpu
//! reports the entry mapped (during any later `submit` or `poll` of the
//! host), a later [`ReadbackRing::poll`] reads its payload, if its stamp says
//! the frame's commands ran, and frees the entry. An encoder the host drops
//! without submitting drops the mapping request: the entry is freed and
//! counted as discarded. Nothing here calls `poll` or waits.
//!
//! [`Submission`] watches an encoder the same way, without a buffer: whether
//! the work recorded into it ran or was dropped with it (the gradient
//! passes, recorded again when their encoder was dropped).

use crate::error::RenderError;
use crate::gpu;
use std::sync::Arc;
use std::sync::atomic::{AtomicU8, Ordering};

/// Bytes before the payload in a ring entry: the frame stamp.
pub(crate) const STAMP_BYTES: u64 = 16;

/// Entry states.
const FREE: u8 = 0;
/// Copied into a host encoder, mapped when the host submits it.
const MAPPING: u8 = 1;
const READY: u8 = 2;
/// Mapping failed, or the encoder was dropped without being submitted.
const FAILED: u8 = 3;

/// The state of an entry whose mapping was requested: the mapping callback
/// takes it and sets `READY` or `FAILED`; dropped without being called (the
/// host dropped the encoder unsubmitted) it sets `FAILED`.
struct Pending(Option<Arc<AtomicU8>>);

impl Pending {
    fn complete(mut self, ok: bool) {
        if let Some(s) = self.0.take() {
            s.store(if ok { READY } else { FAILED }, Ordering::Release);
        }
    }
}

impl Drop for Pending {
    fn drop(&mut self) {
        if let Some(s) = self.0.take() {
            s.store(FAILED, Ordering::Release);
        }
    }
}

/// What became of the commands an encoder held when [`Submission::watch`]
/// was called.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Outcome {
    /// Not run yet (or run, and wgpu has not said so yet).
    Pending,
    /// Ran on the GPU: the host submitted the encoder and the work is done.
    Ran,
    /// Will never run: the host dropped the encoder (or its command buffer)
    /// unsubmitted.
    Dropped,
}

/// Watches one host encoder: its work-done callback says it ran; the
/// callback dropped uncalled (the encoder dropped unsubmitted) says it never
/// will. Never waits.
#[derive(Debug)]
pub(crate) struct Submission(Arc<AtomicU8>);

impl Submission {
    /// Watches `encoder` (what it holds now and what is recorded later).
    pub(crate) fn watch(encoder: &wgpu::CommandEncoder) -> Submission {
        let state = Arc::new(AtomicU8::new(MAPPING));
        let pending = Pending(Some(state.clone()));
        encoder.on_submitted_work_done(move || pending.complete(true));
        Submission(state)
    }

    /// A submission known never to run (what was to be recorded failed).
    pub(crate) fn dropped() -> Submission {
        Submission(Arc::new(AtomicU8::new(FAILED)))
    }

    pub(crate) fn outcome(&self) -> Outcome {
        match self.0.load(Ordering::Acquire) {
            READY => Outcome::Ran,
            FAILED => Outcome::Dropped,
            _ => Outcome::Pending,
        }
    }
}

/// Counters of a ring.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct RingStats {
    /// Frames whose payload was read back.
    pub(crate) applied: u64,
    /// Read-backs discarded: the stamp said the frame's commands never ran
    /// (the host dropped or reordered the encoder) or mapping failed.
    pub(crate) discarded: u64,
    /// Frames that found no free entry (nothing recorded).
    pub(crate) skipped: u64,
    /// Frames between rendering and reading, of the last read-back.
    pub(crate) last_latency: u64,
}

struct Entry<M> {
    buffer: wgpu::Buffer,
    state: Arc<AtomicU8>,
    /// The frame whose payload it holds.
    frame: u64,
    /// What the payload is about (the frame's leaves, its queried keys).
    meta: M,
}

/// A ring of `len` read-back buffers of `payload` bytes each, after the stamp.
pub(crate) struct ReadbackRing<M> {
    entries: Vec<Entry<M>>,
    stamp: wgpu::Buffer,
    pub(crate) stats: RingStats,
}

impl<M: Default> ReadbackRing<M> {
    pub(crate) fn new(
        device: &wgpu::Device,
        label: &'static str,
        len: usize,
        payload: u64,
    ) -> Result<Self, RenderError> {
        let stamp = gpu::buffer(
            device,
            label,
            STAMP_BYTES,
            wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
        )?;
        let mut entries = Vec::with_capacity(len);
        for _ in 0..len {
            entries.push(Entry {
                buffer: gpu::buffer(
                    device,
                    label,
                    STAMP_BYTES + payload,
                    wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                )?,
                state: Arc::new(AtomicU8::new(FREE)),
                frame: 0,
                meta: M::default(),
            });
        }
        Ok(ReadbackRing {
            entries,
            stamp,
            stats: RingStats::default(),
        })
    }

    /// Records into a free entry, after what `encoder` holds so far: the
    /// stamp of `frame`, then `copy(encoder, buffer, offset)`'s copy of the
    /// payload at `offset`; the entry is mapped when the host submits
    /// `encoder`. False (and counted) when no entry is free.
    pub(crate) fn record(
        &mut self,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        frame: u64,
        meta: M,
        copy: impl FnOnce(&mut wgpu::CommandEncoder, &wgpu::Buffer, u64),
    ) -> bool {
        let Some(e) = self
            .entries
            .iter_mut()
            .find(|e| e.state.load(Ordering::Acquire) == FREE)
        else {
            self.stats.skipped += 1;
            return false;
        };
        // The stamp lands in the buffer when the host submits; if this frame's
        // encoder never runs, or runs after the next frame's stamp, the copy
        // carries another stamp and is discarded.
        let stamp = [frame as u32, (frame >> 32) as u32, 0, 0];
        queue.write_buffer(&self.stamp, 0, bytemuck::cast_slice(&stamp));
        encoder.copy_buffer_to_buffer(&self.stamp, 0, &e.buffer, 0, STAMP_BYTES);
        copy(encoder, &e.buffer, STAMP_BYTES);
        e.frame = frame;
        e.meta = meta;
        e.state.store(MAPPING, Ordering::Release);
        let pending = Pending(Some(e.state.clone()));
        encoder.map_buffer_on_submit(&e.buffer, wgpu::MapMode::Read, .., move |r| {
            pending.complete(r.is_ok());
        });
        true
    }

    /// Reads, with `read(entry frame, meta, payload)`, every entry whose
    /// mapping completed and whose stamp matches, oldest first, and frees the
    /// entries it read or whose mapping failed; `frame` is the frame about to
    /// be planned (for the latency). Never waits.
    pub(crate) fn poll<T>(
        &mut self,
        frame: u64,
        mut read: impl FnMut(u64, &M, &[u8]) -> T,
    ) -> Vec<(u64, T)> {
        let mut out = Vec::new();
        for e in &mut self.entries {
            match e.state.load(Ordering::Acquire) {
                READY => {
                    let got = match e.buffer.slice(..).get_mapped_range() {
                        Err(_) => None,
                        Ok(view) => {
                            let w: &[u32] = bytemuck::cast_slice(&view[..8]);
                            let stamp = w[0] as u64 | (w[1] as u64) << 32;
                            (stamp == e.frame)
                                .then(|| read(e.frame, &e.meta, &view[STAMP_BYTES as usize..]))
                        }
                    };
                    e.buffer.unmap();
                    e.state.store(FREE, Ordering::Release);
                    match got {
                        Some(t) => {
                            self.stats.applied += 1;
                            self.stats.last_latency = frame.saturating_sub(e.frame);
                            out.push((e.frame, t));
                        }
                        None => self.stats.discarded += 1,
                    }
                }
                FAILED => {
                    e.state.store(FREE, Ordering::Release);
                    self.stats.discarded += 1;
                }
                _ => {}
            }
        }
        out.sort_by_key(|r| r.0);
        out
    }
}
