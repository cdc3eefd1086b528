//! Raw little-endian samples with a JSON sidecar (the form of `shared/data`).
//!
//! A sidecar with `"affine"` (a row-major voxel-to-world matrix, 4x4 with last
//! row `0 0 0 1`, or its first 3 rows) and `"affine_space"` (`"RAS"`, `"LPS"`
//! or `"image"`), as `brickray-store convert` writes them, places the volume
//! ([`VolumeReader::placement`]). An `"affine"` without `"affine_space"` (older
//! sidecars copied a NIfTI affine so) is not used, and the reader's notes say
//! so; an `"affine_space"` without `"affine"` is an error.
//!
//! A sidecar with `"channels": N` describes N channels of `dims` and `dtype`
//! stored planar, channel slowest (channel 0's whole volume first, then
//! channel 1's: OME's c, z, y, x order); the raw file holds exactly N
//! volumes. [`ReadOptions::channel`] picks the one a [`RawReader`] reads,
//! [`crate::read_channels`] reads them all. A declared `value_range` is every
//! channel's; without one each channel's is scanned from its own samples.

use super::{
    IoError, MAX_HEADER, Placement, ReadOptions, VolumeReader, check_slab, open_regular,
    resolve_data_file, scan_stream,
};
use brickray_core::volume::{DType, VolumeDesc, VolumeKind};
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

/// Reads raw samples (x fastest, then y, then z) from a file at an offset.
#[derive(Debug)]
pub struct RawReader {
    path: PathBuf,
    /// The sidecar it was opened from, if any.
    sidecar: Option<PathBuf>,
    file: File,
    offset: u64,
    desc: VolumeDesc,
    /// The sidecar's `affine` and `affine_space`.
    placement: Option<Placement>,
    notes: Vec<String>,
}

#[derive(serde::Deserialize)]
struct Sidecar {
    dims: Vec<u64>,
    dtype: String,
    // f64, narrowed below: 1e39 becomes infinity (a typed spacing error)
    // whatever serde_json's features (some make f32 out of range a parse error)
    #[serde(default)]
    spacing: Option<Vec<f64>>,
    #[serde(default)]
    file: Option<String>,
    #[serde(default)]
    byte_order: Option<String>,
    #[serde(default)]
    value_range: Option<Vec<f64>>,
    /// `"labels"` (or `"intensity"`); a `labels` list also declares a label
    /// map.
    #[serde(default)]
    kind: Option<String>,
    #[serde(default)]
    labels: Option<serde_json::Value>,
    /// Row-major voxel-to-world matrix (4x4, or 3x4 without the last row).
    #[serde(default)]
    affine: Option<serde_json::Value>,
    /// `"RAS"`, `"LPS"` or `"image"`.
    #[serde(default)]
    affine_space: Option<serde_json::Value>,
    /// Channels in the raw file, planar: channel 0's whole volume first.
    #[serde(default)]
    channels: Option<serde_json::Value>,
}

impl RawReader {
    /// Opens a raw file of known description. `desc.value_range` is used as given.
    /// The file must be a regular file (a FIFO or a device is refused before it
    /// is opened) holding exactly `offset + desc.byte_len()` bytes.
    pub fn new(
        path: impl Into<PathBuf>,
        offset: u64,
        desc: VolumeDesc,
    ) -> Result<RawReader, IoError> {
        RawReader::planar(path.into(), offset, desc, 1, 0)
    }

    /// Channel `channel` of a raw file of `channels` planar channels (each a
    /// whole volume of `desc`, channel 0 first) after `offset` bytes: the
    /// file must hold exactly `offset + channels * desc.byte_len()` bytes.
    fn planar(
        path: PathBuf,
        offset: u64,
        desc: VolumeDesc,
        channels: u64,
        channel: u64,
    ) -> Result<RawReader, IoError> {
        desc.validate().map_err(|e| IoError::volume(&path, e))?;
        let file = open_regular(&path)?;
        let actual = file.metadata().map_err(|e| IoError::io(&path, e))?.len();
        let expected = offset.saturating_add(channels.saturating_mul(desc.byte_len()));
        if actual != expected {
            return Err(IoError::SizeMismatch {
                path,
                expected,
                actual,
            });
        }
        Ok(RawReader {
            path,
            sidecar: None,
            file,
            offset: offset + channel * desc.byte_len(),
            desc,
            placement: None,
            notes: Vec::new(),
        })
    }

