//! The walk the out-of-core ray caster takes (`Traversal::inside`, WGSL
//! `oct_begin_inside`) starts and ends where the ray caster's own clip put the
//! ray, also where the volume's box shares a face with the octree cube.
//!
//! The ray caster clips each ray to the volume's box in texture space (f32
//! divisions, `clip_box` in the render crate's common.wgsl) and samples from
//! that `t0` on; it walks the index on the same ray scaled to octree
//! coordinates. A second clip, to the cube, computed the entry through a shared
//! face another way and rounded above `t0` on many rays: the first leaf's
//! `t_enter > t0` made the first sample's index 1, and that sample was lost.

mod common;

use brickray_index::{LeafHit, Ray, Splits, Traversal, encode_cut, traverse_with};
use common::{Rng, random_cut};
use glam::Vec3;

/// The ray caster's clip to the box `[lo, hi]` (common.wgsl `clip_box`, then
/// `t0 = max(t0, 0)`), in f32 as on the GPU.
fn clip_box(o: Vec3, d: Vec3, lo: Vec3, hi: Vec3) -> (f32, f32) {
    let mut t0 = -3.0e38f32;
    let mut t1 = 3.0e38f32;
    for a in 0..3 {
        if d[a].abs() < 1e-30 {
            if o[a] < lo[a] || o[a] > hi[a] {
                return (1.0, 0.0);
            }
        } else {
            let ta = (lo[a] - o[a]) / d[a];
            let tb = (hi[a] - o[a]) / d[a];
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
    }
    (t0.max(0.0), t1)
}

/// Volumes in their octree cube: `dims / cube side` per axis (the octree
/// coordinate of texture coordinate 1). Each shares some faces with the cube:
/// 64^3 all six, the head CT (256 x 256 x 108 in 256) five, the chest CT of
/// the report (512 x 512 x 61 in 512) five, 64 x 32 x 64 five.
const SCALES: [[f32; 3]; 4] = [
    [1.0, 1.0, 1.0],
    [1.0, 1.0, 108.0 / 256.0],
    [1.0, 1.0, 61.0 / 512.0],
    [1.0, 0.5, 1.0],
];

/// A ray as the ray caster makes it: an eye around the box (texture space,
/// 1-3 box sizes from its centre), aimed at a random point of the box or
/// just outside it, with a direction of random length.
fn camera_ray(rng: &mut Rng) -> (Vec3, Vec3) {
    let u = Vec3::new(
        rng.range(-1.0, 1.0) as f32,
        rng.range(-1.0, 1.0) as f32,
        rng.range(-1.0, 1.0) as f32,
    );
    let eye = Vec3::splat(0.5) + u.normalize_or(Vec3::X) * rng.range(1.0, 3.0) as f32;
    let aim = Vec3::new(
        rng.range(-0.05, 1.05) as f32,
        rng.range(-0.05, 1.05) as f32,
        rng.range(-0.05, 1.05) as f32,
    );
    let d = (aim - eye).normalize() * rng.range(0.1, 4.0) as f32;
    (eye, d)
}

/// The leaves of the walk over `[t0, t1]` on the ray scaled to octree
/// coordinates, as the out-of-core kernel walks them.
fn walk(words: &[u32], o: Vec3, d: Vec3, t0: f32, t1: f32) -> Vec<LeafHit> {
    let ray = Ray::new(o, d).with_range(t0, t1);
    Traversal::inside(words, Splits::ALL, ray, 4096).collect()
}

#[derive(Debug, Default)]
struct Counts {
    rays: u64,
    /// Rays whose clipped walk (`traverse_with`, what the kernel used before)
    /// entered after `t0` (lost the first sample) or left before `t1`.
    clipped_late: u64,
    clipped_early: u64,
}

#[test]
fn inside_walk_starts_at_t0_and_ends_at_t1_on_shared_faces() {
    let mut rng = Rng(35);
    let mut counts = Counts::default();
    for case in 0..24u64 {
        let cut = random_cut(&mut rng, 4, 0.5, 0.8, 2000);
        let index = encode_cut(cut.iter().copied()).unwrap();
        let scale = Vec3::from(SCALES[case as usize % SCALES.len()]);
        for _ in 0..4000 {
            let (o, d) = camera_ray(&mut rng);
            let (t0, t1) = clip_box(o, d, Vec3::ZERO, Vec3::ONE);
            let hit = t1 > t0;
            if !hit {
                continue;
            }
            counts.rays += 1;
            let (oo, od) = (o * scale, d * scale);
            let hits = walk(index.words(), oo, od, t0, t1);
            let ctx = || format!("case {case}, o {o:?}, d {d:?}, t {t0}..{t1}, scale {scale:?}");
            assert!(!hits.is_empty(), "no leaf: {}", ctx());
            assert_eq!(hits[0].t_enter, t0, "first leaf entered late: {}", ctx());
            assert_eq!(
                hits[hits.len() - 1].t_exit,
                t1,
                "last leaf left early: {}",
                ctx()
            );
            for w in hits.windows(2) {
                assert_eq!(w[0].t_exit, w[1].t_enter, "gap: {}", ctx());
            }
            // The first sample (index k = ceil((t_enter - t0) / dt), as
            // ooc.wgsl computes it) is sample 0 at every step.
            for dt in [1e-3f32, 0.5 / 256.0, 0.01] {
                assert_eq!(((hits[0].t_enter - t0) / dt).ceil(), 0.0, "{}", ctx());
            }
            // Before the fix: the walk clipped to the cube again.
            let clipped: Vec<LeafHit> = traverse_with(
                index.words(),
                Splits::ALL,
                Ray::new(oo, od).with_range(t0, t1),
                4096,
            )
            .collect();
            if clipped.first().is_none_or(|h| h.t_enter > t0) {
                counts.clipped_late += 1;
            }
            if clipped.last().is_none_or(|h| h.t_exit < t1) {
                counts.clipped_early += 1;
            }
            // The same leaves as the clipped walk, in the same order (up to
            // a sliver at either end that rounding gives one walk only).
            let keys = |h: &[LeafHit]| h.iter().map(|h| (h.key(), h.slot)).collect::<Vec<_>>();
            let (a, b) = (keys(&hits), keys(&clipped));
            let sliver = |h: &LeafHit| h.t_exit - h.t_enter <= 1e-5 * h.t_exit.abs().max(1.0);
            let a_trim = trim(&a, &hits, &sliver);
            let b_trim = trim(&b, &clipped, &sliver);
            assert_eq!(
                a_trim,
                b_trim,
                "other leaves than the clipped walk: {}",
                ctx()
            );
        }
    }
    eprintln!("{counts:?}");
    assert!(counts.rays >= 50_000, "only {} rays", counts.rays);
}

/// `keys` less a first or last entry whose segment is a sliver.
fn trim<T: Clone>(keys: &[T], hits: &[LeafHit], sliver: &dyn Fn(&LeafHit) -> bool) -> Vec<T> {
    let mut lo = 0;
    let mut hi = keys.len();
    if hi > lo && sliver(&hits[lo]) {
        lo += 1;
    }
    if hi > lo && sliver(&hits[hi - 1]) {
        hi -= 1;
    }
    keys[lo..hi].to_vec()
}

/// A segment past the cube by rounding (its end on the cube's face as the
/// caller computed it) still ends at the caller's `t_max`: a NULL rope ends
/// the walk at `t_end`. A segment off the cube by rounding at its start is
/// located in the leaf at that face.
#[test]
fn inside_walk_keeps_ends_past_the_cube_by_rounding() {
    let cut = common::uniform_cut(2);
    let index = encode_cut(cut.iter().copied()).unwrap();
    let o = Vec3::new(-0.5, 0.3, 0.7);
    let d = Vec3::new(1.0, 0.01, -0.02);
    // The cube spans t in [0.5, 1.5]; the caller's segment is a few ulps wider.
    let (t0, t1) = (0.5f32.next_down().next_down(), 1.5f32.next_up().next_up());
    let hits = walk(index.words(), o, d, t0, t1);
    assert_eq!(hits.len(), 4, "{hits:?}");
    assert_eq!((hits[0].t_enter, hits[3].t_exit), (t0, t1));
    assert_eq!(hits[0].leaf.box_min.x, 0.0);
    assert_eq!(hits[3].leaf.box_min.x, 0.75);
    // Clipped to the cube, the same walk starts and ends on the cube's faces.
    let clipped: Vec<LeafHit> = traverse_with(
        index.words(),
        Splits::ALL,
        Ray::new(o, d).with_range(t0, t1),
        64,
    )
    .collect();
    assert_eq!((clipped[0].t_enter, clipped[3].t_exit), (0.5, 1.5));
    // Empty and reversed segments walk nothing.
    assert!(walk(index.words(), o, d, 1.0, 1.0).is_empty());
    assert!(walk(index.words(), o, d, 1.2, 0.8).is_empty());
    assert!(walk(index.words(), o, d, f32::NAN, 1.0).is_empty());
}
