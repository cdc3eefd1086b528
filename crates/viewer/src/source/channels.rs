//! Opening multi-channel inputs: the probe of a local path's channels, the
//! channels read whole (in core) or, too large for memory, streamed (an
//! OME-Zarr image's channels as stored, other files built into a channel
//! set of one store per channel), with the file's default styles and each
//! channel's histogram.

use super::*;

/// What the channel probe of a local path found.
pub(super) enum Probe {
    /// Two or more channels, opened (and how many the file has when it has
    /// more than [`MAX_CHANNELS`]: the first ones are read).
    Channels(brickray::io::ChannelReaders, Option<u64>),
    /// One channel: its reader (the single-channel path goes on with it).
    One(Box<dyn VolumeReader>),
    /// Not probed, or the probe failed: the single-channel path opens the
    /// path itself (and reports its errors).
    Plain,
}

/// Opens every channel of `path` (its format's `open_channels`: an OME-Zarr
/// `c` axis, an ImageJ hyperstack or OME-TIFF, a raw sidecar's `channels`;
/// other formats are one channel). Label maps (`--labels`) are not probed.
pub(super) fn probe_channels(path: &Path, opts: &OpenOptions) -> Result<Probe, OpenError> {
    if opts.labels {
        return Ok(Probe::Plain);
    }
    let Ok(format) = brickray::io::Registry::global().find(path) else {
        return Ok(Probe::Plain);
    };
    let defaults = ReadOptions::default();
    let (mut opened, too_many) = match format.open_channels(path, &defaults) {
        Ok(o) => (o, None),
        Err(IoError::TooManyChannels { count, .. }) => {
            let first = defaults.channels(Some((0..MAX_CHANNELS as u64).collect()));
            (format.open_channels(path, &first)?, Some(count))
        }
        Err(_) => return Ok(Probe::Plain),
    };
    if opened.readers.len() == 1 && too_many.is_none() {
        return Ok(match opened.readers.pop() {
            Some(r) => Probe::One(r),
            None => Probe::Plain,
        });
    }
    Ok(Probe::Channels(opened, too_many))
}

/// The channels of the OME-Zarr image at `url` (the first [`MAX_CHANNELS`]
/// of more) read whole (`read_zarr_channels_url`) at the finest level that
/// fits in core, or streamed when none fits; `None` for an image of one
/// channel.
#[cfg(feature = "remote")]
pub(super) fn url_channels(
    input: &Input,
    url: &str,
    o: &brickray::remote::RemoteOptions,
    opts: &OpenOptions,
    progress: &Progress,
) -> Result<Option<Loaded>, OpenError> {
    let image = brickray::store::open_zarr_image_url(url, o)?;
    let count = image.channel_count();
    if count < 2 {
        return Ok(None);
    }
    let n = count.min(MAX_CHANNELS as u64);
    let too_many = (count > n).then_some(count);
    let Some(level) = image.level_fitting(n, opts.in_core_max_bytes, opts.max_3d_side as u64)
    else {
        // No level fits in core: every channel streams.
        progress.set_stage(format!("opening {n} channels to stream"));
        let d = brickray::store::BuildOptions::default();
        let read = ReadOptions::default().channels(Some((0..n).collect()));
        let (src, info) = brickray::store::open_zarr_channels_url(url, o, &read, d.brick, d.apron)?;
        let placement = None;
        let indices: Vec<u64> = (0..n).collect();
        return streamed_channels(
            input,
            Arc::new(src),
            info,
            &indices,
            too_many,
            placement,
            format!("streamed from the OME-Zarr image {url}"),
        )
        .map(Some);
    };
    progress.set_stage(format!("reading {n} channels of level {level}"));
    let read = ReadOptions::default()
        .level(Some(level))
        .channels(Some((0..n).collect()));
    let channels = brickray::store::read_zarr_channels_url(url, o, &read)?;
    let level_note = (level > 0).then(|| format!("level {level} (the finest that fits in core)"));
    Ok(Some(loaded_channels(input, channels, too_many, level_note)))
}

