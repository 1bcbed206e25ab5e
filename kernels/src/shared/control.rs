//! Per-member step-size control: which step to try next, and what to do with its outcome
//! (accepted only when every value is finite, the energy did not rise beyond the forcing's work
//! and the error estimate is within the tolerance).
//! CPU twin of `shaders/control.wgsl` (`trial_step`, `conclude_attempt`, `two_sum`, ...);
//! keep the two in sync. (err^-1/2 is written 1/sqrt(err): sqrt is exact on every backend, pow
//! is not, and the GPU must take the same accepted steps; other roots go through the twin exp
//! and ln of `f64_math`, which the f64 kernel computes operation for operation.)

use super::f64_math;
use super::f64_math::two_sum;
use crate::failure::Failure;

/// The highest order the extrapolation tableau reaches (`order = 1..=MAX_ORDER`). 8, not 6: on
/// chains where the columns fall to about second order (docs/accuracy.md), each column still
/// divides the error constant, and order 8 reached 1e-10 on the N = 200 chain with 2.3 times
/// fewer substeps than order 6; orders 9 and 10 with fewer still, but their error drifted to 4
/// times the tolerance, and order 12 lost its accuracy to rounding there. Auto up to 10 saved
/// 1.1-1.5 times at 1e-10 on random chains, but near contact its error grew 2.6-3.6 times.
pub const MAX_ORDER: u8 = 8;

/// How steps are chosen within one output interval [t_start, t_end].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rules {
    pub t_start: f64,
    pub t_end: f64,
    /// Fixed steps: the interval cut into equal steps no longer than dt; `None` when adaptive.
    pub fixed_h: Option<f64>,
    pub dt_min: f64,
    /// The precision's [`TIME_RESOLUTION_F64`] (or f32's): steps below this fraction of |t| are
    /// lost in the rounding of t.
    pub time_resolution: f64,
}

impl Rules {
    pub fn new(
        t_start: f64,
        t_end: f64,
        fixed_dt: Option<f64>,
        dt_min: f64,
        time_resolution: f64,
    ) -> Rules {
        let fixed_h = fixed_dt.map(|dt| {
            let count = ((t_end - t_start) / dt * (1.0 - 1e-12)).ceil().max(1.0);
            (t_end - t_start) / count
        });
        Rules {
            t_start,
            t_end,
            fixed_h,
            dt_min,
            time_resolution,
        }
    }

    /// The smallest step a member may take at time t: dt_min, or the time resolution at t
    /// where that is larger ([`step_floor`]).
    pub fn step_floor(&self, t: f64) -> f64 {
        step_floor(self.dt_min, self.time_resolution, t)
    }
}

/// Steps shorter than 2^-90 |t| are taken as a collapse of the step: below it a member has
/// failed whatever dt_min says. Time is kept as t plus what its rounding left out
/// ([`StepControl::t_low`], [`two_sum`]), so a step far below the last place of t still moves it
/// exactly (a step of 2^-90 t is added with ~2^-16 relative rounding). The floor was 2^-46 |t|,
/// the last places of t alone: near contact a collision's time scale falls with the gap (about
/// 2 eps d/mu) far below that, and the heavier near-contact chains (N = 40 to 150 of the
/// extremes matrix's mu = 1e-4, gamma = 1 member) failed at their first collision at every
/// tolerance, where steps of a few 1e-18 at t = 0.0037 (2^-52 t) resolve it (docs/accuracy.md).
pub const TIME_RESOLUTION_F64: f64 = 1.0 / (1u128 << 90) as f64;
/// The same for f32 time (2^-18 |t|: 32 to 64 units in the last place of an f32 t).
pub const TIME_RESOLUTION_F32: f64 = 1.0 / (1u64 << 18) as f64;

/// max(dt_min, time_resolution |t|): the step below which a member fails.
#[inline]
pub fn step_floor(dt_min: f64, time_resolution: f64, t: f64) -> f64 {
    dt_min.max(time_resolution * t.abs())
}

