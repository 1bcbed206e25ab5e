//! The Aitken–Neville combination of a block's tableau rows with its error estimates
//! (`extrapolate`, twin of the same function in `shaders/step.wgsl`), lane by lane inside each
//! gap or velocity so that the lanes' arithmetic is packed. Each lane runs the operations the
//! WGSL twin runs for one member, in the same order: the results do not depend on the lanes
//! around it, on L or on the instruction set.

use crate::real::Real;
use crate::shared::control::{row_substeps, MAX_ORDER};
use crate::shared::gaps::{log_stored_allowance, GAP_EXP_TAYLOR, LN_RATIO_SERIES};
use crate::simd::SimdLevel;
use crate::step::{encode_ln_gap, gap_exp, gap_exp_taylor, ln_1p_series, ln_gap_ratio, stored_ln};

const M: usize = MAX_ORDER as usize;

/// Per column j = 2..=k, the max-norm of T_jj - T_{j,j-1} (index by column).
pub type Estimates = [f64; M + 1];

/// The tableau's weights 1/(n_j/n_{j-c} - 1) = n_{j-c}/c (0-based row j, n from
/// [`row_substeps`]), as constants: divided at run time they were a third of an order-8
/// step's cost. The same quotients, so the same bits as the WGSL twin's. Index
/// [from_two][c][j] ([`TableauIo::sequence_from_two`]).
const NEVILLE_WEIGHTS: [[[f64; M]; M]; 2] = [neville_weights(false), neville_weights(true)];

const fn neville_weights(from_two: bool) -> [[f64; M]; M] {
    let mut w = [[0.0; M]; M];
    let mut c = 1;
    while c < M {
        let mut j = c;
        while j < M {
            w[c][j] = row_substeps((j - c + 1) as u32, from_two) as f64 / c as f64;
            j += 1;
        }
        c += 1;
    }
    w
}

/// What the tableau reads and writes: each lane's column k (its rows 1..=k), whether the result
/// is the extrapolated T_kk (else row k itself: order 1), whether the rows took 2, 3, …
/// substeps instead of 1, 2, … (`sequence_from_two` of the step control), the rows, the
/// candidate state it writes, and which gaps are bonded (a cluster's: they keep their last row).
pub struct TableauIo<'a, T, const L: usize> {
    pub columns: &'a [usize; L],
    pub extrapolating: bool,
    pub sequence_from_two: bool,
    pub row_gaps: &'a [Vec<T>],
    pub row_vel: &'a [Vec<T>],
    pub cand_gaps: &'a mut [T],
    pub cand_vel: &'a mut [T],
    pub bonded: Option<&'a [bool]>,
}

/// The Aitken–Neville tableau of the rows (n_j substeps, [`row_substeps`]), element by element:
/// T_{j,c+1} = T_{j,c} + (T_{j,c} - T_{j-1,c}) · n_{j-c}/c. cand ← T_kk of each lane's column k
/// (or row k itself when not `extrapolating`: order 1). Gaps are extrapolated in ln d (near
/// contact the accuracy that matters is that of ln d, and the result is a positive gap by
/// construction), velocities linearly. Returns per lane, for j = 2..=k, the max-norm of
/// T_jj - T_{j,j-1}: on gaps of ln d (a relative error), on velocities over 1 + |u| of row k;
/// a NaN counts as infinite. Computed in T, the estimates returned in f64.
///
/// Lanes with fewer rows than the block's most see their last row repeated: a ratio of 1, so
/// the rows they lack add nothing, and T_kk (which reads rows 1..=k only) is theirs alone.
pub fn extrapolate<T: Real, const L: usize>(
    simd: SimdLevel,
    io: TableauIo<T, L>,
) -> [Estimates; L] {
    // SAFETY (both arms): a level is only chosen where the CPU has its features
    // (`SimdLevel::widest_here`).
    #[cfg(target_arch = "x86_64")]
    match simd {
        SimdLevel::Avx512 => return unsafe { extrapolate_avx512::extrapolate_avx512(io) },
        SimdLevel::Avx2Fma => return unsafe { extrapolate_avx2::extrapolate_avx2(io) },
        SimdLevel::Portable => {}
    }
    let _ = simd;
    extrapolate_impl(io)
}

