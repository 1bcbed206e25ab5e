//! A block of L members advanced together: the CPU twin of one GPU invocation per member, with
//! the L lanes' sweeps side by side (`step::euler_step`), the Richardson extrapolation and error
//! norm (`error_norm`, `extrapolate`: twins of the same functions in `shaders/step.wgsl`), and
//! per-lane step control (`control`).

use super::control::{Rules, StepControl};
use super::step::{euler_step, gap_step_admissible, Gamma, Scratch, Terms};
use crate::backend::layout::interleave;
use crate::backend::report::{Failure, MemberReport, MemberStatus};
use crate::model::chain::Chain;
use crate::model::observables::{observe, Snapshot};
use crate::model::params::{MemberParams, Stepping};
use crate::model::plan::{Plan, Power};

#[derive(Debug, Clone)]
pub(super) struct Lane {
    pub(super) member: Option<usize>,
    control: StepControl,
}

pub(super) struct Block<const L: usize> {
    pub(super) lanes: [Lane; L],
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
    pub(super) fn new(
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
    pub(super) fn advance(&mut self, plan: &Plan, t_start: f64, t_end: f64) {
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

    pub(super) fn snapshot(
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

    pub(super) fn reports(&self, params: &[MemberParams], dt_min: f64) -> Vec<MemberReport> {
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
