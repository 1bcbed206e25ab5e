//! Work–precision of the extrapolated schemes on the paper's case 1 (scenes/case1.toml, N = 400,
//! t = 0.4): wall time per member, in a batch of 256 members on the CPU, of the cheapest setting
//! `roughlub accuracy scenes/case1.toml --target 1e-10` found for each error 1e-4, 1e-6, 1e-8
//! and 1e-10. Before the measurements it prints the error each setting reaches against a
//! reference (order auto, tolerance 1e-11; the measured floor of that reference is ~5e-11).

use std::path::Path;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use roughlub::backend::cpu::CpuSolver;
use roughlub::backend::BatchSolver;
use roughlub::model::chain::Chain;
use roughlub::model::observables::Snapshot;
use roughlub::model::params::{Order, OutputFields, Stepping};
use roughlub::model::plan::Plan;
use roughlub::scene::Scene;

const MEMBERS: usize = 256;

fn case1() -> (Plan, Chain) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/case1.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let scene = Scene::from_toml(&text, &path).unwrap();
    let chain = scene.initial_chain().unwrap();
    let mut plan = scene.plan(&chain, scene.precision);
    plan.fields = OutputFields::none();
    plan.fields.gaps = true;
    plan.fields.velocities = true;
    (plan, chain)
}

fn adaptive(tolerance: f64) -> Stepping {
    Stepping::Adaptive {
        tolerance,
        dt_initial: 1e-5,
        dt_min: 1e-14,
    }
}

fn run(plan: &Plan, chain: &Chain, members: usize) -> Vec<Vec<Snapshot>> {
    let mut plan = plan.clone();
    plan.members = vec![plan.members[0]; members];
    let mut solver = CpuSolver::new(plan, vec![chain.clone(); members]);
    let mut out = Vec::new();
    while let Some(s) = solver.next_output(&|_| {}).unwrap() {
        out.push(s);
    }
    out
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

fn settings() -> [(f64, Order, Stepping); 4] {
    [
        (1e-4, Order::Auto, adaptive(1e-4)),
        (1e-6, Order::Auto, adaptive(1e-6)),
        (1e-8, Order::Auto, adaptive(1e-9)),
        (
            1e-10,
            Order::Fixed(6),
            Stepping::Fixed {
                dt: 1e-3,
                dt_min: 1e-14,
            },
        ),
    ]
}

fn work_precision(c: &mut Criterion) {
    let (base, chain) = case1();
    let mut reference_plan = base.clone();
    reference_plan.order = Order::Auto;
    reference_plan.stepping = adaptive(1e-11);
    let reference = run(&reference_plan, &chain, 1);
    for (target, order, stepping) in settings() {
        let mut plan = base.clone();
        plan.order = order;
        plan.stepping = stepping;
        let e = error(&run(&plan, &chain, 1), &reference);
        eprintln!(
            "target {target:e}: order {}, {stepping:?}: error {e:.2e}",
            order.label()
        );
    }
    let mut group = c.benchmark_group("case1_N400_256_members_cpu");
    group
        .sample_size(10)
        .measurement_time(Duration::from_secs(10))
        .warm_up_time(Duration::from_secs(1));
    // Elements are members: criterion's "elem/s" is members per second.
    group.throughput(Throughput::Elements(MEMBERS as u64));
    for (target, order, stepping) in settings() {
        let mut plan = base.clone();
        plan.order = order;
        plan.stepping = stepping;
        group.bench_with_input(
            BenchmarkId::from_parameter(format!("error_{target:e}")),
            &plan,
            |b, plan| b.iter(|| run(plan, &chain, MEMBERS)),
        );
    }
    group.finish();
}

criterion_group!(benches, work_precision);
criterion_main!(benches);
