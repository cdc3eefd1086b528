//! Opening volumes in the background: raw+JSON and NRRD files (loaded whole
//! when small, built into a brick store with progress when large), brick
//! stores, and procedural volumes; an input of several channels is read
//! whole with every channel (`brickray::io::read_channels`, drawn in core)
//! or, too large for memory, streamed (an OME-Zarr image's channels as they
//! are, other files built into one store per channel). GPU-free: the result
//! is handed to the renderer by the app.

use crate::tf::Histogram;
use brickray::core::channels::MAX_CHANNELS;
use brickray::io::{ChannelInfo, IoError, ReadOptions, VolumeReader};
use brickray::{
    BrickSource, ChannelSource, ChannelStyle, ChannelVolume, NodeKey, Volume, VolumeDesc,
};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, mpsc};

use brickray::store::EXTENSION as STORE_EXTENSION;
/// Bins of the histograms.
const HISTOGRAM_BINS: usize = 256;

/// What to open.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Input {
    /// A volume file or a brick store.
    Path(PathBuf),
    /// A procedural fractal-noise volume of `n^3` voxels (never stored).
    Procedural(u64),
    /// A procedural Mandelbulb of `n^3` voxels (never stored).
    Bulb(u64),
}

impl Input {
    /// Parses a command-line or script argument: `procedural[:N]`,
    /// `bulb[:N]` or a path.
    pub(crate) fn parse(s: &str) -> Result<Input, OpenError> {
        let sized = |name: &str, rest: &str, make: fn(u64) -> Input| match rest {
            "" => Ok(make(4096)),
            _ => rest
                .strip_prefix(':')
                .and_then(|n| n.parse().ok())
                .filter(|&n| (1..=1 << 24).contains(&n))
                .map(make)
                .ok_or_else(|| {
                    OpenError::BadInput(format!("{s}: expected {name}:N, N in 1..=16777216"))
                }),
        };
        if let Some(rest) = s.strip_prefix("procedural") {
            sized("procedural", rest, Input::Procedural)
        } else if let Some(rest) = s.strip_prefix("bulb") {
            sized("bulb", rest, Input::Bulb)
        } else {
            Ok(Input::Path(s.into()))
        }
    }

    /// A short name for titles and messages.
    pub(crate) fn name(&self) -> String {
        match self {
            Input::Path(p) => p.display().to_string(),
            Input::Procedural(n) => format!("procedural {n}^3"),
            Input::Bulb(n) => format!("Mandelbulb {n}^3"),
        }
    }
}

/// Why a volume could not be opened.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub(crate) enum OpenError {
    /// The argument names nothing openable.
    #[error("{0}")]
    BadInput(String),
    /// Reading the volume file failed.
    #[error(transparent)]
    Io(#[from] IoError),
    /// Building or opening the brick store failed.
    #[error(transparent)]
    Store(#[from] brickray::store::StoreError),
    /// Reading a brick for the histogram failed.
    #[error(transparent)]
    Brick(#[from] brickray::core::BrickError),
    /// The loader thread stopped without an answer.
    #[error("the loader thread stopped: {0}")]
    Thread(String),
}

/// An opened volume, ready for the renderer.
pub(crate) enum Opened {
    /// Small enough to upload whole (the in-core path).
    InCore(Volume),
    /// Streamed out of core from a brick source.
    Streamed(Arc<dyn BrickSource>),
    /// 2 to 4 channels of one grid: read whole (`brickray::io::read_channels`)
    /// or streamed as one `ChannelSource`.
    Channels(Box<OpenedChannels>),
}

/// A multi-channel volume's data: in core, or streamed.
pub(crate) enum ChannelData {
    /// Read whole, drawn from one packed 3D texture.
    InCore(ChannelVolume),
    /// Too large for memory: the channels' sources (one per channel: an
    /// OME-Zarr image's channels, or one brick store per channel) streamed
    /// together out of core.
    Streamed(Arc<ChannelSource>),
}

impl ChannelData {
    /// Channels.
    pub(crate) fn len(&self) -> usize {
        match self {
            ChannelData::InCore(v) => v.len(),
            ChannelData::Streamed(s) => s.len(),
        }
    }

    /// Each channel's raw value range.
    pub(crate) fn ranges(&self) -> Vec<[f32; 2]> {
        match self {
            ChannelData::InCore(v) => v.channels().iter().map(|c| c.desc().value_range).collect(),
            ChannelData::Streamed(s) => s.layout().channel_ranges().to_vec(),
        }
    }
}

/// A multi-channel input: its channels, what the file says of each and the
/// file's default style of each (`ReadChannels::styles`).
pub(crate) struct OpenedChannels {
    /// The channels (one grid and dtype; each its own value range).
    pub(crate) data: ChannelData,
    /// What the file says of each channel (label, colour, window, active).
    pub(crate) info: Vec<ChannelInfo>,
    /// The file's default classification of each channel.
    pub(crate) styles: Vec<ChannelStyle>,
    /// Each channel's histogram of its normalized values.
    pub(crate) histograms: Vec<Histogram>,
}

impl std::fmt::Debug for Opened {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Opened::InCore(v) => f.debug_tuple("InCore").field(&v.desc()).finish(),
            Opened::Streamed(s) => f.debug_tuple("Streamed").field(s.layout()).finish(),
            Opened::Channels(c) => f
                .debug_tuple("Channels")
                .field(&c.data.len())
                .field(&c.data.ranges())
                .finish(),
        }
    }
}

