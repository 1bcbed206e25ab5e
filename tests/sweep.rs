//! Parameter studies (issue 10): statistics per sweep point, named parameters, designs.
//!
//! 1. A grid sweep's statistics at each point equal those of a separate study of that point's
//!    scene (same seed, same members): moments to 1e-12, quantiles and histograms identical, the
//!    members' rows identical.
//! 2. An expression with a parameter gives exactly the result of the expression with the literal
//!    value (single runs, CPU and GPU).
//! 3. Sampled designs are reproducible across chunk sizes, threads and shards (members.csv,
//!    points.csv and quantiles identical; moments to 1e-12).
//! 4. Bad sweeps and parameters are refused with the key named, before anything is written.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_roughlub");

/// Case 1 at N = 24 with lognormal roughness; `A` scales the initial velocity.
const BASE: &str = r#"name = "sweep"

[model]
particles = 24
mu = 0.01
gamma = 2.0

[parameters]
A = 0.5
level = 0.7

[initial]
rho = "level"
velocity = "A*sin(2*pi*x)"
rho_star = "0.7"

[time]
end = 0.03
outputs = 4
dt = 1e-3

[solver]
backend = "cpu"

[output]
grid = 16
plots = false

[ensemble]
members = 6
seed = 5
chunk = 4
bins = 50
roughness = { kind = "lognormal", spread = 0.2 }
"#;

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

fn roughlub(args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut cmd = Command::new(BIN);
    cmd.args(args);
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.output().expect("roughlub runs")
}

fn run(scene: &Path, out: &Path, extra: &[&str], env: &[(&str, &str)]) -> Output {
    let mut args = vec![
        "run",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ];
    args.extend(extra);
    let o = roughlub(&args, env);
    assert!(
        o.status.success(),
        "roughlub run {scene:?} failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    o
}

fn npy(path: &Path) -> (Vec<u64>, Vec<f64>) {
    let file = std::fs::File::open(path).unwrap_or_else(|e| panic!("{path:?}: {e}"));
    let npy = npyz::NpyFile::new(file).unwrap();
    let shape = npy.shape().to_vec();
    (shape, npy.into_vec::<f64>().unwrap())
}

fn stat(dir: &Path, name: &str) -> (Vec<u64>, Vec<f64>) {
    npy(&dir.join("stats").join(format!("{name}.npy")))
}

fn csv_rows(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let mut r = csv::Reader::from_path(path).unwrap();
    let head = r.headers().unwrap().iter().map(str::to_string).collect();
    let rows = r
        .records()
        .map(|x| x.unwrap().iter().map(str::to_string).collect())
        .collect();
    (head, rows)
}

/// Same bits, NaN equal to NaN.
fn identical(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len()
        && a.iter()
            .zip(b)
            .all(|(x, y)| x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan()))
}

fn close(a: &[f64], b: &[f64], rel: f64) -> bool {
    a.len() == b.len()
        && a.iter().zip(b).all(|(x, y)| {
            (x.is_nan() && y.is_nan()) || (x - y).abs() <= rel * x.abs().max(y.abs()) + 1e-300
        })
}

/// The statistics written per point, with how they must compare: exactly or to 1e-12.
const EXACT: [&str; 8] = [
    "max_density_count",
    "max_density_quantiles",
    "max_density_hist_counts",
    "min_gap_quantiles",
    "rho_quantiles",
    "u_quantiles",
    "first_hit_quantiles",
    "peak_density_quantiles",
];
const MOMENTS: [&str; 6] = [
    "max_density_mean",
    "max_density_var",
    "energy_mean",
    "rho_mean",
    "rho_var",
    "u_mean",
];

/// Slice `p` of an array whose first axis is the sweep point.
fn point_slice(shape: &[u64], values: &[f64], p: usize) -> Vec<f64> {
    let per: usize = shape[1..].iter().product::<u64>() as usize;
    values[p * per..(p + 1) * per].to_vec()
}

// ---------------------------------------------------------------------------------------------
// 1. Per-point statistics equal separate studies.

