// Occlusion-query feedback (Gobbetti et al. 2008, section 6; docs/visibility.md):
// a depth-only render pass over the viewport. `fill` copies the depth of the
// last sample each ray visited (written by the out-of-core kernel into an
// R32Float texture, feedback.wgsl) into the depth attachment; `box_vs` then
// draws the queried leaves' boxes against it, depth test on, depth writes off,
// each inside its own occlusion query: the samples that pass are the box's
// visible pixels. No branch depends on uniforms alone (Mesa 22 lavapipe, see
// docs/rendering-model.md).

struct OcclusionUniforms {
    // World to clip, wgpu depth 0..1 in the camera's depth convention.
    view_proj: mat4x4<f32>,
}

@group(0) @binding(0) var stop_depth_in: texture_2d<f32>;
@group(0) @binding(1) var<uniform> occ: OcclusionUniforms;

struct FillOut {
    @builtin(position) pos: vec4<f32>,
}

// One triangle covering the viewport.
@vertex
fn fill_vs(@builtin(vertex_index) i: u32) -> FillOut {
    var o: FillOut;
    let uv = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u));
    o.pos = vec4<f32>(uv * 2.0 - 1.0, 0.0, 1.0);
    return o;
}

@fragment
fn fill_fs(in: FillOut) -> @builtin(frag_depth) f32 {
    let p = vec2<i32>(in.pos.xy);
    return clamp(textureLoad(stop_depth_in, p, 0).r, 0.0, 1.0);
}

// A box: corner c0 and edge vectors ex, ey, ez (world space).
struct BoxIn {
    @location(0) c0: vec4<f32>,
    @location(1) ex: vec4<f32>,
    @location(2) ey: vec4<f32>,
    @location(3) ez: vec4<f32>,
}

// The 8 corners' unit coordinates, and 12 triangles over them.
const CORNER_OF: array<u32, 36> = array<u32, 36>(
    0u, 2u, 1u, 1u, 2u, 3u,
    4u, 5u, 6u, 5u, 7u, 6u,
    0u, 1u, 4u, 1u, 5u, 4u,
    2u, 6u, 3u, 3u, 6u, 7u,
    0u, 4u, 2u, 2u, 4u, 6u,
    1u, 3u, 5u, 3u, 7u, 5u,
);

@vertex
fn box_vs(@builtin(vertex_index) i: u32, b: BoxIn) -> @builtin(position) vec4<f32> {
    let c = CORNER_OF[i % 36u];
    let u = vec3<f32>(f32(c & 1u), f32((c >> 1u) & 1u), f32((c >> 2u) & 1u));
    let p = b.c0.xyz + b.ex.xyz * u.x + b.ey.xyz * u.y + b.ez.xyz * u.z;
    return occ.view_proj * vec4<f32>(p, 1.0);
}
