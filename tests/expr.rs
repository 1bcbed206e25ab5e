//! Tests of the scene-file expression parser (`roughlub::expr`): evaluation against the same
//! formulas written in Rust, precedence, error positions, dependence queries, and WGSL generation
//! validated with naga.

mod common;

use std::f64::consts::{E, PI};

use roughlub::expr::{BinOp, Expr, Node, WgslFloat};

/// Sample points (x, t).
const POINTS: [(f64, f64); 7] = [
    (0.0, 0.0),
    (0.25, 0.1),
    (0.5, 1.0),
    (0.9, 2.5),
    (1.7, 0.03),
    (0.123456789, 17.25),
    (3.0, 0.5),
];

/// Relative tolerance for evaluation against the Rust formula.
const REL_TOL: f64 = 1e-14;

fn assert_close(got: f64, want: f64, rel: f64, what: &str) {
    if want.is_nan() {
        assert!(got.is_nan(), "{what}: got {got}, want NaN");
        return;
    }
    if want.is_infinite() {
        assert_eq!(got, want, "{what}");
        return;
    }
    let tol = rel * want.abs().max(f64::MIN_POSITIVE);
    assert!(
        (got - want).abs() <= tol,
        "{what}: got {got:e}, want {want:e} (|diff| = {:e} > {tol:e})",
        (got - want).abs()
    );
}

fn parse(src: &str) -> Expr {
    Expr::parse(src).unwrap_or_else(|e| panic!("{src:?} should parse: {e}"))
}

#[test]
fn evaluates_like_the_same_formula_in_rust() {
    type F = fn(f64, f64) -> f64;
    let cases: Vec<(&str, F)> = vec![
        ("0.3*sin(2*pi*x)*cos(3*t)", |x, t| {
            0.3 * (2.0 * PI * x).sin() * (3.0 * t).cos()
        }),
        ("0.6+0.2*exp(-(x-0.5)^2/(2*0.1^2))", |x, _| {
            0.6 + 0.2 * (-(x - 0.5).powf(2.0) / (2.0 * 0.1f64.powf(2.0))).exp()
        }),
        ("0.7", |_, _| 0.7),
        ("-x^2", |x, _| -(x.powf(2.0))),
        ("1e-3*max(x, 0.5)", |x, _| 1e-3 * x.max(0.5)),
        ("sqrt(abs(x - 1)) + log(1 + t)", |x, t| {
            (x - 1.0).abs().sqrt() + (1.0 + t).ln()
        }),
        ("tanh((x - 0.5) / 0.1) * exp(-t)", |x, t| {
            ((x - 0.5) / 0.1).tanh() * (-t).exp()
        }),
        ("tan(x/3) - 2.5E+1*t/(1+x^2)", |x, t| {
            (x / 3.0).tan() - 2.5e1 * t / (1.0 + x.powf(2.0))
        }),
        ("min(x, t)^3 - 4/(1+t)", |x, t| {
            x.min(t).powf(3.0) - 4.0 / (1.0 + t)
        }),
        ("x^t", |x, t| x.powf(t)),
        ("e^(-t) * cos(pi*x)", |x, t| E.powf(-t) * (PI * x).cos()),
        ("+x - -t", |x, t| x - -t),
        ("2^-x * .5 + 5.*t", |x, t| 2f64.powf(-x) * 0.5 + 5.0 * t),
        ("  x*x*x / (t + 1) - x/t/2  ", |x, t| {
            x * x * x / (t + 1.0) - x / t / 2.0
        }),
        ("log(x - 1)", |x, _| (x - 1.0).ln()),
    ];
    for (src, f) in cases {
        let expr = parse(src);
        assert_eq!(expr.source(), src);
        for (x, t) in POINTS {
            assert_close(
                expr.eval(x, t),
                f(x, t),
                REL_TOL,
                &format!("{src} at x={x}, t={t}"),
            );
        }
    }
}

