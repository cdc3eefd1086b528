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
