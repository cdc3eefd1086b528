// Shared by brickray's ray-cast kernels. This file declares the two groups every
// kernel binds:
//   group 0, the frame: its uniforms, the host's depth, and the outputs
//            (owned by `frame.rs` in the render crate);
//   group 1, the transfer function (owned by `tf.rs`).
// Group 2 belongs to the volume backend and is declared by the kernel's own file
// (incore.wgsl, ooc.wgsl). See docs/rendering-model.md.

// Per-frame uniforms (`FrameUniforms` in frame.rs; a test checks the offsets).
// Rays are generated from the camera's basis, in texture space and in world
// space, computed in f64 on the CPU: accuracy does not depend on the near or far
// plane (an inverse view-projection in f32 lost 27 dB at near = 1e-3).
struct Frame {
    // The eye in texture space.
    eye_tex: vec3<f32>,
    // Near plane distance (world).
    near: f32,
    // The unit world view axis, mapped to texture space.
    fwd_tex: vec3<f32>,
    // Clip depth = depth_a + depth_b / distance (perspective) or
    // depth_a + depth_b * distance (orthographic).
    depth_a: f32,
    // NDC x = 1 half-extent (perspective: at distance 1) in texture space.
    right_tex: vec3<f32>,
    depth_b: f32,
    // NDC y = 1 half-extent in texture space.
    up_tex: vec3<f32>,
    // World sampling step.
    dt: f32,
    // The same three vectors in world space (for the headlight and distances).
    fwd_world: vec3<f32>,
    // Step as a fraction of the smallest voxel (opacity correction exponent).
    step_factor: f32,
    right_world: vec3<f32>,
    // Early ray termination opacity (> 1 when off).
    ert_threshold: f32,
    up_world: vec3<f32>,
    // Accumulated opacity at which DVR writes depth.
    depth_opacity: f32,
    iso_color: vec3<f32>,
    // Normalized isovalue.
    isovalue: f32,
    // Inverse transpose of the model's 3x3 part: texture gradients to world.
    normal_mat: mat3x3<f32>,
    // The viewport in the host's target (pixels); outputs are viewport-sized.
    viewport_origin: vec2<u32>,
    viewport_size: vec2<u32>,
    // FLAG_* bits.
    flags: u32,
    iso_refine_steps: u32,
    // Guards: samples (or skips) per ray, index leaves per ray (out of core).
    max_samples: u32,
    max_leaves: u32,
    // Blinn-Phong weights.
    ambient: f32,
    diffuse: f32,
    specular: f32,
    shininess: f32,
    // The clip box (RenderSettings::clip) in texture space; rays sample inside it.
    clip_min: vec3<f32>,
    clip_pad_a: f32,
    clip_max: vec3<f32>,
    clip_pad_b: f32,
    // The intensity window in normalized values (MIP and slice views).
    window_lo: f32,
    window_hi: f32,
    // MAP_*: the colour map (0: MIP through the transfer function).
    color_map: u32,
    // Slice views (slice.wgsl): SLAB_*, the samples across the slab and their
    // spacing in ray parameter (0 for a plane).
    slab_mode: u32,
    slab_samples: u32,
    slab_dt: f32,
    map_pad_a: f32,
    map_pad_b: f32,
}

// Colour maps of the intensity window (brickray_core::ColorMap::id).
const MAP_TF: u32 = 0u;
const MAP_GREY: u32 = 1u;
const MAP_HOT: u32 = 2u;
const MAP_VIRIDIS: u32 = 3u;

const FLAG_HOST_DEPTH: u32 = 1u;
const FLAG_PERSPECTIVE: u32 = 2u;
const FLAG_REVERSED_Z: u32 = 4u;
const FLAG_ADAPTIVE_STEP: u32 = 8u;

@group(0) @binding(0) var<uniform> frame: Frame;
// The host's opaque depth (a 1x1 far-valued texture when the host gives none).
@group(0) @binding(1) var host_depth: texture_depth_2d;
@group(0) @binding(2) var out_color: texture_storage_2d<rgba16float, write>;
@group(0) @binding(3) var out_depth: texture_storage_2d<r32float, write>;
// Diagnostics: volume samples taken along each ray (march and iso refinement;
// gradient taps excluded), for benchmarks.
@group(0) @binding(4) var out_samples: texture_storage_2d<r32uint, write>;