#[test]
fn precedence_and_associativity() {
    let cases = [
        ("2^3^2", 512.0),
        ("-2^2", -4.0),
        ("2*3+4", 10.0),
        ("2+3*4", 14.0),
        ("(1+2)*3", 9.0),
        ("8/2/2", 2.0),
        ("8-2-2", 4.0),
        ("2^-1", 0.5),
        ("2^-1^2", 0.5),
        ("-2^-2", -0.25),
        ("(-2)^2", 4.0),
        ("2*-3", -6.0),
        ("--3", 3.0),
        ("-+-3", 3.0),
        ("1e-3", 1e-3),
        ("2.5E+4", 2.5e4),
        ("3e2", 300.0),
        ("max(1, 2) * min(3, 4)", 6.0),
        ("(((7)))", 7.0),
    ];
    for (src, want) in cases {
        // Exact: every case is exactly representable and computed exactly.
        assert_eq!(parse(src).eval(0.3, 0.7), want, "{src}");
    }
    // Structure: -x^2 is -(x^2).
    assert_eq!(
        parse("-x^2").root(),
        &Node::Neg(Box::new(Node::Bin(
            BinOp::Pow,
            Box::new(Node::X),
            Box::new(Node::Num(2.0))
        )))
    );
    // x^t^2 is x^(t^2) (checked at a point where the two readings differ by far).
    assert_close(parse("x^t^2").eval(2.0, 3.0), 512.0, 1e-15, "x^t^2");
}

#[test]
fn constants_are_folded() {
    assert_eq!(parse("pi").root(), &Node::Num(PI));
    assert_eq!(parse("e").root(), &Node::Num(E));
    assert_eq!(parse("2*pi").root(), &Node::Num(2.0 * PI));
    assert_eq!(parse("-(1+2)").root(), &Node::Num(-3.0));
    assert_eq!(
        parse("x*(2*pi)").root(),
        &Node::Bin(BinOp::Mul, Box::new(Node::X), Box::new(Node::Num(2.0 * PI)))
    );
}

fn parse_err(src: &str) -> roughlub::expr::ExprError {
    match Expr::parse(src) {
        Ok(e) => panic!("{src:?} should not parse, got {:?}", e.root()),
        Err(e) => e,
    }
}

