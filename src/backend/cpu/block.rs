//! A block of L members advanced together: the CPU twin of one GPU invocation per member, with
//! the L lanes' sweeps side by side (`step::euler_step`), the extrapolation tableau and its
//! error estimates (`roughlub_kernels::tableau::extrapolate`, twin of the one in `shaders/step.wgsl`), and
//! per-lane step and order control (`control`). The state and the step compute in T (f64 or
//! f32, [`Real`]); the control (times, steps, energies, estimates) in f64 (see `real.rs`).
//!
//! Just over 700 lines on purpose: one `Block` holds its lanes' state, and its attempts
//! (`advance`, `euler_attempt`, `extrapolated_attempt`: rows, tableau, energy check, control)
//! follow `shaders/step.wgsl`'s attempt loop side by side with it; the tableau's bookkeeping is
//! apart (`tableau`), and what remains (snapshots, reports) reads the same lane state.

mod tableau;

use super::real::{energy_rtol, Real};
use super::step::{
    stored_ln, EnergyWanted, Gamma, HardFailure, Scratch, StepBuffers, StepReport, Terms,
};
use super::SimdLevel;
use crate::backend::layout::interleave;
use crate::backend::report::{
    error_estimate_method, Failure, FailureRecord, MemberReport, MemberStatus,
};
use crate::backend::shared::control::{
    energy_acceptable, extrapolated_energy_rtol, row_substeps, select_order, sequence_from_two,
    step_factor, Outcome, Rules, StepControl, TIME_RESOLUTION_F64,
};
use crate::backend::OutputStatus;
use crate::model::chain::{stored_gap, Chain};
use crate::model::observables::{observe, set_peak_centres, Snapshot};
use crate::model::params::{MemberParams, Order, Sequence, Stepping, MAX_ORDER};
use crate::model::plan::{Plan, Power};
use roughlub_kernels::tableau::TableauIo;
use roughlub_kernels::BlockKernels;
use tableau::substep_buffers;

#[derive(Debug, Clone)]
pub(super) struct Lane {
    pub(super) member: Option<usize>,
    control: StepControl,
    /// `control.error_sum` at each output time so far.
    error_estimates: Vec<f64>,
}

/// How a trial step is made: one Euler step (order 1, fixed steps), or rows of the
/// extrapolation tableau (row j: n_j Euler substeps of H/n_j, `row_substeps`) combined into the
/// lane's column k (order 1 adaptive: the two rows' difference is the error estimate, the
/// result is row 2).
#[derive(Debug, Clone, Copy)]
struct Scheme {
    order: Order,
    adaptive_tol: Option<f64>,
    /// Auto's highest column (`Plan::top_column`).
    top: u8,
}

impl Scheme {
    fn of(plan: &Plan, f32_rounding: bool) -> Scheme {
        Scheme {
            order: plan.order,
            adaptive_tol: match plan.stepping {
                Stepping::Fixed { .. } => None,
                Stepping::Adaptive { tolerance, .. } => Some(tolerance),
            },
            top: plan.top_column(f32_rounding),
        }
    }

    fn plain_euler(&self) -> bool {
        self.order == Order::Fixed(1) && self.adaptive_tol.is_none()
    }

    /// Rows of the tableau a step of column k computes.
    fn rows(&self, k: u8) -> usize {
        (k as usize).max(2)
    }

    /// Whether the result is the extrapolated T_kk (else row k itself: order 1).
    fn extrapolates(&self) -> bool {
        self.order != Order::Fixed(1)
    }

    /// The power of h the scaled estimate grows with: k (order 1: 2, the estimate is that of
    /// a single Euler step).
    fn estimate_order(&self, k: u8) -> u8 {
        k.max(2)
    }
}

