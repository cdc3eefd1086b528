//! Out-of-core MIP with and without empty-space skipping, interleaved, on
//! fractal noise, Marschner-Lobb and four shared volumes (256 x 256, 6 rounds, the median),
//! with each volume's `MacroCellGrid::mip_skip_share` over cells of 8 voxels
//! (the in-core grid, and the out-of-core sub-cells) and of 32 (one brick):
//! what an out-of-core rule for MIP's skipping would have to decide from
//! (docs/benchmarks.md, "skipping").
//!
//! `cargo run --release -p brickray-bench --example ooc_mip_probe` (needs
//! ../shared/data).

use brickray_core::{
    Accel, Camera, MacroCellGrid, RenderMode, RenderSettings, TransferFunction, VolumeFrame,
    synthetic,
};
use brickray_harness::{GpuContext, Offscreen, draw_frame, draw_until_settled};
use brickray_render::{FrameDesc, OutOfCoreConfig, Viewport, VolumeRenderer};

fn main() -> Result<(), String> {
    let gpu = GpuContext::new().map_err(|e| e.to_string())?;
    let size = 256;
    let target = Offscreen::new(&gpu.device, size, size);
    let shared = |n: &str| -> Result<brickray_core::Volume, String> {
        let path = brickray_harness::shared_volume(n).ok_or("needs ../shared/data")?;
        brickray_io::read_volume(path).map_err(|e| e.to_string())
    };
    let vols = vec![
        (
            "fractal noise 128^3",
            brickray_harness::scenes::pareto_noise(128),
        ),
        ("Marschner-Lobb 128^3", synthetic::marschner_lobb(128)),
        ("pycortex T1 MRI", shared("pycortex_s1_t1_mri")?),
        ("Colin27 MRI", shared("mricron_ch2_mri")?),
        ("head CT", shared("invesalius_cranium_ct")?),
        ("nuclei", shared("cells3d_nuclei_fluo")?),
    ];
    let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
    for (i, (name, vol)) in vols.into_iter().enumerate() {
        let d = vol.desc();
        let frame = VolumeFrame::centered(d.dims, d.spacing);
        let camera = Camera::orbit(frame.center(), 2.0, 0.5, 0.3);
        let src = brickray_harness::store_of(&vol, &dir.path().join(format!("{i}.brs")));
        let mut r = VolumeRenderer::new(&gpu.device, brickray_harness::target_desc())
            .map_err(|e| e.to_string())?;
        let config = OutOfCoreConfig {
            tolerance_px: 0.0,
            upload_budget_bytes: 1 << 30,
            ..Default::default()
        };
        r.set_volume_source(&gpu.device, &gpu.queue, src, config)
            .map_err(|e| e.to_string())?;
        r.set_transfer_function(
            &gpu.device,
            &gpu.queue,
            &TransferFunction::ramp(0.0, 1.0, 1.0),
        )
        .map_err(|e| e.to_string())?;
        let desc = |ess: bool| FrameDesc {
            camera,
            frame,
            viewport: Viewport::full(size, size),
            settings: RenderSettings {
                mode: RenderMode::Mip,
                accel: Accel {
                    early_termination: Some(0.99),
                    empty_space_skipping: ess,
                },
                ..Default::default()
            },
            host_depth: None,
            time: None,
        };
        draw_until_settled(&gpu, &mut r, &target, &desc(true), 100).map_err(|e| e.to_string())?;
        let mut ms = [Vec::new(), Vec::new()];
        for round in 0..7 {
            for k in 0..2 {
                let ess = (k + round) % 2 == 0;
                let t0 = std::time::Instant::now();
                draw_frame(&gpu, &mut r, &target, &desc(ess), Some(wgpu::Color::BLACK))
                    .map_err(|e| e.to_string())?;
                // The first round warms both up.
                if round > 0 {
                    ms[usize::from(ess)].push(t0.elapsed().as_secs_f64() * 1e3);
                }
            }
        }
        for v in &mut ms {
            v.sort_by(f64::total_cmp);
        }
        let share = |cell| MacroCellGrid::build(&vol, cell).mip_skip_share();
        println!(
            "{name:<20} share (8) {:.3}, (32) {:.3}: out-of-core MIP without skipping {:.1} ms, with {:.1} ms ({:.2}x)",
            share(8),
            share(32),
            ms[0][3],
            ms[1][3],
            ms[1][3] / ms[0][3]
        );
    }
    Ok(())
}
