//! Convergence in N (`roughlub converge`): the same macroscopic scene at several particle
//! numbers N with the initial data of Prop. 3.1, the fields rho, u, rho* on one common grid at
//! the scene's output times, the differences between successive N, the observed rates, a
//! Richardson-extrapolated limit with its error estimate, and whether the rates are asymptotic.
//!
//! Sampling. rho and rho* (cell values at the cell centres) and u (values at the particles) are
//! sampled on the grid by cubic interpolation through the 4 nearest nodes
//! ([`cubic_interpolated`]; error O(h⁴) for smooth profiles). The run's own sampling (rho
//! piecewise constant, u piecewise linear) has errors O(h) and O(h²) whose factor oscillates
//! with a grid point's place in its cell: measured on case 1, it makes rho's differences fall
//! like 1/N whatever the particle system does, it scatters the rates of u by ±0.2, and the
//! pointwise extrapolation of rho lands twice as far from N = 6400 as N = 1600 itself. With the
//! cubic sampling the same runs give rate 2.00 for rho and u and an extrapolation 15 times
//! closer than the largest N.
//!
//! Rates. For successive pairs k = (N_k, N_{k+1}) with differences e_k (L1, L2, L∞ of
//! f_{N_{k+1}} − f_{N_k} over the grid points; L1 and L2 as means over the grid, i.e. the
//! quadrature on [0, 1]), the observed rate at pair k >= 1 is ln(e_{k−1}/e_k)/ln(r_k),
//! r_k = N_k/N_{k−1}: log2 of the ratio when N doubles; exact for e = C N^-p only when the ratios
//! N_{k+1}/N_k are all equal (otherwise an approximation, and the manifest says
//! `"ratios_equal": false`).
//!
//! Limit. From the two largest N with the observed L1 rate p at the largest pair:
//! f_∞ = f_K + (f_K − f_{K−1})/(r^p − 1), r = N_K/N_{K−1}, with the estimate |f_∞ − f_K| (L1).
//!
//! Asymptotic: per field and output time, the verdict of the L1 rates ([`Verdict`]): the last
//! two observed rates must be finite, positive and within [`DRIFT_TOLERANCE`] of each other
//! (so 4 or more N), unless the differences are at rounding level ([`ROUNDING_FACTOR`],
//! [`ROUNDING_LIMITED`]). The study is asymptotic when every field is at every output time.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::backend::select::RunsOn;
use crate::backend::{select, Backend, BackendRecord, MemberStatus, Precision};
use crate::error::{Error, Result};
use crate::model::observables::{cell_centres, cubic_interpolated, Snapshot};
use crate::model::params::OutputFields;
use crate::output::manifest::{SceneRecord, VERSION};
use crate::output::{write_json_atomic, ProgressReporter, StagedDir, MANIFEST};
use crate::scene::{InitialSpec, Scene, MAX_PARTICLES};

mod outputs;
mod rates;
mod records;

use outputs::{write_arrays, write_plots, Drawn};
use rates::fit_rate;
pub use rates::{
    difference_norms, observed_rate, richardson, verdict, Norms, Verdict, DRIFT_TOLERANCE,
    ROUNDING_FACTOR, ROUNDING_LIMITED,
};
use records::{ConvergeManifest, RunRecord, TimeRecord};
pub use records::{ConvergeSummary, FieldSummary};

/// The fields of all N: `[field][k][t]` → G values.
type FieldStack = Vec<Vec<Vec<Vec<f64>>>>;

/// The fields compared, in the order of every output.
pub const FIELDS: [&str; 3] = ["rho", "u", "rho_star"];

/// Profile figures show at most this many output times.
const PLOTTED_TIMES: usize = 4;

#[derive(Debug, Clone)]
pub struct ConvergeOptions {
    pub out_dir: PathBuf,
    /// The particle numbers N, strictly increasing, at least 2 (3 for a rate).
    pub particles: Vec<usize>,
    pub backend: Option<Backend>,
    pub precision: Option<Precision>,
    pub quiet: bool,
    /// Replace an `out_dir` that holds files that are not a roughlub run.
    pub force: bool,
}

