// Out-of-core single-pass ray caster (Gobbetti et al. 2008, sect. 5.2), compute.
// Prefixed at load time by common.wgsl and octree_traversal.wgsl. Each ray walks
// the octree-with-ropes index over the current cut front to back (stackless),
// skips empty leaves, and samples data leaves from the brick atlas with a step
// matched to the leaf's level (opacity corrected to that step). Every loop is
// bounded. See docs/rendering-model.md and docs/index-format.md.

struct SlotInfo {
    // xyz: atlas texel offset of the slot, w: unused.
    offset: vec4<f32>,
    // x: normalized min, y: normalized max of the brick.
    range: vec4<f32>,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var atlas_tex: texture_3d<f32>;
@group(0) @binding(2) var atlas_sampler: sampler;
@group(0) @binding(3) var<storage, read> tf: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> tf_prefix: array<u32>;
@group(0) @binding(5) var<storage, read> slots: array<SlotInfo>;
@group(0) @binding(6) var host_depth: texture_depth_2d;
@group(0) @binding(7) var out_color: texture_storage_2d<rgba16float, write>;
@group(0) @binding(8) var out_depth: texture_storage_2d<r32float, write>;
@group(0) @binding(9) var out_samples: texture_storage_2d<r32uint, write>;
@group(0) @binding(10) var<storage, read> index_words: array<u32>;
// Normalized min/max of each brick's sub-cells (`params.bricks.w`^3 per slot, x
// fastest), for empty-space skipping inside a brick.
@group(0) @binding(11) var<storage, read> sub_cells: array<vec2<f32>>;

// A data leaf's brick: atlas texture coordinate = uv0 + o * kuv for octree
// point o (texel centres at +0.5 are folded in).
struct Brick {
    uv0: vec3<f32>,
    kuv: vec3<f32>,
    // Finest voxels per voxel of this level (2^(finest - level)).
    f: f32,
    slot: u32,
    box_min: vec3<f32>,
    box_size: f32,
}

fn brick_of(leaf: OctBox, slot: u32) -> Brick {
    var b: Brick;
    let k = f32(params.bricks.x) / leaf.box_size;
    let inv_atlas = 1.0 / params.atlas.xyz;
    b.kuv = k * inv_atlas;
    b.uv0 = (slots[slot].offset.xyz + f32(params.bricks.y) - leaf.box_min * k) * inv_atlas;
    b.f = oct_exp2_pos(params.limits.z - leaf.level);
    b.slot = slot;
    b.box_min = leaf.box_min;
    b.box_size = leaf.box_size;
    return b;
}

fn atlas_value(uv: vec3<f32>) -> f32 {
    return textureSampleLevel(atlas_tex, atlas_sampler, uv, 0.0).r * params.value_map.x + params.value_map.y;
}

fn brick_value(b: Brick, o: vec3<f32>) -> f32 {
    return atlas_value(b.uv0 + o * b.kuv);
}

// World gradient direction and magnitude (normalized value per finest voxel), by
// central differences of one voxel of the brick's level.
fn brick_gradient(b: Brick, o: vec3<f32>) -> vec4<f32> {
    let uv = b.uv0 + o * b.kuv;
    let e = 1.0 / params.atlas.xyz;
    let gx = (atlas_value(uv + vec3<f32>(e.x, 0.0, 0.0)) - atlas_value(uv - vec3<f32>(e.x, 0.0, 0.0))) * 0.5;
    let gy = (atlas_value(uv + vec3<f32>(0.0, e.y, 0.0)) - atlas_value(uv - vec3<f32>(0.0, e.y, 0.0))) * 0.5;
    let gz = (atlas_value(uv + vec3<f32>(0.0, 0.0, e.z)) - atlas_value(uv - vec3<f32>(0.0, 0.0, e.z))) * 0.5;
    let g = vec3<f32>(gx, gy, gz) / b.f;
    let gw = (params.normal_mat * vec4<f32>(g * params.dims.xyz, 0.0)).xyz;
    return vec4<f32>(gw, length(g));
}

// The sub-cell of the brick holding octree point o (integer coordinates).
fn sub_cell_of(b: Brick, o: vec3<f32>) -> vec3<u32> {
    let n = f32(params.bricks.w);
    return vec3<u32>(clamp(floor((o - b.box_min) * (n / b.box_size)), vec3<f32>(0.0), vec3<f32>(n - 1.0)));
}

fn sub_cell_range(b: Brick, j: vec3<u32>) -> vec2<f32> {
    let n = params.bricks.w;
    return sub_cells[((b.slot * n + j.z) * n + j.y) * n + j.x];
}

// t at which the ray leaves sub-cell j of brick b.
fn sub_cell_exit(b: Brick, j: vec3<u32>, oo: vec3<f32>, od: vec3<f32>) -> f32 {
    let side = b.box_size / f32(params.bricks.w);
    let lo = b.box_min + vec3<f32>(j) * side;
    return box_exit(oo, od, lo, lo + side);
}

// t at which the ray o(t) = oo + od t leaves the box [lo, hi].
fn box_exit(oo: vec3<f32>, od: vec3<f32>, lo: vec3<f32>, hi: vec3<f32>) -> f32 {
    let far = select(lo, hi, od > vec3<f32>(0.0));
    let tf = select(vec3<f32>(3.0e38), (far - oo) / od, od != vec3<f32>(0.0));
    return min(tf.x, min(tf.y, tf.z));
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= params.size.x || gid.y >= params.size.y) {
        return;
    }
    let px = gid.xy;
    let mode = MODE;
    let start = start_ray(px);
    let r = start.r;
    let host = start.host;
    let t0 = start.t0;
    let t1 = start.t1;
    var color = vec4<f32>(0.0);
    var depth = host;
    var samples = 0u;
    if (t1 > t0) {
        let oo = r.tex_origin * params.octree.xyz;
        let od = r.tex_dir * params.octree.xyz;
        let dt = params.value_map.w;
        let ess = ESS;
        let ert = ERT;
        let shading = SHADE;
        let ert_thr = params.misc.x;
        let step_factor = params.misc.z;
        let iso = params.iso.x;
        var budget = params.limits.x;
        // Sampling state carried across leaves: the grid (level, spacing, index).
        var grid_f = 0.0;
        var k = 0u;
        var t_last = t0;
        var depth_set = false;
        var m = -3.0e38;
        var tm = t0;
        var st = oct_begin(oo, od, t0, t1, params.limits.y);
        // One flat loop: each iteration either moves to the next leaf or takes
        // (or skips) one sample. Rays of a SIMD group/warp then diverge only per
        // iteration, not per nested leaf loop.
        var have_leaf = false;
        var b: Brick;
        var dtl = dt;
        loop {
            if (!have_leaf) {
                // Walk to the next data leaf (skipping empty ones, and for MIP
                // bricks below the running maximum) in one go.
                var found = false;
                loop {
                    if (!oct_next_leaf(&st)) { break; }
                    if (st.hit.tag == OCT_TAG_DATA && !(mode == MODE_MIP && ess && slots[st.hit.data].range.y <= m)) {
                        found = true;
                        break;
                    }
                }
                if (!found) { break; }
                let slot = st.hit.data;
                b = brick_of(st.hit.leaf, slot);
                dtl = dt * b.f;
                // Snap to this level's sample grid at or after max(t_enter, last sample).
                if (b.f != grid_f) {
                    grid_f = b.f;
                    k = u32(max(ceil((max(st.hit.t_enter, t_last) - t0) / dtl), 0.0));
                }
                k = max(k, u32(max(ceil((st.hit.t_enter - t0) / dtl), 0.0)));
                have_leaf = true;
            }
            let t = t0 + f32(k) * dtl;
            if (t >= st.hit.t_exit || t >= t1) {
                have_leaf = false;
                continue;
            }
            if (budget == 0u) { break; }
            budget = budget - 1u;
            let o = oo + od * t;
            if (ess) {
                // Skip the rest of a sub-cell that cannot contribute: transparent
                // (DVR), or below the running maximum (MIP). The sample grid is
                // unchanged, so skipping never changes the image.
                let j = sub_cell_of(b, o);
                let range = sub_cell_range(b, j);
                let skip = (mode == MODE_DVR && tf_transparent(range)) || (mode == MODE_MIP && range.y <= m);
                if (skip) {
                    let te = min(sub_cell_exit(b, j, oo, od), st.hit.t_exit);
                    k = max(k + 1u, u32(max(ceil((te - t0) / dtl), 0.0)));
                    continue;
                }
            }
            let v = brick_value(b, o);
            samples = samples + 1u;
            if (mode == MODE_DVR) {
                let s = tf_lookup(v);
                if (s.a > 0.0) {
                    let a = 1.0 - pow(1.0 - s.a, step_factor * b.f);
                    var c = s.rgb;
                    if (shading) {
                        c = shade(c, brick_gradient(b, o), r.dir);
                    }
                    color = vec4<f32>(color.rgb + (1.0 - color.a) * a * c, color.a + (1.0 - color.a) * a);
                    if (!depth_set && color.a >= params.misc.y) {
                        depth = depth_at(r, t);
                        depth_set = true;
                    }
                    if (ert && color.a >= ert_thr) { break; }
                }
            } else if (mode == MODE_ISO) {
                if (v >= iso) {
                    // Bracket [previous sample, t], clipped to one voxel of this
                    // level before the leaf (the brick's apron covers it).
                    var a = t;
                    var bb = t;
                    if (t > t0) {
                        a = max(t_last, max(st.hit.t_enter - dtl, t - dtl));
                        if (t_last >= t) { a = t; }
                    }
                    for (var i = 0u; i < params.size.w; i = i + 1u) {
                        if (bb <= a) { break; }
                        let mid = 0.5 * (a + bb);
                        samples = samples + 1u;
                        if (brick_value(b, oo + od * mid) >= iso) {
                            bb = mid;
                        } else {
                            a = mid;
                        }
                    }
                    let th = 0.5 * (a + bb);
                    color = vec4<f32>(shade(params.iso.yzw, brick_gradient(b, oo + od * th), r.dir), 1.0);
                    depth = depth_at(r, th);
                    // The hit ends the ray.
                    break;
                }
                if (ess) {
                    // The whole sub-cell lies below the isovalue, like this sample.
                    let j = sub_cell_of(b, o);
                    if (sub_cell_range(b, j).y < iso) {
                        let te = min(sub_cell_exit(b, j, oo, od), st.hit.t_exit);
                        t_last = t0 + f32(max(u32(max(ceil((te - t0) / dtl), 0.0)), k + 1u) - 1u) * dtl;
                        k = max(k + 1u, u32(max(ceil((te - t0) / dtl), 0.0)));
                        continue;
                    }
                }
            } else {
                if (v > m) {
                    m = v;
                    tm = t;
                }
                if (ert && m >= 1.0) { break; }
            }
            t_last = t;
            k = k + 1u;
        }
        if (mode == MODE_MIP && m > -1.0e38) {
            let s = tf_lookup(m);
            color = vec4<f32>(s.rgb * s.a, s.a);
            depth = depth_at(r, tm);
        }
    }
    textureStore(out_color, vec2<i32>(px), color);
    textureStore(out_depth, vec2<i32>(px), vec4<f32>(min(depth, host), 0.0, 0.0, 0.0));
    textureStore(out_samples, vec2<i32>(px), vec4<u32>(samples, 0u, 0u, 0u));
}
