//! Work–precision of the default scheme on the realistic chain of issue 22
//! (docs/work_precision_random_n200.toml: N = 200, radii uniform within ±30 % of the mean
//! profile, gamma 2, mu 0.01, u0 = 0.5 sin 2πx, t = 0.3, 11 outputs; its first member): wall
//! time per member, in a batch of 64 copies of it on the CPU, of `order = "auto"` with the
//! default sequence at tolerances 1e-4 … 1e-10, as docs/scipy_comparison/compare.py times
//! roughlub against scipy's Radau. Before the measurements it prints the error each tolerance
//! reaches against a reference (auto from 1 at 1e-12, itself checked against 1e-11) and its
//! steps.

use std::path::Path;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use roughlub::backend::cpu::CpuSolver;
use roughlub::backend::{BatchSolver, MemberStatus};
use roughlub::model::chain::Chain;
use roughlub::model::observables::Snapshot;
use roughlub::model::params::{Order, OutputFields, Sequence, Stepping};
use roughlub::model::plan::Plan;
use roughlub::scene::members::EnsembleMembers;
use roughlub::scene::Scene;

const MEMBERS: usize = 64;
const TOLERANCES: [f64; 5] = [1e-4, 1e-6, 3.16e-7, 1e-8, 1e-10];

/// The scene's plan at tolerance 1e-8 (the default sequence resolved for it) and its first
/// member's chain.
fn random_chain() -> (Plan, Chain) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/work_precision_random_n200.toml");
    let text = std::fs::read_to_string(&path)
        .unwrap()
        .replace("dt = 1e-3", "tolerance = 1e-8");
    let scene = Scene::from_toml(&text, &path).unwrap();
    let spec = scene.ensemble.clone().unwrap();
    let member = EnsembleMembers::new(&scene, &spec)
        .unwrap()
        .member(0)
        .unwrap();
    let mut plan = scene.plan(&member.chain, scene.precision);
    plan.members = vec![member.params];
    plan.fields = OutputFields::none();
    plan.fields.gaps = true;
    plan.fields.velocities = true;
    (plan, member.chain)
}

fn at_tolerance(base: &Plan, tolerance: f64) -> Plan {
    let mut plan = base.clone();
    plan.stepping = Stepping::Adaptive {
        tolerance,
        dt_initial: 1e-5,
        dt_min: 1e-14,
    };
    plan
}

/// The snapshots of `members` copies of `chain` and the first member's accepted steps.
fn run(plan: &Plan, chain: &Chain, members: usize) -> (Vec<Vec<Snapshot>>, u64) {
    let mut plan = plan.clone();
    plan.members = vec![plan.members[0]; members];
    let mut solver = CpuSolver::new(plan, vec![chain.clone(); members]);
    let mut out = Vec::new();
    while let Some(s) = solver.next_output(&|_| {}).unwrap() {
        out.push(s);
    }
    let report = &solver.reports()[0];
    assert_eq!(report.status, MemberStatus::Ok);
    (out, report.steps_accepted)
}

/// max over output times of max_i |ln d - ln d_ref| and max |u - u_ref| / max |u_ref|.
fn error(a: &[Vec<Snapshot>], reference: &[Vec<Snapshot>]) -> f64 {
    let mut worst = 0.0f64;
    for (s, r) in a.iter().zip(reference) {
        let (s, r) = (&s[0], &r[0]);
        for (x, y) in s.gaps.iter().zip(&r.gaps) {
            worst = worst.max((x.ln() - y.ln()).abs());
        }
        let scale = r.velocities.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (x, y) in s.velocities.iter().zip(&r.velocities) {
            worst = worst.max((x - y).abs() / scale);
        }
    }
    worst
}

fn work_precision(c: &mut Criterion) {
    let (base, chain) = random_chain();
    let reference_at = |tolerance: f64| {
        let mut plan = at_tolerance(&base, tolerance);
        plan.order = Order::Auto;
        plan.sequence = Sequence::FromOne;
        run(&plan, &chain, 1).0
    };
    let reference = reference_at(1e-12);
    eprintln!(
        "reference (auto from_1, 1e-12) against 1e-11: {:.1e}",
        error(&reference_at(1e-11), &reference)
    );
    for tolerance in TOLERANCES {
        let (snaps, steps) = run(&at_tolerance(&base, tolerance), &chain, 1);
        eprintln!(
            "tolerance {tolerance:e}: error {:.2e}, {steps} steps",
            error(&snaps, &reference)
        );
    }
    let mut group = c.benchmark_group("random_N200_64_members_cpu");
    group
        .sample_size(10)
        .measurement_time(Duration::from_secs(5))
        .warm_up_time(Duration::from_secs(1));
    // Elements are members: criterion's "elem/s" is members per second.
    group.throughput(Throughput::Elements(MEMBERS as u64));
    for tolerance in TOLERANCES {
        let plan = at_tolerance(&base, tolerance);
        group.bench_with_input(
            BenchmarkId::from_parameter(format!("auto_tolerance_{tolerance:e}")),
            &plan,
            |b, plan| b.iter(|| run(plan, &chain, MEMBERS)),
        );
    }
    group.finish();
}

criterion_group!(benches, work_precision);
criterion_main!(benches);
