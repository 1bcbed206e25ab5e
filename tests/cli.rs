//! End-to-end tests of the `roughlub` command: a small profile scene checked against closed
//! forms, a particle-file scene with clusters, bad input rejected with a precise message (exit
//! status 2, no manifest), and `--quiet`.
//!
//! Scenes and particle files live in `tests/data/`; bad scenes are built here from a good base
//! by one textual replacement each, so every case differs from an accepted scene in exactly one
//! place.

mod common;

use std::f64::consts::PI;
use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use roughlub::backend::cpu::SimdLevel;
use serde_json::Value;

const BIN: &str = env!("CARGO_BIN_EXE_roughlub");
const PNG_SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', 0x0d, 0x0a, 0x1a, 0x0a];

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests")
        .join("data")
        .join(name)
}

/// `roughlub run SCENE --out OUT [extra...]`.
fn run(scene: &Path, out: &Path, extra: &[&str]) -> Output {
    Command::new(BIN)
        .arg("run")
        .arg(scene)
        .arg("--out")
        .arg(out)
        .args(extra)
        .output()
        .unwrap_or_else(|e| panic!("cannot start {BIN}: {e}"))
}

fn stderr_of(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn assert_success(out: &Output) {
    assert_eq!(
        out.status.code(),
        Some(0),
        "roughlub failed; stderr:\n{}",
        stderr_of(out)
    );
}

/// An .npy file read back: its shape and its values in C order.
struct Npy {
    shape: Vec<u64>,
    values: Vec<f64>,
}

impl Npy {
    /// Element [i, j, k] of a 3-D array.
    fn at3(&self, i: usize, j: usize, k: usize) -> f64 {
        let s = &self.shape;
        assert_eq!(s.len(), 3);
        self.values[(i * s[1] as usize + j) * s[2] as usize + k]
    }

    /// Element [i, j] of a 2-D array.
    fn at2(&self, i: usize, j: usize) -> f64 {
        let s = &self.shape;
        assert_eq!(s.len(), 2);
        self.values[i * s[1] as usize + j]
    }

    /// Row [i, j, :] of a 3-D array.
    fn row(&self, i: usize, j: usize) -> &[f64] {
        let s = &self.shape;
        assert_eq!(s.len(), 3);
        let len = s[2] as usize;
        let start = (i * s[1] as usize + j) * len;
        &self.values[start..start + len]
    }
}

fn read_npy(path: &Path) -> Npy {
    let file = File::open(path).unwrap_or_else(|e| panic!("cannot open {path:?}: {e}"));
    let npy = npyz::NpyFile::new(file).unwrap_or_else(|e| panic!("{path:?} is not an .npy: {e}"));
    assert_eq!(npy.order(), npyz::Order::C, "{path:?} is not in C order");
    let shape = npy.shape().to_vec();
    let values = npy
        .into_vec::<f64>()
        .unwrap_or_else(|e| panic!("{path:?}: cannot read f64 values: {e}"));
    assert_eq!(
        values.len() as u64,
        shape.iter().product::<u64>(),
        "{path:?}: value count does not match the shape {shape:?}"
    );
    Npy { shape, values }
}

fn read_manifest(dir: &Path) -> Value {
    let path = dir.join("manifest.json");
    let text =
        std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("cannot read {path:?}: {e}"));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{path:?} is not JSON: {e}"))
}

#[track_caller]
fn assert_abs(actual: f64, expected: f64, tol: f64, what: &str) {
    assert!(
        (actual - expected).abs() <= tol,
        "{what}: got {actual:e}, expected {expected:e} (|diff| = {:e} > {tol:e})",
        (actual - expected).abs()
    );
}

#[track_caller]
fn assert_rel(actual: f64, expected: f64, tol: f64, what: &str) {
    let rel = (actual - expected).abs() / expected.abs();
    assert!(
        rel <= tol,
        "{what}: got {actual:e}, expected {expected:e} (relative diff {rel:e} > {tol:e})"
    );
}

fn assert_png(path: &Path) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("cannot read {path:?}: {e}"));
    assert!(bytes.len() > 8, "{path:?} is too short to be a PNG");
    assert_eq!(
        bytes[..8],
        PNG_SIGNATURE,
        "{path:?} lacks the PNG signature"
    );
}

/// The CPU step's instruction set changes its speed only: runs capped at AVX2
/// (ROUGHLUB_CPU_SIMD=avx2) or forced onto the portable lane loops (=portable) write the same
/// numbers, bit for bit, as one on the detected level (AVX-512 or AVX2 + FMA where the CPU has
/// them), and each manifest records its level.
#[test]
fn simd_level_does_not_change_results() {
    let tmp = tempfile::tempdir().unwrap();
    // Nine members: a block of 8 lanes and a padded one.
    let scene = std::fs::read_to_string(data("small.toml"))
        .unwrap()
        .replace(
            "gamma = [1.0, 2.0, 5.0]",
            "gamma = [1.0, 2.0, 5.0, 1.5, 3.0, 2.5, 4.0, 1.0, 2.0]",
        );
    let scene_path = tmp.path().join("nine.toml");
    std::fs::write(&scene_path, scene).unwrap();
    let runs = [
        ("detected", None),
        ("avx2", Some("avx2")),
        ("portable", Some("portable")),
    ];
    let mut outputs = Vec::new();
    for (name, level) in runs {
        let out_dir = tmp.path().join(name);
        let mut cmd = Command::new(BIN);
        cmd.arg("run").arg(&scene_path).arg("--out").arg(&out_dir);
        match level {
            Some(level) => cmd.env("ROUGHLUB_CPU_SIMD", level),
            None => cmd.env_remove("ROUGHLUB_CPU_SIMD"),
        };
        assert_success(&cmd.output().unwrap());
        let simd = read_manifest(&out_dir)["adapter"]["cpu_simd"]
            .as_str()
            .unwrap_or("")
            .to_string();
        let widest = SimdLevel::widest_here();
        let expected = match level {
            None => roughlub::backend::cpu::simd_level(None),
            Some("avx2") => widest.min(SimdLevel::Avx2Fma).name(),
            Some(_) => "portable",
        };
        assert_eq!(simd, expected, "{name} run");
        let bits = |file: &str| -> Vec<u64> {
            read_npy(&out_dir.join(file))
                .values
                .iter()
                .map(|v| v.to_bits())
                .collect()
        };
        outputs.push([bits("gaps.npy"), bits("velocities.npy"), bits("energy.npy")]);
    }
    for (k, file) in ["gaps.npy", "velocities.npy", "energy.npy"]
        .iter()
        .enumerate()
    {
        assert_eq!(outputs[0][k], outputs[1][k], "{file}: detected vs avx2");
        assert_eq!(outputs[0][k], outputs[2][k], "{file}: detected vs portable");
    }
}

// ---------------------------------------------------------------------------------------------
// 1. End to end: tests/data/small.toml (paper case 1 with N = 40, gamma swept over 1, 2, 5).

const N: usize = 40;
const B: usize = 3;
const T: usize = 3;
const GRID: usize = 50;
const GAMMAS: [f64; B] = [1.0, 2.0, 5.0];

