//! A cut of a brick source as the out-of-core kernel draws it, on the CPU:
//! refined once from the root with every brick available (only the given
//! tolerance, brick budget and metric limit it), its leaves resampled onto the
//! finest grid (trilinear inside each leaf's stored brick, apron included),
//! for the f64 reference to render.

use super::LodModelError;
use brickray_cache::refine::{
    DataState, MetaState, RefineEnv, RefineParams, Refinement, ViewGeometry, Views, refine,
};
use brickray_cache::{NodeClass, UploadBudget};
use brickray_core::{
    BrickError, BrickSource, Camera, DType, LodMetric, NodeKey, NodeKind, OctreeLayout, RenderMode,
    TransferFunction, Volume, VolumeData, VolumeFrame,
};
use std::collections::hash_map::Entry;
use std::collections::{HashMap, HashSet};

/// The refinement environment of a cut with every brick available: each
/// node's metadata from the source (a failed read: [`MetaState::Failed`],
/// its error kept for [`take_error`](Self::take_error)), every brick on the
/// GPU, and the visible weights, when given (a node without one: weight 0).
pub struct AllAvailable<'a> {
    source: &'a dyn BrickSource,
    visible: Option<&'a HashMap<NodeKey, f64>>,
    error: Option<BrickError>,
}

impl<'a> AllAvailable<'a> {
    /// Every brick of `source` available; `visible`: what the image shows of
    /// each node ([`RefineEnv::visible_weight`]), `None` where not measured.
    pub fn new(
        source: &'a dyn BrickSource,
        visible: Option<&'a HashMap<NodeKey, f64>>,
    ) -> AllAvailable<'a> {
        AllAvailable {
            source,
            visible,
            error: None,
        }
    }

    /// The first metadata read that failed since the last call, if any.
    pub fn take_error(&mut self) -> Option<BrickError> {
        self.error.take()
    }
}

impl std::fmt::Debug for AllAvailable<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AllAvailable")
            .field("layout", self.source.layout())
            .field("visible", &self.visible.map(HashMap::len))
            .field("error", &self.error)
            .finish()
    }
}

impl RefineEnv for AllAvailable<'_> {
    fn node(&mut self, key: NodeKey) -> MetaState {
        match self.source.node(key) {
            Ok(i) => MetaState::Known(std::sync::Arc::new(i)),
            Err(e) => {
                self.error.get_or_insert(e);
                MetaState::Failed
            }
        }
    }
    fn data(&mut self, _key: NodeKey) -> DataState {
        DataState::OnGpu
    }
    fn visible_weight(&mut self, key: NodeKey) -> Option<f64> {
        self.visible.map(|w| w.get(&key).copied().unwrap_or(0.0))
    }
}

/// What a cut is refined for: the source, the classification and the view.
#[derive(Clone, Copy)]
pub struct CutView<'a> {
    /// The bricks.
    pub source: &'a dyn BrickSource,
    /// The transfer function (decides which nodes are visible).
    pub tf: &'a TransferFunction,
    /// The render mode.
    pub mode: RenderMode,
    /// The camera.
    pub camera: &'a Camera,
    /// The volume's placement in the world.
    pub frame: &'a VolumeFrame,
    /// The image's side in pixels (square images).
    pub size: u32,
    /// What the image shows of each node
    /// ([`visible_weights`](crate::visible_weights)), for refinement ranked
    /// by it; `None`: not measured.
    pub visible: Option<&'a HashMap<NodeKey, f64>>,
}

impl std::fmt::Debug for CutView<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CutView")
            .field("layout", self.source.layout())
            .field("mode", &self.mode)
            .field("camera", self.camera)
            .field("frame", self.frame)
            .field("size", &self.size)
            .field("visible", &self.visible.map(HashMap::len))
            .finish_non_exhaustive()
    }
}

/// The refinement of `view` with every brick available, limited only by
/// `tolerance_px`, the budget of data leaves and the metric. A node whose
/// metadata the refinement asks for and cannot read fails it (the first
/// such error), rather than leaving the cut coarser there.
pub fn refine_cut(
    view: &CutView<'_>,
    tolerance_px: f32,
    max_data_leaves: u32,
    metric: LodMetric,
) -> Result<Refinement, LodModelError> {
    let layout = view.source.layout();
    let params = RefineParams {
        views: &Views::one(ViewGeometry::new(
            layout,
            view.camera,
            1.0,
            view.size,
            view.frame,
        )),
        generation: 0,
        mode: view.mode,
        tf: view.tf,
        channels: &[],
        tolerance_px,
        metric,
        max_data_leaves,
        max_requests: u32::MAX / 2,
        max_prefetch: u32::MAX,
        brick_upload_bytes: layout.brick_bytes() as u64,
        lookahead: false,
    };
    let mut budget = UploadBudget::new(u64::MAX / 4);
    let mut env = AllAvailable::new(view.source, view.visible);
    let r = refine(layout, &params, &mut env, &mut budget);
    match env.take_error() {
        Some(e) => Err(e.into()),
        None => Ok(r),
    }
}

