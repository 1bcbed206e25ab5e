//! The report of a study: `stats/*.npy` and `plots/*.png` from its merged [`StudyState`], and
//! the manifest's description of how the quantiles were computed.

use std::path::Path;

use rayon::prelude::*;

use super::files::StudyHeader;
use super::state::{PointStats, StudyState};
use super::{SCALARS, SCALAR_ALPHA, SCALAR_BINS};
use crate::error::{Error, Result};
use crate::output::manifest::QuantileMethod;
use crate::output::write_npy;
use crate::stats::{ScalarSummary, StatsError};

/// How the study's quantiles and histograms are computed, for the manifest.
pub(super) fn quantile_method(header: &StudyHeader) -> QuantileMethod {
    QuantileMethod {
        scalars: format!("DDSketch, relative accuracy alpha = {SCALAR_ALPHA}: the value reported for level q is within alpha |x| of the sample x of rank floor(q (n-1)); merging shards is exact"),
        fields: "per grid point, a histogram of the given bins on the field's range: the midpoint of the bin holding the sample of rank floor(q (n-1)), within half a bin width of it; NaN where that sample lies outside the range",
        field_ranges: header.field_ranges.clone(),
        bins: header.bins,
        scalar_histograms: format!("{SCALAR_BINS} bins over each time's [min, max], filled from the sketch (each value placed within alpha |x|)"),
    }
}

/// Writes `stats/*.npy` (every statistic with a leading sweep-point axis P), `points.csv` and
/// the plots (`members.csv` is streamed by the caller).
pub(super) fn finalize(
    dir: &Path,
    headers: &[StudyHeader],
    state: &StudyState,
    plots: bool,
) -> Result<()> {
    let header = &headers[0];
    let stats = dir.join("stats");
    std::fs::create_dir_all(&stats).map_err(|e| Error::io(&stats, e))?;
    let t = header.times.len() as u64;
    let g = header.x.len() as u64;
    let qs = &header.quantiles;
    let nq = qs.len() as u64;
    let p_count = header.points.len().max(1) as u64;
    write_npy(stats.join("times.npy"), &[t], &header.times)?;
    write_npy(stats.join("x.npy"), &[g], &header.x)?;
    write_npy(stats.join("quantile_levels.npy"), &[nq], qs)?;
    write_points_csv(&dir.join("points.csv"), header, state)?;
    // A point without members (a partial merge) reports the statistics of no member; empty
    // statistics are built only for such points.
    let empty: std::collections::BTreeMap<u64, PointStats> = (0..p_count)
        .filter(|p| !state.points.contains_key(p))
        .map(|p| Ok((p, PointStats::for_header(header, p)?)))
        .collect::<Result<_>>()?;
    let point = |p: u64| -> &PointStats {
        state
            .points
            .get(&p)
            .or_else(|| empty.get(&p))
            .expect("built when a point has no statistics")
    };
    let points: Vec<u64> = (0..p_count).collect();
    // The per-time statistics (scalars at every time, field bands) cover the detailed points,
    // 0..D: their leading axis is D.
    let d_count = header.detailed_count();
    let detailed: Vec<u64> = (0..d_count).collect();
    write_npy(
        stats.join("detailed_points.npy"),
        &[d_count],
        &detailed.iter().map(|&p| p as f64).collect::<Vec<_>>(),
    )?;

    // Independent files, written side by side: a small design's report is mostly files
    // created and its few detailed points' bands read. Without detailed points the per-time
    // files would hold nothing: they are not written (65 empty files were a tenth of a
    // 64-point design's time).
    let (per_time, (responses, bands)) = rayon::join(
        || match d_count {
            0 => Ok(()),
            _ => write_scalars_per_time(&stats, header, &detailed, &point),
        },
        || {
            rayon::join(
                || {
                    write_responses(&stats, header, &points, &point)?;
                    super::sensitivity::write_sensitivity(dir, header, state, plots)
                },
                || match d_count {
                    0 => Ok(()),
                    _ => write_bands(&stats, header, &detailed, &point),
                },
            )
        },
    );
    per_time?;
    responses?;
    bands?;
    if plots {
        let plots_dir = dir.join("plots");
        std::fs::create_dir_all(&plots_dir).map_err(|e| Error::io(&plots_dir, e))?;
        if p_count == 1 {
            if d_count == 1 {
                write_point_plots(&plots_dir, "", header, point(0))?;
            }
        } else {
            write_response_plots(dir, &plots_dir, header, &point)?;
            for &p in detailed.iter().take(MAX_POINT_PLOTS) {
                if state.points.contains_key(&p) {
                    write_point_plots(&plots_dir, &format!("point{p}_"), header, point(p))?;
                }
            }
        }
    }
    Ok(())
}

