//! The brute-force ray marcher.

use brickray_core::moments::field_trilinear;
use brickray_core::tf::{
    Preintegrator, SEGMENT_PIECES, SPREAD_ROWS, SpreadTable, corrected_alpha, join_pieces,
    segment_values,
};
use brickray_core::{
    Camera, Intensity, LabelOverlay, Ray, RayGen, RenderMode, RenderSettings, Shading,
    TransferFunction, Volume, VolumeFrame,
};
use glam::{DMat3, DMat4, DVec3};
use rayon::prelude::*;

use crate::Image;

mod options;
mod span;
pub use options::{DEFAULT_STEP_FACTOR, EXACT_STEP_FACTOR, ReferenceOptions};
use span::{Peaks, Span, StepGrid};

/// Fine value cells of the reference's segment integrals (16 per column of a
/// 256-column table).
const PREINT_CELLS: u32 = 4096;

/// Most columns of the reference's spread table (the GPU's default limit).
const SPREAD_TABLE_WIDTH: u32 = 8192;

/// Gradients shorter than this (normalized-value units per voxel) leave a sample
/// unshaded.
const MIN_GRADIENT: f64 = 1e-6;

/// Renders the model of `docs/rendering-model.md` on the CPU, brute force, in f64.
///
/// `settings.step_factor` and `settings.accel` are ignored: the step is
/// `opts.step_factor` (with the opacity corrected to it) and every sample is taken
/// (no empty-space skipping, no early ray termination). Rows are rendered in
/// parallel (rayon).
///
/// # Panics
/// If `opts.step_factor` is not finite and positive, if `frame.voxel_world` is not
/// finite and positive, if `opts.host_depth` is not `width * height` long, if
/// `opts.spread` does not hold one value per voxel of `vol`, if `opts.overlay`
/// cannot be drawn over `vol` ([`LabelOverlay::validate`]), or if
/// `settings.mode` is a mode this reference does not define (a variant added to
/// the non-exhaustive [`RenderMode`] after DVR, Iso and MIP): the oracle refuses
/// rather than guessing.
pub fn render_reference(
    vol: &Volume,
    frame: &VolumeFrame,
    tf: &TransferFunction,
    camera: &Camera,
    settings: &RenderSettings,
    opts: &ReferenceOptions<'_>,
) -> Image {
    check_mode(settings);
    let (width, height) = (opts.width, opts.height);
    let mut img = Image::new(width, height);
    if width == 0 || height == 0 {
        return img;
    }
    let step_factor = checked_step(frame, opts);

    if let Some(s) = opts.spread {
        assert_eq!(
            s.len() as u64,
            vol.desc().voxel_count(),
            "spread must hold one value per voxel"
        );
    }

    // A label map: nearest samples through the label table, without
    // pre-integration, shaded only with smooth boundaries (the GPU kernels'
    // rule, `Variant::of`).
    let labels = vol.desc().kind.is_labels();
    let unshaded;
    let settings = if labels && !settings.smooth_labels {
        let mut s = *settings;
        s.shading.enabled = false;
        unshaded = s;
        &unshaded
    } else {
        settings
    };
    if let Some(o) = opts.overlay {
        o.validate(labels)
            .unwrap_or_else(|e| panic!("the overlay cannot be drawn: {e}"));
    }
    let mut marcher = Marcher::new(vol, frame, tf, camera, settings, step_factor, width, height);
    marcher.labels = labels;
    marcher.overlay = opts.overlay;
    marcher.intensity = opts.intensity;
    marcher.ert = opts.early_termination.map(f64::from);
    marcher.mip_refine = opts.mip_refine;
    marcher.adaptive_step = opts.adaptive_step;
    if let Some(s) = opts.spread {
        marcher.spread = Some((s, tf.spread_table(SPREAD_ROWS, SPREAD_TABLE_WIDTH)));
    }
    if opts.preintegrated && !labels {
        marcher.preint = Some(Preintegrator::new(tf, PREINT_CELLS));
    }
    fill_pixels(&mut img, camera, opts, |px, py, n, host| {
        marcher.pixel(px, py, n, host)
    });
    img
}

/// Panics unless `settings.mode` is a mode the reference defines (DVR, Iso,
/// MIP: a variant added to the non-exhaustive `RenderMode` later is refused
/// rather than guessed).
fn check_mode(settings: &RenderSettings) {
    assert!(
        matches!(
            settings.mode,
            RenderMode::Dvr | RenderMode::Iso { .. } | RenderMode::Mip
        ),
        "the reference renderer does not implement {:?}",
        settings.mode
    );
}

