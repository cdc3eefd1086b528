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
    var s = SliceSample(0.0, false);
    let o = u * ooc.octree_scale;
    let root = OctBox(0u, 0u, vec3<f32>(0.0), vec3<f32>(1.0));
    let loc = oct_locate_leaf(root, o, dir * ooc.octree_scale, ooc.splits.xy);
    if (!loc.ok || (loc.word >> OCT_TAG_SHIFT) != OCT_TAG_DATA) {
        return s;
    }
    let record = loc.word & OCT_PTR_MASK;
    if (!oct_in_bounds(record)) {
        return s;
    }
    let slot = index_words[record];
    if (slot >= arrayLength(&slots)) {
        return s;
    }
    if (slot != *last) {
        feedback_reached(slot);
        feedback_add(slot, 1.0);
        *last = slot;
    }
    var c: Cursor;
    c.oo = o;
    c.od = vec3<f32>(0.0);
    cursor_enter(&c, brick_of(loc.leaf, slot));
    s.v = cursor_value(c, 0.0);
    s.ok = true;
    return s;
}
