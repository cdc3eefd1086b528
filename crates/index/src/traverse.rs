//! The CPU twin of the GPU traversal (Gobbetti et al. 2008, Fig. 5): a stackless,
//! rope-following walk over the *encoded words*, enumerating the leaves pierced
//! by a ray front to back.
//!
//! Every function here has a line-by-line counterpart in
//! `shaders/octree_traversal.wgsl` (`oct_` prefix there): plain loops with
//! constant bounds, `f32` math, no recursion, no allocation. Keep them in sync.
//!
//! # Tie rules (see `docs/index-format.md`)
//! * **Zero direction components**: a component with `|d| < 1e-30` is flushed to
//!   exactly 0 ([`ray_setup`]). Along such an axis boxes are half-open
//!   `[min, max)`: a ray lying exactly in the plane between two nodes belongs to
//!   the upper one, and a ray in the plane `1.0` misses the cube.
//! * **Locating a point on a child boundary** ([`locate_leaf`]): per axis the
//!   upper child is taken when `p > mid`, or `p == mid` and `d >= 0`; i.e. ties go
//!   to the side the ray moves into (upper for a zero component). Exact, no epsilon.
//! * **Exit through an edge or corner** ([`exit_face`]): the smallest exit `t`
//!   wins, ties to the lowest axis (x, then y, then z). The rope of that face leads
//!   to a node that touches the exit point; locating the exit point there lands
//!   in a leaf whose exit is (up to rounding) the same `t`, which is left through
//!   the next axis. Such zero-length visits, and any visit with `t_exit <= t_enter`
//!   caused by rounding, count as steps but are not reported: only leaves with
//!   `t_exit > t_enter` are yielded, and consecutive yields share the boundary
//!   `t` exactly (`t_enter` of one is `t_exit` of the previous).
//! * **Ends**: [`traverse`] clips `[t_min, t_max]` to the cube;
//!   [`Traversal::inside`] keeps a segment the caller already clipped to a box
//!   inside the cube, so its first leaf is entered at `t_min` and its last left
//!   at `t_max` exactly (the ray caster samples from its own `t_min`; a second
//!   clip computed a shared face's entry another way, rounded above it and
//!   lost the first sample). Either way a leaf whose exit face is on the
//!   cube's boundary (a NULL rope) is left at the walk's end.

use crate::format::{
    MAX_LEVEL, NULL, ROPE_LEVEL_SHIFT, ROPE_NODE_MASK, Splits, TAG_DATA, TAG_EMPTY, TAG_INNER,
    exp2_neg, exp2_pos, node_ptr, node_tag,
};
use brickray_core::brick::NodeKey;
use glam::{BVec3, Vec3};

/// Direction components with a smaller magnitude are treated as exactly zero.
pub const DIR_EPSILON: f32 = 1e-30;
/// "No exit along this axis" (`t` of a zero direction component).
pub const T_BIG: f32 = 3.0e38;

/// A ray in octree unit-cube coordinates; the points `origin + dir * t` for `t` in
/// `[t_min, t_max]` (`t_max` may be infinite; `dir` need not be normalised).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    /// Origin.
    pub origin: Vec3,
    /// Direction.
    pub dir: Vec3,
    /// Start parameter.
    pub t_min: f32,
    /// End parameter.
    pub t_max: f32,
}

impl Ray {
    /// A ray over `t` in `[0, inf)`.
    pub fn new(origin: Vec3, dir: Vec3) -> Ray {
        Ray {
            origin,
            dir,
            t_min: 0.0,
            t_max: f32::INFINITY,
        }
    }

    /// The same ray over `t` in `[t_min, t_max]`.
    pub fn with_range(self, t_min: f32, t_max: f32) -> Ray {
        Ray {
            t_min,
            t_max,
            ..self
        }
    }
}

