//! Closed-form checks of the reference against the rendering model.

#![allow(clippy::needless_range_loop)] // channel loops over parallel arrays read best indexed

use brickray_core::camera::Projection;
use brickray_core::synthetic;
use brickray_core::{DType, VolumeData, VolumeDesc};
use glam::{Mat4, Vec3};

use super::*;

const NEAR: f32 = 0.5;
const FAR: f32 = 10.0;

pub(super) fn f32_volume(
    dims: [u32; 3],
    spacing: [f32; 3],
    range: [f32; 2],
    f: impl Fn(u32, u32, u32) -> f32,
) -> Volume {
    let mut data = Vec::new();
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                data.push(f(x, y, z));
            }
        }
    }
    Volume::new(
        VolumeDesc {
            dims,
            dtype: DType::F32,
            spacing,
            value_range: range,
            kind: Default::default(),
        },
        VolumeData::F32(data),
    )
    .unwrap()
}

/// A frame placing texture space as the box `size` centred at the origin.
fn box_frame(size: Vec3, dims: [u32; 3]) -> VolumeFrame {
    VolumeFrame::new(
        Mat4::from_translation(-size * 0.5) * Mat4::from_scale(size),
        dims,
    )
}

pub(super) fn ortho(eye: Vec3, height: f32) -> Camera {
    Camera {
        eye,
        target: Vec3::ZERO,
        up: Vec3::Y,
        projection: Projection::Orthographic { height },
        near: NEAR,
        far: FAR,
        depth: brickray_core::DepthConvention::Standard,
    }
}

/// Clip depth of an orthographic camera at world distance `d` from the eye.
fn ortho_depth(d: f64) -> f64 {
    (d - NEAR as f64) / (FAR - NEAR) as f64
}

fn constant_tf(c: [f32; 3], a: f32) -> TransferFunction {
    TransferFunction::from_entries(vec![[c[0], c[1], c[2], a]; 2])
}

pub(super) fn dvr() -> RenderSettings {
    RenderSettings {
        mode: RenderMode::Dvr,
        ..Default::default()
    }
}

/// Number of samples `t0 + k dt < t0 + len`, i.e. `ceil(len / dt)`.
fn sample_count(len: f64, dt: f64) -> u32 {
    (0u32..).take_while(|&k| (k as f64) * dt < len).count() as u32
}

/// The slab of (a): 16 x 16 x 8 voxels, 1 x 1 x 0.999 in the world, so
/// `voxel_world = 1/16` and the z path length is `L = 0.999 = 15.984 voxel_world`,
/// which no step tested divides (so the sample count is not on a rounding edge).
const SLAB_Z: f32 = 0.999;

fn slab() -> (Volume, VolumeFrame) {
    let dims = [16, 16, 8];
    (
        f32_volume(dims, [1.0; 3], [0.0, 1.0], |_, _, _| 0.5),
        box_frame(Vec3::new(1.0, 1.0, SLAB_Z), dims),
    )
}

/// The clip depth, viewed head-on from (0, 0, 3), of the first sample in the
/// slab at which the opacity of a TF of opacity `a` reaches `threshold` at
/// step `sf`.
fn slab_depth(a: f32, sf: f32, vw: f64, threshold: f64) -> f64 {
    let k = (0u32..)
        .find(|&k| 1.0 - (1.0 - a as f64).powf((k + 1) as f64 * sf as f64) >= threshold)
        .unwrap();
    ortho_depth(3.0 - (SLAB_Z as f64 * 0.5 - k as f64 * sf as f64 * vw))
}

