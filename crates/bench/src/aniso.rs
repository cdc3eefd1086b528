//! LOD sweep on an anisotropic CT: the head CT resampled to 4.5 mm slices (every
//! third slice of 0.957 x 0.957 x 1.5 mm), stored as today's all-axes octree
//! ("before") and as an anisotropic pyramid ("after", `BuildOptions::anisotropic`
//! with the per-axis LOD metric). For each screen-space tolerance the cut is
//! refined with every brick available (one refinement from the root, no pool,
//! upload or request limits), the cut's bricks are resampled onto the finest
//! grid exactly as the out-of-core kernel samples them (trilinear inside each
//! leaf's stored brick, apron included), and the f64 CPU reference renders that
//! volume; PSNR is against the reference render of the finest data. GPU-free.
//! `--crop N` keeps the central N x N voxels of each slice (the spacing and
//! the slices unchanged): a quick look, or a smoke run.

use crate::Figures;
use crate::cut::{CutView, cut_volume};
use brickray_core::{
    Camera, LodMetric, OctreeLayout, RenderSettings, Volume, VolumeData, VolumeDesc, VolumeFrame,
};
use brickray_harness::ct;
use brickray_reference::{ReferenceOptions, psnr, render_reference};
use brickray_store::BuildOptions;

/// The shared head CT with every third slice kept (0.96 x 0.96 x 4.5 mm).
pub(crate) fn ct_every_third_slice() -> Result<Volume, String> {
    let path = brickray_harness::shared_volume("invesalius_cranium_ct")
        .ok_or("this suite needs ../shared/data/invesalius_cranium_ct")?;
    let full = brickray_io::read_volume(&path).map_err(|e| e.to_string())?;
    let d = full.desc().clone();
    let slice = d.dims[0] as usize * d.dims[1] as usize;
    let VolumeData::I16(all) = full.data() else {
        return Err("the head CT is not i16".into());
    };
    let nz = d.dims[2].div_ceil(3);
    let thick: Vec<i16> = (0..nz as usize)
        .flat_map(|z| all[3 * z * slice..(3 * z + 1) * slice].iter().copied())
        .collect();
    let desc = VolumeDesc {
        dims: [d.dims[0], d.dims[1], nz],
        spacing: [d.spacing[0], d.spacing[1], d.spacing[2] * 3.0],
        ..d
    };
    Volume::new(desc, VolumeData::I16(thick)).map_err(|e| e.to_string())
}

/// The central `side x side` voxels of each slice of an i16 volume (all of
/// a slice's axis where it is narrower).
fn crop_slices(vol: Volume, side: u32) -> Result<Volume, String> {
    let d = vol.desc().clone();
    let (w, h) = (side.min(d.dims[0]), side.min(d.dims[1]));
    if (w, h) == (d.dims[0], d.dims[1]) {
        return Ok(vol);
    }
    let VolumeData::I16(all) = vol.data() else {
        return Err("--crop: the volume is not i16".into());
    };
    let (x0, y0) = ((d.dims[0] - w) / 2, (d.dims[1] - h) / 2);
    let mut kept = Vec::with_capacity(w as usize * h as usize * d.dims[2] as usize);
    for z in 0..d.dims[2] as usize {
        for y in y0..y0 + h {
            let row = (z * d.dims[1] as usize + y as usize) * d.dims[0] as usize;
            kept.extend_from_slice(&all[row + x0 as usize..row + (x0 + w) as usize]);
        }
    }
    let desc = VolumeDesc {
        dims: [w, h, d.dims[2]],
        ..d
    };
    Volume::new(desc, VolumeData::I16(kept)).map_err(|e| e.to_string())
}