/// The step factor of `opts`, after checking it and the frame's voxel size
/// (finite, positive) and the host depth's length (panics otherwise).
fn checked_step(frame: &VolumeFrame, opts: &ReferenceOptions<'_>) -> f64 {
    let step_factor = opts.step_factor as f64;
    assert!(
        step_factor.is_finite() && step_factor > 0.0,
        "step_factor must be finite and > 0, got {step_factor}"
    );
    let voxel_world = frame.voxel_world as f64;
    assert!(
        voxel_world.is_finite() && voxel_world > 0.0,
        "frame.voxel_world must be finite and > 0, got {voxel_world}"
    );
    if let Some(d) = opts.host_depth {
        assert_eq!(
            d.len(),
            opts.width as usize * opts.height as usize,
            "host_depth must hold width * height values"
        );
    }
    step_factor
}

/// Fills `img` (cleared to the far depth first) in parallel rows with
/// `pixel(px, py, supersample, host depth)` of every pixel.
fn fill_pixels(
    img: &mut Image,
    camera: &Camera,
    opts: &ReferenceOptions<'_>,
    pixel: impl Fn(f64, f64, u32, Option<f32>) -> RayResult + Sync,
) {
    let n = opts.supersample.max(1);
    let far = camera.depth.far_value();
    img.depth.fill(far);
    let w = img.width as usize;
    img.color
        .par_chunks_mut(w)
        .zip(img.depth.par_chunks_mut(w))
        .enumerate()
        .for_each(|(py, (colors, depths))| {
            for (px, (color, depth)) in colors.iter_mut().zip(depths.iter_mut()).enumerate() {
                let host = opts.host_depth.map(|d| d[py * w + px]);
                let (c, z) = pixel(px as f64, py as f64, n, host);
                *color = c.map(|x| x as f32);
                *depth = z.map_or(far, |z| z as f32);
            }
        });
}

/// The per-frame constants of a render.
struct Marcher<'a> {
    vol: &'a Volume,
    tf: &'a TransferFunction,
    settings: &'a RenderSettings,
    dims: DVec3,
    rays: RayGen,
    inv_model: DMat4,
    /// Inverse transpose of the model's 3x3 (texture-space gradients to world).
    normal_matrix: DMat3,
    step_factor: f64,
    dt: f64,
    width: u32,
    height: u32,
    /// Pre-integrated DVR ([`ReferenceOptions::preintegrated`]).
    preint: Option<Preintegrator<'a>>,
    /// MIP's window and colour map ([`ReferenceOptions::intensity`]).
    intensity: Option<Intensity>,
    /// Spread per voxel and the TF's spread table ([`ReferenceOptions::spread`]).
    spread: Option<(&'a [f32], SpreadTable)>,
    /// A label map: values are read at the nearest voxel.
    labels: bool,
    /// A label map over the image ([`ReferenceOptions::overlay`]).
    overlay: Option<&'a LabelOverlay<'a>>,
    /// DVR's termination threshold ([`ReferenceOptions::early_termination`]).
    ert: Option<f64>,
    /// MIP refines its maximum ([`ReferenceOptions::mip_refine`]).
    mip_refine: bool,
    /// DVR's adaptive step ([`ReferenceOptions::adaptive_step`]).
    adaptive_step: bool,
}

/// The opacity of `n` pieces of opacity `a` each, `1 - (1 - a)^n` (0 when
/// `n <= 0`): the share of a stopped ray's residual its fill takes (the
/// kernels' `ert_fill`).
fn ert_fill(a: f64, n: f64) -> f64 {
    1.0 - (1.0 - a).max(1e-30).powf(n.max(0.0))
}

/// The result of one ray: premultiplied RGBA and clip depth.
type RayResult = ([f64; 4], Option<f64>);

/// A DVR ray's running sum: premultiplied colour, opacity and the depth where
/// the opacity first reached the settings' depth opacity; with termination,
/// the length of ray whose pieces composited colour and whether it stopped.
#[derive(Default)]
struct Composite {
    c: [f64; 3],
    a: f64,
    depth: Option<f64>,
    seen: f64,
    stopped: bool,
}

impl Composite {
    fn result(&self) -> RayResult {
        ([self.c[0], self.c[1], self.c[2], self.a], self.depth)
    }
}

