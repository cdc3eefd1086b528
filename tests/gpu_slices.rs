//! Slice views (docs/rendering-model.md, "Slice views") and the intensity
//! window on a real wgpu device (lavapipe in CI), against the CPU reference
//! (`brickray_reference::render_slice`, exact trilinear in f64):
//!
//! * axial, coronal, sagittal and oblique planes, a mean and a MIP slab, in
//!   core and out of core (the bricks of the cut, through the index), each
//!   >= 45 dB PSNR (8-bit RGB over black; the values are printed);
//! * a slice and a 3D view of one streamed volume share one pool (one plan a
//!   frame, one working set): adding the slice refines the shared cut, reads
//!   no brick that was already read, and every brick is read once;
//! * MIP through a window and colour map against the reference;
//! * bad planes and windows are typed errors of `prepare`.

use brickray::core::{DType, VolumeData, VolumeDesc};
use brickray::{
    Camera, ColorMap, FrameDesc, Intensity, OutOfCoreConfig, PrepareError, RenderMode,
    RenderSettings, SlabMode, SliceAxis, SliceView, StreamedVolume, TransferFunction, Volume,
    VolumeFrame, VolumeRenderer, Window,
};
use brickray_harness::{CountingSource, Offscreen, shared_gpu as gpu, target_desc as targets};
use brickray_reference::{ReferenceOptions, assert_close, render_reference, render_slice};
use glam::Vec3;
use std::sync::Arc;

const N: u32 = 64;
/// Two pixels per voxel across the fitted slices: the finest level.
const SIZE: u32 = 128;
const MIN_DB: f64 = 45.0;

/// A smooth field with structure on every axis (value range 0..1).
fn field() -> Volume {
    field_of([N; 3], [1.0; 3])
}

fn field_of(dims: [u32; 3], spacing: [f32; 3]) -> Volume {
    let mut data = Vec::with_capacity(dims.iter().map(|&d| d as usize).product());
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let (x, y, z) = (x as f64, y as f64, z as f64);
                let v = 0.5
                    + 0.25 * (x / 5.0).sin() * (y / 7.0).cos()
                    + 0.2 * (z / 6.0 + x / 11.0).sin()
                    + 0.05 * ((x - 32.0).hypot(y - 30.0) / 3.0).cos();
                data.push(v as f32);
            }
        }
    }
    Volume::new(
        VolumeDesc {
            dims,
            dtype: DType::F32,
            spacing,
            value_range: [0.0, 1.0],
            kind: Default::default(),
        },
        VolumeData::F32(data),
    )
    .unwrap()
}

fn frame() -> VolumeFrame {
    VolumeFrame::centered([N; 3], [1.0; 3])
}

/// The slices checked: name, view, intensity.
fn slices() -> Vec<(&'static str, SliceView, Intensity)> {
    let f = frame();
    let grey = Intensity::new(Window::from_min_max(0.0, 1.0).unwrap(), ColorMap::Grey);
    let narrow = Intensity::new(Window::new(0.5, 0.6).unwrap(), ColorMap::Viridis);
    let hot = Intensity::new(Window::new(0.55, 0.7).unwrap(), ColorMap::Hot);
    let ortho = |a, i| SliceView::orthogonal(a, i, &f, 1.0).unwrap();
    let oblique = SliceView::with_normal([31.0, 30.5, 33.0], [1.0, 2.0, 3.0], 0.9).unwrap();
    vec![
        ("axial", ortho(SliceAxis::Axial, 20.0), grey),
        ("coronal", ortho(SliceAxis::Coronal, 33.0), narrow),
        ("sagittal", ortho(SliceAxis::Sagittal, 10.5), grey),
        ("oblique", oblique, hot),
        (
            "axial mean slab",
            ortho(SliceAxis::Axial, 40.0).with_slab(6.0 / N as f64, SlabMode::Mean),
            grey,
        ),
        (
            "oblique max slab",
            oblique.with_slab(4.0 / N as f64, SlabMode::Max),
            narrow,
        ),
    ]
}

fn desc() -> FrameDesc<'static> {
    // The camera is the slice's; this one is never used.
    FrameDesc::new(
        Camera::orbit(Vec3::ZERO, 2.0, 0.3, 0.2),
        frame(),
        SIZE,
        SIZE,
    )
}

