// Multi-channel out-of-core ray caster (compute; its slice view:
// channel_slice.wgsl), after common.wgsl,
// modes.wgsl, overlay.wgsl, predict.wgsl (their shared functions and
// switches), brickray-index's octree_traversal.wgsl, ooc_volume.wgsl,
// channel_class.wgsl and feedback.wgsl. A brick holds every channel of its
// voxels packed in one texel (RG or RGBA), so each sample is one filtered
// atlas read for all channels, composited as in core (channels.wgsl;
// brickray_core::channels): DVR mixes the visible channels' absorbers at
// each sample with the TF tables corrected to the leaf level's step; MIP
// classifies and mixes each channel's maximum; iso stops at the first
// crossing of any visible channel's own isovalue. The walk over the index,
// the per-level steps, fades, borrowed octants and the usage feedback are
// ooc.wgsl's. Empty-space skipping: a sub-cell is skipped when it is empty in
// every visible channel (its own range per channel).

// Group 2 beyond ooc_volume.wgsl's: the channels' classification
// (`OocChannelParams` in backend/ooc_channels.rs; a test checks the offsets).
struct OocChannelParams {
    // normalized = texel * scale + offset, per channel.
    scale: vec4<f32>,
    offset: vec4<f32>,
    // Entries of each channel's TF (as floats) and the first in chan_tf.
    tf_count: vec4<f32>,
    tf_offset: vec4<u32>,
    // Each channel's opacity prefix sums in chan_tf (tf_count + 1 rows, the
    // sum in x): prefix[i] = entries j < i with alpha > 0.
    prefix_offset: vec4<u32>,
    // Rows of each channel's corrected table (one per level step), and the
    // tables' columns.
    table_rows: f32,
    table_width: f32,
    pad0: f32,
    pad1: f32,
}

@group(2) @binding(8) var<uniform> chan: OocChannelParams;
// The channels' corrected tables stacked: channel c's row r is row
// c * table_rows + r.
@group(2) @binding(9) var chan_table: texture_2d<f32>;
// The classification header (channel_class.wgsl), the TF entries, then the
// prefix sums.
@group(2) @binding(10) var<storage, read> chan_tf: array<vec4<f32>>;

// Every channel's normalized value at atlas point uv (one filtered read).
fn atlas_values(uv: vec3<f32>) -> vec4<f32> {
    return textureSampleLevel(atlas_tex, atlas_sampler, uv, 0.0) * chan.scale + chan.offset;
}

// Every channel's value at t, mixed with the fade fallback's as ooc.wgsl's
// cursor_value mixes one.
fn cursor_values(c: Cursor, t: f32) -> vec4<f32> {
    let passes = cursor_passes(c);
    var uv = c.ua + c.ud * t;
    var w = 1.0 - c.b.fb_w;
    var v = vec4<f32>(0.0);
    var i = 0u;
    loop {
        v = v + w * atlas_values(uv);
        i = i + 1u;
        if (i >= passes) { break; }
        uv = c.fa + c.fd * t;
        w = c.b.fb_w;
    }
    return v;
}

// The cursor's channel (iso bisection).
fn cursor_value(c: Cursor, t: f32) -> f32 {
    return lane_of(cursor_values(c, t), c.c);
}

// Every channel's gradient at t (central differences of one voxel of the
// brick's level, per finest voxel, mixed while fading) as world direction
// and magnitude.
fn cursor_gradients(c: Cursor, t: f32) -> Quad {
    let passes = cursor_passes(c);
    var uv = c.ua + c.ud * t;
    var f3 = c.b.f3;
    var w = 1.0 - c.b.fb_w;
    let e = 1.0 / ooc.atlas_size;
    var dx = vec4<f32>(0.0);
    var dy = vec4<f32>(0.0);
    var dz = vec4<f32>(0.0);
    var i = 0u;
    loop {
        dx = dx + w * (atlas_values(uv + vec3<f32>(e.x, 0.0, 0.0)) - atlas_values(uv - vec3<f32>(e.x, 0.0, 0.0))) * 0.5 / f3.x;
        dy = dy + w * (atlas_values(uv + vec3<f32>(0.0, e.y, 0.0)) - atlas_values(uv - vec3<f32>(0.0, e.y, 0.0))) * 0.5 / f3.y;
        dz = dz + w * (atlas_values(uv + vec3<f32>(0.0, 0.0, e.z)) - atlas_values(uv - vec3<f32>(0.0, 0.0, e.z))) * 0.5 / f3.z;
        i = i + 1u;
        if (i >= passes) { break; }
        uv = c.fa + c.fd * t;
        f3 = c.b.fb_f3;
        w = c.b.fb_w;
    }
    return Quad(
        ooc_world_gradient(vec3<f32>(dx.x, dy.x, dz.x)),
        ooc_world_gradient(vec3<f32>(dx.y, dy.y, dz.y)),
        ooc_world_gradient(vec3<f32>(dx.z, dy.z, dz.z)),
        ooc_world_gradient(vec3<f32>(dx.w, dy.w, dz.w)),
    );
}

