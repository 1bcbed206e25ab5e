//! Solving one chunk of members through the [`BatchSolver`](crate::backend::BatchSolver) seam
//! ([`solve_chunk`]) and turning its snapshots into the chunk's statistics and `members.csv`
//! rows.

use std::path::PathBuf;
use std::time::Instant;

use super::files::{ChunkFile, MemberRow, StudyHeader};
use super::state::StudyState;
use super::{FIELDS, SCALARS};
use crate::backend::gpu::solver::GpuStats;
use crate::backend::{Engine, MemberStatus};
use crate::ensemble::members::EnsembleMembers;
use crate::error::{Error, Result};
use crate::model::chain::Chain;
use crate::model::observables::Snapshot;
use crate::model::params::MemberParams;
use crate::model::plan::Plan;
use crate::output::{write_npy, ProgressReporter};
use crate::scene::{EnsembleSpec, Scene};

/// The plan of a chunk: the scene's, with these members, and the fields the statistics need.
pub(super) fn chunk_plan(scene: &Scene, first_chain: &Chain, members: Vec<MemberParams>) -> Plan {
    let mut plan = Plan::new(scene, first_chain);
    plan.members = members;
    plan.repulsion = first_chain.dstar.is_some();
    plan.fields.rho_star = plan.repulsion;
    plan.fields.rho = true;
    plan.fields.u = true;
    plan
}

/// One member's observables at one output time, as far as the statistics need them: kept until
/// the chunk is solved, because a member that fails later must not enter the statistics of any
/// time (failed members are counted and listed, never averaged in).
struct RecordedObservables {
    /// The values of [`SCALARS`], in that order.
    scalars: [f64; SCALARS.len()],
    /// The rows of [`FIELDS`], in that order.
    fields: [Vec<f64>; FIELDS.len()],
}

/// Solves members [first, end) with a solver from `engine` (the study's backend, through the
/// `BatchSolver` seam) and returns the chunk's statistics and `members.csv` rows.
#[allow(clippy::too_many_arguments)]
/// What the solved chunks of one invocation cost beyond the solve itself.
#[derive(Debug, Default)]
pub(super) struct StudyCosts {
    /// Wall time spent on statistics.
    pub statistics_seconds: f64,
    /// The GPU's work counters summed over chunks (`None` on the CPU).
    pub gpu: Option<GpuStats>,
}

