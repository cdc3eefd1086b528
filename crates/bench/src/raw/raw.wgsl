// The `raw` suite's yardstick: the least a ray caster must do per sample. The
// same rays as brickray (from the camera basis, origin on the near plane), one 3D
// texture, a transfer function read per sample, front-to-back accumulation; no
// traversal, no skipping, no early termination, no diagnostics but a per-ray
// sample count written once. Its rate (samples per second) is what the device
// allows; brickray's brute-force rate is compared with it.

// MODE: 0 DVR, 1 shaded DVR, 2 isosurface, 3 MIP.
override MODE: u32 = 0u;
// The TF read: a filtered 2D texture (one row, opacity already corrected to the
// step), or a storage buffer interpolated by hand.
override TF_TEXTURE: bool = true;

struct Raw {
    eye: vec3<f32>,
    near: f32,
    fwd: vec3<f32>,
    dt: f32,
    right: vec3<f32>,
    // 1 perspective, 0 orthographic.
    persp: f32,
    up: vec3<f32>,
    isovalue: f32,
    size: vec2<u32>,
    refine_steps: u32,
    // normalized = texel * value_scale + value_offset (as brickray maps values).
    value_scale: f32,
    // Voxel dimensions (central differences of one voxel).
    dims: vec3<f32>,
    tf_count: f32,
    value_offset: f32,
    pad0: f32,
    pad1: f32,
    pad2: f32,
}

@group(0) @binding(0) var<uniform> p: Raw;
@group(0) @binding(1) var vol: texture_3d<f32>;
@group(0) @binding(2) var lin: sampler;
@group(0) @binding(3) var tf_tex: texture_2d<f32>;
@group(0) @binding(4) var<storage, read> tf_buf: array<vec4<f32>>;
@group(0) @binding(5) var out_color: texture_storage_2d<rgba16float, write>;
@group(0) @binding(6) var<storage, read_write> counts: array<u32>;

fn value(u: vec3<f32>) -> f32 {
    return textureSampleLevel(vol, lin, u, 0.0).r * p.value_scale + p.value_offset;
}

fn tf(v: f32) -> vec4<f32> {
    if (TF_TEXTURE) {
        let x = (clamp(v, 0.0, 1.0) * (p.tf_count - 1.0) + 0.5) / p.tf_count;
        return textureSampleLevel(tf_tex, lin, vec2<f32>(x, 0.5), 0.0);
    }
    let n = p.tf_count;
    let x = clamp(v, 0.0, 1.0) * (n - 1.0);
    let i = min(u32(floor(x)), u32(n) - 1u);
    let j = min(i + 1u, u32(n) - 1u);
    return mix(tf_buf[i], tf_buf[j], x - f32(i));
}

fn shade(c: vec3<f32>, u: vec3<f32>, dir: vec3<f32>) -> vec3<f32> {
    let e = 1.0 / p.dims;
    let g = vec3<f32>(
        value(u + vec3<f32>(e.x, 0.0, 0.0)) - value(u - vec3<f32>(e.x, 0.0, 0.0)),
        value(u + vec3<f32>(0.0, e.y, 0.0)) - value(u - vec3<f32>(0.0, e.y, 0.0)),
        value(u + vec3<f32>(0.0, 0.0, e.z)) - value(u - vec3<f32>(0.0, 0.0, e.z)),
    );
    if (dot(g, g) < 1e-12) {
        return c;
    }
    let ndl = abs(dot(normalize(g * p.dims), -dir));
    return clamp(c * (0.2 + 0.8 * ndl) + vec3<f32>(0.3 * pow(ndl, 32.0)), vec3<f32>(0.0), vec3<f32>(1.0));
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    // brickray's pixel order (common.wgsl, tile_pixel): a workgroup's 8 x 8
    // pixels in Morton order.
    let gx = (li & 1u) | ((li >> 1u) & 2u) | ((li >> 2u) & 4u);
    let gy = ((li >> 1u) & 1u) | ((li >> 2u) & 2u) | ((li >> 3u) & 4u);
    let gid = wg.xy * 8u + vec2<u32>(gx, gy);
    if (gid.x >= p.size.x || gid.y >= p.size.y) {
        return;
    }
    let sz = vec2<f32>(p.size);
    let ndc = vec2<f32>(2.0 * (f32(gid.x) + 0.5) / sz.x - 1.0, 1.0 - 2.0 * (f32(gid.y) + 0.5) / sz.y);
    let lateral = ndc.x * p.right + ndc.y * p.up;
    let d = p.fwd + p.persp * lateral;
    let len = length(d);
    let dir = d / len;
    let origin = p.eye + p.fwd * p.near + lateral * select(1.0, p.near, p.persp > 0.5);
    // Slab test against the unit box.
    let inv = 1.0 / dir;
    let ta = (vec3<f32>(0.0) - origin) * inv;
    let tb = (vec3<f32>(1.0) - origin) * inv;
    let t0 = max(max(max(min(ta.x, tb.x), min(ta.y, tb.y)), min(ta.z, tb.z)), 0.0);
    let t1 = min(min(max(ta.x, tb.x), max(ta.y, tb.y)), max(ta.z, tb.z));
    var c = vec4<f32>(0.0);
    var n = 0u;
    if (t1 > t0) {
        let steps = u32(ceil((t1 - t0) / p.dt));
        var m = -1.0;
        var hit = false;
        var ha = 0.0;
        var hb = 0.0;
        for (var k = 0u; k < steps; k = k + 1u) {
            let t = t0 + f32(k) * p.dt;
            let u = origin + dir * t;
            let v = value(u);
            n = n + 1u;
            if (MODE == 2u) {
                // Bracket the first crossing; it is bisected after the loop, where
                // the lanes of a SIMD group refine together.
                if (v >= p.isovalue) {
                    hit = true;
                    ha = select(t - p.dt, t, k == 0u);
                    hb = t;
                    break;
                }
            } else if (MODE == 3u) {
                m = max(m, v);
            } else {
                let s = tf(v);
                if (s.a > 0.0) {
                    var rgb = s.rgb;
                    if (MODE == 1u) {
                        rgb = shade(rgb, u, dir);
                    }
                    c = vec4<f32>(c.rgb + (1.0 - c.a) * s.a * rgb, c.a + (1.0 - c.a) * s.a);
                }
            }
        }
        if (MODE == 2u && hit) {
            var a = ha;
            var b = hb;
            for (var i = 0u; i < p.refine_steps + n - n; i = i + 1u) {
                let mid = 0.5 * (a + b);
                n = n + 1u;
                if (value(origin + dir * mid) >= p.isovalue) { b = mid; } else { a = mid; }
            }
            let th = 0.5 * (a + b);
            c = vec4<f32>(shade(vec3<f32>(0.9, 0.8, 0.7), origin + dir * th, dir), 1.0);
        }
        if (MODE == 3u && n > 0u) {
            let s = tf(m);
            c = vec4<f32>(s.rgb * s.a, s.a);
        }
    }
    textureStore(out_color, vec2<i32>(gid.xy), c);
    counts[gid.y * p.size.x + gid.x] = n;
}
