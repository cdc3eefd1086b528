//! The out-of-core frame's feedback loop (docs/visibility.md): read-backs of
//! earlier frames (the ray caster's usage counts and visible weights, the
//! occlusion queries) feed the visibility state and the visible weights, which
//! steer refinement through [`Filter`]; the new cut goes back to them and to
//! the occlusion queries' scheduler.

use super::{MIN_TILE_PX, OutOfCore};
use crate::desc::FrameDesc;
use brickray_core::{LodMetric, NodeKey, TransferFunction, VolumeFrame};
use brickray_visibility::{VisibilityState, VisibleWeights};

/// How much more an inner node of the cut weighs for refinement than a leaf
/// (`VisibleWeights::ranked_weight`, which also holds the weight a node split
/// with while the view stays): a split node collapses only once its priority
/// falls below half the error budget.
pub(super) const WEIGHT_HYSTERESIS: f64 = 2.0;

/// What the visible weights' memory of a view holds for: the camera, the
/// volume's placement, and what decides the ranking (the mode, the transfer
/// function, the error and brick budgets). Any change starts a new view.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct WeightsView {
    camera: brickray_core::Camera,
    frame: VolumeFrame,
    mode: brickray_core::RenderMode,
    tf: TransferFunction,
    metric: LodMetric,
    brick_budget: Option<u32>,
}

/// Refinement's view of the feedback: the visibility state where a policy
/// culls, the visible weights where the metric ranks by them.
pub(super) struct Filter<'a> {
    pub(super) visibility: Option<&'a mut VisibilityState>,
    pub(super) weights: Option<&'a mut VisibleWeights>,
}

impl brickray_cache::SplitFilter for Filter<'_> {
    /// Not when hidden in the previous frames, nor when it collapsed
    /// `MAX_COLLAPSES` times in this view (`VisibleWeights::may_split`).
    fn may_split(&mut self, key: NodeKey) -> bool {
        self.visibility.as_mut().is_none_or(|v| v.visible(key))
            && self.weights.as_ref().is_none_or(|w| w.may_split(key))
    }

    /// The pixels a leaf last showed order its children's loads: `1 + ln(1 +
    /// pixels)` (1 when not observed; an invisible leaf is not split at all).
    fn request_weight(&mut self, key: NodeKey) -> f64 {
        self.visibility
            .as_ref()
            .and_then(|v| v.pixels(key))
            .map_or(1.0, |p| 1.0 + (1.0 + p as f64).ln())
    }

    fn visible_weight(&mut self, key: NodeKey) -> Option<f64> {
        self.weights
            .as_mut()
            .and_then(|w| w.ranked_weight(key, WEIGHT_HYSTERESIS))
    }
}

impl OutOfCore {
    /// Feeds what was read back since the last frame (never waits) to the
    /// visibility state (by the policy) and, when `weighted`, the visible
    /// weights, after forgetting the weights' memory of another view.
    pub(super) fn observe_feedback(
        &mut self,
        desc: &FrameDesc<'_>,
        tf: &TransferFunction,
        weighted: bool,
    ) {
        // What split nodes showed as leaves, and how often nodes collapsed,
        // hold for their view only.
        let same_view = self.weights_view.as_ref().is_some_and(|v| {
            v.camera == desc.camera
                && v.frame == desc.frame
                && v.mode == desc.settings.mode
                && v.metric == self.manager.config().lod_metric
                && v.brick_budget == self.manager.config().brick_budget
                && v.tf == *tf
        });
        if !same_view {
            self.weights.forget_view();
            self.weights_view = Some(WeightsView {
                camera: desc.camera,
                frame: desc.frame,
                mode: desc.settings.mode,
                tf: tf.clone(),
                metric: self.manager.config().lod_metric,
                brick_budget: self.manager.config().brick_budget,
            });
        }
        for u in self.pool.feedback.poll(self.frame) {
            if self.policy.ray_guided() {
                for &(key, count) in &u.counts {
                    self.visibility.observe(u.frame, key, count);
                }
            }
            // (Read-backs of frames drawn before the switch to VisibleError
            // hold no weights; VisibleWeights ignores them: their frames
            // precede every leaf's entry into its cut.)
            if weighted {
                for (&(key, _), &w) in u.counts.iter().zip(&u.weights) {
                    self.weights.observe(u.frame, key, w);
                }
            }
        }
        for (frame, key, samples) in self.occlusion.poll(self.frame) {
            if self.policy.occlusion_queries() {
                self.visibility.observe(frame, key, samples);
            }
        }
    }

    /// Hands the frame's cut (`self.leaves`, and refinement's own data
    /// leaves `refined`) to the visibility state and the weights, and
    /// schedules this frame's occlusion queries.
    pub(super) fn note_cut(
        &mut self,
        queue: &wgpu::Queue,
        desc: &FrameDesc<'_>,
        refined: &[NodeKey],
        weighted: bool,
    ) {
        let vp = desc.viewport;
        if self.policy.culls() {
            self.visibility
                .set_cut(self.frame, self.leaves.iter().map(|l| l.1));
        }
        if weighted {
            self.weights
                .set_cut(self.frame, self.leaves.iter().map(|l| l.1));
            self.weights.set_refined_cut(refined);
        } else {
            self.weights.clear();
        }
        if self.policy.occlusion_queries() {
            let geo = brickray_cache::refine::ViewGeometry::new(
                &self.layout,
                &desc.camera,
                vp.aspect() as f32,
                vp.height,
                &self.frame_of_world,
            );
            let keys: Vec<NodeKey> = self.leaves.iter().map(|l| l.1).collect();
            let near = self.occlusion.schedule(
                queue,
                &geo,
                &desc.camera,
                vp.aspect() as f32,
                [vp.width, vp.height],
                self.frame,
                &keys,
                self.visibility.config().queries_per_frame,
                MIN_TILE_PX,
            );
            // A box reaching behind the eye cannot be rasterised whole: visible.
            for k in near {
                self.visibility.observe(self.frame, k, u32::MAX);
            }
            // A leaf keeps its state until the rotation queries it again.
            let mut c = self.visibility.config();
            if c.hold_frames < self.occlusion.stats.period {
                c.hold_frames = self.occlusion.stats.period;
                self.visibility.set_config(c);
            }
        }
    }
}