/// Every pixel of `img` is `alpha` of the colour `rgb` (premultiplied) at
/// `depth`, to 1e-6.
fn assert_slab(img: &Image, alpha: f64, rgb: [f32; 3], depth: f64, what: &str) {
    for (i, c) in img.color.iter().enumerate() {
        assert!(
            (c[3] as f64 - alpha).abs() < 1e-6,
            "{what} px={i}: {} vs {alpha}",
            c[3]
        );
        for k in 0..3 {
            assert!(
                (c[k] as f64 - alpha * rgb[k] as f64).abs() < 1e-6,
                "{what} px={i}"
            );
        }
        assert!(
            (img.depth[i] as f64 - depth).abs() < 1e-6,
            "{what}: depth {} vs {depth}",
            img.depth[i]
        );
    }
}

/// (a) A constant slab viewed along its axis accumulates `1 - (1 - a)^(L/voxel_world)`,
/// whatever the step: the discrete sum is exactly `1 - (1 - a)^(N * step)` with
/// `N = ceil(L / dt)` samples, which here is the continuous answer to within one step.
/// (a') With early termination (`ReferenceOptions::early_termination`), a ray
/// stopped in the slab gathers the continuous answer exactly.
#[test]
fn constant_slab_opacity_is_step_independent() {
    let (vol, frame) = slab();
    assert!((frame.voxel_world - 1.0 / 16.0).abs() < 1e-9);
    let vw = frame.voxel_world as f64;
    let len = SLAB_Z as f64;
    let cam = ortho(Vec3::new(0.0, 0.0, 3.0), 0.8);
    let rgb = [0.2f32, 0.6, 1.0];
    for a in [0.05f32, 0.1, 0.3] {
        let tf = constant_tf(rgb, a);
        let continuous = 1.0 - (1.0 - a as f64).powf(len / vw);
        let mut seen = Vec::new();
        for sf in [1.0f32, 0.5, 0.25, 0.125] {
            let opts = ReferenceOptions::new(4, 4).with_step_factor(sf);
            let img = render_reference(&vol, &frame, &tf, &cam, &dvr(), &opts);
            let n = sample_count(len, sf as f64 * vw);
            let exact = 1.0 - (1.0 - a as f64).powf(n as f64 * sf as f64);
            // Depth: the first sample at which A >= 0.5.
            let depth = slab_depth(a, sf, vw, 0.5);
            assert_slab(&img, exact, rgb, depth, &format!("a={a} sf={sf}"));
            assert!(
                (img.color[0][3] as f64 - continuous).abs() < 1e-3,
                "a={a} sf={sf}"
            );
            seen.push(img.color[5][3]);
            // Stopped at 0.33 (below the depth opacity; no step tested puts a
            // sample on it), the fill gathers the continuous answer exactly,
            // at every step: the mean extinction of the pieces the ray
            // crossed, continued over the rest of the slab, is the slab's
            // own. The ray has its depth where it stops.
            let stopped = opts.with_early_termination(0.33);
            let img = render_reference(&vol, &frame, &tf, &cam, &dvr(), &stopped);
            let depth = slab_depth(a, sf, vw, 0.33);
            assert_slab(
                &img,
                continuous,
                rgb,
                depth,
                &format!("stopped, a={a} sf={sf}"),
            );
        }
        for s in &seen {
            assert!((s - seen[3]).abs() < 1e-3, "{seen:?}");
        }
    }
}

proptest::proptest! {
    /// The fill's share of the residual makes any uniform medium exact: `k`
    /// pieces of opacity `a` composited, then the fill over `n` more,
    /// gather what `k + n` pieces would; and the share lies in 0..=1.
    #[test]
    fn ert_fill_continues_a_uniform_medium_exactly(
        a in 1e-4f64..0.9,
        k in 1u32..200,
        n in 0.0f64..300.0,
    ) {
        let gathered = 1.0 - (1.0 - a).powi(k as i32);
        let share = ert_fill(gathered, n / k as f64);
        proptest::prop_assert!((0.0..=1.0).contains(&share));
        let filled = gathered + (1.0 - gathered) * share;
        let exact = 1.0 - (1.0 - a).powf(k as f64 + n);
        proptest::prop_assert!((filled - exact).abs() < 1e-9, "{filled} vs {exact}");
    }
}

