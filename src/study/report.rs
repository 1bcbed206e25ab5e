//! The report of a study: `stats/*.npy` and `plots/*.png` from its merged [`StudyState`], and
//! the manifest's description of how the quantiles were computed.

use std::path::Path;

use super::files::StudyHeader;
use super::state::StudyState;
use super::{SCALAR_ALPHA, SCALAR_BINS};
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

/// Writes `stats/*.npy` and the plots (`members.csv` is streamed by the caller).
pub(super) fn finalize(
    dir: &Path,
    headers: &[StudyHeader],
    state: &StudyState,
    plots: bool,
) -> Result<()> {
    let header = &headers[0];
    let stats = dir.join("stats");
    std::fs::create_dir_all(&stats).map_err(|e| Error::io(&stats, e))?;
    let t = header.times.len();
    let g = header.x.len();
    let qs = &header.quantiles;
    let nq = qs.len() as u64;
    write_npy(stats.join("times.npy"), &[t as u64], &header.times)?;
    write_npy(stats.join("x.npy"), &[g as u64], &header.x)?;
    write_npy(stats.join("quantile_levels.npy"), &[nq], qs)?;
    for (name, per_time) in &state.scalars {
        let col = |f: &dyn Fn(&ScalarSummary) -> f64| per_time.iter().map(f).collect::<Vec<f64>>();
        write_npy(
            stats.join(format!("{name}_count.npy")),
            &[t as u64],
            &col(&|s| s.stats().count() as f64),
        )?;
        write_npy(
            stats.join(format!("{name}_mean.npy")),
            &[t as u64],
            &col(&|s| s.stats().mean()),
        )?;
        write_npy(
            stats.join(format!("{name}_var.npy")),
            &[t as u64],
            &col(&|s| s.stats().variance()),
        )?;
        write_npy(
            stats.join(format!("{name}_min.npy")),
            &[t as u64],
            &col(&|s| s.stats().min()),
        )?;
        write_npy(
            stats.join(format!("{name}_max.npy")),
            &[t as u64],
            &col(&|s| s.stats().max()),
        )?;
        let quant: Vec<f64> = per_time
            .iter()
            .flat_map(|s| qs.iter().map(|&q| s.quantile(q).unwrap_or(f64::NAN)))
            .collect();
        write_npy(
            stats.join(format!("{name}_quantiles.npy")),
            &[t as u64, nq],
            &quant,
        )?;
        let (edges, counts) = scalar_histograms(per_time, &stats)?;
        write_npy(
            stats.join(format!("{name}_hist_edges.npy")),
            &[t as u64, SCALAR_BINS as u64 + 1],
            &edges,
        )?;
        write_npy(
            stats.join(format!("{name}_hist_counts.npy")),
            &[t as u64, SCALAR_BINS as u64],
            &counts,
        )?;
    }
    let fh = &state.first_hit;
    write_npy(
        stats.join("first_hit.npy"),
        &[6],
        &[
            fh.stats().count() as f64,
            state.never_hit as f64,
            fh.stats().mean(),
            fh.stats().variance(),
            fh.stats().min(),
            fh.stats().max(),
        ],
    )?;
    let fq: Vec<f64> = qs
        .iter()
        .map(|&q| fh.quantile(q).unwrap_or(f64::NAN))
        .collect();
    write_npy(stats.join("first_hit_quantiles.npy"), &[nq], &fq)?;
    for (name, per_time) in &state.fields {
        let mean: Vec<f64> = per_time.iter().flat_map(|b| b.mean_row()).collect();
        let var: Vec<f64> = per_time.iter().flat_map(|b| b.variance_row()).collect();
        let mut quant: Vec<f64> = Vec::with_capacity(t * qs.len() * g);
        for band in per_time {
            for &q in qs {
                quant.extend(band.quantile_row(q).map_err(|e| stats_error(&stats, e))?);
            }
        }
        write_npy(
            stats.join(format!("{name}_mean.npy")),
            &[t as u64, g as u64],
            &mean,
        )?;
        write_npy(
            stats.join(format!("{name}_var.npy")),
            &[t as u64, g as u64],
            &var,
        )?;
        write_npy(
            stats.join(format!("{name}_quantiles.npy")),
            &[t as u64, nq, g as u64],
            &quant,
        )?;
    }
    if plots {
        write_plots(dir, header, state)?;
    }
    Ok(())
}

fn stats_error(path: &Path, e: StatsError) -> Error {
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

fn write_plots(dir: &Path, header: &StudyHeader, state: &StudyState) -> Result<()> {
    let plots = dir.join("plots");
    std::fs::create_dir_all(&plots).map_err(|e| Error::io(&plots, e))?;
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
        let bands = &state.fields[field];
        let mean: Vec<Vec<f64>> = shown.iter().map(|&k| bands[k].mean_row()).collect();
        let row = |k: usize, q: f64| bands[k].quantile_row(q).map_err(|e| stats_error(&plots, e));
        let lower = shown
            .iter()
            .map(|&k| row(k, q_lo))
            .collect::<Result<Vec<_>>>()?;
        let upper = shown
            .iter()
            .map(|&k| row(k, q_hi))
            .collect::<Result<Vec<_>>>()?;
        let times: Vec<f64> = shown.iter().map(|&k| header.times[k]).collect();
        let reference: Option<Vec<Vec<f64>>> = (field == "rho").then(|| {
            shown
                .iter()
                .map(|&k| state.fields["rho_star"][k].mean_row())
                .collect()
        });
        let has_reference = reference
            .as_ref()
            .is_some_and(|r| r.iter().any(|row| row.iter().any(|v| v.is_finite())));
        let title = format!(
            "{}: mean {field} over {} members",
            header.scene_name, state.completed
        );
        let label = format!("{:.0}%-{:.0}% of members", 100.0 * q_lo, 100.0 * q_hi);
        crate::plot::plot_band(
            &plots.join(format!("{field}_band.png")),
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
    let last = t - 1;
    let hist = state.scalars["max_density"][last]
        .range_histogram(SCALAR_BINS)
        .map_err(|e| stats_error(&plots, e))?;
    crate::plot::plot_histogram(
        &plots.join("max_density_hist.png"),
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
            .map_err(|e| stats_error(&plots, e))?;
        let note = format!("{} members never reached the threshold", state.never_hit);
        crate::plot::plot_histogram(
            &plots.join("first_hit_hist.png"),
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
