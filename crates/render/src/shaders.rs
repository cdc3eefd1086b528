//! The WGSL library of the ray casters, packaged with this crate
//! (`crates/render/shaders/`):
//!
//! * `common.wgsl`: groups 0 (frame: uniforms, host depth, outputs) and 1
//!   (transfer function), ray generation, depth conventions, TF lookups, stores;
//! * `modes.wgsl`: the override switches and what a ray computes (DVR
//!   accumulation, iso bisection and shading, MIP), once for both kernels;
//! * `incore.wgsl`, `ooc.wgsl`: each backend's group 2, its sampling `Cursor`
//!   and its march; the out-of-core kernels also include brickray-index's
//!   traversal library, `ooc_volume.wgsl` (their group 2, the brick a leaf
//!   samples and the cursor through it) and `feedback.wgsl` (ray-guided
//!   usage counters);
//! * `channels.wgsl`, `ooc_channels.wgsl`: the multi-channel kernels in core
//!   (group 2: the packed channels) and out of core (the packed brick atlas
//!   and the channels' classification beside ooc_volume.wgsl's bindings),
//!   both over `channel_class.wgsl` (the channels' stacked transfer
//!   functions, visibility, isovalues and how their samples mix), with
//!   `channel_slice.wgsl` their slice view;
//! * `overlay.wgsl`: group 3, a label map over the image (both kernels);
//! * `predict.wgsl`: the isosurface prediction buffer's bindings (group 0) and
//!   switches, in both kernels; `incore_predict.wgsl`, `ooc_predict.wgsl`:
//!   its traversals in each kernel;
//! * `slice.wgsl`: slice views, a second entry point (`slice_main`) of each
//!   kernel; `slice_incore.wgsl`, `slice_ooc.wgsl`: where each samples;
//! * `composite.wgsl`: the draw into the host's pass.
//!
//! Every composed kernel is validated by naga in this module's tests, which also
//! reflect it and check the Rust side against it (uniform offsets, overrides,
//! entry points, workgroup size, mode ids, flag bits), so a WGSL error or drift
//! fails `cargo test` without a GPU.

/// Groups 0 and 1 and the functions every kernel shares.
pub const COMMON: &str = include_str!("../shaders/common.wgsl");
/// The switches and the per-mode ray logic.
pub const MODES: &str = include_str!("../shaders/modes.wgsl");
/// The in-core kernel's own part.
pub const INCORE: &str = include_str!("../shaders/incore.wgsl");
/// The multi-channel in-core kernel's own part.
pub const CHANNELS: &str = include_str!("../shaders/channels.wgsl");
/// The out-of-core kernel's own part.
pub const OOC: &str = include_str!("../shaders/ooc.wgsl");
/// The out-of-core group 2 and brick cursor both out-of-core kernels share.
pub const OOC_VOLUME: &str = include_str!("../shaders/ooc_volume.wgsl");
/// The multi-channel out-of-core kernel.
pub const OOC_CHANNELS: &str = include_str!("../shaders/ooc_channels.wgsl");
/// The classification of several channels, shared by both multi-channel
/// kernels.
pub const CHANNEL_CLASS: &str = include_str!("../shaders/channel_class.wgsl");
/// The slice view of both multi-channel kernels.
pub const CHANNEL_SLICE: &str = include_str!("../shaders/channel_slice.wgsl");
/// A label map over the image (group 3, both kernels).
pub const OVERLAY: &str = include_str!("../shaders/overlay.wgsl");
/// The prediction buffer's bindings, switches and encoding (both kernels).
pub const PREDICT: &str = include_str!("../shaders/predict.wgsl");
/// The in-core traversals of the prediction buffer.
pub const INCORE_PREDICT: &str = include_str!("../shaders/incore_predict.wgsl");
/// The out-of-core traversals of the prediction buffer.
pub const OOC_PREDICT: &str = include_str!("../shaders/ooc_predict.wgsl");
/// The prediction buffer's reprojection pass (a module of its own).
pub const REPROJECT: &str = include_str!("../shaders/reproject.wgsl");
/// The out-of-core kernel's usage feedback (group 2, binding 6).
pub const FEEDBACK: &str = include_str!("../shaders/feedback.wgsl");
/// Slice views: the entry point `slice_main` of both kernels.
pub const SLICE: &str = include_str!("../shaders/slice.wgsl");
/// Where an in-core slice samples.
pub const SLICE_INCORE: &str = include_str!("../shaders/slice_incore.wgsl");
/// Where an out-of-core slice samples.
pub const SLICE_OOC: &str = include_str!("../shaders/slice_ooc.wgsl");
/// The composite (fullscreen) shader.
pub const COMPOSITE: &str = include_str!("../shaders/composite.wgsl");

/// The colour maps' tables as WGSL constants, from `brickray_core::window`
/// (one source for the kernels and the CPU reference).
pub fn color_tables() -> String {
    let v = brickray_core::window::VIRIDIS;
    let entries: Vec<String> = v
        .iter()
        .map(|c| format!("vec3<f32>({:?}, {:?}, {:?})", c[0], c[1], c[2]))
        .collect();
    format!(
        "const VIRIDIS_N: u32 = {n}u;\nconst VIRIDIS: array<vec3<f32>, {n}> = array<vec3<f32>, {n}>({});\n",
        entries.join(", "),
        n = v.len()
    )
}

/// The in-core ray caster as compiled (with its slice entry point).
pub fn incore() -> String {
    format!(
        "{COMMON}\n{}\n{MODES}\n{OVERLAY}\n{PREDICT}\n{INCORE}\n{INCORE_PREDICT}\n{SLICE}\n{SLICE_INCORE}",
        color_tables()
    )
}

/// The multi-channel in-core ray caster as compiled (modes, overlay and
/// prediction for their shared functions and switches).
pub fn channels() -> String {
    format!(
        "{COMMON}\n{}\n{MODES}\n{OVERLAY}\n{PREDICT}\n{CHANNEL_CLASS}\n{CHANNELS}\n{CHANNEL_SLICE}",
        color_tables()
    )
}

/// The out-of-core ray caster as compiled (with the octree traversal library
/// and its slice entry point).
pub fn ooc() -> String {
    format!(
        "{COMMON}\n{}\n{MODES}\n{OVERLAY}\n{PREDICT}\n{}\n{OOC_VOLUME}\n{OOC}\n{OOC_PREDICT}\n{FEEDBACK}\n{SLICE}\n{SLICE_OOC}",
        color_tables(),
        brickray_index::OCTREE_TRAVERSAL_WGSL
    )
}

/// The multi-channel out-of-core ray caster as compiled (modes, overlay and
/// prediction for their shared functions and switches; with its slice entry
/// point).
pub fn ooc_channels() -> String {
    format!(
        "{COMMON}\n{}\n{MODES}\n{OVERLAY}\n{PREDICT}\n{}\n{OOC_VOLUME}\n{CHANNEL_CLASS}\n{OOC_CHANNELS}\n{FEEDBACK}\n{CHANNEL_SLICE}",
        color_tables(),
        brickray_index::OCTREE_TRAVERSAL_WGSL
    )
}

#[cfg(test)]
mod tests;
