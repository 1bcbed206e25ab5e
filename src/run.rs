//! A single run: scene → chain → plan → backend (through [`crate::backend::select`]) →
//! observables → output directory.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::backend::report::{run_error_estimate_method, GpuStats};
use crate::backend::select::BackendRecord;
use crate::backend::{select, Backend, MemberReport, MemberStatus, Precision};
use crate::error::{Error, Result};
use crate::model::observables::Snapshot;
use crate::model::plan::Plan;
use crate::output::manifest::{ErrorEstimateRecord, RunManifest, SceneRecord, VERSION};
use crate::output::{
    write_json_atomic, write_npy, NpyStream, ProgressReporter, StagedDir, MANIFEST,
};
use crate::plot::{plot_profiles, plot_series, ProfilePlot};
use crate::scene::Scene;

#[derive(Debug, Clone)]
pub struct RunOptions {
    pub out_dir: PathBuf,
    pub backend: Option<Backend>,
    pub precision: Option<Precision>,
    pub quiet: bool,
    /// Replace an `out_dir` that holds files that are not a roughlub run.
    pub force: bool,
    /// Write outputs larger than [`OUTPUT_SIZE_LIMIT`].
    pub allow_large: bool,
}

/// Outputs larger than this are refused unless `--allow-large` (a mistyped `outputs` or `grid`
/// must not fill the disk before anyone notices).
pub const OUTPUT_SIZE_LIMIT: u64 = 20 << 30;

/// Profile plots draw at most this many output times (evenly spaced, first and last included):
/// more curves are unreadable and cost minutes of drawing.
pub const MAX_PLOTTED_TIMES: usize = 41;

/// What the size of a run's outputs depends on.
struct OutputShape {
    particles: usize,
    members: usize,
    times: usize,
    grid: usize,
    fields: crate::model::params::OutputFields,
}

impl OutputShape {
    fn of_plan(plan: &Plan) -> OutputShape {
        OutputShape {
            particles: plan.particles,
            members: plan.members.len(),
            times: plan.output_times.len(),
            grid: plan.grid,
            fields: plan.fields,
        }
    }

    /// From the scene alone, where it gives N and whether there is roughness (profiles; a
    /// particle file says only once read).
    fn of_scene(scene: &Scene) -> Option<OutputShape> {
        let (Some(particles), crate::scene::InitialSpec::Profiles { rho_star, .. }) =
            (scene.particles, &scene.initial)
        else {
            return None;
        };
        let mut fields = scene.fields;
        fields.rho_star &= rho_star.is_some();
        Some(OutputShape {
            particles,
            members: scene.member_parameters().len(),
            times: scene.output_times.len(),
            grid: scene.grid,
            fields,
        })
    }

    /// Bytes of the .npy arrays a run writes: per output time and member, N gaps, N-1
    /// velocities, G values of each grid field and the scalars.
    fn bytes(&self) -> u64 {
        let f = &self.fields;
        let (n, g) = (self.particles as u64, self.grid as u64);
        let per_member = u64::from(f.gaps) * n
            + u64::from(f.velocities) * (n - 1)
            + (u64::from(f.rho) + u64::from(f.u) + u64::from(f.rho_star)) * g
            + 5;
        8 * self.times as u64 * self.members as u64 * per_member
    }
}

/// The output indices whose profiles are plotted: all, or MAX_PLOTTED_TIMES evenly spaced.
fn plotted_times(count: usize) -> Vec<usize> {
    crate::plot::thinned_indices(count, MAX_PLOTTED_TIMES)
}

#[derive(Debug, Clone)]
pub struct RunSummary {
    pub out_dir: PathBuf,
    pub backend: String,
    /// What ran it: "name (backend)" of the GPU adapter, or the CPU description.
    pub adapter: String,
    pub members: usize,
    pub failed: usize,
    pub wall_seconds: f64,
    /// The largest error estimate of a completed member at any output time.
    pub largest_error_estimate: Option<f64>,
    /// Whether the scheme estimates its error at all (order 1 with fixed steps does not).
    pub error_estimate_available: bool,
    /// The manifest's warning about the largest estimate, if any.
    pub error_estimate_warning: Option<String>,
}

