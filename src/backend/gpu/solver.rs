//! The GPU backend: the batch advanced by the generated WGSL kernel (`shaders/step.wgsl`, the
//! twin of `crate::backend::cpu::step`, `Block::{error_norm, extrapolate}` and `crate::backend::cpu::control`),
//! state kept on the GPU between output times.
//!
//! Every scheme of the CPU backend runs here: orders 1 and 2, fixed and adaptive steps (each
//! member its own dt), rejection and retry of a step that closes or halves a gap, per-member
//! failure status without stopping the others, clusters, repulsion, forcing; f64 (on adapters
//! with SHADER_F64) or f32.
//!
//! Layout: element i of member b sits at `i·B + b` (B members). Per output interval the host
//! writes the interval into the uniform config, then submits command buffers of
//! `begin_interval` (first submit only) and `advance` dispatches (up to [`ATTEMPTS_PER_SUBMIT`] trial steps per member per submit),
//! each of which lets every running member try up to [`MAX_ATTEMPTS_PER_DISPATCH`] steps in a
//! loop of its own invocation (fewer on lavapipe, see [`attempts_per_dispatch`]): many steps per
//! dispatch and per submit. After each submit the host reads back
//! one u32, the number of members still running; when it is 0, `gather` copies each member's
//! current state into the read-back buffers, which are read once (readback only at output
//! times).

use wgpu::util::DeviceExt;

use super::context::GpuContext;
use crate::backend::error::GpuError;
use super::kernel::{
    binding, generate_step_wgsl, GammaSpec, KernelSpec, SchemeSpec, ADVANCE_ENTRY, BEGIN_ENTRY,
    GATHER_ENTRY, STEP_WORKGROUP_SIZE,
};
use crate::backend::report::{Failure, MemberReport, MemberStatus};
use crate::backend::layout::interleave;
use crate::backend::{BatchSolver, Progress};
use crate::model::chain::Chain;
use crate::model::observables::{grid_points, observe, Snapshot};
use crate::model::plan::{Plan, Power};
use crate::backend::Precision;
use crate::model::params::Stepping;

/// Trial steps per member encoded into one command buffer (as dispatches × attempts per
/// dispatch): many steps per submit, one read-back of 4 bytes per submit.
pub const ATTEMPTS_PER_SUBMIT: u32 = 256;

/// Most trial steps per member per `advance` dispatch (each invocation loops over them, so a
/// dispatch advances every member by many steps).
pub const MAX_ATTEMPTS_PER_DISPATCH: u32 = 16;

/// Whether the adapter is llvmpipe (lavapipe), which bounds the loop iterations of a shader
/// invocation ([`LAVAPIPE_LOOP_LIMIT`]).
fn is_lavapipe(ctx: &GpuContext) -> bool {
    let d = &ctx.description;
    d.driver.to_lowercase().contains("llvmpipe") || d.name.to_lowercase().contains("llvmpipe")
}

/// Loop iterations over the chain per trial step: two sweeps per Euler step (one for order 1 with
/// fixed steps, three with Richardson), plus the error norm and the extrapolation (two each).
fn loops_per_attempt(scheme: SchemeSpec) -> u64 {
    (if scheme.richardson() { 6 } else { 2 })
        + if scheme.adaptive { 2 } else { 0 }
        + if scheme.order2 { 2 } else { 0 }
}

/// Trial steps per member per `advance` dispatch: [`MAX_ATTEMPTS_PER_DISPATCH`], or on lavapipe
/// as many as fit its loop budget (measured: past the budget the invocation stops silently and
/// the state is wrong; within it the GPU matches the CPU bit for bit).
/// `ROUGHLUB_GPU_ATTEMPTS_PER_DISPATCH` (1..=4096) overrides it.
fn attempts_per_dispatch(ctx: &GpuContext, n: usize, scheme: SchemeSpec) -> u32 {
    if let Some(k) = std::env::var("ROUGHLUB_GPU_ATTEMPTS_PER_DISPATCH")
        .ok()
        .and_then(|v| v.parse::<u32>().ok())
        .filter(|&k| (1..=4096).contains(&k))
    {
        return k;
    }
    if is_lavapipe(ctx) {
        // The attempt loop itself counts too: one iteration per attempt.
        let per = loops_per_attempt(scheme) * n as u64 + 1;
        (LAVAPIPE_LOOP_LIMIT / per).clamp(1, MAX_ATTEMPTS_PER_DISPATCH as u64) as u32
    } else {
        MAX_ATTEMPTS_PER_DISPATCH
    }
}

