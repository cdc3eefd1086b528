//! How refinement classifies a node (empty, invisible, culled, data) from
//! its metadata, and how it ranks one: the screen error of each metric
//! ([`ScreenError`]) and the heap's order, which under the error-aware
//! metrics is that error per brick a split adds ([`HeapItem`]).

use std::sync::Arc;

use super::{MetaClass, MetaState, NodeClass, RefineEnv, RefineParams, Views, is_visible};
use brickray_core::{
    EmptyReason, NodeInfo, NodeKey, OctreeLayout, RenderMode, TfErrorTable, node_pixel_error,
    node_visible_error,
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
#[derive(Debug, Clone)]
pub(super) struct Classified {
    pub(super) class: NodeClass,
    pub(super) uniform: bool,
    /// Its metadata (for data nodes classified with it).
    pub(super) info: Option<Arc<NodeInfo>>,
}

/// Why a node could not be classified.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Unknown {
    Pending,
    Failed,
}

/// The frame's test of a node that holds data: visible under the mode,
/// transfer function and channels of `params` ([`is_visible`]).
pub(super) fn visible_under<'p>(
    params: &'p RefineParams<'_>,
    layout: &'p OctreeLayout,
) -> impl Fn(&NodeInfo) -> bool + 'p {
    move |i| is_visible(i, params.mode, params.tf, params.channels, layout)
}

/// Classifies `key` under the view from its class
/// ([`RefineEnv::meta_class`]): empty, invisible under the mode and
/// transfer function, culled, or data. With `with_info` a data node's
/// metadata is read too ([`RefineEnv::node`]); without it, its
/// [`Classified::info`] is `None` (see [`known_info`]).
pub(super) fn classify(
    key: NodeKey,
    layout: &OctreeLayout,
    params: &RefineParams<'_>,
    geo: &Views,
    env: &mut dyn RefineEnv,
    with_info: bool,
) -> Result<Classified, Unknown> {
    let empty = |reason| Classified {
        class: NodeClass::Empty(reason),
        uniform: false,
        info: None,
    };
    if !layout.in_volume(key) {
        return Ok(empty(EmptyReason::Empty));
    }
    let uniform = match env.meta_class(key, &visible_under(params, layout)) {
        MetaClass::Empty => return Ok(empty(EmptyReason::Empty)),
        MetaClass::Invisible => return Ok(empty(EmptyReason::Invisible)),
        MetaClass::Pending => return Err(Unknown::Pending),
        MetaClass::Failed => return Err(Unknown::Failed),
        MetaClass::Data { uniform } => uniform,
    };
    if geo.culled(key) {
        return Ok(empty(EmptyReason::Culled));
    }
    if !with_info {
        return Ok(Classified {
            class: NodeClass::Data,
            uniform,
            info: None,
        });
    }
    match env.node(key) {
        MetaState::Known(info) => Ok(Classified {
            class: NodeClass::Data,
            uniform,
            info: Some(info),
        }),
        MetaState::Pending => Err(Unknown::Pending),
        MetaState::Failed => Err(Unknown::Failed),
    }
}

/// The classification of a node's children (`children.len()` first
/// entries), or `None` while a child's metadata is pending or failed.
pub(super) fn classify_children(
    children: &[NodeKey],
    layout: &OctreeLayout,
    params: &RefineParams<'_>,
    geo: &Views,
    env: &mut dyn RefineEnv,
    with_info: bool,
) -> Option<[Classified; 8]> {
    let mut classes = [UNCLASSIFIED; 8];
    for (c, out) in children.iter().zip(classes.iter_mut()) {
        *out = classify(*c, layout, params, geo, env, with_info).ok()?;
    }
    Some(classes)
}

/// A node's metadata where it is known.
pub(super) fn known_info(env: &mut dyn RefineEnv, key: NodeKey) -> Option<Arc<NodeInfo>> {
    match env.node(key) {
        MetaState::Known(info) => Some(info),
        MetaState::Pending | MetaState::Failed => None,
    }
}

