//! roughlub: batched simulation of one-dimensional chains of rough particles interacting through
//! lubrication (see README.md, section "Architecture", for where each part lives).
//!
//! scene file → [`scene::Scene`] → [`model::plan::Plan`] → [`backend`] (cpu | gpu, behind
//! [`backend::BatchSolver`]) → observables and [`stats`] → [`output`] directory, orchestrated by
//! [`run`] (one batch), [`study`] (ensembles) and [`converge`] (convergence in N).

pub mod accuracy;
pub mod backend;
pub mod converge;
pub mod ensemble;
pub mod error;
pub mod expr;
pub(crate) mod input;
pub mod model;
pub mod output;
pub mod plot;
pub mod run;
pub mod scene;
pub mod stats;
pub mod study;
#[cfg(test)]
mod test_rng;

pub use error::{Error, Result};