// Transfer-function uniforms (`TfInfo` in tf.rs).
struct TfInfo {
    // Number of entries, as a float.
    count: f32,
    // Columns and rows of the corrected table, as floats.
    width: f32,
    rows: f32,
    // Columns (and rows) of a pre-integrated table layer, as a float.
    preint_size: f32,
}

@group(1) @binding(0) var<storage, read> tf: array<vec4<f32>>;
// Texels per row of a table texture (gpu::TABLE_ROW; a test checks they
// agree): entry i of a table at texel (i % TABLE_ROW, i / TABLE_ROW), read
// with a texel fetch where a storage-buffer load whose address differs
// between lanes costs lavapipe a loop over the lanes.
const TABLE_ROW: u32 = 2048u;

fn table_texel(i: u32) -> vec2<u32> {
    return vec2<u32>(i % TABLE_ROW, i / TABLE_ROW);
}

// Opacity prefix sums (a table): entry i counts the entries j < i with
// alpha > 0.
@group(1) @binding(1) var tf_prefix_tex: texture_2d<u32>;

fn tf_prefix(i: u32) -> u32 {
    return textureLoad(tf_prefix_tex, table_texel(i), 0).r;
}
@group(1) @binding(2) var<uniform> tf_info: TfInfo;
// The corrected table (brickray_core::tf::CorrectedTable): row r holds the TF
// with its opacity corrected to step_factor * 2^r reference lengths, read with
// hardware linear filtering: no interpolation by hand and no pow per sample.
@group(1) @binding(3) var tf_table: texture_2d<f32>;
@group(1) @binding(4) var tf_sampler: sampler;
// The pre-integrated table (brickray_core::tf::PreintTable; a 1x1 stand-in
// unless the pipeline pre-integrates): layer r holds, at (front, back), the
// associated colour and opacity of a segment of step_factor * 2^r reference
// lengths whose value runs linearly from front to back.
@group(1) @binding(5) var tf_preint: texture_2d_array<f32>;
// The spread table (brickray_core::tf::SpreadTable::corrected_layers; a 1x1
// stand-in unless the pipeline classifies spreads): layer r holds, at
// (value, spread row), the TF averaged over a Gaussian of that spread, its
// opacity corrected to step_factor * 2^r reference lengths; row 0 is the
// corrected table's row r.
@group(1) @binding(6) var tf_spread: texture_2d_array<f32>;

// A ray through one pixel, parametrised by world distance t from its origin on
// the near plane.
struct Ray {
    tex_origin: vec3<f32>,
    // Texture-space displacement per unit t.
    tex_dir: vec3<f32>,
    // Unit world direction.
    dir: vec3<f32>,
    // View distance gained per unit t.
    dist_per_t: f32,
}

fn has_flag(f: u32) -> bool {
    return (frame.flags & f) != 0u;
}

// Mesa's lavapipe (22.x, what CI and users without a GPU run) recompiles a
// shader, per command buffer and without ever freeing it, for every `if` or loop
// bound that depends on uniform values alone ("inlinable uniforms"): process
// memory grew by 0.35-0.8 MB a frame. So no branch or loop bound here depends on
// `frame` alone: projection and host-depth variants are blended with `select`,
// and loop trip counts involve per-ray values. See docs/rendering-model.md.

