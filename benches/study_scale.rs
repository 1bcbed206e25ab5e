//! What a study costs beside its members (issue 23): the rows of the issue's table, each run
//! through the `roughlub` command on the CPU. N = 60, gamma 2, 21 outputs, dt = 1e-3, t = 0.2,
//! lognormal roughness (spread 0.3), grid 200 unless a row says otherwise:
//!
//! - `batch_4096`: a `[batch]` of 4096 members (a list of mu, fields = energy), no statistics;
//! - `ensemble_4096`: an `[ensemble]` of 4096 members with the default outputs;
//! - `ensemble_4096_grid20`, `ensemble_4096_energy`: the same with grid = 20, fields = energy;
//! - `ensemble_1024_N200`, `ensemble_256_N1000`: ensembles of longer chains, default outputs;
//! - `random_P_x1`: a random design of P points x 1 member (P = 64, 256, 4096, 10000).
//!
//! Criterion times each row (the whole command); further runs of each print the table (five, or
//! for short rows as many as fill 2 s, at most 41): median wall time, median statistics' share
//! of it (from the manifest) with its range over the runs, largest peak memory (the child's
//! ru_maxrss) and the size of the output directory. `STUDY_SCALE_ROWS=ensemble_4096,batch_4096`
//! restricts the rows.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, Criterion};

const BIN: &str = env!("CARGO_BIN_EXE_roughlub");

fn base(extra_output: &str, tail: &str) -> String {
    base_n(60, extra_output, tail)
}

fn base_n(particles: usize, extra_output: &str, tail: &str) -> String {
    format!(
        r#"
name = "study_scale"
[parameters]
A = 0.5
[model]
particles = {particles}
mu = 0.01
gamma = 2.0
[initial]
rho = "0.7"
velocity = "A*sin(2*pi*x)"
rho_star = "0.7"
[time]
end = 0.2
outputs = 21
dt = 1e-3
[solver]
order = 1
backend = "cpu"
[output]
plots = false
{extra_output}
{tail}
"#
    )
}

fn ensemble(members: u64, extra_output: &str, sweep: &str) -> String {
    base(
        extra_output,
        &format!(
            "{sweep}\n[ensemble]\nmembers = {members}\nseed = 1\nroughness = {{ kind = \"lognormal\", spread = 0.3 }}\n"
        ),
    )
}

/// An ensemble of chains of N particles with the default outputs (the statistics' share from
/// N = 60 to N = 1000).
fn ensemble_n(members: u64, particles: usize) -> String {
    base_n(
        particles,
        "",
        &format!("[ensemble]\nmembers = {members}\nseed = 1\nroughness = {{ kind = \"lognormal\", spread = 0.3 }}\n"),
    )
}

fn rows() -> Vec<(String, String)> {
    let mus: Vec<String> = (0..4096)
        .map(|j| format!("{:.6}", 0.005 + 0.01 * j as f64 / 4096.0))
        .collect();
    let batch = base(
        "fields = [\"energy\"]",
        &format!("[batch]\nmu = [{}]\n", mus.join(", ")),
    );
    let random = |p: u64| {
        (
            format!("random_{p}_x1"),
            ensemble(
                1,
                "",
                &format!("[sweep]\ndesign = \"random\"\npoints = {p}\nseed = 3\nmu = {{ min = 0.005, max = 0.05, scale = \"log\" }}\nA = {{ min = 0.2, max = 0.8 }}\n"),
            ),
        )
    };
    vec![
        ("batch_4096".into(), batch),
        ("ensemble_4096".into(), ensemble(4096, "", "")),
        (
            "ensemble_4096_grid20".into(),
            ensemble(4096, "grid = 20", ""),
        ),
        (
            "ensemble_4096_energy".into(),
            ensemble(4096, "fields = [\"energy\"]", ""),
        ),
        ("ensemble_1024_N200".into(), ensemble_n(1024, 200)),
        ("ensemble_256_N1000".into(), ensemble_n(256, 1000)),
        random(64),
        random(256),
        random(4096),
        random(10_000),
    ]
}

