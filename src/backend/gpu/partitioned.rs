//! The partitioned kernel (`shaders/partitioned.wgsl`): few members with huge N. Each trial
//! step's tridiagonal solves are split into segments solved side by side (the SPIKE-style
//! algorithm of `crate::backend::cpu::step::partitioned`), and everything else a trial step does
//! (projection, energy, extrapolation, error norm, step control) into per-segment parts and
//! per-member reductions, one dispatch each. No invocation loops over more than one segment or
//! over one member's segments, which lifts lavapipe's per-invocation loop budget (N = 10^6 runs)
//! and gives a handful of members thousands of invocations.
//!
//! Here: which batches take it ([`choose`]), how the rows are cut ([`Segments`]), its extra
//! buffers' uniform ([`PartsUniform`]), and the fixed sequence of dispatches of one trial step
//! (see the header of `shaders/partitioned.wgsl`).

use bytemuck::{Pod, Zeroable};

use super::attempts::LAVAPIPE_LOOP_LIMIT;
use super::context::GpuContext;
use super::kernel::{SchemeSpec, STEP_WORKGROUP_SIZE};
use crate::backend::error::GpuError;

/// Workgroup size of the per-segment kernels (`@workgroup_size(32)` in partitioned.wgsl):
/// smaller than the step kernel's 64 so that a few hundred segments still make several
/// workgroups (lavapipe runs one workgroup per thread).
pub const SEGMENT_WORKGROUP_SIZE: u32 = 32;

/// Rows per segment the default cut aims at (at least), as the CPU's `SEGMENT_ROWS`: long
/// enough that the two sweeps dominate the per-segment overhead and the reduced system (one
/// invocation per member, serial over the segments) stays small.
pub const SEGMENT_ROWS: usize = 256;

/// At most this many segments per member by default (longer segments beyond): the per-member
/// kernels loop over a member's segments.
pub const MAX_SEGMENTS: usize = 4096;

/// The partitioned kernel is chosen for batches of fewer members than this (one workgroup of
/// the one-invocation-per-member kernel is then not even full) ...
pub const PARTITION_MAX_MEMBERS: usize = STEP_WORKGROUP_SIZE as usize;

/// ... with at least this many particles; and for any batch whose chains exceed lavapipe's
/// loop budget for one invocation per member.
pub const PARTITION_MIN_PARTICLES: usize = 1 << 14;

/// The spike's flush threshold in f32 (the CPU's 1e-140 is below f32's range): far above
/// f32's smallest normal, far below anything that matters. The CPU's f32 partitioned solve's
/// too (defined in `crate::backend::shared::gaps`, with the f64 one).
pub const SPIKE_TINY_F32: f64 = crate::backend::shared::gaps::SPIKE_TINY_F32;

/// Which kernel a solver uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum GpuPartition {
    /// The rule of [`choose`] (`ROUGHLUB_GPU_PARTITION=off` keeps one invocation per member
    /// wherever that runs).
    #[default]
    Auto,
    /// One invocation per member (refused on lavapipe where it exceeds the loop budget).
    Off,
    /// The partitioned kernel with segments of (at least) this many rows.
    SegmentRows(usize),
}

/// How the rows 1..n-1 of a chain are cut: `segments` segments of `seg` rows, the first `rem`
/// with one more (the CPU's `Layout` gives them all to segment 0 instead).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Segments {
    pub segments: u32,
    pub seg: u32,
    pub rem: u32,
}

impl Segments {
    /// Segments of at least `rows_per_segment` rows (one segment if the chain is shorter).
    pub fn new(n: usize, rows_per_segment: usize) -> Segments {
        let rows = n.saturating_sub(1).max(1);
        let p = (rows / rows_per_segment.max(1)).max(1);
        Segments {
            segments: p as u32,
            seg: (rows / p) as u32,
            rem: (rows % p) as u32,
        }
    }