fn ooc_world_gradient(g: vec3<f32>) -> vec4<f32> {
    return vec4<f32>(frame.normal_mat * (g * ooc.dims), length(g));
}

// The cursor's channel's gradient (iso shading).
// No spreads in this kernel (modes.wgsl's SPREAD is off): every sample is
// classified as the TF of its value.
fn cursor_spread(c: Cursor, t: f32) -> f32 {
    return 0.0;
}

fn cursor_gradient(c: Cursor, t: f32) -> vec4<f32> {
    return quad_get(cursor_gradients(c, t), c.c);
}

// 1 when channel c's TF is transparent over the normalized range r (its
// prefix sums; tf_transparent of common.wgsl per channel), else 0.
fn channel_transparent(c: u32, r: vec2<f32>) -> f32 {
    let n1 = lane_of(chan.tf_count, c) - 1.0;
    let i0 = u32(floor(clamp(r.x, 0.0, 1.0) * n1));
    let i1 = min(u32(ceil(clamp(r.y, 0.0, 1.0) * n1)), u32(n1));
    let p = u32(lane_of(vec4<f32>(chan.prefix_offset), c));
    return f32(chan_tf[p + i1 + 1u].x == chan_tf[p + min(i0, i1)].x);
}

// True when sub-cell j of brick b is empty in every visible channel: DVR
// transparent, iso below the isovalue, MIP not above the running maximum mx
// (the CPU twin: brickray_core::channels::node_visible).
fn channel_cell_skips(b: Brick, j: vec3<u32>, mx: vec4<f32>, vis: vec4<f32>, iso: vec4<f32>) -> bool {
    // A fading leaf's values lie between its brick's and its fallback's
    // (ooc_volume.wgsl, sub_cell_range).
    let at = sub_cell_index(b.slot, j) * CHANNELS;
    let fat = fade_sub_cell_index(b, j) * CHANNELS;
    let r0 = range_union(sub_cell_entry(at), sub_cell_entry(fat));
    var hi = vec4<f32>(r0.y, -3.0e38, -3.0e38, -3.0e38);
    var opaque = vec4<f32>(1.0 - channel_transparent(0u, r0), 0.0, 0.0, 0.0);
    if (CHANNELS > 1u) {
        let r = range_union(sub_cell_entry(at + 1u), sub_cell_entry(fat + 1u));
        hi.y = r.y;
        opaque.y = 1.0 - channel_transparent(1u, r);
    }
    if (CHANNELS > 2u) {
        let r = range_union(sub_cell_entry(at + 2u), sub_cell_entry(fat + 2u));
        hi.z = r.y;
        opaque.z = 1.0 - channel_transparent(2u, r);
    }
    if (CHANNELS > 3u) {
        let r = range_union(sub_cell_entry(at + 3u), sub_cell_entry(fat + 3u));
        hi.w = r.y;
        opaque.w = 1.0 - channel_transparent(3u, r);
    }
    var shows = opaque;
    if (MODE == MODE_MIP) {
        shows = vec4<f32>(1.0) - step(hi, mx);
    } else if (MODE == MODE_ISO) {
        shows = step(iso, hi);
    }
    return dot(shows * vis, vec4<f32>(1.0)) <= 0.0;
}

