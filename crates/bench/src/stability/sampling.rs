//! Cases 3 and 7: a high-frequency transfer function against the step, and
//! early ray termination thresholds.

use super::{Case, Ctx, Series, line_chart, noise, quality, s};
use crate::runner::{Runner, finest_ooc_renderer, median, round2};
use brickray_core::{Accel, Camera, RenderSettings, TransferFunction, VolumeFrame};
use brickray_render::RendererOptions;

/// A narrow opacity spike: opacity 0.8 at 0.5, zero 0.005 either side (about
/// a fifth of a voxel's change of the noise field).
pub(crate) fn spike_tf() -> TransferFunction {
    TransferFunction::from_points(
        &[
            (0.495, [1.0, 0.9, 0.6, 0.0]),
            (0.5, [1.0, 0.9, 0.6, 0.8]),
            (0.505, [1.0, 0.9, 0.6, 0.0]),
        ],
        1024,
    )
}

/// Steps of case 3, in voxels.
pub(crate) const STEPS: [f32; 6] = [0.125, 0.25, 0.5, 1.0, 2.0, 4.0];
/// The reference's step in case 3 (finer than every step measured).
const REF_STEP: f32 = 1.0 / 32.0;
/// Case 3's failure threshold.
const HF_FAIL_DB: f64 = 30.0;
/// What the shipped step keeps on the spike (in core and out of core).
const HF_SHIPPED_DB: f64 = 15.0;
/// Least gain per halving of the step from 1 to 1/8 voxel (in core).
const HF_GAIN_DB: f64 = 3.0;

/// The TF variants of case 3's columns: the opacity-corrected table, and the
/// pre-integrated table (`RenderSettings::preintegrated`).
const TF_VARIANTS: &[&str] = &["plain", "preintegrated"];

/// One TF variant and step of the high-frequency TF case.
#[derive(Debug, serde::Serialize)]
struct HfRow {
    variant: String,
    step: f32,
    psnr_incore_db: f64,
    flip_incore: f64,
    psnr_ooc_db: f64,
    flip_ooc: f64,
    psnr_incore_vs_reference_same_step_db: f64,
}

/// Pre-integration's gain over the plain table at one step, in core.
#[derive(Debug, serde::Serialize)]
struct PreintGain {
    step: f64,
    gain_db: f64,
}

/// The high-frequency TF case's figures.
#[derive(Debug, serde::Serialize)]
struct HfFigures {
    rows: Vec<HfRow>,
    /// The smallest gain of halving the step (plain, in core), dB.
    min_gain_per_halving_db: f64,
    preint_gain: Vec<PreintGain>,
    /// The reference at 1/8 against 1/32 voxel.
    reference_1_8_vs_1_32_db: f64,
}

/// One TF and threshold of the early termination case.
#[derive(Debug, serde::Serialize)]
struct ErtRow {
    tf: String,
    threshold: String,
    max_err_vs_no_ert: f64,
    bound_levels: f64,
    psnr_ref_db: f64,
    flip_ref: f64,
    samples_per_ray: f64,
    time_vs_no_ert: f64,
}

