//! NRRD (<https://teem.sourceforge.net/nrrd/format.html>): attached or detached
//! data, `raw` and `gzip` encodings, 3D scalar volumes of u8/u16/i16/f32.
//!
//! Placement: with `space directions` (one vector per axis, `none` for the
//! leading non-spatial axis of a 4D volume of size 1), the affine's columns are
//! the direction vectors and its translation `space origin` (the world origin,
//! with a warning, when absent); the spacing is each vector's length. `space`
//! `right-anterior-superior` (`RAS`) gives `"RAS"`, `left-posterior-superior`
//! (`LPS`) `"LPS"`, `left-anterior-superior` (`LAS`) `"RAS"` with x negated,
//! `scanner-xyz`, `3D-right-handed`, `3D-left-handed` or a bare `space
//! dimension: 3` `"image"`; the spaces with time are refused. Without `space
//! directions` there is no placement and the spacing is `spacings` (else 1).

use super::{
    IoError, MAX_HEADER, Placement, ReadOptions, VolumeReader, check_slab, open_regular,
    regular_file_metadata, resolve_data_file, scan_stream,
};
use brickray_core::volume::{DType, VolumeDesc};
use flate2::read::GzDecoder;
use std::fs::File;
use std::io::{BufRead, BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Encoding {
    Raw,
    Gzip,
}

/// Streams a NRRD file.
#[derive(Debug)]
pub struct NrrdReader {
    path: PathBuf,
    data_path: PathBuf,
    data_offset: u64,
    encoding: Encoding,
    big_endian: bool,
    desc: VolumeDesc,
    placement: Option<Placement>,
    warnings: Vec<String>,
    /// Open gzip stream and the decoded byte position it stands at.
    gz: Option<(GzDecoder<BufReader<File>>, u64)>,
}

impl NrrdReader {
    /// Parses the header and checks that the data is all there (for raw encoding, by
    /// size; for gzip, by decoding once, which also finds the value range when the
    /// header gives none). A detached data file must resolve inside the header's
    /// folder (see [`open_with`](Self::open_with)); header and data must be
    /// regular files.
    pub fn open(path: &Path) -> Result<NrrdReader, IoError> {
        NrrdReader::open_with(path, &ReadOptions::default())
    }

    /// [`open`](Self::open) with options: [`ReadOptions::allow_outside_dir`]
    /// lets `data file` name a file outside the header's folder.
    pub fn open_with(path: &Path, opts: &ReadOptions) -> Result<NrrdReader, IoError> {
        let file = open_regular(path)?;
        let mut rd = BufReader::new(file);
        // Every line is read through a limit, so a forged file without newlines
        // cannot make us buffer gigabytes of "header".
        let mut consumed = 0usize;
        let mut next_line = |rd: &mut BufReader<File>| -> Result<Option<String>, IoError> {
            let mut raw = Vec::new();
            let limit = (MAX_HEADER - consumed.min(MAX_HEADER)) as u64 + 1;
            let n = rd
                .by_ref()
                .take(limit)
                .read_until(b'\n', &mut raw)
                .map_err(|e| IoError::io(path, e))?;
            consumed += n;
            if consumed > MAX_HEADER {
                return Err(IoError::header(path, "header longer than 1 MiB"));
            }
            if n == 0 {
                return Ok(None);
            }
            String::from_utf8(raw)
                .map(Some)
                .map_err(|_| IoError::header(path, "header is not text"))
        };
        let magic = match next_line(&mut rd) {
            Ok(Some(m)) => m,
            Ok(None) | Err(IoError::BadHeader { .. }) => {
                return Err(IoError::header(path, "missing NRRD magic"));
            }
            Err(e) => return Err(e),
        };
        if !magic.starts_with("NRRD000") {
            return Err(IoError::header(path, "missing NRRD magic"));
        }
        let mut fields: Vec<(String, String)> = Vec::new();
        // `None` at EOF: allowed only for detached headers (an attached one then
        // holds no data, which the size check below reports).
        while let Some(line) = next_line(&mut rd)? {
            let l = line.trim_end_matches(['\n', '\r']);
            if l.is_empty() {
                break;
            }
            if l.starts_with('#') {
                continue;
            }
            if let Some((k, v)) = l.split_once(": ") {
                let (k, v) = (k.trim().to_ascii_lowercase(), v.trim().to_owned());
                if (k == "data file" || k == "datafile") && v.starts_with("LIST") {
                    // the file names follow as lines of their own
                    return Err(IoError::Unsupported {
                        path: path.to_owned(),
                        what: "multi-file data".into(),
                    });
                }
                fields.push((k, v));
            } else if l.contains(":=") {
                continue; // key/value pairs: ignored
            } else {
                return Err(IoError::header(path, format!("unparsable line {l:?}")));
            }
        }
        let consumed = consumed;
        let get = |k: &str| fields.iter().find(|(n, _)| n == k).map(|(_, v)| v.as_str());
        let ty = get("type").ok_or_else(|| IoError::header(path, "no type field"))?;
        let dtype = match ty.to_ascii_lowercase().as_str() {
            "uchar" | "unsigned char" | "uint8" | "uint8_t" => DType::U8,
            "ushort" | "unsigned short" | "unsigned short int" | "uint16" | "uint16_t" => {
                DType::U16
            }
            "short" | "short int" | "signed short" | "signed short int" | "int16" | "int16_t" => {
                DType::I16
            }
            "float" => DType::F32,
            _ => {
                return Err(IoError::UnknownDType {
                    path: path.to_owned(),
                    name: ty.to_owned(),
                });
            }
        };
        let dimension: usize = get("dimension")
            .ok_or_else(|| IoError::header(path, "no dimension field"))?
            .parse()
            .map_err(|_| IoError::header(path, "dimension is not a number"))?;
        let sizes: Vec<u64> = get("sizes")
            .ok_or_else(|| IoError::header(path, "no sizes field"))?
            .split_whitespace()
            .map(|s| s.parse::<u64>())
            .collect::<Result<_, _>>()
            .map_err(|_| IoError::header(path, "sizes are not numbers"))?;
        if sizes.len() != dimension {
            return Err(IoError::header(path, "sizes does not match dimension"));
        }
        // Accept 3D, or 4D with a leading axis of size 1.
        let sizes3 = match sizes.as_slice() {
            [x, y, z] => [*x, *y, *z],
            [1, x, y, z] => [*x, *y, *z],
            _ => {
                return Err(IoError::Unsupported {
                    path: path.to_owned(),
                    what: format!(
                        "{dimension}D data with sizes {sizes:?} (3D scalar volumes only)"
                    ),
                });
            }
        };
        brickray_core::volume::voxel_count(sizes3).map_err(|e| IoError::volume(path, e))?;
        let dims = sizes3.map(|d| d as u32);
        let encoding = match get("encoding").map(|e| e.to_ascii_lowercase()) {
            Some(e) if e == "raw" => Encoding::Raw,
            Some(e) if e == "gzip" || e == "gz" => Encoding::Gzip,
            Some(e) => {
                return Err(IoError::Unsupported {
                    path: path.to_owned(),
                    what: format!("encoding {e:?}"),
                });
            }
            None => return Err(IoError::header(path, "no encoding field")),
        };
        let big_endian = matches!(get("endian"), Some(e) if e.eq_ignore_ascii_case("big"));
        let geometry = parse_geometry(path, &fields, sizes.len() == 4)?;
        if get("line skip").is_some_and(|v| v != "0") || get("byte skip").is_some_and(|v| v != "0")
        {
            return Err(IoError::Unsupported {
                path: path.to_owned(),
                what: "line skip / byte skip".into(),
            });
        }
        // Every range field present must be a finite number; the range is used
        // when both ends are given and increasing (a flat one, as a constant
        // volume has, falls back to the data's).
        let number = |key: &'static str| -> Result<Option<f32>, IoError> {
            let Some(v) = get(key) else { return Ok(None) };
            let x = v
                .parse::<f32>()
                .map_err(|_| IoError::header(path, format!("{key} is not a number: {v:?}")))?;
            if !x.is_finite() {
                return Err(IoError::NonFiniteValue {
                    path: path.to_owned(),
                    field: key,
                    value: x,
                });
            }
            Ok(Some(x))
        };
        let (min, max) = (number("min")?, number("max")?);
        let (old_min, old_max) = (number("old min")?, number("old max")?);
        let declared = match (min.or(old_min), max.or(old_max)) {
            (Some(a), Some(b)) if b > a => Some([a, b]),
            _ => None,
        };
        let (data_path, data_offset) = match get("data file").or(get("datafile")) {
            Some(f) if f.starts_with("LIST") || f.contains('%') => {
                return Err(IoError::Unsupported {
                    path: path.to_owned(),
                    what: "multi-file data".into(),
                });
            }
            Some(f) => (resolve_data_file(path, Path::new(f), opts)?, 0),
            None => (path.to_owned(), consumed as u64),
        };
        let desc = VolumeDesc {
            dims,
            dtype,
            spacing: geometry.spacing,
            value_range: declared.unwrap_or([0.0, 1.0]),
            kind: Default::default(),
        };
        desc.validate().map_err(|e| IoError::volume(path, e))?;
        let mut r = NrrdReader {
            path: path.to_owned(),
            data_path,
            data_offset,
            encoding,
            big_endian,
            desc,
            placement: geometry.placement,
            warnings: geometry.warnings,
            gz: None,
        };
        let file_len = regular_file_metadata(&r.data_path)?.len();
        let available = file_len.saturating_sub(r.data_offset);
        if encoding == Encoding::Raw && available < r.desc.byte_len() {
            return Err(IoError::Truncated {
                path: path.to_owned(),
                expected: r.desc.byte_len(),
                actual: available,
            });
        }
        // For gzip the only way to know the stream is whole is to decode it; the
        // scan doubles as the value-range pass.
        if declared.is_none() || encoding == Encoding::Gzip {
            let range = r.scan()?;
            if declared.is_none() {
                r.desc.value_range = range;
            }
        }
        Ok(r)
    }

    /// One pass over the data in bounded memory: the value range, NaN/Inf, and
    /// (for gzip) that the stream is whole, checksum included.
    fn scan(&mut self) -> Result<[f32; 2], IoError> {
        let mut f = open_regular(&self.data_path)?;
        f.seek(SeekFrom::Start(self.data_offset))
            .map_err(|e| IoError::io(&self.data_path, e))?;
        let f = BufReader::new(f);
        let expected = self.desc.byte_len();
        let path = self.path.clone();
        let io_err = |e: std::io::Error, pos: u64| gz_error(&path, e, expected, pos);
        match self.encoding {
            Encoding::Raw => scan_stream(
                &self.path,
                &self.desc,
                self.big_endian,
                &mut f.take(expected),
                &io_err,
            ),
            Encoding::Gzip => {
                let mut gz = GzDecoder::new(f);
                let range = scan_stream(&self.path, &self.desc, self.big_endian, &mut gz, &io_err);
                if matches!(
                    range,
                    Err(IoError::Truncated { .. } | IoError::BadHeader { .. } | IoError::Io { .. })
                ) {
                    return range;
                }
                // Read on to the end of the member so that the CRC and length in
                // the gzip trailer are checked (extra decoded bytes are ignored):
                // corrupt data is reported as such, not as the NaNs it decoded to.
                let mut rest = [0u8; 4096];
                loop {
                    match gz.read(&mut rest) {
                        Ok(0) => break,
                        Ok(_) => {}
                        Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                        Err(e) => return Err(io_err(e, expected)),
                    }
                }
                range
            }
        }
    }

    fn truncated(&self, actual: u64) -> IoError {
        IoError::Truncated {
            path: self.path.clone(),
            expected: self.desc.byte_len(),
            actual,
        }
    }

    fn read_gzip(&mut self, start: u64, out: &mut [u8]) -> Result<(), IoError> {
        let restart = match &self.gz {
            Some((_, pos)) => *pos > start,
            None => true,
        };
        if restart {
            let mut f = open_regular(&self.data_path)?;
            f.seek(SeekFrom::Start(self.data_offset))
                .map_err(|e| IoError::io(&self.data_path, e))?;
            self.gz = Some((GzDecoder::new(BufReader::new(f)), 0));
        }
        let (gz, pos) = self.gz.as_mut().expect("set above");
        let skip = start - *pos;
        let copied = std::io::copy(&mut gz.by_ref().take(skip), &mut std::io::sink());
        let copied = copied.map_err(|e| gz_error(&self.path, e, self.desc.byte_len(), start))?;
        *pos += copied;
        if copied < skip {
            let p = *pos;
            self.gz = None;
            return Err(self.truncated(p));
        }
        let mut filled = 0;
        while filled < out.len() {
            match gz.read(&mut out[filled..]) {
                Ok(0) => {
                    let p = *pos + filled as u64;
                    self.gz = None;
                    return Err(self.truncated(p));
                }
                Ok(n) => filled += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => {
                    let err = gz_error(&self.path, e, self.desc.byte_len(), *pos + filled as u64);
                    self.gz = None;
                    return Err(err);
                }
            }
        }
        *pos += filled as u64;
        Ok(())
    }
}

