//! Stability at the extremes (issue 8): energy never rises, near-contact gaps are right in ln d
//! at any size (against an independent log-gap reference), failures say what happened.

mod common;

use common::reference::log_gap_reference;
use common::{plan_for, run_all};
use roughlub::backend::{BatchSolver, MemberStatus};
use roughlub::expr::Expr;
use roughlub::model::chain::Chain;
use roughlub::model::observables::Snapshot;
use roughlub::model::params::{Jacobian, MemberParams, Stepping};
use roughlub::model::plan::Plan;
use roughlub::scene::initial::chain_from_profiles;

fn chain(n: usize, rho: &str, u: &str, rho_star: &str) -> Chain {
    chain_from_profiles(
        n,
        &Expr::parse(rho).unwrap(),
        &Expr::parse(u).unwrap(),
        Some(&Expr::parse(rho_star).unwrap()),
    )
    .unwrap()
}

/// Runs every output interval on the CPU in `precision`.
fn run_cpu_in(
    plan: roughlub::model::plan::Plan,
    chains: Vec<Chain>,
    precision: roughlub::backend::Precision,
) -> (Vec<Vec<Snapshot>>, Vec<roughlub::backend::MemberReport>) {
    let mut solver = roughlub::backend::cpu::CpuSolver::with_precision(plan, chains, precision);
    let mut out = Vec::new();
    while let Some(s) = solver.next_output(&|_| {}).unwrap() {
        out.push(s);
    }
    (out, solver.reports())
}

fn times(end: f64, count: usize) -> Vec<f64> {
    (0..count)
        .map(|k| end * k as f64 / (count - 1) as f64)
        .collect()
}

/// Case-1 data with gamma = 1000 and fixed dt = 1e-3 (the blow-up: 0.045 → 1.4e10 before):
/// with f = 0 the energy of every output is at most the previous one (relative 1e-12), for both
/// orders and for adaptive steps, and every member completes.
#[test]
fn energy_never_rises_at_gamma_1000() {
    let c = chain(200, "0.7", "0.5*sin(2*pi*x)", "0.7");
    let params = vec![
        MemberParams {
            mu: 0.01,
            gamma: 1000.0,
        },
        MemberParams {
            mu: 0.01,
            gamma: 200.0,
        },
    ];
    let fixed = Stepping::Fixed {
        dt: 1e-3,
        dt_min: 1e-12,
    };
    let adaptive = Stepping::Adaptive {
        tolerance: 1e-5,
        dt_initial: 1e-3,
        dt_min: 1e-12,
    };
    for (order, stepping) in [(1u8, fixed), (2, fixed), (1, adaptive)] {
        let plan = plan_for(&c, params.clone(), order, stepping, times(0.4, 401), None);
        let (snaps, solver) = run_all(plan, vec![c.clone(); 2]);
        for (m, report) in solver.reports().iter().enumerate() {
            assert_eq!(report.status, MemberStatus::Ok, "order {order}: {report:?}");
            let energy: Vec<f64> = snaps.iter().map(|s| s[m].energy).collect();
            for k in 1..energy.len() {
                assert!(
                    energy[k] <= energy[k - 1] * (1.0 + 1e-12),
                    "order {order} {stepping:?}, member {m}: energy rose from {} to {} at output {k}",
                    energy[k - 1],
                    energy[k]
                );
            }
            eprintln!(
                "order {order} {stepping:?} gamma {}: E {:.4} -> {:.4}, {} steps, {} rejected",
                report.gamma,
                energy[0],
                energy[energy.len() - 1],
                report.steps_accepted,
                report.steps_rejected
            );
        }
    }
}

