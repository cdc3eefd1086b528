//! Cameras, the volume's placement in the world, and the ray model that the GPU
//! ray caster and the CPU reference share.
//!
//! * World space is right-handed; the camera looks down its view axis
//!   (`target - eye`).
//! * Clip depth follows the camera's [`DepthConvention`]: standard (0 at the near
//!   plane, 1 at the far plane, as in wgpu's default) or reversed-Z (1 near, 0 far).
//!   The far plane may be at infinity for perspective cameras (`far =
//!   f32::INFINITY`), as in Bevy.
//! * The volume's *texture space* is the unit cube `[0,1]^3` over the voxel grid's
//!   footprint (voxel `i` is centred at `(i + 0.5) / dims`). [`VolumeFrame`] maps it
//!   into the world; by default the box is centred at the origin with its longest
//!   physical side 1, so anisotropic spacing keeps its proportions.
//! * The ray through pixel `(px, py)` (pixel centres at `+0.5`, `py` down) starts on
//!   the near plane and is parametrised by world distance `t`.
//!
//! Rays are generated from the camera's basis ([`RayGen`]), never by unprojecting
//! through an inverse view-projection matrix: the matrix is ill-conditioned for
//! small near planes (a near plane at 1e-4 of the scene cost 40 dB in f32) and
//! singular for an infinite far plane. The basis is exact for any near and far.

use glam::{DMat4, DVec3, Mat4, Vec3, Vec4};
use thiserror::Error;

/// Projection kind.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Projection {
    /// Perspective with a vertical field of view in radians.
    Perspective {
        /// Vertical field of view (radians).
        fov_y: f32,
    },
    /// Orthographic with the view's height in world units.
    Orthographic {
        /// Height of the view volume.
        height: f32,
    },
}

/// How clip depth maps to distance: which end of `0..1` is near.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum DepthConvention {
    /// 0 at the near plane, 1 at the far plane; depth test `Less`/`LessEqual`,
    /// cleared to 1.
    #[default]
    Standard,
    /// 1 at the near plane, 0 at the far plane (better precision in f32 depth
    /// buffers); depth test `Greater`/`GreaterEqual`, cleared to 0.
    ReversedZ,
}

impl DepthConvention {
    /// The depth of "nothing here" (the far end): 1 standard, 0 reversed.
    pub fn far_value(self) -> f32 {
        match self {
            DepthConvention::Standard => 1.0,
            DepthConvention::ReversedZ => 0.0,
        }
    }

    /// The nearer of two clip depths.
    pub fn nearer(self, a: f32, b: f32) -> f32 {
        match self {
            DepthConvention::Standard => a.min(b),
            DepthConvention::ReversedZ => a.max(b),
        }
    }
}

/// A camera that cannot form an image.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
#[non_exhaustive]
pub enum CameraError {
    /// A field holds NaN or an infinity where a finite value is needed.
    #[error("camera {field} is not finite")]
    NotFinite {
        /// The field.
        field: &'static str,
    },
    /// The eye is at (or numerically at) the target: no view direction.
    #[error("camera eye {eye:?} equals its target")]
    EyeAtTarget {
        /// The eye.
        eye: [f32; 3],
    },
    /// The up vector is zero or parallel to the view direction.
    #[error("camera up {up:?} is zero or parallel to the view direction")]
    UpParallelToView {
        /// The up vector.
        up: [f32; 3],
    },
    /// The vertical field of view is not in `(0, pi)`.
    #[error("field of view {fov_y} rad is not in (0, pi)")]
    BadFieldOfView {
        /// The field of view.
        fov_y: f32,
    },
    /// The orthographic height is not positive.
    #[error("orthographic height {height} is not > 0")]
    BadOrthographicHeight {
        /// The height.
        height: f32,
    },
    /// The near plane is not positive (or is infinite).
    #[error("near plane {near} is not > 0 and finite")]
    BadNear {
        /// The near plane.
        near: f32,
    },
    /// The far plane is not beyond the near plane, or infinite for an
    /// orthographic camera (which has no infinite form).
    #[error("far plane {far} is not beyond the near plane {near} (infinite only for perspective)")]
    BadFar {
        /// The near plane.
        near: f32,
        /// The far plane.
        far: f32,
    },
}

