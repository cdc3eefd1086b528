//! Camera-dependent geometry of a refinement (frustum planes, projected voxel
//! size) and the metadata-only visibility test.

use brickray_core::{
    Camera, NodeInfo, NodeKey, NodeKind, OctreeLayout, Projection, RenderMode, TransferFunction,
    VolumeFrame,
};
use glam::{DMat4, DVec3, DVec4};

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
    /// to the eye (perspective) or anywhere (orthographic). Not finite (NaN or
    /// infinite) when the camera or the frame is not: refinement then does not
    /// refine the node.
    pub fn voxel_pixels(&self, key: NodeKey) -> f64 {
        let finest = self.levels.saturating_sub(1);
        let shift = (finest - key.level.min(finest)) as i32;
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