/// The .npy streams of the per-member arrays, [T, B, ...], opened only for requested fields.
struct FieldStreams {
    gaps: Option<NpyStream>,
    velocities: Option<NpyStream>,
    rho: Option<NpyStream>,
    u: Option<NpyStream>,
    rho_star: Option<NpyStream>,
}

impl FieldStreams {
    fn open(dir: &std::path::Path, plan: &Plan) -> Result<FieldStreams> {
        let (t, b) = (plan.output_times.len() as u64, plan.members.len() as u64);
        let (n, g) = (plan.particles as u64, plan.grid as u64);
        let f = plan.fields;
        let open = |name: &str, shape: &[u64], on: bool| -> Result<Option<NpyStream>> {
            on.then(|| NpyStream::create(dir.join(name), shape))
                .transpose()
        };
        Ok(FieldStreams {
            gaps: open("gaps.npy", &[t, b, n], f.gaps)?,
            velocities: open("velocities.npy", &[t, b, n - 1], f.velocities)?,
            rho: open("rho.npy", &[t, b, g], f.rho)?,
            u: open("u.npy", &[t, b, g], f.u)?,
            rho_star: open("rho_star.npy", &[t, b, g], f.rho_star)?,
        })
    }

    fn push(&mut self, s: &Snapshot) -> Result<()> {
        for (stream, values) in [
            (&mut self.gaps, &s.gaps),
            (&mut self.velocities, &s.velocities),
            (&mut self.rho, &s.rho),
            (&mut self.u, &s.u),
            (&mut self.rho_star, &s.rho_star),
        ] {
            if let Some(stream) = stream {
                stream.push(values)?;
            }
        }
        Ok(())
    }

    fn finish(self) -> Result<Vec<PathBuf>> {
        [self.gaps, self.velocities, self.rho, self.u, self.rho_star]
            .into_iter()
            .flatten()
            .map(NpyStream::finish)
            .collect()
    }
}

/// A plotted member's fields at some output times, kept for its plots (the plots need the
/// fields even when they are not written).
#[derive(Default)]
struct FieldRows {
    rho: Vec<Vec<f64>>,
    u: Vec<Vec<f64>>,
    rho_star: Vec<Vec<f64>>,
}

impl FieldRows {
    fn record(&mut self, s: &Snapshot, grid: usize) {
        let or_nan = |v: &Vec<f64>| {
            if v.is_empty() {
                vec![f64::NAN; grid]
            } else {
                v.clone()
            }
        };
        self.rho.push(or_nan(&s.rho));
        self.u.push(or_nan(&s.u));
        self.rho_star.push(or_nan(&s.rho_star));
    }
}

/// A plotted member's fields at the profile plot's times and at the x–t map's.
#[derive(Default)]
struct PlottedProfiles {
    profiles: FieldRows,
    map: FieldRows,
}

