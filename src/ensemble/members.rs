//! The members of an ensemble: member m's inputs (chain with its roughness, perturbed velocities
//! and jittered gaps, swept parameters) as a pure function of (scene, seed, m), so its result does
//! not depend on chunking, threads, backend or shard.

use crate::ensemble::{
    dstar_from_radii, jitter_gaps, mean_radii_from_rho_star, perturbed_velocity, RoughnessSampler,
};
use crate::error::{Error, Result};
use crate::model::chain::{positions_from_gaps, Chain};
use crate::model::params::MemberParams;
use crate::scene::{EnsembleSpec, InitialSpec, Scene};

/// What all members of an ensemble share (the scene's initial chain, the roughness sampler, the
/// parameter sweep), from which [`member`](Self::member) builds member m's inputs.
pub struct EnsembleMembers {
    /// The scene's initial chain, before any per-member draw.
    pub chain: Chain,
    /// Its particle positions (where the roughness is sampled).
    pub positions: Vec<f64>,
    /// Draws each member's roughness radii; `None` without `ensemble.roughness`.
    pub sampler: Option<RoughnessSampler>,
    /// The swept parameter points; member m uses point `m % sweep.len()`.
    pub sweep: Vec<MemberParams>,
}

/// Member m's inputs: the chain and parameters it is solved with, and its velocity draw (for
/// `members.csv`).
#[derive(Debug, Clone)]
pub struct MemberInputs {
    pub chain: Chain,
    pub params: MemberParams,
    /// Amplitude factor of the initial velocity.
    pub velocity_factor: f64,
    /// Phase shift of the initial velocity profile.
    pub velocity_phase: f64,
}

impl EnsembleMembers {
    /// The shared part of the ensemble `spec` of `scene`.
    pub fn new(scene: &Scene, spec: &EnsembleSpec) -> Result<EnsembleMembers> {
        let chain = scene.initial_chain()?;
        let positions = chain.positions();
        let sampler = match &spec.roughness {
            None => None,
            Some(r) => {
                let mean = match &chain.dstar {
                    Some(d) => mean_radii_from_rho_star(d),
                    None => vec![spec.mean_radius.unwrap_or(0.0); chain.particles() + 1],
                };
                Some(
                    RoughnessSampler::new(r, &mean, &positions, spec.seed).map_err(|e| {
                        Error::invalid(
                            "ensemble.roughness",
                            format!("{r:?}"),
                            e.to_string(),
                            "see the scene reference",
                        )
                    })?,
                )
            }
        };
        Ok(EnsembleMembers {
            chain,
            positions,
            sampler,
            sweep: scene.member_parameters(),
        })
    }

    /// Number of members: `spec.members` per sweep point.
    pub fn total(&self, spec: &EnsembleSpec) -> u64 {
        spec.members * self.sweep.len() as u64
    }

    /// The sweep point of member m.
    pub fn sweep_point(&self, m: u64) -> usize {
        (m % self.sweep.len() as u64) as usize
    }

    /// Member m's inputs: a pure function of (scene, seed, m).
    pub fn member(&self, scene: &Scene, spec: &EnsembleSpec, m: u64) -> Result<MemberInputs> {
        let mut chain = self.chain.clone();
        if let Some(sampler) = &self.sampler {
            let radii = sampler.sample(m);
            chain.dstar = Some(dstar_from_radii(&radii));
        }
        if spec.jitter > 0.0 {
            jitter_gaps(
                &mut chain.gaps,
                chain.bonded.as_deref(),
                spec.jitter,
                spec.seed,
                m,
            )
            .map_err(|e| {
                Error::invalid("ensemble.jitter", spec.jitter, e.to_string(), "0 <= jitter")
            })?;
        }
        let (factor, phase) = perturbed_velocity(
            spec.velocity_amplitude_spread,
            spec.velocity_phase_spread,
            spec.seed,
            m,
        );
        match &scene.initial {
            InitialSpec::Profiles { velocity, .. } => {
                let q = positions_from_gaps(&chain.gaps, chain.eps);
                for (i, u) in chain.velocities.iter_mut().enumerate() {
                    *u = factor * velocity.eval(q[i + 1] - phase, 0.0);
                }
            }
            InitialSpec::Particles { .. } => {
                for u in chain.velocities.iter_mut() {
                    *u *= factor;
                }
            }
        }
        // Particles glued into a cluster keep one velocity.
        if let Some(bonded) = &chain.bonded {
            let n = chain.particles();
            for g in 1..n {
                if bonded[g] {
                    chain.velocities[g] = chain.velocities[g - 1];
                }
            }
            if bonded[0] {
                chain.velocities[0] = 0.0;
                for g in 1..n - 1 {
                    if bonded[g] {
                        chain.velocities[g] = 0.0;
                    } else {
                        break;
                    }
                }
            }
        }
        let params = self.sweep[self.sweep_point(m)];
        Ok(MemberInputs {
            chain,
            params,
            velocity_factor: factor,
            velocity_phase: phase,
        })
    }
}
