//! TIFF (the `tiff` crate): multi-page stacks (one page per z slice) and
//! folders of single-slice files (ordered by a natural sort of their names:
//! `z2` before `z10`). Classic TIFF and BigTIFF, strips and tiles, either byte
//! order, the compressions the `tiff` crate decodes (none, LZW, Deflate,
//! PackBits, JPEG); grey samples of u8, i8, u16, i16, u32, i32, f32, f64
//! (converted as [`crate::SampleConverter`] states).
//!
//! Spacing comes from ImageJ metadata (`spacing=` for z, the resolution tags
//! for x and y, in the description's `unit`) or OME-TIFF XML
//! (`PhysicalSizeX/Y/Z`); a TIFF with neither has no spacing (1, 1, 1; set it
//! or give it with [`ReadOptions::spacing`]). ImageJ hyperstacks (pages
//! channel fastest, then z, then t; a missing `slices=` is what the channels
//! and frames leave) and OME-TIFF (pages in its `DimensionOrder`) with
//! several channels or time points read one ([`ReadOptions::channel`],
//! [`ReadOptions::time`]), or every channel ([`TiffReader::open_channels`],
//! [`crate::read_channels`]). Colour (RGB, palette) images are refused.

use crate::slab::desc_range;
use crate::{
    ChannelReaders, Claim, Entry, EntryKind, Format, IoError, Probe, ReadOptions, Registry,
    SampleConverter, SourceType, VolumeReader, check_slab, open_regular,
};
use brickray_core::VolumeDesc;
use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};
use tiff::decoder::{Decoder, DecodingResult};
use tiff::tags::Tag;

mod meta;

use meta::{Shape, StackMeta, parse_description};

type Dec = Decoder<BufReader<File>>;

fn terr(path: &Path, e: tiff::TiffError) -> IoError {
    match e {
        tiff::TiffError::UnsupportedError(u) => IoError::unsupported(path, u.to_string()),
        tiff::TiffError::IoError(io) if io.kind() != std::io::ErrorKind::UnexpectedEof => {
            IoError::io(path, io)
        }
        other => IoError::decode(path, "TIFF", other),
    }
}

fn open_decoder(path: &Path) -> Result<Dec, IoError> {
    let f = open_regular(path)?;
    Decoder::new(BufReader::new(f)).map_err(|e| terr(path, e))
}

/// The current page's size and sample type.
fn page_info(path: &Path, d: &mut Dec) -> Result<((u32, u32), SourceType), IoError> {
    let dims = d.dimensions().map_err(|e| terr(path, e))?;
    let ct = d.colortype().map_err(|e| terr(path, e))?;
    let bits = match ct {
        tiff::ColorType::Gray(b) => b,
        other => {
            return Err(IoError::unsupported(
                path,
                format!("colour type {other:?} (only single-channel grey images are volumes)"),
            ));
        }
    };
    let fmt = d
        .find_tag_unsigned::<u16>(Tag::SampleFormat)
        .map_err(|e| terr(path, e))?
        .unwrap_or(1);
    let t = match (fmt, bits) {
        (1, 8) => SourceType::U8,
        (1, 16) => SourceType::U16,
        (1, 32) => SourceType::U32,
        (2, 8) => SourceType::I8,
        (2, 16) => SourceType::I16,
        (2, 32) => SourceType::I32,
        (3, 32) => SourceType::F32,
        (3, 64) => SourceType::F64,
        _ => {
            return Err(IoError::UnknownDType {
                path: path.to_owned(),
                name: format!("TIFF SampleFormat {fmt} with {bits} bits"),
            });
        }
    };
    Ok((dims, t))
}

