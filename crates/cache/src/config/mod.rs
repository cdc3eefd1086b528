//! The cache's configuration ([`OutOfCoreConfig`]), what the renderer's device stores
//! per pool slot ([`GpuFormat`]), the retry back-off ([`RetryPolicy`]) and their
//! validation ([`ConfigError`]).

use crate::fade::FadeDuration;
use crate::pool::PoolLimits;
use brickray_core::{
    DType, LodMetric, OctreeLayout, SampleEncoding, TexelCaps, U8Filtering, sub_cells_per_axis,
};
use brickray_visibility::{VisibilityConfig, VisibilityPolicy};
use std::time::Duration;
use thiserror::Error;

/// Most loader threads a [`OutOfCoreConfig`] accepts.
pub const MAX_LOADER_THREADS: usize = 64;

/// Fewest bricks the CPU cache and the GPU pool must hold: the root and its
/// eight children, so that the root can be split at all.
pub const MIN_RESIDENT_BRICKS: u32 = 9;

/// Exponential back-off of automatic retries of failed reads, per node:
/// the `n`-th consecutive failure is retried after `min(initial * factor^(n-1), max)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RetryPolicy {
    /// Delay after the first failure (> 0).
    pub initial: Duration,
    /// Longest delay (`>= initial`).
    pub max: Duration,
    /// Growth per consecutive failure (finite, `>= 1`).
    pub factor: f32,
}

impl Default for RetryPolicy {
    /// 1 s, doubling up to 60 s.
    fn default() -> Self {
        RetryPolicy {
            initial: Duration::from_secs(1),
            max: Duration::from_secs(60),
            factor: 2.0,
        }
    }
}

impl RetryPolicy {
    /// The delay before retrying after the `failures`-th consecutive failure
    /// (`failures >= 1`; 0 is treated as 1).
    pub fn delay(&self, failures: u32) -> Duration {
        let exp = failures.saturating_sub(1).min(1024) as i32;
        let secs = self.initial.as_secs_f64() * (self.factor as f64).powi(exp);
        let capped = secs.min(self.max.as_secs_f64());
        Duration::try_from_secs_f64(capped).unwrap_or(self.max)
    }

    /// Checks the fields (see each field's doc).
    pub fn validate(&self) -> Result<(), ConfigError> {
        if !self.factor.is_finite() || self.factor < 1.0 {
            return Err(ConfigError::RetryFactor {
                factor: self.factor,
            });
        }
        if self.initial.is_zero() || self.max < self.initial {
            return Err(ConfigError::RetryDelays {
                initial: self.initial,
                max: self.max,
            });
        }
        Ok(())
    }
}