macro_rules! instance {
    ($features:literal, $name:ident) => {
        // In a module of its own: see `simd_versions!` in step.rs.
        #[cfg(target_arch = "x86_64")]
        mod $name {
            use super::*;

            #[target_feature(enable = $features)]
            pub(super) unsafe fn $name<T: Real, const L: usize>(
                io: TableauIo<T, L>,
            ) -> [Estimates; L] {
                extrapolate_impl(io)
            }
        }
    };
}

instance!("avx2,fma", extrapolate_avx2);
instance!("avx2,fma,avx512f,avx512vl,avx512dq", extrapolate_avx512);

#[inline(always)]
fn extrapolate_impl<T: Real, const L: usize>(io: TableauIo<T, L>) -> [Estimates; L] {
    let TableauIo {
        columns,
        extrapolating,
        sequence_from_two: from_two,
        row_gaps,
        row_vel,
        cand_gaps,
        cand_vel,
        bonded,
    } = io;
    let zero = T::ZERO;
    let rows = columns.iter().copied().max().unwrap_or(1);
    // Per column and lane the largest estimate so far, NaN once any was (it stays: no
    // comparison with a NaN is true).
    let mut est = [[zero; L]; M + 1];

    for (g, out) in cand_gaps.chunks_exact_mut(L).enumerate() {
        let base = g * L;
        let (last, y) = lane_rows(row_gaps, base, columns, rows);
        let bonded: Option<&[bool]> = bonded.map(|b| &b[base..base + L]);
        let is_bonded = |l: usize| bonded.is_some_and(|b| b[l]);
        // rho_j = ln(Y_j / Y_k): the tableau in ln d, shifted by ln Y_k (the extrapolation's
        // weights sum to 1, so the shift passes through, and the rows' ratios are near 1).
        // The series of `ln_gap_ratio` for every lane at once; the rare lane outside its range,
        // or with a log-stored row, again on its own (not a bonded gap's lane: its row is kept
        // as it is). Flags as 0/1 in lanes as wide as T, as in the step (bools cost packing).
        let flag = T::Flag::from;
        let mut rho = [[zero; L]; M];
        let mut packed = [flag(true); L];
        let inv_last: [T; L] = std::array::from_fn(|l| T::ONE / last[l]);
        for j in 0..rows {
            for l in 0..L {
                let delta = (y[j][l] - last[l]) * inv_last[l];
                packed[l] &= flag(y[j][l] > zero && delta.abs() < T::c(LN_RATIO_SERIES));
                rho[j][l] = ln_1p_series(delta);
            }
        }
        let plain = |l: usize| y.iter().take(rows).all(|yj| yj[l] > zero);
        let mut log_stored = [false; L];
        for l in 0..L {
            if packed[l] == flag(true) || is_bonded(l) {
                continue;
            }
            let plain = plain(l);
            log_stored[l] = !plain;
            for j in 0..rows {
                rho[j][l] = if plain {
                    ln_gap_ratio(y[j][l], last[l], inv_last[l])
                } else {
                    stored_ln(y[j][l]) - stored_ln(last[l])
                };
            }
        }
        let mut e = [[zero; L]; M + 1];
        neville(&mut rho, rows, from_two, &mut e, |delta, _| delta.abs());
        for l in (0..L).filter(|&l| log_stored[l]) {
            let ln_last = stored_ln(last[l]);
            for ej in e.iter_mut().take(rows + 1).skip(2) {
                ej[l] = log_stored_allowance(ej[l], ln_last);
            }
        }
        let x: [T; L] = std::array::from_fn(|l| {
            if extrapolating {
                rho[columns[l] - 1][l]
            } else {
                zero
            }
        });
        // `gap_exp`'s Taylor branch for every lane; on its own the lane that needs its exp, or
        // has a log-stored row, or leaves the stored range.
        let mut grown = [zero; L];
        for l in 0..L {
            grown[l] = last[l] * gap_exp_taylor(x[l]);
            packed[l] &= flag(
                x[l].abs() < T::c(GAP_EXP_TAYLOR)
                    && grown[l] >= T::GAP_FLOOR
                    && grown[l] < T::INFINITY,
            );
        }
        out.copy_from_slice(&grown);
        for l in 0..L {
            if packed[l] == flag(true) {
                continue;
            }
            let g = if x[l].abs() >= T::c(GAP_EXP_TAYLOR) || x[l].is_nan() {
                last[l] * gap_exp(x[l])
            } else {
                grown[l]
            };
            out[l] = if plain(l) && g >= T::GAP_FLOOR && g < T::INFINITY {
                g
            } else {
                encode_ln_gap(stored_ln(last[l]) + x[l])
            };
        }
        if let Some(bonded) = bonded {
            for l in 0..L {
                if bonded[l] {
                    // A bonded gap keeps its row: nothing to extrapolate or estimate.
                    out[l] = last[l];
                    for ej in e.iter_mut() {
                        ej[l] = zero;
                    }
                }
            }
        }
        note_columns(&mut est, &e, rows);
    }

    for (g, out) in cand_vel.chunks_exact_mut(L).enumerate() {
        let (last, mut t) = lane_rows(row_vel, g * L, columns, rows);
        // Every column's estimate over the same 1 + |u| (row k's): one division per velocity.
        let inv_scale: [T; L] = std::array::from_fn(|l| T::ONE / (T::ONE + last[l].abs()));
        let mut e = [[zero; L]; M + 1];
        neville(&mut t, rows, from_two, &mut e, |delta, l| {
            delta.abs() * inv_scale[l]
        });
        for l in 0..L {
            out[l] = if extrapolating {
                t[columns[l] - 1][l]
            } else {
                last[l]
            };
        }
        note_columns(&mut est, &e, rows);
    }

    std::array::from_fn(|l| {
        let mut err = [0.0f64; M + 1];
        for (j, e) in err.iter_mut().enumerate().take(columns[l] + 1) {
            *e = if est[j][l].is_nan() {
                f64::INFINITY
            } else {
                est[j][l].to_f64()
            };
        }
        err
    })
}

