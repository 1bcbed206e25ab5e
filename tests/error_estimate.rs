//! Order 1 with fixed steps estimates its own error (issue 22, item 3): a companion at 4 dt (or
//! finer, where dt reaches an output interval) runs beside the run and their difference, scaled
//! by their step counts (|y(dt) - y(4 dt)| / 3 where both take whole steps), estimates the run's
//! global error. Checked against
//! the error measured from a converged reference (order 1 at dt = 2e-6), in the
//! estimate's norm (ln d on gaps, |du| / (1 + |u|) on velocities), on a smooth scene and on a
//! near-contact one, where dt = 1e-3 is far from converged and the run must say so.

use std::path::{Path, PathBuf};
use std::process::Command;

use roughlub::backend::{select, Backend, Precision};
use roughlub::model::params::Stepping;
use roughlub::model::plan::Plan;
use roughlub::scene::Scene;
use serde_json::Value;

const BIN: &str = env!("CARGO_BIN_EXE_roughlub");

/// Paper case 1 (rho0 = rho*0 = 0.7, u0 = 0.5 sin 2 pi x, mu 0.01, gamma 2) to t = 0.1.
fn smooth(dt: f64) -> String {
    scene("0.7", "0.7", "0.5", 0.01, 2.0, 0.1, dt, "")
}

/// Near contact: rho0 = 0.99, rho*0 = 0.995, u0 = 2 sin 2 pi x, mu 1e-3, gamma 1, to t = 0.2
/// (the smallest gap reaches ln d ~ -614).
fn near_contact(extra_solver: &str) -> String {
    scene("0.99", "0.995", "2", 1e-3, 1.0, 0.2, 1e-3, extra_solver)
}

#[allow(clippy::too_many_arguments)]
fn scene(
    rho: &str,
    rho_star: &str,
    amplitude: &str,
    mu: f64,
    gamma: f64,
    end: f64,
    dt: f64,
    extra_solver: &str,
) -> String {
    format!(
        r#"
name = "estimate"
[model]
particles = 40
mu = {mu}
gamma = {gamma}
[initial]
rho = "{rho}"
velocity = "{amplitude}*sin(2*pi*x)"
rho_star = "{rho_star}"
[time]
end = {end}
outputs = 3
dt = {dt}
[solver]
order = 1
backend = "cpu"
{extra_solver}
[output]
grid = 20
plots = false
"#
    )
}

/// (the run's largest reported estimate at the end, its error against the reference) for the
/// scene text `text`.
fn estimate_and_error(text: &str) -> (f64, f64) {
    let scene = Scene::from_toml(text, Path::new("estimate.toml")).expect("valid scene");
    let chain = scene.initial_chain().expect("initial chain");
    let plan = scene.plan(&chain, scene.precision);
    let members = plan.members.len();
    let engine = select(Backend::Cpu, Precision::F64, &plan).unwrap();
    let last = |plan: Plan| {
        let mut with_state = plan;
        with_state.fields.gaps = true;
        with_state.fields.velocities = true;
        let mut solver = engine
            .solver(with_state, vec![chain.clone(); members])
            .unwrap();
        let mut last = None;
        while let Some(s) = solver.next_output(&|_| {}).unwrap() {
            last = Some(s);
        }
        (last.unwrap(), solver.reports())
    };
    let (run, reports) = last(plan.clone());
    // Order 1 at 2e-6: its own error is ~500 times below that of the runs checked (dt >= 1e-3
    // in the near-contact case, where order 4 adaptive at tight tolerances can collapse its step).
    let mut reference_plan = plan.clone();
    reference_plan.companion_estimate = false;
    reference_plan.stepping = Stepping::Fixed {
        dt: 2e-6,
        dt_min: 1e-14,
    };
    let (reference, _) = last(reference_plan);
    let mut estimate = 0.0f64;
    let mut error = 0.0f64;
    for m in 0..members {
        let e = reports[m].error_estimate.as_ref().expect("an estimate");
        estimate = estimate.max(*e.last().unwrap());
        for (a, b) in run[m].gaps.iter().zip(&reference[m].gaps) {
            error = error.max((a.ln() - b.ln()).abs());
        }
        for (a, b) in run[m].velocities.iter().zip(&reference[m].velocities) {
            error = error.max((a - b).abs() / (1.0 + b.abs()));
        }
    }
    (estimate, error)
}

