//! The members `accuracy` measures (spread over a sweep's points), their runs at one setting,
//! and their errors against the reference.

use std::time::Instant;

use super::{Errors, Run, Setting};
use crate::backend::select;
use crate::error::Result;
use crate::model::chain::Chain;
use crate::model::observables::Snapshot;
use crate::model::plan::Plan;
use crate::scene::members::EnsembleMembers;
use crate::scene::Scene;

/// How many sweep points a parameter study's accuracy measures by default: the first, the last
/// and two between.
pub const DEFAULT_SWEEP_POINTS: u64 = 4;

/// Measured members that one plan holds: the members of one sweep point (or the scene's).
pub(super) struct MeasuredGroup {
    pub(super) plan: Plan,
    pub(super) chains: Vec<Chain>,
    /// The sweep point (`None` without a sweep).
    pub(super) point: Option<u64>,
}

/// The sweep points measured when `count` members are asked for out of `points` points: evenly
/// spread, the first and the last always among them, each point at most once.
pub(super) fn spread_points(points: u64, count: u64) -> Vec<u64> {
    if count <= 1 || points <= 1 {
        return vec![0];
    }
    let k = count.min(points);
    let mut chosen: Vec<u64> = (0..k)
        .map(|j| ((j as f64 * (points - 1) as f64 / (k - 1) as f64).round() as u64).min(points - 1))
        .collect();
    chosen.dedup();
    chosen
}

/// The members the trade is measured on, in groups that one plan holds. Without a sweep: the
/// scene's first `count` (default 1). In a parameter study: the first members of sweep points
/// spread over the sweep ([`spread_points`]; default [`DEFAULT_SWEEP_POINTS`] points), and when
/// `count` exceeds the points, every point with `count / points` members (rounded up), built as
/// the study builds them. Also returns the scene of the first measured point (its time settings
/// are every point's).
pub(super) fn measured_members(
    scene: &Scene,
    count: Option<usize>,
) -> Result<(Scene, Vec<MeasuredGroup>)> {
    if let Some(spec) = &scene.ensemble {
        let members = EnsembleMembers::new(scene, spec)?;
        let count = match count {
            Some(c) => c as u64,
            None => members.points.min(DEFAULT_SWEEP_POINTS),
        };
        let points = spread_points(members.points, count);
        let per_point = count
            .div_ceil(points.len() as u64)
            .clamp(1, members.per_point);
        let mut groups = Vec::new();
        for &p in &points {
            let mut chains = Vec::new();
            let mut params = Vec::new();
            for j in 0..per_point {
                let inputs = members.member(p * members.per_point + j)?;
                chains.push(inputs.chain);
                params.push(inputs.params);
            }
            let setup = members.setup(p)?;
            // The sequence, as order and stepping, is each setting's (`solve`).
            let mut plan = setup.scene.plan(&chains[0], setup.scene.precision);
            plan.members = params;
            groups.push(MeasuredGroup {
                plan,
                chains,
                point: (members.points > 1).then_some(p),
            });
        }
        let scene = members.setup(points[0])?.scene.clone();
        return Ok((scene, groups));
    }
    // A `[batch]` (mu and gamma lists) is a sweep of one member per value: its members are
    // spread like sweep points.
    let chain = scene.initial_chain()?;
    let all = scene.member_parameters();
    let listed = all.len() as u64;
    let chosen = if listed > 1 {
        spread_points(listed, count.map_or(DEFAULT_SWEEP_POINTS, |c| c as u64))
    } else {
        vec![0]
    };
    let mut plan = scene.plan(&chain, scene.precision);
    plan.members = chosen.iter().map(|&m| all[m as usize]).collect();
    let chains = vec![chain; plan.members.len()];
    // With several listed members, each is a group of its own, so the worst can be named.
    let groups = if listed > 1 {
        chosen
            .iter()
            .zip(&plan.members)
            .map(|(&m, &params)| {
                let mut one = plan.clone();
                one.members = vec![params];
                MeasuredGroup {
                    plan: one,
                    chains: vec![chains[0].clone()],
                    point: Some(m),
                }
            })
            .collect()
    } else {
        vec![MeasuredGroup {
            plan,
            chains,
            point: None,
        }]
    };
    Ok((scene.clone(), groups))
}

