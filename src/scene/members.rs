//! The members of an ensemble: member m's inputs (chain with its roughness, perturbed velocities
//! and jittered gaps, swept parameters) as a pure function of (scene, seed, m), so its result does
//! not depend on chunking, threads, backend or shard.

use crate::ensemble::{
    dstar_from_radii, jitter_gaps, mean_radii_from_rho_star, perturbed_velocity, RoughnessSampler,
};
use crate::error::{Error, Result};
use crate::expr::Expr;
use crate::model::chain::{positions_from_gaps, Chain};
use crate::model::params::MemberParams;
use crate::scene::{EnsembleSpec, InitialSpec, Scene, SweepTarget};

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

/// What the members of one sweep point share: the point's scene (swept settings set, expressions
/// bound to its parameters), its initial chain and roughness sampler.
pub struct PointSetup {
    /// Index of the point.
    pub point: u64,
    /// The scene of this point ([`Scene::at_point`]).
    pub scene: Scene,
    /// Its `[ensemble]` section.
    pub spec: EnsembleSpec,
    /// The point's initial chain, before any per-member draw.
    pub chain: Chain,
    /// Its particle positions (where the roughness is sampled).
    pub positions: Vec<f64>,
    /// Draws each member's roughness radii; `None` without `ensemble.roughness`.
    pub sampler: Option<RoughnessSampler>,
    /// The point's mu and gamma.
    pub params: MemberParams,
}

/// What the setups built while checking a study's points may hold at most.
const PREBUILT_BYTES: usize = 64 << 20;

/// A sweep point's initial velocity u of `particle` (at x): finite and at most MAX_VELOCITY (the
/// unswept scene's profile was sampled over [0, 1] when the scene was read).
fn check_point_velocity(
    velocity: &Expr,
    u: f64,
    particle: usize,
    x: f64,
    point: u64,
) -> Result<()> {
    if u.is_finite() && u.abs() <= crate::scene::MAX_VELOCITY {
        return Ok(());
    }
    Err(Error::invalid(
        "initial.velocity",
        format!("\"{}\"", velocity.source()),
        format!("u0 = {u} at particle {particle} (x = {x}) of sweep point {point}"),
        format!("finite, |u0| <= {:e}", crate::scene::MAX_VELOCITY),
    ))
}

/// Roughly the memory of a point's setup with `particles` particles and a scene text of
/// `text_bytes`: a few KB for the scene, the chain, the positions and the sampler's arrays.
fn setup_bytes(text_bytes: usize, particles: usize) -> usize {
    4096 + text_bytes + 10 * 8 * (particles + 1)
}

impl PointSetup {
    /// Its size in memory, roughly: the scene's text and a few KB for the rest of it, the chain,
    /// the positions and the sampler's per-particle arrays.
    fn approximate_bytes(&self) -> usize {
        setup_bytes(self.scene.source_text.len(), self.chain.particles())
    }

    fn new(point: u64, scene: Scene) -> Result<PointSetup> {
        let chain = scene.initial_chain()?;
        let positions = chain.positions();
        if let (true, InitialSpec::Profiles { velocity, .. }) = (point != 0, &scene.initial) {
            for (i, (&u, &q)) in chain.velocities.iter().zip(&positions[1..]).enumerate() {
                check_point_velocity(velocity, u, i + 1, q, point)?;
            }
        }
        PointSetup::with_chain(point, scene, chain, positions)
    }

    /// The setup of a point whose scene differs from `first`'s only where the initial chain's
    /// gaps and roughness do not see it (its density and rho* profiles and N are the same: a
    /// swept velocity, forcing or roughness parameter): `first`'s gaps are reused, which saves
    /// the Prop. 3.1 construction (thousands of quadrature panels) per point; the velocities
    /// are the point's own.
    fn like(point: u64, scene: Scene, first: &PointSetup) -> Result<Option<PointSetup>> {
        if !PointSetup::shares_first_chain(&scene, first) {
            return Ok(None);
        }
        let InitialSpec::Profiles { velocity, .. } = &scene.initial else {
            return Ok(None);
        };
        let mut chain = first.chain.clone();
        for (i, (u, &q)) in chain
            .velocities
            .iter_mut()
            .zip(&first.positions[1..])
            .enumerate()
        {
            *u = velocity.eval(q, 0.0);
            check_point_velocity(velocity, *u, i + 1, q, point)?;
        }
        let positions = first.positions.clone();
        PointSetup::with_chain(point, scene, chain, positions).map(Some)
    }