/// Budgets and knobs of a [`BrickManager`](crate::BrickManager). Nothing here
/// depends on the device: what the device stores per slot is a [`GpuFormat`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OutOfCoreConfig {
    /// System memory for prepared bricks (texels + sub-cell ranges), the level-2
    /// cache; at least [`MIN_RESIDENT_BRICKS`] prepared bricks.
    pub cpu_budget_bytes: u64,
    /// GPU memory for the brick pool (atlas texels, sub-cell table and slot table
    /// per slot); at least [`MIN_RESIDENT_BRICKS`] slots.
    pub gpu_budget_bytes: u64,
    /// Bytes uploaded per frame (at least one split or one brick always goes).
    pub upload_budget_bytes: u64,
    /// Screen-space error tolerance: a brick is refined while one of its voxels
    /// covers more than this many pixels (finite, `>= 0`; 0 = always the finest
    /// level the budgets allow).
    pub tolerance_px: f32,
    /// The refinement rule: geometric (`tolerance_px`) or error-aware with an
    /// error budget in 8-bit levels x pixels ([`LodMetric`], `docs/cache.md`).
    pub lod_metric: LodMetric,
    /// Loader threads, `1..=`[`MAX_LOADER_THREADS`].
    pub loader_threads: usize,
    /// Most bytes of bricks being read at once, counted at the stored brick
    /// size (one brick is always allowed): what bounds the memory and the
    /// bandwidth a source over the network ties up, separately from the
    /// CPU cache. With batches ([`BrickSource::batch_size`](brickray_core::BrickSource::batch_size))
    /// the threads x batch bricks in flight are cut to it. 64 MiB by
    /// default.
    pub max_bytes_in_flight: u64,
    /// Automatic retry of failed reads; `None`: only on request
    /// ([`BrickManager::retry_failed`](crate::BrickManager::retry_failed)).
    pub retry: Option<RetryPolicy>,
    /// Level-of-detail transitions: a region whose level changes blends from
    /// its old brick to its new one over this long instead of switching in one
    /// frame ([`crate::fade`]); `None`: switch at once.
    pub fade: Option<FadeDuration>,
    /// Most pool slots pinned for the coarse floor: the top levels of the
    /// octree (as many whole levels as fit, within a quarter of the pool and
    /// leaving [`MIN_RESIDENT_BRICKS`] slots) stay resident, never evicted, so
    /// that a region evicted under memory pressure falls back to an ancestor,
    /// never to nothing. 0: no floor.
    pub floor_slots: u32,
    /// Most data bricks the cut may hold (its working set), below what the
    /// pool holds: refinement splits in its priority order until the next
    /// split would exceed it, so the working set degrades gradually with the
    /// budget (`docs/cache.md`, "Brick budget"). `None` (the default): the
    /// pool's capacity. Must be `>= 1` (the root's brick).
    pub brick_budget: Option<u32>,
    /// Where refinement's visibility comes from (`docs/visibility.md`): with
    /// [`VisibilityPolicy::RayGuided`] the ray caster's per-brick usage
    /// counts, read back a few frames later without waiting, stop refinement
    /// of bricks no ray reaches (hidden behind opaque material): they stay at
    /// the level they have and request nothing. Default: none. A change
    /// forgets what was observed.
    pub visibility: VisibilityPolicy,
    /// The visibility threshold (pixels), hold (frames) and occlusion
    /// queries per frame.
    pub visibility_config: VisibilityConfig,
    /// How long set-up ([`BrickManager::preload_root`](crate::BrickManager::preload_root))
    /// waits for the source to answer for the root (its metadata and brick)
    /// before it fails with [`LoadError::TimedOut`](crate::LoadError::TimedOut)
    /// (> 0). The read runs on a thread of its own, so a source that never
    /// answers cannot hold set-up; what it answers later is dropped.
    pub setup_deadline: Duration,
    /// When refinement also requests the bricks one level past those a split
    /// waits for ([`Lookahead`]); never by default.
    pub lookahead: Lookahead,
    /// While the view moves, refine by evolving the last frame's cut instead
    /// of rebuilding it from the root (docs/cache.md, "A moving view: the
    /// cut evolves"): on by default. Applies under
    /// [`LodMetric::Geometric`] without lookahead or failures; a view that
    /// stops, and every
    /// [`EVOLVED_FRAMES_MAX`](crate::EVOLVED_FRAMES_MAX)-th moving frame,
    /// are refined from the root, so the cut at convergence is the same.
    pub evolve: bool,
}

/// When refinement requests the bricks one level past those a split waits
/// for ([`RefineParams::lookahead`](crate::refine::RefineParams::lookahead)),
/// at the child's priority, so after every brick a split waits for. Each
/// level of the octree costs a round trip before refinement knows the next
/// is wanted; asking for the next with it saves those round trips where the
/// levels, not the bricks per round trip, bound the time. Measured on the
/// shared MRI over HTTP (docs/remote.md) it gained at most 1.10x at 80 and
/// 300 ms once metadata went in batches, so it is off by default; a deep
/// octree reached through few bricks per level is where it would pay.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Lookahead {
    /// Never: only what the cut waits for is requested. The default.
    #[default]
    Never,
    /// For a source read in batches ([`BrickSource::batch_size`](brickray_core::BrickSource::batch_size)
    /// above 1: a store or an OME-Zarr image over the network).
    Remote,
    /// For every source.
    Always,
}

