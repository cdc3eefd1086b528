//! Tests of the LOD models on small stores built in temporary directories.

use super::*;
use crate::{ReferenceOptions, render_reference};
use brickray_core::{
    BrickError, BrickSource, Camera, LodMetric, NodeInfo, NodeKey, NodeKind, OctreeLayout,
    RenderMode, RenderSettings, TfErrorTable, TransferFunction, Volume, VolumeFrame, synthetic,
};
use brickray_store::Store;
use proptest::prelude::*;
use std::collections::{HashMap, HashSet};

/// A store of `vol` with bricks of side `brick`.
fn build(dir: &std::path::Path, vol: &Volume, brick: u32, anisotropic: bool) -> Store {
    let path = dir.join("v.brs");
    let mut reader = brickray_io::MemoryReader::new(vol.clone(), "memory");
    let build = brickray_store::BuildOptions {
        anisotropic,
        brick,
        ..Default::default()
    };
    brickray_store::build(&mut reader, &path, &build).unwrap();
    brickray_store::open(&path).unwrap()
}

/// The classification and view of the tests: DVR, the whole volume in view.
struct Scene {
    tf: TransferFunction,
    camera: Camera,
    frame: VolumeFrame,
}

impl Scene {
    fn new(vol: &Volume) -> Scene {
        let d = vol.desc();
        let frame = VolumeFrame::centered(d.dims, d.spacing);
        Scene {
            // Every value above the smallest shows.
            tf: TransferFunction::ramp(0.0, 1.0, 1.0),
            camera: Camera::orbit(frame.center(), 2.0, 0.5, 0.3),
            frame,
        }
    }

    fn view<'a>(&'a self, source: &'a dyn BrickSource) -> CutView<'a> {
        CutView {
            source,
            tf: &self.tf,
            mode: RenderMode::Dvr,
            camera: &self.camera,
            frame: &self.frame,
            size: 64,
            visible: None,
        }
    }

    /// The f64 reference's image of `v` (32 px).
    fn draw(&self, v: &Volume) -> Vec<u8> {
        let settings = RenderSettings {
            mode: RenderMode::Dvr,
            ..RenderSettings::default()
        };
        let opts = ReferenceOptions::new(32, 32);
        render_reference(v, &self.frame, &self.tf, &self.camera, &settings, &opts)
            .to_rgba8([0.0; 3])
    }
}

fn finest_leaves(view: &CutView<'_>) -> HashSet<NodeKey> {
    refine_cut(view, 0.0, u32::MAX / 2, LodMetric::Geometric)
        .unwrap()
        .leaves
        .iter()
        .map(|l| l.key)
        .collect()
}

fn ancestor_at(layout: &OctreeLayout, k: NodeKey, level: u8) -> NodeKey {
    let mut p = k;
    while p.level > level {
        p = layout.parent(p).unwrap();
    }
    p
}

/// The finest cut (tolerance 0, no budget) resampled is the source volume,
/// voxel for voxel, in f32 and u8, isotropic and anisotropic pyramids; its
/// data leaves are all at the finest level.
#[test]
fn finest_cut_resamples_to_the_source() {
    let ml = synthetic::marschner_lobb(40);
    let mut aniso = ml.desc().clone();
    aniso.spacing = [1.0, 1.0, 3.0];
    let cases = [
        (ml.clone(), false),
        (Volume::new(aniso, ml.data().clone()).unwrap(), true),
        (synthetic::sphere(24), false),
    ];
    for (vol, anisotropic) in cases {
        let dir = tempfile::tempdir().unwrap();
        let store = build(dir.path(), &vol, 8, anisotropic);
        let layout = store.layout().clone();
        assert!(layout.levels >= 3, "{layout:?}");
        let scene = Scene::new(&vol);
        let cut = cut_volume(&scene.view(&store), 0.0, u32::MAX / 2, LodMetric::Geometric).unwrap();
        assert_eq!(cut.volume.desc(), vol.desc());
        assert!(
            cut.volume.data() == vol.data(),
            "{:?}: the finest cut differs from the source",
            vol.desc()
        );
        assert!(cut.data_leaves > 0);
        let finest = layout.levels as usize - 1;
        assert_eq!(cut.data_leaves_per_level[finest], cut.data_leaves);
        assert_eq!(
            cut.data_leaves_per_level.iter().sum::<u32>(),
            cut.data_leaves
        );
    }
}