/// The strong-compression scene (rho0 = 0.99, rho*0 = 0.995, gamma = 20, u0 = 0.5 sin 2πx) at
/// mu = 1e-5, where gaps fall far below f64's range (ln d ~ -13000): the solver's ln d against the
/// fully implicit log-gap reference (`log_gap_reference`, a different scheme), within 1e-3
/// relative in ln d and 1e-3 in velocity; sum d conserved to 1e-12. Through these collisions the
/// reference converges at first order (its velocities move by 1.8e-3, 8.6e-4, 4.3e-4, 2.1e-4 from
/// 5000 to 80000 steps), so it is extrapolated once more from 40000 and 80000 steps; that agrees
/// with the same from 20000 and 40000 to 1.1e-5 in velocity and 0.08 in ln d (measured). The
/// solver at dt = 5e-5 is 4.0e-4 from it (the W-method before the exact Jacobian: 1.2e-3; the
/// 10000-step reference this test used before was itself 1.7e-3 off).
#[test]
fn gaps_below_the_float_range_match_a_log_gap_reference() {
    let n = 24;
    let c = chain(n, "0.99", "0.5*sin(2*pi*x)", "0.995");
    let (mu, gamma, t_end) = (1e-5, 20.0, 0.05);
    let reference = |steps| chain_log_gap_reference(&c, mu, gamma, t_end, steps);
    let ((coarse_s, coarse_u), (fine_s, fine_u)) = (reference(40_000), reference(80_000));
    let extrapolate = |fine: &[f64], coarse: &[f64]| -> Vec<f64> {
        fine.iter().zip(coarse).map(|(f, c)| 2.0 * f - c).collect()
    };
    let (ref_s, ref_u) = (
        extrapolate(&fine_s, &coarse_s),
        extrapolate(&fine_u, &coarse_u),
    );
    let smallest = ref_s.iter().cloned().fold(f64::INFINITY, f64::min);
    eprintln!("reference: smallest ln d = {smallest:.3}");
    assert!(smallest < -800.0, "test data: gaps below the f64 range");
    for (jacobian, dt) in [(Jacobian::Exact, 5e-5), (Jacobian::Frozen, 2.5e-5)] {
        let plan = Plan {
            jacobian,
            ..plan_for(
                &c,
                vec![MemberParams { mu, gamma }],
                2,
                Stepping::Fixed { dt, dt_min: 1e-12 },
                vec![0.0, t_end],
                None,
            )
        };
        let (snaps, solver) = run_all(plan, vec![c.clone()]);
        assert_eq!(solver.reports()[0].status, MemberStatus::Ok);
        let last = &snaps[1][0];
        let got_min = last.log_min_gap;
        eprintln!("{jacobian:?}, dt {dt}: smallest ln d = {got_min:.3}");
        assert!(
            (got_min - smallest).abs() <= 1e-3 * smallest.abs(),
            "{jacobian:?}: smallest ln d {got_min} vs reference {smallest}"
        );
        let du = last
            .velocities
            .iter()
            .zip(&ref_u)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(du <= 1e-3, "{jacobian:?}: velocities differ by {du}");
        let sum: f64 = last.gaps.iter().sum();
        let total: f64 = c.gaps.iter().sum();
        assert!(
            (sum - total).abs() <= 1e-12 * total,
            "sum d {sum} vs {total}"
        );
    }
}

/// The same in f32 on the CPU: every member completes and the energy of every output is at most
/// the previous one plus the f32 energy check's slack, relative ENERGY_RTOL_F32 +
/// ENERGY_RTOL_PER_GAMMA_F32·gamma (1e-5 + 2.4e-7·gamma, the f32 GPU kernel's; an extrapolated
/// state's check allows EXTRAPOLATED_ENERGY_SLACK_MAX = 1e-6 more, which this leaves out), where the
/// linearised repulsion overshoots by orders of magnitude unchecked. With fixed steps the energy
/// stays within the f32-vs-f64 rounding bound 2·steps·(gamma + 1)·2^-24 relative of f64's
/// (tests/cpu_f32.rs; steps: the member's accepted steps, 400 to 570 here); the adaptive runs
/// (order 1 at 1e-5: 26000 to 55000 steps, where that bound exceeds 1) are only printed
/// (measured: 3.8e-2 at gamma 1000).
#[test]
fn energy_never_rises_at_gamma_1000_in_f32() {
    use roughlub::backend::shared::control::{ENERGY_RTOL_F32, ENERGY_RTOL_PER_GAMMA_F32};
    use roughlub::backend::Precision;
    let c = chain(200, "0.7", "0.5*sin(2*pi*x)", "0.7");
    let params = vec![
        MemberParams {
            mu: 0.01,
            gamma: 1000.0,
        },
        MemberParams {
            mu: 0.01,
            gamma: 200.0,
        },
    ];
    let fixed = Stepping::Fixed {
        dt: 1e-3,
        dt_min: 1e-12,
    };
    let adaptive = Stepping::Adaptive {
        tolerance: 1e-5,
        dt_initial: 1e-3,
        dt_min: 1e-12,
    };
    for (order, stepping) in [(1u8, fixed), (2, fixed), (1, adaptive)] {
        let plan = plan_for(&c, params.clone(), order, stepping, times(0.4, 401), None);
        let (snaps, reports) = run_cpu_in(plan.clone(), vec![c.clone(); 2], Precision::F32);
        let (snaps64, _) = run_cpu_in(plan, vec![c.clone(); 2], Precision::F64);
        for (m, report) in reports.iter().enumerate() {
            assert_eq!(report.status, MemberStatus::Ok, "order {order}: {report:?}");
            let rtol = ENERGY_RTOL_F32 + ENERGY_RTOL_PER_GAMMA_F32 * report.gamma;
            let bound = 2.0 * report.steps_accepted as f64 * (report.gamma + 1.0) * 2f64.powi(-24);
            let mut worst = 0.0f64;
            let energy: Vec<f64> = snaps.iter().map(|s| s[m].energy).collect();
            for k in 1..energy.len() {
                assert!(
                    energy[k] <= energy[k - 1] * (1.0 + rtol),
                    "f32 order {order} {stepping:?}, member {m}: energy rose from {} to {} at output {k}",
                    energy[k - 1],
                    energy[k]
                );
                let e64 = snaps64[k][m].energy;
                worst = worst.max((energy[k] - e64).abs() / e64);
                assert!(
                    matches!(stepping, Stepping::Adaptive { .. })
                        || (energy[k] - e64).abs() <= bound * e64,
                    "f32 order {order} {stepping:?}, member {m}: energy {} vs f64 {e64} at output {k}",
                    energy[k]
                );
            }
            eprintln!(
                "f32 order {order} {stepping:?} gamma {}: E {:.4} -> {:.4} (f64 {:.4}; largest relative difference {worst:.1e}, bound {bound:.1e}), {} steps, {} rejected",
                report.gamma,
                energy[0],
                energy[energy.len() - 1],
                snaps64[energy.len() - 1][m].energy,
                report.steps_accepted,
                report.steps_rejected
            );
        }
    }
}

