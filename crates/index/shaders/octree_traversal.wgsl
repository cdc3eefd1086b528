// Octree-with-ropes traversal (Gobbetti et al. 2008, section 5.2 and Fig. 5)
// over the index encoded by brickray-index (docs/index-format.md).
//
// Library file: it has no entry point and declares NO binding. The including
// shader provides the index's words through two functions, from a storage
// buffer, a texture or wherever it keeps them, e.g.
//
//     @group(0) @binding(9) var<storage, read> index_words: array<u32>;
//     fn oct_word(i: u32) -> u32 { return index_words[i]; }
//     fn oct_word_count() -> u32 { return arrayLength(&index_words); }
//
// (oct_word is called only for i < oct_word_count(). The ray casters keep the
// words in a texture: on lavapipe a storage-buffer load whose address differs
// between lanes runs as a loop over the lanes.)
//
// OCT_OCTREE: every level splits every axis (`splits` is OCT_SPLITS_ALL). A
// pipeline that sets it has oct_mask and oct_halvings folded to constants.
//
// All names are prefixed `oct_` / `Oct` / `OCT_`. The code mirrors
// crates/index/src/traverse.rs (the CPU twin, which the tests check against a
// brute-force oracle) function by function; change both together.
//
// Usage (coordinates are octree unit-cube coordinates, t_max finite; `splits`
// the packed split masks, Rust `Splits::gpu_words`, OCT_SPLITS_ALL for the
// octree):
//
//     var st = oct_begin(origin, dir, t_min, t_max, 4096u, splits);
//     while (oct_next_leaf(&st)) {
//         // st.hit.leaf.{node, level, box_min, box_size}, st.hit.tag,
//         // st.hit.data (brick-pool slot when tag == OCT_TAG_DATA),
//         // st.hit.t_enter < st.hit.t_exit
//         if (done) { break; }
//     }
//     // oct_begin_inside instead for a segment already clipped to a box
//     // inside the cube: its ends are then the first leaf's t_enter and the
//     // last leaf's t_exit exactly.
//     // st.status: OCT_STATUS_FINISHED, _STEP_LIMIT or _CORRUPT (or _RUNNING
//     // when the caller broke out early)

const OCT_NULL: u32 = 0xffffffffu;
const OCT_TAG_SHIFT: u32 = 30u;
const OCT_PTR_MASK: u32 = 0x3fffffffu;
const OCT_TAG_INNER: u32 = 0u;
const OCT_TAG_EMPTY: u32 = 1u;
const OCT_TAG_DATA: u32 = 2u;
const OCT_LEAF_RECORD_WORDS: u32 = 7u;
const OCT_ROPE_LEVEL_SHIFT: u32 = 27u;
const OCT_ROPE_NODE_MASK: u32 = 0x07ffffffu;
const OCT_MAX_LEVEL: u32 = 20u;
const OCT_DIR_EPSILON: f32 = 1e-30;
const OCT_T_BIG: f32 = 3.0e38;
// Split masks of levels 0..9 (x) and 10..19 (y), 3 bits a level (Rust: Splits);
// every level splits all axes.
const OCT_SPLITS_ALL: vec2<u32> = vec2<u32>(0x3fffffffu, 0x3fffffffu);
// Bit 0 of each level's 3-bit mask, levels 0..9.
const OCT_SPLIT_AXIS_BITS: u32 = 0x09249249u;

// Set by a pipeline whose index is an octree (see above); the split masks
// are then not read.
override OCT_OCTREE: bool = false;

const OCT_STATUS_RUNNING: u32 = 0u;
const OCT_STATUS_FINISHED: u32 = 1u;
const OCT_STATUS_STEP_LIMIT: u32 = 2u;
const OCT_STATUS_CORRUPT: u32 = 3u;

// A node and its box (Rust: NodeBox); box_size per axis.
struct OctBox {
    node: u32,
    level: u32,
    box_min: vec3<f32>,
    box_size: vec3<f32>,
}

// One reported leaf (Rust: LeafHit). tag is OCT_TAG_EMPTY or OCT_TAG_DATA;
// data is the brick-pool slot of a data leaf, OCT_NULL for an empty one.
struct OctLeaf {
    leaf: OctBox,
    tag: u32,
    data: u32,
    t_enter: f32,
    t_exit: f32,
}

