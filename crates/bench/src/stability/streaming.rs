//! Cases 1 and 2: streaming under a tiny pool and a slow source, and memory
//! pressure with the camera circling.

use super::{
    Case, Ctx, CutCheck, Series, SlowSource, dark, line_chart, mean_abs_diff, noise, quality,
};
use crate::runner::{Runner, median, quantile, round2};
use brickray_core::{BrickSource, Camera, RenderSettings, TransferFunction, VolumeFrame};
use brickray_render::OutOfCoreConfig;
use glam::Vec3;
use std::sync::Arc;
use std::time::Duration;

/// Brick side of the streamed volumes (small, so a 128^3 volume has 512
/// finest bricks and four levels).
pub(crate) const BRICK: u32 = 16;

/// The translucent TF of the procedural noise (the `ooc` suite's).
pub(crate) fn noise_tf() -> TransferFunction {
    TransferFunction::from_points(
        &[(0.45, [0.2, 0.5, 1.0, 0.0]), (0.7, [1.0, 0.8, 0.5, 0.3])],
        256,
    )
}

/// Frames each view of case 1 is held.
const HOLD: usize = 40;
/// Brick read delays of case 1, ms.
const DELAYS_MS: [u64; 3] = [0, 5, 20];

/// One added read delay of the streaming case.
#[derive(Debug, serde::Serialize)]
struct DelayRow {
    delay_ms: u64,
    cut_holes_max: u64,
    dark_pixels_max: u64,
    frames_to_converge_start: Option<usize>,
    frames_to_converge_jump: Option<usize>,
    median_ms: f64,
    p99_ms: f64,
    p99_over_median: f64,
    psnr_start_db: f64,
    psnr_jump_db: f64,
    flip_jump: f64,
}

/// The streaming case's figures.
#[derive(Debug, serde::Serialize)]
struct StreamingFigures {
    rows: Vec<DelayRow>,
    /// Dark pixels where only the root is resident.
    root_only_dark_pixels: Vec<u64>,
}

/// One GPU pool size of the memory pressure case.
#[derive(Debug, serde::Serialize)]
struct PoolRow {
    /// The pool as a multiple of the bricks the view needs.
    pool_factor: f64,
    slots: u64,
    uploads_per_frame_median: f64,
    uploads_per_frame_max: f64,
    flicker_ratio: f64,
    cut_holes_max: u64,
    dark_pixels_max: u64,
    psnr_min_db: f64,
    psnr_mean_db: f64,
}

/// The memory pressure case's figures.
#[derive(Debug, serde::Serialize)]
struct PressureFigures {
    rows: Vec<PoolRow>,
    /// Bricks the view needs at the finest level.
    need_bricks: u64,
}

