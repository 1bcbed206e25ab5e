//! A fixed pseudo-random stream for the unit tests (xorshift), so that their inputs are the same
//! on every run and no test module carries its own copy.

/// Uniform values in [0, 1) from `seed`.
pub(crate) fn uniform_stream(seed: u64) -> impl FnMut() -> f64 {
    let mut next = integer_stream(seed);
    move || (next() >> 11) as f64 / (1u64 << 53) as f64
}

/// The stream's raw 64-bit integers from `seed` (nonzero).
pub(crate) fn integer_stream(mut seed: u64) -> impl FnMut() -> u64 {
    move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    }
}
