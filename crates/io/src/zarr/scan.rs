//! The value range of one level, channel and time point of an OME-Zarr
//! image: one pass over the chunks that are stored, plus the fill value
//! when a chunk is not (it reads as the fill value), so that a scan takes
//! the time the data on disk takes to read, not the time the shape its
//! metadata declares would (a shape forged to 2^48 voxels over a few small
//! chunks is scanned in an instant). Each read decodes at most
//! [`SCAN_VOXELS`] samples.

use super::*;
use std::collections::HashSet;
use std::ops::Range;

/// Most samples one read of a scan decodes.
const SCAN_VOXELS: u64 = 1 << 24;

/// A box of voxels (x, y, z): `lo` inclusive, `hi` exclusive.
type Box3 = ([u64; 3], [u64; 3]);

/// The value range of `level` at channel `c` and time point `t` (NaN and
/// infinite samples refused).
pub(super) fn scan(z: &OmeZarr, level: usize, c: u64, t: u64) -> Result<[f64; 2], IoError> {
    let conv = SampleConverter::choose(z.src, false, 1.0, 0.0, None);
    let mut range = [f64::INFINITY, f64::NEG_INFINITY];
    let mut read = |a: [u64; 3], b: [u64; 3]| -> Result<(), IoError> {
        let bytes = z.region(level, c, t, a, b)?;
        let (nx, ny) = (b[0] - a[0], b[1] - a[1]);
        for (i, s) in bytes.chunks_exact(z.src.size()).enumerate() {
            let v = conv.value(s);
            if !v.is_finite() {
                let i = i as u64;
                let p = [a[0] + i % nx, a[1] + (i / nx) % ny, a[2] + i / (nx * ny)];
                return Err(IoError::volume(
                    &z.root,
                    brickray_core::VolumeError::NonFinite {
                        count: 1,
                        first: p.map(|v| v as u32),
                    },
                ));
            }
            range = [range[0].min(v), range[1].max(v)];
        }
        Ok(())
    };
    let boxes = match stored_boxes(z, level, c, t)? {
        Some(boxes) => boxes,
        None => vec![([0; 3], z.dims(level))],
    };
    for (lo, hi) in boxes {
        for_tiles(lo, hi, &mut read)?;
    }
    Ok(range)
}

/// Calls `f` on boxes of at most [`SCAN_VOXELS`] voxels that tile `lo..hi`:
/// whole slices where they fit, else rows, else runs of a row.
fn for_tiles(
    lo: [u64; 3],
    hi: [u64; 3],
    f: &mut dyn FnMut([u64; 3], [u64; 3]) -> Result<(), IoError>,
) -> Result<(), IoError> {
    let n = [0, 1, 2].map(|a| hi[a].saturating_sub(lo[a]));
    if n.contains(&0) {
        return Ok(());
    }
    let plane = n[0].saturating_mul(n[1]);
    let step = if plane <= SCAN_VOXELS {
        [n[0], n[1], SCAN_VOXELS / plane]
    } else if n[0] <= SCAN_VOXELS {
        [n[0], SCAN_VOXELS / n[0], 1]
    } else {
        [SCAN_VOXELS, 1, 1]
    };
    let mut z = lo[2];
    while z < hi[2] {
        let z1 = hi[2].min(z + step[2]);
        let mut y = lo[1];
        while y < hi[1] {
            let y1 = hi[1].min(y + step[1]);
            let mut x = lo[0];
            while x < hi[0] {
                let x1 = hi[0].min(x + step[0]);
                f([x, y, z], [x1, y1, z1])?;
                x = x1;
            }
            y = y1;
        }
        z = z1;
    }
    Ok(())
}

