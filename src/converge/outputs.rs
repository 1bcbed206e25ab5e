//! What a convergence study writes besides its CSV and manifest: the fields at every N as
//! arrays, and the plots of the profiles and of the differences against N.

use std::path::{Path, PathBuf};

use super::rates::fit_rate;
use super::records::FieldSummary;
use super::{shown_times, time_text, FieldStack, Verdict, FIELDS};
use crate::error::{Error, Result};
use crate::output::write_npy;
use crate::plot::{
    plot_convergence_profiles, plot_convergence_rate, ConvergenceProfilesPlot, ConvergenceRatePlot,
};
use crate::scene::Scene;

/// What the study's arrays and plots are drawn from.
pub(super) struct Drawn<'a> {
    pub(super) scene: &'a Scene,
    pub(super) ns: &'a [usize],
    pub(super) grid: &'a [f64],
    /// fields[f][k][t] = the grid's values.
    pub(super) fields: &'a FieldStack,
    /// limits[f] = the extrapolated limit, t-major (three or more N).
    pub(super) limits: &'a [Vec<f64>],
    pub(super) summaries: &'a [FieldSummary],
    pub(super) repulsion: bool,
}

impl Drawn<'_> {
    /// rho* is a field only where the scene has roughness.
    fn field_on(&self, f: usize) -> bool {
        f != 2 || self.repulsion
    }
}

/// The arrays: each field at every N, time and grid point, its limit, and the axes.
pub(super) fn write_arrays(dir: &Path, drawn: &Drawn) -> Result<Vec<PathBuf>> {
    let scene = drawn.scene;
    let (k_count, t_count, g) = (drawn.ns.len(), scene.output_times.len(), drawn.grid.len());
    let (k64, t64, g64) = (k_count as u64, t_count as u64, g as u64);
    let mut files = Vec::new();
    for (f, name) in FIELDS.iter().enumerate() {
        if !drawn.field_on(f) {
            continue;
        }
        let flat: Vec<f64> = drawn.fields[f]
            .iter()
            .flatten()
            .flatten()
            .copied()
            .collect();
        files.push(write_npy(
            dir.join(format!("fields_{name}.npy")),
            &[k64, t64, g64],
            &flat,
        )?);
        if k_count >= 3 {
            files.push(write_npy(
                dir.join(format!("limit_{name}.npy")),
                &[t64, g64],
                &drawn.limits[f],
            )?);
        }
    }
    let ns_f64: Vec<f64> = drawn.ns.iter().map(|&n| n as f64).collect();
    files.push(write_npy(dir.join("particles.npy"), &[k64], &ns_f64)?);
    files.push(write_npy(
        dir.join("times.npy"),
        &[t64],
        &scene.output_times,
    )?);
    files.push(write_npy(dir.join("x.npy"), &[g64], drawn.grid)?);
    Ok(files)
}

/// The plots: each field's profiles at every N (and the limit), and its L1 differences against
/// N with the fitted rate.
pub(super) fn write_plots(dir: &Path, drawn: &Drawn) -> Result<Vec<PathBuf>> {
    let (scene, ns, grid) = (drawn.scene, drawn.ns, drawn.grid);
    let (k_count, t_count, g) = (ns.len(), scene.output_times.len(), grid.len());
    let mut files = Vec::new();
    let plot_dir = dir.join("plots");
    std::fs::create_dir_all(&plot_dir).map_err(|e| Error::io(&plot_dir, e))?;
    let shown = shown_times(t_count);
    let labels: Vec<String> = ns.iter().map(|n| format!("N = {n}")).collect();
    let times: Vec<f64> = shown.iter().map(|&t| scene.output_times[t]).collect();
    let last_t = *scene.output_times.last().expect("output times");
    for (f, name) in FIELDS.iter().enumerate() {
        if !drawn.field_on(f) {
            continue;
        }
        let values: Vec<Vec<Vec<f64>>> = shown
            .iter()
            .map(|&t| {
                (0..k_count)
                    .map(|k| drawn.fields[f][k][t].clone())
                    .collect()
            })
            .collect();
        let limit_rows: Vec<Vec<f64>> = shown
            .iter()
            .map(|&t| drawn.limits[f][t * g..(t + 1) * g].to_vec())
            .collect();
        let path = plot_dir.join(format!("{name}_profiles.png"));
        plot_convergence_profiles(
            &path,
            &ConvergenceProfilesPlot {
                title: &format!("{}: {name} at each N", scene.name),
                y_label: name,
                x: grid,
                times: &times,
                labels: &labels,
                values: &values,
                limit: (k_count >= 3).then_some(limit_rows.as_slice()),
            },
        )?;
        files.push(path);

        let summary = drawn
            .summaries
            .iter()
            .find(|s| s.field == *name)
            .expect("summary of every field shown");
        let n_fine: Vec<f64> = ns[1..].iter().map(|&n| n as f64).collect();
        let fit = fit_rate(&n_fine, &summary.diff_l1).filter(|_| summary.fitted_rate.is_finite());
        let mut note = match fit {
            Some((p, _)) => format!("fitted rate {p:.3} (dashed)"),
            None if summary.verdict == Verdict::Exact => {
                "differences at rounding level: no rate".to_string()
            }
            None => "no fitted rate (fewer than 2 nonzero differences)".to_string(),
        };
        if summary.rate.is_finite() {
            note.push_str(&format!(
                "\nrate at the largest pair {:.3}\n{}",
                summary.rate,
                summary.verdict.name().replace('_', " ")
            ));
        }
        let path = plot_dir.join(format!("{name}_rate.png"));
        plot_convergence_rate(
            &path,
            &ConvergenceRatePlot {
                title: &format!(
                    "{}: {name}, L1 difference between successive N at t = {}",
                    scene.name,
                    time_text(last_t)
                ),
                y_label: &format!("L1 difference of {name}"),
                n: &n_fine,
                diff: &summary.diff_l1,
                fit,
                note: &note,
            },
        )?;
        files.push(path);
    }
    Ok(files)
}
