//! The partitioned GPU kernel (few members, huge N: `shaders/partitioned.wgsl`) against the CPU's
//! sequential sweep: 1e-12 relative on every gap and on the velocities (relative to the largest),
//! the same accepted and rejected steps, orders and status, at moderate N with short segments
//! forced (segment boundaries next to clusters and to gaps below GAP_FLOOR), and above the old
//! loop limit of one invocation per member on lavapipe. GPU tests go through
//! `acquire_for_tests(true)` (skipped without an f64 adapter unless `ROUGHLUB_REQUIRE_GPU=1`).

mod common;

use common::gpu::acquire_for_tests;
use common::{plan_for, random_chain, Rng};
use roughlub::backend::cpu::CpuSolver;
use roughlub::backend::gpu::partitioned::Segments;
use roughlub::backend::gpu::solver::{GpuPartition, GpuSolver};
use roughlub::backend::gpu::GpuContext;
use roughlub::backend::shared::gaps::GAP_FLOOR;
use roughlub::backend::{BatchSolver, MemberReport, MemberStatus, Precision};
use roughlub::model::chain::Chain;
use roughlub::model::observables::Snapshot;
use roughlub::model::params::{Jacobian, MemberParams, Order, Sequence, Stepping};
use roughlub::model::plan::Plan;

/// The CPU's sequential sweep is what the GPU is compared with: every N here is below its
/// partition threshold (2^18).
fn run_cpu(plan: &Plan, chains: &[Chain]) -> (Vec<Vec<Snapshot>>, Vec<MemberReport>) {
    let mut solver = CpuSolver::new(plan.clone(), chains.to_vec());
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
    partition: GpuPartition,
) -> (Vec<Vec<Snapshot>>, Vec<MemberReport>) {
    let mut solver = GpuSolver::new_with(ctx, plan.clone(), chains.to_vec(), precision, partition)
        .unwrap_or_else(|e| panic!("{e}"));
    let mut out = Vec::new();
    while let Some(s) = solver
        .next_output(&|_| {})
        .unwrap_or_else(|e| panic!("{e}"))
    {
        out.push(s);
    }
    let stats = solver.stats();
    eprintln!("{precision:?}: {stats:?}");
    assert!(stats.segments > 1, "the partitioned kernel ran: {stats:?}");
    let errors = ctx.take_uncaptured_errors();
    assert!(errors.is_empty(), "{errors:?}");
    (out, solver.reports())
}

/// Largest relative difference of gaps and of velocities, over all outputs and members: a gap
/// against itself (exact zeros must match), in ln d below GAP_FLOOR (the kernel stores ln d
/// there, ~ -690 for the gaps of 1e-300 here, so ln d's own rounding is ~1e-13 absolute: the
/// relative error of the stored value is what both backends can keep); velocities against the
/// member's largest |u|.
fn differences(a: &[Vec<Snapshot>], b: &[Vec<Snapshot>]) -> (f64, f64) {
    assert_eq!(a.len(), b.len());
    let mut worst = (0.0f64, 0.0f64);
    for (sa, sb) in a.iter().zip(b) {
        for (ma, mb) in sa.iter().zip(sb) {
            for (&x, &y) in ma.gaps.iter().zip(&mb.gaps) {
                if y == 0.0 {
                    assert_eq!(x, 0.0, "a gap zero on one backend only");
                } else if y < GAP_FLOOR {
                    worst.0 = worst.0.max((x.ln() - y.ln()).abs() / y.ln().abs());
                } else {
                    worst.0 = worst.0.max((x - y).abs() / y.abs());
                }
            }
            let scale = mb.velocities.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for (&x, &y) in ma.velocities.iter().zip(&mb.velocities) {
                worst.1 = worst.1.max((x - y).abs() / scale);
            }
        }
    }
    worst
}

/// The tolerance for orders 1 and 2: rounding only (the same operations, the solve reordered).
const TOL: f64 = 1e-12;
/// Orders 3 to 8: the tableau's weights (hundreds at order 6, a thousand at 8) amplify the solves' rounding
/// differences, as between the backends in tests/gpu_solver.rs (which allows 1e-10 there).
const TOL_HIGH_ORDER: f64 = 1e-10;

