//! What both backends must agree on, imported by `cpu/` and `gpu/` alike: the gap floors and
//! the gap update's limits ([`gaps`]), step-size and order control with its tolerances and time
//! resolution ([`control`]), and exp and ln as the f64 kernels compute them ([`f64_math`], the
//! twin of `shaders/f64_math.wgsl`). They live in the `roughlub-kernels` crate (`kernels/`),
//! beside the CPU step that uses them.

pub use roughlub_kernels::shared::{control, f64_math, gaps};
