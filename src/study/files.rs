//! The files of a study directory: `study.json` ([`StudyHeader`], and the resume check against
//! it), `chunks/chunk_<first>_<end>.json` ([`ChunkFile`]), `partial.json` ([`PartialFile`]) and
//! `members.csv` ([`MemberRow`], streamed by [`CsvOut`]).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::state::StudyState;
use crate::backend::select::{BackendRecord, RunsOn};
use crate::backend::Precision;
use crate::ensemble::members::EnsembleMembers;
use crate::error::{Error, Result};
use crate::model::params::MemberParams;
use crate::scene::{EnsembleSpec, Scene};

/// What a study computes; written to `study.json` first and checked on resume and merge.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StudyHeader {
    pub roughlub_version: String,
    pub scene_name: String,
    pub scene_text: String,
    pub scene_hash: String,
    pub members_total: u64,
    pub shard: (u64, u64),
    pub member_range: (u64, u64),
    pub chunk: usize,
    pub times: Vec<f64>,
    pub x: Vec<f64>,
    pub quantiles: Vec<f64>,
    pub sweep: Vec<MemberParams>,
    pub field_ranges: BTreeMap<String, (f64, f64)>,
    pub bins: usize,
    /// Where this run writes (per-member arrays go to `<out_dir>/members/`).
    pub out_dir: String,
    /// What computed the members: resume and merge refuse to mix backends or precisions.
    pub backend: RunsOn,
    pub precision: Precision,
    /// Every file the members are built from (a particle file, a roughness file), path →
    /// FNV-1a of its bytes: resume and merge refuse a study whose inputs changed.
    #[serde(default)]
    pub input_files: BTreeMap<String, String>,
}

/// One CSV row per member.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MemberRow {
    pub member: u64,
    pub sweep_point: usize,
    #[serde(with = "crate::output::serde_f64")]
    pub mu: f64,
    #[serde(with = "crate::output::serde_f64")]
    pub gamma: f64,
    pub status: String,
    #[serde(with = "crate::output::serde_f64")]
    pub failure_time: f64,
    #[serde(with = "crate::output::serde_f64")]
    pub velocity_factor: f64,
    #[serde(with = "crate::output::serde_f64")]
    pub velocity_phase: f64,
    #[serde(with = "crate::output::serde_f64")]
    pub mean_dstar: f64,
    #[serde(with = "crate::output::serde_f64")]
    pub min_rho_star: f64,
    #[serde(with = "crate::output::serde_f64")]
    pub peak_density: f64,
    #[serde(with = "crate::output::serde_f64")]
    pub peak_time: f64,
    #[serde(with = "crate::output::serde_f64")]
    pub min_gap: f64,
    #[serde(with = "crate::output::serde_f64")]
    pub final_energy: f64,
    #[serde(with = "crate::output::serde_f64")]
    pub first_hit_time: f64,
    pub steps_accepted: u64,
    pub steps_rejected: u64,
}

/// `chunks/chunk_<first>_<end>.json`: the statistics and `members.csv` rows of one finished
/// chunk (written atomically; `--resume` reuses it).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(super) struct ChunkFile {
    pub range: (u64, u64),
    pub state: StudyState,
    pub rows: Vec<MemberRow>,
}

/// FNV-1a of the scene text: identifies the study for resume and merge.
fn scene_hash(text: &str) -> String {
    fnv1a(text.as_bytes())
}

/// The files the study's members are read from, each with the FNV-1a of its bytes.
pub(super) fn input_file_hashes(
    scene: &Scene,
    spec: &EnsembleSpec,
) -> Result<BTreeMap<String, String>> {
    let mut paths: Vec<&Path> = Vec::new();
    if let crate::scene::InitialSpec::Particles { path, .. } = &scene.initial {
        paths.push(path);
    }
    if let Some(r) = &spec.roughness {
        if let crate::ensemble::RoughnessKind::File(path) = &r.kind {
            paths.push(path);
        }
    }
    let mut out = BTreeMap::new();
    for path in paths {
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        out.insert(path.display().to_string(), fnv1a(&bytes));
    }
    Ok(out)
}

fn fnv1a(bytes: &[u8]) -> String {
    let mut h: u64 = 0xcbf29ce484222325;
    for b in bytes {
        h ^= *b as u64;
        h = h.wrapping_mul(0x100000001b3);
    }
    format!("{h:016x}")
}

/// members.csv, written row by row as chunks (or shards) are read, in member order: memory does
/// not grow with the number of members. It is written as `members.csv.partial` and renamed when
/// complete, so an interrupted run leaves no complete-looking table.
pub(super) struct CsvOut {
    path: PathBuf,
    partial: PathBuf,
    writer: csv::Writer<std::fs::File>,
}