/// The `--particles` list: at least 2 values, strictly increasing, each in 2 ..= 1e8.
pub fn check_particles(list: &[usize]) -> Result<()> {
    let shown = || {
        list.iter()
            .map(|n| n.to_string())
            .collect::<Vec<_>>()
            .join(",")
    };
    let allowed = format!(
        "at least 2 (3 or more for a rate) strictly increasing particle numbers, each in 2 ..= {MAX_PARTICLES}, e.g. 100,200,400,800"
    );
    if list.len() < 2 {
        return Err(Error::invalid(
            "--particles",
            shown(),
            "a convergence study compares successive N",
            allowed,
        ));
    }
    if let Some(&n) = list
        .iter()
        .find(|&&n| n < 2 || n as u64 > MAX_PARTICLES as u64)
    {
        return Err(Error::invalid(
            "--particles",
            shown(),
            format!("N = {n} is outside the scene's range of particle numbers"),
            allowed,
        ));
    }
    if let Some(w) = list.windows(2).find(|w| w[1] <= w[0]) {
        return Err(Error::invalid(
            "--particles",
            shown(),
            format!("{} after {} is not increasing", w[1], w[0]),
            allowed,
        ));
    }
    Ok(())
}

/// Refuses scenes whose macroscopic data are not rebuilt at each N.
fn check_scene(scene: &Scene) -> Result<()> {
    if let InitialSpec::Particles { path, .. } = &scene.initial {
        return Err(Error::invalid(
            "initial.particles",
            format!("\"{}\"", path.display()),
            "a convergence study rebuilds the initial data at each N from the profiles (Prop. 3.1); a particle file fixes N",
            "a scene with initial.rho (and initial.velocity, initial.rho_star) profiles",
        ));
    }
    if scene.ensemble.is_some() {
        return Err(Error::invalid(
            "ensemble",
            "[ensemble]",
            "a convergence study runs one member per N from the scene's profiles; an ensemble's members draw their own roughness and perturbations",
            "a scene without [ensemble] (and without [sweep])",
        ));
    }
    Ok(())
}

/// The scene at particle number `n`, with its first `[batch]` member only.
fn scene_at(scene: &Scene, n: usize) -> Scene {
    let mut s = scene.clone();
    s.particles = Some(n);
    s.mu.truncate(1);
    s.gamma.truncate(1);
    s.gamma_swept = false;
    s.fields = OutputFields {
        gaps: true,
        velocities: true,
        rho: false,
        u: false,
        rho_star: false,
        energy: false,
    };
    s
}

