//! The `roughlub` command.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use roughlub::backend::{Backend, Precision};
use roughlub::converge::{run_convergence, ConvergeOptions, ConvergeSummary};
use roughlub::error::Error;
use roughlub::run::{run_scene, RunOptions, RunSummary};
use roughlub::scene::Scene;
use roughlub::study::{merge_studies, run_study, StudyOptions, StudySummary};

#[derive(Parser)]
#[command(
    name = "roughlub",
    version,
    about = "Batched simulation of chains of rough particles interacting through lubrication"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a scene and write its outputs (an ensemble study when the scene has [ensemble]).
    Run {
        /// Scene file (TOML).
        scene: PathBuf,
        /// Output directory [default: out/<scene name>].
        #[arg(long)]
        out: Option<PathBuf>,
        #[command(flatten)]
        overrides: BackendArgs,
        /// No progress bar and no summary line.
        #[arg(long)]
        quiet: bool,
        /// Ensembles only: solve shard K of N (K from 0), e.g. --shard 3/1000.
        #[arg(long)]
        shard: Option<String>,
        /// Ensembles only: finish an interrupted run in the same directory from its last checkpoint.
        #[arg(long)]
        resume: bool,
        /// Ensembles only: seconds of solving between checkpoints of the finished chunks (what an
        /// interrupted run can lose; 0 = after every chunk, inf = never) [default: 60]
        #[arg(long, value_name = "SECONDS")]
        checkpoint_every: Option<f64>,
        #[command(flatten)]
        replace: ReplaceArgs,
        /// Write outputs larger than 21.5 GB, sweep more than 100000 points, or run a study whose memory estimate exceeds half the machine's memory (refused otherwise).
        #[arg(long)]
        allow_large: bool,
    },
    /// Measure the speed/accuracy trade on a scene: a reference, a ladder of settings (orders x
    /// tolerances and fixed steps), work_precision.csv and .png, and the cheapest setting that
    /// meets --target. Uses the scene's first member(s), or in a parameter study members spread
    /// over its sweep points (the first and the last among them), judged by the worst.
    Accuracy {
        /// Scene file (TOML).
        scene: PathBuf,
        /// The error to reach (largest of: relative gap error, relative velocity error, L1 of rho).
        #[arg(long, default_value_t = 1e-6)]
        target: f64,
        /// Output directory [default: out/<scene name>_accuracy].
        #[arg(long)]
        out: Option<PathBuf>,
        /// How many members to measure: the scene's first (default 1), or in a parameter study
        /// one at each of K sweep points spread over the sweep, first and last included (default
        /// 4 points), and more per point when K exceeds the points.
        #[arg(long)]
        members: Option<usize>,
        /// Backends and precisions of the ladder: a comma list of cpu (f64), cpu-f32, gpu (f64),
        /// gpu-f32, or "available": the CPU in f64 and f32, and the GPU in f64 and f32 where an
        /// adapter is found.
        #[arg(long, default_value = "available")]
        backends: String,
        /// No progress lines (the recommendation is still printed, on stdout).
        #[arg(long)]
        quiet: bool,
        #[command(flatten)]
        replace: ReplaceArgs,
    },
    /// Merge the partial statistics of ensemble shards into the statistics of the whole study.
    Merge {
        /// Shard output directories.
        #[arg(required = true)]
        dirs: Vec<PathBuf>,
        /// Output directory of the merged study.
        #[arg(long)]
        out: PathBuf,
        /// Skip the plots.
        #[arg(long)]
        no_plots: bool,
        /// Merge even when shards are missing (stderr and the manifest name the missing members).
        #[arg(long)]
        allow_partial: bool,
        #[command(flatten)]
        replace: ReplaceArgs,
    },
    /// Convergence in N: the scene at each particle number N (Prop. 3.1 initial data), the
    /// differences between successive N, observed rates and an extrapolated limit.
    Converge {
        /// Scene file (TOML) with profile initial data (no particle file, no [ensemble]).
        scene: PathBuf,
        /// Particle numbers N, strictly increasing, comma-separated: 100,200,400,800 (at least
        /// 3 for a rate, 4 to judge whether it is asymptotic).
        #[arg(long, value_delimiter = ',', required = true)]
        particles: Vec<usize>,
        /// Output directory [default: out/<scene name>_converge].
        #[arg(long)]
        out: Option<PathBuf>,
        #[command(flatten)]
        overrides: BackendArgs,
        /// No progress bar and no summary (warnings are still printed).
        #[arg(long)]
        quiet: bool,
        #[command(flatten)]
        replace: ReplaceArgs,
    },
}

/// The scene's backend and precision, overridden (`run`, `converge`).
#[derive(clap::Args)]
struct BackendArgs {
    /// Override the scene's backend.
    #[arg(long, value_enum)]
    backend: Option<Backend>,
    /// Override the scene's precision.
    #[arg(long, value_enum)]
    precision: Option<Precision>,
}

/// What a command that writes an --out directory does with one that is not a roughlub run.
#[derive(clap::Args)]
struct ReplaceArgs {
    /// Replace an --out directory that holds files that are not a roughlub run.
    #[arg(long)]
    force: bool,
}

