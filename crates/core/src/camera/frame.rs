//! The volume's placement in the world.

use glam::{Mat4, Vec3, Vec4};
use thiserror::Error;

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
