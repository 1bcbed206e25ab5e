//! The CPU reference backend: members packed into blocks of L lanes (interleaved like the GPU
//! batch, so the Thomas sweeps of L members run side by side in SIMD registers), rayon across
//! blocks, each lane with its own time, step size and status.

pub mod control;
pub mod step;

use rayon::prelude::*;

use crate::backend::{BatchSolver, Progress};
use crate::error::Result;

use crate::model::chain::Chain;
use crate::model::observables::{grid_points, observe, Snapshot};
use crate::model::plan::{Plan, Power};
use crate::model::params::{MemberParams, Stepping};
use crate::backend::report::{Failure, MemberReport, MemberStatus};
use crate::backend::layout::interleave;
use control::{Rules, StepControl};
use step::{euler_step, gap_step_admissible, Gamma, Scratch, Terms};

#[derive(Debug, Clone)]
struct Lane {
    member: Option<usize>,
    control: StepControl,
}

struct Block<const L: usize> {
    lanes: [Lane; L],
    mu: [f64; L],
    gamma: Gamma<L>,
    dstar: Option<Vec<f64>>,
    bonded: Option<Vec<bool>>,
    gaps: Vec<f64>,
    vel: Vec<f64>,
    cand_gaps: Vec<f64>,
    cand_vel: Vec<f64>,
    /// Richardson / error estimate buffers: one full step and the half step.
    full_gaps: Vec<f64>,
    full_vel: Vec<f64>,
    half_gaps: Vec<f64>,
    half_vel: Vec<f64>,
    scratch: Scratch,
}

fn lane_values<const L: usize>(data: &[f64], l: usize) -> Vec<f64> {
    data.iter().skip(l).step_by(L).copied().collect()
}

impl<const L: usize> Block<L> {
    fn new(
        plan: &Plan,
        chains: &[&Chain; L],
        members: [Option<usize>; L],
        params: [MemberParams; L],
        dt0: f64,
    ) -> Self {
        let n = plan.particles;
        let gaps = interleave::<f64>(&chains.map(|c| c.gaps.as_slice()));
        let vel = interleave::<f64>(&chains.map(|c| c.velocities.as_slice()));
        let dstar = plan.repulsion.then(|| {
            interleave::<f64>(
                &chains.map(|c| c.dstar.as_deref().expect("plan.repulsion implies d*")),
            )
        });
        let no_bonds = vec![false; n];
        let bonded = plan
            .clusters
            .then(|| interleave::<bool>(&chains.map(|c| c.bonded.as_deref().unwrap_or(&no_bonds))));
        let gammas = params.map(|p| p.gamma);
        let gamma = if gammas.iter().all(|&g| g == gammas[0]) {
            Gamma::Uniform(Power::of(gammas[0]))
        } else {
            Gamma::PerLane(gammas)
        };
        let lane = |member| Lane {
            member,
            control: StepControl::new(dt0),
        };
        let richardson = plan.order == 2 || matches!(plan.stepping, Stepping::Adaptive { .. });
        let extra = if richardson { gaps.len() } else { 0 };
        let extra_v = if richardson { vel.len() } else { 0 };
        Block {
            lanes: members.map(lane),
            mu: params.map(|p| p.mu),
            gamma,
            dstar,
            bonded,
            cand_gaps: gaps.clone(),
            cand_vel: vel.clone(),
            full_gaps: vec![0.0; extra],
            full_vel: vec![0.0; extra_v],
            half_gaps: vec![0.0; extra],
            half_vel: vec![0.0; extra_v],
            gaps,
            vel,
            scratch: Scratch::new(n, L),
        }
    }

