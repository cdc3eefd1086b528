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
    /// (`None` = off). Default 0.99.
    pub early_termination: Option<f32>,
    /// Empty-space skipping over the min/max macro-cell grid.
    pub empty_space_skipping: bool,
}

impl Default for Accel {
    fn default() -> Self {
        Accel {
            early_termination: Some(0.99),
            empty_space_skipping: true,
        }
    }
}

impl Accel {
    /// Both accelerations off.
    pub const BRUTE_FORCE: Accel = Accel {
        early_termination: None,
        empty_space_skipping: false,
    };
    /// Early ray termination at 0.99 only.
    pub const ERT_ONLY: Accel = Accel {
        early_termination: Some(0.99),
        empty_space_skipping: false,
    };
    /// Empty-space skipping only.
    pub const ESS_ONLY: Accel = Accel {
        early_termination: None,
        empty_space_skipping: true,
    };
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
        }
    }
}
