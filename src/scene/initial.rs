//! Initial chains: from macroscopic profiles by the construction of Prop. 3.1, or from a particle
//! file (`super::particle_file`). The state is gaps and velocities (never positions), see
//! DESIGN.md §2.

use super::checks::approx_text;
use super::{InitialSpec, Scene};
use crate::backend::Precision;
use crate::error::{Error, Result};
use crate::expr::Expr;
use crate::model::chain::Chain;
use crate::model::quadrature::GaussLegendre;

pub use super::particle_file::chain_from_particle_file;

/// Prop. 3.1: eps = M0/(2N); q_i with ∫_{q_{i-1}}^{q_i} rho0 = 2 eps; d*_i such that rho*_i is the
/// mean of rho*0 over the cell; u_i = u0(q_i).
pub fn chain_from_profiles(
    n: usize,
    rho: &Expr,
    velocity: &Expr,
    rho_star: Option<&Expr>,
) -> Result<Chain> {
    let gl = GaussLegendre::new(8);
    // Cumulative mass on a fine partition (8-point Gauss–Legendre per panel, exact to rounding
    // for smooth profiles at this panel width).
    let panels = n.clamp(4096, 2_000_000);
    let h = 1.0 / panels as f64;
    let mut density = |x: f64| rho.eval(x, 0.0);
    let density_scale = profile_scale(rho);
    let mut cumulative = Vec::with_capacity(panels + 1);
    cumulative.push(0.0);
    // Neumaier-compensated running sum: M0 and the cell masses keep full precision at large N.
    let (mut mass, mut compensation) = (0.0f64, 0.0f64);
    for k in 0..panels {
        let a = k as f64 * h;
        let term = gl.integrate_adaptive(a, a + h, density_scale, &mut density);
        let sum = mass + term;
        compensation += if mass.abs() >= term.abs() {
            (mass - sum) + term
        } else {
            (term - sum) + mass
        };
        mass = sum;
        cumulative.push(mass + compensation);
    }
    let total_mass = mass + compensation;
    let eps = total_mass / (2.0 * n as f64);
    if !(eps > 0.0 && eps.is_finite()) {
        return Err(Error::invalid(
            "initial.rho",
            total_mass,
            "the total mass M0 = ∫ rho0 must be positive",
            "0 < M0 < 1",
        ));
    }

    // q_0 = 0, the cell boundaries q_1..q_{N-1}, q_N = 1.
    let mut q = Vec::with_capacity(n + 1);
    q.push(0.0);
    let mut panel = 0;
    for i in 1..n {
        let target = total_mass * i as f64 / n as f64;
        while panel + 1 < panels && cumulative[panel + 1] <= target {
            panel += 1;
        }
        let a = panel as f64 * h;
        let b = a + h;
        let m_a = cumulative[panel];
        let span = cumulative[panel + 1] - m_a;
        // Newton on M(x) = target inside the panel, safeguarded by bisection.
        let mut lo = a;
        let mut hi = b;
        let mut x = a + h * ((target - m_a) / span).clamp(0.0, 1.0);
        for _ in 0..60 {
            let m = m_a + gl.integrate_adaptive(a, x, density_scale, &mut density);
            let residual = m - target;
            if residual > 0.0 {
                hi = x;
            } else {
                lo = x;
            }
            let step = residual / density(x);
            let mut next = x - step;
            if !(next > lo && next < hi) {
                next = 0.5 * (lo + hi);
            }
            if (next - x).abs() <= 1e-17 + 1e-16 * x.abs() {
                x = next;
                break;
            }
            x = next;
        }
        q.push(x);
    }
    q.push(1.0);

    let mut gaps = Vec::with_capacity(n);
    for i in 1..=n {
        let d = q[i] - q[i - 1] - 2.0 * eps;
        if d.is_nan() || d <= 0.0 {
            return Err(Error::invalid(
                "model.particles",
                n,
                format!("the construction gives a non-positive gap d_{i} = {d:e}; rho0 too close to 1 for this N"),
                "rho0 < 1 with gaps resolved by N",
            ));
        }
        gaps.push(d);
    }
    let velocities = (1..n).map(|i| velocity.eval(q[i], 0.0)).collect();
    let dstar = rho_star.map(|rs| {
        let scale = profile_scale(rs);
        (1..=n)
            .map(|i| {
                let width = q[i] - q[i - 1];
                // The mean of a profile <= 1 can exceed 1 only by rounding.
                let mean = (gl.integrate_adaptive(q[i - 1], q[i], scale, &mut |x| rs.eval(x, 0.0))
                    / width)
                    .min(1.0);
                2.0 * eps * (1.0 - mean) / mean
            })
            .collect()
    });
    Ok(Chain {
        eps,
        gaps,
        velocities,
        dstar,
        bonded: None,
    })
}

