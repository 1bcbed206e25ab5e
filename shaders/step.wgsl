// The batch advanced on the GPU, one invocation per member (member b's element i at
// `i * batch + b`), each member with its own time, step size and status. WGSL twin of
// src/backend/cpu/step.rs (`euler`: the linearly implicit Euler step fused with the Thomas
// solve; read its header for the equations), of `Block::error_norm` / `Block::extrapolate` in
// src/backend/cpu/mod.rs and of `StepControl` in src/backend/cpu/control.rs. Keep them in sync,
// loop for loop.
//
// Entry points: `begin_interval` (StepControl::begin_interval), `advance` (up to
// config.max_attempts trial steps per member per dispatch, as the lane loop of Block::advance:
// one Euler step for order 1 with fixed steps, else one full and two half steps, the error
// estimate and/or the extrapolation, then accept or reject), `gather` (copies each member's
// current state into the output buffers for read-back at output times).
// A member's state lives in one of two buffer sets (its `parity`); the candidate goes to the
// other set and an accepted step only flips the parity, so nothing is copied.
//
// This file is a TEMPLATE, filled by `generate_step_wgsl` (src/backend/gpu/kernel.rs), line by line:
//  - the line declaring the alias `real` is replaced by the element type (f32 or f64);
//  - blocks between the marker lines BEGIN NAME and END NAME (comment lines starting with
//    slash-slash-at) are kept or removed: REPULSION, CLUSTERS, FREE (= no clusters), FORCING,
//    EULER (order 1, fixed steps), RICHARDSON (else), ADAPTIVE, ORDER2;
//    terms the plan leaves out are not compiled at all;
//  - the marker line GENERATED is replaced by the generated code: REAL_MAX, `power(r, gamma)`
//    (integer gamma: a fixed square-and-multiply chain, the sequence of `powi_by_squaring`;
//    per-member gamma: the same chain when gamma is an integer <= 64 as `Power::of` does, else
//    exp/pow), `gamma_of(gamma)`, the forcing function `forcing(x, t)` and the unrolled
//    Gauss–Legendre sum `particle_force(eps, t, q)`; the f64 math library is prepended when the
//    generated code calls it.
//
// Bindings (group 0): 0 config (uniform), 1 gap sets, 2 velocity sets, 3 member parameters,
// 4 controls, 5 scratch (w | lambda | y, each (N-1)·batch), 6 running counter (atomic),
// 7 gathered gaps, 8 dstar (repulsion only), 9 bonded (u32, clusters only), 10 gathered velocities.
// The host uploads and reads back Config, Param and Control (src/backend/gpu/wgsl_types.rs and
// src/backend/gpu/buffers.rs): keep their layouts in sync.

alias real = f64;

// Keep in sync with `ConfigF64` / `ConfigF32` in src/backend/gpu/wgsl_types.rs (`padding`
// keeps the reals 8-aligned for f64).
struct Config {
    batch: u32,
    particles: u32,
    max_attempts: u32,
    padding: u32,
    eps: real,
    t_start: real,
    t_end: real,
    // > 0: fixed steps of this size (Rules::fixed_h); 0: adaptive steps.
    fixed_h: real,
    dt_min: real,
    tolerance: real,
}

// Uploaded as pairs of reals (mu, gamma) per member by src/backend/gpu/buffers.rs.
struct Param {
    mu: real,
    // Used only with a per-member gamma (GammaSpec::PerMember).
    gamma: real,
}

// StepControl of src/backend/cpu/control.rs (counters in u32, flags as u32). Keep in sync with
// `ControlF64` / `ControlF32` in src/backend/gpu/wgsl_types.rs.
struct Control {
    t: real,
    dt: real,
    failure_time: real,
    accepted: u32,
    rejected: u32,
    regular_steps: u32,
    regular: u32,
    failure: u32,
    parity: u32,
}

struct GapTerms {
    c: real,
    g: real,
}

@group(0) @binding(0) var<uniform> config: Config;
@group(0) @binding(1) var<storage, read_write> gap_sets: array<real>;
@group(0) @binding(2) var<storage, read_write> vel_sets: array<real>;
@group(0) @binding(3) var<storage, read> params: array<Param>;
@group(0) @binding(4) var<storage, read_write> controls: array<Control>;
@group(0) @binding(5) var<storage, read_write> scratch: array<real>;
@group(0) @binding(6) var<storage, read_write> running: atomic<u32>;
@group(0) @binding(7) var<storage, read_write> gathered_gaps: array<real>;
@group(0) @binding(10) var<storage, read_write> gathered_vel: array<real>;
//@BEGIN REPULSION
@group(0) @binding(8) var<storage, read> dstar: array<real>;
//@END REPULSION
//@BEGIN CLUSTERS
@group(0) @binding(9) var<storage, read> bonded: array<u32>;
//@END CLUSTERS

