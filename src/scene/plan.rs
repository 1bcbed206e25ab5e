//! The plan of a scene's chain: which terms of the model it needs and which outputs it asks
//! for (built here, so that `model/` knows nothing of scenes).

use super::Scene;
use crate::backend::Precision;
use crate::model::chain::Chain;
use crate::model::params::Sequence;
use crate::model::plan::{Forcing, Plan};
use crate::model::quadrature::GaussLegendre;

impl Scene {
    /// The tableau's sequence this scene's runs take in `precision` (`[solver] sequence`
    /// resolved for its order and stepping): what its plans hold and a study's header records.
    pub fn sequence_in(&self, precision: Precision) -> Sequence {
        self.sequence.resolve(self.order, self.stepping, precision)
    }

    /// The plan a solver runs for `chain` under this scene in `precision` (which decides the
    /// tableau's sequence where the scene leaves it to auto).
    pub fn plan(&self, chain: &Chain, precision: Precision) -> Plan {
        let scene = self;
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
                params: Vec::new(),
            }),
            order: scene.order,
            stepping: scene.stepping,
            members: scene.member_parameters(),
            output_times: scene.output_times.clone(),
            fields,
            grid: scene.grid,
            companion_estimate: scene.error_estimate,
            jacobian: scene.jacobian,
            sequence: scene.sequence_in(precision),
            peak_centre: false,
            energy_sums: true,
            overrides: scene.overrides.clone(),
        }
    }
}
