//! Cases 5 and 6: rays along brick faces and level boundaries, and position
//! precision at 65536^3.

use super::{Case, Ctx, holes, noise, quality, region_volume, s};
use crate::runner::{Runner, finest_ooc_renderer, round2};
use crate::stability::detail::ortho;
use crate::stability::streaming::{BRICK, noise_tf};
use brickray_core::{
    BrickSource, Camera, ClipBox, DepthConvention, Projection, RenderMode, RenderSettings,
    VolumeFrame,
};
use brickray_render::{OutOfCoreConfig, RendererOptions, VolumeRenderer};
use brickray_store::ProceduralSource;
use glam::{DVec3, Mat4, Vec3};
use std::sync::Arc;

/// Mean absolute error (8-bit RGB) of the columns in `cols` over that of the
/// other columns: above 1 where the columns show a seam.
pub(crate) fn seam_ratio(
    img: &[u8],
    reference: &[u8],
    w: usize,
    cols: &dyn Fn(usize) -> bool,
) -> f64 {
    let (mut on, mut n_on, mut off, mut n_off) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for (i, (a, b)) in img
        .chunks_exact(4)
        .zip(reference.chunks_exact(4))
        .enumerate()
    {
        let e: f64 = (0..3)
            .map(|c| (a[c] as f64 - b[c] as f64).abs())
            .sum::<f64>()
            / 3.0;
        if cols(i % w) {
            on += e;
            n_on += 1.0;
        } else {
            off += e;
            n_off += 1.0;
        }
    }
    // One level of error floor so two exact images give 1, not 0/0.
    (on / n_on.max(1.0) + 1.0) / (off / n_off.max(1.0) + 1.0)
}

/// One view, mode and renderer of the grazing rays.
#[derive(Debug, serde::Serialize)]
struct GrazingRow {
    view: String,
    mode: String,
    renderer: String,
    psnr_db: f64,
    flip: f64,
    holes: u64,
    seam_ratio: f64,
    levels: String,
}

/// The grazing case's figures.
#[derive(Debug, serde::Serialize)]
struct GrazingFigures {
    rows: Vec<GrazingRow>,
    /// Iso on voxel faces against a quarter pixel off, dB lost.
    iso_on_face_loss_db: f64,
}

/// One position in the precision case: volume, level and mode.
#[derive(Debug, serde::Serialize)]
struct PrecisionRow {
    where_: String,
    level_name: String,
    mode: String,
    position_error_voxels: f64,
    psnr_db: f64,
    flip: f64,
    psnr_unit_scale_ooc_db: f64,
    psnr_unit_scale_incore_db: f64,
    loss_db: f64,
    finest_level_in_cut: Option<usize>,
    lit_pct: f64,
    converged: bool,
}

/// The f32 error of the emulated sweep at one volume side.
#[derive(Debug, serde::Serialize)]
struct SweepPoint {
    dims: u64,
    position_error_voxels: f64,
}

/// The precision case's figures.
#[derive(Debug, serde::Serialize)]
struct PrecisionFigures {
    rows: Vec<PrecisionRow>,
    f32_sweep: Vec<SweepPoint>,
}

