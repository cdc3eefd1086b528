//! `brickray-store`: build a brick octree store from a volume, or describe one.
//!
//! ```text
//! brickray-store build <input | OME-Zarr URL> <out.brs> [--brick N] [--apron N]
//!                      [--filter average|max|mode] [--empty-below V] [--memory-mib N]
//!                      [--series UID|N] [--level N] [--channel N] [--time N]
//!                      [--spacing X,Y,Z] [--allow-outside-dir] [--quiet]
//!                      [--anisotropic] [--labels] [--spread]
//!                      [--allow-http] [--anonymous] [--endpoint URL]
//! brickray-store build <input> <NAME.channels.json> [--channels 0,2,...] [build options]
//! brickray-store info <store.brs | NAME.channels.json | URL | input> [--bins N]
//!                     [--allow-http] [--anonymous] [--endpoint URL]
//! brickray-store convert <input> <out.json> [--memory-mib N] [--quiet] [selection as for build]
//! ```
//!
//! An input is any format `brickray_io::open` reads: raw + JSON, NRRD, NIfTI,
//! TIFF (a stack or a folder of slices), DICOM (a folder) or OME-Zarr. `info`
//! on an input lists its series, levels, channels and time points. `info`
//! also reads a store over S3, GCS, Azure or HTTP(S) (`s3://bucket/key`,
//! `https://host/store.brs`; feature `remote`, on by default), configured
//! by the usual environment variables (`AWS_*`, see docs/remote.md), and
//! `build` reads an OME-Zarr image from such a URL. A `build` whose output
//! ends in `.channels.json` builds every channel of a multi-channel input
//! (at most 4, or those `--channels` lists) into a store of its own
//! (`NAME.cC.brs` beside it) and records them in that channel set, which
//! the library opens as one multi-channel volume
//! (`brickray_store::open_channels`).
//!
//! On a signal that would end it and that a process may catch (SIGHUP,
//! SIGINT, SIGQUIT, SIGTERM, SIGUSR1, SIGUSR2, SIGALRM, SIGXCPU, SIGXFSZ) a
//! build removes its temporary files, then dies of the signal. Over the file
//! size limit (SIGXFSZ caught) the write fails instead, and the build removes
//! its temporaries as on any error.

use brickray_core::{BrickSource, NodeKind};
use brickray_io::ReadOptions;
use brickray_store::{BuildOptions, Filter, Store, StoreError};
use clap::{Parser, Subcommand};
use rayon::prelude::*;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};

mod info;
use info::{cmd_info, cmd_info_channels, cmd_info_input, info_zarr_url};

