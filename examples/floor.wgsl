// The opaque floor the embedding examples draw as host geometry.
struct Floor { view_proj: mat4x4<f32>, color: vec4<f32> }
@group(0) @binding(0) var<uniform> floor: Floor;
@vertex fn vs(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    let k = array(0u, 1u, 2u, 2u, 1u, 3u)[i];
    let c = vec2<f32>(f32(k & 1u), f32(k >> 1u)) * 1.6 - 0.8;
    return floor.view_proj * vec4<f32>(c.x, 0.0, c.y, 1.0);
}
@fragment fn fs() -> @location(0) vec4<f32> { return floor.color; }
