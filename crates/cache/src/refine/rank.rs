//! How refinement classifies a node (empty, invisible, culled, data) from
//! its metadata, and how it ranks one: the screen error of each metric
//! ([`ScreenError`]) and the heap's order, which under the error-aware
//! metrics is that error per brick a split adds ([`HeapItem`]).

use super::{MetaState, NodeClass, RefineEnv, RefineParams, Views, is_visible};
use brickray_core::{
    EmptyReason, LodMetric, NodeInfo, NodeKey, NodeKind, OctreeLayout, TfErrorTable,
    node_pixel_error, node_tf_error, node_visible_error,
};

/// A node in refinement's max-heap.
#[derive(Debug, PartialEq)]
pub(super) struct HeapItem {
    /// The heap's key: the priority, or under error-aware refinement, once
    /// the node's children are known, the priority per brick its split adds.
    pub(super) order: f64,
    /// The node's screen error (the tolerance test, its requests and leaf).
    pub(super) priority: f64,
    /// Set once `order` is the priority per brick: the index of its
    /// children's classification (kept for the split).
    pub(super) classified: Option<u32>,
    pub(super) key: NodeKey,
    pub(super) uniform: bool,
    /// Its upload was charged to the budget when its parent was split.
    pub(super) charged: bool,
}
impl Eq for HeapItem {}
impl PartialOrd for HeapItem {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for HeapItem {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.order
            .total_cmp(&other.order)
            .then_with(|| other.key.cmp(&self.key))
    }
}

/// A classified node.
#[derive(Debug, Clone, Copy)]
pub(super) struct Classified {
    pub(super) class: NodeClass,
    pub(super) uniform: bool,
    /// Its metadata (for nodes inside the volume).
    pub(super) info: Option<NodeInfo>,
}

/// Why a node could not be classified.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Unknown {
    Pending,
    Failed,
}

/// Classifies `key` under the view from its metadata: empty, invisible
/// under the mode and transfer function, culled, or data.
pub(super) fn classify(
    key: NodeKey,
    layout: &OctreeLayout,
    params: &RefineParams<'_>,
    geo: &Views,
    env: &mut dyn RefineEnv,
) -> Result<Classified, Unknown> {
    let empty = |reason, info| Classified {
        class: NodeClass::Empty(reason),
        uniform: false,
        info,
    };
    if !layout.in_volume(key) {
        return Ok(empty(EmptyReason::Empty, None));
    }
    let info = match env.node(key) {
        MetaState::Known(info) => info,
        MetaState::Pending => return Err(Unknown::Pending),
        MetaState::Failed => return Err(Unknown::Failed),
    };
    if info.kind == NodeKind::Empty {
        return Ok(empty(EmptyReason::Empty, Some(info)));
    }
    if !is_visible(&info, params.mode, params.tf, params.channels, layout) {
        return Ok(empty(EmptyReason::Invisible, Some(info)));
    }
    if geo.culled(key) {
        return Ok(empty(EmptyReason::Culled, Some(info)));
    }
    Ok(Classified {
        class: NodeClass::Data,
        uniform: matches!(info.kind, NodeKind::Uniform(_)),
        info: Some(info),
    })
}

/// The classification of a node's children (`children.len()` first
/// entries), or `None` while a child's metadata is pending or failed.
pub(super) fn classify_children(
    children: &[NodeKey],
    layout: &OctreeLayout,
    params: &RefineParams<'_>,
    geo: &Views,
    env: &mut dyn RefineEnv,
) -> Option<[Classified; 8]> {
    let mut classes = [UNCLASSIFIED; 8];
    for (c, out) in children.iter().zip(classes.iter_mut()) {
        *out = classify(*c, layout, params, geo, env).ok()?;
    }
    Some(classes)
}

/// Placeholder of a child array's unused entries.
pub(super) const UNCLASSIFIED: Classified = Classified {
    class: NodeClass::Empty(EmptyReason::Empty),
    uniform: false,
    info: None,
};

/// How one refinement weighs a node's projected voxel size.
pub(super) struct ScreenError {
    /// `Some` for error-aware refinement over a source with error bounds.
    pub(super) table: Option<TfErrorTable>,
    /// The strict bound ([`LodMetric::ErrorBound`]) instead of the expected error.
    pub(super) strict: bool,
    /// Ranks by measured visible weights ([`LodMetric::VisibleError`]), divided
    /// by this (`brick^2`); `None`: weights are not used.
    pub(super) weight_norm: Option<f64>,
    pub(super) threshold: f64,
}

impl ScreenError {
    pub(super) fn new(
        params: &RefineParams<'_>,
        root: Option<&NodeInfo>,
        layout: &OctreeLayout,
    ) -> ScreenError {
        let has_errors = root.is_some_and(|i| i.error.is_some());
        match params.metric.budget() {
            Some(budget) if has_errors => ScreenError {
                table: Some(TfErrorTable::new(params.tf)),
                strict: matches!(params.metric, LodMetric::ErrorBound { .. }),
                weight_norm: params
                    .metric
                    .uses_visible_weights()
                    .then(|| (layout.brick as f64).powi(2).max(1.0)),
                threshold: budget.max(0.0) as f64,
            },
            _ => ScreenError {
                table: None,
                strict: false,
                weight_norm: None,
                threshold: params.tolerance_px.max(0.0) as f64,
            },
        }
    }

    /// The node's priority: its projected voxel size, times 255 x its
    /// expected error (or its bound) under the mode and transfer function when
    /// error-aware (a node without error data counts as full-scale error);
    /// under [`LodMetric::VisibleError`], for a node with a `visible` weight,
    /// that weight times 255 x the per-sample expected error
    /// ([`node_visible_error`]) over `brick^2` instead.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn priority(
        &self,
        px: f64,
        visible: Option<f64>,
        key: NodeKey,
        info: Option<&NodeInfo>,
        params: &RefineParams<'_>,
        layout: &OctreeLayout,
    ) -> f64 {
        match (&self.table, info, visible.zip(self.weight_norm)) {
            // The node's summed pixel change, linearised (RefineEnv::visible_weight),
            // per brick^2 (LodMetric::VisibleError).
            (Some(t), Some(i), Some((w, norm))) => {
                let e = node_visible_error(i, params.mode, t, layout).unwrap_or(1.0);
                w.max(0.0) * 255.0 * e / norm
            }
            (Some(t), Some(i), _) => {
                let e = if self.strict {
                    node_tf_error(i, params.mode, t, layout)
                } else {
                    node_pixel_error(i, key.level, params.mode, t, layout)
                }
                .unwrap_or(1.0);
                // 0 x inf (a degenerate camera on a flat node) stays NaN: never refined.
                px * 255.0 * e
            }
            _ => px,
        }
    }
}
