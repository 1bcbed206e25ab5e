//! The CPU backend in f32 (`CpuSolver::with_precision(.., Precision::F32)`, the twin of the GPU's
//! f32 kernel) against the CPU in f64: within the rounding bound the GPU f32 test derives
//! (tests/gpu_solver.rs `f32_agrees_with_f64_within_the_derived_tolerance`), scaled by the
//! extrapolation's amplification of rounding for orders above 1, far below the scheme's error at
//! order 1; adaptive f32 as accurate as adaptive f64 against an independent reference.

use roughlub::backend::cpu::CpuSolver;
use roughlub::backend::shared::control::top_column;
use roughlub::backend::{BatchSolver, MemberReport, MemberStatus, Precision};
use roughlub::expr::Expr;
use roughlub::model::chain::Chain;
use roughlub::model::observables::Snapshot;
use roughlub::model::params::{MemberParams, Order, OutputFields, Stepping};
use roughlub::model::plan::Plan;
use roughlub::scene::initial::chain_from_profiles;

fn profile_chain(n: usize, rho: &str, u: &str, rho_star: &str) -> Chain {
    chain_from_profiles(
        n,
        &Expr::parse(rho).unwrap(),
        &Expr::parse(u).unwrap(),
        Some(&Expr::parse(rho_star).unwrap()),
    )
    .unwrap()
}

fn plan(chain: &Chain, members: Vec<MemberParams>, order: Order, stepping: Stepping) -> Plan {
    Plan {
        particles: chain.particles(),
        eps: chain.eps,
        repulsion: true,
        clusters: false,
        forcing: None,
        order,
        stepping,
        members,
        output_times: vec![0.0, 0.1, 0.2],
        fields: OutputFields::all(),
        grid: 16,
        companion_estimate: false,
        jacobian: Default::default(),
        sequence: Default::default(),
        peak_centre: false,
        energy_sums: true,
        overrides: Default::default(),
    }
}

/// gamma in {1, 2, 5, 20} × mu in {0.01, 0.005, 0.02, 0.001}.
fn sweep() -> Vec<MemberParams> {
    let mut members = Vec::new();
    for gamma in [1.0, 2.0, 5.0, 20.0] {
        for mu in [0.01, 0.005, 0.02, 0.001] {
            members.push(MemberParams { mu, gamma });
        }
    }
    members
}

/// The two scenes of the GPU f32 test: paper case 1 over the sweep, and a dense chain
/// (rho0 = 0.99) at gamma 20.
fn scenes() -> Vec<(&'static str, Chain, Vec<MemberParams>)> {
    vec![
        (
            "case 1 sweep",
            profile_chain(200, "0.7", "0.5*sin(2*pi*x)", "0.7"),
            sweep(),
        ),
        (
            "dense rho0 = 0.99, gamma 20",
            profile_chain(200, "0.99", "0.05*sin(2*pi*x)", "0.99"),
            vec![
                MemberParams {
                    mu: 1e-3,
                    gamma: 20.0,
                },
                MemberParams {
                    mu: 1e-2,
                    gamma: 20.0,
                },
            ],
        ),
    ]
}

fn run(
    plan: &Plan,
    chain: &Chain,
    precision: Precision,
) -> (Vec<Vec<Snapshot>>, Vec<MemberReport>) {
    let chains = vec![chain.clone(); plan.members.len()];
    let mut solver = CpuSolver::with_precision(plan.clone(), chains, precision);
    let mut out = Vec::new();
    while let Some(s) = solver.next_output(&|_| {}).unwrap() {
        out.push(s);
    }
    (out, solver.reports())
}

/// Largest |a - b| / max_member |b| over members (each member scaled by its own largest value),
/// for gaps and for velocities, over all output times.
fn max_rel_diff(a: &[Vec<Snapshot>], b: &[Vec<Snapshot>]) -> (f64, f64) {
    assert_eq!(a.len(), b.len());
    let rel = |x: &[f64], y: &[f64]| {
        assert_eq!(x.len(), y.len());
        let scale = y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        x.iter()
            .zip(y)
            .fold(0.0f64, |m, (p, q)| m.max((p - q).abs() / scale))
    };
    let mut worst = (0.0f64, 0.0f64);
    for (sa, sb) in a.iter().zip(b) {
        for (ma, mb) in sa.iter().zip(sb) {
            worst.0 = worst.0.max(rel(&ma.gaps, &mb.gaps));
            worst.1 = worst.1.max(rel(&ma.velocities, &mb.velocities));
        }
    }
    worst
}