/// GPU f64 (partitioned as `partition` says) against the CPU's sequential sweep: 1e-12 on gaps
/// and velocities (1e-10 above order 2), the same accepted/rejected steps, status, order and
/// (to rounding) last dt.
fn assert_agreement(
    ctx: &GpuContext,
    label: &str,
    plan: &Plan,
    chains: &[Chain],
    partition: GpuPartition,
) {
    let (cpu, cpu_reports) = run_cpu(plan, chains);
    let (gpu, gpu_reports) = run_gpu(ctx, plan, chains, Precision::F64, partition);
    let (dg, dv) = differences(&gpu, &cpu);
    eprintln!("{label}: GPU partitioned vs CPU: gaps {dg:.2e}, velocities {dv:.2e}");
    for (g, c) in gpu_reports.iter().zip(&cpu_reports) {
        eprintln!(
            "{label}: member {}: accepted {} rejected {} order {} status {:?}",
            c.index, c.steps_accepted, c.steps_rejected, c.last_order, c.status
        );
        assert_eq!(
            (g.steps_accepted, g.steps_rejected, g.last_order),
            (c.steps_accepted, c.steps_rejected, c.last_order),
            "{label}: member {} steps and order",
            c.index
        );
        assert_eq!(g.status, c.status, "{label}: member {} status", c.index);
        // dt comes from the error estimate, a difference of tableau rows of about the
        // tolerance (1e-5..1e-8 of the state), so the state's rounding differences (~1e-14)
        // reach it amplified by 1/tolerance: 1e-7 at order 2, as in tests/gpu_solver.rs 1e-5
        // above (the tableau's weights reach hundreds; a thousand at columns 7 and 8, where
        // tests/gpu_solver.rs measured 3.6e-5).
        let dt_tol = match plan.order.columns() {
            0..=2 => 1e-7,
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
    }
    let tol = if plan.order.columns() <= 2 {
        TOL
    } else {
        TOL_HIGH_ORDER
    };
    assert!(
        dg <= tol && dv <= tol,
        "{label}: gaps {dg:e}, velocities {dv:e} (tolerance {tol:e})"
    );
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

/// Gap indices at the segments' boundaries (each segment's first gap, and its neighbours).
fn boundary_gaps(segments: Segments) -> Vec<usize> {
    let mut out = Vec::new();
    for s in 1..segments.segments {
        let b = segments.rows(s).start as usize;
        out.extend([b - 2, b - 1, b]);
    }
    out
}

/// Three members of N = `n` with their own roughness and mu, gamma 1, 2 and 3.5.
fn members_and_chains(n: usize, seed: u64) -> (Vec<MemberParams>, Vec<Chain>) {
    let mut rng = Rng(seed);
    let eps = 0.35 / n as f64;
    let chains: Vec<Chain> = (0..3)
        .map(|_| random_chain(&mut rng, n, eps, Some(0.6 * eps)))
        .collect();
    let members = [1.0, 2.0, 3.5]
        .iter()
        .map(|&gamma| MemberParams {
            mu: rng.uniform(0.005, 0.05),
            gamma,
        })
        .collect();
    (members, chains)
}

/// Segments of 97 rows (N = 3001: 30 segments, some one row longer): roughness and forcing,
/// order 1 with fixed steps and order 2 adaptive with either matrix.
#[test]
fn short_segments_agree_with_the_sequential_sweep() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let n = 3001;
    let (members, chains) = members_and_chains(n, 31);
    for (order, stepping, jacobian) in [
        (1, FIXED, Jacobian::Auto),
        (2, ADAPTIVE, Jacobian::Frozen),
        (2, ADAPTIVE, Jacobian::Exact),
    ] {
        let plan = Plan {
            jacobian,
            ..plan_for(
                &chains[0],
                members.clone(),
                order,
                stepping,
                vec![0.0, 0.02, 0.04],
                Some(("0.3*sin(2*pi*x)*cos(3*t)", 3)),
            )
        };
        assert_agreement(
            &ctx,
            &format!("N = {n}, order {order}, {stepping:?}, {jacobian:?}"),
            &plan,
            &chains,
            GpuPartition::SegmentRows(97),
        );
    }
}

/// Clusters (bonded gaps at and next to segment boundaries, bodies glued to both walls, one
/// cluster over a whole segment) and gaps of 1e-300 (below GAP_FLOOR, stored as ln d) at and
/// next to boundaries and at the walls: the rates across the interfaces, the rigid bodies and
/// the log-form updates agree.
#[test]
fn clusters_and_near_contact_at_segment_boundaries_agree() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let n = 2001;
    let rows = 61;
    let segments = Segments::new(n, rows);
    let boundaries = boundary_gaps(segments);
    let (members, chains) = members_and_chains(n, 5);
    // Clusters: glued to the left wall (gaps 0..3), boundary gaps of every third segment, a
    // whole segment (rows of segment 10 and its first gap), glued to the right wall.
    let mut bonded = vec![false; n];
    for g in [0, 1, 2, n - 2, n - 1] {
        bonded[g] = true;
    }
    for (k, &g) in boundaries.iter().enumerate() {
        if (k / 3) % 3 == 0 {
            bonded[g] = true;
        }
    }
    let whole = segments.rows(10);
    bonded[whole.start as usize - 1..whole.end as usize].fill(true);
    // Near contact: boundary gaps of the other segments, and gaps inside segments.
    let mut near: Vec<usize> = boundaries
        .iter()
        .enumerate()
        .filter(|(k, _)| (k / 3) % 3 == 1)
        .map(|(_, &g)| g)
        .collect();
    near.extend([5, 300, 301, 302, n - 4]);
    near.retain(|&g| !bonded[g]);
    let chains: Vec<Chain> = chains
        .into_iter()
        .map(|mut c| {
            for &g in &near {
                c.gaps[g] = 1e-300;
            }
            for (g, &b) in bonded.iter().enumerate() {
                if b {
                    c.gaps[g] = 0.0;
                }
            }
            c.bonded = Some(bonded.clone());
            c
        })
        .collect();
    for (order, stepping) in [(1, FIXED), (2, ADAPTIVE)] {
        let plan = plan_for(
            &chains[0],
            members.clone(),
            order,
            stepping,
            vec![0.0, 0.01, 0.02],
            Some(("sin(6*x)*(1+t)", 3)),
        );
        let label = format!("clusters and near contact, order {order}");
        assert_agreement(
            &ctx,
            &label,
            &plan,
            &chains,
            GpuPartition::SegmentRows(rows),
        );
        // The near-contact gaps are still below GAP_FLOOR (the log form was exercised), and
        // the bonded ones exactly 0 with equal velocities on both sides.
        let (gpu, _) = run_gpu(
            &ctx,
            &plan,
            &chains,
            Precision::F64,
            GpuPartition::SegmentRows(rows),
        );
        let last = &gpu.last().unwrap()[0];
        assert!(near.iter().any(|&g| last.gaps[g] < 1e-250), "{label}");
        for (g, &b) in bonded.iter().enumerate() {
            if b {
                assert_eq!(last.gaps[g], 0.0, "{label}: bonded gap {g} opened");
            }
        }
        assert_eq!(last.velocities[0], 0.0, "{label}: glued to the left wall");
        assert_eq!(
            last.velocities[n - 2],
            0.0,
            "{label}: glued to the right wall"
        );
    }
}

