//! A multi-channel volume in the viewer (fluorescence microscopy: nuclei,
//! membrane, a protein of interest, each in its own colour): the channel
//! panel (per channel its label, colour, window in the channel's raw units,
//! opacity, visibility and isovalue) and the script's `channel N ...` lines.
//! The channels are drawn in core (`VolumeRenderer::set_channel_volume`) or
//! streamed (`set_volume_source` with a `ChannelSource`), each through its own
//! `ChannelStyle`; the blend is the render mode (DVR: additive
//! emission-absorption mix, MIP: each channel's maximum, isosurface: each
//! channel's surface at its own isovalue).

use super::*;
use crate::script::ChannelEdit;
use crate::source::OpenedChannels;
use brickray::ChannelStyle;
use brickray::io::{CHANNEL_PALETTE, DEFAULT_CHANNEL_OPACITY};

/// One channel's controls, in its raw units.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct ChannelControl {
    /// The file's name for it (else `channel N`, its index in the file).
    pub(super) label: String,
    /// Its colour, linear RGB 0..1.
    pub(super) color: [f32; 3],
    /// Its window in raw values: transparent at the low end, `opacity` at
    /// the high end and above.
    pub(super) window: [f32; 2],
    /// Opacity per voxel at and above the window's high end.
    pub(super) opacity: f32,
    /// The channel's raw value range (its normalization).
    pub(super) range: [f32; 2],
    /// Its histogram of normalized values.
    pub(super) histogram: Histogram,
}

impl ChannelControl {
    /// Raw value `v` normalized over the channel's range, as
    /// `ChannelInfo::style` normalizes a window (`None`: the range is empty
    /// or not finite).
    fn normalize(&self, v: f32) -> Option<f32> {
        let [lo, hi] = self.range.map(f64::from);
        (hi > lo && lo.is_finite() && hi.is_finite())
            .then(|| ((f64::from(v) - lo) / (hi - lo)) as f32)
    }

    /// Normalized value `x` in raw units.
    fn raw(&self, x: f32) -> f32 {
        let [lo, hi] = self.range.map(f64::from);
        (lo + f64::from(x) * (hi - lo)) as f32
    }

    /// The window normalized (the whole range when it cannot be).
    fn window_normalized(&self) -> [f32; 2] {
        match (
            self.normalize(self.window[0]),
            self.normalize(self.window[1]),
        ) {
            (Some(a), Some(b)) => [a, b],
            _ => [0.0, 1.0],
        }
    }

    /// The transfer function of `style` rebuilt from the colour, window and
    /// opacity (`ChannelStyle::window`), its visibility and isovalue kept.
    fn restyle(&self, style: &ChannelStyle) -> ChannelStyle {
        ChannelStyle::window(self.color, self.window_normalized(), self.opacity)
            .visible(style.visible)
            .with_isovalue(style.isovalue)
    }
}

/// The channels of the volume shown: each one's controls and the styles the
/// renderer draws (kept in step; an edit changes only what it edits).
#[derive(Debug)]
pub(super) struct ChannelPanel {
    pub(super) controls: Vec<ChannelControl>,
    pub(super) styles: Vec<ChannelStyle>,
    /// The file's controls and styles (the panel's "reset").
    defaults: (Vec<ChannelControl>, Vec<ChannelStyle>),
    /// The styles changed since the renderer last had them.
    pub(super) dirty: bool,
}

