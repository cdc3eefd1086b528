//! Regression tests of the stability suite's bounds, cases 4-6 (thin
//! structures, rays on brick faces, precision at 65536^3; the others:
//! `tests/gpu_stability.rs`, docs/stability-suite.md). Each asserts the bound
//! with a stated threshold against the f64 CPU reference and checks a guard
//! that shows the measure can fail.

#[path = "stability_support.rs"]
mod support;

use support::*;

/// The thin-structures volume of the bench (case 4).
fn thin_volume(n: u32) -> Volume {
    brickray_harness::scenes::thin_volume(n).unwrap()
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
        let mut r = ooc(source, config, &tf);
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
    let mut r = ooc(src, config, &tf);
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
    let mut r = ooc(src, config, &tf);
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
