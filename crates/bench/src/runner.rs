//! What the suites share: timed frames into an offscreen target, convergence of
//! the out-of-core path, and order statistics.

use brickray_core::{Camera, RenderSettings, TransferFunction, Volume, VolumeFrame};
use brickray_harness::{GpuContext, GpuTimer, Offscreen};
use brickray_render::{FrameDesc, OutOfCoreStats, RendererOptions, VolumeRenderer};
use std::time::Duration;

/// One rendered frame.
pub(crate) struct Shot {
    /// `prepare + submit + wait` wall time.
    pub(crate) ms: f64,
    /// The ray-cast pass's own time by GPU timestamps, where the device
    /// has them.
    pub(crate) gpu_ms: Option<f64>,
    /// The host thread's part of `ms`: `prepare`, recording and submitting,
    /// before the wait for the GPU.
    pub(crate) host_ms: f64,
    /// The process's CPU time over the same span ([`process_cpu_ms`]).
    pub(crate) cpu_ms: f64,
    /// The image (RGBA8; empty when not read).
    pub(crate) rgba: Vec<u8>,
    /// Mean samples per ray over the rays that enter the volume (0 when not read).
    pub(crate) samples: f64,
    /// Samples of all rays (0 when not read).
    pub(crate) total_samples: u64,
    /// Samples as SIMD hardware executes them: each group of
    /// [`SIMD_LANES`] rays (a 4 x 2 pixel block, [`lane_samples`]) costs its
    /// longest ray's samples times the lanes (0 when not read).
    pub(crate) lane_samples: u64,
}

/// CPU time of this process so far (all its threads: lavapipe's rasteriser
/// threads run in it), in ms, from `/proc/self/stat` at its 10 ms tick; NaN
/// where that is not available. On a machine shared with other work, CPU time
/// moves far less than wall time, so suites report both.
/// Changes the configuration of the streamed volume `r` draws.
pub(crate) fn configure(
    gpu: &GpuContext,
    r: &VolumeRenderer,
    f: impl FnOnce(&mut brickray_render::OutOfCoreConfig),
) -> Result<(), String> {
    r.streamed_volume()
        .ok_or("the renderer draws no streamed volume")?
        .edit(&gpu.device, &gpu.queue, f)
        .map_err(|e| e.to_string())
}

pub(crate) fn process_cpu_ms() -> f64 {
    let ticks = || -> Option<f64> {
        let s = std::fs::read_to_string("/proc/self/stat").ok()?;
        // Fields after the command name in parentheses, from field 3 (state).
        let rest = s.get(s.rfind(')')? + 2..)?;
        let f: Vec<&str> = rest.split_whitespace().collect();
        let utime: f64 = f.get(11)?.parse().ok()?;
        let stime: f64 = f.get(12)?.parse().ok()?;
        Some(utime + stime)
    };
    // USER_HZ is 100 on every Linux ABI.
    ticks().map_or(f64::NAN, |t| t * 10.0)
}

/// An out-of-core renderer over `source` kept at the finest level
/// (`tolerance_px = 0`, a 1 GiB upload budget so it converges in a few frames).
pub(crate) fn finest_ooc_renderer(
    gpu: &GpuContext,
    source: std::sync::Arc<dyn brickray_core::BrickSource>,
    options: brickray_render::RendererOptions,
) -> Result<VolumeRenderer, String> {
    let mut ooc =
        VolumeRenderer::with_options(&gpu.device, brickray_harness::target_desc(), options)
            .map_err(|e| e.to_string())?;
    ooc.set_volume_source(
        &gpu.device,
        &gpu.queue,
        source,
        brickray_render::OutOfCoreConfig {
            tolerance_px: 0.0,
            upload_budget_bytes: 1 << 30,
            ..Default::default()
        },
    )
    .map_err(|e| e.to_string())?;
    Ok(ooc)
}

/// A streamed volume's gradients as a suite compares them: kept, or six
/// reads (never the library's default, which keeps them only where every
/// brick fits, so that a suite's variants stay what they say).
pub(crate) fn keep_gradients(kept: bool) -> brickray_render::KeepGradients {
    if kept {
        brickray_render::KeepGradients::Always
    } else {
        brickray_render::KeepGradients::Never
    }
}

