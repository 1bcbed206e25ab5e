//! One member with a huge chain: the step's tridiagonal solve split into segments solved side
//! by side (a partitioned, SPIKE-style Thomas algorithm).
//!
//! Why: a single member's sequential sweep is bound by the latency of its row-to-row dependency
//! (a division per row), and a block of one lane has no other lanes to fill the SIMD registers or
//! the other cores. Splitting the rows into P independent segments gives P sweeps to run as the
//! lanes of the usual lane loop (SIMD across segments) and in parallel (rayon across groups of
//! segments), so one member at N = 10^6 runs near the batched rate.
//!
//! How. The rows 1..n-1 are cut into P = G·S segments (S lanes per group, G groups), all m rows
//! long except segment 0, which also takes the r = (n-1) mod P rows left over (swept alone
//! before and after its group: the prologue). Segment s, rows [b, e), is swept forward exactly as
//! the sequential sweep does, but not from the state its left neighbour would hand it: it starts
//! from the rate of its first gap, tau = r_b = (u_b - u_{b-1})/d_b, as an unknown (ls = 0,
//! ys = -tau). The rows' ys are then affine in tau, ys_i = ys0_i + z_i tau (the spike z is swept
//! along; segment 0 starts from the wall and has none), and the sweep also accumulates the
//! segment's first velocity as u_b = A + B u_e + C tau. Per segment, the end of the sweep gives
//!   tau_{s+1} = ls_{e-1} u_e - ys0_{e-1} - z_{e-1} tau_s   (the rate of the next segment's first gap)
//!   u_b = A + B u_e + C tau_s,
//! a small system in the 2P interface values (tau_s, u_{b_s}) that is itself swept like a Thomas
//! system: left to right carrying tau_s = Lc u_{b_s} - Yc (the sequential sweep's state at the
//! interface), right to left from the wall. Its pivots 1 - Lc C are >= 1 (Lc >= 0, C <= 0) and
//! Lc stays >= 0: no cancellation. The back-substitution of each segment from its tau and right
//! neighbour's first velocity is then the sequential back sweep (velocities, rate form of the
//! gap update, flags for the energy certificate, sum of the new gaps), again side by side.
//!
//! The interface carries a rate, not a velocity: near contact (d below GAP_FLOOR) the rate is
//! O(1) while u_b - u_{b-1} is below rounding, so a velocity interface would lose the rate of a
//! gap at a segment boundary; this one computes every rate as the sequential sweep does. The
//! results equal the sequential sweep's up to rounding (tested to 1e-12 relative, clusters and
//! log-stored gaps included); the segments depend on n only, and per-segment sums are added in a
//! fixed order, so the result does not depend on the thread count.
//!
//! Layout of the sweep scratch (w, ls, ys, spike, length n-1): the prologue's rows at row - 1,
//! then per group its S segments interleaved (local row k of lane l at k·S + l), so that the
//! lane loops read and write whole rows; gaps and velocities keep their natural layout (gathered
//! and scattered per row). The rest of the step (hard-failure lookup, log-gap fix-up,
//! certificate, projection and energy) is the sequential path's code.

use rayon::prelude::*;

use super::{
    energy_certified, find_hard_failure, fix_up_lane, fmax, fmin, gap_exp, gap_terms,
    particle_force, Law, Scratch, SimdLevel, StepReport, Terms, EXP_FAST_MAX, GAP_EXP_TAYLOR,
    GAP_FLOOR, MAX_OPENING,
};
use crate::model::chain::stored_gap;

/// Segments per group: the lanes of the partitioned lane loops (as many as the batched blocks,
/// to keep several divisions in flight per core).
pub(crate) const SEGMENT_LANES: usize = 16;
/// Chains of fewer particles keep the sequential sweep (measured: see `benches/cpu_solver.rs`).
pub(crate) const PARTITION_MIN_PARTICLES: usize = 1 << 14;
/// Rows per segment the default layout aims at (at least), and its largest number of groups
/// (enough to share out over many cores; more only adds interfaces).
const SEGMENT_ROWS: usize = 512;
const MAX_GROUPS: usize = 16;
/// Spike coefficients and the running product of w are set to 0 below this: their terms are
/// then far below rounding, and letting them decay through the subnormals would cost a
/// microcode assist per operation.
const TINY: f64 = 1e-140;

/// How the rows of a chain are cut: `groups` groups of SEGMENT_LANES segments of `seg` rows,
/// segment 0 with `rem` more rows in front.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Layout {
    groups: usize,
    seg: usize,
    rem: usize,
}

impl Layout {
    /// `groups` groups for a chain of n particles; None if a segment would have no row.
    pub(crate) fn new(n: usize, groups: usize) -> Option<Layout> {
        let rows = n.checked_sub(1)?;
        let p = groups * SEGMENT_LANES;
        if groups == 0 || rows < p {
            return None;
        }
        let seg = rows / p;
        Some(Layout {
            groups,
            seg,
            rem: rows - p * seg,
        })
    }

    /// The layout a step of a one-member block with n particles uses, None for the sequential
    /// sweep: below PARTITION_MIN_PARTICLES, or with `ROUGHLUB_CPU_PARTITION=off`. Depends on n
    /// only (never on the thread count).
    pub(crate) fn for_chain(n: usize) -> Option<Layout> {
        static OFF: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
        let off =
            *OFF.get_or_init(|| std::env::var("ROUGHLUB_CPU_PARTITION").is_ok_and(|v| v == "off"));
        if off || n < PARTITION_MIN_PARTICLES {
            return None;
        }
        let groups = ((n - 1) / (SEGMENT_LANES * SEGMENT_ROWS)).clamp(1, MAX_GROUPS);
        Layout::new(n, groups)
    }

    fn segments(&self) -> usize {
        self.groups * SEGMENT_LANES
    }

    /// Scratch index (= row - 1) where group g's main rows start; group 0's chunk also holds the
    /// prologue's rem rows before it.
    fn main_start(&self, g: usize) -> usize {
        self.rem + g * SEGMENT_LANES * self.seg
    }