/// Attempts after which a member checks that its steps still advance it ([`StepControl::window_t`]).
pub const STALL_WINDOW: u32 = 100_000;
/// The slowest pace a member may keep over [`STALL_WINDOW`] attempts, as a fraction of the time
/// left to the next output time an attempt: 1e-12, the fixed step's floor (end/1e12). Slower,
/// the member would take more than 1e12 attempts to get there and is failed: a forcing singular
/// at a quadrature point (tan(pi x) at x = 1/2) held every step near 1e-28 at t = 1e-14, each
/// above the step floor, and the run never ended. Collisions resolved with steps of 1e-18 t
/// take thousands of attempts at that pace, not 1e5 (docs/accuracy-measurements.md). For fixed
/// steps, which may be as small as end/1e12 (`time.dt`'s range).
pub const STALL_PACE: f64 = 1e-12;
/// The same for adaptive steps: 1e-10, so more than 1e10 attempts to the next output time
/// (hours at the fastest rates of small chains). At 1e-12 an f32 member with gamma = 1000 and
/// mu = 1e-8 kept a pace of ~1e-12 (its steps near the rounding of its error estimates) and ran
/// for hours where f64 failed it at once; at 1e-9 a legitimate run of 3e9 attempts in one
/// output interval (order 2 to t = 1e6 under an oscillating forcing, 2.5 h) failed.
pub const STALL_PACE_ADAPTIVE: f64 = 1e-10;

pub const REJECT_SHRINK: f64 = 0.25;
pub const SAFETY: f64 = 0.9;
pub const MAX_GROWTH: f64 = 5.0;
pub const MAX_SHRINK: f64 = 0.2;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepControl {
    /// The time, rounded; the exact time is t + t_low.
    pub t: f64,
    /// What the rounding of t left out (|t_low| <= half an ulp of t): steps far below the last
    /// place of t add up here ([`two_sum`]).
    pub t_low: f64,
    pub dt: f64,
    pub accepted: u64,
    pub rejected: u64,
    /// Fixed steps: accepted steps since the interval start while no step was rejected, so that
    /// t = t_start + k·h exactly (time is a count of steps, not an accumulated sum).
    pub regular_steps: u64,
    pub regular: bool,
    pub failure: Failure,
    pub failure_time: f64,
    /// What the failure message names: a position, a density ratio or ln of the smallest gap.
    pub failure_detail: f64,
    /// ... and the particle or gap it concerns (1-based).
    pub failure_index: u32,
    /// Discrete energy of the current state.
    pub energy: f64,
    /// The tableau column the next step ends in (its order; the fixed order, or auto's choice).
    pub order: u8,
    /// Sum of the accepted steps' local error estimates (see [`Outcome::estimate`]).
    pub error_sum: f64,
    /// The last accepted step, when the controller chose it (not shortened to an output time)
    /// and the next one ends in the same column; 0 otherwise (see [`predictive_factor`]).
    pub h_previous: f64,
    /// Its scaled error estimate, at least 1e-2.
    pub err_previous: f64,
    /// The last attempt was rejected: the step accepted next raises neither the step nor the
    /// column (see `conclude_attempt`).
    pub after_rejection: bool,
    /// The time at the start of the current window of [`STALL_WINDOW`] attempts, and the
    /// attempts in it so far (both reset at each output interval).
    pub window_t: f64,
    pub window_attempts: u32,
}

/// Why a trial step was not accepted (or that it was).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outcome {
    /// Every value finite.
    pub admissible: bool,
    /// Energy not above the previous one plus the forcing's work (to rounding).
    pub energy_ok: bool,
    /// Scaled error estimate that decides acceptance (0 for fixed steps).
    pub err: f64,
    /// The step factor the estimates ask for (`step_factor`, or auto's choice); adaptive only.
    pub factor: f64,
    /// The tableau column the next step should use.
    pub order_next: u8,
    /// Unscaled local error estimate of the step (relative on gaps, mixed on velocities), added
    /// to `error_sum` when accepted; 0 where none exists (order 1, fixed steps).
    pub estimate: f64,
}

