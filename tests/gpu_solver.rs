//! The GPU backend (`roughlub::backend::gpu::solver::GpuSolver`) against the CPU backend. GPU
//! tests go through `acquire_for_tests(true)`: skipped without an f64 adapter unless
//! `ROUGHLUB_REQUIRE_GPU=1` (CI), which turns a missing adapter into a failure.

mod common;

use common::gpu::acquire_for_tests;
use common::{plan_for, random_chain, Rng};
use roughlub::backend::cpu::CpuSolver;
use roughlub::backend::gpu::solver::GpuSolver;
use roughlub::backend::gpu::GpuContext;
use roughlub::backend::shared::control::top_column;
use roughlub::backend::{BatchSolver, MemberReport, MemberStatus, Precision};
use roughlub::expr::Expr;
use roughlub::model::chain::Chain;
use roughlub::model::observables::Snapshot;
use roughlub::model::params::{Jacobian, MemberParams, Order, Sequence, Stepping};
use roughlub::model::plan::Plan;
use roughlub::scene::initial::chain_from_profiles;

fn profile_chain(n: usize, rho: &str, u: &str, rho_star: Option<&str>) -> Chain {
    chain_from_profiles(
        n,
        &Expr::parse(rho).unwrap(),
        &Expr::parse(u).unwrap(),
        rho_star.map(|s| Expr::parse(s).unwrap()).as_ref(),
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

fn run_cpu(plan: &Plan, chains: &[Chain]) -> (Vec<Vec<Snapshot>>, Vec<MemberReport>) {
    run_cpu_in(plan, chains, Precision::F64)
}

fn run_cpu_in(
    plan: &Plan,
    chains: &[Chain],
    precision: Precision,
) -> (Vec<Vec<Snapshot>>, Vec<MemberReport>) {
    let mut solver = CpuSolver::with_precision(plan.clone(), chains.to_vec(), precision);
    let mut out = Vec::new();
    while let Some(s) = solver.next_output(&|_| {}).unwrap() {
        out.push(s);
    }
    (out, solver.reports())
}

fn run_gpu(
    ctx: &GpuContext,
    plan: &Plan,
    chains: &[Chain],
    precision: Precision,
) -> (Vec<Vec<Snapshot>>, Vec<MemberReport>) {
    let mut solver = GpuSolver::new(ctx, plan.clone(), chains.to_vec(), precision)
        .unwrap_or_else(|e| panic!("{e}"));
    let mut out = Vec::new();
    while let Some(s) = solver
        .next_output(&|_| {})
        .unwrap_or_else(|e| panic!("{e}"))
    {
        out.push(s);
    }
    eprintln!("{precision:?}: {:?}", solver.stats());
    let errors = ctx.take_uncaptured_errors();
    assert!(errors.is_empty(), "{errors:?}");
    (out, solver.reports())
}

/// Largest |a - b| / max_member |b| over members (each member scaled by its own largest value),
/// for gaps and for velocities, over all output times. NaN rows (failed members) must match.
fn max_rel_diff(a: &[Vec<Snapshot>], b: &[Vec<Snapshot>]) -> (f64, f64) {
    assert_eq!(a.len(), b.len());
    let rel = |x: &[f64], y: &[f64]| {
        assert_eq!(x.len(), y.len());
        let scale = y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        x.iter().zip(y).fold(0.0f64, |m, (p, q)| {
            if p.is_nan() || q.is_nan() {
                assert!(
                    p.is_nan() && q.is_nan(),
                    "one backend failed, the other did not"
                );
                m
            } else {
                m.max((p - q).abs() / scale)
            }
        })
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

/// GPU f64 against CPU f64: 1e-10 relative on gaps and velocities (rounding only: the same
/// operations in the same order; lavapipe does not fuse, a real GPU may contract to fma), and the
/// same accepted and rejected steps and status for every member.
fn assert_f64_agreement(ctx: &GpuContext, label: &str, plan: &Plan, chains: &[Chain]) {
    let (cpu, cpu_reports) = run_cpu(plan, chains);
    let (gpu, gpu_reports) = run_gpu(ctx, plan, chains, Precision::F64);
    for (g, c) in gpu_reports.iter().zip(&cpu_reports) {
        if g.status != c.status {
            eprintln!("{label}: member {}: GPU {:?} vs CPU {:?}", c.index, g, c);
        }
    }
    let (dg, dv) = max_rel_diff(&gpu, &cpu);
    eprintln!("{label}: GPU f64 vs CPU f64: gaps {dg:.2e}, velocities {dv:.2e}");
    assert!(
        dg <= 1e-10 && dv <= 1e-10,
        "{label}: gaps {dg:e}, velocities {dv:e}"
    );
    for (g, c) in gpu_reports.iter().zip(&cpu_reports) {
        assert_eq!(
            g.steps_accepted, c.steps_accepted,
            "{label}: member {} accepted steps",
            c.index
        );
        assert_eq!(
            g.steps_rejected, c.steps_rejected,
            "{label}: member {} rejected steps",
            c.index
        );
        assert_eq!(
            std::mem::discriminant(&g.status),
            std::mem::discriminant(&c.status),
            "{label}: member {} status {:?} vs {:?}",
            c.index,
            g.status,
            c.status
        );
        // Orders above 2 set dt from estimates that carry the backends' rounding differences
        // amplified by the tableau's weights (see the estimates below): hundreds up to column
        // 6, about a thousand at columns 7 and 8 (auto at 1e-8 measured 3.6e-5 on 40 particles,
        // every accepted and rejected step the same). The rows from 2 weigh the rounding about
        // 3 times more (sum of |weights| at column 8: 9851 against 3392; auto at 1e-8 measured
        // 1.3e-4).
        let weights = if plan.sequence == Sequence::FromTwo {
            3.0
        } else {
            1.0
        };
        let dt_tol = weights
            * match plan.order.columns() {
                0..=2 => 1e-9,
                3..=6 => 1e-5,
                _ => 1e-4,
            };
        assert!(
            (g.last_dt - c.last_dt).abs() <= dt_tol * c.last_dt,
            "{label}: member {} last dt {} vs {}",
            c.index,
            g.last_dt,
            c.last_dt
        );
        assert_eq!(
            g.last_order, c.last_order,
            "{label}: member {} order",
            c.index
        );
        match (&g.error_estimate, &c.error_estimate) {
            (None, None) => {}
            (Some(ge), Some(ce)) => {
                // An estimate is a difference of tableau entries: the backends' rounding
                // differences in those (up to ~1e-12 of the state at order 6, where the
                // tableau's weights reach hundreds; ~1e-11 at order 8, measured 3.6e-11 on
                // velocities, where they reach a thousand) pass into it unscaled.
                let floor = weights
                    * if plan.order.columns() <= 6 {
                        1e-12
                    } else {
                        1e-11
                    };
                for (a, b) in ge.iter().zip(ce) {
                    assert!(
                        (a - b).abs() <= 1e-6 * b.abs() + floor,
                        "{label}: member {} error estimates {ge:?} vs {ce:?}",
                        c.index
                    );
                }
            }
            other => panic!("{label}: member {}: error estimates {other:?}", c.index),
        }
    }
}

fn case1_plan(order: u8, stepping: Stepping) -> (Plan, Vec<Chain>) {
    let chain = profile_chain(200, "0.7", "0.5*sin(2*pi*x)", Some("0.7"));
    let members = sweep();
    let chains = vec![chain.clone(); members.len()];
    let plan = plan_for(&chain, members, order, stepping, vec![0.0, 0.1, 0.2], None);
    (plan, chains)
}

const FIXED: Stepping = Stepping::Fixed {
    dt: 1e-3,
    dt_min: 1e-9,
};
const ADAPTIVE: Stepping = Stepping::Adaptive {
    tolerance: 1e-5,
    dt_initial: 1e-4,
    dt_min: 1e-12,
};

#[test]
fn paper_case1_sweep_agrees_for_both_orders_fixed_and_adaptive() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    for (order, stepping, label) in [
        (1, FIXED, "case 1, order 1, 200 fixed steps"),
        (2, FIXED, "case 1, order 2, 200 fixed steps"),
        (1, ADAPTIVE, "case 1, order 1, adaptive"),
        (2, ADAPTIVE, "case 1, order 2, adaptive"),
    ] {
        let (plan, chains) = case1_plan(order, stepping);
        assert_f64_agreement(&ctx, label, &plan, &chains);
    }
}

/// Many steps per dispatch and per submit, state read back only at output times: one member of
/// case 1 with 200 fixed steps over two output intervals.
#[test]
fn many_steps_per_dispatch_and_readback_only_at_outputs() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let (mut plan, chains) = case1_plan(1, FIXED);
    plan.members.truncate(1);
    let mut solver = GpuSolver::new(&ctx, plan, chains[..1].to_vec(), Precision::F64).unwrap();
    while solver.next_output(&|_| {}).unwrap().is_some() {}
    let st = solver.stats();
    eprintln!("{st:?}");
    assert_eq!(st.steps, 200);
    assert!(st.attempts_per_dispatch > 1, "{st:?}");
    // Per interval: begin + the advance dispatches of one submit + gather; 100 steps each.
    assert!(st.dispatches < st.steps / 2, "{st:?}");
    // One advance submit per interval (100 steps < attempts × dispatches per submit), plus one
    // gather per output time (3, t = 0 included).
    assert_eq!(st.submits, 2 + 3, "{st:?}");
    // Read-backs: per output the controls, gaps and velocities, plus 4 bytes per advance submit.
    let n = 200u64;
    // The control is 120 bytes in f64 (`ControlF64`).
    let state_bytes = 120 + 8 * n + 8 * (n - 1);
    assert_eq!(
        st.bytes_read,
        3 * state_bytes + 4 * (st.submits - 3),
        "{st:?}"
    );
}

#[test]
fn paper_cases_2a_and_3_agree() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let members = vec![
        MemberParams {
            mu: 0.01,
            gamma: 1.0,
        },
        MemberParams {
            mu: 0.005,
            gamma: 1.0,
        },
    ];
    let g = "exp(-(x-0.5)^2/(2*0.1^2))";
    for (label, chain) in [
        (
            "case 2a (no repulsion)",
            profile_chain(300, "0.7", "0.5*sin(2*pi*x)", None),
        ),
        (
            "case 3",
            profile_chain(
                300,
                &format!("0.6 + 0.2*{g}"),
                "0.5*sin(2*pi*x)",
                Some(&format!("0.6 - 0.2*{g}")),
            ),
        ),
    ] {
        let plan = plan_for(
            &chain,
            members.clone(),
            2,
            FIXED,
            vec![0.0, 0.15, 0.3],
            None,
        );
        assert_f64_agreement(&ctx, label, &plan, &vec![chain.clone(); 2]);
    }
}

/// Members with their own random roughness and forcing; order 1 and 2, fixed and adaptive
/// (the adaptive runs must take the same accepted and rejected steps as on the CPU).
#[test]
fn random_roughness_and_forcing_agree_including_adaptive_step_sequences() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let mut rng = Rng(2024);
    let n = 60;
    let eps = 0.35 / n as f64;
    let chains: Vec<Chain> = (0..12)
        .map(|_| random_chain(&mut rng, n, eps, Some(0.6 * eps)))
        .collect();
    let members: Vec<MemberParams> = (0..12)
        .map(|_| MemberParams {
            mu: rng.uniform(0.005, 0.05),
            gamma: [1.0, 2.0, 3.5][rng.next_u64() as usize % 3],
        })
        .collect();
    for (order, stepping) in [(1, FIXED), (2, FIXED), (1, ADAPTIVE), (2, ADAPTIVE)] {
        let plan = plan_for(
            &chains[0],
            members.clone(),
            order,
            stepping,
            (0..=4).map(|k| 0.05 * k as f64).collect(),
            Some(("0.3*sin(2*pi*x)*cos(3*t)", 3)),
        );
        assert_f64_agreement(
            &ctx,
            &format!("random roughness + forcing, order {order}, {stepping:?}"),
            &plan,
            &chains,
        );
    }
}

