//! A camera controller for hosts: orbit, pan, zoom and fly, reset and axis
//! views, perspective and orthographic. GPU-free: it turns abstract input
//! ([`CameraInput`]: drags in pixels, wheel notches, a fly velocity held for
//! a time) into a [`Camera`], whatever the windowing toolkit. Every input,
//! including non-finite deltas, leaves a camera that validates.

use super::{Camera, DepthConvention, Projection, VolumeFrame};
use crate::anatomy::Direction;
use glam::Vec3;

/// How mouse drags and keys move the camera.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Navigation {
    /// Turn about the target; drag to orbit, pan with the right button.
    Orbit,
    /// Move the eye; drag to look around, WASD/QE to move.
    Fly,
}

/// An axis-aligned view direction: the camera looks *from* this side.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AxisView {
    /// From +x.
    PosX,
    /// From -x.
    NegX,
    /// From +y (above).
    PosY,
    /// From -y (below).
    NegY,
    /// From +z.
    PosZ,
    /// From -z.
    NegZ,
}

impl AxisView {
    /// All six, in menu order.
    pub const ALL: [AxisView; 6] = [
        AxisView::PosX,
        AxisView::NegX,
        AxisView::PosY,
        AxisView::NegY,
        AxisView::PosZ,
        AxisView::NegZ,
    ];

    /// Its label.
    pub fn label(self) -> &'static str {
        match self {
            AxisView::PosX => "+X",
            AxisView::NegX => "-X",
            AxisView::PosY => "+Y",
            AxisView::NegY => "-Y",
            AxisView::PosZ => "+Z",
            AxisView::NegZ => "-Z",
        }
    }

    /// Parses `+x`, `-y`, ... (case-insensitive).
    pub fn parse(s: &str) -> Option<AxisView> {
        AxisView::ALL
            .into_iter()
            .find(|a| a.label().eq_ignore_ascii_case(s))
    }

    /// Its (yaw, pitch) in the orbit parametrisation of [`Camera::orbit`].
    fn angles(self) -> (f32, f32) {
        use std::f32::consts::FRAC_PI_2;
        match self {
            AxisView::PosX => (FRAC_PI_2, 0.0),
            AxisView::NegX => (-FRAC_PI_2, 0.0),
            AxisView::PosY => (0.0, MAX_PITCH),
            AxisView::NegY => (0.0, -MAX_PITCH),
            AxisView::PosZ => (0.0, 0.0),
            AxisView::NegZ => (std::f32::consts::PI, 0.0),
        }
    }
}

/// Pitch stays this far from the poles, so the up vector (+y) is never
/// parallel to the view.
pub const MAX_PITCH: f32 = std::f32::consts::FRAC_PI_2 - 1e-3;
/// Radians of orbit per pixel dragged.
const ORBIT_PER_PX: f32 = 0.008;
/// Distance factor per zoom step (a wheel notch).
const ZOOM_PER_STEP: f32 = 0.9;

/// Which button drags.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DragButton {
    /// Orbits (or turns the view when flying).
    Primary,
    /// Pans (the secondary or middle button).
    Secondary,
}

/// One input event, in toolkit-independent units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CameraInput {
    /// The pointer dragged `(dx, dy)` pixels with `button` held, over a
    /// viewport `viewport_height` pixels high (panning follows the cursor).
    Drag {
        /// The button held.
        button: DragButton,
        /// Pixels right.
        dx: f32,
        /// Pixels down.
        dy: f32,
        /// The viewport's height in pixels.
        viewport_height: f32,
    },
    /// Wheel notches (positive: closer).
    Wheel(f32),
    /// A fly velocity `(right, up, forward)` in scene radii per second, held
    /// for `dt` seconds (keys such as WASD/QE).
    Move {
        /// The velocity.
        velocity: Vec3,
        /// Seconds.
        dt: f32,
    },
    /// Back to the home framing.
    Reset,
    /// The home framing seen from an axis.
    Axis(AxisView),
    /// The home framing seen from an anatomical direction (a volume placed
    /// by [`Orientation::frame`](crate::anatomy::Orientation::frame)).
    Anatomical(Direction),
}

