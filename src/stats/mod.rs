//! Mergeable summary statistics for ensembles.
//!
//! An ensemble of thousands to millions of members is never held in memory at once: each chunk
//! (and each shard, possibly on another machine) is summarized, and the summaries are merged. Every
//! type here therefore has a `push` (one observation), a `merge` (combine two summaries of
//! disjoint sets of observations) and a serde representation that round-trips **bit-exactly**, so
//! that a shard written to JSON on one machine and merged on another gives the same numbers as a
//! summary computed in one place.
//!
//! * [`RunningStats`]: count, mean, sample variance, min, max (compensated Welford updates, Chan et
//!   al. pairwise combination).
//! * [`QuantileSketch`]: a DDSketch (Masson, Rim & Lee, VLDB 2019) with a relative-error guarantee
//!   on every quantile. Its state is integer bucket counts, so merging is exact, associative and
//!   commutative: any sharding and any merge order give the identical sketch.
//! * [`Histogram`]: fixed equal-width bins plus underflow / overflow counts.
//! * [`ScalarSummary`]: the three above for one scalar observable.
//! * [`FieldSummary`]: [`RunningStats`] and [`QuantileSketch`] pointwise over a grid of G points.
//!
//! # Non-finite values
//!
//! NaN and ±infinity are never averaged, sketched or binned. Every `push` returns `true` when the
//! value was taken into the summary and `false` when it was not; the rejected values are counted in
//! a separate `non_finite` counter (reported by `non_finite()`, merged like the other counts).
//!
//! # Serialization
//!
//! `f64` state (means, sums of squares, extremes, `alpha`, histogram edges) is written in
//! human-readable formats as a decimal *string* holding the shortest representation that parses
//! back to the same bits (`"0.005"`, `"1.0000000012345e8"`, `"inf"`). serde_json (as configured in
//! this crate, without its `float_roundtrip` feature) does not parse every JSON number back to the
//! same `f64` (about one random double in five comes back one unit in the last place off), which would make a
//! merge of deserialized shards differ from the in-memory merge. Plain JSON numbers are still
//! accepted when reading. Binary (non-human-readable) formats store raw `f64`.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// Errors from building, merging, querying or deserializing summaries.
#[derive(Debug, thiserror::Error)]
pub enum StatsError {
    #[error("quantile sketch: relative accuracy alpha = {0} is outside the allowed range [{min}, {max}]", min = QuantileSketch::MIN_ALPHA, max = QuantileSketch::MAX_ALPHA)]
    InvalidAlpha(f64),

    #[error("cannot merge quantile sketches with different relative accuracies (alpha = {left} and alpha = {right})")]
    AlphaMismatch { left: f64, right: f64 },

    #[error("histogram: invalid binning lo = {lo}, hi = {hi}, bins = {bins} (need finite lo < hi with finite hi - lo, and 1 <= bins <= 2^32 - 1)")]
    InvalidHistogram { lo: f64, hi: f64, bins: usize },

    #[error("cannot merge histograms with different bins: [{lo_a}, {hi_a}] in {bins_a} bins and [{lo_b}, {hi_b}] in {bins_b} bins")]
    HistogramMismatch {
        lo_a: f64,
        hi_a: f64,
        bins_a: usize,
        lo_b: f64,
        hi_b: f64,
        bins_b: usize,
    },

    #[error("cannot merge a scalar summary that has a histogram with one that has none")]
    HistogramPresenceMismatch,

    #[error("{what}: length {got} does not match the expected {expected}")]
    LengthMismatch {
        what: &'static str,
        expected: usize,
        got: usize,
    },

    #[error("quantile level q = {0} is outside [0, 1]")]
    InvalidQuantile(f64),

    #[error("inconsistent serialized {what}: {message}")]
    InvalidState { what: &'static str, message: String },
}

/// `a + b` as an unevaluated sum `s + e` with `s = fl(a + b)` (Knuth's TwoSum, exact).
#[inline]
fn two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    let bb = s - a;
    let e = (a - (s - bb)) + (b - bb);
    (s, e)
}

// ------------------------------------------------------------------------------------------------
// RunningStats

/// Count, mean, sample variance, minimum and maximum of a stream of finite values.
///
/// Updates use Welford's recurrence with the mean carried as a double-double (`mean + mean_lo`),
/// so that deviations `x - mean` are accurate even when the spread is tiny compared with the mean
/// (e.g. values `1e8 + N(0, 1)`: plain Welford loses about 8 digits of the variance there, this
/// keeps it to ~1e-14 relative). [`RunningStats::merge`] is the pairwise combination of Chan,
/// Golub & LeVeque (1979), again with a double-double mean; merging with an empty side is exact.
///
/// Non-finite inputs are rejected: [`RunningStats::push`] returns `false` and increments the
/// `non_finite` counter; they do not enter `count`, the mean, the variance or the extremes.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RunningStats {
    count: u64,
    /// Leading part of the mean (the mean rounded to `f64`).
    #[serde(with = "crate::output::serde_f64")]
    mean: f64,
    /// Trailing part: the mean is `mean + mean_lo` to about twice `f64` precision.
    #[serde(with = "crate::output::serde_f64")]
    mean_lo: f64,
    /// Sum of squared deviations from the mean.
    #[serde(with = "crate::output::serde_f64")]
    m2: f64,
    /// `+inf` while empty.
    #[serde(with = "crate::output::serde_f64")]
    min: f64,
    /// `-inf` while empty.
    #[serde(with = "crate::output::serde_f64")]
    max: f64,
    non_finite: u64,
}

impl Default for RunningStats {
    fn default() -> Self {
        Self::new()
    }
}

