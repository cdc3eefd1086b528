//! Label maps on a real wgpu device (lavapipe in CI), against the CPU
//! reference's label model (nearest voxel, exact per-label table):
//!
//! * the two shared label maps (the Brodmann atlas, u8, and the cells3d
//!   nuclei, u32) in core and out of core at the finest level, each >= 45 dB
//!   PSNR against the reference, nearest, with smooth boundaries
//!   (`RenderSettings::smooth_labels`) and with smooth boundaries shaded by
//!   their indicator's gradient, marched at the reference's step (1/8
//!   voxel): a label's boundary is a step in the data, so where a coarser
//!   step lands on it is a sampling error, not the model's (the default half
//!   voxel's is printed beside it);
//! * out of core at 1, 2 and 4 px of tolerance against the finest level
//!   (coarse levels are the mode of their children, so no label is invented:
//!   tested in `brickray-store`), and the same ids as an intensity volume
//!   (trilinear samples, averaged levels: how brickray drew a label map
//!   before) at 2 px: labels at least 5 dB closer to the finest;
//! * hidden labels: empty-space skipping skips what only hidden labels fill
//!   (fewer samples) and the image equals the one drawn without skipping;
//! * a float volume cannot be made a label map (typed error);
//! * label maps over the images they segment: the `overlay` module
//!   (`gpu_overlay.rs`, in this binary to save a link).

#[path = "gpu_overlay.rs"]
mod overlay;

use brickray::core::labels::{self, LabelTable};
use brickray::{
    Camera, FrameDesc, OutOfCoreConfig, RenderMode, RenderSettings, Volume, VolumeFrame,
    VolumeRenderer,
};
use brickray_harness::predict::{draw, samples_per_ray};
use brickray_harness::{Offscreen, draw_until_settled, shared_gpu as gpu, target_desc};
use brickray_reference::{ReferenceOptions, assert_close, compare, render_reference};
use std::path::PathBuf;
use std::sync::Arc;

const SIZE: u32 = 128;
const MIN_DB: f64 = 45.0;

fn shared_label_map(name: &str) -> Option<Volume> {
    let dir: PathBuf = brickray_harness::shared_data_dir()?;
    let path = dir.join("labels").join(name).join(format!("{name}.json"));
    let vol = brickray::io::read_volume(&path).unwrap_or_else(|e| panic!("{e}"));
    assert!(vol.desc().kind.is_labels(), "the sidecar's labels list");
    Some(vol)
}

/// DVR at the reference's step (see the module documentation).
fn settings() -> RenderSettings {
    RenderSettings {
        mode: RenderMode::Dvr,
        step_factor: brickray_reference::DEFAULT_STEP_FACTOR,
        ..Default::default()
    }
}

/// The default table: every label but the background, hashed colours,
/// opacity 0.5.
fn table() -> LabelTable {
    LabelTable::default()
}

/// Out of core at `tolerance_px`, with room to upload every brick at once.
fn ooc_config(tolerance_px: f32) -> OutOfCoreConfig {
    OutOfCoreConfig {
        tolerance_px,
        upload_budget_bytes: 1 << 30,
        ..Default::default()
    }
}

fn store(vol: &Volume, dir: &std::path::Path) -> Arc<dyn brickray::core::BrickSource> {
    let path = dir.join(format!("{:?}.brs", vol.desc().kind));
    let mut reader = brickray::io::MemoryReader::new(vol.clone(), "memory");
    let options = brickray::store::BuildOptions {
        brick: 16,
        ..Default::default()
    };
    brickray::store::build(&mut reader, &path, &options).unwrap();
    let s = brickray::store::open(&path).unwrap();
    let mode = vol.desc().kind.is_labels();
    assert_eq!(s.filter() == brickray::store::Filter::Mode, mode);
    Arc::new(s)
}

