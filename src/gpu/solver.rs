//! A first GPU backend: the batch stepped by the generated WGSL step kernel
//! ([`super::kernel::generate_step_wgsl`]), state kept on the GPU between output times.
//!
//! Scope (everything else is refused by [`GpuSolver::new`] with "not yet supported on the GPU
//! backend: ..."): order 1, fixed steps, f64 or f32, whatever terms the kernel supports
//! (repulsion with integer or per-member gamma, clusters, forcing).
//!
//! Layout: element i of member b sits at `i·B + b` (B members). The gaps and velocities live in
//! two buffer sets A and B; step k reads one set and writes the other (two bind groups,
//! alternating). Each step is two dispatches in one compute pass:
//!
//! 1. the step kernel (`euler_step`), which reads each member's `{mu, h, t, gamma}`;
//! 2. a small bookkeeping kernel (`advance_schedule`, below) that makes a member's failure sticky
//!    (`status[b] = 1` once its `ok` flag is 0: the kernel overwrites `ok` every step) and writes
//!    the next step's `t` and `h` from a per-chunk schedule into the member parameters, so that
//!    every step has exactly the time and step size of the CPU backend (`Block::advance`: equal
//!    steps h = interval / ceil(interval / dt · (1 − 1e-12)), t = t_start + k·h, the last step
//!    landing exactly on the output time).
//!
//! The steps of an output interval are encoded into one command encoder and submitted once per
//! chunk of at most [`MAX_STEPS_PER_SUBMIT`] steps. Gaps, velocities and the failure flags are
//! read back only at output times.
//!
//! Rejection: the CPU backend halves a rejected fixed step and retries; this backend does not
//! yet. A member whose step closed or collapsed a gap (or gave a non-finite value) during an
//! interval is marked failed, with the interval start as its time, and its snapshots are
//! [`Snapshot::failed`] from then on.

use wgpu::util::DeviceExt;

use super::context::{GpuContext, GpuError};
use super::kernel::{
    binding, generate_step_wgsl, GammaSpec, KernelSpec, STEP_ENTRY, STEP_WORKGROUP_SIZE,
};
use crate::cpu::{MemberReport, MemberStatus};
use crate::initial::Chain;
use crate::observables::{grid_points, observe, Snapshot};
use crate::plan::{Plan, Power};
use crate::scene::{Precision, Stepping};

/// Most steps encoded into one command buffer before it is submitted.
pub const MAX_STEPS_PER_SUBMIT: usize = 256;

/// Entry point of the bookkeeping kernel.
const SCHEDULE_ENTRY: &str = "advance_schedule";

/// The bookkeeping kernel, run after every step (the `real` alias is replaced like in
/// `step.wgsl`). `status` holds B failure flags, then B step cursors (steps done in the chunk).
const SCHEDULE_WGSL: &str = r#"
alias real = f64;

struct Member {
    mu: real,
    h: real,
    t: real,
    gamma: real,
}

struct Slot {
    t: real,
    h: real,
}

@group(0) @binding(0) var<storage, read> ok_flags: array<u32>;
@group(0) @binding(1) var<storage, read_write> members: array<Member>;
@group(0) @binding(2) var<storage, read_write> status: array<u32>;
@group(0) @binding(3) var<storage, read> schedule: array<Slot>;

@compute @workgroup_size(64)
fn advance_schedule(@builtin(global_invocation_id) gid: vec3<u32>) {
    let b = gid.x;
    let batch = arrayLength(&ok_flags);
    if b >= batch {
        return;
    }
    if ok_flags[b] == 0u {
        status[b] = 1u;
    }
    let k = status[batch + b] + 1u;
    status[batch + b] = k;
    let slot = schedule[min(k, arrayLength(&schedule) - 1u)];
    members[b].t = slot.t;
    members[b].h = slot.h;
}
"#;

/// Reason recorded for a member rejected on the GPU.
pub const GPU_REJECTION_REASON: &str = "a fixed step closed or collapsed a gap on the GPU \
     (step halving is not yet implemented on the GPU backend)";

