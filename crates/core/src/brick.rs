//! Vocabulary of the brick octree, shared by the store, the caches, the index and
//! the renderer: node keys, the octree layout, node metadata and the
//! [`BrickSource`] trait (implemented by the file store and the procedural source).
//!
//! The volume is embedded in the smallest cube of `2^(levels-1)` bricks per axis
//! at the finest level. Level 0 is the root (one brick covering the whole cube at
//! the coarsest resolution); level `levels - 1` holds the original voxels. A node
//! at level `l` has integer position `(x, y, z)` in `0..2^l` and covers the
//! *octree cube* `[p / 2^l, (p + 1) / 2^l]` of the unit cube.

use crate::range::CancelToken;
use crate::volume::{DType, VolumeDesc};
use thiserror::Error;

/// A map keyed by node, hashed with FxHash (`rustc-hash`): several times
/// cheaper per lookup than the standard library's SipHash, which planning
/// pays on every node it visits. Keys come from the octree, not from outside,
/// so the standard hasher's resistance to chosen collisions buys nothing here.
pub type NodeMap<V> = std::collections::HashMap<NodeKey, V, rustc_hash::FxBuildHasher>;

/// A set of nodes, hashed like [`NodeMap`].
pub type NodeSet = std::collections::HashSet<NodeKey, rustc_hash::FxBuildHasher>;

/// Identifies an octree node.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct NodeKey {
    /// Level, 0 = root.
    pub level: u8,
    /// Position along x at this level.
    pub x: u32,
    /// Position along y at this level.
    pub y: u32,
    /// Position along z at this level.
    pub z: u32,
}

impl NodeKey {
    /// The root.
    pub const ROOT: NodeKey = NodeKey {
        level: 0,
        x: 0,
        y: 0,
        z: 0,
    };

    /// Builds a key.
    pub fn new(level: u8, x: u32, y: u32, z: u32) -> NodeKey {
        NodeKey { level, x, y, z }
    }

    /// Child `i` (bit 0 = +x, bit 1 = +y, bit 2 = +z).
    pub fn child(self, i: u8) -> NodeKey {
        NodeKey {
            level: self.level + 1,
            x: self.x * 2 + (i & 1) as u32,
            y: self.y * 2 + ((i >> 1) & 1) as u32,
            z: self.z * 2 + ((i >> 2) & 1) as u32,
        }
    }

    /// The eight children in order 0..8.
    pub fn children(self) -> [NodeKey; 8] {
        std::array::from_fn(|i| self.child(i as u8))
    }

    /// The parent, `None` for the root.
    pub fn parent(self) -> Option<NodeKey> {
        (self.level > 0).then(|| NodeKey::new(self.level - 1, self.x / 2, self.y / 2, self.z / 2))
    }

    /// Index of this node among its parent's children.
    pub fn child_index(self) -> u8 {
        ((self.x & 1) | ((self.y & 1) << 1) | ((self.z & 1) << 2)) as u8
    }

    /// The node's cube in octree unit-cube coordinates: `(min corner, side)`.
    pub fn unit_box(self) -> ([f64; 3], f64) {
        let side = 1.0 / (1u64 << self.level) as f64;
        (
            [
                self.x as f64 * side,
                self.y as f64 * side,
                self.z as f64 * side,
            ],
            side,
        )
    }
}

/// Geometry of a brick octree over a volume.
#[derive(Debug, Clone, PartialEq)]
pub struct OctreeLayout {
    /// The volume.
    pub volume: VolumeDesc,
    /// Interior voxels per brick side.
    pub brick: u32,
    /// Apron voxels replicated on each side of a brick.
    pub apron: u32,
    /// Number of levels (>= 1).
    pub levels: u8,
    /// Per-level split masks (see [`OctreeLayout::split_mask`]); empty for the
    /// isotropic octree, where every level halves all three axes.
    pub(crate) splits: Vec<u8>,
    /// The value range of each channel of a channel volume
    /// ([`crate::channels`]; channel 0's is `volume.value_range`); empty for
    /// a plain single-channel volume. A stored brick holds every channel of
    /// each voxel together, channel fastest ([`OctreeLayout::with_channels`]).
    pub(crate) channels: Vec<[f32; 2]>,
}