/// Statistics of a study's points, by point index (every point has them, empty where no member
/// reached it).
type PointOf<'a> = dyn Fn(u64) -> &'a PointStats + Sync + 'a;

/// The scalars at every output time of the detailed points: `stats/{scalar}_{count,mean,var,
/// min,max}.npy` [D, T], `_quantiles.npy` [D, T, Q] and the histograms.
fn write_scalars_per_time<'a>(
    stats: &Path,
    header: &StudyHeader,
    detailed: &[u64],
    point: &PointOf<'a>,
) -> Result<()> {
    let (d_count, t) = (detailed.len() as u64, header.times.len() as u64);
    let qs = &header.quantiles;
    let nq = qs.len() as u64;
    SCALARS.par_iter().try_for_each(|&name| -> Result<()> {
        let per_point = |f: &dyn Fn(&ScalarSummary) -> f64| -> Vec<f64> {
            detailed
                .iter()
                .flat_map(|&p| point(p).scalars[name].iter().map(f).collect::<Vec<_>>())
                .collect()
        };
        let shape = [d_count, t];
        write_npy(
            stats.join(format!("{name}_count.npy")),
            &shape,
            &per_point(&|s| s.stats().count() as f64),
        )?;
        write_npy(
            stats.join(format!("{name}_mean.npy")),
            &shape,
            &per_point(&|s| s.stats().mean()),
        )?;
        write_npy(
            stats.join(format!("{name}_var.npy")),
            &shape,
            &per_point(&|s| s.stats().variance()),
        )?;
        write_npy(
            stats.join(format!("{name}_min.npy")),
            &shape,
            &per_point(&|s| s.stats().min()),
        )?;
        write_npy(
            stats.join(format!("{name}_max.npy")),
            &shape,
            &per_point(&|s| s.stats().max()),
        )?;
        let quant: Vec<f64> = detailed
            .iter()
            .flat_map(|&p| point(p).scalars[name].iter())
            .flat_map(|s| qs.iter().map(|&q| s.quantile(q).unwrap_or(f64::NAN)))
            .collect();
        write_npy(
            stats.join(format!("{name}_quantiles.npy")),
            &[d_count, t, nq],
            &quant,
        )?;
        let (mut edges, mut counts) = (Vec::new(), Vec::new());
        for &p in detailed {
            let (e, c) = scalar_histograms(&point(p).scalars[name], stats)?;
            edges.extend(e);
            counts.extend(c);
        }
        write_npy(
            stats.join(format!("{name}_hist_edges.npy")),
            &[d_count, t, SCALAR_BINS as u64 + 1],
            &edges,
        )?;
        write_npy(
            stats.join(format!("{name}_hist_counts.npy")),
            &[d_count, t, SCALAR_BINS as u64],
            &counts,
        )?;
        Ok(())
    })
}

