//! What a chunk writes per member: its rows of members.csv and, with `store_members = true`, its
//! arrays of gaps, velocities, rho and error estimates.

use std::path::Path;

use crate::backend::{MemberReport, MemberStatus};
use crate::error::{Error, Result};
use crate::model::observables::Snapshot;
use crate::output::write_npy;
use crate::study::files::{MemberRow, StudyHeader};

use super::MemberInputs;

/// Each member's scalar responses over the chunk's output times (its peak density with its time,
/// smallest gap, final energy, first time at the threshold).
pub(super) struct Responses {
    pub peak: Vec<(f64, f64)>,
    pub min_gap: Vec<f64>,
    pub final_energy: Vec<f64>,
    pub first_hit: Vec<f64>,
}

/// The chunk's rows of members.csv (member `first + i` is `inputs[i]`); a failed member's
/// responses are NaN, its status and failure time say why.
pub(super) fn member_rows(
    first: u64,
    header: &StudyHeader,
    inputs: &[MemberInputs],
    reports: &[MemberReport],
    responses: &Responses,
    dstar_summary: &[(f64, f64)],
) -> Vec<MemberRow> {
    let mut rows = Vec::with_capacity(reports.len());
    for (i, r) in reports.iter().enumerate() {
        let m = first + i as u64;
        let (status, failure_time, failure_reason) = match &r.status {
            MemberStatus::Ok => ("ok".to_string(), f64::NAN, String::new()),
            MemberStatus::Failed { time, reason } => ("failed".to_string(), *time, reason.clone()),
        };
        let failed = r.status != MemberStatus::Ok;
        // A failed member's responses are not numbers of its run.
        let if_ok = |v: f64| if failed { f64::NAN } else { v };
        let point = inputs[i].point;
        rows.push(MemberRow {
            member: m,
            sweep_point: point,
            parameters: header.point_values(point),
            mu: r.mu,
            gamma: r.gamma,
            particles: inputs[i].chain.particles(),
            status,
            failure_time,
            failure_reason,
            velocity_factor: inputs[i].velocity_factor,
            velocity_phase: inputs[i].velocity_phase,
            mean_dstar: dstar_summary[i].0,
            min_rho_star: dstar_summary[i].1,
            peak_density: if_ok(responses.peak[i].0),
            peak_time: if_ok(responses.peak[i].1),
            min_gap: if_ok(responses.min_gap[i]),
            final_energy: if_ok(responses.final_energy[i]),
            first_hit_time: responses.first_hit[i],
            steps_accepted: r.steps_accepted,
            steps_rejected: r.steps_rejected,
            error_estimate: match (&r.error_estimate, failed) {
                (Some(_), false) => r.largest_error_estimate().unwrap_or(f64::NAN),
                _ => f64::NAN,
            },
        });
    }
    rows
}

/// The chunk's per-member arrays (`store_members = true`): gaps, velocities, rho and the error
/// estimate of each kept member at each output time, NaN-padded where a member failed, into
/// `dir/members/chunk_<first>_<end>_<what>.npy`.
pub(super) fn write_kept_members(
    dir: &Path,
    (first, end): (u64, u64),
    grid: usize,
    t_count: usize,
    kept_snapshots: &[Vec<Snapshot>],
    kept_estimates: &[Vec<f64>],
) -> Result<()> {
    let count = (end - first) as usize;
    let n = kept_snapshots
        .iter()
        .flat_map(|s| s.iter())
        .map(|s| s.gaps.len())
        .max()
        .unwrap_or(0);
    let mut kept_gaps: Vec<f64> = Vec::new();
    let mut kept_vel: Vec<f64> = Vec::new();
    let mut kept_rho: Vec<f64> = Vec::new();
    let pad = |v: &[f64], len: usize| {
        if v.len() == len {
            v.to_vec()
        } else {
            vec![f64::NAN; len]
        }
    };
    for snaps in kept_snapshots {
        for s in snaps {
            kept_gaps.extend(pad(&s.gaps, n));
            kept_vel.extend(pad(&s.velocities, n.saturating_sub(1)));
            kept_rho.extend(pad(&s.rho, grid));
        }
    }
    // Into the directory being written (the staging directory of a fresh study).
    let members_dir = dir.join("members");
    std::fs::create_dir_all(&members_dir).map_err(|e| Error::io(&members_dir, e))?;
    let (c, t, n) = (count as u64, t_count as u64, n as u64);
    let name = |what: &str| members_dir.join(format!("chunk_{first:012}_{end:012}_{what}.npy"));
    write_npy(name("gaps"), &[c, t, n], &kept_gaps)?;
    write_npy(name("velocities"), &[c, t, n.saturating_sub(1)], &kept_vel)?;
    write_npy(name("rho"), &[c, t, grid as u64], &kept_rho)?;
    let estimates: Vec<f64> = kept_estimates
        .iter()
        .flat_map(|e| (0..t_count).map(|k| e.get(k).copied().unwrap_or(f64::NAN)))
        .collect();
    write_npy(name("error_estimate"), &[c, t], &estimates)?;
    Ok(())
}
