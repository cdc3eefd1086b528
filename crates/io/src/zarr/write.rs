//! Writing a volume (or the channels of a multi-channel volume) as a
//! one-level OME-Zarr 0.4 image (Zarr v2, 64^3 uncompressed chunks): to hand
//! a volume (a label map with its colours, channels with their `omero`
//! colours and windows) to other OME-Zarr tools, and for tests of the
//! reader.

use crate::{ChannelInfo, IoError};
use brickray_core::{ChannelVolume, DType, LabelTable, Volume};
use serde_json::{Value, json};
use std::path::Path;

/// The chunk side.
const CHUNK: u64 = 64;

/// Writes `volume` at `dir` (created) as an OME-Zarr 0.4 image: axes z, y,
/// x in voxel units of its spacing, one level `0`. A label map is written as
/// a label image (`image-label`, with `table`'s colours of the ids listed in
/// `colors`, when given).
pub fn write_ome_zarr(
    dir: &Path,
    volume: &Volume,
    table: Option<(&LabelTable, &[u32])>,
) -> Result<(), IoError> {
    let d = volume.desc();
    let s = d.spacing;
    let mut attrs = json!({
        "multiscales": [{
            "version": "0.4",
            "axes": [
                {"name": "z", "type": "space"},
                {"name": "y", "type": "space"},
                {"name": "x", "type": "space"}
            ],
            "datasets": [{
                "path": "0",
                "coordinateTransformations": [{"type": "scale", "scale": [s[2], s[1], s[0]]}]
            }]
        }]
    });
    if d.kind.is_labels() {
        let colors: Vec<Value> = table
            .map(|(t, ids)| {
                ids.iter()
                    .map(|&id| {
                        let c = t.rgba(id).map(|v| (v * 255.0).round() as u8);
                        json!({"label-value": id, "rgba": c})
                    })
                    .collect()
            })
            .unwrap_or_default();
        attrs["image-label"] = json!({"version": "0.4", "colors": colors});
    }
    write_image(dir, &attrs, &[volume], false)
}

/// Writes the channels of `volume` at `dir` (created) as an OME-Zarr 0.4
/// image: axes c, z, y, x (one chunk per channel and 64^3 voxels), one level
/// `0`, and `omero` metadata of each channel from `info` (empty: none given;
/// else one per channel): its label when it has one, its colour (else
/// [`crate::CHANNEL_PALETTE`]'s, by index) as `"RRGGBB"`, its window (else
/// the channel's value range) as `window.start`/`end` with the value range
/// as `min`/`max`, and `active`.
pub fn write_ome_zarr_channels(
    dir: &Path,
    volume: &ChannelVolume,
    info: &[ChannelInfo],
) -> Result<(), IoError> {
    if !info.is_empty() && info.len() != volume.len() {
        return Err(IoError::header(
            dir,
            format!("{} channel infos for {} channels", info.len(), volume.len()),
        ));
    }
    let s = volume.desc().spacing;
    let channels: Vec<Value> = volume
        .channels()
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let default = ChannelInfo::default();
            let c = info.get(i).unwrap_or(&default);
            let [lo, hi] = v.desc().value_range;
            let [start, end] = c.window.unwrap_or([lo, hi]);
            let color = c
                .color
                .unwrap_or(crate::CHANNEL_PALETTE[i % crate::CHANNEL_PALETTE.len()]);
            let mut o = json!({
                "color": super::omero::hex_string(color),
                "window": {"start": start, "end": end, "min": lo, "max": hi},
                "active": c.active
            });
            if let Some(l) = &c.label {
                o["label"] = json!(l);
            }
            o
        })
        .collect();
    let attrs = json!({
        "multiscales": [{
            "version": "0.4",
            "axes": [
                {"name": "c", "type": "channel"},
                {"name": "z", "type": "space"},
                {"name": "y", "type": "space"},
                {"name": "x", "type": "space"}
            ],
            "datasets": [{
                "path": "0",
                "coordinateTransformations": [{"type": "scale", "scale": [1.0, s[2], s[1], s[0]]}]
            }]
        }],
        "omero": {"version": "0.4", "channels": channels, "rdefs": {"model": "color"}}
    });
    let vols: Vec<&Volume> = volume.channels().iter().collect();
    write_image(dir, &attrs, &vols, true)
}

