//! The generated WGSL step kernel (`shaders/step.wgsl` via `roughlub::gpu::kernel`):
//! - CPU only: every combination of precision × repulsion × clusters × forcing parses and
//!   validates with naga, and absent terms leave no code behind;
//! - GPU (through `acquire_for_tests(true)`, skipped without an f64 adapter unless
//!   `ROUGHLUB_REQUIRE_GPU=1`): one f64 step of a small batch against the CPU kernel
//!   `roughlub::cpu::step::euler_step::<1>` run per member.

use roughlub::cpu::step::{euler_step, Gamma, Scratch, Terms};
use roughlub::expr::Expr;
use roughlub::gpu::kernel::{
    binding, generate_step_wgsl, GammaSpec, KernelSpec, STEP_ENTRY, STEP_WORKGROUP_SIZE,
};
use roughlub::gpu::{acquire_for_tests, validate_wgsl, GpuContext};
use roughlub::plan::{Forcing, Power};
use roughlub::quadrature::GaussLegendre;
use roughlub::scene::Precision;
use wgpu::util::DeviceExt;

const FORCING: &str = "0.3*sin(2*pi*x)*cos(3*t)";

fn forcing_spec(points: usize) -> (Expr, Vec<f64>, Vec<f64>) {
    let rule = GaussLegendre::new(points);
    (Expr::parse(FORCING).unwrap(), rule.nodes, rule.weights)
}

#[test]
fn every_variant_validates_and_omits_absent_terms() {
    let repulsions = [
        None,
        Some(GammaSpec::Integer(1)),
        Some(GammaSpec::Integer(2)),
        Some(GammaSpec::Integer(7)),
        Some(GammaSpec::PerMember),
    ];
    for precision in [Precision::F32, Precision::F64] {
        for repulsion in repulsions {
            for clusters in [false, true] {
                for forced in [false, true] {
                    let spec = KernelSpec {
                        precision,
                        repulsion,
                        clusters,
                        forcing: forced.then(|| forcing_spec(3)),
                    };
                    let label = format!("{spec:?}");
                    let src = generate_step_wgsl(&spec);
                    if let Err(e) = validate_wgsl("step.wgsl", &src) {
                        panic!("{label}: {e}\n{src}");
                    }
                    assert!(src.contains("fn euler_step("), "{label}");
                    assert!(!src.contains("//@"), "{label}: leftover marker");
                    // The code without its comments.
                    let src: String = src
                        .lines()
                        .map(|l| l.split("//").next().unwrap())
                        .collect::<Vec<_>>()
                        .join("\n");
                    assert_eq!(src.contains("dstar"), repulsion.is_some(), "{label}");
                    assert_eq!(src.contains("fn power("), repulsion.is_some(), "{label}");
                    assert_eq!(src.contains("bonded"), clusters, "{label}");
                    assert_eq!(src.contains("excess_carry"), clusters, "{label}");
                    assert_eq!(src.contains("particle_force"), forced, "{label}");
                    assert_eq!(src.contains("fn forcing("), forced, "{label}");
                    let real = match precision {
                        Precision::F32 => "alias real = f32;",
                        Precision::F64 => "alias real = f64;",
                    };
                    assert!(src.contains(real), "{label}");
                    // The f64 library only where something calls it.
                    let needs_lib = precision == Precision::F64
                        && (forced || repulsion == Some(GammaSpec::PerMember));
                    assert_eq!(src.contains("fn exp_f64("), needs_lib, "{label}");
                }
            }
        }
    }
}

#[test]
fn integer_power_is_the_square_and_multiply_chain() {
    let spec = |n| KernelSpec {
        precision: Precision::F64,
        repulsion: Some(GammaSpec::Integer(n)),
        clusters: false,
        forcing: None,
    };
    // 7 = 0b111: result = r; base = r^2; result *= base; base = r^4; result *= base.
    let src = generate_step_wgsl(&spec(7));
    assert_eq!(src.matches("base = base * base;").count(), 2);
    assert_eq!(src.matches("result = result * base;").count(), 2);
    let src = generate_step_wgsl(&spec(1));
    assert_eq!(src.matches("base = base * base;").count(), 0);
    assert!(validate_wgsl("step0", &generate_step_wgsl(&spec(0))).is_ok());
}