/// The controller's state. The eye is `target + dir(yaw, pitch) * distance`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraController {
    /// The point looked at (orbit centre).
    target: Vec3,
    /// Radians about +y.
    yaw: f32,
    /// Radians above the horizon, within `±MAX_PITCH`.
    pitch: f32,
    /// Eye to target.
    distance: f32,
    /// Vertical field of view of the perspective projection (radians).
    fov_y: f32,
    /// Orthographic instead of perspective (the same framing at the target).
    pub orthographic: bool,
    /// How input moves the camera.
    pub navigation: Navigation,
    /// The scene's bounding radius (sets zoom limits, clip planes and speeds).
    radius: f32,
    /// The framing `reset` returns to.
    home: (Vec3, f32, f32, f32),
}

impl CameraController {
    /// A controller framing the volume's box, seen from a three-quarter view.
    pub fn new(frame: &VolumeFrame) -> CameraController {
        let radius = (frame.world_size().length() * 0.5).max(1e-6);
        let fov_y = 40f32.to_radians();
        // Far enough that the bounding sphere fits the vertical field of view.
        let distance = radius / (fov_y * 0.5).sin() * 1.05;
        let home = (frame.center(), 0.6, 0.35, distance);
        CameraController {
            target: home.0,
            yaw: home.1,
            pitch: home.2,
            distance: home.3,
            fov_y,
            orthographic: false,
            navigation: Navigation::Orbit,
            radius,
            home,
        }
    }

    /// The point looked at (the orbit centre).
    pub fn target(&self) -> Vec3 {
        self.target
    }

    /// Radians about +y.
    pub fn yaw(&self) -> f32 {
        self.yaw
    }

    /// Radians above the horizon, within `±MAX_PITCH`.
    pub fn pitch(&self) -> f32 {
        self.pitch
    }

    /// Eye to target.
    pub fn distance(&self) -> f32 {
        self.distance
    }

    /// The vertical field of view of the perspective projection (radians).
    pub fn fov_y(&self) -> f32 {
        self.fov_y
    }

    /// Sets the vertical field of view, clamped to 1-170 degrees (a
    /// non-finite value is ignored).
    pub fn set_fov_y(&mut self, radians: f32) {
        if radians.is_finite() {
            self.fov_y = radians.clamp(1f32.to_radians(), 170f32.to_radians());
        }
    }

    /// Applies one input event.
    pub fn apply(&mut self, input: CameraInput) {
        match input {
            CameraInput::Drag {
                button: DragButton::Primary,
                dx,
                dy,
                ..
            } => self.rotate(dx, dy),
            CameraInput::Drag {
                button: DragButton::Secondary,
                dx,
                dy,
                viewport_height,
            } => self.pan(dx, dy, viewport_height),
            CameraInput::Wheel(steps) => self.zoom(steps),
            CameraInput::Move { velocity, dt } => self.fly(velocity, dt),
            CameraInput::Reset => self.reset(),
            CameraInput::Axis(a) => self.axis_view(a),
            CameraInput::Anatomical(d) => self.anatomical_view(d),
        }
    }

    /// Back to the initial framing (projection and navigation kept).
    pub fn reset(&mut self) {
        (self.target, self.yaw, self.pitch, self.distance) = self.home;
    }

    /// Looks at the home target from `axis` at the home distance.
    pub fn axis_view(&mut self, axis: AxisView) {
        self.reset();
        (self.yaw, self.pitch) = axis.angles();
    }

    /// Looks at the home target from anatomical direction `from` at the home
    /// distance, for a volume placed by
    /// [`Orientation::frame`](crate::anatomy::Orientation::frame): from R, L,
    /// A and P the head is up; from S and I anterior is up.
    pub fn anatomical_view(&mut self, from: Direction) {
        self.reset();
        (self.yaw, self.pitch) = from.view_angles(MAX_PITCH);
    }