/// A node and its box: the cursor of the traversal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NodeBox {
    /// Node index (position of its node word).
    pub node: u32,
    /// Octree level of the node.
    pub level: u32,
    /// Minimum corner of the node's box.
    pub box_min: Vec3,
    /// Sides of the node's box: `2^-level` on every axis in the octree,
    /// `2^-halvings[a]` per axis with split masks ([`Splits::halvings`]).
    pub box_size: Vec3,
}

impl NodeBox {
    /// The root: node 0, the unit cube.
    pub const ROOT: NodeBox = NodeBox {
        node: 0,
        level: 0,
        box_min: Vec3::ZERO,
        box_size: Vec3::ONE,
    };

    /// The node's key, from its box (exact: corners are multiples of `2^-level`).
    pub fn key(&self) -> NodeKey {
        let k = self.box_min * exp2_pos(self.level);
        NodeKey::new(self.level as u8, k.x as u32, k.y as u32, k.z as u32)
    }

    /// The node's key in an octree with split masks (exact: corners are
    /// multiples of the box sizes).
    pub fn key_with(&self, splits: Splits) -> NodeKey {
        let h = splits.halvings(self.level);
        let k: [u32; 3] = std::array::from_fn(|a| (self.box_min[a] * exp2_pos(h[a])) as u32);
        NodeKey::new(self.level as u8, k[0], k[1], k[2])
    }
}

/// The encoded words are malformed (out-of-range pointer, bad tag, too deep).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CorruptIndex;

#[inline]
fn read(words: &[u32], i: u32) -> Result<u32, CorruptIndex> {
    words.get(i as usize).copied().ok_or(CorruptIndex)
}

/// Ray setup: flushes tiny direction components to zero and returns
/// `(dir, inv_dir)` with `inv_dir = 0` on zero components.
pub fn ray_setup(dir: Vec3) -> (Vec3, Vec3) {
    let d = Vec3::select(dir.abs().cmplt(Vec3::splat(DIR_EPSILON)), Vec3::ZERO, dir);
    let nonzero = d.cmpne(Vec3::ZERO);
    let inv = Vec3::select(
        nonzero,
        Vec3::ONE / Vec3::select(nonzero, d, Vec3::ONE),
        Vec3::ZERO,
    );
    (d, inv)
}