/// The size of a profile's values on [0, 1] (their mean magnitude at 1025 points): the scale
/// below which [`GaussLegendre::integrate_adaptive`] stops refining.
fn profile_scale(profile: &Expr) -> f64 {
    let points = 1024;
    let sum: f64 = (0..=points)
        .map(|k| profile.eval(k as f64 / points as f64, 0.0).abs())
        .filter(|v| v.is_finite())
        .sum();
    sum / (points + 1) as f64
}

impl Scene {
    /// The initial chain the scene describes (Prop. 3.1 from profiles, or the particle file).
    /// A single run (or an ensemble whose members all start from it unchanged) whose repulsion
    /// overflows f64 at t = 0 is refused here, see [`check_repulsion_at_start`].
    pub fn initial_chain(&self) -> Result<Chain> {
        self.initial_chain_in(Precision::F64)
    }

    /// [`Scene::initial_chain`] for a run in `precision`: in f32 the repulsion's overflow at
    /// t = 0 is that of f32 (a member would fail at its first step).
    pub fn initial_chain_in(&self, precision: Precision) -> Result<Chain> {
        let chain = match &self.initial {
            InitialSpec::Profiles {
                rho,
                velocity,
                rho_star,
            } => {
                let n = self.particles.ok_or_else(|| {
                    Error::missing("model.particles", "required with profile initial data")
                })?;
                chain_from_profiles(n, rho, velocity, rho_star.as_ref())?
            }
            InitialSpec::Particles { path, radius } => {
                chain_from_particle_file(path, *radius, self.particles)?
            }
        };
        // Without roughness there is no repulsion, so every gamma of a sweep would give the same
        // member: refused rather than run as identical copies.
        let roughness_drawn = self
            .ensemble
            .as_ref()
            .is_some_and(|e| e.roughness.is_some());
        let mut distinct = self.gamma.clone();
        distinct.sort_by(f64::total_cmp);
        distinct.dedup();
        if self.gamma_swept && distinct.len() > 1 && chain.dstar.is_none() && !roughness_drawn {
            return Err(gamma_swept_without_roughness(
                "batch.gamma",
                format!("{:?}", self.gamma),
            ));
        }
        // An ensemble's members draw their own roughness or jitter their gaps: their repulsion at
        // t = 0 is theirs, and a member that overflows fails with its own reason.
        let members_start_here = self
            .ensemble
            .as_ref()
            .is_none_or(|e| e.roughness.is_none() && e.jitter == 0.0);
        if members_start_here {
            for (j, &gamma) in self.gamma.iter().enumerate() {
                let field = if self.gamma_swept {
                    format!("batch.gamma[{j}]")
                } else {
                    "model.gamma".to_string()
                };
                check_repulsion_at_start(&chain, gamma, &field, precision)?;
            }
            // Under a sweep a forcing that is not finite at some point fails that point's
            // members, each with its reason, not the study.
            let checked_here = self.sweep.is_none() && self.sweep_point.is_none();
            if let Some(forcing) = self
                .forcing
                .as_ref()
                .filter(|f| checked_here && f.symbolic_count() == 0)
            {
                check_forcing_at_start(&chain, forcing, self.quadrature_points, precision)?;
            }
        }
        Ok(chain)
    }
}

