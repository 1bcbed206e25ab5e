//! Fields over members: [`FieldBand`], pointwise moments and a fixed-bin histogram per grid point
//! (quantile bands), in one bulk pass over the rows of a chunk.

use serde::{Deserialize, Deserializer, Serialize, Serializer};

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
#[cfg(test)]
mod tests;

/// The serialized form (field names and layout of the study's chunk and partial files).
#[derive(Serialize)]
struct FieldBandRef<'a> {
    lo: f64,
    hi: f64,
    bins: u32,
    points: &'a [RunningStats],
    #[serde(serialize_with = "sparse_counts::serialize")]
    counts: Vec<Vec<u32>>,
}

#[derive(Deserialize)]
struct FieldBandState {
    lo: f64,
    hi: f64,
    bins: u32,
    points: Vec<RunningStats>,
    #[serde(deserialize_with = "sparse_counts::deserialize")]
    counts: Vec<Vec<u64>>,
}

/// The binary (columnar) form: see the type's documentation. Columns are little-endian byte
/// strings (one CBOR byte string each, written and read as a block).
#[derive(Serialize, Deserialize)]
struct FieldBandColumns {
    lo: f64,
    hi: f64,
    bins: u32,
    /// u64 per point.
    count: serde_bytes::ByteBuf,
    /// u64 per point.
    non_finite: serde_bytes::ByteBuf,
    /// `[mean, mean_lo, m2, min, max]` (f64) of every point, point after point.
    moments: serde_bytes::ByteBuf,
    /// Per point, how many of its slots are non-empty (u32).
    nonzero: serde_bytes::ByteBuf,
    /// The non-empty slots, each as its step from the previous one of its point (from -1): u16
    /// when the slots fit (bins < 65534), else u32.
    slot_steps: serde_bytes::ByteBuf,
    /// Their counts: u32 when every count fits, else u64.
    slot_counts: serde_bytes::ByteBuf,
    /// Bytes per entry of `slot_steps` and `slot_counts`.
    step_bytes: u8,
    count_bytes: u8,
}

/// Little-endian integers of `width` bytes (2, 4 or 8), appended to `out`.
fn put(out: &mut Vec<u8>, v: u64, width: u8) {
    out.extend_from_slice(&v.to_le_bytes()[..width as usize]);
}

/// The `i`-th little-endian integer of `width` bytes in `bytes`.
fn get(bytes: &[u8], i: usize, width: u8) -> u64 {
    let w = width as usize;
    let mut b = [0u8; 8];
    b[..w].copy_from_slice(&bytes[i * w..(i + 1) * w]);
    u64::from_le_bytes(b)
}

impl FieldBandColumns {
    fn of(band: &FieldBand) -> Self {
        let g = band.points.len();
        let step_bytes = if band.bins.len() + 2 <= u16::MAX as usize {
            2
        } else {
            4
        };
        // Counts are u32 in memory; 8-byte counts (state written before) are read when they fit.
        let count_bytes = 4;
        let (mut count, mut non_finite) = (Vec::with_capacity(8 * g), Vec::with_capacity(8 * g));
        let mut moments = Vec::with_capacity(40 * g);
        let mut nonzero = Vec::with_capacity(4 * g);
        let (mut steps, mut counts) = (Vec::new(), Vec::new());
        // Point j's moments and its non-empty slots with their counts, in increasing order.
        let mut emit = |j: usize, occupied: &mut dyn Iterator<Item = (usize, u32)>| {
            let (n, nf, m) = band.points[j].raw();
            put(&mut count, n, 8);
            put(&mut non_finite, nf, 8);
            for v in m {
                moments.extend_from_slice(&v.to_le_bytes());
            }
            let mut previous = -1i64;
            let mut filled = 0u64;
            for (slot, c) in occupied {
                put(&mut steps, (slot as i64 - previous) as u64, step_bytes);
                put(&mut counts, c.into(), count_bytes);
                previous = slot as i64;
                filled += 1;
            }
            put(&mut nonzero, filled, 4);
        };
        if band.dense {
            band.for_each_point(|j, slots, occupied| {
                let start = occupied.start;
                emit(
                    j,
                    &mut slots[occupied]
                        .iter()
                        .enumerate()
                        .filter(|(_, &c)| c > 0)
                        .map(|(s, &c)| (start + s, c)),
                )
            });
        } else {
            // A held point's values in order: its non-empty slots are their runs.
            let mut sorted = Vec::with_capacity(band.held_rows);
            for j in 0..g {
                band.held_sorted(j, &mut sorted);
                emit(
                    j,
                    &mut sorted
                        .chunk_by(|a, b| a == b)
                        .map(|run| (run[0] as usize, run.len() as u32)),
                );
            }
        }
        FieldBandColumns {
            lo: band.bins.lo(),
            hi: band.bins.hi(),
            bins: band.bins.len() as u32,
            count: serde_bytes::ByteBuf::from(count),
            non_finite: serde_bytes::ByteBuf::from(non_finite),
            moments: serde_bytes::ByteBuf::from(moments),
            nonzero: serde_bytes::ByteBuf::from(nonzero),
            slot_steps: serde_bytes::ByteBuf::from(steps),
            slot_counts: serde_bytes::ByteBuf::from(counts),
            step_bytes,
            count_bytes,
        }
    }