    /// Scratch (and velocity) index range of group g: the chunks split the scratch, the
    /// velocities and (shifted by one) the gaps 1..n among the groups.
    fn chunk(&self, g: usize) -> std::ops::Range<usize> {
        let start = if g == 0 { 0 } else { self.main_start(g) };
        start..self.main_start(g + 1)
    }

    /// Segment s's first row (s >= 1; segment 0 starts at row 1).
    fn first_row(&self, s: usize) -> usize {
        1 + self.rem + s * self.seg
    }

    /// `s` cut at the chunks (read only).
    fn chunk_slices<'a>(&self, s: &'a [f64]) -> Vec<&'a [f64]> {
        (0..self.groups).map(|g| &s[self.chunk(g)]).collect()
    }

    /// Scratch index of row `row` (1-based).
    fn index_of(&self, row: usize) -> usize {
        let i = row - 1;
        if i < self.rem {
            return i;
        }
        let j = i - self.rem;
        let per_group = SEGMENT_LANES * self.seg;
        let (g, within) = (j / per_group, j % per_group);
        let (l, k) = (within / self.seg, within % self.seg);
        self.main_start(g) + k * SEGMENT_LANES + l
    }
}

/// `s` cut at the chunks of `layout` (of the slice's own first `offset` elements, which go
/// nowhere).
fn split_chunks<'a, T>(layout: &Layout, s: &'a mut [T], offset: usize) -> Vec<&'a mut [T]> {
    let mut rest = &mut s[offset..];
    let mut out = Vec::with_capacity(layout.groups);
    for g in 0..layout.groups {
        let (head, tail) = std::mem::take(&mut rest).split_at_mut(layout.chunk(g).len());
        out.push(head);
        rest = tail;
    }
    out
}

/// Values at base, base + stride, …: one bounds check for the row, none per lane.
#[inline(always)]
fn gather<const S: usize, T: Copy>(src: &[T], base: usize, stride: usize) -> [T; S] {
    assert!(base + (S - 1) * stride < src.len());
    // SAFETY: every index is at most base + (S-1)·stride, checked above.
    std::array::from_fn(|l| unsafe { *src.get_unchecked(base + l * stride) })
}

#[inline(always)]
fn scatter<const S: usize, T: Copy>(dst: &mut [T], base: usize, stride: usize, v: &[T; S]) {
    assert!(base + (S - 1) * stride < dst.len());
    for (l, x) in v.iter().enumerate() {
        // SAFETY: as in `gather`.
        unsafe { *dst.get_unchecked_mut(base + l * stride) = *x };
    }
}

/// The forward sweep's state of S segments.
#[derive(Clone, Copy)]
struct Sweep<const S: usize> {
    a_prev: [f64; S],
    g_prev: [f64; S],
    ls_prev: [f64; S],
    ys_prev: [f64; S],
    /// d ys/d tau of the previous row.
    z_prev: [f64; S],
    /// Running product of w from the segment's first row (the weight of u_{i} in u_b).
    pi: [f64; S],
    /// u_b = acc_a + pi·u_e + acc_c·tau.
    acc_a: [f64; S],
    acc_c: [f64; S],
    nonfinite: [u64; S],
    /// Position of the last particle swept (forcing only).
    q: [f64; S],
}

/// The end of one segment's forward sweep (see the module doc).
#[derive(Clone, Copy, Default, Debug)]
struct SegmentEnd {
    ls: f64,
    ys: f64,
    z: f64,
    a: f64,
    b: f64,
    c: f64,
}

/// Constants of one step.
#[derive(Clone, Copy)]
struct Step {
    mu: f64,
    eps: f64,
    h: f64,
    t: f64,
    m_over_h: f64,
}

/// One row of the forward sweep for S segments: the sequential sweep's operations, plus the
/// spike and the accumulation of u_b. Returns (w, z) of the row; ls, ys are left in the state.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn forward_row<const S: usize, const REP: bool, const CLU: bool, P, Q>(
    law: Law<P, Q>,
    c: Step,
    st: &mut Sweep<S>,
    stored: &[f64; S],
    dstar: &[f64; S],
    bonded: &[bool; S],
    vel: &[f64; S],
    f: &[f64; S],
) -> ([f64; S], [f64; S])
where
    P: Fn(usize, f64) -> f64 + Copy,
    Q: Fn(usize) -> f64 + Copy,
{
    let eps2 = 2.0 * c.eps;
    let mut w = [0.0; S];
    let mut zs = [0.0; S];
    for l in 0..S {
        let (a_next, g_next, d_next) =
            gap_terms::<REP, CLU, P, Q>(law, 0, c.mu, eps2, stored[l], dstar[l], bonded[l], c.h);
        st.nonfinite[l] |= !(g_next + f[l]).is_finite() as u64;
        let rhs = c.m_over_h * vel[l] + st.g_prev[l] - g_next + f[l];
        // As in the sequential sweep (step.rs), operation for operation.
        let excess = c.m_over_h + st.a_prev[l] * st.ls_prev[l];
        let delta = rhs + st.a_prev[l] * st.ys_prev[l];
        let pivot_base = c.m_over_h * d_next + a_next;
        let coupling = st.a_prev[l] * d_next;
        let inv = 1.0 / (pivot_base + coupling * st.ls_prev[l]);
        let ls = excess * inv;
        let ys = delta * inv;
        let z = st.a_prev[l] * st.z_prev[l] * inv;
        // z <= 0; flushed to 0 once negligible (NaN is kept).
        let z = if z > -TINY { 0.0 } else { z };
        w[l] = a_next * inv;
        zs[l] = z;
        st.acc_a[l] += st.pi[l] * (d_next * ys);
        st.acc_c[l] += st.pi[l] * (d_next * z);
        let pi = st.pi[l] * w[l];
        st.pi[l] = if pi < TINY { 0.0 } else { pi };
        st.ls_prev[l] = ls;
        st.ys_prev[l] = ys;
        st.z_prev[l] = z;
        st.a_prev[l] = a_next;
        st.g_prev[l] = g_next;
    }
    (w, zs)
}

