//! The CPU reference of slice views (docs/rendering-model.md, "Slice views"):
//! for each pixel centre, the slab's samples
//! ([`SliceGeometry::texture_point`]) that lie in the volume's texture box
//! (inclusive), each the exact trilinear value in f64, reduced by their
//! maximum or mean, mapped through the window and colour map, opaque; a pixel
//! with no sample in the box is transparent.

use crate::Image;
use brickray_core::channels::{self, ChannelStyle, ChannelVolume};
use brickray_core::{
    Intensity, LabelOverlay, SlabMode, SliceError, SliceView, TransferFunction, Volume,
    VolumeFrame, WindowError,
};
use rayon::prelude::*;

/// Why the reference cannot draw a slice.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum SliceReferenceError {
    /// The slice view.
    #[error(transparent)]
    Slice(#[from] SliceError),
    /// The window against the volume's value range.
    #[error(transparent)]
    Window(#[from] WindowError),
}

/// Renders `slice` of `vol` placed by `frame` into a `width x height` image
/// (premultiplied; depth stays at the far value, as the renderer writes none).
pub fn render_slice(
    vol: &Volume,
    frame: &VolumeFrame,
    slice: &SliceView,
    intensity: &Intensity,
    width: u32,
    height: u32,
) -> Result<Image, SliceReferenceError> {
    render_slice_with_overlay(vol, frame, slice, intensity, None, width, height)
}

/// [`render_slice`] with a label map over the image
/// (`brickray_core::overlay`): each pixel's colour, opaque, takes the label
/// under its slab's front sample ([`LabelOverlay::apply`], nearest; a mask
/// makes a pixel outside the visible labels `1 - opacity` opaque,
/// premultiplied).
pub fn render_slice_with_overlay(
    vol: &Volume,
    frame: &VolumeFrame,
    slice: &SliceView,
    intensity: &Intensity,
    overlay: Option<&LabelOverlay<'_>>,
    width: u32,
    height: u32,
) -> Result<Image, SliceReferenceError> {
    let range = vol.desc().value_range;
    // Checked once: every pixel maps through it.
    intensity.map(0.0, range)?;
    slab_pixels(vol, frame, slice, width, height, |samples, mode, front| {
        let v = match mode {
            SlabMode::Max => samples.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            SlabMode::Mean => samples.iter().sum::<f64>() / samples.len() as f64,
        };
        let [r, gr, b] = intensity.map(v, range).expect("checked above");
        let [r, gr, b, a] = match overlay {
            Some(o) => o.apply([r, gr, b, 1.0], front, false),
            None => [r, gr, b, 1.0],
        };
        Some([(r * a) as f32, (gr * a) as f32, (b * a) as f32, a as f32])
    })
}

/// Renders `slice` of the label map `vol` through its label table `tf`
/// (`LabelTable::to_transfer_function`): each pixel takes the slab's front
/// sample at the nearest voxel and draws its label's colour, opaque, or
/// nothing where the label is hidden (the renderer's `LABELS` slices).
pub fn render_label_slice(
    vol: &Volume,
    frame: &VolumeFrame,
    slice: &SliceView,
    tf: &TransferFunction,
    width: u32,
    height: u32,
) -> Result<Image, SliceReferenceError> {
    slab_pixels(vol, frame, slice, width, height, |samples, _, _| {
        let [r, g, b, a] = tf.lookup(samples[0]);
        (a > 0.0).then_some([r as f32, g as f32, b as f32, 1.0])
    })
}

/// Renders `slice` of the multi-channel `vol` with one style per channel
/// (`brickray_core::channels`): each visible channel's slab samples reduced
/// by their maximum or mean, classified by its TF (uncorrected), and the
/// channels added at full colour ([`channels::slice_color`]), opaque, with a
/// label map over them applied at the slab's front sample as
/// [`render_slice_with_overlay`] does; a pixel with no sample is
/// transparent.
///
/// # Panics
/// If the styles do not match the channels.
pub fn render_channel_slice(
    vol: &ChannelVolume,
    frame: &VolumeFrame,
    slice: &SliceView,
    styles: &[ChannelStyle],
    overlay: Option<&LabelOverlay<'_>>,
    width: u32,
    height: u32,
) -> Result<Image, SliceReferenceError> {
    channels::validate_styles(styles, vol.len())
        .unwrap_or_else(|e| panic!("the channel styles cannot be drawn: {e}"));
    let gains: Vec<f64> = styles.iter().map(|s| channels::slice_gain(&s.tf)).collect();
    let dims = vol.dims().map(f64::from);
    slab_points(frame, slice, width, height, |points, mode| {
        let mut parts = Vec::with_capacity(styles.len());
        for ((v, s), &gain) in vol.channels().iter().zip(styles).zip(&gains) {
            if !s.visible {
                continue;
            }
            let values = points
                .iter()
                .map(|t| v.sample_trilinear([0, 1, 2].map(|a| t[a] * dims[a] - 0.5)));
            let x = match mode {
                SlabMode::Max => values.fold(f64::NEG_INFINITY, f64::max),
                SlabMode::Mean => values.sum::<f64>() / points.len() as f64,
            };
            let [r, g, b, a] = s.tf.lookup(x);
            parts.push(([r, g, b], a, gain));
        }
        let [r, g, b] = channels::slice_color(&parts);
        let [r, g, b, a] = match overlay {
            Some(o) => o.apply([r, g, b, 1.0], points[0], false),
            None => [r, g, b, 1.0],
        };
        Some([(r * a) as f32, (g * a) as f32, (b * a) as f32, a as f32])
    })
}

/// Each pixel's slab samples that lie in the volume's texture box (front
/// first; exact trilinear values, or the nearest voxel's for a label map),
/// coloured by `color` (nothing: transparent), which also gets the front
/// sample's texture point.
fn slab_pixels(
    vol: &Volume,
    frame: &VolumeFrame,
    slice: &SliceView,
    width: u32,
    height: u32,
    color: impl Fn(&[f64], SlabMode, [f64; 3]) -> Option<[f32; 4]> + Sync,
) -> Result<Image, SliceReferenceError> {
    let labels = vol.desc().kind.is_labels();
    let dims = vol.dims().map(f64::from);
    slab_points(frame, slice, width, height, |points, mode| {
        let samples: Vec<f64> = points
            .iter()
            .map(|t| {
                let p = [0, 1, 2].map(|a| t[a] * dims[a] - 0.5);
                if labels {
                    vol.sample_nearest(p)
                } else {
                    vol.sample_trilinear(p)
                }
            })
            .collect();
        color(&samples, mode, points[0])
    })
}

/// Each pixel's slab points ([`SliceGeometry::texture_point`]) that lie in
/// the texture box (inclusive), front first, coloured by `color` (called
/// only with at least one point; nothing: transparent).
fn slab_points(
    frame: &VolumeFrame,
    slice: &SliceView,
    width: u32,
    height: u32,
    color: impl Fn(&[[f64; 3]], SlabMode) -> Option<[f32; 4]> + Sync,
) -> Result<Image, SliceReferenceError> {
    let mut img = Image::new(width, height);
    if width == 0 || height == 0 {
        return Ok(img);
    }
    let g = slice.resolve(frame, width as f64 / height as f64)?;
    let w = width as usize;
    img.color
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(py, row)| {
            let mut points = Vec::new();
            for (px, out) in row.iter_mut().enumerate() {
                points.clear();
                for k in 0..g.samples {
                    let t = g.texture_point(px as u32, py as u32, width, height, k);
                    if (0..3).all(|a| (0.0..=1.0).contains(&t[a])) {
                        points.push(t.to_array());
                    }
                }
                if !points.is_empty()
                    && let Some(c) = color(&points, g.mode)
                {
                    *out = c;
                }
            }
        });
    Ok(img)
}

