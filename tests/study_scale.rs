//! Studies that scale with their points (issue 23), through the `roughlub` command:
//!
//! 1. a Sobol design of thousands of points x 1 member runs in bounded memory and disk, keeps
//!    per-time statistics for its first points only and every point's responses;
//! 2. `[output] fields` decides which field bands are accumulated;
//! 3. the state files are binary, merge exactly, and a study directory of the old (JSON) format
//!    is refused by name;
//! 4. a study whose memory estimate exceeds the limit is refused with the settings that drive it.
//! 5. a design with every point detailed keeps each one-member band at what it holds.
//!
//! The peak memory of a run is the child's own `ru_maxrss` (wait4), so this file holds the only
//! tests that measure it and each spawns its own child.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_roughlub");

/// A small chain (N = 30, three outputs) with lognormal roughness; `{ensemble}` and `{extra}`
/// complete it.
fn scene_text(ensemble: &str, extra: &str) -> String {
    format!(
        r#"
name = "scale"
[parameters]
A = 0.5
[model]
particles = 30
mu = 0.01
gamma = 2.0
[initial]
rho = "0.7"
velocity = "A*sin(2*pi*x)"
rho_star = "0.7"
[time]
end = 0.02
outputs = 3
dt = 1e-3
[solver]
backend = "cpu"
[output]
plots = false
{extra}
[ensemble]
seed = 5
roughness = {{ kind = "lognormal", spread = 0.3 }}
{ensemble}
"#
    )
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

/// Runs `roughlub args...`; returns its output and its peak resident memory in bytes.
fn roughlub_measured(args: &[&str]) -> (Output, u64) {
    let child = Command::new(BIN)
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let pid = child.id() as libc::pid_t;
    // Read the pipes on threads so that the child never blocks on a full pipe.
    let mut child = child;
    let mut out_pipe = child.stdout.take().unwrap();
    let mut err_pipe = child.stderr.take().unwrap();
    let out_reader = std::thread::spawn(move || {
        let mut v = Vec::new();
        std::io::Read::read_to_end(&mut out_pipe, &mut v).unwrap();
        v
    });
    let err_reader = std::thread::spawn(move || {
        let mut v = Vec::new();
        std::io::Read::read_to_end(&mut err_pipe, &mut v).unwrap();
        v
    });
    let mut status: libc::c_int = 0;
    // SAFETY: an all-zero rusage is a valid value; wait4 fills it for our own child.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let waited = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
    assert_eq!(waited, pid, "wait4 failed");
    let code = if libc::WIFEXITED(status) {
        libc::WEXITSTATUS(status)
    } else {
        -1
    };
    let output = Output {
        status: std::os::unix::process::ExitStatusExt::from_raw(if code >= 0 {
            code << 8
        } else {
            status
        }),
        stdout: out_reader.join().unwrap(),
        stderr: err_reader.join().unwrap(),
    };
    // ru_maxrss is in KiB on Linux.
    (output, usage.ru_maxrss as u64 * 1024)
}

/// `roughlub run SCENE --out OUT --quiet`, with its peak resident memory in bytes.
fn run_study_measured(scene: &Path, out: &Path) -> (Output, u64) {
    roughlub_measured(&[
        "run",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ])
}

/// A sampled `[sweep]` of `points` points over mu (log scale) and A.
fn sampled_sweep(design: &str, points: u64, seed: u64) -> String {
    format!(
        "[sweep]\ndesign = \"{design}\"\npoints = {points}\nseed = {seed}\nmu = {{ min = 0.005, max = 0.05, scale = \"log\" }}\nA = {{ min = 0.2, max = 0.8 }}\n"
    )
}

fn roughlub(args: &[&str]) -> Output {
    Command::new(BIN).args(args).output().unwrap()
}

fn run_study(scene: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "run",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    roughlub(&args)
}

fn assert_success(o: &Output, what: &str) {
    assert!(
        o.status.success(),
        "{what} failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

fn npy(path: &Path) -> (Vec<u64>, Vec<f64>) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{path:?}: {e}"));
    let npy = npyz::NpyFile::new(&bytes[..]).unwrap();
    let shape = npy.shape().to_vec();
    (shape, npy.into_vec::<f64>().unwrap())
}

fn dir_bytes(dir: &Path) -> u64 {
    let mut total = 0;
    for entry in std::fs::read_dir(dir).unwrap() {
        let entry = entry.unwrap();
        let meta = entry.metadata().unwrap();
        total += if meta.is_dir() {
            dir_bytes(&entry.path())
        } else {
            meta.len()
        };
    }
    total
}

fn manifest(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("manifest.json")).unwrap()).unwrap()
}

