//! One batch of a chunk's pass: compatible members solved from output time to output time, each
//! output's statistics (responses, scalars, field rows, peak centres) beside the solve to the
//! next.

use std::path::Path;
use std::time::Instant;

use rayon::prelude::*;

use super::members::Responses;
use super::{
    band_row, chunk_plan, push_as_observed, push_output_scalars, row_offset, MomentsBefore,
    RecordedObservables, StudyCosts,
};
use crate::backend::{Engine, MemberReport, OutputStatus};
use crate::error::Result;
use crate::model::chain::Chain;
use crate::model::observables::Snapshot;
use crate::model::params::MemberParams;
use crate::scene::members::{EnsembleMembers, MemberInputs};
use crate::scene::EnsembleSpec;
use crate::study::files::StudyHeader;
use crate::study::state::StudyState;

/// What a chunk's pass shares with each of its batches.
pub(super) struct PassContext<'a> {
    pub(super) dir: &'a Path,
    pub(super) spec: &'a EnsembleSpec,
    pub(super) members: &'a EnsembleMembers,
    pub(super) header: &'a StudyHeader,
    pub(super) engine: &'a Engine,
    pub(super) inputs: &'a [MemberInputs],
    pub(super) groups: &'a [(usize, usize)],
    pub(super) eager: &'a MomentsBefore,
    /// The group of each member of the chunk.
    pub(super) group_of: Vec<usize>,
    /// Per member of the chunk, how many before it are deferred (their rows wait for the end
    /// of the chunk in `field_rows`): a deferred member's row index there; one more entry, the
    /// count of all.
    pub(super) row_slot: Vec<usize>,
    /// (output times, deferred members, grid points) of `field_rows`.
    pub(super) shape: (usize, usize, usize),
}

impl PassContext<'_> {
    /// Whether member `m` of the chunk pushes its rows as they are observed.
    pub(super) fn is_eager(&self, m: usize) -> bool {
        self.eager[self.group_of[m]].is_some()
    }
}

/// What one batch of a chunk's pass leaves, per member in member order.
pub(super) struct BatchOutcome {
    pub(super) reports: Vec<MemberReport>,
    pub(super) recorded: Vec<Vec<Option<RecordedObservables>>>,
    pub(super) kept: Vec<Vec<Snapshot>>,
    pub(super) estimates: Vec<Vec<f64>>,
}