#[test]
fn errors_report_position_and_cause() {
    let e = parse_err("0.3*sinn(x)");
    assert_eq!(e.position, 4, "{e}");
    assert!(e.message.contains("sinn"), "{e}");
    assert!(e.message.contains("sin,"), "lists the known names: {e}");
    assert_eq!(e.to_string(), format!("at position 4: {}", e.message));

    let e = parse_err("(x+1");
    assert_eq!(e.position, 0, "{e}");
    assert!(e.message.contains("unclosed"), "{e}");

    let e = parse_err("sin(x");
    assert_eq!(e.position, 3, "{e}");
    assert!(e.message.contains("unclosed"), "{e}");

    let e = parse_err("(x+1 2");
    assert_eq!(e.position, 5, "{e}");
    assert!(e.message.contains("expected ')'"), "{e}");

    let e = parse_err("x+1)");
    assert_eq!(e.position, 3, "{e}");
    assert!(e.message.contains("unmatched"), "{e}");

    let e = parse_err("x+");
    assert_eq!(e.position, 2, "{e}");
    assert!(e.message.contains("end of input"), "{e}");

    let e = parse_err("1.2.3");
    assert_eq!(e.position, 0, "{e}");
    assert!(e.message.contains("1.2.3"), "{e}");

    for src in ["1e", "2*1e+", "1e-x"] {
        let e = parse_err(src);
        assert!(e.message.contains("exponent"), "{src}: {e}");
    }
    let e = parse_err("2*1e+");
    assert_eq!(e.position, 2, "{e}");

    let e = parse_err("3*1e400");
    assert_eq!(e.position, 2, "{e}");
    assert!(e.message.contains("range"), "{e}");

    for src in ["", "   "] {
        let e = parse_err(src);
        assert_eq!(e.position, 0, "{src:?}: {e}");
        assert!(e.message.contains("empty"), "{src:?}: {e}");
    }

    let e = parse_err("max(x)");
    assert_eq!(e.position, 0, "{e}");
    assert!(e.message.contains("max"), "{e}");
    assert!(e.message.contains("2 arguments"), "{e}");

    let e = parse_err("1 + sin(x, t)");
    assert_eq!(e.position, 4, "{e}");
    assert!(e.message.contains("'sin' takes 1 argument,"), "{e}");

    let e = parse_err("cos()");
    assert_eq!(e.position, 0, "{e}");
    assert!(e.message.contains("got 0"), "{e}");

    let e = parse_err("sin x");
    assert_eq!(e.position, 4, "{e}");
    assert!(e.message.contains("'('"), "{e}");

    let e = parse_err("x $ 2");
    assert_eq!(e.position, 2, "{e}");
    assert!(e.message.contains('$'), "{e}");

    let e = parse_err("2 x");
    assert_eq!(e.position, 2, "{e}");

    let e = parse_err("X + 1");
    assert_eq!(e.position, 0, "{e}");
    assert!(e.message.contains("'X'"), "{e}");

    let e = parse_err("x * * 2");
    assert_eq!(e.position, 4, "{e}");

    let e = parse_err("min(x,)");
    assert_eq!(e.position, 6, "{e}");

    // Positions count characters, not bytes (U+00A0 is whitespace, two bytes in UTF-8).
    let e = parse_err("x\u{a0}$");
    assert_eq!(e.position, 2, "{e}");
}

#[test]
fn deep_nesting_is_an_error_not_a_crash() {
    let n = 100_000;
    let deep_parens = format!("{}x{}", "(".repeat(n), ")".repeat(n));
    let deep_minus = format!("{}x", "-".repeat(n));
    let long_sum = format!("{}x", "x+".repeat(n));
    let long_pow = format!("{}x", "x^".repeat(n));
    for src in [&deep_parens, &deep_minus, &long_sum, &long_pow] {
        let e = parse_err(src);
        assert!(e.message.contains("too deeply"), "{e}");
    }
    // Moderate nesting is fine, and long constant chains fold.
    let ok = format!("{}x{}", "(".repeat(200), ")".repeat(200));
    assert_eq!(parse(&ok).eval(1.5, 0.0), 1.5);
    let ones = format!("{}1", "1+".repeat(n));
    assert_eq!(parse(&ones).constant_value(), Some((n + 1) as f64));
}

#[test]
fn dependence_and_constant_value() {
    let e = parse("0.3*sin(2*pi*x)*cos(3*t)");
    assert!(e.uses_x() && e.uses_t());
    assert_eq!(e.constant_value(), None);

    let e = parse("0.7");
    assert!(!e.uses_x() && !e.uses_t());
    assert_eq!(e.constant_value(), Some(0.7));

    let e = parse("sin(t) + 2");
    assert!(!e.uses_x() && e.uses_t());
    assert_eq!(e.constant_value(), None);

    let e = parse("max(x, 0.5)");
    assert!(e.uses_x() && !e.uses_t());

    // No symbolic simplification: x - x depends on x.
    let e = parse("x - x");
    assert!(e.uses_x());
    assert_eq!(e.constant_value(), None);

    assert_eq!(parse("2*pi").constant_value(), Some(2.0 * PI));
    assert_eq!(parse("exp(1) - e").constant_value(), Some(1f64.exp() - E));
    assert_eq!(
        parse("sqrt(2)^2").constant_value(),
        Some(2f64.sqrt().powf(2.0))
    );
    assert!(parse("log(-1)").constant_value().unwrap().is_nan());
    assert_eq!(parse("1/0").constant_value(), Some(f64::INFINITY));
}

