//! Volume input of brickray: the [`VolumeReader`] seam, a [`Registry`] of
//! formats, and the readers.
//!
//! A reader describes the volume ([`VolumeReader::desc`]), where it lies in the
//! world when the file says so ([`VolumeReader::placement`]), and streams z-slabs
//! of little-endian samples ([`VolumeReader::read_slices`]), so a builder can
//! consume an input far larger than memory. An input is a path: one file (raw +
//! JSON, NRRD, NIfTI, a TIFF stack) or a folder (a DICOM series, a folder of TIFF
//! slices, an OME-Zarr store). [`open`] finds the format through the default
//! [`Registry`], to which every compiled-in format adds itself; an application
//! can register its own ([`Registry::register`]).
//!
//! Formats (cargo features; the default enables all):
//!
//! | format | feature | reader |
//! |---|---|---|
//! | raw + JSON sidecar | always | [`RawReader`] |
//! | NRRD | always | [`NrrdReader`] |
//! | NIfTI-1 / NIfTI-2 | `nifti` | `NiftiReader` |
//! | TIFF stack / slice folder | `tiff` | `TiffReader` |
//! | DICOM series | `dicom` | `DicomReader` |
//! | OME-Zarr 0.4 / 0.5 | `zarr` | `ZarrReader`, and `ZarrBrickSource` (streamed) |

mod nrrd;
mod raw;
mod registry;
mod slab;

#[cfg(feature = "dicom")]
pub mod dicom;
#[cfg(feature = "nifti")]
pub mod nifti;
#[cfg(feature = "tiff")]
pub mod tiff;
#[cfg(feature = "zarr")]
pub mod zarr;

pub use nrrd::NrrdReader;
pub use raw::RawReader;
pub use registry::{Claim, Entry, EntryKind, Format, Probe, Registry};
pub use slab::{SampleConverter, SourceType};

use brickray_core::VolumeFrame;
use brickray_core::volume::{DType, Volume, VolumeData, VolumeDesc, VolumeError};
use std::io::Read;
use std::path::{Path, PathBuf};
use thiserror::Error;