#[test]
fn small_scene_end_to_end() {
    let tmp = tempfile::tempdir().unwrap();
    let out_dir = tmp.path().join("out");
    let out = run(&data("small.toml"), &out_dir, &[]);
    assert_success(&out);

    // --- manifest
    let m = read_manifest(&out_dir);
    assert_eq!(m["roughlub_version"], env!("CARGO_PKG_VERSION"));
    assert_eq!(m["backend"], "cpu");
    assert_eq!(m["precision"], "f64");
    // The CPU step's instruction set, as the library detects it on this machine.
    let simd = m["adapter"]["cpu_simd"].as_str().unwrap_or("");
    assert!(
        ["avx512", "avx2+fma", "portable"].contains(&simd),
        "cpu_simd {simd:?}"
    );
    assert_eq!(simd, roughlub::backend::cpu::simd_level(None));
    assert_eq!(m["particles"], N as u64);
    assert_eq!(m["grid"], GRID as u64);
    assert_eq!(m["scene"]["name"], "small");
    // The solve is a part of the run's wall time, never all of it (reading and writing remain).
    let (solve, wall) = (
        m["solve_seconds"].as_f64().expect("solve_seconds"),
        m["wall_seconds"].as_f64().expect("wall_seconds"),
    );
    assert!(
        solve > 0.0 && solve < wall,
        "solve {solve} s, wall {wall} s"
    );
    let eps = 0.7 / (2.0 * N as f64);
    // eps = M0/(2N), M0 = ∫ 0.7 summed over 4096 quadrature panels: rounding only, but a plain
    // sum of 4096 terms (src/initial.rs) loses ~4e-14 relative, hence 1e-13.
    assert_rel(m["eps"].as_f64().unwrap(), eps, 1e-13, "manifest eps");
    let members = m["members"].as_array().expect("members is an array");
    assert_eq!(members.len(), B, "members: {members:?}");
    for (k, member) in members.iter().enumerate() {
        assert_eq!(member["index"], k as u64, "member {k}: {member}");
        assert_eq!(member["status"], "ok", "member {k}: {member}");
        assert_eq!(member["mu"].as_f64(), Some(0.01), "member {k}");
        assert_eq!(member["gamma"].as_f64(), Some(GAMMAS[k]), "member {k}");
    }
    assert_eq!(m["failed_members"], serde_json::json!([]));
    // Every file the manifest lists exists; the temporary manifest is gone.
    let files = m["files"].as_array().expect("files is an array");
    for f in files {
        let p = out_dir.join(f.as_str().unwrap());
        assert!(p.is_file(), "manifest lists {p:?}, which does not exist");
    }
    assert!(!out_dir.join(".manifest.json.tmp").exists());

    // --- shapes
    let (t, b, n, g) = (T as u64, B as u64, N as u64, GRID as u64);
    let expected_shapes: [(&str, Vec<u64>); 11] = [
        ("times.npy", vec![t]),
        ("x.npy", vec![g]),
        ("gaps.npy", vec![t, b, n]),
        ("velocities.npy", vec![t, b, n - 1]),
        ("rho.npy", vec![t, b, g]),
        ("u.npy", vec![t, b, g]),
        ("rho_star.npy", vec![t, b, g]),
        ("energy.npy", vec![t, b]),
        ("dissipation.npy", vec![t, b]),
        ("min_gap.npy", vec![t, b]),
        ("max_density.npy", vec![t, b]),
    ];
    for (name, shape) in &expected_shapes {
        let npy = read_npy(&out_dir.join(name));
        assert_eq!(&npy.shape, shape, "shape of {name}");
        assert!(
            files.iter().any(|f| f == name),
            "manifest does not list {name}"
        );
    }

    // --- times and grid
    let times = read_npy(&out_dir.join("times.npy")).values;
    for (k, expected) in [0.0, 0.025, 0.05].into_iter().enumerate() {
        assert_abs(times[k], expected, 1e-15, &format!("times[{k}]"));
    }
    let x = read_npy(&out_dir.join("x.npy")).values;
    for (j, &xj) in x.iter().enumerate() {
        assert_abs(xj, j as f64 / (GRID - 1) as f64, 1e-15, &format!("x[{j}]"));
    }

    let gaps = read_npy(&out_dir.join("gaps.npy"));
    let vel = read_npy(&out_dir.join("velocities.npy"));
    let rho = read_npy(&out_dir.join("rho.npy"));
    let u = read_npy(&out_dir.join("u.npy"));
    let rho_star = read_npy(&out_dir.join("rho_star.npy"));
    let energy = read_npy(&out_dir.join("energy.npy"));
    let dissipation = read_npy(&out_dir.join("dissipation.npy"));
    let min_gap = read_npy(&out_dir.join("min_gap.npy"));
    let max_density = read_npy(&out_dir.join("max_density.npy"));
    let mu = 0.01;

    // --- t = 0: constant rho0 = 0.7 gives equally spaced particles q_i = i/N.
    // A gap (0.0075) is a difference of positions of order 1 minus 2 eps, so it carries the
    // absolute rounding of those: even exact q_i = i/N rounded to f64 give ~3e-14 relative. The
    // tolerance is absolute, 2e-14 (~90 ulp of 1, i.e. 2.7e-12 relative); the positions come
    // from a cumulative mass summed over 4096 panels (measured: 6.4e-15).
    let gap0 = 1.0 / N as f64 - 2.0 * eps;
    for mb in 0..B {
        for i in 0..N {
            assert_abs(
                gaps.at3(0, mb, i),
                gap0,
                2e-14,
                &format!("gap d_{} of member {mb} at t = 0", i + 1),
            );
        }
        for i in 1..N {
            assert_abs(
                vel.at3(0, mb, i - 1),
                0.5 * (2.0 * PI * i as f64 / N as f64).sin(),
                1e-12,
                &format!("u_{i} of member {mb} at t = 0"),
            );
        }
        for j in 0..GRID {
            assert_abs(
                rho.at3(0, mb, j),
                0.7,
                1e-12,
                &format!("rho(x_{j}) of member {mb} at t = 0"),
            );
            // u is the piecewise linear interpolant of 0.5 sin(2 pi x) on the nodes i/N:
            // |error| <= h^2/8 max|u''| = (1/40)^2/8 * 0.5 (2 pi)^2 = 1.55e-3.
            assert_abs(
                u.at3(0, mb, j),
                0.5 * (2.0 * PI * x[j]).sin(),
                1.6e-3,
                &format!("u(x_{j}) of member {mb} at t = 0"),
            );
        }
        // The walls do not move.
        assert_abs(u.at3(0, mb, 0), 0.0, 0.0, "u(0) at t = 0");
        assert_abs(u.at3(0, mb, GRID - 1), 0.0, 0.0, "u(1) at t = 0");
        assert_abs(min_gap.at2(0, mb), gap0, 2e-14, "min_gap at t = 0");
        assert_rel(max_density.at2(0, mb), 0.7, 1e-13, "max_density at t = 0");
    }

    // --- every time and member: sum of gaps is conserved (the update telescopes) and rho*
    // is 0.7 everywhere (d* is fixed in time and equal on every cell).
    for k in 0..T {
        for mb in 0..B {
            let sum: f64 = gaps.row(k, mb).iter().sum();
            assert_abs(
                sum,
                1.0 - 2.0 * eps * N as f64,
                1e-13,
                &format!("sum of gaps, t index {k}, member {mb}"),
            );
            for j in 0..GRID {
                assert_abs(
                    rho_star.at3(k, mb, j),
                    0.7,
                    1e-12,
                    &format!("rho_star(x_{j}), t index {k}, member {mb}"),
                );
            }
            for &d in gaps.row(k, mb) {
                assert!(d > 0.0, "a gap closed: {d:e} (t index {k}, member {mb})");
            }
        }
    }

    // --- energy at t = 0, from the written gaps and velocities.
    // E = eps sum u_i^2 + sum Phi_i; gamma = 1: Phi_i = -(d*_i + 2eps) ln(d_i + 2eps), with
    // d* = d since rho* = rho0.
    let kinetic = |mb: usize| eps * vel.row(0, mb).iter().map(|v| v * v).sum::<f64>();
    let e1: f64 = kinetic(0)
        + gaps
            .row(0, 0)
            .iter()
            .map(|&d| -(d + 2.0 * eps) * (d + 2.0 * eps).ln())
            .sum::<f64>();
    assert_rel(energy.at2(0, 0), e1, 1e-12, "energy (gamma = 1) at t = 0");
    // Closed form: eps * 0.25 * sum_{i<N} sin^2(2 pi i/N) = eps N/8 and -sum (1/N) ln(1/N) = ln N.
    let closed = eps * N as f64 / 8.0 + (N as f64).ln();
    assert_rel(
        energy.at2(0, 0),
        closed,
        1e-12,
        "energy (gamma = 1) closed form",
    );
    // gamma > 1: Phi_i = (d_i + 2eps) (s*/s)^gamma / (gamma - 1) with s* = s, so sum Phi = 1/(gamma-1).
    for mb in 1..B {
        let gamma = GAMMAS[mb];
        let phi: f64 = gaps
            .row(0, mb)
            .iter()
            .map(|&d| (d + 2.0 * eps) / (gamma - 1.0))
            .sum();
        assert_rel(
            energy.at2(0, mb),
            kinetic(mb) + phi,
            1e-12,
            &format!("energy (gamma = {gamma}) at t = 0"),
        );
        assert_rel(
            energy.at2(0, mb),
            eps * N as f64 / 8.0 + 1.0 / (gamma - 1.0),
            1e-12,
            &format!("energy (gamma = {gamma}) closed form"),
        );
    }
    // Dissipation mu sum (u_i - u_{i-1})^2 / d_i at t = 0 with u_0 = u_N = 0.
    for mb in 0..B {
        let v = vel.row(0, mb);
        let d = gaps.row(0, mb);
        let mut expected = 0.0;
        for i in 0..N {
            let right = if i < N - 1 { v[i] } else { 0.0 };
            let left = if i > 0 { v[i - 1] } else { 0.0 };
            expected += (right - left).powi(2) / d[i];
        }
        assert_rel(
            dissipation.at2(0, mb),
            mu * expected,
            1e-12,
            &format!("dissipation of member {mb} at t = 0"),
        );
    }
    // The model dissipates: dE/dt = -D < 0, so the energy decreases from output to output.
    for mb in 0..B {
        for k in 1..T {
            assert!(
                energy.at2(k, mb) < energy.at2(k - 1, mb),
                "energy of member {mb} grew from t index {} to {k}: {} -> {}",
                k - 1,
                energy.at2(k - 1, mb),
                energy.at2(k, mb)
            );
        }
    }

    // --- plots: one per member (plot_members defaults to 4 >= 3) and the max-density series.
    let plots = out_dir.join("plots");
    for name in [
        "member_0000.png",
        "member_0001.png",
        "member_0002.png",
        "max_density.png",
    ] {
        assert_png(&plots.join(name));
    }
    assert!(!plots.join("member_0003.png").exists());
}

