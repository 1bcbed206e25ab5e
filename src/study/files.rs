//! The files of a study directory: `study.json` ([`StudyHeader`], and the resume check against
//! it), `checkpoint.state` ([`CheckpointFile`]), `partial.state` ([`PartialFile`]) and
//! `members.csv` ([`MemberRow`], streamed by [`CsvOut`]).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::state::StudyState;
use crate::backend::select::{BackendRecord, RunsOn};
use crate::backend::Precision;
use crate::error::{Error, Result};
use crate::scene::members::EnsembleMembers;
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
    /// The swept keys (settings and parameters), in design order; empty without a sweep.
    pub sweep_names: Vec<String>,
    /// Each sweep point's values of `sweep_names` (one empty point without a sweep).
    pub points: Vec<Vec<f64>>,
    /// Members per point (member m belongs to point m div members_per_point).
    pub members_per_point: u64,
    /// "grid", "random", "latin_hypercube" or "sobol" ("grid" without a sweep).
    pub sweep_design: String,
    /// Per swept key, whether its values are spread on a log scale (a range with scale = "log",
    /// or a list of positive values spanning more than a decade).
    pub sweep_log_scale: Vec<bool>,
    /// Per swept key, its declared range (min, max), or the least and greatest listed value; a
    /// header written before has none, and readers fall back to the points' least and greatest.
    #[serde(default)]
    pub sweep_bounds: Vec<(f64, f64)>,
    pub field_ranges: BTreeMap<String, (f64, f64)>,
    pub bins: usize,
    /// The fields whose pointwise bands are accumulated: those of `[output] fields` among
    /// [`FIELDS`](super::FIELDS), in that order.
    #[serde(default)]
    pub band_fields: Vec<String>,
    /// Points 0..detailed_points keep statistics per output time (every scalar at every time,
    /// the field bands); the others keep their members' responses only.
    #[serde(default)]
    pub detailed_points: u64,
    /// Where this run writes (per-member arrays go to `<out_dir>/members/`).
    pub out_dir: String,
    /// What computed the members: resume and merge refuse to mix backends or precisions.
    pub backend: RunsOn,
    pub precision: Precision,
    /// The tableau's rows the members ran ("from_1" or "from_2"): its default changed within
    /// one version (auto takes from_2 for order auto in f64 since 2026-11-30), so resume and
    /// merge refuse to mix them. A header written before has none, and ran from_1 unless its
    /// scene named from_2 (then this refuses to resume it, which is safe).
    #[serde(default = "sequence_before_auto")]
    pub sequence: String,
    /// Every file the members are built from (a particle file, a roughness file), path →
    /// FNV-1a of its bytes: resume and merge refuse a study whose inputs changed.
    #[serde(default)]
    pub input_files: BTreeMap<String, String>,
}

impl StudyHeader {
    /// Whether point `p` keeps statistics per output time.
    pub fn is_detailed(&self, p: u64) -> bool {
        p < self.detailed_points
    }

    /// The number of points with per-time statistics (the leading axis of the per-time files in
    /// `stats/`).
    pub fn detailed_count(&self) -> u64 {
        self.detailed_points.min(self.points.len().max(1) as u64)
    }

    /// The values of the swept keys at point `p`.
    pub fn point_values(&self, p: u64) -> Vec<f64> {
        self.points.get(p as usize).cloned().unwrap_or_default()
    }
}

/// One CSV row per member (the swept keys' values are columns named after them, after
/// `sweep_point`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MemberRow {
    pub member: u64,
    pub sweep_point: u64,
    /// The values of the study's swept keys at this member's point.
    pub parameters: Vec<f64>,
    pub particles: usize,
    #[serde(with = "crate::output::serde_f64")]
    pub mu: f64,
    #[serde(with = "crate::output::serde_f64")]
    pub gamma: f64,
    pub status: String,
    /// Why a failed member failed (the manifest's `reason` of a single run); empty where ok.
    pub failure_reason: String,
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
    /// The member's error estimate at the end (NaN where unavailable or failed).
    #[serde(with = "crate::output::serde_f64")]
    pub error_estimate: f64,
}

/// `checkpoint.state`: the statistics of the chunks a running study has finished so far (their
/// member ranges are `state.ranges`), how many bytes of `members.csv.partial` hold their rows
/// and the FNV-1a of those bytes, and their largest error estimate. Written atomically every
/// `--checkpoint-every` seconds; `--resume` continues from it, and a complete study removes it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(super) struct CheckpointFile {
    pub state: StudyState,
    pub csv_bytes: u64,
    /// None in a checkpoint written before 2026-11-30 (its rows are then taken unchecked).
    #[serde(default)]
    pub csv_hash: Option<String>,
    pub largest_error_estimate: Option<f64>,
}

