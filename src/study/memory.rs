//! The memory a study will need, estimated before anything is solved: a study whose estimate is
//! above the limit (half the machine's memory) is refused with the settings that drive it,
//! unless `--allow-large`, so that no study dies by the kernel's OOM killer without a message.
//!
//! The estimate follows what the study holds at once: the per-time statistics of the detailed
//! points (the run's total, its field bands, and one chunk's scalar summaries), the responses
//! of every point, and one chunk's members (solver state, recorded observables, kept arrays) or,
//! once they are solved, the rows the report writes (whichever is more).

use super::files::StudyHeader;
use super::SCALARS;
use crate::error::{Error, Result};
use crate::scene::EnsembleSpec;
use crate::stats::FieldBand;

/// Bytes of one scalar summary (moments and a DDSketch) of `members` values: its fixed part and
/// a dense bucket store that spans the occupied buckets, up to a few hundred (4 KiB) with many
/// members. At 4 KiB whatever the members, a random design of 100000 points of one member was
/// estimated at 3.3 GB where it held 0.23 GB (about 1 KiB a point).
fn summary_bytes(members: u64) -> u64 {
    256 + 8 * (8 * members).min(480)
}

/// Bytes of one point's response summaries (four scalar summaries, map overhead).
fn point_response_bytes(members: u64) -> u64 {
    4 * summary_bytes(members) + 256
}
/// Bytes per particle of one member being solved: gaps, velocities, tridiagonal work arrays and
/// the extrapolation tableau (order 8: its rows and two substep states), in f64.
const SOLVER_BYTES_PER_PARTICLE: u64 = 64 * 8;
/// Bytes of one members.csv row held for a chunk.
const ROW_BYTES: u64 = 512;

/// What a study will hold in memory, part by part.
#[derive(Debug, Clone)]
pub struct MemoryEstimate {
    pub bytes: u64,
    pub detailed_bytes: u64,
    pub responses_bytes: u64,
    pub chunk_bytes: u64,
    /// The band rows the report holds while it writes them (after the chunks: the estimate
    /// counts the larger of the two).
    pub report_bytes: u64,
}

/// The estimate for the study `header` describes, with chains of up to `particles` particles
/// and `solvers` batches of a chunk in flight at once (2 with the order-1 error estimate's
/// companion).
pub fn estimate(
    header: &StudyHeader,
    spec: &EnsembleSpec,
    particles: usize,
    solvers: u64,
) -> MemoryEstimate {
    let t = header.times.len() as u64;
    let g = header.x.len() as u64;
    let points = header.points.len().max(1) as u64;
    let detailed = header.detailed_count();
    let per_point = header.members_per_point.max(1);
    let chunk = spec.chunk as u64;
    // A field band: per grid point its moments, and its members' slots as held (u32 each)
    // while they are few (`FieldBand::max_held_rows_for`), its bins + 2 slot counts (u32) beyond.
    let held = if per_point <= FieldBand::max_held_rows_for(header.bins) as u64 {
        per_point
    } else {
        header.bins as u64 + 2
    };
    let band = g * (64 + held * 4);
    let scalars = SCALARS.len() as u64 * t * summary_bytes(per_point);
    let per_detailed = header.band_fields.len() as u64 * t * band + scalars;
    // The run's total, and the chunk's own scalar statistics of the detailed points it touches
    // (its field rows go straight into the total's bands).
    let touched = detailed.min(chunk.div_ceil(per_point) + 1);
    let detailed_bytes = detailed * per_detailed + touched * scalars;
    let responses_bytes = 2 * points * point_response_bytes(per_point);
    let n = particles as u64;
    let recorded = (header.band_fields.len() as u64 * g + SCALARS.len() as u64) * 8 * t;
    // Kept members' gaps, velocities and rho, twice: as snapshots, and as the arrays written
    // (without the second copy 12-33 % under the measured peak).
    let kept = if spec.store_members {
        2 * (2 * n + g) * 8 * t
    } else {
        0
    };
    // Snapshots carry rho on the grid (the peak centre), and the solver its state.
    let chunk_bytes =
        chunk * (solvers * n * SOLVER_BYTES_PER_PARTICLE + recorded + kept + g * 8 + ROW_BYTES);
    // After the last chunk, the report holds band rows for every detailed point while it
    // writes them.
    let (_, report_bytes) = super::report::band_rows_held(header, detailed);
    MemoryEstimate {
        bytes: detailed_bytes + responses_bytes + chunk_bytes.max(report_bytes),
        detailed_bytes,
        responses_bytes,
        chunk_bytes,
        report_bytes,
    }
}

