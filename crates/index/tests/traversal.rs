//! The CPU twin of the GPU traversal against a brute-force oracle, over random
//! cuts and >= 100,000 random rays of every awkward kind.

mod common;

use brickray_core::brick::NodeKey;
use brickray_index::{
    CutLeaf, DIR_EPSILON, LeafHit, LeafKind, Ray, TraversalStatus, encode_cut, traverse,
};
use common::{Rng, random_cut};
use glam::Vec3;
use proptest::test_runner::{Config, TestCaseError, TestRunner};
use std::collections::{HashMap, HashSet};

/// A segment of the oracle: the leaf and its exact (f64) parameter interval.
#[derive(Debug, Clone, Copy)]
struct Seg {
    key: NodeKey,
    kind: LeafKind,
    t0: f64,
    t1: f64,
}

/// Brute force: intersect the ray with every leaf box (closed slabs; half-open
/// `[min, max)` along zero direction components, the twin's tie rule), clip to
/// `[t_min, t_max]`, drop zero-length touches, sort by entry.
fn oracle(cut: &[CutLeaf], ray: &Ray) -> Vec<Seg> {
    let o = ray.origin.to_array().map(f64::from);
    let d = ray.dir.to_array().map(|c| {
        if c.abs() < DIR_EPSILON {
            0.0
        } else {
            f64::from(c)
        }
    });
    let mut out = Vec::new();
    if d == [0.0; 3] {
        return out;
    }
    'leaves: for &CutLeaf { key, kind, .. } in cut {
        let (lo, size) = key.unit_box();
        let mut t0 = f64::from(ray.t_min);
        let mut t1 = f64::from(ray.t_max);
        for a in 0..3 {
            let hi = lo[a] + size;
            if d[a] == 0.0 {
                if !(lo[a] <= o[a] && o[a] < hi) {
                    continue 'leaves;
                }
            } else {
                let ta = (lo[a] - o[a]) / d[a];
                let tb = (hi - o[a]) / d[a];
                t0 = t0.max(ta.min(tb));
                t1 = t1.min(ta.max(tb));
            }
        }
        if t1 > t0 {
            out.push(Seg { key, kind, t0, t1 });
        }
    }
    out.sort_by(|a, b| a.t0.total_cmp(&b.t0));
    out
}

/// Segments shorter than this (in `t`) may be missing from, or extra in, the
/// twin's output (edge and corner touches, f32 rounding).
const TINY: f64 = 2e-5;
/// Endpoint agreement between twin (f32) and oracle (f64), relative to max(1, |t|).
const T_TOL: f64 = 5e-5;
/// Continuity of consecutive twin segments.
const GAP_TOL: f32 = 1e-5;

#[derive(Debug, Default)]
struct Totals {
    rays: u64,
    rays_hitting: u64,
    leaves_in_cuts: u64,
    max_leaves_per_ray: usize,
    rays_by_kind: [u64; 8],
    hits_by_kind: [u64; 8],
    hits: u64,
    steps: u64,
    max_step_excess: i64,
    max_endpoint_err: f64,
    tiny_extra: u64,
    tiny_missing: u64,
}

