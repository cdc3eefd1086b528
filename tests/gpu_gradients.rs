//! GPU tests of shaded DVR in core from per-voxel gradients
//! (`GradientSource::Precomputed`, the default) against six reads per sample
//! (`GradientSource::SixReads`), on a real wgpu device (lavapipe in CI).
//!
//! Trilinear interpolation of the per-voxel central differences is the
//! central difference of the trilinear field one voxel apart, and within half
//! a voxel of the volume's faces the kernel scales it by the factor the six
//! reads' clamping makes, so the two differ only by the gradients' half
//! floats. Thresholds (8-bit RGB over black, 96 x 96): the two images >= 70 dB
//! apart (measured 75.07 dB on Marschner-Lobb, 79.76 on the noise, 78.75 on
//! the shared head CT; 47.12 dB on Marschner-Lobb without the faces' factor),
//! and against the CPU reference the precomputed image is within 0.5 dB of
//! the six-read one (measured within 0.01 dB).
//! The gradients are made by the first shaded DVR frame and counted in
//! `volume_bytes` (8 bytes a voxel); unshaded, MIP and iso frames make none,
//! and a label map never has them.
//!
//! Out of core, a streamed volume that keeps its texels' gradients
//! (`VolumeOptions::gradients`, made for each uploaded brick) against one
//! that does not, with the same thresholds (measured 74.49-79.99 dB apart,
//! within 0.01 dB against the reference, at the finest level and at a coarse
//! cut); the atlas takes 8 more bytes a texel of the same budget.
//!
//! Both record the pass that makes gradients into the host's encoder; a host
//! that drops that encoder instead of submitting it would leave no gradients
//! where the kernel reads them (17.7 dB from six reads, in core and out of
//! core, before the renderer watched its encoders): the renderer records the
//! pass again into the next frame's encoder, and the same thresholds hold
//! after dropped frames (measured 75.07 and 74.49 dB, as without them).
//! Out of core the pass runs only in frames that shade DVR, for every brick
//! that arrived since the last one; by default a streamed volume keeps
//! gradients where its GPU budget holds every brick with them.

use brickray::{
    Camera, FrameDesc, GradientSource, KeepGradients, RenderMode, RenderSettings, RendererOptions,
    Shading, TransferFunction, Viewport, Volume, VolumeFrame, VolumeRenderer,
};
use brickray_harness::{Offscreen, shared_gpu as gpu, target_desc as targets};
use brickray_reference::{ReferenceOptions, psnr, render_reference};

const SIZE: u32 = 96;

fn renderer(vol: &Volume, tf: &TransferFunction, gradients: GradientSource) -> VolumeRenderer {
    let g = gpu();
    let options = RendererOptions {
        gradients,
        ..Default::default()
    };
    let mut r = VolumeRenderer::with_options(&g.device, targets(), options).unwrap();
    r.set_volume(&g.device, &g.queue, vol).unwrap();
    r.set_transfer_function(&g.device, &g.queue, tf).unwrap();
    r
}

fn view(vol: &Volume) -> (VolumeFrame, Camera) {
    let d = vol.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    (frame, Camera::orbit(frame.center(), 2.0, 0.5, 0.3))
}

fn shaded(mode: RenderMode, shaded: bool) -> RenderSettings {
    RenderSettings {
        mode,
        shading: Shading {
            enabled: shaded,
            ..Default::default()
        },
        ..Default::default()
    }
}

/// Frames of `settings` until the renderer settles, at most `max_frames`:
/// the frames it took (`None`: not settled) and the last image, RGBA8.
fn settle(
    r: &mut VolumeRenderer,
    vol: &Volume,
    settings: RenderSettings,
    max_frames: usize,
) -> (Option<usize>, Vec<u8>) {
    let g = gpu();
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let (frame, camera) = view(vol);
    let desc = FrameDesc {
        camera,
        frame,
        viewport: Viewport::full(SIZE, SIZE),
        settings,
        host_depth: None,
        time: None,
    };
    let frames =
        brickray_harness::draw_until_settled(g, r, &target, &desc, max_frames).expect("frame");
    (frames, target.read_color(g))
}