/// Errors from reading volume files.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum IoError {
    /// The operating system refused a read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// The header or sidecar is malformed.
    #[error("{path}: malformed header: {msg}")]
    BadHeader {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        msg: String,
    },
    /// The sample type is not one brickray reads.
    #[error("{path}: unsupported sample type {name:?} (supported: u8, u16, i16, f32)")]
    UnknownDType {
        /// The file.
        path: PathBuf,
        /// The type as written.
        name: String,
    },
    /// The file holds fewer sample bytes than its header announces.
    #[error("{path}: truncated: header announces {expected} bytes of samples, file holds {actual}")]
    Truncated {
        /// The file.
        path: PathBuf,
        /// Bytes announced.
        expected: u64,
        /// Bytes present.
        actual: u64,
    },
    /// The raw file's size does not match the announced dims and sample type.
    #[error("{path}: raw file holds {actual} bytes but dims and dtype need {expected}")]
    SizeMismatch {
        /// The file.
        path: PathBuf,
        /// Bytes needed.
        expected: u64,
        /// Bytes present.
        actual: u64,
    },
    /// A feature of the format that brickray does not implement.
    #[error("{path}: unsupported: {what}")]
    Unsupported {
        /// The file.
        path: PathBuf,
        /// What is unsupported.
        what: String,
    },
    /// The described volume is invalid (dims, spacing, NaN samples, ...).
    #[error("{path}: {source}")]
    Volume {
        /// The file.
        path: PathBuf,
        /// The problem.
        #[source]
        source: VolumeError,
    },
    /// The path names something other than a regular file (a FIFO, a device,
    /// a directory, ...). Reported from its metadata, before opening it: opening
    /// a FIFO for reading would block.
    #[error("{path} is a {kind}, not a regular file")]
    NotRegularFile {
        /// The path.
        path: PathBuf,
        /// What it is.
        kind: FileKind,
    },
    /// A header or sidecar names a data file that does not resolve inside the
    /// header's folder (an absolute path, `..`, or a symbolic link leading out),
    /// and the reader was not allowed to read outside it
    /// ([`ReadOptions::allow_outside_dir`]).
    #[error(
        "{path}: data file {data} resolves outside the header's folder {dir} \
         (allowed only on request: ReadOptions::allow_outside_dir, \
         brickray-store build --allow-outside-dir)"
    )]
    OutsideDir {
        /// The header or sidecar.
        path: PathBuf,
        /// The data file as named, joined to the header's folder.
        data: PathBuf,
        /// The header's folder.
        dir: PathBuf,
    },
    /// A numeric header field is NaN or infinite.
    #[error("{path}: header field `{field}` is {value}, not a finite number")]
    NonFiniteValue {
        /// The file.
        path: PathBuf,
        /// The field (`min`, `max`, `old min`, `old max`, `value_range`).
        field: &'static str,
        /// The value read.
        value: f32,
    },
    /// A codec or library failed to decode the file's data (a corrupt chunk,
    /// a damaged compressed stream, ...).
    #[error("{path}: cannot decode {format} data: {msg}")]
    Decode {
        /// The file (or chunk) that failed.
        path: PathBuf,
        /// The format (`"TIFF"`, `"DICOM"`, `"OME-Zarr"`, ...).
        format: &'static str,
        /// What the decoder said.
        msg: String,
    },
    /// A DICOM file's transfer syntax is one brickray cannot decode (a
    /// compression whose decoder needs a system library, or an unknown one).
    #[error("{path}: DICOM transfer syntax {uid} ({name}) is not supported")]
    UnsupportedTransferSyntax {
        /// The file.
        path: PathBuf,
        /// The transfer syntax UID.
        uid: String,
        /// Its name, when known.
        name: String,
    },
    /// The files of a multi-file volume (a DICOM series, a folder of TIFF
    /// slices) do not make one volume: mixed sizes or types, a missing slice.
    #[error("{path}: {file}: {msg}")]
    Inconsistent {
        /// The folder.
        path: PathBuf,
        /// The file that does not fit.
        file: PathBuf,
        /// What is wrong.
        msg: String,
    },
    /// A selection (series, level, channel, time point) names nothing in the input.
    #[error("{path}: no {what} {wanted:?} (available: {available})")]
    NoSuchChoice {
        /// The input.
        path: PathBuf,
        /// `"series"`, `"level"`, `"channel"` or `"time point"`.
        what: &'static str,
        /// What was asked for.
        wanted: String,
        /// What there is.
        available: String,
    },
    /// No registered format reads this path.
    #[error("{path}: no reader for this input ({tried})")]
    UnknownFormat {
        /// The input.
        path: PathBuf,
        /// The formats tried, and what each expects.
        tried: String,
    },
    /// Samples decode, after the file's rescale, to values beyond the range of
    /// the stored sample type (f32): they would be stored as infinity. Refused
    /// at open, like NaN and infinite samples.
    #[error(
        "{path}: samples decode to {lo:e}..{hi:e} (after the file's rescale), \
         beyond the range of f32: they would be stored as infinity"
    )]
    SampleOverflow {
        /// The file (or folder).
        path: PathBuf,
        /// The smallest decoded value.
        lo: f64,
        /// The largest decoded value.
        hi: f64,
    },
    /// The buffer given to [`VolumeReader::read_slices`] is not the slab's
    /// size.
    #[error("read_slices: a buffer of {actual} bytes for a slab of {expected}")]
    SlabBuffer {
        /// The slab's bytes.
        expected: u64,
        /// The buffer's.
        actual: u64,
    },
    /// A slab outside the volume was asked for.
    #[error("slices {z0}..{z1} requested from a volume of depth {depth}")]
    BadSlab {
        /// First slice.
        z0: u32,
        /// One past the last slice.
        z1: u32,
        /// Volume depth.
        depth: u32,
    },
}

