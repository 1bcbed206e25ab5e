//! Solving one chunk of members through the [`BatchSolver`](crate::backend::BatchSolver) seam
//! ([`solve_chunk`]) and turning its snapshots into the chunk's statistics and `members.csv`
//! rows. A pass over the chunk ([`solve_pass`]) solves its batches (`batch.rs`: each output's
//! statistics beside the solve to the next), takes back what it pushed when a member failed
//! after its rows went in, and merges the chunk into the total; `members.rs` writes what the
//! chunk leaves per member.

use std::path::Path;
use std::time::Instant;

use super::files::{MemberRow, StudyHeader};
use super::state::StudyState;
use super::{ERROR_ESTIMATE, SCALARS};
use crate::backend::report::GpuStats;
use crate::backend::{Engine, MemberReport, MemberStatus, Precision};
use crate::error::Result;
use crate::model::chain::Chain;
use crate::model::observables::Snapshot;
use crate::model::params::MemberParams;
use crate::model::plan::Plan;
use crate::output::ProgressReporter;
use crate::scene::members::{EnsembleMembers, MemberInputs};
use crate::scene::{EnsembleSpec, Scene};
use crate::stats::{FieldBand, RunningStats};
use rayon::prelude::*;

mod batch;
mod members;
use batch::{solve_batch, PassContext};
use members::{member_rows, write_kept_members, Responses};

/// The plan of a chunk: the scene's, with these members, and the fields the statistics need.
/// With `detailed` (a member of a detailed point among them): rho (its band and the peak
/// centre are read from it), u and rho* where their bands are asked for. Without, no field on
/// the grid: only detailed points keep anything per output time, and the grid was most of a
/// snapshot's cost. Rho also where the members' arrays are kept (`store_members`).
pub(super) fn chunk_plan(
    scene: &Scene,
    first_chain: &Chain,
    members: Vec<MemberParams>,
    store_members: bool,
    detailed: bool,
    precision: Precision,
) -> Plan {
    let mut plan = scene.plan(first_chain, precision);
    plan.members = members;
    plan.repulsion = first_chain.dstar.is_some();
    plan.fields.rho_star = detailed && plan.repulsion && scene.fields.rho_star;
    plan.fields.u &= detailed;
    plan.fields.rho = detailed || store_members;
    plan.peak_centre = detailed;
    // Gaps and velocities per member are read only, and always, where the members' arrays are
    // kept: `store_members` writes them whatever `[output] fields` lists for the bands.
    plan.fields.gaps = store_members;
    plan.fields.velocities = store_members;
    plan
}

/// One member's observables at one output time, as far as the statistics need them: kept until
/// the chunk is solved, because a member that fails later must not enter the statistics of any
/// time (failed members are counted and listed, never averaged in).
#[derive(Clone, Copy)]
struct RecordedObservables {
    /// The values of [`SCALARS`], in that order.
    scalars: [f64; SCALARS.len()],
    /// Bit f set: band field f has a row in the chunk's `field_rows` (a snapshot without that
    /// field has none; see [`row_offset`] for where it is).
    rows_present: u8,
}

/// Where the row of band field `f` at output time `k` of the chunk's deferred member `i` (its
/// [`PassContext::row_slot`](batch::PassContext)) starts in the chunk's `field_rows`: laid out
/// [field][time][member][grid point], so that the rows one band reads are consecutive in memory
/// (streamed, not gathered from rows a whole member apart).
fn row_offset(f: usize, k: usize, i: usize, (times, count, grid): (usize, usize, usize)) -> usize {
    ((f * times + k) * count + i) * grid
}

/// The row of band field `name` ("rho", "u" or "rho_star") in a snapshot (empty when the
/// snapshot has none).
fn band_row<'s>(s: &'s Snapshot, name: &str) -> &'s [f64] {
    match name {
        "rho" => &s.rho,
        "u" => &s.u,
        _ => &s.rho_star,
    }
}

