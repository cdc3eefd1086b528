//! Where a reference ray samples: its clipped span, DVR's step grid
//! (with the adaptive step) and MIP's peaks along it.

use brickray_core::adaptive_step_doublings;

/// The sample positions of a clipped ray.
#[derive(Debug, Clone, Copy)]
pub(super) struct Span {
    pub(super) t0: f64,
    pub(super) t1: f64,
    pub(super) dt: f64,
}

impl Span {
    /// `t_k = t0 + k * dt` for `k = 0, 1, ...` while `t_k < t1`.
    pub(super) fn samples(self) -> impl Iterator<Item = f64> {
        (0u64..)
            .map(move |k| self.t0 + k as f64 * self.dt)
            .take_while(move |&t| t < self.t1)
    }
}

/// DVR's sample grid along a span (the kernels' `StepGrid`): the samples
/// lie at `tb + k dt 2^j`; with the adaptive step the doublings `j` follow
/// the ray's opacity ([`adaptive_step_doublings`], the kernels'
/// `step_doublings`), and a change of `j` starts the grid anew at the
/// sample where it happens.
pub(super) struct StepGrid {
    span: Span,
    adaptive: bool,
    tb: f64,
    k: u64,
    j: u32,
}

impl StepGrid {
    pub(super) fn new(span: Span, adaptive: bool) -> StepGrid {
        StepGrid {
            span,
            adaptive,
            tb: span.t0,
            k: 0,
            j: 0,
        }
    }

    /// The next sample of a ray whose opacity so far is `a`: its `t` and
    /// its step in steps `dt` (`2^j`); `None` past the span.
    pub(super) fn next(&mut self, a: f64) -> Option<(f64, f64)> {
        let t = self.tb + self.k as f64 * self.span.dt * f64::from(1u32 << self.j);
        if t >= self.span.t1 {
            return None;
        }
        if self.adaptive {
            let j = adaptive_step_doublings(1.0 - a);
            if j != self.j {
                (self.tb, self.k, self.j) = (t, 0, j);
            }
        }
        self.k += 1;
        Some((t, f64::from(1u32 << self.j)))
    }
}

/// MIP's peaks along a ray, `(value, t)`: the running maximum and the
/// runner-up (a maximum replaced by one more than a step and a half away,
/// or a sample that far from the maximum above it), as the kernels'
/// `mip_sample` keeps them (the multi-channel kernels: per channel,
/// `channel_mip_sample`).
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Peaks {
    best: Option<(f64, f64)>,
    alt: Option<(f64, f64)>,
}

impl Peaks {
    /// The sample `v` at `t`, the samples `dt` apart.
    pub(super) fn take(&mut self, v: f64, t: f64, dt: f64) {
        let far = self.best.is_some_and(|(_, tm)| t - tm > 1.5 * dt);
        if self.best.is_none_or(|(m, _)| v > m) {
            if far {
                self.alt = self.best;
            }
            self.best = Some((v, t));
        } else if far && self.alt.is_none_or(|(a, _)| v > a) {
            self.alt = Some((v, t));
        }
    }

    /// The ray's maximum: with `refine`, the maximum and the runner-up
    /// refined between samples of `value`, as the kernels' `mip_refine`
    /// does (half a step, then a quarter, either side of each peak's best
    /// value so far, within the span), the best kept; without, the
    /// samples' maximum.
    pub(super) fn maximum(
        self,
        refine: bool,
        span: Span,
        value: impl Fn(f64) -> f64,
    ) -> Option<(f64, f64)> {
        let mut best = self.best;
        if refine {
            for (v0, t0) in [self.best, self.alt].into_iter().flatten() {
                let (mut bv, mut bt) = (v0, t0);
                let mut h = 0.5 * span.dt;
                for _ in 0..2 {
                    for t in [bt - h, bt + h].map(|t| t.clamp(span.t0, span.t1)) {
                        let v = value(t);
                        if v > bv {
                            (bv, bt) = (v, t);
                        }
                    }
                    h *= 0.5;
                }
                if best.is_none_or(|(m, _)| bv > m) {
                    best = Some((bv, bt));
                }
            }
        }
        best
    }
}
