// Reprojection of the isosurface prediction buffer (docs/prediction.md): last
// frame's hits, warped into this frame's view before the ray cast. One
// invocation per pixel of last frame: its hit, a world point on its ray, is
// projected into this frame's camera and written, as this frame's eye
// distance, to the pixel it lands on; the nearest wins. Warped entries are
// stored complemented (~bits), so that the buffer's clear value 0 means "none"
// and atomicMax keeps the smallest distance (entries' bits order like
// distances). Pixels nothing lands on keep 0, which the ray cast treats as a
// hole: the sparse traversal.
// A module of its own (`FrameState` in frame.rs owns its pipeline).

// `ReprojectUniforms` in frame.rs (a test checks the offsets). Camera bases in
// world space: the eye, the unit view axis, the half-extent vectors of the
// image plane at distance 1 (perspective) or of the view volume (orthographic).
struct Reproject {
    prev_eye: vec3<f32>,
    prev_perspective: u32,
    prev_fwd: vec3<f32>,
    prev_near: f32,
    prev_right: vec3<f32>,
    pad0: f32,
    prev_up: vec3<f32>,
    pad1: f32,
    eye: vec3<f32>,
    perspective: u32,
    fwd: vec3<f32>,
    near: f32,
    right: vec3<f32>,
    pad2: f32,
    up: vec3<f32>,
    pad3: f32,
    // The viewport (both frames: a resize clears the history).
    size: vec2<u32>,
    // Offsets (u32 elements) of last frame's entries and of the warped ones.
    read_off: u32,
    write_off: u32,
}

@group(0) @binding(0) var<storage, read_write> entries: array<atomic<u32>>;
@group(0) @binding(1) var<uniform> rp: Reproject;

// As predict.wgsl.
const HIT_MAX: u32 = 0xfffffffdu;

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= rp.size.x || gid.y >= rp.size.y) {
        return;
    }
    let size = vec2<f32>(rp.size);
    let q = gid.y * rp.size.x + gid.x;
    let last = atomicLoad(&entries[rp.read_off + q]);
    if (last == 0u || last >= HIT_MAX) {
        return;
    }
    let e = bitcast<f32>(last) - 1.0;
    // Last frame's ray through this pixel (common.wgsl's pixel_ray, in world).
    let ndc = vec2<f32>(2.0 * (f32(gid.x) + 0.5) / size.x - 1.0, 1.0 - 2.0 * (f32(gid.y) + 0.5) / size.y);
    let lateral = ndc.x * rp.prev_right + ndc.y * rp.prev_up;
    let persp_prev = rp.prev_perspective != 0u;
    let dir = normalize(rp.prev_fwd + select(vec3<f32>(0.0), lateral, persp_prev));
    // Perspective: e along the ray from the eye; orthographic: e along the axis
    // from the eye's plane, through the pixel's lateral offset.
    let p = select(rp.prev_eye + lateral + rp.prev_fwd * e, rp.prev_eye + dir * e, persp_prev);
    // Into this frame's camera.
    let d = p - rp.eye;
    let a = dot(d, rp.fwd);
    let b = dot(d, rp.right) / dot(rp.right, rp.right);
    let c = dot(d, rp.up) / dot(rp.up, rp.up);
    let persp = rp.perspective != 0u;
    let ndc_new = select(vec2<f32>(b, c), vec2<f32>(b, c) / max(a, 1e-30), persp);
    let e_new = select(a, length(d), persp);
    let px = vec2<f32>((ndc_new.x + 1.0) * 0.5 * size.x, (1.0 - ndc_new.y) * 0.5 * size.y);
    let inside = all(px >= vec2<f32>(0.0)) && all(px < size) && a > rp.near;
    if (inside) {
        let pi = vec2<u32>(px);
        atomicMax(&entries[rp.write_off + pi.y * rp.size.x + pi.x], ~bitcast<u32>(max(e_new, 0.0) + 1.0));
    }
}