/// Orders 3 to 8 and auto (each member its own order per step: members idle through the
/// substeps they do not take) at short segments.
#[test]
fn higher_orders_and_auto_agree() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let n = 1201;
    let (members, chains) = members_and_chains(n, 77);
    let tight = Stepping::Adaptive {
        tolerance: 1e-8,
        dt_initial: 1e-4,
        dt_min: 1e-12,
    };
    for (order, stepping) in [
        (Order::Fixed(3), FIXED),
        (Order::Fixed(6), FIXED),
        (Order::Fixed(8), FIXED),
        (Order::Auto, tight),
    ] {
        let plan = plan_for(
            &chains[0],
            members.clone(),
            order,
            stepping,
            vec![0.0, 0.01, 0.02],
            Some(("0.3*sin(2*pi*x)*cos(3*t)", 3)),
        );
        assert_agreement(
            &ctx,
            &format!("N = {n}, order {}, {stepping:?}", order.label()),
            &plan,
            &chains,
            GpuPartition::SegmentRows(50),
        );
    }
}

/// A chain too long for one invocation per member on lavapipe with auto's 8 columns, and too
/// short for the default cut to make two segments of it (N = 400: 399 rows, 178 loop iterations
/// a row with the tableau, 71208 in all, above the driver's 65535): the default choice cuts it
/// into segments that fit, on the default and the from_2 sequence, and agrees with the CPU (the
/// tolerances of `assert_agreement`). Before, it failed with a loop-limit error that advised N
/// <= 1503232. (Elsewhere than lavapipe one invocation per member runs it: nothing to test.)
#[test]
fn a_chain_too_long_for_the_default_cut_is_cut_to_fit() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let n = 400;
    let (members, chains) = members_and_chains(n, 5);
    let (members, chains) = (members[..1].to_vec(), chains[..1].to_vec());
    let tight = Stepping::Adaptive {
        tolerance: 1e-6,
        dt_initial: 1e-4,
        dt_min: 1e-12,
    };
    for sequence in [Sequence::FromOne, Sequence::FromTwo] {
        let mut plan = plan_for(
            &chains[0],
            members.clone(),
            Order::Auto,
            tight,
            vec![0.0, 0.01],
            None,
        );
        plan.sequence = sequence;
        let choice = GpuSolver::check(&ctx, &plan, Precision::F64).unwrap();
        let d = &ctx.description;
        let lavapipe = format!("{} {}", d.name, d.driver)
            .to_lowercase()
            .contains("llvmpipe");
        let Some(segments) = choice.segments else {
            // Other drivers have no loop budget: one invocation per member runs it.
            assert!(!lavapipe, "lavapipe needs the partitioned kernel here");
            return;
        };
        assert_eq!(segments.segments, 2, "{segments:?}");
        assert_agreement(
            &ctx,
            &format!("N = {n}, auto, {sequence:?}"),
            &plan,
            &chains,
            GpuPartition::Auto,
        );
    }
}

