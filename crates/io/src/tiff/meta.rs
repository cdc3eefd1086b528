//! What a TIFF stack's description says of it: ImageJ's `key=value` lines
//! and OME-TIFF's XML (channels, slices, frames, their page order, spacing,
//! channel names and colours), and the shape of the stack they give.

use crate::ChannelInfo;

/// Stack metadata from ImageJ or OME-XML descriptions.
#[derive(Debug, Default, Clone, PartialEq)]
pub(super) struct StackMeta {
    pub(super) channels: u64,
    /// 0: not stated (ImageJ writes `slices=` only for more than one).
    pub(super) slices: u64,
    pub(super) frames: u64,
    /// The order of the pages: `C`, `Z` and `T`, fastest first (ImageJ's
    /// is `CZT`; OME's `DimensionOrder` without its `XY`).
    pub(super) order: [u8; 3],
    pub(super) spacing: [Option<f64>; 3],
    pub(super) source: &'static str,
    /// What OME-TIFF's `Channel` elements say (name, colour), in order.
    pub(super) channel_info: Vec<ChannelInfo>,
    /// What was assumed (a resolution tag of 0 read as spacing 1, ...).
    pub(super) warnings: Vec<String>,
}

/// How a stack's pages are laid out: channels, slices and time points, and
/// the page step of each.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Shape {
    pub(super) c: u64,
    pub(super) z: u64,
    pub(super) t: u64,
    /// Pages between channels, slices, time points.
    pub(super) step: [u64; 3],
}

impl Shape {
    /// The layout `meta` gives `pages` pages: its channels, slices and time
    /// points when they account for every page (ImageJ's missing `slices=`:
    /// the pages the others leave), else one channel of `pages` slices.
    pub(super) fn of(meta: Option<&StackMeta>, pages: u64) -> Shape {
        if let Some(m) = meta {
            let ct = m.channels.checked_mul(m.frames).filter(|&n| n > 0);
            let z = match (m.slices, ct) {
                (0, Some(ct)) if m.source == "ImageJ" && pages.is_multiple_of(ct) => pages / ct,
                (z, _) => z,
            };
            if z > 0 && ct.and_then(|ct| ct.checked_mul(z)) == Some(pages) {
                let n = |d: u8| match d {
                    b'C' => m.channels,
                    b'Z' => z,
                    _ => m.frames,
                };
                let mut step = [0u64; 3];
                let mut at = 1u64;
                for &d in &m.order {
                    let slot = match d {
                        b'C' => 0,
                        b'Z' => 1,
                        _ => 2,
                    };
                    step[slot] = at;
                    at *= n(d);
                }
                return Shape {
                    c: m.channels,
                    z,
                    t: m.frames,
                    step,
                };
            }
        }
        Shape {
            c: 1,
            z: pages,
            t: 1,
            step: [pages, 1, pages],
        }
    }

    /// The page of channel `c`, slice `z` and time point `t`.
    pub(super) fn page(&self, c: u64, z: u64, t: u64) -> u64 {
        c * self.step[0] + z * self.step[1] + t * self.step[2]
    }
}

pub(super) fn attr(xml: &str, name: &str) -> Option<String> {
    let key = format!(" {name}=\"");
    let i = xml.find(&key)? + key.len();
    let j = xml[i..].find('"')?;
    Some(xml[i..i + j].to_owned())
}

/// A count (channels, slices, frames, SizeC/Z/T): a positive integer.
pub(super) fn count(field: &str, v: &str) -> Result<u64, String> {
    v.trim()
        .parse::<u64>()
        .ok()
        .filter(|&n| n > 0)
        .ok_or_else(|| format!("{field} is {v:?}, not a positive integer"))
}

/// A voxel size: a positive finite number.
pub(super) fn size(field: &str, v: &str) -> Result<f64, String> {
    v.trim()
        .parse::<f64>()
        .ok()
        .filter(|s| s.is_finite() && *s > 0.0)
        .ok_or_else(|| format!("{field} is {v:?}, not a positive finite number"))
}