impl<'a> Marcher<'a> {
    /// The constants of a `width x height` render at `step_factor`.
    #[allow(clippy::too_many_arguments)]
    fn new(
        vol: &'a Volume,
        frame: &VolumeFrame,
        tf: &'a TransferFunction,
        camera: &Camera,
        settings: &'a RenderSettings,
        step_factor: f64,
        width: u32,
        height: u32,
    ) -> Marcher<'a> {
        let model = frame.model.as_dmat4();
        Marcher {
            vol,
            tf,
            settings,
            dims: DVec3::from_array(vol.dims().map(f64::from)),
            rays: camera.rays(width as f64 / height as f64),
            inv_model: model.inverse(),
            normal_matrix: DMat3::from_mat4(model).inverse().transpose(),
            step_factor,
            dt: step_factor * frame.voxel_world as f64,
            width,
            height,
            preint: None,
            intensity: None,
            spread: None,
            labels: false,
            overlay: None,
            ert: None,
            mip_refine: true,
            adaptive_step: false,
        }
    }
}

impl Marcher<'_> {
    /// The nearer of two clip depths in the camera's convention.
    fn nearer(&self, a: f64, b: f64) -> f64 {
        match self.rays.depth.convention {
            brickray_core::DepthConvention::ReversedZ => a.max(b),
            _ => a.min(b),
        }
    }

    /// One pixel: `n x n` stratified rays, colours averaged, nearest depth kept.
    fn pixel(&self, px: f64, py: f64, n: u32, host_depth: Option<f32>) -> RayResult {
        self.pixel_with(px, py, n, host_depth, |x, y, h| self.trace(x, y, h))
    }

    /// [`Self::pixel`] with each ray traced by `trace` (the multi-channel
    /// marcher's).
    fn pixel_with(
        &self,
        px: f64,
        py: f64,
        n: u32,
        host_depth: Option<f32>,
        trace: impl Fn(f64, f64, Option<f32>) -> RayResult,
    ) -> RayResult {
        if n == 1 {
            return trace(px, py, host_depth);
        }
        let mut sum = [0.0f64; 4];
        let mut depth: Option<f64> = None;
        let inv = 1.0 / n as f64;
        for j in 0..n {
            for i in 0..n {
                // `through_pixel` adds 0.5: sub-pixel centre (i + 0.5) / n.
                let (c, z) = trace(
                    px + (i as f64 + 0.5) * inv - 0.5,
                    py + (j as f64 + 0.5) * inv - 0.5,
                    host_depth,
                );
                for k in 0..4 {
                    sum[k] += c[k];
                }
                if let Some(z) = z {
                    depth = Some(depth.map_or(z, |d| self.nearer(d, z)));
                }
            }
        }
        let count = (n * n) as f64;
        (sum.map(|s| s / count), depth)
    }

    /// The ray through image position `(px + 0.5, py + 0.5)` and its
    /// samples' span (clipped to the clip box and the host's depth), or
    /// `None` when it misses the clip box.
    fn ray_span(&self, px: f64, py: f64, host_depth: Option<f32>) -> Option<(Ray, Span)> {
        let ray = self
            .rays
            .pixel_ray(&self.inv_model, px, py, self.width, self.height);
        let clip = self.settings.clip;
        let (t0, mut t1) = ray.clip_box(clip.min.map(f64::from), clip.max.map(f64::from))?;
        if let Some(d) = host_depth.filter(|d| !d.is_nan()) {
            t1 = t1.min(self.rays.t_at_depth(&ray, d as f64));
        }
        let span = Span {
            t0,
            t1,
            dt: self.dt,
        };
        Some((ray, span))
    }

    /// One ray through image position `(px + 0.5, py + 0.5)`.
    fn trace(&self, px: f64, py: f64, host_depth: Option<f32>) -> RayResult {
        let Some((ray, span)) = self.ray_span(px, py, host_depth) else {
            return ([0.0; 4], None);
        };
        match self.settings.mode {
            RenderMode::Iso { value, color } => {
                self.iso(&ray, span, value as f64, color.map(f64::from))
            }
            RenderMode::Mip => self.mip(&ray, span),
            RenderMode::Dvr => self.dvr(&ray, span),
            other => unreachable!("mode {other:?} was rejected by render_reference"),
        }
    }

    /// Front-to-back emission-absorption.
    fn dvr(&self, ray: &Ray, span: Span) -> RayResult {
        let mut out = Composite::default();
        if let Some(p) = &self.preint {
            self.dvr_segments(ray, span, p, &mut out);
            return out.result();
        }
        let mut grid = StepGrid::new(span, self.adaptive_step);
        while let Some((t, m)) = grid.next(out.a) {
            let v = self.value(ray, t);
            let [r, g, b, a] = match &self.spread {
                Some((sigma, table)) => {
                    let p = self.voxel_pos(ray, t).to_array();
                    let s = field_trilinear(sigma, self.vol.dims(), p);
                    table.lookup(self.tf, v, s)
                }
                None => self.tf.lookup(v),
            };
            let a = corrected_alpha(a, self.step_factor * m);
            // A plain sample stands for the step after it.
            let piece = [self.dt * m, span.t1 - t - self.dt * m];
            self.composite(&mut out, ray, [r, g, b, a], t, t, piece);
            if out.stopped {
                break;
            }
        }
        out.result()
    }

    /// Pre-integrated DVR: the segment between each two samples, in pieces
    /// along the parabola through them and the sample before
    /// ([`segment_values`], [`join_pieces`]), then the ray's last piece. The
    /// ray's first sample only records the front of the next segment (the
    /// segment ending there would start a step before the ray does). A segment `[t - dt, t]` is shaded at its midpoint: at its
    /// back sample the shading would lag the emission by half a step. The last
    /// piece, from the last sample to the ray's end (less than a step), is
    /// taken as constant at the last sample's value and shaded there: the
    /// kernels sample nothing past their last sample. Without it a ray that
    /// leaves the volume in material would lose up to a step of it (a plain
    /// sample stands for the step after it, so the plain sum does not).
    fn dvr_segments(&self, ray: &Ray, span: Span, p: &Preintegrator<'_>, out: &mut Composite) {
        // The segment's associated colour, made straight again (shading
        // applies to the straight colour; compositing multiplies back).
        let straight = |[r, g, b, a]: [f64; 4]| {
            let s = if a > 0.0 { 1.0 / a } else { 0.0 };
            [r * s, g * s, b * s, a]
        };
        let mut prev: Option<(f64, f64)> = None;
        // The sample before `prev` (the parabola's third point).
        let mut before: Option<f64> = None;
        for t in span.samples() {
            let v = self.value(ray, t);
            if let Some((_, front)) = prev.replace((t, v)) {
                let x = segment_values(before, front, v);
                let whole: [[f64; 4]; SEGMENT_PIECES] =
                    std::array::from_fn(|j| p.segment(x[j], x[j + 1], self.step_factor));
                if self.settings.shading.enabled {
                    // Piece by piece, each lit at its middle with the
                    // gradient interpolated between the segment's two
                    // samples (the kernels' `preint_shaded`).
                    // (Read once, where a piece is drawn.)
                    let g = std::cell::OnceCell::new();
                    let len = self.dt / SEGMENT_PIECES as f64;
                    for (j, w) in whole.iter().enumerate() {
                        if out.stopped {
                            break;
                        }
                        let f = (j as f64 + 0.5) / SEGMENT_PIECES as f64;
                        let rest = span.t1 - t + (SEGMENT_PIECES - 1 - j) as f64 * len;
                        let piece =
                            join_pieces(std::array::from_fn(
                                |i| {
                                    if i == 0 { *w } else { [0.0; 4] }
                                },
                            ));
                        self.composite_lit(out, ray, straight(piece), t, [len, rest], || {
                            let [g0, g1] = *g.get_or_init(|| {
                                [self.gradient(ray, t - self.dt), self.gradient(ray, t)]
                            });
                            self.normal_of(g0 * (1.0 - f) + g1 * f)
                        });
                    }
                } else {
                    let piece = [self.dt, span.t1 - t];
                    self.composite(out, ray, straight(join_pieces(whole)), t, t, piece);
                }
                before = Some(front);
                if out.stopped {
                    return;
                }
            }
        }
        if let Some((t, v)) = prev.filter(|&(t, _)| span.t1 > t) {
            let d = self.step_factor * (span.t1 - t) / self.dt;
            let piece = [span.t1 - t, 0.0];
            self.composite(out, ray, straight(p.segment(v, v, d)), t, t, piece);
        }
    }

    /// Composites the straight colour and opacity `rgba` of the sample at `t`
    /// (the label overlay and the depth are taken there), shaded at `ts`;
    /// `piece`: the length of ray it stands for and the ray's length after
    /// it (for termination's fill).
    fn composite(
        &self,
        out: &mut Composite,
        ray: &Ray,
        rgba: [f64; 4],
        t: f64,
        ts: f64,
        piece: [f64; 2],
    ) {
        self.composite_lit(out, ray, rgba, t, piece, || self.normal(ray, ts));
    }

    /// [`composite`](Self::composite) lit with the normal `n` gives (unlit
    /// where `None`, as a vanishing gradient leaves a sample), asked only
    /// when the sample shows and is shaded.
    fn composite_lit(
        &self,
        out: &mut Composite,
        ray: &Ray,
        rgba: [f64; 4],
        t: f64,
        piece: [f64; 2],
        n: impl FnOnce() -> Option<DVec3>,
    ) {
        let [r, g, b, a] = match self.overlay {
            Some(o) => {
                let u = (ray.tex_origin + ray.tex_dir * t).to_array();
                o.apply(rgba, u, self.settings.smooth_labels)
            }
            None => rgba,
        };
        if a <= 0.0 {
            // Contributes nothing (and cannot change A or the depth).
            return;
        }
        let shading = &self.settings.shading;
        let c = if shading.enabled {
            lit(n(), ray, [r, g, b], shading)
        } else {
            [r, g, b]
        };
        let w = (1.0 - out.a) * a;
        for (acc, x) in out.c.iter_mut().zip(c) {
            *acc += w * x;
        }
        out.a += w;
        if let Some(threshold) = self.ert {
            out.seen += piece[0];
            if out.a >= threshold {
                // The residual, as far as the ray's mean extinction so far
                // would fill it over the rest of the ray (the kernels'
                // `accumulate` and `ert_fill`).
                let fill = (1.0 - out.a) * ert_fill(out.a, piece[1] / out.seen.max(1e-30));
                for (acc, x) in out.c.iter_mut().zip(c) {
                    *acc += fill * x;
                }
                out.a += fill;
                out.stopped = true;
            }
        }
        if out.depth.is_none() && (out.a >= self.settings.depth_opacity as f64 || out.stopped) {
            out.depth = Some(self.clip_depth(ray, t));
        }
    }

    /// First crossing of `iso`, bisection-refined, shaded, opaque.
    fn iso(&self, ray: &Ray, span: Span, iso: f64, color: [f64; 3]) -> RayResult {
        let inside = |t: f64| self.value(ray, t) >= iso;
        let mut prev = None;
        let mut hit = None;
        for t in span.samples() {
            if inside(t) {
                hit = Some(match prev {
                    // The first sample is inside: a capped cut at t0.
                    None => t,
                    Some(t_prev) => {
                        let (mut a, mut b) = (t_prev, t); // a outside, b inside
                        for _ in 0..self.settings.iso_refine_steps {
                            let m = 0.5 * (a + b);
                            if inside(m) {
                                b = m;
                            } else {
                                a = m;
                            }
                        }
                        0.5 * (a + b)
                    }
                });
                break;
            }
            prev = Some(t);
        }
        match hit {
            None => ([0.0; 4], None),
            Some(t) => {
                let color = self.tint(ray, t, color);
                let [r, g, b] = self.shade(ray, t, color, &self.settings.shading);
                ([r, g, b, 1.0], Some(self.clip_depth(ray, t)))
            }
        }
    }

    /// Maximum intensity projection.
    fn mip(&self, ray: &Ray, span: Span) -> RayResult {
        let mut peaks = Peaks::default();
        for t in span.samples() {
            peaks.take(self.value(ray, t), t, span.dt);
        }
        let best = peaks.maximum(self.mip_refine, span, |t| self.value(ray, t));
        match best {
            None => ([0.0; 4], None),
            Some((m, t)) if self.intensity.is_some() => {
                let i = self.intensity.expect("matched");
                let [r, g, b] = self.tint(
                    ray,
                    t,
                    i.map(m, self.vol.desc().value_range)
                        .expect("the renderer refuses a volume without a finite value range"),
                );
                ([r, g, b, 1.0], Some(self.clip_depth(ray, t)))
            }
            Some((m, t)) => {
                let [r, g, b, a] = self.tf.lookup(m);
                let [r, g, b] = self.tint(ray, t, [r, g, b]);
                ([r * a, g * a, b * a, a], Some(self.clip_depth(ray, t)))
            }
        }
    }

    /// Iso and MIP: `rgb` tinted by the overlay's label at `t`, if any.
    fn tint(&self, ray: &Ray, t: f64, rgb: [f64; 3]) -> [f64; 3] {
        match self.overlay {
            Some(o) => {
                let u = (ray.tex_origin + ray.tex_dir * t).to_array();
                o.tint(rgb, u, self.settings.smooth_labels)
            }
            None => rgb,
        }
    }

    /// Continuous voxel coordinates of the ray at `t`.
    #[inline]
    fn voxel_pos(&self, ray: &Ray, t: f64) -> DVec3 {
        (ray.tex_origin + ray.tex_dir * t) * self.dims - DVec3::splat(0.5)
    }

    /// The normalized trilinear value at `t` (a label map: the nearest
    /// voxel's).
    #[inline]
    fn value(&self, ray: &Ray, t: f64) -> f64 {
        let p = self.voxel_pos(ray, t).to_array();
        if self.labels && self.settings.smooth_labels {
            let id = brickray_core::labels::smooth_label_at(self.vol, p) as f64;
            let [lo, hi] = self.vol.desc().value_range.map(f64::from);
            (id - lo) / (hi - lo)
        } else if self.labels {
            self.vol.sample_nearest(p)
        } else {
            self.vol.sample_trilinear(p)
        }
    }

    /// Clip depth of the ray's point at `t`.
    fn clip_depth(&self, ray: &Ray, t: f64) -> f64 {
        self.rays.depth_at(ray, t)
    }

    /// The unit world normal at `t`, or `None` where the gradient vanishes
    /// (a smooth label map: of its boundary's filtered indicator).
    fn normal(&self, ray: &Ray, t: f64) -> Option<DVec3> {
        self.normal_of(self.gradient(ray, t))
    }

    /// The gradient at `t` per voxel: central differences of the
    /// normalized field (a smooth label map: its boundary indicator's).
    fn gradient(&self, ray: &Ray, t: f64) -> DVec3 {
        let p = self.voxel_pos(ray, t);
        if self.labels {
            DVec3::from_array(
                brickray_core::labels::smooth_label_gradient(self.vol, p.to_array()).1,
            )
        } else {
            self.central_difference(p)
        }
    }

    /// The world normal of the per-voxel gradient `g` (`None` below
    /// `MIN_GRADIENT`).
    fn normal_of(&self, g: DVec3) -> Option<DVec3> {
        if g.length() < MIN_GRADIENT {
            return None;
        }
        // Per voxel -> per texture unit (x dims), then to world by the inverse
        // transpose of the texture-to-world 3x3 (see the crate docs).
        let n = self.normal_matrix * (g * self.dims);
        let n = n.normalize_or_zero();
        (n != DVec3::ZERO).then_some(n)
    }

    /// The central difference of the normalized field at voxel point `p`,
    /// one voxel along each axis.
    fn central_difference(&self, p: DVec3) -> DVec3 {
        DVec3::from_array(std::array::from_fn(|i| {
            let mut e = DVec3::ZERO;
            e[i] = 1.0;
            let hi = self.vol.sample_trilinear((p + e).to_array());
            let lo = self.vol.sample_trilinear((p - e).to_array());
            (hi - lo) * 0.5
        }))
    }

    /// Blinn-Phong with a headlight, two-sided, clamped to 0..1.
    fn shade(&self, ray: &Ray, t: f64, c: [f64; 3], s: &Shading) -> [f64; 3] {
        lit(self.normal(ray, t), ray, c, s)
    }
}

/// Blinn-Phong with a headlight (two-sided) of normal `n`, clamped to 0..1;
/// unlit (clamped) without a normal.
fn lit(n: Option<DVec3>, ray: &Ray, c: [f64; 3], s: &Shading) -> [f64; 3] {
    let Some(n) = n else {
        return c.map(|x| x.clamp(0.0, 1.0));
    };
    let l = -ray.dir; // L = H
    let ndl = n.dot(l).abs();
    let diffuse = s.ambient as f64 + s.diffuse as f64 * ndl;
    let specular = s.specular as f64 * ndl.powf(s.shininess as f64);
    c.map(|x| (x * diffuse + specular).clamp(0.0, 1.0))
}

mod channels;
pub use channels::render_channels_reference;

#[cfg(test)]
mod tests;

#[cfg(test)]
mod preint_tests;

#[cfg(test)]
mod spread_tests;