impl StepControl {
    pub fn new(dt: f64, order: u8) -> StepControl {
        StepControl {
            order,
            error_sum: 0.0,
            h_previous: 0.0,
            err_previous: 0.0,
            t: 0.0,
            t_low: 0.0,
            dt,
            accepted: 0,
            rejected: 0,
            regular_steps: 0,
            regular: true,
            after_rejection: false,
            failure: Failure::None,
            failure_time: 0.0,
            failure_detail: 0.0,
            failure_index: 0,
            energy: 0.0,
            window_t: 0.0,
            window_attempts: 0,
        }
    }

    pub fn begin_interval(&mut self, rules: &Rules) {
        if self.failure != Failure::None {
            return;
        }
        self.regular_steps = 0;
        self.regular = true;
        self.window_t = self.t;
        self.window_attempts = 0;
        if let Some(h) = rules.fixed_h {
            self.dt = h;
        }
    }

    pub fn running(&self, rules: &Rules) -> bool {
        self.failure == Failure::None && self.t < rules.t_end
    }

    /// What is left of the output interval: t_end - (t + t_low).
    pub fn remaining(&self, rules: &Rules) -> f64 {
        (rules.t_end - self.t) - self.t_low
    }

    /// The step to try: dt, or exactly what is left when that is within rounding of dt (no
    /// sliver steps before an output time). Adaptive steps take what is left in two halves when
    /// it is less than two steps: dt and then a sliver cost as many steps, and a sliver's
    /// estimates are near rounding, so auto read every column as equally cheap after it,
    /// dropped an order and was rejected at the next output interval's first step (on
    /// `docs/work_precision_random_n200.toml` at 1e-10: 145 + 4 steps, 98 + 0 in halves).
    pub fn trial_step(&self, rules: &Rules) -> f64 {
        let remaining = self.remaining(rules);
        if remaining <= self.dt * (1.0 + 1e-9) {
            remaining
        } else if rules.fixed_h.is_none() && remaining < 2.0 * self.dt {
            0.5 * remaining
        } else {
            self.dt
        }
    }

