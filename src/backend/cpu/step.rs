//! One linearly implicit Euler step for a block of L members, fused with the batched Thomas
//! solve. CPU twin of `shaders/step.wgsl`: the lane loop here is the invocation there, and the
//! loops over rows have the same shape. Keep the two in sync.
//!
//! Layout: element i of lane l at `i * L + l` (the GPU interleaves the whole batch the same way).
//! With c_i = mu/d_i + h·gamma·G_i/(d_i + 2 eps) (lubrication plus linearised repulsion),
//!   (2eps/h) u_i' - c_{i+1}(u_{i+1}' - u_i') + c_i(u_i' - u_{i-1}') = (2eps/h) u_i + G_i - G_{i+1} + F_i,
//! then d_i' = d_i + h (u_i' - u_{i-1}'). The matrix is SPD and strictly diagonally dominant, so
//! the forward sweep needs no pivoting. The sweep stores the rows in normalised form
//! u_i = y_i + w_i u_{i+1}, so the back sweep is one fma per row and also updates the gaps (the
//! update telescopes, so sum d_i is conserved to rounding).
//!
//! Precision at tiny gaps: the textbook pivot beta_i = D_i - c_i^2/beta_{i-1} cancels
//! catastrophically when a gap is tiny (c ~ mu/d huge). The sweep instead carries the pivot's
//! excess over its right coupling, e_i = beta_i - c_{i+1} = m/h + c_i e_{i-1}/beta_{i-1}: a sum of
//! positive terms (c_i in series with everything to its left). With lambda_i = e_i/beta_i and
//! w_i = c_{i+1}/beta_i, the relative velocity u_{i+1} - u_i = lambda_i u_{i+1} - y_i is a difference of
//! two small numbers when gap i+1 is small, so gaps keep their relative precision down to ~1e-300
//! instead of being swamped by the rounding of absolute velocities.
//!
//! Clusters (Appendix A): a gap that is zero at t = 0 is "bonded": its two particles move as
//! one. The forward sweep then adds the row into the next one (mass and forces add up) and
//! stores w = 1, y = 0 so that the back sweep copies the velocity exactly; a cluster attached to
//! the wall is "pinned" (w = y = 0). Bonded gaps have c = G = 0: their forces cancel inside the
//! cluster.

use crate::model::plan::{Forcing, Power};

/// A step may shrink a gap to no less than this fraction of its old value. The gap update is
/// explicit in d, so a step that shrinks a gap by more has left the regime where it is accurate
/// (and the next one would close it): it is rejected and retried with a smaller step, exactly as
/// a step that closes a gap.
pub const MIN_GAP_RATIO: f64 = 0.5;

/// Whether a free gap may go from `old` to `new` in one step (NaN fails every comparison).
#[inline(always)]
pub fn gap_step_admissible(old: f64, new: f64) -> bool {
    new > MIN_GAP_RATIO * old && new < f64::INFINITY
}

/// What the plan says exists, for one block. Absent terms cost nothing.
pub struct Terms<'a, const L: usize> {
    pub eps: f64,
    pub mu: [f64; L],
    /// d* (interleaved, length N·L) and how G is evaluated: present iff the model has repulsion.
    pub repulsion: Option<(&'a [f64], Gamma<L>)>,
    /// Bonded gaps (interleaved, length N·L): present iff some member has clusters.
    pub bonded: Option<&'a [bool]>,
    pub forcing: Option<&'a Forcing>,
}

/// gamma for a block: uniform across lanes (integer → multiplications), or per lane.
#[derive(Debug, Clone, Copy)]
pub enum Gamma<const L: usize> {
    Uniform(Power),
    PerLane([f64; L]),
}

impl<const L: usize> Gamma<L> {
    #[inline(always)]
    fn gamma(&self, l: usize) -> f64 {
        match self {
            Gamma::Uniform(Power::Integer(n)) => *n as f64,
            Gamma::Uniform(Power::Real(g)) => *g,
            Gamma::PerLane(g) => g[l],
        }
    }
    #[inline(always)]
    fn power(&self, l: usize, ratio: f64) -> f64 {
        match self {
            Gamma::Uniform(p) => p.apply(ratio),
            Gamma::PerLane(g) => Power::of(g[l]).apply(ratio),
        }
    }
}

