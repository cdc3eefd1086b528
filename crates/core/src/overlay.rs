//! A label map drawn over the image it segments, in the same ray: the model
//! both backends and the CPU reference compute (`docs/labels.md`, "Labels
//! over the image").
//!
//! The two volumes may have different grids, resolutions and placements:
//! [`overlay_transform`] maps the image's texture coordinates to the label
//! map's, from where each lies in a common world (two files' placements, or
//! any two [`VolumeFrame`]s). At each DVR sample of the image the label under
//! the sample (the nearest voxel, or with smooth boundaries the heaviest of
//! the 8 around it; no label outside the map) is looked up in a
//! [`LabelTable`], and [`OverlayStyle`] says what it does to the image's
//! sample:
//!
//! * [`OverlayMode::Color`]: the label's colour over the image's TF colour,
//!   weighted by the label's opacity times the overlay's; the opacity is the
//!   image's. Labels colour what the image's TF shows (empty-space skipping
//!   and early termination stay exact); a label where the image is
//!   transparent is not drawn (draw the label map alone for that).
//! * [`OverlayMode::Mask`]: the image only inside the visible (or selected)
//!   labels: elsewhere its opacity is multiplied by `1 - opacity`.
//!
//! The overlay applies before shading (the label's colour is shaded by the
//! image's gradient, so tinted tissue keeps its shape). In iso and MIP, where
//! one sample decides a pixel, `Color` tints that sample's colour (the
//! surface's before shading, the maximum's after its mapping) by the label
//! under it ([`LabelOverlay::tint`]); `Mask` applies to DVR only.

use crate::camera::VolumeFrame;
use crate::labels::{LABEL_TABLE_ENTRIES, LabelTable, label_at, smooth_label_at};
use crate::volume::Volume;
use glam::DMat4;
use thiserror::Error;

/// What a label map does to the image's samples.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash)]
pub enum OverlayMode {
    /// The label's colour over the image's colour (its opacity unchanged).
    #[default]
    Color,
    /// The image inside the visible labels only.
    Mask,
}

/// How a label map is drawn over the image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OverlayStyle {
    /// What the labels do.
    pub mode: OverlayMode,
    /// `Color`: the weight of the label colours (times each label's
    /// opacity); `Mask`: how much of the image outside the labels is removed.
    /// 0..1.
    pub opacity: f32,
}

impl Default for OverlayStyle {
    /// Label colours at full weight (each label's own opacity).
    fn default() -> Self {
        OverlayStyle {
            mode: OverlayMode::Color,
            opacity: 1.0,
        }
    }
}

/// An overlay that cannot be drawn.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum OverlayError {
    /// The overlay is not a label map.
    #[error("an overlay must be a label map (this volume holds intensities)")]
    NotLabels,
    /// The image is a label map (an overlay colours an intensity image).
    #[error("the image under an overlay must hold intensities, not labels")]
    ImageIsLabels,
    /// The transform from the image to the labels is not finite or singular.
    #[error("the overlay's placement relative to the image is not finite or is singular")]
    BadTransform,
    /// The opacity is not within 0..1.
    #[error("overlay opacity {0} is not within 0..1")]
    BadOpacity(f32),
    /// A label id past the label table (renumber the map with
    /// `labels::relabel_dense`).
    #[error(
        "label id {id} is past the label table's {max} entries (renumber with labels::relabel_dense)"
    )]
    IdTooLarge {
        /// The largest id.
        id: u64,
        /// `LABEL_TABLE_ENTRIES`.
        max: usize,
    },
}

impl OverlayStyle {
    /// Checks the opacity.
    pub fn validate(&self) -> Result<(), OverlayError> {
        if (0.0..=1.0).contains(&self.opacity) {
            Ok(())
        } else {
            Err(OverlayError::BadOpacity(self.opacity))
        }
    }
}

/// The map from the image's texture coordinates to the label map's, for two
/// volumes placed in one world by `image` and `labels` (e.g. both from their
/// files' placements): `inverse(labels.model) * image.model`. It does not
/// change when both move together, so it is set once per pair.
pub fn overlay_transform(image: &VolumeFrame, labels: &VolumeFrame) -> DMat4 {
    labels.model.as_dmat4().inverse() * image.model.as_dmat4()
}