/// A pinhole or orthographic camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Eye position.
    pub eye: Vec3,
    /// Point looked at.
    pub target: Vec3,
    /// Up direction.
    pub up: Vec3,
    /// Projection.
    pub projection: Projection,
    /// Near plane distance (> 0).
    pub near: f32,
    /// Far plane distance (> near; `f32::INFINITY` for an infinite perspective).
    pub far: f32,
    /// Which end of clip depth is near.
    pub depth: DepthConvention,
}

impl Camera {
    /// A perspective camera orbiting `target` at `distance`, `yaw` about +y and
    /// `pitch` above the horizon (radians), with a 40 degree field of view.
    pub fn orbit(target: Vec3, distance: f32, yaw: f32, pitch: f32) -> Camera {
        let dir = Vec3::new(
            yaw.sin() * pitch.cos(),
            pitch.sin(),
            yaw.cos() * pitch.cos(),
        );
        Camera {
            eye: target + dir * distance,
            target,
            up: Vec3::Y,
            projection: Projection::Perspective {
                fov_y: 40f32.to_radians(),
            },
            near: 0.01,
            far: distance + 10.0,
            depth: DepthConvention::Standard,
        }
    }

    /// Checks that the camera forms an image: finite fields, a view direction, an
    /// up vector not parallel to it, a field of view in `(0, pi)` or a positive
    /// orthographic height, `0 < near < far` (far may be infinite in perspective).
    pub fn validate(&self) -> Result<(), CameraError> {
        let finite3 = |v: Vec3, field| {
            if v.is_finite() {
                Ok(())
            } else {
                Err(CameraError::NotFinite { field })
            }
        };
        finite3(self.eye, "eye")?;
        finite3(self.target, "target")?;
        finite3(self.up, "up")?;
        let view = self.target.as_dvec3() - self.eye.as_dvec3();
        let len = view.length();
        if !len.is_finite() || len <= 0.0 || len < 1e-12 * self.eye.as_dvec3().length() {
            return Err(CameraError::EyeAtTarget {
                eye: self.eye.to_array(),
            });
        }
        let up = self.up.as_dvec3();
        if up.length() <= 0.0 || view.normalize().cross(up.normalize()).length() < 1e-6 {
            return Err(CameraError::UpParallelToView {
                up: self.up.to_array(),
            });
        }
        match self.projection {
            Projection::Perspective { fov_y } => {
                if !(fov_y > 0.0 && fov_y < std::f32::consts::PI) {
                    return Err(CameraError::BadFieldOfView { fov_y });
                }
            }
            Projection::Orthographic { height } => {
                if !(height > 0.0 && height.is_finite()) {
                    return Err(CameraError::BadOrthographicHeight { height });
                }
            }
        }
        if !(self.near > 0.0 && self.near.is_finite()) {
            return Err(CameraError::BadNear { near: self.near });
        }
        let ortho = matches!(self.projection, Projection::Orthographic { .. });
        if self.far.is_nan() || self.far <= self.near || (ortho && self.far.is_infinite()) {
            return Err(CameraError::BadFar {
                near: self.near,
                far: self.far,
            });
        }
        Ok(())
    }

    /// The view matrix.
    pub fn view(&self) -> Mat4 {
        Mat4::look_at_rh(self.eye, self.target, self.up)
    }