/// Case 5: an orthographic view down -z, shifted half a pixel, so that every
/// ray lies exactly on a voxel face in x and y (the columns at multiples of the
/// brick side on brick faces); and a perspective view (odd width) whose centre
/// column lies in the brick face x = 1/4 of every level and whose centre row
/// in y = 1/2, at the finest level and with mixed levels (tolerance 1 px).
pub(crate) fn grazing(ctx: &Ctx<'_>) -> Result<Case, String> {
    let n = ctx.size;
    let (vol, src) = noise(n as u64, BRICK)?;
    let frame = VolumeFrame::centered([n; 3], [1.0; 3]);
    println!(
        "\n5. grazing rays: {n}^3 noise, bricks {BRICK}; orthographic down -z with every ray on voxel faces ({n} px); perspective along the face x = 1/4 ({} px)",
        n - 1
    );
    let half = 0.5 / n as f32;
    let ortho_cam = {
        let mut c = ortho(Vec3::new(-half, -half, 0.0), Vec3::Z, 1.0);
        c.up = Vec3::Y;
        c
    };
    let persp_cam = Camera {
        eye: Vec3::new(-0.25, 0.0, 1.6),
        target: Vec3::new(-0.25, 0.0, 0.0),
        up: Vec3::Y,
        projection: Projection::Perspective {
            fov_y: 40f32.to_radians(),
        },
        near: 0.01,
        far: 10.0,
        depth: DepthConvention::Standard,
    };
    let tf = noise_tf();
    let modes = [
        ("dvr", RenderSettings::default()),
        (
            "iso",
            RenderSettings {
                mode: RenderMode::Iso {
                    value: 0.6,
                    color: [0.9, 0.85, 0.75],
                },
                ..Default::default()
            },
        ),
    ];
    let mut incore = super::incore(ctx.gpu, &vol, &tf)?;
    let mut finest = finest_ooc_renderer(
        ctx.gpu,
        src.clone() as Arc<dyn BrickSource>,
        RendererOptions::default(),
    )?;
    finest
        .set_transfer_function(&ctx.gpu.device, &ctx.gpu.queue, &tf)
        .map_err(s)?;
    let mixed_cfg = OutOfCoreConfig {
        tolerance_px: 1.0,
        upload_budget_bytes: 1 << 30,
        ..Default::default()
    };
    let mut mixed = super::ooc(ctx.gpu, src.clone(), mixed_cfg, &tf)?;
    println!(
        "  {:<6} {:<5} {:<10} {:>9} {:>8} {:>6} {:>7} {:>7}",
        "view", "mode", "renderer", "PSNR", "FLIP", "holes", "seam", "levels"
    );
    let mut rows = Vec::new();
    let (mut holes_max, mut seam_max, mut psnr_min) = (0u64, 0.0f64, f64::INFINITY);
    // Iso PSNR of the orthographic views: (on the faces, renderer, dB).
    let mut iso_ortho: Vec<(bool, &str, f64)> = Vec::new();
    let b = BRICK as usize;
    // Control: the same orthographic view a quarter pixel off the faces.
    let off_cam = {
        let q = 0.25 / n as f32;
        ortho(Vec3::new(-half + q, -half + q, 0.0), Vec3::Z, 1.0)
    };
    let mut brute = super::incore(ctx.gpu, &vol, &tf)?;
    for (view, cam, px) in [
        ("ortho", ortho_cam, n),
        ("ortho_off", off_cam, n),
        ("persp", persp_cam, n - 1),
    ] {
        let run = Runner::new(ctx.gpu, px)?;
        let w = px as usize;
        let face: Box<dyn Fn(usize) -> bool> = if view != "persp" {
            Box::new(move |x| x % b == 0)
        } else {
            Box::new(move |x| x == w / 2)
        };
        // The persp view's "other" columns: a band around the face column.
        for (mname, settings) in &modes {
            let reference = super::reference(&vol, &frame, &tf, &cam, settings, px, 0.5);
            let renderers: [(&str, &mut VolumeRenderer); 4] = [
                ("in core", &mut incore),
                ("in brute", &mut brute),
                ("ooc finest", &mut finest),
                ("ooc mixed", &mut mixed),
            ];
            for (rname, r) in renderers {
                let mut levels = String::from("-");
                let settings = &if rname == "in brute" {
                    RenderSettings {
                        accel: brickray_core::Accel::BRUTE_FORCE,
                        ..*settings
                    }
                } else {
                    *settings
                };
                if rname.starts_with("ooc") {
                    let (_, st) = run.converge(r, cam, frame, *settings, 200)?;
                    let ls: Vec<String> = (0..16)
                        .filter(|&l| st.data_leaves_per_level[l] > 0)
                        .map(|l| l.to_string())
                        .collect();
                    levels = ls.join(",");
                }
                let shot = run.frame(r, cam, frame, *settings, true)?;
                let (p, f) = quality(&shot.rgba, &reference, px);
                let h = holes(&shot.rgba, &reference);
                let seam = if view != "persp" {
                    seam_ratio(&shot.rgba, &reference, w, &*face)
                } else {
                    // Only a band of 7 columns around the face column counts.
                    let band: Vec<u8> = band_cols(&shot.rgba, w, w / 2, 3);
                    let rband: Vec<u8> = band_cols(&reference, w, w / 2, 3);
                    seam_ratio(&band, &rband, 7, &|x| x == 3)
                };
                println!(
                    "  {view:<6} {mname:<5} {rname:<10} {p:>9.2} {f:>8.4} {h:>6} {seam:>7.2} {levels:>7}"
                );
                holes_max = holes_max.max(h);
                seam_max = seam_max.max(seam);
                if *mname == "dvr" && rname != "ooc mixed" {
                    psnr_min = psnr_min.min(p);
                }
                if *mname == "iso" && view.starts_with("ortho") {
                    iso_ortho.push((view == "ortho", rname, p));
                }
                rows.push(GrazingRow {
                    view: view.to_string(),
                    mode: mname.to_string(),
                    renderer: rname.to_string(),
                    psnr_db: p,
                    flip: f,
                    holes: h,
                    seam_ratio: round2(seam),
                    levels: levels.to_string(),
                });
            }
        }
    }
    const SEAM_BOUND: f64 = 1.5;
    const PSNR_BOUND: f64 = 40.0;
    const ISO_FACE_LOSS: f64 = 5.0;
    // Iso on the faces against the same view a quarter pixel off, per renderer.
    let iso_loss = iso_ortho
        .iter()
        .filter(|x| !x.0)
        .filter_map(|off| {
            iso_ortho
                .iter()
                .find(|on| on.0 && on.1 == off.1)
                .map(|on| (off.2 - on.2, on.2, off.2))
        })
        .fold(
            (f64::NEG_INFINITY, 0.0, 0.0),
            |a, b| if b.0 > a.0 { b } else { a },
        );
    Ok(Case {
        name: "grazing",
        varied: "rays exactly on voxel and brick faces (orthographic), along a brick face of every level (perspective), finest and mixed levels, DVR and iso".into(),
        fails: format!(
            "no hole or seam ({}); iso with every ray exactly on voxel faces (orthographic, axis-aligned)",
            if holes_max == 0 && seam_max <= SEAM_BOUND { "none found" } else { "FOUND: see the table" }
        ),
        by: format!(
            "iso {:.2} dB on the faces vs {:.2} dB a quarter pixel off ({:.2} dB lost); worst seam ratio {seam_max:.2}, holes {holes_max}",
            iso_loss.1, iso_loss.2, iso_loss.0
        ),
        shipped: "f64 ray basis rounded once, brick aprons, contiguous segments across leaves".into(),
        bound: format!(
            "0 holes; seam ratio <= {SEAM_BOUND}; DVR >= {PSNR_BOUND} dB (in core, finest; measured {psnr_min:.2}); iso on faces within {ISO_FACE_LOSS} dB of off the faces"
        ),
        holds: holes_max == 0
            && seam_max <= SEAM_BOUND
            && psnr_min >= PSNR_BOUND
            && iso_loss.0 <= ISO_FACE_LOSS,
        holes_max,
        fig: super::figures(&GrazingFigures {
            rows,
            iso_on_face_loss_db: round2(iso_loss.0),
        }),
    })
}

