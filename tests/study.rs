//! End-to-end tests of ensemble studies (`[ensemble]` scenes, `src/study/`) through the
//! `roughlub` command:
//!
//! 1. the statistics written by a study against a direct computation over members rebuilt and
//!    solved here with the library (`scene::members::EnsembleMembers`, `cpu::CpuSolver`);
//! 2. sharding: `--shard k/3` runs merged with `roughlub merge` equal the unsharded study, and
//!    overlapping shards are refused;
//! 3. reproducibility of members.csv across chunk sizes and thread counts;
//! 4. `--resume` after a kill reuses the finished chunks and gives the uninterrupted result, and
//!    refuses a directory of another scene;
//! 5. failed members are counted and listed, never averaged in.
//!
//! Scenes live in `tests/data/study_*.toml`; variants are made here by one textual replacement
//! and written to a temporary directory. Every CLI run uses `--backend cpu`.

mod common;

use std::collections::BTreeMap;
use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use roughlub::backend::BatchSolver;
use roughlub::scene::members::EnsembleMembers;
use roughlub::scene::Scene;
use serde_json::Value;
use {roughlub::backend::cpu::CpuSolver, roughlub::backend::MemberStatus};

const BIN: &str = env!("CARGO_BIN_EXE_roughlub");

/// Scalar observables and fields a study summarises (`study::SCALARS`, `study::FIELDS`).
const SCALARS: [&str; 6] = [
    "max_density",
    "min_gap",
    "energy",
    "dissipation",
    "peak_centre",
    "error_estimate",
];
const FIELDS: [&str; 3] = ["rho", "u", "rho_star"];

// ---------------------------------------------------------------------------------------------
// Helpers.

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests")
        .join("data")
        .join(name)
}

/// The text of `tests/data/<name>` with each `(from, to)` replaced (each `from` must occur once),
/// written to `dir/<file>`.
fn scene_variant(name: &str, replacements: &[(&str, &str)], dir: &Path, file: &str) -> PathBuf {
    let mut text = std::fs::read_to_string(data(name)).unwrap();
    for (from, to) in replacements {
        assert_eq!(
            text.matches(from).count(),
            1,
            "`{from}` should occur exactly once in {name}"
        );
        text = text.replace(from, to);
    }
    let path = dir.join(file);
    std::fs::write(&path, text).unwrap();
    path
}

fn cli(args: &[&std::ffi::OsStr], env: &[(&str, &str)]) -> Output {
    let mut cmd = Command::new(BIN);
    cmd.args(args);
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.output()
        .unwrap_or_else(|e| panic!("cannot start {BIN}: {e}"))
}

/// `roughlub run SCENE --out OUT --backend cpu --quiet [extra...]`.
fn run_with_env(scene: &Path, out: &Path, extra: &[&str], env: &[(&str, &str)]) -> Output {
    let mut args: Vec<&std::ffi::OsStr> = vec![
        "run".as_ref(),
        scene.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
        "--backend".as_ref(),
        "cpu".as_ref(),
        "--quiet".as_ref(),
    ];
    args.extend(extra.iter().map(std::ffi::OsStr::new));
    cli(&args, env)
}

fn run(scene: &Path, out: &Path, extra: &[&str]) -> Output {
    run_with_env(scene, out, extra, &[])
}

/// `roughlub merge DIRS... --out OUT --no-plots`.
fn merge(dirs: &[&Path], out: &Path) -> Output {
    let mut args: Vec<&std::ffi::OsStr> = vec!["merge".as_ref()];
    args.extend(dirs.iter().map(|d| d.as_os_str()));
    args.extend(["--out".as_ref(), out.as_os_str(), "--no-plots".as_ref()]);
    cli(&args, &[])
}

