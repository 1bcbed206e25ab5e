//! How many trial steps each member takes per `advance` dispatch and per submit, and the loop
//! budget of lavapipe that bounds them.

use super::context::GpuContext;
use super::kernel::SchemeSpec;
use crate::backend::error::GpuError;

/// Trial steps per member encoded into one command buffer (as dispatches × attempts per
/// dispatch): many steps per submit, one read-back of 4 bytes per submit.
pub const ATTEMPTS_PER_SUBMIT: u32 = 256;

/// Most trial steps per member per `advance` dispatch (each invocation loops over them, so a
/// dispatch advances every member by many steps).
pub const MAX_ATTEMPTS_PER_DISPATCH: u32 = 16;

/// llvmpipe (lavapipe) stops every shader invocation after 65535 loop iterations in total
/// (measured: `gather` over 2 loops of N = 40000 left the tail unwritten; N = 20000 was right).
/// One invocation per member sweeps the whole chain, so on that driver N is bounded; other
/// drivers have no such limit. Beyond it the solver takes the partitioned kernel
/// (`super::partitioned`), whose invocations loop over one segment or one member's segments;
/// [`check_loop_budget`] (and `partitioned::fit_budget`) return a clear error instead of
/// silently wrong results where a kernel still would not fit.
pub const LAVAPIPE_LOOP_LIMIT: u64 = 65_535;

/// Whether the adapter is llvmpipe (lavapipe), which bounds the loop iterations of a shader
/// invocation ([`LAVAPIPE_LOOP_LIMIT`]).
pub(super) fn is_lavapipe(ctx: &GpuContext) -> bool {
    let d = &ctx.description;
    d.driver.to_lowercase().contains("llvmpipe") || d.name.to_lowercase().contains("llvmpipe")
}

/// Loop iterations per particle per trial step, at most: per Euler substep two sweeps, the
/// wall-glued bodies, the log-gap fix-up and the projection's two loops (7); with the tableau,
/// per element of gaps and velocities its loops over the R rows (loads, ratios, the Neville
/// double loop, the estimates: at most 3R + R² + 1), the result's projection (two) and the
/// smallest gap named by a failure (one).
fn loops_per_attempt(scheme: SchemeSpec) -> u64 {
    let r = u64::from(scheme.rows);
    7 * u64::from(scheme.substeps())
        + if scheme.tableau() {
            2 * (3 * r + r * r + 1) + 2
        } else {
            0
        }
        + 1
}

/// Trial steps per member per `advance` dispatch: [`MAX_ATTEMPTS_PER_DISPATCH`], or on lavapipe
/// as many as fit its loop budget (measured: past the budget the invocation stops silently and
/// the state is wrong; within it the GPU matches the CPU bit for bit).
/// `forced` (`ROUGHLUB_GPU_ATTEMPTS_PER_DISPATCH`, 1..=4096) overrides it.
pub fn attempts_per_dispatch(
    ctx: &GpuContext,
    n: usize,
    scheme: SchemeSpec,
    forced: Option<u32>,
) -> u32 {
    if let Some(k) = forced {
        return k;
    }
    if is_lavapipe(ctx) {
        // The attempt loop itself counts too: one iteration per attempt.
        let per = loops_per_attempt(scheme) * n as u64 + 1;
        (LAVAPIPE_LOOP_LIMIT / per).clamp(1, MAX_ATTEMPTS_PER_DISPATCH as u64) as u32
    } else {
        MAX_ATTEMPTS_PER_DISPATCH
    }
}

/// `advance` dispatches per submit: [`ATTEMPTS_PER_SUBMIT`] trial steps, at least 4 and at most
/// 64 dispatches.
pub fn dispatches_per_submit(attempts_per_dispatch: u32) -> u32 {
    (ATTEMPTS_PER_SUBMIT / attempts_per_dispatch).clamp(4, 64)
}

/// On lavapipe, [`GpuError::LoopLimit`] when one invocation of `advance` (`attempts` trial
/// steps) or `gather` would exceed [`LAVAPIPE_LOOP_LIMIT`] loop iterations for N = `n`.
pub fn check_loop_budget(
    ctx: &GpuContext,
    n: usize,
    scheme: SchemeSpec,
    attempts: u32,
) -> Result<(), GpuError> {
    if !is_lavapipe(ctx) {
        return Ok(());
    }
    // One `advance` invocation (`begin_interval`'s energy and `gather` need two loops).
    let per = loops_per_attempt(scheme).max(2);
    let iterations = attempts as u64 * (per * n as u64 + 1);
    if iterations > LAVAPIPE_LOOP_LIMIT {
        return Err(GpuError::LoopLimit {
            adapter: ctx.description.short(),
            particles: n,
            iterations,
            limit: LAVAPIPE_LOOP_LIMIT,
            max_particles: (LAVAPIPE_LOOP_LIMIT / attempts as u64 - 1) / per,
        });
    }
    Ok(())
}
