//! Render modes and switches shared by the GPU renderer and the CPU reference.

/// What a ray computes.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub enum RenderMode {
    /// Direct volume rendering: front-to-back emission-absorption through the
    /// transfer function.
    Dvr,
    /// First crossing of a normalized isovalue, refined by bisection and shaded.
    Iso {
        /// Isovalue in normalized (transfer-function) space.
        value: f32,
        /// Surface colour (linear RGB).
        color: [f32; 3],
    },
    /// Maximum intensity projection; the maximum is mapped through the transfer
    /// function (premultiplied, no step correction).
    Mip,
}

/// Blinn-Phong shading with a headlight, from central-difference gradients.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Shading {
    /// Shade DVR samples (iso surfaces are always shaded).
    pub enabled: bool,
    /// Ambient weight.
    pub ambient: f32,
    /// Diffuse weight.
    pub diffuse: f32,
    /// Specular weight.
    pub specular: f32,
    /// Specular exponent.
    pub shininess: f32,
}

impl Default for Shading {
    fn default() -> Self {
        Shading {
            enabled: false,
            ambient: 0.3,
            diffuse: 0.7,
            specular: 0.2,
            shininess: 24.0,
        }
    }
}

/// Krueger-Westermann acceleration switches. With both off a renderer is the
/// brute-force reference.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Accel {
    /// Early ray termination: stop once accumulated opacity reaches this
    /// (`None` = off). Default 0.99. A DVR ray that stops fills the light it
    /// would still gather with the colour of the sample that stopped it, as
    /// far as its mean extinction so far would take it over the rest of the
    /// ray (docs/rendering-model.md, *Accelerations*).
    pub early_termination: Option<f32>,
    /// Empty-space skipping over the min/max macro-cell grid.
    pub empty_space_skipping: bool,
    /// DVR: the step grows as the ray's transmittance falls, doubled once it
    /// reaches 1/4 and again at 1/16 ([`ADAPTIVE_STEP_DOUBLINGS`] times at
    /// most, each sample's opacity corrected to its step): samples behind
    /// what the ray has gathered weigh less, so they are taken further apart.
    /// Each change of step starts the new step's grid at the sample where it
    /// happens (a multi-channel volume's from the mixture's transmittance).
    /// Not with pre-integration. Default off (docs/rendering-model.md,
    /// *Accelerations*).
    pub adaptive_step: bool,
}

/// The most times [`Accel::adaptive_step`] doubles the step (so at most 4x).
pub const ADAPTIVE_STEP_DOUBLINGS: u32 = 2;

/// The doublings of [`Accel::adaptive_step`] for a ray of transmittance `t`:
/// one per factor of 4 it has fallen (`t <= 1/4`: 1, `t <= 1/16`: 2), at
/// most [`ADAPTIVE_STEP_DOUBLINGS`] (the kernels' `step_doublings`).
pub fn adaptive_step_doublings(t: f64) -> u32 {
    let mut j = 0;
    while j < ADAPTIVE_STEP_DOUBLINGS && t <= 0.25f64.powi(j as i32 + 1) {
        j += 1;
    }
    j
}

impl Default for Accel {
    fn default() -> Self {
        Accel {
            early_termination: Some(0.99),
            empty_space_skipping: true,
            adaptive_step: false,
        }
    }
}

impl Accel {
    /// Both accelerations off.
    pub const BRUTE_FORCE: Accel = Accel {
        early_termination: None,
        empty_space_skipping: false,
        adaptive_step: false,
    };
    /// Early ray termination at 0.99 only.
    pub const ERT_ONLY: Accel = Accel {
        early_termination: Some(0.99),
        empty_space_skipping: false,
        adaptive_step: false,
    };
    /// Empty-space skipping only.
    pub const ESS_ONLY: Accel = Accel {
        early_termination: None,
        empty_space_skipping: true,
        adaptive_step: false,
    };
}

/// An axis-aligned box in the volume's texture space (`0..1` per axis over the
/// volume's box) that cuts the volume: rays sample only inside it. The default
/// is the whole volume.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClipBox {
    /// The lower corner.
    pub min: [f32; 3],
    /// The upper corner (`>= min` per axis; equal: nothing is drawn).
    pub max: [f32; 3],
}