/// Forcing of one row of S segments (rows `row0 + l·stride`): interpreted, so not in the lane
/// loop. Writes F to `force` (natural layout, index row - 1 - `force_at`).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn forces<const S: usize, const L: usize>(
    terms: &Terms<L>,
    c: Step,
    st: &mut Sweep<S>,
    gaps_in: &[f64],
    row0: usize,
    stride: usize,
    force: &mut [f64],
    force_at: usize,
) -> [f64; S] {
    let mut f = [0.0; S];
    if let Some(forcing) = terms.forcing {
        for l in 0..S {
            let row = row0 + l * stride;
            st.q[l] += stored_gap::decode(gaps_in[row - 1]) + 2.0 * c.eps;
            f[l] = particle_force(forcing, terms.forcing_params[0], c.eps, c.t, st.q[l]);
            force[row - 1 - force_at] = f[l];
        }
    }
    f
}

/// Group g's chunks of the scratch arrays (natural layout for `force`).
struct Chunks<'a> {
    w: &'a mut [f64],
    ls: &'a mut [f64],
    ys: &'a mut [f64],
    z: &'a mut [f64],
    force: &'a mut [f64],
}

/// What a group's forward sweep hands to the interface solve.
struct GroupEnd {
    ends: [SegmentEnd; SEGMENT_LANES],
    nonfinite: u64,
}

simd_versions!(forward_group_simd, forward_group_avx2, forward_group_impl, (
    terms: &Terms<L>,
    layout: &Layout,
    g: usize,
    c: Step,
    q_start: &[f64],
    inputs: &(&[f64], &[f64], &[bool], &[f64]),
    out: Chunks<'_>
) -> GroupEnd);

/// Forward sweep of group g's segments (and of the prologue, for group 0). `inputs` are the
/// gaps, d*, bonded flags and velocities (natural layout; d* and bonded only where they exist);
/// `q_start` the position of each segment's particle b - 1 (forcing only).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn forward_group_impl<const L: usize, const REP: bool, const FRC: bool, const CLU: bool, P, Q>(
    terms: &Terms<L>,
    layout: &Layout,
    g: usize,
    c: Step,
    q_start: &[f64],
    inputs: &(&[f64], &[f64], &[bool], &[f64]),
    out: Chunks,
    law: Law<P, Q>,
) -> GroupEnd
where
    P: Fn(usize, f64) -> f64 + Copy,
    Q: Fn(usize) -> f64 + Copy,
{
    const S: usize = SEGMENT_LANES;
    let (gaps_in, dstar_all, bonded_all, vel_in) = *inputs;
    let m = layout.seg;
    let chunk_at = layout.chunk(g).start;
    let main = layout.main_start(g);
    let off = main - chunk_at;
    let eps2 = 2.0 * c.eps;
    let dstar_of = |at: usize, stride: usize| -> [f64; S] {
        if REP {
            gather::<S, f64>(dstar_all, at, stride)
        } else {
            [0.0; S]
        }
    };
    let bonded_of = |at: usize, stride: usize| -> [bool; S] {
        if CLU {
            gather::<S, bool>(bonded_all, at, stride)
        } else {
            [false; S]
        }
    };
    // Each segment starts from the unknown rate of its first gap (index main + l·m): ls = 0,
    // ys = -tau, i.e. ys0 = 0 and z = -1.
    let mut st = Sweep::<S> {
        a_prev: [0.0; S],
        g_prev: [0.0; S],
        ls_prev: [0.0; S],
        ys_prev: [0.0; S],
        z_prev: [-1.0; S],
        pi: [1.0; S],
        acc_a: [0.0; S],
        acc_c: [0.0; S],
        nonfinite: [0; S],
        q: [0.0; S],
    };
    {
        let stored = gather::<S, f64>(gaps_in, main, m);
        let dstar = dstar_of(main, m);
        let bonded = bonded_of(main, m);
        for l in 0..S {
            let (a, gg, _) = gap_terms::<REP, CLU, P, Q>(
                law, 0, c.mu, eps2, stored[l], dstar[l], bonded[l], c.h,
            );
            st.a_prev[l] = a;
            st.g_prev[l] = gg;
        }
        if FRC {
            st.q.copy_from_slice(&q_start[g * S..(g + 1) * S]);
        }
    }
    if g == 0 {
        // Segment 0 starts from the left wall (lambda_0 = 1: ls_0 = 1/d_1, ys_0 = 0, no spike),
        // as the sequential sweep does, and sweeps the prologue's rows alone.
        let mut s0 = Sweep::<1> {
            a_prev: [0.0],
            g_prev: [0.0],
            ls_prev: [0.0],
            ys_prev: [0.0],
            z_prev: [0.0],
            pi: [1.0],
            acc_a: [0.0],
            acc_c: [0.0],
            nonfinite: [0],
            q: [0.0],
        };
        let (a, gg, d) = gap_terms::<REP, CLU, P, Q>(
            law,
            0,
            c.mu,
            eps2,
            gaps_in[0],
            if REP { dstar_all[0] } else { 0.0 },
            CLU && bonded_all[0],
            c.h,
        );
        s0.a_prev[0] = a;
        s0.g_prev[0] = gg;
        s0.ls_prev[0] = 1.0 / d;
        s0.nonfinite[0] |= !gg.is_finite() as u64;
        for row in 1..=layout.rem {
            let f = if FRC {
                forces::<1, L>(terms, c, &mut s0, gaps_in, row, 0, out.force, 0)
            } else {
                [0.0]
            };
            let stored = [gaps_in[row]];
            let dstar = [if REP { dstar_all[row] } else { 0.0 }];
            let bonded = [CLU && bonded_all[row]];
            let vel = [vel_in[row - 1]];
            let (w, z) = forward_row::<1, REP, CLU, P, Q>(
                law, c, &mut s0, &stored, &dstar, &bonded, &vel, &f,
            );
            out.w[row - 1] = w[0];
            out.ls[row - 1] = s0.ls_prev[0];
            out.ys[row - 1] = s0.ys_prev[0];
            out.z[row - 1] = z[0];
        }
        st.ls_prev[0] = s0.ls_prev[0];
        st.ys_prev[0] = s0.ys_prev[0];
        st.z_prev[0] = 0.0;
        st.nonfinite[0] |= s0.nonfinite[0];
        st.q[0] = s0.q[0];
    }
    for k in 0..m {
        // Row main + 1 + l·m + k of lane l; its next gap has index main + 1 + l·m + k.
        let row0 = main + 1 + k;
        let f = if FRC {
            forces::<S, L>(terms, c, &mut st, gaps_in, row0, m, out.force, chunk_at)
        } else {
            [0.0; S]
        };
        let stored = gather::<S, f64>(gaps_in, row0, m);
        let dstar = dstar_of(row0, m);
        let bonded = bonded_of(row0, m);
        let vel = gather::<S, f64>(vel_in, row0 - 1, m);
        let (w, z) =
            forward_row::<S, REP, CLU, P, Q>(law, c, &mut st, &stored, &dstar, &bonded, &vel, &f);
        let at = off + k * S;
        out.w[at..at + S].copy_from_slice(&w);
        out.ls[at..at + S].copy_from_slice(&st.ls_prev);
        out.ys[at..at + S].copy_from_slice(&st.ys_prev);
        out.z[at..at + S].copy_from_slice(&z);
    }
    GroupEnd {
        ends: std::array::from_fn(|l| SegmentEnd {
            ls: st.ls_prev[l],
            ys: st.ys_prev[l],
            z: st.z_prev[l],
            a: st.acc_a[l],
            b: st.pi[l],
            c: st.acc_c[l],
        }),
        nonfinite: st.nonfinite.iter().fold(0, |a, b| a | b),
    }
}

