//! Particle-steps per second (members × particles × steps / wall time) of the batched CPU
//! solver: order 1, fixed steps, integer gamma (repulsion on, gamma = 2), no forcing.
//! B1_N1000000 and B4_N1000000 are the few-members-huge-N cases, which take the partitioned
//! solve in f64 and in f32 (`ROUGHLUB_CPU_PARTITION=off` measures the sequential sweep instead).
//! The f64 rows are the group `cpu_order1_fixed_integer_gamma`, the f32 rows
//! `cpu_f32_order1_fixed_integer_gamma` (`cargo bench --bench cpu_solver -- f32`). The group
//! `cpu_order1_fixed_with_estimate` runs three of the f64 rows as a scene does by default, with
//! the companion at 4 dt that estimates order 1's error (`[solver] error_estimate`): its
//! particle-steps are the run's, so the ratio of the two groups' rates is the estimate's cost.

use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use roughlub::backend::companion::{companion_plan, CompanionEstimate};
use roughlub::backend::cpu::CpuSolver;
use roughlub::backend::{BatchSolver, Precision};
use roughlub::expr::Expr;
use roughlub::model::params::{MemberParams, OutputFields, Stepping};
use roughlub::model::plan::Plan;
use roughlub::scene::initial::chain_from_profiles;

fn solver(
    members: usize,
    particles: usize,
    steps: usize,
    dt: f64,
    precision: Precision,
) -> CpuSolver {
    let (plan, chains) = plan_and_chains(members, particles, steps, dt);
    let mut s = CpuSolver::with_precision(plan, chains, precision);
    s.next_output(&|_| {}).unwrap();
    s
}

/// The f64 solver of [`solver`] with its companion, as `roughlub run` builds them for order 1
/// with fixed steps, past its first output.
fn solver_with_estimate(
    members: usize,
    particles: usize,
    steps: usize,
    dt: f64,
) -> CompanionEstimate<'static> {
    let (mut plan, chains) = plan_and_chains(members, particles, steps, dt);
    plan.companion_estimate = true;
    // The comparison reads the gaps and velocities of both.
    plan.fields.gaps = true;
    plan.fields.velocities = true;
    let run = CpuSolver::with_precision(plan.clone(), chains.clone(), Precision::F64);
    let companion = CpuSolver::with_precision(companion_plan(&plan), chains, Precision::F64);
    let mut s = CompanionEstimate::new(plan, Box::new(run), Box::new(companion));
    s.next_output(&|_| {}).unwrap();
    s
}

fn plan_and_chains(
    members: usize,
    particles: usize,
    steps: usize,
    dt: f64,
) -> (Plan, Vec<roughlub::model::chain::Chain>) {
    let chain = chain_from_profiles(
        particles,
        &Expr::parse("0.7").unwrap(),
        &Expr::parse("0.5*sin(2*pi*x)").unwrap(),
        Some(&Expr::parse("0.7").unwrap()),
    )
    .unwrap();
    let plan = Plan {
        particles,
        eps: chain.eps,
        repulsion: true,
        clusters: false,
        forcing: None,
        order: 1.into(),
        stepping: Stepping::Fixed { dt, dt_min: 1e-14 },
        members: vec![
            MemberParams {
                mu: 0.01,
                gamma: 2.0
            };
            members
        ],
        // The first output is t = 0 (no steps); the second needs `steps` steps.
        output_times: vec![0.0, steps as f64 * dt],
        fields: OutputFields::none(),
        grid: 2,
        companion_estimate: false,
        jacobian: Default::default(),
        sequence: Default::default(),
        peak_centre: false,
        energy_sums: true,
        // The bench is the top: `ROUGHLUB_CPU_PARTITION=off` and `ROUGHLUB_CPU_SIMD` apply.
        overrides: roughlub::backend::overrides::Overrides::from_env(),
    };
    (plan, vec![chain; members])
}

/// (members, particles, steps) of each row.
const ROWS: [(usize, usize, usize); 5] = [
    (1, 100_000, 20),
    (1, 1_000_000, 10),
    (4, 1_000_000, 4),
    (256, 1000, 40),
    (4096, 100, 40),
];

fn particle_steps(c: &mut Criterion) {
    rows(c, "cpu_order1_fixed_integer_gamma", &ROWS, |m, n, k, dt| {
        solver(m, n, k, dt, Precision::F64)
    });
    rows(
        c,
        "cpu_f32_order1_fixed_integer_gamma",
        &ROWS,
        |m, n, k, dt| solver(m, n, k, dt, Precision::F32),
    );
    rows(
        c,
        "cpu_order1_fixed_with_estimate",
        &[ROWS[0], ROWS[3], ROWS[4]],
        solver_with_estimate,
    );
}

/// A group timing one output of `steps` steps from the solver `make` builds for each row.
fn rows<S: BatchSolver>(
    c: &mut Criterion,
    name: &str,
    sizes: &[(usize, usize, usize)],
    make: impl Fn(usize, usize, usize, f64) -> S,
) {
    let mut group = c.benchmark_group(name);
    group
        .sample_size(10)
        .measurement_time(Duration::from_secs(8))
        .warm_up_time(Duration::from_secs(1));
    for &(members, particles, steps) in sizes {
        let dt = 1e-4;
        group.throughput(Throughput::Elements((members * particles * steps) as u64));
        group.bench_with_input(
            BenchmarkId::from_parameter(format!("B{members}_N{particles}")),
            &(members, particles, steps),
            |b, &(m, n, k)| {
                b.iter_batched(
                    || make(m, n, k, dt),
                    |mut s| s.next_output(&|_| {}).unwrap(),
                    criterion::BatchSize::LargeInput,
                )
            },
        );
    }
    group.finish();
}

criterion_group!(benches, particle_steps);
criterion_main!(benches);