    /// Opens `name.json` and the raw file it names (`"file"`, else `name.raw`).
    /// When the sidecar gives no `value_range`, the data is scanned for one.
    /// The raw file must resolve inside the sidecar's folder (see
    /// [`open_sidecar_with`](Self::open_sidecar_with)); both must be regular
    /// files.
    pub fn open_sidecar(json: &Path) -> Result<RawReader, IoError> {
        RawReader::open_sidecar_with(json, &ReadOptions::default())
    }

    /// [`open_sidecar`](Self::open_sidecar) with options:
    /// [`ReadOptions::allow_outside_dir`] lets `"file"` name a file outside the
    /// sidecar's folder.
    pub fn open_sidecar_with(json: &Path, opts: &ReadOptions) -> Result<RawReader, IoError> {
        let sc = load_sidecar(json)?;
        let spacing_f32 = sc
            .spacing
            .as_ref()
            .map(|v| v.iter().map(|&x| x as f32).collect::<Vec<f32>>());
        let range_f32 = sc
            .value_range
            .as_ref()
            .map(|v| v.iter().map(|&x| x as f32).collect::<Vec<f32>>());
        if sc.dims.len() != 3 {
            return Err(IoError::header(
                json,
                format!("dims must have 3 entries, got {}", sc.dims.len()),
            ));
        }
        let dims64 = [sc.dims[0], sc.dims[1], sc.dims[2]];
        brickray_core::volume::voxel_count(dims64).map_err(|e| IoError::volume(json, e))?;
        let dims = dims64.map(|d| d as u32);
        let dtype = DType::parse(&sc.dtype).ok_or_else(|| IoError::UnknownDType {
            path: json.to_owned(),
            name: sc.dtype.clone(),
        })?;
        if let Some(order) = &sc.byte_order
            && !order.eq_ignore_ascii_case("little")
            && dtype.size() > 1
        {
            return Err(IoError::Unsupported {
                path: json.to_owned(),
                what: format!("byte_order {order:?} (only little-endian)"),
            });
        }
        let spacing = match spacing_f32.as_deref() {
            None => [1.0; 3],
            Some([a, b, c]) => [*a, *b, *c],
            Some(s) => {
                return Err(IoError::header(
                    json,
                    format!("spacing must have 3 entries, got {}", s.len()),
                ));
            }
        };
        let raw = match &sc.file {
            Some(f) => resolve_data_file(json, Path::new(f), opts)?,
            None => {
                let name = json.with_extension("raw");
                resolve_data_file(json, Path::new(name.file_name().unwrap_or_default()), opts)?
            }
        };
        if same_file(json, &raw) {
            return Err(IoError::header(
                json,
                format!(
                    "the sidecar names itself as its raw file ({})",
                    raw.display()
                ),
            ));
        }
        if let Some(&v) = range_f32
            .as_deref()
            .and_then(|r| r.iter().find(|v| !v.is_finite()))
        {
            return Err(IoError::NonFiniteValue {
                path: json.to_owned(),
                field: "value_range",
                value: v,
            });
        }
        let declared = match range_f32.as_deref() {
            Some([lo, hi]) if lo.is_finite() && hi.is_finite() && hi > lo => Some([*lo, *hi]),
            Some(r) => {
                return Err(IoError::header(
                    json,
                    format!("value_range must be [lo, hi] with lo < hi, got {r:?}"),
                ));
            }
            None => None,
        };
        let kind = match sc.kind.as_deref() {
            Some(k) => VolumeKind::parse(k).ok_or_else(|| {
                IoError::header(
                    json,
                    format!("kind {k:?}: expected \"labels\" or \"intensity\""),
                )
            })?,
            None if sc.labels.is_some() => VolumeKind::Labels,
            None => VolumeKind::Intensity,
        };
        let (placement, notes) = match (&sc.affine, &sc.affine_space) {
            (Some(a), Some(sp)) => (Some(sidecar_placement(json, a, sp)?), Vec::new()),
            (Some(_), None) => (
                None,
                vec![
                    "the sidecar's \"affine\" has no \"affine_space\": not used as a placement"
                        .to_owned(),
                ],
            ),
            (None, Some(_)) => {
                return Err(IoError::header(
                    json,
                    "\"affine_space\" without an \"affine\"",
                ));
            }
            (None, None) => (None, Vec::new()),
        };
        let channels = sidecar_channels(json, &sc)?;
        let channel = opts.channel.unwrap_or(0);
        if channel >= channels {
            return Err(IoError::NoSuchChoice {
                path: json.to_owned(),
                what: "channel",
                wanted: channel.to_string(),
                available: format!("0..{channels}"),
            });
        }
        let labels = kind.is_labels();
        let desc = VolumeDesc {
            dims,
            dtype,
            spacing,
            value_range: if labels {
                brickray_core::labels::label_value_range()
            } else {
                declared.unwrap_or([0.0, 1.0])
            },
            kind,
        };
        desc.validate().map_err(|e| IoError::volume(json, e))?;
        let mut reader = RawReader::planar(raw, 0, desc, channels, channel)?;
        reader.sidecar = Some(json.to_owned());
        reader.placement = placement;
        reader.notes = notes;
        if channels > 1 {
            reader
                .notes
                .push(format!("channel {channel} of {channels} (planar)"));
        }
        if declared.is_none() && !labels {
            reader.desc.value_range = reader.scan()?;
        }
        Ok(reader)
    }
}

