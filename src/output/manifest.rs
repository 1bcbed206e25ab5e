//! The manifests, typed: what a run, a study and a merge record (written last, atomically, by
//! [`super::write_json_atomic`]). Each records what determines its results: scene text, crate
//! version, backend and precision.

use std::collections::BTreeMap;

use serde::Serialize;

use crate::backend::report::GpuStats;
use crate::backend::select::BackendRecord;
use crate::backend::MemberReport;
use crate::model::params::Stepping;
use crate::model::plan::PlanSummary;
use crate::scene::EnsembleSpec;

pub const VERSION: &str = env!("CARGO_PKG_VERSION");

#[derive(Debug, Serialize)]
pub struct SceneRecord {
    pub name: String,
    pub description: Option<String>,
    pub path: String,
    pub text: String,
}

/// `serialize_with` helpers for optional numbers that may be infinite or NaN: JSON has no such
/// numbers and serde_json writes them as null, which the manifest keeps for "unavailable", so
/// they are written as [`serde_f64`](crate::output::serde_f64) writes them ("inf", "-inf",
/// "NaN"; Python's `float()` reads either form).
pub mod non_finite {
    use serde::ser::{SerializeSeq, Serializer};

    struct Number(f64);

    impl serde::Serialize for Number {
        fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
            crate::output::serde_f64::serialize(&self.0, serializer)
        }
    }

    pub fn option<S: Serializer>(value: &Option<f64>, serializer: S) -> Result<S::Ok, S::Error> {
        match value {
            Some(x) => crate::output::serde_f64::serialize(x, serializer),
            None => serializer.serialize_none(),
        }
    }

    pub fn option_vec<S: Serializer>(
        value: &Option<Vec<f64>>,
        serializer: S,
    ) -> Result<S::Ok, S::Error> {
        match value {
            Some(values) => {
                let mut seq = serializer.serialize_seq(Some(values.len()))?;
                for &x in values {
                    seq.serialize_element(&Number(x))?;
                }
                seq.end()
            }
            None => serializer.serialize_none(),
        }
    }
}

/// How the members' error estimates (`error_estimate` per member and output time, in a single
/// run's members; each member's largest over its output times in members.csv of a study) are
/// made, and the largest.
#[derive(Debug, Clone, Serialize)]
pub struct ErrorEstimateRecord {
    pub method: std::borrow::Cow<'static, str>,
    /// The largest estimate over the members that completed and their output times (null where
    /// unavailable; "inf" where infinite: a companion that failed where the run did not).
    #[serde(serialize_with = "non_finite::option")]
    pub largest: Option<f64>,
    /// Set where the largest estimate is above its method's limit (see [`large_error_warning`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub warning: Option<String>,
}

impl ErrorEstimateRecord {
    /// `companion`: whether order 1 with fixed steps ran its error-estimating companion.
    pub fn new(
        order: crate::model::params::Order,
        stepping: crate::model::params::Stepping,
        precision: crate::backend::Precision,
        companion: bool,
        largest: Option<f64>,
    ) -> Self {
        match crate::backend::report::run_error_estimate_method(order, stepping, companion) {
            Some(method) => ErrorEstimateRecord {
                method: method.into(),
                largest,
                warning: large_error_warning(largest, method, stepping.tolerance(), precision),
            },
            None => ErrorEstimateRecord {
                method: ERROR_ESTIMATE_UNAVAILABLE.into(),
                largest: None,
                warning: None,
            },
        }
    }
}

