//! The GPU backend: the batch advanced by the generated WGSL kernel (`shaders/step.wgsl`, the
//! twin of `crate::backend::cpu::step`, `Block::{error_norm, extrapolate}` in
//! `crate::backend::cpu` and `crate::backend::shared::control`), state kept on the GPU between
//! output times.
//!
//! Every scheme of the CPU backend runs here: orders 1 and 2, fixed and adaptive steps (each
//! member its own dt), rejection and retry of a step that closes or halves a gap, per-member
//! failure status without stopping the others, clusters, repulsion, forcing; f64 (on adapters
//! with SHADER_F64) or f32.
//!
//! Layout: element i of member b sits at `i·B + b` (B members). Per output interval the host
//! writes the interval into the uniform config, then submits command buffers of
//! `begin_interval` (first submit only) and `advance` dispatches (up to [`ATTEMPTS_PER_SUBMIT`]
//! trial steps per member per submit), each of which lets every running member try up to
//! [`MAX_ATTEMPTS_PER_DISPATCH`] steps in a loop of its own invocation (fewer on lavapipe, see
//! `attempts::attempts_per_dispatch`): many steps per dispatch and per submit. After each submit the host
//! reads back one u32, the number of members still running; when it is 0, `gather` copies each
//! member's current state into the read-back buffers, which are read once (readback only at
//! output times).
//!
//! Few members with huge N (and any N beyond lavapipe's loop budget) take the partitioned kernel
//! instead (`shaders/partitioned.wgsl`, see `super::partitioned`): the same state, controls and
//! read-backs, but each trial step is a fixed sequence of dispatches over (segment, member) pairs
//! and over members, `attempts_per_submit` trial steps per submit, then a count of the members
//! still running.
//!
//! Over 700 lines on purpose: one `GpuSolver` holds the buffers, pipelines and per-interval
//! dispatch sequence of one batch, and the order of its dispatches and readbacks is what the
//! tests against the CPU pin; the kernel's generation (`kernel.rs`), the buffers (`buffers.rs`),
//! the dispatch budget (`attempts.rs`) and the partitioned kernel (`partitioned.rs`) are apart.

use super::attempts::{attempts_per_dispatch, check_loop_budget, dispatches_per_submit};
pub use super::attempts::{ATTEMPTS_PER_SUBMIT, LAVAPIPE_LOOP_LIMIT, MAX_ATTEMPTS_PER_DISPATCH};
use super::buffers::PartsData;
use super::buffers::{BoundBuffers, BufferSizes, InitialData, StepBuffers};
use super::context::GpuContext;
use super::kernel::generate_partitioned_wgsl;
use super::kernel::{
    generate_step_wgsl, GammaSpec, KernelSpec, SchemeSpec, ADVANCE_ENTRY, BEGIN_ENTRY,
    GATHER_ENTRY, STEP_WORKGROUP_SIZE,
};
pub use super::partitioned::GpuPartition;
use super::partitioned::{
    attempt_sequence, attempts_per_submit, choose, entry_points, fit_budget, struct_size, Dispatch,
    Over, Segments, BEGIN_SEQUENCE, SEGMENT_WORKGROUP_SIZE,
};
use super::wgsl_types::{
    config_bytes, control_size, controls_from_bytes, reals_from_bytes, ConfigF64, ControlF64,
};
use crate::backend::error::GpuError;
pub use crate::backend::report::GpuStats;
use crate::backend::report::{
    error_estimate_method, Failure, FailureRecord, MemberReport, MemberStatus,
};
use crate::backend::shared::control::Rules;
use crate::backend::{BatchSolver, Precision, Progress};
use crate::model::chain::Chain;
use crate::model::observables::{grid_points, observe, set_peak_centres, Snapshot};
use crate::model::params::Stepping;
use crate::model::plan::{Plan, Power};

/// The compute pipelines of the kernel's entry points.
struct StepPipelines {
    begin: wgpu::ComputePipeline,
    advance: wgpu::ComputePipeline,
    gather: wgpu::ComputePipeline,
}

