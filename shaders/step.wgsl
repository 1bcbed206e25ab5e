// The batch advanced on the GPU, one invocation per member (member b's element i at
// `i * batch + b`), each member with its own time, step size and status. WGSL twin of
// kernels/src/step.rs (`euler`: the linearly implicit Euler step fused with the Thomas
// solve, the gap update exact in ln d, the projection onto sum d and the energy; read its header
// for the equations), of the attempts in src/backend/cpu/block.rs and of `extrapolate` in
// kernels/src/tableau.rs; the step control (`StepControl`, `step_factor`, `select_order` of
// kernels/src/shared/control.rs) is in shaders/control.wgsl, appended at generation. Keep them
// in sync, loop for loop.
// Gaps are stored as in `crate::model::chain::stored_gap`: d, or ln d (< 0) below GAP_FLOOR, or 0
// when bonded.
//
// Over 700 lines on purpose: WGSL has no modules (one source string per pipeline), and the
// kernel is generated from this one template (one pass over its marker blocks); its functions
// follow kernels/src/step.rs and src/backend/cpu/block.rs in the same order, to be read side
// by side. The f64 math it shares with partitioned.wgsl is in f64_math.wgsl,
// prepended at generation.
//
// Entry points: `begin_interval` (StepControl::begin_interval), `advance` (up to
// config.max_attempts trial steps per member per dispatch, as the lane loop of Block::advance:
// one Euler step for order 1 with fixed steps, else rows 1..=k of the extrapolation tableau
// (row j: n_j substeps of h/n_j, `row_substeps`), the extrapolation and its error estimates,
// then accept or reject and, for auto, the next order), `gather` (copies each member's
// current state into the output buffers for read-back at output times).
// A member's state lives in one of two buffer sets (its `parity`); the candidate goes to the
// other set and an accepted step only flips the parity, so nothing is copied.
//
// This file is a TEMPLATE, filled by `generate_step_wgsl` (src/backend/gpu/kernel.rs), line by line:
//  - the line declaring the alias `real` is replaced by the element type (f32 or f64);
//  - blocks between the marker lines BEGIN NAME and END NAME (comment lines starting with
//    slash-slash-at) are kept or removed: REPULSION, CLUSTERS, FREE (= no clusters), FORCING,
//    EULER (order 1, fixed steps), TABLEAU (else), ADAPTIVE, AUTO (order "auto"), FIXEDORDER
//    (adaptive with a fixed order);
//    terms the plan leaves out are not compiled at all;
//  - the marker line GENERATED is replaced by the generated code: REAL_MAX, GAP_FLOOR,
//    LN_GAP_FLOOR, ENERGY_RTOL, TIME_RESOLUTION, LN_RATIO_SERIES, ONE_DIVISION_RECIPROCALS (f64: see
//    `gap_reciprocals`), EXTRAPOLATES (order >= 2: the result is the
//    tableau's T_kk, else row k), EXACT_JACOBIAN (`Plan::exact_jacobian`), `exp_real`, `ln_real`, `power(r, gamma)`
//    (integer gamma: a fixed square-and-multiply chain, the sequence of `powi_by_squaring`;
//    per-member gamma: the same chain when gamma is an integer <= 1000 as `Power::of` does, else
//    exp/pow), `gamma_of(gamma)`, the forcing function `forcing(x, t)` and the unrolled
//    Gauss–Legendre sum `particle_force(eps, t, q)`; the f64 math library is prepended when the
//    generated code calls it.
//
// Bindings (group 0): 0 config (uniform), 1 gap sets, 2 velocity sets, 3 member parameters,
// 4 controls, 5 scratch (w | ls | ys | force | k, each (N-1)·batch), 6 running counter (atomic),
// 7 gathered gaps, 8 dstar (repulsion only), 9 bonded (u32, clusters only), 10 gathered velocities.
// The partitioned kernel (shaders/partitioned.wgsl, few members with huge N) is appended to this
// file and calls its functions (gap_terms, potential, extrapolate_gap, conclude_attempt, ...):
// keep their signatures in step with it.
// The host uploads and reads back Config, Param and Control (src/backend/gpu/wgsl_types.rs and
// src/backend/gpu/buffers.rs): keep their layouts in sync.

alias real = f64;

// Keep in sync with `ConfigF64` / `ConfigF32` in src/backend/gpu/wgsl_types.rs (`top_column`
// keeps the reals 8-aligned for f64).
struct Config {
    batch: u32,
    particles: u32,
    max_attempts: u32,
    // Auto's highest column (`Plan::top_column`).
    top_column: u32,
    eps: real,
    t_start: real,
    t_end: real,
    // > 0: fixed steps of this size (Rules::fixed_h); 0: adaptive steps.
    fixed_h: real,
    dt_min: real,
    tolerance: real,
}

