//! A block of L members advanced together: the CPU twin of one GPU invocation per member, with
//! the L lanes' sweeps side by side (`step::euler_step`), the Richardson extrapolation and error
//! norm (`error_norm`, `extrapolate`: twins of the same functions in `shaders/step.wgsl`), and
//! per-lane step control (`control`).

use super::control::{energy_acceptable, Outcome, Rules, StepControl, ENERGY_RTOL_F64};
use super::step::{
    conclude, encode_ln_gap, euler_step, state_energy, stored_ln, Gamma, HardFailure, Scratch,
    StepReport, Terms, GAP_FLOOR,
};
use crate::backend::layout::interleave;
use crate::backend::report::{Failure, FailureRecord, MemberReport, MemberStatus};
use crate::model::chain::{stored_gap, Chain};
use crate::model::observables::{observe, Snapshot};
use crate::model::params::{MemberParams, Stepping};
use crate::model::plan::{Plan, Power};

#[derive(Debug, Clone)]
pub(super) struct Lane {
    pub(super) member: Option<usize>,
    control: StepControl,
}

/// What the lanes' model is made of: the owned data behind a step's [`Terms`]. Kept apart from
/// the state buffers so that the terms can be borrowed while the step writes those.
struct LaneModel<const L: usize> {
    mu: [f64; L],
    gamma: Gamma<L>,
    dstar: Option<Vec<f64>>,
    bonded: Option<Vec<bool>>,
    /// sum d_i of each lane's initial chain (kept by every step's projection).
    total_gap: [f64; L],
    /// See `Terms::contact_repulsion`.
    contact_repulsion: [f64; L],
    /// Each lane's member (for its forcing parameters).
    members: [Option<usize>; L],
}

impl<const L: usize> LaneModel<L> {
    fn terms<'a>(&'a self, plan: &'a Plan) -> Terms<'a, L> {
        Terms::<L> {
            eps: plan.eps,
            mu: self.mu,
            total_gap: self.total_gap,
            contact_repulsion: self.contact_repulsion,
            repulsion: self.dstar.as_deref().map(|d| (d, self.gamma)),
            bonded: self.bonded.as_deref(),
            forcing: plan.forcing.as_ref(),
            forcing_params: std::array::from_fn(|l| {
                match (plan.forcing.as_ref(), self.members[l]) {
                    (Some(f), Some(m)) => f.member_params(m),
                    _ => &[],
                }
            }),
        }
    }
}

