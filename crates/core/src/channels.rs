//! Multi-channel volumes (fluorescence stacks: nuclei, membrane, a protein of
//! interest, each in its own colour): 1 to [`MAX_CHANNELS`] intensity
//! channels of one dtype on one grid ([`ChannelVolume`]), each classified by
//! its own transfer function ([`ChannelStyle`], or a colour and a window as
//! OME-Zarr's `omero` metadata gives them: [`ChannelStyle::window`]), and
//! composited in one ray.
//!
//! How the channels of one sample combine ([`mix`], the CPU twin of the
//! kernels' `channel_mix`): each visible channel `c` classifies its own value
//! to a colour `rgb_c` and an opacity `a_c` corrected to the step; the sample
//! is the mixture of their absorbers, whose extinctions `tau_c = -ln(1 - a_c)`
//! add (emission-absorption with several emitters, the standard model of
//! additive channel blending):
//!
//! ```text
//! a   = 1 - prod_c (1 - a_c)
//! rgb = sum_c tau_c rgb_c / sum_c tau_c          (premultiplied: a * rgb)
//! ```
//!
//! One channel gives exactly its own sample; a hidden channel is absent; the
//! order of the channels does not matter. Render modes: DVR composites these
//! mixed samples front to back; MIP takes each channel's maximum along the
//! ray, classifies it (uncorrected) and mixes the results; an isosurface is
//! the first crossing of any visible channel's own isovalue
//! ([`ChannelStyle::isovalue`]), coloured by that channel's transfer function
//! at its isovalue and shaded by that channel's gradient.

use crate::tf::TransferFunction;
use crate::volume::{DType, Volume, VolumeDesc};
use thiserror::Error;

/// Most channels a volume may have (one RGBA texel holds them).
pub const MAX_CHANNELS: usize = 4;

/// The largest opacity whose extinction [`mix`] takes (`-ln(1 - a)` is
/// infinite at 1): an opaque channel weighs as `-ln(2^-20)`.
pub const OPAQUE_ALPHA: f64 = 1.0 - 1.0 / 1048576.0;

/// A multi-channel volume that cannot be built or drawn as given.
#[derive(Debug, Error, Clone, PartialEq)]
#[non_exhaustive]
pub enum ChannelError {
    /// No channel, or more than [`MAX_CHANNELS`].
    #[error("a multi-channel volume holds 1 to {max} channels, got {count}")]
    Count {
        /// Channels given.
        count: usize,
        /// The maximum.
        max: usize,
    },
    /// A channel's grid or sample type differs from the first channel's.
    #[error(
        "channel {channel} has {what} {found}, channel 0 has {expected}: channels share one grid and one dtype"
    )]
    Mismatch {
        /// The channel.
        channel: usize,
        /// `dims`, `dtype` or `spacing`.
        what: &'static str,
        /// Channel 0's.
        expected: String,
        /// This channel's.
        found: String,
    },
    /// A channel is a label map (channels are intensities; draw a label map
    /// over them as an overlay).
    #[error("channel {channel} is a label map: channels are intensities")]
    Labels {
        /// The channel.
        channel: usize,
    },
    /// The styles given do not match the channels drawn.
    #[error("{styles} channel styles for a volume of {channels} channels")]
    StyleCount {
        /// Styles given.
        styles: usize,
        /// Channels of the volume.
        channels: usize,
    },
    /// An isovalue or a window bound is not finite.
    #[error("channel {channel}: {what} is not finite")]
    NotFinite {
        /// The channel.
        channel: usize,
        /// What.
        what: &'static str,
    },
}

/// 1 to [`MAX_CHANNELS`] intensity channels on one grid, of one dtype; each
/// keeps its own value range (normalized 0..1 per channel).
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelVolume {
    channels: Vec<Volume>,
}

impl ChannelVolume {
    /// Checks the count, that every channel has channel 0's dims, dtype and
    /// spacing, and that none is a label map.
    pub fn new(channels: Vec<Volume>) -> Result<ChannelVolume, ChannelError> {
        if channels.is_empty() || channels.len() > MAX_CHANNELS {
            return Err(ChannelError::Count {
                count: channels.len(),
                max: MAX_CHANNELS,
            });
        }
        let first = channels[0].desc().clone();
        for (c, v) in channels.iter().enumerate() {
            let d = v.desc();
            if d.kind.is_labels() {
                return Err(ChannelError::Labels { channel: c });
            }
            let mismatch = |what, e: String, f: String| ChannelError::Mismatch {
                channel: c,
                what,
                expected: e,
                found: f,
            };
            if d.dims != first.dims {
                return Err(mismatch(
                    "dims",
                    format!("{:?}", first.dims),
                    format!("{:?}", d.dims),
                ));
            }
            if d.dtype != first.dtype {
                return Err(mismatch(
                    "dtype",
                    first.dtype.name().into(),
                    d.dtype.name().into(),
                ));
            }
            if d.spacing != first.spacing {
                return Err(mismatch(
                    "spacing",
                    format!("{:?}", first.spacing),
                    format!("{:?}", d.spacing),
                ));
            }
        }
        Ok(ChannelVolume { channels })
    }