impl IoError {
    pub(crate) fn decode(
        path: &Path,
        format: &'static str,
        msg: impl std::fmt::Display,
    ) -> IoError {
        IoError::Decode {
            path: path.to_owned(),
            format,
            msg: msg.to_string(),
        }
    }
    pub(crate) fn unsupported(path: &Path, what: impl Into<String>) -> IoError {
        IoError::Unsupported {
            path: path.to_owned(),
            what: what.into(),
        }
    }
    pub(crate) fn io(path: &Path, source: std::io::Error) -> IoError {
        IoError::Io {
            path: path.to_owned(),
            source,
        }
    }
    pub(crate) fn header(path: &Path, msg: impl Into<String>) -> IoError {
        IoError::BadHeader {
            path: path.to_owned(),
            msg: msg.into(),
        }
    }
    pub(crate) fn volume(path: &Path, source: VolumeError) -> IoError {
        IoError::Volume {
            path: path.to_owned(),
            source,
        }
    }
}

/// What a path names when it is not a regular file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum FileKind {
    /// A directory.
    Directory,
    /// A named pipe (FIFO).
    Fifo,
    /// A socket.
    Socket,
    /// A character device (`/dev/null`, a terminal, ...).
    CharDevice,
    /// A block device.
    BlockDevice,
    /// Anything else that is not a regular file.
    Other,
}

impl FileKind {
    /// The kind of a file type, `None` for a regular file.
    pub fn of(ft: std::fs::FileType) -> Option<FileKind> {
        if ft.is_file() {
            return None;
        }
        if ft.is_dir() {
            return Some(FileKind::Directory);
        }
        #[cfg(unix)]
        {
            use std::os::unix::fs::FileTypeExt;
            if ft.is_fifo() {
                return Some(FileKind::Fifo);
            }
            if ft.is_socket() {
                return Some(FileKind::Socket);
            }
            if ft.is_char_device() {
                return Some(FileKind::CharDevice);
            }
            if ft.is_block_device() {
                return Some(FileKind::BlockDevice);
            }
        }
        Some(FileKind::Other)
    }
}

impl std::fmt::Display for FileKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            FileKind::Directory => "directory",
            FileKind::Fifo => "FIFO (named pipe)",
            FileKind::Socket => "socket",
            FileKind::CharDevice => "character device",
            FileKind::BlockDevice => "block device",
            FileKind::Other => "special file",
        })
    }
}

/// Options of the readers ([`open_with`], [`RawReader::open_sidecar_with`],
/// [`NrrdReader::open_with`], ...): safety switches and which part of a
/// multi-part input to read. The default is strict and reads the default part
/// (the largest DICOM series, the finest OME-Zarr level, the first channel and
/// time point).
#[derive(Debug, Clone, Default, PartialEq)]
#[non_exhaustive]
pub struct ReadOptions {
    /// Let a sidecar's `file`, a NRRD header's `data file` or a NIfTI header's
    /// `.img` name a file outside the header's folder (absolute paths, `..`,
    /// symbolic links leading out). Off by default: a header from elsewhere
    /// cannot make the reader read any file the process can read.
    pub allow_outside_dir: bool,
    /// The DICOM series to read (its SeriesInstanceUID, or its index in
    /// [`Registry::list`]'s order); `None`: the series with the most slices.
    pub series: Option<String>,
    /// The OME-Zarr multiscale level (0 = finest); `None`: 0.
    pub level: Option<usize>,
    /// The channel of a multi-channel input; `None`: the first.
    pub channel: Option<u64>,
    /// The time point of a time series; `None`: the first.
    pub time: Option<u64>,
    /// The voxel spacing to use where the file states none (a plain TIFF);
    /// `None`: 1, 1, 1 there. Formats that state a spacing keep theirs.
    pub spacing: Option<[f32; 3]>,
}

impl ReadOptions {
    /// Sets [`ReadOptions::allow_outside_dir`].
    pub fn allow_outside_dir(mut self, allow: bool) -> ReadOptions {
        self.allow_outside_dir = allow;
        self
    }
    /// Sets [`ReadOptions::series`].
    pub fn series(mut self, series: Option<String>) -> ReadOptions {
        self.series = series;
        self
    }
    /// Sets [`ReadOptions::level`].
    pub fn level(mut self, level: Option<usize>) -> ReadOptions {
        self.level = level;
        self
    }
    /// Sets [`ReadOptions::channel`].
    pub fn channel(mut self, channel: Option<u64>) -> ReadOptions {
        self.channel = channel;
        self
    }
    /// Sets [`ReadOptions::spacing`].
    pub fn spacing(mut self, spacing: Option<[f32; 3]>) -> ReadOptions {
        self.spacing = spacing;
        self
    }
    /// Sets [`ReadOptions::time`].
    pub fn time(mut self, time: Option<u64>) -> ReadOptions {
        self.time = time;
        self
    }
}

