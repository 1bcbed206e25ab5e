//! scene → chain → plan → backend → observables → output directory.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use serde_json::json;

use crate::cpu::{CpuSolver, MemberReport, MemberStatus};
use crate::error::{Error, Result};
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

/// The backend that will run: (name for the manifest, a line for stderr).
fn choose_backend(requested: Backend, precision: Precision) -> Result<(String, String)> {
    match (requested, precision) {
        (Backend::Cpu | Backend::Auto, Precision::F64) => Ok((
            "cpu".into(),
            if requested == Backend::Auto {
                "backend auto: the GPU path is not built into this version; running on the CPU (f64, rayon)".into()
            } else {
                "backend cpu (f64, rayon)".into()
            },
        )),
        (Backend::Cpu | Backend::Auto, Precision::F32) => Err(Error::invalid(
            "solver.precision",
            "\"f32\"",
            "the CPU reference path computes in f64 only",
            "\"f64\" with backend \"cpu\"",
        )),
        (Backend::Gpu, _) => Err(Error::invalid(
            "solver.backend",
            "\"gpu\"",
            "the GPU path is not available in this version",
            "\"cpu\" or \"auto\"",
        )),
    }
}

pub fn run_scene(scene: &Scene, options: &RunOptions) -> Result<RunSummary> {
    let started = Instant::now();
    let requested = options.backend.unwrap_or(scene.backend);
    let precision = options.precision.unwrap_or(scene.precision);
    let (backend_name, backend_line) = choose_backend(requested, precision)?;

    // Everything a user supplies is validated before the directory is touched.
    let chain = initial_chain(scene)?;
    let plan = Plan::new(scene, &chain);
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

    let chains = vec![chain; plan.members.len()];
    let mut solver = CpuSolver::new(plan.clone(), chains);
    let progress = ProgressBar::with_draw_target(Some(b * t_count), ProgressDrawTarget::hidden());
    progress.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:40}] {pos}/{len} member-intervals, eta {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let mut shown = false;
    let mut k = 0;
    while let Some(snaps) = solver.next_output(Some(&progress)) {
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
        &backend_name,
        precision,
        wall,
        &reports,
        &files,
        dir,
    );
    write_manifest(dir, &manifest)?;
    Ok(RunSummary {
        out_dir: dir.clone(),
        backend: backend_name,
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

#[allow(clippy::too_many_arguments)]
fn manifest_json(
    scene: &Scene,
    plan: &Plan,
    backend: &str,
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
        "backend": backend,
        "adapter": serde_json::Value::Null,
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
