//! Channel sets: a multi-channel volume stored as one brick store per
//! channel and a small JSON file, `NAME.channels.json`, that records them
//! in order with what the input said of each channel (its label, colour,
//! window and whether it is shown; `brickray_io::ChannelInfo`). Opened, the
//! stores are read together as one [`ChannelSource`]: each node is one brick
//! of every channel, each store read once per brick
//! (docs/store-format.md, "Channel sets").
//!
//! ```json
//! { "format": "brickray-channels", "version": 1,
//!   "channels": [ { "store": "cells.c0.brs", "label": "nuclei",
//!                   "color": [0.0, 1.0, 0.0], "window": [100, 4000],
//!                   "active": true }, ... ] }
//! ```
//!
//! Store paths are relative to the set's folder (or absolute).

use crate::{BuildOptions, BuildReport, StoreError};
use brickray_core::{BrickSource, ChannelSource};
use brickray_io::{ChannelInfo, ChannelReaders};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The suffix of a channel set's file.
pub const CHANNEL_SET_SUFFIX: &str = ".channels.json";

/// The `format` field of a channel set.
const FORMAT: &str = "brickray-channels";

/// True when `path` names a channel set (its name ends in
/// [`CHANNEL_SET_SUFFIX`]).
pub fn is_channel_set(path: &Path) -> bool {
    path.file_name()
        .and_then(|n| n.to_str())
        .is_some_and(|n| n.to_ascii_lowercase().ends_with(CHANNEL_SET_SUFFIX))
}

#[derive(Debug, Serialize, Deserialize)]
struct SetFile {
    format: String,
    version: u32,
    channels: Vec<SetEntry>,
}

#[derive(Debug, Serialize, Deserialize)]
struct SetEntry {
    store: PathBuf,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    label: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    color: Option<[f32; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    window: Option<[f32; 2]>,
    #[serde(default = "shown")]
    active: bool,
}

fn shown() -> bool {
    true
}

/// An opened channel set.
#[derive(Debug)]
pub struct ChannelSet {
    /// The channels' stores read together.
    pub source: ChannelSource,
    /// What the input said of each channel.
    pub info: Vec<ChannelInfo>,
    /// Each channel's store.
    pub stores: Vec<PathBuf>,
}

fn bad(path: &Path, reason: impl Into<String>) -> StoreError {
    StoreError::ChannelSet {
        path: path.to_owned(),
        reason: reason.into(),
    }
}

/// The store of channel `c` of the set `set` (`NAME.channels.json`):
/// `NAME.cC.brs` beside it.
pub fn channel_store_path(set: &Path, c: u64) -> PathBuf {
    let name = set.file_name().and_then(|n| n.to_str()).unwrap_or("volume");
    let stem = if is_channel_set(set) {
        &name[..name.len() - CHANNEL_SET_SUFFIX.len()]
    } else {
        name
    };
    set.with_file_name(format!("{stem}.c{c}.{}", crate::EXTENSION))
}

/// Records `stores` (in channel order) with what the input said of each
/// (`info`, as many) as the channel set `path`, written whole under a
/// temporary name and renamed.
pub fn write_channel_set(
    path: &Path,
    stores: &[PathBuf],
    info: &[ChannelInfo],
) -> Result<(), StoreError> {
    if stores.is_empty() || stores.len() != info.len() {
        return Err(bad(
            path,
            format!(
                "{} stores and {} channel descriptions",
                stores.len(),
                info.len()
            ),
        ));
    }
    let dir = path.parent().unwrap_or(Path::new(""));
    let channels = stores
        .iter()
        .zip(info)
        .map(|(s, i)| SetEntry {
            store: s.strip_prefix(dir).map(Path::to_owned).unwrap_or(s.clone()),
            label: i.label.clone(),
            color: i.color,
            window: i.window,
            active: i.active,
        })
        .collect();
    let text = serde_json::to_string_pretty(&SetFile {
        format: FORMAT.into(),
        version: 1,
        channels,
    })
    .map_err(|e| bad(path, e.to_string()))?;
    let tmp = path.with_extension(format!("json.partial.{}", std::process::id()));
    let io = |e: std::io::Error| StoreError::Io {
        path: path.to_owned(),
        source: e,
    };
    std::fs::write(&tmp, text).map_err(io)?;
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        io(e)
    })
}

/// Builds every channel `readers` opened into its own store
/// ([`channel_store_path`]: `NAME.cC.brs` beside `path`, C the channel's
/// index in the input) with `opts`, then records them as the channel set
/// `path` (`NAME.channels.json`). Returns each store's build report.
pub fn build_channels(
    readers: ChannelReaders,
    path: &Path,
    opts: &BuildOptions,
) -> Result<Vec<BuildReport>, StoreError> {
    if !is_channel_set(path) {
        return Err(bad(
            path,
            format!("the set's name must end in {CHANNEL_SET_SUFFIX}"),
        ));
    }
    let ChannelReaders {
        mut readers,
        info,
        indices,
    } = readers;
    let mut stores = Vec::with_capacity(readers.len());
    let mut reports = Vec::with_capacity(readers.len());
    for (reader, &c) in readers.iter_mut().zip(&indices) {
        let store = channel_store_path(path, c);
        reports.push(crate::build(reader.as_mut(), &store, opts)?);
        stores.push(store);
    }
    write_channel_set(path, &stores, &info)?;
    Ok(reports)
}

/// Opens the channel set `path`: every store it records, checked to share
/// one octree, read together as one [`ChannelSource`], with what the input
/// said of each channel.
pub fn open_channels(path: &Path) -> Result<ChannelSet, StoreError> {
    let text = std::fs::read_to_string(path).map_err(|e| StoreError::Io {
        path: path.to_owned(),
        source: e,
    })?;
    let set: SetFile = serde_json::from_str(&text).map_err(|e| bad(path, e.to_string()))?;
    if set.format != FORMAT || set.version != 1 {
        return Err(bad(
            path,
            format!(
                "format {:?} version {}, expected {FORMAT:?} version 1",
                set.format, set.version
            ),
        ));
    }
    let dir = path.parent().unwrap_or(Path::new(""));
    let mut parts: Vec<Arc<dyn BrickSource>> = Vec::with_capacity(set.channels.len());
    let mut stores = Vec::with_capacity(set.channels.len());
    let mut info = Vec::with_capacity(set.channels.len());
    for e in set.channels {
        let store = dir.join(&e.store);
        parts.push(Arc::new(crate::open(&store)?));
        stores.push(store);
        info.push(ChannelInfo {
            label: e.label,
            color: e.color,
            window: e.window,
            active: e.active,
        });
    }
    let source = ChannelSource::new(parts).map_err(|e| bad(path, e.to_string()))?;
    Ok(ChannelSet {
        source,
        info,
        stores,
    })
}

#[cfg(test)]
mod tests;
