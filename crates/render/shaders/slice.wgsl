// Slice views (docs/rendering-model.md, "Slice views"): a second entry point of
// each ray-cast kernel, after the kernel's own file, which provides
//     fn slice_begin(px: vec2<u32>)
//     fn slice_sample(u: vec3<f32>, dir: vec3<f32>, last: ptr<function, u32>) -> SliceSample
// (the normalized value at texture point u, sampled from the volume texture in
// core and from the brick atlas through the index out of core).
//
// The frame's camera is the slice's: orthographic, looking along the plane's
// normal, its near plane the slab's front face. Pixel (x, y) takes the samples
// t_k = (k + 1/2) slab_dt, k < slab_samples (t = 0, the plane, for a thin
// slice) that lie in the ray's extent in the clip box, reduces them by their
// maximum or mean and maps the result through the intensity window and colour
// map, opaque. A label map (LABELS) takes the slab's front sample instead
// (ids are neither maximised nor averaged) and draws its label's colour from
// the label table (the TF), opaque, or nothing for a hidden label. A label
// map over an intensity image (OVERLAY) colours or masks each pixel by the
// label under its front sample. A pixel with no sample is transparent; no
// depth is written.

const SLAB_MAX: u32 = 0u;
const SLAB_MEAN: u32 = 1u;

struct SliceSample {
    v: f32,
    ok: bool,
}

@compute @workgroup_size(8, 8, 1)
fn slice_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= frame.viewport_size.x || gid.y >= frame.viewport_size.y) {
        return;
    }
    let px = gid.xy;
    let start = start_ray(px);
    slice_begin(px);
    let sdt = frame.slab_dt;
    let range = slab_range(start);
    let n = range.y;
    var k = range.x;
    var count = 0u;
    var sum = 0.0;
    var best = -3.0e38;
    var front = 0.0;
    var front_u = vec3<f32>(0.0);
    var last = 0xffffffffu;
    loop {
        if (k >= n) { break; }
        let t = (f32(k) + 0.5) * sdt;
        if (t > start.t1) { break; }
        if (t >= start.t0) {
            let u = tex_at(start.r, t);
            let s = slice_sample(u, start.r.tex_dir, &last);
            if (s.ok) {
                if (count == 0u) {
                    front = s.v;
                    front_u = u;
                }
                count = count + 1u;
                sum = sum + s.v;
                best = max(best, s.v);
            }
        }
        k = k + 1u;
    }
    var color = vec4<f32>(0.0);
    if (count > 0u) {
        if (LABELS) {
            let c = tf_lookup(front);
            color = select(vec4<f32>(0.0), vec4<f32>(c.rgb, 1.0), c.a > 0.0);
        } else {
            let v = select(best, sum / f32(count), frame.slab_mode == SLAB_MEAN);
            // A label map over the image: the label under the front sample
            // (overlay.wgsl), premultiplied.
            let c = overlay_apply(vec4<f32>(intensity_color(v), 1.0), front_u);
            color = vec4<f32>(c.rgb * c.a, c.a);
        }
    }
    store_pixel(px, color, far_depth(), start.host, count);
}
