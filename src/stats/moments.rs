//! Moments: [`RunningStats`], count, mean, sample variance and extremes of a stream of values,
//! merged pairwise (Chan et al.).

use roughlub_kernels::shared::f64_math::two_sum;
use serde::{Deserialize, Serialize};

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

    /// The raw state `(count, non_finite, [mean, mean_lo, m2, min, max])`, for the columnar
    /// binary form of [`FieldBand`](super::FieldBand).
    pub(super) fn raw(&self) -> (u64, u64, [f64; 5]) {
        (
            self.count,
            self.non_finite,
            [self.mean, self.mean_lo, self.m2, self.min, self.max],
        )
    }

    /// The accumulator whose [`raw`](Self::raw) state this is (bit for bit).
    pub(super) fn from_raw(count: u64, non_finite: u64, v: [f64; 5]) -> Self {
        RunningStats {
            count,
            mean: v[0],
            mean_lo: v[1],
            m2: v[2],
            min: v[3],
            max: v[4],
            non_finite,
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

    /// Counts `n` more rejected (non-finite) observations, e.g. skipped by a bulk accumulation.
    pub(super) fn add_non_finite(&mut self, n: u64) {
        self.non_finite += n;
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