impl ClipBox {
    /// The whole volume.
    pub const FULL: ClipBox = ClipBox {
        min: [0.0; 3],
        max: [1.0; 3],
    };
}

impl Default for ClipBox {
    fn default() -> Self {
        ClipBox::FULL
    }
}

/// Everything that decides what a ray computes, besides camera, volume and TF.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderSettings {
    /// The mode.
    pub mode: RenderMode,
    /// Shading.
    pub shading: Shading,
    /// Accelerations.
    pub accel: Accel,
    /// Sampling step as a fraction of the smallest voxel side (default 0.5).
    pub step_factor: f32,
    /// Bisection iterations refining an isosurface hit.
    pub iso_refine_steps: u32,
    /// Accumulated opacity at which DVR writes depth.
    pub depth_opacity: f32,
    /// The part of the volume that is drawn (default: all of it).
    pub clip: ClipBox,
    /// DVR with a pre-integrated transfer function (Engel et al. 2001): each
    /// sample composites the segment from the previous sample's value to its own,
    /// integrated through the TF, instead of the TF at one point (default off;
    /// `docs/rendering-model.md`, "Pre-integration"). Iso and MIP ignore it.
    pub preintegrated: bool,
    /// Label maps: smooth boundaries. Each sample takes the label with the
    /// largest trilinear weight among its 8 neighbouring voxels (the label
    /// whose indicator, filtered, is largest: `labels::smooth_label_at`),
    /// so boundaries are reconstructed between voxels instead of as voxel
    /// steps (default off: the nearest voxel). Intensity volumes ignore it.
    pub smooth_labels: bool,
}

impl Default for RenderSettings {
    fn default() -> Self {
        RenderSettings {
            mode: RenderMode::Dvr,
            shading: Shading::default(),
            accel: Accel::default(),
            step_factor: 0.5,
            iso_refine_steps: 8,
            depth_opacity: 0.5,
            clip: ClipBox::FULL,
            preintegrated: false,
            smooth_labels: false,
        }
    }
}

/// A setting outside the range the renderers accept.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum SettingsError {
    /// A value is NaN, infinite or outside its documented range.
    #[error("{field} = {value} is outside {min}..={max}")]
    OutOfRange {
        /// The setting.
        field: &'static str,
        /// Its value.
        value: f64,
        /// Smallest accepted value.
        min: f64,
        /// Largest accepted value.
        max: f64,
    },
    /// A render mode this version does not implement.
    #[error("render mode {0:?} is not supported")]
    UnsupportedMode(RenderMode),
}

impl RenderSettings {
    /// Smallest accepted `step_factor`: finer steps cost more than they gain (the
    /// reference itself samples at 1/8), and every ray's work is bounded by the
    /// volume's diagonal over the step.
    pub const MIN_STEP_FACTOR: f32 = 1.0 / 64.0;
    /// Largest accepted `step_factor`.
    pub const MAX_STEP_FACTOR: f32 = 16.0;
    /// Largest accepted `iso_refine_steps` (bisection halves the bracket each step;
    /// 32 exhausts f32).
    pub const MAX_ISO_REFINE_STEPS: u32 = 32;

