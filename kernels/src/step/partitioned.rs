//! One member with a huge chain: the step's tridiagonal solve split into segments solved side
//! by side (a partitioned, SPIKE-style Thomas algorithm), in f64 or f32 (generic over
//! [`PartitionedReal`], as the sequential sweep is over `Real`).
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
//! results equal the sequential sweep's up to rounding (tested to 1e-12 relative in f64 and
//! 2^-14 = 6.1e-5 in f32, clusters and log-stored gaps included); the segments depend on n
//! only, and per-segment sums are added in a fixed order, so the result does not depend on the
//! thread count.
//!
//! f32 (the twin of the GPU's f32 partitioned kernel): the lane loops in f32, the sums of the new
//! gaps in f64 (as the sequential f32 sweep's, for the projection), the spike flushed at
//! [`TINY_F32`] (the GPU's). The interface system is solved in f64 from the segments' ends
//! (exact in f64) and its values rounded once to f32: it adds no rounding of its own, so the
//! f32 result differs from the sequential f32 sweep's only by the segments' sweeps (in f32
//! each rounding of the reduced sweep would be amplified along the segments like the rows'
//! own; P values, nothing to save). The GPU twin solves it in f32, so the two f32 paths agree
//! to rounding, not bit for bit (they cut the rows differently anyway).
//!
//! Two passes over the chain, because at N = 10^6 memory, not arithmetic, is the limit (measured
//! here: 15 GB/s for one core, 17 for two): the first sweeps every segment forward with the
//! spike and keeps only its end (and the forces); after the interface solve, the second sweeps
//! each group forward again from its known tau into per-thread rows that stay in cache, and back.
//! That reads the inputs twice and stores nothing per row but the new state (about 80 bytes
//! per particle-step in f64 against ~140 for storing the spike rows; half in f32), at the price
//! of a second forward sweep. The log-form fix-up of a gap is local, so it is done in the back
//! sweep (the rates are not kept); the hard-failure lookup, certificate, projection and energy
//! are the sequential path's code.
//!
//! Layout: the rows of group g (and the prologue's, for group 0) are one contiguous range; the
//! lane loops work on tiles of TILE rows × S segments copied in from the natural layout of
//! gaps and velocities and out again (4×4 f64 or 8×8 f32 AVX2 transposes where available; only
//! moves).
//!
//! `ROUGHLUB_CPU_PARTITION=off` keeps the sequential sweep at every N (for comparisons).
//!
//! GPU twin: `shaders/partitioned.wgsl` (`forward` is `forward_row` with and without SPIKE,
//! `p_interface` is [`interfaces`], `p_solve`'s back sweep is `back_row`). It runs one pass per
//! dispatch (no cache to keep rows in: it stores them) and cuts the rows into equal segments
//! rather than giving segment 0 the leftover rows. Keep the sweeps' operations in sync.
//!
//! Over 700 lines on purpose: the CPU twin of `shaders/partitioned.wgsl`, pass for pass (the
//! segments' forward and back sweeps, the interfaces' reduced system, the per-segment parts of
//! the projection and energy, and the tile transposes that feed the lanes): one algorithm whose
//! loops mirror its twin, and split apart neither would read against the other. Its unit tests
//! are in `partitioned/tests.rs`.

use rayon::prelude::*;

use super::{
    energy_certified, find_hard_failure, fixed_up, fmax, fmin, gap_exp, gap_reciprocals, gap_terms,
    jacobian_factor, particle_force, reciprocal_scale, Law, Real, Scratch, SimdLevel, StepReport,
    Terms, EXP_FAST_MAX, GAP_EXP_TAYLOR, MAX_OPENING, NEGLIGIBLE_OPENING,
};

/// Segments per group: the lanes of the partitioned lane loops (as many as the batched blocks,
/// to keep several divisions in flight per core).
pub(crate) const SEGMENT_LANES: usize = 16;
/// Chains of fewer particles keep the sequential sweep. Measured (`cargo bench --bench
/// cpu_solver`, 2 cores): at N = 1e5 the sequential sweep does 90 Melem/s and the partitioned
/// one 81 (its two passes move more bytes); at N = 1e6, 65 against 101.
pub(crate) const PARTITION_MIN_PARTICLES: usize = 1 << 18;
/// Rows per segment the default layout aims at (at least): 2^14 particles would make 4 groups to
/// share out over cores, and a group's rows and inputs (16·m·48 bytes) stay well inside L2.
const SEGMENT_ROWS: usize = 256;
pub(crate) use crate::shared::gaps::{SPIKE_TINY as TINY, SPIKE_TINY_F32 as TINY_F32};
const _: () = assert!(TINY_F32 > 1e6 * f32::MIN_POSITIVE as f64);

/// What the partitioned solve needs of its element type beyond [`Real`]: the spike's flush
/// threshold, the tiles' copies (transposes where the type has them) and a per-thread buffer
/// for a group's sweep rows.
pub(crate) trait PartitionedReal: Real {
    /// [`TINY`] or [`TINY_F32`].
    const SPIKE_TINY: Self;
    /// [`tile_in`], by AVX2 transposes where `simd` allows (the same values: only moves).
    fn tile_in<const S: usize>(
        simd: SimdLevel,
        src: &[Self],
        base: usize,
        stride: usize,
        kn: usize,
        tile: &mut [[Self; S]; TILE],
    );
    /// [`tile_out`], by AVX2 transposes where `simd` allows.
    fn tile_out<const S: usize>(
        simd: SimdLevel,
        dst: &mut [Self],
        base: usize,
        stride: usize,
        kn: usize,
        tile: &[[Self; S]; TILE],
    );
    /// `f` with this thread's buffer of sweep rows (see [`ROWS_F64`]).
    fn with_rows<R>(f: impl FnOnce(&mut Vec<Self>) -> R) -> R;
}

impl PartitionedReal for f64 {
    const SPIKE_TINY: f64 = TINY;

    /// 4×4 AVX2 transposes (the scalar copy costs a load and a store per value, a third of the
    /// step).
    #[inline(always)]
    fn tile_in<const S: usize>(
        simd: SimdLevel,
        src: &[f64],
        base: usize,
        stride: usize,
        kn: usize,
        tile: &mut [[f64; S]; TILE],
    ) {
        #[cfg(target_arch = "x86_64")]
        if simd.has_avx2() && S.is_multiple_of(4) {
            assert!(kn <= TILE && base + (S - 1) * stride + kn <= src.len());
            // SAFETY: AVX2 is there (`has_avx2`); every read is within the lanes' ranges
            // checked above, every write within the tile.
            unsafe {
                transpose_avx2::<S, true>(
                    src.as_ptr() as *mut f64,
                    stride,
                    base,
                    kn,
                    tile.as_mut_ptr(),
                )
            };
            return;
        }
        let _ = simd;
        tile_in(src, base, stride, kn, tile);
    }

