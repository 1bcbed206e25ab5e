//! What every backend reports about its members: status, failure reason, step counts.

use crate::backend::shared::control::{step_floor, STALL_PACE, STALL_PACE_ADAPTIVE, STALL_WINDOW};
pub use roughlub_kernels::failure::Failure;

/// Why a member stopped.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(tag = "status", rename_all = "lowercase")]
pub enum MemberStatus {
    Ok,
    Failed { reason: String, time: f64 },
}

/// A member's bookkeeping, reported in the manifest.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct MemberReport {
    pub index: usize,
    pub mu: f64,
    pub gamma: f64,
    #[serde(flatten)]
    pub status: MemberStatus,
    pub steps_accepted: u64,
    pub steps_rejected: u64,
    pub last_dt: f64,
    /// The tableau column (order) of the member's last step: the fixed order, or auto's choice.
    pub last_order: u8,
    /// Estimated error of the member's state at each output time (see [`error_estimate_method`]);
    /// `None` where the scheme has no estimate (order 1, fixed steps, without its companion).
    /// Infinite or NaN values are written as strings ("inf", "NaN": a failed member).
    #[serde(serialize_with = "crate::output::manifest::non_finite::option_vec")]
    pub error_estimate: Option<Vec<f64>>,
}

impl MemberReport {
    /// The member's largest error estimate over its output times: the last one where the
    /// estimates are sums of local ones (the tableau's), the worst of the output times where
    /// they are global errors that may shrink again after a collision (the companion's).
    pub fn largest_error_estimate(&self) -> Option<f64> {
        self.error_estimate
            .as_ref()?
            .iter()
            .copied()
            .reduce(f64::max)
    }

    /// Makes NaN the estimates at output times after the member failed: it has no state there
    /// (its rows of the outputs are NaN too), so no error to estimate.
    pub fn clear_estimates_after_failure(&mut self, output_times: &[f64]) {
        let (MemberStatus::Failed { time, .. }, Some(estimates)) =
            (&self.status, self.error_estimate.as_mut())
        else {
            return;
        };
        for (estimate, &t) in estimates.iter_mut().zip(output_times) {
            if t > *time {
                *estimate = f64::NAN;
            }
        }
    }
}

/// How adaptive runs estimate their error (the manifest's `error_estimate.method`).
pub const ADAPTIVE_ESTIMATE_METHOD: &str =
    "sum over accepted steps of the controller's local estimate |T_kk - T_k,k-1| of the \
     extrapolation tableau (order 1: one step against two half steps), as a max-norm: relative \
     on gaps (the error of ln d), |du|/(1 + |u|) on velocities; local errors added without \
     their propagation";

/// How the extrapolated orders with fixed steps estimate their error.
pub const FIXED_STEP_ESTIMATE_METHOD: &str =
    "sum over steps of |T_pp - T_p,p-1|, the difference from the next lower order of the \
     extrapolation tableau (an estimate of that lower order's local error, so an overestimate \
     of order p's), as a max-norm: relative on gaps (the error of ln d), |du|/(1 + |u|) on \
     velocities; local errors added without their propagation";

/// How the error estimates of a run with this plan are made, or `None` when it has none.
pub fn error_estimate_method(
    order: crate::model::params::Order,
    stepping: crate::model::params::Stepping,
) -> Option<&'static str> {
    use crate::model::params::{Order, Stepping};
    match (order, stepping) {
        (Order::Fixed(1), Stepping::Fixed { .. }) => None,
        (_, Stepping::Adaptive { .. }) => Some(ADAPTIVE_ESTIMATE_METHOD),
        (_, Stepping::Fixed { .. }) => Some(FIXED_STEP_ESTIMATE_METHOD),
    }
}

/// How the error estimates of a run are made, counting the companion run that estimates order
/// 1 with fixed steps (see [`companion`](super::companion)) when `companion` is on; `None` when
/// the run has none.
pub fn run_error_estimate_method(
    order: crate::model::params::Order,
    stepping: crate::model::params::Stepping,
    companion: bool,
) -> Option<&'static str> {
    use crate::model::params::{Order, Stepping};
    match (order, stepping) {
        (Order::Fixed(1), Stepping::Fixed { .. }) if companion => {
            Some(super::companion::COMPANION_METHOD)
        }
        _ => error_estimate_method(order, stepping),
    }
}

/// Above this error estimate an adaptive run warns that its results may not be converged (on
/// stderr and in the manifest, as [`large_error_warning`](crate::output::manifest::large_error_warning)
/// words it for the estimate's method): a tenth of the relative size of the state. The
/// controller's estimate is a sum of local estimates, mostly above the error.
pub const LARGE_ERROR_ESTIMATE: f64 = 0.1;

/// Below [`LARGE_ERROR_ESTIMATE`], an adaptive run whose estimate is more than this many times
/// its tolerance warns that the tolerance was not met. The estimate adds the local errors that
/// the controller held below the tolerance, so it grows with the steps: in f64, on four chains
/// from 1e-3 to 1e-10, it was 0.5 to 101 times the tolerance, with errors of 0.04 to 7.5 times
/// it (only the 101, at 1e-10, warns); in f32, with auto's columns capped by their rounding
/// (`top_column`), 0.96 to 522 times from 1e-2 to 3e-5 with errors of 0.5 to 30 times, the
/// estimate summing the local errors of up to 751 steps: the runs that err 30 and 5.2 times the
/// tolerance on a chain driven to a gap of 1e-13 warn (at 3e-5 and 1e-4), and so does case 2a at
/// 3e-5 (error 3.0 times, estimate 144), where that chain's 5.6 times at 1e-3 does not
/// (`docs/error_estimate/tolerance_factor.py`).
pub const TOLERANCE_NOT_MET_FACTOR: f64 = 100.0;