#[test]
fn per_point_statistics_equal_separate_studies() {
    let tmp = tempfile::tempdir().unwrap();
    // 2 x 2 grid: A (slowest) and the roughness spread; chunks of 4 straddle the points.
    let sweep_text = format!("{BASE}\n[sweep]\nA = [0.3, 0.6]\nroughness_spread = [0.1, 0.3]\n");
    let scene = write(tmp.path(), "sweep.toml", &sweep_text);
    let swept = tmp.path().join("swept");
    run(&scene, &swept, &[], &[]);
    let (_, points) = csv_rows(&swept.join("points.csv"));
    assert_eq!(points.len(), 4);
    let (head, rows) = csv_rows(&swept.join("members.csv"));
    assert_eq!(rows.len(), 24);
    let fixed = head.iter().position(|h| h == "mu").unwrap();
    assert_eq!(
        &head[..fixed],
        ["member", "sweep_point", "A", "roughness_spread"]
    );

    for (p, (a, spread)) in [(0.3, 0.1), (0.3, 0.3), (0.6, 0.1), (0.6, 0.3)]
        .iter()
        .enumerate()
    {
        assert_eq!(points[p][1].parse::<f64>().unwrap(), *a);
        assert_eq!(points[p][2].parse::<f64>().unwrap(), *spread);
        let alone = BASE
            .replace("A = 0.5", &format!("A = {a}"))
            .replace("spread = 0.2", &format!("spread = {spread}"));
        let alone_scene = write(tmp.path(), &format!("point{p}.toml"), &alone);
        let alone_dir = tmp.path().join(format!("point{p}"));
        run(&alone_scene, &alone_dir, &[], &[]);
        for name in EXACT {
            let (shape, got) = stat(&swept, name);
            let (alone_shape, want) = stat(&alone_dir, name);
            assert_eq!(shape[0], 4, "{name}: leading axis P");
            assert_eq!(alone_shape[0], 1);
            assert_eq!(shape[1..], alone_shape[1..], "{name} shape");
            assert!(
                identical(&point_slice(&shape, &got, p), &want),
                "{name} at point {p} differs from the separate study"
            );
        }
        for name in MOMENTS {
            let (shape, got) = stat(&swept, name);
            let (_, want) = stat(&alone_dir, name);
            assert!(
                close(&point_slice(&shape, &got, p), &want, 1e-12),
                "{name} at point {p} differs from the separate study by more than 1e-12"
            );
        }
        // The members themselves: member j of point p is member j of the separate study.
        let (alone_head, alone_rows) = csv_rows(&alone_dir.join("members.csv"));
        let alone_fixed = alone_head.iter().position(|h| h == "mu").unwrap();
        for j in 0..6 {
            assert_eq!(
                rows[p * 6 + j][fixed..],
                alone_rows[j][alone_fixed..],
                "member {j} of point {p}"
            );
        }
    }
}

// ---------------------------------------------------------------------------------------------
// 2. A parameter is its literal value, on the CPU and the GPU.

const SINGLE: &str = r#"name = "param"

[model]
particles = 30
mu = 0.02
gamma = 2.0
forcing = "FORCING"

[parameters]
F = 0.8
k = 3.0
level = 0.65

[initial]
rho = "RHO"
velocity = "0.4*sin(2*pi*x)"
rho_star = "0.7"

[time]
end = 0.02
outputs = 3
dt = 1e-3

[output]
grid = 20
plots = false
"#;

