//! The mergeable state of a study ([`StudyState`]): what a chunk, a run and a shard each produce,
//! and what `merge` combines. Everything in it merges exactly (counts, sketches, histograms) or
//! to rounding (moments), whatever the chunking or sharding.

use std::collections::BTreeMap;
use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::files::StudyHeader;
use super::{FIELDS, SCALARS, SCALAR_ALPHA};
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
    /// Per scalar observable, one summary per output time.
    pub scalars: BTreeMap<String, Vec<ScalarSummary>>,
    /// First output time at which max density reaches the threshold.
    pub first_hit: ScalarSummary,
    pub never_hit: u64,
    /// Each member's peak density (its largest max density over the output times).
    pub peak_density: ScalarSummary,
    /// Per field, one band per output time.
    pub fields: BTreeMap<String, Vec<FieldBand>>,
}

impl PointStats {
    /// The empty statistics of one point of the study `header` describes (its times, grid,
    /// field ranges and bins).
    pub fn for_header(header: &StudyHeader) -> Result<PointStats> {
        PointStats::with_u_range(header, header.field_ranges["u"])
    }

    /// As [`for_header`](Self::for_header), with the point's own velocity range of the u band.
    pub fn with_u_range(header: &StudyHeader, u_range: (f64, f64)) -> Result<PointStats> {
        let times = header.times.len();
        let summary =
            || ScalarSummary::new(SCALAR_ALPHA).expect("SCALAR_ALPHA is a valid accuracy");
        let mut fields = BTreeMap::new();
        for f in FIELDS {
            let (lo, hi) = if f == "u" {
                u_range
            } else {
                header.field_ranges[f]
            };
            let band = FieldBand::new(header.x.len(), lo, hi, header.bins).map_err(|e| {
                Error::invalid(
                    format!("range of the {f} band"),
                    format!("[{lo}, {hi}] in {} bins", header.bins),
                    e.to_string(),
                    "finite lo < hi, bins >= 1",
                )
            })?;
            fields.insert(f.to_string(), vec![band; times]);
        }
        Ok(PointStats {
            completed: 0,
            failed: 0,
            scalars: SCALARS
                .iter()
                .map(|s| (s.to_string(), (0..times).map(|_| summary()).collect()))
                .collect(),
            first_hit: summary(),
            never_hit: 0,
            peak_density: summary(),
            fields,
        })
    }

    fn merge(&mut self, other: &PointStats) -> std::result::Result<(), String> {
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
        self.first_hit
            .merge(&other.first_hit)
            .map_err(|e| e.to_string())?;
        self.never_hit += other.never_hit;
        self.peak_density
            .merge(&other.peak_density)
            .map_err(|e| e.to_string())?;
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

    /// The statistics of point `p`, created empty for `header` (and the point's velocity range
    /// of the u band) on first use.
    pub fn point_mut(
        &mut self,
        p: u64,
        header: &StudyHeader,
        u_range: (f64, f64),
    ) -> Result<&mut PointStats> {
        if !self.points.contains_key(&p) {
            self.points
                .insert(p, PointStats::with_u_range(header, u_range)?);
        }
        Ok(self.points.get_mut(&p).expect("inserted"))
    }

    pub fn merge(&mut self, other: &StudyState) -> Result<()> {
        let bad = |message: String| Error::Output {
            path: PathBuf::from("partial.json"),
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
