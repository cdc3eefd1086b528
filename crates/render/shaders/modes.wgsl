// What a ray computes, once for every kernel: DVR accumulation, isosurface
// bisection and shading, MIP finalisation (docs/rendering-model.md, "Modes").
//
// The volume backend's kernel (incore.wgsl, ooc.wgsl) provides where samples come
// from, as
//     struct Cursor { ... }                                  // e.g. the brick
//     fn cursor_value(c: Cursor, t: f32) -> f32              // normalized value
//     fn cursor_gradient(c: Cursor, t: f32) -> vec4<f32>     // world dir, |g|
// and marches the ray; these functions do the rest.

// Pipeline-overridable switches: every combination is compiled into its own
// pipeline (`Variant` in kernels.rs), so a kernel carries only its mode's code.
override MODE: u32 = 0u;
override ERT: bool = true;
override ESS: bool = true;
override SHADE: bool = false;
// DVR with the pre-integrated table (RenderSettings::preintegrated).
override PREINT: bool = false;
// Out of core: measure the visible weights (feedback.wgsl; the in-core kernel
// ignores it).
override WEIGHTS: bool = false;
// A label map: samples are the nearest texel's, loaded at integer
// coordinates (textureLoad), never filtered (a label id is not interpolated;
// the sampler's fixed-point coordinates would also move boundaries).
override LABELS: bool = false;
// A label map with smooth boundaries (RenderSettings::smooth_labels): the
// label with the largest trilinear weight among a sample's 8 voxels.
override SMOOTH_LABELS: bool = false;
// DVR classifies each sample with its spread (out of core, a source with
// spreads: coarse levels drawn as the average of what their finest voxels
// look like under the TF; docs/rendering-model.md, "Coarse levels").
override SPREAD: bool = false;
// Shaded DVR reads the per-voxel gradients, one filtered texel instead of six
// taps (gradients.wgsl: in core once made, out of core where the volume keeps
// them; declared here with the other switches, read by incore.wgsl and
// ooc.wgsl).
override GRADIENTS: bool = false;
// Out of core: some leaf of the cut drawn fades between its brick and an
// ancestor's (docs/stability.md). Off, a sample reads its own brick alone
// and a sub-cell its own range: a converged frame has no fade, and takes
// 0.86-0.97x the time without the second pass (benchmarks.md, `raw`). The
// in-core kernels ignore it.
override FADES: bool = true;

// Of 8 voxels' label texels and trilinear weights, the label whose weights
// sum highest, ties to the first corner's (labels::smooth_label_at).
fn heaviest_label(ids: array<f32, 8>, w: array<f32, 8>) -> f32 {
    var best = ids[0];
    var best_w = -1.0;
    for (var c = 0u; c < 8u; c = c + 1u) {
        var total = 0.0;
        for (var k = 0u; k < 8u; k = k + 1u) {
            if (ids[k] == ids[c]) {
                total = total + w[k];
            }
        }
        if (total > best_w) {
            best_w = total;
            best = ids[c];
        }
    }
    return best;
}

// The trilinear weight of corner c (bit 0 +x, bit 1 +y, bit 2 +z) at
// fractions t.
fn corner_weight(c: u32, t: vec3<f32>) -> f32 {
    let o = vec3<bool>((c & 1u) != 0u, (c & 2u) != 0u, (c & 4u) != 0u);
    let w = select(vec3<f32>(1.0) - t, t, o);
    return w.x * w.y * w.z;
}

fn corner_offset(c: u32) -> vec3<i32> {
    return vec3<i32>(i32(c & 1u), i32((c >> 1u) & 1u), i32(c >> 2u));
}

// The 8 texels around texture point u of `tex` (`size` texels a side,
// clamped), x fastest, and the fractions of u between them.
struct LabelCorners {
    ids: array<f32, 8>,
    t: vec3<f32>,
}

fn label_corners(tex: texture_3d<f32>, u: vec3<f32>, size: vec3<f32>) -> LabelCorners {
    let hi = vec3<i32>(size) - vec3<i32>(1);
    let p = u * size - vec3<f32>(0.5);
    let f = floor(p);
    var k: LabelCorners;
    k.t = p - f;
    for (var c = 0u; c < 8u; c = c + 1u) {
        let at = clamp(vec3<i32>(f) + corner_offset(c), vec3<i32>(0), hi);
        k.ids[c] = textureLoad(tex, at, 0).r;
    }
    return k;
}

