//! Part (c) of the `ooc` suite: a scripted camera path with streaming.

use super::*;

/// (c) A scripted camera path with streaming.
/// Knobs of part (c).
#[derive(Debug, Clone, Copy)]
pub(super) struct PathOptions {
    pub(super) size: u32,
    pub(super) dims: u64,
    /// Frames the close-up is held after the jump.
    pub(super) hold: usize,
    /// GPU pool budget.
    pub(super) gpu_mib: u64,
}

/// (c) The path with one kind of texels.
#[derive(Debug, Serialize)]
pub(crate) struct PathResult {
    /// exact or fast (8-bit texels).
    u8_filtering: &'static str,
    median_ms: f64,
    p99_ms: f64,
    pub(super) p99_over_median: f64,
    /// Frames until converged after the jump (null: not within the hold).
    pub(super) frames_to_converge_after_jump: Option<usize>,
}

pub(super) fn part_c(
    gpu: &GpuContext,
    path: PathOptions,
    u8_filtering: U8Filtering,
) -> Result<PathResult, String> {
    let PathOptions {
        size, dims, hold, ..
    } = path;
    const ORBIT: usize = 15;
    const MOVE: usize = 15;
    println!(
        "\n(c) camera path over {dims}^3 fractal noise at {size}x{size}: GPU {} MiB, upload 16 MiB/frame, tolerance 1 px,\n  TF opacity per world length of the {PATH_TF_REFERENCE_DIMS}^3 voxel",
        path.gpu_mib
    );
    println!(
        "  {ORBIT} frames slow orbit, jump to a close-up held {hold} frames, {MOVE} frames slow motion"
    );
    let source = noise_source(dims)?;
    let frame = VolumeFrame::centered([dims as u32; 3], [1.0; 3]);
    let options = RendererOptions {
        u8_filtering,
        ..Default::default()
    };
    println!("  u8 texels: {u8_filtering:?}");
    let mut renderer =
        VolumeRenderer::with_options(&gpu.device, targets(), options).map_err(|e| e.to_string())?;
    renderer
        .set_volume_source(
            &gpu.device,
            &gpu.queue,
            source,
            OutOfCoreConfig {
                gpu_budget_bytes: path.gpu_mib << 20,
                ..Default::default()
            },
        )
        .map_err(|e| e.to_string())?;
    renderer
        .set_transfer_function(
            &gpu.device,
            &gpu.queue,
            &noise_tf_world(dims, PATH_TF_REFERENCE_DIMS),
        )
        .expect("transfer function");
    let settings = RenderSettings::default();
    let run = Runner::new(gpu, size)?;
    let c = frame.center();
    // Warm start: the first view converged (not timed as part of the path).
    let start = Camera::orbit(c, 2.0, 0.5, 0.3);
    let (warm, _) = run.converge(&mut renderer, start, frame, settings, 600)?;
    println!(
        "  start view converged in {} frames",
        warm.map_or("(not)".to_string(), |f| f.to_string())
    );
    // A close-up of a region near the back face, seen from outside the box.
    let close_target = c + Vec3::new(-0.25, 0.2, -0.35);
    let mut cams = Vec::new();
    for i in 0..ORBIT {
        cams.push(Camera::orbit(c, 2.0, 0.5 + 0.01 * i as f32, 0.3));
    }
    for _ in 0..hold {
        cams.push(Camera::orbit(close_target, 0.4, 3.3, -0.2));
    }
    for i in 0..MOVE {
        cams.push(Camera::orbit(
            close_target,
            0.4,
            3.3 + 0.005 * (i + 1) as f32,
            -0.2,
        ));
    }
    let mut times = Vec::new();
    let mut after_jump = None;
    let mut max_uploaded = 0u64;
    let mut max_refine = 0.0f64;
    let mut worst = (0.0f64, 0usize);
    for (i, cam) in cams.iter().enumerate() {
        let shot = run.frame(&mut renderer, *cam, frame, settings, false)?;
        let s = renderer.stats().out_of_core.ok_or("not out of core")?;
        times.push(shot.ms);
        max_uploaded = max_uploaded.max(s.cache.upload_bytes);
        max_refine = max_refine.max(s.refine_ms);
        if shot.ms > worst.0 {
            worst = (shot.ms, i);
        }
        let first_converged =
            after_jump.is_none() && (ORBIT..ORBIT + hold).contains(&i) && s.converged;
        if first_converged {
            after_jump = Some(i - ORBIT + 1);
        }
        if i % 10 == 0 || i == ORBIT || first_converged {
            println!(
                "  frame {i:>3}: {:>7.1} ms, bricks {:>5}, uploaded {:>5.1} MiB, in flight {:>4}, refine {:>5.2} ms{}",
                shot.ms,
                s.cache.working_set_bricks,
                s.cache.upload_bytes as f64 / (1 << 20) as f64,
                s.cache.requests_in_flight,
                s.refine_ms,
                if s.converged { ", converged" } else { "" }
            );
        }
    }
    let med = median(&times);
    let p99 = quantile(&times, 0.99);
    println!(
        "  frames {}: median {med:.1} ms, p99 {p99:.1} ms, p99/median {:.2}, worst frame {} ({:.1} ms); max upload {:.1} MiB/frame, max refine {max_refine:.2} ms",
        times.len(),
        p99 / med,
        worst.1,
        worst.0,
        max_uploaded as f64 / (1 << 20) as f64
    );
    match after_jump {
        Some(f) => println!("  converged {f} frames after the jump"),
        None => println!("  NOT converged within the {hold} frames held after the jump"),
    }
    Ok(PathResult {
        u8_filtering: match u8_filtering {
            U8Filtering::Exact => "exact",
            _ => "fast",
        },
        median_ms: round2(med),
        p99_ms: round2(p99),
        p99_over_median: round2(p99 / med),
        frames_to_converge_after_jump: after_jump,
    })
}
