// Slice views of the channels, the second entry point of both multi-channel
// kernels, after the kernel's own file, which provides
//     fn channel_slice_begin(px: vec2<u32>)
//     fn channel_slice_sample(u: vec3<f32>, dir: vec3<f32>, last: ptr<function, u32>) -> ChannelSliceSample
// (every channel's normalized value at texture point u: from the packed
// texture in core, from the brick atlas through the index out of core).
// slice.wgsl's geometry, every channel at once
// (brickray_core::channels::slice_color): pixel (x, y) takes the slab's
// samples in the clip box, reduces each channel by the maximum or mean,
// classifies each by its TF (uncorrected) and adds the visible channels'
// colours weighted by their opacity over their TF's largest, clamped,
// opaque. A pixel with no sample is transparent; no depth is written.
const SLAB_MAX: u32 = 0u;
const SLAB_MEAN: u32 = 1u;

struct ChannelSliceSample {
    v: vec4<f32>,
    ok: bool,
}

@compute @workgroup_size(8, 8, 1)
fn slice_main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= frame.viewport_size.x || gid.y >= frame.viewport_size.y) {
        return;
    }
    let px = gid.xy;
    let start = start_ray(px);
    channel_slice_begin(px);
    let sdt = frame.slab_dt;
    let range = slab_range(start);
    let n = range.y;
    var k = range.x;
    var count = 0u;
    var sum = vec4<f32>(0.0);
    var best = vec4<f32>(-3.0e38);
    var front_u = vec3<f32>(0.0);
    var last = 0xffffffffu;
    loop {
        if (k >= n) { break; }
        let t = (f32(k) + 0.5) * sdt;
        if (t > start.t1) { break; }
        if (t >= start.t0) {
            let u = tex_at(start.r, t);
            let s = channel_slice_sample(u, start.r.tex_dir, &last);
            if (s.ok) {
                front_u = select(front_u, u, count == 0u);
                count = count + 1u;
                sum = sum + s.v;
                best = max(best, s.v);
            }
        }
        k = k + 1u;
    }
    var color = vec4<f32>(0.0);
    if (count > 0u) {
        let v = select(best, sum / f32(count), frame.slab_mode == SLAB_MEAN);
        let q = channel_tf_lookup4(v);
        let w = quad_alpha(q) * chan_slice_gain() * chan_visible();
        let rgb = q.q0.rgb * w.x + q.q1.rgb * w.y + q.q2.rgb * w.z + q.q3.rgb * w.w;
        // A label map over the channels: the label under the front sample
        // (overlay.wgsl), premultiplied.
        let c = overlay_apply(vec4<f32>(min(rgb, vec3<f32>(1.0)), 1.0), front_u);
        color = vec4<f32>(c.rgb * c.a, c.a);
    }
    store_pixel(px, color, far_depth(), start.host, count);
}
