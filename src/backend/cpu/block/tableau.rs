//! The extrapolation tableau of a block's trial step: where each substep reads and writes, and
//! the Aitken–Neville combination of the rows with its error estimates (`extrapolate`, twin of
//! the same function in `shaders/step.wgsl`).

use super::super::real::Real;
use super::super::step::{encode_ln_gap, gap_exp, ln_ratio, stored_ln};
use crate::model::params::MAX_ORDER;

/// The source and destination of substep s (0-based) of tableau row j: the current state for
/// the first, row j's slot for the last, the two substep buffers in turn between.
#[allow(clippy::type_complexity)]
pub(super) fn substep_buffers<'a, T>(
    current: (&'a [T], &'a [T]),
    subs: (&'a mut [Vec<T>; 2], &'a mut [Vec<T>; 2]),
    row: (&'a mut [T], &'a mut [T]),
    s: usize,
    j: usize,
) -> (&'a [T], &'a [T], &'a mut [T], &'a mut [T]) {
    let (sub_g, sub_v) = subs;
    let [g0, g1] = sub_g;
    let [v0, v1] = sub_v;
    // Substep s writes buffer s % 2 (or the row) and reads buffer (s - 1) % 2.
    let (read_g, write_g, read_v, write_v) = if s % 2 == 1 {
        (&*g0, g1, &*v0, v1)
    } else {
        (&*g1, g0, &*v1, v0)
    };
    let (src_g, src_v) = if s == 0 {
        current
    } else {
        (read_g.as_slice(), read_v.as_slice())
    };
    if s + 1 == j {
        (src_g, src_v, row.0, row.1)
    } else {
        (src_g, src_v, write_g.as_mut_slice(), write_v.as_mut_slice())
    }
}

/// Tableau rows a lane may use at most (index by column).
type Estimates = [f64; MAX_ORDER as usize + 1];

/// The Aitken–Neville tableau of the rows (harmonic sequence n_j = j), element by element:
/// T_{j,c+1} = T_{j,c} + (T_{j,c} - T_{j-1,c}) · (j - c)/c. cand ← T_kk of each lane's column k
/// (or row k itself when not `extrapolating`: order 1). Gaps are extrapolated in ln d (near
/// contact the accuracy that matters is that of ln d, and the result is a positive gap by
/// construction), velocities linearly. Returns per lane, for j = 2..=k, the max-norm of
/// T_jj - T_{j,j-1}: on gaps of ln d (a relative error), on velocities over 1 + |T_{j,j-1}|;
/// a NaN counts as infinite. Computed in T, the estimates returned in f64.
pub(super) fn extrapolate<T: Real, const L: usize>(
    columns: &[usize; L],
    extrapolating: bool,
    row_gaps: &[Vec<T>],
    row_vel: &[Vec<T>],
    cand_gaps: &mut [T],
    cand_vel: &mut [T],
    bonded: Option<&[bool]>,
) -> [Estimates; L] {
    const M: usize = MAX_ORDER as usize;
    let zero = T::ZERO;
    let mut err = [[0.0f64; M + 1]; L];
    let note = |err: &mut Estimates, j: usize, e: T| {
        let e = e.to_f64();
        err[j] = if e.is_nan() {
            f64::INFINITY
        } else {
            err[j].max(e)
        };
    };
    for (i, out) in cand_gaps.iter_mut().enumerate() {
        let l = i % L;
        let k = columns[l];
        let mut y = [zero; M];
        for j in 0..k {
            y[j] = row_gaps[j][i];
        }
        if bonded.is_some_and(|b| b[i]) {
            *out = y[k - 1];
            continue;
        }
        // rho_j = ln(Y_j / Y_k): the tableau in ln d, shifted by ln Y_k (the extrapolation's
        // weights sum to 1, so the shift passes through, and the rows' ratios are near 1).
        let last = y[k - 1];
        let plain = y[..k].iter().all(|&v| v > zero);
        let mut rho = [zero; M];
        for j in 0..k {
            rho[j] = if plain {
                ln_ratio(y[j] / last)
            } else {
                stored_ln(y[j]) - stored_ln(last)
            };
        }
        let mut e = [zero; M + 1];
        neville(&mut rho, k, &mut e);
        let x = if extrapolating { rho[k - 1] } else { zero };
        let grown = last * gap_exp(x);
        *out = if plain && grown >= T::GAP_FLOOR && grown < T::INFINITY {
            grown
        } else {
            encode_ln_gap(stored_ln(last) + x)
        };
        for (j, &ej) in e.iter().enumerate().take(k + 1).skip(2) {
            note(&mut err[l], j, ej);
        }
    }
    for (i, out) in cand_vel.iter_mut().enumerate() {
        let l = i % L;
        let k = columns[l];
        let mut t = [zero; M];
        for j in 0..k {
            t[j] = row_vel[j][i];
        }
        let last = t[k - 1];
        let mut e = [zero; M + 1];
        for c in 1..k {
            for j in (c..k).rev() {
                let delta = (t[j] - t[j - 1]) * T::c((j + 1 - c) as f64 / c as f64);
                if j == c {
                    e[c + 1] = delta.abs() / (T::ONE + t[j].abs());
                }
                t[j] += delta;
            }
        }
        *out = if extrapolating { t[k - 1] } else { last };
        for (j, &ej) in e.iter().enumerate().take(k + 1).skip(2) {
            note(&mut err[l], j, ej);
        }
    }
    err
}

/// The tableau in place (t[j] ends as T_{j+1,j+1}), with e[j] = |T_jj - T_{j,j-1}| (on ln d:
/// the relative error of d).
fn neville<T: Real>(
    t: &mut [T; MAX_ORDER as usize],
    k: usize,
    e: &mut [T; MAX_ORDER as usize + 1],
) {
    for c in 1..k {
        for j in (c..k).rev() {
            let delta = (t[j] - t[j - 1]) * T::c((j + 1 - c) as f64 / c as f64);
            if j == c {
                e[c + 1] = delta.abs();
            }
            t[j] += delta;
        }
    }
}
