//! The GPU backend (`roughlub::gpu::solver::GpuSolver`, order 1, fixed steps) against the CPU
//! backend on the paper's case 1 (N = 200, rho0 = 0.7, u0 = 0.5 sin(2 pi x), rho*0 = 0.7), a
//! 16-member mu × gamma sweep, dt = 1e-3, outputs at t = 0, 0.1, 0.2 (200 steps). GPU tests go
//! through `acquire_for_tests(true)` (skipped without an f64 adapter unless
//! `ROUGHLUB_REQUIRE_GPU=1`).

mod common;

use common::plan_for;
use roughlub::cpu::{CpuSolver, MemberStatus};
use roughlub::expr::Expr;
use roughlub::gpu::acquire_for_tests;
use roughlub::gpu::solver::GpuSolver;
use roughlub::gpu::{GpuContext, GpuError};
use roughlub::initial::{chain_from_profiles, Chain};
use roughlub::observables::Snapshot;
use roughlub::plan::Plan;
use roughlub::scene::{MemberParams, Precision, Stepping};

const DT: f64 = 1e-3;
const TIMES: [f64; 3] = [0.0, 0.1, 0.2];

fn case1_chain() -> Chain {
    chain_from_profiles(
        200,
        &Expr::parse("0.7").unwrap(),
        &Expr::parse("0.5*sin(2*pi*x)").unwrap(),
        Some(&Expr::parse("0.7").unwrap()),
    )
    .unwrap()
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

fn case1_plan(order: u8, dt: f64) -> (Plan, Vec<Chain>) {
    let chain = case1_chain();
    let members = sweep();
    let chains = vec![chain.clone(); members.len()];
    let plan = plan_for(
        &chain,
        members,
        order,
        Stepping::Fixed { dt, dt_min: 1e-9 },
        TIMES.to_vec(),
        None,
    );
    (plan, chains)
}

fn run_cpu(dt: f64) -> Vec<Vec<Snapshot>> {
    let (plan, chains) = case1_plan(1, dt);
    let mut solver = CpuSolver::new(plan, chains);
    let mut out = Vec::new();
    while let Some(s) = solver.next_output(None) {
        out.push(s);
    }
    for r in solver.reports() {
        assert_eq!(r.status, MemberStatus::Ok, "CPU member {}", r.index);
        assert_eq!(r.steps_rejected, 0, "CPU member {}: rejections", r.index);
    }
    out
}

fn run_gpu(ctx: &GpuContext, precision: Precision) -> Vec<Vec<Snapshot>> {
    let (plan, chains) = case1_plan(1, DT);
    let mut solver = GpuSolver::new(ctx, plan, chains, precision).unwrap_or_else(|e| panic!("{e}"));
    let mut out = Vec::new();
    while let Some(s) = solver.next_output().unwrap_or_else(|e| panic!("{e}")) {
        out.push(s);
    }
    let stats = solver.stats();
    eprintln!("{precision:?}: {stats:?}");
    assert_eq!(stats.steps, 200);
    assert_eq!(stats.dispatches, 400);
    assert_eq!(stats.submits, 2, "one submit per output interval");
    for r in solver.reports() {
        assert_eq!(r.status, MemberStatus::Ok, "GPU member {}", r.index);
        assert_eq!(r.steps_accepted, 200, "GPU member {}", r.index);
        assert!((r.last_dt - DT).abs() < 1e-15, "GPU member {}", r.index);
    }
    let errors = ctx.take_uncaptured_errors();
    assert!(errors.is_empty(), "{errors:?}");
    out
}

/// Largest |a - b| / max_member |b| over the members, for gaps and for velocities, at each
/// output time.
fn max_rel_diff(a: &[Vec<Snapshot>], b: &[Vec<Snapshot>]) -> Vec<(f64, f64)> {
    assert_eq!(a.len(), b.len());
    let rel = |x: &[f64], y: &[f64]| {
        assert_eq!(x.len(), y.len());
        let scale = y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        x.iter()
            .zip(y)
            .fold(0.0f64, |m, (p, q)| m.max((p - q).abs() / scale))
    };
    a.iter()
        .zip(b)
        .map(|(sa, sb)| {
            assert_eq!(sa.len(), sb.len());
            sa.iter()
                .zip(sb)
                .fold((0.0f64, 0.0f64), |(g, v), (ma, mb)| {
                    (
                        g.max(rel(&ma.gaps, &mb.gaps)),
                        v.max(rel(&ma.velocities, &mb.velocities)),
                    )
                })
        })
        .collect()
}

/// The tolerance for f32 against f64 (see `gpu_f32_matches_cpu_f64_within_derived_tolerance`):
/// u_f32 = 2^-24 ≈ 6e-8 per operation; the initial data alone differ by u; each of the 200
/// steps adds a rounding error of a few u (the Thomas sweep and the update), which the implicit,
/// dissipative step does not amplify, but the repulsion G = ratio^gamma turns a relative error
/// e of a gap into gamma·e in G (gamma up to 20). Bound: steps × gamma_max × u ≈ 200 × 20 × 6e-8
/// ≈ 2.4e-4.
const F32_TOLERANCE: f64 = 200.0 * 20.0 * 5.96e-8;

#[test]
fn gpu_f64_matches_cpu_f64() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let cpu = run_cpu(DT);
    let gpu = run_gpu(&ctx, Precision::F64);
    assert_eq!(gpu.len(), TIMES.len());
    let diffs = max_rel_diff(&gpu, &cpu);
    for (t, (g, v)) in TIMES.iter().zip(&diffs) {
        eprintln!("f64 GPU vs CPU at t = {t}: gaps {g:.2e}, velocities {v:.2e}");
        assert!(*g <= 1e-10, "t = {t}: gaps {g:e}");
        assert!(*v <= 1e-10, "t = {t}: velocities {v:e}");
    }
    // Something happened between the outputs.
    assert!(max_rel_diff(&cpu[2..], &cpu[..1])[0].1 > 1e-3);
}

