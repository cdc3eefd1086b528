//! No sample lost at the volume's faces: out of core, at the finest level, a ray
//! takes the same samples as in core, also where it enters through a face the
//! volume shares with the octree cube (where the ray's start, from the clip box,
//! and the first leaf's entry, from the octree's cube, are two computations of
//! one point).
//!
//! Cases: a synthetic 64^3 volume (its box is the octree cube: all six faces
//! shared) seen from the eight octants' diagonals, so rays enter through every
//! face; the shared head CT (256 x 256 x 108 in a cube of 256: faces x = 0,
//! x = 256, y = 0, y = 256 and z = 0 shared) from four of them. DVR, the
//! isosurface and MIP, no empty-space skipping and no early termination (their
//! samples differ by design between the backends: macro cells in core, brick
//! sub-cells out of core).
//!
//! Thresholds, per view and mode, out of core against in core: the same
//! volume-sample count in every pixel, PSNR >= 80 dB and no channel more than
//! 2 levels off (8-bit RGB over black). Counts are compared where no brick of
//! the cut is empty or invisible (out of core skips those whatever the
//! switches): the synthetic volume's TFs and isovalue see every brick; on the
//! head CT the isosurface's air bricks are invisible, so there its counts are
//! not compared. An isosurface march ends at the first sample at or above the
//! isovalue, and a sample within the texture filter's rounding of it (the two
//! backends address the data through different textures) can end it one
//! sample apart: the isosurface may have [`ISO_TIES`] such pixels per view.
//! Before the fix 573-617 of the 4758-4878 rays of a view took one sample
//! fewer out of core on the 64^3 volume (DVR 48-50 dB, iso 33-43 dB, MIP
//! 34-41 dB, up to 209 levels off), 257-578 of 3801 on the head CT (iso
//! 48-85 dB, up to 109 levels off); now none, and 81.8 dB or more, at most
//! one level off.

use brickray::{
    Accel, Camera, FrameDesc, OutOfCoreConfig, RenderMode, RenderSettings, TransferFunction,
    Volume, VolumeFrame, VolumeRenderer,
};
use brickray_harness::predict::{FrameResult, draw};
use brickray_harness::{Offscreen, draw_until_settled, shared_gpu as gpu, target_desc};
use brickray_reference::{compare_and_report, max_abs_diff, psnr, test_output_dir};
use std::f32::consts::{FRAC_PI_2, FRAC_PI_4};
use std::sync::Arc;

const SIZE: u32 = 96;
const MIN_PSNR_DB: f64 = 80.0;
const MAX_LEVELS: u8 = 2;
/// Isosurface pixels a view may count otherwise (a sample within rounding of
/// the isovalue; none on lavapipe at this framing, one at a closer one).
const ISO_TIES: usize = 4;
const DISTANCE: f32 = 2.5;

/// Views from the octants' diagonals: yaw pi/4 + k pi/2, pitch alternating in
/// sign (`all`: both signs at every yaw, 8 views; else 4, which still enter
/// through all six faces of a box).
fn views(frame: &VolumeFrame, all: bool) -> Vec<Camera> {
    let mut v = Vec::new();
    for k in 0..4 {
        let yaw = FRAC_PI_4 + k as f32 * FRAC_PI_2;
        let pitch = if k % 2 == 0 { 0.55 } else { -0.55 };
        v.push(Camera::orbit(frame.center(), DISTANCE, yaw, pitch));
        if all {
            v.push(Camera::orbit(frame.center(), DISTANCE, yaw + 0.3, -pitch));
        }
    }
    v
}

/// A 64^3 u8 volume whose every 32^3 brick spans most of the value range
/// (a product of sines of periods 9-13 voxels) and whose values rise towards
/// the faces (a radial term), so the samples at the faces weigh in every mode.
fn faces_volume() -> Volume {
    let n = 64u32;
    let c = (n as f64 - 1.0) * 0.5;
    let tau = std::f64::consts::TAU;
    brickray::core::synthetic::u8_field(n, |[x, y, z]| {
        let p = [x, y, z].map(|i| i as f64);
        let s = (tau * p[0] / 13.0).sin() * (tau * p[1] / 11.0).sin() * (tau * p[2] / 9.0).sin();
        let r = ((p[0] - c).powi(2) + (p[1] - c).powi(2) + (p[2] - c).powi(2)).sqrt()
            / (c * 3f64.sqrt());
        0.3 + 0.3 * s + 0.4 * r
    })
}