/// The same for fixed steps: their estimates fell to a seventh of the error on coarse steps
/// (`docs/error_estimate/coarse_fixed_steps.py`: order 1's companion 0.15-0.7 times the error,
/// orders 6 and 8 down to 0.15 times), so they warn ten times lower, where an error of 0.1
/// still gives an estimate above the limit.
pub const LARGE_FIXED_STEP_ERROR_ESTIMATE: f64 = 0.01;

/// Where and why a member failed, as the solvers record it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FailureRecord {
    pub failure: Failure,
    pub time: f64,
    /// Particle or gap (1-based) the failure names.
    pub index: u32,
    /// A position (forcing), a density ratio (repulsion) or ln of the smallest gap (step size
    /// collapse).
    pub detail: f64,
}

impl FailureRecord {
    /// The sentence the manifest gives for this failure of member `member` with gamma `gamma`.
    pub fn describe(&self, dt_min: f64, time_resolution: f64, member: usize, gamma: f64) -> String {
        let t = self.time;
        let floor = step_floor(dt_min, time_resolution, t);
        let below = if floor > dt_min {
            format!(
                "the time resolution at t = {t} ({floor:e} = 2^{} t; dt_min = {dt_min:e})",
                time_resolution.log2()
            )
        } else {
            format!("dt_min = {dt_min:e} at t = {t}")
        };
        let smallest_gap = || {
            format!(
                "smallest gap: d_{} = e^{} = {:e}",
                self.index,
                // ln d with four decimals, in exponent form where that would print hundreds of
                // digits (ln d = -8e240 with mu = 1e-300).
                if self.detail.abs() < 1e6 {
                    format!("{:.4}", self.detail)
                } else {
                    format!("{:.4e}", self.detail)
                },
                self.detail.exp()
            )
        };
        let collapse = |why: &str| {
            format!(
                "step size collapsed below {below}: {why} ({})",
                smallest_gap()
            )
        };
        match self.failure {
            Failure::None => "ok".into(),
            Failure::Inadmissible => collapse(
                "every smaller step gave a non-finite value or opened a gap by more than e^5",
            ),
            Failure::ErrorTooLarge => collapse("the error estimate stayed above the tolerance"),
            Failure::EnergyRose => {
                collapse("every smaller step raised the energy beyond the work of the forcing")
            }
            Failure::Forcing => format!(
                "the forcing is not finite at t = {t}, x = {} (particle {} of member {member})",
                self.detail, self.index
            ),
            Failure::Stalled => format!(
                "stalled at t = {t}: its last {STALL_WINDOW} attempts (accepted or rejected) advanced it by less than {STALL_PACE_ADAPTIVE:e} (adaptive steps; {STALL_PACE:e} with fixed steps) of the time left to the next output time each, a pace at which it would take more than {:e} ({:e}) steps to get there, though every step stayed above the step floor ({floor:e}) ({})",
                1.0 / STALL_PACE_ADAPTIVE,
                1.0 / STALL_PACE,
                smallest_gap()
            ),
            Failure::Repulsion => format!(
                "the repulsion (rho/rho*)^gamma overflows at t = {t}: gamma = {gamma}, rho/rho* = {} at gap {} of member {member}",
                self.detail, self.index
            ),
        }
    }
}

/// Work counters of a GPU solver (`gpu::solver::GpuSolver`): part of every backend's report,
/// since a study's manifest sums them over its chunks whatever ran them.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct GpuStats {
    /// Compute dispatches (begin_interval, advance, gather).
    pub dispatches: u64,
    /// Accepted steps summed over members.
    pub steps: u64,
    /// Command buffers submitted.
    pub submits: u64,
    /// Read-backs (each one a copy submission and a wait).
    pub readbacks: u64,
    /// Bytes read back from the GPU.
    pub bytes_read: u64,
    /// Bytes written to the GPU (initial upload, configs).
    pub bytes_written: u64,
    /// Trial steps each member may take per `advance` dispatch.
    pub attempts_per_dispatch: u64,
    /// `advance` dispatches per submit (partitioned kernel: trial steps per submit).
    pub dispatches_per_submit: u64,
    /// Segments per member of the partitioned kernel; 0: one invocation per member.
    pub segments: u64,
}

impl GpuStats {
    /// Adds the work of another solver (a study's next chunk): counters add up, the per-dispatch
    /// settings are the largest seen.
    pub fn accumulate(&mut self, other: &GpuStats) {
        self.dispatches += other.dispatches;
        self.steps += other.steps;
        self.submits += other.submits;
        self.readbacks += other.readbacks;
        self.bytes_read += other.bytes_read;
        self.bytes_written += other.bytes_written;
        self.attempts_per_dispatch = self.attempts_per_dispatch.max(other.attempts_per_dispatch);
        self.dispatches_per_submit = self.dispatches_per_submit.max(other.dispatches_per_submit);
        self.segments = self.segments.max(other.segments);
    }
}