fn corner_weights(t: vec3<f32>) -> array<f32, 8> {
    var w: array<f32, 8>;
    for (var c = 0u; c < 8u; c = c + 1u) {
        w[c] = corner_weight(c, t);
    }
    return w;
}

// A label map's texel at texture point u of `tex` (`size` texels a side),
// loaded at integer coordinates: the texel whose cell holds u (texel
// centres at (i + 0.5) / size), or with SMOOTH_LABELS the heaviest label of
// the 8 around it. Both kernels read label maps through it (out of core a
// brick's apron holds its neighbours' voxels, so the 8 lie in the brick).
fn label_texel(tex: texture_3d<f32>, u: vec3<f32>, size: vec3<f32>) -> f32 {
    if SMOOTH_LABELS {
        let k = label_corners(tex, u, size);
        return heaviest_label(k.ids, corner_weights(k.t));
    }
    let hi = vec3<i32>(size) - vec3<i32>(1);
    let i = clamp(vec3<i32>(floor(u * size)), vec3<i32>(0), hi);
    return textureLoad(tex, i, 0).r;
}

// The gradient, per texel of `tex`, of the trilinearly filtered indicator of
// the heaviest label at u: the normal of a smooth label boundary, zero
// inside one label (labels::smooth_label_gradient).
fn label_gradient(tex: texture_3d<f32>, u: vec3<f32>, size: vec3<f32>) -> vec3<f32> {
    let k = label_corners(tex, u, size);
    let l = heaviest_label(k.ids, corner_weights(k.t));
    var g = vec3<f32>(0.0);
    for (var c = 0u; c < 8u; c = c + 1u) {
        if (k.ids[c] == l) {
            let o = vec3<bool>((c & 1u) != 0u, (c & 2u) != 0u, (c & 4u) != 0u);
            let w = select(vec3<f32>(1.0) - k.t, k.t, o);
            let sg = select(vec3<f32>(-1.0), vec3<f32>(1.0), o);
            g = g + sg * vec3<f32>(w.y * w.z, w.x * w.z, w.x * w.y);
        }
    }
    return g;
}

const MODE_DVR: u32 = 0u;
const MODE_ISO: u32 = 1u;
const MODE_MIP: u32 = 2u;

// Sample k of the grid t0 + k dt. Every kernel computes the grid's points with
// this one expression, so a march's end test (t >= t_end) and the first sample
// of the next leaf or cell (first_k_after) agree on which side of a boundary
// each sample lies.
fn grid_t(t0: f32, k: u32, dt: f32) -> f32 {
    return t0 + f32(k) * dt;
}

// DVR's adaptive step (FLAG_ADAPTIVE_STEP, Accel::adaptive_step): the
// doublings of the step for a ray of opacity `a`, one per factor of 4 its
// transmittance has fallen, at most 2 (brickray_core::
// adaptive_step_doublings); 0 without the flag. A kernel that sees the
// count change at a sample starts the new step's grid there.
fn step_doublings(a: f32) -> u32 {
    let tr = 1.0 - a;
    let j = select(select(0u, 1u, tr <= 0.25), 2u, tr <= 0.0625);
    return select(0u, j, has_flag(FLAG_ADAPTIVE_STEP));
}

// A DVR ray's sample grid under the adaptive step: it starts at `tb` and
// steps `dt`, the undoubled step doubled `j` times, its opacity corrected
// by the table's row `row` (the undoubled step's row plus `j`).
struct StepGrid {
    tb: f32,
    dt: f32,
    j: u32,
    row: f32,
}

// The grid's step and row for an undoubled step `dt0` of row `row0` (a
// leaf's level, out of core), at its doublings.
fn step_grid_set(g: ptr<function, StepGrid>, dt0: f32, row0: f32) {
    (*g).dt = dt0 * f32(1u << (*g).j);
    (*g).row = row0 + f32((*g).j) / tf_info.rows;
}

