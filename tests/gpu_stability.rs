//! Regression tests of the stability suite's bounds
//! (`cargo run --release -p brickray-bench -- stability`, docs/stability-suite.md),
//! cases 1-3, 7 and 8 (cases 4-6: `tests/gpu_stability_geometry.rs`): each
//! renders a small version of one case (64 px, 64^3 volumes) on the device,
//! asserts the bound with a stated threshold against the f64 CPU reference,
//! and checks a guard: the same measure on a configuration known to be wrong
//! violates the threshold, so the test can fail.
//!
//! Hole: a leaf of the cut that wants data and has none (a GPU-free twin of
//! the renderer's planning counts them), or, at the finest level, a pixel at
//! most 2 (of 255, brightest RGB channel) where the reference is at least 24.
//! Thresholds are stated per test.

#[path = "stability_support.rs"]
mod support;

use support::*;

/// Sleeps before every brick read.
struct Slow(Arc<dyn BrickSource>, Duration);

impl BrickSource for Slow {
    fn layout(&self) -> &brickray::OctreeLayout {
        self.0.layout()
    }
    fn node(
        &self,
        key: brickray::NodeKey,
    ) -> Result<brickray::core::NodeInfo, brickray::core::BrickError> {
        self.0.node(key)
    }
    fn read_brick(
        &self,
        key: brickray::NodeKey,
        out: &mut [u8],
    ) -> Result<(), brickray::core::BrickError> {
        std::thread::sleep(self.1);
        self.0.read_brick(key, out)
    }
}

/// A GPU-free twin of the renderer's planning over the same source and
/// configuration; `plan` returns the cut's hole leaves: leaves wanting data
/// without it (`Empty(NotLoaded)`, `Empty(Failed)`, allocation failures) and a
/// cut that does not tile the octree cube.
struct Twin {
    m: brickray::cache::Streamer,
    placement: VolumeFrame,
    levels: u8,
}

impl Twin {
    fn new(
        source: Arc<dyn BrickSource>,
        frame: VolumeFrame,
        config: OutOfCoreConfig,
        preload: bool,
    ) -> Twin {
        let layout = source.layout().clone();
        let caps = brickray::core::TexelCaps {
            norm16: true,
            float32_filterable: false,
        };
        let gpu = brickray::cache::GpuFormat::for_layout(
            &layout,
            caps,
            brickray::U8Filtering::Exact,
            32,
            2048,
        );
        let mut m = brickray::cache::Streamer::new(source, config, gpu).unwrap();
        if preload {
            m.preload_root().unwrap();
        }
        Twin {
            m,
            placement: frame,
            levels: layout.levels,
        }
    }

    fn plan(&mut self, cam: &Camera, tf: &TransferFunction) -> u64 {
        use brickray::cache::{EmptyReason, LeafKind};
        let views = [brickray::core::FrameView::new(
            *cam,
            self.placement,
            [SIZE, SIZE],
        )];
        let plan = self.m.plan(&brickray::cache::StreamFrame {
            views: &views,
            classification: brickray::cache::Classification {
                mode: RenderMode::Dvr,
                tf,
                channels: &[],
                tf_generation: 0,
            },
            feedback: &[],
            time: None,
        });
        let mut holes = plan.stats.cache.allocation_failures as u64;
        let mut covered = 0u128;
        for leaf in &plan.cut {
            covered += 1u128 << (3 * (self.levels - 1 - leaf.key.level) as u32);
            if matches!(
                leaf.kind,
                LeafKind::Empty(EmptyReason::NotLoaded | EmptyReason::Failed)
            ) {
                holes += 1;
            }
        }
        holes + u64::from(covered != 1u128 << (3 * (self.levels - 1) as u32))
    }
}