/// `roughlub run` of the scene `text` (written to `dir/name.toml`) into `dir/name`, quiet, with
/// `extra` arguments; asserts success. (its output directory, stderr, manifest).
fn run_cli(dir: &Path, name: &str, text: &str, extra: &[&str]) -> (PathBuf, String, Value) {
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, text).unwrap();
    let out_dir = dir.join(name);
    let out = Command::new(BIN)
        .arg("run")
        .arg(&path)
        .arg("--out")
        .arg(&out_dir)
        .arg("--quiet")
        .args(extra)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{stderr}");
    let manifest =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("manifest.json")).unwrap())
            .unwrap();
    (out_dir, stderr, manifest)
}

/// The estimate of the smooth scene at `dt`, held within a factor 2 of its measured error.
fn smooth_estimate_within_twice_its_error(dt: f64) -> f64 {
    let (estimate, error) = estimate_and_error(&smooth(dt));
    let ratio = estimate / error;
    eprintln!("dt {dt:e}: estimate {estimate:.3e}, error {error:.3e}, ratio {ratio:.2}");
    assert!(
        (0.5..=2.0).contains(&ratio),
        "dt {dt:e}: estimate {estimate:e} against error {error:e}"
    );
    estimate
}

/// On a smooth scene (paper case 1, N = 40) the estimate is within a factor 2 of the measured
/// error at every dt of a ladder, and falls with dt at first order over the ladder.
#[test]
fn order_one_fixed_step_estimate_tracks_the_measured_error() {
    let ladder = [4e-3, 2e-3, 1e-3, 5e-4];
    let mut estimates = Vec::new();
    for dt in ladder {
        estimates.push(smooth_estimate_within_twice_its_error(dt));
    }
    let rate = (estimates[0] / estimates[3]).log2() / 3.0;
    eprintln!("the estimate falls at order {rate:.2} from dt 4e-3 to 5e-4");
    assert!((0.7..=1.3).contains(&rate), "order {rate:.2}, not 1");
}

/// Steps that do not divide the output interval (0.05 here), or reach it: at 4 dt the
/// companion was cut to the same intervals, took the run's own single step where dt >= 0.05 and
/// estimated 0, and where 4 dt did not fit whole the fixed divisor 3 understated the error (dt =
/// 0.01: 5 steps an interval against the companion's 2, a ratio of 2.5, not 4). The estimate,
/// from the two runs' step counts, stays within a factor 2 of the measured error (0.61 to 0.76;
/// before, 0 at dt = 0.1 and 0.05, 0.38 at 0.01), and is never 0 (2026-11-29, found by an
/// exploratory review).
#[test]
fn the_estimate_holds_where_dt_does_not_divide_the_output_interval() {
    for dt in [0.1, 0.05, 0.02, 0.015, 0.01] {
        smooth_estimate_within_twice_its_error(dt);
    }
}

/// Near contact dt = 1e-3 is far from converged: the estimate says so (within a factor 3 of the
/// measured error, itself above 0.1), and the run warns on stderr and in the manifest (fixed
/// steps warn above an estimate of 0.01).
#[test]
fn a_far_from_converged_fixed_step_run_reports_a_large_estimate_and_warns() {
    let text = near_contact("");
    let (estimate, error) = estimate_and_error(&text);
    eprintln!("near contact: estimate {estimate:.3e}, error {error:.3e}");
    assert!(error > 0.1, "the scene is not hard enough: error {error:e}");
    assert!(
        (error / 3.0..=error * 3.0).contains(&estimate),
        "estimate {estimate:e} against error {error:e}"
    );

    let tmp = tempfile::tempdir().unwrap();
    let (_, stderr, manifest) = run_cli(tmp.path(), "near_contact", &text, &[]);
    assert!(
        stderr.contains("warning: the largest error estimate"),
        "stderr: {stderr}"
    );
    let record = &manifest["error_estimate"];
    let largest = record["largest"].as_f64().unwrap();
    assert!(
        (largest - estimate).abs() <= 1e-12 * estimate,
        "manifest {largest:e} against {estimate:e}"
    );
    // The companion compares two whole runs: its warning says the results are not converged.
    assert!(record["warning"]
        .as_str()
        .is_some_and(|w| w.contains("these results are not converged")));
}

