//! The side panel's widgets: camera, rendering (out-of-core budgets
//! included) and transfer function.

use super::*;

impl ViewerApp {
    pub(super) fn camera_ui(&mut self, ui: &mut egui::Ui) {
        let oriented = self.shown.as_ref().and_then(|s| s.orientation);
        let Some(c) = self.camera.as_mut() else {
            ui.label("no volume");
            return;
        };
        ui.horizontal(|ui| {
            ui.selectable_value(&mut c.navigation, Navigation::Orbit, "Orbit");
            ui.selectable_value(&mut c.navigation, Navigation::Fly, "Fly");
            ui.separator();
            ui.selectable_value(&mut c.orthographic, false, "Perspective");
            ui.selectable_value(&mut c.orthographic, true, "Orthographic");
        });
        ui.horizontal(|ui| {
            if ui.button("Reset").clicked() {
                c.reset();
            }
            for a in AxisView::ALL {
                if ui.button(a.label()).clicked() {
                    c.axis_view(a);
                }
            }
        });
        if let Some(o) = oriented {
            ui.horizontal(|ui| {
                ui.label("from").on_hover_text(format!(
                    "anatomical views (the volume is {}: its index axes point {})",
                    o.code(),
                    o.axes().map(|d| format!("{d:?}").to_lowercase()).join(", ")
                ));
                for d in Direction::ALL {
                    let hint = format!("seen from {:?}", d).to_lowercase();
                    if ui
                        .button(d.letter().to_string())
                        .on_hover_text(hint)
                        .clicked()
                    {
                        c.anatomical_view(d);
                    }
                }
            });
        }
        let mut fov = c.fov_y().to_degrees();
        if ui
            .add(egui::Slider::new(&mut fov, 10.0..=100.0).text("field of view °"))
            .changed()
        {
            c.set_fov_y(fov.to_radians());
        }
        ui.label(
            egui::RichText::new(
                "drag: orbit (fly: look) · right/middle drag: pan · wheel: zoom · WASD/QE: fly · R: reset",
            )
            .small()
            .weak(),
        );
    }

