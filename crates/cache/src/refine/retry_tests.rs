//! Splits refused for want of budget or pool space are retried when the
//! budget or a brick comes back within the same frame.

use super::tests::*;
use super::*;
use brickray_core::{Camera, NodeKind, VolumeFrame};
use glam::Vec3;
use std::collections::HashSet;

/// Bricks of `in_cpu` in CPU memory, every other brick on the GPU.
struct SomeInCpu {
    layout: OctreeLayout,
    in_cpu: HashSet<NodeKey>,
}

impl RefineEnv for SomeInCpu {
    fn node(&mut self, key: NodeKey) -> MetaState {
        MetaState::Known(ball_info(&self.layout, key).into())
    }
    fn data(&mut self, key: NodeKey) -> DataState {
        if self.in_cpu.contains(&key) {
            DataState::InCpu
        } else {
            DataState::OnGpu
        }
    }
}

/// A split refused while the budget is held by speculative charges (children
/// charged at their parent's split that then split into bricks already on the
/// GPU, giving the charge back) is retried once the charges are returned.
/// Before, the frame ended with nothing uploaded and the split still refused,
/// and every later frame repeated it: the view stopped refining for good while
/// reporting itself converged (found on the 4096^3 shells at 512 x 512 after a
/// half turn, stuck at 1244 bricks where the pool allowed 2430).
#[test]
fn splits_refused_on_returned_charges_are_retried() {
    let s = setup();
    let cam = Camera::orbit(Vec3::ZERO, 1.5, 0.3, 0.2);
    let geo = ViewGeometry::new(&s.layout, &cam, 1.0, 512, &s.frame);
    // The level-1 node refinement pops first (the largest on screen) is on the
    // GPU with its children in CPU memory; the other level-1 nodes are in CPU
    // memory, their children on the GPU.
    let level1 = s.layout.children(NodeKey::ROOT);
    let first = *level1
        .iter()
        .max_by(|a, b| geo.voxel_pixels(**a).total_cmp(&geo.voxel_pixels(**b)))
        .unwrap();
    let mut in_cpu: HashSet<NodeKey> = level1.iter().copied().filter(|k| *k != first).collect();
    in_cpu.extend(s.layout.children(first).iter().copied());
    let brick = s.layout.brick_bytes() as u64;
    let views = Views::one(ViewGeometry::new(&s.layout, &cam, 1.0, 512, &s.frame));
    let params = mip_params(&s, &views);
    // Room for the 7 charged level-1 bricks or for the first node's children,
    // not both at once.
    let mut b = UploadBudget::new(8 * brick);
    let mut env = SomeInCpu {
        layout: s.layout.clone(),
        in_cpu,
    };
    let r = refine(&s.layout, &params, &mut env, &mut b);
    assert_exact_cover(&keys(&r), s.layout.levels);
    assert!(
        r.leaves.iter().all(|l| l.key != first),
        "the first node was not split"
    );
    assert_eq!(r.blocked.upload_budget, 0);
    assert!(r.leaves.iter().filter(|l| l.needs_upload).count() as u64 <= 8);
}

/// Two level-1 nodes hold data: `full`, whose 8 children all hold data, and
/// `hollow`, whose children are all empty (its own range reaches into its
/// neighbours' through the apron); the rest of the volume is empty.
struct FullAndHollow {
    full: NodeKey,
    hollow: NodeKey,
}

impl RefineEnv for FullAndHollow {
    fn node(&mut self, key: NodeKey) -> MetaState {
        let data = NodeInfo {
            kind: NodeKind::Data,
            min: 0.0,
            max: 1.0,
            error: None,
            parent_error: None,
            channels: Default::default(),
            channel_errors: None,
        };
        let empty = NodeInfo {
            kind: NodeKind::Empty,
            min: 0.0,
            max: 0.0,
            error: None,
            parent_error: None,
            channels: Default::default(),
            channel_errors: None,
        };
        let under = |a: NodeKey| key == a || key.parent() == Some(a);
        MetaState::Known(
            if key.level == 0 || under(self.full) || key == self.hollow {
                data
            } else {
                empty
            }
            .into(),
        )
    }
    fn data(&mut self, _key: NodeKey) -> DataState {
        DataState::OnGpu
    }
}

/// A split the pool refused is retried once a later split gives a brick back
/// (a node whose children are all empty leaves the cut): with a pool of 8
/// bricks, the cut ends with `full`'s 8 children whichever of the two nodes
/// the view ranks first. Before, a refused split stayed refused for the frame,
/// so when `full` came first the cut kept it whole and ended with 1 brick of
/// the 8 it could hold.
#[test]
fn splits_the_pool_refused_are_retried_when_bricks_come_back() {
    let layout = ball_layout(32);
    let frame = VolumeFrame::centered([32; 3], [1.0; 3]);
    let tf = TransferFunction::ramp(0.0, 1.0, 1.0);
    let cam = Camera::orbit(Vec3::ZERO, 1.5, 0.3, 0.2);
    let (a, b) = (NodeKey::new(1, 0, 0, 0), NodeKey::new(1, 1, 1, 1));
    for (full, hollow) in [(a, b), (b, a)] {
        let params = RefineParams {
            views: &Views::one(ViewGeometry::new(&layout, &cam, 1.0, 512, &frame)),
            generation: 0,
            mode: RenderMode::Dvr,
            tf: &tf,
            channels: &[],
            tolerance_px: 0.0,
            metric: brickray_core::LodMetric::Geometric,
            max_data_leaves: 8,
            max_requests: u32::MAX,
            max_prefetch: u32::MAX,
            brick_upload_bytes: layout.brick_bytes() as u64,
            lookahead: false,
        };
        let mut env = FullAndHollow { full, hollow };
        let r = refine(&layout, &params, &mut env, &mut UploadBudget::new(u64::MAX));
        assert_exact_cover(&keys(&r), layout.levels);
        assert_eq!(r.data_leaves, 8, "full {full:?}");
        assert!(
            r.leaves
                .iter()
                .filter(|l| l.class == NodeClass::Data)
                .all(|l| l.key.parent() == Some(full)),
            "full {full:?}"
        );
        assert_eq!(r.blocked.pool_full, 0);
    }
}
