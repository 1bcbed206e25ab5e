//! `roughlub merge` refuses what would give a wrong or misleading result: missing shards (unless
//! `--allow-partial`, which then names the missing members) and an `--out` that is one of its
//! inputs.

mod common;

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
    assert_succeeded(&out);
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

/// `manifest.json` of a run or merge directory.
fn manifest(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("manifest.json")).unwrap()).unwrap()
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
    let m = manifest(&merged);
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
    let before = std::fs::read(dirs[1].join("partial.state")).unwrap();
    let refs: Vec<&Path> = dirs.iter().map(|d| d.as_path()).collect();
    let out = merge(&refs, &dirs[1], &[]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("merge --out") && err.contains("one of the shards"),
        "{err}"
    );
    assert_eq!(
        std::fs::read(dirs[1].join("partial.state")).unwrap(),
        before
    );
    assert!(
        dirs[1].join("manifest.json").exists(),
        "the shard's own manifest was removed"
    );
}

/// A merge records the shards' error estimate (issue 22, item 3: every run carries one): their
/// method, and the largest of their members' estimates, which must be the largest the shards'
/// own manifests record (study_basic is order 1 with fixed steps: the companion's estimate); a
/// merge of that merge records the same.
#[test]
fn merge_records_the_largest_error_estimate_of_its_shards() {
    let tmp = tempfile::tempdir().unwrap();
    let dirs: Vec<PathBuf> = (0..3).map(|k| tmp.path().join(format!("s{k}"))).collect();
    for (k, d) in dirs.iter().enumerate() {
        shard(d, k as u64);
    }
    let shards: Vec<serde_json::Value> = dirs.iter().map(|d| manifest(d)).collect();
    let expected = shards
        .iter()
        .map(|m| m["error_estimate"]["largest"].as_f64().unwrap())
        .fold(f64::NEG_INFINITY, f64::max);
    assert!(expected > 0.0 && expected.is_finite(), "{expected}");
    let refs: Vec<&Path> = dirs.iter().map(|d| d.as_path()).collect();
    let merged = tmp.path().join("m");
    assert_succeeded(&merge(&refs, &merged, &[]));
    let again = tmp.path().join("m2");
    let out = merge(&[merged.as_path()], &again, &[]);
    assert_succeeded(&out);
    assert!(
        String::from_utf8_lossy(&out.stderr)
            .contains(&format!("largest error estimate {expected:.2e}")),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for dir in [&merged, &again] {
        let m = manifest(dir);
        assert_eq!(
            m["error_estimate"]["largest"].as_f64(),
            Some(expected),
            "{dir:?}"
        );
        assert_eq!(
            m["error_estimate"]["method"], shards[0]["error_estimate"]["method"],
            "{dir:?}"
        );
        assert_eq!(m["jacobian"], shards[0]["jacobian"], "{dir:?}");
        assert_eq!(m["sequence"], shards[0]["sequence"], "{dir:?}");
    }
    // Where each shard ran, as its manifest says: the adapter and the backend asked for.
    let ran = manifest(&merged)["shard_backends"].clone();
    assert_eq!(ran.as_array().map(Vec::len), Some(3), "{ran}");
    // A merge of that merge passes on the same shards.
    assert_eq!(manifest(&again)["shard_backends"], ran);
    for (k, shard) in shards.iter().enumerate() {
        assert_eq!(ran[k]["adapter"], shard["adapter"], "{ran}");
        assert_eq!(ran[k]["backend_requested"], shard["backend_requested"]);
        assert_eq!(ran[k]["member_range"], shard["member_range"]);
        assert!(!shard["adapter"].is_null(), "{shard}");
    }
}

/// Runs `scene_text` (written into `dir`'s parent as scene.toml) into `dir` with `extra` args.
fn run_text(scene_path: &Path, dir: &Path, extra: &[&str]) -> Output {
    let mut args: Vec<&std::ffi::OsStr> = vec![
        "run".as_ref(),
        scene_path.as_os_str(),
        "--out".as_ref(),
        dir.as_os_str(),
        "--quiet".as_ref(),
    ];
    args.extend(extra.iter().map(|s| std::ffi::OsStr::new(*s)));
    roughlub(&args)
}

/// Fails with the command's stderr unless it succeeded.
fn assert_succeeded(out: &Output) {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Shard `k` of 2 of `scene` into `dir`, which it returns; the run must succeed.
fn shard_of_two(scene: &Path, dir: &Path, k: u64) -> PathBuf {
    let out = run_text(scene, dir, &["--shard", &format!("{k}/2")]);
    assert_succeeded(&out);
    dir.to_path_buf()
}

const FILE_ROUGHNESS_SCENE: &str = "name = \"fr\"\n[model]\nparticles = 8\nmu = 0.01\ngamma = 2.0\n\
[initial]\nrho = \"0.7\"\nvelocity = \"0.5*sin(2*pi*x)\"\n[time]\nend = 0.01\noutputs = 2\ndt = 1e-3\n\
[solver]\nbackend = \"cpu\"\n[output]\ngrid = 10\nplots = false\n\
[ensemble]\nmembers = 8\nchunk = 4\nseed = SEED\nroughness = { kind = \"file\", path = \"radii.csv\" }\n";

/// A changed roughness file is a different study (issue 9, item 3): `--resume` refuses it and
/// names the files; the header records every file read with its hash.
#[test]
fn resume_refuses_a_changed_roughness_file() {
    let tmp = tempfile::tempdir().unwrap();
    let radii = |r: f64| format!("r\n{}", format!("{r}\n").repeat(9));
    std::fs::write(tmp.path().join("radii.csv"), radii(0.001)).unwrap();
    let scene = tmp.path().join("scene.toml");
    std::fs::write(&scene, FILE_ROUGHNESS_SCENE.replace("SEED", "7")).unwrap();
    let dir = tmp.path().join("study");
    let out = run_text(&scene, &dir, &[]);
    assert_succeeded(&out);
    let header: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("study.json")).unwrap()).unwrap();
    let files = header["input_files"].as_object().unwrap();
    assert_eq!(files.len(), 1);
    assert!(files.keys().next().unwrap().ends_with("radii.csv"));

    // The same file: resume is accepted.
    let out = run_text(&scene, &dir, &["--resume"]);
    assert_succeeded(&out);
    // Another radius: refused, naming what differs.
    std::fs::write(tmp.path().join("radii.csv"), radii(0.002)).unwrap();
    let out = run_text(&scene, &dir, &["--resume"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("files it reads differ"), "{err}");
}

/// A directory whose `partial.state` belongs to an earlier study than its `study.json` (a later
/// run into it was killed) is refused by merge (issue 9, item 4).
#[test]
fn merge_refuses_a_stale_partial() {
    let tmp = tempfile::tempdir().unwrap();
    std::fs::write(
        tmp.path().join("radii.csv"),
        format!("r\n{}", "0.001\n".repeat(9)),
    )
    .unwrap();
    let (s7, s8) = (tmp.path().join("seed7.toml"), tmp.path().join("seed8.toml"));
    std::fs::write(&s7, FILE_ROUGHNESS_SCENE.replace("SEED", "7")).unwrap();
    std::fs::write(&s8, FILE_ROUGHNESS_SCENE.replace("SEED", "8")).unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    assert_succeeded(&run_text(&s7, &a, &[]));
    assert_succeeded(&run_text(&s8, &b, &[]));
    // What a killed seed-8 run into `a` leaves: its study.json beside seed 7's statistics.
    std::fs::copy(b.join("study.json"), a.join("study.json")).unwrap();
    let out = merge(&[&a], &tmp.path().join("m"), &[]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("partial.state") && err.contains("out of date"),
        "{err}"
    );
    assert!(err.contains("scene text"), "{err}");
}

/// A merge replaces its --out whole: a directory of someone's files is refused (and kept) unless
/// --force; an earlier merge there is replaced, with nothing of it left beside the new one.
#[test]
fn merge_output_is_replaced_whole_and_foreign_files_need_force() {
    let tmp = tempfile::tempdir().unwrap();
    let shards: Vec<PathBuf> = (0..3).map(|k| tmp.path().join(format!("s{k}"))).collect();
    for (k, dir) in shards.iter().enumerate() {
        shard(dir, k as u64);
    }
    let inputs: Vec<&Path> = shards.iter().map(|p| p.as_path()).collect();
    let merged = tmp.path().join("m");
    std::fs::create_dir_all(&merged).unwrap();
    std::fs::write(merged.join("notes.txt"), "mine").unwrap();

    let out = merge(&inputs, &merged, &[]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("--force"), "{err}");
    assert_eq!(
        std::fs::read_to_string(merged.join("notes.txt")).unwrap(),
        "mine"
    );
    assert!(!merged.join("manifest.json").exists());

    let out = merge(&inputs, &merged, &["--force"]);
    assert_succeeded(&out);
    assert!(
        !merged.join("notes.txt").exists(),
        "a foreign file stayed beside the merge"
    );
    // A second merge (of two shards) replaces the first whole.
    std::fs::write(merged.join("stats").join("extra.npy"), b"x").unwrap();
    let out = merge(&inputs[..2], &merged, &["--allow-partial"]);
    assert_succeeded(&out);
    assert!(!merged.join("stats").join("extra.npy").exists());
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(merged.join("manifest.json")).unwrap())
            .unwrap();
    assert_eq!(m["members_covered"], 64, "{m}");
    let leftovers = common::names_starting_with(tmp.path(), ".");
    assert!(
        leftovers.is_empty(),
        "staging directories left: {leftovers:?}"
    );
}