/// One frame of `settings` (in core: settled at once); RGBA8.
fn draw(r: &mut VolumeRenderer, vol: &Volume, settings: RenderSettings) -> Vec<u8> {
    let (frames, img) = settle(r, vol, settings, 1);
    assert_eq!(frames, Some(1));
    img
}

/// Shaded DVR with precomputed gradients against six reads, and both against
/// the CPU reference; the gradients' bytes appear with the first shaded DVR
/// frame only.
fn compare(name: &str, vol: &Volume, tf: &TransferFunction) -> f64 {
    let voxels: u64 = vol.dims().iter().map(|&d| d as u64).product();
    let mut pre = renderer(vol, tf, GradientSource::Precomputed);
    let mut six = renderer(vol, tf, GradientSource::SixReads);
    let base = six.volume_bytes();
    assert_eq!(pre.volume_bytes(), base, "{name}: nothing made at set-up");
    for mode in [
        RenderMode::Mip,
        RenderMode::Iso {
            value: 0.5,
            color: [0.9, 0.85, 0.75],
        },
    ] {
        draw(&mut pre, vol, shaded(mode, true));
    }
    draw(&mut pre, vol, shaded(RenderMode::Dvr, false));
    assert_eq!(
        pre.volume_bytes(),
        base,
        "{name}: MIP, iso and unshaded DVR make no gradients"
    );
    let s = shaded(RenderMode::Dvr, true);
    let a = draw(&mut pre, vol, s);
    assert_eq!(
        pre.volume_bytes(),
        base + 8 * voxels,
        "{name}: the first shaded DVR frame makes them"
    );
    let b = draw(&mut six, vol, s);
    assert_eq!(six.volume_bytes(), base, "{name}: six reads keep none");
    as_six_reads(&format!("{name}, precomputed"), vol, tf, s, &a, &b)
}

/// Checks `kept` (shaded from per-voxel gradients) against `six` (six reads)
/// of the same frame: >= 70 dB apart, and against the CPU reference within
/// 0.5 dB of six reads. Returns the PSNR between them.
fn as_six_reads(
    label: &str,
    vol: &Volume,
    tf: &TransferFunction,
    s: RenderSettings,
    kept: &[u8],
    six: &[u8],
) -> f64 {
    let (frame, camera) = view(vol);
    let cpu = render_reference(
        vol,
        &frame,
        tf,
        &camera,
        &s,
        &ReferenceOptions::new(SIZE, SIZE).with_step_factor(s.step_factor),
    )
    .to_rgba8([0.0; 3]);
    let between = psnr(kept, six);
    let (ref_kept, ref_six) = (psnr(kept, &cpu), psnr(six, &cpu));
    eprintln!(
        "{label}: against six reads {between:.2} dB; against the reference {ref_kept:.2} dB (six reads {ref_six:.2} dB)"
    );
    assert!(between >= 70.0, "{label}: {between} dB");
    assert!(
        ref_kept >= ref_six - 0.5,
        "{label}: {ref_kept} dB, six reads {ref_six} dB"
    );
    between
}

#[test]
fn precomputed_gradients_shade_as_six_reads() {
    use brickray::core::synthetic;
    compare(
        "Marschner-Lobb (f32)",
        &synthetic::marschner_lobb(48),
        &brickray_harness::scenes::marschner_lobb_tf(),
    );
    let noise = synthetic::u8_field(48, |p| synthetic::fractal_noise(p.map(f64::from), 16.0, 4));
    let noise_tf = brickray_harness::scenes::noise_tf();
    compare("fractal noise (u8)", &noise, &noise_tf);
    // The shared head CT (i16) where present, else its procedural stand-in.
    let (ct, name) = brickray_harness::stand_in::head_ct_or_phantom().unwrap();
    compare(name, &ct, &brickray_harness::ct::soft_tissue());
}

