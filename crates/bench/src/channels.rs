//! The `channels` suite: what 2 and 4 channels cost against one, in core
//! and out of core.
//!
//! The shared confocal nuclei (u16, 256x256x60) and transformed copies of it
//! as 1, 2 and 4 channels (`brickray_harness::channels`), each in its own
//! colour and window, one view, the default step:
//!
//! * **cost**: ms per frame (`prepare + submit + wait`, median of
//!   `--rounds` interleaved rounds at `--size` px) of DVR, shaded DVR, MIP
//!   and per-channel isosurfaces, for 1, 2 and 4 channels and for the
//!   single-channel kernel with channel 0's transfer function (what one
//!   channel costs through the multi-channel kernel); samples per ray; the
//!   same out of core: each channel built into a brick store (32-voxel
//!   bricks) and the channels streamed as one `ChannelSource`, at the
//!   finest level (tolerance 0, timed once the cut has settled);
//! * **bytes**: texel bytes per voxel of the packed texture, and bytes of
//!   one prepared brick (texels and sub-cell ranges) out of core;
//! * **error**: each case against the CPU reference
//!   (`render_channels_reference`) at the same step, at 128 px.
//!
//! With `--adaptive`, also DVR with the adaptive step (`dvr adaptive`).
//!
//! `cargo run --release -p brickray-bench -- channels [--size PX] [--rounds N] [--adaptive]`

use crate::report::Timing;
use brickray_core::channels::ChannelVolume;
use brickray_core::{Camera, RenderMode, RenderSettings, VolumeFrame};
use brickray_harness::channels::{modes, nuclei_channels, nuclei_styles};
use brickray_harness::predict::{FrameResult, draw, draw_timed, samples_per_ray};
use brickray_harness::{GpuContext, GpuTimer, Offscreen};
use brickray_reference::{ReferenceOptions, compare, render_channels_reference};
use brickray_render::{FrameDesc, VolumeRenderer};

/// The error images' side.
const ERROR_SIZE: u32 = 128;
/// Channel counts measured.
const COUNTS: [usize; 3] = [1, 2, 4];

/// One mode's figures.
#[derive(Debug, serde::Serialize)]
pub(crate) struct ModeRow {
    mode: &'static str,
    /// Median ms per frame of the single-channel kernel (channel 0).
    single_ms: f64,
    /// Median ms per frame with 1, 2 and 4 channels.
    ms: [f64; 3],
    /// Samples per ray with 1, 2 and 4 channels.
    samples_per_ray: [f64; 3],
    /// PSNR against the reference with 1, 2 and 4 channels.
    psnr_db: [f64; 3],
    /// The same out of core (streamed channels at the finest level).
    ooc_ms: [f64; 3],
    ooc_psnr_db: [f64; 3],
    /// The ray-cast pass's median time by GPU timestamps (null without):
    /// single-channel kernel, 1/2/4 channels in core and out of core.
    single_gpu_ms: Option<f64>,
    gpu_ms: [Option<f64>; 3],
    ooc_gpu_ms: [Option<f64>; 3],
}

/// The suite's result (its JSON line).
#[derive(Debug, serde::Serialize)]
pub(crate) struct ChannelsResult {
    size: u32,
    rounds: usize,
    /// Texel bytes per voxel with 1, 2 and 4 channels.
    bytes_per_voxel: [u32; 3],
    modes: Vec<ModeRow>,
    /// The largest ratio over the modes of 2 (4) channels' ms to 1's.
    cost_ratio_2ch: f64,
    cost_ratio_4ch: f64,
    /// The largest ratio of one channel through the multi-channel kernel
    /// to the single-channel kernel.
    one_channel_overhead: f64,
    /// Out of core: bytes of one prepared brick with 1, 2 and 4 channels,
    /// and the largest ratios of 2 (4) channels' ms to 1's.
    ooc_bytes_per_brick: [u64; 3],
    ooc_cost_ratio_2ch: f64,
    ooc_cost_ratio_4ch: f64,
    /// The largest ratio over modes and counts of out of core to in core.
    ooc_over_incore: f64,
    /// The smallest PSNR in core and out of core.
    psnr_min_db: f64,
}

