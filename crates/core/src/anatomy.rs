//! Anatomical orientation: where a volume's index axes point in the patient,
//! the display frame that shows a patient upright, the six anatomical views
//! and orthogonal slices in the radiological display convention
//! (docs/rendering-model.md, "Anatomical orientation").
//!
//! Conventions, stated once:
//! * **Patient space** is RAS+ (NIfTI's): +x points to the patient's Right,
//!   +y to Anterior, +z to Superior. DICOM's LPS+ is RAS+ with x and y
//!   negated.
//! * **Display world** (what [`Orientation::frame`] places the volume in, the
//!   renderer's world with +y up): `x = R`, `y = S`, `z = -A` (= P), a
//!   right-handed frame in which the patient stands upright and faces -z.
//! * **Views** ([`CameraController::anatomical_view`](crate::camera::CameraController::anatomical_view)):
//!   the camera looks *from* a direction; from R, L, A and P the patient's
//!   head is up; from S and I anterior is up.
//! * **Slices** ([`Orientation::slice`]): radiological, as scanners and PACS
//!   show them: axial seen from the feet (patient's left on the screen's
//!   right, anterior up), coronal seen from the front (left on the right,
//!   superior up), sagittal seen from the patient's left (anterior on the
//!   screen's left, superior up). Slices stay on the voxel grid: each screen
//!   axis is the index axis nearest the anatomical one (an oblique
//!   acquisition is shown in its own planes, labelled by the nearest
//!   directions, as ITK-SNAP and most PACS viewers do).

use crate::camera::VolumeFrame;
use crate::slice::{SliceAxis, SliceError, SliceView};
use glam::{DMat3, DMat4, DVec3};
use thiserror::Error;

/// One of the six anatomical directions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Direction {
    /// Toward the patient's right.
    Right,
    /// Toward the patient's left.
    Left,
    /// Toward the front (face).
    Anterior,
    /// Toward the back.
    Posterior,
    /// Toward the head.
    Superior,
    /// Toward the feet.
    Inferior,
}

impl Direction {
    /// All six, in the order of the viewer's buttons.
    pub const ALL: [Direction; 6] = [
        Direction::Anterior,
        Direction::Posterior,
        Direction::Left,
        Direction::Right,
        Direction::Superior,
        Direction::Inferior,
    ];

    /// Its letter: `R`, `L`, `A`, `P`, `S` or `I`.
    pub fn letter(self) -> char {
        match self {
            Direction::Right => 'R',
            Direction::Left => 'L',
            Direction::Anterior => 'A',
            Direction::Posterior => 'P',
            Direction::Superior => 'S',
            Direction::Inferior => 'I',
        }
    }

    /// Parses a letter or a name (`a`, `anterior`, ...; case-insensitive).
    pub fn parse(s: &str) -> Option<Direction> {
        let s = s.to_ascii_lowercase();
        Direction::ALL.into_iter().find(|d| {
            let name = format!("{d:?}").to_ascii_lowercase();
            s == name || s.len() == 1 && s.starts_with(d.letter().to_ascii_lowercase())
        })
    }

    /// The opposite direction.
    pub fn opposite(self) -> Direction {
        match self {
            Direction::Right => Direction::Left,
            Direction::Left => Direction::Right,
            Direction::Anterior => Direction::Posterior,
            Direction::Posterior => Direction::Anterior,
            Direction::Superior => Direction::Inferior,
            Direction::Inferior => Direction::Superior,
        }
    }

    /// Its unit vector in patient space (RAS+).
    pub fn ras(self) -> DVec3 {
        match self {
            Direction::Right => DVec3::X,
            Direction::Left => -DVec3::X,
            Direction::Anterior => DVec3::Y,
            Direction::Posterior => -DVec3::Y,
            Direction::Superior => DVec3::Z,
            Direction::Inferior => -DVec3::Z,
        }
    }

    /// Its unit vector in the display world of [`Orientation::frame`].
    pub fn world(self) -> DVec3 {
        RAS_TO_WORLD * self.ras()
    }

