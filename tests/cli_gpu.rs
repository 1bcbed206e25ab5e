//! End-to-end tests of backend and precision selection in `roughlub run`: the GPU backend in f64
//! and f32 against the CPU backend, `auto` choosing the GPU when there is one and falling back to
//! the CPU (saying why, in the precision asked for) when there is none, f32 on the CPU, and the
//! clear error (exit status 2, no manifest) for `gpu` without an adapter.
//!
//! Tests that need a GPU adapter ask `common::gpu::acquire_for_tests`: without an adapter they
//! skip with a message, unless `ROUGHLUB_REQUIRE_GPU=1` (CI), where they fail. The "no adapter"
//! cases hide every adapter with `WGPU_ADAPTER_NAME=no-such-adapter` (a substring filter that
//! `GpuContext::acquire` applies), so they run everywhere.
//!
//! The scene is `tests/data/small.toml`: paper case 1 with N = 40, three members (gamma = 1, 2,
//! 5), order 1, fixed dt = 1e-3 up to t = 0.05 (50 steps), outputs at 0, 0.025, 0.05.

mod common;

use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use roughlub::backend::error::NO_ADAPTER_HINT;
use serde_json::Value;

const BIN: &str = env!("CARGO_BIN_EXE_roughlub");

fn small_scene() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests")
        .join("data")
        .join("small.toml")
}

/// `roughlub run SCENE --out OUT [extra...]` with extra environment variables.
fn run_env(scene: &Path, out: &Path, extra: &[&str], env: &[(&str, &str)]) -> Output {
    let mut cmd = Command::new(BIN);
    cmd.arg("run").arg(scene).arg("--out").arg(out).args(extra);
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.output()
        .unwrap_or_else(|e| panic!("cannot start {BIN}: {e}"))
}

fn run(scene: &Path, out: &Path, extra: &[&str]) -> Output {
    run_env(scene, out, extra, &[])
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

/// Exit status 2, an `error:` line containing every one of `needles`, and no output directory.
fn assert_rejected(out: &Output, out_dir: &Path, needles: &[&str]) {
    let stderr = stderr_of(out);
    assert_eq!(
        out.status.code(),
        Some(2),
        "expected exit 2; stderr:\n{stderr}"
    );
    assert!(
        stderr.contains("error: "),
        "no error line; stderr:\n{stderr}"
    );
    for needle in needles {
        assert!(
            stderr.contains(needle),
            "the error does not mention {needle:?}; stderr:\n{stderr}"
        );
    }
    assert!(
        !out_dir.join("manifest.json").exists(),
        "a rejected run wrote a manifest"
    );
    assert!(
        !out_dir.exists(),
        "a run rejected before it started created its output directory"
    );
}

/// Values of an .npy file (f64, C order) and its shape.
fn read_npy(path: &Path) -> (Vec<u64>, Vec<f64>) {
    let file = File::open(path).unwrap_or_else(|e| panic!("cannot open {path:?}: {e}"));
    let npy = npyz::NpyFile::new(file).unwrap_or_else(|e| panic!("{path:?} is not an .npy: {e}"));
    assert_eq!(npy.order(), npyz::Order::C, "{path:?} is not in C order");
    let shape = npy.shape().to_vec();
    let values = npy
        .into_vec::<f64>()
        .unwrap_or_else(|e| panic!("{path:?}: cannot read f64 values: {e}"));
    (shape, values)
}

fn read_manifest(dir: &Path) -> Value {
    let path = dir.join("manifest.json");
    let text =
        std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("cannot read {path:?}: {e}"));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{path:?} is not JSON: {e}"))
}

/// Whether a GPU adapter (with f64 shaders when `want_f64`) exists; `false` means "skip this
/// test" (and panics instead under ROUGHLUB_REQUIRE_GPU=1).
fn have_gpu(want_f64: bool, test: &str) -> bool {
    match common::gpu::acquire_for_tests(want_f64) {
        Some(ctx) => {
            drop(ctx);
            true
        }
        None => {
            eprintln!(
                "{test}: skipped (no GPU adapter{})",
                if want_f64 { " with f64" } else { "" }
            );
            false
        }
    }
}

