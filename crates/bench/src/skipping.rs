//! The `skipping` suite: whether MIP's empty-space skipping pays in core, and
//! whether the rule that decides it from the macro cells
//! (`brickray_core::mip_skipping_pays`, `MipSkipping::WherePays`) chooses
//! right.
//!
//! Per volume (fractal noise and Marschner-Lobb, 128^3, and the shared
//! volumes where present): the share of cells certain to be skipped
//! (`MacroCellGrid::mip_skip_share`), the rule's decision, and MIP frames
//! without skipping, with it always (`MipSkipping::Always`), and as the rule
//! decides, interleaved round by round; samples per ray of each.

use crate::report::{RunInfo, Timing, interleave};
use crate::runner::{Runner, renderer_in_core, round2};
use brickray_core::{
    Accel, Camera, MacroCellGrid, RenderMode, RenderSettings, TransferFunction, Volume,
    VolumeFrame, synthetic,
};
use brickray_harness::GpuContext;
use brickray_render::{MipSkipping, RendererOptions};
use serde::Serialize;

/// The suite's options.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Image side in pixels.
    #[arg(long, default_value_t = 256, value_parser = crate::image_side)]
    size: u32,
    /// Interleaved rounds.
    #[arg(long, default_value_t = 5, value_parser = crate::at_least_one::<usize>)]
    rounds: usize,
    /// Voxels per side of the procedural volumes.
    #[arg(long, default_value_t = 128, value_parser = crate::at_least_one::<u32>)]
    side: u32,
}

/// One volume.
#[derive(Debug, Serialize)]
pub(crate) struct Row {
    volume: String,
    dims: [u32; 3],
    /// `MacroCellGrid::mip_skip_share` (cells of 8^3 voxels).
    skip_share: f64,
    /// The rule's decision.
    rule_skips: bool,
    off: Timing,
    always: Timing,
    rule: Timing,
    samples_per_ray_off: f64,
    samples_per_ray_always: f64,
    /// Always skipping, and the rule, over no skipping (wall time).
    always_over_off: f64,
    rule_over_off: f64,
}

/// The suite's JSON line.
#[derive(Debug, Serialize)]
pub(crate) struct SkippingResult {
    #[serde(flatten)]
    run: RunInfo,
    rows: Vec<Row>,
    /// The largest rule over no-skipping ratio.
    rule_over_off_max: f64,
    /// The largest always-skipping over no-skipping ratio.
    always_over_off_max: f64,
    /// Volumes where the rule chose the slower of skipping and not (by more
    /// than 5%).
    wrong_decisions: usize,
}

/// The volumes: the procedural two, then the shared ones present.
fn volumes(side: u32) -> Vec<(String, Volume)> {
    let mut out = vec![
        (
            format!("fractal noise {side}^3"),
            brickray_harness::scenes::pareto_noise(side),
        ),
        (
            format!("Marschner-Lobb {side}^3"),
            synthetic::marschner_lobb(side),
        ),
    ];
    for name in [
        "pycortex_s1_t1_mri",
        "mricron_ch2_mri",
        "invesalius_cranium_ct",
        "cells3d_nuclei_fluo",
        "cryoet_tomo",
    ] {
        let read =
            brickray_harness::shared_volume(name).and_then(|p| brickray_io::read_volume(&p).ok());
        match read {
            Some(v) => out.push((name.to_string(), v)),
            None => println!("{name}: left out (no ../shared/data)"),
        }
    }
    out
}

pub(crate) fn run(args: &Args) -> Result<SkippingResult, String> {
    let (rounds, size) = (args.rounds, args.size);
    let gpu = GpuContext::new().map_err(|e| e.to_string())?;
    println!("adapter: {}", gpu.describe());
    println!("MIP in core, {size}x{size}, {rounds} interleaved rounds");
    println!(
        "  {:<28} {:>6} {:>6} {:>9} {:>16} {:>16}",
        "volume", "share", "rule", "off ms", "always ms (x)", "rule ms (x)"
    );
    let run = Runner::new(&gpu, size)?;
    let mut rows = Vec::new();
    for (name, vol) in volumes(args.side) {
        let grid = MacroCellGrid::build(&vol, 8);
        let (share, rule_skips) = (
            grid.mip_skip_share(),
            brickray_core::mip_skipping_pays(&grid),
        );
        let d = vol.desc();
        let frame = VolumeFrame::centered(d.dims, d.spacing);
        let camera = Camera::orbit(frame.center(), 2.0, 0.5, 0.3);
        let tf = TransferFunction::ramp(0.0, 1.0, 1.0);
        let with = |mip_skipping| RendererOptions {
            mip_skipping,
            ..Default::default()
        };
        let mut always = renderer_in_core(&gpu, with(MipSkipping::Always), &vol, &tf)?;
        let mut rule = renderer_in_core(&gpu, with(MipSkipping::WherePays), &vol, &tf)?;
        let settings = |ess: bool| RenderSettings {
            mode: RenderMode::Mip,
            accel: Accel {
                early_termination: Some(0.99),
                empty_space_skipping: ess,
            },
            ..Default::default()
        };
        // Warm-up, with the samples per ray.
        let off_shot = run.frame(&mut always, camera, frame, settings(false), true)?;
        let on_shot = run.frame(&mut always, camera, frame, settings(true), true)?;
        run.frame(&mut rule, camera, frame, settings(true), false)?;
        let shots = interleave(rounds, 3, |i| match i {
            0 => run.frame(&mut always, camera, frame, settings(false), false),
            1 => run.frame(&mut always, camera, frame, settings(true), false),
            _ => run.frame(&mut rule, camera, frame, settings(true), false),
        })?;
        // Wall time (two renderers alternate, as in the shading suite).
        let t: Vec<Timing> = shots
            .iter()
            .map(|s| Timing::of_times(s.iter().map(|f| (f.ms, None))))
            .collect();
        let row = Row {
            volume: name,
            dims: vol.dims(),
            skip_share: (share * 1000.0).round() / 1000.0,
            rule_skips,
            always_over_off: round2(t[1].ms / t[0].ms),
            rule_over_off: round2(t[2].ms / t[0].ms),
            off: t[0],
            always: t[1],
            rule: t[2],
            samples_per_ray_off: round2(off_shot.samples),
            samples_per_ray_always: round2(on_shot.samples),
        };
        println!(
            "  {:<28} {:>6.3} {:>6} {:>9.1} {:>9.1} ({:.2}) {:>9.1} ({:.2})",
            row.volume,
            row.skip_share,
            if row.rule_skips { "skip" } else { "off" },
            row.off.ms,
            row.always.ms,
            row.always_over_off,
            row.rule.ms,
            row.rule_over_off
        );
        rows.push(row);
    }
    let max = |f: fn(&Row) -> f64| rows.iter().map(f).fold(f64::NEG_INFINITY, f64::max);
    let wrong_decisions = rows
        .iter()
        .filter(|r| {
            (r.rule_skips && r.always_over_off > 1.05)
                || (!r.rule_skips && r.always_over_off < 0.95)
        })
        .count();
    Ok(SkippingResult {
        run: RunInfo::new(&gpu, size, rounds, "procedural and shared volumes"),
        rule_over_off_max: max(|r| r.rule_over_off),
        always_over_off_max: max(|r| r.always_over_off),
        wrong_decisions,
        rows,
    })
}