impl RunningStats {
    /// An empty accumulator.
    pub fn new() -> Self {
        RunningStats {
            count: 0,
            mean: 0.0,
            mean_lo: 0.0,
            m2: 0.0,
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
            non_finite: 0,
        }
    }

    /// Statistics of `count` finite observations given their mean, sum of squared deviations and
    /// extremes (e.g. accumulated in bulk by a caller); `count = 0` gives an empty accumulator.
    pub fn from_moments(count: u64, mean: f64, m2: f64, min: f64, max: f64) -> Self {
        if count == 0 {
            return Self::new();
        }
        RunningStats {
            count,
            mean,
            mean_lo: 0.0,
            m2: m2.max(0.0),
            min,
            max,
            non_finite: 0,
        }
    }

    /// Adds one observation. Returns `false` (and counts it in [`non_finite`](Self::non_finite))
    /// when `x` is NaN or infinite; such values are not part of any statistic.
    #[inline]
    pub fn push(&mut self, x: f64) -> bool {
        if !x.is_finite() {
            self.non_finite += 1;
            return false;
        }
        let x = x + 0.0; // -0.0 -> +0.0, so that min/max do not depend on the order of pushes
        self.count += 1;
        if self.count == 1 {
            self.mean = x;
            self.mean_lo = 0.0;
            self.m2 = 0.0;
            self.min = x;
            self.max = x;
            return true;
        }
        let n = self.count as f64;
        // Deviation from the old mean; `x - mean` is exact when they are within a factor 2.
        let d = (x - self.mean) - self.mean_lo;
        let (s, e) = two_sum(self.mean, d / n);
        let (hi, lo) = two_sum(s, e + self.mean_lo);
        self.mean = hi;
        self.mean_lo = lo;
        // Deviation from the new mean.
        let d2 = (x - self.mean) - self.mean_lo;
        self.m2 += d * d2;
        if x < self.min {
            self.min = x;
        }
        if x > self.max {
            self.max = x;
        }
        true
    }

    /// Combines with the statistics of a disjoint set of observations (Chan et al.). If either
    /// side is empty the result equals the other side bit for bit.
    pub fn merge(&mut self, other: &RunningStats) {
        let non_finite = self.non_finite + other.non_finite;
        if other.count == 0 {
            self.non_finite = non_finite;
            return;
        }
        if self.count == 0 {
            *self = other.clone();
            self.non_finite = non_finite;
            return;
        }
        let na = self.count as f64;
        let nb = other.count as f64;
        let n = na + nb;
        // delta = mean_b - mean_a in double-double precision.
        let (dh, dl) = two_sum(other.mean, -self.mean);
        let delta = dh + (dl + (other.mean_lo - self.mean_lo));
        let (s, e) = two_sum(self.mean, delta * (nb / n));
        let (hi, lo) = two_sum(s, e + self.mean_lo);
        self.m2 = self.m2 + other.m2 + delta * delta * (na * (nb / n));
        self.mean = hi;
        self.mean_lo = lo;
        self.count += other.count;
        self.min = self.min.min(other.min);
        self.max = self.max.max(other.max);
        self.non_finite = non_finite;
    }

    /// Number of finite observations.
    pub fn count(&self) -> u64 {
        self.count
    }

    /// Number of rejected (NaN or infinite) observations.
    pub fn non_finite(&self) -> u64 {
        self.non_finite
    }

    /// Mean; NaN when empty.
    pub fn mean(&self) -> f64 {
        if self.count == 0 {
            f64::NAN
        } else {
            self.mean
        }
    }

    /// Sum of squared deviations from the mean (0 when empty).
    pub fn sum_sq_dev(&self) -> f64 {
        self.m2
    }

    /// Sample variance `m2 / (n - 1)`; NaN for fewer than two observations.
    pub fn variance(&self) -> f64 {
        if self.count < 2 {
            f64::NAN
        } else {
            self.m2 / (self.count - 1) as f64
        }
    }

    /// Sample standard deviation `sqrt(variance())`; NaN for fewer than two observations.
    pub fn std(&self) -> f64 {
        self.variance().sqrt()
    }

    /// Standard error of the mean `std() / sqrt(n)`; NaN for fewer than two observations.
    pub fn std_error(&self) -> f64 {
        self.std() / (self.count as f64).sqrt()
    }

    /// Smallest observation; NaN when empty.
    pub fn min(&self) -> f64 {
        if self.count == 0 {
            f64::NAN
        } else {
            self.min
        }
    }

    /// Largest observation; NaN when empty.
    pub fn max(&self) -> f64 {
        if self.count == 0 {
            f64::NAN
        } else {
            self.max
        }
    }
}

// ------------------------------------------------------------------------------------------------
// QuantileSketch

/// `2 atanh(s) = ln((1 + s) / (1 - s))` by its Taylor series `2 s (1 + z/3 + z^2/5 + ...)`,
/// `z = s^2`, summed until the terms vanish; for `|s| <= 1/3` (`z <= 1/9`) 40 terms reach 1e-38.
/// Used at compile time for the table of [`det_ln`].
const fn atanh2_series(s: f64) -> f64 {
    let z = s * s;
    let mut p = 0.0;
    let mut j = 40;
    while j > 0 {
        j -= 1;
        p = p * z + 1.0 / (2 * j + 1) as f64;
    }
    2.0 * s * p
}

/// Bits of the mantissa used to index [`LN_TABLE`].
const LN_TABLE_BITS: u32 = 6;