/// Prepares and draws the renderers together until none wants a redraw;
/// returns their images.
fn converge(rs: &mut [&mut VolumeRenderer], descs: &[FrameDesc<'_>]) -> Vec<Vec<u8>> {
    let g = gpu();
    let targets: Vec<Offscreen> = rs
        .iter()
        .map(|_| Offscreen::new(&g.device, SIZE, SIZE))
        .collect();
    for _ in 0..400 {
        let mut enc = g.device.create_command_encoder(&Default::default());
        {
            let mut views: Vec<(&mut VolumeRenderer, &FrameDesc<'_>)> =
                rs.iter_mut().map(|r| &mut **r).zip(descs).collect();
            VolumeRenderer::prepare_views(&g.device, &g.queue, &mut enc, &mut views).unwrap();
        }
        for (r, t) in rs.iter().zip(&targets) {
            let mut pass = t.pass_clear(&mut enc, Some(wgpu::Color::BLACK));
            r.render(&mut pass).unwrap();
        }
        g.submit_wait(enc);
        if rs.iter().all(|r| !r.wants_redraw()) {
            return targets.iter().map(|t| t.read_color(g)).collect();
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    panic!("not converged: {:?}", rs[0].stats());
}

fn check(name: &str, gpu_img: &[u8], vol: &Volume, s: &SliceView, i: &Intensity) -> f64 {
    let cpu = render_slice(vol, &frame(), s, i, SIZE, SIZE)
        .unwrap()
        .to_rgba8([0.0; 3]);
    assert!(
        cpu.chunks_exact(4)
            .any(|p| p[0] > 10 || p[1] > 10 || p[2] > 10),
        "{name}: the reference is black"
    );
    let cmp =
        assert_close(name, gpu_img, &cpu, SIZE, SIZE, MIN_DB).unwrap_or_else(|e| panic!("{e}"));
    eprintln!("{name}: {cmp}");
    cmp.psnr_db
}

#[test]
fn slices_match_the_reference_in_core() {
    let g = gpu();
    let vol = field();
    let mut r = VolumeRenderer::new(&g.device, targets()).unwrap();
    r.set_volume(&g.device, &g.queue, &vol).unwrap();
    for (name, s, i) in slices() {
        r.set_slice(Some(s));
        r.set_intensity(Some(i));
        let img = converge(&mut [&mut r], &[desc()]).remove(0);
        check(&format!("in core, {name}"), &img, &vol, &s, &i);
    }
}

/// An anisotropic volume (voxels twice as long along z) in a non-square
/// viewport: the slices' pixels are square in the world, and the image is the
/// reference's.
#[test]
fn anisotropic_slices_match_the_reference() {
    let g = gpu();
    let (dims, spacing) = ([64, 48, 24], [1.0, 1.0, 2.0]);
    let vol = field_of(dims, spacing);
    let f = VolumeFrame::centered(dims, spacing);
    let (w, h) = (160u32, 112u32);
    let aspect = w as f64 / h as f64;
    let grey = Intensity::new(Window::from_min_max(0.0, 1.0).unwrap(), ColorMap::Grey);
    let cases = [
        (
            "axial",
            SliceView::orthogonal(SliceAxis::Axial, 11.0, &f, aspect).unwrap(),
        ),
        (
            "coronal",
            SliceView::orthogonal(SliceAxis::Coronal, 20.5, &f, aspect).unwrap(),
        ),
        (
            "sagittal",
            SliceView::orthogonal(SliceAxis::Sagittal, 40.0, &f, aspect).unwrap(),
        ),
        (
            "oblique",
            SliceView::with_normal([30.0, 22.0, 11.5], [1.0, -1.0, 2.0], 0.8).unwrap(),
        ),
    ];
    let mut r = VolumeRenderer::new(&g.device, targets()).unwrap();
    r.set_volume(&g.device, &g.queue, &vol).unwrap();
    r.set_intensity(Some(grey));
    let target = Offscreen::new(&g.device, w, h);
    for (name, s) in cases {
        r.set_slice(Some(s));
        let d = FrameDesc::new(Camera::orbit(Vec3::ZERO, 2.0, 0.3, 0.2), f, w, h);
        let mut enc = g.device.create_command_encoder(&Default::default());
        r.prepare(&g.device, &g.queue, &mut enc, &d).unwrap();
        {
            let mut pass = target.pass_clear(&mut enc, Some(wgpu::Color::BLACK));
            r.render(&mut pass).unwrap();
        }
        g.submit_wait(enc);
        let img = target.read_color(g);
        let cpu = render_slice(&vol, &f, &s, &grey, w, h)
            .unwrap()
            .to_rgba8([0.0; 3]);
        let name = format!("anisotropic, {name}");
        let cmp = assert_close(&name, &img, &cpu, w, h, MIN_DB).unwrap_or_else(|e| panic!("{e}"));
        eprintln!("{name}: {cmp}");
    }
}

/// A store of `vol` in a temporary directory, read through a counting source.
fn store(vol: Volume, dir: &tempfile::TempDir) -> Arc<CountingSource> {
    CountingSource::store(vol, dir.path(), "field", 16)
}

fn config() -> OutOfCoreConfig {
    OutOfCoreConfig {
        upload_budget_bytes: 1 << 30,
        fade: None,
        ..Default::default()
    }
}

#[test]
fn slices_match_the_reference_out_of_core() {
    let g = gpu();
    let vol = field();
    let dir = tempfile::tempdir().unwrap();
    let src = store(vol.clone(), &dir);
    let volume =
        StreamedVolume::new(&g.device, &g.queue, src, config(), Default::default()).unwrap();
    let mut r = VolumeRenderer::new(&g.device, targets()).unwrap();
    r.set_streamed_volume(&g.device, &volume).unwrap();
    for (name, s, i) in slices() {
        r.set_slice(Some(s));
        r.set_intensity(Some(i));
        let img = converge(&mut [&mut r], &[desc()]).remove(0);
        let levels = r.stats().out_of_core.unwrap().data_leaves_per_level;
        eprintln!("out of core, {name}: data leaves per level {levels:?}");
        check(&format!("out of core, {name}"), &img, &vol, &s, &i);
    }
}

#[test]
fn a_slice_and_a_3d_view_share_one_pool() {
    let g = gpu();
    let vol = field();
    let dir = tempfile::tempdir().unwrap();
    let src = store(vol.clone(), &dir);
    let volume = StreamedVolume::new(
        &g.device,
        &g.queue,
        src.clone(),
        config(),
        Default::default(),
    )
    .unwrap();
    // A distant 3D MIP view: coarse levels.
    let mut view_3d = VolumeRenderer::new(&g.device, targets()).unwrap();
    view_3d.set_streamed_volume(&g.device, &volume).unwrap();
    view_3d
        .set_transfer_function(&g.device, &g.queue, &TransferFunction::ramp(0.0, 1.0, 1.0))
        .unwrap();
    let d3 = FrameDesc {
        settings: RenderSettings {
            mode: RenderMode::Mip,
            ..Default::default()
        },
        ..FrameDesc::new(
            Camera::orbit(Vec3::ZERO, 6.0, 0.5, 0.3),
            frame(),
            SIZE,
            SIZE,
        )
    };
    converge(&mut [&mut view_3d], std::slice::from_ref(&d3));
    let before = src.reads();
    let resident = view_3d
        .stats()
        .out_of_core
        .unwrap()
        .cache
        .working_set_bricks;
    // The slice beside it, prepared together: the cut is refined for the
    // slice, in the same pool.
    let (_, s, i) = slices().remove(0);
    let mut slice = VolumeRenderer::new(&g.device, targets()).unwrap();
    slice.set_streamed_volume(&g.device, &volume).unwrap();
    slice.set_slice(Some(s));
    slice.set_intensity(Some(i));
    let imgs = converge(&mut [&mut view_3d, &mut slice], &[d3.clone(), desc()]);
    assert!(
        view_3d
            .streamed_volume()
            .unwrap()
            .same(slice.streamed_volume().unwrap())
    );
    let (a, b) = (
        view_3d.stats().out_of_core.unwrap(),
        slice.stats().out_of_core.unwrap(),
    );
    assert_eq!(a.cache.frame, b.cache.frame, "planned once per frame");
    assert_eq!(a.cache.working_set_bricks, b.cache.working_set_bricks);
    let after = src.reads();
    let twice: Vec<_> = after.iter().filter(|(_, n)| **n > 1).collect();
    assert!(twice.is_empty(), "bricks read more than once: {twice:?}");
    let added: Vec<_> = after.keys().filter(|k| !before.contains_key(k)).collect();
    eprintln!(
        "3D view alone: {} bricks read, {resident} resident; with the slice: {} more read, {} resident",
        before.len(),
        added.len(),
        a.cache.working_set_bricks
    );
    // The slice refined the one cut (finer bricks than the distant view
    // needs): more bricks resident, none read again.
    assert!(
        a.cache.working_set_bricks > resident,
        "the slice needs finer bricks than the distant 3D view"
    );
    check("shared pool, axial", &imgs[1], &vol, &s, &i);
}

#[test]
fn mip_through_a_window_matches_the_reference() {
    let g = gpu();
    let vol = field();
    let tf = TransferFunction::ramp(0.0, 1.0, 1.0);
    let camera = Camera::orbit(Vec3::ZERO, 2.0, 0.5, 0.3);
    let settings = RenderSettings {
        mode: RenderMode::Mip,
        ..Default::default()
    };
    for (name, map) in [
        ("grey", ColorMap::Grey),
        ("hot", ColorMap::Hot),
        ("viridis", ColorMap::Viridis),
    ] {
        let intensity = Intensity::new(Window::new(0.8, 0.3).unwrap(), map);
        let mut r = VolumeRenderer::new(&g.device, targets()).unwrap();
        r.set_volume(&g.device, &g.queue, &vol).unwrap();
        r.set_transfer_function(&g.device, &g.queue, &tf).unwrap();
        r.set_intensity(Some(intensity));
        let d = FrameDesc {
            settings,
            ..FrameDesc::new(camera, frame(), SIZE, SIZE)
        };
        let img = converge(&mut [&mut r], &[d]).remove(0);
        let cpu = render_reference(
            &vol,
            &frame(),
            &tf,
            &camera,
            &settings,
            &ReferenceOptions::new(SIZE, SIZE).with_intensity(intensity),
        )
        .to_rgba8([0.0; 3]);
        let cmp = assert_close(
            &format!("windowed MIP, {name}"),
            &img,
            &cpu,
            SIZE,
            SIZE,
            40.0,
        )
        .unwrap_or_else(|e| panic!("{e}"));
        eprintln!("windowed MIP, {name}: {cmp}");
    }
}

#[test]
fn bad_slices_and_windows_are_typed_errors() {
    let g = gpu();
    let vol = field();
    let mut r = VolumeRenderer::new(&g.device, targets()).unwrap();
    r.set_volume(&g.device, &g.queue, &vol).unwrap();
    let good = slices().remove(0).1;
    let bad = [
        SliceView {
            centre: [f64::NAN, 0.0, 0.0],
            ..good
        },
        SliceView {
            up: [0.0; 3],
            ..good
        },
        SliceView {
            right: good.up,
            ..good
        },
        SliceView {
            height: -1.0,
            ..good
        },
        good.with_slab(1e6, SlabMode::Mean),
    ];
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    for s in bad {
        r.set_slice(Some(s));
        let mut enc = g.device.create_command_encoder(&Default::default());
        let e = r.prepare(&g.device, &g.queue, &mut enc, &desc());
        assert!(matches!(e, Err(PrepareError::Slice(_))), "{s:?}: {e:?}");
        {
            let mut pass = target.pass_clear(&mut enc, None);
            assert!(
                r.render(&mut pass).is_err(),
                "{s:?}: drawn after a refused frame"
            );
        }
        g.submit_wait(enc);
    }
    // A constant volume has no value range to window through.
    let flat = Volume::new(
        VolumeDesc {
            dims: [4; 3],
            dtype: DType::F32,
            spacing: [1.0; 3],
            value_range: [3.0, 3.0],
            kind: Default::default(),
        },
        VolumeData::F32(vec![3.0; 64]),
    )
    .unwrap();
    r.set_volume(&g.device, &g.queue, &flat).unwrap();
    r.set_slice(Some(
        SliceView::orthogonal(
            SliceAxis::Axial,
            1.0,
            &VolumeFrame::centered([4; 3], [1.0; 3]),
            1.0,
        )
        .unwrap(),
    ));
    r.set_intensity(None);
    let mut enc = g.device.create_command_encoder(&Default::default());
    let d = FrameDesc::new(
        Camera::orbit(Vec3::ZERO, 2.0, 0.3, 0.2),
        VolumeFrame::centered([4; 3], [1.0; 3]),
        16,
        16,
    );
    let e = r.prepare(&g.device, &g.queue, &mut enc, &d);
    assert!(matches!(e, Err(PrepareError::Window(_))), "{e:?}");
    g.submit_wait(enc);
}