    /// Records the outcome of a trial step h. Returns whether the step is accepted. When the
    /// step falls below the step floor (dt_min or the time resolution) the member fails with the reason of the last rejection (the
    /// caller fills in the smallest gap it names); when its last [`STALL_WINDOW`] attempts
    /// advanced it less than [`STALL_PACE`] of the time left an attempt, it fails as stalled
    /// (this attempt not taken).
    pub fn conclude_attempt(&mut self, rules: &Rules, h: f64, outcome: Outcome) -> bool {
        self.window_attempts += 1;
        if self.window_attempts >= STALL_WINDOW {
            let advanced = (self.t - self.window_t) + self.t_low;
            let pace = if rules.fixed_h.is_some() {
                STALL_PACE
            } else {
                STALL_PACE_ADAPTIVE
            };
            if advanced < STALL_WINDOW as f64 * pace * self.remaining(rules) {
                self.failure = Failure::Stalled;
                self.failure_time = self.t;
                return false;
            }
            self.window_t = self.t;
            self.window_attempts = 0;
        }
        let Outcome {
            admissible,
            energy_ok,
            err,
            factor,
            order_next,
            estimate,
        } = outcome;
        let accepted = admissible && energy_ok && err <= 1.0;
        // The step accepted right after a rejection raises neither the step nor the column, as
        // RADAU5 and ODEX/SEULEX do (Hairer and Wanner I, II.9): near contact auto raised to
        // column 8 after each such step and was rejected there again (err 1.1-2.2), 11531
        // rejections to 21839 accepted steps on docs/work_precision_extreme.toml at 1e-10;
        // with the rule 6830 to 22140 (docs/accuracy.md).
        let (factor, order_next) = if accepted && self.after_rejection {
            (factor.min(1.0), order_next.min(self.order))
        } else {
            (factor, order_next)
        };
        self.after_rejection = !accepted;
        if accepted {
            let shortened = h < self.dt * (1.0 - 1e-9);
            self.accepted += 1;
            self.error_sum += estimate;
            let landed = h == self.remaining(rules);
            self.regular_steps += 1;
            (self.t, self.t_low) = if landed {
                (rules.t_end, 0.0)
            } else if let (Some(hf), true) = (rules.fixed_h, self.regular) {
                (rules.t_start + self.regular_steps as f64 * hf, 0.0)
            } else {
                two_sum(self.t, h + self.t_low)
            };
            if let Some(hf) = rules.fixed_h {
                self.dt = (2.0 * self.dt).min(hf);
            } else {
                // The estimate of column k grows like h^k (order 1: like h^2, as `step_factor`
                // takes it).
                let exponent = self.order.max(2);
                let factor = if shortened {
                    factor
                } else {
                    predictive_factor(factor, h, err, exponent, self.h_previous, self.err_previous)
                };
                self.h_previous = if shortened || order_next != self.order {
                    0.0
                } else {
                    h
                };
                self.err_previous = err.max(1e-2);
                self.order = order_next;
                // A step shortened to land on an output time says little about dt.
                self.dt = if landed {
                    self.dt.max(h * factor)
                } else {
                    h * factor
                };
            }
            true
        } else {
            self.rejected += 1;
            self.regular = false;
            self.dt = if admissible && energy_ok {
                if order_next != self.order {
                    self.h_previous = 0.0;
                }
                self.order = order_next;
                h * factor.min(1.0)
            } else {
                h * REJECT_SHRINK
            };
            if self.dt < rules.step_floor(self.t) {
                self.failure = if !admissible {
                    Failure::Inadmissible
                } else if !energy_ok {
                    Failure::EnergyRose
                } else {
                    Failure::ErrorTooLarge
                };
                self.failure_time = self.t;
            }
            false
        }
    }

    /// Fails the member at once (a failure no smaller step can cure).
    pub fn fail(&mut self, failure: Failure, index: u32, detail: f64) {
        self.failure = failure;
        self.failure_time = self.t;
        self.failure_index = index;
        self.failure_detail = detail;
    }
}

/// The factor by which a step whose scaled error estimate grows like h^q may change:
/// SAFETY·err^(-1/q), within [MAX_SHRINK, MAX_GROWTH].
#[inline]
pub fn step_factor(err: f64, q: u8) -> f64 {
    (SAFETY / root(err.max(1e-10), q)).clamp(MAX_SHRINK, MAX_GROWTH)
}

/// Gustafsson's predictive controller (Hairer and Wanner II, section IV.8, as RADAU5 has it):
/// the standard factor times the trend of the last two accepted steps, (h / h_previous)
/// (err_previous / err)^(1/q), where that trend is below 1 (the step shrinking, or the error
/// growing at the same step), within [MAX_SHRINK, factor]. Approaching a collision the time
/// scale falls geometrically: the standard factor alone grew each accepted step by ~1.15 and
/// the next attempt was rejected (err ~15), one attempt in two (the near-contact chain of
/// `docs/work_precision_extreme.toml` at 1e-6: 5195 + 3668 steps; with the trend 4945 + 192).
/// `h_previous` is 0 (no trend) after a step shortened to an output time or a change of column.
#[inline]
pub fn predictive_factor(
    factor: f64,
    h: f64,
    err: f64,
    exponent: u8,
    h_previous: f64,
    err_previous: f64,
) -> f64 {
    if h_previous <= 0.0 {
        return factor;
    }
    let trend = h / h_previous * root(err_previous / err.max(1e-10), exponent);
    if trend >= 1.0 {
        factor
    } else {
        (factor * trend).max(MAX_SHRINK)
    }
}

