// Few members with huge N on the GPU: each trial step's tridiagonal solves split into segments
// solved side by side (partitioned, SPIKE-style Thomas), the rest of the step (projection,
// energy, extrapolation, error norm, step control) split the same way into per-segment parts
// and per-member reductions. WGSL twin of kernels/src/step/partitioned.rs (`forward_row`,
// `back_row`, `interfaces`: read its header for the algorithm) and, for everything around the
// solve, of shaders/step.wgsl (`euler`, `conclude`, `try_step`, `advance`, `begin_interval`,
// `gather`), whose functions this file calls: it is appended to the generated step kernel
// (`generate_partitioned_wgsl` in src/backend/gpu/kernel.rs), with the same marker blocks.
// Keep them in sync, loop for loop.
//
// Over 700 lines on purpose: WGSL has no modules, and this file is appended to the generated
// step kernel as one piece; its functions follow kernels/src/step/partitioned.rs in order.
//
// Why: one invocation per member runs a member's whole chain in one invocation. With fewer
// members than the GPU's parallel width most of it idles, and lavapipe stops an invocation
// after 65535 loop iterations (N <= ~32767 at order 1). Here no invocation loops over more than
// one segment (SEG_ROWS rows, a few hundred) or over the segments of one member (a few thousand).
//
// Segments: rows 1..n-1 cut into P = parts.segments segments of parts.seg rows, the first
// parts.rem segments one row more (the CPU gives all leftover rows to segment 0, to keep its
// SIMD lanes in step; here that segment could break the loop budget). Segment s owns its rows'
// velocities (index row - 1) and gaps (index row); segment 0 also owns gap 0.
//
// One trial step is a fixed sequence of dispatches, encoded by the host
// (src/backend/gpu/partitioned.rs), over members ([m]) or over (segment, member) pairs ([s],
// invocation s·B + b); each member follows its own substeps through `PState`:
//   p_begin [m]; per Euler substep: (FORCING: p_positions [s], p_scan [m]), p_forward [s] (the
//   first sweep with the spike), p_interface [m] (the reduced system), p_solve [s] (sweep from
//   tau and back sweep), p_finish [m] (sum of the new gaps, gap 0), p_project [s] (projection,
//   energy parts), p_substep_end [m] (the step's report; order 1 fixed: the decision);
//   TABLEAU: p_extrapolate [s], p_extrapolated [m], p_project [s], p_decide [m];
//   then p_smallest [s] and p_failed [m] (the smallest gap named by a failure).
// Per interval: p_energy_parts [s] and p_begin_interval [m] first; p_count [m] after each
// submit; p_gather [s] at output times.
//
// Bindings 12 (parts, uniform), 13 (pstate), 14 (segs), 15 (glued, clusters only) are this
// file's; the rest are step.wgsl's.

// Keep in sync with `PartsUniform` in src/backend/gpu/partitioned.rs.
struct Parts {
    segments: u32,
    seg: u32,
    rem: u32,
    padding: u32,
}

// A member's trial step between dispatches (GPU only; the host sizes it from the module).
struct PState {
    // The trial step, the current substep's size and start time.
    h: real,
    hj: real,
    ts: real,
    // Energy at the step's start, which each row's end is held to (try_step).
    known: real,
    // Factor of the pending projection.
    scale: real,
    hard_detail: real,
    sub_hard_detail: real,
    row_work: array<real, 9>,
    row_energy: array<real, 9>,
    estimates: array<real, 9>,
    // The member takes a trial step / an Euler substep is under way / a projection is pending.
    trying: u32,
    sub_active: u32,
    proj_active: u32,
    // Projection with the forcing's work (an Euler substep) or without (the extrapolated state).
    proj_forced: u32,
    proj_set: u32,
    cur: u32,
    cand: u32,
    rows: u32,
    // The substep: s of row j, from set src to set dst.
    j: u32,
    s: u32,
    src: u32,
    dst: u32,
    // Hard failure of the first substep, and of the current one.
    hard: u32,
    hard_index: u32,
    sub_hard: u32,
    sub_hard_index: u32,
    admissible: u32,
    energy_ok: u32,
    sub_admissible: u32,
    // The step failed the member: p_smallest and p_failed name its smallest gap.
    failed_now: u32,
}

// One segment of one member (GPU only).
struct Seg {
    // The end of the first sweep (`SegmentEnd`): ls, ys0, z of the last row; u_b = a + b u_e + c tau.
    ls: real,
    ys: real,
    z: real,
    a: real,
    b: real,
    c: real,
    // The interface values: the rate of the first gap, the velocity right of the last row.
    tau: real,
    u_right: real,
    // Position of particle first_row - 1 (forcing only).
    pos: real,
    // Sum of the new gaps, largest h r of a gap whose new value is not negligible (`overshoot`).
    sum: real,
    overshoot: real,
    // Energy parts and the forcing's work.
    pot: real,
    kin: real,
    work: real,
    hard_detail: real,
    smallest_ln: real,
    // Velocity of row 1 (segment 0).
    u_first: real,
    err: array<real, 9>,
    hard: u32,
    hard_index: u32,
    nonfinite: u32,
    smallest_index: u32,
}

