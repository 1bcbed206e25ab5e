//! What a researcher looks at: macroscopic fields on a grid (rho and rho* piecewise constant on
//! [q_{i-1}, q_i), u piecewise linear between particles), the discrete energy, the dissipation
//! rate, the smallest gap and the largest density.

use crate::model::chain::stored_gap;
use crate::model::params::MemberParams;
use crate::model::plan::{Plan, Power};

/// One member at one output time.
#[derive(Debug, Clone, PartialEq)]
pub struct Snapshot {
    pub gaps: Vec<f64>,
    pub velocities: Vec<f64>,
    pub rho: Vec<f64>,
    pub u: Vec<f64>,
    pub rho_star: Vec<f64>,
    pub energy: f64,
    pub dissipation: f64,
    pub min_gap: f64,
    /// ln of the smallest gap: defined also when that gap is below the float range.
    pub log_min_gap: f64,
    pub max_density: f64,
    /// [`peak_centre`] of `rho` where the plan asks for it (NaN otherwise): set by the solver
    /// for its snapshots of an output together ([`set_peak_centres`]).
    pub peak_centre: f64,
}

impl Snapshot {
    /// The row written for a member that has failed: every value NaN, so that nothing downstream
    /// can mistake it for data (the manifest says why and when it failed).
    pub fn failed(plan: &Plan) -> Snapshot {
        let n = plan.particles;
        let g = plan.grid;
        let f = &plan.fields;
        let nan = |len: usize, keep: bool| {
            if keep {
                vec![f64::NAN; len]
            } else {
                Vec::new()
            }
        };
        Snapshot {
            gaps: nan(n, f.gaps),
            velocities: nan(n - 1, f.velocities),
            rho: nan(g, f.rho),
            u: nan(g, f.u),
            rho_star: nan(g, f.rho_star),
            energy: f64::NAN,
            dissipation: f64::NAN,
            min_gap: f64::NAN,
            log_min_gap: f64::NAN,
            max_density: f64::NAN,
            peak_centre: f64::NAN,
        }
    }
}

/// Evenly spaced points 0..=1.
pub fn grid_points(grid: usize) -> Vec<f64> {
    (0..grid)
        .map(|j| {
            if j + 1 == grid {
                1.0
            } else {
                j as f64 / (grid - 1) as f64
            }
        })
        .collect()
}

/// Discrete energy E = eps Σ u_i² + Σ Φ_i(d_i) over free gaps, with Φ_i = (d_i + 2eps) G_i/(γ−1)
/// for γ > 1 and Φ_i = −(d*_i + 2eps) ln(d_i + 2eps) for γ = 1 (bonded gaps are constant and left
/// out).
pub fn energy(
    eps: f64,
    gamma: f64,
    gaps: &[f64],
    velocities: &[f64],
    dstar: Option<&[f64]>,
    bonded: Option<&[bool]>,
) -> f64 {
    let kinetic: f64 = eps * velocities.iter().map(|u| u * u).sum::<f64>();
    let Some(dstar) = dstar else { return kinetic };
    let power = Power::of(gamma);
    let mut potential = 0.0;
    for (i, (&d, &ds)) in gaps.iter().zip(dstar).enumerate() {
        if bonded.is_some_and(|b| b[i]) {
            continue;
        }
        potential += potential_of(eps, gamma, power, d, ds);
    }
    kinetic + potential
}

/// Φ_i(d) of a free gap with d* = `dstar` (see [`energy`]).
#[inline(always)]
fn potential_of(eps: f64, gamma: f64, power: Power, d: f64, dstar: f64) -> f64 {
    let s = d + 2.0 * eps;
    let s_star = dstar + 2.0 * eps;
    if gamma == 1.0 {
        -s_star * s.ln()
    } else {
        // Integer gamma by multiplications (as the step computes G): powf cost more than the
        // rest of an output together.
        s * power.apply(s_star / s) / (gamma - 1.0)
    }
}

/// Gaps a chunk of [`observe`]'s packed energy terms holds (on the stack).
const TERM_CHUNK: usize = 64;

