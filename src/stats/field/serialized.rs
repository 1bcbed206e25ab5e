//! The serialized forms of a [`FieldBand`] (see its documentation): JSON for human-readable
//! formats, columns for the study's binary state files.

use serde::{Deserialize, Deserializer, Serialize, Serializer};

use super::{Bins, FieldBand, RunningStats, StatsError};

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
#[inline(always)]
fn put(out: &mut Vec<u8>, v: u64, width: u8) {
    // Each width as a fixed-size copy: a slice of run-time length was a call per value.
    match width {
        2 => out.extend_from_slice(&(v as u16).to_le_bytes()),
        4 => out.extend_from_slice(&(v as u32).to_le_bytes()),
        8 => out.extend_from_slice(&v.to_le_bytes()),
        w => out.extend_from_slice(&v.to_le_bytes()[..w as usize]),
    }
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