impl OctreeLayout {
    /// The layout for a volume: the fewest levels such that `brick * 2^(levels-1)`
    /// covers the largest dimension.
    pub fn new(volume: VolumeDesc, brick: u32, apron: u32) -> OctreeLayout {
        let brick = brick.max(1);
        let max_dim = *volume.dims.iter().max().unwrap_or(&1) as u64;
        let mut levels = 1u8;
        while (brick as u64) << (levels - 1) < max_dim {
            levels += 1;
        }
        OctreeLayout {
            volume,
            brick,
            apron,
            levels,
            splits: Vec::new(),
            channels: Vec::new(),
        }
    }

    /// This layout for a channel volume of `ranges.len()` channels (1 to
    /// [`crate::channels::MAX_CHANNELS`]; none: a plain volume), channel
    /// `c`'s values mapping to 0..1 over `ranges[c]`: a stored brick holds
    /// the channels of each voxel together (channel fastest), `brick_bytes`
    /// grows with them. A channel volume of one channel is stored as a plain
    /// one but drawn through its channel's style.
    pub fn with_channels(mut self, ranges: &[[f32; 2]]) -> OctreeLayout {
        self.channels = ranges.to_vec();
        if let Some(r) = ranges.first() {
            self.volume.value_range = *r;
        }
        self
    }

    /// Channels per voxel (1 for a plain volume).
    pub fn channels(&self) -> usize {
        self.channels.len().max(1)
    }

    /// True for a channel volume ([`Self::with_channels`]), whose channels
    /// are classified by their styles.
    pub fn is_channel_volume(&self) -> bool {
        !self.channels.is_empty()
    }

    /// Each channel's value range (empty for a plain volume).
    pub fn channel_ranges(&self) -> &[[f32; 2]] {
        &self.channels
    }

    /// The single-channel layout of channel `c` of a multi-channel one:
    /// the same octree, channel `c`'s value range.
    pub fn channel_layout(&self, c: usize) -> OctreeLayout {
        let mut l = self.clone();
        if let Some(r) = self.channels.get(c) {
            l.volume.value_range = *r;
        }
        l.channels = Vec::new();
        l
    }

    /// Stored voxels per brick side, `brick + 2 * apron`.
    pub fn stored_side(&self) -> u32 {
        self.brick + 2 * self.apron
    }

    /// Bytes of one stored brick.
    pub fn brick_bytes(&self) -> usize {
        (self.stored_side() as usize).pow(3) * self.volume.dtype.size() * self.channels()
    }

    /// Sample type.
    pub fn dtype(&self) -> DType {
        self.volume.dtype
    }

    /// Finest-level voxels per side of the octree cube (the isotropic octree;
    /// see [`OctreeLayout::cube_voxels_axes`] for the per-axis extents).
    pub fn cube_voxels(&self) -> u64 {
        (self.brick as u64) << (self.levels - 1)
    }

    /// Voxel dimensions of the volume at `level` (each halving rounds up).
    pub fn level_dims(&self, level: u8) -> [u32; 3] {
        let finest = self.halvings(self.levels - 1);
        let here = self.halvings(level);
        std::array::from_fn(|a| {
            let shift = finest[a] - here[a];
            ((self.volume.dims[a] as u64 + (1u64 << shift) - 1) >> shift) as u32
        })
    }

    /// The voxel box `lo..=hi` of `key`'s level that its stored brick (its
    /// voxels and the apron around them) reads, clamped to the level's
    /// dimensions.
    pub fn brick_footprint(&self, key: NodeKey) -> ([u64; 3], [u64; 3]) {
        let d = self.level_dims(key.level).map(|d| d as i64);
        let b = self.brick as i64;
        let a = self.apron as i64;
        let p = [key.x, key.y, key.z].map(|c| c as i64);
        let lo = [0, 1, 2].map(|i| (p[i] * b - a).clamp(0, d[i] - 1) as u64);
        let hi = [0, 1, 2].map(|i| (p[i] * b + b + a - 1).clamp(0, d[i] - 1) as u64);
        (lo, hi)
    }