/// A sidecar's JSON (a regular file of at most 1 MiB).
fn load_sidecar(json: &Path) -> Result<Sidecar, IoError> {
    let mut bytes = Vec::new();
    open_regular(json)?
        .take(MAX_HEADER as u64 + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| IoError::io(json, e))?;
    if bytes.len() > MAX_HEADER {
        return Err(IoError::header(json, "sidecar longer than 1 MiB"));
    }
    let text =
        String::from_utf8(bytes).map_err(|_| IoError::header(json, "sidecar is not UTF-8"))?;
    serde_json::from_str(&text).map_err(|e| IoError::header(json, e.to_string()))
}

/// A sidecar's `channels`: a positive integer, 1 when absent.
fn sidecar_channels(json: &Path, sc: &Sidecar) -> Result<u64, IoError> {
    match &sc.channels {
        None => Ok(1),
        Some(v) => v.as_u64().filter(|&n| n > 0).ok_or_else(|| {
            IoError::header(json, format!("channels is {v}, not a positive integer"))
        }),
    }
}

/// The placement a sidecar's `affine` and `affine_space` give: 3 or 4 rows of
/// 4 finite numbers (a 4th row must be `0 0 0 1`) whose 3x3 part spans space,
/// in `"RAS"`, `"LPS"` or `"image"` space.
fn sidecar_placement(
    json: &Path,
    affine: &serde_json::Value,
    space: &serde_json::Value,
) -> Result<Placement, IoError> {
    let space = match space.as_str() {
        Some(s) if s.eq_ignore_ascii_case("RAS") => "RAS",
        Some(s) if s.eq_ignore_ascii_case("LPS") => "LPS",
        Some(s) if s.eq_ignore_ascii_case("image") => "image",
        _ => {
            return Err(IoError::header(
                json,
                format!("affine_space {space}: expected \"RAS\", \"LPS\" or \"image\""),
            ));
        }
    };
    let bad = |what: &str| {
        IoError::header(
            json,
            format!("affine must be 4 rows (or 3) of 4 numbers, row-major: {what}"),
        )
    };
    let rows = affine.as_array().ok_or_else(|| bad("not an array"))?;
    if !(rows.len() == 3 || rows.len() == 4) {
        return Err(bad(&format!("{} rows", rows.len())));
    }
    let mut a = [[0.0f64; 4]; 4];
    a[3][3] = 1.0;
    for (r, row) in rows.iter().enumerate() {
        let row = row
            .as_array()
            .ok_or_else(|| bad(&format!("row {r} is not an array")))?;
        if row.len() != 4 {
            return Err(bad(&format!("row {r} has {} entries", row.len())));
        }
        for (c, v) in row.iter().enumerate() {
            let x = v
                .as_f64()
                .ok_or_else(|| bad(&format!("[{r}][{c}] is {v}, not a number")))?;
            if !x.is_finite() {
                return Err(IoError::NonFiniteValue {
                    path: json.to_owned(),
                    field: "affine",
                    value: x as f32,
                });
            }
            a[r][c] = x;
        }
    }
    if a[3] != [0.0, 0.0, 0.0, 1.0] {
        return Err(IoError::header(
            json,
            format!("affine's last row is {:?}, not [0, 0, 0, 1]", a[3]),
        ));
    }
    let col = |c: usize| (a[0][c] * a[0][c] + a[1][c] * a[1][c] + a[2][c] * a[2][c]).sqrt();
    let scale = col(0) * col(1) * col(2);
    let det = a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
        - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
        + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
    if !(scale > 0.0 && det.is_finite() && det.abs() > 1e-9 * scale) {
        return Err(IoError::header(
            json,
            format!("affine's voxel axes do not span space (determinant {det})"),
        ));
    }
    Ok(Placement { affine: a, space })
}