impl StepPipelines {
    fn build(
        ctx: &GpuContext,
        source: &str,
        layout: &wgpu::PipelineLayout,
    ) -> Result<StepPipelines, GpuError> {
        let pipeline = |entry: &str| ctx.compute_pipeline("step.wgsl", source, entry, Some(layout));
        Ok(StepPipelines {
            begin: pipeline(BEGIN_ENTRY)?,
            advance: pipeline(ADVANCE_ENTRY)?,
            gather: pipeline(GATHER_ENTRY)?,
        })
    }
}

/// The partitioned kernel's pipelines and its sequence of dispatches per trial step.
struct PartKernel {
    segments: Segments,
    pipelines: std::collections::HashMap<&'static str, wgpu::ComputePipeline>,
    attempt: Vec<Dispatch>,
    attempts_per_submit: u32,
}

/// Which kernel runs the batch.
enum Kernel {
    /// One invocation per member (shaders/step.wgsl).
    Sequential(StepPipelines),
    /// Segments side by side (shaders/partitioned.wgsl).
    Partitioned(PartKernel),
}

/// What [`GpuSolver::check`] found: the kernel's scheme, and how it runs the batch.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct KernelChoice {
    pub scheme: SchemeSpec,
    /// Trial steps per member per `advance` dispatch (one invocation per member).
    pub max_attempts: u32,
    /// The partitioned kernel's cut, or None for one invocation per member.
    pub segments: Option<Segments>,
}

pub struct GpuSolver<'a> {
    ctx: &'a GpuContext,
    plan: Plan,
    precision: Precision,
    /// Per member (f64, for the observables).
    dstar: Vec<Option<Vec<f64>>>,
    bonded: Vec<Option<Vec<bool>>>,
    grid_x: Vec<f64>,
    time_index: usize,
    max_attempts: u32,
    sizes: BufferSizes,
    buffers: StepBuffers,
    group: wgpu::BindGroup,
    kernel: Kernel,
    last_controls: Vec<ControlF64>,
    /// Each member's `error_sum` at each output time so far.
    error_estimates: Vec<Vec<f64>>,
    stats: GpuStats,
}

fn invalid(message: String) -> GpuError {
    GpuError::Validation {
        label: "GpuSolver::new".to_string(),
        message,
    }
}

/// The time scheme the kernel compiles for `plan`.
fn scheme_of(plan: &Plan) -> SchemeSpec {
    SchemeSpec {
        exact_jacobian: plan.exact_jacobian(),
        ..SchemeSpec::of(
            plan.order,
            matches!(plan.stepping, Stepping::Adaptive { .. }),
        )
        .with_sequence(plan.sequence)
    }
}

/// What the kernel for `plan` contains. A uniform integer gamma becomes a fixed chain of
/// multiplications; anything else is read per member (the kernel then follows `Power::of` per
/// member).
fn kernel_spec(plan: &Plan, precision: Precision, scheme: SchemeSpec) -> KernelSpec {
    let repulsion = plan.repulsion.then(|| {
        let g0 = plan.members[0].gamma;
        let uniform = plan.members.iter().all(|p| p.gamma == g0);
        match (uniform, Power::of(g0)) {
            (true, Power::Integer(k)) => GammaSpec::Integer(k),
            _ => GammaSpec::PerMember,
        }
    });
    KernelSpec {
        precision,
        repulsion,
        clusters: plan.clusters,
        forcing: plan
            .forcing
            .as_ref()
            .map(|f| (f.expr.clone(), f.rule.nodes.clone(), f.rule.weights.clone())),
        scheme,
    }
}

/// Fails unless there is one chain per member, each of the plan's size and with d* when the
/// plan has repulsion.
fn check_chains(plan: &Plan, chains: &[Chain]) -> Result<(), GpuError> {
    let bsz = plan.members.len();
    let n = plan.particles;
    if chains.len() != bsz {
        return Err(invalid(format!(
            "{bsz} members and {} chains: need one chain per member",
            chains.len()
        )));
    }
    for (m, c) in chains.iter().enumerate() {
        if c.gaps.len() != n || c.velocities.len() != n - 1 {
            return Err(invalid(format!(
                "member {m}: chain with {} gaps and {} velocities, the plan has N = {n}",
                c.gaps.len(),
                c.velocities.len()
            )));
        }
        if plan.repulsion && c.dstar.as_ref().is_none_or(|d| d.len() != n) {
            return Err(invalid(format!(
                "member {m}: the plan has repulsion but the chain has no d* of length {n}"
            )));
        }
    }
    if let Some(f) = &plan.forcing {
        let k = f.expr.symbolic_count();
        if f.params.len() != k * bsz {
            return Err(invalid(format!(
                "the forcing reads {k} parameter(s) per member: need {} values for {bsz} members, got {}",
                k * bsz,
                f.params.len()
            )));
        }
    }
    Ok(())
}

