//! The sensitivity figure: per response a panel of bars, first-order (S1) and total-order (ST)
//! Sobol index of each swept key side by side, each with its interval as a whisker.

use std::path::Path;

use plotters::prelude::*;

use super::chart::{draw_png, figure, msg};
use super::style::{FONT, TAB10};
use super::SensitivityPlot;

/// Draws the figure of [`plot_sensitivity`](super::plot_sensitivity) on input that passed its
/// check.
pub(super) fn draw(path: &Path, plot: &SensitivityPlot) -> Result<(), String> {
    draw_png(path, |root| {
        let body = figure(root, plot.title)?;
        let panels = body.split_evenly((plot.responses.len(), 1));
        let keys = plot.keys.len();
        for (panel, response) in panels.iter().zip(plot.responses) {
            let finite = response
                .first
                .iter()
                .chain(&response.total)
                .flat_map(|i| [i.0, i.1, i.2])
                .filter(|v| v.is_finite());
            let (lo, hi) = finite.fold((0.0f64, 1.0f64), |(a, b), v| (a.min(v), b.max(v)));
            let mut chart = ChartBuilder::on(panel)
                .margin(8)
                .margin_right(20)
                .caption(response.name, (FONT, 18))
                .x_label_area_size(30)
                .y_label_area_size(60)
                .build_cartesian_2d(-0.5..keys as f64 - 0.5, lo - 0.05..hi + 0.05)
                .map_err(msg)?;
            let names = plot.keys;
            chart
                .configure_mesh()
                .disable_x_mesh()
                .x_labels(keys)
                .x_label_formatter(&|v| {
                    let k = v.round();
                    if (v - k).abs() < 1e-6 && k >= 0.0 && (k as usize) < names.len() {
                        names[k as usize].clone()
                    } else {
                        String::new()
                    }
                })
                .y_desc("Sobol index")
                .label_style((FONT, 14))
                .axis_desc_style((FONT, 16))
                .bold_line_style(BLACK.mix(0.12))
                .light_line_style(BLACK.mix(0.04))
                .draw()
                .map_err(msg)?;
            for (series, (values, offset, label)) in [
                (&response.first, -0.18, "first order S1"),
                (&response.total, 0.18, "total order ST"),
            ]
            .into_iter()
            .enumerate()
            {
                let (r, g, b) = TAB10[series];
                let color = RGBColor(r, g, b);
                let bars = values.iter().enumerate().filter(|(_, v)| v.0.is_finite());
                chart
                    .draw_series(bars.clone().map(|(k, v)| {
                        let x = k as f64 + offset;
                        Rectangle::new([(x - 0.16, 0.0), (x + 0.16, v.0)], color.mix(0.8).filled())
                    }))
                    .map_err(msg)?
                    .label(label)
                    .legend(move |(x, y)| {
                        Rectangle::new([(x, y - 5), (x + 14, y + 5)], color.filled())
                    });
                chart
                    .draw_series(
                        bars.filter(|(_, v)| v.1.is_finite() && v.2.is_finite())
                            .map(|(k, v)| {
                                let x = k as f64 + offset;
                                PathElement::new(vec![(x, v.1), (x, v.2)], BLACK.stroke_width(2))
                            }),
                    )
                    .map_err(msg)?;
            }
            chart
                .configure_series_labels()
                .label_font((FONT, 14))
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK.mix(0.3))
                .draw()
                .map_err(msg)?;
        }
        Ok(())
    })
}