/// Clips `[t_min, t_max]` to the unit cube (half-open along zero components).
/// Returns `(t0, t1)`; the ray misses when `!(t0 < t1)`.
pub fn clip_unit_cube(
    origin: Vec3,
    dir: Vec3,
    inv_dir: Vec3,
    t_min: f32,
    t_max: f32,
) -> (f32, f32) {
    let mut t0 = t_min;
    let mut t1 = t_max;
    if dir == Vec3::ZERO {
        return (1.0, 0.0);
    }
    for a in 0..3 {
        let o = origin[a];
        if dir[a] == 0.0 {
            if !(0.0..1.0).contains(&o) {
                return (1.0, 0.0);
            }
        } else {
            let ta = (0.0 - o) * inv_dir[a];
            let tb = (1.0 - o) * inv_dir[a];
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
    }
    (t0, t1)
}

/// Descends from `start` to the leaf containing `p` (box subdivision, Fig. 5);
/// ties on a child boundary go to the side `dir` moves into (upper when the
/// component is zero). Returns the leaf and its node word.
pub fn locate_leaf(
    words: &[u32],
    start: NodeBox,
    p: Vec3,
    dir: Vec3,
) -> Result<(NodeBox, u32), CorruptIndex> {
    locate_leaf_with(words, Splits::ALL, start, p, dir)
}

/// [`locate_leaf`] with split masks: a level's descent halves only its split
/// axes, and the child index takes their bits in the order x, y, z.
pub fn locate_leaf_with(
    words: &[u32],
    splits: Splits,
    start: NodeBox,
    p: Vec3,
    dir: Vec3,
) -> Result<(NodeBox, u32), CorruptIndex> {
    let mut c = start;
    let mut word = read(words, c.node)?;
    for _ in 0..=MAX_LEVEL {
        if node_tag(word) != TAG_INNER {
            let tag = node_tag(word);
            return if tag == TAG_EMPTY || tag == TAG_DATA {
                Ok((c, word))
            } else {
                Err(CorruptIndex)
            };
        }
        if c.level >= MAX_LEVEL as u32 {
            break;
        }
        let m = splits.mask(c.level);
        let split = BVec3::new(m & 1 != 0, m & 2 != 0, m & 4 != 0);
        c.box_size = Vec3::select(split, c.box_size * 0.5, c.box_size);
        let mid = c.box_min + c.box_size;
        let s: BVec3 = split & (p.cmpgt(mid) | (p.cmpeq(mid) & dir.cmpge(Vec3::ZERO)));
        c.box_min += Vec3::select(s, c.box_size, Vec3::ZERO);
        // Bit of each split axis: its rank among the split axes.
        let ci = s.x as u32 + ((s.y as u32) << (m & 1)) + ((s.z as u32) << (m & 3).count_ones());
        c.node = node_ptr(word) + ci;
        c.level += 1;
        word = read(words, c.node)?;
    }
    Err(CorruptIndex)
}

/// Exit of the ray from box `c`: `(t_exit, face)`, face `2 * axis + (dir > 0)`.
/// The smallest `t` wins; ties go to the lowest axis. `t_exit` is [`T_BIG`] when
/// the direction is zero.
pub fn exit_face(c: &NodeBox, origin: Vec3, dir: Vec3, inv_dir: Vec3) -> (f32, u32) {
    let pos = dir.cmpgt(Vec3::ZERO);
    let far = c.box_min + Vec3::select(pos, c.box_size, Vec3::ZERO);
    let tf = Vec3::select(
        dir.cmpne(Vec3::ZERO),
        (far - origin) * inv_dir,
        Vec3::splat(T_BIG),
    );
    let mut t = tf.x;
    let mut face = pos.x as u32;
    if tf.y < t {
        t = tf.y;
        face = 2 + pos.y as u32;
    }
    if tf.z < t {
        t = tf.z;
        face = 4 + pos.z as u32;
    }
    (t, face)
}

/// Follows `rope` (the word at `leaf record + 1 + face`) out of box `c`: the
/// neighbour's node and box, computed from `c` and the neighbour's level (shift
/// by one box along the face, then snap to the coarser grid). `Ok(None)` for NULL.
pub fn follow_rope(rope: u32, c: &NodeBox, face: u32) -> Result<Option<NodeBox>, CorruptIndex> {
    follow_rope_with(rope, c, face, Splits::ALL)
}

/// [`follow_rope`] with split masks: the coarser box is snapped per axis to the
/// neighbour level's grid, `2^-halvings[a]`.
pub fn follow_rope_with(
    rope: u32,
    c: &NodeBox,
    face: u32,
    splits: Splits,
) -> Result<Option<NodeBox>, CorruptIndex> {
    if rope == NULL {
        return Ok(None);
    }
    let level = rope >> ROPE_LEVEL_SHIFT;
    if level > c.level || face > 5 {
        return Err(CorruptIndex);
    }
    let mut n = *c;
    let axis = (face / 2) as usize;
    n.box_min[axis] += if face & 1 == 1 {
        n.box_size[axis]
    } else {
        -n.box_size[axis]
    };
    if level < c.level {
        let h = splits.halvings(level);
        let up = Vec3::new(exp2_pos(h[0]), exp2_pos(h[1]), exp2_pos(h[2]));
        n.box_size = Vec3::new(exp2_neg(h[0]), exp2_neg(h[1]), exp2_neg(h[2]));
        n.box_min = (n.box_min * up).floor() * n.box_size;
    }
    n.level = level;
    n.node = rope & ROPE_NODE_MASK;
    Ok(Some(n))
}

/// One leaf pierced by the ray.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LeafHit {
    /// The leaf's node, level and box.
    pub leaf: NodeBox,
    /// The brick-pool slot of a data leaf, `None` for an empty leaf (the index
    /// does not keep why a leaf is empty).
    pub slot: Option<u32>,
    /// Ray parameter where the ray enters the leaf (the previous leaf's `t_exit`).
    pub t_enter: f32,
    /// Ray parameter where it leaves (`> t_enter`).
    pub t_exit: f32,
}