/// Decodes the current page into little-endian samples of its type.
fn decode_page(path: &Path, d: &mut Dec, out: &mut Vec<u8>) -> Result<(), IoError> {
    let r = d.read_image().map_err(|e| terr(path, e))?;
    out.clear();
    macro_rules! le {
        ($v:expr) => {
            for x in $v {
                out.extend_from_slice(&x.to_le_bytes());
            }
        };
    }
    match r {
        DecodingResult::U8(v) => out.extend_from_slice(&v),
        DecodingResult::I8(v) => le!(v),
        DecodingResult::U16(v) => le!(v),
        DecodingResult::I16(v) => le!(v),
        DecodingResult::U32(v) => le!(v),
        DecodingResult::I32(v) => le!(v),
        DecodingResult::F32(v) => le!(v),
        DecodingResult::F64(v) => le!(v),
        _ => return Err(IoError::unsupported(path, "64-bit integer or f16 samples")),
    }
    Ok(())
}

/// Compares names as a person would: runs of digits by value (`z2 < z10`).
pub fn natural_cmp(a: &str, b: &str) -> std::cmp::Ordering {
    fn runs(s: &str) -> Vec<(bool, &str)> {
        let mut v = Vec::new();
        let mut start = 0;
        let b = s.as_bytes();
        for i in 1..=b.len() {
            if i == b.len() || b[i].is_ascii_digit() != b[start].is_ascii_digit() {
                v.push((b[start].is_ascii_digit(), &s[start..i]));
                start = i;
            }
        }
        v
    }
    let (ra, rb) = (runs(a), runs(b));
    for (x, y) in ra.iter().zip(rb.iter()) {
        let o = match (x.0, y.0) {
            (true, true) => {
                let (tx, ty) = (x.1.trim_start_matches('0'), y.1.trim_start_matches('0'));
                tx.len().cmp(&ty.len()).then(tx.cmp(ty))
            }
            _ => x.1.cmp(y.1),
        };
        if o.is_ne() {
            return o;
        }
    }
    ra.len().cmp(&rb.len()).then(a.cmp(b))
}

/// A resolution tag's value (a RATIONAL in practice; the `tiff` crate's
/// `into_f64` reads only DOUBLE, which once made every ImageJ x and y
/// spacing a silent 1). A zero denominator gives infinity or NaN, which the
/// caller refuses.
fn rational(d: &mut Dec, tag: Tag) -> Option<f64> {
    use tiff::decoder::ifd::Value;
    #[allow(deprecated)] // RationalBig: BigTIFF's, still decoded
    let v = match d.find_tag(tag).ok().flatten()? {
        Value::Rational(n, dd) => n as f64 / dd as f64,
        Value::SRational(n, dd) => n as f64 / dd as f64,
        Value::RationalBig(n, dd) => n as f64 / dd as f64,
        Value::Double(x) => x,
        Value::Float(x) => x as f64,
        Value::Unsigned(x) => x as f64,
        Value::Short(x) => x as f64,
        Value::List(l) if l.len() == 1 => match &l[0] {
            Value::Rational(n, dd) => *n as f64 / *dd as f64,
            _ => return None,
        },
        _ => return None,
    };
    Some(v)
}

/// Where slice `z` lives: a file and its page.
#[derive(Debug, Clone)]
struct SliceRef {
    file: usize,
    page: usize,
}

/// Streams a TIFF stack or a folder of single-slice TIFFs.
#[derive(Debug)]
pub struct TiffReader {
    path: PathBuf,
    files: Vec<PathBuf>,
    slices: Vec<SliceRef>,
    conv: SampleConverter,
    desc: VolumeDesc,
    notes: Vec<String>,
    warnings: Vec<String>,
    /// The open decoder and the file it reads.
    dec: Option<(usize, Dec)>,
    buf: Vec<u8>,
    entries: Vec<Entry>,
}

/// A stack's metadata and page layout (a folder of slices: none, one
/// channel of its files).
fn stack_shape(path: &Path) -> Result<(Option<StackMeta>, Shape), IoError> {
    let mut d = open_decoder(path)?;
    let meta = describe(path, &mut d)?;
    let mut pages = 1u64;
    while d.more_images() {
        d.next_image().map_err(|e| terr(path, e))?;
        pages += 1;
    }
    let shape = Shape::of(meta.as_ref(), pages);
    Ok((meta, shape))
}