fn stderr_of(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn assert_success(out: &Output, what: &str) {
    assert_eq!(
        out.status.code(),
        Some(0),
        "{what} failed; stderr:\n{}",
        stderr_of(out)
    );
}

/// An .npy file: shape and values in C order.
fn npy(path: &Path) -> (Vec<u64>, Vec<f64>) {
    let file = File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let npy = npyz::NpyFile::new(file).unwrap();
    let shape = npy.shape().to_vec();
    (shape, npy.into_vec::<f64>().unwrap())
}

fn stat(dir: &Path, name: &str) -> (Vec<u64>, Vec<f64>) {
    npy(&dir.join("stats").join(format!("{name}.npy")))
}

fn manifest(dir: &Path) -> Value {
    let text = std::fs::read_to_string(dir.join("manifest.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

/// members.csv as (header, rows of fields).
fn members_csv(dir: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let mut reader = csv::Reader::from_path(dir.join("members.csv")).unwrap();
    let header = reader
        .headers()
        .unwrap()
        .iter()
        .map(str::to_string)
        .collect();
    let rows = reader
        .records()
        .map(|r| r.unwrap().iter().map(str::to_string).collect())
        .collect();
    (header, rows)
}

fn column(header: &[String], name: &str) -> usize {
    header
        .iter()
        .position(|h| h == name)
        .unwrap_or_else(|| panic!("members.csv has no column {name}: {header:?}"))
}

/// |a - b| <= rel max(|a|, |b|) + abs; NaN only equals NaN.
fn close(a: f64, b: f64, rel: f64, abs: f64) -> bool {
    if a.is_nan() || b.is_nan() {
        return a.is_nan() && b.is_nan();
    }
    (a - b).abs() <= rel * a.abs().max(b.abs()) + abs
}

fn assert_all_close(what: &str, got: &[f64], want: &[f64], rel: f64, abs: f64) -> f64 {
    assert_eq!(got.len(), want.len(), "{what}: length");
    let mut worst = 0.0f64;
    for (i, (&g, &w)) in got.iter().zip(want).enumerate() {
        assert!(
            close(g, w, rel, abs),
            "{what}[{i}]: got {g:e}, expected {w:e} (rel {rel:e}, abs {abs:e})"
        );
        if g.is_finite() && w.is_finite() && w != 0.0 {
            worst = worst.max(((g - w) / w).abs());
        }
    }
    worst
}

/// Bitwise equality (NaN equals NaN).
fn assert_identical(what: &str, got: &[f64], want: &[f64]) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    for (i, (&g, &w)) in got.iter().zip(want).enumerate() {
        assert!(
            g.to_bits() == w.to_bits() || (g.is_nan() && w.is_nan()),
            "{what}[{i}]: {g:e} != {w:e}"
        );
    }
}

/// The lower-rank order statistic x_r, r = floor(q (n - 1)), of `values` (finite, any order).
fn order_statistic(values: &[f64], q: f64) -> f64 {
    let mut v = values.to_vec();
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    let r = ((q * (v.len() - 1) as f64).floor() as usize).min(v.len() - 1);
    v[r]
}

fn mean(values: &[f64]) -> f64 {
    values.iter().sum::<f64>() / values.len() as f64
}

/// Two-pass sample variance.
fn variance(values: &[f64]) -> f64 {
    let m = mean(values);
    values.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (values.len() - 1) as f64
}

/// The study's members, rebuilt and solved here with the library, independently of the CLI.
struct Reference {
    times: Vec<f64>,
    quantiles: Vec<f64>,
    threshold: f64,
    /// [T][M]: max density (NaN once failed).
    max_density: Vec<Vec<f64>>,
    /// Field -> [T][M][G].
    fields: BTreeMap<&'static str, Vec<Vec<Vec<f64>>>>,
    /// Failure time per member (None when the member finished).
    failure: Vec<Option<f64>>,
    /// Velocity factor drawn for each member.
    factor: Vec<f64>,
}

impl Reference {
    fn members(&self) -> usize {
        self.failure.len()
    }

    /// Values of the members with a finite value at time k.
    fn finite(&self, row: &[f64]) -> Vec<f64> {
        row.iter().copied().filter(|x| x.is_finite()).collect()
    }
}

/// Every member built with `EnsembleMembers::member` and all solved in one `CpuSolver`, with a plan made as
/// `study::solve_chunk` makes it.
fn reference(scene_path: &Path) -> Reference {
    let scene = Scene::from_file(scene_path).unwrap();
    let spec = scene.ensemble.clone().expect("an ensemble scene");
    let members = EnsembleMembers::new(&scene, &spec).unwrap();
    let total = members.total();
    let mut chains = Vec::new();
    let mut params = Vec::new();
    let mut factor = Vec::new();
    for m in 0..total {
        let inputs = members.member(m).unwrap();
        chains.push(inputs.chain);
        params.push(inputs.params);
        factor.push(inputs.velocity_factor);
    }
    let mut plan = scene.plan(&chains[0], scene.precision);
    plan.members = params;
    plan.repulsion = chains[0].dstar.is_some();
    plan.fields.rho_star = plan.repulsion;
    plan.fields.rho = true;
    plan.fields.u = true;
    let mut solver = CpuSolver::new(plan, chains);
    let mut max_density = Vec::new();
    let mut fields: BTreeMap<&'static str, Vec<Vec<Vec<f64>>>> =
        FIELDS.iter().map(|f| (*f, Vec::new())).collect();
    while let Some(snaps) = solver.next_output(&|_| {}).unwrap() {
        max_density.push(snaps.iter().map(|s| s.max_density).collect());
        for f in FIELDS {
            let rows = snaps
                .iter()
                .map(|s| match f {
                    "rho" => s.rho.clone(),
                    "u" => s.u.clone(),
                    _ => s.rho_star.clone(),
                })
                .collect();
            fields.get_mut(f).unwrap().push(rows);
        }
    }
    let failure = solver
        .reports()
        .iter()
        .map(|r| match &r.status {
            MemberStatus::Ok => None,
            MemberStatus::Failed { time, .. } => Some(*time),
        })
        .collect();
    Reference {
        times: scene.output_times.clone(),
        quantiles: spec.quantiles.clone(),
        threshold: spec.threshold,
        max_density,
        fields,
        failure,
        factor,
    }
}

/// Whether `dir` holds a finished checkpoint of a running study (`checkpoint.state`, not its
/// `.tmp`).
fn has_checkpoint(dir: &Path) -> bool {
    dir.join("checkpoint.state").is_file()
}

// ---------------------------------------------------------------------------------------------
// 1. Statistics against a direct computation.

#[test]
fn statistics_match_direct_computation_over_members() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = data("study_basic.toml");
    let out = tmp.path().join("study");
    assert_success(&run(&scene, &out, &[]), "roughlub run study_basic");
    let r = reference(&scene);
    let (t, m) = (r.times.len(), r.members());
    assert_eq!((t, m), (3, 96));
    assert!(
        r.failure.iter().all(Option::is_none),
        "no member of study_basic should fail"
    );
    let nq = r.quantiles.len();
    let bins = 200.0;

    let (shape, times) = stat(&out, "times");
    assert_eq!(shape, [t as u64]);
    assert_identical("times", &times, &r.times);
    let (_, levels) = stat(&out, "quantile_levels");
    assert_identical("quantile_levels", &levels, &r.quantiles);

    // Scalar max density: moments, extremes, count and DDSketch quantiles.
    let per_time: Vec<Vec<f64>> = r.max_density.iter().map(|row| r.finite(row)).collect();
    let want_mean: Vec<f64> = per_time.iter().map(|v| mean(v)).collect();
    let want_var: Vec<f64> = per_time.iter().map(|v| variance(v)).collect();
    let want_min: Vec<f64> = per_time
        .iter()
        .map(|v| v.iter().copied().fold(f64::INFINITY, f64::min))
        .collect();
    let want_max: Vec<f64> = per_time
        .iter()
        .map(|v| v.iter().copied().fold(f64::NEG_INFINITY, f64::max))
        .collect();
    let (shape, got) = stat(&out, "max_density_mean");
    assert_eq!(shape, [1, t as u64], "[P, T] with P = 1 without a sweep");
    let e_mean = assert_all_close("max_density_mean", &got, &want_mean, 1e-12, 0.0);
    let e_var = assert_all_close(
        "max_density_var",
        &stat(&out, "max_density_var").1,
        &want_var,
        1e-10,
        0.0,
    );
    assert_all_close(
        "max_density_min",
        &stat(&out, "max_density_min").1,
        &want_min,
        1e-12,
        0.0,
    );
    assert_all_close(
        "max_density_max",
        &stat(&out, "max_density_max").1,
        &want_max,
        1e-12,
        0.0,
    );
    assert_identical(
        "max_density_count",
        &stat(&out, "max_density_count").1,
        &vec![m as f64; t],
    );
    // The study's stated relative accuracy of scalar quantiles (at most the sketch default).
    let alpha = roughlub::study::SCALAR_ALPHA;
    assert!(alpha > 0.0 && alpha <= 0.005, "SCALAR_ALPHA = {alpha}");
    let (shape, quant) = stat(&out, "max_density_quantiles");
    assert_eq!(shape, [1, t as u64, nq as u64]);
    let mut e_quant = 0.0f64;
    for k in 0..t {
        for (j, &q) in r.quantiles.iter().enumerate() {
            let x = order_statistic(&per_time[k], q);
            let v = quant[k * nq + j];
            // DDSketch guarantee: |v - x_r| <= alpha |x_r|.
            assert!(
                (v - x).abs() <= alpha * x.abs() * (1.0 + 1e-12),
                "max_density quantile q = {q} at t = {}: {v} vs order statistic {x}",
                r.times[k]
            );
            e_quant = e_quant.max(((v - x) / x).abs());
        }
    }
    eprintln!(
        "max_density: worst relative error mean {e_mean:.1e}, var {e_var:.1e}, quantile {e_quant:.2e} (alpha {alpha})"
    );

    // Fields: pointwise mean and variance, and histogram quantile bands.
    let g = r.fields["rho"][0][0].len();
    assert_eq!(g, 30);
    let (_, x) = stat(&out, "x");
    assert_eq!(x.len(), g);
    // Scalar peak centre: each member's centroid of its rho excess over its mean, from the
    // reference rows (the study computes it where each snapshot is observed).
    let want_centre: Vec<f64> = r.fields["rho"]
        .iter()
        .map(|rows| {
            let centres: Vec<f64> = rows
                .iter()
                .filter_map(|rho| {
                    let level = mean(rho);
                    let (mut wx, mut w) = (0.0, 0.0);
                    for (xi, ri) in x.iter().zip(rho) {
                        let excess = (ri - level).max(0.0);
                        wx += xi * excess;
                        w += excess;
                    }
                    (w > 1e-12).then(|| wx / w)
                })
                .collect();
            assert_eq!(centres.len(), m, "every member's rho has a peak");
            mean(&centres)
        })
        .collect();
    assert_all_close(
        "peak_centre_mean",
        &stat(&out, "peak_centre_mean").1,
        &want_centre,
        1e-12,
        0.0,
    );
    let u_range = &manifest(&out)["quantile_method"]["field_ranges"]["u"];
    let (u_lo, u_hi) = (u_range[0].as_f64().unwrap(), u_range[1].as_f64().unwrap());
    for (field, lo, hi) in [("rho", 0.0, 1.0), ("rho_star", 0.0, 1.0), ("u", u_lo, u_hi)] {
        let samples = &r.fields[field];
        let scale = samples
            .iter()
            .flatten()
            .flatten()
            .fold(0.0f64, |a, &b| a.max(b.abs()));
        let (mut want_mean, mut want_var) = (Vec::new(), Vec::new());
        for per_member in samples {
            for j in 0..g {
                let col: Vec<f64> = per_member.iter().map(|row| row[j]).collect();
                want_mean.push(mean(&col));
                want_var.push(variance(&col));
            }
        }
        let (shape, got_mean) = stat(&out, &format!("{field}_mean"));
        assert_eq!(shape, [1, t as u64, g as u64], "{field}_mean shape");
        // Relative, with an absolute floor at the field's scale for values that cross 0 (u).
        let e_mean = assert_all_close(
            &format!("{field}_mean"),
            &got_mean,
            &want_mean,
            1e-12,
            1e-13 * scale,
        );
        let e_var = assert_all_close(
            &format!("{field}_var"),
            &stat(&out, &format!("{field}_var")).1,
            &want_var,
            1e-10,
            1e-13 * scale * scale,
        );
        let (shape, got_q) = stat(&out, &format!("{field}_quantiles"));
        assert_eq!(
            shape,
            [1, t as u64, nq as u64, g as u64],
            "{field}_quantiles"
        );
        let half_bin = (hi - lo) / (2.0 * bins);
        let mut worst = 0.0f64;
        for (k, per_member) in samples.iter().enumerate() {
            for (iq, &q) in r.quantiles.iter().enumerate() {
                for j in 0..g {
                    let col: Vec<f64> = per_member.iter().map(|row| row[j]).collect();
                    let xr = order_statistic(&col, q);
                    let v = got_q[(k * nq + iq) * g + j];
                    assert!(
                        (lo..=hi).contains(&xr),
                        "{field} sample {xr} outside [{lo}, {hi}]"
                    );
                    assert!(
                        (v - xr).abs() <= half_bin * (1.0 + 1e-9),
                        "{field} quantile q = {q} at t = {}, x = {}: {v} vs order statistic {xr} (half bin {half_bin})",
                        r.times[k],
                        x[j]
                    );
                    worst = worst.max((v - xr).abs() / half_bin);
                }
            }
        }
        eprintln!(
            "{field}: worst relative error mean {e_mean:.1e}, var {e_var:.1e}; quantile error up to {worst:.3} half bins"
        );
    }

    // members.csv: one row per member, peak density = max over time of the max density.
    let (header, rows) = members_csv(&out);
    assert_eq!(rows.len(), m);
    let (c_member, c_status, c_peak, c_factor, c_hit) = (
        column(&header, "member"),
        column(&header, "status"),
        column(&header, "peak_density"),
        column(&header, "velocity_factor"),
        column(&header, "first_hit_time"),
    );
    let mut hits = 0;
    for (i, row) in rows.iter().enumerate() {
        assert_eq!(row[c_member], i.to_string());
        assert_eq!(row[c_status], "ok");
        let peak: f64 = row[c_peak].parse().unwrap();
        let want = (0..t)
            .map(|k| r.max_density[k][i])
            .fold(f64::NEG_INFINITY, f64::max);
        assert!(
            close(peak, want, 1e-14, 0.0),
            "member {i}: peak_density {peak} vs {want}"
        );
        let factor: f64 = row[c_factor].parse().unwrap();
        assert_eq!(factor, r.factor[i], "member {i}: velocity_factor");
        let hit: f64 = row[c_hit].parse().unwrap();
        let want_hit = (0..t)
            .find(|&k| r.max_density[k][i] >= r.threshold)
            .map_or(f64::NAN, |k| r.times[k]);
        assert!(
            close(hit, want_hit, 0.0, 0.0),
            "member {i}: first_hit_time {hit} vs {want_hit}"
        );
        hits += usize::from(hit.is_finite());
    }
    // The threshold splits the members, so first_hit holds both kinds.
    let (_, first_hit) = stat(&out, "first_hit");
    assert_eq!(first_hit[0], hits as f64, "first_hit count");
    assert_eq!(first_hit[1], (m - hits) as f64, "first_hit never_hit");
    assert!(
        0 < hits && hits < m,
        "the threshold should split the members ({hits} of {m} reach it)"
    );
    eprintln!(
        "{hits} of {m} members reached the threshold {}",
        r.threshold
    );
}

// ---------------------------------------------------------------------------------------------
// 2. Sharding and merge.

/// Every statistic of two study directories: moments within `rel`, quantiles, histograms and
/// counts bit for bit.
fn assert_same_statistics(a: &Path, b: &Path, rel: f64) -> f64 {
    let mut worst = 0.0f64;
    for name in ["quantile_levels", "first_hit_quantiles"] {
        assert_identical(name, &stat(a, name).1, &stat(b, name).1);
    }
    let (fa, fb) = (stat(a, "first_hit").1, stat(b, "first_hit").1);
    assert_identical("first_hit counts", &fa[..2], &fb[..2]);
    worst = worst.max(assert_all_close(
        "first_hit moments",
        &fa[2..],
        &fb[2..],
        rel,
        0.0,
    ));
    for s in SCALARS {
        for part in ["count", "quantiles", "hist_counts", "hist_edges"] {
            let name = format!("{s}_{part}");
            let (sa, va) = stat(a, &name);
            let (sb, vb) = stat(b, &name);
            assert_eq!(sa, sb, "{name} shape");
            assert_identical(&name, &va, &vb);
        }
        for part in ["mean", "var", "min", "max"] {
            let name = format!("{s}_{part}");
            worst = worst.max(assert_all_close(
                &name,
                &stat(a, &name).1,
                &stat(b, &name).1,
                rel,
                0.0,
            ));
        }
    }
    for f in FIELDS {
        let name = format!("{f}_quantiles");
        let (sa, va) = stat(a, &name);
        let (sb, vb) = stat(b, &name);
        assert_eq!(sa, sb, "{name} shape");
        assert_identical(&name, &va, &vb);
        for part in ["mean", "var"] {
            let name = format!("{f}_{part}");
            let (va, vb) = (stat(a, &name).1, stat(b, &name).1);
            // Absolute floor far below any value of interest, for points where u crosses 0.
            let scale = va.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            worst = worst.max(assert_all_close(&name, &va, &vb, rel, 1e-14 * scale));
        }
    }
    worst
}

#[test]
fn shards_merge_to_the_unsharded_study() {
    let tmp = tempfile::tempdir().unwrap();
    // 100 members in shards 0..33, 33..66, 66..100: shard bounds fall inside chunks of 16.
    let scene = scene_variant(
        "study_basic.toml",
        &[("members = 96", "members = 100")],
        tmp.path(),
        "study_shards.toml",
    );
    let whole = tmp.path().join("whole");
    assert_success(&run(&scene, &whole, &[]), "unsharded run");
    let shards: Vec<PathBuf> = (0..3).map(|k| tmp.path().join(format!("d{k}"))).collect();
    for (k, d) in shards.iter().enumerate() {
        let spec = format!("{k}/3");
        assert_success(&run(&scene, d, &["--shard", &spec]), "sharded run");
        let man = manifest(d);
        let want = [100 * k as u64 / 3, 100 * (k as u64 + 1) / 3];
        assert_eq!(man["member_range"], serde_json::json!(want), "shard {k}");
    }
    let merged = tmp.path().join("merged");
    let refs: Vec<&Path> = shards.iter().map(PathBuf::as_path).collect();
    assert_success(&merge(&refs, &merged), "merge");

    let worst = assert_same_statistics(&merged, &whole, 1e-12);
    eprintln!("merged vs unsharded: worst relative difference of moments {worst:.1e}");
    let man = manifest(&merged);
    assert_eq!(man["complete"], Value::Bool(true), "merged manifest: {man}");
    assert_eq!(man["members_covered"], 100);
    assert_eq!(man["members_completed"], 100);
    assert_eq!(man["failed_members"], serde_json::json!([]));
    assert_eq!(
        std::fs::read_to_string(merged.join("members.csv")).unwrap(),
        std::fs::read_to_string(whole.join("members.csv")).unwrap(),
        "members.csv of the merged shards differs from the unsharded one"
    );
    // The shards' rows, concatenated, are the unsharded rows (section 3: union of shards).
    let (_, whole_rows) = members_csv(&whole);
    let shard_rows: Vec<Vec<String>> = shards.iter().flat_map(|d| members_csv(d).1).collect();
    assert_eq!(shard_rows, whole_rows);

    // Overlapping shards (the same directory twice) are refused.
    let bad = merge(&[&shards[1], &shards[1]], &tmp.path().join("bad"));
    assert_eq!(bad.status.code(), Some(2), "stderr: {}", stderr_of(&bad));
    assert!(
        stderr_of(&bad).contains("overlap"),
        "message should mention the overlap: {}",
        stderr_of(&bad)
    );
    assert!(!tmp.path().join("bad").join("manifest.json").exists());

    // The output times and the grid of the merged study are those of the scene, to the bit.
    for name in ["times", "x"] {
        assert_identical(
            &format!("merged {name}.npy"),
            &stat(&merged, name).1,
            &stat(&whole, name).1,
        );
    }
}

// ---------------------------------------------------------------------------------------------
// 3. Reproducibility.

#[test]
fn members_csv_does_not_depend_on_chunks_or_threads() {
    let tmp = tempfile::tempdir().unwrap();
    let base_scene = data("study_basic.toml");
    let reference_dir = tmp.path().join("chunk16");
    assert_success(&run(&base_scene, &reference_dir, &[]), "chunk 16");
    let csv = |dir: &Path| std::fs::read_to_string(dir.join("members.csv")).unwrap();
    let want = csv(&reference_dir);
    assert_eq!(want.lines().count(), 97);
    for chunk in [7, 64] {
        let scene = scene_variant(
            "study_basic.toml",
            &[("chunk = 16", &format!("chunk = {chunk}"))],
            tmp.path(),
            &format!("chunk{chunk}.toml"),
        );
        let dir = tmp.path().join(format!("chunk{chunk}"));
        assert_success(&run(&scene, &dir, &[]), "chunk variant");
        assert_eq!(
            manifest(&dir)["chunks"],
            96u64.div_ceil(chunk),
            "chunk {chunk}"
        );
        assert_eq!(csv(&dir), want, "members.csv with chunk = {chunk}");
        // Sketch and histogram states are exact under any chunking.
        for name in ["max_density_quantiles", "rho_quantiles", "u_quantiles"] {
            assert_identical(name, &stat(&dir, name).1, &stat(&reference_dir, name).1);
        }
        assert_all_close(
            "max_density_mean",
            &stat(&dir, "max_density_mean").1,
            &stat(&reference_dir, "max_density_mean").1,
            1e-12,
            0.0,
        );
    }
    for threads in ["1", "2"] {
        let dir = tmp.path().join(format!("threads{threads}"));
        assert_success(
            &run_with_env(&base_scene, &dir, &[], &[("RAYON_NUM_THREADS", threads)]),
            "thread variant",
        );
        // What ran the members, recorded like a single run's: backend, request, adapter.
        let man = manifest(&dir);
        assert_eq!(man["backend"], "cpu", "manifest: {man}");
        assert_eq!(man["backend_requested"], "cpu", "manifest: {man}");
        assert!(man["precision"].is_string(), "manifest: {man}");
        let adapter = &man["adapter"];
        let name = adapter["name"].as_str().unwrap_or("").to_string();
        assert!(
            name.contains(&format!("{threads} thread")),
            "adapter {name:?} should report {threads} thread(s)"
        );
        assert_eq!(
            adapter["threads"],
            threads.parse::<u64>().unwrap(),
            "adapter: {adapter}"
        );
        assert_eq!(
            csv(&dir),
            want,
            "members.csv with RAYON_NUM_THREADS={threads}"
        );
    }
}

// ---------------------------------------------------------------------------------------------
// 4. Resume.

/// Starts a fresh `roughlub run` of `scene` into `dir` (CPU, a checkpoint after every chunk),
/// kills it (SIGKILL) once its staging directory beside `dir` holds a checkpoint and `wait`
/// more has passed, and returns that staging directory.
fn kill_after_checkpoint(scene: &Path, dir: &Path, wait: Duration) -> PathBuf {
    let mut child = Command::new(BIN)
        .arg("run")
        .arg(scene)
        .arg("--out")
        .arg(dir)
        .args(["--backend", "cpu", "--quiet", "--checkpoint-every", "0"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // A fresh study is built beside --out and swapped in when complete.
    let name = dir.file_name().unwrap().to_string_lossy();
    let staging = dir.with_file_name(format!(".{name}.partial-{}", child.id()));
    let started = Instant::now();
    while !has_checkpoint(&staging) {
        assert!(
            child.try_wait().unwrap().is_none(),
            "the run ended before a checkpoint was seen"
        );
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "no checkpoint after 60 s"
        );
        std::thread::sleep(Duration::from_millis(2));
    }
    std::thread::sleep(wait);
    child.kill().unwrap();
    child.wait().unwrap();
    staging
}

#[test]
fn resume_after_kill_reuses_chunks_and_matches_uninterrupted_run() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = data("study_resume.toml");
    let dir = tmp.path().join("killed");
    let staging = kill_after_checkpoint(&scene, &dir, Duration::from_millis(20));
    assert!(has_checkpoint(&staging));
    assert!(
        !staging.join("manifest.json").exists(),
        "the run finished before it was killed; make the scene bigger"
    );
    assert!(
        !dir.exists(),
        "a killed fresh study must leave --out as it was (here: absent)"
    );

    let resumed = run(&scene, &dir, &["--resume"]);
    assert_success(&resumed, "roughlub run --resume");
    let man = manifest(&dir);
    let reused = man["chunks_reused"].as_u64().unwrap();
    eprintln!("killed with {reused} of 20 chunks checkpointed");
    assert!(
        (1..20).contains(&reused),
        "chunks_reused should be the chunks of the checkpoint (1 to 19), got {reused}"
    );
    assert_eq!(man["chunks"], 20);
    // Once the study completes, partial.state holds the checkpoint's statistics and the rest.
    assert!(
        !has_checkpoint(&dir),
        "a complete study keeps no checkpoint"
    );
    assert!(dir.join("partial.state").is_file());
    assert!(
        !staging.exists(),
        "the adopted staging directory is left behind"
    );

    let (header, rows) = members_csv(&dir);
    let c_member = column(&header, "member");
    let members: Vec<u64> = rows.iter().map(|r| r[c_member].parse().unwrap()).collect();
    assert_eq!(members, (0..2000).collect::<Vec<u64>>());

    let whole = tmp.path().join("whole");
    assert_success(&run(&scene, &whole, &[]), "uninterrupted run");
    assert_eq!(manifest(&whole)["chunks_reused"], 0);
    assert_eq!(
        std::fs::read_to_string(dir.join("members.csv")).unwrap(),
        std::fs::read_to_string(whole.join("members.csv")).unwrap(),
        "members.csv after resume differs from the uninterrupted run"
    );
    // The checkpoint is read back bit for bit and chunks are merged in the same order, so the
    // mean is the same to the bit.
    assert_identical(
        "max_density_mean",
        &stat(&dir, "max_density_mean").1,
        &stat(&whole, "max_density_mean").1,
    );
    assert_identical(
        "max_density_quantiles",
        &stat(&dir, "max_density_quantiles").1,
        &stat(&whole, "max_density_quantiles").1,
    );
}

/// A fresh study into a directory that holds a single run: killed, it leaves the single run
/// untouched; completed, nothing of the single run stays beside it (issue 9, item 1).
#[test]
fn a_study_replaces_an_earlier_run_whole() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("out");
    assert_success(&run(&data("small.toml"), &dir, &[]), "single run");
    let single_manifest = std::fs::read(dir.join("manifest.json")).unwrap();
    assert!(dir.join("gaps.npy").is_file());

    let staging = kill_after_checkpoint(&data("study_resume.toml"), &dir, Duration::ZERO);
    assert_eq!(
        std::fs::read(dir.join("manifest.json")).unwrap(),
        single_manifest,
        "the killed study changed the earlier run's manifest"
    );
    assert!(
        !dir.join("study.json").exists(),
        "the killed study wrote into --out"
    );

    let small_study = data("study_basic.toml");
    assert_success(&run(&small_study, &dir, &[]), "fresh study");
    for stale in ["gaps.npy", "velocities.npy", "rho.npy", "energy.npy"] {
        assert!(
            !dir.join(stale).exists(),
            "{stale} of the single run stayed"
        );
    }
    assert_eq!(manifest(&dir)["kind"], "ensemble");
    assert!(
        !staging.exists(),
        "the killed study's staging directory stayed"
    );
}

#[test]
fn resume_into_a_directory_of_another_scene_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("study");
    assert_success(&run(&data("study_basic.toml"), &dir, &[]), "first run");
    let other = scene_variant(
        "study_basic.toml",
        &[("seed = 11", "seed = 12")],
        tmp.path(),
        "other.toml",
    );
    let out = run(&other, &dir, &["--resume"]);
    assert_eq!(out.status.code(), Some(2), "stderr: {}", stderr_of(&out));
    assert!(
        stderr_of(&out).contains("different study"),
        "message: {}",
        stderr_of(&out)
    );
    // The first study is left alone.
    assert!(dir.join("partial.state").is_file());
    assert_eq!(manifest(&dir)["members_completed"], 96);
}

