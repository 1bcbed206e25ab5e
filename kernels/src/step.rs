//! One step for a block of L members: the linearly implicit Euler solve fused with the batched
//! Thomas sweep, a gap update exact in ln d, the projection that keeps sum d_i fixed and the
//! discrete energy of the result. CPU twin of `shaders/step.wgsl`: the lane loop here is the
//! invocation there, and the loops over rows have the same shape. Keep the two in sync.
//!
//! Layout: element i of lane l at `i * L + l` (the GPU interleaves the whole batch the same way).
//!
//! SIMD: the lane loops read whole rows into local arrays and write whole rows back (no bounds
//! checks or aliasing inside them), and are compiled twice, for the build's baseline and for
//! AVX2 + FMA, chosen at run time ([`SimdLevel`]); no fma is ever formed, so both give the same
//! bits (and so does the GPU twin). A block of one lane groups four gaps in place of lanes where
//! the recurrences allow (the back sweep's gap update).
//!
//! The solve. With c_i = mu/d_i + h·gamma·G_i/(d_i + 2 eps) (lubrication plus linearised
//! repulsion),
//!   (2eps/h) u_i' - c_{i+1}(u_{i+1}' - u_i') + c_i(u_i' - u_{i-1}') = (2eps/h) u_i + G_i - G_{i+1} + F_i.
//! The matrix is SPD and strictly diagonally dominant: no pivoting. The sweep never divides by a
//! gap: it carries a_i = c_i d_i = mu + h gamma G_i d_i/(d_i + 2eps) and the rows in the form
//! u_i = d_{i+1} ys_i + w_i u_{i+1}, r_{i+1} = (u_{i+1} - u_i)/d_{i+1} = ls_i u_{i+1} - ys_i, where
//! r is the relative rate of a gap (d ln d/dt). It stays O(1) as a gap closes (lubrication makes
//! mu r a force), so it is computed to full relative precision however small the gap, and a gap
//! below the float range (d = 0 in the sweep) makes its two particles move as one, exactly as the
//! limit says.
//!
//! The exact Jacobian (`Terms::exact_jacobian`: the plan's choice, see the root crate's
//! `Plan::exact_jacobian`; only for extrapolated steps). In the variables
//! (ln d, u) the gap equation d(ln d_i)/dt = r_i has the derivative -r_i in ln d_i. Keeping it
//! (the linearly implicit Euler step with the exact Jacobian, not a W-method) multiplies a_i and
//! the gap's update by k_i = 1/(1 + h r_i), r_i the rate at the step's start
//! ([`jacobian_factor`]): ln d_i' = ln d_i + h k_i r_i'. Without it the extrapolated orders fall
//! to about 2 on long chains with random roughness (docs/accuracy.md); with it they climb towards
//! their nominal order, but at loose tolerances the paper's scenes need more work with it, so
//! plans take it only for tight tolerances by default. The back sweep stores k_i r_i' as the
//! rate. Order 1 keeps k_i = 1: its
//! steps are not extrapolated, and k_i = 1 is what the energy certificate below is proved for.
//!
//! The gap update: ln d_i' = ln d_i + h r_i. The lubrication force over the step is then exactly
//! mu (ln d' - ln d)/h, i.e. the step integrates mu d(ln d)/dt exactly; gaps stay positive and
//! keep their relative precision at any size, and the step need not shrink as a gap closes.
//! Gaps at or above GAP_FLOOR are stored as d; smaller ones as ln d (a negative number; a bonded
//! gap is stored as 0). The update is not telescoping, so the step ends by scaling all gaps by
//! one factor that restores sum d_i (a projection onto the invariant, O(h^2)).
//!
//! Energy: the step returns the discrete energy E' of its result and the work h Σ u_i' F_i of the
//! forcing, so that the caller rejects a step whose energy rose (linearising G is not
//! energy-stable at large gamma h).
//!
//! Clusters (Appendix A): a bonded gap (zero at t = 0) enters the sweep as a gap of GAP_FLOOR with
//! G = 0 and a = mu: the sweep merges its two particles (to ~1e-250); the back sweep then copies
//! the velocity exactly and sets bodies glued to the left wall to exactly 0, and the stored 0 of a
//! bonded gap is never updated.
//!
//! Over 700 lines on purpose: the step is one fused sweep (forward rows, back sweep with the gap
//! update, fix-ups, projection, energy, conclusion), and this file and `shaders/step.wgsl` are
//! that kernel written twice, function for function and loop for loop (the GPU must take the
//! same steps to the bit), so a change to one is a change to the other and the twins are
//! reviewed side by side. What stands alone is elsewhere: the element types (`real.rs`), what
//! both backends share (constants, step control, f64 math: `shared/`), the partitioned solve
//! (`step/partitioned.rs`), the tests (`step/tests.rs`).

use self::partitioned::euler_partitioned;
pub use self::partitioned::Layout;
pub(crate) use self::partitioned::PartitionedReal;
use crate::power::{powi_in_rounds, Power};
use crate::real::Real;
use crate::shared::f64_math;
pub use crate::shared::gaps::{
    EXP_FAST_MAX, GAP_EXP_TAYLOR, GAP_FLOOR, GAP_FLOOR_F32, LN_GAP_FLOOR, LN_GAP_FLOOR_F32,
    LN_RATIO_SERIES, MAX_OPENING, NEGLIGIBLE_OPENING,
};
use crate::SimdLevel;

/// gap_exp of a row of W values: the polynomial for the whole row when every |x| is small
/// (`small` != 0; the loop then stays branch-free), else value by value. Either way each value
/// gets gap_exp(x).
#[inline(always)]
fn exp_row<T: Real, const W: usize>(x: &[T; W], small: T::Flag) -> [T; W] {
    let mut e = [T::ZERO; W];
    if small != T::Flag::default() {
        for j in 0..W {
            e[j] = gap_exp_taylor(x[j]);
        }
    } else {
        for j in 0..W {
            e[j] = gap_exp(x[j]);
        }
    }
    e
}

/// e^x as the gap update computes it: for |x| < 1/16 (every gap of a mild step) the Taylor
/// polynomial to x^8, whose truncation error x^9/9! < 2e-16 is at rounding; else the kernel's
/// exp. The GPU kernel computes the same (`gap_exp` in shaders/step.wgsl).
#[inline(always)]
pub fn gap_exp<T: Real>(x: T) -> T {
    if x.abs() < T::c(GAP_EXP_TAYLOR) {
        gap_exp_taylor(x)
    } else {
        clamp(x, T::c(-EXP_FAST_MAX), T::c(EXP_FAST_MAX)).exp_in_range()
    }
}

/// `f64::clamp` in any [`Real`] (its operations: NaN passes through).
#[inline(always)]
fn clamp<T: Real>(x: T, min: T, max: T) -> T {
    let mut x = x;
    if x < min {
        x = min;
    }
    if x > max {
        x = max;
    }
    x
}

/// ln(y / last) of two rows' values of a gap (both > 0), as the extrapolation tableau computes it:
/// for y within 1/16 of `last` (the rows of an accepted step differ by its error) the series of
/// ln(1 + δ), δ = (y - last)/last, with `last`'s reciprocal given (one division per gap, not
/// one per row: the tableau's divisions were most of its cost); else the kernel's ln of the
/// ratio. The GPU kernel computes the same (`ln_gap_ratio` in shaders/step.wgsl).
#[inline(always)]
pub fn ln_gap_ratio<T: Real>(y: T, last: T, inv_last: T) -> T {
    let delta = (y - last) * inv_last;
    if delta.abs() < T::c(LN_RATIO_SERIES) {
        ln_1p_series(delta)
    } else {
        (y / last).ln_real()
    }
}

/// The series branch of [`ln_gap_ratio`], branch-free for the tableau's lane loop: ln(1 + δ) to
/// δ^13/13 by Horner; for |δ| < 1/16 the truncation, below |δ|^14/14, is under 2^-55 of the
/// result (rounding).
#[inline(always)]
pub(crate) fn ln_1p_series<T: Real>(delta: T) -> T {
    let c = |v: f64| T::c(v);
    let mut p = c(1.0 / 13.0);
    p = c(-1.0 / 12.0) + delta * p;
    p = c(1.0 / 11.0) + delta * p;
    p = c(-1.0 / 10.0) + delta * p;
    p = c(1.0 / 9.0) + delta * p;
    p = c(-1.0 / 8.0) + delta * p;
    p = c(1.0 / 7.0) + delta * p;
    p = c(-1.0 / 6.0) + delta * p;
    p = c(1.0 / 5.0) + delta * p;
    p = c(-1.0 / 4.0) + delta * p;
    p = c(1.0 / 3.0) + delta * p;
    p = c(-1.0 / 2.0) + delta * p;
    p = c(1.0) + delta * p;
    delta * p
}