impl TiffReader {
    #[allow(clippy::needless_range_loop)]
    /// Opens a multi-page TIFF or a folder of single-page TIFFs (`.tif`,
    /// `.tiff`, natural name order). Decodes every slice once (one at a time)
    /// for the value range and to prove the data whole.
    pub fn open(path: &Path, opts: &ReadOptions) -> Result<TiffReader, IoError> {
        let folder = std::fs::metadata(path)
            .map_err(|e| IoError::io(path, e))?
            .is_dir();
        let mut notes = Vec::new();
        let (files, slices, meta, entries) = if folder {
            let files = list_tiffs(path)?;
            let n = files.len();
            notes.push(format!("{n} single-slice files in natural name order"));
            let slices: Vec<SliceRef> = (0..n).map(|file| SliceRef { file, page: 0 }).collect();
            // spacing from the first file's metadata, if any
            let mut d = open_decoder(&files[0])?;
            let meta = describe(&files[0], &mut d)?;
            (files, slices, meta, Vec::new())
        } else {
            let (meta, shape) = stack_shape(path)?;
            let Shape { c, z, t, .. } = shape;
            let ch = opts.channel.unwrap_or(0);
            let tp = opts.time.unwrap_or(0);
            for (what, wanted, n) in [("channel", ch, c), ("time point", tp, t)] {
                if wanted >= n {
                    return Err(IoError::NoSuchChoice {
                        path: path.to_owned(),
                        what,
                        wanted: wanted.to_string(),
                        available: format!("0..{n}"),
                    });
                }
            }
            let mut entries = Vec::new();
            if c > 1 {
                entries.extend((0..c).map(|i| Entry {
                    kind: EntryKind::Channel,
                    id: i.to_string(),
                    summary: format!("channel {i} of {c}"),
                    default: i == ch,
                }));
            }
            if t > 1 {
                entries.extend((0..t).map(|i| Entry {
                    kind: EntryKind::Time,
                    id: i.to_string(),
                    summary: format!("time point {i} of {t}"),
                    default: i == tp,
                }));
            }
            let slices = (0..z)
                .map(|k| SliceRef {
                    file: 0,
                    page: shape.page(ch, k, tp) as usize,
                })
                .collect();
            (vec![path.to_owned()], slices, meta, entries)
        };
        // First slice: size and type.
        let mut d = open_decoder(&files[0])?;
        let (wh, src) = page_info(&files[0], &mut d)?;
        let dims64 = [wh.0 as u64, wh.1 as u64, slices.len() as u64];
        brickray_core::volume::voxel_count(dims64).map_err(|e| IoError::volume(path, e))?;
        let dims = dims64.map(|v| v as u32);
        let mut spacing = [1f32; 3];
        let mut warnings = Vec::new();
        match &meta {
            Some(m) => {
                for a in 0..3 {
                    match m.spacing[a] {
                        Some(s) if (s as f32).is_finite() && s as f32 > 0.0 => {
                            spacing[a] = s as f32;
                        }
                        Some(s) => {
                            return Err(IoError::header(
                                path,
                                format!("{} spacing {s} is not a positive f32", m.source),
                            ));
                        }
                        // ImageJ's z spacing of a single page, or said in
                        // the warnings
                        None => {}
                    }
                }
                warnings.extend(m.warnings.iter().cloned());
                if m.source == "ImageJ" && m.spacing[2].is_none() && slices.len() > 1 {
                    warnings.push("no ImageJ spacing=: the z spacing is taken as 1".into());
                }
                notes.push(format!("spacing from {} metadata", m.source));
            }
            None => notes.push("the TIFF states no spacing".into()),
        }
        if meta.is_none() {
            if let Some(s) = opts.spacing {
                spacing = s;
                notes.push("spacing given by the caller".into());
            } else {
                warnings.push(
                    "the TIFF states no spacing: 1, 1, 1 is assumed (give it with --spacing)"
                        .into(),
                );
            }
        }
        let mut r = TiffReader {
            path: path.to_owned(),
            files,
            slices,
            conv: SampleConverter::choose(src, false, 1.0, 0.0, None),
            desc: VolumeDesc {
                dims,
                dtype: brickray_core::DType::U8,
                spacing,
                value_range: [0.0, 1.0],
                kind: Default::default(),
            },
            notes,
            warnings,
            dec: None,
            buf: Vec::new(),
            entries,
        };
        // One pass: every slice's size and type, the range, NaN/Inf.
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        let mut bad: Option<(u32, u64)> = None;
        let probe = r.conv;
        for z in 0..dims[2] {
            let file = r.page(z, wh, src)?;
            let _ = file;
            for c in r.buf.chunks_exact(src.size()) {
                let v = probe.value(c);
                if v.is_finite() {
                    lo = lo.min(v);
                    hi = hi.max(v);
                } else {
                    bad.get_or_insert((z, 0)).1 += 1;
                }
            }
        }
        if let Some((z, count)) = bad {
            return Err(IoError::volume(
                path,
                brickray_core::VolumeError::NonFinite {
                    count,
                    first: [0, 0, z],
                },
            ));
        }
        let range = [lo, hi];
        r.conv = SampleConverter::choose(src, false, 1.0, 0.0, Some(range));
        r.desc.dtype = r.conv.dst;
        r.desc.value_range = desc_range(path, range)?;
        r.notes.push(format!("samples: {}", r.conv.describe()));
        r.desc.validate().map_err(|e| IoError::volume(path, e))?;
        Ok(r)
    }