/// x^(1/q): sqrt for q = 2, else the twin exp and ln of `f64_math` (see the module's docs).
#[inline]
fn root(x: f64, q: u8) -> f64 {
    match q {
        1 => x,
        2 => x.sqrt(),
        _ => f64_math::exp(f64_math::ln(x) / q as f64),
    }
}

/// Euler substeps n_j of tableau row j (1-based): n_j = j, or the harmonic sequence from 2,
/// n_j = j + 1, where [`sequence_from_two`] says so (as SEULEX's default sequence starts: 2, 3,
/// 4, 6, ...).
#[inline]
pub const fn row_substeps(j: u32, from_two: bool) -> u32 {
    if from_two {
        j + 1
    } else {
        j
    }
}

/// Whether a step's rows take the sequence from 2 ([`row_substeps`]): where the run chose it
/// (`[solver] sequence = "from_2"`) and the step extrapolates (order 1's rows stay one Euler
/// step and its two halves). Measured on the N = 200 random chain in f64 (docs/accuracy.md):
/// without the single implicit Euler step of row 1, which carries the stiff components' largest
/// error into every column, each column's error is 2.5-3.5 times smaller at the same step, and
/// auto reaches an error of 3e-8 with 1.3-1.5 times less work. Not the default: near contact
/// at 1e-9 it cost 1.4 times more, its weights amplify the rows' rounding ~3 times more (in f32
/// its error stopped falling with the tolerance; the GPU's agreement at order 8), its
/// extrapolated velocities can open a near-contact gap beyond the MAX_OPENING safeguard at
/// every step down to 1e-12 (a fixed-step member with that dt_min failed), and fixed steps cost
/// p(p+3)/2 substeps instead of p(p+1)/2. `roughlub accuracy` measures auto with both in f64.
#[inline]
pub const fn sequence_from_two(chosen: bool, extrapolates: bool) -> bool {
    chosen && extrapolates
}

/// Substeps of a step's first k rows (n_1 + … + n_k, [`row_substeps`]): its cost.
#[inline]
pub fn tableau_work(k: u8, from_two: bool) -> f64 {
    (1..=k as u32)
        .map(|j| row_substeps(j, from_two))
        .sum::<u32>() as f64
}

/// How far below an f32 run's tolerance its column's rounding must stay: a column k may carry
/// `extrapolation_rounding_gain(k)` ulps of f32 in each step only where that is at most
/// 1/F32_ROUNDING_MARGIN of the tolerance. Measured on the paper's case 3 (order 4 at 1e-4,
/// rounding 0.05 of the tolerance: error 0.8 times the tolerance; order 3 at 1e-5, 0.13: 2.7
/// times) against auto without it (column 5 at 1e-4, 0.22: 13 times; column 4 at 1e-5, 0.54: 23
/// times; order 2 at 1e-6, 0.3: 32 times): the rounding adds up over the steps where the
/// estimates, which difference two columns of the same rows, leave most of it out.
pub const F32_ROUNDING_MARGIN: f64 = 10.0;

/// The highest column an adaptive run may end its steps in (auto's ceiling; the f32 tolerance
/// floors, `Order::f32_tolerance_floor`, hold column max(k, 3) of order k to the same margin):
/// MAX_ORDER in f64, and in f32 the highest column whose
/// rounding stays [`F32_ROUNDING_MARGIN`] times below the tolerance, at least 2. In f64 the rule
/// would bind only below about 1.6e-10 (column 8 of the sequence from 2); tried there on the four
/// chains of docs/error_estimate/tolerance_factor.py, at 1e-10 it took about twice the steps
/// (estimates 2.1-2.3 times larger) for errors that moved both ways (0.19-7.5 times the
/// tolerance before, 0.34-6.7 after), so f64 is not capped.
pub fn top_column(tolerance: f64, f32_rounding: bool, from_two: bool) -> u8 {
    if !f32_rounding {
        return MAX_ORDER;
    }
    (3..=MAX_ORDER)
        .take_while(|&k| f32_column_floor(k, from_two) <= tolerance)
        .last()
        .unwrap_or(2)
}