/// Compares two gap arrays element by element: |a - b| <= rel |b|. Returns the largest relative
/// difference.
fn assert_gaps_close(gpu: &Path, cpu: &Path, rel: f64, what: &str) -> f64 {
    let (shape_g, g) = read_npy(&gpu.join("gaps.npy"));
    let (shape_c, c) = read_npy(&cpu.join("gaps.npy"));
    assert_eq!(shape_g, shape_c, "{what}: gaps.npy shapes differ");
    assert_eq!(shape_g, vec![3, 3, 40], "{what}: gaps.npy shape [T, B, N]");
    let mut worst: f64 = 0.0;
    for (i, (a, b)) in g.iter().zip(&c).enumerate() {
        assert!(
            a.is_finite() && *b > 0.0,
            "{what}: gap {i}: gpu {a}, cpu {b}"
        );
        let r = (a - b).abs() / b.abs();
        assert!(
            r <= rel,
            "{what}: gap {i} (t {}, member {}, d_{}): gpu {a:e}, cpu {b:e}, relative difference \
             {r:e} > {rel:e}",
            i / 120,
            (i / 40) % 3,
            i % 40 + 1
        );
        worst = worst.max(r);
    }
    worst
}

/// Checks what every GPU run's manifest must say.
fn assert_gpu_manifest(m: &Value, requested: &str, precision: &str) {
    assert_eq!(m["backend"], "gpu", "manifest: {m}");
    assert_eq!(m["backend_requested"], requested);
    assert_eq!(m["precision"], precision);
    let adapter = &m["adapter"];
    for key in ["name", "backend", "driver"] {
        assert!(
            adapter[key].is_string(),
            "adapter.{key} missing; adapter: {adapter}"
        );
    }
    assert!(
        !adapter["name"].as_str().unwrap().is_empty(),
        "empty adapter name; adapter: {adapter}"
    );
    let stats = &m["gpu_stats"];
    assert!(
        stats["submits"].as_u64().is_some_and(|s| s >= 1),
        "gpu_stats.submits: {stats}"
    );
    // How many steps one dispatch takes is the solver's business; at least one ran.
    assert!(
        stats["dispatches"].as_u64().is_some_and(|d| d >= 1),
        "gpu_stats.dispatches: {stats}"
    );
    assert!(
        stats["bytes_read"].as_u64().is_some_and(|b| b > 0),
        "gpu_stats.bytes_read: {stats}"
    );
    for member in m["members"].as_array().expect("members") {
        assert_eq!(member["status"], "ok", "{member}");
    }
}

/// Runs the scene on the CPU (the reference) into `dir`.
fn cpu_reference(dir: &Path) {
    let out = run(&small_scene(), dir, &["--backend", "cpu", "--quiet"]);
    assert_success(&out);
    let m = read_manifest(dir);
    assert_eq!(m["backend"], "cpu");
    assert!(m["gpu_stats"].is_null(), "a CPU run has gpu_stats: {m}");
}

// ---------------------------------------------------------------------------------------------
// 1. --backend gpu --precision f64 matches the CPU

#[test]
fn gpu_f64_matches_cpu() {
    if !have_gpu(true, "gpu_f64_matches_cpu") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let (gpu, cpu) = (tmp.path().join("gpu"), tmp.path().join("cpu"));
    let out = run(
        &small_scene(),
        &gpu,
        &["--backend", "gpu", "--precision", "f64"],
    );
    assert_success(&out);
    let stderr = stderr_of(&out);
    assert!(stderr.contains("backend gpu"), "stderr:\n{stderr}");
    let m = read_manifest(&gpu);
    assert_gpu_manifest(&m, "gpu", "f64");
    assert!(
        stderr.contains(m["adapter"]["name"].as_str().unwrap()),
        "stderr does not name the adapter; stderr:\n{stderr}"
    );

    cpu_reference(&cpu);
    // Same steps, same f64 arithmetic up to operation order and the f64 math library: the two
    // backends agree to a few ulps per step.
    let worst = assert_gaps_close(&gpu, &cpu, 1e-10, "gpu f64 vs cpu");
    eprintln!("gpu f64 vs cpu: largest relative gap difference {worst:e}");
    // Both took the same 50 fixed steps per member.
    let mc = read_manifest(&cpu);
    assert_eq!(m["steps_accepted_total"], mc["steps_accepted_total"]);
}

