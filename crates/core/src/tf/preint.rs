//! Pre-integrated transfer functions (Engel, Kraus and Ertl 2001): the colour and
//! opacity of a ray *segment* whose value runs linearly from a front value `sf` to
//! a back value `sb` over a length of `d` reference lengths, integrated with the
//! TF's piecewise-linear function instead of point-sampled once per step.
//!
//! # The model
//!
//! It is the continuous limit of the reference's own sum: an opacity `a(s)` per
//! reference length is the extinction `tau(s) = -ln(1 - a(s))`, and the straight
//! colour `c(s)` is emitted in proportion to it (so a step of `d` through a
//! constant value composites `c * (1 - (1 - a)^d)`, the corrected single sample).
//! Along the segment `s(x) = sf + (sb - sf) x / d`:
//!
//! ```text
//! alpha = 1 - exp(-D(d)),            D(x) = integral_0^x tau(s(y)) dy
//! C     = integral_0^d c(s(x)) tau(s(x)) exp(-D(x)) dx    (associated colour)
//! ```
//!
//! With the integral function `T(s) = integral_0^s tau(u) du` (exact: `tau` of a
//! linear opacity integrates in closed form), `D(x) = d (T(s(x)) - T(sf)) / (sb - sf)`,
//! so the opacity is exact in O(1). The colour is `integral c dW` with
//! `W = 1 - exp(-D)`, summed over a fine value grid (`FINE` cells per table
//! column): each cell adds its mean colour times its exact opacity increment, so
//! the sum of the increments is `alpha` exactly, `C <= alpha * max c`, and the
//! only error is the colour's variation across one fine cell.
//!
//! `sf == sb` is the corrected single sample exactly (`c * a'`, `a'` from
//! [`corrected_alpha`]). An opacity of exactly 1 over a value interval is an
//! extinction of [`TAU_MAX`] per reference length.
//!
//! # Segments through a midpoint
//!
//! A value that runs linearly between two samples cuts every peak or dip
//! the samples straddle; where the data varies within a step (a skull met
//! at a grazing angle) the linear segment loses to a plain point sample
//! (docs/studies/preint-segment-models.md). The renderers therefore draw a
//! segment as [`SEGMENT_PIECES`] linear pieces along the parabola through
//! the segment's two samples and the sample before them
//! ([`segment_values`]), which needs no sample past the segment. Each piece
//! is looked up as a whole segment of the step over its values and shortened
//! by [`join_pieces`]: a piece's opacity `1 - (1 - a)^(1/n)` is exact (a
//! linear segment's extinction is its length times the mean extinction of
//! its values), its colour is scaled with it.

use super::{TransferFunction, corrected_alpha};

/// The least columns (and rows) of a pre-integrated table.
pub const PREINT_MIN_SIZE: u32 = 256;

/// Fine value cells per table column in the colour quadrature.
pub const FINE: u32 = 4;

/// Extinction per reference length standing for an opacity of exactly 1 over a
/// value interval (opaque to f64 within 1e-4 of a reference length).
pub const TAU_MAX: f64 = 1.0e6;

/// A TF prepared for segment integrals: its integral function `T` and colours on
/// a fine value grid.
#[derive(Debug, Clone)]
pub struct Preintegrator<'a> {
    tf: &'a TransferFunction,
    /// Fine grid points `m / (cells)`, `cells + 1` of them.
    cells: usize,
    /// `T` at each fine grid point.
    t: Vec<f64>,
    /// Straight colour at each fine grid point.
    c: Vec<[f64; 3]>,
}

/// `integral -ln(u) ds` over a piece of length `len` where `u = 1 - a` runs
/// linearly from `u0` to `u1` (in 0..1), capped at `TAU_MAX * len`.
fn tau_piece(u0: f64, u1: f64, len: f64) -> f64 {
    let f = |u: f64| if u > 0.0 { u - u * u.ln() } else { 0.0 };
    let v = if (u1 - u0).abs() < 1e-12 {
        let u = 0.5 * (u0 + u1);
        if u > 0.0 {
            -u.ln() * len
        } else {
            f64::INFINITY
        }
    } else {
        len * (f(u1) - f(u0)) / (u1 - u0)
    };
    v.clamp(0.0, TAU_MAX * len)
}