/// Runs every group at `setting`; the snapshots are the groups' members side by side (per output
/// time, the members of the first group, then of the second, ...), the wall time and the steps
/// their sums.
pub(super) fn solve(groups: &[MeasuredGroup], setting: &Setting) -> Result<Run> {
    let mut run = Run {
        snapshots: Vec::new(),
        wall: 0.0,
        accepted: 0,
        rejected: 0,
        failure: None,
    };
    for group in groups {
        let mut plan = group.plan.clone();
        plan.order = setting.order;
        plan.stepping = setting.stepping;
        plan.sequence = setting.sequence;
        plan.jacobian = setting.jacobian;
        let engine = select(setting.backend, setting.precision, &plan)?;
        let mut solver = engine.solver(plan, group.chains.clone())?;
        // From the built solver: the GPU's shader compilation (~1 s a kernel variant on
        // lavapipe), which a long run pays once, made the first rung of each GPU line 5-15 times
        // slower than the next and hid the coarse rungs, the likely cheapest.
        let started = Instant::now();
        let mut k = 0;
        while let Some(s) = solver.next_output(&|_| {})? {
            match run.snapshots.get_mut(k) {
                Some(at) => at.extend(s),
                None => run.snapshots.push(s),
            }
            k += 1;
        }
        run.wall += started.elapsed().as_secs_f64();
        let reports = solver.reports();
        run.accepted += reports.iter().map(|r| r.steps_accepted).sum::<u64>();
        run.rejected += reports.iter().map(|r| r.steps_rejected).sum::<u64>();
        if run.failure.is_none() {
            run.failure = reports.iter().find_map(|r| match &r.status {
                crate::backend::MemberStatus::Failed { reason, time } => Some(format!(
                    "member {} failed at t = {time:.4e}: {reason}",
                    r.index
                )),
                crate::backend::MemberStatus::Ok => None,
            });
        }
    }
    Ok(run)
}

/// The members of each group in the side-by-side snapshots of [`solve`].
pub(super) fn member_ranges(groups: &[MeasuredGroup]) -> Vec<std::ops::Range<usize>> {
    let mut first = 0;
    groups
        .iter()
        .map(|g| {
            let range = first..first + g.chains.len();
            first = range.end;
            range
        })
        .collect()
}

/// The errors of `run` against `reference` (see the documentation of [`accuracy`](super)).
pub fn errors(run: &[Vec<Snapshot>], reference: &[Vec<Snapshot>]) -> Errors {
    let members = reference.first().map_or(0, Vec::len);
    errors_of_members(run, reference, 0..members)
}

/// [`errors`] over the members in `members` only.
pub(super) fn errors_of_members(
    run: &[Vec<Snapshot>],
    reference: &[Vec<Snapshot>],
    members: std::ops::Range<usize>,
) -> Errors {
    let mut e = Errors {
        gaps: 0.0,
        velocities: 0.0,
        rho: 0.0,
    };
    for (at, ref_at) in run.iter().zip(reference) {
        for (s, r) in at[members.clone()].iter().zip(&ref_at[members.clone()]) {
            for (&d, &dr) in s.gaps.iter().zip(&r.gaps) {
                let diff = if d == dr {
                    0.0
                } else {
                    (d.ln() - dr.ln()).abs()
                };
                e.gaps = e.gaps.max(if diff.is_nan() { f64::INFINITY } else { diff });
            }
            let scale = r.velocities.iter().fold(0.0f64, |m, u| m.max(u.abs()));
            for (&u, &ur) in s.velocities.iter().zip(&r.velocities) {
                let diff = (u - ur).abs() / scale.max(f64::MIN_POSITIVE);
                e.velocities = e
                    .velocities
                    .max(if diff.is_nan() { f64::INFINITY } else { diff });
            }
            if !r.rho.is_empty() {
                let l1 = s
                    .rho
                    .iter()
                    .zip(&r.rho)
                    .map(|(a, b)| (a - b).abs())
                    .sum::<f64>()
                    / r.rho.len() as f64;
                e.rho = e.rho.max(if l1.is_nan() { f64::INFINITY } else { l1 });
            }
        }
    }
    e
}