/// [`CheckpointFile`] borrowed, for writing it without a copy of the state.
#[derive(Serialize)]
pub(super) struct CheckpointFileRef<'a> {
    pub state: &'a StudyState,
    pub csv_bytes: u64,
    pub csv_hash: Option<String>,
    pub largest_error_estimate: Option<f64>,
}

/// FNV-1a of the scene text: identifies the study for resume and merge.
fn scene_hash(text: &str) -> String {
    crate::output::fnv1a(text.as_bytes())
}

/// members.csv, written row by row as chunks (or shards) are read, in member order: memory does
/// not grow with the number of members. It is written as `members.csv.partial` and renamed when
/// complete, so an interrupted run leaves no complete-looking table.
pub(super) struct CsvOut {
    path: PathBuf,
    partial: PathBuf,
    writer: csv::Writer<HashedFile>,
}

/// The file of `members.csv.partial` and the FNV-1a of every byte it holds, kept as the rows are
/// written (a checkpoint records it and a resume checks the rows it keeps against it: a
/// partial damaged without a change of length was taken as it was).
struct HashedFile {
    file: std::fs::File,
    hash: crate::output::Fnv1a,
}

impl std::io::Write for HashedFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = std::io::Write::write(&mut self.file, buf)?;
        self.hash.update(&buf[..n]);
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        std::io::Write::flush(&mut self.file)
    }
}

pub use crate::output::columns::{
    swept_member_column, MEMBER_COLUMNS, MEMBER_KEY_COLUMNS, POINT_COUNT_COLUMNS,
    POINT_INDEX_COLUMN,
};

/// A number as members.csv writes it: the shortest text that reads back to the same f64; NaN
/// and infinities as "NaN", "inf", "-inf".
fn number_text(x: f64) -> String {
    if x.is_nan() {
        "NaN".into()
    } else if x.is_infinite() {
        if x > 0.0 { "inf" } else { "-inf" }.into()
    } else {
        format!("{x:?}")
    }
}

impl MemberRow {
    fn record(&self) -> Vec<String> {
        let mut r = vec![self.member.to_string(), self.sweep_point.to_string()];
        r.extend(self.parameters.iter().map(|&v| number_text(v)));
        r.extend([
            number_text(self.mu),
            number_text(self.gamma),
            self.particles.to_string(),
            self.status.clone(),
            number_text(self.failure_time),
            self.failure_reason.clone(),
            number_text(self.velocity_factor),
            number_text(self.velocity_phase),
            number_text(self.mean_dstar),
            number_text(self.min_rho_star),
            number_text(self.peak_density),
            number_text(self.peak_time),
            number_text(self.min_gap),
            number_text(self.final_energy),
            number_text(self.first_hit_time),
            self.steps_accepted.to_string(),
            self.steps_rejected.to_string(),
            number_text(self.error_estimate),
        ]);
        r
    }
}

impl CsvOut {
    /// Starts members.csv with its header; `sweep_names` are the swept keys' columns.
    pub fn create(path: PathBuf, sweep_names: &[String]) -> Result<CsvOut> {
        let partial = path.with_extension("csv.partial");
        let file = std::fs::File::create(&partial).map_err(|e| Error::io(&partial, e))?;
        let writer = csv::Writer::from_writer(HashedFile {
            file,
            hash: Default::default(),
        });
        let mut out = CsvOut {
            path,
            partial,
            writer,
        };
        let mut header: Vec<String> = MEMBER_KEY_COLUMNS.map(String::from).to_vec();
        header.extend(sweep_names.iter().map(|name| swept_member_column(name)));
        header.extend(MEMBER_COLUMNS.map(String::from));
        out.write(&header)?;
        Ok(out)
    }

    fn write<I: IntoIterator<Item = T>, T: AsRef<[u8]>>(&mut self, record: I) -> Result<()> {
        self.writer.write_record(record).map_err(|e| Error::Output {
            path: self.path.clone(),
            message: e.to_string(),
        })
    }

    pub fn push(&mut self, row: &MemberRow) -> Result<()> {
        self.write(row.record())
    }

    /// A row read from another members.csv (merge), copied as it is.
    pub fn push_record(&mut self, record: &csv::StringRecord) -> Result<()> {
        self.write(record)
    }