pub fn run_scene(scene: &Scene, options: &RunOptions) -> Result<RunSummary> {
    let started = Instant::now();
    let requested = options.backend.unwrap_or(scene.backend);
    let precision = options.precision.unwrap_or(scene.precision);

    // Refused from the scene where it can be, before the initial data of a huge N is built
    // (16 s and 335 MB at N = 1e7, minutes at 1e8, only to be refused).
    if let (false, Some(shape)) = (options.allow_large, OutputShape::of_scene(scene)) {
        check_output_size(&shape)?;
    }
    // Everything a user supplies is validated before the directory is touched.
    let chain = scene.initial_chain_in(precision)?;
    let input_files = crate::output::input_file_hashes(&scene.files_read())?;
    let plan = scene.plan(&chain, precision);
    let engine = select(requested, precision, &plan)?;
    if !options.quiet {
        eprintln!("{}", engine.record.line());
    }
    let members = plan.members.len();
    if !options.allow_large {
        check_output_size(&OutputShape::of_plan(&plan))?;
    }
    let solver_started = Instant::now();
    let mut solver = engine.solver(plan.clone(), vec![chain; members])?;
    let mut solve_seconds = solver_started.elapsed().as_secs_f64();

    // Written into a staging directory beside `out_dir` and swapped in whole at the end: `out_dir`
    // is always a complete earlier run or the complete new one, never a mixture.
    let staged = StagedDir::begin(&options.out_dir, options.force)?;
    let dir = &staged.staging.clone();
    let b = members as u64;
    let t_count = plan.output_times.len() as u64;
    let g = plan.grid as u64;
    let mut streams = FieldStreams::open(dir, &plan)?;
    let mut series = ScalarSeries::with_capacity((t_count * b) as usize);
    let plotted = if scene.plots {
        scene.plot_members.min(members)
    } else {
        0
    };
    let mut profiles: Vec<PlottedProfiles> = (0..plotted).map(|_| Default::default()).collect();

    let drawn_times = plotted_times(plan.output_times.len());
    let map_times =
        crate::plot::thinned_indices(plan.output_times.len(), crate::plot::MAX_XT_CELLS.0);
    let mut time_index = 0;
    let progress = ProgressReporter::new(b * t_count, "member-intervals", options.quiet);
    loop {
        let solving = Instant::now();
        let Some(snaps) = solver.next_output(&|n| progress.inc(n))? else {
            break;
        };
        solve_seconds += solving.elapsed().as_secs_f64();
        let drawn = drawn_times.binary_search(&time_index).is_ok();
        let mapped = map_times.binary_search(&time_index).is_ok();
        time_index += 1;
        for (m, s) in snaps.iter().enumerate() {
            streams.push(s)?;
            series.push(s);
            if m < plotted && drawn {
                profiles[m].profiles.record(s, plan.grid);
            }
            if m < plotted && mapped {
                profiles[m].map.record(s, plan.grid);
            }
        }
    }
    progress.finish();

    let mut files = streams.finish()?;
    files.push(write_npy(
        dir.join("times.npy"),
        &[t_count],
        &plan.output_times,
    )?);
    files.push(write_npy(dir.join("x.npy"), &[g], solver.grid())?);
    series.write(dir, &[t_count, b], plan.fields.energy, &mut files)?;

    if plotted > 0 {
        files.extend(write_plots(
            dir,
            &RunPlots {
                scene,
                plan: &plan,
                grid: solver.grid(),
                profiles: &profiles,
                drawn_times: &drawn_times,
                map_times: &map_times,
                max_density: &series.max_density,
            },
        )?);
    }

    let mut reports = solver.reports();
    for report in &mut reports {
        report.clear_estimates_after_failure(&plan.output_times);
    }
    let wall = started.elapsed().as_secs_f64();
    let largest_error_estimate = reports
        .iter()
        .filter(|r| r.status == MemberStatus::Ok)
        .filter_map(|r| r.largest_error_estimate())
        .reduce(f64::max);
    let manifest = run_manifest(
        scene,
        &plan,
        &engine.record,
        solver.gpu_stats(),
        wall,
        solve_seconds,
        reports,
        largest_error_estimate,
        input_files,
        files.iter().map(|p| p.strip_prefix(dir).unwrap_or(p)),
    );
    write_json_atomic(&dir.join(MANIFEST), &manifest)?;
    staged.commit()?;
    Ok(RunSummary {
        out_dir: options.out_dir.clone(),
        backend: match engine.record.backend {
            crate::backend::select::RunsOn::Cpu => "cpu".into(),
            crate::backend::select::RunsOn::Gpu => "gpu".into(),
        },
        adapter: engine.record.short(),
        members,
        failed: manifest.failed_members.len(),
        wall_seconds: wall,
        largest_error_estimate,
        error_estimate_available: run_error_estimate_method(
            plan.order,
            plan.stepping,
            plan.companion_estimate,
        )
        .is_some(),
        error_estimate_warning: manifest.error_estimate.warning.clone(),
    })
}

/// Each member's scalars at each output time, [T, B] in time order.
struct ScalarSeries {
    energy: Vec<f64>,
    dissipation: Vec<f64>,
    min_gap: Vec<f64>,
    log_min_gap: Vec<f64>,
    max_density: Vec<f64>,
}

impl ScalarSeries {
    fn with_capacity(n: usize) -> ScalarSeries {
        ScalarSeries {
            energy: Vec::with_capacity(n),
            dissipation: Vec::with_capacity(n),
            min_gap: Vec::with_capacity(n),
            log_min_gap: Vec::with_capacity(n),
            max_density: Vec::with_capacity(n),
        }
    }