/// A linear ramp along z: raw value = z index over 32 slices, normalized by 0..31,
/// in an 8 x 8 x 32 grid (a 0.25 x 0.25 x 1 box).
fn ramp() -> (Volume, VolumeFrame) {
    let dims = [8, 8, 32];
    (
        f32_volume(dims, [1.0; 3], [0.0, 31.0], |_, _, z| z as f32),
        VolumeFrame::centered(dims, [1.0; 3]),
    )
}

/// World z of the plane where the ramp equals `iso`: `p_z = 31 iso`,
/// `u_z = (p_z + 0.5) / 32`.
fn ramp_plane(iso: f64) -> f64 {
    -0.5 + (31.0 * iso + 0.5) / 32.0
}

const ISO_COLOR: [f32; 3] = [0.5, 0.25, 0.1];

pub(super) fn iso(value: f32) -> RenderSettings {
    RenderSettings {
        mode: RenderMode::Iso {
            value,
            color: ISO_COLOR,
        },
        ..Default::default()
    }
}

/// `shade(ISO_COLOR, n)` with `|n . L| = 1` and the default weights.
fn head_on_iso_color() -> [f64; 3] {
    let s = Shading::default();
    ISO_COLOR
        .map(|c| (c as f64 * (s.ambient + s.diffuse) as f64 + s.specular as f64).clamp(0.0, 1.0))
}

/// (b) Iso on a linear ramp: the hit is the analytic plane, head-on shading is
/// exact, a first sample inside gives a capped cut at the entry.
#[test]
fn iso_on_ramp_hits_the_analytic_plane() {
    let (vol, frame) = ramp();
    let tf = constant_tf([1.0; 3], 1.0);
    let iso_v = 0.3;
    let z_hit = ramp_plane(iso_v);
    let expected_color = head_on_iso_color();

    // Orthographic from -z: every pixel hits the plane.
    let cam = ortho(Vec3::new(0.0, 0.0, -3.0), 0.2);
    let img = render_reference(
        &vol,
        &frame,
        &tf,
        &cam,
        &iso(iso_v as f32),
        &ReferenceOptions::new(5, 5),
    );
    let depth = ortho_depth(3.0 + z_hit);
    // Bisection leaves at most dt / 2^(steps + 1) of error in t.
    let tol = (0.125 * frame.voxel_world as f64) / 512.0 / (FAR - NEAR) as f64 + 1e-7;
    for (c, d) in img.color.iter().zip(&img.depth) {
        assert!((*d as f64 - depth).abs() < tol, "{d} vs {depth}");
        assert_eq!(c[3], 1.0);
        for k in 0..3 {
            assert!(
                (c[k] as f64 - expected_color[k]).abs() < 1e-6,
                "{c:?} vs {expected_color:?}"
            );
        }
    }

    // Without refinement the hit is the middle of the sample interval: within dt / 2.
    let coarse = RenderSettings {
        iso_refine_steps: 0,
        ..iso(iso_v as f32)
    };
    let img0 = render_reference(
        &vol,
        &frame,
        &tf,
        &cam,
        &coarse,
        &ReferenceOptions::new(5, 5),
    );
    let half_dt = 0.5 * 0.125 * frame.voxel_world as f64 / (FAR - NEAR) as f64;
    assert!((img0.depth[12] as f64 - depth).abs() <= half_dt + 1e-7);

    // Perspective, slightly off axis: every hit unprojects onto the plane.
    let cam = Camera {
        eye: Vec3::new(0.0, 0.0, -3.0),
        target: Vec3::new(0.01, 0.02, 0.0),
        up: Vec3::Y,
        projection: Projection::Perspective {
            fov_y: 3f32.to_radians(),
        },
        near: 1.0,
        far: 5.0,
        depth: brickray_core::DepthConvention::Standard,
    };
    let (w, h) = (9u32, 7u32);
    let img = render_reference(
        &vol,
        &frame,
        &tf,
        &cam,
        &iso(iso_v as f32),
        &ReferenceOptions::new(w, h),
    );
    let ivp = cam.view_proj(w as f32 / h as f32).as_dmat4().inverse();
    for py in 0..h {
        for px in 0..w {
            let d = img.depth_at(px, py) as f64;
            assert!(d < 1.0, "pixel ({px}, {py}) missed");
            let ndc = DVec3::new(
                2.0 * (px as f64 + 0.5) / w as f64 - 1.0,
                1.0 - 2.0 * (py as f64 + 0.5) / h as f64,
                d,
            );
            let p = ivp.project_point3(ndc);
            assert!(
                (p.z - z_hit).abs() < 2e-5,
                "({px}, {py}): z {} vs {z_hit}",
                p.z
            );
            assert!(p.x.abs() < 0.125 && p.y.abs() < 0.125);
        }
    }

    // Oblique view: Blinn-Phong with |n . L| = cos(angle to the plane's normal).
    let eye = Vec3::new(0.0, 0.6, -2.0);
    let cam = ortho(eye, 0.05);
    let img = render_reference(
        &vol,
        &frame,
        &tf,
        &cam,
        &iso(iso_v as f32),
        &ReferenceOptions::new(3, 3),
    );
    let cos = 2.0 / (eye.length() as f64);
    let s = Shading::default();
    for c in &img.color {
        for k in 0..3 {
            let e = ISO_COLOR[k] as f64 * (s.ambient as f64 + s.diffuse as f64 * cos)
                + s.specular as f64 * cos.powf(s.shininess as f64);
            assert!(
                (c[k] as f64 - e).abs() < 1e-6,
                "{c:?}: channel {k} expected {e}"
            );
        }
    }

    // From +z the first sample (v = 1 at the z = 0.5 face) is inside: capped at t0.
    let cam = ortho(Vec3::new(0.0, 0.0, 3.0), 0.2);
    let img = render_reference(
        &vol,
        &frame,
        &tf,
        &cam,
        &iso(iso_v as f32),
        &ReferenceOptions::new(3, 3),
    );
    assert!((img.depth[4] as f64 - ortho_depth(2.5)).abs() < 1e-6);
    assert_eq!(img.color[4][3], 1.0);
}