/// The stored value of a gap given its logarithm.
#[inline(always)]
pub fn encode_ln_gap<T: Real>(s: T) -> T {
    if s > T::LN_GAP_FLOOR {
        s.exp_real()
    } else {
        s
    }
}

/// ln d of a stored free gap (`stored_gap::ln` with the kernel's ln).
#[inline(always)]
pub fn stored_ln<T: Real>(stored: T) -> T {
    if stored > T::ZERO {
        stored.ln_real()
    } else {
        stored
    }
}

/// What the plan says exists, for one block, in the step's element type T. Absent terms cost
/// nothing.
pub struct Terms<'a, const L: usize, T: Real = f64> {
    pub eps: T,
    pub mu: [T; L],
    /// sum d_i of each lane's initial chain, kept by the projection (f64 in either precision:
    /// see `conclude_impl`).
    pub total_gap: [f64; L],
    /// The largest repulsion a gap of the lane can reach, max_i ((d*_i + 2eps)/2eps)^gamma (0
    /// without repulsion), for the energy certificate ([`StepReport::certified`]).
    pub contact_repulsion: [f64; L],
    /// Whether the step keeps the Jacobian's -r_i (k_i = 1/(1 + h r_i)): the plan's choice for
    /// the extrapolated schemes (order 2 and above); order 1 takes k_i = 1.
    pub exact_jacobian: bool,
    /// d* (interleaved, length N·L) and how G is evaluated: present iff the model has repulsion.
    pub repulsion: Option<(&'a [T], Gamma<L>)>,
    /// Bonded gaps (interleaved, length N·L): present iff some member has clusters.
    pub bonded: Option<&'a [bool]>,
    pub forcing: Option<&'a dyn Forcing>,
    /// Each lane's values of the forcing's symbolic parameters (empty without).
    pub forcing_params: [&'a [f64]; L],
    /// The instruction set of the lane loops (at most [`SimdLevel::widest_here`]).
    pub simd: SimdLevel,
    /// Whether the step computes the energy of its result (see [`EnergyWanted`]).
    pub energy: EnergyWanted,
    /// Whether a one-member block with a long chain may take the partitioned solve
    /// (`ROUGHLUB_CPU_PARTITION=off` says no, through [`Overrides`](crate::overrides::Overrides)).
    pub partition: bool,
}

/// Whether a step computes the energy of its result ([`Terms::energy`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EnergyWanted {
    /// Unless every lane's step is certified ([`StepReport::certified`]): a step on its own.
    UnlessCertified,
    /// For every lane: the end of a tableau's row whose earlier substeps were not certified,
    /// so the certificate of the last alone does not bound the row's energy.
    Always,
    /// Not at all (the report's energy is -1): a tableau's substep inside a row, which the
    /// caller does not check (`Block::extrapolated_attempt` in the root crate). The energy's
    /// sums cost ~16 % of an exact-Jacobian substep, which is never certified
    /// (docs/performance.md).
    No,
}

/// gamma for a block: uniform across lanes (integer → multiplications), or per lane.
#[derive(Debug, Clone, Copy)]
pub enum Gamma<const L: usize> {
    Uniform(Power),
    PerLane([f64; L]),
}

impl<const L: usize> Gamma<L> {
    #[inline(always)]
    pub fn gamma(&self, l: usize) -> f64 {
        match self {
            Gamma::Uniform(p) => p.exponent(),
            Gamma::PerLane(g) => g[l],
        }
    }

    /// Every lane's gamma.
    #[inline(always)]
    pub fn per_lane(&self) -> [f64; L] {
        std::array::from_fn(|l| self.gamma(l))
    }
}

/// Thomas sweep scratch, length (N-1)·L each: the rows u_i = d_{i+1} ys_i + w_i u_{i+1} with
/// r_{i+1} = ls_i u_{i+1} - ys_i (the back sweep overwrites ls with the rate r_{i+1}, which the
/// log-gap fix-up reads), and the forces F_i (only with forcing, for the work h Σ u' F).
#[derive(Debug, Clone)]
pub struct Scratch<T: Real = f64> {
    pub w: Vec<T>,
    pub ls: Vec<T>,
    pub ys: Vec<T>,
    pub force: Vec<T>,
    /// The exact Jacobian's factor k_i = 1/(1 + h r_i) of gap i (row i - 1), from the forward
    /// sweep for the back sweep ([`jacobian_factor`]).
    pub k: Vec<T>,
}

impl<T: Real> Scratch<T> {
    pub fn new(particles: usize, lanes: usize) -> Scratch<T> {
        let len = (particles - 1) * lanes;
        Scratch {
            w: vec![T::ZERO; len],
            ls: vec![T::ZERO; len],
            ys: vec![T::ZERO; len],
            force: vec![T::ZERO; len],
            k: vec![T::ZERO; len],
        }
    }
}

/// What a step reads and writes: the state it starts from (gaps in the stored form,
/// velocities; L lanes interleaved), where the candidate goes, and the sweep's work rows, as
/// one argument of the step's entry points ([`euler_step`], `euler_step_as`,
/// [`Real::partitioned_step`]). The sweeps themselves take the five as arguments of their own
/// (see `euler_step_as`).
pub struct StepBuffers<'s, T: Real = f64> {
    pub gaps_in: &'s [T],
    pub vel_in: &'s [T],
    pub gaps_out: &'s mut [T],
    pub vel_out: &'s mut [T],
    pub scratch: &'s mut Scratch<T>,
}

impl<T: Real> StepBuffers<'_, T> {
    /// The same buffers, borrowed for a shorter time (to try one solve and fall back to another).
    pub fn reborrow(&mut self) -> StepBuffers<'_, T> {
        StepBuffers {
            gaps_in: self.gaps_in,
            vel_in: self.vel_in,
            gaps_out: self.gaps_out,
            vel_out: self.vel_out,
            scratch: self.scratch,
        }
    }
}

/// What one step found out, per lane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepReport {
    /// Every gap and velocity of the result finite (a rejected step is retried smaller).
    pub admissible: bool,
    /// A failure that no smaller step can cure, found in the state the step started from:
    /// the forcing or the repulsion is not finite there.
    pub hard: Option<HardFailure>,
    /// The step provably did not raise the energy beyond the forcing's work (see
    /// [`energy_certified`]); its energy was then not computed (`energy` is -1).
    pub certified: bool,
    /// Discrete energy of the result (-1 when not computed: certified, or [`EnergyWanted::No`]).
    pub energy: f64,
    /// Work of the forcing over the step, h Σ u_i' F_i.
    pub work: f64,
}

/// See [`StepReport::hard`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum HardFailure {
    /// F_i is not finite: particle i (1-based) at position x.
    Forcing { particle: usize, x: f64 },
    /// G_i = (rho/rho*)^gamma is not finite: gap i (1-based) with that density ratio.
    Repulsion { gap: usize, ratio: f64 },
}

impl StepReport {
    pub const START: StepReport = StepReport {
        admissible: true,
        hard: None,
        certified: false,
        energy: 0.0,
        work: 0.0,
    };
}

/// How G and gamma are evaluated in one specialised instance of the step (a closure per case of
/// [`Gamma`]: integer gamma as a fixed chain of multiplications, per lane otherwise), and which
/// terms exist (const generics): absent terms compile to nothing and the lane loops have no
/// per-element branches, so they run in SIMD registers.
#[derive(Clone, Copy)]
struct Law<P, Q> {
    power: P,
    gamma: Q,
}

/// The L lanes of row `at` of an interleaved buffer: one bounds check per row, none per lane
/// (a check inside the lane loop keeps it out of SIMD registers).
#[inline(always)]
fn lanes<const L: usize, T>(s: &[T], at: usize) -> &[T; L] {
    s[at..at + L].try_into().unwrap()
}

#[inline(always)]
fn lanes_mut<const L: usize, T>(s: &mut [T], at: usize) -> &mut [T; L] {
    (&mut s[at..at + L]).try_into().unwrap()
}

/// The per-element inputs of the model, as interleaved slices: d* (the gaps themselves without
/// repulsion, never read then) and the bonded flags (empty without clusters, never read then).
struct Inputs<'a, T> {
    dstar: &'a [T],
    bonded: &'a [bool],
}

