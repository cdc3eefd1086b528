//! A multi-channel brick source ([`ChannelSource`]): the channels' own
//! single-channel sources (one brick store per channel, OME-Zarr images,
//! procedural sources) on one octree, read together so each node is one
//! brick holding every channel of its voxels, channel fastest
//! ([`OctreeLayout::with_channels`]). The cache, the loader and the GPU pool
//! see one request, one cache entry and one atlas slot per node for all
//! channels; each channel's source is read once per brick.

use super::{ChannelError, MAX_CHANNELS};
use crate::{BrickError, BrickSource, CancelToken, NodeInfo, NodeKey, NodeKind, OctreeLayout};
use std::sync::Arc;

/// Several single-channel sources on one octree drawn as the channels of
/// one volume (see the module documentation).
pub struct ChannelSource {
    parts: Vec<Arc<dyn BrickSource>>,
    layout: OctreeLayout,
}

impl std::fmt::Debug for ChannelSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ChannelSource")
            .field("layout", &self.layout)
            .finish_non_exhaustive()
    }
}

impl ChannelSource {
    /// The channels `parts` (1 to [`MAX_CHANNELS`], channel `c` from
    /// `parts[c]`): each a single-channel intensity source with channel 0's
    /// octree (dims, dtype, spacing, brick, apron, levels and splits); each
    /// keeps its value range.
    pub fn new(parts: Vec<Arc<dyn BrickSource>>) -> Result<ChannelSource, ChannelError> {
        if parts.is_empty() || parts.len() > MAX_CHANNELS {
            return Err(ChannelError::Count {
                count: parts.len(),
                max: MAX_CHANNELS,
            });
        }
        let first = parts[0].layout().clone();
        let mut ranges = Vec::with_capacity(parts.len());
        for (c, p) in parts.iter().enumerate() {
            let l = p.layout();
            if l.volume.kind.is_labels() {
                return Err(ChannelError::Labels { channel: c });
            }
            let mismatch = |what: &'static str, e: String, f: String| ChannelError::Mismatch {
                channel: c,
                what,
                expected: e,
                found: f,
            };
            if l.is_channel_volume() {
                return Err(mismatch(
                    "channels",
                    "a plain volume".into(),
                    format!("{} channels", l.channels()),
                ));
            }
            let geometry = |l: &OctreeLayout| {
                (
                    l.volume.dims,
                    l.volume.dtype,
                    l.volume.spacing.map(f32::to_bits),
                    l.brick,
                    l.apron,
                    l.levels,
                    l.splits.clone(),
                )
            };
            if geometry(l) != geometry(&first) {
                return Err(mismatch(
                    "octree",
                    format!("{:?}", geometry(&first)),
                    format!("{:?}", geometry(l)),
                ));
            }
            ranges.push(l.volume.value_range);
        }
        Ok(ChannelSource {
            layout: first.with_channels(&ranges),
            parts,
        })
    }

    /// Channels.
    pub fn len(&self) -> usize {
        self.parts.len()
    }

    /// Always false (a source has at least one channel).
    pub fn is_empty(&self) -> bool {
        self.parts.is_empty()
    }

    /// Channel `c`'s source.
    pub fn part(&self, c: usize) -> Option<&Arc<dyn BrickSource>> {
        self.parts.get(c)
    }

    /// One node's metadata from each channel's: empty only where every
    /// channel is empty; `min`/`max` channel 0's, `channels` each one's raw
    /// range (a uniform channel's value; an empty channel's fill),
    /// `channel_errors` each one's LOD error records where the channels'
    /// sources record them (each binned over its own channel's range:
    /// error-aware refinement weighs each through its channel's transfer
    /// function). `error` stays `None`: no single record stands for every
    /// channel.
    fn combine(&self, infos: &[NodeInfo]) -> NodeInfo {
        let mut ranges = [[0.0f32; 2]; MAX_CHANNELS];
        for (r, i) in ranges.iter_mut().zip(infos) {
            *r = match i.kind {
                NodeKind::Uniform(v) => [v, v],
                _ => [i.min, i.max],
            };
        }
        let mut errors = super::ChannelErrors::default();
        for (c, i) in infos.iter().enumerate().take(MAX_CHANNELS) {
            errors.error[c] = i.error;
            errors.parent_error[c] = i.parent_error;
        }
        let recorded = infos.iter().any(|i| i.error.is_some());
        let empty = infos.iter().all(|i| i.kind == NodeKind::Empty);
        NodeInfo {
            kind: if empty {
                NodeKind::Empty
            } else {
                NodeKind::Data
            },
            min: ranges[0][0],
            max: ranges[0][1],
            error: None,
            parent_error: None,
            channels: ranges,
            channel_errors: recorded.then(|| Arc::new(errors)),
        }
    }

    /// Bytes of one channel's brick.
    fn part_bytes(&self) -> usize {
        self.layout.brick_bytes() / self.parts.len()
    }

    /// Interleaves the channels' bricks `bufs` into `out` (channel fastest).
    fn interleave(&self, bufs: &[Vec<u8>], out: &mut [u8]) {
        let parts: Vec<&[u8]> = bufs.iter().map(Vec::as_slice).collect();
        super::interleave_into(
            &parts,
            self.layout.volume.dtype.size(),
            self.parts.len(),
            out,
        );
    }

    fn check_len(&self, out: &[u8]) -> Result<(), BrickError> {
        if out.len() != self.layout.brick_bytes() {
            return Err(BrickError::BufferSize {
                expected: self.layout.brick_bytes(),
                actual: out.len(),
            });
        }
        Ok(())
    }
}

