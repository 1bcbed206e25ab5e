//! The `[time]` section: final time, output times and the step control (fixed or adaptive).

use super::checks::{check_finite, check_non_empty, check_range, Range};
use super::file::{OutputsSpec, TimeSection};
use crate::error::{Error, Result};
use crate::model::params::Stepping;

pub(super) struct Time {
    pub output_times: Vec<f64>,
    pub stepping: Stepping,
}

/// The most fixed steps a member may take: end/dt beyond it is refused before the run (at 1e-30
/// end, the default dt_min, a run took 2e28 steps and never ended; 1e12 steps are days at the
/// fastest rates of `cargo bench --bench cpu_solver`).
const MAX_FIXED_STEPS: f64 = 1e12;

pub(super) fn validate_time(t: &TimeSection) -> Result<Time> {
    let end = check_range(
        "time.end",
        t.end,
        Range::of("end").gt(0.0),
        "the final time",
    )?;
    let output_times = output_times(&t.outputs, end)?;
    let (dt_min, dt_min_text) = match t.dt_min {
        Some(v) => {
            let v = check_range(
                "time.dt_min",
                v,
                Range::of("dt_min").gt(0.0).lt(end).upper_text("end"),
                "a member whose step falls below dt_min is marked failed",
            )?;
            // Named, so that a step refused for it says where its bound comes from.
            (v, format!("dt_min = {v:e}"))
        }
        // Far below any step a run needs, so that in practice the floor is the time resolution
        // (control::step_floor, 2^-90 t): collisions of heavy particles with little lubrication
        // need steps of 1e-18 t and below (docs/accuracy.md); with 1e-18 end two of twelve such
        // runs failed at dt_min that complete with it lower.
        // Never 0 (end below ~1e-278): at t = 0 the floor is dt_min alone.
        None => (
            (1e-30 * end).max(f64::MIN_POSITIVE),
            "1e-30 end".to_string(),
        ),
    };
    let stepping =
        match (t.dt, t.tolerance) {
            (Some(dt), None) => {
                let fewest = end / MAX_FIXED_STEPS;
                let range = if fewest > dt_min {
                    Range::of("dt").ge(fewest).lower_text(format!(
                        "end/{MAX_FIXED_STEPS:e} = {}",
                        crate::input::number_text(fewest)
                    ))
                } else {
                    Range::of("dt").gt(dt_min).lower_text(dt_min_text.clone())
                }
                .le(end)
                .upper_text(format!("end = {}", crate::input::number_text(end)));
                let dt = check_range(
                    "time.dt",
                    dt,
                    range,
                    "the fixed step (a member takes at most 1e12 of them)",
                )?;
                if t.dt_initial.is_some() {
                    return Err(Error::missing(
                        "time.dt_initial",
                        "only with adaptive steps (time.tolerance)",
                    ));
                }
                Stepping::Fixed { dt, dt_min }
            }
            (None, Some(tol)) => {
                let tolerance = check_range(
                    "time.tolerance",
                    tol,
                    Range::of("tolerance")
                        .ge(1e-13)
                        .le(1e-1)
                        .lower_text("1e-13"),
                    "local error tolerance of adaptive steps",
                )?;
                let range = Range::of("dt_initial")
                    .gt(dt_min)
                    .le(end)
                    .lower_text(dt_min_text)
                    .upper_text("end");
                let dt_initial = check_range(
                    "time.dt_initial",
                    t.dt_initial.unwrap_or(1e-4 * end),
                    range,
                    if t.dt_initial.is_some() {
                        "the first trial step"
                    } else {
                        "the first trial step (not set: 1e-4 end)"
                    },
                )?;
                Stepping::Adaptive {
                    tolerance,
                    dt_initial,
                    dt_min,
                }
            }
            (Some(_), Some(_)) => return Err(Error::missing(
                "time.dt",
                "give either time.dt (fixed steps) or time.tolerance (adaptive steps), not both",
            )),
            (None, None) => {
                return Err(Error::missing(
                    "time.dt",
                    "give time.dt (fixed steps, 0 < dt <= end) or time.tolerance (adaptive steps)",
                ))
            }
        };
    Ok(Time {
        output_times,
        stepping,
    })
}

/// Evenly spaced times from 0 to `end` (both included, `end` exact), or the given list, which
/// must increase strictly within [0, end].
fn output_times(outputs: &OutputsSpec, end: f64) -> Result<Vec<f64>> {
    match outputs {
        OutputsSpec::Count(k) => {
            let k = check_range(
                "time.outputs",
                *k,
                Range::count(2, 100_000).or("a list of times"),
                "number of evenly spaced output times including 0 and end",
            )? as usize;
            let times: Vec<f64> = (0..k)
                .map(|j| {
                    if j + 1 == k {
                        end
                    } else {
                        end * j as f64 / (k - 1) as f64
                    }
                })
                .collect();
            // end·j overflows for end near the largest float: refuse rather than write inf.
            if times.windows(2).any(|w| !(w[1] > w[0] && w[1].is_finite())) {
                return Err(Error::invalid(
                    "time.end",
                    format!("{end:e}"),
                    format!("the {k} evenly spaced output times from 0 to end are not finite and strictly increasing"),
                    format!("end <= {:e}", f64::MAX / k as f64),
                ));
            }
            Ok(times)
        }
        OutputsSpec::Times(list) => {
            check_non_empty(
                "time.outputs",
                list,
                "no output time",
                "a non-empty increasing list of times in [0, end]",
            )?;
            for (j, &v) in list.iter().enumerate() {
                let field = format!("time.outputs[{j}]");
                check_finite(&field, v, "a finite number".into())?;
                if !(0.0..=end).contains(&v) || (j > 0 && v <= list[j - 1]) {
                    return Err(Error::invalid(
                        field,
                        v,
                        "output times must increase strictly and lie in [0, end]",
                        format!("previous time < value <= {end}"),
                    ));
                }
            }
            Ok(list.clone())
        }
    }
}
