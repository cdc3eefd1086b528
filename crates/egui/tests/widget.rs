//! The widgets in a headless egui context (no GPU): synthetic pointer and
//! wheel events move the camera controller exactly as the same
//! `CameraInput` events applied directly, the wheel steps a slice, and each
//! widget adds one paint callback to the frame's shapes.

use brickray::core::camera::{CameraController, CameraInput, DragButton};
use brickray::{RenderSettings, SliceAxis, SliceView, VolumeFrame};
use brickray_egui::{SliceWidget, VolumeView};
use egui::{Event, PointerButton, Pos2, Rect, Vec2};

/// A headless egui context with its clock.
struct Headless {
    ctx: egui::Context,
    time: f64,
}

/// What one frame produced.
struct FrameOut {
    /// The view's response.
    response: egui::Response,
    /// `smooth_scroll_delta.y` as the widget saw it.
    scroll: f32,
    /// Paint callbacks among the output shapes.
    callbacks: usize,
    /// All the output shapes.
    shapes: usize,
}

impl Headless {
    fn new() -> Headless {
        Headless {
            ctx: egui::Context::default(),
            time: 0.0,
        }
    }

    /// One frame with `events`, `show` drawing the widget in a central panel.
    fn frame(
        &mut self,
        events: Vec<Event>,
        mut show: impl FnMut(&mut egui::Ui) -> egui::Response,
    ) -> FrameOut {
        self.time += 1.0 / 60.0;
        let input = egui::RawInput {
            screen_rect: Some(Rect::from_min_size(Pos2::ZERO, Vec2::new(400.0, 300.0))),
            time: Some(self.time),
            events,
            ..Default::default()
        };
        let mut seen = None;
        let mut out = self.ctx.run_ui(input, |ui| {
            egui::CentralPanel::default_margins()
                .frame(egui::Frame::NONE)
                .show(ui, |ui| {
                    let scroll = ui.input(|i| i.smooth_scroll_delta.y);
                    seen = Some((show(ui), scroll));
                });
        });
        out.textures_delta.clear();
        let callbacks = out
            .shapes
            .iter()
            .filter(|s| matches!(s.shape, egui::Shape::Callback(_)))
            .count();
        let (response, scroll) = seen.expect("shown");
        FrameOut {
            response,
            scroll,
            callbacks,
            shapes: out.shapes.len(),
        }
    }
}

/// A drag the widget should turn into `CameraInput::Drag`: the button and
/// the pointer's motion.
type Drag = (DragButton, Vec2);

fn button(pos: Pos2, button: PointerButton, pressed: bool) -> Event {
    Event::PointerButton {
        pos,
        button,
        pressed,
        modifiers: Default::default(),
    }
}

fn wheel(dy: f32) -> Event {
    Event::MouseWheel {
        unit: egui::MouseWheelUnit::Point,
        delta: Vec2::new(0.0, dy),
        phase: egui::TouchPhase::Move,
        source: egui::MouseWheelSource::Unknown,
        modifiers: Default::default(),
    }
}

/// Drags and the wheel over a `VolumeView` move the controller as the same
/// `CameraInput` events applied directly do, and the view adds one paint
/// callback per frame.
#[test]
fn volume_view_drives_the_camera_like_camera_inputs() {
    let frame = VolumeFrame::centered([64, 48, 32], [1.0, 1.0, 2.0]);
    let mut widget = CameraController::new(&frame);
    let mut direct = widget;
    let mut ui = Headless::new();
    let settings = RenderSettings::default();

    // The positions the pointer goes through: a primary drag, then a
    // secondary drag (pan).
    let plan: Vec<(Vec<Event>, Option<Drag>)> = vec![
        (vec![Event::PointerMoved(Pos2::new(200.0, 150.0))], None),
        (
            vec![button(
                Pos2::new(200.0, 150.0),
                PointerButton::Primary,
                true,
            )],
            None,
        ),
        (
            vec![Event::PointerMoved(Pos2::new(230.0, 140.0))],
            Some((DragButton::Primary, Vec2::new(30.0, -10.0))),
        ),
        (
            vec![Event::PointerMoved(Pos2::new(250.0, 160.0))],
            Some((DragButton::Primary, Vec2::new(20.0, 20.0))),
        ),
        (
            vec![button(
                Pos2::new(250.0, 160.0),
                PointerButton::Primary,
                false,
            )],
            None,
        ),
        (
            vec![button(
                Pos2::new(250.0, 160.0),
                PointerButton::Secondary,
                true,
            )],
            None,
        ),
        (
            vec![Event::PointerMoved(Pos2::new(240.0, 180.0))],
            Some((DragButton::Secondary, Vec2::new(-10.0, 20.0))),
        ),
        (
            vec![button(
                Pos2::new(240.0, 180.0),
                PointerButton::Secondary,
                false,
            )],
            None,
        ),
    ];
    let mut moved_frames = 0;
    for (events, expect) in plan {
        let out = ui.frame(events, |ui| {
            VolumeView::new(&mut widget, frame, settings).show(ui)
        });
        assert_eq!(out.callbacks, 1, "one paint callback per frame");
        if let Some((button, d)) = expect {
            // The drag delta egui reports is the pointer's motion.
            assert_eq!(out.response.drag_delta(), d);
            direct.apply(CameraInput::Drag {
                button,
                dx: d.x,
                dy: d.y,
                viewport_height: out.response.rect.height(),
            });
            assert!(out.response.changed(), "a camera move marks the response");
            moved_frames += 1;
        } else {
            assert!(!out.response.changed());
        }
        assert_eq!(widget, direct);
    }
    assert_eq!(moved_frames, 3);
    assert_eq!(
        out_rect(&mut ui, &mut widget, frame),
        Rect::from_min_size(Pos2::ZERO, Vec2::new(400.0, 300.0)),
        "the view takes the space available"
    );
    assert_ne!(widget, CameraController::new(&frame), "the drags moved it");

    // The wheel: egui smooths it over frames; each frame's smoothed delta
    // is one Wheel input of delta / 50 notches.
    let before = widget;
    let mut events = vec![wheel(120.0)];
    let mut total = 0.0;
    for _ in 0..120 {
        let out = ui.frame(std::mem::take(&mut events), |ui| {
            VolumeView::new(&mut widget, frame, settings).show(ui)
        });
        if out.scroll != 0.0 {
            direct.apply(CameraInput::Wheel(out.scroll / 50.0));
            total += out.scroll;
        }
        assert_eq!(widget, direct);
    }
    assert!(
        (total - 120.0).abs() < 1.0,
        "the whole wheel delta: {total}"
    );
    assert!(
        widget.distance() < before.distance(),
        "a positive wheel zooms in"
    );
}