/// Where a volume lies in the world, as its file states it: the affine map
/// from voxel indices (`i, j, k`, voxel centres at integers; `i` along x of
/// [`VolumeDesc::dims`]) to world coordinates (for medical formats, patient
/// millimetres in RAS+ or LPS+ as [`Placement::space`] says).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placement {
    /// Row-major 4x4 voxel-to-world affine (last row `0 0 0 1`).
    pub affine: [[f64; 4]; 4],
    /// The world's axes: `"RAS"` (NIfTI), `"LPS"` (DICOM) or `"image"` (a
    /// microscope's stage axes: OME-Zarr, TIFF).
    pub space: &'static str,
}

impl Placement {
    /// A scale-and-translate placement (no rotation): voxel `i` along axis `a`
    /// lies at `origin[a] + i * spacing[a]`.
    pub fn axis_aligned(spacing: [f64; 3], origin: [f64; 3], space: &'static str) -> Placement {
        let mut affine = [[0.0; 4]; 4];
        for a in 0..3 {
            affine[a][a] = spacing[a];
            affine[a][3] = origin[a];
        }
        affine[3][3] = 1.0;
        Placement { affine, space }
    }

    /// The voxel-to-world matrix as a column-major [`glam::DMat4`].
    pub fn matrix(&self) -> glam::DMat4 {
        glam::DMat4::from_cols_array_2d(&self.affine).transpose()
    }

    /// The world position of voxel `(i, j, k)`.
    pub fn voxel_to_world(&self, ijk: [f64; 3]) -> [f64; 3] {
        self.matrix()
            .transform_point3(glam::DVec3::from_array(ijk))
            .to_array()
    }

    /// The [`VolumeFrame`] that puts the volume's texture space `[0,1]^3` where
    /// this placement says (voxel `i` is at texture coordinate `(i + 0.5) / n`),
    /// so that a mirrored or rotated acquisition is shown as acquired.
    pub fn frame(&self, dims: [u32; 3]) -> VolumeFrame {
        let d = glam::DVec3::from_array(dims.map(f64::from));
        let tex_to_voxel =
            glam::DMat4::from_translation(glam::DVec3::splat(-0.5)) * glam::DMat4::from_scale(d);
        VolumeFrame::new((self.matrix() * tex_to_voxel).as_mat4(), dims)
    }
}

/// A source of volume samples that can be streamed slab by slab.
pub trait VolumeReader: Send {
    /// The volume's description. Its `value_range` is the file's declared range,
    /// or the data's min..max when the file declares none.
    fn desc(&self) -> &VolumeDesc;

    /// Reads slices `z0..z1` as little-endian samples into `out`, whose length must
    /// be `(z1 - z0) * nx * ny * dtype.size()` (else [`IoError::SlabBuffer`]). Reading slabs in increasing z is
    /// always efficient; other orders may re-read compressed inputs.
    fn read_slices(&mut self, z0: u32, z1: u32, out: &mut [u8]) -> Result<(), IoError>;

    /// The path that names this input in errors: a file, or a folder for the
    /// formats that are folders (a DICOM series, TIFF slices, OME-Zarr).
    fn path(&self) -> &Path;

