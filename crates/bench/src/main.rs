//! brickray's benchmark binary.
//!
//! `cargo run --release -p brickray-bench -- <suite>` runs one suite, prints what
//! it measured, and ends with one line holding a JSON object of the figures.
//! Variants are interleaved within one run and compared as ratios, because this
//! machine's speed drifts.

mod accel;
mod aniso;
mod build;
mod channels;
mod cut;
mod formats;
mod host;
mod labels;
mod lod;
mod octant;
mod ooc;
mod oracle;
mod pareto;
mod prediction;
mod prediction_chart;
mod preint;
mod raw;
mod remote;
mod runner;
mod soak;
mod stability;
mod u8;
mod visibility;

use std::process::ExitCode;

/// What a suite returns: its figures, printed as the last line.
type Figures = serde_json::Map<String, serde_json::Value>;

/// The value after `name` in `args`, parsed, or `default` when absent.
fn arg<T: std::str::FromStr>(args: &[String], name: &str, default: T) -> Result<T, String> {
    match args.iter().position(|a| a == name) {
        None => Ok(default),
        Some(i) => args
            .get(i + 1)
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| format!("bad {name}")),
    }
}

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

/// The suites and their options (each suite reads its options itself; clap
/// checks them and prints `--help`).
#[derive(Debug, clap::Subcommand)]
enum Suite {
    /// Early ray termination and empty-space skipping vs brute force on the head CT.
    Accel {
        /// Interleaved rounds (default 5).
        #[arg(long, value_parser = at_least_one::<usize>)]
        rounds: Option<usize>,
        /// Image side in pixels (default 512).
        #[arg(long, value_parser = image_side)]
        size: Option<u32>,
    },
    /// LOD sweep on the head CT at 4.5 mm slices: bricks and PSNR per
    /// tolerance and per brick budget, all-axes octree vs anisotropic pyramid
    /// (CPU only).
    Aniso {
        /// Image side in pixels (default 160).
        #[arg(long, value_parser = image_side)]
        size: Option<u32>,
        /// Reference step factor (default 0.5).
        #[arg(long)]
        step: Option<f32>,
        /// Head CT scene: dvr_translucent (default), dvr_opaque, iso, mip.
        #[arg(long)]
        scene: Option<String>,
        /// Brick budgets to sweep, comma-separated (default 78 down to 9 in
        /// steps of 3).
        #[arg(long)]
        budgets: Option<String>,
        /// Write an SVG chart of error against working set to this path.
        #[arg(long)]
        chart: Option<String>,
        /// Keep the central N x N voxels of each slice (default all), for a
        /// quick look.
        #[arg(long, value_parser = at_least_one::<u32>)]
        crop: Option<u32>,
    },
    /// The brick-store builder: throughput, memory bound, banded levels.
    Build {
        /// Smaller inputs, for a quick look.
        #[arg(long)]
        quick: bool,
        /// Keep the stores built.
        #[arg(long)]
        keep: bool,
        /// Inputs 16x smaller per side, for a check that the suite runs
        /// (its figures are not results).
        #[arg(long)]
        smoke: bool,
    },
    /// Store build throughput and memory from each input format (the shared
    /// format fixtures).
    Formats {
        /// The builder's memory bound, MiB (default 8).
        #[arg(long)]
        memory_mib: Option<u64>,
        /// Best of this many builds (default 3).
        #[arg(long, value_parser = at_least_one::<u64>)]
        rounds: Option<u64>,
    },
    /// What the render thread pays per frame out of core: `prepare`'s time
    /// along a moving camera path at cuts of about 1k to 50k bricks.
    Host {
        /// Viewport side in pixels (default 1024).
        #[arg(long, value_parser = image_side)]
        size: Option<u32>,
        /// Path frames timed per cut (default 60).
        #[arg(long, value_parser = at_least_one::<usize>)]
        frames: Option<usize>,
        /// Brick budgets setting the cut sizes, comma-separated (default
        /// 1000,5000,20000,50000).
        #[arg(long)]
        cuts: Option<String>,
        /// Also draw the path under ray-guided visibility.
        #[arg(long)]
        culling: bool,
        /// Viewport side of the drawn (culling) path (default 256).
        #[arg(long, value_parser = image_side)]
        culling_size: Option<u32>,
    },
    /// Out of core vs in core, output sensitivity, a camera path.
    Ooc {
        /// Image side in pixels (default 512).
        #[arg(long, value_parser = image_side)]
        size: Option<u32>,
        /// Interleaved rounds (default 3).
        #[arg(long, value_parser = at_least_one::<usize>)]
        rounds: Option<usize>,
        /// Parts to run: any of a (vs in core), b (output sensitivity), c (camera path) (default abc).
        #[arg(long, value_parser = ooc_parts)]
        parts: Option<String>,
        /// Image side of the camera path (default 256).
        #[arg(long, value_parser = image_side)]
        path_size: Option<u32>,
        /// Voxels per side of the path's procedural volume (default 65536).
        #[arg(long)]
        path_dims: Option<u64>,
        /// Frames each path view is held (default 25).
        #[arg(long)]
        path_hold: Option<usize>,
        /// GPU pool of the path, MiB (default 256).
        #[arg(long)]
        path_gpu_mib: Option<u64>,
    },
    /// Speed against accuracy: one knob at a time around the defaults on five
    /// volumes, time against error against the f64 reference, Pareto fronts
    /// charted (SVG).
    Pareto {
        /// Image side in pixels (default 512).
        #[arg(long, value_parser = image_side)]
        size: Option<u32>,
        /// Interleaved rounds (default 3).
        #[arg(long, value_parser = at_least_one::<usize>)]
        rounds: Option<usize>,
        /// Volumes, comma-separated, of ct, ct5, mri, nuclei, ml, noise (default all).
        #[arg(long)]
        scenes: Option<String>,
        /// Voxels per side of the procedural volumes (default 128).
        #[arg(long)]
        ml_side: Option<u32>,
        /// Where the CSV and the cached reference images go (default target/pareto).
        #[arg(long)]
        out: Option<String>,
        /// Where the SVG charts go (default docs/charts/pareto).
        #[arg(long)]
        charts: Option<String>,
        /// Rays per pixel side of the reference (default 2).
        #[arg(long)]
        supersample: Option<u32>,
        /// Knobs swept, comma-separated (default all; the defaults always run):
        /// step, preint, lod_geometric, lod_error, lod_visible,
        /// bricks_geometric, bricks_error, bricks_visible, bricks_octants, ert,
        /// u8_filtering,
        /// visibility,
        /// in_core.
        #[arg(long)]
        knobs: Option<String>,
        /// Interior voxels per brick side of the stores (default 32).
        #[arg(long)]
        brick: Option<u32>,
    },
    /// The isosurface prediction buffer (Braley et al.): orbits, a failure path,
    /// translation and zoom; variants interleaved frame by frame.
    Prediction {
        /// Image side in pixels (default 256).
        #[arg(long, value_parser = image_side)]
        size: Option<u32>,
        /// Frames of each orbit (default 120).
        #[arg(long, value_parser = at_least_one::<usize>)]
        frames: Option<usize>,
        /// Write the failure path's chart (SVG) here.
        #[arg(long)]
        chart: Option<String>,
        /// Write the traversal-class image (PNG) here.
        #[arg(long)]
        classes_png: Option<String>,
        /// Sparse traversal's kappa (default the paper's 0.5).
        #[arg(long)]
        kappa: Option<f32>,
        /// 1: also time full traversal without empty-space skipping (default 1).
        #[arg(long)]
        brute: Option<u32>,
        /// `incore` (default) or `ooc`: brick stores drawn out of core at the
        /// finest level.
        #[arg(long)]
        backend: Option<String>,
    },
    /// Pre-integrated DVR: table build time, frame time against the plain
    /// path (interleaved, head CT) and PSNR against the exact integral.
    Preint {
        /// Image side in pixels of the timed frames (default 256).
        #[arg(long, value_parser = image_side)]
        size: Option<u32>,
        /// Interleaved rounds (default 5).
        #[arg(long, value_parser = at_least_one::<usize>)]
        rounds: Option<usize>,
    },
    /// Per-sample cost: brickray against a minimal kernel (the device's rate), in
    /// core and out of core, DVR, shaded DVR, iso and MIP.
    Raw {
        /// Image side in pixels (default 512).
        #[arg(long, value_parser = image_side)]
        size: Option<u32>,
        /// Interleaved rounds (default 3).
        #[arg(long, value_parser = at_least_one::<usize>)]
        rounds: Option<usize>,
        /// Step in voxels (default 0.5).
        #[arg(long)]
        step: Option<f32>,
        /// Modes, comma-separated, of dvr, dvr_shaded, iso, mip (default all).
        #[arg(long)]
        modes: Option<String>,
    },
    /// Memory and frame time over a long random-camera run.
    Soak {
        /// Frames (default 10000).
        #[arg(long, value_parser = at_least_one::<usize>)]
        frames: Option<usize>,
        /// Image side in pixels (default 64).
        #[arg(long, value_parser = image_side)]
        size: Option<u32>,
    },
    /// Error-aware vs geometric level of detail at equal working sets (PSNR
    /// against the CPU reference; shared MRI and head CT, Marschner-Lobb).
    Lod {
        /// Image side in pixels (default 256).
        #[arg(long, value_parser = image_side)]
        size: Option<u32>,
        /// Scenes, comma-separated, of mri, ct, ct_iso, ml (default mri,ct,ml);
        /// with `--by oracle`, volumes of the pareto suite (ct, ct5, mri,
        /// nuclei, ml, noise; every mode of each).
        #[arg(long)]
        scenes: Option<String>,
        /// Brick side of the stores (default 32).
        #[arg(long)]
        brick: Option<u32>,
        /// Voxels per side of the procedural volumes (`ml`; with `--by
        /// oracle` also `noise`) (default 128).
        #[arg(long, value_parser = at_least_one::<u32>)]
        ml_side: Option<u32>,
        /// Visibility feedback under both rules: none (default), rayguided or
        /// occlusion.
        #[arg(long)]
        policy: Option<String>,
        /// knob (default): sweep the tolerance and the error budget on the
        /// GPU; budget: both orders under the same brick budgets, on the CPU;
        /// oracle: the geometric and visible orders against a ranking by each
        /// node's exact cost to the image, on the CPU.
        #[arg(long)]
        by: Option<String>,
        /// With `--by oracle`: on (default) costs every node; off skips the
        /// oracle order and compares the geometric and visible orders only.
        #[arg(long)]
        costs: Option<String>,
        /// With `--by oracle`: on (default) draws DVR shaded, as the pareto
        /// suite does; off unshaded.
        #[arg(long)]
        shading: Option<String>,
        /// With `--by oracle`: writes every costed node (scene, level,
        /// position, cost, per-sample expected error, visible weight) as CSV.
        #[arg(long)]
        nodes: Option<String>,
        /// With `--by oracle`: on also draws octant-granular cuts (children
        /// refined one at a time, the others drawn from the parent's brick)
        /// and the per-node order by errors measured on the data; off
        /// (default).
        #[arg(long)]
        octants: Option<String>,
    },
    /// Visibility feedback: working set, image and latency per policy along a
    /// camera path with a half turn (head CT and procedural shells).
    Visibility {
        /// Scenes, comma-separated, of head, shells (default both).
        #[arg(long)]
        scenes: Option<String>,
        /// Image side of the head CT scenes (default 256).
        #[arg(long, value_parser = image_side)]
        size: Option<u32>,
        /// Brick side of the head CT's store (default 32).
        #[arg(long)]
        head_brick: Option<u32>,
        /// Image side of the shells scene (default 512).
        #[arg(long, value_parser = image_side)]
        shell_size: Option<u32>,
        /// Voxels per side of the shells volume (default 4096).
        #[arg(long)]
        shell_dims: Option<u64>,
        /// Most frames each view is held (default 120).
        #[arg(long)]
        hold: Option<usize>,
        /// Frames of the half turn (default 12).
        #[arg(long)]
        turn: Option<usize>,
        /// Write the working-set chart (SVG) here.
        #[arg(long)]
        svg: Option<String>,
        /// GPU pool budget per renderer in MiB (default 1024).
        #[arg(long)]
        gpu_mib: Option<u64>,
        /// CPU brick cache budget per renderer in MiB (default 512).
        #[arg(long)]
        cpu_mib: Option<u64>,
        /// Only the start view: working set, oracle and image, no turn.
        #[arg(long)]
        start_only: bool,
        /// Policies, comma-separated, of rayguided, occlusion, both (none, the
        /// baseline, always runs; default all).
        #[arg(long)]
        policies: Option<String>,
    },
    /// Stability: scripted scenes that drive each method to where it breaks
    /// (streaming, memory pressure, high-frequency TF, thin structures,
    /// grazing rays, precision at 65536^3, ERT, prediction and disocclusion),
    /// against the f64 reference.
    Stability {
        /// Image side in pixels (default 128; also the volumes' side).
        #[arg(long, value_parser = image_side)]
        size: Option<u32>,
        /// Cases, comma-separated numbers 1-8 (default all).
        #[arg(long)]
        cases: Option<String>,
        /// Folder of the SVG charts (default docs/charts; empty: none).
        #[arg(long)]
        charts: Option<String>,
    },
    /// Multi-channel volumes: ms per frame of 1, 2 and 4 channels in every
    /// mode, texel bytes, error against the reference (needs
    /// ../shared/data).
    Channels {
        /// Image side in pixels of the timed frames (default 256).
        #[arg(long, value_parser = image_side)]
        size: Option<u32>,
        /// Interleaved rounds (default 5).
        #[arg(long, value_parser = at_least_one::<usize>)]
        rounds: Option<usize>,
    },
    /// Label maps: cost against intensity DVR of the same view, hidden-label
    /// skipping, error against the reference and of coarse levels (needs
    /// ../shared/data).
    Labels {
        /// Image side in pixels of the timed frames (default 256).
        #[arg(long, value_parser = image_side)]
        size: Option<u32>,
        /// Interleaved rounds (default 5).
        #[arg(long, value_parser = at_least_one::<usize>)]
        rounds: Option<usize>,
    },
    /// Streaming over HTTP with added round-trip time against the local
    /// disk: first image, convergence, bytes and requests, frame times
    /// (needs ../shared/data and python3).
    Remote {
        /// Image side in pixels of the planned frames (default 512).
        #[arg(long, value_parser = image_side)]
        size: Option<u32>,
        /// Added delays in ms, comma-separated (default 0,20,80).
        #[arg(long)]
        delays: Option<String>,
        /// Loader threads (default 8).
        #[arg(long)]
        threads: Option<usize>,
        /// Ranges this close (KiB) are fetched as one request (default 16).
        #[arg(long)]
        gap_kib: Option<u64>,
        /// Rounds of every case (default 3; each row is the median round).
        #[arg(long, value_parser = at_least_one::<usize>)]
        rounds: Option<usize>,
        /// Ray cast every frame too (whole frames; default: planned only).
        #[arg(long)]
        raycast: bool,
    },
    /// u8 volumes: exact interpolation vs 8-bit texels.
    U8 {
        /// Image side in pixels (default 512).
        #[arg(long, value_parser = image_side)]
        size: Option<u32>,
        /// Interleaved rounds (default 5).
        #[arg(long, value_parser = at_least_one::<usize>)]
        rounds: Option<usize>,
    },
}

