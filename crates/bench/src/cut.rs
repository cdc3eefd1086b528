//! A cut of a brick store as the out-of-core kernel draws it, on the CPU:
//! refined once from the root with every brick available (only the given
//! tolerance, brick budget and metric limit it), its leaves resampled onto the
//! finest grid (trilinear inside each leaf's stored brick, apron included),
//! for the f64 reference to render. The `aniso` and `lod` suites compare such
//! cuts; `tests/gpu_aniso.rs` checks that the GPU draws what they resample.

use brickray_cache::refine::{
    DataState, MetaState, RefineEnv, RefineParams, Refinement, ViewGeometry, Views, refine,
};
use brickray_cache::{NodeClass, UploadBudget};
use brickray_core::{
    BrickSource, Camera, DType, NodeKey, NodeKind, OctreeLayout, RenderMode, Volume, VolumeData,
    VolumeFrame,
};
use brickray_store::Store;
use std::collections::{HashMap, HashSet};

/// Every brick available; metadata from the store; the visible weights, when
/// given.
pub(crate) struct AllAvailable<'a>(&'a Store, Option<&'a HashMap<NodeKey, f64>>);

impl RefineEnv for AllAvailable<'_> {
    fn node(&mut self, key: NodeKey) -> MetaState {
        match self.0.info(key) {
            Ok(i) => MetaState::Known(i),
            Err(_) => MetaState::Failed,
        }
    }
    fn data(&mut self, _key: NodeKey) -> DataState {
        DataState::OnGpu
    }
    fn visible_weight(&mut self, key: NodeKey) -> Option<f64> {
        self.1.map(|w| w.get(&key).copied().unwrap_or(0.0))
    }
}

/// What a cut is refined for: the store, the classification and the view.
pub(crate) struct CutView<'a> {
    pub(crate) store: &'a Store,
    pub(crate) tf: &'a brickray_core::TransferFunction,
    pub(crate) mode: RenderMode,
    pub(crate) camera: &'a Camera,
    pub(crate) frame: &'a VolumeFrame,
    pub(crate) size: u32,
    /// What the image shows of each node (`crate::visible`), for refinement
    /// ranked by it; `None`: not measured.
    pub(crate) visible: Option<&'a HashMap<NodeKey, f64>>,
}

/// The refinement of `view` with every brick available, limited only by the
/// tolerance, the budget of data leaves and the metric.
pub(crate) fn refine_cut(
    view: &CutView<'_>,
    tolerance_px: f32,
    max_data_leaves: u32,
    metric: brickray_core::LodMetric,
) -> Refinement {
    let layout = view.store.layout();
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
        brick_upload_bytes: layout.brick_bytes() as u64,
        lookahead: false,
    };
    let mut budget = UploadBudget::new(u64::MAX / 4);
    refine(
        layout,
        &params,
        &mut AllAvailable(view.store, view.visible),
        &mut budget,
    )
}

/// The finest-grid volume the cut's leaves sample to, and its data-leaf count.
pub(crate) fn cut_volume(
    view: &CutView<'_>,
    tolerance_px: f32,
    max_data_leaves: u32,
    metric: brickray_core::LodMetric,
) -> Result<(Volume, u32, Vec<u32>), String> {
    let r = refine_cut(view, tolerance_px, max_data_leaves, metric);
    let layout = view.store.layout();
    let mut per_level = vec![0u32; layout.levels as usize];
    for l in &r.leaves {
        if l.class == NodeClass::Data {
            per_level[l.key.level as usize] += 1;
        }
    }
    let leaves: HashSet<NodeKey> = r.leaves.iter().map(|l| l.key).collect();
    let samples = Resampler::new(view.store).resample(&leaves)?;
    Ok((typed(layout, samples)?, r.data_leaves, per_level))
}

/// Samples leaves' stored bricks onto the finest grid, as the out-of-core
/// kernel samples them (trilinear inside each leaf's brick, apron included).
pub(crate) struct Resampler<'a> {
    store: &'a Store,
    /// Finest voxels per node voxel, per level and axis.
    factors: Vec<[f64; 3]>,
    /// Each brick read so far, decoded.
    bricks: HashMap<NodeKey, Vec<f32>>,
    buf: Vec<u8>,
    /// Stored voxels per brick side; interior voxels and apron per side.
    side: i64,
    brick: f64,
    apron: f64,
}