/// A cut resampled onto the finest grid ([`cut_volume`]).
#[derive(Debug, Clone)]
pub struct CutVolume {
    /// The finest-grid volume the cut's leaves sample to, in the source's
    /// type ([`typed`]).
    pub volume: Volume,
    /// The cut's leaves that need a brick.
    pub data_leaves: u32,
    /// Of them, how many at each level (index: level).
    pub data_leaves_per_level: Vec<u32>,
}

/// The cut of [`refine_cut`] resampled onto the finest grid, with its
/// data-leaf counts.
pub fn cut_volume(
    view: &CutView<'_>,
    tolerance_px: f32,
    max_data_leaves: u32,
    metric: LodMetric,
) -> Result<CutVolume, LodModelError> {
    let r = refine_cut(view, tolerance_px, max_data_leaves, metric)?;
    let layout = view.source.layout();
    let mut per_level = vec![0u32; layout.levels as usize];
    for l in &r.leaves {
        if l.class == NodeClass::Data
            && let Some(n) = per_level.get_mut(l.key.level as usize)
        {
            *n += 1;
        }
    }
    let leaves: HashSet<NodeKey> = r.leaves.iter().map(|l| l.key).collect();
    let samples = Resampler::new(view.source)?.resample(&leaves)?;
    Ok(CutVolume {
        volume: typed(layout, samples)?,
        data_leaves: r.data_leaves,
        data_leaves_per_level: per_level,
    })
}

/// Samples nodes' stored bricks onto the finest grid, as the out-of-core
/// kernel samples them: trilinear inside each node's stored brick, apron
/// included. Bricks are read once and kept, decoded.
pub struct Resampler<'a> {
    source: &'a dyn BrickSource,
    /// Finest voxels per node voxel, per level and axis.
    factors: Vec<[f64; 3]>,
    /// Each brick read so far, decoded: its values, and apart its spreads
    /// ([`sample_spread`](Self::sample_spread)).
    bricks: HashMap<NodeKey, Vec<f32>>,
    spreads: HashMap<NodeKey, Vec<f32>>,
    buf: Vec<u8>,
    /// Stored voxels per brick side; interior voxels and apron per side.
    side: i64,
    brick: f64,
    apron: f64,
}

impl std::fmt::Debug for Resampler<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Resampler")
            .field("layout", self.source.layout())
            .field("bricks_read", &self.bricks.len())
            .finish_non_exhaustive()
    }
}

impl<'a> Resampler<'a> {
    /// A resampler of `source`'s bricks (one channel, stored side at least
    /// 2).
    pub fn new(source: &'a dyn BrickSource) -> Result<Resampler<'a>, LodModelError> {
        let layout = source.layout();
        if layout.channels() != 1 {
            return Err(LodModelError::MultiChannel {
                channels: layout.channels(),
            });
        }
        if layout.stored_side() < 2 {
            return Err(LodModelError::BrickTooSmall {
                stored_side: layout.stored_side(),
            });
        }
        Ok(Resampler {
            source,
            factors: (0..layout.levels).map(|l| layout.voxel_factor(l)).collect(),
            bricks: HashMap::new(),
            spreads: HashMap::new(),
            buf: vec![0u8; layout.brick_bytes()],
            side: layout.stored_side() as i64,
            brick: layout.brick as f64,
            apron: layout.apron as f64,
        })
    }

    /// The source's octree.
    pub fn layout(&self) -> &'a OctreeLayout {
        self.source.layout()
    }

    fn factor(&self, key: NodeKey) -> Result<[f64; 3], LodModelError> {
        self.factors
            .get(key.level as usize)
            .copied()
            .ok_or(LodModelError::NotInOctree {
                key,
                levels: self.factors.len() as u8,
            })
    }

    /// The finest voxel `v` as the node `key` draws it: trilinear in its
    /// stored brick (uniform and empty nodes: their value, an empty node's
    /// the smallest of its range). Voxels outside the node are clamped to
    /// its stored brick.
    pub fn sample(&mut self, key: NodeKey, v: [u32; 3]) -> Result<f32, LodModelError> {
        let f = self.factor(key)?;
        let dtype = self.source.layout().volume.dtype;
        let br = match self.bricks.entry(key) {
            Entry::Occupied(e) => e.into_mut(),
            Entry::Vacant(e) => {
                let info = self.source.node(key)?;
                let n = self.buf.len() / dtype.size();
                e.insert(match info.kind {
                    // No payload: every stored voxel holds the value (an
                    // empty node: its smallest, below the build threshold;
                    // the renderer draws nothing there).
                    NodeKind::Uniform(u) => vec![u; n],
                    NodeKind::Empty => vec![info.min; n],
                    NodeKind::Data => {
                        self.source.read_brick(key, &mut self.buf)?;
                        dtype.decode_le(&self.buf)
                    }
                })
            }
        };
        Ok(trilinear(br, key, v, f, self.side, self.brick, self.apron))
    }

