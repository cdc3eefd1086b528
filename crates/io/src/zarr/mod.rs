//! OME-Zarr 0.4 (zarr v2) and 0.5 (zarr v3) images, read with `zarrs` (codecs:
//! blosc, zstd, gzip, crc32c, transpose, sharding).
//!
//! * the first multiscale image of the group; its axes (`t`, `c`, `z`, `y`,
//!   `x` in the standard's order; `z` may be absent) and each level's `scale`
//!   and `translation` transforms (times the multiscale's own, if any) give
//!   the spacing and the [`Placement`] (the image's own axes and units);
//! * the level ([`ReadOptions::level`], 0 = finest), channel and time point
//!   ([`ReadOptions::channel`], [`ReadOptions::time`]) are selectable, the
//!   first of each by default, and listed by [`crate::list`]; every channel
//!   at once through [`ZarrReader::open_channels`] ([`crate::read_channels`]),
//!   with each one's `omero` label, colour, window and visibility
//!   ([`OmeZarr::channel_info`]);
//! * a missing chunk reads as the array's fill value (the zarr
//!   specification's rule); a corrupt one is an [`IoError::Decode`] naming the
//!   level;
//! * two ways in: [`ZarrReader`] streams z-slabs to the store builder, and
//!   [`ZarrBrickSource`] serves octree bricks straight from the chunks (see
//!   its documentation), so a store need not be built at all;
//! * from a folder, or from objects read by key through an
//!   [`ObjectReader`] ([`OmeZarr::open_objects`],
//!   [`ZarrBrickSource::open_objects`]: an image over HTTP or in a bucket,
//!   with `brickray-remote`); a missing object (404, or S3's 403) is a
//!   missing chunk;
//! * decoded chunks (a sharded array's inner chunks) are kept within
//!   [`CHUNK_CACHE_BYTES`], least recently used first out, so that
//!   neighbouring bricks and slabs that share a chunk decode (and, remotely,
//!   fetch) it once.

use crate::slab::desc_range;
use crate::{
    Claim, Entry, EntryKind, Format, IoError, Placement, Probe, ReadOptions, Registry,
    SampleConverter, SourceType, VolumeReader,
};
use brickray_core::{
    BrickError, BrickSource, DType, NodeInfo, NodeKey, NodeKind, ObjectReader, OctreeLayout,
    VolumeDesc,
};
use parking_lot::Mutex;
use serde_json::Value;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use zarrs::array::{Array, ArrayMetadata, ArraySubset};

mod cache;
mod labels;
mod omero;
mod reader;
mod region;
mod safe;
mod scan;
mod source;
mod write;

use cache::ChunkCache;
pub use cache::{CHUNK_CACHE_BYTES, ChunkCacheStats};
pub use reader::ZarrReader;
use safe::{MAX_CHUNK_BYTES, SafeStore};
use scan::scan;
pub use source::{MAX_BRICK_READ, ZARR_BATCH, ZarrBrickSource};
pub use write::{add_ome_zarr_labels, write_ome_zarr, write_ome_zarr_channels};

type ZArray = Array<SafeStore>;

/// One level of the multiscale image.
#[derive(Debug)]
struct Level {
    path: String,
    shape: Vec<u64>,
    scale: Vec<f64>,
    translation: Vec<f64>,
    /// The decoded unit: the chunk shape, or a sharded array's inner chunk
    /// shape.
    unit: Vec<u64>,
    array: ZArray,
}

/// An opened OME-Zarr multiscale image.
#[derive(Debug)]
pub struct OmeZarr {
    root: PathBuf,
    version: String,
    levels: Vec<Level>,
    /// Array axis of x, y, z (z may be absent), c, t.
    ax: [Option<usize>; 5],
    src: SourceType,
    store: Arc<SafeStore>,
    /// Decoded chunks, by level and unit indices.
    cache: ChunkCache,
    /// What was assumed (see [`VolumeReader::warnings`]).
    warnings: Vec<String>,
    /// A label image's colours (`image-label`; `labels.rs`), `None` for an
    /// intensity image.
    image_label: Option<Vec<(u32, [f32; 4])>>,
    /// What `omero` says of the first channels (`omero.rs`; a channel past
    /// the end has the default).
    channel_info: Vec<crate::ChannelInfo>,
}