// ---------------------------------------------------------------------------------------------
// 2. Particle file with clusters: tests/data/cluster.toml + cluster.csv (N = 10, eps = 0.02).
// Zero gaps: d_1 (particle 1 on the left wall) and d_5, d_6 (particles 4, 5, 6 as one cluster).

#[test]
fn particle_file_clusters_stay_rigid() {
    const N: usize = 10;
    const B: usize = 2;
    const T: usize = 6;
    let eps = 0.02;
    let tmp = tempfile::tempdir().unwrap();
    let out_dir = tmp.path().join("out");
    let out = run(&data("cluster.toml"), &out_dir, &["--quiet"]);
    assert_success(&out);

    let m = read_manifest(&out_dir);
    assert_eq!(m["particles"], N as u64);
    assert_eq!(m["eps"].as_f64(), Some(eps));
    assert_eq!(m["plan"]["clusters"], true);
    let members = m["members"].as_array().unwrap();
    assert_eq!(members.len(), B);
    for member in members {
        assert_eq!(member["status"], "ok", "{member}");
    }

    // The CSV, read independently.
    let csv = std::fs::read_to_string(data("cluster.csv")).unwrap();
    let rows: Vec<Vec<f64>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|c| c.trim().parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), N + 1);

    let gaps = read_npy(&out_dir.join("gaps.npy"));
    let vel = read_npy(&out_dir.join("velocities.npy"));
    let rho_star = read_npy(&out_dir.join("rho_star.npy"));
    let max_density = read_npy(&out_dir.join("max_density.npy"));
    assert_eq!(gaps.shape, vec![T as u64, B as u64, N as u64]);
    assert_eq!(vel.shape, vec![T as u64, B as u64, N as u64 - 1]);

    // Gap indices (0-based, d_{i+1}) and velocity indices (0-based, u_{i+1}).
    let bonded_gaps = [0usize, 4, 5];
    let wall_particle = 0usize; // u_1
    let cluster = [3usize, 4, 5]; // u_4, u_5, u_6

    // t = 0: the file's gaps and velocities.
    for mb in 0..B {
        for i in 1..=N {
            let d = rows[i][0] - rows[i - 1][0] - 2.0 * eps;
            let expected = if bonded_gaps.contains(&(i - 1)) {
                0.0
            } else {
                d
            };
            assert_abs(
                gaps.at3(0, mb, i - 1),
                expected,
                1e-15,
                &format!("d_{i} at t = 0"),
            );
        }
        for i in 1..N {
            assert_eq!(vel.at3(0, mb, i - 1), rows[i][1], "u_{i} at t = 0");
        }
    }

    for k in 0..T {
        for mb in 0..B {
            let at = format!("t index {k}, member {mb}");
            for &i in &bonded_gaps {
                let d = gaps.at3(k, mb, i);
                assert_eq!(d, 0.0, "bonded gap d_{} = {d:e}, {at}", i + 1);
            }
            let uw = vel.at3(k, mb, wall_particle);
            assert_eq!(uw, 0.0, "wall-glued particle 1 moves: u_1 = {uw:e}, {at}");
            let uc = vel.at3(k, mb, cluster[0]);
            for &c in &cluster[1..] {
                let v = vel.at3(k, mb, c);
                assert_eq!(
                    v.to_bits(),
                    uc.to_bits(),
                    "cluster velocities differ: u_{} = {uc:e}, u_{} = {v:e}, {at}",
                    cluster[0] + 1,
                    c + 1
                );
            }
            for (i, &d) in gaps.row(k, mb).iter().enumerate() {
                if !bonded_gaps.contains(&i) {
                    assert!(d > 0.0, "free gap d_{} = {d:e} closed, {at}", i + 1);
                }
            }
            // sum d_i = 1 - 2 eps N is conserved.
            let sum: f64 = gaps.row(k, mb).iter().sum();
            assert_abs(
                sum,
                1.0 - 2.0 * eps * N as f64,
                1e-13,
                &format!("sum of gaps, {at}"),
            );
            // A bonded gap is density 1.
            assert_eq!(max_density.at2(k, mb), 1.0, "max_density, {at}");
            // d*_i = r_{i-1} + r_i = 0.01 everywhere: rho* = 2eps/(d* + 2eps) = 0.8.
            for j in 0..rho_star.shape[2] as usize {
                assert_abs(
                    rho_star.at3(k, mb, j),
                    0.8,
                    1e-12,
                    &format!("rho*(x_{j}), {at}"),
                );
            }
        }
    }
    // The cluster really moved (the checks above are not about a frozen state).
    for mb in 0..B {
        let u_end = vel.at3(T - 1, mb, cluster[0]);
        assert!(
            (u_end - rows[4][1]).abs() > 1e-6,
            "member {mb}: cluster velocity unchanged ({u_end})"
        );
    }
}

