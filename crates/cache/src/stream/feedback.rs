//! The feedback loop of the planner (docs/visibility.md): what the renderer
//! read back of earlier frames (the ray caster's usage counts and visible
//! weights, the occlusion queries' results) feeds the visibility state and
//! the visible weights, which steer refinement through [`Filter`]; the new
//! cut goes back to them.

use super::{Streamer, WEIGHT_HYSTERESIS};
use brickray_core::{NodeKey, NodeMap};
use brickray_visibility::{VisibilityState, VisibleWeights};

/// One frame's usage counts, as the renderer read them back.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct UsageFrame {
    /// The frame (the planner's frame number) they were rendered in.
    pub frame: u64,
    /// Rays that reached each data leaf of that frame's cut.
    pub counts: Vec<(NodeKey, u32)>,
    /// The visible weight of each of those leaves, in the order of `counts`:
    /// the transmittance-weighted length of the rays through it, in finest
    /// voxels, summed over pixels (what `LodMetric::VisibleError` ranks by).
    /// The kernel measures them only when the plan asks
    /// ([`StreamPlan::measures_weights`](super::StreamPlan::measures_weights)):
    /// 0 otherwise.
    pub weights: Vec<f64>,
}

/// The result of one occlusion query.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct QueryResult {
    /// The frame it was issued in.
    pub frame: u64,
    /// The leaf whose box was drawn.
    pub key: NodeKey,
    /// Samples that passed the depth test.
    pub samples: u32,
}

/// What the renderer read back for one view since the last frame.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ViewFeedback {
    /// Usage counts (and visible weights), oldest first.
    pub usage: Vec<UsageFrame>,
    /// Occlusion query results.
    pub queries: Vec<QueryResult>,
}

/// Refinement's view of the feedback: the visibility state where a policy
/// culls, the visible weights where the metric ranks by them.
pub(super) struct Filter<'a> {
    pub(super) visibility: Option<&'a mut VisibilityState>,
    pub(super) weights: Option<&'a mut VisibleWeights>,
}

impl crate::refine::SplitFilter for Filter<'_> {
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

    fn is_inert(&self) -> bool {
        self.visibility.is_none() && self.weights.is_none()
    }

    fn visible_weight(&mut self, key: NodeKey) -> Option<f64> {
        self.weights
            .as_mut()
            .and_then(|w| w.ranked_weight(key, WEIGHT_HYSTERESIS))
    }
}

/// The usage frames of several views summed per frame and leaf: a leaf's
/// rays and visible weight over the views (a leaf is visible when any view
/// shows it; what the image shows of it is what every view shows).
fn merge_views(feedback: &[ViewFeedback]) -> Vec<UsageFrame> {
    if feedback.len() == 1 {
        return feedback[0].usage.clone();
    }
    type Rows = (Vec<(NodeKey, u32, f64)>, NodeMap<usize>);
    let mut frames: std::collections::BTreeMap<u64, Rows> = Default::default();
    for u in feedback.iter().flat_map(|f| &f.usage) {
        let (rows, at) = frames.entry(u.frame).or_default();
        for (i, &(key, count)) in u.counts.iter().enumerate() {
            let w = u.weights.get(i).copied().unwrap_or(0.0);
            match at.get(&key) {
                Some(&j) => {
                    rows[j].1 = rows[j].1.saturating_add(count);
                    rows[j].2 += w;
                }
                None => {
                    at.insert(key, rows.len());
                    rows.push((key, count, w));
                }
            }
        }
    }
    frames
        .into_iter()
        .map(|(frame, (rows, _))| UsageFrame {
            frame,
            counts: rows.iter().map(|r| (r.0, r.1)).collect(),
            weights: rows.iter().map(|r| r.2).collect(),
        })
        .collect()
}

impl Streamer {
    /// Feeds what was read back (never waits) to the visibility state (by
    /// the policy) and, when `weighted`, the visible weights.
    pub(super) fn observe(&mut self, feedback: &[ViewFeedback], weighted: bool) {
        let policy = self.manager.config().visibility;
        for u in merge_views(feedback) {
            if policy.ray_guided() {
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
        if policy.occlusion_queries() {
            for q in feedback.iter().flat_map(|f| &f.queries) {
                self.visibility.observe(q.frame, q.key, q.samples);
            }
        }
    }

    /// Hands the frame's cut (its data leaves, and refinement's own data
    /// leaves `refined`) to the visibility state and the weights.
    pub(super) fn note_cut(&mut self, refined: &[NodeKey], weighted: bool) {
        let frame = self.frame;
        if self.manager.config().visibility.culls() {
            self.visibility
                .set_cut(frame, self.leaves.iter().map(|l| l.1));
        }
        if weighted {
            self.weights.set_cut(frame, self.leaves.iter().map(|l| l.1));
            self.weights.set_refined_cut(refined);
        } else {
            self.weights.clear();
        }
    }
}
