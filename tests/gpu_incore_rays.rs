//! GPU tests of what the in-core ray caster's march decides, on a real
//! wgpu device (lavapipe in CI): early termination and its fill, the
//! adaptive step, MIP's refinement between samples, each against its CPU
//! twin, and the skip rules' decisions by sample counts (the images against
//! the reference: `gpu_incore.rs`).

use brickray::{Camera, RenderMode, TransferFunction, Volume, VolumeRenderer};
use brickray_harness::Offscreen;
use brickray_reference::ReferenceOptions;

use brickray_harness::{shared_gpu as gpu, target_desc as targets};

#[path = "incore_support.rs"]
#[allow(dead_code)]
mod incore_support;
use incore_support::{Scene, translucent_ramp};

#[path = "skip_support.rs"]
mod skip_support;
use skip_support::{STEP, check_rule_decision, skip_frame};

/// A ray that early termination stops has its depth where it stops at the
/// latest (docs/rendering-model.md, *Accelerations*): with a threshold below
/// the depth opacity (0.5) it still gets its depth. Threshold: on
/// Marschner-Lobb under a translucent TF, every pixel that has a depth
/// without termination has one with termination at 0.3 (the ray reaches 0.5
/// only later, or stops first), and a tenth of the image at least has a
/// depth (guard). Measured: 1,018 of 4,096 pixels have a depth and none
/// loses it; with the depth tested only against the opacity, before the
/// residual was filled, 984 of them lost it (rays stopped between 0.3 and
/// 0.5).
#[test]
fn a_ray_stopped_early_keeps_its_depth() {
    let ml = brickray_core::synthetic::marschner_lobb(64);
    let tf = translucent_ramp(0.5);
    let mut s = Scene::new(&ml, &tf, RenderMode::Dvr, 64);
    s.camera = Camera::orbit(s.frame.center(), 3.0, 0.5, 0.3);
    s.settings.accel.early_termination = None;
    let (rgba, full) = s.gpu();
    s.settings.accel.early_termination = Some(0.3);
    let (_, stopped) = s.gpu();
    // The corner's ray misses the volume: the cleared far value.
    assert_eq!(&rgba[..3], &[0, 0, 0], "the corner is background");
    let far = full[0];
    let with_depth = full.iter().filter(|d| **d != far).count();
    let lost = full
        .iter()
        .zip(&stopped)
        .filter(|(f, s)| **f != far && **s == far)
        .count();
    eprintln!(
        "{with_depth} of {} pixels have a depth, {lost} lose it when stopped at 0.3",
        full.len()
    );
    assert!(
        with_depth * 10 >= full.len(),
        "only {with_depth} pixels with a depth"
    );
    assert_eq!(lost, 0, "rays stopped early without their depth");
}

/// A ray that early termination stops fills its residual transmittance as
/// far as the material it has crossed, continued to the ray's end, would
/// (docs/rendering-model.md, *Accelerations*): exact where the material is
/// uniform. A 64^3 volume of one value under a TF of opacity 0.04 a voxel
/// (rays gather 0.87-0.98 across it), terminated at 0.8. Threshold: against
/// the unterminated image, max error <= 2 levels and >= 55 dB; a guard
/// checks that rays stop (under 0.8 of the samples a ray). Measured: max
/// error 1, 60.6 dB, 59.2 samples a ray against 83.8; with the residual
/// filled whole (the kernel before), max error 51 and 26.9 dB.
#[test]
fn a_stopped_ray_fills_only_what_the_material_ahead_would() {
    let n = 64u32;
    let vol = brickray_harness::scenes::u8_volume([n; 3], vec![128; (n * n * n) as usize]).unwrap();
    let tf = TransferFunction::from_points(
        &[(0.0, [1.0, 0.8, 0.5, 0.04]), (1.0, [1.0, 0.8, 0.5, 0.04])],
        256,
    );
    let mut s = Scene::new(&vol, &tf, RenderMode::Dvr, 64);
    s.camera = Camera::orbit(s.frame.center(), 2.2, 0.5, 0.3);
    s.settings.accel.early_termination = None;
    let (full, _, n_full) = s.gpu_counted();
    s.settings.accel.early_termination = Some(0.8);
    let (stopped, _, n_stopped) = s.gpu_counted();
    let db = brickray_reference::psnr(&stopped, &full);
    let max = brickray_reference::max_abs_diff(&stopped, &full);
    eprintln!(
        "uniform medium, ERT 0.8: max error {max}, {db:.1} dB; {n_stopped:.1} samples a ray against {n_full:.1}"
    );
    assert!(
        n_stopped < 0.8 * n_full,
        "guard: rays do not stop ({n_stopped:.1} samples against {n_full:.1})"
    );
    assert!(max <= 2, "max error {max} > 2");
    assert!(db >= 55.0, "{db:.2} dB < 55");
}

