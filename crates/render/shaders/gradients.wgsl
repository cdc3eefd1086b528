// Per-voxel gradients, computed on the GPU (a module of its own;
// backend/gradients.rs makes its pipeline and passes): half the difference of
// the two neighbours' normalized values along each axis, the indices clamped
// at the faces of each box. In core the box is the volume (one, at the
// origin); out of core each box is a pool slot of the brick atlas (its stored
// brick, apron included) that this frame uploaded. Trilinear interpolation is
// linear in the data, so one filtered read of this texture at u equals the
// six-tap central difference of the trilinear field one voxel apart
// (incore.wgsl's and ooc.wgsl's six reads), wherever u lies at least half a
// voxel inside the box; nearer the volume's faces in core the taps clamp
// their positions where this clamps its indices, and the kernel scales the
// read by the exact factor (incore.wgsl, `gradient`); out of core the brick's
// 2-voxel apron (edge-clamped past the volume) keeps every tap within the box,
// and no factor is needed. The kernels then read one texel per shaded sample
// instead of six (`GRADIENTS` in modes.wgsl).

// `GradientParams` in backend/gradients.rs (a test checks the offsets).
struct GradientParams {
    // Texels of one box.
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
// Each box's first texel (xyz; w unused), in both textures.
@group(0) @binding(3) var<storage, read> origins: array<vec4<u32>>;

fn value_at(origin: vec3<i32>, p: vec3<i32>) -> f32 {
    let q = clamp(p, vec3<i32>(0), vec3<i32>(gp.dims) - vec3<i32>(1));
    return textureLoad(volume_tex, origin + q, 0).r * gp.value_scale + gp.value_offset;
}

// One invocation per texel, 8 x 8 of a slice per workgroup (the ray casters'
// workgroup, within the limits `required_limits` asks for); the dispatch's z
// runs over the boxes' slices, box after box.
@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let b = gid.z / gp.dims.z;
    let p = vec3<u32>(gid.xy, gid.z % gp.dims.z);
    if (any(p >= gp.dims) || b >= arrayLength(&origins)) {
        return;
    }
    let o = vec3<i32>(origins[b].xyz);
    let q = vec3<i32>(p);
    let g = vec3<f32>(
        value_at(o, q + vec3<i32>(1, 0, 0)) - value_at(o, q - vec3<i32>(1, 0, 0)),
        value_at(o, q + vec3<i32>(0, 1, 0)) - value_at(o, q - vec3<i32>(0, 1, 0)),
        value_at(o, q + vec3<i32>(0, 0, 1)) - value_at(o, q - vec3<i32>(0, 0, 1)),
    ) * 0.5;
    textureStore(gradients, o + q, vec4<f32>(g, 0.0));
}