/// Solves the chunk's members `a..b` (one batch: compatible members) from output time to output
/// time, each output's statistics beside the solve to the next: the responses into
/// `responses`, the scalars into the chunk's `state`, the rows of eager groups into `total`'s
/// bands and the others' into `field_rows`.
pub(super) fn solve_batch(
    pass: &PassContext,
    (a, b): (usize, usize),
    total: &mut StudyState,
    field_rows: &mut [f64],
    state: &mut StudyState,
    responses: &mut Responses,
    costs: &mut StudyCosts,
) -> Result<BatchOutcome> {
    let PassContext {
        dir,
        spec,
        members,
        header,
        engine,
        inputs,
        groups,
        eager,
        ref row_slot,
        shape,
        ..
    } = *pass;
    let is_eager = |m: usize| pass.is_eager(m);
    let (t_count, grid) = (shape.0, shape.2);
    let keep = spec.store_members;
    let Responses {
        peak,
        min_gap,
        final_energy,
        first_hit,
    } = responses;
    let setup = inputs[a].setup.clone();
    let params: Vec<MemberParams> = inputs[a..b].iter().map(|i| i.params).collect();
    let chains: Vec<Chain> = inputs[a..b].iter().map(|i| i.chain.clone()).collect();
    let detailed = inputs[a..b].iter().any(|i| header.is_detailed(i.point));
    let mut plan = chunk_plan(
        &setup.scene,
        &chains[0],
        params,
        spec.store_members,
        detailed,
        engine.record.precision,
    );
    if let (Some(expr), Some(forcing)) = (members.symbolic_forcing(), plan.forcing.as_mut()) {
        forcing.expr = expr.clone();
        forcing.params = inputs[a..b]
            .iter()
            .flat_map(|i| members.forcing_values(i.point))
            .collect();
    }
    let mut group_recorded: Vec<Vec<Option<RecordedObservables>>> =
        (a..b).map(|_| Vec::with_capacity(t_count)).collect();
    let mut group_kept: Vec<Vec<Snapshot>> = (a..b).map(|_| Vec::new()).collect();
    let mut group_estimates: Vec<Vec<f64>> = (a..b).map(|_| Vec::new()).collect();
    let mut solver = engine.solver(plan, chains)?;
    let mut k = 0;
    // An output's statistics beside the solve to the next output time, which has the
    // threads to itself otherwise only in parts: the rows of groups that push as they go
    // into their bands, the others' rows copied for after the chunk, and the peak centres.
    // `recorded[g]`: batch member a + g is recorded at output k.
    // The batch's deferred members (their rows wait in `field_rows`, at slots
    // first_slot..end_slot in member order).
    let (first_slot, end_slot) = (row_slot[a], row_slot[b]);
    let deferred: Vec<usize> = (0..b - a)
        .filter(|&g| row_slot[a + g + 1] > row_slot[a + g])
        .collect();
    let output_statistics = |snaps: &[Snapshot],
                             k: usize,
                             recorded: &[bool],
                             total: &mut StudyState,
                             field_rows: &mut [f64]|
     -> Result<f64> {
        let busy = std::sync::atomic::AtomicU64::new(0);
        let fields = header.band_fields.len();
        // The buffer's rows of this output, member after member (`fields` rows each, at
        // least one slot so that every member has its chunk; None where not copied).
        let per_member = fields.max(1);
        let mut member_rows: Vec<Option<&mut [f64]>> = Vec::new();
        member_rows.resize_with((b - a) * per_member, || None);
        if end_slot > first_slot && fields > 0 {
            let mut rest = &mut field_rows[row_offset(0, k, first_slot, shape)..];
            let mut at = row_offset(0, k, first_slot, shape);
            for f in 0..fields {
                // Fields lie apart in the buffer, in field order.
                let (_, from) = rest.split_at_mut(row_offset(f, k, first_slot, shape) - at);
                let (these, after) = from.split_at_mut((end_slot - first_slot) * grid);
                for (&g, row) in deferred.iter().zip(these.chunks_mut(grid)) {
                    member_rows[g * per_member + f] = Some(row);
                }
                rest = after;
                at = row_offset(f, k, end_slot, shape);
            }
        }
        // The deferred members' rows, copied for after the chunk (rows pushed as they are
        // observed are read from the snapshot instead).
        snaps
            .par_iter()
            .zip(member_rows.par_chunks_mut(per_member))
            .enumerate()
            .filter(|&(g, _)| recorded[g] && !is_eager(a + g))
            .for_each(|(_, (s, rows))| {
                let started = Instant::now();
                for (row, name) in rows.iter_mut().zip(&header.band_fields) {
                    let from = band_row(s, name);
                    if let (Some(into), true) = (row, from.len() == grid) {
                        into.copy_from_slice(from);
                    }
                }
                let nanos = started.elapsed().as_nanos() as u64;
                busy.fetch_add(nanos, std::sync::atomic::Ordering::Relaxed);
            });
        let pushing = push_as_observed(total, groups, eager, inputs, (a, b), snaps, k, recorded)
            .map_err(|e| crate::study::report::stats_error(dir, e))?;
        Ok(busy.into_inner() as f64 * 1e-9 + pushing)
    };
    // The output last reached, with each member's status there, for the statistics beside
    // the next solve.
    let mut pending: Option<(Vec<Snapshot>, usize, Vec<OutputStatus>)> = None;
    loop {
        let (next, statistics) = rayon::join(
            || solver.next_output(&|_| {}),
            || -> Result<f64> {
                let Some((snaps, k, status_now)) = pending.take() else {
                    return Ok(0.0);
                };
                let started = Instant::now();
                let t = header.times[k];
                let ok_now = |g: usize| status_now[g].ok;
                let recorded_here = |g: usize| ok_now(g) && header.is_detailed(inputs[a + g].point);
                for (g, s) in snaps.iter().enumerate() {
                    let i = a + g;
                    // The estimate of the state at this output time (the last one recorded).
                    let estimate = match ok_now(g) {
                        true => status_now[g].error_estimate,
                        false => f64::NAN,
                    };
                    if keep {
                        group_kept[g].push(s.clone());
                        group_estimates[g].push(estimate);
                    }
                    if !ok_now(g) {
                        group_recorded[g].push(None);
                        continue;
                    }
                    if s.max_density > peak[i].0 {
                        peak[i] = (s.max_density, t);
                    }
                    min_gap[i] = min_gap[i].min(s.min_gap);
                    final_energy[i] = s.energy;
                    if first_hit[i].is_nan() && s.max_density >= spec.threshold {
                        first_hit[i] = t;
                    }
                    if !recorded_here(g) {
                        // Responses only: nothing per time is kept.
                        continue;
                    }
                    let mut rows_present = 0u8;
                    for (f, name) in header.band_fields.iter().enumerate() {
                        if band_row(s, name).len() == grid {
                            rows_present |= 1 << f;
                        }
                    }
                    group_recorded[g].push(Some(RecordedObservables {
                        scalars: [
                            s.max_density,
                            s.min_gap,
                            s.energy,
                            s.dissipation,
                            s.peak_centre,
                            estimate,
                        ],
                        rows_present,
                    }));
                }
                let recorded: Vec<bool> = (0..b - a).map(recorded_here).collect();
                let recording = started.elapsed().as_secs_f64();
                let busy = output_statistics(&snaps, k, &recorded, total, field_rows)?;
                let started = Instant::now();
                push_output_scalars(state, header, &inputs[a..b], k, &group_recorded);
                let scalars = started.elapsed().as_secs_f64();
                // Beside the solve, so its cost to the study's wall time is its threads'
                // time spread over the threads, not how long it was under way.
                Ok((recording + busy + scalars) / rayon::current_num_threads() as f64)
            },
        );
        costs.statistics_seconds += statistics?;
        let Some(snaps) = next? else {
            break;
        };
        // Each member's status here is the solver's work, not the statistics' (with order 1
        // and fixed steps it compares the run with its companion: the error estimate).
        pending = Some((snaps, k, solver.output_status()));
        k += 1;
    }
    let reports = solver.reports();
    if let Some(work) = solver.gpu_stats() {
        costs
            .gpu
            .get_or_insert_with(Default::default)
            .accumulate(&work);
    }
    Ok(BatchOutcome {
        reports,
        recorded: group_recorded,
        kept: group_kept,
        estimates: group_estimates,
    })
}