    /// Continues the `members.csv.partial` of an interrupted run after its first `bytes` bytes
    /// (the rows of the chunks its checkpoint holds; rows written after it are dropped), which
    /// must have the FNV-1a `hash` where the checkpoint recorded one.
    pub fn resume(path: PathBuf, bytes: u64, hash: Option<&str>) -> Result<CsvOut> {
        let partial = path.with_extension("csv.partial");
        // A run killed after its last chunk, while it wrote the statistics, has already renamed
        // the partial to members.csv (its checkpoint is removed last): the same rows.
        if !partial.exists() && path.exists() {
            std::fs::rename(&path, &partial).map_err(|e| Error::io(&path, e))?;
        }
        let mut file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .open(&partial)
            .map_err(|e| Error::io(&partial, e))?;
        if file.metadata().map_err(|e| Error::io(&partial, e))?.len() < bytes {
            return Err(Error::Output {
                path: partial,
                message: format!("shorter than the {bytes} bytes its checkpoint recorded: rerun without --resume"),
            });
        }
        file.set_len(bytes).map_err(|e| Error::io(&partial, e))?;
        let mut kept = crate::output::Fnv1a::default();
        std::io::copy(&mut &file, &mut kept).map_err(|e| Error::io(&partial, e))?;
        if hash.is_some_and(|h| h != kept.hex()) {
            return Err(Error::Output {
                path: partial,
                message: format!("its first {bytes} bytes differ from the rows its checkpoint recorded (FNV-1a {} against {}): the file was changed; rerun without --resume", kept.hex(), hash.unwrap_or_default()),
            });
        }
        std::io::Seek::seek(&mut file, std::io::SeekFrom::End(0))
            .map_err(|e| Error::io(&partial, e))?;
        Ok(CsvOut {
            path,
            partial,
            writer: csv::Writer::from_writer(HashedFile { file, hash: kept }),
        })
    }

    /// Flushes the rows written so far and returns the file's length and the FNV-1a of its
    /// bytes (for a checkpoint).
    pub fn flushed(&mut self) -> Result<(u64, String)> {
        self.writer
            .flush()
            .map_err(|e| Error::io(&self.partial, e))?;
        let out = self.writer.get_ref();
        let len = out
            .file
            .metadata()
            .map(|m| m.len())
            .map_err(|e| Error::io(&self.partial, e))?;
        Ok((len, out.hash.hex()))
    }

    pub fn finish(mut self) -> Result<()> {
        self.writer
            .flush()
            .map_err(|e| Error::io(&self.partial, e))?;
        std::fs::rename(&self.partial, &self.path).map_err(|e| Error::io(&self.path, e))
    }
}

/// Members [K·M/N, (K+1)·M/N) of M for shard K of N (the products in u128: K·M passes u64
/// for large shard counts, and wrapped it gave an empty or reversed range).
pub(super) fn shard_range(total: u64, (k, n): (u64, u64)) -> (u64, u64) {
    let at = |k: u64| (u128::from(total) * u128::from(k) / u128::from(n)) as u64;
    (at(k), at(k + 1))
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
    let total = members.total();
    let range = shard_range(total, shard);
    let u_range = band_u_range(&members.first.spec, &members.first.chain);
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
        sweep_names: scene
            .sweep
            .as_ref()
            .map(|s| s.design.names().to_vec())
            .unwrap_or_default(),
        points: (0..members.points)
            .map(|p| scene.point_values(p).into_iter().map(|(_, v)| v).collect())
            .collect(),
        members_per_point: members.per_point,
        sweep_design: scene
            .sweep
            .as_ref()
            .map_or("grid", |s| s.design.kind().name())
            .to_string(),
        sweep_log_scale: scene
            .sweep
            .as_ref()
            .map(|s| s.design.axes().iter().map(log_scaled).collect())
            .unwrap_or_default(),
        sweep_bounds: scene
            .sweep
            .as_ref()
            .map(|s| s.design.axes().iter().map(declared_bounds).collect())
            .unwrap_or_default(),
        field_ranges,
        bins: spec.bins,
        band_fields: super::FIELDS
            .iter()
            .filter(|f| match **f {
                "rho" => scene.fields.rho,
                "u" => scene.fields.u,
                _ => scene.fields.rho_star,
            })
            .map(|f| f.to_string())
            .collect(),
        detailed_points: {
            let points = members.points;
            let sampled = scene
                .sweep
                .as_ref()
                .is_some_and(|s| s.design.kind().name() != "grid");
            // One member a point: the detailed points' statistics would be that member's
            // fields, at a fixed cost of 10-15 ms that was a third of a 64-point design.
            let default = if sampled && spec.members == 1 {
                0
            } else if sampled {
                crate::scene::DEFAULT_DETAILED_SAMPLED_POINTS.min(points)
            } else {
                points
            };
            spec.detailed_points.unwrap_or(default).min(points)
        },
        out_dir: out_dir.display().to_string(),
        backend: engine.backend,
        precision: engine.precision,
        sequence: scene
            .sequence_in(engine.precision)
            .record(scene.order)
            .to_string(),
        input_files: BTreeMap::new(),
    }
}

