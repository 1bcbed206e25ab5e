//! PNG plots of the macroscopic profiles of one ensemble member, of scalar observables over
//! time, of an ensemble's mean profile with a quantile band, histograms, and the response of a
//! parameter sweep (a mean with its quantile band against one parameter, a heat map over two,
//! a scatter of sampled members), and the figures of a convergence study in N (plotters, bitmap
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
//!
//! Layout: this file holds the public API and its input checks. Each figure is drawn in its own
//! file (`profiles`, `series`, `bands`, `histograms`, `response`) from the shared parts: `style` (font,
//! colours, number formatting), `ranges` (axis ranges), `chart` (canvas, axes, lines, bands) and
//! `legend` (legend column, note box).

use std::path::{Path, PathBuf};

mod bands;
mod chart;
mod convergence;
mod histograms;
mod legend;
mod profiles;
mod ranges;
mod response;
mod sensitivity;
mod series;
mod style;
mod work_precision;

pub use style::register_fonts;

/// Width and height, in pixels, of every PNG written by this module.
pub const PLOT_SIZE: (u32, u32) = (1000, 800);

/// Error from [`plot_profiles`], [`plot_series`], [`plot_band`], [`plot_histogram`],
/// [`plot_response`], [`plot_heatmap`] or [`plot_scatter`].
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

/// Draws the profiles of one member: rho(x) (and rho_star(x), dashed) in the top panel, u(x) in
/// the bottom panel, one line per output time coloured along a viridis-like colormap, with a
/// legend "t = ..." (every k-th time when there are more than 10).
pub fn plot_profiles(path: &Path, plot: &ProfilePlot) -> Result<(), PlotError> {
    checked_draw(path, || check_profiles(plot), || profiles::draw(path, plot))
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
    checked_draw(
        path,
        || check_series(times, series),
        || series::draw(path, title, y_label, times, series),
    )
}

/// Draws an ensemble's mean profile at a few times, each with its quantile band: one panel, one
/// colour per time (the colormap of [`plot_profiles`]), the band `[lower, upper]` as a
/// translucent area, the mean as a solid line and the optional reference dashed, with a legend
/// "t = ..." per time plus an entry for the band. The y axis is [0, 1] when all values lie in
/// it, otherwise fitted to the data.
pub fn plot_band(path: &Path, plot: &BandPlot) -> Result<(), PlotError> {
    checked_draw(path, || check_band(plot), || bands::draw(path, plot))
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
    checked_draw(
        path,
        || check_histogram(edges, counts),
        || histograms::draw(path, title, x_label, edges, counts, note),
    )
}

/// One response's Sobol indices: per key (value, interval low, interval high).
pub struct SensitivityResponse<'a> {
    pub name: &'a str,
    pub first: Vec<(f64, f64, f64)>,
    pub total: Vec<(f64, f64, f64)>,
}

/// The Sobol indices of a study: a panel per response, bars per key.
pub struct SensitivityPlot<'a> {
    pub title: &'a str,
    pub keys: &'a [String],
    pub responses: &'a [SensitivityResponse<'a>],
}

/// Draws the bars of S1 and ST with their intervals, a panel per response.
pub fn plot_sensitivity(path: &Path, plot: &SensitivityPlot) -> Result<(), PlotError> {
    checked_draw(
        path,
        || {
            if plot.keys.is_empty() || plot.responses.is_empty() {
                return Err("no keys or no responses".to_string());
            }
            if plot
                .responses
                .iter()
                .any(|r| r.first.len() != plot.keys.len() || r.total.len() != plot.keys.len())
            {
                return Err("one index per key and response".to_string());
            }
            Ok(())
        },
        || sensitivity::draw(path, plot),
    )
}

/// The response of a one-parameter sweep: a statistic of each of P points against the swept
/// value.
pub struct ResponsePlot<'a> {
    /// Title at the top of the figure.
    pub title: &'a str,
    /// Name of the swept parameter (x axis label), e.g. "mu".
    pub x_label: &'a str,
    /// Name of the response (y axis label), e.g. "time to reach rho = 0.9".
    pub y_label: &'a str,
    /// The swept values, length P, in any order (the points are drawn sorted by x). Points with
    /// a non-finite x are skipped; with `log_x`, finite values must be > 0.
    pub x: &'a [f64],
    /// The response at each point (e.g. the ensemble mean), length P; non-finite values are
    /// skipped.
    pub mean: &'a [f64],
    /// Lower edge of the band (e.g. the 5 % quantile), length P; the band is left out where a
    /// bound is not finite.
    pub lower: &'a [f64],
    /// Upper edge of the band (e.g. the 95 % quantile), length P.
    pub upper: &'a [f64],
    /// Legend label of the band, e.g. "5%-95% of members".
    pub band_label: &'a str,
    /// Logarithmic x axis.
    pub log_x: bool,
}