/// Build a brick octree store from a volume, or describe one.
#[derive(Debug, Parser)]
#[command(name = "brickray-store", version)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Build a store from a volume in any format brickray reads.
    Build {
        /// The input volume: .json / .raw + sidecar, .nrrd / .nhdr, .nii /
        /// .nii.gz / .hdr, .tif (or a folder of slices), a DICOM folder, an
        /// OME-Zarr folder, or an OME-Zarr image's URL (s3://, gs://, az://,
        /// https://; feature `remote`).
        input: PathBuf,
        /// The store to write (by convention `.brs`), or a channel set
        /// (`NAME.channels.json`: one store per channel beside it).
        output: PathBuf,
        /// Interior voxels per brick side.
        #[arg(long, default_value_t = 32)]
        brick: u32,
        /// Apron voxels on each side of a brick.
        #[arg(long, default_value_t = 2)]
        apron: u32,
        /// Filter of inner nodes: `average` (intensities), `max`, or `mode`
        /// (label maps are always filtered by the mode).
        #[arg(long, default_value = "average", value_parser = parse_filter)]
        filter: Filter,
        /// Store nodes whose values all lie below this raw value as empty
        /// (negative values are accepted: `--empty-below -500`).
        #[arg(long, allow_negative_numbers = true)]
        empty_below: Option<f32>,
        /// Upper bound on the builder's memory, in MiB.
        #[arg(long, default_value_t = 1024,
              value_parser = clap::value_parser!(u64).range(1..=MAX_MEMORY_MIB))]
        memory_mib: u64,
        #[command(flatten)]
        select: Select,
        /// No progress bar.
        #[arg(long)]
        quiet: bool,
        /// Build an anisotropic pyramid: coarser levels first halve only the
        /// axes with the finer voxel sides (docs/store-format.md).
        #[arg(long)]
        anisotropic: bool,
        /// The input is a label map (u8, u16 or u32 ids; docs/labels.md):
        /// coarser levels take the most frequent label of their children
        /// and the store records it. A sidecar with `"kind": "labels"` or a
        /// `labels` list says so itself.
        #[arg(long)]
        labels: bool,
        /// Record each coarse voxel's spread (the standard deviation of the
        /// finest voxels it stands for), with which the renderers classify
        /// coarse levels (docs/store-format.md, format version 7). Intensity
        /// volumes with the average filter, built in one streaming pass.
        #[arg(long)]
        spread: bool,
        #[command(flatten)]
        remote: RemoteArgs,
    },
    /// Write any input as raw samples + a JSON sidecar (`<out>.json` and
    /// `<out>.raw`), streamed within the memory bound.
    Convert {
        /// The input volume (as for `build`).
        input: PathBuf,
        /// The sidecar to write; the raw file goes beside it.
        output: PathBuf,
        /// Upper bound on the slab buffer, in MiB.
        #[arg(long, default_value_t = 256,
              value_parser = clap::value_parser!(u64).range(1..=MAX_MEMORY_MIB))]
        memory_mib: u64,
        #[command(flatten)]
        select: Select,
        /// No progress bar.
        #[arg(long)]
        quiet: bool,
    },
    /// Describe a store (placement, levels, bricks, empty and uniform
    /// fractions, compression, value histogram) or an input volume (format,
    /// size, placement, and its series, levels, channels and time points).
    Info {
        /// The store, or an input volume.
        store: PathBuf,
        #[command(flatten)]
        select: Select,
        /// Histogram bins.
        #[arg(long, default_value_t = 16)]
        bins: usize,
        #[command(flatten)]
        remote: RemoteArgs,
    },
}

/// How to reach a store named by a URL.
#[derive(Debug, clap::Args)]
struct RemoteArgs {
    /// Allow a plain `http://` URL or endpoint (also `AWS_ALLOW_HTTP=true`).
    #[arg(long)]
    allow_http: bool,
    /// Unsigned requests, for a public bucket (also `AWS_SKIP_SIGNATURE=true`).
    #[arg(long)]
    anonymous: bool,
    /// An S3-compatible endpoint (also `AWS_ENDPOINT_URL`).
    #[arg(long)]
    endpoint: Option<String>,
}

/// The remote options: the environment's, then the flags.
#[cfg(feature = "remote")]
fn remote_options(remote: &RemoteArgs) -> brickray_store::remote::RemoteOptions {
    let mut o = brickray_store::remote::RemoteOptions::from_env();
    o.allow_http |= remote.allow_http;
    o.anonymous |= remote.anonymous;
    if remote.endpoint.is_some() {
        o.endpoint.clone_from(&remote.endpoint);
    }
    o
}

/// Opens a store from a local path or (feature `remote`) a URL.
fn open_store(store: &std::path::Path, remote: &RemoteArgs) -> Result<Store, String> {
    let name = store.to_string_lossy();
    if looks_like_url(&name) {
        #[cfg(feature = "remote")]
        {
            let o = remote_options(remote);
            return brickray_store::open_url(&name, &o).map_err(|e| e.to_string());
        }
        #[cfg(not(feature = "remote"))]
        {
            let _ = remote;
            return Err(format!(
                "{name}: this brickray-store was built without the `remote` feature \
                 (cargo install with --features remote)"
            ));
        }
    }
    Store::open(store).map_err(|e| e.to_string())
}

/// A scheme before `://` (a URL rather than a path).
fn looks_like_url(s: &str) -> bool {
    s.split_once("://").is_some_and(|(scheme, _)| {
        scheme.len() > 1
            && scheme
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "+-.".contains(c))
    })
}