impl<'a, T: Real> Inputs<'a, T> {
    #[inline(always)]
    fn of<const L: usize>(terms: &Terms<'a, L, T>, gaps: &'a [T]) -> Inputs<'a, T> {
        Inputs {
            dstar: terms.repulsion.map_or(gaps, |r| r.0),
            bonded: terms.bonded.unwrap_or(&[]),
        }
    }

    /// Row `at` of d* and of the bonded flags (all free without clusters).
    #[inline(always)]
    fn row<const L: usize, const CLU: bool>(&self, at: usize) -> (&'a [T; L], [bool; L]) {
        let bonded = if CLU {
            *lanes::<L, bool>(self.bonded, at)
        } else {
            [false; L]
        };
        (lanes::<L, T>(self.dstar, at), bonded)
    }
}

/// The scale of [`gap_reciprocals`]: 1/eps2, at most 1/GAP_FLOOR (finite for any radius).
#[inline(always)]
pub(crate) fn reciprocal_scale<T: Real>(eps2: T) -> T {
    fmin(T::ONE / eps2, T::ONE / T::GAP_FLOOR)
}

/// (1/d, 1/(d + eps2)) of an effective gap d >= GAP_FLOOR. In f64 with one division: both from
/// 1/(d (d + eps2) c), c = [`reciprocal_scale`]; the forward sweep's divisions bound its speed
/// (four per row; measured: one fewer took 5-12 % off a batch's run at N = 200), and c keeps
/// the product within [GAP_FLOOR, ~1/GAP_FLOOR] (d (d + eps2) alone underflows for small d and
/// eps2). The form rounds 1/(d + eps2) ~3 ulps off instead of 1, and G = ratio^gamma takes
/// gamma times that: within f64's energy slack, not f32's (measured: f32 at order 4, gamma =
/// 20, took 61 adaptive steps instead of 49, tests/cpu_f32.rs), so f32 divides twice. Without
/// repulsion, 1/d alone.
#[inline(always)]
pub(crate) fn gap_reciprocals<T: Real, const REP: bool>(d: T, eps2: T, scale: T) -> (T, T) {
    if !REP {
        return (T::ONE / d, T::ZERO);
    }
    if !T::IS_F64 {
        return (T::ONE / d, T::ONE / (d + eps2));
    }
    let s_scaled = (d + eps2) * scale;
    let inv_product = T::ONE / (d * s_scaled);
    (s_scaled * inv_product, d * scale * inv_product)
}

/// (a, G, d, 1/d) of one gap for one lane: a = mu + h gamma G d/(d + 2eps) at the effective gap
/// d (eps2 = 2eps, `scale` its [`reciprocal_scale`]; `dstar` is d* of the gap, read only with
/// repulsion).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn gap_terms<T: Real, const REP: bool, const CLU: bool, P, Q>(
    law: Law<P, Q>,
    l: usize,
    mu: T,
    eps2: T,
    scale: T,
    stored: T,
    dstar: T,
    bonded: bool,
    h: T,
) -> (T, T, T, T)
where
    P: Fn(usize, T) -> T + Copy,
    Q: Fn(usize) -> T + Copy,
{
    let d = fmax(stored, T::GAP_FLOOR);
    let (inv_d, inv_s) = gap_reciprocals::<T, REP>(d, eps2, scale);
    if !REP {
        return (mu, T::ZERO, d, inv_d);
    }
    let ratio = (dstar + eps2) * inv_s;
    let mut g = (law.power)(l, ratio);
    if CLU && bonded {
        g = T::ZERO;
    }
    (mu + h * (law.gamma)(l) * g * d * inv_s, g, d, inv_d)
}

/// The factor k of a gap whose ends move at u_left and u_right at the step's start, x = h r =
/// h (u_right - u_left)/d: the exact Jacobian's 1/(1 + x) where the gap opens (x >= 0: k in
/// (0, 1]), and k = 1 - x/(1 + x + 16 x^4) where it closes, which is 1/(1 + x) to O(x^5), smooth
/// across x = 0, within [1, 1.4] and back to 1 for gaps that would close within the step, where
/// 1/(1 + x) is unbounded and the linearisation about the start rate, which lubrication is about
/// to brake, overshoots. Measured against other forms (docs/accuracy-measurements.md): a cut-off
/// of 1/(1 + x) is a kink the rows of one coarse step straddle (order 4 at dt = 1.6e-2 on case
/// 2a: 8e-2); bounded forms that match 1/(1 + x) only to O(x^3) kept the six-particle chain's
/// order 6 at 7 instead of 6; a closing k that falls to 0 freezes colliding gaps (the collision
/// tests fail). k = 1 where not `exact`, and for gaps stored as ln d (d at the gap floor:
/// collisions, whose ln d update is exact; with k there the collision tests failed, "every
/// smaller step raised the energy"); k = 1 leaves every product it enters unchanged, bit for
/// bit. The switch depends on the state, not on h: before, k = 1 where h (|u_left| +
/// |u_right|) > 1e4 d (taken as an unresolved rate), a kink in h that the rows of one step
/// straddled near contact (the substeps h/n_j on either side of it), which broke the
/// extrapolation: on a random N = 300 chain at ln d ~ -19 to -27
/// (`docs/order_loss/contact_n300.toml`) auto's error at tolerance 1e-8 was 12 times the
/// tolerance in 545 + 46 steps (docs/accuracy.md). x is finite for finite velocities (d is at
/// least the gap floor), and 16 x^4 = inf gives k = 1.
#[inline(always)]
fn jacobian_factor<T: Real>(exact: bool, d: T, inv_d: T, h: T, u_left: T, u_right: T) -> T {
    if exact && d > T::GAP_FLOOR {
        let x = h * (u_right - u_left) * inv_d;
        // One division for both branches (the lane loop computes both; two cost ~5 % of the
        // step, measured): q = 1/(1 + x + [x < 0] 16 x^4), k = q opening, 1 - x q closing.
        // [x < 0] x^4 as min(x, 0)^4, the same values: a select feeding the division became
        // two divisions (LLVM moved the division into both arms, one of them masked).
        let closing_x = fmin(x, T::ZERO);
        let closing = T::c(16.0) * ((closing_x * closing_x) * (closing_x * closing_x));
        let q = T::ONE / (T::ONE + x + closing);
        if x < T::ZERO {
            T::ONE - x * q
        } else {
            q
        }
    } else {
        T::ONE
    }
}

/// Phi_i(d) of one free gap: (d + 2eps) G/(gamma - 1), or -(d* + 2eps) ln(d + 2eps) at gamma = 1.
#[inline(always)]
fn potential_of<T: Real, const REP: bool, P, Q>(
    law: Law<P, Q>,
    l: usize,
    eps2: T,
    dstar: T,
    d: T,
) -> T
where
    P: Fn(usize, T) -> T + Copy,
    Q: Fn(usize) -> T + Copy,
{
    if !REP {
        return T::ZERO;
    }
    let s = d + eps2;
    let s_star = dstar + eps2;
    let g = (law.gamma)(l);
    if g == T::ONE {
        -s_star * s.ln_real()
    } else {
        s * (law.power)(l, s_star / s) / (g - T::ONE)
    }
}

/// The repulsion of gap `gap` (0-based; element `index`) overflowed at the effective gap d.
fn repulsion_failure<T: Real, const L: usize>(
    terms: &Terms<L, T>,
    gap: usize,
    index: usize,
    d: T,
) -> HardFailure {
    let dstar = terms.repulsion.map_or(T::ZERO, |r| r.0[index]);
    let eps2 = T::c(2.0) * terms.eps;
    HardFailure::Repulsion {
        gap: gap + 1,
        ratio: ((dstar + eps2) / (d + eps2)).to_f64(),
    }
}