    /// The default cut: [`SEGMENT_ROWS`] rows, or longer so that there are at most
    /// [`MAX_SEGMENTS`] segments.
    pub fn default_for(n: usize) -> Segments {
        let rows = n.saturating_sub(1);
        Segments::new(n, SEGMENT_ROWS.max(rows.div_ceil(MAX_SEGMENTS)))
    }

    /// Segments of at most `max_rows` rows, as few as that allows.
    pub fn at_most(n: usize, max_rows: usize) -> Segments {
        let rows = n.saturating_sub(1).max(1);
        let p = rows.div_ceil(max_rows.max(1)).max(1);
        Segments {
            segments: p as u32,
            seg: (rows / p) as u32,
            rem: (rows % p) as u32,
        }
    }

    /// Rows [first, last) of segment s (`seg_rows` in partitioned.wgsl).
    pub fn rows(&self, s: u32) -> std::ops::Range<u32> {
        let first = 1 + s * self.seg + s.min(self.rem);
        first..first + self.seg + u32::from(s < self.rem)
    }
}

/// `struct Parts` of shaders/partitioned.wgsl (keep in sync).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct PartsUniform {
    pub segments: u32,
    pub seg: u32,
    pub rem: u32,
    pub padding: u32,
}

impl From<Segments> for PartsUniform {
    fn from(s: Segments) -> Self {
        PartsUniform {
            segments: s.segments,
            seg: s.seg,
            rem: s.rem,
            padding: 0,
        }
    }
}

/// Whether a batch of `members` members of N = `n` takes the partitioned kernel, and its cut:
/// as `partition` says, or for [`GpuPartition::Auto`] when there are fewer than
/// [`PARTITION_MAX_MEMBERS`] members and N >= [`PARTITION_MIN_PARTICLES`], or when one
/// invocation per member would exceed the device's loop budget (`sequential_fits` false).
/// `off` (`ROUGHLUB_GPU_PARTITION=off`) keeps one invocation per member wherever it fits.
pub fn choose(
    partition: GpuPartition,
    members: usize,
    n: usize,
    sequential_fits: bool,
    off: bool,
) -> Option<Segments> {
    match partition {
        GpuPartition::Off => None,
        GpuPartition::SegmentRows(r) => Some(Segments::new(n, r)),
        GpuPartition::Auto => {
            let wanted = members < PARTITION_MAX_MEMBERS && n >= PARTITION_MIN_PARTICLES;
            (!sequential_fits || (wanted && !off)).then(|| Segments::default_for(n))
        }
    }
}

/// Loop iterations per row of the per-segment kernels at most: 3 (the solve's two sweeps and
/// the glued bodies), or with the tableau its loops over the R rows per gap and per velocity
/// (as `loops_per_attempt` counts them).
fn loops_per_row(scheme: SchemeSpec) -> u64 {
    let r = u64::from(scheme.rows);
    if scheme.tableau() {
        (2 * (3 * r + r * r + 1)).max(3)
    } else {
        3
    }
}

/// Loop iterations per segment of the per-member kernels at most (the estimates' reduction
/// loops over the R rows per segment; the reduced system makes three passes).
fn loops_per_segment(scheme: SchemeSpec) -> u64 {
    (u64::from(scheme.rows) + 2).max(3)
}

/// Loop iterations of the longest invocation of the partitioned kernel with this cut: a
/// segment's rows, or a member's segments.
fn partitioned_iterations(scheme: SchemeSpec, segments: Segments) -> u64 {
    let per_segment = loops_per_row(scheme) * u64::from(segments.seg + 1) + 8;
    let per_member = loops_per_segment(scheme) * u64::from(segments.segments) + 8;
    per_segment.max(per_member)
}

