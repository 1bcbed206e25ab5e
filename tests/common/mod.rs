//! Helpers shared by the numerical tests: plans and chains built directly, without scene files.
#![allow(dead_code)]

pub mod gpu;
pub mod reference;

use roughlub::backend::cpu::CpuSolver;
use roughlub::backend::BatchSolver;
use roughlub::expr::Expr;
use roughlub::model::chain::Chain;
use roughlub::model::observables::Snapshot;
use roughlub::model::params::{MemberParams, OutputFields, Stepping};
use roughlub::model::plan::{Forcing, Plan};
use roughlub::model::quadrature::GaussLegendre;

/// The names in `dir` that start with `prefix`: the staging directories a run into
/// `dir/NAME` leaves beside it start with ".NAME.", every hidden one with ".".
pub fn names_starting_with(dir: &std::path::Path, prefix: &str) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|name| name.starts_with(prefix))
        .collect()
}

pub fn all_fields() -> OutputFields {
    OutputFields::all()
}

pub fn plan_for(
    chain: &Chain,
    members: Vec<MemberParams>,
    order: impl Into<roughlub::model::params::Order>,
    stepping: Stepping,
    output_times: Vec<f64>,
    forcing: Option<(&str, usize)>,
) -> Plan {
    Plan {
        particles: chain.particles(),
        eps: chain.eps,
        repulsion: chain.dstar.is_some(),
        clusters: chain.bonded.is_some(),
        forcing: forcing.map(|(src, points)| Forcing {
            expr: Expr::parse(src).expect("test forcing parses"),
            rule: GaussLegendre::new(points),
            params: Vec::new(),
        }),
        order: order.into(),
        stepping,
        members,
        output_times,
        fields: OutputFields {
            rho_star: chain.dstar.is_some(),
            ..all_fields()
        },
        grid: 64,
        companion_estimate: false,
        jacobian: Default::default(),
        sequence: Default::default(),
        peak_centre: false,
        energy_sums: true,
        overrides: Default::default(),
    }
}

/// Runs every output interval; returns snapshots[time][member] and the solver (for reports).
pub fn run_all(plan: Plan, chains: Vec<Chain>) -> (Vec<Vec<Snapshot>>, CpuSolver) {
    let mut solver = CpuSolver::new(plan, chains);
    let mut out = Vec::new();
    while let Some(s) = solver.next_output(&|_| {}).unwrap() {
        out.push(s);
    }
    (out, solver)
}

/// A small deterministic generator (SplitMix64) so the tests need no extra crate.
pub struct Rng(pub u64);
impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E3779B97F4A7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58476D1CE4E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D049BB133111EB);
        z ^ (z >> 31)
    }
    /// Uniform in [a, b).
    pub fn uniform(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * ((self.next_u64() >> 11) as f64 / (1u64 << 53) as f64)
    }
}

/// A chain with N intervals, random gaps summing to 1 - 2 eps N, random velocities and (optionally)
/// random roughness radii r_i in [0, r_max], d*_i = r_{i-1} + r_i.
pub fn random_chain(rng: &mut Rng, n: usize, eps: f64, roughness: Option<f64>) -> Chain {
    let free = 1.0 - 2.0 * eps * n as f64;
    assert!(free > 0.0);
    let weights: Vec<f64> = (0..n).map(|_| rng.uniform(0.5, 1.5)).collect();
    let total: f64 = weights.iter().sum();
    let gaps: Vec<f64> = weights.iter().map(|w| free * w / total).collect();
    let velocities = (1..n).map(|_| rng.uniform(-0.5, 0.5)).collect();
    let dstar = roughness.map(|r_max| {
        let r: Vec<f64> = (0..=n).map(|_| rng.uniform(0.0, r_max)).collect();
        (1..=n).map(|i| r[i - 1] + r[i]).collect()
    });
    Chain {
        eps,
        gaps,
        velocities,
        dstar,
        bonded: None,
    }
}