/// Case 3: PSNR against the reference (step 1/32) per step, in core and out of
/// core at the finest level.
pub(crate) fn high_frequency_tf(ctx: &Ctx<'_>) -> Result<Case, String> {
    let size = ctx.size;
    let dims = size as u64;
    println!(
        "\n3. high-frequency TF: {dims}^3 noise, opacity spike 0.8 at 0.5 (+-0.005), DVR; reference step 1/32; steps {STEPS:?}"
    );
    let (vol, src) = noise(dims, 32)?;
    let frame = VolumeFrame::centered([dims as u32; 3], [1.0; 3]);
    let tf = spike_tf();
    let cam = Camera::orbit(frame.center(), 1.8, 0.5, 0.3);
    let base = RenderSettings::default();
    let reference = super::reference(&vol, &frame, &tf, &cam, &base, size, REF_STEP);
    let ref8 = super::reference(&vol, &frame, &tf, &cam, &base, size, 0.125);
    let (ref_self, _) = quality(&ref8, &reference, size);
    println!("  reference at 1/8 vs 1/32: {ref_self:.2} dB (the reference's own convergence)");
    let run = Runner::new(ctx.gpu, size)?;
    let mut incore = super::incore(ctx.gpu, &vol, &tf)?;
    let mut ooc = finest_ooc_renderer(ctx.gpu, src, RendererOptions::default())?;
    ooc.set_transfer_function(&ctx.gpu.device, &ctx.gpu.queue, &tf)
        .map_err(s)?;
    run.converge(&mut ooc, cam, frame, base, 200)?;
    println!(
        "  {:<12} {:>6} {:>10} {:>10} {:>10} {:>10} {:>12}",
        "variant", "step", "PSNR in", "FLIP in", "PSNR ooc", "FLIP ooc", "in vs ref@s"
    );
    let mut rows = Vec::new();
    let mut series = Vec::new();
    let mut shipped_db = f64::INFINITY;
    let mut fails_at = None;
    for variant in TF_VARIANTS {
        let mut pin = Vec::new();
        let mut pout = Vec::new();
        for step in STEPS {
            let settings = RenderSettings {
                step_factor: step,
                preintegrated: *variant == "preintegrated",
                ..base
            };
            let a = run.frame(&mut incore, cam, frame, settings, true)?;
            run.converge(&mut ooc, cam, frame, settings, 50)?;
            let b = run.frame(&mut ooc, cam, frame, settings, true)?;
            let qa = quality(&a.rgba, &reference, size);
            let qb = quality(&b.rgba, &reference, size);
            // The GPU against the model at its own step: implementation
            // error, apart from the step's sampling error.
            let same = if step >= 0.125 {
                let r_s = super::reference(&vol, &frame, &tf, &cam, &settings, size, step);
                quality(&a.rgba, &r_s, size).0
            } else {
                f64::NAN
            };
            println!(
                "  {variant:<12} {step:>6} {:>10.2} {:>10.4} {:>10.2} {:>10.4} {same:>12.2}",
                qa.0, qa.1, qb.0, qb.1
            );
            if *variant == "plain" {
                if step == 0.5 {
                    shipped_db = qa.0.min(qb.0);
                }
                if fails_at.is_none() && qa.0.min(qb.0) < HF_FAIL_DB {
                    fails_at = Some((step, qa.0.min(qb.0)));
                }
            }
            rows.push(HfRow {
                variant: variant.to_string(),
                step,
                psnr_incore_db: qa.0,
                flip_incore: qa.1,
                psnr_ooc_db: qb.0,
                flip_ooc: qb.1,
                psnr_incore_vs_reference_same_step_db: same,
            });
            pin.push((step as f64, qa.0));
            pout.push((step as f64, qb.0));
        }
        series.push(Series {
            name: format!("{variant}, in core"),
            points: pin,
        });
        series.push(Series {
            name: format!("{variant}, out of core (finest)"),
            points: pout,
        });
    }
    // In core, plain: PSNR at steps 1, 1/2, 1/4, 1/8 (STEPS is ascending).
    let plain_in = &series[0].points;
    let at = |s: f64| plain_in.iter().find(|p| p.0 == s).map_or(f64::NAN, |p| p.1);
    let min_gain = [(1.0, 0.5), (0.5, 0.25), (0.25, 0.125)]
        .iter()
        .map(|&(a, b)| at(b) - at(a))
        .fold(f64::INFINITY, f64::min);
    // Pre-integration's gain over the plain table at each step, in core.
    let pre_in = &series[2].points;
    let mut preint_gain = Vec::new();
    for (p, q) in plain_in.iter().zip(pre_in) {
        println!(
            "  pre-integration at step {}: {:+.2} dB in core",
            p.0,
            q.1 - p.1
        );
        preint_gain.push(PreintGain {
            step: p.0,
            gain_db: round2(q.1 - p.1),
        });
    }
    line_chart(
        &ctx.charts,
        "stability_hf_tf_psnr_vs_step.svg",
        "narrow opacity spike: PSNR vs the reference (step 1/32) by step",
        "step (voxels)",
        "PSNR dB",
        &series,
        true,
    )?;
    // The bound at the shipped step 0.5: what this run measured, floored to
    // the dB below, is what the regression test holds (tests/gpu_stability.rs
    // states its own threshold at its own size).
    Ok(Case {
        name: "hf_tf",
        varied: format!("step {STEPS:?} voxels, in core and out of core"),
        fails: fails_at.map_or(format!("not below {HF_FAIL_DB} dB in the range"), |f| {
            format!("step {} (below {HF_FAIL_DB} dB)", f.0)
        }),
        by: fails_at.map_or("-".into(), |f| format!("{:.2} dB", f.1)),
        shipped: "step 0.5 voxel, opacity-corrected table, no pre-integration".into(),
        bound: format!(
            ">= {HF_SHIPPED_DB} dB at step 0.5 (measured {shipped_db:.2}); >= {HF_GAIN_DB} dB per halving from 1 to 1/8 (measured min {min_gain:.2})"
        ),
        holds: shipped_db >= HF_SHIPPED_DB && min_gain >= HF_GAIN_DB,
        holes_max: 0,
        fig: super::figures(&HfFigures {
            rows,
            min_gain_per_halving_db: round2(min_gain),
            preint_gain,
            reference_1_8_vs_1_32_db: ref_self,
        }),
    })
}

/// Thresholds of case 7 (`None`: no termination).
const ERT: [Option<f32>; 7] = [
    Some(0.9),
    Some(0.95),
    Some(0.98),
    Some(0.99),
    Some(0.995),
    Some(0.999),
    None,
];

/// The largest 8-bit error a threshold `t` allows: what remains after
/// termination is at most `1 - t` of full brightness, plus one level of
/// rounding.
pub(crate) fn ert_bound_levels(t: f32) -> f64 {
    (1.0 - t as f64) * 255.0 + 1.0
}

