//! What `converge` reports: the per-field summary, the run's summary and the manifest records.

use std::collections::BTreeMap;
use std::path::PathBuf;

use serde::Serialize;

use super::rates::Verdict;
use crate::backend::{BackendRecord, MemberReport};
use crate::output::manifest::SceneRecord;

/// Per field, what the study found at the last output time (also in the manifest).
#[derive(Debug, Clone, Serialize)]
pub struct FieldSummary {
    pub field: &'static str,
    /// L1 differences between successive N at the last output time.
    #[serde(serialize_with = "vec_f64")]
    pub diff_l1: Vec<f64>,
    /// Observed L1 rates at the last output time (K − 2 of them).
    #[serde(serialize_with = "vec_f64")]
    pub rates_l1: Vec<f64>,
    /// The rate at the largest pair (NaN without one).
    #[serde(with = "crate::output::serde_f64")]
    pub rate: f64,
    /// Least-squares slope of ln e against ln N over all pairs, negated (the plots' fitted line).
    #[serde(with = "crate::output::serde_f64")]
    pub fitted_rate: f64,
    pub verdict: Verdict,
    /// |f_∞ − f_K| (L1) at the last output time (NaN when there is no limit).
    #[serde(with = "crate::output::serde_f64")]
    pub limit_error_l1: f64,
    /// Whether every output time of this field is asymptotic (or exact).
    pub asymptotic_all_times: bool,
}

#[derive(Debug, Clone)]
pub struct ConvergeSummary {
    pub out_dir: PathBuf,
    pub particles: Vec<usize>,
    /// What ran the largest N, e.g. "cpu (rayon, 2 threads)".
    pub adapter: String,
    pub backend: String,
    pub fields: Vec<FieldSummary>,
    /// Every field at every output time asymptotic (or exact).
    pub asymptotic: bool,
    /// The warning lines printed (also with `quiet`).
    pub warnings: Vec<String>,
    pub wall_seconds: f64,
}

fn vec_f64<S: serde::Serializer>(v: &[f64], s: S) -> std::result::Result<S::Ok, S::Error> {
    use serde::ser::SerializeSeq;
    let mut seq = s.serialize_seq(Some(v.len()))?;
    for x in v {
        seq.serialize_element(&Num(*x))?;
    }
    seq.end()
}

/// An f64 serialised as `serde_f64` does (non-finite values as strings).
struct Num(f64);
impl Serialize for Num {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        crate::output::serde_f64::serialize(&self.0, s)
    }
}

/// One N's run, as recorded in the manifest.
#[derive(Debug, Serialize)]
pub(super) struct RunRecord {
    pub(super) particles: usize,
    pub(super) eps: f64,
    pub(super) adapter: String,
    pub(super) wall_seconds: f64,
    /// What the run at this N modelled and how it stepped (the terms, the matrix and the
    /// tableau's sequence), as a single run's manifest records it.
    pub(super) plan: crate::model::plan::PlanSummary,
    pub(super) member: MemberReport,
}

/// Per field and output time: the rate at the largest pair, the verdict and the limit error.
#[derive(Debug, Serialize)]
pub(super) struct TimeRecord {
    #[serde(with = "crate::output::serde_f64")]
    pub(super) time: f64,
    #[serde(serialize_with = "vec_f64")]
    pub(super) diff_l1: Vec<f64>,
    #[serde(serialize_with = "vec_f64")]
    pub(super) rates_l1: Vec<f64>,
    pub(super) verdict: Verdict,
    pub(super) asymptotic: bool,
    #[serde(with = "crate::output::serde_f64")]
    pub(super) limit_error_l1: f64,
}

#[derive(Debug, Serialize)]
pub(super) struct ConvergeManifest {
    pub(super) roughlub_version: &'static str,
    pub(super) kind: &'static str,
    pub(super) scene: SceneRecord,
    #[serde(flatten)]
    pub(super) backend: BackendRecord,
    pub(super) wall_seconds: f64,
    pub(super) particles: Vec<usize>,
    pub(super) ratios_equal: bool,
    pub(super) mu: f64,
    pub(super) gamma: f64,
    pub(super) batch_note: Option<String>,
    pub(super) output_times: Vec<f64>,
    pub(super) grid: usize,
    pub(super) asymptotic: bool,
    pub(super) drift_tolerance: f64,
    pub(super) fields: Vec<FieldSummary>,
    pub(super) per_time: BTreeMap<&'static str, Vec<TimeRecord>>,
    pub(super) runs: Vec<RunRecord>,
    pub(super) warnings: Vec<String>,
    pub(super) files: Vec<String>,
    pub(super) conventions: BTreeMap<&'static str, &'static str>,
}