    /// A controller framing a volume placed by
    /// [`Orientation::frame`](crate::anatomy::Orientation::frame), its home
    /// a three-quarter view from the patient's front left, a little above
    /// (the face toward the viewer, the head up).
    pub fn anatomical(frame: &VolumeFrame) -> CameraController {
        let mut c = CameraController::new(frame);
        // The eye direction (sin yaw, _, cos yaw) = (-0.56, _, -0.83): toward
        // -x (the patient's left) and -z (anterior), 0.6 rad off the front.
        c.home.1 = 0.6 - std::f32::consts::PI;
        c.reset();
        c
    }

    /// Sets the orbit explicitly (scripts): angles in radians, distance > 0.
    pub fn set_orbit(&mut self, yaw: f32, pitch: f32, distance: f32) {
        self.target = self.home.0;
        self.yaw = wrap(yaw);
        self.pitch = pitch.clamp(-MAX_PITCH, MAX_PITCH);
        self.distance = distance.clamp(self.min_distance(), self.max_distance());
    }

    fn min_distance(&self) -> f32 {
        self.radius * 1e-3
    }

    fn max_distance(&self) -> f32 {
        self.radius * 100.0
    }

    /// Unit vector from the target to the eye.
    fn dir(&self) -> Vec3 {
        let (sy, cy) = self.yaw.sin_cos();
        let (sp, cp) = self.pitch.sin_cos();
        Vec3::new(sy * cp, sp, cy * cp)
    }

    /// The eye position.
    pub fn eye(&self) -> Vec3 {
        self.target + self.dir() * self.distance
    }

    /// The camera's right and up vectors (unit, orthogonal to the view).
    fn basis(&self) -> (Vec3, Vec3) {
        let fwd = -self.dir();
        let right = fwd.cross(Vec3::Y).normalize();
        (right, right.cross(fwd))
    }

    /// A drag of `(dx, dy)` pixels with the primary button: orbit about the
    /// target, or turn the view about the eye when flying.
    pub fn rotate(&mut self, dx: f32, dy: f32) {
        if !(dx.is_finite() && dy.is_finite()) {
            return;
        }
        match self.navigation {
            Navigation::Orbit => {
                self.yaw = wrap(self.yaw - dx * ORBIT_PER_PX);
                self.pitch = (self.pitch + dy * ORBIT_PER_PX).clamp(-MAX_PITCH, MAX_PITCH);
            }
            Navigation::Fly => {
                // Keep the eye; the target swings around it.
                let eye = self.eye();
                self.yaw = wrap(self.yaw - dx * ORBIT_PER_PX);
                self.pitch = (self.pitch - dy * ORBIT_PER_PX).clamp(-MAX_PITCH, MAX_PITCH);
                self.target = eye - self.dir() * self.distance;
            }
        }
    }

    /// A drag of `(dx, dy)` pixels with the secondary button in a viewport
    /// `height` pixels high: moves eye and target in the view plane so the
    /// point at the target's depth follows the cursor.
    pub fn pan(&mut self, dx: f32, dy: f32, height: f32) {
        if !(dx.is_finite() && dy.is_finite()) {
            return;
        }
        let world_per_px = self.view_height() / height.max(1.0);
        let (right, up) = self.basis();
        self.target += (-right * dx + up * dy) * world_per_px;
    }

    /// Zooms by `steps` wheel notches (positive: closer). Orbit moves the eye
    /// towards the target; fly moves both forward.
    pub fn zoom(&mut self, steps: f32) {
        if !steps.is_finite() {
            return;
        }
        let steps = steps.clamp(-50.0, 50.0);
        match self.navigation {
            Navigation::Orbit => {
                self.distance = (self.distance * ZOOM_PER_STEP.powf(steps))
                    .clamp(self.min_distance(), self.max_distance());
            }
            Navigation::Fly => self.fly(Vec3::new(0.0, 0.0, steps * 0.05), 1.0),
        }
    }