// ---------------------------------------------------------------------------------------------
// 2. --backend gpu --precision f32 is close to the CPU

#[test]
fn gpu_f32_close_to_cpu() {
    if !have_gpu(false, "gpu_f32_close_to_cpu") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let (gpu, cpu) = (tmp.path().join("gpu"), tmp.path().join("cpu"));
    let out = run(
        &small_scene(),
        &gpu,
        &["--backend", "gpu", "--precision", "f32"],
    );
    assert_success(&out);
    assert_gpu_manifest(&read_manifest(&gpu), "gpu", "f32");
    // f32 output is still written as f64 .npy.
    cpu_reference(&cpu);
    // f32 has a unit roundoff of 6e-8: the initial gaps are rounded once (relative 6e-8), and
    // each of the 50 steps adds rounding from the tridiagonal solve over 40 unknowns and the
    // gap update d + h (u_i - u_{i-1}), which the implicit scheme damps rather than amplifies.
    // A worst-case bound 50 steps x ~20 roundings x 6e-8 = 6e-5 stays below 1e-4; anything
    // larger would be a kernel error, not rounding (gaps are ~7.5e-3, far from 0).
    let worst = assert_gaps_close(&gpu, &cpu, 1e-4, "gpu f32 vs cpu");
    eprintln!("gpu f32 vs cpu: largest relative gap difference {worst:e}");
    // ...and f32 really is f32: not bit-identical to the f64 reference.
    assert!(worst > 0.0, "f32 results equal the f64 ones exactly");
}

// ---------------------------------------------------------------------------------------------
// 3. --backend auto picks a hardware GPU when there is one, and the native CPU over a software
//    adapter (lavapipe), which --backend gpu still runs

#[test]
fn auto_picks_the_gpu_and_says_so() {
    if !have_gpu(true, "auto_picks_the_gpu_and_says_so") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("auto");
    let out = run(&small_scene(), &dir, &["--backend", "auto"]);
    assert_success(&out);
    let m = read_manifest(&dir);
    let gpu_dir = tmp.path().join("gpu");
    assert_success(&run(&small_scene(), &gpu_dir, &["--backend", "gpu"]));
    let gpu_manifest = read_manifest(&gpu_dir);
    assert_gpu_manifest(&gpu_manifest, "gpu", "f64");
    if gpu_manifest["adapter"]["device_type"] == "Cpu" {
        // Only a software adapter: auto runs the native CPU and says why.
        assert_eq!(m["backend"], "cpu", "manifest: {m}");
        assert_eq!(m["backend_requested"], "auto");
        let why = m["adapter"]["fallback_reason"].as_str().unwrap_or_default();
        assert!(
            why.contains("software rasterizer") && why.contains("--backend gpu"),
            "fallback_reason: {why:?}"
        );
        assert!(
            stderr_of(&out).contains("software rasterizer"),
            "stderr: {}",
            stderr_of(&out)
        );
        let cpu = tmp.path().join("cpu");
        cpu_reference(&cpu);
        let (_, a) = read_npy(&dir.join("gaps.npy"));
        let (_, b) = read_npy(&cpu.join("gaps.npy"));
        assert_eq!(a, b, "auto's CPU run differs from --backend cpu");
        return;
    }
    assert_gpu_manifest(&m, "auto", "f64");
    let stderr = stderr_of(&out);
    let name = m["adapter"]["name"].as_str().unwrap();
    assert!(
        stderr.contains("backend auto") && stderr.contains("GPU") && stderr.contains(name),
        "stderr does not say that auto runs on the GPU adapter {name:?}; stderr:\n{stderr}"
    );
    assert!(
        stderr.contains("on gpu"),
        "the summary line does not name the GPU backend; stderr:\n{stderr}"
    );
}