// leaf_span's test (ooc_volume.wgsl): a sub-cell no visible channel draws
// from (channel_cell_skips; MIP by the maxima `mx`).
fn leaf_cell_skips(b: Brick, j: vec3<u32>, mx: vec4<f32>) -> bool {
    return channel_cell_skips(b, j, mx, chan_visible(), chan_iso());
}

// DVR: the mixed, shaded sample of values v at t (texture point u) of the
// cursor's brick, its tables' row `row`, premultiplied.
fn ooc_channel_dvr_sample(cur: Cursor, v: vec4<f32>, u: vec3<f32>, r: Ray, t: f32, row: f32, vis: vec4<f32>) -> vec4<f32> {
    var q = channel_tf4(v, row);
    var a = quad_alpha(q) * vis;
    channel_overlay(&q, &a, u);
    if (all(a <= vec4<f32>(0.0))) {
        return vec4<f32>(0.0);
    }
    if (SHADE) {
        q = channel_shade(q, cursor_gradients(cur, t), r.dir);
    }
    return channel_mix(q, a);
}

// MIP: channel c's peak p (t, value) refined in the brick of the leaf that
// holds it (peak_leaf_span, ooc_volume.wgsl); returns the best (t, value),
// p itself where the cut holds no data there.
fn channel_peak_refine(acc: ptr<function, Accum>, cur: ptr<function, Cursor>, c: u32, p: vec2<f32>, t0: f32, t1: f32, dt: f32) -> vec2<f32> {
    let s = peak_leaf_span(cur, p.x, t0, t1, dt);
    if (s.z <= 0.0) {
        return p;
    }
    return channel_mip_refine(acc, *cur, c, p, s.x, s.y, s.z);
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let px = tile_pixel(wg.xy, li);
    if (px.x >= frame.viewport_size.x || px.y >= frame.viewport_size.y) {
        return;
    }
    let start = start_ray(px);
    let r = start.r;
    let t0 = start.t0;
    let t1 = start.t1;
    var acc = accum_new();
    var cur: Cursor;
    cur.c = 0u;
    // The channels' visibility and isovalues, once per ray.
    let vis = chan_visible();
    let iso4 = chan_iso();
    // MIP: each channel's running maximum and where it was first attained,
    // and its runner-up (channel_mip_sample).
    var mx = vec4<f32>(-3.0e38);
    var mt = vec4<f32>(0.0);
    var ax = vec4<f32>(-3.0e38);
    var at = vec4<f32>(0.0);
    feedback_stop(px, far_depth());
    if (t1 > t0) {
        let oo = r.tex_origin * ooc.octree_scale;
        let od = r.tex_dir * ooc.octree_scale;
        let inv_od = safe_inverse(od);
        cur.oo = oo;
        cur.od = od;
        let dt = frame.dt;
        // A bracket reaches back at most the brick's apron (ooc.wgsl).
        let apron_t = finest_voxel_t() * f32(ooc.apron);
        var budget = frame.max_samples;
        var grid_f = 0.0;
        var k = 0u;
        var t_last = t0;
        var st = oct_begin_inside(oo, od, t0, t1, frame.max_leaves, ooc.splits.xy);
        var dtl = dt;
        // The sample grid (StepGrid: the leaf level's step, doubled by
        // DVR's adaptive step; ooc.wgsl).
        var grid = StepGrid(t0, dt, 0u, 0.0);
        var done = false;
        loop {
            var found = false;
            loop {
                if (!oct_next_leaf(&st)) { break; }
                if (st.hit.tag == OCT_TAG_DATA) {
                    feedback_reached(st.hit.data);
                    found = true;
                    break;
                }
            }
            if (!found) { break; }
            cursor_enter(&cur, brick_of(st.hit.leaf, st.hit.data));
            dtl = dt * cur.b.f;
            step_grid_set(&grid, dtl, cur.b.tf_v);
            if (cur.b.f != grid_f) {
                grid_f = cur.b.f;
                k = first_k_after(max(st.hit.t_enter, t_last), grid.tb, grid.dt);
            }
            k = max(k, first_k_after(st.hit.t_enter, grid.tb, grid.dt));
            let t_end = min(st.hit.t_exit, t1);
            let t_in = max(st.hit.t_enter, t0);
            let trans_in = select(1.0, 1.0 - acc.color.a, MODE == MODE_DVR);
            // Skipping: samples only from the first of the leaf's sub-cells
            // a visible channel can draw from to the last (leaf_span,
            // ooc_volume.wgsl; MIP by the maxima at the leaf's entry).
            var t_samples = t_end;
            if (ESS) {
                let span = leaf_span(cur.b, oo, od, inv_od, t_in, t_end, mx);
                k = max(k, first_k_after(span.x, grid.tb, grid.dt));
                t_samples = min(t_end, span.y);
            }
            loop {
                let t = grid_t(grid.tb, k, grid.dt);
                if (t >= t_samples) { break; }
                if (budget == 0u) { done = true; break; }
                budget = budget - 1u;
                if (MODE == MODE_DVR && step_grid_adapt(&grid, acc.color.a, t, dtl, cur.b.tf_v)) {
                    k = 0u;
                }
                let v = cursor_values(cur, t);
                acc.samples = acc.samples + 1u;
                if (MODE == MODE_DVR) {
                    // The row of the grid's step (the leaf level's, doubled)
                    // in each channel's tables.
                    let row = grid.row * tf_info.rows - 0.5;
                    let p = ooc_channel_dvr_sample(cur, v, tex_at(r, t), r, t, row, vis);
                    if (p.a > 0.0) {
                        if (accumulate(&acc, r, t, p, vec2<f32>(grid.dt, t1 - t - grid.dt))) { done = true; break; }
                    }
                } else if (MODE == MODE_ISO) {
                    let c = channel_inside(v, vis, iso4);
                    if (c < CHANNELS) {
                        cur.c = c;
                        // The first sample inside is a capped cut; else the
                        // bracket reaches back one step, within the apron.
                        var a = t;
                        if (t > t0) {
                            a = max(max(t_last, st.hit.t_enter - apron_t * cur.b.f), t - dtl);
                        }
                        iso_bracket(&acc, a, t);
                        done = true;
                        break;
                    }
                } else {
                    channel_mip_sample(&mx, &mt, &ax, &at, v, t, dtl);
                    if (ERT && all(max(vec4<f32>(1.0) - mx, vec4<f32>(0.0)) * vis <= vec4<f32>(0.0))) { done = true; break; }
                }
                t_last = t;
                k = k + 1u;
            }
            // (A ray whose samples ended before the leaf's exit passed the
            // rest.)
            let t_out = select(clamp(grid_t(grid.tb, k, grid.dt), t_in, t_end), t_end, !done);
            let trans_out = select(1.0, 1.0 - acc.color.a, MODE == MODE_DVR);
            feedback_seen(cur.b.usage, t_in, t_out, trans_in, trans_out, finest_voxel_t() * cur.b.usage_f);
            if (done) { break; }
        }
        let t_stop = grid_t(grid.tb, k, grid.dt);
        feedback_stop(px, depth_at(r, select(t1, t_stop, feedback_terminated(acc))));
        // MIP: each visible channel's peaks refined in the bricks that hold
        // them.
        if (MODE == MODE_MIP) {
            channel_mip_refine_all(&acc, &cur, &mx, &mt, ax, at, vis, t0, t1, dt);
        }
    }
    if (MODE == MODE_ISO && acc.hit) {
        channel_iso_finish(&acc, cur, r, iso4);
    }
    if (MODE == MODE_MIP) {
        channel_mip_finish(&acc, r, mx, mt, vis);
    }
    store_pixel(px, acc.color, acc.depth, start.host, acc.samples);
}

// Slice views (channel_slice.wgsl): every channel at the point located in
// the frame's cut (slice_cursor, ooc_volume.wgsl); nothing is occluded.
fn channel_slice_begin(px: vec2<u32>) {
    feedback_stop(px, far_depth());
}

fn channel_slice_sample(u: vec3<f32>, dir: vec3<f32>, last: ptr<function, u32>) -> ChannelSliceSample {
    var c: Cursor;
    if (!slice_cursor(u, dir, last, &c)) {
        return ChannelSliceSample(vec4<f32>(0.0), false);
    }
    return ChannelSliceSample(cursor_values(c, 0.0), true);
}