    /// Whether a point's scene differs from `first`'s only where the initial chain's gaps and
    /// roughness do not see it (see [`like`](Self::like)).
    fn shares_first_chain(scene: &Scene, first: &PointSetup) -> bool {
        let (
            InitialSpec::Profiles { rho, rho_star, .. },
            InitialSpec::Profiles {
                rho: rho_first,
                rho_star: rho_star_first,
                ..
            },
        ) = (&scene.initial, &first.scene.initial)
        else {
            return false;
        };
        rho == rho_first && rho_star == rho_star_first && scene.particles == first.scene.particles
    }

    fn with_chain(
        point: u64,
        scene: Scene,
        chain: Chain,
        positions: Vec<f64>,
    ) -> Result<PointSetup> {
        let spec = scene
            .ensemble
            .clone()
            .ok_or_else(|| Error::missing("ensemble", "this scene has no [ensemble] section"))?;
        let sampler = match &spec.roughness {
            None => None,
            Some(r) => {
                let mean = match &chain.dstar {
                    Some(d) => mean_radii_from_rho_star(d),
                    None => vec![spec.mean_radius.unwrap_or(0.0); chain.particles() + 1],
                };
                Some(
                    // The error names the file and line, or the key, and the allowed range.
                    RoughnessSampler::new(r, &mean, &positions, spec.seed)
                        .map_err(|e| Error::missing("ensemble.roughness", e.to_string()))?,
                )
            }
        };
        let params = MemberParams {
            mu: scene.mu[0],
            gamma: scene.gamma[0],
        };
        Ok(PointSetup {
            point,
            scene,
            spec,
            chain,
            positions,
            sampler,
            params,
        })
    }
}

/// The members of an ensemble study: `spec.members` per sweep point, point-major (member m is
/// member j = m mod M of point p = m div M), from which [`member`](Self::member) builds member
/// m's inputs.
///
/// Member j of every point draws the same random inputs (its streams are keyed by j: common
/// random numbers, so that differences between points are not hidden by sampling noise, and a
/// point's members are exactly those of a study of that point's scene alone), unless
/// `[sweep] independent_draws = true`, where every member m draws its own.
pub struct EnsembleMembers {
    /// Sweep points P.
    pub points: u64,
    /// Members per point M.
    pub per_point: u64,
    independent_draws: bool,
    /// The sweep varies only mu and gamma: every point shares point 0's chain and sampler.
    shared: bool,
    base_scene: Scene,
    /// The setup of point 0.
    pub first: Arc<PointSetup>,
    /// The setups built last (members of a chunk are mostly of one or two points).
    recent: Mutex<Vec<Arc<PointSetup>>>,
    /// Per sweep point, whether its chain is its own (not point 0's); empty when shared.
    own_chain: Vec<bool>,
    /// Setups of points with their own chains, built by [`prepare`](Self::prepare).
    prebuilt: HashMap<u64, Arc<PointSetup>>,
    /// The forcing with the swept parameters it uses left symbolic (read per member), and their
    /// names; `None` when the sweep does not reach the forcing.
    symbolic_forcing: Option<(Expr, Vec<String>)>,
}

/// Member m's inputs: the chain and parameters it is solved with, and its velocity draw (for
/// `members.csv`).
#[derive(Debug, Clone)]
pub struct MemberInputs {
    pub chain: Chain,
    pub params: MemberParams,
    /// The member's sweep point.
    pub point: u64,
    /// Amplitude factor of the initial velocity.
    pub velocity_factor: f64,
    /// Phase shift of the initial velocity profile.
    pub velocity_phase: f64,
    /// The setup of the member's sweep point (kept with the member, so that a chunk of many
    /// points builds each point's initial data once).
    pub setup: Arc<PointSetup>,
}

