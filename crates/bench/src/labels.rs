//! The `labels` suite: what label maps cost and how far their coarse levels
//! stray (docs/labels.md).
//!
//! The two shared label maps (the Brodmann atlas, u8 181x217x181, and the
//! cells3d nuclei, u32 256x256x60), drawn through the default label table:
//!
//! * **cost**: ms per frame of the label map against the same ids drawn as an
//!   intensity volume (trilinear, the same table as its TF) in the same view,
//!   in core and out of core at the finest level, interleaved round by round
//!   (`--rounds`, 5) at `--size` px (256), median of `prepare + submit +
//!   wait`; samples per ray;
//! * **hidden labels**: three labels shown, the rest hidden: samples per ray
//!   and ms with empty-space skipping against without;
//! * **error**: against the CPU reference at its step (1/8 voxel) at 128 px,
//!   in core and out of core at the finest level; out of core at 1, 2 and 4
//!   px against the finest level, and the same ids as an averaged intensity
//!   store at 2 px.
//!
//! Smooth boundaries (`RenderSettings::smooth_labels`) are timed against
//! nearest samples in core, interleaved. **Overlays**: each map over the image
//! it segments (the Colin27 MRI, the nuclei fluorescence; colour mode) against
//! the image alone, in core and out of core at the finest level, interleaved;
//! the overlay's error against the reference's overlay at 128 px in core.
//!
//! `cargo run --release -p brickray-bench -- labels [--size PX] [--rounds N]`

use crate::report::{RunInfo, Timing};
use brickray_core::labels::{LabelTable, label_value_range};
use brickray_core::{
    BrickSource, Camera, LabelOverlay, LodMetric, OverlayStyle, RenderMode, RenderSettings,
    TransferFunction, Volume, VolumeDesc, VolumeFrame, VolumeKind, overlay_transform,
};
use brickray_harness::predict::{draw, draw_timed, samples_per_ray};
use brickray_harness::{GpuContext, GpuTimer, Offscreen, draw_frame, draw_until_settled};
use brickray_reference::{DEFAULT_STEP_FACTOR, ReferenceOptions, compare, render_reference};
use brickray_render::{FrameDesc, OutOfCoreConfig, VolumeRenderer};
use serde::Serialize;
use std::sync::Arc;

/// The error images' side.
const ERROR_SIZE: u32 = 128;

/// The suite's options.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Image side in pixels of the timed frames.
    #[arg(long, default_value_t = 256, value_parser = crate::image_side)]
    size: u32,
    /// Interleaved rounds.
    #[arg(long, default_value_t = 5, value_parser = crate::at_least_one::<usize>)]
    rounds: usize,
}

/// A cut of the label map's store under one LOD metric and budget.
#[derive(Debug, Serialize)]
pub(crate) struct LodRow {
    metric: &'static str,
    /// The metric's tolerance (px) or error budget.
    budget: f32,
    /// Against the finest level (128 px).
    psnr_db: f64,
    bricks: u64,
}

/// One label map.
#[derive(Debug, Serialize)]
pub(crate) struct MapRow {
    /// brodmann or nuclei.
    map: &'static str,
    /// Frame times of the labels and of the same ids drawn as intensity.
    labels_incore: Timing,
    intensity_incore: Timing,
    labels_ooc: Timing,
    intensity_ooc: Timing,
    /// Labels over intensity, in core and out of core.
    label_cost_ratio: f64,
    label_cost_ratio_ooc: f64,
    samples_per_ray: f64,
    /// Smooth boundaries over nearest.
    smooth_cost_ratio: f64,
    /// Samples with hidden labels skipped over without skipping.
    hidden_skip_sample_ratio: f64,
    /// Against the reference at the finest level (in core, out of core).
    psnr_incore_db: f64,
    psnr_ooc_finest_db: f64,
    /// Out of core at 1, 2 and 4 px against the finest level, and the ids
    /// drawn as averaged intensities at 2 px.
    psnr_1px_db: f64,
    psnr_2px_db: f64,
    psnr_4px_db: f64,
    psnr_averaged_2px_db: f64,
    lod: Vec<LodRow>,
    overlay: OverlayFigures,
}

