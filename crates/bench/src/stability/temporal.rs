//! Case 8: error over frames of the prediction buffer's failure path and of the
//! visibility feedback's disocclusion (the scenes of the `prediction` and
//! `visibility` suites), against the reference of each frame's camera.

use super::{Case, Ctx, holes, line_chart, named_series, quality, region_volume, s};
use crate::runner::{Runner, round2};
use brickray_core::{Accel, Camera, RenderMode, RenderSettings, TransferFunction, VolumeFrame};
use brickray_harness::predict;
use brickray_render::{OutOfCoreConfig, Prediction, VisibilityPolicy};
use brickray_store::ProceduralSource;
use std::sync::Arc;

/// Frames the camera of the failure path moves, then holds.
const MOVING: usize = 24;
const STILL: usize = 15;
/// Frames of the half turn and of the hold after it.
const TURN: usize = 12;
const HOLD_BACK: usize = 30;
/// A frame within this many dB of the unculled one counts as recovered.
const RECOVERED_DB: f64 = 0.5;
/// Most frames after the turn until the ray-guided image is recovered.
const RECOVERY_BOUND: usize = 10;

/// One prediction variant along the failure path.
#[derive(Debug, serde::Serialize)]
struct PredictionRow {
    variant: String,
    psnr_min_db: f64,
    psnr_mean_db: f64,
    psnr_last_db: f64,
}

/// The prediction failure path.
#[derive(Debug, serde::Serialize)]
struct PredictionFigures {
    rows: Vec<PredictionRow>,
    /// Whether the guard variant equalled full traversal every frame.
    guard_equals_full: bool,
}

/// One visibility policy along the half turn.
#[derive(Debug, serde::Serialize)]
struct PolicyRow {
    policy: String,
    psnr_min_after_turn_db: f64,
    psnr_last_db: f64,
}

/// The visibility half turn.
#[derive(Debug, serde::Serialize)]
struct DisocclusionFigures {
    rows: Vec<PolicyRow>,
    /// Frames after the back view until ray-guided culling recovers.
    recovery_frames: Option<usize>,
}

/// Both halves of the temporal case.
#[derive(Debug, serde::Serialize)]
struct TemporalFigures {
    prediction: PredictionFigures,
    disocclusion: DisocclusionFigures,
}

pub(crate) fn prediction_and_disocclusion(ctx: &Ctx<'_>) -> Result<Case, String> {
    let (pred_fig, pred_worst, pred_ok) = prediction_path(ctx)?;
    let (vis_fig, recovery, holes_max) = disocclusion(ctx)?;
    let holds = pred_ok && recovery.is_some_and(|r| r <= RECOVERY_BOUND) && holes_max == 0;
    Ok(Case {
        name: "temporal",
        varied: "frames along the prediction failure path (paper, guard) and the visibility half turn (none, ray-guided)".into(),
        fails: "prediction buffer (paper) while the occluder moves; ray-guided culling just after the turn".into(),
        by: format!(
            "paper: worst PSNR {pred_worst:.2} dB; ray-guided: recovered {} frames after the turn",
            recovery.map_or("never".into(), |r| r.to_string())
        ),
        shipped: "prediction off by default (guard exact when on); visibility policy None by default".into(),
        bound: format!(
            "guard variant == full traversal every frame; ray-guided within {RECOVERED_DB} dB of unculled <= {RECOVERY_BOUND} frames after the turn; 0 holes"
        ),
        holds,
        holes_max,
        fig: super::figures(&TemporalFigures {
            prediction: pred_fig,
            disocclusion: vis_fig,
        }),
    })
}

/// The failure path in core: full traversal, the paper's prediction and the
/// guarded one, each frame against the reference.
fn prediction_path(ctx: &Ctx<'_>) -> Result<(PredictionFigures, f64, bool), String> {
    let size = ctx.size;
    let vol = predict::occluder_scene(size);
    let d = vol.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let settings = RenderSettings {
        mode: RenderMode::Iso {
            value: 0.5,
            color: [0.9, 0.85, 0.75],
        },
        accel: Accel::default(),
        ..Default::default()
    };
    let tf = TransferFunction::ramp(0.3, 0.6, 0.9);
    let cams: Vec<Camera> = (0..MOVING + STILL)
        .map(|i| {
            let yaw = -0.9 + 0.06 * i.min(MOVING - 1) as f32;
            Camera::orbit(frame.center(), 2.2, yaw, 0.1)
        })
        .collect();
    println!(
        "\n8a. prediction failure path: occluder scene {size}^3, iso 0.5, {MOVING} frames moving then {STILL} still; PSNR vs the reference per frame"
    );
    let variants = [
        ("full", None),
        ("paper", Some(Prediction::PAPER)),
        (
            "guard",
            Some(Prediction {
                guard: true,
                ..Prediction::PAPER
            }),
        ),
    ];
    let run = Runner::new(ctx.gpu, size)?;
    let mut rs = Vec::new();
    for (_, p) in &variants {
        let mut r = super::incore(ctx.gpu, &vol, &tf)?;
        r.set_prediction(*p).map_err(s)?;
        rs.push(r);
    }
    let mut psnr = vec![Vec::new(); variants.len()];
    let mut guard_exact = true;
    for (i, cam) in cams.iter().enumerate() {
        let reference = super::reference(&vol, &frame, &tf, cam, &settings, size, 0.5);
        let mut imgs = Vec::new();
        for (k, r) in rs.iter_mut().enumerate() {
            let shot = run.frame(r, *cam, frame, settings, true)?;
            psnr[k].push((i as f64, quality(&shot.rgba, &reference, size).0));
            imgs.push(shot.rgba);
        }
        guard_exact &= predict::wrong_share(&imgs[2], &imgs[0]) == 0.0;
    }
    let mut rows = Vec::new();
    let mut paper_worst = f64::INFINITY;
    for (k, (name, _)) in variants.iter().enumerate() {
        let v: Vec<f64> = psnr[k].iter().map(|p| p.1).collect();
        let worst = v.iter().copied().fold(f64::INFINITY, f64::min);
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        let end = *v.last().unwrap_or(&0.0);
        println!("  {name:<6} PSNR min {worst:.2} dB, mean {mean:.2} dB, last frame {end:.2} dB");
        if *name == "paper" {
            paper_worst = worst;
        }
        rows.push(PredictionRow {
            variant: name.to_string(),
            psnr_min_db: round2(worst),
            psnr_mean_db: round2(mean),
            psnr_last_db: end,
        });
    }
    println!("  guard identical to full traversal every frame: {guard_exact}");
    let series = named_series(&variants, psnr);
    line_chart(
        &ctx.charts,
        "stability_prediction_psnr.svg",
        "prediction failure path: PSNR vs the reference per frame (camera stops at 24)",
        "frame",
        "PSNR dB",
        &series,
        false,
    )?;
    let fig = PredictionFigures {
        rows,
        guard_equals_full: guard_exact,
    };
    Ok((fig, paper_worst, guard_exact))
}

