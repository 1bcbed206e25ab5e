//! What `accuracy` writes: `work_precision.csv` and the reference arrays.

use std::path::Path;

use super::members::MeasuredGroup;
use super::setting::backend_name;
use super::Measurement;
use crate::error::{Error, Result};
use crate::model::observables::Snapshot;
use crate::model::params::Stepping;
use crate::model::plan::Plan;
use crate::output::write_npy;

pub(super) fn write_csv(path: &Path, measurements: &[Measurement]) -> Result<()> {
    let err = |e: csv::Error| Error::Output {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let mut w = csv::Writer::from_path(path).map_err(err)?;
    w.write_record([
        "backend",
        "precision",
        "order",
        "sequence",
        "jacobian",
        "stepping",
        "dt_or_tolerance",
        "error",
        "gap_error",
        "velocity_error",
        "rho_error",
        "wall_seconds",
        "steps_accepted",
        "steps_rejected",
        "particle_steps_per_second",
        "status",
        "worst_point",
        "observed_order",
    ])
    .map_err(err)?;
    for m in measurements {
        let s = &m.setting;
        let (kind, value) = match s.stepping {
            Stepping::Fixed { dt, .. } => ("fixed", dt),
            Stepping::Adaptive { tolerance, .. } => ("adaptive", tolerance),
        };
        let e = m.errors;
        let num = |v: Option<f64>| v.map_or("NaN".to_string(), |v| format!("{v:e}"));
        w.write_record([
            backend_name(s.backend).to_string(),
            s.precision.name().to_string(),
            s.order.label(),
            s.sequence.record(s.order).to_string(),
            s.jacobian.record(s.order, s.stepping).to_string(),
            kind.to_string(),
            format!("{value:e}"),
            num(e.map(|e| e.worst())),
            num(e.map(|e| e.gaps)),
            num(e.map(|e| e.velocities)),
            num(e.map(|e| e.rho)),
            format!("{:e}", m.wall_seconds),
            m.steps_accepted.to_string(),
            m.steps_rejected.to_string(),
            format!("{:e}", m.particle_steps_per_second),
            if e.is_some() { "ok" } else { "failed" }.to_string(),
            m.worst_point.map_or(String::new(), |p| p.to_string()),
            num(m.observed_order),
        ])
        .map_err(err)?;
    }
    w.flush().map_err(|e| Error::io(path, e))
}

/// The reference's gaps, velocities and rho, [T, B, ...], for checking any later run by hand:
/// `reference_*.npy` over every measured member when they share N, otherwise one set per sweep
/// point, `reference_*_point{p}.npy`.
pub(super) fn write_reference(
    dir: &Path,
    groups: &[MeasuredGroup],
    ranges: &[std::ops::Range<usize>],
    snapshots: &[Vec<Snapshot>],
) -> Result<()> {
    let same_n = groups
        .iter()
        .all(|g| g.plan.particles == groups[0].plan.particles);
    let sets: Vec<(String, std::ops::Range<usize>, &Plan)> = if same_n {
        let all = 0..ranges.last().map_or(0, |r| r.end);
        vec![(String::new(), all, &groups[0].plan)]
    } else {
        groups
            .iter()
            .zip(ranges)
            .map(|(g, r)| {
                (
                    format!("_point{}", g.point.unwrap_or(0)),
                    r.clone(),
                    &g.plan,
                )
            })
            .collect()
    };
    for (suffix, members, plan) in sets {
        let (t, b) = (snapshots.len() as u64, members.len() as u64);
        let (n, g) = (plan.particles as u64, plan.grid as u64);
        let flat = |f: &dyn Fn(&Snapshot) -> &Vec<f64>| -> Vec<f64> {
            snapshots
                .iter()
                .flat_map(|at| &at[members.clone()])
                .flat_map(|s| f(s).iter().copied())
                .collect()
        };
        let name = |what: &str| dir.join(format!("reference_{what}{suffix}.npy"));
        write_npy(name("gaps"), &[t, b, n], &flat(&|s| &s.gaps))?;
        write_npy(
            name("velocities"),
            &[t, b, n - 1],
            &flat(&|s| &s.velocities),
        )?;
        write_npy(name("rho"), &[t, b, g], &flat(&|s| &s.rho))?;
    }
    write_npy(
        dir.join("times.npy"),
        &[snapshots.len() as u64],
        &groups[0].plan.output_times,
    )?;
    Ok(())
}