/// Σ_j |w_j| n_j for the extrapolation T_kk = Σ_j w_j T_j over the rows n_j = 1..k (harmonic
/// sequence, polynomial in h to 0: w_j = Π_{i≠j} n_j/(n_j − n_i)): how much the rounding of
/// row j (n_j substeps, each rounding like one Euler step) can grow in the extrapolated result.
/// 1 for order 1 (one Euler step), 5 for order 2 (2·T_2 − T_1), 91.3 for order 4.
fn rounding_gain(k: u8) -> f64 {
    if k == 1 {
        return 1.0;
    }
    let k = k as i32;
    (1..=k)
        .map(|j| {
            let w: f64 = (1..=k)
                .filter(|&i| i != j)
                .map(|i| j as f64 / (j - i) as f64)
                .product();
            w.abs() * j as f64
        })
        .sum()
}

/// Fixed steps, orders 1, 2 and 4: f32 within 2·steps·(gamma_max + 1)·u32·gain(k) of f64 (the
/// GPU test's bound: G rounds by gamma ulps, the update and projection by one more, doubled for
/// compounding; the tableau multiplies each row's rounding by its weight), every step accepted
/// in both; at order 1 the f32 difference is also below a tenth of the scheme error (dt vs dt/2).
#[test]
fn f32_agrees_with_f64_within_the_derived_tolerance() {
    let u32_eps = 2f64.powi(-24);
    let dt = 1e-3;
    let steps = 200.0;
    for (label, chain, members) in scenes() {
        let gamma_max = members.iter().fold(1.0f64, |m, p| m.max(p.gamma));
        for k in [1u8, 2, 4] {
            let fixed = Stepping::Fixed { dt, dt_min: 1e-9 };
            let p = plan(&chain, members.clone(), Order::Fixed(k), fixed);
            let (f64_run, r64) = run(&p, &chain, Precision::F64);
            let (f32_run, r32) = run(&p, &chain, Precision::F32);
            for (a, b) in r32.iter().zip(&r64) {
                assert_eq!(a.status, MemberStatus::Ok, "{label} order {k}: {a:?}");
                assert_eq!(
                    (a.steps_accepted, a.steps_rejected),
                    (b.steps_accepted, 0),
                    "{label} order {k}: member {}",
                    a.index
                );
            }
            let tolerance = 2.0 * steps * (gamma_max + 1.0) * u32_eps * rounding_gain(k);
            let (dg, dv) = max_rel_diff(&f32_run, &f64_run);
            eprintln!(
                "{label}, order {k}: f32 vs f64 gaps {dg:.2e}, velocities {dv:.2e}; tolerance {tolerance:.2e}"
            );
            assert!(
                dg <= tolerance && dv <= tolerance,
                "{label} order {k}: {dg:e} {dv:e} > {tolerance:e}"
            );
            if k == 1 {
                let half = Stepping::Fixed {
                    dt: dt / 2.0,
                    dt_min: 1e-9,
                };
                let (f64_half, _) = run(
                    &plan(&chain, members.clone(), Order::Fixed(1), half),
                    &chain,
                    Precision::F64,
                );
                let (sg, sv) = max_rel_diff(&f64_half, &f64_run);
                eprintln!("{label}: scheme error (dt vs dt/2) gaps {sg:.2e}, velocities {sv:.2e}");
                assert!(
                    dg <= 0.1 * sg && dv <= 0.1 * sv,
                    "{label}: f32 error should be far below the scheme error"
                );
            }
        }
    }
}

