//! What every backend reports about its members: status, failure reason, step counts.

/// Why a member stopped.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(tag = "status", rename_all = "lowercase")]
pub enum MemberStatus {
    Ok,
    Failed { reason: String, time: f64 },
}

/// A member's bookkeeping, reported in the manifest.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct MemberReport {
    pub index: usize,
    pub mu: f64,
    pub gamma: f64,
    #[serde(flatten)]
    pub status: MemberStatus,
    pub steps_accepted: u64,
    pub steps_rejected: u64,
    pub last_dt: f64,
}

/// Why a member stopped (a code, so the GPU can store it in a u32).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum Failure {
    None = 0,
    /// The step fell below dt_min while every trial closed (or halved) a gap or gave a
    /// non-finite value.
    Inadmissible = 1,
    /// The step fell below dt_min while the error estimate stayed above the tolerance.
    ErrorTooLarge = 2,
}

impl Failure {
    pub fn from_code(code: u32) -> Failure {
        match code {
            0 => Failure::None,
            1 => Failure::Inadmissible,
            _ => Failure::ErrorTooLarge,
        }
    }

    pub fn describe(self, dt_min: f64) -> String {
        match self {
            Failure::None => "ok".into(),
            Failure::Inadmissible => format!(
                "step size collapsed below dt_min = {dt_min:e}: every smaller step closed a gap, shrank one below half, or gave a non-finite value"
            ),
            Failure::ErrorTooLarge => {
                format!("step size collapsed below dt_min = {dt_min:e} (error estimate stayed too large)")
            }
        }
    }
}