/// Work counters of a [`GpuSolver`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct GpuStats {
    /// Compute dispatches (two per step: the step kernel and the bookkeeping kernel).
    pub dispatches: u64,
    /// Steps taken (one step kernel dispatch each).
    pub steps: u64,
    /// Command buffers submitted for stepping.
    pub submits: u64,
    /// Read-backs (each one a copy submission and a wait).
    pub readbacks: u64,
    /// Bytes read back from the GPU.
    pub bytes_read: u64,
    /// Bytes written to the GPU (initial upload, schedules, member parameters).
    pub bytes_written: u64,
}

#[derive(Debug, Clone)]
struct MemberState {
    accepted: u64,
    rejected: u64,
    last_dt: f64,
    failed: Option<(String, f64)>,
}

/// The GPU backend (order 1, fixed steps).
pub struct GpuSolver<'a> {
    ctx: &'a GpuContext,
    plan: Plan,
    precision: Precision,
    /// Per member (f64, for the observables).
    dstar: Vec<Option<Vec<f64>>>,
    bonded: Vec<Option<Vec<bool>>>,
    grid_x: Vec<f64>,
    time_index: usize,
    /// Index of the buffer set holding the current state (0 = A, 1 = B).
    current: usize,
    gaps: [wgpu::Buffer; 2],
    vel: [wgpu::Buffer; 2],
    members: wgpu::Buffer,
    status: wgpu::Buffer,
    schedule: wgpu::Buffer,
    step_pipeline: wgpu::ComputePipeline,
    schedule_pipeline: wgpu::ComputePipeline,
    /// `step_groups[s]` reads set s and writes set 1 - s.
    step_groups: [wgpu::BindGroup; 2],
    schedule_group: wgpu::BindGroup,
    states: Vec<MemberState>,
    stats: GpuStats,
    // Kept alive for the bind groups.
    _other: Vec<wgpu::Buffer>,
}

