//! GPU tests of the in-core ray caster on a real wgpu device (lavapipe in CI):
//! images against the CPU reference (PSNR), accelerations against brute force,
//! host-depth compositing, proportions, typed errors and fallbacks (what a
//! ray's march decides, each against its CPU twin, and the skip rules:
//! `gpu_incore_rays.rs`).
//!
//! Thresholds: GPU vs CPU reference >= 40 dB PSNR (8-bit RGB over black);
//! ERT+ESS vs brute force on the GPU >= 50 dB.

use brickray::{
    Accel, Camera, FrameDesc, Projection, RenderError, RenderMode, RenderSettings, Shading,
    TargetDesc, TransferFunction, Volume, VolumeFrame, VolumeRenderer,
};
use brickray_harness::{GpuContext, Offscreen};
use brickray_reference::{ReferenceOptions, assert_close, render_reference};
use glam::Vec3;

use brickray_harness::{shared_gpu as gpu, target_desc as targets};

#[path = "incore_support.rs"]
#[allow(dead_code)]
mod incore_support;
use incore_support::{Scene, head_ct};

use brickray_harness::ct::{bone as bone_tf, hu, soft_tissue as soft_tissue_tf};

fn gray_ramp() -> TransferFunction {
    TransferFunction::ramp(0.0, 1.0, 1.0)
}