/// `LN_TABLE[j] = ln(c_j)` with `c_j = 1 + (j + 1/2) / 64`, the centre of the j-th of 64 equal
/// sub-intervals of the mantissa range `[1, 2)`; evaluated at compile time (exact IEEE arithmetic).
const LN_TABLE: [f64; 1 << LN_TABLE_BITS] = {
    let mut t = [0.0; 1 << LN_TABLE_BITS];
    let mut j = 0;
    while j < t.len() {
        let c = 1.0 + (j as f64 + 0.5) / t.len() as f64;
        t[j] = atanh2_series((c - 1.0) / (c + 1.0)); // |s| < 1/3
        j += 1;
    }
    t
};

/// Natural logarithm from IEEE-754 basic operations only (no libm), so that bucket indices, and
/// hence sketch states, are identical on every platform. Requires a positive, finite, normal `x`.
///
/// `x = 2^e m`, `m` in `[1, 2)`; with the table centre `c` nearest `m`,
/// `ln x = e ln 2 + ln c + 2 atanh(s)`, `s = (m - c) / (m + c)`, `|s| < 1/256`, for which four terms
/// of the series are exact to double precision (the first omitted one is below 1e-21 relative).
/// Absolute accuracy a few units in the last place of `ln x` (checked against `f64::ln` in the
/// tests), far inside the margin that [`QuantileSketch`] reserves for it.
#[inline]
fn det_ln(x: f64) -> f64 {
    // ln 2 split so that `e * LN2_HI` is exact for |e| < 2^11 (fdlibm constants).
    const LN2_HI: f64 = f64::from_bits(0x3fe6_2e42_fee0_0000); // 6.93147180369123816490e-01
    const LN2_LO: f64 = f64::from_bits(0x3dea_39ef_3579_3c76); // 1.90821492927058770002e-10
    const C3: f64 = 1.0 / 3.0;
    const C5: f64 = 1.0 / 5.0;
    const C7: f64 = 1.0 / 7.0;
    let bits = x.to_bits();
    let e = ((bits >> 52) & 0x7ff) as i32 - 1023;
    let frac = bits & ((1u64 << 52) - 1);
    let m = f64::from_bits(frac | (1023u64 << 52)); // in [1, 2)
    let j = (frac >> (52 - LN_TABLE_BITS)) as usize;
    let c = 1.0 + (j as f64 + 0.5) * (1.0 / (1u64 << LN_TABLE_BITS) as f64);
    let s = (m - c) / (m + c); // m - c is exact
    let z = s * s;
    let ln_m = LN_TABLE[j] + 2.0 * s * (1.0 + z * (C3 + z * (C5 + z * C7)));
    let e = e as f64;
    e * LN2_HI + (e * LN2_LO + ln_m)
}

/// A DDSketch: a deterministic, mergeable quantile summary with relative-error guarantee.
///
/// # Buckets
///
/// With `gamma = (1 + a) / (1 - a)`, a finite value `x` with `|x| >= ZERO_THRESHOLD` goes to
/// bucket `k = ceil(ln|x| / ln gamma)`, i.e. `gamma^(k-1) < |x| <= gamma^k`, of the positive or
/// the negative store according to its sign; `|x| < ZERO_THRESHOLD` (1e-300) is counted as zero.
/// A bucket is represented by `2 gamma^k / (gamma + 1)` (sign restored), which is within relative
/// distance `a` of every point of the bucket. Internally `a = alpha (1 - 1e-5)`: this margin
/// (>= 1e-11 absolute) absorbs the floating-point rounding in the logarithm and the exponential
/// (<= ~3e-13 relative), so the guarantee below holds with the user's `alpha` exactly.
///
/// # Quantile convention and guarantee
///
/// Let `x_0 <= x_1 <= ... <= x_{n-1}` be the `n` finite values pushed (into this sketch or any
/// sketch merged into it). `quantile(q)` uses the *lower rank* `r = floor(q (n - 1))` and returns
/// a value `v` with
///
/// ```text
/// |v - x_r| <= alpha |x_r|        if |x_r| >= ZERO_THRESHOLD,
/// |v - x_r| <  ZERO_THRESHOLD     otherwise (then v = 0 or the exact min/max).
/// ```
///
/// `q = 0` and `q = 1` return the exact minimum and maximum; every other answer is the bucket
/// representative clamped to `[min, max]` (which can only bring it closer to `x_r`).
///
/// # Memory
///
/// One `(i32, u64)` entry per non-empty bucket. Values with magnitudes in `[lo, hi]` occupy at
/// most [`bucket_bound(lo, hi)`](Self::bucket_bound) `= key(hi) - key(lo) + 1 <= ln(hi/lo) / ln
/// gamma + 2` buckets per sign, whatever their number (`ln gamma ~= 2 alpha`); for `[1e-12, 1e12]`
/// and the default `alpha = 0.005` that is `ln(1e24) / ln gamma ~= 5526` plus one or two, i.e.
/// 5528 per sign (at most 2 * 5528 + 1 buckets with zeros, ~100 KiB of map entries).
///
/// # Merging
///
/// [`merge`](Self::merge) adds bucket counts (and takes min/max, adds counts), so it is exact,
/// associative and commutative: the merge of any sharding of a stream, in any order or tree
/// shape, is identical (same serialization, byte for byte) to the sketch of the whole stream.
/// Bucket indices are computed with a logarithm built from IEEE basic operations only, so they do
/// not depend on the platform's libm either.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(try_from = "SketchState", into = "SketchState")]
pub struct QuantileSketch {
    alpha: f64,
    /// ln gamma of the internal (margin-reduced) accuracy.
    ln_gamma: f64,
    inv_ln_gamma: f64,
    /// 2 gamma / (gamma + 1): representative of bucket k is gamma^(k-1) times this.
    rep_factor: f64,
    count: u64,
    non_finite: u64,
    min: f64,
    max: f64,
    zero_count: u64,
    negative: BTreeMap<i32, u64>,
    positive: BTreeMap<i32, u64>,
}