/// Each member's responses summarised per point (every point): `stats/first_hit.npy` [P, 6],
/// `stats/{peak_density,smallest_gap,final_energy}.npy` [P, 5] and their `_quantiles.npy` [P, Q].
fn write_responses<'a>(
    stats: &Path,
    header: &StudyHeader,
    points: &[u64],
    point: &PointOf<'a>,
) -> Result<()> {
    let p_count = points.len() as u64;
    let qs = &header.quantiles;
    let nq = qs.len() as u64;
    let mut first_hit = Vec::with_capacity(points.len() * 6);
    let mut first_hit_q = Vec::with_capacity(points.len() * qs.len());
    for &p in points {
        let ps = point(p);
        let fh = &ps.first_hit;
        first_hit.extend([
            fh.stats().count() as f64,
            ps.never_hit as f64,
            fh.stats().mean(),
            fh.stats().variance(),
            fh.stats().min(),
            fh.stats().max(),
        ]);
        first_hit_q.extend(qs.iter().map(|&q| fh.quantile(q).unwrap_or(f64::NAN)));
    }
    write_npy(stats.join("first_hit.npy"), &[p_count, 6], &first_hit)?;
    // Each member's responses, summarised per point (every point).
    type Response = (&'static str, fn(&PointStats) -> &ScalarSummary);
    let responses: [Response; 3] = [
        ("peak_density", |s| &s.peak_density),
        ("smallest_gap", |s| &s.min_gap),
        ("final_energy", |s| &s.final_energy),
    ];
    for (file, summary) in responses {
        let mut moments = Vec::with_capacity(points.len() * 5);
        let mut quant = Vec::with_capacity(points.len() * qs.len());
        for &p in points {
            let s = summary(point(p));
            moments.extend([
                s.stats().count() as f64,
                s.stats().mean(),
                s.stats().variance(),
                s.stats().min(),
                s.stats().max(),
            ]);
            quant.extend(qs.iter().map(|&q| s.quantile(q).unwrap_or(f64::NAN)));
        }
        write_npy(stats.join(format!("{file}.npy")), &[p_count, 5], &moments)?;
        write_npy(
            stats.join(format!("{file}_quantiles.npy")),
            &[p_count, nq],
            &quant,
        )?;
    }
    write_npy(
        stats.join("first_hit_quantiles.npy"),
        &[p_count, nq],
        &first_hit_q,
    )?;
    Ok(())
}

/// The field bands of the detailed points: `stats/{field}_{mean,var}.npy` [D, T, G] and
/// `_quantiles.npy` [D, T, Q, G].
fn write_bands<'a>(
    stats: &Path,
    header: &StudyHeader,
    detailed: &[u64],
    point: &PointOf<'a>,
) -> Result<()> {
    let (d_count, t, g) = (
        detailed.len() as u64,
        header.times.len() as u64,
        header.x.len() as u64,
    );
    let qs = &header.quantiles;
    let nq = qs.len() as u64;
    // A field's rows for every detailed point are held until its files are written: the
    // fields side by side while all their rows are small, else one after another (a design may
    // detail hundreds of points). Each point's bands are read in parallel either way.
    let write_field = |name: &String| -> Result<()> {
        let mut mean: Vec<f64> = Vec::new();
        let mut var: Vec<f64> = Vec::new();
        let mut quant: Vec<f64> = Vec::new();
        for &p in detailed {
            // The bands of one point, each read on its own (in parallel), written in time order.
            let rows: Vec<_> = point(p).fields[name.as_str()]
                .par_iter()
                .map(|band| {
                    let quantiles = band.quantile_rows(qs);
                    (band.mean_row(), band.variance_row(), quantiles)
                })
                .collect();
            for (band_mean, band_var, band_quantiles) in rows {
                mean.extend(band_mean);
                var.extend(band_var);
                for row in band_quantiles.map_err(|e| stats_error(stats, e))? {
                    quant.extend(row);
                }
            }
        }
        write_npy(
            stats.join(format!("{name}_mean.npy")),
            &[d_count, t, g],
            &mean,
        )?;
        write_npy(
            stats.join(format!("{name}_var.npy")),
            &[d_count, t, g],
            &var,
        )?;
        write_npy(
            stats.join(format!("{name}_quantiles.npy")),
            &[d_count, t, nq, g],
            &quant,
        )?;
        Ok(())
    };
    if band_rows_held(header, d_count).0 {
        header.band_fields.par_iter().try_for_each(write_field)
    } else {
        header.band_fields.iter().try_for_each(write_field)
    }
}

/// The most bytes of band rows the report holds to write its fields side by side.
const REPORT_ROWS_TOGETHER: u64 = 64 << 20;

/// Whether the report writes the band fields of `detailed` points side by side, and the bytes of
/// rows it then holds at once (mean, variance and the quantile levels at every time and grid
/// point, of every field or of one).
pub(super) fn band_rows_held(header: &StudyHeader, detailed: u64) -> (bool, u64) {
    let (t, g) = (header.times.len() as u64, header.x.len() as u64);
    let q = header.quantiles.len() as u64;
    let field = detailed * t * g * (q + 2) * 8;
    let all = header.band_fields.len() as u64 * field;
    if all <= REPORT_ROWS_TOGETHER {
        (true, all)
    } else {
        (false, field)
    }
}