/// Steps too large for gamma = 300 and 1000: rejections and retries agree, and a member whose
/// dt collapses fails at the same time with the same smallest gap named.
#[test]
fn rejections_and_failures_agree() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let n = 1501;
    let (_, chains) = members_and_chains(n, 9);
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
    let plan = plan_for(
        &chains[0],
        members,
        1,
        Stepping::Fixed {
            dt: 0.01,
            dt_min: 1e-3,
        },
        vec![0.0, 0.05, 0.1],
        None,
    );
    let (_, cpu) = run_cpu(&plan, &chains);
    assert!(
        cpu.iter().any(|r| r.steps_rejected > 0),
        "test data: rejections"
    );
    assert!(
        cpu.iter()
            .any(|r| matches!(r.status, MemberStatus::Failed { .. })),
        "test data: a failure {cpu:?}"
    );
    assert_agreement(
        &ctx,
        "rejections",
        &plan,
        &chains,
        GpuPartition::SegmentRows(100),
    );
}

/// Above the old limit of one invocation per member on lavapipe (N = 50000 > 32767 at order 1):
/// the default choice takes the partitioned kernel and agrees with the CPU, order 1 with fixed
/// steps and order 2 adaptive, a few steps.
#[test]
fn beyond_the_old_loop_limit_runs_and_agrees() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let n = 50_000;
    let expr = |s: &str| roughlub::expr::Expr::parse(s).unwrap();
    let chain = roughlub::scene::initial::chain_from_profiles(
        n,
        &expr("0.5 + 0.2*sin(2*pi*x)"),
        &expr("0.3*sin(2*pi*x)"),
        Some(&expr("0.6 + 0.1*cos(6*x)")),
    )
    .unwrap();
    let members = vec![
        MemberParams {
            mu: 0.01,
            gamma: 2.0,
        },
        MemberParams {
            mu: 0.003,
            gamma: 3.5,
        },
    ];
    let chains = vec![chain; 2];
    for (order, stepping, end) in [
        (
            1,
            Stepping::Fixed {
                dt: 1e-4,
                dt_min: 1e-12,
            },
            3e-4,
        ),
        (2, ADAPTIVE, 2e-3),
    ] {
        let plan = plan_for(
            &chains[0],
            members.clone(),
            order,
            stepping,
            vec![0.0, end],
            None,
        );
        let choice = GpuSolver::check(&ctx, &plan, Precision::F64).unwrap();
        assert!(choice.segments.is_some(), "{choice:?}");
        assert_agreement(
            &ctx,
            &format!("N = {n}, order {order}"),
            &plan,
            &chains,
            GpuPartition::Auto,
        );
    }
}