/// A metadata file's JSON; `Ok(None)` when it does not exist. Regular files
/// only (a FIFO is refused before it is opened), at most 1 MiB.
pub(super) fn read_json(path: &Path) -> Result<Option<Value>, IoError> {
    let f = match crate::open_regular(path) {
        Ok(f) => f,
        Err(IoError::Io { source, .. }) if source.kind() == std::io::ErrorKind::NotFound => {
            return Ok(None);
        }
        Err(e) => return Err(e),
    };
    let mut b = Vec::new();
    std::io::Read::read_to_end(
        &mut std::io::Read::take(f, crate::MAX_HEADER as u64 + 1),
        &mut b,
    )
    .map_err(|e| IoError::io(path, e))?;
    if b.len() > crate::MAX_HEADER {
        return Err(IoError::header(path, "metadata longer than 1 MiB"));
    }
    serde_json::from_slice(&b)
        .map(Some)
        .map_err(|e| IoError::header(path, e.to_string()))
}

fn zerr(path: &Path, e: impl std::fmt::Display) -> IoError {
    IoError::decode(path, "OME-Zarr", e)
}

/// A node's `coordinateTransformations` (the multiscale's or a dataset's):
/// its scale and translation, each `n` finite numbers when present
/// (identity otherwise), and whether it had a scale. Anything else (a
/// scale of the wrong length, `"NaN"`, a transform read from a file) is a
/// typed error, never a silent 1.
fn transforms(
    v: &Value,
    n: usize,
    file: &Path,
    what: &str,
) -> Result<(Vec<f64>, Vec<f64>, bool), IoError> {
    let bad = |msg: String| IoError::header(file, format!("{what}: {msg}"));
    let (mut scale, mut trans) = (None, None);
    let list = match v.get("coordinateTransformations") {
        None => return Ok((vec![1.0; n], vec![0.0; n], false)),
        Some(Value::Array(list)) => list,
        Some(other) => {
            return Err(bad(format!(
                "coordinateTransformations is {other}, not a list"
            )));
        }
    };
    for t in list {
        let kind = t.get("type").and_then(Value::as_str).unwrap_or("");
        let nums = |k: &str| -> Result<Vec<f64>, IoError> {
            let Some(a) = t.get(k).and_then(Value::as_array) else {
                return Err(if t.get("path").is_some() {
                    IoError::unsupported(
                        file,
                        format!("{what}: a {kind} transform stored in a file"),
                    )
                } else {
                    bad(format!("a {kind} transform without a `{k}` list"))
                });
            };
            if a.len() != n {
                return Err(bad(format!("{k} has {} entries for {n} axes", a.len())));
            }
            a.iter()
                .map(|x| {
                    x.as_f64()
                        .filter(|f| f.is_finite())
                        .ok_or_else(|| bad(format!("{k} entry {x} is not a finite number")))
                })
                .collect()
        };
        let slot = match kind {
            "scale" => &mut scale,
            "translation" => &mut trans,
            "identity" => continue,
            other => {
                return Err(IoError::unsupported(
                    file,
                    format!("{what}: a coordinate transformation of type {other:?}"),
                ));
            }
        };
        if slot.replace(nums(kind)?).is_some() {
            return Err(bad(format!("two {kind} transforms")));
        }
    }
    let had = scale.is_some();
    Ok((
        scale.unwrap_or_else(|| vec![1.0; n]),
        trans.unwrap_or_else(|| vec![0.0; n]),
        had,
    ))
}