/// The cut the partitioned kernel runs on this device. Elsewhere than lavapipe `segments`
/// itself. On lavapipe an invocation may not exceed [`LAVAPIPE_LOOP_LIMIT`] loop iterations:
/// where `segments` does and `recut` allows (the default cut, not one the user set), the chain
/// is cut into segments short enough to fit, at most [`MAX_SEGMENTS`] as in the default cut, so
/// that the longest chain is still the one the error names (the default cut's 256 rows and more take 178 loop
/// iterations a row with auto's 8 columns: N = 400 needed 71208); where no cut fits,
/// [`GpuError::LoopLimit`].
pub fn fit_budget(
    ctx: &GpuContext,
    n: usize,
    scheme: SchemeSpec,
    segments: Segments,
    recut: bool,
) -> Result<Segments, GpuError> {
    if !super::attempts::is_lavapipe(ctx)
        || partitioned_iterations(scheme, segments) <= LAVAPIPE_LOOP_LIMIT
    {
        return Ok(segments);
    }
    // The longest segments that fit, and as many of them as fit up to MAX_SEGMENTS.
    let rows = ((LAVAPIPE_LOOP_LIMIT - 8) / loops_per_row(scheme)).saturating_sub(1);
    let count = ((LAVAPIPE_LOOP_LIMIT - 8) / loops_per_segment(scheme)).min(MAX_SEGMENTS as u64);
    if recut && rows > 0 {
        let shorter = Segments::at_most(n, rows as usize);
        if shorter.segments as usize <= MAX_SEGMENTS
            && partitioned_iterations(scheme, shorter) <= LAVAPIPE_LOOP_LIMIT
        {
            return Ok(shorter);
        }
    }
    Err(GpuError::LoopLimit {
        adapter: ctx.description.short(),
        particles: n,
        iterations: partitioned_iterations(scheme, segments),
        limit: LAVAPIPE_LOOP_LIMIT,
        max_particles: rows * count,
    })
}

/// Entry points of the partitioned kernel.
pub mod entry {
    pub const BEGIN: &str = "p_begin";
    pub const POSITIONS: &str = "p_positions";
    pub const SCAN: &str = "p_scan";
    pub const FORWARD: &str = "p_forward";
    pub const INTERFACE: &str = "p_interface";
    pub const SOLVE: &str = "p_solve";
    pub const FINISH: &str = "p_finish";
    pub const PROJECT: &str = "p_project";
    pub const SUBSTEP_END: &str = "p_substep_end";
    pub const EXTRAPOLATE: &str = "p_extrapolate";
    pub const EXTRAPOLATED: &str = "p_extrapolated";
    pub const DECIDE: &str = "p_decide";
    pub const SMALLEST: &str = "p_smallest";
    pub const FAILED: &str = "p_failed";
    pub const ENERGY_PARTS: &str = "p_energy_parts";
    pub const BEGIN_INTERVAL: &str = "p_begin_interval";
    pub const COUNT: &str = "p_count";
    pub const GATHER: &str = "p_gather";
}

/// Over members (one invocation each) or over (segment, member) pairs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Over {
    Members,
    Segments,
}