impl Lookahead {
    /// Whether it applies to a source that is (`remote`) or is not read in
    /// batches.
    pub fn applies(self, remote: bool) -> bool {
        match self {
            Lookahead::Remote => remote,
            Lookahead::Always => true,
            Lookahead::Never => false,
        }
    }
}

/// Default [`OutOfCoreConfig::max_bytes_in_flight`]: 64 MiB.
pub const DEFAULT_MAX_BYTES_IN_FLIGHT: u64 = 64 << 20;

/// Default [`OutOfCoreConfig::setup_deadline`]: 30 s.
pub const DEFAULT_SETUP_DEADLINE: Duration = Duration::from_secs(30);

/// Default [`OutOfCoreConfig::floor_slots`]: levels 0 to 2 of a cubic volume.
pub const DEFAULT_FLOOR_SLOTS: u32 = 73;

impl Default for OutOfCoreConfig {
    /// 512 MiB CPU, 256 MiB GPU, 16 MiB uploaded per frame, 1 px, 2 threads
    /// with at most 64 MiB of bricks in flight,
    /// retries after 1 s doubling to 60 s, fades of 120 ms, a floor of up to
    /// 73 slots, no visibility feedback, a set-up deadline of 30 s.
    fn default() -> Self {
        OutOfCoreConfig {
            cpu_budget_bytes: 512 << 20,
            gpu_budget_bytes: 256 << 20,
            upload_budget_bytes: 16 << 20,
            tolerance_px: 1.0,
            lod_metric: LodMetric::Geometric,
            loader_threads: 2,
            max_bytes_in_flight: DEFAULT_MAX_BYTES_IN_FLIGHT,
            retry: Some(RetryPolicy::default()),
            fade: Some(FadeDuration::default()),
            floor_slots: DEFAULT_FLOOR_SLOTS,
            brick_budget: None,
            visibility: VisibilityPolicy::None,
            visibility_config: VisibilityConfig::default(),
            setup_deadline: DEFAULT_SETUP_DEADLINE,
            lookahead: Lookahead::Never,
            evolve: true,
        }
    }
}

/// What the renderer's device stores per pool slot: the texel encoding of the
/// atlas, the sub-cell table and the per-slot table row.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GpuFormat {
    /// How samples become texels (must match the layout's dtype and value range).
    pub encoding: SampleEncoding,
    /// Sub-cells per brick axis of the empty-space-skipping table
    /// (`1..=brick`, usually [`sub_cells_per_axis`]).
    pub sub_cells_per_axis: u32,
    /// Bytes of one row of the renderer's per-slot table.
    pub slot_row_bytes: u32,
    /// Device limit on a 3D texture dimension (`max_texture_dimension_3d`).
    pub max_texture_dim_3d: u32,
    /// Channels per voxel ([`OctreeLayout::channels`]): a texel packs them
    /// in [`lanes`](Self::lanes) lanes of `encoding`'s format.
    pub channel_count: u32,
    /// Each channel's encoding (its own value range; channel 0's is
    /// `encoding`; entries past the channels repeat it).
    pub channel_encodings: [SampleEncoding; brickray_core::MAX_CHANNELS],
    /// The atlas carries each texel's spread (a second, `R16Float` atlas at
    /// the same slots; [`brickray_core::BrickSource::read_spread`]): coarse
    /// levels classified with their spread. Set when the source delivers
    /// spreads; 2 more bytes per stored voxel.
    pub spread: bool,
    /// The GPU keeps each texel's gradient (a third atlas at the same slots,
    /// `Rgba16Float`, made on the GPU from the uploaded texels), so that
    /// shaded DVR reads one texel instead of six: 8 more bytes per stored
    /// voxel on the GPU, none in the CPU cache or the uploads.
    pub gradients: bool,
}

