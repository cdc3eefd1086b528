//! View- and transfer-function-dependent refinement (Gobbetti et al. 2008, sect. 4).
//!
//! Each frame the cut is rebuilt from the root: a max-heap of the cut's refinable
//! nodes, keyed by the projected screen-space size of their voxels, is refined
//! greedily. Terminal nodes are those outside the view frustum, empty or invisible
//! under the current mode and transfer function, uniform, at the finest level, or
//! already within the screen-error tolerance. A node is split only when the bricks
//! of all its visible children are on the GPU or in CPU memory (missing ones are
//! requested with the parent's priority), the pool has slots for them and the
//! frame's upload budget can take those not yet on the GPU.
//!
//! Classification uses node metadata only ([`RefineEnv::node`]); no brick is read.

use crate::upload::UploadBudget;
use brickray_core::{
    Camera, NodeInfo, NodeKey, NodeKind, OctreeLayout, Projection, RenderMode, TransferFunction,
    VolumeFrame,
};
use glam::{DMat4, DVec3, DVec4};
use std::collections::BinaryHeap;

/// Why a leaf of the cut needs no brick.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum EmptyReason {
    /// Outside the volume or empty by construction ([`NodeKind::Empty`]).
    Empty,
    /// Invisible under the current mode: transparent range for DVR, isovalue
    /// outside `[min, max]` for iso-surfaces.
    Invisible,
    /// Outside the view frustum.
    Culled,
    /// Its data is wanted but not available yet (only the root, before it loads),
    /// or could not be loaded.
    NotLoaded,
}

/// The classification of one node under a view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum NodeClass {
    /// Needs no brick.
    Empty(EmptyReason),
    /// Needs its brick.
    Data,
}

/// Where a node's brick is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DataState {
    /// In a GPU pool slot.
    OnGpu,
    /// In the CPU cache (not on the GPU).
    InCpu,
    /// Neither; may be queued or loading.
    Missing,
    /// Its load failed.
    Failed,
}

/// What refinement needs to know about the world outside it.
pub trait RefineEnv {
    /// Node metadata; `None` when it cannot be read (the node is then treated as
    /// unavailable data).
    fn node(&mut self, key: NodeKey) -> Option<NodeInfo>;
    /// Where the node's brick is.
    fn data(&mut self, key: NodeKey) -> DataState;
}

/// The view and the knobs of one refinement.
#[derive(Debug, Clone, Copy)]
pub struct RefineParams<'a> {
    /// The camera.
    pub camera: &'a Camera,
    /// Viewport width / height.
    pub aspect: f32,
    /// Viewport height in pixels.
    pub viewport_height_px: u32,
    /// The volume's placement in the world.
    pub volume_frame: &'a VolumeFrame,
    /// Render mode (decides emptiness).
    pub mode: RenderMode,
    /// Transfer function (decides DVR transparency).
    pub tf: &'a TransferFunction,
    /// Screen-space error tolerance: a node whose voxels project to at most this
    /// many pixels is not refined (default 1).
    pub tolerance_px: f32,
    /// Most leaves needing a brick (the pool's slot count).
    pub max_data_leaves: u32,
}

/// One leaf of a refined cut.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RefinedLeaf {
    /// The node.
    pub key: NodeKey,
    /// Whether it needs its brick.
    pub class: NodeClass,
    /// Projected voxel size in pixels (0 for culled and empty leaves).
    pub priority: f32,
    /// True when the brick is needed and not on the GPU (an upload this frame).
    pub needs_upload: bool,
}

/// Counts of refusals to split, by reason.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SplitBlocks {
    /// Children's data not in memory yet.
    pub missing_data: u32,
    /// A child's data or metadata failed to load.
    pub failed: u32,
    /// Not enough pool slots.
    pub pool_full: u32,
    /// Upload budget of the frame spent.
    pub upload_budget: u32,
}