pub(crate) fn run(args: &[String]) -> Result<Figures, String> {
    let size: u32 = crate::arg(args, "--size", 160)?;
    let step: f32 = crate::arg(args, "--step", 0.5)?;
    let scene: String = crate::arg(args, "--scene", "dvr_translucent".to_string())?;
    // Brick budgets, largest first.
    let budgets: Vec<u32> = crate::arg(
        args,
        "--budgets",
        "78,75,72,69,66,63,60,57,54,51,48,45,42,39,36,33,30,27,24,21,18,15,12,9".to_string(),
    )?
    .split(',')
    .map(|t| {
        t.trim()
            .parse::<u32>()
            .map_err(|e| format!("--budgets: {e}"))
    })
    .collect::<Result<_, _>>()?;
    // An SVG chart of error against working set, when given a path.
    let chart: String = crate::arg(args, "--chart", String::new())?;
    let crop: u32 = crate::arg(args, "--crop", u32::MAX)?;
    if crop == 0 {
        return Err("--crop must be at least 1".into());
    }
    let mut curves: Vec<Curve> = Vec::new();
    let (_, mode, tf) = ct::scenes()
        .into_iter()
        .find(|(n, _, _)| *n == scene)
        .ok_or("--scene: one of dvr_translucent, dvr_opaque, iso, mip")?;
    let vol = crop_slices(ct_every_third_slice()?, crop)?;
    let desc = vol.desc().clone();
    let frame = VolumeFrame::centered(desc.dims, desc.spacing);
    let camera = Camera::orbit(frame.center(), 1.6, 0.6, 0.35);
    let settings = RenderSettings {
        mode,
        ..Default::default()
    };
    let opts = ReferenceOptions::new(size, size).with_step_factor(step);
    println!(
        "volume: head CT every third slice, {:?} i16 spacing {:?} mm; image {size}x{size}, \
         {scene}, reference step factor {step}",
        desc.dims, desc.spacing
    );
    let reference =
        render_reference(&vol, &frame, &tf, &camera, &settings, &opts).to_rgba8([0.0, 0.0, 0.0]);
    let tmp = tempfile::tempdir().map_err(|e| e.to_string())?;
    let mut fig = Figures::new();
    println!(
        "\n{:<7} {:>6} {:>8} {:>9} {:>10}  data leaves per level (root first)",
        "octree", "tol px", "bricks", "PSNR dB", "masks"
    );
    for (name, anisotropic) in [("before", false), ("after", true)] {
        let out = tmp.path().join(format!("{name}.brs"));
        let o = BuildOptions {
            anisotropic,
            ..BuildOptions::default()
        };
        let mut reader = brickray_io::MemoryReader::new(vol.clone(), "head_ct_4.5mm");
        brickray_store::build(&mut reader, &out, &o).map_err(|e| e.to_string())?;
        let store = brickray_store::open(&out).map_err(|e| e.to_string())?;
        let layout: &OctreeLayout = store.layout();
        let view = CutView {
            store: &store,
            tf: &tf,
            mode,
            camera: &camera,
            frame: &frame,
            size,
            visible: None,
        };
        let masks: String = layout
            .split_masks()
            .iter()
            .map(|m| format!("{m:o}"))
            .collect::<Vec<_>>()
            .join(",");
        let mut tol_curve = Vec::new();
        for tol in [0.5f32, 1.0, 1.41, 2.0, 2.83, 4.0, 5.66, 8.0] {
            let (cv, bricks, per_level) =
                cut_volume(&view, tol, u32::MAX / 2, LodMetric::Geometric)?;
            let img = render_reference(&cv, &frame, &tf, &camera, &settings, &opts)
                .to_rgba8([0.0, 0.0, 0.0]);
            let p = psnr(&img, &reference);
            println!("{name:<7} {tol:>6} {bricks:>8} {p:>9.2} {masks:>10}  {per_level:?}");
            tol_curve.push((bricks as f64, rmse_of(p)));
            let t = format!("{tol}").replace('.', "_");
            fig.insert(format!("{name}_bricks_at_{t}px"), bricks.into());
            fig.insert(
                format!("{name}_psnr_at_{t}px"),
                ((p * 100.0).round() / 100.0).into(),
            );
            if anisotropic && tol == 1.0 {
                fig.insert("anisotropic_ct_bricks_at_1px".into(), bricks.into());
            }
        }
        curves.push((format!("{name}, tolerance"), tol_curve));
        for (rule, metric) in [
            ("geometric", LodMetric::Geometric),
            ("error-aware", LodMetric::ErrorAware { budget: 0.0 }),
        ] {
            budget_sweep(&mut BudgetSweep {
                name,
                rule,
                metric,
                view: &view,
                settings: &settings,
                opts: &opts,
                reference: &reference,
                budgets: &budgets,
                fig: &mut fig,
                curves: &mut curves,
            })?;
        }
    }
    if !chart.is_empty() {
        write_chart(&chart, &curves)?;
        println!("chart: {chart}");
    }
    Ok(fig)
}

/// One layout's sweep of the brick budget.
struct BudgetSweep<'a> {
    name: &'a str,
    /// The refinement rule's name and metric (its threshold 0: only the
    /// budget stops refinement, the metric orders the splits).
    rule: &'a str,
    metric: LodMetric,
    view: &'a CutView<'a>,
    settings: &'a RenderSettings,
    opts: &'a ReferenceOptions<'a>,
    reference: &'a [u8],
    budgets: &'a [u32],
    fig: &'a mut Figures,
    /// Charted curves (name, (bricks, RMSE) points).
    curves: &'a mut Vec<Curve>,
}

