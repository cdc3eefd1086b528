//! The Pareto suite's charts: time per frame against PSNR for one volume and
//! mode, each knob's sweep in its colour, the front as a line, the default
//! marked (SVG); and the level-of-detail sweeps' PSNR against their working
//! set (data bricks).

use plotters::prelude::*;

/// One point of a chart.
pub(crate) struct ChartPoint<'a> {
    /// The knob swept (the series).
    pub(crate) knob: &'a str,
    pub(crate) ms: f64,
    pub(crate) psnr_db: f64,
    /// Data bricks of the cut (0 in core).
    pub(crate) bricks: f64,
}

/// What a chart's horizontal axis shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Axis {
    /// Milliseconds per frame, every knob, the front drawn.
    Time,
    /// Data bricks of the cut, the level-of-detail knobs only, no front.
    Bricks,
}

impl Axis {
    fn x(self, p: &ChartPoint<'_>) -> f64 {
        match self {
            Axis::Time => p.ms,
            Axis::Bricks => p.bricks,
        }
    }

    fn shows(self, p: &ChartPoint<'_>) -> bool {
        let x = self.x(p);
        x.is_finite()
            && x > 0.0
            && p.psnr_db.is_finite()
            && match self {
                Axis::Time => true,
                Axis::Bricks => {
                    p.knob == "default"
                        || p.knob.starts_with("lod_")
                        || p.knob.starts_with("bricks_")
                }
            }
    }
}

/// Draws `points` into an SVG at `path` against `axis`; `front` lists the
/// indices on the front (by increasing time; drawn on the time axis only) and
/// `default` the default configuration's index.
pub(crate) fn draw(
    path: &std::path::Path,
    title: &str,
    axis: Axis,
    points: &[ChartPoint<'_>],
    front: &[usize],
    default: usize,
) -> Result<(), String> {
    let e = |x: &dyn std::fmt::Display| x.to_string();
    let root = SVGBackend::new(path, (760, 520)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let finite: Vec<&ChartPoint<'_>> = points.iter().filter(|p| axis.shows(p)).collect();
    let (t0, t1) = finite.iter().fold((f64::MAX, 0.0f64), |(a, b), p| {
        (a.min(axis.x(p)), b.max(axis.x(p)))
    });
    let (p0, p1) = finite.iter().fold((f64::MAX, 0.0f64), |(a, b), p| {
        (a.min(p.psnr_db), b.max(p.psnr_db))
    });
    let (t0, t1) = (t0.max(1e-3) / 1.2, t1.max(1e-3) * 1.2);
    let (p0, p1) = ((p0 - 2.0).max(0.0), p1 + 2.0);
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(50)
        .build_cartesian_2d((t0..t1).log_scale(), p0..p1)
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc(match axis {
            Axis::Time => "ms per frame (median of interleaved rounds, log scale)",
            Axis::Bricks => "data bricks of the cut (working set, log scale)",
        })
        .y_desc("PSNR against the f64 reference, dB")
        .draw()
        .map_err(|x| e(&x))?;
    // The front as a staircase: from each front point, level until the next.
    let mut stair = Vec::new();
    let front = if axis == Axis::Time { front } else { &[] };
    for (k, &i) in front.iter().enumerate() {
        let p = &points[i];
        stair.push((p.ms, p.psnr_db));
        if let Some(&j) = front.get(k + 1) {
            stair.push((points[j].ms, p.psnr_db));
        }
    }
    if !stair.is_empty() {
        chart
            .draw_series(LineSeries::new(stair, BLACK.mix(0.5)))
            .map_err(|x| e(&x))?
            .label("Pareto front")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.mix(0.5)));
    }
    let colors = [
        BLUE,
        RED,
        GREEN,
        MAGENTA,
        CYAN,
        RGBColor(230, 140, 0),
        RGBColor(120, 80, 40),
        RGBColor(128, 128, 128),
        RGBColor(110, 0, 160),
        RGBColor(0, 120, 90),
        RGBColor(200, 0, 100),
        RGBColor(0, 60, 140),
        RGBColor(160, 160, 0),
    ];
    let mut knobs: Vec<&str> = Vec::new();
    for p in points.iter().filter(|p| axis.shows(p)) {
        if !knobs.contains(&p.knob) {
            knobs.push(p.knob);
        }
    }
    for (k, knob) in knobs.iter().enumerate() {
        let c = colors[k % colors.len()];
        let series: Vec<(f64, f64)> = points
            .iter()
            .filter(|p| p.knob == *knob && axis.shows(p))
            .map(|p| (axis.x(p), p.psnr_db))
            .collect();
        chart
            .draw_series(series.iter().map(|&xy| Circle::new(xy, 4, c.filled())))
            .map_err(|x| e(&x))?
            .label(*knob)
            .legend(move |(x, y)| Circle::new((x + 10, y), 4, c.filled()));
    }
    let d = &points[default];
    if axis.shows(d) {
        chart
            .draw_series([Circle::new(
                (axis.x(d), d.psnr_db),
                9,
                BLACK.stroke_width(2),
            )])
            .map_err(|x| e(&x))?
            .label("default")
            .legend(|(x, y)| Circle::new((x + 10, y), 6, BLACK.stroke_width(2)));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(|x| e(&x))?;
    root.present().map_err(|x| e(&x))?;
    Ok(())
}