/// Case 1: a tiny pool (2 MiB) and a source that sleeps before every brick
/// read; a cold start view, then a jump to a close-up. Holes per frame
/// against the reference, frames to converge, frame time.
pub(crate) fn streaming(ctx: &Ctx<'_>) -> Result<Case, String> {
    let size = ctx.size;
    let dims = size as u64;
    println!(
        "\n1. streaming: {dims}^3 noise, bricks {BRICK}, pool 2 MiB, delay per brick read {DELAYS_MS:?} ms, {HOLD} frames per view"
    );
    let (vol, src) = noise(dims, BRICK)?;
    let frame = VolumeFrame::centered([dims as u32; 3], [1.0; 3]);
    let tf = noise_tf();
    let settings = RenderSettings::default();
    let c = frame.center();
    let views = [
        Camera::orbit(c, 1.8, 0.5, 0.3),
        Camera::orbit(c + Vec3::new(-0.2, 0.15, -0.2), 0.6, 2.5, -0.2),
    ];
    let refs: Vec<Vec<u8>> = views
        .iter()
        .map(|v| super::reference(&vol, &frame, &tf, v, &settings, size, 0.5))
        .collect();
    let run = Runner::new(ctx.gpu, size)?;
    println!(
        "  {:>6} {:>6} {:>6} {:>9} {:>9} {:>8} {:>8} {:>7} {:>7} {:>8} {:>8}",
        "delay",
        "holes",
        "dark",
        "frames A",
        "frames B",
        "med ms",
        "p99 ms",
        "p99/med",
        "reads",
        "PSNR A",
        "PSNR B"
    );
    let mut rows = Vec::new();
    let mut holes_max = 0;
    let mut ratio_max = 0.0f64;
    let mut chart = Vec::new();
    let mut conv_frames = Vec::new();
    for delay in DELAYS_MS {
        let slow = Arc::new(SlowSource::new(
            src.clone() as Arc<dyn BrickSource>,
            Duration::from_millis(delay),
        ));
        let config = OutOfCoreConfig {
            gpu_budget_bytes: 2 << 20,
            ..Default::default()
        };
        let mut r = super::ooc(ctx.gpu, slow.clone(), config, &tf)?;
        let twin_src = Arc::new(SlowSource::new(
            src.clone() as Arc<dyn BrickSource>,
            Duration::from_millis(delay),
        ));
        let mut twin = CutCheck::new(twin_src, frame, config)?;
        let mut dark_max = 0;
        let mut ms = Vec::new();
        let mut hole_track = Vec::new();
        let mut converged_at = [None, None];
        let mut last = [Vec::new(), Vec::new()];
        for (v, cam) in views.iter().enumerate() {
            for i in 0..HOLD {
                let shot = run.frame(&mut r, *cam, frame, settings, true)?;
                ms.push(shot.ms);
                let h = twin.plan(cam, size, settings.mode, &tf);
                let dk = dark(&shot.rgba, &refs[v]);
                dark_max = dark_max.max(dk);
                hole_track.push((hole_track.len() as f64, dk as f64));
                holes_max = holes_max.max(h);
                let st = r.stats().out_of_core.ok_or("not out of core")?;
                if st.converged && converged_at[v].is_none() {
                    converged_at[v] = Some(i + 1);
                }
                last[v] = shot.rgba;
                std::thread::sleep(Duration::from_millis(2));
            }
        }
        let (med, p99) = (median(&ms), quantile(&ms, 0.99));
        ratio_max = ratio_max.max(p99 / med);
        let qa = quality(&last[0], &refs[0], size);
        let qb = quality(&last[1], &refs[1], size);
        let h = holes_max;
        let fr = |x: Option<usize>| x.map_or(format!(">{HOLD}"), |f| f.to_string());
        println!(
            "  {delay:>4}ms {h:>6} {dark_max:>6} {:>9} {:>9} {med:>8.1} {p99:>8.1} {:>7.2} {:>7} {:>8.2} {:>8.2}",
            fr(converged_at[0]),
            fr(converged_at[1]),
            p99 / med,
            slow.reads.load(std::sync::atomic::Ordering::Relaxed),
            qa.0,
            qb.0
        );
        conv_frames.push((delay, converged_at));
        rows.push(DelayRow {
            delay_ms: delay,
            cut_holes_max: h,
            dark_pixels_max: dark_max,
            frames_to_converge_start: converged_at[0],
            frames_to_converge_jump: converged_at[1],
            median_ms: round2(med),
            p99_ms: round2(p99),
            p99_over_median: round2(p99 / med),
            psnr_start_db: qa.0,
            psnr_jump_db: qb.0,
            flip_jump: qb.1,
        });
        chart.push(Series {
            name: format!("delay {delay} ms"),
            points: hole_track,
        });
    }
    line_chart(
        &ctx.charts,
        "stability_streaming_holes.svg",
        "streaming: pixels dark in the frame but lit in the reference (start view, jump at 40)",
        "frame",
        "dark pixels",
        &chart,
        false,
    )?;
    // Scale for the dark pixels: the root alone (always resident) against
    // the reference: detail the coarsest level lacks, not holes.
    let mut root = super::ooc(ctx.gpu, src.clone(), OutOfCoreConfig::default(), &tf)?;
    crate::runner::configure(ctx.gpu, &root, |c| c.tolerance_px = 1.0e6)?;
    let mut root_dark = Vec::new();
    for (v, cam) in views.iter().enumerate() {
        let shot = run.frame(&mut root, *cam, frame, settings, true)?;
        root_dark.push(dark(&shot.rgba, &refs[v]));
    }
    println!(
        "  holes: leaves of the CPU twin's cuts wanting data without it (or not tiling the cube); dark: pixels dark in the frame, lit in the reference (the root alone: {root_dark:?})"
    );
    let fast = conv_frames.first().and_then(|c| c.1[1]);
    let slowest = conv_frames.last().and_then(|c| c.1[1]);
    // The bound: no hole in any frame; p99 frame time within 4x the median
    // (the render thread never waits for a read).
    const P99_BOUND: f64 = 4.0;
    let holds = holes_max == 0 && ratio_max <= P99_BOUND;
    Ok(Case {
        name: "streaming",
        varied: format!("delay per brick read {DELAYS_MS:?} ms, 2 MiB pool"),
        fails: "does not show holes; the slow source only delays refinement".into(),
        by: format!(
            "frames to converge after the jump: {} at 0 ms, {} at {} ms",
            fast.map_or("not".into(), |f| f.to_string()),
            slowest.map_or(format!(">{HOLD}"), |f| f.to_string()),
            DELAYS_MS[2]
        ),
        shipped:
            "root preloaded, coarser resident level drawn until the finer arrives, async loader"
                .into(),
        bound: format!(
            "0 hole leaves in every cut (CPU twin); p99/median frame time {ratio_max:.2} <= {P99_BOUND}"
        ),
        holds,
        holes_max,
        fig: super::figures(&StreamingFigures {
            rows,
            root_only_dark_pixels: root_dark,
        }),
    })
}

