//! Octant-granular cuts: a node's children are refined one at a time, those
//! not refined yet drawn from their parent's brick, which stays in the
//! working set while any of them is. A split then costs one brick a child,
//! not all the children's bricks at once less the parent's, so the bricks go
//! to the octants that show error rather than to whole nodes.
//!
//! The cut is the set of nodes with their own brick refined (the root
//! first); each finest voxel is drawn from the deepest of them holding it
//! ([`Resampler::resample_deepest`]). A node's brick is in the working set
//! while it draws some region: a child that needs data (not empty, visible
//! under the mode and transfer function) is not refined, or the node is at
//! the finest level, or uniform. Candidates (the unrefined children of
//! refined nodes) are ranked by their visible weight times the error of
//! drawing them from their parent's brick, from the source's records
//! ([`OctantError::Store`]: each octant's parent-error record since store
//! format 3; before, the parent's own record, the same for its eight
//! octants) or measured on the data for each octant ([`OctantError::Data`]).
//!
//! The GPU renderer draws such cuts (`LodMetric::VisibleOctants`); this
//! models them for the f64 reference.

use super::{LodModelError, Resampler};
use brickray_cache::refine::is_visible;
use brickray_core::{
    BrickSource, NodeInfo, NodeKey, NodeKind, OctreeLayout, RenderMode, TfErrorTable,
    TransferFunction, Volume, node_visible_error,
};
use std::collections::{BinaryHeap, HashMap, HashSet};

#[derive(PartialEq)]
struct Item(f64, NodeKey);
impl Eq for Item {}
impl PartialOrd for Item {
    fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Item {
    fn cmp(&self, o: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&o.0).then(o.1.cmp(&self.1))
    }
}

/// Where a candidate octant's error comes from.
#[derive(Debug, Clone, Copy)]
pub enum OctantError<'a> {
    /// The per-sample expected error (`brickray_core::node_visible_error`)
    /// of the octant's parent-error record (store format 3), over the
    /// parent's range; on a source without those records, the parent's own
    /// record, the same for every octant.
    Store,
    /// Measured on the data: [`data_error`] of the parent over the octant
    /// against the finest volume (of the source's dimensions).
    Data(&'a Volume),
}

/// An octant-granular cut ([`octant_cut`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OctantCut {
    /// The nodes with their own brick refined (every empty or invisible
    /// child of a refined node included); each finest voxel is drawn from
    /// the deepest of them holding it.
    pub nodes: HashSet<NodeKey>,
    /// The bricks the cut's working set holds.
    pub bricks: u32,
}

