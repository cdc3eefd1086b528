//! One view of the volume in one frame ([`FrameView`]), built once per frame
//! from the host's frame description and read by everything that needs the
//! view: refinement, occlusion scheduling, prediction and the ray caster's
//! uniforms.

use super::{Camera, VolumeFrame};
use crate::settings::ClipBox;
use glam::{DMat4, Mat4};

/// One view of the volume in one frame: the camera, the volume's placement,
/// the viewport's size, and what follows from them (aspect ratio,
/// view-projection), computed once.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameView {
    /// The camera.
    pub camera: Camera,
    /// The volume's placement in the world.
    pub placement: VolumeFrame,
    /// The viewport's width and height in pixels.
    pub size: [u32; 2],
    /// `width / height`.
    pub aspect: f32,
    /// The camera's view-projection at this aspect ratio (f64: refinement
    /// and occlusion project box corners with it).
    pub view_proj: DMat4,
    /// The part of the volume the view draws (texture space; the whole volume
    /// by default): what lies wholly outside it needs no brick.
    pub clip: ClipBox,
}

impl FrameView {
    /// The view of `camera` over a `size` viewport with the volume placed by
    /// `placement`.
    pub fn new(camera: Camera, placement: VolumeFrame, size: [u32; 2]) -> FrameView {
        let aspect = (size[0] as f64 / size[1].max(1) as f64) as f32;
        FrameView {
            camera,
            placement,
            size,
            aspect,
            view_proj: camera.view_proj(aspect).as_dmat4(),
            clip: ClipBox::FULL,
        }
    }

    /// The view drawing only `clip` of the volume.
    pub fn with_clip(self, clip: ClipBox) -> FrameView {
        FrameView { clip, ..self }
    }

    /// The view-projection in f32 (what shaders receive).
    pub fn view_proj_f32(&self) -> Mat4 {
        self.view_proj.as_mat4()
    }

    /// The viewport's height in pixels.
    pub fn height(&self) -> u32 {
        self.size[1]
    }
}

/// Tracks a sequence of frames' views and numbers them: the generation changes
/// exactly when a view differs from the previous frame's (a camera, a
/// placement, a viewport size or a clip box changed, or the number of views
/// did). What
/// belongs to one view (refinement's memories, the prediction history) keys on
/// the generation instead of comparing and cloning the values it depends on.
#[derive(Debug, Clone, Default)]
pub struct ViewGenerations {
    last: Vec<FrameView>,
    generation: u64,
}

impl ViewGenerations {
    /// Notes this frame's views; returns their generation.
    pub fn note(&mut self, views: &[FrameView]) -> u64 {
        let same = self.last.len() == views.len()
            && self.last.iter().zip(views).all(|(a, b)| {
                a.camera == b.camera
                    && a.placement == b.placement
                    && a.size == b.size
                    && a.clip == b.clip
            });
        if !same {
            self.generation += 1;
            self.last.clear();
            self.last.extend_from_slice(views);
        }
        self.generation
    }

    /// The generation of the last views noted (0 before any).
    pub fn current(&self) -> u64 {
        self.generation
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn generation_changes_with_the_view_only() {
        let frame = VolumeFrame::centered([8, 8, 8], [1.0; 3]);
        let a = FrameView::new(Camera::orbit(Vec3::ZERO, 2.0, 0.1, 0.2), frame, [64, 48]);
        let b = FrameView::new(Camera::orbit(Vec3::ZERO, 2.0, 0.3, 0.2), frame, [64, 48]);
        let mut g = ViewGenerations::default();
        let g1 = g.note(&[a]);
        assert_eq!(g.note(&[a]), g1);
        let g2 = g.note(&[b]);
        assert_ne!(g2, g1);
        let g3 = g.note(&[b, a]);
        assert_ne!(g3, g2);
        assert_eq!(g.note(&[b, a]), g3);
        let resized = FrameView::new(b.camera, frame, [64, 64]);
        assert_ne!(g.note(&[resized, a]), g3);
        assert!((a.aspect - 64.0 / 48.0).abs() < 1e-6);
        assert_eq!(a.view_proj, a.camera.view_proj(a.aspect).as_dmat4());
    }
}