// ---------------------------------------------------------------------------------------------
// GPU against CPU

/// Small deterministic generator (xorshift64*), uniform in [0, 1).
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let x = self.0.wrapping_mul(0x2545_f491_4f6c_dd1d);
        (x >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.next()
    }
}

struct Batch {
    batch: usize,
    particles: usize,
    eps: f64,
    gaps: Vec<f64>,
    vel: Vec<f64>,
    /// mu, h, t, gamma per member.
    members: Vec<[f64; 4]>,
    dstar: Vec<f64>,
    bonded: Vec<bool>,
}

fn random_batch(seed: u64, batch: usize, particles: usize, clusters: bool) -> Batch {
    let mut rng = Rng(seed);
    let n = particles;
    let gammas = [2.0, 3.5, 7.0, 1.3, 1.0, 12.0, 0.7, 4.0];
    let members: Vec<[f64; 4]> = (0..batch)
        .map(|b| {
            [
                rng.range(0.5, 1.5),
                rng.range(1e-4, 2e-3),
                rng.range(0.0, 2.0),
                gammas[b % gammas.len()],
            ]
        })
        .collect();
    let mut members: Vec<[f64; 4]> = members;
    // A step far too large for member 3: some gap shrinks below half, the step is rejected.
    members[3][0] = 1e-6;
    members[3][1] = 0.5;
    let mut bonded = vec![false; n * batch];
    if clusters {
        for b in 0..batch {
            // A cluster pinned to the left wall for odd members, and two inner clusters.
            if b % 2 == 1 {
                bonded[b] = true;
                bonded[batch + b] = true;
            }
            for i in [5 + b % 3, 6 + b % 3, 17, n - 1] {
                bonded[i * batch + b] = true;
            }
        }
    }
    let gaps = (0..n * batch)
        .map(|k| {
            if bonded[k] {
                0.0
            } else {
                rng.range(0.005, 0.2)
            }
        })
        .collect();
    let vel = (0..(n - 1) * batch).map(|_| rng.range(-1.0, 1.0)).collect();
    let dstar = (0..n * batch).map(|_| rng.range(0.01, 0.1)).collect();
    Batch {
        batch,
        particles,
        eps: 0.05,
        gaps,
        vel,
        members,
        dstar,
        bonded,
    }
}

struct StepResult {
    gaps: Vec<f64>,
    vel: Vec<f64>,
    ok: Vec<bool>,
}

/// The CPU kernel per member (L = 1), results interleaved like the GPU's.
fn cpu_step(spec: &KernelSpec, data: &Batch) -> StepResult {
    let (bsz, n) = (data.batch, data.particles);
    let forcing = spec.forcing.as_ref().map(|(expr, nodes, weights)| Forcing {
        expr: expr.clone(),
        rule: GaussLegendre {
            nodes: nodes.clone(),
            weights: weights.clone(),
        },
    });
    let mut out = StepResult {
        gaps: vec![0.0; n * bsz],
        vel: vec![0.0; (n - 1) * bsz],
        ok: vec![false; bsz],
    };
    for b in 0..bsz {
        let pick = |v: &[f64], len: usize| (0..len).map(|i| v[i * bsz + b]).collect::<Vec<f64>>();
        let gaps = pick(&data.gaps, n);
        let vel = pick(&data.vel, n - 1);
        let dstar = pick(&data.dstar, n);
        let bonded: Vec<bool> = (0..n).map(|i| data.bonded[i * bsz + b]).collect();
        let [mu, h, t, gamma] = data.members[b];
        let terms = Terms::<1> {
            eps: data.eps,
            mu: [mu],
            repulsion: spec.repulsion.map(|g| {
                let gamma = match g {
                    GammaSpec::Integer(k) => Gamma::Uniform(Power::Integer(k)),
                    GammaSpec::PerMember => Gamma::PerLane([gamma]),
                };
                (dstar.as_slice(), gamma)
            }),
            bonded: spec.clusters.then_some(bonded.as_slice()),
            forcing: forcing.as_ref(),
        };
        let mut gaps_out = vec![0.0; n];
        let mut vel_out = vec![0.0; n - 1];
        let mut scratch = Scratch::new(n, 1);
        let ok = euler_step::<1>(
            &terms,
            n,
            &[t],
            &[h],
            &gaps,
            &vel,
            &mut gaps_out,
            &mut vel_out,
            &mut scratch,
        );
        for (i, d) in gaps_out.iter().enumerate() {
            out.gaps[i * bsz + b] = *d;
        }
        for (i, u) in vel_out.iter().enumerate() {
            out.vel[i * bsz + b] = *u;
        }
        out.ok[b] = ok[0];
    }
    out
}

