// The classification of 1 to 4 intensity channels, shared by the
// multi-channel kernels (in core: channels.wgsl; out of core:
// ooc_channels.wgsl; brickray_core::channels). Each kernel declares in its
// group 2 `chan` (a uniform with the fields tf_count, tf_offset, table_rows
// and table_width), `chan_table` (the channels' corrected tables stacked)
// and `chan_tf` (the classification header, then the TF entries), and its
// `Cursor` (with the channel `c` it bisects and shades), `cursor_value` and
// `cursor_gradient`.

// Channels drawn (1..4). The code works lane-wise over vec4s, one lane per
// channel, with no loop over channels and no dynamic index into local
// values; visibility masks by multiplication (1 or 0 per lane, read from
// storage: see chan_tf). Lanes past the channels are never visible.
override CHANNELS: u32 = 1u;

// The largest opacity whose extinction the mixture takes
// (brickray_core::channels::OPAQUE_ALPHA).
const OPAQUE_ALPHA: f32 = 1.0 - 1.0 / 1048576.0;

// Rows of chan_tf before the TF entries (`CLASS_HEADER` in
// backend/channels.rs).
const CLASS_HEADER: u32 = 7u;

// Each channel's slice gain (brickray_core::channels::slice_gain).
fn chan_slice_gain() -> vec4<f32> {
    return chan_tf[6];
}

// 1 in the lanes of the visible channels, 0 elsewhere.
fn chan_visible() -> vec4<f32> {
    return chan_tf[0];
}

// Each channel's normalized isovalue.
fn chan_iso() -> vec4<f32> {
    return chan_tf[1];
}

// Channel c's isosurface colour.
fn chan_iso_color(c: u32) -> vec3<f32> {
    return chan_tf[2u + min(c, 3u)].rgb;
}

// 1 in lane c, 0 elsewhere.
fn lane(c: u32) -> vec4<f32> {
    return vec4<f32>(f32(c == 0u), f32(c == 1u), f32(c == 2u), f32(c == 3u));
}

// Lane c of x.
fn lane_of(x: vec4<f32>, c: u32) -> f32 {
    return dot(x, lane(c));
}

// Four RGBA values, one per channel (lanes past the channels zero).
struct Quad {
    q0: vec4<f32>,
    q1: vec4<f32>,
    q2: vec4<f32>,
    q3: vec4<f32>,
}

fn quad_get(q: Quad, c: u32) -> vec4<f32> {
    return select(select(select(q.q0, q.q1, c == 1u), q.q2, c == 2u), q.q3, c == 3u);
}

fn quad_alpha(q: Quad) -> vec4<f32> {
    return vec4<f32>(q.q0.a, q.q1.a, q.q2.a, q.q3.a);
}

// Channel c's TF at v with its opacity corrected to row r's step: one
// filtered read of its corrected table.
fn channel_tf_sample(c: u32, v: f32, r: f32) -> vec4<f32> {
    let w = chan.table_width;
    let x = (clamp(v, 0.0, 1.0) * (w - 1.0) + 0.5) / w;
    let y = (f32(c) * chan.table_rows + r + 0.5) / (f32(CHANNELS) * chan.table_rows);
    return textureSampleLevel(chan_table, tf_sampler, vec2<f32>(x, y), 0.0);
}

// Every channel's corrected TF sample at its value in v.
fn channel_tf4(v: vec4<f32>, r: f32) -> Quad {
    var q = Quad(channel_tf_sample(0u, v.x, r), vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0));
    if (CHANNELS > 1u) {
        q.q1 = channel_tf_sample(1u, v.y, r);
    }
    if (CHANNELS > 2u) {
        q.q2 = channel_tf_sample(2u, v.z, r);
    }
    if (CHANNELS > 3u) {
        q.q3 = channel_tf_sample(3u, v.w, r);
    }
    return q;
}

// Channel c's TF at v, exact and uncorrected (MIP's maxima): tf_lookup of
// its entries.
fn channel_tf_lookup(c: u32, v: f32) -> vec4<f32> {
    let n = lane_of(chan.tf_count, c);
    let x = clamp(v, 0.0, 1.0) * (n - 1.0);
    let i = min(u32(floor(x)), u32(n) - 1u);
    let j = min(i + 1u, u32(n) - 1u);
    let f = x - f32(i);
    let o = u32(lane_of(vec4<f32>(chan.tf_offset), c));
    return mix(chan_tf[o + i], chan_tf[o + j], f);
}

// Every channel's exact TF at its value in v.
fn channel_tf_lookup4(v: vec4<f32>) -> Quad {
    var q = Quad(channel_tf_lookup(0u, v.x), vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0));
    if (CHANNELS > 1u) {
        q.q1 = channel_tf_lookup(1u, v.y);
    }
    if (CHANNELS > 2u) {
        q.q2 = channel_tf_lookup(2u, v.z);
    }
    if (CHANNELS > 3u) {
        q.q3 = channel_tf_lookup(3u, v.w);
    }
    return q;
}