/// What to read from an input, and how.
#[derive(Debug, clap::Args)]
struct Select {
    /// DICOM: the series to read (its SeriesInstanceUID, or its number in
    /// `info`'s list); default: the one with the most slices.
    #[arg(long)]
    series: Option<String>,
    /// OME-Zarr: the multiscale level (0 = finest).
    #[arg(long)]
    level: Option<usize>,
    /// The channel (OME-Zarr, multi-channel TIFF); default 0.
    #[arg(long)]
    channel: Option<u64>,
    /// The channels of a channel set's build, `0,2,3` (default: every
    /// channel, at most 4).
    #[arg(long, value_delimiter = ',')]
    channels: Option<Vec<u64>>,
    /// The time point (OME-Zarr, TIFF, 4D NIfTI); default 0.
    #[arg(long)]
    time: Option<u64>,
    /// Voxel spacing `x,y,z` for inputs that state none (a plain TIFF).
    #[arg(long, value_parser = parse_spacing)]
    spacing: Option<[f32; 3]>,
    /// Let the sidecar's `file`, the NRRD `data file` or a NIfTI `.img` name a
    /// file outside the header's folder (absolute paths, `..`, links leading
    /// out).
    #[arg(long)]
    allow_outside_dir: bool,
}

impl Select {
    fn options(&self) -> ReadOptions {
        ReadOptions::default()
            .allow_outside_dir(self.allow_outside_dir)
            .series(self.series.clone())
            .level(self.level)
            .channel(self.channel)
            .channels(self.channels.clone())
            .time(self.time)
            .spacing(self.spacing)
    }
}

fn parse_spacing(v: &str) -> Result<[f32; 3], String> {
    let p: Vec<f32> = v
        .split(',')
        .map(|t| t.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|e| format!("{v:?}: {e}"))?;
    match p.as_slice() {
        [x, y, z] if p.iter().all(|s| s.is_finite() && *s > 0.0) => Ok([*x, *y, *z]),
        _ => Err(format!("expected three positive numbers x,y,z, got {v:?}")),
    }
}

/// Set by the signal thread before it removes the build's temporaries.
static INTERRUPTED: AtomicBool = AtomicBool::new(false);

/// The largest `--memory-mib` whose byte count fits in a u64.
const MAX_MEMORY_MIB: u64 = u64::MAX >> 20;

fn parse_filter(v: &str) -> Result<Filter, String> {
    Filter::parse(v).ok_or_else(|| format!("expected average or max, got {v:?}"))
}

/// Ends the process quietly when stdout is closed early (`brickray-store
/// info store.brs | head`), as a shell tool does on SIGPIPE; any other
/// panic keeps the default report.
fn quiet_on_closed_stdout() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let msg = info
            .payload()
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| info.payload().downcast_ref::<&str>().copied())
            .unwrap_or("");
        if msg.contains("failed printing to stdout") && msg.contains("Broken pipe") {
            std::process::exit(141);
        }
        default(info);
    }));
}

fn main() -> ExitCode {
    quiet_on_closed_stdout();
    let r = match Cli::parse().command {
        Command::Build {
            input,
            output,
            brick,
            apron,
            filter,
            empty_below,
            memory_mib,
            select,
            quiet,
            anisotropic,
            labels,
            spread,
            remote,
        } => remove_temporaries_on_signals().and_then(|()| {
            let memory_bound = memory_mib.checked_mul(1 << 20).ok_or_else(|| {
                StoreError::BadOption {
                    option: "memory-mib",
                    reason: format!("{memory_mib} MiB does not fit in 64 bits of bytes"),
                }
                .to_string()
            })?;
            let o = BuildOptions {
                brick,
                apron,
                filter,
                empty_below,
                memory_bound,
                progress: (!quiet).then(progress_bar),
                anisotropic,
                spread,
            };
            cmd_build(&input, &output, &o, &select.options(), labels, &remote)
        }),
        Command::Convert {
            input,
            output,
            memory_mib,
            select,
            quiet,
        } => cmd_convert(
            &input,
            &output,
            memory_mib << 20,
            &select.options(),
            (!quiet).then(progress_bar).as_ref(),
        ),
        Command::Info {
            store,
            bins,
            select,
            remote,
        } => {
            // A URL is a store; a path a volume format claims is an input;
            // anything else a store.
            if brickray_store::is_channel_set(&store) {
                cmd_info_channels(&store, bins.clamp(1, 4096))
            } else if !looks_like_url(&store.to_string_lossy())
                && brickray_io::Registry::global().find(&store).is_ok()
            {
                cmd_info_input(&store, &select.options())
            } else if let Some(r) = info_zarr_url(&store, &remote, &select.options()) {
                r
            } else {
                open_store(&store, &remote).and_then(|s| cmd_info(&s, bins.clamp(1, 4096)))
            }
        }
    };
    match r {
        Ok(()) => ExitCode::SUCCESS,
        // The build failed because a signal removed its files: the signal
        // thread ends the process (with the signal's status); wait for it.
        Err(_) if INTERRUPTED.load(Ordering::SeqCst) => loop {
            std::thread::park();
        },
        Err(e) => {
            eprintln!("brickray-store: {e}");
            ExitCode::FAILURE
        }
    }
}

