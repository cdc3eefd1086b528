//! Slice views and the intensity window of the renderer: what a frame maps
//! values with (`frame.rs` carries it in the frame's uniforms) and, for a
//! renderer drawing a slice ([`crate::VolumeRenderer::set_slice`]), the
//! slice's geometry for the frame's viewport and the camera it is planned and
//! drawn with (docs/rendering-model.md, "Slice views").

use crate::desc::FrameDesc;
use crate::error::PrepareError;
use crate::frame::FrameUniforms;
use brickray_core::{
    Intensity, RenderMode, RenderSettings, SlabMode, SliceGeometry, SliceView, TransferFunction,
};

/// `SLAB_MAX` and `SLAB_MEAN` of slice.wgsl.
pub(crate) const SLAB_MAX: u32 = 0;
pub(crate) const SLAB_MEAN: u32 = 1;

/// What one frame maps intensities with, and its slice.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct FrameMapping {
    /// The window in normalized values and the colour map id (`None`: MIP
    /// through the transfer function).
    window: Option<([f32; 2], u32)>,
    /// The slice drawn, resolved for the frame.
    pub(crate) slice: Option<SliceGeometry>,
}

impl FrameMapping {
    /// The mapping of a frame of a renderer drawing `slice` (or the 3D view)
    /// with `intensity` (a slice without one: grey over the value range) of a
    /// volume whose raw values span `range`. Checks the slice and the window.
    pub(crate) fn new(
        slice: Option<&SliceView>,
        intensity: Option<Intensity>,
        range: [f32; 2],
        desc: &FrameDesc<'_>,
    ) -> Result<FrameMapping, PrepareError> {
        let slice = slice
            .map(|s| s.resolve(&desc.frame, desc.viewport.aspect()))
            .transpose()?;
        let intensity = match (intensity, slice) {
            (Some(i), _) => Some(i),
            (None, Some(_)) => Some(Intensity::grey(range)?),
            (None, None) => None,
        };
        let window = intensity
            .map(|i| -> Result<_, PrepareError> {
                let [lo, hi] = i.window.normalized(range)?;
                Ok(([lo as f32, hi as f32], i.color_map.id()))
            })
            .transpose()?;
        // (A window narrower than f32 resolves would divide by zero.)
        if let Some(([lo, hi], _)) = window
            && !(hi > lo && (hi - lo).is_finite())
        {
            return Err(PrepareError::Window(brickray_core::WindowError::BadWidth {
                width: (hi - lo) as f64,
            }));
        }
        Ok(FrameMapping { window, slice })
    }

    /// The frame a slice is planned and drawn as: the slice's camera (its
    /// frustum is the slab) and MIP settings (a slice classifies as MIP:
    /// every node with data is visible); the 3D view's frame unchanged.
    pub(crate) fn frame<'a>(&self, desc: &FrameDesc<'a>) -> FrameDesc<'a> {
        match &self.slice {
            None => desc.clone(),
            Some(g) => FrameDesc {
                camera: g.camera(),
                settings: RenderSettings {
                    mode: RenderMode::Mip,
                    preintegrated: false,
                    clip: desc.settings.clip,
                    ..RenderSettings::default()
                },
                ..desc.clone()
            },
        }
    }

    /// Writes the window, colour map and slab into the frame's uniforms.
    pub(crate) fn apply(&self, u: &mut FrameUniforms) {
        if let Some(([lo, hi], map)) = self.window {
            u.window_lo = lo;
            u.window_hi = hi;
            u.color_map = map;
        }
        if let Some(g) = &self.slice {
            u.slab_mode = match g.mode {
                SlabMode::Max => SLAB_MAX,
                SlabMode::Mean => SLAB_MEAN,
            };
            u.slab_samples = g.samples;
            u.slab_dt = (g.thickness / g.samples as f64) as f32;
        }
    }
}

/// The transfer function a renderer that draws only slices binds (the
/// kernels' group 1 is bound whatever they read): a grey ramp.
pub(crate) fn slice_tf() -> TransferFunction {
    TransferFunction::ramp(0.0, 1.0, 1.0)
}