/// Element `base / L` of each lane's rows: its last row (row k), and rows 1..=`rows` with the
/// rows beyond its own k repeating its last.
#[inline(always)]
fn lane_rows<T: Real, const L: usize>(
    rows_in: &[Vec<T>],
    base: usize,
    columns: &[usize; L],
    rows: usize,
) -> ([T; L], [[T; L]; M]) {
    let mut y = [[T::ZERO; L]; M];
    if columns.iter().all(|&k| k == rows) {
        // Every lane has all the rows (a per-lane choice costs a select per element).
        for (j, yj) in y.iter_mut().enumerate().take(rows) {
            *yj = *<&[T; L]>::try_from(&rows_in[j][base..base + L]).unwrap();
        }
        return (y[rows - 1], y);
    }
    let last: [T; L] = std::array::from_fn(|l| rows_in[columns[l] - 1][base + l]);
    for (j, yj) in y.iter_mut().enumerate().take(rows) {
        let row = &rows_in[j][base..base + L];
        for l in 0..L {
            yj[l] = if j < columns[l] { row[l] } else { last[l] };
        }
    }
    (last, y)
}

/// The estimates of columns 2..=rows into their running maxima, every lane (columns beyond a
/// lane's own k are dropped at the end: a per-lane mask here was a fifth of the tableau's
/// time); a NaN sticks (counts as infinite).
#[inline(always)]
fn note_columns<T: Real, const L: usize>(
    est: &mut [[T; L]; M + 1],
    e: &[[T; L]; M + 1],
    rows: usize,
) {
    for j in 2..=rows {
        for l in 0..L {
            let v = e[j][l];
            est[j][l] = if v > est[j][l] || v.is_nan() {
                v
            } else {
                est[j][l]
            };
        }
    }
}

