// Per-voxel gradients of an in-core volume, computed once on the GPU (a module
// of its own; backend/gradients.rs makes its pipeline and pass): half the
// difference of the two neighbours' normalized values along each axis, the
// indices clamped at the faces. Trilinear interpolation is linear in the data,
// so one filtered read of this texture at u equals incore.wgsl's six-tap
// central difference of the trilinear field one voxel apart, wherever u lies
// at least half a voxel inside the volume; nearer the faces the taps clamp
// their positions where this clamps its indices, and the kernel scales the
// read by the exact factor (incore.wgsl, `gradient`). The kernel then reads
// one texel per shaded sample instead of six (`GRADIENTS` in modes.wgsl).

// `GradientParams` in backend/gradients.rs (a test checks the offsets).
struct GradientParams {
    dims: vec3<u32>,
    // normalized = texel * value_scale + value_offset.
    value_scale: f32,
    value_offset: f32,
    pad0: f32,
    pad1: f32,
    pad2: f32,
}

@group(0) @binding(0) var volume_tex: texture_3d<f32>;
@group(0) @binding(1) var<uniform> gp: GradientParams;
@group(0) @binding(2) var gradients: texture_storage_3d<rgba16float, write>;

fn value_at(p: vec3<i32>) -> f32 {
    let q = clamp(p, vec3<i32>(0), vec3<i32>(gp.dims) - vec3<i32>(1));
    return textureLoad(volume_tex, q, 0).r * gp.value_scale + gp.value_offset;
}

// One invocation per voxel, 8 x 8 of a slice per workgroup (the ray casters'
// workgroup, within the limits `required_limits` asks for).
@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (any(gid >= gp.dims)) {
        return;
    }
    let p = vec3<i32>(gid);
    let g = vec3<f32>(
        value_at(p + vec3<i32>(1, 0, 0)) - value_at(p - vec3<i32>(1, 0, 0)),
        value_at(p + vec3<i32>(0, 1, 0)) - value_at(p - vec3<i32>(0, 1, 0)),
        value_at(p + vec3<i32>(0, 0, 1)) - value_at(p - vec3<i32>(0, 0, 1)),
    ) * 0.5;
    textureStore(gradients, p, vec4<f32>(g, 0.0));
}