/// `[solver] error_estimate = false` turns the companion off: no estimate, no warning, and the
/// run's own results are the same to the bit.
#[test]
fn the_companion_can_be_turned_off_and_does_not_change_the_run() {
    let tmp = tempfile::tempdir().unwrap();
    let (on, _, _) = run_cli(tmp.path(), "on", &near_contact(""), &[]);
    let (off, stderr_off, manifest) = run_cli(
        tmp.path(),
        "off",
        &near_contact("error_estimate = false"),
        &[],
    );
    assert!(!stderr_off.contains("error estimate"), "{stderr_off}");
    assert!(manifest["error_estimate"]["largest"].is_null());
    assert!(manifest["error_estimate"]["method"]
        .as_str()
        .unwrap()
        .starts_with("unavailable"));
    for file in ["gaps.npy", "velocities.npy", "rho.npy"] {
        assert_eq!(
            std::fs::read(on.join(file)).unwrap(),
            std::fs::read(off.join(file)).unwrap(),
            "{file} differs with the companion on"
        );
    }
}

/// What a study records at each output (`output_status`: running or not, the last estimate) is
/// what the full reports say, at every output time, for the companion's estimate (order 1,
/// fixed steps), the controller's (order 4, adaptive) and members that fail part way (a step
/// floor the tight tolerance runs into near contact).
#[test]
fn output_status_is_what_the_reports_say() {
    use roughlub::backend::OutputStatus;
    use roughlub::model::params::Order;
    let text = format!("{}\n[batch]\nmu = [1e-3, 1e-2, 0.1]\n", near_contact(""));
    let scene = Scene::from_toml(&text, Path::new("estimate.toml")).expect("valid scene");
    let chain = scene.initial_chain().expect("initial chain");
    let plan = scene.plan(&chain, scene.precision);
    let members = plan.members.len();
    assert_eq!(members, 3);
    let engine = select(Backend::Cpu, Precision::F64, &plan).unwrap();
    let mut adaptive = plan.clone();
    adaptive.order = Order::Fixed(4);
    adaptive.stepping = Stepping::Adaptive {
        tolerance: 1e-6,
        dt_initial: 1e-4,
        dt_min: 1e-14,
    };
    let mut failing = adaptive.clone();
    failing.stepping = Stepping::Adaptive {
        tolerance: 1e-12,
        dt_initial: 1e-4,
        dt_min: 1e-5,
    };
    let mut failures = 0;
    for (name, plan) in [
        ("order 1", plan),
        ("order 4", adaptive),
        ("failing", failing),
    ] {
        let mut solver = engine.solver(plan, vec![chain.clone(); members]).unwrap();
        let mut outputs = 0;
        while solver.next_output(&|_| {}).unwrap().is_some() {
            let expected: Vec<OutputStatus> =
                solver.reports().iter().map(OutputStatus::of).collect();
            let got = solver.output_status();
            assert_eq!(got.len(), members, "{name}");
            for (g, e) in got.iter().zip(&expected) {
                assert_eq!(g.ok, e.ok, "{name}, output {outputs}");
                assert_eq!(
                    g.error_estimate.to_bits(),
                    e.error_estimate.to_bits(),
                    "{name}, output {outputs}"
                );
            }
            // An estimate where the scheme has one (NaN only before the first step).
            if outputs > 0 {
                assert!(
                    got.iter().all(|s| !s.error_estimate.is_nan()),
                    "{name}: {got:?}"
                );
            }
            failures += got.iter().filter(|s| !s.ok).count();
            outputs += 1;
        }
        assert_eq!(outputs, 3, "{name}");
    }
    assert!(
        failures > 0,
        "no member failed: the failing case does not test failures"
    );
}