// ---------------------------------------------------------------------------------------------
// 3. Bad input: exit status 2, "error: ..." naming the field and the allowed range or reason,
// and no manifest.json in the output directory.

/// A good profile scene; each bad case changes one piece of it.
const BASE: &str = include_str!("data/validation_base.toml");

/// A good particle-file scene reading `p.csv` next to it.
const BASE_FILE: &str = include_str!("data/validation_base_file.toml");

/// A good particle file for BASE_FILE: N = 4, all gaps positive.
const GOOD_CSV: &str =
    "x,u,r\n0.0,0.0,0.0\n0.25,0.1,0.0\n0.5,-0.1,0.0\n0.75,0.2,0.0\n1.0,0.0,0.0\n";

/// `base` with `from` replaced by `to` (which must occur exactly once).
fn edit(base: &str, from: &str, to: &str) -> String {
    assert_eq!(
        base.matches(from).count(),
        1,
        "test bug: {from:?} must occur once in the base scene"
    );
    base.replace(from, to)
}

/// Writes `scene` (and `files`) into a fresh directory, runs it, and checks the rejection.
/// Returns stderr.
#[track_caller]
fn expect_rejected(scene: &str, files: &[(&str, &str)], needles: &[&str]) -> String {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("scene.toml");
    std::fs::write(&path, scene).unwrap();
    for (name, text) in files {
        std::fs::write(tmp.path().join(name), text).unwrap();
    }
    let out_dir = tmp.path().join("out");
    let out = run(&path, &out_dir, &[]);
    let stderr = stderr_of(&out);
    assert_eq!(
        out.status.code(),
        Some(2),
        "expected exit status 2; stderr:\n{stderr}"
    );
    assert!(
        stderr.starts_with("error:"),
        "stderr does not start with \"error:\":\n{stderr}"
    );
    for needle in needles {
        assert!(
            stderr.contains(needle),
            "stderr does not mention {needle:?}:\n{stderr}"
        );
    }
    assert!(
        !out_dir.join("manifest.json").exists(),
        "a rejected scene left a manifest"
    );
    stderr
}

#[test]
fn base_scenes_are_accepted() {
    // The bad cases below differ from these in one place only.
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("scene.toml");
    std::fs::write(&scene, BASE).unwrap();
    let out = run(&scene, &tmp.path().join("a"), &["--quiet"]);
    assert_success(&out);
    let m = read_manifest(&tmp.path().join("a"));
    // Rounding of the mass sum over 4096 panels (see small_scene_end_to_end).
    assert_rel(m["eps"].as_f64().unwrap(), 0.7 / 20.0, 1e-13, "eps of BASE");

    let scene = tmp.path().join("file.toml");
    std::fs::write(&scene, BASE_FILE).unwrap();
    std::fs::write(tmp.path().join("p.csv"), GOOD_CSV).unwrap();
    let out = run(&scene, &tmp.path().join("b"), &["--quiet"]);
    assert_success(&out);
    let m = read_manifest(&tmp.path().join("b"));
    assert_eq!(m["particles"], 4);
    // d_1 = x_1 - x_0 - 2 radius.
    let gaps = read_npy(&tmp.path().join("b").join("gaps.npy"));
    assert_abs(gaps.at3(0, 0, 0), 0.25 - 0.04, 1e-15, "d_1 of GOOD_CSV");
}

#[test]
fn rejects_unknown_key() {
    let s = edit(BASE, "mu = 0.01\n", "mu = 0.01\nviscosity = 2\n");
    // toml names the key and lists the allowed ones.
    expect_rejected(&s, &[], &["viscosity", "unknown field", "`mu`"]);
}

#[test]
fn rejects_negative_mu() {
    let s = edit(BASE, "mu = 0.01", "mu = -1");
    expect_rejected(&s, &[], &["model.mu", "0 < mu <= 1e12"]);
}