// ---------------------------------------------------------------------------------------------
// 4. --backend cpu --precision f32 runs in f32, close to f64, and the manifest says so

/// The CPU in f32 against the CPU in f64: within the same 1e-4 as the GPU's f32 (the same
/// rounding budget, see `gpu_f32_close_to_cpu`), not bit-identical, and the manifest records
/// backend cpu, precision f32 and the SIMD level of the lane loops.
#[test]
fn cpu_f32_runs_and_the_manifest_says_f32() {
    let tmp = tempfile::tempdir().unwrap();
    let (dir, cpu) = (tmp.path().join("f32"), tmp.path().join("cpu"));
    let out = run(
        &small_scene(),
        &dir,
        &["--backend", "cpu", "--precision", "f32"],
    );
    assert_success(&out);
    let stderr = stderr_of(&out);
    assert!(
        stderr.contains("backend cpu") && stderr.contains("precision f32"),
        "stderr: {stderr}"
    );
    let m = read_manifest(&dir);
    assert_eq!(m["backend"], "cpu", "manifest: {m}");
    assert_eq!(m["backend_requested"], "cpu");
    assert_eq!(m["precision"], "f32");
    assert!(m["gpu_stats"].is_null());
    let simd = m["adapter"]["cpu_simd"].as_str().unwrap_or_default();
    assert!(
        ["avx512", "avx2+fma", "portable"].contains(&simd),
        "cpu_simd {simd:?}"
    );
    cpu_reference(&cpu);
    let worst = assert_gaps_close(&dir, &cpu, 1e-4, "cpu f32 vs cpu f64");
    eprintln!("cpu f32 vs cpu f64: largest relative gap difference {worst:e}");
    assert!(worst > 0.0, "f32 results equal the f64 ones exactly");
    // The same 50 fixed steps per member.
    let mc = read_manifest(&cpu);
    assert_eq!(m["steps_accepted_total"], mc["steps_accepted_total"]);
}

// ---------------------------------------------------------------------------------------------
// 5. no adapter: `gpu` is an error with the install hint, `auto` falls back to the CPU

#[test]
fn gpu_without_adapter_is_an_error_with_the_install_hint() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("out");
    let env = [("WGPU_ADAPTER_NAME", "no-such-adapter")];
    for precision in ["f64", "f32"] {
        let out = run_env(
            &small_scene(),
            &dir,
            &["--backend", "gpu", "--precision", precision],
            &env,
        );
        assert_rejected(
            &out,
            &dir,
            &["solver.backend", "no GPU adapter", NO_ADAPTER_HINT],
        );
    }
}

