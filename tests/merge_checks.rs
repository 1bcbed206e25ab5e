//! `roughlub merge` refuses what would give a wrong or misleading result: missing shards (unless
//! `--allow-partial`, which then names the missing members) and an `--out` that is one of its
//! inputs.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_roughlub");

fn scene() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/study_basic.toml")
}

fn roughlub(args: &[&std::ffi::OsStr]) -> Output {
    Command::new(BIN)
        .args(args)
        .output()
        .expect("roughlub runs")
}

/// Shard `k` of 3 of tests/data/study_basic.toml (96 members: 32 per shard).
fn shard(dir: &Path, k: u64) {
    let spec = format!("{k}/3");
    let out = roughlub(&[
        "run".as_ref(),
        scene().as_os_str(),
        "--out".as_ref(),
        dir.as_os_str(),
        "--shard".as_ref(),
        spec.as_ref(),
        "--quiet".as_ref(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

fn merge(inputs: &[&Path], out: &Path, extra: &[&str]) -> Output {
    let mut args: Vec<&std::ffi::OsStr> = vec!["merge".as_ref()];
    args.extend(inputs.iter().map(|p| p.as_os_str()));
    args.push("--out".as_ref());
    args.push(out.as_os_str());
    args.push("--no-plots".as_ref());
    args.extend(extra.iter().map(|s| std::ffi::OsStr::new(*s)));
    roughlub(&args)
}

#[test]
fn a_missing_shard_is_refused_unless_allowed_and_then_named() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, c) = (tmp.path().join("s0"), tmp.path().join("s2"));
    shard(&a, 0);
    shard(&c, 2);
    let merged = tmp.path().join("m");
    let out = merge(&[&a, &c], &merged, &[]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("32..64") && err.contains("--allow-partial"),
        "{err}"
    );
    assert!(!merged.exists(), "a refused merge wrote {merged:?}");

    let out = merge(&[&a, &c], &merged, &["--allow-partial"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("members 32..64 are missing"), "{err}");
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(merged.join("manifest.json")).unwrap())
            .unwrap();
    assert_eq!(m["complete"], false);
    assert_eq!(m["members_covered"], 64);
    assert_eq!(m["missing_member_ranges"], serde_json::json!([[32, 64]]));
}

#[test]
fn out_naming_an_input_is_refused_and_the_input_is_untouched() {
    let tmp = tempfile::tempdir().unwrap();
    let dirs: Vec<PathBuf> = (0..3).map(|k| tmp.path().join(format!("s{k}"))).collect();
    for (k, d) in dirs.iter().enumerate() {
        shard(d, k as u64);
    }
    let before = std::fs::read(dirs[1].join("partial.json")).unwrap();
    let refs: Vec<&Path> = dirs.iter().map(|d| d.as_path()).collect();
    let out = merge(&refs, &dirs[1], &[]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("merge --out") && err.contains("one of the shards"),
        "{err}"
    );
    assert_eq!(std::fs::read(dirs[1].join("partial.json")).unwrap(), before);
    assert!(
        dirs[1].join("manifest.json").exists(),
        "the shard's own manifest was removed"
    );
}
