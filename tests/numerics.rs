//! Numerical checks of the CPU solver against independent expectations.

mod common;

use common::reference::{dense_reference_step, rk4_reference};
use common::{plan_for, random_chain, run_all, Rng};
use roughlub::backend::cpu::step::{euler_step, EnergyWanted, Gamma, Scratch, StepBuffers, Terms};
use roughlub::backend::cpu::SimdLevel;
use roughlub::backend::BatchSolver;
use roughlub::backend::MemberStatus;
use roughlub::expr::Expr;
use roughlub::model::chain::stored_gap;
use roughlub::model::observables::{dissipation, energy, grid_points, observe, Snapshot};
use roughlub::model::params::{Jacobian, MemberParams, Order, Sequence, Stepping, MAX_ORDER};
use roughlub::model::plan::{Forcing, Plan, Power};
use roughlub::model::quadrature::GaussLegendre;
use {roughlub::model::chain::Chain, roughlub::scene::initial::chain_from_profiles};

const L: usize = 8;

/// F_i for f(t, x) = 0.5 x² − 0.3 x³ + t x, integrated exactly over [q − eps, q + eps].
fn cubic_force(eps: f64) -> impl Fn(f64, f64) -> f64 {
    move |q: f64, t: f64| {
        let prim = |x: f64| 0.5 * x.powi(3) / 3.0 - 0.3 * x.powi(4) / 4.0 + t * x * x / 2.0;
        prim(q + eps) - prim(q - eps)
    }
}

fn interleave(lanes: &[Vec<f64>]) -> Vec<f64> {
    let len = lanes[0].len();
    (0..len * L).map(|k| lanes[k % L][k / L]).collect()
}

#[test]
fn batched_thomas_step_matches_dense_lu_on_random_spd_systems() {
    let mut rng = Rng(42);
    for with_clusters in [false, true] {
        for trial in 0..6 {
            let n = 5 + trial * 7;
            let eps = 0.3 / n as f64;
            let chains: Vec<Chain> = (0..L)
                .map(|_| {
                    let mut c = random_chain(&mut rng, n, eps, Some(0.5 * eps));
                    if with_clusters {
                        // Random bonded gaps: a gap of 0 whose two particles share one velocity.
                        let mut bonded = vec![false; n];
                        for (g, b) in bonded.iter_mut().enumerate() {
                            *b = g + 1 < n && rng.uniform(0.0, 1.0) < 0.3;
                        }
                        bonded[0] = rng.uniform(0.0, 1.0) < 0.5; // sometimes glued to the left wall
                        let freed: f64 = c
                            .gaps
                            .iter()
                            .zip(&bonded)
                            .filter(|(_, &b)| b)
                            .map(|(d, _)| d)
                            .sum();
                        let free_count = bonded.iter().filter(|&&b| !b).count() as f64;
                        for (d, &b) in c.gaps.iter_mut().zip(&bonded) {
                            *d = if b { 0.0 } else { *d + freed / free_count };
                        }
                        let mut u_all = vec![0.0; n + 1];
                        u_all[1..n].copy_from_slice(&c.velocities);
                        for g in 1..=n {
                            if bonded[g - 1] {
                                u_all[g] = u_all[g - 1];
                            }
                        }
                        u_all[n] = 0.0;
                        c.velocities = u_all[1..n].to_vec();
                        c.bonded = Some(bonded);
                    }
                    c
                })
                .collect();
            let mu: [f64; L] = std::array::from_fn(|_| rng.uniform(1e-3, 0.1));
            let gammas: [f64; L] = std::array::from_fn(|_| rng.uniform(1.0, 6.0).round());
            let h: [f64; L] = std::array::from_fn(|_| rng.uniform(1e-4, 1e-2));
            let t: [f64; L] = std::array::from_fn(|_| rng.uniform(0.0, 1.0));
            let gaps = interleave(&chains.iter().map(|c| c.gaps.clone()).collect::<Vec<_>>());
            let vel = interleave(
                &chains
                    .iter()
                    .map(|c| c.velocities.clone())
                    .collect::<Vec<_>>(),
            );
            let dstar = interleave(
                &chains
                    .iter()
                    .map(|c| c.dstar.clone().unwrap())
                    .collect::<Vec<_>>(),
            );
            let bonded_lanes: Vec<Vec<bool>> = chains
                .iter()
                .map(|c| c.bonded.clone().unwrap_or(vec![false; n]))
                .collect();
            let bonded: Vec<bool> = (0..n * L).map(|k| bonded_lanes[k % L][k / L]).collect();
            let forcing = Forcing {
                expr: Expr::parse("0.5*x^2 - 0.3*x^3 + t*x").unwrap(),
                rule: GaussLegendre::new(3), // exact for this cubic
                params: Vec::new(),
            };
            let total_gap: [f64; L] = std::array::from_fn(|l| chains[l].gaps.iter().sum());
            let terms = Terms::<L> {
                eps,
                mu,
                total_gap,
                // Large: the energy is always computed (and checked against the model's below).
                contact_repulsion: [f64::INFINITY; L],
                exact_jacobian: false,
                energy: EnergyWanted::UnlessCertified,
                repulsion: Some((&dstar, Gamma::PerLane(gammas))),
                bonded: with_clusters.then_some(bonded.as_slice()),
                forcing: Some(&forcing),
                forcing_params: [&[]; L],
                simd: SimdLevel::widest_here(),
                partition: true,
            };
            let mut gaps_out = vec![0.0; gaps.len()];
            let mut vel_out = vec![0.0; vel.len()];
            let mut scratch = Scratch::new(n, L);
            let reports = euler_step(
                &terms,
                n,
                &t,
                &h,
                StepBuffers {
                    gaps_in: &gaps,
                    vel_in: &vel,
                    gaps_out: &mut gaps_out,
                    vel_out: &mut vel_out,
                    scratch: &mut scratch,
                },
            );
            for l in 0..L {
                let c = &chains[l];
                let (want_gaps, want_vel) = dense_reference_step(
                    eps,
                    mu[l],
                    gammas[l],
                    h[l],
                    t[l],
                    &c.gaps,
                    &c.velocities,
                    c.dstar.as_ref().unwrap(),
                    &bonded_lanes[l],
                    &cubic_force(eps),
                );
                let scale = want_vel.iter().fold(1e-3f64, |m, v| m.max(v.abs()));
                for i in 0..n - 1 {
                    let got = vel_out[i * L + l];
                    // Tolerance: rounding of a well-conditioned (diagonally dominant) solve.
                    assert!(
                        (got - want_vel[i]).abs() <= 1e-11 * scale,
                        "clusters={with_clusters} n={n} lane {l} u_{}: {got} vs {}",
                        i + 1,
                        want_vel[i]
                    );
                }
                for i in 0..n {
                    let got = gaps_out[i * L + l];
                    assert!(
                        (got - want_gaps[i]).abs() <= 1e-12 * eps.max(want_gaps[i]),
                        "lane {l} d_{}: {got} vs {}",
                        i + 1,
                        want_gaps[i]
                    );
                }
                // Gaps are positive by construction: every step is admissible, and its reported
                // energy is the model's energy of the result.
                assert!(reports[l].admissible && reports[l].hard.is_none());
                let want_energy = energy(
                    eps,
                    gammas[l],
                    &want_gaps,
                    &want_vel,
                    c.dstar.as_deref(),
                    Some(&bonded_lanes[l]),
                );
                assert!(
                    (reports[l].energy - want_energy).abs() <= 1e-11 * want_energy,
                    "lane {l}: energy {} vs {want_energy}",
                    reports[l].energy
                );
            }
        }
    }
}