fn check_ray(
    cut: &[CutLeaf],
    words: &[u32],
    ray: &Ray,
    kind: usize,
    totals: &mut Totals,
) -> Result<(), String> {
    let want = oracle(cut, ray);
    let max_steps = 10_000;
    let mut it = traverse(words, *ray, max_steps);
    let got: Vec<LeafHit> = it.by_ref().collect();
    if it.status() != TraversalStatus::Finished {
        return Err(format!(
            "status {:?} after {} steps",
            it.status(),
            it.steps()
        ));
    }
    // Bounded steps: every step visits a distinct leaf; zero-length visits happen
    // only at edges and corners (at most 2 per crossing).
    let bound = 3 * want.len() as u32 + 3;
    if it.steps() > bound {
        return Err(format!(
            "{} steps for {} oracle leaves",
            it.steps(),
            want.len()
        ));
    }
    totals.max_step_excess = totals
        .max_step_excess
        .max(it.steps() as i64 - want.len() as i64);
    totals.steps += it.steps() as u64;
    totals.hits += got.len() as u64;
    totals.hits_by_kind[kind] += got.len() as u64;
    totals.rays_hitting += u64::from(!got.is_empty());
    totals.max_leaves_per_ray = totals.max_leaves_per_ray.max(got.len());

    // No repeats, positive lengths, no gaps.
    let mut seen = HashSet::new();
    for (i, h) in got.iter().enumerate() {
        if !seen.insert(h.key()) {
            return Err(format!("leaf {:?} reported twice", h.key()));
        }
        if h.t_exit.partial_cmp(&h.t_enter) != Some(std::cmp::Ordering::Greater) {
            return Err(format!("empty segment {h:?}"));
        }
        if i > 0 && (h.t_enter - got[i - 1].t_exit).abs() > GAP_TOL {
            return Err(format!("gap between {:?} and {h:?}", got[i - 1]));
        }
        let (lo, size) = h.key().unit_box();
        if h.leaf.box_size.to_array().map(f64::from) != [size; 3]
            || h.leaf.box_min.to_array().map(f64::from) != lo
        {
            return Err(format!("box of {h:?} disagrees with its key"));
        }
    }

    let tol = |t: f64| T_TOL * t.abs().max(1.0);
    let by_key: HashMap<NodeKey, &Seg> = want.iter().map(|s| (s.key, s)).collect();
    // Every twin leaf is an oracle leaf with the same kind and interval (tiny
    // extra touches excepted).
    let mut order = Vec::new();
    for h in &got {
        let (t0, t1) = (f64::from(h.t_enter), f64::from(h.t_exit));
        match by_key.get(&h.key()) {
            Some(s) => {
                if s.kind.slot() != h.slot {
                    return Err(format!("kind of {h:?} != {s:?}"));
                }
                let err = (t0 - s.t0).abs().max((t1 - s.t1).abs());
                totals.max_endpoint_err = totals.max_endpoint_err.max(err);
                if (t0 - s.t0).abs() > tol(s.t0) || (t1 - s.t1).abs() > tol(s.t1) {
                    return Err(format!("interval of {h:?} != oracle {s:?}"));
                }
                order.push(s.t0);
            }
            None if t1 - t0 <= TINY => totals.tiny_extra += 1,
            None => return Err(format!("{h:?} is not pierced (oracle {want:?})")),
        }
    }
    // Front to back in the oracle's order.
    if order.windows(2).any(|w| w[0] >= w[1]) {
        return Err("order differs from the oracle".into());
    }
    // Every oracle leaf is reported (tiny touches excepted).
    let got_keys: HashSet<NodeKey> = got.iter().map(|h| h.key()).collect();
    for s in &want {
        if !got_keys.contains(&s.key) {
            if s.t1 - s.t0 <= TINY {
                totals.tiny_missing += 1;
            } else {
                return Err(format!("missing {s:?}"));
            }
        }
    }
    // Same overall extent.
    match (want.first(), want.last(), got.first(), got.last()) {
        (Some(a), Some(b), Some(c), Some(d)) => {
            if (f64::from(c.t_enter) - a.t0).abs() > tol(a.t0) + TINY
                || (f64::from(d.t_exit) - b.t1).abs() > tol(b.t1) + TINY
            {
                return Err("extent differs".into());
            }
        }
        (None, None, None, None) => {}
        _ => {
            let total: f64 = want.iter().map(|s| s.t1 - s.t0).sum::<f64>()
                + got
                    .iter()
                    .map(|h| f64::from(h.t_exit - h.t_enter))
                    .sum::<f64>();
            if total > 2.0 * TINY {
                return Err("one side is empty".into());
            }
        }
    }
    Ok(())
}

fn dyadic(rng: &mut Rng, max_level: u32, lo: i64, hi: i64) -> f32 {
    // k / 2^l with k / 2^l in [lo, hi].
    let l = rng.below(max_level as u64 + 1) as u32;
    let n = 1i64 << l;
    let k = lo * n + rng.below(((hi - lo) * n + 1) as u64) as i64;
    k as f32 / n as f32
}

fn random_dir(rng: &mut Rng) -> Vec3 {
    loop {
        let d = Vec3::new(
            rng.range(-1.0, 1.0) as f32,
            rng.range(-1.0, 1.0) as f32,
            rng.range(-1.0, 1.0) as f32,
        );
        let l = d.length();
        if l > 0.2 && l <= 1.0 {
            return d / l * rng.range(0.5, 2.0) as f32;
        }
    }
}