/// The tableau in place, every lane at once (t[j] ends as T_{j+1,j+1}), with
/// e[c + 1] = `scale(T_{c+1,c+1} - T_{c+1,c}, lane)`.
#[inline(always)]
fn neville<T: Real, const L: usize>(
    t: &mut [[T; L]; M],
    rows: usize,
    from_two: bool,
    e: &mut [[T; L]; M + 1],
    scale: impl Fn(T, usize) -> T,
) {
    let weights = &NEVILLE_WEIGHTS[usize::from(from_two)];
    for c in 1..rows {
        // Rows above c, then row c with its estimate, as one loop over j = rows-1..=c would
        // (the test `j == c` inside the lane loop had the vectoriser assemble rows from
        // shifted scalar loads).
        for j in (c + 1..rows).rev() {
            let w = T::c(weights[c][j]);
            let (below, row) = t.split_at_mut(j);
            for (x, &y) in row[0].iter_mut().zip(&below[j - 1]) {
                *x += (*x - y) * w;
            }
        }
        let w = T::c(weights[c][c]);
        for l in 0..L {
            let delta = (t[c][l] - t[c - 1][l]) * w;
            e[c + 1][l] = scale(delta, l);
            t[c][l] += delta;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shared::gaps::LOG_STORED_ROUNDING;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// One member's tableau, element by element, as the WGSL twin computes it (and as this
    /// crate did before the lanes were packed): the independent expectation.
    fn one_member<T: Real>(
        k: usize,
        extrapolating: bool,
        from_two: bool,
        gap_rows: &[Vec<T>],
        vel_rows: &[Vec<T>],
        bonded: &[bool],
    ) -> (Vec<T>, Vec<T>, Estimates) {
        let mut err = [0.0f64; M + 1];
        let mut note = |j: usize, e: T| {
            let e = e.to_f64();
            err[j] = if e.is_nan() {
                f64::INFINITY
            } else {
                err[j].max(e)
            };
        };
        // `velocity_scale`: the velocities' 1 + |u| of row k (None for gaps).
        let tableau = |t: &mut [T; M], e: &mut [T; M + 1], velocity_scale: Option<T>| {
            for c in 1..k {
                for j in (c..k).rev() {
                    let n = if from_two { j + 2 - c } else { j + 1 - c };
                    let delta = (t[j] - t[j - 1]) * T::c(n as f64 / c as f64);
                    if j == c {
                        e[c + 1] = match velocity_scale {
                            Some(scale) => delta.abs() * (T::ONE / scale),
                            None => delta.abs(),
                        };
                    }
                    t[j] += delta;
                }
            }
        };
        let mut gaps = Vec::new();
        for i in 0..gap_rows[0].len() {
            let y: Vec<T> = (0..k).map(|j| gap_rows[j][i]).collect();
            let last = y[k - 1];
            if bonded[i] {
                gaps.push(last);
                continue;
            }
            let plain = y.iter().all(|&v| v > T::ZERO);
            let mut rho = [T::ZERO; M];
            for j in 0..k {
                rho[j] = if plain {
                    ln_gap_ratio(y[j], last, T::ONE / last)
                } else {
                    stored_ln(y[j]) - stored_ln(last)
                };
            }
            let mut e = [T::ZERO; M + 1];
            tableau(&mut rho, &mut e, None);
            if !plain {
                for ej in e.iter_mut().take(k + 1).skip(2) {
                    *ej = log_stored_allowance(*ej, stored_ln(last));
                }
            }
            let x = if extrapolating { rho[k - 1] } else { T::ZERO };
            let grown = last * gap_exp(x);
            gaps.push(if plain && grown >= T::GAP_FLOOR && grown < T::INFINITY {
                grown
            } else {
                encode_ln_gap(stored_ln(last) + x)
            });
            for j in 2..=k {
                note(j, e[j]);
            }
        }
        let mut vel = Vec::new();
        for i in 0..vel_rows[0].len() {
            let mut t = [T::ZERO; M];
            for j in 0..k {
                t[j] = vel_rows[j][i];
            }
            let last = t[k - 1];
            let mut e = [T::ZERO; M + 1];
            tableau(&mut t, &mut e, Some(T::ONE + last.abs()));
            vel.push(if extrapolating { t[k - 1] } else { last });
            for j in 2..=k {
                note(j, e[j]);
            }
        }
        (gaps, vel, err)
    }

    /// Eight lanes with columns 1..=8 (each its own k), rows near each other as in an accepted
    /// step, and the elements that leave the packed path: a ratio outside the series' range, a
    /// log-stored gap (negative: ln d), a bonded gap, a NaN row of one lane. Every SIMD level
    /// gives, lane by lane and bit for bit, the one-member tableau of that lane's rows.
    fn lanes_equal_one_member<T: Real>(level: SimdLevel) {
        const L: usize = 8;
        let (n, nv) = (37, 36);
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let columns: [usize; L] = [3, 8, 1, 5, 2, 7, 6, 4];
        let mut gap_rows = vec![vec![T::ZERO; n * L]; M];
        let mut vel_rows = vec![vec![T::ZERO; nv * L]; M];
        for i in 0..n * L {
            let d: f64 = rng.random_range(1e-4..1e-2);
            for row in gap_rows.iter_mut() {
                row[i] = T::c(d * (1.0 + rng.random_range(-1e-3..1e-3)));
            }
        }
        for i in 0..nv * L {
            let u: f64 = rng.random_range(-1.0..1.0);
            for row in vel_rows.iter_mut() {
                row[i] = T::c(u + rng.random_range(-1e-3..1e-3));
            }
        }
        gap_rows[0][3 * L + 1] = gap_rows[7][3 * L + 1] * T::c(1.5); // outside the series
        gap_rows[2][5 * L + 6] = T::c(-30.0); // log-stored: d = e^-30
        vel_rows[1][7 * L + 4] = T::c(f64::NAN); // lane 4's column 2 sees a NaN
        let mut bonded = vec![false; n * L];
        bonded[9 * L + 5] = true;
        for (extrapolating, from_two) in [(true, false), (true, true), (false, false)] {
            let mut cand_gaps = vec![T::ZERO; n * L];
            let mut cand_vel = vec![T::ZERO; nv * L];
            let err = extrapolate(
                level,
                TableauIo {
                    columns: &columns,
                    extrapolating,
                    sequence_from_two: from_two,
                    row_gaps: &gap_rows,
                    row_vel: &vel_rows,
                    cand_gaps: &mut cand_gaps,
                    cand_vel: &mut cand_vel,
                    bonded: Some(&bonded),
                },
            );
            for l in 0..L {
                let lane = |rows: &[Vec<T>], count: usize| -> Vec<Vec<T>> {
                    rows.iter()
                        .map(|r| (0..count).map(|i| r[i * L + l]).collect())
                        .collect()
                };
                let lane_bonded: Vec<bool> = (0..n).map(|i| bonded[i * L + l]).collect();
                let (gaps, vel, expected) = one_member(
                    columns[l],
                    extrapolating,
                    from_two,
                    &lane(&gap_rows, n),
                    &lane(&vel_rows, nv),
                    &lane_bonded,
                );
                let bits = |v: &[T]| v.iter().map(|x| x.to_f64().to_bits()).collect::<Vec<_>>();
                let got_gaps: Vec<T> = (0..n).map(|i| cand_gaps[i * L + l]).collect();
                let got_vel: Vec<T> = (0..nv).map(|i| cand_vel[i * L + l]).collect();
                assert_eq!(bits(&got_gaps), bits(&gaps), "{level:?} lane {l} gaps");
                assert_eq!(bits(&got_vel), bits(&vel), "{level:?} lane {l} velocities");
                let cols = columns[l];
                assert_eq!(
                    err[l][2..=cols]
                        .iter()
                        .map(|e| e.to_bits())
                        .collect::<Vec<_>>(),
                    expected[2..=cols]
                        .iter()
                        .map(|e| e.to_bits())
                        .collect::<Vec<_>>(),
                    "{level:?} lane {l} estimates"
                );
            }
            // The NaN reached lane 4's estimates (as infinite), and no other lane's.
            assert_eq!(err[4][2], f64::INFINITY);
            assert!(err[0][2].is_finite() && err[1][2].is_finite());
        }
    }

    /// One gap's estimates (one lane, column = rows given), stored values as given.
    fn one_gap_estimates(stored_rows: &[f64]) -> Estimates {
        let k = stored_rows.len();
        let mut gap_rows = vec![vec![0.0f64; 1]; M];
        for (row, &v) in gap_rows.iter_mut().zip(stored_rows) {
            row[0] = v;
        }
        let vel_rows = vec![Vec::<f64>::new(); M];
        let (mut cand_gaps, mut cand_vel) = (vec![0.0; 1], Vec::new());
        extrapolate::<f64, 1>(
            SimdLevel::Portable,
            TableauIo {
                columns: &[k],
                extrapolating: true,
                sequence_from_two: false,
                row_gaps: &gap_rows,
                row_vel: &vel_rows,
                cand_gaps: &mut cand_gaps,
                cand_vel: &mut cand_vel,
                bonded: None,
            },
        )[0]
    }

    /// Rows ln d_j = L + c/j (an error of first order in the substep H/j): column 2 removes it,
    /// so e_2 = c/2 and the later columns see rounding only. A gap stored as ln d (L = -709,
    /// where one ulp is 1.1e-13) gets e_2 = c/2 less LOG_STORED_ROUNDING eps |L| (5.0e-12), and
    /// e_3, e_4 exactly 0; a gap stored as d (L = -7) keeps c/2 whole.
    #[test]
    fn log_stored_gaps_estimates_leave_out_their_rounding() {
        let c = 1e-9;
        let rows = |l: f64| -> Vec<f64> { (1..=4).map(|j| l + c / j as f64).collect() };
        let allowance = LOG_STORED_ROUNDING * f64::EPSILON * 709.0;
        let log_stored = one_gap_estimates(&rows(-709.0));
        assert!(
            (log_stored[2] - (c / 2.0 - allowance)).abs() <= 1e-12,
            "log-stored e_2 = {:e}, expected {:e}",
            log_stored[2],
            c / 2.0 - allowance
        );
        assert_eq!((log_stored[3], log_stored[4]), (0.0, 0.0));
        let plain: Vec<f64> = rows(-7.0).iter().map(|x| x.exp()).collect();
        let plain = one_gap_estimates(&plain);
        assert!(
            (plain[2] - c / 2.0).abs() <= 1e-15,
            "plain e_2 = {:e}, expected {:e}",
            plain[2],
            c / 2.0
        );
    }

    #[test]
    fn packed_lanes_equal_the_one_member_tableau_bitwise() {
        for level in [SimdLevel::Portable, SimdLevel::Avx2Fma, SimdLevel::Avx512] {
            if level <= SimdLevel::widest_here() {
                lanes_equal_one_member::<f64>(level);
                lanes_equal_one_member::<f32>(level);
            }
        }
    }
}