/// Which size overflowed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum SizeQuantity {
    /// Stored voxels per brick side (`brick + 2 * apron`).
    StoredSide,
    /// Bytes of one brick as the source stores it.
    RawBrick,
    /// Bytes of one prepared brick (texels and sub-cell ranges).
    PreparedBrick,
    /// Bytes of one GPU pool slot.
    Slot,
}

/// A configuration the cache cannot work with.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum ConfigError {
    /// The tolerance is NaN, negative or infinite.
    #[error("tolerance_px must be finite and >= 0, got {value}")]
    Tolerance {
        /// The value given.
        value: f32,
    },
    /// A brick budget of 0 (the root's brick is always needed).
    #[error("brick_budget must be >= 1, got {value}")]
    BrickBudget {
        /// The value given.
        value: u32,
    },
    /// The error budget of an error-aware [`LodMetric`] is NaN, negative or
    /// infinite.
    #[error("the error budget must be finite and >= 0, got {value}")]
    ErrorBudget {
        /// The value given.
        value: f32,
    },
    /// Zero loader threads, or more than [`MAX_LOADER_THREADS`].
    #[error("loader_threads must be in 1..={max}, got {threads}")]
    LoaderThreads {
        /// The value given.
        threads: usize,
        /// The most accepted.
        max: usize,
    },
    /// The CPU budget holds fewer than [`MIN_RESIDENT_BRICKS`] prepared bricks.
    #[error(
        "cpu_budget_bytes {budget_bytes} holds {bricks} prepared bricks of {brick_bytes} B; \
         at least {needed} are needed (the root and its children)"
    )]
    CpuBudgetTooSmall {
        /// The budget given.
        budget_bytes: u64,
        /// Bytes of one prepared brick.
        brick_bytes: u64,
        /// Bricks the budget holds.
        bricks: u64,
        /// Bricks needed.
        needed: u32,
    },
    /// The GPU budget (within the device's texture limit) gives fewer than
    /// [`MIN_RESIDENT_BRICKS`] slots.
    #[error(
        "gpu_budget_bytes {budget_bytes} gives {slots} pool slots of {slot_bytes} B \
         ({stored_side}^3 voxels, max 3D texture dimension {max_texture_dim_3d}); \
         at least {needed} are needed"
    )]
    GpuBudgetTooSmall {
        /// The budget given.
        budget_bytes: u64,
        /// Bytes of one slot.
        slot_bytes: u64,
        /// Stored voxels per brick side.
        stored_side: u32,
        /// The device limit.
        max_texture_dim_3d: u32,
        /// Slots the budget gives.
        slots: u32,
        /// Slots needed.
        needed: u32,
    },
    /// A loader thread could not be started (a thread-count change).
    #[error("cannot start a loader thread: {reason}")]
    LoaderStart {
        /// What the OS said.
        reason: String,
    },
    /// A fade duration of 0 frames, or milliseconds negative or not finite.
    #[error("fade duration must be >= 1 frame or finite >= 0 ms, got {value:?}")]
    Fade {
        /// The value given.
        value: FadeDuration,
    },
    /// A size computed from the layout and format overflows.
    #[error("the size of {quantity:?} overflows")]
    SizeOverflow {
        /// Which one.
        quantity: SizeQuantity,
    },
    /// The encoding converts another dtype or value range than the layout's.
    #[error(
        "the GPU encoding is for {encoding_dtype:?} over {encoding_range:?}, \
         the volume is {layout_dtype:?} over {layout_range:?}"
    )]
    EncodingMismatch {
        /// The volume's dtype.
        layout_dtype: DType,
        /// The encoding's dtype.
        encoding_dtype: DType,
        /// The volume's value range.
        layout_range: [f32; 2],
        /// The encoding's value range.
        encoding_range: [f32; 2],
    },
    /// Sub-cells per axis outside `1..=max`.
    #[error("sub_cells_per_axis must be in 1..={max}, got {per_axis}")]
    SubCells {
        /// The value given.
        per_axis: u32,
        /// The most accepted (the brick's interior side).
        max: u32,
    },
    /// The retry factor is not finite or below 1.
    #[error("retry factor must be finite and >= 1, got {factor}")]
    RetryFactor {
        /// The value given.
        factor: f32,
    },
    /// A set-up deadline of zero.
    #[error("setup_deadline must be > 0, got {value:?}")]
    SetupDeadline {
        /// The value given.
        value: Duration,
    },
    /// The retry delays are zero or `max < initial`.
    #[error("retry delays must satisfy 0 < initial <= max, got {initial:?} and {max:?}")]
    RetryDelays {
        /// The initial delay given.
        initial: Duration,
        /// The longest delay given.
        max: Duration,
    },
}

