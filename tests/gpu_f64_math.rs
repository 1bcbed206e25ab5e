//! Accuracy of the f64 elementary functions of `shaders/f64_math.wgsl` on the GPU against Rust's
//! std f64 functions, plus CPU-only naga validation of the shader and error-path checks of the
//! GPU context.
//!
//! GPU tests go through `acquire_for_tests(true)`: they skip (pass vacuously, printing
//! "skipping: no GPU adapter") without an f64-capable adapter, unless `ROUGHLUB_REQUIRE_GPU=1`.
//! Run with `--nocapture` to see the measured errors.
//!
//! Error measure: `|gpu - std| / |std|` (0 when both are equal, including equal infinities).
//! Tolerance (per function in `TOL_*`): 2e-15 relative, i.e. about 9-18 ulp, for every function,
//! everywhere, including sin/cos/tan next to their zeros (arguments next to multiples of pi/2):
//! the pi/2 reduction carries ~100 bits, so the relative accuracy does not degrade there and no
//! absolute-error escape is needed. The std functions are themselves within ~1 ulp of the true
//! values, which the tolerance absorbs.

mod common;

use common::gpu::{acquire_for_tests, run_compute_f64};
use roughlub::backend::gpu::{validate_wgsl, GpuContext, GpuError, F64_MATH_WGSL};

/// Maximum relative error allowed for each function.
const TOL_EXP: f64 = 2e-15;
const TOL_EXPM1: f64 = 2e-15;
const TOL_LOG: f64 = 2e-15;
const TOL_SIN: f64 = 2e-15;
const TOL_COS: f64 = 2e-15;
const TOL_TAN: f64 = 2e-15;
const TOL_TANH: f64 = 2e-15;
const TOL_POW: f64 = 2e-15;

const WORKGROUP: usize = 64;

/// Kernel that applies `call` (an expression in `x` and `y`) to every element, with
/// `prelude` (more WGSL) after the f64 functions.
fn kernel(prelude: &str, call: &str) -> String {
    format!(
        "{F64_MATH_WGSL}\n{prelude}\n\
@group(0) @binding(0) var<storage, read> xs: array<f64>;\n\
@group(0) @binding(1) var<storage, read> ys: array<f64>;\n\
@group(0) @binding(2) var<storage, read_write> out: array<f64>;\n\
\n\
@compute @workgroup_size({WORKGROUP})\n\
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {{\n\
    let i = gid.x;\n\
    if (i >= arrayLength(&out)) {{\n\
        return;\n\
    }}\n\
    let x = xs[i];\n\
    let y = ys[i];\n\
    out[i] = {call};\n\
}}\n"
    )
}

fn eval(ctx: &GpuContext, call: &str, xs: &[f64], ys: &[f64]) -> Vec<f64> {
    eval_with(ctx, "", call, xs, ys)
}

/// [`eval`] with `prelude` in the kernel ([`kernel`]).
fn eval_with(ctx: &GpuContext, prelude: &str, call: &str, xs: &[f64], ys: &[f64]) -> Vec<f64> {
    assert_eq!(xs.len(), ys.len());
    let groups = xs.len().div_ceil(WORKGROUP) as u32;
    run_compute_f64(
        ctx,
        &kernel(prelude, call),
        "main",
        &[xs, ys],
        xs.len(),
        groups,
    )
    .unwrap_or_else(|e| panic!("{call}: {e}"))
}

/// splitmix64, uniform in [0, 1).
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }
    fn uniform(&mut self, a: f64, b: f64, n: usize) -> Vec<f64> {
        (0..n).map(|_| a + (b - a) * self.next()).collect()
    }
    /// Log-uniform on [a, b], a > 0.
    fn log_uniform(&mut self, a: f64, b: f64, n: usize) -> Vec<f64> {
        let (la, lb) = (a.ln(), b.ln());
        (0..n)
            .map(|_| (la + (lb - la) * self.next()).exp())
            .collect()
    }
}

