// Step control on the GPU: WGSL twin of kernels/src/shared/control.rs (`StepControl`'s
// `trial_step` and `conclude_attempt`, `step_factor`, `predictive_factor`, `select_order`,
// `energy_acceptable`), function for function. Appended to the generated step kernel
// (`generate_step_wgsl` in src/backend/gpu/kernel.rs), whose `Config`, `Control`, `Attempt`
// and generated constants it reads. Keep them in sync.

// Step control constants of kernels/src/shared/control.rs.
const REJECT_SHRINK: real = 0.25;
const SAFETY: real = 0.9;
const MAX_GROWTH: real = 5.0;
const MAX_SHRINK: real = 0.2;

// STALL_WINDOW, STALL_PACE (fixed steps) and STALL_PACE_ADAPTIVE of
// kernels/src/shared/control.rs: a member whose last
// STALL_WINDOW attempts advanced it less than STALL_PACE of the time left an attempt fails.
const STALL_WINDOW: u32 = 100000u;
const STALL_PACE: real = 1e-12;
const STALL_PACE_ADAPTIVE: real = 1e-10;

// WORK_SLACK of kernels/src/shared/control.rs.
const WORK_SLACK: real = 0.1;

// `energy_acceptable` of kernels/src/shared/control.rs, with the rounding of G (about gamma ulps)
// added to the slack (ENERGY_RTOL_PER_GAMMA: 0 in f64, where ENERGY_RTOL covers it).
fn energy_acceptable(before: real, after: real, work: real, gamma: real) -> bool {
    return energy_within(before, after, work, ENERGY_RTOL + ENERGY_RTOL_PER_GAMMA * gamma);
}

// The test of `energy_acceptable` of kernels/src/shared/control.rs with the relative slack rtol.
fn energy_within(before: real, after: real, work: real, rtol: real) -> bool {
    return after <= before + work + rtol * abs(before) + WORK_SLACK * abs(work);
}

// `extrapolation_amplification` of kernels/src/shared/control.rs: sum of |c_j| over the weights
// c_j = prod_{m != j} n_j / (n_j - n_m) by which column k combines its rows.
fn extrapolation_amplification(k: u32) -> real {
    var sum: real = 0.0;
    for (var j = 1u; j <= k; j++) {
        let nj = real(row_substeps(j));
        var c: real = 1.0;
        for (var m = 1u; m <= k; m++) {
            if m != j {
                c *= nj / (nj - real(row_substeps(m)));
            }
        }
        sum += abs(c);
    }
    return sum;
}

// EXTRAPOLATED_ENERGY_SLACK_MAX of kernels/src/shared/control.rs.
const EXTRAPOLATED_ENERGY_SLACK_MAX: real = 1e-6;

// `energy_acceptable` for the extrapolated state of column k, with the slack of
// `extrapolated_energy_rtol` of kernels/src/shared/control.rs: the rows' rounding as the tableau
// amplifies it and E magnifies it (2 ulps per ulp of a velocity, gamma per ulp of a gap), at
// most EXTRAPOLATED_ENERGY_SLACK_MAX.
fn extrapolated_energy_acceptable(before: real, after: real, work: real, gamma: real, k: u32) -> bool {
    let amplified = (2.0 + gamma) * REAL_EPSILON * extrapolation_amplification(k);
    let rtol = ENERGY_RTOL + ENERGY_RTOL_PER_GAMMA * gamma + min(amplified, EXTRAPOLATED_ENERGY_SLACK_MAX);
    return energy_within(before, after, work, rtol);
}

// `step_factor` of kernels/src/shared/control.rs: SAFETY err^(-1/q) within [MAX_SHRINK, MAX_GROWTH].
fn step_factor(err_in: real, q: u32) -> real {
    return clamp(SAFETY / root_of(max(err_in, 1e-10), q), MAX_SHRINK, MAX_GROWTH);
}

// `root` of kernels/src/shared/control.rs: x^(1/q) (sqrt for q = 2).
fn root_of(x: real, q: u32) -> real {
    if q == 1u {
        return x;
    } else if q == 2u {
        return sqrt(x);
    }
    return exp_real(ln_real(x) / real(q));
}

// `predictive_factor` of kernels/src/shared/control.rs: the factor times the trend of the last
// two accepted steps where that is below 1 (Gustafsson), within [MAX_SHRINK, factor].
fn predictive_factor(factor: real, h: real, err: real, q: u32, h_previous: real, err_previous: real) -> real {
    if h_previous <= 0.0 {
        return factor;
    }
    let trend = h / h_previous * root_of(err_previous / max(err, 1e-10), q);
    if trend >= 1.0 {
        return factor;
    }
    return max(factor * trend, MAX_SHRINK);
}

// `tableau_work`: substeps of a step's first k rows (n_1 + ... + n_k, `row_substeps`).
fn tableau_work(k: u32) -> real {
    let from_one = k * (k + 1u) / 2u;
    return real(select(from_one, from_one + k, SEQUENCE_FROM_TWO));
}

