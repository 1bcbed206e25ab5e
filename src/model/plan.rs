//! The plan: which terms of the model a scene needs, so that nothing it does not use is computed
//! (no roughness → no d* and no G; no forcing → no quadrature; integer gamma → multiplications;
//! no clusters → no contact bookkeeping) and which outputs are asked for.

use crate::expr::Expr;
use crate::model::chain::Chain;
use crate::model::params::{MemberParams, OutputFields, Stepping};
use crate::model::quadrature::GaussLegendre;
use crate::scene::Scene;

/// How G = ratio^gamma is evaluated.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(tag = "kind", content = "value", rename_all = "lowercase")]
pub enum Power {
    /// A chain of multiplications (square and multiply).
    Integer(u32),
    /// exp(gamma ln ratio).
    Real(f64),
}

impl Power {
    pub fn of(gamma: f64) -> Power {
        if gamma.fract() == 0.0 && gamma <= 64.0 {
            Power::Integer(gamma as u32)
        } else {
            Power::Real(gamma)
        }
    }

    #[inline(always)]
    pub fn apply(self, ratio: f64) -> f64 {
        match self {
            Power::Integer(n) => powi_by_squaring(ratio, n),
            Power::Real(g) => ratio.powf(g),
        }
    }
}

/// ratio^n by square-and-multiply: ~2 log2(n) multiplications, the same sequence on CPU and GPU.
#[inline(always)]
pub fn powi_by_squaring(ratio: f64, n: u32) -> f64 {
    let mut result = 1.0;
    let mut base = ratio;
    let mut e = n;
    while e > 0 {
        if e & 1 == 1 {
            result *= base;
        }
        e >>= 1;
        if e > 0 {
            base *= base;
        }
    }
    result
}

#[derive(Debug, Clone)]
pub struct Forcing {
    pub expr: Expr,
    pub rule: GaussLegendre,
}

#[derive(Debug, Clone)]
pub struct Plan {
    pub particles: usize,
    pub eps: f64,
    pub repulsion: bool,
    pub clusters: bool,
    pub forcing: Option<Forcing>,
    pub order: u8,
    pub stepping: Stepping,
    pub members: Vec<MemberParams>,
    pub output_times: Vec<f64>,
    pub fields: OutputFields,
    pub grid: usize,
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct PlanSummary {
    pub repulsion: bool,
    pub clusters: bool,
    pub forcing: Option<String>,
    pub quadrature_points: Option<usize>,
    pub gamma_evaluation: Vec<Power>,
}

impl Plan {
    pub fn new(scene: &Scene, chain: &Chain) -> Plan {
        let mut fields = scene.fields;
        // Without roughness there is no rho* to output.
        fields.rho_star &= chain.dstar.is_some();
        Plan {
            particles: chain.particles(),
            eps: chain.eps,
            repulsion: chain.dstar.is_some(),
            clusters: chain.bonded.is_some(),
            forcing: scene.forcing.as_ref().map(|e| Forcing {
                expr: e.clone(),
                rule: GaussLegendre::new(scene.quadrature_points),
            }),
            order: scene.order,
            stepping: scene.stepping,
            members: scene.member_parameters(),
            output_times: scene.output_times.clone(),
            fields,
            grid: scene.grid,
        }
    }

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
        }
    }
}