/// A label map is never shaded from gradients of its ids: none are made.
#[test]
fn label_maps_make_no_gradients() {
    let n = 24u32;
    let ids: Vec<u8> = (0..n * n * n)
        .map(|i| {
            let p = [i % n, i / n % n, i / (n * n)].map(|c| c as f32 - n as f32 / 2.0);
            u8::from(p.iter().map(|c| c * c).sum::<f32>() < 64.0) * 3
        })
        .collect();
    let vol =
        brickray::core::labels::label_volume([n; 3], [1.0; 3], brickray::core::VolumeData::U8(ids))
            .unwrap();
    let tf = TransferFunction::ramp(0.0, 1.0, 1.0);
    let mut r = renderer(&vol, &tf, GradientSource::Precomputed);
    let before = r.volume_bytes();
    let mut s = shaded(RenderMode::Dvr, true);
    s.smooth_labels = true;
    draw(&mut r, &vol, s);
    assert_eq!(r.volume_bytes(), before);
}

/// An out-of-core configuration at `tolerance_px` whose uploads never wait.
fn streaming(tolerance_px: f32) -> brickray::OutOfCoreConfig {
    brickray::OutOfCoreConfig {
        tolerance_px,
        upload_budget_bytes: 1 << 30,
        ..Default::default()
    }
}

/// A streamed volume of `source` under `config` keeping gradients as
/// `gradients` says, and a renderer drawing it through `tf`.
fn streamed(
    source: &std::sync::Arc<dyn brickray::BrickSource>,
    tf: &TransferFunction,
    config: brickray::OutOfCoreConfig,
    gradients: KeepGradients,
) -> (VolumeRenderer, brickray::StreamedVolume) {
    let g = gpu();
    let options = brickray::VolumeOptions {
        gradients,
        ..Default::default()
    };
    let v = brickray::StreamedVolume::new(&g.device, &g.queue, source.clone(), config, options)
        .unwrap();
    let mut r = VolumeRenderer::new(&g.device, targets()).unwrap();
    r.set_streamed_volume(&g.device, &v).unwrap();
    r.set_transfer_function(&g.device, &g.queue, tf).unwrap();
    (r, v)
}

/// Marschner-Lobb at 48^3 (f32), its TF, and a store of it (in `dir`).
fn marschner_lobb_store(
    dir: &tempfile::TempDir,
) -> (
    Volume,
    TransferFunction,
    std::sync::Arc<dyn brickray::BrickSource>,
) {
    let vol = brickray::core::synthetic::marschner_lobb(48);
    let source = brickray_harness::store_of(&vol, &dir.path().join("vol.brs"));
    (vol, brickray_harness::scenes::marschner_lobb_tf(), source)
}

/// Marschner-Lobb's store (`marschner_lobb_store`) streamed at the finest
/// level twice, one volume keeping its gradients and one shading by six
/// reads, each with its renderer.
#[allow(clippy::type_complexity)]
fn kept_and_six_reads(
    dir: &tempfile::TempDir,
) -> (
    Volume,
    TransferFunction,
    (VolumeRenderer, brickray::StreamedVolume),
    (VolumeRenderer, brickray::StreamedVolume),
) {
    let (vol, tf, source) = marschner_lobb_store(dir);
    let kept = streamed(&source, &tf, streaming(0.0), KeepGradients::Always);
    let six = streamed(&source, &tf, streaming(0.0), KeepGradients::Never);
    (vol, tf, kept, six)
}