/// The extrapolated orders 3..=8 and auto: the same tableau, error estimates, step sequences
/// and order choices on both backends (members with their own roughness, mu, gamma, forcing).
#[test]
fn higher_orders_and_auto_agree_including_order_choices() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let mut rng = Rng(77);
    let n = 40;
    let eps = 0.35 / n as f64;
    let chains: Vec<Chain> = (0..8)
        .map(|_| random_chain(&mut rng, n, eps, Some(0.6 * eps)))
        .collect();
    let members: Vec<MemberParams> = (0..8)
        .map(|_| MemberParams {
            mu: rng.uniform(0.005, 0.05),
            gamma: [1.0, 2.0, 3.5][rng.next_u64() as usize % 3],
        })
        .collect();
    let tight = Stepping::Adaptive {
        tolerance: 1e-8,
        dt_initial: 1e-4,
        dt_min: 1e-12,
    };
    for (order, stepping) in [
        (Order::Fixed(3), FIXED),
        (Order::Fixed(6), FIXED),
        (Order::Fixed(8), FIXED),
        (Order::Fixed(4), ADAPTIVE),
        (Order::Auto, ADAPTIVE),
        (Order::Auto, tight),
    ] {
        let plan = plan_for(
            &chains[0],
            members.clone(),
            order,
            stepping,
            (0..=3).map(|k| 0.05 * k as f64).collect(),
            Some(("0.3*sin(2*pi*x)*cos(3*t)", 3)),
        );
        // The tight case takes the exact Jacobian (`Jacobian::Auto` at 1e-8), the others the
        // frozen one; order 6 with fixed steps is also run with the exact one. Order 6 fixed and
        // the auto cases also with the rows from 2 (`Sequence::FromTwo`, the twins' other
        // substeps, weights and work model).
        if order == Order::Fixed(6) {
            let exact = Plan {
                jacobian: Jacobian::Exact,
                ..plan.clone()
            };
            assert_f64_agreement(&ctx, "order 6, fixed, exact Jacobian", &exact, &chains);
        }
        if order == Order::Fixed(6) || order == Order::Auto {
            let from_two = Plan {
                sequence: Sequence::FromTwo,
                ..plan.clone()
            };
            let label = format!("order {}, {stepping:?}, rows from 2", order.label());
            assert_f64_agreement(&ctx, &label, &from_two, &chains);
        }
        let label = format!("order {}, {stepping:?}", order.label());
        assert_f64_agreement(&ctx, &label, &plan, &chains);
        if order == Order::Auto {
            // The controller does move between orders (else auto would test one order only).
            let (_, reports) = run_cpu(&plan, &chains);
            let orders: std::collections::BTreeSet<u8> =
                reports.iter().map(|r| r.last_order).collect();
            eprintln!("{label}: last orders {orders:?}");
        }
    }
}

