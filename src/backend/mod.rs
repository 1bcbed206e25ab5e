//! The backend seam: one trait ([`BatchSolver`]) that the CPU and the GPU solver implement, the
//! report types both speak, and one selection policy ([`select`]) from (requested backend,
//! precision, plan) to an [`Engine`] that makes solvers and says what runs them.
//!
//! Single runs (`crate::run`) and studies (`crate::study`) are written once against this seam.

pub mod companion;
pub mod cpu;
pub mod error;
pub mod gpu;
pub mod layout;
pub mod report;
pub mod select;
pub mod shared;

pub use roughlub_kernels::overrides;

pub use error::GpuError;
pub use report::{Failure, MemberReport, MemberStatus};
pub use select::{select, BackendRecord, Engine};

use crate::error::Result;
use crate::model::observables::Snapshot;
use crate::model::plan::Plan;

/// Which backend the user asked for (scene `[solver] backend`, CLI `--backend`).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    Cpu,
    Gpu,
    /// The GPU when a usable adapter is found, else the CPU (saying why).
    Auto,
}

/// The floating-point type the solver computes in (outputs are f64 either way).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    F64,
    F32,
}

impl Precision {
    pub fn name(self) -> &'static str {
        match self {
            Precision::F64 => "f64",
            Precision::F32 => "f32",
        }
    }

    /// The fraction of |t| below which a step is lost in the rounding of t
    /// (`control::step_floor`).
    pub fn time_resolution(self) -> f64 {
        match self {
            Precision::F64 => shared::control::TIME_RESOLUTION_F64,
            Precision::F32 => shared::control::TIME_RESOLUTION_F32,
        }
    }
}

/// Told how many member-intervals were completed (called from the solver's worker threads).
pub type Progress<'a> = &'a (dyn Fn(u64) + Sync);

/// A member at an output time, as far as a study records it ([`BatchSolver::output_status`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OutputStatus {
    pub ok: bool,
    /// The estimate of the member's error at this output time; NaN without one.
    pub error_estimate: f64,
}

impl OutputStatus {
    /// Read from a member's report.
    pub fn of(report: &MemberReport) -> OutputStatus {
        OutputStatus {
            ok: report.status == MemberStatus::Ok,
            error_estimate: report
                .error_estimate
                .as_ref()
                .and_then(|e| e.last().copied())
                .unwrap_or(f64::NAN),
        }
    }
}

/// A batch of members advanced from output time to output time.
pub trait BatchSolver: Send {
    /// Advances every member to the next output time and returns their snapshots in member
    /// order (the first call returns the initial state); `None` after the last output time.
    /// `progress` is told of each member-interval as it completes.
    fn next_output(&mut self, progress: Progress) -> Result<Option<Vec<Snapshot>>>;

    /// Every member's status and step counts as of the last output, in member order.
    fn reports(&self) -> Vec<MemberReport>;

    /// What a study records of each member at every output time, in member order: whether it
    /// is still running (not failed), and the estimate of its error at the last output (NaN
    /// where it has none). The same as read from [`reports`](Self::reports), which builds
    /// every report and copies every estimate so far (20 ms of a 0.75 s study, between solves).
    fn output_status(&self) -> Vec<OutputStatus> {
        self.reports().iter().map(OutputStatus::of).collect()
    }

    /// The plan the batch runs.
    fn plan(&self) -> &Plan;

    /// The points the macroscopic fields are sampled at.
    fn grid(&self) -> &[f64];

    /// The GPU's work counters (`None` on the CPU), for the manifest.
    fn gpu_stats(&self) -> Option<report::GpuStats> {
        None
    }
}