/// Linear pieces of a pre-integrated segment ([`segment_values`]).
pub const SEGMENT_PIECES: usize = 4;

/// The values at the ends of the [`SEGMENT_PIECES`] pieces of the segment
/// from `s1` to `s2` (consecutive samples one step apart), `x = j / n` for
/// `j` in `0..=n`: on the parabola through the sample before them, `s0`, and
/// the two, `s1 + (s2 - s0) x / 2 + (s2 - 2 s1 + s0) x^2 / 2`; without `s0`
/// (the segment follows a ray's first sample, skipped space or a change of
/// step) on the straight line. Clamped to 0..1; the ends are `s1` and `s2`.
pub fn segment_values(s0: Option<f64>, s1: f64, s2: f64) -> [f64; SEGMENT_PIECES + 1] {
    let s0 = s0.unwrap_or(2.0 * s1 - s2);
    std::array::from_fn(|j| {
        let x = j as f64 / SEGMENT_PIECES as f64;
        (s1 + 0.5 * (s2 - s0) * x + 0.5 * (s2 - 2.0 * s1 + s0) * x * x).clamp(0.0, 1.0)
    })
}

/// A segment in [`SEGMENT_PIECES`] pieces, each given as the premultiplied
/// RGBA of a whole step's segment over its values (from one value of
/// [`segment_values`] to the next, [`Preintegrator::segment`] or the table):
/// each piece's opacity `1 - (1 - a)^(1/n)` (exact for a linear segment of
/// `1/n` the length: its extinction is its length times the mean extinction
/// of its values), its colour scaled by the same factor, composited front to
/// back. A constant segment gives back its whole step's.
pub fn join_pieces(pieces: [[f64; 4]; SEGMENT_PIECES]) -> [f64; 4] {
    let mut out = [0.0; 4];
    for p in pieces {
        let a = p[3].clamp(0.0, 1.0);
        let h = 1.0 - (1.0 - a).powf(1.0 / SEGMENT_PIECES as f64);
        let k = if a > 0.0 { h / a } else { 0.0 };
        let t = 1.0 - out[3];
        for c in 0..3 {
            out[c] += t * k * p[c];
        }
        out[3] += t * h;
    }
    out
}

