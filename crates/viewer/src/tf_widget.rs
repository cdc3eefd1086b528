//! The transfer-function editor widget (egui): the opacity curve over the
//! histogram and the colour strip below it. All logic (points, interpolation,
//! hit testing, edits) is [`TfModel`]'s; this file only maps it to the screen.
//!
//! Opacity area: drag a point to move it, click elsewhere to add one,
//! right-click a point to remove it. Colour strip: the same, and a click
//! selects a point for the colour picker.

use crate::tf::Histogram;
use brickray::core::tf::TfModel;
use eframe::egui::{self, Color32, Pos2, Rect, Sense, Stroke, Vec2};

/// Pick radius in points.
const PICK: f32 = 7.0;

/// What is being dragged.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Drag {
    Opacity(usize),
    Color(usize),
}

/// The widget's state between frames.
#[derive(Debug)]
pub(crate) struct TfEditor {
    drag: Option<Drag>,
    /// The colour point the picker edits.
    pub(crate) selected_color: Option<usize>,
    /// Show the histogram as `ln(1 + count)`.
    pub(crate) log_histogram: bool,
    /// The opacity area of the last frame, in points.
    curve: Option<Rect>,
}

impl Default for TfEditor {
    fn default() -> Self {
        // Log by default: air or background dominates most volumes.
        TfEditor {
            drag: None,
            selected_color: None,
            log_histogram: true,
            curve: None,
        }
    }
}

fn color32(rgb: [f32; 3]) -> Color32 {
    let c = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    Color32::from_rgb(c(rgb[0]), c(rgb[1]), c(rgb[2]))
}

