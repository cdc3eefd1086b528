//! A cut of a brick store as the out-of-core kernel draws it, on the CPU:
//! refined once from the root with every brick available (only the given
//! tolerance, brick budget and metric limit it), its leaves resampled onto the
//! finest grid (trilinear inside each leaf's stored brick, apron included),
//! for the f64 reference to render. The `aniso` and `lod` suites compare such
//! cuts; `tests/gpu_aniso.rs` checks that the GPU draws what they resample.

use brickray_cache::refine::{DataState, MetaState, RefineEnv, RefineParams, refine};
use brickray_cache::{NodeClass, UploadBudget};
use brickray_core::{
    BrickSource, Camera, DType, NodeKey, NodeKind, RenderMode, Volume, VolumeData, VolumeFrame,
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

/// The finest-grid volume the cut's leaves sample to, and its data-leaf count.
pub(crate) fn cut_volume(
    view: &CutView<'_>,
    tolerance_px: f32,
    max_data_leaves: u32,
    metric: brickray_core::LodMetric,
) -> Result<(Volume, u32, Vec<u32>), String> {
    let store = view.store;
    let layout = store.layout().clone();
    let params = RefineParams {
        camera: view.camera,
        aspect: 1.0,
        viewport_height_px: view.size,
        volume_frame: view.frame,
        mode: view.mode,
        tf: view.tf,
        tolerance_px,
        metric,
        max_data_leaves,
        max_requests: u32::MAX / 2,
        brick_upload_bytes: layout.brick_bytes() as u64,
    };
    let mut budget = UploadBudget::new(u64::MAX / 4);
    let r = refine(
        &layout,
        &params,
        &mut AllAvailable(store, view.visible),
        &mut budget,
    );
    let mut per_level = vec![0u32; layout.levels as usize];
    let leaves: HashSet<NodeKey> = r.leaves.iter().map(|l| l.key).collect();
    for l in &r.leaves {
        if l.class == NodeClass::Data {
            per_level[l.key.level as usize] += 1;
        }
    }
    let d = layout.volume.dims;
    let side = layout.stored_side() as i64;
    let (b, a) = (layout.brick as f64, layout.apron as f64);
    let mut bricks: HashMap<NodeKey, Vec<f32>> = HashMap::new();
    let mut buf = vec![0u8; layout.brick_bytes()];
    let dtype = layout.volume.dtype;
    let mut out = vec![0f32; d.iter().map(|&n| n as usize).product()];
    let factors: Vec<[f64; 3]> = (0..layout.levels).map(|l| layout.voxel_factor(l)).collect();
    for z in 0..d[2] {
        for y in 0..d[1] {
            for x in 0..d[0] {
                let v = [x, y, z];
                // The leaf holding this voxel.
                let mut key = None;
                for l in 0..layout.levels {
                    let f = factors[l as usize];
                    let p: [u32; 3] =
                        std::array::from_fn(|i| (v[i] as f64 / (f[i] * b)).floor() as u32);
                    let k = NodeKey::new(l, p[0], p[1], p[2]);
                    if leaves.contains(&k) {
                        key = Some(k);
                        break;
                    }
                }
                let key = key.ok_or_else(|| format!("voxel {v:?} in no leaf"))?;
                let br = match bricks.entry(key) {
                    std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
                    std::collections::hash_map::Entry::Vacant(e) => {
                        let info = store.info(key).map_err(|e| e.to_string())?;
                        e.insert(match info.kind {
                            // No payload: every stored voxel holds the value
                            // (an empty node: its smallest, below the build
                            // threshold; the renderer draws nothing there).
                            NodeKind::Uniform(u) => vec![u; buf.len() / dtype.size()],
                            NodeKind::Empty => vec![info.min; buf.len() / dtype.size()],
                            NodeKind::Data => {
                                store.read_brick(key, &mut buf).map_err(|e| e.to_string())?;
                                dtype.decode_le(&buf)
                            }
                        })
                    }
                };
                let f = factors[key.level as usize];
                let kp = [key.x, key.y, key.z];
                // Brick-local coordinate of this voxel's centre.
                let c: [f64; 3] = std::array::from_fn(|i| {
                    ((v[i] as f64 + 0.5) / f[i] - 0.5 - kp[i] as f64 * b + a)
                        .clamp(0.0, (side - 1) as f64)
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
                out[(x + d[0] * (y + d[1] * z)) as usize] = s as f32;
            }
        }
    }
    // Stored as the source's type (integers rounded to the nearest value).
    let data = match dtype {
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
    let vol = Volume::new(layout.volume.clone(), data).map_err(|e| e.to_string())?;
    Ok((vol, r.data_leaves, per_level))
}