/// A response over a two-parameter grid, one value per (x, y) cell.
pub struct HeatmapPlot<'a> {
    /// Title at the top of the figure.
    pub title: &'a str,
    /// Name of the parameter along x.
    pub x_label: &'a str,
    /// Name of the parameter along y.
    pub y_label: &'a str,
    /// Name of the value (the colour bar's label).
    pub value_label: &'a str,
    /// The x values of the columns, finite and distinct, in any order (> 0 with `log_x`).
    pub xs: &'a [f64],
    /// The y values of the rows, finite and distinct, in any order (> 0 with `log_y`).
    pub ys: &'a [f64],
    /// `ys.len()` rows of `xs.len()` values: `values[j][i]` belongs to (xs[i], ys[j]).
    /// Non-finite values leave their cell blank.
    pub values: &'a [Vec<f64>],
    /// Logarithmic x axis.
    pub log_x: bool,
    /// Logarithmic y axis.
    pub log_y: bool,
}

/// One dot per member of a sampled design: a response against one parameter.
pub struct ScatterPlot<'a> {
    /// Title at the top of the figure.
    pub title: &'a str,
    /// Name of the parameter (x axis label).
    pub x_label: &'a str,
    /// Name of the response (y axis label).
    pub y_label: &'a str,
    /// Parameter values, one per member (> 0 where finite with `log_x`).
    pub x: &'a [f64],
    /// Responses, one per member; members with a non-finite x or y are skipped (and counted in
    /// a note).
    pub y: &'a [f64],
    /// Logarithmic x axis.
    pub log_x: bool,
}

/// Draws the response of a one-parameter sweep: the points sorted by x, the band
/// `[lower, upper]` as a translucent area, the mean as a line with a marker at each point, with
/// a legend ("mean" and the band label). On a log x axis the ticks are values (powers of ten
/// where the range spans two decades or more).
pub fn plot_response(path: &Path, plot: &ResponsePlot) -> Result<(), PlotError> {
    checked_draw(
        path,
        || check_response(plot),
        || response::draw_response(path, plot),
    )
}

/// Draws a heat map: one cell per (x, y) pair, centred on its values (the cell edges halfway
/// between neighbouring values, in log space on a log axis), coloured by value along the
/// viridis-like colormap of the other figures, with a colour bar giving the scale (the range of
/// the finite values). Cells with a non-finite value are left blank; when the cells are large
/// enough their values are written in them.
pub fn plot_heatmap(path: &Path, plot: &HeatmapPlot) -> Result<(), PlotError> {
    checked_draw(
        path,
        || check_heatmap(plot),
        || response::draw_heatmap(path, plot),
    )
}

/// One line of the work–precision figure: its label, and its runs as (wall time in seconds,
/// error, observed order against the line's previous run).
pub type WorkPrecisionLine = (String, Vec<(f64, f64, Option<f64>)>);

/// The work–precision figure: per scheme, its runs' (wall time, error, observed order) joined
/// by a line, on log–log axes, each run's observed order written beside its point, with the
/// target error as a dashed line. Non-positive or non-finite values are skipped.
pub fn plot_work_precision(
    path: &Path,
    title: &str,
    lines: &[WorkPrecisionLine],
    target: Option<f64>,
) -> Result<(), PlotError> {
    checked_draw(
        path,
        || {
            if lines.is_empty() || lines.iter().all(|(_, p)| p.is_empty()) {
                Err("no runs to draw".to_string())
            } else {
                Ok(())
            }
        },
        || work_precision::draw(path, title, lines, target),
    )
}

/// The RGB colour a heat map (and an x–t map) gives `value` on a colour scale from `lo` to `hi`
/// (the range of its finite values): for checking a picture against its data.
pub fn heatmap_color(value: f64, lo: f64, hi: f64) -> [u8; 3] {
    let c = response::value_color(response::scale_position(value, (lo, hi)));
    [c.0, c.1, c.2]
}

/// Largest number of rows (times) and columns (grid points) of an x–t map: more cells than the
/// picture has pixels only cost drawing time.
pub const MAX_XT_CELLS: (usize, usize) = (400, 250);

