//! The viewer run for real: a window on the X server of `DISPLAY` (Xvfb in
//! CI), on the machine's adapter (lavapipe in CI), driven by `--script`. It
//! opens the shared head CT, loads a transfer function from a JSON file,
//! renders DVR and an isosurface, and its screenshots (the view's pixels read
//! back from egui's frame) are compared with the library's own rendering of the
//! same camera, viewport, TF and settings into an offscreen target.
//!
//! Threshold: PSNR >= 40 dB over RGB. Both paths run the same kernels on the
//! same device, so they differ only where egui's target format and rounding
//! could (measured on lavapipe: bit-identical, PSNR infinite); a different
//! scene scores far below (checked: the DVR screenshot against the library's
//! isosurface image).
//!
//! The third screenshot cuts the head with a clip box (drawn by the library),
//! the fourth and fifth draw DVR with the accelerations the script sets
//! (termination, skipping, the adaptive step, pre-integration): each matches
//! the library's image with those settings, its sidecar records them, and
//! it differs from the defaults' image.
//!
//! Out-of-core runs (a brick store, a procedural volume, the out-of-core
//! settings the script reaches) are in `scripted/streamed.rs`.

use brickray::{
    Camera, ClipBox, DepthConvention, FrameDesc, Projection, RenderMode, RenderSettings,
    TransferFunction, VolumeFrame, VolumeRenderer,
};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

#[path = "scripted/anatomy.rs"]
mod anatomy;
#[path = "scripted/channels.rs"]
mod channels;
#[path = "scripted/labels.rs"]
mod labels;
#[path = "scripted/streamed.rs"]
mod streamed;

/// The required PSNR of a screenshot against the library's image.
const MIN_PSNR_DB: f64 = 40.0;

/// Pixels of an RGBA8 screenshot with a channel above 20: what a test
/// checks the view shows something with before comparing it.
fn lit_pixels(shot: &[u8]) -> usize {
    shot.chunks(4)
        .filter(|p| p[..3].iter().any(|&c| c > 20))
        .count()
}

/// Hounsfield units to the head CT's normalized value (range -1024..2986).
fn hu(v: f32) -> f32 {
    (v + 1024.0) / 4010.0
}

/// The bone TF, as control points shared by colour and opacity.
fn bone_points() -> [(f32, [f32; 4]); 2] {
    [
        (hu(250.0), [0.9, 0.85, 0.75, 0.0]),
        (hu(600.0), [1.0, 0.95, 0.85, 1.0]),
    ]
}

fn tf_json() -> String {
    let [(x0, c0), (x1, c1)] = bone_points();
    format!(
        r#"{{"colors": [{{"x": {x0}, "rgb": [{}, {}, {}]}}, {{"x": {x1}, "rgb": [{}, {}, {}]}}],
            "opacity": [{{"x": {x0}, "a": {}}}, {{"x": {x1}, "a": {}}}]}}"#,
        c0[0], c0[1], c0[2], c1[0], c1[1], c1[2], c0[3], c1[3]
    )
}

/// A temporary folder for a windowed test, or `None` (the test returns)
/// without a display ([`display_available`]).
fn windowed_test_dir() -> Option<tempfile::TempDir> {
    display_available().then(|| tempfile::tempdir().expect("temp dir"))
}

fn display_available() -> bool {
    if std::env::var_os("DISPLAY").is_some() || std::env::var_os("WAYLAND_DISPLAY").is_some() {
        return true;
    }
    assert!(
        std::env::var("CI").as_deref() != Ok("true"),
        "CI=true but no display: run the tests under Xvfb (scripts/test.sh starts one)"
    );
    eprintln!("skipping: no display (DISPLAY unset; scripts/test.sh starts Xvfb)");
    false
}

/// Runs the viewer with `script`, killing it after `limit`.
fn run_viewer(script: &Path, limit: Duration) -> std::process::Output {
    run_viewer_with(script, limit, &[])
}

