//! `roughlub converge`: the paper's case 1 at N = 100..1600 (rates stable and reported at the
//! largest pair; the extrapolated limit closer to N = 6400 than N = 1600 is), a scene that does
//! not move (differences at rounding for every N), few N (no rate, no verdict), and bad input
//! (exit status 2, a message naming `--particles` or the scene key, nothing written).
//!
//! Every study runs on the CPU (case 1 at N = 1600 to t = 0.4 takes well under a second there).

use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::Value;

const BIN: &str = env!("CARGO_BIN_EXE_roughlub");

fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(path)
}

/// `roughlub converge SCENE --particles LIST --out OUT --backend cpu --quiet`.
fn converge(scene: &Path, particles: &str, out: &Path) -> Output {
    Command::new(BIN)
        .arg("converge")
        .arg(scene)
        .args(["--particles", particles, "--backend", "cpu", "--quiet"])
        .arg("--out")
        .arg(out)
        .output()
        .unwrap_or_else(|e| panic!("cannot start {BIN}: {e}"))
}

fn stderr_of(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[track_caller]
fn assert_success(out: &Output) {
    assert_eq!(
        out.status.code(),
        Some(0),
        "roughlub converge failed; stderr:\n{}",
        stderr_of(out)
    );
}

/// An .npy file: shape and values in C order.
fn read_npy(path: &Path) -> (Vec<u64>, Vec<f64>) {
    let file = File::open(path).unwrap_or_else(|e| panic!("cannot open {path:?}: {e}"));
    let npy = npyz::NpyFile::new(file).unwrap_or_else(|e| panic!("{path:?} is not an .npy: {e}"));
    let shape = npy.shape().to_vec();
    let values = npy.into_vec::<f64>().unwrap();
    assert_eq!(values.len() as u64, shape.iter().product::<u64>());
    (shape, values)
}

fn read_manifest(dir: &Path) -> Value {
    let text = std::fs::read_to_string(dir.join("manifest.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

/// The rows of convergence.csv as (header → value) maps.
fn read_csv(dir: &Path) -> Vec<std::collections::HashMap<String, String>> {
    let mut reader = csv::Reader::from_path(dir.join("convergence.csv")).unwrap();
    let headers = reader.headers().unwrap().clone();
    reader
        .records()
        .map(|r| {
            let r = r.unwrap();
            headers
                .iter()
                .map(String::from)
                .zip(r.iter().map(String::from))
                .collect()
        })
        .collect()
}

fn num(text: &str) -> f64 {
    text.parse()
        .unwrap_or_else(|_| panic!("not a number: {text:?}"))
}

fn mean_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum::<f64>() / a.len() as f64
}

/// The test on case 1 (smooth): every observed L1 rate of rho between successive N from
/// 100 to 1600 lies within 0.15 of the rate the study reports at the largest pair (at every
/// output time), the study calls itself asymptotic, and the extrapolated limit is closer (L1)
/// to a run at 4 × 1600 = 6400 than the N = 1600 run is, for rho and u at every output time
/// where they change with N. The N = 6400 fields are taken from a second study (1600, 6400)
/// so that they are sampled the same way.
#[test]
fn case1_rates_are_stable_and_the_limit_is_closer_to_4n_than_the_largest_n() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = repo("scenes/case1.toml");
    let study = tmp.path().join("study");
    let out = converge(&scene, "100,200,400,800,1600", &study);
    assert_success(&out);
    let m = read_manifest(&study);
    assert_eq!(m["kind"], "convergence");
    assert_eq!(
        m["particles"],
        serde_json::json!([100, 200, 400, 800, 1600])
    );
    assert_eq!(m["ratios_equal"], true);
    assert_eq!(m["asymptotic"], true, "stderr:\n{}", stderr_of(&out));
    // Each N's run records what it ran: case 1 is order auto, adaptive, in f64, so the tableau's
    // default sequence there, from_2.
    for run in m["runs"].as_array().unwrap() {
        assert_eq!(run["plan"]["sequence"], "from_2", "{run}");
    }

    let rho = m["fields"]
        .as_array()
        .unwrap()
        .iter()
        .find(|f| f["field"] == "rho")
        .unwrap();
    let reported = rho["rate"].as_f64().unwrap();
    // Measured: 2.000 (the particle system's fields converge like N^-2 on case 1).
    assert!(
        (1.5..2.5).contains(&reported),
        "rate at the largest pair {reported}"
    );

    let rows = read_csv(&study);
    let times: Vec<String> = {
        let mut t: Vec<String> = rows
            .iter()
            .filter(|r| r["field"] == "rho")
            .map(|r| r["time"].clone())
            .collect();
        t.dedup();
        t
    };
    assert_eq!(times.len(), 9);
    let mut checked = 0;
    for t in &times {
        let here: Vec<_> = rows
            .iter()
            .filter(|r| r["field"] == "rho" && &r["time"] == t)
            .collect();
        assert_eq!(here.len(), 4, "4 successive pairs at t = {t}");
        if here[0]["verdict"] == "exact" {
            // t = 0: rho0 = 0.7 is constant, every N samples it exactly.
            continue;
        }
        let rates: Vec<f64> = here[1..].iter().map(|r| num(&r["rate_l1"])).collect();
        let last = *rates.last().unwrap();
        for (k, p) in rates.iter().enumerate() {
            assert!(
                (p - last).abs() <= 0.15,
                "t = {t}: rate {p} of pair {k} is not within 0.15 of the largest pair's {last}"
            );
        }
        if t == times.last().unwrap() {
            assert_eq!(
                last, reported,
                "CSV and manifest disagree on the reported rate"
            );
        }
        checked += 1;
    }
    assert_eq!(checked, 8, "every output time after t = 0 checked");

    // The reference at 4 × the largest N.
    let reference = tmp.path().join("reference");
    assert_success(&converge(&scene, "1600,6400", &reference));
    for field in ["rho", "u"] {
        let (shape, fields) = read_npy(&study.join(format!("fields_{field}.npy")));
        assert_eq!(shape, vec![5, 9, 400]);
        let (lshape, limit) = read_npy(&study.join(format!("limit_{field}.npy")));
        assert_eq!(lshape, vec![9, 400]);
        let (rshape, ref_fields) = read_npy(&reference.join(format!("fields_{field}.npy")));
        assert_eq!(rshape, vec![2, 9, 400]);
        let g = 400;
        let per_time = &m["per_time"][field];
        for t in 0..9 {
            let verdict = per_time[t]["verdict"].as_str().unwrap();
            if verdict != "asymptotic" {
                continue; // exact or rounding-limited at t = 0
            }
            let largest = &fields[(4 * 9 + t) * g..(4 * 9 + t + 1) * g];
            let lim = &limit[t * g..(t + 1) * g];
            let six400 = &ref_fields[(9 + t) * g..(9 + t + 1) * g];
            let (err_lim, err_largest) =
                (mean_abs_diff(lim, six400), mean_abs_diff(largest, six400));
            assert!(
                err_lim < err_largest,
                "{field} at t index {t}: the limit is {err_lim:e} from N = 6400, N = 1600 is {err_largest:e}"
            );
            // Measured: about 15 times closer; half is a loose bound that still fails when the
            // extrapolation only shuffles noise.
            assert!(
                err_lim < 0.5 * err_largest,
                "{field} at t index {t}: the limit ({err_lim:e}) gains little over N = 1600 ({err_largest:e})"
            );
            // The estimate |f_inf - f_K| is of the size of the error of f_K.
            let est = per_time[t]["limit_error_l1"].as_f64().unwrap();
            assert!(
                est > 0.5 * err_largest && est < 2.0 * err_largest,
                "{field} at t index {t}: estimate {est:e}, actual error of N = 1600 about {err_largest:e}"
            );
        }
    }

    for f in ["rho", "u", "rho_star"] {
        for kind in ["profiles", "rate"] {
            let png = study.join("plots").join(format!("{f}_{kind}.png"));
            assert!(png.metadata().is_ok_and(|m| m.len() > 1000), "{png:?}");
        }
    }
    for f in [
        "particles.npy",
        "times.npy",
        "x.npy",
        "fields_rho_star.npy",
        "limit_rho_star.npy",
    ] {
        assert!(study.join(f).exists(), "{f}");
    }
}

/// rho0 = rho*0 constant, u0 = 0, f = 0: nothing moves in the particle system or in the limit,
/// so every difference is zero to rounding at every N and time, the verdict is "exact" and the
/// limit is the field.
#[test]
fn a_scene_at_rest_gives_differences_at_rounding() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("rest.toml");
    std::fs::write(
        &scene,
        "name = \"rest\"\n[model]\nparticles = 10\nmu = 0.01\ngamma = 2\n\
         [initial]\nrho = \"0.6\"\nvelocity = \"0\"\nrho_star = \"0.6\"\n\
         [time]\nend = 0.1\noutputs = 3\ndt = 1e-2\n[output]\ngrid = 50\nplots = false\n",
    )
    .unwrap();
    let study = tmp.path().join("study");
    assert_success(&converge(&scene, "20,40,80,160", &study));
    let m = read_manifest(&study);
    assert_eq!(m["asymptotic"], true);
    for row in read_csv(&study) {
        for norm in ["diff_l1", "diff_l2", "diff_linf"] {
            let e = num(&row[norm]);
            assert!(
                e < 1e-12,
                "{} at t = {}: {norm} = {e:e}",
                row["field"],
                row["time"]
            );
        }
        assert_eq!(row["verdict"], "exact", "{row:?}");
    }
    let (_, limit) = read_npy(&study.join("limit_rho.npy"));
    assert!(limit.iter().all(|v| (v - 0.6).abs() < 1e-12));
    assert!(!study.join("plots").exists(), "plots = false");
}

/// Three N give one rate: the verdict is "too_few_rates" and the study does not call itself
/// asymptotic (a warning says so); unequal ratios are recorded. Two N give differences only: no
/// rate and no limit files.
#[test]
fn few_particle_numbers_give_no_verdict() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = repo("scenes/case1.toml");
    let three = tmp.path().join("three");
    let out = converge(&scene, "50,100,300", &three);
    assert_success(&out);
    let m = read_manifest(&three);
    assert_eq!(m["asymptotic"], false);
    assert_eq!(m["ratios_equal"], false);
    assert!(
        stderr_of(&out).contains("warning: rho: the observed L1 rate is not asymptotic"),
        "{}",
        stderr_of(&out)
    );
    let rho_rows: Vec<_> = read_csv(&three)
        .into_iter()
        .filter(|r| r["field"] == "rho" && r["time"] == "0.4")
        .collect();
    assert_eq!(rho_rows.len(), 2);
    assert_eq!(rho_rows[0]["rate_l1"], "");
    assert!(num(&rho_rows[1]["rate_l1"]).is_finite());
    assert_eq!(rho_rows[1]["verdict"], "too_few_rates");
    assert_eq!(rho_rows[1]["asymptotic"], "false");

    let two = tmp.path().join("two");
    assert_success(&converge(&scene, "50,100", &two));
    assert!(two.join("fields_rho.npy").exists());
    assert!(!two.join("limit_rho.npy").exists());
    assert_eq!(read_manifest(&two)["asymptotic"], false);
}

