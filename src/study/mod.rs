//! Ensemble studies (`[ensemble]` in a scene): thousands to millions of members that differ by
//! random roughness profiles, perturbed initial data and swept parameters, solved in chunks and
//! summarised by mergeable statistics. Member m's random inputs are a pure function of
//! (seed, m) (`crate::ensemble`), so its result does not depend on chunking, threads, backend or
//! shard.
//!
//! Layout of a study directory:
//! - `study.json`: what is being computed (scene text and hash, shard, member range, times, grid);
//!   written first, checked by `--resume` and `merge`;
//! - `chunks/chunk_<first>_<end>.json`: the statistics and CSV rows of each finished chunk,
//!   written atomically (a killed run keeps every finished chunk; `--resume` skips them);
//! - `partial.json`: the mergeable statistics of all members of this run (or shard);
//! - `stats/*.npy`, `members.csv`, `plots/*.png`, and `manifest.json` last.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::backend::select::{BackendRecord, RunsOn};
use crate::backend::{select, Backend, Engine, MemberStatus, Precision};
use crate::ensemble::{
    dstar_from_radii, jitter_gaps, mean_radii_from_rho_star, perturbed_velocity, RoughnessSampler,
};
use crate::error::{Error, Result};
use crate::model::chain::{positions_from_gaps, Chain};
use crate::model::observables::Snapshot;
use crate::model::params::MemberParams;
use crate::model::plan::Plan;
use crate::output::manifest::{
    MergedManifest, QuantileMethod, StudyManifest, StudySceneRecord, VERSION,
};
use crate::output::{
    prepare_dir, read_json, write_json_atomic, write_npy, ProgressReporter, MANIFEST,
};
use crate::scene::{EnsembleSpec, InitialSpec, Scene};
use crate::stats::{QuantileSketch, RunningStats, ScalarSummary};

/// Scalar observables summarised at every output time.
pub const SCALARS: [&str; 5] = [
    "max_density",
    "min_gap",
    "energy",
    "dissipation",
    "peak_centre",
];
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
}

#[derive(Debug, Clone)]
pub struct StudySummary {
    pub out_dir: PathBuf,
    pub members: u64,
    pub failed: u64,
    pub chunks_reused: usize,
    pub wall_seconds: f64,
    pub statistics_seconds: f64,
}

// ---------------------------------------------------------------------------------------------
// Field bands: pointwise mean/variance and a histogram per grid point (quantile bands).

/// Pointwise statistics of a field over members: mean and variance (Chan-mergeable) and a
/// fixed-bin histogram on [lo, hi] per point, from which quantiles are read: the reported value
/// is the midpoint of the bin that holds the sample of the requested rank, so it is within half
/// a bin width, (hi - lo)/(2 bins), of that sample. Values outside [lo, hi] are counted apart;
/// a quantile whose rank falls among them is NaN (reported, never guessed). Histogram counts
/// merge exactly, so sharded bands equal unsharded ones.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FieldBand {
    pub lo: f64,
    pub hi: f64,
    pub bins: u32,
    pub points: Vec<RunningStats>,
    /// Per point, bins + 2 counts: bin 0 = below lo, bins + 1 = above hi (stored sparse on disk).
    #[serde(with = "sparse_counts")]
    pub counts: Vec<Vec<u64>>,
}

/// Histogram counts are mostly zero: on disk each row is a list of (bin, count) pairs.
mod sparse_counts {
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    #[derive(Serialize, Deserialize)]
    struct Row {
        len: usize,
        nonzero: Vec<(u32, u64)>,
    }

    pub fn serialize<S: Serializer>(rows: &[Vec<u64>], s: S) -> Result<S::Ok, S::Error> {
        let sparse: Vec<Row> = rows
            .iter()
            .map(|r| Row {
                len: r.len(),
                nonzero: r
                    .iter()
                    .enumerate()
                    .filter(|(_, &c)| c > 0)
                    .map(|(b, &c)| (b as u32, c))
                    .collect(),
            })
            .collect();
        sparse.serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<Vec<u64>>, D::Error> {
        let sparse = Vec::<Row>::deserialize(d)?;
        let mut rows = Vec::with_capacity(sparse.len());
        for row in sparse {
            let mut dense = vec![0u64; row.len];
            for (b, c) in row.nonzero {
                let slot = dense.get_mut(b as usize).ok_or_else(|| {
                    serde::de::Error::custom(format!("histogram bin {b} beyond {}", row.len))
                })?;
                *slot = c;
            }
            rows.push(dense);
        }
        Ok(rows)
    }
}

impl FieldBand {
    pub fn new(points: usize, lo: f64, hi: f64, bins: usize) -> FieldBand {
        FieldBand {
            lo,
            hi,
            bins: bins as u32,
            points: vec![RunningStats::new(); points],
            counts: vec![vec![0; bins + 2]; points],
        }
    }