/// The channels of `vols[last]` built into stores under `dir`, and a
/// renderer streaming the first `n` of them for each count.
fn streamed(
    gpu: &GpuContext,
    vols: &[ChannelVolume],
    dir: &std::path::Path,
) -> Result<Vec<VolumeRenderer>, String> {
    let all = vols.last().ok_or("no volume")?;
    let parts: Vec<std::sync::Arc<dyn brickray_core::BrickSource>> = all
        .channels()
        .iter()
        .enumerate()
        .map(|(c, v)| brickray_harness::store_of(v, &dir.join(format!("c{c}.brs"))))
        .collect();
    let config = brickray_cache::OutOfCoreConfig {
        tolerance_px: 0.0,
        upload_budget_bytes: 1 << 30,
        ..Default::default()
    };
    COUNTS
        .iter()
        .map(|&n| {
            let src = brickray_core::ChannelSource::new(parts[..n].to_vec())
                .map_err(|e| e.to_string())?;
            let mut r = VolumeRenderer::new(&gpu.device, brickray_harness::target_desc())
                .map_err(|e| e.to_string())?;
            r.set_volume_source(&gpu.device, &gpu.queue, std::sync::Arc::new(src), config)
                .map_err(|e| e.to_string())?;
            r.set_channel_styles(&nuclei_styles(n))
                .map_err(|e| e.to_string())?;
            Ok(r)
        })
        .collect()
}

/// The suite's options.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Image side in pixels of the timed frames.
    #[arg(long, default_value_t = 256, value_parser = crate::image_side)]
    size: u32,
    /// Interleaved rounds.
    #[arg(long, default_value_t = 5, value_parser = crate::at_least_one::<usize>)]
    rounds: usize,
    /// Also DVR with the adaptive step (`Accel::adaptive_step`), its error
    /// against the reference with the same step rule.
    #[arg(long)]
    adaptive: bool,
}