@group(0) @binding(12) var<uniform> parts: Parts;
@group(0) @binding(13) var<storage, read_write> pstate: array<PState>;
@group(0) @binding(14) var<storage, read_write> segs: array<Seg>;
//@BEGIN CLUSTERS
// Per member: how many gaps from the left wall are bonded (those bodies do not move).
@group(0) @binding(15) var<storage, read> glued: array<u32>;
//@END CLUSTERS

// Rows [x, y) of segment s.
fn seg_rows(s: u32) -> vec2<u32> {
    let first = 1u + s * parts.seg + min(s, parts.rem);
    var len = parts.seg;
    if s < parts.rem {
        len += 1u;
    }
    return vec2<u32>(first, first + len);
}

// The first gap segment s owns (segment 0 also owns gap 0).
fn seg_first_gap(s: u32, range: vec2<u32>) -> u32 {
    return select(range.x, 0u, s == 0u);
}

// What the first forward sweep of a segment hands to the reduced system.
struct Ends {
    ls: real,
    ys: real,
    z: real,
    a: real,
    b: real,
    c: real,
    hard: u32,
    hard_index: u32,
    hard_detail: real,
}

// Forward sweep of segment s of member b (rows [first, last)), reading set st.src: the
// operations of `euler`'s forward sweep (step.wgsl), from the wall (segment 0) or from the rate
// tau of the segment's first gap (ls = 0, ys = -tau). `spike` (the first pass, tau unknown):
// also the spike z = dys/dtau and u_b = a + b u_e + c tau (`forward_row` with SPIKE), the forces
// computed and stored, the first hard failure; else (tau known) the rows w, ls, ys stored in the
// scratch for the back sweep and the forces read back.
fn forward(b: u32, s: u32, spike: bool, tau: real, st: PState, p: Param) -> Ends {
    let batch = config.batch;
    let n = config.particles;
    let eps = config.eps;
    let mass = 2.0 * eps;
    let eps2 = 2.0 * eps;
    let scale = reciprocal_scale(eps2);
    let h = st.hj;
    let m_over_h = mass / h;
    let rows = (n - 1u) * batch;
    let gi = st.src * n * batch;
    let vi = st.src * rows;
    let range = seg_rows(s);
    var e = Ends(0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0u, 0u, 0.0);
    var a_prev: real;
    var g_prev: real;
    var ls_prev: real;
    var ys_prev: real;
    var z_prev: real = 0.0;
    var pi: real = 1.0;
    var acc_a: real = 0.0;
    var acc_c: real = 0.0;
    var q: real = 0.0;
    if s == 0u {
        // The wall (u_0 = 0): ls_0 = 1/d_1, ys_0 = 0, no spike.
        let first = gap_terms(b, gap_sets[gi + b], p, h, eps2, scale);
        a_prev = first.a * jacobian_factor(first.d, first.inv_d, h, 0.0, velocity_or_wall(vi, 0u, b));
        g_prev = first.g;
        ls_prev = first.inv_d;
        ys_prev = 0.0;
//@BEGIN REPULSION
        if spike && !is_finite_real(first.g) {
            e.hard = 5u;
            e.hard_index = 1u;
            e.hard_detail = (dstar[b] + eps2) / (first.d + eps2);
        }
//@END REPULSION
    } else {
        // The segment's first gap is the previous row's next gap (checked there), and its k
        // is that row's.
        let k = (range.x - 1u) * batch + b;
        let first = gap_terms(k, gap_sets[gi + k], p, h, eps2, scale);
        let u_left = vel_sets[vi + (range.x - 2u) * batch + b];
        a_prev = first.a * jacobian_factor(first.d, first.inv_d, h, u_left, velocity_or_wall(vi, range.x - 1u, b));
        g_prev = first.g;
        ls_prev = 0.0;
        ys_prev = -tau;
        z_prev = select(real(0.0), real(-1.0), spike);
//@BEGIN FORCING
        q = segs[s * batch + b].pos;
//@END FORCING
    }
    for (var i: u32 = range.x; i < range.y; i++) {
        let row = (i - 1u) * batch + b;
        let next_gap = i * batch + b;
        let next = gap_terms(next_gap, gap_sets[gi + next_gap], p, h, eps2, scale);
        var f: real = 0.0;
//@BEGIN FORCING
        if spike {
            forcing_member = b;
            q = q + stored_decode(gap_sets[gi + row]) + mass;
            f = particle_force(eps, st.ts, q);
            scratch[3u * rows + row] = f;
            if !is_finite_real(f) && e.hard == 0u {
                e.hard = 4u;
                e.hard_index = i;
                e.hard_detail = q;
            }
        } else {
            f = scratch[3u * rows + row];
        }
//@END FORCING
//@BEGIN REPULSION
        if spike && !is_finite_real(next.g) && e.hard == 0u {
            e.hard = 5u;
            e.hard_index = i + 1u;
            e.hard_detail = (dstar[next_gap] + eps2) / (next.d + eps2);
        }
//@END REPULSION
        let vel = vel_sets[vi + row];
        let k = jacobian_factor(next.d, next.inv_d, h, vel, velocity_or_wall(vi, i, b));
        let a_next = next.a * k;
        let rhs = m_over_h * vel + g_prev - next.g + f;
        // As in `euler`, operation for operation.
        let excess = m_over_h + a_prev * ls_prev;
        let delta = rhs + a_prev * ys_prev;
        let pivot_base = m_over_h * next.d + a_next;
        let coupling = a_prev * next.d;
        let inv = 1.0 / (pivot_base + coupling * ls_prev);
        let ls = excess * inv;
        let ys = delta * inv;
        let w = a_next * inv;
        if spike {
            // z <= 0; flushed to 0 once negligible (NaN is kept), as is the product of w.
            var z = a_prev * z_prev * inv;
            if z > -TINY {
                z = 0.0;
            }
            acc_a = acc_a + pi * (next.d * ys);
            acc_c = acc_c + pi * (next.d * z);
            pi = pi * w;
            if pi < TINY {
                pi = 0.0;
            }
            z_prev = z;
        } else {
            scratch[row] = w;
            scratch[rows + row] = ls;
            scratch[2u * rows + row] = ys;
            scratch[4u * rows + row] = k;
        }
        ls_prev = ls;
        ys_prev = ys;
        a_prev = a_next;
        g_prev = next.g;
    }
    e.ls = ls_prev;
    e.ys = ys_prev;
    e.z = z_prev;
    e.a = acc_a;
    e.b = pi;
    e.c = acc_c;
    return e;
}