/// What the loader hands back.
#[derive(Debug)]
pub(crate) struct Loaded {
    /// What was opened.
    pub(crate) input: Input,
    /// The volume's description (dims, dtype, spacing, value range).
    pub(crate) desc: VolumeDesc,
    /// The data.
    pub(crate) volume: Opened,
    /// Histogram of normalized values (whole volume in core; a coarse level
    /// when streamed).
    pub(crate) histogram: Histogram,
    /// One line on how it was opened.
    pub(crate) note: String,
    /// Where the file places the volume (its anatomical orientation when
    /// the placement is in patient space).
    pub(crate) placement: Option<brickray::io::Placement>,
}

/// Progress of a background open, shared with the UI thread.
#[derive(Debug, Default)]
pub(crate) struct Progress {
    /// Work done (bytes of input read).
    done: AtomicU64,
    /// Total work (bytes), 0 while unknown.
    total: AtomicU64,
    /// What is being done now.
    stage: Mutex<String>,
}

impl Progress {
    /// Sets what is being done now.
    fn set_stage(&self, s: impl Into<String>) {
        if let Ok(mut g) = self.stage.lock() {
            *g = s.into();
        }
    }

    /// What is being done now.
    pub(crate) fn stage(&self) -> String {
        self.stage.lock().map(|g| g.clone()).unwrap_or_default()
    }

    /// Done as a fraction (0 while the total is unknown).
    pub(crate) fn fraction(&self) -> f32 {
        let total = self.total.load(Ordering::Relaxed);
        if total == 0 {
            0.0
        } else {
            (self.done.load(Ordering::Relaxed) as f64 / total as f64).min(1.0) as f32
        }
    }
}

/// Where and how to open.
#[derive(Debug, Clone)]
pub(crate) struct OpenOptions {
    /// Volume files up to this many bytes are loaded whole; larger ones are
    /// built into a brick store.
    pub(crate) in_core_max_bytes: u64,
    /// Largest side the device's 3D textures accept (larger volumes stream).
    pub(crate) max_3d_side: u32,
    /// Where built stores go.
    pub(crate) store_dir: PathBuf,
    /// Open files as label maps (`--labels`; a sidecar or store that says
    /// so is one anyway).
    pub(crate) labels: bool,
    /// Stores built from large files record spreads (`--spread`).
    pub(crate) spread: bool,
}

/// A background open in progress.
#[derive(Debug)]
pub(crate) struct Opening {
    /// Its progress.
    pub(crate) progress: Arc<Progress>,
    /// What is being opened.
    pub(crate) input: Input,
    rx: mpsc::Receiver<Result<Loaded, OpenError>>,
}

impl Opening {
    /// Starts opening `input` on a thread.
    pub(crate) fn start(input: Input, opts: OpenOptions) -> Opening {
        let progress = Arc::new(Progress::default());
        let (tx, rx) = mpsc::channel();
        let (p, i, tx2) = (progress.clone(), input.clone(), tx.clone());
        let spawned = std::thread::Builder::new()
            .name("brickray-viewer open".into())
            .spawn(move || {
                let _ = tx.send(open(&i, &opts, &p));
            });
        if let Err(e) = spawned {
            let _ = tx2.send(Err(OpenError::Thread(e.to_string())));
        }
        Opening {
            progress,
            input,
            rx,
        }
    }

    /// The result once the thread is done.
    pub(crate) fn poll(&self) -> Option<Result<Loaded, OpenError>> {
        match self.rx.try_recv() {
            Ok(r) => Some(r),
            Err(mpsc::TryRecvError::Empty) => None,
            Err(mpsc::TryRecvError::Disconnected) => {
                Some(Err(OpenError::Thread("no result".into())))
            }
        }
    }
}