/// Columns `c - r ..= c + r` of a `w`-wide RGBA image.
fn band_cols(img: &[u8], w: usize, c: usize, r: usize) -> Vec<u8> {
    img.chunks_exact(4 * w)
        .flat_map(|row| row[4 * (c - r)..4 * (c + r + 1)].iter().copied())
        .collect()
}

/// Largest sample position error, in finest voxels, of the GPU's f32 ray set-up
/// (`pixel_ray`, `clip_box` and `t0 + k dt` of common.wgsl and ooc.wgsl,
/// emulated on the CPU) against the f64 rays, over every 4th pixel and its first
/// `samples` samples.
pub(crate) fn position_error(
    cam: &Camera,
    frame: &VolumeFrame,
    clip: &ClipBox,
    size: u32,
    step: f32,
    samples: u32,
) -> f64 {
    let rg = cam.rays(1.0);
    let inv = frame.model.as_dmat4().inverse();
    let f = |v: DVec3| v.as_vec3();
    let eye_tex = f(inv.transform_point3(rg.eye));
    let fwd_tex = f(inv.transform_vector3(rg.fwd));
    let right_tex = f(inv.transform_vector3(rg.right));
    let up_tex = f(inv.transform_vector3(rg.up));
    let (fwd_w, right_w, up_w) = (f(rg.fwd), f(rg.right), f(rg.up));
    let near = rg.near as f32;
    let k = if rg.perspective { 1.0f32 } else { 0.0 };
    let dt32 = step * frame.voxel_world;
    let dt64 = step as f64 * frame.voxel_world as f64;
    let dims = DVec3::from_array(frame.dims.map(f64::from));
    let lo = Vec3::from_array(clip.min);
    let hi = Vec3::from_array(clip.max);
    let mut worst = 0.0f64;
    for py in (0..size).step_by(4) {
        for px in (0..size).step_by(4) {
            let ray = rg.pixel_ray(&inv, px as f64, py as f64, size, size);
            let Some((t0, t1)) = ray.clip_box(lo.as_dvec3().to_array(), hi.as_dvec3().to_array())
            else {
                continue;
            };
            let t0 = t0.max(0.0);
            // f32, as the kernels compute it.
            let sz = size as f32;
            let ndc = (
                2.0 * (px as f32 + 0.5) / sz - 1.0,
                1.0 - 2.0 * (py as f32 + 0.5) / sz,
            );
            let lat_w = right_w * ndc.0 + up_w * ndc.1;
            let lat_t = right_tex * ndc.0 + up_tex * ndc.1;
            let dw = fwd_w + lat_w * k;
            let len = dw.length();
            let dir = (fwd_tex + lat_t * k) / len;
            let org = eye_tex + fwd_tex * near + lat_t * if k > 0.0 { near } else { 1.0 };
            let (mut a, mut b) = (-3.0e38f32, 3.0e38f32);
            for ax in 0..3 {
                if dir[ax].abs() >= 1e-30 {
                    let ta = (lo[ax] - org[ax]) / dir[ax];
                    let tb = (hi[ax] - org[ax]) / dir[ax];
                    a = a.max(ta.min(tb));
                    b = b.min(ta.max(tb));
                }
            }
            let _ = b;
            let t0_32 = a.max(0.0);
            for j in 0..samples {
                let t64 = t0 + j as f64 * dt64;
                if t64 >= t1 {
                    break;
                }
                let p64 = ray.tex_origin + ray.tex_dir * t64;
                let t32 = t0_32 + j as f32 * dt32;
                let p32 = (org + dir * t32).as_dvec3();
                let e = ((p32 - p64) * dims).abs().max_element();
                worst = worst.max(e);
            }
        }
    }
    worst
}