impl GpuFormat {
    /// The format a device with `caps` stores for `layout`: the encoding chosen for
    /// the volume's kind, dtype and value range, [`sub_cells_per_axis`] of the brick.
    pub fn for_layout(
        layout: &OctreeLayout,
        caps: TexelCaps,
        u8_filtering: U8Filtering,
        slot_row_bytes: u32,
        max_texture_dim_3d: u32,
    ) -> GpuFormat {
        let encoding = SampleEncoding::for_volume(&layout.volume, caps, u8_filtering);
        GpuFormat {
            encoding,
            sub_cells_per_axis: sub_cells_per_axis(layout.brick),
            slot_row_bytes,
            max_texture_dim_3d,
            channel_count: layout.channels() as u32,
            channel_encodings: std::array::from_fn(|c| {
                layout.channel_ranges().get(c).map_or(encoding, |r| {
                    SampleEncoding::choose(layout.volume.dtype, *r, caps, u8_filtering)
                })
            }),
            spread: false,
            gradients: false,
        }
    }

    /// Texel lanes of the atlas: 1, 2 or 4 (three channels take four).
    pub fn lanes(&self) -> u32 {
        brickray_core::channels::texel_lanes(self.channel_count as usize) as u32
    }

    /// Bytes of one atlas texel (every channel of a voxel).
    pub fn texel_bytes(&self) -> u32 {
        self.encoding.texel_bytes() * self.lanes()
    }

    /// Checks the format against the layout: encoding of the same dtype and value
    /// range, sub-cells in range, sizes that do not overflow.
    pub fn validate(&self, layout: &OctreeLayout) -> Result<(), ConfigError> {
        let (ld, lr) = (layout.volume.dtype, layout.volume.value_range);
        let (ed, er) = (self.encoding.dtype(), self.encoding.value_range());
        if ld != ed
            || lr.map(f32::to_bits) != er.map(f32::to_bits)
            || self.channel_count as usize != layout.channels()
        {
            return Err(ConfigError::EncodingMismatch {
                layout_dtype: ld,
                encoding_dtype: ed,
                layout_range: lr,
                encoding_range: er,
            });
        }
        let max = layout.brick.max(1);
        if self.sub_cells_per_axis == 0 || self.sub_cells_per_axis > max {
            return Err(ConfigError::SubCells {
                per_axis: self.sub_cells_per_axis,
                max,
            });
        }
        self.slot_bytes(layout).map(|_| ())
    }

    /// Bytes of one atlas texel's spread ([`Self::spread`]): 2 or 0.
    pub fn spread_bytes(&self) -> u32 {
        if self.spread { 2 } else { 0 }
    }

