//! Ensemble studies (`[ensemble]` in a scene): thousands to millions of members that differ by
//! random roughness profiles, perturbed initial data and swept parameters, solved in chunks and
//! summarised by mergeable statistics. Member m's random inputs are a pure function of
//! (seed, m) ([`crate::scene::members`]), so its result does not depend on chunking, threads,
//! backend or shard.
//!
//! A fresh study is written into a staging directory beside `--out` (`.NAME.partial-PID`) and
//! swapped in whole when it completes, so `--out` is always a complete run (the earlier one until
//! then). `--resume` continues in `--out` when it holds the study, or adopts the staging
//! directory a killed fresh run left behind, from its last checkpoint.
//!
//! Layout of a study directory:
//! - `study.json`: what is being computed (scene text and hash, shard, member range, times, grid);
//!   written first, checked by `--resume` and `merge`;
//! - `checkpoint.state`: the statistics of the chunks finished so far and the length of
//!   `members.csv.partial` that holds their rows, written atomically every
//!   `--checkpoint-every` seconds while the study runs (`--resume` continues from it), removed
//!   when the study completes. Chunks add to the run's total in memory; a per-chunk copy of
//!   the statistics would cost as much as the members' own data for small chains;
//! - `partial.state`: the mergeable statistics of all members of this run (or shard);
//! - `stats/*.npy`, `members.csv`, `plots/*.png`, and `manifest.json` last.
//!
//! State files are binary ([`crate::output::state_file`], CBOR); study.json and the manifest
//! stay JSON.
//!
//! The code follows the pipeline: [`EnsembleMembers`](crate::scene::members::EnsembleMembers)
//! builds each member's inputs; `chunk.rs` solves a chunk of members through the backend seam and
//! summarises it into a [`StudyState`] (`state.rs`, everything mergeable); `files.rs` holds the
//! header, checkpoint and partial files, members.csv and the resume check; `report.rs` writes
//! `stats/*.npy` and the plots; `merge.rs` is `roughlub merge` over shards. This file
//! orchestrates a run ([`run_study`]).

mod chunk;
mod files;
mod memory;
mod merge;
mod report;
mod sensitivity;
mod state;

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::backend::report::run_error_estimate_method;
use crate::backend::{select, Backend, Engine, Precision};
use crate::error::{Error, Result};
use crate::output::manifest::{ErrorEstimateRecord, StudyManifest, StudySceneRecord, VERSION};
use crate::output::{
    prepare_dir, read_json, read_state, write_json_atomic, write_state_atomic, ProgressReporter,
    StagedDir, MANIFEST,
};
use crate::scene::members::EnsembleMembers;
use crate::scene::{EnsembleSpec, Scene};

use chunk::{chunk_plan, solve_chunk, RowBuffer, StudyCosts};
use files::{
    check_resume, check_state, header_for, shard_range, CheckpointFile, CheckpointFileRef, CsvOut,
    PartialFile, PartialFileRef,
};
use report::{finalize, quantile_method};

pub use crate::model::observables::peak_centre;
pub use files::{
    MemberRow, StudyHeader, MEMBER_COLUMNS, MEMBER_KEY_COLUMNS, POINT_COUNT_COLUMNS,
    POINT_INDEX_COLUMN,
};
pub use merge::merge_studies;
pub use state::StudyState;

/// The mergeable statistics of a run, shard or merge (a binary state file).
pub const PARTIAL: &str = "partial.state";
/// The finished chunks of a running study (see [`StudyOptions::checkpoint_seconds`]).
pub const CHECKPOINT: &str = "checkpoint.state";
/// Seconds between checkpoints unless `--checkpoint-every` says otherwise.
pub const DEFAULT_CHECKPOINT_SECONDS: f64 = 60.0;
/// What roughlub 0.1 wrote instead (JSON, state format 1): refused by name.
const OLD_PARTIAL: &str = "partial.json";

