//! Multi-channel volumes streamed out of core on a real wgpu device
//! (lavapipe in CI), against the CPU reference's channel compositing
//! (`brickray_reference::render_channels_reference`):
//!
//! * 2 and 4 u16 channels, each built into its own brick store and read
//!   together as one `ChannelSource` (one brick per node holds every
//!   channel): DVR, shaded DVR, MIP and per-channel isosurfaces at the
//!   finest level >= 45 dB;
//! * every brick is read once for all its channels: each channel's store
//!   reads exactly the nodes the others read, each once;
//! * one streamed channel through its style equals the single-channel
//!   out-of-core image with its transfer function (>= 60 dB);
//! * a hidden channel gives the image of the others and is skipped (the
//!   same samples as the volume without it), and sub-cell skipping changes
//!   no pixel (>= 60 dB) while it skips samples;
//! * refinement under the channels' styles: a channel hidden or made
//!   transparent leaves its bricks unloaded (fewer reads), without touching
//!   the store; error-aware refinement weighs each visible channel's
//!   recorded LOD error through its own transfer function (the planner
//!   alone, no GPU);
//! * the shared confocal nuclei with two transformed copies as three
//!   streamed channels (u16, three channels in RGBA texels): >= 45 dB in
//!   every mode;
//! * slices and slabs of streamed channels against `render_channel_slice`:
//!   >= 45 dB;
//! * typed errors: styles that do not match, no styles, sources that do not
//!   share an octree.
//!
//! Images are marched at step 1/2 in both renderers.

#[path = "channel_support.rs"]
mod channel_support;

use brickray::core::channels::{ChannelStyle, ChannelVolume};
use brickray::{
    Camera, ChannelError, ChannelSource, FrameDesc, OutOfCoreConfig, PrepareError, RenderError,
    RenderSettings, Volume, VolumeFrame, VolumeRenderer,
};
use brickray_harness::CountingSource;
use brickray_harness::predict::draw;
use brickray_harness::{Offscreen, draw_until_settled, shared_gpu as gpu, target_desc};
use brickray_reference::compare;
use glam::Vec3;
use std::collections::HashMap;
use std::sync::Arc;

const SIZE: u32 = 80;
const MIN_DB: f64 = 45.0;
const STEP: f32 = 0.5;

use brickray_harness::channels::COLORS;

use brickray_harness::channels::{
    blob_channel as channel, blob_channels as channels, blob_styles as styles,
};

fn modes() -> Vec<(&'static str, RenderSettings)> {
    brickray_harness::channels::modes(STEP, 0.45)
}

/// Each channel built into a store of 8-voxel bricks under `dir`, its reads
/// counted.
fn stores(vols: &[Volume], dir: &std::path::Path) -> Vec<Arc<CountingSource>> {
    vols.iter()
        .enumerate()
        .map(|(c, v)| CountingSource::store(v.clone(), dir, &format!("c{c}"), 8))
        .collect()
}

fn source(parts: &[Arc<CountingSource>]) -> Arc<ChannelSource> {
    let parts = parts
        .iter()
        .map(|p| p.clone() as Arc<dyn brickray::BrickSource>)
        .collect();
    Arc::new(ChannelSource::new(parts).unwrap())
}

/// Out of core at the finest level, with room for every brick.
fn config() -> OutOfCoreConfig {
    OutOfCoreConfig {
        tolerance_px: 0.0,
        upload_budget_bytes: 1 << 30,
        ..Default::default()
    }
}

fn streamed(src: Arc<ChannelSource>, styles: &[ChannelStyle]) -> VolumeRenderer {
    let g = gpu();
    let mut r = VolumeRenderer::new(&g.device, target_desc()).unwrap();
    r.set_volume_source(&g.device, &g.queue, src, config())
        .unwrap();
    r.set_channel_styles(styles).unwrap();
    r
}

/// Draws `desc` until the streamed volume settles; returns its last frame.
fn settle(
    r: &mut VolumeRenderer,
    target: &Offscreen,
    desc: &FrameDesc<'_>,
) -> brickray_harness::predict::FrameResult {
    let g = gpu();
    draw_until_settled(g, r, target, desc, 300)
        .unwrap()
        .expect("the streamed channels settle");
    draw(g, r, target, desc).unwrap()
}

