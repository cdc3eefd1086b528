use super::*;
use crate::camera::CameraController;
use proptest::prelude::*;

/// A voxel-to-RAS matrix whose index axis `i` points along `dirs[i]` with
/// spacing `spacing[i]`, turned by `angle` radians about `tilt_axis` (an
/// oblique acquisition), with an origin.
fn placement(dirs: [Direction; 3], spacing: [f64; 3], tilt_axis: DVec3, angle: f64) -> DMat4 {
    let turn = DMat3::from_axis_angle(tilt_axis.normalize(), angle);
    let cols = [0, 1, 2].map(|i| turn * dirs[i].ras() * spacing[i]);
    DMat4::from_cols(
        cols[0].extend(0.0),
        cols[1].extend(0.0),
        cols[2].extend(0.0),
        DVec3::new(-90.0, 120.0, -60.0).extend(1.0),
    )
}

/// Index-axis directions covering the three anatomical axes, each way.
fn directions() -> impl Strategy<Value = [Direction; 3]> {
    (0usize..6, any::<[bool; 3]>())
        .prop_map(|(p, flip)| [0, 1, 2].map(|i| Direction::of_axis(PERMS[p][i], flip[i])))
}

fn ras_of_world(v: DVec3) -> DVec3 {
    RAS_TO_WORLD.transpose() * v
}

fn close(a: DVec3, b: DVec3, tol: f64) -> bool {
    (a - b).length() <= tol
}

#[test]
fn the_usual_acquisitions_have_their_codes() {
    // NIfTI in the canonical order.
    let nifti = placement(
        [Direction::Right, Direction::Anterior, Direction::Superior],
        [1.0, 1.0, 1.0],
        DVec3::X,
        0.0,
    );
    assert_eq!(Orientation::new(nifti).unwrap().code(), "RAS");
    // A DICOM axial series: rows toward the patient's left, columns toward
    // posterior, slices toward the head (LPS+ diagonal), in RAS+.
    let dicom = DMat4::from_diagonal(glam::DVec4::new(-0.48, -0.48, 1.5, 1.0));
    let o = Orientation::new(dicom).unwrap();
    assert_eq!(o.code(), "LPS");
    assert_eq!(o.index_axis(Direction::Right), (0, -1.0));
    assert_eq!(o.index_axis(Direction::Posterior), (1, 1.0));
    assert_eq!(o.direction_of(2, -1.0), Direction::Inferior);
    // A sagittal series, 20 degrees oblique.
    let sag = placement(
        [Direction::Posterior, Direction::Inferior, Direction::Left],
        [0.9, 0.9, 1.2],
        DVec3::new(0.3, 1.0, 0.2),
        20f64.to_radians(),
    );
    assert_eq!(Orientation::new(sag).unwrap().code(), "PIL");
}

#[test]
fn bad_matrices_are_typed_errors() {
    let mut m = DMat4::IDENTITY;
    m.x_axis.x = f64::NAN;
    assert_eq!(Orientation::new(m), Err(AnatomyError::NotFinite));
    let flat = DMat4::from_diagonal(glam::DVec4::new(1.0, 1.0, 0.0, 1.0));
    assert!(matches!(
        Orientation::new(flat),
        Err(AnatomyError::Singular { .. })
    ));
    // Two index axes along one direction.
    let twin = DMat4::from_cols(
        DVec3::X.extend(0.0),
        DVec3::X.extend(0.0),
        DVec3::Z.extend(0.0),
        glam::DVec4::W,
    );
    assert!(Orientation::new(twin).is_err());
}

#[test]
fn directions_parse_by_letter_and_name() {
    for d in Direction::ALL {
        assert_eq!(Direction::parse(&d.letter().to_string()), Some(d));
        assert_eq!(Direction::parse(&format!("{d:?}").to_uppercase()), Some(d));
        assert_eq!(d.opposite().opposite(), d);
        assert!(close(d.world(), -d.opposite().world(), 0.0));
    }
    assert_eq!(Direction::parse("x"), None);
    assert_eq!(Direction::parse("an"), None);
    // The display world: head up, facing -z, right-handed.
    assert_eq!(Direction::Superior.world(), DVec3::Y);
    assert_eq!(Direction::Anterior.world(), -DVec3::Z);
    assert!((RAS_TO_WORLD.determinant() - 1.0).abs() < 1e-12);
}

/// The screen's right and up of a camera, in the world.
fn screen_axes(c: &crate::Camera) -> (DVec3, DVec3, DVec3) {
    let f = (c.target - c.eye).normalize().as_dvec3();
    let up = c.up.as_dvec3();
    let up = (up - f * up.dot(f)).normalize();
    (f.cross(up), up, f)
}