    /// The direction along `+` of RAS axis `axis` (0: R, 1: A, 2: S), or its
    /// opposite when `negative`.
    fn of_axis(axis: usize, negative: bool) -> Direction {
        let d = [Direction::Right, Direction::Anterior, Direction::Superior][axis];
        if negative { d.opposite() } else { d }
    }

    /// The camera's orbit angles `(yaw, pitch)` of the view *from* this
    /// direction in the display world ([`crate::Camera::orbit`]'s
    /// parametrisation, pitch within `±max_pitch`): the head up from R, L, A
    /// and P; anterior up from S and I.
    pub(crate) fn view_angles(self, max_pitch: f32) -> (f32, f32) {
        use std::f32::consts::{FRAC_PI_2, PI};
        match self {
            Direction::Right => (FRAC_PI_2, 0.0),
            Direction::Left => (-FRAC_PI_2, 0.0),
            Direction::Anterior => (PI, 0.0),
            Direction::Posterior => (0.0, 0.0),
            // Just off the pole on the posterior side: the screen's up is
            // anterior.
            Direction::Superior => (0.0, max_pitch),
            Direction::Inferior => (PI, -max_pitch),
        }
    }
}

/// The six assignments of three index axes to three anatomical axes.
pub(crate) const PERMS: [[usize; 3]; 6] = [
    [0, 1, 2],
    [0, 2, 1],
    [1, 0, 2],
    [1, 2, 0],
    [2, 0, 1],
    [2, 1, 0],
];

/// Patient space (RAS+) to the display world: `x = R`, `y = S`, `z = -A`.
pub const RAS_TO_WORLD: DMat3 = DMat3::from_cols(
    DVec3::new(1.0, 0.0, 0.0),
    DVec3::new(0.0, 0.0, -1.0),
    DVec3::new(0.0, 1.0, 0.0),
);

/// A placement that cannot orient a volume.
#[derive(Debug, Clone, Copy, PartialEq, Error)]
#[non_exhaustive]
pub enum AnatomyError {
    /// The voxel-to-patient matrix holds NaN or an infinity.
    #[error("the voxel-to-patient matrix is not finite")]
    NotFinite,
    /// The voxel-to-patient matrix is singular (its axes span no volume).
    #[error("the voxel-to-patient matrix is singular (determinant {determinant})")]
    Singular {
        /// Its determinant.
        determinant: f64,
    },
}

/// Where a volume's index axes point in the patient (see the module
/// documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Orientation {
    /// Voxel index (voxel centres at integers) to patient millimetres, RAS+.
    voxel_to_ras: DMat4,
    /// The nearest anatomical direction of each index axis's `+` end.
    axes: [Direction; 3],
}

impl Orientation {
    /// The orientation of a volume whose voxel `(i, j, k)` lies at
    /// `voxel_to_ras * (i, j, k, 1)` in patient space (RAS+; a DICOM or
    /// NRRD LPS+ matrix is converted by negating its first two rows).
    ///
    /// Each index axis is given the anatomical axis it is nearest to, as the
    /// assignment of the three index axes to the three anatomical axes that
    /// maximises the sum of the absolute cosines (so two index axes never
    /// share one, however oblique the acquisition).
    pub fn new(voxel_to_ras: DMat4) -> Result<Orientation, AnatomyError> {
        let lin = DMat3::from_mat4(voxel_to_ras);
        if !voxel_to_ras.is_finite() {
            return Err(AnatomyError::NotFinite);
        }
        let determinant = lin.determinant();
        let scale = lin.x_axis.length() * lin.y_axis.length() * lin.z_axis.length();
        if determinant.is_nan() || determinant.abs() <= 1e-12 * scale {
            return Err(AnatomyError::Singular { determinant });
        }
        let unit = |i: usize| lin.col(i).normalize();
        let score = |p: &[usize; 3]| (0..3).map(|i| unit(i)[p[i]].abs()).sum::<f64>();
        // The first best permutation: deterministic at exact ties (45 degrees).
        let mut best = PERMS[0];
        for p in &PERMS[1..] {
            if score(p) > score(&best) {
                best = *p;
            }
        }
        let axes = [0, 1, 2].map(|i| Direction::of_axis(best[i], unit(i)[best[i]] < 0.0));
        Ok(Orientation { voxel_to_ras, axes })
    }