    #[inline(always)]
    fn tile_out<const S: usize>(
        simd: SimdLevel,
        dst: &mut [f64],
        base: usize,
        stride: usize,
        kn: usize,
        tile: &[[f64; S]; TILE],
    ) {
        #[cfg(target_arch = "x86_64")]
        if simd.has_avx2() && S.is_multiple_of(4) {
            assert!(kn <= TILE && base + (S - 1) * stride + kn <= dst.len());
            // SAFETY: as in `tile_in`; `dst` is borrowed mutably, the tile is only read.
            unsafe {
                transpose_avx2::<S, false>(
                    dst.as_mut_ptr(),
                    stride,
                    base,
                    kn,
                    tile.as_ptr() as *mut _,
                )
            };
            return;
        }
        let _ = simd;
        tile_out(dst, base, stride, kn, tile);
    }

    #[inline(always)]
    fn with_rows<R>(f: impl FnOnce(&mut Vec<f64>) -> R) -> R {
        ROWS_F64.with_borrow_mut(f)
    }
}

impl PartitionedReal for f32 {
    const SPIKE_TINY: f32 = TINY_F32 as f32;

    /// 8×8 AVX2 transposes.
    #[inline(always)]
    fn tile_in<const S: usize>(
        simd: SimdLevel,
        src: &[f32],
        base: usize,
        stride: usize,
        kn: usize,
        tile: &mut [[f32; S]; TILE],
    ) {
        #[cfg(target_arch = "x86_64")]
        if simd.has_avx2() && S.is_multiple_of(8) {
            assert!(kn <= TILE && base + (S - 1) * stride + kn <= src.len());
            // SAFETY: as for f64.
            unsafe {
                transpose_avx2_f32::<S, true>(
                    src.as_ptr() as *mut f32,
                    stride,
                    base,
                    kn,
                    tile.as_mut_ptr(),
                )
            };
            return;
        }
        let _ = simd;
        tile_in(src, base, stride, kn, tile);
    }

    #[inline(always)]
    fn tile_out<const S: usize>(
        simd: SimdLevel,
        dst: &mut [f32],
        base: usize,
        stride: usize,
        kn: usize,
        tile: &[[f32; S]; TILE],
    ) {
        #[cfg(target_arch = "x86_64")]
        if simd.has_avx2() && S.is_multiple_of(8) {
            assert!(kn <= TILE && base + (S - 1) * stride + kn <= dst.len());
            // SAFETY: as for f64.
            unsafe {
                transpose_avx2_f32::<S, false>(
                    dst.as_mut_ptr(),
                    stride,
                    base,
                    kn,
                    tile.as_ptr() as *mut _,
                )
            };
            return;
        }
        let _ = simd;
        tile_out(dst, base, stride, kn, tile);
    }

    #[inline(always)]
    fn with_rows<R>(f: impl FnOnce(&mut Vec<f32>) -> R) -> R {
        ROWS_F32.with_borrow_mut(f)
    }
}

/// How the rows of a chain are cut: `groups` groups of SEGMENT_LANES segments of `seg` rows,
/// segment 0 with `rem` more rows in front.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Layout {
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
    /// sweep: below PARTITION_MIN_PARTICLES. Depends on n only (never on the thread count).
    pub(crate) fn for_chain(n: usize) -> Option<Layout> {
        if n < PARTITION_MIN_PARTICLES {
            return None;
        }
        let groups = ((n - 1) / (SEGMENT_LANES * SEGMENT_ROWS)).max(1);
        Layout::new(n, groups)
    }

    fn segments(&self) -> usize {
        self.groups * SEGMENT_LANES
    }

    /// Index (= row - 1) where group g's main rows start; group 0's chunk also holds the
    /// prologue's rem rows before it.
    fn main_start(&self, g: usize) -> usize {
        self.rem + g * SEGMENT_LANES * self.seg
    }

    /// Row - 1 range of group g: the chunks split the forces, the velocities and (shifted by one)
    /// the gaps 1..n among the groups; a group's sweep rows are its chunk, interleaved.
    fn chunk(&self, g: usize) -> std::ops::Range<usize> {
        let start = if g == 0 { 0 } else { self.main_start(g) };
        start..self.main_start(g + 1)
    }

    /// Segment s's first row (s >= 1; segment 0 starts at row 1).
    fn first_row(&self, s: usize) -> usize {
        1 + self.rem + s * self.seg
    }

    /// Index of row `row` (1-based) in the groups' sweep rows laid end to end (the prologue's at
    /// row - 1, then each group's segments interleaved: local row k of lane l at k·S + l).
    #[cfg(test)]
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

/// `s` cut at the chunks of `layout`.
fn split_chunks<'a, T>(layout: &Layout, s: &'a mut [T]) -> Vec<&'a mut [T]> {
    let mut rest = s;
    let mut out = Vec::with_capacity(layout.groups);
    for g in 0..layout.groups {
        let (head, tail) = std::mem::take(&mut rest).split_at_mut(layout.chunk(g).len());
        out.push(head);
        rest = tail;
    }
    out
}

/// Values at base, base + stride, …: one bounds check for the row, none per lane (for the
/// segments' first gaps).
#[inline(always)]
fn gather<const S: usize, T: Copy>(src: &[T], base: usize, stride: usize) -> [T; S] {
    assert!(base + (S - 1) * stride < src.len());
    // SAFETY: every index is at most base + (S-1)·stride, checked above.
    std::array::from_fn(|l| unsafe { *src.get_unchecked(base + l * stride) })
}

/// Rows per tile of the lane loops (a tile of each input is 8 KiB: all stay in L1).
const TILE: usize = 64;

/// tile[k][l] = src[base + l·stride + k] for k < kn: lane l's next kn values, read in order.
#[inline(always)]
fn tile_in<const S: usize, T: Copy>(
    src: &[T],
    base: usize,
    stride: usize,
    kn: usize,
    tile: &mut [[T; S]; TILE],
) {
    for l in 0..S {
        let from = &src[base + l * stride..base + l * stride + kn];
        for (row, &v) in tile.iter_mut().zip(from) {
            row[l] = v;
        }
    }
}

/// dst[base + l·stride + k] = tile[k][l] for k < kn (the inverse of [`tile_in`]).
#[inline(always)]
fn tile_out<const S: usize, T: Copy>(
    dst: &mut [T],
    base: usize,
    stride: usize,
    kn: usize,
    tile: &[[T; S]; TILE],
) {
    for l in 0..S {
        let to = &mut dst[base + l * stride..base + l * stride + kn];
        for (row, v) in tile.iter().zip(to) {
            *v = row[l];
        }
    }
}