/// Case 7: ERT thresholds on two translucent TFs: error against the same
/// renderer without termination (max 8-bit error vs the analytic bound) and
/// against the reference, samples per ray and time.
pub(crate) fn ert(ctx: &Ctx<'_>) -> Result<Case, String> {
    let size = ctx.size;
    let dims = size as u64;
    println!("\n7. early ray termination: {dims}^3 noise, in core, thresholds {ERT:?}");
    let (vol, _) = noise(dims, 32)?;
    let frame = VolumeFrame::centered([dims as u32; 3], [1.0; 3]);
    let cam = Camera::orbit(frame.center(), 1.8, 0.5, 0.3);
    let tfs = [
        ("translucent_0.3", super::streaming::noise_tf()),
        (
            "translucent_0.05",
            TransferFunction::from_points(
                &[(0.3, [0.2, 0.5, 1.0, 0.0]), (0.7, [1.0, 0.8, 0.5, 0.05])],
                256,
            ),
        ),
    ];
    let run = Runner::new(ctx.gpu, size)?;
    let mut rows = Vec::new();
    let mut all_within = true;
    let mut shipped = String::new();
    let mut fails = None;
    let mut series = Vec::new();
    for (name, tf) in &tfs {
        let settings = |t: Option<f32>| RenderSettings {
            accel: Accel {
                early_termination: t,
                ..Accel::default()
            },
            ..Default::default()
        };
        let reference = super::reference(&vol, &frame, tf, &cam, &settings(None), size, 0.5);
        let mut r = super::incore(ctx.gpu, &vol, tf)?;
        let full = run.frame(&mut r, cam, frame, settings(None), true)?;
        let shots: Vec<_> = ERT
            .iter()
            .map(|t| run.frame(&mut r, cam, frame, settings(*t), true))
            .collect::<Result<_, _>>()?;
        // Time: three rounds, the order rotated.
        let mut times = vec![Vec::new(); ERT.len()];
        for round in 0..3 {
            for k in 0..ERT.len() {
                let i = (k + round) % ERT.len();
                times[i].push(run.frame(&mut r, cam, frame, settings(ERT[i]), false)?.ms);
            }
        }
        let t_none = median(&times[ERT.len() - 1]);
        println!(
            "  {name}: {:>7} {:>8} {:>8} {:>9} {:>9} {:>8} {:>8}",
            "ERT", "max err", "bound", "PSNR ref", "FLIP ref", "smp/ray", "time"
        );
        let mut pts = Vec::new();
        for (i, t) in ERT.iter().enumerate() {
            let err = brickray_reference::max_abs_diff(&shots[i].rgba, &full.rgba) as f64;
            let bound = t.map_or(1.0, ert_bound_levels);
            let (p, f) = quality(&shots[i].rgba, &reference, size);
            let ratio = median(&times[i]) / t_none;
            all_within &= err <= bound;
            let label = t.map_or("off".to_string(), |t| t.to_string());
            println!(
                "  {:>17} {:>8} {:>8.1} {:>9.2} {:>9.4} {:>8.1} {:>7.2}x",
                label, err, bound, p, f, shots[i].samples, ratio
            );
            if *t == Some(0.99) {
                shipped.push_str(&format!("{name}: {p:.2} dB, max err {err} "));
            }
            if let Some(tv) = t {
                pts.push((1.0 - *tv as f64, p));
                if p < 40.0 && fails.as_ref().is_none_or(|f: &(f32, f64)| f.0 < *tv) {
                    fails = Some((*tv, p));
                }
            }
            rows.push(ErtRow {
                tf: name.to_string(),
                threshold: label.to_string(),
                max_err_vs_no_ert: err as f64,
                bound_levels: round2(bound),
                psnr_ref_db: p,
                flip_ref: f,
                samples_per_ray: round2(shots[i].samples),
                time_vs_no_ert: round2(ratio),
            });
        }
        series.push(Series {
            name: name.to_string(),
            points: pts,
        });
    }
    line_chart(
        &ctx.charts,
        "stability_ert_psnr.svg",
        "early ray termination: PSNR vs the reference by 1 - threshold",
        "1 - threshold",
        "PSNR dB",
        &series,
        true,
    )?;
    Ok(Case {
        name: "ert",
        varied: "threshold 0.9 to 0.999 and off, two translucent TFs".into(),
        fails: fails.map_or("not below 40 dB in the range".into(), |f| {
            format!("threshold {} and below (under 40 dB)", f.0)
        }),
        by: fails.map_or("-".into(), |f| format!("{:.2} dB", f.1)),
        shipped: format!("0.99 ({})", shipped.trim()),
        bound: "max 8-bit error vs no termination <= (1 - t) * 255 + 1 at every t".into(),
        holds: all_within,
        holes_max: 0,
        fig: super::figures(&rows),
    })
}