impl<'a> Preintegrator<'a> {
    /// Prepares `tf` with `cells` fine value cells over 0..1 (at least 1).
    pub fn new(tf: &'a TransferFunction, cells: u32) -> Preintegrator<'a> {
        let cells = cells.max(1) as usize;
        let mut t = Vec::with_capacity(cells + 1);
        t.push(0.0);
        let mut acc = 0.0;
        for m in 0..cells {
            acc += tf.tau_integral(m as f64 / cells as f64, (m + 1) as f64 / cells as f64);
            t.push(acc);
        }
        let c = (0..=cells)
            .map(|m| {
                let e = tf.lookup(m as f64 / cells as f64);
                [e[0], e[1], e[2]]
            })
            .collect();
        Preintegrator { tf, cells, t, c }
    }

    /// `T(s)` for `s` in 0..1.
    fn t_at(&self, s: f64) -> f64 {
        let x = s.clamp(0.0, 1.0) * self.cells as f64;
        let m = (x.floor() as usize).min(self.cells);
        let s_m = m as f64 / self.cells as f64;
        self.t[m] + self.tf.tau_integral(s_m, s.clamp(0.0, 1.0))
    }

    /// The premultiplied RGBA of a segment from value `sf` to `sb` (clamped to
    /// 0..1) of `d` reference lengths, front to back.
    pub fn segment(&self, sf: f64, sb: f64, d: f64) -> [f64; 4] {
        let mut out = [[0.0; 4]];
        self.segment_layers(sf, sb, d, &mut out);
        out[0]
    }

    /// [`Self::segment`] for the lengths `d * 2^l`, `l` in `0..out.len()`, at
    /// once: the attenuation of a cell at length `2d` is the square of that at
    /// `d`, so the exponentials are taken once for all lengths.
    pub fn segment_layers(&self, sf: f64, sb: f64, d: f64, out: &mut [[f64; 4]]) {
        const CHUNK: usize = 32;
        if out.len() > CHUNK {
            for (c, part) in out.chunks_mut(CHUNK).enumerate() {
                self.segment_layers(sf, sb, d * ((c * CHUNK) as f64).exp2(), part);
            }
            return;
        }
        let layers = out.len();
        let (sf, sb) = (sf.clamp(0.0, 1.0), sb.clamp(0.0, 1.0));
        let delta = sb - sf;
        if delta.abs() < 1e-9 || d <= 0.0 {
            let e = self.tf.lookup(sf);
            for (l, o) in out.iter_mut().enumerate() {
                let a = corrected_alpha(e[3], (d * (l as f64).exp2()).max(0.0));
                *o = [e[0] * a, e[1] * a, e[2] * a, a];
            }
            return;
        }
        let k = d / delta.abs();
        let tf0 = self.t_at(sf);
        let n = self.cells as f64;
        // Fine grid points strictly between sf and sb, in travel order.
        let (lo, hi) = if delta > 0.0 { (sf, sb) } else { (sb, sf) };
        let m_lo = (lo * n).floor() as usize + 1;
        let m_hi = ((hi * n).ceil() as usize).saturating_sub(1);
        for o in out.iter_mut() {
            *o = [0.0; 4];
        }
        let mut prev_w = [1.0f64; CHUNK];
        let mut prev_c = self.colour(sf);
        // Each fine cell adds its mean colour times its exact opacity increment.
        let mut cell = |t: f64, c: [f64; 3]| {
            let mut w = (-k * (t - tf0).abs()).exp();
            let mean = [
                0.5 * (prev_c[0] + c[0]),
                0.5 * (prev_c[1] + c[1]),
                0.5 * (prev_c[2] + c[2]),
            ];
            for (o, pw) in out.iter_mut().zip(prev_w.iter_mut()) {
                let dw = (*pw - w).max(0.0);
                for i in 0..3 {
                    o[i] += mean[i] * dw;
                }
                *pw = w;
                w *= w;
            }
            prev_c = c;
        };
        if m_lo <= m_hi {
            if delta > 0.0 {
                (m_lo..=m_hi).for_each(|m| cell(self.t[m], self.c[m]));
            } else {
                (m_lo..=m_hi).rev().for_each(|m| cell(self.t[m], self.c[m]));
            }
        }
        let tb = self.t_at(sb);
        cell(tb, self.colour(sb));
        let mut w_end = (-k * (tb - tf0).abs()).exp();
        for o in out.iter_mut().take(layers) {
            o[3] = 1.0 - w_end;
            w_end *= w_end;
        }
    }

    fn colour(&self, s: f64) -> [f64; 3] {
        let e = self.tf.lookup(s);
        [e[0], e[1], e[2]]
    }
}

/// A pre-integrated table: `layers` square tables of `size x size` RGBA texels,
/// layer `l` for segments of `step_factor * 2^l` reference lengths; in a layer,
/// texel `(i, j)` (column `i` = front value `i / (size - 1)`, row `j` = back value
/// `j / (size - 1)`) is at `(l * size + j) * size + i`. Colours are associated
/// (premultiplied by the segment's opacity).
#[derive(Debug, Clone, PartialEq)]
pub struct PreintTable {
    /// Columns and rows of a layer.
    pub size: u32,
    /// Layers (step lengths).
    pub layers: u32,
    /// `layers * size * size` premultiplied RGBA texels.
    pub texels: Vec<[f32; 4]>,
}

impl TransferFunction {
    /// `integral_{s0}^{s1} -ln(1 - a(s)) ds` of the TF's piecewise-linear opacity
    /// (values clamped to 0..1, `s0 <= s1`), in closed form per entry interval.
    pub fn tau_integral(&self, s0: f64, s1: f64) -> f64 {
        let (s0, s1) = (s0.clamp(0.0, 1.0), s1.clamp(0.0, 1.0));
        if s1 <= s0 {
            return 0.0;
        }
        let n1 = (self.len() - 1) as f64;
        let mut sum = 0.0;
        let mut a = s0;
        while a < s1 {
            // The end of the entry interval holding a.
            let mut i = (a * n1).floor() + 1.0;
            if i / n1 <= a {
                i += 1.0;
            }
            let b = (i / n1).min(s1);
            sum += tau_piece(1.0 - self.lookup(a)[3], 1.0 - self.lookup(b)[3], b - a);
            a = b;
        }
        sum
    }

