//! One scalar observable: [`ScalarSummary`], moments and quantiles (and histograms over its
//! range, from the sketch).

use serde::{Deserialize, Serialize};

use super::{Histogram, QuantileSketch, RunningStats, StatsError};

/// Everything kept about one scalar observable: moments ([`RunningStats`]) and quantiles
/// ([`QuantileSketch`]); a histogram over the observed `[min, max]` is read from the sketch
/// ([`range_histogram`](Self::range_histogram)).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct ScalarSummary {
    stats: RunningStats,
    sketch: QuantileSketch,
}

impl ScalarSummary {
    /// Moments and a sketch of relative accuracy `alpha`.
    pub fn new(alpha: f64) -> Result<Self, StatsError> {
        Ok(ScalarSummary {
            stats: RunningStats::new(),
            sketch: QuantileSketch::new(alpha)?,
        })
    }

    /// Adds one observation to every part; `false` if it was rejected as non-finite.
    #[inline]
    pub fn push(&mut self, x: f64) -> bool {
        let ok = self.stats.push(x);
        self.sketch.push(x);
        ok
    }

    /// Adds one observation to the moments only (see [`push_quantile`](Self::push_quantile));
    /// `false` if it was rejected as non-finite.
    #[inline]
    pub fn push_moments(&mut self, x: f64) -> bool {
        self.stats.push(x)
    }

    /// Adds one observation to the sketch only. With [`push_moments`](Self::push_moments) on
    /// another summary, it lets the sketch's counts go straight into a larger total (exact
    /// either way) while the moments are merged from a chunk's own (which keeps their rounding
    /// independent of how the total was built).
    #[inline]
    pub fn push_quantile(&mut self, x: f64) {
        self.sketch.push(x);
    }

    /// Merges every part; fails, leaving `self` unchanged, if the sketches' `alpha` differ.
    pub fn merge(&mut self, other: &ScalarSummary) -> Result<(), StatsError> {
        self.sketch.check_compatible(&other.sketch)?;
        self.stats.merge(&other.stats);
        self.sketch.merge(&other.sketch)?;
        Ok(())
    }

    pub fn stats(&self) -> &RunningStats {
        &self.stats
    }

    pub fn sketch(&self) -> &QuantileSketch {
        &self.sketch
    }

    /// Shorthand for `sketch().quantile(q)`.
    pub fn quantile(&self, q: f64) -> Option<f64> {
        self.sketch.quantile(q)
    }

    /// Shorthand for `sketch().range_histogram(bins)`: `bins` equal bins over `[min, max]`.
    pub fn range_histogram(&self, bins: usize) -> Result<Histogram, StatsError> {
        self.sketch.range_histogram(bins)
    }
}
