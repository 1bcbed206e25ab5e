//! Fields over members: [`FieldBand`], pointwise moments and a fixed-bin histogram per grid point
//! (quantile bands), in one bulk pass over the rows of a chunk.

use roughlub_kernels::SimdLevel;

use std::ops::Range;

use super::histogram::{check_levels, levels_in_order, occupied_slots};
use super::{Bins, Histogram, RunningStats, StatsError};
use fill::{fill_block, Counter, DenseCounts, HeldSlots, BLOCK};
#[cfg(target_arch = "x86_64")]
use fill::{fill_block_avx2, fill_block_avx512};

/// A held entry of a value that is counted nowhere (NaN or an infinity).
const UNCOUNTED: u32 = u32::MAX;

/// Pointwise statistics of a field sampled on a grid of G points, over members: per point the
/// moments ([`RunningStats`], Chan-mergeable) and the counts of a fixed-bin histogram on
/// `[lo, hi]` ([`Bins`], the same bins at every point), from which quantiles are read.
///
/// # Quantiles
///
/// [`quantile_row`](Self::quantile_row) reports, at each point, the midpoint of the bin that
/// holds the value of rank `floor(q (n - 1))` among the point's `n` finite values, so it is
/// within half a bin width, `(hi - lo) / (2 bins)`, of that value. Values outside `[lo, hi]` are
/// counted apart (underflow / overflow); a quantile whose rank falls among them is NaN
/// (reported, never guessed). Histogram counts merge exactly, so sharded bands equal unsharded
/// ones bit for bit (quantiles included); moments agree to rounding.
///
/// # Non-finite values
///
/// NaN and ±infinity are rejected pointwise: they enter neither the moments nor the counts and
/// are counted in that point's [`RunningStats::non_finite`].
///
/// # Few members
///
/// A band that holds few rows (at most a quarter of its slots a point: 100 rows for 400 bins)
/// keeps each row's slots as they are and counts them only when read: the per-point bands of a
/// sampled design hold one member each, and 402 counters a grid point for one value made their
/// memory and its first touch most of a small study's statistics. Past that many rows it
/// counts them into the slots, as a band of many members does from its first push. Both
/// give the same counts, so the same quantiles, histograms and state files.
///
/// # Serialization
///
/// Human-readable formats (JSON): `{lo, hi, bins, points, counts}`, where `counts` holds per
/// point the `bins + 2` slot counts (underflow, bins, overflow) stored sparse:
/// `{len, nonzero: [[slot, count], ...]}`. Binary formats (the study's CBOR state files): one
/// column per moment over the points, and the non-empty slots of all points as step/count
/// columns (small integers, which CBOR stores in one or two bytes): the size follows what the
/// band holds, not `points × bins`.
#[derive(Clone, Debug)]
pub struct FieldBand {
    bins: Bins,
    points: Vec<RunningStats>,
    /// Once `dense`: per point, `bins + 2` slot counts (see [`Bins::slot`]), point after point
    /// in one block: the fill indexes it without a pointer per point, and u32 halves what is
    /// zeroed, scanned and read. A point holds at most `u32::MAX` values (4 billion members of
    /// one sweep point); more is refused ([`StatsError::CountOverflow`]), never wrapped. Empty
    /// before.
    slots: Vec<u32>,
    /// Until `dense`: the slot of every value pushed, row after row of G points
    /// ([`UNCOUNTED`] for a non-finite value), `held_rows` rows. Empty after.
    held: Vec<u32>,
    held_rows: usize,
    dense: bool,
}

impl FieldBand {
    /// An empty band of a field with `points` grid points, `bins` equal bins on `[lo, hi]`.
    pub fn new(points: usize, lo: f64, hi: f64, bins: usize) -> Result<Self, StatsError> {
        let bins = Bins::new(lo, hi, bins)?;
        Ok(FieldBand::from_parts(
            bins,
            vec![RunningStats::new(); points],
            Vec::new(),
        ))
    }

    /// A band of these points: dense with these slot counts, or held and empty if there are
    /// none (a new band).
    fn from_parts(bins: Bins, points: Vec<RunningStats>, slots: Vec<u32>) -> Self {
        let dense = !slots.is_empty();
        FieldBand {
            bins,
            points,
            slots,
            held: Vec::new(),
            held_rows: 0,
            dense,
        }
    }