/// Opens `input` (blocking; run on a thread).
pub(crate) fn open(
    input: &Input,
    opts: &OpenOptions,
    progress: &Progress,
) -> Result<Loaded, OpenError> {
    match input {
        Input::Procedural(n) | Input::Bulb(n) => {
            progress.set_stage("generating the histogram");
            let (source, what): (Arc<dyn BrickSource>, _) = match input {
                Input::Bulb(_) => (
                    Arc::new(brickray::store::MandelbulbSource::new(*n, 32, 2)?),
                    "Mandelbulb",
                ),
                _ => (
                    Arc::new(brickray::store::ProceduralSource::fractal_noise(
                        [*n; 3], 32, 2,
                    )?),
                    "fractal noise",
                ),
            };
            let desc = source.layout().volume.clone();
            let histogram = source_histogram(&*source)?;
            let note = format!(
                "procedural {what} {n}^3 u8 ({:.1} GiB virtual), computed on demand",
                (*n as f64).powi(3) / (1u64 << 30) as f64
            );
            Ok(Loaded {
                input: input.clone(),
                desc,
                volume: Opened::Streamed(source),
                histogram,
                note,
                placement: None,
            })
        }
        Input::Path(path) => {
            let ext = path
                .extension()
                .and_then(|e| e.to_str())
                .unwrap_or("")
                .to_ascii_lowercase();
            if ext == STORE_EXTENSION {
                progress.set_stage("opening the brick store");
                return open_store(input, path, "brick store".into());
            }
            if brickray::store::is_channel_set(path) {
                progress.set_stage("opening the channel set");
                let set = brickray::store::open_channels(path)?;
                let indices: Vec<u64> = (0..set.info.len() as u64).collect();
                let placement = brickray::store::open(&set.stores[0])?.placement();
                return streamed_channels(
                    input,
                    Arc::new(set.source),
                    set.info,
                    &indices,
                    None,
                    placement,
                    format!("streamed from the channel set {}", path.display()),
                );
            }
            // An OME-Zarr image over the network streams as it is (no store
            // is built from it).
            #[cfg(feature = "remote")]
            {
                let s = path.to_string_lossy();
                if brickray::remote::is_url(&s) {
                    let o = brickray::remote::RemoteOptions::from_env();
                    if brickray::store::is_zarr_url(&s, &o) {
                        progress.set_stage("opening the OME-Zarr image");
                        // A multi-channel image that fits in core is read
                        // whole, every channel at the finest level that
                        // fits; otherwise its first channel streams.
                        if !opts.labels
                            && let Some(loaded) = url_channels(input, &s, &o, opts, progress)?
                        {
                            return Ok(loaded);
                        }
                        let d = brickray::store::BuildOptions::default();
                        let src = brickray::store::open_zarr_url(
                            &s,
                            &o,
                            &brickray::io::ReadOptions::default(),
                            d.brick,
                            d.apron,
                        )?;
                        let warned = warning_note(&src.warnings());
                        let placement = Some(src.placement());
                        let source: Arc<dyn BrickSource> = Arc::new(src);
                        let desc = source.layout().volume.clone();
                        let histogram = source_histogram(&*source)?;
                        let note = format!(
                            "{:?} {} streamed from the OME-Zarr image {s}{warned}",
                            desc.dims,
                            desc.dtype.name()
                        );
                        return Ok(Loaded {
                            input: input.clone(),
                            desc,
                            volume: Opened::Streamed(source),
                            histogram,
                            note,
                            placement,
                        });
                    }
                }
            }
            // A multi-channel input is read whole with every channel; a
            // one-channel input goes on with the reader the probe opened.
            let mut reader = match probe_channels(path, opts)? {
                Probe::Channels(opened, too_many) => {
                    return read_channels(input, path, opts, progress, opened, too_many);
                }
                Probe::One(reader) => reader,
                Probe::Plain => brickray::io::open(path)?,
            };
            if opts.labels && !reader.desc().kind.is_labels() {
                reader = Box::new(brickray::io::AsLabels::new(reader)?);
            }
            // What the reader assumed where the file did not say, shown with
            // the volume's note.
            let warned = warning_note(&reader.warnings());
            let placement = reader.placement();
            let desc = reader.desc().clone();
            let bytes = desc.byte_len();
            progress.total.store(bytes, Ordering::Relaxed);
            let small =
                bytes <= opts.in_core_max_bytes && desc.dims.iter().all(|&d| d <= opts.max_3d_side);
            if small {
                progress.set_stage("reading the volume");
                let mut volume = read_with_progress(reader.as_mut(), progress)?;
                // Label ids beyond the table are renumbered (in core only).
                let mut renumbered = String::new();
                if volume.desc().kind.is_labels()
                    && volume
                        .data()
                        .min_max()
                        .is_some_and(|(_, hi)| hi as usize >= brickray::core::LABEL_TABLE_ENTRIES)
                {
                    let (v, ids) = brickray::core::labels::relabel_dense(&volume)
                        .map_err(|e| OpenError::BadInput(e.to_string()))?;
                    volume = v;
                    renumbered = format!("; {} labels renumbered 0..{}", ids.len(), ids.len());
                }
                let mut histogram = Histogram::new(HISTOGRAM_BINS);
                let d = volume.desc().clone();
                for i in 0..volume.data().len() {
                    histogram.add(d.normalize(volume.data().get(i)));
                }
                let note = format!(
                    "{:?} {}{} loaded whole ({:.1} MiB){renumbered}{warned}",
                    d.dims,
                    d.dtype.name(),
                    if d.kind.is_labels() { " labels" } else { "" },
                    bytes as f64 / (1 << 20) as f64
                );
                return Ok(Loaded {
                    input: input.clone(),
                    desc: d,
                    volume: Opened::InCore(volume),
                    histogram,
                    note,
                    placement,
                });
            }
            // Large: build a brick store once (reused while newer than the input).
            let stem = path
                .file_stem()
                .and_then(|s| s.to_str())
                .unwrap_or("volume");
            let store = opts.store_dir.join(format!("{stem}.{STORE_EXTENSION}"));
            // A store built before stores kept placements (format 6) is
            // built again when the file has one.
            // Likewise a store without spreads when they are asked for.
            let spread = opts.spread && !reader.desc().kind.is_labels();
            let fresh = newer(&store, &reader.input_files())
                && brickray::store::open(&store).is_ok_and(|s| {
                    (placement.is_none() || s.placement().is_some()) && (!spread || s.has_spread())
                });
            if !fresh {
                progress.set_stage(format!("building the brick store {}", store.display()));
                std::fs::create_dir_all(&opts.store_dir).map_err(|e| {
                    OpenError::BadInput(format!("{}: {e}", opts.store_dir.display()))
                })?;
                let mut counting = Counting {
                    inner: reader.as_mut(),
                    progress,
                };
                let build = brickray::store::BuildOptions {
                    spread,
                    ..Default::default()
                };
                brickray::store::build(&mut counting, &store, &build)?;
            }
            let how = if fresh { "reused" } else { "built" };
            open_store(
                input,
                &store,
                format!("{how} brick store {}{warned}", store.display()),
            )
        }
    }
}

