//! Variation of the initial data between members: the velocity perturbation and the gap jitter.

use super::streams::{lognormal_sigma, member_rng, normal, Purpose};
use super::EnsembleError;

/// Checks the two spreads of [`perturbed_velocity`] (scene-load validation).
pub fn validate_velocity_perturbation(
    amplitude_spread: f64,
    phase_spread: f64,
) -> Result<(), EnsembleError> {
    for (field, v) in [
        ("velocity.amplitude_spread", amplitude_spread),
        ("velocity.phase_spread", phase_spread),
    ] {
        if !(v >= 0.0 && v.is_finite()) {
            return Err(EnsembleError::parameter(
                field,
                v,
                "a standard deviation must be finite and non-negative",
                "0 <= spread < inf",
            ));
        }
    }
    Ok(())
}

/// Member `member`'s perturbation of a velocity profile u0(x): returns `(factor, phase)` with
/// `factor = 1 + amplitude_spread Z_0` and `phase = phase_spread Z_1`, Z_0, Z_1 independent N(0,1)
/// (draws 0 and 1 of the member's `Velocity` stream, whatever the spreads). So factor has mean 1
/// and standard deviation `amplitude_spread` (it is negative with probability Φ(-1/amplitude_spread),
/// i.e. essentially never for spreads below ~0.25), and phase has mean 0 and standard deviation
/// `phase_spread`, in units of x. The caller evaluates `u_i = factor * u0(q_i - phase)`.
/// Spreads are expected finite and >= 0 (see [`validate_velocity_perturbation`]).
pub fn perturbed_velocity(
    amplitude_spread: f64,
    phase_spread: f64,
    seed: u64,
    member: u64,
) -> (f64, f64) {
    let mut rng = member_rng(seed, Purpose::Velocity, member);
    let z_amplitude = normal(&mut rng);
    let z_phase = normal(&mut rng);
    (1.0 + amplitude_spread * z_amplitude, phase_spread * z_phase)
}

/// Neumaier-compensated sum.
fn compensated_sum(values: impl IntoIterator<Item = f64>) -> f64 {
    let (mut sum, mut c) = (0.0f64, 0.0f64);
    for v in values {
        let t = sum + v;
        c += if sum.abs() >= v.abs() {
            (sum - t) + v
        } else {
            (v - t) + sum
        };
        sum = t;
    }
    sum + c
}

/// Member `member`'s random jitter of particle positions through the gaps d_1..d_N, keeping the
/// total mass (sum of gaps, so q_N = 1) and positive gaps:
///
/// 1. each free gap is multiplied by w_i = exp(s Z_i - s^2/2), s^2 = ln(1 + relative^2), Z_i the
///    i-th normal of the member's `Jitter` stream (lognormal, mean 1, relative sd `relative`;
///    bonded gaps consume their draw too, so gap i's factor does not depend on the bonded set);
/// 2. all free gaps are rescaled by S/S', S and S' the compensated sums of the free gaps before and
///    after step 1;
/// 3. the remaining rounding residual S - sum(new free gaps) (compensated) is added to the largest
///    free gap, twice, so that the compensated sum of the free gaps equals S to within about one
///    ulp of the largest gap (relative error ~1e-16 of the total, independent of N).
///
/// Bonded gaps (`bonded[i] == true`, the zero gaps of Appendix A clusters) are left bit-for-bit
/// untouched. Free gaps must be finite and > 0. On error, `gaps` is unchanged. `relative = 0`
/// leaves the gaps bit-for-bit unchanged.
pub fn jitter_gaps(
    gaps: &mut [f64],
    bonded: Option<&[bool]>,
    relative: f64,
    seed: u64,
    member: u64,
) -> Result<(), EnsembleError> {
    if !(relative >= 0.0 && relative.is_finite()) {
        return Err(EnsembleError::parameter(
            "jitter.relative",
            relative,
            "the relative standard deviation of the gap factors must be finite and non-negative",
            "0 <= relative < inf",
        ));
    }
    if let Some(b) = bonded {
        if b.len() != gaps.len() {
            return Err(EnsembleError::LengthMismatch {
                field: "bonded".into(),
                got: b.len(),
                expected: gaps.len(),
                message: "one flag per gap d_1..d_N".into(),
            });
        }
    }
    let is_free = |i: usize| bonded.is_none_or(|b| !b[i]);
    for (i, &d) in gaps.iter().enumerate() {
        if is_free(i) && !(d > 0.0 && d.is_finite()) {
            return Err(EnsembleError::entry(
                "gaps",
                i,
                d,
                "a free (not bonded) gap must be positive; mark zero gaps as bonded",
                "0 < gap < inf",
            ));
        }
    }
    let free: Vec<usize> = (0..gaps.len()).filter(|&i| is_free(i)).collect();
    if free.is_empty() || relative == 0.0 {
        return Ok(());
    }

    let sigma = lognormal_sigma(relative);
    let shift = 0.5 * sigma * sigma;
    let mut rng = member_rng(seed, Purpose::Jitter, member);
    let mut new = Vec::with_capacity(free.len());
    let mut next_free = free.iter().peekable();
    for (i, &d) in gaps.iter().enumerate() {
        let z = normal(&mut rng);
        if next_free.peek() == Some(&&i) {
            next_free.next();
            new.push(d * (sigma * z - shift).exp());
        }
    }
    let target = compensated_sum(free.iter().map(|&i| gaps[i]));
    let scale = target / compensated_sum(new.iter().copied());
    for v in new.iter_mut() {
        *v *= scale;
    }
    let largest = (0..new.len())
        .max_by(|&a, &b| new[a].total_cmp(&new[b]))
        .expect("at least one free gap");
    for _ in 0..2 {
        let residual = target - compensated_sum(new.iter().copied());
        new[largest] += residual;
    }
    if let Some((k, &v)) = new
        .iter()
        .enumerate()
        .find(|(_, v)| !(**v > 0.0 && v.is_finite()))
    {
        return Err(EnsembleError::entry(
            "gaps",
            free[k],
            v,
            format!("jitter with relative = {relative} produced a non-positive gap"),
            "a smaller jitter.relative",
        ));
    }
    for (&i, &v) in free.iter().zip(&new) {
        gaps[i] = v;
    }
    Ok(())
}