impl<'a> Resampler<'a> {
    pub(crate) fn new(store: &'a Store) -> Resampler<'a> {
        let layout = store.layout();
        Resampler {
            store,
            factors: (0..layout.levels).map(|l| layout.voxel_factor(l)).collect(),
            bricks: HashMap::new(),
            buf: vec![0u8; layout.brick_bytes()],
            side: layout.stored_side() as i64,
            brick: layout.brick as f64,
            apron: layout.apron as f64,
        }
    }

    /// The finest voxel `v` as the leaf `key` draws it.
    pub(crate) fn sample(&mut self, key: NodeKey, v: [u32; 3]) -> Result<f32, String> {
        let dtype = self.store.layout().volume.dtype;
        let (side, b, a) = (self.side, self.brick, self.apron);
        let br = match self.bricks.entry(key) {
            std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
            std::collections::hash_map::Entry::Vacant(e) => {
                let info = self.store.info(key).map_err(|e| e.to_string())?;
                let n = self.buf.len() / dtype.size();
                e.insert(match info.kind {
                    // No payload: every stored voxel holds the value (an
                    // empty node: its smallest, below the build threshold;
                    // the renderer draws nothing there).
                    NodeKind::Uniform(u) => vec![u; n],
                    NodeKind::Empty => vec![info.min; n],
                    NodeKind::Data => {
                        self.store
                            .read_brick(key, &mut self.buf)
                            .map_err(|e| e.to_string())?;
                        dtype.decode_le(&self.buf)
                    }
                })
            }
        };
        let f = self.factors[key.level as usize];
        let kp = [key.x, key.y, key.z];
        // Brick-local coordinate of this voxel's centre.
        let c: [f64; 3] = std::array::from_fn(|i| {
            ((v[i] as f64 + 0.5) / f[i] - 0.5 - kp[i] as f64 * b + a).clamp(0.0, (side - 1) as f64)
        });
        let i0 = c.map(|t| (t.floor() as i64).min(side - 2).max(0));
        let w: [f64; 3] = std::array::from_fn(|i| c[i] - i0[i] as f64);
        let at = |i: i64, j: i64, k: i64| br[(i + side * (j + side * k)) as usize] as f64;
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
        Ok(s as f32)
    }

    /// The node of level `l` holding the finest voxel `v`.
    fn node_at(&self, l: u8, v: [u32; 3]) -> NodeKey {
        let f = self.factors[l as usize];
        let b = self.brick;
        let p: [u32; 3] = std::array::from_fn(|i| (v[i] as f64 / (f[i] * b)).floor() as u32);
        NodeKey::new(l, p[0], p[1], p[2])
    }

    /// Every finest voxel, from the leaf of `leaves` that holds it.
    pub(crate) fn resample(&mut self, leaves: &HashSet<NodeKey>) -> Result<Vec<f32>, String> {
        self.resample_from(leaves, false)
    }

    /// Every finest voxel, from the deepest node of `nodes` that holds it
    /// (`crate::octant`'s cuts: a node draws the regions of its children
    /// that are not in the set).
    pub(crate) fn resample_deepest(
        &mut self,
        nodes: &HashSet<NodeKey>,
    ) -> Result<Vec<f32>, String> {
        self.resample_from(nodes, true)
    }

    fn resample_from(&mut self, set: &HashSet<NodeKey>, deepest: bool) -> Result<Vec<f32>, String> {
        let d = self.store.layout().volume.dims;
        let levels = self.store.layout().levels;
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
                        .ok_or_else(|| format!("voxel {v:?} in no leaf"))?;
                    out[(x + d[0] * (y + d[1] * z)) as usize] = self.sample(key, v)?;
                }
            }
        }
        Ok(out)
    }

    /// The finest voxels under `key`: per axis, `lo..hi`.
    pub(crate) fn region(&self, key: NodeKey) -> ([u32; 3], [u32; 3]) {
        let d = self.store.layout().volume.dims;
        let f = self.factors[key.level as usize];
        let b = self.brick;
        let kp = [key.x, key.y, key.z];
        (
            std::array::from_fn(|i| ((kp[i] as f64 * f[i] * b).ceil() as u32).min(d[i])),
            std::array::from_fn(|i| (((kp[i] + 1) as f64 * f[i] * b).ceil() as u32).min(d[i])),
        )
    }

    /// Overwrites the finest voxels under `key` in `out` (a finest-grid
    /// volume) with `key`'s own brick: the cut with that one node drawn
    /// instead of its descendants.
    pub(crate) fn splice(&mut self, key: NodeKey, out: &mut [f32]) -> Result<(), String> {
        let d = self.store.layout().volume.dims;
        let (lo, hi) = self.region(key);
        for z in lo[2]..hi[2] {
            for y in lo[1]..hi[1] {
                for x in lo[0]..hi[0] {
                    let v = [x, y, z];
                    debug_assert_eq!(self.node_at(key.level, v), key);
                    out[(x + d[0] * (y + d[1] * z)) as usize] = self.sample(key, v)?;
                }
            }
        }
        Ok(())
    }
}