/// The smallest gap's ln d at each output time and the members' reports, for the scene `text`.
fn smallest_log_gaps(text: &str) -> (Vec<f64>, Vec<roughlub::backend::MemberReport>) {
    let scene = Scene::from_toml(text, Path::new("estimate.toml")).expect("valid scene");
    let chain = scene.initial_chain().expect("initial chain");
    let plan = scene.plan(&chain, scene.precision);
    let engine = select(Backend::Cpu, Precision::F64, &plan).unwrap();
    let mut solver = engine.solver(plan, vec![chain]).unwrap();
    let mut smallest = Vec::new();
    while let Some(s) = solver.next_output(&|_| {}).unwrap() {
        smallest.push(s[0].log_min_gap);
    }
    (smallest, solver.reports())
}

/// A collision that both the run (dt = 1e-3) and its companion (4e-3) step over: the extremes
/// matrix's near-contact chain (N = 200, rho0 = 0.99, mu = 1e-4, gamma = 1), whose smallest gap
/// reaches ln d = -1326 at t = 0.01, below the float range, where the run has -734 and the
/// companion -124. The estimate must be of the size of the error (issue 22, item 3: within a
/// factor 10 of the smallest gap's error in ln d at each output, 591 and 300 here, against a
/// reference at tolerance 1e-6 that agrees with 1e-10 to 2e-5), and the manifest's largest
/// estimate must be that of the worst output time, not of the last.
#[test]
fn a_collision_stepped_over_gets_an_estimate_of_its_size() {
    let text = |stepping: &str, order: &str| {
        format!(
            r#"
name = "stepped_over"
[model]
particles = 200
mu = 1e-4
gamma = 1.0
[initial]
rho = "0.99"
velocity = "0.5*sin(2*pi*x)"
rho_star = "0.995"
[time]
end = 0.02
outputs = 3
{stepping}
[solver]
order = {order}
backend = "cpu"
[output]
fields = ["gaps", "velocities", "energy"]
plots = false
"#
        )
    };
    let (run, reports) = smallest_log_gaps(&text("dt = 1e-3", "1"));
    let (reference, _) = smallest_log_gaps(&text("tolerance = 1e-6", "\"auto\""));
    let estimates = reports[0]
        .error_estimate
        .clone()
        .expect("a companion estimate");
    for k in 1..run.len() {
        let error = (run[k] - reference[k]).abs();
        let estimate = estimates[k];
        eprintln!(
            "t index {k}: smallest ln d {:.1} against {:.1}: error {error:.1}, estimate {estimate:.1}",
            run[k], reference[k]
        );
        assert!(error > 100.0, "not stepped over: error {error}");
        assert!(
            (error / 10.0..=error * 10.0).contains(&estimate),
            "output {k}: estimate {estimate:e} against error {error:e}"
        );
    }
    let largest = reports[0].largest_error_estimate().unwrap();
    assert_eq!(largest, estimates.iter().copied().fold(0.0, f64::max));
    assert!(largest > *estimates.last().unwrap());
}

/// On coarse fixed steps the extrapolated orders' estimate (each step's local error, without
/// what the later steps do to it) falls below the error: order 6 at dt = 0.05 on a chain
/// compressed toward contact (rho0 = 0.5, rho*0 = 0.6, u0 = sin 2 pi x, mu 1e-3) errs by 0.25 in
/// ln d at t = 0.1 and estimates 0.025 there (2026-11-30; to t = 0.3 the largest over output
/// times are 0.29 and 0.050: docs/error_estimate/coarse_fixed_steps.py). Fixed steps warn from
/// an estimate of 0.01, so this run, with an error above 0.1, warns.
#[test]
fn a_coarse_fixed_step_run_whose_estimate_falls_below_its_error_still_warns() {
    let text = scene("0.5", "0.6", "1", 1e-3, 1.0, 0.1, 0.05, "").replace("order = 1", "order = 6");
    let (estimate, error) = estimate_and_error(&text);
    eprintln!("order 6 at dt = 0.05: estimate {estimate:.3e}, error {error:.3e}");
    assert!(error > 0.1, "the scene is not hard enough: error {error:e}");
    assert!(
        (0.01..0.1).contains(&estimate),
        "estimate {estimate:e} (against error {error:e}): the case no longer shows the limit's reason"
    );
    let tmp = tempfile::tempdir().unwrap();
    let (_, stderr, manifest) = run_cli(tmp.path(), "coarse", &text, &[]);
    let warning = manifest["error_estimate"]["warning"].as_str().unwrap_or("");
    for text in [warning, &stderr] {
        assert!(text.contains("may not be converged"), "{text}");
    }
}