/// Member m of an f64 run without forcing, at every output: ln of its smallest gap finite (every
/// gap positive, even below f64's range), sum d equal to `total` within 1e-12 relative, and the
/// energy never above the previous output's (1e-12 relative).
fn assert_member_sound(label: &str, snaps: &[Vec<Snapshot>], m: usize, total: f64) {
    assert_member_sound_within(label, snaps, m, total, 1e-12, 1e-12);
}

/// [`assert_member_sound`] with sum d kept to `sum_rtol` and the energy allowed to rise by
/// `energy_rtol` (both relative) from one output to the next.
fn assert_member_sound_within(
    label: &str,
    snaps: &[Vec<Snapshot>],
    m: usize,
    total: f64,
    sum_rtol: f64,
    energy_rtol: f64,
) {
    for k in 0..snaps.len() {
        let s = &snaps[k][m];
        assert!(
            s.log_min_gap.is_finite(),
            "{label}: ln min gap {}",
            s.log_min_gap
        );
        let sum: f64 = s.gaps.iter().sum();
        assert!(
            (sum - total).abs() <= sum_rtol * total,
            "{label}: sum d {sum}"
        );
        if k > 0 {
            let before = snaps[k - 1][m].energy;
            assert!(
                s.energy <= before * (1.0 + energy_rtol),
                "{label}: energy {before} -> {} at output {k}",
                s.energy
            );
        }
    }
}

/// A pair at contact that flies apart with little lubrication (mu = 1e-4) opens by m Δu / mu
/// whatever the step (mu ln d changes by the momentum). scenes/extremes/rho0.9999_u0.5.toml and
/// rho0.9999_u2.toml with fixed order 4 at dt = 1e-3, on both tableau sequences: every member
/// completes (before `NEGLIGIBLE_OPENING` the mu = 1e-4 members failed at t = 6.4e-5, every
/// retry of a step opening a gap of e^-556 beyond the e^5 safeguard, where order 1 completes),
/// every gap stays positive, sum d is kept to 1e-12 and the energy never rises (1e-12
/// relative), and the members at mu = 1e-4 say that this step does not resolve them: an error
/// estimate above 1 (measured 2.0e2 to 1.4e3). The GPU in f64 (the WGSL twin of the safeguard)
/// takes the same steps and ends within 1e-10 of the CPU in ln d, relative (measured 1.2e-11).
#[test]
fn fixed_high_orders_complete_where_a_contact_pair_flies_apart() {
    use roughlub::backend::gpu::solver::GpuSolver;
    use roughlub::backend::Precision;
    use roughlub::model::params::{Order, Sequence};
    use roughlub::scene::Scene;
    let ctx = common::gpu::acquire_for_tests(true);
    for name in ["rho0.9999_u0.5", "rho0.9999_u2"] {
        let path = format!("{}/scenes/extremes/{name}.toml", env!("CARGO_MANIFEST_DIR"));
        let text = std::fs::read_to_string(&path).unwrap();
        let scene = Scene::from_toml(&text, std::path::Path::new(&path)).unwrap();
        let chain = scene.initial_chain().unwrap();
        let total: f64 = chain.gaps.iter().sum();
        for sequence in [Sequence::FromOne, Sequence::FromTwo] {
            let mut plan = scene.plan(&chain, scene.precision);
            plan.order = Order::Fixed(4);
            plan.sequence = sequence;
            let members = plan.members.len();
            let chains = vec![chain.clone(); members];
            let (snaps, solver) = run_all(plan.clone(), chains.clone());
            if let (Some(ctx), Sequence::FromOne) = (&ctx, sequence) {
                let mut gpu = GpuSolver::new(ctx, plan.clone(), chains, Precision::F64).unwrap();
                let mut last = None;
                while let Some(s) = gpu.next_output(&|_| {}).unwrap() {
                    last = Some(s);
                }
                let last = last.unwrap();
                for (m, (g, c)) in gpu.reports().iter().zip(solver.reports()).enumerate() {
                    let label = format!("{name} gpu mu {} gamma {}", c.mu, c.gamma);
                    assert_eq!(g.status, c.status, "{label}");
                    assert_eq!(
                        (g.steps_accepted, g.steps_rejected),
                        (c.steps_accepted, c.steps_rejected),
                        "{label}"
                    );
                    let (a, b) = (last[m].log_min_gap, snaps.last().unwrap()[m].log_min_gap);
                    assert!(
                        (a - b).abs() <= 1e-10 * b.abs().max(1.0),
                        "{label}: ln min gap {a} vs {b}"
                    );
                }
            }
            for (m, r) in solver.reports().iter().enumerate() {
                let label = format!("{name} {sequence:?} mu {} gamma {}", r.mu, r.gamma);
                assert_eq!(r.status, MemberStatus::Ok, "{label}");
                assert_member_sound(&label, &snaps, m, total);
                for s in &snaps {
                    assert!(s[m].gaps.iter().all(|&d| d >= 0.0), "{label}: a gap < 0");
                }
                if r.mu == 1e-4 {
                    let estimate = r.largest_error_estimate().unwrap_or(0.0);
                    eprintln!("{label}: error estimate {estimate:.2e}");
                    assert!(estimate > 1.0, "{label}: error estimate {estimate}");
                }
            }
        }
    }
}

