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

mod controller;
mod frame;
mod ray;
mod view;

pub use controller::{AxisView, CameraController, CameraInput, DragButton, MAX_PITCH, Navigation};
pub use frame::{FrameError, VolumeFrame};
pub use ray::{Ray, RayGen};
pub use view::{FrameView, ViewGenerations};

use glam::{DMat4, Mat4, Vec3};
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

    /// The point seen at clip depth `depth` under pixel `(px, py)` of a
    /// `width x height` view of `frame` (pixel centres at +0.5): its volume
    /// texture coordinates (0..1 over the volume) and world position; `None`
    /// at the far end (nothing drawn there) or for a depth that is not
    /// finite. What a renderer's pick returns, and its CPU twin.
    pub fn unproject(
        &self,
        frame: &VolumeFrame,
        [width, height]: [u32; 2],
        [px, py]: [u32; 2],
        depth: f32,
    ) -> Option<([f64; 3], [f64; 3])> {
        if !depth.is_finite() || depth == self.depth.far_value() || width == 0 || height == 0 {
            return None;
        }
        let rays = self.rays(width as f64 / height as f64);
        let inv_model = frame.model.as_dmat4().inverse();
        let ray = rays.pixel_ray(&inv_model, px as f64, py as f64, width, height);
        let t = rays.t_at_depth(&ray, depth as f64);
        t.is_finite().then(|| {
            (
                (ray.tex_origin + ray.tex_dir * t).to_array(),
                (ray.origin + ray.dir * t).to_array(),
            )
        })
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

#[cfg(test)]
mod tests;