/// Opens the array at `path` in the store, re-created from its zarr v3 form
/// (so that a v2 compressor goes through the bounded codecs too), and
/// checks its chunk geometry: no decoded chunk or shard index larger than
/// [`MAX_CHUNK_BYTES`] (a chunk shape forged to 2^31 per axis would
/// otherwise read as fill values, or make a decoder allocate for it).
fn open_array(
    store: &Arc<SafeStore>,
    lp: &Path,
    path: &str,
    sample: u64,
) -> Result<(ZArray, Vec<u64>), IoError> {
    let err = |e: &dyn std::fmt::Display| store.take_error().unwrap_or_else(|| zerr(lp, e));
    let array = ZArray::open(store.clone(), path).map_err(|e| err(&e))?;
    let array = array.to_v3().map_err(|e| err(&e))?;
    let ArrayMetadata::V3(meta) = array.metadata().clone() else {
        return Err(zerr(lp, "not convertible to zarr v3 metadata"));
    };
    let json = serde_json::to_value(&meta).map_err(|e| err(&e))?;
    let array = ZArray::new_with_metadata(store.clone(), path, ArrayMetadata::V3(meta))
        .map_err(|e| err(&e))?;
    let zeros = vec![0u64; array.shape().len()];
    let chunk: Vec<u64> = array
        .chunk_shape(&zeros)
        .map_err(|e| err(&e))?
        .iter()
        .map(|c| c.get())
        .collect();
    let codecs = json.get("codecs").cloned().unwrap_or(Value::Null);
    let mut unit = chunk.clone();
    if let Some(ix) = check_chunk(lp, &chunk, &codecs, sample)? {
        store.add_sharded(format!("{}/", path.trim_matches('/')), ix);
        // checked there: the sharding codec's inner chunk shape
        unit = codecs
            .as_array()
            .and_then(|l| {
                l.iter().find_map(|c| {
                    (c.get("name")?.as_str()? == "sharding_indexed")
                        .then(|| c.get("configuration")?.get("chunk_shape")?.as_array())?
                })
            })
            .map(|a| a.iter().filter_map(Value::as_u64).collect())
            .unwrap_or(chunk);
    }
    Ok((array, unit))
}

/// Checks one chunk shape (or shard shape) and, through a sharding codec,
/// the inner chunks and the index; the index's layout when sharded.
fn check_chunk(
    lp: &Path,
    chunk: &[u64],
    codecs: &Value,
    sample: u64,
) -> Result<Option<safe::ShardIndex>, IoError> {
    let elems = chunk
        .iter()
        .try_fold(1u64, |a, &c| a.checked_mul(c))
        .filter(|&e| e > 0);
    let sharding = codecs.as_array().and_then(|l| {
        l.iter()
            .find(|c| c.get("name").and_then(Value::as_str) == Some("sharding_indexed"))
    });
    let Some(sh) = sharding else {
        let bytes = elems.and_then(|e| e.checked_mul(sample));
        if bytes.is_none_or(|b| b > MAX_CHUNK_BYTES) {
            return Err(IoError::header(
                lp,
                format!(
                    "chunks of {chunk:?} samples ({}) exceed {MAX_CHUNK_BYTES} bytes",
                    bytes.map_or("overflowing u64".into(), |b| format!("{b} bytes"))
                ),
            ));
        }
        return Ok(None);
    };
    // A shard is read in parts: its index (16 bytes per inner chunk) and the
    // inner chunks it needs.
    let cfg = sh.get("configuration").cloned().unwrap_or(Value::Null);
    let inner: Vec<u64> = cfg
        .get("chunk_shape")
        .and_then(Value::as_array)
        .map(|a| a.iter().filter_map(Value::as_u64).collect())
        .unwrap_or_default();
    if inner.len() != chunk.len() || inner.contains(&0) {
        return Err(IoError::header(
            lp,
            format!("sharding: inner chunks {inner:?} for shards {chunk:?}"),
        ));
    }
    let entries = chunk
        .iter()
        .zip(&inner)
        .try_fold(1u64, |a, (&s, &c)| a.checked_mul(s.div_ceil(c)));
    let Some(entries) = entries.filter(|&e| e <= MAX_CHUNK_BYTES / 16) else {
        return Err(IoError::header(
            lp,
            format!(
                "sharding: shards of {chunk:?} in inner chunks of {inner:?}: the index exceeds {MAX_CHUNK_BYTES} bytes"
            ),
        ));
    };
    // The index: little-endian u64 pairs, optionally with a crc32c, at the
    // start or the end; anything else is not read.
    let names: Vec<&str> = cfg
        .get("index_codecs")
        .and_then(Value::as_array)
        .map(|l| l.iter().filter_map(|c| c.get("name")?.as_str()).collect())
        .unwrap_or_default();
    let endian = cfg
        .get("index_codecs")
        .and_then(|l| l.get(0))
        .and_then(|c| c.get("configuration"))
        .and_then(|c| c.get("endian"))
        .and_then(Value::as_str);
    let trailer = match (names.as_slice(), endian) {
        (["bytes"], Some("little") | None) => 0,
        (["bytes", "crc32c"], Some("little") | None) => 4,
        _ => {
            return Err(IoError::unsupported(
                lp,
                format!("a shard index encoded as {names:?} ({endian:?} endian)"),
            ));
        }
    };
    let at_end = match cfg.get("index_location").and_then(Value::as_str) {
        None | Some("end") => true,
        Some("start") => false,
        Some(other) => {
            return Err(IoError::unsupported(
                lp,
                format!("a shard index at {other:?}"),
            ));
        }
    };
    let inner_codecs = cfg.get("codecs").unwrap_or(&Value::Null);
    if check_chunk(lp, &inner, inner_codecs, sample)?.is_some() {
        return Err(IoError::unsupported(lp, "shards within shards"));
    }
    Ok(Some(safe::ShardIndex {
        entries,
        trailer,
        at_end,
    }))
}

