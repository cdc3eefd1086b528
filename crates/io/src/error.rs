//! The readers' error type.

use brickray_core::volume::VolumeError;
use std::path::{Path, PathBuf};
use thiserror::Error;

use crate::FileKind;

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
    /// ([`ReadOptions::allow_outside_dir`](crate::ReadOptions::allow_outside_dir)).
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
    /// An input of more channels than a multi-channel volume holds, read
    /// without a selection ([`ReadOptions::channels`](crate::ReadOptions::channels)),
    /// or a selection of more than that.
    #[error(
        "{path}: {count} channels, a multi-channel volume holds at most {max} \
         (select up to {max} with ReadOptions::channels)"
    )]
    TooManyChannels {
        /// The input.
        path: PathBuf,
        /// Channels in the input (or selected).
        count: u64,
        /// The most a volume holds ([`brickray_core::MAX_CHANNELS`]).
        max: usize,
    },
    /// The channels read do not make one multi-channel volume (a label map
    /// among them, different grids).
    #[error("{path}: {source}")]
    Channels {
        /// The input.
        path: PathBuf,
        /// What is wrong.
        #[source]
        source: brickray_core::ChannelError,
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
    /// The buffer given to [`VolumeReader::read_slices`](crate::VolumeReader::read_slices) is not the slab's
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
