//! Fuzz-style robustness of the command line against bad input (issue 9): several hundred mutants
//! of the test scenes and of a particle file (random byte edits, deleted and repeated lines, and
//! numbers replaced by extreme or ill-typed values) are run through `roughlub run`.
//!
//! Expected of every mutant, independent of what the mutation hit:
//! - the process never panics (exit status 101, "panicked" on stderr) and never dies of a signal
//!   it did not get from the test;
//! - a refused input exits with status 2, prints an `error:` line and leaves no output directory
//!   and no manifest (nothing that looks like a complete run);
//! - an accepted input exits with status 0 and leaves a manifest.
//!
//! A mutant that runs longer than `TIME_LIMIT` (e.g. `end` raised by orders of magnitude) is
//! killed; it must not have written a manifest either. The mutants are a pure function of
//! `SEED`, so a failure names a reproducible case (its text is printed).

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_roughlub");
const SEED: u64 = 0x5eed_2026_1123;
const MUTANTS_PER_BASE: usize = 150;
const TIME_LIMIT: Duration = Duration::from_secs(8);

/// splitmix64: a small deterministic generator, enough for choosing mutations.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// Values a number in a scene or particle file is replaced by: out of range, non-finite,
/// subnormal, huge, fractional where an integer is expected, and not a number at all.
const REPLACEMENTS: &[&str] = &[
    "0",
    "-1",
    "-0.0",
    "1",
    "2.5",
    "0.999999",
    "1e308",
    "-1e308",
    "1e-320",
    "nan",
    "inf",
    "-inf",
    "1000000000",
    "99999999999999999999",
    "1e3",
    "\"x\"",
    "[]",
    "",
    "0x10",
    "1e",
    "--1",
];

/// Bytes a random byte is replaced by: TOML and CSV syntax, digits, letters, and invalid UTF-8.
const BYTES: &[u8] = b"=\"'[]{},.#\n-+e0123456789x \t\xff";

/// Byte ranges of the numbers in `text` (a digit, optionally led by a sign or a dot, and the
/// digits, dots, exponent markers and signs that follow).
fn number_spans(text: &[u8]) -> Vec<(usize, usize)> {
    let mut spans = Vec::new();
    let mut i = 0;
    while i < text.len() {
        if text[i].is_ascii_digit() && (i == 0 || !text[i - 1].is_ascii_alphabetic()) {
            let start = if i > 0 && (text[i - 1] == b'-' || text[i - 1] == b'.') {
                i - 1
            } else {
                i
            };
            let mut end = i;
            while end < text.len()
                && (text[end].is_ascii_digit()
                    || matches!(text[end], b'.' | b'e' | b'E')
                    || (matches!(text[end], b'-' | b'+') && matches!(text[end - 1], b'e' | b'E')))
            {
                end += 1;
            }
            spans.push((start, end));
            i = end;
        } else {
            i += 1;
        }
    }
    spans
}

/// One random mutation of `text`, and a short description of it.
fn mutate(text: &[u8], rng: &mut Rng) -> (Vec<u8>, String) {
    let mut out = text.to_vec();
    let lines: Vec<(usize, usize)> = {
        let mut v = Vec::new();
        let mut start = 0;
        for (i, &b) in text.iter().enumerate() {
            if b == b'\n' {
                v.push((start, i + 1));
                start = i + 1;
            }
        }
        if start < text.len() {
            v.push((start, text.len()));
        }
        v
    };
    match rng.below(6) {
        0 | 1 => {
            let spans = number_spans(text);
            if spans.is_empty() {
                return (out, "unchanged".into());
            }
            let (a, b) = spans[rng.below(spans.len())];
            let value = REPLACEMENTS[rng.below(REPLACEMENTS.len())];
            out.splice(a..b, value.bytes());
            (
                out,
                format!(
                    "number {:?} -> {value:?}",
                    String::from_utf8_lossy(&text[a..b])
                ),
            )
        }
        2 => {
            let at = rng.below(out.len());
            let byte = BYTES[rng.below(BYTES.len())];
            out[at] = byte;
            (out, format!("byte {at} -> {byte:#04x}"))
        }
        3 => {
            let at = rng.below(out.len());
            let len = 1 + rng.below(5);
            let end = (at + len).min(out.len());
            out.drain(at..end);
            (out, format!("bytes {at}..{end} deleted"))
        }
        4 => {
            let (a, b) = lines[rng.below(lines.len())];
            let line = text[a..b].to_vec();
            out.splice(b..b, line);
            (out, format!("line at byte {a} repeated"))
        }
        _ => {
            let (a, b) = lines[rng.below(lines.len())];
            out.drain(a..b);
            (out, format!("line at byte {a} deleted"))
        }
    }
}

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests")
        .join("data")
        .join(name)
}

/// What happened to one mutant; `Err` says what went wrong.
fn check_one(scene: &Path, out_dir: &Path) -> Result<&'static str, String> {
    let mut child = Command::new(BIN)
        .arg("run")
        .arg(scene)
        .arg("--out")
        .arg(out_dir)
        .arg("--quiet")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| format!("cannot start roughlub: {e}"))?;
    let started = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().map_err(|e| e.to_string())? {
            break Some(status);
        }
        if started.elapsed() > TIME_LIMIT {
            child.kill().ok();
            child.wait().ok();
            break None;
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    let mut stderr = String::new();
    if let Some(mut pipe) = child.stderr.take() {
        use std::io::Read;
        let mut bytes = Vec::new();
        pipe.read_to_end(&mut bytes).ok();
        stderr = String::from_utf8_lossy(&bytes).into_owned();
    }
    let manifest = out_dir.join("manifest.json").exists();
    let Some(status) = status else {
        return if manifest {
            Err("killed after the time limit, but a manifest exists".into())
        } else {
            Ok("timed out (killed; no manifest)")
        };
    };
    if stderr.contains("panicked") {
        return Err(format!("panicked: {stderr}"));
    }
    match status.code() {
        Some(0) if manifest => Ok("accepted"),
        Some(0) => Err(format!("exit 0 without a manifest; stderr: {stderr}")),
        Some(2) => {
            if !stderr.contains("error: ") {
                Err(format!("exit 2 without an error line; stderr: {stderr}"))
            } else if manifest || out_dir.exists() {
                Err(format!(
                    "refused ({}), but it left {}",
                    stderr.trim(),
                    if manifest {
                        "a manifest"
                    } else {
                        "an output directory"
                    }
                ))
            } else {
                Ok("refused")
            }
        }
        code => Err(format!("exit status {code:?}; stderr: {stderr}")),
    }
}