fn next_up(x: f64) -> f64 {
    if x == 0.0 {
        return f64::from_bits(1);
    }
    f64::from_bits(if x > 0.0 {
        x.to_bits() + 1
    } else {
        x.to_bits() - 1
    })
}

fn next_down(x: f64) -> f64 {
    -next_up(-x)
}

fn ulp(x: f64) -> f64 {
    let a = x.abs();
    if a == 0.0 || !a.is_finite() {
        return f64::MIN_POSITIVE;
    }
    next_up(a) - a
}

struct Report {
    name: &'static str,
    max_rel: f64,
    max_ulp: f64,
    worst_x: f64,
    worst_y: f64,
    worst_gpu: f64,
    worst_ref: f64,
    n: usize,
}

fn compare(
    name: &'static str,
    xs: &[f64],
    ys: &[f64],
    gpu: &[f64],
    reference: impl Fn(f64, f64) -> f64,
) -> Report {
    let mut r = Report {
        name,
        max_rel: 0.0,
        max_ulp: 0.0,
        worst_x: f64::NAN,
        worst_y: f64::NAN,
        worst_gpu: f64::NAN,
        worst_ref: f64::NAN,
        n: xs.len(),
    };
    for ((&x, &y), &g) in xs.iter().zip(ys).zip(gpu) {
        let want = reference(x, y);
        let (rel, ulps) = if g == want {
            (0.0, 0.0)
        } else {
            let d = (g - want).abs();
            // NaN (a wrong NaN, or a NaN where a number is expected) compares as infinite error.
            let rel = if d.is_nan() {
                f64::INFINITY
            } else {
                d / want.abs()
            };
            (rel, d / ulp(want))
        };
        if rel > r.max_rel || (r.worst_x.is_nan() && rel >= r.max_rel) {
            r.max_rel = rel;
            r.worst_x = x;
            r.worst_y = y;
            r.worst_gpu = g;
            r.worst_ref = want;
        }
        r.max_ulp = r.max_ulp.max(ulps);
    }
    println!(
        "{:6} n = {:6}: max rel err {:.3e} ({:.2} ulp max); worst at x = {:e}{} gpu {:e} std {:e}",
        r.name,
        r.n,
        r.max_rel,
        r.max_ulp,
        r.worst_x,
        if name == "pow" {
            format!(", y = {:e}", r.worst_y)
        } else {
            String::new()
        },
        r.worst_gpu,
        r.worst_ref
    );
    r
}

fn check(report: Report, tol: f64) {
    assert!(
        report.max_rel <= tol,
        "{}: max relative error {:e} > {:e} at x = {:e}, y = {:e}: gpu {:e}, std {:e}",
        report.name,
        report.max_rel,
        tol,
        report.worst_x,
        report.worst_y,
        report.worst_gpu,
        report.worst_ref
    );
}

/// Unary function test over `xs`.
fn unary(
    ctx: &GpuContext,
    name: &'static str,
    wgsl_fn: &str,
    xs: &[f64],
    reference: fn(f64) -> f64,
    tol: f64,
) {
    let ys = vec![0.0; xs.len()];
    let gpu = eval(ctx, &format!("{wgsl_fn}(x)"), xs, &ys);
    check(compare(name, xs, &ys, &gpu, |x, _| reference(x)), tol);
}

/// Points next to multiples of pi/2 (the double nearest to k pi/2 and its neighbours), up to
/// |x| <= limit: where the reduction cancels most bits.
fn near_half_pi_multiples(limit: f64) -> Vec<f64> {
    let kmax = (limit / std::f64::consts::FRAC_PI_2) as i64;
    let mut v = Vec::new();
    let mut k = -kmax;
    while k <= kmax {
        let x = k as f64 * std::f64::consts::FRAC_PI_2;
        v.extend([x, next_up(x), next_down(x)]);
        // every multiple near 0, then a sparser sweep
        k += if k.abs() < 64 { 1 } else { 37 };
    }
    v
}