/// What the solved chunks of one invocation cost beyond the solve itself.
#[derive(Debug, Default)]
pub(super) struct StudyCosts {
    /// Wall time spent on statistics.
    pub statistics_seconds: f64,
    /// The GPU's work counters summed over chunks (`None` on the CPU).
    pub gpu: Option<GpuStats>,
    /// Chunks solved twice: a member failed after rows of its point had been pushed as they
    /// were observed (see [`solve_chunk`]).
    pub chunks_solved_twice: usize,
}

/// Consecutive members [a, b) of a chunk that one batch can hold: the same N, eps, terms
/// (roughness, clusters) and forcing. Members of one sweep point always can; points that differ
/// only in mu, gamma or the random draws share a batch too.
fn batch_groups(inputs: &[MemberInputs], members: &EnsembleMembers) -> Result<Vec<(usize, usize)>> {
    let mut groups: Vec<(usize, usize)> = Vec::new();
    for i in 0..inputs.len() {
        let joins = match groups.last() {
            Some(&(a, _)) => {
                let (x, y) = (&inputs[a], &inputs[i]);
                x.point == y.point
                    || (x.chain.particles() == y.chain.particles()
                        && x.chain.eps.to_bits() == y.chain.eps.to_bits()
                        && x.chain.dstar.is_some() == y.chain.dstar.is_some()
                        && x.chain.bonded.is_some() == y.chain.bonded.is_some()
                        && (members.symbolic_forcing().is_some()
                            || x.setup.scene.forcing == y.setup.scene.forcing))
            }
            None => false,
        };
        match groups.last_mut() {
            Some(g) if joins => g.1 = i + 1,
            _ => groups.push((i, i + 1)),
        }
    }
    Ok(groups)
}

/// Groups of at least this many members of one detailed sweep point push their rows as they are
/// observed. Smaller groups copy them for after the chunk: an eager push needs a copy of the
/// group's moments (to undo it exactly should a member fail later), which costs about as much as
/// pushing two rows.
const EAGER_MIN_MEMBERS: usize = 4;

/// What one chunk leaves to the next about its field rows.
#[derive(Debug, Default)]
pub(super) struct RowBuffer {
    /// The rows of members whose group pushes after the chunk is solved, kept from chunk to
    /// chunk (grown, never cleared: refilling it would write every chunk's worth of rows twice).
    field_rows: Vec<f64>,
    /// Whether the last chunk had a failed member. Failures come in runs (a region of the
    /// sweep, a stiff setting), and a chunk that pushed rows as it went and then saw a member
    /// fail is solved a second time; so after a chunk with failures the next one pushes after
    /// its solve.
    failures_last_chunk: bool,
}

/// Each group's band moments before its eager pushes, in the order of its point's
/// `fields` map and then output time (None for a group that pushes after the chunk).
type MomentsBefore = Vec<Option<Vec<Vec<Vec<RunningStats>>>>>;

/// How one pass over a chunk ended.
enum Pass {
    Done(Vec<MemberRow>),
    /// A member of a group that pushed as it went failed after some of its rows were pushed:
    /// the chunk must be solved again and those pushes undone.
    Undo,
}

