//! Particle-steps per second (members × particles × steps / wall time) of the GPU solver
//! (`roughlub::backend::gpu::solver::GpuSolver`) on whatever wgpu adapter is found: order 1, fixed
//! steps, case-1 data (rho0 = 0.7, u0 = 0.5 sin(2 pi x), rho* = 0.7), f32 and f64.
//!
//! Group `gpu_order1_fixed_integer_gamma`: integer gamma 2 with repulsion, no forcing, for
//! (members, N) = (256, 1000), (4096, 100), (1, 10^5), (1, 10^6), (4, 10^6). The kernel is the
//! solver's own choice: one invocation per member for the first two, the partitioned kernel
//! (`shaders/partitioned.wgsl`: fewer than 64 members with N >= 2^14, and any N beyond lavapipe's
//! loop budget) for the others. Each row prints the kernel and the bytes it moves per
//! particle-step ([`bytes_per_particle_step`], counted from the kernels' loads and stores).
//!
//! Group `partition_threshold`: (1, 8000) and (4, 8000) in f64, one invocation per member
//! against the partitioned kernel (default segments), where both run on lavapipe.
//!
//! Group `specialisation`: (256, 1000) in f64, the base scene against one change at a time:
//! a per-member gamma kernel (gamma 2 everywhere but one member at 3, so the kernel reads gamma
//! per member), a forcing term present but zero ("0*x": the Gauss–Legendre sum is executed),
//! and no repulsion (no d*). The time ratios say what each specialisation of the kernel saves.
//!
//! The solver (buffers, pipelines) is built and its t = 0 output taken outside the timed part;
//! the timed part is one `next_output()` over an interval of fixed steps (64, fewer for the
//! largest batches: [`steps_for`]): the submits of trial steps, the running-counter read-backs,
//! the gather, the read-backs of controls, gaps and velocities, and the host-side observables.
//!
//! Without an adapter the benchmarks are skipped; a configuration the adapter cannot run is
//! reported and skipped.

use std::time::Duration;

use criterion::{
    criterion_group, criterion_main, BatchSize, BenchmarkGroup, BenchmarkId, Criterion,
    SamplingMode, Throughput,
};
use roughlub::backend::gpu::solver::{GpuPartition, GpuSolver, GpuStats};
use roughlub::backend::gpu::{GpuContext, GpuError};
use roughlub::backend::{BatchSolver, Precision};
use roughlub::error::{Error, Result};
use roughlub::expr::Expr;
use roughlub::model::chain::Chain;
use roughlub::model::params::{MemberParams, OutputFields, Stepping};
use roughlub::model::plan::{Forcing, Plan};
use roughlub::model::quadrature::GaussLegendre;
use roughlub::scene::initial::chain_from_profiles;

/// Fixed steps per timed interval up to 2^20 elements: exactly one submit of 64 `advance`
/// dispatches of one invocation per member (one trial step per member per dispatch), so no
/// dispatch of the submit is idle.
const STEPS: usize = 64;
const DT: f64 = 1e-4;

/// Steps per timed interval for B·N elements: [`STEPS`], or about 2^24 particle-steps for larger
/// batches (4 to 64), so that an iteration of (4, 10^6) stays a few seconds on lavapipe.
fn steps_for(members: usize, particles: usize) -> usize {
    let elements = members * particles;
    if elements <= 1 << 20 {
        STEPS
    } else {
        ((1usize << 24) / elements).clamp(4, STEPS)
    }
}

/// Bytes each kernel moves per particle and Euler step, counted from its loads and stores of
/// per-element buffers (one real each; per-segment and per-member values are left out: a few
/// per 256 rows) for the benchmarked scene (order 1, fixed steps, repulsion, no forcing, no
/// clusters). Keep in sync with the kernels:
/// - one invocation per member (shaders/step.wgsl, `euler` and `conclude`): the forward sweep
///   reads gap, d*, u and writes w, ls, ys (3 + 3); the back sweep reads gap, w, ls, ys and writes
///   u, gap and the rate (4 + 3); the projection reads gap, d*, u and writes the gap (3 + 1):
///   17 reals.
/// - partitioned (shaders/partitioned.wgsl): `p_forward` reads gap, d*, u (3); `p_solve` sweeps
///   forward again (3 + 3) and back (4 + 2: no rate kept, the fix-up is in place); `p_project`
///   as above (3 + 1): 19 reals.
fn bytes_per_particle_step(segments: u64, precision: Precision) -> u64 {
    let reals = if segments > 0 { 19 } else { 17 };
    let size = match precision {
        Precision::F32 => 4,
        Precision::F64 => 8,
    };
    reals * size
}

/// One benchmarked scene.
#[derive(Clone, Copy, Debug)]
struct Case {
    members: usize,
    particles: usize,
    steps: usize,
    /// Repulsion (d* from rho* = 0.7) or none (no d*, no G).
    repulsion: bool,
    /// Forcing "0*x" (the quadrature runs, the force is zero) or none.
    forcing: bool,
    /// Member 0 gets gamma = 3 instead of 2: the kernel reads gamma per member.
    per_member_gamma: bool,
    /// Which kernel.
    partition: GpuPartition,
}