    fn push(&mut self, s: &Snapshot) {
        self.energy.push(s.energy);
        self.dissipation.push(s.dissipation);
        self.min_gap.push(s.min_gap);
        self.log_min_gap.push(s.log_min_gap);
        self.max_density.push(s.max_density);
    }

    /// `{energy,dissipation}.npy` (when the energy is an output), `min_gap.npy`,
    /// `log_min_gap.npy` and `max_density.npy`, of `shape` [T, B], each added to `files`.
    fn write(
        &self,
        dir: &Path,
        shape: &[u64; 2],
        energy: bool,
        files: &mut Vec<PathBuf>,
    ) -> Result<()> {
        if energy {
            files.push(write_npy(dir.join("energy.npy"), shape, &self.energy)?);
            files.push(write_npy(
                dir.join("dissipation.npy"),
                shape,
                &self.dissipation,
            )?);
        }
        files.push(write_npy(dir.join("min_gap.npy"), shape, &self.min_gap)?);
        files.push(write_npy(
            dir.join("log_min_gap.npy"),
            shape,
            &self.log_min_gap,
        )?);
        files.push(write_npy(
            dir.join("max_density.npy"),
            shape,
            &self.max_density,
        )?);
        Ok(())
    }
}

/// The manifest of a single run: everything that determines its result, each member's report
/// and the files written (relative to the run's directory).
#[allow(clippy::too_many_arguments)]
fn run_manifest<'a>(
    scene: &Scene,
    plan: &Plan,
    record: &BackendRecord,
    gpu_stats: Option<GpuStats>,
    wall: f64,
    solve_seconds: f64,
    reports: Vec<MemberReport>,
    largest_error_estimate: Option<f64>,
    input_files: BTreeMap<String, String>,
    files: impl Iterator<Item = &'a Path>,
) -> RunManifest {
    RunManifest {
        roughlub_version: VERSION,
        scene: SceneRecord {
            name: scene.name.clone(),
            description: scene.description.clone(),
            path: scene.source_path.display().to_string(),
            text: scene.source_text.clone(),
        },
        backend: record.clone(),
        gpu_stats,
        wall_seconds: wall,
        solve_seconds,
        particles: plan.particles,
        eps: plan.eps,
        order: plan.order,
        stepping: plan.stepping,
        plan: plan.summary(),
        output_times: plan.output_times.clone(),
        grid: plan.grid,
        error_estimate: ErrorEstimateRecord::new(
            plan.order,
            plan.stepping,
            record.precision,
            plan.companion_estimate,
            largest_error_estimate,
        ),
        steps_accepted_total: reports.iter().map(|r| r.steps_accepted).sum(),
        steps_rejected_total: reports.iter().map(|r| r.steps_rejected).sum(),
        input_files,
        failed_members: reports
            .iter()
            .filter(|r| r.status != MemberStatus::Ok)
            .map(|r| r.index)
            .collect(),
        members: reports,
        files: files.map(|p| p.display().to_string()).collect(),
        conventions: BTreeMap::from([
            ("failed_members", "rows of a member after it failed are NaN; its status gives the reason and time"),
            ("gaps", "d_i = q_i - q_{i-1} - 2 eps, i = 1..N (index i-1)"),
            ("velocities", "u_i, i = 1..N-1 (index i-1); u_0 = u_N = 0"),
            ("fields", "sampled at x.npy; rho and rho_star piecewise constant on [q_{i-1}, q_i), u piecewise linear"),
        ]),
    }
}

/// Refuses a run whose outputs would exceed [`OUTPUT_SIZE_LIMIT`], naming what drives their
/// size (`--allow-large` skips this).
fn check_output_size(plan: &OutputShape) -> Result<()> {
    let bytes = plan.bytes();
    if bytes > OUTPUT_SIZE_LIMIT {
        return Err(Error::invalid(
            "time.outputs",
            plan.times,
            format!(
                "the outputs would take {:.1} GB ({} output times x {} members x N = {}, grid = {}, fields {}) before anything else is written",
                bytes as f64 / 1e9,
                plan.times,
                plan.members,
                plan.particles,
                plan.grid,
                {
                    let f = &plan.fields;
                    let on = [f.gaps, f.velocities, f.rho, f.u, f.rho_star, f.energy];
                    crate::model::params::FIELD_NAMES
                        .iter()
                        .zip(on)
                        .filter(|(_, on)| *on)
                        .map(|(n, _)| *n)
                        .collect::<Vec<_>>()
                        .join(", ")
                }
            ),
            format!(
                "at most {:.1} GB: fewer outputs, a coarser [output] grid or fewer fields, or --allow-large",
                OUTPUT_SIZE_LIMIT as f64 / 1e9
            ),
        ));
    }
    Ok(())
}

