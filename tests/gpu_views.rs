//! Several views of one streamed volume (docs/cache.md, "Views of one
//! volume"): a stereo pair, and a 3D view beside an orthogonal one, drawn by
//! two renderers that share one `StreamedVolume` and are prepared together.
//!
//! * each brick is read from the source at most once (a counting source);
//! * the two renderers share one pool (one atlas, one cut);
//! * at convergence each view's image equals the image the view gets alone,
//!   from a volume of its own, within 50 dB PSNR (the shared cut is the finer
//!   of the two views' cuts, so a view may show a little more detail);
//! * views prepared together that disagree on the transfer function are a
//!   typed error.

use brickray::{
    Camera, FrameDesc, OutOfCoreConfig, PrepareError, Projection, RenderSettings, StreamedVolume,
    TransferFunction, VolumeFrame, VolumeRenderer,
};
use brickray_harness::{CountingSource, Offscreen, shared_gpu as gpu, target_desc as targets};
use brickray_reference::psnr;
use glam::Vec3;
use std::sync::Arc;

const SIZE: u32 = 96;

/// The noise volume as a store whose brick reads are counted.
fn counting(dir: &tempfile::TempDir) -> Arc<CountingSource> {
    let vol = brickray_harness::scenes::noise_volume(64);
    CountingSource::store(vol, dir.path(), "noise", 8)
}

fn config() -> OutOfCoreConfig {
    OutOfCoreConfig {
        upload_budget_bytes: 1 << 30,
        fade: None,
        ..Default::default()
    }
}

fn tf() -> TransferFunction {
    TransferFunction::ramp(0.45, 0.9, 0.6)
}

fn placement() -> VolumeFrame {
    VolumeFrame::centered([64; 3], [1.0; 3])
}

fn desc(camera: Camera) -> FrameDesc<'static> {
    FrameDesc {
        settings: RenderSettings::default(),
        ..FrameDesc::new(camera, placement(), SIZE, SIZE)
    }
}

fn renderer(volume: &StreamedVolume) -> VolumeRenderer {
    let g = gpu();
    let mut r = VolumeRenderer::new(&g.device, targets()).unwrap();
    r.set_streamed_volume(&g.device, volume).unwrap();
    r.set_transfer_function(&g.device, &g.queue, &tf()).unwrap();
    r
}