    /// Bytes of one prepared brick at most (the most the CPU cache counts
    /// and a frame uploads for one): `stored_side^3` texels (and spreads,
    /// which a finest-level brick does not carry) and `sub_cells^3` ranges
    /// of 8 bytes per channel.
    pub fn prepared_brick_bytes(&self, layout: &OctreeLayout) -> Result<u64, ConfigError> {
        let side = stored_side(layout)? as u64;
        let n = self.sub_cells_per_axis as u64;
        let overflow = ConfigError::SizeOverflow {
            quantity: SizeQuantity::PreparedBrick,
        };
        let texels = side
            .checked_pow(3)
            .and_then(|v| v.checked_mul((self.texel_bytes() + self.spread_bytes()) as u64));
        let cells = n
            .checked_pow(3)
            .and_then(|v| v.checked_mul(8 * self.channel_count as u64));
        texels
            .zip(cells)
            .and_then(|(t, c)| t.checked_add(c))
            .ok_or(overflow)
    }

    /// Bytes of one atlas texel's gradient on the GPU ([`Self::gradients`]):
    /// 8 or 0.
    pub fn gradient_bytes(&self) -> u32 {
        if self.gradients { 8 } else { 0 }
    }

    /// Bytes one pool slot costs on the GPU: the prepared brick, its
    /// gradients ([`Self::gradients`]) and one row of the slot table.
    pub fn slot_bytes(&self, layout: &OctreeLayout) -> Result<u64, ConfigError> {
        let gradients = (stored_side(layout)? as u64)
            .checked_pow(3)
            .and_then(|v| v.checked_mul(self.gradient_bytes() as u64));
        self.prepared_brick_bytes(layout)?
            .checked_add(self.slot_row_bytes as u64)
            .zip(gradients)
            .and_then(|(s, g)| s.checked_add(g))
            .ok_or(ConfigError::SizeOverflow {
                quantity: SizeQuantity::Slot,
            })
    }

    /// The pool's sizing inputs for a GPU budget, checked to give at least
    /// [`MIN_RESIDENT_BRICKS`] slots, and capped at a slot for every brick of
    /// `layout` ([`brick_count`]): a budget beyond that is not allocated.
    pub fn pool_limits(
        &self,
        layout: &OctreeLayout,
        gpu_budget_bytes: u64,
    ) -> Result<PoolLimits, ConfigError> {
        let limits = PoolLimits {
            budget_bytes: gpu_budget_bytes,
            slot_bytes: self.slot_bytes(layout)?,
            stored_side: stored_side(layout)?,
            max_dim: self.max_texture_dim_3d,
            max_slots: brick_count(layout).max(MIN_RESIDENT_BRICKS as u64),
        };
        let slots = limits
            .grid()
            .map_or(0, |g| g.iter().map(|&a| a as u64).product::<u64>());
        if slots < MIN_RESIDENT_BRICKS as u64 {
            return Err(ConfigError::GpuBudgetTooSmall {
                budget_bytes: gpu_budget_bytes,
                slot_bytes: limits.slot_bytes,
                stored_side: limits.stored_side,
                max_texture_dim_3d: self.max_texture_dim_3d,
                slots: slots as u32,
                needed: MIN_RESIDENT_BRICKS,
            });
        }
        Ok(limits)
    }

    /// True when a pool of `gpu_budget_bytes` in this format has a slot for
    /// every brick of `layout` at once (each level's nodes over the volume,
    /// [`brick_count`]): the pool then never evicts for room, and what more
    /// each slot carries costs no brick a cut could use. False when the
    /// budget does not size a pool.
    pub fn holds_every_brick(&self, layout: &OctreeLayout, gpu_budget_bytes: u64) -> bool {
        let Ok(limits) = self.pool_limits(layout, gpu_budget_bytes) else {
            return false;
        };
        let slots = limits
            .grid()
            .map_or(0, |g| g.iter().map(|&a| a as u64).product::<u64>());
        slots >= brick_count(layout)
    }
}

