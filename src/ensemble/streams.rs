//! Counter-based per-member random streams (see the [`ensemble`](super) documentation) and the
//! variates drawn from them.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha12Rng;
use rand_distr::StandardNormal;

/// What a random stream is used for. Each purpose has a fixed 64-bit tag (ASCII of its name);
/// the key of member streams for that purpose is derived from (seed, tag), so purposes never share
/// numbers. New purposes get new tags; existing tags must never change.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum Purpose {
    /// Roughness radii ([`roughness_radii`](super::roughness_radii),
    /// [`correlated_field`](super::correlated_field)): draw i belongs to particle i.
    Roughness,
    /// Velocity perturbation ([`perturbed_velocity`](super::perturbed_velocity)): draw 0
    /// amplitude, draw 1 phase.
    Velocity,
    /// Gap jitter ([`jitter_gaps`](super::jitter_gaps)): draw i belongs to gap i (bonded gaps
    /// consume theirs too).
    Jitter,
    /// Points of a random or Latin hypercube parameter design
    /// ([`Design`](super::design::Design)): the stream of point p, draw d belongs to dimension d.
    Design,
    /// The per-dimension permutations of a Latin hypercube design: the stream of dimension d
    /// drives the Fisher–Yates shuffle of that dimension's strata.
    DesignPermutation,
}

impl Purpose {
    /// The fixed tag hashed with the seed: the little-endian bytes of an 8-letter ASCII name.
    pub const fn tag(self) -> u64 {
        match self {
            Purpose::Roughness => u64::from_le_bytes(*b"roughnes"),
            Purpose::Velocity => u64::from_le_bytes(*b"velocity"),
            Purpose::Jitter => u64::from_le_bytes(*b"jittergp"),
            Purpose::Design => u64::from_le_bytes(*b"designpt"),
            Purpose::DesignPermutation => u64::from_le_bytes(*b"designpm"),
        }
    }
}

/// SplitMix64 finaliser (Steele, Lea, Flood 2014): a bijective 64-bit mixer.
const fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The key seed of a purpose: `splitmix64(splitmix64(seed) ^ purpose.tag())`.
pub const fn purpose_seed(seed: u64, purpose: Purpose) -> u64 {
    splitmix64(splitmix64(seed) ^ purpose.tag())
}

/// Member `member`'s stream for `purpose`: `ChaCha12Rng::seed_from_u64(purpose_seed(seed,
/// purpose))` with `set_stream(member)`, starting at word 0. A pure function of its arguments.
pub fn member_rng(seed: u64, purpose: Purpose, member: u64) -> ChaCha12Rng {
    let mut rng = ChaCha12Rng::seed_from_u64(purpose_seed(seed, purpose));
    rng.set_stream(member);
    rng
}

/// A standard normal variate (`rand_distr`'s ziggurat): every normal draw of every purpose.
pub(super) fn normal(rng: &mut ChaCha12Rng) -> f64 {
    rng.sample(StandardNormal)
}

/// The sigma that gives the lognormal factor exp(sigma Z - sigma^2/2) mean 1 and relative
/// standard deviation `spread`.
pub(super) fn lognormal_sigma(spread: f64) -> f64 {
    // sigma^2 = ln(1 + spread^2): E exp(sigma Z - sigma^2/2) = 1, Var = exp(sigma^2) - 1 = spread^2.
    // Where spread^2 overflows (spread above ~1.3e154; sigma was NaN and every member failed), as
    // 2 ln(spread) (spread^-2 is below rounding there); elsewhere as it always was, bit for bit.
    let square = spread * spread;
    if square.is_finite() {
        square.ln_1p().sqrt()
    } else {
        (2.0 * spread.ln()).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::lognormal_sigma;

    /// exp(sigma^2) - 1 = spread^2 (the lognormal factor's relative variance) where spread^2 is
    /// a number, and sigma^2 = 2 ln(spread) to rounding beyond (it was NaN there).
    #[test]
    fn lognormal_sigma_gives_the_spread_and_stays_finite() {
        for spread in [0.0, 1e-8, 0.3, 1.0, 7.0, 1e100] {
            let s2 = lognormal_sigma(spread).powi(2);
            let variance = s2.exp_m1();
            assert!(
                (variance - spread * spread).abs() <= 1e-13 * (spread * spread).max(1e-300),
                "{spread}: {variance}"
            );
        }
        for spread in [1e155, 1e300, f64::MAX] {
            let s2 = lognormal_sigma(spread).powi(2);
            assert!(
                (s2 - 2.0 * spread.ln()).abs() <= 1e-13 * s2,
                "{spread}: {s2}"
            );
        }
    }
}
