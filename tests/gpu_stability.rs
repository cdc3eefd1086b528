//! Regression tests of the stability suite's bounds
//! (`cargo run --release -p brickray-bench -- stability`, docs/stability-suite.md):
//! each renders a small version of one case (64 px, 64^3 volumes) on the
//! device, asserts the bound with a stated threshold against the f64 CPU
//! reference, and checks a guard: the same measure on a configuration known
//! to be wrong violates the threshold, so the test can fail.
//!
//! Hole: a pixel at most 2 (of 255, brightest RGB channel) where the reference
//! is at least 24. Thresholds are stated per test.

use brickray::store::ProceduralSource;
use brickray::{
    Accel, BrickSource, Camera, ClipBox, DepthConvention, FrameDesc, OutOfCoreConfig,
    OutOfCoreStats, Projection, RenderMode, RenderSettings, TransferFunction, Volume, VolumeFrame,
    VolumeRenderer,
};
use brickray_harness::{Offscreen, shared_gpu as gpu, target_desc as targets};
use brickray_reference::{ReferenceOptions, max_abs_diff, psnr, render_reference};
use glam::Vec3;
use std::sync::Arc;
use std::time::Duration;

const SIZE: u32 = 64;
const DIM: u64 = 64;

fn noise(dims: u64, brick: u32) -> (Volume, Arc<ProceduralSource>) {
    let src = ProceduralSource::fractal_noise([dims; 3], brick, 2).unwrap();
    let vol = region(&src, [0; 3], dims);
    (vol, Arc::new(src))
}

fn region(src: &ProceduralSource, lo: [u64; 3], n: u64) -> Volume {
    let finest = src.layout().levels - 1;
    let data = src.region(finest, lo, lo.map(|c| c + n - 1)).unwrap();
    u8_volume(n as u32, data)
}

fn u8_volume(n: u32, data: Vec<u8>) -> Volume {
    Volume::new(
        brickray::VolumeDesc {
            dims: [n; 3],
            dtype: brickray::DType::U8,
            spacing: [1.0; 3],
            value_range: [0.0, 255.0],
        },
        brickray::core::VolumeData::U8(data),
    )
    .unwrap()
}

fn noise_tf() -> TransferFunction {
    TransferFunction::from_points(
        &[(0.45, [0.2, 0.5, 1.0, 0.0]), (0.7, [1.0, 0.8, 0.5, 0.3])],
        256,
    )
}

fn frame_of(n: u64) -> VolumeFrame {
    VolumeFrame::centered([n as u32; 3], [1.0; 3])
}

fn reference(
    vol: &Volume,
    frame: &VolumeFrame,
    tf: &TransferFunction,
    cam: &Camera,
    st: &RenderSettings,
    step: f32,
) -> Vec<u8> {
    let opts = ReferenceOptions::new(SIZE, SIZE).with_step_factor(step);
    render_reference(vol, frame, tf, cam, st, &opts).to_rgba8([0.0; 3])
}

fn draw(r: &mut VolumeRenderer, cam: Camera, frame: VolumeFrame, st: RenderSettings) -> Vec<u8> {
    let g = gpu();
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let desc = FrameDesc {
        camera: cam,
        frame,
        viewport: brickray::Viewport::full(SIZE, SIZE),
        settings: st,
        host_depth: None,
    };
    brickray_harness::draw_frame(g, r, &target, &desc, Some(brickray::wgpu::Color::BLACK))
        .expect("frame");
    target.read_color(g)
}

fn converge(
    r: &mut VolumeRenderer,
    cam: Camera,
    frame: VolumeFrame,
    st: RenderSettings,
) -> (Vec<u8>, OutOfCoreStats) {
    for _ in 0..150 {
        let img = draw(r, cam, frame, st);
        let s = r.out_of_core_stats().unwrap();
        if s.converged {
            return (img, s);
        }
        std::thread::sleep(Duration::from_millis(3));
    }
    panic!("not converged: {:?}", r.out_of_core_stats());
}

fn incore(vol: &Volume, tf: &TransferFunction) -> VolumeRenderer {
    let g = gpu();
    let mut r = VolumeRenderer::new(&g.device, targets()).unwrap();
    r.set_volume(&g.device, &g.queue, vol).unwrap();
    r.set_transfer_function(&g.device, &g.queue, tf).unwrap();
    r
}