    /// The pre-integrated table of `layers` step lengths (`step_factor * 2^l`
    /// reference lengths) at `size x size` (at least [`PREINT_MIN_SIZE`]).
    /// Rows are computed on up to `available_parallelism` threads, all layers
    /// of a texel at once ([`Preintegrator::segment_layers`]).
    pub fn preintegrated_table(&self, step_factor: f32, layers: u32, size: u32) -> PreintTable {
        let size = size.max(PREINT_MIN_SIZE);
        self.preintegrated_table_any(step_factor, layers, size)
    }

    /// [`Self::preintegrated_table`] at any `size >= 2` (small tables for tests).
    pub fn preintegrated_table_any(&self, step_factor: f32, layers: u32, size: u32) -> PreintTable {
        let size = size.max(2);
        let layers = layers.max(1);
        let p = Preintegrator::new(self, (size - 1) * FINE);
        let n = size as usize;
        let nl = layers as usize;
        let threads = std::thread::available_parallelism().map_or(1, |t| t.get());
        let per = n.div_ceil(threads).max(1);
        // Rows of back values per thread, every layer at once.
        let parts: Vec<Vec<[f32; 4]>> = std::thread::scope(|scope| {
            let handles: Vec<_> = (0..n)
                .step_by(per)
                .map(|j0| {
                    let p = &p;
                    scope.spawn(move || {
                        let j1 = (j0 + per).min(n);
                        let mut part = vec![[0.0f32; 4]; (j1 - j0) * n * nl];
                        let mut seg = vec![[0.0f64; 4]; nl];
                        for j in j0..j1 {
                            let sb = j as f64 / (n - 1) as f64;
                            for i in 0..n {
                                let sf = i as f64 / (n - 1) as f64;
                                p.segment_layers(sf, sb, step_factor as f64, &mut seg);
                                for (l, x) in seg.iter().enumerate() {
                                    part[(l * (j1 - j0) + (j - j0)) * n + i] = x.map(|c| c as f32);
                                }
                            }
                        }
                        part
                    })
                })
                .collect();
            handles
                .into_iter()
                .map(|h| h.join().expect("table thread"))
                .collect()
        });
        let mut texels = vec![[0.0f32; 4]; nl * n * n];
        for (c, part) in parts.iter().enumerate() {
            let j0 = c * per;
            let rows = part.len() / (n * nl);
            for l in 0..nl {
                let src = &part[l * rows * n..(l + 1) * rows * n];
                texels[(l * n + j0) * n..(l * n + j0 + rows) * n].copy_from_slice(src);
            }
        }
        PreintTable {
            size,
            layers,
            texels,
        }
    }
}

impl PreintTable {
    /// What a filtering lookup of layer `layer` at (front, back) returns with
    /// exact bilinear weights (hardware adds weight quantisation).
    pub fn lookup(&self, layer: u32, front: f64, back: f64) -> [f64; 4] {
        let n = self.size as usize;
        let at = |v: f64| {
            let x = v.clamp(0.0, 1.0) * (n - 1) as f64;
            let i = (x.floor() as usize).min(n - 2);
            (i, x - i as f64)
        };
        let (i, fx) = at(front);
        let (j, fy) = at(back);
        let base = layer.min(self.layers - 1) as usize * n * n;
        let t = |i: usize, j: usize| self.texels[base + j * n + i];
        std::array::from_fn(|k| {
            let top = t(i, j)[k] as f64 * (1.0 - fx) + t(i + 1, j)[k] as f64 * fx;
            let bot = t(i, j + 1)[k] as f64 * (1.0 - fx) + t(i + 1, j + 1)[k] as f64 * fx;
            top * (1.0 - fy) + bot * fy
        })
    }
}

#[cfg(test)]
mod tests;