/// A negative or NaN `--checkpoint-every` is refused before anything is written, naming the
/// option and its range.
#[test]
fn a_bad_checkpoint_interval_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    for bad in ["-1", "NaN"] {
        let dir = tmp.path().join(format!("study{bad}"));
        let flag = format!("--checkpoint-every={bad}");
        let out = run(&data("study_basic.toml"), &dir, &[flag.as_str()]);
        assert_eq!(out.status.code(), Some(2), "stderr: {}", stderr_of(&out));
        let err = stderr_of(&out);
        assert!(
            err.contains("--checkpoint-every") && err.contains("0 <= SECONDS"),
            "message: {err}"
        );
        assert!(!dir.exists(), "{bad}: an output directory was written");
    }
}

// ---------------------------------------------------------------------------------------------
// 5. Failed members.

#[test]
fn failed_members_are_counted_and_listed_never_averaged() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = data("study_fail.toml");
    // The library says which members fail: some, all at mu = 1e-7 (the second point, 20..39).
    let r = reference(&scene);
    let m = r.members();
    assert_eq!(m, 40);
    let failing: Vec<u64> = (0..m as u64)
        .filter(|&i| r.failure[i as usize].is_some())
        .collect();
    assert!(
        !failing.is_empty() && failing.len() < m / 2,
        "expected some but not all mu = 1e-7 members to fail: {failing:?}"
    );
    assert!(
        failing.iter().all(|&i| i >= 20),
        "only mu = 1e-7 members should fail: {failing:?}"
    );

    let out = tmp.path().join("study");
    let o = run(&scene, &out, &[]);
    assert_success(&o, "roughlub run study_fail");
    assert!(stderr_of(&o).contains(&format!("{} member(s) failed", failing.len())));
    let man = manifest(&out);
    assert_eq!(man["failed_members"], serde_json::json!(failing));
    assert_eq!(man["members_completed"], (m - failing.len()) as u64);
    // The chunk of members 16..31 pushes its points' rows as they are observed, then sees
    // members fail: it is solved again and those pushes are undone. The checks below (counts and
    // means over the ok members only) hold through that path.
    assert!(man["chunks_solved_twice"].as_u64().unwrap() >= 1, "{man}");

    let (header, rows) = members_csv(&out);
    let (c_status, c_peak, c_ft, c_mu, c_reason) = (
        column(&header, "status"),
        column(&header, "peak_density"),
        column(&header, "failure_time"),
        column(&header, "mu"),
        column(&header, "failure_reason"),
    );
    for (i, row) in rows.iter().enumerate() {
        let want_mu = if i < 20 { 0.01 } else { 1e-7 };
        assert_eq!(row[c_mu].parse::<f64>().unwrap(), want_mu, "member {i}: mu");
        match r.failure[i] {
            Some(t) => {
                assert_eq!(row[c_status], "failed", "member {i}");
                assert_eq!(
                    row[c_ft].parse::<f64>().unwrap(),
                    t,
                    "member {i}: failure_time"
                );
                assert!(row[c_peak].parse::<f64>().unwrap().is_nan());
                // Why, in words (as a single run's manifest gives it).
                assert!(row[c_reason].len() > 10, "member {i}: {:?}", row[c_reason]);
            }
            None => {
                assert_eq!(row[c_status], "ok", "member {i}");
                assert!(row[c_ft].parse::<f64>().unwrap().is_nan());
                assert_eq!(row[c_reason], "", "member {i}");
            }
        }
    }

    // Counts: at every time t_k, exactly the ok members of each sweep point (stats are [P, T]
    // with P = 2 points of 20 members): a member that fails later is left out of every time's
    // statistics (never averaged in), even where its snapshot was valid.
    let (shape, count) = stat(&out, "max_density_count");
    let t_count = r.times.len();
    assert_eq!(shape, [2, t_count as u64]);
    let (_, got_mean) = stat(&out, "max_density_mean");
    let (_, got_max) = stat(&out, "max_density_max");
    let (_, rho_mean) = stat(&out, "rho_mean");
    let g = r.fields["rho"][0][0].len();
    for p in 0..2 {
        let members = 20 * p..20 * (p + 1);
        let ok = |i: &usize| r.failure[*i].is_none();
        let alive = members.clone().filter(ok).count();
        for (k, &t) in r.times.iter().enumerate() {
            let finite: Vec<f64> = members
                .clone()
                .filter(ok)
                .map(|i| r.max_density[k][i])
                .collect();
            let at = p * t_count + k;
            assert_eq!(
                count[at], alive as f64,
                "max_density_count, point {p}, t = {t}"
            );
            assert!(
                close(got_mean[at], mean(&finite), 1e-12, 0.0),
                "max_density_mean, point {p}, t = {t}: {} vs {}",
                got_mean[at],
                mean(&finite)
            );
            let want_max = finite.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            assert_eq!(got_max[at], want_max, "max_density_max, point {p}, t = {t}");
            // The field bands count the same members: their means are over the ok members
            // only, at every time.
            for j in 0..g {
                let col: Vec<f64> = members
                    .clone()
                    .filter(ok)
                    .map(|i| r.fields["rho"][k][i][j])
                    .collect();
                let at = (p * t_count + k) * g + j;
                assert!(close(rho_mean[at], mean(&col), 1e-12, 1e-15));
            }
        }
        eprintln!("point {p}: {alive} of 20 members counted");
    }
    assert_eq!(
        count[t_count - 1] + count[2 * t_count - 1],
        (m - failing.len()) as f64,
        "at the end only ok members are counted"
    );
}