/// Calls `$f` (a function made by `simd_versions!`) for the element type `$t` with `$law` bound
/// to the specialised [`Law`] for the block's gamma and the const generics REP (repulsion) and
/// CLU (clusters) set from `$terms`.
macro_rules! specialised {
    ($t:ty, $terms:expr, $f:ident, $args:tt) => {
        specialised!(@go $t, [$t,], $terms, $f, $args)
    };
    (@go $t:ty, [$($pre:tt)*], $terms:expr, $f:ident, ($($arg:expr),*)) => {{
        let terms = $terms;
        macro_rules! with_flags {
            ($rep:literal, $clu:literal, $law:expr) => {{
                // Forcing is a run-time branch (a loop of its own per row, skipped without it): as
                // a const flag it doubled the kernels' instances and build time for no measured
                // speed. The law is bound once: a closure written in each arm would be a type of
                // its own per arm, and every function generic over it would be compiled once per
                // arm.
                let law = $law;
                $f::<$($pre)* L, $rep, $clu, _, _>($($arg,)* law)
            }};
        }
        // A law evaluated per lane (any gamma, integer or not, with the same operations as the
        // uniform laws below: `Power::of` gives back the plan's `Power`, so the same bits). One
        // closure makes it, so it is one type wherever it is taken (with and without clusters,
        // uniform non-integer gamma or gamma per lane): each written-out law is a type of its
        // own, and every function generic over it is compiled once more.
        let per_lane_law = |gamma: Gamma<L>| {
            let gs = gamma.per_lane();
            let gt: [$t; L] = gs.map(<$t as Real>::c);
            Law {
                power: move |l: usize, r: $t| <$t as Real>::power(Power::of(gs[l]), r),
                gamma: move |l: usize| gt[l],
            }
        };
        let no_repulsion = Law { power: |_l: usize, _r: $t| <$t as Real>::ZERO, gamma: |_l: usize| <$t as Real>::ONE };
        if terms.bonded.is_some() {
            // Clusters (touching particles of a particle file) are rare, so with them every
            // gamma takes the per-lane law: two instances of each kernel instead of one per law
            // (measured: a law each doubled the step kernels' build).
            match terms.repulsion.map(|r| r.1) {
                None => with_flags!(false, true, no_repulsion),
                Some(gamma) => with_flags!(true, true, per_lane_law(gamma)),
            }
        } else {
        match terms.repulsion.map(|r| r.1) {
            None => with_flags!(false, false, no_repulsion),
            Some(Gamma::Uniform(Power::Integer(1))) => {
                with_flags!(true, false, Law { power: |_l: usize, r: $t| r, gamma: |_l: usize| <$t as Real>::ONE })
            }
            Some(Gamma::Uniform(Power::Integer(2))) => {
                with_flags!(true, false, Law { power: |_l: usize, r: $t| r * r, gamma: |_l: usize| <$t as Real>::c(2.0) })
            }
            Some(Gamma::Uniform(Power::Integer(n))) => {
                // Gamma 3, 4 and above in a fixed number of rounds (packed over the lanes, n
                // known at run time): the same products as written out, so the same bits.
                let g = <$t as Real>::c(n as f64);
                with_flags!(true, false, Law { power: move |_l: usize, r: $t| powi_in_rounds(r, n), gamma: move |_l: usize| g })
            }
            // A non-integer gamma costs its pow per lane either way (not packed), so it takes
            // the per-lane law.
            Some(gamma) => with_flags!(true, false, per_lane_law(gamma)),
        }
        }
    }};
}

/// Defines `$name`, which runs the `#[inline(always)]` body `$body` compiled for the instruction
/// set `simd` names: the same source, so the same operations in the same order at every level
/// (bitwise equal results), only wider registers. `$avx` is the AVX2 + FMA instance, `$avx512`
/// the AVX-512 one.
macro_rules! simd_versions {
    // Generic over an element type with more than `Real` (the partitioned solve's
    // `PartitionedReal`: its tiles' transposes per type), clusters tested at run time.
    (T: $bound:ident; $($rest:tt)*) => {
        simd_versions!(@go [T: $bound,] [T,] T {const REP: bool,} {REP,}; $($rest)*);
    };
    // Generic over the element type T: Real.
    ($name:ident, $($rest:tt)*) => {
        simd_versions!(@go [T: Real,] [T,] T {const REP: bool, const CLU: bool,} {REP, CLU,}; $name, $($rest)*);
    };
    (@go [$($tp:tt)*] [$($ta:tt)*] $elem:ty {$($cp:tt)*} {$($ca:tt)*}; $name:ident, $avx:ident, $avx512:ident, $body:ident, ($($arg:ident: $ty:ty),*) -> $ret:ty) => {
        #[allow(clippy::too_many_arguments)]
        fn $name<$($tp)* const L: usize, $($cp)* P, Q>(
            simd: SimdLevel,
            $($arg: $ty,)*
            law: Law<P, Q>,
        ) -> $ret
        where
            P: Fn(usize, $elem) -> $elem + Copy,
            Q: Fn(usize) -> $elem + Copy,
        {
            // SAFETY (both arms): a level is only chosen where the CPU has its features
            // (`SimdLevel::widest_here`).
            #[cfg(target_arch = "x86_64")]
            match simd {
                SimdLevel::Avx512 => {
                    return unsafe { $avx512::$avx512::<$($ta)* L, $($ca)* P, Q>($($arg,)* law) };
                }
                SimdLevel::Avx2Fma => {
                    return unsafe { $avx::$avx::<$($ta)* L, $($ca)* P, Q>($($arg,)* law) };
                }
                SimdLevel::Portable => {}
            }
            let _ = simd;
            $body::<$($ta)* L, $($ca)* P, Q>($($arg,)* law)
        }

        simd_versions!(@instance "avx2,fma", [$($tp)*] [$($ta)*] $elem {$($cp)*} {$($ca)*}; $avx, $body, ($($arg: $ty),*) -> $ret);
        simd_versions!(@instance "avx2,fma,avx512f,avx512vl,avx512dq", [$($tp)*] [$($ta)*] $elem {$($cp)*} {$($ca)*}; $avx512, $body, ($($arg: $ty),*) -> $ret);
    };
    // `$body` compiled with the target features `$features` enabled, as the unsafe fn
    // `$name::$name`. In a module of its own because rustc places a generic function's instances
    // in the codegen unit of the module that defines it: all levels in one module made one
    // unit that LLVM optimised on one core for most of the crate's build.
    (@instance $features:literal, [$($tp:tt)*] [$($ta:tt)*] $elem:ty {$($cp:tt)*} {$($ca:tt)*}; $name:ident, $body:ident, ($($arg:ident: $ty:ty),*) -> $ret:ty) => {
        #[cfg(target_arch = "x86_64")]
        mod $name {
            use super::*;

            #[target_feature(enable = $features)]
            #[allow(clippy::too_many_arguments)]
            pub(super) unsafe fn $name<$($tp)* const L: usize, $($cp)* P, Q>(
                $($arg: $ty,)*
                law: Law<P, Q>,
            ) -> $ret
            where
                P: Fn(usize, $elem) -> $elem + Copy,
                Q: Fn(usize) -> $elem + Copy,
            {
                $body::<$($ta)* L, $($ca)* P, Q>($($arg,)* law)
            }
        }
    };
}

/// Discrete energy E = eps Σ u_i² + Σ Phi_i(d_i) of every lane's state (the same sums, in the
/// same order, as a step's report, so that the energy check compares like with like).
pub fn state_energy<T: Real, const L: usize>(
    terms: &Terms<L, T>,
    n: usize,
    gaps: &[T],
    vel: &[T],
) -> [f64; L] {
    specialised!(T, terms, state_energy_impl, (terms, n, gaps, vel))
}

fn state_energy_impl<T: Real, const L: usize, const REP: bool, const CLU: bool, P, Q>(
    terms: &Terms<L, T>,
    n: usize,
    gaps: &[T],
    vel: &[T],
    law: Law<P, Q>,
) -> [f64; L]
where
    P: Fn(usize, T) -> T + Copy,
    Q: Fn(usize) -> T + Copy,
{
    let eps2 = T::c(2.0) * terms.eps;
    let inputs = Inputs::of(terms, gaps);
    // Sums in f64 in either precision (as `conclude_impl`'s).
    let mut kinetic = [0.0f64; L];
    let mut energy = [0.0f64; L];
    for i in 0..n {
        let k = i * L;
        let (dstar, bonded) = inputs.row::<L, CLU>(k);
        let stored = lanes::<L, T>(gaps, k);
        for l in 0..L {
            let phi =
                potential_of::<T, REP, P, Q>(law, l, eps2, dstar[l], stored[l].max_real(T::ZERO));
            if !bonded[l] {
                energy[l] += phi.to_f64();
            }
        }
        if i + 1 < n {
            let u = lanes::<L, T>(vel, k);
            for l in 0..L {
                kinetic[l] += (u[l] * u[l]).to_f64();
            }
        }
    }
    for l in 0..L {
        energy[l] += terms.eps.to_f64() * kinetic[l];
    }
    energy
}

/// F_i = ∫_{q_i - eps}^{q_i + eps} f(t, x) dx ([`Forcing::particle_force`]).
#[inline(always)]
fn particle_force(forcing: &dyn Forcing, params: &[f64], eps: f64, t: f64, q: f64) -> f64 {
    forcing.particle_force(params, eps, t, q)
}

