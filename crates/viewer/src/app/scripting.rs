//! The script runner (`--script`, `crate::script`) and screenshots: the
//! view's pixels as PNG and a JSON sidecar of the camera and the settings.

use super::*;

/// A screenshot waiting for egui's capture.
#[derive(Debug)]
pub(super) struct PendingShot {
    pub(super) path: PathBuf,
    pub(super) viewport: Viewport,
    pub(super) camera: brickray::Camera,
    /// The settings the view was drawn with.
    pub(super) settings: brickray::RenderSettings,
    /// Where the volume was placed (its model matrix) and its anatomical
    /// axis code, if it has one.
    pub(super) frame: brickray::VolumeFrame,
    pub(super) orientation: Option<String>,
    /// Out of core: the data bricks of the last frame's cut.
    pub(super) working_set_bricks: Option<u32>,
    /// Out of core: the level-of-detail rule and tolerance in force.
    pub(super) lod: Option<(brickray::LodMetric, f32)>,
    /// Out of core: the visibility policy in force.
    pub(super) visibility: Option<brickray::VisibilityPolicy>,
    /// Out of core: whether the volume keeps its texels' gradients.
    pub(super) gradients_kept: Option<bool>,
    /// The prediction buffer's setting, and the last frame's state of it
    /// (`None`: that frame did not predict).
    pub(super) prediction: (PredictionChoice, Option<brickray::PredictionFrame>),
    /// The four-view layout's slices: each one's viewport in the shot's
    /// pixels and its view.
    pub(super) slices: Vec<(Viewport, brickray::SliceView)>,
    /// The four-view layout's 3D view, in the shot's pixels.
    pub(super) view_3d: Option<Viewport>,
    pub(super) image: Arc<Mutex<Option<Arc<egui::ColorImage>>>>,
}

/// The script's progress.
#[derive(Debug)]
pub(super) struct ScriptRunner {
    pub(super) actions: Vec<Action>,
    pub(super) next: usize,
    /// Frames left to draw before the next action.
    pub(super) wait: u32,
    /// Waiting for convergence, with the frames left.
    pub(super) converge: Option<u32>,
}

impl ViewerApp {
    pub(super) fn finish_script(&mut self, r: Result<(), String>) {
        // A failed step ends the run: the window closes and the exit status
        // says why (a script never leaves the viewer waiting on a failure).
        self.close_requested |= r.is_err();
        if let Ok(mut o) = self.outcome.lock()
            && o.is_none()
        {
            *o = Some(r);
        }
        self.script = None;
    }

    /// Starts a screenshot of the volume view.
    /// With `window`, of the whole window.
    pub(super) fn request_shot(
        &mut self,
        ctx: &egui::Context,
        path: PathBuf,
        callback: Option<&VolumeCallback>,
        window: bool,
    ) {
        let Some(cb) = callback else {
            return self.fail("screenshot: no volume view".into());
        };
        let screen = ctx.content_rect().size() * ctx.pixels_per_point();
        let screen = [screen.x.round() as u32, screen.y.round() as u32];
        let rect = if window { ctx.content_rect() } else { cb.rect };
        let Some(viewport) = viewport_px(&rect, ctx.pixels_per_point(), screen) else {
            return self.fail("screenshot: the view is empty".into());
        };
        let slices = self
            .shown_slices
            .iter()
            .filter_map(|(r, v)| {
                let p = viewport_px(r, ctx.pixels_per_point(), screen)?;
                let (x, y) = (p.x.checked_sub(viewport.x)?, p.y.checked_sub(viewport.y)?);
                Some((Viewport { x, y, ..p }, *v))
            })
            .collect();
        let view_3d = self.shown_view_3d.and_then(|r| {
            let p = viewport_px(&r, ctx.pixels_per_point(), screen)?;
            let (x, y) = (p.x.checked_sub(viewport.x)?, p.y.checked_sub(viewport.y)?);
            Some(Viewport { x, y, ..p })
        });
        let slot = Arc::new(Mutex::new(None));
        let (s, c) = (slot.clone(), ctx.clone());
        ctx.request_screenshot(move |image| {
            if let Ok(mut g) = s.lock() {
                *g = Some(image);
            }
            c.request_repaint();
        });
        let streamed = self.shown.as_ref().is_some_and(|s| s.streamed);
        self.shot = Some(PendingShot {
            path,
            viewport,
            camera: cb.camera,
            settings: cb.settings,
            frame: cb.frame,
            orientation: self
                .shown
                .as_ref()
                .and_then(|s| s.orientation)
                .map(|o| o.code()),
            working_set_bricks: self
                .stats
                .last()
                .filter(|_| streamed)
                .map(|s| s.working_set as u32),
            lod: streamed.then_some((self.ooc.lod_metric, self.ooc.tolerance_px)),
            visibility: streamed.then_some(self.ooc.visibility),
            gradients_kept: self.stats.gradients_kept().filter(|_| streamed),
            prediction: (self.prediction, self.stats.prediction()),
            slices,
            view_3d,
            image: slot,
        });
    }