/// The differences between successive N, per field: L1/L2/Linf differences and rates at each
/// output time (written to `dir/convergence.csv`), their verdicts, the extrapolated limits and
/// each field's summary, with a warning for each field that is not asymptotic.
fn analyse(
    dir: &Path,
    scene: &Scene,
    (ns, precision): (&[usize], Precision),
    fields: &FieldStack,
    warnings: &mut Vec<String>,
) -> Result<Analysis> {
    let k_count = ns.len();
    let t_count = scene.output_times.len();
    let g = crate::model::observables::grid_points(scene.grid).len();
    let repulsion = has_repulsion(scene);
    let ratios: Vec<f64> = ns.windows(2).map(|w| w[1] as f64 / w[0] as f64).collect();
    let ratios_equal = ratios
        .windows(2)
        .all(|w| (w[0] - w[1]).abs() <= 1e-12 * w[0]);
    // Rounding level of a difference, relative to the field's size: the gaps of the initial
    // data are differences of positions near 1 (relative error about N ε in f64), so the level
    // grows with the largest N; in f32 the solver's own rounding is larger.
    let run_epsilon = match precision {
        Precision::F64 => f64::EPSILON,
        Precision::F32 => f32::EPSILON as f64,
    };
    let unit_rounding = ROUNDING_FACTOR * (ns[k_count - 1] as f64 * f64::EPSILON).max(run_epsilon);
    let field_on = |f: usize| f != 2 || repulsion;
    let mut csv =
        csv::Writer::from_path(dir.join("convergence.csv")).map_err(|e| Error::Output {
            path: dir.join("convergence.csv"),
            message: e.to_string(),
        })?;
    let csv_err = |e: csv::Error| Error::Output {
        path: dir.join("convergence.csv"),
        message: e.to_string(),
    };
    csv.write_record([
        "field",
        "time",
        "n_coarse",
        "n_fine",
        "diff_l1",
        "diff_l2",
        "diff_linf",
        "rate_l1",
        "rate_l2",
        "rate_linf",
        "verdict",
        "asymptotic",
        "limit_error_l1",
    ])
    .map_err(csv_err)?;
    let mut limits: Vec<Vec<f64>> = vec![Vec::with_capacity(t_count * g); FIELDS.len()];
    let mut per_time: BTreeMap<&'static str, Vec<TimeRecord>> = BTreeMap::new();
    let mut summaries = Vec::new();
    for (f, name) in FIELDS.iter().enumerate() {
        if !field_on(f) {
            continue;
        }
        let mut records = Vec::with_capacity(t_count);
        for (t, &time) in scene.output_times.iter().enumerate() {
            let rows: Vec<&[f64]> = (0..k_count).map(|k| &fields[f][k][t][..]).collect();
            let AtTime {
                norms,
                rates: [r1, r2, rinf],
                verdict: v,
                limit,
                limit_error,
            } = at_time(&rows, &ratios, unit_rounding);
            let diffs: Vec<f64> = norms.iter().map(|n| n.l1).collect();
            limits[f].extend_from_slice(&limit);
            for (k, norm) in norms.iter().enumerate() {
                let rate = |r: &[f64]| {
                    if k == 0 {
                        String::new()
                    } else {
                        csv_number(r[k - 1])
                    }
                };
                let last = k + 2 == k_count;
                csv.write_record([
                    name.to_string(),
                    csv_number(time),
                    ns[k].to_string(),
                    ns[k + 1].to_string(),
                    csv_number(norm.l1),
                    csv_number(norm.l2),
                    csv_number(norm.linf),
                    rate(&r1),
                    rate(&r2),
                    rate(&rinf),
                    v.name().to_string(),
                    v.is_asymptotic().to_string(),
                    if last {
                        csv_number(limit_error)
                    } else {
                        String::new()
                    },
                ])
                .map_err(csv_err)?;
            }
            records.push(TimeRecord {
                time,
                diff_l1: diffs,
                rates_l1: r1,
                verdict: v,
                asymptotic: v.is_asymptotic(),
                limit_error_l1: limit_error,
            });
        }
        let last = records.last().expect("at least two output times");
        let n_fine: Vec<f64> = ns[1..].iter().map(|&n| n as f64).collect();
        // Rates of rounding noise are no rates.
        let exact = last.verdict == Verdict::Exact;
        let fitted_rate = match fit_rate(&n_fine, &last.diff_l1) {
            Some((p, _)) if !exact => p,
            _ => f64::NAN,
        };
        let not_asymptotic: Vec<&TimeRecord> = records.iter().filter(|r| !r.asymptotic).collect();
        if !not_asymptotic.is_empty() && k_count >= 3 {
            let first = not_asymptotic[0];
            let times: Vec<String> = not_asymptotic.iter().map(|r| time_text(r.time)).collect();
            let rates: Vec<String> = first.rates_l1.iter().map(|p| format!("{p:.3}")).collect();
            warnings.push(format!(
                "{name}: the observed L1 rate is not asymptotic at t = {} ({} at t = {}: rates [{}]; asymptotic needs the last two rates finite, positive and within {DRIFT_TOLERANCE} of each other, with 4 or more N); its rates and limit are not converged numbers",
                times.join(", "),
                first.verdict.name(),
                time_text(first.time),
                rates.join(", ")
            ));
        }
        summaries.push(FieldSummary {
            field: name,
            diff_l1: last.diff_l1.clone(),
            rates_l1: last.rates_l1.clone(),
            rate: match last.rates_l1.last() {
                Some(&p) if !exact => p,
                _ => f64::NAN,
            },
            fitted_rate,
            verdict: last.verdict,
            limit_error_l1: last.limit_error_l1,
            asymptotic_all_times: not_asymptotic.is_empty(),
        });
        per_time.insert(name, records);
    }
    csv.flush()
        .map_err(|e| Error::io(dir.join("convergence.csv"), e))?;
    drop(csv);
    Ok(Analysis {
        ratios_equal,
        limits,
        per_time,
        summaries,
    })
}