pub(super) struct Block<const L: usize> {
    pub(super) lanes: [Lane; L],
    model: LaneModel<L>,
    /// Gaps in the stored form (`stored_gap`): d, or ln d below GAP_FLOOR, or 0 when bonded.
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
        let total_gap = chains.map(|c| c.gaps.iter().sum::<f64>());
        // max_i ((d*_i + 2eps)/2eps)^gamma: the repulsion of gap i at contact.
        let contact_repulsion: [f64; L] = std::array::from_fn(|l| {
            chains[l].dstar.as_ref().map_or(0.0, |dstar| {
                let widest = dstar.iter().fold(0.0f64, |m, &d| m.max(d));
                Power::of(params[l].gamma).apply((widest + 2.0 * plan.eps) / (2.0 * plan.eps))
            })
        });
        let mut gaps = interleave::<f64>(&chains.map(|c| c.gaps.as_slice()));
        for d in gaps.iter_mut() {
            *d = stored_gap::encode(*d, GAP_FLOOR);
        }
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
        let mut block = Block {
            lanes: members.map(lane),
            model: LaneModel {
                mu: params.map(|p| p.mu),
                gamma,
                dstar,
                bonded,
                total_gap,
                contact_repulsion,
                members,
            },
            cand_gaps: gaps.clone(),
            cand_vel: vel.clone(),
            full_gaps: vec![0.0; extra],
            full_vel: vec![0.0; extra_v],
            half_gaps: vec![0.0; extra],
            half_vel: vec![0.0; extra_v],
            gaps,
            vel,
            scratch: Scratch::new(n, L),
        };
        let energy = state_energy(&block.model.terms(plan), n, &block.gaps, &block.vel);
        for (lane, e) in block.lanes.iter_mut().zip(energy) {
            lane.control.energy = e;
        }
        block
    }

    /// Advances every running lane to `t_end`.
    pub(super) fn advance(&mut self, plan: &Plan, t_start: f64, t_end: f64) {
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
            let (outcome, hard, energy) = self.attempt(plan, &t, &h, adaptive_tol, richardson);
            let mut keep_old = [false; L];
            for l in 0..L {
                if !active[l] {
                    keep_old[l] = true;
                    continue;
                }
                let control = &mut self.lanes[l].control;
                if let Some(hard) = hard[l] {
                    match hard {
                        HardFailure::Forcing { particle, x } => {
                            control.fail(Failure::Forcing, particle as u32, x)
                        }
                        HardFailure::Repulsion { gap, ratio } => {
                            control.fail(Failure::Repulsion, gap as u32, ratio)
                        }
                    }
                    keep_old[l] = true;
                    continue;
                }
                if control.conclude_attempt(&rules, h[l], outcome[l]) {
                    control.energy = energy[l];
                } else {
                    keep_old[l] = true;
                    if control.failure != Failure::None {
                        let (index, ln_d) =
                            smallest_gap::<L>(&self.gaps, self.model.bonded.as_deref(), l);
                        control.failure_index = index;
                        control.failure_detail = ln_d;
                    }
                }
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

    /// One trial step of every lane into the candidate buffers: one Euler step, or (Richardson)
    /// one full and two half steps with the error estimate and/or the extrapolation. Returns each
    /// lane's outcome, any hard failure found in the current state, and the candidate's energy.
    #[allow(clippy::type_complexity)]
    fn attempt(
        &mut self,
        plan: &Plan,
        t: &[f64; L],
        h: &[f64; L],
        adaptive_tol: Option<f64>,
        richardson: bool,
    ) -> ([Outcome; L], [Option<HardFailure>; L], [f64; L]) {
        let n = plan.particles;
        let terms = self.model.terms(plan);
        let mut err = [0.0; L];
        let (candidate, hard, work): ([StepReport; L], _, [f64; L]) = if !richardson {
            let r = euler_step(
                &terms,
                n,
                t,
                h,
                &self.gaps,
                &self.vel,
                &mut self.cand_gaps,
                &mut self.cand_vel,
                &mut self.scratch,
            );
            (r, r.map(|x| x.hard), r.map(|x| x.work))
        } else {
            let full = euler_step(
                &terms,
                n,
                t,
                h,
                &self.gaps,
                &self.vel,
                &mut self.full_gaps,
                &mut self.full_vel,
                &mut self.scratch,
            );
            let half = h.map(|x| 0.5 * x);
            let first = euler_step(
                &terms,
                n,
                t,
                &half,
                &self.gaps,
                &self.vel,
                &mut self.half_gaps,
                &mut self.half_vel,
                &mut self.scratch,
            );
            let mut t_mid = *t;
            for l in 0..L {
                t_mid[l] += half[l];
            }
            let mut second = euler_step(
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
            let mut work = [0.0; L];
            for l in 0..L {
                second[l].admissible &= full[l].admissible && first[l].admissible;
                // Two certified halves are a certified step; else E' was computed.
                second[l].certified &= first[l].certified;
                work[l] = first[l].work + second[l].work;
            }
            if let Some(tol) = adaptive_tol {
                err = self.error_norm(tol);
            }
            if plan.order == 2 {
                second = extrapolate(
                    &terms,
                    n,
                    &mut self.cand_gaps,
                    &mut self.cand_vel,
                    &self.full_gaps,
                    &self.full_vel,
                    second,
                );
            }
            (second, full.map(|x| x.hard), work)
        };
        let mut outcome = [Outcome {
            admissible: false,
            energy_ok: false,
            err: 0.0,
        }; L];
        // The energy the step started from, where a lane needs it and it was not computed (the
        // previous step was certified).
        let unknown = (0..L).any(|l| !candidate[l].certified && self.lanes[l].control.energy < 0.0);
        let current = unknown.then(|| state_energy(&terms, n, &self.gaps, &self.vel));
        for l in 0..L {
            let mut before = self.lanes[l].control.energy;
            if before < 0.0 {
                if let Some(e) = current {
                    before = e[l];
                }
            }
            outcome[l] = Outcome {
                admissible: candidate[l].admissible,
                energy_ok: candidate[l].certified
                    || energy_acceptable(before, candidate[l].energy, work[l], ENERGY_RTOL_F64),
                err: err[l],
            };
        }
        (outcome, hard, candidate.map(|x| x.energy))
    }

    /// Scaled max-norm of (two half steps − one full step): on gaps the error of ln d (a gap's
    /// error measured against the gap itself, at any size), mixed absolute/relative on
    /// velocities.
    fn error_norm(&self, tol: f64) -> [f64; L] {
        let mut err = [0.0f64; L];
        for (i, (&a, &b)) in self.cand_gaps.iter().zip(&self.full_gaps).enumerate() {
            let l = i % L;
            if self.model.bonded.as_ref().is_some_and(|bd| bd[i]) {
                continue;
            }
            let e = if a > 0.0 && b > 0.0 {
                (a - b).abs() / (tol * a)
            } else {
                (stored_ln(a) - stored_ln(b)).abs() / tol
            };
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
            let dstar = self.model.dstar.as_ref().map(|d| lane_values::<L>(d, l));
            let bonded = self
                .model
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
                            reason: FailureRecord {
                                failure: f,
                                time: lane.control.failure_time,
                                index: lane.control.failure_index,
                                detail: lane.control.failure_detail,
                            }
                            .describe(dt_min, m, params[m].gamma),
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

/// Index (1-based) and ln d of lane l's smallest free gap.
fn smallest_gap<const L: usize>(gaps: &[f64], bonded: Option<&[bool]>, l: usize) -> (u32, f64) {
    let mut best = (0u32, f64::INFINITY);
    for (i, &v) in gaps.iter().skip(l).step_by(L).enumerate() {
        if bonded.is_some_and(|b| b[i * L + l]) {
            continue;
        }
        let s = stored_ln(v);
        if s < best.1 {
            best = (i as u32 + 1, s);
        }
    }
    best
}

/// Order 2: cand ← the Richardson extrapolation of (two half steps, one full step), in ln d
/// for gaps (ln d' = 2 ln a − ln b: positive by construction) and linear for velocities, then
/// the projection and the energy of the result.
fn extrapolate<const L: usize>(
    terms: &Terms<L>,
    n: usize,
    cand_gaps: &mut [f64],
    cand_vel: &mut [f64],
    full_gaps: &[f64],
    full_vel: &[f64],
    mut report: [StepReport; L],
) -> [StepReport; L] {
    for (i, (a, &b)) in cand_gaps.iter_mut().zip(full_gaps).enumerate() {
        if terms.bonded.is_some_and(|bd| bd[i]) {
            continue;
        }
        let linear = *a * (*a / b);
        // The linear form where both are stored as d and the result stays a normal gap; else in
        // logs (it may leave the range).
        *a = if *a > 0.0 && b > 0.0 && linear >= GAP_FLOOR && linear < f64::INFINITY {
            linear
        } else {
            encode_ln_gap(2.0 * stored_ln(*a) - stored_ln(b))
        };
    }
    for (a, b) in cand_vel.iter_mut().zip(full_vel) {
        *a = 2.0 * *a - b;
    }
    // The certificate covers Euler steps, not their extrapolation: its energy is computed.
    for r in report.iter_mut() {
        r.certified = false;
    }
    // The work stays that of the two half steps (the caller's).
    let h = [1.0; L];
    conclude::<L>(terms, n, &h, cand_gaps, cand_vel, &mut report);
    report
}