    fn into_band(self) -> Result<FieldBand, StatsError> {
        let bins = Bins::new(self.lo, self.hi, self.bins as usize)?;
        let bad = |message: String| StatsError::InvalidState {
            what: "field band",
            message,
        };
        if ![2, 4].contains(&self.step_bytes) || ![4, 8].contains(&self.count_bytes) {
            return Err(bad("unknown integer widths".into()));
        }
        let g = self.count.len() / 8;
        let entries = self.slot_steps.len() / self.step_bytes as usize;
        if self.count.len() != 8 * g
            || self.non_finite.len() != 8 * g
            || self.moments.len() != 40 * g
            || self.nonzero.len() != 4 * g
            || self.slot_steps.len() != entries * self.step_bytes as usize
            || self.slot_counts.len() != entries * self.count_bytes as usize
        {
            return Err(bad("columns of different lengths".into()));
        }
        let filled: u64 = (0..g).map(|j| get(&self.nonzero, j, 4)).sum();
        if filled != entries as u64 {
            return Err(bad("slot columns do not add up".into()));
        }
        let mut points = Vec::with_capacity(g);
        let stride = bins.len() + 2;
        let mut slots = vec![0u32; g * stride];
        let mut next = 0;
        for j in 0..g {
            let m: [f64; 5] =
                std::array::from_fn(|k| f64::from_bits(get(&self.moments, 5 * j + k, 8)));
            points.push(RunningStats::from_raw(
                get(&self.count, j, 8),
                get(&self.non_finite, j, 8),
                m,
            ));
            let row = &mut slots[j * stride..(j + 1) * stride];
            let mut slot = -1i64;
            for _ in 0..get(&self.nonzero, j, 4) {
                slot += get(&self.slot_steps, next, self.step_bytes) as i64;
                let count = get(&self.slot_counts, next, self.count_bytes);
                *row.get_mut(slot as usize)
                    .ok_or_else(|| bad(format!("slot {slot} beyond {stride}")))? =
                    u32::try_from(count)
                        .map_err(|_| bad(format!("count {count} beyond {}", u32::MAX)))?;
                next += 1;
            }
        }
        Ok(FieldBand::from_parts(bins, points, slots))
    }
}

impl Serialize for FieldBand {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        if !s.is_human_readable() {
            return FieldBandColumns::of(self).serialize(s);
        }
        FieldBandRef {
            lo: self.bins.lo(),
            hi: self.bins.hi(),
            bins: self.bins.len() as u32,
            points: &self.points,
            counts: {
                let mut counts = Vec::with_capacity(self.points());
                self.for_each_point(|_, slots, _| counts.push(slots.to_vec()));
                counts
            },
        }
        .serialize(s)
    }
}

impl<'de> Deserialize<'de> for FieldBand {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        if !d.is_human_readable() {
            return FieldBandColumns::deserialize(d)?
                .into_band()
                .map_err(serde::de::Error::custom);
        }
        let st = FieldBandState::deserialize(d)?;
        FieldBand::try_from(st).map_err(serde::de::Error::custom)
    }
}

impl TryFrom<FieldBandState> for FieldBand {
    type Error = StatsError;

    fn try_from(st: FieldBandState) -> Result<Self, StatsError> {
        let bins = Bins::new(st.lo, st.hi, st.bins as usize)?;
        if st.counts.len() != st.points.len() {
            return Err(StatsError::LengthMismatch {
                what: "serialized field band counts",
                expected: st.points.len(),
                got: st.counts.len(),
            });
        }
        if let Some(row) = st.counts.iter().find(|r| r.len() != bins.len() + 2) {
            return Err(StatsError::LengthMismatch {
                what: "serialized field band slots",
                expected: bins.len() + 2,
                got: row.len(),
            });
        }
        let mut slots = Vec::with_capacity(st.counts.len() * (bins.len() + 2));
        for &c in st.counts.iter().flatten() {
            slots.push(u32::try_from(c).map_err(|_| StatsError::CountOverflow {
                what: "serialized field band slot",
                limit: u32::MAX as u64,
            })?);
        }
        Ok(FieldBand::from_parts(bins, st.points, slots))
    }
}

/// Histogram counts are mostly zero: on disk each row is a list of (slot, count) pairs.
mod sparse_counts {
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    #[derive(Serialize, Deserialize)]
    struct Row {
        len: usize,
        nonzero: Vec<(u32, u64)>,
    }

    pub fn serialize<S: Serializer>(rows: &[Vec<u32>], s: S) -> Result<S::Ok, S::Error> {
        let sparse: Vec<Row> = rows
            .iter()
            .map(|r| Row {
                len: r.len(),
                nonzero: r
                    .iter()
                    .enumerate()
                    .filter(|(_, &c)| c > 0)
                    .map(|(b, &c)| (b as u32, u64::from(c)))
                    .collect(),
            })
            .collect();
        sparse.serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<Vec<u64>>, D::Error> {
        let sparse = Vec::<Row>::deserialize(d)?;
        let mut rows = Vec::with_capacity(sparse.len());
        for row in sparse {
            let mut dense = vec![0u64; row.len];
            for (b, c) in row.nonzero {
                let slot = dense.get_mut(b as usize).ok_or_else(|| {
                    serde::de::Error::custom(format!("histogram bin {b} beyond {}", row.len))
                })?;
                *slot = c;
            }
            rows.push(dense);
        }
        Ok(rows)
    }
}