// The substep (j, s) of the member's trial step: its size, start time and sets, as try_step
// (or one Euler step from cur to cand).
fn set_substep(st: ptr<function, PState>, t: real) {
    let j = (*st).j;
    let s = (*st).s;
//@BEGIN EULER
    (*st).hj = (*st).h;
    (*st).ts = t;
    (*st).src = (*st).cur;
    (*st).dst = (*st).cand;
//@END EULER
//@BEGIN TABLEAU
    let substeps = row_substeps(j);
    let hj = (*st).h / real(substeps);
    (*st).hj = hj;
    (*st).ts = t + real(s) * hj;
    var src = SUB_SET + (s + 1u) % 2u;
    if s == 0u {
        src = (*st).cur;
    }
    var dst = SUB_SET + s % 2u;
    if s + 1u == substeps {
        dst = ROW_SET + j - 1u;
    }
    (*st).src = src;
    (*st).dst = dst;
//@END TABLEAU
}

// Decodes the invocation of a per-segment kernel: (segment, member), or none past the end.
fn seg_invocation(id: u32) -> vec3<u32> {
    let batch = config.batch;
    let valid = id < parts.segments * batch;
    return vec3<u32>(id / batch, id % batch, select(0u, 1u, valid));
}

// `advance`'s attempt loop, first part: the member's trial step begins (if it is running).
@compute @workgroup_size(64)
fn p_begin(@builtin(global_invocation_id) gid: vec3<u32>) {
    let b = gid.x;
    if b >= config.batch {
        return;
    }
    let c = controls[b];
    var st = pstate[b];
    st.trying = 0u;
    st.sub_active = 0u;
    st.proj_active = 0u;
    st.failed_now = 0u;
    if is_running(c) {
        st.trying = 1u;
        st.sub_active = 1u;
        st.h = trial_step(c);
        st.cur = c.parity;
        st.cand = 1u - c.parity;
//@BEGIN EULER
        st.rows = 1u;
//@END EULER
//@BEGIN TABLEAU
        st.rows = max(c.order, 2u);
//@END TABLEAU
        st.j = 1u;
        st.s = 0u;
        st.known = c.energy;
        st.admissible = 1u;
        st.energy_ok = 1u;
        st.hard = 0u;
        st.hard_index = 0u;
        st.hard_detail = 0.0;
        for (var j: u32 = 0u; j < 9u; j++) {
            st.row_work[j] = 0.0;
            st.row_energy[j] = 0.0;
        }
        set_substep(&st, c.t);
    }
    pstate[b] = st;
}

