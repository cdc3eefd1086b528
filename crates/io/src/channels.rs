//! Every channel of an input at once ([`read_channels`]): a
//! [`ChannelVolume`] of 1 to [`MAX_CHANNELS`] intensity channels, what the
//! file says of each ([`ChannelInfo`]: OME-Zarr's `omero` label, colour,
//! window and visibility; OME-TIFF's channel names and colours) and the
//! default classification of each ([`ChannelInfo::style`]).
//!
//! Formats with channels: OME-Zarr (its `c` axis), ImageJ hyperstacks and
//! OME-TIFF, raw + JSON with `"channels": N` (planar, channel slowest). Any
//! other format reads as one channel. An input of more than
//! [`MAX_CHANNELS`] channels is [`IoError::TooManyChannels`] unless
//! [`ReadOptions::channels`] selects at most that many.

use crate::{IoError, Placement, ReadOptions, Registry, VolumeReader};
use brickray_core::channels::{ChannelStyle, ChannelVolume, MAX_CHANNELS};
use brickray_core::volume::{DType, Volume, VolumeData};
use brickray_core::{VolumeDesc, VolumeFrame};
use std::path::Path;

/// The colours of channels whose file gives none, by channel index (index 4
/// takes the first again): green, magenta, cyan, yellow (linear RGB).
pub const CHANNEL_PALETTE: [[f32; 3]; 4] = [
    [0.0, 1.0, 0.0],
    [1.0, 0.0, 1.0],
    [0.0, 1.0, 1.0],
    [1.0, 1.0, 0.0],
];

/// The opacity per reference length (one voxel) of a channel's default style
/// ([`ChannelInfo::style`]) at and above the top of its window.
pub const DEFAULT_CHANNEL_OPACITY: f32 = 0.5;

/// What a file says of one channel (OME-Zarr: `omero.channels[i]`).
/// Everything the file does not say (or says unusably, with a warning) is
/// `None`, and a channel is active unless the file says otherwise.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelInfo {
    /// The channel's name (`omero` `label`, OME-TIFF `Channel Name`).
    pub label: Option<String>,
    /// Its display colour, RGB 0..1 (the `omero` hex string `"RRGGBB"`,
    /// each byte over 255).
    pub color: Option<[f32; 3]>,
    /// Its display window in raw data values: `omero` `window.start` and
    /// `window.end`.
    pub window: Option<[f32; 2]>,
    /// Whether it is shown (`omero` `active`; true when absent).
    pub active: bool,
}

impl Default for ChannelInfo {
    fn default() -> ChannelInfo {
        ChannelInfo {
            label: None,
            color: None,
            window: None,
            active: true,
        }
    }
}

impl ChannelInfo {
    /// The default classification of channel `index` whose values span
    /// `value_range` (the channel's [`VolumeDesc::value_range`]): its colour
    /// (else [`CHANNEL_PALETTE`]`[index % 4]`), through its window normalized
    /// by `value_range` (else the whole range: `[0, 1]`), transparent at the
    /// window's start and [`DEFAULT_CHANNEL_OPACITY`] from its end
    /// ([`ChannelStyle::window`]), visible when active.
    pub fn style(&self, index: usize, value_range: [f32; 2]) -> ChannelStyle {
        let color = self
            .color
            .unwrap_or(CHANNEL_PALETTE[index % CHANNEL_PALETTE.len()]);
        let [lo, hi] = value_range.map(f64::from);
        let window = match self.window {
            Some([s, e]) if hi > lo && lo.is_finite() && hi.is_finite() => {
                let n = |v: f32| ((f64::from(v) - lo) / (hi - lo)) as f32;
                [n(s), n(e)]
            }
            _ => [0.0, 1.0],
        };
        ChannelStyle::window(color, window, DEFAULT_CHANNEL_OPACITY).visible(self.active)
    }
}

/// The channels a [`Format`](crate::Format) opened for [`read_channels`]:
/// one reader per channel read (every reader of one grid and spacing), what
/// the file says of each, and each one's index in the file.
pub struct ChannelReaders {
    /// One reader per channel, in order.
    pub readers: Vec<Box<dyn VolumeReader>>,
    /// What the file says of each (as many as `readers`).
    pub info: Vec<ChannelInfo>,
    /// Each one's channel index in the file (as many as `readers`).
    pub indices: Vec<u64>,
}