/// Solves members [first, end) with solvers from `engine` (the study's backend, through the
/// `BatchSolver` seam; one batch per group of compatible members), adds their statistics to
/// `total` (the run's, per sweep point) and returns their `members.csv` rows.
///
/// The chunk's scalar statistics are summarised on their own and then merged into `total`. Its
/// field rows go straight into `total`'s bands, one push per band and chunk of each point's rows
/// in member order: the same arithmetic as an empty band merged in (one Chan merge of the chunk's
/// moments per grid point, integer counts) without a chunk-sized copy of every band. A point
/// with many members pushes each output time's rows as they are observed (in cache, not copied);
/// only members that complete may count, so should one of them fail later the chunk is solved
/// again and those pushes undone exactly (the results are the same bits either way).
#[allow(clippy::too_many_arguments)]
pub(super) fn solve_chunk(
    dir: &Path,
    spec: &EnsembleSpec,
    members: &EnsembleMembers,
    header: &StudyHeader,
    engine: &Engine,
    (first, end): (u64, u64),
    total: &mut StudyState,
    buffer: &mut RowBuffer,
    costs: &mut StudyCosts,
    progress: &ProgressReporter,
) -> Result<Vec<MemberRow>> {
    let inputs: Vec<MemberInputs> = (first..end)
        .map(|m| members.member(m))
        .collect::<Result<_>>()?;
    let groups = point_groups(&inputs);
    // Every point of the chunk has its statistics (and bands, where detailed) in `total` before
    // a row is pushed; the chunk's merge below then adds to them.
    for &(i, _) in &groups {
        let setup = &inputs[i].setup;
        let u_range = super::files::band_u_range(&setup.spec, &setup.chain);
        total
            .point_mut(inputs[i].point, header)
            .add_bands(header, u_range)?;
    }
    let eager_allowed = !buffer.failures_last_chunk;
    let moments_before: MomentsBefore = groups
        .iter()
        .map(|&(i, j)| {
            let eager =
                eager_allowed && header.is_detailed(inputs[i].point) && j - i >= EAGER_MIN_MEMBERS;
            eager.then(|| {
                total.points[&inputs[i].point]
                    .fields
                    .values()
                    .map(|per_time| per_time.iter().map(|b| b.stats().to_vec()).collect())
                    .collect()
            })
        })
        .collect();
    let pass = |eager: &MomentsBefore,
                undo: Option<&MomentsBefore>,
                total: &mut StudyState,
                buffer: &mut RowBuffer,
                costs: &mut StudyCosts| {
        solve_pass(
            dir,
            spec,
            members,
            header,
            engine,
            (first, end),
            (&inputs, &groups),
            total,
            buffer,
            eager,
            undo,
            costs,
        )
    };
    let rows = match pass(&moments_before, None, total, buffer, costs)? {
        Pass::Done(rows) => rows,
        Pass::Undo => {
            // The second pass pushes every row after the solve, and first takes back what the
            // first pass pushed.
            costs.chunks_solved_twice += 1;
            let deferred: MomentsBefore = vec![None; groups.len()];
            match pass(&deferred, Some(&moments_before), total, buffer, costs)? {
                Pass::Done(rows) => rows,
                Pass::Undo => {
                    unreachable!("a pass that pushes after the solve has nothing to undo")
                }
            }
        }
    };
    buffer.failures_last_chunk = rows.iter().any(|r| r.status != "ok");
    progress.inc(end - first);
    Ok(rows)
}

/// The rows of output `k` of the groups that push as they go (`eager`), straight from the
/// snapshots of batch members [a, b) (`recorded[g]`: member a + g is recorded at this output):
/// each (point, field) band of this output time is its own accumulator, so they are filled in
/// parallel, each from its rows in member order. Returns the threads' time in the pushes
/// (seconds, summed over threads).
#[allow(clippy::too_many_arguments)]
fn push_as_observed(
    total: &mut StudyState,
    groups: &[(usize, usize)],
    eager: &MomentsBefore,
    inputs: &[MemberInputs],
    (a, b): (usize, usize),
    snaps: &[Snapshot],
    k: usize,
    recorded: &[bool],
) -> std::result::Result<f64, crate::stats::StatsError> {
    let eager_here: Vec<(u64, (usize, usize))> = groups
        .iter()
        .enumerate()
        .filter(|&(gi, &(i, _))| eager[gi].is_some() && (a..b).contains(&i))
        .map(|(_, &(i, j))| (inputs[i].point, (i, j)))
        .collect();
    let (Some(lowest), Some(highest)) = (
        eager_here.iter().map(|e| e.0).min(),
        eager_here.iter().map(|e| e.0).max(),
    ) else {
        return Ok(0.0);
    };
    let mut pushes: Vec<(&mut FieldBand, Vec<&[f64]>)> = Vec::new();
    for (p, stats) in total.points.range_mut(lowest..=highest) {
        let Some(&(_, (i, j))) = eager_here.iter().find(|(q, _)| q == p) else {
            continue;
        };
        for (name, per_time) in stats.fields.iter_mut() {
            let grid = per_time[k].points();
            let rows: Vec<&[f64]> = (i..j)
                .filter(|&m| recorded[m - a])
                .map(|m| band_row(&snaps[m - a], name))
                .filter(|row| row.len() == grid)
                .collect();
            pushes.push((&mut per_time[k], rows));
        }
    }
    // Summed over the pushes, each on one thread start to end.
    let busy_nanos = std::sync::atomic::AtomicU64::new(0);
    pushes.par_iter_mut().try_for_each(|(band, rows)| {
        let started = Instant::now();
        band.push_rows(rows)?;
        let nanos = started.elapsed().as_nanos() as u64;
        busy_nanos.fetch_add(nanos, std::sync::atomic::Ordering::Relaxed);
        Ok(())
    })?;
    Ok(busy_nanos.into_inner() as f64 * 1e-9)
}

