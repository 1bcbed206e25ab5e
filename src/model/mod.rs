//! The vocabulary every layer speaks: a chain, a member's parameters, the plan (which terms
//! exist), the observables and the quadrature rule.

pub mod chain;
pub mod observables;
pub mod params;
pub mod plan;
pub mod quadrature;