impl std::fmt::Debug for ChannelReaders {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ChannelReaders")
            .field("readers", &self.readers.len())
            .field("info", &self.info)
            .field("indices", &self.indices)
            .finish()
    }
}

/// The channels of [`ReadOptions::channels`] out of `count`: the selection
/// (every index below `count`, 1 to [`MAX_CHANNELS`] of them), else all of
/// them when there are at most [`MAX_CHANNELS`]; otherwise
/// [`IoError::TooManyChannels`] (or [`IoError::NoSuchChoice`] for an index
/// the input does not have, or an empty selection).
pub fn select_channels(path: &Path, count: u64, opts: &ReadOptions) -> Result<Vec<u64>, IoError> {
    let max = MAX_CHANNELS as u64;
    let Some(pick) = &opts.channels else {
        if count > max {
            return Err(IoError::TooManyChannels {
                path: path.to_owned(),
                count,
                max: MAX_CHANNELS,
            });
        }
        return Ok((0..count).collect());
    };
    let no = |wanted: String| IoError::NoSuchChoice {
        path: path.to_owned(),
        what: "channel",
        wanted,
        available: format!("0..{count}"),
    };
    if pick.is_empty() {
        return Err(no("none (an empty selection)".into()));
    }
    if let Some(c) = pick.iter().find(|&&c| c >= count) {
        return Err(no(c.to_string()));
    }
    if pick.len() > MAX_CHANNELS {
        return Err(IoError::TooManyChannels {
            path: path.to_owned(),
            count: pick.len() as u64,
            max: MAX_CHANNELS,
        });
    }
    Ok(pick.clone())
}

impl ChannelReaders {
    /// The channels of [`select_channels`] out of `count`, each opened by
    /// `open` (given the options with [`ReadOptions::channel`] set to it), the
    /// file's `info` of each (`info[c]` for channel `c`; missing entries are
    /// [`ChannelInfo::default`]).
    pub fn open_each(
        path: &Path,
        count: u64,
        info: &[ChannelInfo],
        opts: &ReadOptions,
        mut open: impl FnMut(&ReadOptions) -> Result<Box<dyn VolumeReader>, IoError>,
    ) -> Result<ChannelReaders, IoError> {
        let indices = select_channels(path, count, opts)?;
        let mut readers = Vec::with_capacity(indices.len());
        for &c in &indices {
            readers.push(open(&opts.clone().channel(Some(c)))?);
        }
        let info = indices
            .iter()
            .map(|&c| {
                usize::try_from(c)
                    .ok()
                    .and_then(|c| info.get(c))
                    .cloned()
                    .unwrap_or_default()
            })
            .collect();
        Ok(ChannelReaders {
            readers,
            info,
            indices,
        })
    }
}

/// Every channel of an input, read whole ([`read_channels`]).
#[derive(Debug, Clone)]
#[non_exhaustive]
pub struct ReadChannels {
    /// The channels (one grid, spacing and sample type; each its own value
    /// range).
    pub volume: ChannelVolume,
    /// What the file says of each channel, in order.
    pub info: Vec<ChannelInfo>,
    /// Each channel's index in the file.
    pub indices: Vec<u64>,
    /// Where the file places the volume, as the single-channel read gives it
    /// ([`VolumeReader::placement`]).
    pub placement: Option<Placement>,
    /// The format's name.
    pub format: &'static str,
    /// What the readers noticed ([`VolumeReader::notes`]), each line once.
    pub notes: Vec<String>,
    /// What the readers assumed ([`VolumeReader::warnings`]: a malformed
    /// `omero` field ignored, a spacing taken as 1, ...), each line once; a
    /// caller should show these.
    pub warnings: Vec<String>,
}

impl ReadChannels {
    /// The frame of the placement ([`Placement::frame`]), or without one the
    /// default ([`VolumeFrame::centered`] at the volume's spacing).
    pub fn frame(&self) -> VolumeFrame {
        let d = self.volume.desc();
        match &self.placement {
            Some(p) => p.frame(d.dims),
            None => VolumeFrame::centered(d.dims, d.spacing),
        }
    }

    /// The default style of every channel ([`ChannelInfo::style`] at its
    /// value range), in order.
    pub fn styles(&self) -> Vec<ChannelStyle> {
        self.info
            .iter()
            .zip(self.volume.channels())
            .enumerate()
            .map(|(i, (info, v))| info.style(i, v.desc().value_range))
            .collect()
    }

