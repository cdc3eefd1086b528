//! What the reference renders and how it samples: [`ReferenceOptions`] and
//! its steps.

use brickray_core::{Intensity, LabelOverlay};

/// The reference's default step: 1/8 of the smallest voxel side (the GPU's
/// default is 1/2).
pub const DEFAULT_STEP_FACTOR: f32 = 0.125;

/// The step of [`ReferenceOptions::exact_integral`]: 1/16 of the smallest voxel.
pub const EXACT_STEP_FACTOR: f32 = 1.0 / 16.0;

/// How the reference samples the image and the rays.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReferenceOptions<'a> {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Sampling step as a fraction of the smallest voxel side (replaces
    /// `RenderSettings::step_factor`; default [`DEFAULT_STEP_FACTOR`]). Opacity is
    /// corrected to this step, so images at different steps converge to the same
    /// integral.
    pub step_factor: f32,
    /// `1`: one ray through each pixel centre. `n`: `n x n` stratified rays at the
    /// centres of an `n x n` grid of sub-pixels, their premultiplied colours
    /// averaged and the nearest of their depths kept. `0` is treated as `1`.
    pub supersample: u32,
    /// Host clip depth per pixel (`width * height`, row 0 at the top): each ray of
    /// that pixel stops there.
    pub host_depth: Option<&'a [f32]>,
    /// DVR composites pre-integrated segments (Engel et al. 2001): sample `k >= 1`
    /// composites the segment from the value of sample `k - 1` to its own,
    /// `step_factor` reference lengths long (the first sample composites
    /// nothing: the ray starts there), integrated exactly through the TF in f64
    /// ([`Preintegrator::segment`](brickray_core::tf::Preintegrator::segment))
    /// in pieces along the parabola through its samples and the sample before
    /// ([`segment_values`](brickray_core::tf::segment_values),
    /// [`join_pieces`](brickray_core::tf::join_pieces)), as the kernels do,
    /// shaded at the segment's midpoint. `settings.preintegrated` is ignored, like
    /// `settings.step_factor`. Default off.
    pub preintegrated: bool,
    /// MIP maps its maximum through this window and colour map, opaque,
    /// instead of the transfer function (`VolumeRenderer::set_intensity`).
    /// Default `None`.
    pub intensity: Option<Intensity>,
    /// The spread of each voxel of `vol` (normalized units, x fastest, one per
    /// voxel): the standard deviation of the finest values a coarse level's
    /// voxel stands for ([`brickray_core::MomentGrid::sigmas`]). Point-sampled
    /// DVR (shaded or not) then classifies each sample with the TF convolved
    /// by a Gaussian of the trilinearly interpolated spread
    /// ([`brickray_core::tf::spread`], a table of
    /// [`SPREAD_ROWS`](brickray_core::tf::SPREAD_ROWS) rows); a sample of
    /// spread 0 is classified exactly as without it. Iso and MIP use the mean
    /// field alone, and pre-integrated segments ignore the spread. Default
    /// `None` (the finest level, or a coarse level drawn as the TF of its
    /// mean).
    pub spread: Option<&'a [f32]>,
    /// A label map drawn over the image (`brickray_core::overlay`): DVR
    /// samples take the label under them ([`LabelOverlay::apply`], nearest,
    /// or the heaviest of 8 with `settings.smooth_labels`) before shading;
    /// iso surfaces (before shading) and MIP maxima are tinted by the label
    /// under them in colour mode ([`LabelOverlay::tint`]). Default `None`.
    pub overlay: Option<&'a LabelOverlay<'a>>,
    /// DVR stops a ray once its opacity reaches this threshold and fills
    /// the residual as the kernels do: the ray's mean extinction over the
    /// pieces that composited colour, continued over the rest of the ray,
    /// in the stopping piece's colour (the CPU twin of the kernels'
    /// `accumulate`; docs/rendering-model.md, *Accelerations*). The GPU's
    /// `settings.accel.early_termination` is ignored: by default (`None`) the
    /// reference does not terminate. The multi-channel reference
    /// ([`render_channels_reference`](crate::render_channels_reference))
    /// ignores this too.
    pub early_termination: Option<f32>,
    /// MIP refines the largest sample and the runner-up (the best sample more
    /// than a step and a half from it) between samples as the scalar kernels
    /// do (`mip_sample`, `mip_refine`: half a step, then a quarter, either
    /// side), and so do the multi-channel kernels and
    /// [`render_channels_reference`](crate::render_channels_reference) per
    /// channel. Default on; off, the maximum of the samples alone.
    pub mip_refine: bool,
    /// DVR's step grows as the ray's transmittance falls, as the kernels'
    /// does with `Accel::adaptive_step` (`brickray_core::adaptive_step_doublings`
    /// before each sample: when the count changes, the new step's grid
    /// starts at that sample; each sample's opacity corrected to its step).
    /// The GPU's `settings.accel.adaptive_step` is ignored. Pre-integrated
    /// segments keep the step; the multi-channel reference doubles it with
    /// the mixture's transmittance. Default off.
    pub adaptive_step: bool,
}

