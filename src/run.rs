//! scene → chain → plan → backend → observables → output directory.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use serde_json::json;

use crate::cpu::{CpuSolver, MemberReport, MemberStatus};
use crate::error::{Error, Result};
use crate::gpu::solver::GpuSolver;
use crate::gpu::{GpuContext, GpuError};
use crate::initial::{chain_from_particle_file, chain_from_profiles, Chain};
use crate::observables::Snapshot;
use crate::output::{prepare_dir, write_manifest, write_npy, NpyStream};
use crate::plan::Plan;
use crate::plot::{plot_profiles, plot_series, ProfilePlot};
use crate::scene::{Backend, InitialSpec, Precision, Scene};

#[derive(Debug, Clone)]
pub struct RunOptions {
    pub out_dir: PathBuf,
    pub backend: Option<Backend>,
    pub precision: Option<Precision>,
    pub quiet: bool,
}

#[derive(Debug, Clone)]
pub struct RunSummary {
    pub out_dir: PathBuf,
    pub backend: String,
    /// The adapter that ran it, "name (backend)", or the CPU description.
    pub adapter: String,
    pub members: usize,
    pub failed: usize,
    pub wall_seconds: f64,
}

/// Builds the initial chain a scene describes.
pub fn initial_chain(scene: &Scene) -> Result<Chain> {
    match &scene.initial {
        InitialSpec::Profiles {
            rho,
            velocity,
            rho_star,
        } => {
            let n = scene.particles.ok_or_else(|| {
                Error::missing("model.particles", "required with profile initial data")
            })?;
            chain_from_profiles(n, rho, velocity, rho_star.as_ref())
        }
        InitialSpec::Particles { path, radius } => {
            chain_from_particle_file(path, *radius, scene.particles)
        }
    }
}

/// The CPU path, described like a GPU adapter (for stderr and the manifest).
fn cpu_adapter(fallback_reason: Option<&str>) -> (String, serde_json::Value) {
    let threads = rayon::current_num_threads();
    let name = format!("cpu (rayon, {threads} threads)");
    let value = json!({
        "name": name,
        "backend": "cpu",
        "driver": "rayon",
        "device_type": "Cpu",
        "threads": threads,
        "supports_f64": true,
        "fallback_reason": fallback_reason,
    });
    (name, value)
}

/// Why `backend = "auto"` did not use the GPU, from the error of [`GpuContext::acquire`].
fn fallback_reason(e: &GpuError) -> String {
    match e {
        // The message already starts "no GPU adapter found".
        GpuError::NoAdapter { .. } => e.to_string(),
        GpuError::NoF64 { .. } => format!("no GPU adapter with f64 shaders: {e}"),
        _ => format!("no usable GPU adapter: {e}"),
    }
}

/// `GpuContext::acquire` failed for `backend = "gpu"`: name the setting and what to do.
fn gpu_acquire_error(e: GpuError, precision: Precision) -> Error {
    match (&e, precision) {
        (GpuError::NoF64 { .. }, Precision::F64) => Error::gpu(
            "solver.precision = \"f64\" with backend \"gpu\"",
            e,
            "; use precision \"f32\" on this adapter, or backend \"cpu\" for f64",
        ),
        _ => Error::gpu(
            "solver.backend = \"gpu\"",
            e,
            "; or use backend \"cpu\" (or \"auto\", which falls back to the CPU)",
        ),
    }
}

/// The solver that runs: one output loop for both backends.
#[allow(clippy::large_enum_variant)] // one value per run, on the stack
enum Solver<'a> {
    Cpu(CpuSolver),
    Gpu(GpuSolver<'a>),
}

impl Solver<'_> {
    /// Next output time's snapshots (see `CpuSolver::next_output`); advances `progress` by one
    /// per member and output interval.
    fn next_output(
        &mut self,
        progress: &ProgressBar,
    ) -> std::result::Result<Option<Vec<Snapshot>>, GpuError> {
        match self {
            Solver::Cpu(s) => Ok(s.next_output(Some(progress))),
            Solver::Gpu(s) => {
                let snaps = s.next_output()?;
                if let Some(v) = &snaps {
                    progress.inc(v.len() as u64);
                }
                Ok(snaps)
            }
        }
    }

    fn grid(&self) -> &[f64] {
        match self {
            Solver::Cpu(s) => s.grid(),
            Solver::Gpu(s) => s.grid(),
        }
    }

    fn reports(&self) -> Vec<MemberReport> {
        match self {
            Solver::Cpu(s) => s.reports(),
            Solver::Gpu(s) => s.reports(),
        }
    }

    /// The GPU's work counters, for the manifest (`None` on the CPU).
    fn gpu_stats(&self) -> Option<serde_json::Value> {
        match self {
            Solver::Cpu(_) => None,
            Solver::Gpu(s) => {
                let st = s.stats();
                Some(json!({
                    "dispatches": st.dispatches,
                    "steps": st.steps,
                    "submits": st.submits,
                    "readbacks": st.readbacks,
                    "bytes_read": st.bytes_read,
                    "bytes_written": st.bytes_written,
                    "attempts_per_dispatch": st.attempts_per_dispatch,
                    "dispatches_per_submit": st.dispatches_per_submit,
                }))
            }
        }
    }
}