/// The bricks of `layout`: at each level, the nodes whose boxes meet the
/// volume (`ceil(level_dims / brick)` per axis), summed over the levels.
pub fn brick_count(layout: &OctreeLayout) -> u64 {
    let b = layout.brick.max(1) as u64;
    (0..layout.levels)
        .map(|l| {
            layout
                .level_dims(l)
                .iter()
                .map(|&d| (d as u64).div_ceil(b))
                .product::<u64>()
        })
        .sum()
}

/// `brick + 2 * apron`, checked.
pub(crate) fn stored_side(layout: &OctreeLayout) -> Result<u32, ConfigError> {
    layout
        .apron
        .checked_mul(2)
        .and_then(|a| a.checked_add(layout.brick))
        .ok_or(ConfigError::SizeOverflow {
            quantity: SizeQuantity::StoredSide,
        })
}

/// Bytes of one brick as the source stores it, checked (`layout.brick_bytes()`).
pub(crate) fn raw_brick_bytes(layout: &OctreeLayout) -> Result<usize, ConfigError> {
    (stored_side(layout)? as usize)
        .checked_pow(3)
        .and_then(|v| v.checked_mul(layout.volume.dtype.size() * layout.channels()))
        .ok_or(ConfigError::SizeOverflow {
            quantity: SizeQuantity::RawBrick,
        })
}

impl OutOfCoreConfig {
    /// Checks every field against the layout and the GPU format (see each
    /// field's doc); the first violation found is returned.
    pub fn validate(&self, layout: &OctreeLayout, gpu: &GpuFormat) -> Result<(), ConfigError> {
        validate_tolerance(self.tolerance_px)?;
        validate_metric(self.lod_metric)?;
        validate_brick_budget(self.brick_budget)?;
        if self.loader_threads == 0 || self.loader_threads > MAX_LOADER_THREADS {
            return Err(ConfigError::LoaderThreads {
                threads: self.loader_threads,
                max: MAX_LOADER_THREADS,
            });
        }
        if let Some(r) = &self.retry {
            r.validate()?;
        }
        if let Some(f) = self.fade.filter(|f| !f.is_valid()) {
            return Err(ConfigError::Fade { value: f });
        }
        if self.setup_deadline.is_zero() {
            return Err(ConfigError::SetupDeadline {
                value: self.setup_deadline,
            });
        }
        gpu.validate(layout)?;
        raw_brick_bytes(layout)?;
        validate_cpu_budget(self.cpu_budget_bytes, layout, gpu)?;
        gpu.pool_limits(layout, self.gpu_budget_bytes)?;
        Ok(())
    }
}

pub(crate) fn validate_tolerance(value: f32) -> Result<(), ConfigError> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(ConfigError::Tolerance { value })
    }
}

pub(crate) fn validate_brick_budget(budget: Option<u32>) -> Result<(), ConfigError> {
    match budget {
        Some(0) => Err(ConfigError::BrickBudget { value: 0 }),
        _ => Ok(()),
    }
}

pub(crate) fn validate_metric(metric: LodMetric) -> Result<(), ConfigError> {
    match metric.budget() {
        Some(budget) if !(budget.is_finite() && budget >= 0.0) => {
            Err(ConfigError::ErrorBudget { value: budget })
        }
        _ => Ok(()),
    }
}

pub(crate) fn validate_cpu_budget(
    budget_bytes: u64,
    layout: &OctreeLayout,
    gpu: &GpuFormat,
) -> Result<(), ConfigError> {
    let brick_bytes = gpu.prepared_brick_bytes(layout)?;
    let bricks = budget_bytes.checked_div(brick_bytes).unwrap_or(u64::MAX);
    if bricks < MIN_RESIDENT_BRICKS as u64 {
        return Err(ConfigError::CpuBudgetTooSmall {
            budget_bytes,
            brick_bytes,
            bricks,
            needed: MIN_RESIDENT_BRICKS,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests;
