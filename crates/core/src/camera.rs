//! Cameras, the volume's placement in the world, and the ray model that the GPU
//! ray caster and the CPU reference share.
//!
//! * World space is right-handed; clip depth runs 0 (near) to 1 (far), as in wgpu.
//! * The volume's *texture space* is the unit cube `[0,1]^3` over the voxel grid's
//!   footprint (voxel `i` is centred at `(i + 0.5) / dims`). [`VolumeFrame`] maps it
//!   into the world; by default the box is centred at the origin with its longest
//!   physical side 1, so anisotropic spacing keeps its proportions.
//! * The ray through pixel `(px, py)` (pixel centres at `+0.5`, `py` down) starts on
//!   the near plane and is parametrised by world distance `t`.

use glam::{DMat4, DVec3, Mat4, Vec3};

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
    /// Far plane distance.
    pub far: f32,
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
        }
    }

    /// The view matrix.
    pub fn view(&self) -> Mat4 {
        Mat4::look_at_rh(self.eye, self.target, self.up)
    }

    /// The projection matrix for a viewport aspect ratio (width / height).
    pub fn proj(&self, aspect: f32) -> Mat4 {
        match self.projection {
            Projection::Perspective { fov_y } => {
                Mat4::perspective_rh(fov_y, aspect, self.near, self.far)
            }
            Projection::Orthographic { height } => {
                let h = height * 0.5;
                let w = h * aspect;
                Mat4::orthographic_rh(-w, w, -h, h, self.near, self.far)
            }
        }
    }

    /// `proj * view`.
    pub fn view_proj(&self, aspect: f32) -> Mat4 {
        self.proj(aspect) * self.view()
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
}

impl Ray {
    /// The ray through pixel `(px, py)` of a `width x height` image. f64 throughout.
    pub fn through_pixel(
        inv_view_proj: &DMat4,
        inv_model: &DMat4,
        px: f64,
        py: f64,
        width: u32,
        height: u32,
    ) -> Ray {
        let nx = 2.0 * (px + 0.5) / width as f64 - 1.0;
        let ny = 1.0 - 2.0 * (py + 0.5) / height as f64;
        let near = inv_view_proj.project_point3(DVec3::new(nx, ny, 0.0));
        let far = inv_view_proj.project_point3(DVec3::new(nx, ny, 1.0));
        let dir = (far - near).normalize();
        let tex_origin = inv_model.transform_point3(near);
        let tex_dir = inv_model.transform_vector3(dir);
        Ray {
            origin: near,
            dir,
            tex_origin,
            tex_dir,
        }
    }

    /// World distance along the ray to the point whose clip depth at this pixel is
    /// `depth` (0..1).
    pub fn t_at_depth(&self, inv_view_proj: &DMat4, ndc_xy: (f64, f64), depth: f64) -> f64 {
        let p = inv_view_proj.project_point3(DVec3::new(ndc_xy.0, ndc_xy.1, depth));
        (p - self.origin).dot(self.dir)
    }

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
    }

    #[test]
    fn centre_ray_hits_box() {
        let cam = Camera::orbit(Vec3::ZERO, 3.0, 0.0, 0.0);
        let f = VolumeFrame::centered([8, 8, 8], [1.0; 3]);
        let ivp = cam.view_proj(1.0).as_dmat4().inverse();
        let im = f.model.as_dmat4().inverse();
        let r = Ray::through_pixel(&ivp, &im, 31.5, 31.5, 64, 64);
        let (t0, t1) = r.clip_unit_box().unwrap();
        assert!((t1 - t0 - 1.0).abs() < 1e-3, "{t0} {t1}");
    }
}