    /// Advances every running lane to `t_end`.
    fn advance(&mut self, plan: &Plan, t_start: f64, t_end: f64) {
        let n = plan.particles;
        let (fixed_dt, adaptive_tol) = match plan.stepping {
            Stepping::Fixed { dt, .. } => (Some(dt), None),
            Stepping::Adaptive { tolerance, .. } => (None, Some(tolerance)),
        };
        let rules = Rules::new(t_start, t_end, fixed_dt, plan.stepping.dt_min());
        for lane in self.lanes.iter_mut() {
            lane.control.begin_interval(&rules);
        }
        let richardson = plan.order == 2 || adaptive_tol.is_some();
        loop {
            let mut active = [false; L];
            let mut h = [0.0; L];
            let mut t = [0.0; L];
            for (l, lane) in self.lanes.iter().enumerate() {
                active[l] = lane.member.is_some() && lane.control.running(&rules);
                t[l] = lane.control.t;
                // Idle lanes compute with their (finite) dt; their result is discarded.
                h[l] = if active[l] {
                    lane.control.trial_step(&rules)
                } else {
                    lane.control.dt
                };
            }
            if !active.iter().any(|&a| a) {
                break;
            }
            let terms = Terms::<L> {
                eps: plan.eps,
                mu: self.mu,
                repulsion: self.dstar.as_deref().map(|d| (d, self.gamma)),
                bonded: self.bonded.as_deref(),
                forcing: plan.forcing.as_ref(),
            };
            let mut err = [0.0; L];
            let ok = if !richardson {
                euler_step(
                    &terms,
                    n,
                    &t,
                    &h,
                    &self.gaps,
                    &self.vel,
                    &mut self.cand_gaps,
                    &mut self.cand_vel,
                    &mut self.scratch,
                )
            } else {
                let ok_full = euler_step(
                    &terms,
                    n,
                    &t,
                    &h,
                    &self.gaps,
                    &self.vel,
                    &mut self.full_gaps,
                    &mut self.full_vel,
                    &mut self.scratch,
                );
                let half = h.map(|x| 0.5 * x);
                let ok_half = euler_step(
                    &terms,
                    n,
                    &t,
                    &half,
                    &self.gaps,
                    &self.vel,
                    &mut self.half_gaps,
                    &mut self.half_vel,
                    &mut self.scratch,
                );
                let mut t_mid = t;
                for l in 0..L {
                    t_mid[l] += half[l];
                }
                let ok_two = euler_step(
                    &terms,
                    n,
                    &t_mid,
                    &half,
                    &self.half_gaps,
                    &self.half_vel,
                    &mut self.cand_gaps,
                    &mut self.cand_vel,
                    &mut self.scratch,
                );
                let mut ok = [false; L];
                for l in 0..L {
                    ok[l] = ok_full[l] && ok_half[l] && ok_two[l];
                }
                if let Some(tol) = adaptive_tol {
                    err = self.error_norm(tol);
                }
                if plan.order == 2 {
                    ok = self.extrapolate(ok);
                }
                ok
            };
            let mut keep_old = [false; L];
            for l in 0..L {
                keep_old[l] = !active[l]
                    || !self.lanes[l]
                        .control
                        .conclude_attempt(&rules, h[l], ok[l], err[l]);
            }
            // Lanes that did not move keep their old state in the candidate buffers.
            if keep_old.iter().any(|&k| k) {
                for (i, (cg, g)) in self.cand_gaps.iter_mut().zip(&self.gaps).enumerate() {
                    if keep_old[i % L] {
                        *cg = *g;
                    }
                }
                for (i, (cv, v)) in self.cand_vel.iter_mut().zip(&self.vel).enumerate() {
                    if keep_old[i % L] {
                        *cv = *v;
                    }
                }
            }
            std::mem::swap(&mut self.gaps, &mut self.cand_gaps);
            std::mem::swap(&mut self.vel, &mut self.cand_vel);
        }
    }