    pub(super) fn render_ui(&mut self, ui: &mut egui::Ui) {
        egui::ComboBox::from_label("mode")
            .selected_text(self.mode.label())
            .show_ui(ui, |ui| {
                for m in ModeName::ALL {
                    ui.selectable_value(&mut self.mode, m, m.label());
                }
            });
        if self.mode == ModeName::Iso && self.channels.is_some() {
            ui.label("each channel's isovalue: the Channels panel");
        } else if self.mode == ModeName::Iso
            && let Some(s) = &self.shown
        {
            let raw =
                s.desc.value_range[0] + self.iso * (s.desc.value_range[1] - s.desc.value_range[0]);
            ui.add(
                egui::Slider::new(&mut self.iso, 0.0..=1.0)
                    .text(format!("isovalue (raw {raw:.1})")),
            );
            histogram_strip(
                ui,
                &s.histogram,
                self.tf_editor.log_histogram,
                Some(self.iso),
            );
            let before = self.prediction;
            egui::ComboBox::from_label("prediction buffer")
                .selected_text(self.prediction.name())
                .show_ui(ui, |ui| {
                    for p in PredictionChoice::ALL {
                        ui.selectable_value(&mut self.prediction, p, p.name())
                            .on_hover_text(p.hover());
                    }
                })
                .response
                .on_hover_text("reuse last frame's hit depths (Braley et al.; docs/prediction.md)");
            self.prediction_dirty |= self.prediction != before;
        }
        let s = &mut self.settings;
        ui.add(
            egui::Slider::new(&mut s.step_factor, RenderSettings::MIN_STEP_FACTOR..=2.0)
                .logarithmic(true)
                .text("step (voxels)"),
        );
        let mut ert = s.accel.early_termination.is_some();
        ui.horizontal(|ui| {
            ui.checkbox(&mut ert, "early ray termination");
            let mut t = s.accel.early_termination.unwrap_or(0.99);
            ui.add_enabled(ert, egui::Slider::new(&mut t, 0.5..=1.0));
            s.accel.early_termination = ert.then_some(t);
        });
        ui.checkbox(&mut s.accel.empty_space_skipping, "empty-space skipping");
        if matches!(self.mode, ModeName::Dvr | ModeName::Shaded) {
            ui.checkbox(&mut s.preintegrated, "pre-integrated")
                .on_hover_text(
                    "each segment between two samples integrated through the TF: sharp TFs \
                     at coarse steps, about 2x the frame (docs/rendering-model.md)",
                );
            ui.add_enabled(
                !s.preintegrated,
                egui::Checkbox::new(&mut s.accel.adaptive_step, "adaptive step"),
            )
            .on_hover_text(
                "the step doubles as the ray's transmittance falls to 1/4 and 1/16: \
                 0.6-1.0x the frame for 0.1-1.7 dB (not with pre-integration)",
            );
        }
        if ui
            .checkbox(&mut self.u8_exact, "exact u8 interpolation")
            .on_hover_text("u8 volumes in 16-bit texels (exact) or 8-bit (half the memory); reopens the volume")
            .changed()
        {
            self.renderer_dirty = true;
        }
        ui.add(egui::Slider::new(&mut s.depth_opacity, 0.01..=1.0).text("depth at opacity"));
        ui.add(
            egui::Slider::new(
                &mut s.iso_refine_steps,
                0..=RenderSettings::MAX_ISO_REFINE_STEPS,
            )
            .text("iso refinement"),
        );
        egui::CollapsingHeader::new("shading").show(ui, |ui| {
            ui.add(egui::Slider::new(&mut s.shading.ambient, 0.0..=1.0).text("ambient"));
            ui.add(egui::Slider::new(&mut s.shading.diffuse, 0.0..=1.0).text("diffuse"));
            ui.add(egui::Slider::new(&mut s.shading.specular, 0.0..=1.0).text("specular"));
            ui.add(egui::Slider::new(&mut s.shading.shininess, 1.0..=128.0).text("shininess"));
        });
        if self.shown.as_ref().is_some_and(|s| s.streamed) {
            egui::CollapsingHeader::new("out of core")
                .default_open(true)
                .show(ui, |ui| {
                    let c = &mut self.ooc;
                    let mut changed = lod_ui(ui, &mut c.lod_metric, &mut c.tolerance_px);
                    let before = c.visibility;
                    egui::ComboBox::from_label("visibility")
                        .selected_text(c.visibility.name())
                        .show_ui(ui, |ui| {
                            for p in brickray::VisibilityPolicy::ALL {
                                ui.selectable_value(&mut c.visibility, p, p.name());
                            }
                        })
                        .response
                        .on_hover_text(
                            "bricks hidden behind opaque matter are neither refined nor \
                             loaded: occlusion queries (the paper's), the ray caster's usage \
                             counts (rayguided), or both (docs/visibility.md)",
                        );
                    changed |= c.visibility != before;
                    let mut mib = |ui: &mut egui::Ui,
                                   v: &mut u64,
                                   range: std::ops::RangeInclusive<u64>,
                                   text: &str| {
                        let mut m = *v >> 20;
                        let r = ui.add(
                            egui::Slider::new(&mut m, range)
                                .logarithmic(true)
                                .text(text),
                        );
                        if r.drag_stopped() || (r.changed() && !r.dragged()) {
                            *v = m << 20;
                            changed = true;
                        }
                    };
                    mib(
                        ui,
                        &mut c.upload_budget_bytes,
                        1..=256,
                        "upload MiB per frame",
                    );
                    mib(ui, &mut c.cpu_budget_bytes, 64..=16384, "CPU cache MiB");
                    mib(ui, &mut c.gpu_budget_bytes, 16..=4096, "GPU pool MiB");
                    // The working set's cap in bricks: the level of detail then
                    // degrades gradually, splitting the most needed first.
                    let mut capped = c.brick_budget.is_some();
                    let mut bricks = c.brick_budget.unwrap_or(4096);
                    ui.horizontal(|ui| {
                        changed |= ui
                            .checkbox(&mut capped, "brick budget")
                            .on_hover_text(
                                "most data bricks the cut holds; refinement fills it in the \
                                 LOD rule's order (docs/cache.md, \"Brick budget\")",
                            )
                            .changed();
                        let r = ui.add_enabled(
                            capped,
                            egui::Slider::new(&mut bricks, 9..=65536)
                                .logarithmic(true)
                                // A script's budget outside the range stays.
                                .clamping(egui::SliderClamping::Edits)
                                .text("bricks"),
                        );
                        if r.drag_stopped() || (r.changed() && !r.dragged()) {
                            changed = true;
                        }
                    });
                    c.brick_budget = capped.then_some(bricks);
                    self.ooc_dirty |= changed;
                });
        }
        egui::CollapsingHeader::new("clip box").show(ui, |ui| {
            let c = &mut self.settings.clip;
            for (a, name) in ["x", "y", "z"].iter().enumerate() {
                ui.horizontal(|ui| {
                    ui.label(*name);
                    ui.add(egui::Slider::new(&mut c.min[a], 0.0..=1.0).show_value(false));
                    ui.add(egui::Slider::new(&mut c.max[a], 0.0..=1.0).show_value(false));
                    // Dragging a bound past the other pushes it along.
                    if c.min[a] > c.max[a] {
                        c.max[a] = c.min[a];
                    }
                });
            }
            if ui.button("whole volume").clicked() {
                *c = brickray::ClipBox::FULL;
            }
        });
        ui.horizontal(|ui| {
            ui.checkbox(&mut self.overlays, "bounding box and axes");
            ui.label("background");
            ui.color_edit_button_srgb(&mut self.background);
        });
    }