    /// Flies: `v = (right, up, forward)` in units of the scene radius per
    /// second, for `dt` seconds. Eye and target move together.
    pub fn fly(&mut self, v: Vec3, dt: f32) {
        if !v.is_finite() || !dt.is_finite() {
            return;
        }
        let (right, up) = self.basis();
        let fwd = -self.dir();
        let d = (right * v.x + up * v.y + fwd * v.z) * self.radius * dt;
        // Stay within reach of the scene so the clip planes stay sane.
        let target = self.target + d;
        if (target - self.home.0).length() <= self.max_distance() {
            self.target = target;
        }
    }

    /// World height seen at the target's depth (the orthographic height).
    fn view_height(&self) -> f32 {
        2.0 * self.distance * (self.fov_y * 0.5).tan()
    }

    /// The camera (standard depth, clip planes around the scene).
    pub fn camera(&self) -> Camera {
        let eye = self.eye();
        let projection = if self.orthographic {
            Projection::Orthographic {
                height: self.view_height(),
            }
        } else {
            Projection::Perspective { fov_y: self.fov_y }
        };
        let to_centre = (eye - self.home.0).length();
        let far = to_centre + self.radius * 2.0;
        // Orthographic rays start at the near plane: keep it behind the scene.
        let near = if self.orthographic {
            self.radius * 1e-3
        } else {
            (to_centre - self.radius).max(far * 1e-4)
        };
        let eye = if self.orthographic {
            // Back off so the whole scene is in front of the near plane.
            self.target + self.dir() * (self.distance.max(to_centre) + self.radius * 2.0)
        } else {
            eye
        };
        let far = if self.orthographic {
            (eye - self.home.0).length() + self.radius * 2.0
        } else {
            far
        };
        // The up vector from the angles, orthogonal to the view (the same
        // orientation as +y): with the eye far from the origin and close to
        // the target, `target - eye` in f32 can lose the view's horizontal
        // part near the poles and come out parallel to +y.
        let (_, up) = self.basis();
        Camera {
            eye,
            target: self.target,
            up,
            projection,
            near,
            far,
            depth: DepthConvention::Standard,
        }
    }
}