// Traversal state (Rust: Traversal). cur.node == OCT_NULL when done.
struct OctState {
    origin: vec3<f32>,
    dir: vec3<f32>,
    inv_dir: vec3<f32>,
    t: f32,
    t_end: f32,
    cur: OctBox,
    steps: u32,
    max_steps: u32,
    status: u32,
    hit: OctLeaf,
    splits: vec2<u32>,
}

struct OctLocated {
    leaf: OctBox,
    word: u32,
    ok: bool,
}

struct OctExit {
    t: f32,
    face: u32,
}

struct OctRope {
    next: OctBox,
    ok: bool,
}

// 2^-level and 2^level, exact (built from the float bits).
fn oct_exp2_neg(level: u32) -> f32 {
    return bitcast<f32>((127u - level) << 23u);
}

fn oct_exp2_pos(level: u32) -> f32 {
    return bitcast<f32>((127u + level) << 23u);
}

// Rust: Splits::mask. The axes a node of `level` is split along (7 from level 20).
fn oct_mask(splits: vec2<u32>, level: u32) -> u32 {
    if (OCT_OCTREE) {
        return 7u;
    }
    let w = select(splits.y, splits.x, level < 10u);
    return select(7u, (w >> (3u * (level % 10u))) & 7u, level < 20u);
}

// Rust: Splits::halvings. Per axis, the levels above `level` that split it.
fn oct_halvings(splits: vec2<u32>, level: u32) -> vec3<u32> {
    if (OCT_OCTREE) {
        return vec3<u32>(level);
    }
    let lo = splits.x & ((1u << (3u * min(level, 10u))) - 1u);
    let hi = splits.y & ((1u << (3u * (clamp(level, 10u, 20u) - 10u))) - 1u);
    let b = OCT_SPLIT_AXIS_BITS;
    let h = vec3<u32>(
        countOneBits(lo & b) + countOneBits(hi & b),
        countOneBits((lo >> 1u) & b) + countOneBits((hi >> 1u) & b),
        countOneBits((lo >> 2u) & b) + countOneBits((hi >> 2u) & b),
    );
    // Levels past 20 split all axes.
    return h + vec3<u32>(max(level, 20u) - 20u);
}

fn oct_in_bounds(i: u32) -> bool {
    return i < oct_word_count();
}

// Rust: clip_unit_cube. Returns (t0, t1); the ray misses when !(t0 < t1).
fn oct_clip_unit_cube(origin: vec3<f32>, dir: vec3<f32>, inv_dir: vec3<f32>, t_min: f32, t_max: f32) -> vec2<f32> {
    var t0 = t_min;
    var t1 = t_max;
    if (all(dir == vec3<f32>(0.0))) {
        return vec2<f32>(1.0, 0.0);
    }
    for (var a = 0u; a < 3u; a = a + 1u) {
        let o = origin[a];
        if (dir[a] == 0.0) {
            if (o < 0.0 || o >= 1.0) {
                return vec2<f32>(1.0, 0.0);
            }
        } else {
            let ta = (0.0 - o) * inv_dir[a];
            let tb = (1.0 - o) * inv_dir[a];
            t0 = max(t0, min(ta, tb));
            t1 = min(t1, max(ta, tb));
        }
    }
    return vec2<f32>(t0, t1);
}

// Rust: Traversal::inside. A walk over a segment [t_min, t_max] that the caller
// already clipped to a box inside the cube (the ray caster's clip box, in
// octree coordinates): not clipped again, so the first leaf is entered at t_min
// and the last one left at t_max, exactly. A second clip, to the cube, computes
// the same entry another way where the two boxes share a face, and rounds to
// either side of it (the ray caster lost its first sample, at t_min, where it
// rounded above). A start point off the cube by rounding is located in the
// leaf at that face. Flushes |d| < 1e-30 to 0.
fn oct_begin_inside(origin: vec3<f32>, dir_in: vec3<f32>, t_min: f32, t_max: f32, max_steps: u32, splits: vec2<u32>) -> OctState {
    var st: OctState;
    let d = select(dir_in, vec3<f32>(0.0), abs(dir_in) < vec3<f32>(OCT_DIR_EPSILON));
    let nz = d != vec3<f32>(0.0);
    st.origin = origin;
    st.dir = d;
    st.inv_dir = select(vec3<f32>(0.0), vec3<f32>(1.0) / select(vec3<f32>(1.0), d, nz), nz);
    st.t = t_min;
    st.t_end = t_max;
    st.cur = OctBox(0u, 0u, vec3<f32>(0.0), vec3<f32>(1.0));
    st.splits = splits;
    if (!(t_min < t_max)) {
        st.cur.node = OCT_NULL;
    }
    st.steps = 0u;
    st.max_steps = max_steps;
    st.status = OCT_STATUS_RUNNING;
    return st;
}

