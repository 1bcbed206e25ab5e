//! The fill of a [`FieldBand`](super::FieldBand): a chunk's rows into a block of grid points'
//! moments and histogram slots, one body compiled for each instruction set.

use super::{Bins, RunningStats};

/// Points per block of the fill: a block's slot counts stay in cache while the rows stream
/// through it.
pub(super) const BLOCK: usize = 64;

/// How many rows ahead the fill asks for its part of a row: the rows are members' snapshots,
/// apart in memory and often in another core's cache, so the prefetcher cannot guess them
/// (the study's fill took 14 % less time with it).
const PREFETCH_AHEAD: usize = 2;

/// [`fill_block`] compiled for AVX2: the same operations in the same order (no FMA contraction
/// in Rust), so the same bits, on 4 lanes instead of 2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
pub(super) fn fill_block_avx2<C: Counter>(
    bins: Bins,
    rows: &[&[f64]],
    j0: usize,
    points: &mut [RunningStats],
    counter: C,
) {
    fill_block(bins, rows, j0, points, counter)
}

/// [`fill_block`] compiled for AVX-512: 8 lanes, and 32 registers for the block's sums
/// (1.5-2 times the AVX2 fill's speed, `cargo bench --bench field_band`).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vl,avx512dq,avx2,fma")]
pub(super) fn fill_block_avx512<C: Counter>(
    bins: Bins,
    rows: &[&[f64]],
    j0: usize,
    points: &mut [RunningStats],
    counter: C,
) {
    fill_block(bins, rows, j0, points, counter)
}

/// Where the fill puts each finite value's slot: counted in the block's dense slots, or held
/// as it is while the band holds few rows.
pub(super) trait Counter {
    /// The value of row `m` at the block's point `k` falls in `slot` (in `0..=bins + 1`).
    fn count(&mut self, m: usize, k: usize, slot: i32);
}

/// A block's `bins + 2` slot counts a point, point after point.
pub(super) struct DenseCounts<'a> {
    pub slots: &'a mut [u32],
    pub stride: usize,
}

impl Counter for DenseCounts<'_> {
    #[inline(always)]
    fn count(&mut self, _m: usize, k: usize, slot: i32) {
        // SAFETY: slot is in [0, bins + 1] and k < the block's width, so the index is inside
        // the block's `width * stride` slots.
        unsafe {
            *self
                .slots
                .get_unchecked_mut(k * self.stride + slot as usize) += 1
        };
    }
}

/// The slots of the rows being pushed, row after row, each of G points (the entries of a
/// non-finite value keep [`UNCOUNTED`](super::UNCOUNTED)); the block starts at point `j0`.
pub(super) struct HeldSlots<'a> {
    pub held: &'a mut [u32],
    pub points: usize,
    pub j0: usize,
}

impl Counter for HeldSlots<'_> {
    #[inline(always)]
    fn count(&mut self, m: usize, k: usize, slot: i32) {
        self.held[m * self.points + self.j0 + k] = slot as u32;
    }
}