pub(crate) fn run(args: &Args) -> Result<ChannelsResult, String> {
    let (size, rounds) = (args.size, args.rounds);
    let gpu = GpuContext::new().map_err(|e| e.to_string())?;
    println!("adapter: {}", gpu.describe());
    println!("timing at {size}x{size}, {rounds} interleaved rounds; errors at {ERROR_SIZE} px");
    let vols: Vec<ChannelVolume> = COUNTS
        .iter()
        .map(|&n| nuclei_channels(n).ok_or("the channels suite needs ../shared/data"))
        .collect::<Result<_, _>>()?;
    let d = vols[0].desc().clone();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let camera = Camera::orbit(frame.center(), 2.0, 0.5, 0.6);
    let mut renderers = Vec::new();
    for (vol, &n) in vols.iter().zip(&COUNTS) {
        let mut r = VolumeRenderer::new(&gpu.device, brickray_harness::target_desc())
            .map_err(|e| e.to_string())?;
        r.set_channel_volume(&gpu.device, &gpu.queue, vol)
            .map_err(|e| e.to_string())?;
        r.set_channel_styles(&nuclei_styles(n))
            .map_err(|e| e.to_string())?;
        renderers.push(r);
    }
    let style0 = nuclei_styles(1).remove(0);
    let mut single = VolumeRenderer::new(&gpu.device, brickray_harness::target_desc())
        .map_err(|e| e.to_string())?;
    single
        .set_volume(&gpu.device, &gpu.queue, &vols[0].channels()[0])
        .map_err(|e| e.to_string())?;
    single
        .set_transfer_function(&gpu.device, &gpu.queue, &style0.tf)
        .map_err(|e| e.to_string())?;
    let bytes_per_voxel: [u32; 3] = std::array::from_fn(|i| {
        let v = renderers[i].volume_bytes() / d.voxel_count();
        v as u32
    });
    let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
    let mut ooc = streamed(&gpu, &vols, dir.path())?;
    let ooc_bytes_per_brick: [u64; 3] = std::array::from_fn(|i| {
        ooc[i].streamed_volume().map_or(0, |v| {
            let layout = v.layout();
            v.inspect(|s| s.gpu_format().prepared_brick_bytes(&layout).unwrap_or(0))
        })
    });
    let target = Offscreen::new(&gpu.device, size, size);
    let small = Offscreen::new(&gpu.device, ERROR_SIZE, ERROR_SIZE);
    let mut rows = Vec::new();
    println!(
        "| mode | single-channel kernel ms | 1 / 2 / 4 channels ms | 2ch / 1ch | 4ch / 1ch | samples per ray | PSNR 1 / 2 / 4 ch (dB) |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|");
    let mut cases = modes(RenderSettings::default().step_factor, 0.35);
    if args.adaptive {
        let mut s = cases[0].1;
        s.accel.adaptive_step = true;
        cases.insert(1, ("dvr adaptive", s));
    }
    for (mode, settings) in cases {
        let mut desc = FrameDesc {
            settings,
            ..FrameDesc::new(camera, frame, size, size)
        };
        let mut single_desc = desc.clone();
        if let RenderMode::Iso { .. } = settings.mode {
            single_desc.settings.mode = RenderMode::Iso {
                value: style0.isovalue,
                color: style0.iso_color(),
            };
        }
        // Warm-up: pipelines compiled, tables built.
        let err = |e: brickray_render::PrepareError| e.to_string();
        draw(&gpu, &mut single, &target, &single_desc).map_err(err)?;
        let mut spr = [0.0; 3];
        for (i, r) in renderers.iter_mut().enumerate() {
            spr[i] = samples_per_ray(&draw(&gpu, r, &target, &desc).map_err(err)?.samples);
        }
        for r in ooc.iter_mut() {
            settle(&gpu, r, &target, &desc)?;
        }
        let mut single_t = Vec::new();
        let mut times: [Vec<(f64, Option<f64>)>; 3] = Default::default();
        let mut ooc_times: [Vec<(f64, Option<f64>)>; 3] = Default::default();
        let timer = GpuTimer::new(&gpu);
        let t = timer.as_ref();
        let ms_of = |f: FrameResult| (f.ms, f.gpu_ms);
        for _ in 0..rounds {
            single_t.push(ms_of(
                draw_timed(&gpu, &mut single, &target, &single_desc, t).map_err(err)?,
            ));
            for (i, r) in renderers.iter_mut().enumerate() {
                times[i].push(ms_of(draw_timed(&gpu, r, &target, &desc, t).map_err(err)?));
            }
            for (i, r) in ooc.iter_mut().enumerate() {
                ooc_times[i].push(ms_of(draw_timed(&gpu, r, &target, &desc, t).map_err(err)?));
            }
        }
        let single_timing = Timing::of_times(single_t);
        let timing: [Timing; 3] = std::array::from_fn(|i| Timing::of_times(times[i].clone()));
        let ooc_timing: [Timing; 3] =
            std::array::from_fn(|i| Timing::of_times(ooc_times[i].clone()));
        desc.viewport = brickray_render::Viewport::full(ERROR_SIZE, ERROR_SIZE);
        let mut psnr = [0.0; 3];
        let mut ooc_psnr = [0.0; 3];
        for (i, vol) in vols.iter().enumerate() {
            let opts = ReferenceOptions::new(ERROR_SIZE, ERROR_SIZE)
                .with_step_factor(settings.step_factor)
                .with_adaptive_step(settings.accel.adaptive_step);
            let want = render_channels_reference(
                vol,
                &frame,
                &nuclei_styles(COUNTS[i]),
                &camera,
                &settings,
                &opts,
            )
            .to_rgba8([0.0; 3]);
            let got = draw(&gpu, &mut renderers[i], &small, &desc)
                .map_err(err)?
                .color;
            psnr[i] = compare(&got, &want, ERROR_SIZE, ERROR_SIZE).psnr_db;
            let got = settle(&gpu, &mut ooc[i], &small, &desc)?;
            ooc_psnr[i] = compare(&got, &want, ERROR_SIZE, ERROR_SIZE).psnr_db;
        }
        let row = ModeRow {
            mode,
            single_ms: single_timing.ms,
            ms: timing.map(|t| t.ms),
            samples_per_ray: spr,
            psnr_db: psnr,
            ooc_ms: ooc_timing.map(|t| t.ms),
            ooc_psnr_db: ooc_psnr,
            single_gpu_ms: single_timing.gpu_ms,
            gpu_ms: timing.map(|t| t.gpu_ms),
            ooc_gpu_ms: ooc_timing.map(|t| t.gpu_ms),
        };
        println!(
            "| {mode} | {:.1} | {:.1} / {:.1} / {:.1} | {:.2} | {:.2} | {:.1} / {:.1} / {:.1} | {:.1} / {:.1} / {:.1} |",
            row.single_ms,
            row.ms[0],
            row.ms[1],
            row.ms[2],
            row.ms[1] / row.ms[0],
            row.ms[2] / row.ms[0],
            spr[0],
            spr[1],
            spr[2],
            psnr[0],
            psnr[1],
            psnr[2]
        );
        println!(
            "| {mode} out of core | | {:.1} / {:.1} / {:.1} | {:.2} | {:.2} | | {:.1} / {:.1} / {:.1} |",
            row.ooc_ms[0],
            row.ooc_ms[1],
            row.ooc_ms[2],
            row.ooc_ms[1] / row.ooc_ms[0],
            row.ooc_ms[2] / row.ooc_ms[0],
            ooc_psnr[0],
            ooc_psnr[1],
            ooc_psnr[2]
        );
        rows.push(row);
    }
    let max_over = |f: &dyn Fn(&ModeRow) -> f64| rows.iter().map(f).fold(0.0f64, f64::max);
    let result = ChannelsResult {
        size,
        rounds,
        bytes_per_voxel,
        cost_ratio_2ch: max_over(&|r| r.ms[1] / r.ms[0]),
        cost_ratio_4ch: max_over(&|r| r.ms[2] / r.ms[0]),
        one_channel_overhead: max_over(&|r| r.ms[0] / r.single_ms),
        ooc_bytes_per_brick,
        ooc_cost_ratio_2ch: max_over(&|r| r.ooc_ms[1] / r.ooc_ms[0]),
        ooc_cost_ratio_4ch: max_over(&|r| r.ooc_ms[2] / r.ooc_ms[0]),
        ooc_over_incore: max_over(&|r| (0..3).map(|i| r.ooc_ms[i] / r.ms[i]).fold(0.0, f64::max)),
        psnr_min_db: rows
            .iter()
            .flat_map(|r| r.psnr_db.into_iter().chain(r.ooc_psnr_db))
            .fold(f64::INFINITY, f64::min),
        modes: rows,
    };
    println!(
        "bytes per voxel 1 / 2 / 4 channels: {:?}; worst 2ch / 1ch {:.2}, 4ch / 1ch {:.2}; one channel / single-channel kernel {:.2}; PSNR min {:.1} dB",
        result.bytes_per_voxel,
        result.cost_ratio_2ch,
        result.cost_ratio_4ch,
        result.one_channel_overhead,
        result.psnr_min_db
    );
    println!(
        "out of core: bytes per brick {:?}; worst 2ch / 1ch {:.2}, 4ch / 1ch {:.2}; worst out of core / in core {:.2}",
        result.ooc_bytes_per_brick,
        result.ooc_cost_ratio_2ch,
        result.ooc_cost_ratio_4ch,
        result.ooc_over_incore
    );
    Ok(result)
}

/// Draws `desc` until the streamed volume settles (every brick the view
/// needs arrived); returns the last frame's colour.
fn settle(
    gpu: &GpuContext,
    r: &mut VolumeRenderer,
    target: &Offscreen,
    desc: &FrameDesc<'_>,
) -> Result<Vec<u8>, String> {
    brickray_harness::draw_until_settled(gpu, r, target, desc, 500)
        .map_err(|e| e.to_string())?
        .ok_or("the streamed channels did not settle in 500 frames")?;
    Ok(draw(gpu, r, target, desc).map_err(|e| e.to_string())?.color)
}