    /// Adds the rows of one chunk (each of length `points`). Moments are accumulated in bulk
    /// (shifted sums, then one Chan merge per point) because this is the hot part of the
    /// statistics.
    pub fn push_rows(&mut self, rows: &[&[f64]]) {
        let g = self.points.len();
        let bins = self.bins as usize;
        let scale = bins as f64 / (self.hi - self.lo);
        // Shift each point by its first finite value (keeps the shifted sums well conditioned).
        let mut shift = vec![f64::NAN; g];
        for row in rows {
            for (s, &x) in shift.iter_mut().zip(row.iter()) {
                if s.is_nan() && x.is_finite() {
                    *s = x;
                }
            }
        }
        // Rows outer, points inner: memory is read in order.
        let mut n = vec![0u64; g];
        let mut s1 = vec![0.0f64; g];
        let mut s2 = vec![0.0f64; g];
        let mut min = vec![f64::INFINITY; g];
        let mut max = vec![f64::NEG_INFINITY; g];
        for row in rows {
            for j in 0..g {
                let x = row[j];
                if !x.is_finite() {
                    continue;
                }
                n[j] += 1;
                let d = x - shift[j];
                s1[j] += d;
                s2[j] += d * d;
                min[j] = min[j].min(x);
                max[j] = max[j].max(x);
                let bin = if x < self.lo {
                    0
                } else if x > self.hi {
                    bins + 1
                } else {
                    1 + (((x - self.lo) * scale) as usize).min(bins - 1)
                };
                self.counts[j][bin] += 1;
            }
        }
        for j in 0..g {
            if n[j] == 0 {
                continue;
            }
            let mean_d = s1[j] / n[j] as f64;
            let m2 = (s2[j] - s1[j] * mean_d).max(0.0);
            self.points[j].merge(&RunningStats::from_moments(
                n[j],
                shift[j] + mean_d,
                m2,
                min[j],
                max[j],
            ));
        }
    }

    pub fn merge(&mut self, other: &FieldBand) -> Result<()> {
        if other.lo != self.lo
            || other.hi != self.hi
            || other.bins != self.bins
            || other.points.len() != self.points.len()
        {
            return Err(Error::Output {
                path: PathBuf::from("partial.json"),
                message: "field bands with different ranges, bins or grids cannot be merged".into(),
            });
        }
        for (j, p) in other.points.iter().enumerate() {
            self.points[j].merge(p);
            for (a, b) in self.counts[j].iter_mut().zip(&other.counts[j]) {
                *a += b;
            }
        }
        Ok(())
    }

    pub fn mean_row(&self) -> Vec<f64> {
        self.points.iter().map(|p| p.mean()).collect()
    }

    pub fn variance_row(&self) -> Vec<f64> {
        self.points.iter().map(|p| p.variance()).collect()
    }

    /// The q-quantile at each point (lower rank floor(q (n-1))), within half a bin width.
    pub fn quantile_row(&self, q: f64) -> Vec<f64> {
        let width = (self.hi - self.lo) / self.bins as f64;
        self.counts
            .iter()
            .map(|counts| {
                let n: u64 = counts.iter().sum();
                if n == 0 {
                    return f64::NAN;
                }
                let rank = ((q * (n - 1) as f64).floor() as u64).min(n - 1);
                let mut seen = 0;
                for (b, &c) in counts.iter().enumerate() {
                    let b = b as u32;
                    seen += c;
                    if rank < seen {
                        return if b == 0 || b == self.bins + 1 {
                            f64::NAN
                        } else {
                            self.lo + (b as f64 - 0.5) * width
                        };
                    }
                }
                f64::NAN
            })
            .collect()
    }
}

// ---------------------------------------------------------------------------------------------
// Study state: everything mergeable.

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StudyState {
    /// Member ranges [first, end) included, sorted and disjoint.
    pub ranges: Vec<(u64, u64)>,
    pub completed: u64,
    pub failed: Vec<u64>,
    /// Per scalar observable, one summary per output time.
    pub scalars: BTreeMap<String, Vec<ScalarSummary>>,
    /// First output time at which max density reaches the threshold.
    pub first_hit: ScalarSummary,
    pub never_hit: u64,
    /// Per field, one band per output time.
    pub fields: BTreeMap<String, Vec<FieldBand>>,
}

impl StudyState {
    fn new(
        times: usize,
        grid: usize,
        ranges: &BTreeMap<String, (f64, f64)>,
        bins: usize,
    ) -> StudyState {
        let summary =
            || ScalarSummary::new(SCALAR_ALPHA).expect("SCALAR_ALPHA is a valid accuracy");
        StudyState {
            ranges: Vec::new(),
            completed: 0,
            failed: Vec::new(),
            scalars: SCALARS
                .iter()
                .map(|s| (s.to_string(), (0..times).map(|_| summary()).collect()))
                .collect(),
            first_hit: summary(),
            never_hit: 0,
            fields: FIELDS
                .iter()
                .map(|f| {
                    let (lo, hi) = ranges[*f];
                    (
                        f.to_string(),
                        (0..times)
                            .map(|_| FieldBand::new(grid, lo, hi, bins))
                            .collect(),
                    )
                })
                .collect(),
        }
    }

