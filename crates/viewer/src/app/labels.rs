//! A label map in the viewer: its panel (the labels present, visibility,
//! colour, selection, opacity, the table file) and the picks that select the
//! label under a click.

use super::*;

impl ViewerApp {
    /// A label map's table: every label present (in core) with its colour
    /// and visibility, show all / none, the selection's and the default
    /// opacity, and the table file.
    pub(super) fn labels_ui(&mut self, ui: &mut egui::Ui) {
        let Some(t) = self.labels.as_mut() else {
            return;
        };
        let mut changed = false;
        ui.horizontal(|ui| {
            if ui.button("show all").clicked() {
                t.show_all();
                changed = true;
            }
            if ui.button("hide all").clicked() {
                t.show_only(&[]);
                changed = true;
            }
            if !t.selected.is_empty() && ui.button("clear selection").clicked() {
                t.selected.clear();
                changed = true;
            }
        });
        changed |= ui
            .add(egui::Slider::new(&mut t.default_opacity, 0.0..=1.0).text("opacity"))
            .changed();
        if !t.selected.is_empty() {
            changed |= ui
                .add(egui::Slider::new(&mut t.unselected_opacity, 0.0..=1.0).text("others"))
                .changed();
        }
        if self.label_ids.is_empty() {
            ui.label("(labels streamed: use the script's `labels` commands)");
        }
        egui::ScrollArea::vertical()
            .max_height(240.0)
            .show(ui, |ui| {
                for &id in &self.label_ids {
                    let mut s = t.style(id);
                    ui.horizontal(|ui| {
                        let mut rgb = s.color;
                        if ui.checkbox(&mut s.visible, format!("{id}")).changed() {
                            t.set_visible(id, s.visible);
                            changed = true;
                        }
                        if ui.color_edit_button_rgb(&mut rgb).changed() {
                            t.set_color(id, rgb);
                            changed = true;
                        }
                        let mut sel = t.selected.contains(&id);
                        if ui.checkbox(&mut sel, "select").changed() {
                            if sel {
                                t.selected.insert(id);
                            } else {
                                t.selected.remove(&id);
                            }
                            changed = true;
                        }
                    });
                }
            });
        ui.horizontal(|ui| {
            ui.add(egui::TextEdit::singleline(&mut self.label_path).desired_width(160.0));
            if ui.button("Save").clicked() {
                let r = std::fs::write(&self.label_path, t.to_json());
                self.messages.push(
                    r.map_or_else(|e| e.to_string(), |_| format!("saved {}", self.label_path)),
                );
            }
            if ui.button("Load").clicked() {
                match std::fs::read(&self.label_path)
                    .map_err(|e| e.to_string())
                    .and_then(|b| {
                        brickray::LabelTable::from_file_bytes(&b).map_err(|e| e.to_string())
                    }) {
                    Ok(table) => {
                        *t = table;
                        changed = true;
                    }
                    Err(e) => self.messages.push(format!("{}: {e}", self.label_path)),
                }
            }
        });
        if changed {
            self.tf_dirty = true;
        }
    }

    /// Picks read back: on a label map a click selects the label under it
    /// (or clears the selection on the background); the message says which.
    pub(super) fn apply_picks(&mut self, frame: &eframe::Frame) {
        if !self.pick_queue.is_empty() {
            let q = std::mem::take(&mut self.pick_queue);
            if let Some(Err(e)) = self.with_gpu(frame, |_, _, r| r.renderer.request_picks(&q)) {
                self.messages.push(format!("pick: {e}"));
            }
            // (Read back a frame or two later: keep drawing until then.)
            self.pick_frames = 8;
        }
        self.pick_frames = self.pick_frames.saturating_sub(1);
        let picks = self
            .with_gpu(frame, |_, _, r| r.renderer.take_picks())
            .unwrap_or_default();
        for p in picks {
            let (Some(_), Some(point)) = (self.labels.as_ref(), p.point) else {
                if let Some(t) = self.labels.as_mut() {
                    t.selected.clear();
                    self.tf_dirty = true;
                }
                continue;
            };
            let id = match (self.overlay_label_at(point.texture), &self.label_volume) {
                // Over the image: the label under the image's sample, if any.
                (Some(Some(id)), _) => id,
                (Some(None), _) => continue,
                (None, Some(vol)) => brickray::core::labels::label_at(vol, point.texture),
                // Streamed: the one finest brick under the pick.
                (None, None) => match self
                    .label_source
                    .as_deref()
                    .map(|src| brickray::core::labels::label_at_source(src, point.texture))
                {
                    Some(Ok(id)) => id,
                    Some(Err(e)) => {
                        self.messages.push(format!("pick: {e}"));
                        continue;
                    }
                    None => continue,
                },
            };
            let Some(t) = self.labels.as_mut() else {
                continue;
            };
            let w = point.world;
            if t.background == Some(id) {
                t.selected.clear();
            } else if !t.selected.remove(&id) {
                t.selected.insert(id);
            }
            self.tf_dirty = true;
            self.messages.push(format!(
                "label {id} at ({:.1}, {:.1}, {:.1}); selected {:?}",
                w[0], w[1], w[2], t.selected
            ));
        }
    }
}