/// The velocity range of the u band of a sweep point (`ensemble.u_range`, or twice the largest
/// initial speed of the point's chain, widened by the amplitude spread): each point has its own,
/// so that a point's statistics equal those of a study of that point alone.
pub(super) fn band_u_range(spec: &EnsembleSpec, chain: &crate::model::chain::Chain) -> (f64, f64) {
    let u_max = chain.velocities.iter().fold(0.0f64, |m, u| m.max(u.abs()));
    spec.u_range.map(|[a, b]| (a, b)).unwrap_or_else(|| {
        let u = (2.0 * u_max * (1.0 + spec.velocity_amplitude_spread * 4.0)).max(1e-3);
        (-u, u)
    })
}

/// Whether an axis is best drawn on a log scale.
fn log_scaled(axis: &crate::ensemble::Axis) -> bool {
    match axis {
        crate::ensemble::Axis::Range { scale, .. } => *scale == crate::ensemble::Scale::Log,
        crate::ensemble::Axis::Values(_) => {
            let (lo, hi) = declared_bounds(axis);
            lo > 0.0 && hi / lo > 10.0
        }
    }
}

fn declared_bounds(axis: &crate::ensemble::Axis) -> (f64, f64) {
    match axis {
        crate::ensemble::Axis::Range { min, max, .. } => (*min, *max),
        crate::ensemble::Axis::Values(v) => (
            v.iter().copied().fold(f64::INFINITY, f64::min),
            v.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        ),
    }
}

fn sequence_before_auto() -> String {
    "from_1".to_string()
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
        ("tableau sequence", a.sequence != b.sequence),
        // Its default changed within one version (sampled designs of one member a point).
        ("detailed points", a.detailed_points != b.detailed_points),
    ];
    differs.iter().filter(|d| d.1).map(|d| d.0).collect()
}

/// `partial.state`: the mergeable statistics of all members of a run (or shard, or merge), with
/// the header that says what they are; `roughlub merge` reads these.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(super) struct PartialFile {
    pub header: StudyHeader,
    pub state: StudyState,
}

/// Checks that a state read from `path` has what the report and a merge look up by name and
/// count for the study `header` describes: band fields among rho, u, rho_star (each once, in
/// that order), and per detailed point every scalar and band field at every output time, each
/// band over the grid. A state file is input to `merge` and `--resume`, so a damaged or edited
/// one gets an error naming it, not a panic or two threads writing one file.
pub(super) fn check_state(header: &StudyHeader, state: &StudyState, path: &Path) -> Result<()> {
    let bad = |message: String| {
        Err(Error::Output {
            path: path.to_path_buf(),
            message: format!("inconsistent study state: {message}; rerun the study"),
        })
    };
    let mut known = super::FIELDS.iter();
    for name in &header.band_fields {
        if !known.any(|f| f == name) {
            return bad(format!(
                "band fields {:?} are not among {:?}, each once and in that order",
                header.band_fields,
                super::FIELDS
            ));
        }
    }
    let (t, g) = (header.times.len(), header.x.len());
    for (p, stats) in &state.points {
        if !header.is_detailed(*p) {
            continue;
        }
        for name in super::SCALARS {
            if stats.scalars.get(name).map(Vec::len) != Some(t) {
                return bad(format!(
                    "point {p} lacks {name} at each of the {t} output times"
                ));
            }
        }
        if stats.fields.is_empty() {
            continue;
        }
        if stats.fields.len() != header.band_fields.len() {
            return bad(format!(
                "point {p} has bands of {:?}, the study {:?}",
                stats.fields.keys().collect::<Vec<_>>(),
                header.band_fields
            ));
        }
        for name in &header.band_fields {
            let fits = stats.fields.get(name).is_some_and(|per_time| {
                per_time.len() == t && per_time.iter().all(|b| b.points() == g)
            });
            if !fits {
                return bad(format!(
                    "point {p} lacks the {name} band at each of the {t} output times over {g} grid points"
                ));
            }
        }
    }
    Ok(())
}