/// A finest-grid resampling stored as the source's type (integers rounded to
/// the nearest value).
pub(crate) fn typed(layout: &OctreeLayout, out: Vec<f32>) -> Result<Volume, String> {
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
        other => return Err(format!("cut_volume: no resampling for {other:?}")),
    };
    Volume::new(layout.volume.clone(), data).map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
    use brickray_core::{LodMetric, TransferFunction, synthetic};

    /// Splicing a node into the finest cut's samples gives what resampling
    /// the cut with that node as a leaf gives, voxel for voxel, in isotropic
    /// and anisotropic pyramids (the oracle's costs rest on it).
    #[test]
    fn splice_is_resampling_with_the_node_as_leaf() {
        for anisotropic in [false, true] {
            let ml = synthetic::marschner_lobb(24);
            let mut desc = ml.desc().clone();
            if anisotropic {
                desc.spacing = [1.0, 1.0, 3.0];
            }
            let vol = Volume::new(desc, ml.data().clone()).unwrap();
            let dir = tempfile::tempdir().unwrap();
            let path = dir.path().join("v.brs");
            let mut reader = brickray_io::MemoryReader::new(vol.clone(), "memory");
            let build = brickray_store::BuildOptions {
                anisotropic,
                brick: 4,
                ..Default::default()
            };
            brickray_store::build(&mut reader, &path, &build).unwrap();
            let store = brickray_store::open(&path).unwrap();
            let layout = store.layout().clone();
            assert!(layout.levels >= 3, "{layout:?}");
            let d = vol.desc();
            let frame = VolumeFrame::centered(d.dims, d.spacing);
            let camera = Camera::orbit(frame.center(), 2.0, 0.5, 0.3);
            let tf = TransferFunction::ramp(0.0, 1.0, 1.0);
            let view = CutView {
                store: &store,
                tf: &tf,
                mode: RenderMode::Dvr,
                camera: &camera,
                frame: &frame,
                size: 64,
                visible: None,
            };
            let finest = refine_cut(&view, 0.0, u32::MAX / 2, LodMetric::Geometric);
            let leaves: HashSet<NodeKey> = finest.leaves.iter().map(|l| l.key).collect();
            let mut r = Resampler::new(&store);
            let samples = r.resample(&leaves).unwrap();
            // Every node of level 1: its descendants out, itself in.
            let (mut checked, mut coarser) = (0, 0);
            for node in leaves
                .iter()
                .filter(|k| k.level >= 2)
                .map(|k| {
                    let mut p = *k;
                    while p.level > 1 {
                        p = layout.parent(p).unwrap();
                    }
                    p
                })
                .collect::<HashSet<_>>()
            {
                let mut cut: HashSet<NodeKey> = leaves
                    .iter()
                    .copied()
                    .filter(|k| {
                        let mut p = *k;
                        while p.level > node.level {
                            p = layout.parent(p).unwrap();
                        }
                        p != node
                    })
                    .collect();
                cut.insert(node);
                let want = Resampler::new(&store).resample(&cut).unwrap();
                let mut got = samples.clone();
                r.splice(node, &mut got).unwrap();
                assert_eq!(got, want, "{node:?}, anisotropic {anisotropic}");
                checked += 1;
                coarser += usize::from(got != samples);
            }
            assert!(
                checked >= 2 && coarser >= 2,
                "{checked} nodes, {coarser} coarser"
            );
        }
    }
}