/// Column 8's weights amplify the rows' rounding 3392 times (9851 from 2), and with gamma = 1000
/// each ulp of a gap is 1000 ulps of G: the extrapolated state's energy may carry up to ~1e-9 of
/// E in rounding, where the energy check allowed 1e-12 (the sums'). scenes/extremes/rho0.9_u2.toml's
/// mu = 1, gamma = 1000 member at N = 24 with fixed order 8 at dt = 1e-3 failed on both
/// sequences ("every smaller step raised the energy", at t = 0.1 from 1 and 0.076 from 2); with
/// the slack of `extrapolated_energy_rtol` it completes in 200 steps, sum d kept to 1e-12, the
/// energy at the outputs never above the one before by more than 1e-10 relative (a rise of
/// 3.5e-12 measured, where E has fallen to 1e-16 of its start), and it ends within 1e-9 of auto
/// at tolerance 1e-10 in ln d and velocities (relative to the largest initial |u|, 2; measured
/// 8.3e-12 from 1, 2.4e-11 from 2). The GPU in f64 (the WGSL twins), with one invocation per
/// member and partitioned in segments of 8 rows, takes the same steps and ends within 1e-10 of
/// the CPU in ln d.
#[test]
fn order_eight_completes_where_the_energy_barely_falls() {
    use roughlub::backend::gpu::solver::{GpuPartition, GpuSolver};
    use roughlub::backend::Precision;
    use roughlub::model::params::{Order, Sequence};
    use roughlub::scene::Scene;
    let ctx = common::gpu::acquire_for_tests(true);
    let path = format!(
        "{}/scenes/extremes/rho0.9_u2.toml",
        env!("CARGO_MANIFEST_DIR")
    );
    let text = std::fs::read_to_string(&path)
        .unwrap()
        .replace("particles = 200", "particles = 24");
    let text = text
        .lines()
        .map(|l| match l.split('=').next().map(str::trim) {
            Some("mu") if l.contains('[') => "mu = [1.0]",
            Some("gamma") if l.contains('[') => "gamma = [1000.0]",
            _ => l,
        })
        .collect::<Vec<_>>()
        .join("\n");
    let scene = Scene::from_toml(&text, std::path::Path::new(&path)).unwrap();
    let chain = scene.initial_chain().unwrap();
    assert_eq!(chain.gaps.len(), 24);
    let total: f64 = chain.gaps.iter().sum();
    let mut reference_plan = scene.plan(&chain, scene.precision);
    assert_eq!(reference_plan.members.len(), 1);
    assert_eq!(reference_plan.members[0].gamma, 1000.0);
    reference_plan.order = Order::Auto;
    reference_plan.stepping = Stepping::Adaptive {
        tolerance: 1e-10,
        dt_initial: 1e-5,
        dt_min: 1e-14,
    };
    let (reference, solver) = run_all(reference_plan, vec![chain.clone()]);
    assert_eq!(solver.reports()[0].status, MemberStatus::Ok);
    let reference = &reference.last().unwrap()[0];
    for sequence in [Sequence::FromOne, Sequence::FromTwo] {
        let mut plan = scene.plan(&chain, scene.precision);
        plan.order = Order::Fixed(8);
        plan.sequence = sequence;
        let (snaps, solver) = run_all(plan.clone(), vec![chain.clone()]);
        let r = &solver.reports()[0];
        let label = format!("{sequence:?}");
        assert_eq!(r.status, MemberStatus::Ok, "{label}");
        assert_eq!((r.steps_accepted, r.steps_rejected), (200, 0), "{label}");
        assert_member_sound_within(&label, &snaps, 0, total, 1e-12, 1e-10);
        let last = &snaps.last().unwrap()[0];
        let mut worst = 0.0f64;
        for (d, d_ref) in last.gaps.iter().zip(&reference.gaps) {
            worst = worst.max((d.ln() - d_ref.ln()).abs());
        }
        for (u, u_ref) in last.velocities.iter().zip(&reference.velocities) {
            worst = worst.max((u - u_ref).abs() / 2.0);
        }
        eprintln!("{label}: order 8 at dt = 1e-3 against auto at 1e-10: {worst:.2e}");
        assert!(worst <= 1e-9, "{label}: {worst:e}");
        let Some(ctx) = &ctx else { continue };
        for partition in [GpuPartition::Off, GpuPartition::SegmentRows(8)] {
            let label = format!("{label} gpu {partition:?}");
            let mut gpu = GpuSolver::new_with(
                ctx,
                plan.clone(),
                vec![chain.clone()],
                Precision::F64,
                partition,
            )
            .unwrap();
            let mut gpu_last = None;
            while let Some(s) = gpu.next_output(&|_| {}).unwrap() {
                gpu_last = Some(s);
            }
            let g = &gpu.reports()[0];
            assert_eq!(g.status, MemberStatus::Ok, "{label}");
            assert_eq!(
                (g.steps_accepted, g.steps_rejected),
                (r.steps_accepted, r.steps_rejected),
                "{label}"
            );
            let (a, b) = (gpu_last.unwrap()[0].log_min_gap, last.log_min_gap);
            assert!(
                (a - b).abs() <= 1e-10 * b.abs().max(1.0),
                "{label}: ln min gap {a} vs {b}"
            );
        }
    }
}