// Before the sample at t of a ray of opacity `a`: when the doublings
// change, the grid starts anew at t and true is returned (the kernel's
// sample index then restarts at 0, its sub-cell test with it).
fn step_grid_adapt(g: ptr<function, StepGrid>, a: f32, t: f32, dt0: f32, row0: f32) -> bool {
    let j = step_doublings(a);
    if (j == (*g).j) {
        return false;
    }
    (*g).j = j;
    (*g).tb = t;
    step_grid_set(g, dt0, row0);
    return true;
}

// The first index k of the sample grid at or after t: the smallest k with
// grid_t(t0, k, dt) >= t, exactly (skips land on the same grid, so empty-space
// skipping never changes which samples are taken). The quotient rounds apart
// from grid_t by up to one index: a sample within rounding of a leaf's
// boundary was in neither leaf (out of core lost it), or in both.
fn first_k_after(t: f32, t0: f32, dt: f32) -> u32 {
    let k = u32(max(ceil((t - t0) / dt), 0.0));
    let down = (k > 0u) & (grid_t(t0, max(k, 1u) - 1u, dt) >= t);
    let up = grid_t(t0, k, dt) < t;
    return select(select(k, k + 1u, up), k - 1u, down);
}

// What a ray has accumulated so far.
struct Accum {
    // Premultiplied colour.
    color: vec4<f32>,
    // Clip depth of the result (the far value until set).
    depth: f32,
    depth_set: bool,
    // MIP: running maximum and where it was first attained.
    max_v: f32,
    max_t: f32,
    // MIP: the best sample more than a step and a half from the maximum's
    // when it was taken (the runner-up, a second peak; mip_refine).
    alt_v: f32,
    alt_t: f32,
    // Iso: the bracket [hit_a, hit_b] of the first crossing, when hit.
    hit: bool,
    hit_a: f32,
    hit_b: f32,
    // Volume samples taken (march and bisection).
    samples: u32,
    // Pre-integration: t and value of the last sample composited; the value
    // one step before it, when `prev_joined` (the parabola's third point,
    // preint_front); the segment's third point as preint_front found it
    // (`seg_s0`, used when `seg_s0_set`).
    prev_t: f32,
    prev_v: f32,
    prev2_v: f32,
    prev_joined: bool,
    seg_s0: f32,
    seg_s0_set: bool,
    // Pre-integration, shaded (preint_shaded): where the segment being
    // composited starts, when joined to the sample before (else far below
    // any t), and the gradient last computed at a sample and its t.
    seg_front_t: f32,
    prev_g: vec4<f32>,
    prev_g_t: f32,
    // The length of ray (in t) whose samples composited colour, for early
    // ray termination's fill (accumulate).
    seen: f32,
}

fn accum_new() -> Accum {
    var a: Accum;
    a.color = vec4<f32>(0.0);
    a.depth = far_depth();
    a.depth_set = false;
    a.max_v = -3.0e38;
    a.max_t = 0.0;
    a.alt_v = -3.0e38;
    a.alt_t = 0.0;
    a.hit = false;
    a.hit_a = 0.0;
    a.hit_b = 0.0;
    a.samples = 0u;
    a.prev_t = -3.0e38;
    a.prev_v = 0.0;
    a.prev2_v = 0.0;
    a.prev_joined = false;
    a.seg_s0 = 0.0;
    a.seg_s0_set = false;
    a.seg_front_t = -2.0e38;
    a.prev_g = vec4<f32>(0.0);
    a.prev_g_t = -3.0e38;
    a.seen = 0.0;
    return a;
}

// Pre-integration: true when the last sample composited lies one step `dt`
// before t (the segment ending at t starts there).
fn preint_joined(acc: Accum, t: f32, dt: f32) -> bool {
    return abs(acc.prev_t - (t - dt)) <= 0.01 * dt;
}

// Pre-integration: true when the segment [t - dt, t] starts before t_min, the
// ray's start (the ray's first sample, k = 0 on the grid t_min + k dt; the
// tolerance keeps k = 1 after it whatever the rounding of t - dt). Such a
// sample composites nothing: it only records the next segment's front.
fn preint_before_start(t: f32, dt: f32, t_min: f32) -> bool {
    return t - dt < t_min - 0.01 * dt;
}

