// Multi-channel in-core ray caster (compute), after common.wgsl, modes.wgsl,
// overlay.wgsl and predict.wgsl (for their shared functions and switches; a
// label map over the channels is drawn, the prediction buffer is not). 1 to 4
// intensity channels packed in one texel, each classified by its own
// transfer function and composited in one ray (brickray_core::channels;
// docs/rendering-model.md, "Channels"):
//   DVR: each sample mixes the visible channels' classified samples
//        (channel_mix: opacity 1 - prod(1 - a_c), colour the
//        extinction-weighted mean) and composites the mixture;
//   MIP: each channel's maximum, classified, mixed;
//   iso: the first crossing of any visible channel's own isovalue, in that
//        channel's colour, shaded by its gradient.
// Empty-space skipping: a macro cell is skipped when it is empty in every
// visible channel (DVR, iso: distances computed on the CPU; MIP: per channel
// against its running maximum).
// The classification: channel_class.wgsl.

// Group 2: the multi-channel volume and its classification
// (`ChannelParams` in backend/channels.rs; a test checks the offsets).
struct ChannelParams {
    // Voxel dimensions.
    dims: vec3<f32>,
    // Channels (CHANNELS).
    channels: u32,
    // Macro cells per axis.
    cells: vec3<u32>,
    // Macro-cell side in voxels.
    cell_size: u32,
    // normalized = texel * scale + offset, per channel.
    scale: vec4<f32>,
    offset: vec4<f32>,
    // Entries of each channel's TF (as floats) and the first in chan_tf.
    tf_count: vec4<f32>,
    tf_offset: vec4<u32>,
    // Rows of each channel's corrected table, and the tables' columns.
    table_rows: f32,
    table_width: f32,
    pad0: f32,
    pad1: f32,
}

@group(2) @binding(0) var<uniform> chan: ChannelParams;
@group(2) @binding(1) var volume_tex: texture_3d<f32>;
@group(2) @binding(2) var volume_sampler: sampler;
// Normalized min/max of every macro cell and channel (cell * CHANNELS + c).
@group(2) @binding(3) var<storage, read> cell_ranges: array<vec2<f32>>;
// Per macro cell: the Chebyshev distance in cells to the nearest cell that a
// visible channel can contribute in (DVR: through its TF; iso: at or above
// its isovalue), 0 for those.
@group(2) @binding(4) var<storage, read> cell_skip: array<u32>;
// The channels' corrected tables stacked: channel c's row r is row
// c * table_rows + r (read through group 1's linear sampler).
@group(2) @binding(5) var chan_table: texture_2d<f32>;
// The channels' classification: CLASS_HEADER rows (visibility: 1 or 0 per
// lane; isovalues; each channel's isosurface colour; slice gains), then
// their TF entries, concatenated (channel c's from tf_offset[c]). Lavapipe (22.x) inlines
// uniform values that steer branches and crashed compiling this kernel when
// the visibility and isovalues were uniforms: read from storage they are
// never inlined.
@group(2) @binding(6) var<storage, read> chan_tf: array<vec4<f32>>;

// The normalized value of every channel at texture point u (filtered).
fn channel_values(u: vec3<f32>) -> vec4<f32> {
    return textureSampleLevel(volume_tex, volume_sampler, u, 0.0) * chan.scale + chan.offset;
}

// A voxel-space gradient as the world direction and its magnitude.
fn world_gradient(g: vec3<f32>) -> vec4<f32> {
    return vec4<f32>(frame.normal_mat * (g * chan.dims), length(g));
}

// The world-space gradient direction and voxel-space magnitude of every
// channel at u (gradient() of incore.wgsl, four channels per fetch).
fn channel_gradients(u: vec3<f32>) -> Quad {
    let e = 1.0 / chan.dims;
    let dx = (channel_values(u + vec3<f32>(e.x, 0.0, 0.0)) - channel_values(u - vec3<f32>(e.x, 0.0, 0.0))) * 0.5;
    let dy = (channel_values(u + vec3<f32>(0.0, e.y, 0.0)) - channel_values(u - vec3<f32>(0.0, e.y, 0.0))) * 0.5;
    let dz = (channel_values(u + vec3<f32>(0.0, 0.0, e.z)) - channel_values(u - vec3<f32>(0.0, 0.0, e.z))) * 0.5;
    return Quad(
        world_gradient(vec3<f32>(dx.x, dy.x, dz.x)),
        world_gradient(vec3<f32>(dx.y, dy.y, dz.y)),
        world_gradient(vec3<f32>(dx.z, dy.z, dz.z)),
        world_gradient(vec3<f32>(dx.w, dy.w, dz.w)),
    );
}

// DVR: the mixed, shaded sample of values v at u, premultiplied.
// `vis`: chan_visible(), read once per ray.
fn channel_dvr_sample(v: vec4<f32>, u: vec3<f32>, r: Ray, row: f32, vis: vec4<f32>) -> vec4<f32> {
    var q = channel_tf4(v, row);
    var a = quad_alpha(q) * vis;
    channel_overlay(&q, &a, u);
    if (all(a <= vec4<f32>(0.0))) {
        return vec4<f32>(0.0);
    }
    if (SHADE) {
        q = channel_shade(q, channel_gradients(u), r.dir);
    }
    return channel_mix(q, a);
}

// In this kernel a cursor samples one channel (iso bisection and shading).
struct Cursor {
    r: Ray,
    c: u32,
}

fn cursor_value(cur: Cursor, t: f32) -> f32 {
    return lane_of(channel_values(tex_at(cur.r, t)), cur.c);
}

// No spreads in this kernel (modes.wgsl's SPREAD is off): every sample is
// classified as the TF of its value.
fn cursor_spread(cur: Cursor, t: f32) -> f32 {
    return 0.0;
}