/// Case 6: a 65536^3 procedural volume, a 60^3 box of finest voxels at the
/// centre and at the far corner clipped out and viewed from 40 voxels (4 px a
/// voxel) and through a telephoto lens from half the volume away; the same
/// scene at unit scale (the box as a 64^3 in-core volume, the camera scaled
/// by 1024), out of core at the finest level, is the control (and in core,
/// for scale).
pub(crate) fn precision(ctx: &Ctx<'_>) -> Result<Case, String> {
    const DIMS: u64 = 65536;
    const N: u64 = 64;
    const M: u64 = 2;
    let size = ctx.size;
    println!(
        "\n6. precision: {DIMS}^3 noise, a {}^3 box of finest voxels clipped out, DVR and iso; GPU out of core vs the reference of the box, and the same scene at unit scale (the box as a 64^3 store, out of core at the finest level: the control; and in core)",
        N - 2 * M
    );
    let src = Arc::new(ProceduralSource::fractal_noise([DIMS; 3], 32, 2).map_err(s)?);
    let big = VolumeFrame::centered([DIMS as u32; 3], [1.0; 3]);
    let run = Runner::new(ctx.gpu, size)?;
    let mut r = super::ooc(
        ctx.gpu,
        src.clone(),
        OutOfCoreConfig {
            upload_budget_bytes: 1 << 30,
            ..Default::default()
        },
        &noise_tf(),
    )?;
    println!(
        "  {:<7} {:<6} {:<5} {:>10} {:>9} {:>9} {:>9} {:>7} {:>5} {:>9}",
        "where",
        "lens",
        "mode",
        "pos err vx",
        "PSNR ooc",
        "unit ooc",
        "loss dB",
        "level",
        "lit%",
        "unit in"
    );
    let mut rows = Vec::new();
    const ERR_BOUND: f64 = 1.0 / 32.0;
    const LOSS_BOUND: f64 = 1.0;
    let mut iso_loss_max = f64::NEG_INFINITY;
    let (mut err_max, mut loss_max) = (0.0f64, f64::NEG_INFINITY);
    let d = DIMS as f64;
    for (wname, lo) in [("centre", DIMS / 2 - N / 2), ("corner", DIMS - N - 8)] {
        let sub = region_volume(&src, [lo; 3], [N; 3])?;
        let (tf, iso) = region_tf(&sub);
        r.set_transfer_function(&ctx.gpu.device, &ctx.gpu.queue, &tf)
            .map_err(s)?;
        // The box in world (exact in f32: dyadic values).
        let off = (lo as f64 / d - 0.5) as f32;
        let scale = (N as f64 / d) as f32;
        let sub_frame = VolumeFrame::new(
            Mat4::from_translation(Vec3::splat(off)) * Mat4::from_scale(Vec3::splat(scale)),
            [N as u32; 3],
        );
        let unit = VolumeFrame::centered([N as u32; 3], [1.0; 3]);
        let sub_clip = ClipBox {
            min: [(M as f64 / N as f64) as f32; 3],
            max: [((N - M) as f64 / N as f64) as f32; 3],
        };
        let big_clip = ClipBox {
            min: [((lo + M) as f64 / d) as f32; 3],
            max: [((lo + N - M) as f64 / d) as f32; 3],
        };
        let centre = Vec3::splat(off + scale * 0.5);
        let vx = (1.0 / d) as f32;
        let close = Camera {
            near: 2.0 * vx,
            far: 400.0 * vx,
            ..Camera::orbit(centre, 40.0 * vx, 0.6, 0.35)
        };
        // Telephoto: half the volume away, the same view height at the box.
        let tele = Camera {
            projection: Projection::Perspective {
                fov_y: 2.0 * ((40.0 * (20f64.to_radians()).tan()) / 32768.0).atan() as f32,
            },
            // Near and far planes 60 voxels either side of the box: refinement
            // culls by the frustum but does not know the clip box, so a deeper
            // frustum would spend the pool on bricks in front of and behind it.
            near: 0.5 - 60.0 * vx,
            far: 0.5 + 60.0 * vx,
            ..Camera::orbit(centre, 0.5, 0.6, 0.35)
        };
        let mut inc = super::incore(ctx.gpu, &sub, &tf)?;
        // The control out of core too: the box as its own brick store, at the
        // finest level.
        let dir = tempfile::tempdir().map_err(s)?;
        let path = dir.path().join("box.brs");
        let mut reader = brickray_io::MemoryReader::new(sub.clone(), "box");
        brickray_store::build(&mut reader, &path, &Default::default()).map_err(s)?;
        let box_src: Arc<dyn BrickSource> = Arc::new(brickray_store::open(&path).map_err(s)?);
        let mut uooc = finest_ooc_renderer(ctx.gpu, box_src, RendererOptions::default())?;
        uooc.set_transfer_function(&ctx.gpu.device, &ctx.gpu.queue, &tf)
            .map_err(s)?;
        // Inside the box (20 voxels from its centre): rays start at the near
        // plane, not on a clip face, so no cap is decided at an f32 box entry.
        let inside = Camera {
            near: 0.5 * vx,
            far: 400.0 * vx,
            ..Camera::orbit(centre, 20.0 * vx, 0.6, 0.35)
        };
        for (lname, cam) in [("close", close), ("tele", tele), ("inside", inside)] {
            // The camera at unit scale: world_big = off + (world_unit + 0.5) * scale.
            let to_unit = |p: Vec3| {
                ((p.as_dvec3() - off as f64) / scale as f64 - DVec3::splat(0.5)).as_vec3()
            };
            let ucam = Camera {
                eye: to_unit(cam.eye),
                target: to_unit(cam.target),
                near: cam.near / scale,
                far: cam.far / scale,
                ..cam
            };
            for (mname, mode) in [
                ("dvr", RenderMode::Dvr),
                (
                    "iso",
                    RenderMode::Iso {
                        value: iso,
                        color: [0.9, 0.85, 0.75],
                    },
                ),
            ] {
                let st_big = RenderSettings {
                    mode,
                    clip: big_clip,
                    ..Default::default()
                };
                let st_sub = RenderSettings {
                    clip: sub_clip,
                    ..st_big
                };
                let reference = super::reference(&sub, &sub_frame, &tf, &cam, &st_sub, size, 0.5);
                let ref_unit = super::reference(&sub, &unit, &tf, &ucam, &st_sub, size, 0.5);
                let (conv, st) = run.converge(&mut r, cam, big, st_big, 400)?;
                if conv.is_none() {
                    println!("  (not converged in 400 frames)");
                }
                let level = (0..16).rev().find(|&l| st.data_leaves_per_level[l] > 0);
                let shot = run.frame(&mut r, cam, big, st_big, true)?;
                let ushot = run.frame(&mut inc, ucam, unit, st_sub, true)?;
                let (p, fl) = quality(&shot.rgba, &reference, size);
                let (pin, _) = quality(&ushot.rgba, &ref_unit, size);
                run.converge(&mut uooc, ucam, unit, st_sub, 100)?;
                let oshot = run.frame(&mut uooc, ucam, unit, st_sub, true)?;
                let (pu, _) = quality(&oshot.rgba, &ref_unit, size);
                let err = position_error(&cam, &big, &big_clip, size, 0.5, 400);
                let loss = pu - p;
                let lit = 100.0 * lit_share(&reference);
                println!(
                    "  {wname:<7} {lname:<6} {mname:<5} {err:>10.5} {p:>9.2} {pu:>9.2} {loss:>9.2} {:>7} {lit:>5.1} {pin:>9.2}",
                    level.map_or("-".into(), |l| l.to_string())
                );
                err_max = err_max.max(err);
                if mname == "dvr" {
                    loss_max = loss_max.max(loss);
                } else {
                    iso_loss_max = iso_loss_max.max(loss);
                }
                rows.push(PrecisionRow {
                    where_: wname.to_string(),
                    level_name: lname.to_string(),
                    mode: mname.to_string(),
                    position_error_voxels: err,
                    psnr_db: p,
                    flip: fl,
                    psnr_unit_scale_ooc_db: pu,
                    psnr_unit_scale_incore_db: pin,
                    loss_db: round2(loss),
                    finest_level_in_cut: level,
                    lit_pct: round2(lit),
                    converged: st.converged,
                });
            }
        }
    }
    // Where f32 breaks: the same close view of the far corner in virtual
    // frames up to 2^24 voxels a side (the emulation needs no data).
    let mut sweep = Vec::new();
    let mut breaks_at = None;
    println!("  f32 sample position error, close view of the far corner (emulated, no data):");
    for bits in [16u32, 18, 20, 22, 24] {
        let dd = 1u64 << bits;
        let f = VolumeFrame::centered([dd as u32; 3], [1.0; 3]);
        let e = corner_error(&f, size);
        println!("    {dd:>9}^3: {e:.4} voxel");
        if breaks_at.is_none() && e > ERR_BOUND {
            breaks_at = Some((dd, e));
        }
        sweep.push(SweepPoint {
            dims: dd,
            position_error_voxels: e,
        });
    }
    Ok(Case {
        name: "precision",
        varied: "65536^3, box at the centre and the far corner, close (40 voxels), telephoto (32768 voxels away, near and far planes 60 voxels either side of the box) and inside (20 voxels) views, DVR and iso".into(),
        fails: format!(
            "positions: {}; iso out of core at 65536^3 (DVR unaffected)",
            breaks_at.map_or("not within 2^24 voxels a side".into(), |b| format!(
                "{}^3 exceeds 1/32 voxel (emulated)",
                b.0
            ))
        ),
        by: format!(
            "iso up to {iso_loss_max:.2} dB below the unit-scale control; positions at 65536^3 within {err_max:.4} voxel; {}",
            breaks_at.map_or(String::new(), |b| format!("{:.3} voxel at {}^3", b.1, b.0))
        ),
        shipped: "f32 texture-space rays from an f64 basis; 65536^3 the largest procedural size tested".into(),
        bound: format!(
            "at 65536^3: sample position error <= {ERR_BOUND} voxel (measured {err_max:.4}); DVR within {LOSS_BOUND} dB of unit scale (measured {loss_max:.2})"
        ),
        holds: err_max <= ERR_BOUND && loss_max <= LOSS_BOUND,
        holes_max: 0,
        fig: super::figures(&PrecisionFigures {
            rows,
            f32_sweep: sweep,
        }),
    })
}