/// A fixed step far too large for a member with almost no lubrication: both backends reject,
/// shrink and retry the same way; a member whose dt collapses fails on both with the same time.
#[test]
fn rejection_retry_and_failure_agree() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let chain = profile_chain(200, "0.7", "0.5*sin(2*pi*x)", Some("0.7"));
    // gamma = 1000 at dt = 0.01: steps that raise the energy are rejected and retried smaller;
    // with dt_min = 1e-3 the member whose every retry raises it fails.
    let members = vec![
        MemberParams {
            mu: 0.02,
            gamma: 2.0,
        },
        MemberParams {
            mu: 0.01,
            gamma: 300.0,
        },
        MemberParams {
            mu: 0.01,
            gamma: 1000.0,
        },
    ];
    let dt_min = 1e-9;
    let plan = plan_for(
        &chain,
        members.clone(),
        1,
        Stepping::Fixed { dt: 0.01, dt_min },
        vec![0.0, 0.1, 0.2],
        None,
    );
    let chains = vec![chain.clone(); 3];
    let (_, cpu_reports) = run_cpu(&plan, &chains);
    eprintln!("CPU: {cpu_reports:?}");
    assert!(
        cpu_reports.iter().any(|r| r.steps_rejected > 0),
        "test data: some rejection"
    );
    assert_f64_agreement(
        &ctx,
        &format!("rejections, dt_min {dt_min}"),
        &plan,
        &chains,
    );
}

