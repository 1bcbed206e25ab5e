//! `roughlub merge`: the statistics of several shards (or runs) of one study.

use std::path::{Path, PathBuf};
use std::time::Instant;

use super::files::{CsvOut, MemberRow, PartialFile, StudyHeader};
use super::report::{finalize, quantile_method};
use super::state::StudyState;
use super::StudySummary;
use crate::error::{Error, Result};
use crate::output::manifest::{MergedManifest, StudySceneRecord, VERSION};
use crate::output::{prepare_dir, read_json, write_json_atomic, MANIFEST};

/// `roughlub merge`: the statistics of several shards (or runs) of one study.
pub fn merge_studies(inputs: &[PathBuf], out: &Path, plots: bool) -> Result<StudySummary> {
    let started = Instant::now();
    if inputs.is_empty() {
        return Err(Error::missing("merge", "give at least one study directory"));
    }
    // Shards in member order, so that members.csv streams out in order.
    let mut partials: Vec<(PathBuf, PartialFile)> = Vec::with_capacity(inputs.len());
    for dir in inputs {
        partials.push((dir.clone(), read_json(&dir.join("partial.json"))?));
    }
    partials.sort_by_key(|(_, p)| p.header.member_range.0);
    prepare_dir(out)?;
    let mut csv_out = CsvOut::create(out.join("members.csv"))?;
    let mut headers: Vec<StudyHeader> = Vec::new();
    let mut state: Option<StudyState> = None;
    for (dir, p) in partials {
        if let Some(h0) = headers.first() {
            let differs = [
                ("scene text", h0.scene_hash != p.header.scene_hash),
                ("times", h0.times != p.header.times),
                ("grid", h0.x != p.header.x),
                ("backend", h0.backend != p.header.backend),
                ("precision", h0.precision != p.header.precision),
            ];
            let what: Vec<&str> = differs.iter().filter(|d| d.1).map(|d| d.0).collect();
            if !what.is_empty() {
                return Err(Error::Output {
                    path: dir.clone(),
                    message: format!("not a shard of the same study ({} differ)", what.join(", ")),
                });
            }
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
        for r in reader.deserialize::<MemberRow>() {
            csv_out.push(&r.map_err(|e| Error::Output {
                path: csv_in.clone(),
                message: e.to_string(),
            })?)?;
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
    write_json_atomic(
        &out.join("partial.json"),
        &PartialFile {
            header: merged_header.clone(),
            state: state.clone(),
        },
    )?;
    finalize(out, &headers, &state, plots)?;
    let covered: u64 = state.ranges.iter().map(|(a, b)| b - a).sum();
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
            members_completed: state.completed,
            failed_members: state.failed.clone(),
            wall_seconds: started.elapsed().as_secs_f64(),
            quantile_method: quantile_method(&merged_header),
        },
    )?;
    Ok(StudySummary::of(
        out,
        &state,
        0,
        started.elapsed().as_secs_f64(),
        0.0,
    ))
}
