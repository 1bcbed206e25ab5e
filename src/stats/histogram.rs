//! Fixed equal-width bins: [`Bins`] (the one binning rule, shared by [`Histogram`] and
//! [`FieldBand`](super::FieldBand)) and [`Histogram`] (counts in those bins plus underflow and
//! overflow), with quantiles read from bin midpoints.

use serde::{Deserialize, Serialize};

use super::StatsError;

/// The most bins a histogram may have: slots (bins + 2) are counted as i32 in the field bands'
/// bulk fill.
pub const MAX_BINS: usize = i32::MAX as usize - 2;

/// `bins` equal bins on `[lo, hi]`: the one binning rule of this crate.
///
/// A finite `lo <= x <= hi` is in bin `min(trunc(fl(fl(x - lo) * fl(bins / (hi - lo)))), bins -
/// 1)`: one subtraction, one multiplication and a truncation, cheap enough for the hot loop of
/// [`FieldBand::push_rows`](super::FieldBand::push_rows). `x < lo` is underflow, `x > hi`
/// overflow. Counts are kept in *slots*: slot 0 is underflow, slots `1..=bins` the bins, slot
/// `bins + 1` overflow ([`slot`](Self::slot)).
///
/// The rule is monotone in `x`, so bin `i` is exactly the interval `edge(i) <= x < edge(i + 1)`
/// (the last bin also `x == hi`, NumPy's convention) with [`edge`](Self::edge)`(i)` the smallest
/// `f64` that the rule puts in bin `i` or above: `edge(0) = lo`, `edge(bins) = hi`, and in
/// between within a few units in the last place of `lo + i (hi - lo) / bins`. Where the bins are
/// narrower than the spacing of the `f64` values, consecutive edges coincide and the bins between
/// them stay empty.
#[derive(Clone, Copy, Debug)]
pub struct Bins {
    lo: f64,
    hi: f64,
    bins: usize,
    /// Derived: `bins / (hi - lo)`.
    scale: f64,
}

impl Bins {
    /// `bins` equal bins on `[lo, hi]`; needs finite `lo < hi` with finite `hi - lo`, and
    /// `1 <= bins <= 2^32 - 1`.
    pub fn new(lo: f64, hi: f64, bins: usize) -> Result<Self, StatsError> {
        if !(lo < hi && (hi - lo).is_finite()) || bins == 0 || bins > MAX_BINS {
            return Err(StatsError::InvalidHistogram { lo, hi, bins });
        }
        Ok(Bins {
            lo,
            hi,
            bins,
            scale: bins as f64 / (hi - lo),
        })
    }

    /// Left edge of the range.
    pub fn lo(&self) -> f64 {
        self.lo
    }

    /// Right edge of the range.
    pub fn hi(&self) -> f64 {
        self.hi
    }

    /// Bins per unit of x: `bins / (hi - lo)`.
    pub fn scale(&self) -> f64 {
        self.scale
    }

    /// Number of bins.
    pub fn len(&self) -> usize {
        self.bins
    }

    /// Always false (there is at least one bin).
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Bin width `(hi - lo) / bins`.
    pub fn width(&self) -> f64 {
        (self.hi - self.lo) / self.bins as f64
    }

    /// Edge `i` (0..=bins): `lo` for `i = 0`, `hi` for `i >= bins`, otherwise the smallest `f64`
    /// in `[lo, hi]` that [`slot`](Self::slot) puts in bin `i` or above (found by bisection over
    /// the ordered `f64` values, so bin membership agrees exactly with the edges).
    pub fn edge(&self, i: usize) -> f64 {
        if i == 0 {
            return self.lo;
        }
        if i >= self.bins {
            return self.hi;
        }
        // f64 <-> integers in the same order (as in `f64::total_cmp`).
        let key = |x: f64| {
            let b = x.to_bits() as i64;
            b ^ (((b >> 63) as u64) >> 1) as i64
        };
        let value = |k: i64| f64::from_bits((k ^ (((k >> 63) as u64) >> 1) as i64) as u64);
        let (lo_key, hi_key) = (key(self.lo), key(self.hi));
        // The edge is within a few ulps of lo + i width: walk from there (a study writes
        // thousands of edges), and bisect only if the walk does not end soon.
        let guess = (self.lo + i as f64 * self.width()).clamp(self.lo, self.hi);
        let mut k = key(guess);
        for _ in 0..64 {
            if self.bin(value(k)) >= i {
                if k == lo_key || self.bin(value(k - 1)) < i {
                    return value(k) + 0.0; // -0.0 -> +0.0
                }
                k -= 1;
            } else {
                if k == hi_key {
                    break;
                }
                k += 1;
            }
        }
        // Invariant: bin(a) < i <= bin(b); bin(lo) = 0 and bin(hi) = bins - 1.
        let (mut a, mut b) = (lo_key, hi_key);
        while (b as i128 - a as i128) > 1 {
            let mid = ((a as i128 + b as i128) >> 1) as i64;
            if self.bin(value(mid)) >= i {
                b = mid;
            } else {
                a = mid;
            }
        }
        value(b) + 0.0 // -0.0 -> +0.0
    }