    /// The spread ([`BrickSource::read_spread`]: the standard deviation of
    /// the normalized values of the finest voxels a voxel stands for) at the
    /// finest voxel `v` as the node `key` draws it, trilinear in its stored
    /// spreads as [`sample`](Self::sample) is in its values: 0 at the finest
    /// level, in uniform and empty nodes and in a source without spreads.
    pub fn sample_spread(&mut self, key: NodeKey, v: [u32; 3]) -> Result<f32, LodModelError> {
        let f = self.factor(key)?;
        let n = (self.side * self.side * self.side) as usize;
        let br = match self.spreads.entry(key) {
            Entry::Occupied(e) => e.into_mut(),
            Entry::Vacant(e) => {
                let info = self.source.node(key)?;
                e.insert(match info.kind {
                    NodeKind::Data => {
                        let mut bits = vec![0u16; n];
                        self.source.read_spread(key, &mut bits)?;
                        bits.into_iter()
                            .map(brickray_core::texel::f16_to_f32)
                            .collect()
                    }
                    _ => vec![0.0; n],
                })
            }
        };
        Ok(trilinear(br, key, v, f, self.side, self.brick, self.apron))
    }

    /// The node of level `l` holding the finest voxel `v`.
    fn node_at(&self, l: u8, v: [u32; 3]) -> NodeKey {
        let f = self.factors[l as usize];
        let b = self.brick;
        let p: [u32; 3] = std::array::from_fn(|i| (v[i] as f64 / (f[i] * b)).floor() as u32);
        NodeKey::new(l, p[0], p[1], p[2])
    }

    /// Every finest voxel (x fastest), from the coarsest node of `leaves`
    /// that holds it: for a cut's leaves, the one leaf that does.
    pub fn resample(&mut self, leaves: &HashSet<NodeKey>) -> Result<Vec<f32>, LodModelError> {
        self.resample_from(leaves, false, false)
    }

    /// The spreads of [`resample`](Self::resample)'s voxels
    /// ([`sample_spread`](Self::sample_spread)).
    pub fn resample_spread(
        &mut self,
        leaves: &HashSet<NodeKey>,
    ) -> Result<Vec<f32>, LodModelError> {
        self.resample_from(leaves, false, true)
    }

    /// `v` of `key`: its value, or with `spread` its spread.
    fn sample_field(
        &mut self,
        key: NodeKey,
        v: [u32; 3],
        spread: bool,
    ) -> Result<f32, LodModelError> {
        match spread {
            true => self.sample_spread(key, v),
            false => self.sample(key, v),
        }
    }

    /// Every finest voxel (x fastest), from the deepest node of `nodes` that
    /// holds it ([`octant_cut`](super::octant_cut)'s cuts: a node draws the
    /// regions of its children that are not in the set).
    pub fn resample_deepest(
        &mut self,
        nodes: &HashSet<NodeKey>,
    ) -> Result<Vec<f32>, LodModelError> {
        self.resample_from(nodes, true, false)
    }

    fn resample_from(
        &mut self,
        set: &HashSet<NodeKey>,
        deepest: bool,
        spread: bool,
    ) -> Result<Vec<f32>, LodModelError> {
        let layout = self.source.layout();
        let d = layout.volume.dims;
        let levels = layout.levels;
        let mut out = vec![0f32; d.iter().map(|&n| n as usize).product()];
        for z in 0..d[2] {
            for y in 0..d[1] {
                for x in 0..d[0] {
                    let v = [x, y, z];
                    let found = |l: &u8| set.contains(&self.node_at(*l, v));
                    let l = if deepest {
                        (0..levels).rev().find(found)
                    } else {
                        (0..levels).find(found)
                    };
                    let key = l
                        .map(|l| self.node_at(l, v))
                        .ok_or(LodModelError::Uncovered { voxel: v })?;
                    out[(x + d[0] * (y + d[1] * z)) as usize] =
                        self.sample_field(key, v, spread)?;
                }
            }
        }
        Ok(out)
    }

    /// The finest voxels under `key`: per axis, `lo..hi` (empty for a node
    /// outside the volume).
    pub fn region(&self, key: NodeKey) -> Result<([u32; 3], [u32; 3]), LodModelError> {
        let d = self.source.layout().volume.dims;
        let f = self.factor(key)?;
        let b = self.brick;
        let kp = [key.x, key.y, key.z];
        let lo: [u32; 3] =
            std::array::from_fn(|i| ((kp[i] as f64 * f[i] * b).ceil() as u32).min(d[i]));
        let hi: [u32; 3] = std::array::from_fn(|i| {
            (((kp[i] as f64 + 1.0) * f[i] * b).ceil() as u32)
                .min(d[i])
                .max(lo[i])
        });
        Ok((lo, hi))
    }