/// A GPU-free streamer over `source` with `config`, for a device that
/// stores 16-bit texels exactly (lavapipe's formats, the renderer's
/// defaults), carrying spreads when `spread`; its root read.
pub(crate) fn gpu_free_streamer(
    source: std::sync::Arc<dyn brickray_core::BrickSource>,
    config: brickray_render::OutOfCoreConfig,
    spread: bool,
) -> Result<brickray_cache::Streamer, String> {
    let caps = brickray_core::TexelCaps {
        norm16: true,
        float32_filterable: false,
    };
    let gpu = brickray_cache::GpuFormat {
        spread,
        ..brickray_cache::GpuFormat::for_layout(
            source.layout(),
            caps,
            brickray_core::U8Filtering::Exact,
            32,
            2048,
        )
    };
    let mut streamer =
        brickray_cache::Streamer::new(source, config, gpu).map_err(|e| e.to_string())?;
    streamer.preload_root().map_err(|e| e.to_string())?;
    Ok(streamer)
}

/// Lanes of one SIMD group of rays: 8 x 32-bit on lavapipe's 256-bit vectors.
/// Consecutive invocations of an 8x8 workgroup are pixels in Morton order
/// (`tile_pixel` in common.wgsl), so each group covers a 4 x 2 block.
pub(crate) const SIMD_LANES: usize = 8;

/// Samples as SIMD lanes execute them: each group of [`SIMD_LANES`] rays (a
/// 4 x 2 pixel block; clipped at the image's edges) costs its longest ray's
/// samples on every lane it holds.
pub(crate) fn lane_samples(counts: &[u32], width: usize) -> u64 {
    const W: usize = 4;
    const H: usize = SIMD_LANES / W;
    if width == 0 {
        return 0;
    }
    let height = counts.len() / width;
    let mut sum = 0u64;
    for y0 in (0..height).step_by(H) {
        for x0 in (0..width).step_by(W) {
            let (mut max, mut lanes) = (0u32, 0u64);
            for y in y0..(y0 + H).min(height) {
                for x in x0..(x0 + W).min(width) {
                    max = max.max(counts[y * width + x]);
                    lanes += 1;
                }
            }
            sum += max as u64 * lanes;
        }
    }
    sum
}

/// Builds `vol` into a brick store of `brick`-voxel bricks at `path` (default
/// options otherwise).
pub(crate) fn build_store(
    vol: brickray_core::Volume,
    brick: u32,
    path: &std::path::Path,
) -> Result<brickray_store::BuildReport, String> {
    let mut reader = brickray_io::MemoryReader::new(vol, "memory");
    brickray_store::build(
        &mut reader,
        path,
        &brickray_store::BuildOptions {
            brick,
            ..Default::default()
        },
    )
    .map_err(|e| e.to_string())
}

/// Draws frames of one size into an offscreen target and times them.
pub(crate) struct Runner<'a> {
    pub(crate) gpu: &'a GpuContext,
    pub(crate) target: Offscreen,
    pub(crate) size: u32,
    /// Times the ray-cast pass where the device has timestamps.
    pub(crate) timer: Option<GpuTimer>,
}