/// A label map over an image: the labels, where they lie relative to the
/// image, their table and the style.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LabelOverlay<'a> {
    /// The label map ([`crate::VolumeKind::Labels`]).
    pub labels: &'a Volume,
    /// Image texture coordinates to the label map's ([`overlay_transform`]).
    pub image_to_labels: DMat4,
    /// Colours, opacities, visibility and selection of the labels.
    pub table: &'a LabelTable,
    /// What the labels do to the image.
    pub style: OverlayStyle,
}

impl LabelOverlay<'_> {
    /// Checks that the overlay can be drawn over an image (a label map when
    /// `image_is_labels`): a label map, ids within the label table, a
    /// finite, invertible placement, an opacity within 0..1.
    pub fn validate(&self, image_is_labels: bool) -> Result<(), OverlayError> {
        if !self.labels.desc().kind.is_labels() {
            return Err(OverlayError::NotLabels);
        }
        if image_is_labels {
            return Err(OverlayError::ImageIsLabels);
        }
        let m = self.image_to_labels;
        if !m.is_finite() || m.determinant().abs() < 1e-12 {
            return Err(OverlayError::BadTransform);
        }
        if let Some((_, hi)) = self.labels.data().min_max()
            && hi as u64 >= LABEL_TABLE_ENTRIES as u64
        {
            return Err(OverlayError::IdTooLarge {
                id: hi as u64,
                max: LABEL_TABLE_ENTRIES,
            });
        }
        self.style.validate()
    }

    /// The label under image texture point `u` (nearest voxel, or with
    /// `smooth` the heaviest of the 8 around it), `None` outside the label
    /// map (ids are below [`LABEL_TABLE_ENTRIES`] in an overlay that
    /// validates; larger ones read as the last entry).
    pub fn label_at(&self, u: [f64; 3], smooth: bool) -> Option<u32> {
        let q = self
            .image_to_labels
            .transform_point3(glam::DVec3::from_array(u))
            .to_array();
        if q.iter().any(|&x| !(0.0..1.0).contains(&x)) {
            return None;
        }
        let id = if smooth {
            let d = self.labels.dims();
            smooth_label_at(self.labels, [0, 1, 2].map(|a| q[a] * d[a] as f64 - 0.5))
        } else {
            label_at(self.labels, q)
        };
        Some(id.min(LABEL_TABLE_ENTRIES as u32 - 1))
    }

    /// Iso and MIP: colour `rgb` at image texture point `u` tinted by the
    /// label there (`Color` mode; `Mask` leaves it).
    pub fn tint(&self, rgb: [f64; 3], u: [f64; 3], smooth: bool) -> [f64; 3] {
        if self.style.mode != OverlayMode::Color {
            return rgb;
        }
        let [r, g, b, _] = self.apply([rgb[0], rgb[1], rgb[2], 1.0], u, smooth);
        [r, g, b]
    }

    /// The image's sample `s` (straight RGB, opacity) at image texture point
    /// `u` with the labels applied ([`OverlayMode`]).
    pub fn apply(&self, s: [f64; 4], u: [f64; 3], smooth: bool) -> [f64; 4] {
        let l = self
            .label_at(u, smooth)
            .map_or([0.0; 4], |id| self.table.rgba(id).map(f64::from));
        apply_label(s, l, self.style)
    }
}

