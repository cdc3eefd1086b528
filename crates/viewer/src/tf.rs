//! The viewer's histogram of normalized values (the transfer-function
//! editor's background and the isovalue slider). The editor's model is the
//! library's [`brickray::core::tf::TfModel`]; the egui widget is
//! `tf_widget.rs`.

/// A histogram of normalized values, for the editor's background and the
/// isovalue slider.
#[derive(Debug, Clone, PartialEq, Default)]
pub(crate) struct Histogram {
    /// Counts per bin over 0..1.
    pub(crate) bins: Vec<u64>,
}

impl Histogram {
    /// An empty histogram of `n` bins.
    pub(crate) fn new(n: usize) -> Histogram {
        Histogram {
            bins: vec![0; n.max(1)],
        }
    }

    /// Counts a normalized value (clamped to 0..1; NaN ignored).
    pub(crate) fn add(&mut self, v: f32) {
        if v.is_nan() {
            return;
        }
        let n = self.bins.len();
        let i = ((v.clamp(0.0, 1.0) * n as f32) as usize).min(n - 1);
        self.bins[i] += 1;
    }

    /// Bin heights scaled to 0..1 by the tallest bin, linearly or as
    /// `ln(1 + count)`.
    pub(crate) fn heights(&self, log: bool) -> Vec<f32> {
        let f = |c: u64| if log { (c as f64).ln_1p() } else { c as f64 };
        let max = self.bins.iter().map(|&c| f(c)).fold(0.0, f64::max);
        self.bins
            .iter()
            .map(|&c| if max > 0.0 { (f(c) / max) as f32 } else { 0.0 })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn histogram_counts_and_scales() {
        let mut h = Histogram::new(4);
        for v in [0.0, 0.1, 0.3, 0.99, 1.0, 2.0, -1.0, f32::NAN] {
            h.add(v);
        }
        assert_eq!(h.bins, vec![3, 1, 0, 3]);
        assert_eq!(h.heights(false), vec![1.0, 1.0 / 3.0, 0.0, 1.0]);
        let log = h.heights(true);
        assert!((log[1] - (2f64.ln() / 4f64.ln()) as f32).abs() < 1e-6);
    }
}