    pub(super) fn tf_ui(&mut self, ui: &mut egui::Ui) {
        let range = self
            .shown
            .as_ref()
            .map_or([0.0, 1.0], |s| s.desc.value_range);
        // The preset the TF equals, if any (an edited TF is "custom").
        let active = Preset::ALL
            .into_iter()
            .find(|&p| TfModel::preset(p, range) == self.tf)
            .map_or("custom", Preset::name);
        ui.horizontal(|ui| {
            egui::ComboBox::from_id_salt("brickray-viewer preset")
                .selected_text(format!("preset: {active}"))
                .show_ui(ui, |ui| {
                    for p in Preset::ALL {
                        if ui.selectable_label(p.name() == active, p.name()).clicked() {
                            self.tf = TfModel::preset(p, range);
                            self.tf_dirty = true;
                        }
                    }
                });
            ui.checkbox(&mut self.tf_editor.log_histogram, "log histogram");
        });
        let empty = Histogram::new(1);
        let h = self.shown.as_ref().map_or(&empty, |s| &s.histogram);
        if self.tf_editor.show(ui, &mut self.tf, h) {
            self.tf_dirty = true;
        }
        ui.horizontal(|ui| {
            ui.add(egui::TextEdit::singleline(&mut self.tf_path).desired_width(160.0));
            if ui.button("Save").clicked() {
                let r = self.tf.save(Path::new(&self.tf_path));
                self.messages
                    .push(r.map_or_else(|e| e.to_string(), |_| format!("saved {}", self.tf_path)));
            }
            if ui.button("Load").clicked() {
                match TfModel::load(Path::new(&self.tf_path)) {
                    Ok(m) => {
                        self.tf = m;
                        self.tf_dirty = true;
                    }
                    Err(e) => self.messages.push(e.to_string()),
                }
            }
        });
    }
}

