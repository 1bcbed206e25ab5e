//! The error estimate of order 1 with fixed steps, which has no tableau to estimate from: a
//! companion batch of the same members with another step runs beside the run
//! ([`CompanionEstimate`], at the [`BatchSolver`] seam, so on either backend). The scheme is
//! first order, so the global error at an output time is about C h̄ with h̄ = t / (steps so
//! far), the mean step; with s steps for the run and s_c for the companion,
//! |y_run − y_companion| s_c / |s − s_c| estimates the run's own global error, propagation
//! included (|y(dt) − y(4 dt)| / 3 where both take whole steps). The companion steps at
//! `COARSENING` dt (1/4 of the run's steps) where the run takes two steps or more in every output
//! interval; where dt reaches an output interval, 4 dt is cut to the interval too and would take
//! the run's own steps (an estimate of 0), so there it steps at half the smaller of dt and the
//! shortest interval (twice the run's steps or more).

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
     at 4 dt (or, where dt reaches an output interval, at half the smaller of dt and the shortest \
     interval): |y_run - y_companion| s_c / |s - s_c| with s and s_c the two runs' steps so far \
     (|y(dt) - y(4 dt)| / 3 where both take whole steps), as a max-norm: relative on gaps (the \
     error of ln d; the smallest gaps compared in ln d also below the float range, other gaps \
     below it on one side only at the range's edge, a lower bound), |du|/(1 + |u|) on \
     velocities; infinite where the companion failed and the run did not";

/// Whether a plan runs order 1 with fixed steps (the runs that need a companion for an estimate).
pub fn needs_companion(plan: &Plan) -> bool {
    needs_companion_for(plan.order, plan.stepping)
}

/// [`needs_companion`] from the order and stepping alone (a scene's, before its plan exists).
pub fn needs_companion_for(order: Order, stepping: Stepping) -> bool {
    matches!((order, stepping), (Order::Fixed(1), Stepping::Fixed { .. }))
}

/// The companion's step for a run at fixed step `dt` with these output times (from t = 0):
/// `COARSENING` dt where the run takes at least two steps in every output interval, else half
/// of the smaller of dt and the shortest interval (see the module's documentation).
pub fn companion_step(dt: f64, output_times: &[f64]) -> f64 {
    let shortest = std::iter::once(0.0)
        .chain(output_times.iter().copied())
        .collect::<Vec<f64>>()
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|&interval| interval > 0.0)
        .fold(f64::INFINITY, f64::min);
    // The step control takes what is left of an interval within 1e-9 of dt as one step
    // (`StepControl::trial_step`), and on the GPU in f32 within f32's rounding of dt (1e-9 is
    // below it there): 1e-6 covers both, and where the run does take two steps within it the
    // finer companion still takes more.
    if shortest > dt * (1.0 + 1e-6) {
        dt * COARSENING
    } else {
        0.5 * dt.min(shortest)
    }
}