/// The back sweep's flags and sums of S segments.
#[derive(Clone, Copy)]
struct Back<const S: usize> {
    u_next: [f64; S],
    tau: [f64; S],
    sum: [f64; S],
    opening: [f64; S],
    closing: [f64; S],
    needs_fixup: [u64; S],
}

/// One row of the back sweep for S segments: the sequential back sweep's operations with
/// ys = ys0 + z·tau. Returns (u, rate, new stored gap) of the row.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn back_row<const S: usize, const CLU: bool>(
    h: f64,
    gamma2: f64,
    st: &mut Back<S>,
    old: &[f64; S],
    bonded: &[bool; S],
    w: &[f64; S],
    ys0: &[f64; S],
    z: &[f64; S],
    ls: &[f64; S],
) -> ([f64; S], [f64; S], [f64; S]) {
    let mut rates = [0.0; S];
    let mut x = [0.0; S];
    let mut small = 1u64;
    for l in 0..S {
        let ys = ys0[l] + z[l] * st.tau[l];
        let d = fmax(old[l], GAP_FLOOR);
        let mut u = d * ys + w[l] * st.u_next[l];
        if CLU && bonded[l] {
            u = st.u_next[l];
        }
        let rate = ls[l] * st.u_next[l] - ys;
        x[l] = h * rate;
        small &= (x[l].abs() < GAP_EXP_TAYLOR) as u64;
        rates[l] = rate;
        st.u_next[l] = u;
    }
    let e = super::exp_row(&x, small);
    let mut grown_row = [0.0; S];
    for l in 0..S {
        let grown = old[l] * e[l];
        grown_row[l] = grown;
        st.sum[l] += fmax(grown, 0.0);
        if old[l] > 0.0 {
            st.opening[l] = fmax(x[l], st.opening[l]);
        }
        let d = fmax(old[l], GAP_FLOOR);
        st.closing[l] = fmax(d * (gamma2 * fmin(x[l], 0.0) - 1.0), st.closing[l]);
        // NaN fails the comparisons.
        st.needs_fixup[l] |=
            !((GAP_FLOOR..f64::INFINITY).contains(&grown) && x[l] <= EXP_FAST_MAX) as u64;
    }
    (st.u_next, rates, grown_row)
}

/// What a group's back sweep hands back: per segment the sum of its new gaps (segment 0's
/// including the prologue's), and the flags.
struct GroupBack {
    sums: [f64; SEGMENT_LANES],
    opening: f64,
    closing: f64,
    needs_fixup: u64,
    /// u_1 (group 0 only).
    u_first: f64,
}

/// Group g's chunks of the outputs (natural layout: velocities of the chunk's rows, the gaps
/// after them).
struct Outputs<'a> {
    vel: &'a mut [f64],
    gaps: &'a mut [f64],
    /// The sweep scratch (the back sweep reads w, ys, z and overwrites ls with the rates).
    w: &'a [f64],
    ls: &'a mut [f64],
    ys: &'a [f64],
    z: &'a [f64],
}

simd_versions!(back_group_simd, back_group_avx2, back_group_impl, (
    terms: &Terms<L>,
    layout: &Layout,
    g: usize,
    h: f64,
    iface: &[(f64, f64)],
    gaps_in: &[f64],
    out: Outputs<'_>
) -> GroupBack);