#[cfg(test)]
mod tests {
    use super::*;
    use brickray_core::{ColorMap, DType, SliceAxis, VolumeData, VolumeDesc, Window};

    /// A linear ramp along z: an axial slice at index k is the constant
    /// k / (n - 1); a coronal slice is a vertical ramp.
    fn ramp(n: u32) -> Volume {
        let mut data = Vec::new();
        for z in 0..n {
            for _y in 0..n {
                for _x in 0..n {
                    data.push(z as f32);
                }
            }
        }
        Volume::new(
            VolumeDesc {
                dims: [n; 3],
                dtype: DType::F32,
                spacing: [1.0; 3],
                value_range: [0.0, (n - 1) as f32],
                kind: Default::default(),
            },
            VolumeData::F32(data),
        )
        .unwrap()
    }

    #[test]
    fn slices_of_a_ramp_are_exact() {
        let n = 16;
        let vol = ramp(n);
        let frame = VolumeFrame::centered([n; 3], [1.0; 3]);
        let grey = Intensity::new(Window::from_min_max(0.0, 15.0).unwrap(), ColorMap::Grey);
        let s = SliceView::orthogonal(SliceAxis::Axial, 6.0, &frame, 1.0).unwrap();
        let img = render_slice(&vol, &frame, &s, &grey, 32, 32).unwrap();
        for c in &img.color {
            assert!((c[0] as f64 - 6.0 / 15.0).abs() < 1e-6, "{c:?}");
            assert_eq!(c[3], 1.0);
        }
        // Coronal: up is +z, so row 0 is the top slice (z near 15).
        let s = SliceView::orthogonal(SliceAxis::Coronal, 3.0, &frame, 1.0).unwrap();
        let img = render_slice(&vol, &frame, &s, &grey, 32, 32).unwrap();
        let top = img.pixel(5, 0)[0];
        let bottom = img.pixel(5, 31)[0];
        assert!(top > 0.95 && bottom < 0.05, "{top} {bottom}");
        // A slab's mean of a linear ramp along its normal is the centre
        // value; its max the value at the last sample.
        let s = SliceView::orthogonal(SliceAxis::Axial, 7.0, &frame, 1.0).unwrap();
        let mean = render_slice(
            &vol,
            &frame,
            &s.with_slab(4.0 / 16.0, SlabMode::Mean),
            &grey,
            8,
            8,
        )
        .unwrap();
        assert!((mean.pixel(3, 3)[0] as f64 - 7.0 / 15.0).abs() < 1e-6);
        let max = render_slice(
            &vol,
            &frame,
            &s.with_slab(4.0 / 16.0, SlabMode::Max),
            &grey,
            8,
            8,
        )
        .unwrap();
        // 8 samples over 4 voxels: the last at 7 + 2 - 0.25.
        assert!(
            (max.pixel(3, 3)[0] as f64 - 8.75 / 15.0).abs() < 1e-6,
            "{:?}",
            max.pixel(3, 3)
        );
        // Outside the volume: transparent.
        let s = SliceView::orthogonal(SliceAxis::Axial, 40.0, &frame, 1.0).unwrap();
        let img = render_slice(&vol, &frame, &s, &grey, 8, 8).unwrap();
        assert!(img.color.iter().all(|c| c[3] == 0.0));
    }