fn trig_points(rng: &mut Rng) -> Vec<f64> {
    let mut xs = rng.uniform(-1e4, 1e4, 6000);
    xs.extend(rng.uniform(-8.0, 8.0, 3000));
    xs.extend(near_half_pi_multiples(1e4));
    xs.extend([
        0.0, -0.0, 1e-300, -1e-300, 1e-17, -1e-17, 1e-8, -1e-8, 1e4, -1e4,
    ]);
    xs.extend([
        std::f64::consts::FRAC_PI_4,
        next_up(std::f64::consts::FRAC_PI_4),
        0.5,
        1.0,
        2.0,
        3.0,
        4.0,
    ]);
    xs
}

#[test]
fn naga_validates_f64_math_wgsl() {
    // The library on its own (no entry point) and inside a kernel, on the CPU.
    validate_wgsl("f64_math.wgsl", F64_MATH_WGSL).unwrap_or_else(|e| panic!("{e}"));
    let module = validate_wgsl("kernel", &kernel("", "pow_f64(x, y) + sin_f64(x)"))
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(module.entry_points.len(), 1);
    let names: Vec<&str> = module
        .functions
        .iter()
        .filter_map(|(_, f)| f.name.as_deref())
        .collect();
    for f in [
        "exp_f64",
        "expm1_f64",
        "log_f64",
        "sin_f64",
        "cos_f64",
        "tan_f64",
        "tanh_f64",
        "pow_f64",
    ] {
        assert!(names.contains(&f), "{f} missing from f64_math.wgsl");
    }
}

#[test]
fn naga_errors_are_gpu_errors() {
    // Parse error and validation error both become GpuError::Shader carrying naga's message.
    match validate_wgsl("broken", "fn f( -> f64 { return 1.0; }") {
        Err(GpuError::Shader { label, message }) => {
            assert_eq!(label, "broken");
            assert!(!message.is_empty());
        }
        other => panic!("expected a shader error, got {other:?}"),
    }
    match validate_wgsl("mistyped", "fn f(x: f64) -> f32 { return x; }") {
        Err(GpuError::Shader { message, .. }) => assert!(!message.is_empty()),
        other => panic!("expected a shader error, got {other:?}"),
    }
}

#[test]
fn gpu_exp_expm1() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    println!("adapter: {}", ctx.description);
    let mut rng = Rng(1);
    let mut xs = rng.uniform(-700.0, 700.0, 6000);
    xs.extend(rng.uniform(-3.0, 3.0, 3000));
    xs.extend(rng.uniform(-1e-6, 1e-6, 500));
    let ln2 = std::f64::consts::LN_2;
    xs.extend((-1000..=1000).step_by(10).map(|k| k as f64 * ln2));
    xs.extend((-1000..=1000).step_by(10).map(|k| (k as f64 + 0.5) * ln2));
    xs.extend([
        0.0, -0.0, 1e-300, -1e-300, 1e-17, -1e-17, 700.0, -700.0, 699.9, -699.9, 709.0, 709.78,
        -708.0,
    ]);
    xs.extend([
        next_up(0.5 * ln2),
        next_down(0.5 * ln2),
        1.0,
        -1.0,
        0.5,
        -0.5,
    ]);
    unary(&ctx, "exp", "exp_f64", &xs, f64::exp, TOL_EXP);

    let mut xs = rng.uniform(-40.0, 40.0, 4000);
    xs.extend(rng.uniform(-2.0, 2.0, 4000));
    xs.extend(rng.log_uniform(1e-300, 1.0, 1000));
    xs.extend(rng.log_uniform(1e-300, 1.0, 1000).iter().map(|x| -x));
    xs.extend([
        0.0,
        1e-17,
        -1e-17,
        0.25,
        -0.25,
        0.5 * ln2,
        -0.5 * ln2,
        1.5 * ln2,
        -1.5 * ln2,
        700.0,
        -700.0,
    ]);
    xs.extend((-60..=60).map(|k| k as f64 * ln2));
    unary(&ctx, "expm1", "expm1_f64", &xs, f64::exp_m1, TOL_EXPM1);
}