/// [`run_viewer`] with more command-line arguments.
fn run_viewer_with(script: &Path, limit: Duration, args: &[&str]) -> std::process::Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_brickray-viewer"))
        .args(["--window", "640x400"])
        .args(args)
        .arg("--script")
        .arg(script)
        // As on a bare X server: the viewer makes its own runtime directory
        // (no library complains of a missing one; `run_script` checks).
        .env_remove("XDG_RUNTIME_DIR")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("start the viewer");
    let t = Instant::now();
    while child.try_wait().expect("wait for the viewer").is_none() {
        if t.elapsed() > limit {
            let _ = child.kill();
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    child.wait_with_output().expect("the viewer's output")
}

/// Writes `script` to `dir/script.txt`, runs the viewer on it (killed after
/// `limit`) and asserts that every action succeeded.
fn run_script(dir: &Path, script: &str, limit: Duration) {
    run_script_with(dir, script, limit, &[]);
}

/// [`run_script`] with more command-line arguments.
fn run_script_with(dir: &Path, script: &str, limit: Duration, args: &[&str]) {
    let path = dir.join("script.txt");
    std::fs::write(&path, script).expect("write the script");
    let run = run_viewer_with(&path, limit, args);
    assert!(
        run.status.success(),
        "the viewer failed ({:?}): {}",
        run.status,
        String::from_utf8_lossy(&run.stderr)
    );
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(
        !err.contains("XDG_RUNTIME_DIR"),
        "the viewer's launch printed a runtime-directory warning: {err}"
    );
}

/// The JSON sidecar of a screenshot.
fn sidecar_json(png: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(png.with_extension("json")).expect("the sidecar");
    serde_json::from_str(&text).expect("sidecar JSON")
}

/// A brick store of a 96^3 sphere (with error records) in `dir`.
fn sphere_store(dir: &Path) -> PathBuf {
    let store = dir.join("sphere.brs");
    brickray_harness::store_of(&brickray::core::synthetic::sphere(96), &store);
    store
}

/// The camera and viewport size recorded next to a screenshot.
fn sidecar(png: &Path) -> (Camera, u32, u32) {
    let v = sidecar_json(png);
    let f = |v: &serde_json::Value| v.as_f64().expect("a number") as f32;
    let v3 = |v: &serde_json::Value| glam::Vec3::new(f(&v[0]), f(&v[1]), f(&v[2]));
    let c = &v["camera"];
    let projection = match c["projection"].get("perspective") {
        Some(p) => Projection::Perspective {
            fov_y: f(&p["fov_y"]),
        },
        None => Projection::Orthographic {
            height: f(&c["projection"]["orthographic"]["height"]),
        },
    };
    let camera = Camera {
        eye: v3(&c["eye"]),
        target: v3(&c["target"]),
        up: v3(&c["up"]),
        projection,
        near: f(&c["near"]),
        far: f(&c["far"]),
        depth: DepthConvention::Standard,
    };
    let size = |i: usize| v["viewport"][i].as_u64().expect("viewport") as u32;
    (camera, size(0), size(1))
}

/// The library's rendering of the head CT with `settings`, for the camera
/// and viewport of a screenshot.
fn library_image(
    volume: &brickray::Volume,
    camera: Camera,
    w: u32,
    h: u32,
    settings: RenderSettings,
) -> Vec<u8> {
    let d = volume.desc();
    let desc = FrameDesc {
        settings,
        ..FrameDesc::new(camera, VolumeFrame::centered(d.dims, d.spacing), w, h)
    };
    library_render(volume, &desc, None, None)
}

/// The library's in-core rendering of `volume` for `desc` with the bone TF
/// (the viewer samples its editor's points into 1024 entries), a slice view
/// and a window if given.
fn library_render(
    volume: &brickray::Volume,
    desc: &FrameDesc,
    slice: Option<brickray::SliceView>,
    intensity: Option<brickray::Intensity>,
) -> Vec<u8> {
    let gpu = brickray_harness::shared_gpu();
    let mut renderer =
        VolumeRenderer::new(&gpu.device, brickray_harness::target_desc()).expect("renderer");
    renderer
        .set_volume(&gpu.device, &gpu.queue, volume)
        .expect("volume");
    let tf = TransferFunction::from_points(&bone_points(), 1024);
    renderer
        .set_transfer_function(&gpu.device, &gpu.queue, &tf)
        .expect("tf");
    renderer.set_slice(slice);
    renderer.set_intensity(intensity);
    let (w, h) = (desc.viewport.width, desc.viewport.height);
    let target = brickray_harness::Offscreen::new(&gpu.device, w, h);
    brickray_harness::draw_frame(gpu, &mut renderer, &target, desc, Some(wgpu::Color::BLACK))
        .expect("draw");
    target.read_color(gpu)
}

/// The library's out-of-core rendering of a store with the viewer's default
/// budgets and its grey preset, drawn until converged.
/// The library's own rendering of a slice view of a store through a grey
/// window, converged.
fn library_store_slice(
    store: &Path,
    view: brickray::SliceView,
    window: brickray::Window,
    w: u32,
    h: u32,
) -> Vec<u8> {
    let gpu = brickray_harness::shared_gpu();
    let source = std::sync::Arc::new(brickray::store::open(store).expect("open the store"));
    let d = source.desc().clone();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let mut renderer =
        VolumeRenderer::new(&gpu.device, brickray_harness::target_desc()).expect("renderer");
    renderer
        .set_volume_source(&gpu.device, &gpu.queue, source, Default::default())
        .expect("source");
    renderer.set_slice(Some(view));
    renderer.set_intensity(Some(brickray::Intensity::new(
        window,
        brickray::ColorMap::Grey,
    )));
    let target = brickray_harness::Offscreen::new(&gpu.device, w, h);
    let desc = FrameDesc::new(Camera::orbit(glam::Vec3::ZERO, 2.0, 0.3, 0.2), frame, w, h);
    let settled = brickray_harness::draw_until_settled(gpu, &mut renderer, &target, &desc, 600)
        .expect("draw");
    assert!(settled.is_some(), "the library's slice did not converge");
    target.read_color(gpu)
}

fn library_store_image(store: &Path, camera: Camera, w: u32, h: u32) -> Vec<u8> {
    let gpu = brickray_harness::shared_gpu();
    let source = std::sync::Arc::new(brickray::store::open(store).expect("open the store"));
    let d = source.desc().clone();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let config = brickray::OutOfCoreConfig {
        gpu_budget_bytes: 256 << 20,
        cpu_budget_bytes: 1024 << 20,
        ..Default::default()
    };
    let mut renderer =
        VolumeRenderer::new(&gpu.device, brickray_harness::target_desc()).expect("renderer");
    renderer
        .set_volume_source(&gpu.device, &gpu.queue, source, config)
        .expect("source");
    // The viewer's "grey" preset: colour and opacity ramps over the range.
    let tf = TransferFunction::from_points(
        &[(0.0, [0.0, 0.0, 0.0, 0.0]), (1.0, [1.0, 1.0, 1.0, 0.5])],
        1024,
    );
    renderer
        .set_transfer_function(&gpu.device, &gpu.queue, &tf)
        .expect("tf");
    let target = brickray_harness::Offscreen::new(&gpu.device, w, h);
    let desc = FrameDesc::new(camera, frame, w, h);
    let settled = brickray_harness::draw_until_settled(gpu, &mut renderer, &target, &desc, 600)
        .expect("draw");
    assert!(
        settled.is_some(),
        "the library's rendering did not converge"
    );
    target.read_color(gpu)
}

fn read_png(path: &Path) -> (Vec<u8>, u32, u32) {
    let img = image::open(path).expect("the screenshot").to_rgba8();
    let (w, h) = img.dimensions();
    (img.into_raw(), w, h)
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
#[cfg_attr(
    no_display,
    ignore = "needs an X server (DISPLAY unset when the tests were built; scripts/test.sh starts Xvfb)"
)]
fn scripted_screenshots_match_the_library() {
    if !display_available() {
        return;
    }
    let Some(ct) = brickray_harness::shared_volume("invesalius_cranium_ct") else {
        return;
    };
    let dir = tempfile::tempdir().expect("temp dir");
    let out = |name: &str| -> PathBuf { dir.path().join(name) };
    std::fs::write(out("bone.json"), tf_json()).expect("write the TF");
    let iso = hu(400.0);
    let script = format!(
        "open {ct}\nbackground 0 0 0\noverlays off\ntf load {tf}\ncamera orbit 30 15 1.0\n\
         wait converged\nscreenshot {dvr}\nmode iso {iso}\nwait 2\nscreenshot {isopng}\n\
         clip 0 0 0 1 0.55 1\nwait 2\nscreenshot {clippng}\n\
         clip off\nmode dvr\ntermination 0.9\nskipping off\nadaptive on\nwait 2\nscreenshot {fast}\n\
         preint on\nwait 2\nscreenshot {preint}\nquit\n",
        ct = ct.display(),
        tf = out("bone.json").display(),
        dvr = out("dvr.png").display(),
        isopng = out("iso.png").display(),
        clippng = out("clip.png").display(),
        fast = out("fast.png").display(),
        preint = out("preint.png").display(),
    );
    let t = Instant::now();
    run_script(dir.path(), &script, Duration::from_secs(120));
    eprintln!(
        "viewer ran the script in {:.1} s",
        t.elapsed().as_secs_f64()
    );

    let volume = brickray::io::read_volume(&ct).expect("the head CT");
    let iso_mode = RenderMode::Iso {
        value: iso,
        color: [0.9, 0.85, 0.75],
    };
    let (mut dvr_shot, mut iso_shot) = (None, None);
    let cut = ClipBox {
        min: [0.0; 3],
        max: [1.0, 0.55, 1.0],
    };
    let with = |mode, clip| RenderSettings {
        mode,
        clip,
        ..RenderSettings::default()
    };
    // The script's accelerations: termination at 0.9, no skipping, the
    // adaptive step; then pre-integrated (which the adaptive step yields to).
    let fast = RenderSettings {
        accel: brickray::Accel {
            early_termination: Some(0.9),
            empty_space_skipping: false,
            adaptive_step: true,
        },
        ..RenderSettings::default()
    };
    let preint = RenderSettings {
        preintegrated: true,
        ..fast
    };
    for (name, settings) in [
        ("dvr", with(RenderMode::Dvr, ClipBox::FULL)),
        ("iso", with(iso_mode, ClipBox::FULL)),
        ("clip", with(iso_mode, cut)),
        ("fast", fast),
        ("preint", preint),
    ] {
        let png = out(&format!("{name}.png"));
        let (shot, w, h) = read_png(&png);
        let (camera, vw, vh) = sidecar(&png);
        assert_eq!(
            (w, h),
            (vw, vh),
            "{name}: the screenshot is the view's size"
        );
        assert!(w >= 64 && h >= 64, "{name}: a {w}x{h} view");
        let lib = library_image(&volume, camera, w, h, settings);
        // The head covers a good part of the view (not a blank image).
        let lit = lit_pixels(&shot);
        assert!(lit * 10 > (w * h) as usize, "{name}: only {lit} lit pixels");
        let cmp = brickray_reference::assert_close(
            &format!("viewer-{name}"),
            &shot,
            &lib,
            w,
            h,
            MIN_PSNR_DB,
        )
        .unwrap_or_else(|e| panic!("{e}"));
        eprintln!("viewer {name} vs library: {cmp}");
        // The sidecar records what the view was drawn with.
        let drawn = &sidecar_json(&png)["settings"];
        assert_eq!(
            (
                drawn["early_termination"].as_f64().map(|t| t as f32),
                drawn["empty_space_skipping"].as_bool(),
                drawn["adaptive_step"].as_bool(),
                drawn["preintegrated"].as_bool(),
            ),
            (
                settings.accel.early_termination,
                Some(settings.accel.empty_space_skipping),
                Some(settings.accel.adaptive_step),
                Some(settings.preintegrated),
            ),
            "{name}: {drawn}"
        );
        if name == "dvr" {
            dvr_shot = Some(shot);
        } else if matches!(name, "fast" | "preint") {
            // Each changed the image (drawn the same otherwise).
            let db = brickray_reference::psnr(dvr_shot.as_deref().expect("dvr first"), &shot);
            assert!(db.is_finite(), "{name}: the same image as the defaults'");
        } else if name == "iso" {
            // The metric tells these scenes apart: the DVR screenshot is far
            // from the library's isosurface.
            let other = brickray_reference::psnr(dvr_shot.as_deref().expect("dvr first"), &lib);
            assert!(
                other < MIN_PSNR_DB - 10.0,
                "DVR vs iso scored {other:.1} dB"
            );
            iso_shot = Some(shot);
        } else {
            // The clip box cut something away.
            let db = brickray_reference::psnr(iso_shot.as_deref().expect("iso first"), &shot);
            assert!(db < 30.0, "the clip changed too little ({db:.1} dB)");
        }
    }
}