impl LeafHit {
    /// The leaf's key.
    pub fn key(&self) -> NodeKey {
        self.leaf.key()
    }
}

/// How a traversal stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TraversalStatus {
    /// More leaves may follow.
    Running,
    /// The ray left the cube or reached `t_max`: every leaf was reported.
    Finished,
    /// The step bound was reached before the end.
    StepLimit,
    /// The words are malformed; traversal stopped.
    Corrupt,
}

/// Iterator over the leaves pierced by a ray, front to back (see [`traverse`]).
#[derive(Debug, Clone)]
pub struct Traversal<'a> {
    words: &'a [u32],
    origin: Vec3,
    dir: Vec3,
    inv_dir: Vec3,
    t: f32,
    t_end: f32,
    /// Where to locate next; `node == NULL` when done.
    cur: NodeBox,
    steps: u32,
    max_steps: u32,
    status: TraversalStatus,
    splits: Splits,
}

/// Walks the encoded index `words` along `ray`, front to back. Each visited leaf
/// (reported or not, see the tie rules) costs one step; after `max_steps` steps
/// the iterator ends with [`TraversalStatus::StepLimit`].
pub fn traverse(words: &[u32], ray: Ray, max_steps: u32) -> Traversal<'_> {
    traverse_with(words, Splits::ALL, ray, max_steps)
}

/// [`traverse`] over an index encoded with split masks
/// ([`encode_cut_with`](crate::encode_cut_with)); the same `splits` must be given.
/// With [`Splits::ALL`] this is `traverse`.
pub fn traverse_with(words: &[u32], splits: Splits, ray: Ray, max_steps: u32) -> Traversal<'_> {
    let mut tr = Traversal::inside(words, splits, ray, max_steps);
    let (t0, t1) = clip_unit_cube(ray.origin, tr.dir, tr.inv_dir, ray.t_min, ray.t_max);
    tr.t = t0;
    tr.t_end = t1;
    // `!(t0 < t1)` also catches NaN.
    tr.cur.node = if t0 < t1 { NodeBox::ROOT.node } else { NULL };
    tr
}

impl<'a> Traversal<'a> {
    /// A walk over a segment `[t_min, t_max]` that the caller already clipped
    /// to a box inside the unit cube (WGSL `oct_begin_inside`; the ray
    /// caster's clip box in octree coordinates): not clipped again, so the
    /// first reported leaf has `t_enter == ray.t_min` and the last one
    /// `t_exit == ray.t_max`, exactly. [`traverse_with`] clips to the cube,
    /// which computes the entry through a face the box shares with the cube a
    /// second way, and rounds to either side of the caller's (the ray caster
    /// lost its first sample, at `t_min`, where it rounded above). A start
    /// point off the cube by rounding is located in the leaf at that face. The
    /// segment must be finite; parts of it outside the cube are attributed to
    /// the leaves at the faces.
    pub fn inside(words: &'a [u32], splits: Splits, ray: Ray, max_steps: u32) -> Traversal<'a> {
        let (dir, inv_dir) = ray_setup(ray.dir);
        let mut cur = NodeBox::ROOT;
        // A NaN end misses too.
        let hit = ray.t_min < ray.t_max;
        if !hit {
            cur.node = NULL;
        }
        Traversal {
            words,
            origin: ray.origin,
            dir,
            inv_dir,
            t: ray.t_min,
            t_end: ray.t_max,
            cur,
            steps: 0,
            max_steps,
            status: TraversalStatus::Running,
            splits,
        }
    }
}

impl Traversal<'_> {
    /// Current status (`Running` until the iterator has returned `None`).
    pub fn status(&self) -> TraversalStatus {
        self.status
    }

    /// Steps (leaf visits) taken so far.
    pub fn steps(&self) -> u32 {
        self.steps
    }

