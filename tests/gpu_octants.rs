//! Octant-granular cuts on the GPU (`LodMetric::VisibleOctants`, lavapipe):
//! a leaf drawn from its parent's brick is drawn as the parent draws it, and
//! the cut keeps its brick budget.

use brickray::core::LodMetric;
use brickray::{
    Camera, FrameDesc, OutOfCoreConfig, OutOfCoreStats, RenderSettings, TransferFunction,
    VolumeFrame, VolumeRenderer,
};
use brickray_harness::{
    Offscreen, draw_frame, shared_gpu as gpu, store_of, target_desc as targets,
};
use brickray_reference::psnr;
use std::sync::Arc;

const SIZE: u32 = 96;
const DIM: u64 = 128;

fn world() -> VolumeFrame {
    VolumeFrame::centered([DIM as u32; 3], [1.0; 3])
}

fn shells(dir: &tempfile::TempDir) -> Arc<dyn brickray::BrickSource> {
    let p = brickray::store::ProceduralSource::sphere_shells([DIM; 3], 16, 2).unwrap();
    let layout = brickray::BrickSource::layout(&p).clone();
    let data = p.region(layout.levels - 1, [0; 3], [DIM - 1; 3]).unwrap();
    let vol = brickray::Volume::new(layout.volume, brickray::core::VolumeData::U8(data)).unwrap();
    store_of(&vol, &dir.path().join("shells.brs"))
}

fn tf() -> TransferFunction {
    TransferFunction::from_points(
        &[
            (0.15, [0.9, 0.8, 0.7, 0.0]),
            (0.22, [0.9, 0.8, 0.7, 0.08]),
            (0.5, [0.9, 0.3, 0.2, 0.4]),
        ],
        256,
    )
}

/// A renderer of `source` under `metric` and a brick budget.
fn renderer(
    source: Arc<dyn brickray::BrickSource>,
    metric: LodMetric,
    bricks: Option<u32>,
) -> VolumeRenderer {
    let g = gpu();
    let mut r = VolumeRenderer::new(&g.device, targets()).unwrap();
    let config = OutOfCoreConfig {
        tolerance_px: 0.0,
        lod_metric: metric,
        brick_budget: bricks,
        upload_budget_bytes: 1 << 30,
        ..Default::default()
    };
    r.set_volume_source(&g.device, &g.queue, source, config)
        .unwrap();
    r.set_transfer_function(&g.device, &g.queue, &tf()).unwrap();
    r
}

/// The converged image and stats of `metric` under a brick budget.
fn converged(
    source: Arc<dyn brickray::BrickSource>,
    metric: LodMetric,
    bricks: Option<u32>,
) -> (Vec<u8>, OutOfCoreStats) {
    converged_in(source, metric, bricks, RenderSettings::default())
}