/// What [`analyse`] finds.
struct Analysis {
    ratios_equal: bool,
    limits: Vec<Vec<f64>>,
    per_time: BTreeMap<&'static str, Vec<TimeRecord>>,
    summaries: Vec<FieldSummary>,
}

/// Whether the scene's profiles give rho* (roughness), so that the rho* field is compared.
fn has_repulsion(scene: &Scene) -> bool {
    matches!(
        &scene.initial,
        InitialSpec::Profiles {
            rho_star: Some(_),
            ..
        }
    )
}

/// Output indices shown in the profile figures: up to [`PLOTTED_TIMES`], evenly spaced, the
/// last one included.
fn shown_times(count: usize) -> Vec<usize> {
    crate::plot::thinned_indices(count, PLOTTED_TIMES)
}

/// An output time in a message, to 7 significant digits (0.15, not 0.15000000000000002).
fn time_text(t: f64) -> String {
    let rounded: f64 = format!("{t:.6e}").parse().unwrap_or(t);
    crate::scene::number_text(rounded)
}

/// Text of a number in the CSV: the shortest text that reads back to the same f64 (exponent
/// form for small and large values); `NaN`, `inf`, `-inf`.
fn csv_number(x: f64) -> String {
    format!("{x:?}")
}

pub fn run_convergence(scene: &Scene, options: &ConvergeOptions) -> Result<ConvergeSummary> {
    let started = Instant::now();
    check_particles(&options.particles)?;
    check_scene(scene)?;
    let requested = options.backend.unwrap_or(scene.backend);
    let precision = options.precision.unwrap_or(scene.precision);
    let ns = &options.particles;
    let k_count = ns.len();
    let mut warnings = Vec::new();
    let batch_note = (scene.mu.len() > 1 || scene.gamma.len() > 1).then(|| {
        format!(
            "the scene's [batch] has {} members; the study uses its first (mu = {}, gamma = {})",
            scene.mu.len() * scene.gamma.len(),
            scene.mu[0],
            scene.gamma[0]
        )
    });
    if let Some(note) = &batch_note {
        if !options.quiet {
            eprintln!("note: {note}");
        }
    }

    // The initial data and the backend at the smallest N are checked before anything is
    // written (a bad profile, a repulsion that overflows, a missing adapter).
    {
        let s = scene_at(scene, ns[0]);
        let chain = s.initial_chain()?;
        select(requested, precision, &s.plan(&chain, precision))?;
    }

    check_memory(scene, k_count)?;

    let staged = StagedDir::begin(&options.out_dir, options.force)?;
    let dir = staged.staging.clone();
    let t_count = scene.output_times.len();
    let grid = crate::model::observables::grid_points(scene.grid);
    let g = grid.len();
    let repulsion = has_repulsion(scene);

    // fields[f][k][t] = G values
    let mut fields: FieldStack = vec![Vec::with_capacity(k_count); FIELDS.len()];
    let mut runs = Vec::with_capacity(k_count);
    let mut record: Option<BackendRecord> = None;
    let total: u64 = ns.iter().map(|&n| n as u64).sum::<u64>() * t_count as u64;
    let progress = ProgressReporter::new(total, "particle-intervals", options.quiet);
    for &n in ns {
        let RunAtN {
            run,
            backend,
            fields: per_field,
        } = run_at_n(scene, n, requested, precision, &grid, &progress)?;
        if run.member.status != MemberStatus::Ok {
            warnings.push(format!(
                "the run at N = {n} failed ({}); its fields after the failure are NaN, and every rate involving it is NaN",
                serde_json::to_string(&run.member.status).unwrap_or_default()
            ));
        }
        runs.push(run);
        record = Some(backend);
        for (f, rows) in per_field.into_iter().enumerate() {
            fields[f].push(rows);
        }
    }
    progress.finish();
    let record = record.expect("at least two N");

    // Differences, rates, verdicts and limits.
    let Analysis {
        ratios_equal,
        limits,
        per_time,
        summaries,
    } = analyse(&dir, scene, (ns, precision), &fields, &mut warnings)?;
    let mut files = vec![PathBuf::from("convergence.csv")];
    let asymptotic = summaries.iter().all(|s| s.asymptotic_all_times);
    if k_count == 2 {
        warnings.push(
            "2 values of N give the differences only: no rate, no limit, and no verdict (3 or more N for a rate, 4 or more to judge whether it is asymptotic)"
                .to_string(),
        );
    }

    let drawn = Drawn {
        scene,
        ns,
        grid: &grid,
        fields: &fields,
        limits: &limits,
        summaries: &summaries,
        repulsion,
    };
    files.extend(write_arrays(&dir, &drawn)?);
    if scene.plots {
        files.extend(write_plots(&dir, &drawn)?);
    }

    for line in &warnings {
        eprintln!("warning: {line}");
    }
    let wall = started.elapsed().as_secs_f64();
    let rel = |p: &Path| p.strip_prefix(&dir).unwrap_or(p).display().to_string();
    let manifest = ConvergeManifest {
        roughlub_version: VERSION,
        kind: "convergence",
        scene: SceneRecord {
            name: scene.name.clone(),
            description: scene.description.clone(),
            path: scene.source_path.display().to_string(),
            text: scene.source_text.clone(),
        },
        backend: record.clone(),
        wall_seconds: wall,
        particles: ns.clone(),
        ratios_equal,
        mu: scene.mu[0],
        gamma: scene.gamma[0],
        batch_note,
        output_times: scene.output_times.clone(),
        grid: g,
        asymptotic,
        drift_tolerance: DRIFT_TOLERANCE,
        fields: summaries.clone(),
        per_time,
        runs,
        warnings: warnings.clone(),
        files: files.iter().map(|p| rel(p)).collect(),
        conventions: conventions(),
    };
    write_json_atomic(&dir.join(MANIFEST), &manifest)?;
    staged.commit()?;
    Ok(ConvergeSummary {
        out_dir: options.out_dir.clone(),
        particles: ns.clone(),
        adapter: record.short(),
        backend: match record.backend {
            RunsOn::Cpu => "cpu".into(),
            RunsOn::Gpu => "gpu".into(),
        },
        fields: summaries,
        asymptotic,
        warnings,
        wall_seconds: wall,
    })
}