impl ChannelPanel {
    /// The panel of a multi-channel input with the file's default styles
    /// (`ReadChannels::styles`: its colours, windows and active flags).
    pub(super) fn new(c: &OpenedChannels) -> ChannelPanel {
        let controls: Vec<ChannelControl> = c
            .data
            .ranges()
            .into_iter()
            .enumerate()
            .map(|(i, range)| {
                let info = c.info.get(i).cloned().unwrap_or_default();
                ChannelControl {
                    label: info.label.unwrap_or_else(|| format!("channel {i}")),
                    color: info
                        .color
                        .unwrap_or(CHANNEL_PALETTE[i % CHANNEL_PALETTE.len()]),
                    window: info.window.unwrap_or(range),
                    opacity: DEFAULT_CHANNEL_OPACITY,
                    range,
                    histogram: c.histograms.get(i).cloned().unwrap_or_default(),
                }
            })
            .collect();
        ChannelPanel {
            defaults: (controls.clone(), c.styles.clone()),
            controls,
            styles: c.styles.clone(),
            dirty: true,
        }
    }

    /// Back to the file's styles.
    fn reset(&mut self) {
        (self.controls, self.styles) = self.defaults.clone();
        self.dirty = true;
    }

    /// Applies a script's `channel N ...` line.
    pub(super) fn edit(&mut self, c: usize, edit: ChannelEdit) -> Result<(), String> {
        let n = self.controls.len();
        let (Some(ctl), Some(style)) = (self.controls.get_mut(c), self.styles.get_mut(c)) else {
            return Err(format!(
                "channel {c}: the volume shown has {n} channels (0..={})",
                n.saturating_sub(1)
            ));
        };
        match edit {
            ChannelEdit::Visible(v) => style.visible = v,
            ChannelEdit::Iso(raw) => {
                style.isovalue = ctl.normalize(raw).ok_or_else(|| {
                    format!("channel {c}: its value range is empty (no isovalue to set)")
                })?;
            }
            ChannelEdit::Window(lo, hi) => {
                ctl.window = [lo, hi];
                *style = ctl.restyle(style);
            }
            ChannelEdit::Color(rgb) => {
                ctl.color = rgb;
                *style = ctl.restyle(style);
            }
            ChannelEdit::Opacity(a) => {
                ctl.opacity = a;
                *style = ctl.restyle(style);
            }
        }
        self.dirty = true;
        Ok(())
    }
}

impl ViewerApp {
    /// The channel panel: the blend (the render mode), and per channel its
    /// visibility, colour, window (raw units, over its histogram), opacity
    /// and, in iso mode, isovalue.
    pub(super) fn channels_ui(&mut self, ui: &mut egui::Ui) {
        ui.horizontal(|ui| {
            ui.label("blend:").on_hover_text(
                "the render mode: DVR mixes the channels additively (emission-absorption), \
                 MIP takes each channel's maximum, isosurface draws each channel's surface \
                 at its own isovalue",
            );
            for (m, text) in [
                (ModeName::Dvr, "DVR (additive)"),
                (ModeName::Mip, "MIP (maximum)"),
                (ModeName::Iso, "Iso (surfaces)"),
            ] {
                ui.selectable_value(&mut self.mode, m, text);
            }
        });
        let iso = self.mode == ModeName::Iso;
        let log = self.tf_editor.log_histogram;
        let Some(p) = self.channels.as_mut() else {
            return;
        };
        ui.horizontal(|ui| {
            if ui.button("show all").clicked() {
                for s in &mut p.styles {
                    s.visible = true;
                }
                p.dirty = true;
            }
            if ui
                .button("reset")
                .on_hover_text("the file's colours, windows and visibility")
                .clicked()
            {
                p.reset();
            }
        });
        let mut edits = Vec::new();
        for (c, (ctl, style)) in p.controls.iter().zip(&p.styles).enumerate() {
            ui.push_id(("channel", c), |ui| {
                ui.separator();
                ui.horizontal(|ui| {
                    let mut visible = style.visible;
                    if ui
                        .checkbox(&mut visible, format!("{c}: {}", ctl.label))
                        .changed()
                    {
                        edits.push((c, ChannelEdit::Visible(visible)));
                    }
                    let mut rgb = ctl.color;
                    if ui.color_edit_button_rgb(&mut rgb).changed() {
                        edits.push((c, ChannelEdit::Color(rgb)));
                    }
                });
                let [lo, hi] = ctl.range;
                let speed = ((hi - lo).abs() / 500.0).max(1e-6) as f64;
                let mut w = ctl.window;
                let mut changed = false;
                ui.horizontal(|ui| {
                    ui.label("window");
                    changed |= ui
                        .add(egui::DragValue::new(&mut w[0]).speed(speed))
                        .changed();
                    changed |= ui
                        .add(egui::DragValue::new(&mut w[1]).speed(speed))
                        .changed();
                    ui.label(egui::RichText::new(format!("raw, range {lo}..{hi}")).weak());
                });
                if changed && w.iter().all(|v| v.is_finite()) {
                    // Dragging an end past the other pushes it along.
                    if w[0] > w[1] {
                        if w[0] != ctl.window[0] {
                            w[1] = w[0];
                        } else {
                            w[0] = w[1];
                        }
                    }
                    edits.push((c, ChannelEdit::Window(w[0], w[1])));
                }
                let mut a = ctl.opacity;
                if ui
                    .add(egui::Slider::new(&mut a, 0.0..=1.0).text("opacity"))
                    .changed()
                {
                    edits.push((c, ChannelEdit::Opacity(a)));
                }
                let mut raw_iso = ctl.raw(style.isovalue);
                if iso
                    && ui
                        .add(
                            egui::Slider::new(&mut raw_iso, lo..=hi)
                                .clamping(egui::SliderClamping::Edits)
                                .text("isovalue (raw)"),
                        )
                        .changed()
                {
                    edits.push((c, ChannelEdit::Iso(raw_iso)));
                }
                let marks = (
                    ctl.window_normalized(),
                    iso.then_some(style.isovalue),
                    ctl.color,
                );
                channel_histogram(ui, &ctl.histogram, log, marks);
            });
        }
        for (c, e) in edits {
            if let Err(e) = p.edit(c, e) {
                self.messages.push(e);
            }
        }
    }

