//! What the usage feedback and the occlusion queries share: a ring of
//! read-back buffers, each a 16-byte frame stamp then a payload, mapped
//! asynchronously and read when ready, never waited for.

use std::sync::Arc;
use std::sync::atomic::{AtomicU8, Ordering};

/// Bytes before the payload in a ring entry: the frame stamp.
pub(crate) const STAMP_BYTES: u64 = 16;

/// Entry states.
pub(crate) const FREE: u8 = 0;
pub(crate) const COPIED: u8 = 1;
const MAPPING: u8 = 2;
const READY: u8 = 3;
const FAILED: u8 = 4;

/// What one step of an entry gave.
pub(crate) enum Polled<T> {
    /// Nothing to read yet (free, copied this frame, or mapping).
    Pending,
    /// The payload was read (its stamp was the entry's frame); the entry is free.
    Read(T),
    /// The mapping failed or the stamp did not match; the entry is free.
    Discarded,
}

/// Advances one ring entry copied in `entry_frame`: starts mapping it once a
/// later frame (`frame`) runs, so the copy was submitted; when mapped, reads
/// its payload with `read` if the stamp is `entry_frame`, then unmaps and
/// frees it. Never waits.
pub(crate) fn poll_entry<T>(
    buffer: &wgpu::Buffer,
    state: &Arc<AtomicU8>,
    entry_frame: u64,
    frame: u64,
    read: impl FnOnce(&[u8]) -> T,
) -> Polled<T> {
    match state.load(Ordering::Acquire) {
        COPIED if entry_frame < frame => {
            state.store(MAPPING, Ordering::Release);
            let s = state.clone();
            buffer.slice(..).map_async(wgpu::MapMode::Read, move |r| {
                s.store(if r.is_ok() { READY } else { FAILED }, Ordering::Release);
            });
            Polled::Pending
        }
        READY => {
            let got = match buffer.slice(..).get_mapped_range() {
                Err(_) => None,
                Ok(view) => {
                    let w: &[u32] = bytemuck::cast_slice(&view[..8]);
                    let stamp = w[0] as u64 | (w[1] as u64) << 32;
                    (stamp == entry_frame).then(|| read(&view[STAMP_BYTES as usize..]))
                }
            };
            buffer.unmap();
            state.store(FREE, Ordering::Release);
            got.map_or(Polled::Discarded, Polled::Read)
        }
        FAILED => {
            state.store(FREE, Ordering::Release);
            Polled::Discarded
        }
        _ => Polled::Pending,
    }
}