#[test]
fn a_parameter_gives_the_literal_result_on_cpu_and_gpu() {
    let tmp = tempfile::tempdir().unwrap();
    let with = SINGLE
        .replace("FORCING", "F*sin(k*pi*x)*exp(-t)")
        .replace("RHO", "level + 0.05*cos(2*pi*x)");
    let literal = SINGLE
        .replace("FORCING", "0.8*sin(3.0*pi*x)*exp(-t)")
        .replace("RHO", "0.65 + 0.05*cos(2*pi*x)");
    let with = write(tmp.path(), "with.toml", &with);
    let literal = write(tmp.path(), "literal.toml", &literal);
    let mut backends = vec![("cpu", "f64")];
    if common::gpu::acquire_for_tests(true).is_some() {
        backends.push(("gpu", "f64"));
    }
    if common::gpu::acquire_for_tests(false).is_some() {
        backends.push(("gpu", "f32"));
    }
    for (backend, precision) in backends {
        let extra = ["--backend", backend, "--precision", precision];
        let a = tmp.path().join(format!("with_{backend}_{precision}"));
        let b = tmp.path().join(format!("literal_{backend}_{precision}"));
        run(&with, &a, &extra, &[]);
        run(&literal, &b, &extra, &[]);
        for file in ["gaps.npy", "velocities.npy", "rho.npy", "energy.npy"] {
            let (sa, va) = npy(&a.join(file));
            let (sb, vb) = npy(&b.join(file));
            assert_eq!(sa, sb);
            assert!(
                identical(&va, &vb),
                "{backend} {precision}: {file} with parameters differs from the literal run"
            );
        }
        eprintln!("{backend} {precision}: parameters = literals, bit for bit");
    }
}

// ---------------------------------------------------------------------------------------------
// 3. Sampled designs: reproducible across chunks, threads and shards.

fn sampled(design: &str, chunk: usize) -> String {
    format!(
        "{}\n[sweep]\ndesign = \"{design}\"\npoints = 5\nseed = 3\nmu = {{ min = 0.005, max = 0.05, scale = \"log\" }}\nA = {{ min = 0.2, max = 0.8 }}\n",
        BASE.replace("chunk = 4", &format!("chunk = {chunk}"))
            .replace("members = 6", "members = 3")
    )
}