fn check(name: &str, vol: &Volume) {
    let g = gpu();
    let d = vol.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let tf = table().to_transfer_function();
    let camera = Camera::orbit(frame.center(), 2.2, 0.8, 0.45);
    let reference = render_reference(
        vol,
        &frame,
        &tf,
        &camera,
        &settings(),
        &ReferenceOptions::new(SIZE, SIZE),
    )
    .to_rgba8([0.0; 3]);
    let desc = FrameDesc {
        settings: settings(),
        ..FrameDesc::new(camera, frame, SIZE, SIZE)
    };
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let mut incore = VolumeRenderer::new(&g.device, target_desc()).unwrap();
    incore.set_volume(&g.device, &g.queue, vol).unwrap();
    incore
        .set_transfer_function(&g.device, &g.queue, &tf)
        .unwrap();
    // The default half-voxel step: its sampling error at label boundaries.
    let coarse = FrameDesc {
        settings: RenderSettings {
            step_factor: RenderSettings::default().step_factor,
            ..settings()
        },
        ..desc.clone()
    };
    let half = draw(g, &mut incore, &target, &coarse).unwrap();
    eprintln!(
        "labels_{name}_incore at the default step: {}, {:.1} samples per ray",
        compare(&half.color, &reference, SIZE, SIZE),
        samples_per_ray(&half.samples)
    );
    let got = draw(g, &mut incore, &target, &desc).unwrap();
    let label = format!("labels_{name}_incore");
    let cmp = assert_close(&label, &got.color, &reference, SIZE, SIZE, MIN_DB)
        .unwrap_or_else(|e| panic!("{e}"));
    eprintln!(
        "{label}: {cmp}, {:.1} samples per ray",
        samples_per_ray(&got.samples)
    );

    let dir = tempfile::tempdir().unwrap();
    // Smooth boundaries, in core and out of core at the finest level.
    let smooth = RenderSettings {
        smooth_labels: true,
        ..settings()
    };
    let smooth_ref = render_reference(
        vol,
        &frame,
        &tf,
        &camera,
        &smooth,
        &ReferenceOptions::new(SIZE, SIZE),
    )
    .to_rgba8([0.0; 3]);
    let sdesc = FrameDesc {
        settings: smooth,
        ..desc.clone()
    };
    let s_in = draw(g, &mut incore, &target, &sdesc).unwrap();
    let label = format!("labels_{name}_smooth_incore");
    let cmp = assert_close(&label, &s_in.color, &smooth_ref, SIZE, SIZE, MIN_DB)
        .unwrap_or_else(|e| panic!("{e}"));
    eprintln!(
        "{label}: {cmp}; nearest vs smooth: {}",
        compare(&got.color, &s_in.color, SIZE, SIZE)
    );
    let mut ooc = VolumeRenderer::new(&g.device, target_desc()).unwrap();
    let config = ooc_config(0.0);
    ooc.set_volume_source(&g.device, &g.queue, store(vol, dir.path()), config)
        .unwrap();
    ooc.set_transfer_function(&g.device, &g.queue, &tf).unwrap();
    draw_until_settled(g, &mut ooc, &target, &sdesc, 300)
        .unwrap()
        .expect("out of core settles");
    let label = format!("labels_{name}_smooth_ooc_finest");
    let cmp = assert_close(
        &label,
        &target.read_color(g),
        &smooth_ref,
        SIZE,
        SIZE,
        MIN_DB,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    eprintln!("{label}: {cmp}");

    // Smooth boundaries shaded by their indicator's gradient, in core and
    // out of core at the finest level.
    let shaded = RenderSettings {
        shading: brickray::Shading {
            enabled: true,
            ..Default::default()
        },
        ..smooth
    };
    let shaded_ref = render_reference(
        vol,
        &frame,
        &tf,
        &camera,
        &shaded,
        &ReferenceOptions::new(SIZE, SIZE),
    )
    .to_rgba8([0.0; 3]);
    let hdesc = FrameDesc {
        settings: shaded,
        ..desc.clone()
    };
    let h_in = draw(g, &mut incore, &target, &hdesc).unwrap();
    let label = format!("labels_{name}_smooth_shaded_incore");
    let cmp = assert_close(&label, &h_in.color, &shaded_ref, SIZE, SIZE, MIN_DB)
        .unwrap_or_else(|e| panic!("{e}"));
    let change = compare(&s_in.color, &h_in.color, SIZE, SIZE);
    eprintln!("{label}: {cmp}; unshaded vs shaded: {change}");
    assert!(change.psnr_db < 40.0, "shading shows: {change}");
    draw_until_settled(g, &mut ooc, &target, &hdesc, 300)
        .unwrap()
        .expect("out of core settles");
    let label = format!("labels_{name}_smooth_shaded_ooc_finest");
    let cmp = assert_close(
        &label,
        &target.read_color(g),
        &shaded_ref,
        SIZE,
        SIZE,
        MIN_DB,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    eprintln!("{label}: {cmp}");

    // The same ids as an intensity volume, as brickray drew a label map
    // before it knew labels: trilinear samples, averaged coarse levels.
    let mut as_intensity = Volume::new(
        brickray::VolumeDesc {
            kind: brickray::VolumeKind::Intensity,
            ..vol.desc().clone()
        },
        vol.data().clone(),
    )
    .unwrap();
    as_intensity.set_value_range(labels::label_value_range());
    let mut finest = None;
    let mut two_px = Vec::new();
    for (kind, volume, tolerances) in [
        ("ooc", vol, &[0.0f32, 1.0, 2.0, 4.0][..]),
        ("averaged_ooc", &as_intensity, &[0.0, 2.0][..]),
    ] {
        let source = store(volume, dir.path());
        for &tolerance_px in tolerances {
            let mut ooc = VolumeRenderer::new(&g.device, target_desc()).unwrap();
            let config = ooc_config(tolerance_px);
            ooc.set_volume_source(&g.device, &g.queue, source.clone(), config)
                .unwrap();
            ooc.set_transfer_function(&g.device, &g.queue, &tf).unwrap();
            let frames = draw_until_settled(g, &mut ooc, &target, &desc, 300)
                .unwrap()
                .expect("out of core settles");
            let image = target.read_color(g);
            let bricks = ooc
                .stats()
                .out_of_core
                .map_or(0, |s| s.cache.working_set_bricks);
            match &finest {
                None => {
                    let label = format!("labels_{name}_{kind}_finest");
                    let cmp = assert_close(&label, &image, &reference, SIZE, SIZE, MIN_DB)
                        .unwrap_or_else(|e| panic!("{e}"));
                    eprintln!("{label}: {cmp} after {frames} frames, {bricks} bricks");
                    finest = Some(image);
                }
                Some(f) => {
                    let cmp = compare(&image, f, SIZE, SIZE);
                    if tolerance_px == 2.0 {
                        two_px.push(cmp.psnr_db);
                    }
                    eprintln!(
                        "labels_{name}_{kind}_{tolerance_px}px vs the label finest: {cmp}, {bricks} bricks, {frames} frames"
                    );
                }
            }
        }
    }
    // At 2 px the mode pyramid drawn as labels stays well above the averaged
    // pyramid drawn as intensities (measured +7.6 dB on the atlas, +10.5 dB
    // on the nuclei).
    let [labels_db, averaged_db] = two_px[..] else {
        panic!("two 2 px figures, got {two_px:?}");
    };
    assert!(
        labels_db >= averaged_db + 5.0,
        "{name} at 2 px: labels {labels_db:.1} dB, averaged {averaged_db:.1} dB"
    );
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
fn brodmann_atlas_matches_reference() {
    let Some(vol) = shared_label_map("mricron_brodmann_labels") else {
        return;
    };
    assert_eq!(vol.desc().dtype, brickray::DType::U8);
    check("brodmann", &vol);
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
fn nuclei_u32_match_reference() {
    let Some(vol) = shared_label_map("cells3d_nuclei_labels") else {
        return;
    };
    assert_eq!(vol.desc().dtype, brickray::DType::U32);
    check("nuclei", &vol);
}

/// A labelled phantom: background 0, four blobs with ids 3, 7, 9 and 1500.
fn phantom(n: u32) -> Volume {
    let mut data = Vec::with_capacity((n * n * n) as usize);
    let blobs = [
        ([0.3, 0.3, 0.3], 0.18, 3u32),
        ([0.7, 0.35, 0.5], 0.2, 7),
        ([0.5, 0.7, 0.6], 0.22, 9),
        ([0.3, 0.7, 0.25], 0.12, 1500),
    ];
    for z in 0..n {
        for y in 0..n {
            for x in 0..n {
                let p = [x, y, z].map(|c| (c as f32 + 0.5) / n as f32);
                let id = blobs
                    .iter()
                    .find(|(c, r, _)| {
                        let d: f32 = (0..3).map(|a| (p[a] - c[a]).powi(2)).sum();
                        d.sqrt() < *r
                    })
                    .map_or(0, |b| b.2);
                data.push(id);
            }
        }
    }
    labels::label_volume([n; 3], [1.0; 3], brickray::core::VolumeData::U32(data)).unwrap()
}

#[test]
fn hidden_labels_are_skipped_and_change_nothing_else() {
    let g = gpu();
    let vol = phantom(64);
    let d = vol.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let camera = Camera::orbit(frame.center(), 2.0, 0.6, 0.3);
    let mut t = table();
    t.show_only(&[1500]);
    let tf = t.to_transfer_function();
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let mut r = VolumeRenderer::new(&g.device, target_desc()).unwrap();
    r.set_volume(&g.device, &g.queue, &vol).unwrap();
    r.set_transfer_function(&g.device, &g.queue, &tf).unwrap();
    let mut images = Vec::new();
    for ess in [true, false] {
        let mut s = settings();
        s.accel.empty_space_skipping = ess;
        let desc = FrameDesc {
            settings: s,
            ..FrameDesc::new(camera, frame, SIZE, SIZE)
        };
        images.push(draw(g, &mut r, &target, &desc).unwrap());
    }
    let (skip, all) = (&images[0], &images[1]);
    let cmp = compare(&skip.color, &all.color, SIZE, SIZE);
    let (a, b) = (
        samples_per_ray(&skip.samples),
        samples_per_ray(&all.samples),
    );
    eprintln!("hidden labels: skipping {a:.1} vs {b:.1} samples per ray, images {cmp}");
    assert!(cmp.psnr_db >= 60.0, "skipping changed the image: {cmp}");
    assert!(
        a < 0.5 * b,
        "{a:.1} samples per ray with skipping, {b:.1} without"
    );
    // The one visible label is drawn, and matches the reference.
    let reference = render_reference(
        &vol,
        &frame,
        &tf,
        &camera,
        &settings(),
        &ReferenceOptions::new(SIZE, SIZE),
    )
    .to_rgba8([0.0; 3]);
    assert!(
        skip.color
            .chunks(4)
            .any(|p| p[0] > 0 || p[1] > 0 || p[2] > 0)
    );
    assert_close("labels_hidden", &skip.color, &reference, SIZE, SIZE, MIN_DB)
        .unwrap_or_else(|e| panic!("{e}"));
}

#[test]
fn float_volumes_are_not_label_maps() {
    let v = brickray::core::VolumeData::F32(vec![1.0; 8]);
    let e = labels::label_volume([2, 2, 2], [1.0; 3], v).unwrap_err();
    assert!(e.to_string().contains("u8, u16 or u32"), "{e}");
}

/// Picks 1,000 pixels (a fixed pseudo-random set) on the GPU and finds the
/// labels under them; the CPU reference's depth image, unprojected the same
/// way, gives its own. Where the reference's 8 neighbouring pixels show the
/// same label as the pixel (not on a boundary), the two agree everywhere;
/// returns (agreeing, compared, on a boundary and disagreeing).
fn check_picks(name: &str, vol: &Volume) -> (usize, usize, usize) {
    let g = gpu();
    let d = vol.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let tf = table().to_transfer_function();
    let camera = Camera::orbit(frame.center(), 2.0, 0.6, 0.3);
    // Depth where the opacity reaches 0.25: no exact tie with the table's
    // per-step opacities.
    let s = RenderSettings {
        depth_opacity: 0.25,
        ..settings()
    };
    let reference = render_reference(
        vol,
        &frame,
        &tf,
        &camera,
        &s,
        &ReferenceOptions::new(SIZE, SIZE),
    );
    let label_of = |depth: f32, px: [u32; 2]| {
        camera
            .unproject(&frame, [SIZE, SIZE], px, depth)
            .map(|(tex, _)| labels::label_at(vol, tex))
    };
    let ref_label = |x: i64, y: i64| -> Option<u32> {
        if x < 0 || y < 0 || x >= SIZE as i64 || y >= SIZE as i64 {
            return None;
        }
        let depth = reference.depth[(y * SIZE as i64 + x) as usize];
        label_of(depth, [x as u32, y as u32])
    };
    let mut h = 0x2545_f491_4f6c_dd1du64;
    let pixels: Vec<[u32; 2]> = (0..1000)
        .map(|_| {
            h ^= h << 13;
            h ^= h >> 7;
            h ^= h << 17;
            [(h % SIZE as u64) as u32, ((h >> 20) % SIZE as u64) as u32]
        })
        .collect();
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let mut r = VolumeRenderer::new(&g.device, target_desc()).unwrap();
    r.set_volume(&g.device, &g.queue, vol).unwrap();
    r.set_transfer_function(&g.device, &g.queue, &tf).unwrap();
    r.request_picks(&pixels).unwrap();
    let desc = FrameDesc {
        settings: s,
        ..FrameDesc::new(camera, frame, SIZE, SIZE)
    };
    let mut picks = Vec::new();
    for _ in 0..5 {
        brickray_harness::draw_frame(g, &mut r, &target, &desc, None).unwrap();
        picks.extend(r.take_picks());
        if !picks.is_empty() {
            break;
        }
    }
    assert_eq!(picks.len(), pixels.len(), "every pick read back");
    let (mut agree, mut compared, mut boundary_misses) = (0, 0, 0);
    for p in &picks {
        let gpu_label = p.point.map(|q| labels::label_at(vol, q.texture));
        let [x, y] = p.pixel.map(i64::from);
        let mine = ref_label(x, y);
        let interior = (-1..=1).all(|dy| (-1..=1).all(|dx| ref_label(x + dx, y + dy) == mine));
        if interior {
            compared += 1;
            assert_eq!(
                gpu_label, mine,
                "{name}: pixel {:?} picks {gpu_label:?}, the reference {mine:?}",
                p.pixel
            );
            agree += 1;
        } else if gpu_label != mine {
            boundary_misses += 1;
        }
    }
    eprintln!(
        "picks {name}: {agree} of {compared} interior pixels agree; {boundary_misses} of {} boundary pixels differ",
        picks.len() - compared
    );
    assert!(compared > 500, "{name}: only {compared} interior pixels");
    (agree, compared, boundary_misses)
}

#[test]
fn picks_find_the_reference_labels() {
    check_picks("phantom", &phantom(64));
    if let Some(vol) = shared_label_map("mricron_brodmann_labels") {
        check_picks("brodmann", &vol);
    }
}

/// Slices of a label map: an axial, a coronal and an oblique slice, in core
/// and out of core, against `render_label_slice` (front sample at the
/// nearest voxel, the label's colour, hidden labels transparent), with one
/// label hidden.
#[test]
fn label_slices_match_the_reference() {
    let g = gpu();
    let vol = phantom(64);
    let d = vol.desc();
    let f = VolumeFrame::centered(d.dims, d.spacing);
    let mut t = table();
    t.set_visible(7, false);
    let tf = t.to_transfer_function();
    let dir = tempfile::tempdir().unwrap();
    let mut incore = VolumeRenderer::new(&g.device, target_desc()).unwrap();
    incore.set_volume(&g.device, &g.queue, &vol).unwrap();
    let mut ooc = VolumeRenderer::new(&g.device, target_desc()).unwrap();
    let config = ooc_config(0.0);
    ooc.set_volume_source(&g.device, &g.queue, store(&vol, dir.path()), config)
        .unwrap();
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let views = [
        brickray::SliceView::orthogonal(brickray::SliceAxis::Axial, 20.0, &f, 1.0).unwrap(),
        // (Not 40.5: halfway between two voxel centres the nearest voxel is a
        // tie, which each path may break its own way.)
        brickray::SliceView::orthogonal(brickray::SliceAxis::Coronal, 40.3, &f, 1.0).unwrap(),
        brickray::SliceView::with_normal([30.0, 25.0, 20.0], [1.0, 2.0, 3.0], 0.9).unwrap(),
    ];
    for (i, s) in views.iter().enumerate() {
        let cpu = brickray_reference::render_label_slice(&vol, &f, s, &tf, SIZE, SIZE)
            .unwrap()
            .to_rgba8([0.0; 3]);
        assert!(cpu.chunks(4).any(|p| p[0] > 0 || p[1] > 0 || p[2] > 0));
        for (name, r) in [("incore", &mut incore), ("ooc", &mut ooc)] {
            r.set_transfer_function(&g.device, &g.queue, &tf).unwrap();
            r.set_slice(Some(*s));
            let desc = FrameDesc::new(Camera::orbit(f.center(), 2.0, 0.3, 0.2), f, SIZE, SIZE);
            draw_until_settled(g, r, &target, &desc, 200)
                .unwrap()
                .expect("settles");
            let label = format!("label_slice_{i}_{name}");
            let cmp = assert_close(&label, &target.read_color(g), &cpu, SIZE, SIZE, MIN_DB)
                .unwrap_or_else(|e| panic!("{e}"));
            eprintln!("{label}: {cmp}");
        }
    }
}