impl Default for QuantileSketch {
    fn default() -> Self {
        Self::new(Self::DEFAULT_ALPHA).expect("default alpha is valid")
    }
}

impl QuantileSketch {
    /// Default relative accuracy (0.5 %).
    pub const DEFAULT_ALPHA: f64 = 0.005;
    /// Smallest accepted `alpha` (keeps bucket indices of all finite `f64` within `i32`).
    pub const MIN_ALPHA: f64 = 1e-6;
    /// Largest accepted `alpha`.
    pub const MAX_ALPHA: f64 = 0.5;
    /// Magnitudes below this are counted as zero.
    pub const ZERO_THRESHOLD: f64 = 1e-300;
    /// Relative safety margin between the stated `alpha` and the bucket width actually used.
    const MARGIN: f64 = 1e-5;

    /// An empty sketch with relative accuracy `alpha` in `[MIN_ALPHA, MAX_ALPHA]`.
    pub fn new(alpha: f64) -> Result<Self, StatsError> {
        if !(Self::MIN_ALPHA..=Self::MAX_ALPHA).contains(&alpha) {
            return Err(StatsError::InvalidAlpha(alpha));
        }
        let a = alpha * (1.0 - Self::MARGIN);
        let gamma = (1.0 + a) / (1.0 - a);
        let ln_gamma = det_ln(gamma);
        Ok(QuantileSketch {
            alpha,
            ln_gamma,
            inv_ln_gamma: 1.0 / ln_gamma,
            rep_factor: 2.0 * gamma / (gamma + 1.0),
            count: 0,
            non_finite: 0,
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
            zero_count: 0,
            negative: BTreeMap::new(),
            positive: BTreeMap::new(),
        })
    }

    /// The relative accuracy this sketch guarantees.
    pub fn alpha(&self) -> f64 {
        self.alpha
    }

    /// `gamma` of the buckets actually used (`gamma^(k-1) < |x| <= gamma^k`).
    pub fn gamma(&self) -> f64 {
        self.ln_gamma.exp()
    }

    #[inline]
    fn key(&self, magnitude: f64) -> i32 {
        (det_ln(magnitude) * self.inv_ln_gamma).ceil() as i32
    }

    /// Representative magnitude of bucket `k`: `2 gamma^k / (gamma + 1)`, computed as
    /// `gamma^(k-1) * 2 gamma / (gamma + 1)`, and capped at `f64::MAX` (in the top bucket it can
    /// exceed every finite value; capping only brings it closer to the values in the bucket).
    #[inline]
    fn representative(&self, k: i32) -> f64 {
        (((k as f64 - 1.0) * self.ln_gamma).exp() * self.rep_factor).min(f64::MAX)
    }

    /// Adds one observation. Returns `false` (and counts it in [`non_finite`](Self::non_finite))
    /// for NaN or infinite `x`, which are not sketched.
    #[inline]
    pub fn push(&mut self, x: f64) -> bool {
        if !x.is_finite() {
            self.non_finite += 1;
            return false;
        }
        let x = x + 0.0; // -0.0 -> +0.0
        self.count += 1;
        if x < self.min {
            self.min = x;
        }
        if x > self.max {
            self.max = x;
        }
        let ax = x.abs();
        if ax < Self::ZERO_THRESHOLD {
            self.zero_count += 1;
        } else {
            let k = self.key(ax);
            let store = if x > 0.0 {
                &mut self.positive
            } else {
                &mut self.negative
            };
            *store.entry(k).or_insert(0) += 1;
        }
        true
    }

    fn check_compatible(&self, other: &QuantileSketch) -> Result<(), StatsError> {
        if self.alpha.to_bits() != other.alpha.to_bits() {
            return Err(StatsError::AlphaMismatch {
                left: self.alpha,
                right: other.alpha,
            });
        }
        Ok(())
    }

    /// Adds the observations summarized by `other` (exact: bucket counts are added). Fails, leaving
    /// `self` unchanged, if the two sketches were built with different `alpha`.
    pub fn merge(&mut self, other: &QuantileSketch) -> Result<(), StatsError> {
        self.check_compatible(other)?;
        for (&k, &c) in &other.positive {
            *self.positive.entry(k).or_insert(0) += c;
        }
        for (&k, &c) in &other.negative {
            *self.negative.entry(k).or_insert(0) += c;
        }
        self.zero_count += other.zero_count;
        self.count += other.count;
        self.non_finite += other.non_finite;
        self.min = self.min.min(other.min);
        self.max = self.max.max(other.max);
        Ok(())
    }

    /// The lower-rank index `floor(q (n - 1))` used by [`quantile`](Self::quantile), or `None`
    /// when the sketch is empty or `q` is not in `[0, 1]`.
    pub fn rank(&self, q: f64) -> Option<u64> {
        if self.count == 0 || !(0.0..=1.0).contains(&q) {
            return None;
        }
        Some(((q * (self.count - 1) as f64).floor() as u64).min(self.count - 1))
    }