/// Issue 8, item 3: values certain to fail are refused before the run, naming the field.
#[test]
fn rejects_values_certain_to_fail() {
    let s = edit(BASE, "mu = 0.01", "mu = 1e308");
    expect_rejected(
        &s,
        &[],
        &["model.mu = 1e308", "mu/d_i overflow", "0 < mu <= 1e12"],
    );
    let s = edit(BASE, "0.5*sin(2*pi*x)", "1e308*x");
    expect_rejected(
        &s,
        &[],
        &["initial.velocity", "u0 = 1e308 at x = 1", "|u0| <= 1e12"],
    );
    let csv = "x,u,r\n0.0,0.0,0.0\n0.25,0.1,1e300\n0.5,-0.1,0.0\n0.75,0.2,0.0\n1.0,0.0,0.0\n";
    expect_rejected(
        BASE_FILE,
        &[("p.csv", csv)],
        &["p.csv", "line 3", "column r", "r = 1e300", "0 <= r < 1"],
    );
    // gamma = 1000 with rho/rho* = 0.9/0.3 = 3: G = 3^1000 overflows f64 at t = 0.
    let s = edit(
        &edit(
            &edit(BASE, "rho = \"0.7\"", "rho = \"0.9\""),
            "rho_star = \"0.7\"",
            "rho_star = \"0.3\"",
        ),
        "gamma = 1.0",
        "gamma = 1000.0",
    );
    expect_rejected(
        &s,
        &[],
        &[
            "model.gamma = 1000",
            "overflows f64 at t = 0",
            "rho/rho* = 3,",
            "gamma <= 646",
        ],
    );
    // In f32 at gamma = 100: 3^100 = 5e47 passes f32's 3.4e38 (ln 88.72: gamma <= 80), not f64's.
    let s = edit(&s, "gamma = 1000.0", "gamma = 100.0");
    let f32_scene = edit(
        &s,
        "backend = \"cpu\"",
        "backend = \"cpu\"\nprecision = \"f32\"",
    );
    expect_rejected(
        &f32_scene,
        &[],
        &[
            "model.gamma = 100",
            "overflows f32 at t = 0",
            "ln(f32::MAX) = 88.72",
            "gamma <= 80",
        ],
    );
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("scene.toml");
    std::fs::write(&path, &s).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_roughlub"))
        .args([
            "run".as_ref(),
            path.as_os_str(),
            "--quiet".as_ref(),
            "--out".as_ref(),
        ])
        .arg(tmp.path().join("out"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn rejects_gamma_below_one() {
    let s = edit(BASE, "gamma = 1.0", "gamma = 0.5");
    expect_rejected(&s, &[], &["model.gamma", "1 <= gamma"]);
}

#[test]
fn rejects_one_particle() {
    let s = edit(BASE, "particles = 10", "particles = 1");
    expect_rejected(&s, &[], &["model.particles", "2 <= particles"]);
}

#[test]
fn rejects_rho_above_one() {
    let s = edit(BASE, "rho = \"0.7\"", "rho = \"1.2\"");
    expect_rejected(&s, &[], &["initial.rho", "(0, 1)"]);
}

#[test]
fn rejects_zero_rho_star() {
    let s = edit(BASE, "rho_star = \"0.7\"", "rho_star = \"0\"");
    expect_rejected(&s, &[], &["initial.rho_star", "(0, 1]"]);
}

#[test]
fn rejects_unparsable_velocity() {
    let s = edit(BASE, "0.5*sin(2*pi*x)", "0.5*sinn(2*pi*x)");
    // "sinn" starts at character 4 (0-based) of the expression.
    expect_rejected(&s, &[], &["initial.velocity", "sinn", "position 4"]);
}

#[test]
fn rejects_dt_and_tolerance_together() {
    let s = edit(BASE, "dt = 1e-3\n", "dt = 1e-3\ntolerance = 1e-6\n");
    expect_rejected(&s, &[], &["time.dt", "time.tolerance", "not both"]);
}

#[test]
fn rejects_neither_dt_nor_tolerance() {
    let s = edit(BASE, "dt = 1e-3\n", "");
    expect_rejected(&s, &[], &["time.dt", "time.tolerance"]);
}

#[test]
fn rejects_one_output() {
    let s = edit(BASE, "outputs = 2", "outputs = 1");
    expect_rejected(&s, &[], &["time.outputs", "2 ..= 100000"]);
}

#[test]
fn rejects_fractional_output_count_in_the_users_words() {
    let s = edit(BASE, "outputs = 2", "outputs = 2.5");
    let err = expect_rejected(&s, &[], &["time.outputs", "whole number of output times"]);
    assert!(!err.contains("untagged"), "{err}");
}

#[test]
fn rejects_an_end_time_whose_output_times_overflow() {
    let s = edit(BASE, "outputs = 2", "outputs = 100");
    let s = s.replacen("end = ", "end = 1e308 # ", 1);
    expect_rejected(&s, &[], &["time.end", "1e308", "strictly increasing"]);
}

#[test]
fn rejects_nan_dt() {
    let s = edit(BASE, "dt = 1e-3", "dt = nan");
    expect_rejected(&s, &[], &["time.dt", "finite"]);
}

#[test]
fn rejects_order_nine_and_auto_with_fixed_steps() {
    let s = edit(BASE, "order = 1", "order = 9");
    expect_rejected(&s, &[], &["solver.order = 9", "2..=8", "\"auto\""]);
    let s = edit(BASE, "order = 1", "order = \"auto\"");
    expect_rejected(&s, &[], &["solver.order", "time.tolerance"]);
}

/// Orders 7 and 8 in f32 are refused before anything runs: their error estimates carry about
/// 1e-3 of f32 rounding (measured: order 8 in f32 failed at tolerances 1e-4 to 1e-6 on the
/// N = 200 chain of docs/accuracy.md, where order 6 completed); order 6 in f32 still runs.
#[test]
fn rejects_orders_above_six_in_f32() {
    let s = edit(BASE, "order = 1", "order = 8\nprecision = \"f32\"");
    expect_rejected(
        &s,
        &[],
        &["solver.order = 8 with precision f32", "1..=6", "f64"],
    );
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("scene.toml");
    std::fs::write(
        &path,
        edit(BASE, "order = 1", "order = 6\nprecision = \"f32\""),
    )
    .unwrap();
    let out = run(&path, &tmp.path().join("out"), &[]);
    assert_success(&out);
}

/// Tolerances below an order's f32 rounding are refused before anything runs: 10 · 2^-23 times
/// the rounding gain sum |c_j| n_j of column max(k, 3) (order 4: 91.33 ulps, 1.09e-4; auto,
/// column 3: 22 ulps, 2.63e-5; `Order::f32_tolerance_floor`), where the rounding added up over
/// the steps exceeds the tolerance (auto at 1e-5 on case 2a: 13 times it). Above the floor, and
/// in f64 at the refused tolerance, the same scene completes in at most 100 steps.
#[test]
fn rejects_f32_tolerances_below_the_orders_rounding() {
    let adaptive = |order: &str, tolerance: &str, precision: &str| {
        edit(BASE, "dt = 1e-3", &format!("tolerance = {tolerance}")).replace(
            "order = 1",
            &format!("order = {order}\nprecision = \"{precision}\""),
        )
    };
    expect_rejected(
        &adaptive("4", "1e-5", "f32"),
        &[],
        &[
            "time.tolerance = 1e-5 with precision f32, order 4 and sequence from_1",
            ">= 1.09e-4",
        ],
    );
    expect_rejected(
        &adaptive("\"auto\"", "1e-7", "f32"),
        &[],
        &[
            "time.tolerance = 1e-7 with precision f32, order auto and sequence from_1",
            ">= 2.63e-5",
            "1.73e-3 for 6",
        ],
    );
    // The floors of from_2 (10 · 2^-23 times 63.1 for column 3), named for it.
    expect_rejected(
        &adaptive("\"auto\"", "1e-6", "f32").replace(
            "order = \"auto\"",
            "order = \"auto\"\nsequence = \"from_2\"",
        ),
        &[],
        &[
            "order auto and sequence from_2",
            ">= 7.52e-5",
            "5.49e-3 for 6",
        ],
    );
    // The bound a message names is allowed (1.73e-3 for order 6: 1.7221e-3 rounded up).
    for (order, tolerance, precision) in [
        ("4", "2e-4", "f32"),
        ("4", "1e-5", "f64"),
        ("6", "1.73e-3", "f32"),
    ] {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("scene.toml");
        std::fs::write(&path, adaptive(order, tolerance, precision)).unwrap();
        let out_dir = tmp.path().join("out");
        assert_success(&run(&path, &out_dir, &[]));
        let member = &read_manifest(&out_dir)["members"][0];
        let label = format!("order {order} at {tolerance} in {precision}");
        assert_eq!(member["status"], "ok", "{label}");
        let steps =
            member["steps_accepted"].as_u64().unwrap() + member["steps_rejected"].as_u64().unwrap();
        assert!(steps <= 100, "{label}: {steps} steps");
    }
}

/// A sequence or jacobian that order 1 ignores is said on stderr (the run goes on, and its
/// manifest records what ran: from_1, frozen).
#[test]
fn settings_order_one_ignores_are_said() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("scene.toml");
    let scene = edit(
        BASE,
        "order = 1",
        "order = 1\nsequence = \"from_2\"\njacobian = \"exact\"",
    );
    std::fs::write(&path, scene).unwrap();
    let out_dir = tmp.path().join("out");
    let out = run(&path, &out_dir, &[]);
    assert_success(&out);
    let stderr = String::from_utf8_lossy(&out.stderr);
    for needle in [
        "warning: solver.sequence = \"from_2\" has no effect with order 1",
        "warning: solver.jacobian = \"exact\" has no effect with order 1",
    ] {
        assert!(stderr.contains(needle), "{needle} not in {stderr}");
    }
    let manifest = read_manifest(&out_dir);
    assert_eq!(manifest["plan"]["sequence"], "from_1");
    assert_eq!(manifest["plan"]["jacobian"], "frozen");
}

/// `output.fields` listing rho_star in a scene without roughness: the run goes on without it
/// and says so (a script may list the same fields for every scene).
#[test]
fn a_listed_rho_star_without_roughness_is_said() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("scene.toml");
    let scene = edit(
        &edit(BASE, "rho_star = \"0.7\"\n", ""),
        "grid = 20",
        "grid = 20\nfields = [\"rho\", \"rho_star\"]",
    );
    std::fs::write(&path, scene).unwrap();
    let out_dir = tmp.path().join("out");
    let out = run(&path, &out_dir, &[]);
    assert_success(&out);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("warning: output.fields lists \"rho_star\""),
        "{stderr}"
    );
    assert!(out_dir.join("rho.npy").exists());
    assert!(!out_dir.join("rho_star.npy").exists());
}

