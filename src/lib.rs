//! roughlub: batched simulation of one-dimensional chains of rough particles interacting through
//! lubrication (see README.md and ../shared/DESIGN.md).

pub mod expr;
pub mod gpu;
pub mod plot;

pub mod cpu;
pub mod error;
pub mod initial;
pub mod observables;
pub mod plan;
pub mod quadrature;
pub mod scene;

pub use error::{Error, Result};
pub mod ensemble;
pub mod output;
pub mod run;
pub mod stats;
pub mod study;