    /// The voxel-to-patient (RAS+) matrix.
    pub fn voxel_to_ras(&self) -> DMat4 {
        self.voxel_to_ras
    }

    /// The nearest anatomical direction of each index axis's `+` end.
    pub fn axes(&self) -> [Direction; 3] {
        self.axes
    }

    /// The axis code, as nibabel and ITK spell it: the letters of
    /// [`Self::axes`] (`"RAS"` for a NIfTI in the canonical order, `"LPS"`
    /// for a DICOM axial series).
    pub fn code(&self) -> String {
        self.axes.iter().map(|d| d.letter()).collect()
    }

    /// The index axis nearest `d` and its sign (`+1`: toward `d` as the index
    /// grows).
    pub fn index_axis(&self, d: Direction) -> (usize, f64) {
        for (i, a) in self.axes.iter().enumerate() {
            if *a == d {
                return (i, 1.0);
            }
            if a.opposite() == d {
                return (i, -1.0);
            }
        }
        unreachable!("the three axes cover the three anatomical axes")
    }

    /// The anatomical direction of index direction `axis` with `sign`.
    pub fn direction_of(&self, axis: usize, sign: f64) -> Direction {
        let d = self.axes[axis];
        if sign < 0.0 { d.opposite() } else { d }
    }

    /// The display frame: the volume placed by its patient position in the
    /// display world (`x = R`, `y = S`, `z = P`: upright, facing -z), its
    /// centre at the origin and its longest side 1, like
    /// [`VolumeFrame::centered`] (which this equals, up to the rotation, for
    /// a volume with no rotation).
    pub fn frame(&self, dims: [u32; 3]) -> VolumeFrame {
        let d = DVec3::from_array(dims.map(|n| n.max(1) as f64));
        let tex_to_voxel = DMat4::from_translation(DVec3::splat(-0.5)) * DMat4::from_scale(d);
        let to_world = DMat4::from_mat3(RAS_TO_WORLD) * self.voxel_to_ras * tex_to_voxel;
        let longest = (0..3)
            .map(|a| to_world.col(a).truncate().length())
            .fold(0.0, f64::max);
        let centre = to_world.transform_point3(DVec3::splat(0.5));
        let model = DMat4::from_scale(DVec3::splat(1.0 / longest))
            * DMat4::from_translation(-centre)
            * to_world;
        VolumeFrame::new(model.as_mat4(), dims)
    }

    /// The screen's right and up of `axis` as signed index axes, in the
    /// radiological convention (see the module documentation), and the index
    /// axis normal to the slice.
    pub fn slice_axes(&self, axis: SliceAxis) -> SliceAxes {
        let (normal, right, up) = match axis {
            SliceAxis::Axial => (Direction::Superior, Direction::Left, Direction::Anterior),
            SliceAxis::Coronal => (Direction::Anterior, Direction::Left, Direction::Superior),
            SliceAxis::Sagittal => (Direction::Right, Direction::Posterior, Direction::Superior),
        };
        SliceAxes {
            normal: self.index_axis(normal).0,
            right: self.index_axis(right),
            up: self.index_axis(up),
        }
    }

    /// The orthogonal slice along `axis` (its anatomical meaning) through
    /// `point` (index coordinates), fitted into a viewport of aspect `aspect`
    /// as [`SliceView::orthogonal`] fits it, oriented radiologically.
    pub fn slice(
        &self,
        axis: SliceAxis,
        point: [f64; 3],
        frame: &VolumeFrame,
        aspect: f64,
    ) -> Result<SliceView, SliceError> {
        let a = self.slice_axes(axis);
        SliceView::oriented(a.normal, point[a.normal], a.right, a.up, frame, aspect)
    }
}

/// A slice's screen axes as signed index axes ([`Orientation::slice_axes`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SliceAxes {
    /// The index axis normal to the slice.
    pub normal: usize,
    /// The screen's rightward direction: an index axis and its sign.
    pub right: (usize, f64),
    /// The screen's upward direction: an index axis and its sign.
    pub up: (usize, f64),
}

#[cfg(test)]
mod tests;