/// The extrapolated orders' estimate with fixed steps adds each step's local error without the
/// damping of the steps after it. Near contact with velocities far from their
/// force balance at t = 0 the first steps leave a large local error in a transient that the next
/// steps damp at once: order 2 at dt = 1e-5 estimates more than 0.1 where its error against the
/// converged reference is below 1e-6 (measured 2026-11-30: 0.15 against 5.0e-12 at N = 40).
/// The warning then says that a transient can inflate the estimate, not that the results are not
/// converged, which only the companion of order 1, comparing two whole runs, can say.
#[test]
fn an_estimate_that_a_damped_transient_inflates_says_so_in_its_warning() {
    let text =
        scene("0.9999", "0.99995", "2", 1.0, 1.0, 0.02, 1e-5, "").replace("order = 1", "order = 2");
    let (estimate, error) = estimate_and_error(&text);
    eprintln!("order 2 near contact: estimate {estimate:.3e}, error {error:.3e}");
    assert!(estimate > 0.1, "not inflated: estimate {estimate:e}");
    assert!(error < 1e-6, "not converged: error {error:e}");

    let tmp = tempfile::tempdir().unwrap();
    let (_, stderr, manifest) = run_cli(tmp.path(), "transient", &text, &[]);
    let warning = manifest["error_estimate"]["warning"].as_str().unwrap_or("");
    for text in [warning, &stderr] {
        assert!(
            text.contains("may not be converged") && text.contains("a fast transient"),
            "{text}"
        );
        assert!(!text.contains("these results are not converged"), "{text}");
    }
}

/// A study warns as a run does, and `--resume` of the complete study prints the warning its
/// manifest recorded (until 2026-11-30 it rebuilt it from the recorded estimate, which it read
/// only where finite): the near-contact scene as an ensemble of 4 members with rough radii.
#[test]
fn a_resumed_complete_study_repeats_its_recorded_warning() {
    let text = format!(
        "{}\n[ensemble]\nmembers = 4\nseed = 3\nchunk = 2\nroughness = {{ kind = \"lognormal\", spread = 0.1 }}\n",
        near_contact("")
    );
    let tmp = tempfile::tempdir().unwrap();
    let (_, first, manifest) = run_cli(tmp.path(), "study", &text, &[]);
    let recorded = manifest["error_estimate"]["warning"]
        .as_str()
        .expect("a recorded warning")
        .to_string();
    assert!(
        recorded.contains("these results are not converged"),
        "{recorded}"
    );
    let (_, resumed, _) = run_cli(tmp.path(), "study", &text, &["--resume"]);
    for stderr in [&first, &resumed] {
        assert!(
            stderr.contains(&format!("warning: {recorded}")),
            "stderr: {stderr}"
        );
    }
}

/// A member that fails has no state after its failure, so no error estimate there: the
/// manifest's estimates at later output times are "NaN", as its rows of gaps.npy are.
#[test]
fn a_failed_members_estimates_after_its_failure_are_nan() {
    let dir = tempfile::tempdir().unwrap();
    // Velocities of 1e6 close a gap below 1e-250 within 1e-7 of the start.
    let scene = r#"
name = "fails"
[model]
particles = 20
mu = 0.01
[initial]
rho = "0.7"
velocity = "1e6*sin(2*pi*x)"
rho_star = "0.7"
[time]
end = 0.05
outputs = 3
tolerance = 1e-4
[solver]
backend = "cpu"
[output]
plots = false
"#;
    let (_, _, manifest) = run_cli(dir.path(), "fails", scene, &[]);
    let member = &manifest["members"][0];
    assert_eq!(member["status"], "failed", "{member}");
    let failed_at = member["time"].as_f64().unwrap();
    assert!(failed_at < 0.025, "failed at {failed_at}");
    let estimates: Vec<String> = member["error_estimate"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.to_string())
        .collect();
    assert_eq!(estimates[0], "0.0", "{estimates:?}");
    assert_eq!(&estimates[1..], ["\"NaN\"", "\"NaN\""], "{estimates:?}");
}