/// The image's sample `s` (straight RGB, opacity) with the label-table entry
/// `l` (straight RGB, opacity; all zero where no label lies) applied: what
/// the kernels' `overlay_apply` computes.
pub fn apply_label(s: [f64; 4], l: [f64; 4], style: OverlayStyle) -> [f64; 4] {
    let o = style.opacity as f64;
    match style.mode {
        OverlayMode::Color => {
            let w = l[3] * o;
            let mix = |a: f64, b: f64| a + (b - a) * w;
            [mix(s[0], l[0]), mix(s[1], l[1]), mix(s[2], l[2]), s[3]]
        }
        OverlayMode::Mask => {
            let keep = if l[3] > 0.0 { 1.0 } else { 1.0 - o };
            [s[0], s[1], s[2], s[3] * keep]
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::labels::label_volume;
    use crate::volume::VolumeData;
    use glam::{DVec3, Mat4};

    /// A 4x4x4 map: label 1 in x < 2, label 2 elsewhere.
    fn halves() -> Volume {
        let mut ids = vec![0u8; 64];
        for (i, v) in ids.iter_mut().enumerate() {
            *v = if i % 4 < 2 { 1 } else { 2 };
        }
        label_volume([4, 4, 4], [1.0; 3], VolumeData::U8(ids)).unwrap()
    }

    #[test]
    fn the_transform_maps_a_shared_world_point_to_both_volumes() {
        // Image: 0..2 mm; labels: 1..3 mm (a shifted, coarser map).
        let image = VolumeFrame::new(Mat4::from_scale(glam::Vec3::splat(2.0)), [8, 8, 8]);
        let labels = VolumeFrame::new(
            Mat4::from_translation(glam::Vec3::splat(1.0))
                * Mat4::from_scale(glam::Vec3::splat(2.0)),
            [4, 4, 4],
        );
        let m = overlay_transform(&image, &labels);
        // World 1.5 mm: image texture 0.75, label texture 0.25.
        let q = m.transform_point3(DVec3::splat(0.75));
        assert!((q - DVec3::splat(0.25)).abs().max_element() < 1e-6, "{q}");
    }

    #[test]
    fn color_mixes_by_label_opacity_and_keeps_the_image_opacity() {
        let style = OverlayStyle {
            mode: OverlayMode::Color,
            opacity: 0.5,
        };
        let s = apply_label([0.2, 0.4, 0.6, 0.3], [1.0, 0.0, 0.0, 0.8], style);
        let w = 0.4;
        let want = [0.2 + 0.8 * w, 0.4 * (1.0 - w), 0.6 * (1.0 - w), 0.3];
        for k in 0..4 {
            assert!((s[k] - want[k]).abs() < 1e-12, "{s:?} vs {want:?}");
        }
        // No label: the image unchanged.
        assert_eq!(
            apply_label([0.2, 0.4, 0.6, 0.3], [0.0; 4], style),
            [0.2, 0.4, 0.6, 0.3]
        );
    }

    #[test]
    fn mask_keeps_the_image_inside_visible_labels_only() {
        let style = OverlayStyle {
            mode: OverlayMode::Mask,
            opacity: 1.0,
        };
        let s = [0.5, 0.5, 0.5, 0.4];
        assert_eq!(apply_label(s, [1.0, 1.0, 1.0, 0.5], style), s);
        assert_eq!(apply_label(s, [1.0, 1.0, 1.0, 0.0], style)[3], 0.0);
        let half = OverlayStyle {
            opacity: 0.25,
            ..style
        };
        assert!((apply_label(s, [0.0; 4], half)[3] - 0.3).abs() < 1e-12);
    }

    #[test]
    fn labels_are_read_at_the_nearest_voxel_and_nothing_outside() {
        let v = halves();
        let table = LabelTable::default();
        let o = LabelOverlay {
            labels: &v,
            image_to_labels: DMat4::IDENTITY,
            table: &table,
            style: OverlayStyle::default(),
        };
        assert_eq!(o.label_at([0.1, 0.5, 0.5], false), Some(1));
        assert_eq!(o.label_at([0.9, 0.5, 0.5], false), Some(2));
        assert_eq!(o.label_at([0.49, 0.5, 0.5], true), Some(1));
        assert_eq!(o.label_at([1.0, 0.5, 0.5], false), None);
        assert_eq!(o.label_at([-0.01, 0.5, 0.5], false), None);
        // Outside the map: no label, the sample is the image's.
        let s = [0.3, 0.3, 0.3, 0.5];
        assert_eq!(o.apply(s, [1.5, 0.5, 0.5], false), s);
        assert!(o.validate(false).is_ok());
        assert_eq!(o.validate(true), Err(OverlayError::ImageIsLabels));
        let singular = LabelOverlay {
            image_to_labels: DMat4::ZERO,
            ..o
        };
        assert_eq!(singular.validate(false), Err(OverlayError::BadTransform));
        // Ids past the table: a typed error, not a silent clamp.
        let big = Volume::new(
            crate::VolumeDesc {
                dims: [2, 1, 1],
                dtype: crate::DType::U32,
                spacing: [1.0; 3],
                value_range: crate::labels::label_value_range(),
                kind: crate::VolumeKind::Labels,
            },
            VolumeData::U32(vec![1, 5000]),
        )
        .unwrap();
        let past = LabelOverlay { labels: &big, ..o };
        assert_eq!(
            past.validate(false),
            Err(OverlayError::IdTooLarge {
                id: 5000,
                max: LABEL_TABLE_ENTRIES
            })
        );
    }
}