impl OmeZarr {
    /// The description of `dims` samples of `dtype` at `spacing` whose data
    /// range is `range`: a label image is a label map
    /// (`VolumeKind::Labels`, the label value range; u8, u16 or u32 ids).
    pub(crate) fn volume_desc(
        &self,
        root: &Path,
        dims: [u64; 3],
        dtype: brickray_core::DType,
        spacing: [f64; 3],
        range: [f64; 2],
    ) -> Result<VolumeDesc, IoError> {
        let labels = self.is_labels();
        let desc = VolumeDesc {
            dims: dims.map(|d| d as u32),
            dtype,
            spacing: spacing.map(|v| v as f32),
            value_range: if labels {
                brickray_core::labels::label_value_range()
            } else {
                desc_range(root, range)?
            },
            kind: if labels {
                brickray_core::VolumeKind::Labels
            } else {
                Default::default()
            },
        };
        desc.validate().map_err(|e| IoError::volume(root, e))?;
        Ok(desc)
    }

    /// Opens the group at `root` (a `.zarr` folder).
    pub fn open(root: &Path) -> Result<OmeZarr, IoError> {
        OmeZarr::open_in(Arc::new(SafeStore::new(root)))
    }

    /// Opens the group whose objects `reader` reads by key (`zarr.json`,
    /// `s0/c/0/0/0`, ...): an image over HTTP or in a bucket. Reads the
    /// metadata only (the group's and each level's).
    pub fn open_objects(reader: Arc<dyn ObjectReader>) -> Result<OmeZarr, IoError> {
        OmeZarr::open_in(Arc::new(SafeStore::objects(reader)))
    }

