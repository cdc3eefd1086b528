// The out-of-core volume's group 2 and what both out-of-core kernels (one
// channel: ooc.wgsl; several: ooc_channels.wgsl) share: the brick a data leaf
// samples (brick_of: its atlas mapping, level step, fade and borrowed
// octant), the ray's cursor through it, its sub-cells and the step units.
// After common.wgsl, modes.wgsl and brickray-index's octree_traversal.wgsl;
// each includer defines `leaf_cell_skips` (leaf_span).

// Group 2: the out-of-core volume (`OutOfCore` in backend/ooc.rs; a test checks
// the offsets).
struct OocParams {
    // Voxel dimensions of the finest level.
    dims: vec3<f32>,
    // normalized = texel * value_scale + value_offset.
    value_scale: f32,
    // Octree coordinate = texture coordinate * octree_scale.
    octree_scale: vec3<f32>,
    value_offset: f32,
    // Atlas size in texels.
    atlas_size: vec3<f32>,
    // The finest octree level.
    finest_level: u32,
    // Interior voxels per brick side.
    brick: u32,
    // Apron voxels on each side.
    apron: u32,
    // Stored voxels per brick side (brick + 2 apron).
    stored_side: u32,
    // Sub-cells per brick axis (empty-space skipping inside bricks).
    sub_cells: u32,
    // xy: the octree's split masks for octree_traversal.wgsl (OCT_SPLITS_ALL for
    // an octree; docs/index-format.md); zw: unused.
    splits: vec4<u32>,
}

struct SlotInfo {
    // xyz: atlas texel offset of the slot, w: levels up to the brick's fade
    // fallback (0: not fading; docs/stability.md).
    offset: vec4<f32>,
    // x: normalized min, y: normalized max of the brick; z: the fallback's
    // slot, w: the fallback's weight (value = mix(own, fallback, w)).
    range: vec4<f32>,
}

@group(2) @binding(0) var<uniform> ooc: OocParams;
@group(2) @binding(1) var atlas_tex: texture_3d<f32>;
@group(2) @binding(2) var atlas_sampler: sampler;
// The tables (`TableTexture`s, common.wgsl's table_texel). A table's
// capacity is its rows': the entries past what was written are stale or
// zero, as a grown buffer's were.
//
// The slot table: SlotInfo's two vec4 per row.
@group(2) @binding(3) var slots_tex: texture_2d<f32>;
// Normalized min/max of each brick's sub-cells (`sub_cells`^3 per slot, x
// fastest), for empty-space skipping inside a brick.
@group(2) @binding(4) var sub_cells_tex: texture_2d<f32>;
// The octree with ropes (docs/index-format.md), walked by
// octree_traversal.wgsl: one word per entry.
@group(2) @binding(5) var index_tex: texture_2d<u32>;

fn oct_word(i: u32) -> u32 {
    return textureLoad(index_tex, table_texel(i), 0).r;
}

fn oct_word_count() -> u32 {
    return TABLE_ROW * textureDimensions(index_tex).y;
}

// Rows of the slot table.
fn slot_count() -> u32 {
    return TABLE_ROW / 2u * textureDimensions(slots_tex).y;
}

// SlotInfo::offset and SlotInfo::range of a slot's row.
fn slot_offset(slot: u32) -> vec4<f32> {
    return textureLoad(slots_tex, table_texel(2u * slot), 0);
}

fn slot_range(slot: u32) -> vec4<f32> {
    return textureLoad(slots_tex, table_texel(2u * slot + 1u), 0);
}

// Entry i of the sub-cell table.
fn sub_cell_entry(i: u32) -> vec2<f32> {
    return textureLoad(sub_cells_tex, table_texel(i), 0).xy;
}

