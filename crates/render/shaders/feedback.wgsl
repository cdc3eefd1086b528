// Ray-guided usage feedback of the out-of-core kernel (docs/visibility.md),
// after ooc.wgsl's group 2. Each ray adds 1 to the counter of every pool slot
// whose data leaf it reaches before it terminates (early ray termination, an
// isosurface hit, the sample budget) or leaves the volume: the count of rays,
// i.e. pixels, that could see the brick. The renderer clears the counters
// before the pass, copies them to a read-back ring after it, and maps them
// asynchronously; `brickray-visibility` turns counts below the threshold
// (4 pixels) into "invisible", so refinement stops splitting what rays never
// reach. A leaf skipped because the running MIP maximum exceeds its range is
// still counted: coarser data may have a lower maximum than finer data, so
// only the traversal, not the skip, says the brick is unneeded.

// One counter per pool slot (`OutOfCore`'s usage buffer, backend/ooc.rs).
@group(2) @binding(6) var<storage, read_write> usage: array<atomic<u32>>;

// Records that this ray reached the brick in `slot`.
fn feedback_reached(slot: u32) {
    atomicAdd(&usage[slot], 1u);
}

// Occlusion-query feedback: the clip depth of the last sample each ray visited
// (where early ray termination or an isosurface hit stopped it; the end of its
// extent in the volume, clipped to the host's depth, otherwise), per viewport
// pixel; occlusion.wgsl rasterises leaf boxes against it.
@group(2) @binding(7) var stop_depth: texture_storage_2d<r32float, write>;

fn feedback_stop(px: vec2<u32>, depth: f32) {
    textureStore(stop_depth, vec2<i32>(px), vec4<f32>(depth, 0.0, 0.0, 0.0));
}

// True when the ray stopped before the end of its extent: DVR early ray
// termination or an isosurface hit. MIP and rays that ran out of samples count
// as not stopped (nothing behind them is hidden).
fn feedback_terminated(acc: Accum) -> bool {
    let ert = ERT && MODE == MODE_DVR && acc.color.a >= frame.ert_threshold;
    return ert || (MODE == MODE_ISO && acc.hit);
}