/// Each member's d* (repulsion only).
fn member_dstar(plan: &Plan, chains: &[Chain]) -> Vec<Option<Vec<f64>>> {
    chains
        .iter()
        .map(|c| {
            if plan.repulsion {
                c.dstar.clone()
            } else {
                None
            }
        })
        .collect()
}

/// Each member's bonded flags (clusters only; a chain without them has no bonds).
fn member_bonded(plan: &Plan, chains: &[Chain]) -> Vec<Option<Vec<bool>>> {
    chains
        .iter()
        .map(|c| {
            plan.clusters.then(|| {
                c.bonded
                    .clone()
                    .unwrap_or_else(|| vec![false; plan.particles])
            })
        })
        .collect()
}

/// A member's control before its first step (as `StepControl::new`).
fn initial_control(plan: &Plan, precision: Precision) -> ControlF64 {
    let dt = match plan.stepping {
        Stepping::Fixed { dt, .. } => dt,
        Stepping::Adaptive { dt_initial, .. } => dt_initial,
    };
    ControlF64 {
        t: 0.0,
        dt,
        failure_time: 0.0,
        failure_detail: 0.0,
        // Negative: `begin_interval` computes the initial energy on the GPU (E >= 0 otherwise).
        energy: -1.0,
        error_sum: 0.0,
        h_previous: 0.0,
        err_previous: 0.0,
        t_low: 0.0,
        window_t: 0.0,
        accepted: 0,
        rejected: 0,
        regular_steps: 0,
        regular: 1,
        failure: 0,
        parity: 0,
        failure_index: 0,
        order: u32::from(plan.initial_column(precision == Precision::F32)),
        after_rejection: 0,
        window_attempts: 0,
    }
}

impl<'a> GpuSolver<'a> {
    /// Whether this context can run `plan` at `precision` (f64 support, sizes, and on lavapipe
    /// the loop budget), without building anything: the selection policy asks this before
    /// choosing the GPU. Returns the kernel the solver would use ([`GpuPartition::Auto`]).
    pub fn check(
        ctx: &GpuContext,
        plan: &Plan,
        precision: Precision,
    ) -> Result<KernelChoice, GpuError> {
        Self::check_with(ctx, plan, precision, GpuPartition::Auto)
    }

    /// [`GpuSolver::check`] with the kernel chosen as `partition` says.
    pub fn check_with(
        ctx: &GpuContext,
        plan: &Plan,
        precision: Precision,
        partition: GpuPartition,
    ) -> Result<KernelChoice, GpuError> {
        if precision == Precision::F64 && !ctx.f64 {
            return Err(GpuError::NoF64 {
                adapter: ctx.description.short(),
            });
        }
        let bsz = plan.members.len();
        let n = plan.particles;
        if bsz == 0 || n < 2 {
            return Err(invalid(format!(
                "{bsz} members, N = {n}: need members >= 1, N >= 2"
            )));
        }
        if let GpuPartition::SegmentRows(0) = partition {
            return Err(invalid("segments of 0 rows".to_string()));
        }
        // The kernel indexes its buffers with u32, and its buffer sets hold N·B reals each.
        let scheme = scheme_of(plan);
        let sets = BufferSizes::of(n, bsz, scheme, precision).sets;
        if n as u64 * bsz as u64 > u32::MAX as u64 / sets {
            return Err(invalid(format!(
                "N·B = {} elements: the kernel indexes buffers with u32 (at most {} with {sets} buffer sets); use fewer members per run",
                n as u64 * bsz as u64,
                u32::MAX as u64 / sets
            )));
        }
        BufferSizes::of(n, bsz, scheme, precision).check(ctx)?;
        let overrides = &plan.overrides;
        let max_attempts =
            attempts_per_dispatch(ctx, n, scheme, overrides.gpu_attempts_per_dispatch);
        let sequential = check_loop_budget(ctx, n, scheme, max_attempts);
        let segments = choose(
            partition,
            bsz,
            n,
            sequential.is_ok(),
            overrides.gpu_partition_off,
        );
        let segments = match segments {
            Some(s) => {
                let recut = !matches!(partition, GpuPartition::SegmentRows(_));
                Some(fit_budget(ctx, n, scheme, s, recut)?)
            }
            None => {
                sequential?;
                None
            }
        };
        Ok(KernelChoice {
            scheme,
            max_attempts,
            segments,
        })
    }