/// The result of [`refine`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Refinement {
    /// Leaves covering the octree cube, each point in exactly one.
    pub leaves: Vec<RefinedLeaf>,
    /// Nodes to load, with priorities (higher first).
    pub requests: Vec<(NodeKey, f32)>,
    /// Why nodes were not split.
    pub blocked: SplitBlocks,
    /// Leaves needing a brick.
    pub data_leaves: u32,
}

/// Camera-dependent geometry of a refinement.
#[derive(Debug, Clone)]
pub struct ViewGeometry {
    planes: [DVec4; 6],
    model: DMat4,
    scale: [f64; 3],
    /// Finest-level voxel world size per axis.
    voxel_world: [f64; 3],
    levels: u8,
    eye: DVec3,
    near: f64,
    /// Pixels per world unit at distance 1 (perspective) or anywhere (ortho).
    px_per_unit: f64,
    perspective: bool,
}

impl ViewGeometry {
    /// Geometry of `camera` over `layout` placed by `frame`.
    pub fn new(
        layout: &OctreeLayout,
        camera: &Camera,
        aspect: f32,
        viewport_height_px: u32,
        frame: &VolumeFrame,
    ) -> Self {
        let vp = camera.view_proj(aspect).as_dmat4();
        let r = [vp.row(0), vp.row(1), vp.row(2), vp.row(3)];
        // wgpu clip space: -w <= x, y <= w, 0 <= z <= w.
        let planes = [
            r[3] + r[0],
            r[3] - r[0],
            r[3] + r[1],
            r[3] - r[1],
            r[2],
            r[3] - r[2],
        ];
        let model = frame.model.as_dmat4();
        let dims = layout.volume.dims;
        let voxel_world: [f64; 3] =
            std::array::from_fn(|a| model.col(a).truncate().length() / dims[a].max(1) as f64);
        let h = viewport_height_px.max(1) as f64;
        let (px_per_unit, perspective) = match camera.projection {
            Projection::Perspective { fov_y } => (h / (2.0 * (fov_y as f64 * 0.5).tan()), true),
            Projection::Orthographic { height } => (h / (height as f64).max(1e-30), false),
        };
        ViewGeometry {
            planes,
            model,
            scale: layout.volume_scale(),
            voxel_world,
            levels: layout.levels,
            eye: camera.eye.as_dvec3(),
            near: (camera.near as f64).max(1e-9),
            px_per_unit,
            perspective,
        }
    }

    /// The node's box in texture space, clipped to the volume `[0,1]^3`.
    pub fn tex_box(&self, key: NodeKey) -> (DVec3, DVec3) {
        let (o, side) = key.unit_box();
        let lo: [f64; 3] = std::array::from_fn(|a| (o[a] / self.scale[a]).min(1.0));
        let hi: [f64; 3] = std::array::from_fn(|a| ((o[a] + side) / self.scale[a]).min(1.0));
        (DVec3::from_array(lo), DVec3::from_array(hi))
    }

    /// The eight world-space corners of the node's (clipped) box.
    pub fn world_corners(&self, key: NodeKey) -> [DVec3; 8] {
        let (lo, hi) = self.tex_box(key);
        std::array::from_fn(|i| {
            let p = DVec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            );
            self.model.transform_point3(p)
        })
    }

    /// True when the node's box lies wholly outside one frustum plane (conservative:
    /// a node reported visible may still be off-screen).
    pub fn culled(&self, key: NodeKey) -> bool {
        let c = self.world_corners(key);
        self.planes
            .iter()
            .any(|p| c.iter().all(|q| p.truncate().dot(*q) + p.w < 0.0))
    }

    /// Projected size in pixels of one voxel of `key` at the node's nearest point
    /// to the eye (perspective) or anywhere (orthographic).
    pub fn voxel_pixels(&self, key: NodeKey) -> f64 {
        let shift = (self.levels - 1 - key.level.min(self.levels - 1)) as i32;
        let voxel = self.voxel_world.iter().fold(0.0f64, |m, v| m.max(*v)) * 2f64.powi(shift);
        if !self.perspective {
            return voxel * self.px_per_unit;
        }
        let c = self.world_corners(key);
        let lo = c.iter().fold(DVec3::splat(f64::INFINITY), |m, p| m.min(*p));
        let hi = c
            .iter()
            .fold(DVec3::splat(f64::NEG_INFINITY), |m, p| m.max(*p));
        let d = (self.eye.clamp(lo, hi) - self.eye).length().max(self.near);
        voxel * self.px_per_unit / d
    }
}

