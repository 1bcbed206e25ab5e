//! Every environment variable roughlub itself reads, read once into [`Overrides`] by the command
//! line (`main`, before any thread starts) and passed down in the plan (`Plan::overrides`): the
//! CPU step gets its instruction set and partition choice through `Terms`, the GPU backend the
//! rest. Library users pass [`Overrides::from_env`] or a value of their own; the default
//! overrides nothing.
//! They compare code paths whose results are the same (`ROUGHLUB_CPU_SIMD`,
//! `ROUGHLUB_CPU_PARTITION`, `ROUGHLUB_GPU_PARTITION`, `ROUGHLUB_GPU_ATTEMPTS_PER_DISPATCH`) or
//! restrict the adapters (`WGPU_ADAPTER_NAME`). wgpu reads its own (`WGPU_BACKEND`, ...).

use crate::SimdLevel;

/// What the environment overrides (see the module's documentation).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Overrides {
    /// `ROUGHLUB_CPU_SIMD=portable` or `=avx2`: the widest instruction set the CPU step may use.
    pub cpu_simd_cap: Option<SimdLevel>,
    /// `ROUGHLUB_CPU_PARTITION=off`: the CPU never takes the partitioned solve.
    pub cpu_partition_off: bool,
    /// `ROUGHLUB_GPU_PARTITION=off`: the GPU takes the partitioned kernel only where the
    /// sequential one does not fit.
    pub gpu_partition_off: bool,
    /// `ROUGHLUB_GPU_ATTEMPTS_PER_DISPATCH` (1..=4096): trial steps per GPU dispatch.
    pub gpu_attempts_per_dispatch: Option<u32>,
    /// `WGPU_ADAPTER_NAME`: only adapters whose name contains it (case-insensitive).
    pub adapter_name: Option<String>,
}

impl Overrides {
    /// Reads the variables now (values outside their forms are ignored, as unset).
    pub fn from_env() -> Overrides {
        let var = |name: &str| std::env::var(name).ok();
        Overrides {
            cpu_simd_cap: match var("ROUGHLUB_CPU_SIMD").as_deref() {
                Some("portable") => Some(SimdLevel::Portable),
                Some("avx2") => Some(SimdLevel::Avx2Fma),
                _ => None,
            },
            cpu_partition_off: var("ROUGHLUB_CPU_PARTITION").is_some_and(|v| v == "off"),
            gpu_partition_off: var("ROUGHLUB_GPU_PARTITION").is_some_and(|v| v == "off"),
            gpu_attempts_per_dispatch: var("ROUGHLUB_GPU_ATTEMPTS_PER_DISPATCH")
                .and_then(|v| v.parse::<u32>().ok())
                .filter(|k| (1..=4096).contains(k)),
            adapter_name: var("WGPU_ADAPTER_NAME"),
        }
    }
}
