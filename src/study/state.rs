//! The mergeable state of a study ([`StudyState`]): what a chunk, a run and a shard each produce,
//! and what `merge` combines. Everything in it merges exactly (counts, sketches, histograms) or
//! to rounding (moments), whatever the chunking or sharding.

use std::collections::BTreeMap;
use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::files::StudyHeader;
use super::{SCALARS, SCALAR_ALPHA};
use crate::error::{Error, Result};
use crate::stats::{FieldBand, ScalarSummary};

/// Everything mergeable of a set of members (a chunk, a run, a shard, merged shards): the member
/// ranges and failures, and the statistics of each sweep point that has members in it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StudyState {
    /// Member ranges [first, end) included, sorted and disjoint.
    pub ranges: Vec<(u64, u64)>,
    pub completed: u64,
    pub failed: Vec<u64>,
    /// Per sweep point with members here, its statistics.
    pub points: BTreeMap<u64, PointStats>,
}

/// The statistics of the members of one sweep point.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PointStats {
    pub completed: u64,
    pub failed: u64,
    /// First output time at which max density reaches the threshold.
    pub first_hit: ScalarSummary,
    pub never_hit: u64,
    /// Each member's peak density (its largest max density over the output times).
    pub peak_density: ScalarSummary,
    /// Each member's smallest gap over the output times.
    pub min_gap: ScalarSummary,
    /// Each member's energy at the last output time.
    pub final_energy: ScalarSummary,
    /// Per scalar observable, one summary per output time: detailed points only (empty map
    /// otherwise, see [`StudyHeader::is_detailed`]).
    pub scalars: BTreeMap<String, Vec<ScalarSummary>>,
    /// Per band field ([`StudyHeader::band_fields`]), one band per output time: detailed points
    /// only.
    pub fields: BTreeMap<String, Vec<FieldBand>>,
}

fn summary() -> ScalarSummary {
    ScalarSummary::new(SCALAR_ALPHA).expect("SCALAR_ALPHA is a valid accuracy")
}

impl PointStats {
    /// The empty statistics of point `p` of the study `header` describes (its times, grid,
    /// field ranges and bins).
    pub fn for_header(header: &StudyHeader, p: u64) -> Result<PointStats> {
        PointStats::with_u_range(header, p, header.field_ranges["u"])
    }

    /// As [`for_header`](Self::for_header), with the point's own velocity range of the u band.
    pub fn with_u_range(header: &StudyHeader, p: u64, u_range: (f64, f64)) -> Result<PointStats> {
        let mut stats = PointStats::without_bands(header, p);
        stats.add_bands(header, u_range)?;
        Ok(stats)
    }

    /// The empty statistics of point `p` with no field bands yet (a chunk's own: its bands go
    /// straight into the run's total, see `solve_chunk`).
    pub fn without_bands(header: &StudyHeader, p: u64) -> PointStats {
        let mut stats = PointStats {
            completed: 0,
            failed: 0,
            first_hit: summary(),
            never_hit: 0,
            peak_density: summary(),
            min_gap: summary(),
            final_energy: summary(),
            scalars: BTreeMap::new(),
            fields: BTreeMap::new(),
        };
        if header.is_detailed(p) {
            let times = header.times.len();
            stats.scalars = SCALARS
                .iter()
                .map(|s| (s.to_string(), (0..times).map(|_| summary()).collect()))
                .collect();
        }
        stats
    }

    /// Adds the empty bands of the header's band fields to a detailed point that has none (the
    /// u band on `u_range`); nothing for a point without per-time statistics.
    pub fn add_bands(&mut self, header: &StudyHeader, u_range: (f64, f64)) -> Result<()> {
        if !self.is_detailed() || !self.fields.is_empty() {
            return Ok(());
        }
        let times = header.times.len();
        for f in &header.band_fields {
            let (lo, hi) = if f == "u" {
                u_range
            } else {
                header.field_ranges[f.as_str()]
            };
            let band = FieldBand::new(header.x.len(), lo, hi, header.bins).map_err(|e| {
                Error::invalid(
                    format!("range of the {f} band"),
                    format!("[{lo}, {hi}] in {} bins", header.bins),
                    e.to_string(),
                    "finite lo < hi, bins >= 1",
                )
            })?;
            self.fields.insert(f.to_string(), vec![band; times]);
        }
        Ok(())
    }

    /// Whether this point keeps statistics per output time.
    pub fn is_detailed(&self) -> bool {
        !self.scalars.is_empty()
    }

    fn merge(&mut self, other: &PointStats) -> std::result::Result<(), String> {
        if self.is_detailed() != other.is_detailed() {
            return Err("per-time statistics on one side only".into());
        }
        self.completed += other.completed;
        self.failed += other.failed;
        for (name, per_time) in &other.scalars {
            let mine = self
                .scalars
                .get_mut(name)
                .ok_or_else(|| format!("unknown observable {name}"))?;
            for (a, b) in mine.iter_mut().zip(per_time) {
                a.merge(b).map_err(|e| e.to_string())?;
            }
        }
        for (mine, theirs) in [
            (&mut self.first_hit, &other.first_hit),
            (&mut self.peak_density, &other.peak_density),
            (&mut self.min_gap, &other.min_gap),
            (&mut self.final_energy, &other.final_energy),
        ] {
            mine.merge(theirs).map_err(|e| e.to_string())?;
        }
        self.never_hit += other.never_hit;
        for (name, per_time) in &other.fields {
            let mine = self
                .fields
                .get_mut(name)
                .ok_or_else(|| format!("unknown field {name}"))?;
            if mine.len() != per_time.len() {
                return Err("different numbers of output times".into());
            }
            for (a, b) in mine.iter_mut().zip(per_time) {
                a.merge(b).map_err(|e| format!("field {name}: {e}"))?;
            }
        }
        Ok(())
    }
}

impl StudyState {
    /// The empty state (no members, no points).
    pub fn new() -> StudyState {
        StudyState {
            ranges: Vec::new(),
            completed: 0,
            failed: Vec::new(),
            points: BTreeMap::new(),
        }
    }

    /// The statistics of point `p`, created empty for `header` (without field bands) on first
    /// use.
    pub fn point_mut(&mut self, p: u64, header: &StudyHeader) -> &mut PointStats {
        self.points
            .entry(p)
            .or_insert_with(|| PointStats::without_bands(header, p))
    }

    pub fn merge(&mut self, other: &StudyState) -> Result<()> {
        let bad = |message: String| Error::Output {
            path: PathBuf::from(super::PARTIAL),
            message,
        };
        self.ranges.extend_from_slice(&other.ranges);
        self.ranges.sort();
        for w in self.ranges.windows(2) {
            if w[0].1 > w[1].0 {
                return Err(bad(format!(
                    "member ranges {:?} and {:?} overlap: a member would be counted twice",
                    w[0], w[1]
                )));
            }
        }
        self.completed += other.completed;
        self.failed.extend_from_slice(&other.failed);
        self.failed.sort_unstable();
        for (p, stats) in &other.points {
            match self.points.get_mut(p) {
                Some(mine) => mine
                    .merge(stats)
                    .map_err(|e| bad(format!("sweep point {p}: {e}")))?,
                None => {
                    self.points.insert(*p, stats.clone());
                }
            }
        }
        Ok(())
    }
}

impl Default for StudyState {
    fn default() -> Self {
        StudyState::new()
    }
}
