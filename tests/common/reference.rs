//! Reference models, independent of the solver's code, each with what it is a reference for.
//!
//! - [`dense_reference_step`]: one linearly implicit Euler step assembled densely per rigid body
//!   and solved by LU, with the gap update ln d' = ln d + h·(relative velocity)/d and the
//!   projection onto sum d = const written out directly. Reference for the batched, cancellation-free Thomas sweep
//!   (`backend::cpu::step::euler_step`), including clusters and forcing (tests/numerics.rs).
//! - [`rk4_reference`]: classical RK4 on the position form (q, u) of the model at a tiny step.
//!   Reference for the trajectories and the convergence orders of orders 1 and 2
//!   (tests/numerics.rs).

use nalgebra::{DMatrix, DVector};
use roughlub::model::chain::Chain;

/// The linear system of one Euler step assembled densely per rigid body (free particles and
/// clusters), straight from the model: masses 2 eps n, couplings c_k = mu/d_k + h γ G_k/(d_k+2eps)
/// across free gaps, forces G and F summed over each body. Solved with nalgebra's LU.
#[allow(clippy::too_many_arguments)]
pub fn dense_reference_step(
    eps: f64,
    mu: f64,
    gamma: f64,
    h: f64,
    t: f64,
    gaps: &[f64],
    vel: &[f64],
    dstar: &[f64],
    bonded: &[bool],
    forcing: &dyn Fn(f64, f64) -> f64,
) -> (Vec<f64>, Vec<f64>) {
    let n = gaps.len();
    // body[i] for particles 0..=N; bodies joined by bonded gaps.
    let mut body = vec![0usize; n + 1];
    for i in 1..=n {
        body[i] = if bonded[i - 1] {
            body[i - 1]
        } else {
            body[i - 1] + 1
        };
    }
    let fixed_left = body[0];
    let fixed_right = body[n];
    let bodies = body[n] + 1;
    // Unknown index of each free body.
    let index =
        |b: usize| -> Option<usize> { (b != fixed_left && b != fixed_right).then(|| b - 1) };
    let unknowns = bodies - 2;
    let mut a = DMatrix::<f64>::zeros(unknowns, unknowns);
    let mut r = DVector::<f64>::zeros(unknowns);
    let q: Vec<f64> = std::iter::once(0.0)
        .chain(gaps.iter().scan(0.0, |x, d| {
            *x += d + 2.0 * eps;
            Some(*x)
        }))
        .collect();
    for i in 1..n {
        if let Some(k) = index(body[i]) {
            a[(k, k)] += 2.0 * eps / h;
            r[k] += 2.0 * eps / h * vel[i - 1] + forcing(q[i], t);
        }
    }
    for g in 1..=n {
        if bonded[g - 1] {
            continue;
        }
        let d = gaps[g - 1];
        let s = d + 2.0 * eps;
        let big_g = ((dstar[g - 1] + 2.0 * eps) / s).powf(gamma);
        let c = mu / d + h * gamma * big_g / s;
        let left = index(body[g - 1]);
        let right = index(body[g]);
        if let Some(k) = left {
            a[(k, k)] += c;
            r[k] -= big_g;
        }
        if let Some(k) = right {
            a[(k, k)] += c;
            r[k] += big_g;
        }
        if let (Some(p), Some(k)) = (left, right) {
            a[(p, k)] -= c;
            a[(k, p)] -= c;
        }
    }
    let solution = a.lu().solve(&r).expect("the step matrix is SPD");
    let u_new: Vec<f64> = (1..n)
        .map(|i| index(body[i]).map_or(0.0, |k| solution[k]))
        .collect();
    let u_at = |i: usize| if i == 0 || i == n { 0.0 } else { u_new[i - 1] };
    // The gap update exact in ln d (ln d' = ln d + h (u_g - u_{g-1})/d), then every gap scaled by
    // one factor so that sum d is kept.
    let grown: Vec<f64> = (1..=n)
        .map(|g| {
            let d = gaps[g - 1];
            if bonded[g - 1] {
                0.0
            } else {
                d * (h * (u_at(g) - u_at(g - 1)) / d).exp()
            }
        })
        .collect();
    let scale = gaps.iter().sum::<f64>() / grown.iter().sum::<f64>();
    let gaps_new = grown.iter().map(|d| d * scale).collect();
    (gaps_new, u_new)
}

