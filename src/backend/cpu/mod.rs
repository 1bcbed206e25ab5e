//! The CPU reference backend: members packed into blocks of L lanes (interleaved like the GPU
//! batch, so the Thomas sweeps of L members run side by side in SIMD registers), rayon across
//! blocks, each lane with its own time, step size and status. It computes in f64 or in f32
//! ([`real::Real`]; the f32 path is the twin of the GPU's f32 kernel).

mod block;

pub use roughlub_kernels::{real, step, SimdLevel};

use rayon::prelude::*;

use crate::backend::report::error_estimate_method;
use crate::backend::{BatchSolver, MemberReport, OutputStatus, Precision, Progress};
use crate::error::Result;
use crate::model::chain::Chain;
use crate::model::observables::{grid_points, Snapshot};
use crate::model::params::{MemberParams, Stepping};
use crate::model::plan::Plan;
use block::Block;
use roughlub_kernels::BlockKernels;

/// The name of the instruction set the CPU step uses here ("avx512", "avx2+fma" or "portable")
/// at most `cap` (`ROUGHLUB_CPU_SIMD`, [`Plan::overrides`]), for the manifest.
pub fn simd_level(cap: Option<SimdLevel>) -> &'static str {
    SimdLevel::capped(cap).name()
}

/// Blocks as wide as the batch allows: 16 f64 lanes (four AVX2 registers) keep several
/// independent sweeps in flight per core (the forward sweep's divisions have a long latency);
/// f32 lanes are half as wide, so its widest blocks have 32 lanes, again four registers. A lane's
/// result does not depend on its block, so the width changes speed only.
enum Blocks {
    Single(Vec<Block<f64, 1>>),
    Eight(Vec<Block<f64, 8>>),
    Sixteen(Vec<Block<f64, 16>>),
    SingleF32(Vec<Block<f32, 1>>),
    EightF32(Vec<Block<f32, 8>>),
    ThirtyTwoF32(Vec<Block<f32, 32>>),
}

/// `$body` with `$bs` bound to the blocks, whatever their type and width.
macro_rules! with_blocks {
    ($blocks:expr, $bs:ident => $body:expr) => {
        match $blocks {
            Blocks::Single($bs) => $body,
            Blocks::Eight($bs) => $body,
            Blocks::Sixteen($bs) => $body,
            Blocks::SingleF32($bs) => $body,
            Blocks::EightF32($bs) => $body,
            Blocks::ThirtyTwoF32($bs) => $body,
        }
    };
}

/// The CPU backend: a batch of members sharing N, each with its own chain and parameters.
pub struct CpuSolver {
    plan: Plan,
    blocks: Blocks,
    grid_x: Vec<f64>,
    time_index: usize,
}

fn build_blocks<T: BlockKernels<L>, const L: usize>(
    plan: &Plan,
    chains: &[Chain],
    dt0: f64,
) -> Vec<Block<T, L>> {
    let b = plan.members.len();
    (0..b.div_ceil(L))
        .map(|k| {
            let members: [Option<usize>; L] = std::array::from_fn(|l| {
                let m = k * L + l;
                (m < b).then_some(m)
            });
            // Padding lanes repeat the block's first member and never step.
            let pick = |l: usize| members[l].unwrap_or(k * L);
            let chain_refs: [&Chain; L] = std::array::from_fn(|l| &chains[pick(l)]);
            let params: [MemberParams; L] = std::array::from_fn(|l| plan.members[pick(l)]);
            Block::new(plan, &chain_refs, members, params, dt0)
        })
        .collect()
}

impl CpuSolver {
    /// `chains[m]` is member m's initial chain (all with the plan's N and eps); computes in f64.
    pub fn new(plan: Plan, chains: Vec<Chain>) -> CpuSolver {
        CpuSolver::with_precision(plan, chains, Precision::F64)
    }