/// A coarser cut (a larger tolerance, or a small budget of data leaves)
/// has fewer data leaves than the finest, and its resampled volume differs
/// from the source.
#[test]
fn coarser_cuts_have_fewer_leaves_and_differ() {
    let vol = synthetic::marschner_lobb(40);
    let dir = tempfile::tempdir().unwrap();
    let store = build(dir.path(), &vol, 8, false);
    let scene = Scene::new(&vol);
    let view = scene.view(&store);
    let finest = cut_volume(&view, 0.0, u32::MAX / 2, LodMetric::Geometric).unwrap();
    for (tolerance, budget) in [(16.0, u32::MAX / 2), (0.0, finest.data_leaves / 4)] {
        let coarse = cut_volume(&view, tolerance, budget, LodMetric::Geometric).unwrap();
        assert!(
            coarse.data_leaves < finest.data_leaves,
            "tolerance {tolerance}, budget {budget}: {} >= {}",
            coarse.data_leaves,
            finest.data_leaves
        );
        assert!(coarse.data_leaves <= budget);
        assert!(coarse.volume.data() != vol.data(), "tolerance {tolerance}");
        assert_eq!(coarse.volume.desc(), vol.desc());
        let finest_level = store.layout().levels as usize - 1;
        assert!(
            coarse.data_leaves_per_level[..finest_level]
                .iter()
                .sum::<u32>()
                > 0
        );
    }
}