// The mixture of the channels' straight colours `q` with opacities `a`
// (brickray_core::channels::mix), premultiplied.
fn channel_mix(q: Quad, a: vec4<f32>) -> vec4<f32> {
    let tau = -log(vec4<f32>(1.0) - min(a, vec4<f32>(OPAQUE_ALPHA)));
    let total = tau.x + tau.y + tau.z + tau.w;
    if (total <= 0.0) {
        return vec4<f32>(0.0);
    }
    let keep = (1.0 - a.x) * (1.0 - a.y) * (1.0 - a.z) * (1.0 - a.w);
    let rgb = q.q0.rgb * tau.x + q.q1.rgb * tau.y + q.q2.rgb * tau.z + q.q3.rgb * tau.w;
    let alpha = 1.0 - keep;
    return vec4<f32>(rgb * (alpha / total), alpha);
}

// The overlay (overlay.wgsl) over every channel's classified sample at
// texture point u: colours or masks each as it does one channel's.
fn channel_overlay(q: ptr<function, Quad>, a: ptr<function, vec4<f32>>, u: vec3<f32>) {
    if (OVERLAY != 0u) {
        let l = overlay_label(u);
        if (OVERLAY == OVERLAY_MASK) {
            *a = *a * select(1.0 - overlay.opacity, 1.0, l.a > 0.0);
        } else {
            let w = l.a * overlay.opacity;
            (*q).q0 = vec4<f32>(mix((*q).q0.rgb, l.rgb, w), (*q).q0.a);
            (*q).q1 = vec4<f32>(mix((*q).q1.rgb, l.rgb, w), (*q).q1.a);
            (*q).q2 = vec4<f32>(mix((*q).q2.rgb, l.rgb, w), (*q).q2.a);
            (*q).q3 = vec4<f32>(mix((*q).q3.rgb, l.rgb, w), (*q).q3.a);
        }
    }
}

// Each channel's colour shaded by its gradient g (world direction and
// magnitude, as shade() takes it), for the ray direction dir.
fn channel_shade(q: Quad, g: Quad, dir: vec3<f32>) -> Quad {
    return Quad(
        vec4<f32>(shade(q.q0.rgb, g.q0, dir), 0.0),
        vec4<f32>(shade(q.q1.rgb, g.q1, dir), 0.0),
        vec4<f32>(shade(q.q2.rgb, g.q2, dir), 0.0),
        vec4<f32>(shade(q.q3.rgb, g.q3, dir), 0.0),
    );
}

// Iso: the first visible channel at or above its isovalue in v, or CHANNELS.
fn channel_inside(v: vec4<f32>, vis: vec4<f32>, iso: vec4<f32>) -> u32 {
    // Above 0.25 in a visible lane at or above its isovalue (sign is 0 at
    // equality), by arithmetic: no comparison with the uniforms themselves.
    let m = vis * (sign(v - iso) * 0.5 + vec4<f32>(0.5));
    var c = CHANNELS;
    c = select(c, 3u, m.w > 0.25);
    c = select(c, 2u, m.z > 0.25);
    c = select(c, 1u, m.y > 0.25);
    c = select(c, 0u, m.x > 0.25);
    return c;
}

// Iso, both kernels: the hit bracketed in acc bisected on the crossing
// channel (the cursor's; its isovalue in iso4) with the kernel's
// cursor_value, drawn in that channel's colour (tinted by a label map at
// the hit) and shaded by its gradient.
fn channel_iso_finish(acc: ptr<function, Accum>, cur: Cursor, r: Ray, iso4: vec4<f32>) {
    var a = (*acc).hit_a;
    var b = (*acc).hit_b;
    let steps = select(0u, frame.iso_refine_steps, b > a);
    let iso = lane_of(iso4, cur.c);
    for (var i = 0u; i < steps; i = i + 1u) {
        let m = 0.5 * (a + b);
        (*acc).samples = (*acc).samples + 1u;
        if (cursor_value(cur, m) >= iso) {
            b = m;
        } else {
            a = m;
        }
    }
    let th = 0.5 * (a + b);
    let base = overlay_tint(chan_iso_color(cur.c), tex_at(r, th));
    (*acc).color = vec4<f32>(shade(base, cursor_gradient(cur, th), r.dir), 1.0);
    (*acc).depth = depth_at(r, th);
    (*acc).depth_set = true;
}