impl Case {
    fn base(members: usize, particles: usize) -> Case {
        Case {
            members,
            particles,
            steps: steps_for(members, particles),
            repulsion: true,
            forcing: false,
            per_member_gamma: false,
            partition: GpuPartition::Auto,
        }
    }

    fn particle_steps(&self) -> u64 {
        (self.members * self.particles * self.steps) as u64
    }

    fn size_label(&self) -> String {
        format!("B{}_N{}", self.members, self.particles)
    }
}

fn precision_label(p: Precision) -> &'static str {
    match p {
        Precision::F32 => "f32",
        Precision::F64 => "f64",
    }
}

/// Case 1 of the paper: rho0 = 0.7, u0 = 0.5 sin(2 pi x), rho* = 0.7 (or no roughness).
fn chain(case: &Case) -> Chain {
    let rho_star = Expr::parse("0.7").unwrap();
    chain_from_profiles(
        case.particles,
        &Expr::parse("0.7").unwrap(),
        &Expr::parse("0.5*sin(2*pi*x)").unwrap(),
        case.repulsion.then_some(&rho_star),
    )
    .unwrap()
}

/// The plan as in `benches/cpu_solver.rs`: order 1, fixed steps, outputs at 0 and after
/// `steps` steps, no output fields.
fn plan(case: &Case, eps: f64) -> Plan {
    let mut members = vec![
        MemberParams {
            mu: 0.01,
            gamma: 2.0
        };
        case.members
    ];
    if case.per_member_gamma {
        members[0].gamma = 3.0;
    }
    Plan {
        particles: case.particles,
        eps,
        repulsion: case.repulsion,
        clusters: false,
        forcing: case.forcing.then(|| Forcing {
            expr: Expr::parse("0*x").unwrap(),
            rule: GaussLegendre::new(3),
            params: Vec::new(),
        }),
        order: 1.into(),
        stepping: Stepping::Fixed {
            dt: DT,
            dt_min: 1e-14,
        },
        members,
        // The first output is t = 0 (no steps); the second needs `steps` steps.
        output_times: vec![0.0, case.steps as f64 * DT],
        fields: OutputFields::none(),
        grid: 2,
        companion_estimate: false,
        jacobian: Default::default(),
        sequence: Default::default(),
        peak_centre: false,
        energy_sums: true,
        overrides: roughlub::backend::overrides::Overrides::from_env(),
    }
}

/// Builds the solver and takes its t = 0 output, so that the next `next_output()` runs the
/// `steps` steps of the interval.
fn solver<'a>(ctx: &'a GpuContext, case: &Case, precision: Precision) -> Result<GpuSolver<'a>> {
    let c = chain(case);
    let plan = plan(case, c.eps);
    let mut s = GpuSolver::new_with(ctx, plan, vec![c; case.members], precision, case.partition)
        .map_err(|e| Error::gpu("GpuSolver::new", e, ""))?;
    s.next_output(&|_| {})?;
    Ok(s)
}

fn stats_delta(after: GpuStats, before: GpuStats) -> GpuStats {
    GpuStats {
        dispatches: after.dispatches - before.dispatches,
        steps: after.steps - before.steps,
        submits: after.submits - before.submits,
        readbacks: after.readbacks - before.readbacks,
        bytes_read: after.bytes_read - before.bytes_read,
        bytes_written: after.bytes_written - before.bytes_written,
        attempts_per_dispatch: after.attempts_per_dispatch,
        dispatches_per_submit: after.dispatches_per_submit,
        segments: after.segments,
    }
}

/// Builds the solver once untimed and runs the interval: returns false (after saying why) when
/// the configuration cannot run on this adapter; otherwise prints the work counters of one
/// interval and checks that every member took its steps.
fn probe(ctx: &GpuContext, case: &Case, precision: Precision, id: &str) -> bool {
    let mut s = match solver(ctx, case, precision) {
        Ok(s) => s,
        Err(e) => {
            let why = match e {
                Error::GpuBackend {
                    source: GpuError::LoopLimit { .. },
                    ..
                } => " (refused on lavapipe)",
                _ => "",
            };
            println!("{id}: skipped{why}: {e}");
            return false;
        }
    };
    let before = s.stats();
    match s.next_output(&|_| {}) {
        Ok(Some(_)) => {}
        Ok(None) => panic!("{id}: no second output"),
        Err(e) => {
            println!("{id}: skipped: the interval failed: {e}");
            return false;
        }
    }
    let d = stats_delta(s.stats(), before);
    let reports = s.reports();
    let failed = reports
        .iter()
        .filter(|r| !matches!(r.status, roughlub::backend::MemberStatus::Ok))
        .count();
    let steps: u64 = reports.iter().map(|r| r.steps_accepted).sum();
    let kernel = match d.segments {
        0 => "one invocation per member".to_string(),
        p => format!("partitioned, {p} segments per member"),
    };
    println!(
        "{id}: {kernel}, {} bytes per particle-step; one interval of {} steps: {} dispatches, \
         {} submits (+ one copy submit per read-back), {} read-backs ({} bytes), {} bytes \
         written; {steps} member-steps accepted, {failed} members failed",
        bytes_per_particle_step(d.segments, precision),
        case.steps,
        d.dispatches,
        d.submits,
        d.readbacks,
        d.bytes_read,
        d.bytes_written
    );
    assert_eq!(failed, 0, "{id}: members failed");
    assert_eq!(
        steps,
        (case.members * case.steps) as u64,
        "{id}: steps taken"
    );
    true
}