/// [`PartialFile`] borrowed, for writing it without a copy of the state.
#[derive(Serialize)]
pub(super) struct PartialFileRef<'a> {
    pub header: &'a StudyHeader,
    pub state: &'a StudyState,
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
                "--resume: this directory holds a different study ({} differ; it ran on {} in {} with sequence {}; this run: {} in {} with sequence {}); run without --resume into a new directory, or resume with the same settings",
                what.join(", "),
                old.backend.name(),
                old.precision.name(),
                old.sequence,
                new.backend.name(),
                new.precision.name(),
                new.sequence
            ),
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::{shard_range, CsvOut, MemberRow};

    /// Shards partition the members in order, also where K·M exceeds u64 (it wrapped, giving
    /// shard 2^61 - 1 of 2^61 of 8 members the range [7, 0]).
    #[test]
    fn shard_ranges_partition_the_members_without_overflow() {
        let n = 1u64 << 61;
        assert_eq!(shard_range(8, (n - 1, n)), (7, 8));
        assert_eq!(shard_range(8, (n / 2 - 1, n)), (3, 4));
        assert_eq!(shard_range(u64::MAX, (1, 2)), (u64::MAX / 2, u64::MAX));
        let (total, shards) = (1_000_000_007u64, 13u64);
        let mut next = 0;
        for k in 0..shards {
            let (a, b) = shard_range(total, (k, shards));
            assert_eq!(a, next);
            assert!(b >= a);
            next = b;
        }
        assert_eq!(next, total);
    }

    /// A study killed after its last chunk, while it wrote its statistics, has renamed its
    /// members.csv.partial to members.csv but kept its checkpoint: resuming takes members.csv
    /// back, cut to the checkpoint's rows (it failed: "members.csv.partial: No such file").
    #[test]
    fn resume_takes_back_a_members_csv_renamed_before_the_kill() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("members.csv");
        std::fs::write(&path, "member,x\n0,1\n1,2\n").unwrap();
        let kept = "member,x\n0,1\n".len() as u64;
        let mut csv = CsvOut::resume(path.clone(), kept, None).unwrap();
        assert_eq!(csv.flushed().unwrap().0, kept);
        csv.finish().unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "member,x\n0,1\n");
        assert!(!path.with_extension("csv.partial").exists());
    }

    /// A checkpoint records the FNV-1a of the rows it holds: a resume takes them back unchanged,
    /// and refuses them when a byte among them changed without a change of length (it took
    /// them as they were until 2026-11-30); rows after the checkpoint do not count.
    #[test]
    fn resume_refuses_rows_changed_since_their_checkpoint() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("members.csv");
        let mut csv = CsvOut::create(path.clone(), &[]).unwrap();
        let row = |member: u64| MemberRow {
            member,
            sweep_point: 0,
            parameters: vec![],
            mu: 0.01,
            gamma: 2.0,
            particles: 10,
            status: "ok".into(),
            failure_time: f64::NAN,
            failure_reason: String::new(),
            velocity_factor: 1.0,
            velocity_phase: 0.0,
            mean_dstar: 0.1,
            min_rho_star: 0.7,
            peak_density: 0.75,
            peak_time: 0.5,
            min_gap: 1e-3,
            final_energy: 0.25,
            first_hit_time: f64::NAN,
            steps_accepted: 12,
            steps_rejected: 1,
            error_estimate: 1e-5,
        };
        csv.push(&row(0)).unwrap();
        csv.push(&row(1)).unwrap();
        let (bytes, hash) = csv.flushed().unwrap();
        csv.push(&row(2)).unwrap();
        drop(csv);
        let partial = path.with_extension("csv.partial");
        let text = std::fs::read(&partial).unwrap();
        assert_eq!(hash, crate::output::fnv1a(&text[..bytes as usize]));

        let mut resumed = CsvOut::resume(path.clone(), bytes, Some(&hash)).unwrap();
        assert_eq!(resumed.flushed().unwrap(), (bytes, hash.clone()));
        drop(resumed);

        let mut damaged = text.clone();
        let at = damaged[..bytes as usize]
            .iter()
            .rposition(|&b| b == b'7')
            .unwrap();
        damaged[at] = b'8';
        std::fs::write(&partial, &damaged).unwrap();
        let err = CsvOut::resume(path.clone(), bytes, Some(&hash))
            .err()
            .expect("a changed row is refused")
            .to_string();
        assert!(err.contains("rerun without --resume"), "{err}");
    }
}