#[test]
fn clusters_agree_and_stay_rigid_on_the_gpu() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let n = 30;
    let eps = 0.01;
    let mut bonded = vec![false; n];
    for g in [0usize, 7, 8, 20, 29] {
        bonded[g] = true; // glued to both walls, and two clusters inside
    }
    let free = 1.0 - 2.0 * eps * n as f64;
    let free_count = bonded.iter().filter(|b| !**b).count() as f64;
    let gaps: Vec<f64> = bonded
        .iter()
        .map(|&b| if b { 0.0 } else { free / free_count })
        .collect();
    let mut u_all: Vec<f64> = (0..=n)
        .map(|i| 0.3 * (2.0 * std::f64::consts::PI * i as f64 / n as f64).sin())
        .collect();
    u_all[0] = 0.0;
    u_all[n] = 0.0;
    for g in 1..=n {
        if bonded[g - 1] {
            u_all[g] = u_all[g - 1];
        }
    }
    for g in (1..=n).rev() {
        if bonded[g - 1] && g == n {
            u_all[g - 1] = 0.0;
        }
    }
    let velocities = u_all[1..n].to_vec();
    let dstar = Some((0..n).map(|i| 0.004 + 0.001 * (i % 4) as f64).collect());
    let chain = Chain {
        eps,
        gaps,
        velocities,
        dstar,
        bonded: Some(bonded.clone()),
    };
    let members = vec![
        MemberParams {
            mu: 0.01,
            gamma: 2.0,
        },
        MemberParams {
            mu: 0.03,
            gamma: 2.0,
        },
    ];
    for (order, stepping) in [(1, FIXED), (2, ADAPTIVE)] {
        let plan = plan_for(
            &chain,
            members.clone(),
            order,
            stepping,
            vec![0.0, 0.1, 0.2],
            Some(("sin(6*x)*(1+t)", 4)),
        );
        let chains = vec![chain.clone(); 2];
        assert_f64_agreement(&ctx, &format!("clusters, order {order}"), &plan, &chains);
        let (gpu, _) = run_gpu(&ctx, &plan, &chains, Precision::F64);
        for s in &gpu {
            for m in s {
                for (g, &b) in bonded.iter().enumerate() {
                    if b {
                        assert_eq!(m.gaps[g], 0.0, "bonded gap {} opened on the GPU", g + 1);
                    }
                }
                assert_eq!(m.velocities[0], 0.0, "wall-glued particle moved");
                assert_eq!(m.velocities[7], m.velocities[6], "cluster 7-8");
            }
        }
    }
}

