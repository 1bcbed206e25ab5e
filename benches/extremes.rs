//! The extremes matrix of issue 8 (scenes/extremes/, N = 200, 16 (mu, gamma) members per file):
//! wall time per file on the CPU (f64) and, where an adapter exists, on the GPU (f64 and f32),
//! and the steps each member takes (printed once per file: accepted/rejected, largest of the 16).

use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use roughlub::backend::cpu::CpuSolver;
use roughlub::backend::gpu::solver::GpuSolver;
use roughlub::backend::gpu::GpuContext;
use roughlub::backend::{BatchSolver, Precision};
use roughlub::model::chain::Chain;
use roughlub::model::plan::Plan;
use roughlub::scene::Scene;

fn load() -> Vec<(String, Plan, Vec<Chain>)> {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/extremes");
    let mut files: Vec<_> = std::fs::read_dir(dir)
        .expect("scenes/extremes")
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    files
        .into_iter()
        .map(|path| {
            let text = std::fs::read_to_string(&path).unwrap();
            let scene = Scene::from_toml(&text, &path).unwrap();
            let chain = scene.initial_chain().unwrap();
            let plan = scene.plan(&chain, scene.precision);
            let members = plan.members.len();
            let name = path.file_stem().unwrap().to_string_lossy().into_owned();
            (name, plan, vec![chain; members])
        })
        .collect()
}

fn run(solver: &mut dyn BatchSolver) -> (u64, u64) {
    while solver.next_output(&|_| {}).unwrap().is_some() {}
    let r = solver.reports();
    (
        r.iter().map(|m| m.steps_accepted).max().unwrap_or(0),
        r.iter().map(|m| m.steps_rejected).max().unwrap_or(0),
    )
}

fn extremes(c: &mut Criterion) {
    let cases = load();
    let ctx = GpuContext::acquire(true).ok();
    let mut group = c.benchmark_group("extremes");
    group
        .sample_size(10)
        .measurement_time(Duration::from_secs(3))
        .warm_up_time(Duration::from_millis(300));
    for (name, plan, chains) in &cases {
        let (acc, rej) = run(&mut CpuSolver::new(plan.clone(), chains.clone()));
        eprintln!("{name}: cpu f64, most steps of a member: {acc} accepted, {rej} rejected");
        group.bench_function(format!("cpu_f64/{name}"), |b| {
            b.iter(|| run(&mut CpuSolver::new(plan.clone(), chains.clone())))
        });
        if let Some(ctx) = &ctx {
            for precision in [Precision::F64, Precision::F32] {
                let label = format!("gpu_{precision:?}/{name}").to_lowercase();
                let mut probe =
                    GpuSolver::new(ctx, plan.clone(), chains.clone(), precision).unwrap();
                let (acc, rej) = run(&mut probe);
                eprintln!("{label}: most steps of a member: {acc} accepted, {rej} rejected");
                group.bench_function(label, |b| {
                    b.iter(|| {
                        let mut s =
                            GpuSolver::new(ctx, plan.clone(), chains.clone(), precision).unwrap();
                        run(&mut s)
                    })
                });
            }
        }
    }
    group.finish();
}

criterion_group!(benches, extremes);
criterion_main!(benches);
