//! Slice views: a plane (or a thick slab about it) through the volume, drawn
//! at screen resolution, as GPU-free geometry that the renderer and the CPU
//! reference share (docs/rendering-model.md, "Slice views").
//!
//! A [`SliceView`] is given in the volume's index axes (voxel centres at
//! integer coordinates): a centre, the image's rightward and upward
//! directions and the world height the image covers. The volume's placement
//! ([`VolumeFrame`]) maps it to the world, where the image has square pixels:
//! its up axis is the world image of `up`, its right axis the world image of
//! `right` made perpendicular to it. [`SliceView::resolve`] turns it into a
//! [`SliceGeometry`] for one viewport, whose [`camera`](SliceGeometry::camera)
//! is an orthographic camera whose frustum is the slab: the renderer plans
//! and draws a slice as such a view.

use crate::camera::{Camera, DepthConvention, Projection, VolumeFrame};
use glam::{DMat4, DVec3, Vec3};
use thiserror::Error;

/// Most samples across a slab (a thicker slab is refused).
pub const MAX_SLAB_SAMPLES: u32 = 4096;

/// Slab samples per smallest voxel side of thickness.
pub const SLAB_SAMPLES_PER_VOXEL: f64 = 2.0;

/// The three orthogonal slices, in the volume's index axes (anatomical names
/// for the usual storage order of medical volumes: x left-right, y
/// front-back, z foot-head; the volume's own anatomical frame is not used).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SliceAxis {
    /// Normal along z: the image's right is +x, its up +y.
    Axial,
    /// Normal along y: right +x, up +z.
    Coronal,
    /// Normal along x: right +y, up +z.
    Sagittal,
}

impl SliceAxis {
    /// The index axis normal to the slice (0: x, 1: y, 2: z).
    pub fn normal_axis(self) -> usize {
        match self {
            SliceAxis::Axial => 2,
            SliceAxis::Coronal => 1,
            SliceAxis::Sagittal => 0,
        }
    }

    /// The index axes of the image's right and up directions.
    pub fn image_axes(self) -> (usize, usize) {
        match self {
            SliceAxis::Axial => (0, 1),
            SliceAxis::Coronal => (0, 2),
            SliceAxis::Sagittal => (1, 2),
        }
    }
}

/// How a thick slab reduces its samples along the normal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SlabMode {
    /// The maximum (a thin MIP).
    Max,
    /// The mean.
    Mean,
}

/// A thick slab about the plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Slab {
    /// World thickness, centred on the plane (0: the plane alone).
    pub thickness: f64,
    /// The reduction along the normal.
    pub mode: SlabMode,
}

/// A slice view (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SliceView {
    /// The point at the image's centre, in voxel index coordinates (voxel
    /// `(i, j, k)`'s centre at `(i, j, k)`).
    pub centre: [f64; 3],
    /// The image's rightward direction, in index axes (any length).
    pub right: [f64; 3],
    /// The image's upward direction, in index axes (any length).
    pub up: [f64; 3],
    /// The world height the viewport's height covers.
    pub height: f64,
    /// A thick slab, or `None`: the plane alone.
    pub slab: Option<Slab>,
}

/// A slice view that cannot be drawn.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
#[non_exhaustive]
pub enum SliceError {
    /// A coordinate, direction, height or thickness is NaN or infinite.
    #[error("the slice's {field} is not finite")]
    NotFinite {
        /// The field.
        field: &'static str,
    },
    /// `right` or `up` is zero, or they are parallel (no plane), in the world.
    #[error("the slice's right and up directions do not span a plane")]
    NoPlane,
    /// The height is not positive.
    #[error("the slice's height {height} is not > 0")]
    BadHeight {
        /// The value.
        height: f64,
    },
    /// The slab thickness is negative or needs more than [`MAX_SLAB_SAMPLES`].
    #[error("slab thickness {thickness} is negative or needs more than {MAX_SLAB_SAMPLES} samples")]
    BadSlab {
        /// The value.
        thickness: f64,
    },
    /// The volume's placement is singular or not finite.
    #[error("the volume's placement cannot place a slice")]
    BadFrame,
    /// The viewport's aspect ratio is not a positive finite number.
    #[error("viewport aspect ratio {aspect} is not > 0 and finite")]
    BadAspect {
        /// The value.
        aspect: f64,
    },
}