/// The tightest tolerance at which column k's f32 rounding stays [`F32_ROUNDING_MARGIN`] times
/// below it: the margin times 2^-23 times its rounding gain.
pub fn f32_column_floor(k: u8, from_two: bool) -> f64 {
    F32_ROUNDING_MARGIN * extrapolation_rounding_gain(k, from_two) * f64::from(f32::EPSILON)
}

/// Auto order: the column for the next step and its step factor, from the scaled estimates
/// `errs[j]` of columns j = 2..=k (Hairer–Wanner II §IV.9 and the order selection of their
/// ODEX/SEULEX: the least work per unit step, W_j = A_j / H_j). A column is dropped when the one
/// below costs less per unit step by a margin, added when the current one beats the one below
/// (from column 2, which has no column below to compare with, always after an accepted step) and
/// is below `top` ([`top_column`]); a rejected step never raises the order.
pub fn select_order(
    k: u8,
    errs: &[f64; MAX_ORDER as usize + 1],
    accepted: bool,
    from_two: bool,
    top: u8,
) -> (u8, f64) {
    let factor = |j: u8| step_factor(errs[j as usize], j);
    let work = |j: u8| tableau_work(j, from_two) / factor(j);
    if k > 2 && work(k - 1) < 0.8 * work(k) {
        return (k - 1, factor(k - 1));
    }
    let raise = accepted && k < top && (k == 2 || work(k) < 0.9 * work(k - 1));
    if raise {
        let f =
            (factor(k) * tableau_work(k + 1, from_two) / tableau_work(k, from_two)).min(MAX_GROWTH);
        (k + 1, f)
    } else {
        (k, factor(k))
    }
}

/// Relative slack of the energy check: rounding of the sums that make E (f64).
pub const ENERGY_RTOL_F64: f64 = 1e-12;
/// The same for the f32 GPU kernel (sums of N terms with 6e-8 relative rounding each, and the
/// rounding of the projection).
pub const ENERGY_RTOL_F32: f64 = 1e-5;
/// f32 only: G = ratio^gamma carries about gamma ulps of rounding, so the slack grows with gamma
/// (4 ulps of f32 per unit of gamma).
pub const ENERGY_RTOL_PER_GAMMA_F32: f64 = 2.4e-7;
/// With forcing, the fraction of the forcing's work h Σ u' F allowed on top of it: the work is
/// itself an O(h) estimate.
pub const WORK_SLACK: f64 = 0.1;

/// The weight c_j = prod_{m != j} n_j / (n_j - n_m) by which column k of the tableau takes row j
/// (polynomial extrapolation to h = 0 through h_j = H / n_j, [`row_substeps`]).
fn extrapolation_weight(j: u32, k: u8, from_two: bool) -> f64 {
    let nj = row_substeps(j, from_two) as f64;
    let mut c = 1.0;
    for m in 1..=k as u32 {
        if m != j {
            c *= nj / (nj - row_substeps(m, from_two) as f64);
        }
    }
    c
}

/// Sum of |c_j| over column k's weights ([`extrapolation_weight`]): how much the extrapolated
/// state amplifies the rows' rounding. 3392 for column 8 of the sequence from 1, 9851 from 2, 1
/// for column 1.
pub fn extrapolation_amplification(k: u8, from_two: bool) -> f64 {
    (1..=k as u32)
        .map(|j| extrapolation_weight(j, k, from_two).abs())
        .sum()
}