/// Between lane streams (lane l's k-th value at `mem[base + l·stride + k]`) and a tile of rows
/// (tile[k][l]): into the tile (`IN`) or out of it, four lanes by four rows per transpose.
///
/// # Safety
/// AVX2 must be available; `mem` must be valid for reads (IN) or writes of
/// base + l·stride + k for all l < S, k < kn, and `tile` for writes (IN) or reads of kn rows;
/// S a multiple of 4.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn transpose_avx2<const S: usize, const IN: bool>(
    mem: *mut f64,
    stride: usize,
    base: usize,
    kn: usize,
    tile: *mut [f64; S],
) {
    use std::arch::x86_64::*;
    let k4 = kn & !3;
    for l0 in (0..S).step_by(4) {
        let p = mem.add(base + l0 * stride);
        let mut k = 0;
        while k < k4 {
            // a: four vectors of four; b = its transpose.
            let a: [__m256d; 4] = if IN {
                std::array::from_fn(|j| _mm256_loadu_pd(p.add(j * stride + k)))
            } else {
                std::array::from_fn(|j| _mm256_loadu_pd((*tile.add(k + j)).as_ptr().add(l0)))
            };
            let t0 = _mm256_unpacklo_pd(a[0], a[1]);
            let t1 = _mm256_unpackhi_pd(a[0], a[1]);
            let t2 = _mm256_unpacklo_pd(a[2], a[3]);
            let t3 = _mm256_unpackhi_pd(a[2], a[3]);
            let b = [
                _mm256_permute2f128_pd::<0x20>(t0, t2),
                _mm256_permute2f128_pd::<0x20>(t1, t3),
                _mm256_permute2f128_pd::<0x31>(t0, t2),
                _mm256_permute2f128_pd::<0x31>(t1, t3),
            ];
            for (j, v) in b.into_iter().enumerate() {
                if IN {
                    _mm256_storeu_pd((*tile.add(k + j)).as_mut_ptr().add(l0), v);
                } else {
                    _mm256_storeu_pd(p.add(j * stride + k), v);
                }
            }
            k += 4;
        }
        for k in k4..kn {
            for j in 0..4 {
                if IN {
                    (*tile.add(k))[l0 + j] = *p.add(j * stride + k);
                } else {
                    *p.add(j * stride + k) = (*tile.add(k))[l0 + j];
                }
            }
        }
    }
}

/// [`transpose_avx2`] for f32: eight lanes by eight rows per transpose.
///
/// # Safety
/// As for [`transpose_avx2`], S a multiple of 8.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn transpose_avx2_f32<const S: usize, const IN: bool>(
    mem: *mut f32,
    stride: usize,
    base: usize,
    kn: usize,
    tile: *mut [f32; S],
) {
    use std::arch::x86_64::*;
    let k8 = kn & !7;
    for l0 in (0..S).step_by(8) {
        let p = mem.add(base + l0 * stride);
        let mut k = 0;
        while k < k8 {
            // a: eight vectors of eight; b = its transpose.
            let a: [__m256; 8] = if IN {
                std::array::from_fn(|j| _mm256_loadu_ps(p.add(j * stride + k)))
            } else {
                std::array::from_fn(|j| _mm256_loadu_ps((*tile.add(k + j)).as_ptr().add(l0)))
            };
            // Pairs interleaved, then quadruples, then the 128-bit halves swapped.
            let t: [__m256; 8] = [
                _mm256_unpacklo_ps(a[0], a[1]),
                _mm256_unpackhi_ps(a[0], a[1]),
                _mm256_unpacklo_ps(a[2], a[3]),
                _mm256_unpackhi_ps(a[2], a[3]),
                _mm256_unpacklo_ps(a[4], a[5]),
                _mm256_unpackhi_ps(a[4], a[5]),
                _mm256_unpacklo_ps(a[6], a[7]),
                _mm256_unpackhi_ps(a[6], a[7]),
            ];
            let q: [__m256; 8] = [
                _mm256_shuffle_ps::<0x44>(t[0], t[2]),
                _mm256_shuffle_ps::<0xEE>(t[0], t[2]),
                _mm256_shuffle_ps::<0x44>(t[1], t[3]),
                _mm256_shuffle_ps::<0xEE>(t[1], t[3]),
                _mm256_shuffle_ps::<0x44>(t[4], t[6]),
                _mm256_shuffle_ps::<0xEE>(t[4], t[6]),
                _mm256_shuffle_ps::<0x44>(t[5], t[7]),
                _mm256_shuffle_ps::<0xEE>(t[5], t[7]),
            ];
            let b = [
                _mm256_permute2f128_ps::<0x20>(q[0], q[4]),
                _mm256_permute2f128_ps::<0x20>(q[1], q[5]),
                _mm256_permute2f128_ps::<0x20>(q[2], q[6]),
                _mm256_permute2f128_ps::<0x20>(q[3], q[7]),
                _mm256_permute2f128_ps::<0x31>(q[0], q[4]),
                _mm256_permute2f128_ps::<0x31>(q[1], q[5]),
                _mm256_permute2f128_ps::<0x31>(q[2], q[6]),
                _mm256_permute2f128_ps::<0x31>(q[3], q[7]),
            ];
            for (j, v) in b.into_iter().enumerate() {
                if IN {
                    _mm256_storeu_ps((*tile.add(k + j)).as_mut_ptr().add(l0), v);
                } else {
                    _mm256_storeu_ps(p.add(j * stride + k), v);
                }
            }
            k += 8;
        }
        for k in k8..kn {
            for j in 0..8 {
                if IN {
                    (*tile.add(k))[l0 + j] = *p.add(j * stride + k);
                } else {
                    *p.add(j * stride + k) = (*tile.add(k))[l0 + j];
                }
            }
        }
    }
}

/// The forward sweep's state of S segments.
#[derive(Clone, Copy)]
struct Sweep<T: Real, const S: usize> {
    a_prev: [T; S],
    g_prev: [T; S],
    ls_prev: [T; S],
    ys_prev: [T; S],
    /// d ys/d tau of the previous row (first pass only).
    z_prev: [T; S],
    /// Running product of w from the segment's first row (the weight of u_i in u_b).
    pi: [T; S],
    /// u_b = acc_a + pi·u_e + acc_c·tau.
    acc_a: [T; S],
    acc_c: [T; S],
    /// 0/1 in lanes as wide as T (as the sequential sweep's flags).
    nonfinite: [T::Flag; S],
    /// Position of the last particle swept (forcing only).
    q: [T; S],
}

