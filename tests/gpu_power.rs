//! G = ratio^gamma in the generated WGSL (`roughlub::backend::gpu::kernel::power_wgsl`) against
//! the CPU's `Power::of(gamma).apply(ratio)`: integer gamma up to 1000 is the same chain of
//! square-and-multiply on both sides, so f64 results are equal bit for bit, both with a
//! per-member gamma (the kernel's unrolled 10-bit chain) and with one integer gamma for every
//! member (the straight-line chain).
//!
//! CPU only: the generated functions validate with naga. GPU tests go through
//! `acquire_for_tests(true)`: skipped without an f64 adapter unless `ROUGHLUB_REQUIRE_GPU=1`.

mod common;

use common::gpu::{acquire_for_tests, run_compute_f64};
use roughlub::backend::gpu::kernel::{power_wgsl, GammaSpec};
use roughlub::backend::gpu::{validate_wgsl, F64_MATH_WGSL};
use roughlub::backend::Precision;
use roughlub::model::plan::{powi_by_squaring, Power, MAX_INTEGER_GAMMA};

const WORKGROUP: usize = 64;

/// The integer gammas pinned here: above the old limit of 64, and up to the largest a scene
/// accepts.
const INTEGER_GAMMAS: [u32; 4] = [65, 100, 999, 1000];

/// Ratios near 1 (where large gamma is used), below and above, and ones that underflow and
/// overflow at large gamma.
const RATIOS: [f64; 9] = [
    1.001,
    0.999,
    1.000_000_1,
    0.999_999_9,
    1.0,
    1.5,
    0.5,
    2.0,
    0.123_456_789,
];

/// A compute shader writing `power(rs[i], gammas[i])` to `out[i]`.
fn kernel(gamma: GammaSpec, precision: Precision) -> String {
    let (real, math) = match precision {
        Precision::F64 => ("f64", F64_MATH_WGSL),
        Precision::F32 => ("f32", ""),
    };
    format!(
        "{math}\n\
alias real = {real};\n\
{}\n\
@group(0) @binding(0) var<storage, read> rs: array<real>;\n\
@group(0) @binding(1) var<storage, read> gammas: array<real>;\n\
@group(0) @binding(2) var<storage, read_write> out: array<real>;\n\
\n\
@compute @workgroup_size({WORKGROUP})\n\
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {{\n\
    let i = gid.x;\n\
    if (i >= arrayLength(&out)) {{\n\
        return;\n\
    }}\n\
    out[i] = power(rs[i], gammas[i]);\n\
}}\n",
        power_wgsl(gamma, precision)
    )
}

/// Every (ratio, gamma) pair of `ratios` × `gammas`.
fn pairs(gammas: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let mut rs = Vec::new();
    let mut gs = Vec::new();
    for &g in gammas {
        for &r in &RATIOS {
            rs.push(r);
            gs.push(g);
        }
    }
    (rs, gs)
}

#[test]
fn generated_power_validates_and_unrolls_ten_bits() {
    for precision in [Precision::F64, Precision::F32] {
        for gamma in [
            GammaSpec::PerMember,
            GammaSpec::Integer(1000),
            GammaSpec::Integer(65),
        ] {
            let src = kernel(gamma, precision);
            if let Err(e) = validate_wgsl("power", &src) {
                panic!("{gamma:?} {precision:?}: {e}");
            }
        }
        let per_member = power_wgsl(GammaSpec::PerMember, precision);
        // 10 bits cover gamma <= 1000 (1000 < 2^10).
        assert_eq!(MAX_INTEGER_GAMMA, 1000);
        assert_eq!(per_member.matches("e = e >> 1u;").count(), 10);
        assert!(
            per_member.contains("gamma <= 1000.0"),
            "the per-member chain covers gamma <= 1000:\n{per_member}"
        );
    }
    // 1000 = 0b1111101000: 9 squarings and 6 set bits (the first is `result = base`).
    let chain = power_wgsl(GammaSpec::Integer(1000), Precision::F64);
    assert_eq!(chain.matches("base = base * base;").count(), 9);
    assert_eq!(chain.matches("result = result * base;").count(), 5);
}