// Buffer sets: 0 and 1 hold a member's state and candidate (by parity); 2 and 3 the full and
// half steps of Richardson extrapolation.
const FULL_SET: u32 = 2u;
const HALF_SET: u32 = 3u;

// Step control constants of src/backend/cpu/control.rs.
const REJECT_SHRINK: real = 0.25;
const SAFETY: real = 0.9;
const MAX_GROWTH: real = 5.0;
const MAX_SHRINK: real = 0.2;

// MIN_GAP_RATIO of src/backend/cpu/step.rs.
const MIN_GAP_RATIO: real = 0.5;

//@GENERATED

// `gap_step_admissible`: new > MIN_GAP_RATIO * old and finite (NaN fails both comparisons).
fn gap_step_admissible(old: real, new_gap: real) -> bool {
    return new_gap > MIN_GAP_RATIO * old && new_gap <= REAL_MAX;
}

// Whether a gap is free (not bonded inside a cluster).
fn is_free(index: u32) -> bool {
//@BEGIN CLUSTERS
    return bonded[index] == 0u;
//@END CLUSTERS
//@BEGIN FREE
    return true;
//@END FREE
}

// Coupling c and repulsion G of one gap (`gap_terms`).
fn gap_terms(index: u32, d: real, p: Param, h: real, eps2: real) -> GapTerms {
//@BEGIN CLUSTERS
    if bonded[index] != 0u {
        return GapTerms(0.0, 0.0);
    }
//@END CLUSTERS
    var c: real = p.mu / d;
    var g: real = 0.0;
//@BEGIN REPULSION
    let inv_s = 1.0 / (d + eps2);
    let ratio = (dstar[index] + eps2) * inv_s;
    g = power(ratio, p.gamma);
    c = c + h * gamma_of(p.gamma) * g * inv_s;
//@END REPULSION
    return GapTerms(c, g);
}

// `euler_step`: one step h from time t, reading set `src` and writing set `dst`. Returns
// whether the result is admissible (every free gap finite and above MIN_GAP_RATIO of its old
// value).
fn euler(b: u32, src: u32, dst: u32, h: real, t: real, p: Param) -> bool {
    let batch = config.batch;
    let n = config.particles;
    let eps = config.eps;
    let mass = 2.0 * eps;
    let eps2 = 2.0 * eps;
    let m_over_h = mass / h;
    let rows = (n - 1u) * batch;
    // Offsets of the two sets in the gap and velocity buffers.
    let gi = src * n * batch;
    let go = dst * n * batch;
    let vi = src * rows;
    let vo = dst * rows;

    // Row 0 is the wall: u_0 = 0, so y_0 = 0; lambda_prev = 1 (infinite pivot excess).
    let first = gap_terms(b, gap_sets[gi + b], p, h, eps2);
    var c_prev: real = first.c;
    var g_prev: real = first.g;
    var y_prev: real = 0.0;
    var lambda_prev: real = 1.0;
    var q: real = 0.0;
//@BEGIN CLUSTERS
    // Cluster-aware sweep: a row merged into the next carries its excess and right-hand side.
    var excess_carry: real = 0.0;
    var delta_carry: real = 0.0;
    var pinned = true;
//@END CLUSTERS

    for (var i: u32 = 1u; i < n; i++) {
        let row = (i - 1u) * batch + b;
        let next_gap = i * batch + b;
        let next = gap_terms(next_gap, gap_sets[gi + next_gap], p, h, eps2);
        var f: real = 0.0;
//@BEGIN FORCING
        q = q + gap_sets[gi + row] + mass;
        f = particle_force(eps, t, q);
//@END FORCING
        let rhs = m_over_h * vel_sets[vi + row] + g_prev - next.g + f;
//@BEGIN FREE
        let excess = m_over_h + c_prev * lambda_prev;
        let delta = rhs + c_prev * y_prev;
        let inv = 1.0 / (excess + next.c);
        let w = next.c * inv;
        let lambda = excess * inv;
        let y = delta * inv;
//@END FREE
//@BEGIN CLUSTERS
        var excess: real;
        var delta: real;
        if bonded[row] != 0u {
            // Gap i bonded (c_i = 0): row i-1 was merged into this row.
            excess = m_over_h + excess_carry;
            delta = rhs + delta_carry;
        } else {
            pinned = false;
            excess = m_over_h + c_prev * lambda_prev;
            delta = rhs + c_prev * y_prev;
        }
        var w: real;
        var lambda: real;
        var y: real;
        if bonded[next_gap] != 0u {
            excess_carry = excess;
            delta_carry = delta;
            w = 1.0;
            lambda = 0.0;
            y = 0.0;
        } else if pinned {
            w = 0.0;
            lambda = 1.0;
            y = 0.0;
        } else {
            let inv = 1.0 / (excess + next.c);
            w = next.c * inv;
            lambda = excess * inv;
            y = delta * inv;
        }
//@END CLUSTERS
        scratch[row] = w;
        scratch[rows + row] = lambda;
        scratch[2u * rows + row] = y;
        lambda_prev = lambda;
        y_prev = y;
        c_prev = next.c;
        g_prev = next.g;
    }

    // Back sweep from the right wall (u_N = 0), updating gap i+1 with u_{i+1} - u_i.
    var ok = true;
    var u_next: real = 0.0;
    for (var i: u32 = n - 1u; i >= 1u; i--) {
        let row = (i - 1u) * batch + b;
        let gap = i * batch + b;
        let w = scratch[row];
        let lambda = scratch[rows + row];
        let y = scratch[2u * rows + row];
        let u = y + w * u_next;
        // u_{i+1} - u_i without cancelling two large velocities.
        let relative = lambda * u_next - y;
        // The old gap is loaded once (the store below may alias it for the compiler).
        let old = gap_sets[gi + gap];
        let d = old + h * relative;
        vel_sets[vo + row] = u;
        gap_sets[go + gap] = d;
        ok = ok && (!is_free(gap) || gap_step_admissible(old, d));
        u_next = u;
    }
    let old0 = gap_sets[gi + b];
    let d0 = old0 + h * u_next;
    gap_sets[go + b] = d0;
    ok = ok && (!is_free(b) || gap_step_admissible(old0, d0));
    return ok;
}