//@BEGIN FORCING
// Per segment: the sum of (gap + 2 eps) over its rows' gaps row - 1 (the positions' parts).
@compute @workgroup_size(32)
fn p_positions(@builtin(global_invocation_id) gid: vec3<u32>) {
    let v = seg_invocation(gid.x);
    if v.z == 0u || pstate[v.y].sub_active == 0u {
        return;
    }
    let batch = config.batch;
    let gi = pstate[v.y].src * config.particles * batch;
    let mass = 2.0 * config.eps;
    let range = seg_rows(v.x);
    var pos: real = 0.0;
    for (var i: u32 = range.x; i < range.y; i++) {
        pos = pos + stored_decode(gap_sets[gi + (i - 1u) * batch + v.y]) + mass;
    }
    segs[gid.x].pos = pos;
}

// Per member: each segment's start position (particle first_row - 1), the parts summed in order.
@compute @workgroup_size(64)
fn p_scan(@builtin(global_invocation_id) gid: vec3<u32>) {
    let b = gid.x;
    if b >= config.batch || pstate[b].sub_active == 0u {
        return;
    }
    var q: real = 0.0;
    for (var s: u32 = 0u; s < parts.segments; s++) {
        let k = s * config.batch + b;
        let part = segs[k].pos;
        segs[k].pos = q;
        q = q + part;
    }
}
//@END FORCING

// The first pass (`ends_group_impl`): every segment swept with the spike.
@compute @workgroup_size(32)
fn p_forward(@builtin(global_invocation_id) gid: vec3<u32>) {
    let v = seg_invocation(gid.x);
    if v.z == 0u {
        return;
    }
    let st = pstate[v.y];
    if st.sub_active == 0u {
        return;
    }
    let e = forward(v.y, v.x, true, 0.0, st, params[v.y]);
    let k = gid.x;
    segs[k].ls = e.ls;
    segs[k].ys = e.ys;
    segs[k].z = e.z;
    segs[k].a = e.a;
    segs[k].b = e.b;
    segs[k].c = e.c;
    segs[k].hard = e.hard;
    segs[k].hard_index = e.hard_index;
    segs[k].hard_detail = e.hard_detail;
}

// `interfaces`: the reduced system in (tau_s, u_{b_s}) swept like a Thomas system (alpha and
// beta kept in the tau and u_right slots on the way), and the first hard failure along the chain.
@compute @workgroup_size(64)
fn p_interface(@builtin(global_invocation_id) gid: vec3<u32>) {
    let b = gid.x;
    let batch = config.batch;
    if b >= batch {
        return;
    }
    var st = pstate[b];
    if st.sub_active == 0u {
        return;
    }
    let count = parts.segments;
    st.sub_hard = 0u;
    st.sub_hard_index = 0u;
    st.sub_hard_detail = 0.0;
    for (var s: u32 = 0u; s < count; s++) {
        let k = s * batch + b;
        if segs[k].hard != 0u {
            st.sub_hard = segs[k].hard;
            st.sub_hard_index = segs[k].hard_index;
            st.sub_hard_detail = segs[k].hard_detail;
            break;
        }
    }
    // tau_s = alpha_s + beta_s u_{b_{s+1}}; segment 0 has tau = 0. The state at the interface:
    // tau_s = lc u_{b_s} - yc.
    var lc = segs[b].ls;
    var yc = segs[b].ys;
    segs[b].tau = 0.0;
    segs[b].u_right = 0.0;
    for (var s: u32 = 1u; s < count; s++) {
        let k = s * batch + b;
        let ec = segs[k].c;
        let ez = segs[k].z;
        let inv = 1.0 / (1.0 - lc * ec);
        let alpha = (lc * segs[k].a - yc) * inv;
        let beta = lc * segs[k].b * inv;
        lc = segs[k].ls - ez * beta;
        yc = segs[k].ys + ez * alpha;
        segs[k].tau = alpha;
        segs[k].u_right = beta;
    }
    // The right wall: u_n = 0.
    var u_right: real = 0.0;
    for (var s: u32 = count; s >= 1u; s--) {
        let k = (s - 1u) * batch + b;
        let tau = segs[k].tau + segs[k].u_right * u_right;
        segs[k].tau = tau;
        segs[k].u_right = u_right;
        u_right = segs[k].a + segs[k].b * u_right + segs[k].c * tau;
    }
    pstate[b] = st;
}

