//! Solving one chunk of members through the [`BatchSolver`](crate::backend::BatchSolver) seam
//! ([`solve_chunk`]) and turning its snapshots into the chunk's statistics and `members.csv`
//! rows.

use std::path::Path;
use std::time::Instant;

use super::files::{MemberRow, StudyHeader};
use super::state::StudyState;
use super::{ERROR_ESTIMATE, SCALARS};
use crate::backend::gpu::solver::GpuStats;
use crate::backend::{Engine, MemberReport, MemberStatus};
use crate::ensemble::members::{EnsembleMembers, MemberInputs};
use crate::error::{Error, Result};
use crate::model::chain::Chain;
use crate::model::observables::Snapshot;
use crate::model::params::MemberParams;
use crate::model::plan::Plan;
use crate::output::{write_npy, ProgressReporter};
use crate::scene::{EnsembleSpec, Scene};
use crate::stats::{FieldBand, ScalarSummary};
use rayon::prelude::*;

/// The plan of a chunk: the scene's, with these members, and the fields the statistics need
/// (rho always: the peak density and its centre are read from it; u and rho* where their bands
/// are asked for).
pub(super) fn chunk_plan(
    scene: &Scene,
    first_chain: &Chain,
    members: Vec<MemberParams>,
    store_members: bool,
) -> Plan {
    let mut plan = Plan::new(scene, first_chain);
    plan.members = members;
    plan.repulsion = first_chain.dstar.is_some();
    plan.fields.rho_star = plan.repulsion && scene.fields.rho_star;
    plan.fields.rho = true;
    // Gaps and velocities per member are only read when the members' arrays are kept.
    plan.fields.gaps &= store_members;
    plan.fields.velocities &= store_members;
    plan
}

/// One member's observables at one output time, as far as the statistics need them: kept until
/// the chunk is solved, because a member that fails later must not enter the statistics of any
/// time (failed members are counted and listed, never averaged in).
struct RecordedObservables {
    /// The values of [`SCALARS`], in that order.
    scalars: [f64; SCALARS.len()],
    /// Bit f set: band field f has a row in the chunk's `field_rows` (a snapshot without that
    /// field has none; see [`row_offset`] for where it is).
    rows_present: u8,
}

/// Where the row of band field `f` at output time `k` of the chunk's member `i` starts in the
/// chunk's `field_rows`: laid out [field][time][member][grid point], so that the rows one band
/// reads are consecutive in memory (streamed, not gathered from rows a whole member apart).
fn row_offset(f: usize, k: usize, i: usize, (times, count, grid): (usize, usize, usize)) -> usize {
    ((f * times + k) * count + i) * grid
}

/// The row of band field `name` ("rho", "u" or "rho_star") in a snapshot (empty when the
/// snapshot has none).
fn band_row<'s>(s: &'s Snapshot, name: &str) -> &'s [f64] {
    match name {
        "rho" => &s.rho,
        "u" => &s.u,
        _ => &s.rho_star,
    }
}

/// What the solved chunks of one invocation cost beyond the solve itself.
#[derive(Debug, Default)]
pub(super) struct StudyCosts {
    /// Wall time spent on statistics.
    pub statistics_seconds: f64,
    /// The GPU's work counters summed over chunks (`None` on the CPU).
    pub gpu: Option<GpuStats>,
}