#[test]
fn gpu_log() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let mut rng = Rng(2);
    let mut xs = rng.log_uniform(1e-300, 1e300, 6000);
    xs.extend(rng.uniform(0.5, 2.0, 2000));
    xs.extend(rng.uniform(1.0 - 1e-6, 1.0 + 1e-6, 1000));
    let one = 1.0f64;
    xs.extend([
        one,
        next_up(one),
        next_down(one),
        next_up(next_up(one)),
        next_down(next_down(one)),
    ]);
    xs.extend([
        std::f64::consts::FRAC_1_SQRT_2,
        std::f64::consts::SQRT_2,
        2.0,
        0.5,
        10.0,
        std::f64::consts::E,
    ]);
    xs.extend([1e-300, 1e300, f64::MIN_POSITIVE, f64::MAX]);
    xs.extend((-1000..1000).step_by(7).map(|k| 2f64.powi(k)));
    unary(&ctx, "log", "log_f64", &xs, f64::ln, TOL_LOG);
}

#[test]
fn gpu_sin_cos_tan() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let mut rng = Rng(3);
    let xs = trig_points(&mut rng);
    unary(&ctx, "sin", "sin_f64", &xs, f64::sin, TOL_SIN);
    unary(&ctx, "cos", "cos_f64", &xs, f64::cos, TOL_COS);
    unary(&ctx, "tan", "tan_f64", &xs, f64::tan, TOL_TAN);
}

#[test]
fn gpu_tanh() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let mut rng = Rng(4);
    let mut xs = rng.uniform(-30.0, 30.0, 4000);
    xs.extend(rng.uniform(-1.5, 1.5, 4000));
    xs.extend(rng.uniform(-1e-5, 1e-5, 1000));
    xs.extend([
        0.0, -0.0, 1e-300, -1e-300, 1e-17, -1e-17, 0.55, -0.55, 1.0, -1.0, 22.0, -22.0, 30.0, -30.0,
    ]);
    xs.extend([next_down(1.0), next_up(1.0), next_down(22.0)]);
    unary(&ctx, "tanh", "tanh_f64", &xs, f64::tanh, TOL_TANH);
}

#[test]
fn gpu_pow() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let mut rng = Rng(5);
    let n = 9000;
    let mut xs = rng.log_uniform(1e-3, 1e3, n);
    let mut ys = rng.uniform(-50.0, 50.0, n);
    // moderate exponents, bases near 1, integer and half-integer exponents
    xs.extend(rng.log_uniform(1e-3, 1e3, 1000));
    ys.extend(rng.uniform(-3.0, 3.0, 1000));
    xs.extend(rng.uniform(0.999, 1.001, 500));
    ys.extend(rng.uniform(-50.0, 50.0, 500));
    for (x, y) in [
        (2.0, 0.5),
        (2.0, -1.0),
        (10.0, 2.0),
        (10.0, -3.0),
        (3.0, 3.0),
        (1e3, 50.0),
        (1e-3, 50.0),
        (1e3, -50.0),
        (1e-3, -50.0),
        (1.0, 50.0),
        (7.0, 0.0),
        (0.0, 2.0),
        (0.0, 0.5),
        (0.5, 1.0),
        (123.456, 1.0),
    ] {
        xs.push(x);
        ys.push(y);
    }
    let gpu = eval(&ctx, "pow_f64(x, y)", &xs, &ys);
    check(compare("pow", &xs, &ys, &gpu, f64::powf), TOL_POW);
}

