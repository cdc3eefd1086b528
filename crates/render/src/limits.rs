//! The device limits the library needs.

use crate::frame::{self, FrameUniforms};
use crate::kernels;
use crate::{gpu, group2};

/// The device limits brickray needs, all within WebGPU's defaults
/// (`wgpu::Limits::default()`): request at least these when creating the
/// device. Larger volumes, viewports, pools and transfer functions need more of
/// the size limits; a setting beyond the device's limits is a typed
/// [`RenderError::LowDeviceLimit`](crate::RenderError::LowDeviceLimit) naming
/// the limit.
pub fn required_limits() -> wgpu::Limits {
    wgpu::Limits {
        max_bind_groups: kernels::BIND_GROUPS,
        max_storage_buffers_per_shader_stage: group2::MAX_VOLUME_STORAGE
            + group2::STORAGE_OUTSIDE_VOLUME,
        max_storage_textures_per_shader_stage: frame::OUTPUT_FORMATS.len() as u32
            + group2::STORAGE_TEXTURES,
        max_sampled_textures_per_shader_stage: [
            group2::CHANNEL_SAMPLED_TEXTURES,
            group2::OOC_CHANNEL_SAMPLED_TEXTURES,
            group2::OOC_SAMPLED_TEXTURES,
            group2::INCORE_SAMPLED_TEXTURES,
        ]
        .into_iter()
        .fold(0, u32::max),
        max_samplers_per_shader_stage: group2::SAMPLERS,
        max_uniform_buffers_per_shader_stage: group2::CHANNEL_UNIFORM_BUFFERS,
        max_compute_invocations_per_workgroup: gpu::WORKGROUP[0] * gpu::WORKGROUP[1],
        max_compute_workgroup_size_x: gpu::WORKGROUP[0],
        max_compute_workgroup_size_y: gpu::WORKGROUP[1],
        max_compute_workgroup_size_z: 1,
        max_uniform_buffer_binding_size: std::mem::size_of::<FrameUniforms>() as u64,
        ..wgpu::Limits::downlevel_defaults()
    }
}

/// An optional device feature brickray uses when the host enables it, and
/// what it buys.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OptionalFeature {
    /// The feature.
    pub feature: wgpu::Features,
    /// What brickray does with it, and without it.
    pub buys: &'static str,
}

/// The optional device features brickray uses (none is required): enable
/// those the adapter has, `adapter.features() & brickray::optional_features()`.
pub fn optional_features() -> wgpu::Features {
    OPTIONAL_FEATURES
        .iter()
        .fold(wgpu::Features::empty(), |f, o| f | o.feature)
}

/// [`optional_features`], each with what it buys (the texel formats:
/// `docs/rendering-model.md`, "Sample storage and exact interpolation";
/// timestamps: `docs/ARCHITECTURE.md`, "Timing the ray cast").
pub const OPTIONAL_FEATURES: [OptionalFeature; 3] = [
    OptionalFeature {
        feature: wgpu::Features::TEXTURE_FORMAT_16BIT_NORM,
        buys: "R16Unorm texels: u16 and i16 volumes (and u8 volumes, filtered exactly) are \
               stored and interpolated exactly; without it they are stored as R16Float, \
               whose 11-bit mantissa quantises wide-range values and moves isosurfaces",
    },
    OptionalFeature {
        feature: wgpu::Features::FLOAT32_FILTERABLE,
        buys: "filterable R32Float texels: f32 volumes are interpolated in full precision; \
               without it they are stored as normalized R16Float",
    },
    OptionalFeature {
        feature: wgpu::Features::TIMESTAMP_QUERY,
        buys: "GPU timestamps of the ray-cast pass: the host can time the kernel itself \
               (VolumeRenderer::set_pass_timestamps); without it only the frame's wall time \
               is measurable",
    },
];

#[cfg(test)]
mod tests {
    /// Each optional feature is listed once, says what it buys, and the
    /// timestamps `set_pass_timestamps` writes are among them.
    #[test]
    fn optional_features_are_distinct_and_include_timestamps() {
        let listed = &super::OPTIONAL_FEATURES;
        for (i, a) in listed.iter().enumerate() {
            assert!(!a.feature.is_empty() && !a.buys.is_empty(), "{a:?}");
            for b in &listed[i + 1..] {
                assert!(!a.feature.intersects(b.feature), "{a:?} and {b:?}");
            }
        }
        assert!(super::optional_features().contains(wgpu::Features::TIMESTAMP_QUERY));
    }

    /// What the library needs fits WebGPU's default limits, so any conformant
    /// adapter can run it.
    #[test]
    fn required_limits_fit_webgpu_defaults() {
        let need = super::required_limits();
        assert!(need.check_limits(&wgpu::Limits::default()));
        assert!(need.max_storage_buffers_per_shader_stage >= 5);
        assert!(
            need.max_uniform_buffer_binding_size
                >= std::mem::size_of::<super::FrameUniforms>() as u64
        );
    }
}