    /// Decodes slice `z` into `self.buf` (source samples, little-endian),
    /// checking it has the size and type of the first; returns its file.
    fn page(&mut self, z: u32, wh: (u32, u32), src: SourceType) -> Result<usize, IoError> {
        let s = self.slices[z as usize].clone();
        let file = &self.files[s.file];
        if self.dec.as_ref().is_none_or(|(f, _)| *f != s.file) {
            self.dec = Some((s.file, open_decoder(file)?));
        }
        let (_, d) = self.dec.as_mut().expect("set above");
        d.seek_to_image(s.page).map_err(|e| terr(file, e))?;
        let (pwh, psrc) = page_info(file, d)?;
        if pwh != wh || psrc != src {
            return Err(IoError::Inconsistent {
                path: self.path.clone(),
                file: file.clone(),
                msg: format!(
                    "slice {z} (page {}) is {}x{} {}, the first is {}x{} {}",
                    s.page,
                    pwh.0,
                    pwh.1,
                    psrc.name(),
                    wh.0,
                    wh.1,
                    src.name()
                ),
            });
        }
        decode_page(file, d, &mut self.buf)?;
        if self.buf.len() != wh.0 as usize * wh.1 as usize * src.size() {
            return Err(IoError::decode(
                file,
                "TIFF",
                "page decoded to the wrong size",
            ));
        }
        Ok(s.file)
    }

    /// The selectable channels and time points of a hyperstack.
    pub fn entries(&self) -> &[Entry] {
        &self.entries
    }

    /// One reader per channel of [`ReadOptions::channels`] (else every
    /// channel; see [`crate::select_channels`]) of an ImageJ hyperstack or
    /// OME-TIFF at the time point of `opts`, with the names and colours an
    /// OME-TIFF gives its channels. A plain stack or a folder of slices is
    /// one channel.
    pub fn open_channels(path: &Path, opts: &ReadOptions) -> Result<ChannelReaders, IoError> {
        let folder = std::fs::metadata(path)
            .map_err(|e| IoError::io(path, e))?
            .is_dir();
        let (count, info) = if folder {
            (1, Vec::new())
        } else {
            let (meta, shape) = stack_shape(path)?;
            let info = match meta {
                Some(m) if shape.c > 1 || m.channel_info.len() == 1 => m.channel_info,
                _ => Vec::new(),
            };
            (shape.c, info)
        };
        ChannelReaders::open_each(path, count, &info, opts, |o| {
            Ok(Box::new(TiffReader::open(path, o)?))
        })
    }
}

