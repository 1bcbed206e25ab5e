//! `roughlub merge`: the statistics of several shards (or runs) of one study.

use std::path::{Path, PathBuf};
use std::time::Instant;

use super::files::{check_state, study_differences, CsvOut, PartialFile, StudyHeader};
use super::report::{finalize, quantile_method};
use super::state::StudyState;
use super::{StudySummary, ERROR_ESTIMATE, OLD_PARTIAL, PARTIAL};
use crate::error::{Error, Result};
use crate::output::manifest::{
    large_error_warning, ErrorEstimateRecord, MergedManifest, ShardBackend, StudySceneRecord,
    ERROR_ESTIMATE_UNAVAILABLE, VERSION,
};
use crate::output::state_file::old_format_error;
use crate::output::{
    read_json, read_state, write_json_atomic, write_state_atomic, StagedDir, MANIFEST,
};

/// `roughlub merge`: the statistics of several shards (or runs) of one study.
///
/// Refused, before anything is written: an `--out` that is one of the inputs (it would overwrite
/// that shard's statistics), and shards that leave members uncovered unless `allow_partial`
/// (then stderr and the manifest name the missing member ranges). The merged study is written
/// beside `out` and swapped in whole; an `out` holding files that are not a roughlub run is
/// replaced only with `force`.
pub fn merge_studies(
    inputs: &[PathBuf],
    out: &Path,
    plots: bool,
    allow_partial: bool,
    force: bool,
) -> Result<StudySummary> {
    let started = Instant::now();
    if inputs.is_empty() {
        return Err(Error::missing("merge", "give at least one study directory"));
    }
    if let Ok(out_real) = out.canonicalize() {
        if let Some(dir) = inputs
            .iter()
            .find(|d| d.canonicalize().is_ok_and(|d| d == out_real))
        {
            return Err(Error::invalid(
                "merge --out",
                dir.display(),
                "is one of the shards being merged; the merge would overwrite its statistics",
                "a directory that is not among the inputs",
            ));
        }
    }
    // Shards in member order, so that members.csv streams out in order.
    let mut partials: Vec<(PathBuf, PartialFile)> = Vec::with_capacity(inputs.len());
    for dir in inputs {
        let partial_path = dir.join(PARTIAL);
        if !partial_path.exists() && dir.join(OLD_PARTIAL).exists() {
            return Err(old_format_error(&dir.join(OLD_PARTIAL)));
        }
        // A study is complete once its manifest is written (last): a directory without one is an
        // interrupted run's, or its staging directory, whose statistics may be a checkpoint's.
        if partial_path.exists() && !dir.join(MANIFEST).exists() {
            return Err(Error::Output {
                path: dir.clone(),
                message: format!("has no {MANIFEST}: not a complete study (an interrupted run, or its staging directory); finish it with roughlub run SCENE --out DIR --resume, or run that shard again"),
            });
        }
        let partial: PartialFile = read_state(&partial_path)?;
        check_state(&partial.header, &partial.state, &partial_path)?;
        // A run killed before it finished leaves the previous study's partial.json beside its
        // own study.json: those statistics are not this directory's study.
        let study_path = dir.join("study.json");
        if study_path.exists() {
            let study: StudyHeader = read_json(&study_path)?;
            let mut what = study_differences(&study, &partial.header);
            if study.member_range != partial.header.member_range {
                what.push("member range");
            }
            if !what.is_empty() {
                return Err(Error::Output {
                    path: partial_path.clone(),
                    message: format!(
                        "out of date: it holds the statistics of an earlier study than study.json ({} differ; was a later run into this directory interrupted?); rerun that shard",
                        what.join(", ")
                    ),
                });
            }
        }
        partials.push((dir.clone(), partial));
    }
    partials.sort_by_key(|(_, p)| p.header.member_range.0);
    // Every shard must belong to the same study; checked before anything is written.
    let (_, first) = &partials[0];
    for (dir, p) in &partials[1..] {
        let h0 = &first.header;
        let mut what = study_differences(h0, &p.header);
        if h0.times != p.header.times {
            what.push("times");
        }
        if h0.x != p.header.x {
            what.push("grid");
        }
        if !what.is_empty() {
            return Err(Error::Output {
                path: dir.clone(),
                message: format!("not a shard of the same study ({} differ)", what.join(", ")),
            });
        }
    }
    let missing = missing_members(&partials)?;
    if !missing.is_empty() {
        let list = describe_ranges(&missing);
        if !allow_partial {
            return Err(Error::missing(
                "merge",
                format!("the shards leave members {list} uncovered; merge every shard, or pass --allow-partial to merge what there is"),
            ));
        }
        eprintln!("warning: merging a partial study: members {list} are missing");
    }
    // Built aside and swapped in whole, like a run: `out` is never a mixture of two merges.
    let staged = StagedDir::begin(out, force)?;
    let target = out;
    let out = staged.staging.as_path();
    let mut csv_out = CsvOut::create(out.join("members.csv"), &partials[0].1.header.sweep_names)?;
    let mut headers: Vec<StudyHeader> = Vec::new();
    let mut state: Option<StudyState> = None;
    // The inputs' error estimates: their method (the same scene, so the same method) from their
    // manifests, the largest from their members' rows.
    let mut estimate_method: Option<String> = None;
    let mut largest_error_estimate: Option<f64> = None;
    // Where each shard ran (shards of one study may run on different machines) and the matrix
    // they ran with, as their manifests record them.
    let mut shard_backends = Vec::new();
    let mut jacobian: Option<String> = None;
    for (dir, p) in partials {
        let recorded = input_manifest(&dir)?;
        let field = |name: &str| recorded.as_ref().and_then(|m| m.get(name)).cloned();
        if estimate_method.is_none() {
            estimate_method = field("error_estimate")
                .and_then(|e| e.get("method").and_then(|m| m.as_str()).map(str::to_owned));
        }
        if jacobian.is_none() {
            jacobian = field("jacobian").and_then(|j| j.as_str().map(str::to_owned));
        }
        // A merge given as an input passes on its own inputs' entries.
        match field("shard_backends").and_then(|v| serde_json::from_value(v).ok()) {
            Some(inner) => shard_backends.extend::<Vec<ShardBackend>>(inner),
            None => shard_backends.push(ShardBackend {
                input: dir.display().to_string(),
                member_range: p.header.member_range,
                backend_requested: field("backend_requested"),
                adapter: field("adapter"),
            }),
        }
        match &mut state {
            None => state = Some(p.state),
            Some(s) => s.merge(&p.state)?,
        }
        let csv_in = dir.join("members.csv");
        let mut reader = csv::Reader::from_path(&csv_in).map_err(|e| Error::Output {
            path: csv_in.clone(),
            message: e.to_string(),
        })?;
        let estimate_column = reader
            .headers()
            .map_err(|e| Error::Output {
                path: csv_in.clone(),
                message: e.to_string(),
            })?
            .iter()
            .position(|name| name == ERROR_ESTIMATE);
        for r in reader.records() {
            let record = r.map_err(|e| Error::Output {
                path: csv_in.clone(),
                message: e.to_string(),
            })?;
            // NaN where a member has none (failed, or no estimate): left out, as a run does.
            let estimate = estimate_column
                .and_then(|c| record.get(c))
                .and_then(|text| text.parse::<f64>().ok())
                .filter(|e| !e.is_nan());
            if let Some(e) = estimate {
                largest_error_estimate = Some(largest_error_estimate.map_or(e, |l: f64| l.max(e)));
            }
            csv_out.push_record(&record)?;
        }
        headers.push(p.header);
    }
    csv_out.finish()?;
    let state = state.expect("at least one input");
    let mut merged_header = headers[0].clone();
    merged_header.shard = (0, 1);
    merged_header.member_range = (
        state.ranges.first().map_or(0, |r| r.0),
        state.ranges.last().map_or(0, |r| r.1),
    );
    write_state_atomic(
        &out.join(PARTIAL),
        &PartialFile {
            header: merged_header.clone(),
            state: state.clone(),
        },
    )?;
    finalize(out, &headers, &state, plots)?;
    let covered: u64 = state.ranges.iter().map(|(a, b)| b - a).sum();
    let available = estimate_method
        .as_deref()
        .is_some_and(|m| m != ERROR_ESTIMATE_UNAVAILABLE);
    let largest_error_estimate = largest_error_estimate.filter(|_| available);
    let method = estimate_method.unwrap_or_else(|| UNRECORDED_ESTIMATE_METHOD.into());
    let error_estimate = ErrorEstimateRecord {
        warning: large_error_warning(
            largest_error_estimate,
            &method,
            scene_tolerance(&merged_header.scene_text),
            merged_header.precision,
        ),
        method: method.into(),
        largest: largest_error_estimate,
    };
    write_json_atomic(
        &out.join(MANIFEST),
        &MergedManifest {
            roughlub_version: VERSION,
            kind: "ensemble (merged)",
            inputs: inputs.iter().map(|p| p.display().to_string()).collect(),
            scene: StudySceneRecord {
                name: merged_header.scene_name.clone(),
                text: merged_header.scene_text.clone(),
                hash: merged_header.scene_hash.clone(),
            },
            backend: merged_header.backend,
            precision: merged_header.precision,
            members_total: merged_header.members_total,
            members_covered: covered,
            complete: covered == merged_header.members_total,
            member_ranges: state.ranges.clone(),
            missing_member_ranges: missing,
            members_completed: state.completed,
            failed_members: state.failed.clone(),
            error_estimate: error_estimate.clone(),
            input_files: merged_header.input_files.clone(),
            jacobian,
            sequence: merged_header.sequence.clone(),
            shard_backends,
            wall_seconds: started.elapsed().as_secs_f64(),
            quantile_method: quantile_method(&merged_header),
        },
    )?;
    staged.commit()?;
    Ok(
        StudySummary::of(target, &state, 0, started.elapsed().as_secs_f64(), 0.0)
            .with_error_estimate(largest_error_estimate, available, error_estimate.warning),
    )
}