#[test]
fn per_member_integer_gamma_up_to_1000_is_bitwise_the_cpu_chain() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let mut gammas: Vec<f64> = INTEGER_GAMMAS.iter().map(|&n| n as f64).collect();
    // Every bit pattern of the 10-bit chain.
    gammas.extend([
        1.0, 2.0, 3.0, 64.0, 127.0, 128.0, 511.0, 512.0, 768.0, 1000.0,
    ]);
    let (rs, gs) = pairs(&gammas);
    let src = kernel(GammaSpec::PerMember, Precision::F64);
    let groups = rs.len().div_ceil(WORKGROUP) as u32;
    let gpu = run_compute_f64(&ctx, &src, "main", &[&rs, &gs], rs.len(), groups)
        .unwrap_or_else(|e| panic!("per-member power: {e}"));
    let mut wrong = Vec::new();
    for ((&r, &g), &got) in rs.iter().zip(&gs).zip(&gpu) {
        assert_eq!(Power::of(g), Power::Integer(g as u32), "gamma = {g}");
        let cpu = Power::of(g).apply(r);
        assert_eq!(cpu.to_bits(), powi_by_squaring(r, g as u32).to_bits());
        if got.to_bits() != cpu.to_bits() {
            wrong.push(format!("{r}^{g}: gpu {got:e}, cpu {cpu:e}"));
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

#[test]
fn uniform_integer_gamma_up_to_1000_is_bitwise_the_cpu_chain() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let mut wrong = Vec::new();
    for n in INTEGER_GAMMAS {
        let (rs, gs) = pairs(&[n as f64]);
        let src = kernel(GammaSpec::Integer(n), Precision::F64);
        let groups = rs.len().div_ceil(WORKGROUP) as u32;
        let gpu = run_compute_f64(&ctx, &src, "main", &[&rs, &gs], rs.len(), groups)
            .unwrap_or_else(|e| panic!("power^{n}: {e}"));
        for (&r, &got) in rs.iter().zip(&gpu) {
            let cpu = powi_by_squaring(r, n);
            if got.to_bits() != cpu.to_bits() {
                wrong.push(format!("{r}^{n}: gpu {got:e}, cpu {cpu:e}"));
            }
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

/// Above 1000 and for fractional gamma both sides use the real power (not bit for bit: the
/// GPU's `pow_f64` is within a few ulp of `powf` in ln G).
#[test]
fn gamma_above_1000_or_fractional_is_the_real_power() {
    for g in [1000.5, 1001.0, 64.5] {
        assert_eq!(Power::of(g), Power::Real(g), "gamma = {g}");
    }
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let (rs, gs) = pairs(&[1000.5, 1001.0, 64.5]);
    let src = kernel(GammaSpec::PerMember, Precision::F64);
    let groups = rs.len().div_ceil(WORKGROUP) as u32;
    let gpu = run_compute_f64(&ctx, &src, "main", &[&rs, &gs], rs.len(), groups)
        .unwrap_or_else(|e| panic!("per-member power: {e}"));
    for ((&r, &g), &got) in rs.iter().zip(&gs).zip(&gpu) {
        let cpu = Power::of(g).apply(r);
        if cpu.is_finite() && cpu > f64::MIN_POSITIVE {
            // A relative error e of ln G is e |ln G| in G.
            let tol = 1e-14 * (1.0 + (g * r.ln()).abs());
            assert!(
                ((got - cpu) / cpu).abs() <= tol,
                "{r}^{g}: gpu {got:e}, cpu {cpu:e}"
            );
        } else {
            assert_eq!(
                got.is_finite(),
                cpu.is_finite(),
                "{r}^{g}: gpu {got:e}, cpu {cpu:e}"
            );
        }
    }
}