fn cursor_gradient(cur: Cursor, t: f32) -> vec4<f32> {
    return quad_get(channel_gradients(tex_at(cur.r, t)), cur.c);
}

fn channel_cell_of(u: vec3<f32>) -> vec3<u32> {
    let c = floor(u * chan.dims / f32(chan.cell_size));
    return vec3<u32>(clamp(c, vec3<f32>(0.0), vec3<f32>(chan.cells) - 1.0));
}

fn channel_cell_index(c: vec3<u32>) -> u32 {
    return (c.z * chan.cells.y + c.y) * chan.cells.x + c.x;
}

fn channel_cell_exit(r: Ray, inv_dir: vec3<f32>, c: vec3<u32>, reach: u32) -> f32 {
    let s = f32(chan.cell_size) / chan.dims;
    let lo = (vec3<f32>(c) - f32(reach - 1u)) * s;
    let hi = (vec3<f32>(c) + f32(reach)) * s;
    return box_exit(r.tex_origin, r.tex_dir, inv_dir, lo, hi);
}

// MIP: true when no visible channel's range in the cell exceeds its running
// maximum mx.
fn channel_mip_skips(cell: u32, mx: vec4<f32>, vis: vec4<f32>) -> bool {
    let at = cell * CHANNELS;
    var hi = vec4<f32>(-3.0e38);
    hi.x = cell_ranges[at].y;
    if (CHANNELS > 1u) {
        hi.y = cell_ranges[at + 1u].y;
    }
    if (CHANNELS > 2u) {
        hi.z = cell_ranges[at + 2u].y;
    }
    if (CHANNELS > 3u) {
        hi.w = cell_ranges[at + 3u].y;
    }
    return all(max(hi - mx, vec4<f32>(0.0)) * vis <= vec4<f32>(0.0));
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
    var cur = Cursor(r, 0u);
    // The channels' visibility and isovalues, once per ray.
    let vis = chan_visible();
    let iso4 = chan_iso();
    // MIP: each channel's running maximum and where it was first attained,
    // and its runner-up (channel_mip_sample).
    var mx = vec4<f32>(-3.0e38);
    var mt = vec4<f32>(0.0);
    var ax = vec4<f32>(-3.0e38);
    var at = vec4<f32>(0.0);
    if (t1 > t0) {
        let dt = frame.dt;
        let inv_dir = safe_inverse(r.tex_dir);
        let n = min(first_k_after(t1, t0, dt), frame.max_samples);
        var k = 0u;
        var k_cell = 0u;
        // The sample grid (StepGrid: DVR's adaptive step moves it, as in
        // incore.wgsl); `n` bounds the trips.
        let tf_v = tf_row(0.0);
        var grid = StepGrid(t0, dt, 0u, tf_v);
        var trips = 0u;
        loop {
            if (trips >= n) { break; }
            trips = trips + 1u;
            let t = grid_t(grid.tb, k, grid.dt);
            if (t >= t1) { break; }
            if (MODE == MODE_DVR && step_grid_adapt(&grid, acc.color.a, t, dt, tf_v)) {
                k = 0u;
                k_cell = 0u;
            }
            let u = tex_at(r, t);
            if (ESS && k >= k_cell) {
                let c = channel_cell_of(u);
                let cell = channel_cell_index(c);
                var reach = 1u;
                var skip = false;
                if (MODE == MODE_MIP) {
                    skip = channel_mip_skips(cell, mx, vis);
                } else {
                    let d = cell_skip[cell];
                    skip = d > 0u;
                    reach = max(d, 1u);
                }
                let k_exit = max(k + 1u, first_k_after(channel_cell_exit(r, inv_dir, c, reach), grid.tb, grid.dt));
                if (skip) {
                    k = k_exit;
                    continue;
                }
                k_cell = k_exit;
            }
            let v = channel_values(u);
            acc.samples = acc.samples + 1u;
            if (MODE == MODE_DVR) {
                // The row of the grid's step in each channel's tables.
                let p = channel_dvr_sample(v, u, r, grid.row * tf_info.rows - 0.5, vis);
                if (p.a > 0.0) {
                    if (accumulate(&acc, r, t, p, vec2<f32>(grid.dt, t1 - t - grid.dt))) { break; }
                }
            } else if (MODE == MODE_ISO) {
                let c = channel_inside(v, vis, iso4);
                if (c < CHANNELS) {
                    cur.c = c;
                    // The first sample inside is a capped cut.
                    iso_bracket(&acc, select(t - dt, t, k == 0u), t);
                    break;
                }
            } else {
                channel_mip_sample(&mx, &mt, &ax, &at, v, t, dt);
                if (ERT && all(max(vec4<f32>(1.0) - mx, vec4<f32>(0.0)) * vis <= vec4<f32>(0.0))) { break; }
            }
            k = k + 1u;
        }
        // MIP: each visible channel's peaks refined between samples within
        // the ray, as a single channel's (incore.wgsl).
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

// MIP: channel c's peak p (t, value) refined along the ray within [t0, t1]
// (channel_mip_refine_all); returns the best (t, value).
fn channel_peak_refine(acc: ptr<function, Accum>, cur: ptr<function, Cursor>, c: u32, p: vec2<f32>, t0: f32, t1: f32, dt: f32) -> vec2<f32> {
    return channel_mip_refine(acc, *cur, c, p, t0, t1, dt);
}

// Slice views (channel_slice.wgsl): every channel at texture point u.
fn channel_slice_begin(px: vec2<u32>) {}

fn channel_slice_sample(u: vec3<f32>, dir: vec3<f32>, last: ptr<function, u32>) -> ChannelSliceSample {
    return ChannelSliceSample(channel_values(u), true);
}