// Pre-integration: the front value of the segment [t - dt, t] ending at the
// sample of value v, and that sample recorded as the next segment's front. The
// front is the previous sample's value when it was taken one step before; else
// the segment is taken as constant (front = v, the corrected single sample).
// A ray's first sample composites no segment (`preint_before_start`). In core
// the kernel samples the front at t - dt first after skipped empty space
// (`preint_fetch`), so no constant segment remains. Out of core it does not (a
// second atlas sample in the march loop, in any form tried, crashed lavapipe's
// shader compiler): the first sample after skipped space (an empty leaf or
// sub-cell, transparent by construction) or a change of level composites a
// constant segment.
// The sample before the front, when it too lay a step before, is recorded
// as the segment's third point for its parabola (`preint_segment`).
fn preint_front(acc: ptr<function, Accum>, t: f32, dt: f32, v: f32) -> f32 {
    let joined = preint_joined(*acc, t, dt);
    let front = select(v, (*acc).prev_v, joined);
    (*acc).seg_front_t = select(-2.0e38, (*acc).prev_t, joined);
    (*acc).seg_s0 = (*acc).prev2_v;
    (*acc).seg_s0_set = joined && (*acc).prev_joined;
    (*acc).prev2_v = (*acc).prev_v;
    (*acc).prev_joined = joined;
    (*acc).prev_t = t;
    (*acc).prev_v = v;
    return front;
}

// Pre-integration: the segment from `front` to `back` in four linear pieces
// along the parabola through the sample before the front (`s0`, when
// `has_s0`; else along the straight line) and the two, each piece looked up
// as a whole step's segment over its values and shortened: opacity
// `1 - (1 - a)^(1/4)`, colour scaled with it (brickray_core::tf::
// segment_values and join_pieces, the CPU twins). A linear segment alone
// cuts every peak the samples straddle (docs/rendering-model.md,
// "Pre-integration"). The pieces are a loop's trips, not unrolled.
fn preint_segment(s0: f32, has_s0: bool, front: f32, back: f32, tf_v: f32) -> vec4<f32> {
    let bc = preint_curve(s0, has_s0, front, back);
    var out = vec4<f32>(0.0);
    var v0 = front;
    var j = 1u;
    loop {
        let v1 = preint_curve_at(front, bc, f32(j) * 0.25);
        out = out + (1.0 - out.a) * preint_quarter(v0, v1, tf_v);
        v0 = v1;
        j = j + 1u;
        if (j > 4u) { break; }
    }
    return out;
}

// The parabola of a segment (`preint_segment`) as value(x) = front + (b + c
// x) x over the segment's x in 0..1: (b, c), through the sample before the
// front (`s0`, when `has_s0`; else the straight line).
fn preint_curve(s0: f32, has_s0: bool, front: f32, back: f32) -> vec2<f32> {
    let s = select(2.0 * front - back, s0, has_s0);
    return vec2<f32>(0.5 * (back - s), 0.5 * (back - 2.0 * front + s));
}

// The parabola's value at x, clamped to 0..1.
fn preint_curve_at(front: f32, bc: vec2<f32>, x: f32) -> f32 {
    return clamp(front + (bc.x + bc.y * x) * x, 0.0, 1.0);
}

// A quarter of a segment, from value v0 to v1: the whole step's lookup
// shortened (opacity 1 - (1 - a)^(1/4), colour scaled with it), premultiplied.
fn preint_quarter(v0: f32, v1: f32, tf_v: f32) -> vec4<f32> {
    let p = tf_preint_sample(v0, v1, tf_v);
    let a = clamp(p.a, 0.0, 1.0);
    let h = 1.0 - sqrt(sqrt(1.0 - a));
    let k = select(0.0, h / a, a > 0.0);
    return vec4<f32>(k * p.rgb, h);
}