/// [`potential_of`] of each gap `d[k]` with `dstar[k]`, into `terms` (as long as `d`): the same
/// operations, with gamma's power taken a squaring at a time over the whole chunk (the steps of
/// [`powi_by_squaring`](roughlub_kernels::power::powi_by_squaring), so the same bits) instead of
/// a gap at a time.
fn potential_terms(
    eps: f64,
    gamma: f64,
    power: Power,
    d: &[f64],
    dstar: &[f64],
    terms: &mut [f64],
) {
    let dstar = &dstar[..d.len()];
    let n = match power {
        Power::Integer(n) if gamma != 1.0 => n,
        // ln and powf: a call a gap either way.
        _ => {
            for ((t, &dk), &sk) in terms.iter_mut().zip(d).zip(dstar) {
                *t = potential_of(eps, gamma, power, dk, sk);
            }
            return;
        }
    };
    let mut base = [0.0f64; TERM_CHUNK];
    let base = &mut base[..d.len()];
    for ((b, &dk), &sk) in base.iter_mut().zip(d).zip(dstar) {
        *b = (sk + 2.0 * eps) / (dk + 2.0 * eps);
    }
    terms.fill(1.0);
    let mut e = n;
    while e > 0 {
        if e & 1 == 1 {
            for (t, &b) in terms.iter_mut().zip(base.iter()) {
                *t *= b;
            }
        }
        e >>= 1;
        if e > 0 {
            for b in base.iter_mut() {
                *b *= *b;
            }
        }
    }
    for (t, &dk) in terms.iter_mut().zip(d) {
        *t = (dk + 2.0 * eps) * *t / (gamma - 1.0);
    }
}

/// [`dissipation_term`] of the positive gaps `d` (gaps `start..start + d.len()` of `n`), into
/// `terms`: the interior gaps in a loop without the walls' branches, so that it packs.
fn dissipation_terms(velocities: &[f64], n: usize, start: usize, d: &[f64], terms: &mut [f64]) {
    let end = start + d.len();
    // Gaps 1..n - 1 have a velocity on both sides.
    let (lo, hi) = (start.max(1), end.min(n.saturating_sub(1)));
    if lo < hi {
        let right = &velocities[lo..hi];
        let left = &velocities[lo - 1..hi - 1];
        let k = lo - start..hi - start;
        for (((t, &dk), &r), &l) in terms[k.clone()].iter_mut().zip(&d[k]).zip(right).zip(left) {
            *t = (r - l).powi(2) / dk;
        }
    }
    for i in (start..end).filter(|&i| i < lo || i >= hi.max(lo)) {
        terms[i - start] = dissipation_term_of(velocities, n, i, d[i - start]);
    }
}

/// Dissipation rate mu Σ (u_i − u_{i−1})² / d_i over free gaps. A gap below the float range
/// (d = 0) contributes mu d r² = 0: its two particles move as one to rounding.
pub fn dissipation(mu: f64, gaps: &[f64], velocities: &[f64], bonded: Option<&[bool]>) -> f64 {
    let n = gaps.len();
    let mut s = 0.0;
    for i in 0..n {
        if bonded.is_some_and(|b| b[i]) {
            continue;
        }
        s += dissipation_term(gaps, velocities, i, gaps[i]);
    }
    mu * s
}

/// (u_i − u_{i−1})² / d_i of gap i (0-based) with gap d (0 for d = 0; the walls are at rest).
#[inline(always)]
fn dissipation_term<G>(gaps: &[G], velocities: &[f64], i: usize, d: f64) -> f64 {
    dissipation_term_of(velocities, gaps.len(), i, d)
}

/// [`dissipation_term`] of gap i of n.
#[inline(always)]
fn dissipation_term_of(velocities: &[f64], n: usize, i: usize, d: f64) -> f64 {
    let right = if i < n - 1 { velocities[i] } else { 0.0 };
    let left = if i > 0 { velocities[i - 1] } else { 0.0 };
    if d > 0.0 {
        (right - left).powi(2) / d
    } else {
        0.0
    }
}

/// Centres (q_{i-1} + q_i)/2 of the cells whose widths q_i − q_{i-1} (i = 1..N) are given,
/// with q_0 = 0.
pub fn cell_centres(cell_widths: &[f64]) -> Vec<f64> {
    let mut q = 0.0;
    cell_widths
        .iter()
        .map(|&w| {
            let c = q + 0.5 * w;
            q += w;
            c
        })
        .collect()
}