    /// Approximate `q`-quantile (see the type's documentation for the rank convention and the
    /// guarantee). `None` when the sketch is empty or `q` is not in `[0, 1]` (NaN included).
    pub fn quantile(&self, q: f64) -> Option<f64> {
        let r = self.rank(q)?;
        if r == 0 {
            return Some(self.min);
        }
        if r == self.count - 1 {
            return Some(self.max);
        }
        let clamp = |v: f64| v.max(self.min).min(self.max);
        let mut seen = 0u64;
        // Ascending order: negatives from the largest magnitude down, zeros, positives up.
        for (&k, &c) in self.negative.iter().rev() {
            seen += c;
            if r < seen {
                return Some(clamp(-self.representative(k)));
            }
        }
        seen += self.zero_count;
        if r < seen {
            return Some(clamp(0.0));
        }
        for (&k, &c) in &self.positive {
            seen += c;
            if r < seen {
                return Some(clamp(self.representative(k)));
            }
        }
        unreachable!("bucket counts sum to count")
    }

    /// Number of finite observations.
    pub fn count(&self) -> u64 {
        self.count
    }

    /// Counts per bin of `edges` (ascending, at least 2), plus the counts below the first and
    /// above the last edge. Each bucket's count goes to the bin of its representative value
    /// (clamped to [min, max]), so a value is binned at most `alpha |x|` away from where it is:
    /// the same guarantee as the quantiles, and identical for any sharding of the stream.
    pub fn histogram(&self, edges: &[f64]) -> (Vec<u64>, u64, u64) {
        let bins = edges.len().saturating_sub(1);
        let mut counts = vec![0u64; bins];
        let (mut under, mut over) = (0u64, 0u64);
        let clamp = |v: f64| v.max(self.min).min(self.max);
        let mut place = |v: f64, c: u64| {
            if bins == 0 || v < edges[0] {
                under += c;
            } else if v > edges[bins] {
                over += c;
            } else {
                let k = edges.partition_point(|&e| e <= v).clamp(1, bins) - 1;
                counts[k] += c;
            }
        };
        for (&k, &c) in &self.negative {
            place(clamp(-self.representative(k)), c);
        }
        if self.zero_count > 0 {
            place(clamp(0.0), self.zero_count);
        }
        for (&k, &c) in &self.positive {
            place(clamp(self.representative(k)), c);
        }
        (counts, under, over)
    }

    /// Number of rejected (NaN or infinite) observations.
    pub fn non_finite(&self) -> u64 {
        self.non_finite
    }

    /// Number of observations with magnitude below [`ZERO_THRESHOLD`](Self::ZERO_THRESHOLD).
    pub fn zero_count(&self) -> u64 {
        self.zero_count
    }

    /// Exact smallest observation; NaN when empty.
    pub fn min(&self) -> f64 {
        if self.count == 0 {
            f64::NAN
        } else {
            self.min
        }
    }

    /// Exact largest observation; NaN when empty.
    pub fn max(&self) -> f64 {
        if self.count == 0 {
            f64::NAN
        } else {
            self.max
        }
    }

    /// Number of non-empty buckets (positive + negative, plus one if there are zeros): the
    /// memory in use is proportional to this.
    pub fn bucket_count(&self) -> usize {
        self.positive.len() + self.negative.len() + usize::from(self.zero_count > 0)
    }

    /// Upper bound on the number of buckets of one sign occupied by magnitudes in `[lo, hi]`
    /// (`0 < lo <= hi`, finite; `lo` is raised to the zero threshold):
    /// `key(hi) - key(lo) + 1 <= ln(hi / lo) / ln gamma + 2`.
    pub fn bucket_bound(&self, lo: f64, hi: f64) -> usize {
        let lo = lo.max(Self::ZERO_THRESHOLD);
        if !(lo <= hi && hi.is_finite()) {
            return 0;
        }
        (self.key(hi) as i64 - self.key(lo) as i64 + 1) as usize
    }
}

/// Serialized form of [`QuantileSketch`] (the derived constants are recomputed on reading).
#[derive(Serialize, Deserialize)]
struct SketchState {
    #[serde(with = "crate::output::serde_f64")]
    alpha: f64,
    count: u64,
    non_finite: u64,
    #[serde(with = "crate::output::serde_f64")]
    min: f64,
    #[serde(with = "crate::output::serde_f64")]
    max: f64,
    zero_count: u64,
    /// Bucket index -> count, for negative values (bucket of |x|).
    negative: BTreeMap<i32, u64>,
    /// Bucket index -> count, for positive values.
    positive: BTreeMap<i32, u64>,
}

impl From<QuantileSketch> for SketchState {
    fn from(s: QuantileSketch) -> Self {
        SketchState {
            alpha: s.alpha,
            count: s.count,
            non_finite: s.non_finite,
            min: s.min,
            max: s.max,
            zero_count: s.zero_count,
            negative: s.negative,
            positive: s.positive,
        }
    }
}

impl TryFrom<SketchState> for QuantileSketch {
    type Error = StatsError;

    fn try_from(st: SketchState) -> Result<Self, StatsError> {
        let bad = |message: String| StatsError::InvalidState {
            what: "quantile sketch",
            message,
        };
        let mut s = QuantileSketch::new(st.alpha)?;
        s.positive = st.positive;
        s.negative = st.negative;
        s.positive.retain(|_, c| *c > 0);
        s.negative.retain(|_, c| *c > 0);
        let total = s
            .positive
            .values()
            .chain(s.negative.values())
            .try_fold(st.zero_count, |acc, &c| acc.checked_add(c));
        if total != Some(st.count) {
            return Err(bad(format!(
                "bucket counts and zero_count add up to {total:?}, but count = {}",
                st.count
            )));
        }
        if st.count > 0 && !(st.min <= st.max && st.min.is_finite() && st.max.is_finite()) {
            return Err(bad(format!("min = {} and max = {}", st.min, st.max)));
        }
        s.count = st.count;
        s.non_finite = st.non_finite;
        s.zero_count = st.zero_count;
        s.min = if st.count > 0 { st.min } else { f64::INFINITY };
        s.max = if st.count > 0 {
            st.max
        } else {
            f64::NEG_INFINITY
        };
        Ok(s)
    }
}

