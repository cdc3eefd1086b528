//! The word layout of the encoded index (`docs/index-format.md` is the normative
//! description; these constants are its executable form and are mirrored by
//! `shaders/octree_traversal.wgsl`).
//!
//! The index is one `Vec<u32>`:
//!
//! * words `0..node_count`: one **node word** per octree node, in breadth-first
//!   order (the root is word 0; the 8 children of an inner node are consecutive,
//!   child `i` at `first_child + i`, bit 0 = +x, bit 1 = +y, bit 2 = +z).
//!   Bits 31..30 hold the tag ([`TAG_INNER`], [`TAG_EMPTY`], [`TAG_DATA`]), bits
//!   29..0 a pointer: the node index of the first child (inner) or the word index
//!   of the node's leaf record (leaves).
//! * then one **leaf record** of [`LEAF_RECORD_WORDS`] words per leaf, in the same
//!   breadth-first order: word 0 is the data word (the brick-pool slot of a data
//!   leaf, [`NULL`] for an empty one), words `1 + face` are the six rope words for
//!   faces `-x, +x, -y, +y, -z, +z` (face `2 * axis + (positive as u32)`).
//!
//! A rope word is [`NULL`] on the cube boundary, otherwise bits 31..27 hold the
//! level of the neighbour and bits 26..0 its node index.

/// Shift of the 2-bit tag in a node word.
pub const TAG_SHIFT: u32 = 30;
/// Mask of the pointer bits of a node word.
pub const PTR_MASK: u32 = (1 << TAG_SHIFT) - 1;
/// Tag of an inner node (pointer = node index of its first child).
pub const TAG_INNER: u32 = 0;
/// Tag of an empty leaf (pointer = word index of its leaf record).
pub const TAG_EMPTY: u32 = 1;
/// Tag of a data leaf (pointer = word index of its leaf record).
pub const TAG_DATA: u32 = 2;
/// Words per leaf record: the data word and six rope words.
pub const LEAF_RECORD_WORDS: u32 = 7;
/// Shift of the neighbour level in a rope word.
pub const ROPE_LEVEL_SHIFT: u32 = 27;
/// Mask of the node index in a rope word.
pub const ROPE_NODE_MASK: u32 = (1 << ROPE_LEVEL_SHIFT) - 1;
/// The NULL rope / empty data word.
pub const NULL: u32 = u32::MAX;
/// Deepest level the index accepts. The format could hold 30 (the level field
/// has 5 bits and 31 would collide with [`NULL`]); 20 keeps every box corner
/// exactly representable in `f32` with headroom. The `f32` traversal is accurate
/// to about `1e-6` in unit-cube coordinates, so levels beyond ~16 make little sense.
pub const MAX_LEVEL: u8 = 20;
/// Most nodes an index may have (rope node field).
pub const MAX_NODES: usize = ROPE_NODE_MASK as usize + 1;
/// Most words an index may have (node word pointer field).
pub const MAX_WORDS: usize = PTR_MASK as usize + 1;

/// Face `-x`.
pub const FACE_NEG_X: u32 = 0;
/// Face `+x`.
pub const FACE_POS_X: u32 = 1;
/// Face `-y`.
pub const FACE_NEG_Y: u32 = 2;
/// Face `+y`.
pub const FACE_POS_Y: u32 = 3;
/// Face `-z`.
pub const FACE_NEG_Z: u32 = 4;
/// Face `+z`.
pub const FACE_POS_Z: u32 = 5;

/// Builds a node word.
#[inline]
pub const fn node_word(tag: u32, ptr: u32) -> u32 {
    (tag << TAG_SHIFT) | (ptr & PTR_MASK)
}

/// Tag of a node word.
#[inline]
pub const fn node_tag(word: u32) -> u32 {
    word >> TAG_SHIFT
}

/// Pointer of a node word.
#[inline]
pub const fn node_ptr(word: u32) -> u32 {
    word & PTR_MASK
}

/// Builds a rope word for a neighbour at `level` with node index `node`.
#[inline]
pub const fn rope_word(node: u32, level: u8) -> u32 {
    ((level as u32) << ROPE_LEVEL_SHIFT) | (node & ROPE_NODE_MASK)
}

/// Decoded rope: `None` for [`NULL`], else `(neighbour node index, neighbour level)`.
#[inline]
pub const fn decode_rope(word: u32) -> Option<(u32, u8)> {
    if word == NULL {
        None
    } else {
        Some((word & ROPE_NODE_MASK, (word >> ROPE_LEVEL_SHIFT) as u8))
    }
}

/// `2^-level` as an exact `f32` (built from its bits, as the shader does).
#[inline]
pub const fn exp2_neg(level: u32) -> f32 {
    f32::from_bits((127 - level) << 23)
}

/// `2^level` as an exact `f32` (built from its bits, as the shader does).
#[inline]
pub const fn exp2_pos(level: u32) -> f32 {
    f32::from_bits((127 + level) << 23)
}
