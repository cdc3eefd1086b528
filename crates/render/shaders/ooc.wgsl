// Out-of-core single-pass ray caster (Gobbetti et al. 2008, sect. 5.2), compute,
// after common.wgsl, modes.wgsl and brickray-index's octree_traversal.wgsl. Each
// ray walks the octree-with-ropes index over the current cut front to back
// (stackless), skips empty leaves, and samples data leaves from the brick atlas
// with a step matched to the leaf's level (opacity corrected to that step). Every
// loop is bounded. See docs/rendering-model.md and docs/index-format.md.

// Group 2 and the brick cursor: ooc_volume.wgsl.

fn atlas_value(uv: vec3<f32>) -> f32 {
    if LABELS {
        return label_texel(atlas_tex, uv, ooc.atlas_size) * ooc.value_scale + ooc.value_offset;
    }
    return textureSampleLevel(atlas_tex, atlas_sampler, uv, 0.0).r * ooc.value_scale + ooc.value_offset;
}

// Each atlas texel's spread (normalized units; R16Float at the atlas's
// slots, a 1x1x1 stand-in unless SPREAD), filtered like the value.
@group(2) @binding(11) var spread_tex: texture_3d<f32>;

// Each atlas texel's gradient (gradients.wgsl, made for each upload; a
// 1x1x1 stand-in unless the volume keeps them), read with GRADIENTS.
@group(2) @binding(12) var gradient_tex: texture_3d<f32>;

// The spread at the cursor's point, mixed like the value while fading (the
// mixture's spread is taken as the mix of the spreads). A brick of the
// finest level has none: its texels are not read (a fading one reads only
// its coarser fallback's). The reads are the trips of a loop, not the sides
// of an `if`: lavapipe runs both sides of an `if` for the whole SIMD group
// (see cursor_passes), and a group of finest bricks makes no trip.
fn cursor_spread(c: Cursor, t: f32) -> f32 {
    var s = 0.0;
    var i = select(1u, 0u, c.b.coarse);
    let end = cursor_passes(c);
    loop {
        if (i >= end) { break; }
        let own = i == 0u;
        let uv = select(c.fa + c.fd * t, c.ua + c.ud * t, own);
        let w = select(c.b.fb_w, 1.0 - c.b.fb_w, own);
        s = s + w * textureSampleLevel(spread_tex, atlas_sampler, uv, 0.0).r;
        i = i + 1u;
    }
    return s;
}

// A fading leaf mixes its value with its ancestor's at the same point, before
// classification (one transfer-function lookup; iso-surfaces and maxima move
// continuously from the old level to the new).
fn cursor_value(c: Cursor, t: f32) -> f32 {
    let passes = cursor_passes(c);
    var uv = c.ua + c.ud * t;
    var w = 1.0 - c.b.fb_w;
    var v = 0.0;
    var i = 0u;
    loop {
        v = v + w * atlas_value(uv);
        i = i + 1u;
        if (i >= passes) { break; }
        uv = c.fa + c.fd * t;
        w = c.b.fb_w;
    }
    return v;
}

// Central differences of one atlas texel at uv, per finest voxel (f3: finest
// voxels per texel, per axis), six reads or with GRADIENTS one read of the
// per-texel differences, which interpolate to the same (gradients.wgsl: the
// apron keeps every tap within the brick, so no factor at the faces); a
// smooth label map: its boundary indicator's gradient.
fn atlas_gradient(uv: vec3<f32>, f3: vec3<f32>) -> vec3<f32> {
    if (LABELS && SMOOTH_LABELS) {
        return label_gradient(atlas_tex, uv, ooc.atlas_size) / f3;
    }
    if (GRADIENTS) {
        return textureSampleLevel(gradient_tex, atlas_sampler, uv, 0.0).xyz / f3;
    }
    let e = 1.0 / ooc.atlas_size;
    let gx = (atlas_value(uv + vec3<f32>(e.x, 0.0, 0.0)) - atlas_value(uv - vec3<f32>(e.x, 0.0, 0.0))) * 0.5;
    let gy = (atlas_value(uv + vec3<f32>(0.0, e.y, 0.0)) - atlas_value(uv - vec3<f32>(0.0, e.y, 0.0))) * 0.5;
    let gz = (atlas_value(uv + vec3<f32>(0.0, 0.0, e.z)) - atlas_value(uv - vec3<f32>(0.0, 0.0, e.z))) * 0.5;
    return vec3<f32>(gx, gy, gz) / f3;
}