    pub fn merge(&mut self, other: &StudyState) -> Result<()> {
        let bad = |message: String| Error::Output {
            path: PathBuf::from("partial.json"),
            message,
        };
        self.ranges.extend_from_slice(&other.ranges);
        self.ranges.sort();
        for w in self.ranges.windows(2) {
            if w[0].1 > w[1].0 {
                return Err(bad(format!(
                    "member ranges {:?} and {:?} overlap: a member would be counted twice",
                    w[0], w[1]
                )));
            }
        }
        self.completed += other.completed;
        self.failed.extend_from_slice(&other.failed);
        self.failed.sort_unstable();
        for (name, per_time) in &other.scalars {
            let mine = self
                .scalars
                .get_mut(name)
                .ok_or_else(|| bad(format!("unknown observable {name}")))?;
            for (a, b) in mine.iter_mut().zip(per_time) {
                a.merge(b).map_err(|e| bad(e.to_string()))?;
            }
        }
        self.first_hit
            .merge(&other.first_hit)
            .map_err(|e| bad(e.to_string()))?;
        self.never_hit += other.never_hit;
        for (name, per_time) in &other.fields {
            let mine = self
                .fields
                .get_mut(name)
                .ok_or_else(|| bad(format!("unknown field {name}")))?;
            if mine.len() != per_time.len() {
                return Err(bad("different numbers of output times".into()));
            }
            for (a, b) in mine.iter_mut().zip(per_time) {
                a.merge(b)?;
            }
        }
        Ok(())
    }
}

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

#[derive(Debug, Clone, Serialize, Deserialize)]
struct ChunkFile {
    range: (u64, u64),
    state: StudyState,
    rows: Vec<MemberRow>,
}

/// FNV-1a of the scene text: identifies the study for resume and merge.
fn scene_hash(text: &str) -> String {
    let mut h: u64 = 0xcbf29ce484222325;
    for b in text.as_bytes() {
        h ^= *b as u64;
        h = h.wrapping_mul(0x100000001b3);
    }
    format!("{h:016x}")
}

// ---------------------------------------------------------------------------------------------
// Members.

/// The deterministic part shared by all members.
pub struct Base {
    pub chain: Chain,
    pub positions: Vec<f64>,
    pub sampler: Option<RoughnessSampler>,
    pub sweep: Vec<MemberParams>,
}

/// Member m's inputs beyond the chain, for the CSV.
#[derive(Debug, Clone, Copy)]
pub struct MemberDraw {
    pub factor: f64,
    pub phase: f64,
}

impl Base {
    pub fn new(scene: &Scene, spec: &EnsembleSpec) -> Result<Base> {
        let chain = scene.initial_chain()?;
        let positions = chain.positions();
        let sampler = match &spec.roughness {
            None => None,
            Some(r) => {
                let mean = match &chain.dstar {
                    Some(d) => mean_radii_from_rho_star(d),
                    None => vec![spec.mean_radius.unwrap_or(0.0); chain.particles() + 1],
                };
                Some(
                    RoughnessSampler::new(r, &mean, &positions, spec.seed).map_err(|e| {
                        Error::invalid(
                            "ensemble.roughness",
                            format!("{r:?}"),
                            e.to_string(),
                            "see the scene reference",
                        )
                    })?,
                )
            }
        };
        Ok(Base {
            chain,
            positions,
            sampler,
            sweep: scene.member_parameters(),
        })
    }