/// The extremes matrix (scenes/extremes/: rho0 ∈ {0.9, 0.99, 0.9999} × u0 amplitude ∈ {0, 0.5, 2}
/// files, each with mu ∈ {1e-4, 1e-2, 1, 1e3} × gamma ∈ {1, 20, 100, 1000}) at N = 200: every member
/// completes, every gap stays positive (ln d finite, even below the float range), sum d is kept
/// to 1e-12 and the energy never rises (relative 1e-12; f = 0). On the GPU (where an adapter
/// exists): f64 equals the CPU to 1e-10 with the same accepted and rejected steps, and every
/// member completes in f32 with ln of the smallest gap within 1e-3·(1 + |ln d|) of f64 where
/// mu >= 1e-2 (the largest deviation is printed). The CPU in f32 meets the GPU f32's bounds, and
/// its energy never rises beyond the f32 slack (1e-5 + 2.4e-7·gamma relative) with sum d kept to
/// 1e-5 (f32 rounding of the projection's scale and of a sum of 200 gaps).
#[test]
fn extremes_matrix_completes_conserves_and_never_gains_energy() {
    use roughlub::backend::gpu::solver::GpuSolver;
    use roughlub::backend::Precision;
    use roughlub::scene::Scene;
    let ctx = common::gpu::acquire_for_tests(true);
    let mut files: Vec<_> =
        std::fs::read_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/extremes"))
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
    files.sort();
    assert_eq!(files.len(), 9);
    let mut worst_f32 = (0.0f64, String::new(), 0.0, 0.0);
    let mut worst_cpu_f32 = (0.0f64, String::new(), 0.0, 0.0);
    for path in files {
        let text = std::fs::read_to_string(&path).unwrap();
        let scene = Scene::from_toml(&text, &path).unwrap();
        let chain = scene.initial_chain().unwrap();
        let plan = scene.plan(&chain, scene.precision);
        let members = plan.members.len();
        assert_eq!(members, 16);
        let total: f64 = chain.gaps.iter().sum();
        let chains = vec![chain; members];
        let (snaps, solver) = run_all(plan.clone(), chains.clone());
        let reports = solver.reports();
        for (m, r) in reports.iter().enumerate() {
            let label = format!("{} mu {} gamma {}", path.display(), r.mu, r.gamma);
            assert_eq!(r.status, MemberStatus::Ok, "{label}");
            assert_member_sound(&label, &snaps, m, total);
        }
        {
            use roughlub::backend::shared::control::{ENERGY_RTOL_F32, ENERGY_RTOL_PER_GAMMA_F32};
            let (out, reports32) = run_cpu_in(plan.clone(), chains.clone(), Precision::F32);
            for (m, (r, c)) in reports32.iter().zip(&reports).enumerate() {
                let label = format!("{} cpu f32 mu {} gamma {}", path.display(), c.mu, c.gamma);
                assert_eq!(r.status, MemberStatus::Ok, "{label}");
                let rtol = ENERGY_RTOL_F32 + ENERGY_RTOL_PER_GAMMA_F32 * c.gamma;
                assert_member_sound_within(&label, &out, m, total, 1e-5, rtol);
                for k in 0..out.len() {
                    let (a, b) = (&out[k][m], &snaps[k][m]);
                    let dev = (a.log_min_gap - b.log_min_gap).abs() / (1.0 + b.log_min_gap.abs());
                    if dev > worst_cpu_f32.0 {
                        worst_cpu_f32 = (dev, label.clone(), a.log_min_gap, b.log_min_gap);
                    }
                    if c.mu >= 1e-2 {
                        assert!(
                            dev <= 1e-3,
                            "{label}: f32 ln min gap {} vs f64 {}",
                            a.log_min_gap,
                            b.log_min_gap
                        );
                    }
                }
            }
        }
        let Some(ctx) = &ctx else { continue };
        for precision in [Precision::F64, Precision::F32] {
            let mut gpu = GpuSolver::new(ctx, plan.clone(), chains.clone(), precision).unwrap();
            let mut out = Vec::new();
            while let Some(s) = gpu.next_output(&|_| {}).unwrap() {
                out.push(s);
            }
            let gpu_reports = gpu.reports();
            for (m, (g, c)) in gpu_reports.iter().zip(&reports).enumerate() {
                let label = format!(
                    "{} {precision:?} mu {} gamma {}",
                    path.display(),
                    c.mu,
                    c.gamma
                );
                assert_eq!(g.status, MemberStatus::Ok, "{label}");
                for k in 0..out.len() {
                    let (a, b) = (&out[k][m], &snaps[k][m]);
                    if precision == Precision::F64 {
                        // The CPU step uses the kernel's exp and ln (`backend::shared::f64_math`): with libm's
                        // an ulp now and then grew to 1e-6 in the hard-collision corner.
                        for (x, y) in a.velocities.iter().zip(&b.velocities) {
                            assert!(
                                (x - y).abs() <= 1e-10 * (1.0 + y.abs()),
                                "{label}: u {x} vs {y}"
                            );
                        }
                        assert!(
                            (a.log_min_gap - b.log_min_gap).abs() <= 1e-10 * b.log_min_gap.abs(),
                            "{label}: ln min gap {} vs {}",
                            a.log_min_gap,
                            b.log_min_gap
                        );
                    } else if precision == Precision::F32 {
                        let dev =
                            (a.log_min_gap - b.log_min_gap).abs() / (1.0 + b.log_min_gap.abs());
                        if dev > worst_f32.0 {
                            worst_f32 = (dev, label.clone(), a.log_min_gap, b.log_min_gap);
                        }
                        assert!(a.log_min_gap.is_finite(), "{label}: f32 ln min gap");
                        // Bounded where fixed dt = 1e-3 resolves the dynamics (measured: 4e-5 at
                        // most); at mu = 1e-4 dt and dt/2 differ by hundreds in ln d themselves,
                        // and f32 by up to 5 % (printed, not bounded).
                        if c.mu >= 1e-2 {
                            assert!(
                                dev <= 1e-3,
                                "{label}: f32 ln min gap {} vs f64 {}",
                                a.log_min_gap,
                                b.log_min_gap
                            );
                        }
                    }
                }
            }
        }
    }
    eprintln!("largest f32 deviation of ln min gap (relative to 1 + |ln d|): {worst_f32:?}");
    eprintln!("largest CPU f32 deviation of ln min gap: {worst_cpu_f32:?}");
}