fn describe(path: &Path, d: &mut Dec) -> Result<Option<StackMeta>, IoError> {
    let Ok(desc) = d.get_tag_ascii_string(Tag::ImageDescription) else {
        return Ok(None);
    };
    let x = rational(d, Tag::XResolution);
    let y = rational(d, Tag::YResolution);
    parse_description(&desc, x, y).map_err(|m| IoError::header(path, m))
}

fn list_tiffs(dir: &Path) -> Result<Vec<PathBuf>, IoError> {
    let mut names: Vec<(String, PathBuf)> = std::fs::read_dir(dir)
        .map_err(|e| IoError::io(dir, e))?
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .filter(|p| {
            p.extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("tif") || e.eq_ignore_ascii_case("tiff"))
                && p.is_file()
        })
        .map(|p| {
            (
                p.file_name()
                    .unwrap_or_default()
                    .to_string_lossy()
                    .into_owned(),
                p,
            )
        })
        .collect();
    if names.is_empty() {
        return Err(IoError::UnknownFormat {
            path: dir.to_owned(),
            tried: "TIFF slices: no .tif or .tiff file in the folder".into(),
        });
    }
    names.sort_by(|a, b| natural_cmp(&a.0, &b.0));
    Ok(names.into_iter().map(|(_, p)| p).collect())
}

impl VolumeReader for TiffReader {
    fn desc(&self) -> &VolumeDesc {
        &self.desc
    }

    fn format(&self) -> &'static str {
        "TIFF"
    }

    fn path(&self) -> &Path {
        &self.path
    }

    fn input_files(&self) -> Vec<PathBuf> {
        self.files.clone()
    }

    fn notes(&self) -> Vec<String> {
        self.notes.clone()
    }

    fn warnings(&self) -> Vec<String> {
        self.warnings.clone()
    }

    fn read_slices(&mut self, z0: u32, z1: u32, out: &mut [u8]) -> Result<(), IoError> {
        let slice = check_slab(&self.desc, z0, z1, out)? as usize;
        let wh = (self.desc.dims[0], self.desc.dims[1]);
        let src = self.conv.src;
        for z in z0..z1 {
            self.page(z, wh, src)?;
            let o = (z - z0) as usize * slice;
            self.conv.convert(&self.buf, &mut out[o..o + slice]);
        }
        Ok(())
    }
}

#[derive(Debug)]
struct TiffFormat;

impl Format for TiffFormat {
    fn name(&self) -> &'static str {
        "TIFF"
    }
    fn expects(&self) -> &'static str {
        ".tif, .tiff, .btf, or a folder of them"
    }
    fn claims(&self, probe: &Probe) -> Claim {
        match probe.ext.as_str() {
            "tif" | "tiff" | "btf" | "tf8" if !probe.is_dir() => Claim::ByName,
            _ if probe.is_dir() => {
                // a folder whose files are TIFFs (and no OME-Zarr or DICOM marker)
                let has_tiff = std::fs::read_dir(&probe.path).ok().is_some_and(|rd| {
                    rd.filter_map(|e| e.ok()).any(|e| {
                        e.path().extension().is_some_and(|x| {
                            x.eq_ignore_ascii_case("tif") || x.eq_ignore_ascii_case("tiff")
                        })
                    })
                });
                if has_tiff {
                    Claim::ByContent
                } else {
                    Claim::No
                }
            }
            _ if probe.head.starts_with(b"II*\0")
                || probe.head.starts_with(b"MM\0*")
                || probe.head.starts_with(b"II+\0")
                || probe.head.starts_with(b"MM\0+") =>
            {
                Claim::ByContent
            }
            _ => Claim::No,
        }
    }
    fn open(&self, path: &Path, opts: &ReadOptions) -> Result<Box<dyn VolumeReader>, IoError> {
        Ok(Box::new(TiffReader::open(path, opts)?))
    }
    fn list(&self, path: &Path, opts: &ReadOptions) -> Result<Vec<Entry>, IoError> {
        Ok(TiffReader::open(path, opts)?.entries)
    }
    fn open_channels(&self, path: &Path, opts: &ReadOptions) -> Result<ChannelReaders, IoError> {
        TiffReader::open_channels(path, opts)
    }
}