/// One dispatch of the sequence: entry point and what it runs over.
pub type Dispatch = (&'static str, Over);

/// The dispatches of one trial step (see the header of shaders/partitioned.wgsl): `substeps`
/// rounds of the Euler substep's dispatches (members with fewer substeps idle through the
/// rest), then the extrapolation and decision, then the smallest gap of a failed member.
pub fn attempt_sequence(scheme: SchemeSpec, forcing: bool) -> Vec<Dispatch> {
    use entry::*;
    use Over::{Members as M, Segments as S};
    let mut out = vec![(BEGIN, M)];
    for _ in 0..scheme.substeps() {
        if forcing {
            out.extend([(POSITIONS, S), (SCAN, M)]);
        }
        out.extend([
            (FORWARD, S),
            (INTERFACE, M),
            (SOLVE, S),
            (FINISH, M),
            (PROJECT, S),
            (SUBSTEP_END, M),
        ]);
    }
    if scheme.tableau() {
        out.extend([(EXTRAPOLATE, S), (EXTRAPOLATED, M)]);
        if scheme.extrapolates {
            out.push((PROJECT, S));
        }
        out.push((DECIDE, M));
    }
    out.extend([(SMALLEST, S), (FAILED, M)]);
    out
}

/// The dispatches that begin an output interval.
pub const BEGIN_SEQUENCE: [Dispatch; 2] = [
    (entry::ENERGY_PARTS, Over::Segments),
    (entry::BEGIN_INTERVAL, Over::Members),
];

/// Every entry point the kernel for `scheme` has.
pub fn entry_points(scheme: SchemeSpec, forcing: bool) -> Vec<&'static str> {
    let mut names: Vec<&'static str> = attempt_sequence(scheme, forcing)
        .into_iter()
        .chain(BEGIN_SEQUENCE)
        .map(|(e, _)| e)
        .collect();
    names.extend([entry::COUNT, entry::GATHER]);
    names.sort_unstable();
    names.dedup();
    names
}

/// Trial steps per submit: about 2^22 row-substeps of work per submit (so that a submit of a
/// huge chain stays short and one of a small chain still carries many steps), 1 to 64.
pub fn attempts_per_submit(n: usize, members: usize, scheme: SchemeSpec) -> u32 {
    let work = (n * members) as u64 * u64::from(scheme.substeps());
    ((1u64 << 22) / work.max(1)).clamp(1, 64) as u32
}

/// Byte size of the WGSL struct `name` in `module` (the GPU-only structs of the partitioned
/// kernel, which the host only allocates).
pub fn struct_size(module: &naga::Module, name: &str) -> Option<u64> {
    let mut layouter = naga::proc::Layouter::default();
    layouter.update(module.to_ctx()).ok()?;
    module
        .types
        .iter()
        .find(|(_, ty)| ty.name.as_deref() == Some(name))
        .map(|(handle, _)| u64::from(layouter[handle].size))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The cut covers rows 1..n-1 once, in order, with segments of seg or seg + 1 rows.
    #[test]
    fn segments_cover_every_row_once() {
        for (n, r) in [
            (2, 256),
            (100, 7),
            (1001, 256),
            (40_000, 256),
            (1_000_000, 256),
        ] {
            let s = Segments::new(n, r);
            let mut next = 1;
            for k in 0..s.segments {
                let rows = s.rows(k);
                assert_eq!(rows.start, next, "n {n}, segment {k}");
                assert!(rows.len() as u32 == s.seg || rows.len() as u32 == s.seg + 1);
                assert!(rows.len() >= r.min(n - 1), "n {n}: {s:?}");
                next = rows.end;
            }
            assert_eq!(next as usize, n, "n {n}: {s:?}");
        }
        // Segments of at most r rows, as few as that allows.
        for (n, r) in [(2, 5), (400, 367), (400, 399), (401, 100), (1_000_000, 367)] {
            let s = Segments::at_most(n, r);
            let rows = n - 1;
            assert_eq!(s.segments as usize, rows.div_ceil(r), "n {n}, r {r}: {s:?}");
            let longest = s.seg + u32::from(s.rem > 0);
            assert!(longest as usize <= r, "n {n}, r {r}: {s:?}");
            assert_eq!(
                s.segments * s.seg + s.rem,
                rows as u32,
                "n {n}, r {r}: {s:?}"
            );
            let mut next = 1;
            for k in 0..s.segments {
                assert_eq!(s.rows(k).start, next, "n {n}, r {r}, segment {k}");
                next = s.rows(k).end;
            }
            assert_eq!(next as usize, n, "n {n}, r {r}: {s:?}");
        }
        assert_eq!(Segments::default_for(1_000_001).segments, 3906);
        assert!(Segments::default_for(100_000_001).segments as usize <= MAX_SEGMENTS);
    }
}