/// Without roughness there is no repulsion, so every gamma of a sweep gives the same member:
/// refused, as in `[batch]` (`Scene::initial_chain_in`), with the same error.
fn refuse_gamma_swept_without_roughness(
    scene: &Scene,
    spec: &EnsembleSpec,
    first_chain: &Chain,
) -> Result<()> {
    let Some(sweep) = &scene.sweep else {
        return Ok(());
    };
    let Some(k) = sweep.targets.iter().position(|t| *t == SweepTarget::Gamma) else {
        return Ok(());
    };
    if first_chain.dstar.is_some() || spec.roughness.is_some() {
        return Ok(());
    }
    let axis = &sweep.design.axes()[k];
    let value = match axis {
        crate::ensemble::Axis::Values(v) if v.iter().all(|&g| g == v[0]) => return Ok(()),
        crate::ensemble::Axis::Values(v) => format!("{v:?}"),
        crate::ensemble::Axis::Range { min, max, .. } => format!("{{ min = {min}, max = {max} }}"),
    };
    Err(crate::scene::initial::gamma_swept_without_roughness(
        "sweep.gamma",
        value,
    ))
}

impl EnsembleMembers {
    /// The members of the ensemble of `scene` (its `[ensemble]` is `spec`).
    pub fn new(scene: &Scene, spec: &EnsembleSpec) -> Result<EnsembleMembers> {
        let points = scene.sweep_points();
        let shared = scene.sweep.as_ref().is_none_or(|s| {
            s.targets
                .iter()
                .all(|t| matches!(t, SweepTarget::Mu | SweepTarget::Gamma))
        });
        let mut base_scene = scene.clone();
        base_scene.ensemble = Some(spec.clone());
        let first = Arc::new(PointSetup::new(0, base_scene.at_point(0)?)?);
        let mut own_chain = Vec::new();
        if shared {
            base_scene.initial_chain()?;
        } else {
            // Every point's settings and profiles are checked before any member is solved: a
            // value that is out of range at point 3 of 4 is an error now, not after the first
            // three points' work. (mu and gamma alone are checked with the sweep's lists; the
            // initial chains of a run's own points, by `prepare`.)
            own_chain = vec![false; points as usize];
            for p in 1..points {
                let scene = base_scene.at_point(p)?;
                own_chain[p as usize] = !PointSetup::shares_first_chain(&scene, &first);
            }
        }
        refuse_gamma_swept_without_roughness(scene, spec, &first.chain)?;
        let symbolic_forcing = match (&scene.forcing, &scene.sweep) {
            (Some(forcing), Some(sweep)) => {
                let names: Vec<String> = sweep
                    .targets
                    .iter()
                    .filter_map(|t| match t {
                        SweepTarget::Parameter(name) if forcing.params_used().contains(name) => {
                            Some(name.clone())
                        }
                        _ => None,
                    })
                    .collect();
                if names.is_empty() {
                    None
                } else {
                    let expr = Expr::parse_symbolic(forcing.source(), &scene.parameters, &names)
                        .map_err(|source| Error::Expression {
                            field: "model.forcing".into(),
                            source_text: forcing.source().to_string(),
                            source,
                        })?;
                    Some((expr, names))
                }
            }
            _ => None,
        };
        Ok(EnsembleMembers {
            symbolic_forcing,
            points,
            per_point: spec.members,
            independent_draws: scene.sweep.as_ref().is_some_and(|s| s.independent_draws),
            shared,
            base_scene,
            first,
            recent: Mutex::new(Vec::new()),
            own_chain,
            prebuilt: HashMap::new(),
        })
    }

    /// The sweep points of members `range` (a shard's).
    fn points_of(&self, (first, end): (u64, u64)) -> std::ops::Range<u64> {
        if first >= end {
            return 0..0;
        }
        self.sweep_point(first)..self.sweep_point(end - 1) + 1
    }

    /// Builds the setup of every sweep point of members `range` (a shard's) as the solve will,
    /// before anything is solved: a velocity infinite at some particle of point 3 of 4 is an
    /// error now, not after the first three points' work. Setups with their own chain (density,
    /// rho* or N swept), the costly part, are kept for the solve while they fit in
    /// PREBUILT_BYTES ([`prebuilt_bound`](Self::prebuilt_bound)): built twice, a rho-swept
    /// design of 10000 points of N = 20 took half again its time. Only the run's own points: in
    /// every shard of 1000 all points took 7 times a shard's time.
    pub fn prepare(&mut self, range: (u64, u64)) -> Result<()> {
        if self.shared {
            return Ok(());
        }
        let mut budget = PREBUILT_BYTES;
        for p in self.points_of(range).filter(|&p| p != 0) {
            let scene = self.base_scene.at_point(p)?;
            if !self.own_chain[p as usize] {
                PointSetup::like(p, scene, &self.first)?;
                continue;
            }
            let setup = PointSetup::new(p, scene)?;
            let bytes = setup.approximate_bytes();
            if bytes <= budget {
                budget -= bytes;
                self.prebuilt.insert(p, Arc::new(setup));
            }
        }
        Ok(())
    }