// Rust: traverse_with. oct_begin_inside over [t_min, t_max] clipped to the cube.
fn oct_begin(origin: vec3<f32>, dir_in: vec3<f32>, t_min: f32, t_max: f32, max_steps: u32, splits: vec2<u32>) -> OctState {
    var st = oct_begin_inside(origin, dir_in, t_min, t_max, max_steps, splits);
    let tc = oct_clip_unit_cube(origin, st.dir, st.inv_dir, t_min, t_max);
    st.t = tc.x;
    st.t_end = tc.y;
    st.cur.node = select(0u, OCT_NULL, !(tc.x < tc.y));
    return st;
}

// Rust: locate_leaf_with. Down traversal from `start` to the leaf containing p by
// box subdivision of the level's split axes; a tie (p == mid) goes to the side dir
// moves into (upper if 0). The child index takes the split axes' bits in order.
fn oct_locate_leaf(start: OctBox, p: vec3<f32>, dir: vec3<f32>, splits: vec2<u32>) -> OctLocated {
    var r: OctLocated;
    var c = start;
    r.ok = false;
    r.word = OCT_NULL;
    if (!oct_in_bounds(c.node)) {
        r.leaf = c;
        return r;
    }
    var word = oct_word(c.node);
    for (var i = 0u; i <= OCT_MAX_LEVEL; i = i + 1u) {
        if ((word >> OCT_TAG_SHIFT) != OCT_TAG_INNER) {
            let tag = word >> OCT_TAG_SHIFT;
            r.leaf = c;
            r.word = word;
            r.ok = tag == OCT_TAG_EMPTY || tag == OCT_TAG_DATA;
            return r;
        }
        if (c.level >= OCT_MAX_LEVEL) {
            break;
        }
        let m = oct_mask(splits, c.level);
        let split = (vec3<u32>(m) & vec3<u32>(1u, 2u, 4u)) != vec3<u32>(0u);
        c.box_size = select(c.box_size, c.box_size * 0.5, split);
        let mid = c.box_min + c.box_size;
        let s = split & ((p > mid) | ((p == mid) & (dir >= vec3<f32>(0.0))));
        c.box_min = c.box_min + select(vec3<f32>(0.0), c.box_size, s);
        let si = select(vec3<u32>(0u), vec3<u32>(1u), s);
        c.node = (word & OCT_PTR_MASK) + si.x + (si.y << (m & 1u)) + (si.z << countOneBits(m & 3u));
        c.level = c.level + 1u;
        if (!oct_in_bounds(c.node)) {
            break;
        }
        word = oct_word(c.node);
    }
    r.leaf = c;
    return r;
}

// Rust: exit_face. Smallest exit t over the far planes; ties to the lowest axis.
// face = 2 * axis + (dir[axis] > 0): 0 -x, 1 +x, 2 -y, 3 +y, 4 -z, 5 +z.
fn oct_exit_face(c: OctBox, origin: vec3<f32>, dir: vec3<f32>, inv_dir: vec3<f32>) -> OctExit {
    let pos = dir > vec3<f32>(0.0);
    let far = c.box_min + select(vec3<f32>(0.0), c.box_size, pos);
    let tf = select(vec3<f32>(OCT_T_BIG), (far - origin) * inv_dir, dir != vec3<f32>(0.0));
    var e: OctExit;
    e.t = tf.x;
    e.face = select(0u, 1u, pos.x);
    if (tf.y < e.t) {
        e.t = tf.y;
        e.face = select(2u, 3u, pos.y);
    }
    if (tf.z < e.t) {
        e.t = tf.z;
        e.face = select(4u, 5u, pos.z);
    }
    return e;
}