/// Early termination against its CPU twin: the reference terminating as the
/// kernels do (`ReferenceOptions::with_early_termination`, the fill from the
/// ray's mean extinction so far) at the GPU's step, on Marschner-Lobb under
/// a translucent TF stopped at 0.8, plain and pre-integrated, unshaded and
/// shaded. Threshold: >= 55 dB each, and at least 15 dB closer than to the
/// unterminated reference at the same step (guard: the termination shows).
/// Measured: 63.37 / 65.47 / 63.56 / 63.93 dB (plain, plain shaded,
/// pre-integrated, pre-integrated shaded) against 35.56-37.77 unterminated;
/// the kernel that filled the residual whole scored 33.31 dB against the
/// twin (plain, unshaded).
#[test]
fn early_termination_matches_its_cpu_twin() {
    let ml = brickray_core::synthetic::marschner_lobb(64);
    let tf = translucent_ramp(0.6);
    let mut s = Scene::new(&ml, &tf, RenderMode::Dvr, 64);
    s.camera = Camera::orbit(s.frame.center(), 2.2, 0.5, 0.3);
    s.settings.accel.early_termination = Some(0.8);
    for (preint, shaded) in [(false, false), (false, true), (true, false), (true, true)] {
        s.settings.preintegrated = preint;
        s.settings.shading.enabled = shaded;
        let (gpu, _) = s.gpu();
        let opts = ReferenceOptions::new(s.size, s.size)
            .with_step_factor(s.settings.step_factor)
            .with_preintegration(preint);
        let twin =
            brickray_reference::psnr(&gpu, &s.reference_with(opts.with_early_termination(0.8)));
        let full = brickray_reference::psnr(&gpu, &s.reference_with(opts));
        eprintln!(
            "preint {preint}, shaded {shaded}: GPU at 0.8 vs its twin {twin:.2} dB, vs unterminated {full:.2} dB"
        );
        assert!(
            twin >= 55.0,
            "preint {preint}, shaded {shaded}: {twin:.2} dB < 55"
        );
        assert!(
            twin >= full + 15.0,
            "guard, preint {preint}, shaded {shaded}: {twin:.2} dB against {full:.2} unterminated"
        );
    }
}

/// DVR's adaptive step (`Accel::adaptive_step`, docs/rendering-model.md,
/// *Accelerations*) draws what its CPU twin draws
/// (`ReferenceOptions::with_adaptive_step`, termination at 0.99 as the
/// kernels' default), plain and shaded, and takes fewer samples.
/// Marschner-Lobb through a translucent ramp at a step of 1 voxel.
/// Thresholds: against the twin >= 55 dB and at least 10 dB closer than to
/// the reference that keeps its step; samples per ray below 0.95x the
/// fixed step's. Measured: see the test's output (docs/rendering-model.md
/// gives the figures).
#[test]
fn adaptive_step_matches_its_cpu_twin() {
    let ml = brickray_core::synthetic::marschner_lobb(64);
    let tf = translucent_ramp(0.6);
    let mut s = Scene::new(&ml, &tf, RenderMode::Dvr, 64);
    s.camera = Camera::orbit(s.frame.center(), 2.2, 0.5, 0.3);
    s.settings.step_factor = 1.0;
    for shaded in [false, true] {
        s.settings.shading.enabled = shaded;
        s.settings.accel.adaptive_step = false;
        let (_, _, fixed_samples) = s.gpu_counted();
        s.settings.accel.adaptive_step = true;
        let (gpu, _, samples) = s.gpu_counted();
        let opts = ReferenceOptions::new(s.size, s.size)
            .with_step_factor(1.0)
            .with_early_termination(0.99);
        let twin = brickray_reference::psnr(&gpu, &s.reference_with(opts.with_adaptive_step(true)));
        let fixed = brickray_reference::psnr(&gpu, &s.reference_with(opts));
        eprintln!(
            "shaded {shaded}: adaptive step vs its twin {twin:.2} dB, vs the fixed step's reference {fixed:.2} dB; {samples:.1} samples per ray against {fixed_samples:.1}"
        );
        assert!(twin >= 55.0, "shaded {shaded}: {twin:.2} dB < 55");
        assert!(
            twin >= fixed + 10.0,
            "guard, shaded {shaded}: {twin:.2} dB against {fixed:.2} to the fixed step"
        );
        assert!(
            samples < 0.95 * fixed_samples,
            "shaded {shaded}: {samples:.1} samples per ray against {fixed_samples:.1}"
        );
    }
}

