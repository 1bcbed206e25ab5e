//! The step kernel's buffers (see the binding table in the header of `shaders/step.wgsl`): their
//! sizes, the bytes uploaded at construction, and their bind group.

use wgpu::util::DeviceExt;

use super::context::GpuContext;
use super::kernel::{binding, SchemeSpec};
use super::partitioned::{PartsUniform, Segments};
use super::wgsl_types::{controls_bytes, real_bytes, real_size, ControlF64, CONFIG_BUFFER_SIZE};
use crate::backend::error::GpuError;
use crate::backend::layout::interleave;
use crate::backend::shared::gaps::{GAP_FLOOR, GAP_FLOOR_F32};
use crate::backend::Precision;
use crate::model::chain::{stored_gap, Chain};
use crate::model::plan::Plan;

/// Byte sizes of the per-element buffers of a batch of B members of N particles.
#[derive(Debug, Clone, Copy)]
pub struct BufferSizes {
    /// Buffer sets of gaps and velocities: state and candidate, plus with the extrapolation
    /// tableau two for the states between substeps and one per row.
    pub sets: u64,
    /// One set of gaps (N·B reals).
    pub gaps: u64,
    /// One set of velocities ((N-1)·B reals).
    pub velocities: u64,
}

impl BufferSizes {
    pub fn of(particles: usize, members: usize, scheme: SchemeSpec, precision: Precision) -> Self {
        let rs = real_size(precision);
        BufferSizes {
            sets: if scheme.tableau() {
                4 + u64::from(scheme.rows)
            } else {
                2
            },
            gaps: (particles * members) as u64 * rs,
            velocities: ((particles - 1) * members) as u64 * rs,
        }
    }

    /// The Thomas solve's scratch: w, ls, ys, the forces and the exact Jacobian's factors k,
    /// one set of velocities each.
    pub fn scratch(&self) -> u64 {
        5 * self.velocities
    }

    /// Fails with [`GpuError::BufferTooLarge`] when a storage buffer exceeds the device limits.
    pub fn check(&self, ctx: &GpuContext) -> Result<(), GpuError> {
        ctx.check_storage_size(
            "gap sets (state, candidate, substeps and tableau rows)",
            self.sets * self.gaps,
        )?;
        ctx.check_storage_size("velocity sets", self.sets * self.velocities)?;
        ctx.check_storage_size("Thomas scratch", self.scratch())
    }
}

/// What is uploaded at construction, as bytes of the kernel's types, elements interleaved
/// (element i of member b at `i·B + b`).
pub struct InitialData {
    pub sizes: BufferSizes,
    /// The initial gaps in set 0, the other sets zero.
    pub gap_sets: Vec<u8>,
    /// The initial velocities in set 0, the other sets zero.
    pub vel_sets: Vec<u8>,
    /// `array<Param>`: mu, gamma and the total gap per member.
    pub params: Vec<u8>,
    /// `array<Control>`: every member at its initial control.
    pub controls: Vec<u8>,
    /// d* per gap (repulsion only).
    pub dstar: Option<Vec<u8>>,
    /// Bonded flags per gap as u32 (clusters only).
    pub bonded: Option<Vec<u8>>,
    /// The forcing's symbolic parameter values, member-major (only when it has some).
    pub forcing_params: Option<Vec<u8>>,
    /// The partitioned kernel's buffers (only with it).
    pub parts: Option<PartsData>,
}

/// What the partitioned kernel's buffers hold at construction (shaders/partitioned.wgsl).
pub struct PartsData {
    /// `Parts` (uniform).
    pub uniform: PartsUniform,
    /// Bytes of `array<PState>` and `array<Seg>` (zeroed).
    pub pstate_bytes: u64,
    pub segs_bytes: u64,
    /// Per member the number of bonded gaps from the left wall, as u32 (clusters only).
    pub glued: Option<Vec<u8>>,
}

impl PartsData {
    /// The data for `segments`, the structs' sizes taken from the kernel's module.
    pub fn new(
        segments: Segments,
        members: usize,
        pstate_size: u64,
        seg_size: u64,
        bonded: &[Option<Vec<bool>>],
        clusters: bool,
    ) -> PartsData {
        let glued = clusters.then(|| {
            let counts: Vec<u32> = bonded
                .iter()
                .map(|b| {
                    b.as_deref()
                        .map_or(0, |b| b.iter().take_while(|&&x| x).count() as u32)
                })
                .collect();
            bytemuck::cast_slice(&counts).to_vec()
        });
        PartsData {
            uniform: segments.into(),
            pstate_bytes: pstate_size * members as u64,
            segs_bytes: seg_size * members as u64 * u64::from(segments.segments),
            glued,
        }
    }
}