/// `SliceView` resolved for one volume placement and viewport: world axes,
/// extents and the slab's samples.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SliceGeometry {
    /// The image's centre (world).
    pub centre: DVec3,
    /// Unit world directions: right, up, and the normal the view looks along
    /// (`up x right`).
    pub right: DVec3,
    /// See `right`.
    pub up: DVec3,
    /// See `right`.
    pub normal: DVec3,
    /// World half extents of the image.
    pub half_width: f64,
    /// See `half_width`.
    pub half_height: f64,
    /// World thickness of the slab (0: the plane).
    pub thickness: f64,
    /// Samples across the slab (1 for the plane).
    pub samples: u32,
    /// The slab's reduction.
    pub mode: SlabMode,
    /// Texture space to world and back.
    model: DMat4,
    inv_model: DMat4,
    /// The smallest voxel side (world).
    voxel_world: f64,
    /// Voxel dimensions.
    dims: DVec3,
}

fn finite3(v: [f64; 3], field: &'static str) -> Result<DVec3, SliceError> {
    let v = DVec3::from_array(v);
    if v.is_finite() {
        Ok(v)
    } else {
        Err(SliceError::NotFinite { field })
    }
}

impl SliceView {
    /// The orthogonal slice through index `index` along `axis` of the volume
    /// placed by `frame`, centred, the whole slice fitted into a viewport of
    /// aspect ratio `aspect` (width / height).
    pub fn orthogonal(
        axis: SliceAxis,
        index: f64,
        frame: &VolumeFrame,
        aspect: f64,
    ) -> Result<SliceView, SliceError> {
        let (r, u) = axis.image_axes();
        SliceView::oriented(axis.normal_axis(), index, (r, 1.0), (u, 1.0), frame, aspect)
    }

    /// The slice normal to index axis `normal` through index `index`, the
    /// screen's right along index axis `right.0` (toward `+` when `right.1`
    /// is positive, else toward `-`) and its up along `up`, centred and
    /// fitted as [`Self::orthogonal`] (which is this with positive signs):
    /// the anatomical slices of
    /// [`Orientation::slice`](crate::anatomy::Orientation::slice).
    pub fn oriented(
        normal: usize,
        index: f64,
        right: (usize, f64),
        up: (usize, f64),
        frame: &VolumeFrame,
        aspect: f64,
    ) -> Result<SliceView, SliceError> {
        if !(aspect > 0.0 && aspect.is_finite()) {
            return Err(SliceError::BadAspect { aspect });
        }
        let distinct = normal != right.0 && normal != up.0 && right.0 != up.0;
        let sign_ok = |s: f64| s.is_finite() && s != 0.0;
        if !distinct || normal.max(right.0).max(up.0) > 2 || !sign_ok(right.1) || !sign_ok(up.1) {
            return Err(SliceError::NoPlane);
        }
        let dims = frame.dims.map(|d| d as f64);
        let mut centre = dims.map(|d| d * 0.5 - 0.5);
        centre[normal] = index;
        let (mut r, mut u) = ([0.0; 3], [0.0; 3]);
        r[right.0] = right.1.signum();
        u[up.0] = up.1.signum();
        let model = frame.model.as_dmat4();
        let len = |a: usize| model.col(a).truncate().length();
        let height = len(up.0).max(len(right.0) / aspect);
        Ok(SliceView {
            centre,
            right: r,
            up: u,
            height,
            slab: None,
        })
    }

    /// A plane through `centre` (index coordinates) with `normal` (index
    /// axes): the view looks along `normal`; its up is the index axis least
    /// aligned with the normal, made perpendicular to it.
    pub fn with_normal(
        centre: [f64; 3],
        normal: [f64; 3],
        height: f64,
    ) -> Result<SliceView, SliceError> {
        let n = finite3(normal, "normal")?;
        if n.length() == 0.0 {
            return Err(SliceError::NoPlane);
        }
        let n = n.normalize();
        let a = n.abs();
        let helper = if a.z <= a.x && a.z <= a.y {
            DVec3::Z
        } else if a.y <= a.x {
            DVec3::Y
        } else {
            DVec3::X
        };
        let up = (helper - n * helper.dot(n)).normalize();
        // normal = up x right, so right = normal x up.
        let right = n.cross(up);
        Ok(SliceView {
            centre,
            right: right.to_array(),
            up: up.to_array(),
            height,
            slab: None,
        })
    }

    /// The orthogonal slice along `axis` through `point` (index
    /// coordinates), fitted as [`Self::orthogonal`]: the slices of a linked
    /// crosshair, each through the crosshair's point.
    pub fn through(
        axis: SliceAxis,
        point: [f64; 3],
        frame: &VolumeFrame,
        aspect: f64,
    ) -> Result<SliceView, SliceError> {
        SliceView::orthogonal(axis, point[axis.normal_axis()], frame, aspect)
    }