/// A script whose step fails ends the run at once with a failing exit status
/// and the reason on stderr: an `open` of a missing file, and a failed
/// `wait converged` is covered by the same path (the window closes on the
/// first failure; before, it stayed open until killed).
#[test]
#[cfg_attr(
    no_display,
    ignore = "needs an X server (DISPLAY unset when the tests were built; scripts/test.sh starts Xvfb)"
)]
fn a_failed_step_ends_the_script_with_a_failure() {
    let Some(dir) = windowed_test_dir() else {
        return;
    };
    let path = dir.path().join("script.txt");
    let never = dir.path().join("never.png");
    std::fs::write(
        &path,
        format!(
            "open /nonexistent/vol.nii.gz\nwait 10\nscreenshot {}\nquit\n",
            never.display()
        ),
    )
    .expect("write the script");
    let t = Instant::now();
    let limit = Duration::from_secs(60);
    let run = run_viewer(&path, limit);
    let took = t.elapsed();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(
        took < limit,
        "killed after {took:?}: the viewer did not exit"
    );
    assert!(!run.status.success(), "exit status {:?}", run.status);
    assert!(
        stderr.contains("script failed") && stderr.contains("/nonexistent/vol.nii.gz"),
        "stderr: {stderr}"
    );
    assert!(!never.exists(), "a step after the failure ran");
    eprintln!("a failed open ended the viewer in {took:?}");
}