/// Evenly spaced indices into 0..count, at most `max`, first and last included.
pub fn thinned_indices(count: usize, max: usize) -> Vec<usize> {
    if count <= max || max < 2 {
        return (0..count).collect();
    }
    let mut v: Vec<usize> = (0..max).map(|k| k * (count - 1) / (max - 1)).collect();
    v.dedup();
    v
}

/// A field's x–t map (space–time picture): `rows[k]` is the field on the grid `x` at
/// `times[k]`, drawn as a heat map with x across and t upwards (thinned to [`MAX_XT_CELLS`]).
/// How a researcher reads a congestion event at a glance.
pub fn plot_xt(
    path: &Path,
    title: &str,
    value_label: &str,
    x: &[f64],
    times: &[f64],
    rows: &[Vec<f64>],
) -> Result<(), PlotError> {
    let ti = thinned_indices(times.len(), MAX_XT_CELLS.0);
    let xi = thinned_indices(x.len(), MAX_XT_CELLS.1);
    let xs: Vec<f64> = xi.iter().map(|&i| x[i]).collect();
    let ys: Vec<f64> = ti.iter().map(|&k| times[k]).collect();
    let values: Vec<Vec<f64>> = ti
        .iter()
        .map(|&k| {
            xi.iter()
                .map(|&i| {
                    rows.get(k)
                        .and_then(|r| r.get(i))
                        .copied()
                        .unwrap_or(f64::NAN)
                })
                .collect()
        })
        .collect();
    plot_heatmap(
        path,
        &HeatmapPlot {
            title,
            x_label: "x",
            y_label: "t",
            value_label,
            xs: &xs,
            ys: &ys,
            values: &values,
            log_x: false,
            log_y: false,
        },
    )
}

/// Draws one dot per member at (x, y), translucent so that overlaps show; the members that
/// were skipped (non-finite x or y) are counted in a note.
pub fn plot_scatter(path: &Path, plot: &ScatterPlot) -> Result<(), PlotError> {
    checked_draw(
        path,
        || check_scatter(plot),
        || response::draw_scatter(path, plot),
    )
}

/// A field at every N of a convergence study, at a few times (one panel each).
pub struct ConvergenceProfilesPlot<'a> {
    /// Title at the top of the figure.
    pub title: &'a str,
    /// Name of the field (y axis label), e.g. "rho".
    pub y_label: &'a str,
    /// Grid, length G.
    pub x: &'a [f64],
    /// The times shown, 1 to 4 (one panel each).
    pub times: &'a [f64],
    /// Legend label of each N, e.g. "N = 400", length K.
    pub labels: &'a [String],
    /// `values[j][k]`: the field at times[j] for labels[k], G values (non-finite values skipped).
    pub values: &'a [Vec<Vec<f64>>],
    /// The extrapolated limit at each time (G values), drawn dashed black.
    pub limit: Option<&'a [Vec<f64>]>,
}

/// Differences between successive N against N, on log–log axes.
pub struct ConvergenceRatePlot<'a> {
    /// Title at the top of the figure.
    pub title: &'a str,
    /// y axis label, e.g. "L1 difference of rho".
    pub y_label: &'a str,
    /// The finer N of each pair, length K − 1.
    pub n: &'a [f64],
    /// The difference of each pair (values <= 0 or non-finite are skipped).
    pub diff: &'a [f64],
    /// The fitted line diff = C N^-p as (p, log10 C), drawn dashed.
    pub fit: Option<(f64, f64)>,
    /// Text in a box in the top right corner (e.g. the rates), may be empty.
    pub note: &'a str,
}

/// Draws a field at every N over x: one panel per time (up to 4, in a 2 × 2 grid), one line
/// per N coloured along the sequential colormap (small N dark), the optional extrapolated limit
/// dashed black, and a legend of the N.
pub fn plot_convergence_profiles(
    path: &Path,
    plot: &ConvergenceProfilesPlot,
) -> Result<(), PlotError> {
    checked_draw(
        path,
        || check_convergence_profiles(plot),
        || convergence::draw_profiles(path, plot),
    )
}