    /// The most rows a band of `bins` bins holds before it counts them into slots: their
    /// entries then take a quarter of the slots' memory (the study's memory estimate uses it).
    pub(crate) fn max_held_rows_for(bins: usize) -> usize {
        (bins + 2) / 4
    }

    fn max_held_rows(&self) -> usize {
        Self::max_held_rows_for(self.bins.len())
    }

    /// Counts rows of held slots (`held`, rows of G points) into the dense `slots`.
    fn count_held(held: &[u32], stride: usize, slots: &mut [u32]) {
        let g = slots.len() / stride;
        for row in held.chunks_exact(g.max(1)) {
            for (j, &s) in row.iter().enumerate().filter(|(_, &s)| s != UNCOUNTED) {
                slots[j * stride + s as usize] += 1;
            }
        }
    }

    /// The slots of point `j`'s finite values while the band holds its rows.
    fn held_values(&self, j: usize) -> impl Iterator<Item = usize> + '_ {
        self.held
            .iter()
            .skip(j)
            .step_by(self.points.len())
            .filter(|&&s| s != UNCOUNTED)
            .map(|&s| s as usize)
    }

    /// The slots of point `j`'s finite held values, in increasing order, into `sorted`.
    fn held_sorted(&self, j: usize, sorted: &mut Vec<u32>) {
        sorted.clear();
        sorted.extend(self.held_values(j).map(|s| s as u32));
        sorted.sort_unstable();
    }

    /// Counts the held rows into slots; from then on pushes and merges count there.
    fn make_dense(&mut self) {
        if self.dense {
            return;
        }
        let stride = self.stride();
        let mut slots = vec![0u32; self.points.len() * stride];
        Self::count_held(&self.held, stride, &mut slots);
        self.slots = slots;
        self.held = Vec::new();
        self.held_rows = 0;
        self.dense = true;
    }

    /// Calls `f` with each point's index, slot counts and occupied slots (empty outside them),
    /// in order: a held band counts each point's values into one reused array, cleared after
    /// each call.
    fn for_each_point(&self, mut f: impl FnMut(usize, &[u32], Range<usize>)) {
        let (g, stride) = (self.points.len(), self.stride());
        if self.dense {
            for (j, slots) in self.slots.chunks_exact(stride).enumerate() {
                f(j, slots, occupied_slots(slots));
            }
            return;
        }
        let mut slots = vec![0u32; stride];
        for j in 0..g {
            let (mut first, mut last) = (stride, 0);
            for s in self.held_values(j) {
                slots[s] += 1;
                (first, last) = (first.min(s), last.max(s + 1));
            }
            f(j, &slots, first.min(last)..last);
            for s in self.held_values(j) {
                slots[s] = 0;
            }
        }
    }

    /// Slots per point: the bins, underflow and overflow.
    fn stride(&self) -> usize {
        self.bins.len() + 2
    }

    /// The slot counts of point `j`.
    fn point_slots(&self, j: usize) -> std::borrow::Cow<'_, [u32]> {
        let stride = self.stride();
        if self.dense {
            return self.slots[j * stride..(j + 1) * stride].into();
        }
        let mut slots = vec![0u32; stride];
        for s in self.held_values(j) {
            slots[s] += 1;
        }
        slots.into()
    }

    /// Fails unless every point can count `extra` more values (see [`slots`](Self::slots)).
    fn check_room(&self, extra: impl Fn(usize) -> u64) -> Result<(), StatsError> {
        for (j, p) in self.points.iter().enumerate() {
            if p.count().saturating_add(extra(j)) > u32::MAX as u64 {
                return Err(StatsError::CountOverflow {
                    what: "field band point",
                    limit: u32::MAX as u64,
                });
            }
        }
        Ok(())
    }

    /// Number of grid points G.
    pub fn points(&self) -> usize {
        self.points.len()
    }

    /// The bins of every point.
    pub fn binning(&self) -> &Bins {
        &self.bins
    }

    /// Per-point moments.
    pub fn stats(&self) -> &[RunningStats] {
        &self.points
    }

    /// The histogram of point `j` (panics if `j >= points()`).
    pub fn histogram(&self, j: usize) -> Histogram {
        Histogram::from_slots(
            self.bins,
            self.point_slots(j).iter().map(|&c| u64::from(c)).collect(),
            self.points[j].non_finite(),
        )
    }

    /// Adds the rows of one chunk of members (each row of length G). Moments are accumulated in
    /// bulk (shifted sums, then one Chan merge per point) because this is the hot part of a
    /// study's statistics. Fails, adding nothing, if a row's length is not G or a point would
    /// hold more than `u32::MAX` values.
    pub fn push_rows(&mut self, rows: &[&[f64]]) -> Result<(), StatsError> {
        // The widest instruction set here (every level gives the same bits; `ROUGHLUB_CPU_SIMD`
        // caps the step's, not this).
        self.push_rows_at(SimdLevel::widest_here(), rows)
    }

    /// [`push_rows`](Self::push_rows) at a given instruction set (at most what the CPU runs,
    /// [`SimdLevel::widest_here`]): every level does the same operations in the same order, so
    /// the same bits.
    fn push_rows_at(&mut self, level: SimdLevel, rows: &[&[f64]]) -> Result<(), StatsError> {
        let level = level.min(SimdLevel::widest_here());
        let g = self.points.len();
        if let Some(bad) = rows.iter().find(|r| r.len() != g) {
            return Err(StatsError::LengthMismatch {
                what: "field row",
                expected: g,
                got: bad.len(),
            });
        }
        self.check_room(|_| rows.len() as u64)?;
        if rows.is_empty() {
            return Ok(());
        }
        if self.held_rows + rows.len() > self.max_held_rows() {
            self.make_dense();
        }
        let (bins, stride) = (self.bins, self.stride());
        if self.dense {
            let blocks = self
                .points
                .chunks_mut(BLOCK)
                .zip(self.slots.chunks_mut(BLOCK * stride));
            for (b, (points, slots)) in blocks.enumerate() {
                let counts = DenseCounts { slots, stride };
                fill_at(level, bins, rows, b * BLOCK, points, counts);
            }
            return Ok(());
        }
        let first = self.held.len();
        self.held.resize(first + rows.len() * g, UNCOUNTED);
        for (b, points) in self.points.chunks_mut(BLOCK).enumerate() {
            let held = HeldSlots {
                held: &mut self.held[first..],
                points: g,
                j0: b * BLOCK,
            };
            fill_at(level, bins, rows, b * BLOCK, points, held);
        }
        self.held_rows += rows.len();
        Ok(())
    }

    /// Undoes earlier pushes exactly: the moments are set back to `moments_before` (what
    /// [`stats`](Self::stats) held before them; floating-point sums cannot be subtracted back
    /// bit for bit) and the slot counts of `rows`, the rows those pushes added, are taken out
    /// (integers, so exactly). Fails, changing nothing, if the lengths do not match or a slot
    /// would go below zero (rows that were never pushed).
    pub fn undo_pushes(
        &mut self,
        moments_before: &[RunningStats],
        rows: &[&[f64]],
    ) -> Result<(), StatsError> {
        let g = self.points.len();
        if moments_before.len() != g {
            return Err(StatsError::LengthMismatch {
                what: "field band points",
                expected: g,
                got: moments_before.len(),
            });
        }
        if let Some(bad) = rows.iter().find(|r| r.len() != g) {
            return Err(StatsError::LengthMismatch {
                what: "field row",
                expected: g,
                got: bad.len(),
            });
        }
        self.make_dense();
        let stride = self.stride();
        let mut slots = self.slots.clone();
        for row in rows {
            for (j, &x) in row.iter().enumerate().filter(|(_, x)| x.is_finite()) {
                let count = &mut slots[j * stride + self.bins.slot(x)];
                *count = count.checked_sub(1).ok_or(StatsError::NotCounted {
                    what: "field band row taken out",
                })?;
            }
        }
        self.slots = slots;
        self.points.clone_from_slice(moments_before);
        Ok(())
    }

    /// Merges pointwise; fails, leaving `self` unchanged, if G or the bins differ or a point
    /// would hold more than `u32::MAX` values.
    pub fn merge(&mut self, other: &FieldBand) -> Result<(), StatsError> {
        self.bins.check_compatible(&other.bins)?;
        if other.points() != self.points() {
            return Err(StatsError::LengthMismatch {
                what: "field band points",
                expected: self.points(),
                got: other.points(),
            });
        }
        self.check_room(|j| other.points[j].count())?;
        for (a, b) in self.points.iter_mut().zip(&other.points) {
            a.merge(b);
        }
        if other.dense || self.held_rows + other.held_rows > self.max_held_rows() {
            self.make_dense();
        }
        if !self.dense {
            self.held.extend_from_slice(&other.held);
            self.held_rows += other.held_rows;
        } else if other.dense {
            for (x, y) in self.slots.iter_mut().zip(&other.slots) {
                *x += y;
            }
        } else {
            Self::count_held(&other.held, self.stride(), &mut self.slots);
        }
        Ok(())
    }

    /// Pointwise mean (NaN where a point has no finite value).
    pub fn mean_row(&self) -> Vec<f64> {
        self.points.iter().map(RunningStats::mean).collect()
    }

    /// Pointwise sample variance (NaN where a point has fewer than two finite values).
    pub fn variance_row(&self) -> Vec<f64> {
        self.points.iter().map(RunningStats::variance).collect()
    }

    /// Pointwise sample standard deviation (NaN where a point has fewer than two finite values).
    pub fn std_row(&self) -> Vec<f64> {
        self.points.iter().map(RunningStats::std).collect()
    }

    /// Pointwise minimum (NaN where empty).
    pub fn min_row(&self) -> Vec<f64> {
        self.points.iter().map(RunningStats::min).collect()
    }

    /// Pointwise maximum (NaN where empty).
    pub fn max_row(&self) -> Vec<f64> {
        self.points.iter().map(RunningStats::max).collect()
    }

    /// Pointwise `q`-quantile (see the type's documentation: within half a bin width; NaN where
    /// a point has no finite value or the value of that rank is outside `[lo, hi]`). Fails if `q`
    /// is not in `[0, 1]`.
    pub fn quantile_row(&self, q: f64) -> Result<Vec<f64>, StatsError> {
        Ok(self.quantile_rows(&[q])?.swap_remove(0))
    }

    /// [`quantile_row`](Self::quantile_row) at each level of `qs` (one row per level, in that
    /// order), from one pass over each point's slots.
    pub fn quantile_rows(&self, qs: &[f64]) -> Result<Vec<Vec<f64>>, StatsError> {
        check_levels(qs)?;
        let mut rows = vec![Vec::with_capacity(self.points()); qs.len()];
        let (by_level, mut values) = (levels_in_order(qs), vec![f64::NAN; qs.len()]);
        if !self.dense {
            // A point's few held values in order give their ranks directly: no slot counts to
            // fill, walk and clear (the detailed points of a sampled design hold one member).
            let mut sorted = Vec::with_capacity(self.held_rows);
            for j in 0..self.points() {
                self.held_sorted(j, &mut sorted);
                self.bins.quantiles_of_sorted(&sorted, qs, &mut values);
                for (row, &v) in rows.iter_mut().zip(&values) {
                    row.push(v);
                }
            }
            return Ok(rows);
        }
        self.for_each_point(|_, slots, occupied| {
            self.bins
                .quantiles_in(slots, occupied, qs, &by_level, &mut values);
            for (row, &v) in rows.iter_mut().zip(&values) {
                row.push(v);
            }
        });
        Ok(rows)
    }
}

/// [`fill_block`] at the instruction set `level` (at most what the CPU runs).
fn fill_at<C: Counter>(
    level: SimdLevel,
    bins: Bins,
    rows: &[&[f64]],
    j0: usize,
    points: &mut [RunningStats],
    counter: C,
) {
    #[cfg(target_arch = "x86_64")]
    match level {
        // SAFETY: the CPU has AVX-512 F/VL/DQ (`level` is at most `widest_here`).
        SimdLevel::Avx512 => return unsafe { fill_block_avx512(bins, rows, j0, points, counter) },
        // SAFETY: the CPU has AVX2 (`level` is at most `widest_here`).
        SimdLevel::Avx2Fma => return unsafe { fill_block_avx2(bins, rows, j0, points, counter) },
        SimdLevel::Portable => {}
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = level;
    fill_block(bins, rows, j0, points, counter)
}

mod fill;
mod serialized;
#[cfg(test)]
mod tests;