/// Thomas sweep scratch, length (N-1)·L each: the normalised rows u_i = y_i + w_i u_{i+1} and
/// lambda_i = 1 - w_i kept separately, so that u_{i+1} - u_i = lambda_i u_{i+1} - y_i is computed
/// from small numbers when gap i+1 is tiny (see `euler_step`).
#[derive(Debug, Clone)]
pub struct Scratch {
    pub w: Vec<f64>,
    pub lambda: Vec<f64>,
    pub y: Vec<f64>,
}

impl Scratch {
    pub fn new(particles: usize, lanes: usize) -> Scratch {
        let len = (particles - 1) * lanes;
        Scratch {
            w: vec![0.0; len],
            lambda: vec![0.0; len],
            y: vec![0.0; len],
        }
    }
}

/// Coupling c and repulsion G of one gap for one lane.
#[inline(always)]
fn gap_terms<const L: usize>(
    terms: &Terms<L>,
    l: usize,
    index: usize,
    d: f64,
    h: f64,
) -> (f64, f64) {
    if let Some(bonded) = terms.bonded {
        if bonded[index] {
            return (0.0, 0.0);
        }
    }
    let mut c = terms.mu[l] / d;
    let mut g = 0.0;
    if let Some((dstar, gamma)) = &terms.repulsion {
        let inv_s = 1.0 / (d + 2.0 * terms.eps);
        let ratio = (dstar[index] + 2.0 * terms.eps) * inv_s;
        g = gamma.power(l, ratio);
        c += h * gamma.gamma(l) * g * inv_s;
    }
    (c, g)
}

/// F_i = ∫_{q_i - eps}^{q_i + eps} f(t, x) dx by Gauss–Legendre.
#[inline(always)]
fn particle_force(forcing: &Forcing, eps: f64, t: f64, q: f64) -> f64 {
    let mut s = 0.0;
    for (xi, w) in forcing.rule.nodes.iter().zip(&forcing.rule.weights) {
        s += w * forcing.expr.eval(q + eps * xi, t);
    }
    eps * s
}

/// Registers carried along the forward sweep (per lane).
struct SweepState<const L: usize> {
    lambda_prev: [f64; L],
    y_prev: [f64; L],
    c_prev: [f64; L],
    g_prev: [f64; L],
    q: [f64; L],
}

#[inline(always)]
fn forcing_or(f: &Forcing) -> Option<&Forcing> {
    Some(f)
}

/// Forward sweep without clusters. `coupling(l, gap_index, d, h)` gives (c, G) of one gap.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn forward_sweep_free<
    const L: usize,
    const FORCED: bool,
    C: Fn(usize, usize, f64, f64) -> (f64, f64),
>(
    n: usize,
    eps: f64,
    forcing: Option<&Forcing>,
    t: &[f64; L],
    h: &[f64; L],
    m_over_h: &[f64; L],
    gaps_in: &[f64],
    vel_in: &[f64],
    scratch: &mut Scratch,
    mut st: SweepState<L>,
    coupling: C,
) {
    let mass = 2.0 * eps;
    // The first gap with the same specialised arithmetic as the others.
    for l in 0..L {
        (st.c_prev[l], st.g_prev[l]) = coupling(l, l, gaps_in[l], h[l]);
    }
    for i in 1..n {
        let row = (i - 1) * L;
        let next_gap = i * L;
        for l in 0..L {
            let (c_next, g_next) = coupling(l, next_gap + l, gaps_in[next_gap + l], h[l]);
            let mut f = 0.0;
            if FORCED {
                if let Some(forcing) = forcing {
                    st.q[l] += gaps_in[row + l] + mass;
                    f = particle_force(forcing, eps, t[l], st.q[l]);
                }
            }
            let rhs = m_over_h[l] * vel_in[row + l] + st.g_prev[l] - g_next + f;
            let excess = m_over_h[l] + st.c_prev[l] * st.lambda_prev[l];
            let delta = rhs + st.c_prev[l] * st.y_prev[l];
            let inv = 1.0 / (excess + c_next);
            let lambda = excess * inv;
            let y = delta * inv;
            scratch.w[row + l] = c_next * inv;
            scratch.lambda[row + l] = lambda;
            scratch.y[row + l] = y;
            st.lambda_prev[l] = lambda;
            st.y_prev[l] = y;
            st.c_prev[l] = c_next;
            st.g_prev[l] = g_next;
        }
    }
}