impl TfEditor {
    /// Shows the editor; returns true when the model changed.
    pub(crate) fn show(
        &mut self,
        ui: &mut egui::Ui,
        model: &mut TfModel,
        histogram: &Histogram,
    ) -> bool {
        let width = ui.available_width().max(120.0);
        let (rect, response) =
            ui.allocate_exact_size(Vec2::new(width, 150.0), Sense::click_and_drag());
        let strip_h = 18.0;
        let curve = Rect::from_min_max(rect.min, Pos2::new(rect.max.x, rect.max.y - strip_h - 4.0));
        let strip = Rect::from_min_max(Pos2::new(rect.min.x, rect.max.y - strip_h), rect.max);
        self.curve = Some(curve);
        let (sx, sy) = (curve.width(), curve.height());
        let to_screen = |x: f32, a: f32| Pos2::new(curve.left() + x * sx, curve.bottom() - a * sy);
        let from_screen = |p: Pos2| ((p.x - curve.left()) / sx, (curve.bottom() - p.y) / sy);

        let mut changed = false;
        // Interaction first, so the drawing shows this frame's state.
        if let Some(pos) = response.interact_pointer_pos() {
            let (x, a) = from_screen(pos);
            let in_strip = pos.y >= strip.top() - 2.0;
            if response.drag_started_by(egui::PointerButton::Primary) || response.clicked() {
                // Pick where the button went down, not where the drag began.
                let origin = ui.input(|i| i.pointer.press_origin()).unwrap_or(pos);
                let (x, a) = from_screen(origin);
                let in_strip = origin.y >= strip.top() - 2.0;
                self.drag = if in_strip {
                    match model.hit_color(x, sx, PICK) {
                        Some(i) => Some(Drag::Color(i)),
                        None => {
                            changed = true;
                            Some(Drag::Color(model.add_color(x)))
                        }
                    }
                } else {
                    match model.hit_opacity(x, a, sx, sy, PICK) {
                        Some(i) => Some(Drag::Opacity(i)),
                        None => {
                            changed = true;
                            Some(Drag::Opacity(model.add_opacity(x, a)))
                        }
                    }
                };
                if let Some(Drag::Color(i)) = self.drag {
                    self.selected_color = Some(i);
                }
            }
            if response.dragged_by(egui::PointerButton::Primary) {
                match self.drag {
                    Some(Drag::Opacity(i)) => {
                        model.move_opacity(i, x, a);
                        changed = true;
                    }
                    Some(Drag::Color(i)) => {
                        model.move_color(i, x);
                        changed = true;
                    }
                    None => {}
                }
            }
            if response.secondary_clicked() {
                let removed = if in_strip {
                    model
                        .hit_color(x, sx, PICK)
                        .is_some_and(|i| model.remove_color(i))
                } else {
                    model
                        .hit_opacity(x, a, sx, sy, PICK)
                        .is_some_and(|i| model.remove_opacity(i))
                };
                if removed {
                    self.selected_color = None;
                    changed = true;
                }
            }
        }
        if !response.dragged() {
            self.drag = None;
        }

        // Histogram bars, the opacity curve and its points.
        let painter = ui.painter_at(rect);
        painter.rect_filled(curve, 2.0, Color32::from_gray(24));
        let heights = histogram.heights(self.log_histogram);
        let n = heights.len().max(1) as f32;
        for (i, h) in heights.iter().enumerate() {
            if *h > 0.0 {
                let x0 = curve.left() + i as f32 / n * sx;
                let x1 = curve.left() + (i + 1) as f32 / n * sx;
                let bar = Rect::from_min_max(
                    Pos2::new(x0, curve.bottom() - h * sy),
                    Pos2::new(x1, curve.bottom()),
                );
                painter.rect_filled(bar, 0.0, Color32::from_gray(70));
            }
        }
        let samples = 128;
        let pts: Vec<Pos2> = (0..=samples)
            .map(|i| {
                let x = i as f32 / samples as f32;
                to_screen(x, model.opacity_at(x))
            })
            .collect();
        painter.add(egui::Shape::line(
            pts,
            Stroke::new(1.5, Color32::from_rgb(240, 240, 240)),
        ));
        for (i, p) in model.opacity.iter().enumerate() {
            let active = self.drag == Some(Drag::Opacity(i));
            let fill = color32(model.color_at(p.x));
            painter.circle(
                to_screen(p.x, p.a),
                if active { 6.0 } else { 4.5 },
                fill,
                Stroke::new(1.0, Color32::WHITE),
            );
        }
        // The colour strip and its points.
        for i in 0..samples {
            let x0 = i as f32 / samples as f32;
            let x1 = (i + 1) as f32 / samples as f32;
            let r = Rect::from_min_max(
                Pos2::new(strip.left() + x0 * sx, strip.top()),
                Pos2::new(strip.left() + x1 * sx + 0.5, strip.bottom()),
            );
            painter.rect_filled(r, 0.0, color32(model.color_at((x0 + x1) * 0.5)));
        }
        for (i, p) in model.colors.iter().enumerate() {
            let x = strip.left() + p.x * sx;
            let selected = self.selected_color == Some(i);
            let stroke = Stroke::new(if selected { 2.5 } else { 1.0 }, Color32::WHITE);
            painter.add(egui::Shape::convex_polygon(
                vec![
                    Pos2::new(x, strip.top()),
                    Pos2::new(x - 5.0, strip.bottom()),
                    Pos2::new(x + 5.0, strip.bottom()),
                ],
                color32(p.rgb),
                stroke,
            ));
        }

        // The selected colour point's picker.
        if let Some(i) = self.selected_color.filter(|&i| i < model.colors.len()) {
            ui.horizontal(|ui| {
                ui.label(format!("colour point {i} at {:.3}", model.colors[i].x));
                let mut rgb = model.colors[i].rgb;
                if ui.color_edit_button_rgb(&mut rgb).changed() {
                    model.set_color(i, rgb);
                    changed = true;
                }
            });
        }
        changed
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use brickray::core::tf::TfPreset as Preset;

    /// The widget in a headless egui context, driven by pointer events.
    struct Ui {
        ctx: egui::Context,
        time: f64,
        editor: TfEditor,
        model: TfModel,
    }

    impl Ui {
        fn new() -> Ui {
            let mut ui = Ui {
                ctx: egui::Context::default(),
                time: 0.0,
                editor: TfEditor::default(),
                model: TfModel::preset(Preset::Grey, [0.0, 1.0]),
            };
            ui.frame(Vec::new());
            ui
        }

        /// One frame with `events`; returns whether the model changed.
        fn frame(&mut self, events: Vec<egui::Event>) -> bool {
            self.time += 0.1;
            let input = egui::RawInput {
                screen_rect: Some(Rect::from_min_size(Pos2::ZERO, Vec2::new(400.0, 300.0))),
                time: Some(self.time),
                events,
                ..Default::default()
            };
            let mut changed = false;
            let hist = Histogram::new(8);
            let (editor, model) = (&mut self.editor, &mut self.model);
            let mut out = self.ctx.run_ui(input, |ui| {
                changed |= editor.show(ui, model, &hist);
            });
            // Nothing renders here: the font atlas updates are dropped.
            out.textures_delta.clear();
            changed
        }

        /// Where `(x, a)` of the opacity area is on screen.
        fn at(&self, x: f32, a: f32) -> Pos2 {
            let c = self.editor.curve.expect("drawn");
            Pos2::new(c.left() + x * c.width(), c.bottom() - a * c.height())
        }

        fn button(pos: Pos2, button: egui::PointerButton, pressed: bool) -> egui::Event {
            egui::Event::PointerButton {
                pos,
                button,
                pressed,
                modifiers: Default::default(),
            }
        }

        fn click(&mut self, pos: Pos2, button: egui::PointerButton) -> bool {
            let a = self.frame(vec![
                egui::Event::PointerMoved(pos),
                Ui::button(pos, button, true),
            ]);
            let b = self.frame(vec![Ui::button(pos, button, false)]);
            a | b
        }

        fn drag(&mut self, from: Pos2, to: Pos2) -> bool {
            let mut changed = self.frame(vec![
                egui::Event::PointerMoved(from),
                Ui::button(from, egui::PointerButton::Primary, true),
            ]);
            for k in 1..=5 {
                let p = from + (to - from) * (k as f32 / 5.0);
                changed |= self.frame(vec![egui::Event::PointerMoved(p)]);
            }
            changed |= self.frame(vec![Ui::button(to, egui::PointerButton::Primary, false)]);
            changed
        }
    }

    fn near(p: &brickray::core::tf::OpacityPoint, x: f32, a: f32) -> bool {
        (p.x - x).abs() < 0.01 && (p.a - a).abs() < 0.02
    }

    #[test]
    fn clicking_empty_space_adds_an_opacity_point() {
        let mut ui = Ui::new();
        assert_eq!(ui.model.opacity.len(), 2);
        assert!(ui.click(ui.at(0.5, 0.1), egui::PointerButton::Primary));
        assert_eq!(ui.model.opacity.len(), 3, "{:?}", ui.model.opacity);
        assert!(
            near(&ui.model.opacity[1], 0.5, 0.1),
            "{:?}",
            ui.model.opacity
        );
    }

    #[test]
    fn dragging_a_point_moves_it_and_right_click_removes_it() {
        let mut ui = Ui::new();
        // The grey preset's last opacity point sits at (1, 0.5).
        assert!(ui.drag(ui.at(1.0, 0.5), ui.at(0.8, 0.9)));
        assert_eq!(
            ui.model.opacity.len(),
            2,
            "moved, not added: {:?}",
            ui.model.opacity
        );
        assert!(
            near(&ui.model.opacity[1], 0.8, 0.9),
            "{:?}",
            ui.model.opacity
        );
        assert!(ui.click(ui.at(0.8, 0.9), egui::PointerButton::Secondary));
        assert_eq!(ui.model.opacity.len(), 1, "{:?}", ui.model.opacity);
        // The last point stays.
        assert!(!ui.click(ui.at(0.0, 0.0), egui::PointerButton::Secondary));
        assert_eq!(ui.model.opacity.len(), 1);
    }

    #[test]
    fn clicking_the_strip_adds_and_selects_a_colour_point() {
        let mut ui = Ui::new();
        let c = ui.editor.curve.expect("drawn");
        // The strip lies below the opacity area.
        let pos = Pos2::new(c.left() + 0.3 * c.width(), c.bottom() + 4.0 + 9.0);
        assert!(ui.click(pos, egui::PointerButton::Primary));
        assert_eq!(ui.model.colors.len(), 3, "{:?}", ui.model.colors);
        assert!((ui.model.colors[1].x - 0.3).abs() < 0.01);
        assert_eq!(ui.editor.selected_color, Some(1));
        // The new point shows the colour that was there.
        assert!((ui.model.colors[1].rgb[0] - 0.3).abs() < 0.01);
    }
}