/// `(name, mode, TF)`: DVR whose opacity is above zero at every value (no brick
/// invisible), the isosurface at `iso`, MIP through a grey ramp.
fn modes(
    iso: f32,
    dvr: TransferFunction,
    mip: TransferFunction,
) -> Vec<(&'static str, RenderMode, TransferFunction)> {
    vec![
        ("dvr", RenderMode::Dvr, dvr.clone()),
        (
            "iso",
            RenderMode::Iso {
                value: iso,
                color: [0.9, 0.85, 0.75],
            },
            dvr,
        ),
        ("mip", RenderMode::Mip, mip),
    ]
}

fn desc(camera: Camera, frame: VolumeFrame, mode: RenderMode) -> FrameDesc<'static> {
    FrameDesc {
        settings: RenderSettings {
            mode,
            accel: Accel::BRUTE_FORCE,
            ..Default::default()
        },
        ..FrameDesc::new(camera, frame, SIZE, SIZE)
    }
}

/// What one view and mode measured.
struct Outcome {
    label: String,
    ok: bool,
    count_mismatches: usize,
    one_fewer: usize,
    psnr_db: f64,
    max_levels: u8,
}

/// Renders every view and mode in core and out of core (finest level) and
/// compares them; returns one outcome per view and mode.
fn compare_backends(
    name: &str,
    vol: &Volume,
    cameras: &[Camera],
    cases: &[(&'static str, RenderMode, TransferFunction)],
    counted: &[&str],
    brick: u32,
) -> Vec<Outcome> {
    let g = gpu();
    let d = vol.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("vol.brs");
    let mut reader = brickray::io::MemoryReader::new(vol.clone(), "memory");
    let options = brickray::store::BuildOptions {
        brick,
        ..Default::default()
    };
    brickray::store::build(&mut reader, &path, &options).unwrap();
    let source = Arc::new(brickray::store::open(&path).unwrap());
    let mut incore = VolumeRenderer::new(&g.device, target_desc()).unwrap();
    incore.set_volume(&g.device, &g.queue, vol).unwrap();
    let mut ooc = VolumeRenderer::new(&g.device, target_desc()).unwrap();
    let config = OutOfCoreConfig {
        tolerance_px: 0.0,
        upload_budget_bytes: 1 << 30,
        ..Default::default()
    };
    ooc.set_volume_source(&g.device, &g.queue, source, config)
        .unwrap();
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let mut out = Vec::new();
    for (mode_name, mode, tf) in cases {
        incore
            .set_transfer_function(&g.device, &g.queue, tf)
            .unwrap();
        ooc.set_transfer_function(&g.device, &g.queue, tf).unwrap();
        for (i, camera) in cameras.iter().enumerate() {
            let desc = desc(*camera, frame, *mode);
            let a: FrameResult = draw(g, &mut incore, &target, &desc).unwrap();
            let settled = draw_until_settled(g, &mut ooc, &target, &desc, 300).unwrap();
            assert!(
                settled.is_some(),
                "{name} {mode_name} view {i}: out of core did not settle"
            );
            let b: FrameResult = draw(g, &mut ooc, &target, &desc).unwrap();
            assert_eq!(
                a.samples.len(),
                (SIZE * SIZE) as usize,
                "no sample counts in core"
            );
            assert_eq!(
                b.samples.len(),
                a.samples.len(),
                "no sample counts out of core"
            );
            let (mut mismatches, mut one_fewer) = (0, 0);
            if counted.contains(mode_name) {
                for (sa, sb) in a.samples.iter().zip(&b.samples) {
                    if sa != sb {
                        mismatches += 1;
                        if *sb + 1 == *sa {
                            one_fewer += 1;
                        }
                    }
                }
            }
            let label = format!("faces_{name}_{mode_name}_view{i}");
            let psnr_db = psnr(&b.color, &a.color);
            let max_levels = max_abs_diff(&b.color, &a.color);
            let allowed = if *mode_name == "iso" { ISO_TIES } else { 0 };
            let ok = mismatches <= allowed && psnr_db >= MIN_PSNR_DB && max_levels <= MAX_LEVELS;
            if !ok {
                compare_and_report(&label, &b.color, &a.color, SIZE, SIZE, test_output_dir());
            }
            let rays = a.samples.iter().filter(|&&n| n > 0).count();
            eprintln!(
                "{label}: {mismatches} of {rays} rays with other sample counts ({one_fewer} one fewer out of core), {psnr_db:.1} dB, max {max_levels} levels"
            );
            out.push(Outcome {
                label,
                ok,
                count_mismatches: mismatches,
                one_fewer,
                psnr_db,
                max_levels,
            });
        }
    }
    out
}

fn assert_outcomes(outcomes: &[Outcome]) {
    let bad: Vec<String> = outcomes
        .iter()
        .filter(|o| !o.ok)
        .map(|o| {
            format!(
                "{}: {} pixels with other sample counts ({} one fewer out of core), {:.1} dB, max {} levels",
                o.label, o.count_mismatches, o.one_fewer, o.psnr_db, o.max_levels
            )
        })
        .collect();
    assert!(
        bad.is_empty(),
        "out of core differs from in core (want equal sample counts, iso up to {ISO_TIES} pixels, >= {MIN_PSNR_DB} dB, <= {MAX_LEVELS} levels):\n{}",
        bad.join("\n")
    );
}

/// The synthetic volume's DVR: some opacity at every value.
fn cube_dvr() -> TransferFunction {
    TransferFunction::from_points(
        &[
            (0.0, [0.2, 0.4, 0.9, 0.02]),
            (0.5, [0.9, 0.6, 0.3, 0.08]),
            (1.0, [1.0, 0.9, 0.7, 0.4]),
        ],
        256,
    )
}

#[test]
fn synthetic_cube_faces_lose_no_sample() {
    let vol = faces_volume();
    let d = vol.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let cases = modes(0.6, cube_dvr(), TransferFunction::ramp(0.0, 1.0, 1.0));
    let outcomes = compare_backends(
        "cube64",
        &vol,
        &views(&frame, true),
        &cases,
        &["dvr", "iso", "mip"],
        32,
    );
    assert_outcomes(&outcomes);
}

/// The same with bricks of 8 voxels, DVR and MIP: 512 leaves, whose
/// boundaries the rays cross 10-20 times each; a sample within rounding of a
/// boundary must be taken in exactly one of the two leaves (one ray of view 2
/// lost one when the leaf's first sample came from a quotient the march's end
/// test did not share). The isosurface is left out: at this brick size its
/// shading differs by one level on more pixels (77-80 dB; filter rounding in
/// the atlas, not samples).
#[test]
fn synthetic_small_bricks_lose_no_sample() {
    let vol = faces_volume();
    let d = vol.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let mut cases = modes(0.6, cube_dvr(), TransferFunction::ramp(0.0, 1.0, 1.0));
    cases.retain(|c| c.0 != "iso");
    let outcomes = compare_backends(
        "cube64_b8",
        &vol,
        &views(&frame, true),
        &cases,
        &["dvr", "mip"],
        8,
    );
    assert_outcomes(&outcomes);
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
fn head_ct_faces_lose_no_sample() {
    use brickray_harness::ct::hu;
    let Some(path) = brickray_harness::shared_volume("invesalius_cranium_ct") else {
        return;
    };
    let vol = brickray::io::read_volume(path).unwrap();
    let d = vol.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    // Faint everywhere (no brick invisible), soft tissue and opaque bone.
    let dvr = TransferFunction::from_points(
        &[
            (0.0, [0.3, 0.3, 0.4, 0.004]),
            (hu(-100.0), [0.8, 0.5, 0.4, 0.02]),
            (hu(250.0), [0.9, 0.8, 0.7, 0.05]),
            (hu(600.0), [1.0, 0.95, 0.85, 0.9]),
        ],
        512,
    );
    let cases = modes(
        hu(400.0),
        dvr,
        TransferFunction::ramp(hu(-1100.0), hu(1500.0), 1.0),
    );
    let outcomes = compare_backends(
        "head_ct",
        &vol,
        &views(&frame, false),
        &cases,
        &["dvr", "mip"],
        32,
    );
    assert_outcomes(&outcomes);
}
