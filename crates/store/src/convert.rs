//! Conversion of any readable volume into raw samples + a JSON sidecar (the
//! form of `shared/data`), streamed in z-slabs within a memory bound.

use crate::{BuildProgress, StoreError, check_output};
use brickray_io::VolumeReader;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What [`convert`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct ConvertReport {
    /// The sidecar.
    pub json: PathBuf,
    /// The raw file.
    pub raw: PathBuf,
    /// Bytes of samples written.
    pub bytes: u64,
    /// Slices per slab read.
    pub slab: u32,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// Writes `reader`'s volume as `<stem>.raw` (little-endian, x fastest) beside
/// the sidecar `json` (dims, dtype, spacing, value range, the format read,
/// its placement and notes; `.json` is appended to a path that does not end
/// in it, so `out` writes `out.json` and `out.raw`). Slabs hold at most `memory_bound` bytes (at
/// least one slice). The raw file is written under a temporary name and
/// renamed when complete; neither output may be one of the reader's inputs.
pub fn convert(
    reader: &mut dyn VolumeReader,
    json: &Path,
    memory_bound: u64,
) -> Result<ConvertReport, StoreError> {
    convert_with_progress(reader, json, memory_bound, None)
}

/// [`convert`], reporting `(done, total)` voxels written to `progress` after
/// each slab (as [`BuildProgress`] reports a build's), first `(0, total)`.
pub fn convert_with_progress(
    reader: &mut dyn VolumeReader,
    json: &Path,
    memory_bound: u64,
    progress: Option<&BuildProgress>,
) -> Result<ConvertReport, StoreError> {
    let t0 = Instant::now();
    let json = &sidecar_path(json);
    let raw = json.with_extension("raw");
    let inputs = reader.input_files();
    check_output(json, &inputs)?;
    check_output(&raw, &inputs)?;
    let d = reader.desc().clone();
    let slice = d.dims[0] as u64 * d.dims[1] as u64 * d.dtype.size() as u64;
    let slab = (memory_bound / slice.max(1)).clamp(1, d.dims[2] as u64) as u32;
    let tmp = raw.with_extension(format!("raw.partial.{}", std::process::id()));
    let io = |p: &Path, e: std::io::Error| StoreError::Io {
        path: p.to_owned(),
        source: e,
    };
    let result = (|| -> Result<(), StoreError> {
        let f = std::fs::File::create(&tmp).map_err(|e| io(&tmp, e))?;
        let mut w = std::io::BufWriter::new(f);
        let mut buf = Vec::new();
        let mut z = 0;
        let per_slice = d.dims[0] as u64 * d.dims[1] as u64;
        let total = per_slice * d.dims[2] as u64;
        let report = |z: u32| {
            if let Some(p) = progress {
                (p.0)(per_slice * z as u64, total);
            }
        };
        report(0);
        while z < d.dims[2] {
            let z1 = (z + slab).min(d.dims[2]);
            buf.resize(((z1 - z) as u64 * slice) as usize, 0);
            reader.read_slices(z, z1, &mut buf)?;
            w.write_all(&buf).map_err(|e| io(&tmp, e))?;
            z = z1;
            report(z);
        }
        w.flush().map_err(|e| io(&tmp, e))?;
        Ok(())
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    std::fs::rename(&tmp, &raw).map_err(|e| io(&raw, e))?;
    let mut sc = serde_json::json!({
        "dims": d.dims,
        "dtype": d.dtype.name(),
        "spacing": d.spacing,
        "value_range": d.value_range,
        "file": raw.file_name().map(|n| n.to_string_lossy().into_owned()),
        "byte_order": "little",
        "layout": "x fastest, then y, then z (a C array [z][y][x])",
        "bytes": d.byte_len(),
        "original_format": reader.format(),
        "source": reader.path().display().to_string(),
        "notes": reader.notes(),
    });
    if let Some(p) = reader.placement() {
        sc["affine"] = serde_json::json!(p.affine);
        sc["affine_space"] = serde_json::json!(p.space);
    }
    let text = serde_json::to_string_pretty(&sc).map_err(|e| io(json, std::io::Error::other(e)))?;
    std::fs::write(json, text).map_err(|e| io(json, e))?;
    Ok(ConvertReport {
        json: json.to_owned(),
        raw,
        bytes: d.byte_len(),
        slab,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// `path` if it ends in `.json`, else `path` with `.json` appended.
fn sidecar_path(path: &Path) -> PathBuf {
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"))
    {
        return path.to_owned();
    }
    let mut s = path.as_os_str().to_owned();
    s.push(".json");
    PathBuf::from(s)
}

#[cfg(test)]
mod tests {
    use super::sidecar_path;
    use std::path::Path;

    #[test]
    fn the_sidecar_always_ends_in_json() {
        let p = |s: &str| sidecar_path(Path::new(s)).display().to_string();
        assert_eq!(p("out.json"), "out.json");
        assert_eq!(p("dir/out.JSON"), "dir/out.JSON");
        assert_eq!(p("out"), "out.json");
        assert_eq!(p("dir/head.nii"), "dir/head.nii.json");
        // The raw file then sits beside it with the same stem.
        assert_eq!(
            sidecar_path(Path::new("out")).with_extension("raw"),
            Path::new("out.raw")
        );
    }
}

#[cfg(test)]
mod progress_tests {
    use super::*;
    use brickray_io::MemoryReader;
    use std::sync::{Arc, Mutex};

    /// The progress of a conversion in slabs of 3 slices of a 10-slice
    /// volume: `(0, total)` first, then after each slab, ending at the total;
    /// the files are those of a conversion without progress.
    #[test]
    fn a_conversion_reports_its_progress_slab_by_slab() {
        let volume = brickray_core::synthetic::sphere(10);
        let slice = 10 * 10 * volume.desc().dtype.size() as u64;
        let dir = tempfile::tempdir().unwrap();
        let seen = Arc::new(Mutex::new(Vec::new()));
        let s = seen.clone();
        let progress = BuildProgress(Arc::new(move |done, total| {
            s.lock().unwrap().push((done, total));
        }));
        let mut reader = MemoryReader::new(volume.clone(), "sphere");
        let with = dir.path().join("with.json");
        convert_with_progress(&mut reader, &with, 3 * slice, Some(&progress)).unwrap();
        let total = 1000;
        let want: Vec<(u64, u64)> = [0, 3, 6, 9, 10].iter().map(|z| (z * 100, total)).collect();
        assert_eq!(*seen.lock().unwrap(), want);
        let mut reader = MemoryReader::new(volume, "sphere");
        let without = dir.path().join("without.json");
        convert(&mut reader, &without, 3 * slice).unwrap();
        let read = |p: &Path| std::fs::read(p).unwrap();
        assert_eq!(
            read(&with.with_extension("raw")),
            read(&without.with_extension("raw"))
        );
    }
}