    /// The `bins + 1` bin edges.
    pub fn edges(&self) -> Vec<f64> {
        (0..=self.bins).map(|i| self.edge(i)).collect()
    }

    /// Midpoint `lo + (i + 1/2) width` of bin `i` (0-based).
    #[inline]
    pub fn midpoint(&self, i: usize) -> f64 {
        self.lo + (i as f64 + 0.5) * self.width()
    }

    /// The bin of `lo <= x <= hi` (see the type's documentation).
    #[inline]
    fn bin(&self, x: f64) -> usize {
        (((x - self.lo) * self.scale) as usize).min(self.bins - 1) // `as` saturates, >= 0
    }

    /// The slot of a finite `x`: 0 below `lo`, `1 + i` for bin `i`, `bins + 1` above `hi`.
    /// (A NaN lands in slot 1; callers reject non-finite values first.)
    #[inline]
    pub fn slot(&self, x: f64) -> usize {
        if x < self.lo {
            0
        } else if x > self.hi {
            self.bins + 1
        } else {
            1 + self.bin(x)
        }
    }

    /// The `q`-quantile of the values counted in `slots` (`bins + 2` slots, see
    /// [`slot`](Self::slot)) with the lower-rank convention `r = floor(q (n - 1))` over all `n`
    /// counted values: the midpoint of the bin holding the value of rank `r`, hence within half a
    /// bin width `(hi - lo) / (2 bins)` of it. NaN when nothing is counted or that value is
    /// below `lo` or above `hi` (reported, never guessed). Fails if `q` is not in `[0, 1]`.
    pub fn quantile<C: Copy + Into<u64>>(&self, slots: &[C], q: f64) -> Result<f64, StatsError> {
        Ok(self.quantiles(slots, &[q])?[0])
    }

    /// [`quantile`](Self::quantile) at each level of `qs`, in that order, from one pass over the
    /// slots. Fails if a level is not in `[0, 1]`.
    pub fn quantiles<C: Copy + Into<u64>>(
        &self,
        slots: &[C],
        qs: &[f64],
    ) -> Result<Vec<f64>, StatsError> {
        check_levels(qs)?;
        if slots.len() != self.bins + 2 {
            return Err(StatsError::LengthMismatch {
                what: "histogram slots",
                expected: self.bins + 2,
                got: slots.len(),
            });
        }
        // Counted over the occupied slots only: a field band's point fills a few of its
        // hundreds, and a full pass here cost as much as the rest of its quantiles.
        let mut out = vec![f64::NAN; qs.len()];
        self.quantiles_in(
            slots,
            occupied_slots(slots),
            qs,
            &levels_in_order(qs),
            &mut out,
        );
        Ok(out)
    }

    /// [`quantiles`](Self::quantiles) into `out`, without allocating: `slots` are empty outside
    /// `occupied`, the levels `qs` are in `[0, 1]` and `by_level` lists their indices in
    /// increasing order of level ([`levels_in_order`]).
    pub(super) fn quantiles_in<C: Copy + Into<u64>>(
        &self,
        slots: &[C],
        occupied: std::ops::Range<usize>,
        qs: &[f64],
        by_level: &[usize],
        out: &mut [f64],
    ) {
        out.fill(f64::NAN);
        let n: u64 = slots[occupied.clone()].iter().map(|&c| c.into()).sum();
        if n == 0 {
            return;
        }
        // Ranks grow with the level, so one walk up the cumulative counts finds each in turn.
        let mut pending = by_level.iter().copied().peekable();
        let mut seen = 0;
        // Empty slots below the first value find no level (every rank is >= 0 = seen there).
        for (s, &c) in slots.iter().enumerate().skip(occupied.start) {
            seen += c.into();
            while let Some(&i) = pending.peek() {
                if quantile_rank(qs[i], n) >= seen {
                    break;
                }
                out[i] = self.slot_value(s);
                pending.next();
            }
            if pending.peek().is_none() {
                break;
            }
        }
    }