    /// Gathers `key`'s stored brick from the values of its footprint
    /// ([`brick_footprint`](Self::brick_footprint): `lo..=hi`, x fastest): for
    /// each stored voxel in order (x fastest, `stored_side()^3` of them), the
    /// index of the footprint value it holds, edge-clamped where the brick
    /// reaches past the volume. `put(i)` is called once per stored voxel.
    pub fn gather_brick(
        &self,
        key: NodeKey,
        (lo, hi): ([u64; 3], [u64; 3]),
        mut put: impl FnMut(usize),
    ) {
        let n = [0, 1, 2].map(|a| (hi[a] - lo[a] + 1) as i64);
        let d = self.level_dims(key.level).map(|d| d as i64);
        let b = self.brick as i64;
        let a = self.apron as i64;
        let side = self.stored_side() as i64;
        let origin = [key.x, key.y, key.z].map(|c| c as i64 * b - a);
        let idx = |axis: usize, i: i64| (origin[axis] + i).clamp(0, d[axis] - 1) - lo[axis] as i64;
        for k in 0..side {
            let zk = idx(2, k);
            for j in 0..side {
                let row = (zk * n[1] + idx(1, j)) * n[0];
                for i in 0..side {
                    put((row + idx(0, i)) as usize);
                }
            }
        }
    }

    /// True when `key` is a valid position and its box overlaps the volume.
    pub fn in_volume(&self, key: NodeKey) -> bool {
        if key.level >= self.levels {
            return false;
        }
        let n = self.nodes_per_axis(key.level);
        let ld = self.level_dims(key.level);
        let p = [key.x, key.y, key.z];
        (0..3).all(|a| (p[a] as u64) < n[a] && (p[a] as u64) * (self.brick as u64) < ld[a] as u64)
    }

    /// The volume's extent inside the octree box, per axis (0..1]: texture
    /// coordinate `u` of the volume maps to octree coordinate `u * scale`.
    pub fn volume_scale(&self) -> [f64; 3] {
        let c = self.cube_voxels_axes();
        std::array::from_fn(|a| self.volume.dims[a] as f64 / c[a] as f64)
    }
}

/// What a node holds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum NodeKind {
    /// Nothing to draw: wholly outside the volume, or below the build threshold.
    Empty,
    /// Every stored voxel (apron included) has this raw value; no payload.
    Uniform(f32),
    /// A brick payload.
    Data,
}

/// Metadata of one node.
#[derive(Debug, Clone, PartialEq)]
pub struct NodeInfo {
    /// What the node holds.
    pub kind: NodeKind,
    /// Smallest raw value any sample in the node can interpolate from (apron included).
    pub min: f32,
    /// Largest such value.
    pub max: f32,
    /// The recorded bound on the error of drawing this node instead of the
    /// finest data ([`crate::lod`]); `None` when the source records none (a
    /// version-1 store): error-aware refinement then uses the geometric rule.
    pub error: Option<crate::lod::NodeError>,
    /// The recorded error of drawing this node's region from its *parent's*
    /// brick instead of the finest data, binned over the parent's value range
    /// (store format version 3; `docs/store-format.md`): what an
    /// octant-granular cut ([`crate::LodMetric::VisibleOctants`]) ranks an
    /// octant by. `None` at the root and when the source records none.
    pub parent_error: Option<crate::lod::NodeError>,
    /// A multi-channel source's raw `[min, max]` per channel (channel `c`
    /// in entry `c`, as `min`/`max` are bounded; `min`/`max` then hold
    /// channel 0's); zeros for a single-channel source.
    pub channels: [[f32; 2]; crate::channels::MAX_CHANNELS],
    /// A multi-channel source's LOD error records per channel (each over
    /// its channel's own range, as its store recorded it), where the
    /// channels' sources record them; `None` otherwise.
    pub channel_errors: Option<std::sync::Arc<crate::channels::ChannelErrors>>,
}

impl NodeInfo {
    /// Channel `c`'s own metadata of a multi-channel node: its range, its
    /// error records, the node's kind.
    pub fn channel(&self, c: usize) -> NodeInfo {
        let r = self
            .channels
            .get(c)
            .copied()
            .unwrap_or([self.min, self.max]);
        let e = self.channel_errors.as_deref();
        NodeInfo {
            kind: self.kind,
            min: r[0],
            max: r[1],
            error: e.and_then(|e| e.error.get(c).copied().flatten()),
            parent_error: e.and_then(|e| e.parent_error.get(c).copied().flatten()),
            channels: Default::default(),
            channel_errors: None,
        }
    }
}

/// Why a leaf of a cut needs no brick.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum EmptyReason {
    /// Outside the volume or empty by construction ([`NodeKind::Empty`]).
    Empty,
    /// Invisible under the current mode: transparent range for DVR, isovalue
    /// outside `[min, max]` for iso-surfaces.
    Invisible,
    /// Outside the view frustum.
    Culled,
    /// Its data is wanted but not available yet (only the root, before its
    /// metadata or brick arrives).
    NotLoaded,
    /// Its data is wanted but its metadata or brick could not be read (only the
    /// root: other nodes whose children failed are simply not split).
    Failed,
}