/// The body of [`FieldBand::push_rows`] for the block of points `j0..j0 + points.len()` (rows of
/// length G already checked, at least one row): its moments, and each finite value's slot to
/// `counter`.
#[inline(always)]
pub(super) fn fill_block<C: Counter>(
    bins: Bins,
    rows: &[&[f64]],
    j0: usize,
    points: &mut [RunningStats],
    mut counter: C,
) {
    let first_row = rows[0];
    let width = points.len();
    let (lo, hi, scale) = (bins.lo(), bins.hi(), bins.scale());
    let last_bin = (bins.len() - 1) as f64;
    // Slots as i32: `Bins::new` allows at most MAX_BINS bins.
    let above = (bins.len() + 1) as i32;
    // Bins::slot, branch-free. For lo <= x <= hi the bin is (x - lo) scale truncated (>= 0,
    // so truncation is floor). Clamped to [-1, last bin] first (NaN becomes -1), the
    // truncation fits an i32 for every x, so it converts packed without Rust's saturating
    // `as` (a scalar conversion per value); values clamped up are below lo, slot 0 anyway.
    let slot_of = |x: f64| -> i32 {
        let t = ((x - lo) * scale).max(-1.0).min(last_bin);
        // SAFETY: t is finite and in [-1, MAX_BINS - 1], which i32 holds.
        let bin = 1 + unsafe { t.to_int_unchecked::<i32>() };
        if x < lo {
            0
        } else if x > hi {
            above
        } else {
            bin
        }
    };
    // Shift each point by its first finite value (keeps the shifted sums well
    // conditioned); NaN for a point without one, which then adds nothing.
    let mut shift = [f64::NAN; BLOCK];
    for (k, s) in shift[..width].iter_mut().enumerate() {
        let first = first_row[j0 + k];
        *s = if first.is_finite() {
            first
        } else {
            rows.iter()
                .map(|r| r[j0 + k])
                .find(|x| x.is_finite())
                .unwrap_or(f64::NAN)
        };
    }
    let mut n = [0u64; BLOCK];
    // Rows without a non-finite value, counted once for every point of the block.
    let mut finite_rows = 0u64;
    let mut s1 = [0.0f64; BLOCK];
    let mut s2 = [0.0f64; BLOCK];
    let mut min = [f64::INFINITY; BLOCK];
    let mut max = [f64::NEG_INFINITY; BLOCK];
    let mut slot = [0i32; BLOCK];
    // Members outer, the points of a row inner: each point's sums run over the rows in order
    // (the result does not depend on the blocking), and the moment updates are straight-line
    // over the block (packed SIMD).
    for (m, row) in rows.iter().enumerate() {
        #[cfg(target_arch = "x86_64")]
        if let Some(next) = rows.get(m + PREFETCH_AHEAD) {
            for line in next[j0..j0 + width].chunks(8) {
                // SAFETY: a prefetch is a hint; the address is inside the row.
                unsafe {
                    std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(
                        line.as_ptr().cast(),
                    )
                };
            }
        }
        let xs = &row[j0..j0 + width];
        // A row without NaN or infinity (nearly all) takes the loop without the
        // non-finite selects; both loops do the same arithmetic on finite values.
        if xs.iter().fold(true, |all, x| all & x.is_finite()) {
            for k in 0..width {
                let x = xs[k];
                let d = x - shift[k];
                s1[k] += d;
                s2[k] += d * d;
                min[k] = min[k].min(x);
                max[k] = max[k].max(x);
                slot[k] = slot_of(x);
            }
            for (k, &s) in slot[..width].iter().enumerate() {
                counter.count(m, k, s);
            }
            finite_rows += 1;
            continue;
        }
        for k in 0..width {
            let x = xs[k];
            let finite = x.is_finite();
            // Adding 0.0 to a sum that started at +0.0 leaves it bit for bit as it was.
            let d = if finite { x - shift[k] } else { 0.0 };
            n[k] += finite as u64;
            s1[k] += d;
            s2[k] += d * d;
            min[k] = min[k].min(if finite { x } else { f64::INFINITY });
            max[k] = max[k].max(if finite { x } else { f64::NEG_INFINITY });
            slot[k] = slot_of(x);
        }
        for k in 0..width {
            if xs[k].is_finite() {
                counter.count(m, k, slot[k]);
            }
        }
    }
    for (k, point) in points.iter_mut().enumerate() {
        n[k] += finite_rows;
        let non_finite = rows.len() as u64 - n[k];
        if n[k] > 0 {
            let mean_d = s1[k] / n[k] as f64;
            let m2 = (s2[k] - s1[k] * mean_d).max(0.0);
            point.merge(&RunningStats::from_moments(
                n[k],
                shift[k] + mean_d,
                m2,
                min[k],
                max[k],
            ));
        }
        point.add_non_finite(non_finite);
    }
}
