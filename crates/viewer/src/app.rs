//! The viewer application: state, the volume view and the frame (the side
//! panel's widgets are in `panels`, the script runner and screenshots in
//! `scripting`, multi-channel volumes in `channels`, putting a loaded volume
//! into the renderers in `install`).

mod channels;
mod four_views;
mod install;
mod labels;
mod orient;
mod overlay;
mod panels;
mod scripting;

use scripting::{PendingShot, ScriptRunner};

use crate::script::{Action, LabelAction, ModeName, PredictionChoice, WindowChoice};
use crate::source::{ChannelData, Input, Loaded, OpenOptions, Opened, Opening};
use crate::stats::Stats;
use crate::tf::Histogram;
use crate::tf_widget::TfEditor;
use brickray::core::anatomy::{Direction, Orientation};
use brickray::core::camera::{AxisView, CameraController, Navigation};
use brickray::core::tf::{TABLE_ENTRIES, TfModel, TfPreset as Preset};
use brickray::{
    LabelTable, OutOfCoreConfig, RenderMode, RenderSettings, Viewport, VolumeDesc, VolumeFrame,
};
use brickray::{SliceAxis, SliceView};
use brickray_egui::{FourViewCallback, ViewResources, VolumeCallback, VolumeView, viewport_px};
use eframe::egui::{self, Color32};
use eframe::egui_wgpu;
use orient::{slice_normal, slice_through};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// What the command line asked for.
#[derive(Debug, Clone)]
pub(crate) struct Startup {
    /// Open this first.
    pub(crate) input: Option<Input>,
    /// Run this script.
    pub(crate) script: Option<Vec<Action>>,
    /// Where the script's outcome goes (read by `main` after the window closes).
    pub(crate) outcome: Arc<Mutex<Option<Result<(), String>>>>,
    /// Open options.
    pub(crate) open: OpenOptions,
    /// Out-of-core budgets.
    pub(crate) ooc: OutOfCoreConfig,
    /// Whether streamed volumes keep their texels' gradients (`--gradients`).
    pub(crate) streamed_gradients: brickray::KeepGradients,
    /// A label map to draw over the first image opened (`--overlay`).
    pub(crate) overlay: Option<PathBuf>,
}

/// The volume on display.
#[derive(Debug)]
struct Shown {
    input: Input,
    desc: VolumeDesc,
    frame: VolumeFrame,
    /// The volume's anatomical orientation (its file places it in patient
    /// space): the frame shows the patient upright, the views and slices are
    /// anatomical.
    orientation: Option<Orientation>,
    histogram: Histogram,
    note: String,
    streamed: bool,
}

/// The viewer.
pub(crate) struct ViewerApp {
    open_opts: OpenOptions,
    ooc: OutOfCoreConfig,
    /// Whether streamed volumes keep their texels' gradients (`--gradients`).
    streamed_gradients: brickray::KeepGradients,
    ooc_dirty: bool,
    /// The isosurface prediction buffer.
    prediction: PredictionChoice,
    prediction_dirty: bool,
    opening: Option<Opening>,
    /// A script failed: the window closes on the next frame.
    close_requested: bool,
    shown: Option<Shown>,
    camera: Option<CameraController>,
    mode: ModeName,
    iso: f32,
    settings: RenderSettings,
    tf: TfModel,
    tf_dirty: bool,
    tf_editor: TfEditor,
    tf_path: String,
    overlays: bool,
    background: [u8; 3],
    stats: Stats,
    started: Instant,
    last_frame: Option<Instant>,
    /// The last frame asked for the next one at once.
    continuous: bool,
    frames_seen: u64,
    open_path: String,
    messages: Vec<String>,
    script: Option<ScriptRunner>,
    outcome: Arc<Mutex<Option<Result<(), String>>>>,
    shot: Option<PendingShot>,
    shots_taken: u32,
    shot_requested: bool,
    /// u8 volumes interpolated exactly (a renderer option: changing it
    /// recreates the renderer and reopens the volume).
    u8_exact: bool,
    renderer_dirty: bool,
    gpu_error: Option<String>,
    /// The four-view layout (three orthogonal slices and 3D).
    four_views: bool,
    /// The slices' crosshair in voxel index coordinates (`None`: the
    /// volume's centre).
    crosshair: Option<[f64; 3]>,
    /// The slices drawn last in the four-view layout, with their rectangles
    /// (recorded in screenshots' sidecars).
    shown_slices: Vec<(egui::Rect, SliceView)>,
    /// The four-view layout's 3D view rectangle (recorded in sidecars).
    shown_view_3d: Option<egui::Rect>,
    /// The slices' and MIP's window, and whether the renderers have it.
    window: WindowChoice,
    window_dirty: bool,
    /// A label map is shown: its table (drawn instead of the TF), the labels
    /// present (in core; empty when streamed) and the table file field.
    labels: Option<LabelTable>,
    label_ids: Vec<u32>,
    label_path: String,
    /// The label map's voxels (in core), to name what a click picks.
    label_volume: Option<Arc<brickray::Volume>>,
    /// A streamed label map's source, to name what a click picks (one brick
    /// read per pick).
    label_source: Option<Arc<dyn brickray::BrickSource>>,
    /// A label map drawn over the image (its table is `labels`).
    label_overlay: Option<overlay::OverlayLayer>,
    /// The label map to draw over the next image installed (`--overlay`).
    pending_overlay: Option<PathBuf>,
    /// The script's overlay lines, run at the next `apply`.
    overlay_queue: Vec<crate::script::OverlayAction>,
    /// View pixels clicked (or scripted) to pick at the next frame.
    pick_queue: Vec<[u32; 2]>,
    /// Frames left to redraw while picks are read back.
    pick_frames: u32,
    /// A multi-channel volume is shown: its channels' controls and styles.
    channels: Option<channels::ChannelPanel>,
}

