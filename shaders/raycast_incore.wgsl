// In-core single-pass ray caster (compute). Krueger-Westermann 2003 accelerations:
// early ray termination and empty-space skipping over a min/max macro-cell grid,
// classified per transfer function by an opacity prefix-sum table.
// Prepended at load time by common.wgsl. See docs/rendering-model.md.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var volume_tex: texture_3d<f32>;
@group(0) @binding(2) var volume_sampler: sampler;
@group(0) @binding(3) var<storage, read> tf: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> tf_prefix: array<u32>;
@group(0) @binding(5) var<storage, read> cell_ranges: array<vec2<f32>>;
@group(0) @binding(6) var host_depth: texture_depth_2d;
@group(0) @binding(7) var out_color: texture_storage_2d<rgba16float, write>;
@group(0) @binding(8) var out_depth: texture_storage_2d<r32float, write>;
// Diagnostics: volume samples taken along each ray (march and iso refinement;
// gradient taps excluded), for benchmarks.
@group(0) @binding(9) var out_samples: texture_storage_2d<r32uint, write>;

fn sample_value(u: vec3<f32>) -> f32 {
    return textureSampleLevel(volume_tex, volume_sampler, u, 0.0).r * params.value_map.x + params.value_map.y;
}

// World-space gradient direction (unnormalized) and the voxel-space magnitude.
fn gradient(u: vec3<f32>) -> vec4<f32> {
    let e = 1.0 / params.dims.xyz;
    let gx = (sample_value(u + vec3<f32>(e.x, 0.0, 0.0)) - sample_value(u - vec3<f32>(e.x, 0.0, 0.0))) * 0.5;
    let gy = (sample_value(u + vec3<f32>(0.0, e.y, 0.0)) - sample_value(u - vec3<f32>(0.0, e.y, 0.0))) * 0.5;
    let gz = (sample_value(u + vec3<f32>(0.0, 0.0, e.z)) - sample_value(u - vec3<f32>(0.0, 0.0, e.z))) * 0.5;
    let g = vec3<f32>(gx, gy, gz);
    let gw = (params.normal_mat * vec4<f32>(g * params.dims.xyz, 0.0)).xyz;
    return vec4<f32>(gw, length(g));
}

fn cell_of(u: vec3<f32>) -> vec3<u32> {
    let c = floor(u * params.dims.xyz / f32(params.cells.w));
    return vec3<u32>(clamp(c, vec3<f32>(0.0), vec3<f32>(params.cells.xyz) - 1.0));
}

fn cell_range(c: vec3<u32>) -> vec2<f32> {
    return cell_ranges[(c.z * params.cells.y + c.y) * params.cells.x + c.x];
}

// t at which the ray leaves macro cell c.
fn cell_exit(r: RaySetup, c: vec3<u32>) -> f32 {
    let s = f32(params.cells.w) / params.dims.xyz;
    let lo = vec3<f32>(c) * s;
    let hi = lo + s;
    let tb = clip_box(r, lo, hi);
    return tb.y;
}

// First sample index at or after t.
fn first_k_after(t: f32, t0: f32, dt: f32) -> u32 {
    return u32(max(ceil((t - t0) / dt), 0.0));
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
        let dt = params.value_map.w;
        let n = min(u32(ceil((t1 - t0) / dt)), params.limits.x);
        let ess = ESS;
        let ert = ERT;
        let shading = SHADE;
        let ert_thr = params.misc.x;
        let step_factor = params.misc.z;
        var k = 0u;
        if (mode == MODE_DVR) {
            var depth_set = false;
            loop {
                if (k >= n) { break; }
                let t = t0 + f32(k) * dt;
                if (t >= t1) { break; }
                let u = tex_at(r, t);
                if (ess) {
                    let c = cell_of(u);
                    if (tf_transparent(cell_range(c))) {
                        k = max(k + 1u, first_k_after(cell_exit(r, c), t0, dt));
                        continue;
                    }
                }
                let v = sample_value(u);
                samples = samples + 1u;
                let s = tf_lookup(v);
                if (s.a > 0.0) {
                    let a = 1.0 - pow(1.0 - s.a, step_factor);
                    var c = s.rgb;
                    if (shading) {
                        c = shade(c, gradient(u), r.dir);
                    }
                    color = vec4<f32>(color.rgb + (1.0 - color.a) * a * c, color.a + (1.0 - color.a) * a);
                    if (!depth_set && color.a >= params.misc.y) {
                        depth = depth_at(r, t);
                        depth_set = true;
                    }
                    if (ert && color.a >= ert_thr) { break; }
                }
                k = k + 1u;
            }
        } else if (mode == MODE_ISO) {
            let iso = params.iso.x;
            var hit = false;
            var t_lo = t0;
            var t_hi = t0;
            loop {
                if (k >= n) { break; }
                let t = t0 + f32(k) * dt;
                if (t >= t1) { break; }
                let u = tex_at(r, t);
                let inside = sample_value(u) >= iso;
                samples = samples + 1u;
                if (inside) {
                    hit = true;
                    if (k == 0u) {
                        t_lo = t;
                        t_hi = t;
                    } else {
                        t_lo = t - dt;
                        t_hi = t;
                    }
                    break;
                }
                if (ess) {
                    let c = cell_of(u);
                    let cr = cell_range(c);
                    if (iso < cr.x || iso > cr.y) {
                        // The whole cell lies on this sample's side of the isovalue.
                        k = max(k + 1u, first_k_after(cell_exit(r, c), t0, dt));
                        continue;
                    }
                }
                k = k + 1u;
            }
            if (hit) {
                var a = t_lo;
                var b = t_hi;
                if (b > a) {
                    for (var i = 0u; i < params.size.w; i = i + 1u) {
                        let m = 0.5 * (a + b);
                        samples = samples + 1u;
                        if (sample_value(tex_at(r, m)) >= iso) {
                            b = m;
                        } else {
                            a = m;
                        }
                    }
                }
                let th = 0.5 * (a + b);
                let c = shade(params.iso.yzw, gradient(tex_at(r, th)), r.dir);
                color = vec4<f32>(c, 1.0);
                depth = depth_at(r, th);
            }
        } else {
            var m = -3.0e38;
            var tm = t0;
            loop {
                if (k >= n) { break; }
                let t = t0 + f32(k) * dt;
                if (t >= t1) { break; }
                let u = tex_at(r, t);
                if (ess) {
                    let c = cell_of(u);
                    if (cell_range(c).y <= m) {
                        k = max(k + 1u, first_k_after(cell_exit(r, c), t0, dt));
                        continue;
                    }
                }
                let v = sample_value(u);
                samples = samples + 1u;
                if (v > m) {
                    m = v;
                    tm = t;
                }
                if (ert && m >= 1.0) { break; }
                k = k + 1u;
            }
            if (m > -1.0e38) {
                let s = tf_lookup(m);
                color = vec4<f32>(s.rgb * s.a, s.a);
                depth = depth_at(r, tm);
            }
        }
    }
    textureStore(out_color, vec2<i32>(px), color);
    textureStore(out_depth, vec2<i32>(px), vec4<f32>(min(depth, host), 0.0, 0.0, 0.0));
    textureStore(out_samples, vec2<i32>(px), vec4<u32>(samples, 0u, 0u, 0u));
}