/// What a merge records as the method where no input's manifest records one (a manifest
/// written before manifests of merges had one).
const UNRECORDED_ESTIMATE_METHOD: &str =
    "not recorded in the inputs' manifests; the largest is that of their members' rows";

/// An input's `manifest.json` (None where it has none: a shard still running or killed).
fn input_manifest(dir: &Path) -> Result<Option<serde_json::Value>> {
    let path = dir.join(MANIFEST);
    if !path.exists() {
        return Ok(None);
    }
    Ok(Some(read_json(&path)?))
}

/// Member ranges [first, end) of the study that no shard covers; shards that overlap (a member
/// counted twice) are an error.
fn missing_members(partials: &[(PathBuf, PartialFile)]) -> Result<Vec<(u64, u64)>> {
    let Some((_, first)) = partials.first() else {
        return Ok(Vec::new());
    };
    let mut covered: Vec<(u64, u64)> = partials
        .iter()
        .flat_map(|(_, p)| p.state.ranges.iter().copied())
        .collect();
    covered.sort_unstable();
    let mut missing = Vec::new();
    let mut next = 0;
    for (a, b) in covered {
        if a < next {
            return Err(Error::missing(
                "merge",
                format!("member ranges overlap at member {a}: a member would be counted twice (is a shard given twice?)"),
            ));
        }
        if a > next {
            missing.push((next, a));
        }
        next = next.max(b);
    }
    if next < first.header.members_total {
        missing.push((next, first.header.members_total));
    }
    Ok(missing)
}

fn describe_ranges(ranges: &[(u64, u64)]) -> String {
    let parts: Vec<String> = ranges.iter().map(|(a, b)| format!("{a}..{b}")).collect();
    parts.join(", ")
}

/// `[time] tolerance` of a scene's text (the shards' scene, which resume and merge check is the
/// same for all), `None` where it has none (fixed steps) or is not a number.
fn scene_tolerance(scene_text: &str) -> Option<f64> {
    let scene: toml::Table = scene_text.parse().ok()?;
    let tolerance = scene.get("time")?.get("tolerance")?;
    tolerance
        .as_float()
        .or_else(|| tolerance.as_integer().map(|t| t as f64))
}