// Pre-integrated and shaded: the segment from `front` (at the sample before
// t, or `t_front` where none was joined) to `v` at t, composited piece by
// piece, each lit at its middle with the gradient interpolated between the
// segment's two samples (the front's kept from the segment before when it
// computed it there; else read at `t_front`, clamped out of core to the
// brick's entry). Four lightings from the gradients plain sampling reads: one
// lighting at the segment's middle lost up to 1 dB against plain sampling on
// the MRI; these are within 0.02 dB of it or ahead on every pareto scene
// and step, by up to 11 dB (docs/rendering-model.md, "Pre-integration").
// The CPU twin: the reference's `dvr_segments`. True when early ray
// termination ends the ray.
fn preint_shaded(acc: ptr<function, Accum>, c: Cursor, r: Ray, t: f32, t_front: f32, front: f32, v: f32, tf_v: f32, dt: f32, t_end: f32) -> bool {
    let bc = preint_curve((*acc).seg_s0, (*acc).seg_s0_set, front, v);
    let v1 = preint_curve_at(front, bc, 0.25);
    let v2 = preint_curve_at(front, bc, 0.5);
    let v3 = preint_curve_at(front, bc, 0.75);
    let v4 = preint_curve_at(front, bc, 1.0);
    let q1 = preint_quarter(front, v1, tf_v);
    let q2 = preint_quarter(v1, v2, tf_v);
    let q3 = preint_quarter(v2, v3, tf_v);
    let q4 = preint_quarter(v3, v4, tf_v);
    if (q1.a + q2.a + q3.a + q4.a <= 0.0) {
        return false;
    }
    let g1 = cursor_gradient(c, t);
    // The front's gradient: kept, or read (a loop's trip, which a SIMD group
    // whose lanes all kept it skips; see cursor_passes).
    var g0 = (*acc).prev_g;
    var i = select(0u, 1u, (*acc).prev_g_t == (*acc).seg_front_t);
    loop {
        if (i >= 1u) { break; }
        g0 = cursor_gradient(c, t_front);
        i = i + 1u;
    }
    (*acc).prev_g = g1;
    (*acc).prev_g_t = t;
    var stop = false;
    var j = 0u;
    loop {
        let q = select(select(q3, q4, j == 3u), select(q1, q2, j == 1u), j < 2u);
        // After a stop the residual is filled: the pieces left add nothing.
        if (q.a > 0.0 && !stop) {
            let s = dvr_overlaid(vec4<f32>(q.rgb / q.a, q.a), r, t);
            if (s.a > 0.0) {
                let g = mix(g0, g1, (f32(j) + 0.5) * 0.25);
                stop = dvr_accumulate(acc, r, t, s, g, vec2<f32>(0.25 * dt, t_end - t + f32(3u - j) * 0.25 * dt));
            }
        }
        j = j + 1u;
        if (j >= 4u) { break; }
    }
    return stop;
}

// Pre-integration after skipped space: records the value at t - dt (when not
// before t_min, the ray's start) as the front of the segment ending at t.
fn preint_fetch(acc: ptr<function, Accum>, c: Cursor, t: f32, dt: f32, t_min: f32) {
    if (!preint_joined(*acc, t, dt) && !preint_before_start(t, dt, t_min)) {
        (*acc).prev_t = t - dt;
        (*acc).prev_v = cursor_value(c, t - dt);
        (*acc).prev_joined = false;
        (*acc).samples = (*acc).samples + 1u;
    }
}

// Pre-integration: the ray's last piece, from its last sample (prev_t) to its
// end t_end, less than a step `dt`, taken as constant at the last sample's
// value (the layer `tf_v`'s diagonal, its opacity raised to the piece's share
// of the step) and shaded at `ts`, the last sample or the nearest point of
// the brick being read (the kernels sample nothing past their last sample).
// Without it a ray leaving the volume in material loses up to a step of it; a
// plain sample stands for the step after it. None when the ray stopped early
// (terminated: its fill already covers the rest; out of samples) or its last
// samples were skipped (transparent): then the last sample lies more than a
// step before t_end.
fn preint_tail(acc: ptr<function, Accum>, c: Cursor, r: Ray, t_end: f32, ts: f32, dt: f32, tf_v: f32) {
    let len = t_end - (*acc).prev_t;
    let stopped = ERT && (*acc).color.a >= frame.ert_threshold;
    if (!(len > 0.0 && len <= 1.001 * dt) || stopped) {
        return;
    }
    let v = (*acc).prev_v;
    let p = tf_preint_sample(v, v, tf_v);
    if (p.a <= 0.0) {
        return;
    }
    let a = 1.0 - pow(max(1.0 - p.a, 0.0), min(len / dt, 1.0));
    _ = dvr_composite(acc, c, r, (*acc).prev_t, ts, vec4<f32>(p.rgb / p.a, a), vec2<f32>(len, 0.0));
}

