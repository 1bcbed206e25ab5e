//! The arithmetic of a convergence study: difference norms, observed rates, the verdict on
//! them and the Richardson limit (see the documentation of [`converge`](super)).

use serde::Serialize;

/// Two successive observed rates further apart than this are "drifting": not yet asymptotic.
pub const DRIFT_TOLERANCE: f64 = 0.15;

/// A difference below ROUNDING_FACTOR · max(N_K ε₆₄, ε) · max(1, max|f_K|) is rounding (N_K the
/// largest N, ε₆₄ that of f64, ε that of the run's precision; the 1 is the scale of a field that
/// is zero, such as u at rest: rho and rho* are at most 1, and times and lengths are O(1)).
pub const ROUNDING_FACTOR: f64 = 16.0;

/// A difference at the largest pair below this many times the rounding level makes the verdict
/// [`Verdict::RoundingLimited`] (a relative error of 1 % in each difference moves a rate by
/// about 0.03).
pub const ROUNDING_LIMITED: f64 = 100.0;

/// What the L1 rates at one field and output time say.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    /// Every difference is at rounding level (the field does not depend on N): nothing to
    /// converge, the limit is the field itself.
    Exact,
    /// The difference at the largest pair is within [`ROUNDING_LIMITED`] times the rounding
    /// level (but not every difference is rounding): the field has converged as far as the
    /// precision resolves, and its last rates are set by rounding, not by N.
    RoundingLimited,
    /// The last two observed rates are finite, positive and within [`DRIFT_TOLERANCE`].
    Asymptotic,
    /// The last two observed rates differ by more than [`DRIFT_TOLERANCE`].
    Drifting,
    /// A difference grew, or a rate is not finite (NaN from a failed member, or a difference
    /// that is zero at one pair only): the differences do not decrease like a power of N.
    NotMonotone,
    /// Fewer than two observed rates (fewer than 4 values of N): drift cannot be judged.
    TooFewRates,
    /// A run failed before this time at some N (its fields are NaN): nothing to judge.
    Failed,
}

impl Verdict {
    /// Whether the rates may be read as converged.
    pub fn is_asymptotic(self) -> bool {
        matches!(
            self,
            Verdict::Exact | Verdict::RoundingLimited | Verdict::Asymptotic
        )
    }

    pub fn name(self) -> &'static str {
        match self {
            Verdict::Exact => "exact",
            Verdict::RoundingLimited => "rounding_limited",
            Verdict::Asymptotic => "asymptotic",
            Verdict::Drifting => "drifting",
            Verdict::NotMonotone => "not_monotone",
            Verdict::TooFewRates => "too_few_rates",
            Verdict::Failed => "failed",
        }
    }
}

/// L1, L2 (means over the grid points) and L∞ norms of a difference.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Norms {
    pub l1: f64,
    pub l2: f64,
    pub linf: f64,
}

/// Norms of `a − b` over the grid (NaN where either holds a NaN).
pub fn difference_norms(a: &[f64], b: &[f64]) -> Norms {
    let g = a.len().max(1) as f64;
    let (mut l1, mut l2, mut linf) = (0.0, 0.0, 0.0f64);
    for (x, y) in a.iter().zip(b) {
        let d = (x - y).abs();
        l1 += d;
        l2 += d * d;
        linf = if d.is_nan() { f64::NAN } else { linf.max(d) };
    }
    Norms {
        l1: l1 / g,
        l2: (l2 / g).sqrt(),
        linf,
    }
}

/// Observed rate between two successive differences: ln(e_prev/e_next)/ln(r) (NaN when either
/// is NaN or both are zero; +inf when only the later one is zero).
pub fn observed_rate(e_prev: f64, e_next: f64, ratio: f64) -> f64 {
    if !(e_prev.is_finite() && e_next.is_finite()) || (e_prev == 0.0 && e_next == 0.0) {
        return f64::NAN;
    }
    (e_prev / e_next).ln() / ratio.ln()
}

/// The verdict on a sequence of L1 differences and their rates (`rates[k]` between
/// `diffs[k]` and `diffs[k + 1]`); `rounding` is the level below which a difference is rounding.
pub fn verdict(diffs: &[f64], rates: &[f64], rounding: f64) -> Verdict {
    if diffs.iter().any(|e| e.is_nan()) {
        return Verdict::Failed;
    }
    if diffs.iter().all(|&e| e <= rounding) {
        return Verdict::Exact;
    }
    let tail: Vec<f64> = rates.iter().rev().take(2).copied().collect();
    // Near the rounding level only where rounding shows in the last rate (not finite and
    // positive, or fallen below the one before): differences that still fall steadily are
    // judged by their rates (in f32 the level, 1.9e-4 at 100 times, is above real differences
    // of modest N, which were called rounding_limited and asymptotic with 3 N).
    let spoiled = match tail.as_slice() {
        [last, ..] if !(last.is_finite() && *last > 0.0) => true,
        [last, previous] => previous.is_finite() && *last < previous - DRIFT_TOLERANCE,
        _ => false,
    };
    if spoiled
        && diffs
            .last()
            .is_some_and(|&e| e <= ROUNDING_LIMITED * rounding)
    {
        return Verdict::RoundingLimited;
    }
    if tail.iter().any(|&p| !(p.is_finite() && p > 0.0)) {
        return Verdict::NotMonotone;
    }
    if tail.len() < 2 {
        return Verdict::TooFewRates;
    }
    if (tail[0] - tail[1]).abs() > DRIFT_TOLERANCE {
        Verdict::Drifting
    } else {
        Verdict::Asymptotic
    }
}

/// Richardson extrapolation f_K + (f_K − f_{K−1})/(r^p − 1) (NaN everywhere when p is not a
/// finite positive rate).
pub fn richardson(fine: &[f64], coarse: &[f64], ratio: f64, rate: f64) -> Vec<f64> {
    let denom = ratio.powf(rate) - 1.0;
    fine.iter()
        .zip(coarse)
        .map(|(&f, &c)| {
            if rate.is_finite() && rate > 0.0 && denom > 0.0 {
                f + (f - c) / denom
            } else {
                f64::NAN
            }
        })
        .collect()
}

/// Least-squares slope of ln e against ln n over the pairs with e > 0 (negated: the rate), and
/// log10 of the constant C in e = C n^-p; `None` with fewer than 2 such pairs.
pub(super) fn fit_rate(n: &[f64], e: &[f64]) -> Option<(f64, f64)> {
    let pts: Vec<(f64, f64)> = n
        .iter()
        .zip(e)
        .filter(|(_, &e)| e.is_finite() && e > 0.0)
        .map(|(&n, &e)| (n.log10(), e.log10()))
        .collect();
    if pts.len() < 2 {
        return None;
    }
    let m = pts.len() as f64;
    let (sx, sy) = pts
        .iter()
        .fold((0.0, 0.0), |(a, b), &(x, y)| (a + x, b + y));
    let (mx, my) = (sx / m, sy / m);
    let sxx: f64 = pts.iter().map(|&(x, _)| (x - mx) * (x - mx)).sum();
    let sxy: f64 = pts.iter().map(|&(x, y)| (x - mx) * (y - my)).sum();
    if sxx <= 0.0 {
        return None;
    }
    let slope = sxy / sxx;
    Some((-slope, my - slope * mx))
}