#[test]
fn gpu_special_values() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let inf = f64::INFINITY;
    let cases: &[(&str, f64, f64, f64)] = &[
        // (call, x, y, expected); NaN expected means "is NaN"
        ("exp_f64(x)", 710.0, 0.0, inf),
        ("exp_f64(x)", 1e10, 0.0, inf),
        ("exp_f64(x)", -746.0, 0.0, 0.0),
        ("exp_f64(x)", -1e10, 0.0, 0.0),
        ("exp_f64(x)", 0.0, 0.0, 1.0),
        ("expm1_f64(x)", -100.0, 0.0, -1.0),
        ("expm1_f64(x)", 710.0, 0.0, inf),
        ("log_f64(x)", 0.0, 0.0, -inf),
        ("log_f64(x)", -1.0, 0.0, f64::NAN),
        ("log_f64(x)", inf, 0.0, inf),
        ("log_f64(x)", 1.0, 0.0, 0.0),
        ("pow_f64(x, y)", 0.0, 2.0, 0.0),
        ("pow_f64(x, y)", 0.0, -2.0, inf),
        ("pow_f64(x, y)", 5.0, 0.0, 1.0),
        ("pow_f64(x, y)", -2.0, 0.5, f64::NAN),
        ("pow_f64(x, y)", 10.0, 400.0, inf),
        ("pow_f64(x, y)", 10.0, -400.0, 0.0),
        ("pow_f64(x, y)", inf, 2.0, inf),
        ("pow_f64(x, y)", inf, -2.0, 0.0),
        ("tanh_f64(x)", 1e10, 0.0, 1.0),
        ("tanh_f64(x)", -1e10, 0.0, -1.0),
        ("tanh_f64(x)", inf, 0.0, 1.0),
        ("sin_f64(x)", 0.0, 0.0, 0.0),
        ("cos_f64(x)", 0.0, 0.0, 1.0),
        ("sin_f64(x)", inf, 0.0, f64::NAN),
        ("exp_f64(x)", f64::NAN, 0.0, f64::NAN),
    ];
    let mut failures = Vec::new();
    for &(call, x, y, want) in cases {
        let got = eval(&ctx, call, &[x], &[y])[0];
        let ok = if want.is_nan() {
            got.is_nan()
        } else {
            got == want
        };
        if !ok {
            failures.push(format!(
                "{call} at x = {x:e}, y = {y:e}: got {got:e}, want {want:e}"
            ));
        }
    }
    assert!(
        failures.is_empty(),
        "special values:\n{}",
        failures.join("\n")
    );
}

/// ldexp on f64 is exact on the device (the library builds 2^k with it), and so is the
/// library's exponent split `f64m_frexp` (WGSL's frexp on f64 is unusable: naga types its
/// exponent as i64, which needs SHADER_INT64). Also prints, for information, what the built-in
/// f64 sin/exp/log/pow return (garbage on Vulkan).
#[test]
fn gpu_ldexp_frexp_and_builtins() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let mut rng = Rng(6);
    let mut xs = rng.log_uniform(1e-300, 1e300, 2000);
    xs.extend([
        1.0,
        0.5,
        0.75,
        3.0,
        2.0,
        next_down(2.0),
        f64::MIN_POSITIVE,
        f64::MAX,
        1e-300,
        1e300,
    ]);
    let ks: Vec<f64> = (0..xs.len())
        .map(|i| ((i * 37) % 1200) as f64 - 600.0)
        .collect();
    let mantissa = eval(&ctx, "f64m_frexp(x).x", &xs, &ks);
    let exps = eval(&ctx, "f64m_frexp(x).y", &xs, &ks);
    let scaled = eval(&ctx, "ldexp(-x, i32(y))", &xs, &ks);
    for i in 0..xs.len() {
        let x = xs[i];
        // normal x = m 2^e with m in [1, 2), from the bits
        let b = x.to_bits();
        let want_exp = ((b >> 52) & 0x7ff) as i32 - 1023;
        let want_m = f64::from_bits((b & !(0x7ffu64 << 52)) | (1023u64 << 52));
        assert_eq!(
            (mantissa[i], exps[i]),
            (want_m, want_exp as f64),
            "f64m_frexp({x:e})"
        );
        let want_scaled = -x * 2f64.powi(ks[i] as i32);
        if want_scaled.is_normal() {
            assert_eq!(scaled[i], want_scaled, "ldexp({:e}, {})", -x, ks[i]);
        }
    }
    for call in ["sin(x)", "exp(x)", "log(x)", "pow(x, y)"] {
        let got = eval(&ctx, call, &[4.0], &[0.5])[0];
        let want = match call {
            "sin(x)" => 4f64.sin(),
            "exp(x)" => 4f64.exp(),
            "log(x)" => 4f64.ln(),
            _ => 2.0,
        };
        println!("built-in f64 {call} at x = 4, y = 0.5: {got:e} (std {want:e})");
    }
    let sub = eval(&ctx, "x * y", &[1e-300], &[1e-10])[0];
    println!(
        "f64 subnormal result 1e-300 * 1e-10 on the device: {sub:e} (IEEE: {:e})",
        1e-310
    );
}