fn gpu_step(ctx: &GpuContext, spec: &KernelSpec, data: &Batch) -> StepResult {
    let (bsz, n) = (data.batch, data.particles);
    let src = generate_step_wgsl(spec);
    let pipeline = ctx
        .compute_pipeline("step", &src, STEP_ENTRY, None)
        .unwrap_or_else(|e| panic!("{e}"));
    let device = &ctx.device;
    let init = |label: &str, bytes: &[u8], usage: wgpu::BufferUsages| {
        device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: bytes,
            usage,
        })
    };
    let storage = wgpu::BufferUsages::STORAGE;
    let output = |label: &str, bytes: u64| {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: bytes.max(4),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        })
    };
    let mut config = Vec::new();
    config.extend_from_slice(&(bsz as u32).to_le_bytes());
    config.extend_from_slice(&(n as u32).to_le_bytes());
    config.extend_from_slice(&data.eps.to_le_bytes());
    let config = init("config", &config, wgpu::BufferUsages::UNIFORM);
    let gaps_in = init("gaps_in", bytemuck::cast_slice(&data.gaps), storage);
    let vel_in = init("vel_in", bytemuck::cast_slice(&data.vel), storage);
    let members = init("members", bytemuck::cast_slice(&data.members), storage);
    let dstar = init("dstar", bytemuck::cast_slice(&data.dstar), storage);
    let bonded: Vec<u32> = data.bonded.iter().map(|&x| x as u32).collect();
    let bonded = init("bonded", bytemuck::cast_slice(&bonded), storage);
    let gaps_bytes = (n * bsz * 8) as u64;
    let vel_bytes = ((n - 1) * bsz * 8) as u64;
    let gaps_out = output("gaps_out", gaps_bytes);
    let vel_out = output("vel_out", vel_bytes);
    let scratch = output("scratch", 3 * vel_bytes);
    let ok = output("ok", (bsz * 4) as u64);

    let mut entries = vec![
        (binding::CONFIG, &config),
        (binding::GAPS_IN, &gaps_in),
        (binding::VEL_IN, &vel_in),
        (binding::MEMBERS, &members),
        (binding::GAPS_OUT, &gaps_out),
        (binding::VEL_OUT, &vel_out),
        (binding::SCRATCH, &scratch),
        (binding::OK, &ok),
    ];
    if spec.repulsion.is_some() {
        entries.push((binding::DSTAR, &dstar));
    }
    if spec.clusters {
        entries.push((binding::BONDED, &bonded));
    }
    let entries: Vec<wgpu::BindGroupEntry> = entries
        .into_iter()
        .map(|(binding, buffer)| wgpu::BindGroupEntry {
            binding,
            resource: buffer.as_entire_binding(),
        })
        .collect();
    let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("step"),
        layout: &pipeline.get_bind_group_layout(0),
        entries: &entries,
    });
    let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
        label: Some("step"),
    });
    {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("step"),
            timestamp_writes: None,
        });
        pass.set_pipeline(&pipeline);
        pass.set_bind_group(0, &bind_group, &[]);
        pass.dispatch_workgroups((bsz as u32).div_ceil(STEP_WORKGROUP_SIZE), 1, 1);
    }
    ctx.queue.submit([encoder.finish()]);
    let errors = ctx.take_uncaptured_errors();
    assert!(errors.is_empty(), "{errors:?}");
    let read_f64 = |buffer: &wgpu::Buffer, bytes: u64| -> Vec<f64> {
        bytemuck::pod_collect_to_vec(&ctx.read_buffer(buffer, bytes).unwrap())
    };
    let ok: Vec<u32> =
        bytemuck::pod_collect_to_vec(&ctx.read_buffer(&ok, (bsz * 4) as u64).unwrap());
    StepResult {
        gaps: read_f64(&gaps_out, gaps_bytes),
        vel: read_f64(&vel_out, vel_bytes),
        ok: ok.iter().map(|&x| x == 1).collect(),
    }
}

