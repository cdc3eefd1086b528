//! The brick octree store of brickray (issue #3).
//!
//! * [`build`] / [`build_file`]: a streaming, parallel, memory-bounded builder that
//!   reads any [`brickray_io::VolumeReader`] and writes one store file
//!   (temporary name, renamed when complete; never over one of its inputs or
//!   a non-regular file); [`remove_partial_files`] removes the temporaries of
//!   builds in progress (for signal handlers; [`ignored_signals`] says which
//!   signals the process started with ignored, which such handlers leave
//!   alone);
//! * [`open`] / [`Store`]: validated open, lock-free positional brick reads with
//!   checksum verification and a check of every decoded brick against its
//!   node's table entry, metadata queries, and for a store built with
//!   [`BuildOptions::spread`] each coarse voxel's spread
//!   ([`Store::read_spread`], format version 7); implements [`BrickSource`]; the
//!   parser reads through [`RangeReader`] ([`Store::open_with`]), so a store
//!   opens from a file, from memory, or (feature `remote`) from S3, GCS,
//!   Azure or HTTP(S) (`open_url`); OME-Zarr images stream from the same
//!   places as brick sources (`open_zarr_url`, `open_source_any`);
//! * channel sets ([`build_channels`], [`open_channels`]): a multi-channel
//!   volume as one store per channel recorded in a `NAME.channels.json`,
//!   opened as one [`brickray_core::ChannelSource`];
//! * [`ProceduralSource`]: a virtual volume of up to `65536^3` voxels (and more)
//!   whose bricks are computed on demand, with exactly filtered inner nodes;
//!   implements [`BrickSource`].
//!
//! The file format, the apron and the filter are specified in
//! `docs/store-format.md`. Brick semantics follow [`brickray_core::brick`].
//!
//! [`BrickSource`]: brickray_core::BrickSource

mod build;
mod bulb;
mod channels;
mod convert;
mod error;
mod errsec;
pub mod format;
mod opening;
mod partial;
mod placement;
mod procedural;
mod reader;
mod sample;
#[cfg(feature = "remote")]
mod url;

pub use brickray_core::{MemRangeReader, RangeRead, RangeReader};
/// Range readers over object storage and HTTP(S) (feature `remote`).
#[cfg(feature = "remote")]
pub use brickray_remote as remote;
pub use build::{BuildOptions, BuildProgress, BuildReport, build, build_file, check_output};
pub use bulb::MandelbulbSource;
pub use channels::{
    CHANNEL_SET_SUFFIX, ChannelSet, build_channels, channel_store_path, is_channel_set,
    open_channels, write_channel_set,
};
pub use convert::{ConvertReport, convert, convert_with_progress};
pub use error::{Mismatch, StoreError};
pub use errsec::ERROR_ENTRY_LEN;
pub use partial::{ignored_signals, remove_partial_files};
pub use procedural::ProceduralSource;
pub use reader::{NodeRecord, STORE_BATCH, Store, StoreStats, decode_payload, open};
#[cfg(feature = "remote")]
pub use url::{
    is_zarr_url, open_any, open_source_any, open_url, open_zarr_channels_url, open_zarr_image_url,
    open_zarr_reader_url, open_zarr_url, read_zarr_channels_url,
};

/// The 2x downsampling filter that computes a level-`l-1` voxel from the 2x2x2
/// level-`l` voxels `(2i + {0,1}, 2j + {0,1}, 2k + {0,1})`, indices clamped to the
/// level's edge (odd sizes repeat the last voxel).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Filter {
    /// The mean; integer types round half up (`floor(sum / 8 + 1/2)`), f32 sums
    /// in f64 in the order x fastest, then y, then z. For intensities.
    #[default]
    Average,
    /// The largest of the eight. For maximum-intensity projection.
    Max,
    /// The most frequent of the eight, ties to the smallest
    /// ([`brickray_core::labels::mode_of`]): the filter of label volumes (a
    /// coarser level holds no label the finer data lacks; the builder uses it
    /// for every label volume).
    Mode,
}

impl Filter {
    /// Parses `average`/`avg`/`mean`, `max` and `mode`.
    pub fn parse(s: &str) -> Option<Filter> {
        match s.to_ascii_lowercase().as_str() {
            "average" | "avg" | "mean" => Some(Filter::Average),
            "max" => Some(Filter::Max),
            "mode" | "labels" => Some(Filter::Mode),
            _ => None,
        }
    }
}

/// The file extension of brick stores (`volume.brs`), used by the demo, the
/// viewer and the documentation.
pub const EXTENSION: &str = "brs";

/// Marks an entry the builder has not written yet (never a valid level).
pub(crate) const NO_ENTRY_LEVEL: u8 = u8::MAX;
