//! The octree-with-ropes spatial index of the out-of-core ray caster (Gobbetti et
//! al. 2008, section 5), GPU-free.
//!
//! * [`encode_cut`] validates a *cut* ([`CutLeaf`]s tiling the unit cube, each
//!   [`LeafKind::Empty`] or [`LeafKind::Data`] with a brick-pool slot; the cut
//!   vocabulary lives in [`brickray_core::brick`] and is re-exported here) and
//!   encodes the octree with neighbour pointers as `u32` words for a GPU storage
//!   buffer ([`format`](mod@format), `docs/index-format.md`).
//! * [`traverse`] is the CPU twin of the GPU traversal: it reads the same words
//!   as `shaders/octree_traversal.wgsl` ([`OCTREE_TRAVERSAL_WGSL`]) and enumerates
//!   the leaves pierced by a ray front to back, following ropes without a stack.
//!
//! ```
//! use brickray_core::brick::NodeKey;
//! use brickray_index::{CutLeaf, EmptyReason, Ray, encode_cut, traverse};
//! use glam::Vec3;
//!
//! // The root split once; child 0 holds brick 7, the rest is empty.
//! let cut = NodeKey::ROOT.children().map(|k| {
//!     if k.child_index() == 0 {
//!         CutLeaf::data(k, 7)
//!     } else {
//!         CutLeaf::empty(k, EmptyReason::Empty)
//!     }
//! });
//! let index = encode_cut(cut).unwrap();
//! assert_eq!(index.stats().nodes, 9);
//! let ray = Ray::new(Vec3::new(-1.0, 0.25, 0.25), Vec3::X);
//! let hits: Vec<_> = traverse(index.words(), ray, 64).collect();
//! assert_eq!(hits.len(), 2);
//! assert_eq!(hits[0].slot, Some(7));
//! assert_eq!(hits[1].slot, None);
//! assert_eq!((hits[0].t_enter, hits[0].t_exit, hits[1].t_exit), (1.0, 1.5, 2.0));
//! ```

pub mod format;

mod cut;
mod traverse;

pub use brickray_core::brick::{CutLeaf, EmptyReason, LeafKind};
pub use cut::{CutError, EncodedIndex, IndexStats, encode_cut, encode_cut_with};
pub use format::Splits;
pub use traverse::{
    CorruptIndex, DIR_EPSILON, LeafHit, NodeBox, Ray, T_BIG, Traversal, TraversalStatus,
    clip_unit_cube, exit_face, follow_rope, follow_rope_with, locate_leaf, locate_leaf_with,
    ray_setup, traverse, traverse_with,
};

/// The WGSL traversal library (`crates/index/shaders/octree_traversal.wgsl`). It declares no
/// bindings: the including shader provides the index's words with
/// `fn oct_word(i: u32) -> u32` and `fn oct_word_count() -> u32` (from a
/// storage buffer, a texture, ...). Its override `OCT_OCTREE` (default
/// false) folds the split masks away where the index is an octree.
pub const OCTREE_TRAVERSAL_WGSL: &str = include_str!("../shaders/octree_traversal.wgsl");