/// Every field of every N is held in memory (and written): refuses what would not fit.
fn check_memory(scene: &Scene, k_count: usize) -> Result<()> {
    let bytes = 8
        * FIELDS.len() as u64
        * k_count as u64
        * scene.output_times.len() as u64
        * scene.grid as u64;
    if bytes > crate::run::OUTPUT_SIZE_LIMIT {
        return Err(Error::invalid(
            "output.grid",
            scene.grid,
            format!(
                "the fields of {k_count} values of N x {} output times x {} grid points take {:.1} GB, held in memory",
                scene.output_times.len(),
                scene.grid,
                bytes as f64 / 1e9
            ),
            format!(
                "at most {:.1} GB: a coarser [output] grid, fewer [time] outputs or fewer N",
                crate::run::OUTPUT_SIZE_LIMIT as f64 / 1e9
            ),
        ));
    }
    Ok(())
}

/// What the convergence run's files and numbers mean (the manifest's `conventions`).
fn conventions() -> BTreeMap<&'static str, &'static str> {
    BTreeMap::from([
        ("fields_*.npy", "[K, T, G]: each N (particles.npy) at each output time (times.npy) on the grid x.npy"),
        ("limit_*.npy", "[T, G]: Richardson extrapolation from the two largest N with the L1 rate at the largest pair, f_K + (f_K - f_{K-1})/(r^p - 1); the field itself where every difference is rounding (verdict exact); NaN where the rate is not finite and positive; absent with 2 values of N"),
        ("sampling", "cubic interpolation through the 4 nearest nodes: rho and rho_star from the cell values at the cell centres, u from the particle velocities (O(h^4) for smooth profiles; the run's piecewise-constant / piecewise-linear sampling is O(h) / O(h^2) with a factor oscillating from point to point, which hides the particle system's convergence and defeats pointwise extrapolation)"),
        ("time_steps", "every N runs with the scene's time stepping: the limit is N -> infinity at those steps, and the time-step error (common to all N) is not in the differences"),
        ("norms", "L1 and L2 as means over the grid points, Linf the largest difference"),
        ("rates", "ln(e_{k-1}/e_k)/ln(N_k/N_{k-1}) between the differences of successive pairs: log2 of the ratio when N doubles; exact for e = C N^-p only when the ratios are equal (ratios_equal)"),
        ("asymptotic", "per field and time: the last two L1 rates finite, positive and within drift_tolerance (needs 4 or more N), or every L1 difference at rounding level, 16 max(N_K eps_f64, eps) max(1, max|f_K|) with eps that of the precision (exact), or the difference at the largest pair within 100 times that level where the last rate shows it (not finite and positive, or 0.15 below the one before: rounding_limited, converged as far as the precision resolves); failed where a run failed before that time"),
    ])
}