// The second pass (`solve_group_impl`, `back_row`): each segment swept forward from its tau,
// then back from its right neighbour's first velocity: velocities, the gap update in rate form
// with the log-form fix-up done in place (`fix_up`), the sum of the new gaps and the largest
// opening of a gap whose new value is not negligible (`overshoot`); bodies glued to the left
// wall set to 0.
@compute @workgroup_size(32)
fn p_solve(@builtin(global_invocation_id) gid: vec3<u32>) {
    let v = seg_invocation(gid.x);
    if v.z == 0u {
        return;
    }
    let s = v.x;
    let b = v.y;
    let st = pstate[b];
    if st.sub_active == 0u {
        return;
    }
    let k = gid.x;
    forward(b, s, false, segs[k].tau, st, params[b]);
    let batch = config.batch;
    let n = config.particles;
    let h = st.hj;
    let rows = (n - 1u) * batch;
    let gi = st.src * n * batch;
    let go = st.dst * n * batch;
    let vo = st.dst * rows;
    let range = seg_rows(s);
    var overshoot: real = 0.0;
    let negligible = NEGLIGIBLE_OPENING * params[b].total_gap;
    var sum: real = 0.0;
    var u_next = segs[k].u_right;
    for (var i: u32 = range.y - 1u; i >= range.x; i--) {
        let row = (i - 1u) * batch + b;
        let gap = i * batch + b;
        let old = gap_sets[gi + gap];
        let d = max(old, GAP_FLOOR);
        var u = d * scratch[2u * rows + row] + scratch[row] * u_next;
//@BEGIN CLUSTERS
        if bonded[gap] != 0u {
            u = u_next;
        }
//@END CLUSTERS
        let rate = (scratch[rows + row] * u_next - scratch[2u * rows + row]) * scratch[4u * rows + row];
        let x = h * rate;
        var grown = old * gap_exp(x);
        if grown > negligible {
            overshoot = max(overshoot, x);
        }
        if !(grown >= GAP_FLOOR && grown <= REAL_MAX && x <= EXP_FAST_MAX) {
            // `fix_up` of this gap.
            if is_free(gap) {
                grown = encode_ln_gap(stored_ln(old) + x);
            } else {
                grown = 0.0;
            }
        }
        vel_sets[vo + row] = u;
        gap_sets[go + gap] = grown;
        sum = sum + max(grown, 0.0);
        u_next = u;
    }
//@BEGIN CLUSTERS
    // Bodies glued to the left wall do not move, exactly (after the sweep, as in `euler`).
    let stop = min(range.y - 1u, glued[b]);
    for (var i: u32 = range.x - 1u; i < stop; i++) {
        vel_sets[vo + i * batch + b] = 0.0;
    }
//@END CLUSTERS
    segs[k].sum = sum;
    segs[k].overshoot = overshoot;
    if s == 0u {
        segs[k].u_first = u_next;
    }
}

// The end of `euler` for a member: the sum of the new gaps (segments from the last down, as the
// back sweep adds them), gap 0's update, the opening check, and the projection to do.
@compute @workgroup_size(64)
fn p_finish(@builtin(global_invocation_id) gid: vec3<u32>) {
    let b = gid.x;
    let batch = config.batch;
    if b >= batch {
        return;
    }
    var st = pstate[b];
    if st.sub_active == 0u {
        return;
    }
    let n = config.particles;
    var sum: real = 0.0;
    var overshoot: real = 0.0;
    for (var s: u32 = parts.segments; s >= 1u; s--) {
        let k = (s - 1u) * batch + b;
        sum = sum + segs[k].sum;
        overshoot = max(overshoot, segs[k].overshoot);
    }
    let old0 = gap_sets[st.src * n * batch + b];
    let d0 = max(old0, GAP_FLOOR);
    let eps2 = 2.0 * config.eps;
    let inv_d0 = gap_reciprocals(d0, eps2, reciprocal_scale(eps2)).inv_d;
    let k_first = jacobian_factor(d0, inv_d0, st.hj, 0.0, velocity_or_wall(st.src * (n - 1u) * batch, 0u, b));
    let rate_first = segs[b].u_first / d0 * k_first;
    let x0 = st.hj * rate_first;
    var grown0 = old0 * gap_exp(x0);
    if grown0 > NEGLIGIBLE_OPENING * params[b].total_gap {
        overshoot = max(overshoot, x0);
    }
    if !(grown0 >= GAP_FLOOR && grown0 <= REAL_MAX && x0 <= EXP_FAST_MAX) {
        if is_free(b) {
            grown0 = encode_ln_gap(stored_ln(old0) + x0);
        } else {
            grown0 = 0.0;
        }
    }
    gap_sets[st.dst * n * batch + b] = grown0;
    sum = sum + max(grown0, 0.0);
    st.sub_admissible = select(0u, 1u, overshoot <= MAX_OPENING);
    st.scale = params[b].total_gap / sum;
    st.proj_set = st.dst;
    st.proj_active = 1u;
    st.proj_forced = 1u;
    pstate[b] = st;
}