fn max_error(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// The end-time error (max over gaps + max over velocities) against the reference of fixed-step
/// runs of `order` at each of `dts`, on the test chain with forcing 0.3 sin(2πx) cos(3t); each
/// run must complete.
fn fixed_step_errors(
    chain: &Chain,
    params: &[MemberParams],
    scheme: (u8, Jacobian, Sequence),
    dts: [f64; 3],
    t_end: f64,
    (ref_gaps, ref_vel): (&[f64], &[f64]),
) -> Vec<f64> {
    dts.iter()
        .map(|&dt| {
            let stepping = Stepping::Fixed { dt, dt_min: 1e-12 };
            let forcing = Some(("0.3*sin(2*pi*x)*cos(3*t)", 8));
            let (last, status) = fixed_step_end(chain, params, scheme, stepping, t_end, forcing);
            assert_eq!(status, MemberStatus::Ok, "{scheme:?} dt {dt}");
            max_error(&last.gaps, ref_gaps) + max_error(&last.velocities, ref_vel)
        })
        .collect()
}

/// The two observed orders of `errors` at steps H, H/2, H/4 (log2 of successive ratios),
/// printed, each held to `order` ± 0.3.
fn assert_converges_at(label: &str, order: u8, errors: &[f64]) {
    let rates = [
        (errors[0] / errors[1]).log2(),
        (errors[1] / errors[2]).log2(),
    ];
    eprintln!("{label} order {order}: errors {errors:?}, measured orders {rates:.3?}");
    for p in rates {
        assert!(
            (p - order as f64).abs() <= 0.3,
            "{label} order {order}: measured {p} from errors {errors:?}"
        );
    }
}

/// The state at t_end of one member run with fixed steps of `order`, `jacobian` and the rows of
/// `sequence`, and its status.
fn fixed_step_end(
    chain: &Chain,
    params: &[MemberParams],
    (order, jacobian, sequence): (u8, Jacobian, Sequence),
    stepping: Stepping,
    t_end: f64,
    forcing: Option<(&str, usize)>,
) -> (Snapshot, MemberStatus) {
    let plan = Plan {
        jacobian,
        sequence,
        ..plan_for(
            chain,
            params.to_vec(),
            order,
            stepping,
            vec![0.0, t_end],
            forcing,
        )
    };
    let (mut snaps, solver) = run_all(plan, vec![chain.clone()]);
    (snaps[1].swap_remove(0), solver.reports()[0].status.clone())
}

#[test]
fn converges_to_independent_solution_with_orders_one_and_two() {
    let mut rng = Rng(7);
    let chain = random_chain(&mut rng, 6, 0.05, Some(0.03));
    let (mu, gamma, t_end) = (0.05, 2.0, 0.2);
    let (ref_gaps, ref_vel) = rk4_reference(&chain, mu, gamma, t_end, 20_000);
    let params = vec![MemberParams { mu, gamma }];
    for order in [1u8, 2] {
        let dts = [0.01, 0.005, 0.0025];
        let errors = fixed_step_errors(
            &chain,
            &params,
            (order, Jacobian::Frozen, Sequence::FromOne),
            dts,
            t_end,
            (&ref_gaps, &ref_vel),
        );
        let p1 = (errors[0] / errors[1]).log2();
        let p2 = (errors[1] / errors[2]).log2();
        eprintln!("order {order}: errors {errors:?}, measured orders {p1:.3} {p2:.3}");
        for p in [p1, p2] {
            assert!(
                (p - order as f64).abs() <= 0.2,
                "order {order}: measured {p} from errors {errors:?}"
            );
        }
        // Error within the scheme's order: C dt^p with a modest C (measured C ≈ 1.1 for order 1
        // and ≈ 6.5 for order 2 on this chain; see the printed errors).
        let c = if order == 1 { 3.0 } else { 20.0 };
        assert!(
            errors[2] < c * 0.0025f64.powi(order as i32),
            "order {order}: error {} too large",
            errors[2]
        );
    }
}

fn case1_chain(n: usize, rho_star: Option<&str>) -> Chain {
    chain_from_profiles(
        n,
        &Expr::parse("0.7").unwrap(),
        &Expr::parse("0.5*sin(2*pi*x)").unwrap(),
        rho_star.map(|s| Expr::parse(s).unwrap()).as_ref(),
    )
    .unwrap()
}

#[test]
fn energy_never_increases_without_forcing() {
    let chain = case1_chain(50, Some("0.7"));
    let times: Vec<f64> = (0..=100).map(|k| 0.004 * k as f64).collect();
    let members = vec![
        MemberParams {
            mu: 0.01,
            gamma: 1.0,
        },
        MemberParams {
            mu: 0.01,
            gamma: 3.0,
        },
    ];
    let steppings = [
        Stepping::Fixed {
            dt: 2e-3,
            dt_min: 1e-12,
        },
        Stepping::Adaptive {
            tolerance: 1e-5,
            dt_initial: 1e-4,
            dt_min: 1e-12,
        },
    ];
    let orders = (1..=MAX_ORDER).map(Order::Fixed).chain([Order::Auto]);
    for order in orders {
        for stepping in steppings {
            if order == Order::Auto && matches!(stepping, Stepping::Fixed { .. }) {
                continue;
            }
            let plan = plan_for(
                &chain,
                members.clone(),
                order,
                stepping,
                times.clone(),
                None,
            );
            let (snaps, _) = run_all(plan, vec![chain.clone(); 2]);
            for m in 0..2 {
                let e: Vec<f64> = snaps.iter().map(|s| s[m].energy).collect();
                assert!(
                    e[0] - e[e.len() - 1] > 1e-4,
                    "energy should decay visibly: {e:?}"
                );
                for k in 1..e.len() {
                    // Tolerance: rounding of a sum of ~100 terms of size ~|E|.
                    assert!(
                        e[k] <= e[k - 1] + 1e-13 * e[k - 1].abs(),
                        "order {} {stepping:?} gamma {}: E rose from {} to {} at t = {}",
                        order.label(),
                        members[m].gamma,
                        e[k - 1],
                        e[k],
                        times[k]
                    );
                }
            }
        }
    }
}

#[test]
fn gaps_stay_positive_and_sum_is_conserved_at_the_extremes() {
    // rho0 = 0.99, gamma = 20, mu = 1e-3: gaps start at 5e-5 and the compression drives the
    // smallest ones below 1e-25, where only gaps stored with full relative precision survive.
    let chain = chain_from_profiles(
        200,
        &Expr::parse("0.99").unwrap(),
        &Expr::parse("0.2*sin(2*pi*x)").unwrap(),
        Some(&Expr::parse("0.99").unwrap()),
    )
    .unwrap();
    let total0: f64 = chain.gaps.iter().sum();
    assert!((total0 - (1.0 - 2.0 * chain.eps * 200.0)).abs() < 1e-14);
    let members = vec![MemberParams {
        mu: 1e-3,
        gamma: 20.0,
    }];
    let times: Vec<f64> = (0..=20).map(|k| 0.01 * k as f64).collect();
    for (order, stepping) in [
        (
            1u8,
            Stepping::Fixed {
                dt: 1e-3,
                dt_min: 1e-12,
            },
        ),
        (
            2u8,
            Stepping::Fixed {
                dt: 1e-3,
                dt_min: 1e-12,
            },
        ),
        (
            1u8,
            Stepping::Adaptive {
                tolerance: 1e-4,
                dt_initial: 1e-5,
                dt_min: 1e-12,
            },
        ),
        (
            2u8,
            Stepping::Adaptive {
                tolerance: 1e-6,
                dt_initial: 1e-5,
                dt_min: 1e-12,
            },
        ),
    ] {
        let plan = plan_for(
            &chain,
            members.clone(),
            order,
            stepping,
            times.clone(),
            None,
        );
        let (snaps, solver) = run_all(plan, vec![chain.clone()]);
        let report = &solver.reports()[0];
        assert_eq!(
            report.status,
            MemberStatus::Ok,
            "order {order} {stepping:?}: {report:?}"
        );
        for (k, s) in snaps.iter().enumerate() {
            let s = &s[0];
            assert!(s.min_gap > 0.0, "t = {}: min gap {}", times[k], s.min_gap);
            let total: f64 = s.gaps.iter().sum();
            // Conservation to rounding: ~N ulps of the free length 1 - 2 eps N ≈ 0.01.
            assert!(
                (total - total0).abs() <= 1e-14,
                "t = {}: sum of gaps drifted by {:e}",
                times[k],
                total - total0
            );
        }
        // The compression really reaches the extreme: some gap falls below 1e-15.
        assert!(
            snaps.iter().any(|s| s[0].min_gap < 1e-15),
            "the scene should squeeze gaps hard"
        );
    }
}

#[test]
fn prop_3_1_initial_density_error_decreases_like_one_over_n() {
    // Lipschitz, not smooth: a kink at x = 0.4.
    let rho = Expr::parse("0.5 + 0.3*abs(x - 0.4)").unwrap();
    let u = Expr::parse("0").unwrap();
    let mut errors = Vec::new();
    let sizes = [50usize, 100, 200, 400, 800];
    for &n in &sizes {
        let chain = chain_from_profiles(n, &rho, &u, None).unwrap();
        let q = chain.positions();
        // Each cell holds mass 2 eps exactly (the construction), checked by a closed-form integral.
        let mass = |a: f64, b: f64| {
            let prim = |x: f64| 0.5 * x + 0.15 * (x - 0.4) * (x - 0.4).abs();
            prim(b) - prim(a)
        };
        let mut err: f64 = 0.0;
        for i in 1..=n {
            assert!(
                (mass(q[i - 1], q[i]) - 2.0 * chain.eps).abs() < 1e-13,
                "cell {i} mass"
            );
            let rho_i = 2.0 * chain.eps / (chain.gaps[i - 1] + 2.0 * chain.eps);
            // rho0 is piecewise linear, so the sup over a cell is at its ends or at the kink.
            let mut pts = vec![q[i - 1], q[i]];
            if q[i - 1] < 0.4 && 0.4 < q[i] {
                pts.push(0.4);
            }
            for x in pts {
                err = err.max((rho_i - rho.eval(x, 0.0)).abs());
            }
        }
        errors.push(err);
    }
    for w in errors.windows(2) {
        let p = (w[0] / w[1]).log2();
        assert!((p - 1.0).abs() <= 0.2, "measured order {p} from {errors:?}");
    }
    // Constant: L0 · 2eps/δ with L0 = 0.3, δ = 0.5 (the bound in the proof of Prop. 3.1).
    for (&n, &e) in sizes.iter().zip(&errors) {
        let eps = 0.5 * (0.5 + 0.15 * (0.36 + 0.16)) / n as f64;
        assert!(
            e <= 0.3 * 2.0 * eps / 0.5,
            "N = {n}: error {e} above the proof's bound"
        );
    }
}

#[test]
fn clusters_move_rigidly() {
    // Particles 3,4,5 form a cluster; particle 1 is glued to the left wall.
    let n = 12;
    let eps = 0.025;
    let mut bonded = vec![false; n];
    bonded[0] = true; // gap 1: particles 0 and 1
    bonded[3] = true; // gap 4: particles 3 and 4
    bonded[4] = true; // gap 5: particles 4 and 5
    let free = 1.0 - 2.0 * eps * n as f64;
    let free_gaps = bonded.iter().filter(|b| !**b).count() as f64;
    let gaps: Vec<f64> = bonded
        .iter()
        .map(|&b| if b { 0.0 } else { free / free_gaps })
        .collect();
    let mut velocities: Vec<f64> = (1..n).map(|i| 0.3 * (i as f64).sin()).collect();
    velocities[0] = 0.0; // particle 1, glued to the wall
    for v in &mut velocities[2..5] {
        *v = 0.2; // particles 3, 4, 5: one cluster, one velocity
    }
    let dstar: Vec<f64> = (0..n).map(|i| 0.01 + 0.002 * (i % 3) as f64).collect();
    let chain = Chain {
        eps,
        gaps,
        velocities,
        dstar: Some(dstar),
        bonded: Some(bonded.clone()),
    };
    let times: Vec<f64> = (0..=10).map(|k| 0.02 * k as f64).collect();
    let plan = plan_for(
        &chain,
        vec![MemberParams {
            mu: 0.02,
            gamma: 2.0,
        }],
        2,
        Stepping::Adaptive {
            tolerance: 1e-6,
            dt_initial: 1e-4,
            dt_min: 1e-12,
        },
        times,
        Some(("sin(6*x)*(1+t)", 4)),
    );
    let (snaps, solver) = run_all(plan, vec![chain]);
    assert_eq!(solver.reports()[0].status, MemberStatus::Ok);
    let mut moved = false;
    for s in &snaps {
        let s = &s[0];
        for (g, &b) in bonded.iter().enumerate() {
            if b {
                assert_eq!(s.gaps[g], 0.0, "bonded gap {} opened", g + 1);
            }
        }
        assert_eq!(s.velocities[0], 0.0, "the wall-glued particle moved");
        assert_eq!(
            s.velocities[2], s.velocities[3],
            "particles 3 and 4 of the cluster"
        );
        assert_eq!(
            s.velocities[3], s.velocities[4],
            "particles 4 and 5 of the cluster"
        );
        moved |= (s.velocities[3] - 0.2).abs() > 1e-3;
    }
    assert!(moved, "the cluster should feel forces and change velocity");
}

#[test]
fn integer_and_real_power_agree() {
    for n in 0..=20u32 {
        for &r in &[0.3, 0.97, 1.0, 1.03, 2.5] {
            let a = Power::Integer(n).apply(r);
            let b = r.powf(n as f64);
            assert!(
                (a - b).abs() <= 1e-14 * b.abs().max(1e-300) * n.max(1) as f64,
                "{r}^{n}: {a} vs {b}"
            );
        }
    }
}

/// The extrapolated schemes (`order = 1..=8`: the tableau of 1, 2, …, p linearly implicit Euler
/// substeps) converge at their order against the independent RK4 reference, on a small mildly
/// stiff chain with random roughness and forcing, with either matrix (`Jacobian::Frozen`, the
/// W-method, and `Jacobian::Exact`). Each order gets steps H, H/2, H/4 in its asymptotic range,
/// with errors well above the reference's (checked: RK4 at 2× its steps moves by less than
/// 1e-13) and above rounding.
#[test]
fn extrapolation_orders_converge_at_their_order() {
    let mut rng = Rng(7);
    let chain = random_chain(&mut rng, 6, 0.05, Some(0.03));
    // mu = 0.01: stiff enough to matter, mild enough that order 6 reaches its asymptotic range
    // above the reference's accuracy (at mu = 0.05 its rates were still 5.3..5.8 there).
    let (mu, gamma, t_end) = (0.01, 2.0, 0.2);
    let (ref_gaps, ref_vel) = rk4_reference(&chain, mu, gamma, t_end, 20_000);
    let (fine_gaps, fine_vel) = rk4_reference(&chain, mu, gamma, t_end, 40_000);
    let reference_error = max_error(&ref_gaps, &fine_gaps) + max_error(&ref_vel, &fine_vel);
    eprintln!("reference moves by {reference_error:e} at twice the steps");
    assert!(
        reference_error < 1e-13,
        "reference moves by {reference_error:e}"
    );
    let params = vec![MemberParams { mu, gamma }];
    // The coarsest step of each order's three: where its rates have settled (measured over
    // dt = 0.1·2^-k, k = 0..9). Frozen: order 1 reaches 0.97 at k = 6, order 6 5.83 at k = 3
    // and the reference's accuracy from k = 6. Exact: order 4 4.06, 4.06, 4.01 from k = 2;
    // order 5 4.44 from k = 3, then 4.81, 4.93, 4.97; order 6 5.98, 5.99 from k = 3.
    let coarse_steps = |jacobian| match jacobian {
        Jacobian::Exact => [0.1 / 64.0, 0.0125, 0.00625, 0.0125, 0.00625, 0.0125],
        _ => [0.1 / 64.0, 0.0125, 0.00625, 0.0125, 0.0125, 0.0125],
    };
    for jacobian in [Jacobian::Frozen, Jacobian::Exact] {
        for (order, coarse) in (1u8..=6).zip(coarse_steps(jacobian)) {
            let dts = [coarse, coarse / 2.0, coarse / 4.0];
            let errors = fixed_step_errors(
                &chain,
                &params,
                (order, jacobian, Sequence::FromOne),
                dts,
                t_end,
                (&ref_gaps, &ref_vel),
            );
            assert_converges_at(&format!("{jacobian:?}"), order, &errors);
            assert!(
                errors[2] > 100.0 * reference_error,
                "{jacobian:?} order {order}: {errors:?} at the reference's accuracy"
            );
        }
        // Orders 7 and 8 reach the rounding floor of the extrapolation (about 1e-12 here) within
        // a few halvings, before their rates settle (measured, frozen, over dt = 0.2·2^-k: order
        // 7 climbs 4.5, 5.8, 6.1, 7.5, 6.4; order 8 5.1, 6.5, 7.6, 7.3, then 3.3 on the floor;
        // exact, over dt = 0.1·2^-k: order 7 5.7, 6.0, 7.9, 6.3, then 2.1 on the floor; order 8
        // 6.0, 8.1, 6.9, then 3.7): on their last halvings above it each converges faster than
        // order 6 (exact: 5.6 and 6.0 over order 7's steps) and is more accurate than it at
        // every step.
        for (order, coarse) in [(7u8, 0.025), (8, 0.05)] {
            let dts = [coarse, coarse / 2.0, coarse / 4.0];
            let reference = (&ref_gaps[..], &ref_vel[..]);
            let errors = fixed_step_errors(
                &chain,
                &params,
                (order, jacobian, Sequence::FromOne),
                dts,
                t_end,
                reference,
            );
            let sixth = fixed_step_errors(
                &chain,
                &params,
                (6, jacobian, Sequence::FromOne),
                dts,
                t_end,
                reference,
            );
            let rates = [
                (errors[0] / errors[1]).log2(),
                (errors[1] / errors[2]).log2(),
            ];
            eprintln!(
                "{jacobian:?} order {order}: errors {errors:?}, measured orders {rates:.3?}; order 6 {sixth:?}"
            );
            // Frozen measured 6.4 and 6.5 at least on these steps, exact 6.3.
            let faster_than_six = if jacobian == Jacobian::Exact {
                6.0
            } else {
                6.3
            };
            for p in rates {
                assert!(
                    p >= faster_than_six,
                    "{jacobian:?} order {order}: measured {p} from errors {errors:?}"
                );
            }
            for (e, e6) in errors.iter().zip(&sixth) {
                assert!(
                    e < e6,
                    "{jacobian:?} order {order}: {errors:?} not below order 6's {sixth:?}"
                );
            }
        }
    }
}

/// The rows from 2 (`[solver] sequence = "from_2"`: 2, 3, …, p + 1 substeps, weights
/// n_{j-c}/c) converge at the same orders 2 to 6 against the same RK4 reference on the same
/// chain, frozen matrix, over three steps each from the coarse steps of the test above.
#[test]
fn extrapolation_from_two_converges_at_its_order() {
    let mut rng = Rng(7);
    let chain = random_chain(&mut rng, 6, 0.05, Some(0.03));
    let (mu, gamma, t_end) = (0.01, 2.0, 0.2);
    let (ref_gaps, ref_vel) = rk4_reference(&chain, mu, gamma, t_end, 20_000);
    let params = vec![MemberParams { mu, gamma }];
    // Order 6 from 0.025: at 0.0125 its third step reached the floor (1.3e-12, rate 5.3).
    for (order, coarse) in [
        (2u8, 0.0125),
        (3, 0.00625),
        (4, 0.0125),
        (5, 0.0125),
        (6, 0.025),
    ] {
        let errors = fixed_step_errors(
            &chain,
            &params,
            (order, Jacobian::Frozen, Sequence::FromTwo),
            [coarse, coarse / 2.0, coarse / 4.0],
            t_end,
            (&ref_gaps, &ref_vel),
        );
        assert_converges_at("from 2,", order, &errors);
        assert!(
            errors[2] > 1e-11,
            "order {order}: {errors:?} at the reference's accuracy"
        );
    }
}

/// Fixed steps dt = 0.3 2^-k, k = 4..=12, to t = 0.3: the differences of successive runs (max
/// over ln d plus max over the velocities at the end) and log2 of their successive ratios, the
/// observed orders.
fn fixed_step_rates(
    chain: &Chain,
    params: &[MemberParams],
    order: u8,
    jacobian: Jacobian,
) -> (Vec<f64>, Vec<f64>) {
    fixed_step_rates_to(chain, params, order, jacobian, 0.3)
}

/// [`fixed_step_rates`] to `t_end`, at dt = t_end 2^-k.
fn fixed_step_rates_to(
    chain: &Chain,
    params: &[MemberParams],
    order: u8,
    jacobian: Jacobian,
    t_end: f64,
) -> (Vec<f64>, Vec<f64>) {
    let ends: Vec<(Vec<f64>, Vec<f64>)> = (4..=12)
        .map(|k| {
            let dt = t_end / f64::powi(2.0, k);
            let stepping = Stepping::Fixed { dt, dt_min: 1e-14 };
            let (end, status) = fixed_step_end(
                chain,
                params,
                (order, jacobian, Sequence::FromOne),
                stepping,
                t_end,
                None,
            );
            assert_eq!(status, MemberStatus::Ok);
            (end.gaps.iter().map(|d| d.ln()).collect(), end.velocities)
        })
        .collect();
    let differences: Vec<f64> = ends
        .windows(2)
        .map(|w| max_error(&w[0].0, &w[1].0) + max_error(&w[0].1, &w[1].1))
        .collect();
    let rates = differences
        .windows(2)
        .map(|w| (w[0] / w[1]).log2())
        .collect();
    (differences, rates)
}

/// The random chain's loss of order is the roughness's, not the code's: the same N = 200 chain
/// with every d* equal (rho* = rho = 0.7, the same u0, mu and gamma, the same substeps, gap
/// update, projection and energy check) keeps orders 3 to 5 within +-0.5 over at least three
/// successive halvings of dt in their asymptotic range with the exact matrix, and orders 3 and
/// 4 with the frozen one. Order 6 (exact) meets rounding while it still climbs (measured 5.46,
/// 5.61, 5.73, then 1e-12), so it is held within +-0.6; frozen orders 5 and 6 meet it after two
/// halvings inside (4.68, 4.79; 5.19, 5.46) and are printed, not held.
/// The asymptotic range: halvings whose differences both lie above 5e-12, where the
/// differences of successive runs level off at ~1e-12 (rounding of ln d and u over 4096 steps).
#[test]
fn orders_three_to_six_hold_on_a_chain_of_200_with_uniform_roughness() {
    let profile = |text: &str| Expr::parse(text).unwrap();
    let chain = chain_from_profiles(
        200,
        &profile("0.7"),
        &profile("0.5*sin(2*pi*x)"),
        Some(&profile("0.7")),
    )
    .unwrap();
    let params = [MemberParams {
        mu: 0.01,
        gamma: 2.0,
    }];
    for (order, jacobian, within) in [
        (3u8, Jacobian::Exact, 0.5),
        (4, Jacobian::Exact, 0.5),
        (5, Jacobian::Exact, 0.5),
        (6, Jacobian::Exact, 0.6),
        (3, Jacobian::Frozen, 0.5),
        (4, Jacobian::Frozen, 0.5),
        (5, Jacobian::Frozen, f64::INFINITY),
        (6, Jacobian::Frozen, f64::INFINITY),
    ] {
        let (differences, rates) = fixed_step_rates(&chain, &params, order, jacobian);
        let shown: Vec<String> = differences.iter().map(|d| format!("{d:.1e}")).collect();
        eprintln!("order {order}, {jacobian:?}: differences {shown:?}, rates {rates:.2?}");
        if within.is_infinite() {
            continue;
        }
        let resolved: Vec<bool> = differences.windows(2).map(|w| w[1] > 5e-12).collect();
        let held = rates
            .iter()
            .zip(&resolved)
            .map(|(p, &r)| r && (p - order as f64).abs() <= within)
            .collect::<Vec<bool>>();
        assert!(
            held.windows(3).any(|w| w.iter().all(|&h| h)),
            "order {order}, {jacobian:?}: no three successive halvings within +-{within} \
             above rounding: rates {rates:.2?}, differences {shown:?}"
        );
    }
}

/// Issue 22, item 1, on a realistic chain: N = 200, roughness radii uniform within ±30 % of the
/// mean (d* of gap i from its two radii), rho 0.7, u0 = 0.5 sin 2πx, gamma 2, mu 0.01, to
/// t = 0.3. Fixed steps dt = 0.3·2^-k, k = 4..12; the observed order of each halving is log2 of
/// the ratio of successive differences (max over ln d plus max over u, at the end: no reference
/// needed). With the exact Jacobian, orders 2 and 3 stay within ±0.5 of their order over all
/// seven rates (measured: 1.89..1.99 and 2.63..3.04); order 4 only over the first two (4.34,
/// 4.24), then 3.06, 2.79, 2.59, 2.25, 2.65, and order 6 4.06, then 1.2..4.5: the stiff order
/// reduction of docs/accuracy.md, printed here, not held. The frozen matrix's rates are printed
/// beside them (order 3 falls to 1.3 there).
#[test]
fn orders_on_a_random_chain_of_200() {
    let chain = random_chain_of_200();
    let params = vec![MemberParams {
        mu: 0.01,
        gamma: 2.0,
    }];
    let rates =
        |order: u8, jacobian: Jacobian| fixed_step_rates(&chain, &params, order, jacobian).1;
    for (order, halvings_held) in [(2u8, 7), (3, 7), (4, 2), (6, 0)] {
        let exact = rates(order, Jacobian::Exact);
        let frozen = rates(order, Jacobian::Frozen);
        eprintln!("order {order}: exact {exact:.2?}, frozen {frozen:.2?}");
        for p in &exact[..halvings_held] {
            assert!(
                (p - order as f64).abs() <= 0.5,
                "order {order} with the exact Jacobian: observed {p} ({exact:.2?})"
            );
        }
    }
}

/// The random chain of 200 over the issue's parameter range (gamma 1 and 20 at mu 0.01; mu 1e-3
/// and 1 at gamma 2; mu 1 to t = 0.05, as the issue measured it), exact matrix: the observed
/// orders of fixed steps dt = t_end 2^-k, k = 4..=12, printed. The reduction is that of stiff
/// problems over the steps where h λ ~ 1 for part of the chain's spectrum (docs/accuracy.md): at
/// mu = 1 the stiff modes are damped at every step measured, at mu = 1e-3 the smallest steps
/// reach the classical range, at mu = 0.01 the steps measured lie within it for every gamma.
/// Held: within ±0.5 over three successive halvings above rounding (differences above 5e-12),
/// order 3 everywhere (measured 2026-11-30: gamma 1 2.85, 2.92, 2.93, 2.94; gamma 20 2.61, 2.90,
/// 2.99; mu 1e-3 2.56, 2.69, 2.86; mu 1 2.78, 2.88, 2.94, 2.96) and order 5 at mu 1e-3 (4.77,
/// 5.22, 5.19); order 4 reaches 3.91 at mu 1e-3 and 3.82 at mu 1 (printed, not held), order 6
/// 5.87 at mu 1e-3.
#[test]
fn orders_over_the_issues_range_of_parameters() {
    let chain = random_chain_of_200();
    let cases = [
        ("gamma 1", 0.01, 1.0, 0.3),
        ("gamma 20", 0.01, 20.0, 0.3),
        ("mu 1e-3", 1e-3, 2.0, 0.3),
        ("mu 1", 1.0, 2.0, 0.05),
    ];
    let held = [
        ("gamma 1", 3u8),
        ("gamma 20", 3),
        ("mu 1e-3", 3),
        ("mu 1", 3),
        ("mu 1e-3", 5),
    ];
    for (label, mu, gamma, t_end) in cases {
        let params = [MemberParams { mu, gamma }];
        for order in [3u8, 4, 5, 6] {
            let (differences, rates) =
                fixed_step_rates_to(&chain, &params, order, Jacobian::Exact, t_end);
            let shown: Vec<String> = differences.iter().map(|d| format!("{d:.1e}")).collect();
            eprintln!("{label}, order {order}: differences {shown:?}, rates {rates:.2?}");
            if !held.contains(&(label, order)) {
                continue;
            }
            let within: Vec<bool> = rates
                .iter()
                .zip(differences.windows(2))
                .map(|(p, w)| w[1] > 5e-12 && (p - order as f64).abs() <= 0.5)
                .collect();
            assert!(
                within.windows(3).any(|w| w.iter().all(|&h| h)),
                "{label}, order {order}: no three successive halvings within +-0.5 above \
                 rounding: rates {rates:.2?}, differences {shown:?}"
            );
        }
    }
}

/// N = 200, roughness radii uniform within ±30 % of the mean (d* of gap i from its two radii),
/// rho 0.7, u0 = 0.5 sin 2πx.
fn random_chain_of_200() -> Chain {
    chain_with_random_radii(200, "0.5*sin(2*pi*x)", 11)
}

/// N particles at rho 0.7 with initial velocity `velocity`, roughness radii uniform within ±30 %
/// of the mean (d* of gap i from its two radii), drawn from `seed`.
fn chain_with_random_radii(n: usize, velocity: &str, seed: u64) -> Chain {
    let profile = |text: &str| Expr::parse(text).unwrap();
    let mut chain = chain_from_profiles(
        n,
        &profile("0.7"),
        &profile(velocity),
        Some(&profile("0.7")),
    )
    .unwrap();
    let mut rng = Rng(seed);
    let radii: Vec<f64> = (0..=n).map(|_| rng.uniform(0.7, 1.3)).collect();
    for (i, d) in chain.dstar.as_mut().unwrap().iter_mut().enumerate() {
        *d *= 0.5 * (radii[i] + radii[i + 1]);
    }
    chain
}

/// One member of `chain` with auto and adaptive steps at `tolerance` (from `dt_initial`), the
/// plan adjusted by `adjust`: its snapshot at each output time and its report (asserted ok).
fn auto_member(
    chain: &Chain,
    params: MemberParams,
    outputs: &[f64],
    tolerance: f64,
    dt_initial: f64,
    adjust: impl FnOnce(&mut Plan),
) -> (Vec<Snapshot>, roughlub::backend::MemberReport) {
    let stepping = Stepping::Adaptive {
        tolerance,
        dt_initial,
        dt_min: 1e-14,
    };
    let mut plan = plan_for(
        chain,
        vec![params],
        Order::Auto,
        stepping,
        outputs.to_vec(),
        None,
    );
    adjust(&mut plan);
    let (snaps, solver) = run_all(plan, vec![chain.clone()]);
    let report = solver.reports()[0].clone();
    assert_eq!(report.status, MemberStatus::Ok);
    (snaps.into_iter().map(|mut s| s.remove(0)).collect(), report)
}

/// The largest over output times of |ln d - ln d_ref| and |u - u_ref| / max |u_ref| (the
/// largest over every output).
fn largest_state_error(run: &[Snapshot], reference: &[Snapshot]) -> f64 {
    let u_scale = reference
        .iter()
        .flat_map(|r| &r.velocities)
        .fold(0.0f64, |m, u| m.max(u.abs()));
    let mut worst = 0.0f64;
    for (x, r) in run.iter().zip(reference) {
        for (d, d_ref) in x.gaps.iter().zip(&r.gaps) {
            worst = worst.max((d.ln() - d_ref.ln()).abs());
        }
        for (u, u_ref) in x.velocities.iter().zip(&r.velocities) {
            worst = worst.max((u - u_ref).abs() / u_scale);
        }
    }
    worst
}

/// 10^(-k/2): whole decades exactly as written (1e-8 is auto's switch of matrix, compared with
/// `<=`), the half decades between them from powf.
fn half_decade(k: u32) -> f64 {
    if k.is_multiple_of(2) {
        10f64.powi(-((k / 2) as i32))
    } else {
        10f64.powf(-0.5 * k as f64)
    }
}

/// How far above the requested tolerance the global error may be (measured: see the tests).
const TOLERANCE_FACTOR: f64 = 3.0;

/// Item 2's hold on one rung of a tolerance ladder (tightening): the error `e` within
/// TOLERANCE_FACTOR of `tolerance` and not above the looser rung's (10 % allowed: see
/// `auto_error_falls_with_the_tolerance_on_a_random_chain_of_200`); `previous` becomes `e`.
fn assert_follows_tolerance(what: &str, tolerance: f64, e: f64, previous: &mut f64) {
    assert!(
        e <= TOLERANCE_FACTOR * tolerance,
        "{what}tolerance {tolerance:e}: error {e:e}"
    );
    assert!(
        e <= 1.1 * *previous,
        "{what}tolerance {tolerance:e}: error {e:e} above the looser {previous:e}"
    );
    *previous = e;
}

/// A test's reference, `resolution` off its check run, held within `bound`.
fn assert_reference_resolved(what: &str, resolution: f64, bound: f64) {
    eprintln!("{what}: {resolution:.1e}");
    assert!(resolution <= bound, "reference unresolved: {resolution:e}");
}

/// Issue 22, item 2: auto's error falls at every half decade of tolerance from 1e-4 to 1e-10
/// and stays within TOLERANCE_FACTOR of it, on the random chain of 200 with 11 output times
/// (so that steps land on them: landing with a sliver step once made auto drop its order after
/// every output and doubled the steps at 1e-10). The error is the largest over the output times
/// of |ln d - ln d_ref| and |u - u_ref| / max |u_ref| (the largest over every output), against
/// auto at 1e-13, itself held to agree with 1e-12 within 1e-10 / 4. "Falls" allows 10 %: where
/// the output spacing, not the tolerance, sets the last steps, the error can stay put from one
/// half decade to the next (2.514e-8 at both 3.16e-8 and 1e-8 while both took the exact matrix:
/// two halves of 0.015 at order 8). Measured 0.10 to 2.51 times the tolerance. The same holds with
/// `[solver] sequence = "from_2"`, auto's default in f64 since 2026-11-30 (measured 0.02 to 1.49
/// times, 2026-11-29); while auto took the
/// exact matrix from 1e-7 (now from 1e-8) it did not fall there: 5.6e-8 at 3.16e-7 (33 steps),
/// 1.1e-7 at 1e-7 (25 steps).
#[test]
fn auto_error_falls_with_the_tolerance_on_a_random_chain_of_200() {
    let chain = random_chain_of_200();
    let params = MemberParams {
        mu: 0.01,
        gamma: 2.0,
    };
    let outputs: Vec<f64> = (0..=10).map(|i| 0.03 * i as f64).collect();
    let run = |tolerance: f64, sequence: Sequence| {
        let (snaps, report) = auto_member(&chain, params, &outputs, tolerance, 3e-5, |plan| {
            plan.sequence = sequence
        });
        (snaps, report.steps_accepted + report.steps_rejected)
    };
    let (reference, _) = run(1e-13, Sequence::FromOne);
    let resolution = largest_state_error(&run(1e-12, Sequence::FromOne).0, &reference);
    assert_reference_resolved("reference 1e-13 against 1e-12", resolution, 1e-10 / 4.0);
    for sequence in [Sequence::FromOne, Sequence::FromTwo] {
        let mut previous = f64::INFINITY;
        for k in 8..=20 {
            let tolerance = half_decade(k);
            let (snaps, steps) = run(tolerance, sequence);
            let e = largest_state_error(&snaps, &reference);
            eprintln!(
                "{sequence:?} tolerance {tolerance:.2e}: error {e:.3e} ({:.2}x), {steps} steps",
                e / tolerance
            );
            assert_follows_tolerance(&format!("{sequence:?} "), tolerance, e, &mut previous);
        }
    }
}

/// Adaptive runs meet their tolerance: against the independent RK4 reference, the error at the
/// end stays within a small factor of the requested tolerance from 1e-3 to 1e-10, for a fixed
/// low and high order and for auto (the tolerance bounds each step's local error; the
/// global error adds those up, damped or amplified by the dynamics).
#[test]
fn adaptive_runs_meet_their_tolerance_from_1e3_to_1e10() {
    let mut rng = Rng(7);
    let chain = random_chain(&mut rng, 6, 0.05, Some(0.03));
    let (mu, gamma, t_end) = (0.01, 2.0, 0.2);
    let (ref_gaps, ref_vel) = rk4_reference(&chain, mu, gamma, t_end, 20_000);
    let params = vec![MemberParams { mu, gamma }];
    for order in [Order::Fixed(2), Order::Fixed(5), Order::Auto] {
        for k in 3..=10 {
            let tolerance = 10f64.powi(-k);
            let plan = plan_for(
                &chain,
                params.clone(),
                order,
                Stepping::Adaptive {
                    tolerance,
                    dt_initial: 1e-4,
                    dt_min: 1e-14,
                },
                vec![0.0, t_end],
                Some(("0.3*sin(2*pi*x)*cos(3*t)", 8)),
            );
            let (snaps, solver) = run_all(plan, vec![chain.clone()]);
            let reports = solver.reports();
            let last = &snaps[1][0];
            let error = max_error(&last.gaps, &ref_gaps) + max_error(&last.velocities, &ref_vel);
            eprintln!(
                "order {} tolerance {tolerance:e}: error {error:.2e} ({:.2}× tolerance), {} steps, estimate {:?}",
                order.label(),
                error / tolerance,
                reports[0].steps_accepted,
                reports[0].error_estimate
            );
            assert!(
                error <= TOLERANCE_FACTOR * tolerance,
                "order {} tolerance {tolerance:e}: error {error:e}",
                order.label()
            );
        }
    }
}

/// The fields on the grid against a direct evaluation at each point: rho and rho* are the values
/// of the cell [q_{i-1}, q_i) that holds x (the last cell for x >= q_N), u is linear between
/// the cell's end velocities (the walls at rest). Chains from 1 to 300 particles on grids
/// coarser and finer than their cells, so that cells holding no point, one point and many are
/// all walked, with gaps far below the grid spacing, one stored as ln d.
#[test]
fn fields_on_the_grid_are_the_cell_values_at_each_point() {
    let mut rng = Rng(11);
    for (n, grid) in [
        (1usize, 11usize),
        (7, 200),
        (60, 200),
        (300, 101),
        (40, 1000),
    ] {
        let eps = 0.2 / n as f64;
        let chain = random_chain(&mut rng, n, eps, Some(eps));
        let mut stored = chain.gaps.clone();
        if n > 3 {
            // Squeezed gaps (the others keep their widths, so points past q_N < 1 belong to the
            // last cell).
            stored[1] = 1e-9;
            stored[2] = (1e-200f64).ln();
        }
        let plan = plan_for(
            &chain,
            vec![MemberParams {
                mu: 0.1,
                gamma: 2.0,
            }],
            1,
            Stepping::Fixed {
                dt: 1e-3,
                dt_min: 1e-12,
            },
            vec![0.0],
            None,
        );
        let x = grid_points(grid);
        let dstar = chain.dstar.as_deref().unwrap();
        let s = observe(
            &plan,
            &plan.members[0],
            &stored,
            &chain.velocities,
            Some(dstar),
            None,
            &x,
        );
        assert_eq!(
            (s.rho.len(), s.u.len(), s.rho_star.len()),
            (grid, grid, grid)
        );
        let d: Vec<f64> = stored.iter().map(|&v| stored_gap::decode(v)).collect();
        let mut q = vec![0.0];
        for &di in &d {
            q.push(q.last().unwrap() + (di + 2.0 * eps));
        }
        let velocity = |i: usize| {
            if i == 0 || i == n {
                0.0
            } else {
                chain.velocities[i - 1]
            }
        };
        for (j, &xj) in x.iter().enumerate() {
            let i = (1..=n).find(|&i| xj < q[i]).unwrap_or(n);
            let what = format!("N = {n}, grid {grid}, x_{j} = {xj} in cell {i}");
            assert_eq!(s.rho[j], 2.0 * eps / (d[i - 1] + 2.0 * eps), "rho, {what}");
            assert_eq!(
                s.rho_star[j],
                2.0 * eps / (dstar[i - 1] + 2.0 * eps),
                "rho*, {what}"
            );
            let frac = ((xj - q[i - 1]) / (q[i] - q[i - 1])).clamp(0.0, 1.0);
            let u = velocity(i - 1) + (velocity(i) - velocity(i - 1)) * frac;
            assert!(
                (s.u[j] - u).abs() <= 1e-15,
                "u = {} against {u}, {what}",
                s.u[j]
            );
        }
    }
}

/// `observe`'s energy and dissipation are the sums of `energy` and `dissipation` (one term a
/// gap, in the chain's order), bit for bit: chains across the packed terms' chunk of 64 gaps,
/// gamma 1, integer gammas up to 1000 and a real one, with every gap stored as d (the packed
/// path) and with one stored as ln d (the gap-by-gap path). Without the sums
/// (`Plan::energy_sums`) the minima are the same.
#[test]
fn observed_energy_and_dissipation_are_the_plain_sums_bit_for_bit() {
    let mut rng = Rng(29);
    for n in [1usize, 2, 3, 63, 64, 65, 129, 200] {
        for gamma in [1.0, 2.0, 3.0, 7.0, 1000.0, 2.5] {
            for squeezed in [false, true] {
                let eps = 0.2 / n as f64;
                let chain = random_chain(&mut rng, n, eps, Some(eps));
                let mut stored = chain.gaps.clone();
                if squeezed {
                    stored[n / 2] = (1e-200f64).ln();
                }
                let d: Vec<f64> = stored.iter().map(|&v| stored_gap::decode(v)).collect();
                let mu = 0.1;
                let plan = plan_for(
                    &chain,
                    vec![MemberParams { mu, gamma }],
                    1,
                    Stepping::Fixed {
                        dt: 1e-3,
                        dt_min: 1e-12,
                    },
                    vec![0.0],
                    None,
                );
                let dstar = chain.dstar.as_deref();
                let grid = grid_points(11);
                let observed = |energy_sums: bool| {
                    let mut plan = plan.clone();
                    plan.energy_sums = energy_sums;
                    observe(
                        &plan,
                        &plan.members[0],
                        &stored,
                        &chain.velocities,
                        dstar,
                        None,
                        &grid,
                    )
                };
                let s = observed(true);
                let what = format!("N = {n}, gamma {gamma}, squeezed {squeezed}");
                let e = energy(eps, gamma, &d, &chain.velocities, dstar, None);
                assert_eq!(s.energy.to_bits(), e.to_bits(), "energy, {what}");
                let q = dissipation(mu, &d, &chain.velocities, None);
                assert_eq!(s.dissipation.to_bits(), q.to_bits(), "dissipation, {what}");
                assert!(e.is_finite() && q.is_finite(), "{what}");
                // Without the sums (the order-1 companion's snapshots, only compared) the
                // minima and the density they give are the same bits; no energy is made up.
                let t = observed(false);
                for (a, b, name) in [
                    (t.min_gap, s.min_gap, "min_gap"),
                    (t.log_min_gap, s.log_min_gap, "log_min_gap"),
                    (t.max_density, s.max_density, "max_density"),
                ] {
                    assert_eq!(a.to_bits(), b.to_bits(), "{name}, {what}");
                }
                assert!(t.energy.is_nan() && t.dissipation.is_nan(), "{what}");
            }
        }
    }
}

/// A random chain of 300 driven towards contact (u0 = 2 sin 2πx, gamma 5, mu 0.01, to t = 0.2,
/// its smallest gaps at ln d ~ -24): auto at half decades of tolerance from 1e-6 to 1e-9
/// against the frozen matrix at 1e-11 (at 1e-8 and below auto takes the exact Jacobian, so
/// there the reference is the other matrix, not the scheme checked), itself held within 1e-9/4
/// of the exact matrix at 1e-11 (1.6e-10).
/// While the factor k switched to 1 where h (|u_l| + |u_r|) > 1e4 d, a kink in the substep h
/// that the rows of one step straddled here, the error at 1e-8 was 5.5 times the tolerance in
/// 480 + 73 steps; with the switch by the state (log-stored gaps only), 1.67 and 0.73 times the
/// tolerance in 274 + 0 and 458 + 0 steps (2026-11-29). While auto took the exact matrix from
/// 1e-7, whose errors add up over the steps near contact, the error at 1e-7 was above the
/// error at 3.16e-7. Held for both tableau sequences: within 3 times the tolerance, falling at
/// every half decade (10 % allowed), and with the exact matrix at most one step in 20 rejected.
/// Measured 2026-11-30: from_1 0.57 to 1.67 times, from_2 (auto's default in f64) 0.43 to 1.83
/// times, with a 3 % rise where auto changes matrix (1.36e-8 at 3.16e-8, 1.40e-8 at 1e-8).
#[test]
fn auto_near_contact_follows_the_tolerance_across_its_change_of_matrix() {
    let chain = chain_with_random_radii(300, "2*sin(2*pi*x)", 16);
    let params = MemberParams {
        mu: 0.01,
        gamma: 5.0,
    };
    let outputs: Vec<f64> = (0..=8).map(|i| 0.025 * i as f64).collect();
    let run = |tolerance: f64, jacobian: Jacobian, sequence: Sequence| {
        auto_member(&chain, params, &outputs, tolerance, 1e-5, |plan| {
            plan.jacobian = jacobian;
            plan.sequence = sequence;
        })
    };
    let (reference, _) = run(1e-11, Jacobian::Frozen, Sequence::FromOne);
    // The reference against the other matrix at the same tolerance: well below the tightest
    // tolerance checked (measured 2026-11-29: see the eprintln).
    let resolution = largest_state_error(
        &run(1e-11, Jacobian::Exact, Sequence::FromOne).0,
        &reference,
    );
    assert_reference_resolved(
        "reference (frozen, 1e-11) against exact at 1e-11",
        resolution,
        1e-9 / 4.0,
    );
    let smallest = reference
        .iter()
        .flat_map(|s| &s.gaps)
        .fold(f64::INFINITY, |m, &d| m.min(d));
    eprintln!("smallest gap of the reference: ln d = {:.1}", smallest.ln());
    // Both tableau sequences: from_2 is auto's default in f64.
    for sequence in [Sequence::FromOne, Sequence::FromTwo] {
        let mut previous = f64::INFINITY;
        for k in 12..=18 {
            let tolerance = half_decade(k);
            let (snaps, report) = run(tolerance, Jacobian::Auto, sequence);
            let (accepted, rejected) = (report.steps_accepted, report.steps_rejected);
            let e = largest_state_error(&snaps, &reference);
            eprintln!(
                "{sequence:?}, tolerance {tolerance:.2e}: error {e:.2e} ({:.2}x), {accepted} + \
                 {rejected} steps",
                e / tolerance
            );
            assert_follows_tolerance(&format!("{sequence:?} "), tolerance, e, &mut previous);
            // Auto's exact matrix (tolerances up to 1e-8).
            if tolerance <= 1e-8 {
                assert!(
                    rejected * 20 <= accepted,
                    "{sequence:?}, tolerance {tolerance:e}: {rejected} rejected of {accepted}"
                );
            }
        }
    }
}
