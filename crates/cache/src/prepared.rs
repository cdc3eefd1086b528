//! Bricks prepared for the GPU off the frame path: the loader's workers turn each
//! brick they read into its texels and sub-cell ranges, so the render thread only
//! copies bytes.

use crate::config::{ConfigError, GpuFormat, raw_brick_bytes};
use brickray_core::tf::spread::spread_reach;
use brickray_core::tf::{SPREAD_ROWS, TABLE_MIN_WIDTH};
use brickray_core::{
    BrickError, BrickSource, NodeInfo, NodeKey, OctreeLayout, SampleEncoding, sub_cell_ranges,
    sub_cell_spreads,
};
use std::sync::Arc;

/// A brick ready to upload: what the renderer writes into its atlas slot, its
/// sub-cell table and its slot-table row.
#[derive(Debug, Clone, PartialEq)]
pub struct PreparedBrick {
    /// `stored_side^3` texels of [`GpuFormat::encoding`], x fastest.
    pub texels: Arc<[u8]>,
    /// Normalized `[min, max]` of each of the `n^3` sub-cells (x fastest,
    /// `n` = [`GpuFormat::sub_cells_per_axis`]); see
    /// [`sub_cell_ranges`](brickray_core::sub_cell_ranges). A multi-channel
    /// brick has one per sub-cell and channel, channel fastest.
    pub sub_cells: Arc<[[f32; 2]]>,
    /// Normalized `[min, max]` bounding every sample inside the brick: the
    /// node's metadata range (its interior voxels) widened to its sub-cells'
    /// ranges, which cover the apron voxels that samples near a face read.
    /// `[-inf, inf]` when either is not finite: never skipped; always for
    /// a multi-channel brick (its channels' ranges are its sub-cells').
    pub range: [f32; 2],
    /// With [`GpuFormat::spread`], for a brick above the finest level: the
    /// spread of each stored voxel as half-float bits (`stored_side^3`, x
    /// fastest), what the renderer writes into its spread atlas; the ranges
    /// above are then widened by the spread's reach
    /// ([`brickray_core::tf::spread::spread_reach`]). `None` at the finest
    /// level, whose spread is 0 and which the kernel never reads.
    pub spread: Option<Arc<[u16]>>,
}

impl PreparedBrick {
    /// Bytes it occupies (and uploads): `texels.len() + 8 * sub_cells.len()`,
    /// and 2 per spread.
    pub fn bytes(&self) -> u64 {
        self.texels.len() as u64
            + 8 * self.sub_cells.len() as u64
            + 2 * self.spread.as_ref().map_or(0, |s| s.len() as u64)
    }
}

/// Turns bricks as the source stores them into [`PreparedBrick`]s.
#[derive(Debug, Clone)]
pub struct Preparer {
    layout: OctreeLayout,
    encoding: SampleEncoding,
    gpu: GpuFormat,
    sub_cells_per_axis: u32,
    raw_bytes: usize,
}

impl Preparer {
    /// A preparer for `layout` and what the device stores (`gpu`), checked.
    pub fn new(layout: &OctreeLayout, gpu: &GpuFormat) -> Result<Preparer, ConfigError> {
        gpu.validate(layout)?;
        Ok(Preparer {
            layout: layout.clone(),
            encoding: gpu.encoding,
            gpu: *gpu,
            sub_cells_per_axis: gpu.sub_cells_per_axis,
            raw_bytes: raw_brick_bytes(layout)?,
        })
    }

    /// The octree layout.
    pub fn layout(&self) -> &OctreeLayout {
        &self.layout
    }

    /// Bytes of a brick as the source stores it (the read buffer).
    pub fn raw_bytes(&self) -> usize {
        self.raw_bytes
    }

    /// The normalized `[min, max]` of a node's metadata, ordered; `[-inf, inf]`
    /// when not finite.
    pub fn range(&self, info: &NodeInfo) -> [f32; 2] {
        let d = &self.layout.volume;
        let (a, b) = (d.normalize(info.min), d.normalize(info.max));
        if a.is_finite() && b.is_finite() {
            [a.min(b), a.max(b)]
        } else {
            [f32::NEG_INFINITY, f32::INFINITY]
        }
    }