#[test]
fn rejects_unknown_backend() {
    let s = edit(BASE, "backend = \"cpu\"", "backend = \"tpu\"");
    expect_rejected(
        &s,
        &[],
        &["solver.backend", "tpu", "\"cpu\", \"gpu\" or \"auto\""],
    );
}

#[test]
fn rejects_overlapping_particles() {
    // Particle 2 (file line 4: header, particles 0, 1, 2) sits 0.03 right of particle 1: the
    // gap 0.03 - 2 * 0.02 = -0.01 < 0.
    let csv = "x,u,r\n0.0,0.0,0.0\n0.2,0.1,0.0\n0.23,-0.1,0.0\n0.6,0.2,0.0\n1.0,0.0,0.0\n";
    expect_rejected(
        BASE_FILE,
        &[("p.csv", csv)],
        &["p.csv", "line 4", "overlap", "particles 1 and 2"],
    );
}

/// The reader skips '#' comment lines, so "line K" must count them to point at the row in the
/// file. (Fails at the time of writing: src/initial.rs numbers rows as record index + 2.)
#[test]
fn particle_file_line_numbers_count_comment_lines() {
    // Same overlap as above, with two comment lines ('#', which the reader accepts) before the
    // rows: particle 2 is now on line 6 of the file.
    let csv = "# particles for a test\nx,u,r\n# particle 0 is the left wall\n0.0,0.0,0.0\n0.2,0.1,0.0\n0.23,-0.1,0.0\n0.6,0.2,0.0\n1.0,0.0,0.0\n";
    expect_rejected(
        BASE_FILE,
        &[("p.csv", csv)],
        &["p.csv", "line 6", "overlap"],
    );
}

#[test]
fn rejects_last_particle_not_at_one() {
    // N = 4: particle 4 is on line 6.
    let csv = "x,u,r\n0.0,0.0,0.0\n0.25,0.1,0.0\n0.5,-0.1,0.0\n0.75,0.2,0.0\n0.9,0.0,0.0\n";
    expect_rejected(BASE_FILE, &[("p.csv", csv)], &["p.csv", "line 6", "x = 1"]);
}

#[test]
fn rejects_non_numeric_cell() {
    let csv = "x,u,r\n0.0,0.0,0.0\n0.25,0.1,0.0\n0.5,abc,0.0\n0.75,0.2,0.0\n1.0,0.0,0.0\n";
    expect_rejected(
        BASE_FILE,
        &[("p.csv", csv)],
        &["p.csv", "line 4", "not a row of numbers"],
    );
}

#[test]
fn rejects_missing_particle_file() {
    let s = edit(BASE_FILE, "\"p.csv\"", "\"missing.csv\"");
    expect_rejected(&s, &[], &["missing.csv", "cannot open"]);
}

#[test]
fn rejects_invalid_toml() {
    let s = edit(BASE, "[model]", "[model");
    // The message names the file and the line of the error (line 3).
    let stderr = expect_rejected(&s, &[], &["scene file", "scene.toml", "line 3"]);
    assert!(stderr.contains("TOML parse error"), "{stderr}");
}

/// A bad scene run into a directory that holds a complete earlier run. Validation (scene, then
/// the initial chain) happens before `prepare_dir` (src/run.rs), so the rejected run never
/// touches the directory: the earlier manifest stays, byte for byte, and still describes the
/// files beside it.
#[test]
fn rejected_scene_leaves_an_earlier_run_untouched() {
    let tmp = tempfile::tempdir().unwrap();
    let out_dir = tmp.path().join("out");
    let good = tmp.path().join("good.toml");
    std::fs::write(&good, BASE).unwrap();
    assert_success(&run(&good, &out_dir, &["--quiet"]));
    let before = std::fs::read(out_dir.join("manifest.json")).unwrap();

    let bad = tmp.path().join("bad.toml");
    std::fs::write(&bad, edit(BASE, "mu = 0.01", "mu = -1")).unwrap();
    let out = run(&bad, &out_dir, &["--quiet"]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr_of(&out));
    assert!(stderr_of(&out).contains("model.mu"));
    let after = std::fs::read(out_dir.join("manifest.json"))
        .expect("the earlier manifest.json is still there");
    assert_eq!(before, after, "the earlier manifest.json changed");
    assert_eq!(read_manifest(&out_dir)["scene"]["name"], "base");
}

/// A run killed while it writes (SIGKILL) leaves the earlier run complete and unchanged: the new
/// one is written beside it and swapped in only when complete (issue 9, items 1 and 2).
#[test]
fn a_killed_run_leaves_the_earlier_run_whole() {
    let tmp = tempfile::tempdir().unwrap();
    let out_dir = tmp.path().join("out");
    let good = tmp.path().join("good.toml");
    std::fs::write(&good, BASE).unwrap();
    assert_success(&run(&good, &out_dir, &["--quiet"]));
    let before: Vec<(String, Vec<u8>)> = files_of(&out_dir);

    // A long run: many particles and outputs, killed while it writes.
    let long = tmp.path().join("long.toml");
    let text = edit(
        &edit(BASE, "particles = 10", "particles = 20000"),
        "end = 0.01",
        "end = 100.0",
    );
    std::fs::write(&long, edit(&text, "outputs = 2", "outputs = 2000")).unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_roughlub"))
        .args([
            "run".as_ref(),
            long.as_os_str(),
            "--out".as_ref(),
            out_dir.as_os_str(),
            "--quiet".as_ref(),
        ])
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(1500));
    assert!(
        child.try_wait().unwrap().is_none(),
        "test data: the long run was still going"
    );
    let leftover = tmp.path().join(format!(".out.partial-{}", child.id()));
    child.kill().unwrap();
    child.wait().unwrap();
    assert_eq!(files_of(&out_dir), before, "the earlier run changed");

    // The killed run's staging directory is removed by the next run into the same --out.
    assert!(leftover.is_dir(), "expected the killed run's {leftover:?}");
    let again = run(&good, &out_dir, &["--quiet"]);
    assert_success(&again);
    assert!(!leftover.exists(), "the leftover staging directory stayed");
    assert!(
        String::from_utf8_lossy(&again.stderr).contains("left by an interrupted run"),
        "the removal is not reported: {}",
        String::from_utf8_lossy(&again.stderr)
    );
}

