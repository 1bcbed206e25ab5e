//! One axis of a `[sweep]`: a list (grid) or a range table (samples), each value checked
//! against the range of the setting it sets.

use super::{number, SweepTarget};
use crate::ensemble::design::{Axis, Scale};
use crate::error::{Error, Result};
use crate::scene::checks::{check_gamma, check_mu};
use crate::scene::MAX_PARTICLES;

pub(super) fn target_name(t: &SweepTarget) -> &str {
    match t {
        SweepTarget::Mu => "mu",
        SweepTarget::Gamma => "gamma",
        SweepTarget::Particles => "particles",
        SweepTarget::RoughnessSpread => "roughness_spread",
        SweepTarget::CorrelationLength => "correlation_length",
        SweepTarget::VelocityAmplitudeSpread => "velocity_amplitude_spread",
        SweepTarget::VelocityPhaseSpread => "velocity_phase_spread",
        SweepTarget::Jitter => "jitter",
        SweepTarget::Parameter(p) => p,
    }
}

/// One axis: a list (grid) or a range table (samples), each value checked against the range of
/// the setting it sets.
pub(super) fn axis(field: &str, value: &toml::Value, target: &SweepTarget) -> Result<Axis> {
    match value {
        toml::Value::Array(list) => {
            if list.is_empty() {
                return Err(Error::invalid(
                    field,
                    "[]",
                    "an empty list sweeps nothing",
                    "a non-empty list of values",
                ));
            }
            let mut values: Vec<f64> = Vec::with_capacity(list.len());
            for (j, v) in list.iter().enumerate() {
                let f = format!("{field}[{j}]");
                let x = number(&f, v)?;
                check_value(&f, target, x)?;
                // A listed N is taken as written (a range's draws are rounded: parameter-studies).
                if *target == SweepTarget::Particles && x.fract() != 0.0 {
                    return Err(Error::invalid(
                        &f,
                        x,
                        "the number N of particle intervals",
                        "a whole number",
                    ));
                }
                // A repeated value would be two points with one meaning (and one cell of a
                // response map for two points).
                if let Some(k) = values.iter().position(|&y| y == x) {
                    return Err(Error::invalid(
                        &f,
                        x,
                        format!("the same value as {field}[{k}]"),
                        "distinct values",
                    ));
                }
                values.push(x);
            }
            Ok(Axis::Values(values))
        }
        toml::Value::Table(t) => {
            for key in t.keys() {
                if !matches!(key.as_str(), "min" | "max" | "scale") {
                    return Err(Error::invalid(
                        format!("{field}.{key}"),
                        key,
                        "unknown key of a range",
                        "min, max, scale",
                    ));
                }
            }
            let get = |k: &str| {
                t.get(k)
                    .ok_or_else(|| {
                        Error::missing(format!("{field}.{k}"), "a range needs min and max")
                    })
                    .and_then(|v| number(&format!("{field}.{k}"), v))
            };
            let (min, max) = (get("min")?, get("max")?);
            let scale = match t.get("scale").map(|s| s.as_str()) {
                None | Some(Some("linear")) => Scale::Linear,
                Some(Some("log")) => Scale::Log,
                Some(_) => {
                    return Err(Error::invalid(
                        format!("{field}.scale"),
                        &t["scale"],
                        "how values are spread over the range",
                        "\"linear\" or \"log\"",
                    ))
                }
            };
            if min >= max {
                return Err(Error::invalid(
                    field,
                    format!("{{ min = {min}, max = {max} }}"),
                    "an empty or inverted range",
                    "min < max",
                ));
            }
            if scale == Scale::Log && min <= 0.0 {
                return Err(Error::invalid(
                    format!("{field}.min"),
                    min,
                    "a log scale needs positive values",
                    "min > 0 with scale = \"log\"",
                ));
            }
            check_value(&format!("{field}.min"), target, min)?;
            check_value(&format!("{field}.max"), target, max)?;
            Ok(Axis::Range { min, max, scale })
        }
        other => Err(Error::invalid(
            field,
            other,
            "a swept key takes a list (grid) or a range (sampled designs)",
            "[v1, v2, ...] or { min = a, max = b }",
        )),
    }
}

/// The range of each setting (the same checks as the scene's own keys).
pub(super) fn check_value(field: &str, target: &SweepTarget, v: f64) -> Result<()> {
    let within = |lo: f64, hi: f64, what: &str| {
        if (lo..=hi).contains(&v) {
            Ok(())
        } else {
            Err(Error::invalid(
                field,
                v,
                what,
                format!("{lo} <= value <= {hi}"),
            ))
        }
    };
    match target {
        SweepTarget::Mu => check_mu(field, v).map(|_| ()),
        SweepTarget::Gamma => check_gamma(field, v).map(|_| ()),
        SweepTarget::Particles => within(
            2.0,
            MAX_PARTICLES as f64,
            "the number N of particle intervals",
        ),
        SweepTarget::RoughnessSpread => within(
            0.0,
            crate::ensemble::MAX_RELATIVE_SPREAD,
            "relative spread of the roughness radii",
        ),
        SweepTarget::CorrelationLength => {
            if v > 0.0 {
                Ok(())
            } else {
                Err(Error::invalid(
                    field,
                    v,
                    "correlation length in x",
                    "length > 0",
                ))
            }
        }
        SweepTarget::VelocityAmplitudeSpread => within(0.0, 10.0, "relative spread"),
        SweepTarget::VelocityPhaseSpread => within(0.0, 1.0, "relative spread"),
        SweepTarget::Jitter => within(0.0, 2.0, "relative spread"),
        SweepTarget::Parameter(_) => Ok(()),
    }
}