impl<T: Real, const S: usize> Sweep<T, S> {
    /// Segments starting from the rate tau of their first gap: ls = 0, ys = -tau (the first
    /// pass: tau unknown, ys0 = 0 and z = -1).
    fn new(tau: [T; S], spike: T) -> Sweep<T, S> {
        Sweep {
            a_prev: [T::ZERO; S],
            g_prev: [T::ZERO; S],
            ls_prev: [T::ZERO; S],
            ys_prev: tau.map(|x| -x),
            z_prev: [spike; S],
            pi: [T::ONE; S],
            acc_a: [T::ZERO; S],
            acc_c: [T::ZERO; S],
            nonfinite: [T::Flag::default(); S],
            q: [T::ZERO; S],
        }
    }
}

/// The end of one segment's first forward sweep (see the module doc), in f64 (exact for f32
/// ends): the interface system is solved in f64.
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
struct Step<T> {
    /// The instruction set the lane loops run (for the tiles' transposes).
    simd: SimdLevel,
    mu: T,
    eps: T,
    h: T,
    t: f64,
    m_over_h: T,
    /// `Terms::exact_jacobian`.
    exact: bool,
}

/// One row of the forward sweep for S segments: the sequential sweep's operations, plus (with
/// SPIKE) the spike and the accumulation of u_b. `vel` and `vel_right` are the velocities at
/// the two ends of the row's next gap. Returns w and the next gap's k; ls, ys are left in the
/// state.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn forward_row<
    T: PartitionedReal,
    const S: usize,
    const REP: bool,
    const CLU: bool,
    const SPIKE: bool,
    const EXACT: bool,
    P,
    Q,
>(
    law: Law<P, Q>,
    c: Step<T>,
    st: &mut Sweep<T, S>,
    stored: &[T; S],
    dstar: &[T; S],
    bonded: &[bool; S],
    vel: &[T; S],
    vel_right: &[T; S],
    f: &[T; S],
) -> ([T; S], [T; S])
where
    P: Fn(usize, T) -> T + Copy,
    Q: Fn(usize) -> T + Copy,
{
    let eps2 = T::c(2.0) * c.eps;
    let scale = reciprocal_scale(eps2);
    let tiny = T::SPIKE_TINY;
    let mut w = [T::ZERO; S];
    let mut k = [T::ZERO; S];
    for l in 0..S {
        let (a_next, g_next, d_next, inv_d) = gap_terms::<T, REP, true, P, Q>(
            law, 0, c.mu, eps2, scale, stored[l], dstar[l], bonded[l], c.h,
        );
        // EXACT is c.exact, as a constant: a run-time test left the factor's division in the
        // frozen matrix's loop (see the sequential sweep's `forward_rows`).
        k[l] = jacobian_factor(EXACT, d_next, inv_d, c.h, vel[l], vel_right[l]);
        let a_next = a_next * k[l];
        st.nonfinite[l] |= T::Flag::from(!(g_next + f[l]).is_finite());
        let rhs = c.m_over_h * vel[l] + st.g_prev[l] - g_next + f[l];
        // As in the sequential sweep (step.rs), operation for operation.
        let excess = c.m_over_h + st.a_prev[l] * st.ls_prev[l];
        let delta = rhs + st.a_prev[l] * st.ys_prev[l];
        let pivot_base = c.m_over_h * d_next + a_next;
        let coupling = st.a_prev[l] * d_next;
        let inv = T::ONE / (pivot_base + coupling * st.ls_prev[l]);
        let ls = excess * inv;
        let ys = delta * inv;
        w[l] = a_next * inv;
        if SPIKE {
            let z = st.a_prev[l] * st.z_prev[l] * inv;
            // z <= 0; flushed to 0 once negligible (NaN is kept).
            let z = if z > -tiny { T::ZERO } else { z };
            st.acc_a[l] += st.pi[l] * (d_next * ys);
            st.acc_c[l] += st.pi[l] * (d_next * z);
            let pi = st.pi[l] * w[l];
            st.pi[l] = if pi < tiny { T::ZERO } else { pi };
            st.z_prev[l] = z;
        }
        st.ls_prev[l] = ls;
        st.ys_prev[l] = ys;
        st.a_prev[l] = a_next;
        st.g_prev[l] = g_next;
    }
    (w, k)
}

/// Forcing of one row of S segments (rows `row0 + l·stride`): interpreted, so not in the lane
/// loop. Writes F to `force` (natural layout, index row - 1 - `force_at`). q and F as the
/// sequential sweep computes them (q in T, F evaluated in f64 and rounded to T).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn forces<T: Real, const S: usize, const L: usize>(
    terms: &Terms<L, T>,
    c: Step<T>,
    st: &mut Sweep<T, S>,
    gaps_in: &[T],
    row0: usize,
    stride: usize,
    force: &mut [T],
    force_at: usize,
) -> [T; S] {
    let mut f = [T::ZERO; S];
    if let Some(forcing) = terms.forcing {
        let mass = T::c(2.0) * c.eps;
        for (l, (q, fl)) in st.q.iter_mut().zip(f.iter_mut()).enumerate() {
            let row = row0 + l * stride;
            *q += gaps_in[row - 1].decode_stored() + mass;
            *fl = T::c(particle_force(
                forcing,
                terms.forcing_params[0],
                c.eps.to_f64(),
                c.t,
                q.to_f64(),
            ));
            force[row - 1 - force_at] = *fl;
        }
    }
    f
}

/// The inputs, natural layout: gaps, d* and bonded flags (where they exist), velocities.
type Inputs<'a, T> = (&'a [T], &'a [T], &'a [bool], &'a [T]);

/// The sweep rows of one group (w, ls, ys and the next gap's k: the prologue's rows at
/// row - 1, then the group's rows interleaved), for the second pass.
struct Rows<'a, T> {
    w: &'a mut [T],
    ls: &'a mut [T],
    ys: &'a mut [T],
    k: &'a mut [T],
}

/// The velocity of index `at` (natural layout), 0 beyond the last particle (the right wall).
#[inline(always)]
fn velocity_at<T: Real>(vel_in: &[T], at: usize) -> T {
    vel_in.get(at).copied().unwrap_or(T::ZERO)
}

