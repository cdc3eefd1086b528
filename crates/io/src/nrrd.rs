//! NRRD (<https://teem.sourceforge.net/nrrd/format.html>): attached or detached
//! data, `raw` and `gzip` encodings, 3D scalar volumes of u8/u16/i16/f32.

use super::{
    IoError, MAX_HEADER, ReadOptions, VolumeReader, check_slab, open_regular,
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
        let spacing = parse_spacing(
            path,
            get("spacings"),
            get("space directions"),
            sizes.len() == 4,
        )?;
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
            spacing,
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

fn parse_spacing(
    path: &Path,
    spacings: Option<&str>,
    directions: Option<&str>,
    four_d: bool,
) -> Result<[f32; 3], IoError> {
    if let Some(s) = spacings {
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
        if v.len() == 3 {
            return Ok([v[0], v[1], v[2]]);
        }
        return Err(IoError::header(path, "spacings must give 3 values"));
    }
    if let Some(d) = directions {
        // "(a,b,c) (d,e,f) (g,h,i)", possibly preceded by "none" for a 4D axis.
        let vecs: Vec<f32> = d
            .split(')')
            .map(|t| {
                t.trim()
                    .trim_start_matches("none")
                    .trim()
                    .trim_start_matches('(')
            })
            .filter(|t| !t.is_empty())
            .map(|t| {
                let c: Vec<f32> = t
                    .split(',')
                    .map(|x| x.trim().parse::<f32>())
                    .collect::<Result<_, _>>()
                    .map_err(|_| {
                        IoError::header(path, format!("space direction ({t}) is not numeric"))
                    })?;
                if c.len() != 3 {
                    return Err(IoError::header(
                        path,
                        format!("space direction ({t}) needs 3 components"),
                    ));
                }
                Ok(c.iter().map(|x| x * x).sum::<f32>().sqrt())
            })
            .collect::<Result<_, _>>()?;
        if vecs.len() == 3 {
            return Ok([vecs[0], vecs[1], vecs[2]]);
        }
        return Err(IoError::header(
            path,
            "space directions must give 3 vectors",
        ));
    }
    Ok([1.0; 3])
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