/// `store_members = true`: the per-member arrays land in --out (they are written into the
/// staging directory that becomes --out), with one row per member, and they hold the gaps and
/// velocities whatever `[output] fields` asks the bands for: with `fields = ["energy"]` the
/// arrays are the same, bit for bit (they once came out empty, with a wrapped shape).
#[test]
fn stored_member_arrays_land_in_out() {
    let tmp = tempfile::tempdir().unwrap();
    let stored = |fields: &str, name: &str| {
        let scene = scene_variant(
            "study_basic.toml",
            &[
                ("plots = false", fields),
                ("jitter = 0.05", "jitter = 0.05\nstore_members = true"),
            ],
            tmp.path(),
            &format!("{name}.toml"),
        );
        let dir = tmp.path().join(name);
        assert_success(&run(&scene, &dir, &[]), "store_members run");
        let mut arrays = std::collections::BTreeMap::new();
        for e in std::fs::read_dir(dir.join("members")).unwrap() {
            let p = e.unwrap().path();
            let file = p.file_name().unwrap().to_string_lossy().into_owned();
            if file.ends_with("_gaps.npy") || file.ends_with("_velocities.npy") {
                arrays.insert(file, npy(&p));
            }
        }
        arrays
    };
    let all = stored("plots = false", "stored");
    let mut total = 0;
    for (file, (shape, _)) in &all {
        if file.ends_with("_gaps.npy") {
            assert_eq!(shape[1..], [3, 40], "[member, T, N] of {file}");
            total += shape[0];
        } else {
            assert_eq!(shape[1..], [3, 39], "[member, T, N - 1] of {file}");
        }
    }
    assert_eq!(total, 96, "one stored row per member");
    let energy_only = stored("plots = false\nfields = [\"energy\"]", "energy_only");
    assert_eq!(energy_only.len(), all.len(), "the same chunk files");
    for (file, (shape, values)) in &all {
        let (other_shape, other_values) = &energy_only[file];
        assert_eq!(
            other_shape, shape,
            "shape of {file} with fields = [\"energy\"]"
        );
        let same = values
            .iter()
            .zip(other_values)
            .all(|(a, b)| a.to_bits() == b.to_bits());
        assert!(same, "{file} differs with fields = [\"energy\"]");
    }
}