    fn open_in(store: Arc<SafeStore>) -> Result<OmeZarr, IoError> {
        safe::install();
        let root = store.root().to_owned();
        let root = root.as_path();
        let (attrs, meta_path) = if let Some(v) = store.json("zarr.json")? {
            let a = v
                .get("attributes")
                .and_then(|a| a.get("ome"))
                .cloned()
                .unwrap_or(Value::Null);
            (a, root.join("zarr.json"))
        } else if let Some(v) = store.json(".zattrs")? {
            (v, root.join(".zattrs"))
        } else {
            return Err(IoError::UnknownFormat {
                path: root.to_owned(),
                tried: if store.is_local() {
                    "OME-Zarr: no zarr.json or .zattrs".into()
                } else {
                    "OME-Zarr: no zarr.json or .zattrs (not found, or access denied: \
                     S3 answers 403 for both; check the URL and the credentials)"
                        .into()
                },
            });
        };
        let bad = |msg: &str| IoError::header(&meta_path, msg.to_owned());
        let ms = attrs
            .get("multiscales")
            .and_then(Value::as_array)
            .and_then(|m| m.first())
            .ok_or_else(|| bad("no multiscales (not an OME-Zarr image)"))?;
        let version = ms
            .get("version")
            .or(attrs.get("version"))
            .and_then(Value::as_str)
            .unwrap_or("0.4")
            .to_owned();
        if !matches!(version.as_str(), "0.4" | "0.5") {
            return Err(IoError::unsupported(
                &meta_path,
                format!("OME-Zarr version {version} (0.4 and 0.5 are read)"),
            ));
        }
        let axes = ms
            .get("axes")
            .and_then(Value::as_array)
            .ok_or_else(|| bad("multiscales has no axes"))?;
        let n = axes.len();
        let mut ax = [None; 5];
        let mut order = Vec::new();
        for (i, a) in axes.iter().enumerate() {
            let name = a.get("name").and_then(Value::as_str).unwrap_or("");
            let kind = a.get("type").and_then(Value::as_str).unwrap_or("");
            let slot = match (name, kind) {
                ("x", _) => 0,
                ("y", _) => 1,
                ("z", _) => 2,
                (_, "channel") | ("c", _) => 3,
                (_, "time") | ("t", _) => 4,
                _ => {
                    return Err(IoError::unsupported(
                        &meta_path,
                        format!("axis {name:?} of type {kind:?}"),
                    ));
                }
            };
            if ax[slot].replace(i).is_some() {
                return Err(bad("an axis appears twice"));
            }
            order.push(slot);
        }
        if ax[0].is_none() || ax[1].is_none() {
            return Err(bad("no x or y axis"));
        }
        // OME-NGFF orders axes t, c, z, y, x: x is the fastest in memory.
        if order.windows(2).any(|w| w[0] < w[1]) {
            return Err(IoError::unsupported(
                &meta_path,
                "axes not in the standard t, c, z, y, x order",
            ));
        }
        let (gscale, gtrans, _) = transforms(ms, n, &meta_path, "multiscales")?;
        let mut warnings = Vec::new();
        let datasets = ms
            .get("datasets")
            .and_then(Value::as_array)
            .filter(|d| !d.is_empty())
            .ok_or_else(|| bad("multiscales has no datasets"))?;
        // Every level's array metadata in one round trip over the network
        // (the loop below then reads it from the cache).
        let v3 = meta_path.ends_with("zarr.json");
        let keys: Vec<String> = datasets
            .iter()
            .filter_map(|d| d.get("path").and_then(Value::as_str))
            .filter(|p| !p.split('/').any(|c| c == ".." || c.is_empty()))
            .map(|p| format!("{p}/{}", if v3 { "zarr.json" } else { ".zarray" }))
            .collect();
        store.prefetch_json(&keys);
        let mut levels = Vec::new();
        let mut src = None;
        for d in datasets {
            let path = d
                .get("path")
                .and_then(Value::as_str)
                .ok_or_else(|| bad("a dataset has no path"))?
                .to_owned();
            let lp = root.join(&path);
            if path.split('/').any(|c| c == ".." || c.is_empty()) {
                return Err(bad("a dataset path leaves the group"));
            }
            // the array's own metadata first (a FIFO there is refused by
            // name), then zarrs' view of it
            let dtype = array_dtype(&store, &path, &lp)?;
            let (array, unit) = open_array(&store, &lp, &format!("/{path}"), dtype.size() as u64)?;
            let shape = array.shape().to_vec();
            if shape.len() != n {
                return Err(IoError::header(
                    &lp,
                    format!("{} dims, the axes say {n}", shape.len()),
                ));
            }
            if src.is_some_and(|s| s != dtype) {
                return Err(IoError::Inconsistent {
                    path: root.to_owned(),
                    file: lp,
                    msg: "levels of different sample types".into(),
                });
            }
            src = Some(dtype);
            let (mut scale, mut trans, had_scale) =
                transforms(d, n, &meta_path, &format!("dataset {path:?}"))?;
            if !had_scale {
                warnings.push(format!(
                    "level {path} has no scale transform: its voxels are taken as 1 x 1 x 1"
                ));
            }
            for i in 0..n {
                trans[i] = trans[i] * gscale[i] + gtrans[i];
                scale[i] *= gscale[i];
                if !(scale[i].is_finite() && scale[i] > 0.0 && trans[i].is_finite()) {
                    return Err(IoError::header(
                        &lp,
                        "scale or translation not a positive finite number",
                    ));
                }
            }
            levels.push(Level {
                path,
                shape,
                scale,
                translation: trans,
                unit,
                array,
            });
        }
        let Some(src) = src else {
            return Err(bad("multiscales has no datasets"));
        };
        let image_label = attrs.get("image-label").map(labels::image_label_colors);
        let channels = ax[3].map_or(1, |i| levels[0].shape[i]);
        let (channel_info, omero_warnings) = omero::channel_info(attrs.get("omero"), channels);
        warnings.extend(omero_warnings);
        Ok(OmeZarr {
            root: root.to_owned(),
            version,
            levels,
            ax,
            src,
            store,
            cache: ChunkCache::new(CHUNK_CACHE_BYTES),
            warnings,
            image_label,
            channel_info,
        })
    }