/// What a run's plots are drawn from.
struct RunPlots<'a> {
    scene: &'a Scene,
    plan: &'a Plan,
    grid: &'a [f64],
    /// The plotted members' profiles and x-t maps.
    profiles: &'a [PlottedProfiles],
    drawn_times: &'a [usize],
    map_times: &'a [usize],
    /// Time-major, every member.
    max_density: &'a [f64],
}

/// The plotted members' profiles and x-t maps, and the largest density over time of the first
/// 16 members.
fn write_plots(dir: &std::path::Path, plots: &RunPlots) -> Result<Vec<PathBuf>> {
    let RunPlots {
        scene,
        plan,
        grid,
        profiles,
        drawn_times,
        map_times,
        max_density,
    } = *plots;
    let members = plan.members.len();
    let t_count = plan.output_times.len() as u64;
    let mut files = Vec::new();
    let plot_dir = dir.join("plots");
    std::fs::create_dir_all(&plot_dir).map_err(|e| Error::io(&plot_dir, e))?;
    for (m, p) in profiles.iter().enumerate() {
        let params = &plan.members[m];
        let title = format!(
            "{} - member {m} (mu = {}, gamma = {})",
            scene.name, params.mu, params.gamma
        );
        let path = plot_dir.join(format!("member_{m:04}.png"));
        plot_profiles(
            &path,
            &ProfilePlot {
                title: &title,
                x: grid,
                times: &drawn_times
                    .iter()
                    .map(|&k| plan.output_times[k])
                    .collect::<Vec<f64>>(),
                rho: &p.profiles.rho,
                u: &p.profiles.u,
                rho_star: plan.repulsion.then_some(p.profiles.rho_star.as_slice()),
            },
        )?;
        files.push(path);
        let map_t: Vec<f64> = map_times.iter().map(|&k| plan.output_times[k]).collect();
        let mut maps = vec![("rho", &p.map.rho), ("u", &p.map.u)];
        if plan.repulsion {
            maps.push(("rho_star", &p.map.rho_star));
        }
        for (field, rows) in maps {
            let path = plot_dir.join(format!("member_{m:04}_{field}_xt.png"));
            crate::plot::plot_xt(
                &path,
                &format!("{title}: {field}(x, t)"),
                field,
                grid,
                &map_t,
                rows,
            )?;
            files.push(path);
        }
    }
    let series: Vec<(String, Vec<f64>)> = (0..members.min(16))
        .map(|m| {
            let p = &plan.members[m];
            let column = (0..t_count as usize).map(|t| max_density[t * members + m]);
            (format!("mu={} gamma={}", p.mu, p.gamma), column.collect())
        })
        .collect();
    let path = plot_dir.join("max_density.png");
    plot_series(
        &path,
        &format!("{}: max density", scene.name),
        "max rho",
        &plan.output_times,
        &series,
    )?;
    files.push(path);
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Plots draw every time up to MAX_PLOTTED_TIMES, then that many, evenly spaced, first and
    /// last included (100000 outputs took 53 s to draw before).
    #[test]
    fn plotted_times_are_thinned_evenly() {
        assert_eq!(plotted_times(5), vec![0, 1, 2, 3, 4]);
        assert_eq!(plotted_times(41).len(), 41);
        for count in [42usize, 100, 5001, 100_000] {
            let t = plotted_times(count);
            assert_eq!(t.len(), MAX_PLOTTED_TIMES, "{count}");
            assert_eq!((t[0], t[t.len() - 1]), (0, count - 1));
            let steps: Vec<usize> = t.windows(2).map(|w| w[1] - w[0]).collect();
            let (lo, hi) = (steps.iter().min().unwrap(), steps.iter().max().unwrap());
            assert!(hi - lo <= 1, "{count}: uneven {lo}..{hi}");
        }
    }
}