fn failure_of(report: &roughlub::backend::MemberReport) -> (String, f64) {
    match &report.status {
        MemberStatus::Failed { reason, time } => (reason.clone(), *time),
        s => panic!("expected a failure, got {s:?}"),
    }
}

/// Each failure reason, triggered and checked by its text: a forcing that is not finite (named
/// with t, x and the particle), a repulsion that overflows (gamma, rho/rho*, the gap, the member)
/// and a step-size collapse (the reason of the last rejection, the time and the smallest gap).
#[test]
fn failures_say_what_happened() {
    let fixed = Stepping::Fixed {
        dt: 1e-3,
        dt_min: 1e-12,
    };
    let params = vec![MemberParams {
        mu: 0.01,
        gamma: 2.0,
    }];
    // sqrt of a negative number left of x = 0.5: particle 1 fails at t = 0.
    let c = chain(40, "0.7", "0.5*sin(2*pi*x)", "0.7");
    let plan = plan_for(
        &c,
        params.clone(),
        1,
        fixed,
        vec![0.0, 0.01],
        Some(("sqrt(x-0.5)", 2)),
    );
    let (_, solver) = run_all(plan, vec![c.clone()]);
    let (reason, time) = failure_of(&solver.reports()[0]);
    assert_eq!(time, 0.0);
    let x = c.positions()[1];
    assert_eq!(
        reason,
        format!("the forcing is not finite at t = 0, x = {x} (particle 1 of member 0)")
    );

    // rho/rho* = 3 everywhere with gamma = 1000: 3^1000 overflows f64 at once (the scene
    // validation refuses this up front; the solver says so for members built otherwise).
    let c3 = chain(40, "0.9", "0", "0.3");
    let plan = plan_for(
        &c3,
        vec![MemberParams {
            mu: 0.01,
            gamma: 1000.0,
        }],
        1,
        fixed,
        vec![0.0, 0.01],
        None,
    );
    let (_, solver) = run_all(plan, vec![c3]);
    let (reason, time) = failure_of(&solver.reports()[0]);
    assert_eq!(time, 0.0);
    let prefix = "the repulsion (rho/rho*)^gamma overflows at t = 0: gamma = 1000, rho/rho* = ";
    assert!(reason.starts_with(prefix), "{reason}");
    let rest = &reason[prefix.len()..];
    let ratio: f64 = rest.split(' ').next().unwrap().parse().unwrap();
    assert!((ratio - 3.0).abs() < 1e-9, "{reason}");
    assert!(rest.ends_with(" at gap 1 of member 0"), "{reason}");

    // gamma = 1000, weak lubrication, dt = 0.01 with dt_min = 2e-3: every retry down to dt_min
    // raises the energy; the message names the reason, the time and the smallest gap.
    let plan = plan_for(
        &c,
        vec![MemberParams {
            mu: 1e-4,
            gamma: 1000.0,
        }],
        1,
        Stepping::Fixed {
            dt: 0.01,
            dt_min: 2e-3,
        },
        vec![0.0, 0.2],
        None,
    );
    let (_, solver) = run_all(plan, vec![c.clone()]);
    let (reason, time) = failure_of(&solver.reports()[0]);
    let prefix = format!("step size collapsed below dt_min = 2e-3 at t = {time}: ");
    assert!(reason.starts_with(&prefix), "{reason}");
    assert!(
        reason.contains("every smaller step raised the energy beyond the work of the forcing")
            || reason.contains("every smaller step gave a non-finite value"),
        "{reason}"
    );
    assert!(reason.contains("(smallest gap: d_"), "{reason}");
}