/// Maps a read error at decoded byte `pos` of a stream announced as `expected` bytes.
fn gz_error(path: &Path, e: std::io::Error, expected: u64, pos: u64) -> IoError {
    match e.kind() {
        std::io::ErrorKind::UnexpectedEof => IoError::Truncated {
            path: path.to_owned(),
            expected,
            actual: pos,
        },
        std::io::ErrorKind::InvalidInput | std::io::ErrorKind::InvalidData => {
            IoError::header(path, format!("corrupt gzip data: {e}"))
        }
        _ => IoError::io(path, e),
    }
}

/// Where the header places the volume, and the spacing that goes with it.
struct Geometry {
    spacing: [f32; 3],
    placement: Option<Placement>,
    warnings: Vec<String>,
}

/// A NRRD `space` name as brickray's space, and the signs that turn the
/// NRRD space's axes into it (LAS is RAS with x negated).
fn nrrd_space(path: &Path, name: &str) -> Result<(&'static str, [f64; 3]), IoError> {
    match name.to_ascii_lowercase().as_str() {
        "right-anterior-superior" | "ras" => Ok(("RAS", [1.0, 1.0, 1.0])),
        "left-anterior-superior" | "las" => Ok(("RAS", [-1.0, 1.0, 1.0])),
        "left-posterior-superior" | "lps" => Ok(("LPS", [1.0, 1.0, 1.0])),
        "scanner-xyz" | "3d-right-handed" | "3d-left-handed" => Ok(("image", [1.0, 1.0, 1.0])),
        "right-anterior-superior-time"
        | "rast"
        | "left-anterior-superior-time"
        | "last"
        | "left-posterior-superior-time"
        | "lpst"
        | "scanner-xyz-time"
        | "3d-right-handed-time"
        | "3d-left-handed-time" => Err(IoError::unsupported(
            path,
            format!("space {name:?}: a world space with time (3D world spaces only)"),
        )),
        _ => Err(IoError::header(
            path,
            format!(
                "unknown space {name:?} (expected right-anterior-superior, \
                 left-anterior-superior, left-posterior-superior, scanner-xyz, \
                 3D-right-handed or 3D-left-handed, or their abbreviations)"
            ),
        )),
    }
}