/// Out of core, a streamed volume that keeps its texels' gradients
/// (`VolumeOptions::gradients`): made on the GPU as each brick is uploaded,
/// counted in the atlas's bytes, and shading as six reads do (half floats
/// apart; the bricks' apron keeps every tap within the brick, so no factor
/// at the faces), at the finest level and at a coarser cut.
fn compare_out_of_core(name: &str, vol: &Volume, tf: &TransferFunction, tolerance_px: f32) -> f64 {
    let dir = tempfile::tempdir().unwrap();
    let source = brickray_harness::store_of(vol, &dir.path().join("vol.brs"));
    let config = streaming(tolerance_px);
    let (mut pre, with) = streamed(&source, tf, config, KeepGradients::Always);
    let (mut six, without) = streamed(&source, tf, config, KeepGradients::Never);
    // The atlas's bytes per texel: the texels' and 8 more for the gradients.
    // The default budget holds every brick either way, and the pool stops
    // there: the same slots, each larger.
    let bpp = brickray_harness::atlas_bytes_per_texel;
    let slots = |v: &brickray::StreamedVolume| v.inspect(|s| s.pool().slot_count()) as u64;
    assert_eq!(
        bpp(&with),
        bpp(&without) + 8,
        "{name}: 8 bytes of gradient a texel"
    );
    let bricks = brickray::cache::brick_count(&with.layout());
    assert!(
        slots(&with) == slots(&without) && slots(&with) >= bricks,
        "{name}: {} and {} slots for {bricks} bricks",
        slots(&with),
        slots(&without)
    );
    let s = shaded(RenderMode::Dvr, true);
    let a = draw_converged(&mut pre, vol, s);
    let b = draw_converged(&mut six, vol, s);
    // The cut's levels: only the finest at 0 px, some coarser one above.
    let levels = with.layout().levels as usize;
    let per_level = pre.stats().out_of_core.unwrap().data_leaves_per_level;
    let coarse: u32 = per_level[..levels - 1].iter().sum();
    assert_eq!(coarse > 0, tolerance_px > 0.0, "{name}: {per_level:?}");
    let label = format!("{name}, out of core at {tolerance_px} px, gradients kept");
    as_six_reads(&label, vol, tf, s, &a, &b)
}

#[test]
fn streamed_gradients_shade_as_six_reads() {
    use brickray::core::synthetic;
    let ml = synthetic::marschner_lobb(48);
    let ml_tf = brickray_harness::scenes::marschner_lobb_tf();
    compare_out_of_core("Marschner-Lobb (f32)", &ml, &ml_tf, 0.0);
    compare_out_of_core("Marschner-Lobb (f32)", &ml, &ml_tf, 16.0);
    let noise = synthetic::u8_field(48, |p| synthetic::fractal_noise(p.map(f64::from), 16.0, 4));
    compare_out_of_core(
        "fractal noise (u8)",
        &noise,
        &brickray_harness::scenes::noise_tf(),
        0.0,
    );
    let (ct, name) = brickray_harness::stand_in::head_ct_or_phantom().unwrap();
    compare_out_of_core(name, &ct, &brickray_harness::ct::soft_tissue(), 0.0);
}

/// Prepares a frame of `settings` and drops its encoder unsubmitted (the
/// queue's writes still land with the next submission, here an empty one).
fn prepare_and_drop(r: &mut VolumeRenderer, vol: &Volume, settings: RenderSettings) {
    let g = gpu();
    let (frame, camera) = view(vol);
    let desc = FrameDesc {
        camera,
        frame,
        viewport: Viewport::full(SIZE, SIZE),
        settings,
        host_depth: None,
        time: None,
    };
    let mut enc = g.device.create_command_encoder(&Default::default());
    r.prepare(&g.device, &g.queue, &mut enc, &desc).unwrap();
    drop(enc);
    g.queue.submit([g
        .device
        .create_command_encoder(&Default::default())
        .finish()]);
}

