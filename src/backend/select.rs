//! The one selection policy: from (requested backend, precision, plan) to an [`Engine`] that
//! makes solvers, and a [`BackendRecord`] of what runs them (for stderr and every manifest).
//! Single runs and studies both call [`select`], so they fall back the same way and record the
//! same fields.

use serde::Serialize;

use super::cpu::CpuSolver;
use super::gpu::solver::GpuSolver;
use super::gpu::{AdapterDescription, GpuContext};
use super::{Backend, BatchSolver, GpuError, Precision};
use crate::error::{Error, Result};
use crate::model::chain::Chain;
use crate::model::params::{Order, Stepping, MAX_ORDER, MAX_ORDER_F32};
use crate::model::plan::Plan;

/// Which backend actually runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RunsOn {
    Cpu,
    Gpu,
}

impl RunsOn {
    /// As the manifest writes it.
    pub fn name(self) -> &'static str {
        match self {
            RunsOn::Cpu => "cpu",
            RunsOn::Gpu => "gpu",
        }
    }
}

/// What runs the batch, described the same way for the GPU (its adapter) and the CPU.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct AdapterRecord {
    #[serde(flatten)]
    pub description: AdapterDescription,
    /// CPU only: rayon's worker threads.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub threads: Option<usize>,
    /// CPU only: the instruction set of the step's lane loops ([`super::cpu::simd_level`]:
    /// "avx512", "avx2+fma" or "portable"); results do not depend on it, speed does.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cpu_simd: Option<String>,
    /// Why `backend = "auto"` did not use the GPU (`None` when it did, or was not asked).
    pub fallback_reason: Option<String>,
}

/// Recorded in the manifest of every run and study.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct BackendRecord {
    pub backend: RunsOn,
    pub backend_requested: Backend,
    pub precision: Precision,
    pub adapter: AdapterRecord,
}

impl BackendRecord {
    fn gpu(requested: Backend, precision: Precision, d: &AdapterDescription) -> BackendRecord {
        BackendRecord {
            backend: RunsOn::Gpu,
            backend_requested: requested,
            precision,
            adapter: AdapterRecord {
                description: d.clone(),
                threads: None,
                cpu_simd: None,
                fallback_reason: None,
            },
        }
    }

    fn cpu(
        requested: Backend,
        precision: Precision,
        simd_cap: Option<crate::backend::cpu::SimdLevel>,
        fallback_reason: Option<String>,
    ) -> Self {
        let threads = rayon::current_num_threads();
        BackendRecord {
            backend: RunsOn::Cpu,
            backend_requested: requested,
            precision,
            adapter: AdapterRecord {
                description: AdapterDescription {
                    name: format!("cpu (rayon, {threads} threads)"),
                    backend: "cpu".into(),
                    driver: "rayon".into(),
                    driver_info: String::new(),
                    device_type: "Cpu".into(),
                    supports_f64: true,
                },
                threads: Some(threads),
                cpu_simd: Some(super::cpu::simd_level(simd_cap).into()),
                fallback_reason,
            },
        }
    }

    /// "name (backend)" for the GPU, "rayon, K threads" for the CPU.
    pub fn short(&self) -> String {
        match self.backend {
            RunsOn::Gpu => self.adapter.description.short(),
            RunsOn::Cpu => format!("rayon, {} threads", self.adapter.threads.unwrap_or(1)),
        }
    }

    /// The line printed on stderr when a run starts.
    pub fn line(&self) -> String {
        let a = &self.adapter.description;
        let fallback_reason = &self.adapter.fallback_reason;
        let precision = self.precision.name();
        match (self.backend, self.backend_requested, fallback_reason) {
            (RunsOn::Gpu, requested, _) => format!(
                "{}: {} ({}, driver {} {}, {}), precision {precision}",
                if requested == Backend::Auto {
                    "backend auto: a GPU adapter is present; running on the GPU"
                } else {
                    "backend gpu"
                },
                a.name,
                a.backend,
                a.driver,
                a.driver_info,
                a.device_type
            ),
            (RunsOn::Cpu, _, Some(why)) => format!(
                "backend auto: {why}; running on the CPU: {}, precision {precision}",
                a.name
            ),
            (RunsOn::Cpu, Backend::Auto, None) => format!(
                "backend auto: running on the CPU: {}, precision {precision}",
                a.name
            ),
            (RunsOn::Cpu, _, None) => format!("backend cpu: {}, precision {precision}", a.name),
        }
    }
}