/// Parses a list of NRRD vectors (`(x,y,z)`, each 3 finite numbers) and
/// `none`s, one per axis.
fn parse_vectors(
    path: &Path,
    field: &'static str,
    s: &str,
) -> Result<Vec<Option<[f64; 3]>>, IoError> {
    let mut out = Vec::new();
    let mut rest = s.trim_start();
    while !rest.is_empty() {
        if let Some(after) = rest.strip_prefix("none") {
            if after.starts_with(|c: char| !c.is_whitespace() && c != '(') {
                return Err(IoError::header(
                    path,
                    format!("{field}: unparsable {rest:?} (expected (x,y,z) or none)"),
                ));
            }
            out.push(None);
            rest = after.trim_start();
            continue;
        }
        let Some(inner_rest) = rest.strip_prefix('(') else {
            return Err(IoError::header(
                path,
                format!("{field}: unparsable {rest:?} (expected (x,y,z) or none)"),
            ));
        };
        let Some((inner, after)) = inner_rest.split_once(')') else {
            return Err(IoError::header(
                path,
                format!("{field}: vector {rest:?} has no closing parenthesis"),
            ));
        };
        if inner.contains('(') {
            return Err(IoError::header(
                path,
                format!("{field}: vector ({inner} has no closing parenthesis"),
            ));
        }
        let c: Vec<f64> = inner
            .split(',')
            .map(|x| x.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|_| IoError::header(path, format!("{field}: ({inner}) is not numeric")))?;
        let [x, y, z] = c[..] else {
            return Err(IoError::header(
                path,
                format!("{field}: ({inner}) needs 3 components"),
            ));
        };
        if let Some(&v) = c.iter().find(|v| !v.is_finite()) {
            return Err(IoError::NonFiniteValue {
                path: path.to_owned(),
                field,
                value: v as f32,
            });
        }
        out.push(Some([x, y, z]));
        rest = after.trim_start();
    }
    Ok(out)
}