/// The strong-compression scene in f32 on the CPU (gaps fall below f32's range: smallest
/// ~e^-150 at mu = 1e-3, where GAP_FLOOR_F32 = 1e-24 is e^-55) against the log-gap reference: the
/// member completes, ln of the smallest gap within 1e-3 relative of the reference and of the
/// CPU's f64, sum d kept to 1e-6 (f32 rounding of a sum of 24 gaps, with margin).
#[test]
fn f32_on_the_cpu_survives_gaps_below_its_range() {
    use roughlub::backend::Precision;
    let n = 24;
    let c = chain(n, "0.99", "0.5*sin(2*pi*x)", "0.995");
    let (mu, gamma, t_end) = (1e-3, 20.0, 0.05);
    let (ref_s, _) = chain_log_gap_reference(&c, mu, gamma, t_end, 10_000);
    let smallest = ref_s.iter().cloned().fold(f64::INFINITY, f64::min);
    assert!(
        smallest < -88.0,
        "test data: below f32's range ({smallest})"
    );
    let plan = plan_for(
        &c,
        vec![MemberParams { mu, gamma }],
        2,
        Stepping::Fixed {
            dt: 5e-5,
            dt_min: 1e-12,
        },
        vec![0.0, t_end],
        None,
    );
    let (cpu, _) = run_all(plan.clone(), vec![c.clone()]);
    let (out, reports) = run_cpu_in(plan, vec![c.clone()], Precision::F32);
    assert_eq!(reports[0].status, MemberStatus::Ok);
    let got = out[1][0].log_min_gap;
    eprintln!(
        "cpu f32: smallest ln d {got:.4}, f64 {:.4}, reference {smallest:.4}",
        cpu[1][0].log_min_gap
    );
    assert!(
        (got - smallest).abs() <= 1e-3 * smallest.abs(),
        "{got} vs {smallest}"
    );
    assert!((got - cpu[1][0].log_min_gap).abs() <= 1e-3 * smallest.abs());
    let sum: f64 = out[1][0].gaps.iter().sum();
    let total: f64 = c.gaps.iter().sum();
    assert!(
        (sum - total).abs() <= 1e-6 * total,
        "sum d {sum} vs {total}"
    );
}