/// Scalar observables summarised at every output time.
pub const SCALARS: [&str; 6] = [
    "max_density",
    "min_gap",
    "energy",
    "dissipation",
    "peak_centre",
    "error_estimate",
];
/// The scalar that is absent (count 0) where the scheme gives no estimate (order 1, fixed steps).
pub const ERROR_ESTIMATE: &str = "error_estimate";
/// Fields summarised pointwise over the grid at every output time.
pub const FIELDS: [&str; 3] = ["rho", "u", "rho_star"];
/// Relative accuracy of the scalar quantile sketches (values near 1, like densities, are then
/// resolved to 0.001).
pub const SCALAR_ALPHA: f64 = 0.001;
/// Bins of the scalar histograms (over each time's [min, max]).
pub const SCALAR_BINS: usize = 32;

#[derive(Debug, Clone)]
pub struct StudyOptions {
    pub out_dir: PathBuf,
    pub backend: Option<Backend>,
    pub precision: Option<Precision>,
    pub quiet: bool,
    /// (k, n): this run solves shard k of n (0-based).
    pub shard: (u64, u64),
    pub resume: bool,
    /// Replace an output directory that holds files but no roughlub run.
    pub force: bool,
    /// Accept more sweep points than [`MAX_SWEEP_POINTS`](crate::scene::MAX_SWEEP_POINTS).
    pub allow_large: bool,
    /// Seconds of solving between checkpoints of the finished chunks ([`CHECKPOINT`]): what an
    /// interrupted run can lose, against the time of writing the statistics so far (0: after
    /// every chunk).
    pub checkpoint_seconds: f64,
}

#[derive(Debug, Clone)]
pub struct StudySummary {
    pub out_dir: PathBuf,
    pub members: u64,
    pub failed: u64,
    pub chunks_reused: usize,
    pub wall_seconds: f64,
    pub statistics_seconds: f64,
    /// The largest completed member's error estimate at the end.
    pub largest_error_estimate: Option<f64>,
    /// Whether the scheme estimates its error at all (order 1 with fixed steps does not).
    pub error_estimate_available: bool,
    /// The manifest's warning about the largest estimate, if any.
    pub error_estimate_warning: Option<String>,
}

impl StudySummary {
    fn of(out_dir: &Path, state: &StudyState, chunks_reused: usize, wall: f64, stats: f64) -> Self {
        StudySummary {
            out_dir: out_dir.to_path_buf(),
            members: state.completed + state.failed.len() as u64,
            failed: state.failed.len() as u64,
            chunks_reused,
            wall_seconds: wall,
            statistics_seconds: stats,
            largest_error_estimate: None,
            error_estimate_available: false,
            error_estimate_warning: None,
        }
    }

    fn with_error_estimate(
        mut self,
        largest: Option<f64>,
        available: bool,
        warning: Option<String>,
    ) -> Self {
        self.largest_error_estimate = largest;
        self.error_estimate_available = available;
        self.error_estimate_warning = warning;
        self
    }
}

/// The study's backend, chosen by the one selection policy for a batch like its largest chunk.
fn select_for_study(
    scene: &Scene,
    spec: &EnsembleSpec,
    members: &EnsembleMembers,
    member_range: (u64, u64),
    options: &StudyOptions,
) -> Result<Engine> {
    let (first, end) = member_range;
    // Member `first` is built up front so that bad ensemble settings fail before anything is
    // written.
    let inputs = members.member(first)?;
    let largest_chunk = (spec.chunk as u64).min(end.saturating_sub(first)).max(1) as usize;
    let setup = inputs.setup.clone();
    let precision = options.precision.unwrap_or(scene.precision);
    let plan = chunk_plan(
        &setup.scene,
        &inputs.chain,
        vec![inputs.params; largest_chunk],
        spec.store_members,
        // The engine is chosen for the heaviest chunk: one with detailed members.
        true,
        precision,
    );
    select(options.backend.unwrap_or(scene.backend), precision, &plan)
}

