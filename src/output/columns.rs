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
/// A swept key's column in members.csv: its name, or `point_<name>` where the key has a member
/// column of its own (mu, gamma, particles: the member's value, the same) so that no two columns
/// share a name.
pub fn swept_member_column(name: &str) -> String {
    if MEMBER_COLUMNS.contains(&name) {
        format!("point_{name}")
    } else {
        name.to_string()
    }
}

/// points.csv: this column, the swept keys', then [`POINT_COUNT_COLUMNS`].
pub const POINT_INDEX_COLUMN: &str = "point";
pub const POINT_COUNT_COLUMNS: [&str; 2] = ["completed", "failed"];
