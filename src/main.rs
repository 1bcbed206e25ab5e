//! The `roughlub` command.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use roughlub::run::{run_scene, RunOptions};
use roughlub::scene::{Backend, Precision, Scene};

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
    /// Run a scene and write its outputs.
    Run {
        /// Scene file (TOML).
        scene: PathBuf,
        /// Output directory [default: out/<scene name>].
        #[arg(long)]
        out: Option<PathBuf>,
        /// Override the scene's backend: cpu, gpu or auto.
        #[arg(long)]
        backend: Option<String>,
        /// Override the scene's precision: f64 or f32.
        #[arg(long)]
        precision: Option<String>,
        /// No progress bar and no summary line.
        #[arg(long)]
        quiet: bool,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Run {
            scene,
            out,
            backend,
            precision,
            quiet,
        } => {
            let result = (|| -> roughlub::Result<roughlub::run::RunSummary> {
                let scene = Scene::from_file(&scene)?;
                let backend: Option<Backend> = backend.as_deref().map(str::parse).transpose()?;
                let precision: Option<Precision> =
                    precision.as_deref().map(str::parse).transpose()?;
                let out_dir = out.unwrap_or_else(|| PathBuf::from("out").join(&scene.name));
                run_scene(
                    &scene,
                    &RunOptions {
                        out_dir,
                        backend,
                        precision,
                        quiet,
                    },
                )
            })();
            match result {
                Ok(summary) => {
                    if !quiet {
                        eprintln!(
                            "{} members ({} failed) on {} ({}) in {:.2} s; outputs in {}",
                            summary.members,
                            summary.failed,
                            summary.backend,
                            summary.adapter,
                            summary.wall_seconds,
                            summary.out_dir.display()
                        );
                    }
                    if summary.failed > 0 {
                        // The run itself succeeded; failed members are data, listed in the manifest.
                        eprintln!(
                            "warning: {} member(s) failed; see \"failed_members\" in the manifest",
                            summary.failed
                        );
                    }
                    ExitCode::SUCCESS
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    ExitCode::from(2)
                }
            }
        }
    }
}
