//! The work–precision figure of `roughlub accuracy`: error against wall time, both on log axes
//! (drawn as log10 of the values, with the axis titles saying so), one line per scheme, each
//! run's observed order written beside its point.

use std::path::Path;

use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::chart::{build_chart, draw_line, draw_png, figure, msg};
use super::legend::{draw_legend, legend_width, LegendEntry, LegendMark};
use super::ranges::{finite_min_max, padded_range};
use super::style::{series_color, shorten, FONT};

/// Draws the figure of [`plot_work_precision`](super::plot_work_precision) on checked input.
pub(super) fn draw(
    path: &Path,
    title: &str,
    lines: &[super::WorkPrecisionLine],
    target: Option<f64>,
) -> Result<(), String> {
    // One colour per scheme family (order, sequence, backend and precision), the fixed-step line
    // dashed and the adaptive one solid: 12 colours for 12 lines were too close to tell apart.
    let family = |label: &str| label.replace(" adaptive", "").replace(" fixed dt", "");
    let mut families: Vec<String> = Vec::new();
    for (label, _) in lines {
        if !families.contains(&family(label)) {
            families.push(family(label));
        }
    }
    let family_index: Vec<usize> = lines
        .iter()
        .map(|(l, _)| families.iter().position(|f| *f == family(l)).unwrap_or(0))
        .collect();
    let dashed: Vec<bool> = lines.iter().map(|(l, _)| l.contains("fixed dt")).collect();
    let color = |i: usize| series_color(family_index[i], families.len());
    let log = |v: f64| if v > 0.0 { v.log10() } else { f64::NAN };
    let xs: Vec<Vec<f64>> = lines
        .iter()
        .map(|(_, p)| p.iter().map(|q| log(q.0)).collect())
        .collect();
    let ys: Vec<Vec<f64>> = lines
        .iter()
        .map(|(_, p)| p.iter().map(|q| log(q.1)).collect())
        .collect();
    let x_range = padded_range(finite_min_max(xs.iter().flatten()), "the wall times")?;
    let mut y_values: Vec<f64> = ys.iter().flatten().copied().collect();
    if let Some(t) = target {
        y_values.push(log(t));
    }
    let y_range = padded_range(finite_min_max(y_values.iter()), "the errors")?;

    draw_png(path, |root| {
        let body = figure(root, title)?;
        let labels: Vec<String> = lines.iter().map(|(l, _)| shorten(l, 40)).collect();
        let width = legend_width(&body, &labels, 120)?;
        let (panel, legend_area) = body.split_horizontally(body.dim_in_pixel().0 as i32 - width);
        let mut chart = build_chart(
            &panel,
            x_range.clone(),
            y_range,
            "log10 wall time per run [s]",
            "log10 error",
        )?;
        for (i, (x, y)) in xs.iter().zip(&ys).enumerate() {
            draw_line(&mut chart, x, y, color(i), dashed[i])?;
            chart
                .draw_series(
                    x.iter()
                        .zip(y)
                        .filter(|(a, b)| a.is_finite() && b.is_finite())
                        .map(|(&a, &b)| Circle::new((a, b), 4, color(i).filled())),
                )
                .map_err(msg)?;
            // The observed order, right of its point, in the line's colour.
            let ink = color(i);
            let style = TextStyle::from((FONT, 13).into_font())
                .color(&ink)
                .pos(Pos::new(HPos::Left, VPos::Center));
            chart
                .draw_series(
                    x.iter()
                        .zip(y)
                        .zip(&lines[i].1)
                        .filter(|((a, b), _)| a.is_finite() && b.is_finite())
                        .filter_map(|((&a, &b), &(_, _, order))| {
                            let text = format!("{:.1}", order?);
                            Some(EmptyElement::at((a, b)) + Text::new(text, (6, 0), style.clone()))
                        }),
                )
                .map_err(msg)?;
        }
        let mut entries: Vec<LegendEntry> = labels
            .iter()
            .enumerate()
            .map(|(i, l)| LegendEntry {
                label: l.clone(),
                color: color(i),
                mark: if dashed[i] {
                    LegendMark::Dashed
                } else {
                    LegendMark::Line
                },
            })
            .collect();
        if let Some(t) = target {
            let ty = log(t);
            // Black: the palette's grey is a family's colour, and fixed-step lines are dashed too.
            draw_line(
                &mut chart,
                &[x_range.start, x_range.end],
                &[ty, ty],
                BLACK,
                true,
            )?;
            entries.push(LegendEntry {
                label: format!("target {t:e}"),
                color: BLACK,
                mark: LegendMark::Dashed,
            });
        }
        draw_legend(&legend_area, 22, "", &entries)?;
        Ok(())
    })
}