impl std::fmt::Debug for ViewerApp {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ViewerApp").finish_non_exhaustive()
    }
}

impl ViewerApp {
    /// Creates the app and its GPU resources in egui-wgpu's callback resources.
    pub(crate) fn new(cc: &eframe::CreationContext<'_>, startup: Startup) -> ViewerApp {
        let mut gpu_error = None;
        match cc.wgpu_render_state.as_ref() {
            Some(rs) => {
                let options = brickray::RendererOptions {
                    // An interactive host: the render thread only applies plans.
                    background_planning: true,
                    ..Default::default()
                };
                if let Err(e) = brickray_egui::install(rs, options) {
                    gpu_error = Some(format!("brickray cannot render here: {e}"));
                }
            }
            None => gpu_error = Some("eframe runs without wgpu".into()),
        }
        let mut open_opts = startup.open;
        if let Some(rs) = cc.wgpu_render_state.as_ref() {
            // Larger volumes stream instead of failing to upload.
            open_opts.max_3d_side = rs.device.limits().max_texture_dimension_3d;
        }
        let mut app = ViewerApp {
            open_opts,
            ooc: startup.ooc,
            streamed_gradients: startup.streamed_gradients,
            prediction: PredictionChoice::Off,
            prediction_dirty: false,
            ooc_dirty: false,
            opening: None,
            close_requested: false,
            shown: None,
            camera: None,
            mode: ModeName::Dvr,
            iso: 0.5,
            settings: RenderSettings::default(),
            tf: TfModel::preset(Preset::Grey, [0.0, 1.0]),
            tf_dirty: true,
            tf_editor: TfEditor::default(),
            tf_path: "tf.json".into(),
            overlays: true,
            background: [18, 18, 24],
            stats: Stats::default(),
            started: Instant::now(),
            last_frame: None,
            continuous: false,
            frames_seen: 0,
            open_path: String::new(),
            messages: Vec::new(),
            script: startup.script.map(|actions| ScriptRunner {
                actions,
                next: 0,
                wait: 0,
                converge: None,
            }),
            outcome: startup.outcome,
            shot: None,
            shots_taken: 0,
            shot_requested: false,
            u8_exact: true,
            renderer_dirty: false,
            gpu_error,
            four_views: false,
            crosshair: None,
            shown_slices: Vec::new(),
            shown_view_3d: None,
            window: WindowChoice::Off,
            window_dirty: false,
            labels: None,
            label_ids: Vec::new(),
            label_path: "labels.json".into(),
            label_volume: None,
            label_source: None,
            label_overlay: None,
            pending_overlay: startup.overlay,
            overlay_queue: Vec::new(),
            pick_queue: Vec::new(),
            pick_frames: 0,
            channels: None,
        };
        if let Some(input) = startup.input {
            app.start_open(input);
        }
        app
    }

    fn start_open(&mut self, input: Input) {
        self.messages.push(format!("opening {}", input.name()));
        self.opening = Some(Opening::start(input, self.open_opts.clone()));
    }