    /// [`quantiles_in`](Self::quantiles_in) of values given by their slots in increasing order:
    /// the value of rank r is in the r-th slot, so no counts are needed (a band of few members).
    pub(super) fn quantiles_of_sorted(&self, sorted_slots: &[u32], qs: &[f64], out: &mut [f64]) {
        let n = sorted_slots.len() as u64;
        for (o, &q) in out.iter_mut().zip(qs) {
            *o = match n {
                0 => f64::NAN,
                _ => self.slot_value(sorted_slots[quantile_rank(q, n) as usize] as usize),
            };
        }
    }

    /// What a quantile reports for a value in slot `s`: its bin's midpoint, NaN below `lo` or
    /// above `hi`.
    #[inline]
    fn slot_value(&self, s: usize) -> f64 {
        if s == 0 || s == self.bins + 1 {
            f64::NAN
        } else {
            self.midpoint(s - 1)
        }
    }

    /// Fails unless `other` has the same range and number of bins (bit for bit).
    pub(super) fn check_compatible(&self, other: &Bins) -> Result<(), StatsError> {
        if self.lo.to_bits() != other.lo.to_bits()
            || self.hi.to_bits() != other.hi.to_bits()
            || self.bins != other.bins
        {
            return Err(StatsError::HistogramMismatch {
                lo_a: self.lo,
                hi_a: self.hi,
                bins_a: self.bins,
                lo_b: other.lo,
                hi_b: other.hi,
                bins_b: other.bins,
            });
        }
        Ok(())
    }
}

/// Counts of a stream of values in [`Bins`], plus underflow / overflow counts; NaN and
/// ±infinity are counted in `non_finite`.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(try_from = "HistogramState", into = "HistogramState")]
pub struct Histogram {
    bins: Bins,
    /// `bins + 2` slots: underflow, the bins, overflow.
    slots: Vec<u64>,
    non_finite: u64,
}

impl Histogram {
    /// `bins` equal bins on `[lo, hi]`; needs finite `lo < hi` with finite `hi - lo`, `bins >= 1`.
    pub fn new(lo: f64, hi: f64, bins: usize) -> Result<Self, StatsError> {
        Ok(Self::with_bins(Bins::new(lo, hi, bins)?))
    }

    /// An empty histogram on `bins`.
    pub fn with_bins(bins: Bins) -> Self {
        Histogram {
            bins,
            slots: vec![0; bins.len() + 2],
            non_finite: 0,
        }
    }

    /// A histogram from its `bins + 2` slot counts (see [`Bins::slot`]).
    pub(super) fn from_slots(bins: Bins, slots: Vec<u64>, non_finite: u64) -> Self {
        debug_assert_eq!(slots.len(), bins.len() + 2);
        Histogram {
            bins,
            slots,
            non_finite,
        }
    }

    /// The binning.
    pub fn binning(&self) -> &Bins {
        &self.bins
    }

    /// Left edge of the range.
    pub fn lo(&self) -> f64 {
        self.bins.lo()
    }

    /// Right edge of the range.
    pub fn hi(&self) -> f64 {
        self.bins.hi()
    }

    /// Number of bins.
    pub fn bins(&self) -> usize {
        self.bins.len()
    }

    /// Edge `i` (see [`Bins::edge`]): bin `i` holds `edge(i) <= x < edge(i + 1)`.
    pub fn edge(&self, i: usize) -> f64 {
        self.bins.edge(i)
    }

    /// The `bins + 1` bin edges.
    pub fn edges(&self) -> Vec<f64> {
        self.bins.edges()
    }

    /// Adds one observation. Returns `false` (counted in `non_finite`) for NaN or ±infinity.
    #[inline]
    pub fn push(&mut self, x: f64) -> bool {
        if !x.is_finite() {
            self.non_finite += 1;
            return false;
        }
        self.slots[self.bins.slot(x)] += 1;
        true
    }

    /// Adds `count` observations of the value `x` (`false`, counted in `non_finite`, when `x` is
    /// not finite).
    pub fn add(&mut self, x: f64, count: u64) -> bool {
        if !x.is_finite() {
            self.non_finite += count;
            return false;
        }
        self.slots[self.bins.slot(x)] += count;
        true
    }

    /// Counts `count` more rejected (non-finite) observations.
    pub fn add_non_finite(&mut self, count: u64) {
        self.non_finite += count;
    }

    /// Adds the counts of `other`; fails, leaving `self` unchanged, if the binning differs.
    pub fn merge(&mut self, other: &Histogram) -> Result<(), StatsError> {
        self.bins.check_compatible(&other.bins)?;
        for (a, b) in self.slots.iter_mut().zip(&other.slots) {
            *a += b;
        }
        self.non_finite += other.non_finite;
        Ok(())
    }

