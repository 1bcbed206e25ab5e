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

/// Everything mergeable of a set of members (a chunk, a run, a shard, merged shards).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StudyState {
    /// Member ranges [first, end) included, sorted and disjoint.
    pub ranges: Vec<(u64, u64)>,
    pub completed: u64,
    pub failed: Vec<u64>,
    /// Per scalar observable, one summary per output time.
    pub scalars: BTreeMap<String, Vec<ScalarSummary>>,
    /// First output time at which max density reaches the threshold.
    pub first_hit: ScalarSummary,
    pub never_hit: u64,
    /// Per field, one band per output time.
    pub fields: BTreeMap<String, Vec<FieldBand>>,
}

impl StudyState {
    /// The empty state of the study `header` describes (its times, grid, field ranges and bins).
    pub fn for_header(header: &StudyHeader) -> Result<StudyState> {
        let times = header.times.len();
        let summary =
            || ScalarSummary::new(SCALAR_ALPHA).expect("SCALAR_ALPHA is a valid accuracy");
        let mut fields = BTreeMap::new();
        for f in FIELDS {
            let (lo, hi) = header.field_ranges[f];
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
        Ok(StudyState {
            ranges: Vec::new(),
            completed: 0,
            failed: Vec::new(),
            scalars: SCALARS
                .iter()
                .map(|s| (s.to_string(), (0..times).map(|_| summary()).collect()))
                .collect(),
            first_hit: summary(),
            never_hit: 0,
            fields,
        })
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
        for (name, per_time) in &other.scalars {
            let mine = self
                .scalars
                .get_mut(name)
                .ok_or_else(|| bad(format!("unknown observable {name}")))?;
            for (a, b) in mine.iter_mut().zip(per_time) {
                a.merge(b).map_err(|e| bad(e.to_string()))?;
            }
        }
        self.first_hit
            .merge(&other.first_hit)
            .map_err(|e| bad(e.to_string()))?;
        self.never_hit += other.never_hit;
        for (name, per_time) in &other.fields {
            let mine = self
                .fields
                .get_mut(name)
                .ok_or_else(|| bad(format!("unknown field {name}")))?;
            if mine.len() != per_time.len() {
                return Err(bad("different numbers of output times".into()));
            }
            for (a, b) in mine.iter_mut().zip(per_time) {
                a.merge(b).map_err(|e| bad(format!("field {name}: {e}")))?;
            }
        }
        Ok(())
    }
}
