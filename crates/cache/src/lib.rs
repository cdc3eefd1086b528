//! Out-of-core brick management for brickray, after Gobbetti et al. 2008 (sect. 3
//! and 4), free of any GPU API:
//!
//! * [`OutOfCoreConfig`]: budgets and knobs, validated ([`ConfigError`]); with
//!   [`GpuFormat`], what the renderer's device stores per pool slot;
//! * [`CpuCache`]: the level-2 cache of [`PreparedBrick`]s (texels and sub-cell
//!   ranges, made off the frame path), LRU within a byte budget;
//! * [`Loader`]: worker threads reading node metadata and bricks from a
//!   [`BrickSource`](brickray_core::BrickSource) (metadata first, then bricks in
//!   priority order) and preparing them, with cancellation, panics caught and a
//!   drop that never waits on a hung read;
//! * [`BrickPool`]: bookkeeping of the GPU brick atlas (slot grid within device
//!   limits, frame-stamped LRU that never evicts what the current frame uses);
//! * [`UploadBudget`]: bytes uploaded per frame, always making progress;
//! * [`refine`](refine::refine): the view- and transfer-function-dependent cut,
//!   bounded work per frame whatever the camera;
//! * [`BrickManager`]: the per-frame façade tying them together; its
//!   [`update`](BrickManager::update) returns a [`FramePlan`] (cut, uploads, stats)
//!   and never calls the source; failures are counted, surfaced once
//!   ([`BrickManager::take_error`]) and retried after a back-off ([`RetryPolicy`]);
//! * [`Streamer`]: the out-of-core planner a renderer executes: the manager,
//!   the visibility feedback (`brickray-visibility`), the visible weights,
//!   occlusion scheduling and the convergence rule, over one or several views
//!   ([`StreamPlan`]).
//!
//! The cut vocabulary ([`CutLeaf`], [`LeafKind`], [`EmptyReason`]) is
//! `brickray_core`'s, re-exported here. See `docs/cache.md` for the design.

mod config;
mod cpu_cache;
pub mod fade;
mod failures;
mod loader;
mod manager;
mod pool;
mod prepared;
pub mod refine;
pub mod stream;
mod upload;

#[cfg(test)]
mod test_source;

pub use brickray_core::{CutLeaf, EmptyReason, LeafKind};
pub use config::{
    ConfigError, DEFAULT_FLOOR_SLOTS, DEFAULT_MAX_BYTES_IN_FLIGHT, DEFAULT_SETUP_DEADLINE,
    GpuFormat, Lookahead, MAX_LOADER_THREADS, MIN_RESIDENT_BRICKS, OutOfCoreConfig, RetryPolicy,
    SizeQuantity, brick_count,
};
pub use cpu_cache::CpuCache;
pub use fade::{Displayed, Fade, FadeDuration, Fader, MAX_FADE_FRAMES};
pub use failures::{Clock, FailureCounts, FetchKind, StreamError, SystemClock};
pub use loader::{
    BrickRequest, LoadError, Loader, LoaderConfig, PollReport, RequestOutcome, SHUTDOWN_WAIT,
};
pub use manager::{
    BrickManager, CacheError, EVOLVED_FRAMES_MAX, FadeSlot, FrameInput, FramePlan, FrameStats,
    PhaseTimes, Reconfigured, Residency, ResidencyCounts, UNTIMED_FRAME_RATE, Upload,
};
pub use pool::{Allocation, BrickPool, PoolError, PoolLimits, SlotId};
pub use prepared::{PreparedBrick, Preparer};
pub use refine::{NodeClass, SplitBlocks, SplitFilter, Views, lod_voxel_world};
pub use stream::{
    Classification, MAX_QUERIES_PER_FRAME, QueryBatch, QueryResult, QuerySchedule, StreamFrame,
    StreamPlan, StreamStats, Streamer, UsageFrame, ViewFeedback,
};
pub use upload::{UploadBudget, UploadCandidate};