/// Makes solvers on the selected backend (the GPU context, when there is one, is built once and
/// shared by every solver, e.g. every chunk of a study).
pub struct Engine {
    gpu: Option<GpuContext>,
    pub record: BackendRecord,
}

impl Engine {
    /// A solver for `chains` (`chains[m]` is member m's initial chain) on this engine.
    /// Order 1 with fixed steps gets its error estimate from a companion run at 4 dt (see
    /// [`companion`](super::companion)) unless the plan turns it off.
    pub fn solver(&self, plan: Plan, chains: Vec<Chain>) -> Result<Box<dyn BatchSolver + '_>> {
        use super::companion::{companion_plan, needs_companion, CompanionEstimate};
        if !(plan.companion_estimate && needs_companion(&plan)) {
            return self.plain_solver(plan, chains);
        }
        let companion = self.plain_solver(companion_plan(&plan), chains.clone())?;
        let mut compared = plan.clone();
        compared.fields.gaps = true;
        compared.fields.velocities = true;
        let run = self.plain_solver(compared, chains)?;
        Ok(Box::new(CompanionEstimate::new(plan, run, companion)))
    }

    /// A solver of the plan as it is, on this engine's backend.
    fn plain_solver(&self, plan: Plan, chains: Vec<Chain>) -> Result<Box<dyn BatchSolver + '_>> {
        Ok(match &self.gpu {
            None => Box::new(CpuSolver::with_precision(
                plan,
                chains,
                self.record.precision,
            )),
            Some(ctx) => Box::new(
                GpuSolver::new(ctx, plan, chains, self.record.precision).map_err(|e| {
                    Error::gpu(
                        format!("backend gpu on {}", self.record.short()),
                        e,
                        "; use backend \"cpu\"",
                    )
                })?,
            ),
        })
    }
}

/// Why `backend = "auto"` did not use the GPU, from the error of [`GpuContext::acquire`].
fn fallback_reason(e: &GpuError) -> String {
    match e {
        // The message already starts "no GPU adapter found".
        GpuError::NoAdapter { .. } => e.to_string(),
        GpuError::NoF64 { .. } => format!("no GPU adapter with f64 shaders: {e}"),
        _ => format!("no usable GPU adapter: {e}"),
    }
}

/// `GpuContext::acquire` failed for `backend = "gpu"`: name the setting and what to do.
fn gpu_acquire_error(e: GpuError, precision: Precision) -> Error {
    match (&e, precision) {
        (GpuError::NoF64 { .. }, Precision::F64) => Error::gpu(
            "precision \"f64\" (solver.precision or --precision) with backend \"gpu\"",
            e,
            "; use precision \"f32\" on this adapter, or backend \"cpu\" for f64",
        ),
        _ => Error::gpu(
            "backend \"gpu\" (solver.backend or --backend)",
            e,
            "; or use backend \"cpu\" (or \"auto\", which falls back to the CPU)",
        ),
    }
}