/// Runs `count` mutants of the file `mutated` (the scene, or a file it reads; `companions` are the
/// other files it reads), two at a time; returns the tally of outcomes and panics listing every
/// mutant that broke a rule.
fn fuzz(
    scene: &str,
    mutated: &str,
    companions: &[&str],
    count: usize,
    seed: u64,
) -> Vec<(&'static str, usize)> {
    let original = std::fs::read(data(mutated)).unwrap();
    let mut rng = Rng(seed);
    let mutants: Vec<(Vec<u8>, String)> = (0..count)
        .map(|_| {
            // One to three mutations on top of each other.
            let mut text = original.clone();
            let mut what = Vec::new();
            for _ in 0..1 + rng.below(3) {
                let (t, w) = mutate(&text, &mut rng);
                text = t;
                what.push(w);
            }
            (text, what.join("; "))
        })
        .collect();
    let tmp = tempfile::tempdir().unwrap();
    let results: Vec<(usize, Result<&'static str, String>)> = std::thread::scope(|s| {
        let workers: Vec<_> = (0..2)
            .map(|w| {
                let mutants = &mutants;
                let tmp = tmp.path();
                s.spawn(move || {
                    let mut results = Vec::new();
                    for (k, (text, _)) in mutants.iter().enumerate().skip(w).step_by(2) {
                        let case = tmp.join(format!("case{k}"));
                        std::fs::create_dir_all(&case).unwrap();
                        for file in companions.iter().copied().chain([scene, mutated]) {
                            std::fs::copy(data(file), case.join(file)).unwrap();
                        }
                        std::fs::write(case.join(mutated), text).unwrap();
                        let outcome = check_one(&case.join(scene), &case.join("out"));
                        results.push((k, outcome));
                    }
                    results
                })
            })
            .collect();
        workers
            .into_iter()
            .flat_map(|w| w.join().unwrap())
            .collect()
    });
    let mut tally: Vec<(&'static str, usize)> = Vec::new();
    let mut broken = Vec::new();
    for (k, outcome) in results {
        match outcome {
            Ok(kind) => match tally.iter_mut().find(|(n, _)| *n == kind) {
                Some((_, c)) => *c += 1,
                None => tally.push((kind, 1)),
            },
            Err(e) => broken.push(format!(
                "mutant {k} of {mutated} ({}):\n{}\n--> {e}",
                mutants[k].1,
                String::from_utf8_lossy(&mutants[k].0)
            )),
        }
    }
    eprintln!("{mutated}: {tally:?}");
    assert!(
        broken.is_empty(),
        "{} of {count} mutants broke a rule:\n\n{}",
        broken.len(),
        broken.join("\n\n")
    );
    tally
}

/// The refusals must be a real share of the mutants (else the mutations miss the input), and
/// some mutants must still be accepted (else every run fails for a reason unrelated to them).
fn assert_mixed(tally: &[(&str, usize)], what: &str) {
    let count = |kind: &str| {
        tally
            .iter()
            .find(|(n, _)| *n == kind)
            .map_or(0, |(_, c)| *c)
    };
    assert!(
        count("refused") >= 10,
        "{what}: too few refusals: {tally:?}"
    );
    assert!(
        count("accepted") >= 5,
        "{what}: too few accepted: {tally:?}"
    );
}

#[test]
fn mutated_scenes_are_refused_cleanly_or_run() {
    let tally = fuzz(
        "validation_base.toml",
        "validation_base.toml",
        &[],
        MUTANTS_PER_BASE,
        SEED,
    );
    assert_mixed(&tally, "validation_base.toml");
}

#[test]
fn mutated_particle_scenes_are_refused_cleanly_or_run() {
    let tally = fuzz(
        "cluster.toml",
        "cluster.toml",
        &["cluster.csv"],
        MUTANTS_PER_BASE,
        SEED ^ 1,
    );
    assert_mixed(&tally, "cluster.toml");
}

#[test]
fn mutated_particle_files_are_refused_cleanly_or_run() {
    let tally = fuzz(
        "cluster.toml",
        "cluster.csv",
        &[],
        MUTANTS_PER_BASE,
        SEED ^ 2,
    );
    assert_mixed(&tally, "cluster.csv");
}

#[test]
fn mutated_ensemble_scenes_are_refused_cleanly_or_run() {
    let tally = fuzz(
        "study_basic.toml",
        "study_basic.toml",
        &[],
        MUTANTS_PER_BASE,
        SEED ^ 3,
    );
    assert_mixed(&tally, "study_basic.toml");
}

#[test]
fn mutated_parameter_studies_are_refused_cleanly_or_run() {
    let tally = fuzz(
        "study_sweep.toml",
        "study_sweep.toml",
        &[],
        MUTANTS_PER_BASE,
        SEED ^ 4,
    );
    assert_mixed(&tally, "study_sweep.toml");
}
