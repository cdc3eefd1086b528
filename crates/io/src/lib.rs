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

// Helpers that only the optional formats use (decoders, slab reads) are dead
// code in a build without any of them.
#![cfg_attr(
    not(any(
        feature = "nifti",
        feature = "tiff",
        feature = "dicom",
        feature = "zarr"
    )),
    allow(dead_code)
)]

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

mod channels;
mod error;
mod files;
mod labels;
mod memory;
mod reader;
mod scan;

pub use channels::{
    CHANNEL_PALETTE, ChannelInfo, ChannelReaders, DEFAULT_CHANNEL_OPACITY, ReadChannels,
    open_channels, read_channels, select_channels,
};
pub use error::IoError;
pub use files::{FileKind, regular_file_metadata};
pub(crate) use files::{MAX_HEADER, open_regular, resolve_data_file};
pub use labels::AsLabels;
pub use memory::MemoryReader;
pub use reader::{Placement, ReadOptions, VolumeReader};
pub use scan::scan_range;
pub(crate) use scan::{check_slab, scan_stream};

use brickray_core::volume::Volume;
use std::path::Path;

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
