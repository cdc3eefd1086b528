//! What one sweep gains over another, from the measured configurations.

use super::{Config, Measured};
use crate::runner::median;

/// The median PSNR gain of an error-aware LOD sweep (`knob`) over the
/// geometric one at equal working-set size: each error-aware point's PSNR
/// minus the geometric sweep's PSNR interpolated (in log bricks) at its brick
/// count; points outside the geometric sweep's range are left out. `None`
/// without both sweeps.
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
        .filter_map(|&(b, p)| interpolate(&geo, b).map(|g| p - g))
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

/// The adaptive step (`Accel::adaptive_step`) against plain sampling at the
/// same step (the defaults' at their own step, the step sweep's elsewhere):
/// its time over plain sampling's and its PSNR minus theirs, `None` without
/// both.
pub(super) fn adaptive_vs_plain(cfgs: &[Config], m: &[Measured], step: f32) -> Option<(f64, f64)> {
    let at = |knob: &str| {
        cfgs.iter()
            .zip(m)
            .find(|(c, _)| c.knob == knob && c.settings.step_factor == step)
            .map(|(_, x)| x)
    };
    let adaptive = at("adaptive")?;
    let plain = at("default").or_else(|| at("step"))?;
    Some((
        adaptive.ms / plain.ms,
        adaptive.psnr_db.min(99.0) - plain.psnr_db.min(99.0),
    ))
}

/// PSNR of the geometric curve at `bricks` (linear in log bricks), `None`
/// outside its range (equal brick counts keep the best PSNR).
fn interpolate(curve: &[(f64, f64)], bricks: f64) -> Option<f64> {
    let mut c: Vec<(f64, f64)> = curve.to_vec();
    c.sort_by(|a, b| a.0.total_cmp(&b.0));
    // Equal brick counts: keep the best PSNR.
    c.dedup_by(|b, a| {
        if a.0 == b.0 {
            a.1 = a.1.max(b.1);
            true
        } else {
            false
        }
    });
    for w in c.windows(2) {
        let ((b0, p0), (b1, p1)) = (w[0], w[1]);
        if b0 <= bricks && bricks <= b1 {
            if b1 == b0 {
                return Some(p0.max(p1));
            }
            let t = (bricks.ln() - b0.ln()) / (b1.ln() - b0.ln());
            return Some(p0 + t * (p1 - p0));
        }
    }
    c.iter().find(|p| p.0 == bricks).map(|p| p.1)
}

#[cfg(test)]
mod tests {
    use super::interpolate;

    #[test]
    fn interpolation_is_linear_in_log_bricks_and_bounded() {
        let c = [(10.0, 20.0), (100.0, 40.0), (1000.0, 50.0)];
        assert_eq!(interpolate(&c, 5.0), None);
        assert_eq!(interpolate(&c, 2000.0), None);
        assert!((interpolate(&c, 10.0f64.powf(1.5)).unwrap() - 30.0).abs() < 1e-9);
        assert_eq!(interpolate(&c, 1000.0), Some(50.0));
    }
}