/// `roughlub run` of an `[ensemble]` scene: solves this shard's members chunk by chunk (reusing
/// finished chunk files with `--resume`), merges their statistics, writes the report and the
/// manifest.
pub fn run_study(scene: &Scene, options: &StudyOptions) -> Result<StudySummary> {
    let started = Instant::now();
    let spec = scene
        .ensemble
        .as_ref()
        .ok_or_else(|| Error::missing("ensemble", "this scene has no [ensemble] section"))?;
    check_options(scene, options)?;
    let (k, n) = options.shard;
    let mut members = EnsembleMembers::new(scene, spec)?;
    let range = shard_range(members.total(), options.shard);
    let engine = select_for_study(scene, spec, &members, range, options)?;
    let mut header = header_for(
        scene,
        spec,
        &members,
        options.shard,
        &options.out_dir,
        &engine.record,
    );
    header.input_files = crate::output::input_file_hashes(&scene.files_read())?;
    // The order-1 error estimate solves a companion batch beside each chunk's.
    let solvers = if scene.error_estimate
        && crate::backend::companion::needs_companion_for(scene.order, scene.stepping)
    {
        2
    } else {
        1
    };
    // The largest chain of the study: where particles is swept, the largest point's (the
    // points hold N as it runs, rounded).
    let particles = header
        .sweep_names
        .iter()
        .position(|name| name == "particles")
        .and_then(|k| header.points.iter().map(|point| point[k] as usize).max())
        .map_or(members.first.chain.particles(), |largest| {
            largest.max(members.first.chain.particles())
        });
    let mut memory = memory::estimate(&header, spec, particles, solvers);
    // The points' setups built while checking them, kept for the solve.
    memory.bytes += members.prebuilt_bound(range, particles) as u64;
    let memory_limit = memory::memory_limit();
    let disk = memory::disk_bytes(&header, spec, particles, &memory);
    if !options.allow_large {
        memory::check(&memory, &header, spec, memory_limit)?;
        memory::check_disk(disk, &header, spec)?;
    }
    members.prepare(range)?;
    if !options.quiet {
        eprintln!(
            "ensemble {}: members {}..{} of {} (shard {k}/{n}); {}; estimated memory {:.3} GB (limit {:.1} GB), disk {:.3} GB",
            scene.name,
            header.member_range.0,
            header.member_range.1,
            header.members_total,
            engine.record.line(),
            memory.bytes as f64 / 1e9,
            memory_limit as f64 / 1e9,
            disk as f64 / 1e9,
        );
    }

    // A fresh study is built in a staging directory and swapped in whole at the end (the target
    // stays the earlier complete run until then); `--resume` continues in the target when it
    // holds the study, or adopts the staging directory an interrupted fresh run left beside it.
    let (dir, staged) = study_dir(&header, options)?;
    let dir = &dir;
    if let Some(complete) = complete_study(dir, staged.is_none(), &header, options)? {
        let wall = started.elapsed().as_secs_f64();
        // The estimate and its warning as the complete study's manifest recorded them (an
        // infinite or NaN estimate is written as the string "inf" or "NaN").
        let recorded = read_json::<serde_json::Value>(&dir.join(MANIFEST))
            .ok()
            .map(|m| m["error_estimate"].clone())
            .unwrap_or_default();
        let largest = recorded["largest"].as_f64().or_else(|| {
            recorded["largest"]
                .as_str()
                .and_then(|s| s.parse::<f64>().ok())
        });
        let warning = recorded["warning"].as_str().map(String::from);
        return Ok(StudySummary::of(&options.out_dir, &complete, 0, wall, 0.0)
            .with_error_estimate(
                largest,
                run_error_estimate_method(scene.order, scene.stepping, scene.error_estimate)
                    .is_some(),
                warning,
            ));
    }
    let chunks_dir = dir.join("chunks");
    if chunks_dir.is_dir() {
        // Chunk files of roughlub 0.2.0's interrupted runs: this version checkpoints instead.
        if !options.quiet {
            eprintln!(
                "{}: chunk files of an earlier roughlub are not reused; their members are solved again",
                chunks_dir.display()
            );
        }
        std::fs::remove_dir_all(&chunks_dir).map_err(|e| Error::io(&chunks_dir, e))?;
    }
    prepare_dir(dir)?;
    write_json_atomic(&dir.join("study.json"), &header)?;

    let solved = solve_chunks(dir, spec, &members, &header, &engine, options)?;
    let SolvedChunks {
        state,
        chunks,
        reused,
        largest_error_estimate,
        mut costs,
    } = solved;
    let t0 = Instant::now();
    // The state for merges and the statistics' files read the same state: written side by side.
    let (partial, stats_files) = rayon::join(
        || {
            write_state_atomic(
                &dir.join(PARTIAL),
                &PartialFileRef {
                    header: &header,
                    state: &state,
                },
            )
        },
        || finalize(dir, &[header.clone()], &state, scene.plots),
    );
    partial?;
    stats_files?;
    // partial.state and members.csv hold everything the checkpoint did.
    let checkpoint_path = dir.join(CHECKPOINT);
    if checkpoint_path.exists() {
        std::fs::remove_file(&checkpoint_path).map_err(|e| Error::io(&checkpoint_path, e))?;
    }
    costs.statistics_seconds += t0.elapsed().as_secs_f64();
    let wall = started.elapsed().as_secs_f64();
    let error_estimate = ErrorEstimateRecord::new(
        scene.order,
        scene.stepping,
        header.precision,
        scene.error_estimate,
        largest_error_estimate,
    );
    write_json_atomic(
        &dir.join(MANIFEST),
        &StudyManifest {
            roughlub_version: VERSION,
            kind: "ensemble",
            scene: StudySceneRecord {
                name: scene.name.clone(),
                text: scene.source_text.clone(),
                hash: header.scene_hash.clone(),
            },
            backend: engine.record.clone(),
            gpu_stats: costs.gpu,
            shard: (k, n),
            member_range: header.member_range,
            members_total: header.members_total,
            members_completed: state.completed,
            failed_members: state.failed.clone(),
            error_estimate: error_estimate.clone(),
            input_files: header.input_files.clone(),
            jacobian: scene.jacobian.record(scene.order, scene.stepping),
            sequence: header.sequence.clone(),
            chunks,
            chunks_reused: reused,
            chunks_solved_twice: costs.chunks_solved_twice,
            wall_seconds: wall,
            statistics_seconds: costs.statistics_seconds,
            statistics_share: costs.statistics_seconds / wall.max(1e-12),
            memory_estimate_bytes: memory.bytes,
            disk_estimate_bytes: disk,
            memory_limit_bytes: memory_limit,
            detailed_points: header.detailed_count(),
            band_fields: header.band_fields.clone(),
            state_format: crate::output::STATE_FORMAT,
            ensemble: spec.clone(),
            quantile_method: quantile_method(&header),
        },
    )?;
    if let Some(staged) = staged {
        staged.commit()?;
    }
    Ok(StudySummary::of(
        &options.out_dir,
        &state,
        reused,
        wall,
        costs.statistics_seconds,
    )
    .with_error_estimate(
        largest_error_estimate,
        run_error_estimate_method(scene.order, scene.stepping, scene.error_estimate).is_some(),
        error_estimate.warning,
    ))
}