/// Writes the group (`.zgroup`, `.zattrs` holding `attrs`) and its level
/// `0` of `volumes` (one grid and type): with a `c` axis when `c_axis`
/// (then one chunk per channel), else the one volume as z, y, x.
fn write_image(
    dir: &Path,
    attrs: &Value,
    volumes: &[&Volume],
    c_axis: bool,
) -> Result<(), IoError> {
    let d = volumes[0].desc();
    let [nx, ny, nz] = d.dims.map(u64::from);
    let dtype = match d.dtype {
        DType::U8 => "|u1",
        DType::U16 => "<u2",
        DType::I16 => "<i2",
        DType::U32 => "<u4",
        DType::F32 => "<f4",
        other => {
            return Err(IoError::unsupported(
                dir,
                format!("writing {} samples to OME-Zarr", other.name()),
            ));
        }
    };
    let io = |p: &Path, e: std::io::Error| IoError::io(p, e);
    let write = |p: &Path, bytes: &[u8]| std::fs::write(p, bytes).map_err(|e| io(p, e));
    std::fs::create_dir_all(dir.join("0")).map_err(|e| io(dir, e))?;
    write(&dir.join(".zgroup"), br#"{"zarr_format": 2}"#)?;
    write(&dir.join(".zattrs"), attrs.to_string().as_bytes())?;
    let c = [nz.min(CHUNK), ny.min(CHUNK), nx.min(CHUNK)];
    let zarray = if c_axis {
        json!({
            "zarr_format": 2, "shape": [volumes.len(), nz, ny, nx], "chunks": [1, c[0], c[1], c[2]],
            "dtype": dtype, "compressor": null, "fill_value": 0, "order": "C", "filters": null
        })
    } else {
        json!({
            "zarr_format": 2, "shape": [nz, ny, nx], "chunks": c, "dtype": dtype,
            "compressor": null, "fill_value": 0, "order": "C", "filters": null
        })
    };
    write(&dir.join("0/.zarray"), zarray.to_string().as_bytes())?;
    let size = d.dtype.size();
    let mut chunk = Vec::new();
    for (ch, v) in volumes.iter().enumerate() {
        let src = v.data().as_bytes();
        let key = if c_axis {
            format!("{ch}.")
        } else {
            String::new()
        };
        for cz in 0..nz.div_ceil(c[0]) {
            for cy in 0..ny.div_ceil(c[1]) {
                for cx in 0..nx.div_ceil(c[2]) {
                    // Whole chunks, the grid's edge padded with zeros.
                    chunk.clear();
                    for z in cz * c[0]..(cz + 1) * c[0] {
                        for y in cy * c[1]..(cy + 1) * c[1] {
                            for x in cx * c[2]..(cx + 1) * c[2] {
                                if x < nx && y < ny && z < nz {
                                    let i = ((z * ny + y) * nx + x) as usize * size;
                                    chunk.extend_from_slice(&src[i..i + size]);
                                } else {
                                    chunk.extend(std::iter::repeat_n(0u8, size));
                                }
                            }
                        }
                    }
                    write(&dir.join(format!("0/{key}{cz}.{cy}.{cx}")), &chunk)?;
                }
            }
        }
    }
    Ok(())
}

/// Adds the label map `labels` to the OME-Zarr image at `image` as its label
/// image `name` (`image/labels/name`, listed in `image/labels`'s `labels`
/// attribute with those already there), with `table`'s colours of `ids`.
pub fn add_ome_zarr_labels(
    image: &Path,
    name: &str,
    labels: &Volume,
    table: (&LabelTable, &[u32]),
) -> Result<(), IoError> {
    if name.is_empty() || name == "." || name == ".." || name.contains(['/', '\\']) {
        return Err(IoError::header(image, format!("label image name {name:?}")));
    }
    if !labels.desc().kind.is_labels() {
        return Err(IoError::header(image, "not a label map"));
    }
    let group = image.join("labels");
    std::fs::create_dir_all(&group).map_err(|e| IoError::io(&group, e))?;
    let attrs_path = group.join(".zattrs");
    let mut names: Vec<String> = super::read_json(&attrs_path)?
        .and_then(|v| v.get("labels").cloned())
        .and_then(|l| serde_json::from_value(l).ok())
        .unwrap_or_default();
    if !names.iter().any(|n| n == name) {
        names.push(name.to_owned());
    }
    let p = group.join(".zgroup");
    std::fs::write(&p, br#"{"zarr_format": 2}"#).map_err(|e| IoError::io(&p, e))?;
    std::fs::write(&attrs_path, json!({ "labels": names }).to_string())
        .map_err(|e| IoError::io(&attrs_path, e))?;
    write_ome_zarr(&group.join(name), labels, Some(table))
}
