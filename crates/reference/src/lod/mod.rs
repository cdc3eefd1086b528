//! CPU models of level-of-detail cuts, for tests and benchmarks.
//!
//! The out-of-core renderer draws a *cut* of a brick octree: a set of
//! leaves covering the volume, each drawn from its own stored brick. These
//! models compute, on the CPU and from any [`BrickSource`], what such a cut
//! shows, so that the f64 reference ([`render_reference`](crate::render_reference))
//! can render it and the image metrics compare cuts:
//!
//! * [`refine_cut`] / [`cut_volume`]: a cut refined once from the root with
//!   every brick available ([`AllAvailable`]; only the tolerance, the budget
//!   of data leaves and the metric limit it), and its leaves resampled onto
//!   the finest grid;
//! * [`Resampler`]: samples leaves' stored bricks onto the finest grid as the
//!   out-of-core kernel samples them (trilinear inside each leaf's brick,
//!   apron included); [`Resampler::splice`] draws one node instead of its
//!   descendants; [`typed`] stores a resampling as the source's type;
//! * [`octant_cut`]: octant-granular cuts (a node's children refined one at
//!   a time, those not refined drawn from their parent's brick), ranked by
//!   [`OctantError`]; [`data_error`] measures a node's error on the data;
//! * [`node_costs`]: the LOD oracle, each node above the finest cut costed
//!   by the squared RGB error ([`sse`]) of the image when it is drawn instead
//!   of its descendants ([`node_costs_spread`]: with the levels' spreads);
//!   [`spearman`] compares rankings.
//!
//! Every function reports a failing source or inconsistent input as a
//! [`LodModelError`]; none panics on bad input.
//!
//! [`BrickSource`]: brickray_core::BrickSource

mod cut;
mod octant;
mod oracle;
#[cfg(test)]
mod tests;

pub use cut::{AllAvailable, CutView, CutVolume, Resampler, cut_volume, refine_cut, typed};
pub use octant::{OctantCut, OctantError, data_error, octant_cut};
pub use oracle::{NodeCost, node_costs, node_costs_spread, nodes_above, spearman, sse};

use brickray_core::{BrickError, DType, NodeKey, VolumeError};

/// What the models of cuts report instead of a result.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LodModelError {
    /// Reading a node's metadata or brick from the source failed.
    #[error("reading the brick source: {0}")]
    Brick(#[from] BrickError),
    /// The key's level is not one of the octree's.
    #[error("node {key:?} is below the octree's finest level ({levels} levels)")]
    NotInOctree {
        /// The key.
        key: NodeKey,
        /// The octree's levels.
        levels: u8,
    },
    /// A finest voxel lies in no node of the set resampled.
    #[error("finest voxel {voxel:?} lies in no node of the cut")]
    Uncovered {
        /// The voxel.
        voxel: [u32; 3],
    },
    /// A finest-grid buffer does not hold one sample per finest voxel.
    #[error("{actual} samples given for a finest grid of {dims:?} ({expected} voxels)")]
    SampleCount {
        /// The source's dimensions.
        dims: [u32; 3],
        /// Samples needed.
        expected: usize,
        /// Samples given.
        actual: usize,
    },
    /// A volume given with the source has other dimensions than the source.
    #[error("volume of dims {actual:?} given for a source of dims {expected:?}")]
    DimsMismatch {
        /// The source's dimensions.
        expected: [u32; 3],
        /// The volume's.
        actual: [u32; 3],
    },
    /// The source's sample type has no resampling (label volumes, `u32`).
    #[error("no resampling for {dtype:?} volumes")]
    UnsupportedDType {
        /// The type.
        dtype: DType,
    },
    /// The source holds several channels per brick; the models resample one.
    #[error("the source holds {channels} channels; the LOD models resample one")]
    MultiChannel {
        /// The source's channels.
        channels: usize,
    },
    /// The source's stored bricks are too small to interpolate in.
    #[error("stored bricks of side {stored_side}: trilinear sampling needs at least 2")]
    BrickTooSmall {
        /// Stored voxels per brick side (interior and apron).
        stored_side: u32,
    },
    /// Two images to compare have different sizes.
    #[error("image of {actual} bytes, the finest cut's has {expected}")]
    ImageSize {
        /// The finest cut's image's bytes.
        expected: usize,
        /// The other image's.
        actual: usize,
    },
    /// The resampled volume cannot be represented.
    #[error("resampled volume: {0}")]
    Volume(#[from] VolumeError),
}