/// A new run replaces the directory whole: nothing of the earlier run (other fields, another N)
/// stays beside it (issue 9, item 1).
#[test]
fn a_new_run_leaves_nothing_of_the_earlier_one() {
    let tmp = tempfile::tempdir().unwrap();
    let out_dir = tmp.path().join("out");
    let full = tmp.path().join("full.toml");
    std::fs::write(&full, BASE).unwrap();
    assert_success(&run(&full, &out_dir, &["--quiet"]));
    assert!(out_dir.join("velocities.npy").is_file());
    let gaps_only = tmp.path().join("gaps.toml");
    let text = edit(BASE, "particles = 10", "particles = 12");
    std::fs::write(
        &gaps_only,
        edit(
            &text,
            "grid = 20",
            "grid = 20\nfields = [\"gaps\"]\nplots = false",
        ),
    )
    .unwrap();
    assert_success(&run(&gaps_only, &out_dir, &["--quiet"]));
    assert!(
        !out_dir.join("velocities.npy").exists(),
        "velocities.npy of the earlier run stayed"
    );
    assert!(
        !out_dir.join("rho.npy").exists(),
        "rho.npy of the earlier run stayed"
    );
    assert_eq!(read_npy(&out_dir.join("gaps.npy")).shape, vec![2, 1, 12]);
    // No staging directory is left beside it.
    let leftovers = common::names_starting_with(tmp.path(), ".out.");
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

/// A directory that holds files but no roughlub run is not replaced without --force.
#[test]
fn a_foreign_directory_is_replaced_only_with_force() {
    let tmp = tempfile::tempdir().unwrap();
    let out_dir = tmp.path().join("data");
    std::fs::create_dir(&out_dir).unwrap();
    std::fs::write(out_dir.join("thesis.tex"), "precious").unwrap();
    let scene = tmp.path().join("scene.toml");
    std::fs::write(&scene, BASE).unwrap();
    let out = run(&scene, &out_dir, &["--quiet"]);
    let stderr = stderr_of(&out);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("holds files but no roughlub run") && stderr.contains("--force"),
        "{stderr}"
    );
    assert_eq!(
        std::fs::read_to_string(out_dir.join("thesis.tex")).unwrap(),
        "precious"
    );
    assert_success(&run(&scene, &out_dir, &["--quiet", "--force"]));
    assert!(out_dir.join("manifest.json").is_file());
    assert!(!out_dir.join("thesis.tex").exists());
}

/// A `manifest.json` or `study.json` that roughlub did not write (no `roughlub_version`) does not
/// make a directory a run; nor does a `.NAME.partial-PID` name without the staging marker make
/// a directory a leftover to remove.
#[test]
fn files_named_like_roughlubs_do_not_make_a_directory_replaceable() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("scene.toml");
    std::fs::write(&scene, BASE).unwrap();
    for (record, text) in [
        ("manifest.json", r#"{"name": "webapp"}"#),
        ("study.json", "not json"),
    ] {
        let out_dir = tmp.path().join(format!("site_{record}"));
        std::fs::create_dir(&out_dir).unwrap();
        std::fs::write(out_dir.join(record), text).unwrap();
        std::fs::write(out_dir.join("index.html"), "precious").unwrap();
        let out = run(&scene, &out_dir, &["--quiet"]);
        let stderr = stderr_of(&out);
        assert_eq!(out.status.code(), Some(2), "{record}: {stderr}");
        assert!(
            stderr.contains("holds files but no roughlub run"),
            "{stderr}"
        );
        assert_eq!(
            std::fs::read_to_string(out_dir.join("index.html")).unwrap(),
            "precious"
        );
    }
    // A user's directory named like a killed run's staging directory (PID 1 is never ours and
    // always alive, 4194305 above Linux's PID limit: dead), with a study.json of its own.
    for pid in [1u32, 4194305] {
        let lookalike = tmp.path().join(format!(".out.partial-{pid}"));
        std::fs::create_dir(&lookalike).unwrap();
        std::fs::write(lookalike.join("study.json"), "{}").unwrap();
        std::fs::write(lookalike.join("x.txt"), "precious").unwrap();
    }
    assert_success(&run(&scene, &tmp.path().join("out"), &["--quiet"]));
    for pid in [1u32, 4194305] {
        let kept = tmp.path().join(format!(".out.partial-{pid}")).join("x.txt");
        assert_eq!(
            std::fs::read_to_string(&kept).unwrap(),
            "precious",
            "{kept:?}"
        );
    }
}

/// Every file under `dir` (relative path, bytes), sorted.
fn files_of(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p.strip_prefix(dir).unwrap().display().to_string();
                out.push((rel, std::fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

// ---------------------------------------------------------------------------------------------
// 4. --quiet

#[test]
fn quiet_prints_nothing_and_default_names_the_backend() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("scene.toml");
    std::fs::write(&scene, BASE).unwrap();

    let out = run(&scene, &tmp.path().join("q"), &["--quiet"]);
    assert_success(&out);
    assert_eq!(stderr_of(&out), "", "--quiet printed on stderr");
    assert_eq!(
        String::from_utf8_lossy(&out.stdout),
        "",
        "--quiet printed on stdout"
    );
    assert!(tmp.path().join("q").join("manifest.json").is_file());

    let out = run(&scene, &tmp.path().join("v"), &[]);
    assert_success(&out);
    let stderr = stderr_of(&out);
    assert!(stderr.contains("backend cpu"), "stderr:\n{stderr}");
    // The summary line: 1 member, none failed, on the CPU backend.
    assert!(
        stderr.contains("1 members (0 failed) on cpu"),
        "stderr:\n{stderr}"
    );

    // --backend overrides the scene; auto names itself and the backend that runs (the GPU where
    // an adapter exists, else the CPU), and the manifest agrees with stderr.
    let out = run(&scene, &tmp.path().join("w"), &["--backend", "auto"]);
    assert_success(&out);
    let stderr = stderr_of(&out);
    assert!(stderr.contains("backend auto"), "stderr:\n{stderr}");
    let backend = read_manifest(&tmp.path().join("w"))["backend"]
        .as_str()
        .unwrap()
        .to_string();
    assert!(backend == "cpu" || backend == "gpu", "{backend}");
    assert!(
        stderr.contains(&format!("on {backend}")),
        "stderr:\n{stderr}"
    );
}

/// A run whose outputs would not fit any sane disk is refused before anything is written, naming
/// the size and what to change; `--allow-large` is the way past it (issue 9, item 8).
#[test]
fn outputs_beyond_the_size_limit_are_refused_before_writing() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("big.toml");
    let text = edit(
        &edit(BASE, "outputs = 2", "outputs = 100000"),
        "end = 0.01",
        "end = 10.0",
    );
    std::fs::write(&scene, edit(&text, "grid = 20", "grid = 1000000")).unwrap();
    let out_dir = tmp.path().join("out");
    let out = run(&scene, &out_dir, &["--quiet"]);
    let stderr = stderr_of(&out);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    // 100000 times x 1 member x (10 + 9 + 3 x 1e6 + 5) x 8 bytes.
    let gb = 100_000.0 * (10.0 + 9.0 + 3e6 + 5.0) * 8.0 / 1e9;
    assert!(
        stderr.contains(&format!(
            "time.outputs = 100000: the outputs would take {gb:.1} GB"
        )),
        "{stderr}"
    );
    assert!(stderr.contains("--allow-large"), "{stderr}");
    assert!(!out_dir.exists(), "a refused run created its directory");

    // With N = 1e8 the refusal comes from the scene, before the initial data (1.6 GB of gaps
    // and velocities, minutes to build) exists; this test would take that long otherwise.
    std::fs::write(
        &scene,
        edit(&text, "particles = 10", "particles = 100000000"),
    )
    .unwrap();
    let out = run(&scene, &out_dir, &["--quiet"]);
    let stderr = stderr_of(&out);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("N = 100000000"), "{stderr}");
    assert!(!out_dir.exists(), "a refused run created its directory");
}

