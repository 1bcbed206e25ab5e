//! The error estimate of order 1 with fixed steps, which has no tableau to estimate from: a
//! companion batch of the same members at `COARSENING` times the step runs beside the run
//! ([`CompanionEstimate`], at the [`BatchSolver`] seam, so on either backend). The scheme is
//! first order, so the global errors at a common output time are e(k dt) ≈ k e(dt), and
//! |y(dt) − y(k dt)| / (k − 1) estimates the run's own global error, propagation included. The
//! companion costs 1/k of the run's steps.

use rayon::prelude::*;

use super::{BatchSolver, MemberReport, MemberStatus, OutputStatus};
use crate::error::Result;
use crate::model::observables::Snapshot;
use crate::model::params::{Order, Stepping};
use crate::model::plan::Plan;

/// The companion's step, in units of the run's: a quarter of the run's steps (the cost
/// bound is 30 %), still close enough to the run's step that a first-order error expansion that
/// holds at dt mostly holds at 4 dt.
pub const COARSENING: f64 = 4.0;

/// How the estimate is made (the manifest's `error_estimate.method`).
pub const COMPANION_METHOD: &str = "global error of order 1 with fixed steps from a companion run \
     at 4 dt: |y(dt) - y(4 dt)| / 3, as a max-norm: relative on gaps (the error of ln d), \
     |du|/(1 + |u|) on velocities; infinite where the companion failed and the run did not";

/// Whether a plan runs order 1 with fixed steps (the runs that need a companion for an estimate).
pub fn needs_companion(plan: &Plan) -> bool {
    needs_companion_for(plan.order, plan.stepping)
}

/// [`needs_companion`] from the order and stepping alone (a scene's, before its plan exists).
pub fn needs_companion_for(order: Order, stepping: Stepping) -> bool {
    matches!((order, stepping), (Order::Fixed(1), Stepping::Fixed { .. }))
}

/// The companion's plan: the run's, at `COARSENING` times its step, with the gaps and velocities
/// it is compared on, and no fields.
pub fn companion_plan(plan: &Plan) -> Plan {
    let mut coarse = plan.clone();
    if let Stepping::Fixed { dt, dt_min } = plan.stepping {
        coarse.stepping = Stepping::Fixed {
            dt: dt * COARSENING,
            dt_min,
        };
    }
    coarse.fields.gaps = true;
    coarse.fields.velocities = true;
    coarse.fields.rho = false;
    coarse.fields.u = false;
    coarse.fields.rho_star = false;
    coarse
}

/// A run and its companion: snapshots and reports are the run's, each member's
/// `error_estimate` the difference of the two at each output time.
pub struct CompanionEstimate<'a> {
    /// The plan as the caller made it (the run's own asks for gaps and velocities too).
    plan: Plan,
    run: Box<dyn BatchSolver + 'a>,
    companion: Box<dyn BatchSolver + 'a>,
    /// Whether the run's own plan asked for gaps / velocities (the comparison needs them).
    keep_gaps: bool,
    keep_velocities: bool,
    estimates: Vec<Vec<f64>>,
}

impl<'a> CompanionEstimate<'a> {
    /// `run` must have been built from `plan` with gaps and velocities on (they are dropped
    /// from the snapshots where `plan` did not ask for them).
    pub fn new(
        plan: Plan,
        run: Box<dyn BatchSolver + 'a>,
        companion: Box<dyn BatchSolver + 'a>,
    ) -> Self {
        let members = run.plan().members.len();
        CompanionEstimate {
            keep_gaps: plan.fields.gaps,
            keep_velocities: plan.fields.velocities,
            plan,
            run,
            companion,
            estimates: vec![Vec::new(); members],
        }
    }
}

/// |a − b| / (k − 1) in the estimate's norm: ln d on gaps, |du|/(1 + |u|) on velocities.
fn difference(fine: &Snapshot, coarse: &Snapshot) -> f64 {
    let mut worst = 0.0f64;
    for (&a, &b) in fine.gaps.iter().zip(&coarse.gaps) {
        let e = if a > 0.0 && b > 0.0 {
            // |ln a - ln b| with one logarithm.
            (a / b).ln().abs()
        } else if a == b {
            0.0
        } else {
            // One gap below the float range and not the other: no finite bound.
            f64::INFINITY
        };
        worst = worst.max(e);
    }
    for (&a, &b) in fine.velocities.iter().zip(&coarse.velocities) {
        worst = worst.max((a - b).abs() / (1.0 + a.abs()));
    }
    if fine
        .gaps
        .iter()
        .chain(&fine.velocities)
        .any(|v| !v.is_finite())
    {
        return f64::NAN;
    }
    worst / (COARSENING - 1.0)
}

impl BatchSolver for CompanionEstimate<'_> {
    fn next_output(&mut self, progress: super::Progress) -> Result<Option<Vec<Snapshot>>> {
        let Some(mut snaps) = self.run.next_output(progress)? else {
            return Ok(None);
        };
        let coarse = self.companion.next_output(&|_| {})?;
        let run_ok = self.run.reports();
        let companion_ok = self.companion.reports();
        let (keep_gaps, keep_velocities) = (self.keep_gaps, self.keep_velocities);
        let estimates: Vec<f64> = snaps
            .par_iter_mut()
            .enumerate()
            .map(|(m, s)| {
                let estimate = match (&coarse, run_ok[m].status == MemberStatus::Ok) {
                    (_, false) => f64::NAN,
                    (Some(c), true) if companion_ok[m].status == MemberStatus::Ok => {
                        difference(s, &c[m])
                    }
                    // The companion failed (or ended) where the run did not.
                    _ => f64::INFINITY,
                };
                if !keep_gaps {
                    s.gaps = Vec::new();
                }
                if !keep_velocities {
                    s.velocities = Vec::new();
                }
                estimate
            })
            .collect();
        for (per_member, e) in self.estimates.iter_mut().zip(estimates) {
            per_member.push(e);
        }
        Ok(Some(snaps))
    }

    fn reports(&self) -> Vec<MemberReport> {
        let mut reports = self.run.reports();
        for (r, e) in reports.iter_mut().zip(&self.estimates) {
            r.error_estimate = Some(e.clone());
        }
        reports
    }

    fn output_status(&self) -> Vec<OutputStatus> {
        let mut status = self.run.output_status();
        for (s, e) in status.iter_mut().zip(&self.estimates) {
            s.error_estimate = e.last().copied().unwrap_or(f64::NAN);
        }
        status
    }

    fn plan(&self) -> &Plan {
        &self.plan
    }

    fn grid(&self) -> &[f64] {
        self.run.grid()
    }

    /// The run's own counters (the companion's work, about a quarter of its steps, is not in
    /// them: the counters describe the run the manifest reports).
    fn gpu_stats(&self) -> Option<super::report::GpuStats> {
        self.run.gpu_stats()
    }
}