/// 1. A Sobol design of 3000 points x 1 member: bounded memory and disk, no per-time statistics
///    (a point of one member has none by default), responses for all, one row per member and
///    per point. With several members a point, the first 4 points keep per-time statistics.
#[test]
fn a_sampled_design_of_thousands_of_points_runs_in_bounded_memory() {
    let tmp = tempfile::tempdir().unwrap();
    let points = 3000u64;
    let text = scene_text(
        "members = 1\nchunk = 512",
        &sampled_sweep("sobol", points, 2),
    );
    let scene = write(tmp.path(), "sobol.toml", &text);
    let out = tmp.path().join("sobol");
    let (o, peak) = run_study_measured(&scene, &out);
    assert_success(&o, "sobol design");
    let disk = dir_bytes(&out);
    eprintln!(
        "{points} points x 1 member: peak memory {:.1} MB, {:.2} MB on disk",
        peak as f64 / 1e6,
        disk as f64 / 1e6
    );
    // Before the change this design held ~40 MB of statistics per point (> 100 GB here).
    // 200 MB bounds it with room for the binary, its libraries and one chunk.
    assert!(peak < 200_000_000, "peak memory {peak} B");
    // 3000 points: members.csv and points.csv rows, per-point responses.
    assert!(disk < 20_000_000, "{disk} B on disk");

    let (shape, detailed) = npy(&out.join("stats/detailed_points.npy"));
    assert_eq!(shape, [0], "no detailed point with one member a point");
    assert!(detailed.is_empty());
    for file in ["rho_mean.npy", "u_quantiles.npy", "max_density_mean.npy"] {
        assert!(
            !out.join("stats").join(file).exists(),
            "{file}: per-time statistics of no point are not written"
        );
    }
    let (shape, peak_density) = npy(&out.join("stats/peak_density.npy"));
    assert_eq!(shape, [points, 5], "responses for every point");
    // One member per point: its count is 1 and its mean is its own peak density.
    let csv = std::fs::read_to_string(out.join("members.csv")).unwrap();
    let mut lines = csv.lines();
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    let c_peak = head.iter().position(|h| *h == "peak_density").unwrap();
    let c_point = head.iter().position(|h| *h == "sweep_point").unwrap();
    let mut rows = 0;
    for line in lines {
        let r: Vec<&str> = line.split(',').collect();
        let p: usize = r[c_point].parse().unwrap();
        let v: f64 = r[c_peak].parse().unwrap();
        assert_eq!(peak_density[5 * p], 1.0);
        assert_eq!(peak_density[5 * p + 1].to_bits(), v.to_bits(), "point {p}");
        rows += 1;
    }
    assert_eq!(rows, points);
    let m = manifest(&out);
    assert_eq!(m["detailed_points"], 0);
    assert!(
        !out.join("chunks").exists(),
        "a complete study keeps no chunk files"
    );
    // The estimates made before the run: memory within a factor 2 of the peak (which includes
    // the binary and its libraries; at 4 KiB a summary whatever the members, it was 11 times
    // the peak on such designs), disk within 2 times what it wrote.
    let estimate = m["memory_estimate_bytes"].as_u64().unwrap();
    let disk_estimate = m["disk_estimate_bytes"].as_u64().unwrap();
    eprintln!(
        "estimates: memory {:.1} MB, disk {:.2} MB",
        estimate as f64 / 1e6,
        disk_estimate as f64 / 1e6
    );
    assert!(
        estimate < m["memory_limit_bytes"].as_u64().unwrap(),
        "estimate {estimate}"
    );
    let ratio = estimate as f64 / peak as f64;
    assert!(
        (0.5..=2.0).contains(&ratio),
        "memory estimate / peak = {ratio:.2}"
    );
    let ratio = disk_estimate as f64 / disk as f64;
    assert!(
        (0.5..=2.0).contains(&ratio),
        "disk estimate / written = {ratio:.2}"
    );
}