#[test]
fn gpu_f32_matches_cpu_f64_within_derived_tolerance() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let cpu = run_cpu(DT);
    let cpu_half = run_cpu(DT / 2.0);
    let gpu = run_gpu(&ctx, Precision::F32);
    let diffs = max_rel_diff(&gpu, &cpu);
    let scheme = max_rel_diff(&cpu_half, &cpu);
    for ((t, (g, v)), (sg, sv)) in TIMES.iter().zip(&diffs).zip(&scheme) {
        eprintln!(
            "f32 GPU vs f64 CPU at t = {t}: gaps {g:.2e}, velocities {v:.2e}; \
             scheme (CPU dt/2 vs dt): gaps {sg:.2e}, velocities {sv:.2e}; \
             tolerance {F32_TOLERANCE:.2e}"
        );
        assert!(*g <= F32_TOLERANCE, "t = {t}: gaps {g:e}");
        assert!(*v <= F32_TOLERANCE, "t = {t}: velocities {v:e}");
    }
    // f32 rounding stays well below the time discretisation error at this dt.
    let (sg, sv) = scheme[2];
    let (g, v) = diffs[2];
    assert!(
        g < 0.1 * sg && v < 0.1 * sv,
        "f32 {g:e}/{v:e} vs scheme {sg:e}/{sv:e}"
    );
}

fn expect_unsupported(result: Result<GpuSolver<'_>, GpuError>, what: &str) {
    match result {
        Ok(_) => panic!("{what}: expected an error"),
        Err(e) => {
            let message = e.to_string();
            eprintln!("{what}: {message}");
            assert!(
                message.contains("not yet supported on the GPU backend"),
                "{what}: {message}"
            );
            assert!(matches!(e, GpuError::Validation { .. }), "{what}: {e:?}");
        }
    }
}

#[test]
fn order_two_and_adaptive_are_refused_clearly() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let (plan, chains) = case1_plan(2, DT);
    expect_unsupported(
        GpuSolver::new(&ctx, plan, chains, Precision::F64),
        "order 2",
    );
    let (mut plan, chains) = case1_plan(1, DT);
    plan.stepping = Stepping::Adaptive {
        tolerance: 1e-4,
        dt_initial: DT,
        dt_min: 1e-9,
    };
    expect_unsupported(
        GpuSolver::new(&ctx, plan, chains, Precision::F64),
        "adaptive",
    );
}

