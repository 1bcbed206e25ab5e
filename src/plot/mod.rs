//! PNG plots of the macroscopic profiles of one ensemble member, of scalar observables over
//! time, of an ensemble's mean profile with a quantile band, and histograms (plotters, bitmap
//! backend).
//!
//! Text is rendered with plotters' `ab_glyph` feature, which does not look for system fonts: the
//! DejaVu Sans font shipped in `assets/` is embedded in the binary and registered on first use
//! (see [`register_fonts`]).
//!
//! Every plot is a [`PLOT_SIZE`] PNG. The path should end in `.png` (the encoder picks the format
//! from the extension). Bad input (empty or mismatched arrays) gives a [`PlotError`], never a
//! panic; non-finite values (a failed member's rows after its failure) are skipped, breaking the
//! line where they occur.

use std::fmt::Display;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// Width and height, in pixels, of every PNG written by this module.
pub const PLOT_SIZE: (u32, u32) = (1000, 800);

/// Error from [`plot_profiles`], [`plot_series`], [`plot_band`] or [`plot_histogram`].
#[derive(Debug, thiserror::Error)]
#[error("cannot draw plot {path}: {message}")]
pub struct PlotError {
    pub path: PathBuf,
    pub message: String,
}

/// One member's macroscopic profiles at several output times.
pub struct ProfilePlot<'a> {
    /// Title at the top of the figure, e.g. "case1 — member 0 (mu = 0.01, gamma = 1)".
    pub title: &'a str,
    /// Grid, length G, in [0, 1].
    pub x: &'a [f64],
    /// Output times, length T.
    pub times: &'a [f64],
    /// Density: T rows of G values (non-finite values are skipped).
    pub rho: &'a [Vec<f64>],
    /// Velocity: T rows of G values (non-finite values are skipped).
    pub u: &'a [Vec<f64>],
    /// Rough-contact density: T rows of G values, when the model has roughness (drawn dashed).
    pub rho_star: Option<&'a [Vec<f64>]>,
}

/// Mean of a field over an ensemble with a quantile band, at a few times.
pub struct BandPlot<'a> {
    /// Title at the top of the figure.
    pub title: &'a str,
    /// Name of the field, used as the y axis label, e.g. "rho".
    pub y_label: &'a str,
    /// Grid, length G.
    pub x: &'a [f64],
    /// The times shown (one curve and one band each), length T (a handful: the colours of more
    /// than about 6 are hard to tell apart).
    pub times: &'a [f64],
    /// Ensemble mean: T rows of G values (non-finite values are skipped).
    pub mean: &'a [Vec<f64>],
    /// Lower edge of the band (e.g. the 5 % quantile): T rows of G values. The band is left out
    /// where a bound or x is not finite.
    pub lower: &'a [Vec<f64>],
    /// Upper edge of the band (e.g. the 95 % quantile): T rows of G values.
    pub upper: &'a [Vec<f64>],
    /// Legend label of the band, e.g. "5%-95% of members".
    pub band_label: &'a str,
    /// Optional reference curves (e.g. the mean of rho*), T rows of G values, drawn dashed in the
    /// colour of their time and labelled "reference" in the legend.
    pub reference: Option<&'a [Vec<f64>]>,
}

const FONT: &str = "sans-serif";
const FONT_BYTES: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");

/// Registers the embedded DejaVu Sans font with plotters (once per process) under the family
/// names "sans-serif", "serif" and "monospace", so that any plotters text can be rendered.
/// Called by the plotting functions of this module; other code drawing text with plotters
/// must call it first.
pub fn register_fonts() -> Result<(), String> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        ["sans-serif", "serif", "monospace"]
            .iter()
            .all(|name| plotters::style::register_font(name, FontStyle::Normal, FONT_BYTES).is_ok())
    });
    if ok {
        Ok(())
    } else {
        Err("the embedded font assets/DejaVuSans.ttf could not be loaded".to_string())
    }
}

/// Draws the profiles of one member: rho(x) (and rho_star(x), dashed) in the top panel, u(x) in
/// the bottom panel, one line per output time coloured along a viridis-like colormap, with a
/// legend "t = ..." (every k-th time when there are more than 10).
pub fn plot_profiles(path: &Path, plot: &ProfilePlot) -> Result<(), PlotError> {
    let err = |message: String| PlotError {
        path: path.to_path_buf(),
        message,
    };
    check_profiles(plot).map_err(err)?;
    register_fonts().map_err(err)?;
    draw_profiles(path, plot).map_err(err)
}

