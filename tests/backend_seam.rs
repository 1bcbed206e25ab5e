//! The one backend seam, seen from the CLI: runs and studies choose the backend through the same
//! policy, record the same fields, and a study refuses to mix backends or precisions on
//! `--resume` and `merge`. GPU cases go through lavapipe in CI (ROUGHLUB_REQUIRE_GPU=1) and are
//! skipped without an adapter otherwise.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_roughlub");

fn study_scene() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/study_basic.toml")
}

fn run(args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut cmd = Command::new(BIN);
    cmd.args(args);
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.output().expect("roughlub runs")
}

fn read_json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn manifest(dir: &Path) -> serde_json::Value {
    read_json(&dir.join("manifest.json"))
}

/// `roughlub run SCENE --out DIR --quiet [extra...]`.
fn run_scene(scene: &Path, dir: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "run",
        scene.to_str().unwrap(),
        "--out",
        dir.to_str().unwrap(),
        "--quiet",
    ];
    args.extend_from_slice(extra);
    run(&args, &[])
}

fn study(dir: &Path, extra: &[&str]) -> Output {
    run_scene(&study_scene(), dir, extra)
}

/// A study's manifest records the backend fields of a single run; with `auto` and no usable
/// adapter (none matches WGPU_ADAPTER_NAME) it falls back to the CPU and records why, as runs do.
#[test]
fn study_records_backend_and_auto_falls_back_like_a_run() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s");
    let scene = study_scene();
    let out = run(
        &[
            "run",
            scene.to_str().unwrap(),
            "--out",
            dir.to_str().unwrap(),
            "--quiet",
            "--backend",
            "auto",
        ],
        &[("WGPU_ADAPTER_NAME", "no-such-adapter-anywhere")],
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let m = manifest(&dir);
    assert_eq!(m["backend"], "cpu", "{m}");
    assert_eq!(m["backend_requested"], "auto");
    assert_eq!(m["precision"], "f64");
    assert_eq!(m["adapter"]["backend"], "cpu");
    let why = m["adapter"]["fallback_reason"].as_str().unwrap_or("");
    assert!(why.contains("no GPU adapter"), "fallback_reason: {why:?}");
    let header: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("study.json")).unwrap()).unwrap();
    assert_eq!(
        (header["backend"].as_str(), header["precision"].as_str()),
        (Some("cpu"), Some("f64"))
    );
}

/// `--resume` of a CPU f64 study on the GPU in f32 (or f64) is refused, naming what differs, and
/// writes no manifest.
#[test]
fn resume_on_another_backend_or_precision_is_refused() {
    if common::gpu::acquire_for_tests(false).is_none() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s");
    assert!(study(&dir, &[]).status.success());
    std::fs::remove_file(dir.join("manifest.json")).unwrap();
    let out = study(
        &dir,
        &["--resume", "--backend", "gpu", "--precision", "f32"],
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("backend") && err.contains("precision") && err.contains("differ"),
        "{err}"
    );
    assert!(!dir.join("manifest.json").exists());
}

/// The study scene with auto at tolerance 1e-4 (auto's sequence then depends on the precision)
/// and 4 members, written into `dir`; with `ensemble` false, no `[ensemble]`: a single run.
fn auto_scene(dir: &Path, ensemble: bool, solver_extra: &str) -> PathBuf {
    let text = std::fs::read_to_string(study_scene()).unwrap();
    let mut text = text
        .replace("dt = 1e-3", "tolerance = 1e-4")
        .replace("order = 1", &format!("order = \"auto\"\n{solver_extra}"))
        .replace("members = 96", "members = 4")
        .replace("chunk = 16", "chunk = 4");
    if !ensemble {
        text.truncate(text.find("[ensemble]").unwrap());
    }
    let path = dir.join(if ensemble { "study.toml" } else { "run.toml" });
    std::fs::write(&path, text).unwrap();
    path
}