/// What a leaf of a cut holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LeafKind {
    /// Nothing to sample here; the ray skips it.
    Empty(EmptyReason),
    /// Sample the brick in this GPU pool slot.
    Data {
        /// The slot (any `u32` to the index encoder).
        slot: u32,
    },
}

impl LeafKind {
    /// The slot of a data leaf.
    pub fn slot(self) -> Option<u32> {
        match self {
            LeafKind::Data { slot } => Some(slot),
            LeafKind::Empty(_) => None,
        }
    }

    /// True for a data leaf.
    pub fn is_data(self) -> bool {
        matches!(self, LeafKind::Data { .. })
    }
}

/// One leaf of a cut of the octree: the cache produces them
/// (`FramePlan::cut`), the index encoder consumes them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CutLeaf {
    /// The node.
    pub key: NodeKey,
    /// What it holds.
    pub kind: LeafKind,
    /// Projected voxel size in pixels (0 for empty leaves; ignored by the encoder).
    pub priority: f32,
}

impl CutLeaf {
    /// A leaf with priority 0.
    pub fn new(key: NodeKey, kind: LeafKind) -> CutLeaf {
        CutLeaf {
            key,
            kind,
            priority: 0.0,
        }
    }

    /// A data leaf in `slot`, priority 0.
    pub fn data(key: NodeKey, slot: u32) -> CutLeaf {
        CutLeaf::new(key, LeafKind::Data { slot })
    }

    /// An empty leaf, priority 0.
    pub fn empty(key: NodeKey, reason: EmptyReason) -> CutLeaf {
        CutLeaf::new(key, LeafKind::Empty(reason))
    }

    /// The pool slot of a data leaf.
    pub fn slot(&self) -> Option<u32> {
        self.kind.slot()
    }
}

/// Errors from a brick source.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum BrickError {
    /// The key names no node of this octree.
    #[error("node {key:?} is outside the octree")]
    OutOfRange {
        /// The key.
        key: NodeKey,
    },
    /// The node's stored data is damaged.
    #[error("node {key:?} is corrupt: {reason}")]
    Corrupt {
        /// The key.
        key: NodeKey,
        /// What is wrong.
        reason: String,
    },
    /// Reading the node failed.
    #[error("node {key:?}: I/O error: {source}")]
    Io {
        /// The key.
        key: NodeKey,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// The read was cancelled: nobody wants the brick any more
    /// ([`BrickSource::read_bricks`]).
    #[error("node {key:?}: the read was cancelled")]
    Cancelled {
        /// The key.
        key: NodeKey,
    },
    /// The output buffer has the wrong size.
    #[error("brick buffer holds {actual} bytes, expected {expected}")]
    BufferSize {
        /// Bytes needed.
        expected: usize,
        /// Bytes given.
        actual: usize,
    },
}

/// Random access to the nodes of a brick octree. Implementations are thread-safe
/// so loader threads can read concurrently.
pub trait BrickSource: Send + Sync {
    /// The octree geometry.
    fn layout(&self) -> &OctreeLayout;

    /// Metadata of a node.
    fn node(&self, key: NodeKey) -> Result<NodeInfo, BrickError>;

    /// Metadata of several nodes, one result per key, each as
    /// [`node`](Self::node) gives it (a node that fails does not fail the
    /// others). The default reads them one after the other; a source whose
    /// metadata costs a round trip (an OME-Zarr image over the network
    /// reads it from the data) reads them together. The loader asks for the
    /// children of a brick it has just read in one call.
    fn nodes(&self, keys: &[NodeKey]) -> Vec<Result<NodeInfo, BrickError>> {
        keys.iter().map(|&key| self.node(key)).collect()
    }

    /// Writes the node's stored brick (`stored_side()^3` little-endian samples of
    /// the volume's dtype, x fastest, apron included) into `out`, whose length must
    /// be `layout().brick_bytes()`. Uniform and empty nodes are filled with their
    /// value (empty: the volume's minimum).
    fn read_brick(&self, key: NodeKey, out: &mut [u8]) -> Result<(), BrickError>;

    /// True when the source delivers each voxel's spread
    /// ([`read_spread`](Self::read_spread)): the standard deviation of the
    /// finest voxels a coarse voxel stands for, with which the renderers
    /// classify coarse levels (`docs/rendering-model.md`, *Coarse levels*).
    /// False by default: every voxel is drawn as the TF of its value.
    fn has_spread(&self) -> bool {
        false
    }