// `select_order` of kernels/src/shared/control.rs: (next column, step factor) from the scaled
// estimates of columns 2..=k, raised only below `top` (`top_column`).
fn select_order(k: u32, errs: array<real, 9>, accepted: bool, top: u32) -> vec2<real> {
    var e = errs;
    var work_k = tableau_work(k) / step_factor(e[k], k);
    if k > 2u {
        let work_lower = tableau_work(k - 1u) / step_factor(e[k - 1u], k - 1u);
        if work_lower < 0.8 * work_k {
            return vec2<real>(real(k - 1u), step_factor(e[k - 1u], k - 1u));
        }
    }
    var raise = false;
    if accepted && k < top {
        if k == 2u {
            raise = true;
        } else {
            raise = work_k < 0.9 * (tableau_work(k - 1u) / step_factor(e[k - 1u], k - 1u));
        }
    }
    if raise {
        let f = min(step_factor(e[k], k) * tableau_work(k + 1u) / tableau_work(k), MAX_GROWTH);
        return vec2<real>(real(k + 1u), f);
    }
    return vec2<real>(real(k), step_factor(e[k], k));
}

// x, hidden from the driver compiler's value-unsafe algebra (`opaque_f64` of f64_math.wgsl,
// for either real): Mesa NIR (lavapipe) folds (a + b) - a to b, which made two_sum's error 0
// (measured: 256 of 256 cases on lavapipe f64, against ~1e-19 on the CPU).
fn opaque_real(x: real) -> real {
    return select(-x, x, x == x);
}

// `two_sum` of kernels/src/shared/f64_math.rs: (a + b rounded, what the rounding left out), the
// same operations with the intermediate sums kept opaque. `two_sum_f64` of f64_math.wgsl again,
// for either real: the f32 kernel is generated without f64_math.wgsl.
fn two_sum(a: real, b: real) -> vec2<real> {
    let s = opaque_real(a + b);
    let b_taken = opaque_real(s - a);
    let a_taken = s - b_taken;
    return vec2<real>(s, (a - a_taken) + (b - b_taken));
}

// StepControl::remaining: t_end - (t + t_low).
fn remaining_time(c: Control) -> real {
    return (config.t_end - c.t) - c.t_low;
}

// StepControl::trial_step: dt, or exactly what is left when that is within rounding of dt;
// adaptive steps take what is left in two halves when it is less than two steps (no slivers).
fn trial_step(c: Control) -> real {
    let remaining = remaining_time(c);
    if remaining <= c.dt * (1.0 + 1e-9) {
        return remaining;
    }
    if config.fixed_h == 0.0 && remaining < 2.0 * c.dt {
        return 0.5 * remaining;
    }
    return c.dt;
}

// StepControl::conclude_attempt. Returns whether the step is accepted. On failure the caller
// fills in the smallest gap.
fn conclude_attempt(c: ptr<function, Control>, h: real, r_in: Attempt) -> bool {
    (*c).window_attempts += 1u;
    if (*c).window_attempts >= STALL_WINDOW {
        let advanced = ((*c).t - (*c).window_t) + (*c).t_low;
        let pace = select(STALL_PACE_ADAPTIVE, STALL_PACE, config.fixed_h > 0.0);
        if advanced < real(STALL_WINDOW) * pace * remaining_time(*c) {
            // Failure::Stalled = 6.
            (*c).failure = 6u;
            (*c).failure_time = (*c).t;
            return false;
        }
        (*c).window_t = (*c).t;
        (*c).window_attempts = 0u;
    }
    let accepted = r_in.admissible && r_in.energy_ok && r_in.err <= 1.0;
    // The step accepted right after a rejection raises neither the step nor the column.
    var r = r_in;
    if accepted && (*c).after_rejection == 1u {
        r.factor = min(r.factor, 1.0);
        r.order_next = min(r.order_next, (*c).order);
    }
    (*c).after_rejection = select(1u, 0u, accepted);
    if accepted {
        (*c).accepted += 1u;
        (*c).error_sum = (*c).error_sum + r.estimate;
        let landed = h == remaining_time(*c);
        let shortened = h < (*c).dt * (1.0 - 1e-9);
        (*c).regular_steps += 1u;
        if landed {
            (*c).t = config.t_end;
            (*c).t_low = 0.0;
        } else if config.fixed_h > 0.0 && (*c).regular == 1u {
            (*c).t = config.t_start + real((*c).regular_steps) * config.fixed_h;
            (*c).t_low = 0.0;
        } else {
            let t = two_sum((*c).t, h + (*c).t_low);
            (*c).t = t.x;
            (*c).t_low = t.y;
        }
        if config.fixed_h > 0.0 {
            (*c).dt = min(2.0 * (*c).dt, config.fixed_h);
        } else {
            var factor = r.factor;
            if !shortened {
                factor = predictive_factor(r.factor, h, r.err, max((*c).order, 2u), (*c).h_previous, (*c).err_previous);
            }
            if shortened || r.order_next != (*c).order {
                (*c).h_previous = 0.0;
            } else {
                (*c).h_previous = h;
            }
            (*c).err_previous = max(r.err, 1e-2);
            (*c).order = r.order_next;
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
    if r.admissible && r.energy_ok {
        if r.order_next != (*c).order {
            (*c).h_previous = 0.0;
        }
        (*c).order = r.order_next;
        (*c).dt = h * min(r.factor, 1.0);
    } else {
        (*c).dt = h * REJECT_SHRINK;
    }
    // Rules::step_floor: dt_min, or the time resolution at t where larger.
    if (*c).dt < max(config.dt_min, TIME_RESOLUTION * abs((*c).t)) {
        // Failure::Inadmissible = 1, ErrorTooLarge = 2, EnergyRose = 3.
        if !r.admissible {
            (*c).failure = 1u;
        } else if !r.energy_ok {
            (*c).failure = 3u;
        } else {
            (*c).failure = 2u;
        }
        (*c).failure_time = (*c).t;
    }
    return false;
}

fn is_running(c: Control) -> bool {
    return c.failure == 0u && c.t < config.t_end;
}
