//! Fields over members: [`FieldBand`], pointwise moments and a fixed-bin histogram per grid point
//! (quantile bands), in one bulk pass over the rows of a chunk.

use serde::{Deserialize, Deserializer, Serialize, Serializer};

use super::{Bins, Histogram, RunningStats, StatsError};

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
/// # Serialization
///
/// `{lo, hi, bins, points, counts}`, where `counts` holds per point the `bins + 2` slot counts
/// (underflow, bins, overflow) stored sparse: `{len, nonzero: [[slot, count], ...]}`.
#[derive(Clone, Debug)]
pub struct FieldBand {
    bins: Bins,
    points: Vec<RunningStats>,
    /// Per point, `bins + 2` slot counts (see [`Bins::slot`]).
    slots: Vec<Vec<u64>>,
}

impl FieldBand {
    /// An empty band of a field with `points` grid points, `bins` equal bins on `[lo, hi]`.
    pub fn new(points: usize, lo: f64, hi: f64, bins: usize) -> Result<Self, StatsError> {
        let bins = Bins::new(lo, hi, bins)?;
        Ok(FieldBand {
            bins,
            points: vec![RunningStats::new(); points],
            slots: vec![vec![0; bins.len() + 2]; points],
        })
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
            self.slots[j].clone(),
            self.points[j].non_finite(),
        )
    }

    /// Adds the rows of one chunk of members (each row of length G). Moments are accumulated in
    /// bulk (shifted sums, then one Chan merge per point) because this is the hot part of a
    /// study's statistics. Fails, adding nothing, if a row's length is not G.
    pub fn push_rows(&mut self, rows: &[&[f64]]) -> Result<(), StatsError> {
        let g = self.points.len();
        if let Some(bad) = rows.iter().find(|r| r.len() != g) {
            return Err(StatsError::LengthMismatch {
                what: "field row",
                expected: g,
                got: bad.len(),
            });
        }
        let bins = self.bins;
        // Shift each point by its first finite value (keeps the shifted sums well conditioned).
        let mut shift = vec![f64::NAN; g];
        for row in rows {
            for (s, &x) in shift.iter_mut().zip(row.iter()) {
                if s.is_nan() && x.is_finite() {
                    *s = x;
                }
            }
        }
        // Rows outer, points inner: memory is read in order.
        let mut n = vec![0u64; g];
        let mut non_finite = vec![0u64; g];
        let mut s1 = vec![0.0f64; g];
        let mut s2 = vec![0.0f64; g];
        let mut min = vec![f64::INFINITY; g];
        let mut max = vec![f64::NEG_INFINITY; g];
        for row in rows {
            for j in 0..g {
                let x = row[j];
                if !x.is_finite() {
                    non_finite[j] += 1;
                    continue;
                }
                n[j] += 1;
                let d = x - shift[j];
                s1[j] += d;
                s2[j] += d * d;
                min[j] = min[j].min(x);
                max[j] = max[j].max(x);
                self.slots[j][bins.slot(x)] += 1;
            }
        }
        for j in 0..g {
            if n[j] > 0 {
                let mean_d = s1[j] / n[j] as f64;
                let m2 = (s2[j] - s1[j] * mean_d).max(0.0);
                self.points[j].merge(&RunningStats::from_moments(
                    n[j],
                    shift[j] + mean_d,
                    m2,
                    min[j],
                    max[j],
                ));
            }
            self.points[j].add_non_finite(non_finite[j]);
        }
        Ok(())
    }

    /// Merges pointwise; fails, leaving `self` unchanged, if G or the bins differ.
    pub fn merge(&mut self, other: &FieldBand) -> Result<(), StatsError> {
        self.bins.check_compatible(&other.bins)?;
        if other.points() != self.points() {
            return Err(StatsError::LengthMismatch {
                what: "field band points",
                expected: self.points(),
                got: other.points(),
            });
        }
        for (a, b) in self.points.iter_mut().zip(&other.points) {
            a.merge(b);
        }
        for (a, b) in self.slots.iter_mut().zip(&other.slots) {
            for (x, y) in a.iter_mut().zip(b) {
                *x += y;
            }
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
        self.slots
            .iter()
            .map(|slots| self.bins.quantile(slots, q))
            .collect()
    }
}

/// The serialized form (field names and layout of the study's chunk and partial files).
#[derive(Serialize)]
struct FieldBandRef<'a> {
    lo: f64,
    hi: f64,
    bins: u32,
    points: &'a [RunningStats],
    #[serde(serialize_with = "sparse_counts::serialize")]
    counts: &'a [Vec<u64>],
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

impl Serialize for FieldBand {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        FieldBandRef {
            lo: self.bins.lo(),
            hi: self.bins.hi(),
            bins: self.bins.len() as u32,
            points: &self.points,
            counts: &self.slots,
        }
        .serialize(s)
    }
}

impl<'de> Deserialize<'de> for FieldBand {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
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
        Ok(FieldBand {
            bins,
            points: st.points,
            slots: st.counts,
        })
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

    pub fn serialize<S: Serializer>(rows: &&[Vec<u64>], s: S) -> Result<S::Ok, S::Error> {
        let sparse: Vec<Row> = rows
            .iter()
            .map(|r| Row {
                len: r.len(),
                nonzero: r
                    .iter()
                    .enumerate()
                    .filter(|(_, &c)| c > 0)
                    .map(|(b, &c)| (b as u32, c))
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