impl InitialData {
    /// `dstar` and `bonded` are the per-member values the solver keeps for the observables
    /// (present iff the plan has repulsion, respectively clusters).
    pub fn new(
        plan: &Plan,
        chains: &[Chain],
        dstar: &[Option<Vec<f64>>],
        bonded: &[Option<Vec<bool>>],
        control: ControlF64,
        sizes: BufferSizes,
        precision: Precision,
    ) -> Self {
        // The stored form (`stored_gap`): gaps below the kernel's GAP_FLOOR as ln d.
        let floor = match precision {
            Precision::F64 => GAP_FLOOR,
            Precision::F32 => GAP_FLOOR_F32,
        };
        let stored: Vec<Vec<f64>> = chains
            .iter()
            .map(|c| {
                c.gaps
                    .iter()
                    .map(|&d| stored_gap::encode(d, floor))
                    .collect()
            })
            .collect();
        let gaps: Vec<&[f64]> = stored.iter().map(|g| g.as_slice()).collect();
        let velocities: Vec<&[f64]> = chains.iter().map(|c| c.velocities.as_slice()).collect();
        let mut gap_sets = real_bytes(&interleave(&gaps), precision);
        gap_sets.resize((sizes.sets * sizes.gaps) as usize, 0);
        let mut vel_sets = real_bytes(&interleave(&velocities), precision);
        vel_sets.resize((sizes.sets * sizes.velocities) as usize, 0);
        let params: Vec<f64> = plan
            .members
            .iter()
            .zip(chains)
            .flat_map(|(p, c)| [p.mu, p.gamma, c.gaps.iter().sum::<f64>()])
            .collect();
        let dstar = plan.repulsion.then(|| {
            let refs: Vec<&[f64]> = dstar.iter().map(|d| d.as_deref().unwrap_or(&[])).collect();
            real_bytes(&interleave(&refs), precision)
        });
        let bonded = plan.clusters.then(|| {
            let refs: Vec<&[bool]> = bonded.iter().map(|d| d.as_deref().unwrap_or(&[])).collect();
            let flags: Vec<u32> = interleave(&refs).into_iter().map(u32::from).collect();
            bytemuck::cast_slice(&flags).to_vec()
        });
        let forcing_params = plan
            .forcing
            .as_ref()
            .filter(|f| f.expr.symbolic_count() > 0)
            .map(|f| real_bytes(&f.params, precision));
        InitialData {
            sizes,
            gap_sets,
            vel_sets,
            params: real_bytes(&params, precision),
            controls: controls_bytes(&vec![control; plan.members.len()], precision),
            dstar,
            bonded,
            forcing_params,
            parts: None,
        }
    }
}

/// Every buffer of the step kernel (owned here, so they live as long as the bind group).
pub struct StepBuffers {
    /// Uniform `Config`, rewritten per output interval.
    pub config: wgpu::Buffer,
    gap_sets: wgpu::Buffer,
    vel_sets: wgpu::Buffer,
    params: wgpu::Buffer,
    /// Read back at output times.
    pub controls: wgpu::Buffer,
    scratch: wgpu::Buffer,
    /// Members still running, cleared before the last dispatch of a submit and read back after.
    pub running: wgpu::Buffer,
    /// Each member's state copied by `gather`, read back at output times.
    pub gathered_gaps: wgpu::Buffer,
    pub gathered_vel: wgpu::Buffer,
    dstar: Option<wgpu::Buffer>,
    bonded: Option<wgpu::Buffer>,
    forcing_params: Option<wgpu::Buffer>,
    parts: Option<PartBuffers>,
}

/// The partitioned kernel's own buffers (bindings 12 to 15).
struct PartBuffers {
    uniform: wgpu::Buffer,
    pstate: wgpu::Buffer,
    segs: wgpu::Buffer,
    glued: Option<wgpu::Buffer>,
}

/// The step kernel's buffers bound in group 0.
pub struct BoundBuffers {
    pub buffers: StepBuffers,
    pub group: wgpu::BindGroup,
    pub pipeline_layout: wgpu::PipelineLayout,
    /// Bytes uploaded.
    pub bytes_written: u64,
}

impl BoundBuffers {
    /// Creates and fills the buffers and binds them.
    pub fn create(ctx: &GpuContext, initial: &InitialData) -> Result<BoundBuffers, GpuError> {
        let (bound, error) = ctx.scoped(|| {
            let (buffers, bytes_written) = StepBuffers::create(&ctx.device, initial);
            let (group, pipeline_layout) = buffers.bind(&ctx.device);
            BoundBuffers {
                buffers,
                group,
                pipeline_layout,
                bytes_written,
            }
        });
        match error {
            Some(message) => Err(GpuError::Validation {
                label: "GpuSolver::new (buffers and bind groups)".to_string(),
                message,
            }),
            None => Ok(bound),
        }
    }
}