    /// The projection matrix for a viewport aspect ratio (width / height), in the
    /// camera's depth convention (with an infinite far plane when `far` is).
    pub fn proj(&self, aspect: f32) -> Mat4 {
        let d = self.depth_map();
        let (sx, sy) = match self.projection {
            Projection::Perspective { fov_y } => {
                let f = 1.0 / (fov_y as f64 * 0.5).tan();
                (f / aspect as f64, f)
            }
            Projection::Orthographic { height } => {
                let h = height as f64 * 0.5;
                (1.0 / (h * aspect as f64), 1.0 / h)
            }
        };
        // View space looks down -z; `dist = -z_view`.
        let m = if d.perspective {
            // depth = A + B / dist, w = dist.
            DMat4::from_cols_array(&[
                sx, 0.0, 0.0, 0.0, //
                0.0, sy, 0.0, 0.0, //
                0.0, 0.0, -d.a, -1.0, //
                0.0, 0.0, d.b, 0.0,
            ])
        } else {
            // depth = A + B * dist, w = 1.
            DMat4::from_cols_array(&[
                sx, 0.0, 0.0, 0.0, //
                0.0, sy, 0.0, 0.0, //
                0.0, 0.0, -d.b, 0.0, //
                0.0, 0.0, d.a, 1.0,
            ])
        };
        m.as_mat4()
    }

    /// `proj * view`.
    pub fn view_proj(&self, aspect: f32) -> Mat4 {
        self.proj(aspect) * self.view()
    }

    /// Clip depth as a function of view distance, in f64.
    pub fn depth_map(&self) -> DepthMap {
        let (n, f) = (self.near as f64, self.far as f64);
        let perspective = matches!(self.projection, Projection::Perspective { .. });
        let reversed = self.depth == DepthConvention::ReversedZ;
        let (a, b) = match (perspective, reversed, f.is_infinite()) {
            // depth = A + B / dist.
            (true, false, false) => (f / (f - n), -n * f / (f - n)),
            (true, false, true) => (1.0, -n),
            (true, true, false) => (-n / (f - n), n * f / (f - n)),
            (true, true, true) => (0.0, n),
            // depth = A + B * dist.
            (false, false, _) => (-n / (f - n), 1.0 / (f - n)),
            (false, true, _) => (f / (f - n), -1.0 / (f - n)),
        };
        DepthMap {
            a,
            b,
            perspective,
            convention: self.depth,
        }
    }

    /// The f64 ray generator of this camera for a viewport aspect ratio.
    pub fn rays(&self, aspect: f64) -> RayGen {
        let eye = self.eye.as_dvec3();
        let fwd = (self.target.as_dvec3() - eye).normalize();
        let right = fwd.cross(self.up.as_dvec3()).normalize();
        let up = right.cross(fwd);
        let (half_w, half_h, perspective) = match self.projection {
            Projection::Perspective { fov_y } => {
                let h = (fov_y as f64 * 0.5).tan();
                (h * aspect, h, true)
            }
            Projection::Orthographic { height } => {
                let h = height as f64 * 0.5;
                (h * aspect, h, false)
            }
        };
        RayGen {
            eye,
            fwd,
            right: right * half_w,
            up: up * half_h,
            near: self.near as f64,
            perspective,
            depth: self.depth_map(),
        }
    }
}

/// Clip depth as a function of the distance `dist` along the view axis:
/// `A + B / dist` (perspective) or `A + B * dist` (orthographic).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthMap {
    /// `A`.
    pub a: f64,
    /// `B`.
    pub b: f64,
    /// Perspective (`B / dist`) or orthographic (`B * dist`).
    pub perspective: bool,
    /// The convention it encodes.
    pub convention: DepthConvention,
}

impl DepthMap {
    /// Clip depth at view distance `dist`, clamped to 0..1.
    pub fn depth(&self, dist: f64) -> f64 {
        let d = if self.perspective {
            self.a + self.b / dist
        } else {
            self.a + self.b * dist
        };
        d.clamp(0.0, 1.0)
    }

    /// View distance of clip depth `depth` (infinite at the far end of an
    /// infinite projection).
    pub fn distance(&self, depth: f64) -> f64 {
        if self.perspective {
            let q = self.b / (depth - self.a);
            if q.is_nan() || q < 0.0 {
                f64::INFINITY
            } else {
                q
            }
        } else {
            (depth - self.a) / self.b
        }
    }
}