    /// Saves a finished screenshot (the view's pixels) and its JSON sidecar.
    pub(super) fn finish_shot(&mut self) {
        let Some(shot) = self.shot.as_ref() else {
            return;
        };
        let Some(image) = shot.image.lock().ok().and_then(|mut g| g.take()) else {
            return;
        };
        let shot = self.shot.take().expect("checked above");
        match save_shot(&shot, &image) {
            Ok(()) => self.messages.push(format!("saved {}", shot.path.display())),
            Err(e) => self.fail(format!("screenshot {}: {e}", shot.path.display())),
        }
    }

    /// Runs script actions until one has to wait.
    pub(super) fn step_script(
        &mut self,
        ctx: &egui::Context,
        converged: bool,
        callback: Option<&VolumeCallback>,
    ) {
        loop {
            let Some(s) = self.script.as_mut() else {
                return;
            };
            if self.opening.is_some() || self.shot.is_some() {
                return;
            }
            if s.wait > 0 {
                s.wait -= 1;
                return;
            }
            if let Some(left) = s.converge {
                if converged {
                    s.converge = None;
                } else if left == 0 {
                    s.converge = None;
                    return self.fail("wait converged: the image did not converge".into());
                } else {
                    s.converge = Some(left - 1);
                    return;
                }
            }
            let Some(action) = s.actions.get(s.next).cloned() else {
                return self.finish_script(Ok(()));
            };
            s.next += 1;
            match action {
                Action::Open(a) => match Input::parse(&a) {
                    Ok(i) => self.start_open(i),
                    Err(e) => return self.fail(e.to_string()),
                },
                Action::TfPreset(p) => {
                    let range = self
                        .shown
                        .as_ref()
                        .map_or([0.0, 1.0], |s| s.desc.value_range);
                    self.tf = TfModel::preset(p, range);
                    self.tf_dirty = true;
                }
                Action::TfLoad(path) => match TfModel::load(&path) {
                    Ok(m) => {
                        self.tf = m;
                        self.tf_dirty = true;
                    }
                    Err(e) => return self.fail(e.to_string()),
                },
                Action::Mode(m, iso) => {
                    self.mode = m;
                    if let Some(v) = iso {
                        self.iso = v;
                    }
                }
                Action::Iso(v) => self.iso = v,
                Action::Step(v) => self.settings.step_factor = v,
                Action::Termination(t) => self.settings.accel.early_termination = t,
                Action::Skipping(on) => self.settings.accel.empty_space_skipping = on,
                Action::Preint(on) => self.settings.preintegrated = on,
                Action::AdaptiveStep(on) => self.settings.accel.adaptive_step = on,
                Action::Orbit(yaw, pitch, d) => {
                    let home = self
                        .shown
                        .as_ref()
                        .map(|s| CameraController::new(&s.frame).distance());
                    if let (Some(c), Some(home)) = (self.camera.as_mut(), home) {
                        c.set_orbit(yaw.to_radians(), pitch.to_radians(), d * home);
                    }
                }
                Action::Axis(a) => {
                    if let Some(c) = self.camera.as_mut() {
                        c.axis_view(a);
                    }
                }
                Action::View(d) => {
                    if self.shown.as_ref().is_some_and(|s| s.orientation.is_none()) {
                        return self
                            .fail("camera view: the volume has no anatomical orientation".into());
                    }
                    if let Some(c) = self.camera.as_mut() {
                        c.anatomical_view(d);
                    }
                }
                Action::Reset => {
                    if let Some(c) = self.camera.as_mut() {
                        c.reset();
                    }
                }
                Action::Orthographic(o) => {
                    if let Some(c) = self.camera.as_mut() {
                        c.orthographic = o;
                    }
                }
                Action::Overlays(on) => self.overlays = on,
                Action::FourViews(on) => self.four_views = on,
                Action::Crosshair(p) => self.crosshair = Some(p),
                Action::Window(w) => {
                    self.window = w;
                    self.window_dirty = true;
                }
                Action::Background(c) => self.background = c,
                Action::U8Exact(exact) => {
                    if exact != self.u8_exact {
                        self.u8_exact = exact;
                        self.renderer_dirty = true;
                    }
                    // The reopen starts at the next frame; wait for it.
                    if let Some(s) = self.script.as_mut() {
                        s.wait = 1;
                    }
                    return;
                }
                Action::Clip(min, max) => self.settings.clip = brickray::ClipBox { min, max },
                Action::Bricks(budget) => {
                    self.ooc.brick_budget = budget;
                    self.ooc_dirty = true;
                }
                Action::Visibility(policy) => {
                    self.ooc.visibility = policy;
                    self.ooc_dirty = true;
                }
                Action::Prediction(choice) => {
                    self.prediction = choice;
                    self.prediction_dirty = true;
                }
                Action::Lod(metric, tolerance_px) => {
                    self.ooc.lod_metric = metric;
                    if let Some(t) = tolerance_px {
                        self.ooc.tolerance_px = t;
                    }
                    self.ooc_dirty = true;
                }
                // Changes above take effect in this frame's drawing; waits
                // count frames drawn after it.
                Action::Wait(n) => {
                    if let Some(s) = self.script.as_mut() {
                        s.wait = n;
                    }
                    return;
                }
                Action::WaitConverged(n) => {
                    if let Some(s) = self.script.as_mut() {
                        s.converge = Some(n);
                        s.wait = 1;
                    }
                    return;
                }
                Action::Screenshot(p) => {
                    // The capture is of the next frame: the state is unchanged.
                    self.request_shot(ctx, p, callback, false);
                    return;
                }
                Action::WindowScreenshot(p) => {
                    self.request_shot(ctx, p, callback, true);
                    return;
                }
                Action::Pick(px) => self.pick_queue.push(px),
                // Sent to the renderer at the next frame's `apply`.
                Action::Channel(c, edit) => {
                    if let Err(e) = self.channel_action(c, edit) {
                        return self.fail(e);
                    }
                }
                // Run with the GPU at the next frame's `apply`, before the
                // script's next line.
                Action::Overlay(o) => {
                    self.overlay_queue.push(o);
                    return;
                }
                Action::Labels(l) => {
                    let Some(t) = self.labels.as_mut() else {
                        return self.fail("labels: the volume shown is not a label map".into());
                    };
                    match l {
                        LabelAction::ShowOnly(ids) => t.show_only(&ids),
                        LabelAction::ShowAll => t.show_all(),
                        LabelAction::Select(ids) => t.selected = ids.into_iter().collect(),
                        LabelAction::Opacity(o) => t.default_opacity = o,
                        LabelAction::Table(path) => {
                            match std::fs::read(&path)
                                .map_err(|e| e.to_string())
                                .and_then(|b| {
                                    brickray::LabelTable::from_file_bytes(&b)
                                        .map_err(|e| e.to_string())
                                }) {
                                Ok(table) => *t = table,
                                Err(e) => return self.fail(format!("{}: {e}", path.display())),
                            }
                        }
                    }
                    self.tf_dirty = true;
                }
                Action::Quit => {
                    self.finish_script(Ok(()));
                    ctx.send_viewport_cmd(egui::ViewportCommand::Close);
                    return;
                }
            }
        }
    }
}

