//! GPU tests of level-of-detail fades and the coarse floor, out of core
//! (docs/stability.md):
//!
//! * a split fades over the configured frames: with every brick resident, a
//!   tolerance change refines the whole cut in one frame; with fades of 4
//!   frames the 3 frames in between lie between the old and the new image
//!   (mean absolute distance to the old one grows, to the new one shrinks) and
//!   the 4th is the new image; with fades off the 1st is; a renderer warmed
//!   up for the mode compiles no pipeline in any of these frames;
//! * the floor: with a pool of 40 slots and a CPU cache of 9 bricks, a camera
//!   circling and diving never draws a leaf without a brick (`holes` 0);
//! * a zoom path (40 frames, 2.6% closer a frame, tolerance 4 px) with fades
//!   of 6 frames has no pop (16x16 tile error change above 8 units against
//!   the in-core rendering at the finest level); without fades it has some.
//! * a fading leaf skips empty space, with one channel and with two: in the
//!   frame a split from level 1 to the finest starts fading, skipping on
//!   draws the image skipping off draws, with fewer samples per ray, in DVR,
//!   MIP and iso.

use brickray::core::channels::ChannelStyle;
use brickray::{
    Camera, FadeDuration, FrameDesc, OutOfCoreConfig, RenderMode, RenderSettings, TransferFunction,
    Volume, VolumeFrame, VolumeRenderer,
};
use brickray_harness::{Offscreen, draw_frame, draw_until_settled};
use brickray_harness::{shared_gpu as gpu, target_desc as targets};
use brickray_reference::{TemporalOptions, temporal_stability};
use glam::Vec3;
use std::sync::Arc;

const SIZE: u32 = 64;

/// The modes every fade test draws.
const MODES: [RenderMode; 3] = [
    RenderMode::Dvr,
    RenderMode::Mip,
    RenderMode::Iso {
        value: 0.6,
        color: [1.0, 0.8, 0.6],
    },
];

fn noise(n: u32) -> Volume {
    brickray_harness::scenes::noise_volume(n)
}

/// A store of `vol` with 8-voxel bricks (4 levels at 64^3).
fn store(vol: &Volume, dir: &tempfile::TempDir) -> Arc<dyn brickray::BrickSource> {
    store_of(vol, dir, 8)
}

/// A store of `vol` with `brick`-voxel bricks.
fn store_of(vol: &Volume, dir: &tempfile::TempDir, brick: u32) -> Arc<dyn brickray::BrickSource> {
    store_in(vol, &dir.path().join("noise.brs"), brick)
}

/// A store of `vol` at `path` with `brick`-voxel bricks.
fn store_in(vol: &Volume, path: &std::path::Path, brick: u32) -> Arc<dyn brickray::BrickSource> {
    let mut reader = brickray::io::MemoryReader::new(vol.clone(), "memory");
    let opt = brickray::store::BuildOptions {
        brick,
        ..Default::default()
    };
    brickray::store::build(&mut reader, path, &opt).unwrap();
    Arc::new(brickray::store::open(path).unwrap())
}

fn tf() -> TransferFunction {
    TransferFunction::ramp(0.5, 0.8, 0.5)
}

fn renderer(source: Arc<dyn brickray::BrickSource>, config: OutOfCoreConfig) -> VolumeRenderer {
    let g = gpu();
    let mut r = VolumeRenderer::new(&g.device, targets()).unwrap();
    r.set_volume_source(&g.device, &g.queue, source, config)
        .unwrap();
    r.set_transfer_function(&g.device, &g.queue, &tf()).unwrap();
    r
}

fn desc(camera: Camera, mode: RenderMode) -> FrameDesc<'static> {
    FrameDesc {
        settings: RenderSettings {
            mode,
            ..Default::default()
        },
        ..FrameDesc::new(camera, VolumeFrame::centered([64; 3], [1.0; 3]), SIZE, SIZE)
    }
}

fn draw(r: &mut VolumeRenderer, t: &Offscreen, d: &FrameDesc<'_>) -> Vec<u8> {
    draw_frame(gpu(), r, t, d, Some(brickray::wgpu::Color::BLACK)).unwrap();
    t.read_color(gpu())
}