    /// The format's name (`"raw"`, `"NRRD"`, `"NIfTI-1"`, `"DICOM"`, ...).
    fn format(&self) -> &'static str {
        "raw"
    }

    /// Where the file places the volume in the world, if it says (NIfTI's
    /// qform/sform, DICOM's patient position and orientation, OME-Zarr's
    /// coordinate transformations). `None`: only [`VolumeDesc::spacing`] is
    /// known.
    fn placement(&self) -> Option<Placement> {
        None
    }

    /// What the reader noticed and the user should know (a conversion of the
    /// sample type, a gantry tilt, non-uniform slice spacing, ...), one line each.
    fn notes(&self) -> Vec<String> {
        Vec::new()
    }

    /// What the reader had to assume because the file did not say, or said
    /// something unusable where the format's readers customarily fall back
    /// (a DICOM slice without PixelSpacing read at 1 mm, a TIFF without
    /// spacing read at 1, 1, 1, a NIfTI `scl_slope` that is not finite read
    /// as no rescale, ...), one line each. Empty when the volume is as the
    /// file states it. A caller should show these to the user (the
    /// command-line tools print them, the viewer shows them): a value that is
    /// invalid and has no customary fallback is an error instead, never a
    /// silent default.
    fn warnings(&self) -> Vec<String> {
        Vec::new()
    }

    /// Every file this reader reads (header or sidecar, and data file; each
    /// slice of a folder), so that a caller writing a file can refuse to
    /// overwrite one of its inputs. The default is [`path`](Self::path).
    fn input_files(&self) -> Vec<PathBuf> {
        vec![self.path().to_owned()]
    }

    /// Reads the whole volume, validating it (NaN/Inf samples are an error).
    fn read_volume(&mut self) -> Result<Volume, IoError> {
        let desc = self.desc().clone();
        let len = usize::try_from(desc.byte_len()).map_err(|_| {
            IoError::volume(
                self.path(),
                VolumeError::BadDims {
                    dims: desc.dims.map(u64::from),
                    max: brickray_core::volume::MAX_DIM,
                },
            )
        })?;
        let mut bytes = vec![0u8; len];
        self.read_slices(0, desc.dims[2], &mut bytes)?;
        let data = VolumeData::from_le_bytes(desc.dtype, &bytes);
        Volume::new(desc, data).map_err(|e| IoError::volume(self.path(), e))
    }
}

/// The metadata of `path` (following symbolic links) if it names a regular
/// file, else [`IoError::NotRegularFile`]. It never opens the path, so a FIFO
/// is refused at once instead of blocking the caller.
pub fn regular_file_metadata(path: &Path) -> Result<std::fs::Metadata, IoError> {
    let md = std::fs::metadata(path).map_err(|e| IoError::io(path, e))?;
    match FileKind::of(md.file_type()) {
        None => Ok(md),
        Some(kind) => Err(IoError::NotRegularFile {
            path: path.to_owned(),
            kind,
        }),
    }
}

/// Opens a regular file for reading: its metadata is checked first (opening a
/// FIFO would block), and the opened file again (the path may have changed in
/// between).
pub(crate) fn open_regular(path: &Path) -> Result<std::fs::File, IoError> {
    regular_file_metadata(path)?;
    let f = std::fs::File::open(path).map_err(|e| IoError::io(path, e))?;
    let md = f.metadata().map_err(|e| IoError::io(path, e))?;
    match FileKind::of(md.file_type()) {
        None => Ok(f),
        Some(kind) => Err(IoError::NotRegularFile {
            path: path.to_owned(),
            kind,
        }),
    }
}

/// Longest JSON sidecar or NRRD header read (a forged file cannot make a
/// reader buffer gigabytes of "header").
pub(crate) const MAX_HEADER: usize = 1 << 20;

/// The data file `name` (as written in the header or sidecar `header`),
/// relative to the header's folder. Unless `opts` allows otherwise it must
/// resolve inside that folder: no absolute path or `..` leading out, and, when
/// it exists, its canonical path (symbolic links followed) must lie in the
/// folder's.
pub(crate) fn resolve_data_file(
    header: &Path,
    name: &Path,
    opts: &ReadOptions,
) -> Result<PathBuf, IoError> {
    let dir = header
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let data = dir.join(name);
    if opts.allow_outside_dir {
        return Ok(data);
    }
    let outside = || IoError::OutsideDir {
        path: header.to_owned(),
        data: data.clone(),
        dir: dir.to_owned(),
    };
    match (dir.canonicalize(), data.canonicalize()) {
        (Ok(cdir), Ok(cdata)) => {
            if cdata.starts_with(&cdir) {
                Ok(data)
            } else {
                Err(outside())
            }
        }
        // The folder exists (it holds the header) but the data file does not
        // resolve: judge the name alone, so that the error does not tell
        // whether a file outside the folder exists.
        _ => {
            let mut depth = 0i64;
            for c in name.components() {
                match c {
                    std::path::Component::Normal(_) => depth += 1,
                    std::path::Component::CurDir => {}
                    std::path::Component::ParentDir => depth -= 1,
                    std::path::Component::RootDir | std::path::Component::Prefix(_) => {
                        return Err(outside());
                    }
                }
                if depth < 0 {
                    return Err(outside());
                }
            }
            Ok(data)
        }
    }
}