/// On every signal that ends a process by default and that it may catch:
/// remove the temporary files of the build in progress, then die of the
/// signal (as without a handler). A signal that the process was started with
/// ignored (`nohup`, a background job of a non-interactive shell) stays
/// ignored. (SIGKILL cannot be caught, nor a crash handled safely: the next
/// build into the folder removes what they leave.)
fn remove_temporaries_on_signals() -> Result<(), String> {
    use signal_hook::consts::{
        SIGALRM, SIGHUP, SIGINT, SIGQUIT, SIGTERM, SIGUSR1, SIGUSR2, SIGXCPU, SIGXFSZ,
    };
    let ignored = brickray_store::ignored_signals();
    let wanted: Vec<i32> = [
        SIGINT, SIGTERM, SIGHUP, SIGQUIT, SIGUSR1, SIGUSR2, SIGALRM, SIGXCPU, SIGXFSZ,
    ]
    .into_iter()
    .filter(|&s| ignored & (1u64 << (s - 1)) == 0)
    .collect();
    let mut signals = signal_hook::iterator::Signals::new(wanted)
        .map_err(|e| format!("cannot install signal handlers: {e}"))?;
    std::thread::spawn(move || {
        if let Some(sig) = signals.forever().next() {
            INTERRUPTED.store(true, Ordering::SeqCst);
            let n = brickray_store::remove_partial_files();
            eprintln!("brickray-store: interrupted (signal {sig}); removed {n} temporary file(s)");
            let _ = signal_hook::low_level::emulate_default_handler(sig);
            std::process::exit(128 + sig);
        }
    });
    Ok(())
}

/// A progress bar on stderr, drawn from a build's or a conversion's
/// progress reports.
fn progress_bar() -> brickray_store::BuildProgress {
    let pb = indicatif::ProgressBar::new(0);
    pb.set_style(
        indicatif::ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {wide_bar} {percent}% {human_pos}/{human_len} voxels, \
             {rate}, {eta} left",
        )
        .map(|s| {
            s.with_key(
                "rate",
                |st: &indicatif::ProgressState, w: &mut dyn std::fmt::Write| {
                    let _ = write!(w, "{:.1} Mvoxel/s", st.per_sec() / 1e6);
                },
            )
        })
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    brickray_store::BuildProgress(std::sync::Arc::new(move |done, total| {
        pb.set_length(total);
        pb.set_position(done);
        if done >= total {
            pb.finish_and_clear();
        }
    }))
}