/// Forward sweep of group g's segments (and of the prologue, for group 0) from `start`. The
/// first pass (SPIKE, `rows` None) computes F into `force` and returns the segments' ends; the
/// second (tau known) reads F from `force` and stores the rows.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn forward_group<T: PartitionedReal, const L: usize, const REP: bool, const SPIKE: bool, P, Q>(
    terms: &Terms<L, T>,
    layout: &Layout,
    g: usize,
    c: Step<T>,
    mut st: Sweep<T, SEGMENT_LANES>,
    inputs: &Inputs<T>,
    force: &mut [T],
    mut rows: Option<Rows<T>>,
    law: Law<P, Q>,
) -> Sweep<T, SEGMENT_LANES>
where
    P: Fn(usize, T) -> T + Copy,
    Q: Fn(usize) -> T + Copy,
{
    const S: usize = SEGMENT_LANES;
    let zero = T::ZERO;
    let (gaps_in, dstar_all, bonded_all, vel_in) = *inputs;
    // Clusters are a run-time test here (the helpers' CLU = true reads the flags, all false
    // without clusters): as a const flag they doubled the partitioned solve's build.
    let clu = !bonded_all.is_empty();
    let m = layout.seg;
    let chunk_at = layout.chunk(g).start;
    let main = layout.main_start(g);
    let off = main - chunk_at;
    let eps2 = T::c(2.0) * c.eps;
    let scale = reciprocal_scale(eps2);
    {
        // The first gap of each segment (index main + l·m) is the previous row's.
        let stored = gather::<S, T>(gaps_in, main, m);
        let dstar = if REP {
            gather::<S, T>(dstar_all, main, m)
        } else {
            [zero; S]
        };
        let bonded = if clu {
            gather::<S, bool>(bonded_all, main, m)
        } else {
            [false; S]
        };
        for l in 0..S {
            let (a, gg, d, inv_d) = gap_terms::<T, REP, true, P, Q>(
                law, 0, c.mu, eps2, scale, stored[l], dstar[l], bonded[l], c.h,
            );
            // The gap's k as the row before it computes it (index 0 is the left wall's gap).
            let at = main + l * m;
            let u_left = if at == 0 { zero } else { vel_in[at - 1] };
            let k = jacobian_factor(c.exact, d, inv_d, c.h, u_left, velocity_at(vel_in, at));
            st.a_prev[l] = a * k;
            st.g_prev[l] = gg;
        }
    }
    if g == 0 {
        // Segment 0 starts from the left wall (lambda_0 = 1: ls_0 = 1/d_1, ys_0 = 0, no spike),
        // as the sequential sweep does, and sweeps the prologue's rows alone.
        let mut s0 = Sweep::<T, 1>::new([zero], zero);
        let (a, gg, d, inv_d) = gap_terms::<T, REP, true, P, Q>(
            law,
            0,
            c.mu,
            eps2,
            scale,
            gaps_in[0],
            if REP { dstar_all[0] } else { zero },
            clu && bonded_all[0],
            c.h,
        );
        s0.a_prev[0] = a * jacobian_factor(c.exact, d, inv_d, c.h, zero, velocity_at(vel_in, 0));
        s0.g_prev[0] = gg;
        s0.ls_prev[0] = inv_d;
        s0.nonfinite[0] |= T::Flag::from(!gg.is_finite());
        for row in 1..=layout.rem {
            let f = match (terms.forcing.is_some(), SPIKE) {
                (false, _) => [zero],
                (true, true) => forces::<T, 1, L>(terms, c, &mut s0, gaps_in, row, 0, force, 0),
                (true, false) => [force[row - 1]],
            };
            let stored = [gaps_in[row]];
            let dstar = [if REP { dstar_all[row] } else { zero }];
            let bonded = [clu && bonded_all[row]];
            let vel = [vel_in[row - 1]];
            let vel_right = [velocity_at(vel_in, row)];
            let (w, k) = if c.exact {
                forward_row::<T, 1, REP, true, false, true, P, Q>(
                    law, c, &mut s0, &stored, &dstar, &bonded, &vel, &vel_right, &f,
                )
            } else {
                forward_row::<T, 1, REP, true, false, false, P, Q>(
                    law, c, &mut s0, &stored, &dstar, &bonded, &vel, &vel_right, &f,
                )
            };
            if let Some(r) = rows.as_mut() {
                r.w[row - 1] = w[0];
                r.ls[row - 1] = s0.ls_prev[0];
                r.ys[row - 1] = s0.ys_prev[0];
                r.k[row - 1] = k[0];
            }
        }
        st.ls_prev[0] = s0.ls_prev[0];
        st.ys_prev[0] = s0.ys_prev[0];
        st.z_prev[0] = zero;
        st.nonfinite[0] |= s0.nonfinite[0];
        st.q[0] = s0.q[0];
    }
    // Rows in tiles of TILE: each lane's inputs are copied in (contiguous reads per lane), so
    // that the lane loop reads whole rows (gathering a row lane by lane stalls every row on
    // store forwarding).
    let mut t_gap = [[zero; S]; TILE];
    let mut t_dstar = [[zero; S]; TILE];
    let mut t_bond = [[false; S]; TILE];
    let mut t_vel = [[zero; S]; TILE];
    let mut t_f = [[zero; S]; TILE];
    let mut k0 = 0;
    while k0 < m {
        let kn = TILE.min(m - k0);
        // Row main + 1 + l·m + k of lane l; its next gap has index main + 1 + l·m + k.
        let row0 = main + 1 + k0;
        T::tile_in(c.simd, gaps_in, row0, m, kn, &mut t_gap);
        T::tile_in(c.simd, vel_in, row0 - 1, m, kn, &mut t_vel);
        if REP {
            T::tile_in(c.simd, dstar_all, row0, m, kn, &mut t_dstar);
        }
        if clu {
            tile_in(bonded_all, row0, m, kn, &mut t_bond);
        }
        if !SPIKE && terms.forcing.is_some() {
            T::tile_in(c.simd, force, row0 - 1 - chunk_at, m, kn, &mut t_f);
        }
        for kk in 0..kn {
            if SPIKE && terms.forcing.is_some() {
                t_f[kk] =
                    forces::<T, S, L>(terms, c, &mut st, gaps_in, row0 + kk, m, force, chunk_at);
            }
            // The velocity right of the row's next gap: the next row's, or past the tile's end
            // read from the input (the right wall's 0 after the last row).
            let vel_right: [T; S] = if kk + 1 < kn {
                t_vel[kk + 1]
            } else {
                std::array::from_fn(|l| velocity_at(vel_in, row0 + kk + l * m))
            };
            let row = (&t_gap[kk], &t_dstar[kk], &t_bond[kk], &t_vel[kk], &t_f[kk]);
            let (w, k) = if c.exact {
                forward_row::<T, S, REP, true, SPIKE, true, P, Q>(
                    law, c, &mut st, row.0, row.1, row.2, row.3, &vel_right, row.4,
                )
            } else {
                forward_row::<T, S, REP, true, SPIKE, false, P, Q>(
                    law, c, &mut st, row.0, row.1, row.2, row.3, &vel_right, row.4,
                )
            };
            if let Some(r) = rows.as_mut() {
                let at = off + (k0 + kk) * S;
                r.w[at..at + S].copy_from_slice(&w);
                r.ls[at..at + S].copy_from_slice(&st.ls_prev);
                r.ys[at..at + S].copy_from_slice(&st.ys_prev);
                r.k[at..at + S].copy_from_slice(&k);
            }
        }
        k0 += kn;
    }
    st
}