/// [`position_error`] of a view from 40 voxels of a 60^3 box 8 voxels from
/// the far corner of `frame` (any size: no data is read).
pub(crate) fn corner_error(frame: &VolumeFrame, size: u32) -> f64 {
    let d = frame.dims[0] as f64;
    let lo = d - 72.0;
    let clip = ClipBox {
        min: [((lo + 2.0) / d) as f32; 3],
        max: [((lo + 62.0) / d) as f32; 3],
    };
    let centre = Vec3::splat(((lo + 32.0) / d - 0.5) as f32);
    let vx = (1.0 / d) as f32;
    let cam = Camera {
        near: 2.0 * vx,
        far: 400.0 * vx,
        ..Camera::orbit(centre, 40.0 * vx, 0.6, 0.35)
    };
    position_error(&cam, frame, &clip, size, 0.5, 400)
}

/// A TF and an isovalue fitted to a region's values: opacity from 0 at 35% of
/// its range to 0.4 at 75%, the isovalue at 50% (normalized).
pub(crate) fn region_tf(vol: &brickray_core::Volume) -> (brickray_core::TransferFunction, f32) {
    let (lo, hi) = vol.data().min_max().unwrap_or((0.0, 255.0));
    let (lo, hi) = (lo / 255.0, hi / 255.0);
    let at = |k: f32| lo + k * (hi - lo);
    let tf = brickray_core::TransferFunction::from_points(
        &[
            (at(0.35), [0.2, 0.5, 1.0, 0.0]),
            (at(0.75), [1.0, 0.8, 0.5, 0.4]),
        ],
        256,
    );
    (tf, at(0.5))
}

/// Share of pixels at least 24 (of 255) in their brightest RGB channel.
pub(crate) fn lit_share(img: &[u8]) -> f64 {
    let lit = img
        .chunks_exact(4)
        .filter(|p| p[0].max(p[1]).max(p[2]) >= super::HOLE_REF_MIN)
        .count();
    lit as f64 / (img.len() / 4).max(1) as f64
}
