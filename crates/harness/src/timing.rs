//! Timing frames: [`GpuTimer`] (GPU timestamps of the ray-cast pass) and
//! [`draw_frame_timed`] (a frame's wall time, its host part and the pass).

use crate::{GpuContext, Offscreen};

/// Times a renderer's ray-cast pass with GPU timestamps
/// ([`brickray_render::VolumeRenderer::set_pass_timestamps`]): a 2-entry
/// timestamp query set, the buffer it resolves into and a buffer to map.
/// Per frame: `renderer.set_pass_timestamps(&device, Some(timer.writes()))`
/// (once), `prepare`, [`GpuTimer::resolve`] into the same encoder, submit and
/// wait, then [`GpuTimer::read_ms`]. Blocking: tests and benchmarks only.
///
/// On lavapipe the pass can read far less than it took on frames whose
/// submission also writes bricks into the atlas (about 0 ms where the wait
/// says 100 ms), and now and then under load: there, [`TimedFrame::ms`] and
/// [`TimedFrame::host_ms`] are the figures to trust.
#[derive(Debug)]
pub struct GpuTimer {
    queries: wgpu::QuerySet,
    resolved: wgpu::Buffer,
    readback: wgpu::Buffer,
    /// Nanoseconds a tick.
    period: f32,
}

impl GpuTimer {
    /// Bytes of the two resolved timestamps.
    const BYTES: u64 = 2 * std::mem::size_of::<u64>() as u64;

    /// A timer on `gpu`'s device, `None` when it lacks
    /// [`wgpu::Features::TIMESTAMP_QUERY`].
    pub fn new(gpu: &GpuContext) -> Option<GpuTimer> {
        let device = &gpu.device;
        if !device.features().contains(wgpu::Features::TIMESTAMP_QUERY) {
            return None;
        }
        let queries = device.create_query_set(&wgpu::QuerySetDescriptor {
            label: Some("brickray-harness timer"),
            ty: wgpu::QueryType::Timestamp,
            count: 2,
        });
        let buffer = |label, usage| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: GpuTimer::BYTES,
                usage,
                mapped_at_creation: false,
            })
        };
        Some(GpuTimer {
            queries,
            resolved: buffer(
                "brickray-harness timer resolve",
                wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
            ),
            readback: buffer(
                "brickray-harness timer readback",
                wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            ),
            period: gpu.queue.get_timestamp_period(),
        })
    }

    /// Where the ray-cast pass writes its beginning (query 0) and end (1).
    pub fn writes(&self) -> brickray_render::PassTimestamps {
        brickray_render::PassTimestamps {
            query_set: self.queries.clone(),
            beginning: 0,
            end: 1,
        }
    }

    /// Records the resolve of both timestamps and their copy into the
    /// buffer [`GpuTimer::read_ms`] maps: after the frame's `prepare`, in the
    /// same or a later encoder of the same submission.
    pub fn resolve(&self, encoder: &mut wgpu::CommandEncoder) {
        encoder.resolve_query_set(&self.queries, 0..2, &self.resolved, 0);
        encoder.copy_buffer_to_buffer(&self.resolved, 0, &self.readback, 0, GpuTimer::BYTES);
    }

    /// The pass's time in milliseconds, once the submission holding
    /// [`GpuTimer::resolve`] completed (blocks on the map). `None` when the
    /// map fails or the end precedes the beginning (nothing was written).
    pub fn read_ms(&self, gpu: &GpuContext) -> Option<f64> {
        let slice = self.readback.slice(..);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        let _ = gpu.device.poll(wgpu::PollType::wait_indefinitely());
        rx.recv().ok()?.ok()?;
        let ticks = slice.get_mapped_range().ok().map(|data| {
            let t = |i: usize| {
                let mut b = [0u8; 8];
                b.copy_from_slice(&data[i * 8..i * 8 + 8]);
                u64::from_le_bytes(b)
            };
            (t(0), t(1))
        });
        self.readback.unmap();
        let (begin, end) = ticks?;
        let elapsed = end.checked_sub(begin)?;
        Some(elapsed as f64 * self.period as f64 / 1e6)
    }
}

/// A frame drawn by [`draw_frame_timed`].
#[derive(Debug)]
pub struct TimedFrame {
    /// What `prepare` reported.
    pub stats: brickray_render::FrameStats,
    /// Wall time of prepare, submit and wait (ms; the timestamps' read-back
    /// after it is not counted).
    pub ms: f64,
    /// What the host thread spent before waiting: `prepare`, recording the
    /// draw and the submission (ms). The rest of [`TimedFrame::ms`] is the
    /// wait for the GPU.
    pub host_ms: f64,
    /// The ray-cast pass's own time by GPU timestamps (ms); `None` without
    /// a timer.
    pub gpu_ms: Option<f64>,
}

/// [`draw_frame`](crate::draw_frame), timed: its wall time, and with a `timer` the ray-cast
/// pass's own time by GPU timestamps. The renderer's pass timestamps are
/// set for this frame only.
pub fn draw_frame_timed(
    gpu: &GpuContext,
    renderer: &mut brickray_render::VolumeRenderer,
    target: &Offscreen,
    desc: &brickray_render::FrameDesc<'_>,
    clear: Option<wgpu::Color>,
    timer: Option<&GpuTimer>,
) -> Result<TimedFrame, brickray_render::PrepareError> {
    // A timer is made on this device and has the feature: setting it cannot
    // fail, and a failure would only lose the timing.
    let timed = timer.is_some_and(|t| {
        renderer
            .set_pass_timestamps(&gpu.device, Some(t.writes()))
            .is_ok()
    });
    let t0 = std::time::Instant::now();
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    let prepared = renderer.prepare(&gpu.device, &gpu.queue, &mut enc, desc);
    if timed {
        let _ = renderer.set_pass_timestamps(&gpu.device, None);
    }
    let stats = prepared?;
    {
        let mut pass = target.pass_clear(&mut enc, clear);
        renderer.render(&mut pass)?;
    }
    if let (true, Some(t)) = (timed, timer) {
        t.resolve(&mut enc);
    }
    gpu.queue.submit([enc.finish()]);
    let host_ms = t0.elapsed().as_secs_f64() * 1e3;
    let _ = gpu.device.poll(wgpu::PollType::wait_indefinitely());
    let ms = t0.elapsed().as_secs_f64() * 1e3;
    let gpu_ms = if timed {
        timer.and_then(|t| t.read_ms(gpu))
    } else {
        None
    };
    Ok(TimedFrame {
        stats,
        ms,
        host_ms,
        gpu_ms,
    })
}