/// Generates the rays of a camera, in f64, from its basis: the eye, the unit view
/// axis and the half-extent vectors of the image plane at distance 1
/// (perspective) or of the view volume (orthographic).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayGen {
    /// Eye position (world).
    pub eye: DVec3,
    /// Unit view axis (world).
    pub fwd: DVec3,
    /// Right half-extent: NDC x = 1 is `fwd + right` (perspective) or `eye + right`
    /// (orthographic).
    pub right: DVec3,
    /// Up half-extent, likewise for NDC y = 1.
    pub up: DVec3,
    /// Near plane distance.
    pub near: f64,
    /// Perspective or orthographic.
    pub perspective: bool,
    /// Clip depth of view distance.
    pub depth: DepthMap,
}

impl RayGen {
    /// NDC of pixel `(px, py)` of a `width x height` image (pixel centres at +0.5,
    /// row 0 at the top).
    pub fn ndc(px: f64, py: f64, width: u32, height: u32) -> (f64, f64) {
        (
            2.0 * (px + 0.5) / width as f64 - 1.0,
            1.0 - 2.0 * (py + 0.5) / height as f64,
        )
    }

    /// The ray through NDC `(x, y)`: it starts on the near plane; `inv_model` maps
    /// world to texture space.
    pub fn ray(&self, inv_model: &DMat4, (x, y): (f64, f64)) -> Ray {
        let (origin, dir, dist_per_t) = if self.perspective {
            let d = self.fwd + self.right * x + self.up * y;
            let len = d.length();
            // dot(dir, fwd) = 1 / len: the near plane is `near * len` along the ray.
            (self.eye + d * self.near, d / len, 1.0 / len)
        } else {
            (
                self.eye + self.right * x + self.up * y + self.fwd * self.near,
                self.fwd,
                1.0,
            )
        };
        Ray {
            origin,
            dir,
            tex_origin: inv_model.transform_point3(origin),
            tex_dir: inv_model.transform_vector3(dir),
            dist0: self.near,
            dist_per_t,
        }
    }

    /// The ray through pixel `(px, py)` of a `width x height` image.
    pub fn pixel_ray(&self, inv_model: &DMat4, px: f64, py: f64, width: u32, height: u32) -> Ray {
        self.ray(inv_model, RayGen::ndc(px, py, width, height))
    }

    /// Clip depth of the ray's point at `t`.
    pub fn depth_at(&self, ray: &Ray, t: f64) -> f64 {
        self.depth.depth(ray.dist0 + t * ray.dist_per_t)
    }

    /// The ray's `t` at clip depth `depth` (infinite at the far end of an infinite
    /// projection).
    pub fn t_at_depth(&self, ray: &Ray, depth: f64) -> f64 {
        (self.depth.distance(depth) - ray.dist0) / ray.dist_per_t
    }
}

/// Places the volume's texture space `[0,1]^3` in the world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VolumeFrame {
    /// Texture space to world.
    pub model: Mat4,
    /// Voxel dimensions.
    pub dims: [u32; 3],
    /// World length of the smallest voxel side: the opacity reference length and
    /// the unit of the sampling step.
    pub voxel_world: f32,
}

/// A volume frame that cannot place the volume.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
#[non_exhaustive]
pub enum FrameError {
    /// The model matrix holds NaN or an infinity.
    #[error("the volume's model matrix is not finite")]
    NotFinite,
    /// The model matrix is singular (or nearly: a degenerate box) or not affine.
    #[error("the volume's model matrix is singular or not affine (determinant {determinant})")]
    Singular {
        /// Its determinant.
        determinant: f32,
    },
    /// `voxel_world` is not a positive finite length.
    #[error("voxel_world {voxel_world} is not > 0 and finite")]
    BadVoxelSize {
        /// The value.
        voxel_world: f32,
    },
}