#[test]
fn from_str_display_and_serde() {
    let e: Expr = "x + 1".parse().unwrap();
    assert_eq!(e.to_string(), "x + 1");
    let json = serde_json::to_string(&e).unwrap();
    assert_eq!(json, "\"x + 1\"");
    let back: Expr = serde_json::from_str(&json).unwrap();
    assert_eq!(back, e);
    let c: Expr = serde_json::from_str("0.25").unwrap();
    assert_eq!(c.constant_value(), Some(0.25));
    let c: Expr = serde_json::from_str("3").unwrap();
    assert_eq!(c.constant_value(), Some(3.0));
    let bad = serde_json::from_str::<Expr>("\"sinn(x)\"").unwrap_err();
    assert!(bad.to_string().contains("sinn"), "{bad}");
}

// ---------------------------------------------------------------------------------------------
// WGSL

/// Expressions covering every node kind, function and power case of the WGSL generator.
const WGSL_CASES: [&str; 16] = [
    "0.3*sin(2*pi*x)*cos(3*t)",
    "0.6+0.2*exp(-(x-0.5)^2/(2*0.1^2))",
    "0.7",
    "-0.7",
    "-x^2",
    "1e-3*max(x, 0.5) - min(t, -2)",
    "tan(x) + log(t) + sqrt(x) + abs(t) + tanh(x)",
    "x^0 + x^1 + x^3 + x^-2 + (x+t)^16 + x^-16",
    "x^2.5 + x^t + 2^x + x^17 + x^-20 + x^1e9",
    "x - -t - (-1)",
    "1/0 * x + log(-1) * t - (-1/0)",
    "1e300 * x + 1e-300 * t",
    "5e-324 * x",
    "x^(2^-1)",
    "-(x)",
    "-(-x)",
];

fn f64_stub(name: &str) -> String {
    if name == "pow_f64" {
        format!("fn {name}(a: f64, b: f64) -> f64 {{ return a; }}\n")
    } else {
        format!("fn {name}(a: f64) -> f64 {{ return a; }}\n")
    }
}

/// Parses and validates `source` with naga (f64 capability on), panicking with naga's report.
fn validate_wgsl(source: &str) -> naga::Module {
    let module = naga::front::wgsl::parse_str(source)
        .unwrap_or_else(|e| panic!("naga cannot parse:\n{source}\n{}", e.emit_to_string(source)));
    naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::FLOAT64,
    )
    .validate(&module)
    .unwrap_or_else(|e| {
        panic!(
            "naga rejects:\n{source}\n{}",
            e.emit_to_string_with_path(source, "generated.wgsl")
        )
    });
    module
}

/// Module for `expr` at the given precision: the `*_f64` stubs it needs, then the function.
fn wgsl_module(expr: &Expr, float: WgslFloat) -> String {
    let mut src = String::new();
    if float == WgslFloat::F64 {
        for name in expr.wgsl_f64_functions_used() {
            src.push_str(&f64_stub(name));
        }
    }
    src.push_str(&expr.to_wgsl(float, "profile"));
    src
}

#[test]
fn generated_wgsl_validates_with_naga() {
    for src in WGSL_CASES {
        let expr = parse(src);
        for float in [WgslFloat::F32, WgslFloat::F64] {
            let code = expr.to_wgsl(float, "profile");
            let ty = if float == WgslFloat::F32 {
                "f32"
            } else {
                "f64"
            };
            assert!(
                code.starts_with(&format!("fn profile(x: {ty}, t: {ty}) -> {ty} {{")),
                "{code}"
            );
            assert!(!code.contains("--"), "{code}");
            let module = validate_wgsl(&wgsl_module(&expr, float));
            assert!(
                module
                    .functions
                    .iter()
                    .any(|(_, f)| f.name.as_deref() == Some("profile")),
                "{src}"
            );
        }
    }
}