    /// Member m: a pure function of (scene, seed, m).
    pub fn member(
        &self,
        scene: &Scene,
        spec: &EnsembleSpec,
        m: u64,
    ) -> Result<(Chain, MemberParams, MemberDraw)> {
        let mut chain = self.chain.clone();
        if let Some(sampler) = &self.sampler {
            let radii = sampler.sample(m);
            chain.dstar = Some(dstar_from_radii(&radii));
        }
        if spec.jitter > 0.0 {
            jitter_gaps(
                &mut chain.gaps,
                chain.bonded.as_deref(),
                spec.jitter,
                spec.seed,
                m,
            )
            .map_err(|e| {
                Error::invalid("ensemble.jitter", spec.jitter, e.to_string(), "0 <= jitter")
            })?;
        }
        let (factor, phase) = perturbed_velocity(
            spec.velocity_amplitude_spread,
            spec.velocity_phase_spread,
            spec.seed,
            m,
        );
        match &scene.initial {
            InitialSpec::Profiles { velocity, .. } => {
                let q = positions_from_gaps(&chain.gaps, chain.eps);
                for (i, u) in chain.velocities.iter_mut().enumerate() {
                    *u = factor * velocity.eval(q[i + 1] - phase, 0.0);
                }
            }
            InitialSpec::Particles { .. } => {
                for u in chain.velocities.iter_mut() {
                    *u *= factor;
                }
            }
        }
        // Particles glued into a cluster keep one velocity.
        if let Some(bonded) = &chain.bonded {
            let n = chain.particles();
            for g in 1..n {
                if bonded[g] {
                    chain.velocities[g] = chain.velocities[g - 1];
                }
            }
            if bonded[0] {
                chain.velocities[0] = 0.0;
                for g in 1..n - 1 {
                    if bonded[g] {
                        chain.velocities[g] = 0.0;
                    } else {
                        break;
                    }
                }
            }
        }
        let params = self.sweep[(m % self.sweep.len() as u64) as usize];
        Ok((chain, params, MemberDraw { factor, phase }))
    }
}

// ---------------------------------------------------------------------------------------------
// Running a study.

/// The plan of a chunk: the scene's, with these members, and the fields the statistics need.
fn chunk_plan(scene: &Scene, first_chain: &Chain, members: Vec<MemberParams>) -> Plan {
    let mut plan = Plan::new(scene, first_chain);
    plan.members = members;
    plan.repulsion = first_chain.dstar.is_some();
    plan.fields.rho_star = plan.repulsion;
    plan.fields.rho = true;
    plan.fields.u = true;
    plan
}

/// Solves members [first, end) and returns their statistics and rows.
#[allow(clippy::too_many_arguments)]
fn solve_chunk(
    scene: &Scene,
    spec: &EnsembleSpec,
    base: &Base,
    header: &StudyHeader,
    engine: &Engine,
    first: u64,
    end: u64,
    stats_seconds: &mut f64,
    progress: &ProgressReporter,
) -> Result<ChunkFile> {
    let mut chains = Vec::with_capacity((end - first) as usize);
    let mut params = Vec::with_capacity(chains.capacity());
    let mut draws = Vec::with_capacity(chains.capacity());
    for m in first..end {
        let (c, p, d) = base.member(scene, spec, m)?;
        chains.push(c);
        params.push(p);
        draws.push(d);
    }
    let plan = chunk_plan(scene, &chains[0], params.clone());
    let t_count = header.times.len();
    let grid = header.x.len();
    let mut state = StudyState::new(t_count, grid, &header.field_ranges, header.bins);
    state.ranges.push((first, end));
    let count = (end - first) as usize;
    let mut peak = vec![(f64::NEG_INFINITY, f64::NAN); count];
    let mut min_gap = vec![f64::INFINITY; count];
    let mut final_energy = vec![f64::NAN; count];
    let mut first_hit = vec![f64::NAN; count];
    let dstar_summary: Vec<(f64, f64)> = chains
        .iter()
        .map(|c| match &c.dstar {
            Some(d) => {
                let mean = d.iter().sum::<f64>() / d.len() as f64;
                let max_d = d.iter().fold(0.0f64, |a, &b| a.max(b));
                (mean, 2.0 * c.eps / (max_d + 2.0 * c.eps))
            }
            None => (f64::NAN, f64::NAN),
        })
        .collect();

    // Full per-member arrays, only when asked for: [member, time, ...] per chunk.
    let keep = spec.store_members;
    let mut kept_gaps: Vec<f64> = Vec::new();
    let mut kept_vel: Vec<f64> = Vec::new();
    let mut kept_rho: Vec<f64> = Vec::new();
    let mut per_time: Vec<Vec<Snapshot>> = Vec::new();
    // Each output time's observables, kept per member until the chunk is solved: a member that
    // fails later must not enter the statistics of any time (failed members are counted and
    // listed, never averaged in). Only what the statistics need is kept (scalars, field rows).
    struct Lite {
        scalars: [f64; 5],
        fields: [Vec<f64>; 3],
    }
    let mut recorded: Vec<Vec<Option<Lite>>> = Vec::with_capacity(t_count);
    let mut consume = |k: usize, snaps: &[Snapshot], failed_now: &[bool]| {
        if keep {
            per_time.push(snaps.to_vec());
        }
        let started = Instant::now();
        let t = header.times[k];
        let mut row = Vec::with_capacity(snaps.len());
        for (i, s) in snaps.iter().enumerate() {
            if failed_now[i] {
                row.push(None);
                continue;
            }
            let centre = peak_centre(&header.x, &s.rho);
            if s.max_density > peak[i].0 {
                peak[i] = (s.max_density, t);
            }
            min_gap[i] = min_gap[i].min(s.min_gap);
            final_energy[i] = s.energy;
            if first_hit[i].is_nan() && s.max_density >= spec.threshold {
                first_hit[i] = t;
            }
            row.push(Some(Lite {
                scalars: [s.max_density, s.min_gap, s.energy, s.dissipation, centre],
                fields: [s.rho.clone(), s.u.clone(), s.rho_star.clone()],
            }));
        }
        recorded.push(row);
        *stats_seconds += started.elapsed().as_secs_f64();
    };

    let mut solver = engine.solver(plan, chains)?;
    let mut k = 0;
    while let Some(snaps) = solver.next_output(&|_| {})? {
        let failed_now: Vec<bool> = solver
            .reports()
            .iter()
            .map(|r| r.status != MemberStatus::Ok)
            .collect();
        consume(k, &snaps, &failed_now);
        k += 1;
    }
    let reports = solver.reports();
    progress.inc(count as u64);
    let started = Instant::now();
    let ok_member: Vec<bool> = reports
        .iter()
        .map(|r| r.status == MemberStatus::Ok)
        .collect();
    for (k, row) in recorded.iter().enumerate() {
        for (i, lite) in row.iter().enumerate() {
            if let (true, Some(l)) = (ok_member[i], lite) {
                for (name, &v) in SCALARS.iter().zip(&l.scalars) {
                    state.scalars.get_mut(*name).expect("known observable")[k].push(v);
                }
            }
        }
        for (f, name) in FIELDS.iter().enumerate() {
            let rows: Vec<&[f64]> = row
                .iter()
                .zip(&ok_member)
                .filter_map(|(lite, &ok)| if ok { lite.as_ref() } else { None })
                .map(|l| l.fields[f].as_slice())
                .filter(|r| r.len() == grid)
                .collect();
            state.fields.get_mut(*name).expect("known field")[k].push_rows(&rows);
        }
    }
    *stats_seconds += started.elapsed().as_secs_f64();
    if keep {
        let n = header_particles(&per_time);
        for i in 0..count {
            for snaps in &per_time {
                let s = &snaps[i];
                let pad = |v: &[f64], len: usize| {
                    if v.len() == len {
                        v.to_vec()
                    } else {
                        vec![f64::NAN; len]
                    }
                };
                kept_gaps.extend(pad(&s.gaps, n));
                kept_vel.extend(pad(&s.velocities, n.saturating_sub(1)));
                kept_rho.extend(pad(&s.rho, grid));
            }
        }
        let members_dir = header_dir(header).join("members");
        std::fs::create_dir_all(&members_dir).map_err(|e| Error::io(&members_dir, e))?;
        let (c, t, n) = (count as u64, t_count as u64, n as u64);
        let name = |what: &str| members_dir.join(format!("chunk_{first:012}_{end:012}_{what}.npy"));
        write_npy(name("gaps"), &[c, t, n], &kept_gaps)?;
        write_npy(name("velocities"), &[c, t, n - 1], &kept_vel)?;
        write_npy(name("rho"), &[c, t, grid as u64], &kept_rho)?;
    }

    let mut rows = Vec::with_capacity(count);
    for (i, r) in reports.iter().enumerate() {
        let m = first + i as u64;
        let (status, failure_time) = match &r.status {
            MemberStatus::Ok => ("ok".to_string(), f64::NAN),
            MemberStatus::Failed { time, .. } => ("failed".to_string(), *time),
        };
        let failed = r.status != MemberStatus::Ok;
        if failed {
            state.failed.push(m);
        } else {
            state.completed += 1;
            if first_hit[i].is_nan() {
                state.never_hit += 1;
            } else {
                state.first_hit.push(first_hit[i]);
            }
        }
        rows.push(MemberRow {
            member: m,
            sweep_point: (m % base.sweep.len() as u64) as usize,
            mu: r.mu,
            gamma: r.gamma,
            status,
            failure_time,
            velocity_factor: draws[i].factor,
            velocity_phase: draws[i].phase,
            mean_dstar: dstar_summary[i].0,
            min_rho_star: dstar_summary[i].1,
            peak_density: if failed { f64::NAN } else { peak[i].0 },
            peak_time: if failed { f64::NAN } else { peak[i].1 },
            min_gap: if failed { f64::NAN } else { min_gap[i] },
            final_energy: if failed { f64::NAN } else { final_energy[i] },
            first_hit_time: first_hit[i],
            steps_accepted: r.steps_accepted,
            steps_rejected: r.steps_rejected,
        });
    }
    Ok(ChunkFile {
        range: (first, end),
        state,
        rows,
    })
}

/// N of the stored chunk (from any member's gaps; failed members have none after failing).
fn header_particles(per_time: &[Vec<Snapshot>]) -> usize {
    per_time
        .iter()
        .flat_map(|s| s.iter())
        .map(|s| s.gaps.len())
        .max()
        .unwrap_or(0)
}

fn header_dir(header: &StudyHeader) -> PathBuf {
    PathBuf::from(&header.out_dir)
}

/// Centre of mass of the density peak: the centroid of the excess of rho over its spatial mean
/// (NaN when the profile is flat).
pub fn peak_centre(x: &[f64], rho: &[f64]) -> f64 {
    if rho.is_empty() {
        return f64::NAN;
    }
    let mean = rho.iter().sum::<f64>() / rho.len() as f64;
    let (mut wx, mut w) = (0.0, 0.0);
    for (xi, r) in x.iter().zip(rho) {
        let e = (r - mean).max(0.0);
        wx += xi * e;
        w += e;
    }
    if w > 1e-12 {
        wx / w
    } else {
        f64::NAN
    }
}

/// members.csv, written row by row as chunks (or shards) are read, in member order: memory does
/// not grow with the number of members. It is written as `members.csv.partial` and renamed when
/// complete, so an interrupted run leaves no complete-looking table.
struct CsvOut {
    path: PathBuf,
    partial: PathBuf,
    writer: csv::Writer<std::fs::File>,
}

impl CsvOut {
    fn create(path: PathBuf) -> Result<CsvOut> {
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
    fn push(&mut self, row: &MemberRow) -> Result<()> {
        self.writer.serialize(row).map_err(|e| Error::Output {
            path: self.path.clone(),
            message: e.to_string(),
        })
    }
    fn finish(mut self) -> Result<()> {
        self.writer
            .flush()
            .map_err(|e| Error::io(&self.partial, e))?;
        std::fs::rename(&self.partial, &self.path).map_err(|e| Error::io(&self.path, e))
    }
}

fn chunk_path(dir: &Path, first: u64, end: u64) -> PathBuf {
    dir.join("chunks")
        .join(format!("chunk_{first:012}_{end:012}.json"))
}

/// Members [K·M/N, (K+1)·M/N) of M for shard K of N.
fn shard_range(total: u64, (k, n): (u64, u64)) -> (u64, u64) {
    (total * k / n, total * (k + 1) / n)
}

fn header_for(
    scene: &Scene,
    spec: &EnsembleSpec,
    base: &Base,
    shard: (u64, u64),
    out_dir: &Path,
    engine: &BackendRecord,
) -> StudyHeader {
    let total = spec.members * base.sweep.len() as u64;
    let range = shard_range(total, shard);
    let u_max = base
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
        sweep: base.sweep.clone(),
        field_ranges,
        bins: spec.bins,
        out_dir: out_dir.display().to_string(),
        backend: engine.backend,
        precision: engine.precision,
    }
}

/// The study's backend, chosen by the one selection policy for a batch like its largest chunk.
fn select_for_study(
    scene: &Scene,
    spec: &EnsembleSpec,
    base: &Base,
    member_range: (u64, u64),
    options: &StudyOptions,
) -> Result<Engine> {
    let (first, end) = member_range;
    // Member `first` is built up front so that bad ensemble settings fail before anything is
    // written.
    let (chain, params, _) = base.member(scene, spec, first)?;
    let largest_chunk = (spec.chunk as u64).min(end.saturating_sub(first)).max(1) as usize;
    let plan = chunk_plan(scene, &chain, vec![params; largest_chunk]);
    select(
        options.backend.unwrap_or(scene.backend),
        options.precision.unwrap_or(scene.precision),
        &plan,
    )
}

pub fn run_study(scene: &Scene, options: &StudyOptions) -> Result<StudySummary> {
    let started = Instant::now();
    let spec = scene
        .ensemble
        .as_ref()
        .ok_or_else(|| Error::missing("ensemble", "this scene has no [ensemble] section"))?;
    let (k, n) = options.shard;
    if n == 0 || k >= n {
        return Err(Error::invalid(
            "--shard",
            format!("{k}/{n}"),
            "shard K of N, K counted from 0",
            "0 <= K < N",
        ));
    }
    let base = Base::new(scene, spec)?;
    let range = shard_range(spec.members * base.sweep.len() as u64, options.shard);
    let engine = select_for_study(scene, spec, &base, range, options)?;
    let header = header_for(
        scene,
        spec,
        &base,
        options.shard,
        &options.out_dir,
        &engine.record,
    );
    if !options.quiet {
        eprintln!(
            "ensemble {}: members {}..{} of {} (shard {k}/{n}); {}",
            scene.name,
            header.member_range.0,
            header.member_range.1,
            header.members_total,
            engine.record.line()
        );
    }

    let dir = &options.out_dir;
    let chunks_dir = dir.join("chunks");
    let header_path = dir.join("study.json");
    if options.resume {
        let old: StudyHeader = read_json(&header_path)?;
        let differs = [
            ("scene text", old.scene_hash != header.scene_hash),
            ("shard", old.shard != header.shard),
            ("chunk size", old.chunk != header.chunk),
            ("backend", old.backend != header.backend),
            ("precision", old.precision != header.precision),
        ];
        let what: Vec<&str> = differs.iter().filter(|d| d.1).map(|d| d.0).collect();
        if !what.is_empty() {
            return Err(Error::Output {
                path: header_path,
                message: format!(
                    "--resume: this directory holds a different study ({} differ: it ran on {:?} in {:?}); run without --resume into a new directory, or resume with the same settings",
                    what.join(", "),
                    old.backend,
                    old.precision
                ),
            });
        }
    } else if chunks_dir.exists() {
        std::fs::remove_dir_all(&chunks_dir).map_err(|e| Error::io(&chunks_dir, e))?;
    }
    std::fs::create_dir_all(&chunks_dir).map_err(|e| Error::io(&chunks_dir, e))?;
    prepare_dir(dir)?;
    write_json_atomic(&header_path, &header)?;

    let (first, end) = header.member_range;
    let bounds: Vec<(u64, u64)> = (first..end)
        .step_by(spec.chunk)
        .map(|a| (a, (a + spec.chunk as u64).min(end)))
        .collect();
    let progress = ProgressReporter::new(end - first, "members", options.quiet);
    let mut stats_seconds = 0.0;
    let mut reused = 0;
    let mut total: Option<StudyState> = None;
    let mut csv_out = CsvOut::create(dir.join("members.csv"))?;
    for &(a, b) in &bounds {
        let path = chunk_path(dir, a, b);
        let chunk: ChunkFile = if path.exists() {
            reused += 1;
            progress.inc(b - a);
            read_json(&path)?
        } else {
            let c = solve_chunk(
                scene,
                spec,
                &base,
                &header,
                &engine,
                a,
                b,
                &mut stats_seconds,
                &progress,
            )?;
            write_json_atomic(&path, &c)?;
            c
        };
        let t0 = Instant::now();
        match &mut total {
            None => total = Some(chunk.state),
            Some(s) => s.merge(&chunk.state)?,
        }
        stats_seconds += t0.elapsed().as_secs_f64();
        for row in &chunk.rows {
            csv_out.push(row)?;
        }
    }
    progress.finish();
    csv_out.finish()?;
    let state = total.unwrap_or_else(|| {
        StudyState::new(
            header.times.len(),
            header.x.len(),
            &header.field_ranges,
            header.bins,
        )
    });
    write_json_atomic(
        &dir.join("partial.json"),
        &PartialFile {
            header: header.clone(),
            state: state.clone(),
        },
    )?;
    let t0 = Instant::now();
    finalize(dir, &[header.clone()], &state, scene.plots)?;
    stats_seconds += t0.elapsed().as_secs_f64();
    let wall = started.elapsed().as_secs_f64();
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
            gpu_stats: None,
            shard: (k, n),
            member_range: header.member_range,
            members_total: header.members_total,
            members_completed: state.completed,
            failed_members: state.failed.clone(),
            chunks: bounds.len(),
            chunks_reused: reused,
            wall_seconds: wall,
            statistics_seconds: stats_seconds,
            statistics_share: stats_seconds / wall.max(1e-12),
            ensemble: spec.clone(),
            quantile_method: quantile_method(&header),
        },
    )?;
    Ok(StudySummary {
        out_dir: dir.clone(),
        members: state.completed + state.failed.len() as u64,
        failed: state.failed.len() as u64,
        chunks_reused: reused,
        wall_seconds: wall,
        statistics_seconds: stats_seconds,
    })
}