/// Draws a scalar observable of several members over time (e.g. the maximum density of each
/// member): one line per `(label, values)` series, `values` having one entry per output time,
/// with a legend of the labels. Non-finite values are skipped.
pub fn plot_series(
    path: &Path,
    title: &str,
    y_label: &str,
    times: &[f64],
    series: &[(String, Vec<f64>)],
) -> Result<(), PlotError> {
    let err = |message: String| PlotError {
        path: path.to_path_buf(),
        message,
    };
    check_series(times, series).map_err(err)?;
    register_fonts().map_err(err)?;
    draw_series(path, title, y_label, times, series).map_err(err)
}

/// Draws an ensemble's mean profile at a few times, each with its quantile band: one panel, one
/// colour per time (the colormap of [`plot_profiles`]), the band `[lower, upper]` as a
/// translucent area, the mean as a solid line and the optional reference dashed, with a legend
/// "t = ..." per time plus an entry for the band. The y axis is [0, 1] when all values lie in
/// it, otherwise fitted to the data.
pub fn plot_band(path: &Path, plot: &BandPlot) -> Result<(), PlotError> {
    let err = |message: String| PlotError {
        path: path.to_path_buf(),
        message,
    };
    check_band(plot).map_err(err)?;
    register_fonts().map_err(err)?;
    draw_band(path, plot).map_err(err)
}

/// Draws a histogram: one bar per bin `[edges[i], edges[i + 1])` of height `counts[i]`, the
/// count axis starting at 0, and the optional `note` (e.g. "12 members never reached 0.9") in a
/// top corner of the panel. `edges` must be finite and strictly increasing, with one more entry
/// than `counts`.
pub fn plot_histogram(
    path: &Path,
    title: &str,
    x_label: &str,
    edges: &[f64],
    counts: &[u64],
    note: Option<&str>,
) -> Result<(), PlotError> {
    let err = |message: String| PlotError {
        path: path.to_path_buf(),
        message,
    };
    check_histogram(edges, counts).map_err(err)?;
    register_fonts().map_err(err)?;
    draw_histogram(path, title, x_label, edges, counts, note).map_err(err)
}

// ---------------------------------------------------------------------------------------------
// Input checks
// ---------------------------------------------------------------------------------------------

fn check_rows(name: &str, rows: &[Vec<f64>], n_times: usize, n_x: usize) -> Result<(), String> {
    if rows.len() != n_times {
        return Err(format!(
            "{name} has {} rows but there are {n_times} output times",
            rows.len()
        ));
    }
    for (i, row) in rows.iter().enumerate() {
        if row.len() != n_x {
            return Err(format!(
                "{name} row {i} has {} values but the grid x has {n_x} points",
                row.len()
            ));
        }
    }
    Ok(())
}

fn check_profiles(plot: &ProfilePlot) -> Result<(), String> {
    if plot.x.is_empty() {
        return Err("the grid x is empty".to_string());
    }
    if plot.times.is_empty() {
        return Err("there are no output times".to_string());
    }
    let (t, g) = (plot.times.len(), plot.x.len());
    check_rows("rho", plot.rho, t, g)?;
    check_rows("u", plot.u, t, g)?;
    if let Some(rho_star) = plot.rho_star {
        check_rows("rho_star", rho_star, t, g)?;
    }
    Ok(())
}

fn check_series(times: &[f64], series: &[(String, Vec<f64>)]) -> Result<(), String> {
    if times.is_empty() {
        return Err("there are no output times".to_string());
    }
    if series.is_empty() {
        return Err("there are no series to plot".to_string());
    }
    for (label, values) in series {
        if values.len() != times.len() {
            return Err(format!(
                "series \"{label}\" has {} values but there are {} output times",
                values.len(),
                times.len()
            ));
        }
    }
    Ok(())
}

fn check_band(plot: &BandPlot) -> Result<(), String> {
    if plot.x.is_empty() {
        return Err("the grid x is empty".to_string());
    }
    if plot.times.is_empty() {
        return Err("there are no times to show".to_string());
    }
    let (t, g) = (plot.times.len(), plot.x.len());
    check_rows("mean", plot.mean, t, g)?;
    check_rows("lower", plot.lower, t, g)?;
    check_rows("upper", plot.upper, t, g)?;
    if let Some(reference) = plot.reference {
        check_rows("reference", reference, t, g)?;
    }
    Ok(())
}

