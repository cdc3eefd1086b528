//! The multi-channel reference: each channel marched by its own
//! [`Marcher`] (its volume and transfer function) along the same rays, the
//! channels composited as `brickray_core::channels` specifies.

use super::{Image, Marcher, Peaks, RayResult, Span, StepGrid};
use brickray_core::channels::{self, ChannelStyle, ChannelVolume};
use brickray_core::tf::corrected_alpha;
use brickray_core::{Camera, LabelOverlay, Ray, RenderMode, RenderSettings, VolumeFrame};

use super::ReferenceOptions;

/// The multi-channel analogue of [`super::render_reference`]: `vol`'s
/// channels, each classified by its style (`styles[c]`: transfer function,
/// visibility, isovalue), composited in one ray as the GPU's multi-channel
/// kernel does ([`brickray_core::channels`]): DVR mixes the visible
/// channels' samples (each corrected to the step and, shaded, by its own
/// gradient) and composites the mixture front to back; MIP classifies each
/// visible channel's maximum (uncorrected) and mixes them, at the depth of
/// the nearest maximum; iso takes the first sample where a visible channel
/// reaches its isovalue (the lowest such channel), bisects on that channel,
/// and shades that channel's isosurface colour by its gradient.
/// `settings.mode`'s isovalue and colour are not used (each channel has its
/// own). With [`ReferenceOptions::adaptive_step`] DVR's step doubles with
/// the mixture's transmittance, as one channel's does.
///
/// A label map over the channels (`opts.overlay`) applies to each channel's
/// sample before shading (DVR), tints iso colours at the hit and each
/// channel's MIP colour at its maximum (colour mode).
///
/// # Panics
/// As [`super::render_reference`], and if the styles do not match the
/// channels or `opts` asks for what channels are not drawn with
/// (pre-integration, a spread or an intensity window).
pub fn render_channels_reference(
    vol: &ChannelVolume,
    frame: &VolumeFrame,
    styles: &[ChannelStyle],
    camera: &Camera,
    settings: &RenderSettings,
    opts: &ReferenceOptions<'_>,
) -> Image {
    channels::validate_styles(styles, vol.len())
        .unwrap_or_else(|e| panic!("the channel styles cannot be drawn: {e}"));
    super::check_mode(settings);
    assert!(
        !opts.preintegrated && opts.spread.is_none() && opts.intensity.is_none(),
        "pre-integration, spreads and intensity windows are not drawn with channels"
    );
    if let Some(o) = opts.overlay {
        o.validate(false)
            .unwrap_or_else(|e| panic!("the overlay cannot be drawn: {e}"));
    }
    let (width, height) = (opts.width, opts.height);
    let mut img = Image::new(width, height);
    if width == 0 || height == 0 {
        return img;
    }
    let step_factor = super::checked_step(frame, opts);
    let marchers: Vec<Marcher<'_>> = vol
        .channels()
        .iter()
        .zip(styles)
        .map(|(v, s)| {
            let mut m = Marcher::new(
                v,
                frame,
                &s.tf,
                camera,
                settings,
                step_factor,
                width,
                height,
            );
            m.mip_refine = opts.mip_refine;
            m
        })
        .collect();
    let m = ChannelMarcher {
        marchers,
        styles,
        settings,
        step_factor,
        overlay: opts.overlay,
        adaptive_step: opts.adaptive_step,
    };
    super::fill_pixels(&mut img, camera, opts, |px, py, n, host| {
        m.marchers[0].pixel_with(px, py, n, host, |x, y, h| m.trace(x, y, h))
    });
    img
}

/// One marcher per channel and the channels' styles.
struct ChannelMarcher<'a> {
    marchers: Vec<Marcher<'a>>,
    styles: &'a [ChannelStyle],
    settings: &'a RenderSettings,
    step_factor: f64,
    /// A label map over the channels.
    overlay: Option<&'a LabelOverlay<'a>>,
    /// DVR's adaptive step ([`ReferenceOptions::adaptive_step`]).
    adaptive_step: bool,
}