/// The streamed channels against the reference in every mode; returns the
/// smallest PSNR.
fn check(name: &str, vols: Vec<Volume>, styles: &[ChannelStyle], camera: Camera) -> f64 {
    let g = gpu();
    let dir = tempfile::tempdir().unwrap();
    let parts = stores(&vols, dir.path());
    let vol = ChannelVolume::new(vols).unwrap();
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let mut r = streamed(source(&parts), styles);
    let worst = channel_support::check_channel_modes(
        &format!("streamed channels {name}"),
        &mut r,
        &vol,
        styles,
        camera,
        SIZE,
        STEP,
        MIN_DB,
        150,
        |r, desc| settle(r, &target, desc).color,
    );
    // Each brick was read once, for all its channels: every channel's store
    // read the same nodes, each once.
    let reads: Vec<HashMap<_, u32>> = parts.iter().map(|p| p.reads()).collect();
    assert!(!reads[0].is_empty(), "{name}: nothing was read");
    for (c, r) in reads.iter().enumerate() {
        assert!(
            r.values().all(|&n| n == 1),
            "{name}: channel {c} read a brick twice: {r:?}"
        );
        let mut a: Vec<_> = r.keys().collect();
        let mut b: Vec<_> = reads[0].keys().collect();
        a.sort();
        b.sort();
        assert_eq!(a, b, "{name}: channel {c} read other bricks than channel 0");
    }
    eprintln!(
        "{name}: {} bricks, each read once for all channels",
        reads[0].len()
    );
    worst
}

#[test]
fn two_and_four_streamed_channels_match_the_reference() {
    let camera = Camera::orbit(Vec3::ZERO, 2.3, 0.6, 0.35);
    for n in [2, 4] {
        let worst = check(&format!("{n} channels"), channels(n), &styles(n), camera);
        eprintln!("{n} streamed channels: worst {worst:.1} dB");
    }
}

/// Runs `check` on the four blob channels streamed from their stores at
/// the finest level, seen from the tests' camera, with the settled draw of
/// a `SIZE` px target.
fn on_four_streamed_channels(
    check: impl FnOnce(
        &mut VolumeRenderer,
        &ChannelVolume,
        &[ChannelStyle],
        Camera,
        &mut channel_support::Draw<'_>,
    ),
) {
    let all = channels(4);
    let dir = tempfile::tempdir().unwrap();
    let parts = stores(&all, dir.path());
    let vol = ChannelVolume::new(all).unwrap();
    let target = Offscreen::new(&gpu().device, SIZE, SIZE);
    let mut r = streamed(source(&parts), &styles(4));
    let camera = Camera::orbit(Vec3::ZERO, 2.3, 0.6, 0.35);
    let mut draw = |r: &mut VolumeRenderer, desc: &FrameDesc<'_>| settle(r, &target, desc).color;
    check(&mut r, &vol, &styles(4), camera, &mut draw);
}

/// MIP refines each streamed channel's peaks between samples in the bricks
/// that hold them (`channel_support::check_channel_mip_at_a_coarse_step`, four
/// channels at a step of 2 voxels, the finest level): the GPU against its
/// twin >= 62 dB, and against the fine reference at least 8 dB closer than
/// the samples' maxima alone.
#[test]
fn streamed_channel_mip_refines_each_maximum_between_samples() {
    on_four_streamed_channels(|r, vol, styles, camera, draw| {
        let label = "four streamed channels";
        channel_support::check_channel_mip_at_a_coarse_step(
            label, r, vol, styles, camera, SIZE, draw,
        );
    });
}

/// DVR's step doubles as the mixture's transmittance falls in the streamed
/// channels too (`channel_support::check_channel_adaptive_step`, four
/// channels at a step of 1 voxel, the finest level): the GPU against its
/// twin >= 55 dB, and 10 dB closer to it than to the fixed step's reference.
#[test]
fn streamed_channel_dvr_takes_the_adaptive_step() {
    on_four_streamed_channels(|r, vol, styles, camera, draw| {
        let label = "four streamed channels";
        channel_support::check_channel_adaptive_step(
            label, r, vol, styles, camera, SIZE, 1.0, 55.0, draw,
        );
    });
}