/// Work counters of a [`GpuSolver`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct GpuStats {
    /// Compute dispatches (begin_interval, advance, gather).
    pub dispatches: u64,
    /// Accepted steps summed over members.
    pub steps: u64,
    /// Command buffers submitted.
    pub submits: u64,
    /// Read-backs (each one a copy submission and a wait).
    pub readbacks: u64,
    /// Bytes read back from the GPU.
    pub bytes_read: u64,
    /// Bytes written to the GPU (initial upload, configs).
    pub bytes_written: u64,
    /// Trial steps each member may take per `advance` dispatch.
    pub attempts_per_dispatch: u64,
    /// `advance` dispatches per submit.
    pub dispatches_per_submit: u64,
}

/// A member's step control as read back (the `Control` struct of step.wgsl).
#[derive(Debug, Clone, Copy)]
struct ControlState {
    t: f64,
    dt: f64,
    failure_time: f64,
    accepted: u32,
    rejected: u32,
    failure: u32,
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
    config: wgpu::Buffer,
    controls: wgpu::Buffer,
    running: wgpu::Buffer,
    gathered_gaps: wgpu::Buffer,
    gathered_vel: wgpu::Buffer,
    begin: wgpu::ComputePipeline,
    advance: wgpu::ComputePipeline,
    gather: wgpu::ComputePipeline,
    group: wgpu::BindGroup,
    last_controls: Vec<ControlState>,
    stats: GpuStats,
    // Kept alive for the bind group.
    _buffers: Vec<wgpu::Buffer>,
}

fn invalid(message: String) -> GpuError {
    GpuError::Validation {
        label: "GpuSolver::new".to_string(),
        message,
    }
}

/// Bytes of `values` as the kernel's real type.
fn real_bytes(values: &[f64], precision: Precision) -> Vec<u8> {
    match precision {
        Precision::F64 => bytemuck::cast_slice(values).to_vec(),
        Precision::F32 => {
            let v: Vec<f32> = values.iter().map(|&x| x as f32).collect();
            bytemuck::cast_slice(&v).to_vec()
        }
    }
}

/// Reals of the kernel's type back to f64.
fn reals_from_bytes(bytes: &[u8], precision: Precision) -> Vec<f64> {
    match precision {
        Precision::F64 => bytemuck::pod_collect_to_vec(bytes),
        Precision::F32 => {
            let v: Vec<f32> = bytemuck::pod_collect_to_vec(bytes);
            v.into_iter().map(f64::from).collect()
        }
    }
}

fn real_size(precision: Precision) -> u64 {
    match precision {
        Precision::F64 => 8,
        Precision::F32 => 4,
    }
}

/// Size of the `Control` struct of step.wgsl: three reals and six u32.
fn control_size(precision: Precision) -> u64 {
    3 * real_size(precision) + 6 * 4
}

/// llvmpipe (lavapipe) stops every shader invocation after 65535 loop iterations in total
/// (measured: `gather` over 2 loops of N = 40000 left the tail unwritten; N = 20000 was right).
/// One invocation per member sweeps the whole chain, so on that driver N is bounded; other
/// drivers have no such limit. Returns a clear error instead of silently wrong results.
pub const LAVAPIPE_LOOP_LIMIT: u64 = 65_535;

fn check_loop_budget(
    ctx: &GpuContext,
    n: usize,
    scheme: SchemeSpec,
    attempts: u32,
) -> Result<(), GpuError> {
    if !is_lavapipe(ctx) {
        return Ok(());
    }
    // One `advance` invocation; `gather` needs two loops over the chain.
    let per = loops_per_attempt(scheme).max(2);
    let iterations = attempts as u64 * (per * n as u64 + 1);
    if iterations > LAVAPIPE_LOOP_LIMIT {
        return Err(GpuError::LoopLimit {
            adapter: ctx.description.short(),
            particles: n,
            iterations,
            limit: LAVAPIPE_LOOP_LIMIT,
            max_particles: (LAVAPIPE_LOOP_LIMIT / attempts as u64 - 1) / per,
        });
    }
    Ok(())
}

