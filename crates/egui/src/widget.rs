//! The widgets: a 3D view driven by a camera controller, a slice view, and
//! the pointer and keyboard mapping they share.

use crate::{SliceCallback, VolumeCallback};
use brickray::core::camera::{CameraController, CameraInput, DragButton};
use brickray::{RenderSettings, SliceView, VolumeFrame};

/// Feeds egui's input over `response` to `controller`: a primary drag
/// orbits (or looks around when flying), a secondary or middle drag pans,
/// the wheel over the view zooms (`smooth_scroll_delta.y / 50` notches),
/// and, unless egui wants the keyboard (a text field has focus), W/A/S/D/Q/E
/// fly at half a scene radius per second and R resets the camera. Returns
/// whether a fly key is held (the camera moves every frame: keep
/// repainting).
///
/// [`VolumeView`] calls it; call it yourself for a view you lay out
/// otherwise (a quadrant of [`crate::FourViewCallback`]).
pub fn camera_input(
    ui: &egui::Ui,
    response: &egui::Response,
    controller: &mut CameraController,
) -> bool {
    let c = controller;
    let d = response.drag_delta();
    let drag = |button| CameraInput::Drag {
        button,
        dx: d.x,
        dy: d.y,
        viewport_height: response.rect.height(),
    };
    if response.dragged_by(egui::PointerButton::Primary) {
        c.apply(drag(DragButton::Primary));
    }
    if response.dragged_by(egui::PointerButton::Secondary)
        || response.dragged_by(egui::PointerButton::Middle)
    {
        c.apply(drag(DragButton::Secondary));
    }
    if response.hovered() {
        let scroll = ui.input(|i| i.smooth_scroll_delta.y);
        if scroll != 0.0 {
            c.apply(CameraInput::Wheel(scroll / 50.0));
        }
    }
    if ui.ctx().egui_wants_keyboard_input() {
        return false;
    }
    let (keys, dt) = ui.input(|i| {
        let k = |key| if i.key_down(key) { 1.0 } else { 0.0 };
        let v = glam::Vec3::new(
            k(egui::Key::D) - k(egui::Key::A),
            k(egui::Key::E) - k(egui::Key::Q),
            k(egui::Key::W) - k(egui::Key::S),
        );
        if i.key_pressed(egui::Key::R) {
            c.apply(CameraInput::Reset);
        }
        (v, i.stable_dt.min(0.1))
    });
    if keys != glam::Vec3::ZERO {
        c.apply(CameraInput::Move {
            velocity: keys * 0.5,
            dt,
        });
        return true;
    }
    false
}

/// A 3D view of the volume: allocates its rectangle, moves the camera with
/// the pointer and keyboard ([`camera_input`]) and adds the paint callback
/// that draws [`crate::ViewResources::renderer`] there.
///
/// ```no_run
/// # fn host(ui: &mut egui::Ui, controller: &mut brickray::core::camera::CameraController) {
/// // Once, at start-up: brickray_egui::install(render_state, options); then
/// // give the renderer a volume through brickray_egui::with_resources.
/// let frame = brickray::VolumeFrame::centered([256, 256, 128], [1.0, 1.0, 2.0]);
/// let response = brickray_egui::VolumeView::new(controller, frame, Default::default()).show(ui);
/// if response.changed() {
///     // The camera moved.
/// }
/// # }
/// ```
#[derive(Debug)]
#[must_use = "a view draws nothing until `show`n"]
pub struct VolumeView<'a> {
    controller: &'a mut CameraController,
    frame: VolumeFrame,
    settings: RenderSettings,
    overlays: bool,
    background: Option<egui::Color32>,
    size: Option<egui::Vec2>,
}

/// What [`VolumeView::show_output`] returns.
#[derive(Debug, Clone)]
pub struct VolumeViewOutput {
    /// The view's response (clicks, hover; marked changed when the camera
    /// moved).
    pub response: egui::Response,
    /// The paint callback added this frame (its rectangle, camera and
    /// placement, e.g. to take a screenshot of the view).
    pub callback: VolumeCallback,
    /// A fly key is held ([`camera_input`]).
    pub flying: bool,
}

impl<'a> VolumeView<'a> {
    /// The volume placed by `frame`, seen through `controller`'s camera and
    /// drawn with `settings`; the bounding box and axes drawn, no
    /// background, all the space available.
    pub fn new(
        controller: &'a mut CameraController,
        frame: VolumeFrame,
        settings: RenderSettings,
    ) -> VolumeView<'a> {
        VolumeView {
            controller,
            frame,
            settings,
            overlays: true,
            background: None,
            size: None,
        }
    }

    /// Draws the bounding box and axes, composited with the volume by depth
    /// (default: on).
    pub fn overlays(mut self, on: bool) -> Self {
        self.overlays = on;
        self
    }

    /// Fills the rectangle with `color` under the volume (default: nothing,
    /// what is behind shows through).
    pub fn background(mut self, color: egui::Color32) -> Self {
        self.background = Some(color);
        self
    }

    /// The view's size in points (default: `ui.available_size()`).
    pub fn size(mut self, size: egui::Vec2) -> Self {
        self.size = Some(size);
        self
    }

    /// Shows the view; returns its response (marked changed when the camera
    /// moved). Requests a repaint while a fly key is held.
    pub fn show(self, ui: &mut egui::Ui) -> egui::Response {
        self.show_output(ui).response
    }

    /// [`Self::show`], with the paint callback added and whether a fly key
    /// is held.
    pub fn show_output(self, ui: &mut egui::Ui) -> VolumeViewOutput {
        let size = self.size.unwrap_or_else(|| ui.available_size());
        let (rect, mut response) = ui.allocate_exact_size(size, egui::Sense::click_and_drag());
        if let Some(color) = self.background {
            ui.painter().rect_filled(rect, 0.0, color);
        }
        let before = *self.controller;
        let flying = camera_input(ui, &response, self.controller);
        if *self.controller != before {
            response.mark_changed();
        }
        if flying {
            ui.ctx().request_repaint();
        }
        let callback = VolumeCallback {
            rect,
            camera: self.controller.camera(),
            frame: self.frame,
            settings: self.settings,
            overlays: self.overlays,
            time: ui.input(|i| i.time),
        };
        ui.painter().add(egui_wgpu::Callback::new_paint_callback(
            rect,
            callback.clone(),
        ));
        VolumeViewOutput {
            response,
            callback,
            flying,
        }
    }
}

