//! Members per second of an ensemble study: 10^4 members at N = 200 to t = 0.2 (lognormal
//! roughness, spread 0.3, case-1 data, order 1, dt = 1e-3, 3 output times, grid 100), and of a
//! parameter study of 10^4 members over 16 sweep points (a 4 x 4 grid of mu and the velocity
//! amplitude parameter A, 625 members each, otherwise the same scene), on the CPU and on the GPU
//! path where an adapter exists, with the statistics' share of the wall time (printed; it must
//! stay under 10 %).

use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use roughlub::study::{run_study, StudyOptions};
use {roughlub::backend::Backend, roughlub::scene::Scene};

const MEMBERS: u64 = 10_000;

const SWEEP: &str = r#"
[sweep]
mu = [0.005, 0.01, 0.02, 0.04]
A = [0.3, 0.4, 0.5, 0.6]
"#;

fn scene(members: u64, sweep: &str) -> Scene {
    let text = format!(
        r#"
name = "bench_ensemble"
[parameters]
A = 0.5
[model]
particles = 200
mu = 0.01
gamma = 1.0
[initial]
rho = "0.7"
velocity = "A*sin(2*pi*x)"
rho_star = "0.7"
[time]
end = 0.2
outputs = 3
dt = 1e-3
[output]
grid = 100
plots = false
[ensemble]
members = {members}
seed = 1
chunk = 1000
roughness = {{ kind = "lognormal", spread = 0.3 }}
{sweep}"#
    );
    Scene::from_toml(&text, std::path::Path::new("bench_ensemble.toml"))
        .expect("bench scene is valid")
}

fn ensemble(c: &mut Criterion) {
    study(c, "ensemble_1e4_members_N200_t0.2", &scene(MEMBERS, ""));
    study(
        c,
        "sweep_1e4_members_16_points_N200_t0.2",
        &scene(MEMBERS / 16, SWEEP),
    );
}

fn study(c: &mut Criterion, name: &str, scene: &Scene) {
    let mut group = c.benchmark_group(name);
    group
        .sample_size(10)
        .measurement_time(Duration::from_secs(30))
        .warm_up_time(Duration::from_secs(1));
    group.throughput(Throughput::Elements(MEMBERS));
    let gpu_present = roughlub::backend::gpu::GpuContext::acquire(true).is_ok();
    let backends: Vec<(&str, Backend)> = if gpu_present {
        vec![("cpu", Backend::Cpu), ("gpu", Backend::Gpu)]
    } else {
        vec![("cpu", Backend::Cpu)]
    };
    for (label, backend) in backends {
        let dir = tempfile::tempdir().expect("temp dir");
        let options = StudyOptions {
            out_dir: dir.path().to_path_buf(),
            backend: Some(backend),
            precision: None,
            quiet: true,
            shard: (0, 1),
            resume: false,
            force: false,
            allow_large: false,
            checkpoint_seconds: roughlub::study::DEFAULT_CHECKPOINT_SECONDS,
        };
        let mut shares = Vec::new();
        group.bench_function(label, |b| {
            b.iter(|| {
                let s = run_study(scene, &options).expect("study runs");
                shares.push(s.statistics_seconds / s.wall_seconds);
            })
        });
        if !shares.is_empty() {
            let worst = shares.iter().cloned().fold(0.0f64, f64::max);
            let mean = shares.iter().sum::<f64>() / shares.len() as f64;
            println!(
                "{label}: statistics share of wall time: mean {:.1} %, worst {:.1} %",
                100.0 * mean,
                100.0 * worst
            );
        }
    }
    group.finish();
}

criterion_group!(benches, ensemble);
criterion_main!(benches);