// ------------------------------------------------------------------------------------------------
// Histogram

/// Equal-width histogram on `[lo, hi]` with `bins` bins, plus underflow / overflow counts.
///
/// Bin `i` holds `edges[i] <= x < edges[i + 1]`, the last bin also `x == hi` (NumPy's
/// convention), where `edges` are exactly the values returned by [`edges`](Self::edges):
/// `x < lo` is underflow, `x > hi` overflow. NaN and ±infinity are counted in `non_finite`.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(try_from = "HistogramState", into = "HistogramState")]
pub struct Histogram {
    lo: f64,
    hi: f64,
    /// Derived: `1 / bins` and `bins / (hi - lo)`.
    inv_bins: f64,
    scale: f64,
    counts: Vec<u64>,
    underflow: u64,
    overflow: u64,
    non_finite: u64,
}

impl Histogram {
    /// `bins` equal bins on `[lo, hi]`; needs finite `lo < hi` with finite `hi - lo`, `bins >= 1`.
    pub fn new(lo: f64, hi: f64, bins: usize) -> Result<Self, StatsError> {
        if !(lo < hi && (hi - lo).is_finite()) || bins == 0 || bins > u32::MAX as usize {
            return Err(StatsError::InvalidHistogram { lo, hi, bins });
        }
        Ok(Histogram {
            lo,
            hi,
            inv_bins: 1.0 / bins as f64,
            scale: bins as f64 / (hi - lo),
            counts: vec![0; bins],
            underflow: 0,
            overflow: 0,
            non_finite: 0,
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

    /// Number of bins.
    pub fn bins(&self) -> usize {
        self.counts.len()
    }

    /// Edge `i` (0..=bins): `lo + (hi - lo) * (i * fl(1 / bins))` in floating point, and exactly
    /// `hi` for `i >= bins`. Bin membership is decided against exactly these values.
    #[inline]
    pub fn edge(&self, i: usize) -> f64 {
        if i >= self.counts.len() {
            self.hi
        } else {
            self.lo + (self.hi - self.lo) * (i as f64 * self.inv_bins)
        }
    }

    /// The `bins + 1` bin edges.
    pub fn edges(&self) -> Vec<f64> {
        (0..=self.counts.len()).map(|i| self.edge(i)).collect()
    }

    /// The bin of `lo <= x <= hi` by bisection over `edge()`: the largest `i < bins` with
    /// `edge(i) <= x` (edges are non-decreasing; bins between equal edges stay empty).
    #[cold]
    fn locate(&self, x: f64) -> usize {
        let (mut a, mut b) = (0, self.counts.len() - 1);
        while a < b {
            let mid = (a + b).div_ceil(2);
            if self.edge(mid) <= x {
                a = mid;
            } else {
                b = mid - 1;
            }
        }
        a
    }

    /// Adds one observation. Returns `false` (counted in `non_finite`) for NaN or ±infinity.
    #[inline]
    pub fn push(&mut self, x: f64) -> bool {
        if !x.is_finite() {
            self.non_finite += 1;
            return false;
        }
        if x < self.lo {
            self.underflow += 1;
        } else if x > self.hi {
            self.overflow += 1;
        } else {
            let bins = self.counts.len();
            let t = (x - self.lo) * self.scale;
            let mut i = (t as usize).min(bins - 1); // `as` saturates, t >= 0
                                                    // Make the bin agree exactly with `edge()` despite rounding in `t` (rarely needed).
            if !(self.edge(i) <= x && (x < self.edge(i + 1) || i + 1 == bins)) {
                i = self.locate(x);
            }
            self.counts[i] += 1;
        }
        true
    }

    fn check_compatible(&self, other: &Histogram) -> Result<(), StatsError> {
        if self.lo.to_bits() != other.lo.to_bits()
            || self.hi.to_bits() != other.hi.to_bits()
            || self.counts.len() != other.counts.len()
        {
            return Err(StatsError::HistogramMismatch {
                lo_a: self.lo,
                hi_a: self.hi,
                bins_a: self.counts.len(),
                lo_b: other.lo,
                hi_b: other.hi,
                bins_b: other.counts.len(),
            });
        }
        Ok(())
    }

    /// Adds the counts of `other`; fails, leaving `self` unchanged, if the binning differs.
    pub fn merge(&mut self, other: &Histogram) -> Result<(), StatsError> {
        self.check_compatible(other)?;
        for (a, b) in self.counts.iter_mut().zip(&other.counts) {
            *a += b;
        }
        self.underflow += other.underflow;
        self.overflow += other.overflow;
        self.non_finite += other.non_finite;
        Ok(())
    }

    /// Counts per bin.
    pub fn counts(&self) -> &[u64] {
        &self.counts
    }

    /// Finite observations below `lo`.
    pub fn underflow(&self) -> u64 {
        self.underflow
    }

    /// Finite observations above `hi`.
    pub fn overflow(&self) -> u64 {
        self.overflow
    }

    /// Rejected NaN / infinite observations.
    pub fn non_finite(&self) -> u64 {
        self.non_finite
    }

    /// All finite observations (in bins, underflow and overflow).
    pub fn total(&self) -> u64 {
        self.counts.iter().sum::<u64>() + self.underflow + self.overflow
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
            lo: h.lo,
            hi: h.hi,
            bins: h.counts.len(),
            counts: h.counts,
            underflow: h.underflow,
            overflow: h.overflow,
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
        h.counts = st.counts;
        h.underflow = st.underflow;
        h.overflow = st.overflow;
        h.non_finite = st.non_finite;
        Ok(h)
    }
}

// ------------------------------------------------------------------------------------------------
// ScalarSummary

/// Everything kept about one scalar observable: moments ([`RunningStats`]), quantiles
/// ([`QuantileSketch`]) and optionally a [`Histogram`].
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct ScalarSummary {
    stats: RunningStats,
    sketch: QuantileSketch,
    histogram: Option<Histogram>,
}

impl ScalarSummary {
    /// Moments and a sketch of relative accuracy `alpha`, no histogram.
    pub fn new(alpha: f64) -> Result<Self, StatsError> {
        Ok(ScalarSummary {
            stats: RunningStats::new(),
            sketch: QuantileSketch::new(alpha)?,
            histogram: None,
        })
    }

    /// Moments, a sketch of relative accuracy `alpha` and the (empty) histogram `histogram`.
    pub fn with_histogram(alpha: f64, histogram: Histogram) -> Result<Self, StatsError> {
        let mut s = Self::new(alpha)?;
        s.histogram = Some(histogram);
        Ok(s)
    }

    /// Adds one observation to every part; `false` if it was rejected as non-finite.
    #[inline]
    pub fn push(&mut self, x: f64) -> bool {
        let ok = self.stats.push(x);
        self.sketch.push(x);
        if let Some(h) = &mut self.histogram {
            h.push(x);
        }
        ok
    }

    /// Merges every part; fails, leaving `self` unchanged, if the sketches' `alpha` or the
    /// histograms' binning (or presence) differ.
    pub fn merge(&mut self, other: &ScalarSummary) -> Result<(), StatsError> {
        self.sketch.check_compatible(&other.sketch)?;
        match (&self.histogram, &other.histogram) {
            (Some(a), Some(b)) => a.check_compatible(b)?,
            (None, None) => {}
            _ => return Err(StatsError::HistogramPresenceMismatch),
        }
        self.stats.merge(&other.stats);
        self.sketch.merge(&other.sketch)?;
        if let (Some(a), Some(b)) = (&mut self.histogram, &other.histogram) {
            a.merge(b)?;
        }
        Ok(())
    }

    pub fn stats(&self) -> &RunningStats {
        &self.stats
    }

    pub fn sketch(&self) -> &QuantileSketch {
        &self.sketch
    }

    pub fn histogram(&self) -> Option<&Histogram> {
        self.histogram.as_ref()
    }

    /// Shorthand for `sketch().quantile(q)`.
    pub fn quantile(&self, q: f64) -> Option<f64> {
        self.sketch.quantile(q)
    }
}

// ------------------------------------------------------------------------------------------------
// FieldSummary

/// Pointwise statistics of a field sampled on a grid of `G` points: one [`RunningStats`] and one
/// [`QuantileSketch`] per point. Each ensemble member contributes one row of `G` values;
/// non-finite entries are rejected pointwise (counted in that point's `non_finite`).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(try_from = "FieldState", into = "FieldState")]
pub struct FieldSummary {
    rows: u64,
    stats: Vec<RunningStats>,
    sketches: Vec<QuantileSketch>,
}

impl FieldSummary {
    /// Empty summary of a field with `points` grid points, sketches of relative accuracy `alpha`.
    pub fn new(points: usize, alpha: f64) -> Result<Self, StatsError> {
        let sketch = QuantileSketch::new(alpha)?;
        Ok(FieldSummary {
            rows: 0,
            stats: vec![RunningStats::new(); points],
            sketches: vec![sketch; points],
        })
    }

    /// Number of grid points G.
    pub fn points(&self) -> usize {
        self.stats.len()
    }

    /// Number of rows (members) pushed, including rows with non-finite entries.
    pub fn rows(&self) -> u64 {
        self.rows
    }

    /// Relative accuracy of the sketches.
    pub fn alpha(&self) -> f64 {
        self.sketches
            .first()
            .map_or(QuantileSketch::DEFAULT_ALPHA, |s| s.alpha())
    }

    /// Adds one member's field (length G).
    pub fn push_row(&mut self, row: &[f64]) -> Result<(), StatsError> {
        if row.len() != self.stats.len() {
            return Err(StatsError::LengthMismatch {
                what: "field row",
                expected: self.stats.len(),
                got: row.len(),
            });
        }
        for ((st, sk), &x) in self.stats.iter_mut().zip(&mut self.sketches).zip(row) {
            st.push(x);
            sk.push(x);
        }
        self.rows += 1;
        Ok(())
    }

    /// Merges pointwise; fails, leaving `self` unchanged, if G or `alpha` differ.
    pub fn merge(&mut self, other: &FieldSummary) -> Result<(), StatsError> {
        if other.points() != self.points() {
            return Err(StatsError::LengthMismatch {
                what: "field summary points",
                expected: self.points(),
                got: other.points(),
            });
        }
        if let (Some(a), Some(b)) = (self.sketches.first(), other.sketches.first()) {
            a.check_compatible(b)?;
        }
        for (a, b) in self.stats.iter_mut().zip(&other.stats) {
            a.merge(b);
        }
        for (a, b) in self.sketches.iter_mut().zip(&other.sketches) {
            a.merge(b)?;
        }
        self.rows += other.rows;
        Ok(())
    }

    /// Per-point statistics.
    pub fn stats(&self) -> &[RunningStats] {
        &self.stats
    }

    /// Per-point sketches.
    pub fn sketches(&self) -> &[QuantileSketch] {
        &self.sketches
    }

    /// Pointwise mean (NaN where a point has no finite value).
    pub fn mean_row(&self) -> Vec<f64> {
        self.stats.iter().map(RunningStats::mean).collect()
    }

    /// Pointwise sample standard deviation (NaN where a point has fewer than two finite values).
    pub fn std_row(&self) -> Vec<f64> {
        self.stats.iter().map(RunningStats::std).collect()
    }

    /// Pointwise minimum (NaN where empty).
    pub fn min_row(&self) -> Vec<f64> {
        self.stats.iter().map(RunningStats::min).collect()
    }

    /// Pointwise maximum (NaN where empty).
    pub fn max_row(&self) -> Vec<f64> {
        self.stats.iter().map(RunningStats::max).collect()
    }

    /// Pointwise `q`-quantile ([`QuantileSketch::quantile`] conventions; NaN where a point has no
    /// finite value). Fails if `q` is not in `[0, 1]`.
    pub fn quantile_row(&self, q: f64) -> Result<Vec<f64>, StatsError> {
        if !(0.0..=1.0).contains(&q) {
            return Err(StatsError::InvalidQuantile(q));
        }
        Ok(self
            .sketches
            .iter()
            .map(|s| s.quantile(q).unwrap_or(f64::NAN))
            .collect())
    }
}

#[derive(Serialize, Deserialize)]
struct FieldState {
    rows: u64,
    stats: Vec<RunningStats>,
    sketches: Vec<QuantileSketch>,
}

impl From<FieldSummary> for FieldState {
    fn from(f: FieldSummary) -> Self {
        FieldState {
            rows: f.rows,
            stats: f.stats,
            sketches: f.sketches,
        }
    }
}

impl TryFrom<FieldState> for FieldSummary {
    type Error = StatsError;

    fn try_from(st: FieldState) -> Result<Self, StatsError> {
        if st.stats.len() != st.sketches.len() {
            return Err(StatsError::LengthMismatch {
                what: "serialized field summary sketches",
                expected: st.stats.len(),
                got: st.sketches.len(),
            });
        }
        if let Some(first) = st.sketches.first() {
            for s in &st.sketches {
                first.check_compatible(s)?;
            }
        }
        Ok(FieldSummary {
            rows: st.rows,
            stats: st.stats,
            sketches: st.sketches,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn det_ln_matches_libm() {
        // Error relative to max(|ln x|, 1): what shifts a bucket boundary (relative error in x).
        let mut worst = 0.0f64;
        let mut check = |y: f64| {
            let err = (det_ln(y) - y.ln()).abs() / y.ln().abs().max(1.0);
            worst = worst.max(err);
        };
        let mut x = 1e-300;
        while x < 1e300 {
            for f in [1.0, 1.000_000_1, std::f64::consts::SQRT_2, 1.999_999] {
                check(x * f);
            }
            x *= 1.37;
        }
        // Every table sub-interval: its ends and centre, near 1 and in a far binade.
        for j in 0..=(1u64 << LN_TABLE_BITS) {
            let m = 1.0 + j as f64 / (1u64 << LN_TABLE_BITS) as f64;
            for y in [m.next_down(), m, m.next_up(), m + 0.5 / 64.0] {
                check(y);
                check(y * 2f64.powi(-900));
            }
        }
        eprintln!("det_ln: worst |error| / max(|ln x|, 1) = {worst:.3e}");
        assert!(worst < 2.0 * f64::EPSILON, "worst relative error {worst:e}");
        assert_eq!(det_ln(1.0), 0.0);
        assert_eq!(det_ln(2.0), std::f64::consts::LN_2);
    }

    /// Every single value is within relative distance alpha of its bucket's representative,
    /// including values on and next to the computed bucket boundaries.
    #[test]
    fn representative_within_alpha_of_every_value() {
        // xorshift64*, to stay free of dev-dependencies here.
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = move || {
            state ^= state >> 12;
            state ^= state << 25;
            state ^= state >> 27;
            state.wrapping_mul(0x2545_F491_4F6C_DD1D)
        };
        for alpha in [
            QuantileSketch::MIN_ALPHA,
            1e-4,
            0.005,
            0.01,
            QuantileSketch::MAX_ALPHA,
        ] {
            let s = QuantileSketch::new(alpha).unwrap();
            let mut worst = 0.0f64;
            let mut check = |x: f64| {
                let v = s.representative(s.key(x));
                let e = (v - x).abs() / x;
                worst = worst.max(e / alpha);
                assert!(e <= alpha, "alpha {alpha}, x {x:e}: v {v:e}, rel err {e:e}");
            };
            for _ in 0..200_000 {
                // Random bits: uniform in exponent and mantissa over [1e-300, f64::MAX].
                let x = f64::from_bits(next() >> 1);
                if x.is_finite() && x >= QuantileSketch::ZERO_THRESHOLD {
                    check(x);
                }
                // Computed boundaries gamma^k and their neighbours.
                let k = (next() % 60_000) as i32 - 30_000;
                let b = (k as f64 * s.ln_gamma).exp();
                if b.is_finite() && b >= QuantileSketch::ZERO_THRESHOLD {
                    for y in [b.next_down(), b, b.next_up()] {
                        check(y);
                    }
                }
            }
            check(f64::MAX);
            check(QuantileSketch::ZERO_THRESHOLD);
            eprintln!("alpha {alpha:e}: worst |v - x| / (alpha x) = {worst:.12}");
            assert!(
                worst > 0.99,
                "alpha {alpha}: worst {worst} (buckets should be nearly full width)"
            );
        }
    }
}