/// One streamed channel drawn through its style equals the single-channel
/// out-of-core image with that style's transfer function (>= 60 dB).
#[test]
fn one_streamed_channel_is_the_single_channel_image() {
    let g = gpu();
    let vol = channel([0.4, 0.5, 0.5], 1.0);
    let dir = tempfile::tempdir().unwrap();
    let parts = stores(std::slice::from_ref(&vol), dir.path());
    let frame = VolumeFrame::centered(vol.dims(), vol.desc().spacing);
    let camera = Camera::orbit(Vec3::ZERO, 2.3, 0.6, 0.35);
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let style = ChannelStyle::window(COLORS[0], [0.08, 0.7], 0.6).with_isovalue(0.45);
    let mut multi = streamed(source(&parts), std::slice::from_ref(&style));
    let mut single = VolumeRenderer::new(&g.device, target_desc()).unwrap();
    single
        .set_volume_source(&g.device, &g.queue, parts[0].clone(), config())
        .unwrap();
    single
        .set_transfer_function(&g.device, &g.queue, &style.tf)
        .unwrap();
    for (mode, mut settings) in modes() {
        if let brickray::RenderMode::Iso { .. } = settings.mode {
            settings.mode = brickray::RenderMode::Iso {
                value: style.isovalue,
                color: style.iso_color(),
            };
        }
        let desc = FrameDesc {
            settings,
            ..FrameDesc::new(camera, frame, SIZE, SIZE)
        };
        let a = settle(&mut multi, &target, &desc).color;
        let b = settle(&mut single, &target, &desc).color;
        let c = compare(&a, &b, SIZE, SIZE);
        eprintln!(
            "one streamed channel {mode}: {:.1} dB, max {}",
            c.psnr_db, c.max_abs_diff
        );
        assert!(c.psnr_db >= 60.0, "one streamed channel {mode}: {c:?}");
    }
}

/// A hidden channel: the image of the others with the samples of the
/// volume without it; skipping changes nothing but the samples taken.
#[test]
fn a_hidden_streamed_channel_is_absent_and_skipped() {
    let g = gpu();
    let all = channels(3);
    let dir = tempfile::tempdir().unwrap();
    let parts = stores(&all, dir.path());
    let camera = Camera::orbit(Vec3::ZERO, 2.3, 0.6, 0.35);
    let frame = VolumeFrame::centered(all[0].dims(), all[0].desc().spacing);
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let mut s3 = styles(3);
    s3[1] = s3[1].clone().visible(false);
    let s2 = vec![styles(3)[0].clone(), styles(3)[2].clone()];
    let mut hidden = streamed(source(&parts), &s3);
    let mut without = streamed(source(&[parts[0].clone(), parts[2].clone()]), &s2);
    let total = |v: &[u32]| v.iter().map(|&x| x as u64).sum::<u64>();
    for (mode, settings) in modes() {
        let desc = FrameDesc {
            settings,
            ..FrameDesc::new(camera, frame, SIZE, SIZE)
        };
        let h = settle(&mut hidden, &target, &desc);
        let w = settle(&mut without, &target, &desc);
        let c = compare(&h.color, &w.color, SIZE, SIZE);
        eprintln!(
            "streamed hidden {mode}: {:.1} dB against the two others",
            c.psnr_db
        );
        assert!(c.psnr_db >= 60.0, "hidden {mode}: {c:?}");
        let (sh, sw) = (total(&h.samples), total(&w.samples));
        eprintln!("{mode}: samples hidden {sh}, without {sw}");
        assert_eq!(
            sh, sw,
            "{mode}: a hidden channel is skipped as an absent one"
        );
        let off = FrameDesc {
            settings: RenderSettings {
                accel: brickray::core::Accel {
                    empty_space_skipping: false,
                    ..settings.accel
                },
                ..settings
            },
            ..desc.clone()
        };
        let ho = settle(&mut hidden, &target, &off);
        assert!(total(&ho.samples) > sh, "{mode}: skipping skipped nothing");
        let c = compare(&ho.color, &h.color, SIZE, SIZE);
        assert!(
            c.psnr_db >= 60.0,
            "{mode}: skipping changed the image: {c:?}"
        );
    }
}