/// What [`run_at_n`] gives: the run's record, the backend's, and each field's rows on the grid
/// at every output time (`fields[f][t]`, f in rho, u, rho*).
struct RunAtN {
    run: RunRecord,
    backend: BackendRecord,
    fields: [Vec<Vec<f64>>; 3],
}

/// The scene at N particles, one member, on the backend chosen for it.
fn run_at_n(
    scene: &Scene,
    n: usize,
    requested: Backend,
    precision: Precision,
    grid: &[f64],
    progress: &ProgressReporter,
) -> Result<RunAtN> {
    let run_started = Instant::now();
    let s = scene_at(scene, n);
    let chain = s.initial_chain()?;
    let plan = s.plan(&chain, precision);
    let engine = select(requested, precision, &plan)?;
    let eps = plan.eps;
    let summary = plan.summary();
    let dstar = chain.dstar.clone();
    let mut solver = engine.solver(plan, vec![chain])?;
    let mut per_field: [Vec<Vec<f64>>; 3] = Default::default();
    while let Some(snaps) = solver.next_output(&|_| {})? {
        progress.inc(n as u64);
        let rows = sampled_fields(&snaps[0], eps, dstar.as_deref(), grid);
        for (field_rows, row) in per_field.iter_mut().zip(rows) {
            field_rows.push(row);
        }
    }
    let member = solver.reports().remove(0);
    let run = RunRecord {
        particles: n,
        eps,
        adapter: engine.record.short(),
        wall_seconds: run_started.elapsed().as_secs_f64(),
        plan: summary,
        member,
    };
    Ok(RunAtN {
        run,
        backend: engine.record.clone(),
        fields: per_field,
    })
}

/// One field at one output time, from its rows at each N (coarse to fine): the differences of
/// successive N, their observed rates (L1, L2, Linf), the verdict and the extrapolated limit.
struct AtTime {
    norms: Vec<Norms>,
    rates: [Vec<f64>; 3],
    verdict: Verdict,
    limit: Vec<f64>,
    /// L1 distance from the limit to the finest N.
    limit_error: f64,
}

