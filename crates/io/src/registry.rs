//! The format registry: [`open`](crate::open) asks each registered [`Format`]
//! whether it reads a path and opens it with the one that claims it most
//! surely. Every compiled-in format adds itself ([`Registry::builtin`]); an
//! application adds its own with [`Registry::register`] or
//! [`Registry::register_global`].

use crate::{ChannelReaders, FileKind, IoError, ReadChannels, ReadOptions, VolumeReader};
use parking_lot::RwLock;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::{Arc, LazyLock};

/// How surely a format reads a path.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Claim {
    /// Not this format.
    No,
    /// Possibly this format, when no other claims it (a folder that may hold
    /// DICOM files).
    Fallback,
    /// The content looks like this format (magic bytes, a folder's files).
    ByContent,
    /// The name says so (its extension).
    ByName,
}

/// What a format may look at to claim a path: its name and, for a regular
/// file, its first bytes (a FIFO or a device is never opened here).
#[derive(Debug, Clone)]
pub struct Probe {
    /// The path.
    pub path: PathBuf,
    /// Lower-case extension, with `.nii.gz` kept whole (`"nii.gz"`); empty if none.
    pub ext: String,
    /// What the path names (`None`: a regular file), or the metadata error.
    pub kind: Result<Option<FileKind>, std::io::ErrorKind>,
    /// Up to the first 1 KiB of a regular file (empty otherwise).
    pub head: Vec<u8>,
}

impl Probe {
    /// Looks at `path` (following symbolic links).
    pub fn new(path: &Path) -> Probe {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        let ext = if name.ends_with(".nii.gz") {
            "nii.gz".to_owned()
        } else {
            path.extension()
                .map(|e| e.to_string_lossy().to_ascii_lowercase())
                .unwrap_or_default()
        };
        let kind = std::fs::metadata(path)
            .map(|m| FileKind::of(m.file_type()))
            .map_err(|e| e.kind());
        let mut head = Vec::new();
        if let Ok(None) = kind
            && let Ok(f) = std::fs::File::open(path)
        {
            let _ = f.take(1024).read_to_end(&mut head);
        }
        Probe {
            path: path.to_owned(),
            ext,
            kind,
            head,
        }
    }

    /// The path names a directory.
    pub fn is_dir(&self) -> bool {
        matches!(self.kind, Ok(Some(FileKind::Directory)))
    }
}

/// What an input holds besides the default volume: one selectable part.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Entry {
    /// What kind of part.
    pub kind: EntryKind,
    /// How to select it ([`ReadOptions::series`], `level`, `channel`, `time`).
    pub id: String,
    /// A one-line description (dims, sample type, spacing, files).
    pub summary: String,
    /// Whether [`open`](crate::open) reads this part by default.
    pub default: bool,
}

/// The kind of an [`Entry`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum EntryKind {
    /// A DICOM series.
    Series,
    /// A multiscale level.
    Level,
    /// A channel.
    Channel,
    /// A time point.
    Time,
}

impl std::fmt::Display for EntryKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            EntryKind::Series => "series",
            EntryKind::Level => "level",
            EntryKind::Channel => "channel",
            EntryKind::Time => "time",
        })
    }
}

/// A volume file format.
pub trait Format: Send + Sync + std::fmt::Debug {
    /// The format's name.
    fn name(&self) -> &'static str;

    /// What the format reads, for the error when nothing claims a path
    /// (`".nrrd, .nhdr"`).
    fn expects(&self) -> &'static str;

    /// Whether this format reads `probe`'s path.
    fn claims(&self, probe: &Probe) -> Claim;

    /// Opens the path.
    fn open(&self, path: &Path, opts: &ReadOptions) -> Result<Box<dyn VolumeReader>, IoError>;