    /// Checks every field: finite and within its range, a supported mode.
    pub fn validate(&self) -> Result<(), SettingsError> {
        fn check(field: &'static str, value: f32, min: f32, max: f32) -> Result<(), SettingsError> {
            if value >= min && value <= max {
                Ok(())
            } else {
                Err(SettingsError::OutOfRange {
                    field,
                    value: value as f64,
                    min: min as f64,
                    max: max as f64,
                })
            }
        }
        check(
            "step_factor",
            self.step_factor,
            Self::MIN_STEP_FACTOR,
            Self::MAX_STEP_FACTOR,
        )?;
        check("depth_opacity", self.depth_opacity, 0.0, 1.0)?;
        if self.iso_refine_steps > Self::MAX_ISO_REFINE_STEPS {
            return Err(SettingsError::OutOfRange {
                field: "iso_refine_steps",
                value: self.iso_refine_steps as f64,
                min: 0.0,
                max: Self::MAX_ISO_REFINE_STEPS as f64,
            });
        }
        if let Some(t) = self.accel.early_termination {
            check("accel.early_termination", t, f32::MIN_POSITIVE, 1.0)?;
        }
        for a in 0..3 {
            check("clip.min", self.clip.min[a], 0.0, 1.0)?;
            check("clip.max", self.clip.max[a], self.clip.min[a], 1.0)?;
        }
        let s = &self.shading;
        check("shading.ambient", s.ambient, 0.0, f32::MAX)?;
        check("shading.diffuse", s.diffuse, 0.0, f32::MAX)?;
        check("shading.specular", s.specular, 0.0, f32::MAX)?;
        check("shading.shininess", s.shininess, 0.0, 1.0e4)?;
        match self.mode {
            RenderMode::Dvr | RenderMode::Mip => Ok(()),
            RenderMode::Iso { value, color } => {
                check("iso.value", value, f32::MIN, f32::MAX)?;
                for c in color {
                    check("iso.color", c, 0.0, 1.0)?;
                }
                Ok(())
            }
            #[allow(unreachable_patterns)]
            other => Err(SettingsError::UnsupportedMode(other)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_step_doubles_per_factor_of_four_of_transmittance() {
        assert_eq!(adaptive_step_doublings(1.0), 0);
        assert_eq!(adaptive_step_doublings(0.2501), 0);
        assert_eq!(adaptive_step_doublings(0.25), 1);
        assert_eq!(adaptive_step_doublings(0.0626), 1);
        assert_eq!(adaptive_step_doublings(0.0625), 2);
        assert_eq!(adaptive_step_doublings(0.0), ADAPTIVE_STEP_DOUBLINGS);
        // Never fewer as the transmittance falls.
        let mut last = 0;
        for i in (0..=1000).rev() {
            let j = adaptive_step_doublings(i as f64 / 1000.0);
            assert!(j >= last && j <= ADAPTIVE_STEP_DOUBLINGS);
            last = j;
        }
    }

    #[test]
    fn defaults_validate() {
        assert_eq!(RenderSettings::default().validate(), Ok(()));
    }

    #[test]
    fn non_finite_and_out_of_range_settings_are_refused() {
        let ok = RenderSettings::default();
        let bad = [
            RenderSettings {
                clip: ClipBox {
                    min: [0.0, f32::NAN, 0.0],
                    max: [1.0; 3],
                },
                ..ok
            },
            RenderSettings {
                clip: ClipBox {
                    min: [0.6, 0.0, 0.0],
                    max: [0.5, 1.0, 1.0],
                },
                ..ok
            },
            RenderSettings {
                clip: ClipBox {
                    min: [0.0; 3],
                    max: [1.0, 1.5, 1.0],
                },
                ..ok
            },
            RenderSettings {
                step_factor: f32::NAN,
                ..ok
            },
            RenderSettings {
                step_factor: 1e-6,
                ..ok
            },
            RenderSettings {
                step_factor: -1.0,
                ..ok
            },
            RenderSettings {
                step_factor: f32::INFINITY,
                ..ok
            },
            RenderSettings {
                depth_opacity: f32::NAN,
                ..ok
            },
            RenderSettings {
                iso_refine_steps: 1000,
                ..ok
            },
            RenderSettings {
                accel: Accel {
                    early_termination: Some(f32::NAN),
                    ..ok.accel
                },
                ..ok
            },
            RenderSettings {
                accel: Accel {
                    early_termination: Some(0.0),
                    ..ok.accel
                },
                ..ok
            },
            RenderSettings {
                shading: Shading {
                    ambient: f32::NAN,
                    ..ok.shading
                },
                ..ok
            },
            RenderSettings {
                shading: Shading {
                    shininess: f32::INFINITY,
                    ..ok.shading
                },
                ..ok
            },
            RenderSettings {
                mode: RenderMode::Iso {
                    value: f32::NAN,
                    color: [1.0; 3],
                },
                ..ok
            },
            RenderSettings {
                mode: RenderMode::Iso {
                    value: 0.5,
                    color: [f32::NAN, 0.0, 0.0],
                },
                ..ok
            },
        ];
        for s in bad {
            assert!(
                matches!(s.validate(), Err(SettingsError::OutOfRange { .. })),
                "{s:?} must be refused"
            );
        }
    }
}