/// With `--resume`: checks that `dir` holds this study (refusing the state format of an older
/// roughlub), and returns its state when `dir` is the target and already holds the study
/// complete (nothing to do then).
fn complete_study(
    dir: &Path,
    in_target: bool,
    header: &StudyHeader,
    options: &StudyOptions,
) -> Result<Option<StudyState>> {
    if !options.resume {
        return Ok(None);
    }
    if dir.join(OLD_PARTIAL).exists() && !dir.join(PARTIAL).exists() {
        return Err(crate::output::state_file::old_format_error(
            &dir.join(OLD_PARTIAL),
        ));
    }
    let header_path = dir.join("study.json");
    check_resume(&read_json(&header_path)?, header, &header_path)?;
    if !(in_target && dir.join(MANIFEST).exists() && dir.join(PARTIAL).exists()) {
        return Ok(None);
    }
    // A complete study: its chunks are merged into partial.state.
    let partial: PartialFile = read_state(&dir.join(PARTIAL))?;
    check_state(header, &partial.state, &dir.join(PARTIAL))?;
    let held: u64 = partial.state.ranges.iter().map(|(a, b)| b - a).sum();
    if held != header.member_range.1 - header.member_range.0 {
        return Ok(None);
    }
    if !options.quiet {
        eprintln!(
            "{} holds this study complete: nothing to resume",
            dir.display()
        );
    }
    Ok(Some(partial.state))
}