/// Checks that a slab request fits the volume and the buffer.
pub(crate) fn check_slab(desc: &VolumeDesc, z0: u32, z1: u32, out: &[u8]) -> Result<u64, IoError> {
    if z0 > z1 || z1 > desc.dims[2] {
        return Err(IoError::BadSlab {
            z0,
            z1,
            depth: desc.dims[2],
        });
    }
    let slice = desc.dims[0] as u64 * desc.dims[1] as u64 * desc.dtype.size() as u64;
    let need = (z1 - z0) as u64 * slice;
    if out.len() as u64 != need {
        return Err(IoError::SlabBuffer {
            expected: need,
            actual: out.len() as u64,
        });
    }
    Ok(slice)
}

/// Min and max of little-endian samples, and the index of the first non-finite one.
pub fn scan_range(dtype: DType, bytes: &[u8]) -> (f32, f32, Option<usize>) {
    let mut lo = f32::INFINITY;
    let mut hi = f32::NEG_INFINITY;
    let mut bad = None;
    let mut push = |i: usize, x: f32| {
        if x.is_finite() {
            lo = lo.min(x);
            hi = hi.max(x);
        } else if bad.is_none() {
            bad = Some(i);
        }
    };
    match dtype {
        DType::U8 => bytes
            .iter()
            .enumerate()
            .for_each(|(i, &b)| push(i, b as f32)),
        DType::U16 => bytes
            .chunks_exact(2)
            .enumerate()
            .for_each(|(i, c)| push(i, u16::from_le_bytes([c[0], c[1]]) as f32)),
        DType::I16 => bytes
            .chunks_exact(2)
            .enumerate()
            .for_each(|(i, c)| push(i, i16::from_le_bytes([c[0], c[1]]) as f32)),
        DType::F32 => bytes
            .chunks_exact(4)
            .enumerate()
            .for_each(|(i, c)| push(i, f32::from_le_bytes([c[0], c[1], c[2], c[3]]))),
        // A sample type added to brickray-core after this reader: no range.
        _ => {}
    }
    (lo, hi, bad)
}

/// Bytes decoded per step by [`scan_stream`]: memory stays bounded whatever the
/// dims claim (a multiple of every sample size).
const SCAN_CHUNK: usize = 1 << 20;

/// Streams the `desc.byte_len()` sample bytes of `src` (in file byte order) once,
/// returning the data's min..max (widened to `lo..lo+1` when flat). Errors on
/// NaN/Inf with the total count and the first voxel, and with
/// [`IoError::Truncated`] when the stream ends early. `io_err` maps a read error
/// at a decoded byte position. Memory use is bounded by [`SCAN_CHUNK`], so a
/// forged header cannot make the scan allocate what the data does not hold.
pub(crate) fn scan_stream(
    path: &Path,
    desc: &VolumeDesc,
    big_endian: bool,
    src: &mut dyn Read,
    io_err: &dyn Fn(std::io::Error, u64) -> IoError,
) -> Result<[f32; 2], IoError> {
    let size = desc.dtype.size();
    let total = desc.byte_len();
    let mut buf = vec![0u8; (SCAN_CHUNK as u64).min(total) as usize];
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    let mut count = 0u64;
    let mut first: Option<u64> = None;
    let mut pos = 0u64;
    while pos < total {
        let want = (total - pos).min(buf.len() as u64) as usize;
        let chunk = &mut buf[..want];
        let mut filled = 0;
        while filled < want {
            match src.read(&mut chunk[filled..]) {
                Ok(0) => {
                    return Err(IoError::Truncated {
                        path: path.to_owned(),
                        expected: total,
                        actual: pos + filled as u64,
                    });
                }
                Ok(n) => filled += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(io_err(e, pos + filled as u64)),
            }
        }
        if big_endian && size > 1 {
            chunk.chunks_exact_mut(size).for_each(|c| c.reverse());
        }
        let (a, b, bad) = scan_range(desc.dtype, chunk);
        if let Some(i) = bad {
            count += bytes_non_finite(desc.dtype, chunk);
            first.get_or_insert(pos / size as u64 + i as u64);
        }
        lo = lo.min(a);
        hi = hi.max(b);
        pos += want as u64;
    }
    if let Some(i) = first {
        let [nx, ny, _] = desc.dims.map(u64::from);
        let first = [
            (i % nx) as u32,
            ((i / nx) % ny) as u32,
            (i / (nx * ny)) as u32,
        ];
        return Err(IoError::volume(
            path,
            VolumeError::NonFinite { count, first },
        ));
    }
    // Both finite here (NaN/Inf returned above, and there is at least one voxel).
    Ok(slab::widen_flat(lo, hi))
}