/// DVR shading on the ramp viewed head-on: every sample is shaded to
/// `min(c + specular, 1)`, so `C = A * shaded colour`.
#[test]
fn dvr_shading_head_on() {
    let (vol, frame) = ramp();
    let rgb = [0.2f32, 0.5, 0.9];
    let tf = constant_tf(rgb, 0.05);
    let cam = ortho(Vec3::new(0.0, 0.0, 3.0), 0.2);
    let plain = render_reference(
        &vol,
        &frame,
        &tf,
        &cam,
        &dvr(),
        &ReferenceOptions::new(3, 3),
    );
    let mut s = dvr();
    s.shading.enabled = true;
    let shaded = render_reference(&vol, &frame, &tf, &cam, &s, &ReferenceOptions::new(3, 3));
    let a = plain.color[4][3];
    assert!(a > 0.5);
    assert_eq!(shaded.color[4][3], a);
    for k in 0..3 {
        let expected = a as f64 * (rgb[k] as f64 * 1.0 + 0.2).min(1.0);
        assert!(
            (shaded.color[4][k] as f64 - expected).abs() < 1e-6,
            "{:?}",
            shaded.color[4]
        );
        assert!((plain.color[4][k] - a * rgb[k]).abs() < 1e-6);
    }
    // A constant volume has no gradient: shading leaves it unchanged.
    let (vol, frame) = slab();
    let p = render_reference(
        &vol,
        &frame,
        &tf,
        &cam,
        &dvr(),
        &ReferenceOptions::new(2, 2),
    );
    let q = render_reference(&vol, &frame, &tf, &cam, &s, &ReferenceOptions::new(2, 2));
    assert_eq!(p, q);
}