/// The view's rectangle (one frame without input).
fn out_rect(ui: &mut Headless, controller: &mut CameraController, frame: VolumeFrame) -> Rect {
    ui.frame(Vec::new(), |ui| {
        VolumeView::new(controller, frame, RenderSettings::default()).show(ui)
    })
    .response
    .rect
}

/// `show_output` reports the callback it added (the controller's camera,
/// the view's rectangle) and a background is painted under it.
#[test]
fn volume_view_output_and_background() {
    let frame = VolumeFrame::centered([16, 16, 16], [1.0; 3]);
    let mut controller = CameraController::new(&frame);
    let mut ui = Headless::new();
    let mut callback = None;
    let out = ui.frame(Vec::new(), |ui| {
        let o = VolumeView::new(&mut controller, frame, RenderSettings::default())
            .overlays(false)
            .background(egui::Color32::BLACK)
            .size(Vec2::new(200.0, 100.0))
            .show_output(ui);
        callback = Some(o.callback);
        assert!(!o.flying);
        o.response
    });
    assert_eq!(out.callbacks, 1);
    let plain = ui.frame(Vec::new(), |ui| {
        VolumeView::new(&mut controller, frame, RenderSettings::default()).show(ui)
    });
    assert_eq!(
        out.shapes,
        plain.shapes + 1,
        "the background is one more shape"
    );
    let cb = callback.expect("shown");
    assert_eq!(cb.rect, out.response.rect);
    assert_eq!(cb.rect.size(), Vec2::new(200.0, 100.0));
    assert_eq!(cb.camera, controller.camera());
    assert!(!cb.overlays);
}

/// The wheel over a `SliceWidget` steps its slice one voxel along the
/// normal per frame with a delta, as `SliceView::stepped` does.
#[test]
fn slice_widget_steps_with_the_wheel() {
    let frame = VolumeFrame::centered([64, 48, 32], [1.0, 1.0, 2.0]);
    let start = SliceView::through(SliceAxis::Axial, [32.0, 24.0, 16.0], &frame, 4.0 / 3.0)
        .expect("a slice");
    let mut slice = start;
    let mut want = start;
    let mut ui = Headless::new();
    // egui hovers what was under the pointer last frame: move there first.
    ui.frame(vec![Event::PointerMoved(Pos2::new(100.0, 100.0))], |ui| {
        SliceWidget::new(&mut slice, frame).slot(1).show(ui)
    });
    let mut events = vec![wheel(-60.0)];
    let mut steps = 0;
    for _ in 0..60 {
        let out = ui.frame(std::mem::take(&mut events), |ui| {
            SliceWidget::new(&mut slice, frame).slot(1).show(ui)
        });
        assert_eq!(out.callbacks, 1);
        if out.scroll != 0.0 {
            let g = want.resolve(&frame, 4.0 / 3.0).expect("resolves");
            want = want
                .stepped(&frame, out.scroll.signum() as f64 * g.normal_voxel())
                .expect("steps");
            assert!(out.response.changed());
            steps += 1;
        }
        assert_eq!(slice, want);
    }
    assert!(steps > 0, "the wheel reached the widget");
    assert_ne!(slice.centre, start.centre);
    // Stepped along the axial normal only.
    let moved: Vec<usize> = (0..3)
        .filter(|&a| (slice.centre[a] - start.centre[a]).abs() > 1e-9)
        .collect();
    assert_eq!(moved.len(), 1, "{:?} -> {:?}", start.centre, slice.centre);
}
