//! Global sensitivity of a study on a Saltelli design (`[sweep] design = "saltelli"`):
//! `sensitivity.csv`, `sensitivity_failures.csv` and `plots/sensitivity.png`, from the merged
//! per-point responses.
//!
//! The indices are those of each point's mean response over its members (with one member per
//! point, that member's response). The per-point responses are part of the mergeable state, so
//! the indices are the same from one process, from chunks of any size, from any number of
//! threads and from merged shards (to the rounding of the means of points with several members).
//!
//! A point without a value (its members failed, or for the first-hit time none reached the
//! threshold) leaves a hole in its base point's pick-freeze group: the whole group is dropped and
//! counted. Above [`MAX_DROPPED`] of the groups dropped, a response's indices are not reported
//! (NaN, with the reason in the `note` column).

use std::path::Path;

use super::files::StudyHeader;
use super::state::{PointStats, StudyState};
use crate::error::{Error, Result};
use crate::stats::sensitivity::{sobol_indices, Bootstrap, PickFreezeGroup};
use crate::stats::ScalarSummary;

/// The largest fraction of dropped groups for which indices are reported.
pub const MAX_DROPPED: f64 = 0.1;
/// Bootstrap resamples of the base points for the intervals (95 %).
const RESAMPLES: usize = 1000;
/// Key ranges per key in sensitivity_failures.csv.
const FAILURE_BINS: usize = 4;