// `conclude` per segment: the projection of set proj_set (gaps times scale, log-stored ones
// shifted by ln scale) and the parts of the energy and of the forcing's work.
@compute @workgroup_size(32)
fn p_project(@builtin(global_invocation_id) gid: vec3<u32>) {
    let v = seg_invocation(gid.x);
    if v.z == 0u {
        return;
    }
    let s = v.x;
    let b = v.y;
    let st = pstate[b];
    if st.proj_active == 0u {
        return;
    }
    let batch = config.batch;
    let n = config.particles;
    let eps2 = 2.0 * config.eps;
    let rows = (n - 1u) * batch;
    let base = st.proj_set * n * batch;
    let scale = st.scale;
    let p = params[b];
    let range = seg_rows(s);
    var potential_sum: real = 0.0;
    var kinetic: real = 0.0;
    var work: real = 0.0;
    var nonfinite = 0u;
    var shift: real = 0.0;
    var shifted = false;
    for (var i: u32 = seg_first_gap(s, range); i < range.y; i++) {
        let k = i * batch + b;
        let g = gap_sets[base + k];
        let scaled = g * scale;
        if !is_finite_real(g) {
            nonfinite = 1u;
        }
        if g > 0.0 {
            gap_sets[base + k] = scaled;
        } else if g < 0.0 {
            // `shift_logged`.
            if !shifted {
                shift = ln_real(scale);
                shifted = true;
            }
            gap_sets[base + k] = g + shift;
        }
        let phi = potential(k, max(scaled, 0.0), p, eps2);
        if is_free(k) {
            potential_sum = potential_sum + phi;
        }
    }
    for (var i: u32 = range.x - 1u; i + 1u < range.y; i++) {
        let k = i * batch + b;
        let u = vel_sets[st.proj_set * rows + k];
        kinetic = kinetic + u * u;
//@BEGIN FORCING
        if st.proj_forced != 0u {
            work = work + u * scratch[3u * rows + k];
        }
//@END FORCING
    }
    segs[gid.x].pot = potential_sum;
    segs[gid.x].kin = kinetic;
    segs[gid.x].work = work;
    segs[gid.x].nonfinite = nonfinite;
}

// The energy (sum of the segments' parts in order), the work and whether it is admissible:
// `conclude`'s report.
fn projected_report(b: u32, h: real, admissible: bool) -> StepReport {
    var potential_sum: real = 0.0;
    var kinetic: real = 0.0;
    var work: real = 0.0;
    var finite = admissible;
    for (var s: u32 = 0u; s < parts.segments; s++) {
        let k = s * config.batch + b;
        potential_sum = potential_sum + segs[k].pot;
        kinetic = kinetic + segs[k].kin;
        work = work + segs[k].work;
        finite = finite && segs[k].nonfinite == 0u;
    }
    var report = StepReport(finite, 0u, 0u, 0.0, 0.0, 0.0);
    report.energy = potential_sum + config.eps * kinetic;
    report.work = h * work;
    report.admissible = report.admissible && is_finite_real(report.energy);
    return report;
}

// The end of `advance`'s attempt: a hard failure, an accepted step (the parity flips) or a
// rejected one (a failure then names the smallest gap: p_smallest, p_failed).
fn decide(b: u32, st: ptr<function, PState>, r: Attempt) {
    var c = controls[b];
    if r.hard != 0u {
        c.failure = r.hard;
        c.failure_time = c.t;
        c.failure_index = r.hard_index;
        c.failure_detail = r.hard_detail;
    } else if conclude_attempt(&c, (*st).h, r) {
        c.parity = (*st).cand;
        c.energy = r.energy;
    } else if c.failure != 0u {
        (*st).failed_now = 1u;
    }
    controls[b] = c;
    (*st).trying = 0u;
    (*st).sub_active = 0u;
}

// The substep's report; try_step's bookkeeping of the tableau (or, for one Euler step, the
// decision) and the next substep.
@compute @workgroup_size(64)
fn p_substep_end(@builtin(global_invocation_id) gid: vec3<u32>) {
    let b = gid.x;
    if b >= config.batch {
        return;
    }
    var st = pstate[b];
    if st.sub_active == 0u {
        return;
    }
    st.proj_active = 0u;
    let c = controls[b];
    let gamma = gamma_of_member(params[b]);
    let r = projected_report(b, st.hj, st.sub_admissible != 0u);
//@BEGIN EULER
    decide(b, &st, Attempt(
        r.admissible,
        energy_acceptable(c.energy, r.energy, r.work, gamma),
        0.0,
        1.0,
        1u,
        0.0,
        st.sub_hard,
        st.sub_hard_index,
        st.sub_hard_detail,
        r.energy
    ));
//@END EULER
//@BEGIN TABLEAU
    if st.j == 1u && st.s == 0u {
        st.hard = st.sub_hard;
        st.hard_index = st.sub_hard_index;
        st.hard_detail = st.sub_hard_detail;
    } else if st.sub_hard != 0u {
        // Met in a substep's state: a smaller step may avoid it.
        st.admissible = 0u;
    }
    if !r.admissible {
        st.admissible = 0u;
    }
    st.row_work[st.j] = st.row_work[st.j] + r.work;
    if st.s + 1u == row_substeps(st.j) {
        if !energy_acceptable(st.known, r.energy, st.row_work[st.j], gamma) {
            st.energy_ok = 0u;
        }
        st.row_energy[st.j] = r.energy;
    }
    st.s += 1u;
    if st.s == row_substeps(st.j) {
        st.j += 1u;
        st.s = 0u;
    }
    if st.j > st.rows {
        st.sub_active = 0u;
    } else {
        set_substep(&st, c.t);
    }
//@END TABLEAU
    pstate[b] = st;
}

