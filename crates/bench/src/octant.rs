//! Octant-granular cuts (`lod --by oracle --octants on`, GPU-free): a
//! node's children are refined one at a time, those not refined yet drawn
//! from their parent's brick, which stays in the working set while any of
//! them is. A split then costs one brick a child, not all the children's
//! bricks at once less the parent's, so the bricks go to the octants that
//! show error rather than to whole nodes.
//!
//! The cut is the set of nodes with their own brick refined (the root
//! first); each finest voxel is drawn from the deepest of them holding it. A
//! node's brick is in the working set while it draws some region: a child
//! that needs data (not empty, visible under the mode and transfer function)
//! is not refined, or the node is at the finest level, or uniform. Candidates
//! (the unrefined children of refined nodes) are ranked by their visible
//! weight times the error of drawing them from their parent's brick, from
//! the store's records ([`OctantError::Store`]: each octant's parent-error
//! record since store format 3; before, the parent's own record, the same
//! for its eight octants) or measured on the data for each octant
//! ([`OctantError::Data`]).
//!
//! The GPU renderer draws such cuts (`LodMetric::VisibleOctants`); this
//! measures them on the f64 reference, with the oracle's weights, at the
//! equal brick budgets of the other orders.

use crate::cut::Resampler;
use brickray_cache::refine::is_visible;
use brickray_core::{
    NodeKey, NodeKind, OctreeLayout, RenderMode, TfErrorTable, TransferFunction, Volume,
    node_visible_error,
};
use brickray_store::Store;
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
#[derive(Clone, Copy)]
pub(crate) enum OctantError<'a> {
    /// The per-sample expected error (`brickray_core::node_visible_error`)
    /// of the octant's parent-error record (store format 3), over the
    /// parent's range; on a store without those records, the parent's own
    /// record, the same for every octant.
    Store,
    /// Measured on the data: [`data_error`] of the parent over the octant
    /// against the finest volume.
    Data(&'a Volume),
}

