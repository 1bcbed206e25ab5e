//! The plan: which terms of the model a scene needs, so that nothing it does not use is computed
//! (no roughness → no d* and no G; no forcing → no quadrature; integer gamma → multiplications;
//! no clusters → no contact bookkeeping) and which outputs are asked for.

use crate::expr::Expr;
use crate::model::params::{Jacobian, MemberParams, Order, OutputFields, Sequence, Stepping};
use crate::model::quadrature::GaussLegendre;
use roughlub_kernels::overrides::Overrides;
use roughlub_kernels::shared::control::{top_column, MAX_ORDER};

pub use roughlub_kernels::power::{powi_by_squaring, Power, MAX_INTEGER_GAMMA};

#[derive(Debug, Clone)]
pub struct Forcing {
    pub expr: Expr,
    pub rule: GaussLegendre,
    /// Values of the expression's symbolic parameters ([`Expr::parse_symbolic`]), member-major:
    /// member b's K values at `b·K..(b+1)·K`, K = `expr.symbolic_count()`. Empty when K = 0.
    pub params: Vec<f64>,
}

impl roughlub_kernels::step::Forcing for Forcing {
    /// By Gauss–Legendre.
    fn particle_force(&self, params: &[f64], eps: f64, t: f64, q: f64) -> f64 {
        let mut s = 0.0;
        for (xi, w) in self.rule.nodes.iter().zip(&self.rule.weights) {
            s += w * self.expr.eval_with(q + eps * xi, t, params);
        }
        eps * s
    }
}

impl Forcing {
    /// Member b's symbolic parameter values.
    pub fn member_params(&self, b: usize) -> &[f64] {
        let k = self.expr.symbolic_count();
        self.params.get(b * k..(b + 1) * k).unwrap_or(&[])
    }
}

#[derive(Debug, Clone)]
pub struct Plan {
    pub particles: usize,
    pub eps: f64,
    pub repulsion: bool,
    pub clusters: bool,
    pub forcing: Option<Forcing>,
    pub order: Order,
    pub stepping: Stepping,
    pub members: Vec<MemberParams>,
    pub output_times: Vec<f64>,
    pub fields: OutputFields,
    pub grid: usize,
    /// Order 1 with fixed steps: estimate the error with a companion run (see
    /// [`crate::backend::companion`]).
    pub companion_estimate: bool,
    /// The matrix of the extrapolated steps (`[solver] jacobian`); see [`Plan::exact_jacobian`].
    pub jacobian: Jacobian,
    /// The substeps of the tableau's rows (`[solver] sequence`).
    pub sequence: Sequence,
    /// Compute each snapshot's [`peak_centre`](crate::model::observables::peak_centre) (a
    /// study's detailed points: there the rho row is still in cache).
    pub peak_centre: bool,
    /// Compute each snapshot's energy and dissipation (false only for the companion that
    /// estimates order 1's error, whose snapshots are only compared: with the copy of d* they
    /// cost 1-4 % of a run of many short members with the estimate, docs/performance.md).
    pub energy_sums: bool,
    /// What the environment overrides (read once by the command line, passed down from the
    /// scene): the CPU step's instruction set and partition choice, the GPU's adapter,
    /// partition and attempts per dispatch. The default overrides nothing.
    pub overrides: Overrides,
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct PlanSummary {
    pub repulsion: bool,
    pub clusters: bool,
    pub forcing: Option<String>,
    pub quadrature_points: Option<usize>,
    #[serde(serialize_with = "serialize_powers")]
    pub gamma_evaluation: Vec<Power>,
    /// "exact" or "frozen": the matrix the run's extrapolated steps used.
    pub jacobian: &'static str,
    /// "from_1" or "from_2": the substeps of the tableau's rows ([`Sequence::record`]).
    pub sequence: &'static str,
}

/// [`Power`] as the manifest records it (`{"kind": "integer", "value": 2}`). The kernels crate
/// builds without serde, so that its long build starts before serde's derive macros are built.
#[derive(serde::Serialize)]
#[serde(tag = "kind", content = "value", rename_all = "lowercase")]
enum PowerRecord {
    Integer(u32),
    Real(f64),
}

fn serialize_powers<S: serde::Serializer>(powers: &[Power], s: S) -> Result<S::Ok, S::Error> {
    s.collect_seq(powers.iter().map(|p| match *p {
        Power::Integer(n) => PowerRecord::Integer(n),
        Power::Real(g) => PowerRecord::Real(g),
    }))
}

impl Plan {
    pub fn summary(&self) -> PlanSummary {
        let mut gamma_evaluation: Vec<Power> = Vec::new();
        if self.repulsion {
            for m in &self.members {
                let p = Power::of(m.gamma);
                if !gamma_evaluation.contains(&p) {
                    gamma_evaluation.push(p);
                }
            }
        }
        PlanSummary {
            repulsion: self.repulsion,
            clusters: self.clusters,
            forcing: self.forcing.as_ref().map(|f| f.expr.source().to_string()),
            quadrature_points: self.forcing.as_ref().map(|f| f.rule.nodes.len()),
            gamma_evaluation,
            jacobian: self.jacobian.record(self.order, self.stepping),
            sequence: self.sequence.record(self.order),
        }
    }