/// 1b. Points of several members: the first 4 of a sampled design keep per-time statistics and
///     field bands by default (bands of 2 members, the rest responses only).
#[test]
fn a_sampled_design_of_several_members_a_point_details_its_first_four() {
    let tmp = tempfile::tempdir().unwrap();
    let text = scene_text("members = 2", &sampled_sweep("random", 6, 4));
    let scene = write(tmp.path(), "random.toml", &text);
    let out = tmp.path().join("random");
    let o = run_study(&scene, &out, &[]);
    assert_success(&o, "random design of 2 members a point");
    let (shape, detailed) = npy(&out.join("stats/detailed_points.npy"));
    assert_eq!(shape, [4]);
    assert_eq!(detailed, [0.0, 1.0, 2.0, 3.0]);
    let (shape, counts) = npy(&out.join("stats/max_density_count.npy"));
    assert_eq!(
        shape[0], 4,
        "per-time statistics for the detailed points only"
    );
    assert!(counts.iter().all(|&c| c == 2.0), "each holds its 2 members");
    let (shape, _) = npy(&out.join("stats/rho_mean.npy"));
    assert_eq!(shape[0], 4, "field bands for the detailed points only");
    let (shape, _) = npy(&out.join("stats/peak_density.npy"));
    assert_eq!(shape[0], 6, "responses for every point");
}

/// 2. `[output] fields` decides the bands: with fields = ["energy"] no band is accumulated or
///    written, and the scalar statistics are those of the default study, bit for bit.
#[test]
fn output_fields_decide_which_bands_are_kept() {
    let tmp = tempfile::tempdir().unwrap();
    let all = write(
        tmp.path(),
        "all.toml",
        &scene_text("members = 40\nchunk = 16", ""),
    );
    let energy = write(
        tmp.path(),
        "energy.toml",
        &scene_text("members = 40\nchunk = 16", "fields = [\"energy\"]"),
    );
    let (a, e) = (tmp.path().join("all"), tmp.path().join("energy"));
    assert_success(&run_study(&all, &a, &[]), "default fields");
    assert_success(&run_study(&energy, &e, &[]), "fields = energy");
    for f in ["rho", "u", "rho_star"] {
        assert!(a.join(format!("stats/{f}_mean.npy")).is_file());
        assert!(
            !e.join(format!("stats/{f}_mean.npy")).exists(),
            "{f} band written though not asked for"
        );
    }
    assert_eq!(manifest(&e)["band_fields"], serde_json::json!([]));
    for name in [
        "max_density_quantiles",
        "min_gap_mean",
        "energy_mean",
        "peak_density",
        "first_hit",
        "smallest_gap",
        "final_energy",
    ] {
        let file = format!("stats/{name}.npy");
        let (x, y) = (npy(&a.join(&file)).1, npy(&e.join(&file)).1);
        assert_eq!(
            x.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            y.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            "{name}"
        );
    }
    assert!(
        dir_bytes(&e) < dir_bytes(&a),
        "fewer fields must cost less disk"
    );
}