/// The octant-granular cut of at most `budget` bricks: the set of nodes
/// with their own brick refined (every empty or invisible child of a refined
/// node included, free), and the bricks its working set holds.
pub(crate) fn octant_cut(
    store: &Store,
    mode: RenderMode,
    tf: &TransferFunction,
    weights: &HashMap<NodeKey, f64>,
    budget: u32,
    error: OctantError<'_>,
) -> Result<(HashSet<NodeKey>, u32), String> {
    let layout: &OctreeLayout = store.layout();
    let table = TfErrorTable::new(tf);
    let info = |k: NodeKey| store.info(k).map_err(|e| e.to_string());
    let needs_data = |k: NodeKey| -> Result<bool, String> {
        let i = info(k)?;
        Ok(i.kind != NodeKind::Empty && is_visible(&i, mode, tf, &[], layout))
    };
    // Per refined node: its children that need data and are not refined yet.
    let mut open: HashMap<NodeKey, u32> = HashMap::new();
    let mut refined: HashSet<NodeKey> = HashSet::new();
    let mut heap = BinaryHeap::new();
    let mut bricks = 0u32;
    let res = std::cell::RefCell::new(Resampler::new(store));
    // Refines `k` (its brick joins the working set): its children become
    // candidates, ranked by what they show times the error of drawing them
    // from `k`'s brick.
    let add = |k: NodeKey,
               refined: &mut HashSet<NodeKey>,
               open: &mut HashMap<NodeKey, u32>,
               heap: &mut BinaryHeap<Item>,
               bricks: &mut u32|
     -> Result<(), String> {
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
                                let from = brickray_core::NodeInfo {
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
        let parent = layout.parent(c).expect("a candidate has a parent");
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
    Ok((refined, bricks))
}

/// The error of drawing `c`'s region from `p`'s brick, measured on the
/// data: the mean, over the finest voxels of the region (at most 16 per
/// axis, evenly strided), of the classified change between `p`'s sample and
/// the finest value (DVR), their difference over the value range (MIP), or
/// whether the isovalue lies between them (iso-surfaces). `p == c` gives a
/// node's own error.
pub(crate) fn data_error(
    r: &mut Resampler<'_>,
    p: NodeKey,
    c: NodeKey,
    mode: RenderMode,
    table: &TfErrorTable,
    finest: &Volume,
) -> Result<f64, String> {
    let desc = finest.desc();
    let (lo, hi) = r.region(c);
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

#[cfg(test)]
mod tests {
    use super::*;
    use brickray_core::synthetic;

    fn store(dir: &std::path::Path) -> (Store, Volume) {
        let vol = synthetic::marschner_lobb(40);
        let path = dir.join("v.brs");
        let mut reader = brickray_io::MemoryReader::new(vol.clone(), "memory");
        let build = brickray_store::BuildOptions {
            brick: 4,
            ..Default::default()
        };
        brickray_store::build(&mut reader, &path, &build).unwrap();
        (brickray_store::open(&path).unwrap(), vol)
    }

    /// The bricks an octant cut's working set holds, counted from the set
    /// alone: its nodes needing data that draw some region themselves.
    fn working_set(store: &Store, set: &HashSet<NodeKey>, tf: &TransferFunction) -> u32 {
        let layout = store.layout();
        let needs = |k: NodeKey| {
            let i = store.info(k).unwrap();
            i.kind != NodeKind::Empty && is_visible(&i, RenderMode::Dvr, tf, &[], layout)
        };
        set.iter()
            .filter(|&&k| {
                let uniform = matches!(store.info(k).unwrap().kind, NodeKind::Uniform(_));
                let children = layout.children(k);
                needs(k)
                    && (uniform
                        || children.is_empty()
                        || children
                            .iter()
                            .any(|&c| layout.in_volume(c) && needs(c) && !set.contains(&c)))
            })
            .count() as u32
    }

    /// Every budget is kept, the count is the working set's, and a larger
    /// budget refines at least as much; with every node's weight known the
    /// cut reaches the finest level.
    #[test]
    fn octant_cuts_keep_their_budget() {
        let dir = tempfile::tempdir().unwrap();
        let (store, vol) = store(dir.path());
        let layout = store.layout().clone();
        assert!(layout.levels >= 3, "{layout:?}");
        let tf = TransferFunction::ramp(0.3, 0.7, 1.0);
        // Weight 1 everywhere (every node shows).
        let mut weights = HashMap::new();
        let mut stack = vec![NodeKey::ROOT];
        while let Some(k) = stack.pop() {
            weights.insert(k, 1.0);
            stack.extend(layout.children(k).iter().filter(|c| layout.in_volume(**c)));
        }
        for error in [OctantError::Store, OctantError::Data(&vol)] {
            let mut last = 0;
            for budget in [1, 5, 20, 60, 200, 100_000] {
                let (set, bricks) =
                    octant_cut(&store, RenderMode::Dvr, &tf, &weights, budget, error).unwrap();
                assert!(bricks <= budget, "{bricks} > {budget}");
                assert_eq!(bricks, working_set(&store, &set, &tf), "budget {budget}");
                assert!(set.len() >= last, "budget {budget}: {} < {last}", set.len());
                last = set.len();
                assert!(set.contains(&NodeKey::ROOT));
                for k in &set {
                    if let Some(p) = layout.parent(*k) {
                        assert!(set.contains(&p), "{k:?} without its parent");
                    }
                }
            }
            let deepest = weights
                .keys()
                .filter(|k| k.level + 1 == layout.levels)
                .count();
            assert!(deepest > 0);
            let (set, _) =
                octant_cut(&store, RenderMode::Dvr, &tf, &weights, 100_000, error).unwrap();
            assert!(set.iter().any(|k| k.level + 1 == layout.levels));
        }
    }

    /// A per-node cut's leaves with all their ancestors, drawn deepest
    /// first, are that cut: what the octant cuts' images rest on.
    #[test]
    fn deepest_of_a_closed_set_is_the_cut() {
        let dir = tempfile::tempdir().unwrap();
        let (store, _) = store(dir.path());
        let layout = store.layout();
        // Level 1 everywhere, one node of it refined to level 2.
        let mut leaves: HashSet<NodeKey> = layout
            .children(NodeKey::ROOT)
            .iter()
            .copied()
            .filter(|c| layout.in_volume(*c))
            .collect();
        let split = *leaves.iter().min().unwrap();
        leaves.remove(&split);
        leaves.extend(
            layout
                .children(split)
                .iter()
                .filter(|c| layout.in_volume(**c)),
        );
        let mut closed = leaves.clone();
        closed.insert(NodeKey::ROOT);
        closed.insert(split);
        let mut r = Resampler::new(&store);
        let want = r.resample(&leaves).unwrap();
        let got = r.resample_deepest(&closed).unwrap();
        assert_eq!(got, want);
        // And the coarsest-first resampling of the closed set is the root.
        let root: HashSet<NodeKey> = [NodeKey::ROOT].into();
        assert_eq!(
            r.resample(&closed).unwrap(),
            r.resample_deepest(&root).unwrap()
        );
        assert_ne!(got, r.resample(&root).unwrap());
    }
}