const SHADED: Shading = Shading {
    enabled: true,
    ambient: 0.3,
    diffuse: 0.7,
    specular: 0.2,
    shininess: 24.0,
};

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
fn head_ct_dvr_matches_reference() {
    let Some(vol) = head_ct() else { return };
    let tf = soft_tissue_tf();
    let mut s = Scene::new(&vol, &tf, RenderMode::Dvr, 256);
    s.settings.shading = SHADED;
    s.check_reference("head_ct_dvr", 40.0);
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
fn head_ct_iso_matches_reference() {
    let Some(vol) = head_ct() else { return };
    let tf = bone_tf();
    let s = Scene::new(
        &vol,
        &tf,
        RenderMode::Iso {
            value: hu(400.0),
            color: [0.9, 0.85, 0.75],
        },
        256,
    );
    s.check_reference("head_ct_iso", 40.0);
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
fn head_ct_mip_matches_reference() {
    let Some(vol) = head_ct() else { return };
    let tf = TransferFunction::ramp(hu(-200.0), hu(1500.0), 1.0);
    let s = Scene::new(&vol, &tf, RenderMode::Mip, 256);
    s.check_reference("head_ct_mip", 40.0);
}

/// u8, u16 and f32 real volumes (the i16 one is the head CT above).
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
fn other_shared_volumes_match_reference() {
    for (name, mode, lo, hi) in [
        ("pycortex_s1_t1_mri", RenderMode::Dvr, 0.25, 0.8),
        ("cells3d_nuclei_fluo", RenderMode::Dvr, 0.15, 0.6),
        ("cryoet_tomo", RenderMode::Mip, 0.4, 0.9),
    ] {
        let Some(path) = brickray_harness::shared_volume(name) else {
            return;
        };
        let vol = brickray::io::read_volume(path).unwrap();
        let tf = TransferFunction::from_points(
            &[(lo, [0.2, 0.5, 1.0, 0.0]), (hi, [1.0, 0.9, 0.7, 0.4])],
            256,
        );
        let mut s = Scene::new(&vol, &tf, mode, 128);
        s.settings.shading = SHADED;
        s.check_reference(name, 40.0);
    }
}

#[test]
fn synthetic_volumes_match_reference() {
    let sphere = brickray_core::synthetic::sphere(48);
    let ml = brickray_core::synthetic::marschner_lobb(64);
    let tf = TransferFunction::from_points(
        &[(0.2, [0.3, 0.6, 1.0, 0.0]), (0.9, [1.0, 0.8, 0.5, 0.5])],
        256,
    );
    // Orthographic iso of the sphere.
    let mut s = Scene::new(
        &sphere,
        &tf,
        RenderMode::Iso {
            value: 0.5,
            color: [0.8, 0.8, 0.8],
        },
        96,
    );
    s.camera.projection = Projection::Orthographic { height: 1.5 };
    s.check_reference("sphere_iso_ortho", 40.0);
    // DVR of Marschner-Lobb, shaded.
    let mut s = Scene::new(&ml, &tf, RenderMode::Dvr, 96);
    s.settings.shading = SHADED;
    s.check_reference("ml_dvr", 40.0);
    // The camera inside the volume. Marschner-Lobb's shells are thinner than the
    // default half-voxel step at grazing angles (at 0.5 a few silhouette pixels
    // miss a crossing the reference finds: 38.8 dB), so this case samples at 0.25.
    let mut s = Scene::new(
        &ml,
        &tf,
        RenderMode::Iso {
            value: 0.5,
            color: [0.9, 0.7, 0.5],
        },
        96,
    );
    s.camera = Camera::orbit(s.frame.center(), 0.3, 0.4, 0.2);
    s.settings.step_factor = 0.25;
    s.check_reference("ml_iso_inside", 40.0);
}

/// ERT and ESS, alone and together, give the brute-force image (>= 50 dB).
#[test]
fn accelerations_preserve_the_image() {
    let owned;
    let vol = match head_ct() {
        Some(v) => {
            owned = v;
            &owned
        }
        None => {
            owned = brickray_core::synthetic::marschner_lobb(64);
            &owned
        }
    };
    let is_ct = vol.desc().dtype == brickray::DType::I16;
    let (bone, soft) = if is_ct {
        (bone_tf(), soft_tissue_tf())
    } else {
        (
            TransferFunction::ramp(0.5, 0.6, 1.0),
            TransferFunction::ramp(0.3, 1.0, 0.1),
        )
    };
    let iso = if is_ct { hu(400.0) } else { 0.5 };
    let ramp = gray_ramp();
    let cases: [(&str, RenderMode, &TransferFunction); 4] = [
        ("opaque", RenderMode::Dvr, &bone),
        ("translucent", RenderMode::Dvr, &soft),
        (
            "iso",
            RenderMode::Iso {
                value: iso,
                color: [0.9, 0.9, 0.9],
            },
            &bone,
        ),
        ("mip", RenderMode::Mip, &ramp),
    ];
    for (name, mode, tf) in cases {
        let mut s = Scene::new(vol, tf, mode, 128);
        s.settings.shading = SHADED;
        s.settings.accel = Accel::BRUTE_FORCE;
        let (brute, _) = s.gpu();
        for (label, accel) in [
            ("ert", Accel::ERT_ONLY),
            ("ess", Accel::ESS_ONLY),
            ("both", Accel::default()),
        ] {
            s.settings.accel = accel;
            let (fast, _) = s.gpu();
            let cmp = assert_close(
                &format!("accel_{name}_{label}"),
                &fast,
                &brute,
                128,
                128,
                50.0,
            )
            .unwrap_or_else(|e| panic!("{e}"));
            eprintln!("accel {name} {label}: {cmp}");
        }
    }
}

/// Anisotropic spacing keeps physical proportions: a 32x32x8 slab of spacing
/// (1, 1, 4) seen orthographically from the side is as tall as it is wide.
#[test]
fn anisotropic_spacing_keeps_proportions() {
    let dims = [32u32, 32, 8];
    let data = vec![200u8; (dims[0] * dims[1] * dims[2]) as usize];
    let desc = brickray::VolumeDesc {
        dims,
        dtype: brickray::DType::U8,
        spacing: [1.0, 1.0, 4.0],
        value_range: [0.0, 255.0],
        kind: Default::default(),
    };
    let vol = Volume::new(desc, brickray::core::VolumeData::U8(data)).unwrap();
    let tf = TransferFunction::ramp(0.0, 0.5, 1.0);
    let size = 64;
    let mut s = Scene::new(
        &vol,
        &tf,
        RenderMode::Iso {
            value: 0.5,
            color: [1.0; 3],
        },
        size,
    );
    // Look along -y: x is horizontal, z vertical.
    s.camera = Camera {
        eye: s.frame.center() + Vec3::new(0.0, 3.0, 0.0),
        target: s.frame.center(),
        up: Vec3::Z,
        projection: Projection::Orthographic { height: 1.6 },
        near: 0.1,
        far: 10.0,
        depth: brickray::DepthConvention::Standard,
    };
    let (rgba, _) = s.gpu();
    let covered: Vec<(u32, u32)> = (0..size * size)
        .filter(|i| rgba[(4 * i) as usize] > 0)
        .map(|i| (i % size, i / size))
        .collect();
    let w =
        covered.iter().map(|p| p.0).max().unwrap() - covered.iter().map(|p| p.0).min().unwrap() + 1;
    let h =
        covered.iter().map(|p| p.1).max().unwrap() - covered.iter().map(|p| p.1).min().unwrap() + 1;
    assert!(
        (w as i32 - h as i32).abs() <= 1,
        "silhouette {w}x{h} should be square"
    );
    assert!(
        (38..=42).contains(&w),
        "silhouette width {w} should be 40 px (1.0 of a 1.6-high view)"
    );
}

#[test]
fn typed_errors_not_panics() {
    let g = gpu();
    let mut r = VolumeRenderer::new(&g.device, targets()).unwrap();
    // prepare before a volume, render before prepare.
    let vol = brickray_core::synthetic::sphere(8);
    let frame = VolumeFrame::centered(vol.dims(), [1.0; 3]);
    let desc = FrameDesc {
        camera: Camera::orbit(frame.center(), 2.0, 0.0, 0.0),
        frame,
        viewport: brickray::Viewport::full(16, 16),
        settings: RenderSettings::default(),
        host_depth: None,
        time: None,
    };
    let mut enc = g.device.create_command_encoder(&Default::default());
    assert!(matches!(
        r.prepare(&g.device, &g.queue, &mut enc, &desc),
        Err(brickray::PrepareError::NoVolume)
    ));
    // A volume beyond the 3D texture limit.
    let limit = g.device.limits().max_texture_dimension_3d;
    let desc_big = brickray::VolumeDesc {
        dims: [limit + 1, 1, 1],
        dtype: brickray::DType::U8,
        spacing: [1.0; 3],
        value_range: [0.0, 255.0],
        kind: Default::default(),
    };
    let big = Volume::new(
        desc_big,
        brickray::core::VolumeData::U8(vec![0; limit as usize + 1]),
    )
    .unwrap();
    assert!(matches!(
        r.set_volume(&g.device, &g.queue, &big),
        Err(RenderError::VolumeTooLarge { limit: l, .. }) if l == limit
    ));
    // No TF yet, then a zero viewport, then a bad step.
    r.set_volume(&g.device, &g.queue, &vol).unwrap();
    assert!(matches!(
        r.prepare(&g.device, &g.queue, &mut enc, &desc),
        Err(brickray::PrepareError::NoTransferFunction)
    ));
    r.set_transfer_function(&g.device, &g.queue, &gray_ramp())
        .unwrap();
    let zero = FrameDesc {
        viewport: brickray::Viewport::full(0, 16),
        ..desc.clone()
    };
    assert!(matches!(
        r.prepare(&g.device, &g.queue, &mut enc, &zero),
        Err(brickray::PrepareError::BadViewport { .. })
    ));
    let mut bad = desc.clone();
    bad.settings.step_factor = f32::NAN;
    assert!(matches!(
        r.prepare(&g.device, &g.queue, &mut enc, &bad),
        Err(brickray::PrepareError::Settings(_))
    ));
    // A non-blendable target format.
    let t = TargetDesc::new(wgpu::TextureFormat::R32Uint);
    assert!(matches!(
        VolumeRenderer::new(&g.device, t),
        Err(RenderError::BadTargetFormat(_))
    ));
}

/// Without the optional features (16-bit normalized and filterable 32-bit float
/// textures) the renderer falls back to normalized R16Float textures and still
/// matches the reference, for every dtype that needs them.
#[test]
fn missing_texture_features_fall_back() {
    let g = GpuContext::with_features(wgpu::Features::empty()).expect("a wgpu adapter");
    assert!(
        !g.device
            .features()
            .contains(wgpu::Features::TEXTURE_FORMAT_16BIT_NORM)
    );
    let mut vols = vec![("ml_f32", brickray_core::synthetic::marschner_lobb(48))];
    for name in ["invesalius_cranium_ct", "cells3d_nuclei_fluo"] {
        if let Some(p) = brickray_harness::shared_volume(name) {
            vols.push((name, brickray::io::read_volume(p).unwrap()));
        }
    }
    let tf = TransferFunction::from_points(
        &[(0.3, [0.3, 0.6, 1.0, 0.0]), (0.8, [1.0, 0.8, 0.5, 0.5])],
        256,
    );
    for (name, vol) in &vols {
        let d = vol.desc();
        let frame = VolumeFrame::centered(d.dims, d.spacing);
        let mut r = VolumeRenderer::new(&g.device, targets()).unwrap();
        r.set_volume(&g.device, &g.queue, vol).unwrap();
        if d.dtype != brickray::DType::U8 {
            assert_eq!(
                r.volume_format(),
                Some(wgpu::TextureFormat::R16Float),
                "{name}"
            );
        }
        r.set_transfer_function(&g.device, &g.queue, &tf).unwrap();
        let size = 96;
        let target = Offscreen::new(&g.device, size, size);
        let camera = Camera::orbit(frame.center(), 2.0, 0.5, 0.3);
        let settings = RenderSettings {
            mode: RenderMode::Mip,
            ..Default::default()
        };
        let mut enc = g.device.create_command_encoder(&Default::default());
        let desc = FrameDesc {
            camera,
            frame,
            viewport: brickray::Viewport::full(size, size),
            settings,
            host_depth: None,
            time: None,
        };
        r.prepare(&g.device, &g.queue, &mut enc, &desc).unwrap();
        {
            let mut pass = target.pass(&mut enc, true);
            r.render(&mut pass).unwrap();
        }
        g.submit_wait(enc);
        let gpu_img = target.read_color(&g);
        let cpu = render_reference(
            vol,
            &frame,
            &tf,
            &camera,
            &settings,
            &ReferenceOptions::new(size, size),
        )
        .to_rgba8([0.0; 3]);
        let cmp = assert_close(
            &format!("fallback_{name}"),
            &gpu_img,
            &cpu,
            size,
            size,
            40.0,
        )
        .unwrap_or_else(|e| panic!("{e}"));
        eprintln!("fallback {name}: {cmp}");
    }
}
