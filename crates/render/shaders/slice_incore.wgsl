// Slice views in core (slice.wgsl): the volume texture's trilinear value.

fn slice_begin(px: vec2<u32>) {}

fn slice_sample(u: vec3<f32>, dir: vec3<f32>, last: ptr<function, u32>) -> SliceSample {
    return SliceSample(sample_value(u), true);
}
