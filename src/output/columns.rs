//! The column names of a study's tables (members.csv, points.csv): written by the study, and
//! reserved by the scene's `[sweep]` (a swept key may not take one of them).

/// The first columns of members.csv, before the swept keys'.
pub const MEMBER_KEY_COLUMNS: [&str; 2] = ["member", "sweep_point"];
/// The columns of members.csv after the swept keys'.
pub const MEMBER_COLUMNS: [&str; 18] = [
    "mu",
    "gamma",
    "particles",
    "status",
    "failure_time",
    "failure_reason",
    "velocity_factor",
    "velocity_phase",
    "mean_dstar",
    "min_rho_star",
    "peak_density",
    "peak_time",
    "min_gap",
    "final_energy",
    "first_hit_time",
    "steps_accepted",
    "steps_rejected",
    "error_estimate",
];
/// points.csv: this column, the swept keys', then [`POINT_COUNT_COLUMNS`].
pub const POINT_INDEX_COLUMN: &str = "point";
pub const POINT_COUNT_COLUMNS: [&str; 2] = ["completed", "failed"];