/// The warning for an error estimate above its method's limit
/// ([`LARGE_ERROR_ESTIMATE`](crate::backend::report::LARGE_ERROR_ESTIMATE) for adaptive steps,
/// [`LARGE_FIXED_STEP_ERROR_ESTIMATE`](crate::backend::report::LARGE_FIXED_STEP_ERROR_ESTIMATE)
/// for fixed steps), if it is. The companion's (order 1, fixed steps) compares two whole runs, so
/// it measures the error with its propagation: above the limit the results are not converged,
/// and on coarse steps it fell to 0.15-0.7 times the error. The extrapolated orders add each
/// step's local estimate without what the later steps do to it: it fell to 0.15 times the error
/// where fixed steps are coarse and the errors grow along the run (docs/error_estimate), and a
/// fast transient that fixed steps do not resolve (velocities far from their force balance at
/// t = 0 near contact) adds its first steps' local error in full although the next steps damp
/// it, so there the estimate can grow as dt shrinks while the error falls (order 2 on
/// scenes/extremes/rho0.9999_u2.toml, mu = gamma = 1: 5.0e-3 at dt = 1e-3, where the error
/// against a converged run is 2e-11, and 0.15 at 1e-5; docs/outputs.md). So their warning says
/// the results may not be converged. A method recorded by no version of this one (a merge of old
/// studies) warns as the fixed-step orders do. Below its limit, an adaptive run (`tolerance`)
/// whose estimate is more than [`TOLERANCE_NOT_MET_FACTOR`](crate::backend::report::TOLERANCE_NOT_MET_FACTOR)
/// times its tolerance warns that the tolerance was not met, and in f32 that rounding is why.
pub fn large_error_warning(
    largest: Option<f64>,
    method: &str,
    tolerance: Option<f64>,
    precision: crate::backend::Precision,
) -> Option<String> {
    use crate::backend::report::{
        ADAPTIVE_ESTIMATE_METHOD, LARGE_ERROR_ESTIMATE, LARGE_FIXED_STEP_ERROR_ESTIMATE,
        TOLERANCE_NOT_MET_FACTOR,
    };
    let adaptive = method == ADAPTIVE_ESTIMATE_METHOD;
    let limit = if adaptive {
        LARGE_ERROR_ESTIMATE
    } else {
        LARGE_FIXED_STEP_ERROR_ESTIMATE
    };
    if let (true, Some(e), Some(tolerance)) = (adaptive, largest, tolerance) {
        if e <= limit && e > TOLERANCE_NOT_MET_FACTOR * tolerance {
            let times = e / tolerance;
            let why = match precision {
                crate::backend::Precision::F32 => "in f32 the rounding of the steps adds up over them, most near contact (measured with order auto: 0.5 to 3.1 times the tolerance on the paper's cases 1, 2a and 3 from 1e-2 to 3e-5, but 30 times at 3e-5 on a chain driven to a gap of 1e-13, docs/backends-and-precision.md): use precision = \"f64\" near contact or for tighter results",
                crate::backend::Precision::F64 => "the estimate adds the local errors that the steps held below the tolerance, without what later steps do to them, so it is mostly above the error; near contact they add up (docs/accuracy.md, Near contact)",
            };
            return Some(format!(
                "the largest error estimate {e:.2e} is {times:.0} times the tolerance {tolerance:e}: these results may be accurate only to about the estimate, not to the tolerance; {why}"
            ));
        }
    }
    let e = largest.filter(|e| !(*e <= limit))?;
    let head = format!("the largest error estimate {e:.2e} is above {limit}");
    Some(if method == crate::backend::companion::COMPANION_METHOD {
        format!(
            "{head}: these results are not converged in time; use a smaller dt or a higher order (roughlub accuracy SCENE measures which). The estimate compares the run with one at 4 dt; on coarse steps it was measured down to a seventh of the error"
        )
    } else if adaptive {
        format!(
            "{head}: these results may not be converged in time; use a smaller tolerance (roughlub accuracy SCENE measures which). The estimate adds each step's local error without what later steps do to it, mostly above the error"
        )
    } else {
        format!(
            "{head}: these results may not be converged in time; use a smaller dt or a higher order (roughlub accuracy SCENE measures which). The estimate adds each step's local error without what later steps do to it: on coarse steps it was measured down to a seventh of the error, and a fast transient that the steps do not resolve can inflate it while the error is small, as can many steps: it adds the next lower order's local errors (order 2 at dt = 1e-3 on the paper's cases, 3000 steps: 0.04 to 0.16, 117 to 664 times the error, docs/error_estimate/paper_fixed_steps.py)"
        )
    })
}

