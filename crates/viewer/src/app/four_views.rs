//! The four-view layout: axial, coronal and sagittal slices through a
//! linked crosshair beside the 3D view, their input (click, wheel) and the
//! overlays drawn over them.

use super::*;

impl ViewerApp {
    /// The four-view layout in `rect`: axial (top left), coronal (top
    /// right), sagittal (bottom left) and the 3D view (bottom right), drawn
    /// by one callback. A click in a slice moves the crosshair there (the
    /// other slices follow), the wheel steps a slice by a voxel. Returns the
    /// callback (for screenshots: the whole rectangle, the 3D camera) and
    /// whether the 3D camera is flying.
    pub(super) fn four_views_ui(
        &mut self,
        ui: &mut egui::Ui,
        rect: egui::Rect,
    ) -> (Option<VolumeCallback>, bool) {
        let (Some(shown), Some(_)) = (&self.shown, &self.camera) else {
            return (None, false);
        };
        let vframe = shown.frame;
        let orientation = shown.orientation;
        let dims = vframe.dims.map(|d| d as f64);
        let mut point = self
            .crosshair
            .unwrap_or(dims.map(|d| (d * 0.5 - 0.5).floor()));
        let half = rect.size() * 0.5;
        let quad = |i: usize| {
            let min = rect.min + egui::vec2((i % 2) as f32 * half.x, (i / 2) as f32 * half.y);
            egui::Rect::from_min_size(min, half).shrink(1.0)
        };
        let axes = [SliceAxis::Axial, SliceAxis::Coronal, SliceAxis::Sagittal];
        let mut slices = Vec::with_capacity(3);
        for (i, axis) in axes.into_iter().enumerate() {
            let r = quad(i);
            let aspect = (r.width() / r.height().max(1.0)) as f64;
            let Ok(view) = slice_through(orientation.as_ref(), axis, point, &vframe, aspect) else {
                return (None, false);
            };
            let resp = ui.interact(r, ui.scope_id().with(("slice", i)), egui::Sense::click());
            if let Ok(g) = view.resolve(&vframe, aspect) {
                if let Some(pos) = resp.interact_pointer_pos().filter(|_| resp.clicked()) {
                    let p = pos - r.min;
                    let q = g.index_at(p.x as f64, p.y as f64, r.width() as u32, r.height() as u32);
                    for a in 0..3 {
                        if a != slice_normal(orientation.as_ref(), axis) {
                            point[a] = q[a].clamp(0.0, dims[a] - 1.0);
                        }
                    }
                }
                if resp.hovered() {
                    let scroll = ui.input(|i| i.smooth_scroll_delta.y);
                    if scroll != 0.0 {
                        let a = slice_normal(orientation.as_ref(), axis);
                        point[a] = (point[a] + scroll.signum() as f64).clamp(0.0, dims[a] - 1.0);
                    }
                }
            }
            slices.push((r, axis));
        }
        self.crosshair = Some(point);
        let r3 = quad(3);
        let resp = ui.interact(
            r3,
            ui.scope_id().with("view 3d"),
            egui::Sense::click_and_drag(),
        );
        let Some(c) = self.camera.as_mut() else {
            return (None, false);
        };
        let flying = brickray_egui::camera_input(ui, &resp, c);
        let view_3d = VolumeCallback {
            rect: r3,
            camera: c.camera(),
            frame: vframe,
            settings: self.frame_settings(),
            // The box and the slices' planes.
            overlays: self.overlays,
            time: ui.input(|i| i.time),
        };
        let mut views = Vec::with_capacity(3);
        for (r, axis) in &slices {
            let aspect = (r.width() / r.height().max(1.0)) as f64;
            match slice_through(orientation.as_ref(), *axis, point, &vframe, aspect) {
                Ok(v) => views.push((*r, v)),
                Err(_) => return (None, flying),
            }
        }
        let cb = FourViewCallback {
            view_3d: view_3d.clone(),
            slices: [views[0], views[1], views[2]],
        };
        ui.painter()
            .add(egui_wgpu::Callback::new_paint_callback(rect, cb));
        self.shown_slices = views.clone();
        self.shown_view_3d = Some(r3);
        // The crosshair over each slice (with the other overlays).
        let stroke = egui::Stroke::new(1.0, Color32::from_rgb(230, 200, 40));
        for (r, v) in views.iter().filter(|_| self.overlays) {
            let aspect = (r.width() / r.height().max(1.0)) as f64;
            if let Ok(g) = v.resolve(&vframe, aspect) {
                let (p, _) = g.image_of(point, r.width() as u32, r.height() as u32);
                let c = r.min + egui::vec2(p[0] as f32, p[1] as f32);
                let painter = ui.painter().with_clip_rect(*r);
                painter.line_segment(
                    [egui::pos2(r.left(), c.y), egui::pos2(r.right(), c.y)],
                    stroke,
                );
                painter.line_segment(
                    [egui::pos2(c.x, r.top()), egui::pos2(c.x, r.bottom())],
                    stroke,
                );
            }
        }
        if let Some(o) = orientation.filter(|_| self.overlays) {
            for (r, v) in &views {
                orient::slice_letters(ui.painter(), *r, &o, v);
            }
            orient::marker(ui.painter(), r3, &view_3d.camera);
        }
        (Some(VolumeCallback { rect, ..view_3d }), flying)
    }
}
