//! The drawing layer shared by the figures: the PNG canvas, a chart with labelled axes, and the
//! lines and bands drawn on it.

use std::fmt::Display;
use std::ops::Range;
use std::path::Path;

use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;

use super::style::{format_tick, shorten, FONT};
use super::PLOT_SIZE;

/// A region of the PNG canvas.
pub(super) type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;
/// A panel with linear x and y axes.
pub(super) type Chart<'a, 'b> =
    ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// Plotters errors become the message of a [`PlotError`](super::PlotError).
pub(super) fn msg<E: Display>(e: E) -> String {
    e.to_string()
}

/// Fills `root` white and titles it: the area below `title` is for the panels.
pub(super) fn figure<'a>(root: &Area<'a>, title: &str) -> Result<Area<'a>, String> {
    root.fill(&WHITE).map_err(msg)?;
    root.titled(&shorten(title, 90), (FONT, 26)).map_err(msg)
}

/// Draws a [`PLOT_SIZE`] figure with `draw` in memory and writes it to `path` as a PNG (RGB,
/// 8 bits), only once it is drawn: a figure that fails leaves no file.
pub(super) fn draw_png(
    path: &Path,
    draw: impl FnOnce(&Area) -> Result<(), String>,
) -> Result<(), String> {
    let (width, height) = PLOT_SIZE;
    let mut pixels = vec![0u8; width as usize * height as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, PLOT_SIZE).into_drawing_area();
        draw(&root)?;
        root.present().map_err(msg)?;
    }
    let file = std::fs::File::create(path).map_err(msg)?;
    let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), width, height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header().map_err(msg)?;
    writer.write_image_data(&pixels).map_err(msg)?;
    writer.finish().map_err(msg)
}

/// A panel on `area` with axis titles, a light grid and at most 10 tick labels per axis.
pub(super) fn build_chart<'a, 'b>(
    area: &'a Area<'b>,
    x_range: Range<f64>,
    y_range: Range<f64>,
    x_desc: &str,
    y_desc: &str,
) -> Result<Chart<'a, 'b>, String> {
    build_chart_with_y_labels(area, x_range, y_range, x_desc, y_desc, 10)
}

/// Like [`build_chart`], with at most `y_labels` tick labels on the y axis.
pub(super) fn build_chart_with_y_labels<'a, 'b>(
    area: &'a Area<'b>,
    x_range: Range<f64>,
    y_range: Range<f64>,
    x_desc: &str,
    y_desc: &str,
    y_labels: usize,
) -> Result<Chart<'a, 'b>, String> {
    let (x_span, y_span) = (x_range.end - x_range.start, y_range.end - y_range.start);
    let mut chart = ChartBuilder::on(area)
        .margin(12)
        .margin_right(20)
        .x_label_area_size(45)
        .y_label_area_size(75)
        .build_cartesian_2d(x_range, y_range)
        .map_err(msg)?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .label_style((FONT, 16))
        .axis_desc_style((FONT, 20))
        .bold_line_style(BLACK.mix(0.12))
        .light_line_style(BLACK.mix(0.04))
        .x_label_formatter(&|v| format_tick(*v, x_span))
        .y_label_formatter(&|v| format_tick(*v, y_span))
        .y_labels(y_labels)
        .draw()
        .map_err(msg)?;
    Ok(chart)
}

/// Draws one line (solid or dashed) through the finite points of `(xs, ys)`; isolated finite
/// points become dots.
pub(super) fn draw_line(
    chart: &mut Chart,
    xs: &[f64],
    ys: &[f64],
    color: RGBColor,
    dashed: bool,
) -> Result<(), String> {
    let style = color.stroke_width(2);
    for run in finite_runs(xs, ys) {
        if run.len() == 1 {
            chart
                .draw_series(std::iter::once(Circle::new(run[0], 3, color.filled())))
                .map_err(msg)?;
        } else if dashed {
            chart
                .draw_series(DashedLineSeries::new(run, 8, 5, style))
                .map_err(msg)?;
        } else {
            chart
                .draw_series(LineSeries::new(run, style))
                .map_err(msg)?;
        }
    }
    Ok(())
}

/// Splits `(x, y)` into the runs of consecutive points where both are finite.
fn finite_runs(xs: &[f64], ys: &[f64]) -> Vec<Vec<(f64, f64)>> {
    let mut runs = Vec::new();
    let mut current = Vec::new();
    for (&x, &y) in xs.iter().zip(ys) {
        if x.is_finite() && y.is_finite() {
            current.push((x, y));
        } else if !current.is_empty() {
            runs.push(std::mem::take(&mut current));
        }
    }
    if !current.is_empty() {
        runs.push(current);
    }
    runs
}

/// Opacity of the quantile bands of [`plot_band`](super::plot_band).
pub(super) const BAND_ALPHA: f64 = 0.2;

/// Fills the band between `lower` and `upper` over the runs of points where `x` and both bounds
/// are finite (a polygon along `upper`, back along `lower`); a run of one point becomes a vertical
/// segment.
pub(super) fn draw_band_area(
    chart: &mut Chart,
    xs: &[f64],
    lower: &[f64],
    upper: &[f64],
    color: RGBColor,
) -> Result<(), String> {
    let mut runs: Vec<Vec<(f64, f64, f64)>> = Vec::new();
    let mut current = Vec::new();
    for ((&x, &lo), &hi) in xs.iter().zip(lower).zip(upper) {
        if x.is_finite() && lo.is_finite() && hi.is_finite() {
            current.push((x, lo, hi));
        } else if !current.is_empty() {
            runs.push(std::mem::take(&mut current));
        }
    }
    if !current.is_empty() {
        runs.push(current);
    }
    for run in runs {
        if run.len() == 1 {
            let (x, lo, hi) = run[0];
            chart
                .draw_series(std::iter::once(PathElement::new(
                    vec![(x, lo), (x, hi)],
                    color.mix(0.5).stroke_width(2),
                )))
                .map_err(msg)?;
            continue;
        }
        let points: Vec<(f64, f64)> = run
            .iter()
            .map(|&(x, _, hi)| (x, hi))
            .chain(run.iter().rev().map(|&(x, lo, _)| (x, lo)))
            .collect();
        chart
            .draw_series(std::iter::once(Polygon::new(
                points,
                color.mix(BAND_ALPHA).filled(),
            )))
            .map_err(msg)?;
    }
    Ok(())
}