// Block::error_norm: scaled max-norm of (two half steps - one full step), relative on free gaps,
// mixed absolute/relative on velocities; a NaN counts as REAL_MAX (the CPU's infinity: both
// reject with the largest shrink).
fn error_norm(b: u32, two_halves: u32, full: u32) -> real {
    let batch = config.batch;
    let n = config.particles;
    let rows = (n - 1u) * batch;
    let tol = config.tolerance;
    var err: real = 0.0;
    for (var i: u32 = 0u; i < n; i++) {
        let k = i * batch + b;
        let a = gap_sets[two_halves * n * batch + k];
        let e = abs(a - gap_sets[full * n * batch + k]) / (tol * abs(a));
        // Bonded gaps (0/0) do not count; no `continue`, so the loop stays uniform.
        err = select(err, select(REAL_MAX, max(err, e), e <= REAL_MAX), is_free(k));
    }
    for (var i: u32 = 0u; i + 1u < n; i++) {
        let k = i * batch + b;
        let a = vel_sets[two_halves * rows + k];
        let e = abs(a - vel_sets[full * rows + k]) / (tol * (1.0 + abs(a)));
        err = select(REAL_MAX, max(err, e), e <= REAL_MAX);
    }
    return err;
}

// Block::extrapolate: cand <- 2 cand - full; free gaps must stay admissible against the state
// `cur` the step started from, velocities finite.
fn extrapolate(b: u32, cand: u32, full: u32, cur: u32, ok_in: bool) -> bool {
    let batch = config.batch;
    let n = config.particles;
    let rows = (n - 1u) * batch;
    var ok = ok_in;
    for (var i: u32 = 0u; i < n; i++) {
        let k = i * batch + b;
        let a = 2.0 * gap_sets[cand * n * batch + k] - gap_sets[full * n * batch + k];
        gap_sets[cand * n * batch + k] = a;
        ok = ok && (!is_free(k) || gap_step_admissible(gap_sets[cur * n * batch + k], a));
    }
    for (var i: u32 = 0u; i + 1u < n; i++) {
        let k = i * batch + b;
        let a = 2.0 * vel_sets[cand * rows + k] - vel_sets[full * rows + k];
        vel_sets[cand * rows + k] = a;
        ok = ok && abs(a) <= REAL_MAX;
    }
    return ok;
}

// StepControl::trial_step: dt, or exactly what is left when that is within rounding of dt.
fn trial_step(c: Control) -> real {
    let remaining = config.t_end - c.t;
    if remaining <= c.dt * (1.0 + 1e-9) {
        return remaining;
    }
    return c.dt;
}