/// Every output's (gaps, velocities) of the single member of the scene `text` at `precision`.
fn outputs_at(text: &str, precision: Precision) -> Vec<(Vec<f64>, Vec<f64>)> {
    let scene = Scene::from_toml(text, Path::new("tolerance.toml")).expect("valid scene");
    let chain = scene.initial_chain_in(precision).expect("initial chain");
    let mut plan = scene.plan(&chain, precision);
    plan.fields.gaps = true;
    plan.fields.velocities = true;
    let engine = select(Backend::Cpu, precision, &plan).unwrap();
    let mut solver = engine.solver(plan, vec![chain]).unwrap();
    let mut outputs = Vec::new();
    while let Some(s) = solver.next_output(&|_| {}).unwrap() {
        outputs.push((s[0].gaps.clone(), s[0].velocities.clone()));
    }
    outputs
}

/// Auto in f32 follows its tolerance on the paper's case 3 (issue 22, item 2): with its columns
/// capped where their rounding stays 10 times below the tolerance (`top_column`), its error
/// against the case in f64 at 1e-11 falls at every tolerance from 1e-3 to 3e-5 (auto's f32 floor
/// is 2.63e-5) and stays within 4 times it (measured 2026-11-30: 1.59, 1.10 and 1.52 times; 1.59,
/// 13.0 and, at 1e-5, 23.0 times before the cap).
#[test]
fn f32_auto_follows_its_tolerance_on_case_3() {
    let chain = r#"
name = "case3"
[model]
particles = 400
mu = 0.01
gamma = 1.0
[initial]
rho = "0.6 + 0.2*exp(-(x-0.5)^2/(2*0.1^2))"
velocity = "0.5*sin(2*pi*x)"
rho_star = "0.6 - 0.2*exp(-(x-0.5)^2/(2*0.1^2))"
[time]
end = 0.4
outputs = 9
"#;
    let text = |tolerance: f64, precision: &str| auto_on_the_cpu(chain, tolerance, precision);
    let reference = outputs_at(&text(1e-11, "f64"), Precision::F64);
    let mut previous = f64::INFINITY;
    for tolerance in [1e-3, 1e-4, 3e-5] {
        let error = largest_error(
            &outputs_at(&text(tolerance, "f32"), Precision::F32),
            &reference,
        );
        eprintln!(
            "f32 at {tolerance:e}: error {error:.3e} ({:.2} times)",
            error / tolerance
        );
        assert!(error <= 4.0 * tolerance, "{tolerance:e}: {error:e}");
        assert!(
            error < previous,
            "{tolerance:e}: {error:e} after {previous:e}"
        );
        previous = error;
    }
}

/// `chain` (a scene up to its `[time]` section's end and outputs) with order auto on the CPU at
/// `tolerance` in `precision`, and small outputs.
fn auto_on_the_cpu(chain: &str, tolerance: f64, precision: &str) -> String {
    format!(
        "{chain}tolerance = {tolerance}\n[solver]\norder = \"auto\"\nbackend = \"cpu\"\n\
         precision = \"{precision}\"\n[output]\ngrid = 20\nplots = false\n"
    )
}

/// The largest over output times of |ln d - ln d_ref| and |u - u_ref| / (1 + |u_ref|): the
/// adaptive estimate's norm.
fn largest_error(outputs: &[(Vec<f64>, Vec<f64>)], reference: &[(Vec<f64>, Vec<f64>)]) -> f64 {
    let mut error = 0.0f64;
    for ((gaps, velocities), (ref_gaps, ref_velocities)) in outputs.iter().zip(reference) {
        for (a, b) in gaps.iter().zip(ref_gaps) {
            error = error.max((a.ln() - b.ln()).abs());
        }
        for (a, b) in velocities.iter().zip(ref_velocities) {
            error = error.max((a - b).abs() / (1.0 + b.abs()));
        }
    }
    error
}