/// A body force density f(t, x), as the step needs it: integrated over each particle. The
/// scene's forcing (an expression and a Gauss–Legendre rule, `roughlub::model::plan::Forcing`)
/// implements it; the step calls it once per particle, outside its lane loops.
pub trait Forcing: Sync {
    /// ∫_{q - eps}^{q + eps} f(t, x) dx for a member whose symbolic parameters are `params`.
    fn particle_force(&self, params: &[f64], eps: f64, t: f64, q: f64) -> f64;
}

/// max(a, b) as one packed max: b when a is NaN, as `f64::max` gives (whose NaN handling for
/// either argument costs a compare and a blend per use). Callers pass the value that may be NaN
/// as `a` and a never-NaN bound or accumulator as `b`, so the result is `f64::max`'s.
#[inline(always)]
fn fmax<T: Real>(a: T, b: T) -> T {
    if a > b {
        a
    } else {
        b
    }
}

/// min(a, b) as one packed min, b when a is NaN (see [`fmax`]).
#[inline(always)]
fn fmin<T: Real>(a: T, b: T) -> T {
    if a < b {
        a
    } else {
        b
    }
}

/// The Taylor branch of [`gap_exp`] (|x| < GAP_EXP_TAYLOR), branch-free for the lane loop.
#[allow(clippy::excessive_precision)]
#[inline(always)]
pub(crate) fn gap_exp_taylor<T: Real>(x: T) -> T {
    // Horner, 1/k! as the nearest f64 (the WGSL twin writes the same literals; in f32 both round
    // them once).
    let c = T::c;
    c(1.0)
        + x * (c(1.0)
            + x * (c(0.5)
                + x * (c(1.666_666_666_666_666_6e-1)
                    + x * (c(4.166_666_666_666_666_4e-2)
                        + x * (c(8.333_333_333_333_333e-3)
                            + x * (c(1.388_888_888_888_889e-3)
                                + x * (c(1.984_126_984_126_984e-4)
                                    + x * c(2.480_158_730_158_730_2e-5))))))))
}

/// Advances every lane by its own step `h[l]` from (gaps_in, vel_in) to (gaps_out, vel_out)
/// (gaps in the stored form: d, or ln d below GAP_FLOOR). Lanes whose report is not admissible
/// (or has a hard failure) must be rejected by the caller: their output is garbage.
pub fn euler_step<T: Real, const L: usize>(
    terms: &Terms<L, T>,
    particles: usize,
    t: &[f64; L],
    h: &[T; L],
    io: StepBuffers<'_, T>,
) -> [StepReport; L] {
    euler_step_as(
        terms.simd,
        default_layout::<L>(particles, terms.partition),
        terms,
        particles,
        t,
        h,
        io,
    )
}

/// The solve a block of L lanes with `particles` particles uses: for one member with a long
/// chain the partitioned one (the sequential sweep would be bound by its row-to-row latency),
/// else the sequential sweep (`None`). The same rule in f64 and f32 ([`Layout::for_chain`]: it
/// depends on the chain's length only).
pub(crate) fn default_layout<const L: usize>(particles: usize, partition: bool) -> Option<Layout> {
    if L == 1 && partition {
        Layout::for_chain(particles)
    } else {
        None
    }
}

/// [`euler_step`] with the lane loops compiled for `simd` (which the CPU must support) and the
/// solve chosen: the sequential sweep (`None`) or the partitioned one with this layout (L = 1;
/// [`Real::partitioned_step`]).
pub(crate) fn euler_step_as<T: Real, const L: usize>(
    simd: SimdLevel,
    layout: Option<Layout>,
    terms: &Terms<L, T>,
    particles: usize,
    t: &[f64; L],
    h: &[T; L],
    mut io: StepBuffers<'_, T>,
) -> [StepReport; L] {
    if let Some(layout) = layout {
        let r = T::partitioned_step(simd, layout, terms, particles, t, h, io.reborrow());
        if let Some(r) = r {
            return r;
        }
    }
    // The sweeps take the buffers as arguments of their own: as `&mut` arguments they are known
    // not to overlap, which the lane loops' vectorisation needs (in the struct, the
    // (4096, 100) row of `cargo bench --bench cpu_solver` ran 13 % slower, f32 (256, 1000) 22 %).
    let StepBuffers {
        gaps_in,
        vel_in,
        gaps_out,
        vel_out,
        scratch,
    } = io;
    specialised!(
        T,
        terms,
        euler_simd,
        (simd, terms, particles, t, h, gaps_in, vel_in, gaps_out, vel_out, scratch)
    )
}

/// The partitioned solve ([`euler_step_as`] with a layout) in f64 or f32
/// (`Real::partitioned_step`).
pub(crate) fn partitioned_real<T: PartitionedReal, const L: usize>(
    simd: SimdLevel,
    layout: Layout,
    terms: &Terms<L, T>,
    particles: usize,
    t: &[f64; L],
    h: &[T; L],
    io: StepBuffers<'_, T>,
) -> [StepReport; L] {
    let StepBuffers {
        gaps_in,
        vel_in,
        gaps_out,
        vel_out,
        scratch,
    } = io;
    specialised!(
        T,
        terms,
        euler_partitioned,
        (simd, terms, particles, t, h, gaps_in, vel_in, gaps_out, vel_out, scratch, layout)
    )
}

simd_versions!(euler_simd, euler_avx2, euler_avx512, euler_impl, (
    terms: &Terms<L, T>,
    n: usize,
    t: &[f64; L],
    h: &[T; L],
    gaps_in: &[T],
    vel_in: &[T],
    gaps_out: &mut [T],
    vel_out: &mut [T],
    scratch: &mut Scratch<T>
) -> [StepReport; L]);