/// The specialised kernels give the general kernel's result: an integer gamma as a chain of
/// multiplications against the per-member path (exp/log or the same chain read at run time),
/// a forcing term that is present but zero against no forcing term, and the cluster-aware
/// sweep with no bonded gap against the plain sweep — all to rounding.
#[test]
fn specialised_kernels_match_the_general_kernel() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let chain = profile_chain(
        100,
        "0.7",
        "0.5*sin(2*pi*x)",
        Some("0.65 + 0.05*cos(2*pi*x)"),
    );
    let members = vec![
        MemberParams {
            mu: 0.01,
            gamma: 3.0,
        },
        MemberParams {
            mu: 0.02,
            gamma: 3.0,
        },
    ];
    let times = vec![0.0, 0.1, 0.2];
    let special = plan_for(&chain, members.clone(), 1, FIXED, times.clone(), None);
    let (reference, _) = run_gpu(&ctx, &special, &vec![chain.clone(); 2], Precision::F64);

    // gamma = 3 integer but members differ → PerMember path: use gamma 3 and 3 + 0 via a third
    // member with another gamma, then compare the first two members.
    let mut general_members = members.clone();
    general_members.push(MemberParams {
        mu: 0.01,
        gamma: 2.5,
    });
    let general = plan_for(&chain, general_members, 1, FIXED, times.clone(), None);
    let (per_member, _) = run_gpu(&ctx, &general, &vec![chain.clone(); 3], Precision::F64);
    let first_two: Vec<Vec<Snapshot>> = per_member.iter().map(|s| s[..2].to_vec()).collect();
    let (dg, dv) = max_rel_diff(&first_two, &reference);
    eprintln!("per-member gamma vs integer chain: {dg:.2e} {dv:.2e}");
    assert!(dg <= 1e-13 && dv <= 1e-13);

    let zero_forcing = plan_for(
        &chain,
        members.clone(),
        1,
        FIXED,
        times.clone(),
        Some(("0*x", 3)),
    );
    let (forced, _) = run_gpu(&ctx, &zero_forcing, &vec![chain.clone(); 2], Precision::F64);
    let (dg, dv) = max_rel_diff(&forced, &reference);
    eprintln!("zero forcing vs no forcing: {dg:.2e} {dv:.2e}");
    assert!(dg <= 1e-13 && dv <= 1e-13);

    let mut clustered = special.clone();
    clustered.clusters = true;
    let mut with_flags = chain.clone();
    with_flags.bonded = Some(vec![false; chain.particles()]);
    let (cl, _) = run_gpu(&ctx, &clustered, &vec![with_flags; 2], Precision::F64);
    let (dg, dv) = max_rel_diff(&cl, &reference);
    eprintln!("cluster-aware sweep without bonds vs plain sweep: {dg:.2e} {dv:.2e}");
    assert!(dg <= 1e-13 && dv <= 1e-13);
}

