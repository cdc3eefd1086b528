//! Helpers of the stability regression tests (`tests/gpu_stability.rs`,
//! `tests/gpu_stability_geometry.rs`): small volumes with a CPU twin for the
//! reference, renderers, frames and image measures.
#![allow(dead_code, unused_imports)]

pub(crate) use brickray::store::ProceduralSource;
pub(crate) use brickray::{
    Accel, BrickSource, Camera, ClipBox, DepthConvention, FrameDesc, OutOfCoreConfig,
    OutOfCoreStats, Projection, RenderMode, RenderSettings, TransferFunction, Volume, VolumeFrame,
    VolumeRenderer,
};
pub(crate) use brickray_harness::scenes::ortho;
pub(crate) use brickray_harness::{Offscreen, shared_gpu as gpu, target_desc as targets};
pub(crate) use brickray_reference::{ReferenceOptions, max_abs_diff, psnr, render_reference};
pub(crate) use glam::Vec3;
pub(crate) use std::sync::Arc;
pub(crate) use std::time::Duration;

pub(crate) const SIZE: u32 = 64;
pub(crate) const DIM: u64 = 64;

pub(crate) fn noise(dims: u64, brick: u32) -> (Volume, Arc<ProceduralSource>) {
    let src = ProceduralSource::fractal_noise([dims; 3], brick, 2).unwrap();
    let vol = region(&src, [0; 3], dims);
    (vol, Arc::new(src))
}

pub(crate) fn region(src: &ProceduralSource, lo: [u64; 3], n: u64) -> Volume {
    let finest = src.layout().levels - 1;
    let data = src.region(finest, lo, lo.map(|c| c + n - 1)).unwrap();
    u8_volume(n as u32, data)
}

pub(crate) fn u8_volume(n: u32, data: Vec<u8>) -> Volume {
    brickray_harness::scenes::u8_volume([n; 3], data).unwrap()
}

pub(crate) fn noise_tf() -> TransferFunction {
    TransferFunction::from_points(
        &[(0.45, [0.2, 0.5, 1.0, 0.0]), (0.7, [1.0, 0.8, 0.5, 0.3])],
        256,
    )
}

pub(crate) fn frame_of(n: u64) -> VolumeFrame {
    VolumeFrame::centered([n as u32; 3], [1.0; 3])
}

pub(crate) fn reference(
    vol: &Volume,
    frame: &VolumeFrame,
    tf: &TransferFunction,
    cam: &Camera,
    st: &RenderSettings,
    step: f32,
) -> Vec<u8> {
    let opts = ReferenceOptions::new(SIZE, SIZE).with_step_factor(step);
    render_reference(vol, frame, tf, cam, st, &opts).to_rgba8([0.0; 3])
}

pub(crate) fn draw(
    r: &mut VolumeRenderer,
    cam: Camera,
    frame: VolumeFrame,
    st: RenderSettings,
) -> Vec<u8> {
    let g = gpu();
    let target = Offscreen::new(&g.device, SIZE, SIZE);
    let desc = FrameDesc {
        camera: cam,
        frame,
        viewport: brickray::Viewport::full(SIZE, SIZE),
        settings: st,
        host_depth: None,
        time: None,
    };
    brickray_harness::draw_frame(g, r, &target, &desc, Some(brickray::wgpu::Color::BLACK))
        .expect("frame");
    target.read_color(g)
}

pub(crate) fn converge(
    r: &mut VolumeRenderer,
    cam: Camera,
    frame: VolumeFrame,
    st: RenderSettings,
) -> (Vec<u8>, OutOfCoreStats) {
    for _ in 0..150 {
        let img = draw(r, cam, frame, st);
        let s = r.stats().out_of_core.unwrap();
        if s.converged {
            return (img, s);
        }
        std::thread::sleep(Duration::from_millis(3));
    }
    panic!("not converged: {:?}", r.stats().out_of_core);
}

pub(crate) fn incore(vol: &Volume, tf: &TransferFunction) -> VolumeRenderer {
    let g = gpu();
    let mut r = VolumeRenderer::new(&g.device, targets()).unwrap();
    r.set_volume(&g.device, &g.queue, vol).unwrap();
    r.set_transfer_function(&g.device, &g.queue, tf).unwrap();
    r
}

pub(crate) fn ooc(
    source: Arc<dyn BrickSource>,
    config: OutOfCoreConfig,
    tf: &TransferFunction,
) -> VolumeRenderer {
    let g = gpu();
    let mut r = VolumeRenderer::new(&g.device, targets()).unwrap();
    r.set_volume_source(&g.device, &g.queue, source, config)
        .unwrap();
    r.set_transfer_function(&g.device, &g.queue, tf).unwrap();
    r
}

/// As [`ooc`], with a streamed volume that never keeps gradients: its slots
/// are the size a pool under pressure has (one that does not hold every
/// brick keeps none by default), whatever the budget.
pub(crate) fn ooc_without_gradients(
    source: Arc<dyn BrickSource>,
    config: OutOfCoreConfig,
    tf: &TransferFunction,
) -> VolumeRenderer {
    let g = gpu();
    let options = brickray::VolumeOptions {
        gradients: brickray::KeepGradients::Never,
        ..Default::default()
    };
    let v = brickray::StreamedVolume::new(&g.device, &g.queue, source, config, options).unwrap();
    let mut r = VolumeRenderer::new(&g.device, targets()).unwrap();
    r.set_streamed_volume(&g.device, &v).unwrap();
    r.set_transfer_function(&g.device, &g.queue, tf).unwrap();
    r
}

pub(crate) fn peak(p: &[u8]) -> u8 {
    p[0].max(p[1]).max(p[2])
}

pub(crate) fn holes(img: &[u8], reference: &[u8]) -> usize {
    img.chunks_exact(4)
        .zip(reference.chunks_exact(4))
        .filter(|(a, b)| peak(b) >= 24 && peak(a) <= 2)
        .count()
}

pub(crate) fn mean_abs_diff(a: &[u8], b: &[u8]) -> f64 {
    let s: u64 = a
        .chunks_exact(4)
        .zip(b.chunks_exact(4))
        .map(|(p, q)| (0..3).map(|c| p[c].abs_diff(q[c]) as u64).sum::<u64>())
        .sum();
    s as f64 / (3 * a.len() / 4) as f64
}