fn converged_in(
    source: Arc<dyn brickray::BrickSource>,
    metric: LodMetric,
    bricks: Option<u32>,
    settings: RenderSettings,
) -> (Vec<u8>, OutOfCoreStats) {
    let g = gpu();
    let mut r = renderer(source, metric, bricks);
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let desc = FrameDesc {
        camera: Camera::orbit(world().center(), 1.7, 0.6, 0.35),
        frame: world(),
        viewport: brickray::Viewport::full(SIZE, SIZE),
        settings,
        host_depth: None,
        time: None,
    };
    let mut since = None;
    for f in 1..=300u64 {
        draw_frame(g, &mut r, &target, &desc, Some(wgpu::Color::BLACK)).expect("frame");
        let s = r.stats().out_of_core.unwrap();
        since = if s.converged { since.or(Some(f)) } else { None };
        if since.is_some_and(|c| f >= c + 4 && r.last_usage().is_some_and(|u| u.frame >= c)) {
            return (target.read_color(g), s);
        }
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    panic!("not converged: {:?}", r.stats().out_of_core);
}

/// With one brick, the octant cut is the root's children, all drawn from
/// the root's brick: the image must be the root's own (the same brick,
/// mapping, step and sample grid; only the leaves' boundaries differ).
/// Threshold 55 dB (measured: see the run's output).
#[test]
fn borrowed_octants_draw_as_their_parent() {
    let dir = tempfile::tempdir().unwrap();
    let s = shells(&dir);
    let (root, rs) = converged(s.clone(), LodMetric::VisibleError { budget: 0.0 }, Some(1));
    let (oct, os) = converged(s, LodMetric::VisibleOctants { budget: 0.0 }, Some(1));
    assert_eq!(rs.cache.working_set_bricks, 1);
    assert_eq!(os.cache.working_set_bricks, 1);
    assert_eq!(rs.data_leaves_per_level[0], 1);
    assert_eq!(os.data_leaves_per_level[0], 0);
    assert!(
        os.data_leaves_per_level[1] >= 2,
        "{:?}",
        os.data_leaves_per_level
    );
    let p = psnr(&root, &oct);
    eprintln!("root alone against its octants: {p:.1} dB");
    assert!(p >= 55.0, "{p:.1} dB");
}

/// Under a brick budget, the octant cut keeps it, draws some octants from
/// their parents, and against the finest cut does at least as well as the
/// per-node cut of the same budget (margin and figures: the run's output).
#[test]
fn octant_cuts_keep_the_budget_and_track_the_finest_cut() {
    let dir = tempfile::tempdir().unwrap();
    let s = shells(&dir);
    let (finest, fs) = converged(s.clone(), LodMetric::VisibleError { budget: 0.0 }, None);
    let budget = (fs.cache.working_set_bricks / 4).max(2);
    let (node, ns) = converged(
        s.clone(),
        LodMetric::VisibleError { budget: 0.0 },
        Some(budget),
    );
    let (oct, os) = converged(s, LodMetric::VisibleOctants { budget: 0.0 }, Some(budget));
    let (pn, po) = (psnr(&finest, &node), psnr(&finest, &oct));
    eprintln!(
        "finest {} bricks; budget {budget}: per node {} bricks {pn:.1} dB, octants {} bricks {po:.1} dB",
        fs.cache.working_set_bricks, ns.cache.working_set_bricks, os.cache.working_set_bricks
    );
    assert!(os.cache.working_set_bricks <= budget);
    assert!(po >= pn, "octants {po:.1} dB, per node {pn:.1} dB");
}

/// Octant cuts settle in every mode under a brick budget (a cut that never
/// converges keeps loading and redrawing).
#[test]
fn octant_cuts_converge_in_every_mode() {
    let dir = tempfile::tempdir().unwrap();
    let s = shells(&dir);
    for mode in [
        brickray::RenderMode::Mip,
        brickray::RenderMode::Iso {
            value: 0.3,
            color: [0.9, 0.8, 0.7],
        },
    ] {
        let settings = RenderSettings {
            mode,
            ..RenderSettings::default()
        };
        let (_, st) = converged_in(
            s.clone(),
            LodMetric::VisibleOctants { budget: 0.0 },
            Some(20),
            settings,
        );
        assert!(st.cache.working_set_bricks <= 20);
    }
}

/// Switching to octant cuts at run time grows the renderer's slot table and
/// usage counters (the other metrics allocate no borrowed rows): the cut then
/// settles as a renderer created with the metric does, with the same image.
#[test]
fn switching_to_octant_cuts_at_run_time() {
    let dir = tempfile::tempdir().unwrap();
    let s = shells(&dir);
    let (fresh, fs) = converged(
        s.clone(),
        LodMetric::VisibleOctants { budget: 0.0 },
        Some(14),
    );
    let g = gpu();
    let mut r = renderer(s, LodMetric::VisibleError { budget: 0.0 }, Some(14));
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let desc = FrameDesc {
        camera: Camera::orbit(world().center(), 1.7, 0.6, 0.35),
        frame: world(),
        viewport: brickray::Viewport::full(SIZE, SIZE),
        settings: RenderSettings::default(),
        host_depth: None,
        time: None,
    };
    for _ in 0..20 {
        draw_frame(g, &mut r, &target, &desc, Some(wgpu::Color::BLACK)).expect("frame");
    }
    brickray_harness::configure(gpu(), &r, |c| {
        c.lod_metric = LodMetric::VisibleOctants { budget: 0.0 }
    })
    .unwrap();
    let mut done = None;
    for f in 1..=300u64 {
        draw_frame(g, &mut r, &target, &desc, Some(wgpu::Color::BLACK)).expect("frame");
        let st = r.stats().out_of_core.unwrap();
        if st.converged && f > 10 {
            done = Some(st);
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    let st = done.expect("converged after the switch");
    assert_eq!(st.cache.working_set_bricks, fs.cache.working_set_bricks);
    let p = psnr(&fresh, &target.read_color(g));
    eprintln!("switched against fresh: {p:.1} dB");
    assert!(p >= 40.0, "{p:.1} dB");
}