fn bench_case<M: criterion::measurement::Measurement<Value = Duration>>(
    group: &mut BenchmarkGroup<'_, M>,
    ctx: &GpuContext,
    case: Case,
    precision: Precision,
    id: BenchmarkId,
    label: &str,
) {
    if !probe(ctx, &case, precision, label) {
        return;
    }
    group.throughput(Throughput::Elements(case.particle_steps()));
    group.bench_function(id, |b| {
        b.iter_batched(
            || solver(ctx, &case, precision).expect("GpuSolver (built once already)"),
            // The solver is returned so that it is dropped outside the timed part.
            |mut s| {
                let out = s.next_output(&|_| {}).expect("GPU interval");
                (s, out)
            },
            BatchSize::LargeInput,
        )
    });
}

fn configure<M: criterion::measurement::Measurement>(group: &mut BenchmarkGroup<'_, M>) {
    // Building a solver compiles three pipelines (slow on a software device), once per
    // iteration; flat sampling keeps the iteration count at about one per sample.
    group
        .sample_size(10)
        .sampling_mode(SamplingMode::Flat)
        .measurement_time(Duration::from_secs(3))
        .warm_up_time(Duration::from_millis(500));
}

fn gpu_benches(c: &mut Criterion) {
    let ctx32 = match GpuContext::acquire(false) {
        Ok(ctx) => ctx,
        Err(e) => {
            println!("no GPU adapter: skipping GPU benchmarks ({e})");
            return;
        }
    };
    println!(
        "f32 adapter: {} (driver {} {})",
        ctx32.description.short(),
        ctx32.description.driver,
        ctx32.description.driver_info
    );
    let ctx64 = match GpuContext::acquire(true) {
        Ok(ctx) => {
            println!("f64 adapter: {}", ctx.description.short());
            Some(ctx)
        }
        Err(e) => {
            println!("no f64 adapter: skipping the f64 benchmarks ({e})");
            None
        }
    };

    let mut group = c.benchmark_group("gpu_order1_fixed_integer_gamma");
    configure(&mut group);
    for (members, particles) in [
        (256usize, 1000usize),
        (4096, 100),
        (1, 100_000),
        (1, 1_000_000),
        (4, 1_000_000),
    ] {
        let case = Case::base(members, particles);
        for (precision, ctx) in [
            (Precision::F32, Some(&ctx32)),
            (Precision::F64, ctx64.as_ref()),
        ] {
            let Some(ctx) = ctx else { continue };
            let p = precision_label(precision);
            let label = format!("gpu_order1_fixed_integer_gamma/{p}/{}", case.size_label());
            bench_case(
                &mut group,
                ctx,
                case,
                precision,
                BenchmarkId::new(p, case.size_label()),
                &label,
            );
        }
    }
    group.finish();

    let Some(ctx) = ctx64.as_ref() else { return };
    // Both kernels where both run on lavapipe (N <= 8191 for one invocation per member).
    let mut group = c.benchmark_group("partition_threshold");
    configure(&mut group);
    for members in [1usize, 4] {
        for (name, partition) in [
            ("sequential", GpuPartition::Off),
            (
                "partitioned",
                GpuPartition::SegmentRows(roughlub::backend::gpu::partitioned::SEGMENT_ROWS),
            ),
        ] {
            let case = Case {
                partition,
                ..Case::base(members, 8000)
            };
            let label = format!("partition_threshold/{name}/f64_{}", case.size_label());
            bench_case(
                &mut group,
                ctx,
                case,
                Precision::F64,
                BenchmarkId::new(name, format!("f64_{}", case.size_label())),
                &label,
            );
        }
    }
    group.finish();

    // One change at a time from the base scene (integer gamma 2, repulsion, no forcing).
    let base = Case::base(256, 1000);
    let variants = [
        ("integer_gamma", base),
        (
            "per_member_gamma",
            Case {
                per_member_gamma: true,
                ..base
            },
        ),
        (
            "forcing_0x",
            Case {
                forcing: true,
                ..base
            },
        ),
        (
            "no_repulsion",
            Case {
                repulsion: false,
                ..base
            },
        ),
    ];
    let mut group = c.benchmark_group("specialisation");
    configure(&mut group);
    for (name, case) in variants {
        let label = format!("specialisation/{name}/f64_{}", case.size_label());
        bench_case(
            &mut group,
            ctx,
            case,
            Precision::F64,
            BenchmarkId::new(name, format!("f64_{}", case.size_label())),
            &label,
        );
    }
    group.finish();
}

criterion_group!(benches, gpu_benches);
criterion_main!(benches);