/// Adaptive steps (order 2, order 4 and auto at tolerance 2e-4, above the f32 floors): every
/// member completes in f32 with the step counts of f64 to 5 % plus 3 steps per member for the
/// fixed orders (the estimates differ by rounding, ~1e-6, far below the tolerance, but one
/// decision taken the other way shifts the sequence; auto in f32 stops at column 4, where its
/// rounding stays 10 times below the tolerance, `top_column`, so it takes more steps than in
/// f64), and its error against an independent reference (f64, order 4, fixed dt = 1e-4) is at
/// most 1.5 times f64's (both held to the same tolerance by step sequences that differ; measured
/// at most 1.21 with the fixed orders; auto's against the larger of f64's auto and order 4, the
/// columns it may take) plus the order-1 rounding bound 2·steps·(gamma_max +
/// 1)·u32 at the steps taken (the rows' rounding is correlated: the fixed-step test at order 4
/// stays within it). Until auto's columns were capped in f32, its high columns' estimates were
/// dominated by amplified rounding and its choices followed it (case 1 at 1e-4: velocities
/// 1.8e-2 in f32 against 2.8e-3 in f64), so it was held only to 10 times f64's error. f32
/// rounding grows with the step count, so at tighter tolerances f32 falls behind f64: measured
/// at 1e-5, order 2, case 1 (~2300 steps per member, before f32 refused that tolerance): f32
/// 1.7e-3 against f64 9.1e-5 on gaps.
#[test]
fn adaptive_f32_is_as_accurate_as_adaptive_f64_up_to_rounding() {
    let tol = 2e-4;
    let u32_eps = 2f64.powi(-24);
    for (label, chain, members) in scenes() {
        let gamma_max = members.iter().fold(1.0f64, |m, p| m.max(p.gamma));
        let reference = plan(
            &chain,
            members.clone(),
            Order::Fixed(4),
            Stepping::Fixed {
                dt: 1e-4,
                dt_min: 1e-12,
            },
        );
        let (exact, _) = run(&reference, &chain, Precision::F64);
        // Auto's highest column in f32 at this tolerance, and f64's errors with it.
        assert_eq!(top_column(tol, true, false), 4);
        let mut f64_at_top = (0.0, 0.0);
        for order in [Order::Fixed(2), Order::Fixed(4), Order::Auto] {
            let adaptive = Stepping::Adaptive {
                tolerance: tol,
                dt_initial: 1e-3,
                dt_min: 1e-12,
            };
            let p = plan(&chain, members.clone(), order, adaptive);
            let (f64_run, r64) = run(&p, &chain, Precision::F64);
            let (f32_run, r32) = run(&p, &chain, Precision::F32);
            assert!(
                r32.iter().all(|r| r.status == MemberStatus::Ok),
                "{label} {order:?}: {r32:?}"
            );
            let total = |r: &[MemberReport]| r.iter().map(|m| m.steps_accepted).sum::<u64>() as f64;
            let (s64, s32) = (total(&r64), total(&r32));
            let steps = r32.iter().map(|m| m.steps_accepted).max().unwrap() as f64;
            let (e64g, e64v) = max_rel_diff(&f64_run, &exact);
            let (e32g, e32v) = max_rel_diff(&f32_run, &exact);
            let rounding = 2.0 * steps * (gamma_max + 1.0) * u32_eps;
            eprintln!(
                "{label} {order:?}: error f64 gaps {e64g:.2e} velocities {e64v:.2e} ({s64} steps), f32 gaps {e32g:.2e} velocities {e32v:.2e} ({s32} steps); rounding bound {rounding:.2e}"
            );
            if order != Order::Auto {
                assert!(
                    (s32 - s64).abs() <= 0.05 * s64 + 3.0 * members.len() as f64,
                    "{label} {order:?}: {s32} steps in f32, {s64} in f64"
                );
            }
            if order == Order::Fixed(4) {
                f64_at_top = (e64g, e64v);
            }
            let (e64g, e64v) = match order {
                Order::Auto => (e64g.max(f64_at_top.0), e64v.max(f64_at_top.1)),
                Order::Fixed(_) => (e64g, e64v),
            };
            let factor = 1.5;
            assert!(
                e32g <= factor * e64g + rounding && e32v <= factor * e64v + rounding,
                "{label} {order:?}: f32 error {e32g:e} {e32v:e} vs f64 {e64g:e} {e64v:e}"
            );
        }
    }
}