/// True when a node with this metadata can contribute to the image in `mode`.
pub fn is_visible(
    info: &NodeInfo,
    mode: RenderMode,
    tf: &TransferFunction,
    layout: &OctreeLayout,
) -> bool {
    let (min, max) = match info.kind {
        NodeKind::Empty => return false,
        NodeKind::Uniform(v) => (v, v),
        NodeKind::Data => (info.min, info.max),
    };
    let (a, b) = (layout.volume.normalize(min), layout.volume.normalize(max));
    let (lo, hi) = if a <= b { (a, b) } else { (b, a) };
    match mode {
        RenderMode::Dvr => !tf.is_transparent(lo, hi),
        // A node wholly inside the surface (min > iso) stays visible: a ray that
        // enters the volume there hits the surface at once (a capped cut), and an
        // empty leaf could not carry that inside state.
        RenderMode::Iso { value, .. } => value <= hi,
        _ => true,
    }
}

#[derive(Debug, PartialEq)]
struct HeapItem {
    priority: f64,
    key: NodeKey,
    uniform: bool,
    /// Its upload was charged to the budget when its parent was split.
    charged: bool,
}
impl Eq for HeapItem {}
impl PartialOrd for HeapItem {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for HeapItem {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.priority
            .total_cmp(&other.priority)
            .then_with(|| other.key.cmp(&self.key))
    }
}

/// Classification of a node that needs no data decisions.
fn classify(
    key: NodeKey,
    layout: &OctreeLayout,
    params: &RefineParams<'_>,
    geo: &ViewGeometry,
    env: &mut dyn RefineEnv,
) -> Result<(NodeClass, bool), ()> {
    if !layout.in_volume(key) {
        return Ok((NodeClass::Empty(EmptyReason::Empty), false));
    }
    let info = env.node(key).ok_or(())?;
    if info.kind == NodeKind::Empty {
        return Ok((NodeClass::Empty(EmptyReason::Empty), false));
    }
    if !is_visible(&info, params.mode, params.tf, layout) {
        return Ok((NodeClass::Empty(EmptyReason::Invisible), false));
    }
    if geo.culled(key) {
        return Ok((NodeClass::Empty(EmptyReason::Culled), false));
    }
    Ok((NodeClass::Data, matches!(info.kind, NodeKind::Uniform(_))))
}