impl VolumeFrame {
    /// The default placement: centred at the origin, longest physical side 1.
    pub fn centered(dims: [u32; 3], spacing: [f32; 3]) -> VolumeFrame {
        let extent = glam::UVec3::from_array(dims).as_vec3() * Vec3::from_array(spacing);
        let size = extent / extent.max_element();
        let model = Mat4::from_translation(-size * 0.5) * Mat4::from_scale(size);
        VolumeFrame::new(model, dims)
    }

    /// A frame from any affine texture-to-world matrix.
    pub fn new(model: Mat4, dims: [u32; 3]) -> VolumeFrame {
        let voxel_world = (0..3)
            .map(|i| model.col(i).truncate().length() / dims[i] as f32)
            .fold(f32::INFINITY, f32::min);
        VolumeFrame {
            model,
            dims,
            voxel_world,
        }
    }

    /// Checks that the frame places a non-degenerate box: a finite, affine,
    /// invertible model and a positive finite `voxel_world`.
    pub fn validate(&self) -> Result<(), FrameError> {
        if !self.model.is_finite() {
            return Err(FrameError::NotFinite);
        }
        let m = self.model.as_dmat4();
        let det = m.determinant();
        let scale = (0..3)
            .map(|i| m.col(i).truncate().length())
            .product::<f64>();
        if self.model.row(3) != Vec4::W || det.is_nan() || det.abs() <= 1e-9 * scale || scale == 0.0
        {
            return Err(FrameError::Singular {
                determinant: det as f32,
            });
        }
        if !(self.voxel_world > 0.0 && self.voxel_world.is_finite()) {
            return Err(FrameError::BadVoxelSize {
                voxel_world: self.voxel_world,
            });
        }
        Ok(())
    }

    /// World-space size of the volume's box (for placing cameras).
    pub fn world_size(&self) -> Vec3 {
        Vec3::new(
            self.model.col(0).truncate().length(),
            self.model.col(1).truncate().length(),
            self.model.col(2).truncate().length(),
        )
    }

    /// Centre of the box in world space.
    pub fn center(&self) -> Vec3 {
        self.model.transform_point3(Vec3::splat(0.5))
    }
}

/// A ray in world space, with its image of the volume's texture space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    /// World origin (on the near plane).
    pub origin: DVec3,
    /// Unit world direction.
    pub dir: DVec3,
    /// Texture-space origin.
    pub tex_origin: DVec3,
    /// Texture-space displacement per unit of world `t`.
    pub tex_dir: DVec3,
    /// View distance (along the camera's axis) of the origin: the near plane.
    pub dist0: f64,
    /// View distance gained per unit of `t` (`dir . fwd`).
    pub dist_per_t: f64,
}