/// Reads the channels `opened` holds whole (`ReadChannels::read`) with the
/// file's default styles, or says why they cannot be drawn: a multi-channel
/// volume is drawn in core, in one 3D texture.
pub(super) fn read_channels(
    input: &Input,
    path: &Path,
    opts: &OpenOptions,
    progress: &Progress,
    opened: brickray::io::ChannelReaders,
    too_many: Option<u64>,
) -> Result<Loaded, OpenError> {
    let n = opened.readers.len();
    let first = opened
        .readers
        .first()
        .ok_or_else(|| OpenError::BadInput(format!("{}: no channel", path.display())))?;
    let d = first.desc().clone();
    let bytes = d.byte_len() * n as u64;
    let mib = |b: u64| b as f64 / (1 << 20) as f64;
    let too_large = if d.dims.iter().any(|&s| s > opts.max_3d_side) {
        Some(format!(
            "more than {} voxels a side, the device's 3D texture limit",
            opts.max_3d_side
        ))
    } else if bytes > opts.in_core_max_bytes {
        Some(format!(
            "more than --in-core-max {:.0} MiB",
            mib(opts.in_core_max_bytes)
        ))
    } else {
        None
    };
    if let Some(why) = too_large {
        return stream_channels(input, path, opts, progress, opened, too_many, &why);
    }
    progress.total.store(bytes, Ordering::Relaxed);
    progress.set_stage(format!("reading {n} channels"));
    let read = brickray::io::ReadChannels::read(path, opened)?;
    progress.done.store(bytes, Ordering::Relaxed);
    Ok(loaded_channels(input, read, too_many, None))
}

/// Streams the channels `opened` holds (too large for memory: `why`): an
/// OME-Zarr image's channels as the image stores them; any other file's
/// channels built into one brick store each (`<stem>.c<index>.brs` in the
/// store folder, reused while newer than the file), read together as one
/// `ChannelSource` with the file's default styles.
pub(super) fn stream_channels(
    input: &Input,
    path: &Path,
    opts: &OpenOptions,
    progress: &Progress,
    mut opened: brickray::io::ChannelReaders,
    too_many: Option<u64>,
    why: &str,
) -> Result<Loaded, OpenError> {
    let n = opened.readers.len();
    let first = opened
        .readers
        .first()
        .ok_or_else(|| OpenError::BadInput(format!("{}: no channel", path.display())))?;
    let placement = first.placement();
    let warned = warning_note(&first.warnings());
    let zarr = first.format() == "OME-Zarr";
    let d = brickray::store::BuildOptions::default();
    let (source, how) = if zarr {
        progress.set_stage(format!("opening {n} channels of the OME-Zarr image"));
        let read = ReadOptions::default().channels(Some(opened.indices.clone()));
        let (src, _) =
            brickray::io::zarr::ZarrBrickSource::open_channels(path, &read, d.brick, d.apron)?;
        (src, "streamed from the OME-Zarr image".to_string())
    } else {
        let stem = path
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or("volume")
            .to_string();
        std::fs::create_dir_all(&opts.store_dir)
            .map_err(|e| OpenError::BadInput(format!("{}: {e}", opts.store_dir.display())))?;
        let set = opts
            .store_dir
            .join(format!("{stem}{}", brickray::store::CHANNEL_SET_SUFFIX));
        let mut parts: Vec<Arc<dyn BrickSource>> = Vec::with_capacity(n);
        let mut stores = Vec::with_capacity(n);
        let mut built = 0;
        for (reader, &c) in opened.readers.iter_mut().zip(&opened.indices) {
            let store = brickray::store::channel_store_path(&set, c);
            if !newer(&store, &reader.input_files()) {
                progress.set_stage(format!("building the brick store {}", store.display()));
                progress
                    .total
                    .store(reader.desc().byte_len(), Ordering::Relaxed);
                progress.done.store(0, Ordering::Relaxed);
                let mut counting = Counting {
                    inner: reader.as_mut(),
                    progress,
                };
                brickray::store::build(&mut counting, &store, &d)?;
                built += 1;
            }
            parts.push(Arc::new(open_store_at(&store)?));
            stores.push(store);
        }
        // The set records the stores with the file's description of each
        // channel (`brickray-viewer NAME.channels.json` opens it again).
        brickray::store::write_channel_set(&set, &stores, &opened.info)?;
        let src = ChannelSource::new(parts)
            .map_err(|e| OpenError::BadInput(format!("{}: {e}", path.display())))?;
        let how = if built > 0 { "built" } else { "reused" };
        (
            src,
            format!(
                "streamed from {how} brick stores of the channel set {}",
                set.display()
            ),
        )
    };
    streamed_channels(
        input,
        Arc::new(source),
        opened.info,
        &opened.indices,
        too_many,
        placement,
        format!("{how} ({why}){warned}"),
    )
}