    /// Number of channels (the extent of the `c` axis; 1 without one).
    pub fn channel_count(&self) -> u64 {
        self.extent(3)
    }

    /// What the image's `omero` metadata says of channel `c` (its label,
    /// colour, window and whether it is active); the default where it says
    /// nothing or something malformed (then with a warning in
    /// [`warnings`](Self::warnings)).
    pub fn channel_info(&self, c: u64) -> crate::ChannelInfo {
        usize::try_from(c)
            .ok()
            .and_then(|c| self.channel_info.get(c))
            .cloned()
            .unwrap_or_default()
    }

    /// What was assumed where the metadata did not say (a level without a
    /// scale transform), one line each.
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }

    /// The OME-Zarr version (`"0.4"`, `"0.5"`).
    pub fn version(&self) -> &str {
        &self.version
    }

    /// Number of levels.
    pub fn level_count(&self) -> usize {
        self.levels.len()
    }

    /// Bytes of one stored sample (the array's data type).
    pub fn sample_bytes(&self) -> usize {
        self.src.size()
    }

    /// The finest level whose `channels` channels fit `max_bytes` of stored
    /// samples and `max_side` voxels a side (what the in-core renderers can
    /// take whole); `None` when not even the coarsest does.
    pub fn level_fitting(&self, channels: u64, max_bytes: u64, max_side: u64) -> Option<usize> {
        (0..self.level_count()).find(|&l| {
            self.level_dims(l).is_some_and(|d| {
                let bytes = d.iter().try_fold(
                    channels.saturating_mul(self.sample_bytes() as u64),
                    |a, &x| a.checked_mul(x),
                );
                d.iter().all(|&x| x <= max_side) && bytes.is_some_and(|b| b <= max_bytes)
            })
        })
    }

    /// Voxel dims (x, y, z) of a level; `None` past the last level.
    pub fn level_dims(&self, level: usize) -> Option<[u64; 3]> {
        let s = &self.levels.get(level)?.shape;
        Some([0, 1, 2].map(|a| self.ax[a].map_or(1, |i| s[i])))
    }

    /// Voxel dims (x, y, z) of a level that exists.
    pub(crate) fn dims(&self, level: usize) -> [u64; 3] {
        self.level_dims(level).unwrap_or([1; 3])
    }

    fn extent(&self, slot: usize) -> u64 {
        self.ax[slot].map_or(1, |i| self.levels[0].shape[i])
    }

    /// Spacing and translation (x, y, z) of a level.
    fn xyz(&self, level: usize) -> ([f64; 3], [f64; 3]) {
        let l = &self.levels[level];
        (
            [0, 1, 2].map(|a| self.ax[a].map_or(1.0, |i| l.scale[i])),
            [0, 1, 2].map(|a| self.ax[a].map_or(0.0, |i| l.translation[i])),
        )
    }

    fn check_choice(&self, opts: &ReadOptions) -> Result<(usize, u64, u64), IoError> {
        let level = opts.level.unwrap_or(0);
        let c = opts.channel.unwrap_or(0);
        let t = opts.time.unwrap_or(0);
        let fail = |what, wanted: String, n: u64| IoError::NoSuchChoice {
            path: self.root.clone(),
            what,
            wanted,
            available: format!("0..{n}"),
        };
        if level >= self.levels.len() {
            return Err(fail("level", level.to_string(), self.levels.len() as u64));
        }
        if c >= self.extent(3) {
            return Err(fail("channel", c.to_string(), self.extent(3)));
        }
        if t >= self.extent(4) {
            return Err(fail("time point", t.to_string(), self.extent(4)));
        }
        Ok((level, c, t))
    }

    /// The selectable levels, channels and time points.
    pub fn entries(&self, opts: &ReadOptions) -> Vec<Entry> {
        let mut v: Vec<Entry> = (0..self.levels.len())
            .map(|i| {
                let (s, _) = self.xyz(i);
                Entry {
                    kind: EntryKind::Level,
                    id: i.to_string(),
                    summary: format!(
                        "{}: {:?} voxels (x, y, z), spacing {:?}",
                        self.levels[i].path,
                        self.dims(i),
                        s
                    ),
                    default: i == opts.level.unwrap_or(0),
                }
            })
            .collect();
        for (slot, kind, what) in [
            (3, EntryKind::Channel, "channel"),
            (4, EntryKind::Time, "time point"),
        ] {
            let n = self.extent(slot);
            let pick = if slot == 3 { opts.channel } else { opts.time }.unwrap_or(0);
            if n > 1 {
                v.extend((0..n).map(|i| Entry {
                    kind,
                    id: i.to_string(),
                    summary: format!("{what} {i} of {n}"),
                    default: i == pick,
                }));
            }
        }
        v
    }
}