    /// Uploads the batch (`chains[m]` is member m's initial chain) and builds the kernels.
    pub fn new(
        ctx: &'a GpuContext,
        plan: Plan,
        chains: Vec<Chain>,
        precision: Precision,
    ) -> Result<GpuSolver<'a>, GpuError> {
        Self::new_with(ctx, plan, chains, precision, GpuPartition::Auto)
    }

    /// [`GpuSolver::new`] with the kernel chosen as `partition` says.
    pub fn new_with(
        ctx: &'a GpuContext,
        plan: Plan,
        chains: Vec<Chain>,
        precision: Precision,
        partition: GpuPartition,
    ) -> Result<GpuSolver<'a>, GpuError> {
        let choice = Self::check_with(ctx, &plan, precision, partition)?;
        let (scheme, max_attempts) = (choice.scheme, choice.max_attempts);
        check_chains(&plan, &chains)?;
        let spec = kernel_spec(&plan, precision, scheme);
        let dstar = member_dstar(&plan, &chains);
        let bonded = member_bonded(&plan, &chains);
        let sizes = BufferSizes::of(plan.particles, plan.members.len(), scheme, precision);
        let control = initial_control(&plan, precision);
        let mut initial =
            InitialData::new(&plan, &chains, &dstar, &bonded, control, sizes, precision);
        let source = match choice.segments {
            None => generate_step_wgsl(&spec),
            Some(segments) => {
                let source = generate_partitioned_wgsl(&spec);
                let module = super::validate_wgsl("partitioned.wgsl", &source)?;
                let size = |name: &str| {
                    struct_size(&module, name)
                        .ok_or_else(|| invalid(format!("no struct {name} in the kernel")))
                };
                initial.parts = Some(PartsData::new(
                    segments,
                    plan.members.len(),
                    size("PState")?,
                    size("Seg")?,
                    &bonded,
                    plan.clusters,
                ));
                source
            }
        };
        let bound = BoundBuffers::create(ctx, &initial)?;
        let mut stats = GpuStats {
            bytes_written: bound.bytes_written,
            attempts_per_dispatch: max_attempts as u64,
            dispatches_per_submit: dispatches_per_submit(max_attempts) as u64,
            ..GpuStats::default()
        };
        let kernel = match choice.segments {
            None => Kernel::Sequential(StepPipelines::build(ctx, &source, &bound.pipeline_layout)?),
            Some(segments) => {
                let forcing = spec.forcing.is_some();
                let mut pipelines = std::collections::HashMap::new();
                for entry in entry_points(scheme, forcing) {
                    let pipeline = ctx.compute_pipeline(
                        "partitioned.wgsl",
                        &source,
                        entry,
                        Some(&bound.pipeline_layout),
                    )?;
                    pipelines.insert(entry, pipeline);
                }
                let attempts = attempts_per_submit(plan.particles, plan.members.len(), scheme);
                stats.attempts_per_dispatch = 1;
                stats.dispatches_per_submit = attempts as u64;
                stats.segments = segments.segments as u64;
                Kernel::Partitioned(PartKernel {
                    segments,
                    pipelines,
                    attempt: attempt_sequence(scheme, forcing),
                    attempts_per_submit: attempts,
                })
            }
        };
        Ok(GpuSolver {
            ctx,
            grid_x: grid_points(plan.grid),
            last_controls: vec![control; plan.members.len()],
            error_estimates: vec![Vec::new(); plan.members.len()],
            plan,
            precision,
            dstar,
            bonded,
            time_index: 0,
            max_attempts,
            sizes,
            buffers: bound.buffers,
            group: bound.group,
            kernel,
            stats,
        })
    }

    pub fn precision(&self) -> Precision {
        self.precision
    }

    /// Counters of the work done so far.
    pub fn stats(&self) -> GpuStats {
        self.stats
    }

    fn workgroups(&self) -> u32 {
        (self.plan.members.len() as u32).div_ceil(STEP_WORKGROUP_SIZE)
    }

    /// Encodes `begin_interval` (when `begin`) and `dispatches_per_submit` `advance`
    /// dispatches, the running counter cleared before the last one, and submits them
    /// (partitioned kernel: `attempts_per_submit` trial steps, then the count).
    fn submit_advance(&mut self, begin: bool) -> Result<(), GpuError> {
        let ctx = self.ctx;
        let (dispatches, error) = ctx.scoped(|| {
            let mut encoder = ctx
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("advance"),
                });
            let mut dispatches = 0u64;
            match &self.kernel {
                Kernel::Sequential(pipelines) => {
                    if begin {
                        self.encode_dispatches(&mut encoder, "begin_interval", &pipelines.begin, 1);
                    }
                    let advance = &pipelines.advance;
                    let count = self.stats.dispatches_per_submit as u32;
                    self.encode_dispatches(&mut encoder, "advance", advance, count - 1);
                    // The counter then holds the members still running after the last dispatch.
                    encoder.clear_buffer(&self.buffers.running, 0, None);
                    self.encode_dispatches(&mut encoder, "advance (last)", advance, 1);
                    dispatches = u64::from(count + u32::from(begin));
                }
                Kernel::Partitioned(part) => {
                    let mut sequence: Vec<Dispatch> = Vec::new();
                    if begin {
                        sequence.extend(BEGIN_SEQUENCE);
                    }
                    for _ in 0..part.attempts_per_submit {
                        sequence.extend(part.attempt.iter().copied());
                    }
                    dispatches += self.encode_sequence(&mut encoder, "advance", part, &sequence);
                    encoder.clear_buffer(&self.buffers.running, 0, None);
                    dispatches += self.encode_sequence(
                        &mut encoder,
                        "count",
                        part,
                        &[(super::partitioned::entry::COUNT, Over::Members)],
                    );
                }
            }
            ctx.queue.submit([encoder.finish()]);
            dispatches
        });
        if let Some(message) = error {
            return Err(GpuError::Validation {
                label: "GpuSolver advance".to_string(),
                message,
            });
        }
        self.stats.submits += 1;
        self.stats.dispatches += dispatches;
        Ok(())
    }

    /// Encodes and submits one `gather` dispatch.
    fn submit_gather(&mut self) -> Result<(), GpuError> {
        let ctx = self.ctx;
        let ((), error) = ctx.scoped(|| {
            let mut encoder = ctx
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("gather"),
                });
            match &self.kernel {
                Kernel::Sequential(pipelines) => {
                    self.encode_dispatches(&mut encoder, "gather", &pipelines.gather, 1);
                }
                Kernel::Partitioned(part) => {
                    self.encode_sequence(
                        &mut encoder,
                        "gather",
                        part,
                        &[(super::partitioned::entry::GATHER, Over::Segments)],
                    );
                }
            }
            ctx.queue.submit([encoder.finish()]);
        });
        if let Some(message) = error {
            return Err(GpuError::Validation {
                label: "GpuSolver gather".to_string(),
                message,
            });
        }
        self.stats.submits += 1;
        self.stats.dispatches += 1;
        Ok(())
    }

    /// The dispatches of `sequence` of the partitioned kernel in one compute pass; returns
    /// their count.
    fn encode_sequence(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        label: &str,
        part: &PartKernel,
        sequence: &[Dispatch],
    ) -> u64 {
        let members = self.plan.members.len() as u32;
        let member_groups = members.div_ceil(STEP_WORKGROUP_SIZE);
        let segment_groups = (members * part.segments.segments).div_ceil(SEGMENT_WORKGROUP_SIZE);
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some(label),
            timestamp_writes: None,
        });
        pass.set_bind_group(0, &self.group, &[]);
        for &(entry, over) in sequence {
            pass.set_pipeline(&part.pipelines[entry]);
            pass.dispatch_workgroups(
                match over {
                    Over::Members => member_groups,
                    Over::Segments => segment_groups,
                },
                1,
                1,
            );
        }
        sequence.len() as u64
    }

    /// `count` dispatches of `pipeline` (one invocation per member) in one compute pass.
    fn encode_dispatches(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        label: &str,
        pipeline: &wgpu::ComputePipeline,
        count: u32,
    ) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some(label),
            timestamp_writes: None,
        });
        pass.set_bind_group(0, &self.group, &[]);
        pass.set_pipeline(pipeline);
        for _ in 0..count {
            pass.dispatch_workgroups(self.workgroups(), 1, 1);
        }
    }

    fn read(&mut self, buffer: ReadBack, bytes: u64) -> Result<Vec<u8>, GpuError> {
        let buffer = match buffer {
            ReadBack::Running => &self.buffers.running,
            ReadBack::Controls => &self.buffers.controls,
            ReadBack::GatheredGaps => &self.buffers.gathered_gaps,
            ReadBack::GatheredVelocities => &self.buffers.gathered_vel,
        };
        let data = self.ctx.read_buffer(buffer, bytes)?;
        self.stats.readbacks += 1;
        self.stats.bytes_read += bytes;
        Ok(data)
    }

    /// The uniform config of the interval (t_start, t_end].
    fn interval_config(&self, t_start: f64, t_end: f64) -> ConfigF64 {
        let stepping = self.plan.stepping;
        let fixed_dt = match stepping {
            Stepping::Fixed { dt, .. } => Some(dt),
            Stepping::Adaptive { .. } => None,
        };
        let rules = Rules::new(
            t_start,
            t_end,
            fixed_dt,
            stepping.dt_min(),
            self.precision.time_resolution(),
        );
        ConfigF64 {
            batch: self.plan.members.len() as u32,
            particles: self.plan.particles as u32,
            max_attempts: self.max_attempts,
            top_column: u32::from(self.plan.top_column(self.precision == Precision::F32)),
            eps: self.plan.eps,
            t_start,
            t_end,
            fixed_h: rules.fixed_h.unwrap_or(0.0),
            dt_min: rules.dt_min,
            tolerance: match stepping {
                Stepping::Adaptive { tolerance, .. } => tolerance,
                Stepping::Fixed { .. } => 0.0,
            },
            tail: [],
        }
    }

    /// Submits `advance` dispatches until no member is running any more (every member has
    /// reached the config's t_end or failed).
    fn advance_until_all_stopped(&mut self) -> Result<(), GpuError> {
        let mut first = true;
        loop {
            self.submit_advance(first)?;
            first = false;
            let running: Vec<u32> = bytemuck::pod_collect_to_vec(&self.read(ReadBack::Running, 4)?);
            if running[0] == 0 {
                return Ok(());
            }
        }
    }

    /// Gathers each member's current state and reads it back with the controls: the gaps and
    /// velocities of every member, interleaved.
    fn gather_and_read(&mut self) -> Result<(Vec<f64>, Vec<f64>), GpuError> {
        self.submit_gather()?;
        let bsz = self.plan.members.len() as u64;
        let control_bytes = self.read(ReadBack::Controls, control_size(self.precision) * bsz)?;
        self.last_controls = controls_from_bytes(&control_bytes, self.precision);
        for (estimates, c) in self.error_estimates.iter_mut().zip(&self.last_controls) {
            estimates.push(c.error_sum);
        }
        self.stats.steps = self.last_controls.iter().map(|c| c.accepted as u64).sum();
        let gap_bytes = self.read(ReadBack::GatheredGaps, self.sizes.gaps)?;
        let vel_bytes = self.read(ReadBack::GatheredVelocities, self.sizes.velocities)?;
        Ok((
            reals_from_bytes(&gap_bytes, self.precision),
            reals_from_bytes(&vel_bytes, self.precision),
        ))
    }

    /// Every member's snapshot from the interleaved gaps and velocities (failed members: an
    /// empty snapshot).
    fn snapshots(&self, gaps: &[f64], vel: &[f64]) -> Vec<Snapshot> {
        let bsz = self.plan.members.len();
        let member = |values: &[f64], b: usize| -> Vec<f64> {
            values.iter().skip(b).step_by(bsz).copied().collect()
        };
        let mut snapshots: Vec<Snapshot> = self
            .last_controls
            .iter()
            .enumerate()
            .map(|(b, control)| {
                if control.failure != 0 {
                    return Snapshot::failed(&self.plan);
                }
                observe(
                    &self.plan,
                    &self.plan.members[b],
                    &member(gaps, b),
                    &member(vel, b),
                    self.dstar[b].as_deref(),
                    self.bonded[b].as_deref(),
                    &self.grid_x,
                )
            })
            .collect();
        if self.plan.peak_centre {
            // Beside each other on the CPU's threads (a batch can hold a million members).
            use rayon::prelude::*;
            snapshots
                .par_chunks_mut(64)
                .for_each(|some| set_peak_centres(&self.grid_x, some.iter_mut()));
        }
        snapshots
    }

    /// Advances to the next output time and returns every member's snapshot there, in member
    /// order (the first call returns the initial state); `Ok(None)` after the last output time.
    /// Same semantics as `CpuSolver::next_output`.
    fn advance_to_next_output(&mut self) -> Result<Option<Vec<Snapshot>>, GpuError> {
        let k = self.time_index;
        let Some(&t_end) = self.plan.output_times.get(k) else {
            return Ok(None);
        };
        let t_start = if k == 0 {
            0.0
        } else {
            self.plan.output_times[k - 1]
        };
        self.time_index += 1;
        let config = config_bytes(self.interval_config(t_start, t_end), self.precision);
        self.ctx
            .queue
            .write_buffer(&self.buffers.config, 0, &config);
        self.stats.bytes_written += config.len() as u64;
        if t_end > t_start {
            self.advance_until_all_stopped()?;
        }
        let (gaps, vel) = self.gather_and_read()?;
        Ok(Some(self.snapshots(&gaps, &vel)))
    }

    /// Every member's bookkeeping as of the last output, in member order (like
    /// `CpuSolver::reports`).
    fn member_reports(&self) -> Vec<MemberReport> {
        let dt_min = self.plan.stepping.dt_min();
        let has_estimates = error_estimate_method(self.plan.order, self.plan.stepping).is_some();
        self.last_controls
            .iter()
            .enumerate()
            .map(|(m, c)| MemberReport {
                index: m,
                mu: self.plan.members[m].mu,
                gamma: self.plan.members[m].gamma,
                status: match Failure::from_code(c.failure) {
                    Failure::None => MemberStatus::Ok,
                    f => MemberStatus::Failed {
                        reason: FailureRecord {
                            failure: f,
                            time: c.failure_time,
                            index: c.failure_index,
                            detail: c.failure_detail,
                        }
                        .describe(
                            dt_min,
                            self.precision.time_resolution(),
                            m,
                            self.plan.members[m].gamma,
                        ),
                        time: c.failure_time,
                    },
                },
                steps_accepted: c.accepted as u64,
                steps_rejected: c.rejected as u64,
                last_dt: c.dt,
                last_order: c.order as u8,
                error_estimate: has_estimates.then(|| self.error_estimates[m].clone()),
            })
            .collect()
    }
}

impl BatchSolver for GpuSolver<'_> {
    fn next_output(&mut self, progress: Progress) -> crate::error::Result<Option<Vec<Snapshot>>> {
        let snaps = self.advance_to_next_output().map_err(|e| {
            crate::error::Error::gpu(
                format!("backend gpu on {}", self.ctx.description.short()),
                e,
                "; the outputs written so far are incomplete (no manifest)",
            )
        })?;
        if let Some(v) = &snaps {
            progress(v.len() as u64);
        }
        Ok(snaps)
    }

    fn reports(&self) -> Vec<MemberReport> {
        self.member_reports()
    }

    fn plan(&self) -> &Plan {
        &self.plan
    }

    fn grid(&self) -> &[f64] {
        &self.grid_x
    }

    fn gpu_stats(&self) -> Option<GpuStats> {
        Some(self.stats)
    }
}

#[derive(Clone, Copy)]
/// The buffers the host reads back: the running count after each submit, the rest at outputs.
enum ReadBack {
    Running,
    Controls,
    GatheredGaps,
    GatheredVelocities,
}