/// The world normal of a field linear in world space is its gradient direction,
/// for any affine frame (rotated, sheared, anisotropic) and anisotropic spacing.
#[test]
fn normals_are_world_gradients() {
    let dims = [12u32, 9, 7];
    let model = Mat4::from_translation(Vec3::new(0.1, -0.2, 0.3))
        * Mat4::from_axis_angle(Vec3::new(1.0, 2.0, 0.5).normalize(), 0.7)
        * Mat4::from_cols(
            glam::Vec4::new(0.9, 0.0, 0.0, 0.0),
            glam::Vec4::new(0.2, 0.6, 0.0, 0.0),
            glam::Vec4::new(0.0, 0.1, 0.4, 0.0),
            glam::Vec4::W,
        );
    let frame = VolumeFrame::new(model, dims);
    let k = DVec3::new(0.3, -0.5, 0.8);
    let m = model.as_dmat4();
    let vol = f32_volume(dims, [1.0, 2.0, 3.0], [-2.0, 2.0], |x, y, z| {
        let u = (DVec3::new(x as f64, y as f64, z as f64) + 0.5) / DVec3::new(12.0, 9.0, 7.0);
        k.dot(m.transform_point3(u)) as f32
    });
    let tf = constant_tf([1.0; 3], 0.5);
    let cam = Camera::orbit(frame.center(), 3.0, 0.4, 0.3);
    let settings = dvr();
    let marcher = Marcher::new(&vol, &frame, &tf, &cam, &settings, 0.125, 16, 16);
    let ray = marcher.rays.pixel_ray(&marcher.inv_model, 7.5, 8.0, 16, 16);
    let (t0, t1) = ray.clip_unit_box().expect("hits");
    // Interior points (central differences need one voxel of margin).
    let mut checked = 0;
    for i in 0..=20 {
        let t = t0 + (t1 - t0) * i as f64 / 20.0;
        let p = marcher.voxel_pos(&ray, t);
        if (0..3).any(|a| p[a] < 1.0 || p[a] > dims[a] as f64 - 2.0) {
            continue;
        }
        let n = marcher.normal(&ray, t).expect("non-zero gradient");
        assert!(
            (n - k.normalize()).length() < 1e-4,
            "{n} vs {}",
            k.normalize()
        );
        checked += 1;
    }
    assert!(checked >= 5, "{checked}");
}

/// (c) MIP of one bright voxel is seen at its pixel, with the premultiplied lookup
/// of the maximum and the depth of the voxel.
#[test]
fn mip_sees_the_bright_voxel() {
    let dims = [16u32; 3];
    let vol = f32_volume(dims, [1.0; 3], [0.0, 255.0], |x, y, z| {
        if (x, y, z) == (5, 10, 7) { 255.0 } else { 0.0 }
    });
    let frame = VolumeFrame::centered(dims, [1.0; 3]);
    let tf = TransferFunction::from_points(&[(0.0, [0.0; 4]), (1.0, [1.0, 0.5, 0.25, 0.8])], 256);
    let cam = ortho(Vec3::new(0.0, 0.0, 3.0), 1.0);
    let settings = RenderSettings {
        mode: RenderMode::Mip,
        ..Default::default()
    };
    let img = render_reference(
        &vol,
        &frame,
        &tf,
        &cam,
        &settings,
        &ReferenceOptions::new(16, 16),
    );
    // Voxel x = 5 is column 5; voxel y = 10 is world y = 0.15625, row 5 (rows go down).
    let best = (0..256)
        .max_by(|&a, &b| img.color[a][3].total_cmp(&img.color[b][3]))
        .unwrap();
    assert_eq!((best % 16, best / 16), (5, 5));
    let c = img.pixel(5, 5);
    let expected = [0.8, 0.4, 0.2, 0.8];
    for k in 0..4 {
        assert!((c[k] - expected[k]).abs() < 1e-5, "{c:?}");
    }
    // Voxel z = 7 is at world z = -0.5 + 7.5 / 16.
    let depth = ortho_depth(3.0 - (-0.5 + 7.5 / 16.0));
    let dt = 0.125 / 16.0;
    assert!((img.depth_at(5, 5) as f64 - depth).abs() <= dt / (FAR - NEAR) as f64 + 1e-7);
    // Every other pixel samples only zeros (neighbour rays pass through voxel centres).
    for (i, c) in img.color.iter().enumerate() {
        if i != best {
            assert_eq!(*c, [0.0; 4], "pixel {i}");
        }
    }
}

