//! The figures of a parameter sweep: the response against one swept parameter (mean line with
//! markers and a quantile band), a heat map over two, and a scatter of sampled members.
//!
//! Log axes are drawn as linear axes of log10(value) whose tick labels are the values (powers of
//! ten when the range spans two decades or more), so that the lines, bands and cells of the
//! shared [`chart`](super::chart) helpers apply unchanged.

use std::ops::Range;
use std::path::Path;

use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::chart::{draw_band_area, draw_line, draw_png, msg, Area, Chart};
use super::legend::{draw_legend, draw_note, legend_width, LegendEntry, LegendMark};
use super::ranges::{finite_min_max, padded_range};
use super::style::{format_number, format_tick, indexed_color, shorten, FONT, TAB10};
use super::{HeatmapPlot, ResponsePlot, ScatterPlot};

// Each figure computes what it draws (and every error about the data) before it draws, so that
// a bad input is reported as such rather than as a drawing error.

/// Draws the figure of [`plot_response`](super::plot_response) on input that passed its check.
pub(super) fn draw_response(path: &Path, plot: &ResponsePlot) -> Result<(), String> {
    let data = ResponseData::new(plot)?;
    draw_png(path, |root| response_on(root, plot, &data))
}

/// Draws the figure of [`plot_heatmap`](super::plot_heatmap) on input that passed its check.
pub(super) fn draw_heatmap(path: &Path, plot: &HeatmapPlot) -> Result<(), String> {
    let data = HeatmapData::new(plot)?;
    draw_png(path, |root| heatmap_on(root, plot, &data).map(|_| ()))
}

/// Draws the figure of [`plot_scatter`](super::plot_scatter) on input that passed its check.
pub(super) fn draw_scatter(path: &Path, plot: &ScatterPlot) -> Result<(), String> {
    let data = ScatterData::new(plot)?;
    draw_png(path, |root| scatter_on(root, plot, &data))
}

/// Plot coordinate of a value: the value itself, or its log10 on a log axis (NaN for values
/// <= 0, which are then skipped like other non-finite values).
pub(super) fn coord(v: f64, log: bool) -> f64 {
    match (log, v > 0.0) {
        (false, _) => v,
        (true, true) => v.log10(),
        (true, false) => f64::NAN,
    }
}

/// Fills `root` white and writes the title; returns the area below it.
pub(super) fn titled<'a>(root: &Area<'a>, title: &str) -> Result<Area<'a>, String> {
    root.fill(&WHITE).map_err(msg)?;
    root.titled(&shorten(title, 90), (FONT, 26)).map_err(msg)
}

/// Tick label of an axis: the value, or 10^v on a log axis.
fn tick_label(v: f64, span: f64, log: bool) -> String {
    if log {
        format_number(10f64.powf(v))
    } else {
        format_tick(v, span)
    }
}

/// Most tick labels on an axis: on a log axis spanning 1.5 decades or more, few enough that
/// the ticks fall on integer powers of ten.
fn label_count(span: f64, log: bool) -> usize {
    match (log, span >= 1.5) {
        (false, _) => 10,
        (true, true) => (span.floor() as usize + 1).min(10),
        (true, false) => 6,
    }
}