impl ReferenceOptions<'static> {
    /// `width x height`, step 1/8, one ray per pixel, no host depth.
    pub fn new(width: u32, height: u32) -> ReferenceOptions<'static> {
        ReferenceOptions {
            width,
            height,
            step_factor: DEFAULT_STEP_FACTOR,
            supersample: 1,
            host_depth: None,
            preintegrated: false,
            intensity: None,
            spread: None,
            overlay: None,
            early_termination: None,
            mip_refine: true,
            adaptive_step: false,
        }
    }
}

impl Default for ReferenceOptions<'static> {
    /// 256 x 256, step 1/8, one ray per pixel, no host depth.
    fn default() -> Self {
        ReferenceOptions::new(256, 256)
    }
}

impl<'a> ReferenceOptions<'a> {
    /// With another step factor.
    pub fn with_step_factor(self, step_factor: f32) -> Self {
        ReferenceOptions {
            step_factor,
            ..self
        }
    }

    /// With `n x n` rays per pixel.
    pub fn with_supersample(self, n: u32) -> Self {
        ReferenceOptions {
            supersample: n,
            ..self
        }
    }

    /// With or without pre-integrated segments ([`Self::preintegrated`]).
    pub fn with_preintegration(self, preintegrated: bool) -> Self {
        ReferenceOptions {
            preintegrated,
            ..self
        }
    }

    /// The exact-integral mode: the TF point-sampled at a very fine step
    /// ([`EXACT_STEP_FACTOR`], 1/16 voxel) without pre-integration, whose sum
    /// converges to the emission-absorption integral; what pre-integrated and
    /// plain images at coarse steps are measured against.
    pub fn exact_integral(self) -> Self {
        ReferenceOptions {
            step_factor: EXACT_STEP_FACTOR,
            preintegrated: false,
            ..self
        }
    }

    /// With or without DVR's adaptive step ([`Self::adaptive_step`]).
    pub fn with_adaptive_step(self, adaptive_step: bool) -> Self {
        ReferenceOptions {
            adaptive_step,
            ..self
        }
    }

    /// With a host depth buffer.
    pub fn with_host_depth<'b>(self, depth: &'b [f32]) -> ReferenceOptions<'b>
    where
        'a: 'b,
    {
        ReferenceOptions {
            host_depth: Some(depth),
            ..self
        }
    }

    /// With MIP mapped through `intensity` ([`Self::intensity`]).
    pub fn with_intensity(self, intensity: Intensity) -> Self {
        ReferenceOptions {
            intensity: Some(intensity),
            ..self
        }
    }

    /// With a spread per voxel ([`Self::spread`]).
    pub fn with_spread<'b>(self, sigma: &'b [f32]) -> ReferenceOptions<'b>
    where
        'a: 'b,
    {
        ReferenceOptions {
            spread: Some(sigma),
            ..self
        }
    }

    /// Terminating DVR rays at `threshold` as the kernels do
    /// ([`Self::early_termination`]).
    pub fn with_early_termination(self, threshold: f32) -> Self {
        ReferenceOptions {
            early_termination: Some(threshold),
            ..self
        }
    }

    /// With or without MIP's refinement between samples ([`Self::mip_refine`]).
    pub fn with_mip_refinement(self, mip_refine: bool) -> Self {
        ReferenceOptions { mip_refine, ..self }
    }

    /// With a label map over the image ([`Self::overlay`]).
    pub fn with_overlay<'b>(self, overlay: &'b LabelOverlay<'b>) -> ReferenceOptions<'b>
    where
        'a: 'b,
    {
        ReferenceOptions {
            overlay: Some(overlay),
            ..self
        }
    }
}