simd_versions!(T: PartitionedReal; ends_group_simd, ends_group_avx2, ends_group_avx512, ends_group_impl, (
    terms: &Terms<L, T>,
    layout: &Layout,
    g: usize,
    c: Step<T>,
    q_start: &[T],
    inputs: &Inputs<'_, T>,
    force: &mut [T]
) -> ([SegmentEnd; SEGMENT_LANES], bool));

/// The first pass over group g: the segments' ends from a forward sweep with the spike (nothing
/// stored but F), and whether some G or F was not finite. `q_start` is the position of each
/// segment's particle b - 1 (forcing only).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn ends_group_impl<T: PartitionedReal, const L: usize, const REP: bool, P, Q>(
    terms: &Terms<L, T>,
    layout: &Layout,
    g: usize,
    c: Step<T>,
    q_start: &[T],
    inputs: &Inputs<'_, T>,
    force: &mut [T],
    law: Law<P, Q>,
) -> ([SegmentEnd; SEGMENT_LANES], bool)
where
    P: Fn(usize, T) -> T + Copy,
    Q: Fn(usize) -> T + Copy,
{
    const S: usize = SEGMENT_LANES;
    let mut start = Sweep::<T, S>::new([T::ZERO; S], -T::ONE);
    if terms.forcing.is_some() {
        start.q.copy_from_slice(&q_start[g * S..(g + 1) * S]);
    }
    let st = forward_group::<T, L, REP, true, P, Q>(
        terms, layout, g, c, start, inputs, force, None, law,
    );
    let ends = std::array::from_fn(|l| SegmentEnd {
        ls: st.ls_prev[l].to_f64(),
        ys: st.ys_prev[l].to_f64(),
        z: st.z_prev[l].to_f64(),
        a: st.acc_a[l].to_f64(),
        b: st.pi[l].to_f64(),
        c: st.acc_c[l].to_f64(),
    });
    (ends, st.nonfinite.iter().any(|&f| f != T::Flag::default()))
}

/// The back sweep's flags and sums of S segments.
#[derive(Clone, Copy)]
struct Back<T: Real, const S: usize> {
    u_next: [T; S],
    /// The sums of the new gaps in f64 in either precision (as the sequential sweep's).
    sum: [f64; S],
    opening: [T; S],
    /// As the sequential sweep's `overshoot`.
    overshoot: [T; S],
    closing: [T; S],
    needs_fixup: [T::Flag; S],
}

/// One row of the back sweep for S segments: the sequential back sweep's operations, with the
/// log-form fix-up of the gaps that need it done here (their rates are not kept) before the
/// sum. Returns (u, new stored gap) of the row.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn back_row<T: Real, const S: usize, const CLU: bool>(
    h: T,
    gamma2: T,
    negligible: T,
    st: &mut Back<T, S>,
    old: &[T; S],
    bonded: &[bool; S],
    w: &[T; S],
    ys: &[T; S],
    ls: &[T; S],
    k: &[T; S],
) -> ([T; S], [T; S]) {
    let zero = T::ZERO;
    let floor = T::GAP_FLOOR;
    let flag = T::Flag::from;
    let mut x = [zero; S];
    let mut small = flag(true);
    for l in 0..S {
        let d = fmax(old[l], floor);
        let mut u = d * ys[l] + w[l] * st.u_next[l];
        if CLU && bonded[l] {
            u = st.u_next[l];
        }
        let rate = (ls[l] * st.u_next[l] - ys[l]) * k[l];
        x[l] = h * rate;
        small &= flag(x[l].abs() < T::c(GAP_EXP_TAYLOR));
        st.u_next[l] = u;
    }
    let e = super::exp_row(&x, small);
    let mut grown = [zero; S];
    let mut flags = [T::Flag::default(); S];
    let mut any = T::Flag::default();
    for l in 0..S {
        grown[l] = old[l] * e[l];
        if old[l] > zero {
            st.opening[l] = fmax(x[l], st.opening[l]);
        }
        if grown[l] > negligible {
            st.overshoot[l] = fmax(x[l], st.overshoot[l]);
        }
        let d = fmax(old[l], floor);
        st.closing[l] = fmax(d * (gamma2 * fmin(x[l], zero) - T::ONE), st.closing[l]);
        // NaN fails the comparisons.
        flags[l] =
            flag(!(grown[l] >= floor && grown[l] < T::INFINITY && x[l] <= T::c(EXP_FAST_MAX)));
        st.needs_fixup[l] |= flags[l];
        any |= flags[l];
    }
    if any != T::Flag::default() {
        for l in 0..S {
            if flags[l] != T::Flag::default() {
                grown[l] = if CLU && bonded[l] {
                    zero
                } else {
                    fixed_up(old[l], x[l], grown[l])
                };
            }
        }
    }
    for (sum, g) in st.sum.iter_mut().zip(grown) {
        *sum += fmax(g, zero).to_f64();
    }
    (st.u_next, grown)
}

/// What a group's second pass hands back: per segment the sum of its new gaps (segment 0's
/// including the prologue's), and the flags.
struct GroupBack<T> {
    sums: [f64; SEGMENT_LANES],
    opening: T,
    overshoot: T,
    closing: T,
    needs_fixup: bool,
    /// u_1 (group 0 only).
    u_first: T,
}

/// Group g's chunks of the outputs (natural layout: velocities of the chunk's rows, the gaps
/// after them) and of the forces.
struct Outputs<'a, T> {
    vel: &'a mut [T],
    gaps: &'a mut [T],
    force: &'a mut [T],
}

std::thread_local! {
    /// Per thread: the sweep rows of the group it solves (w, ls, ys), reused by every group, so
    /// that they stay in its cache and never go to memory.
    static ROWS_F64: std::cell::RefCell<Vec<f64>> = const { std::cell::RefCell::new(Vec::new()) };
    /// [`ROWS_F64`] for f32.
    static ROWS_F32: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
}