/// Shader and pipeline errors from wgpu itself (not caught by naga) come back as GpuError
/// instead of panicking through wgpu's default error handler.
#[test]
fn gpu_errors_do_not_panic() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    // Invalid WGSL: caught by naga up front.
    let err = run_compute_f64(&ctx, "fn main( {", "main", &[], 1, 1).unwrap_err();
    assert!(matches!(err, GpuError::Shader { .. }), "{err}");
    // Valid WGSL whose bindings do not match the layout (binding 5 does not exist): wgpu's
    // pipeline validation error, caught by an error scope.
    let src = "@group(0) @binding(5) var<storage, read_write> out: array<f64>;\n\
               @compute @workgroup_size(1) fn main() { out[0] = 1.0; }";
    let err = run_compute_f64(&ctx, src, "main", &[], 1, 1).unwrap_err();
    assert!(matches!(err, GpuError::Shader { .. }), "{err}");
    // Missing entry point.
    let src = "@group(0) @binding(0) var<storage, read_write> out: array<f64>;\n\
               @compute @workgroup_size(1) fn main() { out[0] = 1.0; }";
    let err = run_compute_f64(&ctx, src, "nope", &[], 1, 1).unwrap_err();
    assert!(matches!(err, GpuError::Shader { .. }), "{err}");
    // Too many workgroups.
    let err = run_compute_f64(&ctx, src, "main", &[], 1, u32::MAX).unwrap_err();
    assert!(matches!(err, GpuError::Validation { .. }), "{err}");
    // A buffer above the binding limit.
    let limit = ctx
        .limits
        .max_storage_buffer_binding_size
        .min(ctx.limits.max_buffer_size);
    let err = ctx.check_storage_size("huge", limit + 8).unwrap_err();
    assert!(matches!(err, GpuError::BufferTooLarge { .. }), "{err}");
    // The working path still works afterwards, and nothing escaped the error scopes.
    let out = run_compute_f64(&ctx, src, "main", &[], 1, 1).unwrap();
    assert_eq!(out, vec![1.0]);
    assert!(ctx.take_uncaptured_errors().is_empty());
}