/// `splice` overwrites exactly the finest voxels the node covers (its
/// `region`, the node's brick times its voxel factor, clipped to the volume),
/// each with the node's own sample, and leaves every other voxel alone.
#[test]
fn splice_replaces_exactly_the_nodes_voxels() {
    // 40 voxels: the last nodes of each level are clipped by the volume.
    let vol = synthetic::marschner_lobb(40);
    let dir = tempfile::tempdir().unwrap();
    let store = build(dir.path(), &vol, 8, false);
    let layout = store.layout().clone();
    let d = vol.desc().dims;
    let mut r = Resampler::new(&store).unwrap();
    let sentinel = -12345.0f32;
    let mut nodes = 0;
    for level in 0..layout.levels {
        let f = layout.voxel_factor(level)[0] as u32;
        let side = 8 * f;
        for k in (0..layout.nodes_per_axis(level)[0] as u32)
            .flat_map(|x| [NodeKey::new(level, x, 0, 0), NodeKey::new(level, x, 1, 1)])
            .filter(|k| layout.in_volume(*k))
        {
            let kp = [k.x, k.y, k.z];
            let lo = kp.map(|p| p * side);
            let hi: [u32; 3] = std::array::from_fn(|i| ((kp[i] + 1) * side).min(d[i]));
            assert_eq!(r.region(k).unwrap(), (lo, hi), "{k:?}");
            let mut out = vec![sentinel; vol.data().len()];
            r.splice(k, &mut out).unwrap();
            for z in 0..d[2] {
                for y in 0..d[1] {
                    for x in 0..d[0] {
                        let v = [x, y, z];
                        let got = out[(x + d[0] * (y + d[1] * z)) as usize];
                        if (0..3).all(|i| (lo[i]..hi[i]).contains(&v[i])) {
                            assert_eq!(got, r.sample(k, v).unwrap(), "{k:?} {v:?}");
                            assert_ne!(got, sentinel);
                        } else {
                            assert_eq!(got, sentinel, "{k:?} wrote {v:?}");
                        }
                    }
                }
            }
            nodes += 1;
        }
    }
    assert!(nodes >= 6, "{nodes}");
    // A buffer of the wrong size is refused, untouched.
    let mut short = vec![sentinel; 10];
    assert!(matches!(
        r.splice(NodeKey::ROOT, &mut short),
        Err(LodModelError::SampleCount {
            expected: 64000,
            actual: 10,
            ..
        })
    ));
    assert!(short.iter().all(|&s| s == sentinel));
}

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
        let store = build(dir.path(), &vol, 4, anisotropic);
        let layout = store.layout().clone();
        assert!(layout.levels >= 3, "{layout:?}");
        let scene = Scene::new(&vol);
        let leaves = finest_leaves(&scene.view(&store));
        let mut r = Resampler::new(&store).unwrap();
        let samples = r.resample(&leaves).unwrap();
        // Every node of level 1: its descendants out, itself in.
        let (mut checked, mut coarser) = (0, 0);
        for node in leaves
            .iter()
            .filter(|k| k.level >= 2)
            .map(|k| ancestor_at(&layout, *k, 1))
            .collect::<HashSet<_>>()
        {
            let mut cut: HashSet<NodeKey> = leaves
                .iter()
                .copied()
                .filter(|k| ancestor_at(&layout, *k, node.level) != node)
                .collect();
            cut.insert(node);
            let want = Resampler::new(&store).unwrap().resample(&cut).unwrap();
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

/// The oracle: a node over uniform data (its own brick samples its region
/// exactly as the finest cut does) costs 0; a node whose coarse brick
/// differs costs more than 0; the costs are each node above the finest cut,
/// in key order, and the same as splicing and drawing by hand.
#[test]
fn oracle_costs_zero_over_uniform_data_and_more_where_coarse_differs() {
    // Uniform below x = 18 (the level-1 nodes at x = 0 cover 0..16, their
    // apron reaches 20: data nodes, split at tolerance 0, yet their interior
    // samples are exact); a varying field above.
    let vol = half_uniform([0.7, 0.5, 0.3]);
    let dir = tempfile::tempdir().unwrap();
    let store = build(dir.path(), &vol, 8, false);
    let layout = store.layout().clone();
    assert_eq!(layout.levels, 3, "{layout:?}");
    let scene = Scene::new(&vol);
    let leaves = finest_leaves(&scene.view(&store));
    let costs = node_costs(&store, &leaves, |v| scene.draw(v)).unwrap();
    let keys: Vec<NodeKey> = costs.iter().map(|c| c.key).collect();
    let above: Vec<NodeKey> = nodes_above(&layout, &leaves).into_iter().collect();
    assert_eq!(keys, above);
    assert!(keys.is_sorted());
    assert_eq!(keys[0], NodeKey::ROOT);
    let cost = |k: NodeKey| costs.iter().find(|c| c.key == k).map(|c| c.cost);
    // The root draws the varying half coarse.
    assert!(cost(NodeKey::ROOT).unwrap() > 0.0, "{costs:?}");
    // The level-1 nodes over the uniform half are inner nodes, data, and
    // cost nothing; those over the varying half cost something.
    let mut r = Resampler::new(&store).unwrap();
    let samples = r.resample(&leaves).unwrap();
    let (mut uniform, mut varying) = (0, 0);
    for c in costs.iter().filter(|c| c.key.level == 1) {
        assert_eq!(store.node(c.key).unwrap().kind, NodeKind::Data, "{c:?}");
        let mut s = samples.clone();
        r.splice(c.key, &mut s).unwrap();
        if c.key.x == 0 {
            assert_eq!(s, samples, "{c:?}");
            assert_eq!(c.cost, 0.0, "{c:?}");
            uniform += 1;
        } else {
            assert_ne!(s, samples, "{c:?}");
            varying += usize::from(c.cost > 0.0);
        }
        let by_hand = sse(&scene.draw(&typed(&layout, s).unwrap()), &{
            scene.draw(&typed(&layout, samples.clone()).unwrap())
        });
        assert_eq!(by_hand, c.cost, "{c:?}");
    }
    assert_eq!(uniform, 4, "{costs:?}");
    assert!(varying >= 2, "{costs:?}");
    // Images of another size are refused.
    let mut calls = std::cell::Cell::new(0);
    let err = node_costs(&store, &leaves, |v| {
        calls.set(calls.get() + 1);
        let mut img = scene.draw(v);
        if calls.get() > 1 {
            img.truncate(8);
        }
        img
    })
    .unwrap_err();
    assert!(
        matches!(err, LodModelError::ImageSize { actual: 8, .. }),
        "{err}"
    );
    assert_eq!(*calls.get_mut(), 2);
}

/// Spreads through the oracle: the finest cut's are 0; a coarse node's,
/// spliced, change only its own voxels, and lie between 0 and the standard
/// deviation of the finest values under the whole node; costs drawn without
/// them are `node_costs`'; drawn with them, those of nodes over varying data
/// change.
#[test]
fn spreads_splice_like_values_into_the_oracle() {
    let vol = half_uniform([0.9, 0.7, 0.5]);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("v.brs");
    let mut reader = brickray_io::MemoryReader::new(vol.clone(), "memory");
    let opts = brickray_store::BuildOptions {
        brick: 8,
        spread: true,
        ..Default::default()
    };
    brickray_store::build(&mut reader, &path, &opts).unwrap();
    let store = brickray_store::open(&path).unwrap();
    assert!(store.has_spread());
    let layout = store.layout().clone();
    // A ramp whose slope is where the field varies: spreads matter there.
    let scene = Scene {
        tf: TransferFunction::ramp(0.3, 0.7, 1.0),
        ..Scene::new(&vol)
    };
    let leaves = finest_leaves(&scene.view(&store));
    let mut r = Resampler::new(&store).unwrap();
    let spreads = r.resample_spread(&leaves).unwrap();
    assert!(spreads.iter().all(|&s| s == 0.0));
    // A level-1 node over the varying half.
    let key = NodeKey::new(1, 1, 1, 1);
    let (lo, hi) = r.region(key).unwrap();
    let mut sp = spreads.clone();
    r.splice_spread(key, &mut sp).unwrap();
    let d = layout.volume.dims;
    let idx = |x: u32, y: u32, z: u32| (x + d[0] * (y + d[1] * z)) as usize;
    let (mut inside, mut n) = (0.0f64, 0usize);
    let (mut sum, mut sum2) = (0.0f64, 0.0f64);
    for z in 0..d[2] {
        for y in 0..d[1] {
            for x in 0..d[0] {
                let i = idx(x, y, z);
                let within = (lo[0]..hi[0]).contains(&x)
                    && (lo[1]..hi[1]).contains(&y)
                    && (lo[2]..hi[2]).contains(&z);
                if within {
                    inside += sp[i] as f64;
                    n += 1;
                    let v = vol.data().get(i) as f64 / 255.0;
                    sum += v;
                    sum2 += v * v;
                } else {
                    assert_eq!(sp[i], 0.0, "({x}, {y}, {z}) outside the node");
                }
            }
        }
    }
    let mean_spread = inside / n as f64;
    let sd = (sum2 / n as f64 - (sum / n as f64).powi(2)).max(0.0).sqrt();
    // Each coarse voxel stands for 2^3 finest ones: its spread is that
    // block's deviation, smaller than the whole node's, and not 0.
    assert!(
        mean_spread > 0.02 && mean_spread < sd,
        "{mean_spread} vs {sd}"
    );
    // Without the spreads in the image, the costs are node_costs'.
    let plain = node_costs(&store, &leaves, |v| scene.draw(v)).unwrap();
    let ignored = node_costs_spread(&store, &leaves, |v, _| scene.draw(v)).unwrap();
    assert_eq!(plain, ignored);
    let settings = RenderSettings::default();
    let with = node_costs_spread(&store, &leaves, |v, s| {
        let o = ReferenceOptions::new(32, 32).with_spread(s);
        render_reference(v, &scene.frame, &scene.tf, &scene.camera, &settings, &o)
            .to_rgba8([0.0; 3])
    })
    .unwrap();
    let keys = |c: &[NodeCost]| c.iter().map(|c| c.key).collect::<Vec<_>>();
    assert_eq!(keys(&with), keys(&plain));
    // The uniform half's nodes (spread 0) cost nothing either way; the
    // varying half's cost otherwise (on this field some more, some less).
    let mut changed = 0;
    for (p, w) in plain.iter().zip(&with) {
        if p.key.level == 1 && p.key.x == 0 {
            assert_eq!((p.cost, w.cost), (0.0, 0.0), "{p:?} -> {w:?}");
        }
        changed += usize::from(p.cost != w.cost);
    }
    assert!(changed >= 3, "{plain:?} -> {with:?}");
}

#[test]
fn sse_sums_squared_rgb_differences() {
    let a = [10u8, 20, 30, 255, 0, 0, 0, 0];
    let b = [13u8, 16, 30, 0, 0, 0, 1, 9];
    assert_eq!(sse(&a, &a), 0.0);
    // 3^2 + 4^2 + 0 (alpha ignored), then 1^2.
    assert_eq!(sse(&a, &b), 26.0);
    assert_eq!(sse(&b, &a), 26.0);
}

#[test]
fn spearman_of_identical_and_reversed_rankings() {
    let a = [0.3, 5.0, -1.0, 2.5, 7.0, 0.0];
    let rev: Vec<f64> = a.iter().map(|x| -x).collect();
    assert!((spearman(&a, &a) - 1.0).abs() < 1e-12);
    assert!((spearman(&a, &rev) + 1.0).abs() < 1e-12);
    // Rank-based: any increasing transform keeps 1.
    let cubed: Vec<f64> = a.iter().map(|x| x * x * x + 4.0).collect();
    assert!((spearman(&a, &cubed) - 1.0).abs() < 1e-12);
    assert!(spearman(&a, &a[..3]).is_nan());
    assert!(spearman(&[1.0], &[2.0]).is_nan());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]
    /// For distinct values: 1 against itself and any increasing transform,
    /// -1 against a decreasing one, symmetric, and within [-1, 1].
    #[test]
    fn spearman_is_a_rank_correlation(
        a in prop::collection::hash_set(-1000i32..1000, 2..40),
        b in prop::collection::vec(-1000.0f64..1000.0, 40),
    ) {
        let a: Vec<f64> = a.into_iter().map(f64::from).collect();
        let up: Vec<f64> = a.iter().map(|x| x.exp2().ln_1p() + 3.0 * x).collect();
        let down: Vec<f64> = a.iter().map(|x| -x * 0.5 - 2.0).collect();
        prop_assert!((spearman(&a, &up) - 1.0).abs() < 1e-9);
        prop_assert!((spearman(&a, &down) + 1.0).abs() < 1e-9);
        let b = &b[..a.len()];
        let (ab, ba) = (spearman(&a, b), spearman(b, &a));
        prop_assert!((ab - ba).abs() < 1e-9);
        prop_assert!((-1.0 - 1e-9..=1.0 + 1e-9).contains(&ab), "{}", ab);
    }
}