/// An adaptive run whose estimate is over 100 times its tolerance warns that the tolerance was
/// not met, below the estimate's absolute limit of 0.1 (issue 22, item 2). f32 at tolerance 3e-5
/// (near its floor for auto, 2.63e-5) on a chain driven to a gap of 1e-13 (N = 24, gamma 1, u0 =
/// 2 sin 2 pi x) errs by over 10 times the tolerance against the same chain in f64 at 1e-11
/// (measured 2026-11-30: 30 times, and an estimate of 520 times:
/// docs/error_estimate/tolerance_factor.py); in f64 at 3e-5 the error is within 10 times the
/// tolerance and the run does not warn.
#[test]
fn an_adaptive_run_far_from_its_tolerance_says_so() {
    let chain = r#"
name = "tolerance"
[model]
particles = 24
mu = 0.01
gamma = 1.0
[initial]
rho = "0.6"
velocity = "2*sin(2*pi*x)"
rho_star = "0.65+0.1*sin(6*pi*x)"
[time]
end = 0.2
outputs = 7
"#;
    let text = |tolerance: f64, precision: &str| auto_on_the_cpu(chain, tolerance, precision);
    let reference = outputs_at(&text(1e-11, "f64"), Precision::F64);
    let error = |outputs: &[(Vec<f64>, Vec<f64>)]| largest_error(outputs, &reference);
    let tmp = tempfile::tempdir().unwrap();
    for (precision, name) in [(Precision::F32, "f32"), (Precision::F64, "f64")] {
        let scene = text(3e-5, name);
        let error = error(&outputs_at(&scene, precision));
        let (_, stderr, manifest) = run_cli(tmp.path(), name, &scene, &[]);
        let record = &manifest["error_estimate"];
        let estimate = record["largest"].as_f64().unwrap();
        let warning = record["warning"].as_str();
        eprintln!(
            "{name} at 3e-5: error {error:.3e}, estimate {estimate:.3e}, warning {warning:?}"
        );
        if precision == Precision::F32 {
            assert!(error > 3e-4, "f32 no longer errs far from 3e-5: {error:e}");
            assert!(
                (3e-3..0.1).contains(&estimate),
                "estimate {estimate:e}: not between 100 times the tolerance and the limit"
            );
            for text in [warning.unwrap_or(""), &stderr] {
                assert!(
                    text.contains("times the tolerance 3e-5")
                        && text.contains("precision = \"f64\""),
                    "{text}"
                );
            }
        } else {
            assert!(error < 3e-4, "f64 errs {error:e} at 3e-5");
            assert!(estimate < 3e-3, "estimate {estimate:e}");
            assert!(warning.is_none() && !stderr.contains("warning"), "{stderr}");
        }
    }

    // A study of the f32 chain in two shards, merged, warns as the whole study does (the merge
    // reads the tolerance from the shards' scene).
    let study = format!(
        "{}\n[ensemble]\nmembers = 2\nchunk = 1\n",
        text(3e-5, "f32")
    );
    let (_, _, whole) = run_cli(tmp.path(), "whole", &study, &[]);
    let recorded = whole["error_estimate"]["warning"].as_str().unwrap_or("");
    assert!(recorded.contains("times the tolerance 3e-5"), "{recorded}");
    let mut shards = Vec::new();
    for k in 0..2 {
        let (dir, _, _) = run_cli(
            tmp.path(),
            &format!("shard{k}"),
            &study,
            &["--shard", &format!("{k}/2")],
        );
        shards.push(dir);
    }
    let merged = tmp.path().join("merged");
    let out = Command::new(BIN)
        .arg("merge")
        .args(&shards)
        .arg("--out")
        .arg(&merged)
        .arg("--no-plots")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let manifest: Value =
        serde_json::from_str(&std::fs::read_to_string(merged.join("manifest.json")).unwrap())
            .unwrap();
    assert_eq!(
        manifest["error_estimate"]["warning"].as_str(),
        Some(recorded)
    );
}