/// A panel like [`build_chart`](super::chart::build_chart), with optional log axes (plot
/// coordinates log10 of the values, labelled with the values) and optional grid lines.
pub(super) fn sweep_chart<'a, 'b>(
    area: &'a Area<'b>,
    (x_range, log_x): (Range<f64>, bool),
    (y_range, log_y): (Range<f64>, bool),
    x_desc: &str,
    y_desc: &str,
    grid_lines: bool,
) -> Result<Chart<'a, 'b>, String> {
    let (x_span, y_span) = (x_range.end - x_range.start, y_range.end - y_range.start);
    let mut chart = ChartBuilder::on(area)
        .margin(12)
        .margin_right(20)
        .x_label_area_size(45)
        .y_label_area_size(75)
        .build_cartesian_2d(x_range, y_range)
        .map_err(msg)?;
    let mut mesh = chart.configure_mesh();
    if !grid_lines {
        mesh.disable_mesh();
    }
    mesh.x_desc(x_desc)
        .y_desc(y_desc)
        .label_style((FONT, 16))
        .axis_desc_style((FONT, 20))
        .bold_line_style(BLACK.mix(0.12))
        .light_line_style(BLACK.mix(0.04))
        .x_label_formatter(&|v| tick_label(*v, x_span, log_x))
        .y_label_formatter(&|v| tick_label(*v, y_span, log_y))
        .x_labels(label_count(x_span, log_x))
        .y_labels(label_count(y_span, log_y))
        .draw()
        .map_err(msg)?;
    Ok(chart)
}

/// Plot-coordinate range of `coords` (finite ones), padded; `what` names the axis in errors.
fn axis_range(coords: &[f64], what: &str) -> Result<Range<f64>, String> {
    padded_range(finite_min_max(coords), what)
}

fn tab10(i: usize) -> RGBColor {
    let (r, g, b) = TAB10[i];
    RGBColor(r, g, b)
}

/// The points of a response figure sorted by x (plot coordinates), and the axis ranges.
struct ResponseData {
    xs: Vec<f64>,
    mean: Vec<f64>,
    lower: Vec<f64>,
    upper: Vec<f64>,
    x_range: Range<f64>,
    y_range: Range<f64>,
}

impl ResponseData {
    fn new(plot: &ResponsePlot) -> Result<ResponseData, String> {
        let mut order: Vec<usize> = (0..plot.x.len())
            .filter(|&i| coord(plot.x[i], plot.log_x).is_finite())
            .collect();
        order.sort_by(|&a, &b| plot.x[a].total_cmp(&plot.x[b]));
        let xs: Vec<f64> = order
            .iter()
            .map(|&i| coord(plot.x[i], plot.log_x))
            .collect();
        let pick = |v: &[f64]| -> Vec<f64> { order.iter().map(|&i| v[i]).collect() };
        let (mean, lower, upper) = (pick(plot.mean), pick(plot.lower), pick(plot.upper));

        let x_range = axis_range(&xs, plot.x_label)?;
        let y_range = padded_range(
            finite_min_max(mean.iter().chain(&lower).chain(&upper)),
            plot.y_label,
        )?;
        Ok(ResponseData {
            xs,
            mean,
            lower,
            upper,
            x_range,
            y_range,
        })
    }
}

/// The response figure drawn on `root`.
fn response_on(root: &Area, plot: &ResponsePlot, data: &ResponseData) -> Result<(), String> {
    let ResponseData {
        xs,
        mean,
        lower,
        upper,
        x_range,
        y_range,
    } = data;
    let body = titled(root, plot.title)?;
    let color = tab10(0);
    let entries = [
        LegendEntry {
            label: "mean".to_string(),
            color,
            mark: LegendMark::Line,
        },
        LegendEntry {
            label: shorten(plot.band_label, 32),
            color,
            mark: LegendMark::Band,
        },
    ];
    let labels: Vec<&str> = entries.iter().map(|e| e.label.as_str()).collect();
    let width = legend_width(&body, &labels, 150)?;
    let (panel, legend_area) = body.split_horizontally(body.dim_in_pixel().0 as i32 - width);

    let mut chart = sweep_chart(
        &panel,
        (x_range.clone(), plot.log_x),
        (y_range.clone(), false),
        plot.x_label,
        plot.y_label,
        true,
    )?;
    draw_band_area(&mut chart, xs, lower, upper, color)?;
    draw_line(&mut chart, xs, mean, color, false)?;
    chart
        .draw_series(
            xs.iter()
                .zip(mean)
                .filter(|(x, y)| x.is_finite() && y.is_finite())
                .map(|(&x, &y)| Circle::new((x, y), 4, color.filled())),
        )
        .map_err(msg)?;
    draw_legend(&legend_area, 22, "", &entries)
}