/// Writes the view's pixels as PNG and the camera and viewport as JSON.
fn save_shot(shot: &PendingShot, image: &egui::ColorImage) -> Result<(), String> {
    let vp = shot.viewport;
    let [w, h] = image.size;
    if (vp.x + vp.width) as usize > w || (vp.y + vp.height) as usize > h {
        return Err(format!(
            "the view {vp:?} is outside the captured {w}x{h} image"
        ));
    }
    let mut rgba = Vec::with_capacity((vp.width * vp.height * 4) as usize);
    for y in vp.y..vp.y + vp.height {
        for x in vp.x..vp.x + vp.width {
            rgba.extend_from_slice(&image.pixels[y as usize * w + x as usize].to_array());
        }
    }
    if let Some(dir) = shot.path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| e.to_string())?;
    }
    image::save_buffer(
        &shot.path,
        &rgba,
        vp.width,
        vp.height,
        image::ExtendedColorType::Rgba8,
    )
    .map_err(|e| e.to_string())?;
    let c = shot.camera;
    let projection = match c.projection {
        brickray::Projection::Perspective { fov_y } => {
            serde_json::json!({"perspective": {"fov_y": fov_y}})
        }
        brickray::Projection::Orthographic { height } => {
            serde_json::json!({"orthographic": {"height": height}})
        }
    };
    let sidecar = serde_json::json!({
        "viewport": [vp.width, vp.height],
        "camera": {
            "eye": c.eye.to_array(),
            "target": c.target.to_array(),
            "up": c.up.to_array(),
            "projection": projection,
            "near": c.near,
            "far": c.far,
        },
        // Texture space to world, column-major, and the volume's dims.
        "frame": {
            "model": shot.frame.model.to_cols_array(),
            "dims": shot.frame.dims,
        },
        "orientation": shot.orientation,
        // What the view was drawn with (the sampling and its accelerations).
        "settings": {
            "step": shot.settings.step_factor,
            "shading": shot.settings.shading.enabled,
            "early_termination": shot.settings.accel.early_termination,
            "empty_space_skipping": shot.settings.accel.empty_space_skipping,
            "adaptive_step": shot.settings.accel.adaptive_step,
            "preintegrated": shot.settings.preintegrated,
        },
        "working_set_bricks": shot.working_set_bricks,
        "lod": shot.lod.map(|(metric, tolerance_px)| match metric.budget() {
            None => serde_json::json!({"rule": "geometric", "tolerance_px": tolerance_px}),
            Some(budget) => serde_json::json!({"rule": crate::script::lod_rule_name(metric), "error_budget": budget}),
        }),
        "visibility": shot.visibility.map(brickray::VisibilityPolicy::name),
        "gradients_kept": shot.gradients_kept,
        "prediction": {
            "setting": shot.prediction.0.name(),
            // Frames since the history was cleared, as the renderer reported
            // for the last frame drawn.
            "frames": shot.prediction.1.map(|p| p.frames),
        },
        // The four-view layout's slices (viewport x, y, width, height in
        // this image's pixels; the view in voxel index coordinates).
        "slices": shot.slices.iter().map(|(vp, v)| serde_json::json!({
            "viewport": [vp.x, vp.y, vp.width, vp.height],
            "centre": v.centre,
            "right": v.right,
            "up": v.up,
            "height": v.height,
        })).collect::<Vec<_>>(),
        "view_3d": shot.view_3d.map(|vp| [vp.x, vp.y, vp.width, vp.height]),
    });
    let text = serde_json::to_string_pretty(&sidecar).map_err(|e| e.to_string())?;
    std::fs::write(shot.path.with_extension("json"), text).map_err(|e| e.to_string())
}