simd_versions!(T: PartitionedReal; solve_group_simd, solve_group_avx2, solve_group_avx512, solve_group_impl, (
    terms: &Terms<L, T>,
    layout: &Layout,
    g: usize,
    c: Step<T>,
    iface: &[(T, T)],
    inputs: &Inputs<'_, T>,
    out: Outputs<'_, T>,
    buf: &mut Vec<T>
) -> GroupBack<T>);

/// The second pass over group g (and the prologue, for group 0): forward sweep of each segment
/// from its tau, then the back sweep from the first velocity of the next segment
/// (`iface[s]` = (tau, that velocity)), writing velocities and gaps.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn solve_group_impl<T: PartitionedReal, const L: usize, const REP: bool, P, Q>(
    terms: &Terms<L, T>,
    layout: &Layout,
    g: usize,
    c: Step<T>,
    iface: &[(T, T)],
    inputs: &Inputs<'_, T>,
    out: Outputs<'_, T>,
    buf: &mut Vec<T>,
    law: Law<P, Q>,
) -> GroupBack<T>
where
    P: Fn(usize, T) -> T + Copy,
    Q: Fn(usize) -> T + Copy,
{
    const S: usize = SEGMENT_LANES;
    {
        let len = layout.chunk(g).len();
        if buf.len() < 4 * len {
            buf.resize(4 * len, T::ZERO);
        }
        let (w, rest) = buf.split_at_mut(len);
        let (ls, rest) = rest.split_at_mut(len);
        let (ys, rest) = rest.split_at_mut(len);
        let k = &mut rest[..len];
        let tau: [T; S] = std::array::from_fn(|l| iface[g * S + l].0);
        forward_group::<T, L, REP, false, P, Q>(
            terms,
            layout,
            g,
            c,
            Sweep::new(tau, T::ZERO),
            inputs,
            out.force,
            Some(Rows { w, ls, ys, k }),
            law,
        );
        back_group::<T, L, P, Q>(
            terms,
            layout,
            g,
            c,
            iface,
            inputs.0,
            [w, ls, ys, k],
            out,
            law,
        )
    }
}

/// The back sweep of [`solve_group_impl`].
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn back_group<T: PartitionedReal, const L: usize, P, Q>(
    terms: &Terms<L, T>,
    layout: &Layout,
    g: usize,
    c: Step<T>,
    iface: &[(T, T)],
    gaps_in: &[T],
    [w, ls, ys, k]: [&mut [T]; 4],
    out: Outputs<'_, T>,
    law: Law<P, Q>,
) -> GroupBack<T>
where
    P: Fn(usize, T) -> T + Copy,
    Q: Fn(usize) -> T + Copy,
{
    const S: usize = SEGMENT_LANES;
    let zero = T::ZERO;
    let h = c.h;
    let m = layout.seg;
    let chunk_at = layout.chunk(g).start;
    let main = layout.main_start(g);
    let off = main - chunk_at;
    let bonded_all = terms.bonded.unwrap_or(&[]);
    let clu = !bonded_all.is_empty();
    let gamma2 = -((law.gamma)(0) + T::c(2.0));
    let negligible = T::c(NEGLIGIBLE_OPENING * terms.total_gap[0]);
    let mut st = Back::<T, S> {
        u_next: std::array::from_fn(|l| iface[g * S + l].1),
        sum: [0.0; S],
        opening: [zero; S],
        overshoot: [zero; S],
        closing: [T::NEG_INFINITY; S],
        needs_fixup: [T::Flag::default(); S],
    };
    // Tiles of rows from the top, as in the forward sweep; the outputs go out per tile.
    let mut t_old = [[zero; S]; TILE];
    let mut t_bond = [[false; S]; TILE];
    let mut t_u = [[zero; S]; TILE];
    let mut t_grown = [[zero; S]; TILE];
    let mut k_hi = m;
    while k_hi > 0 {
        let kn = TILE.min(k_hi);
        let k0 = k_hi - kn;
        let row0 = main + 1 + k0;
        T::tile_in(c.simd, gaps_in, row0, m, kn, &mut t_old);
        if clu {
            tile_in(bonded_all, row0, m, kn, &mut t_bond);
        }
        for kk in (0..kn).rev() {
            let at = off + (k0 + kk) * S;
            let (u, grown) = back_row::<T, S, true>(
                h,
                gamma2,
                negligible,
                &mut st,
                &t_old[kk],
                &t_bond[kk],
                w[at..at + S].try_into().unwrap(),
                ys[at..at + S].try_into().unwrap(),
                ls[at..at + S].try_into().unwrap(),
                k[at..at + S].try_into().unwrap(),
            );
            t_u[kk] = u;
            t_grown[kk] = grown;
        }
        // Velocity of row r at r - 1 - chunk_at, gap index r at r - 1 - chunk_at of the chunk.
        T::tile_out(c.simd, out.vel, row0 - 1 - chunk_at, m, kn, &t_u);
        T::tile_out(c.simd, out.gaps, row0 - 1 - chunk_at, m, kn, &t_grown);
        k_hi = k0;
    }
    let mut u_first = zero;
    if g == 0 {
        let mut s0 = Back::<T, 1> {
            u_next: [st.u_next[0]],
            sum: [st.sum[0]],
            opening: [st.opening[0]],
            overshoot: [st.overshoot[0]],
            closing: [st.closing[0]],
            needs_fixup: [st.needs_fixup[0]],
        };
        for row in (1..=layout.rem).rev() {
            let i = row - 1;
            let (u, grown) = back_row::<T, 1, true>(
                h,
                gamma2,
                negligible,
                &mut s0,
                &[gaps_in[row]],
                &[clu && bonded_all[row]],
                &[w[i]],
                &[ys[i]],
                &[ls[i]],
                &[k[i]],
            );
            out.vel[i] = u[0];
            out.gaps[i] = grown[0];
        }
        st.sum[0] = s0.sum[0];
        st.opening[0] = s0.opening[0];
        st.overshoot[0] = s0.overshoot[0];
        st.closing[0] = s0.closing[0];
        st.needs_fixup[0] = s0.needs_fixup[0];
        u_first = s0.u_next[0];
    }
    // max and | do not depend on the order.
    GroupBack {
        sums: st.sum,
        opening: st.opening.iter().fold(zero, |a, &b| fmax(b, a)),
        overshoot: st.overshoot.iter().fold(zero, |a, &b| fmax(b, a)),
        closing: st.closing.iter().fold(T::NEG_INFINITY, |a, &b| fmax(b, a)),
        needs_fixup: st.needs_fixup.iter().any(|&f| f != T::Flag::default()),
        u_first,
    }
}