/// What the lanes' model is made of: the owned data behind a step's [`Terms`]. Kept apart from
/// the state buffers so that the terms can be borrowed while the step writes those.
struct LaneModel<T: Real, const L: usize> {
    mu: [T; L],
    gamma: Gamma<L>,
    dstar: Option<Vec<T>>,
    bonded: Option<Vec<bool>>,
    /// sum d_i of each lane's initial chain (kept by every step's projection; f64 in either
    /// precision, see `step::conclude_impl`).
    total_gap: [f64; L],
    /// The energy check's relative slack per lane (`energy_rtol`).
    energy_rtol: [f64; L],
    /// The gamma it is computed for (1 without repulsion), for the extrapolated state's slack.
    energy_gamma: [f64; L],
    /// See `Terms::contact_repulsion`.
    contact_repulsion: [f64; L],
    /// Each lane's member (for its forcing parameters).
    members: [Option<usize>; L],
    /// The step's instruction set, chosen once from the CPU and `Plan::overrides`.
    simd: SimdLevel,
}

impl<T: Real, const L: usize> LaneModel<T, L> {
    fn terms<'a>(&'a self, plan: &'a Plan) -> Terms<'a, L, T> {
        Terms::<L, T> {
            eps: T::c(plan.eps),
            mu: self.mu,
            total_gap: self.total_gap,
            contact_repulsion: self.contact_repulsion,
            exact_jacobian: plan.exact_jacobian(),
            energy: EnergyWanted::UnlessCertified,
            repulsion: self.dstar.as_deref().map(|d| (d, self.gamma)),
            bonded: self.bonded.as_deref(),
            forcing: plan
                .forcing
                .as_ref()
                .map(|f| f as &dyn roughlub_kernels::step::Forcing),
            forcing_params: std::array::from_fn(|l| {
                match (plan.forcing.as_ref(), self.members[l]) {
                    (Some(f), Some(m)) => f.member_params(m),
                    _ => &[],
                }
            }),
            simd: self.simd,
            partition: !plan.overrides.cpu_partition_off,
        }
    }
}

pub(super) struct Block<T: Real, const L: usize> {
    pub(super) lanes: [Lane; L],
    model: LaneModel<T, L>,
    /// Gaps in the stored form (`stored_gap`): d, or ln d below T's GAP_FLOOR, or 0 when bonded.
    gaps: Vec<T>,
    vel: Vec<T>,
    cand_gaps: Vec<T>,
    cand_vel: Vec<T>,
    /// The tableau's rows: row j's result (n_j substeps of H/n_j) at index j - 1 ...
    row_gaps: Vec<Vec<T>>,
    row_vel: Vec<Vec<T>>,
    /// ... and the states between a row's substeps (two, used in turn).
    sub_gaps: [Vec<T>; 2],
    sub_vel: [Vec<T>; 2],
    scratch: Scratch<T>,
}

/// Lane l's values into `out` (emptied first), in f64 for the observables: one buffer reused
/// across a block's lanes, not a Vec a lane and array.
fn lane_values_into<T: Real, const L: usize>(data: &[T], l: usize, out: &mut Vec<f64>) {
    out.clear();
    // Whole rows: a plain (vectorised) copy for L = 1, where `step_by` was half of an output's
    // cost at N = 10^6.
    out.extend(data.chunks_exact(L).map(|row| row[l].to_f64()));
}

/// Interleaved f64 values in T (rounded once).
fn to_real<T: Real>(v: Vec<f64>) -> Vec<T> {
    v.into_iter().map(T::c).collect()
}