/// The reader's warnings as a suffix of a note (empty without any).
fn warning_note(warnings: &[String]) -> String {
    if warnings.is_empty() {
        String::new()
    } else {
        format!("; warning: {}", warnings.join("; "))
    }
}

/// True when `out` exists and is newer than every input.
fn newer(out: &Path, inputs: &[PathBuf]) -> bool {
    let modified = |p: &Path| std::fs::metadata(p).and_then(|m| m.modified()).ok();
    let Some(t) = modified(out) else { return false };
    inputs.iter().all(|i| modified(i).is_some_and(|ti| ti <= t))
}

/// Opens a store at a local path, or (feature `remote`) at a URL
/// (`s3://…`, `gs://…`, `az://…`, `https://…`), configured by the
/// environment (docs/remote.md).
fn open_store_at(path: &Path) -> Result<brickray::store::Store, OpenError> {
    #[cfg(feature = "remote")]
    {
        let s = path.to_string_lossy();
        if brickray::remote::is_url(&s) {
            let o = brickray::remote::RemoteOptions::from_env();
            return Ok(brickray::store::open_url(&s, &o)?);
        }
    }
    Ok(brickray::store::open(path)?)
}

fn open_store(input: &Input, path: &Path, how: String) -> Result<Loaded, OpenError> {
    let store = Arc::new(open_store_at(path)?);
    let desc = store.desc().clone();
    let histogram = source_histogram(&*store)?;
    let note = format!(
        "{:?} {} streamed from a {how}",
        desc.dims,
        desc.dtype.name()
    );
    let placement = store.placement();
    Ok(Loaded {
        input: input.clone(),
        desc,
        volume: Opened::Streamed(store),
        histogram,
        note,
        placement,
    })
}