// StepControl::conclude_attempt. Returns whether the step is accepted.
fn conclude_attempt(c: ptr<function, Control>, h: real, admissible: bool, err: real) -> bool {
    if admissible && err <= 1.0 {
        (*c).accepted += 1u;
        let landed = h == config.t_end - (*c).t;
        (*c).regular_steps += 1u;
        if landed {
            (*c).t = config.t_end;
        } else if config.fixed_h > 0.0 && (*c).regular == 1u {
            (*c).t = config.t_start + real((*c).regular_steps) * config.fixed_h;
        } else {
            (*c).t = (*c).t + h;
        }
        if config.fixed_h > 0.0 {
            (*c).dt = min(2.0 * (*c).dt, config.fixed_h);
        } else {
            let factor = clamp(SAFETY / sqrt(max(err, 1e-10)), MAX_SHRINK, MAX_GROWTH);
            // A step shortened to land on an output time says little about dt.
            if landed {
                (*c).dt = max((*c).dt, h * factor);
            } else {
                (*c).dt = h * factor;
            }
        }
        return true;
    }
    (*c).rejected += 1u;
    (*c).regular = 0u;
    if admissible {
        (*c).dt = h * clamp(SAFETY / sqrt(err), MAX_SHRINK, 1.0);
    } else {
        (*c).dt = h * REJECT_SHRINK;
    }
    if (*c).dt < config.dt_min {
        // Failure::Inadmissible = 1, Failure::ErrorTooLarge = 2.
        (*c).failure = select(1u, 2u, admissible);
        (*c).failure_time = (*c).t;
    }
    return false;
}

fn is_running(c: Control) -> bool {
    return c.failure == 0u && c.t < config.t_end;
}

@compute @workgroup_size(64)
fn begin_interval(@builtin(global_invocation_id) gid: vec3<u32>) {
    let b = gid.x;
    if b >= config.batch {
        return;
    }
    var c = controls[b];
    if c.failure != 0u {
        return;
    }
    c.regular_steps = 0u;
    c.regular = 1u;
    if config.fixed_h > 0.0 {
        c.dt = config.fixed_h;
    }
    controls[b] = c;
}

@compute @workgroup_size(64)
fn advance(@builtin(global_invocation_id) gid: vec3<u32>) {
    let b = gid.x;
    if b >= config.batch {
        return;
    }
    var c = controls[b];
    let p = params[b];
    // A loop of fixed trip count with the attempt inside an `if`: members finish after different
    // numbers of attempts, and the loop stays uniform across the workgroup.
    for (var attempt: u32 = 0u; attempt < config.max_attempts; attempt++) {
        if is_running(c) {
            let h = trial_step(c);
            let cur = c.parity;
            let cand = 1u - cur;
            var ok: bool;
            var err: real = 0.0;
//@BEGIN EULER
            ok = euler(b, cur, cand, h, c.t, p);
//@END EULER
//@BEGIN RICHARDSON
            let ok_full = euler(b, cur, FULL_SET, h, c.t, p);
            let half = 0.5 * h;
            let ok_half = euler(b, cur, HALF_SET, half, c.t, p);
            let ok_two = euler(b, HALF_SET, cand, half, c.t + half, p);
            ok = ok_full && ok_half && ok_two;
//@END RICHARDSON
//@BEGIN ADAPTIVE
            err = error_norm(b, cand, FULL_SET);
//@END ADAPTIVE
//@BEGIN ORDER2
            ok = extrapolate(b, cand, FULL_SET, cur, ok);
//@END ORDER2
            if conclude_attempt(&c, h, ok, err) {
                c.parity = cand;
            }
        }
    }
    controls[b] = c;
    if is_running(c) {
        atomicAdd(&running, 1u);
    }
}

// Copies each member's current state (set `parity`) to the read-back buffers.
@compute @workgroup_size(64)
fn gather(@builtin(global_invocation_id) gid: vec3<u32>) {
    let b = gid.x;
    let batch = config.batch;
    if b >= batch {
        return;
    }
    let n = config.particles;
    let current = controls[b].parity;
    for (var i: u32 = 0u; i < n; i++) {
        gathered_gaps[i * batch + b] = gap_sets[current * n * batch + i * batch + b];
    }
    for (var i: u32 = 0u; i + 1u < n; i++) {
        gathered_vel[i * batch + b] = vel_sets[current * (n - 1u) * batch + i * batch + b];
    }
}