    /// Scaled max-norm of (two half steps − one full step): relative on free gaps (a gap's error
    /// must be small against the gap itself), mixed absolute/relative on velocities.
    fn error_norm(&self, tol: f64) -> [f64; L] {
        let mut err = [0.0f64; L];
        for (i, (a, b)) in self.cand_gaps.iter().zip(&self.full_gaps).enumerate() {
            let l = i % L;
            if self.bonded.as_ref().is_some_and(|bd| bd[i]) {
                continue;
            }
            let e = (a - b).abs() / (tol * a.abs());
            err[l] = if e.is_nan() {
                f64::INFINITY
            } else {
                err[l].max(e)
            };
        }
        for (i, (a, b)) in self.cand_vel.iter().zip(&self.full_vel).enumerate() {
            let l = i % L;
            let e = (a - b).abs() / (tol * (1.0 + a.abs()));
            err[l] = if e.is_nan() {
                f64::INFINITY
            } else {
                err[l].max(e)
            };
        }
        err
    }

    /// Order 2: cand ← 2·(two half steps) − (one full step); free gaps must stay positive.
    fn extrapolate(&mut self, mut ok: [bool; L]) -> [bool; L] {
        for (i, ((a, b), old)) in self
            .cand_gaps
            .iter_mut()
            .zip(&self.full_gaps)
            .zip(&self.gaps)
            .enumerate()
        {
            *a = 2.0 * *a - b;
            let free = self.bonded.as_ref().is_none_or(|bd| !bd[i]);
            ok[i % L] &= !free || gap_step_admissible(*old, *a);
        }
        for (i, (a, b)) in self.cand_vel.iter_mut().zip(&self.full_vel).enumerate() {
            *a = 2.0 * *a - b;
            ok[i % L] &= a.is_finite();
        }
        ok
    }

    fn snapshot(
        &self,
        plan: &Plan,
        params: &[MemberParams],
        grid_x: &[f64],
    ) -> Vec<(usize, Snapshot)> {
        let mut out = Vec::new();
        for (l, lane) in self.lanes.iter().enumerate() {
            let Some(member) = lane.member else { continue };
            if lane.control.failure != Failure::None {
                out.push((member, Snapshot::failed(plan)));
                continue;
            }
            let dstar = self.dstar.as_ref().map(|d| lane_values::<L>(d, l));
            let bonded = self
                .bonded
                .as_ref()
                .map(|b| b.iter().skip(l).step_by(L).copied().collect::<Vec<bool>>());
            out.push((
                member,
                observe(
                    plan,
                    &params[member],
                    lane_values::<L>(&self.gaps, l),
                    lane_values::<L>(&self.vel, l),
                    dstar.as_deref(),
                    bonded.as_deref(),
                    grid_x,
                ),
            ));
        }
        out
    }

    fn reports(&self, params: &[MemberParams], dt_min: f64) -> Vec<MemberReport> {
        self.lanes
            .iter()
            .filter_map(|lane| {
                let m = lane.member?;
                Some(MemberReport {
                    index: m,
                    mu: params[m].mu,
                    gamma: params[m].gamma,
                    status: match lane.control.failure {
                        Failure::None => MemberStatus::Ok,
                        f => MemberStatus::Failed {
                            reason: f.describe(dt_min),
                            time: lane.control.failure_time,
                        },
                    },
                    steps_accepted: lane.control.accepted,
                    steps_rejected: lane.control.rejected,
                    last_dt: lane.control.dt,
                })
            })
            .collect()
    }
}

enum Blocks {
    Single(Vec<Block<1>>),
    Eight(Vec<Block<8>>),
}

/// The CPU backend: a batch of members sharing N, each with its own chain and parameters.
pub struct CpuSolver {
    plan: Plan,
    blocks: Blocks,
    grid_x: Vec<f64>,
    time_index: usize,
}

