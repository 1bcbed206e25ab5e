//! A fixed pseudo-random stream for the unit tests (xorshift), so that their inputs are the same
//! on every run and no test module carries its own copy.

/// Uniform values in [0, 1) from `seed`.
pub(crate) fn uniform_stream(mut seed: u64) -> impl FnMut() -> f64 {
    move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 11) as f64 / (1u64 << 53) as f64
    }
}