#[test]
fn generated_wgsl_uses_f64_library_only_where_needed() {
    let e = parse("sin(x) + exp(t) * x^t + sqrt(x) + abs(t) + min(x, t) + max(x, t) + x^3");
    assert_eq!(
        e.wgsl_f64_functions_used(),
        ["exp_f64", "pow_f64", "sin_f64"]
    );
    let f64_code = e.to_wgsl(WgslFloat::F64, "f");
    for call in [
        "sin_f64(x)",
        "exp_f64(t)",
        "pow_f64(x, t)",
        "sqrt(x)",
        "abs(t)",
        "min(x, t)",
    ] {
        assert!(f64_code.contains(call), "{call} in {f64_code}");
    }
    assert!(f64_code.contains("(x*x*x)"), "{f64_code}");
    let f32_code = e.to_wgsl(WgslFloat::F32, "f");
    assert!(!f32_code.contains("_f64"), "{f32_code}");
    for call in ["sin(x)", "exp(t)", "pow(x, t)", "(x*x*x)"] {
        assert!(f32_code.contains(call), "{call} in {f32_code}");
    }

    let e = parse("cos(x) + tan(x) + log(x) + tanh(x) + x^0.5");
    assert_eq!(
        e.wgsl_f64_functions_used(),
        ["cos_f64", "log_f64", "pow_f64", "tan_f64", "tanh_f64"]
    );
    // Repeated calls are listed once; unrolled powers and builtins not at all.
    assert_eq!(
        parse("sin(x)*sin(t)").wgsl_f64_functions_used(),
        ["sin_f64"]
    );
    assert!(parse("x^-16 + sqrt(abs(x)) + max(x, t)")
        .wgsl_f64_functions_used()
        .is_empty());
    assert!(
        parse("2^0.5").wgsl_f64_functions_used().is_empty(),
        "folded"
    );

    let code = parse("x^-2").to_wgsl(WgslFloat::F64, "f");
    assert!(code.contains("return (1.0lf / (x*x));"), "{code}");
    // Larger integer powers: |a| to the power, sign restored for odd exponents.
    let code = parse("x^17 + t^-20").to_wgsl(WgslFloat::F64, "f");
    assert!(code.contains("(x * pow_f64(abs(x), 16.0lf))"), "{code}");
    assert!(code.contains("pow_f64(abs(t), (-20.0lf))"), "{code}");
    let code = parse("x^-17").to_wgsl(WgslFloat::F32, "f");
    assert!(code.contains("(x * pow(abs(x), (-18.0f)))"), "{code}");
    let code = parse("-0.5*x").to_wgsl(WgslFloat::F32, "f");
    assert!(code.contains("return ((-0.5f) * x);"), "{code}");
}

/// All float literals in all functions of `module`, as f64.
fn float_literals(module: &naga::Module) -> Vec<f64> {
    let mut out = Vec::new();
    let mut take = |e: &naga::Expression| match *e {
        naga::Expression::Literal(naga::Literal::F64(v)) => out.push(v),
        naga::Expression::Literal(naga::Literal::F32(v)) => out.push(v as f64),
        _ => {}
    };
    for (_, f) in module.functions.iter() {
        f.expressions.iter().for_each(|(_, e)| take(e));
    }
    module.global_expressions.iter().for_each(|(_, e)| take(e));
    out
}

