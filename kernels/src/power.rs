//! How the repulsion G = ratio^gamma is evaluated, the same way on the CPU and in the GPU kernel.

use crate::real::Real;

/// The largest integer gamma evaluated by multiplications ([`Power::Integer`]); larger or
/// non-integer gamma is [`Power::Real`]. 1000 (the largest gamma a scene accepts) takes 10 bits:
/// at most 9 squarings and 10 multiplications, the same sequence on the CPU and in the GPU kernel
/// (`roughlub::backend::gpu::kernel`), so that f64 results agree bit for bit.
pub const MAX_INTEGER_GAMMA: u32 = 1000;

/// How G = ratio^gamma is evaluated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Power {
    /// A chain of multiplications (square and multiply), for integer gamma <= [`MAX_INTEGER_GAMMA`].
    Integer(u32),
    /// exp(gamma ln ratio).
    Real(f64),
}

impl Power {
    /// Integer gamma in 0..=[`MAX_INTEGER_GAMMA`] by multiplications, anything else by `powf`.
    pub fn of(gamma: f64) -> Power {
        if gamma.fract() == 0.0 && (0.0..=MAX_INTEGER_GAMMA as f64).contains(&gamma) {
            Power::Integer(gamma as u32)
        } else {
            Power::Real(gamma)
        }
    }

    /// The gamma this power raises to (`Power::of` of it gives back `self`).
    #[inline(always)]
    pub fn exponent(self) -> f64 {
        match self {
            Power::Integer(k) => k as f64,
            Power::Real(g) => g,
        }
    }

    #[inline(always)]
    pub fn apply(self, ratio: f64) -> f64 {
        match self {
            Power::Integer(n) => powi_by_squaring(ratio, n),
            Power::Real(g) => ratio.powf(g),
        }
    }
}

/// ratio^n by square-and-multiply in any [`Real`]: ~2 log2(n) multiplications, the same
/// sequence on CPU and GPU (f64 and f32 alike, so each agrees with its GPU twin bit for bit).
#[inline(always)]
pub fn powi_by_squaring<T: Real>(ratio: T, n: u32) -> T {
    let mut result = T::ONE;
    let mut base = ratio;
    let mut e = n;
    while e > 0 {
        if e & 1 == 1 {
            result *= base;
        }
        e >>= 1;
        if e > 0 {
            base *= base;
        }
    }
    result
}

/// [`powi_by_squaring`] for n <= [`MAX_INTEGER_GAMMA`] (what [`Power::Integer`] holds) in a fixed
/// number of rounds with selects, as the GPU's per-member power: the step's lane loops stay
/// packed with an n known only at run time, where the loop over n's bits kept them scalar. The
/// selects skip the multiplications the loop skips, so the same bits.
#[inline(always)]
pub fn powi_in_rounds<T: Real>(ratio: T, n: u32) -> T {
    debug_assert!(n <= MAX_INTEGER_GAMMA);
    let (mut result, mut base, mut e) = (T::ONE, ratio, n);
    for _ in 0..INTEGER_GAMMA_BITS {
        result = if e & 1 == 1 { result * base } else { result };
        e >>= 1;
        base = if e > 0 { base * base } else { base };
    }
    result
}

/// Bits of the largest integer gamma evaluated by multiplications (10 for 1000).
pub const INTEGER_GAMMA_BITS: u32 = u32::BITS - MAX_INTEGER_GAMMA.leading_zeros();
