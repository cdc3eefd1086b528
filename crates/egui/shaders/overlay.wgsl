// brickray-egui's host geometry: the volume's bounding box and axes, drawn as
// depth-tested lines in world space (a depth-only pre-pass gives the rays the
// lines' depth; the same lines drawn in egui's pass get the colour).

struct Uniforms {
    view_proj: mat4x4<f32>,
}

@group(0) @binding(0) var<uniform> u: Uniforms;

struct VertexOut {
    @builtin(position) position: vec4<f32>,
    @location(0) color: vec4<f32>,
}

@vertex
fn vs_main(@location(0) position: vec4<f32>, @location(1) color: vec4<f32>) -> VertexOut {
    var out: VertexOut;
    out.position = u.view_proj * vec4<f32>(position.xyz, 1.0);
    out.color = color;
    return out;
}

@fragment
fn fs_main(v: VertexOut) -> @location(0) vec4<f32> {
    return v.color;
}