/// Case 1. Threshold: 0 hole leaves in every cut planned over a source that
/// sleeps 3 ms per brick read with a 1 MiB pool (the CPU twin of the
/// renderer's planning), from a cold start and after a jump, while the
/// renderer draws the same frames without error. Guard: the twin without the
/// root preloaded (what the renderer does at set-up) counts a hole in its
/// first cut.
#[test]
fn streaming_with_a_tiny_pool_and_a_slow_source_shows_no_holes() {
    let (_, src) = noise(DIM, 16);
    let frame = frame_of(DIM);
    let tf = noise_tf();
    let st = RenderSettings::default();
    let c = frame.center();
    let views = [
        Camera::orbit(c, 1.8, 0.5, 0.3),
        Camera::orbit(c + Vec3::new(-0.2, 0.15, -0.2), 0.6, 2.5, -0.2),
    ];
    let slow = |s: &Arc<ProceduralSource>| {
        Arc::new(Slow(
            s.clone() as Arc<dyn BrickSource>,
            Duration::from_millis(3),
        ))
    };
    let config = OutOfCoreConfig {
        gpu_budget_bytes: 1 << 20,
        ..Default::default()
    };
    let mut r = ooc(slow(&src), config, &tf);
    let mut twin = Twin::new(slow(&src), frame, config, true);
    for cam in views {
        for i in 0..15 {
            draw(&mut r, cam, frame, st);
            let s = r.stats().out_of_core.unwrap();
            assert_eq!(
                s.cache.allocation_failures + s.cache.failed_needed,
                0,
                "frame {i}: {:?}",
                s.cache
            );
            assert_eq!(twin.plan(&cam, &tf), 0, "frame {i}: hole leaves in the cut");
            std::thread::sleep(Duration::from_millis(2));
        }
    }
    let mut cold = Twin::new(slow(&src), frame, config, false);
    assert!(
        cold.plan(&views[0], &tf) > 0,
        "guard: no hole counted without the root"
    );
}

/// Case 2. Threshold: with a pool of a quarter of what the view needs and
/// the camera circling (0.1 rad a frame), the summed frame-to-frame change is
/// at most 1.25x the reference's own, and no cut of the CPU twin has holes.
/// Guard: toggling between the finest and a coarse level every frame exceeds
/// 1.25x.
#[test]
fn memory_pressure_does_not_flicker() {
    let (vol, src) = noise(DIM, 16);
    let frame = frame_of(DIM);
    let tf = noise_tf();
    let st = RenderSettings::default();
    let cam = |i: usize| Camera::orbit(frame.center(), 1.4, 0.5 + 0.1 * i as f32, 0.3);
    let cfg = |gpu_budget_bytes| OutOfCoreConfig {
        gpu_budget_bytes,
        tolerance_px: 0.5,
        upload_budget_bytes: 1 << 30,
        ..Default::default()
    };
    let big = 64u64 << 20;
    // The slot's size under pressure (the big pool would keep gradients:
    // it holds every brick with them).
    let mut r = ooc_without_gradients(src.clone(), cfg(big), &tf);
    let (_, s) = converge(&mut r, cam(0), frame, st);
    let per_slot = s.cache.pool_slot_bytes;
    // A quarter of the need in slots (at least the 9 the cache requires).
    let need = s.cache.working_set_bricks as u64;
    let want = (need / 4).max(9);
    let budget = want * per_slot + per_slot / 2;
    let refs: Vec<Vec<u8>> = (0..10)
        .map(|i| reference(&vol, &frame, &tf, &cam(i), &st, 0.5))
        .collect();
    let change = |imgs: &[Vec<u8>]| -> f64 {
        (1..imgs.len())
            .map(|i| mean_abs_diff(&imgs[i], &imgs[i - 1]))
            .sum()
    };
    let ref_change = change(&refs);
    let mut r = ooc(src.clone(), cfg(budget), &tf);
    let (_, s) = converge(&mut r, cam(0), frame, st);
    eprintln!("need {need} bricks, pool {} slots", s.cache.pool_slots);
    assert!(
        s.cache.pool_slots as u64 <= want,
        "pool {} slots > {want}",
        s.cache.pool_slots
    );
    let mut twin = Twin::new(src.clone(), frame, cfg(budget), true);
    let imgs: Vec<Vec<u8>> = (0..10)
        .map(|i| {
            assert_eq!(twin.plan(&cam(i), &tf), 0, "frame {i}: hole leaves");
            draw(&mut r, cam(i), frame, st)
        })
        .collect();
    let flicker = change(&imgs) / ref_change;
    eprintln!("flicker ratio {flicker:.3}");
    assert!(flicker <= 1.25, "flicker ratio {flicker:.3} > 1.25");
    // Guard: a level toggled every frame.
    let mut g = ooc(src, cfg(big), &tf);
    let toggled: Vec<Vec<u8>> = (0..10)
        .map(|i| {
            brickray_harness::configure(gpu(), &g, |c| {
                c.tolerance_px = if i % 2 == 0 { 0.0 } else { 8.0 }
            })
            .unwrap();
            converge(&mut g, cam(i), frame, st).0
        })
        .collect();
    let bad = change(&toggled) / ref_change;
    assert!(
        bad > 1.25,
        "guard: toggling levels gives flicker ratio {bad:.3}"
    );
}