// A data leaf's brick: atlas texture coordinate = uv0 + o * kuv for octree
// point o (texel centres at +0.5 are folded in).
struct Brick {
    uv0: vec3<f32>,
    kuv: vec3<f32>,
    // The step multiple of this level: finest voxels per voxel along the axis
    // the level keeps finest (2^(finest - level) in an octree).
    f: f32,
    // Finest voxels per voxel of this level, per axis.
    f3: vec3<f32>,
    // The corrected TF table's row for this level's step.
    tf_v: f32,
    // The slot sampled (sub-cells): the leaf's, or the ancestor's it is
    // borrowed from.
    slot: u32,
    // The leaf's own slot (feedback counters) and its level's step multiple
    // (the visible weight's unit): a borrowed leaf's differ from `slot`, `f`.
    usage: u32,
    usage_f: f32,
    box_min: vec3<f32>,
    box_size: vec3<f32>,
    // A level-of-detail fade: the ancestor brick's mapping (as uv0, kuv), its
    // finest voxels per voxel per axis, and its weight (0: not fading).
    fb_uv0: vec3<f32>,
    fb_kuv: vec3<f32>,
    fb_f3: vec3<f32>,
    fb_w: f32,
    // The fallback's slot and box (the leaf's own when it does not fade):
    // its sub-cells bound the mixed values (fade_sub_cell_index).
    fb_slot: u32,
    fb_box_min: vec3<f32>,
    fb_box_size: vec3<f32>,
    // The brick sampled is coarser than the finest level along some axis:
    // its voxels may have a spread (the finest level's is 0).
    coarse: bool,
}

fn brick_of(leaf: OctBox, slot: u32) -> Brick {
    var b: Brick;
    let k = f32(ooc.brick) / leaf.box_size;
    let inv_atlas = 1.0 / ooc.atlas_size;
    b.kuv = k * inv_atlas;
    let so = slot_offset(slot);
    let sr = slot_range(slot);
    b.uv0 = (so.xyz + f32(ooc.apron) - leaf.box_min * k) * inv_atlas;
    // Per-axis halvings between this level and the finest.
    let hd = oct_halvings(ooc.splits.xy, ooc.finest_level) - oct_halvings(ooc.splits.xy, leaf.level);
    b.f3 = vec3<f32>(oct_exp2_pos(hd.x), oct_exp2_pos(hd.y), oct_exp2_pos(hd.z));
    let e = min(hd.x, min(hd.y, hd.z));
    b.f = oct_exp2_pos(e);
    b.tf_v = tf_row(f32(e));
    b.slot = slot;
    b.usage = slot;
    b.usage_f = b.f;
    b.box_min = leaf.box_min;
    b.box_size = leaf.box_size;
    // Fading: the ancestor `up` levels coarser, sampled at the same points.
    let up = u32(so.w);
    b.fb_w = 0.0;
    b.fb_f3 = b.f3;
    b.fb_uv0 = b.uv0;
    b.fb_kuv = b.kuv;
    b.fb_slot = slot;
    b.fb_box_min = leaf.box_min;
    b.fb_box_size = leaf.box_size;
    if (up > 0u && up <= leaf.level) {
        // The ancestor's box: each axis doubled once per level that split it.
        let anc = leaf.level - up;
        let hu = oct_halvings(ooc.splits.xy, leaf.level) - oct_halvings(ooc.splits.xy, anc);
        let size = leaf.box_size * vec3<f32>(oct_exp2_pos(hu.x), oct_exp2_pos(hu.y), oct_exp2_pos(hu.z));
        let fmin = floor(leaf.box_min / size) * size;
        let fk = f32(ooc.brick) / size;
        let fs = u32(sr.z);
        b.fb_kuv = fk * inv_atlas;
        b.fb_uv0 = (slot_offset(fs).xyz + f32(ooc.apron) - fmin * fk) * inv_atlas;
        let hf = hd + hu;
        b.fb_f3 = vec3<f32>(oct_exp2_pos(hf.x), oct_exp2_pos(hf.y), oct_exp2_pos(hf.z));
        // (Without FADES no row carries a fade: 0 whatever the table says.)
        b.fb_w = select(0.0, clamp(sr.w, 0.0, 1.0), FADES);
        b.fb_slot = fs;
        b.fb_box_min = fmin;
        b.fb_box_size = size;
        // A borrowed leaf (weight above 1; an octant-granular cut): drawn
        // from the ancestor alone, as the ancestor draws it (its mapping,
        // box, step and sub-cells); counted as itself.
        if (sr.w > 1.5) {
            b.uv0 = b.fb_uv0;
            b.kuv = b.fb_kuv;
            b.f3 = b.fb_f3;
            let ea = min(hf.x, min(hf.y, hf.z));
            b.f = oct_exp2_pos(ea);
            b.tf_v = tf_row(f32(ea));
            b.slot = fs;
            b.box_min = fmin;
            b.box_size = size;
            b.fb_w = 0.0;
        }
    }
    b.coarse = any(b.f3 > vec3<f32>(1.0));
    return b;
}