#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn euler_impl<T: Real, const L: usize, const REP: bool, const CLU: bool, P, Q>(
    terms: &Terms<L, T>,
    n: usize,
    t: &[f64; L],
    h: &[T; L],
    gaps_in: &[T],
    vel_in: &[T],
    gaps_out: &mut [T],
    vel_out: &mut [T],
    scratch: &mut Scratch<T>,
    law: Law<P, Q>,
) -> [StepReport; L]
where
    P: Fn(usize, T) -> T + Copy,
    Q: Fn(usize) -> T + Copy,
{
    let eps = terms.eps;
    assert_eq!(gaps_in.len(), n * L);
    assert_eq!(vel_in.len(), (n - 1) * L);
    let zero = T::ZERO;
    let floor = T::GAP_FLOOR;
    let mass = T::c(2.0) * eps;
    let eps2 = T::c(2.0) * eps;
    let scale = reciprocal_scale(eps2);
    let mu = terms.mu;
    let inputs = Inputs::of(terms, gaps_in);
    let mut report = [StepReport::START; L];
    let mut m_over_h = [zero; L];
    for l in 0..L {
        m_over_h[l] = mass / h[l];
    }

    // Forward sweep. The wall (row 0, u_0 = 0) has an infinite pivot: lambda_0 = 1, so
    // ls_0 = 1/d_1 and ys_0 = 0. Non-finite G or F are noted per lane (a hard failure) and
    // looked up after the sweep, so the loop has no branches.
    let mut a_prev = [zero; L];
    let mut g_prev = [zero; L];
    let mut ls_prev = [zero; L];
    let mut ys_prev = [zero; L];
    let mut q = [zero; L];
    let mut f = [zero; L];
    // Flags as 0/1 in lanes as wide as T (what a packed comparison yields; bools cost packing).
    let flag = T::Flag::from;
    let mut nonfinite = [T::Flag::default(); L];
    let exact = terms.exact_jacobian;
    // The first gap's k (the wall's side does not move); the others' are kept in scratch.k.
    let mut k_first = [T::ONE; L];
    {
        let stored = lanes::<L, T>(gaps_in, 0);
        let (dstar, bonded) = inputs.row::<L, CLU>(0);
        let u_right = if n > 1 {
            *lanes::<L, T>(vel_in, 0)
        } else {
            [zero; L]
        };
        for l in 0..L {
            let (a, g, d, inv_d) = gap_terms::<T, REP, CLU, P, Q>(
                law, l, mu[l], eps2, scale, stored[l], dstar[l], bonded[l], h[l],
            );
            k_first[l] = jacobian_factor(exact, d, inv_d, h[l], zero, u_right[l]);
            a_prev[l] = a * k_first[l];
            g_prev[l] = g;
            ls_prev[l] = inv_d;
            nonfinite[l] |= flag(!g.is_finite());
        }
    }
    // The row loop four times, with and without forcing and the exact matrix: a run-time test
    // inside it kept the forces' lanes live across rows (register spills: 6-12 % slower on 256
    // and 4096 members without forcing), while the whole step specialised on forcing doubled the
    // kernels' build; and a run-time `exact` left the factor's divisions in the frozen matrix's
    // loop (masked, not skipped: 4 packed divisions a row where 2 are needed; the frozen run of
    // 1024 members of the N = 200 chain at 3.16e-8 took 25 % less CPU time without them).
    macro_rules! forward_rows {
        ($forced:literal, $exact:literal) => {
            for i in 1..n {
                let row = (i - 1) * L;
                let next_gap = i * L;
                if let (true, Some(forcing)) = ($forced, terms.forcing) {
                    // Not vectorisable (the expression is interpreted): a loop of its own.
                    let prev = lanes::<L, T>(gaps_in, row);
                    let force = lanes_mut::<L, T>(&mut scratch.force, row);
                    for l in 0..L {
                        q[l] += prev[l].decode_stored() + mass;
                        f[l] = T::c(particle_force(
                            forcing,
                            terms.forcing_params[l],
                            eps.to_f64(),
                            t[l],
                            q[l].to_f64(),
                        ));
                        force[l] = f[l];
                    }
                }
                // The lane loop works on local copies of the rows (no aliasing for the vectoriser to
                // rule out) and stores whole rows after it.
                let stored = *lanes::<L, T>(gaps_in, next_gap);
                let (dstar, bonded) = inputs.row::<L, CLU>(next_gap);
                let dstar = *dstar;
                let vel = *lanes::<L, T>(vel_in, row);
                let vel_right = if i + 1 < n {
                    *lanes::<L, T>(vel_in, next_gap)
                } else {
                    [zero; L]
                };
                let mut w = [zero; L];
                let mut k = [zero; L];
                for l in 0..L {
                    let (a_next, g_next, d_next, inv_d) = gap_terms::<T, REP, CLU, P, Q>(
                        law, l, mu[l], eps2, scale, stored[l], dstar[l], bonded[l], h[l],
                    );
                    k[l] = jacobian_factor($exact, d_next, inv_d, h[l], vel[l], vel_right[l]);
                    let a_next = a_next * k[l];
                    nonfinite[l] |= flag(!(g_next + f[l]).is_finite());
                    let rhs = m_over_h[l] * vel[l] + g_prev[l] - g_next + f[l];
                    // The pivot excess·d + a, grouped as (m/h·d + a) + (a_prev·d)·ls_prev so that only
                    // one multiplication and one addition wait for the previous row (a single member's
                    // sweep is this chain's latency; batches hide it).
                    let excess = m_over_h[l] + a_prev[l] * ls_prev[l];
                    let delta = rhs + a_prev[l] * ys_prev[l];
                    let pivot_base = m_over_h[l] * d_next + a_next;
                    let coupling = a_prev[l] * d_next;
                    let inv = T::ONE / (pivot_base + coupling * ls_prev[l]);
                    let ls = excess * inv;
                    let ys = delta * inv;
                    w[l] = a_next * inv;
                    ls_prev[l] = ls;
                    ys_prev[l] = ys;
                    a_prev[l] = a_next;
                    g_prev[l] = g_next;
                }
                *lanes_mut::<L, T>(&mut scratch.w, row) = w;
                *lanes_mut::<L, T>(&mut scratch.ls, row) = ls_prev;
                *lanes_mut::<L, T>(&mut scratch.ys, row) = ys_prev;
                *lanes_mut::<L, T>(&mut scratch.k, row) = k;
            }
        };
    }
    match (terms.forcing.is_some(), exact) {
        (true, true) => forward_rows!(true, true),
        (true, false) => forward_rows!(true, false),
        (false, true) => forward_rows!(false, true),
        (false, false) => forward_rows!(false, false),
    }
    for l in 0..L {
        if nonfinite[l] != T::Flag::default() {
            report[l].hard = find_hard_failure(terms, law, n, l, t[l], h[l], gaps_in);
        }
    }

    // Back sweep from the right wall (u_N = 0): velocities, the rate of gap i+1 and its update
    // ln d' = ln d + h r, and the sum of the new gaps (for the projection). Log-stored
    // gaps and gaps that leave [GAP_FLOOR, inf) are redone by the fix-up below (rare), from the rate
    // left in `ls`.
    let mut needs_fixup = [T::Flag::default(); L];
    // The largest h r of a gap stored as d (for the energy's certificate), and of one whose new
    // value is not negligible (the MAX_OPENING safeguard, see NEGLIGIBLE_OPENING).
    let mut opening = [zero; L];
    let mut overshoot = [zero; L];
    let negligible: [T; L] = std::array::from_fn(|l| T::c(NEGLIGIBLE_OPENING * terms.total_gap[l]));
    let mut closing = [T::NEG_INFINITY; L];
    // The new gaps' sum, for the projection: in f64 in either precision (see `conclude_impl`).
    let mut sum = [0.0f64; L];
    let mut u_next = [zero; L];
    let gamma2: [T; L] = std::array::from_fn(|l| -((law.gamma)(l) + T::c(2.0)));
    let taylor = T::c(GAP_EXP_TAYLOR);
    let fast_max = T::c(EXP_FAST_MAX);
    // Whether d·e^x is the update (else the fix-up redoes it in log form); NaN fails.
    let fast = |grown: T, x: T| grown >= floor && grown < T::INFINITY && x <= fast_max;
    // f64 sums the new gaps inside the row's lane loop (measured: 7 % faster than a loop of its
    // own at 256 × N = 1000), f32 after it; the same sums in the same order either way.
    let sum_inline = T::IS_F64;
    // Gaps i_top..1 are left to the loop over rows below.
    let mut i_top = n - 1;
    if L == 1 {
        // One lane: gaps in groups of four (the CPU's SIMD width, in place of lanes), so that
        // all but the velocity recurrence runs in SIMD registers across gaps. The same
        // operations per gap as the loop below, and the sum in the same order.
        const W: usize = 4;
        let (h0, gamma0, negligible0) = (h[0], gamma2[0], negligible[0]);
        let mut open_w = [zero; W];
        let mut over_w = [zero; W];
        let mut close_w = [T::NEG_INFINITY; W];
        let mut fixup_w = [T::Flag::default(); W];
        let mut un = u_next[0];
        while i_top >= W {
            // Gaps lo..=i_top, rows lo-1..i_top-1 (element i of the lane at i).
            let lo = i_top + 1 - W;
            let old: [T; W] = gaps_in[lo..lo + W].try_into().unwrap();
            let bonded: [bool; W] = if CLU {
                inputs.bonded[lo..lo + W].try_into().unwrap()
            } else {
                [false; W]
            };
            let w: [T; W] = scratch.w[lo - 1..lo - 1 + W].try_into().unwrap();
            let ys: [T; W] = scratch.ys[lo - 1..lo - 1 + W].try_into().unwrap();
            let ls: [T; W] = scratch.ls[lo - 1..lo - 1 + W].try_into().unwrap();
            let k: [T; W] = scratch.k[lo - 1..lo - 1 + W].try_into().unwrap();
            let mut u = [zero; W];
            let mut u_right = [zero; W];
            for j in (0..W).rev() {
                u_right[j] = un;
                let d = fmax(old[j], floor);
                u[j] = d * ys[j] + w[j] * un;
                if CLU && bonded[j] {
                    u[j] = un;
                }
                un = u[j];
            }
            let mut rates = [zero; W];
            let mut x = [zero; W];
            let mut small = flag(true);
            for j in 0..W {
                rates[j] = (ls[j] * u_right[j] - ys[j]) * k[j];
                x[j] = h0 * rates[j];
                small &= flag(x[j].abs() < taylor);
            }
            let e = exp_row(&x, small);
            let mut grown = [zero; W];
            for j in 0..W {
                grown[j] = old[j] * e[j];
                if old[j] > zero {
                    open_w[j] = fmax(x[j], open_w[j]);
                }
                // A log-stored gap (old <= 0) has grown <= 0 here, so it never counts.
                if grown[j] > negligible0 {
                    over_w[j] = fmax(x[j], over_w[j]);
                }
                let d = fmax(old[j], floor);
                close_w[j] = fmax(d * (gamma0 * fmin(x[j], zero) - T::ONE), close_w[j]);
                fixup_w[j] |= flag(!fast(grown[j], x[j]));
            }
            for j in (0..W).rev() {
                sum[0] += fmax(grown[j], zero).to_f64();
            }
            vel_out[lo - 1..lo - 1 + W].copy_from_slice(&u);
            scratch.ls[lo - 1..lo - 1 + W].copy_from_slice(&rates);
            gaps_out[lo..lo + W].copy_from_slice(&grown);
            i_top -= W;
        }
        u_next[0] = un;
        // max and | do not depend on the order.
        for j in 0..W {
            opening[0] = fmax(open_w[j], opening[0]);
            overshoot[0] = fmax(over_w[j], overshoot[0]);
            closing[0] = fmax(close_w[j], closing[0]);
            needs_fixup[0] |= fixup_w[j];
        }
    }
    for i in (1..=i_top).rev() {
        let row = (i - 1) * L;
        let gap = i * L;
        let old = *lanes::<L, T>(gaps_in, gap);
        let (_, bonded) = inputs.row::<L, CLU>(gap);
        let w = *lanes::<L, T>(&scratch.w, row);
        let ys = *lanes::<L, T>(&scratch.ys, row);
        let ls = *lanes::<L, T>(&scratch.ls, row);
        let k = *lanes::<L, T>(&scratch.k, row);
        let mut rates = [zero; L];
        let mut x = [zero; L];
        let mut small = flag(true);
        for l in 0..L {
            let d = fmax(old[l], floor);
            let mut u = d * ys[l] + w[l] * u_next[l];
            if CLU && bonded[l] {
                // Exactly the velocity of the body it is bonded to (the penalty gives it to
                // ~1e-250).
                u = u_next[l];
            }
            let rate = (ls[l] * u_next[l] - ys[l]) * k[l];
            x[l] = h[l] * rate;
            small &= flag(x[l].abs() < taylor);
            rates[l] = rate;
            u_next[l] = u;
        }
        *lanes_mut::<L, T>(vel_out, row) = u_next;
        *lanes_mut::<L, T>(&mut scratch.ls, row) = rates;
        let e = exp_row(&x, small);
        let mut grown_row = [zero; L];
        for l in 0..L {
            let grown = old[l] * e[l];
            grown_row[l] = grown;
            if sum_inline {
                sum[l] += fmax(grown, zero).to_f64();
            }
            if old[l] > zero {
                opening[l] = fmax(x[l], opening[l]);
            }
            if grown > negligible[l] {
                overshoot[l] = fmax(x[l], overshoot[l]);
            }
            let d = fmax(old[l], floor);
            closing[l] = fmax(d * (gamma2[l] * fmin(x[l], zero) - T::ONE), closing[l]);
            // NaN fails the comparisons.
            needs_fixup[l] |= flag(!fast(grown, x[l]));
        }
        if !sum_inline {
            // A loop of its own in f32: the f64 sum would narrow the loop above to f64's width.
            for l in 0..L {
                sum[l] += fmax(grown_row[l], zero).to_f64();
            }
        }
        *lanes_mut::<L, T>(gaps_out, gap) = grown_row;
    }
    if CLU {
        if let Some(bonded) = terms.bonded {
            // Bodies glued to the left wall do not move, exactly.
            for l in 0..L {
                for i in 0..n - 1 {
                    if !bonded[i * L + l] {
                        break;
                    }
                    vel_out[i * L + l] = zero;
                }
            }
        }
    }
    let mut rate_first = [zero; L];
    for l in 0..L {
        let old = gaps_in[l];
        let rate = u_next[l] / fmax(old, floor) * k_first[l];
        let x = h[l] * rate;
        let grown = old * gap_exp(x);
        gaps_out[l] = grown;
        rate_first[l] = rate;
        sum[l] += fmax(grown, zero).to_f64();
        if old > zero {
            opening[l] = fmax(x, opening[l]);
        }
        if grown > negligible[l] {
            overshoot[l] = fmax(x, overshoot[l]);
        }
        let d = fmax(old, floor);
        closing[l] = fmax(d * (gamma2[l] * fmin(x, zero) - T::ONE), closing[l]);
        needs_fixup[l] |= flag(!fast(grown, x));
    }

    for l in 0..L {
        if needs_fixup[l] != T::Flag::default() {
            fix_up_lane::<T, L>(
                terms,
                n,
                l,
                h[l],
                gaps_in,
                gaps_out,
                &scratch.ls,
                rate_first[l],
            );
            sum[l] = lane_sum::<T, L>(n, l, gaps_out);
        }
        report[l].admissible &= overshoot[l] <= T::c(MAX_OPENING);
        report[l].certified = needs_fixup[l] == T::Flag::default()
            && energy_certified(
                REP,
                exact,
                closing[l].to_f64(),
                opening[l].to_f64(),
                (T::c(2.0) * eps).to_f64(),
                terms.contact_repulsion[l],
                (terms.mu[l] / h[l]).to_f64(),
            );
    }
    let force = terms.forcing.is_some().then_some(scratch.force.as_slice());
    conclude_impl::<T, L, REP, CLU, P, Q>(
        terms,
        n,
        h,
        sum,
        gaps_out,
        vel_out,
        force,
        &mut report,
        law,
    );
    report
}

