//! Occlusion scheduling (Gobbetti et al. 2008, section 6; docs/visibility.md),
//! the GPU-free half: the cut's data leaves are projected to screen
//! rectangles, the screen-tile scheduler picks this frame's subset, and each
//! picked leaf's world box is handed to the renderer, which draws it against
//! the depth of the last sample its rays visited inside an occlusion query.
//! Leaves whose box reaches behind the eye are visible without a query.

use super::Streamer;
use crate::refine::{ViewGeometry, Views};
use brickray_core::{DepthConvention, FrameView, NodeKey};
use brickray_visibility::{PxRect, TileSchedulerConfig, schedule_tiles};

/// Most occlusion queries per view and frame (the renderer's query set).
pub const MAX_QUERIES_PER_FRAME: u32 = 1024;
/// The smallest tile side the scheduler splits to.
pub const MIN_TILE_PX: u32 = 16;

/// How one view's queries were scheduled.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct QuerySchedule {
    /// Queries issued.
    pub queries: u32,
    /// Frames the scheduler's rotation takes to query every on-screen leaf.
    pub period: u32,
    /// Tiles of the screen subdivision.
    pub tiles: u32,
    /// Leaves whose box reaches behind the near plane (visible, not queried).
    pub near_visible: u32,
}

impl QuerySchedule {
    /// Counts summed, the longest period.
    pub fn add(&self, o: &QuerySchedule) -> QuerySchedule {
        QuerySchedule {
            queries: self.queries + o.queries,
            period: self.period.max(o.period),
            tiles: self.tiles + o.tiles,
            near_visible: self.near_visible + o.near_visible,
        }
    }
}

/// One view's occlusion queries of a frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct QueryBatch {
    /// The leaves queried, one query each.
    pub keys: Vec<NodeKey>,
    /// Their boxes in the world: a corner and the three edges (xyz, w = 0).
    pub boxes: Vec<[[f32; 4]; 4]>,
    /// The view's view-projection.
    pub view_proj: [[f32; 4]; 4],
    /// True for a reversed-Z camera.
    pub reversed: bool,
    /// How they were scheduled.
    pub schedule: QuerySchedule,
}

/// Schedules one view's queries over the cut's data leaves `leaves`; returns
/// the batch and the leaves whose box reaches behind the eye.
fn schedule_view(
    geo: &ViewGeometry,
    view: &FrameView,
    frame: u64,
    leaves: &[NodeKey],
    queries_per_frame: u32,
) -> (QueryBatch, Vec<NodeKey>) {
    let vp = view.view_proj;
    let (w, h) = (view.size[0] as f64, view.size[1] as f64);
    let mut near = Vec::new();
    let mut rects = Vec::with_capacity(leaves.len());
    let mut boxes = Vec::with_capacity(leaves.len());
    let mut keys = Vec::with_capacity(leaves.len());
    for &k in leaves {
        let c = geo.world_corners(k);
        let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
        let mut behind = false;
        for p in &c {
            let q = vp * p.extend(1.0);
            if q.w.is_nan() || q.w <= 1e-9 || !q.z.is_finite() {
                behind = true;
                break;
            }
            let (x, y) = (q.x / q.w, q.y / q.w);
            lo = [lo[0].min(x), lo[1].min(y)];
            hi = [hi[0].max(x), hi[1].max(y)];
        }
        if behind {
            near.push(k);
            continue;
        }
        // NDC to pixels (y down), widened to whole pixels.
        let px = |v: f64, n: f64| ((v * 0.5 + 0.5) * n).clamp(0.0, n);
        rects.push(PxRect::new(
            px(lo[0], w).floor() as u32,
            (h - px(hi[1], h)).floor() as u32,
            px(hi[0], w).ceil() as u32,
            (h - px(lo[1], h)).ceil() as u32,
        ));
        keys.push(k);
        let f = |v: glam::DVec3| [v.x as f32, v.y as f32, v.z as f32, 0.0];
        boxes.push([f(c[0]), f(c[1] - c[0]), f(c[2] - c[0]), f(c[4] - c[0])]);
    }
    let cfg = TileSchedulerConfig {
        queries_per_frame: queries_per_frame.clamp(1, MAX_QUERIES_PER_FRAME) as usize,
        min_tile_px: MIN_TILE_PX,
    };
    let s = schedule_tiles(
        PxRect::new(0, 0, view.size[0], view.size[1]),
        &rects,
        &cfg,
        frame,
    );
    let batch = QueryBatch {
        boxes: s.queried.iter().map(|&i| boxes[i]).collect(),
        keys: s.queried.iter().map(|&i| keys[i]).collect(),
        view_proj: view.view_proj_f32().to_cols_array_2d(),
        reversed: view.camera.depth == DepthConvention::ReversedZ,
        schedule: QuerySchedule {
            queries: s.queried.len() as u32,
            period: s.period as u32,
            tiles: s.tiles.len() as u32,
            near_visible: near.len() as u32,
        },
    };
    (batch, near)
}

impl Streamer {
    /// This frame's occlusion queries, one batch per view (empty when the
    /// policy queries nothing). Leaves whose box reaches behind a view's eye
    /// count as visible now, and the visibility state holds a leaf's state
    /// for at least the rotation's period (until it is queried again).
    pub(super) fn schedule_queries(
        &mut self,
        views: &Views,
        frames: &[FrameView],
    ) -> Vec<QueryBatch> {
        if !self.manager.config().visibility.occlusion_queries() {
            return vec![QueryBatch::default(); frames.len()];
        }
        let keys: Vec<NodeKey> = self.leaves.iter().map(|l| l.1).collect();
        let per_view = self.manager.config().visibility_config.queries_per_frame;
        let mut out = Vec::with_capacity(frames.len());
        for (geo, view) in views.geometries().iter().zip(frames) {
            let (batch, near) = schedule_view(geo, view, self.frame, &keys, per_view);
            // A box reaching behind the eye cannot be rasterised whole: visible.
            for k in near {
                self.visibility.observe(self.frame, k, u32::MAX);
            }
            out.push(batch);
        }
        // A leaf keeps its state until the rotation queries it again.
        let period = out.iter().map(|b| b.schedule.period).max().unwrap_or(0);
        let mut c = self.visibility.config();
        if c.hold_frames < period {
            c.hold_frames = period;
            self.visibility.set_config(c);
        }
        out
    }
}