#[test]
fn wgsl_constants_are_exact() {
    let values = [
        0.1,
        0.3,
        2.0 * PI,
        1.0 / 3.0,
        1e-300,
        1.7976931348623157e308,
        5e-324,
        123_456_789.123_456_79,
        0.6,
        2.5e4,
    ];
    let src = values
        .iter()
        .enumerate()
        .map(|(k, v)| format!("{v:e}*{}", if k % 2 == 0 { "x" } else { "t" }))
        .collect::<Vec<_>>()
        .join(" + ");
    let expr = parse(&format!("{src} - 0.3"));

    let module = validate_wgsl(&wgsl_module(&expr, WgslFloat::F64));
    let lits = float_literals(&module);
    for v in values {
        assert!(
            lits.iter().any(|l| l.to_bits() == v.to_bits()),
            "f64 literal {v:e} is not exact in the module: {lits:?}"
        );
    }

    // f32: the f64 value rounded to f32, exactly (values beyond f32's range are skipped).
    let module = validate_wgsl(&wgsl_module(&expr, WgslFloat::F32));
    let lits = float_literals(&module);
    for v in values
        .iter()
        .map(|&v| v as f32)
        .filter(|v| v.is_finite() && *v != 0.0)
    {
        assert!(
            lits.iter().any(|&l| (l as f32).to_bits() == v.to_bits()),
            "f32 literal {v:e} is not exact in the module: {lits:?}"
        );
    }

    // Negative constants come out negative (in parentheses in the text).
    let expr = parse("-0.1*x + (-2)*t");
    let code = expr.to_wgsl(WgslFloat::F64, "f");
    assert!(
        code.contains("(-0.1lf)") && code.contains("(-2.0lf)"),
        "{code}"
    );
    let lits = float_literals(&validate_wgsl(&code));
    for v in [-0.1, -2.0] {
        assert!(lits.contains(&v) || lits.contains(&-v), "{v} in {lits:?}");
    }
}

// ---------------------------------------------------------------------------------------------
// GPU: the generated WGSL computes what `Expr::eval` computes (skipped without an adapter, fails
// then under ROUGHLUB_REQUIRE_GPU=1; lavapipe is enough).

/// Expressions and sample points for the GPU comparison (finite, moderate values).
const GPU_CASES: [&str; 11] = [
    "0.3*sin(2*pi*x)*cos(3*t)",
    "0.6+0.2*exp(-(x-0.5)^2/(2*0.1^2))",
    "0.7",
    "-x^2 + 1e-3*max(x, 0.5) - min(t, 0.25)",
    "tan(x/3) + log(1 + t) + sqrt(abs(x)) + tanh(x - t)",
    "x^0 + x^1 + x^3 + (x-t)^5 + (x+2)^-2 + (x-1)^16 + (x+3)^-16",
    "abs(x)^2.5 + (1+t)^x + 2^x",
    "(x/2)^17 + (x-1.7)^-20 + (x+2)^-21 + (x-2)^18 + 1.01^(-t)",
    "x - -t - (-1) + -(-x)",
    "exp(-t) * cos(pi*x) - e^-x",
    "abs(x)^(2^-1) + abs(x)^(1/3)",
];

/// Constants outside f32's range: f64 only.
const GPU_F64_ONLY_CASES: [&str; 2] = [
    "1e300 * x * 1e-300 + 5e-324 / 5e-324",
    "x * 1e-300 * 1e300 - 1.7976931348623157e308 / 1e308",
];

/// Non-finite constants (1/0, log(-1)) must reach the output.
const GPU_NON_FINITE_CASES: [&str; 3] = ["1/0 + x", "log(-1) * t", "-1/0 * (2 + x)"];

/// Whether `got` is within `tol` of `want`, or both are the same infinity, or both NaN.
fn gpu_agrees(got: f64, want: f64, tol: f64) -> bool {
    if want.is_finite() {
        (got - want).abs() <= tol
    } else {
        got == want || (got.is_nan() && want.is_nan())
    }
}

fn gpu_points() -> (Vec<f64>, Vec<f64>) {
    let n = 256;
    let xs = (0..n)
        .map(|i| -1.0 + 2.5 * (i as f64 + 0.5) / n as f64)
        .collect();
    let ts = (0..n).map(|i| 0.37 * ((i * 7) % 29) as f64).collect();
    (xs, ts)
}

