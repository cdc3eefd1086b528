// A host application's opaque geometry, for tests and demos: an axis-aligned
// screen rectangle at a constant clip depth with a solid colour.

struct Quad {
    // x0, y0, x1, y1 in NDC.
    rect: vec4<f32>,
    color: vec4<f32>,
    // x: clip depth.
    depth: vec4<f32>,
}

@group(0) @binding(0) var<uniform> quad: Quad;

@vertex
fn vs_main(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    let corner = vec2<u32>(i & 1u, (i >> 1u) & 1u);
    let x = select(quad.rect.x, quad.rect.z, corner.x == 1u);
    let y = select(quad.rect.y, quad.rect.w, corner.y == 1u);
    return vec4<f32>(x, y, quad.depth.x, 1.0);
}

@fragment
fn fs_main() -> @location(0) vec4<f32> {
    return quad.color;
}