//@BEGIN TABLEAU
// `extrapolate` per segment: the tableau of the segment's elements into set cand, the largest
// estimates and the sum of the new gaps.
@compute @workgroup_size(32)
fn p_extrapolate(@builtin(global_invocation_id) gid: vec3<u32>) {
    let v = seg_invocation(gid.x);
    if v.z == 0u {
        return;
    }
    let s = v.x;
    let b = v.y;
    let st = pstate[b];
    if st.trying == 0u {
        return;
    }
    let batch = config.batch;
    let base = st.cand * config.particles * batch;
    let range = seg_rows(s);
    var err: array<real, 9>;
    var sum: real = 0.0;
    for (var i: u32 = seg_first_gap(s, range); i < range.y; i++) {
        extrapolate_gap(i * batch + b, st.cand, st.rows, &err);
        sum = sum + max(gap_sets[base + i * batch + b], 0.0);
    }
    for (var i: u32 = range.x - 1u; i + 1u < range.y; i++) {
        extrapolate_velocity(i * batch + b, st.cand, st.rows, &err);
    }
    segs[gid.x].err = err;
    segs[gid.x].sum = sum;
}

// The estimates (largest over the segments) and, for the extrapolated state, its projection.
@compute @workgroup_size(64)
fn p_extrapolated(@builtin(global_invocation_id) gid: vec3<u32>) {
    let b = gid.x;
    let batch = config.batch;
    if b >= batch {
        return;
    }
    var st = pstate[b];
    if st.trying == 0u {
        return;
    }
    var err: array<real, 9>;
    var sum: real = 0.0;
    for (var s: u32 = parts.segments; s >= 1u; s--) {
        let k = (s - 1u) * batch + b;
        for (var j: u32 = 2u; j <= st.rows; j++) {
            err[j] = noted(err[j], segs[k].err[j]);
        }
        sum = sum + segs[k].sum;
    }
    st.estimates = err;
    if EXTRAPOLATES {
        st.scale = params[b].total_gap / sum;
        st.proj_set = st.cand;
        st.proj_active = 1u;
        st.proj_forced = 0u;
    }
    pstate[b] = st;
}