/// Independent reference: classical RK4 on the position form of the model (q, u), with the
/// forcing integral in closed form, at a step far below the scheme's.
pub fn rk4_reference(
    chain: &Chain,
    mu: f64,
    gamma: f64,
    t_end: f64,
    steps: usize,
) -> (Vec<f64>, Vec<f64>) {
    let n = chain.particles();
    let eps = chain.eps;
    let dstar = chain.dstar.clone().unwrap();
    let q0 = chain.positions();
    let mut state: Vec<f64> = q0[1..n].to_vec();
    state.extend_from_slice(&chain.velocities);
    let rhs = |t: f64, s: &[f64]| -> Vec<f64> {
        let m = n - 1;
        let q = |i: usize| {
            if i == 0 {
                0.0
            } else if i == n {
                1.0
            } else {
                s[i - 1]
            }
        };
        let u = |i: usize| if i == 0 || i == n { 0.0 } else { s[m + i - 1] };
        let d = |i: usize| q(i) - q(i - 1) - 2.0 * eps;
        let g = |i: usize| ((dstar[i - 1] + 2.0 * eps) / (d(i) + 2.0 * eps)).powf(gamma);
        let mut out = vec![0.0; 2 * m];
        for i in 1..n {
            out[i - 1] = u(i);
            // ∫ 0.3 sin(2πx) cos(3t) over the particle, in closed form.
            let f = 0.3
                * (3.0 * t).cos()
                * (2.0 * std::f64::consts::PI * q(i)).sin()
                * (2.0 * std::f64::consts::PI * eps).sin()
                / std::f64::consts::PI;
            let force = mu * ((u(i + 1) - u(i)) / d(i + 1) - (u(i) - u(i - 1)) / d(i)) + g(i)
                - g(i + 1)
                + f;
            out[m + i - 1] = force / (2.0 * eps);
        }
        out
    };
    let h = t_end / steps as f64;
    // Compensated (Kahan) accumulation of the state: over 10^4+ steps the plain sums' rounding
    // (~1e-13) would hide the errors of high-order schemes.
    let mut carry = vec![0.0; state.len()];
    for k in 0..steps {
        let t = k as f64 * h;
        let k1 = rhs(t, &state);
        let s2: Vec<f64> = state
            .iter()
            .zip(&k1)
            .map(|(s, k)| s + 0.5 * h * k)
            .collect();
        let k2 = rhs(t + 0.5 * h, &s2);
        let s3: Vec<f64> = state
            .iter()
            .zip(&k2)
            .map(|(s, k)| s + 0.5 * h * k)
            .collect();
        let k3 = rhs(t + 0.5 * h, &s3);
        let s4: Vec<f64> = state.iter().zip(&k3).map(|(s, k)| s + h * k).collect();
        let k4 = rhs(t + h, &s4);
        for i in 0..state.len() {
            let increment = h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]) - carry[i];
            let sum = state[i] + increment;
            carry[i] = (sum - state[i]) - increment;
            state[i] = sum;
        }
    }
    let m = n - 1;
    let q = |i: usize| {
        if i == 0 {
            0.0
        } else if i == n {
            1.0
        } else {
            state[i - 1]
        }
    };
    let gaps = (1..=n).map(|i| q(i) - q(i - 1) - 2.0 * eps).collect();
    (gaps, state[m..].to_vec())
}