/// f32 on the GPU against f64 on the CPU, including a dense member (rho0 = 0.99) and a gamma = 20
/// member. Tolerance, derived: u = 2^-24 ≈ 6e-8 per operation; the stored gaps keep their relative
/// precision, each step adds a few u of rounding that the implicit, dissipative step does not
/// amplify, but G = ratio^gamma turns a relative error e of a gap into gamma·e; over K steps the
/// bound is K·gamma_max·u. The test also checks that this is far below the scheme's own error at
/// that dt (CPU at dt against dt/2), i.e. f32 costs nothing the scheme has not already lost.
#[test]
fn f32_agrees_with_f64_within_the_derived_tolerance() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let u32_eps = 2f64.powi(-24);
    for (label, chain, members) in [
        (
            "case 1 sweep",
            profile_chain(200, "0.7", "0.5*sin(2*pi*x)", Some("0.7")),
            sweep(),
        ),
        (
            "dense rho0 = 0.99, gamma 20",
            profile_chain(200, "0.99", "0.05*sin(2*pi*x)", Some("0.99")),
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
    ] {
        let dt = 1e-3;
        let steps = 200.0;
        let gamma_max = members.iter().fold(1.0f64, |m, p| m.max(p.gamma));
        // Rounding per step: of G (gamma ulps) and of the gap update and its projection (one
        // more), accumulated over the steps, with a factor 2 for their compounding.
        let tolerance = 2.0 * steps * (gamma_max + 1.0) * u32_eps;
        let b = members.len();
        let plan = plan_for(
            &chain,
            members.clone(),
            1,
            Stepping::Fixed { dt, dt_min: 1e-9 },
            vec![0.0, 0.1, 0.2],
            None,
        );
        let chains = vec![chain.clone(); b];
        let (cpu, cpu_reports) = run_cpu(&plan, &chains);
        assert!(cpu_reports
            .iter()
            .all(|r| r.status == MemberStatus::Ok && r.steps_rejected == 0));
        let (gpu32, reports32) = run_gpu(&ctx, &plan, &chains, Precision::F32);
        assert!(
            reports32.iter().all(|r| r.status == MemberStatus::Ok),
            "{label}: {reports32:?}"
        );
        let (dg, dv) = max_rel_diff(&gpu32, &cpu);
        let half = plan_for(
            &chain,
            members,
            1,
            Stepping::Fixed {
                dt: dt / 2.0,
                dt_min: 1e-9,
            },
            vec![0.0, 0.1, 0.2],
            None,
        );
        let (cpu_half, _) = run_cpu(&half, &chains);
        let (sg, sv) = max_rel_diff(&cpu_half, &cpu);
        eprintln!(
            "{label}: f32 vs f64 gaps {dg:.2e}, velocities {dv:.2e}; tolerance {tolerance:.2e}; scheme error (dt vs dt/2) gaps {sg:.2e}, velocities {sv:.2e}"
        );
        assert!(
            dg <= tolerance && dv <= tolerance,
            "{label}: {dg:e} {dv:e} > {tolerance:e}"
        );
        assert!(
            dg <= 0.1 * sg && dv <= 0.1 * sv,
            "{label}: f32 error should be far below the scheme error"
        );
    }
}

/// Case 1's chain at N = 200 for three members (mu, gamma) = (0.01, 1), (0.005, 2), (0.02, 2):
/// the chain, the members, and the chain once per member.
fn case_one_chains() -> (Chain, Vec<MemberParams>, Vec<Chain>) {
    let chain = profile_chain(200, "0.7", "0.5*sin(2*pi*x)", Some("0.7"));
    let members: Vec<MemberParams> = [(0.01, 1.0), (0.005, 2.0), (0.02, 2.0)]
        .iter()
        .map(|&(mu, gamma)| MemberParams { mu, gamma })
        .collect();
    let chains = vec![chain.clone(); members.len()];
    (chain, members, chains)
}