/// Frames of the circling camera in case 2.
const CIRCLE: usize = 32;
/// Pool sizes of case 2, as fractions of the bricks the start view needs.
const POOL_FRACTIONS: [f64; 4] = [2.0, 1.0, 0.5, 0.25];

/// Case 2: pools smaller than the view needs, the camera circling. Uploads per
/// frame (thrash), flicker (frame-to-frame change over the reference's own
/// change), holes, PSNR.
pub(crate) fn pressure(ctx: &Ctx<'_>) -> Result<Case, String> {
    let size = ctx.size;
    let dims = size as u64;
    let (vol, src) = noise(dims, BRICK)?;
    let frame = VolumeFrame::centered([dims as u32; 3], [1.0; 3]);
    let tf = noise_tf();
    let settings = RenderSettings::default();
    let c = frame.center();
    let cam = |i: usize| Camera::orbit(c, 1.4, 0.5 + 0.1 * i as f32, 0.3);
    let tolerance = 0.5;
    let run = Runner::new(ctx.gpu, size)?;
    // What the start view needs, with a pool that holds it all.
    let big: u64 = 64 << 20;
    let config = |gpu_budget_bytes| OutOfCoreConfig {
        gpu_budget_bytes,
        tolerance_px: tolerance,
        ..Default::default()
    };
    // Without gradients, which the big pool would keep (it holds every
    // brick with them) and the small ones not: the same slot under every
    // budget.
    let mut r = super::ooc_without_gradients(ctx.gpu, src.clone(), config(big), &tf)?;
    let (_, st) = run.converge(&mut r, cam(0), frame, settings, 200)?;
    let need = st.cache.working_set_bricks as f64;
    let per_slot = st.cache.pool_slot_bytes as f64;
    drop(r);
    println!(
        "\n2. memory pressure: {dims}^3 noise, bricks {BRICK}, tolerance {tolerance} px; the start view needs {need} bricks; pools of {POOL_FRACTIONS:?} x that; {CIRCLE} frames circling (0.1 rad a frame)"
    );
    let refs: Vec<Vec<u8>> = (0..CIRCLE)
        .map(|i| super::reference(&vol, &frame, &tf, &cam(i), &settings, size, 0.5))
        .collect();
    let ref_change: f64 = (1..CIRCLE)
        .map(|i| mean_abs_diff(&refs[i], &refs[i - 1]))
        .sum();
    println!(
        "  {:>6} {:>6} {:>10} {:>10} {:>8} {:>6} {:>6} {:>9} {:>9}",
        "pool",
        "slots",
        "upl/frame",
        "upl max",
        "flicker",
        "holes",
        "dark",
        "PSNR min",
        "PSNR mean"
    );
    let mut rows = Vec::new();
    let mut holes_max = 0;
    let mut flicker_at = Vec::new();
    let mut psnr_series = Vec::new();
    let mut upload_series = Vec::new();
    for frac in POOL_FRACTIONS {
        // The cache needs at least 9 slots.
        let budget = ((frac * need).max(9.0) * per_slot + per_slot / 2.0) as u64;
        let mut r = super::ooc_without_gradients(ctx.gpu, src.clone(), config(budget), &tf)?;
        run.converge(&mut r, cam(0), frame, settings, 200)?;
        let mut twin = CutCheck::new(src.clone(), frame, config(budget))?;
        for _ in 0..50 {
            twin.plan(&cam(0), size, settings.mode, &tf);
            std::thread::sleep(Duration::from_millis(5));
        }
        let mut dk = 0;
        let mut imgs = Vec::new();
        let mut uploads = Vec::new();
        let mut psnrs = Vec::new();
        let mut h = 0;
        let mut slots = 0;
        for (i, reference) in refs.iter().enumerate() {
            let shot = run.frame(&mut r, cam(i), frame, settings, true)?;
            let st = r.stats().out_of_core.ok_or("not out of core")?;
            slots = st.cache.pool_slots;
            uploads.push(st.cache.upload_bricks as f64);
            h = h.max(twin.plan(&cam(i), size, settings.mode, &tf));
            dk = dk.max(dark(&shot.rgba, reference));
            psnrs.push(quality(&shot.rgba, reference, size).0);
            imgs.push(shot.rgba);
        }
        holes_max = holes_max.max(h);
        let change: f64 = (1..CIRCLE)
            .map(|i| mean_abs_diff(&imgs[i], &imgs[i - 1]))
            .sum();
        let flicker = change / ref_change.max(1e-9);
        let pmin = psnrs.iter().copied().fold(f64::INFINITY, f64::min);
        let pmean = psnrs.iter().sum::<f64>() / psnrs.len() as f64;
        let umax = uploads.iter().copied().fold(0.0, f64::max);
        println!(
            "  {frac:>5.2}x {slots:>6} {:>10.1} {umax:>10} {flicker:>8.3} {h:>6} {dk:>6} {pmin:>9.2} {pmean:>9.2}",
            median(&uploads)
        );
        flicker_at.push((frac, flicker));
        rows.push(PoolRow {
            pool_factor: frac,
            slots: slots as u64,
            uploads_per_frame_median: median(&uploads),
            uploads_per_frame_max: umax,
            flicker_ratio: round2(flicker),
            cut_holes_max: h,
            dark_pixels_max: dk,
            psnr_min_db: round2(pmin),
            psnr_mean_db: round2(pmean),
        });
        psnr_series.push(Series {
            name: format!("pool {frac}x need"),
            points: psnrs
                .iter()
                .enumerate()
                .map(|(i, p)| (i as f64, *p))
                .collect(),
        });
        upload_series.push(Series {
            name: format!("pool {frac}x need"),
            points: uploads
                .iter()
                .enumerate()
                .map(|(i, p)| (i as f64, *p))
                .collect(),
        });
    }
    line_chart(
        &ctx.charts,
        "stability_pressure_psnr.svg",
        "memory pressure: PSNR vs reference per frame, camera circling",
        "frame",
        "PSNR dB",
        &psnr_series,
        false,
    )?;
    line_chart(
        &ctx.charts,
        "stability_pressure_uploads.svg",
        "memory pressure: bricks uploaded per frame",
        "frame",
        "bricks",
        &upload_series,
        false,
    )?;
    const FLICKER_BOUND: f64 = 1.25;
    let worst = flicker_at
        .iter()
        .copied()
        .fold((0.0, 0.0), |a, b| if b.1 > a.1 { b } else { a });
    let holds = holes_max == 0 && worst.1 <= FLICKER_BOUND;
    Ok(Case {
        name: "pressure",
        varied: format!("pool {POOL_FRACTIONS:?} x the start view's need ({need} bricks)"),
        fails: format!("pool {}x need: most frame-to-frame change", worst.0),
        by: format!("flicker ratio {:.3} (image change / reference change)", worst.1),
        shipped: "frame-stamped LRU (never evicts the current frame's bricks); refinement keeps the cut within the slots".into(),
        bound: format!("0 hole leaves (CPU twin); flicker ratio <= {FLICKER_BOUND} at pools >= 0.25x need"),
        holds,
        holes_max,
        fig: super::figures(&PressureFigures {
            rows,
            need_bricks: need as u64,
        }),
    })
}