/// A source whose node `fail` cannot be read (metadata and brick).
struct Failing<'a> {
    inner: &'a Store,
    fail: NodeKey,
}

impl BrickSource for Failing<'_> {
    fn layout(&self) -> &OctreeLayout {
        self.inner.layout()
    }
    fn node(&self, key: NodeKey) -> Result<NodeInfo, BrickError> {
        if key == self.fail {
            return Err(BrickError::Corrupt {
                key,
                reason: "test".into(),
            });
        }
        self.inner.node(key)
    }
    fn read_brick(&self, key: NodeKey, out: &mut [u8]) -> Result<(), BrickError> {
        self.node(key)?;
        self.inner.read_brick(key, out)
    }
}

fn is_corrupt(e: &LodModelError, at: NodeKey) -> bool {
    matches!(e, LodModelError::Brick(BrickError::Corrupt { key, .. }) if *key == at)
}

/// A node that cannot be read gives the source's error, typed, from every
/// model; inconsistent input gives its own.
#[test]
fn bad_sources_and_input_give_typed_errors() {
    let vol = synthetic::marschner_lobb(24);
    let dir = tempfile::tempdir().unwrap();
    let store = build(dir.path(), &vol, 8, false);
    let layout = store.layout().clone();
    let scene = Scene::new(&vol);
    let leaves = finest_leaves(&scene.view(&store));
    let leaf = *leaves
        .iter()
        .filter(|k| layout.in_volume(**k))
        .max()
        .unwrap();
    let bad_leaf = Failing {
        inner: &store,
        fail: leaf,
    };
    let bad_root = Failing {
        inner: &store,
        fail: NodeKey::ROOT,
    };
    // The resampler, of the failing leaf; a cut of it.
    let mut r = Resampler::new(&bad_leaf).unwrap();
    assert!(is_corrupt(&r.sample(leaf, [0; 3]).err().unwrap(), leaf));
    assert!(is_corrupt(&r.resample(&leaves).err().unwrap(), leaf));
    let e = cut_volume(
        &scene.view(&bad_leaf),
        0.0,
        u32::MAX / 2,
        LodMetric::Geometric,
    )
    .err()
    .unwrap();
    assert!(is_corrupt(&e, leaf), "{e}");
    let e = refine_cut(
        &scene.view(&bad_leaf),
        0.0,
        u32::MAX / 2,
        LodMetric::Geometric,
    )
    .err()
    .unwrap();
    assert!(is_corrupt(&e, leaf), "{e}");
    let e = cut_volume(
        &scene.view(&bad_root),
        0.0,
        u32::MAX / 2,
        LodMetric::Geometric,
    )
    .err()
    .unwrap();
    assert!(is_corrupt(&e, NodeKey::ROOT), "{e}");
    let e = node_costs(&bad_root, &leaves, |v| scene.draw(v))
        .err()
        .unwrap();
    assert!(is_corrupt(&e, NodeKey::ROOT), "{e}");
    let e = node_costs(&bad_leaf, &leaves, |v| scene.draw(v))
        .err()
        .unwrap();
    assert!(is_corrupt(&e, leaf), "{e}");
    let weights: HashMap<NodeKey, f64> = leaves.iter().map(|k| (*k, 1.0)).collect();
    for error in [OctantError::Store, OctantError::Data(&vol)] {
        let e = octant_cut(&bad_root, RenderMode::Dvr, &scene.tf, &weights, 10, error).unwrap_err();
        assert!(is_corrupt(&e, NodeKey::ROOT), "{e}");
    }
    // Keys below the finest level, buffers and volumes of other sizes,
    // label types.
    let mut r = Resampler::new(&store).unwrap();
    let deep = NodeKey::new(layout.levels, 0, 0, 0);
    assert!(matches!(
        r.sample(deep, [0; 3]),
        Err(LodModelError::NotInOctree { .. })
    ));
    assert!(matches!(
        r.region(deep),
        Err(LodModelError::NotInOctree { .. })
    ));
    assert!(matches!(
        r.resample(&HashSet::new()),
        Err(LodModelError::Uncovered { voxel: [0, 0, 0] })
    ));
    assert!(matches!(
        typed(&layout, vec![0.0; 5]),
        Err(LodModelError::SampleCount { actual: 5, .. })
    ));
    let mut labels = layout.clone();
    labels.volume.dtype = brickray_core::DType::U32;
    assert!(matches!(
        typed(&labels, vec![0.0; vol.data().len()]),
        Err(LodModelError::UnsupportedDType { .. })
    ));
    let other = synthetic::marschner_lobb(16);
    let table = TfErrorTable::new(&scene.tf);
    let e = data_error(
        &mut r,
        NodeKey::ROOT,
        NodeKey::ROOT,
        RenderMode::Dvr,
        &table,
        &other,
    )
    .unwrap_err();
    assert!(matches!(
        e,
        LodModelError::DimsMismatch {
            expected: [24, 24, 24],
            actual: [16, 16, 16]
        }
    ));
    let e = octant_cut(
        &store,
        RenderMode::Dvr,
        &scene.tf,
        &weights,
        10,
        OctantError::Data(&other),
    )
    .unwrap_err();
    assert!(matches!(e, LodModelError::DimsMismatch { .. }), "{e}");
}

