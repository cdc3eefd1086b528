// Ray-guided usage feedback of the out-of-core kernel (docs/visibility.md),
// after ooc.wgsl's group 2. Each ray adds 1 to the counter of every pool slot
// whose data leaf it reaches before it terminates (early ray termination, an
// isosurface hit, the sample budget) or leaves the volume: the count of rays,
// i.e. pixels, that could see the brick. The renderer clears the counters
// before the pass, copies them to a read-back ring after it, and maps them
// asynchronously; `brickray-visibility` turns counts below the threshold
// (4 pixels) into "invisible", so refinement stops splitting what rays never
// reach. A leaf skipped because the running MIP maximum exceeds its range is
// still counted: coarser data may have a lower maximum than finer data, so
// only the traversal, not the skip, says the brick is unneeded.
//
// The second word of each slot sums what the image shows of the brick, its
// visible weight (docs/visibility.md): each ray adds its transmittance-weighted
// length through the leaf (the trapezoid of the transmittance at the ray's
// entry and exit of the leaf, times the length it marched there; an
// isosurface ray's up to its hit; a MIP ray's only through the leaf that
// holds its maximum, the one sample that decides its pixel), in voxels of the
// leaf's level (at most
// brick x sqrt(3) per ray, so the sum stays within 32 bits up to
// 2^32 / (4 x 55.5) = 19 M rays per brick of 32) in fixed point of
// 1/WEIGHT_SCALE. The host multiplies by the level's step multiple to get
// finest voxels.

// Two words per pool slot (`OutOfCore`'s usage buffer, backend/ooc.rs): the
// rays that reached it, and its visible weight.
@group(2) @binding(6) var<storage, read_write> usage: array<atomic<u32>>;

// Fixed-point scale of the visible weight (feedback.rs reads it back with the
// same constant).
const WEIGHT_SCALE: f32 = 4.0;

// Records that this ray reached the brick in `slot`.
fn feedback_reached(slot: u32) {
    atomicAdd(&usage[2u * slot], 1u);
}

// Adds what this ray showed of the brick in `slot`: transmittance `trans_in`
// at `t_in`, `trans_out` at `t_out`, over ray parameter `t_out - t_in`;
// `t_voxel`: the ray parameter of one voxel of the leaf's level.
// Pipelines without WEIGHTS (every metric but LodMetric::VisibleError) compile
// none of it.
fn feedback_seen(slot: u32, t_in: f32, t_out: f32, trans_in: f32, trans_out: f32, t_voxel: f32) {
    if (!WEIGHTS) {
        return;
    }
    feedback_add(slot, feedback_weight(t_in, t_out, trans_in, trans_out, t_voxel));
}

// The weight `feedback_seen` adds, in voxels of the leaf's level.
fn feedback_weight(t_in: f32, t_out: f32, trans_in: f32, trans_out: f32, t_voxel: f32) -> f32 {
    return 0.5 * (trans_in + trans_out) * max(t_out - t_in, 0.0) / max(t_voxel, 1e-30);
}

// Adds weight `w` (voxels of the leaf's level) to the brick in `slot`.
fn feedback_add(slot: u32, w: f32) {
    if (!WEIGHTS) {
        return;
    }
    let q = u32(min(w * WEIGHT_SCALE + 0.5, 1e9));
    if (q > 0u) {
        atomicAdd(&usage[2u * slot + 1u], q);
    }
}

// Occlusion-query feedback: the clip depth of the last sample each ray visited
// (where early ray termination or an isosurface hit stopped it; the end of its
// extent in the volume, clipped to the host's depth, otherwise), per viewport
// pixel; occlusion.wgsl rasterises leaf boxes against it.
@group(2) @binding(7) var stop_depth: texture_storage_2d<r32float, write>;

fn feedback_stop(px: vec2<u32>, depth: f32) {
    textureStore(stop_depth, vec2<i32>(px), vec4<f32>(depth, 0.0, 0.0, 0.0));
}

// True when the ray stopped before the end of its extent: DVR early ray
// termination or an isosurface hit. MIP and rays that ran out of samples count
// as not stopped (nothing behind them is hidden).
fn feedback_terminated(acc: Accum) -> bool {
    let ert = ERT && MODE == MODE_DVR && acc.color.a >= frame.ert_threshold;
    return ert || (MODE == MODE_ISO && acc.hit);
}