/// Consecutive members [a, b) of a chunk that one batch can hold: the same N, eps, terms
/// (roughness, clusters) and forcing. Members of one sweep point always can; points that differ
/// only in mu, gamma or the random draws share a batch too.
fn batch_groups(inputs: &[MemberInputs], members: &EnsembleMembers) -> Result<Vec<(usize, usize)>> {
    let mut groups: Vec<(usize, usize)> = Vec::new();
    for i in 0..inputs.len() {
        let joins = match groups.last() {
            Some(&(a, _)) => {
                let (x, y) = (&inputs[a], &inputs[i]);
                x.point == y.point
                    || (x.chain.particles() == y.chain.particles()
                        && x.chain.eps.to_bits() == y.chain.eps.to_bits()
                        && x.chain.dstar.is_some() == y.chain.dstar.is_some()
                        && x.chain.bonded.is_some() == y.chain.bonded.is_some()
                        && (members.symbolic_forcing().is_some()
                            || x.setup.scene.forcing == y.setup.scene.forcing))
            }
            None => false,
        };
        match groups.last_mut() {
            Some(g) if joins => g.1 = i + 1,
            _ => groups.push((i, i + 1)),
        }
    }
    Ok(groups)
}

/// Solves members [first, end) with solvers from `engine` (the study's backend, through the
/// `BatchSolver` seam; one batch per group of compatible members), adds their statistics to
/// `total` (the run's, per sweep point) and returns their `members.csv` rows. `field_rows` is
/// scratch space for the recorded field rows, kept by the caller from chunk to chunk.
///
/// The chunk's scalar statistics are summarised on their own and then merged into `total`; its
/// field rows go straight into `total`'s bands, which is the same arithmetic as an empty band
/// merged in (one Chan merge of the chunk's moments per grid point, integer counts) without a
/// chunk-sized copy of every band.
#[allow(clippy::too_many_arguments)]
pub(super) fn solve_chunk(
    dir: &Path,
    spec: &EnsembleSpec,
    members: &EnsembleMembers,
    header: &StudyHeader,
    engine: &Engine,
    (first, end): (u64, u64),
    total: &mut StudyState,
    field_rows: &mut Vec<f64>,
    costs: &mut StudyCosts,
    progress: &ProgressReporter,
) -> Result<Vec<MemberRow>> {
    let inputs: Vec<MemberInputs> = (first..end)
        .map(|m| members.member(m))
        .collect::<Result<_>>()?;
    let t_count = header.times.len();
    let grid = header.x.len();
    let shape = (t_count, (end - first) as usize, grid);
    let any_detailed = inputs.iter().any(|inp| header.is_detailed(inp.point));
    let needed = if any_detailed {
        header.band_fields.len() * t_count * shape.1 * grid
    } else {
        0
    };
    // Only rows written for this chunk are read back (`rows_present`), so the buffer is grown,
    // never cleared: refilling it would write every chunk's worth of rows twice.
    if field_rows.len() < needed {
        field_rows.resize(needed, f64::NAN);
    }
    let mut state = StudyState::new();
    state.ranges.push((first, end));
    let count = (end - first) as usize;
    let mut peak = vec![(f64::NEG_INFINITY, f64::NAN); count];
    let mut min_gap = vec![f64::INFINITY; count];
    let mut final_energy = vec![f64::NAN; count];
    let mut first_hit = vec![f64::NAN; count];
    let dstar_summary: Vec<(f64, f64)> = inputs
        .iter()
        .map(|inp| match &inp.chain.dstar {
            Some(d) => {
                let c = &inp.chain;
                let mean = d.iter().sum::<f64>() / d.len() as f64;
                let max_d = d.iter().fold(0.0f64, |a, &b| a.max(b));
                (mean, 2.0 * c.eps / (max_d + 2.0 * c.eps))
            }
            None => (f64::NAN, f64::NAN),
        })
        .collect();

    // Full per-member arrays, only when asked for: [member, time, ...] per chunk.
    let keep = spec.store_members;
    // Per member, per output time (None once failed), in member order.
    let mut recorded: Vec<Vec<Option<RecordedObservables>>> = Vec::with_capacity(count);
    let mut kept_snapshots: Vec<Vec<Snapshot>> = Vec::new();
    // Each kept member's error estimate at each output time (NaN once failed, or without one).
    let mut kept_estimates: Vec<Vec<f64>> = Vec::new();
    let mut reports: Vec<MemberReport> = Vec::with_capacity(count);
    for (a, b) in batch_groups(&inputs, members)? {
        let setup = inputs[a].setup.clone();
        let params: Vec<MemberParams> = inputs[a..b].iter().map(|i| i.params).collect();
        let chains: Vec<Chain> = inputs[a..b].iter().map(|i| i.chain.clone()).collect();
        let mut plan = chunk_plan(&setup.scene, &chains[0], params, spec.store_members);
        if let (Some(expr), Some(forcing)) = (members.symbolic_forcing(), plan.forcing.as_mut()) {
            forcing.expr = expr.clone();
            forcing.params = inputs[a..b]
                .iter()
                .flat_map(|i| members.forcing_values(i.point))
                .collect();
        }
        let mut group_recorded: Vec<Vec<Option<RecordedObservables>>> =
            (a..b).map(|_| Vec::with_capacity(t_count)).collect();
        let mut group_kept: Vec<Vec<Snapshot>> = (a..b).map(|_| Vec::new()).collect();
        let mut group_estimates: Vec<Vec<f64>> = (a..b).map(|_| Vec::new()).collect();
        let mut solver = engine.solver(plan, chains)?;
        let mut k = 0;
        while let Some(mut snaps) = solver.next_output(&|_| {})? {
            let started = Instant::now();
            let reports_now = solver.reports();
            let t = header.times[k];
            let ok_now = |g: usize| reports_now[g].status == MemberStatus::Ok;
            let recorded_here = |g: usize| ok_now(g) && header.is_detailed(inputs[a + g].point);
            // The per-member work of this output, in one parallel pass: the rows copied into
            // the buffer that lives across chunks (the snapshot's vectors are freed now and
            // reused by the next output's, instead of a chunk's worth of small allocations
            // being held, freed and faulted in again for every chunk), and the peak's centre.
            let fields = header.band_fields.len();
            // The buffer's rows of this output, member after member (`fields` rows each, at
            // least one slot so that every member has its chunk; None where not recorded).
            let per_member = fields.max(1);
            let mut member_rows: Vec<Option<&mut [f64]>> = Vec::new();
            member_rows.resize_with((b - a) * per_member, || None);
            if any_detailed && fields > 0 {
                let mut rest = &mut field_rows[row_offset(0, k, a, shape)..];
                let mut at = row_offset(0, k, a, shape);
                for f in 0..fields {
                    // Fields lie apart in the buffer, in field order.
                    let (_, from) = rest.split_at_mut(row_offset(f, k, a, shape) - at);
                    let (these, after) = from.split_at_mut((b - a) * grid);
                    for (g, row) in these.chunks_mut(grid).enumerate() {
                        member_rows[g * per_member + f] = Some(row);
                    }
                    rest = after;
                    at = row_offset(f, k, b, shape);
                }
            }
            let centres: Vec<f64> = snaps
                .par_iter()
                .zip(member_rows.par_chunks_mut(per_member))
                .enumerate()
                .map(|(g, (s, rows))| {
                    if !recorded_here(g) {
                        return f64::NAN;
                    }
                    for (row, name) in rows.iter_mut().zip(&header.band_fields) {
                        let from = band_row(s, name);
                        if let (Some(into), true) = (row, from.len() == grid) {
                            into.copy_from_slice(from);
                        }
                    }
                    peak_centre(&header.x, &s.rho)
                })
                .collect();
            for (g, s) in snaps.iter_mut().enumerate() {
                let i = a + g;
                // The estimate of the state at this output time (the last one recorded).
                let estimate = match (&reports_now[g].error_estimate, ok_now(g)) {
                    (Some(e), true) => e.last().copied().unwrap_or(f64::NAN),
                    _ => f64::NAN,
                };
                if keep {
                    group_kept[g].push(s.clone());
                    group_estimates[g].push(estimate);
                }
                if !ok_now(g) {
                    group_recorded[g].push(None);
                    continue;
                }
                if s.max_density > peak[i].0 {
                    peak[i] = (s.max_density, t);
                }
                min_gap[i] = min_gap[i].min(s.min_gap);
                final_energy[i] = s.energy;
                if first_hit[i].is_nan() && s.max_density >= spec.threshold {
                    first_hit[i] = t;
                }
                if !recorded_here(g) {
                    // Responses only: nothing per time is kept.
                    continue;
                }
                let mut rows_present = 0u8;
                for (f, name) in header.band_fields.iter().enumerate() {
                    if band_row(s, name).len() == grid {
                        rows_present |= 1 << f;
                    }
                }
                group_recorded[g].push(Some(RecordedObservables {
                    scalars: [
                        s.max_density,
                        s.min_gap,
                        s.energy,
                        s.dissipation,
                        centres[g],
                        estimate,
                    ],
                    rows_present,
                }));
            }
            costs.statistics_seconds += started.elapsed().as_secs_f64();
            k += 1;
        }
        reports.extend(solver.reports());
        if let Some(work) = solver.gpu_stats() {
            costs
                .gpu
                .get_or_insert_with(Default::default)
                .accumulate(&work);
        }
        recorded.extend(group_recorded);
        kept_snapshots.extend(group_kept);
        kept_estimates.extend(group_estimates);
    }
    progress.inc(count as u64);

    // Statistics of the members that completed (a member that failed at any time enters none),
    // per sweep point.
    let started = Instant::now();
    let ok_member: Vec<bool> = reports
        .iter()
        .map(|r| r.status == MemberStatus::Ok)
        .collect();
    // Consecutive members of one sweep point, [i, j).
    let mut groups: Vec<(usize, usize)> = Vec::new();
    for i in 0..count {
        match groups.last_mut() {
            Some(g) if inputs[g.0].point == inputs[i].point => g.1 = i + 1,
            _ => groups.push((i, i + 1)),
        }
    }
    for &(i, j) in &groups {
        let stats = state.point_mut(inputs[i].point, header);
        if stats.is_detailed() {
            // Each (scalar, time) summary is its own accumulator: they are filled in parallel,
            // each from its members in order (the same pushes as one after the other).
            let mut summaries: Vec<(usize, usize, &mut ScalarSummary)> = Vec::new();
            for (name, per_time) in stats.scalars.iter_mut() {
                let s = SCALARS
                    .iter()
                    .position(|n| n == name)
                    .expect("known observable");
                summaries.extend(per_time.iter_mut().enumerate().map(|(k, sum)| (s, k, sum)));
            }
            summaries.par_iter_mut().for_each(|(s, k, summary)| {
                for (m, observed) in recorded[i..j].iter().enumerate() {
                    if let (true, Some(Some(o))) = (ok_member[i + m], observed.get(*k)) {
                        let v = o.scalars[*s];
                        if SCALARS[*s] == ERROR_ESTIMATE && v.is_nan() {
                            // No estimate (order 1, fixed steps): the statistic stays empty.
                            continue;
                        }
                        summary.push(v);
                    }
                }
            });
        }
        for m in i..j {
            if !ok_member[m] {
                stats.failed += 1;
                continue;
            }
            stats.completed += 1;
            stats.peak_density.push(peak[m].0);
            stats.min_gap.push(min_gap[m]);
            stats.final_energy.push(final_energy[m]);
            if first_hit[m].is_nan() {
                stats.never_hit += 1;
            } else {
                stats.first_hit.push(first_hit[m]);
            }
        }
    }
    for (i, r) in reports.iter().enumerate() {
        if r.status == MemberStatus::Ok {
            state.completed += 1;
        } else {
            state.failed.push(first + i as u64);
        }
    }
    total.merge(&state)?;

    // The field rows, into the total's bands.
    for &(i, j) in &groups {
        let setup = inputs[i].setup.clone();
        let u_range = super::files::band_u_range(&setup.spec, &setup.chain);
        let stats = total
            .points
            .get_mut(&inputs[i].point)
            .expect("merged above");
        stats.add_bands(header, u_range)?;
        // Each (field, time) band is its own accumulator: they are filled in parallel, each from
        // its rows in member order (the same sums as one after the other).
        let mut bands: Vec<(usize, usize, &mut FieldBand)> = Vec::new();
        for (name, per_time) in stats.fields.iter_mut() {
            let f = header
                .band_fields
                .iter()
                .position(|n| n == name)
                .expect("a band of a band field");
            bands.extend(per_time.iter_mut().enumerate().map(|(k, b)| (f, k, b)));
        }
        let rows_of = |f: usize, k: usize| -> Vec<&[f64]> {
            (i..j)
                .filter(|&m| ok_member[m])
                .filter(|&m| {
                    recorded[m]
                        .get(k)
                        .and_then(Option::as_ref)
                        .is_some_and(|o| o.rows_present & (1 << f) != 0)
                })
                .map(|m| {
                    let at = row_offset(f, k, m, shape);
                    &field_rows[at..at + grid]
                })
                .collect()
        };
        bands
            .par_iter_mut()
            .try_for_each(|(f, k, band)| band.push_rows(&rows_of(*f, *k)))
            .map_err(|e| super::report::stats_error(dir, e))?;
    }
    costs.statistics_seconds += started.elapsed().as_secs_f64();
    if keep {
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
        for snaps in &kept_snapshots {
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
        write_npy(name("velocities"), &[c, t, n - 1], &kept_vel)?;
        write_npy(name("rho"), &[c, t, grid as u64], &kept_rho)?;
        let estimates: Vec<f64> = kept_estimates
            .iter()
            .flat_map(|e| (0..t_count).map(|k| e.get(k).copied().unwrap_or(f64::NAN)))
            .collect();
        write_npy(name("error_estimate"), &[c, t], &estimates)?;
    }

    let mut rows = Vec::with_capacity(count);
    for (i, r) in reports.iter().enumerate() {
        let m = first + i as u64;
        let (status, failure_time) = match &r.status {
            MemberStatus::Ok => ("ok".to_string(), f64::NAN),
            MemberStatus::Failed { time, .. } => ("failed".to_string(), *time),
        };
        let failed = r.status != MemberStatus::Ok;
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
            velocity_factor: inputs[i].velocity_factor,
            velocity_phase: inputs[i].velocity_phase,
            mean_dstar: dstar_summary[i].0,
            min_rho_star: dstar_summary[i].1,
            peak_density: if failed { f64::NAN } else { peak[i].0 },
            peak_time: if failed { f64::NAN } else { peak[i].1 },
            min_gap: if failed { f64::NAN } else { min_gap[i] },
            final_energy: if failed { f64::NAN } else { final_energy[i] },
            first_hit_time: first_hit[i],
            steps_accepted: r.steps_accepted,
            steps_rejected: r.steps_rejected,
            error_estimate: match (&r.error_estimate, failed) {
                (Some(e), false) => e.last().copied().unwrap_or(f64::NAN),
                _ => f64::NAN,
            },
        });
    }
    Ok(rows)
}

/// Centre of mass of the density peak: the centroid of the excess of rho over its spatial mean
/// (NaN when the profile is flat).
pub fn peak_centre(x: &[f64], rho: &[f64]) -> f64 {
    if rho.is_empty() {
        return f64::NAN;
    }
    let mean = rho.iter().sum::<f64>() / rho.len() as f64;
    let (mut wx, mut w) = (0.0, 0.0);
    for (xi, r) in x.iter().zip(rho) {
        let e = (r - mean).max(0.0);
        wx += xi * e;
        w += e;
    }
    if w > 1e-12 {
        wx / w
    } else {
        f64::NAN
    }
}