    /// Runs `f` on the GPU resources (with the device and queue).
    fn with_gpu<R>(
        &self,
        frame: &eframe::Frame,
        f: impl FnOnce(&wgpu::Device, &wgpu::Queue, &mut ViewResources) -> R,
    ) -> Option<R> {
        brickray_egui::with_resources(frame.wgpu_render_state()?, f)
    }

    /// The settings of the current mode.
    fn frame_settings(&self) -> RenderSettings {
        let mut s = self.settings;
        s.shading.enabled = self.mode == ModeName::Shaded;
        s.mode = match self.mode {
            ModeName::Dvr | ModeName::Shaded => RenderMode::Dvr,
            ModeName::Iso => RenderMode::Iso {
                value: self.iso,
                color: [0.9, 0.85, 0.75],
            },
            ModeName::Mip => RenderMode::Mip,
        };
        s
    }

    /// Applies pending TF and budget changes.
    fn apply(&mut self, frame: &eframe::Frame) {
        for o in std::mem::take(&mut self.overlay_queue) {
            if let Err(e) = self.overlay_action(frame, o) {
                self.fail(e);
            }
            self.tf_dirty = true;
        }
        self.apply_picks(frame);
        self.apply_channels(frame);
        // A multi-channel volume is drawn through its channels' styles.
        if self.channels.is_some() {
            self.tf_dirty = false;
        }
        if self.tf_dirty && self.shown.is_some() {
            self.tf_dirty = false;
            // A label map is drawn through its label table; an overlay's
            // table is the overlay's.
            let table = match (&self.labels, &self.label_overlay) {
                (Some(t), None) => Ok(t.to_transfer_function()),
                _ => self.tf.to_table(TABLE_ENTRIES),
            };
            if let (Some(t), Some(_)) = (&self.labels, &self.label_overlay) {
                self.with_gpu(frame, |_, q, r| {
                    r.renderer.set_overlay_table(q, t);
                    for s in &mut r.slices {
                        s.set_overlay_table(q, t);
                    }
                });
            }
            match table {
                Ok(table) => {
                    if let Some(Err(e)) = self.with_gpu(frame, |d, q, r| {
                        r.renderer.set_transfer_function(d, q, &table)
                    }) {
                        self.fail(format!("transfer function: {e}"));
                    }
                }
                Err(e) => self.fail(e.to_string()),
            }
        }
        if self.ooc_dirty && self.shown.as_ref().is_some_and(|s| s.streamed) {
            self.ooc_dirty = false;
            let c = self.ooc;
            let res = self.with_gpu(frame, |d, q, r| -> Result<(), brickray::RenderError> {
                // One configuration: only what changed is rebuilt (the
                // pool only when the GPU budget changes).
                if let Some(v) = r.renderer.streamed_volume() {
                    v.configure(d, q, c)?;
                }
                Ok(())
            });
            if let Some(Err(e)) = res {
                self.fail(format!("budgets: {e}"));
            }
        }
        if self.window_dirty
            && let Some(shown) = &self.shown
        {
            self.window_dirty = false;
            let range = shown.desc.value_range;
            let raw = range.map(f64::from);
            let window = match self.window {
                WindowChoice::Off => Ok(None),
                WindowChoice::Auto => brickray::Window::auto(&shown.histogram.bins, raw).map(Some),
                WindowChoice::Preset(p) => Ok(Some(p.window())),
                WindowChoice::CentreWidth(c, w) => brickray::Window::new(c, w).map(Some),
            };
            match window {
                Ok(w) => {
                    let i = w.map(|w| brickray::Intensity::new(w, brickray::ColorMap::Grey));
                    self.with_gpu(frame, |_, _, r| {
                        r.renderer.set_intensity(i);
                        for s in &mut r.slices {
                            s.set_intensity(i);
                        }
                    });
                }
                Err(e) => self.fail(format!("window: {e}")),
            }
        }
        if self.prediction_dirty {
            self.prediction_dirty = false;
            let p = self.prediction.settings();
            if let Some(Err(e)) = self.with_gpu(frame, |_, _, r| r.renderer.set_prediction(p)) {
                self.fail(format!("prediction: {e}"));
            }
        }
    }

    /// Records an error: shown in the window, and failing the script if one runs.
    fn fail(&mut self, e: String) {
        eprintln!("brickray-viewer: {e}");
        if self.script.is_some() {
            self.finish_script(Err(e.clone()));
        }
        self.messages.push(e);
    }