// The rest of try_step (the extrapolated state's energy, the error and the next order and
// step) and the decision.
@compute @workgroup_size(64)
fn p_decide(@builtin(global_invocation_id) gid: vec3<u32>) {
    let b = gid.x;
    if b >= config.batch {
        return;
    }
    var st = pstate[b];
    if st.trying == 0u {
        return;
    }
    st.proj_active = 0u;
    let c = controls[b];
    let gamma = gamma_of_member(params[b]);
    let k = c.order;
    let rows = st.rows;
    var admissible = st.admissible != 0u;
    var energy_ok = st.energy_ok != 0u;
    var energy = st.row_energy[rows];
    if EXTRAPOLATES {
        let report = projected_report(b, 1.0, true);
        admissible = admissible && report.admissible;
        energy_ok = energy_ok && extrapolated_energy_acceptable(c.energy, report.energy, st.row_work[rows], gamma, rows);
        energy = report.energy;
    }
    var err: real = 0.0;
    var factor: real = 1.0;
    var order_next = k;
//@BEGIN ADAPTIVE
    var scaled: array<real, 9>;
    for (var j: u32 = 0u; j < 9u; j++) {
        scaled[j] = st.estimates[j] / config.tolerance;
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
    decide(b, &st, Attempt(
        admissible,
        energy_ok,
        err,
        factor,
        order_next,
        st.estimates[rows],
        st.hard,
        st.hard_index,
        st.hard_detail,
        energy
    ));
    pstate[b] = st;
}
//@END TABLEAU

// `smallest_gap` per segment, for members that failed this attempt: the first smallest free
// gap (1-based index, ln d) of the state.
@compute @workgroup_size(32)
fn p_smallest(@builtin(global_invocation_id) gid: vec3<u32>) {
    let v = seg_invocation(gid.x);
    if v.z == 0u {
        return;
    }
    let s = v.x;
    let b = v.y;
    let st = pstate[b];
    if st.failed_now == 0u {
        return;
    }
    let batch = config.batch;
    let base = st.cur * config.particles * batch;
    let range = seg_rows(s);
    var best_index = 0u;
    var best: real = REAL_MAX;
    for (var i: u32 = seg_first_gap(s, range); i < range.y; i++) {
        let k = i * batch + b;
        if !is_free(k) {
            continue;
        }
        let l = stored_ln(gap_sets[base + k]);
        if l < best {
            best = l;
            best_index = i + 1u;
        }
    }
    segs[gid.x].smallest_index = best_index;
    segs[gid.x].smallest_ln = best;
}

// The smallest gap of the segments in order (the first one of a tie), into the failure.
@compute @workgroup_size(64)
fn p_failed(@builtin(global_invocation_id) gid: vec3<u32>) {
    let b = gid.x;
    if b >= config.batch {
        return;
    }
    if pstate[b].failed_now == 0u {
        return;
    }
    var best = vec2<real>(0.0, REAL_MAX);
    for (var s: u32 = 0u; s < parts.segments; s++) {
        let k = s * config.batch + b;
        if segs[k].smallest_ln < best.y {
            best = vec2<real>(real(segs[k].smallest_index), segs[k].smallest_ln);
        }
    }
    controls[b].failure_index = u32(best.x);
    controls[b].failure_detail = best.y;
    pstate[b].failed_now = 0u;
}

// `state_energy` per segment (members whose energy is not known yet).
@compute @workgroup_size(32)
fn p_energy_parts(@builtin(global_invocation_id) gid: vec3<u32>) {
    let v = seg_invocation(gid.x);
    if v.z == 0u {
        return;
    }
    let s = v.x;
    let b = v.y;
    let c = controls[b];
    if c.failure != 0u || c.energy >= 0.0 {
        return;
    }
    let batch = config.batch;
    let n = config.particles;
    let eps2 = 2.0 * config.eps;
    let rows = (n - 1u) * batch;
    let p = params[b];
    let range = seg_rows(s);
    var potential_sum: real = 0.0;
    var kinetic: real = 0.0;
    for (var i: u32 = seg_first_gap(s, range); i < range.y; i++) {
        let k = i * batch + b;
        let phi = potential(k, max(gap_sets[c.parity * n * batch + k], 0.0), p, eps2);
        if is_free(k) {
            potential_sum = potential_sum + phi;
        }
    }
    for (var i: u32 = range.x - 1u; i + 1u < range.y; i++) {
        let u = vel_sets[c.parity * rows + i * batch + b];
        kinetic = kinetic + u * u;
    }
    segs[gid.x].pot = potential_sum;
    segs[gid.x].kin = kinetic;
}

// `begin_interval`, the energy from the segments' parts.
@compute @workgroup_size(64)
fn p_begin_interval(@builtin(global_invocation_id) gid: vec3<u32>) {
    let b = gid.x;
    if b >= config.batch {
        return;
    }
    var c = controls[b];
    if c.failure != 0u {
        return;
    }
    if c.energy < 0.0 {
        var potential_sum: real = 0.0;
        var kinetic: real = 0.0;
        for (var s: u32 = 0u; s < parts.segments; s++) {
            let k = s * config.batch + b;
            potential_sum = potential_sum + segs[k].pot;
            kinetic = kinetic + segs[k].kin;
        }
        c.energy = potential_sum + config.eps * kinetic;
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

// The members still running, after a submit's last attempt.
@compute @workgroup_size(64)
fn p_count(@builtin(global_invocation_id) gid: vec3<u32>) {
    let b = gid.x;
    if b >= config.batch {
        return;
    }
    if is_running(controls[b]) {
        atomicAdd(&running, 1u);
    }
}

// `gather` per segment.
@compute @workgroup_size(32)
fn p_gather(@builtin(global_invocation_id) gid: vec3<u32>) {
    let v = seg_invocation(gid.x);
    if v.z == 0u {
        return;
    }
    let s = v.x;
    let b = v.y;
    let batch = config.batch;
    let n = config.particles;
    let current = controls[b].parity;
    let range = seg_rows(s);
    for (var i: u32 = seg_first_gap(s, range); i < range.y; i++) {
        gathered_gaps[i * batch + b] = gap_sets[current * n * batch + i * batch + b];
    }
    for (var i: u32 = range.x - 1u; i + 1u < range.y; i++) {
        gathered_vel[i * batch + b] = vel_sets[current * (n - 1u) * batch + i * batch + b];
    }
}