/// The strong-compression scene in f32 on the GPU (gaps fall below f32's range: smallest ~e^-150
/// at mu = 1e-3) against the log-gap reference: the member completes, ln of the smallest gap
/// within 1e-3 relative of the reference and of the CPU's f64, sum d kept to 1e-6.
#[test]
fn f32_on_the_gpu_survives_gaps_below_its_range() {
    use roughlub::backend::gpu::solver::GpuSolver;
    use roughlub::backend::Precision;
    let Some(ctx) = common::gpu::acquire_for_tests(false) else {
        return;
    };
    let n = 24;
    let c = chain(n, "0.99", "0.5*sin(2*pi*x)", "0.995");
    let (mu, gamma, t_end) = (1e-3, 20.0, 0.05);
    let (ref_s, _) = chain_log_gap_reference(&c, mu, gamma, t_end, 10_000);
    let smallest = ref_s.iter().cloned().fold(f64::INFINITY, f64::min);
    assert!(
        smallest < -88.0,
        "test data: below f32's range ({smallest})"
    );
    let plan = plan_for(
        &c,
        vec![MemberParams { mu, gamma }],
        2,
        Stepping::Fixed {
            dt: 5e-5,
            dt_min: 1e-12,
        },
        vec![0.0, t_end],
        None,
    );
    let (cpu, _) = run_all(plan.clone(), vec![c.clone()]);
    let mut gpu = GpuSolver::new(&ctx, plan, vec![c.clone()], Precision::F32).unwrap();
    let mut out = Vec::new();
    while let Some(s) = gpu.next_output(&|_| {}).unwrap() {
        out.push(s);
    }
    assert_eq!(gpu.reports()[0].status, MemberStatus::Ok);
    let got = out[1][0].log_min_gap;
    eprintln!(
        "f32: smallest ln d {got:.4}, f64 {:.4}, reference {smallest:.4}",
        cpu[1][0].log_min_gap
    );
    assert!(
        (got - smallest).abs() <= 1e-3 * smallest.abs(),
        "{got} vs {smallest}"
    );
    assert!((got - cpu[1][0].log_min_gap).abs() <= 1e-3 * smallest.abs());
    let sum: f64 = out[1][0].gaps.iter().sum();
    let total: f64 = c.gaps.iter().sum();
    assert!(
        (sum - total).abs() <= 1e-6 * total,
        "sum d {sum} vs {total}"
    );
}

/// [`log_gap_reference`] of chain `c` from its own state (ln d, u, d*).
fn chain_log_gap_reference(
    c: &Chain,
    mu: f64,
    gamma: f64,
    t_end: f64,
    steps: usize,
) -> (Vec<f64>, Vec<f64>) {
    let log_gaps: Vec<f64> = c.gaps.iter().map(|d| d.ln()).collect();
    let dstar = c.dstar.as_deref().expect("a chain with roughness");
    log_gap_reference(
        c.eps,
        mu,
        gamma,
        &log_gaps,
        &c.velocities,
        dstar,
        t_end,
        steps,
    )
}

/// Prop. 3.1 at the extremes of rho0 (a profile down to 1e-7, and one of 100 periods whose
/// values carry the rounding of their argument, ~1e-13): every cell holds the mass 2 eps of the
/// exact primitive of rho0 to 1e-12.
/// Both used to bisect their quadrature to depth 40 (the run never started).
#[test]
fn initial_positions_hold_their_mass_for_profiles_near_zero_and_of_high_frequency() {
    for (amplitude, frequency, n) in [(0.4999999, 2.0, 40), (0.4, 200.0, 2000)] {
        let rho = format!("0.5+{amplitude}*sin({frequency}*pi*x)");
        let c = chain_from_profiles(
            n,
            &Expr::parse(&rho).unwrap(),
            &Expr::parse("0").unwrap(),
            None,
        )
        .unwrap();
        let pi = std::f64::consts::PI;
        // M(x) = 0.5 x + A (1 - cos(f pi x))/(f pi) = 0.5 x + 2 A sin^2(f pi x/2)/(f pi).
        let mass = |x: f64| {
            0.5 * x + 2.0 * amplitude * (0.5 * frequency * pi * x).sin().powi(2) / (frequency * pi)
        };
        let total = mass(1.0);
        assert!(
            (2.0 * c.eps * n as f64 - total).abs() <= 1e-12,
            "{rho}: eps"
        );
        let mut q = 0.0;
        for (i, d) in c.gaps.iter().enumerate() {
            q += d + 2.0 * c.eps;
            let want = total * (i + 1) as f64 / n as f64;
            assert!(
                (mass(q) - want).abs() <= 1e-12,
                "{rho}: cell {}: M(q) = {} against {want}",
                i + 1,
                mass(q)
            );
        }
    }
}