/// Consecutive members of one sweep point, [i, j).
fn point_groups(inputs: &[MemberInputs]) -> Vec<(usize, usize)> {
    let mut groups: Vec<(usize, usize)> = Vec::new();
    for i in 0..inputs.len() {
        match groups.last_mut() {
            Some(g) if inputs[g.0].point == inputs[i].point => g.1 = i + 1,
            _ => groups.push((i, i + 1)),
        }
    }
    groups
}

/// Output `k`'s scalars of `members` (consecutive, with `recorded[g]` the observables of
/// `members[g]` at each output time, None where not recorded) into the chunk's summaries of
/// their points, member after member: each summary of a (scalar, time) receives its members in
/// member order, as one push per member after the chunk would.
fn push_output_scalars(
    state: &mut StudyState,
    header: &StudyHeader,
    members: &[MemberInputs],
    k: usize,
    recorded: &[Vec<Option<RecordedObservables>>],
) {
    for (g, end) in point_groups(members) {
        let stats = state.point_mut(members[g].point, header);
        for (name, per_time) in stats.scalars.iter_mut() {
            let s = SCALARS
                .iter()
                .position(|n| n == name)
                .expect("known observable");
            let estimate = name == ERROR_ESTIMATE;
            for per_member in &recorded[g..end] {
                if let Some(Some(o)) = per_member.get(k) {
                    let v = o.scalars[s];
                    if estimate && v.is_nan() {
                        // No estimate (order 1, fixed steps): the statistic stays empty.
                        continue;
                    }
                    per_time[k].push(v);
                }
            }
        }
    }
}