// Blinn-Phong with a headlight (two-sided), clamped to 0..1. `g.xyz` is the
// world-space gradient direction, `g.w` its magnitude in normalized value per
// finest voxel (below 1e-6 the sample is left unshaded).
fn shade(c: vec3<f32>, g: vec4<f32>, dir: vec3<f32>) -> vec3<f32> {
    if (g.w < 1e-6) {
        return c;
    }
    let n = normalize(g.xyz);
    let ndl = abs(dot(n, -dir));
    let spec = frame.specular * pow(ndl, frame.shininess);
    return clamp(c * (frame.ambient + frame.diffuse * ndl) + vec3<f32>(spec), vec3<f32>(0.0), vec3<f32>(1.0));
}

// DVR: composites the sample of value `v` at `t` front to back, its opacity
// corrected to the step by the corrected table's row `tf_v` (see tf_row); with
// PREINT the pre-integrated segment from value `front` to `v` instead, in
// pieces along a parabola (`preint_segment`; shaded, piece by piece:
// `preint_shaded`, `ts` the segment's start, where its front gradient may
// be read: the kernels pass t - dt, clamped out of core to the brick's
// entry). True when early ray termination ends the ray.
fn dvr_sample(acc: ptr<function, Accum>, c: Cursor, r: Ray, t: f32, ts: f32, front: f32, v: f32, tf_v: f32, dt: f32, t_end: f32) -> bool {
    // A label map over the image (overlay.wgsl) colours or masks the sample
    // before shading; it never raises the opacity, so a transparent sample
    // stays skipped.
    var s: vec4<f32>;
    if (PREINT) {
        if (SHADE) {
            return preint_shaded(acc, c, r, t, ts, front, v, tf_v, dt, t_end);
        }
        let p = preint_segment((*acc).seg_s0, (*acc).seg_s0_set, front, v, tf_v);
        if (p.a <= 0.0) {
            return false;
        }
        s = vec4<f32>(p.rgb / p.a, p.a);
        return dvr_composite(acc, c, r, t, ts, s, vec2<f32>(dt, t_end - t));
    } else {
        if (SPREAD) {
            s = tf_spread_sample(v, cursor_spread(c, t), tf_v);
        } else {
            s = tf_sample(v, tf_v);
        }
        if (s.a <= 0.0) {
            return false;
        }
    }
    return dvr_composite(acc, c, r, t, ts, s, vec2<f32>(dt, t_end - t - dt));
}

// DVR: composites the straight colour and opacity `s` of the sample at `t`
// (the label overlay and the depth are taken there), shaded at `ts` with
// PREINT (the tail's constant piece) and at `t` without. True when early ray
// termination ends the ray.
fn dvr_composite(acc: ptr<function, Accum>, c: Cursor, r: Ray, t: f32, ts: f32, s_in: vec4<f32>, span: vec2<f32>) -> bool {
    let s = dvr_overlaid(s_in, r, t);
    if (s.a <= 0.0) {
        return false;
    }
    var g = vec4<f32>(0.0);
    if (SHADE) {
        g = cursor_gradient(c, select(t, ts, PREINT));
    }
    return dvr_accumulate(acc, r, t, s, g, span);
}

// The straight colour and opacity `s` at `t` under the label overlay
// (overlay.wgsl; none: `s`). It never raises the opacity.
fn dvr_overlaid(s: vec4<f32>, r: Ray, t: f32) -> vec4<f32> {
    if (OVERLAY != 0u) {
        return overlay_apply(s, r.tex_origin + t * r.tex_dir);
    }
    return s;
}

// DVR: composites the straight colour and opacity `s` at `t`, lit with the
// gradient `g` when SHADE, front to back; sets the depth where the opacity
// first reaches depth_opacity. True when early ray termination ends the ray.
fn dvr_accumulate(acc: ptr<function, Accum>, r: Ray, t: f32, s: vec4<f32>, g: vec4<f32>, span: vec2<f32>) -> bool {
    let a = s.a;
    var rgb = s.rgb;
    if (SHADE) {
        rgb = shade(rgb, g, r.dir);
    }
    return accumulate(acc, r, t, vec4<f32>(a * rgb, a), span);
}