fn check_histogram(edges: &[f64], counts: &[u64]) -> Result<(), String> {
    if counts.is_empty() {
        return Err("the histogram has no bins (counts is empty)".to_string());
    }
    if edges.len() != counts.len() + 1 {
        return Err(format!(
            "the histogram has {} bin edges but {} counts (it needs one edge more than counts)",
            edges.len(),
            counts.len()
        ));
    }
    if let Some(i) = edges.iter().position(|e| !e.is_finite()) {
        return Err(format!("bin edge {i} is not finite ({})", edges[i]));
    }
    if let Some(i) = edges.windows(2).position(|w| w[1] <= w[0]) {
        return Err(format!(
            "the bin edges are not strictly increasing (edge {} = {} is not above edge {i} = {})",
            i + 1,
            edges[i + 1],
            edges[i]
        ));
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Helpers
// ---------------------------------------------------------------------------------------------

fn msg<E: Display>(e: E) -> String {
    e.to_string()
}

/// Control points of matplotlib's viridis colormap at 0, 1/8, ..., 1.
const VIRIDIS: [(u8, u8, u8); 9] = [
    (68, 1, 84),
    (71, 44, 122),
    (59, 81, 139),
    (44, 113, 142),
    (33, 144, 141),
    (39, 173, 129),
    (92, 200, 99),
    (170, 220, 50),
    (253, 231, 37),
];

/// Viridis-like colour at `s` in [0, 1]; the light yellow end is left out so that every line
/// stays visible on white.
fn sequential_color(s: f64) -> RGBColor {
    let s = if s.is_finite() {
        s.clamp(0.0, 1.0)
    } else {
        0.0
    } * 0.88;
    let pos = s * (VIRIDIS.len() - 1) as f64;
    let i = (pos.floor() as usize).min(VIRIDIS.len() - 2);
    let f = pos - i as f64;
    let (a, b) = (VIRIDIS[i], VIRIDIS[i + 1]);
    let mix = |p: u8, q: u8| (p as f64 + f * (q as f64 - p as f64)).round() as u8;
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

/// Colour of line `i` out of `n` along the sequential colormap.
fn indexed_color(i: usize, n: usize) -> RGBColor {
    if n <= 1 {
        sequential_color(0.0)
    } else {
        sequential_color(i as f64 / (n - 1) as f64)
    }
}

/// Categorical palette (matplotlib's tab10) for a few unrelated series.
const TAB10: [(u8, u8, u8); 10] = [
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
    (188, 189, 34),
    (23, 190, 207),
];

/// Indices of the lines given a legend entry: all of them up to `max_entries`, otherwise every
/// k-th one and the last one.
fn legend_indices(n: usize, max_entries: usize) -> Vec<usize> {
    let max_entries = max_entries.max(2);
    if n <= max_entries {
        return (0..n).collect();
    }
    let k = n.div_ceil(max_entries - 1);
    let mut idx: Vec<usize> = (0..n).step_by(k).collect();
    if idx.last() != Some(&(n - 1)) {
        idx.push(n - 1);
    }
    idx
}

/// Short decimal form of a number: about four significant digits, trailing zeros removed.
fn format_number(v: f64) -> String {
    if !v.is_finite() {
        return format!("{v}");
    }
    if v == 0.0 {
        return "0".to_string();
    }
    let a = v.abs();
    if (1e-3..1e5).contains(&a) {
        let decimals = (3 - a.log10().floor() as i32).max(0) as usize;
        let s = format!("{v:.decimals$}");
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    } else {
        let s = format!("{v:.3e}");
        match s.split_once('e') {
            Some((mantissa, exp)) if mantissa.contains('.') => format!(
                "{}e{exp}",
                mantissa.trim_end_matches('0').trim_end_matches('.')
            ),
            _ => s,
        }
    }
}

/// Tick label: like [`format_number`], with rounding noise around zero (relative to the axis
/// span) shown as 0.
fn format_tick(v: f64, span: f64) -> String {
    if v.abs() <= 1e-9 * span.abs() {
        "0".to_string()
    } else {
        format_number(v)
    }
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

/// Range of the finite values, if any.
fn finite_min_max<'a>(values: impl IntoIterator<Item = &'a f64>) -> Option<(f64, f64)> {
    values
        .into_iter()
        .copied()
        .filter(|v| v.is_finite())
        .fold(None, |acc, v| match acc {
            None => Some((v, v)),
            Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
        })
}

/// Axis range covering `[lo, hi]` with symmetric padding (5 % of the span, or 10 % of the
/// magnitude for (nearly) constant data, or [-1, 1] around zero for all-zero data).
fn padded_range(min_max: Option<(f64, f64)>, what: &str) -> Result<Range<f64>, String> {
    let Some((lo, hi)) = min_max else {
        return Ok(-1.0..1.0);
    };
    let span = hi - lo;
    let scale = lo.abs().max(hi.abs());
    let pad = if span > scale * 1e-9 {
        0.05 * span
    } else if scale > 1e-200 {
        0.1 * scale
    } else {
        1.0
    };
    let (a, b) = (lo - pad, hi + pad);
    if !(span.is_finite() && a.is_finite() && b.is_finite() && a < b) {
        return Err(format!(
            "the values of {what} (from {lo:e} to {hi:e}) are too large to plot"
        ));
    }
    Ok(a..b)
}

/// Axis range `[lo, hi]` extended (with padding) to hold the finite data if it goes beyond.
fn range_including(
    lo: f64,
    hi: f64,
    min_max: Option<(f64, f64)>,
    what: &str,
) -> Result<Range<f64>, String> {
    let Some((dlo, dhi)) = min_max else {
        return Ok(lo..hi);
    };
    if dlo >= lo && dhi <= hi {
        return Ok(lo..hi);
    }
    padded_range(Some((dlo.min(lo), dhi.max(hi))), what)
}

type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;
type Chart<'a, 'b> =
    ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

fn build_chart<'a, 'b>(
    area: &'a Area<'b>,
    x_range: Range<f64>,
    y_range: Range<f64>,
    x_desc: &str,
    y_desc: &str,
) -> Result<Chart<'a, 'b>, String> {
    build_chart_with_y_labels(area, x_range, y_range, x_desc, y_desc, 10)
}

/// Like [`build_chart`], with at most `y_labels` tick labels on the y axis.
fn build_chart_with_y_labels<'a, 'b>(
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
fn draw_line(
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

/// One legend entry: a short sample (line, dashed line or translucent band) and a label.
struct LegendEntry {
    label: String,
    color: RGBColor,
    mark: LegendMark,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum LegendMark {
    Line,
    Dashed,
    Band,
}

const LEGEND_ROW: i32 = 24;

/// Draws the legend entries in a column of `area`, starting `top` pixels from its top.
fn draw_legend(area: &Area, top: i32, title: &str, entries: &[LegendEntry]) -> Result<(), String> {
    let text = TextStyle::from((FONT, 17).into_font()).pos(Pos::new(HPos::Left, VPos::Center));
    let x0 = 8;
    let mut y = top;
    if !title.is_empty() {
        area.draw_text(title, &text, (x0, y)).map_err(msg)?;
        y += LEGEND_ROW;
    }
    for entry in entries {
        let style = entry.color.stroke_width(2);
        match entry.mark {
            LegendMark::Dashed => {
                for k in 0..3 {
                    let a = x0 + 12 * k;
                    area.draw(&PathElement::new(vec![(a, y), (a + 7, y)], style))
                        .map_err(msg)?;
                }
            }
            LegendMark::Line => {
                area.draw(&PathElement::new(vec![(x0, y), (x0 + 31, y)], style))
                    .map_err(msg)?;
            }
            LegendMark::Band => {
                let corners = [(x0, y - 7), (x0 + 31, y + 7)];
                area.draw(&Rectangle::new(
                    corners,
                    entry.color.mix(BAND_ALPHA).filled(),
                ))
                .map_err(msg)?;
                area.draw(&Rectangle::new(
                    corners,
                    entry.color.mix(0.5).stroke_width(1),
                ))
                .map_err(msg)?;
            }
        }
        area.draw_text(&entry.label, &text, (x0 + 42, y))
            .map_err(msg)?;
        y += LEGEND_ROW;
    }
    Ok(())
}

/// Shortens a legend label to at most `max_chars` characters.
fn shorten(label: &str, max_chars: usize) -> String {
    if label.chars().count() <= max_chars {
        label.to_string()
    } else {
        let mut s: String = label.chars().take(max_chars.saturating_sub(1)).collect();
        s.push('…');
        s
    }
}

/// Opacity of the quantile bands of [`plot_band`].
const BAND_ALPHA: f64 = 0.2;

/// Fills the band between `lower` and `upper` over the runs of points where `x` and both bounds
/// are finite (a polygon along `upper`, back along `lower`); a run of one point becomes a vertical
/// segment.
fn draw_band_area(
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

/// Width of a legend column holding `labels`: the widest label plus the sample, within
/// `[min, 400]` pixels.
fn legend_width(area: &Area, labels: &[&str], min: i32) -> Result<i32, String> {
    let style = TextStyle::from((FONT, 17).into_font());
    let widest = labels
        .iter()
        .map(|l| area.estimate_text_size(l, &style).map(|(w, _)| w))
        .try_fold(0u32, |acc, w| w.map(|w| acc.max(w)))
        .map_err(msg)?;
    Ok((widest.min(1000) as i32 + 60).clamp(min, 400))
}

// ---------------------------------------------------------------------------------------------
// Figures
// ---------------------------------------------------------------------------------------------

fn draw_profiles(path: &Path, plot: &ProfilePlot) -> Result<(), String> {
    let n_times = plot.times.len();

    let x_range = range_including(0.0, 1.0, finite_min_max(plot.x), "x")?;
    let rho_values = plot
        .rho
        .iter()
        .chain(plot.rho_star.into_iter().flatten())
        .flatten();
    let rho_range = range_including(0.0, 1.0, finite_min_max(rho_values), "rho")?;
    let u_range = padded_range(finite_min_max(plot.u.iter().flatten()), "u")?;

    let root = BitMapBackend::new(path, PLOT_SIZE).into_drawing_area();
    root.fill(&WHITE).map_err(msg)?;
    let body = root
        .titled(&shorten(plot.title, 90), (FONT, 26))
        .map_err(msg)?;
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

    root.present().map_err(msg)
}

fn draw_series(
    path: &Path,
    title: &str,
    y_label: &str,
    times: &[f64],
    series: &[(String, Vec<f64>)],
) -> Result<(), String> {
    let n = series.len();
    let color = |i: usize| {
        if n <= TAB10.len() {
            let (r, g, b) = TAB10[i];
            RGBColor(r, g, b)
        } else {
            indexed_color(i, n)
        }
    };

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

    let root = BitMapBackend::new(path, PLOT_SIZE).into_drawing_area();
    root.fill(&WHITE).map_err(msg)?;
    let body = root.titled(&shorten(title, 90), (FONT, 26)).map_err(msg)?;

    const MAX_LABEL: usize = 32;
    let labels: Vec<String> = series.iter().map(|(l, _)| shorten(l, MAX_LABEL)).collect();
    let label_style = TextStyle::from((FONT, 17).into_font());
    let widest = labels
        .iter()
        .map(|l| body.estimate_text_size(l, &label_style).map(|(w, _)| w))
        .try_fold(0u32, |acc, w| w.map(|w| acc.max(w)))
        .map_err(msg)?;
    let legend_width = (widest as i32 + 60).clamp(120, 400);
    let (panel, legend_area) = body.split_horizontally(body.dim_in_pixel().0 as i32 - legend_width);

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

    root.present().map_err(msg)
}

fn draw_band(path: &Path, plot: &BandPlot) -> Result<(), String> {
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

    let root = BitMapBackend::new(path, PLOT_SIZE).into_drawing_area();
    root.fill(&WHITE).map_err(msg)?;
    let body = root
        .titled(&shorten(plot.title, 90), (FONT, 26))
        .map_err(msg)?;

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

    root.present().map_err(msg)
}

fn draw_histogram(
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

    let root = BitMapBackend::new(path, PLOT_SIZE).into_drawing_area();
    root.fill(&WHITE).map_err(msg)?;
    let body = root.titled(&shorten(title, 90), (FONT, 26)).map_err(msg)?;
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

    root.present().map_err(msg)
}

/// Writes `note` (one line per line of the text, at most 6) in a framed white box in the top left
/// or top right corner of `area`.
fn draw_note(area: &Area, note: &str, left: bool) -> Result<(), String> {
    let lines: Vec<String> = note.lines().take(6).map(|l| shorten(l, 80)).collect();
    if lines.is_empty() {
        return Ok(());
    }
    let style = TextStyle::from((FONT, 18).into_font()).pos(Pos::new(HPos::Left, VPos::Top));
    let widest = lines
        .iter()
        .map(|l| area.estimate_text_size(l, &style).map(|(w, _)| w))
        .try_fold(0u32, |acc, w| w.map(|w| acc.max(w)))
        .map_err(msg)?
        .min(2000) as i32;
    let (pad, row, margin) = (8, 24, 10);
    let (w, h) = (widest + 2 * pad, row * lines.len() as i32 + 2 * pad - 8);
    let area_w = area.dim_in_pixel().0 as i32;
    let x0 = if left {
        margin
    } else {
        (area_w - margin - w).max(margin)
    };
    let (y0, corners) = (margin, [(x0, margin), (x0 + w, margin + h)]);
    area.draw(&Rectangle::new(corners, WHITE.mix(0.9).filled()))
        .map_err(msg)?;
    area.draw(&Rectangle::new(corners, BLACK.mix(0.4).stroke_width(1)))
        .map_err(msg)?;
    for (k, line) in lines.iter().enumerate() {
        area.draw_text(line, &style, (x0 + pad, y0 + pad + row * k as i32))
            .map_err(msg)?;
    }
    Ok(())
}