    /// Overwrites the finest voxels under `key` in `out` (a finest-grid
    /// volume, x fastest) with `key`'s own brick's samples: the cut with
    /// that one node drawn instead of its descendants. Every other voxel is
    /// left as it is.
    pub fn splice(&mut self, key: NodeKey, out: &mut [f32]) -> Result<(), LodModelError> {
        self.splice_field(key, out, false)
    }

    /// Overwrites the finest voxels under `key` in `out` with `key`'s
    /// spreads ([`sample_spread`](Self::sample_spread)), as
    /// [`splice`](Self::splice) does its values.
    pub fn splice_spread(&mut self, key: NodeKey, out: &mut [f32]) -> Result<(), LodModelError> {
        self.splice_field(key, out, true)
    }

    fn splice_field(
        &mut self,
        key: NodeKey,
        out: &mut [f32],
        spread: bool,
    ) -> Result<(), LodModelError> {
        let d = self.source.layout().volume.dims;
        let expected: usize = d.iter().map(|&n| n as usize).product();
        if out.len() != expected {
            return Err(LodModelError::SampleCount {
                dims: d,
                expected,
                actual: out.len(),
            });
        }
        let (lo, hi) = self.region(key)?;
        for z in lo[2]..hi[2] {
            for y in lo[1]..hi[1] {
                for x in lo[0]..hi[0] {
                    let v = [x, y, z];
                    debug_assert_eq!(self.node_at(key.level, v), key);
                    out[(x + d[0] * (y + d[1] * z)) as usize] =
                        self.sample_field(key, v, spread)?;
                }
            }
        }
        Ok(())
    }
}

/// Trilinear interpolation in a stored brick `br` (`side`^3 values, x
/// fastest) of node `key` at the centre of the finest voxel `v`, `f` finest
/// voxels per node voxel per axis; coordinates outside the brick clamped.
fn trilinear(br: &[f32], key: NodeKey, v: [u32; 3], f: [f64; 3], side: i64, b: f64, a: f64) -> f32 {
    let kp = [key.x, key.y, key.z];
    // Brick-local coordinate of this voxel's centre.
    let c: [f64; 3] = std::array::from_fn(|i| {
        ((v[i] as f64 + 0.5) / f[i] - 0.5 - kp[i] as f64 * b + a).clamp(0.0, (side - 1) as f64)
    });
    let i0 = c.map(|t| (t.floor() as i64).min(side - 2).max(0));
    let w: [f64; 3] = std::array::from_fn(|i| c[i] - i0[i] as f64);
    let at = |i: i64, j: i64, k: i64| {
        br.get((i + side * (j + side * k)) as usize)
            .copied()
            .unwrap_or(0.0) as f64
    };
    let mut s = 0.0;
    for dz in 0..2 {
        for dy in 0..2 {
            for dx in 0..2 {
                let wt = (if dx == 1 { w[0] } else { 1.0 - w[0] })
                    * (if dy == 1 { w[1] } else { 1.0 - w[1] })
                    * (if dz == 1 { w[2] } else { 1.0 - w[2] });
                s += wt * at(i0[0] + dx, i0[1] + dy, i0[2] + dz);
            }
        }
    }
    s as f32
}

/// A finest-grid resampling (x fastest) stored as the source's type, with
/// the source's description (integers rounded to the nearest value and
/// clamped to the type's range).
pub fn typed(layout: &OctreeLayout, out: Vec<f32>) -> Result<Volume, LodModelError> {
    let d = layout.volume.dims;
    let expected: usize = d.iter().map(|&n| n as usize).product();
    if out.len() != expected {
        return Err(LodModelError::SampleCount {
            dims: d,
            expected,
            actual: out.len(),
        });
    }
    let data = match layout.volume.dtype {
        DType::U8 => VolumeData::U8(
            out.iter()
                .map(|v| v.round().clamp(0.0, 255.0) as u8)
                .collect(),
        ),
        DType::U16 => VolumeData::U16(
            out.iter()
                .map(|v| v.round().clamp(0.0, 65535.0) as u16)
                .collect(),
        ),
        DType::I16 => VolumeData::I16(
            out.iter()
                .map(|v| v.round().clamp(-32768.0, 32767.0) as i16)
                .collect(),
        ),
        DType::F32 => VolumeData::F32(out),
        dtype => return Err(LodModelError::UnsupportedDType { dtype }),
    };
    Ok(Volume::new(layout.volume.clone(), data)?)
}