/// Edges (in plot coordinates) of the cells centred on the sorted, distinct `centres`: halfway
/// between neighbours, the outer cells as wide as their neighbour's half spacing on the inside
/// (a lone cell: one decade on a log axis, ±10 % of the value, or ±0.5 around 0).
fn cell_edges(centres: &[f64], log: bool, what: &str) -> Result<Vec<f64>, String> {
    let n = centres.len();
    let mut edges = Vec::with_capacity(n + 1);
    if n == 1 {
        let c = centres[0];
        let half = if log || c == 0.0 { 0.5 } else { 0.1 * c.abs() };
        edges.extend([c - half, c + half]);
    } else {
        edges.push(centres[0] - 0.5 * (centres[1] - centres[0]));
        edges.extend(centres.windows(2).map(|w| 0.5 * w[0] + 0.5 * w[1]));
        edges.push(centres[n - 1] + 0.5 * (centres[n - 1] - centres[n - 2]));
    }
    if edges.iter().any(|e| !e.is_finite()) || !(edges[n] - edges[0]).is_finite() {
        return Err(format!("the values of {what} are too large to plot"));
    }
    if edges.windows(2).any(|w| w[0] >= w[1]) {
        return Err(format!(
            "the values of {what} are too close together to plot"
        ));
    }
    Ok(edges)
}

/// Sorted plot coordinates of `values` and, for each value, its rank in that order.
fn ranked(values: &[f64], log: bool) -> (Vec<f64>, Vec<usize>) {
    let mut order: Vec<usize> = (0..values.len()).collect();
    order.sort_by(|&a, &b| values[a].total_cmp(&values[b]));
    let mut rank = vec![0; values.len()];
    for (r, &i) in order.iter().enumerate() {
        rank[i] = r;
    }
    (order.iter().map(|&i| coord(values[i], log)).collect(), rank)
}

/// Colour of a value at `s` in [0, 1] of the colour scale: the colormap of the other figures.
pub(super) fn value_color(s: f64) -> RGBColor {
    indexed_color((s.clamp(0.0, 1.0) * 1000.0).round() as usize, 1001)
}

/// Position in [0, 1] of `v` on the scale `[lo, hi]` (0.5 for a constant scale); computed on
/// halves so that a span beyond the largest double does not overflow.
pub(super) fn scale_position(v: f64, (lo, hi): (f64, f64)) -> f64 {
    if hi > lo {
        (0.5 * v - 0.5 * lo) / (0.5 * hi - 0.5 * lo)
    } else {
        0.5
    }
}

/// Width in pixels of the colour bar column of a heat map.
const COLOR_BAR_WIDTH: i32 = 145;

/// The cells of a heat map (plot coordinates) and its colour scale.
struct HeatmapData {
    /// Rank of each x (its column from the left) and of each y (its row from the bottom).
    x_rank: Vec<usize>,
    y_rank: Vec<usize>,
    /// Cell edges, sorted, one more than the values.
    x_edges: Vec<f64>,
    y_edges: Vec<f64>,
    /// Range of the finite values, if any.
    scale: Option<(f64, f64)>,
    /// Axis range of the colour bar.
    bar_range: Option<Range<f64>>,
}

impl HeatmapData {
    fn new(plot: &HeatmapPlot) -> Result<HeatmapData, String> {
        let (x_centres, x_rank) = ranked(plot.xs, plot.log_x);
        let (y_centres, y_rank) = ranked(plot.ys, plot.log_y);
        let x_edges = cell_edges(&x_centres, plot.log_x, plot.x_label)?;
        let y_edges = cell_edges(&y_centres, plot.log_y, plot.y_label)?;
        let scale = finite_min_max(plot.values.iter().flatten());
        let bar_range = match scale {
            None => None,
            Some((lo, hi)) if hi > lo && (hi - lo).is_finite() => Some(lo..hi),
            Some((lo, hi)) if hi > lo => {
                return Err(format!(
                    "the values of {} (from {lo:e} to {hi:e}) are too far apart to plot",
                    plot.value_label
                ))
            }
            some => Some(padded_range(some, plot.value_label)?),
        };
        Ok(HeatmapData {
            x_rank,
            y_rank,
            x_edges,
            y_edges,
            scale,
            bar_range,
        })
    }
}

