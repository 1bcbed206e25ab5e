// One linearly implicit Euler step for the whole batch, fused with the Thomas solve: the WGSL
// twin of `euler_step` in src/cpu/step.rs (read its header for the equations). One invocation
// per member; member b's element i sits at `i * batch + b`. Keep the two in sync, loop for loop.
//
// This file is a TEMPLATE, filled by `generate_step_wgsl` (src/gpu/kernel.rs), line by line:
//  - the line declaring the alias `real` is replaced by the element type (f32 or f64);
//  - blocks between the marker lines BEGIN NAME and END NAME (comment lines starting with
//    slash-slash-at) are kept or removed: REPULSION, CLUSTERS, FREE (= no clusters), FORCING;
//    terms the plan leaves out are not compiled at all;
//  - the marker line GENERATED is replaced by the generated code: REAL_MAX, `power(r, gamma)`
//    (integer gamma: a fixed square-and-multiply chain, the sequence of `powi_by_squaring`;
//    per-member gamma: the same chain when gamma is an integer <= 64 as `Power::of` does, else
//    exp/pow), `gamma_of(m)`, the forcing function `forcing(x, t)` and the unrolled
//    Gauss–Legendre sum `particle_force(eps, t, q)`; the f64 math library is prepended when the
//    generated code calls it.
//
// Bindings (group 0): 0 config (uniform), 1 gaps_in, 2 vel_in, 3 members, 4 gaps_out, 5 vel_out,
// 6 scratch (w | lambda | y, each (N-1)·batch), 7 ok (u32 per member), 8 dstar (repulsion only),
// 9 bonded (u32, clusters only).

alias real = f64;

struct Config {
    batch: u32,
    particles: u32,
    eps: real,
}

struct Member {
    mu: real,
    h: real,
    t: real,
    // Used only with a per-member gamma (GammaSpec::PerMember).
    gamma: real,
}

struct GapTerms {
    c: real,
    g: real,
}

@group(0) @binding(0) var<uniform> config: Config;
@group(0) @binding(1) var<storage, read> gaps_in: array<real>;
@group(0) @binding(2) var<storage, read> vel_in: array<real>;
@group(0) @binding(3) var<storage, read> members: array<Member>;
@group(0) @binding(4) var<storage, read_write> gaps_out: array<real>;
@group(0) @binding(5) var<storage, read_write> vel_out: array<real>;
@group(0) @binding(6) var<storage, read_write> scratch: array<real>;
@group(0) @binding(7) var<storage, read_write> ok_flags: array<u32>;
//@BEGIN REPULSION
@group(0) @binding(8) var<storage, read> dstar: array<real>;
//@END REPULSION
//@BEGIN CLUSTERS
@group(0) @binding(9) var<storage, read> bonded: array<u32>;
//@END CLUSTERS

// MIN_GAP_RATIO of src/cpu/step.rs.
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
fn gap_terms(index: u32, d: real, m: Member, eps2: real) -> GapTerms {
//@BEGIN CLUSTERS
    if bonded[index] != 0u {
        return GapTerms(0.0, 0.0);
    }
//@END CLUSTERS
    var c: real = m.mu / d;
    var g: real = 0.0;
//@BEGIN REPULSION
    let inv_s = 1.0 / (d + eps2);
    let ratio = (dstar[index] + eps2) * inv_s;
    g = power(ratio, m.gamma);
    c = c + m.h * gamma_of(m) * g * inv_s;
//@END REPULSION
    return GapTerms(c, g);
}

@compute @workgroup_size(64)
fn euler_step(@builtin(global_invocation_id) gid: vec3<u32>) {
    let b = gid.x;
    let batch = config.batch;
    if b >= batch {
        return;
    }
    let n = config.particles;
    let eps = config.eps;
    let m = members[b];
    let mass = 2.0 * eps;
    let eps2 = 2.0 * eps;
    let m_over_h = mass / m.h;
    let rows = (n - 1u) * batch;

    // Row 0 is the wall: u_0 = 0, so y_0 = 0; lambda_prev = 1 (infinite pivot excess).
    let first = gap_terms(b, gaps_in[b], m, eps2);
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
        let next = gap_terms(next_gap, gaps_in[next_gap], m, eps2);
        var f: real = 0.0;
//@BEGIN FORCING
        q = q + gaps_in[row] + mass;
        f = particle_force(eps, m.t, q);
//@END FORCING
        let rhs = m_over_h * vel_in[row] + g_prev - next.g + f;
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
        let d = gaps_in[gap] + m.h * relative;
        vel_out[row] = u;
        gaps_out[gap] = d;
        ok = ok && (!is_free(gap) || gap_step_admissible(gaps_in[gap], d));
        u_next = u;
    }
    let d0 = gaps_in[b] + m.h * u_next;
    gaps_out[b] = d0;
    ok = ok && (!is_free(b) || gap_step_admissible(gaps_in[b], d0));
    ok_flags[b] = select(0u, 1u, ok);
}