impl egui::Widget for VolumeView<'_> {
    fn ui(self, ui: &mut egui::Ui) -> egui::Response {
        self.show(ui)
    }
}

/// A slice of the volume (a plane or slab, `brickray::SliceView`) drawn by
/// one of [`crate::ViewResources::slices`] in its rectangle; the wheel over
/// it steps the slice by one voxel along its normal
/// (`SliceView::stepped` by `SliceGeometry::normal_voxel`). Clicks are
/// sensed: map a click to voxel coordinates with
/// `slice.resolve(&frame, aspect)?.index_at(..)`.
///
/// ```no_run
/// # fn host(ui: &mut egui::Ui, slice: &mut brickray::SliceView, frame: brickray::VolumeFrame) {
/// let response = brickray_egui::SliceWidget::new(slice, frame).slot(0).show(ui);
/// # }
/// ```
#[derive(Debug)]
#[must_use = "a view draws nothing until `show`n"]
pub struct SliceWidget<'a> {
    slice: &'a mut SliceView,
    frame: VolumeFrame,
    slot: usize,
    settings: RenderSettings,
    wheel: bool,
    background: Option<egui::Color32>,
    size: Option<egui::Vec2>,
}

impl<'a> SliceWidget<'a> {
    /// `slice` of the volume placed by `frame`, drawn by slice renderer 0,
    /// the wheel stepping it, all the space available.
    pub fn new(slice: &'a mut SliceView, frame: VolumeFrame) -> SliceWidget<'a> {
        SliceWidget {
            slice,
            frame,
            slot: 0,
            settings: RenderSettings::default(),
            wheel: true,
            background: None,
            size: None,
        }
    }

    /// Which of [`crate::ViewResources::slices`] draws it: 0, 1 or 2 (each
    /// slice shown in a frame needs its own).
    ///
    /// # Panics
    ///
    /// When `slot` is 3 or more.
    pub fn slot(mut self, slot: usize) -> Self {
        assert!(slot < 3, "slice slot {slot} is not 0, 1 or 2");
        self.slot = slot;
        self
    }

    /// The render settings (their sampling applies to slabs; default:
    /// `RenderSettings::default()`).
    pub fn settings(mut self, settings: RenderSettings) -> Self {
        self.settings = settings;
        self
    }

    /// Whether the wheel steps the slice (default: yes).
    pub fn wheel_steps(mut self, on: bool) -> Self {
        self.wheel = on;
        self
    }

    /// Fills the rectangle with `color` under the slice (default: nothing).
    pub fn background(mut self, color: egui::Color32) -> Self {
        self.background = Some(color);
        self
    }

    /// The view's size in points (default: `ui.available_size()`).
    pub fn size(mut self, size: egui::Vec2) -> Self {
        self.size = Some(size);
        self
    }

    /// Shows the slice; returns its response (marked changed when the wheel
    /// stepped the slice).
    pub fn show(self, ui: &mut egui::Ui) -> egui::Response {
        let size = self.size.unwrap_or_else(|| ui.available_size());
        let (rect, mut response) = ui.allocate_exact_size(size, egui::Sense::click());
        if let Some(color) = self.background {
            ui.painter().rect_filled(rect, 0.0, color);
        }
        let scroll = ui.input(|i| i.smooth_scroll_delta.y);
        if self.wheel && response.hovered() && scroll != 0.0 {
            let aspect = (rect.width() / rect.height().max(1.0)) as f64;
            let stepped = self.slice.resolve(&self.frame, aspect).and_then(|g| {
                let step = scroll.signum() as f64 * g.normal_voxel();
                self.slice.stepped(&self.frame, step)
            });
            if let Ok(s) = stepped {
                *self.slice = s;
                response.mark_changed();
            }
        }
        let callback = SliceCallback {
            rect,
            slot: self.slot,
            slice: *self.slice,
            frame: self.frame,
            settings: self.settings,
            time: ui.input(|i| i.time),
        };
        ui.painter()
            .add(egui_wgpu::Callback::new_paint_callback(rect, callback));
        response
    }
}

impl egui::Widget for SliceWidget<'_> {
    fn ui(self, ui: &mut egui::Ui) -> egui::Response {
        self.show(ui)
    }
}