impl<T: BlockKernels<L>, const L: usize> Block<T, L> {
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
        // As the GPU uploads them: encoded in f64 with T's floor, then rounded to T.
        let mut gaps = interleave::<f64>(&chains.map(|c| c.gaps.as_slice()));
        for d in gaps.iter_mut() {
            *d = stored_gap::encode(*d, T::GAP_FLOOR_F64);
        }
        let gaps: Vec<T> = to_real(gaps);
        let vel: Vec<T> = to_real(interleave::<f64>(&chains.map(|c| c.velocities.as_slice())));
        let dstar = plan.repulsion.then(|| {
            to_real(interleave::<f64>(&chains.map(|c| {
                c.dstar.as_deref().expect("plan.repulsion implies d*")
            })))
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
        let scheme = Scheme::of(plan, !T::IS_F64);
        let lane = |member| Lane {
            member,
            control: StepControl::new(dt0, plan.initial_column(!T::IS_F64)),
            error_estimates: Vec::new(),
        };
        let (rows, subs) = if scheme.plain_euler() {
            (0, 0)
        } else {
            let rows = scheme.rows(plan.order.columns());
            (rows, if rows > 1 { 2 } else { 0 })
        };
        let states = |count: usize, len: usize| vec![vec![T::ZERO; len]; count];
        let mut sub_g = states(subs, gaps.len()).into_iter();
        let mut sub_v = states(subs, vel.len()).into_iter();
        // gamma_of_member: 1 without repulsion.
        let energy_gamma = params.map(|p| if plan.repulsion { p.gamma } else { 1.0 });
        let mut block = Block {
            lanes: members.map(lane),
            model: LaneModel {
                mu: params.map(|p| T::c(p.mu)),
                gamma,
                energy_rtol: energy_gamma.map(energy_rtol::<T>),
                energy_gamma,
                dstar,
                bonded,
                total_gap,
                contact_repulsion,
                members,
                simd: SimdLevel::capped(plan.overrides.cpu_simd_cap),
            },
            cand_gaps: gaps.clone(),
            cand_vel: vel.clone(),
            row_gaps: states(rows, gaps.len()),
            row_vel: states(rows, vel.len()),
            sub_gaps: std::array::from_fn(|_| sub_g.next().unwrap_or_default()),
            sub_vel: std::array::from_fn(|_| sub_v.next().unwrap_or_default()),
            gaps,
            vel,
            scratch: Scratch::new(n, L),
        };
        let energy = T::state_energy(&block.model.terms(plan), n, &block.gaps, &block.vel);
        for (lane, e) in block.lanes.iter_mut().zip(energy) {
            lane.control.energy = e;
        }
        block
    }

    /// Advances every running lane to `t_end`.
    pub(super) fn advance(&mut self, plan: &Plan, t_start: f64, t_end: f64) {
        let scheme = Scheme::of(plan, !T::IS_F64);
        let fixed_dt = match plan.stepping {
            Stepping::Fixed { dt, .. } => Some(dt),
            Stepping::Adaptive { .. } => None,
        };
        let rules = Rules::new(
            t_start,
            t_end,
            fixed_dt,
            plan.stepping.dt_min(),
            TIME_RESOLUTION_F64,
        );
        for lane in self.lanes.iter_mut() {
            lane.control.begin_interval(&rules);
        }
        loop {
            let mut active = [false; L];
            let mut h = [0.0f64; L];
            let mut t = [0.0f64; L];
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
            let (outcome, hard, energy) = if scheme.plain_euler() {
                self.euler_attempt(plan, &t, &h)
            } else {
                self.extrapolated_attempt(plan, &t, &h, &active, scheme)
            };
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
                            smallest_gap::<T, L>(&self.gaps, self.model.bonded.as_deref(), l);
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

    /// Records each lane's error estimate at an output time.
    pub(super) fn record_error_estimates(&mut self) {
        for lane in self.lanes.iter_mut() {
            lane.error_estimates.push(lane.control.error_sum);
        }
    }

    /// The energy the step started from, where the previous step was certified and did not
    /// compute it.
    fn start_energy(&self, terms: &Terms<L, T>, n: usize) -> [f64; L] {
        let known: [f64; L] = std::array::from_fn(|l| self.lanes[l].control.energy);
        if known.iter().all(|&e| e >= 0.0) {
            return known;
        }
        let computed = T::state_energy(terms, n, &self.gaps, &self.vel);
        std::array::from_fn(|l| {
            if known[l] >= 0.0 {
                known[l]
            } else {
                computed[l]
            }
        })
    }

    /// Order 1, fixed steps: one Euler step of every lane into the candidate buffers. Returns
    /// each lane's outcome, any hard failure found in the current state, and the candidate's
    /// energy.
    #[allow(clippy::type_complexity)]
    fn euler_attempt(
        &mut self,
        plan: &Plan,
        t: &[f64; L],
        h: &[f64; L],
    ) -> ([Outcome; L], [Option<HardFailure>; L], [f64; L]) {
        let n = plan.particles;
        let terms = self.model.terms(plan);
        let h_real = h.map(T::c);
        let r = T::euler_step(
            &terms,
            n,
            t,
            &h_real,
            StepBuffers {
                gaps_in: &self.gaps,
                vel_in: &self.vel,
                gaps_out: &mut self.cand_gaps,
                vel_out: &mut self.cand_vel,
                scratch: &mut self.scratch,
            },
        );
        let before = if r.iter().all(|x| x.certified) {
            [0.0; L]
        } else {
            self.start_energy(&terms, n)
        };
        let outcome = std::array::from_fn(|l| Outcome {
            admissible: r[l].admissible,
            energy_ok: r[l].certified
                || energy_acceptable(before[l], r[l].energy, r[l].work, self.model.energy_rtol[l]),
            err: 0.0,
            factor: 1.0,
            order_next: 1,
            estimate: 0.0,
        });
        (outcome, r.map(|x| x.hard), r.map(|x| x.energy))
    }

    /// One extrapolated trial step of every lane into the candidate buffers: rows 1..=k of the
    /// tableau (row j: n_j Euler substeps of H/n_j, `row_substeps`), each substep held to the
    /// safeguards (finite, no gap opening beyond MAX_OPENING) and each row's result to the
    /// energy's (not above the start's plus the row's forcing work), then the tableau
    /// (`extrapolate`), the projection and energy of the extrapolated state (which must not rise
    /// either), the error estimates and, for auto, the order of the next step. Lanes of one
    /// block may use different columns.
    /// The energy is checked where the step produces a state a run can keep (a row's end, the
    /// extrapolation), not inside a row: there the sums cost ~16 % of an exact-Jacobian substep
    /// (never certified), and a row whose energy rises and falls back ends in a state as good.
    #[allow(clippy::type_complexity)]
    fn extrapolated_attempt(
        &mut self,
        plan: &Plan,
        t: &[f64; L],
        h: &[f64; L],
        active: &[bool; L],
        scheme: Scheme,
    ) -> ([Outcome; L], [Option<HardFailure>; L], [f64; L]) {
        let n = plan.particles;
        let columns: [u8; L] = std::array::from_fn(|l| self.lanes[l].control.order);
        let lane_rows: [usize; L] = columns.map(|k| scheme.rows(k));
        let from_two = sequence_from_two(plan.sequence == Sequence::FromTwo, scheme.extrapolates());
        let rows = (0..L)
            .filter(|&l| active[l])
            .map(|l| lane_rows[l])
            .max()
            .unwrap_or(1);
        let mut start: Option<[f64; L]> = None;
        let mut admissible = [true; L];
        let mut energy_ok = [true; L];
        let mut hard = [None; L];
        // Forcing work and last substep's energy (-1: certified, not computed) of each row.
        let mut row_work = [[0.0; L]; MAX_ORDER as usize + 1];
        let mut row_energy = [[0.0; L]; MAX_ORDER as usize + 1];
        for j in 1..=rows {
            let substeps = row_substeps(j as u32, from_two) as usize;
            let hj: [f64; L] = std::array::from_fn(|l| h[l] / substeps as f64);
            let hj_real = hj.map(T::c);
            // Whether a substep of the row so far was not certified.
            let mut uncertified = false;
            for s in 0..substeps {
                let ts: [f64; L] = std::array::from_fn(|l| t[l] + s as f64 * hj[l]);
                let row_end = s + 1 == substeps;
                let mut terms = self.model.terms(plan);
                terms.energy = match (row_end, uncertified) {
                    (false, _) => EnergyWanted::No,
                    (true, false) => EnergyWanted::UnlessCertified,
                    (true, true) => EnergyWanted::Always,
                };
                let (src_g, src_v, dst_g, dst_v) = substep_buffers(
                    (&self.gaps, &self.vel),
                    (&mut self.sub_gaps, &mut self.sub_vel),
                    (&mut self.row_gaps[j - 1], &mut self.row_vel[j - 1]),
                    s,
                    substeps,
                );
                let r = T::euler_step(
                    &terms,
                    n,
                    &ts,
                    &hj_real,
                    StepBuffers {
                        gaps_in: src_g,
                        vel_in: src_v,
                        gaps_out: dst_g,
                        vel_out: dst_v,
                        scratch: &mut self.scratch,
                    },
                );
                for l in 0..L {
                    if j > lane_rows[l] {
                        continue;
                    }
                    if j == 1 && s == 0 {
                        hard[l] = r[l].hard;
                    } else if r[l].hard.is_some() {
                        // Met in a substep's state: a smaller step may avoid it.
                        admissible[l] = false;
                    }
                    admissible[l] &= r[l].admissible;
                    uncertified |= !r[l].certified;
                    row_work[j][l] += r[l].work;
                    if row_end {
                        // The row's end against the start's energy (-1: the previous step was
                        // certified, not computed) plus the row's work.
                        if !r[l].certified {
                            let mut before = self.lanes[l].control.energy;
                            if before < 0.0 {
                                before =
                                    start.get_or_insert_with(|| self.start_energy(&terms, n))[l];
                            }
                            energy_ok[l] &= energy_acceptable(
                                before,
                                r[l].energy,
                                row_work[j][l],
                                self.model.energy_rtol[l],
                            );
                        }
                        row_energy[j][l] = r[l].energy;
                    }
                }
            }
        }
        let lane_columns: [usize; L] = std::array::from_fn(|l| lane_rows[l].min(rows));
        let terms = self.model.terms(plan);
        let estimates = T::extrapolate(
            terms.simd,
            TableauIo {
                columns: &lane_columns,
                extrapolating: scheme.extrapolates(),
                sequence_from_two: from_two,
                row_gaps: &self.row_gaps,
                row_vel: &self.row_vel,
                cand_gaps: &mut self.cand_gaps,
                cand_vel: &mut self.cand_vel,
                bonded: self.model.bonded.as_deref(),
            },
        );
        let mut energy: [f64; L] = std::array::from_fn(|l| row_energy[lane_columns[l]][l]);
        if scheme.extrapolates() {
            // The Euler substeps' certificates do not cover their extrapolation: the
            // projection computes its energy, which must not exceed the start's plus the
            // finest row's work, to the rounding that the tableau amplifies.
            let mut report = [StepReport::START; L];
            let unit = [T::ONE; L];
            T::conclude(
                &terms,
                n,
                &unit,
                &mut self.cand_gaps,
                &self.cand_vel,
                &mut report,
            );
            let before = *start.get_or_insert_with(|| self.start_energy(&terms, n));
            for l in 0..L {
                let k = lane_columns[l];
                admissible[l] &= report[l].admissible;
                energy_ok[l] &= energy_acceptable(
                    before[l],
                    report[l].energy,
                    row_work[k][l],
                    extrapolated_energy_rtol(
                        self.model.energy_rtol[l],
                        self.model.energy_gamma[l],
                        k as u8,
                        from_two,
                        T::EPSILON.to_f64(),
                    ),
                );
                energy[l] = report[l].energy;
            }
        }
        let outcome = std::array::from_fn(|l| {
            let k = columns[l];
            let estimate = estimates[l][lane_columns[l]];
            let (err, factor, order_next) = match scheme.adaptive_tol {
                None => (0.0, 1.0, k),
                Some(tol) => {
                    let scaled = estimates[l].map(|e| e / tol);
                    let err = scaled[lane_columns[l]];
                    let (order_next, factor) = match scheme.order {
                        Order::Auto => select_order(
                            k,
                            &scaled,
                            admissible[l] && energy_ok[l] && err <= 1.0,
                            from_two,
                            scheme.top,
                        ),
                        Order::Fixed(_) => (k, step_factor(err, scheme.estimate_order(k))),
                    };
                    (err, factor, order_next)
                }
            };
            Outcome {
                admissible: admissible[l],
                energy_ok: energy_ok[l],
                err,
                factor,
                order_next,
                estimate,
            }
        });
        (outcome, hard, energy)
    }

    pub(super) fn snapshot(
        &self,
        plan: &Plan,
        params: &[MemberParams],
        grid_x: &[f64],
    ) -> Vec<(usize, Snapshot)> {
        let mut out = Vec::with_capacity(self.lanes.len());
        let (mut gaps, mut vel, mut dstar) = (Vec::new(), Vec::new(), Vec::new());
        // d* enters the energy and the rho* field only (not the companion's comparison).
        let dstar_read = self
            .model
            .dstar
            .as_ref()
            .filter(|_| plan.energy_sums || plan.fields.rho_star);
        for (l, lane) in self.lanes.iter().enumerate() {
            let Some(member) = lane.member else { continue };
            if lane.control.failure != Failure::None {
                out.push((member, Snapshot::failed(plan)));
                continue;
            }
            lane_values_into::<T, L>(&self.gaps, l, &mut gaps);
            lane_values_into::<T, L>(&self.vel, l, &mut vel);
            if let Some(d) = dstar_read {
                lane_values_into::<T, L>(d, l, &mut dstar);
            }
            let bonded = self
                .model
                .bonded
                .as_ref()
                .map(|b| b.chunks_exact(L).map(|row| row[l]).collect::<Vec<bool>>());
            out.push((
                member,
                observe(
                    plan,
                    &params[member],
                    &gaps,
                    &vel,
                    dstar_read.map(|_| dstar.as_slice()),
                    bonded.as_deref(),
                    grid_x,
                ),
            ));
        }
        if plan.peak_centre {
            set_peak_centres(grid_x, out.iter_mut().map(|(_, s)| s));
        }
        out
    }

    /// [`reports`](Self::reports)' status and last estimate of each member, with its index.
    pub(super) fn output_status(
        &self,
        has_estimates: bool,
    ) -> impl Iterator<Item = (usize, OutputStatus)> + '_ {
        self.lanes.iter().filter_map(move |lane| {
            let error_estimate = match has_estimates {
                true => lane.error_estimates.last().copied().unwrap_or(f64::NAN),
                false => f64::NAN,
            };
            Some((
                lane.member?,
                OutputStatus {
                    ok: lane.control.failure == Failure::None,
                    error_estimate,
                },
            ))
        })
    }

    pub(super) fn reports(&self, plan: &Plan, dt_min: f64) -> Vec<MemberReport> {
        let params = &plan.members;
        let has_estimates = error_estimate_method(plan.order, plan.stepping).is_some();
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
                            .describe(
                                dt_min,
                                TIME_RESOLUTION_F64,
                                m,
                                params[m].gamma,
                            ),
                            time: lane.control.failure_time,
                        },
                    },
                    steps_accepted: lane.control.accepted,
                    steps_rejected: lane.control.rejected,
                    last_dt: lane.control.dt,
                    last_order: lane.control.order,
                    error_estimate: has_estimates.then(|| lane.error_estimates.clone()),
                })
            })
            .collect()
    }
}

/// Index (1-based) and ln d of lane l's smallest free gap.
fn smallest_gap<T: Real, const L: usize>(
    gaps: &[T],
    bonded: Option<&[bool]>,
    l: usize,
) -> (u32, f64) {
    let mut best = (0u32, f64::INFINITY);
    for (i, &v) in gaps.iter().skip(l).step_by(L).enumerate() {
        if bonded.is_some_and(|b| b[i * L + l]) {
            continue;
        }
        let s = stored_ln(v).to_f64();
        if s < best.1 {
            best = (i as u32 + 1, s);
        }
    }
    best
}
