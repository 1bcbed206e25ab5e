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

fn manifest(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("manifest.json")).unwrap()).unwrap()
}

fn study(dir: &Path, extra: &[&str]) -> Output {
    let scene = study_scene();
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

/// `--resume` refuses members computed with other tableau rows (the default sequence changed
/// within one version), naming them; a header written before the field existed counts as
/// from_1, which an order-1 study still runs, so it resumes.
#[test]
fn resume_with_another_tableau_sequence_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("s");
    assert!(study(&dir, &[]).status.success());
    let header_path = dir.join("study.json");
    let header: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&header_path).unwrap()).unwrap();
    assert_eq!(header["sequence"], "from_1", "{header}");
    let with_sequence = |value: Option<&str>| {
        let mut h = header.clone();
        match value {
            Some(v) => h["sequence"] = v.into(),
            None => {
                h.as_object_mut().unwrap().remove("sequence");
            }
        }
        std::fs::write(&header_path, serde_json::to_string(&h).unwrap()).unwrap();
        std::fs::remove_file(dir.join("manifest.json")).unwrap();
        study(&dir, &["--resume"])
    };
    let out = with_sequence(Some("from_2"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("tableau sequence") && err.contains("differ"),
        "{err}"
    );
    assert!(!dir.join("manifest.json").exists());
    // Put back as an older version wrote it: no field at all.
    std::fs::write(dir.join("manifest.json"), "{}").unwrap();
    let out = with_sequence(None);
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