// Out of core a sample depends on the brick and the ray in octree coordinates
// (o(t) = oo + od t); the ray's line in the brick's atlas coordinates,
// uv(t) = ua + ud t, is set once per leaf (`cursor_enter`).
struct Cursor {
    b: Brick,
    oo: vec3<f32>,
    od: vec3<f32>,
    ua: vec3<f32>,
    ud: vec3<f32>,
    // The same line in the fade fallback's atlas coordinates.
    fa: vec3<f32>,
    fd: vec3<f32>,
    // The channel a multi-channel kernel bisects and shades
    // (ooc_channels.wgsl; unused by ooc.wgsl).
    c: u32,
}

fn cursor_enter(c: ptr<function, Cursor>, b: Brick) {
    (*c).b = b;
    (*c).ua = b.uv0 + (*c).oo * b.kuv;
    (*c).ud = (*c).od * b.kuv;
    (*c).fa = b.fb_uv0 + (*c).oo * b.fb_kuv;
    (*c).fd = (*c).od * b.fb_kuv;
}

// Passes over the atlas per value: 2 in a fading leaf (its own brick, then the
// ancestor's), else 1. Lavapipe runs both sides of every `if` for the whole
// SIMD group of rays, but leaves a loop once no lane continues: the ancestor's
// read is the loop's second trip, which a group without a fading lane skips
// (an `if` cost every sample a second atlas read, 30% of the brute-force
// march).
// Without FADES (no leaf of the frame's cut fades) always 1, and the
// second pass is compiled out.
fn cursor_passes(c: Cursor) -> u32 {
    return select(1u, 2u, FADES && c.b.fb_w > 0.0);
}

// The ray parameter of one finest voxel (the step is step_factor of it).
fn finest_voxel_t() -> f32 {
    return frame.dt / max(frame.step_factor, 1e-6);
}

// The ray parameter of one voxel of `level` along its finest axes (the
// visible weight's unit, feedback.wgsl): the finest voxel times the level's
// step multiple (Brick::f).
fn level_voxel_t(level: u32) -> f32 {
    let hd = oct_halvings(ooc.splits.xy, ooc.finest_level) - oct_halvings(ooc.splits.xy, level);
    return finest_voxel_t() * oct_exp2_pos(min(hd.x, min(hd.y, hd.z)));
}

// The sub-cell of the brick holding octree point o (integer coordinates).
fn sub_cell_of(b: Brick, o: vec3<f32>) -> vec3<u32> {
    let n = f32(ooc.sub_cells);
    return vec3<u32>(clamp(floor((o - b.box_min) * (n / b.box_size)), vec3<f32>(0.0), vec3<f32>(n - 1.0)));
}

// Sub-cell j of `slot` in `sub_cells` (a multi-channel kernel's entries are
// this times its channels).
fn sub_cell_index(slot: u32, j: vec3<u32>) -> u32 {
    let n = ooc.sub_cells;
    return ((slot * n + j.z) * n + j.y) * n + j.x;
}

// The fallback's sub-cell that holds sub-cell j of a fading leaf's brick (j
// itself for a leaf that does not fade). An ancestor's sub-cell grid is
// aligned with its descendants' (boxes of powers of two, snapped), so each of
// the leaf's sub-cells lies in one of the fallback's: found from its centre.
fn fade_sub_cell_index(b: Brick, j: vec3<u32>) -> u32 {
    let n = f32(ooc.sub_cells);
    let centre = b.box_min + (vec3<f32>(j) + 0.5) * (b.box_size / n);
    let fj = clamp(floor((centre - b.fb_box_min) * (n / b.fb_box_size)), vec3<f32>(0.0), vec3<f32>(n - 1.0));
    return sub_cell_index(b.fb_slot, vec3<u32>(fj));
}