/// Case 3. A narrow opacity spike (0.8 at 0.5, zero 0.005 either side), in
/// core, against the reference at step 1/32. No practical step holds 30 dB on
/// this TF without pre-integration (measured at 64 px: 24.8 dB at 1/8, 16.3 dB
/// at the shipped 0.5). Thresholds: step 0.5 >= 15 dB, and each halving of
/// the step from 1 to 1/8 gains >= 3 dB (measured 3.4, 3.8, 4.7). Guard:
/// step 4 is below 15 dB.
#[test]
fn high_frequency_tf_converges_with_the_step() {
    const SHIPPED_DB: f64 = 15.0;
    const GAIN_DB: f64 = 3.0;
    let (vol, _) = noise(DIM, 32);
    let frame = frame_of(DIM);
    let tf = TransferFunction::from_points(
        &[
            (0.495, [1.0, 0.9, 0.6, 0.0]),
            (0.5, [1.0, 0.9, 0.6, 0.8]),
            (0.505, [1.0, 0.9, 0.6, 0.0]),
        ],
        1024,
    );
    let cam = Camera::orbit(frame.center(), 1.8, 0.5, 0.3);
    let st = |step_factor| RenderSettings {
        step_factor,
        ..Default::default()
    };
    let reference = reference(&vol, &frame, &tf, &cam, &st(0.5), 1.0 / 32.0);
    let mut r = incore(&vol, &tf);
    let mut db = |s: f32| psnr(&draw(&mut r, cam, frame, st(s)), &reference);
    let steps = [1.0f32, 0.5, 0.25, 0.125];
    let p: Vec<f64> = steps.iter().map(|&s| db(s)).collect();
    let coarse = db(4.0);
    eprintln!("spike TF, steps {steps:?}: {p:.2?} dB; step 4: {coarse:.2} dB");
    assert!(
        p[1] >= SHIPPED_DB,
        "step 0.5: {:.2} dB < {SHIPPED_DB}",
        p[1]
    );
    for i in 1..p.len() {
        assert!(
            p[i] - p[i - 1] >= GAIN_DB,
            "step {} gains {:.2} dB < {GAIN_DB}",
            steps[i],
            p[i] - p[i - 1]
        );
    }
    assert!(coarse < SHIPPED_DB, "guard: step 4 gives {coarse:.2} dB");
}

/// Case 7. Threshold: with early termination at t, no 8-bit channel differs
/// from the unterminated image by more than (1 - t) * 255 + 1 levels, for t of
/// 0.9, 0.99 and 0.999, on a translucent TF; and, with the residual filled as
/// the ray's material so far would fill it to the ray's end
/// (docs/rendering-model.md, *Accelerations*), the 0.9, 0.99 and 0.999
/// images are at least 37.5, 57 and 72 dB from the unterminated one
/// (measured 39.33, 58.45 and 73.58; with the residual filled whole with the
/// last sample's colour 35.48, 54.73 and 69.73; dropped 27.64 and 50.57 at
/// 0.9 and 0.99).
/// Guard: the 0.9 image exceeds the bound of 0.999.
#[test]
fn early_termination_error_stays_within_its_bound() {
    let (vol, _) = noise(DIM, 32);
    let frame = frame_of(DIM);
    let tf = noise_tf();
    let cam = Camera::orbit(frame.center(), 1.8, 0.5, 0.3);
    let st = |t: Option<f32>| RenderSettings {
        accel: Accel {
            early_termination: t,
            ..Accel::default()
        },
        ..Default::default()
    };
    let mut r = incore(&vol, &tf);
    let full = draw(&mut r, cam, frame, st(None));
    let bound = |t: f32| (1.0 - t as f64) * 255.0 + 1.0;
    let (mut errs, mut dbs) = (Vec::new(), Vec::new());
    for t in [0.9f32, 0.99, 0.999] {
        let img = draw(&mut r, cam, frame, st(Some(t)));
        let e = max_abs_diff(&img, &full) as f64;
        eprintln!(
            "ERT {t}: max error {e} (bound {:.1}), {:.2} dB",
            bound(t),
            psnr(&img, &full)
        );
        assert!(e <= bound(t), "ERT {t}: {e} > {:.1}", bound(t));
        errs.push(e);
        dbs.push(psnr(&img, &full));
    }
    assert!(dbs[0] >= 37.5, "ERT 0.9: {:.2} dB < 37.5", dbs[0]);
    assert!(dbs[1] >= 57.0, "ERT 0.99: {:.2} dB < 57", dbs[1]);
    assert!(dbs[2] >= 72.0, "ERT 0.999: {:.2} dB < 72", dbs[2]);
    assert!(
        errs[0] > bound(0.999),
        "guard: ERT 0.9 differs by only {}",
        errs[0]
    );
}