pub(super) fn solve_chunk(
    scene: &Scene,
    spec: &EnsembleSpec,
    members: &EnsembleMembers,
    header: &StudyHeader,
    engine: &Engine,
    first: u64,
    end: u64,
    costs: &mut StudyCosts,
    progress: &ProgressReporter,
) -> Result<ChunkFile> {
    let mut chains = Vec::with_capacity((end - first) as usize);
    let mut params = Vec::with_capacity(chains.capacity());
    let mut velocity = Vec::with_capacity(chains.capacity());
    for m in first..end {
        let inputs = members.member(scene, spec, m)?;
        chains.push(inputs.chain);
        params.push(inputs.params);
        velocity.push((inputs.velocity_factor, inputs.velocity_phase));
    }
    let plan = chunk_plan(scene, &chains[0], params.clone());
    let t_count = header.times.len();
    let grid = header.x.len();
    let mut state = StudyState::for_header(header)?;
    state.ranges.push((first, end));
    let count = (end - first) as usize;
    let mut peak = vec![(f64::NEG_INFINITY, f64::NAN); count];
    let mut min_gap = vec![f64::INFINITY; count];
    let mut final_energy = vec![f64::NAN; count];
    let mut first_hit = vec![f64::NAN; count];
    let dstar_summary: Vec<(f64, f64)> = chains
        .iter()
        .map(|c| match &c.dstar {
            Some(d) => {
                let mean = d.iter().sum::<f64>() / d.len() as f64;
                let max_d = d.iter().fold(0.0f64, |a, &b| a.max(b));
                (mean, 2.0 * c.eps / (max_d + 2.0 * c.eps))
            }
            None => (f64::NAN, f64::NAN),
        })
        .collect();

    // Full per-member arrays, only when asked for: [member, time, ...] per chunk.
    let keep = spec.store_members;
    let mut kept_gaps: Vec<f64> = Vec::new();
    let mut kept_vel: Vec<f64> = Vec::new();
    let mut kept_rho: Vec<f64> = Vec::new();
    let mut per_time: Vec<Vec<Snapshot>> = Vec::new();
    // Per output time, per member (None once failed).
    let mut recorded: Vec<Vec<Option<RecordedObservables>>> = Vec::with_capacity(t_count);
    let mut consume = |k: usize, snaps: &[Snapshot], failed_now: &[bool]| {
        if keep {
            per_time.push(snaps.to_vec());
        }
        let started = Instant::now();
        let t = header.times[k];
        let mut row = Vec::with_capacity(snaps.len());
        for (i, s) in snaps.iter().enumerate() {
            if failed_now[i] {
                row.push(None);
                continue;
            }
            let centre = peak_centre(&header.x, &s.rho);
            if s.max_density > peak[i].0 {
                peak[i] = (s.max_density, t);
            }
            min_gap[i] = min_gap[i].min(s.min_gap);
            final_energy[i] = s.energy;
            if first_hit[i].is_nan() && s.max_density >= spec.threshold {
                first_hit[i] = t;
            }
            row.push(Some(RecordedObservables {
                scalars: [s.max_density, s.min_gap, s.energy, s.dissipation, centre],
                fields: [s.rho.clone(), s.u.clone(), s.rho_star.clone()],
            }));
        }
        recorded.push(row);
        costs.statistics_seconds += started.elapsed().as_secs_f64();
    };

    let mut solver = engine.solver(plan, chains)?;
    let mut k = 0;
    while let Some(snaps) = solver.next_output(&|_| {})? {
        let failed_now: Vec<bool> = solver
            .reports()
            .iter()
            .map(|r| r.status != MemberStatus::Ok)
            .collect();
        consume(k, &snaps, &failed_now);
        k += 1;
    }
    let reports = solver.reports();
    if let Some(work) = solver.gpu_stats() {
        costs
            .gpu
            .get_or_insert_with(Default::default)
            .accumulate(&work);
    }
    progress.inc(count as u64);
    let started = Instant::now();
    let ok_member: Vec<bool> = reports
        .iter()
        .map(|r| r.status == MemberStatus::Ok)
        .collect();
    for (k, row) in recorded.iter().enumerate() {
        for (i, observed) in row.iter().enumerate() {
            if let (true, Some(o)) = (ok_member[i], observed) {
                for (name, &v) in SCALARS.iter().zip(&o.scalars) {
                    state.scalars.get_mut(*name).expect("known observable")[k].push(v);
                }
            }
        }
        for (f, name) in FIELDS.iter().enumerate() {
            let rows: Vec<&[f64]> = row
                .iter()
                .zip(&ok_member)
                .filter_map(|(observed, &ok)| if ok { observed.as_ref() } else { None })
                .map(|o| o.fields[f].as_slice())
                .filter(|r| r.len() == grid)
                .collect();
            state.fields.get_mut(*name).expect("known field")[k]
                .push_rows(&rows)
                .expect("rows have the grid's length");
        }
    }
    costs.statistics_seconds += started.elapsed().as_secs_f64();
    if keep {
        let n = header_particles(&per_time);
        for i in 0..count {
            for snaps in &per_time {
                let s = &snaps[i];
                let pad = |v: &[f64], len: usize| {
                    if v.len() == len {
                        v.to_vec()
                    } else {
                        vec![f64::NAN; len]
                    }
                };
                kept_gaps.extend(pad(&s.gaps, n));
                kept_vel.extend(pad(&s.velocities, n.saturating_sub(1)));
                kept_rho.extend(pad(&s.rho, grid));
            }
        }
        let members_dir = header_dir(header).join("members");
        std::fs::create_dir_all(&members_dir).map_err(|e| Error::io(&members_dir, e))?;
        let (c, t, n) = (count as u64, t_count as u64, n as u64);
        let name = |what: &str| members_dir.join(format!("chunk_{first:012}_{end:012}_{what}.npy"));
        write_npy(name("gaps"), &[c, t, n], &kept_gaps)?;
        write_npy(name("velocities"), &[c, t, n - 1], &kept_vel)?;
        write_npy(name("rho"), &[c, t, grid as u64], &kept_rho)?;
    }

    let mut rows = Vec::with_capacity(count);
    for (i, r) in reports.iter().enumerate() {
        let m = first + i as u64;
        let (status, failure_time) = match &r.status {
            MemberStatus::Ok => ("ok".to_string(), f64::NAN),
            MemberStatus::Failed { time, .. } => ("failed".to_string(), *time),
        };
        let failed = r.status != MemberStatus::Ok;
        if failed {
            state.failed.push(m);
        } else {
            state.completed += 1;
            if first_hit[i].is_nan() {
                state.never_hit += 1;
            } else {
                state.first_hit.push(first_hit[i]);
            }
        }
        rows.push(MemberRow {
            member: m,
            sweep_point: members.sweep_point(m),
            mu: r.mu,
            gamma: r.gamma,
            status,
            failure_time,
            velocity_factor: velocity[i].0,
            velocity_phase: velocity[i].1,
            mean_dstar: dstar_summary[i].0,
            min_rho_star: dstar_summary[i].1,
            peak_density: if failed { f64::NAN } else { peak[i].0 },
            peak_time: if failed { f64::NAN } else { peak[i].1 },
            min_gap: if failed { f64::NAN } else { min_gap[i] },
            final_energy: if failed { f64::NAN } else { final_energy[i] },
            first_hit_time: first_hit[i],
            steps_accepted: r.steps_accepted,
            steps_rejected: r.steps_rejected,
        });
    }
    Ok(ChunkFile {
        range: (first, end),
        state,
        rows,
    })
}

/// N of the stored chunk (from any member's gaps; failed members have none after failing).
fn header_particles(per_time: &[Vec<Snapshot>]) -> usize {
    per_time
        .iter()
        .flat_map(|s| s.iter())
        .map(|s| s.gaps.len())
        .max()
        .unwrap_or(0)
}

fn header_dir(header: &StudyHeader) -> PathBuf {
    PathBuf::from(&header.out_dir)
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
