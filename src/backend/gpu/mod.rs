//! GPU backend (wgpu/WGSL).
//!
//! - [`context`]: acquiring an adapter and device ([`GpuContext`]) and WGSL validation.
//! - [`kernel`]: the step kernel generated per plan from `shaders/step.wgsl`.
//! - [`wgsl_types`]: the kernel's `real` arrays and its `Config` and `Control` structs on the
//!   host side.
//! - [`partitioned`]: the partitioned kernel for few members with huge N (which batches take
//!   it, the segments, its sequence of dispatches).
//! - [`solver`]: [`solver::GpuSolver`], the batch on the GPU, with its buffers (`buffers`) and
//!   the trial steps per dispatch and per submit (`attempts`, lavapipe's loop budget).
//! - [`F64_MATH_WGSL`]: f64 `exp/expm1/log/sin/cos/tan/tanh/pow` for WGSL kernels (the built-in
//!   ones are 32-bit only on Vulkan and return garbage for f64); prepend it to a kernel's source.

mod attempts;
mod buffers;
pub mod context;
pub mod kernel;
pub mod partitioned;
pub mod solver;
pub mod wgsl_types;

pub use crate::backend::error::GpuError;
pub use context::{describe_adapters, validate_wgsl, AdapterDescription, GpuContext};

/// Source of `shaders/f64_math.wgsl`: f64 elementary functions (`exp_f64`, `expm1_f64`,
/// `log_f64`, `sin_f64`, `cos_f64`, `tan_f64`, `tanh_f64`, `pow_f64`), no entry point and no
/// bindings; concatenate it with a kernel's source.
pub const F64_MATH_WGSL: &str = include_str!("../../../shaders/f64_math.wgsl");