/// A charted curve: its name and its (bricks, RMSE) points.
type Curve = (String, Vec<(f64, f64)>);

/// RMSE in 8-bit levels from PSNR (0 for identical images).
fn rmse_of(psnr_db: f64) -> f64 {
    255.0 / 10f64.powf(psnr_db / 20.0)
}

/// RMSE against working-set bricks, one line per curve (SVG).
fn write_chart(path: &str, curves: &[Curve]) -> Result<(), String> {
    use plotters::prelude::*;
    let root = SVGBackend::new(path, (760, 480)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let pts = || curves.iter().flat_map(|c| c.1.iter());
    let xmax = pts().map(|p| p.0).fold(1.0, f64::max);
    let ymax = pts().map(|p| p.1).fold(1.0, f64::max);
    let mut c = ChartBuilder::on(&root)
        .caption(
            "Head CT at 4.5 mm: image error against working set",
            ("sans-serif", 18),
        )
        .margin(10)
        .x_label_area_size(36)
        .y_label_area_size(52)
        .build_cartesian_2d(0.0..xmax * 1.05, 0.0..ymax * 1.08)
        .map_err(|e| e.to_string())?;
    c.configure_mesh()
        .x_desc("working-set bricks")
        .y_desc("RMSE against the finest level (8-bit levels)")
        .draw()
        .map_err(|e| e.to_string())?;
    let colors = [BLACK, RED, BLUE, GREEN, MAGENTA, CYAN];
    for (i, (name, points)) in curves.iter().enumerate() {
        let color = colors[i % colors.len()];
        let mut p = points.clone();
        p.sort_by(|a, b| a.0.total_cmp(&b.0));
        c.draw_series(LineSeries::new(p.iter().cloned(), color))
            .map_err(|e| e.to_string())?
            .label(name.as_str())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], color));
        c.draw_series(p.iter().map(|&q| Circle::new(q, 3, color.filled())))
            .map_err(|e| e.to_string())?;
    }
    c.configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(|e| e.to_string())?;
    root.present().map_err(|e| e.to_string())?;
    Ok(())
}

/// The cut under a brick budget (the GPU pool's capacity) at tolerance 0:
/// nodes split in priority order (largest projected voxel first) until the
/// next split would exceed the budget. Prints bricks, PSNR and RMSE (8-bit
/// levels) per budget, and the largest RMSE rise between neighbouring budgets
/// as a share of the sweep's whole range (1: everything in one step, a cliff).
fn budget_sweep(b: &mut BudgetSweep<'_>) -> Result<(), String> {
    println!(
        "\n{} octree, {} order: brick budget sweep (threshold 0)\n{:>7} {:>8} {:>9} {:>7}  data leaves per level",
        b.name, b.rule, "budget", "bricks", "PSNR dB", "RMSE"
    );
    let mut rmse = Vec::new();
    let mut points = Vec::new();
    for &n in b.budgets {
        let (cv, bricks, per_level) = cut_volume(b.view, 0.0, n, b.metric)?;
        let v = b.view;
        let img = render_reference(&cv, v.frame, v.tf, v.camera, b.settings, b.opts)
            .to_rgba8([0.0, 0.0, 0.0]);
        let p = psnr(&img, b.reference);
        let e = rmse_of(p);
        println!("{n:>7} {bricks:>8} {p:>9.2} {e:>7.2}  {per_level:?}");
        b.fig.insert(
            format!("{}_{}_rmse_at_budget_{n}", b.name, b.rule),
            ((e * 100.0).round() / 100.0).into(),
        );
        rmse.push(e);
        points.push((bricks as f64, e));
    }
    let range =
        rmse.iter().cloned().fold(0.0f64, f64::max) - rmse.iter().cloned().fold(f64::MAX, f64::min);
    let step = rmse
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .fold(0.0f64, f64::max);
    let share = if range > 0.0 { step / range } else { 0.0 };
    println!(
        "largest RMSE change between neighbouring budgets: {step:.2} of {range:.2} ({:.0}% of the range)",
        share * 100.0
    );
    b.fig.insert(
        format!("{}_{}_worst_budget_step_share", b.name, b.rule),
        ((share * 1000.0).round() / 1000.0).into(),
    );
    b.curves
        .push((format!("{}, budget, {} order", b.name, b.rule), points));
    Ok(())
}
