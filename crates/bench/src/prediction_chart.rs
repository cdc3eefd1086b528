//! The prediction suite's chart: per-frame time and wrong pixels of every
//! variant along the failure path (SVG).

use plotters::prelude::*;

/// Draws `tracks` (per variant: ms per frame, wrong share per frame) into an
/// SVG at `path`; a vertical line marks the frame where the camera stopped.
pub(crate) fn draw(
    path: &str,
    names: &[&str],
    tracks: &[(Vec<f64>, Vec<f64>)],
    stop: usize,
) -> Result<(), String> {
    let e = |x: &dyn std::fmt::Display| x.to_string();
    let root = SVGBackend::new(path, (900, 640)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let (top, bottom) = root.split_vertically(320);
    let frames = tracks.first().map_or(0, |t| t.0.len());
    let colors = [BLACK, BLUE, GREEN, RED, MAGENTA];
    let max_ms = tracks
        .iter()
        .flat_map(|t| t.0.iter())
        .copied()
        .fold(1.0, f64::max)
        * 1.1;
    let max_wrong = tracks
        .iter()
        .flat_map(|t| t.1.iter())
        .copied()
        .fold(0.0, f64::max)
        * 110.0
        + 0.05;
    let panels: [(&DrawingArea<SVGBackend, _>, &str, f64, bool); 2] = [
        (
            &top,
            "ms per frame (prepare + submit + wait)",
            max_ms,
            false,
        ),
        (
            &bottom,
            "wrong pixels (% of the image, vs full traversal)",
            max_wrong,
            true,
        ),
    ];
    for (area, title, ymax, wrong) in panels {
        let mut chart = ChartBuilder::on(area)
            .caption(title, ("sans-serif", 18))
            .margin(10)
            .x_label_area_size(30)
            .y_label_area_size(50)
            .build_cartesian_2d(0f64..frames as f64, 0f64..ymax)
            .map_err(|x| e(&x))?;
        chart
            .configure_mesh()
            .x_desc("frame")
            .draw()
            .map_err(|x| e(&x))?;
        chart
            .draw_series(LineSeries::new(
                [(stop as f64, 0.0), (stop as f64, ymax)],
                BLACK.mix(0.3),
            ))
            .map_err(|x| e(&x))?;
        for (k, (ms, w)) in tracks.iter().enumerate() {
            let c = colors[k % colors.len()];
            let ys = if wrong { w } else { ms };
            let scale = if wrong { 100.0 } else { 1.0 };
            chart
                .draw_series(LineSeries::new(
                    ys.iter().enumerate().map(|(i, y)| (i as f64, y * scale)),
                    c,
                ))
                .map_err(|x| e(&x))?
                .label(names[k])
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(|x| e(&x))?;
    }
    root.present().map_err(|x| e(&x))?;
    Ok(())
}