fn range_union(a: vec2<f32>, b: vec2<f32>) -> vec2<f32> {
    return vec2<f32>(min(a.x, b.x), max(a.y, b.y));
}

// The normalized values a sample in sub-cell j of brick b can take: the
// sub-cell's range, and while the leaf fades (value = mix(own, fallback, w),
// between the two) its fallback's sub-cell's as well, so a fading leaf skips
// empty space like any other (it once could not, and a frame in which many
// bricks arrived took up to 2x a converged one).
fn sub_cell_range(b: Brick, j: vec3<u32>) -> vec2<f32> {
    let own = sub_cell_entry(sub_cell_index(b.slot, j));
    if (!FADES) {
        return own;
    }
    return range_union(own, sub_cell_entry(fade_sub_cell_index(b, j)));
}

// The normalized values a sample of the data leaf in `slot` can take: its
// brick's range and, while it fades or borrows, its fallback's (each brick's
// range covers its sub-cells', apron included).
fn leaf_range(slot: u32) -> vec2<f32> {
    let r = slot_range(slot);
    let fs = min(u32(r.z), slot_count() - 1u);
    let f = slot_range(select(slot, fs, slot_offset(slot).w > 0.0));
    return vec2<f32>(min(r.x, f.x), max(r.y, f.y));
}

// The largest normalized value a sample of the data leaf in `slot` can take.
fn leaf_max(slot: u32) -> f32 {
    return leaf_range(slot).y;
}

// t at which the ray o(t) = oo + od t leaves sub-cell j of brick b (`inv_od`:
// safe_inverse(od)).
fn sub_cell_exit(b: Brick, j: vec3<u32>, oo: vec3<f32>, od: vec3<f32>, inv_od: vec3<f32>) -> f32 {
    let side = b.box_size / f32(ooc.sub_cells);
    let lo = b.box_min + vec3<f32>(j) * side;
    return box_exit(oo, od, inv_od, lo, lo + side);
}

// The stretch [ta, tb] of the ray in a data leaf narrowed to where it can
// contribute (x, y: from the entry of the first of the brick's sub-cells
// along the ray that can to the exit of the last; x >= y: none can) and the
// sub-cells read (z). A sub-cell can unless the includer's
// `leaf_cell_skips(b, j, mx)` says no sample of the frame's mode draws from
// it (ooc.wgsl: transparent through the TF, at most the running maximum
// `mx.x` at the leaf's entry, below the isovalue; ooc_channels.wgsl: so in
// every visible channel); a fading leaf's sub-cells bound both levels. One
// walk over the sub-cells the ray crosses (a 3D DDA, at most 3n - 2 of
// them) when the ray enters the leaf, so the sample loop carries no test:
// on lavapipe a sample loop with a test in it ran 1.5x slower even where no
// test was taken. The samples between the first and the last such
// sub-cell are all taken. A walk that stops short of tb (rounding at a
// face) leaves the rest to be sampled.
fn leaf_span(b: Brick, oo: vec3<f32>, od: vec3<f32>, inv_od: vec3<f32>, ta: f32, tb: f32, mx: vec4<f32>) -> vec3<f32> {
    let n = ooc.sub_cells;
    let side = b.box_size / f32(n);
    let dir = vec3<i32>(sign(od));
    var j = vec3<i32>(sub_cell_of(b, oo + od * ta));
    var span = vec2<f32>(tb, ta);
    var t = ta;
    var i = 0u;
    loop {
        if (t >= tb || i >= 3u * n) { break; }
        i = i + 1u;
        let lo = b.box_min + vec3<f32>(j) * side;
        let far = select(lo, lo + side, od > vec3<f32>(0.0));
        let tf = select(vec3<f32>(3.0e38), (far - oo) * inv_od, od != vec3<f32>(0.0));
        let m = min(tf.x, min(tf.y, tf.z));
        let te = min(m, tb);
        if (!leaf_cell_skips(b, vec3<u32>(j), mx)) {
            span = vec2<f32>(min(span.x, t), te);
        }
        t = max(t, te);
        // Across every face the ray leaves by (two or three at an edge or
        // corner).
        j = j + select(vec3<i32>(0), dir, tf <= vec3<f32>(m));
        if (any(j < vec3<i32>(0)) || any(j >= vec3<i32>(i32(n)))) { break; }
    }
    if (t < tb) {
        span = vec2<f32>(min(span.x, t), tb);
    }
    return vec3<f32>(span, f32(i));
}

