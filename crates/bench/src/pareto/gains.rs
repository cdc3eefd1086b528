//! What one sweep gains over another, from the measured configurations.

use super::{Config, Measured};
use crate::runner::median;

/// The median PSNR gain of an error-aware LOD sweep (`knob`) over the geometric one at
/// equal working-set size: each error-aware point's PSNR minus the geometric
/// sweep's PSNR interpolated (in log bricks) at its brick count; points outside
/// the geometric sweep's range are left out. `None` without both sweeps.
pub(super) fn lod_gain(cfgs: &[Config], m: &[Measured], knob: &str) -> Option<f64> {
    let series = |knob: &str| -> Vec<(f64, f64)> {
        cfgs.iter()
            .zip(m)
            .filter(|(c, _)| c.knob == knob || (knob == "lod_geometric" && c.knob == "default"))
            .map(|(_, x)| (x.bricks as f64, x.psnr_db.min(99.0)))
            .collect()
    };
    let (geo, err) = (series("lod_geometric"), series(knob));
    let gains: Vec<f64> = err
        .iter()
        .filter_map(|&(b, p)| crate::lod::interpolate(&geo, b).map(|g| p - g))
        .collect();
    (!gains.is_empty()).then(|| median(&gains))
}

/// The median over brick budgets of the PSNR of the order `knob` minus the
/// geometric order's at the same budget, against the reference and against
/// the finest cut's image (`None` without both sweeps).
pub(super) fn brick_budget_gain(cfgs: &[Config], m: &[Measured], knob: &str) -> Option<(f64, f64)> {
    let at = |knob: &str, value: &str| {
        cfgs.iter()
            .zip(m)
            .find(|(c, _)| c.knob == knob && c.value == value)
            .map(|(_, x)| x)
    };
    let (mut gains, mut lod_gains) = (Vec::new(), Vec::new());
    for c in cfgs.iter().filter(|c| c.knob == knob) {
        let (Some(v), Some(g)) = (at(knob, &c.value), at("bricks_geometric", &c.value)) else {
            continue;
        };
        let d = v.psnr_db.min(99.0) - g.psnr_db.min(99.0);
        let dl = v.psnr_lod_db.min(99.0) - g.psnr_lod_db.min(99.0);
        println!(
            "  brick budget {:>5}: geometric {:>5} bricks {:>6.2} dB ({:>6.2}), {knob} {:>5} bricks {:>6.2} dB ({:>6.2}), {d:+.2} dB ({dl:+.2})",
            c.value,
            g.bricks,
            g.psnr_db,
            g.psnr_lod_db.min(99.0),
            v.bricks,
            v.psnr_db,
            v.psnr_lod_db.min(99.0)
        );
        gains.push(d);
        lod_gains.push(dl);
    }
    (!gains.is_empty()).then(|| (median(&gains), median(&lod_gains)))
}

/// PSNR of pre-integration at step 2 voxels minus the plain step-2 PSNR.
pub(super) fn preint_gain(cfgs: &[Config], m: &[Measured]) -> Option<f64> {
    let at = |knob: &str| {
        cfgs.iter()
            .zip(m)
            .find(|(c, _)| c.knob == knob && c.settings.step_factor == 2.0)
            .map(|(_, x)| x.psnr_db)
    };
    Some(at("preint")? - at("step")?)
}