    /// A script's `channel N ...` line.
    pub(super) fn channel_action(&mut self, c: usize, edit: ChannelEdit) -> Result<(), String> {
        let p = self
            .channels
            .as_mut()
            .ok_or("channel: the volume shown has one channel (open a multi-channel one)")?;
        p.edit(c, edit)
    }

    /// Sends edited channel styles to the renderer.
    pub(super) fn apply_channels(&mut self, frame: &eframe::Frame) {
        let Some(p) = self.channels.as_mut().filter(|p| p.dirty) else {
            return;
        };
        p.dirty = false;
        let styles = p.styles.clone();
        let set = |r: &mut brickray_egui::ViewResources| {
            std::iter::once(&mut r.renderer)
                .chain(r.slices.iter_mut())
                .try_for_each(|v| v.set_channel_styles(&styles))
        };
        if let Some(Err(e)) = self.with_gpu(frame, |_, _, r| set(r)) {
            self.fail(format!("channel styles: {e}"));
        }
    }
}

/// A channel's histogram with its window (lines in the channel's colour,
/// the ramp between them) and, in iso mode, its isovalue (yellow).
fn channel_histogram(
    ui: &mut egui::Ui,
    h: &Histogram,
    log: bool,
    (window, iso, color): ([f32; 2], Option<f32>, [f32; 3]),
) {
    let (rect, p) = super::panels::histogram_bars(ui, h, log, 32.0);
    let c = egui::Rgba::from_rgb(color[0], color[1], color[2]);
    let stroke = egui::Stroke::new(1.5, Color32::from(c));
    let x = |v: f32| rect.left() + v * rect.width();
    let [a, b] = window.map(x);
    p.line_segment(
        [egui::pos2(a, rect.bottom()), egui::pos2(b, rect.top())],
        stroke,
    );
    p.line_segment(
        [
            egui::pos2(b, rect.top()),
            egui::pos2(rect.right(), rect.top()),
        ],
        stroke,
    );
    for v in [a, b] {
        p.line_segment(
            [egui::pos2(v, rect.top()), egui::pos2(v, rect.bottom())],
            stroke,
        );
    }
    if let Some(v) = iso {
        p.line_segment(
            [
                egui::pos2(x(v), rect.top()),
                egui::pos2(x(v), rect.bottom()),
            ],
            egui::Stroke::new(2.0, Color32::YELLOW),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use brickray::io::ChannelInfo;
    use brickray::{ChannelVolume, Volume, VolumeData};

    /// Two u16 channels of ranges 0..1000 and 100..60100, the first with
    /// a file's colour, window and label, the second with nothing.
    fn opened() -> OpenedChannels {
        let ch = |lo: u16, hi: u16| {
            Volume::with_data_range([2, 1, 1], [1.0; 3], VolumeData::U16(vec![lo, hi])).unwrap()
        };
        let volume = ChannelVolume::new(vec![ch(0, 1000), ch(100, 60100)]).unwrap();
        let info = vec![
            ChannelInfo {
                label: Some("nuclei".into()),
                color: Some([0.0, 1.0, 0.0]),
                window: Some([100.0, 700.0]),
                active: true,
            },
            ChannelInfo {
                active: false,
                ..Default::default()
            },
        ];
        let styles = info
            .iter()
            .zip(volume.channels())
            .enumerate()
            .map(|(i, (f, v))| f.style(i, v.desc().value_range))
            .collect();
        OpenedChannels {
            data: crate::source::ChannelData::InCore(volume),
            info,
            styles,
            histograms: vec![Histogram::new(4), Histogram::new(4)],
        }
    }

    #[test]
    fn the_panel_starts_from_the_files_styles_and_edits_only_what_it_edits() {
        let o = opened();
        let mut p = ChannelPanel::new(&o);
        assert_eq!(p.styles, o.styles);
        assert_eq!(p.controls[0].label, "nuclei");
        assert_eq!(p.controls[1].label, "channel 1");
        assert_eq!(p.controls[1].color, CHANNEL_PALETTE[1]);
        assert_eq!(p.controls[1].window, [100.0, 60100.0]);
        assert!(!p.styles[1].visible);
        // Rebuilding a channel's style from its unchanged controls gives
        // the file's style exactly.
        for c in 0..2 {
            assert_eq!(p.controls[c].restyle(&p.styles[c]), o.styles[c], "{c}");
        }
        p.dirty = false;
        p.edit(1, ChannelEdit::Visible(true)).unwrap();
        assert!(p.dirty && p.styles[1].visible);
        assert_eq!(p.styles[0], o.styles[0]);
        assert_eq!(p.styles[1].tf, o.styles[1].tf);
        // A window in raw units: normalized over the channel's range.
        p.edit(0, ChannelEdit::Window(250.0, 500.0)).unwrap();
        let want = ChannelStyle::window([0.0, 1.0, 0.0], [0.25, 0.5], DEFAULT_CHANNEL_OPACITY)
            .with_isovalue(o.styles[0].isovalue);
        assert_eq!(p.styles[0], want);
        p.edit(0, ChannelEdit::Opacity(0.9)).unwrap();
        p.edit(0, ChannelEdit::Color([1.0, 0.0, 0.0])).unwrap();
        let want = ChannelStyle::window([1.0, 0.0, 0.0], [0.25, 0.5], 0.9)
            .with_isovalue(o.styles[0].isovalue);
        assert_eq!(p.styles[0], want);
        p.edit(1, ChannelEdit::Iso(30100.0)).unwrap();
        assert!((p.styles[1].isovalue - 0.5).abs() < 1e-6);
        assert!(p.edit(2, ChannelEdit::Visible(false)).is_err());
        p.reset();
        assert_eq!(p.styles, o.styles);
        assert_eq!(p.controls[0].window, [100.0, 700.0]);
    }
}