fn sphere_scene() -> (Volume, VolumeFrame) {
    let vol = synthetic::sphere(32);
    let frame = VolumeFrame::centered(vol.dims(), [1.0; 3]);
    (vol, frame)
}

/// (d) Orthographic and perspective cameras on the same axis trace the same
/// centre ray (same samples from the box entry), in every mode.
#[test]
fn ortho_and_perspective_agree_at_the_centre() {
    let (vol, frame) = sphere_scene();
    let tf = TransferFunction::ramp(0.05, 1.0, 0.4);
    let persp = Camera::orbit(Vec3::ZERO, 3.0, 0.3, 0.2);
    let orth = Camera {
        projection: Projection::Orthographic { height: 1.2 },
        ..persp
    };
    let mut shaded = dvr();
    shaded.shading.enabled = true;
    let modes = [
        dvr(),
        shaded,
        iso(0.4),
        RenderSettings {
            mode: RenderMode::Mip,
            ..Default::default()
        },
    ];
    for s in modes {
        let opts = ReferenceOptions::new(33, 33);
        let a = render_reference(&vol, &frame, &tf, &persp, &s, &opts);
        let b = render_reference(&vol, &frame, &tf, &orth, &s, &opts);
        let (ca, cb) = (a.pixel(16, 16), b.pixel(16, 16));
        assert!(ca[3] > 0.2, "{:?}: {ca:?}", s.mode);
        for k in 0..4 {
            assert!(
                (ca[k] - cb[k]).abs() < 1e-5,
                "{:?}: {ca:?} vs {cb:?}",
                s.mode
            );
        }
    }
}

/// (e) A host depth buffer stops the rays: per row, the plane z = 0, far (1.0), the
/// near plane (0.0: no samples), and the plane z = 0.25.
#[test]
fn host_depth_stops_rays() {
    let (vol, frame) = slab();
    let a = 0.1f64;
    let tf = constant_tf([1.0; 3], a as f32);
    let cam = ortho(Vec3::new(0.0, 0.0, 3.0), 0.8);
    let vp = cam.view_proj(1.0).as_dmat4();
    let depth_of = |z: f64| vp.project_point3(DVec3::new(0.0, 0.0, z)).z as f32;
    let rows = [depth_of(0.0), 1.0, 0.0, depth_of(0.25)];
    let host: Vec<f32> = rows.iter().flat_map(|&d| [d; 4]).collect();
    let opts = ReferenceOptions::new(4, 4).with_host_depth(&host);
    let img = render_reference(&vol, &frame, &tf, &cam, &dvr(), &opts);
    let top = SLAB_Z as f64 * 0.5;
    let dt = 0.125 / 16.0;
    let lens = [top, 2.0 * top, 0.0, top - 0.25];
    for (row, len) in lens.iter().enumerate() {
        let n = sample_count(*len, dt);
        let expected = 1.0 - (1.0 - a).powf(n as f64 * 0.125);
        for px in 0..4 {
            let got = img.pixel(px, row as u32)[3] as f64;
            assert!(
                (got - expected).abs() < 1e-6,
                "row {row}: {got} vs {expected}"
            );
        }
    }
    assert_eq!(img.pixel(0, 2), [0.0; 4]);
    assert_eq!(img.depth_at(0, 2), 1.0);

    // Iso: a surface behind the host depth is not seen, one in front is.
    let (vol, frame) = ramp();
    let cam = ortho(Vec3::new(0.0, 0.0, -3.0), 0.2);
    let vp = cam.view_proj(1.0).as_dmat4();
    let z_hit = ramp_plane(0.3);
    let host = [
        vp.project_point3(DVec3::new(0.0, 0.0, z_hit - 0.01)).z as f32,
        vp.project_point3(DVec3::new(0.0, 0.0, z_hit + 0.01)).z as f32,
    ];
    let opts = ReferenceOptions::new(2, 1).with_host_depth(&host);
    let img = render_reference(&vol, &frame, &tf, &cam, &iso(0.3), &opts);
    assert_eq!(img.color[0], [0.0; 4]);
    assert_eq!(img.color[1][3], 1.0);
}