/// Every format of the shared fixtures opens in the viewer (through
/// `brickray::io::open`) and shows an image (MIP, grey TF): NIfTI, a TIFF
/// stack, a folder of TIFF slices, a DICOM series and OME-Zarr 0.4 and 0.5.
#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the format fixtures), absent when the tests were built"
)]
#[cfg_attr(
    no_display,
    ignore = "needs an X server (DISPLAY unset when the tests were built; scripts/test.sh starts Xvfb)"
)]
fn opens_every_shared_format() {
    if !display_available() {
        return;
    }
    let formats = brickray_harness::shared_data_dir()
        .expect("shared data")
        .join("formats");
    let inputs = [
        ("nifti", "nifti/pycortex_s1_t1.nii.gz"),
        ("tiff_stack", "tiff/cells3d_nuclei.tif"),
        ("tiff_slices", "tiff_slices/cryoet_tomo"),
        ("dicom", "dicom/cranium_ct"),
        ("zarr_v04", "ome-zarr/cryoet_tomo_v04.ome.zarr"),
        ("zarr_v05", "ome-zarr/pycortex_s1_t1_v05.ome.zarr"),
    ];
    let dir = tempfile::tempdir().expect("temp dir");
    let mut script = String::from("background 0 0 0\noverlays off\n");
    for (name, rel) in inputs {
        script += &format!(
            "open {}\ntf grey\nmode mip\nwait 2\nscreenshot {}\n",
            formats.join(rel).display(),
            dir.path().join(format!("{name}.png")).display()
        );
    }
    script += "quit\n";
    run_script(dir.path(), &script, Duration::from_secs(240));
    for (name, _) in inputs {
        let (shot, w, h) = read_png(&dir.path().join(format!("{name}.png")));
        let lit = lit_pixels(&shot);
        eprintln!("{name}: {lit} lit pixels of {w}x{h}");
        // The nuclei stack is thin (60 slices of 256x256): about 2.5% of the
        // view; a failed open or an empty volume draws none.
        assert!(
            lit * 100 > (w * h) as usize,
            "{name}: only {lit} lit pixels"
        );
    }
}