// World gradient direction and magnitude (normalized value per finest voxel), by
// central differences of one voxel of the brick's level (mixed like the value
// while fading).
fn cursor_gradient(c: Cursor, t: f32) -> vec4<f32> {
    let passes = cursor_passes(c);
    var uv = c.ua + c.ud * t;
    var f3 = c.b.f3;
    var w = 1.0 - c.b.fb_w;
    var g = vec3<f32>(0.0);
    var i = 0u;
    loop {
        g = g + w * atlas_gradient(uv, f3);
        i = i + 1u;
        if (i >= passes) { break; }
        uv = c.fa + c.fd * t;
        f3 = c.b.fb_f3;
        w = c.b.fb_w;
    }
    return vec4<f32>(frame.normal_mat * (g * ooc.dims), length(g));
}

// A sub-cell of brick b that no sample of the frame's mode can draw from
// (leaf_span, ooc_volume.wgsl): transparent through the TF (DVR), a maximum
// at most the running maximum `mx.x` (MIP) or below the isovalue (iso).
fn leaf_cell_skips(b: Brick, j: vec3<u32>, mx: vec4<f32>) -> bool {
    let range = sub_cell_range(b, j);
    return (MODE == MODE_DVR && tf_transparent(range))
        || (MODE == MODE_MIP && range.y <= mx.x)
        || (MODE == MODE_ISO && range.y < frame.isovalue);
}