    #[test]
    fn bad_input_is_a_typed_error() {
        let vol = ramp(4);
        let frame = VolumeFrame::centered([4; 3], [1.0; 3]);
        let grey = Intensity::grey([0.0, 3.0]).unwrap();
        let mut s = SliceView::orthogonal(SliceAxis::Axial, 1.0, &frame, 1.0).unwrap();
        s.up = [f64::NAN; 3];
        assert!(matches!(
            render_slice(&vol, &frame, &s, &grey, 4, 4),
            Err(SliceReferenceError::Slice(_))
        ));
    }

    /// One white channel through a window is the grey slice of that window
    /// (its slice gain undoes the opacity); a hidden channel adds nothing.
    #[test]
    fn a_white_channel_is_the_grey_slice() {
        let n = 16;
        let vol = ramp(n);
        let frame = VolumeFrame::centered([n; 3], [1.0; 3]);
        let grey = Intensity::new(Window::from_min_max(3.0, 12.0).unwrap(), ColorMap::Grey);
        let style = ChannelStyle::window([1.0; 3], [3.0 / 15.0, 12.0 / 15.0], 0.3);
        let two = ChannelVolume::new(vec![vol.clone(), vol.clone()]).unwrap();
        let styles = [style.clone(), style.visible(false)];
        let s = SliceView::orthogonal(SliceAxis::Coronal, 5.0, &frame, 1.0).unwrap();
        let a = render_slice(&vol, &frame, &s, &grey, 24, 24).unwrap();
        let b = render_channel_slice(&two, &frame, &s, &styles, None, 24, 24).unwrap();
        for (x, y) in a.color.iter().zip(&b.color) {
            for k in 0..4 {
                assert!((x[k] - y[k]).abs() < 2e-3, "{x:?} {y:?}");
            }
        }
    }
}