    /// Whether the extrapolated steps keep the exact Jacobian's -r_i (see [`Jacobian`]).
    pub fn exact_jacobian(&self) -> bool {
        self.jacobian.is_exact(self.order, self.stepping)
    }

    /// The highest column the steps may end in (`top_column`: in f32, `f32_rounding`, auto's
    /// columns stay where their rounding is well below the tolerance).
    pub fn top_column(&self, f32_rounding: bool) -> u8 {
        match self.stepping {
            Stepping::Adaptive { tolerance, .. } => top_column(
                tolerance,
                f32_rounding,
                self.sequence.of(self.order) == Sequence::FromTwo,
            ),
            Stepping::Fixed { .. } => MAX_ORDER,
        }
    }

    /// The column a member's first step ends in: the order's [`Order::initial`], for auto at most
    /// [`Plan::top_column`].
    pub fn initial_column(&self, f32_rounding: bool) -> u8 {
        match self.order {
            Order::Fixed(p) => p,
            Order::Auto => self
                .order
                .initial(&self.stepping)
                .min(self.top_column(f32_rounding)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integer_gamma_up_to_1000_is_multiplications() {
        for g in [
            0.0, 1.0, 2.0, 64.0, 65.0, 100.0, 127.0, 128.0, 999.0, 1000.0,
        ] {
            assert_eq!(Power::of(g), Power::Integer(g as u32), "gamma = {g}");
        }
        for g in [
            1000.5,
            1001.0,
            1024.0,
            2.5,
            64.5,
            -1.0,
            -64.0,
            f64::NAN,
            f64::INFINITY,
        ] {
            assert!(matches!(Power::of(g), Power::Real(_)), "gamma = {g}");
        }
        assert_eq!(MAX_INTEGER_GAMMA, 1000);
    }

    #[test]
    fn integer_power_is_square_and_multiply() {
        for n in [65u32, 100, 999, 1000] {
            for r in [1.001, 0.999, 1.000_000_1, 0.5, 2.0] {
                let p = Power::of(n as f64).apply(r);
                assert_eq!(p.to_bits(), powi_by_squaring(r, n).to_bits(), "{r}^{n}");
                let exact = r.powf(n as f64);
                if exact.is_finite() && exact > f64::MIN_POSITIVE {
                    // ~2 log2(n) roundings, each amplified at most n times.
                    let tol = 4.0 * n as f64 * f64::EPSILON;
                    assert!((p - exact).abs() <= tol * exact, "{r}^{n}: {p} vs {exact}");
                } else {
                    assert_eq!(p.is_finite(), exact.is_finite(), "{r}^{n}");
                }
            }
        }
    }

    #[test]
    fn integer_power_in_rounds_takes_the_same_products() {
        // The step's uniform integer law (`powi_in_rounds`, a fixed number of rounds) against
        // the loop over the exponent's bits, which the GPU twin follows: bit for bit, every n.
        use roughlub_kernels::power::powi_in_rounds;
        for n in 0..=MAX_INTEGER_GAMMA {
            for r in [1.001, 0.999, 1.000_000_1, 0.5, 2.0, 1.0e-3, f64::NAN] {
                let (rounds, looped) = (powi_in_rounds(r, n), powi_by_squaring(r, n));
                assert_eq!(rounds.to_bits(), looped.to_bits(), "{r}^{n}");
                let (rounds, looped) = (powi_in_rounds(r as f32, n), powi_by_squaring(r as f32, n));
                assert_eq!(rounds.to_bits(), looped.to_bits(), "{r}^{n} in f32");
            }
        }
    }
}
