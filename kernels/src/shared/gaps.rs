//! The gap floors and the limits of the gap update: values both backends' step kernels use.
//! The WGSL kernels get the gap floors, `LN_RATIO_SERIES` and the spike's threshold from
//! `roughlub::backend::gpu::kernel`; `GAP_EXP_TAYLOR`, `EXP_FAST_MAX`, `MAX_OPENING` and
//! `NEGLIGIBLE_OPENING` are written in `shaders/step.wgsl` with the same values (keep them in
//! sync).

/// Gaps smaller than this are stored as ln d, and enter the linear solve as this value (the
/// velocities it yields differ from the limit d → 0 by ~GAP_FLOOR·r, far below rounding).
pub const GAP_FLOOR: f64 = 1e-250;
/// ln(GAP_FLOOR).
pub const LN_GAP_FLOOR: f64 = -575.646_273_248_511_4;
/// GAP_FLOOR of the f32 kernels (GPU and CPU): far enough above f32's smallest normal (1.2e-38) that
/// mu/GAP_FLOOR and the sweep's products stay finite for mu up to 1e12.
pub const GAP_FLOOR_F32: f64 = 1e-24;
/// ln(GAP_FLOOR_F32).
pub const LN_GAP_FLOOR_F32: f64 = -55.262_042_231_857_1;

/// Largest h r a step may give an opening gap stored as d (it grows by at most e^MAX_OPENING).
/// The solve linearises the lubrication impulse mu (ln d' − ln d) as mu h r, which e^{h r}
/// honours exactly; but a pair flying apart separates linearly, and for large h r that update
/// overshoots (measured: a gap of 1e-4 grown by e^20 took the whole length, and the projection
/// then crushed every other gap). Such a step is rejected and retried smaller. h r = F h/mu for
/// a pair pulled apart by a force F, so the limit does not depend on the gap; closing gaps have
/// none (e^{h r} is the lubrication brake), nor do gaps stored as ln d (their growth is
/// negligible against the total, and their rate comes from the force balance). 5 was the
/// cheapest value that completed the extremes matrix at N = 24 and 200 (2 did too, with twice
/// the rejections).
pub const MAX_OPENING: f64 = 5.0;

/// A gap that opens beyond MAX_OPENING in a step is let through where its new value stays below
/// this fraction of the member's total gap: the overshoot MAX_OPENING guards against is the
/// length such a gap takes from the others (the projection gives it back from all of them, here
/// at most this fraction of each). A pair at contact that flies apart with lubrication
/// dominating opens by m Δu / mu whatever the step (mu ln d changes by the momentum), so without
/// this every retry of such a step was rejected: fixed order 4 at dt = 1e-3 failed the
/// mu = 1e-4 members of scenes/extremes/rho0.9999_u0.5.toml (a gap of e^-556 opening), which
/// order 1 completes.
pub const NEGLIGIBLE_OPENING: f64 = 1e-12;

/// How many of its rounding units, eps |ln d|, a log-stored gap's ln d carries into the
/// tableau's estimates, which count only above it ([`log_stored_allowance`]). Each substep
/// rounds ln d' = ln d + h r to eps |ln d|, and the Aitken-Neville weights amplify the rows'
/// differences: on `docs/work_precision_extreme.toml` (gaps down to e^-1536) the estimates at
/// tolerance 1e-12 were whole multiples of ulp(ln d)/6 at ln d ~ -709, up to 6.6 eps |ln d|,
/// whatever the step, and the step collapsed (t = 0.0046, 105545 + 119279 steps).
pub const LOG_STORED_ROUNDING: f64 = 32.0;

/// The part of a log-stored gap's estimate e that is rounding, LOG_STORED_ROUNDING eps |ln d|,
/// taken off e (a NaN stays NaN): e counts only where it exceeds what ln d's rounding alone
/// gives. A gap stored as d has none: its rows' ratios are exact to eps.
#[inline(always)]
pub fn log_stored_allowance<T: crate::real::Real>(e: T, ln_d: T) -> T {
    let allowance = T::c(LOG_STORED_ROUNDING) * T::EPSILON * ln_d.abs();
    if e <= allowance {
        T::ZERO
    } else {
        e - allowance
    }
}

/// Below this |y - last|/last [`ln_gap_ratio`](crate::step::ln_gap_ratio) uses its series.
pub const LN_RATIO_SERIES: f64 = 1.0 / 16.0;

/// Below this |h r| the gap update uses the Taylor polynomial ([`gap_exp`](crate::step::gap_exp)).
pub const GAP_EXP_TAYLOR: f64 = 1.0 / 16.0;

/// Range in which the back sweep's branch-free exp is used (`f64_math::exp_in_range`); a step
/// whose h r leaves it is redone in log form (below) or is far beyond MAX_OPENING (above).
pub const EXP_FAST_MAX: f64 = 700.0;

/// The partitioned solve (`crate::step::partitioned` and its GPU twin): spike
/// coefficients and the running product of w are set to 0 below this: their terms are
/// then far below rounding, and letting them decay through the subnormals would cost a
/// microcode assist per operation.
/// (Also the GPU twin's, `shaders/partitioned.wgsl`.)
pub const SPIKE_TINY: f64 = 1e-140;
/// [`SPIKE_TINY`] in f32 (1e-140 is below f32's range): far above f32's smallest normal (1.2e-38),
/// far below anything that matters against the O(1) terms it is added to (2^-24).
/// (Also the GPU's f32 twin's, `SPIKE_TINY_F32` in src/backend/gpu/partitioned.rs.)
pub const SPIKE_TINY_F32: f64 = 1e-30;