fn quantile_method(header: &StudyHeader) -> QuantileMethod {
    QuantileMethod {
        scalars: format!("DDSketch, relative accuracy alpha = {SCALAR_ALPHA}: the value reported for level q is within alpha |x| of the sample x of rank floor(q (n-1)); merging shards is exact"),
        fields: "per grid point, a histogram of the given bins on the field's range: the midpoint of the bin holding the sample of rank floor(q (n-1)), within half a bin width of it; NaN where that sample lies outside the range",
        field_ranges: header.field_ranges.clone(),
        bins: header.bins,
        scalar_histograms: format!("{SCALAR_BINS} bins over each time's [min, max], filled from the sketch (each value placed within alpha |x|)"),
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct PartialFile {
    header: StudyHeader,
    state: StudyState,
}

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
    Ok(StudySummary {
        out_dir: out.to_path_buf(),
        members: state.completed + state.failed.len() as u64,
        failed: state.failed.len() as u64,
        chunks_reused: 0,
        wall_seconds: started.elapsed().as_secs_f64(),
        statistics_seconds: 0.0,
    })
}

/// Writes `stats/*.npy` and the plots (`members.csv` is streamed by the caller).
fn finalize(dir: &Path, headers: &[StudyHeader], state: &StudyState, plots: bool) -> Result<()> {
    let header = &headers[0];
    let stats = dir.join("stats");
    std::fs::create_dir_all(&stats).map_err(|e| Error::io(&stats, e))?;
    let t = header.times.len();
    let g = header.x.len();
    let qs = &header.quantiles;
    let nq = qs.len() as u64;
    write_npy(stats.join("times.npy"), &[t as u64], &header.times)?;
    write_npy(stats.join("x.npy"), &[g as u64], &header.x)?;
    write_npy(stats.join("quantile_levels.npy"), &[nq], qs)?;
    for (name, per_time) in &state.scalars {
        let col = |f: &dyn Fn(&ScalarSummary) -> f64| per_time.iter().map(f).collect::<Vec<f64>>();
        write_npy(
            stats.join(format!("{name}_count.npy")),
            &[t as u64],
            &col(&|s| s.stats().count() as f64),
        )?;
        write_npy(
            stats.join(format!("{name}_mean.npy")),
            &[t as u64],
            &col(&|s| s.stats().mean()),
        )?;
        write_npy(
            stats.join(format!("{name}_var.npy")),
            &[t as u64],
            &col(&|s| s.stats().variance()),
        )?;
        write_npy(
            stats.join(format!("{name}_min.npy")),
            &[t as u64],
            &col(&|s| s.stats().min()),
        )?;
        write_npy(
            stats.join(format!("{name}_max.npy")),
            &[t as u64],
            &col(&|s| s.stats().max()),
        )?;
        let quant: Vec<f64> = per_time
            .iter()
            .flat_map(|s| qs.iter().map(|&q| s.quantile(q).unwrap_or(f64::NAN)))
            .collect();
        write_npy(
            stats.join(format!("{name}_quantiles.npy")),
            &[t as u64, nq],
            &quant,
        )?;
        let (edges, counts) = scalar_histograms(per_time.iter().map(|s| s.sketch()));
        write_npy(
            stats.join(format!("{name}_hist_edges.npy")),
            &[t as u64, SCALAR_BINS as u64 + 1],
            &edges,
        )?;
        write_npy(
            stats.join(format!("{name}_hist_counts.npy")),
            &[t as u64, SCALAR_BINS as u64],
            &counts,
        )?;
    }
    let fh = &state.first_hit;
    write_npy(
        stats.join("first_hit.npy"),
        &[6],
        &[
            fh.stats().count() as f64,
            state.never_hit as f64,
            fh.stats().mean(),
            fh.stats().variance(),
            fh.stats().min(),
            fh.stats().max(),
        ],
    )?;
    let fq: Vec<f64> = qs
        .iter()
        .map(|&q| fh.quantile(q).unwrap_or(f64::NAN))
        .collect();
    write_npy(stats.join("first_hit_quantiles.npy"), &[nq], &fq)?;
    for (name, per_time) in &state.fields {
        let mean: Vec<f64> = per_time.iter().flat_map(|b| b.mean_row()).collect();
        let var: Vec<f64> = per_time.iter().flat_map(|b| b.variance_row()).collect();
        let quant: Vec<f64> = per_time
            .iter()
            .flat_map(|b| qs.iter().flat_map(move |&q| b.quantile_row(q)))
            .collect();
        write_npy(
            stats.join(format!("{name}_mean.npy")),
            &[t as u64, g as u64],
            &mean,
        )?;
        write_npy(
            stats.join(format!("{name}_var.npy")),
            &[t as u64, g as u64],
            &var,
        )?;
        write_npy(
            stats.join(format!("{name}_quantiles.npy")),
            &[t as u64, nq, g as u64],
            &quant,
        )?;
    }
    if plots {
        write_plots(dir, header, state)?;
    }
    Ok(())
}

/// Histograms of a scalar per time over that time's [min, max], filled from the sketches.
fn scalar_histograms<'a>(
    sketches: impl Iterator<Item = &'a QuantileSketch>,
) -> (Vec<f64>, Vec<f64>) {
    let mut edges_all = Vec::new();
    let mut counts_all = Vec::new();
    for s in sketches {
        let (lo, hi) = if s.count() > 0 {
            (s.min(), s.max())
        } else {
            (0.0, 1.0)
        };
        let (lo, hi) = if hi > lo {
            (lo, hi)
        } else {
            (
                lo - 0.5 * lo.abs().max(1e-12),
                hi + 0.5 * hi.abs().max(1e-12),
            )
        };
        let edges: Vec<f64> = (0..=SCALAR_BINS)
            .map(|k| lo + (hi - lo) * k as f64 / SCALAR_BINS as f64)
            .collect();
        let (counts, _, _) = s.histogram(&edges);
        edges_all.extend_from_slice(&edges);
        counts_all.extend(counts.into_iter().map(|c| c as f64));
    }
    (edges_all, counts_all)
}