type Response = (&'static str, fn(&PointStats) -> &ScalarSummary);
const RESPONSES: [Response; 4] = [
    ("peak_density", |s| &s.peak_density),
    ("first_hit_time", |s| &s.first_hit),
    ("smallest_gap", |s| &s.min_gap),
    ("final_energy", |s| &s.final_energy),
];

/// Writes the sensitivity files of a study on a Saltelli design (nothing for other designs).
pub(super) fn write_sensitivity(
    dir: &Path,
    header: &StudyHeader,
    state: &StudyState,
    plots: bool,
) -> Result<()> {
    if header.sweep_design != "saltelli" {
        return Ok(());
    }
    let d = header.sweep_names.len();
    let p_count = header.points.len() as u64;
    let base = p_count / (d as u64 + 2);
    let csv_path = dir.join("sensitivity.csv");
    let err = |path: &Path, e: csv::Error| Error::Output {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let mut w = csv::Writer::from_path(&csv_path).map_err(|e| err(&csv_path, e))?;
    w.write_record([
        "response",
        "key",
        "S1",
        "S1_low",
        "S1_high",
        "ST",
        "ST_low",
        "ST_high",
        "evaluations",
        "groups",
        "groups_dropped",
        "note",
    ])
    .map_err(|e| err(&csv_path, e))?;
    let mut plotted = Vec::new();
    for (name, summary) in RESPONSES {
        let value = |p: u64| -> f64 {
            state.points.get(&p).map_or(f64::NAN, |s| {
                let s = summary(s);
                if s.stats().count() > 0 {
                    s.stats().mean()
                } else {
                    f64::NAN
                }
            })
        };
        let mut groups = Vec::with_capacity(base as usize);
        for j in 0..base {
            let first = j * (d as u64 + 2);
            let g = PickFreezeGroup {
                a: value(first),
                ab: (1..=d as u64).map(|i| value(first + i)).collect(),
                b: value(first + d as u64 + 1),
            };
            if g.a.is_finite() && g.b.is_finite() && g.ab.iter().all(|v| v.is_finite()) {
                groups.push(g);
            }
        }
        let dropped = base as usize - groups.len();
        let fraction = dropped as f64 / base.max(1) as f64;
        let (indices, note) = if fraction > MAX_DROPPED {
            (
                None,
                format!(
                    "not reported: {dropped} of {base} groups incomplete ({:.1} %, more than {:.0} %)",
                    100.0 * fraction,
                    100.0 * MAX_DROPPED
                ),
            )
        } else {
            let bootstrap = Bootstrap {
                resamples: RESAMPLES,
                confidence: 0.95,
                seed: 0x5e45_1715,
            };
            match sobol_indices(&groups, bootstrap) {
                Some(i) => (Some(i), String::new()),
                None => (
                    None,
                    "not reported: fewer than 2 groups, or the response does not vary".into(),
                ),
            }
        };
        let evaluations = groups.len() * (d + 2);
        let num = |x: f64| format!("{x:?}");
        let mut first = Vec::new();
        let mut total = Vec::new();
        for (i, key) in header.sweep_names.iter().enumerate() {
            let (s1, st) = match &indices {
                Some(ix) => (ix.first[i], ix.total[i]),
                None => {
                    let nan = crate::stats::sensitivity::Index {
                        value: f64::NAN,
                        low: f64::NAN,
                        high: f64::NAN,
                        std_error: f64::NAN,
                    };
                    (nan, nan)
                }
            };
            first.push((s1.value, s1.low, s1.high));
            total.push((st.value, st.low, st.high));
            w.write_record([
                name.to_string(),
                key.clone(),
                num(s1.value),
                num(s1.low),
                num(s1.high),
                num(st.value),
                num(st.low),
                num(st.high),
                evaluations.to_string(),
                groups.len().to_string(),
                dropped.to_string(),
                note.clone(),
            ])
            .map_err(|e| err(&csv_path, e))?;
        }
        if indices.is_some() {
            plotted.push((name, first, total));
        }
    }
    w.flush().map_err(|e| Error::io(&csv_path, e))?;
    write_failures(dir, header, state)?;
    if plots && !plotted.is_empty() {
        let responses: Vec<crate::plot::SensitivityResponse> = plotted
            .into_iter()
            .map(|(name, first, total)| crate::plot::SensitivityResponse { name, first, total })
            .collect();
        let plots_dir = dir.join("plots");
        std::fs::create_dir_all(&plots_dir).map_err(|e| Error::io(&plots_dir, e))?;
        crate::plot::plot_sensitivity(
            &plots_dir.join("sensitivity.png"),
            &crate::plot::SensitivityPlot {
                title: &format!(
                    "{}: Sobol indices (95 % bootstrap intervals, {base} base points)",
                    header.scene_name
                ),
                keys: &header.sweep_names,
                responses: &responses,
            },
        )?;
    }
    Ok(())
}

/// `sensitivity_failures.csv`: per key and per quarter of its declared range (in the design's
/// unit coordinates), the members there and how many failed.
fn write_failures(dir: &Path, header: &StudyHeader, state: &StudyState) -> Result<()> {
    let path = dir.join("sensitivity_failures.csv");
    let err = |e: csv::Error| Error::Output {
        path: path.clone(),
        message: e.to_string(),
    };
    let mut w = csv::Writer::from_path(&path).map_err(err)?;
    w.write_record(["key", "from", "to", "members", "failed", "failure_rate"])
        .map_err(err)?;
    for (k, key) in header.sweep_names.iter().enumerate() {
        let values: Vec<f64> = header.points.iter().map(|v| v[k]).collect();
        // The declared range, so that the quarters are the same in every study of one scene.
        let (lo, hi) = header.sweep_bounds.get(k).copied().unwrap_or_else(|| {
            (
                values.iter().copied().fold(f64::INFINITY, f64::min),
                values.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            )
        });
        let log = header.sweep_log_scale.get(k).copied().unwrap_or(false) && lo > 0.0;
        let unit = |v: f64| {
            if hi <= lo {
                0.0
            } else if log {
                (v / lo).ln() / (hi / lo).ln()
            } else {
                (v - lo) / (hi - lo)
            }
        };
        let mut members = [0u64; FAILURE_BINS];
        let mut failed = [0u64; FAILURE_BINS];
        for (p, &v) in values.iter().enumerate() {
            let bin = ((unit(v).max(0.0) * FAILURE_BINS as f64) as usize).min(FAILURE_BINS - 1);
            if let Some(s) = state.points.get(&(p as u64)) {
                members[bin] += s.completed + s.failed;
                failed[bin] += s.failed;
            }
        }
        for b in 0..FAILURE_BINS {
            let edge = |t: f64| {
                if log {
                    lo * (hi / lo).powf(t)
                } else {
                    lo + t * (hi - lo)
                }
            };
            let rate = if members[b] > 0 {
                failed[b] as f64 / members[b] as f64
            } else {
                f64::NAN
            };
            w.write_record([
                key.clone(),
                format!("{:?}", edge(b as f64 / FAILURE_BINS as f64)),
                format!("{:?}", edge((b + 1) as f64 / FAILURE_BINS as f64)),
                members[b].to_string(),
                failed[b].to_string(),
                format!("{rate:?}"),
            ])
            .map_err(err)?;
        }
    }
    w.flush().map_err(|e| Error::io(&path, e))
}