fn bytes_non_finite(dtype: DType, bytes: &[u8]) -> u64 {
    if dtype != DType::F32 {
        return 0;
    }
    bytes
        .chunks_exact(4)
        .filter(|c| !f32::from_le_bytes([c[0], c[1], c[2], c[3]]).is_finite())
        .count() as u64
}

/// Opens a volume through the default [`Registry`]: raw + JSON (`.json`, or a
/// `.raw` beside its sidecar), NRRD (`.nrrd`, `.nhdr`), and with their
/// features NIfTI (`.nii`, `.nii.gz`, `.hdr`/`.img`), TIFF (`.tif`, `.tiff`,
/// or a folder of slices), DICOM (a folder, searched recursively, or one file)
/// and OME-Zarr (a `.zarr` folder). Strict: a data file named by a header must
/// resolve inside the header's folder (see [`open_with`]).
pub fn open(path: impl AsRef<Path>) -> Result<Box<dyn VolumeReader>, IoError> {
    open_with(path, &ReadOptions::default())
}

/// [`open`] with options (safety switches; series, level, channel, time point).
pub fn open_with(
    path: impl AsRef<Path>,
    opts: &ReadOptions,
) -> Result<Box<dyn VolumeReader>, IoError> {
    Registry::global().open(path.as_ref(), opts)
}

/// What an input holds beyond the volume [`open`] reads: its DICOM series,
/// OME-Zarr levels, channels and time points (through the default
/// [`Registry`]).
pub fn list(path: impl AsRef<Path>, opts: &ReadOptions) -> Result<Vec<Entry>, IoError> {
    Registry::global().list(path.as_ref(), opts)
}

/// Opens and loads a volume whole (see [`open`]).
pub fn read_volume(path: impl AsRef<Path>) -> Result<Volume, IoError> {
    open(path)?.read_volume()
}

/// A [`VolumeReader`] over a volume already in memory (for building a brick store
/// from generated data, and for tests).
#[derive(Debug)]
pub struct MemoryReader {
    volume: Volume,
    path: PathBuf,
}

impl MemoryReader {
    /// Wraps a volume; `name` stands for its path in errors.
    pub fn new(volume: Volume, name: impl Into<PathBuf>) -> MemoryReader {
        MemoryReader {
            volume,
            path: name.into(),
        }
    }
}

impl VolumeReader for MemoryReader {
    fn desc(&self) -> &VolumeDesc {
        self.volume.desc()
    }

    fn path(&self) -> &Path {
        &self.path
    }

    /// None: the volume is in memory (its name is not a file).
    fn input_files(&self) -> Vec<PathBuf> {
        Vec::new()
    }

    fn format(&self) -> &'static str {
        "memory"
    }

    fn read_slices(&mut self, z0: u32, z1: u32, out: &mut [u8]) -> Result<(), IoError> {
        let slice = check_slab(self.volume.desc(), z0, z1, out)? as usize;
        let bytes = self.volume.data().as_bytes();
        out.copy_from_slice(&bytes[z0 as usize * slice..z1 as usize * slice]);
        Ok(())
    }

    fn read_volume(&mut self) -> Result<Volume, IoError> {
        Ok(self.volume.clone())
    }
}