/// The heat map drawn on `root`. Returns the pixel centre of each cell, `[j][i]` for
/// (xs[i], ys[j]) (for tests).
fn heatmap_on(
    root: &Area,
    plot: &HeatmapPlot,
    data: &HeatmapData,
) -> Result<Vec<Vec<(i32, i32)>>, String> {
    let HeatmapData {
        x_rank,
        y_rank,
        x_edges,
        y_edges,
        scale,
        ..
    } = data;
    let scale = *scale;
    let body = titled(root, plot.title)?;
    let (panel, bar_area) = body.split_horizontally(body.dim_in_pixel().0 as i32 - COLOR_BAR_WIDTH);
    let (nx, ny) = (x_rank.len(), y_rank.len());
    let mut chart = sweep_chart(
        &panel,
        (x_edges[0]..x_edges[nx], plot.log_x),
        (y_edges[0]..y_edges[ny], plot.log_y),
        plot.x_label,
        plot.y_label,
        false,
    )?;

    let cell = |i: usize, j: usize| {
        let (c, r) = (x_rank[i], y_rank[j]);
        [(x_edges[c], y_edges[r]), (x_edges[c + 1], y_edges[r + 1])]
    };
    let mut centres = Vec::with_capacity(ny);
    for (j, row) in plot.values.iter().enumerate() {
        let mut row_centres = Vec::with_capacity(nx);
        for (i, &v) in row.iter().enumerate() {
            let [a, b] = cell(i, j);
            let (pa, pb) = (chart.backend_coord(&a), chart.backend_coord(&b));
            row_centres.push(((pa.0 + pb.0) / 2, (pa.1 + pb.1) / 2));
            if let (true, Some(scale)) = (v.is_finite(), scale) {
                let color = value_color(scale_position(v, scale));
                chart
                    .draw_series(std::iter::once(Rectangle::new([a, b], color.filled())))
                    .map_err(msg)?;
            }
        }
        centres.push(row_centres);
    }

    // The values written in the cells when there are few, large enough cells.
    if let Some(scale) = scale {
        let (w, h) = (
            (centres[0].last().unwrap().0 - centres[0][0].0).abs() / (nx.max(2) - 1) as i32,
            (centres.last().unwrap()[0].1 - centres[0][0].1).abs() / (ny.max(2) - 1) as i32,
        );
        let big_enough = |size: i32, n: usize| n == 1 || size >= 60;
        if nx * ny <= 144 && big_enough(w, nx) && big_enough(h, ny) {
            let pos = Pos::new(HPos::Center, VPos::Center);
            for (row, row_centres) in plot.values.iter().zip(&centres) {
                for (&v, &(px, py)) in row.iter().zip(row_centres) {
                    if !v.is_finite() {
                        continue;
                    }
                    let ink = if scale_position(v, scale) < 0.6 {
                        WHITE
                    } else {
                        BLACK
                    };
                    let style = TextStyle::from((FONT, 15).into_font()).color(&ink).pos(pos);
                    root.draw_text(&format_number(v), &style, (px, py))
                        .map_err(msg)?;
                }
            }
        }
    }

    match (scale, &data.bar_range) {
        (Some(scale), Some(range)) => {
            draw_color_bar(&bar_area, scale, range.clone(), plot.value_label)?
        }
        _ => draw_note(
            &chart.plotting_area().strip_coord_spec(),
            "no finite values",
            true,
        )?,
    }
    Ok(centres)
}

