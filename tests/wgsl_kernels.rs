//! The generated WGSL step kernel (`shaders/step.wgsl` via `roughlub::backend::gpu::kernel`):
//! CPU only: every combination of precision × repulsion × clusters × forcing × time scheme
//! (order 1/2, fixed/adaptive) — every specialisation the plan can produce — parses and
//! validates with naga, and absent terms leave no code behind.
//! The GPU kernel's results against the CPU are in tests/gpu_solver.rs.

use roughlub::backend::gpu::kernel::{generate_step_wgsl, GammaSpec, KernelSpec, SchemeSpec};
use roughlub::backend::gpu::validate_wgsl;
use roughlub::backend::Precision;
use roughlub::expr::Expr;
use roughlub::model::params::{Order, MAX_ORDER};
use roughlub::model::quadrature::GaussLegendre;

const FORCING: &str = "0.3*sin(2*pi*x)*cos(3*t)";

fn forcing_spec(points: usize) -> (Expr, Vec<f64>, Vec<f64>) {
    let rule = GaussLegendre::new(points);
    (Expr::parse(FORCING).unwrap(), rule.nodes, rule.weights)
}

#[test]
fn every_variant_validates_and_omits_absent_terms() {
    let repulsions = [
        None,
        Some(GammaSpec::Integer(1)),
        Some(GammaSpec::Integer(2)),
        Some(GammaSpec::Integer(7)),
        Some(GammaSpec::PerMember),
    ];
    for precision in [Precision::F32, Precision::F64] {
        for repulsion in repulsions {
            for clusters in [false, true] {
                for forced in [false, true] {
                    for (order, adaptive) in [
                        (Order::Fixed(1), false),
                        (Order::Fixed(2), false),
                        (Order::Fixed(6), false),
                        (Order::Fixed(1), true),
                        (Order::Fixed(4), true),
                        (Order::Auto, true),
                    ] {
                        let scheme = SchemeSpec::of(order, adaptive);
                        let spec = KernelSpec {
                            precision,
                            repulsion,
                            clusters,
                            forcing: forced.then(|| forcing_spec(3)),
                            scheme,
                        };
                        let label = format!("{spec:?}");
                        let src = generate_step_wgsl(&spec);
                        if let Err(e) = validate_wgsl("step.wgsl", &src) {
                            panic!("{label}: {e}\n{src}");
                        }
                        for entry in [
                            "fn begin_interval(",
                            "fn advance(",
                            "fn gather(",
                            "fn euler(",
                        ] {
                            assert!(src.contains(entry), "{label}: {entry}");
                        }
                        assert!(!src.contains("//@"), "{label}: leftover marker");
                        // The code without its comments.
                        let src: String = src
                            .lines()
                            .map(|l| l.split("//").next().unwrap())
                            .collect::<Vec<_>>()
                            .join("\n");
                        assert_eq!(src.contains("dstar"), repulsion.is_some(), "{label}");
                        assert_eq!(src.contains("fn power("), repulsion.is_some(), "{label}");
                        assert_eq!(src.contains("bonded"), clusters, "{label}");
                        // Without clusters no trace of the wall-glued bodies' loop.
                        assert_eq!(src.contains("bonded[i * batch + b]"), clusters, "{label}");
                        assert_eq!(src.contains("particle_force"), forced, "{label}");
                        assert_eq!(src.contains("fn forcing("), forced, "{label}");
                        let real = match precision {
                            Precision::F32 => "alias real = f32;",
                            Precision::F64 => "alias real = f64;",
                        };
                        assert!(src.contains(real), "{label}");
                        // The f64 library in every f64 kernel (the gap update is exp, log-stored
                        // gaps need ln), never in f32 ones.
                        let needs_lib = precision == Precision::F64;
                        assert_eq!(src.contains("fn exp_f64("), needs_lib, "{label}");
                        // Only the scheme asked for: one Euler step, or the tableau (+ the
                        // step control from its estimates, + the order selection).
                        assert_eq!(
                            src.contains("= extrapolate(b, cand, rows)"),
                            order != Order::Fixed(1) || adaptive,
                            "{label}"
                        );
                        assert_eq!(
                            src.contains("euler(b, cur, cand, h, c.t, p)"),
                            order == Order::Fixed(1) && !adaptive,
                            "{label}"
                        );
                        assert_eq!(src.contains("err = scaled[rows]"), adaptive, "{label}");
                        assert_eq!(
                            src.contains("= select_order(k, scaled"),
                            order == Order::Auto,
                            "{label}"
                        );
                        let extrapolates =
                            format!("const EXTRAPOLATES: bool = {};", order != Order::Fixed(1));
                        assert!(src.contains(&extrapolates), "{label}");
                    }
                }
            }
        }
    }
}