fn main() -> ExitCode {
    let cli = <Cli as clap::Parser>::parse();
    let args: Vec<String> = std::env::args().skip(1).collect();
    let suite = args.first().map(String::as_str).unwrap_or("");
    let rest = &args[args.len().min(1)..];
    let result: Result<Figures, String> = match cli.suite {
        Suite::Accel { .. } => accel::run(rest),
        Suite::Aniso { .. } => aniso::run(rest),
        Suite::Build { .. } => build::run(rest),
        Suite::Formats { .. } => formats::run(rest),
        Suite::Ooc { .. } => ooc::run(rest),
        Suite::Pareto { .. } => pareto::run(rest),
        Suite::Prediction { .. } => prediction::run(rest),
        Suite::Preint { .. } => preint::run(rest),
        Suite::Raw { .. } => raw::run(rest),
        Suite::Soak { .. } => soak::run(rest),
        Suite::Host { .. } => host::run(rest),
        Suite::Stability { .. } => stability::run(rest),
        Suite::U8 { .. } => u8::run(rest),
        Suite::Labels { .. } => labels::run(rest),
        Suite::Channels { size, rounds } => channels::run(size.unwrap_or(256), rounds.unwrap_or(5)),
        Suite::Remote { .. } => remote::run(rest),
        Suite::Lod { .. } => lod::run(rest),
        Suite::Visibility { .. } => visibility::run(rest),
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