fn pixel_ray(px: vec2<u32>) -> Ray {
    let size = vec2<f32>(frame.viewport_size);
    let ndc = vec2<f32>(2.0 * (f32(px.x) + 0.5) / size.x - 1.0, 1.0 - 2.0 * (f32(px.y) + 0.5) / size.y);
    // Perspective: rays from the eye through the image plane at distance 1,
    // origin on the near plane. Orthographic: parallel rays from the near
    // plane's rectangle.
    let persp = has_flag(FLAG_PERSPECTIVE);
    let k = select(0.0, 1.0, persp);
    let lateral_world = ndc.x * frame.right_world + ndc.y * frame.up_world;
    let lateral_tex = ndc.x * frame.right_tex + ndc.y * frame.up_tex;
    let dw = frame.fwd_world + k * lateral_world;
    let len = length(dw);
    var r: Ray;
    r.dir = dw / len;
    r.tex_dir = (frame.fwd_tex + k * lateral_tex) / len;
    r.tex_origin = frame.eye_tex + frame.fwd_tex * frame.near + lateral_tex * select(1.0, frame.near, persp);
    r.dist_per_t = 1.0 / len;
    return r;
}

fn tex_at(r: Ray, t: f32) -> vec3<f32> {
    return r.tex_origin + r.tex_dir * t;
}

// The far end of clip depth ("nothing here") and the nearer of two depths, in
// the host's convention.
fn far_depth() -> f32 {
    return select(1.0, 0.0, has_flag(FLAG_REVERSED_Z));
}

fn nearer_depth(a: f32, b: f32) -> f32 {
    return select(min(a, b), max(a, b), has_flag(FLAG_REVERSED_Z));
}

fn depth_at(r: Ray, t: f32) -> f32 {
    let d = frame.near + t * r.dist_per_t;
    // A + B / d (perspective) or A + B * d (orthographic).
    let z = frame.depth_a + frame.depth_b * select(d, 1.0 / d, has_flag(FLAG_PERSPECTIVE));
    return clamp(z, 0.0, 1.0);
}

// The ray's t at clip depth `depth` (3e38 at the far end of an infinite
// projection).
fn t_at_depth(r: Ray, depth: f32) -> f32 {
    let q = depth - frame.depth_a;
    let inv = frame.depth_b / q;
    let persp_d = select(3.0e38, inv, q != 0.0 && inv > 0.0);
    let d = select(q / frame.depth_b, persp_d, has_flag(FLAG_PERSPECTIVE));
    return (d - frame.near) / r.dist_per_t;
}