/// The boxes a scan reads: the part of each stored chunk in the selection
/// (x, y and z whole, channel `c`, time point `t`), in z, y, x order, and
/// one voxel of a chunk of the selection that is not stored (its fill
/// value), if there is one. `None` when the chunk keys are in an encoding
/// not listed here: then every voxel is read.
fn stored_boxes(z: &OmeZarr, level: usize, c: u64, t: u64) -> Result<Option<Vec<Box3>>, IoError> {
    if !z.store.is_local() {
        // objects over HTTP or in a bucket are not listed: every voxel is read
        return Ok(None);
    }
    let l = &z.levels[level];
    let array = &l.array;
    let encoding = serde_json::to_value(array.metadata()).ok().and_then(|m| {
        Some(
            m.get("chunk_key_encoding")?
                .get("name")?
                .as_str()?
                .to_owned(),
        )
    });
    if !matches!(encoding.as_deref(), Some("default" | "v2")) {
        return Ok(None);
    }
    let mut sel: Vec<Range<u64>> = l.shape.iter().map(|&s| 0..s).collect();
    if let Some(i) = z.ax[3] {
        sel[i] = c..c + 1;
    }
    if let Some(i) = z.ax[4] {
        sel[i] = t..t + 1;
    }
    let Ok(Some(chunks)) = array.chunks_in_array_subset(&ArraySubset::new_with_ranges(&sel)) else {
        return Ok(None);
    };
    let chunks = chunks.to_ranges();
    let xyz = |r: &[Range<u64>]| -> Box3 {
        (
            [0, 1, 2].map(|a| z.ax[a].map_or(0, |i| r[i].start)),
            [0, 1, 2].map(|a| z.ax[a].map_or(1, |i| r[i].end)),
        )
    };
    // The stored chunks: the files under the level's folder named as chunk
    // keys (a file of another name is never read).
    let prefix = l.path.trim_matches('/');
    let mut keys = Vec::new();
    walk(&z.root.join(prefix), prefix, l.shape.len() + 1, &mut keys)?;
    let mut stored = HashSet::new();
    let mut boxes = Vec::new();
    for key in keys {
        let Some(idx) = chunk_indices(array, prefix, &key) else {
            continue;
        };
        if idx.iter().zip(&chunks).any(|(i, r)| !r.contains(i)) {
            continue;
        }
        let Ok(sub) = array.chunk_subset_bounded(&idx) else {
            continue;
        };
        let mut r = sub.to_ranges();
        for (a, s) in [(3, c), (4, t)] {
            if let Some(i) = z.ax[a] {
                r[i] = s..s + 1;
            }
        }
        boxes.push(xyz(&r));
        stored.insert(idx);
    }
    boxes.sort_by_key(|(lo, _)| [lo[2], lo[1], lo[0]]);
    let total = chunks
        .iter()
        .try_fold(1u64, |a, r| a.checked_mul(r.end - r.start));
    if total.is_none_or(|n| (stored.len() as u64) < n) {
        // The first chunk of the selection (in index order) not stored: at
        // most one more step than there are stored chunks.
        let mut idx: Vec<u64> = chunks.iter().map(|r| r.start).collect();
        while stored.contains(&idx) {
            let mut a = idx.len();
            loop {
                if a == 0 {
                    return Ok(Some(boxes));
                }
                a -= 1;
                idx[a] += 1;
                if idx[a] < chunks[a].end {
                    break;
                }
                idx[a] = chunks[a].start;
            }
        }
        if let Ok(sub) = array.chunk_subset_bounded(&idx) {
            let (lo, _) = xyz(&sub.to_ranges());
            boxes.push((lo, lo.map(|v| v + 1)));
        }
    }
    Ok(Some(boxes))
}

/// The chunk indices `key` (a path below the store's root) names, when it is
/// exactly the key of those indices.
fn chunk_indices(array: &ZArray, prefix: &str, key: &str) -> Option<Vec<u64>> {
    let rest = if prefix.is_empty() {
        key
    } else {
        key.strip_prefix(prefix)?.strip_prefix('/')?
    };
    let mut tokens = rest.split(['/', '.']).peekable();
    if tokens.peek() == Some(&"c") {
        tokens.next();
    }
    let idx: Vec<u64> = tokens.map(|s| s.parse().ok()).collect::<Option<_>>()?;
    (idx.len() == array.shape().len() && array.chunk_key(&idx).as_str() == key).then_some(idx)
}

/// The files below `dir` (its key `rel` below the store's root), at most
/// `depth` folders deep, but the metadata files; a folder that does not
/// exist holds none.
fn walk(dir: &Path, rel: &str, depth: usize, out: &mut Vec<String>) -> Result<(), IoError> {
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(IoError::io(dir, e)),
    };
    for e in entries {
        let e = e.map_err(|err| IoError::io(dir, err))?;
        let Some(name) = e.file_name().to_str().map(str::to_owned) else {
            continue;
        };
        let key = if rel.is_empty() {
            name.clone()
        } else {
            format!("{rel}/{name}")
        };
        let path = e.path();
        if std::fs::metadata(&path).is_ok_and(|m| m.is_dir()) {
            if depth > 1 {
                walk(&path, &key, depth - 1, out)?;
            }
        } else if !matches!(
            name.as_str(),
            "zarr.json" | ".zarray" | ".zattrs" | ".zgroup"
        ) {
            out.push(key);
        }
    }
    Ok(())
}