/// The interface values (tau_s, u of the next segment's first row) of every segment from the
/// segments' forward ends (the reduced system, swept like a Thomas system; see the module doc),
/// in f64 in either precision.
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
    T: PartitionedReal,
    const L: usize,
    const REP: bool,
    const CLU: bool,
    P,
    Q,
>(
    simd: SimdLevel,
    terms: &Terms<L, T>,
    n: usize,
    t: &[f64; L],
    h: &[T; L],
    gaps_in: &[T],
    vel_in: &[T],
    gaps_out: &mut [T],
    vel_out: &mut [T],
    scratch: &mut Scratch<T>,
    layout: Layout,
    law: Law<P, Q>,
) -> [StepReport; L]
where
    P: Fn(usize, T) -> T + Copy + Send + Sync,
    Q: Fn(usize) -> T + Copy + Send + Sync,
{
    assert_eq!(L, 1, "the partitioned solve is for one member");
    assert_eq!(gaps_in.len(), n);
    assert_eq!(vel_in.len(), n - 1);
    assert_eq!(Layout::new(n, layout.groups), Some(layout));
    let zero = T::ZERO;
    let floor = T::GAP_FLOOR;
    let (h0, t0) = (h[0], t[0]);
    let eps = terms.eps;
    let mass = T::c(2.0) * eps;
    let c = Step {
        simd,
        mu: terms.mu[0],
        eps,
        h: h0,
        t: t0,
        m_over_h: mass / h0,
        exact: terms.exact_jacobian,
    };
    let mut report = [StepReport::START; L];
    let p = layout.segments();
    // Positions of each segment's particle b - 1, summed in the sequential sweep's order (and
    // type).
    let mut q_start = Vec::new();
    if terms.forcing.is_some() {
        q_start = vec![zero; p];
        let mut q = zero;
        let mut s = 1;
        for row in 1..n {
            if s < p && row == layout.first_row(s) {
                q_start[s] = q;
                s += 1;
            }
            q += gaps_in[row - 1].decode_stored() + mass;
        }
    }
    let dstar_all: &[T] = terms.repulsion.map_or(&[], |r| r.0);
    let bonded_all: &[bool] = terms.bonded.unwrap_or(&[]);
    let inputs: Inputs<T> = (gaps_in, dstar_all, bonded_all, vel_in);

    // 1. The ends of every segment's forward sweep (and the forces).
    let group_ends: Vec<([SegmentEnd; SEGMENT_LANES], bool)> =
        split_chunks(&layout, &mut scratch.force)
            .into_par_iter()
            .enumerate()
            .map(|(g, force)| {
                ends_group_simd::<T, L, REP, P, Q>(
                    simd, terms, &layout, g, c, &q_start, &inputs, force, law,
                )
            })
            .collect();
    if group_ends.iter().any(|e| e.1) {
        report[0].hard = find_hard_failure(terms, law, n, 0, t0, h0, gaps_in);
    }
    let ends: Vec<SegmentEnd> = group_ends.iter().flat_map(|e| e.0).collect();

    // 2. The interface values, rounded once to T.
    let iface: Vec<(T, T)> = interfaces(&ends)
        .into_iter()
        .map(|(tau, u)| (T::c(tau), T::c(u)))
        .collect();

    // 3. Every segment solved from its interface values.
    let (gap_first, gaps_rest) = gaps_out.split_at_mut(1);
    let outs: Vec<Outputs<T>> = split_chunks(&layout, vel_out)
        .into_iter()
        .zip(split_chunks(&layout, gaps_rest))
        .zip(split_chunks(&layout, &mut scratch.force))
        .map(|((vel, gaps), force)| Outputs { vel, gaps, force })
        .collect();
    let backs: Vec<GroupBack<T>> = outs
        .into_par_iter()
        .enumerate()
        .map(|(g, out)| {
            // The thread's buffer is taken here: a closure inside the AVX2 instance would be
            // compiled without AVX2.
            T::with_rows(|buf| {
                solve_group_simd::<T, L, REP, P, Q>(
                    simd, terms, &layout, g, c, &iface, &inputs, out, buf, law,
                )
            })
        })
        .collect();
    // The sum of the new gaps in a fixed order (from the last segment down), so that it does
    // not depend on the thread count; in f64 in either precision.
    let mut sum = 0.0f64;
    let mut opening = zero;
    let mut overshoot = zero;
    let mut closing = T::NEG_INFINITY;
    let mut needs_fixup = false;
    for b in backs.iter().rev() {
        for s in b.sums.iter().rev() {
            sum += s;
        }
        opening = fmax(b.opening, opening);
        overshoot = fmax(b.overshoot, overshoot);
        closing = fmax(b.closing, closing);
        needs_fixup |= b.needs_fixup;
    }
    let u_first = backs[0].u_first;

    // 4. The rest as in the sequential path (step.rs `euler_impl`): bodies glued to the left
    // wall, the first gap, the certificate and the projection.
    if CLU {
        for i in 0..n - 1 {
            if !bonded_all[i] {
                break;
            }
            vel_out[i] = zero;
        }
    }
    let gamma2 = -((law.gamma)(0) + T::c(2.0));
    let old = gaps_in[0];
    let d = fmax(old, floor);
    let eps2 = T::c(2.0) * c.eps;
    let (inv_d, _) = gap_reciprocals::<T, REP>(d, eps2, reciprocal_scale(eps2));
    let k_first = jacobian_factor(c.exact, d, inv_d, h0, zero, vel_in[0]);
    let x = h0 * (u_first / d * k_first);
    let mut grown = old * gap_exp(x);
    if old > zero {
        opening = fmax(x, opening);
    }
    if grown > T::c(NEGLIGIBLE_OPENING * terms.total_gap[0]) {
        overshoot = fmax(x, overshoot);
    }
    closing = fmax(d * (gamma2 * fmin(x, zero) - T::ONE), closing);
    if !(grown >= floor && grown < T::INFINITY && x <= T::c(EXP_FAST_MAX)) {
        needs_fixup = true;
        grown = if CLU && bonded_all[0] {
            zero
        } else {
            fixed_up(old, x, grown)
        };
    }
    gap_first[0] = grown;
    sum += fmax(grown, zero).to_f64();
    report[0].admissible &= overshoot <= T::c(MAX_OPENING);
    // As the sequential sweep's.
    report[0].certified = !needs_fixup
        && energy_certified(
            REP,
            c.exact,
            closing.to_f64(),
            opening.to_f64(),
            mass.to_f64(),
            terms.contact_repulsion[0],
            (terms.mu[0] / h0).to_f64(),
        );
    let force = terms.forcing.is_some().then_some(scratch.force.as_slice());
    super::conclude_simd::<T, L, REP, CLU, P, Q>(
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
mod tests;
