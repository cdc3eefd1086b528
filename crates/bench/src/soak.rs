//! The `soak` suite: 10,000 frames at 64x64 of a 65536^3 procedural volume with a
//! 64 MiB pool and a 32 MiB CPU cache, a random camera each frame (jumps, inside
//! the volume, extreme zoom, every depth convention and mode), process memory
//! sampled every 250 frames. Reports RSS at frame 250 and at the end, the
//! maximum, frame time median and p99 per 1,000 frames, stalls and panics.
//! A stall is a frame over 10x both the median frame time and what its own
//! work predicts (its samples times the median time per sample); frames over
//! 10x the median alone are reported beside it (with a random camera most of
//! them are views that are expensive by nature, such as a MIP through a finely
//! refined region).
//!
//! `cargo run --release -p brickray-bench -- soak [--frames N] [--size PX]`

use brickray_harness::GpuContext;
use brickray_harness::soak::{self, FeatureFrames, SoakConfig};
use serde::Serialize;

/// The suite's options.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Frames.
    #[arg(long, default_value_t = SoakConfig::default().frames, value_parser = crate::at_least_one::<usize>)]
    frames: usize,
    /// Image side in pixels.
    #[arg(long, default_value_t = SoakConfig::default().size, value_parser = crate::image_side)]
    size: u32,
}

/// Frames in which each feature was at work (`FeatureFrames`).
#[derive(Debug, Serialize)]
pub(crate) struct Features {
    frames: u64,
    dvr: u64,
    iso: u64,
    mip: u64,
    reversed_z: u64,
    prediction: u64,
    visibility: u64,
    culled: u64,
    occlusion_queries: u64,
    usage_feedback: u64,
    fades: u64,
    uploads: u64,
}

impl From<FeatureFrames> for Features {
    fn from(f: FeatureFrames) -> Features {
        Features {
            frames: f.frames as u64,
            dvr: f.dvr as u64,
            iso: f.iso as u64,
            mip: f.mip as u64,
            reversed_z: f.reversed_z as u64,
            prediction: f.prediction as u64,
            visibility: f.visibility as u64,
            culled: f.culled as u64,
            occlusion_queries: f.occlusion_queries as u64,
            usage_feedback: f.usage_feedback as u64,
            fades: f.fades as u64,
            uploads: f.uploads as u64,
        }
    }
}

/// The suite's JSON line.
#[derive(Debug, Serialize)]
pub(crate) struct SoakResult {
    frames: usize,
    /// Process RSS at frame 250, at the end, and its maximum, MiB.
    rss_start_mib: f64,
    rss_end_mib: f64,
    rss_max_mib: f64,
    /// RSS growth from frame 250 to the end, percent.
    rss_growth_pct: f64,
    /// The last block's median frame time over the first's.
    frame_time_drift: f64,
    /// Median and p99 frame time of each block of 1,000 frames, ms.
    median_ms_per_1000: Vec<f64>,
    p99_ms_per_1000: Vec<f64>,
    /// Frames over 10x the median and what their work predicts.
    stalls: usize,
    /// Frames over 10x the median alone.
    frames_over_10x_median: usize,
    /// Frames in which each feature was active.
    feature_frames: Features,
    errors: usize,
    panics: usize,
}

pub(crate) fn run(args: &Args) -> Result<SoakResult, String> {
    let config = SoakConfig {
        frames: args.frames,
        size: args.size,
        ..SoakConfig::default()
    };
    let gpu = GpuContext::new().map_err(|e| e.to_string())?;
    println!("adapter: {}", gpu.describe());
    println!(
        "soak: {} frames at {}x{} of a {}^3 procedural volume, pool {} MiB, CPU cache {} MiB, prediction {}, visibility {:?}",
        config.frames,
        config.size,
        config.size,
        config.volume,
        config.gpu_budget_bytes >> 20,
        config.cpu_budget_bytes >> 20,
        if config.prediction.is_some() {
            "on"
        } else {
            "off"
        },
        config.visibility
    );
    let every = config.sample_every;
    let r = soak::run(&gpu, config, |i, _| {
        if (i + 1) % every == 0 {
            println!(
                "  frame {:>6}: RSS {:>7.1} MiB",
                i + 1,
                soak::rss_bytes() as f64 / (1 << 20) as f64
            );
        }
    })?;
    let mib = |b: u64| b as f64 / (1 << 20) as f64;
    let blocks = r.blocks(1000);
    for (i, (med, p99)) in blocks.iter().enumerate() {
        println!(
            "  frames {:>5}-{:>5}: median {med:.2} ms, p99 {p99:.2} ms",
            i * 1000,
            (i + 1) * 1000 - 1
        );
    }
    let start = every.min(config.frames);
    let max = r.rss.iter().map(|s| s.1).max().unwrap_or(0);
    let growth = r.rss_growth_pct(start);
    let drift = r.drift(1000);
    let stall_list = r.stalls(10.0);
    let stalls = stall_list.len();
    let slow = r.slow_frames(10.0);
    println!(
        "RSS {:.1} MiB at frame {start}, {:.1} MiB at the end ({growth:+.1}%), max {:.1} MiB; drift {drift:.3}; {stalls} stalls ({slow} frames over 10x the median, by the view's work); {} errors; {} panics",
        mib(r.rss_at(start)),
        mib(r.rss.last().map_or(0, |s| s.1)),
        mib(max),
        r.errors,
        r.panics
    );
    println!("features active: {}", r.features.describe());
    for (i, ms, samples) in &stall_list {
        println!("  stall: frame {i}, {ms:.1} ms, {samples} samples");
    }
    if let Some(f) = &r.first_failure {
        println!("first failure: {f}");
    }
    Ok(SoakResult {
        frames: config.frames,
        rss_start_mib: mib(r.rss_at(start)),
        rss_end_mib: mib(r.rss.last().map_or(0, |s| s.1)),
        rss_max_mib: mib(max),
        rss_growth_pct: growth,
        frame_time_drift: drift,
        median_ms_per_1000: blocks.iter().map(|b| b.0).collect(),
        p99_ms_per_1000: blocks.iter().map(|b| b.1).collect(),
        stalls,
        frames_over_10x_median: slow,
        feature_frames: r.features.into(),
        errors: r.errors,
        panics: r.panics,
    })
}