/// The suite's JSON line.
#[derive(Debug, Serialize)]
pub(crate) struct LabelsResult {
    #[serde(flatten)]
    run: RunInfo,
    maps: Vec<MapRow>,
    psnr_finest_db_min: f64,
    psnr_2px_db_min: f64,
    label_cost_ratio_max: f64,
    label_cost_ratio_ooc_max: f64,
    hidden_skip_sample_ratio_max: f64,
    overlay_cost_ratio: f64,
    overlay_psnr_db_min: f64,
    smooth_cost_ratio: f64,
}

pub(crate) fn run(args: &Args) -> Result<LabelsResult, String> {
    let (size, rounds) = (args.size, args.rounds);
    let gpu = GpuContext::new().map_err(|e| e.to_string())?;
    println!("adapter: {}", gpu.describe());
    println!("timing at {size}x{size}, {rounds} interleaved rounds; errors at {ERROR_SIZE} px");
    let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
    let mut maps = Vec::new();
    let (mut finest_min, mut two_px_min, mut cost_max, mut ooc_cost_max) =
        (f64::INFINITY, f64::INFINITY, 0.0f64, 0.0f64);
    let mut skip_ratio_max = 0.0f64;
    let mut smooth_max = 0.0f64;
    let (mut overlay_max, mut overlay_db_min) = (0.0f64, f64::INFINITY);
    let mut overlay_rows = Vec::new();
    println!(
        "| map | labels / intensity ms (in core) | (out of core) | smooth / nearest | samples per ray | hidden: samples with / without skipping | finest dB (in core, ooc) | 1 / 2 / 4 px vs finest dB | averaged 2 px dB |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|");
    for (name, dirname, image_dir) in [
        ("brodmann", "mricron_brodmann_labels", "mricron_ch2_mri"),
        ("nuclei", "cells3d_nuclei_labels", "cells3d_nuclei_fluo"),
    ] {
        let path = brickray_harness::shared_data_dir()
            .ok_or("the labels suite needs ../shared/data (the shared label maps)")?
            .join("labels")
            .join(dirname)
            .join(format!("{dirname}.json"));
        let vol = brickray_io::read_volume(&path).map_err(|e| e.to_string())?;
        if !vol.desc().kind.is_labels() {
            return Err(format!("{}: not a label map", path.display()));
        }
        let intensity = as_intensity(&vol)?;
        let d = vol.desc();
        let frame = VolumeFrame::centered(d.dims, d.spacing);
        let camera = Camera::orbit(frame.center(), 2.2, 0.8, 0.45);
        let table = LabelTable::default();
        let tf = table.to_transfer_function();
        let settings = RenderSettings {
            mode: RenderMode::Dvr,
            ..Default::default()
        };
        let big = Offscreen::new(&gpu.device, size, size);
        let desc = FrameDesc {
            settings,
            ..FrameDesc::new(camera, frame, size, size)
        };

        // Cost, in core and out of core, interleaved.
        let mut incore = Vec::new();
        for v in [&vol, &intensity] {
            let mut r = renderer(&gpu, &tf)?;
            r.set_volume(&gpu.device, &gpu.queue, v)
                .map_err(|e| e.to_string())?;
            incore.push(r);
        }
        let (in_t, samples) = {
            let [a, b] = &mut incore[..] else {
                unreachable!()
            };
            timed(&gpu, &mut [(a, &desc), (b, &desc)], &big, rounds)?
        };
        // Smooth boundaries against nearest, the same renderer interleaved.
        let smooth_desc = FrameDesc {
            settings: RenderSettings {
                smooth_labels: true,
                ..settings
            },
            ..desc.clone()
        };
        let (smooth_t, _) = {
            let mut s = renderer(&gpu, &tf)?;
            s.set_volume(&gpu.device, &gpu.queue, &vol)
                .map_err(|e| e.to_string())?;
            let r = &mut incore[0];
            timed(
                &gpu,
                &mut [(r, &desc), (&mut s, &smooth_desc)],
                &big,
                rounds,
            )?
        };
        let smooth_cost = smooth_t[1].ms / smooth_t[0].ms;
        let mut ooc = Vec::new();
        for v in [&vol, &intensity] {
            let mut r = renderer(&gpu, &tf)?;
            r.set_volume_source(
                &gpu.device,
                &gpu.queue,
                store(v, dir.path(), name)?,
                finest(0.0),
            )
            .map_err(|e| e.to_string())?;
            draw_until_settled(&gpu, &mut r, &big, &desc, 300)
                .map_err(|e| e.to_string())?
                .ok_or("out of core did not settle")?;
            ooc.push(r);
        }
        let (ooc_t, _) = {
            let [a, b] = &mut ooc[..] else { unreachable!() };
            timed(&gpu, &mut [(a, &desc), (b, &desc)], &big, rounds)?
        };
        let in_ms: Vec<f64> = in_t.iter().map(|t| t.ms).collect();
        let ooc_ms: Vec<f64> = ooc_t.iter().map(|t| t.ms).collect();
        let cost = in_ms[0] / in_ms[1];
        let ooc_cost = ooc_ms[0] / ooc_ms[1];

        // Hidden labels: three shown.
        let present = brickray_core::labels::labels_present(&vol);
        let keep: Vec<u32> = present
            .iter()
            .copied()
            .filter(|&i| i != 0)
            .take(3)
            .collect();
        let mut hidden = table.clone();
        hidden.show_only(&keep);
        let r = &mut incore[0];
        r.set_transfer_function(&gpu.device, &gpu.queue, &hidden.to_transfer_function())
            .map_err(|e| e.to_string())?;
        let mut hidden_samples = Vec::new();
        for ess in [true, false] {
            let mut s = settings;
            s.accel.empty_space_skipping = ess;
            let desc = FrameDesc {
                settings: s,
                ..desc.clone()
            };
            let f = draw(&gpu, r, &big, &desc).map_err(|e| e.to_string())?;
            hidden_samples.push(samples_per_ray(&f.samples));
        }
        r.set_transfer_function(&gpu.device, &gpu.queue, &tf)
            .map_err(|e| e.to_string())?;
        let skip_ratio = hidden_samples[0] / hidden_samples[1].max(1e-9);

        // Error against the reference at its step, and coarse levels.
        let fine = RenderSettings {
            step_factor: DEFAULT_STEP_FACTOR,
            ..settings
        };
        let small = Offscreen::new(&gpu.device, ERROR_SIZE, ERROR_SIZE);
        let sdesc = FrameDesc {
            settings: fine,
            ..FrameDesc::new(camera, frame, ERROR_SIZE, ERROR_SIZE)
        };
        let reference = render_reference(
            &vol,
            &frame,
            &tf,
            &camera,
            &fine,
            &ReferenceOptions::new(ERROR_SIZE, ERROR_SIZE),
        )
        .to_rgba8([0.0; 3]);
        draw_frame(
            &gpu,
            &mut incore[0],
            &small,
            &sdesc,
            Some(wgpu::Color::BLACK),
        )
        .map_err(|e| e.to_string())?;
        let in_db = compare(&small.read_color(&gpu), &reference, ERROR_SIZE, ERROR_SIZE).psnr_db;
        let mut levels = Vec::new();
        let mut finest_img = Vec::new();
        for (v, tol) in [
            (&vol, 0.0f32),
            (&vol, 1.0),
            (&vol, 2.0),
            (&vol, 4.0),
            (&intensity, 2.0),
        ] {
            let mut r = renderer(&gpu, &tf)?;
            r.set_volume_source(
                &gpu.device,
                &gpu.queue,
                store(v, dir.path(), name)?,
                finest(tol),
            )
            .map_err(|e| e.to_string())?;
            draw_until_settled(&gpu, &mut r, &small, &sdesc, 300)
                .map_err(|e| e.to_string())?
                .ok_or("out of core did not settle")?;
            let img = small.read_color(&gpu);
            if finest_img.is_empty() {
                finest_img = img;
                levels.push(compare(&finest_img, &reference, ERROR_SIZE, ERROR_SIZE).psnr_db);
            } else {
                levels.push(compare(&img, &finest_img, ERROR_SIZE, ERROR_SIZE).psnr_db);
            }
        }
        println!(
            "| {name} | {cost:.3} ({:.1} / {:.1} ms) | {ooc_cost:.3} ({:.1} / {:.1} ms) | {smooth_cost:.3} | {:.1} / {:.1} | {:.1} / {:.1} | {in_db:.1}, {:.1} | {:.1} / {:.1} / {:.1} | {:.1} |",
            in_ms[0],
            in_ms[1],
            ooc_ms[0],
            ooc_ms[1],
            samples[0],
            samples[1],
            hidden_samples[0],
            hidden_samples[1],
            levels[0],
            levels[1],
            levels[2],
            levels[3],
            levels[4]
        );
        // The label error in the LOD metric: visible-error cuts (the share of
        // changed labels times their classified change, weighted by what the
        // image shows) against the geometric ones above, PSNR against the
        // label finest and bricks.
        let mut lod = Vec::new();
        for (metric, budget) in [
            ("geometric", 2.0f32),
            ("geometric-smooth", 2.0),
            ("geometric-smooth", 1.0),
            ("visible", 255.0),
            ("visible", 64.0),
            ("visible", 16.0),
        ] {
            let geometric = metric.starts_with("geometric");
            let mut config = finest(if geometric { budget } else { 1.0 });
            config.lod_metric = match metric {
                "visible" => LodMetric::VisibleError { budget },
                _ => LodMetric::Geometric,
            };
            let mut r = renderer(&gpu, &tf)?;
            r.set_volume_source(
                &gpu.device,
                &gpu.queue,
                store(&vol, dir.path(), name)?,
                config,
            )
            .map_err(|e| e.to_string())?;
            // Coarse levels drawn with smooth boundaries, against the
            // finest drawn nearest.
            let d = FrameDesc {
                settings: RenderSettings {
                    smooth_labels: metric == "geometric-smooth",
                    ..fine
                },
                ..sdesc.clone()
            };
            draw_until_settled(&gpu, &mut r, &small, &d, 300)
                .map_err(|e| e.to_string())?
                .ok_or("out of core did not settle")?;
            let db = compare(&small.read_color(&gpu), &finest_img, ERROR_SIZE, ERROR_SIZE).psnr_db;
            let bricks = r
                .stats()
                .out_of_core
                .map_or(0, |s| s.cache.working_set_bricks);
            println!("  {name} LOD {metric} {budget}: {db:.1} dB vs finest, {bricks} bricks");
            lod.push(LodRow {
                metric,
                budget,
                psnr_db: db,
                bricks: bricks as u64,
            });
        }
        finest_min = finest_min.min(in_db).min(levels[0]);
        two_px_min = two_px_min.min(levels[2]);
        cost_max = cost_max.max(cost);
        ooc_cost_max = ooc_cost_max.max(ooc_cost);
        skip_ratio_max = skip_ratio_max.max(skip_ratio);
        smooth_max = smooth_max.max(smooth_cost);
        let o = overlay(&gpu, &vol, image_dir, name, dir.path(), size, rounds)?;
        overlay_max = overlay_max.max(o.cost_incore).max(o.cost_ooc);
        overlay_db_min = overlay_db_min.min(o.psnr_db);
        overlay_rows.push(format!(
            "| {name} over {image_dir} | {:.3} ({:.1} / {:.1} ms) | {:.3} ({:.1} / {:.1} ms) | {:.1} |",
            o.cost_incore,
            o.incore[0].ms,
            o.incore[1].ms,
            o.cost_ooc,
            o.ooc[0].ms,
            o.ooc[1].ms,
            o.psnr_db
        ));
        maps.push(MapRow {
            map: name,
            labels_incore: in_t[0],
            intensity_incore: in_t[1],
            labels_ooc: ooc_t[0],
            intensity_ooc: ooc_t[1],
            label_cost_ratio: cost,
            label_cost_ratio_ooc: ooc_cost,
            samples_per_ray: samples[0],
            smooth_cost_ratio: smooth_cost,
            hidden_skip_sample_ratio: skip_ratio,
            psnr_incore_db: in_db,
            psnr_ooc_finest_db: levels[0],
            psnr_1px_db: levels[1],
            psnr_2px_db: levels[2],
            psnr_4px_db: levels[3],
            psnr_averaged_2px_db: levels[4],
            lod,
            overlay: o,
        });
    }
    println!();
    println!(
        "| overlay | with / without, in core | out of core (finest) | vs reference dB (in core, 128 px) |"
    );
    println!("|---|---:|---:|---:|");
    for row in &overlay_rows {
        println!("{row}");
    }
    Ok(LabelsResult {
        run: RunInfo::new(&gpu, size, rounds, "brodmann_labels,cells3d_nuclei_labels"),
        maps,
        psnr_finest_db_min: finest_min,
        psnr_2px_db_min: two_px_min,
        label_cost_ratio_max: cost_max,
        label_cost_ratio_ooc_max: ooc_cost_max,
        hidden_skip_sample_ratio_max: skip_ratio_max,
        overlay_cost_ratio: overlay_max,
        overlay_psnr_db_min: overlay_db_min,
        smooth_cost_ratio: smooth_max,
    })
}