pub(crate) fn register(r: &mut Registry) {
    r.register(std::sync::Arc::new(TiffFormat));
}

#[cfg(test)]
mod tests {
    use super::natural_cmp;

    #[test]
    fn natural_order() {
        let mut v = vec![
            "s10.tif", "s2.tif", "s1.tif", "s02.tif", "a.tif", "s100.tif",
        ];
        v.sort_by(|a, b| natural_cmp(a, b));
        assert_eq!(
            v,
            [
                "a.tif", "s1.tif", "s02.tif", "s2.tif", "s10.tif", "s100.tif"
            ]
        );
    }

    #[test]
    fn page_layouts() {
        use super::meta::{Shape, StackMeta, ome_order};
        let meta = |c, z, t, order: &[u8; 3], source| StackMeta {
            channels: c,
            slices: z,
            frames: t,
            order: *order,
            source,
            ..Default::default()
        };
        // ImageJ: channel fastest, then z, then t
        let s = Shape::of(Some(&meta(2, 3, 2, b"CZT", "ImageJ")), 12);
        assert_eq!((s.c, s.z, s.t), (2, 3, 2));
        assert_eq!(s.page(1, 2, 1), 1 + 2 * 2 + 6);
        // ImageJ without slices=: what channels and frames leave
        let s = Shape::of(Some(&meta(2, 0, 1, b"CZT", "ImageJ")), 10);
        assert_eq!((s.c, s.z, s.t), (2, 5, 1));
        // counts that do not account for the pages: a plain stack
        let s = Shape::of(Some(&meta(2, 4, 1, b"CZT", "ImageJ")), 10);
        assert_eq!((s.c, s.z, s.t), (1, 10, 1));
        assert_eq!(s.page(0, 7, 0), 7);
        // OME XYZCT: z fastest, then c
        let s = Shape::of(Some(&meta(3, 4, 1, b"ZCT", "OME-TIFF")), 12);
        assert_eq!(s.page(2, 1, 0), 2 * 4 + 1);
        assert_eq!(ome_order("XYZCT"), Some(*b"ZCT"));
        assert_eq!(ome_order("XYTZC"), Some(*b"TZC"));
        assert_eq!(ome_order("XYZZT"), None);
        assert_eq!(ome_order("YXCZT"), None);
    }

    #[test]
    fn ome_channel_names_and_colours() {
        let d = r#"<?xml version="1.0"?><OME><Image><Pixels DimensionOrder="XYZCT" SizeX="4" SizeY="4" SizeZ="2" SizeC="2" SizeT="1" PhysicalSizeX="1" PhysicalSizeY="1" PhysicalSizeZ="1"><Channel ID="Channel:0:0" Name="DAPI &amp; more" Color="65535" SamplesPerPixel="1"/><ChannelRef/><Channel ID="Channel:0:1" Color="-16776961"/><Channel ID="Channel:0:2" Color="red"/></Pixels></Image></OME>"#;
        let m = super::parse_description(d, None, None).unwrap().unwrap();
        assert_eq!(m.order, *b"ZCT");
        let c = &m.channel_info;
        assert_eq!(c.len(), 3);
        assert_eq!(c[0].label.as_deref(), Some("DAPI & more"));
        assert_eq!(c[0].color, Some([0.0, 0.0, 1.0]));
        assert_eq!(c[1].label, None);
        assert_eq!(c[1].color, Some([1.0, 0.0, 0.0]));
        assert_eq!(c[2].color, None);
        assert!(
            m.warnings.iter().any(|w| w.contains("Channel 2")),
            "{:?}",
            m.warnings
        );
    }

    #[test]
    fn imagej_description() {
        let m = super::parse_description(
            "ImageJ=1.53\nimages=6\nchannels=2\nslices=3\nspacing=0.5\nunit=micron\n",
            Some(4.0),
            Some(2.0),
        )
        .unwrap()
        .unwrap();
        assert_eq!((m.channels, m.slices, m.frames), (2, 3, 1));
        assert_eq!(m.spacing, [Some(0.25), Some(0.5), Some(0.5)]);
    }
}
