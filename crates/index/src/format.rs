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

/// Per-level split masks of an anisotropic octree (see
/// `brickray_core::OctreeLayout::split_mask`), packed 3 bits per level, level 0
/// in the lowest bits: bit 0 = x, 1 = y, 2 = z, the axes along which a node of
/// that level is split. A node of level `l` has `2^popcount(mask(l))` children,
/// consecutive in the index; child `i`'s bits enumerate the split axes in the
/// order x, y, z. [`Splits::ALL`] is the octree (every level splits all axes).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Splits(pub u64);

impl Splits {
    /// Every level splits all three axes: the octree.
    pub const ALL: Splits = Splits((1u64 << (3 * MAX_LEVEL as u64)) - 1);

    /// The masks of `levels` (root first); levels past the end split all axes.
    /// `None` when a mask is not in `1..=7` or there are more than [`MAX_LEVEL`].
    pub fn from_masks(masks: &[u8]) -> Option<Splits> {
        if masks.len() > MAX_LEVEL as usize || masks.iter().any(|m| *m == 0 || *m > 7) {
            return None;
        }
        let mut p = Splits::ALL.0;
        for (l, m) in masks.iter().enumerate() {
            p &= !(7u64 << (3 * l));
            p |= (*m as u64) << (3 * l);
        }
        Some(Splits(p))
    }

    /// The split masks of a layout (`ALL` for the isotropic octree and for
    /// layouts deeper than [`MAX_LEVEL`], whose cuts the encoder refuses anyway).
    pub fn from_layout(layout: &brickray_core::OctreeLayout) -> Splits {
        Splits::from_masks(&layout.split_masks()).unwrap_or(Splits::ALL)
    }

    /// The two words the WGSL traversal takes (`oct_begin`'s `splits`): the
    /// masks of levels 0..10 and 10..20, 3 bits a level.
    pub const fn gpu_words(self) -> [u32; 2] {
        [
            (self.0 & 0x3fff_ffff) as u32,
            ((self.0 >> 30) & 0x3fff_ffff) as u32,
        ]
    }

    /// The mask of `level` (7 from [`MAX_LEVEL`] on).
    #[inline]
    pub const fn mask(self, level: u32) -> u32 {
        if level >= MAX_LEVEL as u32 {
            7
        } else {
            ((self.0 >> (3 * level)) & 7) as u32
        }
    }

    /// Children of a node of `level`.
    #[inline]
    pub const fn child_count(self, level: u32) -> u32 {
        1 << self.mask(level).count_ones()
    }

    /// Per axis, the levels above `level` that split it (node positions along
    /// axis `a` at `level` run over `0..2^halvings[a]`).
    pub fn halvings(self, level: u32) -> [u32; 3] {
        let mut h = [0u32; 3];
        for l in 0..level {
            let m = self.mask(l);
            for (a, ha) in h.iter_mut().enumerate() {
                *ha += (m >> a) & 1;
            }
        }
        h
    }

    /// Child `i` of `key` under these splits.
    pub fn child(self, key: brickray_core::NodeKey, i: u32) -> brickray_core::NodeKey {
        let m = self.mask(key.level as u32);
        let mut p = [key.x, key.y, key.z];
        let mut bit = 0;
        for (a, pa) in p.iter_mut().enumerate() {
            if m & (1 << a) != 0 {
                *pa = *pa * 2 + ((i >> bit) & 1);
                bit += 1;
            }
        }
        brickray_core::NodeKey::new(key.level + 1, p[0], p[1], p[2])
    }

    /// The node's box in unit-cube coordinates: `(min corner, size)` per axis.
    pub fn unit_box(self, key: brickray_core::NodeKey) -> ([f64; 3], [f64; 3]) {
        let h = self.halvings(key.level as u32);
        let p = [key.x, key.y, key.z];
        let size: [f64; 3] = std::array::from_fn(|a| 1.0 / (1u64 << h[a]) as f64);
        (std::array::from_fn(|a| p[a] as f64 * size[a]), size)
    }
}