fn gpu_kernel(body: &str, ty: &str) -> String {
    format!(
        "@group(0) @binding(0) var<storage, read> xs: array<{ty}>;\n\
         @group(0) @binding(1) var<storage, read> ts: array<{ty}>;\n\
         @group(0) @binding(2) var<storage, read_write> out: array<{ty}>;\n\
         {body}\n\
         @compute @workgroup_size(64)\n\
         fn main(@builtin(global_invocation_id) id: vec3<u32>) {{\n\
             let i = id.x;\n\
             if (i < arrayLength(&out)) {{ out[i] = profile(xs[i], ts[i]); }}\n\
         }}\n"
    )
}

#[test]
fn generated_wgsl_f64_matches_eval_on_gpu() {
    let Some(ctx) = common::gpu::acquire_for_tests(true) else {
        return;
    };
    let (xs, ts) = gpu_points();
    let cases = GPU_CASES
        .iter()
        .chain(&GPU_F64_ONLY_CASES)
        .chain(&GPU_NON_FINITE_CASES);
    for src in cases {
        let expr = parse(src);
        // The whole f64 library, so that its functions are exercised as the solver will use them.
        let body = format!(
            "{}\n{}",
            roughlub::backend::gpu::F64_MATH_WGSL,
            expr.to_wgsl(WgslFloat::F64, "profile")
        );
        let kernel = gpu_kernel(&body, "f64");
        let got = common::gpu::run_compute_f64(
            &ctx,
            &kernel,
            "main",
            &[&xs, &ts],
            xs.len(),
            xs.len().div_ceil(64) as u32,
        )
        .unwrap_or_else(|e| panic!("{src}: {e}"));
        for (i, (&x, &t)) in xs.iter().zip(&ts).enumerate() {
            let want = expr.eval(x, t);
            // A few ulp per library call and per unrolled multiplication, amplified by at most
            // ~1e2 by cancellation in these expressions.
            let tol = 1e-13 * want.abs().max(1.0);
            assert!(
                gpu_agrees(got[i], want, tol),
                "{src} at x={x}, t={t}: gpu {:e}, cpu {want:e}",
                got[i]
            );
        }
    }
}

#[test]
fn generated_wgsl_f32_matches_eval_on_gpu() {
    let Some(ctx) = common::gpu::acquire_for_tests(false) else {
        return;
    };
    let (xs, ts) = gpu_points();
    let xs32: Vec<f32> = xs.iter().map(|&v| v as f32).collect();
    let ts32: Vec<f32> = ts.iter().map(|&v| v as f32).collect();
    for src in GPU_CASES.iter().chain(&GPU_NON_FINITE_CASES) {
        let expr = parse(src);
        let kernel = gpu_kernel(&expr.to_wgsl(WgslFloat::F32, "profile"), "f32");
        let bytes = common::gpu::run_compute_raw(
            &ctx,
            src,
            &kernel,
            "main",
            &[bytemuck::cast_slice(&xs32), bytemuck::cast_slice(&ts32)],
            (xs.len() * 4) as u64,
            [xs.len().div_ceil(64) as u32, 1, 1],
        )
        .unwrap_or_else(|e| panic!("{src}: {e}"));
        let got: Vec<f32> = bytemuck::pod_collect_to_vec(&bytes);
        for (i, (&x, &t)) in xs32.iter().zip(&ts32).enumerate() {
            // Reference at the f32 inputs, evaluated in f64.
            let want = expr.eval(x as f64, t as f64);
            let g = got[i] as f64;
            // f32 arithmetic and builtins (WGSL allows a few ulp, more for pow/exp of large
            // arguments), amplified by cancellation.
            let tol = 1e-4 * want.abs().max(1.0);
            assert!(
                gpu_agrees(g, want, tol),
                "{src} at x={x}, t={t}: gpu {g:e}, cpu {want:e}"
            );
        }
    }
}
