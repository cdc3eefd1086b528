// Functions shared by brickray's ray casters. Concatenated in front of a ray-cast
// shader that declares `params` (type Params), `tf` (array<vec4<f32>>),
// `tf_prefix` (array<u32>) and `host_depth` (texture_depth_2d).
// See docs/rendering-model.md.

struct Params {
    inv_view_proj: mat4x4<f32>,
    view_proj: mat4x4<f32>,
    inv_model: mat4x4<f32>,
    // Inverse transpose of the model's 3x3 part (columns), for gradients.
    normal_mat: mat4x4<f32>,
    // xyz: voxel dims, w: world length of the smallest voxel side.
    dims: vec4<f32>,
    // x: texel-to-normalized scale, y: offset, z: TF entry count, w: world step dt.
    value_map: vec4<f32>,
    // x: isovalue, yzw: iso colour.
    iso: vec4<f32>,
    // ambient, diffuse, specular, shininess.
    shade: vec4<f32>,
    // x: ERT threshold (>1 = off), y: depth opacity, z: step_factor, w: unused.
    misc: vec4<f32>,
    // x: width, y: height, z: flags (FLAG_HOST_DEPTH), w: iso bisection steps.
    size: vec4<u32>,
    // xyz: macro cells per axis, w: cell size in voxels.
    cells: vec4<u32>,
    // x: max steps per ray, y: max leaves per ray (out of core), z: finest level
    // (out of core), w: unused.
    limits: vec4<u32>,
    // Out of core: xyz octree scale (octree coord = texture coord * scale), w: unused.
    octree: vec4<f32>,
    // Out of core: x interior voxels per brick, y apron, z stored side, w sub-cells
    // per brick axis.
    bricks: vec4<u32>,
    // Out of core: xyz atlas size in texels, w unused.
    atlas: vec4<f32>,
}

// Pipeline-overridable switches: every combination is compiled into its own
// pipeline (VolumeRenderer keys them by mode, ERT, ESS and shading), so a ray
// caster carries only the code of its mode.
override MODE: u32 = 0u;
override ERT: bool = true;
override ESS: bool = true;
override SHADE: bool = false;

const MODE_DVR: u32 = 0u;
const MODE_ISO: u32 = 1u;
const MODE_MIP: u32 = 2u;
const FLAG_HOST_DEPTH: u32 = 32u;

struct RaySetup {
    origin: vec3<f32>,
    dir: vec3<f32>,
    tex_origin: vec3<f32>,
    tex_dir: vec3<f32>,
    ndc: vec2<f32>,
}

fn unproject(ndc: vec3<f32>) -> vec3<f32> {
    let h = params.inv_view_proj * vec4<f32>(ndc, 1.0);
    return h.xyz / h.w;
}

fn ray_through_pixel(px: vec2<u32>) -> RaySetup {
    let w = f32(params.size.x);
    let h = f32(params.size.y);
    let ndc = vec2<f32>(2.0 * (f32(px.x) + 0.5) / w - 1.0, 1.0 - 2.0 * (f32(px.y) + 0.5) / h);
    let near = unproject(vec3<f32>(ndc, 0.0));
    let far = unproject(vec3<f32>(ndc, 1.0));
    let dir = normalize(far - near);
    var r: RaySetup;
    r.origin = near;
    r.dir = dir;
    r.tex_origin = (params.inv_model * vec4<f32>(near, 1.0)).xyz;
    r.tex_dir = (params.inv_model * vec4<f32>(dir, 0.0)).xyz;
    r.ndc = ndc;
    return r;
}

// Slab test against the box [lo, hi] in texture space; returns (t_enter, t_exit).
fn clip_box(r: RaySetup, lo: vec3<f32>, hi: vec3<f32>) -> vec2<f32> {
    var t0 = -3.0e38;
    var t1 = 3.0e38;
    for (var a = 0; a < 3; a = a + 1) {
        let o = r.tex_origin[a];
        let d = r.tex_dir[a];
        if (abs(d) < 1e-30) {
            if (o < lo[a] || o > hi[a]) {
                return vec2<f32>(1.0, 0.0);
            }
        } else {
            let ta = (lo[a] - o) / d;
            let tb = (hi[a] - o) / d;
            t0 = max(t0, min(ta, tb));
            t1 = min(t1, max(ta, tb));
        }
    }
    return vec2<f32>(t0, t1);
}

// A pixel's ray, the host's depth there (1 without one) and the ray's extent in
// the volume box, clipped to the host's depth.
struct RayStart {
    r: RaySetup,
    host: f32,
    t0: f32,
    t1: f32,
}

fn start_ray(px: vec2<u32>) -> RayStart {
    var s: RayStart;
    s.r = ray_through_pixel(px);
    s.host = 1.0;
    let with_host = (params.size.z & FLAG_HOST_DEPTH) != 0u;
    if (with_host) {
        s.host = textureLoad(host_depth, vec2<i32>(px), 0);
    }
    let tb = clip_box(s.r, vec3<f32>(0.0), vec3<f32>(1.0));
    s.t0 = max(tb.x, 0.0);
    s.t1 = tb.y;
    if (with_host) {
        s.t1 = min(s.t1, t_at_depth(s.r, s.host));
    }
    return s;
}

fn t_at_depth(r: RaySetup, depth: f32) -> f32 {
    let p = unproject(vec3<f32>(r.ndc, depth));
    return dot(p - r.origin, r.dir);
}

fn depth_at(r: RaySetup, t: f32) -> f32 {
    let c = params.view_proj * vec4<f32>(r.origin + r.dir * t, 1.0);
    return clamp(c.z / c.w, 0.0, 1.0);
}

fn tex_at(r: RaySetup, t: f32) -> vec3<f32> {
    return r.tex_origin + r.tex_dir * t;
}

// Linear interpolation between the two nearest TF entries (clamped to 0..1).
fn tf_lookup(v: f32) -> vec4<f32> {
    let n = params.value_map.z;
    let x = clamp(v, 0.0, 1.0) * (n - 1.0);
    let i = min(u32(floor(x)), u32(n) - 1u);
    let j = min(i + 1u, u32(n) - 1u);
    let f = x - f32(i);
    return mix(tf[i], tf[j], f);
}

// O(1): can any value in [lo, hi] be visible through the TF?
fn tf_transparent(range: vec2<f32>) -> bool {
    let n1 = params.value_map.z - 1.0;
    let i0 = u32(floor(clamp(range.x, 0.0, 1.0) * n1));
    let i1 = min(u32(ceil(clamp(range.y, 0.0, 1.0) * n1)), u32(n1));
    return tf_prefix[i1 + 1u] == tf_prefix[min(i0, i1)];
}

// Blinn-Phong with a headlight (two-sided), clamped to 0..1. `g.xyz` is the
// world-space gradient direction, `g.w` its magnitude in normalized value per
// finest voxel (below 1e-6 the sample is left unshaded).
fn shade(c: vec3<f32>, g: vec4<f32>, dir: vec3<f32>) -> vec3<f32> {
    if (g.w < 1e-6) {
        return c;
    }
    let n = normalize(g.xyz);
    let l = -dir;
    let ndl = abs(dot(n, l));
    let spec = params.shade.z * pow(ndl, params.shade.w);
    return clamp(c * (params.shade.x + params.shade.y * ndl) + vec3<f32>(spec), vec3<f32>(0.0), vec3<f32>(1.0));
}