/// The uniform `Config` of step.wgsl (keep in sync): 4 u32, then eps, t_start, t_end, fixed_h
/// (0 = adaptive), dt_min, tolerance; padded to 64 bytes.
#[allow(clippy::too_many_arguments)]
fn config_bytes(
    precision: Precision,
    batch: u32,
    particles: u32,
    max_attempts: u32,
    eps: f64,
    t_start: f64,
    t_end: f64,
    fixed_h: f64,
    dt_min: f64,
    tolerance: f64,
) -> Vec<u8> {
    let mut out = Vec::with_capacity(64);
    for v in [batch, particles, max_attempts, 0] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&real_bytes(
        &[eps, t_start, t_end, fixed_h, dt_min, tolerance],
        precision,
    ));
    out.resize(64, 0);
    out
}

impl<'a> GpuSolver<'a> {
    /// Whether this context can run `plan` at `precision` (f64 support, sizes, and on lavapipe
    /// the loop budget), without building anything: the selection policy asks this before
    /// choosing the GPU. Returns the kernel's scheme and trial steps per dispatch.
    pub fn check(
        ctx: &GpuContext,
        plan: &Plan,
        precision: Precision,
    ) -> Result<(SchemeSpec, u32), GpuError> {
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
        if n as u64 * bsz as u64 > u32::MAX as u64 / 4 {
            return Err(invalid(format!(
                "N·B = {} elements: the kernel indexes buffers with u32 (at most {}); use fewer members per run",
                n as u64 * bsz as u64,
                u32::MAX / 4
            )));
        }
        let scheme = SchemeSpec {
            order2: plan.order == 2,
            adaptive: matches!(plan.stepping, Stepping::Adaptive { .. }),
        };
        let rs = real_size(precision);
        let sets: u64 = if scheme.richardson() { 4 } else { 2 };
        let gaps_bytes = (n * bsz) as u64 * rs;
        let vel_bytes = ((n - 1) * bsz) as u64 * rs;
        ctx.check_storage_size(
            "gap sets (state, candidate, full and half steps)",
            sets * gaps_bytes,
        )?;
        ctx.check_storage_size("velocity sets", sets * vel_bytes)?;
        ctx.check_storage_size("Thomas scratch", 3 * vel_bytes)?;
        let max_attempts = attempts_per_dispatch(ctx, n, scheme);
        check_loop_budget(ctx, n, scheme, max_attempts)?;
        Ok((scheme, max_attempts))
    }

    /// Uploads the batch (`chains[m]` is member m's initial chain) and builds the kernels.
    pub fn new(
        ctx: &'a GpuContext,
        plan: Plan,
        chains: Vec<Chain>,
        precision: Precision,
    ) -> Result<GpuSolver<'a>, GpuError> {
        let (scheme, max_attempts) = Self::check(ctx, &plan, precision)?;
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

        // Kernel variant: a uniform integer gamma becomes a fixed chain of multiplications,
        // anything else is read per member (the kernel then follows Power::of per member).
        let repulsion = plan.repulsion.then(|| {
            let g0 = plan.members[0].gamma;
            let uniform = plan.members.iter().all(|p| p.gamma == g0);
            match (uniform, Power::of(g0)) {
                (true, Power::Integer(k)) => GammaSpec::Integer(k),
                _ => GammaSpec::PerMember,
            }
        });
        let dt0 = match plan.stepping {
            Stepping::Fixed { dt, .. } => dt,
            Stepping::Adaptive { dt_initial, .. } => dt_initial,
        };
        let spec = KernelSpec {
            precision,
            repulsion,
            clusters: plan.clusters,
            forcing: plan
                .forcing
                .as_ref()
                .map(|f| (f.expr.clone(), f.rule.nodes.clone(), f.rule.weights.clone())),
            scheme,
        };
        let source = generate_step_wgsl(&spec);

        let rs = real_size(precision);
        let sets: u64 = if scheme.richardson() { 4 } else { 2 };
        let gaps_bytes = (n * bsz) as u64 * rs;
        let vel_bytes = ((n - 1) * bsz) as u64 * rs;