    /// The same view moved `distance` world units along its normal
    /// (scrolling through slices: one voxel of an orthogonal slice is
    /// `SliceGeometry::normal_voxel`).
    pub fn stepped(&self, frame: &VolumeFrame, distance: f64) -> Result<SliceView, SliceError> {
        if !distance.is_finite() {
            return Err(SliceError::NotFinite { field: "distance" });
        }
        let g = self.resolve(frame, 1.0)?;
        let dims = DVec3::from_array(frame.dims.map(|d| d.max(1) as f64));
        // World displacement to index displacement.
        let d_tex = g.inv_model.transform_vector3(g.normal * distance);
        let c = DVec3::from_array(self.centre) + d_tex * dims;
        Ok(SliceView {
            centre: c.to_array(),
            ..*self
        })
    }

    /// With a thick slab.
    pub fn with_slab(self, thickness: f64, mode: SlabMode) -> SliceView {
        SliceView {
            slab: Some(Slab { thickness, mode }),
            ..self
        }
    }

    /// Resolves the view for the volume placed by `frame` and a viewport of
    /// aspect ratio `aspect`; every field is checked.
    pub fn resolve(&self, frame: &VolumeFrame, aspect: f64) -> Result<SliceGeometry, SliceError> {
        let centre = finite3(self.centre, "centre")?;
        let right = finite3(self.right, "right")?;
        let up = finite3(self.up, "up")?;
        if !self.height.is_finite() {
            return Err(SliceError::NotFinite { field: "height" });
        }
        if self.height <= 0.0 {
            return Err(SliceError::BadHeight {
                height: self.height,
            });
        }
        if !(aspect > 0.0 && aspect.is_finite()) {
            return Err(SliceError::BadAspect { aspect });
        }
        let model = frame.model.as_dmat4();
        let det = model.determinant();
        if !model.is_finite() || !det.is_finite() || det == 0.0 {
            return Err(SliceError::BadFrame);
        }
        let inv_model = model.inverse();
        let dims = DVec3::from_array(frame.dims.map(|d| d.max(1) as f64));
        let to_world = |d: DVec3| model.transform_vector3(d / dims);
        let (r_w, u_w) = (to_world(right), to_world(up));
        let (rl, ul) = (r_w.length(), u_w.length());
        let normal = u_w.cross(r_w);
        if !(rl > 0.0 && ul > 0.0) || normal.length() <= 1e-9 * rl * ul {
            return Err(SliceError::NoPlane);
        }
        let up_w = u_w / ul;
        let normal = normal.normalize();
        let right_w = normal.cross(up_w);
        let voxel_world = (0..3)
            .map(|a| model.col(a).truncate().length() / dims[a])
            .fold(f64::INFINITY, f64::min);
        let (thickness, mode) = match self.slab {
            None => (0.0, SlabMode::Max),
            Some(s) => (s.thickness, s.mode),
        };
        if !thickness.is_finite() {
            return Err(SliceError::NotFinite { field: "thickness" });
        }
        let samples = (thickness * SLAB_SAMPLES_PER_VOXEL / voxel_world).ceil();
        if thickness < 0.0 || samples > MAX_SLAB_SAMPLES as f64 {
            return Err(SliceError::BadSlab { thickness });
        }
        let tex = (centre + DVec3::splat(0.5)) / dims;
        Ok(SliceGeometry {
            centre: model.transform_point3(tex),
            right: right_w,
            up: up_w,
            normal,
            half_width: self.height * 0.5 * aspect,
            half_height: self.height * 0.5,
            thickness,
            samples: (samples as u32).max(1),
            mode,
            model,
            inv_model,
            voxel_world,
            dims,
        })
    }
}

impl SliceGeometry {
    /// The world distance from the slab's front face (the camera's near
    /// plane) of sample `k`: `(k + 1/2) thickness / samples` (0: the plane).
    pub fn sample_offset(&self, k: u32) -> f64 {
        (k as f64 + 0.5) * self.thickness / self.samples as f64
    }

    /// The world point of sample `k` across the slab at pixel `(x, y)` of a
    /// `width x height` viewport (pixel centres; y down).
    pub fn world_point(&self, x: u32, y: u32, width: u32, height: u32, k: u32) -> DVec3 {
        let nx = 2.0 * (x as f64 + 0.5) / width as f64 - 1.0;
        let ny = 1.0 - 2.0 * (y as f64 + 0.5) / height as f64;
        let front = self.centre - self.normal * (self.thickness * 0.5);
        front
            + self.right * (nx * self.half_width)
            + self.up * (ny * self.half_height)
            + self.normal * self.sample_offset(k)
    }

