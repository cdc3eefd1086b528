// The isosurface prediction buffer (Braley et al., "GPU accelerated isosurface
// volume rendering using depth-based coherence"; docs/prediction.md), shared by
// both kernels: its bindings in group 0 (owned by `frame.rs`), its switches and
// its per-pixel encoding. The in-core traversals are in incore_predict.wgsl.
//
// Per pixel the buffer holds last frame's result: the hit's distance from the
// eye along the ray (at the upper sample of the crossing's bracket) or a flag. The next frame picks a traversal: local
// (search outward from the predicted t), sparse (march with a coarse step and
// bisect) or full (the ordinary march); a pixel whose ray misses the box is not
// traversed. Pipelines without PREDICT compile none of this.

override PREDICT: bool = false;
// The first-hit guard: a local hit is accepted only once the macro cells in
// front of it are proven unable to hold the isovalue.
override GUARD: bool = false;
// Empty-space skipping in the sparse traversal.
override SPARSE_ESS: bool = false;

// `PredictUniforms` in frame.rs (a test checks the offsets).
struct Predict {
    // Offsets (in u32 elements) of last frame's history, this frame's history
    // and the per-pixel traversal classes in `pred_buf`.
    read_off: u32,
    write_off: u32,
    class_off: u32,
    // 1 on a full-refresh frame (every alpha frames), else 0.
    refresh: u32,
    // Most steps of the local search in each direction.
    local_steps: u32,
    // Extra bisection steps of a sparse bracket (log2 of sparse_dt / dt).
    sparse_refine: u32,
    // Sparse step (world): the smallest voxel / kappa.
    sparse_dt: f32,
    // 1 when `read_off` holds last frame's hits warped into this view
    // (reproject.wgsl: complemented; 0 a hole, which takes the sparse traversal).
    reprojected: u32,
}

@group(0) @binding(5) var<storage, read_write> pred_buf: array<u32>;
@group(0) @binding(6) var<uniform> pred: Predict;

// History entries: 0 = no information (a cleared buffer), a hit at eye
// distance e as the bits of e + 1 (ordered like e, as u32), or a flag.
const PRED_NO_INFO: u32 = 0u;
const PRED_MISS_SURFACE: u32 = 0xfffffffeu;
const PRED_MISS_BOX: u32 = 0xfffffffdu;

// Per-pixel traversal classes (`TraversalClass` in predict.rs).
const TRAVERSAL_NONE: u32 = 0u;
const TRAVERSAL_LOCAL: u32 = 1u;
const TRAVERSAL_LOCAL_MISSED: u32 = 2u;
const TRAVERSAL_GUARD_REJECTED: u32 = 3u;
const TRAVERSAL_SPARSE: u32 = 4u;
const TRAVERSAL_FULL: u32 = 5u;

fn pred_encode_hit(t: f32) -> u32 {
    return bitcast<u32>(max(t, 0.0) + 1.0);
}

fn pred_decode_hit(v: u32) -> f32 {
    return bitcast<f32>(v) - 1.0;
}

fn pred_is_hit(v: u32) -> bool {
    return v != PRED_NO_INFO && v < PRED_MISS_BOX;
}

// This pixel's entry from last frame (warped when reprojected). Selected, not
// branched, on the uniform flag.
fn pred_last(p: u32) -> u32 {
    let raw = pred_buf[pred.read_off + p];
    let warped = select(0u, ~raw, raw != 0u);
    return select(raw, warped, pred.reprojected != 0u);
}

fn pred_pixel(px: vec2<u32>) -> u32 {
    return px.y * frame.viewport_size.x + px.x;
}
