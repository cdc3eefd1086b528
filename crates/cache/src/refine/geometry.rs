//! Camera-dependent geometry of a refinement (frustum planes, projected voxel
//! size) and the metadata-only visibility test.

use brickray_core::{
    Camera, ClipBox, FrameView, NodeInfo, NodeKey, NodeKind, OctreeLayout, Projection, RenderMode,
    TransferFunction, VolumeFrame,
};
use glam::{DMat4, DVec3, DVec4};

/// Camera-dependent geometry of a refinement.
#[derive(Debug, Clone)]
pub struct ViewGeometry {
    planes: [DVec4; 6],
    view_proj: DMat4,
    model: DMat4,
    scale: [f64; 3],
    /// Per level, the node size in octree unit-box coordinates per axis.
    unit_size: Vec<[f64; 3]>,
    /// Per level, the world size of the voxel the LOD metric projects
    /// ([`lod_voxel_world`]).
    lod_voxel: Vec<f64>,
    eye: DVec3,
    near: f64,
    /// Pixels per world unit at distance 1 (perspective) or anywhere (ortho).
    px_per_unit: f64,
    perspective: bool,
    /// The clip box (texture space): nodes wholly outside it are culled.
    clip: [DVec3; 2],
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
        let view_proj = camera.view_proj(aspect).as_dmat4();
        Self::build(
            layout,
            camera,
            view_proj,
            viewport_height_px,
            frame,
            ClipBox::FULL,
        )
    }

    /// Geometry of one frame's view over `layout` (its view-projection as
    /// the view computed it).
    pub fn of(layout: &OctreeLayout, view: &FrameView) -> Self {
        Self::build(
            layout,
            &view.camera,
            view.view_proj,
            view.height(),
            &view.placement,
            view.clip,
        )
    }

    fn build(
        layout: &OctreeLayout,
        camera: &Camera,
        vp: DMat4,
        viewport_height_px: u32,
        frame: &VolumeFrame,
        clip: ClipBox,
    ) -> Self {
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
        let lod_voxel = (0..layout.levels)
            .map(|l| lod_voxel_world(layout, voxel_world, l))
            .collect();
        let unit_size = (0..layout.levels)
            .map(|l| layout.nodes_per_axis(l).map(|n| 1.0 / n as f64))
            .collect();
        let h = viewport_height_px.max(1) as f64;
        let (mut px_per_unit, perspective) = match camera.projection {
            Projection::Perspective { fov_y } => (h / (2.0 * (fov_y as f64 * 0.5).tan()), true),
            Projection::Orthographic { height } => (h / (height as f64).max(1e-30), false),
        };
        // A degenerate camera or frame (NaN or infinite matrices, zero-size
        // projection, eye on the target) projects nothing meaningfully: every
        // projected size becomes NaN, so nothing is refined.
        if !(vp.is_finite() && model.is_finite() && camera.eye.is_finite()) {
            px_per_unit = f64::NAN;
        }
        ViewGeometry {
            planes,
            view_proj: vp,
            model,
            scale: layout.volume_scale(),
            unit_size,
            lod_voxel,
            eye: camera.eye.as_dvec3(),
            near: (camera.near as f64).max(1e-9),
            px_per_unit,
            perspective,
            clip: [
                DVec3::from_array(clip.min.map(f64::from)),
                DVec3::from_array(clip.max.map(f64::from)),
            ],
        }
    }

    /// The view-projection the geometry projects with.
    pub fn view_proj(&self) -> DMat4 {
        self.view_proj
    }

    /// The node's box in texture space, clipped to the volume `[0,1]^3`.
    pub fn tex_box(&self, key: NodeKey) -> (DVec3, DVec3) {
        let last = self.unit_size.len().saturating_sub(1);
        let size = self.unit_size[(key.level as usize).min(last)];
        let p = [key.x, key.y, key.z];
        let o: [f64; 3] = std::array::from_fn(|a| p[a] as f64 * size[a]);
        let lo: [f64; 3] = std::array::from_fn(|a| (o[a] / self.scale[a]).min(1.0));
        let hi: [f64; 3] = std::array::from_fn(|a| ((o[a] + size[a]) / self.scale[a]).min(1.0));
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

    /// True when the node's box lies wholly outside one frustum plane or
    /// wholly outside the clip box, where no ray samples (conservative: a node
    /// reported visible may still be off-screen).
    pub fn culled(&self, key: NodeKey) -> bool {
        let (lo, hi) = self.tex_box(key);
        if hi.cmplt(self.clip[0]).any() || lo.cmpgt(self.clip[1]).any() {
            return true;
        }
        let c = self.world_corners(key);
        self.planes
            .iter()
            .any(|p| c.iter().all(|q| p.truncate().dot(*q) + p.w < 0.0))
    }

    /// How central `key` is on screen: `1 / (1 + d)` with `d` the distance of
    /// its box's projected centre from the viewport's centre in normalized
    /// device coordinates (1 at the centre, 0.5 at an edge's midpoint, about
    /// 0.41 at a corner, less beyond). A centre behind the eye or not finite
    /// weighs 0.5. Orders load requests (the centre of the image first); never
    /// decides the cut.
    pub fn centre_weight(&self, key: NodeKey) -> f64 {
        let (lo, hi) = self.tex_box(key);
        let c = self.model.transform_point3((lo + hi) * 0.5);
        let clip = self.view_proj * c.extend(1.0);
        if !(clip.w > 0.0 && clip.is_finite()) {
            return 0.5;
        }
        let d = (clip.truncate().truncate() / clip.w).length();
        1.0 / (1.0 + d)
    }

    /// Projected size in pixels of one voxel of `key` ([`lod_voxel_world`]) at
    /// the node's nearest point to the eye (perspective) or anywhere
    /// (orthographic). Not finite (NaN or infinite) when the camera or the frame
    /// is not: refinement then does not refine the node.
    pub fn voxel_pixels(&self, key: NodeKey) -> f64 {
        let last = self.lod_voxel.len().saturating_sub(1);
        let voxel = self.lod_voxel[(key.level as usize).min(last)];
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

/// The views one refinement serves (one for a single view; two for a
/// stereo pair; a 3D view and slice views): a node is culled when every view
/// culls it, and its projected voxel size and centrality are the largest any
/// view gives it, so the cut holds each node at the finest level any view
/// needs.
#[derive(Debug, Clone)]
pub struct Views {
    views: Vec<ViewGeometry>,
}

impl Views {
    /// The geometry of each of `views` over `layout`.
    pub fn of(layout: &OctreeLayout, views: &[FrameView]) -> Views {
        Views {
            views: views.iter().map(|v| ViewGeometry::of(layout, v)).collect(),
        }
    }

    /// One view's geometry.
    pub fn one(view: ViewGeometry) -> Views {
        Views { views: vec![view] }
    }

    /// The views' geometries.
    pub fn geometries(&self) -> &[ViewGeometry] {
        &self.views
    }

    /// True when every view culls the node (no view: culled).
    pub fn culled(&self, key: NodeKey) -> bool {
        self.views.iter().all(|v| v.culled(key))
    }

    /// The largest projected voxel size of the node over the views (NaN when
    /// a view's is NaN: a degenerate view refines nothing).
    pub fn voxel_pixels(&self, key: NodeKey) -> f64 {
        self.views
            .iter()
            .map(|v| v.voxel_pixels(key))
            .reduce(|a, b| {
                if a.is_nan() || b.is_nan() {
                    f64::NAN
                } else {
                    a.max(b)
                }
            })
            .unwrap_or(f64::NAN)
    }

    /// The largest [`ViewGeometry::centre_weight`] over the views.
    pub fn centre_weight(&self, key: NodeKey) -> f64 {
        self.views
            .iter()
            .map(|v| v.centre_weight(key))
            .fold(0.0, f64::max)
    }
}

/// The world size of a voxel of `level` that the LOD metric projects: the largest
/// of its sides along the axes where the level is coarser than the finest data
/// (at the finest level: the axes its parent level splits; with one level: all
/// axes). Each side is the finest voxel's world side along that axis times the
/// level's per-axis voxel factor ([`OctreeLayout::voxel_factor`]).
///
/// Axes at full resolution are left out: no refinement can make them finer, so
/// they would hold a node above the tolerance however far it is refined (a CT
/// with 5 mm slices would never leave the finest level). In the isotropic
/// octree every axis is coarsened at every level but the finest, and this is the
/// largest voxel side times `2^(finest - level)`, exactly as before.
pub fn lod_voxel_world(layout: &OctreeLayout, voxel_world: [f64; 3], level: u8) -> f64 {
    let finest = layout.levels.saturating_sub(1);
    let level = level.min(finest);
    let mut axes = (level..finest).fold(0u8, |m, l| m | layout.split_mask(l));
    if axes == 0 && finest > 0 {
        axes = layout.split_mask(finest - 1);
    }
    if axes == 0 {
        axes = brickray_core::ALL_AXES;
    }
    let f = layout.voxel_factor(level);
    (0..3)
        .filter(|a| axes & (1 << a) != 0)
        .fold(0.0f64, |m, a| m.max(voxel_world[a] * f[a]))
}

/// True when a node with this metadata can contribute to the image in `mode`;
/// a multi-channel node under `channels` (its styles; empty: one channel)
/// when some visible channel does
/// ([`brickray_core::channels::node_visible`]).
pub fn is_visible(
    info: &NodeInfo,
    mode: RenderMode,
    tf: &TransferFunction,
    channels: &[brickray_core::ChannelStyle],
    layout: &OctreeLayout,
) -> bool {
    if info.kind == NodeKind::Empty {
        return false;
    }
    if layout.is_channel_volume() && !channels.is_empty() {
        return brickray_core::channels::node_visible(
            &info.channels[..layout.channels()],
            layout.channel_ranges(),
            channels,
            mode,
        );
    }
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

#[cfg(test)]
#[path = "geometry_tests.rs"]
mod tests;