/// Values at `nodes` (strictly increasing, at least 2) sampled at the ascending points `grid_x`
/// by cubic Lagrange interpolation through the 4 nearest nodes (the 2 on each side where there
/// are, the 4 at the end otherwise; fewer when there are fewer nodes). Points outside the nodes
/// get the end cubic's extrapolation.
///
/// The convergence study in N ([`crate::converge`]) samples rho and rho* (values of the cells at
/// their centres) and u (values at the particles) with it: the error of a smooth profile is
/// O(h⁴) in the spacing h. The run's own sampling (see [`observe`]: rho piecewise constant,
/// u piecewise linear) is O(h) and O(h²) with a factor that oscillates with a point's place in
/// its cell, which hides how the particle system itself converges and defeats pointwise
/// extrapolation.
pub fn cubic_interpolated(nodes: &[f64], values: &[f64], grid_x: &[f64]) -> Vec<f64> {
    let n = nodes.len();
    let m = n.min(4);
    debug_assert!(n >= 2 && values.len() == n);
    let mut next = 0; // first node > x
    grid_x
        .iter()
        .map(|&x| {
            while next < n && nodes[next] <= x {
                next += 1;
            }
            let first = next.saturating_sub(2).min(n - m);
            let window = first..first + m;
            let mut sum = 0.0;
            for a in window.clone() {
                let mut l = 1.0;
                for b in window.clone() {
                    if a != b {
                        l *= (x - nodes[b]) / (nodes[a] - nodes[b]);
                    }
                }
                sum += l * values[a];
            }
            sum
        })
        .collect()
}

/// Per cell of a chain: its width and the densities the grid points in it take.
#[derive(Default)]
struct CellValues {
    widths: Vec<f64>,
    rho: Vec<f64>,
    rho_star: Vec<f64>,
}

thread_local! {
    static CELL_VALUES: std::cell::Cell<CellValues> = std::cell::Cell::new(CellValues::default());
}