/// One pass of [`solve_chunk`]: the groups with `Some` in `eager` push each output's rows as
/// they are observed, the others after the solve; `undo` holds what an earlier pass over the
/// same chunk pushed as it went (its moments before), to be taken back first.
#[allow(clippy::too_many_arguments)]
fn solve_pass(
    dir: &Path,
    spec: &EnsembleSpec,
    members: &EnsembleMembers,
    header: &StudyHeader,
    engine: &Engine,
    (first, end): (u64, u64),
    (inputs, groups): (&[MemberInputs], &[(usize, usize)]),
    total: &mut StudyState,
    buffer: &mut RowBuffer,
    eager: &MomentsBefore,
    undo: Option<&MomentsBefore>,
    costs: &mut StudyCosts,
) -> Result<Pass> {
    let t_count = header.times.len();
    let grid = header.x.len();
    let count = (end - first) as usize;
    let mut group_of = vec![0usize; count];
    for (gi, &(i, j)) in groups.iter().enumerate() {
        group_of[i..j].fill(gi);
    }
    // Rows are kept for the deferred members only (detailed, in a group that does not push as
    // it goes): a design's chunk holds a few detailed members among hundreds, and a buffer for
    // all of them was most of a small design's statistics (its pages first touched).
    let mut row_slot = Vec::with_capacity(count + 1);
    let mut deferred = 0;
    for m in 0..count {
        row_slot.push(deferred);
        if eager[group_of[m]].is_none() && header.is_detailed(inputs[m].point) {
            deferred += 1;
        }
    }
    row_slot.push(deferred);
    let shape = (t_count, deferred, grid);
    let needed = header.band_fields.len() * t_count * deferred * grid;
    // Only rows written for this chunk are read back (`rows_present`).
    if buffer.field_rows.len() < needed {
        buffer.field_rows.resize(needed, f64::NAN);
    }
    let mut state = StudyState::new();
    state.ranges.push((first, end));
    let mut responses = Responses {
        peak: vec![(f64::NEG_INFINITY, f64::NAN); count],
        min_gap: vec![f64::INFINITY; count],
        final_energy: vec![f64::NAN; count],
        first_hit: vec![f64::NAN; count],
    };
    let pass = PassContext {
        dir,
        spec,
        members,
        header,
        engine,
        inputs,
        groups,
        eager,
        group_of,
        row_slot,
        shape,
    };
    let is_eager = |m: usize| pass.is_eager(m);

    // Per member, per output time (None once failed), in member order.
    let mut recorded: Vec<Vec<Option<RecordedObservables>>> = Vec::with_capacity(count);
    // Full per-member arrays, only when asked for: [member, time, ...] per chunk.
    let mut kept_snapshots: Vec<Vec<Snapshot>> = Vec::new();
    // Each kept member's error estimate at each output time (NaN once failed, or without one).
    let mut kept_estimates: Vec<Vec<f64>> = Vec::new();
    let mut reports: Vec<MemberReport> = Vec::with_capacity(count);
    for (a, b) in batch_groups(inputs, members)? {
        let batch = solve_batch(
            &pass,
            (a, b),
            total,
            &mut buffer.field_rows,
            &mut state,
            &mut responses,
            costs,
        )?;
        reports.extend(batch.reports);
        recorded.extend(batch.recorded);
        kept_snapshots.extend(batch.kept);
        kept_estimates.extend(batch.estimates);
    }
    let ok_member: Vec<bool> = reports
        .iter()
        .map(|r| r.status == MemberStatus::Ok)
        .collect();
    // Rows of member m pushed at output k of band field f (whether m completed or not).
    let pushed = |m: usize, f: usize, k: usize| {
        recorded[m]
            .get(k)
            .and_then(Option::as_ref)
            .is_some_and(|o| o.rows_present & (1 << f) != 0)
    };
    let pushed_any = |m: usize| recorded[m].iter().flatten().any(|o| o.rows_present != 0);
    if (0..count).any(|m| is_eager(m) && !ok_member[m] && pushed_any(m)) {
        return Ok(Pass::Undo);
    }

    let started = Instant::now();
    settle_points(
        &mut state, header, inputs, groups, &ok_member, &recorded, &responses,
    );
    for (i, r) in reports.iter().enumerate() {
        if r.status == MemberStatus::Ok {
            state.completed += 1;
        } else {
            state.failed.push(first + i as u64);
        }
    }
    total.merge(&state)?;

    // The field rows of the groups that did not push as they went, into the total's bands
    // (their bands were added before the solve).
    for (gi, &(i, j)) in groups.iter().enumerate() {
        if eager[gi].is_some() {
            continue;
        }
        let stats = total
            .points
            .get_mut(&inputs[i].point)
            .expect("added before the solve");
        let before = undo.and_then(|u| u[gi].as_ref());
        // Each (field, time) band is its own accumulator: they are filled in parallel, each from
        // its rows in member order (the same sums as one after the other).
        let mut bands: Vec<(usize, usize, usize, &mut FieldBand)> = Vec::new();
        for (fi, (name, per_time)) in stats.fields.iter_mut().enumerate() {
            let f = header
                .band_fields
                .iter()
                .position(|n| n == name)
                .expect("a band of a band field");
            bands.extend(per_time.iter_mut().enumerate().map(|(k, b)| (fi, f, k, b)));
        }
        let rows_of = |f: usize, k: usize, completed_only: bool| -> Vec<&[f64]> {
            (i..j)
                .filter(|&m| ok_member[m] || !completed_only)
                .filter(|&m| pushed(m, f, k))
                .map(|m| {
                    let at = row_offset(f, k, pass.row_slot[m], shape);
                    &buffer.field_rows[at..at + grid]
                })
                .collect()
        };
        bands
            .par_iter_mut()
            .try_for_each(|(fi, f, k, band)| {
                if let Some(before) = before {
                    // What the earlier pass pushed as it went: every recorded row.
                    band.undo_pushes(&before[*fi][*k], &rows_of(*f, *k, false))?;
                }
                band.push_rows(&rows_of(*f, *k, true))
            })
            .map_err(|e| super::report::stats_error(dir, e))?;
    }
    costs.statistics_seconds += started.elapsed().as_secs_f64();
    if spec.store_members {
        write_kept_members(
            dir,
            (first, end),
            grid,
            t_count,
            &kept_snapshots,
            &kept_estimates,
        )?;
    }

    let rows = member_rows(
        first,
        header,
        inputs,
        &reports,
        &responses,
        &dstar_summaries(inputs),
    );
    Ok(Pass::Done(rows))
}