    /// The channels, in order.
    pub fn channels(&self) -> &[Volume] {
        &self.channels
    }

    /// The channels, to give away.
    pub fn into_channels(self) -> Vec<Volume> {
        self.channels
    }

    /// Number of channels (1 to [`MAX_CHANNELS`]).
    pub fn len(&self) -> usize {
        self.channels.len()
    }

    /// Always false (a channel volume has at least one channel).
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Voxels along x, y, z.
    pub fn dims(&self) -> [u32; 3] {
        self.channels[0].dims()
    }

    /// The sample type of every channel.
    pub fn dtype(&self) -> DType {
        self.channels[0].desc().dtype
    }

    /// Channel 0's description (dims, dtype and spacing are every channel's;
    /// each channel's value range is its own).
    pub fn desc(&self) -> &VolumeDesc {
        self.channels[0].desc()
    }

    /// Bytes of sample data of all channels.
    pub fn byte_len(&self) -> u64 {
        self.channels.iter().map(|v| v.desc().byte_len()).sum()
    }
}

/// How one channel is classified and drawn.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelStyle {
    /// The channel's transfer function over its normalized values.
    pub tf: TransferFunction,
    /// Drawn or hidden (a hidden channel is absent from the image and from
    /// empty-space skipping).
    pub visible: bool,
    /// The channel's isovalue in iso mode, normalized.
    pub isovalue: f32,
}

impl ChannelStyle {
    /// A visible channel classified by `tf`, isovalue 0.5.
    pub fn new(tf: TransferFunction) -> ChannelStyle {
        ChannelStyle {
            tf,
            visible: true,
            isovalue: 0.5,
        }
    }

    /// A channel drawn in one colour through a window (the napari and
    /// OME-Zarr `omero` model): transparent at and below `window[0]`, its
    /// opacity rising linearly to `opacity` at `window[1]` and kept above it
    /// (normalized values; a window of zero width is a step). Its isovalue is
    /// the window's middle.
    pub fn window(color: [f32; 3], window: [f32; 2], opacity: f32) -> ChannelStyle {
        let [lo, hi] = window;
        let hi = if hi > lo { hi } else { lo + 1e-6 };
        let [r, g, b] = color;
        let tf = TransferFunction::from_points(
            &[(lo, [r, g, b, 0.0]), (hi, [r, g, b, opacity])],
            crate::tf::TABLE_ENTRIES,
        );
        ChannelStyle {
            tf,
            visible: true,
            isovalue: 0.5 * (lo + hi),
        }
    }

    /// With `visible` set.
    pub fn visible(self, visible: bool) -> ChannelStyle {
        ChannelStyle { visible, ..self }
    }

    /// With the isovalue set.
    pub fn with_isovalue(self, isovalue: f32) -> ChannelStyle {
        ChannelStyle { isovalue, ..self }
    }

    /// The colour of this channel's isosurface: its transfer function's
    /// colour at its isovalue.
    pub fn iso_color(&self) -> [f32; 3] {
        let c = self.tf.lookup(self.isovalue as f64);
        [c[0] as f32, c[1] as f32, c[2] as f32]
    }
}

/// Checks styles against a volume of `channels` channels: one style per
/// channel, finite isovalues.
pub fn validate_styles(styles: &[ChannelStyle], channels: usize) -> Result<(), ChannelError> {
    if styles.len() != channels {
        return Err(ChannelError::StyleCount {
            styles: styles.len(),
            channels,
        });
    }
    for (c, s) in styles.iter().enumerate() {
        if !s.isovalue.is_finite() {
            return Err(ChannelError::NotFinite {
                channel: c,
                what: "the isovalue",
            });
        }
    }
    Ok(())
}

/// Mixes the classified samples of the visible channels at one point:
/// straight colours and opacities `(rgb_c, a_c)` (corrected to the step in
/// DVR) into one premultiplied RGBA (see the module docs). Channels of zero
/// opacity add nothing; no channel gives transparent black.
pub fn mix(samples: &[([f64; 3], f64)]) -> [f64; 4] {
    let mut keep = 1.0;
    let mut tau_sum = 0.0;
    let mut rgb = [0.0f64; 3];
    for &(c, a) in samples {
        let a = a.clamp(0.0, 1.0);
        if a <= 0.0 {
            continue;
        }
        keep *= 1.0 - a;
        let tau = -(1.0 - a.min(OPAQUE_ALPHA)).ln();
        tau_sum += tau;
        for k in 0..3 {
            rgb[k] += tau * c[k];
        }
    }
    if tau_sum <= 0.0 {
        return [0.0; 4];
    }
    let a = 1.0 - keep;
    let s = a / tau_sum;
    [rgb[0] * s, rgb[1] * s, rgb[2] * s, a]
}

/// The gain of a channel in slice views: one over its transfer function's
/// largest opacity (0 when it is transparent everywhere), so that a slice
/// shows the channel at full colour where its TF is most opaque.
pub fn slice_gain(tf: &TransferFunction) -> f64 {
    let max = tf.entries().iter().map(|e| e[3]).fold(0.0f32, f32::max) as f64;
    if max > 0.0 { 1.0 / max } else { 0.0 }
}