/// Back sweep of group g's segments (and of the prologue, for group 0): `iface[s]` is segment
/// s's (tau, velocity of the next segment's first row).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn back_group_impl<const L: usize, const REP: bool, const FRC: bool, const CLU: bool, P, Q>(
    terms: &Terms<L>,
    layout: &Layout,
    g: usize,
    h: f64,
    iface: &[(f64, f64)],
    gaps_in: &[f64],
    out: Outputs,
    law: Law<P, Q>,
) -> GroupBack
where
    P: Fn(usize, f64) -> f64 + Copy,
    Q: Fn(usize) -> f64 + Copy,
{
    const S: usize = SEGMENT_LANES;
    let m = layout.seg;
    let chunk_at = layout.chunk(g).start;
    let main = layout.main_start(g);
    let off = main - chunk_at;
    let bonded_all = terms.bonded.unwrap_or(&[]);
    let gamma2 = -((law.gamma)(0) + 2.0);
    let mut st = Back::<S> {
        u_next: std::array::from_fn(|l| iface[g * S + l].1),
        tau: std::array::from_fn(|l| iface[g * S + l].0),
        sum: [0.0; S],
        opening: [0.0; S],
        closing: [f64::NEG_INFINITY; S],
        needs_fixup: [0; S],
    };
    for k in (0..m).rev() {
        let row0 = main + 1 + k;
        let old = gather::<S, f64>(gaps_in, row0, m);
        let bonded = if CLU {
            gather::<S, bool>(bonded_all, row0, m)
        } else {
            [false; S]
        };
        let at = off + k * S;
        let w: &[f64; S] = out.w[at..at + S].try_into().unwrap();
        let ys: &[f64; S] = out.ys[at..at + S].try_into().unwrap();
        let z: &[f64; S] = out.z[at..at + S].try_into().unwrap();
        let ls: &mut [f64; S] = (&mut out.ls[at..at + S]).try_into().unwrap();
        let (u, rates, grown) = back_row::<S, CLU>(h, gamma2, &mut st, &old, &bonded, w, ys, z, ls);
        *ls = rates;
        // Velocity of row r at r - 1 - chunk_at, gap index r at r - 1 - chunk_at of the chunk.
        scatter::<S, f64>(out.vel, row0 - 1 - chunk_at, m, &u);
        scatter::<S, f64>(out.gaps, row0 - 1 - chunk_at, m, &grown);
    }
    let mut u_first = 0.0;
    if g == 0 {
        let mut s0 = Back::<1> {
            u_next: [st.u_next[0]],
            tau: [0.0],
            sum: [st.sum[0]],
            opening: [st.opening[0]],
            closing: [st.closing[0]],
            needs_fixup: [st.needs_fixup[0]],
        };
        for row in (1..=layout.rem).rev() {
            let i = row - 1;
            let old = [gaps_in[row]];
            let bonded = [CLU && bonded_all[row]];
            let (u, rates, grown) = back_row::<1, CLU>(
                h,
                gamma2,
                &mut s0,
                &old,
                &bonded,
                &[out.w[i]],
                &[out.ys[i]],
                &[out.z[i]],
                &[out.ls[i]],
            );
            out.ls[i] = rates[0];
            out.vel[i] = u[0];
            out.gaps[i] = grown[0];
        }
        st.sum[0] = s0.sum[0];
        st.opening[0] = s0.opening[0];
        st.closing[0] = s0.closing[0];
        st.needs_fixup[0] = s0.needs_fixup[0];
        u_first = s0.u_next[0];
    }
    // max and | do not depend on the order.
    GroupBack {
        sums: st.sum,
        opening: st.opening.iter().fold(0.0, |a, &b| fmax(b, a)),
        closing: st
            .closing
            .iter()
            .fold(f64::NEG_INFINITY, |a, &b| fmax(b, a)),
        needs_fixup: st.needs_fixup.iter().fold(0, |a, b| a | b),
        u_first,
    }
}

/// The interface values (tau_s, u of the next segment's first row) of every segment from the
/// segments' forward ends (the reduced system, swept like a Thomas system; see the module doc).
fn interfaces(ends: &[SegmentEnd]) -> Vec<(f64, f64)> {
    let p = ends.len();
    // tau_s = alpha_s + beta_s u_{b_{s+1}}; segment 0 has tau = 0.
    let mut alpha = vec![0.0; p];
    let mut beta = vec![0.0; p];
    // The state at the interface: tau_s = lc·u_{b_s} - yc.
    let (mut lc, mut yc) = (ends[0].ls, ends[0].ys);
    for s in 1..p {
        let e = ends[s];
        let inv = 1.0 / (1.0 - lc * e.c);
        alpha[s] = (lc * e.a - yc) * inv;
        beta[s] = lc * e.b * inv;
        lc = e.ls - e.z * beta[s];
        yc = e.ys + e.z * alpha[s];
    }
    let mut out = vec![(0.0, 0.0); p];
    // The right wall: u_n = 0.
    let mut u_right = 0.0;
    for s in (0..p).rev() {
        let tau = alpha[s] + beta[s] * u_right;
        out[s] = (tau, u_right);
        let e = ends[s];
        u_right = e.a + e.b * u_right + e.c * tau;
    }
    out
}

/// `euler_impl` for a block of one lane (L = 1) with the rows cut as `layout` says: the same
/// step, the tridiagonal solve partitioned (see the module doc).
#[allow(clippy::too_many_arguments)]
pub(super) fn euler_partitioned<
    const L: usize,
    const REP: bool,
    const FRC: bool,
    const CLU: bool,
    P,
    Q,