fn at_time(rows: &[&[f64]], ratios: &[f64], unit_rounding: f64) -> AtTime {
    let k_count = rows.len();
    let norms: Vec<Norms> = (0..k_count - 1)
        .map(|k| difference_norms(rows[k + 1], rows[k]))
        .collect();
    let rate_of = |pick: fn(&Norms) -> f64| -> Vec<f64> {
        (1..k_count - 1)
            .map(|k| observed_rate(pick(&norms[k - 1]), pick(&norms[k]), ratios[k - 1]))
            .collect()
    };
    let (r1, r2, rinf) = (rate_of(|n| n.l1), rate_of(|n| n.l2), rate_of(|n| n.linf));
    let fine = rows[k_count - 1];
    let coarse = rows[k_count - 2];
    let scale = fine
        .iter()
        .map(|v| v.abs())
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max)
        .max(1.0);
    let diffs: Vec<f64> = norms.iter().map(|n| n.l1).collect();
    let v = verdict(&diffs, &r1, unit_rounding * scale);
    // The limit: the field itself when exact; Richardson with the last rate otherwise
    // (NaN when there is no rate, or it is not positive).
    let usable = |p: f64| p.is_finite() && p > 0.0;
    let limit: Vec<f64> = match (v, r1.last()) {
        (Verdict::Exact, _) => fine.to_vec(),
        (Verdict::RoundingLimited, p) if !p.is_some_and(|&p| usable(p)) => fine.to_vec(),
        (_, Some(&p)) => richardson(fine, coarse, ratios[k_count - 2], p),
        (_, None) => vec![f64::NAN; fine.len()],
    };
    let limit_error = difference_norms(&limit, fine).l1;
    // Rates between differences at rounding level mean nothing: an exact field has none.
    let (r1, r2, rinf) = if v == Verdict::Exact {
        let none = vec![f64::NAN; r1.len()];
        (none.clone(), none.clone(), none)
    } else {
        (r1, r2, rinf)
    };
    AtTime {
        norms,
        rates: [r1, r2, rinf],
        verdict: v,
        limit,
        limit_error,
    }
}

/// One output of one N on the grid: rho and rho* cubic through the cells' centres, u cubic
/// through the particles (walls at rest); NaN rows for a member that has failed.
fn sampled_fields(snap: &Snapshot, eps: f64, dstar: Option<&[f64]>, grid: &[f64]) -> [Vec<f64>; 3] {
    let g = grid.len();
    let widths: Vec<f64> = snap.gaps.iter().map(|&d| d + 2.0 * eps).collect();
    if !widths.iter().chain(&snap.velocities).all(|v| v.is_finite()) {
        return std::array::from_fn(|_| vec![f64::NAN; g]);
    }
    let centres = cell_centres(&widths);
    let rho: Vec<f64> = widths.iter().map(|&w| 2.0 * eps / w).collect();
    let mut nodes = Vec::with_capacity(widths.len() + 1);
    nodes.push(0.0);
    nodes.extend(widths.iter().scan(0.0, |q, &w| {
        *q += w;
        Some(*q)
    }));
    let mut u = Vec::with_capacity(widths.len() + 1);
    u.push(0.0);
    u.extend_from_slice(&snap.velocities);
    u.push(0.0);
    let rho_star = match dstar {
        Some(ds) => {
            let rs: Vec<f64> = ds.iter().map(|&d| 2.0 * eps / (d + 2.0 * eps)).collect();
            cubic_interpolated(&centres, &rs, grid)
        }
        None => vec![f64::NAN; g],
    };
    [
        cubic_interpolated(&centres, &rho, grid),
        cubic_interpolated(&nodes, &u, grid),
        rho_star,
    ]
}

#[cfg(test)]
mod tests;