// DVR, every kernel: composites the premultiplied colour `p` (opacity p.a) of
// a piece of ray at `t` front to back and sets the depth where the opacity
// first reaches depth_opacity. `span`: the piece's length and the ray's
// length after it (to the kernels' t1), in t. True when early ray termination
// ends the ray; the light the ray would still gather (its remaining
// transmittance, at most 1 - ert_threshold) is then filled with the stopping
// sample's colour in the share that the ray's mean extinction so far (over
// the pieces that composited colour, `seen`) takes over the rest of the ray:
// 1 - (1 - opacity)^(rest / seen) (ert_fill). The material it stops in is
// taken to continue to the ray's end, as dense as what the ray has crossed.
// A stopped ray has its depth where it stops at the latest, so a threshold
// below depth_opacity keeps it. Against the exact integral (`preint`'s
// scenes, 64 px, ERT 0.99) and the unterminated image (the stability
// suite's case 7) this is ahead of dropping the residual, of filling it
// whole and of continuing the stopping sample's own opacity; the error
// never exceeds the residual (docs/rendering-model.md, "Accelerations").
fn accumulate(acc: ptr<function, Accum>, r: Ray, t: f32, p: vec4<f32>, span: vec2<f32>) -> bool {
    let acc_a = (*acc).color.a;
    var c = vec4<f32>((*acc).color.rgb + (1.0 - acc_a) * p.rgb, acc_a + (1.0 - acc_a) * p.a);
    let stop = ERT && c.a >= frame.ert_threshold;
    if (ERT) {
        (*acc).seen = (*acc).seen + span.x;
        let share = ert_fill(c.a, span.y / max((*acc).seen, 1e-30));
        let fill = select(0.0, (1.0 - c.a) * share, stop);
        c = vec4<f32>(c.rgb + fill * p.rgb / max(p.a, 1e-6), c.a + fill);
    }
    if (!(*acc).depth_set && (c.a >= frame.depth_opacity || stop)) {
        (*acc).depth = depth_at(r, t);
        (*acc).depth_set = true;
    }
    (*acc).color = c;
    return stop;
}

// The opacity of `n` pieces of opacity `a` each: 1 - (1 - a)^n (0 when
// n <= 0, 1 when a = 1).
fn ert_fill(a: f32, n: f32) -> f32 {
    return 1.0 - exp2(max(n, 0.0) * log2(max(1.0 - a, 1e-30)));
}

// Iso: records that the surface lies in [a, b] (below the isovalue at a, at or
// above at b; a == b for a capped cut). The march ends; the bracket is refined
// after the loop (`finish_ray`), where every lane of a SIMD group refines at
// once instead of each lane stalling the others inside the march.
fn iso_bracket(acc: ptr<function, Accum>, a: f32, b: f32) {
    (*acc).hit = true;
    (*acc).hit_a = a;
    (*acc).hit_b = b;
}

// Iso: bisects the bracket [a, b] (below the isovalue at a, at or above at b)
// `steps` times in cursor `c`; returns the final [a, b].
fn iso_bisect(acc: ptr<function, Accum>, c: Cursor, a_in: f32, b_in: f32, steps: u32) -> vec2<f32> {
    var a = a_in;
    var b = b_in;
    for (var i = 0u; i < steps; i = i + 1u) {
        if (b <= a) {
            break;
        }
        let m = 0.5 * (a + b);
        (*acc).samples = (*acc).samples + 1u;
        if (cursor_value(c, m) >= frame.isovalue) {
            b = m;
        } else {
            a = m;
        }
    }
    return vec2<f32>(a, b);
}

// Iso: bisects [a, b] `iso_refine_steps` times, shades at the midpoint of the
// final interval and sets the opaque result.
fn iso_hit(acc: ptr<function, Accum>, c: Cursor, r: Ray, a_in: f32, b_in: f32) {
    // The trip count involves the ray's bracket, never the uniform alone (see
    // pixel_ray in common.wgsl).
    let ab = iso_bisect(acc, c, a_in, b_in, select(0u, frame.iso_refine_steps, b_in > a_in));
    let th = 0.5 * (ab.x + ab.y);
    let base = overlay_tint(frame.iso_color, r.tex_origin + th * r.tex_dir);
    (*acc).color = vec4<f32>(shade(base, cursor_gradient(c, th), r.dir), 1.0);
    (*acc).depth = depth_at(r, th);
    (*acc).depth_set = true;
}

