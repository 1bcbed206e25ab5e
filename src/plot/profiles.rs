//! The figure of one member's profiles: rho (and rho*) over x in the top panel, u in the bottom.

use std::path::Path;

use plotters::prelude::*;

use super::chart::{build_chart, draw_line, draw_png, figure};
use super::legend::{draw_legend, legend_indices, LegendEntry, LegendMark, LEGEND_ROW};
use super::ranges::{finite_min_max, padded_range, range_including};
use super::style::{format_number, indexed_color};
use super::ProfilePlot;

/// Draws the figure of [`plot_profiles`](super::plot_profiles) on input that passed its check.
pub(super) fn draw(path: &Path, plot: &ProfilePlot) -> Result<(), String> {
    let n_times = plot.times.len();

    let x_range = range_including(0.0, 1.0, finite_min_max(plot.x), "x")?;
    let rho_values = plot
        .rho
        .iter()
        .chain(plot.rho_star.into_iter().flatten())
        .flatten();
    let rho_range = range_including(0.0, 1.0, finite_min_max(rho_values), "rho")?;
    let u_range = padded_range(finite_min_max(plot.u.iter().flatten()), "u")?;

    draw_png(path, |root| {
        let body = figure(root, plot.title)?;
        let legend_width = 170;
        let (panels, legend_area) =
            body.split_horizontally(body.dim_in_pixel().0 as i32 - legend_width);
        let (top, bottom) = panels.split_vertically(panels.dim_in_pixel().1 as i32 / 2);

        let mut rho_chart = build_chart(&top, x_range.clone(), rho_range, "x", "rho")?;
        let mut u_chart = build_chart(&bottom, x_range, u_range, "x", "u")?;

        for i in 0..n_times {
            let color = indexed_color(i, n_times);
            draw_line(&mut rho_chart, plot.x, &plot.rho[i], color, false)?;
            if let Some(rho_star) = plot.rho_star {
                draw_line(&mut rho_chart, plot.x, &rho_star[i], color, true)?;
            }
            draw_line(&mut u_chart, plot.x, &plot.u[i], color, false)?;
        }

        let mut entries: Vec<LegendEntry> = legend_indices(n_times, 10)
            .into_iter()
            .map(|i| LegendEntry {
                label: format!("t = {}", format_number(plot.times[i])),
                color: indexed_color(i, n_times),
                mark: LegendMark::Line,
            })
            .collect();
        draw_legend(&legend_area, 22, "time", &entries)?;
        if plot.rho_star.is_some() {
            entries = vec![
                LegendEntry {
                    label: "rho".to_string(),
                    color: RGBColor(60, 60, 60),
                    mark: LegendMark::Line,
                },
                LegendEntry {
                    label: "rho*".to_string(),
                    color: RGBColor(60, 60, 60),
                    mark: LegendMark::Dashed,
                },
            ];
            let top = 22 + LEGEND_ROW * (legend_indices(n_times, 10).len() as i32 + 2);
            draw_legend(&legend_area, top, "", &entries)?;
        }

        Ok(())
    })
}