/// The four-view layout (`layout four`): axial, coronal and sagittal slices
/// through the crosshair and the 3D view, one streamed volume (a 96^3 ball,
/// out of core). Each slice quadrant shows the ball's disc through the
/// crosshair (lit near the centre, dark at its corners) and the crosshair's
/// lines; the 3D quadrant shows the ball.
#[test]
#[cfg_attr(
    no_display,
    ignore = "needs an X server (DISPLAY unset when the tests were built; scripts/test.sh starts Xvfb)"
)]
fn the_four_view_layout_shows_three_slices_and_3d() {
    let Some(dir) = windowed_test_dir() else {
        return;
    };
    let store = sphere_store(dir.path());
    let shot = dir.path().join("four.png");
    let plain = dir.path().join("plain.png");
    let script = format!(
        "open {store}\nbackground 0 0 0\ntf grey\nlayout four\ncrosshair 47.5 47.5 47.5\n\
         wait converged 600\nscreenshot {shot}\noverlays off\ncrosshair 40 52 45.5\nwindow 100 120\n\
         wait converged 600\nscreenshot {plain}\nquit\n",
        store = store.display(),
        shot = shot.display(),
        plain = plain.display(),
    );
    run_script(dir.path(), &script, Duration::from_secs(120));
    let (img, w, h) = read_png(&shot);
    let px = |x: f32, y: f32| {
        let (x, y) = ((x as u32).min(w - 1), (y as u32).min(h - 1));
        let i = ((y * w + x) * 4) as usize;
        [img[i], img[i + 1], img[i + 2]]
    };
    let (qw, qh) = (w as f32 * 0.5, h as f32 * 0.5);
    for q in 0..4 {
        let (x0, y0) = ((q % 2) as f32 * qw, (q / 2) as f32 * qh);
        let quadrant = |fx: f32, fy: f32| px(x0 + fx * qw, y0 + fy * qh);
        let (mut lit, mut yellow) = (0usize, 0usize);
        for j in 0..qh as u32 {
            for i in 0..qw as u32 {
                let p = quadrant(i as f32 / qw, j as f32 / qh);
                if p.iter().any(|&c| c > 40) {
                    lit += 1;
                }
                if p[0] > 200 && p[1] > 170 && p[2] < 90 {
                    yellow += 1;
                }
            }
        }
        let area = (qw * qh) as usize;
        eprintln!("quadrant {q}: {lit} lit, {yellow} crosshair pixels of {area}");
        assert!(lit * 20 > area, "quadrant {q}: only {lit} lit pixels");
        if q < 3 {
            // A slice: the disc near the crosshair, dark corners.
            let near = quadrant(0.56, 0.56);
            assert!(near[0] > 60, "slice {q}: {near:?} near the centre");
            for (fx, fy) in [(0.03, 0.03), (0.97, 0.03), (0.03, 0.97), (0.97, 0.97)] {
                let c = quadrant(fx, fy);
                assert!(c[0] < 20, "slice {q}: corner {c:?}");
            }
            assert!(yellow > (qw.min(qh) as usize), "slice {q}: no crosshair");
        } else {
            assert_eq!(yellow, 0, "the 3D view has no crosshair");
        }
    }
    // Without overlays (no crosshair lines) and through a window (raw
    // 40..160 of the ball's 0..255), each slice of the screenshot is the
    // library's own rendering of that slice view.
    let (img, w, _) = read_png(&plain);
    let side = sidecar_json(&plain);
    let slices = side["slices"]
        .as_array()
        .expect("the slices in the sidecar");
    assert_eq!(slices.len(), 3);
    for (i, s) in slices.iter().enumerate() {
        let f = |v: &serde_json::Value| v.as_f64().expect("a number");
        let v3 = |v: &serde_json::Value| [f(&v[0]), f(&v[1]), f(&v[2])];
        let vp: Vec<u32> = (0..4).map(|k| f(&s["viewport"][k]) as u32).collect();
        let view = brickray::SliceView {
            centre: v3(&s["centre"]),
            right: v3(&s["right"]),
            up: v3(&s["up"]),
            height: f(&s["height"]),
            slab: None,
        };
        let mut crop = Vec::with_capacity((vp[2] * vp[3] * 4) as usize);
        for y in vp[1]..vp[1] + vp[3] {
            let row = ((y * w + vp[0]) * 4) as usize;
            crop.extend_from_slice(&img[row..row + (vp[2] * 4) as usize]);
        }
        let window = brickray::Window::new(100.0, 120.0).unwrap();
        let lib = library_store_slice(&store, view, window, vp[2], vp[3]);
        let name = format!("viewer-slice-{i}");
        let cmp = brickray_reference::assert_close(&name, &crop, &lib, vp[2], vp[3], MIN_PSNR_DB)
            .unwrap_or_else(|e| panic!("{e}"));
        eprintln!("four views, slice {i} vs library: {cmp}");
    }
}
