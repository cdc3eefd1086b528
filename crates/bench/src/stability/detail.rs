//! Case 4: thin structures and small bright features at coarse levels, with
//! average and max downsampling of the store's inner nodes.

use super::{Case, Ctx, Series, line_chart, quality, s};
use crate::runner::{Runner, round2};
use brickray_core::{
    BrickSource, RenderMode, RenderSettings, TransferFunction, Volume, VolumeFrame,
};
use brickray_render::OutOfCoreConfig;
use brickray_store::Filter;
use glam::Vec3;
use std::sync::Arc;

pub(crate) use brickray_harness::scenes::ortho;

/// The thin-structures volume ([`brickray_harness::scenes::thin_volume`]).
pub(crate) fn thin_volume(n: u32) -> Result<Volume, String> {
    brickray_harness::scenes::thin_volume(n).map_err(s)
}

/// The modes of case 4: `(name, settings, TF)`.
pub(crate) fn thin_modes() -> [(&'static str, RenderSettings, TransferFunction); 3] {
    [
        (
            "mip",
            RenderSettings {
                mode: RenderMode::Mip,
                ..Default::default()
            },
            TransferFunction::ramp(0.0, 1.0, 1.0),
        ),
        (
            "dvr",
            RenderSettings::default(),
            TransferFunction::ramp(0.3, 0.6, 0.9),
        ),
        (
            "iso",
            RenderSettings {
                mode: RenderMode::Iso {
                    value: 0.5,
                    color: [0.9, 0.85, 0.75],
                },
                ..Default::default()
            },
            TransferFunction::ramp(0.3, 0.6, 0.9),
        ),
    ]
}

/// Share of the features' brightness an image keeps: over the pixels where
/// the reference is at least 64 (of 255), the sum of `min(image, reference)`
/// over the sum of the reference (brightest channel).
pub(crate) fn retention(img: &[u8], reference: &[u8]) -> f64 {
    let peak = |p: &[u8]| p[0].max(p[1]).max(p[2]) as f64;
    let (mut kept, mut all) = (0.0, 0.0);
    for (a, b) in img.chunks_exact(4).zip(reference.chunks_exact(4)) {
        let r = peak(b);
        if r >= 64.0 {
            kept += peak(a).min(r);
            all += r;
        }
    }
    if all == 0.0 { 1.0 } else { kept / all }
}

/// Tolerances (px) that put the whole orthographic view at the finest level
/// and at 1, 2 and 3 levels coarser (a finest voxel projects to 0.83 px).
const TOLERANCES: [f32; 4] = [0.0, 2.0, 4.0, 8.0];
/// Retention the max filter keeps for MIP at every level.
const MIP_MAX_RETENTION: f64 = 0.9;

/// One filter, mode and level of the thin structures.
#[derive(Debug, serde::Serialize)]
struct ThinRow {
    filter: String,
    mode: String,
    coarser: u32,
    level: u32,
    psnr_db: f64,
    flip: f64,
    /// Share of the features' brightness kept.
    retention: f64,
}

/// Case 4.
pub(crate) fn thin_structures(ctx: &Ctx<'_>) -> Result<Case, String> {
    let size = ctx.size;
    let n = size;
    let vol = thin_volume(n)?;
    let frame = VolumeFrame::centered([n; 3], [1.0; 3]);
    let cam = ortho(frame.center(), Vec3::new(0.5, 0.3, 1.0), 1.2);
    println!(
        "\n4. thin structures: {n}^3 air with a one-voxel sheet, two lines and 27 bright voxels; orthographic; bricks 16; levels forced by tolerance {TOLERANCES:?} px; reference step 0.5"
    );
    let dir = tempfile::tempdir().map_err(s)?;
    let run = Runner::new(ctx.gpu, size)?;
    let modes = thin_modes();
    let refs: Vec<Vec<u8>> = modes
        .iter()
        .map(|(_, st, tf)| super::reference(&vol, &frame, tf, &cam, st, size, 0.5))
        .collect();
    println!(
        "  {:<8} {:<5} {:>6} {:>6} {:>9} {:>8} {:>10}",
        "filter", "mode", "tol", "level", "PSNR", "FLIP", "retention"
    );
    let mut rows = Vec::new();
    let mut series = Vec::new();
    let mut mip_max_min = f64::INFINITY;
    let mut mip_avg = Vec::new();
    for (fname, filter) in [("average", Filter::Average), ("max", Filter::Max)] {
        let path = dir.path().join(format!("{fname}.brs"));
        let mut reader = brickray_io::MemoryReader::new(vol.clone(), "thin");
        let opts = brickray_store::BuildOptions {
            brick: 16,
            filter,
            ..Default::default()
        };
        brickray_store::build(&mut reader, &path, &opts).map_err(s)?;
        let source: Arc<dyn BrickSource> = Arc::new(brickray_store::open(&path).map_err(s)?);
        let finest = source.layout().levels as usize - 1;
        for (m, (mname, settings, tf)) in modes.iter().enumerate() {
            let config = OutOfCoreConfig {
                tolerance_px: 0.0,
                upload_budget_bytes: 1 << 30,
                ..Default::default()
            };
            let mut r = super::ooc(ctx.gpu, source.clone(), config, tf)?;
            let mut pts = Vec::new();
            for tol in TOLERANCES {
                crate::runner::configure(ctx.gpu, &r, |c| c.tolerance_px = tol)?;
                let (_, st) = run.converge(&mut r, cam, frame, *settings, 100)?;
                let level = (0..16)
                    .rev()
                    .find(|&l| st.data_leaves_per_level[l] > 0)
                    .unwrap_or(0);
                let shot = run.frame(&mut r, cam, frame, *settings, true)?;
                let (p, fl) = quality(&shot.rgba, &refs[m], size);
                let keep = retention(&shot.rgba, &refs[m]);
                println!(
                    "  {fname:<8} {mname:<5} {tol:>6} {level:>6} {p:>9.2} {fl:>8.4} {keep:>10.3}"
                );
                let coarser = finest.saturating_sub(level);
                pts.push((coarser as f64, keep));
                if *mname == "mip" {
                    if filter == Filter::Max {
                        mip_max_min = mip_max_min.min(keep);
                    } else {
                        mip_avg.push((coarser, keep));
                    }
                }
                rows.push(ThinRow {
                    filter: fname.to_string(),
                    mode: mname.to_string(),
                    coarser: coarser as u32,
                    level: level as u32,
                    psnr_db: p,
                    flip: fl,
                    retention: round2(keep),
                });
            }
            series.push(Series {
                name: format!("{mname}, {fname}"),
                points: pts,
            });
        }
    }
    line_chart(
        &ctx.charts,
        "stability_thin_retention.svg",
        "thin structures: share of the features' brightness kept, by levels below the finest",
        "levels coarser than the finest",
        "retention",
        &series,
        false,
    )?;
    let avg1 = mip_avg.iter().find(|p| p.0 == 1).map_or(f64::NAN, |p| p.1);
    let avg_worst = mip_avg.iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
    Ok(Case {
        name: "thin",
        varied: "level (finest to 3 coarser) x DVR/iso/MIP x average/max downsampling".into(),
        fails: "average downsampling, MIP, one level below the finest and coarser".into(),
        by: format!("MIP retention {avg1:.2} one level coarser, {avg_worst:.2} at the coarsest measured"),
        shipped: "Filter::Average by default; remedy Filter::Max (BuildOptions::filter, `--filter max`) for MIP".into(),
        bound: format!("MIP with Filter::Max keeps >= {MIP_MAX_RETENTION} of the features' brightness at every level (measured min {mip_max_min:.3})"),
        holds: mip_max_min >= MIP_MAX_RETENTION,
        holes_max: 0,
        fig: super::figures(&rows),
    })
}