#[test]
fn auto_without_adapter_falls_back_to_the_cpu_and_says_why() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("auto");
    let env = [("WGPU_ADAPTER_NAME", "no-such-adapter")];
    let out = run_env(&small_scene(), &dir, &["--backend", "auto"], &env);
    assert_success(&out);
    let stderr = stderr_of(&out);
    assert!(
        stderr.contains("backend auto")
            && stderr.contains("no GPU adapter")
            && stderr.contains("running on the CPU")
            && stderr.contains("rayon"),
        "stderr does not say why auto runs on the CPU; stderr:\n{stderr}"
    );
    let m = read_manifest(&dir);
    assert_eq!(m["backend"], "cpu");
    assert_eq!(m["backend_requested"], "auto");
    assert_eq!(m["precision"], "f64");
    assert!(m["gpu_stats"].is_null());
    let adapter = &m["adapter"];
    assert_eq!(adapter["backend"], "cpu", "adapter: {adapter}");
    assert!(
        adapter["name"]
            .as_str()
            .is_some_and(|n| n.starts_with("cpu (rayon, ") && n.ends_with(" threads)")),
        "adapter: {adapter}"
    );
    assert!(
        adapter["fallback_reason"]
            .as_str()
            .is_some_and(|r| r.contains("no GPU adapter")),
        "adapter: {adapter}"
    );

    // The fallback runs the same numbers as the CPU backend.
    let cpu = tmp.path().join("cpu");
    cpu_reference(&cpu);
    let (_, a) = read_npy(&dir.join("gaps.npy"));
    let (_, b) = read_npy(&cpu.join("gaps.npy"));
    assert_eq!(a, b, "auto's CPU fallback differs from --backend cpu");

    // f32 falls back to the CPU in f32 (not a silent f64 run): the same numbers as
    // `--backend cpu --precision f32`.
    let dir32 = tmp.path().join("auto32");
    let out = run_env(
        &small_scene(),
        &dir32,
        &["--backend", "auto", "--precision", "f32"],
        &env,
    );
    assert_success(&out);
    let m = read_manifest(&dir32);
    assert_eq!(m["backend"], "cpu");
    assert_eq!(m["backend_requested"], "auto");
    assert_eq!(m["precision"], "f32");
    let cpu32 = tmp.path().join("cpu32");
    let out = run(
        &small_scene(),
        &cpu32,
        &["--backend", "cpu", "--precision", "f32", "--quiet"],
    );
    assert_success(&out);
    let (_, a) = read_npy(&dir32.join("gaps.npy"));
    let (_, b) = read_npy(&cpu32.join("gaps.npy"));
    assert_eq!(
        a, b,
        "auto's f32 CPU fallback differs from --backend cpu --precision f32"
    );
    let (_, c) = read_npy(&cpu.join("gaps.npy"));
    assert_ne!(a, c, "auto with f32 ran in f64");
}

// ---------------------------------------------------------------------------------------------
// A GPU run on a headless machine prints nothing that looks like an error

/// Mesa's Vulkan device-selection layer connects to a Wayland display and, with no
/// XDG_RUNTIME_DIR, prints "error: XDG_RUNTIME_DIR is invalid or not set" (twice per run
/// before roughlub turned the layer off). Expected: stderr has no line containing "error".
#[test]
fn a_headless_gpu_run_prints_no_error_lines() {
    if !have_gpu(false, "a_headless_gpu_run_prints_no_error_lines") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("headless");
    let mut cmd = Command::new(BIN);
    cmd.arg("run")
        .arg(small_scene())
        .arg("--out")
        .arg(&out_dir)
        .args(["--backend", "gpu"])
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("WAYLAND_DISPLAY")
        .env_remove("NODEVICE_SELECT")
        .env_remove("MESA_VK_DEVICE_SELECT");
    let out = cmd.output().expect("roughlub starts");
    assert_success(&out);
    let stderr = stderr_of(&out);
    let noisy: Vec<&str> = stderr
        .lines()
        // roughlub's own end line names the largest error estimate.
        .filter(|l| l.to_lowercase().contains("error") && !l.contains("; largest error estimate "))
        .collect();
    assert!(
        noisy.is_empty(),
        "a successful GPU run printed error-like lines: {noisy:?}"
    );
}

/// The single member of `scene` run on `backend` into `out_dir`, asserted failed as stalled,
/// and its attempts (accepted and rejected steps).
fn stalled_member(scene: &Path, out_dir: &Path, backend: &str) -> (Value, u64) {
    let out = run(scene, out_dir, &["--quiet", "--backend", backend]);
    assert_success(&out);
    let member = read_manifest(out_dir)["members"][0].clone();
    assert_eq!(member["status"], "failed", "{backend}: {member}");
    assert!(
        member["reason"].as_str().unwrap().contains("stalled"),
        "{backend}: {member}"
    );
    let attempts =
        member["steps_accepted"].as_u64().unwrap() + member["steps_rejected"].as_u64().unwrap();
    (member, attempts)
}

