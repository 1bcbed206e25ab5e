//! The CPU step kernels of roughlub, in a crate of their own so that they are compiled once:
//! an edit anywhere else in roughlub neither recompiles nor re-optimises them (they are most of
//! its build time). The step ([`step`]), the element types it runs in ([`real`]), what the CPU
//! and the GPU backend must agree on ([`shared`]), and the few model types the step reads.
//!
//! Every generic entry point is compiled here for the six block types the CPU backend uses
//! ([`BlockKernels`]): a generic function called from another crate would be compiled there.

pub mod failure;
pub mod overrides;
pub mod power;
pub mod real;
pub mod shared;
pub mod simd;
pub mod step;
pub mod stored_gap;
pub mod tableau;

pub use simd::SimdLevel;

use real::Real;
use step::{StepBuffers, StepReport, Terms};

/// The step's entry points for blocks of L lanes of this type, compiled in this crate (see the
/// crate's documentation); each is the function of [`step`] with the same name.
pub trait BlockKernels<const L: usize>: Real {
    fn euler_step(
        terms: &Terms<L, Self>,
        particles: usize,
        t: &[f64; L],
        h: &[Self; L],
        io: StepBuffers<'_, Self>,
    ) -> [StepReport; L];

    fn state_energy(terms: &Terms<L, Self>, n: usize, gaps: &[Self], vel: &[Self]) -> [f64; L];

    fn conclude(
        terms: &Terms<L, Self>,
        n: usize,
        h: &[Self; L],
        gaps: &mut [Self],
        vel: &[Self],
        report: &mut [StepReport; L],
    );

    fn extrapolate(simd: SimdLevel, io: tableau::TableauIo<Self, L>) -> [tableau::Estimates; L];
}

macro_rules! block_kernels {
    ($($t:ty, $l:literal);*) => {$(
        impl BlockKernels<$l> for $t {
            #[inline(never)]
            fn euler_step(
                terms: &Terms<$l, $t>,
                particles: usize,
                t: &[f64; $l],
                h: &[$t; $l],
                io: StepBuffers<'_, $t>,
            ) -> [StepReport; $l] {
                step::euler_step(terms, particles, t, h, io)
            }

            #[inline(never)]
            fn state_energy(
                terms: &Terms<$l, $t>,
                n: usize,
                gaps: &[$t],
                vel: &[$t],
            ) -> [f64; $l] {
                step::state_energy(terms, n, gaps, vel)
            }

            #[inline(never)]
            fn conclude(
                terms: &Terms<$l, $t>,
                n: usize,
                h: &[$t; $l],
                gaps: &mut [$t],
                vel: &[$t],
                report: &mut [StepReport; $l],
            ) {
                step::conclude(terms, n, h, gaps, vel, report)
            }

            #[inline(never)]
            fn extrapolate(
                simd: SimdLevel,
                io: tableau::TableauIo<$t, $l>,
            ) -> [tableau::Estimates; $l] {
                tableau::extrapolate(simd, io)
            }
        }
    )*};
}

// The CPU backend's block types (`roughlub::backend::cpu`): f64 x1/x8/x16, f32 x1/x8/x32.
block_kernels!(f64, 1; f64, 8; f64, 16; f32, 1; f32, 8; f32, 32);