/// f32 through the partitioned kernel against the CPU in f64, measured against the f32 error
/// of the one-invocation-per-member kernel (tests/gpu_solver.rs bounds that one) on the same
/// chains: the spike and the reduced system add no cancellation (their pivots are >= 1), so the
/// partitioned solve may differ in its rounding but not lose more than a factor 2 over it.
/// (Random chains at N = 3001 are worse conditioned than that test's mild scenes: both errors
/// here are ~1e-5, above its 2 × steps × (gamma + 1) × 2^-24 = 2.1e-5 for velocities.)
#[test]
fn f32_loses_no_more_than_the_sequential_f32_kernel() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let n = 3001;
    let (members, chains) = members_and_chains(n, 41);
    let plan = plan_for(&chains[0], members, 1, FIXED, vec![0.0, 0.02, 0.04], None);
    let (cpu, reports) = run_cpu(&plan, &chains);
    assert!(reports.iter().all(|r| r.status == MemberStatus::Ok));
    let (gpu, reports32) = run_gpu(
        &ctx,
        &plan,
        &chains,
        Precision::F32,
        GpuPartition::SegmentRows(97),
    );
    assert!(reports32
        .iter()
        .all(|r| r.status == MemberStatus::Ok && r.steps_accepted == 40));
    let mut sequential =
        GpuSolver::new_with(&ctx, plan, chains, Precision::F32, GpuPartition::Off).unwrap();
    let mut reference = Vec::new();
    while let Some(s) = sequential.next_output(&|_| {}).unwrap() {
        reference.push(s);
    }
    let (dg, dv) = differences(&gpu, &cpu);
    let (sg, sv) = differences(&reference, &cpu);
    eprintln!(
        "f32 vs CPU f64: partitioned gaps {dg:.2e}, velocities {dv:.2e}; one invocation per member gaps {sg:.2e}, velocities {sv:.2e}"
    );
    assert!(
        dg <= 2.0 * sg && dv <= 2.0 * sv,
        "{dg:e} {dv:e} vs {sg:e} {sv:e}"
    );
    assert!(dg <= 1e-4 && dv <= 1e-4, "{dg:e} {dv:e}");
}

/// N = 10^6, one member (smooth profiles), order 2 adaptive, a few steps: runs on lavapipe and
/// agrees with the CPU (whose partitioned solve takes this N) like the runs above. Ignored by
/// default (slow here): `cargo test --release --test gpu_partitioned -- --ignored`.
#[test]
#[ignore]
fn a_million_particles_order_2_adaptive() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let expr = |s: &str| roughlub::expr::Expr::parse(s).unwrap();
    let chain = roughlub::scene::initial::chain_from_profiles(
        1_000_000,
        &expr("0.5 + 0.2*sin(2*pi*x)"),
        &expr("0.3*sin(2*pi*x)"),
        Some(&expr("0.6")),
    )
    .unwrap();
    let members = vec![MemberParams {
        mu: 0.01,
        gamma: 2.0,
    }];
    let plan = plan_for(&chain, members, 2, ADAPTIVE, vec![0.0, 1e-3], None);
    let chains = vec![chain];
    let (_, cpu) = run_cpu(&plan, &chains);
    assert!(
        cpu[0].status == MemberStatus::Ok && cpu[0].steps_accepted >= 3,
        "test data: {cpu:?}"
    );
    assert_agreement(
        &ctx,
        "N = 1e6, order 2 adaptive",
        &plan,
        &chains,
        GpuPartition::Auto,
    );
}