    /// Prepares brick `key` read from `source` (`raw`: `raw_bytes()`
    /// little-endian samples, metadata `info`), with its spread read from
    /// `source` when the format carries one ([`GpuFormat::spread`]) and the
    /// brick lies above the finest level. A finest-level brick's spread is 0
    /// and the kernel never reads it (it classifies such a brick by its
    /// values, and a fade reads only the coarser fallback's spread), so it
    /// is neither read, kept in CPU memory nor uploaded: half of a u8 or u16
    /// brick's bytes.
    pub fn prepare_from(
        &self,
        source: &dyn BrickSource,
        key: NodeKey,
        raw: &[u8],
        info: &NodeInfo,
    ) -> Result<PreparedBrick, BrickError> {
        let finest = key.level + 1 >= self.layout.levels;
        if !self.gpu.spread || self.gpu.channel_count > 1 || finest {
            return Ok(self.prepare(raw, info));
        }
        let side = self.layout.stored_side() as usize;
        let mut spread = vec![0u16; side * side * side];
        source.read_spread(key, &mut spread)?;
        Ok(self.prepare_with_spread(raw, Some(spread.into()), info))
    }

    /// Prepares a brick read from the source (`raw`: `raw_bytes()` little-endian
    /// samples) whose metadata is `info`, without a spread.
    pub fn prepare(&self, raw: &[u8], info: &NodeInfo) -> PreparedBrick {
        if self.gpu.channel_count > 1 {
            return self.prepare_channels(raw);
        }
        self.prepare_with_spread(raw, None, info)
    }

    /// A single-channel brick, with its spread per stored voxel (half-float
    /// bits) when given: each sub-cell's range widened by the reach of its
    /// largest spread through any spread table the renderers build (at
    /// least [`TABLE_MIN_WIDTH`] columns), so that skipping stays
    /// conservative for the spread's lookups.
    fn prepare_with_spread(
        &self,
        raw: &[u8],
        spread: Option<Arc<[u16]>>,
        info: &NodeInfo,
    ) -> PreparedBrick {
        let texels: Arc<[u8]> = Arc::from(self.encoding.encode(raw).as_ref());
        let mut cells = sub_cell_ranges(&self.layout, raw, self.sub_cells_per_axis);
        if let Some(s) = &spread {
            let widths = sub_cell_spreads(&self.layout, s, self.sub_cells_per_axis);
            for (c, w) in cells.iter_mut().zip(widths) {
                let reach = spread_reach(w, TABLE_MIN_WIDTH, SPREAD_ROWS) as f32;
                if reach.is_finite() {
                    *c = [c[0] - reach, c[1] + reach];
                } else {
                    *c = [f32::NEG_INFINITY, f32::INFINITY];
                }
            }
        }
        let sub_cells: Arc<[[f32; 2]]> = cells.into();
        let range = sub_cells.iter().fold(self.range(info), |[lo, hi], c| {
            if lo.is_finite() && c[0].is_finite() && c[1].is_finite() {
                [lo.min(c[0]), hi.max(c[1])]
            } else {
                [f32::NEG_INFINITY, f32::INFINITY]
            }
        });
        PreparedBrick {
            texels,
            sub_cells,
            range,
            spread,
        }
    }
}

