//! Anatomical orientation on screen: the slices of the four-view layout in
//! the radiological convention, the letters at their edges and the
//! orientation marker of the 3D view (the library's
//! `brickray::core::anatomy` does the geometry).

use brickray::core::anatomy::{Direction, Orientation};
use brickray::{Camera, SliceAxis, SliceError, SliceView, VolumeFrame};
use eframe::egui::{self, Color32};

/// The slice along `axis` through `point` (index coordinates): anatomical
/// and radiological when the volume is oriented, else in its index axes.
pub(super) fn slice_through(
    orientation: Option<&Orientation>,
    axis: SliceAxis,
    point: [f64; 3],
    frame: &VolumeFrame,
    aspect: f64,
) -> Result<SliceView, SliceError> {
    match orientation {
        Some(o) => o.slice(axis, point, frame, aspect),
        None => SliceView::through(axis, point, frame, aspect),
    }
}

/// The index axis normal to the slice along `axis`.
pub(super) fn slice_normal(orientation: Option<&Orientation>, axis: SliceAxis) -> usize {
    orientation.map_or(axis.normal_axis(), |o| o.slice_axes(axis).normal)
}

/// The anatomical direction of a slice's index direction (`view.right` or
/// `view.up`: one signed index axis), if it is one.
fn direction(o: &Orientation, v: [f64; 3]) -> Option<Direction> {
    let a = (0..3).find(|&a| v[a] != 0.0)?;
    Some(o.direction_of(a, v[a]))
}

/// The letters of the directions at a slice's four edges (`L` at the right
/// edge of an axial slice: the patient's left).
pub(super) fn slice_letters(
    painter: &egui::Painter,
    rect: egui::Rect,
    o: &Orientation,
    view: &SliceView,
) {
    let (Some(right), Some(up)) = (direction(o, view.right), direction(o, view.up)) else {
        return;
    };
    let font = egui::FontId::proportional(13.0);
    let colour = Color32::from_rgb(230, 200, 40);
    let c = rect.center();
    for (d, pos, align) in [
        (
            right,
            egui::pos2(rect.right() - 4.0, c.y),
            egui::Align2::RIGHT_CENTER,
        ),
        (
            right.opposite(),
            egui::pos2(rect.left() + 4.0, c.y),
            egui::Align2::LEFT_CENTER,
        ),
        (
            up,
            egui::pos2(c.x, rect.top() + 3.0),
            egui::Align2::CENTER_TOP,
        ),
        (
            up.opposite(),
            egui::pos2(c.x, rect.bottom() - 3.0),
            egui::Align2::CENTER_BOTTOM,
        ),
    ] {
        painter.text(pos, align, d.letter(), font.clone(), colour);
    }
}

/// The orientation marker: the patient's R, A and S axes as the camera sees
/// them, in the bottom-left corner of the 3D view (red, green and blue, as
/// 3D Slicer draws them; an axis pointing away from the viewer is dimmed).
pub(super) fn marker(painter: &egui::Painter, rect: egui::Rect, camera: &Camera) {
    let size = (rect.width().min(rect.height()) * 0.08).clamp(18.0, 48.0);
    let centre = egui::pos2(rect.left() + size * 1.6, rect.bottom() - size * 1.6);
    let view = camera.view();
    let font = egui::FontId::proportional(12.0);
    let mut axes: Vec<(Direction, glam::Vec3, Color32)> = [
        (Direction::Right, Color32::from_rgb(230, 80, 70)),
        (Direction::Anterior, Color32::from_rgb(90, 200, 90)),
        (Direction::Superior, Color32::from_rgb(90, 140, 240)),
    ]
    .into_iter()
    .map(|(d, c)| (d, view.transform_vector3(d.world().as_vec3()), c))
    .collect();
    // Farthest first, so the nearer axes are drawn over it.
    axes.sort_by(|a, b| a.1.z.total_cmp(&b.1.z));
    for (d, v, colour) in axes {
        // View space: +x right, +y up, -z into the screen.
        let end = centre + egui::vec2(v.x, -v.y) * size;
        let colour = if v.z < -0.3 {
            colour.gamma_multiply(0.5)
        } else {
            colour
        };
        painter.line_segment([centre, end], egui::Stroke::new(2.5, colour));
        let label = centre + egui::vec2(v.x, -v.y) * (size + 9.0);
        painter.text(
            label,
            egui::Align2::CENTER_CENTER,
            d.letter(),
            font.clone(),
            colour,
        );
    }
}