    fn top_bar(&mut self, ui: &mut egui::Ui) {
        ui.horizontal(|ui| {
            ui.label("Open:");
            let edit = ui.add(
                egui::TextEdit::singleline(&mut self.open_path)
                    .hint_text("volume.json | .nrrd | .nii.gz | .tif | .zarr | DICOM folder | store.brs | procedural:N")
                    .desired_width(320.0),
            );
            let enter = edit.lost_focus() && ui.input(|i| i.key_pressed(egui::Key::Enter));
            if (ui.button("Open").clicked() || enter) && !self.open_path.trim().is_empty() {
                match Input::parse(self.open_path.trim()) {
                    Ok(i) => self.start_open(i),
                    Err(e) => self.messages.push(e.to_string()),
                }
            }
            if ui.button("Mandelbulb 4096³").clicked() {
                self.start_open(Input::Bulb(4096));
            }
            if ui.button("Noise 4096³").clicked() {
                self.start_open(Input::Procedural(4096));
            }
            if ui
                .button("Screenshot")
                .on_hover_text("saves the view to brickray-viewer-N.png")
                .clicked()
            {
                self.shot_requested = true;
            }
            ui.separator();
            if let Some(s) = &self.shown {
                ui.label(format!("{}: {}", s.input.name(), s.note));
            }
        });
        if let Some(o) = &self.opening {
            ui.horizontal(|ui| {
                ui.label(format!("{}: {}", o.input.name(), o.progress.stage()));
                ui.add(
                    egui::ProgressBar::new(o.progress.fraction())
                        .show_percentage()
                        .desired_width(240.0),
                );
            });
        }
        if let Some(m) = self.messages.last() {
            ui.label(egui::RichText::new(m).weak());
        }
    }
}

impl eframe::App for ViewerApp {
    fn ui(&mut self, ui: &mut egui::Ui, frame: &mut eframe::Frame) {
        self.frame_ui(ui, frame);
        if self.close_requested {
            ui.ctx().send_viewport_cmd(egui::ViewportCommand::Close);
        }
    }
}

