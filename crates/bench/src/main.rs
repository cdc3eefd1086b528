//! brickray's benchmark binary.
//!
//! `cargo run --release -p brickray-bench -- <suite>` runs one suite, prints what
//! it measured, and ends with one line holding a JSON object of the figures.
//! Variants are interleaved within one run and compared as ratios, because this
//! machine's speed drifts.

mod accel;
mod build;
mod channels;
mod chart;
mod formats;
mod host;
mod labels;
mod lodrank;
mod ooc;
mod pareto;
mod prediction;
mod preint;
mod raw;
mod remote;
mod report;
mod runner;
mod shading;
mod skipping;
mod soak;
mod spread;
mod stability;
mod u8;
mod visibility;

use std::process::ExitCode;

/// What a suite returns: its figures, printed as the last line.
type Figures = serde_json::Map<String, serde_json::Value>;

/// The largest image side a suite accepts, in pixels: the 2D texture limit
/// of most desktop devices and of Mesa's lavapipe (a suite also checks its
/// device's own limit before it creates a target).
const MAX_IMAGE_SIDE: u32 = 16384;

/// An image side: 1 to [`MAX_IMAGE_SIDE`] pixels.
fn image_side(s: &str) -> Result<u32, String> {
    let n: u32 = s.parse().map_err(|e| format!("{e}"))?;
    if (1..=MAX_IMAGE_SIDE).contains(&n) {
        Ok(n)
    } else {
        Err(format!(
            "{n} is not an image side in 1..={MAX_IMAGE_SIDE} pixels"
        ))
    }
}

/// A sample step in voxels, within what `RenderSettings::validate` accepts.
fn sample_step(s: &str) -> Result<f32, String> {
    let step: f32 = s.parse().map_err(|e| format!("{s}: {e}"))?;
    let (lo, hi) = (
        brickray_core::RenderSettings::MIN_STEP_FACTOR,
        brickray_core::RenderSettings::MAX_STEP_FACTOR,
    );
    if (lo..=hi).contains(&step) {
        Ok(step)
    } else {
        Err(format!("{s}: a sample step lies in {lo}..={hi} voxels"))
    }
}

/// A count of rounds or frames: at least 1.
fn at_least_one<T: std::str::FromStr + PartialOrd + From<u8>>(s: &str) -> Result<T, String>
where
    T::Err: std::fmt::Display,
{
    let n: T = s.parse().map_err(|e| format!("{e}"))?;
    if n >= T::from(1) {
        Ok(n)
    } else {
        Err(format!("{s} is not at least 1"))
    }
}

/// The parts of the `ooc` suite: one or more of a, b and c.
fn ooc_parts(s: &str) -> Result<String, String> {
    if !s.is_empty() && s.chars().all(|c| matches!(c, 'a' | 'b' | 'c')) {
        Ok(s.to_string())
    } else {
        Err(format!(
            "{s:?} names no parts: use one or more of a, b and c"
        ))
    }
}

/// brickray's benchmarks: each suite prints what it measured and ends with one
/// line holding a JSON object of the figures.
#[derive(Debug, clap::Parser)]
#[command(name = "brickray-bench", version)]
struct Cli {
    #[command(subcommand)]
    suite: Suite,
}