/// Whether a linearly implicit Euler step (with the update e^{h r} and the projection) provably
/// did not raise the energy beyond the forcing's work, from two numbers the back sweep keeps per
/// lane. With x_i = h r_i, D_i = d_i x_i (the linear gap change), k_i = Phi_i''(d_i) and
/// e_i = d_i (e^{x_i} - 1 - x_i) >= 0 (what the update adds beyond D_i; the projection removes
/// their sum again):
///   E' - E - W <= sum_i (R_i - k_i D_i^2/2) + (e^{max(x, 0)} G_max/2 - mu/h) sum_i d_i x_i^2,
/// where R_i is the Taylor remainder of Phi_i beyond second order over D_i (the scheme's own
/// balance gives -mu/h sum d x^2 - sum k D^2/2, the projection at most G_max sum e_i, and
/// sum e_i <= e^{max x} sum d x^2/2). The third derivative of Phi is negative, so R_i <= 0 for
/// an opening gap, and R_i <= k_i D_i^2/2 for a closing one when
/// (gamma + 1)|D_i| <= d_i + D_i + 2eps, i.e. when
/// `closing` = max_i d_i ((gamma + 2)(-x_i) - 1) <= 2eps; the second term is <= 0 when
/// e^{max x} G_max/2 <= mu/h, with G_max bounded by the contact repulsion. A mild step
/// is certified and skips the potential energy; any other is checked by computing E'.
/// The bound is proved for the frozen matrix (`exact_jacobian` false: the factor of
/// [`jacobian_factor`], here kappa_i, is 1): with kappa_i != 1 the step's energy balance has a
/// term G d x h r(0) of either sign (the velocities do the work h G d r', the gap moves by
/// d x = d h kappa r'), so with repulsion such a step is never certified. Without repulsion the
/// kinetic balance, E' - E - W <= -(mu/h) sum d x^2/kappa, holds for any kappa > 0.
#[inline(always)]
pub fn energy_certified(
    repulsion: bool,
    exact_jacobian: bool,
    closing: f64,
    opening: f64,
    eps2: f64,
    contact_repulsion: f64,
    mu_over_h: f64,
) -> bool {
    if !repulsion {
        // Phi = 0: the kinetic balance alone, E' - E - W <= -mu/h sum d x^2/kappa.
        return true;
    }
    !exact_jacobian
        && closing <= eps2
        && 0.5 * f64_math::exp(opening.max(0.0)) * contact_repulsion <= mu_over_h
}

/// The hard failure of a lane whose forward sweep met a non-finite G or F (outside the hot loop).
fn find_hard_failure<T: Real, const L: usize, P, Q>(
    terms: &Terms<L, T>,
    law: Law<P, Q>,
    n: usize,
    l: usize,
    t: f64,
    h: T,
    gaps_in: &[T],
) -> Option<HardFailure>
where
    P: Fn(usize, T) -> T + Copy,
    Q: Fn(usize) -> T + Copy,
{
    let eps = terms.eps;
    let mut q = T::ZERO;
    for i in 0..n {
        let k = i * L + l;
        if i > 0 {
            if let Some(forcing) = terms.forcing {
                // The forward sweep's q and F, operation for operation.
                q += gaps_in[(i - 1) * L + l].decode_stored() + T::c(2.0) * eps;
                let f = T::c(particle_force(
                    forcing,
                    terms.forcing_params[l],
                    eps.to_f64(),
                    t,
                    q.to_f64(),
                ));
                if !f.is_finite() {
                    return Some(HardFailure::Forcing {
                        particle: i,
                        x: q.to_f64(),
                    });
                }
            }
        }
        if let Some((dstar, _)) = terms.repulsion {
            if terms.bonded.is_none_or(|b| !b[k]) {
                let eps2 = T::c(2.0) * eps;
                let (_, g, d, _) = gap_terms::<T, true, false, P, Q>(
                    law,
                    l,
                    terms.mu[l],
                    eps2,
                    reciprocal_scale(eps2),
                    gaps_in[k],
                    dstar[k],
                    false,
                    h,
                );
                if !g.is_finite() {
                    return Some(repulsion_failure(terms, i, k, d));
                }
            }
        }
    }
    None
}

