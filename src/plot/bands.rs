//! The figure of an ensemble's mean profile with its quantile band at a few times.

use std::path::Path;

use plotters::prelude::*;

use super::chart::{build_chart, draw_band_area, draw_line, draw_png, figure};
use super::legend::{
    draw_legend, legend_indices, legend_width, LegendEntry, LegendMark, LEGEND_ROW,
};
use super::ranges::{finite_min_max, padded_range};
use super::style::{format_number, indexed_color, shorten};
use super::BandPlot;

/// Draws the figure of [`plot_band`](super::plot_band) on input that passed its check.
pub(super) fn draw(path: &Path, plot: &BandPlot) -> Result<(), String> {
    let n_times = plot.times.len();

    let x_range = match finite_min_max(plot.x) {
        Some((lo, hi)) if lo >= 0.0 && hi <= 1.0 => 0.0..1.0,
        Some((lo, hi)) if hi - lo > lo.abs().max(hi.abs()) * 1e-12 => lo..hi,
        some => padded_range(some, "x")?,
    };
    if !(x_range.end - x_range.start).is_finite() {
        return Err("the values of x are too large to plot".to_string());
    }
    let y_values = plot
        .mean
        .iter()
        .chain(plot.lower)
        .chain(plot.upper)
        .chain(plot.reference.into_iter().flatten())
        .flatten();
    let y_range = match finite_min_max(y_values) {
        None => 0.0..1.0,
        Some((lo, hi)) if lo >= 0.0 && hi <= 1.0 => 0.0..1.0,
        some => padded_range(some, plot.y_label)?,
    };

    draw_png(path, |root| {
        let body = figure(root, plot.title)?;

        const MAX_LABEL: usize = 32;
        let band_label = shorten(plot.band_label, MAX_LABEL);
        let shown = legend_indices(n_times, 10);
        let mut entries: Vec<LegendEntry> = shown
            .iter()
            .map(|&i| LegendEntry {
                label: shorten(&format!("t = {}", format_number(plot.times[i])), MAX_LABEL),
                color: indexed_color(i, n_times),
                mark: LegendMark::Line,
            })
            .collect();
        let grey = RGBColor(60, 60, 60);
        let mut extra = vec![LegendEntry {
            label: band_label,
            color: grey,
            mark: LegendMark::Band,
        }];
        if plot.reference.is_some() {
            extra.push(LegendEntry {
                label: "reference".to_string(),
                color: grey,
                mark: LegendMark::Dashed,
            });
        }
        let labels: Vec<&str> = entries
            .iter()
            .chain(&extra)
            .map(|e| e.label.as_str())
            .collect();
        let width = legend_width(&body, &labels, 170)?;
        let (panel, legend_area) = body.split_horizontally(body.dim_in_pixel().0 as i32 - width);

        let mut chart = build_chart(&panel, x_range, y_range, "x", plot.y_label)?;
        for i in 0..n_times {
            let color = indexed_color(i, n_times);
            draw_band_area(&mut chart, plot.x, &plot.lower[i], &plot.upper[i], color)?;
        }
        for i in 0..n_times {
            let color = indexed_color(i, n_times);
            if let Some(reference) = plot.reference {
                draw_line(&mut chart, plot.x, &reference[i], color, true)?;
            }
            draw_line(&mut chart, plot.x, &plot.mean[i], color, false)?;
        }

        draw_legend(&legend_area, 22, "time", &entries)?;
        let top = 22 + LEGEND_ROW * (shown.len() as i32 + 2);
        entries = extra;
        draw_legend(&legend_area, top, "", &entries)?;

        Ok(())
    })
}
