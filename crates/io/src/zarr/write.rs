//! Writing a volume as a one-level OME-Zarr 0.4 image (Zarr v2, 64^3
//! uncompressed chunks): to hand a volume (a label map with its colours) to
//! other OME-Zarr tools, and for tests of the reader.

use crate::IoError;
use brickray_core::{DType, LabelTable, Volume};
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
    write(&dir.join(".zattrs"), attrs.to_string().as_bytes())?;
    let c = [nz.min(CHUNK), ny.min(CHUNK), nx.min(CHUNK)];
    let zarray = json!({
        "zarr_format": 2, "shape": [nz, ny, nx], "chunks": c, "dtype": dtype,
        "compressor": null, "fill_value": 0, "order": "C", "filters": null
    });
    write(&dir.join("0/.zarray"), zarray.to_string().as_bytes())?;
    let size = d.dtype.size();
    let src = volume.data().as_bytes();
    let mut chunk = Vec::new();
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
                write(&dir.join(format!("0/{cz}.{cy}.{cx}")), &chunk)?;
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
