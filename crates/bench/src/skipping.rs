//! The `skipping` suite: whether MIP's empty-space skipping pays, in core and
//! out of core, and whether the rules that decide it (`SkipRule::WherePays`:
//! in core from the macro cells, `brickray_core::mip_skipping_pays`; out of
//! core from the sub-cells of the cut's bricks,
//! `brickray_core::MIP_SKIP_SHARE_MIN_BRICKS`) choose right.
//!
//! Per volume (fractal noise and Marschner-Lobb, 128^3, and the shared
//! volumes where present): the share of cells certain to be skipped
//! (`MacroCellGrid::mip_skip_share`; out of core, within each finest brick,
//! `brickray_harness::finest_bricks_mip_share`), the rule's decision, and
//! MIP frames without skipping, with it always (`SkipRule::Always`), and
//! as the rule decides, interleaved round by round; samples per ray of each.
//! Out of core the volume is a brick store (bricks of 32) drawn at its
//! finest level, converged before timing. Then DVR through three ramps per
//! volume (opaque from 0, 30% and 60% of the range), unshaded and shaded,
//! in core with and without its rule (`brickray_core::dvr_skip_share_min`,
//! the share of macro cells transparent through the TF) and out of core
//! with and without its own (`brickray_core::dvr_skip_share_min_bricks`,
//! the share of the drawn bricks' sub-cells transparent).

