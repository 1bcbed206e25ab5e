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
     at 4 dt: |y(dt) - y(4 dt)| / 3, as a max-norm: relative on gaps (the error of ln d; the \
     smallest gaps compared in ln d also below the float range, other gaps below it on one side \
     only at the range's edge, a lower bound), |du|/(1 + |u|) on velocities; infinite where the \
     companion failed and the run did not";

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
    // Its snapshots are only compared, never summarised.
    coarse.peak_centre = false;
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
    if fine
        .gaps
        .iter()
        .chain(&fine.velocities)
        .any(|v| !v.is_finite())
    {
        return f64::NAN;
    }
    let mut gaps = largest_log_ratio(&fine.gaps, &coarse.gaps);
    // Where a smallest gap is below the normal range, also those two in ln d, which the
    // snapshot keeps there (a collision stepped over by both runs leaves both gaps at 0 in d).
    // |min ln a - min ln b| is at most max |ln a_i - ln b_i|, so it only completes the gaps'
    // term; elsewhere the term is left as it is, bit for bit.
    if fine.min_gap.min(coarse.min_gap) < f64::MIN_POSITIVE {
        let smallest = (fine.log_min_gap - coarse.log_min_gap).abs();
        if !smallest.is_nan() {
            gaps = gaps.max(smallest);
        }
    }
    let velocities = largest_of(&fine.velocities, &coarse.velocities, 0.0, |a, b| {
        (a - b).abs() / (1.0 + a.abs())
    });
    gaps.max(velocities) / (COARSENING - 1.0)
}

/// The largest of `start` and `term(a, b)` over the pairs (a NaN term counts as nothing, as in
/// `f64::max`), four pairs at a time so that the divisions pack: max is exact, so the order
/// does not change the result.
#[inline(always)]
fn largest_of(fine: &[f64], coarse: &[f64], start: f64, term: impl Fn(f64, f64) -> f64) -> f64 {
    const LANES: usize = 4;
    let len = fine.len().min(coarse.len());
    let (fine, coarse) = (&fine[..len], &coarse[..len]);
    let mut largest = [start; LANES];
    let four_fine = fine.chunks_exact(LANES);
    let four_coarse = coarse.chunks_exact(LANES);
    let rest = four_fine.remainder().iter().zip(four_coarse.remainder());
    for (a, b) in four_fine.zip(four_coarse) {
        for l in 0..LANES {
            let t = term(a[l], b[l]);
            largest[l] = if t > largest[l] { t } else { largest[l] };
        }
    }
    let mut worst = largest.into_iter().fold(start, f64::max);
    for (&a, &b) in rest {
        worst = worst.max(term(a, b));
    }
    worst
}

/// max_i |ln a_i − ln b_i| over pairs of gaps; where one gap is below the float range (0) and
/// the other is not, |ln b − ln(smallest subnormal)|, which the true difference exceeds.
fn largest_log_ratio(fine: &[f64], coarse: &[f64]) -> f64 {
    // Where every gap of both is positive (nearly always), two logarithms: ln is monotone, so
    // the largest |ln(a/b)| is that of the largest or the smallest ratio, the same value as
    // one logarithm a gap (a logarithm a gap was a tenth of a short chain's run).
    if fine
        .iter()
        .zip(coarse)
        .all(|(&a, &b)| (a > 0.0) & (b > 0.0))
    {
        // From 1 (|ln 1| = 0, the loop's start); the smallest ratio as the largest negated one
        // (negation is exact).
        let largest = largest_of(fine, coarse, 1.0, |a, b| a / b);
        let smallest = -largest_of(fine, coarse, -1.0, |a, b| -(a / b));
        return largest.ln().abs().max(smallest.ln().abs());
    }
    let mut worst = 0.0f64;
    for (&a, &b) in fine.iter().zip(coarse) {
        let e = if a > 0.0 && b > 0.0 {
            // |ln a - ln b| with one logarithm.
            (a / b).ln().abs()
        } else if a == b {
            0.0
        } else {
            // One gap below the float range and not the other: at least as far as the range's
            // edge.
            a.max(b).ln() - SMALLEST_SUBNORMAL.ln()
        };
        worst = worst.max(e);
    }
    worst
}

/// The smallest positive f64: a gap stored as 0 is below it.
const SMALLEST_SUBNORMAL: f64 = f64::from_bits(1);

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

#[cfg(test)]
mod tests {
    use super::largest_log_ratio;
    use crate::test_rng::uniform_stream;

    /// The two-logarithm form gives the largest |ln(a/b)| of the pairs, bit for bit, whether the
    /// ratios lie above 1, below it or on both sides; a gap of 0 on one side only is infinite.
    #[test]
    fn largest_log_ratio_is_the_largest_pairwise_one() {
        let mut uniform = uniform_stream(0x2545f4914f6cdd1d);
        for case in 0..300 {
            let n = 1 + case % 40;
            let fine: Vec<f64> = (0..n).map(|_| 10f64.powf(-12.0 * uniform())).collect();
            // Ratios within [0.5, 2), [1, 2) or (0.5, 1]: around 1, above it, below it.
            let coarse: Vec<f64> = fine
                .iter()
                .map(|&a| match case % 3 {
                    0 => a * (0.5 + 1.5 * uniform()),
                    1 => a / (1.0 + uniform()),
                    _ => a * (1.0 + uniform()),
                })
                .collect();
            let pairwise = fine
                .iter()
                .zip(&coarse)
                .map(|(&a, &b)| (a / b).ln().abs())
                .fold(0.0f64, f64::max);
            assert_eq!(
                largest_log_ratio(&fine, &coarse).to_bits(),
                pairwise.to_bits(),
                "case {case}"
            );
        }
        assert_eq!(largest_log_ratio(&[0.0, 1.0], &[0.0, 0.5]), 2f64.ln());
        // 1e-300 against a gap below 4.94e-324: at least ln(1e-300 / 4.94e-324) = 53.66; 0.5
        // against one: ln 0.5 + 744.44.
        let one_sided = largest_log_ratio(&[1e-3, 0.0], &[1e-3, 1e-300]);
        assert!((one_sided - 53.664).abs() < 1e-3, "{one_sided}");
        let far = largest_log_ratio(&[0.5], &[0.0]);
        assert!((far - 743.747).abs() < 1e-3, "{far}");
        assert_eq!(largest_log_ratio(&[], &[]), 0.0);
    }
}