// Octant-granular cuts.

fn octant_store(dir: &std::path::Path) -> (Store, Volume) {
    let vol = synthetic::marschner_lobb(40);
    (build(dir, &vol, 4, false), vol)
}

/// The bricks an octant cut's working set holds, counted from the set
/// alone: its nodes needing data that draw some region themselves.
fn working_set(store: &Store, set: &HashSet<NodeKey>, tf: &TransferFunction) -> u32 {
    let layout = store.layout();
    let needs = |k: NodeKey| {
        let i = store.node(k).unwrap();
        i.kind != NodeKind::Empty
            && brickray_cache::refine::is_visible(&i, RenderMode::Dvr, tf, &[], layout)
    };
    set.iter()
        .filter(|&&k| {
            let uniform = matches!(store.node(k).unwrap().kind, NodeKind::Uniform(_));
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
    let (store, vol) = octant_store(dir.path());
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
            let OctantCut { nodes: set, bricks } =
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
        let cut = octant_cut(&store, RenderMode::Dvr, &tf, &weights, 100_000, error).unwrap();
        assert!(cut.nodes.iter().any(|k| k.level + 1 == layout.levels));
    }
}

/// A per-node cut's leaves with all their ancestors, drawn deepest
/// first, are that cut: what the octant cuts' images rest on.
#[test]
fn deepest_of_a_closed_set_is_the_cut() {
    let dir = tempfile::tempdir().unwrap();
    let (store, _) = octant_store(dir.path());
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
    let mut r = Resampler::new(&store).unwrap();
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

/// A node's own measured error is 0 at the finest level (its brick is the
/// data) and more than 0 above it on varying data.
#[test]
fn data_error_is_zero_at_the_finest_level() {
    let dir = tempfile::tempdir().unwrap();
    let (store, vol) = octant_store(dir.path());
    let layout = store.layout().clone();
    let tf = TransferFunction::ramp(0.0, 1.0, 1.0);
    let table = TfErrorTable::new(&tf);
    let mut r = Resampler::new(&store).unwrap();
    let fine = NodeKey::new(layout.levels - 1, 3, 2, 1);
    for mode in [RenderMode::Dvr, RenderMode::Mip] {
        assert_eq!(
            data_error(&mut r, fine, fine, mode, &table, &vol).unwrap(),
            0.0
        );
        let coarse = data_error(&mut r, NodeKey::ROOT, NodeKey::ROOT, mode, &table, &vol).unwrap();
        assert!(coarse > 0.0, "{mode:?}");
    }
}

/// A 32^3 u8 field, uniform (0.5) below x = 18 and varying above, as
/// `sin(y ky) cos(z kz + x kx)` for `[ky, kz, kx]`.
fn half_uniform(k: [f64; 3]) -> Volume {
    synthetic::u8_field(32, |[x, y, z]| {
        if x < 18 {
            0.5
        } else {
            0.5 + 0.45 * ((y as f64 * k[0]).sin() * (z as f64 * k[1] + x as f64 * k[2]).cos())
        }
    })
}