/// An angle wrapped to `(-pi, pi]`.
fn wrap(a: f32) -> f32 {
    use std::f32::consts::{PI, TAU};
    let a = (a + PI).rem_euclid(TAU) - PI;
    if a <= -PI { a + TAU } else { a }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn frame() -> VolumeFrame {
        VolumeFrame::centered([256, 256, 108], [0.957, 0.957, 1.5])
    }

    /// One scripted step: an input event or a setting a host's UI changes.
    #[derive(Debug, Clone)]
    enum Op {
        Input(CameraInput),
        Nav(bool),
        Ortho(bool),
        Fov(f32),
    }

    fn op() -> impl Strategy<Value = Op> {
        let px = -2000.0f32..2000.0;
        let button = prop_oneof![Just(DragButton::Primary), Just(DragButton::Secondary)];
        let odd = prop_oneof![
            Just(f32::NAN),
            Just(f32::INFINITY),
            Just(-f32::INFINITY),
            Just(0.0f32),
            Just(1e30f32)
        ];
        prop_oneof![
            (button, px.clone(), px.clone(), 0.0f32..2000.0).prop_map(|(button, dx, dy, h)| {
                Op::Input(CameraInput::Drag {
                    button,
                    dx,
                    dy,
                    viewport_height: h,
                })
            }),
            (-20.0f32..20.0).prop_map(|s| Op::Input(CameraInput::Wheel(s))),
            (-3.0f32..3.0, -3.0f32..3.0, -3.0f32..3.0, 0.0f32..0.5).prop_map(|(a, b, c, dt)| {
                Op::Input(CameraInput::Move {
                    velocity: Vec3::new(a, b, c),
                    dt,
                })
            }),
            odd.clone().prop_map(|v| Op::Input(CameraInput::Wheel(v))),
            (odd.clone(), px).prop_map(|(v, d)| Op::Input(CameraInput::Drag {
                button: DragButton::Secondary,
                dx: v,
                dy: d,
                viewport_height: v,
            })),
            Just(Op::Input(CameraInput::Reset)),
            (0usize..6).prop_map(|i| Op::Input(CameraInput::Axis(AxisView::ALL[i]))),
            (0usize..6).prop_map(|i| Op::Input(CameraInput::Anatomical(Direction::ALL[i]))),
            any::<bool>().prop_map(Op::Nav),
            any::<bool>().prop_map(Op::Ortho),
            prop_oneof![-1.0f32..4.0, odd].prop_map(Op::Fov),
        ]
    }

    fn apply(c: &mut CameraController, op: &Op) {
        match *op {
            Op::Input(i) => c.apply(i),
            Op::Nav(f) => {
                c.navigation = if f {
                    Navigation::Fly
                } else {
                    Navigation::Orbit
                }
            }
            Op::Ortho(o) => c.orthographic = o,
            Op::Fov(f) => c.set_fov_y(f),
        }
    }

    /// Events do what the methods they stand for do.
    #[test]
    fn events_route_to_their_movements() {
        let mut a = CameraController::new(&frame());
        let mut b = a;
        a.apply(CameraInput::Drag {
            button: DragButton::Primary,
            dx: 30.0,
            dy: -12.0,
            viewport_height: 200.0,
        });
        b.rotate(30.0, -12.0);
        assert_eq!(a, b);
        a.apply(CameraInput::Drag {
            button: DragButton::Secondary,
            dx: 5.0,
            dy: 7.0,
            viewport_height: 200.0,
        });
        b.pan(5.0, 7.0, 200.0);
        assert_eq!(a, b);
        a.apply(CameraInput::Wheel(2.5));
        b.zoom(2.5);
        assert_eq!(a, b);
        a.apply(CameraInput::Move {
            velocity: Vec3::new(0.1, 0.0, 1.0),
            dt: 0.2,
        });
        b.fly(Vec3::new(0.1, 0.0, 1.0), 0.2);
        assert_eq!(a, b);
        a.apply(CameraInput::Axis(AxisView::NegZ));
        b.axis_view(AxisView::NegZ);
        assert_eq!(a, b);
        assert_ne!(
            a,
            CameraController::new(&frame()),
            "the inputs moved the camera"
        );
        a.apply(CameraInput::Reset);
        let mut home = CameraController::new(&frame());
        home.axis_view(AxisView::NegZ);
        home.reset();
        assert_eq!(a, home);
    }

    proptest! {
        /// Any input sequence leaves a camera the renderer accepts, with the
        /// pitch inside its bounds and the scene between the clip planes.
        #[test]
        fn any_input_gives_a_valid_camera(ops in proptest::collection::vec(op(), 0..40)) {
            let mut c = CameraController::new(&frame());
            for op in &ops {
                apply(&mut c, op);
                let cam = c.camera();
                prop_assert!(cam.validate().is_ok(), "{op:?}: {:?}", cam.validate());
                prop_assert!(c.pitch.abs() <= MAX_PITCH);
                prop_assert!(c.distance > 0.0 && c.distance.is_finite());
                let centre_dist = (cam.eye - frame().center()).length();
                prop_assert!(cam.far >= centre_dist + c.radius * 1.99, "far {} < scene", cam.far);
            }
        }

        /// Orbiting keeps the target and the distance; only the direction turns.
        #[test]
        fn orbit_keeps_target_and_distance(dx in -500.0f32..500.0, dy in -500.0f32..500.0) {
            let mut c = CameraController::new(&frame());
            let (target, distance) = (c.target, c.distance);
            c.rotate(dx, dy);
            prop_assert_eq!(c.target, target);
            prop_assert!(((c.eye() - c.target).length() - distance).abs() < 1e-4 * distance);
        }

        /// Flying turns the view about the eye: the eye stays put.
        #[test]
        fn fly_look_keeps_the_eye(dx in -500.0f32..500.0, dy in -500.0f32..500.0) {
            let mut c = CameraController::new(&frame());
            c.navigation = Navigation::Fly;
            let eye = c.eye();
            c.rotate(dx, dy);
            prop_assert!((c.eye() - eye).length() < 1e-4);
        }

        /// Panning moves the target within the view plane, by the cursor's
        /// motion at the target's depth.
        #[test]
        fn pan_moves_in_the_view_plane(dx in -300.0f32..300.0, dy in -300.0f32..300.0) {
            let mut c = CameraController::new(&frame());
            let before = c.target;
            let fwd = -c.dir();
            let h = c.view_height();
            c.pan(dx, dy, 300.0);
            let d = c.target - before;
            prop_assert!(d.dot(fwd).abs() < 1e-4);
            let expect = (dx * dx + dy * dy).sqrt() * h / 300.0;
            prop_assert!((d.length() - expect).abs() < 1e-3 * (1.0 + expect));
        }

        /// Zooming in then out by the same steps returns (within the limits).
        #[test]
        fn zoom_in_out_returns(steps in -5.0f32..5.0) {
            let mut c = CameraController::new(&frame());
            let d = c.distance;
            c.zoom(steps);
            c.zoom(-steps);
            prop_assert!((c.distance - d).abs() < 1e-4 * d);
        }
    }

    #[test]
    fn reset_restores_the_home_view() {
        let mut c = CameraController::new(&frame());
        let home = c;
        c.rotate(100.0, 40.0);
        c.pan(30.0, -20.0, 200.0);
        c.zoom(3.0);
        assert_ne!(c, home);
        c.reset();
        assert_eq!(c, home);
    }

    #[test]
    fn home_view_frames_the_whole_box() {
        let f = frame();
        let c = CameraController::new(&f).camera();
        let vp = c.view_proj(1.0);
        for i in 0..8 {
            let corner = f.model.transform_point3(Vec3::new(
                (i & 1) as f32,
                ((i >> 1) & 1) as f32,
                (i >> 2) as f32,
            ));
            let p = vp.project_point3(corner);
            assert!(p.x.abs() <= 1.0 && p.y.abs() <= 1.0, "corner {i} at {p}");
            assert!((0.0..=1.0).contains(&p.z), "corner {i} depth {}", p.z);
        }
    }

    #[test]
    fn axis_views_look_along_the_axis() {
        let mut c = CameraController::new(&frame());
        for (axis, from) in [
            (AxisView::PosX, Vec3::X),
            (AxisView::NegX, -Vec3::X),
            (AxisView::PosY, Vec3::Y),
            (AxisView::NegY, -Vec3::Y),
            (AxisView::PosZ, Vec3::Z),
            (AxisView::NegZ, -Vec3::Z),
        ] {
            c.axis_view(axis);
            let d = (c.eye() - c.target).normalize();
            assert!(d.dot(from) > 0.999, "{axis:?}: {d}");
            assert!(c.camera().validate().is_ok());
            assert_eq!(AxisView::parse(&axis.label().to_lowercase()), Some(axis));
        }
    }

    #[test]
    fn orthographic_frames_like_perspective_at_the_target() {
        let mut c = CameraController::new(&frame());
        let p = c.camera();
        c.orthographic = true;
        let o = c.camera();
        let Projection::Orthographic { height } = o.projection else {
            panic!("not orthographic")
        };
        let Projection::Perspective { fov_y } = p.projection else {
            panic!("not perspective")
        };
        let seen = 2.0 * (p.eye - p.target).length() * (fov_y * 0.5).tan();
        assert!((height - seen).abs() < 1e-5 * seen);
        // The ortho eye backs off: the whole box lies beyond the near plane.
        assert!((o.eye - c.target).length() > c.radius + o.near);
    }

    #[test]
    fn non_finite_input_is_ignored() {
        let mut c = CameraController::new(&frame());
        let before = c;
        c.rotate(f32::NAN, f32::INFINITY);
        c.pan(f32::NAN, 1.0, 100.0);
        c.zoom(f32::NAN);
        c.fly(Vec3::NAN, 1.0);
        assert_eq!(c, before);
    }
}