/// Largest |gpu - cpu| / max(|cpu|, floor), floor relative to the largest |cpu| of the member
/// (so that velocities that happen to be near zero are not judged by their own tiny size).
fn max_rel_error(gpu: &[f64], cpu: &[f64], batch: usize) -> f64 {
    let mut worst = 0.0f64;
    for b in 0..batch {
        let scale = cpu
            .iter()
            .skip(b)
            .step_by(batch)
            .fold(0.0f64, |m, x| m.max(x.abs()));
        for k in (b..cpu.len()).step_by(batch) {
            let err = (gpu[k] - cpu[k]).abs();
            if err == 0.0 {
                continue;
            }
            worst = worst.max(err / cpu[k].abs().max(1e-3 * scale));
        }
    }
    worst
}

#[test]
fn gpu_f64_step_matches_cpu() {
    let Some(ctx) = acquire_for_tests(true) else {
        return;
    };
    let variants = [
        (None, false, false),
        (Some(GammaSpec::Integer(2)), false, false),
        (Some(GammaSpec::Integer(7)), false, true),
        (Some(GammaSpec::PerMember), false, false),
        (Some(GammaSpec::PerMember), false, true),
        (None, true, false),
        (Some(GammaSpec::Integer(3)), true, true),
        (Some(GammaSpec::PerMember), true, true),
    ];
    for (k, (repulsion, clusters, forced)) in variants.into_iter().enumerate() {
        let spec = KernelSpec {
            precision: Precision::F64,
            repulsion,
            clusters,
            forcing: forced.then(|| forcing_spec(4)),
        };
        let data = random_batch(0x9e37_79b9_7f4a_7c15 ^ k as u64, 8, 30, clusters);
        let cpu = cpu_step(&spec, &data);
        let gpu = gpu_step(&ctx, &spec, &data);
        let gap_err = max_rel_error(&gpu.gaps, &cpu.gaps, data.batch);
        let vel_err = max_rel_error(&gpu.vel, &cpu.vel, data.batch);
        eprintln!(
            "{repulsion:?} clusters={clusters} forcing={forced}: gaps {gap_err:.2e}, velocities {vel_err:.2e}, ok cpu {:?} gpu {:?}",
            cpu.ok, gpu.ok
        );
        assert_eq!(gpu.ok, cpu.ok, "{spec:?}");
        assert!(cpu.ok.iter().any(|&x| x), "test data: no admissible step");
        assert!(!cpu.ok[3], "test data: member 3 should be rejected");
        assert!(cpu.gaps.iter().zip(&data.gaps).any(|(a, b)| a != b));
        assert!(gap_err <= 1e-12, "{spec:?}: gaps {gap_err:e}");
        assert!(vel_err <= 1e-12, "{spec:?}: velocities {vel_err:e}");
        if clusters {
            // Bonded gaps stay exactly closed.
            for (k, &b) in data.bonded.iter().enumerate() {
                if b {
                    assert_eq!(gpu.gaps[k], 0.0, "bonded gap {k}");
                }
            }
        }
    }
}
