//! Which instruction set the CPU step's lane loops run in.

/// The instruction set of the CPU step's lane loops, chosen at run time from what the CPU has
/// (the build targets baseline x86-64) and passed to the step in `Terms::simd`. Every level runs
/// the same operations in the same order (Rust never contracts a·b + c into an fma, and IEEE add,
/// multiply, divide, min and max round the same at any width), so their results are bitwise
/// equal; only speed differs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum SimdLevel {
    /// Whatever the build targets (SSE2 on x86-64).
    Portable,
    /// 256-bit AVX2 with FMA enabled for the lane loops (x86-64 only).
    Avx2Fma,
    /// AVX-512 (F, VL, DQ) on top of AVX2 + FMA: 512-bit registers and 32 of them, so a block's
    /// sweep state stays in registers (x86-64 only).
    Avx512,
}

impl SimdLevel {
    /// The widest level this CPU runs, at most `cap` (`ROUGHLUB_CPU_SIMD=portable` or `=avx2`,
    /// through [`Overrides`](crate::overrides::Overrides), to compare levels: the results are
    /// the same).
    pub fn capped(cap: Option<SimdLevel>) -> SimdLevel {
        SimdLevel::widest_here().min(cap.unwrap_or(SimdLevel::Avx512))
    }

    /// The widest level the CPU supports, whatever the environment says.
    pub fn widest_here() -> SimdLevel {
        #[cfg(target_arch = "x86_64")]
        if is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") {
            if is_x86_feature_detected!("avx512f")
                && is_x86_feature_detected!("avx512vl")
                && is_x86_feature_detected!("avx512dq")
            {
                return SimdLevel::Avx512;
            }
            return SimdLevel::Avx2Fma;
        }
        SimdLevel::Portable
    }

    /// AVX2 is available at this level (the partitioned solve's transposes).
    pub fn has_avx2(self) -> bool {
        self >= SimdLevel::Avx2Fma
    }

    pub fn name(self) -> &'static str {
        match self {
            SimdLevel::Portable => "portable",
            SimdLevel::Avx2Fma => "avx2+fma",
            SimdLevel::Avx512 => "avx512",
        }
    }
}
