//! The figure of a scalar observable of several members over time.

use std::path::Path;

use super::chart::{build_chart, draw_line, draw_png, figure};
use super::legend::{
    draw_legend, legend_indices, legend_width, LegendEntry, LegendMark, LEGEND_ROW,
};
use super::ranges::{finite_min_max, padded_range};
use super::style::{series_color, shorten};

/// Draws the figure of [`plot_series`](super::plot_series) on input that passed its check.
pub(super) fn draw(
    path: &Path,
    title: &str,
    y_label: &str,
    times: &[f64],
    series: &[(String, Vec<f64>)],
) -> Result<(), String> {
    let n = series.len();
    let color = |i: usize| series_color(i, n);

    let x_range = match finite_min_max(times) {
        None => 0.0..1.0,
        Some((lo, hi)) if hi - lo > lo.abs().max(hi.abs()) * 1e-12 => lo..hi,
        some => padded_range(some, "the output times")?,
    };
    if !(x_range.end - x_range.start).is_finite() {
        return Err("the output times are too large to plot".to_string());
    }
    let y_range = padded_range(
        finite_min_max(series.iter().flat_map(|(_, v)| v.iter())),
        y_label,
    )?;

    draw_png(path, |root| {
        let body = figure(root, title)?;

        const MAX_LABEL: usize = 32;
        let labels: Vec<String> = series.iter().map(|(l, _)| shorten(l, MAX_LABEL)).collect();
        let width = legend_width(&body, &labels, 120)?;
        let (panel, legend_area) = body.split_horizontally(body.dim_in_pixel().0 as i32 - width);

        let mut chart = build_chart(&panel, x_range, y_range, "t", y_label)?;
        for (i, (_, values)) in series.iter().enumerate() {
            draw_line(&mut chart, times, values, color(i), false)?;
        }

        let max_entries = ((legend_area.dim_in_pixel().1 as i32 - 40) / LEGEND_ROW).max(2) as usize;
        let entries: Vec<LegendEntry> = legend_indices(n, max_entries)
            .into_iter()
            .map(|i| LegendEntry {
                label: labels[i].clone(),
                color: color(i),
                mark: LegendMark::Line,
            })
            .collect();
        draw_legend(&legend_area, 22, "", &entries)?;

        Ok(())
    })
}
