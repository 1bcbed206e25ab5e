//! The figures of a convergence study in N: a field at every N over x (one panel per chosen
//! time), and the difference between successive N against N on log–log axes with the fitted
//! rate.

use std::path::Path;

use plotters::prelude::*;

use super::chart::{build_chart, draw_line, draw_png, msg};
use super::legend::{draw_legend, draw_note, legend_indices, LegendEntry, LegendMark};
use super::ranges::{finite_min_max, padded_range, range_including};
use super::response::{coord, sweep_chart, titled};
use super::style::{format_number, indexed_color};
use super::{ConvergenceProfilesPlot, ConvergenceRatePlot};

/// Draws the figure of [`plot_convergence_profiles`](super::plot_convergence_profiles).
pub(super) fn draw_profiles(path: &Path, plot: &ConvergenceProfilesPlot) -> Result<(), String> {
    let k = plot.labels.len();
    let x_range = range_including(0.0, 1.0, finite_min_max(plot.x), "x")?;
    let values = plot
        .values
        .iter()
        .flatten()
        .flatten()
        .chain(plot.limit.into_iter().flatten().flatten());
    let y_range = padded_range(finite_min_max(values), plot.y_label)?;

    draw_png(path, |root| {
        let body = titled(root, plot.title)?;
        let legend_width = 170;
        let (panels, legend_area) =
            body.split_horizontally(body.dim_in_pixel().0 as i32 - legend_width);
        let cells = match plot.times.len() {
            1 => panels.split_evenly((1, 1)),
            2 => panels.split_evenly((2, 1)),
            _ => panels.split_evenly((2, 2)),
        };
        let color = |i: usize| indexed_color(i, k);
        for ((cell, &t), rows) in cells.iter().zip(plot.times).zip(plot.values) {
            let cell = cell
                .titled(
                    &format!("t = {}", format_number(t)),
                    (super::style::FONT, 18),
                )
                .map_err(msg)?;
            let mut chart =
                build_chart(&cell, x_range.clone(), y_range.clone(), "x", plot.y_label)?;
            for (i, row) in rows.iter().enumerate() {
                draw_line(&mut chart, plot.x, row, color(i), false)?;
            }
            if let Some(limit) = plot.limit {
                let j = plot.times.iter().position(|&s| s == t).unwrap_or(0);
                draw_line(&mut chart, plot.x, &limit[j], RGBColor(0, 0, 0), true)?;
            }
        }
        let indices = legend_indices(k, 14);
        let mut entries: Vec<LegendEntry> = indices
            .iter()
            .map(|&i| LegendEntry {
                label: plot.labels[i].clone(),
                color: color(i),
                mark: LegendMark::Line,
            })
            .collect();
        if plot.limit.is_some() {
            entries.push(LegendEntry {
                label: "extrapolated".to_string(),
                color: RGBColor(0, 0, 0),
                mark: LegendMark::Dashed,
            });
        }
        draw_legend(&legend_area, 22, "N", &entries)?;
        Ok(())
    })
}

/// Draws the figure of [`plot_convergence_rate`](super::plot_convergence_rate).
pub(super) fn draw_rate(path: &Path, plot: &ConvergenceRatePlot) -> Result<(), String> {
    let xs: Vec<f64> = plot.n.iter().map(|&v| coord(v, true)).collect();
    let ys: Vec<f64> = plot.diff.iter().map(|&v| coord(v, true)).collect();
    // The fitted line e = C N^-p over the span of the points.
    let fit_line: Option<Vec<(f64, f64)>> = plot.fit.and_then(|(p, log10_c)| {
        let (lo, hi) = finite_min_max(&xs)?;
        (p.is_finite() && log10_c.is_finite())
            .then(|| vec![(lo, log10_c - p * lo), (hi, log10_c - p * hi)])
    });
    let all_y = ys
        .iter()
        .copied()
        .chain(fit_line.iter().flatten().map(|&(_, y)| y))
        .collect::<Vec<f64>>();
    let x_range = padded_range(finite_min_max(&xs), "N")?;
    let y_range = padded_range(finite_min_max(&all_y), plot.y_label)?;

    draw_png(path, |root| {
        let body = titled(root, plot.title)?;
        let mut chart = sweep_chart(
            &body,
            (x_range, true),
            (y_range, true),
            "N (finer of each successive pair)",
            plot.y_label,
            true,
        )?;
        let blue = RGBColor(31, 119, 180);
        draw_line(&mut chart, &xs, &ys, blue, false)?;
        chart
            .draw_series(
                xs.iter()
                    .zip(&ys)
                    .filter(|(x, y)| x.is_finite() && y.is_finite())
                    .map(|(&x, &y)| Circle::new((x, y), 5, blue.filled())),
            )
            .map_err(msg)?;
        if let Some(line) = &fit_line {
            chart
                .draw_series(DashedLineSeries::new(
                    line.clone(),
                    8,
                    5,
                    RGBColor(214, 39, 40).stroke_width(2),
                ))
                .map_err(msg)?;
        }
        if !plot.note.is_empty() {
            draw_note(&body, plot.note, false)?;
        }
        Ok(())
    })
}