fn unsupported(what: &str) -> GpuError {
    GpuError::Validation {
        label: "GpuSolver::new".to_string(),
        message: format!("not yet supported on the GPU backend: {what}"),
    }
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

/// Interleaves per-member vectors of equal length: element i of member b at i·B + b.
fn interleave<T: Copy>(per_member: &[&[T]]) -> Vec<T> {
    let len = per_member.first().map_or(0, |v| v.len());
    let mut out = Vec::with_capacity(len * per_member.len());
    for i in 0..len {
        for m in per_member {
            out.push(m[i]);
        }
    }
    out
}

/// The steps (t, h) of one output interval, exactly as the CPU backend takes them with fixed
/// steps and no rejection.
pub fn fixed_schedule(dt: f64, t_start: f64, t_end: f64) -> (f64, Vec<(f64, f64)>) {
    let count = ((t_end - t_start) / dt * (1.0 - 1e-12)).ceil().max(1.0);
    let hf = (t_end - t_start) / count;
    let mut steps = Vec::with_capacity(count as usize + 1);
    let mut t = t_start;
    let mut k: u64 = 0;
    while t < t_end {
        let remaining = t_end - t;
        let h = if remaining <= hf * (1.0 + 1e-9) {
            remaining
        } else {
            hf
        };
        steps.push((t, h));
        k += 1;
        t = if h == remaining {
            t_end
        } else {
            t_start + k as f64 * hf
        };
    }
    (hf, steps)
}

impl<'a> GpuSolver<'a> {
    /// Uploads the batch (`chains[m]` is member m's initial chain) and builds the kernels.
    /// Plans outside this backend's scope (order 2, adaptive stepping) give a
    /// [`GpuError::Validation`] saying "not yet supported on the GPU backend: ...".
    pub fn new(
        ctx: &'a GpuContext,
        plan: Plan,
        chains: Vec<Chain>,
        precision: Precision,
    ) -> Result<GpuSolver<'a>, GpuError> {
        if plan.order != 1 {
            return Err(unsupported(&format!(
                "order {} (Richardson extrapolation); only order 1 runs on the GPU for now, \
                 use the CPU backend",
                plan.order
            )));
        }
        if let Stepping::Adaptive { .. } = plan.stepping {
            return Err(unsupported(
                "adaptive stepping; only fixed steps run on the GPU for now, use the CPU backend",
            ));
        }
        if precision == Precision::F64 && !ctx.f64 {
            return Err(GpuError::NoF64 {
                adapter: ctx.description.short(),
            });
        }
        let bsz = plan.members.len();
        let n = plan.particles;
        if bsz == 0 {
            return Err(invalid("the plan has no members".to_string()));
        }
        if n < 2 {
            return Err(invalid(format!(
                "{n} particles: the kernel needs at least 2"
            )));
        }
        if chains.len() != bsz {
            return Err(invalid(format!(
                "{} chains for {bsz} members: one chain per member",
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
        let spec = KernelSpec {
            precision,
            repulsion,
            clusters: plan.clusters,
            forcing: plan
                .forcing
                .as_ref()
                .map(|f| (f.expr.clone(), f.rule.nodes.clone(), f.rule.weights.clone())),
        };
        let step_pipeline =
            ctx.compute_pipeline("step.wgsl", &generate_step_wgsl(&spec), STEP_ENTRY, None)?;
        let real_alias = match precision {
            Precision::F64 => "alias real = f64;",
            Precision::F32 => "alias real = f32;",
        };
        let schedule_src = SCHEDULE_WGSL.replace("alias real = f64;", real_alias);
        let schedule_pipeline =
            ctx.compute_pipeline("advance_schedule", &schedule_src, SCHEDULE_ENTRY, None)?;

        let rs = real_size(precision);
        let gaps_bytes = (n * bsz) as u64 * rs;
        let vel_bytes = ((n - 1) * bsz) as u64 * rs;
        let member_bytes = bsz as u64 * 4 * rs;
        let schedule_bytes = (MAX_STEPS_PER_SUBMIT as u64 + 1) * 2 * rs;
        ctx.check_storage_size("gaps", gaps_bytes)?;
        ctx.check_storage_size("velocities", vel_bytes)?;
        ctx.check_storage_size("step scratch", 3 * vel_bytes)?;

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
        let mut config = Vec::with_capacity(16);
        config.extend_from_slice(&(bsz as u32).to_le_bytes());
        config.extend_from_slice(&(n as u32).to_le_bytes());
        config.extend_from_slice(&real_bytes(&[plan.eps], precision));
        config.resize(16, 0);
        let dt = match plan.stepping {
            Stepping::Fixed { dt, .. } => dt,
            Stepping::Adaptive { .. } => unreachable!("refused above"),
        };

        let device = &ctx.device;
        let storage = wgpu::BufferUsages::STORAGE;
        let state_usage = storage | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST;
        let mut bytes_written = 0u64;
        let ((buffers, groups, other), error) = ctx.scoped(|| {
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
            let config = init("config", &config, wgpu::BufferUsages::UNIFORM);
            let gaps_a = init("gaps A", &real_bytes(&gaps0, precision), state_usage);
            let vel_a = init("velocities A", &real_bytes(&vel0, precision), state_usage);
            let gaps_b = empty("gaps B", gaps_bytes, state_usage);
            let vel_b = empty("velocities B", vel_bytes, state_usage);
            let members = empty(
                "members",
                member_bytes,
                storage | wgpu::BufferUsages::COPY_DST,
            );
            let scratch = empty("scratch", 3 * vel_bytes, storage);
            let ok = empty("ok", bsz as u64 * 4, storage);
            let status = empty("status", 2 * bsz as u64 * 4, state_usage);
            let schedule = empty(
                "schedule",
                schedule_bytes,
                storage | wgpu::BufferUsages::COPY_DST,
            );
            let dstar_buf = plan.repulsion.then(|| {
                let refs: Vec<&[f64]> = dstar.iter().map(|d| d.as_deref().unwrap()).collect();
                init("dstar", &real_bytes(&interleave(&refs), precision), storage)
            });
            let bonded_buf = plan.clusters.then(|| {
                let refs: Vec<&[bool]> = bonded.iter().map(|d| d.as_deref().unwrap()).collect();
                let flags: Vec<u32> = interleave(&refs).into_iter().map(u32::from).collect();
                init("bonded", bytemuck::cast_slice(&flags), storage)
            });
            let step_group = |gin: &wgpu::Buffer,
                              vin: &wgpu::Buffer,
                              gout: &wgpu::Buffer,
                              vout: &wgpu::Buffer,
                              label: &str| {
                let mut entries = vec![
                    (binding::CONFIG, &config),
                    (binding::GAPS_IN, gin),
                    (binding::VEL_IN, vin),
                    (binding::MEMBERS, &members),
                    (binding::GAPS_OUT, gout),
                    (binding::VEL_OUT, vout),
                    (binding::SCRATCH, &scratch),
                    (binding::OK, &ok),
                ];
                if let Some(d) = &dstar_buf {
                    entries.push((binding::DSTAR, d));
                }
                if let Some(b) = &bonded_buf {
                    entries.push((binding::BONDED, b));
                }
                let entries: Vec<wgpu::BindGroupEntry> = entries
                    .into_iter()
                    .map(|(binding, buffer)| wgpu::BindGroupEntry {
                        binding,
                        resource: buffer.as_entire_binding(),
                    })
                    .collect();
                device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some(label),
                    layout: &step_pipeline.get_bind_group_layout(0),
                    entries: &entries,
                })
            };
            let group_ab = step_group(&gaps_a, &vel_a, &gaps_b, &vel_b, "step A->B");
            let group_ba = step_group(&gaps_b, &vel_b, &gaps_a, &vel_a, "step B->A");
            let schedule_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("advance_schedule"),
                layout: &schedule_pipeline.get_bind_group_layout(0),
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: ok.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: members.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: status.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 3,
                        resource: schedule.as_entire_binding(),
                    },
                ],
            });
            let mut other = vec![config, scratch, ok];
            other.extend(dstar_buf);
            other.extend(bonded_buf);
            (
                ([gaps_a, gaps_b], [vel_a, vel_b], members, status, schedule),
                ([group_ab, group_ba], schedule_group),
                other,
            )
        });
        if let Some(message) = error {
            return Err(GpuError::Validation {
                label: "GpuSolver::new (buffers and bind groups)".to_string(),
                message,
            });
        }
        let (gaps, vel, members, status, schedule) = buffers;
        let (step_groups, schedule_group) = groups;
        let states = vec![
            MemberState {
                accepted: 0,
                rejected: 0,
                last_dt: dt,
                failed: None,
            };
            bsz
        ];
        let grid_x = grid_points(plan.grid);
        Ok(GpuSolver {
            ctx,
            plan,
            precision,
            dstar,
            bonded,
            grid_x,
            time_index: 0,
            current: 0,
            gaps,
            vel,
            members,
            status,
            schedule,
            step_pipeline,
            schedule_pipeline,
            step_groups,
            schedule_group,
            states,
            stats: GpuStats {
                bytes_written,
                ..GpuStats::default()
            },
            _other: other,
        })
    }

    pub fn plan(&self) -> &Plan {
        &self.plan
    }

    pub fn grid(&self) -> &[f64] {
        &self.grid_x
    }

    pub fn precision(&self) -> Precision {
        self.precision
    }

    /// Counters of the work done so far.
    pub fn stats(&self) -> GpuStats {
        self.stats
    }

    /// Advances to the next output time and returns every member's snapshot there, in member
    /// order (the first call returns the initial state); `Ok(None)` after the last output time.
    /// Same semantics as `CpuSolver::next_output`, except that a rejected step fails the
    /// member (see the module documentation).
    pub fn next_output(&mut self) -> Result<Option<Vec<Snapshot>>, GpuError> {
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
        let dt = match self.plan.stepping {
            Stepping::Fixed { dt, .. } => dt,
            Stepping::Adaptive { .. } => unreachable!("refused by new"),
        };
        let mut steps_taken = 0u64;
        let mut hf = None;
        if t_end > t_start {
            let (h, steps) = fixed_schedule(dt, t_start, t_end);
            hf = Some(h);
            for chunk in steps.chunks(MAX_STEPS_PER_SUBMIT) {
                self.run_chunk(chunk)?;
            }
            steps_taken = steps.len() as u64;
        }
        // Read back the state and the failure flags.
        let bsz = self.plan.members.len();
        let n = self.plan.particles;
        let rs = real_size(self.precision);
        let flags: Vec<u32> =
            bytemuck::pod_collect_to_vec(&self.read(Which::Status, bsz as u64 * 4)?);
        let gaps = reals_from_bytes(
            &self.read(Which::Gaps, (n * bsz) as u64 * rs)?,
            self.precision,
        );
        let vel = reals_from_bytes(
            &self.read(Which::Vel, ((n - 1) * bsz) as u64 * rs)?,
            self.precision,
        );
        let mut out = Vec::with_capacity(bsz);
        for (b, (state, &flag)) in self.states.iter_mut().zip(&flags).enumerate() {
            if state.failed.is_none() {
                if flag != 0 {
                    // Some step of this interval was inadmissible: fail honestly at its start.
                    state.failed = Some((GPU_REJECTION_REASON.to_string(), t_start));
                    state.rejected += 1;
                } else {
                    state.accepted += steps_taken;
                    if let Some(h) = hf {
                        state.last_dt = h;
                    }
                }
            }
            if state.failed.is_some() {
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

    /// Encodes the steps of `chunk` (at most [`MAX_STEPS_PER_SUBMIT`]) and submits them once.
    fn run_chunk(&mut self, chunk: &[(f64, f64)]) -> Result<(), GpuError> {
        let ctx = self.ctx;
        let precision = self.precision;
        let bsz = self.plan.members.len();
        // Schedule slots (t, h), plus the last one repeated (read after the last step).
        let mut slots = Vec::with_capacity(2 * (chunk.len() + 1));
        for &(t, h) in chunk.iter().chain(chunk.last()) {
            slots.push(t);
            slots.push(h);
        }
        let (t0, h0) = chunk[0];
        let mut params = Vec::with_capacity(4 * bsz);
        for p in &self.plan.members {
            params.extend_from_slice(&[p.mu, h0, t0, p.gamma]);
        }
        let slot_bytes = real_bytes(&slots, precision);
        let param_bytes = real_bytes(&params, precision);
        self.stats.bytes_written += (slot_bytes.len() + param_bytes.len()) as u64;
        let workgroups = (bsz as u32).div_ceil(STEP_WORKGROUP_SIZE);
        let mut current = self.current;
        let ((), error) = ctx.scoped(|| {
            ctx.queue.write_buffer(&self.schedule, 0, &slot_bytes);
            ctx.queue.write_buffer(&self.members, 0, &param_bytes);
            let mut encoder = ctx
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("fixed steps"),
                });
            // Step cursors back to 0 (the failure flags stay).
            encoder.clear_buffer(&self.status, bsz as u64 * 4, Some(bsz as u64 * 4));
            {
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("fixed steps"),
                    timestamp_writes: None,
                });
                for _ in chunk {
                    pass.set_pipeline(&self.step_pipeline);
                    pass.set_bind_group(0, &self.step_groups[current], &[]);
                    pass.dispatch_workgroups(workgroups, 1, 1);
                    pass.set_pipeline(&self.schedule_pipeline);
                    pass.set_bind_group(0, &self.schedule_group, &[]);
                    pass.dispatch_workgroups(workgroups, 1, 1);
                    current = 1 - current;
                }
            }
            ctx.queue.submit([encoder.finish()]);
        });
        if let Some(message) = error {
            return Err(GpuError::Validation {
                label: "GpuSolver fixed steps".to_string(),
                message,
            });
        }
        self.current = current;
        self.stats.steps += chunk.len() as u64;
        self.stats.dispatches += 2 * chunk.len() as u64;
        self.stats.submits += 1;
        Ok(())
    }

    fn read(&mut self, which: Which, bytes: u64) -> Result<Vec<u8>, GpuError> {
        let buffer = match which {
            Which::Gaps => &self.gaps[self.current],
            Which::Vel => &self.vel[self.current],
            Which::Status => &self.status,
        };
        let data = self.ctx.read_buffer(buffer, bytes)?;
        self.stats.readbacks += 1;
        self.stats.bytes_read += bytes;
        Ok(data)
    }

    /// Every member's bookkeeping, in member order (like `CpuSolver::reports`). Steps are
    /// counted per output interval: a member that failed during an interval has the accepted
    /// steps of the intervals before it and one rejected step.
    pub fn reports(&self) -> Vec<MemberReport> {
        self.states
            .iter()
            .enumerate()
            .map(|(m, s)| MemberReport {
                index: m,
                mu: self.plan.members[m].mu,
                gamma: self.plan.members[m].gamma,
                status: match &s.failed {
                    None => MemberStatus::Ok,
                    Some((reason, time)) => MemberStatus::Failed {
                        reason: reason.clone(),
                        time: *time,
                    },
                },
                steps_accepted: s.accepted,
                steps_rejected: s.rejected,
                last_dt: s.last_dt,
            })
            .collect()
    }
}

#[derive(Clone, Copy)]
enum Which {
    Gaps,
    Vel,
    Status,
}