    fn step(&mut self) -> Result<Option<LeafHit>, CorruptIndex> {
        let p = self.origin + self.dir * self.t;
        let (leaf, word) = locate_leaf_with(self.words, self.splits, self.cur, p, self.dir)?;
        let (mut t_exit, face) = exit_face(&leaf, self.origin, self.dir, self.inv_dir);
        let record = node_ptr(word);
        let mut rope = NULL;
        if t_exit < self.t_end {
            rope = read(self.words, record + 1 + face)?;
        }
        // The walk ends in this leaf (a NULL rope: `t_end` reached, or the leaf
        // left through the cube's face): it is left at `t_end`. After the clip
        // of [`traverse_with`] the cube's exit is `t_end`; after
        // [`Traversal::inside`] the caller's end, which the cube's face only
        // equals up to rounding.
        if rope == NULL {
            t_exit = self.t_end;
        }
        let t_enter = self.t;
        t_exit = t_exit.max(t_enter);
        let slot = if node_tag(word) == TAG_DATA {
            Some(read(self.words, record)?)
        } else {
            None
        };
        match follow_rope_with(rope, &leaf, face, self.splits)? {
            Some(n) => self.cur = n,
            None => self.cur.node = NULL,
        }
        self.t = t_exit;
        Ok((t_exit > t_enter).then_some(LeafHit {
            leaf,
            slot,
            t_enter,
            t_exit,
        }))
    }
}

impl Iterator for Traversal<'_> {
    type Item = LeafHit;

    fn next(&mut self) -> Option<LeafHit> {
        // Bounded by max_steps: every iteration takes a step or returns.
        loop {
            if self.status != TraversalStatus::Running {
                return None;
            }
            if self.cur.node == NULL {
                self.status = TraversalStatus::Finished;
                return None;
            }
            if self.steps >= self.max_steps {
                self.status = TraversalStatus::StepLimit;
                return None;
            }
            self.steps += 1;
            match self.step() {
                Ok(Some(hit)) => return Some(hit),
                Ok(None) => {}
                Err(CorruptIndex) => {
                    self.status = TraversalStatus::Corrupt;
                    return None;
                }
            }
        }
    }
}