/// Chooses the backend for batches like `plan` (for a study: its largest chunk). With
/// `Backend::Auto`, the GPU when a hardware adapter (not a software rasterizer) is found that can
/// run the plan at `precision`, else the CPU (in the same precision) with the reason recorded.
pub fn select(requested: Backend, precision: Precision, plan: &Plan) -> Result<Engine> {
    if precision == Precision::F32 && !plan.order.runs_in_f32() {
        return Err(Error::invalid(
            "solver.order",
            format!("{} with precision f32", plan.order.label()),
            "its high columns carry about 1e-3 of f32 rounding into their error estimates",
            format!("1..={MAX_ORDER_F32} or \"auto\" in f32; orders up to {MAX_ORDER} in f64"),
        ));
    }
    if let (Precision::F32, Stepping::Adaptive { tolerance, .. }) = (precision, plan.stepping) {
        let floor = plan.order.f32_tolerance_floor(plan.sequence);
        if tolerance < floor {
            // Rounded up, so that the value named is allowed.
            let at_least = |x: f64| format!("{:.2e}", round_up(x, 3));
            let others = [Order::Auto, Order::Fixed(4), Order::Fixed(6)]
                .map(|o| {
                    format!(
                        "{} for {}",
                        at_least(o.f32_tolerance_floor(plan.sequence)),
                        o.label()
                    )
                })
                .join(", ");
            return Err(Error::invalid(
                "time.tolerance",
                format!(
                    "{tolerance:e} with precision f32, order {} and sequence {}",
                    plan.order.label(),
                    plan.sequence.record(plan.order)
                ),
                "the f32 rounding of that order's steps, added up over them, would exceed that \
                 tolerance (column max(order, 3), column 3 for auto, must carry 10 times less \
                 rounding than it)",
                format!(
                    ">= {} for this order and sequence in f32 (with sequence {}: {others}); \
                     down to 1e-13 in f64",
                    at_least(floor),
                    plan.sequence.record(Order::Auto)
                ),
            ));
        }
    }
    let cpu = |fallback: Option<String>| -> Result<Engine> {
        Ok(Engine {
            gpu: None,
            record: BackendRecord::cpu(requested, precision, plan.overrides.cpu_simd_cap, fallback),
        })
    };
    if requested == Backend::Cpu {
        return cpu(None);
    }
    let ctx = match GpuContext::acquire_among(
        precision == Precision::F64,
        plan.overrides.adapter_name.as_deref(),
    ) {
        Ok(ctx) => ctx,
        Err(e) if requested == Backend::Auto => return cpu(Some(fallback_reason(&e))),
        Err(e) => return Err(gpu_acquire_error(e, precision)),
    };
    // The best adapter is ranked: a CPU-type one (lavapipe, llvmpipe, SwiftShader, WARP) means
    // there is no real GPU. Such a rasterizer runs the kernels ~25x slower than the native CPU
    // backend (case 1: 1.63 s against 0.064 s), so `auto` takes it only when asked by name.
    if requested == Backend::Auto && ctx.description.device_type == "Cpu" {
        return cpu(Some(format!(
            "the only GPU adapter, {}, is a software rasterizer on the CPU (device type Cpu), slower than the native CPU backend; --backend gpu runs on it",
            ctx.description.short()
        )));
    }
    if let Err(e) = GpuSolver::check(&ctx, plan, precision) {
        let on = ctx.description.short();
        if requested == Backend::Auto {
            return cpu(Some(format!(
                "the GPU backend cannot run this scene on {on}: {e}"
            )));
        }
        return Err(Error::gpu(
            format!("backend \"gpu\" (solver.backend or --backend) on {on}"),
            e,
            "; use backend \"cpu\" (or \"auto\", which falls back to the CPU)",
        ));
    }
    let record = BackendRecord::gpu(requested, precision, &ctx.description);
    Ok(Engine {
        gpu: Some(ctx),
        record,
    })
}

/// `x` rounded up to `digits` significant digits (a bound named in a message must be allowed).
fn round_up(x: f64, digits: i32) -> f64 {
    if !(x.is_normal() && x > 0.0) {
        return x;
    }
    let scale = 10f64.powi(digits - 1 - x.log10().floor() as i32);
    let up = (x * scale).ceil() / scale;
    // The division can land a rounding below the value: step up to the next representable one.
    if up < x {
        f64::from_bits(up.to_bits() + 1)
    } else {
        up
    }
}