/// `two_sum_f64` and `two_prod_f64` are exact on the device even though the driver may simplify
/// float algebra and WGSL `fma` on f64 may not be fused (both the case on lavapipe). Prints what
/// the naive versions return, for information.
#[test]
fn gpu_error_free_transformations() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let mut rng = Rng(7);
    let n = 4000;
    let mut xs: Vec<f64> = rng.log_uniform(1e-200, 1e200, n);
    let mut ys: Vec<f64> = rng.log_uniform(1e-200, 1e200, n);
    for i in 0..n {
        if i % 2 == 1 {
            xs[i] = -xs[i];
        }
        if i % 3 == 1 {
            ys[i] = -ys[i];
        }
    }
    xs.extend(rng.uniform(1.0, 2.0, 500));
    ys.extend(rng.uniform(1.0, 2.0, 500).iter().map(|y| y * 1e-10));
    let sum_hi = eval(&ctx, "two_sum_f64(x, y).x", &xs, &ys);
    let sum_lo = eval(&ctx, "two_sum_f64(x, y).y", &xs, &ys);
    let prod_hi = eval(&ctx, "two_prod_f64(x, y).x", &xs, &ys);
    let prod_lo = eval(&ctx, "two_prod_f64(x, y).y", &xs, &ys);
    for i in 0..xs.len() {
        let (a, b) = (xs[i], ys[i]);
        let s = a + b;
        let bb = s - a;
        let e = (a - (s - bb)) + (b - bb);
        assert_eq!((sum_hi[i], sum_lo[i]), (s, e), "two_sum_f64({a:e}, {b:e})");
        let p = a * b;
        if p.is_normal() && p.abs() > 1e-290 {
            assert_eq!(
                (prod_hi[i], prod_lo[i]),
                (p, a.mul_add(b, -p)),
                "two_prod_f64({a:e}, {b:e})"
            );
        }
    }
    let naive_fma = eval(&ctx, "fma(x, y, -(x * y))", &xs[n..n + 4], &ys[n..n + 4]);
    let naive_sum = eval(
        &ctx,
        "(x - ((x + y) - ((x + y) - x))) + (y - ((x + y) - x))",
        &xs[n..n + 4],
        &ys[n..n + 4],
    );
    for i in 0..4 {
        let (a, b) = (xs[n + i], ys[n + i]);
        println!(
            "naive fma residual {:e} (exact {:e}); naive TwoSum error {:e} (exact {:e})",
            naive_fma[i],
            a.mul_add(b, -(a * b)),
            naive_sum[i],
            sum_lo[n + i]
        );
    }
}

/// The step control's `two_sum` (shaders/control.wgsl, which keeps the GPU's time as t plus
/// what its rounding left out) against its CPU twin, bit for bit: times t in (1e-4, 1] plus
/// steps from 1e-30 t to 1e-2 t, most below half an ulp of t, where only the error term moves
/// the time. Written with plain sums, Mesa NIR (lavapipe) folded (a + b) - a to b and the GPU's
/// error term was 0 in every case; the CPU's is the exact remainder.
#[test]
fn control_two_sum_equals_the_cpu_bitwise() {
    use roughlub::backend::gpu::kernel::CONTROL_WGSL;
    use roughlub::backend::shared::f64_math::two_sum;
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    // control.wgsl's two functions, on their own: the rest of the file needs the step kernel.
    let start = CONTROL_WGSL
        .find("fn opaque_real")
        .expect("opaque_real in control.wgsl");
    let end = CONTROL_WGSL[start..]
        .find("// StepControl::remaining")
        .expect("two_sum before remaining_time")
        + start;
    let functions = &CONTROL_WGSL[start..end];
    let mut rng = Rng(7);
    let n = 512;
    let ts = rng.log_uniform(1e-4, 1.0, n);
    let steps: Vec<f64> = rng
        .log_uniform(1e-30, 1e-2, n)
        .iter()
        .zip(&ts)
        .map(|(f, t)| f * t)
        .collect();
    let prelude = format!("alias real = f64;\n{functions}");
    let run = |part: &str| {
        eval_with(
            &ctx,
            &prelude,
            &format!("two_sum(x, y).{part}"),
            &ts,
            &steps,
        )
    };
    let (sums, errors) = (run("x"), run("y"));
    let mut nonzero = 0;
    for i in 0..n {
        let (s, e) = two_sum(ts[i], steps[i]);
        assert_eq!(
            sums[i].to_bits(),
            s.to_bits(),
            "sum of {} + {}",
            ts[i],
            steps[i]
        );
        assert_eq!(
            errors[i].to_bits(),
            e.to_bits(),
            "error of {} + {}",
            ts[i],
            steps[i]
        );
        nonzero += usize::from(e != 0.0);
    }
    // Nearly every case has a remainder (the sums are rarely exact): the test sees the fold.
    assert!(nonzero > n * 9 / 10, "{nonzero} of {n} remainders nonzero");
}