fn settle(r: &mut VolumeRenderer, t: &Offscreen, d: &FrameDesc<'_>) -> Vec<u8> {
    draw_until_settled(gpu(), r, t, d, 400)
        .unwrap()
        .expect("settles");
    draw(r, t, d)
}

fn mad(a: &[u8], b: &[u8]) -> f64 {
    let s: u64 = a
        .chunks_exact(4)
        .zip(b.chunks_exact(4))
        .map(|(p, q)| (0..3).map(|k| p[k].abs_diff(q[k]) as u64).sum::<u64>())
        .sum();
    s as f64 / (a.len() / 4 * 3) as f64
}

/// What [`switch`] drew: the settled coarse and fine images, the frames
/// after the switch, and the pipelines compiled once the renderer was warmed
/// up for the mode and at the end.
struct Switch {
    old: Vec<u8>,
    new: Vec<u8>,
    after: Vec<Vec<u8>>,
    pipelines_warm: usize,
    pipelines_end: usize,
}

/// Warms the renderer up for the mode's default settings, settles coarse
/// (root only) and fine (all resident), then switches from coarse to fine.
fn switch(mode: RenderMode, fade: Option<FadeDuration>, frames: usize) -> Switch {
    let vol = noise(64);
    let dir = tempfile::tempdir().unwrap();
    let mut r = renderer(
        store(&vol, &dir),
        OutOfCoreConfig {
            fade,
            tolerance_px: 0.0,
            upload_budget_bytes: 1 << 30,
            ..Default::default()
        },
    );
    let t = Offscreen::new(&gpu().device, SIZE, SIZE);
    let d = desc(Camera::orbit(Vec3::ZERO, 1.8, 0.5, 0.3), mode);
    r.warm_up(&gpu().device, &[d.settings]).unwrap();
    let pipelines_warm = r.compiled_pipelines();
    let new = settle(&mut r, &t, &d);
    brickray_harness::configure(gpu(), &r, |c| c.tolerance_px = 1e6).unwrap();
    let old = settle(&mut r, &t, &d);
    assert_eq!(
        r.stats().out_of_core.unwrap().data_leaves_per_level[0],
        1,
        "coarse: the root"
    );
    brickray_harness::configure(gpu(), &r, |c| c.tolerance_px = 0.0).unwrap();
    let after = (0..frames).map(|_| draw(&mut r, &t, &d)).collect();
    Switch {
        old,
        new,
        after,
        pipelines_warm,
        pipelines_end: r.compiled_pipelines(),
    }
}

#[test]
fn a_split_fades_over_the_configured_frames() {
    for mode in MODES {
        let Switch {
            old,
            new,
            after,
            pipelines_warm,
            pipelines_end,
        } = switch(mode, Some(FadeDuration::Frames(4)), 5);
        // Warming up compiled what the frames used: with fading leaves (while
        // bricks arrived, and during the split's fade) and without (settled).
        assert!(pipelines_warm >= 2, "{mode:?}: {pipelines_warm} warmed");
        assert_eq!(
            pipelines_end, pipelines_warm,
            "{mode:?}: a frame compiled a pipeline warm_up had not"
        );
        let span = mad(&old, &new);
        assert!(span > 1.0, "{mode:?}: the levels differ ({span})");
        let to_old: Vec<f64> = after.iter().map(|f| mad(f, &old)).collect();
        let to_new: Vec<f64> = after.iter().map(|f| mad(f, &new)).collect();
        eprintln!("{mode:?}: old-new {span:.2}, to old {to_old:.2?}, to new {to_new:.2?}");
        for j in 0..3 {
            // Strictly between, and moving from the old image to the new one.
            assert!(
                to_old[j] > 0.0 && to_new[j] > 0.0,
                "{mode:?} frame {j} is an end"
            );
            assert!(
                to_old[j] < span && to_new[j] < span,
                "{mode:?} frame {j} beyond"
            );
            assert!(
                to_new[j + 1] < to_new[j],
                "{mode:?}: not toward the new image"
            );
            assert!(
                to_old[j + 1] > to_old[j],
                "{mode:?}: not away from the old image"
            );
        }
        assert_eq!(to_new[3], 0.0, "{mode:?}: the 4th frame is the new image");
        assert_eq!(to_new[4], 0.0);
    }
}