/// What an overlay costs and how far it is from the reference's.
#[derive(Debug, Serialize)]
pub(crate) struct OverlayFigures {
    /// Frame times with / without the overlay, in core.
    incore: [Timing; 2],
    /// The same out of core at the finest level.
    ooc: [Timing; 2],
    /// With over without the overlay, in core and out of core.
    cost_incore: f64,
    cost_ooc: f64,
    /// In core against the reference's overlay at 128 px, at its step.
    psnr_db: f64,
}

/// The label map `labels` over the shared image `image_dir` (same grid).
fn overlay(
    gpu: &GpuContext,
    labels: &Volume,
    image_dir: &str,
    name: &str,
    dir: &std::path::Path,
    size: u32,
    rounds: usize,
) -> Result<OverlayFigures, String> {
    let path = brickray_harness::shared_data_dir()
        .ok_or("the labels suite needs ../shared/data")?
        .join(image_dir)
        .join(format!("{image_dir}.json"));
    let image = brickray_io::read_volume(&path).map_err(|e| e.to_string())?;
    let d = image.desc();
    let frame = VolumeFrame::centered(d.dims, d.spacing);
    let lframe = VolumeFrame::centered(labels.dims(), labels.desc().spacing);
    let table = LabelTable::default();
    let o = LabelOverlay {
        labels,
        image_to_labels: overlay_transform(&frame, &lframe),
        table: &table,
        style: OverlayStyle::default(),
    };
    // A soft-tissue ramp: the labels colour what it shows.
    let tf = TransferFunction::from_points(
        &[
            (0.15, [0.8, 0.8, 0.8, 0.0]),
            (0.35, [0.9, 0.9, 0.9, 0.05]),
            (0.7, [1.0, 1.0, 1.0, 0.3]),
        ],
        256,
    );
    let camera = Camera::orbit(frame.center(), 2.2, 0.8, 0.45);
    let settings = RenderSettings {
        mode: RenderMode::Dvr,
        ..Default::default()
    };
    let big = Offscreen::new(&gpu.device, size, size);
    let desc = FrameDesc {
        settings,
        ..FrameDesc::new(camera, frame, size, size)
    };
    let map = |e: brickray_render::RenderError| e.to_string();
    let mut incore = Vec::new();
    for with in [true, false] {
        let mut r = renderer(gpu, &tf)?;
        r.set_volume(&gpu.device, &gpu.queue, &image).map_err(map)?;
        if with {
            r.set_overlay(&gpu.device, &gpu.queue, Some(&o))
                .map_err(map)?;
        }
        incore.push(r);
    }
    let (t_in, _) = {
        let [a, b] = &mut incore[..] else {
            unreachable!()
        };
        timed(gpu, &mut [(a, &desc), (b, &desc)], &big, rounds)?
    };
    let source = store(&image, dir, &format!("{name}-image"))?;
    let mut ooc = Vec::new();
    for with in [true, false] {
        let mut r = renderer(gpu, &tf)?;
        r.set_volume_source(&gpu.device, &gpu.queue, source.clone(), finest(0.0))
            .map_err(map)?;
        if with {
            r.set_overlay(&gpu.device, &gpu.queue, Some(&o))
                .map_err(map)?;
        }
        draw_until_settled(gpu, &mut r, &big, &desc, 300)
            .map_err(|e| e.to_string())?
            .ok_or("out of core did not settle")?;
        ooc.push(r);
    }
    let (t_ooc, _) = {
        let [a, b] = &mut ooc[..] else { unreachable!() };
        timed(gpu, &mut [(a, &desc), (b, &desc)], &big, rounds)?
    };
    let fine = RenderSettings {
        step_factor: DEFAULT_STEP_FACTOR,
        ..settings
    };
    let small = Offscreen::new(&gpu.device, ERROR_SIZE, ERROR_SIZE);
    let sdesc = FrameDesc {
        settings: fine,
        ..FrameDesc::new(camera, frame, ERROR_SIZE, ERROR_SIZE)
    };
    let reference = render_reference(
        &image,
        &frame,
        &tf,
        &camera,
        &fine,
        &ReferenceOptions::new(ERROR_SIZE, ERROR_SIZE).with_overlay(&o),
    )
    .to_rgba8([0.0; 3]);
    draw_frame(
        gpu,
        &mut incore[0],
        &small,
        &sdesc,
        Some(wgpu::Color::BLACK),
    )
    .map_err(|e| e.to_string())?;
    let psnr_db = compare(&small.read_color(gpu), &reference, ERROR_SIZE, ERROR_SIZE).psnr_db;
    Ok(OverlayFigures {
        incore: [t_in[0], t_in[1]],
        ooc: [t_ooc[0], t_ooc[1]],
        cost_incore: t_in[0].ms / t_in[1].ms,
        cost_ooc: t_ooc[0].ms / t_ooc[1].ms,
        psnr_db,
    })
}