/// The colour bar of a heat map: the colormap from `lo` (bottom) to `hi` (top) on the axis
/// `range` (`lo..hi`, or a range around a constant value), labelled `label`, on its right.
fn draw_color_bar(
    area: &Area,
    (lo, hi): (f64, f64),
    range: Range<f64>,
    label: &str,
) -> Result<(), String> {
    let span = range.end - range.start;
    let mut bar = ChartBuilder::on(area)
        .margin(12)
        .margin_left(10)
        .margin_right(6)
        .x_label_area_size(45)
        .right_y_label_area_size(80)
        .build_cartesian_2d(0.0..1.0, range.clone())
        .map_err(msg)?;
    bar.configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .y_desc(shorten(label, 40))
        .label_style((FONT, 16))
        .axis_desc_style((FONT, 20))
        .y_label_formatter(&|v| format_tick(*v, span))
        .y_labels(8)
        .draw()
        .map_err(msg)?;
    if hi > lo {
        const STEPS: usize = 200;
        let step = span / STEPS as f64;
        bar.draw_series((0..STEPS).map(|k| {
            let y0 = range.start + k as f64 * step;
            let color = value_color((k as f64 + 0.5) / STEPS as f64);
            Rectangle::new([(0.0, y0), (1.0, y0 + step)], color.filled())
        }))
        .map_err(msg)?;
    } else {
        // A constant value: its colour across the bar, the axis centred on it.
        bar.draw_series(std::iter::once(Rectangle::new(
            [(0.0, range.start), (1.0, range.end)],
            value_color(0.5).filled(),
        )))
        .map_err(msg)?;
    }
    bar.draw_series(std::iter::once(Rectangle::new(
        [(0.0, range.start), (1.0, range.end)],
        BLACK.mix(0.6).stroke_width(1),
    )))
    .map_err(msg)?;
    Ok(())
}

/// The finite points of a scatter figure (plot coordinates) and the axis ranges.
struct ScatterData {
    points: Vec<(f64, f64)>,
    x_range: Range<f64>,
    y_range: Range<f64>,
}

impl ScatterData {
    fn new(plot: &ScatterPlot) -> Result<ScatterData, String> {
        let points: Vec<(f64, f64)> = plot
            .x
            .iter()
            .zip(plot.y)
            .map(|(&x, &y)| (coord(x, plot.log_x), y))
            .filter(|(x, y)| x.is_finite() && y.is_finite())
            .collect();
        let xs: Vec<f64> = points.iter().map(|p| p.0).collect();
        let ys: Vec<f64> = points.iter().map(|p| p.1).collect();
        let x_range = axis_range(&xs, plot.x_label)?;
        let y_range = axis_range(&ys, plot.y_label)?;
        Ok(ScatterData {
            points,
            x_range,
            y_range,
        })
    }
}

/// The scatter figure drawn on `root`.
fn scatter_on(root: &Area, plot: &ScatterPlot, data: &ScatterData) -> Result<(), String> {
    let points = &data.points;
    let body = titled(root, plot.title)?;
    let mut chart = sweep_chart(
        &body,
        (data.x_range.clone(), plot.log_x),
        (data.y_range.clone(), false),
        plot.x_label,
        plot.y_label,
        true,
    )?;
    let color = tab10(0);
    // Smaller, fainter dots for many members.
    let (radius, alpha) = if points.len() > 2000 {
        (2, 0.35)
    } else {
        (4, 0.65)
    };
    chart
        .draw_series(
            points
                .iter()
                .map(|&p| Circle::new(p, radius, color.mix(alpha).filled())),
        )
        .map_err(msg)?;
    let skipped = plot.x.len() - points.len();
    if skipped > 0 {
        let note = format!(
            "{skipped} of {} members not shown (non-finite value)",
            plot.x.len()
        );
        draw_note(&chart.plotting_area().strip_coord_spec(), &note, false)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests;