/// A camera inside the volume starts at its near plane.
#[test]
fn camera_inside_the_volume() {
    let (vol, frame) = slab();
    let a = 0.1f64;
    let tf = constant_tf([1.0; 3], a as f32);
    let cam = Camera {
        eye: Vec3::ZERO,
        target: Vec3::new(0.0, 0.0, -1.0),
        up: Vec3::Y,
        projection: Projection::Perspective {
            fov_y: 1f32.to_radians(),
        },
        near: 0.01,
        far: 5.0,
        depth: brickray_core::DepthConvention::Standard,
    };
    let img = render_reference(
        &vol,
        &frame,
        &tf,
        &cam,
        &dvr(),
        &ReferenceOptions::new(1, 1),
    );
    // From the near plane z = -0.01 to the face z = -0.4995.
    let n = sample_count(SLAB_Z as f64 * 0.5 - 0.01, 0.125 / 16.0);
    let expected = 1.0 - (1.0 - a).powf(n as f64 * 0.125);
    assert!(
        (img.color[0][3] as f64 - expected).abs() < 1e-6,
        "{:?} vs {expected}",
        img.color[0]
    );
}

/// Supersampling averages stratified sub-pixel rays: where every ray sees the
/// same thing it changes nothing; a pixel whose centre lies on the box's edge is
/// half covered.
#[test]
fn supersampling_averages_subpixel_rays() {
    let (vol, frame) = slab();
    let tf = constant_tf([1.0, 0.5, 0.25], 0.2);
    // A 2 x 2 view over 6 x 6 pixels: the box edge x = 0.5 runs through the centres
    // of column 4 (which spans x in [1/3, 2/3]).
    let cam = ortho(Vec3::new(0.0, 0.0, 3.0), 2.0);
    let one = render_reference(
        &vol,
        &frame,
        &tf,
        &cam,
        &dvr(),
        &ReferenceOptions::new(6, 6),
    );
    let full = one.pixel(2, 2);
    for n in [2u32, 4] {
        let img = render_reference(
            &vol,
            &frame,
            &tf,
            &cam,
            &dvr(),
            &ReferenceOptions::new(6, 6).with_supersample(n),
        );
        for k in 0..4 {
            assert!((img.pixel(2, 2)[k] - full[k]).abs() < 1e-6);
            assert!(
                (img.pixel(4, 2)[k] - 0.5 * full[k]).abs() < 1e-6,
                "n={n}: {:?}",
                img.pixel(4, 2)
            );
            // corner pixel (4, 1) spans y in [1/3, 2/3]: a quarter.
            assert!((img.pixel(4, 1)[k] - 0.25 * full[k]).abs() < 1e-6);
        }
        assert_eq!(img.pixel(5, 2), [0.0; 4]);
        // The nearest sub-ray depth is kept.
        assert_eq!(img.depth_at(4, 2), one.depth_at(2, 2));
    }
}

