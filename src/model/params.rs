//! The numbers that define one member's run: its physical parameters, how it steps, and which
//! observables are kept.

/// Per-member physical parameters.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MemberParams {
    pub mu: f64,
    pub gamma: f64,
}

/// How steps are chosen. Fixed: every member steps with `dt` (shortened to land on output times,
/// halved and retried when a step would close a gap). Adaptive: each member its own dt from a
/// local error estimate.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Stepping {
    Fixed {
        dt: f64,
        dt_min: f64,
    },
    Adaptive {
        tolerance: f64,
        dt_initial: f64,
        dt_min: f64,
    },
}

impl Stepping {
    pub fn dt_min(&self) -> f64 {
        match *self {
            Stepping::Fixed { dt_min, .. } | Stepping::Adaptive { dt_min, .. } => dt_min,
        }
    }
}

/// Which observables are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct OutputFields {
    pub gaps: bool,
    pub velocities: bool,
    pub rho: bool,
    pub u: bool,
    pub rho_star: bool,
    pub energy: bool,
}

impl OutputFields {
    pub fn all() -> OutputFields {
        OutputFields::uniform(true)
    }
    pub fn none() -> OutputFields {
        OutputFields::uniform(false)
    }
    fn uniform(on: bool) -> OutputFields {
        OutputFields {
            gaps: on,
            velocities: on,
            rho: on,
            u: on,
            rho_star: on,
            energy: on,
        }
    }
}

pub const FIELD_NAMES: [&str; 6] = ["gaps", "velocities", "rho", "u", "rho_star", "energy"];