fn ooc(
    source: Arc<dyn BrickSource>,
    frame: VolumeFrame,
    config: OutOfCoreConfig,
    tf: &TransferFunction,
) -> VolumeRenderer {
    let g = gpu();
    let mut r = VolumeRenderer::new(&g.device, targets()).unwrap();
    r.set_volume_source(&g.device, &g.queue, source, frame, config)
        .unwrap();
    r.set_transfer_function(&g.device, &g.queue, tf).unwrap();
    r
}

fn peak(p: &[u8]) -> u8 {
    p[0].max(p[1]).max(p[2])
}

fn holes(img: &[u8], reference: &[u8]) -> usize {
    img.chunks_exact(4)
        .zip(reference.chunks_exact(4))
        .filter(|(a, b)| peak(b) >= 24 && peak(a) <= 2)
        .count()
}

fn mean_abs_diff(a: &[u8], b: &[u8]) -> f64 {
    let s: u64 = a
        .chunks_exact(4)
        .zip(b.chunks_exact(4))
        .map(|(p, q)| (0..3).map(|c| p[c].abs_diff(q[c]) as u64).sum::<u64>())
        .sum();
    s as f64 / (3 * a.len() / 4) as f64
}

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
    m: brickray::cache::BrickManager,
    frame: u64,
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
        let mut m = brickray::cache::BrickManager::new(source, frame, config, gpu).unwrap();
        if preload {
            m.preload_root().unwrap();
        }
        Twin {
            m,
            frame: 0,
            levels: layout.levels,
        }
    }

    fn plan(&mut self, cam: &Camera, tf: &TransferFunction) -> u64 {
        use brickray::cache::{EmptyReason, LeafKind};
        self.frame += 1;
        let plan = self
            .m
            .update(cam, 1.0, SIZE, self.frame, RenderMode::Dvr, tf);
        let mut holes = plan.stats.allocation_failures as u64;
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
    let mut r = ooc(slow(&src), frame, config, &tf);
    let mut twin = Twin::new(slow(&src), frame, config, true);
    for cam in views {
        for i in 0..15 {
            draw(&mut r, cam, frame, st);
            let s = r.out_of_core_stats().unwrap();
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
    let mut r = ooc(src.clone(), frame, cfg(big), &tf);
    let (_, s) = converge(&mut r, cam(0), frame, st);
    let per_slot = big / s.cache.pool_slots as u64;
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
    let mut r = ooc(src.clone(), frame, cfg(budget), &tf);
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
    let mut g = ooc(src, frame, cfg(big), &tf);
    let toggled: Vec<Vec<u8>> = (0..10)
        .map(|i| {
            g.set_lod_tolerance(if i % 2 == 0 { 0.0 } else { 8.0 })
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

/// The thin-structures volume of the bench (case 4) at 64^3.
fn thin_volume(n: u32) -> Volume {
    let nn = n as usize;
    let mut data = vec![0u8; nn * nn * nn];
    let idx = |x: usize, y: usize, z: usize| (z * nn + y) * nn + x;
    let f = |k: f32| ((n as f32 * k) as usize).min(nn - 1);
    for a in f(0.125)..f(0.875) {
        for b in f(0.125)..f(0.875) {
            data[idx(f(0.3125), a, b)] = 200;
        }
        data[idx(f(0.75), a, f(0.5))] = 220;
        data[idx(f(0.5), f(0.25), a)] = 220;
    }
    for x in [0.44, 0.53, 0.63] {
        for y in [0.31, 0.5, 0.69] {
            for z in [0.19, 0.34, 0.81] {
                data[idx(f(x), f(y), f(z))] = 255;
            }
        }
    }
    u8_volume(n, data)
}

fn ortho(c: Vec3, dir: Vec3, height: f32) -> Camera {
    Camera {
        eye: c + dir.normalize() * 2.0,
        target: c,
        up: Vec3::Y,
        projection: Projection::Orthographic { height },
        near: 0.01,
        far: 10.0,
        depth: DepthConvention::Standard,
    }
}

fn retention(img: &[u8], reference: &[u8]) -> f64 {
    let (mut kept, mut all) = (0.0, 0.0);
    for (a, b) in img.chunks_exact(4).zip(reference.chunks_exact(4)) {
        let r = peak(b) as f64;
        if r >= 64.0 {
            kept += (peak(a) as f64).min(r);
            all += r;
        }
    }
    kept / all
}

/// Case 4. MIP of one-voxel features, one level below the finest (tolerance 2
/// px, a finest voxel projects to 0.83 px). Threshold: a store built with
/// `Filter::Max` keeps >= 0.9 of the features' brightness. Guard: the default
/// `Filter::Average` keeps less than 0.9 (the failure the max filter fixes).
#[test]
fn max_filter_keeps_small_bright_features_in_coarse_mip() {
    let vol = thin_volume(DIM as u32);
    let frame = frame_of(DIM);
    let tf = TransferFunction::ramp(0.0, 1.0, 1.0);
    let st = RenderSettings {
        mode: RenderMode::Mip,
        ..Default::default()
    };
    let cam = ortho(frame.center(), Vec3::new(0.5, 0.3, 1.0), 1.2);
    let reference = reference(&vol, &frame, &tf, &cam, &st, 0.5);
    let dir = tempfile::tempdir().unwrap();
    let mut kept = Vec::new();
    for (name, filter) in [
        ("average", brickray::store::Filter::Average),
        ("max", brickray::store::Filter::Max),
    ] {
        let path = dir.path().join(format!("{name}.brs"));
        let mut reader = brickray::io::MemoryReader::new(vol.clone(), "thin");
        let opts = brickray::store::BuildOptions {
            brick: 16,
            filter,
            ..Default::default()
        };
        brickray::store::build(&mut reader, &path, &opts).unwrap();
        let source: Arc<dyn BrickSource> = Arc::new(brickray::store::open(&path).unwrap());
        let finest = source.layout().levels as usize - 1;
        let config = OutOfCoreConfig {
            tolerance_px: 2.0,
            upload_budget_bytes: 1 << 30,
            ..Default::default()
        };
        let mut r = ooc(source, frame, config, &tf);
        let (img, s) = converge(&mut r, cam, frame, st);
        assert!(
            s.data_leaves_per_level[finest] == 0 && s.data_leaves_per_level[finest - 1] > 0,
            "{name}: the cut should be one level coarser: {:?}",
            s.data_leaves_per_level
        );
        let k = retention(&img, &reference);
        eprintln!("MIP one level coarser, {name} filter: retention {k:.3}");
        kept.push(k);
    }
    assert!(kept[1] >= 0.9, "max filter keeps {:.3} < 0.9", kept[1]);
    assert!(
        kept[0] < 0.9,
        "guard: the average filter keeps {:.3}",
        kept[0]
    );
}

/// Case 5. An orthographic view down -z, shifted half a pixel, so that every
/// ray lies exactly on a voxel face in x and y, and every 16th column on a
/// brick face. Thresholds, out of core at the finest level: 0 holes, PSNR >=
/// 40 dB, and the brick-face columns' mean error at most 1.5x (+1 level) the
/// other columns'. Guard: the same image with its face columns darkened by 30
/// levels exceeds 1.5x.
#[test]
fn rays_exactly_on_brick_faces_show_no_seams() {
    let (vol, src) = noise(DIM, 16);
    let frame = frame_of(DIM);
    let tf = noise_tf();
    let st = RenderSettings::default();
    let half = 0.5 / SIZE as f32;
    let cam = ortho(Vec3::new(-half, -half, 0.0), Vec3::Z, 1.0);
    let reference = reference(&vol, &frame, &tf, &cam, &st, 0.5);
    let config = OutOfCoreConfig {
        tolerance_px: 0.0,
        upload_budget_bytes: 1 << 30,
        ..Default::default()
    };
    let mut r = ooc(src, frame, config, &tf);
    let (img, _) = converge(&mut r, cam, frame, st);
    let seam = |img: &[u8]| {
        let (mut on, mut n_on, mut off, mut n_off) = (0.0, 0.0, 0.0, 0.0);
        for (i, (a, b)) in img
            .chunks_exact(4)
            .zip(reference.chunks_exact(4))
            .enumerate()
        {
            let e = (0..3).map(|c| a[c].abs_diff(b[c]) as f64).sum::<f64>() / 3.0;
            if (i % SIZE as usize).is_multiple_of(16) {
                on += e;
                n_on += 1.0;
            } else {
                off += e;
                n_off += 1.0;
            }
        }
        (on / n_on + 1.0) / (off / n_off + 1.0)
    };
    let (h, p, s) = (holes(&img, &reference), psnr(&img, &reference), seam(&img));
    eprintln!("rays on brick faces: {h} holes, {p:.2} dB, seam ratio {s:.2}");
    assert_eq!(h, 0, "holes");
    assert!(p >= 40.0, "{p:.2} dB < 40");
    assert!(s <= 1.5, "seam ratio {s:.2} > 1.5");
    let mut bad = img.clone();
    for (i, px) in bad.chunks_exact_mut(4).enumerate() {
        if (i % SIZE as usize).is_multiple_of(16) {
            for c in &mut px[..3] {
                *c = c.saturating_sub(30);
            }
        }
    }
    assert!(
        seam(&bad) > 1.5,
        "guard: a darkened face column reads {:.2}",
        seam(&bad)
    );
}

/// Case 5, iso. In core, iso 0.6: the view with every ray exactly on voxel
/// faces scores at most 5 dB below the same view a quarter pixel off (each
/// against its own reference; measured 4.72 dB here, 4.57 dB at 128 px in
/// the bench: a tight bound that a further loss on the faces breaks).
/// Guard: the on-face image scored against the off-face reference (a quarter
/// pixel of misalignment) is more than 5 dB below.
#[test]
fn iso_with_rays_exactly_on_voxel_faces_stays_near_the_off_face_view() {
    let (vol, _) = noise(DIM, 16);
    let frame = frame_of(DIM);
    let tf = noise_tf();
    let st = RenderSettings {
        mode: RenderMode::Iso {
            value: 0.6,
            color: [0.9, 0.85, 0.75],
        },
        ..Default::default()
    };
    let half = 0.5 / SIZE as f32;
    let q = 0.25 / SIZE as f32;
    let on = ortho(Vec3::new(-half, -half, 0.0), Vec3::Z, 1.0);
    let off = ortho(Vec3::new(-half + q, -half + q, 0.0), Vec3::Z, 1.0);
    let mut r = incore(&vol, &tf);
    let ref_on = reference(&vol, &frame, &tf, &on, &st, 0.5);
    let ref_off = reference(&vol, &frame, &tf, &off, &st, 0.5);
    let img_on = draw(&mut r, on, frame, st);
    let img_off = draw(&mut r, off, frame, st);
    let (p_on, p_off) = (psnr(&img_on, &ref_on), psnr(&img_off, &ref_off));
    eprintln!("iso on the faces {p_on:.2} dB, a quarter pixel off {p_off:.2} dB");
    assert!(
        p_off - p_on <= 5.0,
        "on the faces {p_on:.2} dB, off {p_off:.2} dB"
    );
    let wrong = psnr(&img_on, &ref_off);
    assert!(
        p_off - wrong > 5.0,
        "guard: misaligned reference scores {wrong:.2} dB"
    );
}

/// Case 6. A 65536^3 procedural volume, a 60^3 box of finest voxels 8 voxels
/// from the far corner clipped out and seen from 40 voxels; the reference
/// renders the box alone in f64; the control is the same scene at unit scale
/// (the box as a 64^3 volume, the camera scaled by 1024) in core. DVR with an
/// opacity ramp over the box's own values. Threshold: the 65536^3 image is at
/// most 1 dB below the control's PSNR (measured: 0.01 dB). Guard: the
/// reference of a camera moved by one voxel is more than 1 dB further off.
#[test]
fn finest_voxels_of_a_65536_cubed_volume_match_the_reference() {
    const D: u64 = 65536;
    const N: u64 = 64;
    let src = Arc::new(ProceduralSource::fractal_noise([D; 3], 32, 2).unwrap());
    let big = frame_of(D);
    let lo = D - N - 8;
    let sub = region(&src, [lo; 3], N);
    let off = (lo as f64 / D as f64 - 0.5) as f32;
    let scale = (N as f64 / D as f64) as f32;
    let sub_frame = VolumeFrame::new(
        glam::Mat4::from_translation(Vec3::splat(off)) * glam::Mat4::from_scale(Vec3::splat(scale)),
        [N as u32; 3],
    );
    let unit = frame_of(N);
    let sub_clip = ClipBox {
        min: [2.0 / 64.0; 3],
        max: [62.0 / 64.0; 3],
    };
    let big_clip = ClipBox {
        min: [((lo + 2) as f64 / D as f64) as f32; 3],
        max: [((lo + 62) as f64 / D as f64) as f32; 3],
    };
    let vx = (1.0 / D as f64) as f32;
    let centre = Vec3::splat(off + scale * 0.5);
    let cam = Camera {
        near: 2.0 * vx,
        far: 400.0 * vx,
        ..Camera::orbit(centre, 40.0 * vx, 0.6, 0.35)
    };
    let to_unit =
        |p: Vec3| ((p.as_dvec3() - off as f64) / scale as f64 - glam::DVec3::splat(0.5)).as_vec3();
    let ucam = Camera {
        eye: to_unit(cam.eye),
        target: to_unit(cam.target),
        near: cam.near / scale,
        far: cam.far / scale,
        ..cam
    };
    // Opacity over the box's own values (0 at 35% of its range, 0.4 at 75%).
    let (a, b) = sub.data().min_max().unwrap();
    let at = |k: f32| (a + k * (b - a)) / 255.0;
    let tf = TransferFunction::from_points(
        &[
            (at(0.35), [0.2, 0.5, 1.0, 0.0]),
            (at(0.75), [1.0, 0.8, 0.5, 0.4]),
        ],
        256,
    );
    let st_big = RenderSettings {
        clip: big_clip,
        ..Default::default()
    };
    let st_sub = RenderSettings {
        clip: sub_clip,
        ..st_big
    };
    let reference = reference(&sub, &sub_frame, &tf, &cam, &st_sub, 0.5);
    let ref_unit = reference_unit(&sub, &unit, &tf, &ucam, &st_sub);
    let config = OutOfCoreConfig {
        upload_budget_bytes: 1 << 30,
        ..Default::default()
    };
    let mut r = ooc(src, big, config, &tf);
    let (img, _) = converge(&mut r, cam, big, st_big);
    let mut inc = incore(&sub, &tf);
    let uimg = draw(&mut inc, ucam, unit, st_sub);
    let (p, pu) = (psnr(&img, &reference), psnr(&uimg, &ref_unit));
    eprintln!("65536^3 far corner: {p:.2} dB; unit-scale control {pu:.2} dB");
    assert!(
        pu - p <= 1.0,
        "65536^3: {p:.2} dB, {:.2} dB below the control",
        pu - p
    );
    let moved = Camera {
        eye: cam.eye + Vec3::new(vx, 0.0, 0.0),
        target: cam.target + Vec3::new(vx, 0.0, 0.0),
        ..cam
    };
    let wrong = reference_unit(&sub, &sub_frame, &tf, &moved, &st_sub);
    let pw = psnr(&img, &wrong);
    assert!(
        pu - pw > 1.0,
        "guard: a camera one voxel off scores {pw:.2} dB"
    );
}

fn reference_unit(
    vol: &Volume,
    frame: &VolumeFrame,
    tf: &TransferFunction,
    cam: &Camera,
    st: &RenderSettings,
) -> Vec<u8> {
    reference(vol, frame, tf, cam, st, 0.5)
}

/// Case 7. Threshold: with early termination at t, no 8-bit channel differs
/// from the unterminated image by more than (1 - t) * 255 + 1 levels, for t of
/// 0.9, 0.99 and 0.999, on a translucent TF. Guard: the 0.9 image exceeds
/// the bound of 0.999.
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
    let mut errs = Vec::new();
    for t in [0.9f32, 0.99, 0.999] {
        let e = max_abs_diff(&draw(&mut r, cam, frame, st(Some(t))), &full) as f64;
        eprintln!("ERT {t}: max error {e} (bound {:.1})", bound(t));
        assert!(e <= bound(t), "ERT {t}: {e} > {:.1}", bound(t));
        errs.push(e);
    }
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
        let mut r = ooc(src.clone(), frame, config, &tf);
        r.set_visibility_policy(p).unwrap();
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