    /// What [`prepare`](Self::prepare) may keep for members `range`, with chains of at most
    /// `particles` particles: for the memory estimate, before it runs.
    pub fn prebuilt_bound(&self, range: (u64, u64), particles: usize) -> usize {
        if self.shared {
            return 0;
        }
        let own = self
            .points_of(range)
            .filter(|&p| p != 0 && self.own_chain[p as usize])
            .count();
        let each = setup_bytes(self.base_scene.source_text.len(), particles);
        own.saturating_mul(each).min(PREBUILT_BYTES)
    }

    /// Number of members: `spec.members` per sweep point.
    pub fn total(&self) -> u64 {
        self.per_point * self.points
    }

    /// The forcing with its swept parameters symbolic, when the sweep reaches it: members of
    /// different points then share one batch, each reading its own values.
    pub fn symbolic_forcing(&self) -> Option<&Expr> {
        self.symbolic_forcing.as_ref().map(|(e, _)| e)
    }

    /// The values of the symbolic forcing's parameters at point p (empty without).
    pub fn forcing_values(&self, p: u64) -> Vec<f64> {
        let Some((_, names)) = &self.symbolic_forcing else {
            return Vec::new();
        };
        let values = self.base_scene.point_values(p);
        names
            .iter()
            .map(|n| {
                values
                    .iter()
                    .find(|(v, _)| v == n)
                    .map_or(f64::NAN, |(_, x)| *x)
            })
            .collect()
    }

    /// The sweep point of member m.
    pub fn sweep_point(&self, m: u64) -> u64 {
        m / self.per_point
    }

    /// The setup of sweep point p (built once and kept while its members are being built).
    pub fn setup(&self, p: u64) -> Result<Arc<PointSetup>> {
        if p == 0 {
            return Ok(self.first.clone());
        }
        if let Some(setup) = self.prebuilt.get(&p) {
            return Ok(setup.clone());
        }
        let mut recent = self.recent.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(s) = recent.iter().find(|s| s.point == p) {
            return Ok(s.clone());
        }
        let scene = self.base_scene.at_point(p)?;
        let setup = if self.shared {
            let params = MemberParams {
                mu: scene.mu[0],
                gamma: scene.gamma[0],
            };
            Arc::new(PointSetup {
                point: p,
                scene,
                spec: self.first.spec.clone(),
                chain: self.first.chain.clone(),
                positions: self.first.positions.clone(),
                sampler: self.first.sampler.clone(),
                params,
            })
        } else {
            match PointSetup::like(p, scene.clone(), &self.first)? {
                Some(setup) => Arc::new(setup),
                None => Arc::new(PointSetup::new(p, scene)?),
            }
        };
        if recent.len() >= 8 {
            recent.remove(0);
        }
        recent.push(setup.clone());
        Ok(setup)
    }

    /// Member m's inputs: a pure function of (scene, seed, m).
    pub fn member(&self, m: u64) -> Result<MemberInputs> {
        let p = self.sweep_point(m);
        let setup = self.setup(p)?;
        let draw = if self.independent_draws {
            m
        } else {
            m % self.per_point
        };
        self.member_of(&setup, p, draw)
    }

    fn member_of(&self, setup: &Arc<PointSetup>, p: u64, m: u64) -> Result<MemberInputs> {
        let (scene, spec) = (&setup.scene, &setup.spec);
        let mut chain = setup.chain.clone();
        if let Some(sampler) = &setup.sampler {
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
                    let v = velocity.eval(q[i + 1] - phase, 0.0);
                    // Again at the member's own (jittered, phase-shifted) positions.
                    if p != 0 {
                        check_point_velocity(velocity, v, i + 1, q[i + 1] - phase, p)?;
                    }
                    *u = factor * v;
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
        Ok(MemberInputs {
            chain,
            params: setup.params,
            point: p,
            velocity_factor: factor,
            velocity_phase: phase,
            setup: setup.clone(),
        })
    }
}

impl std::fmt::Debug for PointSetup {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PointSetup")
            .field("point", &self.point)
            .field("particles", &self.chain.particles())
            .finish_non_exhaustive()
    }
}