/// The spacing and placement the header's `spacings`, `space`, `space
/// dimension`, `space directions` and `space origin` give. `four_d`: the
/// volume has a leading non-spatial axis (of size 1), whose spacing and
/// direction are dropped.
fn parse_geometry(
    path: &Path,
    fields: &[(String, String)],
    four_d: bool,
) -> Result<Geometry, IoError> {
    let get = |k: &str| fields.iter().find(|(n, _)| n == k).map(|(_, v)| v.as_str());
    let spacings = match get("spacings") {
        Some(s) => {
            // "nan" parses (as NaN) and is then rejected by validation, except on
            // the leading non-spatial axis of a 4D file, which is dropped.
            let mut v: Vec<f32> = s
                .split_whitespace()
                .map(|t| t.parse::<f32>())
                .collect::<Result<_, _>>()
                .map_err(|_| IoError::header(path, "spacings are not numbers"))?;
            if four_d && v.len() == 4 {
                v.remove(0);
            }
            let [a, b, c] = v[..] else {
                return Err(IoError::header(path, "spacings must give 3 values"));
            };
            Some([a, b, c])
        }
        None => None,
    };
    // The world space: `space` (named), or `space dimension` (unnamed: image).
    let space = match (get("space"), get("space dimension")) {
        (Some(name), dim) => {
            let sp = nrrd_space(path, name)?;
            if let Some(d) = dim
                && d.trim() != "3"
            {
                return Err(IoError::header(
                    path,
                    format!("space dimension {d:?} disagrees with space {name:?} (3D)"),
                ));
            }
            Some(sp)
        }
        (None, Some(d)) => match d.trim().parse::<u32>() {
            Ok(3) => Some(("image", [1.0; 3])),
            Ok(n) => {
                return Err(IoError::unsupported(
                    path,
                    format!("space dimension {n} (3D world spaces only)"),
                ));
            }
            Err(_) => {
                return Err(IoError::header(
                    path,
                    format!("space dimension {d:?} is not a number"),
                ));
            }
        },
        (None, None) => None,
    };
    let origin = match get("space origin") {
        Some(s) => match parse_vectors(path, "space origin", s)?[..] {
            [Some(o)] => Some(o),
            _ => {
                return Err(IoError::header(
                    path,
                    format!("space origin {s:?} must be one vector (x,y,z)"),
                ));
            }
        },
        None => None,
    };
    let Some(d) = get("space directions") else {
        return Ok(Geometry {
            spacing: spacings.unwrap_or([1.0; 3]),
            placement: None,
            warnings: Vec::new(),
        });
    };
    // "(a,b,c) (d,e,f) (g,h,i)", preceded by "none" for the leading axis of a
    // 4D volume: one entry per axis.
    let axes = parse_vectors(path, "space directions", d)?;
    let want = if four_d { 4 } else { 3 };
    if axes.len() != want {
        return Err(IoError::header(
            path,
            format!(
                "space directions must give 3 vectors (one per axis, none for a \
                 non-spatial one), got {} entries for {want} axes",
                axes.len()
            ),
        ));
    }
    if four_d && axes[0].is_some() {
        return Err(IoError::header(
            path,
            "space directions: the leading axis of a 4D volume must be none \
             (3D scalar volumes only)",
        ));
    }
    let spatial = &axes[axes.len() - 3..];
    let mut dirs = [[0.0f64; 3]; 3];
    for (a, v) in spatial.iter().enumerate() {
        dirs[a] = v.ok_or_else(|| {
            IoError::header(
                path,
                format!("space directions: spatial axis {a} has direction none"),
            )
        })?;
    }
    let norms = dirs.map(|v| v.iter().map(|x| x * x).sum::<f64>().sqrt());
    let spacing = norms.map(|n| n as f32);
    if let Some(sp) = spacings {
        for a in 0..3 {
            let (s, n) = (sp[a], spacing[a]);
            if !s.is_nan() && (s - n).abs() > 1e-6 * n.abs().max(s.abs()) {
                return Err(IoError::header(
                    path,
                    format!(
                        "axis {a}: spacings gives {s} but its space direction is {n} long \
                         (a spatial axis takes one or the other)"
                    ),
                ));
            }
        }
    }
    // A zero or overflowing vector is a bad spacing (reported by validation);
    // otherwise the vectors must span space.
    if spacing.iter().all(|s| s.is_finite() && *s > 0.0) {
        let m = dirs;
        let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
        let scale: f64 = norms.iter().product();
        if !(det.is_finite() && det.abs() > 1e-9 * scale) {
            return Err(IoError::header(
                path,
                format!("space directions do not span space (determinant {det})"),
            ));
        }
    }
    let mut warnings = Vec::new();
    let (space, sign) = space.unwrap_or_else(|| {
        warnings.push(
            "space directions without a space or space dimension: placed in image space".to_owned(),
        );
        ("image", [1.0; 3])
    });
    let origin = origin.unwrap_or_else(|| {
        warnings.push("no space origin: voxel (0,0,0) placed at the world's origin".to_owned());
        [0.0; 3]
    });
    // Columns are the axes' directions, the translation the origin; rows
    // negated where the NRRD space's axis is brickray's reversed (LAS).
    let mut affine = [[0.0; 4]; 4];
    for r in 0..3 {
        for (c, v) in dirs.iter().enumerate() {
            affine[r][c] = sign[r] * v[r];
        }
        affine[r][3] = sign[r] * origin[r];
    }
    affine[3][3] = 1.0;
    Ok(Geometry {
        spacing,
        placement: Some(Placement { affine, space }),
        warnings,
    })
}