/// The first frame of a split's fade: the occluder scene at 128^3 in bricks
/// of 32 (4x4x4 sub-cells), settled with every brick resident, drawn at level
/// 1, then refined to the finest level with fades of 4 frames, with
/// empty-space skipping on or off. With `channels`, the scene and the nested
/// shells as two channels of one volume (the multi-channel kernel). Returns
/// the frame and the leaves fading in it.
fn fading_frame(
    mode: RenderMode,
    skip: bool,
    channels: bool,
) -> (brickray_harness::predict::FrameResult, u32) {
    let vol = brickray_harness::predict::occluder_scene(128);
    let dir = tempfile::tempdir().unwrap();
    let config = OutOfCoreConfig {
        fade: Some(FadeDuration::Frames(4)),
        tolerance_px: 0.0,
        upload_budget_bytes: 1 << 30,
        ..Default::default()
    };
    let mut r = if channels {
        let shells = brickray_harness::predict::nested_shells(128);
        let parts = vec![
            store_of(&vol, &dir, 32),
            store_in(&shells, &dir.path().join("shells.brs"), 32),
        ];
        let g = gpu();
        let mut r = VolumeRenderer::new(&g.device, targets()).unwrap();
        let source = Arc::new(brickray::ChannelSource::new(parts).unwrap());
        r.set_volume_source(&g.device, &g.queue, source, config)
            .unwrap();
        let styles: Vec<_> = [[1.0, 0.5, 0.2], [0.2, 0.6, 1.0]]
            .map(|c| ChannelStyle::window(c, [0.5, 0.8], 0.5).with_isovalue(0.6))
            .into();
        r.set_channel_styles(&styles).unwrap();
        r
    } else {
        renderer(store_of(&vol, &dir, 32), config)
    };
    let t = Offscreen::new(&gpu().device, SIZE, SIZE);
    let mut d = desc(Camera::orbit(Vec3::ZERO, 1.8, 0.5, 0.3), mode);
    d.frame = VolumeFrame::centered([128; 3], [0.5; 3]);
    d.settings.accel.empty_space_skipping = skip;
    settle(&mut r, &t, &d);
    brickray_harness::configure(gpu(), &r, |c| c.tolerance_px = 2.0).unwrap();
    settle(&mut r, &t, &d);
    let levels = r.stats().out_of_core.unwrap().data_leaves_per_level;
    assert_eq!(
        levels[..3],
        [0, 8, 0],
        "{mode:?}: level 1 drawn before the split"
    );
    brickray_harness::configure(gpu(), &r, |c| c.tolerance_px = 0.0).unwrap();
    let frame = brickray_harness::predict::draw(gpu(), &mut r, &t, &d).unwrap();
    let stats = r.stats().out_of_core.unwrap();
    let leaves: u32 = stats.data_leaves_per_level.iter().sum();
    assert_eq!(
        stats.data_leaves_per_level[2], leaves,
        "{mode:?}: split to the finest level"
    );
    (frame, stats.cache.fading)
}

/// Skipping on and off in the first frame of a fade (`fading_frame`): the
/// same image, fewer samples.
fn check_fading_skips(channels: bool) {
    use brickray_harness::predict::samples_per_ray;
    for mode in MODES {
        let (on, fading) = fading_frame(mode, true, channels);
        let (off, _) = fading_frame(mode, false, channels);
        assert!(fading >= 32, "{mode:?}: the frame fades ({fading} leaves)");
        let worst = on
            .color
            .iter()
            .zip(&off.color)
            .map(|(a, b)| a.abs_diff(*b))
            .max()
            .unwrap();
        let (s_on, s_off) = (samples_per_ray(&on.samples), samples_per_ray(&off.samples));
        eprintln!(
            "{mode:?} (channels: {channels}): {fading} leaves fading, samples per ray {s_on:.1} skipping, {s_off:.1} not, worst channel difference {worst}"
        );
        // Skipping passes over only what shows nothing.
        assert!(
            worst <= 1,
            "{mode:?}: skipping changed the image by {worst}"
        );
        // When fading leaves did not skip, the two took the same samples.
        assert!(
            s_on < 0.8 * s_off,
            "{mode:?}: fading leaves took {s_on:.1} samples per ray skipping, {s_off:.1} not"
        );
    }
}