/// The per-member responses drawn against the swept keys: (file stem, axis label, members.csv
/// column, the point's summary of it).
type Response = (
    &'static str,
    &'static str,
    &'static str,
    fn(&PointStats) -> &ScalarSummary,
);
const RESPONSES: [Response; 2] = [
    (
        "peak_density",
        "peak density (largest max density over the outputs)",
        "peak_density",
        |s| &s.peak_density,
    ),
    (
        "first_hit",
        "first time the max density reaches the threshold",
        "first_hit_time",
        |s| &s.first_hit,
    ),
];

/// How the flow responds to the swept keys: for a grid over one key, each response's mean and
/// quantile band against it (`{response}_vs_{key}.png`); over two keys, a heat map of the mean
/// (`{response}_map.png`); for sampled designs, every member's response against each key
/// (`{response}_vs_{key}.png`, read back from members.csv). Grids over three or more keys get
/// no response plot (the statistics and points.csv hold them). `point(p)` gives a point's
/// statistics.
fn write_response_plots<'a>(
    dir: &Path,
    plots: &Path,
    header: &StudyHeader,
    point: &dyn Fn(u64) -> &'a PointStats,
) -> Result<()> {
    let names = &header.sweep_names;
    let (q_lo, q_hi) = (
        *header.quantiles.first().unwrap_or(&0.05),
        *header.quantiles.last().unwrap_or(&0.95),
    );
    let band_label = format!("{:.0}%-{:.0}% of members", 100.0 * q_lo, 100.0 * q_hi);
    let log = |d: usize| header.sweep_log_scale.get(d).copied().unwrap_or(false);
    if header.sweep_design != "grid" {
        let csv_path = dir.join("members.csv");
        let mut reader = csv::Reader::from_path(&csv_path).map_err(|e| Error::Output {
            path: csv_path.clone(),
            message: e.to_string(),
        })?;
        let head = reader.headers().cloned().unwrap_or_default();
        let rows: Vec<csv::StringRecord> = reader.records().filter_map(|r| r.ok()).collect();
        if rows.is_empty() {
            // A shard with no members (more shards than members): nothing to plot.
            return Ok(());
        }
        let column = |name: &str| -> Vec<f64> {
            match head.iter().position(|h| h == name) {
                Some(c) => rows
                    .iter()
                    .map(|r| r.get(c).and_then(|v| v.parse().ok()).unwrap_or(f64::NAN))
                    .collect(),
                None => Vec::new(),
            }
        };
        for (d, name) in names.iter().enumerate() {
            // A members.csv resumed from before `point_<key>` names the swept key bare.
            let x = Some(column(&crate::output::columns::swept_member_column(name)))
                .filter(|x| !x.is_empty())
                .unwrap_or_else(|| column(name));
            for (stem, label, col, _) in RESPONSES {
                let y = column(col);
                crate::plot::plot_scatter(
                    &plots.join(format!("{stem}_vs_{name}.png")),
                    &crate::plot::ScatterPlot {
                        title: &format!("{}: {label} against {name}", header.scene_name),
                        x_label: name,
                        y_label: label,
                        x: &x,
                        y: &y,
                        log_x: log(d),
                    },
                )?;
            }
        }
        return Ok(());
    }
    let point = |p: usize| point(p as u64);
    match names.len() {
        1 => {
            let x: Vec<f64> = header.points.iter().map(|v| v[0]).collect();
            for (stem, label, _, summary) in RESPONSES {
                let of = |f: &dyn Fn(&ScalarSummary) -> f64| -> Vec<f64> {
                    (0..x.len()).map(|p| f(summary(point(p)))).collect()
                };
                crate::plot::plot_response(
                    &plots.join(format!("{stem}_vs_{}.png", names[0])),
                    &crate::plot::ResponsePlot {
                        title: &format!("{}: {label}", header.scene_name),
                        x_label: &names[0],
                        y_label: label,
                        x: &x,
                        mean: &of(&|s| s.stats().mean()),
                        lower: &of(&|s| s.quantile(q_lo).unwrap_or(f64::NAN)),
                        upper: &of(&|s| s.quantile(q_hi).unwrap_or(f64::NAN)),
                        band_label: &band_label,
                        log_x: log(0),
                    },
                )?;
            }
        }
        2 => {
            // The first key varies slowest: point p = i0 * n1 + i1.
            let distinct = |d: usize| {
                let mut v: Vec<f64> = Vec::new();
                for p in &header.points {
                    if !v.contains(&p[d]) {
                        v.push(p[d]);
                    }
                }
                v
            };
            let (ys, xs) = (distinct(0), distinct(1));
            for (stem, label, _, summary) in RESPONSES {
                let values: Vec<Vec<f64>> = (0..ys.len())
                    .map(|j| {
                        (0..xs.len())
                            .map(|i| summary(point(j * xs.len() + i)).stats().mean())
                            .collect()
                    })
                    .collect();
                crate::plot::plot_heatmap(
                    &plots.join(format!("{stem}_map.png")),
                    &crate::plot::HeatmapPlot {
                        title: &format!("{}: mean {label}", header.scene_name),
                        x_label: &names[1],
                        y_label: &names[0],
                        value_label: label,
                        xs: &xs,
                        ys: &ys,
                        values: &values,
                        log_x: log(1),
                        log_y: log(0),
                    },
                )?;
            }
        }
        _ => {}
    }
    Ok(())
}