/// Parses an ImageJ or OME-XML description; `Ok(None)`: neither (or an
/// OME order read as a plain stack). Counts and sizes the description
/// states must be valid (an error naming the field otherwise, never a
/// silent 1); a resolution tag ImageJ takes the x or y size from that is
/// 0 or not finite reads as 1, with a warning.
pub(super) fn parse_description(
    desc: &str,
    xres: Option<f64>,
    yres: Option<f64>,
) -> Result<Option<StackMeta>, String> {
    if desc.starts_with("ImageJ=") {
        let mut m = StackMeta {
            channels: 1,
            slices: 0,
            frames: 1,
            order: *b"CZT",
            source: "ImageJ",
            ..Default::default()
        };
        for line in desc.lines() {
            let Some((k, v)) = line.split_once('=') else {
                continue;
            };
            match k.trim() {
                "channels" => m.channels = count("ImageJ channels", v)?,
                "slices" => m.slices = count("ImageJ slices", v)?,
                "frames" => m.frames = count("ImageJ frames", v)?,
                "spacing" => m.spacing[2] = Some(size("ImageJ spacing", v)?),
                _ => {}
            }
        }
        for (a, (tag, r)) in [("XResolution", xres), ("YResolution", yres)]
            .into_iter()
            .enumerate()
        {
            match r {
                Some(r) if r.is_finite() && r > 0.0 && (1.0 / r).is_finite() => {
                    m.spacing[a] = Some(1.0 / r);
                }
                Some(r) => m.warnings.push(format!(
                    "{tag} is {r}: the {} spacing is taken as 1",
                    ["x", "y"][a]
                )),
                None => m.warnings.push(format!(
                    "no {tag}: the {} spacing is taken as 1",
                    ["x", "y"][a]
                )),
            }
        }
        return Ok(Some(m));
    }
    if desc.contains("<OME") {
        let Some(at) = desc.find("<Pixels") else {
            return Ok(None);
        };
        let pixels = &desc[at..];
        let order = attr(pixels, "DimensionOrder").unwrap_or_else(|| "XYCZT".into());
        let Some(order) = ome_order(&order) else {
            // not an order of the standard's: read as a plain stack
            return Ok(None);
        };
        let n = |name: &str, default: u64| -> Result<u64, String> {
            attr(pixels, name).map_or(Ok(default), |v| count(&format!("OME {name}"), &v))
        };
        let mut m = StackMeta {
            channels: n("SizeC", 1)?,
            slices: n("SizeZ", 0)?,
            frames: n("SizeT", 1)?,
            order,
            source: "OME-TIFF",
            ..Default::default()
        };
        m.channel_info = ome_channels(pixels, &mut m.warnings);
        for (a, name) in ["PhysicalSizeX", "PhysicalSizeY", "PhysicalSizeZ"]
            .into_iter()
            .enumerate()
        {
            match attr(pixels, name) {
                Some(v) => m.spacing[a] = Some(size(&format!("OME {name}"), &v)?),
                None => m
                    .warnings
                    .push(format!("no OME {name}: that spacing is taken as 1")),
            }
        }
        return Ok(Some(m));
    }
    Ok(None)
}

/// An OME `DimensionOrder` (`XY` then `C`, `Z` and `T` in some order) as
/// its last three letters.
pub(super) fn ome_order(order: &str) -> Option<[u8; 3]> {
    let b = order.as_bytes();
    if b.len() != 5 || &b[..2] != b"XY" {
        return None;
    }
    let o = [b[2], b[3], b[4]];
    let mut sorted = o;
    sorted.sort_unstable();
    (&sorted == b"CTZ").then_some(o)
}

/// The `Name` and `Color` (a signed 32-bit RGBA integer) of each `Channel`
/// element of an OME `Pixels` element, in order; a colour that is not such
/// an integer is ignored with a warning.
pub(super) fn ome_channels(pixels: &str, warnings: &mut Vec<String>) -> Vec<ChannelInfo> {
    let mut out = Vec::new();
    let mut rest = pixels;
    while let Some(at) = rest.find("<Channel") {
        rest = &rest[at + "<Channel".len()..];
        if !rest.starts_with(|c: char| c.is_whitespace() || c == '/' || c == '>') {
            continue; // <ChannelRef ...>
        }
        let tag = &rest[..rest.find('>').unwrap_or(rest.len())];
        let i = out.len();
        let mut info = ChannelInfo {
            label: attr(tag, "Name").map(|n| xml_unescape(&n)),
            ..Default::default()
        };
        if let Some(c) = attr(tag, "Color") {
            match c.trim().parse::<i64>() {
                Ok(v) if (i64::from(i32::MIN)..=i64::from(u32::MAX)).contains(&v) => {
                    let [r, g, b, _a] = (v as u32).to_be_bytes();
                    info.color = Some([r, g, b].map(|x| f32::from(x) / 255.0));
                }
                _ => warnings.push(format!(
                    "OME Channel {i}'s Color {c:?} is not a 32-bit RGBA integer: ignored"
                )),
            }
        }
        out.push(info);
    }
    out
}

/// XML's five predefined entities replaced.
pub(super) fn xml_unescape(s: &str) -> String {
    s.replace("&lt;", "<")
        .replace("&gt;", ">")
        .replace("&quot;", "\"")
        .replace("&apos;", "'")
        .replace("&amp;", "&")
}