/// f32 runs the higher orders too. Fixed steps: T_kk = sum_j c_j T_j1 with the Aitken–Neville
/// weights of the harmonic sequence, c_j = (-1)^(k-j) j^k / (j! (k-j)!), whose magnitudes sum to
/// Lambda_k (28.3 at k = 4, 302 at k = 6); row j takes j substeps per step, so its rounding is at
/// most j times that of the order 1 run over the same steps (measured here, d1). Hence
/// |f32 - f64| <= Lambda_k · k · d1, with a factor 2 for the extrapolation's own rounding.
/// Adaptive `auto` at tolerance 1e-4 (well above f32 rounding): both runs meet the tolerance
/// (their error stays within ~1.2 times it on this chain in f64), so they agree within 10 times it.
#[test]
fn f32_higher_orders_agree_with_f64() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let (chain, members, chains) = case_one_chains();
    let times = vec![0.0, 0.1, 0.2];
    let fixed = Stepping::Fixed {
        dt: 1e-3,
        dt_min: 1e-9,
    };
    let diff = |order: Order, stepping: Stepping| {
        let plan = plan_for(
            &chain,
            members.clone(),
            order,
            stepping,
            times.clone(),
            None,
        );
        let (cpu, cpu_reports) = run_cpu(&plan, &chains);
        let (gpu32, reports32) = run_gpu(&ctx, &plan, &chains, Precision::F32);
        for r in cpu_reports.iter().chain(&reports32) {
            assert_eq!(r.status, MemberStatus::Ok, "{order:?}: {r:?}");
        }
        max_rel_diff(&gpu32, &cpu)
    };
    let (g1, v1) = diff(Order::Fixed(1), fixed);
    let d1 = g1.max(v1).max(2f64.powi(-24));
    let lambda = |k: i32| -> f64 {
        let fact = |n: i32| (1..=n).map(f64::from).product::<f64>();
        (1..=k)
            .map(|j| f64::from(j).powi(k) / (fact(j) * fact(k - j)))
            .sum()
    };
    for k in [3u8, 4, 6] {
        let (dg, dv) = diff(Order::Fixed(k), fixed);
        let bound = 2.0 * lambda(k as i32) * k as f64 * d1;
        eprintln!("order {k}: f32 vs f64 gaps {dg:.2e}, velocities {dv:.2e}; bound {bound:.2e} (order 1: {d1:.2e})");
        assert!(
            dg <= bound && dv <= bound,
            "order {k}: {dg:e} {dv:e} > {bound:e}"
        );
    }
    let tolerance = 1e-4;
    let adaptive = Stepping::Adaptive {
        tolerance,
        dt_initial: 1e-4,
        dt_min: 1e-12,
    };
    let (dg, dv) = diff(Order::Auto, adaptive);
    eprintln!("auto at {tolerance:e}: f32 vs f64 gaps {dg:.2e}, velocities {dv:.2e}");
    assert!(
        dg <= 10.0 * tolerance && dv <= 10.0 * tolerance,
        "auto: {dg:e} {dv:e}"
    );
}

/// Auto in f32 ends its steps only in columns whose rounding stays 10 times below the tolerance
/// (`top_column`: 3 at 1e-4, 4 at 2e-4), on the CPU and in the GPU's twin alike, where in f64
/// the same members end in higher columns; CPU f32 and GPU f32 take the same number of steps to 5
/// % plus one a member.
#[test]
fn auto_in_f32_keeps_to_the_columns_its_rounding_allows() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let (chain, members, chains) = case_one_chains();
    for (tolerance, top) in [(1e-4, 3u8), (2e-4, 4)] {
        assert_eq!(top_column(tolerance, true, false), top);
        let adaptive = Stepping::Adaptive {
            tolerance,
            dt_initial: 1e-4,
            dt_min: 1e-12,
        };
        let plan = plan_for(
            &chain,
            members.clone(),
            Order::Auto,
            adaptive,
            vec![0.0, 0.1, 0.2],
            None,
        );
        let (_, f64_reports) = run_cpu(&plan, &chains);
        let (_, cpu32) = run_cpu_in(&plan, &chains, Precision::F32);
        let (_, gpu32) = run_gpu(&ctx, &plan, &chains, Precision::F32);
        let columns = |r: &[MemberReport]| r.iter().map(|m| m.last_order).collect::<Vec<_>>();
        let steps = |r: &[MemberReport]| r.iter().map(|m| m.steps_accepted).sum::<u64>() as f64;
        eprintln!(
            "tolerance {tolerance:e}: last columns f64 {:?}, CPU f32 {:?}, GPU f32 {:?}; steps {} {} {}",
            columns(&f64_reports),
            columns(&cpu32),
            columns(&gpu32),
            steps(&f64_reports),
            steps(&cpu32),
            steps(&gpu32)
        );
        assert!(columns(&f64_reports).iter().any(|&k| k > top));
        for r in cpu32.iter().chain(&gpu32) {
            assert_eq!(r.status, MemberStatus::Ok, "{r:?}");
            assert!(r.last_order <= top, "{tolerance:e}: {r:?}");
        }
        assert!(
            (steps(&cpu32) - steps(&gpu32)).abs() <= 0.05 * steps(&cpu32) + members.len() as f64,
            "{tolerance:e}: CPU f32 {} steps, GPU f32 {}",
            steps(&cpu32),
            steps(&gpu32)
        );
    }
}