use crate::report::{RunInfo, Timing, interleave};
use crate::runner::{Runner, renderer_in_core, round2};
use brickray_core::{
    Accel, Camera, MacroCellGrid, RenderMode, RenderSettings, TransferFunction, Volume,
    VolumeFrame, synthetic,
};
use brickray_harness::GpuContext;
use brickray_render::{OutOfCoreConfig, RendererOptions, SkipRule, VolumeRenderer};
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
    /// Sample step in voxels of every frame (the rules' thresholds were
    /// measured at the default, 0.5; `brickray_core::skip_share_min`).
    #[arg(long, default_value_t = 0.5, value_parser = crate::sample_step)]
    step: f32,
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
    /// Every frame's sample step, voxels.
    step_voxels: f32,
    rows: Vec<Row>,
    /// The same out of core (`skip_share`: within each finest brick).
    ooc_rows: Vec<Row>,
    /// Out of core, as the three figures below.
    ooc_rule_over_off_max: f64,
    ooc_always_over_off_max: f64,
    ooc_wrong_decisions: usize,
    /// DVR in core through three ramps per volume (`skip_share`: the macro
    /// cells transparent through the TF), and the figures below.
    dvr_rows: Vec<Row>,
    dvr_rule_over_off_max: f64,
    dvr_always_over_off_max: f64,
    dvr_wrong_decisions: usize,
    /// The same, shaded.
    dvr_shaded_rows: Vec<Row>,
    dvr_shaded_rule_over_off_max: f64,
    dvr_shaded_always_over_off_max: f64,
    dvr_shaded_wrong_decisions: usize,
    /// DVR out of core through the same ramps (no rule: always skips).
    dvr_ooc_rows: Vec<Row>,
    dvr_ooc_always_over_off_max: f64,
    /// Out of core DVR under its rule (`SkipRule::WherePays`), and where it
    /// chose the slower by more than 5%.
    dvr_ooc_rule_over_off_max: f64,
    dvr_ooc_wrong_decisions: usize,
    /// The same out of core, shaded (the streamed volume's default
    /// gradients: kept per brick where its budget holds them).
    dvr_shaded_ooc_rows: Vec<Row>,
    dvr_shaded_ooc_always_over_off_max: f64,
    dvr_shaded_ooc_rule_over_off_max: f64,
    dvr_shaded_ooc_wrong_decisions: usize,
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
    let (rounds, size, step) = (args.rounds, args.size, args.step);
    let gpu = GpuContext::new().map_err(|e| e.to_string())?;
    println!("adapter: {}", gpu.describe());
    println!("MIP and DVR, {size}x{size}, step {step} voxel, {rounds} interleaved rounds");
    println!(
        "  {:<36} {:>6} {:>6} {:>9} {:>16} {:>16}",
        "volume", "share", "rule", "off ms", "always ms (x)", "rule ms (x)"
    );
    let run = Runner::new(&gpu, size)?;
    let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
    let (mut rows, mut ooc_rows) = (Vec::new(), Vec::new());
    let (mut dvr_rows, mut dvr_ooc_rows) = (Vec::new(), Vec::new());
    let (mut dvr_shaded_rows, mut dvr_shaded_ooc_rows) = (Vec::new(), Vec::new());
    let mip = RenderMode::Mip;
    for (i, (name, vol)) in volumes(args.side).into_iter().enumerate() {
        let grid = MacroCellGrid::build(&vol, 8);
        let d = vol.desc();
        let frame = VolumeFrame::centered(d.dims, d.spacing);
        let camera = Camera::orbit(frame.center(), 2.0, 0.5, 0.3);
        let tf = TransferFunction::ramp(0.0, 1.0, 1.0);
        let with = |mip_skipping| RendererOptions {
            mip_skipping,
            ..Default::default()
        };
        let share = grid.mip_skip_share();
        let mut always = renderer_in_core(&gpu, with(SkipRule::Always), &vol, &tf)?;
        let mut rule = renderer_in_core(&gpu, with(SkipRule::WherePays), &vol, &tf)?;
        let view = (camera, frame);
        let dims = vol.dims();
        let case = |label: String, volume: String, share: f64, rule_skips: bool| Case {
            label,
            volume,
            dims,
            share,
            rule_skips,
        };
        let skips = brickray_core::mip_skipping_pays(&grid, step);
        let c = case(name.clone(), name.clone(), share, skips);
        let (a, r) = (&mut always, Some(&mut rule));
        measure(&run, settings(mip, step), a, r, view, rounds, c, &mut rows)?;
        // Out of core: a brick store at its finest level.
        let src = brickray_harness::store_of(&vol, &dir.path().join(format!("{i}.brs")));
        let share = brickray_harness::finest_bricks_mip_share(src.as_ref())?;
        let ooc = |options: RendererOptions| -> Result<_, String> {
            let mut r =
                VolumeRenderer::with_options(&gpu.device, brickray_harness::target_desc(), options)
                    .map_err(|e| e.to_string())?;
            let config = OutOfCoreConfig {
                tolerance_px: 0.0,
                upload_budget_bytes: 1 << 30,
                ..Default::default()
            };
            r.set_volume_source(&gpu.device, &gpu.queue, src.clone(), config)
                .map_err(|e| e.to_string())?;
            r.set_transfer_function(&gpu.device, &gpu.queue, &tf)
                .map_err(|e| e.to_string())?;
            match run.converge(&mut r, camera, frame, settings(mip, step), 300)? {
                (Some(_), _) => Ok(r),
                (None, _) => Err(format!("{name}: out of core did not converge")),
            }
        };
        let (mut always, mut rule) = (
            ooc(with(SkipRule::Always))?,
            ooc(with(SkipRule::WherePays))?,
        );
        let skips = brickray_core::MIP_SKIP_SHARE_MIN_BRICKS.pays(share, step);
        let c = case(format!("{name}, out of core"), name.clone(), share, skips);
        let (a, r) = (&mut always, Some(&mut rule));
        measure(
            &run,
            settings(mip, step),
            a,
            r,
            view,
            rounds,
            c,
            &mut ooc_rows,
        )?;
        // DVR through ramps opaque from 0, 30% and 60% of the range (0.05
        // per reference length at the top): the share of macro cells
        // transparent through each, in core with and without the rule,
        // unshaded and shaded (samples two to three times as dear), and out
        // of core with and without its rule (the row's share: of the drawn
        // bricks' sub-cells, those transparent; `rule_skips` the rule's
        // decision from it).
        let dvr = RenderMode::Dvr;
        let shaded = RenderSettings {
            shading: brickray_core::Shading {
                enabled: true,
                ..Default::default()
            },
            ..settings(dvr, step)
        };
        let dvr_with = |dvr_skipping| RendererOptions {
            dvr_skipping,
            ..Default::default()
        };
        let mut ooc_dvr = ooc(dvr_with(SkipRule::Always))?;
        let mut ooc_dvr_rule = ooc(dvr_with(SkipRule::WherePays))?;
        for from in [0.0f32, 0.3, 0.6] {
            let tf = TransferFunction::ramp(from, 1.0, 0.05);
            let share = grid.transparent_share(&tf);
            let with = |dvr_skipping| RendererOptions {
                dvr_skipping,
                ..Default::default()
            };
            let mut always = renderer_in_core(&gpu, with(SkipRule::Always), &vol, &tf)?;
            let mut rule = renderer_in_core(&gpu, with(SkipRule::WherePays), &vol, &tf)?;
            for (base, kind, rows) in [
                (settings(dvr, step), "DVR", &mut dvr_rows),
                (shaded, "shaded DVR", &mut dvr_shaded_rows),
            ] {
                let threshold = brickray_core::dvr_skip_share_min(base.shading.enabled);
                let skips = threshold.pays(share, step);
                let label = format!("{name}, {kind} from {from}");
                let c = case(label.clone(), label, share, skips);
                let (a, r) = (&mut always, Some(&mut rule));
                measure(&run, base, a, r, view, rounds, c, rows)?;
            }
            for r in [&mut ooc_dvr, &mut ooc_dvr_rule] {
                r.set_transfer_function(&gpu.device, &gpu.queue, &tf)
                    .map_err(|e| e.to_string())?;
                run.converge(r, camera, frame, settings(dvr, step), 300)?;
            }
            for (base, kind, rows) in [
                (settings(dvr, step), "DVR", &mut dvr_ooc_rows),
                (shaded, "shaded DVR", &mut dvr_shaded_ooc_rows),
            ] {
                run.frame(&mut ooc_dvr_rule, camera, frame, base, false)?;
                let rule_skips = ooc_dvr_rule.stats().frame.empty_space_skipping;
                let drawn = ooc_dvr_rule
                    .stats()
                    .out_of_core
                    .and_then(|s| s.dvr_transparent_share)
                    .unwrap_or(f64::NAN);
                let label = format!("{name}, {kind} from {from}, out of core");
                let c = case(label.clone(), label, drawn, rule_skips);
                let (a, r) = (&mut ooc_dvr, Some(&mut ooc_dvr_rule));
                measure(&run, base, a, r, view, rounds, c, rows)?;
            }
        }
    }
    let (max, wrong) = (max_ratio, wrong_decisions);
    Ok(SkippingResult {
        run: RunInfo::new(&gpu, size, rounds, "procedural and shared volumes"),
        step_voxels: step,
        rule_over_off_max: max(&rows, |r| r.rule_over_off),
        always_over_off_max: max(&rows, |r| r.always_over_off),
        wrong_decisions: wrong(&rows),
        ooc_rule_over_off_max: max(&ooc_rows, |r| r.rule_over_off),
        ooc_always_over_off_max: max(&ooc_rows, |r| r.always_over_off),
        ooc_wrong_decisions: wrong(&ooc_rows),
        dvr_rule_over_off_max: max(&dvr_rows, |r| r.rule_over_off),
        dvr_always_over_off_max: max(&dvr_rows, |r| r.always_over_off),
        dvr_wrong_decisions: wrong(&dvr_rows),
        dvr_shaded_always_over_off_max: max(&dvr_shaded_rows, |r| r.always_over_off),
        dvr_shaded_rule_over_off_max: max(&dvr_shaded_rows, |r| r.rule_over_off),
        dvr_shaded_wrong_decisions: wrong(&dvr_shaded_rows),
        dvr_shaded_rows,
        dvr_ooc_always_over_off_max: max(&dvr_ooc_rows, |r| r.always_over_off),
        dvr_ooc_rule_over_off_max: max(&dvr_ooc_rows, |r| r.rule_over_off),
        dvr_ooc_wrong_decisions: wrong(&dvr_ooc_rows),
        dvr_shaded_ooc_always_over_off_max: max(&dvr_shaded_ooc_rows, |r| r.always_over_off),
        dvr_shaded_ooc_rule_over_off_max: max(&dvr_shaded_ooc_rows, |r| r.rule_over_off),
        dvr_shaded_ooc_wrong_decisions: wrong(&dvr_shaded_ooc_rows),
        dvr_shaded_ooc_rows,
        rows,
        ooc_rows,
        dvr_rows,
        dvr_ooc_rows,
    })
}

