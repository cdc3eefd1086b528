//! Out-of-core brick management for brickray, after Gobbetti et al. 2008 (sect. 3
//! and 4), free of any GPU API:
//!
//! * [`CpuCache`]: the level-2 cache of decompressed bricks, LRU within a byte budget;
//! * [`Loader`]: worker threads reading bricks from a
//!   [`BrickSource`](brickray_core::BrickSource) in priority order, with
//!   cancellation and kept failures;
//! * [`BrickPool`]: bookkeeping of the GPU brick atlas (slot grid within device
//!   limits, frame-stamped LRU that never evicts what the current frame uses);
//! * [`UploadBudget`]: bytes uploaded per frame, always making progress;
//! * [`refine`](refine::refine): the view- and transfer-function-dependent cut;
//! * [`BrickManager`]: the per-frame façade tying them together; its
//!   [`update`](BrickManager::update) returns a [`FramePlan`] (cut, uploads, stats).
//!
//! See `docs/cache.md` for the design.

mod cpu_cache;
mod loader;
mod manager;
mod pool;
pub mod refine;
mod upload;

#[cfg(test)]
mod test_source;

pub use cpu_cache::{BrickBytes, CpuCache};
pub use loader::{LoadError, Loader, LoaderConfig, PollReport, RequestOutcome};
pub use manager::{
    BrickManager, CacheError, CutLeaf, FramePlan, FrameStats, LeafKind, ManagerConfig, Residency,
    ResidencyCounts, Upload,
};
pub use pool::{Allocation, BrickPool, PoolError, PoolLimits, SlotId};
pub use refine::{EmptyReason, NodeClass};
pub use upload::{UploadBudget, UploadCandidate};
