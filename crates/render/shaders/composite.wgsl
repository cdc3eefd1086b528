// Composites the ray caster's premultiplied colour into the host's pass and writes
// its depth (the host depth where the volume put none), so host geometry and the
// volume occlude each other correctly both ways. Drawn as one triangle covering
// the viewport; the outputs are viewport-sized, so a fragment reads the texel at
// its framebuffer position minus the viewport origin.

struct Composite {
    // The viewport's origin in the host's target (pixels).
    origin: vec2<u32>,
    pad: vec2<u32>,
}

@group(0) @binding(0) var color_tex: texture_2d<f32>;
@group(0) @binding(1) var depth_tex: texture_2d<f32>;
@group(0) @binding(2) var<uniform> composite: Composite;

@vertex
fn vs_main(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    let x = f32((i << 1u) & 2u) * 2.0 - 1.0;
    let y = f32(i & 2u) * 2.0 - 1.0;
    return vec4<f32>(x, y, 0.0, 1.0);
}

struct FragOut {
    @location(0) color: vec4<f32>,
    @builtin(frag_depth) depth: f32,
}

fn texel(pos: vec4<f32>) -> vec2<i32> {
    return vec2<i32>(pos.xy) - vec2<i32>(composite.origin);
}

@fragment
fn fs_main(@builtin(position) pos: vec4<f32>) -> FragOut {
    let p = texel(pos);
    var o: FragOut;
    o.color = textureLoad(color_tex, p, 0);
    o.depth = textureLoad(depth_tex, p, 0).r;
    return o;
}

// Variant for hosts whose pass has no depth attachment.
@fragment
fn fs_color(@builtin(position) pos: vec4<f32>) -> @location(0) vec4<f32> {
    return textureLoad(color_tex, texel(pos), 0);
}