// Rust: follow_rope_with. The neighbour's box from the current box and the rope's
// level: shift by one box along the face, then snap to the coarser grid (per
// axis, 2^-halvings). next.node == OCT_NULL for a NULL rope (the cube boundary).
fn oct_follow_rope(rope: u32, c: OctBox, face: u32, splits: vec2<u32>) -> OctRope {
    var r: OctRope;
    r.next = c;
    r.ok = true;
    if (rope == OCT_NULL) {
        r.next.node = OCT_NULL;
        return r;
    }
    let level = rope >> OCT_ROPE_LEVEL_SHIFT;
    if (level > c.level || face > 5u) {
        r.ok = false;
        return r;
    }
    let axis = face / 2u;
    var m = c.box_min;
    m[axis] = m[axis] + select(-c.box_size[axis], c.box_size[axis], (face & 1u) == 1u);
    var size = c.box_size;
    if (level < c.level) {
        let h = oct_halvings(splits, level);
        size = vec3<f32>(oct_exp2_neg(h.x), oct_exp2_neg(h.y), oct_exp2_neg(h.z));
        m = floor(m * vec3<f32>(oct_exp2_pos(h.x), oct_exp2_pos(h.y), oct_exp2_pos(h.z))) * size;
    }
    r.next = OctBox(rope & OCT_ROPE_NODE_MASK, level, m, size);
    return r;
}

// Rust: Traversal::next. Advances to the next leaf with t_exit > t_enter and
// stores it in st.hit; false when the traversal ended (see st.status).
// Zero-length visits (edges, corners, rounding) count as steps, are not reported.
fn oct_next_leaf(st: ptr<function, OctState>) -> bool {
    loop {
        if ((*st).status != OCT_STATUS_RUNNING) {
            return false;
        }
        if ((*st).cur.node == OCT_NULL) {
            (*st).status = OCT_STATUS_FINISHED;
            return false;
        }
        if ((*st).steps >= (*st).max_steps) {
            (*st).status = OCT_STATUS_STEP_LIMIT;
            return false;
        }
        (*st).steps = (*st).steps + 1u;
        let p = (*st).origin + (*st).dir * (*st).t;
        let loc = oct_locate_leaf((*st).cur, p, (*st).dir, (*st).splits);
        if (!loc.ok) {
            (*st).status = OCT_STATUS_CORRUPT;
            return false;
        }
        let ex = oct_exit_face(loc.leaf, (*st).origin, (*st).dir, (*st).inv_dir);
        var t_exit = ex.t;
        let record = loc.word & OCT_PTR_MASK;
        var rope = OCT_NULL;
        if (t_exit < (*st).t_end) {
            if (!oct_in_bounds(record + 1u + ex.face)) {
                (*st).status = OCT_STATUS_CORRUPT;
                return false;
            }
            rope = oct_word(record + 1u + ex.face);
        }
        // The walk ends in this leaf (a NULL rope: t_end reached, or the leaf
        // left through the cube's face): it is left at t_end. After oct_begin
        // the cube's exit is t_end; after oct_begin_inside the caller's end,
        // which the cube's face only equals up to rounding.
        if (rope == OCT_NULL) {
            t_exit = (*st).t_end;
        }
        let t_enter = (*st).t;
        t_exit = max(t_exit, t_enter);
        let tag = loc.word >> OCT_TAG_SHIFT;
        var data = OCT_NULL;
        if (tag == OCT_TAG_DATA) {
            if (!oct_in_bounds(record)) {
                (*st).status = OCT_STATUS_CORRUPT;
                return false;
            }
            data = oct_word(record);
        }
        let fr = oct_follow_rope(rope, loc.leaf, ex.face, (*st).splits);
        if (!fr.ok) {
            (*st).status = OCT_STATUS_CORRUPT;
            return false;
        }
        (*st).cur = fr.next;
        (*st).t = t_exit;
        if (t_exit > t_enter) {
            (*st).hit = OctLeaf(loc.leaf, tag, data, t_enter, t_exit);
            return true;
        }
    }
    return false;
}