    /// Counts per bin.
    pub fn counts(&self) -> &[u64] {
        &self.slots[1..=self.bins.len()]
    }

    /// Finite observations below `lo`.
    pub fn underflow(&self) -> u64 {
        self.slots[0]
    }

    /// Finite observations above `hi`.
    pub fn overflow(&self) -> u64 {
        self.slots[self.bins.len() + 1]
    }

    /// Rejected NaN / infinite observations.
    pub fn non_finite(&self) -> u64 {
        self.non_finite
    }

    /// All finite observations (in bins, underflow and overflow).
    pub fn total(&self) -> u64 {
        self.slots.iter().sum()
    }

    /// The `q`-quantile as the midpoint of the bin holding the value of rank `floor(q (n - 1))`
    /// (see [`Bins::quantile`]): within half a bin width; NaN when empty or when that value is
    /// outside `[lo, hi]`.
    pub fn quantile(&self, q: f64) -> Result<f64, StatsError> {
        self.bins.quantile(&self.slots, q)
    }
}

#[derive(Serialize, Deserialize)]
struct HistogramState {
    #[serde(with = "crate::output::serde_f64")]
    lo: f64,
    #[serde(with = "crate::output::serde_f64")]
    hi: f64,
    bins: usize,
    counts: Vec<u64>,
    underflow: u64,
    overflow: u64,
    non_finite: u64,
}

impl From<Histogram> for HistogramState {
    fn from(h: Histogram) -> Self {
        HistogramState {
            lo: h.lo(),
            hi: h.hi(),
            bins: h.bins(),
            counts: h.counts().to_vec(),
            underflow: h.underflow(),
            overflow: h.overflow(),
            non_finite: h.non_finite,
        }
    }
}

impl TryFrom<HistogramState> for Histogram {
    type Error = StatsError;

    fn try_from(st: HistogramState) -> Result<Self, StatsError> {
        let mut h = Histogram::new(st.lo, st.hi, st.bins)?;
        if st.counts.len() != st.bins {
            return Err(StatsError::LengthMismatch {
                what: "serialized histogram counts",
                expected: st.bins,
                got: st.counts.len(),
            });
        }
        h.slots[0] = st.underflow;
        h.slots[1..=st.bins].copy_from_slice(&st.counts);
        h.slots[st.bins + 1] = st.overflow;
        h.non_finite = st.non_finite;
        Ok(h)
    }
}

/// Fails unless every quantile level is in `[0, 1]`.
pub(super) fn check_levels(qs: &[f64]) -> Result<(), StatsError> {
    match qs.iter().find(|q| !(0.0..=1.0).contains(*q)) {
        Some(&q) => Err(StatsError::InvalidQuantile(q)),
        None => Ok(()),
    }
}

/// The rank `floor(q (n - 1))` (0-based, the lower convention) of the `q`-quantile of `n >= 1`
/// values.
#[inline]
pub(super) fn quantile_rank(q: f64, n: u64) -> u64 {
    ((q * (n - 1) as f64).floor() as u64).min(n - 1)
}

/// The indices of the levels `qs` (in `[0, 1]`) in increasing order of level.
pub(super) fn levels_in_order(qs: &[f64]) -> Vec<usize> {
    let mut by_level: Vec<usize> = (0..qs.len()).collect();
    by_level.sort_by(|&a, &b| qs[a].total_cmp(&qs[b]));
    by_level
}

/// The slots from the first non-empty one to the last, found 16 slots at a time (a field
/// band's point holds its members' values in a few dozen of its hundreds of slots, and its
/// quantiles and state file read only those): `0..0` if every slot is empty.
pub(super) fn occupied_slots<C: Copy + Into<u64>>(slots: &[C]) -> std::ops::Range<usize> {
    const RUN: usize = 16;
    let empty = |run: &[C]| run.iter().fold(0u64, |any, &c| any | c.into()) == 0;
    let mut start = 0;
    while start + RUN <= slots.len() && empty(&slots[start..start + RUN]) {
        start += RUN;
    }
    while start < slots.len() && slots[start].into() == 0 {
        start += 1;
    }
    let mut end = slots.len();
    while end >= start + RUN && empty(&slots[end - RUN..end]) {
        end -= RUN;
    }
    while end > start && slots[end - 1].into() == 0 {
        end -= 1;
    }
    if start == end {
        return 0..0;
    }
    start..end
}

#[cfg(test)]
mod tests;