/// The colour of a slice view's pixel (opaque) from the visible channels'
/// classified values `(rgb_c, a_c, gain_c)` (their TFs' uncorrected lookups
/// and [`slice_gain`]s): the channels' colours added, each weighted by its
/// opacity over its TF's largest (a window style: its colour times the
/// windowed intensity), clamped to 1: the additive blending of microscopy
/// viewers.
pub fn slice_color(parts: &[([f64; 3], f64, f64)]) -> [f64; 3] {
    let mut rgb = [0.0f64; 3];
    for &(c, a, gain) in parts {
        let w = a.clamp(0.0, 1.0) * gain;
        for k in 0..3 {
            rgb[k] += w * c[k];
        }
    }
    rgb.map(|x| x.min(1.0))
}

/// Per macro cell of a multi-channel volume: empty when every visible
/// channel's range there is `empty` for that channel (`ranges[c]` is channel
/// `c`'s cell ranges, [`crate::MacroCellGrid::ranges`]). A hidden channel
/// never makes a cell non-empty; with no visible channel every cell is
/// empty.
pub fn cells_empty(
    ranges: &[&[[f32; 2]]],
    visible: &[bool],
    empty: impl Fn(usize, [f32; 2]) -> bool,
) -> Vec<bool> {
    let cells = ranges.first().map_or(0, |r| r.len());
    (0..cells)
        .map(|i| {
            ranges
                .iter()
                .enumerate()
                .all(|(c, r)| !visible.get(c).copied().unwrap_or(false) || empty(c, r[i]))
        })
        .collect()
}

/// Texel lanes that hold `channels` channels (1, 2 or 4: three channels
/// take an RGBA texel, as GPUs have no three-lane filterable formats).
pub fn texel_lanes(channels: usize) -> usize {
    match channels {
        0 | 1 => 1,
        2 => 2,
        _ => 4,
    }
}

/// Interleaves the texels of each channel (`parts[c]`, `texel_bytes` bytes a
/// texel, all of one length) into texels of `lanes` lanes (channel `c` in
/// lane `c`, lanes past the channels zero): the layout of a packed RGBA
/// texture.
pub fn interleave(parts: &[&[u8]], texel_bytes: usize, lanes: usize) -> Vec<u8> {
    let n = parts.first().map_or(0, |p| p.len() / texel_bytes.max(1));
    let mut out = vec![0u8; n * texel_bytes * lanes];
    interleave_into(parts, texel_bytes, lanes, &mut out);
    out
}

/// [`interleave`] into `out` (as many texels of `lanes` lanes as it
/// holds; lanes past the parts keep their bytes).
pub fn interleave_into(parts: &[&[u8]], texel_bytes: usize, lanes: usize, out: &mut [u8]) {
    let stride = texel_bytes * lanes;
    let n = out.len() / stride.max(1);
    for (c, part) in parts.iter().enumerate().take(lanes) {
        for (i, t) in part.chunks_exact(texel_bytes).take(n).enumerate() {
            let at = i * stride + c * texel_bytes;
            out[at..at + texel_bytes].copy_from_slice(t);
        }
    }
}

/// A multi-channel node's LOD error records, channel `c`'s in entry `c`
/// (see [`crate::NodeInfo::channel_errors`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ChannelErrors {
    /// Each channel's error of drawing the node instead of the finest data.
    pub error: [Option<crate::lod::NodeError>; MAX_CHANNELS],
    /// Each channel's error of drawing the node's region from its parent's
    /// brick.
    pub parent_error: [Option<crate::lod::NodeError>; MAX_CHANNELS],
}

/// Whether a node whose channels' raw ranges are `ranges` (channel `c`'s
/// in `ranges[c]`, its value range `value_ranges[c]`) can show anything
/// under `styles` in `mode`: some visible channel is not transparent over
/// its range (DVR), reaches its isovalue (iso, where a node wholly inside
/// stays visible as for one channel), or is drawn at all (MIP). What
/// out-of-core refinement skips a node by, and the kernel a sub-cell by
/// (its GPU twin, in `ooc_channels.wgsl`).
pub fn node_visible(
    ranges: &[[f32; 2]],
    value_ranges: &[[f32; 2]],
    styles: &[ChannelStyle],
    mode: crate::RenderMode,
) -> bool {
    ranges
        .iter()
        .zip(value_ranges)
        .zip(styles)
        .filter(|(_, s)| s.visible)
        .any(|((r, vr), s)| {
            let n = |v: f32| {
                let span = vr[1] - vr[0];
                if span > 0.0 { (v - vr[0]) / span } else { 0.0 }
            };
            let (a, b) = (n(r[0]), n(r[1]));
            let (lo, hi) = (a.min(b), a.max(b));
            match mode {
                crate::RenderMode::Dvr => !s.tf.is_transparent(lo, hi),
                crate::RenderMode::Iso { .. } => s.isovalue <= hi,
                _ => true,
            }
        })
}

mod source;
pub use source::ChannelSource;

#[cfg(test)]
mod tests;