/// The tableau's rows that ran are recorded where a result is: `[solver] sequence`'s default
/// (auto) is from_2 for order auto with adaptive steps in f64 and from_1 in f32, in a run's
/// manifest (`plan.sequence`) and a study's (`sequence`, and its `study.json`); a scene that
/// names one runs it.
#[test]
fn the_sequence_that_ran_is_recorded_for_runs_and_studies() {
    let tmp = tempfile::tempdir().unwrap();
    let cases: [(&str, &[&str], &str); 5] = [
        ("", &[], "from_2"),
        ("", &["--precision", "f32"], "from_1"),
        ("sequence = \"auto\"", &[], "from_2"),
        ("sequence = \"from_1\"", &[], "from_1"),
        ("sequence = \"from_2\"", &["--precision", "f32"], "from_2"),
    ];
    for (k, (extra, args, expected)) in cases.iter().enumerate() {
        for ensemble in [false, true] {
            let case = tmp.path().join(format!("case{k}_{ensemble}"));
            std::fs::create_dir(&case).unwrap();
            let scene = auto_scene(&case, ensemble, extra);
            let out_dir = case.join("out");
            let out = run_scene(&scene, &out_dir, args);
            assert!(
                out.status.success(),
                "{extra} {args:?}: {}",
                String::from_utf8_lossy(&out.stderr)
            );
            let m = manifest(&out_dir);
            if ensemble {
                assert_eq!(m["sequence"], *expected, "study, {extra} {args:?}");
                let header = read_json(&out_dir.join("study.json"));
                assert_eq!(
                    header["sequence"], *expected,
                    "study.json, {extra} {args:?}"
                );
            } else {
                assert_eq!(m["plan"]["sequence"], *expected, "run, {extra} {args:?}");
            }
        }
    }
}

/// `--resume` refuses members computed with other tableau rows (the default sequence changed
/// within one version), naming both; a header written before the field existed counts as
/// from_1, which an order-1 study still runs, so it resumes.
#[test]
fn resume_with_another_tableau_sequence_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    // Order auto in f64: from_2; the header edited as if from_1 had run.
    let scene = auto_scene(tmp.path(), true, "");
    let dir = tmp.path().join("auto");
    assert!(run_scene(&scene, &dir, &[]).status.success());
    let header_path = dir.join("study.json");
    let mut header = read_json(&header_path);
    assert_eq!(header["sequence"], "from_2", "{header}");
    header["sequence"] = "from_1".into();
    std::fs::write(&header_path, serde_json::to_string(&header).unwrap()).unwrap();
    std::fs::remove_file(dir.join("manifest.json")).unwrap();
    let out = run_scene(&scene, &dir, &["--resume"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("tableau sequence")
            && err.contains("in f64 with sequence from_1; this run: ")
            && err.contains("in f64 with sequence from_2)")
            && !err.contains("Cpu"),
        "{err}"
    );
    assert!(!dir.join("manifest.json").exists());

    // An order-1 study whose header has no sequence (an older version's) resumes.
    let dir = tmp.path().join("order1");
    assert!(study(&dir, &[]).status.success());
    let header_path = dir.join("study.json");
    let mut header = read_json(&header_path);
    assert_eq!(header["sequence"], "from_1", "{header}");
    header.as_object_mut().unwrap().remove("sequence");
    std::fs::write(&header_path, serde_json::to_string(&header).unwrap()).unwrap();
    std::fs::remove_file(dir.join("manifest.json")).unwrap();
    let out = study(&dir, &["--resume"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(manifest(&dir)["sequence"], "from_1");
}

/// Shards computed on different backends are not merged.
#[test]
fn merge_of_shards_from_different_backends_is_refused() {
    if common::gpu::acquire_for_tests(true).is_none() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let (a, b, merged) = (
        tmp.path().join("a"),
        tmp.path().join("b"),
        tmp.path().join("m"),
    );
    assert!(study(&a, &["--shard", "0/2"]).status.success());
    let out = study(&b, &["--shard", "1/2", "--backend", "gpu"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let (ma, mb) = (manifest(&a), manifest(&b));
    assert_eq!(mb["backend"], "gpu");
    assert!(ma["gpu_stats"].is_null(), "a CPU study has gpu_stats: {ma}");
    // The GPU's counters summed over chunks: every accepted step of every member is counted.
    let table = std::fs::read_to_string(b.join("members.csv")).unwrap();
    let mut rows = table.lines();
    let header: Vec<&str> = rows.next().unwrap().split(',').collect();
    let column = header.iter().position(|h| *h == "steps_accepted").unwrap();
    let steps: u64 = rows
        .map(|r| r.split(',').nth(column).unwrap().parse::<u64>().unwrap())
        .sum();
    assert!(steps > 0);
    assert_eq!(
        mb["gpu_stats"]["steps"].as_u64(),
        Some(steps),
        "{}",
        mb["gpu_stats"]
    );
    let out = run(
        &[
            "merge",
            a.to_str().unwrap(),
            b.to_str().unwrap(),
            "--out",
            merged.to_str().unwrap(),
        ],
        &[],
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("backend differ"), "{err}");
    assert!(!merged.exists(), "a refused merge created {merged:?}");
}