/// What [`solve_chunks`] leaves: the merged statistics, the chunk counts, the largest error
/// estimate of the rows written, and what the statistics cost.
struct SolvedChunks {
    state: StudyState,
    chunks: usize,
    reused: usize,
    largest_error_estimate: Option<f64>,
    costs: StudyCosts,
}

/// Solves the study's chunks in member order into `dir` (members.csv, and the checkpoint every
/// `options.checkpoint_seconds`), continuing from the checkpoint of an interrupted run with
/// `--resume`.
fn solve_chunks(
    dir: &Path,
    spec: &EnsembleSpec,
    members: &EnsembleMembers,
    header: &StudyHeader,
    engine: &Engine,
    options: &StudyOptions,
) -> Result<SolvedChunks> {
    let (first, end) = header.member_range;
    let bounds: Vec<(u64, u64)> = (first..end)
        .step_by(spec.chunk)
        .map(|a| (a, (a + spec.chunk as u64).min(end)))
        .collect();
    let progress = ProgressReporter::new(end - first, "members", options.quiet);
    let mut costs = StudyCosts::default();
    let checkpoint_path = dir.join(CHECKPOINT);
    // The chunks an interrupted run checkpointed, with the rows and error estimates they wrote.
    let checkpoint: Option<CheckpointFile> = if options.resume && checkpoint_path.exists() {
        let c: CheckpointFile = read_state(&checkpoint_path)?;
        check_state(header, &c.state, &checkpoint_path)?;
        Some(c)
    } else {
        None
    };
    let members_csv = dir.join("members.csv");
    let (mut total, mut csv_out, mut largest_error_estimate) = match checkpoint {
        Some(c) => (
            c.state,
            CsvOut::resume(members_csv, c.csv_bytes, c.csv_hash.as_deref())?,
            c.largest_error_estimate,
        ),
        None => (
            StudyState::new(),
            CsvOut::create(members_csv, &header.sweep_names)?,
            None,
        ),
    };
    let mut reused = 0;
    let mut last_checkpoint = Instant::now();
    let mut row_buffer = RowBuffer::default();
    // The chunks are solved on a thread of the pool that solves them: each parallel step then
    // has that thread as one of its workers, instead of handing the step to the pool and
    // sleeping until it is done (a wake-up of this thread for every step of every output).
    rayon::scope(|_| -> Result<()> {
        for &(a, b) in &bounds {
            if total.ranges.contains(&(a, b)) {
                reused += 1;
                progress.inc(b - a);
                continue;
            }
            let rows = solve_chunk(
                dir,
                spec,
                members,
                header,
                engine,
                (a, b),
                &mut total,
                &mut row_buffer,
                &mut costs,
                &progress,
            )?;
            for row in &rows {
                csv_out.push(row)?;
                if !row.error_estimate.is_nan() {
                    largest_error_estimate = Some(
                        largest_error_estimate
                            .map_or(row.error_estimate, |e: f64| e.max(row.error_estimate)),
                    );
                }
            }
            if b < end && last_checkpoint.elapsed().as_secs_f64() >= options.checkpoint_seconds {
                let t0 = Instant::now();
                let (csv_bytes, csv_hash) = csv_out.flushed()?;
                write_state_atomic(
                    &checkpoint_path,
                    &CheckpointFileRef {
                        state: &total,
                        csv_bytes,
                        csv_hash: Some(csv_hash),
                        largest_error_estimate,
                    },
                )?;
                costs.statistics_seconds += t0.elapsed().as_secs_f64();
                last_checkpoint = Instant::now();
            }
        }
        Ok(())
    })?;
    progress.finish();
    csv_out.finish()?;
    Ok(SolvedChunks {
        state: total,
        chunks: bounds.len(),
        reused,
        largest_error_estimate,
        costs,
    })
}

