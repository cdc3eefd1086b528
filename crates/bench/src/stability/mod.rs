//! The `stability` suite: scripted scenes that drive one method each to where it
//! breaks, measured against the f64 CPU reference (`brickray-reference`: PSNR
//! and mean FLIP of 8-bit RGB over black), reporting the setting brickray
//! ships and the bound it keeps.
//!
//! Cases (`--cases`, comma-separated numbers, default all):
//!
//! 1. streaming under a tiny pool and a slow source (delay per brick read);
//! 2. memory pressure: a pool smaller than the view needs, the camera circling;
//! 3. a high-frequency TF (narrow opacity spike) at steps 1/8 to 4 voxels;
//! 4. thin structures (one-voxel sheets, lines, bright voxels) at coarse
//!    levels, DVR, iso and MIP, average vs max downsampling;
//! 5. grazing rays: an orthographic view exactly axis-aligned with every ray on
//!    a voxel face (brick faces included), and a perspective view whose centre
//!    column lies in a brick face;
//! 6. precision at 65536^3: single voxels at the far corner, sample positions
//!    emulated in f32 and the image against the reference;
//! 7. early ray termination thresholds 0.9 to 0.999 on a translucent TF;
//! 8. the prediction buffer's failure path and the visibility feedback's
//!    disocclusion, error over frames;
//! 9. level-of-detail transitions along a fly-through and a zoom from far away
//!    to inside a procedural volume, fades on and off: the temporal metric
//!    against the reference's own change, pops and holes (`paths.rs`).
//!
//! Each case prints a table and returns a [`Case`]: what was varied, where it
//! fails, by how much, the shipped setting and the bound it keeps. The last
//! line holds `holes_max`, `cases_with_bound`, `cases_total` and the per-case
//! figures.
//!
//! `cargo run --release -p brickray-bench -- stability [--size 128] [--cases 1,2,...] [--charts docs/charts]`

mod detail;
mod geometry;
mod paths;
mod sampling;
mod streaming;
mod temporal;
mod util;

pub(crate) use util::*;

use brickray_harness::GpuContext;
use serde::Serialize;
use std::time::Instant;

/// What one case established.
#[derive(Debug, Serialize)]
pub(crate) struct Case {
    /// Short name (`streaming`, ...).
    pub(crate) name: &'static str,
    /// What was varied.
    pub(crate) varied: String,
    /// Where the method fails (or "does not fail in the range").
    pub(crate) fails: String,
    /// By how much.
    pub(crate) by: String,
    /// The shipped setting.
    pub(crate) shipped: String,
    /// The bound the shipped setting keeps, with its metric.
    pub(crate) bound: String,
    /// Whether the shipped setting kept the bound in this run.
    #[serde(rename = "kept")]
    pub(crate) holds: bool,
    /// Most hole pixels seen in any frame of the case.
    pub(crate) holes_max: u64,
    /// The case's own figures (each case's struct, serialised).
    #[serde(rename = "figures")]
    pub(crate) fig: serde_json::Value,
}

/// A case's typed figures as the value of its `figures` key.
pub(crate) fn figures<T: Serialize>(t: &T) -> serde_json::Value {
    serde_json::to_value(t).unwrap_or(serde_json::Value::Null)
}

/// What the cases share.
pub(crate) struct Ctx<'a> {
    pub(crate) gpu: &'a GpuContext,
    /// Image side.
    pub(crate) size: u32,
    /// Where charts go (`docs/charts` by default; empty: none).
    pub(crate) charts: String,
}

/// An image side for the stability cases: 32 to 1024.
fn case_size(s: &str) -> Result<u32, String> {
    let n: u32 = s.parse().map_err(|e| format!("{e}"))?;
    if (32..=1024).contains(&n) {
        Ok(n)
    } else {
        Err(format!("{n} is not in 32..=1024"))
    }
}

/// A case number: 1 to 9.
fn case_number(s: &str) -> Result<u32, String> {
    match s.trim().parse() {
        Ok(n @ 1..=9) => Ok(n),
        _ => Err(format!("no case {s} (1-9)")),
    }
}

