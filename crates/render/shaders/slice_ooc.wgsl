// Slice views out of core (slice.wgsl): the point is located in the frame's
// cut through the index (brickray-index's oct_locate_leaf from the root) and
// sampled from its data leaf's brick in the atlas exactly as the ray caster
// samples it (brick_of, cursor_value: apron, fades, borrowed leaves). A point
// in an empty leaf has no sample. Each brick a pixel samples counts as
// reached by that pixel (the usage feedback the planner reads, as for rays),
// and nothing is occluded (the stop depth is the far value).

fn slice_begin(px: vec2<u32>) {
    feedback_stop(px, far_depth());
}

fn slice_sample(u: vec3<f32>, dir: vec3<f32>, last: ptr<function, u32>) -> SliceSample {
    var c: Cursor;
    if (!slice_cursor(u, dir, last, &c)) {
        return SliceSample(0.0, false);
    }
    return SliceSample(cursor_value(c, 0.0), true);
}
