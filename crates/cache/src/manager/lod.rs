//! The coarse floor and the fades' side of a frame plan: which top-level
//! bricks stay pinned for good, and the slots of each fading leaf and its
//! fallback ([`FadeSlot`]).

use super::BrickManager;
use crate::config::MIN_RESIDENT_BRICKS;
use crate::failures::FetchKind;
use crate::loader::BrickRequest;
use crate::pool::SlotId;
use brickray_core::{NodeKey, NodeKind, OctreeLayout};

/// One fading leaf as the renderer draws it: the leaf's brick (in `slot`) is
/// mixed with its ancestor's (in `fallback`, `levels_up` levels coarser) by
/// `weight` (of the fallback, in `[0, 1]`), in value space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FadeSlot {
    /// The displayed leaf's slot.
    pub slot: SlotId,
    /// The ancestor's slot.
    pub fallback: SlotId,
    /// Levels between the leaf and the ancestor (>= 1).
    pub levels_up: u32,
    /// Weight of the ancestor's value.
    pub weight: f32,
    /// The leaf is drawn from the ancestor alone, at the ancestor's step, as
    /// the ancestor itself would draw it: an octant of an octant-granular cut
    /// ([`LodMetric::VisibleOctants`](brickray_core::LodMetric::VisibleOctants)),
    /// whose `slot` is a *borrowed slot* (at or past the pool's slot count:
    /// a row of the renderer's slot table and feedback, no atlas space;
    /// [`BrickManager::borrowed_slots`](super::BrickManager::borrowed_slots)).
    /// `weight` is then 1.
    pub borrowed: bool,
}

/// Priority of floor requests: after the root (`f32::MAX`), before the view's.
const FLOOR_PRIORITY: f32 = f32::MAX / 2.0;

/// The nodes of the coarse floor: whole top levels (inside the volume) while
/// their count stays within `floor_slots`, a quarter of the pool and the pool
/// less [`MIN_RESIDENT_BRICKS`]. Empty when not even the root fits.
pub(crate) fn floor_nodes(
    layout: &OctreeLayout,
    slot_count: u32,
    floor_slots: u32,
) -> Vec<NodeKey> {
    let cap = floor_slots
        .min(slot_count / 4)
        .min(slot_count.saturating_sub(MIN_RESIDENT_BRICKS)) as usize;
    let mut out = Vec::new();
    for level in 0..layout.levels.min(8) {
        let n = 1u32 << level;
        let mut this = Vec::new();
        for z in 0..n {
            for y in 0..n {
                for x in 0..n {
                    let k = NodeKey::new(level, x, y, z);
                    if layout.in_volume(k) {
                        this.push(k);
                    }
                    if out.len() + this.len() > cap {
                        return out;
                    }
                }
            }
        }
        out.extend(this);
    }
    out
}

/// What the floor did this frame.
#[derive(Debug, Default)]
pub(crate) struct FloorStep {
    pub(crate) uploads: Vec<super::Upload>,
    pub(crate) requests: Vec<BrickRequest>,
    pub(crate) meta_requests: Vec<(NodeKey, f32)>,
}

impl BrickManager {
    /// Makes the floor resident and pins it: resident floor bricks are pinned,
    /// those in CPU memory uploaded (within the frame's upload budget), the
    /// others requested (metadata first). Empty nodes need no brick.
    pub(crate) fn floor_step(&mut self, frame: u64) -> FloorStep {
        let mut step = FloorStep::default();
        for i in 0..self.floor.len() {
            let key = self.floor[i];
            if self.pool.is_pinned_for_good(key) {
                continue;
            }
            // Top down: below a parent known to need its children's bricks
            // (an empty or uniform parent covers its children).
            if let Some(p) = self.layout.parent(key) {
                match self.meta.get(p) {
                    Some(info) if matches!(info.kind, NodeKind::Data) => {}
                    _ => continue,
                }
            }
            let Some(info) = self.meta.get(key) else {
                if !self.failures.is_failed(FetchKind::Metadata, key) {
                    step.meta_requests.push((key, FLOOR_PRIORITY));
                }
                continue;
            };
            if info.kind == NodeKind::Empty {
                continue;
            }
            if self.pool.contains(key) {
                self.pool.pin(key);
            } else if let Some(brick) = self.cpu.peek(key).cloned() {
                if !self.budget.try_reserve(brick.bytes()) {
                    continue;
                }
                if let Ok(a) = self.pool.allocate(key, frame) {
                    self.pool.pin(key);
                    step.uploads.push(super::Upload {
                        key,
                        slot: a.slot,
                        atlas_offset: self.pool.slot_offset(a.slot),
                        brick,
                    });
                }
            } else if !self.failures.is_failed(FetchKind::Brick, key) {
                step.requests.push(BrickRequest {
                    key,
                    priority: FLOOR_PRIORITY,
                    children_meta: self.children_meta_missing(key, &info),
                    info,
                });
            }
        }
        step
    }

    /// Floor nodes resident and pinned.
    pub(crate) fn floor_pinned(&self) -> u32 {
        self.floor
            .iter()
            .filter(|k| self.pool.is_pinned_for_good(**k))
            .count() as u32
    }

    /// Re-plans the floor for the current pool (after it was rebuilt).
    pub(crate) fn reset_floor(&mut self) {
        self.floor = floor_nodes(
            &self.layout,
            self.pool.slot_count(),
            self.config.floor_slots,
        );
        self.fader.clear();
    }

    /// The coarse floor's nodes ([`OutOfCoreConfig::floor_slots`](crate::OutOfCoreConfig::floor_slots)).
    pub fn floor(&self) -> &[NodeKey] {
        &self.floor
    }
}