/// `--backends cpu,gpu,gpu-f32` or `available`.
fn parse_backends(
    text: &str,
    adapter_name: Option<&str>,
) -> roughlub::Result<Vec<(Backend, Precision)>> {
    if text.trim() == "available" {
        let mut found = vec![
            (Backend::Cpu, Precision::F64),
            (Backend::Cpu, Precision::F32),
        ];
        // An adapter is looked for once; its f64 support decides the f64 line.
        if let Ok(ctx) = roughlub::backend::gpu::GpuContext::acquire_among(false, adapter_name) {
            if ctx.f64 {
                found.push((Backend::Gpu, Precision::F64));
            }
            found.push((Backend::Gpu, Precision::F32));
        }
        return Ok(found);
    }
    let pairs = text
        .split(',')
        .map(|b| match b.trim() {
            "cpu" | "cpu-f64" => Ok((Backend::Cpu, Precision::F64)),
            "cpu-f32" => Ok((Backend::Cpu, Precision::F32)),
            "gpu" | "gpu-f64" => Ok((Backend::Gpu, Precision::F64)),
            "gpu-f32" => Ok((Backend::Gpu, Precision::F32)),
            "available" => Err(Error::invalid(
                "--backends",
                format!("\"{text}\""),
                "\"available\" stands for every backend found, so it stands alone",
                "a comma list of cpu (f64), cpu-f32, gpu (f64), gpu-f32, or available alone",
            )),
            other => Err(Error::invalid(
                "--backends",
                format!("\"{other}\""),
                "a backend and precision of the ladder",
                "a comma list of cpu (f64), cpu-f32, gpu (f64), gpu-f32, or available alone",
            )),
        })
        .collect::<roughlub::Result<Vec<_>>>()?;
    // A pair named twice (`cpu,cpu-f64`) is measured once.
    let mut unique = Vec::new();
    for pair in pairs {
        if !unique.contains(&pair) {
            unique.push(pair);
        }
    }
    Ok(unique)
}

fn parse_shard(text: &str) -> roughlub::Result<(u64, u64)> {
    let bad = || {
        Error::invalid(
            "--shard",
            format!("\"{text}\""),
            "shard K of N, K counted from 0",
            "K/N with 0 <= K < N, e.g. 0/10",
        )
    };
    let (k, n) = text.split_once('/').ok_or_else(bad)?;
    let k: u64 = k.trim().parse().map_err(|_| bad())?;
    let n: u64 = n.trim().parse().map_err(|_| bad())?;
    if n == 0 || k >= n {
        return Err(bad());
    }
    Ok((k, n))
}

/// The end-of-run line's error estimate: a number, or why there is none.
fn estimate_text(largest: Option<f64>, available: bool) -> String {
    match (largest, available) {
        (Some(e), _) => format!("{e:.2e} (see \"error_estimate\" in the manifest)"),
        (None, true) => "none (no member completed)".into(),
        (None, false) => "unavailable (order 1 with fixed steps, error_estimate = false)".into(),
    }
}

/// The warnings at the end of a run or study, printed even with --quiet: a largest error
/// estimate that says it is not converged, and failed members (`where_listed` says where).
fn warn_at_end(estimate_warning: Option<&str>, failed: u64, where_listed: &str) {
    if let Some(w) = estimate_warning {
        eprintln!("warning: {w}");
    }
    if failed > 0 {
        eprintln!("warning: {failed} member(s) failed; {where_listed}");
    }
}

fn report_study(summary: &StudySummary, quiet: bool) {
    if !quiet {
        eprintln!(
            "{} members ({} failed, {} chunks reused) in {:.2} s (statistics {:.1} %); largest error estimate {}; outputs in {}",
            summary.members,
            summary.failed,
            summary.chunks_reused,
            summary.wall_seconds,
            100.0 * summary.statistics_seconds / summary.wall_seconds.max(1e-12),
            estimate_text(
                summary.largest_error_estimate,
                summary.error_estimate_available,
            ),
            summary.out_dir.display()
        );
    }
    warn_at_end(
        summary.error_estimate_warning.as_deref(),
        summary.failed,
        "they are counted and listed (\"failed_members\" in the manifest, status in members.csv), never averaged in",
    );
}

/// The end of a convergence run on stderr: per field its differences, rates and verdict.
fn report_convergence(summary: &ConvergeSummary, quiet: bool) {
    if !quiet {
        for f in &summary.fields {
            eprintln!(
                "{}: L1 differences at the last output time {:?}, rates {:?}, rate at the largest pair {:.3} ({}), limit error estimate {:.3e}",
                f.field,
                f.diff_l1.iter().map(|e| format!("{e:.3e}")).collect::<Vec<_>>(),
                f.rates_l1.iter().map(|p| format!("{p:.3}")).collect::<Vec<_>>(),
                f.rate,
                f.verdict.name(),
                f.limit_error_l1
            );
        }
        eprintln!(
            "N = {:?} on {} ({}) in {:.2} s; {}; outputs in {}",
            summary.particles,
            summary.backend,
            summary.adapter,
            summary.wall_seconds,
            if summary.asymptotic {
                "rates asymptotic at every output time"
            } else {
                "NOT asymptotic everywhere (see the warnings)"
            },
            summary.out_dir.display()
        );
    }
}

