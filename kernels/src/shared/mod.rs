//! What both backends must agree on, imported by `roughlub::backend::cpu` and `gpu` alike: the
//! gap floors and the gap update's limits ([`gaps`]), step-size and order control with its
//! tolerances and time resolution ([`control`]), and exp and ln as the f64 kernels compute them
//! ([`f64_math`], the twin of `shaders/f64_math.wgsl`).

pub mod control;
pub mod f64_math;
pub mod gaps;