fn cmd_build(
    input: &std::path::Path,
    out: &std::path::Path,
    o: &BuildOptions,
    read: &ReadOptions,
    labels: bool,
    remote: &RemoteArgs,
) -> Result<(), String> {
    let output = out.display();
    if brickray_store::is_channel_set(out) {
        if looks_like_url(&input.to_string_lossy()) {
            return Err(format!(
                "{}: a channel set is built from a local input (stream a remote \
                 OME-Zarr image's channels as they are: brickray_store::open_zarr_channels_url)",
                input.display()
            ));
        }
        let _ = (labels, remote);
        let readers = brickray_io::open_channels(input, read)
            .map_err(|e| StoreError::Input(e).to_string())?;
        let n = readers.readers.len();
        let reports = brickray_store::build_channels(readers, out, o).map_err(|e| e.to_string())?;
        let bytes: u64 = reports.iter().map(|r| r.file_bytes).sum();
        let seconds: f64 = reports.iter().map(|r| r.seconds).sum();
        println!(
            "built {output}: {n} channels, one store each ({}), {:.1} MiB in {seconds:.2} s",
            (0..n)
                .map(|c| brickray_store::channel_store_path(out, c as u64)
                    .file_name()
                    .map(|f| f.to_string_lossy().into_owned())
                    .unwrap_or_default())
                .collect::<Vec<_>>()
                .join(", "),
            bytes as f64 / (1 << 20) as f64
        );
        return Ok(());
    }
    let mut reader = open_input(input, read, remote)?;
    if labels && !reader.desc().kind.is_labels() {
        reader = Box::new(
            brickray_io::AsLabels::new(reader).map_err(|e| StoreError::Input(e).to_string())?,
        );
    }
    if o.progress.is_some() {
        for n in reader.notes() {
            eprintln!("{}: {n}", reader.format());
        }
    }
    print_warnings(reader.as_ref());
    let r = brickray_store::build(reader.as_mut(), out, o).map_err(|e| e.to_string())?;
    println!(
        "built {output}: {} levels, {} nodes ({} data, {} uniform, {} empty), {:.1} MiB from {:.1} MiB in {:.2} s ({:.1} Mvoxel/s)",
        r.layout.levels,
        r.nodes,
        r.data_nodes,
        r.uniform_nodes,
        r.empty_nodes,
        r.file_bytes as f64 / (1 << 20) as f64,
        r.input_bytes as f64 / (1 << 20) as f64,
        r.seconds,
        r.input_voxels as f64 / r.seconds / 1e6
    );
    if r.spread {
        println!(
            "spreads     recorded: {:.2} MiB of spread payload",
            r.spread_bytes as f64 / (1 << 20) as f64
        );
    }
    Ok(())
}

/// The input of `build`: a file or folder, or an OME-Zarr image's URL.
fn open_input(
    input: &std::path::Path,
    read: &ReadOptions,
    remote: &RemoteArgs,
) -> Result<Box<dyn brickray_io::VolumeReader>, String> {
    let name = input.to_string_lossy();
    if !looks_like_url(&name) {
        let _ = remote;
        return brickray_io::open_with(input, read).map_err(|e| StoreError::Input(e).to_string());
    }
    #[cfg(feature = "remote")]
    {
        let o = remote_options(remote);
        if !brickray_store::is_zarr_url(&name, &o) {
            return Err(format!(
                "{name}: a store URL is already a store (`info` and the viewer read it \
                 as it is); `build` takes an OME-Zarr image's URL"
            ));
        }
        let r = brickray_store::open_zarr_reader_url(&name, &o, read).map_err(|e| e.to_string())?;
        Ok(Box::new(r))
    }
    #[cfg(not(feature = "remote"))]
    Err(format!(
        "{name}: this brickray-store was built without the `remote` feature \
         (cargo install with --features remote)"
    ))
}

/// What the reader assumed where the input did not say, on stderr.
fn print_warnings(reader: &dyn brickray_io::VolumeReader) {
    for w in reader.warnings() {
        eprintln!("warning: {}: {w}", reader.format());
    }
}

fn cmd_convert(
    input: &std::path::Path,
    out: &std::path::Path,
    memory_bound: u64,
    read: &ReadOptions,
    progress: Option<&brickray_store::BuildProgress>,
) -> Result<(), String> {
    let mut reader =
        brickray_io::open_with(input, read).map_err(|e| StoreError::Input(e).to_string())?;
    print_warnings(reader.as_ref());
    let r = brickray_store::convert_with_progress(reader.as_mut(), out, memory_bound, progress)
        .map_err(|e| e.to_string())?;
    println!(
        "converted {} ({}) to {} + {}: {:.1} MiB in {:.2} s, slabs of {} slices",
        input.display(),
        reader.format(),
        r.json.display(),
        r.raw.display(),
        r.bytes as f64 / (1 << 20) as f64,
        r.seconds,
        r.slab
    );
    Ok(())
}
