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

use crate::{Figures, arg};
use brickray_harness::GpuContext;
use brickray_harness::soak::{self, SoakConfig};
use serde_json::json;

pub(crate) fn run(args: &[String]) -> Result<Figures, String> {
    let d = SoakConfig::default();
    let config = SoakConfig {
        frames: arg(args, "--frames", d.frames)?,
        size: arg(args, "--size", d.size)?,
        ..d
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
    let mut fig = Figures::new();
    fig.insert("frames".into(), json!(config.frames));
    fig.insert("rss_start_mib".into(), json!(mib(r.rss_at(start))));
    fig.insert(
        "rss_end_mib".into(),
        json!(mib(r.rss.last().map_or(0, |s| s.1))),
    );
    fig.insert("rss_max_mib".into(), json!(mib(max)));
    fig.insert("rss_growth_pct".into(), json!(growth));
    fig.insert("frame_time_drift".into(), json!(drift));
    fig.insert(
        "median_ms_per_1000".into(),
        json!(blocks.iter().map(|b| b.0).collect::<Vec<_>>()),
    );
    fig.insert(
        "p99_ms_per_1000".into(),
        json!(blocks.iter().map(|b| b.1).collect::<Vec<_>>()),
    );
    fig.insert("stalls".into(), json!(stalls));
    fig.insert("frames_over_10x_median".into(), json!(slow));
    let f = r.features;
    fig.insert(
        "feature_frames".into(),
        json!({
            "frames": f.frames,
            "dvr": f.dvr,
            "iso": f.iso,
            "mip": f.mip,
            "reversed_z": f.reversed_z,
            "prediction": f.prediction,
            "visibility": f.visibility,
            "culled": f.culled,
            "occlusion_queries": f.occlusion_queries,
            "usage_feedback": f.usage_feedback,
            "fades": f.fades,
            "uploads": f.uploads,
        }),
    );
    fig.insert("errors".into(), json!(r.errors));
    fig.insert("panics".into(), json!(r.panics));
    Ok(fig)
}
