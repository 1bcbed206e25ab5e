//! Drawing the roughness radii of members: a validated [`RoughnessSampler`] and the one-member
//! functions built on it.

use rand::Rng;
use rand_chacha::ChaCha12Rng;

use super::radii::read_radii_file;
use super::roughness::{RoughnessKind, RoughnessSpec};
use super::streams::{lognormal_sigma, member_rng, normal, Purpose};
use super::EnsembleError;

/// A validated spec reduced to what each member's draw needs (derived constants, AR(1)
/// coefficients or the file's radii), so that members do not redo that work.
#[derive(Debug, Clone)]
enum Prepared {
    Constant,
    /// a = sqrt(3) spread.
    Uniform {
        a: f64,
    },
    LogNormal {
        sigma: f64,
    },
    TwoPoint {
        spread: f64,
    },
    Correlated {
        sigma: f64,
        ou: OuCoefficients,
    },
    File {
        radii: Vec<f64>,
    },
}

/// AR(1) coefficients of the exponential-covariance field at given positions.
#[derive(Debug, Clone)]
struct OuCoefficients {
    /// phi_i = exp(-(q_i - q_{i-1})/length), i = 1..N (index 0 unused).
    phi: Vec<f64>,
    /// sqrt(1 - phi_i^2), computed as sqrt(-expm1(-2 (q_i - q_{i-1})/length)).
    innovation: Vec<f64>,
}

impl OuCoefficients {
    fn new(positions: &[f64], length: f64) -> Result<Self, EnsembleError> {
        let n1 = positions.len();
        let mut phi = vec![0.0; n1];
        let mut innovation = vec![1.0; n1];
        for (i, &q) in positions.iter().enumerate() {
            if !q.is_finite() {
                return Err(EnsembleError::entry(
                    "positions",
                    i,
                    q,
                    "particle positions must be finite",
                    "finite, non-decreasing q_0..q_N",
                ));
            }
            if i == 0 {
                continue;
            }
            let dq = q - positions[i - 1];
            if dq < 0.0 {
                return Err(EnsembleError::entry(
                    "positions",
                    i,
                    q,
                    format!("positions decrease (q_{} = {})", i - 1, positions[i - 1]),
                    "finite, non-decreasing q_0..q_N",
                ));
            }
            let x = dq / length;
            phi[i] = (-x).exp();
            innovation[i] = (-(-2.0 * x).exp_m1()).sqrt();
        }
        Ok(OuCoefficients { phi, innovation })
    }

    /// g_0 = Z_0, g_i = phi_i g_{i-1} + sqrt(1 - phi_i^2) Z_i.
    fn fill(&self, rng: &mut ChaCha12Rng, out: &mut [f64]) {
        let mut g = 0.0;
        for (i, o) in out.iter_mut().enumerate() {
            let z = normal(rng);
            g = if i == 0 {
                z
            } else {
                self.phi[i] * g + self.innovation[i] * z
            };
            *o = g;
        }
    }
}

/// A validated roughness generator for many members: checks the spec and profiles and reads a
/// roughness file once; [`RoughnessSampler::fill`] then draws member m's radii without allocating.
/// `fill(m)` gives exactly what [`roughness_radii`] gives for member m.
#[derive(Debug, Clone)]
pub struct RoughnessSampler {
    prepared: Prepared,
    mean: Vec<f64>,
    seed: u64,
}

impl RoughnessSampler {
    /// `mean_radii`: per-particle mean radii r̄_0..r̄_N (finite, >= 0). `positions`: particle
    /// centres q_0..q_N, used only by `Correlated` (may be empty for the other kinds).
    pub fn new(
        spec: &RoughnessSpec,
        mean_radii: &[f64],
        positions: &[f64],
        seed: u64,
    ) -> Result<Self, EnsembleError> {
        spec.validate()?;
        for (i, &m) in mean_radii.iter().enumerate() {
            if !(m >= 0.0 && m.is_finite()) {
                return Err(EnsembleError::entry(
                    "mean_radii",
                    i,
                    m,
                    "mean roughness radii must be finite and non-negative",
                    "0 <= mean radius < inf",
                ));
            }
        }
        let prepared = match &spec.kind {
            RoughnessKind::Constant => Prepared::Constant,
            RoughnessKind::Uniform => Prepared::Uniform {
                a: 3f64.sqrt() * spec.spread,
            },
            RoughnessKind::LogNormal => Prepared::LogNormal {
                sigma: lognormal_sigma(spec.spread),
            },
            RoughnessKind::TwoPoint => Prepared::TwoPoint {
                spread: spec.spread,
            },
            RoughnessKind::Correlated { length } => {
                if positions.len() != mean_radii.len() {
                    return Err(EnsembleError::LengthMismatch {
                        field: "positions".into(),
                        got: positions.len(),
                        expected: mean_radii.len(),
                        message: "correlated roughness needs one position q_i per particle \
                                  (as many as mean_radii)"
                            .into(),
                    });
                }
                Prepared::Correlated {
                    sigma: lognormal_sigma(spec.spread),
                    ou: OuCoefficients::new(positions, *length)?,
                }
            }
            RoughnessKind::File(path) => {
                let radii = read_radii_file(path)?;
                if radii.len() != mean_radii.len() {
                    return Err(EnsembleError::RoughnessFile {
                        path: path.clone(),
                        line: radii.len() + 2,
                        message: format!(
                            "{} rows of r, but the chain has N+1 = {} particles",
                            radii.len(),
                            mean_radii.len()
                        ),
                    });
                }
                Prepared::File { radii }
            }
        };
        Ok(RoughnessSampler {
            prepared,
            mean: mean_radii.to_vec(),
            seed,
        })
    }

