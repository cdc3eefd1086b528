//! Rays from a camera's basis, in f64, and their image in texture space.

use super::DepthMap;
use glam::{DMat4, DVec3};

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
        self.clip_box([0.0; 3], [1.0; 3])
    }

    /// Intersects the texture-space box `lo..hi`; returns `(t_enter, t_exit)`
    /// clipped to `t >= 0`, or `None` if missed.
    pub fn clip_box(&self, lo: [f64; 3], hi: [f64; 3]) -> Option<(f64, f64)> {
        let mut t0 = 0.0f64;
        let mut t1 = f64::INFINITY;
        for a in 0..3 {
            let o = self.tex_origin[a];
            let d = self.tex_dir[a];
            if d.abs() < 1e-300 {
                if !(lo[a]..=hi[a]).contains(&o) {
                    return None;
                }
            } else {
                let ta = (lo[a] - o) / d;
                let tb = (hi[a] - o) / d;
                t0 = t0.max(ta.min(tb));
                t1 = t1.min(ta.max(tb));
            }
        }
        (t0 < t1).then_some((t0, t1))
    }
}