// Uploaded as triples of reals (mu, gamma, total_gap) per member by src/backend/gpu/buffers.rs.
struct Param {
    mu: real,
    // Used only with a per-member gamma (GammaSpec::PerMember).
    gamma: real,
    // sum d_i of the member's initial chain, kept by every step's projection.
    total_gap: real,
}

// StepControl of kernels/src/shared/control.rs (counters in u32, flags as u32). Keep in sync with
// `ControlF64` / `ControlF32` in src/backend/gpu/wgsl_types.rs.
struct Control {
    t: real,
    dt: real,
    failure_time: real,
    failure_detail: real,
    // Discrete energy of the current state (< 0: not computed yet).
    energy: real,
    // Sum of the accepted steps' local error estimates.
    error_sum: real,
    // The last accepted step and its scaled estimate (`StepControl::h_previous`; 0: none).
    h_previous: real,
    err_previous: real,
    // What the rounding of t left out (`StepControl::t_low`): the time is t + t_low.
    t_low: real,
    // The time at the start of the current window of STALL_WINDOW attempts
    // (`StepControl::window_t`).
    window_t: real,
    accepted: u32,
    rejected: u32,
    regular_steps: u32,
    regular: u32,
    failure: u32,
    parity: u32,
    failure_index: u32,
    // The tableau column (order) of the next step.
    order: u32,
    // 1: the last attempt was rejected (`StepControl::after_rejection`).
    after_rejection: u32,
    // The attempts in the current window (`StepControl::window_attempts`).
    window_attempts: u32,
}

// (a, G, effective d) of one gap (`gap_terms`).
struct GapTerms {
    a: real,
    g: real,
    d: real,
    inv_d: real,
}

// `StepReport` of kernels/src/step.rs; `hard` is the Failure code of a hard failure (0: none).
struct StepReport {
    admissible: bool,
    hard: u32,
    hard_index: u32,
    hard_detail: real,
    energy: real,
    work: real,
}