/// A step far too large for a member with little lubrication closes a gap: the CPU halves and
/// retries, the GPU backend (no halving yet) fails that member at the interval start, says why,
/// and leaves the other members alone.
#[test]
fn rejected_fixed_step_fails_the_member_honestly() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let chain = case1_chain();
    let members = vec![
        MemberParams {
            mu: 0.02,
            gamma: 2.0,
        },
        MemberParams {
            mu: 1e-6,
            gamma: 1.0,
        },
    ];
    let chains = vec![chain.clone(); members.len()];
    let plan = plan_for(
        &chain,
        members,
        1,
        Stepping::Fixed {
            dt: 0.05,
            dt_min: 1e-9,
        },
        vec![0.0, 0.1, 0.2],
        None,
    );
    let mut cpu = CpuSolver::new(plan.clone(), chains.clone());
    let mut cpu_out = Vec::new();
    while let Some(s) = cpu.next_output(None) {
        cpu_out.push(s);
    }
    let cpu_reports = cpu.reports();
    eprintln!("CPU: {cpu_reports:?}");
    let mut gpu = GpuSolver::new(&ctx, plan, chains, Precision::F64).unwrap();
    let mut gpu_out = Vec::new();
    while let Some(s) = gpu.next_output().unwrap() {
        gpu_out.push(s);
    }
    let reports = gpu.reports();
    eprintln!("GPU: {reports:?}");
    assert_eq!(
        cpu_reports[0].steps_rejected, 0,
        "test data: member 0 never rejected"
    );
    assert!(
        cpu_reports[1].steps_rejected > 0,
        "test data: member 1 rejected"
    );
    assert_eq!(reports[0].status, MemberStatus::Ok);
    match &reports[1].status {
        MemberStatus::Failed { reason, time } => {
            assert!(
                reason.contains("step halving is not yet implemented"),
                "{reason}"
            );
            assert_eq!(*time, 0.0);
        }
        other => panic!("member 1: {other:?}"),
    }
    for (k, s) in gpu_out.iter().enumerate() {
        if k > 0 {
            assert!(
                s[1].gaps.iter().all(|g| g.is_nan()),
                "failed member at output {k}"
            );
        }
    }
    let diffs = max_rel_diff(
        &gpu_out
            .iter()
            .map(|s| vec![s[0].clone()])
            .collect::<Vec<_>>(),
        &cpu_out
            .iter()
            .map(|s| vec![s[0].clone()])
            .collect::<Vec<_>>(),
    );
    eprintln!("member 0, GPU vs CPU: {diffs:?}");
    assert!(diffs.iter().all(|&(g, v)| g <= 1e-10 && v <= 1e-10));
}

/// An interval of 300 steps is submitted in two chunks (256 + 44); the step times and sizes
/// carry on across the chunk boundary exactly as on the CPU.
#[test]
fn long_interval_is_chunked_and_still_matches_cpu() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let chain = case1_chain();
    let members = vec![
        MemberParams {
            mu: 0.01,
            gamma: 5.0,
        },
        MemberParams {
            mu: 0.005,
            gamma: 5.0,
        },
    ];
    let chains = vec![chain.clone(); members.len()];
    let plan = plan_for(
        &chain,
        members,
        1,
        Stepping::Fixed {
            dt: DT,
            dt_min: 1e-9,
        },
        vec![0.0, 0.3],
        Some(("0.3*sin(2*pi*x)*cos(3*t)", 3)),
    );
    let mut cpu = CpuSolver::new(plan.clone(), chains.clone());
    let mut cpu_out = Vec::new();
    while let Some(s) = cpu.next_output(None) {
        cpu_out.push(s);
    }
    let mut gpu = GpuSolver::new(&ctx, plan, chains, Precision::F64).unwrap();
    let mut gpu_out = Vec::new();
    while let Some(s) = gpu.next_output().unwrap() {
        gpu_out.push(s);
    }
    let stats = gpu.stats();
    eprintln!("{stats:?}");
    assert_eq!(stats.steps, 300);
    assert_eq!(stats.submits, 2);
    let diffs = max_rel_diff(&gpu_out, &cpu_out);
    eprintln!("forced, uniform gamma = 5, 300 steps, GPU vs CPU: {diffs:?}");
    assert!(diffs.iter().all(|&(g, v)| g <= 1e-10 && v <= 1e-10));
    assert_eq!(
        gpu.reports()
            .iter()
            .map(|r| r.steps_accepted)
            .collect::<Vec<_>>(),
        cpu.reports()
            .iter()
            .map(|r| r.steps_accepted)
            .collect::<Vec<_>>()
    );
}