    /// Opens every channel [`read_channels`](crate::read_channels) reads
    /// (those of [`ReadOptions::channels`], else all; see
    /// [`select_channels`](crate::select_channels)), one reader each, with
    /// what the file says of each. By default the input is one channel:
    /// [`open`](Self::open)'s.
    fn open_channels(&self, path: &Path, opts: &ReadOptions) -> Result<ChannelReaders, IoError> {
        crate::channels::open_single(path, opts, |o| self.open(path, o))
    }

    /// The selectable parts of the input (series, levels, channels, time
    /// points); none by default.
    fn list(&self, path: &Path, opts: &ReadOptions) -> Result<Vec<Entry>, IoError> {
        let _ = (path, opts);
        Ok(Vec::new())
    }
}

/// An ordered set of formats.
#[derive(Debug, Clone, Default)]
pub struct Registry {
    formats: Vec<Arc<dyn Format>>,
}

static GLOBAL: LazyLock<RwLock<Registry>> = LazyLock::new(|| RwLock::new(Registry::builtin()));

impl Registry {
    /// An empty registry.
    pub fn new() -> Registry {
        Registry::default()
    }

    /// Every format compiled into this build (raw + JSON and NRRD always; the
    /// others with their cargo features): each module adds itself.
    pub fn builtin() -> Registry {
        let mut r = Registry::new();
        crate::raw::register(&mut r);
        crate::nrrd::register(&mut r);
        #[cfg(feature = "nifti")]
        crate::nifti::register(&mut r);
        #[cfg(feature = "tiff")]
        crate::tiff::register(&mut r);
        #[cfg(feature = "dicom")]
        crate::dicom::register(&mut r);
        #[cfg(feature = "zarr")]
        crate::zarr::register(&mut r);
        r
    }

    /// A snapshot of the process-wide registry that [`open`](crate::open) uses.
    pub fn global() -> Registry {
        GLOBAL.read().clone()
    }

    /// Adds a format to the process-wide registry. A later format wins a tie.
    pub fn register_global(format: Arc<dyn Format>) {
        GLOBAL.write().register(format);
    }

    /// Adds a format. A later format wins a tie with an earlier one.
    pub fn register(&mut self, format: Arc<dyn Format>) {
        self.formats.push(format);
    }

    /// The names of the registered formats.
    pub fn names(&self) -> Vec<&'static str> {
        self.formats.iter().map(|f| f.name()).collect()
    }

    /// The format that claims `path` most surely.
    pub fn find(&self, path: &Path) -> Result<Arc<dyn Format>, IoError> {
        let probe = Probe::new(path);
        let mut best: Option<(Claim, &Arc<dyn Format>)> = None;
        for f in &self.formats {
            let c = f.claims(&probe);
            if c != Claim::No && best.is_none_or(|(b, _)| c >= b) {
                best = Some((c, f));
            }
        }
        if let Some((_, f)) = best {
            return Ok(f.clone());
        }
        if let Err(kind) = probe.kind {
            return Err(IoError::io(path, std::io::Error::from(kind)));
        }
        let tried = self
            .formats
            .iter()
            .map(|f| format!("{}: {}", f.name(), f.expects()))
            .collect::<Vec<_>>()
            .join("; ");
        Err(IoError::UnknownFormat {
            path: path.to_owned(),
            tried,
        })
    }

    /// Opens `path` with the format that claims it.
    pub fn open(&self, path: &Path, opts: &ReadOptions) -> Result<Box<dyn VolumeReader>, IoError> {
        self.find(path)?.open(path, opts)
    }

    /// Every channel of `path`, read whole (see
    /// [`read_channels`](crate::read_channels)).
    pub fn read_channels(&self, path: &Path, opts: &ReadOptions) -> Result<ReadChannels, IoError> {
        let opened = self.find(path)?.open_channels(path, opts)?;
        ReadChannels::read(path, opened)
    }

    /// The selectable parts of `path` (see [`Format::list`]).
    pub fn list(&self, path: &Path, opts: &ReadOptions) -> Result<Vec<Entry>, IoError> {
        self.find(path)?.list(path, opts)
    }
}