#[test]
fn each_anatomical_view_looks_from_its_side_with_the_head_or_the_face_up() {
    let o = Orientation::new(DMat4::from_diagonal(glam::DVec4::new(-0.5, -0.5, 1.5, 1.0))).unwrap();
    let frame = o.frame([256, 256, 108]);
    let mut c = CameraController::anatomical(&frame);
    for from in Direction::ALL {
        c.apply(crate::camera::CameraInput::Anatomical(from));
        let cam = c.camera();
        let (right, up, forward) = screen_axes(&cam);
        let (r, u, f) = (ras_of_world(right), ras_of_world(up), ras_of_world(forward));
        assert!(close(-f, from.ras(), 2e-3), "{from:?}: looks along {f}");
        let (want_up, want_right) = match from {
            Direction::Anterior => (Direction::Superior, Direction::Left),
            Direction::Posterior => (Direction::Superior, Direction::Right),
            Direction::Right => (Direction::Superior, Direction::Anterior),
            Direction::Left => (Direction::Superior, Direction::Posterior),
            Direction::Superior => (Direction::Anterior, Direction::Right),
            Direction::Inferior => (Direction::Anterior, Direction::Left),
        };
        assert!(close(u, want_up.ras(), 2e-3), "{from:?}: up {u}");
        assert!(close(r, want_right.ras(), 2e-3), "{from:?}: right {r}");
    }
    // The home view sees the face (from the front) with the head up.
    c.apply(crate::camera::CameraInput::Reset);
    let (_, up, forward) = screen_axes(&c.camera());
    assert!(
        ras_of_world(forward).y < -0.5,
        "home looks from the front (toward posterior)"
    );
    assert!(ras_of_world(up).z > 0.9, "home has the head up");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Any acquisition, up to 40 degrees oblique: the code names each index
    /// axis's nearest direction; the display frame puts every voxel where
    /// its patient position says (up to the frame's centring and scale) with
    /// the longest side 1 and the centre at the origin.
    #[test]
    fn the_frame_places_voxels_by_their_patient_position(
        dirs in directions(),
        spacing in prop::array::uniform3(0.2f64..3.0),
        dims in prop::array::uniform3(2u32..300),
        tilt in prop::array::uniform3(-1.0f64..1.0),
        angle in -0.7f64..0.7,
    ) {
        let tilt = DVec3::from_array(tilt) + DVec3::new(0.0, 0.0, 1e-3);
        let m = placement(dirs, spacing, tilt, angle);
        let o = Orientation::new(m).unwrap();
        prop_assert_eq!(o.axes(), dirs);
        let frame = o.frame(dims);
        frame.validate().unwrap();
        let model = frame.model.as_dmat4();
        let dimv = DVec3::from_array(dims.map(f64::from));
        let world = |ijk: DVec3| model.transform_point3((ijk + DVec3::splat(0.5)) / dimv);
        let ras = |ijk: DVec3| m.transform_point3(ijk);
        // Differences of voxel positions: the same up to one scale.
        let (a, b, c) = (DVec3::ZERO, dimv - DVec3::ONE, DVec3::new(dimv.x - 1.0, 0.0, 0.0));
        let scale = (world(b) - world(a)).length() / (ras(b) - ras(a)).length();
        for (p, q) in [(a, b), (a, c), (c, b)] {
            let w = ras_of_world(world(q) - world(p));
            prop_assert!(close(w, (ras(q) - ras(p)) * scale, 1e-4), "{w} vs {}", ras(q) - ras(p));
        }
        let longest = (0..3).map(|i| model.col(i).truncate().length()).fold(0.0, f64::max);
        prop_assert!((longest - 1.0).abs() < 1e-5);
        prop_assert!(model.transform_point3(DVec3::splat(0.5)).length() < 1e-5);
    }

    /// Slices of any axis-aligned acquisition show radiologically: the
    /// screen's right and up are the patient directions the convention
    /// names, and the slice passes through the point asked for.
    #[test]
    fn slices_are_radiological_whatever_the_storage_order(
        dirs in directions(),
        spacing in prop::array::uniform3(0.2f64..3.0),
        dims in prop::array::uniform3(2u32..300),
        at in prop::array::uniform3(0.0f64..1.0),
        aspect in 0.3f64..3.0,
    ) {
        let o = Orientation::new(placement(dirs, spacing, DVec3::Z, 0.0)).unwrap();
        let frame = o.frame(dims);
        let point = [0, 1, 2].map(|i| at[i] * (dims[i] - 1) as f64);
        for (axis, right, up) in [
            (SliceAxis::Axial, Direction::Left, Direction::Anterior),
            (SliceAxis::Coronal, Direction::Left, Direction::Superior),
            (SliceAxis::Sagittal, Direction::Posterior, Direction::Superior),
        ] {
            let view = o.slice(axis, point, &frame, aspect).unwrap();
            let g = view.resolve(&frame, aspect).unwrap();
            prop_assert!(close(ras_of_world(g.right), right.ras(), 1e-6), "{axis:?} right");
            prop_assert!(close(ras_of_world(g.up), up.ras(), 1e-6), "{axis:?} up");
            let n = o.slice_axes(axis).normal;
            prop_assert_eq!(view.centre[n], point[n]);
            // The whole slice fits the viewport.
            let (w, h) = (g.half_width * 2.0, g.half_height * 2.0);
            let model = frame.model.as_dmat4();
            let len = |i: usize| model.col(i).truncate().length();
            let a = o.slice_axes(axis);
            prop_assert!(len(a.right.0) <= w + 1e-9 && len(a.up.0) <= h + 1e-9);
        }
    }
}

#[test]
fn oriented_slices_refuse_what_spans_no_plane() {
    let frame = VolumeFrame::centered([8, 8, 8], [1.0; 3]);
    for (n, r, u) in [
        (0, (0, 1.0), (1, 1.0)),
        (2, (1, 1.0), (1, -1.0)),
        (2, (0, 0.0), (1, 1.0)),
        (2, (0, f64::NAN), (1, 1.0)),
        (3, (0, 1.0), (1, 1.0)),
    ] {
        assert_eq!(
            SliceView::oriented(n, 1.0, r, u, &frame, 1.0),
            Err(SliceError::NoPlane),
            "{n} {r:?} {u:?}"
        );
    }
    // Positive signs are the orthogonal slice.
    assert_eq!(
        SliceView::oriented(1, 3.0, (0, 1.0), (2, 1.0), &frame, 1.5),
        SliceView::orthogonal(SliceAxis::Coronal, 3.0, &frame, 1.5)
    );
}
