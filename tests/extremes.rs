//! Stability at the extremes (issue 8): energy never rises, near-contact gaps are right in ln d
//! at any size (against an independent log-gap reference), failures say what happened.

mod common;

use common::reference::log_gap_reference;
use common::{plan_for, run_all};
use roughlub::backend::{BatchSolver, MemberStatus};
use roughlub::expr::Expr;
use roughlub::model::chain::Chain;
use roughlub::model::params::{MemberParams, Stepping};
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
/// mu = 1e-5, where gaps fall far below f64's range (ln d ~ -1000): the solver's ln d against the
/// fully implicit log-gap reference (`log_gap_reference`, a different scheme, Richardson
/// extrapolated at 5e-6), within 1e-3 relative in ln d; sum d conserved to 1e-12.
#[test]
fn gaps_below_the_float_range_match_a_log_gap_reference() {
    let n = 24;
    let c = chain(n, "0.99", "0.5*sin(2*pi*x)", "0.995");
    let (mu, gamma, t_end) = (1e-5, 20.0, 0.05);
    let dstar = c.dstar.clone().unwrap();
    let log_gaps: Vec<f64> = c.gaps.iter().map(|d| d.ln()).collect();
    let (ref_s, ref_u) =
        log_gap_reference(c.eps, mu, gamma, &log_gaps, &c.velocities, &dstar, t_end, 10_000);
    let smallest = ref_s.iter().cloned().fold(f64::INFINITY, f64::min);
    eprintln!("reference: smallest ln d = {smallest:.3}");
    assert!(smallest < -800.0, "test data: gaps below the f64 range");
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
    let (snaps, solver) = run_all(plan, vec![c.clone()]);
    assert_eq!(solver.reports()[0].status, MemberStatus::Ok);
    let last = &snaps[1][0];
    let got_min = last.log_min_gap;
    eprintln!("solver: smallest ln d = {got_min:.3}");
    assert!(
        (got_min - smallest).abs() <= 1e-3 * smallest.abs(),
        "smallest ln d {got_min} vs reference {smallest}"
    );
    let du = last
        .velocities
        .iter()
        .zip(&ref_u)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(du <= 1e-3, "velocities differ by {du}");
    let sum: f64 = last.gaps.iter().sum();
    let total: f64 = c.gaps.iter().sum();
    assert!((sum - total).abs() <= 1e-12 * total, "sum d {sum} vs {total}");
}