impl StepBuffers {
    /// The buffers and the bytes uploaded into them.
    fn create(device: &wgpu::Device, initial: &InitialData) -> (StepBuffers, u64) {
        let storage = wgpu::BufferUsages::STORAGE;
        let readable = storage | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST;
        let mut bytes_written = 0u64;
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
        let sizes = initial.sizes;
        let buffers = StepBuffers {
            config: empty(
                "config",
                CONFIG_BUFFER_SIZE,
                wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            ),
            gap_sets: init("gap sets", &initial.gap_sets, storage),
            vel_sets: init("velocity sets", &initial.vel_sets, storage),
            params: init("member parameters", &initial.params, storage),
            controls: init("controls", &initial.controls, readable),
            scratch: empty("scratch", sizes.scratch(), storage),
            running: empty("running", 4, readable),
            gathered_gaps: empty("gathered gaps", sizes.gaps, readable),
            gathered_vel: empty("gathered velocities", sizes.velocities, readable),
            dstar: initial.dstar.as_ref().map(|d| init("dstar", d, storage)),
            bonded: initial.bonded.as_ref().map(|b| init("bonded", b, storage)),
            forcing_params: initial
                .forcing_params
                .as_ref()
                .map(|f| init("forcing parameters", f, storage)),
            parts: initial.parts.as_ref().map(|p| PartBuffers {
                uniform: init(
                    "parts",
                    bytemuck::bytes_of(&p.uniform),
                    wgpu::BufferUsages::UNIFORM,
                ),
                pstate: empty("partitioned member state", p.pstate_bytes, storage),
                segs: empty("segments", p.segs_bytes, storage),
                glued: p.glued.as_ref().map(|g| init("glued", g, storage)),
            }),
        };
        (buffers, bytes_written)
    }

    /// Binding number, buffer and binding type of every buffer, as declared in step.wgsl.
    fn bindings(&self) -> Vec<(u32, &wgpu::Buffer, wgpu::BufferBindingType)> {
        use wgpu::BufferBindingType::{Storage, Uniform};
        let read_write = Storage { read_only: false };
        let read_only = Storage { read_only: true };
        let mut bindings = vec![
            (binding::CONFIG, &self.config, Uniform),
            (binding::GAP_SETS, &self.gap_sets, read_write),
            (binding::VEL_SETS, &self.vel_sets, read_write),
            (binding::PARAMS, &self.params, read_only),
            (binding::CONTROLS, &self.controls, read_write),
            (binding::SCRATCH, &self.scratch, read_write),
            (binding::RUNNING, &self.running, read_write),
            (binding::GATHERED_GAPS, &self.gathered_gaps, read_write),
            (binding::GATHERED_VEL, &self.gathered_vel, read_write),
        ];
        if let Some(d) = &self.dstar {
            bindings.push((binding::DSTAR, d, read_only));
        }
        if let Some(b) = &self.bonded {
            bindings.push((binding::BONDED, b, read_only));
        }
        if let Some(f) = &self.forcing_params {
            bindings.push((binding::FORCING_PARAMS, f, read_only));
        }
        if let Some(p) = &self.parts {
            bindings.push((binding::PARTS, &p.uniform, Uniform));
            bindings.push((binding::PSTATE, &p.pstate, read_write));
            bindings.push((binding::SEGS, &p.segs, read_write));
            if let Some(g) = &p.glued {
                bindings.push((binding::GLUED, g, read_only));
            }
        }
        bindings
    }

    /// The bind group of all buffers and the pipeline layout of the kernel's entry points.
    fn bind(&self, device: &wgpu::Device) -> (wgpu::BindGroup, wgpu::PipelineLayout) {
        let bindings = self.bindings();
        let layout_entries: Vec<wgpu::BindGroupLayoutEntry> = bindings
            .iter()
            .map(|&(binding, _, ty)| wgpu::BindGroupLayoutEntry {
                binding,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: wgpu::BindingType::Buffer {
                    ty,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            })
            .collect();
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("roughlub step"),
            entries: &layout_entries,
        });
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("roughlub step"),
            layout: &layout,
            entries: &bindings
                .iter()
                .map(|&(binding, buffer, _)| wgpu::BindGroupEntry {
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
        (group, pipeline_layout)
    }
}