/// The end of a single run on stderr: members, failures, the largest error estimate (and the
/// warnings, even with --quiet).
fn report_scene(summary: &RunSummary, quiet: bool) {
    if !quiet {
        eprintln!(
            "{} members ({} failed) on {} ({}) in {:.2} s; largest error estimate {}; outputs in {}",
            summary.members,
            summary.failed,
            summary.backend,
            summary.adapter,
            summary.wall_seconds,
            estimate_text(
                summary.largest_error_estimate,
                summary.error_estimate_available,
            ),
            summary.out_dir.display()
        );
    }
    // The run itself succeeded; failed members are data, listed in the manifest.
    warn_at_end(
        summary.error_estimate_warning.as_deref(),
        summary.failed as u64,
        "see \"failed_members\" in the manifest",
    );
}

fn main() -> ExitCode {
    // SAFETY: no other thread exists yet.
    unsafe { roughlub::backend::gpu::context::quiet_mesa_device_select() };
    // Every variable roughlub reads, read once, here, and passed down with each scene.
    let overrides = roughlub::backend::overrides::Overrides::from_env();
    // `warn_ignored`: say which settings the scene's own order ignores (not for accuracy, whose
    // ladder runs every order with them).
    let load = |path: &std::path::Path, warn_ignored: bool| -> roughlub::Result<Scene> {
        let mut scene = Scene::from_file(path)?;
        if warn_ignored {
            for note in scene.ignored_settings() {
                eprintln!("warning: {note}");
            }
        }
        scene.overrides = overrides.clone();
        Ok(scene)
    };
    let cli = Cli::parse();
    let result: roughlub::Result<()> = match cli.command {
        Command::Run {
            scene,
            out,
            overrides: BackendArgs { backend, precision },
            quiet,
            shard,
            resume,
            checkpoint_every,
            replace: ReplaceArgs { force },
            allow_large,
        } => (|| {
            let scene = load(&scene, true)?;
            let out_dir = out.unwrap_or_else(|| PathBuf::from("out").join(&scene.name));
            if scene.ensemble.is_some() {
                let shard = shard
                    .as_deref()
                    .map(parse_shard)
                    .transpose()?
                    .unwrap_or((0, 1));
                let summary = run_study(
                    &scene,
                    &StudyOptions {
                        out_dir,
                        backend,
                        precision,
                        quiet,
                        shard,
                        resume,
                        force,
                        allow_large,
                        checkpoint_seconds: checkpoint_every
                            .unwrap_or(roughlub::study::DEFAULT_CHECKPOINT_SECONDS),
                    },
                )?;
                report_study(&summary, quiet);
                return Ok(());
            }
            if shard.is_some() || resume || checkpoint_every.is_some() {
                return Err(Error::missing(
                    if resume {
                        "--resume"
                    } else if shard.is_some() {
                        "--shard"
                    } else {
                        "--checkpoint-every"
                    },
                    "only for ensemble scenes (with an [ensemble] section)",
                ));
            }
            let summary = run_scene(
                &scene,
                &RunOptions {
                    out_dir,
                    backend,
                    precision,
                    quiet,
                    force,
                    allow_large,
                },
            )?;
            report_scene(&summary, quiet);
            Ok(())
        })(),
        Command::Accuracy {
            scene,
            target,
            out,
            members,
            backends,
            quiet,
            replace: ReplaceArgs { force },
        } => (|| {
            let scene = load(&scene, false)?;
            let backends = parse_backends(&backends, overrides.adapter_name.as_deref())?;
            let out_dir = out
                .unwrap_or_else(|| PathBuf::from("out").join(format!("{}_accuracy", scene.name)));
            roughlub::accuracy::run_accuracy(
                &scene,
                &roughlub::accuracy::AccuracyOptions {
                    out_dir,
                    target,
                    members,
                    backends,
                    quiet,
                    force,
                },
            )
            .map(|_| ())
        })(),
        Command::Merge {
            dirs,
            out,
            no_plots,
            allow_partial,
            replace: ReplaceArgs { force },
        } => merge_studies(&dirs, &out, !no_plots, allow_partial, force)
            .map(|s| report_study(&s, false)),
        Command::Converge {
            scene,
            particles,
            out,
            overrides: BackendArgs { backend, precision },
            quiet,
            replace: ReplaceArgs { force },
        } => (|| {
            let scene = load(&scene, true)?;
            let out_dir = out
                .unwrap_or_else(|| PathBuf::from("out").join(format!("{}_converge", scene.name)));
            let summary = run_convergence(
                &scene,
                &ConvergeOptions {
                    out_dir,
                    particles,
                    backend,
                    precision,
                    quiet,
                    force,
                },
            )?;
            report_convergence(&summary, quiet);
            Ok(())
        })(),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(2)
        }
    }
}
