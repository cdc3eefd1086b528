//! What every suite's result shares: where it ran, and the rounds of
//! interleaved variants its timings come from.
//!
//! Each suite returns a struct that serialises to its JSON line (one schema
//! per suite, written down in docs/benchmarks.md); `main` prints it.

use crate::runner::{Shot, round2};
use brickray_harness::GpuContext;
use serde::Serialize;

/// Where a GPU suite ran: image side, rounds and adapter. Flattened into
/// the suite's result, so these are top-level keys of its JSON line.
#[derive(Debug, Clone, Serialize)]
pub(crate) struct RunInfo {
    /// Image side of the timed frames, in pixels.
    pub(crate) image_size: u32,
    /// Interleaved rounds each timing is the median of.
    pub(crate) rounds: usize,
    /// The adapter's name.
    pub(crate) adapter: String,
    /// Whether the device measured the ray-cast pass with timestamps (the
    /// `*gpu_ms*` figures; null where it could not).
    pub(crate) gpu_timestamps: bool,
    /// The volume timed: a shared volume's name, a procedural stand-in's
    /// (`head_ct_phantom`, `mri_phantom`) where `../shared/data` is absent,
    /// or the suite's own volumes.
    pub(crate) volume: &'static str,
}

impl RunInfo {
    pub(crate) fn new(
        gpu: &GpuContext,
        image_size: u32,
        rounds: usize,
        volume: &'static str,
    ) -> RunInfo {
        RunInfo {
            image_size,
            rounds,
            adapter: gpu.adapter.get_info().name,
            gpu_timestamps: gpu
                .device
                .features()
                .contains(wgpu::Features::TIMESTAMP_QUERY),
            volume,
        }
    }
}

/// Runs `n` variants for `rounds` rounds, the order rotated each round (the
/// machine's speed drifts within a run, so every variant sees every part of
/// it); `time(i)` times variant `i` once. Returns each variant's times.
pub(crate) fn interleave<T>(
    rounds: usize,
    n: usize,
    mut time: impl FnMut(usize) -> Result<T, String>,
) -> Result<Vec<Vec<T>>, String> {
    let mut times: Vec<Vec<T>> = (0..n).map(|_| Vec::new()).collect();
    for r in 0..rounds {
        for k in 0..n {
            let i = (k + r) % n;
            times[i].push(time(i)?);
        }
    }
    Ok(times)
}

/// A variant's median frame time over its rounds: wall time, and the
/// ray-cast pass's own time where the device has timestamps.
#[derive(Debug, Clone, Copy, Serialize)]
pub(crate) struct Timing {
    /// Median `prepare + submit + wait` wall time, ms.
    pub(crate) ms: f64,
    /// Median time of the ray-cast pass by GPU timestamps, ms (null without).
    pub(crate) gpu_ms: Option<f64>,
}

impl Timing {
    /// The medians of `shots`, rounded to 0.01 ms.
    pub(crate) fn of(shots: &[Shot]) -> Timing {
        Timing::of_times(shots.iter().map(|s| (s.ms, s.gpu_ms)))
    }

    /// The medians of (wall, timestamp) times, rounded to 0.01 ms.
    pub(crate) fn of_times(times: impl IntoIterator<Item = (f64, Option<f64>)>) -> Timing {
        let (ms, gpu): (Vec<f64>, Vec<Option<f64>>) = times.into_iter().unzip();
        let gpu: Vec<f64> = gpu.into_iter().flatten().collect();
        Timing {
            ms: round2(median_or_nan(&ms)),
            gpu_ms: (!gpu.is_empty()).then(|| round2(median_or_nan(&gpu))),
        }
    }
}

/// The median of `v` (the upper one of an even count), NaN when empty.
pub(crate) fn median_or_nan(v: &[f64]) -> f64 {
    if v.is_empty() {
        f64::NAN
    } else {
        crate::runner::median(v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_variant_runs_every_round_in_rotated_order() {
        let mut order = Vec::new();
        let t = interleave(3, 3, |i| {
            order.push(i);
            Ok(i as f64)
        })
        .unwrap();
        assert_eq!(order, [0, 1, 2, 1, 2, 0, 2, 0, 1]);
        assert!(t.iter().enumerate().all(|(i, v)| v == &[i as f64; 3]));
        assert!(median_or_nan(&[]).is_nan());
        assert_eq!(median_or_nan(&[3.0, 1.0, 2.0]), 2.0);
    }
}
