//! Per-frame timing of a streamed volume's first frames: `prepare`, submit,
//! the wait for the GPU and the ray-cast pass by GPU timestamps, with the
//! bricks each frame uploads (`docs/studies/remote-streaming.md`, "Ray-cast
//! frames and fades"). On lavapipe the pass reads about 0 ms on the frames
//! that upload bricks while the wait says otherwise.
//!
//! `cargo run --release -p brickray-bench --example frame_split` (needs
//! `../shared/data`; the MRI as a store, 256 px, local disk).

use brickray_core::tf::{TfModel, TfPreset};
use brickray_core::{BrickSource, Camera, RenderSettings, VolumeFrame};
use brickray_harness::{GpuContext, GpuTimer, Offscreen};
use brickray_render::{FrameDesc, OutOfCoreConfig, VolumeRenderer};
use std::sync::Arc;
use std::time::{Duration, Instant};

fn main() -> Result<(), String> {
    let raw = brickray_harness::shared_volume(brickray_harness::stand_in::SHARED_MRI)
        .ok_or("needs ../shared/data")?;
    let vol = brickray_io::read_volume(&raw).map_err(|e| e.to_string())?;
    let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
    let path = dir.path().join("mri.brs");
    let mut reader = brickray_io::MemoryReader::new(vol, "memory");
    brickray_store::build(&mut reader, &path, &Default::default()).map_err(|e| e.to_string())?;
    let source: Arc<dyn BrickSource> =
        Arc::new(brickray_store::open(&path).map_err(|e| e.to_string())?);
    let gpu = GpuContext::new().map_err(|e| e.to_string())?;
    println!("adapter: {}", gpu.describe());
    let d = source.layout().volume.clone();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let tf = TfModel::preset(TfPreset::Mri, d.value_range)
        .to_table(256)
        .map_err(|e| e.to_string())?;
    let settings = RenderSettings::default();
    let mut r = VolumeRenderer::new(&gpu.device, brickray_harness::target_desc())
        .map_err(|e| e.to_string())?;
    r.set_volume_source(&gpu.device, &gpu.queue, source, OutOfCoreConfig::default())
        .map_err(|e| e.to_string())?;
    r.set_transfer_function(&gpu.device, &gpu.queue, &tf)
        .map_err(|e| e.to_string())?;
    r.warm_up(&gpu.device, &[settings])
        .map_err(|e| e.to_string())?;
    let size = 256;
    let target = Offscreen::new(&gpu.device, size, size);
    let timer = GpuTimer::new(&gpu).ok_or("the device has no timestamp queries")?;
    r.set_pass_timestamps(&gpu.device, Some(timer.writes()))
        .map_err(|e| e.to_string())?;
    let camera = Camera::orbit(frame.center(), 2.0, 0.5, 0.3);
    let desc = FrameDesc {
        settings,
        ..FrameDesc::new(camera, frame, size, size)
    };
    println!(
        "frame | prepare ms | submit ms | wait ms | pass ms (timestamps) | bricks uploaded | working set"
    );
    for i in 0..8 {
        let t0 = Instant::now();
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        r.prepare(&gpu.device, &gpu.queue, &mut enc, &desc)
            .map_err(|e| e.to_string())?;
        let prepare = t0.elapsed().as_secs_f64() * 1e3;
        {
            let mut pass = target.pass(&mut enc, true);
            r.render(&mut pass).map_err(|e| e.to_string())?;
        }
        timer.resolve(&mut enc);
        let t1 = Instant::now();
        gpu.queue.submit([enc.finish()]);
        let submit = t1.elapsed().as_secs_f64() * 1e3;
        let t2 = Instant::now();
        let _ = gpu.device.poll(wgpu::PollType::wait_indefinitely());
        let wait = t2.elapsed().as_secs_f64() * 1e3;
        let pass = timer.read_ms(&gpu).unwrap_or(f64::NAN);
        let s = r.stats().out_of_core.ok_or("not out of core")?;
        println!(
            "{i} | {prepare:.1} | {submit:.1} | {wait:.1} | {pass:.2} | {} | {}",
            s.cache.upload_bricks, s.cache.working_set_bricks
        );
        std::thread::sleep(Duration::from_millis(16));
    }
    Ok(())
}