/// CPU f32 against GPU f32, the two f32 twins of one kernel (orders 1 and 2, fixed steps): each
/// is within the bound above of f64 (2·steps·(gamma_max + 1)·u32, times 5 at order 2, where
/// T_22 = 2·T_2 − T_1 weighs the rows' rounding by |w_j|·n_j = 1 + 4), so they agree to twice
/// it; they differ only by rounding (exp and ln: the GPU's native f32, the CPU's f64 twins
/// rounded once; the step h: rounded from f64 on the CPU, computed in f32 on the GPU), with the
/// same accepted steps.
#[test]
fn cpu_f32_agrees_with_gpu_f32() {
    let Some(ctx) = acquire_for_tests(false) else {
        return;
    };
    let u32_eps = 2f64.powi(-24);
    let chain = profile_chain(200, "0.7", "0.5*sin(2*pi*x)", Some("0.7"));
    let members = sweep();
    let (dt, steps) = (1e-3, 200.0);
    let gamma_max = members.iter().fold(1.0f64, |m, p| m.max(p.gamma));
    for (order, gain) in [(1u8, 1.0), (2, 5.0)] {
        let plan = plan_for(
            &chain,
            members.clone(),
            order,
            Stepping::Fixed { dt, dt_min: 1e-9 },
            vec![0.0, 0.1, 0.2],
            None,
        );
        let chains = vec![chain.clone(); members.len()];
        let (cpu32, cpu_reports) = run_cpu_in(&plan, &chains, Precision::F32);
        let (gpu32, gpu_reports) = run_gpu(&ctx, &plan, &chains, Precision::F32);
        for (c, g) in cpu_reports.iter().zip(&gpu_reports) {
            assert_eq!(c.status, MemberStatus::Ok, "{c:?}");
            assert_eq!(g.status, MemberStatus::Ok, "{g:?}");
            assert_eq!(c.steps_accepted, g.steps_accepted, "member {}", c.index);
        }
        let tolerance = 2.0 * 2.0 * steps * (gamma_max + 1.0) * u32_eps * gain;
        let (dg, dv) = max_rel_diff(&cpu32, &gpu32);
        eprintln!(
            "order {order}: CPU f32 vs GPU f32 gaps {dg:.2e}, velocities {dv:.2e}; tolerance {tolerance:.2e}"
        );
        assert!(
            dg <= tolerance && dv <= tolerance,
            "order {order}: {dg:e} {dv:e} > {tolerance:e}"
        );
    }
}

/// N = 10^6 in one member: runs (the partitioned kernel, tests/gpu_partitioned.rs, also on
/// lavapipe, whose loop budget of 65535 iterations per invocation one invocation per member
/// cannot meet) and agrees with the CPU (its partitioned solve at this N, to the same 1e-10);
/// with the partitioned kernel turned off, lavapipe refuses it with an error naming the limit
/// and what to change.
#[test]
fn a_million_particles_run_or_are_refused_clearly() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let chain = profile_chain(
        1_000_000,
        "0.5 + 0.2*sin(2*pi*x)",
        "0.3*sin(2*pi*x)",
        Some("0.6"),
    );
    let plan = plan_for(
        &chain,
        vec![MemberParams {
            mu: 0.01,
            gamma: 2.0,
        }],
        1,
        Stepping::Fixed {
            dt: 1e-4,
            dt_min: 1e-12,
        },
        vec![0.0, 3e-4],
        None,
    );
    let chains = vec![chain];
    assert_f64_agreement(&ctx, "N = 1e6", &plan, &chains);
    let off = roughlub::backend::gpu::solver::GpuPartition::Off;
    match GpuSolver::new_with(&ctx, plan, chains, Precision::F64, off) {
        Ok(_) => assert!(
            !ctx.description.name.to_lowercase().contains("llvmpipe"),
            "lavapipe ran N = 1e6 in one invocation"
        ),
        Err(e) => {
            let message = e.to_string();
            eprintln!("{message}");
            assert!(
                matches!(e, roughlub::backend::gpu::GpuError::LoopLimit { .. })
                    && message.contains("65535")
                    && message.contains("--backend cpu"),
                "{message}"
            );
        }
    }
}