    /// As [`CpuSolver::new`], computing in `precision` (f32: the twin of the GPU's f32 kernel;
    /// outputs are f64 either way).
    pub fn with_precision(plan: Plan, chains: Vec<Chain>, precision: Precision) -> CpuSolver {
        assert_eq!(chains.len(), plan.members.len(), "one chain per member");
        let dt0 = match plan.stepping {
            Stepping::Fixed { dt, .. } => dt,
            Stepping::Adaptive { dt_initial, .. } => dt_initial,
        };
        let b = plan.members.len();
        // The widest blocks only when there are enough of them for every thread: a block is
        // one thread's work, and on 2 threads 16 f64 members as two blocks of 8 took 0.23 s
        // against 0.38 s as one block of 16 (N = 1000, 5000 steps; f32 32 members: 0.43 s
        // against 0.45 s), while 32 and 64 members gained from the wide blocks (f64 0.38 s
        // against 0.45 s; f32 64 members 0.46 s against 0.82 s). docs/performance.md.
        let threads = rayon::current_num_threads();
        let blocks = match precision {
            Precision::F64 if b >= 16 * threads => {
                Blocks::Sixteen(build_blocks(&plan, &chains, dt0))
            }
            Precision::F64 if b >= 8 => Blocks::Eight(build_blocks(&plan, &chains, dt0)),
            Precision::F64 => Blocks::Single(build_blocks(&plan, &chains, dt0)),
            Precision::F32 if b >= 32 * threads => {
                Blocks::ThirtyTwoF32(build_blocks(&plan, &chains, dt0))
            }
            Precision::F32 if b >= 8 => Blocks::EightF32(build_blocks(&plan, &chains, dt0)),
            Precision::F32 => Blocks::SingleF32(build_blocks(&plan, &chains, dt0)),
        };
        let grid_x = grid_points(plan.grid);
        CpuSolver {
            plan,
            blocks,
            grid_x,
            time_index: 0,
        }
    }

    /// Advances to the next output time and returns every member's snapshot there, in member
    /// order. The first call returns the initial state. `None` after the last output time.
    fn advance_to_next_output(&mut self, progress: Progress) -> Option<Vec<Snapshot>> {
        let k = self.time_index;
        let t_end = *self.plan.output_times.get(k)?;
        let t_start = if k == 0 {
            0.0
        } else {
            self.plan.output_times[k - 1]
        };
        self.time_index += 1;
        let plan = &self.plan;
        let grid = &self.grid_x;
        let mut pairs: Vec<(usize, Snapshot)> = with_blocks!(&mut self.blocks, bs => {
            advance_all(bs, plan, grid, t_start, t_end, progress)
        });
        pairs.sort_by_key(|(m, _)| *m);
        Some(pairs.into_iter().map(|(_, s)| s).collect())
    }

    fn member_reports(&self) -> Vec<MemberReport> {
        let dt_min = self.plan.stepping.dt_min();
        let mut r: Vec<MemberReport> = with_blocks!(&self.blocks, bs => bs
            .iter()
            .flat_map(|b| b.reports(&self.plan, dt_min))
            .collect());
        r.sort_by_key(|m| m.index);
        r
    }
}

fn advance_all<T: BlockKernels<L>, const L: usize>(
    blocks: &mut [Block<T, L>],
    plan: &Plan,
    grid: &[f64],
    t_start: f64,
    t_end: f64,
    progress: Progress,
) -> Vec<(usize, Snapshot)> {
    blocks
        .par_iter_mut()
        .flat_map_iter(|b| {
            if t_end > t_start {
                b.advance(plan, t_start, t_end);
            }
            b.record_error_estimates();
            progress(b.lanes.iter().filter(|l| l.member.is_some()).count() as u64);
            b.snapshot(plan, &plan.members, grid)
        })
        .collect()
}

impl BatchSolver for CpuSolver {
    fn next_output(&mut self, progress: Progress) -> Result<Option<Vec<Snapshot>>> {
        Ok(self.advance_to_next_output(progress))
    }

    fn reports(&self) -> Vec<MemberReport> {
        self.member_reports()
    }

    fn output_status(&self) -> Vec<OutputStatus> {
        let has_estimates = error_estimate_method(self.plan.order, self.plan.stepping).is_some();
        let mut status: Vec<(usize, OutputStatus)> = with_blocks!(&self.blocks, bs => bs
            .iter()
            .flat_map(|b| b.output_status(has_estimates))
            .collect());
        status.sort_by_key(|s| s.0);
        status.into_iter().map(|s| s.1).collect()
    }

    fn plan(&self) -> &Plan {
        &self.plan
    }

    fn grid(&self) -> &[f64] {
        &self.grid_x
    }
}