// Slab test of the ray against the texture-space box [lo, hi]: (t_enter, t_exit).
fn clip_box(r: Ray, lo: vec3<f32>, hi: vec3<f32>) -> vec2<f32> {
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

// 1 / d per component (0 where d is 0), once per ray: box exits then need no
// division per test.
fn safe_inverse(d: vec3<f32>) -> vec3<f32> {
    return select(vec3<f32>(0.0), 1.0 / d, d != vec3<f32>(0.0));
}

// t at which the ray o + d t leaves the box [lo, hi] it is inside; `inv_d` is
// safe_inverse(d).
fn box_exit(o: vec3<f32>, d: vec3<f32>, inv_d: vec3<f32>, lo: vec3<f32>, hi: vec3<f32>) -> f32 {
    let far = select(lo, hi, d > vec3<f32>(0.0));
    let t = select(vec3<f32>(3.0e38), (far - o) * inv_d, d != vec3<f32>(0.0));
    return min(t.x, min(t.y, t.z));
}

// t at which the ray o + d t enters the box [lo, hi] (from outside or on its
// face; -3e38 where no axis bounds it); `inv_d` is safe_inverse(d).
fn box_entry(o: vec3<f32>, d: vec3<f32>, inv_d: vec3<f32>, lo: vec3<f32>, hi: vec3<f32>) -> f32 {
    let near = select(hi, lo, d > vec3<f32>(0.0));
    let t = select(vec3<f32>(-3.0e38), (near - o) * inv_d, d != vec3<f32>(0.0));
    return max(t.x, max(t.y, t.z));
}

// A pixel's ray, the host's depth there (the far value without one) and the
// ray's extent in the clip box (the volume box by default), clipped to the
// host's depth.
struct RayStart {
    r: Ray,
    host: f32,
    t0: f32,
    t1: f32,
}

fn start_ray(px: vec2<u32>) -> RayStart {
    var s: RayStart;
    s.r = pixel_ray(px);
    // Loaded whatever the flag (from the 1x1 stand-in without host depth,
    // clamped into it) and selected: no branch on a uniform alone.
    let with_host = has_flag(FLAG_HOST_DEPTH);
    let at = min(px + frame.viewport_origin, textureDimensions(host_depth) - vec2<u32>(1u));
    s.host = select(far_depth(), textureLoad(host_depth, vec2<i32>(at), 0), with_host);
    let tb = clip_box(s.r, frame.clip_min, frame.clip_max);
    s.t0 = max(tb.x, 0.0);
    s.t1 = select(tb.y, min(tb.y, t_at_depth(s.r, s.host)), with_host);
    return s;
}

// A slice view's samples t_k = (k + 1/2) slab_dt along the ray of `start`
// (slice.wgsl): the first index at or after t0 and a bound from the ray's
// extent, as (k0, n) (no loop bound on a uniform alone).
fn slab_range(start: RayStart) -> vec2<u32> {
    let sdt = frame.slab_dt;
    let k0 = select(0u, u32(max(ceil(start.t0 / max(sdt, 1e-30) - 0.5), 0.0)), sdt > 0.0);
    let span = select(0.0, min((start.t1 - start.t0) / max(sdt, 1e-30), 1.0e6), sdt > 0.0 && start.t1 > start.t0);
    return vec2<u32>(k0, min(frame.slab_samples, k0 + u32(span) + 2u));
}

// The texture coordinate of the corrected table's row for a step of
// step_factor * 2^r reference lengths (hoisted out of the sample loop).
fn tf_row(r: f32) -> f32 {
    return (r + 0.5) / tf_info.rows;
}

// The TF at v (clamped to 0..1) with its opacity corrected to the step of row
// coordinate `row`: one filtered texture read.
fn tf_sample(v: f32, row: f32) -> vec4<f32> {
    let w = tf_info.width;
    let x = (clamp(v, 0.0, 1.0) * (w - 1.0) + 0.5) / w;
    return textureSampleLevel(tf_table, tf_sampler, vec2<f32>(x, row), 0.0);
}

// The largest spread (brickray_core::tf::spread::SIGMA_MAX).
const SPREAD_SIGMA_MAX: f32 = 0.5;

// The TF at v averaged over a Gaussian of spread `s` (normalized units), its
// opacity corrected to the step of row coordinate `row` (its layer:
// floor(row * rows)): one filtered read, bilinear in the value's column and
// the spread's row 31 sqrt(s / 0.5) (brickray_core::tf::spread). Row 0 of a
// layer is the corrected table's row: a spread of 0 is classified as
// without spreads, to the half-float rounding of the two tables. (Reading
// the corrected table instead where s is 0, behind a loop or an `if`, made
// frames slower on lavapipe than this one read.)
fn tf_spread_sample(v: f32, s: f32, row: f32) -> vec4<f32> {
    let w = tf_info.width;
    let rows = f32(textureDimensions(tf_spread).y);
    let y = (rows - 1.0) * sqrt(min(max(s, 0.0), SPREAD_SIGMA_MAX) / SPREAD_SIGMA_MAX);
    let uv = vec2<f32>((clamp(v, 0.0, 1.0) * (w - 1.0) + 0.5) / w, (y + 0.5) / rows);
    return textureSampleLevel(tf_spread, tf_sampler, uv, i32(row * tf_info.rows), 0.0);
}

// The pre-integrated segment from value `front` to `back` (clamped to 0..1) at
// the step of row coordinate `row` (its layer: floor(row * rows)): associated
// colour and opacity, one filtered texture read.
fn tf_preint_sample(front: f32, back: f32, row: f32) -> vec4<f32> {
    let n = tf_info.preint_size;
    let uv = (clamp(vec2<f32>(front, back), vec2<f32>(0.0), vec2<f32>(1.0)) * (n - 1.0) + 0.5) / n;
    return textureSampleLevel(tf_preint, tf_sampler, uv, i32(row * tf_info.rows), 0.0);
}

// Linear interpolation between the two nearest TF entries (clamped to 0..1),
// exact and uncorrected: once per ray (MIP's maximum).
fn tf_lookup(v: f32) -> vec4<f32> {
    let n = tf_info.count;
    let x = clamp(v, 0.0, 1.0) * (n - 1.0);
    let i = min(u32(floor(x)), u32(n) - 1u);
    let j = min(i + 1u, u32(n) - 1u);
    let f = x - f32(i);
    return mix(tf[i], tf[j], f);
}

// O(1): true when no value in [lo, hi] is visible through the TF.
fn tf_transparent(range: vec2<f32>) -> bool {
    let b = tf_bins(range);
    return tf_prefix(b.y + 1u) == tf_prefix(b.x);
}

// The TF entries a value range touches, first and last (the range's ends
// rounded outwards, so a sub-range touches a subset of them).
fn tf_bins(range: vec2<f32>) -> vec2<u32> {
    let n1 = tf_info.count - 1.0;
    let i0 = u32(floor(clamp(range.x, 0.0, 1.0) * n1));
    let i1 = min(u32(ceil(clamp(range.y, 0.0, 1.0) * n1)), u32(n1));
    return vec2<u32>(min(i0, i1), i1);
}

// True when no TF entry the range touches is transparent: then no sub-range
// of it is (tf_transparent is false for each), and a region whose values lie
// in it has nothing to skip.
fn tf_opaque_throughout(range: vec2<f32>) -> bool {
    let b = tf_bins(range);
    return tf_prefix(b.y + 1u) - tf_prefix(b.x) == b.y + 1u - b.x;
}

// Writes one pixel of the outputs: premultiplied colour, the nearer of the
// volume's and the host's depth, and the sample count.
fn store_pixel(px: vec2<u32>, color: vec4<f32>, depth: f32, host: f32, samples: u32) {
    let p = vec2<i32>(px);
    textureStore(out_color, p, color);
    textureStore(out_depth, p, vec4<f32>(nearer_depth(depth, host), 0.0, 0.0, 0.0));
    textureStore(out_samples, p, vec4<u32>(samples, 0u, 0u, 0u));
}

// The opaque colour of normalized value v through the intensity window and
// colour map (brickray_core::Intensity::map): x = clamp((v - lo) / (hi - lo)),
// grey x, hot (3x, 3x - 1, 3x - 2) clamped, viridis interpolated in its table
// (VIRIDIS, generated from brickray_core::window::VIRIDIS). Every map is
// computed and one selected: no branch on a uniform alone.
fn intensity_color(v: f32) -> vec3<f32> {
    let x = clamp((v - frame.window_lo) / (frame.window_hi - frame.window_lo), 0.0, 1.0);
    let grey = vec3<f32>(x);
    let hot = clamp(vec3<f32>(3.0 * x) - vec3<f32>(0.0, 1.0, 2.0), vec3<f32>(0.0), vec3<f32>(1.0));
    let n = f32(VIRIDIS_N - 1u);
    let i = min(u32(floor(x * n)), VIRIDIS_N - 2u);
    let f = x * n - f32(i);
    var table = VIRIDIS;
    let viridis = mix(table[i], table[i + 1u], f);
    return select(select(grey, hot, frame.color_map == MAP_HOT), viridis, frame.color_map == MAP_VIRIDIS);
}

// The pixel of invocation `li` of workgroup `wg`: a workgroup's 8 x 8 pixels
// in Morton (Z) order, so that any 2^k consecutive invocations, the rays one
// SIMD group runs together, cover a compact block (8 lanes: 4 x 2 pixels,
// 16: 4 x 4, 32: 8 x 4) whose rays end alike, rather than a row of 8
// (docs/benchmarks.md, `raw`).
fn tile_pixel(wg: vec2<u32>, li: u32) -> vec2<u32> {
    let x = (li & 1u) | ((li >> 1u) & 2u) | ((li >> 2u) & 4u);
    let y = ((li >> 1u) & 1u) | ((li >> 2u) & 2u) | ((li >> 3u) & 4u);
    return wg * 8u + vec2<u32>(x, y);
}