/// Runs the scene once; returns (wall seconds, peak memory in bytes).
fn run_once(scene: &Path, out: &Path) -> (f64, u64) {
    let started = Instant::now();
    // Waited for with wait4 below, which also gives its peak memory.
    #[allow(clippy::zombie_processes)]
    let child = Command::new(BIN)
        .args([
            "run",
            scene.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .args(["--quiet", "--force"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("roughlub runs");
    let mut status: libc::c_int = 0;
    // SAFETY: an all-zero rusage is valid; wait4 fills it for our own child.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let pid = child.id() as libc::pid_t;
    assert_eq!(unsafe { libc::wait4(pid, &mut status, 0, &mut usage) }, pid);
    assert!(
        libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0,
        "{scene:?} failed"
    );
    (
        started.elapsed().as_secs_f64(),
        usage.ru_maxrss as u64 * 1024,
    )
}

fn dir_bytes(dir: &Path) -> u64 {
    std::fs::read_dir(dir)
        .map(|entries| {
            entries
                .filter_map(|e| e.ok())
                .map(|e| match e.metadata() {
                    Ok(m) if m.is_dir() => dir_bytes(&e.path()),
                    Ok(m) => m.len(),
                    Err(_) => 0,
                })
                .sum()
        })
        .unwrap_or(0)
}

/// Runs of each row behind the printed table: at least `TABLE_RUNS`, more for short rows until
/// they add up to `TABLE_SECONDS` (at most `TABLE_RUNS_MAX`): the share of a 20 ms study moved
/// from 7 to 25 % between medians of 5 runs, a stall of a few ms in writing its files.
const TABLE_RUNS: usize = 5;
const TABLE_SECONDS: f64 = 2.0;
const TABLE_RUNS_MAX: usize = 41;

/// The median (of the two middle values for an even count); sorts `values`.
fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    let half = values.len() / 2;
    match values.len() % 2 {
        1 => values[half],
        _ => 0.5 * (values[half - 1] + values[half]),
    }
}

fn study_scale(c: &mut Criterion) {
    let only: Option<Vec<String>> = std::env::var("STUDY_SCALE_ROWS")
        .ok()
        .map(|v| v.split(',').map(str::to_string).collect());
    let tmp = tempfile::tempdir().expect("temp dir");
    let mut table = Vec::new();
    let mut group = c.benchmark_group("study_scale");
    group
        .sample_size(10)
        .measurement_time(Duration::from_secs(20))
        .warm_up_time(Duration::from_secs(1));
    for (name, text) in rows() {
        if only.as_ref().is_some_and(|o| !o.contains(&name)) {
            continue;
        }
        let scene = tmp.path().join(format!("{name}.toml"));
        std::fs::write(&scene, text).expect("scene written");
        let out = tmp.path().join(&name);
        group.bench_function(&name, |b| b.iter(|| run_once(&scene, &out)));
        // The table's wall time and share are medians of the runs (one run's share varied by 3
        // points of percentage here), its peak memory the largest.
        let (mut walls, mut shares, mut peak) = (Vec::new(), Vec::new(), 0);
        while walls.len() < TABLE_RUNS
            || (walls.iter().sum::<f64>() < TABLE_SECONDS && walls.len() < TABLE_RUNS_MAX)
        {
            let (wall, run_peak) = run_once(&scene, &out);
            walls.push(wall);
            peak = peak.max(run_peak);
            if let Some(share) = std::fs::read_to_string(out.join("manifest.json"))
                .ok()
                .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
                .and_then(|m| m["statistics_share"].as_f64())
            {
                shares.push(share);
            }
        }
        let runs = walls.len();
        // The median, then the range of the runs.
        let share = (!shares.is_empty()).then(|| {
            let middle = median(&mut shares);
            (middle, shares[0], shares[shares.len() - 1])
        });
        table.push((name, runs, median(&mut walls), share, peak, dir_bytes(&out)));
    }
    group.finish();
    println!("\n| study | runs | wall | statistics share (range) | peak memory | on disk |");
    println!("|---|---|---|---|---|---|");
    for (name, runs, wall, share, peak, disk) in table {
        println!(
            "| {name} | {runs} | {wall:.2} s | {} | {:.0} MB | {:.1} MB |",
            share.map_or("-".into(), |(m, lo, hi)| format!(
                "{:.1} % ({:.1}-{:.1} %)",
                100.0 * m,
                100.0 * lo,
                100.0 * hi
            )),
            peak as f64 / 1e6,
            disk as f64 / 1e6
        );
    }
}

criterion_group!(benches, study_scale);
criterion_main!(benches);