// MIP, every channel as mip_sample keeps one (modes.wgsl): the running
// maximum mx (first attained at mt) and the runner-up ax (at at), the best
// sample more than a step and a half from the maximum when it was taken.
fn channel_mip_sample(mx: ptr<function, vec4<f32>>, mt: ptr<function, vec4<f32>>, ax: ptr<function, vec4<f32>>, at: ptr<function, vec4<f32>>, v: vec4<f32>, t: f32, dt: f32) {
    let far = (vec4<f32>(t) - *mt > vec4<f32>(1.5 * dt)) & (*mx > vec4<f32>(-1.0e38));
    let better = v > *mx;
    let demoted = better & far;
    let second = !better & far & (v > *ax);
    *ax = select(select(*ax, v, second), *mx, demoted);
    *at = select(select(*at, vec4<f32>(t), second), *mt, demoted);
    *mx = select(*mx, v, better);
    *mt = select(*mt, vec4<f32>(t), better);
}

// MIP: channel c's peak p (t, value) refined in cursor cur as mip_refine
// refines a single channel's (modes.wgsl), within [lo, hi] at step dt;
// returns the best (t, value) of p and what the probes found, and counts
// the probes in acc.
fn channel_mip_refine(acc: ptr<function, Accum>, cur: Cursor, c: u32, p: vec2<f32>, lo: f32, hi: f32, dt: f32) -> vec2<f32> {
    var k = cur;
    k.c = c;
    var pk = accum_new();
    pk.max_t = p.x;
    pk.max_v = p.y;
    mip_refine(&pk, k, p, lo, hi, dt);
    (*acc).samples = (*acc).samples + pk.samples;
    return vec2<f32>(pk.max_t, pk.max_v);
}

// MIP: lane c of x set to v.
fn with_lane(x: vec4<f32>, c: u32, v: f32) -> vec4<f32> {
    return select(x, vec4<f32>(v), lane(c) > vec4<f32>(0.0));
}

// MIP, both kernels: each visible channel's maximum (mx, at mt) and
// runner-up (ax, at at) refined between samples within [t0, t1] at step dt
// (channel_peak_refine: in core along the ray, out of core in the brick of
// the leaf that holds each peak); mx and mt take the best of each channel.
fn channel_mip_refine_all(acc: ptr<function, Accum>, cur: ptr<function, Cursor>, mx: ptr<function, vec4<f32>>, mt: ptr<function, vec4<f32>>, ax: vec4<f32>, at: vec4<f32>, vis: vec4<f32>, t0: f32, t1: f32, dt: f32) {
    var c = 0u;
    loop {
        if (c >= CHANNELS) { break; }
        let m = lane_of(*mx, c);
        if (lane_of(vis, c) > 0.0 && m > -1.0e38) {
            var b = channel_peak_refine(acc, cur, c, vec2<f32>(lane_of(*mt, c), m), t0, t1, dt);
            let a = lane_of(ax, c);
            if (a > -1.0e38) {
                let q = channel_peak_refine(acc, cur, c, vec2<f32>(lane_of(at, c), a), t0, t1, dt);
                if (q.y > b.y) {
                    b = q;
                }
            }
            *mx = with_lane(*mx, c, b.y);
            *mt = with_lane(*mt, c, b.x);
        }
        c = c + 1u;
    }
}

// MIP, both kernels: every channel's maximum mx (first attained at mt)
// classified by its TF (uncorrected), each tinted by a label map at its
// maximum, and mixed over the visible channels (vis: 1 or 0 per lane;
// hidden ones mix nothing and place no depth); the depth is the nearest
// visible maximum's. Nothing when no sample was taken.
fn channel_mip_finish(acc: ptr<function, Accum>, r: Ray, mx: vec4<f32>, mt: vec4<f32>, vis: vec4<f32>) {
    if (!any(mx > vec4<f32>(-1.0e38))) {
        return;
    }
    var q = channel_tf_lookup4(mx);
    q.q0 = vec4<f32>(overlay_tint(q.q0.rgb, tex_at(r, mt.x)), q.q0.a);
    q.q1 = vec4<f32>(overlay_tint(q.q1.rgb, tex_at(r, mt.y)), q.q1.a);
    q.q2 = vec4<f32>(overlay_tint(q.q2.rgb, tex_at(r, mt.z)), q.q2.a);
    q.q3 = vec4<f32>(overlay_tint(q.q3.rgb, tex_at(r, mt.w)), q.q3.a);
    (*acc).color = channel_mix(q, quad_alpha(q) * vis);
    let tn = mt + vec4<f32>(3.0e38) * (vec4<f32>(1.0) - vis);
    let t_near = min(min(tn.x, tn.y), min(tn.z, tn.w));
    let shown = t_near < 1.0e38;
    (*acc).depth = select((*acc).depth, depth_at(r, t_near), shown);
    (*acc).depth_set = shown;
}