/// The bytes a study (or shard) will write, estimated before it starts: its members' arrays
/// (`store_members`), members.csv, the detailed points' statistics, as .npy in stats/ and in
/// partial.state, and every point's responses (plots besides, a few MB).
pub fn disk_bytes(
    header: &StudyHeader,
    spec: &EnsembleSpec,
    particles: usize,
    memory: &MemoryEstimate,
) -> u64 {
    let t = header.times.len() as u64;
    let g = header.x.len() as u64;
    let n = particles as u64;
    let members = header.member_range.1 - header.member_range.0;
    // gaps [T, N], velocities [T, N-1], rho [T, G] and the error estimate [T] of each member.
    let kept = if spec.store_members {
        (2 * n + g) * 8 * t
    } else {
        0
    };
    // Each field's mean, variance and quantiles at every output time and grid point.
    let stats = header.detailed_count()
        * header.band_fields.len() as u64
        * t
        * g
        * (2 + header.quantiles.len() as u64)
        * 8;
    // The points' responses, once (partial.state, stats/ and points.csv hold them), are half
    // the memory's two copies.
    members * (kept + ROW_BYTES) + stats + memory.detailed_bytes + memory.responses_bytes / 2
}

/// Refuses a study whose outputs would exceed the run's size limit, naming what drives them.
pub fn check_disk(bytes: u64, header: &StudyHeader, spec: &EnsembleSpec) -> Result<()> {
    let limit = crate::run::OUTPUT_SIZE_LIMIT;
    if bytes <= limit {
        return Ok(());
    }
    let gb = |b: u64| b as f64 / 1e9;
    Err(Error::invalid(
        "ensemble (disk)",
        format!("{:.1} GB", gb(bytes)),
        format!(
            "the study would write about {:.1} GB before anything else: {} members{} over {} output times, and the statistics of {} detailed points",
            gb(bytes),
            header.member_range.1 - header.member_range.0,
            if spec.store_members {
                " with their arrays kept (store_members = true)"
            } else {
                ""
            },
            header.times.len(),
            header.detailed_count(),
        ),
        format!(
            "at most {:.1} GB: store_members = false, fewer members or outputs, fewer ensemble.detailed_points, a coarser [output] grid, shards (--shard) on several disks, or --allow-large",
            gb(limit)
        ),
    ))
}

/// The machine's memory (MemTotal of /proc/meminfo), where it can be read.
pub fn machine_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// The limit a study's estimate is held to: half the machine's memory (16 GB where it cannot be
/// read).
pub fn memory_limit() -> u64 {
    machine_memory().map_or(16_000_000_000, |m| m / 2)
}

/// Refuses a study whose estimate is above `limit`, naming the settings that drive it.
pub fn check(
    estimate: &MemoryEstimate,
    header: &StudyHeader,
    spec: &EnsembleSpec,
    limit: u64,
) -> Result<()> {
    if estimate.bytes <= limit {
        return Ok(());
    }
    let gb = |b: u64| b as f64 / 1e9;
    Err(Error::invalid(
        "ensemble (memory)",
        format!("{:.1} GB", gb(estimate.bytes)),
        format!(
            "the study would hold about {:.1} GB in memory: {:.1} GB of per-time statistics for {} detailed points ({} output times x grid {} x {} bins x fields [{}]), {:.1} GB of responses for {} sweep points, and the larger of {:.1} GB for a chunk of {} members and {:.1} GB of band rows while the report writes them",
            gb(estimate.bytes),
            gb(estimate.detailed_bytes),
            header.detailed_count(),
            header.times.len(),
            header.x.len(),
            header.bins,
            header.band_fields.join(", "),
            gb(estimate.responses_bytes),
            header.points.len().max(1),
            gb(estimate.chunk_bytes),
            spec.chunk,
            gb(estimate.report_bytes),
        ),
        format!(
            "at most {:.1} GB (half this machine's memory): fewer sweep points (the responses), fewer ensemble.detailed_points, fewer [output] fields, a coarser [output] grid or ensemble.bins, fewer outputs, a smaller ensemble.chunk, shards (--shard), or --allow-large",
            gb(limit)
        ),
    ))
}