/// Shards computed with two versions of the roughness file are two studies: merge refuses them
/// and names the files (issue 9, item 3); the same two shards from one file merge.
#[test]
fn merge_refuses_shards_from_two_roughness_files() {
    let tmp = tempfile::tempdir().unwrap();
    let radii = |r: f64| format!("r\n{}", format!("{r}\n").repeat(9));
    let scene = tmp.path().join("scene.toml");
    std::fs::write(&scene, FILE_ROUGHNESS_SCENE.replace("SEED", "7")).unwrap();
    let shard_with = |k: u64, r: f64, name: &str| {
        std::fs::write(tmp.path().join("radii.csv"), radii(r)).unwrap();
        shard_of_two(&scene, &tmp.path().join(name), k)
    };
    let a = shard_with(0, 0.001, "a0");
    let b_same = shard_with(1, 0.001, "a1");
    let b_other = shard_with(1, 0.002, "b1");

    let out = merge(&[&a, &b_other], &tmp.path().join("mixed"), &[]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("files it reads"), "{err}");
    assert!(!tmp.path().join("mixed").exists());

    let out = merge(&[&a, &b_same], &tmp.path().join("same"), &[]);
    assert_succeeded(&out);
}

/// A state file whose bands do not match its study (a field's band renamed in one point, as an
/// edited file might have it) is refused with an error naming the file and what is
/// wrong, exit status 2, nothing written; the report used to look the band up and panic.
#[test]
fn merge_refuses_a_state_whose_bands_do_not_match_its_study() {
    let tmp = tempfile::tempdir().unwrap();
    let a = tmp.path().join("s0");
    shard(&a, 0);
    let state = a.join("partial.state");
    let mut bytes = std::fs::read(&state).unwrap();
    // The last "rho" key is a band field's name in the last detailed point's map of bands
    // (the header, written first, names the fields before any point does).
    let at = bytes
        .windows(4)
        .rposition(|w| w == b"\x63rho")
        .expect("a band of rho");
    bytes[at + 3] = b'x';
    // An edit made with the checksum recomputed (a damaged file is refused before: its
    // checksum; see tests/study_scale.rs), so that the study's own consistency check is what
    // refuses it.
    let end = bytes.len() - 4;
    let crc = crc32fast::hash(&bytes[12..end]);
    bytes[end..].copy_from_slice(&crc.to_le_bytes());
    std::fs::write(&state, &bytes).unwrap();
    let merged = tmp.path().join("m");
    let out = merge(&[&a], &merged, &["--allow-partial"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("partial.state") && err.contains("inconsistent study state"),
        "{err}"
    );
    assert!(err.contains("rho"), "the message names the field: {err}");
    assert!(!merged.exists(), "a refused merge wrote {merged:?}");
}

/// Shards whose detailed points differ (an earlier build's default, or an edited setting) are
/// not one study: merge refuses them and names the detailed points among what differs.
#[test]
fn merge_refuses_shards_whose_detailed_points_differ() {
    let tmp = tempfile::tempdir().unwrap();
    let text = "name = \"dp\"\n[model]\nparticles = 8\nmu = 0.01\ngamma = 2.0\n\
[initial]\nrho = \"0.7\"\nrho_star = \"0.7\"\nvelocity = \"0.5*sin(2*pi*x)\"\n[time]\nend = 0.01\noutputs = 2\ndt = 1e-3\n\
[solver]\nbackend = \"cpu\"\n[output]\ngrid = 10\nplots = false\n\
[ensemble]\nmembers = 8\nchunk = 4\nseed = 3\nroughness = { kind = \"lognormal\", spread = 0.3 }\n";
    let shard_of = |k: u64, scene_text: &str, name: &str| {
        let scene = tmp.path().join(format!("{name}.toml"));
        std::fs::write(&scene, scene_text).unwrap();
        shard_of_two(&scene, &tmp.path().join(name), k)
    };
    // Without a sweep the one point is detailed by default; the second shard keeps none.
    let a = shard_of(0, text, "a0");
    let b = shard_of(1, &format!("{text}detailed_points = 0\n"), "b1");
    let out = merge(&[&a, &b], &tmp.path().join("mixed"), &[]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("detailed points"), "{err}");
    assert!(!tmp.path().join("mixed").exists());
}

/// A shard without its manifest (written last) is not a complete study: an interrupted run's
/// directory or its staging directory, whose statistics may be a checkpoint's. Merge refuses it,
/// naming the directory (until 2026-11-30 it merged it and called the result complete).
#[test]
fn merge_refuses_a_shard_without_its_manifest() {
    let tmp = tempfile::tempdir().unwrap();
    let dirs: Vec<PathBuf> = (0..3).map(|k| tmp.path().join(format!("s{k}"))).collect();
    for (k, dir) in dirs.iter().enumerate() {
        shard(dir, k as u64);
    }
    std::fs::remove_file(dirs[1].join("manifest.json")).unwrap();
    let merged = tmp.path().join("m");
    let out = merge(&[&dirs[0], &dirs[1], &dirs[2]], &merged, &[]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("s1") && err.contains("no manifest.json") && err.contains("--resume"),
        "{err}"
    );
    assert!(!merged.exists(), "a refused merge wrote {merged:?}");
}
