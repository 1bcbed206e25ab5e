//! The histogram figure, with an optional note in the emptier top corner.

use std::path::Path;

use plotters::prelude::*;

use super::chart::{build_chart_with_y_labels, draw_png, figure, msg};
use super::legend::draw_note;
use super::style::TAB10;

/// Draws the figure of [`plot_histogram`](super::plot_histogram) on input that passed its check.
pub(super) fn draw(
    path: &Path,
    title: &str,
    x_label: &str,
    edges: &[f64],
    counts: &[u64],
    note: Option<&str>,
) -> Result<(), String> {
    let (lo, hi) = (edges[0], edges[edges.len() - 1]);
    let span = hi - lo;
    if !span.is_finite() {
        return Err(format!(
            "the bin edges (from {lo:e} to {hi:e}) are too large to plot"
        ));
    }
    if span <= lo.abs().max(hi.abs()) * 1e-12 {
        return Err(format!(
            "the bin edges (from {lo:e} to {hi:e}) are too close together to plot"
        ));
    }
    let max_count = counts.iter().copied().max().unwrap_or(0) as f64;
    let headroom = if note.is_some() { 1.25 } else { 1.08 };
    let y_top = (max_count * headroom).max(1.0);
    // Whole-number ticks: at most one label per unit of count.
    let y_labels = (y_top.floor().min(10.0) as usize + 1).clamp(2, 10);

    draw_png(path, |root| {
        let body = figure(root, title)?;
        let mut chart =
            build_chart_with_y_labels(&body, lo..hi, 0.0..y_top, x_label, "count", y_labels)?;

        let (r, g, b) = TAB10[0];
        let fill = RGBColor(r, g, b);
        let edge = RGBColor(r / 2, g / 2, b / 2);
        for (w, &c) in edges.windows(2).zip(counts) {
            if c == 0 {
                continue;
            }
            let corners = [(w[0], 0.0), (w[1], c as f64)];
            chart
                .draw_series([
                    Rectangle::new(corners, fill.mix(0.75).filled()),
                    Rectangle::new(corners, edge.stroke_width(1)),
                ])
                .map_err(msg)?;
        }

        if let Some(note) = note {
            // In the top corner above the lower bars.
            let mid = 0.5 * (lo + hi);
            let half_max = |left: bool| {
                edges
                    .windows(2)
                    .zip(counts)
                    .filter(|(w, _)| (0.5 * (w[0] + w[1]) < mid) == left)
                    .map(|(_, &c)| c)
                    .max()
                    .unwrap_or(0)
            };
            let left = half_max(true) < half_max(false);
            draw_note(&chart.plotting_area().strip_coord_spec(), note, left)?;
        }

        Ok(())
    })
}