    /// Writes the node's spread per stored voxel into `out`
    /// (`stored_side()^3` values, x fastest, apron included, laid out as
    /// [`read_brick`](Self::read_brick)'s samples): the standard deviation
    /// of the normalized values of the finest voxels each voxel covers, as
    /// half-float bits (0 at the finest level). The default, for a source
    /// without spreads, writes 0 everywhere.
    fn read_spread(&self, key: NodeKey, out: &mut [u16]) -> Result<(), BrickError> {
        let _ = key;
        out.fill(0);
        Ok(())
    }

    /// How many bricks one [`read_bricks`](Self::read_bricks) call should
    /// carry: 1 (the default) for a source whose reads cost no round trip
    /// (memory, a local file); more for one over the network, where a batch
    /// of neighbouring bricks costs about one round trip instead of one each.
    /// The loader takes up to this many queued bricks, in priority order, per
    /// call.
    fn batch_size(&self) -> usize {
        1
    }

    /// Reads several bricks, each as [`read_brick`](Self::read_brick) would
    /// into its buffer of `outs` (as many as `keys`), with one result per key:
    /// a brick that fails does not fail the others. The default reads them
    /// one after the other, skipping (with [`BrickError::Cancelled`]) those
    /// not begun when `cancel` is cancelled; a source over the network
    /// fetches them together and aborts its requests when cancelled.
    fn read_bricks(
        &self,
        keys: &[NodeKey],
        outs: &mut [&mut [u8]],
        cancel: &CancelToken,
    ) -> Vec<Result<(), BrickError>> {
        keys.iter()
            .zip(outs.iter_mut())
            .map(|(&key, out)| {
                if cancel.is_cancelled() {
                    Err(BrickError::Cancelled { key })
                } else {
                    self.read_brick(key, out)
                }
            })
            .collect()
    }
}

/// Level `level` of `source` as one in-memory volume: every node of that
/// level read ([`BrickSource::read_brick`]) and its interior voxels copied,
/// x fastest. Its dims are the level's and its spacing the finest spacing
/// times the level's halvings per axis (a coarse voxel covers the finest
/// voxels `x * 2^h .. (x + 1) * 2^h`), so it covers the box the pyramid maps
/// it to. What an overlay draws of a label map too large for one texture
/// (a coarser level), or a whole small map streamed from a store. It holds
/// the whole level in memory: choose the level by
/// [`OctreeLayout::level_dims`] first.
pub fn level_volume(source: &dyn BrickSource, level: u8) -> Result<crate::Volume, BrickError> {
    let layout = source.layout();
    let d = layout.level_dims(level);
    let finest = layout.halvings(layout.levels.saturating_sub(1));
    let here = layout.halvings(level);
    let size = layout.dtype().size();
    let b = layout.brick;
    let side = layout.stored_side() as usize;
    let a = layout.apron as usize;
    let n = d.iter().map(|&v| v as usize).product::<usize>();
    let mut bytes = vec![0u8; n * size];
    let mut buf = vec![0u8; layout.brick_bytes()];
    for z in 0..d[2].div_ceil(b) {
        for y in 0..d[1].div_ceil(b) {
            for x in 0..d[0].div_ceil(b) {
                source.read_brick(NodeKey { level, x, y, z }, &mut buf)?;
                for k in 0..b.min(d[2] - z * b) {
                    for j in 0..b.min(d[1] - y * b) {
                        let row = b.min(d[0] - x * b) as usize;
                        let from = ((k as usize + a) * side + j as usize + a) * side + a;
                        let (vx, vy, vz) = (x * b, y * b + j, z * b + k);
                        let to = vx as usize
                            + d[0] as usize * (vy as usize + d[1] as usize * vz as usize);
                        bytes[to * size..(to + row) * size]
                            .copy_from_slice(&buf[from * size..(from + row) * size]);
                    }
                }
            }
        }
    }
    let v = &layout.volume;
    let desc = VolumeDesc {
        dims: d,
        spacing: std::array::from_fn(|i| v.spacing[i] * (1u32 << (finest[i] - here[i])) as f32),
        ..v.clone()
    };
    let data = crate::VolumeData::from_le_bytes(desc.dtype, &bytes);
    crate::Volume::new(desc, data).map_err(|e| BrickError::Corrupt {
        key: NodeKey {
            level,
            x: 0,
            y: 0,
            z: 0,
        },
        reason: e.to_string(),
    })
}
