//! Putting a loaded volume into the renderers: in core, streamed (the
//! streamed volume made with the viewer's options and shared with the slice
//! views), or as channels; the view, the panels' state and the overlay that
//! go with it; and recreating the renderers when an option changes.

use super::*;

impl ViewerApp {
    /// The renderers' options (`u8_exact`; the render thread only applies
    /// plans, as an interactive host should).
    fn renderer_options(&self) -> brickray::RendererOptions {
        brickray::RendererOptions {
            u8_filtering: if self.u8_exact {
                brickray::U8Filtering::Exact
            } else {
                brickray::U8Filtering::Fast
            },
            background_planning: true,
            ..Default::default()
        }
    }

    /// Installs a loaded volume in the renderer.
    pub(super) fn install(&mut self, frame: &eframe::Frame, loaded: Loaded) -> Result<(), String> {
        let desc = loaded.desc.clone();
        let orientation = loaded.placement.as_ref().and_then(|p| p.orientation());
        let vframe = match &orientation {
            Some(o) => o.frame(desc.dims),
            None => VolumeFrame::centered(desc.dims, desc.spacing),
        };
        let ooc = self.ooc;
        let volume_options = brickray::VolumeOptions {
            u8_filtering: self.renderer_options().u8_filtering,
            background_planning: true,
            gradients: self.streamed_gradients,
        };
        let streamed = match &loaded.volume {
            Opened::Streamed(_) => true,
            Opened::Channels(c) => matches!(c.data, ChannelData::Streamed(_)),
            Opened::InCore(_) => false,
        };
        let label_source = match &loaded.volume {
            Opened::Streamed(src) if desc.kind.is_labels() => Some(src.clone()),
            _ => None,
        };
        let (label_ids, label_volume) = match &loaded.volume {
            Opened::InCore(v) if desc.kind.is_labels() => (
                brickray::core::labels::labels_present(v),
                Some(Arc::new(v.clone())),
            ),
            _ => (Vec::new(), None),
        };
        // Reopening what is shown (a renderer option changed) keeps the view
        // (and a multi-channel volume's edited styles).
        let reopened = self.shown.as_ref().is_some_and(|s| s.input == loaded.input);
        let channel_panel = match &loaded.volume {
            Opened::Channels(c) => Some(match self.channels.take() {
                Some(p) if reopened && p.styles.len() == c.data.len() => p,
                _ => channels::ChannelPanel::new(c),
            }),
            _ => None,
        };
        let channel_styles = channel_panel.as_ref().map(|p| p.styles.clone());
        self.with_gpu(frame, |device, queue, r| {
            match loaded.volume {
                Opened::InCore(v) => {
                    r.renderer.set_volume(device, queue, &v)?;
                    for s in &mut r.slices {
                        s.set_volume(device, queue, &v)?;
                    }
                }
                Opened::Streamed(src) => {
                    let v = brickray::StreamedVolume::new(device, queue, src, ooc, volume_options)?;
                    r.renderer.set_streamed_volume(device, &v)?;
                    for s in &mut r.slices {
                        s.set_streamed_volume(device, &v)?;
                    }
                }
                Opened::Channels(c) => {
                    let styles = channel_styles.as_deref().unwrap_or(&c.styles);
                    match &c.data {
                        ChannelData::InCore(vol) => {
                            for v in std::iter::once(&mut r.renderer).chain(r.slices.iter_mut()) {
                                v.set_channel_volume(device, queue, vol)?;
                            }
                        }
                        ChannelData::Streamed(src) => {
                            r.renderer
                                .set_volume_source(device, queue, src.clone(), ooc)?;
                            if let Some(v) = r.renderer.streamed_volume().cloned() {
                                for s in &mut r.slices {
                                    s.set_streamed_volume(device, &v)?;
                                }
                            }
                        }
                    }
                    for v in std::iter::once(&mut r.renderer).chain(r.slices.iter_mut()) {
                        v.set_channel_styles(styles)?;
                    }
                }
            }
            Ok::<(), brickray::RenderError>(())
        })
        .ok_or("no GPU")?
        .map_err(|e| format!("{}: {e}", loaded.input.name()))?;
        self.channels = channel_panel;
        // An overlay stays over its image (drawn again by the new renderer
        // after a reopen) and goes with it.
        if !reopened || desc.kind.is_labels() {
            self.remove_overlay(frame);
        }
        // A TF suited to new data (CT presets for Hounsfield ranges); scripts
        // and users change it after opening.
        if !reopened {
            let preset = if desc.value_range[0] <= -900.0 {
                Preset::CtBone
            } else if matches!(loaded.input, Input::Bulb(_)) {
                Preset::Surface
            } else {
                Preset::Grey
            };
            self.tf = TfModel::preset(preset, desc.value_range);
        }
        if desc.kind.is_labels() {
            if !reopened || self.labels.is_none() {
                let (table, note) = crate::source::label_table_beside(&loaded.input);
                self.labels = Some(table);
                if let Some(n) = note {
                    self.messages.push(n);
                }
                self.mode = ModeName::Dvr;
            }
        } else if self.label_overlay.is_none() {
            self.labels = None;
        }
        if self.label_overlay.is_none() {
            self.label_ids = label_ids;
        }
        self.label_volume = label_volume;
        self.label_source = label_source;
        self.tf_dirty = true;
        self.messages.push(loaded.note.clone());
        if !reopened || self.camera.is_none() {
            self.camera = Some(match orientation {
                Some(_) => CameraController::anatomical(&vframe),
                None => CameraController::new(&vframe),
            });
        }
        if let Some(o) = &orientation {
            self.messages.push(format!(
                "oriented {} (index axes toward {}), shown upright",
                o.code(),
                o.axes().map(|d| format!("{d:?}").to_lowercase()).join(", ")
            ));
        }
        self.stats.clear();
        if !reopened {
            self.crosshair = None;
        }
        self.window_dirty = true;
        self.shown = Some(Shown {
            input: loaded.input,
            desc,
            frame: vframe,
            orientation,
            histogram: loaded.histogram,
            note: loaded.note,
            streamed,
        });
        self.upload_overlay(frame)?;
        if let Some(path) = self.pending_overlay.take() {
            self.open_overlay(frame, &path)?;
        } else if !reopened && self.labels.is_none() {
            self.overlay_zarr_labels(frame)?;
        }
        Ok(())
    }

    /// Recreates the renderer with the current options and reopens the volume.
    pub(super) fn recreate_renderer(&mut self, frame: &eframe::Frame) {
        let Some(rs) = frame.wgpu_render_state() else {
            return;
        };
        let options = self.renderer_options();
        match brickray_egui::install(rs, options) {
            Ok(()) => {
                // The budgets travel with the reopen (`install`).
                self.tf_dirty = true;
                if let Some(input) = self.shown.as_ref().map(|s| s.input.clone()) {
                    self.start_open(input);
                }
            }
            Err(e) => self.fail(format!("renderer: {e}")),
        }
    }
}