/// The sum of lane l's gaps (in the back sweep's order: from the last gap down).
fn lane_sum<T: Real, const L: usize>(n: usize, l: usize, gaps: &[T]) -> f64 {
    let mut sum = 0.0;
    for i in (0..n).rev() {
        sum += gaps[i * L + l].max_real(T::ZERO).to_f64();
    }
    sum
}

/// Redoes the update of one lane's gaps in log form where the fast form d·e^{hr} does not apply
/// (a log-stored gap, or a result outside [GAP_FLOOR, inf)).
#[allow(clippy::too_many_arguments)]
fn fix_up_lane<T: Real, const L: usize>(
    terms: &Terms<L, T>,
    n: usize,
    l: usize,
    h: T,
    gaps_in: &[T],
    gaps_out: &mut [T],
    rates: &[T],
    rate_first: T,
) {
    for i in 0..n {
        let k = i * L + l;
        if terms.bonded.is_some_and(|b| b[k]) {
            gaps_out[k] = T::ZERO;
            continue;
        }
        let rate = if i == 0 {
            rate_first
        } else {
            rates[(i - 1) * L + l]
        };
        gaps_out[k] = fixed_up(gaps_in[k], h * rate, gaps_out[k]);
    }
}

/// A free gap's stored value after the update to `grown` = old·e^x: kept, or redone in log form
/// where the fast form does not apply (a log-stored gap, or a result outside [GAP_FLOOR, inf)).
#[inline(always)]
fn fixed_up<T: Real>(old: T, x: T, grown: T) -> T {
    if grown >= T::GAP_FLOOR && grown < T::INFINITY && x <= T::c(EXP_FAST_MAX) && old > T::ZERO {
        grown
    } else {
        encode_ln_gap(stored_ln(old) + x)
    }
}

/// Shifts the log-stored gaps of the lanes that have some by ln(scale) (outside the hot loop:
/// rare).
fn shift_logged<T: Real, const L: usize>(
    n: usize,
    scale: &[f64; L],
    logged: &[T::Flag; L],
    gaps: &mut [T],
) {
    for l in 0..L {
        if logged[l] != T::Flag::default() {
            let shift = T::c(f64_math::ln(scale[l]));
            for i in 0..n {
                let k = i * L + l;
                if gaps[k] < T::ZERO {
                    gaps[k] += shift;
                }
            }
        }
    }
}

/// Ends a step: scales every lane's gaps so that their sum is the lane's total again (the
/// projection; log-stored gaps are shifted by the log of the factor) and reports the energy of
/// the result and, given the forces F, the work h Σ u_i' F_i. Non-finite gaps make the lane
/// inadmissible.
pub fn conclude<T: Real, const L: usize>(
    terms: &Terms<L, T>,
    n: usize,
    h: &[T; L],
    gaps: &mut [T],
    vel: &[T],
    report: &mut [StepReport; L],
) {
    let mut total = [0.0f64; L];
    for (l, t) in total.iter_mut().enumerate() {
        *t = lane_sum::<T, L>(n, l, gaps);
    }
    specialised!(
        T,
        terms,
        conclude_simd,
        (terms.simd, terms, n, h, total, gaps, vel, None, report)
    )
}

simd_versions!(conclude_simd, conclude_avx2, conclude_avx512, conclude_impl, (
    terms: &Terms<L, T>,
    n: usize,
    h: &[T; L],
    sum: [f64; L],
    gaps: &mut [T],
    vel: &[T],
    force: Option<&[T]>,
    report: &mut [StepReport; L]
) -> ());

#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn conclude_impl<T: Real, const L: usize, const REP: bool, const CLU: bool, P, Q>(
    terms: &Terms<L, T>,
    n: usize,
    h: &[T; L],
    sum: [f64; L],
    gaps: &mut [T],
    vel: &[T],
    force: Option<&[T]>,
    report: &mut [StepReport; L],
    law: Law<P, Q>,
) where
    P: Fn(usize, T) -> T + Copy,
    Q: Fn(usize) -> T + Copy,
{
    assert_eq!(gaps.len(), n * L);
    let zero = T::ZERO;
    let eps2 = T::c(2.0) * terms.eps;
    // The sum, the scale and the sums of the energy in f64 in either precision: in f32 a scale
    // with the rounding of a sum of N gaps (sqrt(N) ulps) moves every gap by as much, and G by
    // gamma times that (~1e-3 at gamma = 1000, N = 200: measured, steps of every size were then
    // rejected by the energy check, down to dt_min). From the f64 sum, scale − 1 is below half
    // an ulp after a projection, so the projected gaps are a fixed point of the next one and a
    // vanishing step changes nothing. (`Real::scaled` applies the scale in f32 registers.)
    let mut scale = [1.0f64; L];
    let mut delta = [zero; L];
    for l in 0..L {
        scale[l] = terms.total_gap[l] / sum[l];
        delta[l] = T::c(scale[l] - 1.0);
    }
    // 0/1 flags in lanes as wide as T, as in the sweep.
    let flag = T::Flag::from;
    let mut logged = [T::Flag::default(); L];
    let mut nonfinite = [T::Flag::default(); L];
    let mut work = [0.0f64; L];
    let skip_energy = match terms.energy {
        EnergyWanted::No => true,
        EnergyWanted::UnlessCertified => report.iter().all(|r| r.certified),
        EnergyWanted::Always => false,
    };
    if skip_energy {
        // Only the projection (and the forcing's work, which a later energy check of a
        // Richardson step or of a tableau's row adds up): no lane needs its energy.
        // Whole rows from chunks_exact: no per-row check, so that L = 1 vectorises over rows.
        for row in gaps.chunks_exact_mut(L) {
            for l in 0..L {
                let v = row[l];
                logged[l] |= flag(v < zero);
                nonfinite[l] |= flag(!v.is_finite());
                row[l] = if v > zero {
                    v.scaled(scale[l], delta[l])
                } else {
                    v
                };
            }
        }
        if let Some(f) = force {
            for (u, f) in vel.chunks_exact(L).zip(f.chunks_exact(L)) {
                for l in 0..L {
                    work[l] += (u[l] * f[l]).to_f64();
                }
            }
        }
        shift_logged::<T, L>(n, &scale, &logged, gaps);
        for l in 0..L {
            report[l].admissible &= nonfinite[l] == T::Flag::default();
            report[l].energy = -1.0;
            report[l].work = h[l].to_f64() * work[l];
        }
        return;
    }
    let dstar_all: &[T] = terms.repulsion.map_or(&[], |r| r.0);
    let bonded_all: &[bool] = terms.bonded.unwrap_or(&[]);
    let mut potential = [0.0f64; L];
    let mut kinetic = [0.0f64; L];
    for i in 0..n {
        let k = i * L;
        let dstar = if REP {
            *lanes::<L, T>(dstar_all, k)
        } else {
            [zero; L]
        };
        let bonded = if CLU {
            *lanes::<L, bool>(bonded_all, k)
        } else {
            [false; L]
        };
        let row = lanes_mut::<L, T>(gaps, k);
        for l in 0..L {
            let v = row[l];
            let scaled = v.scaled(scale[l], delta[l]);
            logged[l] |= flag(v < zero);
            nonfinite[l] |= flag(!v.is_finite());
            row[l] = if v > zero { scaled } else { v };
            let phi = potential_of::<T, REP, P, Q>(law, l, eps2, dstar[l], scaled.max_real(zero));
            if !bonded[l] {
                potential[l] += phi.to_f64();
            }
        }
        if i + 1 < n {
            let u = lanes::<L, T>(vel, k);
            for l in 0..L {
                kinetic[l] += (u[l] * u[l]).to_f64();
            }
            if let Some(f) = force {
                let f = lanes::<L, T>(f, k);
                for l in 0..L {
                    work[l] += (u[l] * f[l]).to_f64();
                }
            }
        }
    }
    shift_logged::<T, L>(n, &scale, &logged, gaps);
    for l in 0..L {
        report[l].admissible &= nonfinite[l] == T::Flag::default();
        report[l].energy = potential[l] + terms.eps.to_f64() * kinetic[l];
        report[l].work = h[l].to_f64() * work[l];
        report[l].admissible &= report[l].energy.is_finite();
        report[l].certified = false;
    }
}

// After the macros above, which it uses.
mod partitioned;

#[cfg(test)]
mod tests;