/// Draws differences between successive N against N on log–log axes (a line with a marker per
/// pair) with the fitted rate as a dashed line and the note in the top right corner.
pub fn plot_convergence_rate(path: &Path, plot: &ConvergenceRatePlot) -> Result<(), PlotError> {
    checked_draw(
        path,
        || {
            if plot.n.is_empty() {
                return Err("there are no pairs (n is empty)".to_string());
            }
            check_length("diff", plot.diff, plot.n.len(), "n")?;
            check_log_axis("n", plot.n, true)
        },
        || convergence::draw_rate(path, plot),
    )
}

/// The steps shared by the public plotting functions: check the input, make sure the font is
/// registered, draw; the first failure becomes a [`PlotError`] naming the file.
fn checked_draw(
    path: &Path,
    check: impl FnOnce() -> Result<(), String>,
    draw: impl FnOnce() -> Result<(), String>,
) -> Result<(), PlotError> {
    check()
        .and_then(|()| register_fonts())
        .and_then(|()| draw())
        .map_err(|message| PlotError {
            path: path.to_path_buf(),
            message,
        })
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

fn check_length(name: &str, values: &[f64], n: usize, of: &str) -> Result<(), String> {
    if values.len() != n {
        return Err(format!(
            "{name} has {} values but {of} has {n}",
            values.len()
        ));
    }
    Ok(())
}

/// With a log axis, the finite values must be positive.
fn check_log_axis(name: &str, values: &[f64], log: bool) -> Result<(), String> {
    if !log {
        return Ok(());
    }
    match values.iter().position(|&v| v.is_finite() && v <= 0.0) {
        Some(i) => Err(format!(
            "{name}[{i}] = {} cannot be drawn on a log axis (allowed: values > 0)",
            values[i]
        )),
        None => Ok(()),
    }
}

/// Finite and distinct values (the positions of heat map cells).
fn check_cell_positions(name: &str, values: &[f64], log: bool) -> Result<(), String> {
    if values.is_empty() {
        return Err(format!("{name} is empty"));
    }
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        return Err(format!("{name}[{i}] is not finite ({})", values[i]));
    }
    check_log_axis(name, values, log)?;
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    if let Some(w) = sorted.windows(2).find(|w| w[0] == w[1]) {
        return Err(format!(
            "{name} holds {} twice (allowed: distinct values)",
            w[0]
        ));
    }
    Ok(())
}

fn check_response(plot: &ResponsePlot) -> Result<(), String> {
    let n = plot.x.len();
    if n == 0 {
        return Err("there are no points (x is empty)".to_string());
    }
    check_length("mean", plot.mean, n, "x")?;
    check_length("lower", plot.lower, n, "x")?;
    check_length("upper", plot.upper, n, "x")?;
    check_log_axis("x", plot.x, plot.log_x)
}

fn check_heatmap(plot: &HeatmapPlot) -> Result<(), String> {
    check_cell_positions("xs", plot.xs, plot.log_x)?;
    check_cell_positions("ys", plot.ys, plot.log_y)?;
    if plot.values.len() != plot.ys.len() {
        return Err(format!(
            "values has {} rows but ys has {} values (one row per y)",
            plot.values.len(),
            plot.ys.len()
        ));
    }
    match plot
        .values
        .iter()
        .position(|row| row.len() != plot.xs.len())
    {
        Some(j) => Err(format!(
            "values row {j} has {} values but xs has {}",
            plot.values[j].len(),
            plot.xs.len()
        )),
        None => Ok(()),
    }
}

fn check_scatter(plot: &ScatterPlot) -> Result<(), String> {
    if plot.x.is_empty() {
        return Err("there are no points (x is empty)".to_string());
    }
    check_length("y", plot.y, plot.x.len(), "x")?;
    check_log_axis("x", plot.x, plot.log_x)
}

fn check_convergence_profiles(plot: &ConvergenceProfilesPlot) -> Result<(), String> {
    if plot.x.is_empty() {
        return Err("the grid x is empty".to_string());
    }
    if plot.times.is_empty() || plot.times.len() > 4 {
        return Err(format!(
            "{} times to show (allowed: 1 to 4 panels)",
            plot.times.len()
        ));
    }
    if plot.labels.is_empty() {
        return Err("there are no N to show (labels is empty)".to_string());
    }
    if plot.values.len() != plot.times.len() {
        return Err(format!(
            "values has {} rows but there are {} times",
            plot.values.len(),
            plot.times.len()
        ));
    }
    for rows in plot.values {
        check_rows("values", rows, plot.labels.len(), plot.x.len())?;
    }
    if let Some(limit) = plot.limit {
        check_rows("limit", limit, plot.times.len(), plot.x.len())?;
    }
    Ok(())
}