/// Sweep points whose own band and histogram plots are drawn (the first ones).
const MAX_POINT_PLOTS: usize = 4;

/// `points.csv`: per sweep point its index, the swept keys' values, and how many of its members
/// completed and failed.
fn write_points_csv(path: &Path, header: &StudyHeader, state: &StudyState) -> Result<()> {
    let err = |e: csv::Error| Error::Output {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let mut w = csv::Writer::from_path(path).map_err(err)?;
    let mut head = vec![super::files::POINT_INDEX_COLUMN.to_string()];
    head.extend(header.sweep_names.iter().cloned());
    head.extend(super::files::POINT_COUNT_COLUMNS.map(String::from));
    w.write_record(&head).map_err(err)?;
    for (p, values) in header.points.iter().enumerate() {
        let stats = state.points.get(&(p as u64));
        let mut row = vec![p.to_string()];
        row.extend(values.iter().map(|v| format!("{v:?}")));
        row.push(stats.map_or(0, |s| s.completed).to_string());
        row.push(stats.map_or(0, |s| s.failed).to_string());
        w.write_record(&row).map_err(err)?;
    }
    w.flush().map_err(|e| Error::io(path, e))
}

/// A statistics error while writing or merging the study at `path`, as the study's error.
pub(super) fn stats_error(path: &Path, e: StatsError) -> Error {
    Error::Output {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// Per time, the scalar's histogram in [`SCALAR_BINS`] bins over that time's [min, max] (from
/// its sketch): the edges `[T, SCALAR_BINS + 1]` and counts `[T, SCALAR_BINS]`, concatenated.
fn scalar_histograms(per_time: &[ScalarSummary], path: &Path) -> Result<(Vec<f64>, Vec<f64>)> {
    let mut edges = Vec::with_capacity(per_time.len() * (SCALAR_BINS + 1));
    let mut counts = Vec::with_capacity(per_time.len() * SCALAR_BINS);
    for s in per_time {
        let h = s
            .range_histogram(SCALAR_BINS)
            .map_err(|e| stats_error(path, e))?;
        edges.extend(h.edges());
        counts.extend(h.counts().iter().map(|&c| c as f64));
    }
    Ok((edges, counts))
}

/// The band plots of rho and u and the histograms of one point's members, named with `prefix`.
fn write_point_plots(
    plots: &Path,
    prefix: &str,
    header: &StudyHeader,
    state: &PointStats,
) -> Result<()> {
    let t = header.times.len();
    // Up to four times, evenly spread, for the band plot.
    let shown: Vec<usize> = if t <= 4 {
        (0..t).collect()
    } else {
        (0..4).map(|j| j * (t - 1) / 3).collect()
    };
    let (q_lo, q_hi) = (
        *header.quantiles.first().unwrap_or(&0.05),
        *header.quantiles.last().unwrap_or(&0.95),
    );
    for field in ["rho", "u"] {
        let Some(bands) = state.fields.get(field) else {
            continue;
        };
        let mean: Vec<Vec<f64>> = shown.iter().map(|&k| bands[k].mean_row()).collect();
        let row = |k: usize, q: f64| bands[k].quantile_row(q).map_err(|e| stats_error(plots, e));
        let lower = shown
            .iter()
            .map(|&k| row(k, q_lo))
            .collect::<Result<Vec<_>>>()?;
        let upper = shown
            .iter()
            .map(|&k| row(k, q_hi))
            .collect::<Result<Vec<_>>>()?;
        let times: Vec<f64> = shown.iter().map(|&k| header.times[k]).collect();
        let reference: Option<Vec<Vec<f64>>> = match (field, state.fields.get("rho_star")) {
            ("rho", Some(rho_star)) => {
                Some(shown.iter().map(|&k| rho_star[k].mean_row()).collect())
            }
            _ => None,
        };
        let has_reference = reference
            .as_ref()
            .is_some_and(|r| r.iter().any(|row| row.iter().any(|v| v.is_finite())));
        let title = format!(
            "{}: mean {field} over {} members",
            header.scene_name, state.completed
        );
        let label = format!("{:.0}%-{:.0}% of members", 100.0 * q_lo, 100.0 * q_hi);
        crate::plot::plot_band(
            &plots.join(format!("{prefix}{field}_band.png")),
            &crate::plot::BandPlot {
                title: &title,
                y_label: field,
                x: &header.x,
                times: &times,
                mean: &mean,
                lower: &lower,
                upper: &upper,
                band_label: &label,
                reference: if has_reference {
                    reference.as_deref()
                } else {
                    None
                },
            },
        )?;
    }
    // Space–time pictures over all output times: the mean, and the width of the band between
    // the first and last quantile levels.
    for field in ["rho", "u"] {
        let Some(bands) = state.fields.get(field) else {
            continue;
        };
        let mean: Vec<Vec<f64>> = bands.iter().map(|b| b.mean_row()).collect();
        let mut width: Vec<Vec<f64>> = Vec::with_capacity(t);
        for b in bands {
            let lo = b.quantile_row(q_lo).map_err(|e| stats_error(plots, e))?;
            let hi = b.quantile_row(q_hi).map_err(|e| stats_error(plots, e))?;
            width.push(hi.iter().zip(&lo).map(|(h, l)| h - l).collect());
        }
        crate::plot::plot_xt(
            &plots.join(format!("{prefix}{field}_xt_mean.png")),
            &format!(
                "{}: mean {field}(x, t) over {} members",
                header.scene_name, state.completed
            ),
            &format!("mean {field}"),
            &header.x,
            &header.times,
            &mean,
        )?;
        crate::plot::plot_xt(
            &plots.join(format!("{prefix}{field}_xt_band.png")),
            &format!(
                "{}: width of the {:.0}%-{:.0}% band of {field}(x, t)",
                header.scene_name,
                100.0 * q_lo,
                100.0 * q_hi
            ),
            &format!("{field} band width"),
            &header.x,
            &header.times,
            &width,
        )?;
    }
    let last = t - 1;
    let hist = state.scalars["max_density"][last]
        .range_histogram(SCALAR_BINS)
        .map_err(|e| stats_error(plots, e))?;
    crate::plot::plot_histogram(
        &plots.join(format!("{prefix}max_density_hist.png")),
        &format!(
            "{}: max density at t = {}",
            header.scene_name, header.times[last]
        ),
        "max density",
        &hist.edges(),
        hist.counts(),
        None,
    )?;
    if state.first_hit.stats().count() > 0 {
        let hist = state
            .first_hit
            .range_histogram(SCALAR_BINS)
            .map_err(|e| stats_error(plots, e))?;
        let note = format!("{} members never reached the threshold", state.never_hit);
        crate::plot::plot_histogram(
            &plots.join(format!("{prefix}first_hit_hist.png")),
            &format!(
                "{}: first time max density reaches the threshold",
                header.scene_name
            ),
            "t",
            &hist.edges(),
            hist.counts(),
            Some(&note),
        )?;
    }
    Ok(())
}