impl BrickSource for ChannelSource {
    fn layout(&self) -> &OctreeLayout {
        &self.layout
    }

    fn node(&self, key: NodeKey) -> Result<NodeInfo, BrickError> {
        let infos = self
            .parts
            .iter()
            .map(|p| p.node(key))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(self.combine(&infos))
    }

    fn nodes(&self, keys: &[NodeKey]) -> Vec<Result<NodeInfo, BrickError>> {
        let mut per_part: Vec<std::vec::IntoIter<Result<NodeInfo, BrickError>>> = self
            .parts
            .iter()
            .map(|p| p.nodes(keys).into_iter())
            .collect();
        keys.iter()
            .map(|_| {
                let mut infos = Vec::with_capacity(per_part.len());
                let mut first_err = None;
                for it in per_part.iter_mut() {
                    match it.next() {
                        Some(Ok(i)) => infos.push(i),
                        Some(Err(e)) => first_err = first_err.or(Some(e)),
                        None => {}
                    }
                }
                match first_err {
                    Some(e) => Err(e),
                    None => Ok(self.combine(&infos)),
                }
            })
            .collect()
    }

    fn read_brick(&self, key: NodeKey, out: &mut [u8]) -> Result<(), BrickError> {
        self.check_len(out)?;
        let mut bufs = vec![vec![0u8; self.part_bytes()]; self.parts.len()];
        for (p, b) in self.parts.iter().zip(bufs.iter_mut()) {
            p.read_brick(key, b)?;
        }
        self.interleave(&bufs, out);
        Ok(())
    }

    fn batch_size(&self) -> usize {
        self.parts.iter().map(|p| p.batch_size()).max().unwrap_or(1)
    }

    fn read_bricks(
        &self,
        keys: &[NodeKey],
        outs: &mut [&mut [u8]],
        cancel: &CancelToken,
    ) -> Vec<Result<(), BrickError>> {
        let n = self.parts.len();
        // bufs[k][c]: brick k of channel c.
        let mut bufs = vec![vec![vec![0u8; self.part_bytes()]; n]; keys.len()];
        let mut results: Vec<Result<(), BrickError>> =
            outs.iter().map(|o| self.check_len(o)).collect();
        for (c, p) in self.parts.iter().enumerate() {
            let mut views: Vec<&mut [u8]> = bufs.iter_mut().map(|b| b[c].as_mut_slice()).collect();
            let r = p.read_bricks(keys, &mut views, cancel);
            for (res, r) in results.iter_mut().zip(r) {
                if res.is_ok() {
                    *res = r;
                }
            }
        }
        for ((res, out), b) in results.iter().zip(outs.iter_mut()).zip(&bufs) {
            if res.is_ok() {
                self.interleave(b, out);
            }
        }
        results
    }
}