// The data leaf the frame's cut holds at the octree point o, located from
// the root (a point on a face goes to the side `dir` moves into), and its
// brick-pool slot; `ok` false where the cut holds no data there or the index
// or the slot is out of bounds. Slice views and MIP's peaks look up their
// leaves with it.
struct DataLeaf {
    ok: bool,
    leaf: OctBox,
    slot: u32,
}

fn locate_data_leaf(o: vec3<f32>, dir: vec3<f32>) -> DataLeaf {
    var found: DataLeaf;
    found.ok = false;
    let root = OctBox(0u, 0u, vec3<f32>(0.0), vec3<f32>(1.0));
    let loc = oct_locate_leaf(root, o, dir, ooc.splits.xy);
    if (!loc.ok || (loc.word >> OCT_TAG_SHIFT) != OCT_TAG_DATA) {
        return found;
    }
    let record = loc.word & OCT_PTR_MASK;
    if (!oct_in_bounds(record)) {
        return found;
    }
    let slot = oct_word(record);
    if (slot >= slot_count()) {
        return found;
    }
    found.ok = true;
    found.leaf = loc.leaf;
    found.slot = slot;
    return found;
}

// Slice views of both out-of-core kernels: `c` set at texture point u on the
// data leaf the frame's cut holds there (located through the index from the
// root; `dir`, the view direction, decides points on a face), sampled from
// its brick as a ray samples it (apron, fades, borrowed leaves). Its brick
// counts as reached and seen by the pixel once per run of samples in it
// (`last`: the slot sampled before). False where the cut holds no data.
fn slice_cursor(u: vec3<f32>, dir: vec3<f32>, last: ptr<function, u32>, c: ptr<function, Cursor>) -> bool {
    let o = u * ooc.octree_scale;
    let found = locate_data_leaf(o, dir * ooc.octree_scale);
    if (!found.ok) {
        return false;
    }
    let slot = found.slot;
    if (slot != *last) {
        feedback_reached(slot);
        feedback_add(slot, 1.0);
        *last = slot;
    }
    (*c).oo = o;
    (*c).od = vec3<f32>(0.0);
    cursor_enter(c, brick_of(found.leaf, slot));
    return true;
}

// MIP, both out-of-core kernels: where a peak at t (a sample the march took)
// is refined (mip_refine). The cursor `c` (its ray: oo, od) enters the brick
// of the data leaf the cut holds at the peak's point, located from the root
// (a point on a leaf's face goes to the leaf the ray enters there, as the
// march assigns its samples); returns the ray's extent in that leaf widened
// by the refinement's reach (three quarters of the leaf level's step, within
// the brick's apron), within [t0, t1], and the leaf level's step (z; 0
// where the cut holds no data there). Found after the march, so the march
// notes nothing per sample.
fn peak_leaf_span(c: ptr<function, Cursor>, t: f32, t0: f32, t1: f32, dt: f32) -> vec3<f32> {
    let oo = (*c).oo;
    let od = (*c).od;
    let found = locate_data_leaf(oo + od * t, od);
    if (!found.ok) {
        return vec3<f32>(0.0);
    }
    let leaf = found.leaf;
    cursor_enter(c, brick_of(leaf, found.slot));
    let inv = safe_inverse(od);
    let hi = leaf.box_min + leaf.box_size;
    let t_in = box_entry(oo, od, inv, leaf.box_min, hi);
    let t_out = box_exit(oo, od, inv, leaf.box_min, hi);
    let b = (*c).b;
    let dtl = dt * b.f;
    let reach = min(0.75 * dtl, f32(ooc.apron) * finest_voxel_t() * min(b.f3.x, min(b.f3.y, b.f3.z)));
    return vec3<f32>(max(t_in - reach, t0), min(t_out + reach, t1), dtl);
}