    /// [`Self::world_point`] in the volume's texture coordinates.
    pub fn texture_point(&self, x: u32, y: u32, width: u32, height: u32, k: u32) -> DVec3 {
        self.inv_model
            .transform_point3(self.world_point(x, y, width, height, k))
    }

    /// The index coordinates (voxel centres at integers) of image position
    /// `(px, py)` on the plane (pixel `(x, y)`'s centre is `(x + 0.5, y +
    /// 0.5)`; y down): where a click in a slice puts the crosshair.
    pub fn index_at(&self, px: f64, py: f64, width: u32, height: u32) -> [f64; 3] {
        let nx = 2.0 * px / width.max(1) as f64 - 1.0;
        let ny = 1.0 - 2.0 * py / height.max(1) as f64;
        let w =
            self.centre + self.right * (nx * self.half_width) + self.up * (ny * self.half_height);
        let t = self.inv_model.transform_point3(w);
        (t * self.dims - DVec3::splat(0.5)).to_array()
    }

    /// The image position `(px, py)` of index point `index` projected onto
    /// the plane, and its world distance in front of (+) or behind the plane
    /// along the normal: where a slice draws the crosshair.
    pub fn image_of(&self, index: [f64; 3], width: u32, height: u32) -> ([f64; 2], f64) {
        let t = (DVec3::from_array(index) + DVec3::splat(0.5)) / self.dims;
        let d = self.model.transform_point3(t) - self.centre;
        let nx = d.dot(self.right) / self.half_width;
        let ny = d.dot(self.up) / self.half_height;
        (
            [
                (nx + 1.0) * 0.5 * width as f64,
                (1.0 - ny) * 0.5 * height as f64,
            ],
            -d.dot(self.normal),
        )
    }

    /// The world length of one voxel step along the normal of an
    /// orthogonal slice (in general: the normal's world length per index
    /// unit along it).
    pub fn normal_voxel(&self) -> f64 {
        let n_tex = self.inv_model.transform_vector3(self.normal);
        1.0 / (n_tex * self.dims).length()
    }

    /// The world size of one pixel.
    pub fn pixel_world(&self, viewport_height: u32) -> f64 {
        2.0 * self.half_height / viewport_height.max(1) as f64
    }

    /// The orthographic camera whose frustum is the slab: it looks along the
    /// normal, its image is the slice's, its near plane the slab's front face
    /// (the plane for a thin slice) and its far plane the back face (a
    /// hundredth of a voxel behind the plane for a thin slice). Refinement
    /// culls what lies outside this frustum and sizes levels by its pixels.
    pub fn camera(&self) -> Camera {
        let margin = self.voxel_world;
        let depth = self.thickness.max(0.01 * self.voxel_world);
        let front = self.centre - self.normal * (self.thickness * 0.5);
        let eye = front - self.normal * margin;
        let v = |p: DVec3| -> Vec3 { p.as_vec3() };
        Camera {
            eye: v(eye),
            target: v(front + self.normal * depth),
            up: v(self.up),
            projection: Projection::Orthographic {
                height: (2.0 * self.half_height) as f32,
            },
            near: margin as f32,
            far: (margin + depth) as f32,
            depth: DepthConvention::Standard,
        }
    }