/// A member whose steps no longer advance it fails as stalled, on both backends at the same
/// attempt and time (kernels/src/shared/control.rs and its WGSL twin): a forcing that
/// oscillates with period 0.06 holds order 2's steps near 3e-4, which would take ~3e14 steps
/// to reach t = 1e11 and ~3e11 to reach 1e8 (paces of ~3e-15 and ~3e-12 of the time left an
/// attempt); after 100000 attempts (`STALL_WINDOW`) at a pace below 1e-10
/// (`STALL_PACE_ADAPTIVE`) it fails, where it ran for ever (towards 1e8 also at the limit of
/// 1e-12 that adaptive steps had until 2026-11-30, which fixed steps keep).
#[test]
fn a_member_whose_steps_no_longer_advance_it_fails_as_stalled() {
    use roughlub::backend::shared::control::STALL_WINDOW;
    let tmp = tempfile::tempdir().unwrap();
    for end in ["1e11", "1e8"] {
        let scene = tmp.path().join("stall.toml");
        std::fs::write(
            &scene,
            r#"
name = "stall"
[model]
particles = 4
mu = 0.1
forcing = "0.5*sin(2*pi*x)*cos(100*t)"
[initial]
rho = "0.7"
rho_star = "0.7"
[time]
end = 1e11
outputs = 2
tolerance = 1e-6
[solver]
order = 2
[output]
plots = false
"#
            .replace("end = 1e11", &format!("end = {end}")),
        )
        .unwrap();
        let stalled = |backend: &str| {
            let out_dir = tmp.path().join(format!("{backend}_{end}"));
            let (member, attempts) = stalled_member(&scene, &out_dir, backend);
            let reason = member["reason"].as_str().unwrap();
            assert!(
                reason.contains(&format!("its last {STALL_WINDOW} attempts")),
                "{backend}: {reason}"
            );
            let time = member["time"].as_f64().unwrap();
            // It failed in its first window of attempts, long before the end.
            assert_eq!(attempts, u64::from(STALL_WINDOW) - 1, "{backend}: {member}");
            assert!(time > 1.0 && time < 1e3, "{backend}: {time}");
            (attempts, time)
        };
        let (cpu_attempts, cpu_time) = stalled("cpu");
        if have_gpu(
            true,
            "a_member_whose_steps_no_longer_advance_it_fails_as_stalled",
        ) {
            let (gpu_attempts, gpu_time) = stalled("gpu");
            assert_eq!(gpu_attempts, cpu_attempts);
            assert!(
                (gpu_time - cpu_time).abs() <= 1e-12 * cpu_time,
                "{end}: {gpu_time} {cpu_time}"
            );
        }
    }
}

/// An f32 member held by rounding at a pace of ~1e-12 of the time left an attempt (the limit
/// of fixed steps) ran for hours on the CPU (gamma = 1000, mu = 1e-8, found 2026-11-30; f64
/// fails it at once as a step-size collapse, and so does the GPU's f32 kernel). Adaptive steps
/// fail from a pace of 1e-10: it fails as stalled within a few windows of attempts.
#[test]
fn an_f32_member_held_by_rounding_fails_as_stalled() {
    use roughlub::backend::shared::control::STALL_WINDOW;
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("held.toml");
    std::fs::write(
        &scene,
        r#"
name = "held"
[model]
particles = 50
mu = 1e-08
gamma = 1000.0
[initial]
rho = "0.5+0.49*sin(pi*x)"
velocity = "2*sin(2*pi*x)"
rho_star = "0.999"
[time]
end = 0.5
outputs = 11
tolerance = 3e-5
[solver]
precision = "f32"
[output]
grid = 50
plots = false
"#,
    )
    .unwrap();
    let (member, attempts) = stalled_member(&scene, &tmp.path().join("cpu"), "cpu");
    assert!(
        attempts < 5 * u64::from(STALL_WINDOW),
        "{attempts} attempts: {member}"
    );
    assert!(member["time"].as_f64().unwrap() < 0.1, "{member}");
}