impl ChannelMarcher<'_> {
    /// The image texture point of the ray at `t`.
    fn point(&self, ray: &Ray, t: f64) -> [f64; 3] {
        (ray.tex_origin + ray.tex_dir * t).to_array()
    }

    fn smooth(&self) -> bool {
        self.settings.smooth_labels
    }

    /// Iso and MIP colours tinted by the overlay's label at `t` (colour
    /// mode).
    fn tint(&self, ray: &Ray, t: f64, rgb: [f64; 3]) -> [f64; 3] {
        match self.overlay {
            Some(o) => o.tint(rgb, self.point(ray, t), self.smooth()),
            None => rgb,
        }
    }

    /// The visible channels' marchers, with their indices.
    fn visible(&self) -> impl Iterator<Item = (usize, &Marcher<'_>)> {
        self.marchers
            .iter()
            .enumerate()
            .filter(|(c, _)| self.styles[*c].visible)
    }

    fn trace(&self, px: f64, py: f64, host_depth: Option<f32>) -> RayResult {
        let Some((ray, span)) = self.marchers[0].ray_span(px, py, host_depth) else {
            return ([0.0; 4], None);
        };
        match self.settings.mode {
            RenderMode::Iso { .. } => self.iso(&ray, span),
            RenderMode::Mip => self.mip(&ray, span),
            _ => self.dvr(&ray, span),
        }
    }

    fn dvr(&self, ray: &Ray, span: Span) -> RayResult {
        let shading = &self.settings.shading;
        let depth_opacity = self.settings.depth_opacity as f64;
        let mut c_acc = [0.0f64; 3];
        let mut a_acc = 0.0f64;
        let mut depth = None;
        let mut parts = Vec::with_capacity(self.marchers.len());
        // The step doubles with the mixture's opacity, as one channel's.
        let mut grid = StepGrid::new(span, self.adaptive_step);
        while let Some((t, m)) = grid.next(a_acc) {
            let m_step = self.step_factor * m;
            parts.clear();
            for (_, m) in self.visible() {
                let [r, g, b, a] = m.tf.lookup(m.value(ray, t));
                let a = corrected_alpha(a, m_step);
                // The overlay before shading, as for one channel.
                let [r, g, b, a] = match self.overlay {
                    Some(o) => o.apply([r, g, b, a], self.point(ray, t), self.smooth()),
                    None => [r, g, b, a],
                };
                if a <= 0.0 {
                    continue;
                }
                let c = if shading.enabled {
                    m.shade(ray, t, [r, g, b], shading)
                } else {
                    [r, g, b]
                };
                parts.push((c, a));
            }
            let [r, g, b, a] = channels::mix(&parts);
            if a <= 0.0 {
                continue;
            }
            let w = 1.0 - a_acc;
            for (k, p) in [r, g, b].into_iter().enumerate() {
                c_acc[k] += w * p;
            }
            a_acc += w * a;
            if depth.is_none() && a_acc >= depth_opacity {
                depth = Some(self.marchers[0].clip_depth(ray, t));
            }
        }
        ([c_acc[0], c_acc[1], c_acc[2], a_acc], depth)
    }

    /// The first visible channel at or above its isovalue at `t`.
    fn inside(&self, ray: &Ray, t: f64) -> Option<usize> {
        self.visible()
            .find(|(c, m)| m.value(ray, t) >= self.styles[*c].isovalue as f64)
            .map(|(c, _)| c)
    }

    fn iso(&self, ray: &Ray, span: Span) -> RayResult {
        let mut prev = None;
        for t in span.samples() {
            let Some(c) = self.inside(ray, t) else {
                prev = Some(t);
                continue;
            };
            let m = &self.marchers[c];
            let iso = self.styles[c].isovalue as f64;
            let th = match prev {
                None => t,
                Some(t_prev) => {
                    let (mut a, mut b) = (t_prev, t);
                    for _ in 0..self.settings.iso_refine_steps {
                        let mid = 0.5 * (a + b);
                        if m.value(ray, mid) >= iso {
                            b = mid;
                        } else {
                            a = mid;
                        }
                    }
                    0.5 * (a + b)
                }
            };
            let color = self.tint(ray, th, self.styles[c].iso_color().map(f64::from));
            let [r, g, b] = m.shade(ray, th, color, &self.settings.shading);
            return ([r, g, b, 1.0], Some(m.clip_depth(ray, th)));
        }
        ([0.0; 4], None)
    }

    /// Each visible channel's maximum, refined between samples as the
    /// single-channel MIP's (`Peaks`, per channel), classified and mixed.
    fn mip(&self, ray: &Ray, span: Span) -> RayResult {
        let mut peaks = vec![Peaks::default(); self.marchers.len()];
        for t in span.samples() {
            for (c, m) in self.visible() {
                peaks[c].take(m.value(ray, t), t, span.dt);
            }
        }
        let mut parts = Vec::new();
        let mut t_near: Option<f64> = None;
        for (c, m) in self.visible() {
            if let Some((v, t)) = peaks[c].maximum(m.mip_refine, span, |t| m.value(ray, t)) {
                let [r, g, b, a] = m.tf.lookup(v);
                parts.push((self.tint(ray, t, [r, g, b]), a));
                t_near = Some(t_near.map_or(t, |n| n.min(t)));
            }
        }
        match t_near {
            None => ([0.0; 4], None),
            Some(t) => (
                channels::mix(&parts),
                Some(self.marchers[0].clip_depth(ray, t)),
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render_reference;
    use brickray_core::synthetic;
    use brickray_core::{Shading, TransferFunction};
    use glam::Vec3;

    fn modes() -> [RenderMode; 3] {
        [
            RenderMode::Dvr,
            RenderMode::Iso {
                value: 0.4,
                color: [0.9, 0.6, 0.2],
            },
            RenderMode::Mip,
        ]
    }

    fn max_diff(a: &Image, b: &Image) -> f32 {
        a.color
            .iter()
            .zip(&b.color)
            .flat_map(|(x, y)| (0..4).map(move |k| (x[k] - y[k]).abs()))
            .fold(0.0, f32::max)
    }

    /// One channel is the single-channel image of that channel, in every
    /// mode, shaded and not (the iso colour is the TF's at the isovalue; MIP
    /// refined between samples in both).
    #[test]
    fn one_channel_is_the_single_channel_image() {
        let vol = synthetic::marschner_lobb(24);
        let frame = VolumeFrame::centered(vol.dims(), [1.0; 3]);
        let cam = Camera::orbit(Vec3::ZERO, 2.6, 0.5, 0.3);
        let tf = TransferFunction::from_points(
            &[(0.3, [0.9, 0.6, 0.2, 0.0]), (0.7, [0.9, 0.6, 0.2, 0.6])],
            256,
        );
        let one = ChannelVolume::new(vec![vol.clone()]).unwrap();
        let style = ChannelStyle::new(tf.clone()).with_isovalue(0.4);
        let opts = ReferenceOptions::new(40, 32).with_step_factor(0.5);
        for mode in modes() {
            for shaded in [false, true] {
                let settings = RenderSettings {
                    mode,
                    shading: Shading {
                        enabled: shaded,
                        ..Default::default()
                    },
                    ..Default::default()
                };
                let a = render_reference(&vol, &frame, &tf, &cam, &settings, &opts);
                let b = render_channels_reference(
                    &one,
                    &frame,
                    std::slice::from_ref(&style),
                    &cam,
                    &settings,
                    &opts,
                );
                let d = max_diff(&a, &b);
                assert!(d < 1e-6, "{mode:?} shaded {shaded}: {d}");
                assert!(a.color.iter().any(|c| c[3] > 0.1), "{mode:?}: empty image");
                assert_eq!(a.depth, b.depth, "{mode:?} shaded {shaded}");
            }
        }
    }

    /// A hidden channel gives the image of the others; two channels differ
    /// from either alone.
    #[test]
    fn a_hidden_channel_is_absent() {
        let a = synthetic::marschner_lobb(20);
        // The same field mirrored (reversed voxel order).
        let n = a.desc().voxel_count() as usize;
        let mirrored: Vec<f32> = (0..n).rev().map(|i| a.data().get(i)).collect();
        let b =
            brickray_core::Volume::new(a.desc().clone(), brickray_core::VolumeData::F32(mirrored))
                .unwrap();
        let frame = VolumeFrame::centered(a.dims(), [1.0; 3]);
        let cam = Camera::orbit(Vec3::ZERO, 2.6, 0.2, 0.4);
        let sa = ChannelStyle::window([0.0, 1.0, 0.0], [0.3, 0.8], 0.5);
        let sb = ChannelStyle::window([1.0, 0.0, 1.0], [0.2, 0.9], 0.5);
        let two = ChannelVolume::new(vec![a.clone(), b]).unwrap();
        let one = ChannelVolume::new(vec![a]).unwrap();
        let opts = ReferenceOptions::new(32, 32).with_step_factor(0.5);
        for mode in modes() {
            let settings = RenderSettings {
                mode,
                ..Default::default()
            };
            let hidden = render_channels_reference(
                &two,
                &frame,
                &[sa.clone(), sb.clone().visible(false)],
                &cam,
                &settings,
                &opts,
            );
            let alone = render_channels_reference(
                &one,
                &frame,
                std::slice::from_ref(&sa),
                &cam,
                &settings,
                &opts,
            );
            assert_eq!(hidden.color, alone.color, "{mode:?}");
            let both = render_channels_reference(
                &two,
                &frame,
                &[sa.clone(), sb.clone()],
                &cam,
                &settings,
                &opts,
            );
            assert!(max_diff(&both, &alone) > 0.05, "{mode:?}");
        }
    }
}