impl CsvOut {
    pub fn create(path: PathBuf) -> Result<CsvOut> {
        let partial = path.with_extension("csv.partial");
        let writer = csv::Writer::from_path(&partial).map_err(|e| Error::Output {
            path: partial.clone(),
            message: e.to_string(),
        })?;
        Ok(CsvOut {
            path,
            partial,
            writer,
        })
    }
    pub fn push(&mut self, row: &MemberRow) -> Result<()> {
        self.writer.serialize(row).map_err(|e| Error::Output {
            path: self.path.clone(),
            message: e.to_string(),
        })
    }
    pub fn finish(mut self) -> Result<()> {
        self.writer
            .flush()
            .map_err(|e| Error::io(&self.partial, e))?;
        std::fs::rename(&self.partial, &self.path).map_err(|e| Error::io(&self.path, e))
    }
}

/// `chunks/chunk_<first>_<end>.json` of `dir`.
pub(super) fn chunk_path(dir: &Path, first: u64, end: u64) -> PathBuf {
    dir.join("chunks")
        .join(format!("chunk_{first:012}_{end:012}.json"))
}

/// Members [K·M/N, (K+1)·M/N) of M for shard K of N.
pub(super) fn shard_range(total: u64, (k, n): (u64, u64)) -> (u64, u64) {
    (total * k / n, total * (k + 1) / n)
}

/// The header of shard `shard` of the study of `scene`, computed on `engine`.
pub(super) fn header_for(
    scene: &Scene,
    spec: &EnsembleSpec,
    members: &EnsembleMembers,
    shard: (u64, u64),
    out_dir: &Path,
    engine: &BackendRecord,
) -> StudyHeader {
    let total = members.total(spec);
    let range = shard_range(total, shard);
    let u_max = members
        .chain
        .velocities
        .iter()
        .fold(0.0f64, |m, u| m.max(u.abs()));
    let u_range = spec.u_range.map(|[a, b]| (a, b)).unwrap_or_else(|| {
        let u = (2.0 * u_max * (1.0 + spec.velocity_amplitude_spread * 4.0)).max(1e-3);
        (-u, u)
    });
    let field_ranges: BTreeMap<String, (f64, f64)> = [
        ("rho".to_string(), (0.0, 1.0)),
        ("rho_star".to_string(), (0.0, 1.0)),
        ("u".to_string(), u_range),
    ]
    .into_iter()
    .collect();
    StudyHeader {
        roughlub_version: env!("CARGO_PKG_VERSION").to_string(),
        scene_name: scene.name.clone(),
        scene_text: scene.source_text.clone(),
        scene_hash: scene_hash(&scene.source_text),
        members_total: total,
        shard,
        member_range: range,
        chunk: spec.chunk,
        times: scene.output_times.clone(),
        x: crate::model::observables::grid_points(scene.grid),
        quantiles: spec.quantiles.clone(),
        sweep: members.sweep.clone(),
        field_ranges,
        bins: spec.bins,
        out_dir: out_dir.display().to_string(),
        backend: engine.backend,
        precision: engine.precision,
        input_files: BTreeMap::new(),
    }
}

/// What differs between two headers of what should be the same study (for resume, merge and the
/// partial statistics of a directory), by name.
pub(super) fn study_differences(a: &StudyHeader, b: &StudyHeader) -> Vec<&'static str> {
    let differs = [
        ("scene text", a.scene_hash != b.scene_hash),
        ("files it reads", a.input_files != b.input_files),
        ("roughlub version", a.roughlub_version != b.roughlub_version),
        ("backend", a.backend != b.backend),
        ("precision", a.precision != b.precision),
    ];
    differs.iter().filter(|d| d.1).map(|d| d.0).collect()
}

/// `partial.json`: the mergeable statistics of all members of a run (or shard, or merge), with
/// the header that says what they are; `roughlub merge` reads these.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(super) struct PartialFile {
    pub header: StudyHeader,
    pub state: StudyState,
}

/// `--resume`: refuses a directory that holds another study (`old` is its `study.json` at
/// `path`): another scene text, file it reads, roughlub version, shard, chunk size, backend or
/// precision.
pub(super) fn check_resume(old: &StudyHeader, new: &StudyHeader, path: &Path) -> Result<()> {
    let mut what = study_differences(old, new);
    if old.shard != new.shard {
        what.push("shard");
    }
    if old.chunk != new.chunk {
        what.push("chunk size");
    }
    if !what.is_empty() {
        return Err(Error::Output {
            path: path.to_path_buf(),
            message: format!(
                "--resume: this directory holds a different study ({} differ: it ran on {:?} in {:?}); run without --resume into a new directory, or resume with the same settings",
                what.join(", "),
                old.backend,
                old.precision
            ),
        });
    }
    Ok(())
}