impl ViewerApp {
    /// One frame of the UI.
    fn frame_ui(&mut self, ui: &mut egui::Ui, frame: &mut eframe::Frame) {
        let ctx = ui.ctx().clone();
        // A finished open.
        if let Some(result) = self.opening.as_ref().and_then(Opening::poll) {
            self.opening = None;
            match result
                .map_err(|e| e.to_string())
                .and_then(|l| self.install(frame, l))
            {
                Ok(()) => {}
                Err(e) => self.fail(e),
            }
        }
        if let Some(e) = &self.gpu_error {
            let e = e.clone();
            if self.script.is_some() {
                self.fail(e.clone());
            }
            egui::CentralPanel::default_margins().show(ui, |ui| ui.label(e));
            return;
        }
        self.finish_shot();
        if std::mem::take(&mut self.renderer_dirty) {
            self.recreate_renderer(frame);
        }
        self.apply(frame);

        // Statistics of the frame drawn last time, and GPU errors (the
        // slices only count in the four-view layout, which draws them).
        let four = self.four_views;
        let (stats, frames, wants_redraw, err) = self
            .with_gpu(frame, |_, _, r| {
                (
                    r.renderer.stats(),
                    r.frames(),
                    r.renderer.wants_redraw()
                        || (four && r.slices.iter().any(|s| s.wants_redraw())),
                    r.take_error(),
                )
            })
            .unwrap_or_default();
        if let Some(e) = err {
            self.fail(e);
        }
        if frames > self.frames_seen {
            self.frames_seen = frames;
            let now = Instant::now();
            // The interval is a frame time only while redrawing continuously.
            let dt = match self.last_frame {
                Some(t) if self.continuous => (now - t).as_secs_f64() * 1e3,
                _ => f64::NAN,
            };
            self.last_frame = Some(now);
            self.stats
                .push(self.started.elapsed().as_secs_f64(), dt, &stats);
        }
        let converged = stats.out_of_core.is_none_or(|o| o.converged) && !wants_redraw;

        egui::Panel::top("brickray-viewer top").show(ui, |ui| self.top_bar(ui));
        egui::Panel::left("brickray-viewer side")
            .default_size(340.0)
            .resizable(true)
            .show(ui, |ui| {
                egui::ScrollArea::vertical().show(ui, |ui| {
                    egui::CollapsingHeader::new("Camera")
                        .default_open(true)
                        .show(ui, |ui| self.camera_ui(ui));
                    egui::CollapsingHeader::new("Rendering")
                        .default_open(true)
                        .show(ui, |ui| self.render_ui(ui));
                    let label_map = self.labels.is_some() && self.label_overlay.is_none();
                    if self.channels.is_some() {
                        egui::CollapsingHeader::new("Channels")
                            .default_open(true)
                            .show(ui, |ui| self.channels_ui(ui));
                    } else {
                        egui::CollapsingHeader::new(if label_map {
                            "Labels"
                        } else {
                            "Transfer function"
                        })
                        .default_open(true)
                        .show(ui, |ui| {
                            if label_map {
                                self.labels_ui(ui)
                            } else {
                                self.tf_ui(ui)
                            }
                        });
                    }
                    if self.label_overlay.is_some() {
                        egui::CollapsingHeader::new("Labels over the image")
                            .default_open(true)
                            .show(ui, |ui| {
                                self.overlay_ui(ui, frame);
                                self.labels_ui(ui)
                            });
                    }
                    egui::CollapsingHeader::new("Statistics")
                        .default_open(true)
                        .show(ui, |ui| self.stats.show(ui));
                });
            });
        let mut callback = None;
        let mut flying = false;
        egui::CentralPanel::default_margins()
            .frame(egui::Frame::NONE)
            .show(ui, |ui| {
                let [r, g, b] = self.background;
                let background = Color32::from_rgb(r, g, b);
                if self.four_views && self.shown.is_some() && self.camera.is_some() {
                    let (rect, _) =
                        ui.allocate_exact_size(ui.available_size(), egui::Sense::click_and_drag());
                    ui.painter().rect_filled(rect, 0.0, background);
                    let (cb, fly) = self.four_views_ui(ui, rect);
                    flying = fly;
                    callback = cb;
                    return;
                }
                self.shown_slices.clear();
                self.shown_view_3d = None;
                let settings = self.frame_settings();
                let (Some(s), Some(c)) = (&self.shown, self.camera.as_mut()) else {
                    let (rect, _) =
                        ui.allocate_exact_size(ui.available_size(), egui::Sense::click_and_drag());
                    ui.painter().rect_filled(rect, 0.0, background);
                    if self.opening.is_some() {
                        ui.centered_and_justified(|ui| ui.spinner());
                    }
                    return;
                };
                let view = VolumeView::new(c, s.frame, settings)
                    .overlays(self.overlays)
                    .background(background)
                    .show_output(ui);
                flying = view.flying;
                let (rect, response) = (view.response.rect, &view.response);
                // A click on a label map picks the label under it.
                if self.labels.is_some()
                    && let Some(pos) = response
                        .interact_pointer_pos()
                        .filter(|_| response.clicked())
                {
                    let ppp = ui.ctx().pixels_per_point();
                    let p = (pos - rect.min) * ppp;
                    self.pick_queue
                        .push([p.x.max(0.0) as u32, p.y.max(0.0) as u32]);
                }
                if s.orientation.is_some() && self.overlays {
                    orient::marker(ui.painter(), rect, &view.callback.camera);
                }
                callback = Some(view.callback);
            });
        if std::mem::take(&mut self.shot_requested) && self.shot.is_none() {
            self.shots_taken += 1;
            let path = PathBuf::from(format!("brickray-viewer-{}.png", self.shots_taken));
            self.request_shot(&ctx, path, callback.as_ref(), false);
        }
        self.step_script(&ctx, converged, callback.as_ref());

        // Redraw only while the image can change.
        self.continuous = self.script.is_some()
            || self.shot.is_some()
            || wants_redraw
            || flying
            || self.pick_frames > 0
            || !self.pick_queue.is_empty();
        if self.continuous {
            ctx.request_repaint();
        } else if self.opening.is_some() {
            ctx.request_repaint_after(std::time::Duration::from_millis(50));
        }
    }
}

/// The device needs: brickray's limits within the adapter's, and the
/// optional features it benefits from.
pub(crate) fn device_descriptor(adapter: &wgpu::Adapter) -> wgpu::DeviceDescriptor<'static> {
    let wanted = brickray::optional_features();
    let mut limits = brickray::required_limits().using_resolution(adapter.limits());
    // egui's depth buffer spans the window.
    limits.max_texture_dimension_2d = limits
        .max_texture_dimension_2d
        .max(adapter.limits().max_texture_dimension_2d.min(8192));
    wgpu::DeviceDescriptor {
        label: Some("brickray-viewer"),
        required_features: adapter.features() & wanted,
        required_limits: limits,
        ..Default::default()
    }
}