/// Refines the octree of `layout` for one frame. `budget` is the frame's upload
/// budget (already started); bricks of split children not on the GPU are charged
/// to it, as is the root when it is the only leaf and not on the GPU.
pub fn refine(
    layout: &OctreeLayout,
    params: &RefineParams<'_>,
    env: &mut dyn RefineEnv,
    budget: &mut UploadBudget,
) -> Refinement {
    let geo = ViewGeometry::new(
        layout,
        params.camera,
        params.aspect,
        params.viewport_height_px,
        params.volume_frame,
    );
    let brick_bytes = layout.brick_bytes() as u64;
    let finest = layout.levels - 1;
    let tol = params.tolerance_px.max(0.0) as f64;
    let mut out = Refinement::default();
    let mut heap = BinaryHeap::new();

    let empty_leaf = |key, reason| RefinedLeaf {
        key,
        class: NodeClass::Empty(reason),
        priority: 0.0,
        needs_upload: false,
    };

    match classify(NodeKey::ROOT, layout, params, &geo, env) {
        Ok((NodeClass::Empty(r), _)) => {
            out.leaves.push(empty_leaf(NodeKey::ROOT, r));
            return out;
        }
        Ok((NodeClass::Data, uniform)) => {
            heap.push(HeapItem {
                priority: geo.voxel_pixels(NodeKey::ROOT),
                key: NodeKey::ROOT,
                uniform,
                charged: false,
            });
        }
        Err(()) => {
            out.leaves
                .push(empty_leaf(NodeKey::ROOT, EmptyReason::NotLoaded));
            out.blocked.failed += 1;
            return out;
        }
    }
    out.data_leaves = 1;
    if params.max_data_leaves == 0 {
        out.leaves
            .push(empty_leaf(NodeKey::ROOT, EmptyReason::NotLoaded));
        out.data_leaves = 0;
        out.blocked.pool_full += 1;
        return out;
    }
    // The root's brick is wanted first (it is charged to the upload budget only if
    // it ends up a leaf).
    if env.data(NodeKey::ROOT) == DataState::Missing {
        out.requests.push((NodeKey::ROOT, f32::MAX));
    }

    // Nodes that stay leaves and need their brick: (key, priority).
    let mut finals: Vec<(NodeKey, f64)> = Vec::new();
    while let Some(HeapItem {
        priority,
        key,
        uniform,
        charged,
    }) = heap.pop()
    {
        if uniform || key.level >= finest || priority <= tol {
            finals.push((key, priority));
            continue;
        }
        // Classify the children.
        let mut classes = [NodeClass::Empty(EmptyReason::Empty); 8];
        let mut uniforms = [false; 8];
        let mut meta_failed = false;
        for (i, c) in key.children().into_iter().enumerate() {
            match classify(c, layout, params, &geo, env) {
                Ok((cl, u)) => {
                    classes[i] = cl;
                    uniforms[i] = u;
                }
                Err(()) => meta_failed = true,
            }
        }
        if meta_failed {
            out.blocked.failed += 1;
            finals.push((key, priority));
            continue;
        }
        let children = key.children();
        let data: Vec<usize> = (0..8).filter(|&i| classes[i] == NodeClass::Data).collect();
        let states: Vec<DataState> = data.iter().map(|&i| env.data(children[i])).collect();
        if states.contains(&DataState::Failed) {
            out.blocked.failed += 1;
            finals.push((key, priority));
            continue;
        }
        let missing: Vec<usize> = data
            .iter()
            .zip(&states)
            .filter(|(_, s)| **s == DataState::Missing)
            .map(|(i, _)| *i)
            .collect();
        if !missing.is_empty() {
            for i in missing {
                out.requests.push((children[i], priority as f32));
            }
            out.blocked.missing_data += 1;
            finals.push((key, priority));
            continue;
        }
        if out.data_leaves - 1 + data.len() as u32 > params.max_data_leaves {
            out.blocked.pool_full += 1;
            finals.push((key, priority));
            continue;
        }
        // A split node charged at its parent's split is not uploaded after all.
        let uploads = states.iter().filter(|s| **s == DataState::InCpu).count() as u64;
        let release = if charged { brick_bytes } else { 0 };
        if uploads > 0 && !budget.try_exchange(release, uploads * brick_bytes) {
            out.blocked.upload_budget += 1;
            finals.push((key, priority));
            continue;
        }
        out.data_leaves = out.data_leaves - 1 + data.len() as u32;
        if uploads == 0 && charged {
            budget.release(brick_bytes);
        }
        let mut state = states.iter();
        for i in 0..8 {
            match classes[i] {
                NodeClass::Empty(r) => out.leaves.push(empty_leaf(children[i], r)),
                NodeClass::Data => heap.push(HeapItem {
                    priority: geo.voxel_pixels(children[i]),
                    key: children[i],
                    uniform: uniforms[i],
                    charged: state.next() == Some(&DataState::InCpu),
                }),
            }
        }
    }

    for (key, priority) in finals {
        let state = env.data(key);
        let available = match state {
            DataState::OnGpu => true,
            // Split children were charged when split; the root, if a leaf, is the
            // only leaf, so nothing else was charged and the reservation succeeds.
            DataState::InCpu => key != NodeKey::ROOT || budget.try_reserve(brick_bytes),
            DataState::Missing | DataState::Failed => false,
        };
        if available {
            out.leaves.push(RefinedLeaf {
                key,
                class: NodeClass::Data,
                priority: priority as f32,
                needs_upload: state == DataState::InCpu,
            });
        } else {
            out.data_leaves -= 1;
            out.leaves.push(empty_leaf(key, EmptyReason::NotLoaded));
        }
    }
    out
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use brickray_core::{DType, VolumeDesc};
    use glam::Vec3;
    use proptest::prelude::*;
    use std::collections::HashSet;

    /// A ball: raw value `clamp(1 - 2 |p - c|, 0, 1)` over texture space; nodes
    /// wholly outside the ball are `Empty`.
    pub(crate) fn ball_info(layout: &OctreeLayout, key: NodeKey) -> NodeInfo {
        let scale = layout.volume_scale();
        let (o, side) = key.unit_box();
        let mut near2 = 0.0;
        let mut far2 = 0.0;
        for a in 0..3 {
            let lo = (o[a] / scale[a]).min(1.0);
            let hi = ((o[a] + side) / scale[a]).min(1.0);
            let n = (0.5f64.clamp(lo, hi) - 0.5).abs();
            let f = (lo - 0.5).abs().max((hi - 0.5).abs());
            near2 += n * n;
            far2 += f * f;
        }
        let max = (1.0 - 2.0 * near2.sqrt()).max(0.0) as f32;
        let min = (1.0 - 2.0 * far2.sqrt()).max(0.0) as f32;
        let kind = if max <= 0.0 {
            NodeKind::Empty
        } else {
            NodeKind::Data
        };
        NodeInfo { kind, min, max }
    }

    pub(crate) fn ball_layout(dim: u32) -> OctreeLayout {
        let desc = VolumeDesc {
            dims: [dim; 3],
            dtype: DType::U8,
            spacing: [1.0; 3],
            value_range: [0.0, 1.0],
        };
        OctreeLayout::new(desc, 8, 1)
    }

    /// Every brick available in CPU memory; metadata from the ball.
    struct AllInCpu {
        layout: OctreeLayout,
        on_gpu: HashSet<NodeKey>,
        meta_reads: usize,
    }

    impl RefineEnv for AllInCpu {
        fn node(&mut self, key: NodeKey) -> Option<NodeInfo> {
            self.meta_reads += 1;
            Some(ball_info(&self.layout, key))
        }
        fn data(&mut self, key: NodeKey) -> DataState {
            if self.on_gpu.contains(&key) {
                DataState::OnGpu
            } else {
                DataState::InCpu
            }
        }
    }

    pub(crate) fn assert_exact_cover(leaves: &[NodeKey], levels: u8) {
        let set: HashSet<NodeKey> = leaves.iter().copied().collect();
        assert_eq!(set.len(), leaves.len(), "duplicate leaves");
        for l in leaves {
            let mut p = l.parent();
            while let Some(k) = p {
                assert!(
                    !set.contains(&k),
                    "{k:?} and its descendant {l:?} are both leaves"
                );
                p = k.parent();
            }
            assert!(l.level < levels);
        }
        let deepest = levels as u32 - 1;
        let total: u128 = leaves
            .iter()
            .map(|l| 1u128 << (3 * (deepest - l.level as u32)))
            .sum();
        assert_eq!(
            total,
            1u128 << (3 * deepest),
            "leaves do not cover the cube"
        );
    }

    struct Setup {
        layout: OctreeLayout,
        frame: VolumeFrame,
        tf: TransferFunction,
    }

    fn setup() -> Setup {
        let layout = ball_layout(64);
        let frame = VolumeFrame::centered([64; 3], [1.0; 3]);
        Setup {
            layout,
            frame,
            tf: TransferFunction::ramp(0.0, 1.0, 1.0),
        }
    }

    fn run(
        s: &Setup,
        cam: &Camera,
        mode: RenderMode,
        tf: &TransferFunction,
        slots: u32,
        budget: u64,
    ) -> Refinement {
        let mut env = AllInCpu {
            layout: s.layout.clone(),
            on_gpu: HashSet::new(),
            meta_reads: 0,
        };
        let params = RefineParams {
            camera: cam,
            aspect: 1.0,
            viewport_height_px: 512,
            volume_frame: &s.frame,
            mode,
            tf,
            tolerance_px: 1.0,
            max_data_leaves: slots,
        };
        let mut b = UploadBudget::new(budget);
        refine(&s.layout, &params, &mut env, &mut b)
    }

    fn keys(r: &Refinement) -> Vec<NodeKey> {
        r.leaves.iter().map(|l| l.key).collect()
    }

    fn count(r: &Refinement, class: NodeClass) -> usize {
        r.leaves.iter().filter(|l| l.class == class).count()
    }

    #[test]
    fn close_view_refines_to_finest_far_view_stays_coarse() {
        let s = setup();
        let near = Camera::orbit(Vec3::ZERO, 1.5, 0.3, 0.2);
        let r = run(&s, &near, RenderMode::Dvr, &s.tf, 10_000, u64::MAX);
        assert_exact_cover(&keys(&r), s.layout.levels);
        assert!(
            r.leaves
                .iter()
                .any(|l| l.key.level == s.layout.levels - 1 && l.class == NodeClass::Data)
        );
        assert_eq!(r.data_leaves as usize, count(&r, NodeClass::Data));
        let far = Camera::orbit(Vec3::ZERO, 400.0, 0.3, 0.2);
        let r = run(&s, &far, RenderMode::Dvr, &s.tf, 10_000, u64::MAX);
        assert_eq!(keys(&r), vec![NodeKey::ROOT]);
        assert!(r.leaves[0].needs_upload);
    }

    #[test]
    fn frustum_culling_drops_offscreen_nodes() {
        let s = setup();
        // Looking away from the volume: everything culled at the root.
        let mut away = Camera::orbit(Vec3::ZERO, 2.0, 0.0, 0.0);
        away.target = away.eye * 2.0;
        let r = run(&s, &away, RenderMode::Dvr, &s.tf, 10_000, u64::MAX);
        assert_eq!(r.leaves.len(), 1);
        assert_eq!(r.leaves[0].class, NodeClass::Empty(EmptyReason::Culled));
        // Close up on one corner: many culled leaves, and no culled leaf projects on screen.
        let cam = Camera {
            target: Vec3::splat(0.4),
            ..Camera::orbit(Vec3::ZERO, 0.0, 0.0, 0.0)
        };
        let cam = Camera {
            eye: Vec3::new(0.4, 0.4, 1.0),
            ..cam
        };
        let r = run(&s, &cam, RenderMode::Mip, &s.tf, 10_000, u64::MAX);
        assert_exact_cover(&keys(&r), s.layout.levels);
        let culled: Vec<_> = r
            .leaves
            .iter()
            .filter(|l| l.class == NodeClass::Empty(EmptyReason::Culled))
            .collect();
        assert!(!culled.is_empty());
        let geo = ViewGeometry::new(&s.layout, &cam, 1.0, 512, &s.frame);
        let vp = cam.view_proj(1.0).as_dmat4();
        for l in culled {
            // Sample the box densely: no point projects inside the clip volume.
            let c = geo.world_corners(l.key);
            for t in 0..125 {
                let f = [
                    (t % 5) as f64 / 4.0,
                    ((t / 5) % 5) as f64 / 4.0,
                    (t / 25) as f64 / 4.0,
                ];
                let p = c[0] + (c[1] - c[0]) * f[0] + (c[2] - c[0]) * f[1] + (c[4] - c[0]) * f[2];
                let q = vp * p.extend(1.0);
                let inside = q.x.abs() <= q.w && q.y.abs() <= q.w && q.z >= 0.0 && q.z <= q.w;
                assert!(!inside, "culled {:?} is visible at {p:?}", l.key);
            }
        }
        assert!(count(&r, NodeClass::Data) > 0);
    }

    #[test]
    fn empty_and_invisible_nodes_are_terminal() {
        let s = setup();
        let cam = Camera::orbit(Vec3::ZERO, 1.5, 0.3, 0.2);
        // Fully transparent TF: the root is invisible and nothing is requested.
        let clear = TransferFunction::ramp(1.0, 1.0, 0.0);
        let r = run(&s, &cam, RenderMode::Dvr, &clear, 10_000, u64::MAX);
        assert_eq!(r.leaves.len(), 1);
        assert_eq!(r.leaves[0].class, NodeClass::Empty(EmptyReason::Invisible));
        assert!(r.requests.is_empty());
        // MIP: only the Empty corners of the ball are terminal-empty, none invisible.
        let r = run(&s, &cam, RenderMode::Mip, &s.tf, 10_000, u64::MAX);
        assert!(count(&r, NodeClass::Empty(EmptyReason::Empty)) > 0);
        assert_eq!(count(&r, NodeClass::Empty(EmptyReason::Invisible)), 0);
        // Iso at 0.9: only nodes reaching 0.9 (near the centre) hold data.
        let iso = RenderMode::Iso {
            value: 0.9,
            color: [1.0; 3],
        };
        let r = run(&s, &cam, iso, &s.tf, 10_000, u64::MAX);
        assert_exact_cover(&keys(&r), s.layout.levels);
        for l in &r.leaves {
            let info = ball_info(&s.layout, l.key);
            match l.class {
                NodeClass::Data => assert!(info.min <= 0.9 && 0.9 <= info.max, "{l:?}"),
                NodeClass::Empty(EmptyReason::Invisible) => {
                    assert!(!(info.min <= 0.9 && 0.9 <= info.max))
                }
                _ => {}
            }
        }
        assert!(count(&r, NodeClass::Empty(EmptyReason::Invisible)) > 0);
    }

    #[test]
    fn tiny_pool_gives_coarser_complete_cut() {
        let s = setup();
        let cam = Camera::orbit(Vec3::ZERO, 1.5, 0.3, 0.2);
        let big = run(&s, &cam, RenderMode::Mip, &s.tf, 10_000, u64::MAX);
        for slots in [1u32, 3, 8, 20] {
            let r = run(&s, &cam, RenderMode::Mip, &s.tf, slots, u64::MAX);
            assert_exact_cover(&keys(&r), s.layout.levels);
            assert!(r.data_leaves <= slots);
            assert!(r.data_leaves < big.data_leaves);
            assert!(r.blocked.pool_full > 0);
        }
        let r = run(&s, &cam, RenderMode::Mip, &s.tf, 0, u64::MAX);
        assert_eq!(r.leaves[0].class, NodeClass::Empty(EmptyReason::NotLoaded));
    }

    #[test]
    fn upload_budget_limits_splits_but_progresses() {
        let s = setup();
        let cam = Camera::orbit(Vec3::ZERO, 1.5, 0.3, 0.2);
        let r = run(&s, &cam, RenderMode::Mip, &s.tf, 10_000, 0);
        assert_exact_cover(&keys(&r), s.layout.levels);
        // Only the first split is let through (progress), whatever its size.
        assert_eq!(r.leaves.len(), 8);
        assert!(r.leaves.iter().all(|l| l.key.level == 1 && l.needs_upload));
        assert!(r.blocked.upload_budget > 0);
        // Larger budgets: more splits, and the bricks uploaded (leaves not on the
        // GPU; split nodes charged at their parent's split are given back) stay
        // within the budget once past the first split.
        let brick = s.layout.brick_bytes() as u64;
        let mut last = r.leaves.len();
        for n in [16u64, 22, 40, 100] {
            let r = run(&s, &cam, RenderMode::Mip, &s.tf, 10_000, n * brick);
            assert_exact_cover(&keys(&r), s.layout.levels);
            let uploads = r.leaves.iter().filter(|l| l.needs_upload).count() as u64;
            assert!(uploads <= n, "{uploads} > {n}");
            assert!(uploads + 8 > n, "budget {n} underused: {uploads}");
            assert!(r.leaves.len() >= last);
            last = r.leaves.len();
        }
    }

    #[test]
    fn tf_change_reclassifies_from_metadata_only() {
        let s = setup();
        let cam = Camera::orbit(Vec3::ZERO, 1.5, 0.3, 0.2);
        let a = run(
            &s,
            &cam,
            RenderMode::Dvr,
            &TransferFunction::ramp(0.0, 0.2, 1.0),
            10_000,
            u64::MAX,
        );
        let b = run(
            &s,
            &cam,
            RenderMode::Dvr,
            &TransferFunction::ramp(0.7, 1.0, 1.0),
            10_000,
            u64::MAX,
        );
        assert_exact_cover(&keys(&b), s.layout.levels);
        assert!(b.data_leaves < a.data_leaves);
        assert!(
            count(&b, NodeClass::Empty(EmptyReason::Invisible))
                > count(&a, NodeClass::Empty(EmptyReason::Invisible))
        );
    }

    fn arb_camera() -> impl Strategy<Value = Camera> {
        (
            0.0f32..6.3,
            -1.5f32..1.5,
            0.3f32..20.0,
            any::<bool>(),
            0.1f32..3.0,
            -0.6f32..0.6,
        )
            .prop_map(|(yaw, pitch, dist, ortho, h, off)| {
                let mut c = Camera::orbit(Vec3::splat(off), dist, yaw, pitch);
                if ortho {
                    c.projection = Projection::Orthographic { height: h };
                }
                c
            })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// Every point of the octree cube is in exactly one leaf, for any camera,
        /// mode, tolerance and pool size; data leaves never exceed the pool.
        #[test]
        fn cut_covers_cube_exactly(
            cam in arb_camera(),
            slots in 1u32..300,
            tol in 0.5f32..4.0,
            mode in prop_oneof![Just(RenderMode::Dvr), Just(RenderMode::Mip), (0.0f32..1.0).prop_map(|v| RenderMode::Iso { value: v, color: [1.0; 3] })],
            dim in prop_oneof![Just(40u32), Just(64), Just(100)],
        ) {
            let layout = ball_layout(dim);
            let frame = VolumeFrame::centered([dim; 3], [1.0; 3]);
            let tf = TransferFunction::ramp(0.3, 1.0, 0.5);
            let mut env = AllInCpu { layout: layout.clone(), on_gpu: HashSet::new(), meta_reads: 0 };
            let params = RefineParams { camera: &cam, aspect: 1.3, viewport_height_px: 400, volume_frame: &frame, mode, tf: &tf, tolerance_px: tol, max_data_leaves: slots };
            let mut b = UploadBudget::new(u64::MAX);
            let r = refine(&layout, &params, &mut env, &mut b);
            assert_exact_cover(&keys(&r), layout.levels);
            prop_assert!(r.data_leaves <= slots);
            prop_assert_eq!(r.data_leaves as usize, count(&r, NodeClass::Data));
            for l in &r.leaves {
                if l.class == NodeClass::Data {
                    prop_assert!(layout.in_volume(l.key));
                }
            }
        }
    }
}