/// The same ids as an intensity volume over the label value range (what
/// brickray drew before it knew labels: trilinear, averaged levels).
fn as_intensity(vol: &Volume) -> Result<Volume, String> {
    let desc = VolumeDesc {
        kind: VolumeKind::Intensity,
        value_range: label_value_range(),
        ..vol.desc().clone()
    };
    Volume::new(desc, vol.data().clone()).map_err(|e| e.to_string())
}

fn renderer(gpu: &GpuContext, tf: &TransferFunction) -> Result<VolumeRenderer, String> {
    let mut r = VolumeRenderer::new(&gpu.device, brickray_harness::target_desc())
        .map_err(|e| e.to_string())?;
    r.set_transfer_function(&gpu.device, &gpu.queue, tf)
        .map_err(|e| e.to_string())?;
    Ok(r)
}

/// Out of core at `tolerance_px`, with room for every brick.
fn finest(tolerance_px: f32) -> OutOfCoreConfig {
    OutOfCoreConfig {
        tolerance_px,
        upload_budget_bytes: 1 << 30,
        ..Default::default()
    }
}

fn store(vol: &Volume, dir: &std::path::Path, name: &str) -> Result<Arc<dyn BrickSource>, String> {
    let path = dir.join(format!("{name}-{:?}.brs", vol.desc().kind));
    if !path.exists() {
        let mut reader = brickray_io::MemoryReader::new(vol.clone(), "memory");
        let options = brickray_store::BuildOptions {
            brick: 16,
            ..Default::default()
        };
        brickray_store::build(&mut reader, &path, &options).map_err(|e| e.to_string())?;
    }
    Ok(Arc::new(
        brickray_store::open(&path).map_err(|e| e.to_string())?,
    ))
}

/// Median ms per frame of each renderer, interleaved round by round (after a
/// warm-up round), and the samples per ray of each.
fn timed(
    gpu: &GpuContext,
    renderers: &mut [(&mut VolumeRenderer, &FrameDesc<'_>)],
    target: &Offscreen,
    rounds: usize,
) -> Result<(Vec<Timing>, Vec<f64>), String> {
    let n = renderers.len();
    let timer = GpuTimer::new(gpu);
    let mut times = vec![Vec::new(); n];
    let mut samples = vec![0.0; n];
    for round in 0..=rounds {
        for k in 0..n {
            let i = (k + round) % n;
            let (r, desc) = &mut renderers[i];
            let f = draw_timed(gpu, r, target, desc, timer.as_ref()).map_err(|e| e.to_string())?;
            if round > 0 {
                times[i].push((f.ms, f.gpu_ms));
            } else {
                samples[i] = samples_per_ray(&f.samples);
            }
        }
    }
    let timings = times.into_iter().map(Timing::of_times).collect();
    Ok((timings, samples))
}