/// The octant-granular cut of at most `budget` bricks, candidates ranked by
/// their weight in `weights` (0 without one) times their `error`; what shows
/// no error (weight or error 0) is not refined.
pub fn octant_cut(
    source: &dyn BrickSource,
    mode: RenderMode,
    tf: &TransferFunction,
    weights: &HashMap<NodeKey, f64>,
    budget: u32,
    error: OctantError<'_>,
) -> Result<OctantCut, LodModelError> {
    let layout: &OctreeLayout = source.layout();
    if let OctantError::Data(finest) = error {
        check_dims(layout, finest)?;
    }
    let table = TfErrorTable::new(tf);
    let info = |k: NodeKey| source.node(k).map_err(LodModelError::from);
    let needs_data = |k: NodeKey| -> Result<bool, LodModelError> {
        let i = info(k)?;
        Ok(i.kind != NodeKind::Empty && is_visible(&i, mode, tf, &[], layout))
    };
    // Per refined node: its children that need data and are not refined yet.
    let mut open: HashMap<NodeKey, u32> = HashMap::new();
    let mut refined: HashSet<NodeKey> = HashSet::new();
    let mut heap = BinaryHeap::new();
    let mut bricks = 0u32;
    let res = std::cell::RefCell::new(Resampler::new(source)?);
    // Refines `k` (its brick joins the working set): its children become
    // candidates, ranked by what they show times the error of drawing them
    // from `k`'s brick.
    let add = |k: NodeKey,
               refined: &mut HashSet<NodeKey>,
               open: &mut HashMap<NodeKey, u32>,
               heap: &mut BinaryHeap<Item>,
               bricks: &mut u32|
     -> Result<(), LodModelError> {
        refined.insert(k);
        *bricks += 1;
        let i = info(k)?;
        let mut n = 0;
        if !matches!(i.kind, NodeKind::Uniform(_)) {
            let e = node_visible_error(&i, mode, &table, layout).unwrap_or(1.0);
            for &c in layout.children(k).iter() {
                if !layout.in_volume(c) {
                    continue;
                }
                if needs_data(c)? {
                    n += 1;
                    let w = weights.get(&c).copied().unwrap_or(0.0);
                    let e = match error {
                        // The child's parent-error record (store format 3),
                        // over the parent's range; the parent's own without.
                        OctantError::Store => match info(c)?.parent_error {
                            Some(pe) => {
                                let from = NodeInfo {
                                    error: Some(pe),
                                    ..i.clone()
                                };
                                node_visible_error(&from, mode, &table, layout).unwrap_or(1.0)
                            }
                            None => e,
                        },
                        OctantError::Data(finest) => {
                            data_error(&mut res.borrow_mut(), k, c, mode, &table, finest)?
                        }
                    };
                    heap.push(Item(w * e, c));
                } else {
                    refined.insert(c);
                }
            }
        }
        if n > 0 || layout.children(k).is_empty() || matches!(i.kind, NodeKind::Uniform(_)) {
            open.insert(k, n);
        } else {
            // Every child empty: the node draws nothing itself.
            *bricks -= 1;
        }
        Ok(())
    };
    add(
        NodeKey::ROOT,
        &mut refined,
        &mut open,
        &mut heap,
        &mut bricks,
    )?;
    while let Some(Item(p, c)) = heap.pop() {
        // What the image does not show, or shows without error, is not
        // refined (the per-node orders leave such nodes too).
        if p <= 0.0 {
            break;
        }
        // (A candidate is a child of a refined node, never the root.)
        let Some(parent) = layout.parent(c) else {
            continue;
        };
        // Refining the last open child of the parent frees its brick.
        let frees = open.get(&parent) == Some(&1);
        let cost_after = bricks + 1 - u32::from(frees);
        if cost_after > budget {
            continue;
        }
        add(c, &mut refined, &mut open, &mut heap, &mut bricks)?;
        if let Some(n) = open.get_mut(&parent) {
            *n -= 1;
            if *n == 0 {
                open.remove(&parent);
                bricks -= 1;
            }
        }
    }
    Ok(OctantCut {
        nodes: refined,
        bricks,
    })
}

fn check_dims(layout: &OctreeLayout, finest: &Volume) -> Result<(), LodModelError> {
    let (expected, actual) = (layout.volume.dims, finest.desc().dims);
    if expected != actual {
        return Err(LodModelError::DimsMismatch { expected, actual });
    }
    Ok(())
}

/// The error of drawing `c`'s region from `p`'s brick, measured on the
/// data (`finest`: the source's finest level as a volume): the mean, over
/// the finest voxels of the region (at most 16 per axis, evenly strided), of
/// the classified change between `p`'s sample and the finest value (DVR),
/// their difference over the value range (MIP and other modes), or whether
/// the isovalue lies between them (iso-surfaces). `p == c` gives a node's
/// own error; a region without voxels, 0.
pub fn data_error(
    r: &mut Resampler<'_>,
    p: NodeKey,
    c: NodeKey,
    mode: RenderMode,
    table: &TfErrorTable,
    finest: &Volume,
) -> Result<f64, LodModelError> {
    check_dims(r.layout(), finest)?;
    let desc = finest.desc();
    let (lo, hi) = r.region(c)?;
    let stride: [u32; 3] = std::array::from_fn(|i| ((hi[i] - lo[i]) / 16).max(1));
    let [vlo, vhi] = desc.value_range;
    let range = (vhi as f64 - vlo as f64).abs().max(f64::MIN_POSITIVE);
    let (mut sum, mut n) = (0.0, 0u32);
    for z in (lo[2]..hi[2]).step_by(stride[2] as usize) {
        for y in (lo[1]..hi[1]).step_by(stride[1] as usize) {
            for x in (lo[0]..hi[0]).step_by(stride[0] as usize) {
                let a = r.sample(p, [x, y, z])?;
                let b = finest.voxel_clamped(x as i64, y as i64, z as i64);
                let (na, nb) = (desc.normalize(a) as f64, desc.normalize(b) as f64);
                let (lo, hi) = (na.min(nb), na.max(nb));
                sum += match mode {
                    RenderMode::Dvr => table.classified_change(lo, hi),
                    RenderMode::Iso { value, .. } => {
                        f64::from(u8::from((lo..=hi).contains(&(value as f64))))
                    }
                    _ => (a as f64 - b as f64).abs() / range,
                };
                n += 1;
            }
        }
    }
    Ok(if n == 0 { 0.0 } else { sum / n as f64 })
}