/// Bad `--particles` lists and scenes that cannot be rebuilt at each N: exit status 2, a message
/// naming the option (and the allowed range) or the scene key, and no output directory.
#[test]
fn bad_input_is_refused_before_anything_is_written() {
    let tmp = tempfile::tempdir().unwrap();
    let case1 = repo("scenes/case1.toml");
    let cases: Vec<(PathBuf, &str, &[&str])> = vec![
        (
            case1.clone(),
            "100,400,200",
            &[
                "--particles",
                "200 after 400 is not increasing",
                "2 ..= 100000000",
            ],
        ),
        (
            case1.clone(),
            "100,100,200",
            &["--particles", "not increasing"],
        ),
        (
            case1.clone(),
            "100",
            &["--particles", "at least 2", "2 ..= 100000000"],
        ),
        (
            case1.clone(),
            "1,2,4",
            &["--particles", "N = 1 is outside", "2 ..= 100000000"],
        ),
        (
            case1.clone(),
            "100,200,200000000",
            &["--particles", "N = 200000000", "2 ..= 100000000"],
        ),
        (
            repo("tests/data/validation_base_file.toml"),
            "100,200,400",
            &["initial.particles", "particle file"],
        ),
        (
            repo("scenes/rho_star_spread.toml"),
            "100,200,400",
            &["ensemble", "one member per N"],
        ),
    ];
    for (i, (scene, particles, expected)) in cases.iter().enumerate() {
        let dir = tmp.path().join(format!("out{i}"));
        let out = converge(scene, particles, &dir);
        let err = stderr_of(&out);
        assert_eq!(out.status.code(), Some(2), "--particles {particles}: {err}");
        assert!(err.starts_with("error: "), "{err}");
        for e in *expected {
            assert!(
                err.contains(e),
                "--particles {particles}: {err:?} lacks {e:?}"
            );
        }
        assert!(
            !dir.exists(),
            "--particles {particles}: {dir:?} was written"
        );
    }
    // Not a number: clap's own message, also exit 2.
    let out = converge(&case1, "100,abc", &tmp.path().join("nan"));
    assert_eq!(out.status.code(), Some(2));
    assert!(
        stderr_of(&out).contains("--particles"),
        "{}",
        stderr_of(&out)
    );
    // Nothing was left beside the outputs either.
    assert_eq!(std::fs::read_dir(tmp.path()).unwrap().count(), 0);
}
