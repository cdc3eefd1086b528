//! The visibility scheduler of brickray (Gobbetti et al. 2008, section 6), GPU-free.
//!
//! Early ray termination saves samples but not memory: without feedback the
//! loader refines every brick in the frustum whose value range the transfer
//! function shows, including bricks hidden behind opaque material. This crate
//! holds what the renderer learns about which bricks the image actually uses,
//! and what refinement is allowed to do with it:
//!
//! * [`VisibilityState`]: per data leaf of the last cut, when it was last
//!   observed and last seen visible (observations arrive a few frames late,
//!   from either feedback path); an inner node is visible when a leaf below it
//!   is (propagated to the root); a node never observed is visible. Refinement
//!   splits only nodes [`VisibilityState::visible`] says are visible: an
//!   invisible node stays a leaf at the level it has (never a hole) and posts
//!   no load request.
//! * [`schedule_tiles`]: the screen-tile scheduler of section 6: with a budget
//!   of occlusion queries per frame, median splits along alternating axes
//!   isolate a subset of projected leaf rectangles inside one tile; the subsets
//!   rotate so every on-screen leaf is queried within
//!   [`TileSchedule::period`] frames.
//! * [`VisibleWeights`]: what the image shows of each node (the ray caster's
//!   transmittance-weighted ray length through it), summed to the root and
//!   spread to the nodes a split would create, for refinement ranked by
//!   the image change a node makes (`LodMetric::VisibleError`).
//! * [`VisibilityPolicy`]: the switch between no feedback, occlusion queries,
//!   ray-guided usage feedback, or both.
//!
//! See `docs/visibility.md` for the design and what each policy does per mode.

mod policy;
mod state;
mod tiles;
mod weights;

pub use policy::VisibilityPolicy;
pub use state::{VisibilityConfig, VisibilityCounts, VisibilityState};
pub use tiles::{PxRect, TileSchedule, TileSchedulerConfig, schedule_tiles};
pub use weights::{MAX_COLLAPSES, VisibleWeights};