/// A random ray of kind `kind` (0..8).
fn random_ray(rng: &mut Rng, kind: usize) -> Ray {
    let unit = |rng: &mut Rng| rng.range(0.0, 1.0) as f32;
    let outside = |rng: &mut Rng| rng.range(-0.75, 1.75) as f32;
    match kind {
        // Generic: anywhere around the cube, any direction, mostly aimed at a
        // random point of the cube.
        0 => {
            let o = Vec3::new(outside(rng), outside(rng), outside(rng));
            let target = Vec3::new(unit(rng), unit(rng), unit(rng));
            let d = if rng.chance(0.8) && target != o {
                (target - o).normalize() * rng.range(0.5, 2.0) as f32
            } else {
                random_dir(rng)
            };
            Ray::new(o, d)
        }
        // Starting inside, sometimes ending inside.
        1 => {
            let r = Ray::new(Vec3::new(unit(rng), unit(rng), unit(rng)), random_dir(rng));
            if rng.chance(0.5) {
                r.with_range(rng.range(0.0, 0.5) as f32, rng.range(0.0, 1.5) as f32)
            } else {
                r
            }
        }
        // Axis-aligned, origin on the dyadic grid (along faces and edges), from
        // outside or inside.
        2 => {
            let a = rng.below(3) as usize;
            let mut d = Vec3::ZERO;
            d[a] = if rng.chance(0.5) { 1.0 } else { -0.5 };
            let mut o = Vec3::new(
                dyadic(rng, 7, 0, 1),
                dyadic(rng, 7, 0, 1),
                dyadic(rng, 7, 0, 1),
            );
            if rng.chance(0.5) {
                o[a] = if d[a] > 0.0 { -0.5 } else { 1.5 };
            }
            Ray::new(o, d)
        }
        // Grazing: in a face plane (one component zero or tiny), other components
        // aimed at a random point of that plane.
        3 => {
            let a = rng.below(3) as usize;
            let mut o = Vec3::new(outside(rng), outside(rng), outside(rng));
            o[a] = dyadic(rng, 7, 0, 1);
            let mut target = Vec3::new(unit(rng), unit(rng), unit(rng));
            target[a] = o[a];
            let mut d = if target != o {
                (target - o).normalize()
            } else {
                random_dir(rng)
            };
            d[a] = match rng.below(4) {
                0 => 1e-6,
                1 => -1e-6,
                2 => 1e-35, // flushed to zero
                _ => 0.0,
            };
            Ray::new(o, d)
        }
        // Through a dyadic edge or corner point, exactly: origin = c - d * s with
        // dyadic d and s, so the f32 ray passes through c.
        4 | 5 => {
            let c = Vec3::new(
                dyadic(rng, 6, 0, 1),
                dyadic(rng, 6, 0, 1),
                dyadic(rng, 6, 0, 1),
            );
            let mut d = Vec3::ZERO;
            while d == Vec3::ZERO {
                d = Vec3::new(
                    rng.below(9) as f32 - 4.0,
                    rng.below(9) as f32 - 4.0,
                    rng.below(9) as f32 - 4.0,
                ) / 4.0;
            }
            if kind == 5 {
                // Start exactly at the corner.
                return Ray::new(c, d);
            }
            let s = (1 + rng.below(16)) as f32 / 8.0;
            Ray::new(c - d * s, d)
        }
        // Diagonals through cube corners and dyadic lattice points.
        6 => {
            let d = Vec3::new(
                if rng.chance(0.5) { 1.0 } else { -1.0 },
                if rng.chance(0.5) { 1.0 } else { -1.0 },
                if rng.chance(0.5) { 1.0 } else { -1.0 },
            );
            let c = Vec3::new(
                dyadic(rng, 5, 0, 1),
                dyadic(rng, 5, 0, 1),
                dyadic(rng, 5, 0, 1),
            );
            Ray::new(c - d * 2.0, d)
        }
        // Generic with a random sub-range, sometimes negative t_min; half of them
        // from a distant origin (a camera far from the volume).
        _ => {
            let o = if rng.chance(0.5) {
                Vec3::new(outside(rng), outside(rng), outside(rng))
            } else {
                Vec3::new(
                    rng.range(-8.0, 9.0) as f32,
                    rng.range(-8.0, 9.0) as f32,
                    rng.range(-8.0, 9.0) as f32,
                )
            };
            let target = Vec3::new(unit(rng), unit(rng), unit(rng));
            let d = if rng.chance(0.5) && o != target {
                (target - o).normalize()
            } else {
                random_dir(rng)
            };
            let r = Ray::new(o, d);
            if o.length() > 3.0 {
                return if rng.chance(0.5) {
                    r
                } else {
                    r.with_range(rng.range(0.0, 10.0) as f32, rng.range(5.0, 20.0) as f32)
                };
            }
            let a = rng.range(-2.0, 3.0) as f32;
            r.with_range(a, a + rng.range(0.0, 3.0) as f32)
        }
    }
}