/// An adaptive study records each member's error estimate at every output time: the stored
/// [member, T] array equals the estimates of the same members solved directly with the library,
/// its statistics per time are those of that array, and members.csv holds the last column. An
/// order 1 fixed-step study has none (count 0, NaN in the stored array).
#[test]
fn error_estimates_per_member_and_output_time() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = scene_variant(
        "study_basic.toml",
        &[
            ("dt = 1e-3", "tolerance = 1e-6"),
            ("order = 1", "order = \"auto\""),
            ("jitter = 0.05", "jitter = 0.05\nstore_members = true"),
        ],
        tmp.path(),
        "estimates.toml",
    );
    let dir = tmp.path().join("estimates");
    assert_success(
        &run(&scene, &dir, &[]),
        "adaptive study with stored members",
    );

    // Independent: every member rebuilt and solved in one CpuSolver.
    let parsed = Scene::from_file(&scene).unwrap();
    let spec = parsed.ensemble.clone().unwrap();
    let members = EnsembleMembers::new(&parsed, &spec).unwrap();
    let (mut chains, mut params) = (Vec::new(), Vec::new());
    for m in 0..members.total() {
        let inputs = members.member(m).unwrap();
        chains.push(inputs.chain);
        params.push(inputs.params);
    }
    let mut plan = parsed.plan(&chains[0], parsed.precision);
    plan.members = params;
    plan.repulsion = true;
    plan.fields.rho_star = true;
    plan.fields.rho = true;
    plan.fields.u = true;
    let mut solver = CpuSolver::new(plan, chains);
    while solver.next_output(&|_| {}).unwrap().is_some() {}
    let want: Vec<Vec<f64>> = solver
        .reports()
        .iter()
        .map(|r| r.error_estimate.clone().expect("adaptive runs estimate"))
        .collect();
    let t = want[0].len();
    assert_eq!(t, 3);
    assert!(want.iter().all(|e| e[0] == 0.0 && e[t - 1] > 0.0));

    // The stored arrays, chunk by chunk in member order.
    let mut names: Vec<PathBuf> = std::fs::read_dir(dir.join("members"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.to_string_lossy().ends_with("_error_estimate.npy"))
        .collect();
    names.sort();
    let mut stored = Vec::new();
    for p in &names {
        let (shape, values) = npy(p);
        assert_eq!(shape[1], t as u64, "[member, T] of {p:?}");
        stored.extend(values);
    }
    let flat: Vec<f64> = want.iter().flatten().copied().collect();
    assert_identical("stored error estimates", &stored, &flat);

    // Statistics per output time, over members.
    let per_time: Vec<Vec<f64>> = (0..t)
        .map(|k| want.iter().map(|e| e[k]).collect())
        .collect();
    let (shape, max) = stat(&dir, "error_estimate_max");
    assert_eq!(shape, [1, t as u64]);
    let want_max: Vec<f64> = per_time
        .iter()
        .map(|v| v.iter().copied().fold(f64::NEG_INFINITY, f64::max))
        .collect();
    assert_identical("error_estimate_max", &max, &want_max);
    let want_mean: Vec<f64> = per_time.iter().map(|v| mean(v)).collect();
    assert_all_close(
        "error_estimate_mean",
        &stat(&dir, "error_estimate_mean").1,
        &want_mean,
        1e-12,
        0.0,
    );
    assert_identical(
        "error_estimate_count",
        &stat(&dir, "error_estimate_count").1,
        &vec![want.len() as f64; t],
    );

    // members.csv: the estimate at the end.
    let (header, rows) = members_csv(&dir);
    let c = column(&header, "error_estimate");
    let last: Vec<f64> = rows.iter().map(|r| r[c].parse().unwrap()).collect();
    let want_last: Vec<f64> = want.iter().map(|e| e[t - 1]).collect();
    assert_all_close("members.csv error_estimate", &last, &want_last, 1e-15, 0.0);

    // Order 1 with fixed steps and its companion turned off has no estimate: empty statistics.
    let plain = scene_variant(
        "study_basic.toml",
        &[
            ("jitter = 0.05", "jitter = 0.05\nstore_members = true"),
            (
                "backend = \"cpu\"",
                "backend = \"cpu\"\nerror_estimate = false",
            ),
        ],
        tmp.path(),
        "plain.toml",
    );
    let plain_dir = tmp.path().join("plain");
    assert_success(&run(&plain, &plain_dir, &[]), "order 1 study");
    assert_identical(
        "error_estimate_count without estimates",
        &stat(&plain_dir, "error_estimate_count").1,
        &[0.0; 3],
    );
}