/// Advances every lane by its own step h[l] from (gaps_in, vel_in) to (gaps_out, vel_out).
/// Returns, per lane, whether the result is admissible: every free gap finite and above
/// MIN_GAP_RATIO times its old value. Lanes
/// with `ok = false` must be rejected by the caller (their output is garbage).
#[allow(clippy::too_many_arguments)]
pub fn euler_step<const L: usize>(
    terms: &Terms<L>,
    particles: usize,
    t: &[f64; L],
    h: &[f64; L],
    gaps_in: &[f64],
    vel_in: &[f64],
    gaps_out: &mut [f64],
    vel_out: &mut [f64],
    scratch: &mut Scratch,
) -> [bool; L] {
    let n = particles;
    let eps = terms.eps;
    debug_assert_eq!(gaps_in.len(), n * L);
    debug_assert_eq!(vel_in.len(), (n - 1) * L);
    let mass = 2.0 * eps;
    let mut m_over_h = [0.0; L];
    for l in 0..L {
        m_over_h[l] = mass / h[l];
    }

    // Row 0 is the wall: u_0 = 0, so y_0 = 0.
    let mut c_prev = [0.0; L];
    let mut g_prev = [0.0; L];
    let mut y_prev = [0.0; L];
    let mut q = [0.0; L];
    for l in 0..L {
        (c_prev[l], g_prev[l]) = gap_terms(terms, l, l, gaps_in[l], h[l]);
    }

    // lambda_prev = e_{i-1}/beta_{i-1}: 1 at the wall (infinite pivot excess).
    let mut lambda_prev = [1.0; L];
    if let Some(bonded) = terms.bonded {
        // Cluster-aware sweep: a row merged into the next carries its excess and right-hand side.
        let mut excess_carry = [0.0; L];
        let mut delta_carry = [0.0; L];
        let mut pinned = [true; L];
        for i in 1..n {
            let row = (i - 1) * L;
            let next_gap = i * L;
            for l in 0..L {
                let (c_next, g_next) =
                    gap_terms(terms, l, next_gap + l, gaps_in[next_gap + l], h[l]);
                let mut f = 0.0;
                if let Some(forcing) = terms.forcing {
                    q[l] += gaps_in[row + l] + mass;
                    f = particle_force(forcing, eps, t[l], q[l]);
                }
                let rhs = m_over_h[l] * vel_in[row + l] + g_prev[l] - g_next + f;
                let (excess, delta);
                if bonded[row + l] {
                    // Gap i bonded (c_i = 0): row i-1 was merged into this row.
                    excess = m_over_h[l] + excess_carry[l];
                    delta = rhs + delta_carry[l];
                } else {
                    pinned[l] = false;
                    excess = m_over_h[l] + c_prev[l] * lambda_prev[l];
                    delta = rhs + c_prev[l] * y_prev[l];
                }
                let (w, lambda, y) = if bonded[next_gap + l] {
                    excess_carry[l] = excess;
                    delta_carry[l] = delta;
                    (1.0, 0.0, 0.0)
                } else if pinned[l] {
                    (0.0, 1.0, 0.0)
                } else {
                    let inv = 1.0 / (excess + c_next);
                    (c_next * inv, excess * inv, delta * inv)
                };
                scratch.w[row + l] = w;
                scratch.lambda[row + l] = lambda;
                scratch.y[row + l] = y;
                lambda_prev[l] = lambda;
                y_prev[l] = y;
                c_prev[l] = c_next;
                g_prev[l] = g_next;
            }
        }
    } else {
        // Without clusters: the hot path, specialised on the terms present so that the lane loop
        // has no per-element branches (and integer gamma is a fixed chain of multiplications).
        let state = SweepState {
            lambda_prev,
            y_prev,
            c_prev,
            g_prev,
            q,
        };
        let eps2 = 2.0 * eps;
        let mu = terms.mu;
        macro_rules! with_forcing {
            ($coupling:expr) => {
                if let Some(forcing) = terms.forcing {
                    forward_sweep_free::<L, true, _>(
                        n,
                        eps,
                        forcing_or(forcing),
                        t,
                        h,
                        &m_over_h,
                        gaps_in,
                        vel_in,
                        scratch,
                        state,
                        $coupling,
                    )
                } else {
                    forward_sweep_free::<L, false, _>(
                        n, eps, None, t, h, &m_over_h, gaps_in, vel_in, scratch, state, $coupling,
                    )
                }
            };
        }
        match &terms.repulsion {
            None => with_forcing!(|l: usize, _i: usize, d: f64, _h: f64| (mu[l] / d, 0.0)),
            Some((dstar, gamma)) => {
                macro_rules! repulsion {
                    ($pow:expr, $gamma_of:expr) => {
                        with_forcing!(|l: usize, i: usize, d: f64, h: f64| {
                            let inv_s = 1.0 / (d + eps2);
                            let g = $pow((dstar[i] + eps2) * inv_s, l);
                            (mu[l] / d + h * $gamma_of(l) * g * inv_s, g)
                        })
                    };
                }
                match *gamma {
                    Gamma::Uniform(Power::Integer(1)) => repulsion!(|r: f64, _l| r, |_l| 1.0),
                    Gamma::Uniform(Power::Integer(2)) => repulsion!(|r: f64, _l| r * r, |_l| 2.0),
                    Gamma::Uniform(Power::Integer(3)) => {
                        repulsion!(|r: f64, _l| r * r * r, |_l| 3.0)
                    }
                    Gamma::Uniform(Power::Integer(4)) => repulsion!(
                        |r: f64, _l| {
                            let r2 = r * r;
                            r2 * r2
                        },
                        |_l| 4.0
                    ),
                    Gamma::Uniform(p) => {
                        let g = match p {
                            Power::Integer(k) => k as f64,
                            Power::Real(g) => g,
                        };
                        repulsion!(|r: f64, _l| p.apply(r), |_l| g)
                    }
                    Gamma::PerLane(gs) => {
                        repulsion!(|r: f64, l: usize| Power::of(gs[l]).apply(r), |l: usize| gs
                            [l])
                    }
                }
            }
        }
    }

    // Back sweep from the right wall (u_N = 0), updating gap i+1 with u_{i+1} - u_i.
    let mut ok = [true; L];
    let mut u_next = [0.0; L];
    for i in (1..n).rev() {
        let row = (i - 1) * L;
        let gap = i * L;
        for l in 0..L {
            let u = scratch.y[row + l] + scratch.w[row + l] * u_next[l];
            // u_{i+1} - u_i without cancelling two large velocities.
            let relative = scratch.lambda[row + l] * u_next[l] - scratch.y[row + l];
            let old = gaps_in[gap + l];
            let d = old + h[l] * relative;
            vel_out[row + l] = u;
            gaps_out[gap + l] = d;
            let free = terms.bonded.is_none_or(|b| !b[gap + l]);
            ok[l] &= !free || gap_step_admissible(old, d);
            u_next[l] = u;
        }
    }
    for l in 0..L {
        let old = gaps_in[l];
        let d = old + h[l] * u_next[l];
        gaps_out[l] = d;
        let free = terms.bonded.is_none_or(|b| !b[l]);
        ok[l] &= !free || gap_step_admissible(old, d);
    }
    ok
}