#[test]
fn fading_leaves_skip_empty_space() {
    check_fading_skips(false);
}

#[test]
fn fading_leaves_of_channels_skip_empty_space() {
    check_fading_skips(true);
}

#[test]
fn fades_off_switch_in_one_frame() {
    let Switch {
        old, new, after, ..
    } = switch(RenderMode::Dvr, None, 2);
    assert!(mad(&old, &new) > 1.0);
    assert_eq!(mad(&after[0], &new), 0.0);
}

#[test]
fn the_floor_prevents_holes_under_a_tiny_pool_while_circling() {
    let vol = noise(64);
    let dir = tempfile::tempdir().unwrap();
    let source = store(&vol, &dir);
    let layout = source.layout().clone();
    let gpu_format = brickray::cache::GpuFormat::for_layout(
        &layout,
        brickray_core::TexelCaps {
            norm16: true,
            float32_filterable: false,
        },
        brickray::U8Filtering::default(),
        32,
        2048,
    );
    let slot = gpu_format.slot_bytes(&layout).unwrap();
    let brick = gpu_format.prepared_brick_bytes(&layout).unwrap();
    let mut r = renderer(
        source,
        OutOfCoreConfig {
            gpu_budget_bytes: 40 * slot,
            cpu_budget_bytes: 9 * brick,
            fade: Some(FadeDuration::Frames(3)),
            ..Default::default()
        },
    );
    let t = Offscreen::new(&gpu().device, SIZE, SIZE);
    let (mut holes, mut floor) = (0, 0);
    for i in 0..90 {
        let a = i as f32 * 0.12;
        let dist = 1.0 + 0.7 * (i as f32 * 0.21).sin();
        let d = desc(
            Camera::orbit(Vec3::ZERO, dist, a, 0.3 * a.cos()),
            RenderMode::Dvr,
        );
        draw(&mut r, &t, &d);
        let s = r.stats().out_of_core.unwrap();
        holes = holes.max(s.cache.holes);
        floor = floor.max(s.cache.floor_pinned);
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    assert!(floor > 0, "the floor was never resident");
    assert_eq!(holes, 0, "a frame drew a leaf without a brick");
}

const TOL: f32 = 4.0;

#[test]
fn a_zoom_path_with_fades_has_no_pop() {
    let vol = noise(64);
    let dir = tempfile::tempdir().unwrap();
    let g = gpu();
    let t = Offscreen::new(&g.device, SIZE, SIZE);
    // A zoom from 2.5 to 0.9, 2.6% closer a frame.
    let cams: Vec<Camera> = (0..40)
        .map(|i| {
            let d = 2.5 * (0.9f32 / 2.5).powf(i as f32 / 39.0);
            Camera::orbit(Vec3::ZERO, d, 0.6, 0.35)
        })
        .collect();
    // The reference: in core, the finest level.
    let mut incore = VolumeRenderer::new(&g.device, targets()).unwrap();
    incore.set_volume(&g.device, &g.queue, &vol).unwrap();
    incore
        .set_transfer_function(&g.device, &g.queue, &tf())
        .unwrap();
    let reference: Vec<Vec<u8>> = cams
        .iter()
        .map(|c| draw(&mut incore, &t, &desc(*c, RenderMode::Dvr)))
        .collect();
    let run = |fade| {
        let mut r = renderer(
            store(&vol, &dir),
            OutOfCoreConfig {
                fade,
                tolerance_px: TOL,
                ..Default::default()
            },
        );
        settle(&mut r, &t, &desc(cams[0], RenderMode::Dvr));
        let imgs: Vec<Vec<u8>> = cams
            .iter()
            .map(|c| {
                let img = draw(&mut r, &t, &desc(*c, RenderMode::Dvr));
                std::thread::sleep(std::time::Duration::from_millis(10));
                img
            })
            .collect();
        temporal_stability(&imgs, &reference, SIZE, SIZE, TemporalOptions::default()).unwrap()
    };
    let on = run(Some(FadeDuration::Frames(6)));
    let off = run(None);
    eprintln!("fades on: {on:?}\nfades off: {off:?}");
    assert_eq!(on.pops, 0, "pops with fades: {:?}", on.pop_frames);
    // The path does pop without fades (else it would test nothing).
    assert!(off.pops > 0, "no pop without fades");
}
