//! Ensembles: members that differ by random roughness profiles and perturbed initial data.
//!
//! # Reproducibility: member m's random inputs are a pure function of (seed, purpose, m)
//!
//! Every random draw of member `m` comes from its own counter-based stream, built by
//! [`member_rng`]:
//!
//! 1. a per-purpose key seed `k = splitmix64(splitmix64(seed) ^ purpose.tag())` (see [`Purpose`]);
//! 2. `ChaCha12Rng::seed_from_u64(k)` (rand_core's PCG32 expansion of `k` into the 256-bit key);
//! 3. `set_stream(m)`: the 64-bit ChaCha nonce is the member index, the block counter starts at 0.
//!
//! So member m's numbers do not depend on how many members are generated, in which order, on
//! which thread, backend or shard. Each purpose (roughness, velocity perturbation, gap jitter) has
//! its own key, so the purposes are independent of one another and adding a purpose (a new tag)
//! never shifts the numbers of another. Within a stream, draw k always goes to the same place
//! (particle k for roughness, gap k for jitter), whatever the spread. Normal variates are
//! `rand_distr::StandardNormal` (ziggurat), so bit-exact reproduction across versions requires the
//! same rand_distr / rand_chacha versions (pinned by Cargo.lock).
//!
//! # Roughness generators ([`RoughnessKind`])
//!
//! Each returns radii r_0..r_N >= 0 with mean `mean_radii[i]` and relative standard deviation
//! `spread` (except `Constant` and `File`, which draw nothing); see [`roughness_radii`] and, for
//! many members without re-validating or re-reading a file, [`RoughnessSampler`]. The pair
//! critical distances follow with [`dstar_from_radii`].
//!
//! # Layout
//!
//! `design` (parameter designs: grids, random, Latin hypercube and Sobol points), `streams` (the
//! per-member random streams), `roughness` (the roughness specification and its
//! validation), `sampler` (drawing radii), `radii` (the radii file and the radii ↔ critical
//! distance conversions) and `perturb` (velocity perturbation and gap jitter); every public item
//! is re-exported here.

use std::path::PathBuf;

pub mod design;
mod perturb;
mod radii;
mod roughness;
mod sampler;
mod streams;

pub use design::{Axis, Design, DesignKind, Scale};
pub use perturb::{jitter_gaps, perturbed_velocity, validate_velocity_perturbation};
pub use radii::{
    dstar_from_radii, mean_radii_from_rho_star, read_radii_file, MAX_ROUGHNESS_RADIUS,
};
pub use roughness::{RoughnessKind, RoughnessSpec, MAX_RELATIVE_SPREAD, UNIFORM_MAX_SPREAD};
pub use sampler::{correlated_field, roughness_radii, RoughnessSampler};
pub use streams::{member_rng, purpose_seed, Purpose};

/// Errors of the ensemble generators; every message names the field and, where there is one, the
/// allowed range.
#[derive(Debug, thiserror::Error)]
pub enum EnsembleError {
    /// A scalar parameter (spread, correlation length, …) outside its allowed range.
    #[error("{field} = {value}: {message} (allowed: {allowed})")]
    InvalidParameter {
        field: String,
        value: f64,
        message: String,
        allowed: String,
    },

    /// One entry of an input array (mean radius, position, gap) outside its allowed range.
    #[error("{field}[{index}] = {value}: {message} (allowed: {allowed})")]
    InvalidEntry {
        field: String,
        index: usize,
        value: f64,
        message: String,
        allowed: String,
    },

    /// Two arrays that must have matching lengths do not.
    #[error("{field} has length {got}, expected {expected}: {message}")]
    LengthMismatch {
        field: String,
        got: usize,
        expected: usize,
        message: String,
    },

    /// A key missing from a roughness specification, or one that does not apply to its kind.
    #[error("{field}: {message}")]
    Spec { field: String, message: String },

    /// A bad row (or header, or row count) in a roughness file.
    #[error("roughness file {path}, line {line}: {message}")]
    RoughnessFile {
        path: PathBuf,
        line: usize,
        message: String,
    },

    /// The roughness file could not be opened.
    #[error("roughness file {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

impl EnsembleError {
    fn parameter(
        field: &str,
        value: f64,
        message: impl Into<String>,
        allowed: impl Into<String>,
    ) -> Self {
        EnsembleError::InvalidParameter {
            field: field.to_string(),
            value,
            message: message.into(),
            allowed: allowed.into(),
        }
    }

    fn entry(
        field: &str,
        index: usize,
        value: f64,
        message: impl Into<String>,
        allowed: impl Into<String>,
    ) -> Self {
        EnsembleError::InvalidEntry {
            field: field.to_string(),
            index,
            value,
            message: message.into(),
            allowed: allowed.into(),
        }
    }
}