impl<'a> Runner<'a> {
    /// A full-target frame of the runner's size, without host depth.
    fn desc(
        &self,
        camera: Camera,
        frame: VolumeFrame,
        settings: RenderSettings,
    ) -> FrameDesc<'static> {
        FrameDesc {
            camera,
            frame,
            viewport: brickray_render::Viewport::full(self.size, self.size),
            settings,
            host_depth: None,
            // A host's frame time: fades in milliseconds advance with it.
            time: Some(brickray_harness::host_time()),
        }
    }

    /// A runner drawing `size x size` frames; an error when the device
    /// cannot create such a target.
    pub(crate) fn new(gpu: &'a GpuContext, size: u32) -> Result<Self, String> {
        let limit = gpu.device.limits().max_texture_dimension_2d;
        if size == 0 || size > limit {
            return Err(format!(
                "an image side of {size} px is not in 1..={limit}, the device's 2D texture limit"
            ));
        }
        Ok(Runner {
            timer: GpuTimer::new(gpu),
            gpu,
            target: Offscreen::new(&gpu.device, size, size),
            size,
        })
    }

    /// One frame: `prepare + submit + wait` wall time, and optionally the image
    /// and the samples per ray read back (not timed).
    pub(crate) fn frame(
        &self,
        r: &mut VolumeRenderer,
        camera: Camera,
        frame: VolumeFrame,
        settings: RenderSettings,
        read: bool,
    ) -> Result<Shot, String> {
        let g = self.gpu;
        let cpu0 = process_cpu_ms();
        let desc = self.desc(camera, frame, settings);
        let timed = brickray_harness::draw_frame_timed(
            g,
            r,
            &self.target,
            &desc,
            Some(wgpu::Color::BLACK),
            self.timer.as_ref(),
        )
        .map_err(|e| e.to_string())?;
        let (ms, gpu_ms, host_ms) = (timed.ms, timed.gpu_ms, timed.host_ms);
        let cpu_ms = process_cpu_ms() - cpu0;
        if !read {
            return Ok(Shot {
                ms,
                gpu_ms,
                host_ms,
                cpu_ms,
                rgba: Vec::new(),
                samples: 0.0,
                total_samples: 0,
                lane_samples: 0,
            });
        }
        let rgba = self.target.read_color(g);
        let tex = r.sample_count_texture().ok_or("no sample counts")?;
        let counts = brickray_harness::read_texture(g, tex, 4, wgpu::TextureAspect::All);
        let counts: Vec<u32> = counts
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        let sum: u64 = counts.iter().map(|&c| c as u64).sum();
        let n = counts.iter().filter(|&&c| c > 0).count() as u64;
        Ok(Shot {
            ms,
            gpu_ms,
            host_ms,
            cpu_ms,
            rgba,
            samples: sum as f64 / n.max(1) as f64,
            total_samples: sum,
            lane_samples: lane_samples(&counts, self.size as usize),
        })
    }

    /// Plans one frame without ray casting it: `prepare` (refinement, uploads,
    /// index) then a submission that only flushes the queued writes. The cut and
    /// the streaming are those of a rendered frame; only the GPU ray cast is
    /// skipped (lavapipe takes seconds per 512x512 frame).
    pub(crate) fn plan(
        &self,
        r: &mut VolumeRenderer,
        camera: Camera,
        frame: VolumeFrame,
        settings: RenderSettings,
    ) -> Result<(), String> {
        let g = self.gpu;
        let mut enc = g.device.create_command_encoder(&Default::default());
        let desc = self.desc(camera, frame, settings);
        r.prepare(&g.device, &g.queue, &mut enc, &desc)
            .map_err(|e| e.to_string())?;
        drop(enc);
        g.submit_wait(g.device.create_command_encoder(&Default::default()));
        Ok(())
    }

    /// Plans frames of one view until the out-of-core path converges (at most
    /// `max_frames`); returns the frames it took (`None`: not converged) and the
    /// last stats.
    pub(crate) fn converge(
        &self,
        r: &mut VolumeRenderer,
        camera: Camera,
        frame: VolumeFrame,
        settings: RenderSettings,
        max_frames: usize,
    ) -> Result<(Option<usize>, OutOfCoreStats), String> {
        for i in 1..=max_frames {
            self.plan(r, camera, frame, settings)?;
            let s = r.stats().out_of_core.ok_or("not out of core")?;
            if s.converged {
                return Ok((Some(i), s));
            }
            // Give the loader threads the CPU (2 cores, shared with lavapipe).
            std::thread::sleep(Duration::from_millis(10));
        }
        Ok((None, r.stats().out_of_core.ok_or("not out of core")?))
    }
}

pub(crate) fn median(v: &[f64]) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The `p`-quantile (nearest rank).
pub(crate) fn quantile(v: &[f64], p: f64) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    let rank = ((p * v.len() as f64).ceil() as usize).clamp(1, v.len());
    v[rank - 1]
}

pub(crate) fn round2(x: f64) -> f64 {
    (x * 100.0).round() / 100.0
}

pub(crate) fn finite_db(x: f64) -> f64 {
    if x.is_finite() { round2(x) } else { 999.0 }
}

/// A renderer with `options` drawing `vol` in core through `tf`.
pub(crate) fn renderer_in_core(
    gpu: &GpuContext,
    options: RendererOptions,
    vol: &Volume,
    tf: &TransferFunction,
) -> Result<VolumeRenderer, String> {
    let mut r = VolumeRenderer::with_options(&gpu.device, brickray_harness::target_desc(), options)
        .map_err(|e| e.to_string())?;
    r.set_volume(&gpu.device, &gpu.queue, vol)
        .map_err(|e| e.to_string())?;
    r.set_transfer_function(&gpu.device, &gpu.queue, tf)
        .map_err(|e| e.to_string())?;
    Ok(r)
}

#[cfg(test)]
mod tests {
    use super::lane_samples;

    #[test]
    fn lane_groups_are_four_by_two_blocks() {
        // 8 x 2 pixels: two 4 x 2 groups; the longest ray of each sets it.
        let counts = [1, 2, 3, 4, 10, 0, 0, 0, 5, 6, 7, 8, 0, 0, 0, 1];
        assert_eq!(lane_samples(&counts, 8), 8 * 8 + 10 * 8);
        // An image 6 x 3: groups clipped at the edges (4x2, 2x2, 4x1, 2x1).
        let mut c = [0u32; 18];
        c[5] = 3; // (5, 0): the 2 x 2 group
        c[12] = 2; // (0, 2): the 4 x 1 group
        assert_eq!(lane_samples(&c, 6), 3 * 4 + 2 * 4);
        assert_eq!(lane_samples(&[], 0), 0);
    }
}