impl Ray {
    /// Intersects the texture-space unit cube; returns `(t_enter, t_exit)` clipped
    /// to `t >= 0`, or `None` if missed.
    pub fn clip_unit_box(&self) -> Option<(f64, f64)> {
        let mut t0 = 0.0f64;
        let mut t1 = f64::INFINITY;
        for a in 0..3 {
            let o = self.tex_origin[a];
            let d = self.tex_dir[a];
            if d.abs() < 1e-300 {
                if !(0.0..=1.0).contains(&o) {
                    return None;
                }
            } else {
                let ta = (0.0 - o) / d;
                let tb = (1.0 - o) / d;
                t0 = t0.max(ta.min(tb));
                t1 = t1.min(ta.max(tb));
            }
        }
        (t0 < t1).then_some((t0, t1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centered_frame_keeps_proportions() {
        let f = VolumeFrame::centered([256, 256, 108], [0.957, 0.957, 1.5]);
        let s = f.world_size();
        assert!((s.x - 1.0).abs() < 1e-6);
        assert!((s.z - 108.0 * 1.5 / (256.0 * 0.957)).abs() < 1e-5);
        assert!(f.center().length() < 1e-6);
        assert!((f.voxel_world - 1.0 / 256.0).abs() < 1e-6);
        assert_eq!(f.validate(), Ok(()));
    }

    #[test]
    fn centre_ray_hits_box() {
        let cam = Camera::orbit(Vec3::ZERO, 3.0, 0.0, 0.0);
        let f = VolumeFrame::centered([8, 8, 8], [1.0; 3]);
        let im = f.model.as_dmat4().inverse();
        let r = cam.rays(1.0).pixel_ray(&im, 31.5, 31.5, 64, 64);
        let (t0, t1) = r.clip_unit_box().unwrap();
        assert!((t1 - t0 - 1.0).abs() < 1e-3, "{t0} {t1}");
    }

    fn cameras() -> Vec<Camera> {
        let mut out = Vec::new();
        for depth in [DepthConvention::Standard, DepthConvention::ReversedZ] {
            for far in [7.0, f32::INFINITY] {
                for near in [0.5, 1e-3, 1e-6] {
                    let mut c = Camera::orbit(Vec3::new(0.1, -0.2, 0.3), 3.0, 0.7, 0.4);
                    c.near = near;
                    c.far = far;
                    c.depth = depth;
                    out.push(c);
                    if far.is_finite() {
                        c.projection = Projection::Orthographic { height: 1.3 };
                        out.push(c);
                    }
                }
            }
        }
        out
    }

    /// The basis rays agree with the projection matrix: a point at `t` projects
    /// back to the pixel's NDC and to the depth of `depth_at`, in every convention.
    #[test]
    fn rays_and_depth_agree_with_the_projection_matrix() {
        for cam in cameras() {
            cam.validate().unwrap();
            let aspect = 1.5;
            let vp = cam.view_proj(aspect as f32).as_dmat4();
            let g = cam.rays(aspect);
            for (x, y) in [(0.0, 0.0), (0.9, -0.7), (-0.3, 0.99)] {
                let r = g.ray(&DMat4::IDENTITY, (x, y));
                assert!((r.dir.length() - 1.0).abs() < 1e-12);
                // The origin lies on the near plane.
                assert!(((r.origin - g.eye).dot(g.fwd) - g.near).abs() < 1e-9 * (1.0 + g.near));
                for t in [0.5, 2.0, 3.0] {
                    let p = r.origin + r.dir * t;
                    let c = vp * p.extend(1.0);
                    let ndc = c.truncate() / c.w;
                    assert!(
                        (ndc.x - x).abs() < 1e-4 && (ndc.y - y).abs() < 1e-4,
                        "{cam:?}"
                    );
                    let want = ndc.z.clamp(0.0, 1.0);
                    let got = g.depth_at(&r, t);
                    assert!((got - want).abs() < 1e-5, "{cam:?}: {got} vs {want}");
                    if got > 0.0 && got < 1.0 {
                        let back = g.t_at_depth(&r, got);
                        assert!((back - t).abs() < 1e-6 * t, "{cam:?}: t {t} back {back}");
                    }
                }
            }
        }
    }

    /// The near plane maps to the near end of the convention, the far plane to
    /// the far end; the far end of an infinite projection is infinitely far.
    #[test]
    fn conventions_put_near_and_far_at_the_right_ends() {
        for cam in cameras() {
            let m = cam.depth_map();
            let near = m.depth(cam.near as f64);
            let far = m.depth(if cam.far.is_finite() {
                cam.far as f64
            } else {
                1e300
            });
            let (n_want, f_want) = match cam.depth {
                DepthConvention::Standard => (0.0, 1.0),
                DepthConvention::ReversedZ => (1.0, 0.0),
            };
            assert!((near - n_want).abs() < 1e-9, "{cam:?}");
            assert!((far - f_want).abs() < 1e-9, "{cam:?}");
            assert_eq!(cam.depth.far_value() as f64, f_want);
            if cam.far.is_infinite() {
                assert_eq!(m.distance(f_want), f64::INFINITY);
            }
        }
    }

    #[test]
    fn degenerate_cameras_are_typed_errors() {
        let ok = Camera::orbit(Vec3::ZERO, 2.0, 0.3, 0.2);
        type Check = fn(&CameraError) -> bool;
        let cases: Vec<(Camera, Check)> = vec![
            (
                Camera {
                    eye: Vec3::NAN,
                    ..ok
                },
                |e| matches!(e, CameraError::NotFinite { field: "eye" }),
            ),
            (
                Camera {
                    up: Vec3::new(f32::INFINITY, 0.0, 0.0),
                    ..ok
                },
                |e| matches!(e, CameraError::NotFinite { field: "up" }),
            ),
            (
                Camera {
                    target: ok.eye,
                    ..ok
                },
                |e| matches!(e, CameraError::EyeAtTarget { .. }),
            ),
            (
                Camera {
                    up: ok.target - ok.eye,
                    ..ok
                },
                |e| matches!(e, CameraError::UpParallelToView { .. }),
            ),
            (
                Camera {
                    up: Vec3::ZERO,
                    ..ok
                },
                |e| matches!(e, CameraError::UpParallelToView { .. }),
            ),
            (
                Camera {
                    projection: Projection::Perspective { fov_y: 0.0 },
                    ..ok
                },
                |e| matches!(e, CameraError::BadFieldOfView { .. }),
            ),
            (
                Camera {
                    projection: Projection::Perspective { fov_y: f32::NAN },
                    ..ok
                },
                |e| matches!(e, CameraError::BadFieldOfView { .. }),
            ),
            (
                Camera {
                    projection: Projection::Perspective { fov_y: 3.2 },
                    ..ok
                },
                |e| matches!(e, CameraError::BadFieldOfView { .. }),
            ),
            (
                Camera {
                    projection: Projection::Orthographic { height: 0.0 },
                    ..ok
                },
                |e| matches!(e, CameraError::BadOrthographicHeight { .. }),
            ),
            (Camera { near: 0.0, ..ok }, |e| {
                matches!(e, CameraError::BadNear { .. })
            }),
            (
                Camera {
                    near: f32::NAN,
                    ..ok
                },
                |e| matches!(e, CameraError::BadNear { .. }),
            ),
            (Camera { far: ok.near, ..ok }, |e| {
                matches!(e, CameraError::BadFar { .. })
            }),
            (
                Camera {
                    far: f32::NAN,
                    ..ok
                },
                |e| matches!(e, CameraError::BadFar { .. }),
            ),
            (
                Camera {
                    far: f32::INFINITY,
                    projection: Projection::Orthographic { height: 1.0 },
                    ..ok
                },
                |e| matches!(e, CameraError::BadFar { .. }),
            ),
        ];
        for (cam, want) in cases {
            let e = cam.validate().expect_err("must be refused");
            assert!(want(&e), "{cam:?}: {e}");
        }
        assert_eq!(
            Camera {
                far: f32::INFINITY,
                ..ok
            }
            .validate(),
            Ok(())
        );
    }

    #[test]
    fn degenerate_frames_are_typed_errors() {
        let f = VolumeFrame::centered([8, 8, 8], [1.0; 3]);
        assert_eq!(
            VolumeFrame {
                model: Mat4::ZERO,
                ..f
            }
            .validate(),
            Err(FrameError::Singular { determinant: 0.0 })
        );
        assert!(
            VolumeFrame {
                model: Mat4::from_scale(Vec3::new(1.0, 1.0, 0.0)),
                ..f
            }
            .validate()
            .is_err()
        );
        assert_eq!(
            VolumeFrame {
                model: Mat4::NAN,
                ..f
            }
            .validate(),
            Err(FrameError::NotFinite)
        );
        assert!(matches!(
            VolumeFrame {
                voxel_world: 0.0,
                ..f
            }
            .validate(),
            Err(FrameError::BadVoxelSize { .. })
        ));
    }
}
