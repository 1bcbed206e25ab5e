//! Quantiles: [`QuantileSketch`], a DDSketch with a relative-error guarantee and exact merges.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::buckets::BucketStore;
use super::histogram::quantile_rank;
use super::{Histogram, StatsError};

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
/// Per sign, a `u64` count for every bucket between the lowest and highest non-empty one while
/// they are at most 512 apart (4 KiB), else one `(i32, u64)` map entry per non-empty bucket.
/// Values with magnitudes in `[lo, hi]` occupy at
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
    negative: BucketStore,
    positive: BucketStore,
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
            negative: BucketStore::default(),
            positive: BucketStore::default(),
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
        // ceil(t) as truncation plus one below t: f64::ceil is a library call on the baseline
        // x86-64 target (no SSE4.1), a third of a push. The same integer for every t here:
        // |t| <= ln(1e308) / ln(gamma) is far inside i32.
        let t = det_ln(magnitude) * self.inv_ln_gamma;
        let k = t as i32;
        k + i32::from((k as f64) < t)
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
            store.add(k, 1);
        }
        true
    }

    pub(super) fn check_compatible(&self, other: &QuantileSketch) -> Result<(), StatsError> {
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
        self.positive.merge_from(&other.positive);
        self.negative.merge_from(&other.negative);
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
        Some(quantile_rank(q, self.count))
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
        let mut seen = 0u64;
        for (v, c) in self.buckets() {
            seen += c;
            if r < seen {
                return Some(v);
            }
        }
        unreachable!("bucket counts sum to count")
    }

    /// Number of finite observations.
    pub fn count(&self) -> u64 {
        self.count
    }

    /// The sketch's content in ascending order: each non-empty bucket as (its representative
    /// value clamped to [min, max], its count), negatives first, then the zeros, then positives.
    /// Every value pushed is within `alpha |x|` of the representative it is counted at (the
    /// quantile guarantee); the sequence is identical for any sharding of the stream.
    pub fn buckets(&self) -> impl Iterator<Item = (f64, u64)> + '_ {
        let clamp = move |v: f64| v.max(self.min).min(self.max);
        let negative = self
            .negative
            .iter()
            .rev()
            .map(move |(k, c)| (clamp(-self.representative(k)), c));
        let zeros = (self.zero_count > 0).then(|| (clamp(0.0), self.zero_count));
        let positive = self
            .positive
            .iter()
            .map(move |(k, c)| (clamp(self.representative(k)), c));
        negative.chain(zeros).chain(positive)
    }

    /// Histogram of the sketched values in `bins` equal bins over [min, max] (the range widened
    /// symmetrically when all values are equal; [0, 1] when empty). Each bucket's count goes to the
    /// bin of its representative (see [`buckets`](Self::buckets)), so a value is binned at most
    /// `alpha |x|` away from where it is, and the histogram is the same for any sharding.
    pub fn range_histogram(&self, bins: usize) -> Result<Histogram, StatsError> {
        let (lo, hi) = if self.count > 0 {
            (self.min, self.max)
        } else {
            (0.0, 1.0)
        };
        let (lo, hi) = if hi > lo {
            (lo, hi)
        } else {
            (
                lo - 0.5 * lo.abs().max(1e-12),
                hi + 0.5 * hi.abs().max(1e-12),
            )
        };
        let mut h = Histogram::new(lo, hi, bins)?;
        for (v, c) in self.buckets() {
            h.add(v, c);
        }
        h.add_non_finite(self.non_finite);
        Ok(h)
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
            negative: s.negative.to_map(),
            positive: s.positive.to_map(),
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
        let total = st
            .positive
            .values()
            .chain(st.negative.values())
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
        s.positive = BucketStore::from_map(&st.positive);
        s.negative = BucketStore::from_map(&st.negative);
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn key_is_the_ceiling_of_the_scaled_log() {
        // The key's truncation-based ceiling against f64::ceil, over values from 1e-300 to
        // 1e300 and at every bucket's upper end gamma^k (where t is an integer or next to one),
        // below and above 1 (t negative and positive).
        let sketch = QuantileSketch::new(0.001).unwrap();
        let ceil_key = |x: f64| (det_ln(x) * sketch.inv_ln_gamma).ceil() as i32;
        let mut x = 1e-300;
        while x < 1e300 {
            assert_eq!(sketch.key(x), ceil_key(x), "x = {x:e}");
            x *= 1.013;
        }
        for k in -2000..2000 {
            let edge = (k as f64 * sketch.ln_gamma).exp();
            for y in [edge.next_down(), edge, edge.next_up()] {
                assert_eq!(sketch.key(y), ceil_key(y), "x = {y:e}");
            }
        }
        assert_eq!(sketch.key(1.0), 0);
    }

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