fn write_plots(dir: &Path, header: &StudyHeader, state: &StudyState) -> Result<()> {
    let plots = dir.join("plots");
    std::fs::create_dir_all(&plots).map_err(|e| Error::io(&plots, e))?;
    let t = header.times.len();
    // Up to four times, evenly spread, for the band plot.
    let shown: Vec<usize> = if t <= 4 {
        (0..t).collect()
    } else {
        (0..4).map(|j| j * (t - 1) / 3).collect()
    };
    let (q_lo, q_hi) = (
        *header.quantiles.first().unwrap_or(&0.05),
        *header.quantiles.last().unwrap_or(&0.95),
    );
    for field in ["rho", "u"] {
        let bands = &state.fields[field];
        let mean: Vec<Vec<f64>> = shown.iter().map(|&k| bands[k].mean_row()).collect();
        let lower: Vec<Vec<f64>> = shown.iter().map(|&k| bands[k].quantile_row(q_lo)).collect();
        let upper: Vec<Vec<f64>> = shown.iter().map(|&k| bands[k].quantile_row(q_hi)).collect();
        let times: Vec<f64> = shown.iter().map(|&k| header.times[k]).collect();
        let reference: Option<Vec<Vec<f64>>> = (field == "rho").then(|| {
            shown
                .iter()
                .map(|&k| state.fields["rho_star"][k].mean_row())
                .collect()
        });
        let has_reference = reference
            .as_ref()
            .is_some_and(|r| r.iter().any(|row| row.iter().any(|v| v.is_finite())));
        let title = format!(
            "{}: mean {field} over {} members",
            header.scene_name, state.completed
        );
        let label = format!("{:.0}%-{:.0}% of members", 100.0 * q_lo, 100.0 * q_hi);
        crate::plot::plot_band(
            &plots.join(format!("{field}_band.png")),
            &crate::plot::BandPlot {
                title: &title,
                y_label: field,
                x: &header.x,
                times: &times,
                mean: &mean,
                lower: &lower,
                upper: &upper,
                band_label: &label,
                reference: if has_reference {
                    reference.as_deref()
                } else {
                    None
                },
            },
        )?;
    }
    let last = t - 1;
    let sketch = state.scalars["max_density"][last].sketch();
    let (edges, counts) = scalar_histograms(std::iter::once(sketch));
    let counts: Vec<u64> = counts.iter().map(|&c| c as u64).collect();
    crate::plot::plot_histogram(
        &plots.join("max_density_hist.png"),
        &format!(
            "{}: max density at t = {}",
            header.scene_name, header.times[last]
        ),
        "max density",
        &edges,
        &counts,
        None,
    )?;
    if state.first_hit.stats().count() > 0 {
        let (edges, counts) = scalar_histograms(std::iter::once(state.first_hit.sketch()));
        let counts: Vec<u64> = counts.iter().map(|&c| c as u64).collect();
        let note = format!("{} members never reached the threshold", state.never_hit);
        crate::plot::plot_histogram(
            &plots.join("first_hit_hist.png"),
            &format!(
                "{}: first time max density reaches the threshold",
                header.scene_name
            ),
            "t",
            &edges,
            &counts,
            Some(&note),
        )?;
    }
    Ok(())
}