impl VolumeReader for NrrdReader {
    fn desc(&self) -> &VolumeDesc {
        &self.desc
    }

    fn format(&self) -> &'static str {
        "NRRD"
    }

    fn path(&self) -> &Path {
        &self.path
    }

    fn placement(&self) -> Option<Placement> {
        self.placement
    }

    fn warnings(&self) -> Vec<String> {
        self.warnings.clone()
    }

    fn input_files(&self) -> Vec<PathBuf> {
        let mut v = vec![self.path.clone()];
        if self.data_path != self.path {
            v.push(self.data_path.clone());
        }
        v
    }

    fn read_slices(&mut self, z0: u32, z1: u32, out: &mut [u8]) -> Result<(), IoError> {
        let slice = check_slab(&self.desc, z0, z1, out)?;
        let start = z0 as u64 * slice;
        match self.encoding {
            Encoding::Raw => {
                let mut f = open_regular(&self.data_path)?;
                f.seek(SeekFrom::Start(self.data_offset + start))
                    .map_err(|e| IoError::io(&self.path, e))?;
                f.read_exact(out).map_err(|e| match e.kind() {
                    std::io::ErrorKind::UnexpectedEof => self.truncated(start),
                    _ => IoError::io(&self.path, e),
                })?;
            }
            Encoding::Gzip => self.read_gzip(start, out)?,
        }
        if self.big_endian {
            let n = self.desc.dtype.size();
            out.chunks_exact_mut(n).for_each(|c| c.reverse());
        }
        Ok(())
    }
}

/// The NRRD format: `.nrrd`, `.nhdr`, or a file starting with `NRRD000`.
#[derive(Debug)]
struct NrrdFormat;

impl crate::Format for NrrdFormat {
    fn name(&self) -> &'static str {
        "NRRD"
    }
    fn expects(&self) -> &'static str {
        ".nrrd, .nhdr"
    }
    fn claims(&self, probe: &crate::Probe) -> crate::Claim {
        match probe.ext.as_str() {
            "nrrd" | "nhdr" => crate::Claim::ByName,
            _ if probe.head.starts_with(b"NRRD000") => crate::Claim::ByContent,
            _ => crate::Claim::No,
        }
    }
    fn open(&self, path: &Path, opts: &ReadOptions) -> Result<Box<dyn VolumeReader>, IoError> {
        Ok(Box::new(NrrdReader::open_with(path, opts)?))
    }
}

pub(crate) fn register(r: &mut crate::Registry) {
    r.register(std::sync::Arc::new(NrrdFormat));
}