/// The suites; each suite's options are its module's `Args`, parsed here once.
#[derive(Debug, clap::Subcommand)]
enum Suite {
    /// Early ray termination and empty-space skipping vs brute force on the head CT.
    Accel(accel::Args),
    /// The brick-store builder: throughput, memory bound, banded levels.
    Build(build::Args),
    /// Store build throughput and memory from each input format (the shared
    /// format fixtures).
    Formats(formats::Args),
    /// What the render thread pays per frame out of core: `prepare`'s time
    /// along a moving camera path at cuts of about 1k to 50k bricks.
    Host(host::Args),
    /// Out of core vs in core, output sensitivity, a camera path.
    Ooc(ooc::Args),
    /// Speed against accuracy: one knob at a time around the defaults on five
    /// volumes, time against error against the f64 reference, Pareto fronts
    /// charted (SVG).
    Pareto(pareto::Args),
    /// The isosurface prediction buffer (Braley et al.): orbits, a failure path,
    /// translation and zoom; variants interleaved frame by frame.
    Prediction(prediction::Args),
    /// Pre-integrated DVR: table build time, frame time against the plain
    /// path (interleaved, head CT) and PSNR against the exact integral.
    Preint(preint::Args),
    /// Per-sample cost: brickray against a minimal kernel (the device's rate), in
    /// core and out of core, DVR, shaded DVR, iso and MIP.
    Raw(raw::Args),
    /// Shading's cost in core: unshaded, six reads per shaded sample and
    /// precomputed gradients, interleaved, with PSNR against the reference.
    Shading(shading::Args),
    /// MIP's empty-space skipping in core: without it, always, and where the
    /// macro cells say it pays, interleaved, on procedural and shared volumes.
    Skipping(skipping::Args),
    /// Memory and frame time over a long random-camera run.
    Soak(soak::Args),
    /// Coarse levels classified with their spread against the TF of their
    /// values, out of core: frame time and PSNR against in core.
    Spread(spread::Args),
    /// Visibility feedback: working set, image and latency per policy along a
    /// camera path with a half turn (head CT and procedural shells).
    Visibility(visibility::Args),
    /// Stability: scripted scenes that drive each method to where it breaks
    /// (streaming, memory pressure, high-frequency TF, thin structures,
    /// grazing rays, precision at 65536^3, ERT, prediction and disocclusion,
    /// LOD paths), against the f64 reference.
    Stability(stability::Args),
    /// Multi-channel volumes: ms per frame of 1, 2 and 4 channels in every
    /// mode, texel bytes, error against the reference (needs
    /// ../shared/data).
    Channels(channels::Args),
    /// Label maps: cost against intensity DVR of the same view, hidden-label
    /// skipping, error against the reference and of coarse levels (needs
    /// ../shared/data).
    Labels(labels::Args),
    /// How the refiner's priorities rank nodes against their exact cost to
    /// the image, levels drawn as the TF of their mean and with their spreads
    /// (GPU-free).
    Lodrank(lodrank::Args),
    /// Streaming over HTTP with added round-trip time against the local
    /// disk: first image, convergence, bytes and requests, frame times
    /// (needs ../shared/data and python3).
    Remote(remote::Args),
    /// u8 volumes: exact interpolation vs 8-bit texels.
    U8(u8::Args),
    /// brickray against VTK's CPU and GPU volume mappers at equal error on
    /// the head CT and MRI (DVR, shaded DVR, MIP; needs ../shared/data and
    /// VTK's Python package).
    Vtk(pareto::vtk::Args),
}

/// A suite's typed result as its JSON object.
fn emit<T: serde::Serialize>(r: Result<T, String>) -> Result<Figures, String> {
    match serde_json::to_value(r?).map_err(|e| e.to_string())? {
        serde_json::Value::Object(m) => Ok(m),
        other => Err(format!("a result that is not an object: {other}")),
    }
}

fn main() -> ExitCode {
    let cli = <Cli as clap::Parser>::parse();
    let suite = std::env::args().nth(1).unwrap_or_default();
    let result: Result<Figures, String> = match cli.suite {
        Suite::Accel(a) => emit(accel::run(&a)),
        Suite::Build(a) => emit(build::run(&a)),
        Suite::Formats(a) => emit(formats::run(&a)),
        Suite::Ooc(a) => emit(ooc::run(&a)),
        Suite::Pareto(a) => emit(pareto::run(&a)),
        Suite::Prediction(a) => emit(prediction::run(&a)),
        Suite::Preint(a) => emit(preint::run(&a)),
        Suite::Raw(a) => emit(raw::run(&a)),
        Suite::Shading(a) => emit(shading::run(&a)),
        Suite::Skipping(a) => emit(skipping::run(&a)),
        Suite::Soak(a) => emit(soak::run(&a)),
        Suite::Spread(a) => emit(spread::run(&a)),
        Suite::Host(a) => emit(host::run(&a)),
        Suite::Stability(a) => emit(stability::run(&a)),
        Suite::U8(a) => emit(u8::run(&a)),
        Suite::Labels(a) => emit(labels::run(&a)),
        Suite::Lodrank(a) => emit(lodrank::run(&a)),
        Suite::Channels(a) => emit(channels::run(&a)),
        Suite::Remote(a) => emit(remote::run(&a)),
        Suite::Visibility(a) => emit(visibility::run(&a)),
        Suite::Vtk(a) => emit(pareto::vtk::run(&a)),
    };
    match result {
        Ok(fig) => {
            println!("{}", serde_json::Value::Object(fig));
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("brickray-bench {suite}: {e}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_sample_step_is_one_the_renderer_accepts() {
        assert_eq!(super::sample_step("2"), Ok(2.0));
        for bad in ["0", "-1", "17", "nan", "one"] {
            assert!(super::sample_step(bad).is_err(), "{bad}");
        }
    }
}