        // Host-side data.
        let gaps0 =
            interleave::<f64>(&chains.iter().map(|c| c.gaps.as_slice()).collect::<Vec<_>>());
        let vel0 = interleave::<f64>(
            &chains
                .iter()
                .map(|c| c.velocities.as_slice())
                .collect::<Vec<_>>(),
        );
        let dstar: Vec<Option<Vec<f64>>> = chains
            .iter()
            .map(|c| {
                if plan.repulsion {
                    c.dstar.clone()
                } else {
                    None
                }
            })
            .collect();
        let no_bonds = vec![false; n];
        let bonded: Vec<Option<Vec<bool>>> = chains
            .iter()
            .map(|c| {
                plan.clusters
                    .then(|| c.bonded.clone().unwrap_or_else(|| no_bonds.clone()))
            })
            .collect();
        let mut gap_sets = real_bytes(&gaps0, precision);
        gap_sets.resize((sets * gaps_bytes) as usize, 0);
        let mut vel_sets = real_bytes(&vel0, precision);
        vel_sets.resize((sets * vel_bytes) as usize, 0);
        let params: Vec<f64> = plan.members.iter().flat_map(|p| [p.mu, p.gamma]).collect();
        let mut controls = Vec::with_capacity((control_size(precision) * bsz as u64) as usize);
        for _ in 0..bsz {
            // t, dt, failure_time; accepted, rejected, regular_steps, regular, failure, parity.
            controls.extend_from_slice(&real_bytes(&[0.0, dt0, 0.0], precision));
            for v in [0u32, 0, 0, 1, 0, 0] {
                controls.extend_from_slice(&v.to_le_bytes());
            }
        }

