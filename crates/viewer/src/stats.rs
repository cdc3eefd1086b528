//! Statistics over the last seconds, plotted with egui_plot.

use brickray::RendererStats;
use eframe::egui;
use egui_plot::{Bar, BarChart, Legend, Line, Plot};
use std::collections::VecDeque;

/// Seconds of history kept and plotted.
const WINDOW_S: f64 = 20.0;

/// One frame's figures.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct Sample {
    /// Seconds since the viewer started.
    pub(crate) t: f64,
    /// Interval since the previous frame drawn, ms (while redrawing
    /// continuously this is the frame time).
    pub(crate) frame_ms: f64,
    /// MiB written to the GPU this frame.
    pub(crate) upload_mib: f64,
    /// Bricks of the GPU working set (out of core).
    pub(crate) working_set: f64,
    /// Pool occupancy, 0..1 (out of core).
    pub(crate) pool: f64,
    /// Brick requests queued or being read (out of core).
    pub(crate) in_flight: f64,
    /// Frames since the image last converged (0 = converged).
    pub(crate) since_converged: f64,
}

/// The history and the last frame's per-level counts.
#[derive(Debug, Default)]
pub(crate) struct Stats {
    samples: VecDeque<Sample>,
    levels: [u32; 16],
    since_converged: u64,
    streamed: bool,
    /// The last frame's prediction buffer state (`None`: it did not predict).
    prediction: Option<brickray::PredictionFrame>,
    /// Out of core: the visibility policy and the cut's leaves by visibility.
    visibility: Option<(brickray::VisibilityPolicy, brickray::VisibilityCounts)>,
    /// Out of core: whether the volume keeps its texels' gradients.
    gradients_kept: Option<bool>,
}

impl Stats {
    /// Forgets everything (a new volume).
    pub(crate) fn clear(&mut self) {
        *self = Stats::default();
    }

    /// Records a frame drawn at `t` seconds, `frame_ms` after the previous one.
    pub(crate) fn push(&mut self, t: f64, frame_ms: f64, s: &RendererStats) {
        let mut sample = Sample {
            t,
            frame_ms,
            upload_mib: s.frame.uploaded_bytes as f64 / (1u64 << 20) as f64,
            ..Default::default()
        };
        self.streamed = s.out_of_core.is_some();
        self.prediction = s.frame.prediction;
        if let Some(o) = &s.out_of_core {
            let c = &o.cache;
            sample.working_set = c.working_set_bricks as f64;
            sample.pool = c.pool_occupied as f64 / c.pool_slots.max(1) as f64;
            sample.in_flight = c.requests_in_flight as f64;
            self.levels = o.data_leaves_per_level;
            self.visibility = Some((o.policy, o.visibility));
            self.gradients_kept = Some(o.gradients_kept);
            self.since_converged = if o.converged {
                0
            } else {
                self.since_converged + 1
            };
        }
        sample.since_converged = self.since_converged as f64;
        self.samples.push_back(sample);
        while self.samples.front().is_some_and(|f| t - f.t > WINDOW_S) {
            self.samples.pop_front();
        }
    }

    /// The last frame's prediction buffer state.
    pub(crate) fn prediction(&self) -> Option<brickray::PredictionFrame> {
        self.prediction
    }

    /// Out of core: whether the volume keeps its texels' gradients.
    pub(crate) fn gradients_kept(&self) -> Option<bool> {
        self.gradients_kept
    }

    /// The last sample.
    pub(crate) fn last(&self) -> Option<&Sample> {
        self.samples.back()
    }

    /// Points of one figure (frames without it, NaN, are left out).
    fn series(&self, f: impl Fn(&Sample) -> f64) -> Vec<[f64; 2]> {
        self.samples
            .iter()
            .map(|s| [s.t, f(s)])
            .filter(|p| p[1].is_finite())
            .collect()
    }

    /// The plots.
    pub(crate) fn show(&self, ui: &mut egui::Ui) {
        if let Some(s) = self.last() {
            let frame = if s.frame_ms.is_finite() {
                format!("frame {:.1} ms", s.frame_ms)
            } else {
                "idle".to_string()
            };
            ui.label(format!(
                "{frame}, upload {:.2} MiB{}",
                s.upload_mib,
                if self.streamed {
                    format!(
                        ", working set {} bricks, pool {:.0}%, {} in flight, {} frames since converged, shading {}",
                        s.working_set,
                        s.pool * 100.0,
                        s.in_flight,
                        s.since_converged,
                        if self.gradients_kept == Some(true) {
                            "from kept gradients"
                        } else {
                            "by six reads"
                        }
                    )
                } else {
                    String::new()
                }
            ));
        }
        // What the visibility feedback and the prediction buffer did.
        if let Some((policy, v)) = self
            .visibility
            .filter(|(p, _)| *p != brickray::VisibilityPolicy::None)
        {
            ui.label(format!(
                "visibility ({}): {} bricks visible, {} hidden, {} not yet observed",
                policy.name(),
                v.visible,
                v.invisible,
                v.unobserved
            ));
        }
        if let Some(p) = self.prediction {
            ui.label(format!(
                "prediction: {} frames of history{}{}",
                p.frames,
                if p.refresh { ", full refresh" } else { "" },
                if p.reprojected { ", reprojected" } else { "" }
            ));
        }
        let plot = |id: &str| {
            Plot::new(id.to_string())
                .height(110.0)
                .legend(Legend::default())
                .allow_scroll(false)
                .allow_drag(false)
                .allow_zoom(false)
                .include_y(0.0)
        };
        plot("brickray-viewer times").show(ui, |p| {
            p.line(Line::new("frame ms", self.series(|s| s.frame_ms)));
            p.line(Line::new("upload MiB", self.series(|s| s.upload_mib)));
        });
        if self.streamed {
            plot("brickray-viewer bricks").show(ui, |p| {
                p.line(Line::new("working set", self.series(|s| s.working_set)));
                p.line(Line::new("in flight", self.series(|s| s.in_flight)));
                p.line(Line::new(
                    "frames since converged",
                    self.series(|s| s.since_converged),
                ));
            });
            plot("brickray-viewer pool").include_y(1.0).show(ui, |p| {
                p.line(Line::new("pool occupancy", self.series(|s| s.pool)));
            });
            let bars: Vec<Bar> = self
                .levels
                .iter()
                .enumerate()
                .map(|(l, &n)| Bar::new(l as f64, n as f64))
                .collect();
            plot("brickray-viewer levels").show(ui, |p| {
                p.bar_chart(BarChart::new("data bricks per level", bars));
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn history_keeps_the_window() {
        let mut s = Stats::default();
        let r = RendererStats::default();
        for i in 0..100 {
            s.push(i as f64, 16.0, &r);
        }
        assert_eq!(s.samples.len(), (WINDOW_S as usize) + 1);
        assert_eq!(s.last().unwrap().t, 99.0);
    }
}
