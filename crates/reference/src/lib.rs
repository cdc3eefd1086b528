//! The CPU reference renderer and the image metrics: brickray's accuracy oracle.
//!
//! # What it computes
//!
//! [`render_reference`] evaluates the rendering model of `docs/rendering-model.md`
//! (the function of volume, transfer function, camera and settings that every
//! brickray renderer computes) as directly as the text states it:
//!
//! * one ray per pixel centre from the camera's f64 basis
//!   ([`RayGen::pixel_ray`](brickray_core::RayGen::pixel_ray)),
//!   or `n x n` stratified sub-pixel rays averaged ([`ReferenceOptions::supersample`]);
//! * the ray clipped to the volume's texture-space unit cube
//!   ([`Ray::clip_unit_box`](brickray_core::Ray::clip_unit_box)) and, when the host
//!   passes a depth buffer, to the host's depth
//!   ([`RayGen::t_at_depth`](brickray_core::RayGen::t_at_depth), in the camera's
//!   depth convention);
//! * samples at `t_k = t0 + k * dt` (computed from `k`, never accumulated) while
//!   `t_k < t1`, with `dt = step_factor * voxel_world`;
//! * the exact trilinear value of the normalized field
//!   ([`Volume::sample_trilinear`](brickray_core::Volume::sample_trilinear), f64,
//!   clamp-to-edge);
//! * the transfer-function lookup in f64 with the opacity corrected to the step,
//!   `a' = 1 - (1 - a)^step_factor`;
//! * DVR (front to back, premultiplied, optionally Blinn-Phong shaded), Iso (first
//!   crossing refined by bisection, always shaded) and MIP, exactly as specified.
//!
//! Everything is computed in f64, from the same `brickray-core` functions the GPU
//! renderers' host code uses (camera matrices, ray set-up, clipping, lookup).
//!
//! # Why it is the oracle
//!
//! It is deliberately brute force: no empty-space skipping, no early ray
//! termination (`settings.accel` is ignored), no bricks, no caches, no textures.
//! Every sample the model defines is taken, so the only approximation left is the
//! step, and that is the model's own: with the opacity correction, the discrete
//! front-to-back sum converges to the emission-absorption integral as the step
//! shrinks. The reference therefore marches with a much finer step than the GPU
//! (`ReferenceOptions::step_factor`, default 1/8 of a voxel, while
//! `settings.step_factor` is ignored), and a correct GPU image at step 0.5 lies
//! within a small, step-bounded distance of it. The crate's tests check the
//! reference against closed-form answers (constant slabs, linear ramps, single
//! bright voxels), not against another renderer.
//!
//! # Shading normals
//!
//! As the model states: the central difference `g_i = (v(p + e_i) - v(p - e_i)) / 2`
//! (one voxel along each voxel axis, normalized-value units per voxel; samples with
//! `|g| < 1e-6` are left unshaded) becomes the texture-space gradient `g * dims`
//! (since `p = u * dims - 0.5`), which the inverse transpose of the model's 3x3 maps
//! to world. This is the exact world gradient of a linear field in any affine frame
//! (a test checks it on a rotated, sheared, anisotropic frame); for the default
//! centred frame it is the direction of the physical gradient `g_i / spacing_i`.
//!
//! [`render_slice`] is the reference of slice views: exact trilinear samples
//! of a plane or a slab (max or mean), mapped through a window and colour map;
//! [`render_label_slice`] that of a label map's slices (nearest, label table).
//!
//! # Metrics
//!
//! [`psnr`], [`mean_flip`] (NVIDIA's FLIP, through the `nv-flip` crate), [`ssim`],
//! [`compare`], [`compare_and_report`] (writes actual, expected and difference
//! PNGs) and [`assert_close`] compare 8-bit RGBA images such as
//! [`Image::to_rgba8`] produces (composited over a background) or GPU read-backs.
//!
//! # Level-of-detail models
//!
//! [`lod`] models on the CPU the cuts of a brick octree the out-of-core
//! renderer draws (per-node and octant-granular), resampled onto the finest
//! grid for the reference to render, and the LOD oracle (each node's exact
//! image cost of being drawn coarse).

mod image_buf;
pub mod lod;
mod metrics;
mod render;
mod slice;
mod ssim;
mod temporal;
mod visible;

pub use image_buf::{Image, ImageIoError, save_rgba8_png};
pub use metrics::{
    ImageComparison, assert_close, compare, compare_and_report, max_abs_diff, mean_flip, psnr,
    test_output_dir,
};
pub use render::{
    DEFAULT_STEP_FACTOR, EXACT_STEP_FACTOR, ReferenceOptions, render_channels_reference,
    render_reference,
};
pub use slice::{
    SliceReferenceError, render_channel_slice, render_label_slice, render_slice,
    render_slice_with_overlay,
};
pub use ssim::ssim;
pub use temporal::{
    CHANGE_EPS, TemporalError, TemporalOptions, TemporalReport, temporal_stability,
};
pub use visible::visible_weights;