#[test]
fn sampled_designs_are_reproducible_across_chunks_threads_and_shards() {
    let tmp = tempfile::tempdir().unwrap();
    for design in ["random", "latin_hypercube", "sobol"] {
        let reference = tmp.path().join(format!("{design}_ref"));
        let scene = write(tmp.path(), &format!("{design}.toml"), &sampled(design, 15));
        run(&scene, &reference, &[], &[]);
        let small_chunks = write(
            tmp.path(),
            &format!("{design}_c2.toml"),
            &sampled(design, 2),
        );
        let chunked = tmp.path().join(format!("{design}_c2"));
        run(&small_chunks, &chunked, &[], &[("RAYON_NUM_THREADS", "1")]);
        let shards: Vec<PathBuf> = (0..2)
            .map(|k| {
                let dir = tmp.path().join(format!("{design}_s{k}"));
                run(&scene, &dir, &["--shard", &format!("{k}/2")], &[]);
                dir
            })
            .collect();
        let merged = tmp.path().join(format!("{design}_merged"));
        let o = roughlub(
            &[
                "merge",
                shards[0].to_str().unwrap(),
                shards[1].to_str().unwrap(),
                "--out",
                merged.to_str().unwrap(),
                "--no-plots",
            ],
            &[],
        );
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        // More shards than members (a Slurm array larger than the design): 16 shards of 15
        // members, one of them empty, each with its plots, merge to the same.
        let many: Vec<PathBuf> = (0..16)
            .map(|k| {
                let dir = tmp.path().join(format!("{design}_m{k}"));
                run(&scene, &dir, &["--shard", &format!("{k}/16")], &[]);
                dir
            })
            .collect();
        let empty = many
            .iter()
            .filter(|d| csv_rows(&d.join("members.csv")).1.is_empty())
            .count();
        assert_eq!(empty, 1, "{design}: shards without members");
        let merged_many = tmp.path().join(format!("{design}_merged16"));
        let mut args = vec!["merge"];
        args.extend(many.iter().map(|d| d.to_str().unwrap()));
        args.extend(["--out", merged_many.to_str().unwrap(), "--no-plots"]);
        let o = roughlub(&args, &[]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let (head, rows) = csv_rows(&reference.join("members.csv"));
        assert_eq!(rows.len(), 15);
        // No two columns share a name: the swept mu is `point_mu`, beside the member's `mu`.
        let unique: std::collections::BTreeSet<&String> = head.iter().collect();
        assert_eq!(unique.len(), head.len(), "{head:?}");
        let c_mu = head.iter().position(|h| h == "mu").unwrap();
        let c_point_mu = head.iter().position(|h| h == "point_mu").unwrap();
        assert!(c_point_mu < c_mu);
        // Every member records its point's values; they lie in the box.
        let c_a = head.iter().position(|h| h == "A").unwrap();
        for r in &rows {
            let a: f64 = r[c_a].parse().unwrap();
            let mu: f64 = r[c_mu].parse().unwrap();
            assert_eq!(r[c_point_mu], r[c_mu], "{r:?}");
            assert!(
                (0.2..0.8).contains(&a) && (0.005..0.05).contains(&mu),
                "{r:?}"
            );
        }
        for other in [&chunked, &merged, &merged_many] {
            for file in ["members.csv", "points.csv"] {
                assert_eq!(
                    std::fs::read_to_string(reference.join(file)).unwrap(),
                    std::fs::read_to_string(other.join(file)).unwrap(),
                    "{design}: {file} of {other:?}"
                );
            }
            for name in EXACT {
                assert!(
                    identical(&stat(&reference, name).1, &stat(other, name).1),
                    "{design}: {name} of {other:?}"
                );
            }
            for name in MOMENTS {
                assert!(
                    close(&stat(&reference, name).1, &stat(other, name).1, 1e-12),
                    "{design}: {name} of {other:?}"
                );
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// 4. Refusals.

#[test]
fn bad_parameters_and_sweeps_are_refused_naming_the_key() {
    let tmp = tempfile::tempdir().unwrap();
    let cases: [(&str, String, &[&str]); 18] = [
        (
            "a velocity that is infinite at the last point only",
            format!("{BASE}\n[sweep]\nA = [0.1, 0.2, 0.0]\n").replace("A*sin(2*pi*x)", "0.05/A*sin(2*pi*x)"),
            &["initial.velocity", "sweep point 2", "inf"],
        ),
        (
            "a velocity that is infinite at the last point only, which has its own chain",
            format!("{BASE}\n[sweep]\nA = [0.1, 0.2, 0.0]\n")
                .replace("A*sin(2*pi*x)", "0.05/A*sin(2*pi*x)")
                .replace("rho = \"level\"", "rho = \"0.6+0.1*A\""),
            &["initial.velocity", "sweep point 2", "inf"],
        ),
        (
            "a Saltelli design beyond the points' limit",
            format!("{BASE}\n[sweep]\ndesign = \"saltelli\"\npoints = 40000\nA = {{ min = 0.2, max = 0.8 }}\nlevel = {{ min = 0.5, max = 0.7 }}\n"),
            &["sweep.points = 40000", "(2 keys + 2) make 160000 points", "at most 25000 base points", "--allow-large"],
        ),
        (
            "a parameter out of its profile's range at the last point only",
            format!("{BASE}\n[sweep]\nlevel = [0.5, 0.6, 1.5]\n"),
            &["sweep point 2", "level = 1.5", "initial.rho", "(0, 1)"],
        ),
        (
            "a gamma sweep without roughness",
            format!("{BASE}\n[sweep]\ngamma = [1.0, 2.0]\n")
                .replace("rho_star = \"0.7\"\n", "")
                .replace("roughness = { kind = \"lognormal\", spread = 0.2 }\n", ""),
            &["sweep.gamma", "without roughness"],
        ),
        (
            "a repeated grid value",
            format!("{BASE}\n[sweep]\nA = [0.3, 0.5, 0.3]\n"),
            &["sweep.A[2]", "same value as sweep.A[0]"],
        ),
        (
            "a listed N that is not whole",
            format!("{BASE}\n[sweep]\nparticles = [10.5, 20]\n"),
            &["sweep.particles[0]", "10.5", "a whole number"],
        ),
        (
            "a parameter named like a members.csv column",
            BASE.replace("A = 0.5", "A = 0.5\nmember = 1.0"),
            &["parameters.member", "members.csv"],
        ),
        (
            "a parameter named like a swept key's members.csv column",
            BASE.replace("A = 0.5", "A = 0.5\npoint_mu = 1.0"),
            &["parameters.point_mu", "members.csv"],
        ),
        (
            "unknown name in an expression",
            BASE.replace("A*sin(2*pi*x)", "B*sin(2*pi*x)"),
            &["initial.velocity", "unknown identifier 'B'", "parameters: A, level"],
        ),
        (
            "a parameter shadowing x",
            BASE.replace("A = 0.5", "x = 0.5"),
            &["parameters.x", "shadow"],
        ),
        (
            "a parameter shadowing pi",
            BASE.replace("A = 0.5", "pi = 3"),
            &["parameters.pi", "shadow"],
        ),
        (
            "an inverted range",
            format!("{BASE}\n[sweep]\ndesign = \"random\"\npoints = 4\nA = {{ min = 0.8, max = 0.2 }}\n"),
            &["sweep.A", "min < max"],
        ),
        (
            "an empty list",
            format!("{BASE}\n[sweep]\nA = []\n"),
            &["sweep.A", "non-empty"],
        ),
        (
            "an unknown key",
            format!("{BASE}\n[sweep]\nB = [1.0, 2.0]\n"),
            &["sweep.B", "neither a setting", "A, level"],
        ),
        (
            "mu out of range",
            format!("{BASE}\n[sweep]\nmu = [0.01, -1.0]\n"),
            &["sweep.mu[1]"],
        ),
        (
            "a sweep without an ensemble",
            format!(
                "{}\n[sweep]\nA = [0.3, 0.5]\n",
                &BASE[..BASE.find("[ensemble]").unwrap()]
            ),
            &["sweep", "[ensemble]"],
        ),
        (
            "a log range through zero",
            format!("{BASE}\n[sweep]\ndesign = \"sobol\"\npoints = 8\nA = {{ min = 0.0, max = 1.0, scale = \"log\" }}\n"),
            &["sweep.A", "min > 0"],
        ),
    ];
    for (what, text, needles) in cases {
        let scene = write(tmp.path(), "bad.toml", &text);
        let out_dir = tmp.path().join("bad_out");
        let o = roughlub(
            &[
                "run",
                scene.to_str().unwrap(),
                "--out",
                out_dir.to_str().unwrap(),
            ],
            &[],
        );
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{what}: {err}");
        for n in needles {
            assert!(err.contains(n), "{what}: the message lacks {n:?}: {err}");
        }
        assert!(
            !out_dir.exists(),
            "{what}: a refused scene wrote {out_dir:?}"
        );
        let leftovers: Vec<_> = std::fs::read_dir(tmp.path())
            .unwrap()
            .filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().starts_with(".bad_out"))
            .collect();
        assert!(leftovers.is_empty(), "{what}: left {leftovers:?}");
    }
    // A design beyond the stated limit needs --allow-large.
    let big = format!(
        "{}\n[sweep]\ndesign = \"random\"\npoints = 200000\nA = {{ min = 0.1, max = 0.9 }}\n",
        BASE.replace("members = 6", "members = 1")
    );
    let scene = write(tmp.path(), "big.toml", &big);
    let out_dir = tmp.path().join("big_out");
    let o = roughlub(
        &[
            "run",
            scene.to_str().unwrap(),
            "--out",
            out_dir.to_str().unwrap(),
        ],
        &[],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("sweep.points") && err.contains("--allow-large"),
        "{err}"
    );
    assert!(!out_dir.exists());
}

// ---------------------------------------------------------------------------------------------
// 5. A swept forcing parameter: per member, one batch for many points.

fn forcing_study(sweep: &str) -> String {
    BASE.replace(
        "gamma = 2.0\n",
        "gamma = 2.0\nforcing = \"F*sin(2*pi*x)*exp(-t)\"\n",
    )
    .replace("level = 0.7\n", "level = 0.7\nF = 0.3\n")
    .replace("members = 6", "members = 4")
    .replace("chunk = 4", "chunk = 12")
        + sweep
}

#[test]
fn a_swept_forcing_parameter_is_read_per_member_in_one_batch() {
    let tmp = tempfile::tempdir().unwrap();
    let swept = write(
        tmp.path(),
        "forced.toml",
        &forcing_study("\n[sweep]\nF = [0.1, 0.4, 0.7]\n"),
    );
    let cpu = tmp.path().join("forced_cpu");
    run(&swept, &cpu, &[], &[]);
    // Point 2 equals the study of its own scene (F = 0.7, substituted while parsing).
    let alone = write(
        tmp.path(),
        "alone.toml",
        &forcing_study("").replace("F = 0.3", "F = 0.7"),
    );
    let alone_dir = tmp.path().join("alone");
    run(&alone, &alone_dir, &[], &[]);
    for name in EXACT {
        let (shape, got) = stat(&cpu, name);
        assert!(
            identical(&point_slice(&shape, &got, 2), &stat(&alone_dir, name).1),
            "{name}: point F = 0.7 differs from its own study"
        );
    }
    let (head, rows) = csv_rows(&cpu.join("members.csv"));
    let c_peak = head.iter().position(|h| h == "peak_density").unwrap();
    let peaks: Vec<f64> = rows.iter().map(|r| r[c_peak].parse().unwrap()).collect();
    assert!(
        peaks[0] != peaks[8],
        "the forcing amplitude must change the flow: {peaks:?}"
    );
    if common::gpu::acquire_for_tests(true).is_none() {
        return;
    }
    let gpu = tmp.path().join("forced_gpu");
    run(&swept, &gpu, &["--backend", "gpu"], &[]);
    let (_, gpu_rows) = csv_rows(&gpu.join("members.csv"));
    for (i, (a, b)) in rows.iter().zip(&gpu_rows).enumerate() {
        let (x, y): (f64, f64) = (a[c_peak].parse().unwrap(), b[c_peak].parse().unwrap());
        assert!(
            (x - y).abs() <= 1e-10 * x.abs(),
            "member {i}: cpu {x}, gpu {y}"
        );
    }
    // One batch for the three points: as many submissions as a study without the sweep.
    let plain = write(
        tmp.path(),
        "plain.toml",
        &forcing_study("").replace("members = 4", "members = 12"),
    );
    let plain_gpu = tmp.path().join("plain_gpu");
    run(&plain, &plain_gpu, &["--backend", "gpu"], &[]);
    let submits = |dir: &Path| -> u64 {
        let m: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("manifest.json")).unwrap())
                .unwrap();
        m["gpu_stats"]["submits"].as_u64().unwrap()
    };
    assert_eq!(
        submits(&gpu),
        submits(&plain_gpu),
        "the sweep split its batch"
    );
}

/// A sampled N is run rounded, and points.csv and members.csv record the N that ran (a
/// surrogate fitted on points.csv must see the inputs of the runs).
#[test]
fn a_sampled_particle_count_is_recorded_as_it_ran() {
    let tmp = tempfile::tempdir().unwrap();
    let text = format!(
        "{}\n[sweep]\ndesign = \"random\"\npoints = 6\nparticles = {{ min = 10, max = 40 }}\n",
        BASE.replace("members = 6", "members = 1")
    );
    let scene = write(tmp.path(), "n.toml", &text);
    let out = tmp.path().join("n");
    run(&scene, &out, &[], &[]);
    let (head, points) = csv_rows(&out.join("points.csv"));
    let c = head.iter().position(|h| h == "particles").unwrap();
    let listed: Vec<f64> = points.iter().map(|r| r[c].parse().unwrap()).collect();
    assert_eq!(listed.len(), 6);
    let (head, members) = csv_rows(&out.join("members.csv"));
    let c_point = head.iter().position(|h| h == "point_particles").unwrap();
    let c_ran = head.iter().position(|h| h == "particles").unwrap();
    for (r, &n) in members.iter().zip(&listed) {
        assert!(n.fract() == 0.0 && (10.0..=40.0).contains(&n), "{n}");
        assert_eq!(r[c_point].parse::<f64>().unwrap(), n, "{r:?}");
        assert_eq!(r[c_ran].parse::<f64>().unwrap(), n, "{r:?}");
    }
}