impl std::iter::FusedIterator for Traversal<'_> {}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::{FACE_NEG_X, FACE_POS_X, FACE_POS_Y, FACE_POS_Z, rope_word};

    fn nb(level: u32, min: [f32; 3]) -> NodeBox {
        NodeBox {
            node: 0,
            level,
            box_min: Vec3::from(min),
            box_size: Vec3::splat(exp2_neg(level)),
        }
    }

    #[test]
    fn exit_face_prefers_smallest_t_then_lowest_axis() {
        let c = nb(1, [0.0, 0.0, 0.0]);
        let (dir, inv) = ray_setup(Vec3::new(1.0, 2.0, 0.0));
        assert_eq!(
            exit_face(&c, Vec3::new(0.1, 0.1, 0.1), dir, inv),
            (0.2, FACE_POS_Y)
        );
        // Through the corner: x, y and z tie at t = 0.5, x wins.
        let (dir, inv) = ray_setup(Vec3::ONE);
        assert_eq!(exit_face(&c, Vec3::ZERO, dir, inv), (0.5, FACE_POS_X));
        let (dir, inv) = ray_setup(Vec3::new(0.0, 1.0, 1.0));
        assert_eq!(exit_face(&c, Vec3::ZERO, dir, inv), (0.5, FACE_POS_Y));
        let (dir, inv) = ray_setup(Vec3::new(-1.0, 0.0, 1e-31));
        assert_eq!(dir, Vec3::new(-1.0, 0.0, 0.0));
        assert_eq!(
            exit_face(&c, Vec3::new(0.25, 0.1, 0.1), dir, inv),
            (0.25, FACE_NEG_X)
        );
        let (dir, inv) = ray_setup(Vec3::new(0.0, 0.0, 0.5));
        assert_eq!(
            exit_face(&c, Vec3::new(0.25, 0.1, 0.0), dir, inv),
            (1.0, FACE_POS_Z)
        );
    }

    #[test]
    fn locate_ties_follow_the_direction() {
        // Root split once: nodes 1..9 are leaves.
        let mut words = vec![crate::format::node_word(TAG_INNER, 1)];
        for i in 0..8 {
            words.push(crate::format::node_word(TAG_EMPTY, 9 + 7 * i));
        }
        words.resize(9 + 56, NULL);
        let p = Vec3::splat(0.5);
        let at = |d: Vec3| locate_leaf(&words, NodeBox::ROOT, p, d).unwrap().0;
        assert_eq!(at(Vec3::new(1.0, 1.0, 1.0)).node, 1 + 7);
        assert_eq!(at(Vec3::new(-1.0, -1.0, -1.0)).node, 1);
        assert_eq!(at(Vec3::new(0.0, -1.0, 0.0)).node, 1 + 1 + 4);
        let leaf = at(Vec3::new(-1.0, 1.0, 0.0));
        assert_eq!(
            (leaf.node, leaf.level, leaf.box_min, leaf.box_size),
            (1 + 2 + 4, 1, Vec3::new(0.0, 0.5, 0.5), Vec3::splat(0.5))
        );
        assert_eq!(leaf.key(), NodeKey::new(1, 0, 1, 1));
        // A bad tag is corrupt, as is a pointer past the end.
        let mut bad = words.clone();
        bad[8] = 3 << 30;
        assert_eq!(
            locate_leaf(&bad, NodeBox::ROOT, Vec3::splat(0.9), Vec3::X),
            Err(CorruptIndex)
        );
        bad[0] = crate::format::node_word(TAG_INNER, 1000);
        assert_eq!(
            locate_leaf(&bad, NodeBox::ROOT, Vec3::splat(0.9), Vec3::X),
            Err(CorruptIndex)
        );
    }

    #[test]
    fn follow_rope_shifts_and_snaps_to_the_coarser_grid() {
        // Level-3 box at (5, 2, 7)/8 leaving +x into a level-1 neighbour.
        let c = NodeBox {
            node: 3,
            ..nb(3, [5.0 / 8.0, 2.0 / 8.0, 7.0 / 8.0])
        };
        let n = follow_rope(rope_word(11, 1), &c, FACE_POS_X)
            .unwrap()
            .unwrap();
        assert_eq!(
            (n.node, n.level, n.box_min, n.box_size),
            (11, 1, Vec3::new(0.5, 0.0, 0.5), Vec3::splat(0.5))
        );
        // Same level: a pure shift.
        let n = follow_rope(rope_word(12, 3), &c, FACE_NEG_X)
            .unwrap()
            .unwrap();
        assert_eq!(
            (n.level, n.box_min, n.box_size),
            (
                3,
                Vec3::new(4.0 / 8.0, 2.0 / 8.0, 7.0 / 8.0),
                Vec3::splat(0.125)
            )
        );
        // NULL, and a rope to a finer level is corrupt.
        assert_eq!(follow_rope(NULL, &c, FACE_POS_X), Ok(None));
        assert_eq!(
            follow_rope(rope_word(1, 4), &c, FACE_POS_X),
            Err(CorruptIndex)
        );
    }

    #[test]
    fn clip_is_half_open_along_zero_components() {
        let (d, inv) = ray_setup(Vec3::X);
        assert_eq!(
            clip_unit_cube(Vec3::new(-1.0, 0.0, 0.5), d, inv, 0.0, f32::INFINITY),
            (1.0, 2.0)
        );
        let (t0, t1) = clip_unit_cube(Vec3::new(-1.0, 1.0, 0.5), d, inv, 0.0, f32::INFINITY);
        assert!(t0 >= t1);
        let (d, inv) = ray_setup(Vec3::ZERO);
        let (t0, t1) = clip_unit_cube(Vec3::splat(0.5), d, inv, 0.0, 1.0);
        assert!(t0 >= t1);
        assert_eq!(exp2_pos(3) * exp2_neg(3), 1.0);
    }
}