/// Case 8. The visibility suite's shells (64^3, bricks 16, finest level),
/// converged, then a half turn in 12 frames. Threshold: ray-guided culling is
/// within 0.5 dB (PSNR vs the reference of the frame's camera) of no culling
/// at most 10 frames after the back view is reached, and no frame has holes.
/// Guard: the back view's image scored against the start view's reference is
/// more than 0.5 dB below.
#[test]
fn ray_guided_culling_recovers_after_a_half_turn() {
    let src = Arc::new(ProceduralSource::sphere_shells([DIM; 3], 16, 2).unwrap());
    let vol = region(&src, [0; 3], DIM);
    let frame = frame_of(DIM);
    let tf = TransferFunction::from_points(
        &[(0.15, [0.9, 0.8, 0.7, 0.0]), (0.22, [0.9, 0.8, 0.7, 1.0])],
        256,
    );
    let st = RenderSettings::default();
    let cam = |k: usize| {
        Camera::orbit(
            frame.center(),
            1.8,
            0.5 + std::f32::consts::PI * k as f32 / 12.0,
            0.3,
        )
    };
    let config = OutOfCoreConfig {
        tolerance_px: 0.0,
        upload_budget_bytes: 1 << 30,
        ..Default::default()
    };
    let mut rs: Vec<VolumeRenderer> = [
        brickray::VisibilityPolicy::None,
        brickray::VisibilityPolicy::RayGuided,
    ]
    .into_iter()
    .map(|p| {
        let mut r = ooc(src.clone(), config, &tf);
        brickray_harness::configure(gpu(), &r, |c| c.visibility = p).unwrap();
        converge(&mut r, cam(0), frame, st);
        r
    })
    .collect();
    let refs: Vec<Vec<u8>> = (0..=12)
        .map(|k| reference(&vol, &frame, &tf, &cam(k), &st, 0.5))
        .collect();
    let mut recovered = None;
    let mut last = Vec::new();
    for f in 0..24 {
        let k = (f + 1).min(12);
        let imgs: Vec<Vec<u8>> = rs.iter_mut().map(|r| draw(r, cam(k), frame, st)).collect();
        for img in &imgs {
            assert_eq!(holes(img, &refs[k]), 0, "frame {f}: holes");
        }
        let (p0, p1) = (psnr(&imgs[0], &refs[k]), psnr(&imgs[1], &refs[k]));
        if f >= 11 && recovered.is_none() && p1 >= p0 - 0.5 {
            recovered = Some(f - 11);
        }
        last = imgs;
    }
    eprintln!("ray-guided recovered {recovered:?} frames after the back view");
    assert!(
        recovered.is_some_and(|r| r <= 10),
        "recovery {recovered:?} > 10 frames"
    );
    let good = psnr(&last[1], &refs[12]);
    let wrong = psnr(&last[1], &refs[0]);
    assert!(
        wrong < good - 0.5,
        "guard: the wrong reference scores {wrong:.2} vs {good:.2} dB"
    );
}