/// Why order 1 with fixed steps has no estimate.
pub const ERROR_ESTIMATE_UNAVAILABLE: &str = "unavailable: order 1 with fixed steps and [solver] error_estimate = false computes no second solution to compare with";

/// `manifest.json` of a single run.
#[derive(Debug, Serialize)]
pub struct RunManifest {
    pub roughlub_version: &'static str,
    pub scene: SceneRecord,
    #[serde(flatten)]
    pub backend: BackendRecord,
    pub gpu_stats: Option<GpuStats>,
    pub wall_seconds: f64,
    /// The part of `wall_seconds` spent building the solver and advancing it through every
    /// output time (what the work-precision bench times): the wall time less reading the inputs,
    /// choosing the backend (on the GPU: its adapter and device), writing the outputs and plots.
    pub solve_seconds: f64,
    pub particles: usize,
    pub eps: f64,
    pub order: crate::model::params::Order,
    pub stepping: Stepping,
    pub plan: PlanSummary,
    pub output_times: Vec<f64>,
    pub grid: usize,
    pub error_estimate: ErrorEstimateRecord,
    pub members: Vec<MemberReport>,
    pub failed_members: Vec<usize>,
    pub steps_accepted_total: u64,
    pub steps_rejected_total: u64,
    /// Every file the run read besides the scene (a particle file), path -> FNV-1a of its bytes.
    pub input_files: BTreeMap<String, String>,
    pub files: Vec<String>,
    pub conventions: BTreeMap<&'static str, &'static str>,
}

/// Scene identity of a study (the hash is what resume and merge compare).
#[derive(Debug, Serialize)]
pub struct StudySceneRecord {
    pub name: String,
    pub text: String,
    pub hash: String,
}

/// `manifest.json` of an ensemble study (or one shard of it).
#[derive(Debug, Serialize)]
pub struct StudyManifest {
    pub roughlub_version: &'static str,
    pub kind: &'static str,
    pub scene: StudySceneRecord,
    #[serde(flatten)]
    pub backend: BackendRecord,
    pub gpu_stats: Option<GpuStats>,
    pub shard: (u64, u64),
    pub member_range: (u64, u64),
    pub members_total: u64,
    pub members_completed: u64,
    pub failed_members: Vec<u64>,
    pub error_estimate: ErrorEstimateRecord,
    /// Every file the study read besides the scene (particle file, roughness file), path ->
    /// FNV-1a of its bytes (what `--resume` and `merge` compare).
    pub input_files: BTreeMap<String, String>,
    /// "exact" or "frozen": the matrix of the extrapolated steps (`[solver] jacobian`).
    pub jacobian: &'static str,
    /// "from_1" or "from_2": the substeps of the tableau's rows (`[solver] sequence`, as
    /// resolved for the study's precision: its header's).
    pub sequence: String,
    pub chunks: usize,
    pub chunks_reused: usize,
    /// Chunks solved a second time because a member failed after its point's rows had been
    /// pushed as they were observed (the statistics are the same bits either way).
    pub chunks_solved_twice: usize,
    pub wall_seconds: f64,
    pub statistics_seconds: f64,
    pub statistics_share: f64,
    /// The memory the study was estimated to need before it started, and the limit it was held
    /// to (half the machine's memory; `--allow-large` lifts it).
    pub memory_estimate_bytes: u64,
    pub memory_limit_bytes: u64,
    /// The bytes it was estimated to write (members' arrays, members.csv, statistics), held to
    /// the run's output limit unless `--allow-large`.
    pub disk_estimate_bytes: u64,
    /// Points 0..detailed_points keep per-time statistics; the fields whose bands they keep.
    pub detailed_points: u64,
    pub band_fields: Vec<String>,
    /// The format of the binary state files (partial.state, chunks/*.state).
    pub state_format: u32,
    pub ensemble: EnsembleSpec,
    pub quantile_method: QuantileMethod,
}

