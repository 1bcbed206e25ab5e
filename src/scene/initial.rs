//! Initial chains: from macroscopic profiles by the construction of Prop. 3.1, or from a particle
//! file (`super::particle_file`). The state is gaps and velocities (never positions), see
//! DESIGN.md §2.

use super::{InitialSpec, Scene};
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
    let mut cumulative = Vec::with_capacity(panels + 1);
    cumulative.push(0.0);
    // Neumaier-compensated running sum: M0 and the cell masses keep full precision at large N.
    let (mut mass, mut compensation) = (0.0f64, 0.0f64);
    for k in 0..panels {
        let a = k as f64 * h;
        let term = gl.integrate_adaptive(a, a + h, &mut density);
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

    let mut q = vec![0.0; n + 1];
    q[n] = 1.0;
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
            let m = m_a + gl.integrate_adaptive(a, x, &mut density);
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
        q[i] = x;
    }

    let mut gaps = Vec::with_capacity(n);
    for i in 1..=n {
        let d = q[i] - q[i - 1] - 2.0 * eps;
        if !(d > 0.0) {
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
        (1..=n)
            .map(|i| {
                let width = q[i] - q[i - 1];
                // The mean of a profile <= 1 can exceed 1 only by rounding.
                let mean = (gl.integrate_adaptive(q[i - 1], q[i], &mut |x| rs.eval(x, 0.0))
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

impl Scene {
    /// The initial chain the scene describes (Prop. 3.1 from profiles, or the particle file).
    pub fn initial_chain(&self) -> Result<Chain> {
        match &self.initial {
            InitialSpec::Profiles {
                rho,
                velocity,
                rho_star,
            } => {
                let n = self.particles.ok_or_else(|| {
                    Error::missing("model.particles", "required with profile initial data")
                })?;
                chain_from_profiles(n, rho, velocity, rho_star.as_ref())
            }
            InitialSpec::Particles { path, radius } => {
                chain_from_particle_file(path, *radius, self.particles)
            }
        }
    }
}