/// Reads a volume whole, counting bytes.
fn read_with_progress(
    reader: &mut dyn VolumeReader,
    progress: &Progress,
) -> Result<Volume, OpenError> {
    let mut counting = Counting {
        inner: reader,
        progress,
    };
    Ok(counting.read_volume()?)
}

/// A reader that reports the bytes read.
struct Counting<'a> {
    inner: &'a mut dyn VolumeReader,
    progress: &'a Progress,
}

impl VolumeReader for Counting<'_> {
    fn desc(&self) -> &VolumeDesc {
        self.inner.desc()
    }

    fn read_slices(&mut self, z0: u32, z1: u32, out: &mut [u8]) -> Result<(), IoError> {
        // Whole volumes are read in one call: split it so progress moves.
        let slice = (out.len() / (z1 - z0).max(1) as usize).max(1);
        let mut z = z0;
        for chunk in out.chunks_mut(slice * 8) {
            let n = (chunk.len() / slice) as u32;
            self.inner.read_slices(z, z + n, chunk)?;
            z += n;
            self.progress
                .done
                .fetch_add(chunk.len() as u64, Ordering::Relaxed);
        }
        Ok(())
    }

    fn path(&self) -> &Path {
        self.inner.path()
    }

    fn input_files(&self) -> Vec<PathBuf> {
        self.inner.input_files()
    }

    // What a store records of its input: the placement (lost here before,
    // so a big NIfTI or DICOM streamed out of core was not oriented), and
    // the format, notes and warnings it reports.
    fn placement(&self) -> Option<brickray::io::Placement> {
        self.inner.placement()
    }

    fn format(&self) -> &'static str {
        self.inner.format()
    }

    fn notes(&self) -> Vec<String> {
        self.inner.notes()
    }

    fn warnings(&self) -> Vec<String> {
        self.inner.warnings()
    }
}

/// A histogram of the finest level with at most 64 bricks (interiors only).
fn source_histogram(source: &dyn BrickSource) -> Result<Histogram, OpenError> {
    let layout = source.layout().clone();
    let level = (0..layout.levels)
        .take_while(|&l| {
            let d = layout.level_dims(l);
            d.iter()
                .map(|&n| n.div_ceil(layout.brick) as u64)
                .product::<u64>()
                <= 64
        })
        .last()
        .unwrap_or(0);
    let grid = layout.level_dims(level).map(|n| n.div_ceil(layout.brick));
    let side = layout.stored_side() as usize;
    let (a, b) = (layout.apron as usize, layout.brick as usize);
    let dtype = layout.dtype();
    let mut buf = vec![0u8; layout.brick_bytes()];
    let mut h = Histogram::new(HISTOGRAM_BINS);
    for z in 0..grid[2] {
        for y in 0..grid[1] {
            for x in 0..grid[0] {
                let key = NodeKey::new(level, x, y, z);
                if !layout.in_volume(key) {
                    continue;
                }
                source.read_brick(key, &mut buf)?;
                let values = dtype.decode_le(&buf);
                for k in a..a + b {
                    for j in a..a + b {
                        let row = (k * side + j) * side;
                        for v in &values[row + a..row + a + b] {
                            h.add(layout.volume.normalize(*v));
                        }
                    }
                }
            }
        }
    }
    Ok(h)
}

/// The colour table beside a label map, if there is one: `NAME.lut` or
/// `NAME.json` for `NAME.nii.gz` also tried as `NAME.nii.lut` (mricron's
/// convention); else the default table. The note says which file was used or
/// why it was not.
pub(crate) fn label_table_beside(input: &Input) -> (brickray::LabelTable, Option<String>) {
    let Input::Path(path) = input else {
        return (Default::default(), None);
    };
    let name = path.to_string_lossy().to_string();
    let base = name.strip_suffix(".gz").unwrap_or(&name).to_string();
    let stem = path.with_extension("").to_string_lossy().to_string();
    let candidates = [
        format!("{base}.lut"),
        format!("{stem}.lut"),
        format!("{stem}.labels.json"),
    ];
    for c in candidates {
        let p = Path::new(&c);
        if !p.is_file() {
            continue;
        }
        return match std::fs::read(p)
            .map_err(|e| e.to_string())
            .and_then(|b| brickray::LabelTable::from_file_bytes(&b).map_err(|e| e.to_string()))
        {
            Ok(t) => (t, Some(format!("label colours from {c}"))),
            Err(e) => (Default::default(), Some(format!("{c}: {e}"))),
        };
    }
    (Default::default(), None)
}

mod channels;
#[cfg(feature = "remote")]
use channels::url_channels;
use channels::{Probe, probe_channels, read_channels, streamed_channels};

#[cfg(test)]
mod tests;
