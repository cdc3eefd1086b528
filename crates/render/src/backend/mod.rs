//! The volume backends behind one seam: each owns group 2 of its kernel (the
//! volume's textures, tables and uniforms, and their bind group) and updates it
//! per frame. In core the volume is one 3D texture; out of core a brick atlas fed
//! by the cache and walked through the octree-with-ropes index.

pub(crate) mod channels;
pub(crate) mod feedback;
pub(crate) mod gradients;
pub(crate) mod incore;
pub(crate) mod occlusion;
pub(crate) mod ooc;
pub(crate) mod ooc_channels;
pub(crate) mod readback;

pub(crate) use channels::Channels;
pub use feedback::FeedbackStats;
pub(crate) use incore::InCore;
pub use occlusion::OcclusionStats;
pub(crate) use ooc::OutOfCore;

use crate::kernels::KernelKind;

/// What every backend does for the coordinator.
pub(crate) trait VolumeBackend: std::fmt::Debug {
    /// The kernel that samples this backend.
    fn kind(&self) -> KernelKind;
    /// The layout of group 2 (the kernel's pipeline layout is built from it).
    fn layout(&self) -> &wgpu::BindGroupLayout;
    /// Group 2.
    fn bind_group(&self) -> &wgpu::BindGroup;
    /// Records what must precede the ray-cast pass (out of core: clearing the
    /// usage counters).
    fn before_pass(&mut self, encoder: &mut wgpu::CommandEncoder) {
        let _ = encoder;
    }
    /// Records what follows the ray-cast pass (out of core: copying the usage
    /// counters into the read-back ring).
    fn after_pass(&mut self, queue: &wgpu::Queue, encoder: &mut wgpu::CommandEncoder) {
        let _ = (queue, encoder);
    }
    /// True when the kernel must measure the visible weights
    /// (`shaders/feedback.wgsl`; out of core under `LodMetric::VisibleError`).
    fn measures_weights(&self) -> bool {
        false
    }
    /// True when the volume is a label map (nearest samples through the
    /// label table: the kernels draw it unshaded and without
    /// pre-integration, which would interpolate between ids).
    fn labels(&self) -> bool;
    /// True when the volume's atlas carries spreads (out of core, a source
    /// with spreads): DVR classifies coarse levels with them.
    fn spread(&self) -> bool {
        false
    }
    /// True when shaded DVR reads per-voxel gradients (in core, made by the
    /// first shaded DVR frame): the kernel shades with one read instead of six.
    fn gradients(&self) -> bool {
        false
    }
    /// False where MIP's empty-space skipping costs more than it saves at a
    /// sample step of `step` voxels (in core, from the macro cells,
    /// `brickray_core::MIP_SKIP_SHARE_MIN`; out of core, from the sub-cells
    /// of the bricks of the plan applied last,
    /// `brickray_core::MIP_SKIP_SHARE_MIN_BRICKS`): MIP frames then march
    /// without it.
    fn mip_skipping(&self, _step: f32) -> bool {
        true
    }
    /// False where DVR's empty-space skipping costs more than it saves at a
    /// sample step of `step` voxels, `shaded` or not (in core, too few macro
    /// cells transparent through the transfer function,
    /// `brickray_core::dvr_skip_share_min`; out of core, too few sub-cells
    /// of the plan's bricks, `brickray_core::dvr_skip_share_min_bricks`):
    /// DVR frames then march without it.
    fn dvr_skipping(&self, _step: f32, _shaded: bool) -> bool {
        true
    }
    /// True when some leaf the kernel draws mixes its brick with an
    /// ancestor's (out of core, a fade of the plan applied last): without
    /// one, the kernel reads each sample's own brick alone (`FADES`).
    fn fades(&self) -> bool {
        false
    }
    /// True when the out-of-core index is an octree (every level splits
    /// every axis: [`crate::kernels::Variant::octree`]).
    fn octree(&self) -> bool {
        false
    }
    /// Most index leaves one ray may visit (0 in core).
    fn max_leaves(&self) -> u32;
    /// Step lengths the kernel samples with (rows of the corrected TF table):
    /// one in core, one per octree level out of core (the step doubles a level).
    fn step_lengths(&self) -> u32;
    /// True when another frame of the same view would change the image.
    fn wants_redraw(&self) -> bool;
    /// The texture format the samples are stored in.
    fn texel_format(&self) -> wgpu::TextureFormat;
    /// Bytes of volume data resident on the GPU.
    fn resident_bytes(&self) -> u64;
}

/// The backend in use.
#[derive(Debug)]
pub(crate) enum Backend {
    InCore(Box<InCore>),
    OutOfCore(Box<OutOfCore>),
    /// A multi-channel volume in core.
    Channels(Box<Channels>),
}

impl Backend {
    pub(crate) fn get(&self) -> &dyn VolumeBackend {
        match self {
            Backend::InCore(b) => b.as_ref(),
            Backend::OutOfCore(b) => b.as_ref(),
            Backend::Channels(b) => b.as_ref(),
        }
    }

    pub(crate) fn get_mut(&mut self) -> &mut dyn VolumeBackend {
        match self {
            Backend::InCore(b) => b.as_mut(),
            Backend::OutOfCore(b) => b.as_mut(),
            Backend::Channels(b) => b.as_mut(),
        }
    }

    /// Channels of a multi-channel volume (in core or streamed), `None`
    /// for a single-channel one.
    pub(crate) fn channel_count(&self) -> Option<usize> {
        match self {
            Backend::Channels(b) => Some(b.count()),
            Backend::OutOfCore(b) => b.channel_count(),
            _ => None,
        }
    }

    pub(crate) fn out_of_core(&self) -> Option<&OutOfCore> {
        match self {
            Backend::OutOfCore(b) => Some(b),
            Backend::InCore(_) | Backend::Channels(_) => None,
        }
    }
}