/// Sum of |c_j| n_j over column k's weights and its rows' substeps: how many ulps of rounding
/// the column's state and estimate carry, each substep adding about one (1, 5, 22, 91, 367, 1445
/// for columns 1 to 6 from 1).
pub fn extrapolation_rounding_gain(k: u8, from_two: bool) -> f64 {
    (1..=k as u32)
        .map(|j| extrapolation_weight(j, k, from_two).abs() * row_substeps(j, from_two) as f64)
        .sum()
}

/// The largest relative slack [`extrapolated_energy_rtol`] adds: the check is there to catch the
/// linearised repulsion's instability, whose rises are far larger. In f64 the term stays below
/// it (2.2e-9 at column 8 from 2 with gamma = 1000); in f32 it would reach 0.4 of E at column 8
/// with gamma = 1000 and switch the check off, so there the cap leaves the check as it was.
pub const EXTRAPOLATED_ENERGY_SLACK_MAX: f64 = 1e-6;

/// The energy check's relative slack for the extrapolated state of column k of a member with
/// this gamma (1 without repulsion): the sums' rounding (`rtol`) plus the rows' rounding as the
/// tableau amplifies it ([`extrapolation_amplification`]) and E magnifies it: 2 ulps of E per
/// ulp of a velocity (E is quadratic in them), gamma per ulp of a gap (G = (d*/d)^gamma), with
/// `epsilon` the machine epsilon of the state's precision; at most
/// [`EXTRAPOLATED_ENERGY_SLACK_MAX`] more. An estimate (one rounding per row), not a bound.
/// Without it, steps of column 8 were refused at every size where the energy barely falls within
/// a step: near collisions with little lubrication (from 2 in f64, amplification 9851, ~2e-12 of
/// E: the extremes matrix's mu = 1e-4, gamma 100 and 1000 members of rho0.9999_u2 failed with
/// "every smaller step raised the energy") and with gamma = 1000.
pub fn extrapolated_energy_rtol(rtol: f64, gamma: f64, k: u8, from_two: bool, epsilon: f64) -> f64 {
    let amplified = (2.0 + gamma) * epsilon * extrapolation_amplification(k, from_two);
    rtol + amplified.min(EXTRAPOLATED_ENERGY_SLACK_MAX)
}

/// Whether a step from energy `before` to `after`, with the forcing doing `work`, is acceptable.
#[inline(always)]
pub fn energy_acceptable(before: f64, after: f64, work: f64, rtol: f64) -> bool {
    after <= before + work + rtol * before.abs() + WORK_SLACK * work.abs()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Column k's weights by hand: from 1, k = 2: 2 T_2 - T_1; k = 3: T_1 / 2 - 4 T_2 + 9 T_3 / 2;
    /// from 2, k = 2: 3 T_3 - 2 T_2. Column 8, exact rational sums (Python's fractions):
    /// 118717 / 35 from 1, 3103067 / 315 from 2.
    #[test]
    fn extrapolation_amplification_sums_the_weights_magnitudes() {
        // Weighted by the rows' substeps, from 1: 2·2 + 1 = 5, 4·2 + (9/2)·3 + 1/2 = 22.
        assert_eq!(extrapolation_rounding_gain(2, false), 5.0);
        assert!((extrapolation_rounding_gain(3, false) - 22.0).abs() < 1e-12);
        assert!((extrapolation_rounding_gain(6, false) - 7223.0 / 5.0).abs() < 1e-9);
        let cases = [
            (1, false, 1.0),
            (2, false, 3.0),
            (3, false, 9.0),
            (2, true, 5.0),
            (8, false, 118717.0 / 35.0),
            (8, true, 3103067.0 / 315.0),
        ];
        for (k, from_two, expected) in cases {
            let got = extrapolation_amplification(k, from_two);
            assert!(
                (got - expected).abs() <= 1e-12 * expected,
                "column {k}, from two {from_two}: {got} against {expected}"
            );
        }
    }
}