/// What ranks drawing a child's region from `parent`'s brick: `parent`'s
/// metadata with its error record replaced by the `child`'s parent-error
/// record where the source has one (per channel for a multi-channel node).
pub(super) fn drawn_from(parent: &NodeInfo, child: Option<&NodeInfo>) -> NodeInfo {
    let mut d = parent.clone();
    let Some(child) = child else {
        return d;
    };
    if let Some(e) = child.parent_error {
        d.error = Some(e);
    }
    if let (Some(ce), Some(pe)) = (&child.channel_errors, &parent.channel_errors) {
        let mut m = (**pe).clone();
        for (own, from_parent) in m.error.iter_mut().zip(&ce.parent_error) {
            if from_parent.is_some() {
                *own = *from_parent;
            }
        }
        d.channel_errors = Some(std::sync::Arc::new(m));
    }
    d
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
    /// A node's measured visible weight is divided by this (`brick^2`) in
    /// its rank under the error-aware metrics
    /// ([`brickray_core::LodMetric::VisibleError`]).
    pub(super) weight_norm: f64,
    pub(super) threshold: f64,
    /// Error-aware refinement of a multi-channel volume: each visible
    /// channel's error table, single-channel layout and mode (its own
    /// isovalue); a node's error is the largest of its visible channels'.
    channels: Vec<ChannelRank>,
}

/// How one visible channel weighs a node's error.
struct ChannelRank {
    channel: usize,
    table: TfErrorTable,
    layout: OctreeLayout,
    mode: RenderMode,
}

impl ScreenError {
    pub(super) fn new(
        params: &RefineParams<'_>,
        root: Option<&NodeInfo>,
        layout: &OctreeLayout,
    ) -> ScreenError {
        let by_channel = layout.is_channel_volume() && !params.channels.is_empty();
        let has_errors = root.is_some_and(|i| match by_channel {
            true => i.channel_errors.is_some(),
            false => i.error.is_some(),
        });
        let channels = match by_channel && has_errors {
            true => params
                .channels
                .iter()
                .enumerate()
                .filter(|(_, s)| s.visible)
                .map(|(c, s)| ChannelRank {
                    channel: c,
                    table: TfErrorTable::new(&s.tf),
                    layout: layout.channel_layout(c),
                    mode: match params.mode {
                        RenderMode::Iso { color, .. } => RenderMode::Iso {
                            value: s.isovalue,
                            color,
                        },
                        m => m,
                    },
                })
                .collect(),
            false => Vec::new(),
        };
        match params.metric.budget() {
            Some(budget) if has_errors => ScreenError {
                channels,
                table: Some(TfErrorTable::new(params.tf)),
                weight_norm: (layout.brick as f64).powi(2).max(1.0),
                threshold: budget.max(0.0) as f64,
            },
            _ => ScreenError {
                channels,
                table: None,
                weight_norm: 1.0,
                threshold: params.tolerance_px.max(0.0) as f64,
            },
        }
    }

    /// Whether [`priority`](Self::priority) reads a node's metadata (under
    /// the error-aware metrics; the geometric rule needs its size only).
    pub(super) fn needs_info(&self) -> bool {
        self.table.is_some()
    }

    /// The node's priority: its projected voxel size, times 255 x its
    /// expected error under the mode and transfer function when error-aware
    /// (a node without error data counts as full-scale error); for a node
    /// with a `visible` weight, that weight times 255 x the per-sample
    /// expected error ([`node_visible_error`]) over `brick^2` instead.
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
        match (&self.table, info, visible) {
            // The node's summed pixel change, linearised (RefineEnv::visible_weight),
            // per brick^2 (LodMetric::VisibleError).
            (Some(t), Some(i), Some(w)) => {
                let e = self.error(i, params.mode, t, layout, node_visible_error);
                w.max(0.0) * 255.0 * e / self.weight_norm
            }
            (Some(t), Some(i), _) => {
                let e = self.error(i, params.mode, t, layout, |i, m, t, l| {
                    node_pixel_error(i, key.level, m, t, l)
                });
                // 0 x inf (a degenerate camera on a flat node) stays NaN: never refined.
                px * 255.0 * e
            }
            _ => px,
        }
    }

    /// The node's error by `f` (full scale where it has no record): of its
    /// own record, or for a multi-channel node the largest of its visible
    /// channels', each through its channel's table and mode.
    fn error(
        &self,
        i: &NodeInfo,
        mode: RenderMode,
        table: &TfErrorTable,
        layout: &OctreeLayout,
        f: impl Fn(&NodeInfo, RenderMode, &TfErrorTable, &OctreeLayout) -> Option<f64>,
    ) -> f64 {
        if self.channels.is_empty() {
            return f(i, mode, table, layout).unwrap_or(1.0);
        }
        self.channels
            .iter()
            .map(|c| f(&i.channel(c.channel), c.mode, &c.table, &c.layout).unwrap_or(1.0))
            .fold(0.0, f64::max)
    }
}