/// With many output times the profile plots are thinned (see `run::tests`), the .npy outputs keep
/// every time (issue 9, item 8).
#[test]
fn many_output_times_are_thinned_in_plots_only() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("many.toml");
    let text = edit(
        &edit(BASE, "outputs = 2", "outputs = 5001"),
        "end = 0.01",
        "end = 5.0",
    );
    std::fs::write(&scene, text).unwrap();
    let out_dir = tmp.path().join("out");
    assert_success(&run(&scene, &out_dir, &["--quiet"]));
    assert_eq!(read_npy(&out_dir.join("times.npy")).shape, vec![5001]);
    assert_png(&out_dir.join("plots").join("member_0000.png"));
}

/// `roughlub ARGS` run in `dir` (paths in ARGS relative to it).
fn roughlub_in(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_roughlub"))
        .current_dir(dir)
        .args(args)
        .output()
        .unwrap()
}

/// `--out .` (or `DIR/.`, which Path reads as DIR but a rename does not) cannot be swapped in
/// whole by a rename: refused with exit 2 before the run, nothing written.
#[test]
fn out_dot_is_refused() {
    for target in [".", "sub/.", "./sub/."] {
        let tmp = tempfile::tempdir().unwrap();
        let scene = tmp.path().join("s.toml");
        std::fs::write(&scene, BASE).unwrap();
        std::fs::create_dir(tmp.path().join("sub")).unwrap();
        let out = roughlub_in(
            tmp.path(),
            &["run", "s.toml", "--out", target, "--quiet", "--force"],
        );
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{target}: {stderr}");
        assert!(
            stderr.contains("--out must name a directory of its own"),
            "{target}: {stderr}"
        );
        let mut names = common::names_starting_with(tmp.path(), "");
        names.sort();
        assert_eq!(
            names,
            ["s.toml", "sub"],
            "{target}: a refused run wrote {names:?}"
        );
        assert_eq!(
            std::fs::read_dir(tmp.path().join("sub")).unwrap().count(),
            0
        );
    }
}

/// The manifest records every file a run reads (issue standards: everything that determines a
/// result): the particle file with the FNV-1a of its bytes (computed here independently), which
/// changes with one velocity of the file.
#[test]
fn the_manifest_records_the_particle_file_it_read() {
    fn fnv1a(bytes: &[u8]) -> String {
        let mut h: u64 = 0xcbf29ce484222325;
        for &b in bytes {
            h = (h ^ u64::from(b)).wrapping_mul(0x100000001b3);
        }
        format!("{h:016x}")
    }
    let tmp = tempfile::tempdir().unwrap();
    std::fs::write(tmp.path().join("s.toml"), BASE_FILE).unwrap();
    let mut hashes = Vec::new();
    for csv in [
        GOOD_CSV.to_string(),
        GOOD_CSV.replace("0.25,0.1", "0.25,0.11"),
    ] {
        std::fs::write(tmp.path().join("p.csv"), &csv).unwrap();
        let out = roughlub_in(
            tmp.path(),
            &["run", "s.toml", "--out", "o", "--quiet", "--force"],
        );
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let m: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(tmp.path().join("o/manifest.json")).unwrap(),
        )
        .unwrap();
        let files = m["input_files"].as_object().expect("input_files");
        assert_eq!(files.len(), 1, "{files:?}");
        let (path, hash) = files.iter().next().unwrap();
        assert!(path.ends_with("p.csv"), "{path}");
        assert_eq!(hash.as_str().unwrap(), fnv1a(csv.as_bytes()));
        hashes.push(hash.clone());
    }
    assert_ne!(hashes[0], hashes[1]);
}

/// `--out FILE/sub` where FILE is a file: refused before the run, naming the file.
#[test]
fn out_below_a_file_is_refused_naming_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    std::fs::write(tmp.path().join("s.toml"), BASE).unwrap();
    std::fs::write(tmp.path().join("afile"), "not a directory").unwrap();
    let out = roughlub_in(
        tmp.path(),
        &["run", "s.toml", "--out", "afile/sub", "--quiet"],
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("afile is a file, not a directory"),
        "{stderr}"
    );
    assert_eq!(
        std::fs::read_to_string(tmp.path().join("afile")).unwrap(),
        "not a directory"
    );
}

/// Leftovers beside --out are removed only when they are roughlub's: a directory named like a
/// leftover but holding someone's files stays. A commit killed between its two renames (the
/// earlier run moved aside, the new one not yet in place) is repaired by the next run: the
/// earlier run is put back before anything else happens.
#[test]
fn leftovers_are_roughlubs_only_and_an_interrupted_commit_is_repaired() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("s.toml");
    std::fs::write(&scene, BASE).unwrap();
    let out_dir = tmp.path().join("out");
    // A dead PID: larger than any Linux pid_max.
    let foreign = tmp.path().join(".out.old-99999999");
    std::fs::create_dir_all(&foreign).unwrap();
    std::fs::write(foreign.join("notes.txt"), "mine").unwrap();
    assert_success(&run(&scene, &out_dir, &["--quiet"]));
    assert!(
        foreign.join("notes.txt").exists(),
        "someone's directory was removed"
    );

    // Simulate the kill between the renames: the run moved aside, no target.
    let moved = tmp.path().join(".out.old-99999998");
    std::fs::rename(&out_dir, &moved).unwrap();
    let before = files_of(&moved);
    let again = run(&scene, &tmp.path().join("other"), &["--quiet"]);
    assert_success(&again);
    assert!(
        moved.exists(),
        "a run into another --out touched this one's leftovers"
    );
    let repaired = run(&scene, &out_dir, &[]);
    assert_success(&repaired);
    let stderr = String::from_utf8_lossy(&repaired.stderr);
    assert!(
        stderr.contains("interrupted while being replaced") && stderr.contains("the earlier run"),
        "the repair is not reported: {stderr}"
    );
    assert!(!moved.exists(), "the moved-aside run stayed beside --out");
    assert!(out_dir.join("manifest.json").exists());
    assert_eq!(before.len(), files_of(&out_dir).len());
}

/// A symbolic link as --out is refused (the run would replace the link, not its directory).
#[test]
fn a_symlinked_out_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("s.toml");
    std::fs::write(&scene, BASE).unwrap();
    let real = tmp.path().join("real");
    std::fs::create_dir_all(&real).unwrap();
    let link = tmp.path().join("link");
    std::os::unix::fs::symlink(&real, &link).unwrap();
    let out = run(&scene, &link, &["--quiet"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("symbolic link"));
    assert!(link.is_symlink() && std::fs::read_dir(&real).unwrap().next().is_none());
}

/// The options of ensemble studies on a scene without `[ensemble]` are errors naming the option,
/// not silently ignored (`--checkpoint-every` was, until 2026-11-30), and nothing is written.
#[test]
fn study_options_on_a_single_run_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    for extra in [
        &["--checkpoint-every", "5"][..],
        &["--shard", "0/2"],
        &["--resume"],
    ] {
        let out_dir = tmp.path().join("out");
        let out = run(&data("small.toml"), &out_dir, extra);
        let err = stderr_of(&out);
        assert_eq!(out.status.code(), Some(2), "{extra:?}: {err}");
        assert!(
            err.contains(extra[0]) && err.contains("[ensemble]"),
            "{extra:?}: {err}"
        );
        assert!(!out_dir.exists(), "{extra:?} wrote {out_dir:?}");
    }
}