fn build_blocks<const L: usize>(plan: &Plan, chains: &[Chain], dt0: f64) -> Vec<Block<L>> {
    let b = plan.members.len();
    (0..b.div_ceil(L))
        .map(|k| {
            let members: [Option<usize>; L] = std::array::from_fn(|l| {
                let m = k * L + l;
                (m < b).then_some(m)
            });
            // Padding lanes repeat the block's first member and never step.
            let pick = |l: usize| members[l].unwrap_or(k * L);
            let chain_refs: [&Chain; L] = std::array::from_fn(|l| &chains[pick(l)]);
            let params: [MemberParams; L] = std::array::from_fn(|l| plan.members[pick(l)]);
            Block::new(plan, &chain_refs, members, params, dt0)
        })
        .collect()
}

impl CpuSolver {
    /// `chains[m]` is member m's initial chain (all with the plan's N and eps).
    pub fn new(plan: Plan, chains: Vec<Chain>) -> CpuSolver {
        assert_eq!(chains.len(), plan.members.len(), "one chain per member");
        let dt0 = match plan.stepping {
            Stepping::Fixed { dt, .. } => dt,
            Stepping::Adaptive { dt_initial, .. } => dt_initial,
        };
        let blocks = if plan.members.len() >= 8 {
            Blocks::Eight(build_blocks::<8>(&plan, &chains, dt0))
        } else {
            Blocks::Single(build_blocks::<1>(&plan, &chains, dt0))
        };
        let grid_x = grid_points(plan.grid);
        CpuSolver {
            plan,
            blocks,
            grid_x,
            time_index: 0,
        }
    }

    /// Advances to the next output time and returns every member's snapshot there, in member
    /// order. The first call returns the initial state. `None` after the last output time.
    fn advance_to_next_output(&mut self, progress: Progress) -> Option<Vec<Snapshot>> {
        let k = self.time_index;
        let t_end = *self.plan.output_times.get(k)?;
        let t_start = if k == 0 {
            0.0
        } else {
            self.plan.output_times[k - 1]
        };
        self.time_index += 1;
        let plan = &self.plan;
        let grid = &self.grid_x;
        let mut pairs: Vec<(usize, Snapshot)> = match &mut self.blocks {
            Blocks::Single(bs) => advance_all(bs, plan, grid, t_start, t_end, progress),
            Blocks::Eight(bs) => advance_all(bs, plan, grid, t_start, t_end, progress),
        };
        pairs.sort_by_key(|(m, _)| *m);
        Some(pairs.into_iter().map(|(_, s)| s).collect())
    }

    fn member_reports(&self) -> Vec<MemberReport> {
        let mut r: Vec<MemberReport> = match &self.blocks {
            Blocks::Single(bs) => bs
                .iter()
                .flat_map(|b| b.reports(&self.plan.members, self.plan.stepping.dt_min()))
                .collect(),
            Blocks::Eight(bs) => bs
                .iter()
                .flat_map(|b| b.reports(&self.plan.members, self.plan.stepping.dt_min()))
                .collect(),
        };
        r.sort_by_key(|m| m.index);
        r
    }
}

fn advance_all<const L: usize>(
    blocks: &mut [Block<L>],
    plan: &Plan,
    grid: &[f64],
    t_start: f64,
    t_end: f64,
    progress: Progress,
) -> Vec<(usize, Snapshot)> {
    blocks
        .par_iter_mut()
        .flat_map_iter(|b| {
            if t_end > t_start {
                b.advance(plan, t_start, t_end);
            }
            progress(b.lanes.iter().filter(|l| l.member.is_some()).count() as u64);
            b.snapshot(plan, &plan.members, grid)
        })
        .collect()
}

impl BatchSolver for CpuSolver {
    fn next_output(&mut self, progress: Progress) -> Result<Option<Vec<Snapshot>>> {
        Ok(self.advance_to_next_output(progress))
    }

    fn reports(&self) -> Vec<MemberReport> {
        self.member_reports()
    }

    fn plan(&self) -> &Plan {
        &self.plan
    }

    fn grid(&self) -> &[f64] {
        &self.grid_x
    }
}