/// MIP refines its maximum and the runner-up between samples
/// (docs/rendering-model.md, *Modes*). Marschner-Lobb through a grey ramp
/// at a step of 2 voxels. Thresholds: the GPU against its twin (the
/// reference at the same step, refining) >= 58 dB; against the fine
/// reference (1/8 voxel) at least 10 dB closer than the samples' maximum
/// alone (the reference at step 2 without refinement). Measured: 64.13 dB
/// against the twin; 45.67 dB against the fine reference where the
/// samples' maximum alone scores 33.21 (the kernel before refined nothing:
/// about that, and far from the twin).
#[test]
fn mip_refines_its_maximum_between_samples() {
    let ml = brickray_core::synthetic::marschner_lobb(64);
    let tf = TransferFunction::ramp(0.0, 1.0, 1.0);
    let mut s = Scene::new(&ml, &tf, RenderMode::Mip, 64);
    s.settings.step_factor = 2.0;
    let (gpu, _) = s.gpu();
    let at_step = ReferenceOptions::new(s.size, s.size).with_step_factor(2.0);
    let fine = s.reference();
    let twin = brickray_reference::psnr(&gpu, &s.reference_with(at_step));
    let refined = brickray_reference::psnr(&gpu, &fine);
    let samples_only =
        brickray_reference::psnr(&s.reference_with(at_step.with_mip_refinement(false)), &fine);
    eprintln!(
        "MIP at step 2: GPU vs its twin {twin:.2} dB; vs the fine reference {refined:.2} dB, the samples' maximum alone {samples_only:.2} dB"
    );
    assert!(twin >= 58.0, "{twin:.2} dB < 58 against the twin");
    assert!(
        refined >= samples_only + 10.0,
        "refined {refined:.2} dB, samples alone {samples_only:.2} dB"
    );
}

/// MIP in core skips empty space only where the volume's macro cells say it
/// pays (`SkipRule::WherePays`, the default): on fractal noise (share of
/// cells certain to be skipped 0.14, below `MIP_SKIP_SHARE_MIN`) a MIP frame
/// with skipping asked for takes every sample, as without it, while
/// `SkipRule::Always` skips (fewer samples, the same image); on a bright
/// box around a dim core (share above the threshold) both skip, but at a
/// step of 2 voxels, where the threshold is 1, only `Always` does. Images
/// are identical in every case.
#[test]
fn mip_skips_where_the_macro_cells_say_it_pays() {
    use brickray::RendererOptions;
    use brickray::core::{MIP_SKIP_SHARE_MIN, MacroCellGrid};
    let n = 64u32;
    let noise = brickray_harness::scenes::pareto_noise(n);
    let shell = brickray_harness::scenes::bright_shell(n);
    let tf = TransferFunction::ramp(0.0, 1.0, 1.0);
    for (name, vol, step, pays) in [
        ("noise", &noise, STEP, false),
        ("shell", &shell, STEP, true),
        ("shell, a step of 2 voxels", &shell, 2.0, false),
    ] {
        let share = MacroCellGrid::build(vol, 8).mip_skip_share();
        assert_eq!(
            MIP_SKIP_SHARE_MIN.pays(share, step),
            pays,
            "{name}: share {share}"
        );
        let (samples, images) = skip_frames(vol, &tf, RenderMode::Mip, step, false, |rule| {
            RendererOptions {
                mip_skipping: rule,
                ..Default::default()
            }
        });
        eprintln!(
            "{name} (share {share:.3}): samples per ray, rule off/on {:.1}/{:.1}, always off/on {:.1}/{:.1}",
            samples[0], samples[1], samples[2], samples[3]
        );
        check_rule_decision(name, &samples, &images, pays, 0.9, 0.8);
    }
}