/// Per member, the mean critical gap d* and the smallest critical density rho* (NaN without
/// roughness), for members.csv.
fn dstar_summaries(inputs: &[MemberInputs]) -> Vec<(f64, f64)> {
    inputs
        .iter()
        .map(|inp| match &inp.chain.dstar {
            Some(d) => {
                let c = &inp.chain;
                let mean = d.iter().sum::<f64>() / d.len() as f64;
                let max_d = d.iter().fold(0.0f64, |a, &b| a.max(b));
                (mean, 2.0 * c.eps / (max_d + 2.0 * c.eps))
            }
            None => (f64::NAN, f64::NAN),
        })
        .collect()
}

/// Statistics of the members that completed (a member that failed at any time enters none),
/// per sweep point, into the chunk's `state`. The scalars at each output time went into the
/// chunk's summaries beside the solve (`push_output_scalars`); a point with a member that failed
/// after some outputs has them summed again, without it. The chunk's state is then merged into
/// the total, so the moments' rounding does not depend on the chunking of earlier runs, and
/// neither do the sketches' counts (exact either way).
fn settle_points(
    state: &mut StudyState,
    header: &StudyHeader,
    inputs: &[MemberInputs],
    groups: &[(usize, usize)],
    ok_member: &[bool],
    recorded: &[Vec<Option<RecordedObservables>>],
    responses: &Responses,
) {
    let mut summed_again: Vec<u64> = Vec::new();
    for &(i, j) in groups {
        let point = inputs[i].point;
        if !header.is_detailed(point) || (i..j).all(|m| ok_member[m]) {
            continue;
        }
        if !summed_again.contains(&point) {
            summed_again.push(point);
            state.point_mut(point, header).scalars =
                super::state::PointStats::without_bands(header, point).scalars;
        }
    }
    // Only the points summed again copy their members' observables, the failed ones left out.
    // Each (scalar, time) summary still receives its point's groups in order, members in order.
    for &(i, j) in groups {
        if !summed_again.contains(&inputs[i].point) {
            continue;
        }
        let completed: Vec<Vec<Option<RecordedObservables>>> = (i..j)
            .map(|m| match ok_member[m] {
                true => recorded[m].clone(),
                false => vec![None; recorded[m].len()],
            })
            .collect();
        for k in 0..header.times.len() {
            push_output_scalars(state, header, &inputs[i..j], k, &completed);
        }
    }
    for &(i, j) in groups {
        let stats = state.point_mut(inputs[i].point, header);
        for m in i..j {
            if !ok_member[m] {
                stats.failed += 1;
                continue;
            }
            stats.completed += 1;
            stats.peak_density.push(responses.peak[m].0);
            stats.min_gap.push(responses.min_gap[m]);
            stats.final_energy.push(responses.final_energy[m]);
            if responses.first_hit[m].is_nan() {
                stats.never_hit += 1;
            } else {
                stats.first_hit.push(responses.first_hit[m]);
            }
        }
    }
}