pub fn run_scene(scene: &Scene, options: &RunOptions) -> Result<RunSummary> {
    let started = Instant::now();
    let requested = options.backend.unwrap_or(scene.backend);
    let precision = options.precision.unwrap_or(scene.precision);
    if requested == Backend::Cpu && precision == Precision::F32 {
        return Err(Error::invalid(
            "solver.precision",
            "\"f32\"",
            "the CPU reference path computes in f64 only",
            "\"f64\" with backend \"cpu\"; \"f32\" with backend \"gpu\" or \"auto\" and a GPU adapter",
        ));
    }
    let auto_f32_error = |why: String| {
        Error::invalid(
            "solver.precision",
            "\"f32\"",
            format!(
                "backend \"auto\" cannot use the GPU ({why}) and the CPU path computes in f64 only"
            ),
            "\"f64\" without a usable GPU adapter",
        )
    };

    // Everything a user supplies is validated before the directory is touched.
    let chain = initial_chain(scene)?;
    let plan = Plan::new(scene, &chain);
    let b_members = plan.members.len();

    // The GPU context (when one is used) outlives the solver, which borrows it.
    let mut fallback: Option<String> = None;
    let ctx: Option<GpuContext> = match requested {
        Backend::Cpu => None,
        Backend::Gpu => Some(
            GpuContext::acquire(precision == Precision::F64)
                .map_err(|e| gpu_acquire_error(e, precision))?,
        ),
        Backend::Auto => match GpuContext::acquire(precision == Precision::F64) {
            Ok(c) => Some(c),
            Err(e) => {
                let why = fallback_reason(&e);
                if precision == Precision::F32 {
                    return Err(auto_f32_error(why));
                }
                fallback = Some(why);
                None
            }
        },
    };
    let mut solver = match &ctx {
        Some(c) => match GpuSolver::new(c, plan.clone(), vec![chain.clone(); b_members], precision)
        {
            Ok(s) => Solver::Gpu(s),
            Err(e) if requested == Backend::Auto => {
                let why = format!(
                    "the GPU backend cannot run this scene on {}: {e}",
                    c.description.short()
                );
                if precision == Precision::F32 {
                    return Err(auto_f32_error(why));
                }
                fallback = Some(why);
                Solver::Cpu(CpuSolver::new(plan.clone(), vec![chain; b_members]))
            }
            Err(e) => {
                return Err(Error::gpu(
                    format!("solver.backend = \"gpu\" on {}", c.description.short()),
                    e,
                    "; use backend \"cpu\" (or \"auto\", which falls back to the CPU)",
                ))
            }
        },
        None => Solver::Cpu(CpuSolver::new(plan.clone(), vec![chain; b_members])),
    };

    let (backend_name, adapter_json, adapter_short, backend_line) = match (&solver, &ctx) {
        (Solver::Gpu(_), Some(c)) => {
            let d = &c.description;
            let how = if requested == Backend::Auto {
                "backend auto: a GPU adapter is present; running on the GPU"
            } else {
                "backend gpu"
            };
            (
                "gpu",
                serde_json::to_value(d).unwrap_or(serde_json::Value::Null),
                d.short(),
                format!(
                    "{how}: {} ({}, driver {} {}, {}), precision {}",
                    d.name,
                    d.backend,
                    d.driver,
                    d.driver_info,
                    d.device_type,
                    precision_name(precision)
                ),
            )
        }
        _ => {
            let (name, value) = cpu_adapter(fallback.as_deref());
            let line = match &fallback {
                Some(why) => format!(
                    "backend auto: {why}; running on the CPU: {name}, precision {}",
                    precision_name(precision)
                ),
                None if requested == Backend::Auto => format!(
                    "backend auto: running on the CPU: {name}, precision {}",
                    precision_name(precision)
                ),
                None => format!(
                    "backend cpu: {name}, precision {}",
                    precision_name(precision)
                ),
            };
            (
                "cpu",
                value,
                format!("rayon, {} threads", rayon::current_num_threads()),
                line,
            )
        }
    };
    if !options.quiet {
        eprintln!("{backend_line}");
    }

    let dir = &options.out_dir;
    prepare_dir(dir)?;
    let b = plan.members.len() as u64;
    let n = plan.particles as u64;
    let t_count = plan.output_times.len() as u64;
    let g = plan.grid as u64;
    let f = plan.fields;
    let open = |name: &str, shape: &[u64], on: bool| -> Result<Option<NpyStream>> {
        on.then(|| NpyStream::create(dir.join(name), shape))
            .transpose()
    };
    let mut gaps_out = open("gaps.npy", &[t_count, b, n], f.gaps)?;
    let mut vel_out = open("velocities.npy", &[t_count, b, n - 1], f.velocities)?;
    let mut rho_out = open("rho.npy", &[t_count, b, g], f.rho)?;
    let mut u_out = open("u.npy", &[t_count, b, g], f.u)?;
    let mut rho_star_out = open("rho_star.npy", &[t_count, b, g], f.rho_star)?;
    let mut energy = Vec::with_capacity((t_count * b) as usize);
    let mut dissipation = Vec::with_capacity((t_count * b) as usize);
    let mut min_gap = Vec::with_capacity((t_count * b) as usize);
    let mut max_density = Vec::with_capacity((t_count * b) as usize);

    let plotted = if scene.plots {
        scene.plot_members.min(plan.members.len())
    } else {
        0
    };
    let mut plot_rho: Vec<Vec<Vec<f64>>> = vec![Vec::new(); plotted];
    let mut plot_u: Vec<Vec<Vec<f64>>> = vec![Vec::new(); plotted];
    let mut plot_rho_star: Vec<Vec<Vec<f64>>> = vec![Vec::new(); plotted];

    let progress = ProgressBar::with_draw_target(Some(b * t_count), ProgressDrawTarget::hidden());
    progress.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:40}] {pos}/{len} member-intervals, eta {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let mut shown = false;
    let mut k = 0;
    while let Some(snaps) = solver.next_output(&progress).map_err(|e| {
        Error::gpu(
            format!("backend gpu on {adapter_short}"),
            e,
            "; the outputs written so far are incomplete (no manifest)",
        )
    })? {
        // The bar appears only for runs longer than a second.
        if !options.quiet && !shown && started.elapsed() > Duration::from_secs(1) {
            progress.set_draw_target(ProgressDrawTarget::stderr());
            shown = true;
        }
        for (m, s) in snaps.iter().enumerate() {
            push(&mut gaps_out, &s.gaps)?;
            push(&mut vel_out, &s.velocities)?;
            push(&mut rho_out, &s.rho)?;
            push(&mut u_out, &s.u)?;
            push(&mut rho_star_out, &s.rho_star)?;
            energy.push(s.energy);
            dissipation.push(s.dissipation);
            min_gap.push(s.min_gap);
            max_density.push(s.max_density);
            if m < plotted {
                record_for_plot(
                    &mut plot_rho[m],
                    &mut plot_u[m],
                    &mut plot_rho_star[m],
                    s,
                    &plan,
                );
            }
        }
        k += 1;
    }
    progress.finish_and_clear();
    debug_assert_eq!(k as u64, t_count);

    let mut files = Vec::new();
    for s in [gaps_out, vel_out, rho_out, u_out, rho_star_out]
        .into_iter()
        .flatten()
    {
        files.push(s.finish()?);
    }
    files.push(write_npy(
        dir.join("times.npy"),
        &[t_count],
        &plan.output_times,
    )?);
    files.push(write_npy(dir.join("x.npy"), &[g], solver.grid())?);
    if f.energy {
        files.push(write_npy(dir.join("energy.npy"), &[t_count, b], &energy)?);
        files.push(write_npy(
            dir.join("dissipation.npy"),
            &[t_count, b],
            &dissipation,
        )?);
    }
    files.push(write_npy(dir.join("min_gap.npy"), &[t_count, b], &min_gap)?);
    files.push(write_npy(
        dir.join("max_density.npy"),
        &[t_count, b],
        &max_density,
    )?);

    let reports = solver.reports();
    if plotted > 0 {
        let plot_dir = dir.join("plots");
        std::fs::create_dir_all(&plot_dir).map_err(|e| Error::io(&plot_dir, e))?;
        for m in 0..plotted {
            let p = &plan.members[m];
            let title = format!(
                "{} - member {m} (mu = {}, gamma = {})",
                scene.name, p.mu, p.gamma
            );
            let path = plot_dir.join(format!("member_{m:04}.png"));
            plot_profiles(
                &path,
                &ProfilePlot {
                    title: &title,
                    x: solver.grid(),
                    times: &plan.output_times,
                    rho: &plot_rho[m],
                    u: &plot_u[m],
                    rho_star: plan.repulsion.then_some(plot_rho_star[m].as_slice()),
                },
            )?;
            files.push(path);
        }
        let series: Vec<(String, Vec<f64>)> = (0..plan.members.len().min(16))
            .map(|m| {
                let p = &plan.members[m];
                (
                    format!("mu={} gamma={}", p.mu, p.gamma),
                    (0..t_count as usize)
                        .map(|t| max_density[t * b as usize + m])
                        .collect(),
                )
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
    }

    let wall = started.elapsed().as_secs_f64();
    let failed = reports
        .iter()
        .filter(|r| r.status != MemberStatus::Ok)
        .count();
    let manifest = manifest_json(
        scene,
        &plan,
        &BackendRecord {
            requested,
            name: backend_name,
            adapter: adapter_json,
            gpu_stats: solver.gpu_stats(),
        },
        precision,
        wall,
        &reports,
        &files,
        dir,
    );
    write_manifest(dir, &manifest)?;
    Ok(RunSummary {
        out_dir: dir.clone(),
        backend: backend_name.to_string(),
        adapter: adapter_short,
        members: reports.len(),
        failed,
        wall_seconds: wall,
    })
}

fn push(stream: &mut Option<NpyStream>, values: &[f64]) -> Result<()> {
    match stream {
        Some(s) => s.push(values),
        None => Ok(()),
    }
}

fn record_for_plot(
    rho: &mut Vec<Vec<f64>>,
    u: &mut Vec<Vec<f64>>,
    rho_star: &mut Vec<Vec<f64>>,
    s: &Snapshot,
    plan: &Plan,
) {
    // Plots need the fields even when they are not written.
    let grid = plan.grid;
    let nan = || vec![f64::NAN; grid];
    rho.push(if s.rho.is_empty() {
        nan()
    } else {
        s.rho.clone()
    });
    u.push(if s.u.is_empty() { nan() } else { s.u.clone() });
    rho_star.push(if s.rho_star.is_empty() {
        nan()
    } else {
        s.rho_star.clone()
    });
}

fn precision_name(p: Precision) -> &'static str {
    match p {
        Precision::F64 => "f64",
        Precision::F32 => "f32",
    }
}

/// What ran the scene, for the manifest.
struct BackendRecord {
    requested: Backend,
    /// "cpu" or "gpu".
    name: &'static str,
    /// The GPU's `AdapterDescription`, or the CPU described the same way.
    adapter: serde_json::Value,
    gpu_stats: Option<serde_json::Value>,
}

#[allow(clippy::too_many_arguments)]
fn manifest_json(
    scene: &Scene,
    plan: &Plan,
    backend: &BackendRecord,
    precision: Precision,
    wall: f64,
    reports: &[MemberReport],
    files: &[PathBuf],
    dir: &Path,
) -> serde_json::Value {
    let names: Vec<String> = files
        .iter()
        .map(|p| p.strip_prefix(dir).unwrap_or(p).display().to_string())
        .collect();
    json!({
        "roughlub_version": env!("CARGO_PKG_VERSION"),
        "scene": {
            "name": scene.name,
            "description": scene.description,
            "path": scene.source_path.display().to_string(),
            "text": scene.source_text,
        },
        "backend": backend.name,
        "backend_requested": backend.requested,
        "adapter": backend.adapter,
        "gpu_stats": backend.gpu_stats,
        "precision": precision,
        "wall_seconds": wall,
        "particles": plan.particles,
        "eps": plan.eps,
        "order": plan.order,
        "stepping": plan.stepping,
        "plan": plan.summary(),
        "output_times": plan.output_times,
        "grid": plan.grid,
        "members": reports,
        "failed_members": reports.iter().filter(|r| r.status != MemberStatus::Ok).map(|r| r.index).collect::<Vec<_>>(),
        "steps_accepted_total": reports.iter().map(|r| r.steps_accepted).sum::<u64>(),
        "steps_rejected_total": reports.iter().map(|r| r.steps_rejected).sum::<u64>(),
        "files": names,
        "conventions": {
            "failed_members": "rows of a member after it failed are NaN; its status gives the reason and time",
            "gaps": "d_i = q_i - q_{i-1} - 2 eps, i = 1..N (index i-1)",
            "velocities": "u_i, i = 1..N-1 (index i-1); u_0 = u_N = 0",
            "fields": "sampled at x.npy; rho and rho_star piecewise constant on [q_{i-1}, q_i), u piecewise linear",
        },
    })
}