/// 3. The state files are binary (magic line, format 3, a CRC-32 at the end); a damaged one is
///    refused naming it, one of format 2 (no checksum) is still read, and a study directory of
///    roughlub 0.1 (partial.json) is refused by `merge` and `--resume` with the version named.
#[test]
fn state_files_are_binary_and_old_directories_are_refused_by_name() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = write(
        tmp.path(),
        "s.toml",
        &scene_text("members = 20\nchunk = 8", ""),
    );
    let dir = tmp.path().join("s");
    assert_success(&run_study(&scene, &dir, &[]), "study");
    let bytes = std::fs::read(dir.join("partial.state")).unwrap();
    assert_eq!(&bytes[..8], b"RLSTATE\n");
    assert_eq!(u32::from_le_bytes(bytes[8..12].try_into().unwrap()), 3);
    let merge_into = |name: &str| {
        let out = tmp.path().join(name);
        let o = roughlub(&[
            "merge",
            dir.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        (o, out)
    };
    let (o, whole) = merge_into("whole");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    // One bit flipped anywhere after the header (a statistic, a count, the checksum itself).
    for at in [
        12,
        bytes.len() / 3,
        bytes.len() / 2,
        bytes.len() - 5,
        bytes.len() - 1,
    ] {
        let mut damaged = bytes.clone();
        damaged[at] ^= 0x10;
        std::fs::write(dir.join("partial.state"), &damaged).unwrap();
        let (o, out) = merge_into(&format!("damaged_{at}"));
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "byte {at}: {err}");
        assert!(
            err.contains("partial.state") && err.contains("damaged"),
            "{err}"
        );
        assert!(!out.exists(), "byte {at}");
    }
    // Format 2: the same bytes without the checksum.
    let mut unchecked = bytes[..bytes.len() - 4].to_vec();
    unchecked[8..12].copy_from_slice(&2u32.to_le_bytes());
    std::fs::write(dir.join("partial.state"), &unchecked).unwrap();
    let (o, from_format_2) = merge_into("from_format_2");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for file in ["stats/rho_mean.npy", "stats/peak_density.npy"] {
        assert_eq!(
            std::fs::read(whole.join(file)).unwrap(),
            std::fs::read(from_format_2.join(file)).unwrap(),
            "{file}"
        );
    }
    std::fs::write(dir.join("partial.state"), &bytes).unwrap();

    // An old directory: partial.json instead of partial.state.
    std::fs::rename(dir.join("partial.state"), dir.join("partial.json")).unwrap();
    let merged = tmp.path().join("merged");
    let o = roughlub(&[
        "merge",
        dir.to_str().unwrap(),
        "--out",
        merged.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "merge of an old directory succeeded");
    assert!(
        err.contains("roughlub 0.1") && err.contains("state format 1"),
        "{err}"
    );
    assert!(!merged.exists());
    let o = run_study(&scene, &dir, &["--resume"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(err.contains("state format 1"), "{err}");
}

/// 4. A study whose estimated memory exceeds half the machine's is refused before it starts,
///    with the settings that drive it and what to change; nothing is written.
#[test]
fn a_study_too_large_for_memory_is_refused_with_its_drivers() {
    let tmp = tempfile::tempdir().unwrap();
    // 10^6 grid points x 402 slots x 3 fields x 3 times x 64 points of a grid design: ~1 TB
    // (200 members a point, more than a band holds before it counts them into slots).
    let text = scene_text(
        "members = 200\nbins = 400",
        "grid = 1000000\n[sweep]\nA = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8]\nmu = [0.01, 0.02, 0.03, 0.04, 0.05, 0.06, 0.07, 0.08]\n",
    );
    let scene = write(tmp.path(), "huge.toml", &text);
    let out = tmp.path().join("huge");
    let (o, peak) = roughlub_measured(&[
        "run",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    for needle in [
        "ensemble (memory)",
        "detailed points",
        "bins",
        "grid",
        "half this machine's memory",
        "ensemble.detailed_points",
        "--allow-large",
    ] {
        assert!(err.contains(needle), "`{needle}` missing from: {err}");
    }
    assert!(!out.exists(), "a refused study wrote {out:?}");
    assert!(peak < 500_000_000, "the refusal itself used {peak} B");
}

/// 4b. A study whose outputs would exceed the run's size limit (21.5 GB) is refused before it
///     starts, naming what drives them; nothing is written. 1000 members keeping their arrays
///     (store_members) of N = 10000 at 1000 output times: (2 x 10000 + 200) x 8 B x 1000 each,
///     162 GB in all, which a study used to start writing without a word.
#[test]
fn a_study_too_large_for_disk_is_refused_with_its_drivers() {
    let tmp = tempfile::tempdir().unwrap();
    // One member a chunk: its kept arrays (2 x 162 MB) keep the memory estimate far below any
    // machine's limit, so that the disk's is what refuses it.
    let text = scene_text("members = 1000\nchunk = 1\nstore_members = true", "")
        .replace("particles = 30", "particles = 10000")
        .replace("outputs = 3", "outputs = 1000")
        .replace("end = 0.02", "end = 1.0");
    let scene = write(tmp.path(), "disk.toml", &text);
    let out = tmp.path().join("disk");
    let o = run_study(&scene, &out, &[]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    let gb = 1000.0 * (2.0 * 10000.0 + 200.0) * 8.0 * 1000.0 / 1e9;
    let estimated: f64 = err
        .split("ensemble (disk) = ")
        .nth(1)
        .and_then(|rest| rest.split(" GB").next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no size in: {err}"));
    assert!(
        (gb..gb * 1.05).contains(&estimated),
        "{estimated} GB against the arrays' {gb} GB"
    );
    for needle in ["store_members", "--allow-large", "21.5 GB"] {
        assert!(err.contains(needle), "`{needle}` missing from: {err}");
    }
    assert!(!out.exists(), "a refused study wrote {out:?}");
}

/// 5. Per-time statistics for every point of a sampled design (400 points of one member, each
///    detailed): each point's field bands hold its one member's slots, not 402 counters a grid
///    point, so the study stays far below what counted slots would take (3 fields x 3 times x
///    200 points x 402 x 4 B = 2.9 MB a point, 1.2 GB in all), and a band of one member reads
///    back as that member: every quantile level in the same bin, within half a bin of its mean.
#[test]
fn every_point_of_a_design_detailed_stays_small() {
    let tmp = tempfile::tempdir().unwrap();
    let points = 400u64;
    let text = scene_text(
        &format!("members = 1\nchunk = 128\ndetailed_points = {points}"),
        &sampled_sweep("random", points, 4),
    );
    let scene = write(tmp.path(), "detailed.toml", &text);
    let out = tmp.path().join("detailed");
    let (o, peak) = run_study_measured(&scene, &out);
    assert_success(&o, "design with every point detailed");
    let estimate = manifest(&out)["memory_estimate_bytes"].as_u64().unwrap();
    eprintln!(
        "{points} detailed points of one member: peak memory {:.1} MB, estimate {:.1} MB",
        peak as f64 / 1e6,
        estimate as f64 / 1e6
    );
    assert!(peak < 400_000_000, "peak memory {peak} B");
    assert!(estimate < 600_000_000, "estimate {estimate} B");

    let (shape, quantiles) = npy(&out.join("stats/rho_quantiles.npy"));
    let (t, q, g) = (shape[1] as usize, shape[2] as usize, shape[3] as usize);
    assert_eq!((shape[0], t, g), (points, 3, 200));
    let (_, mean) = npy(&out.join("stats/rho_mean.npy"));
    // rho's bins: 400 on [0, 1].
    let half_bin = 0.5 / 400.0;
    for p in 0..points as usize {
        for k in 0..t {
            for j in 0..g {
                let m = mean[(p * t + k) * g + j];
                let first = quantiles[((p * t + k) * q) * g + j];
                assert!(
                    (first - m).abs() <= half_bin + 1e-15,
                    "point {p}, time {k}, x {j}"
                );
                for level in 1..q {
                    let v = quantiles[((p * t + k) * q + level) * g + j];
                    assert_eq!(v.to_bits(), first.to_bits(), "point {p}, level {level}");
                }
            }
        }
    }
}