    /// Number of particles N+1.
    pub fn len(&self) -> usize {
        self.mean.len()
    }

    pub fn is_empty(&self) -> bool {
        self.mean.is_empty()
    }

    /// Member `member`'s radii r_0..r_N into `out` (length N+1; panics otherwise).
    pub fn fill(&self, member: u64, out: &mut [f64]) {
        assert_eq!(
            out.len(),
            self.mean.len(),
            "RoughnessSampler::fill: out has length {}, the chain has N+1 = {} particles",
            out.len(),
            self.mean.len()
        );
        let mean = &self.mean;
        let rng = || member_rng(self.seed, Purpose::Roughness, member);
        match &self.prepared {
            Prepared::Constant => out.copy_from_slice(mean),
            Prepared::File { radii } => out.copy_from_slice(radii),
            Prepared::Uniform { a } => {
                let mut rng = rng();
                for (o, &m) in out.iter_mut().zip(mean) {
                    // U uniform on [-1, 1) (53-bit grid). max(0): at spread = 1/sqrt(3) exactly,
                    // the rounding of sqrt(3) spread may exceed 1 by an ulp.
                    let u = 2.0 * rng.random::<f64>() - 1.0;
                    *o = (m * (1.0 + a * u)).max(0.0);
                }
            }
            Prepared::LogNormal { sigma } => {
                let mut rng = rng();
                let shift = 0.5 * sigma * sigma;
                for (o, &m) in out.iter_mut().zip(mean) {
                    *o = m * (sigma * normal(&mut rng) - shift).exp();
                }
            }
            Prepared::TwoPoint { spread } => {
                let mut rng = rng();
                for (o, &m) in out.iter_mut().zip(mean) {
                    let sign = if rng.random::<bool>() { 1.0 } else { -1.0 };
                    *o = m * (1.0 + sign * spread);
                }
            }
            Prepared::Correlated { sigma, ou } => {
                let mut rng = rng();
                ou.fill(&mut rng, out);
                let shift = 0.5 * sigma * sigma;
                for (o, &m) in out.iter_mut().zip(mean) {
                    *o = m * (sigma * *o - shift).exp();
                }
            }
        }
    }

    /// Member `member`'s radii r_0..r_N.
    pub fn sample(&self, member: u64) -> Vec<f64> {
        let mut out = vec![0.0; self.mean.len()];
        self.fill(member, &mut out);
        out
    }
}

/// Member `member`'s roughness radii r_0..r_N (>= 0), each with mean `mean_radii[i]` and relative
/// standard deviation `spec.spread` (see [`RoughnessKind`] for each generator). `positions`
/// (q_0..q_N) is used only by `Correlated` and may be empty otherwise. A pure function of its
/// arguments (see the [`ensemble`](super) documentation); for many members use [`RoughnessSampler`].
pub fn roughness_radii(
    spec: &RoughnessSpec,
    mean_radii: &[f64],
    positions: &[f64],
    seed: u64,
    member: u64,
) -> Result<Vec<f64>, EnsembleError> {
    Ok(RoughnessSampler::new(spec, mean_radii, positions, seed)?.sample(member))
}

/// The unit-variance Gaussian field g_0..g_N behind `Correlated` roughness (before the lognormal
/// map), with Cov(g_i, g_j) = exp(-|q_i - q_j|/length): for the same (seed, member) and a spec
/// `Correlated { length }` with spread s, the radii are exactly r_i = mean_i exp(sigma g_i -
/// sigma^2/2), sigma^2 = ln(1 + s^2).
pub fn correlated_field(
    positions: &[f64],
    length: f64,
    seed: u64,
    member: u64,
) -> Result<Vec<f64>, EnsembleError> {
    RoughnessSpec::new(RoughnessKind::Correlated { length }, 0.0).validate()?;
    let ou = OuCoefficients::new(positions, length)?;
    let mut out = vec![0.0; positions.len()];
    ou.fill(&mut member_rng(seed, Purpose::Roughness, member), &mut out);
    Ok(out)
}
