//! The configurations the suite sweeps around each mode's defaults: the
//! renderer state each needs, and the knobs' values.

use brickray_core::{Accel, LodMetric, RenderMode, RenderSettings, Shading, U8Filtering};
use brickray_render::VisibilityPolicy;

/// A configuration's renderer state: what needs its own renderer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct RendererKey {
    pub(super) in_core: bool,
    pub(super) tolerance_px: f32,
    pub(super) metric: LodMetric,
    pub(super) u8_filtering: U8Filtering,
    pub(super) policy: VisibilityPolicy,
    /// The cut's brick budget (`OutOfCoreConfig::brick_budget`).
    pub(super) brick_budget: Option<u32>,
    /// Out of core, the streamed volume keeps its texels' gradients
    /// (`VolumeOptions::gradients`).
    pub(super) gradients: bool,
}

/// The defaults: out of core with the cache's default LOD tolerance.
pub(super) const DEFAULT_KEY: RendererKey = RendererKey {
    in_core: false,
    tolerance_px: 1.0,
    metric: LodMetric::Geometric,
    u8_filtering: U8Filtering::Exact,
    policy: VisibilityPolicy::None,
    brick_budget: None,
    gradients: false,
};

/// The brick budgets of the equal-working-set sweeps, as fractions of the
/// finest cut's data bricks.
pub(super) const BRICK_FRACTIONS: [f64; 9] = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9];

/// One configuration of a scene.
#[derive(Debug, Clone)]
pub(super) struct Config {
    /// The knob swept (`default` for the defaults).
    pub(super) knob: &'static str,
    /// The knob's value, as printed.
    pub(super) value: String,
    pub(super) key: RendererKey,
    pub(super) settings: RenderSettings,
}

/// The settings every configuration of a mode starts from: the defaults, DVR
/// shaded.
pub(crate) fn base_settings(mode: RenderMode) -> RenderSettings {
    RenderSettings {
        mode,
        shading: Shading {
            enabled: matches!(mode, RenderMode::Dvr),
            ..Shading::default()
        },
        ..RenderSettings::default()
    }
}

/// The configurations of one mode: the defaults first, then each knob's sweep.
/// `finest_bricks` is the data bricks of the finest cut (the brick-budget
/// sweeps give fractions of it).
pub(super) fn configs(mode: RenderMode, u8_volume: bool, finest_bricks: u32) -> Vec<Config> {
    let base = base_settings(mode);
    let cfg = |knob, value: String, key, settings| Config {
        knob,
        value,
        key,
        settings,
    };
    let mut out = vec![cfg("default", "defaults".into(), DEFAULT_KEY, base)];
    for step in [0.125f32, 0.25, 1.0, 2.0, 4.0] {
        let s = RenderSettings {
            step_factor: step,
            ..base
        };
        out.push(cfg("step", format!("{step}"), DEFAULT_KEY, s));
    }
    if matches!(mode, RenderMode::Dvr) {
        for step in [0.5f32, 1.0, 2.0, 4.0] {
            let s = RenderSettings {
                step_factor: step,
                preintegrated: true,
                ..base
            };
            out.push(cfg("preint", format!("{step}"), DEFAULT_KEY, s));
        }
        // The step doubling as the ray's transmittance falls
        // (`Accel::adaptive_step`), from the default step and around it.
        for step in [0.25f32, 0.5, 1.0, 2.0] {
            let s = RenderSettings {
                step_factor: step,
                accel: Accel {
                    adaptive_step: true,
                    ..base.accel
                },
                ..base
            };
            out.push(cfg("adaptive", format!("{step}"), DEFAULT_KEY, s));
        }
    }
    for tol in [0.0f32, 0.5, 2.0, 4.0, 8.0] {
        let key = RendererKey {
            tolerance_px: tol,
            ..DEFAULT_KEY
        };
        out.push(cfg("lod_geometric", format!("{tol} px"), key, base));
    }
    // The error budget in 8-bit levels x pixels, ranked by what the image
    // shows (the renderer's measured visible weights, LodMetric::VisibleError):
    // 255 refines a fully visible node of full-scale error whose voxels
    // project to 1 px, like the geometric rule at 1 px; nearer nodes weigh
    // more, so the sweep goes far to reach the coarse cuts.
    for budget in [
        32.0f32, 64.0, 128.0, 255.0, 510.0, 1020.0, 2040.0, 4080.0, 8160.0, 16320.0,
    ] {
        let key = RendererKey {
            metric: LodMetric::VisibleError { budget },
            ..DEFAULT_KEY
        };
        out.push(cfg("lod_visible", format!("{budget}"), key, base));
    }
    // Equal working sets by construction: the same brick budgets, filled in
    // the geometric order (projected voxel size, tolerance 0), the
    // visible-error order (`VisibleError` at budget 0), and that order one
    // octant at a time
    // (`VisibleOctants` at budget 0); at budget 0 only the brick budget
    // stops refinement.
    for frac in BRICK_FRACTIONS {
        let bricks = ((finest_bricks as f64 * frac).round() as u32).max(1);
        for (knob, metric, tolerance_px) in [
            ("bricks_geometric", LodMetric::Geometric, 0.0),
            (
                "bricks_visible",
                LodMetric::VisibleError { budget: 0.0 },
                0.0,
            ),
            // The visible-error order, one octant at a time (children drawn
            // from their parent's brick until each gets its own).
            (
                "bricks_octants",
                LodMetric::VisibleOctants { budget: 0.0 },
                0.0,
            ),
        ] {
            let key = RendererKey {
                tolerance_px,
                metric,
                brick_budget: Some(bricks),
                ..DEFAULT_KEY
            };
            out.push(cfg(knob, format!("{bricks}"), key, base));
        }
    }
    for ert in [None, Some(0.9f32), Some(0.95), Some(0.999)] {
        let s = RenderSettings {
            accel: Accel {
                early_termination: ert,
                ..base.accel
            },
            ..base
        };
        let v = ert.map_or("off".to_string(), |t| format!("{t}"));
        out.push(cfg("ert", v, DEFAULT_KEY, s));
    }
    if u8_volume {
        let key = RendererKey {
            u8_filtering: U8Filtering::Fast,
            ..DEFAULT_KEY
        };
        out.push(cfg("u8_filtering", "fast".into(), key, base));
    }
    if !matches!(mode, RenderMode::Mip) {
        for (name, policy) in [
            ("ray-guided", VisibilityPolicy::RayGuided),
            ("occlusion", VisibilityPolicy::OcclusionQueries),
        ] {
            let key = RendererKey {
                policy,
                ..DEFAULT_KEY
            };
            out.push(cfg("visibility", name.into(), key, base));
        }
    }
    let key = RendererKey {
        in_core: true,
        ..DEFAULT_KEY
    };
    out.push(cfg("in_core", "in core".into(), key, base));
    out
}
