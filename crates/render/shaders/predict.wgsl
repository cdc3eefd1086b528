// The isosurface prediction buffer (Braley et al., "GPU accelerated isosurface
// volume rendering using depth-based coherence"; docs/prediction.md), shared by
// both kernels: its bindings in group 0 (owned by `frame.rs`), its switches and
// its per-pixel encoding, and what both kernels' traversals share.
//
// Per pixel the buffer holds last frame's result: the hit's distance from the
// eye along the ray (at the upper sample of the crossing's bracket) or a flag. The next frame picks a traversal: local
// (search outward from the predicted t), sparse (march with a coarse step and
// bisect) or full (the ordinary march); a pixel whose ray misses the box is not
// traversed. Pipelines without PREDICT compile none of this. The traversals
// are in incore_predict.wgsl and ooc_predict.wgsl.

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

// What a predicting pixel starts from: its index in the history, the eye's
// distance from its ray's origin (entries are distances from the eye; t is
// from the near plane, which moves with the near distance) and last frame's
// entry.
struct PredPixel {
    p: u32,
    eye_offset: f32,
    last: u32,
}

fn pred_begin(px: vec2<u32>, r: Ray) -> PredPixel {
    let p = pred_pixel(px);
    return PredPixel(p, frame.near / r.dist_per_t, pred_last(p));
}

// The traversal a pixel takes for last frame's entry `last`: full, local or
// sparse. The refresh flag is mixed with the pixel's entry (never a branch on
// a uniform alone; see common.wgsl). No information means a cleared history
// (full traversal), or with reprojection a hole of the warp (sparse); a miss
// of the surface or of the box (which the ray now enters) is sparse.
fn pred_choice(last: u32) -> u32 {
    let full = pred.refresh != 0u || (last == PRED_NO_INFO && pred.reprojected == 0u);
    let local = !full && pred_is_hit(last);
    return select(select(TRAVERSAL_SPARSE, TRAVERSAL_LOCAL, local), TRAVERSAL_FULL, full);
}

// Writes this frame's entry of pixel p (the hit's eye distance, or the flag
// for a miss of the surface or, `missed_box`, of the box) and its class.
fn pred_store(p: u32, acc: Accum, missed_box: bool, eye_offset: f32, kind: u32) {
    var entry = select(PRED_MISS_SURFACE, PRED_MISS_BOX, missed_box);
    if (acc.hit) {
        entry = pred_encode_hit(acc.hit_b + eye_offset);
    }
    pred_buf[pred.write_off + p] = entry;
    pred_buf[pred.class_off + p] = kind;
}

// Bisects a sparse bracket `pred.sparse_refine` times (in the cursor where it
// was found), so that the remaining bracket is as long as a full traversal's
// before `finish_ray` refines it.
fn sparse_refine(acc: ptr<function, Accum>, c: Cursor) {
    let a = (*acc).hit_a;
    let b = (*acc).hit_b;
    let ab = iso_bisect(acc, c, a, b, select(0u, pred.sparse_refine, b > a));
    (*acc).hit_a = ab.x;
    (*acc).hit_b = ab.y;
}