>(
    simd: SimdLevel,
    terms: &Terms<L>,
    n: usize,
    t: &[f64; L],
    h: &[f64; L],
    gaps_in: &[f64],
    vel_in: &[f64],
    gaps_out: &mut [f64],
    vel_out: &mut [f64],
    scratch: &mut Scratch,
    layout: Layout,
    law: Law<P, Q>,
) -> [StepReport; L]
where
    P: Fn(usize, f64) -> f64 + Copy + Send + Sync,
    Q: Fn(usize) -> f64 + Copy + Send + Sync,
{
    assert_eq!(L, 1, "the partitioned solve is for one member");
    assert_eq!(gaps_in.len(), n);
    assert_eq!(vel_in.len(), n - 1);
    assert_eq!(Layout::new(n, layout.groups), Some(layout));
    let (h0, t0) = (h[0], t[0]);
    let eps = terms.eps;
    let c = Step {
        mu: terms.mu[0],
        eps,
        h: h0,
        t: t0,
        m_over_h: 2.0 * eps / h0,
    };
    let mut report = [StepReport::START; L];
    let p = layout.segments();
    // Positions of each segment's particle b - 1, summed in the sequential sweep's order.
    let mut q_start = Vec::new();
    if FRC {
        q_start = vec![0.0; p];
        let mut q = 0.0;
        let mut s = 1;
        for row in 1..n {
            if s < p && row == layout.first_row(s) {
                q_start[s] = q;
                s += 1;
            }
            q += stored_gap::decode(gaps_in[row - 1]) + 2.0 * eps;
        }
    }
    scratch.spike.resize(n - 1, 0.0);
    let dstar_all: &[f64] = terms.repulsion.map_or(&[], |r| r.0);
    let bonded_all: &[bool] = terms.bonded.unwrap_or(&[]);
    let inputs = (gaps_in, dstar_all, bonded_all, vel_in);

    // 1. Forward sweeps of all segments.
    let chunks: Vec<Chunks> = split_chunks(&layout, &mut scratch.w, 0)
        .into_iter()
        .zip(split_chunks(&layout, &mut scratch.ls, 0))
        .zip(split_chunks(&layout, &mut scratch.ys, 0))
        .zip(split_chunks(&layout, &mut scratch.spike, 0))
        .zip(split_chunks(&layout, &mut scratch.force, 0))
        .map(|((((w, ls), ys), z), force)| Chunks {
            w,
            ls,
            ys,
            z,
            force,
        })
        .collect();
    let group_ends: Vec<GroupEnd> = chunks
        .into_par_iter()
        .enumerate()
        .map(|(g, out)| {
            forward_group_simd::<L, REP, FRC, CLU, P, Q>(
                simd, terms, &layout, g, c, &q_start, &inputs, out, law,
            )
        })
        .collect();
    let nonfinite = group_ends.iter().fold(0, |a, e| a | e.nonfinite);
    if nonfinite != 0 {
        report[0].hard = find_hard_failure(terms, law, n, 0, t0, h0, gaps_in);
    }
    let ends: Vec<SegmentEnd> = group_ends.iter().flat_map(|e| e.ends).collect();

    // 2. The interface values.
    let iface = interfaces(&ends);

    // 3. Back sweeps of all segments.
    let (gap_first, gaps_rest) = gaps_out.split_at_mut(1);
    let ws: Vec<&[f64]> = layout.chunk_slices(&scratch.w);
    let yss: Vec<&[f64]> = layout.chunk_slices(&scratch.ys);
    let zs: Vec<&[f64]> = layout.chunk_slices(&scratch.spike);
    let outs: Vec<Outputs> = split_chunks(&layout, vel_out, 0)
        .into_iter()
        .zip(split_chunks(&layout, gaps_rest, 0))
        .zip(split_chunks(&layout, &mut scratch.ls, 0))
        .enumerate()
        .map(|(g, ((vel, gaps), ls))| Outputs {
            vel,
            gaps,
            w: ws[g],
            ls,
            ys: yss[g],
            z: zs[g],
        })
        .collect();
    let backs: Vec<GroupBack> = outs
        .into_par_iter()
        .enumerate()
        .map(|(g, out)| {
            back_group_simd::<L, REP, FRC, CLU, P, Q>(
                simd, terms, &layout, g, h0, &iface, gaps_in, out, law,
            )
        })
        .collect();
    // The sum of the new gaps in a fixed order (from the last segment down), so that it does
    // not depend on the thread count.
    let mut sum = 0.0;
    let mut opening = 0.0f64;
    let mut closing = f64::NEG_INFINITY;
    let mut needs_fixup = 0u64;
    for b in backs.iter().rev() {
        for s in b.sums.iter().rev() {
            sum += s;
        }
        opening = fmax(b.opening, opening);
        closing = fmax(b.closing, closing);
        needs_fixup |= b.needs_fixup;
    }
    let u_first = backs[0].u_first;

    // 4. The rest as in the sequential path (step.rs `euler_impl`): bodies glued to the left
    // wall, the first gap, the fix-up, the certificate and the projection.
    if CLU {
        if let Some(bonded) = terms.bonded {
            for i in 0..n - 1 {
                if !bonded[i] {
                    break;
                }
                vel_out[i] = 0.0;
            }
        }
    }
    let gamma2 = -((law.gamma)(0) + 2.0);
    let old = gaps_in[0];
    let rate_first = u_first / fmax(old, GAP_FLOOR);
    let x = h0 * rate_first;
    let grown = old * gap_exp(x);
    gap_first[0] = grown;
    sum += fmax(grown, 0.0);
    if old > 0.0 {
        opening = fmax(x, opening);
    }
    let d = fmax(old, GAP_FLOOR);
    closing = fmax(d * (gamma2 * fmin(x, 0.0) - 1.0), closing);
    needs_fixup |= !((GAP_FLOOR..f64::INFINITY).contains(&grown) && x <= EXP_FAST_MAX) as u64;
    if needs_fixup != 0 {
        // The fix-up reads the rates by row (rare: log-stored gaps or extreme steps).
        let rates: Vec<f64> = (1..n).map(|row| scratch.ls[layout.index_of(row)]).collect();
        fix_up_lane::<L>(terms, n, 0, h0, gaps_in, gaps_out, &rates, rate_first);
        sum = super::lane_sum::<L>(n, 0, gaps_out);
    }
    report[0].admissible &= opening <= MAX_OPENING;
    report[0].certified = needs_fixup == 0
        && energy_certified(
            REP,
            closing,
            opening,
            2.0 * eps,
            terms.contact_repulsion[0],
            terms.mu[0] / h0,
        );
    let force = FRC.then_some(scratch.force.as_slice());
    super::conclude_simd::<L, REP, FRC, CLU, P, Q>(
        simd,
        terms,
        n,
        h,
        std::array::from_fn(|_| sum),
        gaps_out,
        vel_out,
        force,
        &mut report,
        law,
    );
    report
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::super::{euler_step_as, stored_ln, Gamma, HardFailure};
    use super::*;
    use crate::expr::Expr;
    use crate::model::plan::{Forcing, Power};
    use crate::model::quadrature::GaussLegendre;

    /// A random chain of n particles: gaps of very different sizes around 1/n (stored form),
    /// velocities, d*, bonded flags; `near` gaps of 1e-300 (stored as ln d) and `bonds` bonded
    /// gaps at the given gap indices.
    struct Chain {
        n: usize,
        gaps: Vec<f64>,
        vel: Vec<f64>,
        dstar: Vec<f64>,
        bonded: Vec<bool>,
    }

    fn chain(n: usize, seed: u64, near: &[usize], bonds: &[usize]) -> Chain {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let scale = 0.5 / n as f64;
        let mut gaps: Vec<f64> = (0..n)
            .map(|_| scale * (0.05 + 2.0 * rng.random::<f64>()))
            .collect();
        let dstar: Vec<f64> = (0..n)
            .map(|_| scale * (0.2 + 1.5 * rng.random::<f64>()))
            .collect();
        let vel: Vec<f64> = (1..n)
            .map(|i| {
                let x = i as f64 / n as f64;
                0.5 * (2.0 * std::f64::consts::PI * x).sin() + 0.05 * (rng.random::<f64>() - 0.5)
            })
            .collect();
        let mut bonded = vec![false; n];
        for &k in near {
            gaps[k] = stored_gap::encode(1e-300, GAP_FLOOR);
        }
        for &k in bonds {
            gaps[k] = 0.0;
            bonded[k] = true;
        }
        Chain {
            n,
            gaps,
            vel,
            dstar,
            bonded,
        }
    }

    /// Which terms a case has.
    #[derive(Clone, Copy, Debug)]
    struct Model {
        gamma: Option<f64>,
        clusters: bool,
        forced: bool,
    }

    type Outcome = (Vec<f64>, Vec<f64>, StepReport);

    /// One step of the chain, sequential (`layout` None) or partitioned.
    fn step(c: &Chain, model: Model, h: f64, layout: Option<Layout>, simd: SimdLevel) -> Outcome {
        let n = c.n;
        let eps = 0.25 / n as f64;
        let forcing = model.forced.then(|| Forcing {
            expr: Expr::parse("0.3*sin(2*pi*(x - t)) + 0.1").unwrap(),
            rule: GaussLegendre::new(3),
            params: Vec::new(),
        });
        let terms = Terms::<1> {
            eps,
            mu: [0.01],
            total_gap: [c.gaps.iter().map(|&v| stored_gap::decode(v)).sum()],
            contact_repulsion: [model.gamma.map_or(0.0, |g| 3f64.powf(g))],
            repulsion: model
                .gamma
                .map(|g| (c.dstar.as_slice(), Gamma::Uniform(Power::of(g)))),
            bonded: model.clusters.then_some(c.bonded.as_slice()),
            forcing: forcing.as_ref(),
            forcing_params: [&[]],
        };
        let mut gaps_out = vec![0.0; n];
        let mut vel_out = vec![0.0; n - 1];
        let mut scratch = Scratch::new(n, 1);
        let report = euler_step_as(
            simd,
            layout,
            &terms,
            n,
            &[0.25],
            &[h],
            &c.gaps,
            &c.vel,
            &mut gaps_out,
            &mut vel_out,
            &mut scratch,
        );
        (gaps_out, vel_out, report[0])
    }

    /// The partitioned result equals the sequential one to `tol`: gaps relatively (in ln d for
    /// log-stored ones; bonded gaps exactly 0 in both), velocities relative to max |u|, the
    /// energy and work relatively, the flags exactly.
    fn assert_close(label: &str, part: &Outcome, seq: &Outcome, tol: f64) {
        let (pg, pv, pr) = part;
        let (sg, sv, sr) = seq;
        for (i, (&a, &b)) in pg.iter().zip(sg).enumerate() {
            let err = if a > 0.0 && b > 0.0 {
                (a - b).abs() / b
            } else if a == 0.0 || b == 0.0 {
                assert_eq!(a, b, "{label}: gap {i} bonded in one only");
                0.0
            } else {
                (stored_ln(a) - stored_ln(b)).abs()
            };
            assert!(err <= tol, "{label}: gap {i}: {a:e} vs {b:e} (rel {err:e})");
        }
        let umax = sv.iter().fold(0.0f64, |m, u| m.max(u.abs()));
        for (i, (a, b)) in pv.iter().zip(sv).enumerate() {
            let err = (a - b).abs() / umax;
            assert!(err <= tol, "{label}: u {i}: {a:e} vs {b:e} (rel {err:e})");
        }
        assert_eq!(
            (pr.admissible, pr.hard, pr.certified),
            (sr.admissible, sr.hard, sr.certified),
            "{label}: flags"
        );
        for (what, a, b) in [("energy", pr.energy, sr.energy), ("work", pr.work, sr.work)] {
            assert!(
                (a - b).abs() <= tol * b.abs().max(1e-300),
                "{label}: {what} {a:e} vs {b:e}"
            );
        }
    }

    const TOL: f64 = 1e-12;

    fn models() -> Vec<Model> {
        let mut out = Vec::new();
        for gamma in [None, Some(2.0), Some(1.5)] {
            for clusters in [false, true] {
                for forced in [false, true] {
                    out.push(Model {
                        gamma,
                        clusters,
                        forced,
                    });
                }
            }
        }
        out
    }

    /// Segment boundaries of a layout: the first gap of each segment (index b - 1) and its
    /// neighbours, where the interface solve matters most.
    fn boundary_gaps(layout: &Layout, n: usize) -> Vec<usize> {
        let mut out = vec![0, 1, n - 1];
        for s in 1..layout.segments() {
            let b = layout.first_row(s);
            out.extend([b - 2, b - 1, b]);
        }
        out
    }

    /// Plain, repulsion, forcing and clusters, on chains whose row count the segments do not
    /// divide (n - 1 = 2000 + 13 rows, 1 to 3 groups), at a mild and a large step.
    #[test]
    fn partitioned_equals_sequential() {
        let n = 2014;
        for groups in [1, 2, 3] {
            let layout = Layout::new(n, groups).unwrap();
            assert_ne!(layout.rem, 0);
            let mut bonds: Vec<usize> = vec![0, 1, 2, 700, 701, n - 1];
            bonds.extend(boundary_gaps(&layout, n).into_iter().skip(3).step_by(4));
            bonds.sort();
            bonds.dedup();
            for model in models() {
                let c = chain(
                    n,
                    7 + groups as u64,
                    &[],
                    if model.clusters { &bonds } else { &[] },
                );
                for h in [1e-4, 3e-3] {
                    let label = format!("{model:?}, groups {groups}, h {h}");
                    let seq = step(&c, model, h, None, SimdLevel::detect());
                    let part = step(&c, model, h, Some(layout), SimdLevel::detect());
                    assert_close(&label, &part, &seq, TOL);
                }
            }
        }
    }

    /// Near contact: gaps of 1e-300 (stored as ln d) at and next to segment boundaries, at the
    /// walls and inside segments, with clusters too: the rates of those gaps (and so ln d')
    /// agree, and the fix-up runs.
    #[test]
    fn near_contact_equals_sequential() {
        let n = 1777;
        let layout = Layout::new(n, 2).unwrap();
        let mut near = boundary_gaps(&layout, n);
        near.extend([5, 300, 301, 302]);
        near.sort();
        near.dedup();
        let bonds = [1000, 1001, 1500];
        for model in models() {
            let c = chain(n, 3, &near, if model.clusters { &bonds } else { &[] });
            for h in [1e-5, 1e-3] {
                let label = format!("near contact, {model:?}, h {h}");
                let seq = step(&c, model, h, None, SimdLevel::detect());
                let part = step(&c, model, h, Some(layout), SimdLevel::detect());
                // The case took the log form (the gaps stay below GAP_FLOOR).
                assert!(seq.0[near[3]] < 0.0, "{label}: not log-stored");
                assert_close(&label, &part, &seq, TOL);
            }
        }
    }

    /// The default layout just above the threshold (and the threshold itself) through
    /// `Layout::for_chain`, with repulsion and clusters.
    #[test]
    fn default_layout_just_above_threshold() {
        assert_eq!(Layout::for_chain(PARTITION_MIN_PARTICLES - 1), None);
        for n in [PARTITION_MIN_PARTICLES, PARTITION_MIN_PARTICLES + 37] {
            let layout = Layout::for_chain(n).expect("partitioned above the threshold");
            assert!(layout.seg >= SEGMENT_ROWS / 2);
            let model = Model {
                gamma: Some(2.0),
                clusters: true,
                forced: false,
            };
            let c = chain(n, 11, &[n / 2], &[n / 3, n / 3 + 1]);
            let seq = step(&c, model, 1e-4, None, SimdLevel::detect());
            let part = step(&c, model, 1e-4, Some(layout), SimdLevel::detect());
            assert_close(&format!("n {n}"), &part, &seq, TOL);
        }
    }

    /// Results do not depend on the thread count (1 or 2 rayon threads), nor on the SIMD level:
    /// bit for bit.
    #[test]
    fn bitwise_equal_across_threads_and_simd_levels() {
        let n = 3001;
        let layout = Layout::new(n, 4).unwrap();
        let model = Model {
            gamma: Some(2.0),
            clusters: true,
            forced: true,
        };
        let c = chain(n, 5, &[10, 2000], &[400, 401]);
        let bits = |o: &Outcome| -> Vec<u64> {
            o.0.iter()
                .chain(&o.1)
                .chain([&o.2.energy, &o.2.work])
                .map(|v| v.to_bits())
                .collect()
        };
        let run = |threads: usize, simd: SimdLevel| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| bits(&step(&c, model, 1e-3, Some(layout), simd)))
        };
        let one = run(1, SimdLevel::detect());
        assert_eq!(one, run(2, SimdLevel::detect()), "1 vs 2 threads");
        assert_eq!(one, run(2, SimdLevel::Portable), "detected vs portable");
    }

    /// A non-finite repulsion is found as by the sequential sweep (the hard-failure lookup).
    #[test]
    fn hard_failure_is_reported() {
        let n = 1500;
        let layout = Layout::new(n, 1).unwrap();
        let mut c = chain(n, 9, &[], &[]);
        c.dstar[900] = 1e300;
        let model = Model {
            gamma: Some(200.0),
            clusters: false,
            forced: false,
        };
        let seq = step(&c, model, 1e-4, None, SimdLevel::detect());
        let part = step(&c, model, 1e-4, Some(layout), SimdLevel::detect());
        assert!(matches!(
            seq.2.hard,
            Some(HardFailure::Repulsion { gap: 901, .. })
        ));
        assert_eq!(part.2.hard, seq.2.hard);
    }

    /// The layout's index map is a bijection of the rows onto the scratch, with the chunks in
    /// order.
    #[test]
    fn layout_indexes_every_row_once() {
        for (n, groups) in [(33, 2), (1000, 1), (1000, 3), (5000, 7)] {
            let layout = Layout::new(n, groups).unwrap();
            let mut seen = vec![false; n - 1];
            for row in 1..n {
                let k = layout.index_of(row);
                assert!(!seen[k], "n {n}: index {k} twice");
                seen[k] = true;
            }
            assert_eq!(layout.chunk(0).start, 0);
            assert_eq!(layout.chunk(groups - 1).end, n - 1);
            for g in 1..groups {
                assert_eq!(layout.chunk(g - 1).end, layout.chunk(g).start);
            }
        }
        assert_eq!(Layout::new(16, 1), None);
    }
}