/// The visibility suite's shells scene at `size^3` (bricks 16, finest level),
/// no culling and ray-guided, along the half turn.
fn disocclusion(ctx: &Ctx<'_>) -> Result<(DisocclusionFigures, Option<usize>, u64), String> {
    let size = ctx.size;
    let n = size as u64;
    let src = Arc::new(ProceduralSource::sphere_shells([n; 3], 16, 2).map_err(s)?);
    let vol = region_volume(&src, [0; 3], [n; 3])?;
    let frame = VolumeFrame::centered([n as u32; 3], [1.0; 3]);
    let tf = TransferFunction::from_points(
        &[(0.15, [0.9, 0.8, 0.7, 0.0]), (0.22, [0.9, 0.8, 0.7, 1.0])],
        256,
    );
    let settings = RenderSettings::default();
    let cam = |k: usize| {
        Camera::orbit(
            frame.center(),
            1.8,
            0.5 + std::f32::consts::PI * k as f32 / TURN as f32,
            0.3,
        )
    };
    println!(
        "\n8b. visibility disocclusion: shells {n}^3, bricks 16, finest level; converge, half turn in {TURN} frames, hold {HOLD_BACK}; PSNR vs the reference per frame"
    );
    let refs: Vec<Vec<u8>> = (0..=TURN)
        .map(|k| super::reference(&vol, &frame, &tf, &cam(k), &settings, size, 0.5))
        .collect();
    let run = Runner::new(ctx.gpu, size)?;
    let config = OutOfCoreConfig {
        tolerance_px: 0.0,
        upload_budget_bytes: 1 << 30,
        ..Default::default()
    };
    let policies = [
        ("none", VisibilityPolicy::None),
        ("ray_guided", VisibilityPolicy::RayGuided),
    ];
    let mut rs = Vec::new();
    for (_, p) in policies {
        let mut r = super::ooc(ctx.gpu, src.clone(), config, &tf)?;
        crate::runner::configure(ctx.gpu, &r, |c| c.visibility = p)?;
        // Converge at the start view (frames drawn: the feedback needs them).
        for _ in 0..60 {
            run.frame(&mut r, cam(0), frame, settings, false)?;
            if r.stats().out_of_core.is_some_and(|s| s.converged) {
                break;
            }
        }
        rs.push(r);
    }
    let mut psnr = vec![Vec::new(); policies.len()];
    let mut holes_max = 0;
    for f in 0..TURN + HOLD_BACK {
        let k = (f + 1).min(TURN);
        for (j, r) in rs.iter_mut().enumerate() {
            let shot = run.frame(r, cam(k), frame, settings, true)?;
            holes_max = holes_max.max(holes(&shot.rgba, &refs[k]));
            psnr[j].push((f as f64, quality(&shot.rgba, &refs[k], size).0));
        }
    }
    // Frames after the back view is reached until ray-guided is within
    // RECOVERED_DB of no culling.
    let recovery = (TURN - 1..TURN + HOLD_BACK)
        .find(|&f| psnr[1][f].1 >= psnr[0][f].1 - RECOVERED_DB)
        .map(|f| f + 1 - TURN);
    let mut rows = Vec::new();
    for (j, (name, _)) in policies.iter().enumerate() {
        let after: Vec<f64> = psnr[j][TURN - 1..].iter().map(|p| p.1).collect();
        let worst = after.iter().copied().fold(f64::INFINITY, f64::min);
        let end = *after.last().unwrap_or(&0.0);
        println!("  {name:<10} from the back view on: PSNR min {worst:.2} dB, last {end:.2} dB");
        rows.push(PolicyRow {
            policy: name.to_string(),
            psnr_min_after_turn_db: round2(worst),
            psnr_last_db: end,
        });
    }
    println!(
        "  ray-guided within {RECOVERED_DB} dB of no culling {} frames after reaching the back view; holes max {holes_max}",
        recovery.map_or("never".into(), |r| r.to_string())
    );
    let series = named_series(&policies, psnr);
    line_chart(
        &ctx.charts,
        "stability_disocclusion_psnr.svg",
        "visibility half turn: PSNR vs the reference per frame (back view reached at 11)",
        "frame",
        "PSNR dB",
        &series,
        false,
    )?;
    let fig = DisocclusionFigures {
        rows,
        recovery_frames: recovery,
    };
    Ok((fig, recovery, holes_max))
}