#[allow(clippy::too_many_arguments)]
/// The snapshot of one member from its state as the solvers store it (`stored_gaps` in the
/// `stored_gap` form). One pass over the chain gives the minima, the energy and the dissipation
/// (the same sums, in the same order, as [`energy`] and [`dissipation`]); only the fields the
/// plan asks for are allocated.
pub fn observe(
    plan: &Plan,
    params: &MemberParams,
    stored_gaps: &[f64],
    velocities: &[f64],
    dstar: Option<&[f64]>,
    bonded: Option<&[bool]>,
    grid_x: &[f64],
) -> Snapshot {
    let eps = plan.eps;
    let n = stored_gaps.len();
    let f = &plan.fields;
    let power = Power::of(params.gamma);
    // min_i ln d_i with one ln: ln is monotone, and a gap stored as ln d (< 0) lies below the
    // floor that every gap stored as d is above.
    let mut min_stored_d = f64::INFINITY;
    let mut min_stored_ln = f64::INFINITY;
    let mut min_gap = f64::INFINITY;
    let mut any_bonded = false;
    let mut kinetic = 0.0;
    let mut potential = 0.0;
    let mut dissipation = 0.0;
    if bonded.is_none() && stored_gaps.iter().all(|&v| v > 0.0) {
        // Every gap free and stored as d (nearly always): the same terms, computed a chunk at a
        // time in loops the compiler packs, then summed in the chain's order, so the same bits
        // as the loop below, whose divisions one after another took a quarter of `observe`'s
        // time in a 4096-member batch (12.9 % of its samples before, 9.6 % after). Without
        // `energy_sums` (the companion's snapshots, only compared) the minima alone.
        min_stored_d = stored_gaps.iter().fold(f64::INFINITY, |m, &v| m.min(v));
        min_gap = min_stored_d;
        if plan.energy_sums {
            kinetic = velocities[..n.saturating_sub(1)]
                .iter()
                .fold(0.0, |k, &u| k + u * u);
            let mut terms = [0.0f64; TERM_CHUNK];
            for start in (0..n).step_by(TERM_CHUNK) {
                let d = &stored_gaps[start..(start + TERM_CHUNK).min(n)];
                let terms = &mut terms[..d.len()];
                if let Some(ds) = dstar {
                    potential_terms(eps, params.gamma, power, d, &ds[start..], terms);
                    potential = terms.iter().fold(potential, |p, &t| p + t);
                }
                dissipation_terms(velocities, n, start, d, terms);
                dissipation = terms.iter().fold(dissipation, |q, &t| q + t);
            }
        }
    } else {
        for (i, &v) in stored_gaps.iter().enumerate() {
            if i + 1 < n {
                kinetic += velocities[i] * velocities[i];
            }
            if bonded.is_some_and(|b| b[i]) {
                any_bonded = true;
                continue;
            }
            let d = stored_gap::decode(v);
            if v > 0.0 {
                min_stored_d = min_stored_d.min(v);
            } else {
                min_stored_ln = min_stored_ln.min(stored_gap::ln(v));
            }
            min_gap = min_gap.min(d);
            if let Some(ds) = dstar {
                potential += potential_of(eps, params.gamma, power, d, ds[i]);
            }
            dissipation += dissipation_term(stored_gaps, velocities, i, d);
        }
    }
    let log_min_gap = min_stored_ln.min(stored_gap::ln(min_stored_d));
    // 2eps/(d + 2eps) falls with d, and so does its rounded value: the largest density is the
    // smallest gap's, bit for bit (a bonded gap has density 1).
    let max_density = (2.0 * eps / (min_gap + 2.0 * eps)).max(if any_bonded { 1.0 } else { 0.0 });
    let energy = if !plan.energy_sums {
        // Neither path's sums stand for anything without them (the gap-by-gap one adds them
        // anyway).
        dissipation = f64::NAN;
        f64::NAN
    } else if dstar.is_some() {
        eps * kinetic + potential
    } else {
        eps * kinetic
    };
    let gap = |i: usize| stored_gap::decode(stored_gaps[i]);

    let g = grid_x.len();
    // Filled in place, cell by cell (a Vec grown a cell at a time cost a call per field and
    // cell, more than the values themselves).
    let mut rho = vec![0.0; if f.rho { g } else { 0 }];
    let mut u = vec![0.0; if f.u { g } else { 0 }];
    let mut rho_star = vec![0.0; if f.rho_star && dstar.is_some() { g } else { 0 }];
    if f.rho || f.u || f.rho_star {
        // Cell by cell, the grid points each holds (a grid is typically several points per cell):
        // a cell's values are computed once, and its points are filled as a slice (rho and rho*
        // constant, u linear). Cell i (1-based) covers [q_{i-1}, q_i); points at or beyond the
        // last q_N belong to the last cell.
        // The cells' widths and values first, in loops the compiler packs: a division each,
        // which inside the walk stalled it.
        let two_eps = 2.0 * eps;
        // In this thread's buffers: three allocations a member and output time, freed at once.
        let mut cells = CELL_VALUES.take();
        let CellValues {
            widths,
            rho: cell_rho,
            rho_star: cell_rho_star,
        } = &mut cells;
        widths.clear();
        widths.extend((0..n).map(|i| gap(i) + two_eps));
        cell_rho.clear();
        if f.rho {
            cell_rho.extend(widths.iter().map(|&w| two_eps / w));
        }
        cell_rho_star.clear();
        if let (false, Some(ds)) = (rho_star.is_empty(), dstar) {
            cell_rho_star.extend(ds.iter().map(|&s| two_eps / (s + two_eps)));
        }
        let (mut j, mut i, mut q_left) = (0, 1, 0.0);
        while j < g {
            let q_right = q_left + widths[i - 1];
            // A NaN width (never in a member that has not failed) keeps the rest in this cell.
            // A linear scan, not a binary search: a cell holds a few points.
            let mut end = j;
            if i == n || q_right.is_nan() {
                end = g;
            } else {
                while end < g && grid_x[end] < q_right {
                    end += 1;
                }
            }
            if end > j {
                if let Some(&value) = cell_rho.get(i - 1) {
                    rho[j..end].fill(value);
                }
                if let Some(&value) = cell_rho_star.get(i - 1) {
                    rho_star[j..end].fill(value);
                }
                if f.u {
                    let u_left = if i >= 2 { velocities[i - 2] } else { 0.0 };
                    let u_right = if i < n { velocities[i - 1] } else { 0.0 };
                    let width = q_right - q_left;
                    for (u, &x) in u[j..end].iter_mut().zip(&grid_x[j..end]) {
                        let s = ((x - q_left) / width).clamp(0.0, 1.0);
                        *u = u_left + (u_right - u_left) * s;
                    }
                }
                j = end;
            }
            q_left = q_right;
            i += 1;
        }
        CELL_VALUES.set(cells);
    }
    Snapshot {
        gaps: if f.gaps {
            (0..n).map(gap).collect()
        } else {
            Vec::new()
        },
        velocities: if f.velocities {
            velocities.to_vec()
        } else {
            Vec::new()
        },
        rho,
        u,
        rho_star,
        energy,
        dissipation: params.mu * dissipation,
        min_gap,
        log_min_gap,
        max_density,
        peak_centre: f64::NAN,
    }
}

/// Centre of mass of the density peak: the centroid of the excess of rho over its spatial mean
/// (NaN when the profile is flat, or `rho` is empty).
pub fn peak_centre(x: &[f64], rho: &[f64]) -> f64 {
    if rho.is_empty() {
        return f64::NAN;
    }
    let mean = rho.iter().sum::<f64>() / rho.len() as f64;
    let (mut wx, mut w) = (0.0, 0.0);
    for (xi, r) in x.iter().zip(rho) {
        let e = (r - mean).max(0.0);
        wx += xi * e;
        w += e;
    }
    if w > 1e-12 {
        wx / w
    } else {
        f64::NAN
    }
}