impl Preparer {
    /// A multi-channel brick (channels interleaved, channel fastest): each
    /// channel encoded with its own encoding and its sub-cells ranged over
    /// its own value range, the texels packed in the format's lanes
    /// ([`brickray_core::channels::interleave`]), the sub-cell ranges
    /// channel fastest.
    fn prepare_channels(&self, raw: &[u8]) -> PreparedBrick {
        let n = self.gpu.channel_count as usize;
        let s = self.layout.volume.dtype.size();
        let parts: Vec<Vec<u8>> = (0..n)
            .map(|c| {
                raw.chunks_exact(s * n)
                    .flat_map(|v| &v[c * s..(c + 1) * s])
                    .copied()
                    .collect()
            })
            .collect();
        let encoded: Vec<_> = parts
            .iter()
            .zip(&self.gpu.channel_encodings)
            .map(|(p, e)| e.encode(p))
            .collect();
        let refs: Vec<&[u8]> = encoded.iter().map(|e| e.as_ref()).collect();
        let texels = brickray_core::channels::interleave(
            &refs,
            self.encoding.texel_bytes() as usize,
            self.gpu.lanes() as usize,
        );
        let ranges: Vec<Vec<[f32; 2]>> = parts
            .iter()
            .enumerate()
            .map(|(c, p)| {
                sub_cell_ranges(&self.layout.channel_layout(c), p, self.sub_cells_per_axis)
            })
            .collect();
        let cells = ranges[0].len();
        let mut sub_cells = Vec::with_capacity(cells * n);
        for i in 0..cells {
            sub_cells.extend(ranges.iter().map(|r| r[i]));
        }
        PreparedBrick {
            texels: texels.into(),
            sub_cells: sub_cells.into(),
            range: [f32::NEG_INFINITY, f32::INFINITY],
            spread: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::refine::tests::ball_layout;
    use brickray_core::{NodeKind, TexelCaps, U8Filtering};

    /// A source whose spreads are non-zero and counted.
    struct Spreads {
        inner: crate::test_source::TestSource,
        reads: std::sync::atomic::AtomicUsize,
    }

    impl BrickSource for Spreads {
        fn layout(&self) -> &OctreeLayout {
            self.inner.layout()
        }
        fn node(&self, key: NodeKey) -> Result<NodeInfo, BrickError> {
            self.inner.node(key)
        }
        fn read_brick(&self, key: NodeKey, out: &mut [u8]) -> Result<(), BrickError> {
            self.inner.read_brick(key, out)
        }
        fn has_spread(&self) -> bool {
            true
        }
        fn read_spread(&self, _key: NodeKey, out: &mut [u16]) -> Result<(), BrickError> {
            self.reads
                .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            out.fill(0x2000);
            Ok(())
        }
    }

    /// A format with spreads reads, keeps and uploads them above the finest
    /// level only: a finest-level brick (spread 0, never read by the
    /// kernel) carries none and costs its texels and ranges alone, with the
    /// same ranges as without spreads.
    #[test]
    fn finest_bricks_carry_no_spread() {
        let layout = ball_layout(64);
        let caps = TexelCaps {
            norm16: true,
            float32_filterable: false,
        };
        let plain = GpuFormat::for_layout(&layout, caps, U8Filtering::Exact, 32, 2048);
        let gpu = GpuFormat {
            spread: true,
            ..plain
        };
        let p = Preparer::new(&layout, &gpu).unwrap();
        let src = Spreads {
            inner: crate::test_source::TestSource::new(64),
            reads: Default::default(),
        };
        let finest = layout.levels - 1;
        let keys = [
            NodeKey::ROOT,
            NodeKey::new(finest - 1, 0, 0, 0),
            NodeKey::new(finest, 1, 2, 3),
        ];
        for key in keys {
            let info = src.node(key).unwrap();
            let mut raw = vec![0u8; p.raw_bytes()];
            src.read_brick(key, &mut raw).unwrap();
            let before = src.reads.load(std::sync::atomic::Ordering::Relaxed);
            let b = p.prepare_from(&src, key, &raw, &info).unwrap();
            let read = src.reads.load(std::sync::atomic::Ordering::Relaxed) - before;
            let without = Preparer::new(&layout, &plain).unwrap().prepare(&raw, &info);
            let max = gpu.prepared_brick_bytes(&layout).unwrap();
            if key.level == finest {
                assert_eq!((b.spread.is_none(), read), (true, 0), "{key:?}");
                assert_eq!(b.bytes(), without.bytes());
                assert_eq!(
                    (&*b.sub_cells, b.range),
                    (&*without.sub_cells, without.range)
                );
                assert!(b.bytes() < max);
            } else {
                let s = b.spread.as_deref().expect("a coarse brick's spread");
                assert_eq!((s.len(), s[0], read), (p.raw_bytes(), 0x2000, 1), "{key:?}");
                assert_eq!(b.bytes(), max);
            }
        }
    }

    #[test]
    fn prepares_texels_cells_and_range() {
        let layout = ball_layout(64);
        let caps = TexelCaps {
            norm16: true,
            float32_filterable: false,
        };
        let gpu = GpuFormat::for_layout(&layout, caps, U8Filtering::Exact, 32, 2048);
        let p = Preparer::new(&layout, &gpu).unwrap();
        assert_eq!(p.raw_bytes(), 1000);
        let mut raw = vec![3u8; 1000];
        raw[0] = 0;
        raw[999] = 9;
        let info = NodeInfo {
            kind: NodeKind::Data,
            min: 0.9,
            max: 0.1,
            error: None,
            parent_error: None,
            channels: Default::default(),
            channel_errors: None,
        };
        let b = p.prepare(&raw, &info);
        assert_eq!(b.texels.len(), 2000);
        assert_eq!(&b.texels[..4], &[0, 0, 3, 3]);
        assert_eq!(&b.texels[1998..], &[9, 9]);
        // One sub-cell (8^3 interior voxels) spanning the whole brick.
        assert_eq!(&*b.sub_cells, &[[0.0, 9.0]]);
        // The metadata says 0.1..0.9 of the interior; samples read 0..9 (the
        // apron included): the range bounds what they read.
        assert_eq!(b.range, [0.0, 9.0]);
        assert_eq!(b.bytes(), 2008);
        assert_eq!(Some(b.bytes()), gpu.prepared_brick_bytes(&layout).ok());
        let nan = NodeInfo {
            min: f32::NAN,
            ..info.clone()
        };
        assert_eq!(p.range(&nan), [f32::NEG_INFINITY, f32::INFINITY]);
        assert_eq!(
            p.prepare(&raw, &nan).range,
            [f32::NEG_INFINITY, f32::INFINITY]
        );
        // Interior values within the metadata: the range is the metadata's.
        let flat = vec![5u8; 1000];
        let wide = NodeInfo {
            min: 1.0,
            max: 7.0,
            ..info.clone()
        };
        assert_eq!(p.prepare(&flat, &wide).range, [1.0, 7.0]);
    }

    /// Three u8 channels of one brick: each encoded (u8 as R16Unorm) and
    /// packed into four lanes, the fourth zero; each channel's sub-cells
    /// ranged over its own value range, channel fastest; no brick range.
    #[test]
    fn prepares_the_channels_of_a_brick() {
        let layout = ball_layout(64).with_channels(&[[0.0, 1.0], [0.0, 2.0], [0.0, 4.0]]);
        let caps = TexelCaps {
            norm16: true,
            float32_filterable: false,
        };
        let gpu = GpuFormat::for_layout(&layout, caps, U8Filtering::Exact, 32, 2048);
        assert_eq!(
            (gpu.channel_count, gpu.lanes(), gpu.texel_bytes()),
            (3, 4, 8)
        );
        let p = Preparer::new(&layout, &gpu).unwrap();
        assert_eq!(p.raw_bytes(), 3000);
        let raw: Vec<u8> = (0..1000).flat_map(|_| [1u8, 2, 4]).collect();
        let info = NodeInfo {
            kind: NodeKind::Data,
            min: 1.0,
            max: 1.0,
            error: None,
            parent_error: None,
            channels: Default::default(),
            channel_errors: None,
        };
        let b = p.prepare(&raw, &info);
        assert_eq!(b.texels.len(), 8000);
        assert_eq!(&b.texels[..8], &[1, 1, 2, 2, 4, 4, 0, 0]);
        assert_eq!(&*b.sub_cells, &[[1.0, 1.0], [1.0, 1.0], [1.0, 1.0]]);
        assert_eq!(b.range, [f32::NEG_INFINITY, f32::INFINITY]);
        assert_eq!(Some(b.bytes()), gpu.prepared_brick_bytes(&layout).ok());
    }
}