/// Refuses a forcing whose force on some moving particle, F_i = ∫ f(0, x) dx over the particle
/// (by the run's Gauss–Legendre rule, at the centres the step computes), is not finite in
/// `precision` at t = 0: every member would fail at its first step.
pub fn check_forcing_at_start(
    chain: &Chain,
    forcing: &Expr,
    quadrature_points: usize,
    precision: Precision,
) -> Result<()> {
    use roughlub_kernels::step::Forcing as _;
    let rule = crate::model::plan::Forcing {
        expr: forcing.clone(),
        rule: GaussLegendre::new(quadrature_points),
        params: Vec::new(),
    };
    let limit = match precision {
        Precision::F64 => f64::MAX,
        Precision::F32 => f64::from(f32::MAX),
    };
    let mut q = 0.0;
    for (i, &d) in chain.gaps.iter().enumerate().take(chain.particles() - 1) {
        q += d + 2.0 * chain.eps;
        let f = rule.particle_force(&[], chain.eps, 0.0, q);
        if !(f.abs() <= limit) {
            let float = precision.name();
            return Err(Error::invalid(
                "model.forcing",
                format!("\"{}\"", forcing.source()),
                format!(
                    "the force on particle {} (x = {}) at t = 0, its integral over the particle by \
                     {quadrature_points} Gauss-Legendre points, is {f} in {float}: every member \
                     would fail at its first step",
                    i + 1,
                    approx_text(q)
                ),
                format!(
                    "a forcing whose integral over every particle is finite in {float} at t = 0"
                ),
            ));
        }
    }
    Ok(())
}

/// The error for a gamma swept (`field`: in `[batch]` or `[sweep]`) where there is no roughness.
pub(crate) fn gamma_swept_without_roughness(field: &str, value: String) -> Error {
    Error::invalid(
        field,
        value,
        "a gamma sweep without roughness: gamma only enters through the repulsion (rho/rho*)^gamma, and without rho* there is none, so every gamma gives the same member",
        "give initial.rho_star (or an r column in the particle file, or [ensemble] roughness), or drop the gamma sweep",
    )
}

/// Refuses a gamma whose repulsion G_i = (rho_i/rho*_i)^gamma = ((d*_i + 2 eps)/(d_i + 2 eps))^gamma
/// overflows `precision` at t = 0 (gamma ln(rho_i/rho*_i) > ln(MAX) for some free gap): the first
/// step would fail. The message names the gap with the largest ratio, its place and the largest
/// gamma these initial data allow.
pub fn check_repulsion_at_start(
    chain: &Chain,
    gamma: f64,
    field: &str,
    precision: Precision,
) -> Result<()> {
    let Some(dstar) = &chain.dstar else {
        return Ok(());
    };
    let two_eps = 2.0 * chain.eps;
    let bonded = |i: usize| chain.bonded.as_ref().is_some_and(|b| b[i]);
    // The largest ratio over the free gaps (bonded gaps have no repulsion), first one on ties,
    // computed as the step computes it.
    let mut worst: Option<(usize, f64)> = None;
    for (i, (&d, &ds)) in chain.gaps.iter().zip(dstar).enumerate() {
        if bonded(i) {
            continue;
        }
        let ratio = (ds + two_eps) * (1.0 / (d + two_eps));
        if worst.is_none_or(|(_, r)| ratio > r) {
            worst = Some((i, ratio));
        }
    }
    let Some((i, ratio)) = worst else {
        return Ok(());
    };
    let (ln_max, float) = match precision {
        Precision::F64 => (f64::MAX.ln(), "f64"),
        Precision::F32 => (f64::from(f32::MAX).ln(), "f32"),
    };
    let exponent = gamma * ratio.ln();
    if exponent <= ln_max {
        return Ok(());
    }
    let positions = chain.positions();
    let x = 0.5 * (positions[i] + positions[i + 1]);
    // Bounds rounded down so that the values they name are accepted.
    let gamma_max = ln_max / ratio.ln();
    let gamma_max = if gamma_max >= 10.0 {
        gamma_max.floor()
    } else {
        (gamma_max * 100.0).floor() / 100.0
    };
    let ratio_max = ((ln_max / gamma).exp() * 1000.0).floor() / 1000.0;
    Err(Error::invalid(
        field,
        gamma,
        format!(
            "the repulsion G = (rho/rho*)^gamma overflows {float} at t = 0: gap {} (particles {i} and {}, x = {}) starts at rho/rho* = {}, so gamma ln(rho/rho*) = {} > ln({float}::MAX) = {}",
            i + 1,
            i + 1,
            approx_text(x),
            approx_text(ratio),
            approx_text(exponent),
            approx_text(ln_max)
        ),
        format!(
            "gamma <= {} with these initial data, or rho/rho* <= {} in every gap with gamma = {gamma}",
            approx_text(gamma_max),
            approx_text(ratio_max)
        ),
    ))
}