    /// Reads every channel `readers` opened (whole, validated) into a
    /// [`ChannelVolume`]. Channels the readers gave different sample types
    /// (an integer type narrowed for one channel and not another) are all
    /// read as f32 (exact for u8, u16 and i16), and the notes say so.
    pub fn read(path: &Path, mut opened: ChannelReaders) -> Result<ReadChannels, IoError> {
        let n = opened.readers.len();
        if n == 0 || n > MAX_CHANNELS {
            return Err(IoError::TooManyChannels {
                path: path.to_owned(),
                count: n as u64,
                max: MAX_CHANNELS,
            });
        }
        opened.info.resize(n, ChannelInfo::default());
        if opened.indices.len() != n {
            opened.indices = (0..n as u64).collect();
        }
        let first = &opened.readers[0];
        let placement = first.placement();
        let format = first.format();
        let mut notes = Vec::new();
        let mut warnings = Vec::new();
        let mut volumes = Vec::with_capacity(n);
        for r in &mut opened.readers {
            push_new(&mut notes, r.notes());
            push_new(&mut warnings, r.warnings());
            volumes.push(r.read_volume()?);
        }
        if volumes
            .iter()
            .any(|v| v.desc().dtype != volumes[0].desc().dtype)
        {
            let types: Vec<&str> = volumes.iter().map(|v| v.desc().dtype.name()).collect();
            notes.push(format!(
                "channels of sample types {types:?}: all read as f32"
            ));
            volumes = volumes
                .into_iter()
                .map(|v| to_f32(path, v))
                .collect::<Result<_, _>>()?;
        }
        let volume = ChannelVolume::new(volumes).map_err(|source| IoError::Channels {
            path: path.to_owned(),
            source,
        })?;
        Ok(ReadChannels {
            volume,
            info: opened.info,
            indices: opened.indices,
            placement,
            format,
            notes,
            warnings,
        })
    }
}

fn push_new(to: &mut Vec<String>, lines: Vec<String>) {
    for l in lines {
        if !to.contains(&l) {
            to.push(l);
        }
    }
}

fn to_f32(path: &Path, v: Volume) -> Result<Volume, IoError> {
    if v.desc().dtype == DType::F32 {
        return Ok(v);
    }
    let data = v.data();
    let values = VolumeData::F32((0..data.len()).map(|i| data.get(i)).collect());
    let desc = VolumeDesc {
        dtype: DType::F32,
        ..v.desc().clone()
    };
    Volume::new(desc, values).map_err(|e| IoError::volume(path, e))
}

/// Reads every channel of the input at `path` (through the default
/// [`Registry`]) as a [`ChannelVolume`], with what the file says of each
/// channel: an OME-Zarr image's `c` axis at the level and time point of
/// `opts`, an ImageJ hyperstack's or OME-TIFF's channels, a raw + JSON
/// sidecar's `"channels"`; any other input is one channel.
/// [`ReadOptions::channels`] selects channels (at most [`MAX_CHANNELS`]);
/// without it every channel is read, and an input of more than
/// [`MAX_CHANNELS`] is [`IoError::TooManyChannels`].
/// [`ReadOptions::channel`] (the single-channel reads' choice) is not used.
pub fn read_channels(path: impl AsRef<Path>, opts: &ReadOptions) -> Result<ReadChannels, IoError> {
    Registry::global().read_channels(path.as_ref(), opts)
}

/// Opens a reader of each selected channel of `path` without reading them
/// (what [`read_channels`] reads; a store builder builds one store of
/// each): the channels `opts.channels` selects, else every channel (more
/// than [`MAX_CHANNELS`] is [`IoError::TooManyChannels`]).
pub fn open_channels(
    path: impl AsRef<Path>,
    opts: &ReadOptions,
) -> Result<ChannelReaders, IoError> {
    let path = path.as_ref();
    Registry::global().find(path)?.open_channels(path, opts)
}

/// Opens the single-channel reader of each selected channel (`count` 1):
/// the [`Format::open_channels`](crate::Format::open_channels) of formats
/// without channels.
pub(crate) fn open_single(
    path: &Path,
    opts: &ReadOptions,
    open: impl FnMut(&ReadOptions) -> Result<Box<dyn VolumeReader>, IoError>,
) -> Result<ChannelReaders, IoError> {
    ChannelReaders::open_each(path, 1, &[], opts, open)
}