// The iso march over the index from t_from to t_to (iso frames of the full
// traversal, and the prediction buffer's traversals, ooc_predict.wgsl). Samples
// lie on the full traversal's grid t0 + k dt f (f: the leaf level's step
// multiple; `dt` the finest level's step: frame.dt, or the prediction's sparse
// step), from its first point at or after t_from. Skips, when `ess`,
// sub-cells whose maximum lies below the isovalue (a fading leaf's bound
// both levels: sub_cell_range); every data leaf walked is counted
// as reached (ray-guided feedback). Skipping whole bricks below the isovalue
// in the walk as well made frames 10% slower on lavapipe (`raw --modes iso`,
// interleaved runs): lanes that skip a brick keep the SIMD group in the walk
// while the others wait to sample; only the probe does it.
//
// A crossing needs a value below the isovalue in front of it: `below` says
// whether that is known at t_from (the ray start, where a first sample inside
// is a capped cut; a point the guard proved). Without it a first sample inside
// ends the march without a hit (the local search lost the surface).
//
// `probe` (the first-hit guard): no sample is taken; bricks and sub-cells
// whose maximum lies below the isovalue are skipped, and the march stops at
// the first sample it would take, having proven everything before it below
// the isovalue (its range reads are counted as samples).
//
// Returns where it stopped: the upper sample of the bracket on a hit (then the
// bracket is in `acc` and its brick in `cur`), the first sample a probe would
// take, or t_to (also when the sample budget ran out).
fn ooc_iso_march(acc: ptr<function, Accum>, cur: ptr<function, Cursor>, t0: f32, t_from: f32, t_to: f32, dt: f32, ess: bool, below_in: bool, probe: bool) -> f32 {
    let oo = (*cur).oo;
    let od = (*cur).od;
    let inv_od = safe_inverse(od);
    // Each march of a ray has the budget that is left (a bound, not a cost).
    var budget = frame.max_samples - min((*acc).samples, frame.max_samples);
    // A bracket never reaches further back into the previous leaf than the
    // brick's apron (beyond it the atlas holds another brick): apron_t * f.
    let apron_t = finest_voxel_t() * f32(ooc.apron);
    var below = below_in;
    var grid_f = 0.0;
    var k = 0u;
    var t_last = t0;
    // [t_from, t_to] lies in the clip box's [t0, t1]: not clipped again (see
    // the main march).
    var st = oct_begin_inside(oo, od, t_from, t_to, frame.max_leaves, ooc.splits.xy);
    loop {
        // Walk to the next data leaf that can hold the isovalue.
        var found = false;
        loop {
            if (!oct_next_leaf(&st)) { break; }
            if (st.hit.tag == OCT_TAG_DATA) {
                feedback_reached(st.hit.data);
                if (probe) {
                    (*acc).samples = (*acc).samples + 1u;
                }
                if (!(probe && leaf_max(st.hit.data) < frame.isovalue)) {
                    found = true;
                    break;
                }
            }
            below = true;
        }
        if (!found) { break; }
        cursor_enter(cur, brick_of(st.hit.leaf, st.hit.data));
        let f = (*cur).b.f;
        let dtl = dt * f;
        if (f != grid_f) {
            grid_f = f;
            k = first_k_after(max(st.hit.t_enter, t_last), t0, dtl);
        }
        k = max(k, first_k_after(st.hit.t_enter, t0, dtl));
        let t_end = min(st.hit.t_exit, t_to);
        // The visible weight (feedback.wgsl): the length marched in the brick
        // (a probe adds none).
        let t_in = max(st.hit.t_enter, t_from);
        let t_voxel = finest_voxel_t() * (*cur).b.usage_f;
        // Skipping (and the probe): samples only from the first of the
        // leaf's sub-cells that can hold the isovalue to the last
        // (leaf_span); those before and after are below it (the bracket's
        // lower end may lie in them: the last grid point skipped).
        var t_samples = t_end;
        if (ess || probe) {
            let span = leaf_span((*cur).b, oo, od, inv_od, t_in, t_end, vec4<f32>(0.0));
            if (probe) {
                (*acc).samples = (*acc).samples + u32(span.z);
            }
            let ks = first_k_after(span.x, t0, dtl);
            if (ks > k) {
                t_last = grid_t(t0, ks - 1u, dtl);
                below = true;
                k = ks;
            }
            t_samples = min(t_end, span.y);
        }
        loop {
            let t = grid_t(t0, k, dtl);
            if (t >= t_samples) { break; }
            if (budget == 0u) {
                if (!probe) { feedback_seen((*cur).b.usage, t_in, t, 1.0, 1.0, t_voxel); }
                return t_to;
            }
            budget = budget - 1u;
            if (probe) { return t; }
            let v = cursor_value(*cur, t);
            (*acc).samples = (*acc).samples + 1u;
            if (v >= frame.isovalue) {
                feedback_seen((*cur).b.usage, t_in, t, 1.0, 1.0, t_voxel);
                if (!below && t > t0) { return t; }
                var a = t;
                if (t > t0 && t_last < t) {
                    a = max(max(t_last, st.hit.t_enter - apron_t * f), max(st.hit.t_enter - dtl, t - dtl));
                }
                iso_bracket(acc, a, t);
                return t;
            }
            below = true;
            t_last = t;
            k = k + 1u;
        }
        // The grid points after the last sub-cell that can hold the
        // isovalue, skipped.
        let ke = first_k_after(t_end, t0, dtl);
        if (ke > k) {
            t_last = grid_t(t0, ke - 1u, dtl);
            below = true;
            k = ke;
        }
        if (!probe) { feedback_seen((*cur).b.usage, t_in, t_end, 1.0, 1.0, t_voxel); }
    }
    return t_to;
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let px = tile_pixel(wg.xy, li);
    if (px.x >= frame.viewport_size.x || px.y >= frame.viewport_size.y) {
        return;
    }
    let start = start_ray(px);
    // Iso with the prediction buffer: ooc_predict.wgsl (an override: pipelines
    // without prediction compile none of it).
    if (MODE == MODE_ISO && PREDICT) {
        ooc_predict_ray(px, start);
        return;
    }
    let r = start.r;
    let t0 = start.t0;
    let t1 = start.t1;
    var acc = accum_new();
    // The brick being sampled (set at each data leaf).
    var cur: Cursor;
    feedback_stop(px, far_depth());
    if (t1 > t0) {
        let oo = r.tex_origin * ooc.octree_scale;
        let od = r.tex_dir * ooc.octree_scale;
        let inv_od = safe_inverse(od);
        cur.oo = oo;
        cur.od = od;
        // Where the ray stopped, for the occlusion feedback.
        var t_stop = t1;
        if (MODE == MODE_ISO) {
            t_stop = ooc_iso_march(&acc, &cur, t0, t0, t1, frame.dt, ESS, true, false);
        } else {
            let dt = frame.dt;
            var budget = frame.max_samples;
            // Sampling state carried across leaves: the grid (level, spacing, index).
            var grid_f = 0.0;
            var k = 0u;
            var t_last = t0;
            // [t0, t1] is the clip box's (start_ray), inside the octree cube:
            // the walk enters its first leaf at t0 and leaves its last at t1
            // exactly, so the first sample is sample 0, as in core. (Clipped
            // to the cube again, the entry through a face the volume shares
            // with the cube rounded above t0 on about one ray in eight, which
            // lost its first sample.)
            var st = oct_begin_inside(oo, od, t0, t1, frame.max_leaves, ooc.splits.xy);
            var dtl = dt;
            // The sample grid (StepGrid: the leaf level's step, doubled by
            // DVR's adaptive step).
            var grid = StepGrid(t0, dt, 0u, 0.0);
            var done = false;
            // MIP: the leaf that holds the running maximum and the weight of
            // the ray through it (feedback.wgsl: only it is counted).
            var mip_slot = 0xffffffffu;
            var mip_w = 0.0;
            // Where the cursor's leaf begins (pre-integration's last piece is
            // shaded inside it).
            var cur_in = t0;
            loop {
                // Walk to the next data leaf (skipping empty ones, and for MIP
                // bricks below the running maximum) in one go.
                var found = false;
                loop {
                    if (!oct_next_leaf(&st)) { break; }
                    if (st.hit.tag == OCT_TAG_DATA) { feedback_reached(st.hit.data); }
                    if (st.hit.tag == OCT_TAG_DATA && !(MODE == MODE_MIP && ESS && leaf_max(st.hit.data) <= acc.max_v)) {
                        found = true;
                        break;
                    }
                    // (A MIP brick skipped whole, below the running maximum,
                    // cannot hold the ray's maximum: it adds no weight.)
                }
                if (!found) { break; }
                cursor_enter(&cur, brick_of(st.hit.leaf, st.hit.data));
                cur_in = st.hit.t_enter;
                dtl = dt * cur.b.f;
                step_grid_set(&grid, dtl, cur.b.tf_v);
                if (cur.b.f != grid_f) {
                    grid_f = cur.b.f;
                    k = first_k_after(max(st.hit.t_enter, t_last), grid.tb, grid.dt);
                }
                k = max(k, first_k_after(st.hit.t_enter, grid.tb, grid.dt));
                let t_end = min(st.hit.t_exit, t1);
                // The visible weight's start (feedback.wgsl); MIP and iso rays
                // are transparent.
                let t_in = max(st.hit.t_enter, t0);
                var k_cell = 0u;
                // DVR: a leaf whose values meet no transparent TF entry has no
                // sub-cell to skip, and its samples run without tests (one
                // test of its range instead of one per sub-cell). Nor does a
                // fading leaf with SPREAD, whose widened ranges do not bound
                // a mixed sample's reach.
                let cell_tests = ESS && (MODE != MODE_DVR || !tf_opaque_throughout(leaf_range(st.hit.data)))
                    && !(SPREAD && cur.b.fb_w > 0.0);
                // Where the samples end: the leaf's exit, or without
                // pre-integration the exit of its last sub-cell that can
                // contribute (leaf_span; the samples begin at the entry of
                // the first). Pre-integrated DVR tests each sub-cell as the
                // ray enters it (below): a segment into a skipped sub-cell
                // can still contribute.
                var t_samples = t_end;
                if (cell_tests && !PREINT) {
                    let span = leaf_span(cur.b, oo, od, inv_od, t_in, t_end, vec4<f32>(acc.max_v));
                    k = max(k, first_k_after(span.x, grid.tb, grid.dt));
                    t_samples = min(t_end, span.y);
                }
                let trans_in = select(1.0, 1.0 - acc.color.a, MODE == MODE_DVR);
                // Pre-integration: as in incore.wgsl.
                var forced = false;
                // MIP: whether a sample of this leaf raised the maximum.
                var holds_max = false;
                loop {
                    let t = grid_t(grid.tb, k, grid.dt);
                    if (t >= t_samples) { break; }
                    if (budget == 0u) { done = true; break; }
                    budget = budget - 1u;
                    if (MODE == MODE_DVR && step_grid_adapt(&grid, acc.color.a, t, dtl, cur.b.tf_v)) {
                        k = 0u;
                        k_cell = 0u;
                    }
                    // A fading leaf's sub-cells bound both levels' values
                    // (sub_cell_range).
                    if (PREINT && cell_tests && k >= k_cell) {
                        let j = sub_cell_of(cur.b, oo + od * t);
                        let te = min(sub_cell_exit(cur.b, j, oo, od, inv_od), st.hit.t_exit);
                        let k_exit = max(k + 1u, first_k_after(te, grid.tb, grid.dt));
                        let skip = leaf_cell_skips(cur.b, j, vec4<f32>(acc.max_v));
                        let force = PREINT && MODE == MODE_DVR && skip && !forced && preint_joined(acc, t, grid.dt);
                        forced = force;
                        if (skip && !force) {
                            k = k_exit;
                            continue;
                        }
                        k_cell = select(k_exit, k + 1u, force);
                    }
                    let v = cursor_value(cur, t);
                    acc.samples = acc.samples + 1u;
                    if (MODE == MODE_DVR) {
                        var front = v;
                        // Pre-integration: the ray's first sample composites nothing.
                        var first = false;
                        if (PREINT) {
                            first = preint_before_start(t, dtl, t0);
                            front = preint_front(&acc, t, grid.dt, v);
                        }
                        // The segment's start, inside the brick (preint_shaded).
                        let ts = max(t - grid.dt, st.hit.t_enter);
                        if (!first && dvr_sample(&acc, cur, r, t, ts, front, v, grid.row, grid.dt, t1)) { done = true; break; }
                    } else {
                        let before = acc.max_v;
                        let stop = mip_sample(&acc, t, v, dtl);
                        holds_max = holds_max || acc.max_v > before;
                        if (stop) { done = true; break; }
                    }
                    t_last = t;
                    k = k + 1u;
                }
                // Where the ray left the brick, or stopped in it (a ray whose
                // samples ended before the leaf's exit passed the rest).
                let t_out = select(clamp(grid_t(grid.tb, k, grid.dt), t_in, t_end), t_end, !done);
                let trans_out = select(1.0, 1.0 - acc.color.a, MODE == MODE_DVR);
                if (MODE == MODE_MIP) {
                    if (holds_max) {
                        mip_slot = cur.b.usage;
                        mip_w = feedback_weight(t_in, t_out, 1.0, 1.0, finest_voxel_t() * cur.b.usage_f);
                    }
                } else {
                    feedback_seen(cur.b.usage, t_in, t_out, trans_in, trans_out, finest_voxel_t() * cur.b.usage_f);
                }
                if (done) { break; }
            }
            if (MODE == MODE_MIP && mip_slot != 0xffffffffu) {
                feedback_add(mip_slot, mip_w);
            }
            // MIP: the maximum and the runner-up refined in the bricks of
            // the leaves that hold them (peak_leaf_span, ooc_volume.wgsl).
            if (MODE == MODE_MIP && acc.max_v > -1.0e38) {
                let alt = vec2<f32>(acc.alt_t, acc.alt_v);
                var s = peak_leaf_span(&cur, acc.max_t, t0, t1, dt);
                if (s.z > 0.0) {
                    mip_refine(&acc, cur, vec2<f32>(acc.max_t, acc.max_v), s.x, s.y, s.z);
                }
                if (alt.y > -1.0e38) {
                    s = peak_leaf_span(&cur, alt.x, t0, t1, dt);
                    if (s.z > 0.0) {
                        mip_refine(&acc, cur, alt, s.x, s.y, s.z);
                    }
                }
            }
            if (PREINT && MODE == MODE_DVR) {
                preint_tail(&acc, cur, r, t1, max(acc.prev_t, cur_in), dtl, cur.b.tf_v);
            }
            t_stop = grid_t(grid.tb, k, grid.dt);
        }
        feedback_stop(px, depth_at(r, select(t1, t_stop, feedback_terminated(acc))));
    }
    finish_ray(px, &acc, cur, r, start.host);
}