/// `manifest.json` of `roughlub merge`.
#[derive(Debug, Serialize)]
pub struct MergedManifest {
    pub roughlub_version: &'static str,
    pub kind: &'static str,
    pub inputs: Vec<String>,
    pub scene: StudySceneRecord,
    pub backend: crate::backend::select::RunsOn,
    pub precision: crate::backend::Precision,
    pub members_total: u64,
    pub members_covered: u64,
    pub complete: bool,
    pub member_ranges: Vec<(u64, u64)>,
    /// Member ranges [first, end) no shard covered (only with `--allow-partial`).
    pub missing_member_ranges: Vec<(u64, u64)>,
    pub members_completed: u64,
    pub failed_members: Vec<u64>,
    /// The inputs' method, and the largest of their members' estimates (members.csv).
    pub error_estimate: ErrorEstimateRecord,
    /// The files the shards read (the same in every shard: merge refuses others).
    pub input_files: BTreeMap<String, String>,
    /// "exact" or "frozen", as the inputs' manifests record it (None where none does).
    pub jacobian: Option<String>,
    /// "from_1" or "from_2": the shards' (merge refuses a mixture).
    pub sequence: String,
    /// Where each shard ran.
    pub shard_backends: Vec<ShardBackend>,
    pub wall_seconds: f64,
    pub quantile_method: QuantileMethod,
}

/// One input of a merge: the backend it asked for and the adapter it ran on, from its manifest
/// (null where it has none). A merge of merges lists the shards of its inputs.
#[derive(Debug, Serialize, serde::Deserialize)]
pub struct ShardBackend {
    pub input: String,
    pub member_range: (u64, u64),
    pub backend_requested: Option<serde_json::Value>,
    pub adapter: Option<serde_json::Value>,
}

/// How a study's quantiles and histograms are computed (and how accurate they are).
#[derive(Debug, Serialize)]
pub struct QuantileMethod {
    pub scalars: String,
    pub fields: &'static str,
    pub field_ranges: BTreeMap<String, (f64, f64)>,
    pub bins: usize,
    pub scalar_histograms: String,
}

#[cfg(test)]
mod tests {
    use super::ErrorEstimateRecord;
    use crate::backend::{MemberReport, Precision};
    use crate::model::params::{Order, Stepping};

    /// An infinite estimate (a companion that failed where the run did not) is "inf", not the
    /// null of "unavailable"; a failed member's NaN is "NaN"; finite values stay numbers.
    #[test]
    fn non_finite_estimates_are_strings_not_null() {
        let stepping = Stepping::Fixed {
            dt: 1e-3,
            dt_min: 1e-12,
        };
        let record = ErrorEstimateRecord::new(
            Order::Fixed(1),
            stepping,
            Precision::F64,
            true,
            Some(f64::INFINITY),
        );
        let json = serde_json::to_value(&record).unwrap();
        assert_eq!(json["largest"], "inf");
        assert!(json["warning"].as_str().unwrap().contains("inf"));
        let unavailable =
            ErrorEstimateRecord::new(Order::Fixed(1), stepping, Precision::F64, false, None);
        assert!(serde_json::to_value(&unavailable).unwrap()["largest"].is_null());
        let report = MemberReport {
            index: 0,
            mu: 0.01,
            gamma: 2.0,
            status: crate::backend::MemberStatus::Ok,
            steps_accepted: 3,
            steps_rejected: 0,
            last_dt: 1e-3,
            last_order: 1,
            error_estimate: Some(vec![0.0, 0.25, f64::INFINITY, f64::NAN]),
        };
        let json = serde_json::to_value(&report).unwrap();
        assert_eq!(
            json["error_estimate"],
            serde_json::json!([0.0, 0.25, "inf", "NaN"])
        );
    }
}