const CASES: u32 = 250;
const RAYS_PER_CASE: usize = 480;

#[test]
fn twin_matches_brute_force_oracle() {
    let start = std::time::Instant::now();
    // BRICKRAY_INDEX_CASES=N runs a longer soak.
    let cases = std::env::var("BRICKRAY_INDEX_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(CASES);
    let mut runner = TestRunner::new(Config {
        cases,
        failure_persistence: None,
        ..Config::default()
    });
    let totals = std::cell::RefCell::new(Totals::default());
    let strategy = (proptest::num::u64::ANY, 0u8..=6, 0.3f64..0.9, 0.0f64..1.0);
    let result = runner.run(&strategy, |(seed, depth, p_refine, p_data)| {
        let mut rng = Rng(seed);
        let cut = random_cut(&mut rng, depth, p_refine, p_data, 3000);
        let index =
            encode_cut(cut.iter().copied()).map_err(|e| TestCaseError::fail(e.to_string()))?;
        let mut totals = totals.borrow_mut();
        totals.leaves_in_cuts += cut.len() as u64;
        for i in 0..RAYS_PER_CASE {
            let kind = i % 8;
            let ray = random_ray(&mut rng, kind);
            totals.rays += 1;
            totals.rays_by_kind[kind] += 1;
            check_ray(&cut, index.words(), &ray, kind, &mut totals).map_err(|e| {
                TestCaseError::fail(format!(
                    "{e}\nray {ray:?}\ncut of {} leaves (depth {depth})",
                    cut.len()
                ))
            })?;
        }
        Ok(())
    });
    let totals = totals.into_inner();
    eprintln!("{totals:#?}\nin {:.2} s", start.elapsed().as_secs_f64());
    result.unwrap();
    assert!(
        totals.rays >= u64::from(cases) * RAYS_PER_CASE as u64,
        "only {} rays",
        totals.rays
    );
    assert!(cases < CASES || totals.rays >= 100_000);
}

/// Hand-picked awkward rays on a fixed mixed-level cut.
#[test]
fn awkward_rays_on_fixed_cut() {
    let mut rng = Rng(1234);
    let cut = random_cut(&mut rng, 4, 0.7, 0.6, 3000);
    let index = encode_cut(cut.iter().copied()).unwrap();
    let mut totals = Totals::default();
    let rays = [
        // Along the central planes and axes.
        Ray::new(Vec3::new(-1.0, 0.5, 0.5), Vec3::X),
        Ray::new(Vec3::new(2.0, 0.5, 0.5), -Vec3::X),
        Ray::new(Vec3::new(0.5, -1.0, 0.5), Vec3::Y),
        Ray::new(Vec3::new(0.5, 0.5, 2.0), -Vec3::Z),
        // Along cube edges (inside: the lower edges; the upper ones miss).
        Ray::new(Vec3::new(-1.0, 0.0, 0.0), Vec3::X),
        Ray::new(Vec3::new(-1.0, 1.0, 1.0), Vec3::X),
        // Main diagonals, both ways.
        Ray::new(Vec3::splat(-1.0), Vec3::ONE),
        Ray::new(Vec3::splat(2.0), -Vec3::ONE),
        Ray::new(Vec3::new(2.0, -1.0, 2.0), Vec3::new(-1.0, 1.0, -1.0)),
        // Starting at the centre, and at a corner of the cube, going out.
        Ray::new(Vec3::splat(0.5), Vec3::new(0.3, -0.7, 0.2)),
        Ray::new(Vec3::ONE, -Vec3::ONE),
        Ray::new(Vec3::ZERO, -Vec3::ONE),
        // Missing rays.
        Ray::new(Vec3::new(-1.0, 2.0, 0.5), Vec3::X),
        Ray::new(Vec3::new(0.5, 0.5, 0.5), Vec3::ZERO),
        // Range ending before the cube and starting after it.
        Ray::new(Vec3::new(-1.0, 0.3, 0.3), Vec3::X).with_range(0.0, 0.5),
        Ray::new(Vec3::new(-1.0, 0.3, 0.3), Vec3::X).with_range(3.0, 4.0),
        // Zero-length range inside.
        Ray::new(Vec3::new(0.2, 0.3, 0.3), Vec3::X).with_range(0.1, 0.1),
    ];
    for ray in rays {
        check_ray(&cut, index.words(), &ray, 0, &mut totals)
            .unwrap_or_else(|e| panic!("{e}\n{ray:?}"));
    }
    // Non-finite inputs neither panic nor loop.
    for ray in [
        Ray::new(Vec3::new(f32::NAN, 0.5, 0.5), Vec3::X),
        Ray::new(Vec3::new(-1.0, 0.5, 0.5), Vec3::new(f32::NAN, 1.0, 0.0)),
        Ray::new(
            Vec3::new(-1.0, 0.5, 0.5),
            Vec3::new(f32::INFINITY, 1.0, 0.0),
        ),
        Ray::new(Vec3::new(-1.0, 0.5, 0.5), Vec3::X).with_range(f32::NEG_INFINITY, f32::INFINITY),
        Ray::new(Vec3::new(-1.0, 0.5, 0.5), Vec3::X).with_range(f32::NAN, 3.0),
    ] {
        let mut it = traverse(index.words(), ray, 1000);
        let n = it.by_ref().count();
        assert!(n <= 1000);
        assert_ne!(it.status(), TraversalStatus::Running);
    }
    // Upper-edge ray misses (half-open rule); lower-edge ray crosses the cube.
    assert_eq!(traverse(index.words(), rays[5], 100).count(), 0);
    assert!(traverse(index.words(), rays[4], 100).count() > 0);
}

#[test]
fn step_limit_and_corrupt_words_are_reported() {
    let cut = common::uniform_cut(3);
    let index = encode_cut(cut).unwrap();
    let ray = Ray::new(Vec3::new(-1.0, 0.3, 0.3), Vec3::X);
    let mut it = traverse(index.words(), ray, 3);
    assert_eq!(it.by_ref().count(), 3);
    assert_eq!(it.status(), TraversalStatus::StepLimit);
    assert_eq!(it.steps(), 3);
    let mut it = traverse(index.words(), ray, 100);
    assert_eq!(it.by_ref().count(), 8);
    assert_eq!(it.status(), TraversalStatus::Finished);
    // Truncated words (the last leaf records are those of the +x+y+z corner).
    let words = &index.words()[..index.words().len() - 20];
    let mut it = traverse(words, Ray::new(Vec3::new(-1.0, 0.9, 0.9), Vec3::X), 100);
    let _ = it.by_ref().count();
    assert_eq!(it.status(), TraversalStatus::Corrupt);
    // Garbage words never panic and never loop forever.
    let mut rng = Rng(99);
    for _ in 0..2000 {
        let mut words = index.words().to_vec();
        for _ in 0..1 + rng.below(8) {
            let i = rng.below(words.len() as u64) as usize;
            words[i] = rng.u64() as u32;
        }
        let r = Ray::new(
            Vec3::new(
                rng.range(-1.0, 2.0) as f32,
                rng.range(-1.0, 2.0) as f32,
                -1.0,
            ),
            random_dir(&mut rng),
        );
        let mut it = traverse(&words, r, 1000);
        let n = it.by_ref().count();
        assert!(n <= 1000 && it.status() != TraversalStatus::Running);
    }
}

/// Throughput of the twin alone on a ~100k-leaf cut (informative; no bound).
#[test]
fn twin_throughput() {
    let mut cut = Vec::new();
    for (i, l) in common::uniform_cut(5).into_iter().enumerate() {
        if i % 3 == 0 {
            cut.extend(l.key.children().map(|c| CutLeaf::new(c, l.kind)));
        } else {
            cut.push(l);
        }
    }
    let index = encode_cut(cut).unwrap();
    let mut rng = Rng(5);
    let rays: Vec<Ray> = (0..20_000).map(|_| random_ray(&mut rng, 0)).collect();
    let t = std::time::Instant::now();
    let mut leaves = 0usize;
    for r in &rays {
        let mut it = traverse(index.words(), *r, 100_000);
        leaves += it.by_ref().count();
        assert_eq!(it.status(), TraversalStatus::Finished);
    }
    let s = t.elapsed().as_secs_f64();
    eprintln!(
        "twin: {} rays, {leaves} leaves in {:.1} ms ({:.0} ns/leaf)",
        rays.len(),
        s * 1e3,
        s * 1e9 / leaves.max(1) as f64
    );
}