/// A strip `height` points high across the panel with the histogram's bars;
/// its rect and painter, for markers over it.
pub(super) fn histogram_bars(
    ui: &mut egui::Ui,
    h: &Histogram,
    log: bool,
    height: f32,
) -> (egui::Rect, egui::Painter) {
    let (rect, _) = ui.allocate_exact_size(
        egui::vec2(ui.available_width(), height),
        egui::Sense::hover(),
    );
    let p = ui.painter_at(rect);
    p.rect_filled(rect, 2.0, Color32::from_gray(24));
    let heights = h.heights(log);
    let n = heights.len().max(1) as f32;
    for (i, v) in heights.iter().enumerate() {
        let x0 = rect.left() + i as f32 / n * rect.width();
        let x1 = rect.left() + (i + 1) as f32 / n * rect.width();
        let bar = egui::Rect::from_min_max(
            egui::pos2(x0, rect.bottom() - v * rect.height()),
            egui::pos2(x1, rect.bottom()),
        );
        p.rect_filled(bar, 0.0, Color32::from_gray(90));
    }
    (rect, p)
}

/// The histogram as a strip with a marker (the isovalue slider's background).
fn histogram_strip(ui: &mut egui::Ui, h: &Histogram, log: bool, marker: Option<f32>) {
    let (rect, p) = histogram_bars(ui, h, log, 40.0);
    if let Some(m) = marker {
        let x = rect.left() + m * rect.width();
        p.line_segment(
            [egui::pos2(x, rect.top()), egui::pos2(x, rect.bottom())],
            egui::Stroke::new(2.0, Color32::YELLOW),
        );
    }
}

/// The level-of-detail rule (docs/cache.md) and its knob: the geometric
/// tolerance in pixels per voxel, or the error budget of the error-aware
/// rules in 8-bit levels x pixels (values a script set outside the sliders'
/// ranges stay). True when either changed.
fn lod_ui(ui: &mut egui::Ui, metric: &mut brickray::LodMetric, tolerance_px: &mut f32) -> bool {
    use brickray::LodMetric;
    let budget = metric
        .budget()
        .unwrap_or(crate::script::DEFAULT_ERROR_BUDGET);
    let rules = [
        (
            LodMetric::Geometric,
            "refine while a voxel projects to more than the tolerance",
        ),
        (
            LodMetric::VisibleError { budget },
            "refine by what the image shows of each node, as the renderer measures it, \
             x its error under the transfer function (from the store's error records; \
             sources without them refine geometrically)",
        ),
        (
            LodMetric::VisibleOctants { budget },
            "as by what the image shows, but one octant at a time: a split node's \
             children are drawn from its brick until each earns its own",
        ),
    ];
    let mut changed = false;
    egui::ComboBox::from_label("LOD rule")
        .selected_text(crate::script::lod_rule_name(*metric))
        .show_ui(ui, |ui| {
            for (rule, hover) in rules {
                let same = std::mem::discriminant(&rule) == std::mem::discriminant(metric);
                if ui
                    .selectable_label(same, crate::script::lod_rule_name(rule))
                    .on_hover_text(hover)
                    .clicked()
                    && !same
                {
                    *metric = rule;
                    changed = true;
                }
            }
        });
    match metric {
        LodMetric::Geometric => {
            changed |= ui
                .add(
                    egui::Slider::new(tolerance_px, 0.0..=8.0)
                        .clamping(egui::SliderClamping::Edits)
                        .text("tolerance (px per voxel)"),
                )
                .changed();
        }
        LodMetric::VisibleError { budget } | LodMetric::VisibleOctants { budget } => {
            changed |= ui
                .add(
                    egui::Slider::new(budget, 0.0..=16384.0)
                        .logarithmic(true)
                        .clamping(egui::SliderClamping::Edits)
                        .text("error budget (8-bit levels x px)"),
                )
                .on_hover_text("0 refines as far as the pool and the brick budget allow")
                .changed();
        }
    }
    changed
}