/// Refinement classifies nodes by every visible channel's style: with one
/// channel made transparent the bricks only it shows are never read; its
/// styles change without a new store.
#[test]
fn refinement_follows_the_channels_styles() {
    let g = gpu();
    let all = channels(2);
    let camera = Camera::orbit(Vec3::ZERO, 2.3, 0.6, 0.35);
    let frame = VolumeFrame::centered(all[0].dims(), all[0].desc().spacing);
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    // The shell is below the window: only the blobs are visible.
    let narrow = |c: usize| ChannelStyle::window(COLORS[c], [0.3, 0.9], 0.6);
    let desc = FrameDesc::new(camera, frame, SIZE, SIZE);
    let reads = |styles: &[ChannelStyle]| {
        let dir = tempfile::tempdir().unwrap();
        let parts = stores(&all, dir.path());
        let mut r = streamed(source(&parts), styles);
        settle(&mut r, &target, &desc);
        parts[0].reads().len()
    };
    let both = reads(&[narrow(0), narrow(1)]);
    let one = reads(&[narrow(0), narrow(1).visible(false)]);
    eprintln!("bricks read: both channels shown {both}, one hidden {one}");
    assert!(
        one < both,
        "hiding a channel loaded the same bricks ({one})"
    );
    // The styles of a volume in use change its classification at the next
    // frame (no new store, no new source).
    let dir = tempfile::tempdir().unwrap();
    let parts = stores(&all, dir.path());
    let mut r = streamed(source(&parts), &[narrow(0), narrow(1).visible(false)]);
    let a = settle(&mut r, &target, &desc).color;
    r.set_channel_styles(&[narrow(0), narrow(1)]).unwrap();
    let b = settle(&mut r, &target, &desc).color;
    assert!(
        compare(&a, &b, SIZE, SIZE).psnr_db < 40.0,
        "showing the second channel changed nothing"
    );
    assert!(
        parts[0].reads().len() > one,
        "no brick of the second channel was loaded"
    );
}

#[test]
#[cfg_attr(
    no_shared_data,
    ignore = "needs ../shared/data (the shared volumes), absent when the tests were built"
)]
fn shared_nuclei_as_three_streamed_channels_match_the_reference() {
    let Some(vol) = brickray_harness::channels::nuclei_channels(3) else {
        assert!(
            std::env::var("CI").is_err(),
            "CI=true but the shared nuclei are missing"
        );
        return;
    };
    let vols = vol.channels().to_vec();
    let styles = brickray_harness::channels::nuclei_styles(3);
    let camera = Camera::orbit(Vec3::ZERO, 2.2, 0.7, 0.4);
    let worst = check("nuclei x3", vols, &styles, camera);
    eprintln!("streamed nuclei x3: worst {worst:.1} dB");
}

/// Slices and slabs of streamed channels (the point located in the cut,
/// sampled from its brick) against `render_channel_slice`, with a channel
/// hidden too: >= 45 dB.
#[test]
fn streamed_channel_slices_match_the_reference() {
    let g = gpu();
    let all = channels(3);
    let dir = tempfile::tempdir().unwrap();
    let parts = stores(&all, dir.path());
    let vol = ChannelVolume::new(all).unwrap();
    let mut r = streamed(source(&parts), &styles(3));
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    channel_support::check_channel_slices(
        "streamed channel slice",
        &mut r,
        &vol,
        &styles(3),
        SIZE,
        MIN_DB,
        200,
        |r, desc| settle(r, &target, desc).color,
    );
}

#[test]
fn streamed_channel_errors_are_typed() {
    let g = gpu();
    let dir = tempfile::tempdir().unwrap();
    let all = channels(2);
    let parts = stores(&all, dir.path());
    let frame = VolumeFrame::centered(all[0].dims(), all[0].desc().spacing);
    let camera = Camera::orbit(Vec3::ZERO, 2.3, 0.6, 0.35);
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let r = &mut streamed(source(&parts), &styles(2));
    // Styles for another count of channels.
    assert!(matches!(
        r.set_channel_styles(&styles(3)),
        Err(RenderError::Channels(ChannelError::StyleCount { .. }))
    ));
    let desc = FrameDesc::new(camera, frame, SIZE, SIZE);
    // No styles.
    let mut bare = VolumeRenderer::new(&g.device, target_desc()).unwrap();
    bare.set_volume_source(&g.device, &g.queue, source(&parts), config())
        .unwrap();
    assert!(matches!(
        brickray_harness::draw_frame(g, &mut bare, &target, &desc, None),
        Err(PrepareError::NoChannelStyles)
    ));
    // Sources on different octrees, a single-channel source and none.
    let other = CountingSource::store(brickray::core::synthetic::sphere(24), dir.path(), "s", 8);
    let e = ChannelSource::new(vec![parts[0].clone(), other]).unwrap_err();
    assert!(
        matches!(e, ChannelError::Mismatch { channel: 1, .. }),
        "{e:?}"
    );
    assert!(matches!(
        ChannelSource::new(Vec::new()),
        Err(ChannelError::Count { count: 0, .. })
    ));
}