/// DVR in core skips empty space only where enough of the volume's macro
/// cells are transparent through the transfer function
/// (`SkipRule::WherePays`, the default; `dvr_skip_share_min`, 0.3 unshaded
/// and 0.15 shaded): on fractal noise through a ramp that leaves a few
/// cells transparent (below both thresholds) a DVR frame with skipping
/// asked for takes every sample, as without it, while `SkipRule::Always`
/// skips those cells (fewer samples); through a ramp that leaves a share
/// between the two the shaded frame skips and the unshaded does not;
/// through a ramp that leaves many transparent (above both) both skip.
/// Images are identical in every case.
#[test]
fn dvr_skips_where_enough_cells_are_transparent() {
    use brickray::RendererOptions;
    use brickray::core::{MacroCellGrid, dvr_skip_share_min};
    let noise = brickray_harness::scenes::pareto_noise(64);
    let grid = MacroCellGrid::build(&noise, 8);
    for (from, shaded, pays) in [
        (0.45f32, true, false),
        (0.5, true, true),
        (0.5, false, false),
        (0.6, false, true),
    ] {
        let tf = TransferFunction::ramp(from, 1.0, 0.05);
        let share = grid.transparent_share(&tf);
        assert!(share > 0.0, "ramp from {from}: some cells transparent");
        assert_eq!(
            dvr_skip_share_min(shaded).pays(share, STEP),
            pays,
            "ramp from {from}, shaded {shaded}: share {share}"
        );
        let mode = RenderMode::Dvr;
        let (samples, images) =
            skip_frames(&noise, &tf, mode, STEP, shaded, |rule| RendererOptions {
                dvr_skipping: rule,
                ..Default::default()
            });
        eprintln!(
            "ramp from {from}, shaded {shaded} (transparent cells {share:.3}): samples per ray, rule off/on {:.1}/{:.1}, always off/on {:.1}/{:.1}",
            samples[0], samples[1], samples[2], samples[3]
        );
        let label = format!("from {from}, shaded {shaded}");
        check_rule_decision(&label, &samples, &images, pays, 1.0, 1.0);
    }
}

/// In core at 96 px, for the rule `WherePays` and then `Always` (`options`
/// sets it), a `mode` frame of `vol` through `tf` (`shaded` or not) without
/// and then with empty-space skipping asked for: the samples per ray and
/// the images, in that order.
fn skip_frames(
    vol: &Volume,
    tf: &TransferFunction,
    mode: RenderMode,
    step: f32,
    shaded: bool,
    options: impl Fn(brickray::SkipRule) -> brickray::RendererOptions,
) -> (Vec<f64>, Vec<Vec<u8>>) {
    const SIZE: u32 = 96;
    let g = gpu();
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let (mut samples, mut images) = (Vec::new(), Vec::new());
    for rule in [brickray::SkipRule::WherePays, brickray::SkipRule::Always] {
        let mut r = VolumeRenderer::with_options(&g.device, targets(), options(rule)).unwrap();
        r.set_volume(&g.device, &g.queue, vol).unwrap();
        r.set_transfer_function(&g.device, &g.queue, tf).unwrap();
        for ess in [false, true] {
            let mut desc = skip_frame(vol, mode, ess, SIZE, step);
            desc.settings.shading.enabled = shaded;
            let f = brickray_harness::predict::draw(g, &mut r, &target, &desc).unwrap();
            samples.push(brickray_harness::predict::samples_per_ray(&f.samples));
            images.push(f.color);
        }
    }
    (samples, images)
}