/// The companion's plan: the run's, at [`companion_step`], with the gaps and velocities it is
/// compared on, and no fields.
pub fn companion_plan(plan: &Plan) -> Plan {
    let mut companion = plan.clone();
    if let Stepping::Fixed { dt, dt_min } = plan.stepping {
        let step = companion_step(dt, &plan.output_times);
        companion.stepping = Stepping::Fixed {
            dt: step,
            // A finer companion keeps the run's floor in proportion to its step.
            dt_min: dt_min * (step / dt).min(1.0),
        };
    }
    companion.fields.gaps = true;
    companion.fields.velocities = true;
    companion.fields.rho = false;
    companion.fields.u = false;
    companion.fields.rho_star = false;
    // Its snapshots are only compared, never summarised.
    companion.peak_centre = false;
    companion.energy_sums = false;
    companion
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

/// |run − companion| in the estimate's norm: ln d on gaps, |du|/(1 + |u|) on velocities.
fn difference(run: &Snapshot, companion: &Snapshot) -> f64 {
    if run
        .gaps
        .iter()
        .chain(&run.velocities)
        .any(|v| !v.is_finite())
    {
        return f64::NAN;
    }
    let mut gaps = largest_log_ratio(&run.gaps, &companion.gaps);
    // Where a smallest gap is below the normal range, also those two in ln d, which the
    // snapshot keeps there (a collision stepped over by both runs leaves both gaps at 0 in d).
    // |min ln a - min ln b| is at most max |ln a_i - ln b_i|, so it only completes the gaps'
    // term; elsewhere the term is left as it is, bit for bit.
    if run.min_gap.min(companion.min_gap) < f64::MIN_POSITIVE {
        let smallest = (run.log_min_gap - companion.log_min_gap).abs();
        if !smallest.is_nan() {
            gaps = gaps.max(smallest);
        }
    }
    let velocities = largest_of(&run.velocities, &companion.velocities, 0.0, |a, b| {
        (a - b).abs() / (1.0 + a.abs())
    });
    gaps.max(velocities)
}

/// The run's global error from the difference of the two runs after `steps` and
/// `companion_steps` steps: C h̄ for each (h̄ = t / steps), so the run's is the difference times
/// s_c / |s - s_c|. Equal counts after a step (which `companion_step` rules out) give no
/// estimate: infinite.
fn global_error(difference: f64, steps: u64, companion_steps: u64) -> f64 {
    if steps == companion_steps {
        // The initial state (no steps yet: no error), else two runs of the same steps, which
        // say nothing of the error even where they agree.
        return if steps == 0 { 0.0 } else { f64::INFINITY };
    }
    difference * companion_steps as f64 / steps.abs_diff(companion_steps) as f64
}

/// The largest of `start` and `term(a, b)` over the pairs (a NaN term counts as nothing, as in
/// `f64::max`), four pairs at a time so that the divisions pack: max is exact, so the order
/// does not change the result.
#[inline(always)]
fn largest_of(left: &[f64], right: &[f64], start: f64, term: impl Fn(f64, f64) -> f64) -> f64 {
    const LANES: usize = 4;
    let len = left.len().min(right.len());
    let (left, right) = (&left[..len], &right[..len]);
    let mut largest = [start; LANES];
    let four_left = left.chunks_exact(LANES);
    let four_right = right.chunks_exact(LANES);
    let rest = four_left.remainder().iter().zip(four_right.remainder());
    for (a, b) in four_left.zip(four_right) {
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
fn largest_log_ratio(run: &[f64], companion: &[f64]) -> f64 {
    // Where every gap of both is positive (nearly always), two logarithms: ln is monotone, so
    // the largest |ln(a/b)| is that of the largest or the smallest ratio, the same value as
    // one logarithm a gap (a logarithm a gap was a tenth of a short chain's run).
    if run
        .iter()
        .zip(companion)
        .all(|(&a, &b)| (a > 0.0) & (b > 0.0))
    {
        // From 1 (|ln 1| = 0, the loop's start); the smallest ratio as the largest negated one
        // (negation is exact).
        let largest = largest_of(run, companion, 1.0, |a, b| a / b);
        let smallest = -largest_of(run, companion, -1.0, |a, b| -(a / b));
        return largest.ln().abs().max(smallest.ln().abs());
    }
    let mut worst = 0.0f64;
    for (&a, &b) in run.iter().zip(companion) {
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
        // On the CPU the two run side by side: a batch of fewer blocks than threads (one long
        // chain: one block) leaves threads idle that the companion can use. GPU solvers take
        // their turns on the device.
        let (run, companion) = (&mut self.run, &mut self.companion);
        let (run_out, companion) = if run.gpu_stats().is_none() && companion.gpu_stats().is_none() {
            rayon::join(
                || run.next_output(progress),
                || companion.next_output(&|_| {}),
            )
        } else {
            let run_out = run.next_output(progress);
            let companion = match run_out {
                Ok(Some(_)) => companion.next_output(&|_| {}),
                _ => Ok(None),
            };
            (run_out, companion)
        };
        let Some(mut snaps) = run_out? else {
            return Ok(None);
        };
        let companion = companion?;
        let run_ok = self.run.reports();
        let companion_ok = self.companion.reports();
        let (keep_gaps, keep_velocities) = (self.keep_gaps, self.keep_velocities);
        let estimates: Vec<f64> = snaps
            .par_iter_mut()
            .enumerate()
            .map(|(m, s)| {
                let estimate = match (&companion, run_ok[m].status == MemberStatus::Ok) {
                    (_, false) => f64::NAN,
                    (Some(c), true) if companion_ok[m].status == MemberStatus::Ok => global_error(
                        difference(s, &c[m]),
                        run_ok[m].steps_accepted,
                        companion_ok[m].steps_accepted,
                    ),
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
    use super::{companion_step, global_error, largest_log_ratio};
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

    /// 4 dt where every output interval takes two steps of the run or more; else half the
    /// smaller of dt and the shortest interval. The estimate scales the difference by
    /// s_c / |s - s_c|.
    #[test]
    fn the_companion_takes_other_steps_than_the_run() {
        // The intervals are differences of output times: within rounding.
        let close = |got: f64, expected: f64| {
            assert!(
                (got - expected).abs() <= 1e-12 * expected,
                "{got} against {expected}"
            )
        };
        let every_tenth = [0.0, 0.1, 0.2, 0.3, 0.4];
        close(companion_step(1e-3, &every_tenth), 4e-3);
        close(companion_step(0.05, &every_tenth), 0.2);
        // dt equal to the interval (within the step control's rounding margin) or above it.
        close(companion_step(0.1, &every_tenth), 0.05);
        close(companion_step(0.1 * (1.0 + 1e-10), &every_tenth), 0.05);
        close(companion_step(0.4, &every_tenth), 0.05);
        // The shortest interval counts, and the first one is from t = 0.
        close(companion_step(0.02, &[0.01, 0.5]), 0.005);
        close(companion_step(0.005, &[0.01, 0.5]), 0.02);
        close(global_error(0.3, 400, 100), 0.3 / 3.0);
        close(global_error(0.3, 5, 2), 0.3 * 2.0 / 3.0);
        close(global_error(0.3, 1, 2), 0.6);
        assert_eq!(global_error(0.0, 0, 0), 0.0);
        assert_eq!(global_error(0.3, 7, 7), f64::INFINITY);
        assert_eq!(global_error(0.0, 7, 7), f64::INFINITY);
        assert_eq!(global_error(0.0, 8, 2), 0.0);
        // Within f32's rounding of the interval (the GPU's f32 run takes one step there).
        close(
            companion_step(0.1 * (1.0 - 1e-8), &every_tenth),
            0.05 * (1.0 - 1e-8),
        );
    }
}