// MIP: takes the sample of value `v` at `t` on a grid of step `dt`, and
// keeps the runner-up: a maximum replaced by one more than a step and a half
// away, or a sample that far from the maximum above the runner-up. True when
// early ray termination ends the ray (the maximum reached 1).
fn mip_sample(acc: ptr<function, Accum>, t: f32, v: f32, dt: f32) -> bool {
    let far = t - (*acc).max_t > 1.5 * dt && (*acc).max_v > -1.0e38;
    if (v > (*acc).max_v) {
        if (far) {
            (*acc).alt_v = (*acc).max_v;
            (*acc).alt_t = (*acc).max_t;
        }
        (*acc).max_v = v;
        (*acc).max_t = t;
    } else if (far && v > (*acc).alt_v) {
        (*acc).alt_v = v;
        (*acc).alt_t = t;
    }
    return ERT && (*acc).max_v >= 1.0;
}

// MIP: refines a peak between the samples. The largest value near the
// sample `p` (t, value) lies within a step `dt` of it; two rounds probe half
// a step and then a quarter step either side of the best value so far,
// within [lo, hi] (the ray's extent; out of core, the ray's extent in the
// leaf that holds the sample, widened by the refinement's reach, three
// quarters of a step, where the brick's apron holds it, so both backends
// probe alike), and the running maximum takes
// the best. Real samples: it never overshoots the data. The kernels refine
// the maximum and the runner-up (mip_sample), eight samples a ray: two
// peaks whose samples lie within the texture filter's rounding of each other
// are both refined in either backend. The CPU twin: the reference's `mip`.
// The multi-channel kernels refine each visible channel's two peaks the same
// way (channel_mip_sample, channel_mip_refine in channel_class.wgsl).
fn mip_refine(acc: ptr<function, Accum>, c: Cursor, p: vec2<f32>, lo: f32, hi: f32, dt: f32) {
    var bt = p.x;
    var bv = p.y;
    var h = 0.5 * dt;
    var i = 0u;
    loop {
        if (i >= 2u) { break; }
        let ta = clamp(bt - h, lo, hi);
        let tb = clamp(bt + h, lo, hi);
        let va = cursor_value(c, ta);
        let vb = cursor_value(c, tb);
        (*acc).samples = (*acc).samples + 2u;
        if (va > bv) {
            bv = va;
            bt = ta;
        }
        if (vb > bv) {
            bv = vb;
            bt = tb;
        }
        h = 0.5 * h;
        i = i + 1u;
    }
    if (bv > (*acc).max_v) {
        (*acc).max_v = bv;
        (*acc).max_t = bt;
    }
}

// MIP: maps the maximum through the TF (premultiplied, no step correction),
// or, with an intensity window (frame.color_map != MAP_TF), through the window
// and colour map, opaque.
fn mip_finish(acc: ptr<function, Accum>, r: Ray) {
    if ((*acc).max_v > -1.0e38) {
        let s = tf_lookup((*acc).max_v);
        let u = r.tex_origin + (*acc).max_t * r.tex_dir;
        let windowed = vec4<f32>(overlay_tint(intensity_color((*acc).max_v), u), 1.0);
        let tinted = overlay_tint(s.rgb, u);
        (*acc).color = select(vec4<f32>(tinted * s.a, s.a), windowed, frame.color_map != MAP_TF);
        (*acc).depth = depth_at(r, (*acc).max_t);
        (*acc).depth_set = true;
    }
}

// Ends a ray: an isosurface hit is refined and shaded at `c` (the cursor it was
// bracketed in), MIP finalised, the pixel stored.
fn finish_ray(px: vec2<u32>, acc: ptr<function, Accum>, c: Cursor, r: Ray, host: f32) {
    if (MODE == MODE_ISO && (*acc).hit) {
        iso_hit(acc, c, r, (*acc).hit_a, (*acc).hit_b);
    }
    if (MODE == MODE_MIP) {
        mip_finish(acc, r);
    }
    store_pixel(px, (*acc).color, (*acc).depth, host, (*acc).samples);
}
