//! The suites' line charts (SVG through plotters): one or more panels
//! stacked vertically, each a set of named series. The pareto suite's
//! scatter-and-front charts are its own (`pareto/chart.rs`).

use plotters::prelude::*;

/// One line of a chart.
pub(crate) struct Series {
    pub(crate) name: String,
    pub(crate) points: Vec<(f64, f64)>,
}

impl Series {
    /// A series of `ys` at x = 0, 1, 2, ...
    pub(crate) fn indexed(name: impl Into<String>, ys: impl IntoIterator<Item = f64>) -> Series {
        Series {
            name: name.into(),
            points: ys
                .into_iter()
                .enumerate()
                .map(|(i, y)| (i as f64, y))
                .collect(),
        }
    }
}

/// One panel: its title, axes and series.
pub(crate) struct Panel {
    pub(crate) title: String,
    pub(crate) x_desc: String,
    pub(crate) y_desc: String,
    pub(crate) series: Vec<Series>,
    /// x on a log2 axis.
    pub(crate) log2_x: bool,
    /// The y axis starts at 0 (else at the data's smallest value).
    pub(crate) y_from_zero: bool,
    /// A vertical marker at this x (an event along a path).
    pub(crate) marker_x: Option<f64>,
}

impl Panel {
    /// A panel of `series` with linear axes fitted to the data.
    pub(crate) fn new(title: &str, x_desc: &str, y_desc: &str, series: Vec<Series>) -> Panel {
        Panel {
            title: title.into(),
            x_desc: x_desc.into(),
            y_desc: y_desc.into(),
            series,
            log2_x: false,
            y_from_zero: false,
            marker_x: None,
        }
    }
}

fn err(e: impl std::fmt::Display) -> String {
    e.to_string()
}

/// Draws `panels` stacked in an SVG at `path`, `width` pixels wide and
/// `panel_height` per panel. Panels without points are drawn empty.
pub(crate) fn draw(
    path: &std::path::Path,
    width: u32,
    panel_height: u32,
    panels: &[Panel],
) -> Result<(), String> {
    let n = panels.len().max(1);
    let root = SVGBackend::new(path, (width, panel_height * n as u32)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let colors = [BLACK, BLUE, RED, GREEN, MAGENTA, CYAN];
    for (panel, area) in panels.iter().zip(root.split_evenly((n, 1))) {
        let fx = |x: f64| if panel.log2_x { x.log2() } else { x };
        let pts = || panel.series.iter().flat_map(|s| s.points.iter());
        let (x0, x1) = pts().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(fx(p.0)), b.max(fx(p.0)))
        });
        let (mut y0, y1) = pts().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p.1), b.max(p.1))
        });
        if panel.y_from_zero {
            y0 = 0.0;
        }
        let (x0, x1) = if x1 > x0 { (x0, x1) } else { (0.0, 1.0) };
        let (y0, y1) = if y1 > y0 { (y0, y1) } else { (0.0, 1.0) };
        let pad = ((y1 - y0) * 0.05).max(1e-3);
        let y_lo = if panel.y_from_zero { 0.0 } else { y0 - pad };
        let mut chart = ChartBuilder::on(&area)
            .caption(&panel.title, ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(32)
            .y_label_area_size(52)
            .build_cartesian_2d(x0..x1, y_lo..y1 + pad)
            .map_err(err)?;
        let x_desc = if panel.log2_x {
            format!("log2 {}", panel.x_desc)
        } else {
            panel.x_desc.clone()
        };
        chart
            .configure_mesh()
            .x_desc(x_desc)
            .y_desc(panel.y_desc.as_str())
            .draw()
            .map_err(err)?;
        if let Some(x) = panel.marker_x {
            chart
                .draw_series(LineSeries::new(
                    [(fx(x), y_lo), (fx(x), y1 + pad)],
                    BLACK.mix(0.3),
                ))
                .map_err(err)?;
        }
        for (k, se) in panel.series.iter().enumerate() {
            let c = colors[k % colors.len()];
            chart
                .draw_series(LineSeries::new(
                    se.points.iter().map(|&(x, y)| (fx(x), y)),
                    c,
                ))
                .map_err(err)?
                .label(se.name.clone())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(err)?;
    }
    root.present().map_err(err)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn panels_are_drawn_into_one_svg() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.svg");
        let s = Series {
            name: "s".into(),
            points: vec![(1.0, 1.0), (2.0, 3.0), (4.0, 2.0)],
        };
        let mut log = Panel::new("a", "x", "y", vec![s]);
        log.log2_x = true;
        let mut marked = Panel::new("b", "x", "y", vec![Series::indexed("t", [0.5; 4])]);
        marked.marker_x = Some(2.0);
        marked.y_from_zero = true;
        let empty = Panel::new("c", "x", "y", Vec::new());
        draw(&path, 400, 200, &[log, marked, empty]).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        // Titles, axis descriptions and legend entries are text lines.
        for text in ["log2 x", "a", "b", "c", "s", "t"] {
            assert!(
                svg.lines().any(|l| l.trim() == text),
                "no {text} in the chart"
            );
        }
    }
}