/// Independent reference for near-contact dynamics, valid at any gap size: the fully implicit
/// Euler step in log-gap variables (the lubrication force mu·d(ln d)/dt integrated exactly, the
/// repulsion at the new gaps; DESIGN.md §2's convex step), solved for the log-gap increments
/// δ_i = ln d_i' − ln d_i by Newton with a dense LU, with Richardson extrapolation (order 2).
/// A gap below the float range (d = e^s = 0) is no obstacle: δ comes out of the momentum balance.
/// Reference for the solver's log-gap update (tests/extremes.rs). Returns (ln d, u) at t_end.
#[allow(clippy::too_many_arguments)]
pub fn log_gap_reference(
    eps: f64,
    mu: f64,
    gamma: f64,
    log_gaps: &[f64],
    velocities: &[f64],
    dstar: &[f64],
    t_end: f64,
    steps: usize,
) -> (Vec<f64>, Vec<f64>) {
    let n = log_gaps.len();
    let step = |s: &[f64], u: &[f64], h: f64| -> (Vec<f64>, Vec<f64>) {
        let d: Vec<f64> = s.iter().map(|x| x.exp()).collect();
        let mut delta = vec![0.0; n];
        let u_new = |delta: &[f64]| -> (Vec<f64>, Vec<f64>) {
            // sigma_j = mu δ_j − h G_j(d_j e^{δ_j}) and its derivative.
            let mut sigma = vec![0.0; n];
            let mut dsigma = vec![0.0; n];
            for j in 0..n {
                let dj = d[j] * delta[j].exp();
                let g = ((dstar[j] + 2.0 * eps) / (dj + 2.0 * eps)).powf(gamma);
                sigma[j] = mu * delta[j] - h * g;
                dsigma[j] = mu + h * gamma * g * dj / (dj + 2.0 * eps);
            }
            let mut un = vec![0.0; n + 1];
            for k in 1..n {
                un[k] = u[k - 1] + (sigma[k] - sigma[k - 1]) / (2.0 * eps);
            }
            (un, dsigma)
        };
        for _ in 0..60 {
            let (un, dsigma) = u_new(&delta);
            let mut r = DVector::<f64>::zeros(n);
            let mut jac = DMatrix::<f64>::zeros(n, n);
            for i in 0..n {
                r[i] = d[i] * delta[i].exp_m1() - h * (un[i + 1] - un[i]);
                jac[(i, i)] += d[i] * delta[i].exp();
                // ∂u'_k/∂δ_j = (σ'_j [j = k+1] − σ'_j [j = k])/(2eps), particles k = 1..N−1.
                for (k, sign) in [(i + 1, -h), (i, h)] {
                    if k == 0 || k == n {
                        continue;
                    }
                    jac[(i, k)] += sign * dsigma[k] / (2.0 * eps);
                    jac[(i, k - 1)] -= sign * dsigma[k - 1] / (2.0 * eps);
                }
            }
            let step = jac.lu().solve(&(-r)).expect("Newton matrix is regular");
            let size = step.amax();
            let damp = if size > 1.0 { 1.0 / size } else { 1.0 };
            for i in 0..n {
                delta[i] += damp * step[i];
            }
            if size < 1e-13 {
                break;
            }
        }
        let (un, _) = u_new(&delta);
        let s_new = s.iter().zip(&delta).map(|(a, b)| a + b).collect();
        (s_new, un[1..n].to_vec())
    };
    let h = t_end / steps as f64;
    let mut s = log_gaps.to_vec();
    let mut u = velocities.to_vec();
    for _ in 0..steps {
        let (s_full, u_full) = step(&s, &u, h);
        let (s_half, u_half) = step(&s, &u, 0.5 * h);
        let (s_two, u_two) = step(&s_half, &u_half, 0.5 * h);
        s = s_two
            .iter()
            .zip(&s_full)
            .map(|(a, b)| 2.0 * a - b)
            .collect();
        u = u_two
            .iter()
            .zip(&u_full)
            .map(|(a, b)| 2.0 * a - b)
            .collect();
    }
    (s, u)
}