/// `mode` at `step` voxels, empty-space skipping asked for.
fn settings(mode: RenderMode, step: f32) -> RenderSettings {
    RenderSettings {
        mode,
        step_factor: step,
        accel: Accel {
            early_termination: Some(0.99),
            empty_space_skipping: true,
            adaptive_step: false,
        },
        ..Default::default()
    }
}

/// What one row measures, beside its timings.
struct Case {
    /// Printed.
    label: String,
    /// The row's `volume`.
    volume: String,
    dims: [u32; 3],
    share: f64,
    rule_skips: bool,
}

/// No skipping, always and the rule, interleaved: `always` draws the first
/// two (without and with skipping asked for, on `base`), `rule` the third
/// (`always` again where there is no rule to measure); the row is printed
/// and kept in `rows`.
#[allow(clippy::too_many_arguments)]
fn measure(
    run: &Runner<'_>,
    base: RenderSettings,
    always: &mut VolumeRenderer,
    mut rule: Option<&mut VolumeRenderer>,
    (camera, frame): (Camera, VolumeFrame),
    rounds: usize,
    case: Case,
    rows: &mut Vec<Row>,
) -> Result<(), String> {
    let s = |ess| RenderSettings {
        accel: Accel {
            empty_space_skipping: ess,
            ..base.accel
        },
        ..base
    };
    // Warm-up, with the samples per ray.
    let off_shot = run.frame(always, camera, frame, s(false), true)?;
    let on_shot = run.frame(always, camera, frame, s(true), true)?;
    if let Some(r) = rule.as_deref_mut() {
        run.frame(r, camera, frame, s(true), false)?;
    }
    let shots = interleave(rounds, 3, |i| match (i, rule.as_deref_mut()) {
        (0, _) => run.frame(always, camera, frame, s(false), false),
        (1, _) | (_, None) => run.frame(always, camera, frame, s(true), false),
        (_, Some(r)) => run.frame(r, camera, frame, s(true), false),
    })?;
    // Wall time (two renderers alternate, as in the shading suite).
    let t: Vec<Timing> = shots
        .iter()
        .map(|s| Timing::of_times(s.iter().map(|f| (f.ms, None))))
        .collect();
    let row = Row {
        volume: case.volume,
        dims: case.dims,
        skip_share: (case.share * 1000.0).round() / 1000.0,
        rule_skips: case.rule_skips,
        always_over_off: round2(t[1].ms / t[0].ms),
        rule_over_off: round2(t[2].ms / t[0].ms),
        off: t[0],
        always: t[1],
        rule: t[2],
        samples_per_ray_off: round2(off_shot.samples),
        samples_per_ray_always: round2(on_shot.samples),
    };
    println!(
        "  {:<36} {:>6.3} {:>6} {:>9.1} {:>9.1} ({:.2}) {:>9.1} ({:.2})",
        case.label,
        row.skip_share,
        if row.rule_skips { "skip" } else { "off" },
        row.off.ms,
        row.always.ms,
        row.always_over_off,
        row.rule.ms,
        row.rule_over_off
    );
    rows.push(row);
    Ok(())
}

fn max_ratio(rows: &[Row], f: fn(&Row) -> f64) -> f64 {
    rows.iter().map(f).fold(f64::NEG_INFINITY, f64::max)
}

/// Volumes where the rule chose the slower of skipping and not (by more
/// than 5%).
fn wrong_decisions(rows: &[Row]) -> usize {
    rows.iter()
        .filter(|r| {
            (r.rule_skips && r.always_over_off > 1.05)
                || (!r.rule_skips && r.always_over_off < 0.95)
        })
        .count()
}