    /// Texture space to world.
    pub fn model(&self) -> DMat4 {
        self.model
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame() -> VolumeFrame {
        VolumeFrame::centered([64, 48, 32], [1.0, 1.0, 2.0])
    }

    #[test]
    fn orthogonal_slices_hit_their_voxel_centres() {
        let f = frame();
        for axis in [SliceAxis::Axial, SliceAxis::Coronal, SliceAxis::Sagittal] {
            let s = SliceView::orthogonal(axis, 7.0, &f, 1.0).unwrap();
            let g = s.resolve(&f, 1.0).unwrap();
            assert_eq!(g.samples, 1);
            for (x, y) in [(0, 0), (31, 17), (63, 63)] {
                let t = g.texture_point(x, y, 64, 64, 0);
                let a = axis.normal_axis();
                let p = t[a] * f.dims[a] as f64 - 0.5;
                assert!((p - 7.0).abs() < 1e-9, "{axis:?}: {p}");
            }
            // The camera's ray through a pixel starts on the plane.
            let cam = g.camera();
            cam.validate().unwrap();
            let rays = cam.rays(1.0);
            let fwd = rays.fwd;
            assert!((fwd - g.normal).length() < 1e-6, "{axis:?}");
        }
    }

    #[test]
    fn a_linked_crosshair_round_trips_and_slices_step() {
        let f = frame();
        let point = [20.25, 11.5, 9.0];
        for axis in [SliceAxis::Axial, SliceAxis::Coronal, SliceAxis::Sagittal] {
            let s = SliceView::through(axis, point, &f, 1.25).unwrap();
            let g = s.resolve(&f, 1.25).unwrap();
            // The point lies on the plane: its image maps back to it.
            let (px, behind) = g.image_of(point, 160, 128);
            assert!(behind.abs() < 1e-9, "{axis:?}: {behind}");
            let back = g.index_at(px[0], px[1], 160, 128);
            for a in 0..3 {
                assert!((back[a] - point[a]).abs() < 1e-9, "{axis:?}: {back:?}");
            }
            // One voxel along the normal moves the plane to the next index.
            let a = axis.normal_axis();
            let next = s.stepped(&f, g.normal_voxel()).unwrap();
            let moved = (next.centre[a] - s.centre[a]).abs();
            assert!((moved - 1.0).abs() < 1e-9, "{axis:?}: {moved}");
        }
        let s = SliceView::through(SliceAxis::Axial, point, &f, 1.0).unwrap();
        assert!(s.stepped(&f, f64::NAN).is_err());
    }

    #[test]
    fn the_whole_slice_fits_and_pixels_are_square() {
        let f = frame();
        let s = SliceView::orthogonal(SliceAxis::Coronal, 0.0, &f, 2.0).unwrap();
        let g = s.resolve(&f, 2.0).unwrap();
        let w = f.model.as_dmat4();
        let x_len = w.col(0).truncate().length();
        let z_len = w.col(2).truncate().length();
        assert!(2.0 * g.half_width >= x_len - 1e-12);
        assert!(2.0 * g.half_height >= z_len - 1e-12);
        assert!((g.half_width / g.half_height - 2.0).abs() < 1e-12);
    }

    #[test]
    fn bad_planes_are_typed_errors() {
        let f = frame();
        let good = SliceView::orthogonal(SliceAxis::Axial, 3.0, &f, 1.0).unwrap();
        let cases = [
            SliceView {
                centre: [f64::NAN, 0.0, 0.0],
                ..good
            },
            SliceView {
                right: [0.0; 3],
                ..good
            },
            SliceView {
                right: good.up,
                ..good
            },
            SliceView {
                up: [f64::INFINITY, 0.0, 0.0],
                ..good
            },
            SliceView {
                height: 0.0,
                ..good
            },
            SliceView {
                height: f64::NAN,
                ..good
            },
            good.with_slab(-1.0, SlabMode::Max),
            good.with_slab(f64::NAN, SlabMode::Mean),
            good.with_slab(1e9, SlabMode::Mean),
        ];
        for c in cases {
            assert!(c.resolve(&f, 1.0).is_err(), "{c:?}");
        }
        assert!(good.resolve(&f, 0.0).is_err());
        assert!(good.resolve(&f, f64::NAN).is_err());
        assert!(SliceView::with_normal([0.0; 3], [0.0; 3], 1.0).is_err());
        assert!(SliceView::with_normal([0.0; 3], [f64::NAN, 0.0, 1.0], 1.0).is_err());
        let singular = VolumeFrame {
            model: glam::Mat4::ZERO,
            ..f
        };
        assert_eq!(good.resolve(&singular, 1.0), Err(SliceError::BadFrame));
    }

    #[test]
    fn an_oblique_plane_has_orthonormal_axes_and_slab_samples() {
        let f = VolumeFrame::centered([32; 3], [1.0; 3]);
        let s = SliceView::with_normal([15.5; 3], [1.0, 2.0, 3.0], 1.0)
            .unwrap()
            .with_slab(0.25, SlabMode::Mean);
        let g = s.resolve(&f, 1.5).unwrap();
        assert!((g.right.length() - 1.0).abs() < 1e-12);
        assert!(g.right.dot(g.up).abs() < 1e-12);
        assert!(g.normal.dot(g.up).abs() < 1e-12);
        let n = DVec3::new(1.0, 2.0, 3.0).normalize();
        assert!((g.normal - n).length() < 1e-12);
        // 0.25 world = 8 voxels of 1/32: 16 samples, symmetric about the plane.
        assert_eq!(g.samples, 16);
        let mid = (g.sample_offset(7) + g.sample_offset(8)) * 0.5;
        assert!((mid - 0.125).abs() < 1e-12);
    }
}