/// The sample type from the array's own metadata.
fn array_dtype(store: &SafeStore, key: &str, level: &Path) -> Result<SourceType, IoError> {
    let (name, file) = if let Some(v) = store.json(&format!("{key}/zarr.json"))? {
        (
            v.get("data_type")
                .and_then(Value::as_str)
                .unwrap_or("")
                .to_owned(),
            level.join("zarr.json"),
        )
    } else if let Some(v) = store.json(&format!("{key}/.zarray"))? {
        let d = v.get("dtype").and_then(Value::as_str).unwrap_or("");
        let n = match d.trim_start_matches(['<', '>', '|', '=']) {
            "u1" => "uint8",
            "i1" => "int8",
            "u2" => "uint16",
            "i2" => "int16",
            "u4" => "uint32",
            "i4" => "int32",
            "f4" => "float32",
            "f8" => "float64",
            other => other,
        };
        (n.to_owned(), level.join(".zarray"))
    } else {
        return Err(IoError::header(level, "no zarr.json or .zarray"));
    };
    Ok(match name.as_str() {
        "uint8" => SourceType::U8,
        "int8" => SourceType::I8,
        "uint16" => SourceType::U16,
        "int16" => SourceType::I16,
        "uint32" => SourceType::U32,
        "int32" => SourceType::I32,
        "float32" => SourceType::F32,
        "float64" => SourceType::F64,
        _ => {
            return Err(IoError::UnknownDType { path: file, name });
        }
    })
}

#[derive(Debug)]
struct ZarrFormat;

impl Format for ZarrFormat {
    fn name(&self) -> &'static str {
        "OME-Zarr"
    }
    fn expects(&self) -> &'static str {
        "a .zarr folder (OME-Zarr 0.4 or 0.5)"
    }
    fn claims(&self, probe: &Probe) -> Claim {
        if !probe.is_dir() {
            return Claim::No;
        }
        if probe.ext == "zarr" {
            return Claim::ByName;
        }
        if probe.path.join("zarr.json").is_file() || probe.path.join(".zattrs").is_file() {
            return Claim::ByContent;
        }
        Claim::No
    }
    fn open(&self, path: &Path, opts: &ReadOptions) -> Result<Box<dyn VolumeReader>, IoError> {
        Ok(Box::new(ZarrReader::open(path, opts)?))
    }
    fn list(&self, path: &Path, opts: &ReadOptions) -> Result<Vec<Entry>, IoError> {
        Ok(OmeZarr::open(path)?.entries(opts))
    }
    fn open_channels(
        &self,
        path: &Path,
        opts: &ReadOptions,
    ) -> Result<crate::ChannelReaders, IoError> {
        ZarrReader::open_channels(path, opts)
    }
}

pub(crate) fn register(r: &mut Registry) {
    r.register(Arc::new(ZarrFormat));
}