/// A rerun into a directory that holds a complete study, killed, is finished by --resume from
/// its own chunks (not refused as "a different study" because of the earlier one).
#[test]
fn resume_finishes_an_interrupted_rerun_over_an_earlier_study() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("o");
    assert_success(&run(&data("study_basic.toml"), &dir, &[]), "earlier study");
    let scene = data("study_resume.toml");
    kill_after_checkpoint(&scene, &dir, Duration::from_millis(20));
    assert_eq!(
        manifest(&dir)["kind"],
        "ensemble",
        "the earlier study stays until the rerun is done"
    );
    let resumed = run(&scene, &dir, &["--resume"]);
    assert_success(&resumed, "resume of the rerun");
    assert!(manifest(&dir)["chunks_reused"].as_u64().unwrap() >= 1);
    assert_eq!(manifest(&dir)["members_total"], 2000);
}

/// A forcing that is not finite at t = 0 at one sweep point fails that point's members, each with
/// its reason, and the study completes (a single run of such a scene is refused instead): point 0
/// (a = 0: 1/t) fails both its members, point 1 (a = 1) completes.
#[test]
fn a_forcing_infinite_at_one_sweep_point_fails_its_members_not_the_study() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = scene_variant(
        "study_basic.toml",
        &[
            (
                "gamma = 1.0",
                "gamma = 1.0\nforcing = \"1/(t + a)\"\n\n[parameters]\na = 0.5",
            ),
            ("members = 96", "members = 2"),
            ("chunk = 16", "chunk = 2"),
            ("roughness = { kind = \"lognormal\", spread = 0.3 }\n", ""),
            ("jitter = 0.05", "jitter = 0.0\n\n[sweep]\na = [0.0, 1.0]"),
        ],
        tmp.path(),
        "forced.toml",
    );
    let out = tmp.path().join("out");
    let o = run(&scene, &out, &[]);
    assert_success(&o, "the study");
    let man = manifest(&out);
    assert_eq!(man["failed_members"], serde_json::json!([0, 1]), "{man}");
    let (header, rows) = members_csv(&out);
    let reason = column(&header, "failure_reason");
    assert!(
        rows[0][reason].contains("forcing is not finite at t = 0"),
        "{:?}",
        rows[0][reason]
    );
    assert_eq!(rows[2][column(&header, "status")], "ok");
}