// What `try_step` found out (the `Outcome` and hard failure per lane of Block's attempts).
struct Attempt {
    admissible: bool,
    energy_ok: bool,
    err: real,
    factor: real,
    order_next: u32,
    estimate: real,
    hard: u32,
    hard_index: u32,
    hard_detail: real,
    energy: real,
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

// Buffer sets: 0 and 1 hold a member's state and candidate (by parity); 2 and 3 the states
// between a tableau row's substeps; from 4 the rows' results (row j in set ROW_SET + j - 1).
const SUB_SET: u32 = 2u;
const ROW_SET: u32 = 4u;
// `MAX_ORDER` of kernels/src/shared/control.rs: the tableau's largest column. Its rows (array<real, 8>)
// and their estimates by column (array<real, 9>, index 0..=MAX_ORDER) are sized with literals
// here, in shaders/control.wgsl and in shaders/partitioned.wgsl: change them with it.
const MAX_ORDER: u32 = 8u;

// `row_substeps` of kernels/src/shared/control.rs: Euler substeps n_j of tableau row j
// (1-based), j + 1 where SEQUENCE_FROM_TWO (`sequence_from_two`: `[solver] sequence =
// "from_2"` and an extrapolated scheme).
fn row_substeps(j: u32) -> u32 {
    return select(j, j + 1u, SEQUENCE_FROM_TWO);
}

// GAP_EXP_TAYLOR, EXP_FAST_MAX of kernels/src/shared/gaps.rs.
const GAP_EXP_TAYLOR: real = 0.0625;
const EXP_FAST_MAX: real = 700.0;

// MAX_OPENING and NEGLIGIBLE_OPENING of kernels/src/shared/gaps.rs.
const MAX_OPENING: real = 5.0;
const NEGLIGIBLE_OPENING: real = 1e-12;

//@GENERATED

// Whether a gap is free (not bonded inside a cluster).
fn is_free(index: u32) -> bool {
//@BEGIN CLUSTERS
    return bonded[index] == 0u;
//@END CLUSTERS
//@BEGIN FREE
    return true;
//@END FREE
}

// `stored_gap::ln`: ln d of a stored free gap.
fn stored_ln(v: real) -> real {
    if v > 0.0 {
        return ln_real(v);
    }
    return v;
}

// `stored_gap::decode`: the gap a stored value stands for.
fn stored_decode(v: real) -> real {
    if v > 0.0 {
        return v;
    }
    if v < 0.0 {
        return exp_real(v);
    }
    return 0.0;
}

// `gap_exp`: e^x for the gap update; the Taylor polynomial to x^8 below |x| = 1/16, else exp.
fn gap_exp(x: real) -> real {
    if abs(x) < GAP_EXP_TAYLOR {
        return 1.0 + x * (1.0 + x * (0.5 + x * (0.16666666666666666 + x * (0.041666666666666664
            + x * (0.008333333333333333 + x * (0.001388888888888889 + x * (0.0001984126984126984
            + x * 0.000024801587301587302)))))));
    }
    return exp_real(clamp(x, -EXP_FAST_MAX, EXP_FAST_MAX));
}

// `encode_ln_gap`: the stored value of a gap given its logarithm.
fn encode_ln_gap(s: real) -> real {
    if s > LN_GAP_FLOOR {
        return exp_real(s);
    }
    return s;
}

// gamma of a member (1 without repulsion: no G to round).
fn gamma_of_member(p: Param) -> real {
//@BEGIN REPULSION
    return gamma_of(p.gamma);
//@END REPULSION
//@BEGIN NOREPULSION
    return 1.0;
//@END NOREPULSION
}

// `reciprocal_scale` of kernels/src/step.rs: 1/eps2, at most 1/GAP_FLOOR.
fn reciprocal_scale(eps2: real) -> real {
    return min(1.0 / eps2, 1.0 / GAP_FLOOR);
}

struct Reciprocals {
    inv_d: real,
    inv_s: real,
}

// `gap_reciprocals`: 1/d and 1/(d + eps2), in f64 from one division (`scale` =
// reciprocal_scale(eps2); ONE_DIVISION_RECIPROCALS: f64); without repulsion 1/d alone.
fn gap_reciprocals(d: real, eps2: real, scale: real) -> Reciprocals {
//@BEGIN REPULSION
    if ONE_DIVISION_RECIPROCALS {
        let s_scaled = (d + eps2) * scale;
        let inv_product = 1.0 / (d * s_scaled);
        return Reciprocals(s_scaled * inv_product, d * scale * inv_product);
    }
    return Reciprocals(1.0 / d, 1.0 / (d + eps2));
//@END REPULSION
//@BEGIN NOREPULSION
    return Reciprocals(1.0 / d, 0.0);
//@END NOREPULSION
}

// `gap_terms`: a = mu + h gamma G d/(d + 2eps), G, d and 1/d of one gap, at the effective gap d.
fn gap_terms(index: u32, stored: real, p: Param, h: real, eps2: real, scale: real) -> GapTerms {
    let d = max(stored, GAP_FLOOR);
    let inv = gap_reciprocals(d, eps2, scale);
//@BEGIN CLUSTERS
    if bonded[index] != 0u {
        return GapTerms(p.mu, 0.0, d, inv.inv_d);
    }
//@END CLUSTERS
    var a: real = p.mu;
    var g: real = 0.0;
//@BEGIN REPULSION
    let ratio = (dstar[index] + eps2) * inv.inv_s;
    g = power(ratio, p.gamma);
    a = a + h * gamma_of(p.gamma) * g * d * inv.inv_s;
//@END REPULSION
    return GapTerms(a, g, d, inv.inv_d);
}

// `jacobian_factor`: k = 1/(1 + x) where the gap opens (x >= 0) and 1 - x/(1 + x + 16 x^4)
// where it closes (1/(1 + x) to O(x^5), bounded, back to 1 for fast closing), x = h (u_right -
// u_left)/d, where the plan keeps the exact Jacobian (EXACT_JACOBIAN: the CPU's
// `Terms::exact_jacobian`, `Plan::exact_jacobian`) and the gap is stored as d (above GAP_FLOOR),
// else 1. The CPU twin in kernels/src/step.rs says why this form and this switch.
fn jacobian_factor(d: real, inv_d: real, h: real, u_left: real, u_right: real) -> real {
    if EXACT_JACOBIAN && d > GAP_FLOOR {
        let x = h * (u_right - u_left) * inv_d;
        // One division for both branches, as the CPU's lane loop: q = 1/(1 + x + [x < 0] 16 x^4),
        // [x < 0] x^4 as min(x, 0)^4 (the CPU's form, where a select became two divisions).
        let closing_x = min(x, 0.0);
        let closing = 16.0 * ((closing_x * closing_x) * (closing_x * closing_x));
        let q = 1.0 / (1.0 + x + closing);
        if x < 0.0 {
            return 1.0 - x * q;
        }
        return q;
    }
    return 1.0;
}

// The velocity of element `index` of the set at `vi`, 0 beyond the last particle (the right
// wall).
fn velocity_or_wall(vi: u32, index: u32, b: u32) -> real {
    if index + 1u < config.particles {
        return vel_sets[vi + index * config.batch + b];
    }
    return 0.0;
}

// `potential`: Phi(d) of one free gap.
fn potential(index: u32, d: real, p: Param, eps2: real) -> real {
//@BEGIN REPULSION
    let s = d + eps2;
    let s_star = dstar[index] + eps2;
    let g = gamma_of(p.gamma);
    if g == 1.0 {
        return -s_star * ln_real(s);
    }
    return s * power(s_star / s, p.gamma) / (g - 1.0);
//@END REPULSION
//@BEGIN NOREPULSION
    return 0.0;
//@END NOREPULSION
}

fn is_finite_real(x: real) -> bool {
    return abs(x) <= REAL_MAX;
}

// `euler_step`: one step h from time t, reading set `src` and writing set `dst`.
fn euler(b: u32, src: u32, dst: u32, h: real, t: real, p: Param) -> StepReport {
    let batch = config.batch;
    let n = config.particles;
    let eps = config.eps;
    let mass = 2.0 * eps;
    let eps2 = 2.0 * eps;
    let scale = reciprocal_scale(eps2);
    let m_over_h = mass / h;
    let rows = (n - 1u) * batch;
    // Offsets of the two sets in the gap and velocity buffers.
    let gi = src * n * batch;
    let go = dst * n * batch;
    let vi = src * rows;
    let vo = dst * rows;
    var report = StepReport(true, 0u, 0u, 0.0, 0.0, 0.0);

    // Forward sweep. The wall (u_0 = 0) has an infinite pivot: ls_0 = 1/d_1, ys_0 = 0.
    let first = gap_terms(b, gap_sets[gi + b], p, h, eps2, scale);
    // The first gap's k (the wall's side does not move); the others' go to the scratch.
    let k_first = jacobian_factor(first.d, first.inv_d, h, 0.0, velocity_or_wall(vi, 0u, b));
    var a_prev: real = first.a * k_first;
    var g_prev: real = first.g;
    var ls_prev: real = first.inv_d;
    var ys_prev: real = 0.0;
    var q: real = 0.0;
//@BEGIN REPULSION
    if !is_finite_real(first.g) {
        report.hard = 5u;
        report.hard_index = 1u;
        report.hard_detail = (dstar[b] + eps2) / (first.d + eps2);
    }
//@END REPULSION

    for (var i: u32 = 1u; i < n; i++) {
        let row = (i - 1u) * batch + b;
        let next_gap = i * batch + b;
        let next = gap_terms(next_gap, gap_sets[gi + next_gap], p, h, eps2, scale);
        var f: real = 0.0;
//@BEGIN FORCING
        forcing_member = b;
        q = q + stored_decode(gap_sets[gi + row]) + mass;
        f = particle_force(eps, t, q);
        scratch[3u * rows + row] = f;
        if !is_finite_real(f) && report.hard == 0u {
            report.hard = 4u;
            report.hard_index = i;
            report.hard_detail = q;
        }
//@END FORCING
//@BEGIN REPULSION
        if !is_finite_real(next.g) && report.hard == 0u {
            report.hard = 5u;
            report.hard_index = i + 1u;
            report.hard_detail = (dstar[next_gap] + eps2) / (next.d + eps2);
        }
//@END REPULSION
        let vel = vel_sets[vi + row];
        let k = jacobian_factor(next.d, next.inv_d, h, vel, velocity_or_wall(vi, i, b));
        let a_next = next.a * k;
        let rhs = m_over_h * vel + g_prev - next.g + f;
        // The pivot excess·d + a grouped as in the CPU twin (one multiply-add on the chain).
        let excess = m_over_h + a_prev * ls_prev;
        let delta = rhs + a_prev * ys_prev;
        let pivot_base = m_over_h * next.d + a_next;
        let coupling = a_prev * next.d;
        let inv = 1.0 / (pivot_base + coupling * ls_prev);
        let ls = excess * inv;
        let ys = delta * inv;
        scratch[row] = a_next * inv;
        scratch[rows + row] = ls;
        scratch[2u * rows + row] = ys;
        scratch[4u * rows + row] = k;
        ls_prev = ls;
        ys_prev = ys;
        a_prev = a_next;
        g_prev = next.g;
    }

    // Back sweep from the right wall (u_N = 0): velocities, the rate k r of gap i+1 (left in the
    // ls slot for the fix-up) and its update ln d' = ln d + h k r.
    var needs_fixup = false;
    // The largest h r of a gap whose new value is not negligible (the MAX_OPENING safeguard;
    // NEGLIGIBLE_OPENING in kernels/src/shared/gaps.rs). The CPU keeps the opening of every gap
    // stored as d too, for its energy certificate, which this kernel does not take.
    var overshoot: real = 0.0;
    let negligible = NEGLIGIBLE_OPENING * p.total_gap;
    var sum: real = 0.0;
    var u_next: real = 0.0;
    for (var i: u32 = n - 1u; i >= 1u; i--) {
        let row = (i - 1u) * batch + b;
        let gap = i * batch + b;
        // The old gap is loaded once (the store below may alias it for the compiler).
        let old = gap_sets[gi + gap];
        let d = max(old, GAP_FLOOR);
        var u = d * scratch[2u * rows + row] + scratch[row] * u_next;
//@BEGIN CLUSTERS
        if bonded[gap] != 0u {
            // Exactly the velocity of the body it is bonded to.
            u = u_next;
        }
//@END CLUSTERS
        let rate = (scratch[rows + row] * u_next - scratch[2u * rows + row]) * scratch[4u * rows + row];
        let x = h * rate;
        let grown = old * gap_exp(x);
        vel_sets[vo + row] = u;
        gap_sets[go + gap] = grown;
        scratch[rows + row] = rate;
        sum = sum + max(grown, 0.0);
        if grown > negligible {
            overshoot = max(overshoot, x);
        }
        needs_fixup = needs_fixup || !(grown >= GAP_FLOOR && grown <= REAL_MAX && x <= EXP_FAST_MAX);
        u_next = u;
    }
//@BEGIN CLUSTERS
    // Bodies glued to the left wall do not move, exactly.
    for (var i: u32 = 0u; i + 1u < n; i++) {
        if bonded[i * batch + b] == 0u {
            break;
        }
        vel_sets[vo + i * batch + b] = 0.0;
    }
//@END CLUSTERS
    let old0 = gap_sets[gi + b];
    let rate_first = u_next / max(old0, GAP_FLOOR) * k_first;
    let x0 = h * rate_first;
    let grown0 = old0 * gap_exp(x0);
    gap_sets[go + b] = grown0;
    sum = sum + max(grown0, 0.0);
    if grown0 > negligible {
        overshoot = max(overshoot, x0);
    }
    needs_fixup = needs_fixup || !(grown0 >= GAP_FLOOR && grown0 <= REAL_MAX && x0 <= EXP_FAST_MAX);

    if needs_fixup {
        fix_up(b, src, dst, h, rate_first);
        sum = lane_sum(b, dst);
    }
    report.admissible = report.admissible && overshoot <= MAX_OPENING;
    // The energy is always computed here; the CPU skips it for steps its certificate
    // (`energy_certified`) proves acceptable, which the computed energy then passes too, and
    // for a tableau's substeps inside a row, whose energy is not checked (`EnergyWanted::No`).
    report = conclude(b, dst, p, report, sum, h, true);
    return report;
}

// `fix_up_lane`: redoes the update in log form where d e^{hr} does not apply.
fn fix_up(b: u32, src: u32, dst: u32, h: real, rate_first: real) {
    let batch = config.batch;
    let n = config.particles;
    let rows = (n - 1u) * batch;
    for (var i: u32 = 0u; i < n; i++) {
        let k = i * batch + b;
        if !is_free(k) {
            gap_sets[dst * n * batch + k] = 0.0;
            continue;
        }
        var rate = rate_first;
        if i > 0u {
            rate = scratch[rows + (i - 1u) * batch + b];
        }
        let x = h * rate;
        let grown = gap_sets[dst * n * batch + k];
        let old = gap_sets[src * n * batch + k];
        if grown >= GAP_FLOOR && grown <= REAL_MAX && x <= EXP_FAST_MAX && old > 0.0 {
            continue;
        }
        gap_sets[dst * n * batch + k] = encode_ln_gap(stored_ln(old) + x);
    }
}

// `lane_sum`: the sum of the member's gaps in set `which`, from the last gap down (the back
// sweep's order).
fn lane_sum(b: u32, which: u32) -> real {
    let batch = config.batch;
    let n = config.particles;
    var sum: real = 0.0;
    for (var i: u32 = n; i >= 1u; i--) {
        sum = sum + max(gap_sets[which * n * batch + (i - 1u) * batch + b], 0.0);
    }
    return sum;
}

// `conclude_impl`: the projection onto sum d = total_gap (`sum` is the gaps' sum), the energy of
// set `which` and, with `forced`, the work h sum u F.
fn conclude(b: u32, which: u32, p: Param, report_in: StepReport, sum: real, h: real, forced: bool) -> StepReport {
    let batch = config.batch;
    let n = config.particles;
    let eps2 = 2.0 * config.eps;
    let rows = (n - 1u) * batch;
    let base = which * n * batch;
    var report = report_in;
    let scale = p.total_gap / sum;
    var potential_sum: real = 0.0;
    var kinetic: real = 0.0;
    var work: real = 0.0;
    var logged = false;
    for (var i: u32 = 0u; i < n; i++) {
        let k = i * batch + b;
        let v = gap_sets[base + k];
        let scaled = v * scale;
        logged = logged || v < 0.0;
        report.admissible = report.admissible && is_finite_real(v);
        if v > 0.0 {
            gap_sets[base + k] = scaled;
        }
        let phi = potential(k, max(scaled, 0.0), p, eps2);
        if is_free(k) {
            potential_sum = potential_sum + phi;
        }
        if i + 1u < n {
            let u = vel_sets[which * rows + k];
            kinetic = kinetic + u * u;
//@BEGIN FORCING
            if forced {
                work = work + u * scratch[3u * rows + k];
            }
//@END FORCING
        }
    }
    if logged {
        // `shift_logged`: log-stored gaps shifted by ln(scale).
        let shift = ln_real(scale);
        for (var i: u32 = 0u; i < n; i++) {
            let k = base + i * batch + b;
            if gap_sets[k] < 0.0 {
                gap_sets[k] = gap_sets[k] + shift;
            }
        }
    }
    report.energy = potential_sum + config.eps * kinetic;
    report.work = h * work;
    report.admissible = report.admissible && is_finite_real(report.energy);
    return report;
}

// `state_energy`: E = eps sum u^2 + sum Phi of set `which` (the same sums, in the same order, as
// `conclude`).
fn state_energy(b: u32, which: u32, p: Param) -> real {
    let batch = config.batch;
    let n = config.particles;
    let eps2 = 2.0 * config.eps;
    let rows = (n - 1u) * batch;
    var potential_sum: real = 0.0;
    var kinetic: real = 0.0;
    for (var i: u32 = 0u; i < n; i++) {
        let k = i * batch + b;
        let phi = potential(k, max(gap_sets[which * n * batch + k], 0.0), p, eps2);
        if is_free(k) {
            potential_sum = potential_sum + phi;
        }
        if i + 1u < n {
            let u = vel_sets[which * rows + k];
            kinetic = kinetic + u * u;
        }
    }
    return potential_sum + config.eps * kinetic;
}

// `ln_gap_ratio` of kernels/src/step.rs: ln(y / last) for two rows' values of a gap (> 0), by
// the series of ln(1 + delta), delta = (y - last)/last, near 1; `inv_last` = 1/last, one
// division per gap.
fn ln_gap_ratio(y: real, last: real, inv_last: real) -> real {
    let delta = (y - last) * inv_last;
    if abs(delta) < LN_RATIO_SERIES {
        // `ln_1p_series`: to delta^13/13 by Horner.
        var p: real = 1.0 / 13.0;
        p = -1.0 / 12.0 + delta * p;
        p = 1.0 / 11.0 + delta * p;
        p = -1.0 / 10.0 + delta * p;
        p = 1.0 / 9.0 + delta * p;
        p = -1.0 / 8.0 + delta * p;
        p = 1.0 / 7.0 + delta * p;
        p = -1.0 / 6.0 + delta * p;
        p = 1.0 / 5.0 + delta * p;
        p = -1.0 / 4.0 + delta * p;
        p = 1.0 / 3.0 + delta * p;
        p = -1.0 / 2.0 + delta * p;
        p = 1.0 + delta * p;
        return delta * p;
    }
    return ln_real(y / last);
}

// A max-norm entry: a NaN or infinity counts as REAL_MAX (the CPU's infinity: both reject with
// the largest shrink).
fn noted(err: real, e: real) -> real {
    return select(REAL_MAX, max(err, e), e <= REAL_MAX);
}

// `log_stored_allowance` of kernels/src/shared/gaps.rs: a log-stored gap's estimate e less the
// rounding of its ln d, LOG_STORED_ROUNDING eps |ln d| (0 below it; a NaN stays NaN).
fn log_stored_allowance(e: real, ln_d: real) -> real {
    let allowance = LOG_STORED_ROUNDING * REAL_EPSILON * abs(ln_d);
    if e <= allowance {
        return 0.0;
    }
    return e - allowance;
}

// `extrapolate` of kernels/src/tableau.rs: the Aitken–Neville tableau of rows 1..=k (set
// ROW_SET + j - 1), element by element, gaps in ln d (shifted by ln of row k), velocities
// linearly; set `cand` <- T_kk (or row k itself when not EXTRAPOLATES: order 1). Returns
// |T_jj - T_{j,j-1}| for j = 2..=k (gaps: of ln d; velocities: over 1 + |u| of row k).
fn extrapolate(b: u32, cand: u32, k: u32) -> array<real, 9> {
    let batch = config.batch;
    let n = config.particles;
    var err: array<real, 9>;
    for (var i: u32 = 0u; i < n; i++) {
        extrapolate_gap(i * batch + b, cand, k, &err);
    }
    for (var i: u32 = 0u; i + 1u < n; i++) {
        extrapolate_velocity(i * batch + b, cand, k, &err);
    }
    return err;
}

// Gap `idx` of `extrapolate` (also called by the partitioned kernel, shaders/partitioned.wgsl):
// writes it to set `cand` and notes its estimates in `err`.
fn extrapolate_gap(idx: u32, cand: u32, k: u32, err: ptr<function, array<real, 9>>) {
    let n = config.particles;
    let batch = config.batch;
    var y: array<real, 8>;
    for (var j: u32 = 0u; j < k; j++) {
        y[j] = gap_sets[(ROW_SET + j) * n * batch + idx];
    }
    let last = y[k - 1u];
    if !is_free(idx) {
        gap_sets[cand * n * batch + idx] = last;
        return;
    }
    var plain = true;
    for (var j: u32 = 0u; j < k; j++) {
        plain = plain && y[j] > 0.0;
    }
    var rho: array<real, 8>;
    let inv_last = 1.0 / last;
    for (var j: u32 = 0u; j < k; j++) {
        if plain {
            rho[j] = ln_gap_ratio(y[j], last, inv_last);
        } else {
            rho[j] = stored_ln(y[j]) - stored_ln(last);
        }
    }
    var e: array<real, 9>;
    // `neville`.
    for (var c: u32 = 1u; c < k; c++) {
        for (var j: u32 = k - 1u; j >= c; j--) {
            let delta = (rho[j] - rho[j - 1u]) * (real(row_substeps(j + 1u - c)) / real(c));
            if j == c {
                e[c + 1u] = abs(delta);
            }
            rho[j] = rho[j] + delta;
        }
    }
    if !plain {
        let ln_last = stored_ln(last);
        for (var j: u32 = 2u; j <= k; j++) {
            e[j] = log_stored_allowance(e[j], ln_last);
        }
    }
    var x: real = 0.0;
    if EXTRAPOLATES {
        x = rho[k - 1u];
    }
    let grown = last * gap_exp(x);
    if plain && grown >= GAP_FLOOR && grown <= REAL_MAX {
        gap_sets[cand * n * batch + idx] = grown;
    } else {
        gap_sets[cand * n * batch + idx] = encode_ln_gap(stored_ln(last) + x);
    }
    for (var j: u32 = 2u; j <= k; j++) {
        (*err)[j] = noted((*err)[j], e[j]);
    }
}

// Velocity `idx` of `extrapolate` (also called by the partitioned kernel).
fn extrapolate_velocity(idx: u32, cand: u32, k: u32, err: ptr<function, array<real, 9>>) {
    let rows = (config.particles - 1u) * config.batch;
    var t: array<real, 8>;
    for (var j: u32 = 0u; j < k; j++) {
        t[j] = vel_sets[(ROW_SET + j) * rows + idx];
    }
    let last = t[k - 1u];
    // Every column's estimate over the same 1 + |u| (row k's): one division per velocity.
    let inv_scale = 1.0 / (1.0 + abs(last));
    var e: array<real, 9>;
    for (var c: u32 = 1u; c < k; c++) {
        for (var j: u32 = k - 1u; j >= c; j--) {
            let delta = (t[j] - t[j - 1u]) * (real(row_substeps(j + 1u - c)) / real(c));
            if j == c {
                e[c + 1u] = abs(delta) * inv_scale;
            }
            t[j] = t[j] + delta;
        }
    }
    if EXTRAPOLATES {
        vel_sets[cand * rows + idx] = t[k - 1u];
    } else {
        vel_sets[cand * rows + idx] = last;
    }
    for (var j: u32 = 2u; j <= k; j++) {
        (*err)[j] = noted((*err)[j], e[j]);
    }
}

// Block::euler_attempt (EULER: order 1, fixed steps) or Block::extrapolated_attempt (TABLEAU):
// one trial step into set `cand`.
fn try_step(b: u32, cur: u32, cand: u32, h: real, c: Control, p: Param) -> Attempt {
    let gamma = gamma_of_member(p);
//@BEGIN EULER
    let r = euler(b, cur, cand, h, c.t, p);
    return Attempt(
        r.admissible,
        energy_acceptable(c.energy, r.energy, r.work, gamma),
        0.0,
        1.0,
        1u,
        0.0,
        r.hard,
        r.hard_index,
        r.hard_detail,
        r.energy
    );
//@END EULER
//@BEGIN TABLEAU
    let k = c.order;
    let rows = max(k, 2u);
    var admissible = true;
    var energy_ok = true;
    var hard = StepReport(true, 0u, 0u, 0.0, 0.0, 0.0);
    // Forcing work and the last substep's energy of each row.
    var row_work: array<real, 9>;
    var row_energy: array<real, 9>;
    for (var j: u32 = 1u; j <= rows; j++) {
        let substeps = row_substeps(j);
        let hj = h / real(substeps);
        // The row's end is held to the start's energy plus the row's work (not each substep:
        // `extrapolated_attempt`).
        for (var s: u32 = 0u; s < substeps; s++) {
            let ts = c.t + real(s) * hj;
            // Substep s reads buffer (s - 1) % 2 and writes s % 2; the first reads the state,
            // the last writes the row's set.
            var src = SUB_SET + (s + 1u) % 2u;
            if s == 0u {
                src = cur;
            }
            var dst = SUB_SET + s % 2u;
            if s + 1u == substeps {
                dst = ROW_SET + j - 1u;
            }
            let r = euler(b, src, dst, hj, ts, p);
            if j == 1u && s == 0u {
                hard = r;
            } else if r.hard != 0u {
                // Met in a substep's state: a smaller step may avoid it.
                admissible = false;
            }
            admissible = admissible && r.admissible;
            row_work[j] = row_work[j] + r.work;
            if s + 1u == substeps {
                energy_ok = energy_ok && energy_acceptable(c.energy, r.energy, row_work[j], gamma);
                row_energy[j] = r.energy;
            }
        }
    }
    let estimates = extrapolate(b, cand, rows);
    var energy = row_energy[rows];
    if EXTRAPOLATES {
        // The extrapolated state: projection and energy, which must not exceed the start's
        // plus the finest row's work, to the rounding that the tableau amplifies.
        let report = conclude(b, cand, p, StepReport(true, 0u, 0u, 0.0, 0.0, 0.0), lane_sum(b, cand), 1.0, false);
        admissible = admissible && report.admissible;
        energy_ok = energy_ok && extrapolated_energy_acceptable(c.energy, report.energy, row_work[rows], gamma, rows);
        energy = report.energy;
    }
    var err: real = 0.0;
    var factor: real = 1.0;
    var order_next = k;
//@BEGIN ADAPTIVE
    var scaled: array<real, 9>;
    for (var j: u32 = 0u; j < 9u; j++) {
        scaled[j] = estimates[j] / config.tolerance;
    }
    err = scaled[rows];
//@BEGIN AUTO
    let chosen = select_order(k, scaled, admissible && energy_ok && err <= 1.0, config.top_column);
    order_next = u32(chosen.x);
    factor = chosen.y;
//@END AUTO
//@BEGIN FIXEDORDER
    factor = step_factor(err, max(k, 2u));
//@END FIXEDORDER
//@END ADAPTIVE
    return Attempt(
        admissible,
        energy_ok,
        err,
        factor,
        order_next,
        estimates[rows],
        hard.hard,
        hard.hard_index,
        hard.hard_detail,
        energy
    );
//@END TABLEAU
}

// Index (1-based) and ln d of the member's smallest free gap in set `set` (`smallest_gap`).
fn smallest_gap(b: u32, which: u32) -> vec2<real> {
    let batch = config.batch;
    let n = config.particles;
    var best = vec2<real>(0.0, REAL_MAX);
    for (var i: u32 = 0u; i < n; i++) {
        let k = i * batch + b;
        if !is_free(k) {
            continue;
        }
        let s = stored_ln(gap_sets[which * n * batch + k]);
        if s < best.y {
            best = vec2<real>(real(i + 1u), s);
        }
    }
    return best;
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
    if c.energy < 0.0 {
        c.energy = state_energy(b, c.parity, params[b]);
    }
    c.regular_steps = 0u;
    c.regular = 1u;
    c.window_t = c.t;
    c.window_attempts = 0u;
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
            let r = try_step(b, cur, cand, h, c, p);
            if r.hard != 0u {
                // A failure no smaller step can cure (`StepControl::fail`).
                c.failure = r.hard;
                c.failure_time = c.t;
                c.failure_index = r.hard_index;
                c.failure_detail = r.hard_detail;
            } else if conclude_attempt(&c, h, r) {
                c.parity = cand;
                c.energy = r.energy;
            } else if c.failure != 0u {
                let smallest = smallest_gap(b, cur);
                c.failure_index = u32(smallest.x);
                c.failure_detail = smallest.y;
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