/// Whether two paths name one file (the same path after `.` and `..`, a
/// symbolic or a hard link): by device and inode where the OS has them.
fn same_file(a: &Path, b: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        if let (Ok(x), Ok(y)) = (std::fs::metadata(a), std::fs::metadata(b)) {
            return x.dev() == y.dev() && x.ino() == y.ino();
        }
    }
    matches!((a.canonicalize(), b.canonicalize()), (Ok(x), Ok(y)) if x == y)
}

impl RawReader {
    /// One bounded-memory pass over the samples for their value range.
    fn scan(&mut self) -> Result<[f32; 2], IoError> {
        self.file
            .seek(SeekFrom::Start(self.offset))
            .map_err(|e| IoError::io(&self.path, e))?;
        let path = self.path.clone();
        let io_err = |e: std::io::Error, _pos: u64| IoError::io(&path, e);
        scan_stream(&self.path, &self.desc, false, &mut self.file, &io_err)
    }
}

impl VolumeReader for RawReader {
    fn desc(&self) -> &VolumeDesc {
        &self.desc
    }

    fn format(&self) -> &'static str {
        "raw"
    }

    fn path(&self) -> &Path {
        &self.path
    }

    fn placement(&self) -> Option<Placement> {
        self.placement
    }

    fn notes(&self) -> Vec<String> {
        self.notes.clone()
    }

    fn input_files(&self) -> Vec<PathBuf> {
        self.sidecar
            .iter()
            .chain(std::iter::once(&self.path))
            .cloned()
            .collect()
    }

    fn read_slices(&mut self, z0: u32, z1: u32, out: &mut [u8]) -> Result<(), IoError> {
        let slice = check_slab(&self.desc, z0, z1, out)?;
        self.file
            .seek(SeekFrom::Start(self.offset + z0 as u64 * slice))
            .map_err(|e| IoError::io(&self.path, e))?;
        self.file.read_exact(out).map_err(|e| {
            if e.kind() == std::io::ErrorKind::UnexpectedEof {
                IoError::Truncated {
                    path: self.path.clone(),
                    expected: self.offset + self.desc.byte_len(),
                    actual: self.file.metadata().map(|m| m.len()).unwrap_or(0),
                }
            } else {
                IoError::io(&self.path, e)
            }
        })
    }
}

/// The raw + JSON sidecar format: `.json`, or a `.raw` beside its sidecar.
#[derive(Debug)]
struct RawFormat;

impl crate::Format for RawFormat {
    fn name(&self) -> &'static str {
        "raw"
    }
    fn expects(&self) -> &'static str {
        ".json sidecar, or .raw beside one"
    }
    fn claims(&self, probe: &crate::Probe) -> crate::Claim {
        match probe.ext.as_str() {
            "json" | "raw" => crate::Claim::ByName,
            _ => crate::Claim::No,
        }
    }
    fn open(&self, path: &Path, opts: &ReadOptions) -> Result<Box<dyn VolumeReader>, IoError> {
        Ok(Box::new(RawReader::open_sidecar_with(
            &sidecar_of(path),
            opts,
        )?))
    }
    fn list(&self, path: &Path, opts: &ReadOptions) -> Result<Vec<crate::Entry>, IoError> {
        let json = sidecar_of(path);
        let n = sidecar_channels(&json, &load_sidecar(&json)?)?;
        let pick = opts.channel.unwrap_or(0);
        Ok(if n > 1 {
            (0..n)
                .map(|i| crate::Entry {
                    kind: crate::EntryKind::Channel,
                    id: i.to_string(),
                    summary: format!("channel {i} of {n} (planar)"),
                    default: i == pick,
                })
                .collect()
        } else {
            Vec::new()
        })
    }
    fn open_channels(
        &self,
        path: &Path,
        opts: &ReadOptions,
    ) -> Result<crate::ChannelReaders, IoError> {
        let json = sidecar_of(path);
        let count = sidecar_channels(&json, &load_sidecar(&json)?)?;
        crate::ChannelReaders::open_each(&json, count, &[], opts, |o| {
            Ok(Box::new(RawReader::open_sidecar_with(&json, o)?))
        })
    }
}

/// The sidecar of `path`: itself, or a `.raw` file's `.json`.
fn sidecar_of(path: &Path) -> PathBuf {
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("raw"))
    {
        path.with_extension("json")
    } else {
        path.to_owned()
    }
}

pub(crate) fn register(r: &mut crate::Registry) {
    r.register(std::sync::Arc::new(RawFormat));
}