/// A study rerun killed between the two renames of its commit (the earlier study moved aside,
/// the finished rerun not yet in place) is repaired by --resume as by a plain run: the finished
/// rerun is put in place, and nothing is left beside --out.
#[test]
fn resume_repairs_a_commit_killed_between_its_renames() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("o");
    assert_success(&run(&data("study_basic.toml"), &dir, &[]), "earlier study");
    let scene = data("study_resume.toml");
    let finished = tmp.path().join("finished");
    assert_success(&run(&scene, &finished, &[]), "the rerun, finished");
    // The kill: the earlier study renamed aside, the rerun still under its staging name, of a
    // dead process (a PID larger than any Linux pid_max).
    std::fs::rename(&dir, tmp.path().join(".o.old-99999998")).unwrap();
    std::fs::rename(&finished, tmp.path().join(".o.partial-99999998")).unwrap();
    let resumed = run(&scene, &dir, &["--resume"]);
    assert_success(&resumed, "resume");
    let stderr = String::from_utf8_lossy(&resumed.stderr);
    assert!(stderr.contains("the finished run"), "{stderr}");
    assert_eq!(manifest(&dir)["members_total"], 2000);
    let beside = common::names_starting_with(tmp.path(), ".o.");
    assert!(beside.is_empty(), "left beside --out: {beside:?}");
}