/// The data leaves of the cut a planner converges to for one view (no GPU:
/// the planner alone), under `metric`, classifying by `tf` or `channels`.
fn converged_cut(
    src: Arc<dyn brickray::BrickSource>,
    metric: brickray::core::LodMetric,
    tf: &brickray::TransferFunction,
    channels: &[ChannelStyle],
) -> std::collections::BTreeSet<brickray::NodeKey> {
    use brickray::cache::{Classification, GpuFormat, StreamFrame, Streamer};
    let layout = src.layout().clone();
    let caps = brickray::core::TexelCaps {
        norm16: true,
        float32_filterable: false,
    };
    let gpu = GpuFormat::for_layout(&layout, caps, brickray::core::U8Filtering::Exact, 32, 2048);
    let config = OutOfCoreConfig {
        lod_metric: metric,
        tolerance_px: 1.0,
        upload_budget_bytes: 1 << 30,
        ..Default::default()
    };
    let mut s = Streamer::new(src, config, gpu).unwrap();
    s.preload_root().unwrap();
    let frame = VolumeFrame::centered(layout.volume.dims, layout.volume.spacing);
    let view =
        brickray::core::FrameView::new(Camera::orbit(Vec3::ZERO, 2.3, 0.6, 0.35), frame, [24, 24]);
    let mut leaves = std::collections::BTreeSet::new();
    for _ in 0..400 {
        let plan = s.plan(&StreamFrame {
            views: std::slice::from_ref(&view),
            classification: Classification {
                mode: brickray::RenderMode::Dvr,
                tf,
                channels,
                tf_generation: 1,
            },
            feedback: &[],
            time: None,
        });
        leaves = plan.leaves.iter().map(|&(_, k)| k).collect();
        // The cache's convergence: nothing pending (no feedback is given, so
        // `VisibleError` ranks by projected size x error and never waits for
        // weights that no ray caster measures).
        if plan.stats.cache.converged() {
            return leaves;
        }
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    panic!("the planner did not converge ({} leaves)", leaves.len());
}

/// Error-aware refinement of a channel volume weighs each visible channel's
/// recorded LOD error (from its own store) through that channel's transfer
/// function (faint wide windows, 24 px, budget 4: a regime where the errors
/// do not saturate): with channel 1 hidden the cut is that of channel 0
/// streamed alone; with both shown it refines at least where channel 0 alone
/// does, and further; and it is not the geometric rule's cut (the records
/// are used).
#[test]
fn error_aware_cuts_weigh_each_visible_channel() {
    let all = channels(2);
    let dir = tempfile::tempdir().unwrap();
    let parts = stores(&all, dir.path());
    let tf = brickray::TransferFunction::ramp(0.0, 1.0, 0.5);
    // Faint, wide windows: errors that do not saturate over a brick's depth.
    let s: Vec<ChannelStyle> = (0..2)
        .map(|c| ChannelStyle::window(COLORS[c], [0.0, 1.0], 0.01))
        .collect();
    let metric = brickray::core::LodMetric::VisibleError { budget: 4.0 };
    let hidden = [s[0].clone(), s[1].clone().visible(false)];
    let a = converged_cut(source(&parts), metric, &tf, &hidden);
    let alone = converged_cut(source(&parts[..1]), metric, &tf, &s[..1]);
    assert_eq!(a, alone, "channel 1 hidden: channel 0's own cut");
    let both = converged_cut(source(&parts), metric, &tf, &s);
    let covered = |fine: &std::collections::BTreeSet<brickray::NodeKey>,
                   coarse: &std::collections::BTreeSet<brickray::NodeKey>| {
        // Every leaf of `coarse` is in `fine` or an ancestor of some of its
        // leaves (`fine` refines at least as far).
        coarse.iter().all(|k| {
            fine.contains(k)
                || fine.iter().any(|f| {
                    let mut a = *f;
                    while a.level > k.level {
                        a = a.parent().expect("a parent above level 0");
                    }
                    f.level > k.level && a == *k
                })
        })
    };
    assert!(covered(&both, &a), "both channels refine less than one");
    assert_ne!(a, both, "the hidden channel's errors still refined the cut");
    let geometric = converged_cut(
        source(&parts),
        brickray::core::LodMetric::Geometric,
        &tf,
        &s,
    );
    let levels = |c: &std::collections::BTreeSet<brickray::NodeKey>| {
        let mut n = [0usize; 8];
        for k in c {
            n[k.level as usize] += 1;
        }
        n
    };
    eprintln!(
        "levels: hidden {:?}, both {:?}, geometric {:?}",
        levels(&a),
        levels(&both),
        levels(&geometric)
    );
    eprintln!(
        "error-aware cut: {} leaves with channel 1 hidden, {} with both; geometric {}",
        a.len(),
        both.len(),
        geometric.len()
    );
    assert_ne!(both, geometric, "the channels' error records were not used");
}