/// Where the study is built, and the staging directory when it is not the target itself: a
/// fresh staging directory, or with `--resume` the one an interrupted run of this study left
/// beside the target, else the target when it holds this study.
fn study_dir(header: &StudyHeader, options: &StudyOptions) -> Result<(PathBuf, Option<StagedDir>)> {
    let target = &options.out_dir;
    if !options.resume {
        let mut fresh = StagedDir::begin(target, options.force)?;
        fresh.keep_on_failure();
        return Ok((fresh.staging.clone(), Some(fresh)));
    }
    // A commit killed between its two renames first (as a run without --resume repairs it:
    // the finished run, or else the earlier one, put back in place, nothing left beside it).
    StagedDir::recover_interrupted_commit(target)?;
    // An interrupted run of this very study beside --out first (a rerun into a directory that
    // holds a complete study), else the study in --out itself.
    let same_study = |path: &Path| {
        read_json::<StudyHeader>(path).is_ok_and(|old| check_resume(&old, header, path).is_ok())
    };
    if let Some(found) = StagedDir::adopt_interrupted_study(target, same_study)? {
        if !options.quiet {
            eprintln!("resuming the interrupted run into {}", target.display());
        }
        return Ok((found.staging.clone(), Some(found)));
    }
    if target.join("study.json").exists() {
        return Ok((target.clone(), None));
    }
    // An interrupted run of another study (or of this one with changed inputs): say what differs.
    let other = StagedDir::interrupted_studies(target)?
        .into_iter()
        .find_map(|path| match read_json::<StudyHeader>(&path) {
            Ok(old) => check_resume(&old, header, &path).err(),
            Err(e) => Some(e),
        });
    let why = match other {
        Some(e) => format!("the interrupted run beside it cannot be continued: {e}"),
        None => "no interrupted run of this study beside it; run without --resume".into(),
    };
    Err(Error::Output {
        path: target.clone(),
        message: format!("nothing to resume: no study.json there, and {why}"),
    })
}

/// The options a study checks before it reads or writes anything: the shard, the checkpoint
/// interval and the number of sweep points.
fn check_options(scene: &Scene, options: &StudyOptions) -> Result<()> {
    let (k, n) = options.shard;
    if n == 0 || k >= n {
        return Err(Error::invalid(
            "--shard",
            format!("{k}/{n}"),
            "shard K of N, K counted from 0",
            "0 <= K < N",
        ));
    }
    // NaN fails the comparison too; infinity is allowed (never checkpoint).
    if !(options.checkpoint_seconds >= 0.0) {
        return Err(Error::invalid(
            "--checkpoint-every",
            options.checkpoint_seconds,
            "seconds of solving between checkpoints",
            "0 <= SECONDS (0: after every chunk)",
        ));
    }
    let points = scene.sweep_points();
    if points > crate::scene::MAX_SWEEP_POINTS && !options.allow_large {
        // A Saltelli design runs its base points x (keys + 2): name both.
        let max = crate::scene::MAX_SWEEP_POINTS;
        let (written, what, allowed) = match &scene.sweep {
            Some(s) if s.design.kind() == crate::ensemble::design::DesignKind::Saltelli => {
                let runs = s.design.names().len() as u64 + 2;
                (
                    points / runs,
                    format!(
                        "{} base points x ({} keys + 2) make {points} points to run, and every sweep point keeps its own responses (in memory, partial.state, stats/ and points.csv)",
                        points / runs,
                        runs - 2
                    ),
                    format!("at most {} base points with {} keys ({max} points to run), or --allow-large", max / runs, runs - 2),
                )
            }
            _ => (
                points,
                "every sweep point keeps its own responses (in memory, partial.state, stats/ and points.csv)".to_string(),
                format!("at most {max} points, or --allow-large"),
            ),
        };
        return Err(Error::invalid("sweep.points", written, what, allowed));
    }
    Ok(())
}