/// The step correction makes a fine-step image of a real volume converge.
#[test]
fn sphere_converges_with_the_step() {
    let (vol, frame) = sphere_scene();
    let tf = TransferFunction::ramp(0.05, 1.0, 0.3);
    let cam = Camera::orbit(Vec3::ZERO, 2.5, 0.5, 0.3);
    let r = |sf: f32| {
        render_reference(
            &vol,
            &frame,
            &tf,
            &cam,
            &dvr(),
            &ReferenceOptions::new(24, 24).with_step_factor(sf),
        )
        .to_rgba8([0.0; 3])
    };
    let (coarse, fine, finer) = (r(0.5), r(0.125), r(1.0 / 16.0));
    let p_fine = crate::psnr(&fine, &finer);
    let p_coarse = crate::psnr(&coarse, &finer);
    assert!(
        p_fine > 40.0 && p_coarse > 30.0 && p_fine >= p_coarse,
        "{p_fine} {p_coarse}"
    );
}

/// The synthetic sphere in each mode: non-empty, transparent corners, mirror
/// symmetric left-right and top-bottom.
#[test]
fn sphere_in_every_mode_is_plausible() {
    let (vol, frame) = sphere_scene();
    let tf = TransferFunction::ramp(0.05, 1.0, 0.3);
    let cam = Camera::orbit(Vec3::ZERO, 2.5, 0.0, 0.0);
    let mut shaded = dvr();
    shaded.shading.enabled = true;
    let modes = [
        dvr(),
        shaded,
        iso(0.5),
        RenderSettings {
            mode: RenderMode::Mip,
            ..Default::default()
        },
    ];
    let n = 32u32;
    for s in modes {
        let img = render_reference(&vol, &frame, &tf, &cam, &s, &ReferenceOptions::new(n, n));
        let covered = img.color.iter().filter(|c| c[3] > 0.01).count();
        assert!(
            img.pixel(n / 2, n / 2)[3] > 0.2,
            "{:?}: {:?}",
            s.mode,
            img.pixel(n / 2, n / 2)
        );
        assert!(img.depth_at(n / 2, n / 2) < 1.0);
        assert!(covered > 20 && covered < 600, "{:?}: {covered}", s.mode);
        for (x, y) in [(0, 0), (n - 1, 0), (0, n - 1), (n - 1, n - 1)] {
            assert_eq!(img.pixel(x, y), [0.0; 4]);
        }
        for y in 0..n {
            for x in 0..n {
                let c = img.pixel(x, y);
                for m in [img.pixel(n - 1 - x, y), img.pixel(x, n - 1 - y)] {
                    for k in 0..4 {
                        assert!(
                            (c[k] - m[k]).abs() < 1e-3,
                            "{:?} ({x}, {y}): {c:?} vs {m:?}",
                            s.mode
                        );
                    }
                }
            }
        }
    }
}

#[test]
fn degenerate_inputs() {
    let (vol, frame) = sphere_scene();
    let tf = TransferFunction::ramp(0.05, 1.0, 0.3);
    let cam = Camera::orbit(Vec3::ZERO, 2.5, 0.0, 0.0);
    let img = render_reference(
        &vol,
        &frame,
        &tf,
        &cam,
        &dvr(),
        &ReferenceOptions::new(0, 5),
    );
    assert!(img.color.is_empty() && img.depth.is_empty());
    // supersample 0 behaves as 1
    let a = render_reference(
        &vol,
        &frame,
        &tf,
        &cam,
        &dvr(),
        &ReferenceOptions::new(4, 4).with_supersample(0),
    );
    let b = render_reference(
        &vol,
        &frame,
        &tf,
        &cam,
        &dvr(),
        &ReferenceOptions::new(4, 4),
    );
    assert_eq!(a, b);
    // Looking away: nothing.
    let away = Camera {
        target: Vec3::new(0.0, 0.0, 5.0),
        ..cam
    };
    let img = render_reference(
        &vol,
        &frame,
        &tf,
        &away,
        &dvr(),
        &ReferenceOptions::new(4, 4),
    );
    assert!(img.color.iter().all(|c| *c == [0.0; 4]) && img.depth.iter().all(|&d| d == 1.0));
}