        let device = &ctx.device;
        let storage = wgpu::BufferUsages::STORAGE;
        let readable = storage | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST;
        let mut bytes_written = 0u64;
        let (built, error) = ctx.scoped(|| {
            let mut init = |label: &str, bytes: &[u8], usage: wgpu::BufferUsages| {
                bytes_written += bytes.len() as u64;
                device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some(label),
                    contents: bytes,
                    usage,
                })
            };
            let empty = |label: &str, size: u64, usage: wgpu::BufferUsages| {
                device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some(label),
                    size: size.max(4).next_multiple_of(4),
                    usage,
                    mapped_at_creation: false,
                })
            };
            let config = empty(
                "config",
                64,
                wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            );
            let gap_sets = init("gap sets", &gap_sets, storage);
            let vel_sets = init("velocity sets", &vel_sets, storage);
            let params = init(
                "member parameters",
                &real_bytes(&params, precision),
                storage,
            );
            let controls = init("controls", &controls, readable);
            let scratch = empty("scratch", 3 * vel_bytes, storage);
            let running = empty("running", 4, readable);
            let gathered_gaps = empty("gathered gaps", gaps_bytes, readable);
            let gathered_vel = empty("gathered velocities", vel_bytes, readable);
            let dstar_buf = plan.repulsion.then(|| {
                let refs: Vec<&[f64]> = dstar.iter().map(|d| d.as_deref().unwrap_or(&[])).collect();
                init("dstar", &real_bytes(&interleave(&refs), precision), storage)
            });
            let bonded_buf = plan.clusters.then(|| {
                let refs: Vec<&[bool]> =
                    bonded.iter().map(|d| d.as_deref().unwrap_or(&[])).collect();
                let flags: Vec<u32> = interleave(&refs).into_iter().map(u32::from).collect();
                init("bonded", bytemuck::cast_slice(&flags), storage)
            });
            let mut entries = vec![
                (binding::CONFIG, &config, true, false),
                (binding::GAP_SETS, &gap_sets, false, false),
                (binding::VEL_SETS, &vel_sets, false, false),
                (binding::PARAMS, &params, false, true),
                (binding::CONTROLS, &controls, false, false),
                (binding::SCRATCH, &scratch, false, false),
                (binding::RUNNING, &running, false, false),
                (binding::GATHERED_GAPS, &gathered_gaps, false, false),
                (binding::GATHERED_VEL, &gathered_vel, false, false),
            ];
            if let Some(d) = &dstar_buf {
                entries.push((binding::DSTAR, d, false, true));
            }
            if let Some(b) = &bonded_buf {
                entries.push((binding::BONDED, b, false, true));
            }
            let layout_entries: Vec<wgpu::BindGroupLayoutEntry> = entries
                .iter()
                .map(
                    |&(binding, _, uniform, read_only)| wgpu::BindGroupLayoutEntry {
                        binding,
                        visibility: wgpu::ShaderStages::COMPUTE,
                        ty: wgpu::BindingType::Buffer {
                            ty: if uniform {
                                wgpu::BufferBindingType::Uniform
                            } else {
                                wgpu::BufferBindingType::Storage { read_only }
                            },
                            has_dynamic_offset: false,
                            min_binding_size: None,
                        },
                        count: None,
                    },
                )
                .collect();
            let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("roughlub step"),
                entries: &layout_entries,
            });
            let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("roughlub step"),
                layout: &layout,
                entries: &entries
                    .iter()
                    .map(|&(binding, buffer, _, _)| wgpu::BindGroupEntry {
                        binding,
                        resource: buffer.as_entire_binding(),
                    })
                    .collect::<Vec<_>>(),
            });
            let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("roughlub step"),
                bind_group_layouts: &[Some(&layout)],
                immediate_size: 0,
            });
            let mut keep = vec![gap_sets, vel_sets, params, scratch];
            keep.extend(dstar_buf);
            keep.extend(bonded_buf);
            (
                (config, controls, running, gathered_gaps, gathered_vel),
                group,
                pipeline_layout,
                keep,
            )
        });
        if let Some(message) = error {
            return Err(GpuError::Validation {
                label: "GpuSolver::new (buffers and bind groups)".to_string(),
                message,
            });
        }
        let ((config, controls, running, gathered_gaps, gathered_vel), group, layout, keep) = built;
        let pipeline =
            |entry: &str| ctx.compute_pipeline("step.wgsl", &source, entry, Some(&layout));
        let begin = pipeline(BEGIN_ENTRY)?;
        let advance = pipeline(ADVANCE_ENTRY)?;
        let gather = pipeline(GATHER_ENTRY)?;
        let grid_x = grid_points(plan.grid);
        let last_controls = vec![
            ControlState {
                t: 0.0,
                dt: dt0,
                failure_time: 0.0,
                accepted: 0,
                rejected: 0,
                failure: 0,
            };
            bsz
        ];
        Ok(GpuSolver {
            ctx,
            plan,
            precision,
            dstar,
            bonded,
            grid_x,
            time_index: 0,
            max_attempts,
            config,
            controls,
            running,
            gathered_gaps,
            gathered_vel,
            begin,
            advance,
            gather,
            group,
            last_controls,
            stats: GpuStats {
                bytes_written,
                attempts_per_dispatch: max_attempts as u64,
                dispatches_per_submit: (ATTEMPTS_PER_SUBMIT / max_attempts).clamp(4, 64) as u64,
                ..GpuStats::default()
            },
            _buffers: keep,
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
    /// dispatches, the running counter cleared before the last one, and submits them.
    fn submit_advance(&mut self, begin: bool) -> Result<(), GpuError> {
        let ctx = self.ctx;
        let ((), error) = ctx.scoped(|| {
            let mut encoder = ctx
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("advance"),
                });
            if begin {
                self.encode_dispatches(&mut encoder, "begin_interval", &self.begin, 1);
            }
            let dispatches = self.stats.dispatches_per_submit as u32;
            self.encode_dispatches(&mut encoder, "advance", &self.advance, dispatches - 1);
            // The counter then holds the members still running after the last dispatch.
            encoder.clear_buffer(&self.running, 0, None);
            self.encode_dispatches(&mut encoder, "advance (last)", &self.advance, 1);
            ctx.queue.submit([encoder.finish()]);
        });
        if let Some(message) = error {
            return Err(GpuError::Validation {
                label: "GpuSolver advance".to_string(),
                message,
            });
        }
        self.stats.submits += 1;
        self.stats.dispatches += self.stats.dispatches_per_submit + u64::from(begin);
        Ok(())
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

    fn read(&mut self, which: Which, bytes: u64) -> Result<Vec<u8>, GpuError> {
        let buffer = match which {
            Which::Running => &self.running,
            Which::Controls => &self.controls,
            Which::Gaps => &self.gathered_gaps,
            Which::Vel => &self.gathered_vel,
        };
        let data = self.ctx.read_buffer(buffer, bytes)?;
        self.stats.readbacks += 1;
        self.stats.bytes_read += bytes;
        Ok(data)
    }

    fn parse_controls(&self, bytes: &[u8]) -> Vec<ControlState> {
        let size = control_size(self.precision) as usize;
        let rs = real_size(self.precision) as usize;
        bytes
            .chunks_exact(size)
            .map(|c| {
                let reals = reals_from_bytes(&c[..3 * rs], self.precision);
                let word = |k: usize| {
                    let o = 3 * rs + 4 * k;
                    u32::from_le_bytes([c[o], c[o + 1], c[o + 2], c[o + 3]])
                };
                ControlState {
                    t: reals[0],
                    dt: reals[1],
                    failure_time: reals[2],
                    accepted: word(0),
                    rejected: word(1),
                    failure: word(4),
                }
            })
            .collect()
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
        let bsz = self.plan.members.len();
        let n = self.plan.particles;
        let fixed_dt = match self.plan.stepping {
            Stepping::Fixed { dt, .. } => Some(dt),
            Stepping::Adaptive { .. } => None,
        };
        let rules =
            crate::backend::cpu::control::Rules::new(t_start, t_end, fixed_dt, self.plan.stepping.dt_min());
        let tolerance = match self.plan.stepping {
            Stepping::Adaptive { tolerance, .. } => tolerance,
            Stepping::Fixed { .. } => 0.0,
        };
        let config = config_bytes(
            self.precision,
            bsz as u32,
            n as u32,
            self.max_attempts,
            self.plan.eps,
            t_start,
            t_end,
            rules.fixed_h.unwrap_or(0.0),
            rules.dt_min,
            tolerance,
        );
        self.ctx.queue.write_buffer(&self.config, 0, &config);
        self.stats.bytes_written += config.len() as u64;
        if t_end > t_start {
            let mut first = true;
            loop {
                self.submit_advance(first)?;
                first = false;
                let running: Vec<u32> =
                    bytemuck::pod_collect_to_vec(&self.read(Which::Running, 4)?);
                if running[0] == 0 {
                    break;
                }
            }
        }
        // Gather each member's current state and read it back with the controls.
        let ctx = self.ctx;
        let ((), error) = ctx.scoped(|| {
            let mut encoder = ctx
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("gather"),
                });
            self.encode_dispatches(&mut encoder, "gather", &self.gather, 1);
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
        let rs = real_size(self.precision);
        let control_bytes =
            self.read(Which::Controls, control_size(self.precision) * bsz as u64)?;
        self.last_controls = self.parse_controls(&control_bytes);
        self.stats.steps = self.last_controls.iter().map(|c| c.accepted as u64).sum();
        let gaps = reals_from_bytes(
            &self.read(Which::Gaps, (n * bsz) as u64 * rs)?,
            self.precision,
        );
        let vel = reals_from_bytes(
            &self.read(Which::Vel, ((n - 1) * bsz) as u64 * rs)?,
            self.precision,
        );
        let mut out = Vec::with_capacity(bsz);
        for (b, control) in self.last_controls.iter().enumerate() {
            if control.failure != 0 {
                out.push(Snapshot::failed(&self.plan));
                continue;
            }
            let member_gaps: Vec<f64> = gaps.iter().skip(b).step_by(bsz).copied().collect();
            let member_vel: Vec<f64> = vel.iter().skip(b).step_by(bsz).copied().collect();
            out.push(observe(
                &self.plan,
                &self.plan.members[b],
                member_gaps,
                member_vel,
                self.dstar[b].as_deref(),
                self.bonded[b].as_deref(),
                &self.grid_x,
            ));
        }
        Ok(Some(out))
    }

    /// Every member's bookkeeping as of the last output, in member order (like
    /// `CpuSolver::reports`).
    fn member_reports(&self) -> Vec<MemberReport> {
        let dt_min = self.plan.stepping.dt_min();
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
                        reason: f.describe(dt_min),
                        time: c.failure_time,
                    },
                },
                steps_accepted: c.accepted as u64,
                steps_rejected: c.rejected as u64,
                last_dt: c.dt,
            })
            .collect()
    }

    /// Member times as of the last output (for tests and progress).
    pub fn member_times(&self) -> Vec<f64> {
        self.last_controls.iter().map(|c| c.t).collect()
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
enum Which {
    Running,
    Controls,
    Gaps,
    Vel,
}