/// Draws the views, prepared together, until every one has converged;
/// returns their images.
fn converge(rs: &mut [VolumeRenderer], cams: &[Camera]) -> Vec<Vec<u8>> {
    let g = gpu();
    let targets: Vec<Offscreen> = cams
        .iter()
        .map(|_| Offscreen::new(&g.device, SIZE, SIZE))
        .collect();
    let descs: Vec<FrameDesc<'static>> = cams.iter().map(|c| desc(*c)).collect();
    for _ in 0..300 {
        let mut enc = g.device.create_command_encoder(&Default::default());
        {
            let mut views: Vec<(&mut VolumeRenderer, &FrameDesc<'_>)> =
                rs.iter_mut().zip(&descs).collect();
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

fn check_pair(name: &str, cams: [Camera; 2]) {
    let g = gpu();
    let dir = tempfile::tempdir().unwrap();
    let src = counting(&dir);
    let volume = StreamedVolume::new(
        &g.device,
        &g.queue,
        src.clone(),
        config(),
        Default::default(),
    )
    .unwrap();
    let mut rs = [renderer(&volume), renderer(&volume)];
    let shared = converge(&mut rs, &cams);
    // One volume, one pool.
    let (a, b) = (&rs[0], &rs[1]);
    assert!(
        a.streamed_volume()
            .unwrap()
            .same(b.streamed_volume().unwrap())
    );
    let (sa, sb) = (
        a.stats().out_of_core.unwrap(),
        b.stats().out_of_core.unwrap(),
    );
    assert_eq!(
        sa.cache.frame, sb.cache.frame,
        "{name}: planned once per frame"
    );
    assert_eq!(sa.cache.working_set_bricks, sb.cache.working_set_bricks);
    let reads = src.reads();
    let twice: Vec<_> = reads.iter().filter(|(_, n)| **n > 1).collect();
    assert!(
        twice.is_empty(),
        "{name}: bricks read more than once: {twice:?}"
    );
    // Each view alone, from a volume of its own.
    for (i, cam) in cams.iter().enumerate() {
        let own = StreamedVolume::new(
            &g.device,
            &g.queue,
            counting(&dir),
            config(),
            Default::default(),
        )
        .unwrap();
        let mut alone = [renderer(&own)];
        let img = converge(&mut alone, &[*cam]).remove(0);
        let db = psnr(&shared[i], &img);
        eprintln!(
            "{name}, view {i}: {db:.1} dB against the view alone ({} bricks shared, {} alone)",
            sa.cache.working_set_bricks,
            alone[0]
                .stats()
                .out_of_core
                .unwrap()
                .cache
                .working_set_bricks
        );
        assert!(db >= 50.0, "{name}, view {i}: {db:.1} dB");
    }
}

#[test]
fn a_stereo_pair_shares_one_cut() {
    let eye = |dx: f32| Camera::orbit(Vec3::new(dx, 0.0, 0.0), 1.6, 0.4, 0.3);
    check_pair("stereo", [eye(-0.03), eye(0.03)]);
}

#[test]
fn a_3d_view_and_an_orthogonal_view_share_one_cut() {
    let orthogonal = Camera {
        projection: Projection::Orthographic { height: 1.2 },
        ..Camera::orbit(Vec3::ZERO, 3.0, 0.0, 0.0)
    };
    check_pair(
        "3d + orthogonal",
        [Camera::orbit(Vec3::ZERO, 1.5, 0.8, 0.4), orthogonal],
    );
}

#[test]
fn views_planned_together_share_the_transfer_function() {
    let g = gpu();
    let dir = tempfile::tempdir().unwrap();
    let volume = StreamedVolume::new(
        &g.device,
        &g.queue,
        counting(&dir),
        config(),
        Default::default(),
    )
    .unwrap();
    let mut a = renderer(&volume);
    let mut b = renderer(&volume);
    b.set_transfer_function(&g.device, &g.queue, &TransferFunction::ramp(0.1, 0.2, 0.3))
        .unwrap();
    let d = desc(Camera::orbit(Vec3::ZERO, 1.6, 0.4, 0.3));
    let mut enc = g.device.create_command_encoder(&Default::default());
    let e = VolumeRenderer::prepare_views(
        &g.device,
        &g.queue,
        &mut enc,
        &mut [(&mut a, &d), (&mut b, &d)],
    );
    assert!(
        matches!(e, Err(PrepareError::ViewsDisagree { first: 0, other: 1 })),
        "{e:?}"
    );
    drop(enc);
    // Apart, in submissions of their own, each is planned for its own view.
    for r in [&mut a, &mut b] {
        let mut enc = g.device.create_command_encoder(&Default::default());
        r.prepare(&g.device, &g.queue, &mut enc, &d).unwrap();
        g.submit_wait(enc);
    }
}

/// Background planning (a worker thread plans the next frame while the
/// current one renders): a view converges to the image inline planning gives,
/// stops wanting redraws once converged, and survives a pool rebuild (a GPU
/// budget change) while a plan is in flight.
#[test]
fn background_planning_converges_to_the_inline_image() {
    let g = gpu();
    let dir = tempfile::tempdir().unwrap();
    let cam = Camera::orbit(Vec3::ZERO, 1.5, 0.8, 0.4);
    let mut images = Vec::new();
    for background in [false, true] {
        let options = brickray::VolumeOptions {
            background_planning: background,
            ..Default::default()
        };
        let volume =
            StreamedVolume::new(&g.device, &g.queue, counting(&dir), config(), options).unwrap();
        let mut r = [renderer(&volume)];
        images.push(converge(&mut r, &[cam]).remove(0));
        assert!(!volume.wants_redraw(), "background {background}");
        if background {
            // A smaller pool: rebuilt under a plan in flight; the view
            // converges again to the same image.
            let d = desc(cam);
            let mut enc = g.device.create_command_encoder(&Default::default());
            r[0].prepare(&g.device, &g.queue, &mut enc, &d).unwrap();
            g.submit_wait(enc);
            volume
                .edit(&g.device, &g.queue, |c| c.gpu_budget_bytes = 48 << 20)
                .unwrap();
            let again = converge(&mut r, &[cam]).remove(0);
            let db = psnr(&images[0], &again);
            assert!(db >= 50.0, "after the pool rebuild: {db:.1} dB");
            // A change that keeps the pool (a brick budget) is planned too:
            // the converged view wants a redraw at once and settles within
            // the budget.
            let free = volume.stats().cache.working_set_bricks;
            let budget = (free / 2).max(1);
            volume
                .edit(&g.device, &g.queue, |c| c.brick_budget = Some(budget))
                .unwrap();
            assert!(volume.wants_redraw(), "a new budget wants a redraw");
            converge(&mut r, &[cam]);
            let capped = volume.stats().cache.working_set_bricks;
            assert!(
                (1..=budget).contains(&capped) && capped < free,
                "budget {budget}: {capped} bricks (free {free})"
            );
        }
    }
    let db = psnr(&images[0], &images[1]);
    eprintln!("background against inline planning: {db:.1} dB");
    assert!(db >= 50.0, "{db:.1} dB");
}