#[test]
fn integer_power_is_the_square_and_multiply_chain() {
    let spec = |n| KernelSpec {
        precision: Precision::F64,
        repulsion: Some(GammaSpec::Integer(n)),
        clusters: false,
        forcing: None,
        scheme: SchemeSpec::of(Order::Fixed(1), false),
    };
    // 7 = 0b111: result = r; base = r^2; result *= base; base = r^4; result *= base.
    let src = generate_step_wgsl(&spec(7));
    assert_eq!(src.matches("base = base * base;").count(), 2);
    assert_eq!(src.matches("result = result * base;").count(), 2);
    let src = generate_step_wgsl(&spec(1));
    assert_eq!(src.matches("base = base * base;").count(), 0);
    assert!(validate_wgsl("step0", &generate_step_wgsl(&spec(0))).is_ok());
}

/// The partitioned kernel (`shaders/partitioned.wgsl` after the step kernel) for every
/// precision × repulsion × clusters × forcing × scheme: validates with naga, has every entry
/// point its sequence of dispatches names, no leftover marker, and the glued-bodies buffer only
/// with clusters; its GPU-only structs have a size.
#[test]
fn every_partitioned_variant_validates() {
    use roughlub::backend::gpu::kernel::generate_partitioned_wgsl;
    use roughlub::backend::gpu::partitioned::{entry_points, struct_size};
    for precision in [Precision::F32, Precision::F64] {
        for repulsion in [
            None,
            Some(GammaSpec::Integer(2)),
            Some(GammaSpec::PerMember),
        ] {
            for clusters in [false, true] {
                for forced in [false, true] {
                    for (order, adaptive) in [
                        (Order::Fixed(1), false),
                        (Order::Fixed(6), false),
                        (Order::Fixed(1), true),
                        (Order::Fixed(2), true),
                        (Order::Auto, true),
                    ] {
                        let scheme = SchemeSpec::of(order, adaptive);
                        let spec = KernelSpec {
                            precision,
                            repulsion,
                            clusters,
                            forcing: forced.then(|| forcing_spec(3)),
                            scheme,
                        };
                        let label = format!("{spec:?}");
                        let src = generate_partitioned_wgsl(&spec);
                        let module = match validate_wgsl("partitioned.wgsl", &src) {
                            Ok(m) => m,
                            Err(e) => panic!("{label}: {e}"),
                        };
                        for entry in entry_points(scheme, forced) {
                            assert!(
                                module.entry_points.iter().any(|e| e.name == entry),
                                "{label}: no entry point {entry}"
                            );
                        }
                        assert!(!src.contains("//@"), "{label}: leftover marker");
                        assert_eq!(
                            src.contains("var<storage, read> glued"),
                            clusters,
                            "{label}"
                        );
                        let real = match precision {
                            Precision::F32 => 4,
                            Precision::F64 => 8,
                        };
                        // Seg: 17 reals, the estimates by column (MAX_ORDER + 1) and 4 u32;
                        // PState: 7 reals, three arrays by column and 20 u32. The shader writes
                        // those arrays with literals: this ties them to MAX_ORDER.
                        let columns = u64::from(MAX_ORDER) + 1;
                        assert_eq!(
                            struct_size(&module, "Seg"),
                            Some((17 + columns) * real + 16),
                            "{label}"
                        );
                        assert_eq!(
                            struct_size(&module, "PState"),
                            Some((7 + 3 * columns) * real + 20 * 4),
                            "{label}"
                        );
                        assert!(
                            src.contains(&format!("const MAX_ORDER: u32 = {MAX_ORDER}u;"))
                                && src.contains(&format!("array<real, {MAX_ORDER}>"))
                                && src.contains(&format!("array<real, {columns}>")),
                            "{label}: the tableau's arrays are not sized for MAX_ORDER = {MAX_ORDER}"
                        );
                    }
                }
            }
        }
    }
}