/// A streamed channel source with the file's default styles (`info`) and
/// each channel's histogram of a coarse level.
pub(super) fn streamed_channels(
    input: &Input,
    source: Arc<ChannelSource>,
    info: Vec<ChannelInfo>,
    indices: &[u64],
    too_many: Option<u64>,
    placement: Option<brickray::io::Placement>,
    how: String,
) -> Result<Loaded, OpenError> {
    let n = source.len();
    let ranges = source.layout().channel_ranges().to_vec();
    let styles = info
        .iter()
        .zip(&ranges)
        .enumerate()
        .map(|(i, (info, r))| info.style(i, *r))
        .collect();
    let histograms = (0..n)
        .map(|c| match source.part(c) {
            Some(p) => source_histogram(&**p),
            None => Ok(Histogram::new(HISTOGRAM_BINS)),
        })
        .collect::<Result<Vec<_>, _>>()?;
    let desc = source.layout().volume.clone();
    let names: Vec<String> = info
        .iter()
        .zip(indices)
        .map(|(info, c)| info.label.clone().unwrap_or_else(|| format!("channel {c}")))
        .collect();
    let more = too_many
        .map(|count| format!("; the file has {count} channels, the first {n} are shown"))
        .unwrap_or_default();
    let note = format!(
        "{n} channels ({}) of {:?} {} {how}{more}",
        names.join(", "),
        desc.dims,
        desc.dtype.name(),
    );
    Ok(Loaded {
        input: input.clone(),
        histogram: histograms.first().cloned().unwrap_or_default(),
        desc,
        placement,
        note,
        volume: Opened::Channels(Box::new(OpenedChannels {
            info,
            styles,
            histograms,
            data: ChannelData::Streamed(source),
        })),
    })
}

/// A volume of channels read whole, with the file's default styles and
/// each channel's histogram; `too_many`: the channels the file has when
/// only the first were read; `level`: a note on the level read.
pub(super) fn loaded_channels(
    input: &Input,
    read: brickray::io::ReadChannels,
    too_many: Option<u64>,
    level: Option<String>,
) -> Loaded {
    let n = read.volume.len();
    let mib = |b: u64| b as f64 / (1 << 20) as f64;
    let styles = read.styles();
    let histograms: Vec<Histogram> = read
        .volume
        .channels()
        .iter()
        .map(|v| {
            let mut h = Histogram::new(HISTOGRAM_BINS);
            let desc = v.desc();
            for i in 0..v.data().len() {
                h.add(desc.normalize(v.data().get(i)));
            }
            h
        })
        .collect();
    let desc = read.volume.desc().clone();
    let names: Vec<String> = read
        .info
        .iter()
        .zip(&read.indices)
        .map(|(info, c)| info.label.clone().unwrap_or_else(|| format!("channel {c}")))
        .collect();
    let more = too_many
        .map(|count| format!("; the file has {count} channels, the first {n} are shown"))
        .unwrap_or_default();
    let level = level.map(|l| format!(", {l}")).unwrap_or_default();
    let note = format!(
        "{n} channels ({}) of {:?} {} loaded whole ({:.1} MiB{level}){more}{}",
        names.join(", "),
        desc.dims,
        desc.dtype.name(),
        mib(read.volume.byte_len()),
        warning_note(&read.warnings)
    );
    Loaded {
        input: input.clone(),
        histogram: histograms.first().cloned().unwrap_or_default(),
        desc,
        placement: read.placement,
        note,
        volume: Opened::Channels(Box::new(OpenedChannels {
            info: read.info,
            styles,
            histograms,
            data: ChannelData::InCore(read.volume),
        })),
    }
}
