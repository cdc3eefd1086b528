//! [`ZarrReader`]: one level, channel and time point of an OME-Zarr image
//! streamed in z-slabs (the input of a store build or a whole read).

use super::OmeZarr;
use super::scan::scan;
use crate::check_slab;
use crate::slab::SampleConverter;
use crate::{ChannelReaders, IoError, Placement, ReadOptions, VolumeReader};
use brickray_core::VolumeDesc;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Streams one level, channel and time point of an OME-Zarr image in z-slabs.
#[derive(Debug)]
pub struct ZarrReader {
    /// Shared by the readers of one image's channels (one chunk cache).
    zarr: Arc<OmeZarr>,
    level: usize,
    c: u64,
    t: u64,
    conv: SampleConverter,
    desc: VolumeDesc,
    notes: Vec<String>,
}

impl ZarrReader {
    /// Opens `root` with the level, channel and time point of `opts`. Scans the
    /// level once (in slabs) for its value range.
    pub fn open(root: &Path, opts: &ReadOptions) -> Result<ZarrReader, IoError> {
        ZarrReader::from_zarr(Arc::new(OmeZarr::open(root)?), opts)
    }

    /// One reader per channel of [`ReadOptions::channels`] (else every
    /// channel; see [`crate::select_channels`]) at the level and time point
    /// of `opts`, sharing the opened image, with each channel's `omero`
    /// metadata ([`OmeZarr::channel_info`]).
    pub fn open_channels(root: &Path, opts: &ReadOptions) -> Result<ChannelReaders, IoError> {
        ZarrReader::channels_of(Arc::new(OmeZarr::open(root)?), opts)
    }

    /// [`ZarrReader::open_channels`] of the image whose objects `reader`
    /// reads by key (an OME-Zarr image over HTTP or in a bucket; see
    /// [`ZarrReader::open_objects`]).
    pub fn open_channels_objects(
        reader: Arc<dyn brickray_core::ObjectReader>,
        opts: &ReadOptions,
    ) -> Result<ChannelReaders, IoError> {
        ZarrReader::channels_of(Arc::new(OmeZarr::open_objects(reader)?), opts)
    }

    fn channels_of(zarr: Arc<OmeZarr>, opts: &ReadOptions) -> Result<ChannelReaders, IoError> {
        let root = zarr.root.clone();
        let root = root.as_path();
        zarr.check_choice(&opts.clone().channel(None))?;
        let count = zarr.channel_count();
        let indices = crate::select_channels(root, count, opts)?;
        let mut readers: Vec<Box<dyn VolumeReader>> = Vec::with_capacity(indices.len());
        for &c in &indices {
            readers.push(Box::new(ZarrReader::from_zarr(
                zarr.clone(),
                &opts.clone().channel(Some(c)),
            )?));
        }
        Ok(ChannelReaders {
            readers,
            info: indices.iter().map(|&c| zarr.channel_info(c)).collect(),
            indices,
        })
    }

    /// Opens the image whose objects `reader` reads by key (an OME-Zarr
    /// image over HTTP or in a bucket), as [`ZarrReader::open`] does a
    /// folder: every chunk of the level is fetched (the scan for the value
    /// range, then the slabs), through the decoded-chunk cache.
    pub fn open_objects(
        reader: Arc<dyn brickray_core::ObjectReader>,
        opts: &ReadOptions,
    ) -> Result<ZarrReader, IoError> {
        ZarrReader::from_zarr(Arc::new(OmeZarr::open_objects(reader)?), opts)
    }

    fn from_zarr(zarr: Arc<OmeZarr>, opts: &ReadOptions) -> Result<ZarrReader, IoError> {
        let root = zarr.root.clone();
        let root = root.as_path();
        let (level, c, t) = zarr.check_choice(opts)?;
        let dims64 = zarr.dims(level);
        brickray_core::volume::voxel_count(dims64).map_err(|e| IoError::volume(root, e))?;
        let range = scan(&zarr, level, c, t)?;
        let conv = SampleConverter::choose(zarr.src, false, 1.0, 0.0, Some(range));
        let (s, _) = zarr.xyz(level);
        let desc = zarr.volume_desc(root, dims64, conv.dst, s, range)?;
        let notes = vec![
            format!(
                "OME-Zarr {}: level {level} of {} ({}), channel {c}, time point {t}",
                zarr.version,
                zarr.levels.len(),
                zarr.levels[level].path
            ),
            format!("samples: {}", conv.describe()),
        ];
        Ok(ZarrReader {
            zarr,
            level,
            c,
            t,
            conv,
            desc,
            notes,
        })
    }
}

impl VolumeReader for ZarrReader {
    fn desc(&self) -> &VolumeDesc {
        &self.desc
    }

    fn format(&self) -> &'static str {
        "OME-Zarr"
    }

    fn path(&self) -> &Path {
        &self.zarr.root
    }

    fn input_files(&self) -> Vec<PathBuf> {
        vec![self.zarr.root.clone()]
    }

    fn placement(&self) -> Option<Placement> {
        let (s, t) = self.zarr.xyz(self.level);
        Some(Placement::axis_aligned(s, t, "image"))
    }

    fn notes(&self) -> Vec<String> {
        self.notes.clone()
    }

    fn warnings(&self) -> Vec<String> {
        self.zarr.warnings.clone()
    }

    fn read_slices(&mut self, z0: u32, z1: u32, out: &mut [u8]) -> Result<(), IoError> {
        check_slab(&self.desc, z0, z1, out)?;
        let [nx, ny, _] = self.desc.dims.map(u64::from);
        let b = self.zarr.region(
            self.level,
            self.c,
            self.t,
            [0, 0, z0 as u64],
            [nx, ny, z1 as u64],
        )?;
        self.conv.convert(&b, out);
        Ok(())
    }
}