/// In core: the first shaded DVR frame's encoder dropped, so the pass that
/// makes the gradients never ran; the next frame records it again and
/// shades as six reads.
#[test]
fn a_dropped_gradient_pass_in_core_is_recorded_again() {
    let vol = brickray::core::synthetic::marschner_lobb(48);
    let tf = brickray_harness::scenes::marschner_lobb_tf();
    let mut pre = renderer(&vol, &tf, GradientSource::Precomputed);
    let mut six = renderer(&vol, &tf, GradientSource::SixReads);
    let s = shaded(RenderMode::Dvr, true);
    prepare_and_drop(&mut pre, &vol, s);
    let a = draw(&mut pre, &vol, s);
    let b = draw(&mut six, &vol, s);
    as_six_reads(
        "in core, the gradient pass dropped once",
        &vol,
        &tf,
        s,
        &a,
        &b,
    );
}

/// Out of core: a streamed volume that keeps gradients converges through
/// frames whose encoders are all dropped (every brick uploaded, none of their
/// gradient passes run; the bench's planning frames do this), then draws a
/// frame that uploads nothing: its encoder makes the gradients of every
/// brick whose pass was dropped, and the image is six reads'.
#[test]
fn dropped_gradient_passes_out_of_core_are_recorded_again() {
    let dir = tempfile::tempdir().unwrap();
    let (vol, tf, (mut pre, _with), (mut six, _without)) = kept_and_six_reads(&dir);
    let s = shaded(RenderMode::Dvr, true);
    let (mut planned, mut uploaded) = (0, 0);
    for _ in 0..60 {
        prepare_and_drop(&mut pre, &vol, s);
        planned += 1;
        uploaded += pre.stats().out_of_core.unwrap().cache.upload_bricks;
        if !pre.wants_redraw() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    assert!(
        !pre.wants_redraw(),
        "not converged in {planned} dropped frames"
    );
    assert!(uploaded > 0, "the dropped frames uploaded the cut");
    settled_frame_as_six_reads(
        "out of core, every gradient pass dropped",
        &mut pre,
        &mut six,
        &vol,
        &tf,
    );
}

/// Out of core the gradients are made by the first frame that shades DVR:
/// a volume converged through unshaded frames (every brick uploaded, no
/// pass) and then drawn shaded once shades as six reads do.
#[test]
fn kept_gradients_are_made_by_the_first_shaded_frame() {
    let dir = tempfile::tempdir().unwrap();
    let (vol, tf, (mut pre, _with), (mut six, _without)) = kept_and_six_reads(&dir);
    draw_converged(&mut pre, &vol, shaded(RenderMode::Dvr, false));
    settled_frame_as_six_reads(
        "out of core, gradients made by the first shaded frame",
        &mut pre,
        &mut six,
        &vol,
        &tf,
    );
}

/// One shaded DVR frame of `pre`, whose cut has converged, uploading no
/// brick (so its gradients come only from passes owed to bricks already
/// uploaded), against six reads' converged frame (`as_six_reads`).
fn settled_frame_as_six_reads(
    label: &str,
    pre: &mut VolumeRenderer,
    six: &mut VolumeRenderer,
    vol: &Volume,
    tf: &TransferFunction,
) {
    let s = shaded(RenderMode::Dvr, true);
    let (frames, a) = settle(pre, vol, s, 1);
    let last = pre.stats().out_of_core.unwrap().cache.upload_bricks;
    assert!(
        frames == Some(1) && last == 0,
        "{label}: the drawn frame uploaded {last} bricks"
    );
    let b = draw_converged(six, vol, s);
    as_six_reads(label, vol, tf, s, &a, &b);
}

/// The default, `KeepGradients::WhenEveryBrickFits`: a volume whose every
/// brick (each level's) fits the GPU budget with its gradients keeps them and
/// shades as six reads do; the same volume under a budget that holds its
/// bricks only without gradients (the pool would lose bricks to them) keeps
/// none, and a budget that holds them with gradients again keeps them.
#[test]
fn gradients_are_kept_by_default_where_every_brick_fits() {
    let dir = tempfile::tempdir().unwrap();
    let (vol, tf, source) = marschner_lobb_store(&dir);
    let bricks = brickray::cache::brick_count(source.layout());
    let open = |gpu_budget_bytes: u64| {
        let config = brickray::OutOfCoreConfig {
            gpu_budget_bytes,
            ..streaming(0.0)
        };
        streamed(&source, &tf, config, KeepGradients::default())
    };
    let slots = |v: &brickray::StreamedVolume| v.inspect(|s| s.pool().slot_count()) as u64;
    let (mut roomy_r, roomy) = open(1 << 30);
    assert!(
        roomy.keeps_gradients(),
        "1 GiB holds the {bricks} bricks with gradients"
    );
    assert!(slots(&roomy) >= bricks);
    // Just enough slots without gradients: with them, a fifth as many.
    let stored = source.layout().stored_side() as u64;
    let (mut tight_r, tight) = open(bricks * (stored.pow(3) * 4 + 64) + (1 << 16));
    assert!(
        !tight.keeps_gradients() && slots(&tight) >= bricks,
        "{} slots for {bricks} bricks",
        slots(&tight)
    );
    // Kept by default, drawn as six reads draw.
    let s = shaded(RenderMode::Dvr, true);
    let a = draw_converged(&mut roomy_r, &vol, s);
    let b = draw_converged(&mut tight_r, &vol, s);
    // The frames' statistics report the decision.
    let kept = |r: &VolumeRenderer| r.stats().out_of_core.unwrap().gradients_kept;
    assert!(kept(&roomy_r) && !kept(&tight_r));
    as_six_reads("kept by default, out of core", &vol, &tf, s, &a, &b);
}

/// The converged frame of `settings` (out of core, within 60 frames); RGBA8.
fn draw_converged(r: &mut VolumeRenderer, vol: &Volume, settings: RenderSettings) -> Vec<u8> {
    let (frames, img) = settle(r, vol, settings, 60);
    assert!(frames.is_some(), "not converged within 60 frames");
    img
}

/// A GPU budget that holds the minimum of slots without gradients but not
/// with them is a typed error when the streamed volume is made (nothing
/// created, no panic), and the same budget without gradients opens, as it
/// does by default (which then keeps none).
#[test]
fn a_budget_too_small_for_kept_gradients_is_a_typed_error() {
    let g = gpu();
    let vol = brickray::core::synthetic::marschner_lobb(48);
    let dir = tempfile::tempdir().unwrap();
    let source = brickray_harness::store_of(&vol, &dir.path().join("vol.brs"));
    // About 24 slots of 36^3 4-byte texels (the f32 volume's) without
    // gradients; with them, a third of that: below the 9 a pool needs.
    let config = brickray::OutOfCoreConfig {
        gpu_budget_bytes: 24 * 36u64.pow(3) * 4 + (1 << 16),
        ..Default::default()
    };
    let open = |gradients: KeepGradients| {
        let options = brickray::VolumeOptions {
            gradients,
            ..Default::default()
        };
        brickray::StreamedVolume::new(&g.device, &g.queue, source.clone(), config, options)
    };
    if let Err(e) = open(KeepGradients::Never) {
        panic!("the budget holds the slots without gradients: {e}");
    }
    // By default the volume opens, without them.
    match open(KeepGradients::default()) {
        Ok(v) => assert!(!v.keeps_gradients(), "kept where they do not fit"),
        Err(e) => panic!("the default keeps no gradients that do not fit: {e}"),
    }
    let e = open(KeepGradients::Always).expect_err("too small with gradients");
    eprintln!("{e}");
    // (`RenderError::Cache(CacheError::Config(..))`: the facade does not
    // re-export `CacheError`, so the variant inside is read from `Debug`.)
    assert!(
        matches!(e, brickray::RenderError::Cache(_))
            && format!("{e:?}").contains("GpuBudgetTooSmall"),
        "{e:?}"
    );
}