/// The suite's options.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Image side in pixels (also the volumes' side).
    #[arg(long, default_value_t = 128, value_parser = case_size)]
    size: u32,
    /// Cases, comma-separated numbers 1-9.
    #[arg(long, value_delimiter = ',', default_value = "1,2,3,4,5,6,7,8,9", value_parser = case_number)]
    cases: Vec<u32>,
    /// Folder of the SVG charts (empty: none).
    #[arg(long, default_value = "docs/charts")]
    charts: String,
}

/// The suite's JSON line.
#[derive(Debug, Serialize)]
pub(crate) struct StabilityResult {
    image_size: u32,
    adapter: String,
    /// Most hole pixels in any frame of any case (and LOD path).
    holes_max: u64,
    /// Cases whose shipped setting kept its bound, of all run.
    cases_with_bound: usize,
    cases_total: usize,
    /// The LOD paths (case 9; null when not run).
    lod_paths: Option<paths::PathFigures>,
    cases: Vec<Case>,
}

pub(crate) fn run(args: &Args) -> Result<StabilityResult, String> {
    let (size, charts) = (args.size, args.charts.clone());
    let wanted = args.cases.clone();
    let cases = wanted
        .iter()
        .map(u32::to_string)
        .collect::<Vec<_>>()
        .join(",");
    if !(32..=1024).contains(&size) {
        return Err("--size must be in 32..=1024".into());
    }
    let gpu = GpuContext::new().map_err(|e| e.to_string())?;
    println!("adapter: {}", gpu.describe());
    println!("image {size}x{size}; cases {cases}; charts into {charts:?}");
    if !charts.is_empty() {
        std::fs::create_dir_all(&charts).map_err(|e| e.to_string())?;
    }
    let ctx = Ctx {
        gpu: &gpu,
        size,
        charts,
    };
    let t = Instant::now();
    let mut done: Vec<Case> = Vec::new();
    let mut lod_paths = None;
    for c in wanted {
        let t0 = Instant::now();
        if c == 9 {
            let opt = paths::PathOptions {
                size: ctx.size,
                ..Default::default()
            };
            let results = paths::cases(ctx.gpu, &opt)?;
            lod_paths = Some(paths::figures(&results));
            for s in paths::summaries(&results, &opt) {
                println!(
                    "  => {}: fails {}; by {}; shipped {}; bound {} ({}) [{:.0} s]",
                    s.name,
                    s.fails,
                    s.by,
                    s.shipped,
                    s.bound,
                    if s.holds { "kept" } else { "NOT KEPT" },
                    t0.elapsed().as_secs_f64()
                );
                done.push(s);
            }
            continue;
        }
        let case = match c {
            1 => streaming::streaming(&ctx)?,
            2 => streaming::pressure(&ctx)?,
            3 => sampling::high_frequency_tf(&ctx)?,
            4 => detail::thin_structures(&ctx)?,
            5 => geometry::grazing(&ctx)?,
            6 => geometry::precision(&ctx)?,
            7 => sampling::ert(&ctx)?,
            8 => temporal::prediction_and_disocclusion(&ctx)?,
            _ => return Err(format!("no case {c} (1-9)")),
        };
        println!(
            "  => {}: fails {}; by {}; shipped {}; bound {} ({}) [{:.0} s]",
            case.name,
            case.fails,
            case.by,
            case.shipped,
            case.bound,
            if case.holds { "kept" } else { "NOT KEPT" },
            t0.elapsed().as_secs_f64()
        );
        done.push(case);
    }

    println!("\nsummary (case | where it fails | by how much | shipped | bound | kept):");
    for c in &done {
        println!(
            "  {} | {} | {} | {} | {} | {}",
            c.name,
            c.fails,
            c.by,
            c.shipped,
            c.bound,
            if c.holds { "yes" } else { "NO" }
        );
    }
    println!("suite wall time: {:.0} s", t.elapsed().as_secs_f64());
    Ok(StabilityResult {
        image_size: size,
        adapter: gpu.adapter.get_info().name,
        holes_max: done
            .iter()
            .map(|c| c.holes_max)
            .chain(lod_paths.as_ref().map(|p| p.holes_max as u64))
            .max()
            .unwrap_or(0),
        cases_with_bound: done.iter().filter(|c| c.holds).count(),
        cases_total: done.len(),
        lod_paths,
        cases: done,
    })
}