/// Sets each snapshot's [`peak_centre`](Snapshot::peak_centre), four snapshots side by side
/// (the same bits as one at a time): the solver calls it on the snapshots of an output it has
/// just observed, their rho rows still in cache. One row's sums are chains of dependent adds;
/// four of them interleave, so the adds do not wait on each other (one at a time, as a
/// statistic reading the rows again, it took 24-29 ms of the 4096-member ensemble's thread
/// time).
pub fn set_peak_centres<'a>(x: &[f64], snapshots: impl Iterator<Item = &'a mut Snapshot>) {
    let mut snapshots: Vec<&mut Snapshot> = snapshots.collect();
    let full = |s: &Snapshot| s.rho.len() == x.len() && !s.rho.is_empty();
    for some in snapshots.chunks_mut(4) {
        if let [a, b, c, d] = some {
            if [&**a, &**b, &**c, &**d].into_iter().all(full) {
                let centres = peak_centre_of_four(x, [&a.rho, &b.rho, &c.rho, &d.rho]);
                for (s, centre) in some.iter_mut().zip(centres) {
                    s.peak_centre = centre;
                }
                continue;
            }
        }
        for s in some.iter_mut() {
            s.peak_centre = peak_centre(x, &s.rho);
        }
    }
}

/// [`peak_centre`] of four rows of `x`'s length, at least one point.
fn peak_centre_of_four(x: &[f64], rows: [&[f64]; 4]) -> [f64; 4] {
    let g = x.len();
    // `Iterator::sum` of f64 starts from -0.0.
    let mut sum = [-0.0f64; 4];
    for j in 0..g {
        for (s, r) in sum.iter_mut().zip(rows) {
            *s += r[j];
        }
    }
    let mean = sum.map(|s| s / g as f64);
    let (mut wx, mut w) = ([0.0f64; 4], [0.0f64; 4]);
    for (j, &xj) in x.iter().enumerate() {
        for l in 0..4 {
            let e = (rows[l][j] - mean[l]).max(0.0);
            wx[l] += xj * e;
            w[l] += e;
        }
    }
    std::array::from_fn(|l| if w[l] > 1e-12 { wx[l] / w[l] } else { f64::NAN })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_rng::uniform_stream;

    fn snapshot_of(rho: Vec<f64>) -> Snapshot {
        Snapshot {
            gaps: Vec::new(),
            velocities: Vec::new(),
            rho,
            u: Vec::new(),
            rho_star: Vec::new(),
            energy: 0.0,
            dissipation: 0.0,
            min_gap: 0.0,
            log_min_gap: 0.0,
            max_density: 0.0,
            peak_centre: f64::NAN,
        }
    }

    /// Four rows side by side give each row's own centre, bit for bit, whatever their mix of
    /// flat, peaked, empty and NaN rows.
    #[test]
    fn peak_centres_side_by_side_are_each_rows_own() {
        let g = 37;
        let x: Vec<f64> = (0..g).map(|j| j as f64 / (g - 1) as f64).collect();
        let mut next = uniform_stream(0x9e3779b97f4a7c15);
        let mut rows: Vec<Vec<f64>> = (0..13)
            .map(|_| (0..g).map(|_| 0.5 + next()).collect())
            .collect();
        rows[3] = vec![0.7; g];
        rows[5] = Vec::new();
        rows[8][4] = f64::NAN;
        let mut snapshots: Vec<Snapshot> = rows.iter().cloned().map(snapshot_of).collect();
        set_peak_centres(&x, snapshots.iter_mut());
        for (r, s) in rows.iter().zip(&snapshots) {
            assert_eq!(s.peak_centre.to_bits(), peak_centre(&x, r).to_bits());
        }
        // Not a NaN everywhere: the peaked rows have centres inside [0, 1].
        assert!(snapshots[0].peak_centre > 0.0 && snapshots[0].peak_centre < 1.0);
        assert!(snapshots[3].peak_centre.is_nan() && snapshots[5].peak_centre.is_nan());
        // The centroid of a single bump is where it is.
        let mut bump = vec![0.5; g];
        bump[9] = 0.9;
        let mut one = [snapshot_of(bump)];
        set_peak_centres(&x, one.iter_mut());
        assert!((one[0].peak_centre - x[9]).abs() < 1e-15);
    }
}
