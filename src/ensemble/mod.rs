//! Ensembles: members that differ by random roughness profiles and perturbed initial data.
//!
//! # Reproducibility: member m's random inputs are a pure function of (seed, purpose, m)
//!
//! Every random draw of member `m` comes from its own counter-based stream, built by
//! [`member_rng`]:
//!
//! 1. a per-purpose key seed `k = splitmix64(splitmix64(seed) ^ purpose.tag())` (see [`Purpose`]);
//! 2. `ChaCha12Rng::seed_from_u64(k)` (rand_core's PCG32 expansion of `k` into the 256-bit key);
//! 3. `set_stream(m)`: the 64-bit ChaCha nonce is the member index, the block counter starts at 0.
//!
//! So member m's numbers do not depend on how many members are generated, in which order, on
//! which thread, backend or shard. Each purpose (roughness, velocity perturbation, gap jitter) has
//! its own key, so the purposes are independent of one another and adding a purpose (a new tag)
//! never shifts the numbers of another. Within a stream, draw k always goes to the same place
//! (particle k for roughness, gap k for jitter), whatever the spread. Normal variates are
//! `rand_distr::StandardNormal` (ziggurat), so bit-exact reproduction across versions requires the
//! same rand_distr / rand_chacha versions (pinned by Cargo.lock).
//!
//! # Roughness generators ([`RoughnessKind`])
//!
//! Each returns radii r_0..r_N >= 0 with mean `mean_radii[i]` and relative standard deviation
//! `spread` (except `Constant` and `File`, which draw nothing); see [`roughness_radii`] and, for
//! many members without re-validating or re-reading a file, [`RoughnessSampler`]. The pair
//! critical distances follow with [`dstar_from_radii`].

pub mod members;

use std::path::{Path, PathBuf};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha12Rng;
use rand_distr::StandardNormal;
use serde::Deserialize;

/// 1/sqrt(3): the largest relative spread of uniform radii that keeps them non-negative.
pub const UNIFORM_MAX_SPREAD: f64 = 0.577_350_269_189_625_8;

// ---------------------------------------------------------------------------------------------
// Errors
// ---------------------------------------------------------------------------------------------

/// Errors of the ensemble generators; every message names the field and, where there is one, the
/// allowed range.
#[derive(Debug, thiserror::Error)]
pub enum EnsembleError {
    /// A scalar parameter (spread, correlation length, …) outside its allowed range.
    #[error("{field} = {value}: {message} (allowed: {allowed})")]
    InvalidParameter {
        field: String,
        value: f64,
        message: String,
        allowed: String,
    },

    /// One entry of an input array (mean radius, position, gap) outside its allowed range.
    #[error("{field}[{index}] = {value}: {message} (allowed: {allowed})")]
    InvalidEntry {
        field: String,
        index: usize,
        value: f64,
        message: String,
        allowed: String,
    },

    /// Two arrays that must have matching lengths do not.
    #[error("{field} has length {got}, expected {expected}: {message}")]
    LengthMismatch {
        field: String,
        got: usize,
        expected: usize,
        message: String,
    },

    /// A key missing from a roughness specification, or one that does not apply to its kind.
    #[error("{field}: {message}")]
    Spec { field: String, message: String },

    /// A bad row (or header, or row count) in a roughness file.
    #[error("roughness file {path}, line {line}: {message}")]
    RoughnessFile {
        path: PathBuf,
        line: usize,
        message: String,
    },

    /// The roughness file could not be opened.
    #[error("roughness file {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

impl EnsembleError {
    fn parameter(
        field: &str,
        value: f64,
        message: impl Into<String>,
        allowed: impl Into<String>,
    ) -> Self {
        EnsembleError::InvalidParameter {
            field: field.to_string(),
            value,
            message: message.into(),
            allowed: allowed.into(),
        }
    }

    fn entry(
        field: &str,
        index: usize,
        value: f64,
        message: impl Into<String>,
        allowed: impl Into<String>,
    ) -> Self {
        EnsembleError::InvalidEntry {
            field: field.to_string(),
            index,
            value,
            message: message.into(),
            allowed: allowed.into(),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Counter-based member streams
// ---------------------------------------------------------------------------------------------

/// What a random stream is used for. Each purpose has a fixed 64-bit tag (ASCII of its name);
/// the key of member streams for that purpose is derived from (seed, tag), so purposes never share
/// numbers. New purposes get new tags; existing tags must never change.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum Purpose {
    /// Roughness radii ([`roughness_radii`], [`correlated_field`]): draw i belongs to particle i.
    Roughness,
    /// Velocity perturbation ([`perturbed_velocity`]): draw 0 amplitude, draw 1 phase.
    Velocity,
    /// Gap jitter ([`jitter_gaps`]): draw i belongs to gap i (bonded gaps consume theirs too).
    Jitter,
}

impl Purpose {
    /// The fixed tag hashed with the seed: the little-endian bytes of an 8-letter ASCII name.
    pub const fn tag(self) -> u64 {
        match self {
            Purpose::Roughness => u64::from_le_bytes(*b"roughnes"),
            Purpose::Velocity => u64::from_le_bytes(*b"velocity"),
            Purpose::Jitter => u64::from_le_bytes(*b"jittergp"),
        }
    }
}

/// SplitMix64 finaliser (Steele, Lea, Flood 2014): a bijective 64-bit mixer.
const fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The key seed of a purpose: `splitmix64(splitmix64(seed) ^ purpose.tag())`.
pub const fn purpose_seed(seed: u64, purpose: Purpose) -> u64 {
    splitmix64(splitmix64(seed) ^ purpose.tag())
}

/// Member `member`'s stream for `purpose`: `ChaCha12Rng::seed_from_u64(purpose_seed(seed,
/// purpose))` with `set_stream(member)`, starting at word 0. A pure function of its arguments.
pub fn member_rng(seed: u64, purpose: Purpose, member: u64) -> ChaCha12Rng {
    let mut rng = ChaCha12Rng::seed_from_u64(purpose_seed(seed, purpose));
    rng.set_stream(member);
    rng
}

fn normal(rng: &mut ChaCha12Rng) -> f64 {
    rng.sample(StandardNormal)
}

// ---------------------------------------------------------------------------------------------
// Roughness specification
// ---------------------------------------------------------------------------------------------

/// How the roughness radii of a member are drawn. In every random kind, r_i has mean
/// `mean_radii[i]` and relative standard deviation `spread` (sd(r_i)/mean_i = spread).
#[derive(Debug, Clone, PartialEq)]
pub enum RoughnessKind {
    /// r_i = mean_i; no randomness (`spread` must be 0).
    Constant,
    /// r_i = mean_i (1 + sqrt(3) spread U_i), U_i iid uniform on [-1, 1);
    /// requires 0 <= spread <= 1/sqrt(3) ≈ 0.577 (larger spreads would give negative radii).
    Uniform,
    /// r_i = mean_i exp(sigma Z_i - sigma^2/2), Z_i iid N(0,1), sigma^2 = ln(1 + spread^2):
    /// exact mean and relative sd, positive for any spread >= 0.
    LogNormal,
    /// r_i = mean_i (1 ± spread), each sign with probability 1/2 (independent per particle);
    /// requires 0 <= spread <= 1.
    TwoPoint,
    /// Spatially correlated lognormal radii: a stationary unit-variance Gaussian field g(x) with
    /// covariance exp(-|x - x'|/length), sampled exactly at the particle centres q_0..q_N (which
    /// may be non-uniform) by the Ornstein–Uhlenbeck / AR(1) recursion
    /// `g_0 = Z_0`, `g_i = phi_i g_{i-1} + sqrt(1 - phi_i^2) Z_i`, `phi_i = exp(-(q_i - q_{i-1})/length)`,
    /// then mapped like `LogNormal`: r_i = mean_i exp(sigma g_i - sigma^2/2),
    /// sigma^2 = ln(1 + spread^2). Exact mean and relative sd; positive for any spread >= 0.
    /// `length` > 0 (may be +inf: one random factor per member).
    Correlated { length: f64 },
    /// Radii read from a CSV file with one column `r` (header `r`, N+1 rows, `#` comments), the
    /// same for every member (`spread` must be 0). A relative path is taken as is (relative to the
    /// working directory); resolve it against the scene file before building the spec.
    File(PathBuf),
}

/// A roughness generator: the kind and the relative standard deviation of the radii.
///
/// Deserialises from a table with a `kind` key, e.g. (TOML)
/// `{ kind = "lognormal", spread = 0.3 }`, `{ kind = "correlated", length = 0.05, spread = 0.3 }`,
/// `{ kind = "file", path = "radii.csv" }`, `{ kind = "constant" }`; kinds are `constant`,
/// `uniform`, `lognormal`, `twopoint` (alias `two_point`), `correlated`, `file`. `spread` is
/// required by the random kinds and must be absent or 0 for `constant` and `file`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(try_from = "RawRoughnessSpec")]
pub struct RoughnessSpec {
    pub kind: RoughnessKind,
    /// Relative standard deviation of the radii, sd(r_i)/mean_i.
    pub spread: f64,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(rename_all = "lowercase")]
enum RawKind {
    Constant,
    Uniform,
    LogNormal,
    #[serde(alias = "two_point")]
    TwoPoint,
    Correlated,
    File,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRoughnessSpec {
    kind: RawKind,
    spread: Option<f64>,
    length: Option<f64>,
    path: Option<PathBuf>,
}

impl TryFrom<RawRoughnessSpec> for RoughnessSpec {
    type Error = EnsembleError;

    fn try_from(raw: RawRoughnessSpec) -> Result<Self, EnsembleError> {
        let spec_err = |field: &str, message: String| EnsembleError::Spec {
            field: format!("roughness.{field}"),
            message,
        };
        let name = format!("{:?}", raw.kind).to_lowercase();
        let random = !matches!(raw.kind, RawKind::Constant | RawKind::File);
        let spread = match (raw.spread, random) {
            (Some(s), _) => s,
            (None, false) => 0.0,
            (None, true) => {
                return Err(spec_err(
                    "spread",
                    format!("kind = \"{name}\" needs spread (relative standard deviation of r)"),
                ))
            }
        };
        if raw.length.is_some() && !matches!(raw.kind, RawKind::Correlated) {
            return Err(spec_err(
                "length",
                format!("only kind = \"correlated\" takes a correlation length, not \"{name}\""),
            ));
        }
        if raw.path.is_some() && !matches!(raw.kind, RawKind::File) {
            return Err(spec_err(
                "path",
                format!("only kind = \"file\" takes a path, not \"{name}\""),
            ));
        }
        let kind = match raw.kind {
            RawKind::Constant => RoughnessKind::Constant,
            RawKind::Uniform => RoughnessKind::Uniform,
            RawKind::LogNormal => RoughnessKind::LogNormal,
            RawKind::TwoPoint => RoughnessKind::TwoPoint,
            RawKind::Correlated => RoughnessKind::Correlated {
                length: raw.length.ok_or_else(|| {
                    spec_err(
                        "length",
                        "kind = \"correlated\" needs length (correlation length in x, > 0)".into(),
                    )
                })?,
            },
            RawKind::File => RoughnessKind::File(raw.path.ok_or_else(|| {
                spec_err(
                    "path",
                    "kind = \"file\" needs path (a CSV with one column r)".into(),
                )
            })?),
        };
        let spec = RoughnessSpec { kind, spread };
        spec.validate()?;
        Ok(spec)
    }
}

impl RoughnessSpec {
    pub fn new(kind: RoughnessKind, spread: f64) -> Self {
        RoughnessSpec { kind, spread }
    }

    /// Checks `spread` (and `length`) against the kind's allowed range, without touching any
    /// file or profile: suitable at scene load.
    pub fn validate(&self) -> Result<(), EnsembleError> {
        let s = self.spread;
        let field = "roughness.spread";
        match &self.kind {
            RoughnessKind::Constant | RoughnessKind::File(_) => {
                if s != 0.0 {
                    let kind = if matches!(self.kind, RoughnessKind::Constant) {
                        "constant"
                    } else {
                        "file"
                    };
                    return Err(EnsembleError::parameter(
                        field,
                        s,
                        format!("kind = \"{kind}\" draws no random numbers"),
                        "spread = 0 (or leave it out)",
                    ));
                }
            }
            RoughnessKind::Uniform => {
                if !(0.0..=UNIFORM_MAX_SPREAD).contains(&s) {
                    return Err(EnsembleError::parameter(
                        field,
                        s,
                        "uniform radii r = mean (1 + sqrt(3) spread U), U in [-1, 1), are negative \
                         for spread > 1/sqrt(3); use kind = \"lognormal\" for larger spreads",
                        "0 <= spread <= 1/sqrt(3) ≈ 0.577",
                    ));
                }
            }
            RoughnessKind::TwoPoint => {
                if !(0.0..=1.0).contains(&s) {
                    return Err(EnsembleError::parameter(
                        field,
                        s,
                        "two-point radii r = mean (1 ± spread) are negative for spread > 1",
                        "0 <= spread <= 1",
                    ));
                }
            }
            RoughnessKind::LogNormal | RoughnessKind::Correlated { .. } => {
                if !(s >= 0.0 && s.is_finite()) {
                    return Err(EnsembleError::parameter(
                        field,
                        s,
                        "the relative standard deviation must be a finite non-negative number",
                        "0 <= spread < inf",
                    ));
                }
            }
        }
        if let RoughnessKind::Correlated { length } = self.kind {
            if length.is_nan() || length <= 0.0 {
                return Err(EnsembleError::parameter(
                    "roughness.length",
                    length,
                    "the correlation length of the roughness field must be positive",
                    "0 < length <= inf",
                ));
            }
        }
        Ok(())
    }
}

// ---------------------------------------------------------------------------------------------
// Roughness sampling
// ---------------------------------------------------------------------------------------------

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

fn lognormal_sigma(spread: f64) -> f64 {
    // sigma^2 = ln(1 + spread^2): E exp(sigma Z - sigma^2/2) = 1, Var = exp(sigma^2) - 1 = spread^2.
    (spread * spread).ln_1p().sqrt()
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
/// arguments (see the module documentation); for many members use [`RoughnessSampler`].
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

/// Reads a CSV with header `r` and one radius per row (N+1 rows; `#` starts a comment line).
pub fn read_radii_file(path: &Path) -> Result<Vec<f64>, EnsembleError> {
    let err = |line: usize, message: String| EnsembleError::RoughnessFile {
        path: path.to_path_buf(),
        line,
        message,
    };
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .comment(Some(b'#'))
        .from_path(path)
        .map_err(|e| EnsembleError::Io {
            path: path.to_path_buf(),
            source: match e.into_kind() {
                csv::ErrorKind::Io(io) => io,
                other => std::io::Error::other(format!("{other:?}")),
            },
        })?;
    let headers = reader
        .headers()
        .map_err(|e| err(1, format!("cannot read the header: {e}")))?
        .clone();
    let names: Vec<&str> = headers.iter().collect();
    if names != ["r"] {
        return Err(err(
            1,
            format!("header is {names:?}; expected one column named r"),
        ));
    }
    let mut radii = Vec::new();
    let mut record = csv::StringRecord::new();
    loop {
        let more = reader.read_record(&mut record).map_err(|e| {
            err(
                e.position().map_or(0, |p| p.line() as usize),
                format!("unreadable row: {e}"),
            )
        })?;
        if !more {
            break;
        }
        let line = record.position().map_or(0, |p| p.line() as usize);
        let text = record.get(0).unwrap_or("");
        let r: f64 = text
            .parse()
            .map_err(|_| err(line, format!("r = \"{text}\" is not a number")))?;
        if !(r >= 0.0 && r.is_finite()) {
            return Err(err(
                line,
                format!("r = {r}: a roughness radius must be finite and >= 0"),
            ));
        }
        radii.push(r);
    }
    if radii.is_empty() {
        return Err(err(2, "no rows of r (need N+1 radii)".into()));
    }
    Ok(radii)
}

/// Critical distances d*_i = r_{i-1} + r_i, i = 1..N (length N) from radii r_0..r_N.
pub fn dstar_from_radii(r: &[f64]) -> Vec<f64> {
    r.windows(2).map(|w| w[0] + w[1]).collect()
}

/// Per-particle mean radii r̄_0..r̄_N from a mean critical-distance profile d*_1..d*_N (e.g. from a
/// scene's rho* by Prop. 3.1): r̄_i is the average of d*/2 over the gaps adjacent to particle i,
/// r̄_0 = d*_1/2, r̄_N = d*_N/2, r̄_i = (d*_i + d*_{i+1})/4. Then r̄_{i-1} + r̄_i = d*_i/2 +
/// (d*_{i-1} + d*_{i+1})/4 = d*_i + (d*_{i-1} - 2 d*_i + d*_{i+1})/4 for interior gaps (exact for a
/// constant or linear profile, O(h^2 d*'') for a smooth one), and d*_1 + (d*_2 - d*_1)/4,
/// d*_N + (d*_{N-1} - d*_N)/4 at the two end gaps (O(h d*')). An empty profile gives an empty
/// result.
pub fn mean_radii_from_rho_star(dstar_mean: &[f64]) -> Vec<f64> {
    let n = dstar_mean.len();
    if n == 0 {
        return Vec::new();
    }
    let mut r = Vec::with_capacity(n + 1);
    r.push(0.5 * dstar_mean[0]);
    for w in dstar_mean.windows(2) {
        r.push(0.25 * (w[0] + w[1]));
    }
    r.push(0.5 * dstar_mean[n - 1]);
    r
}

// ---------------------------------------------------------------------------------------------
// Initial-data variation
// ---------------------------------------------------------------------------------------------

/// Checks the two spreads of [`perturbed_velocity`] (scene-load validation).
pub fn validate_velocity_perturbation(
    amplitude_spread: f64,
    phase_spread: f64,
) -> Result<(), EnsembleError> {
    for (field, v) in [
        ("velocity.amplitude_spread", amplitude_spread),
        ("velocity.phase_spread", phase_spread),
    ] {
        if !(v >= 0.0 && v.is_finite()) {
            return Err(EnsembleError::parameter(
                field,
                v,
                "a standard deviation must be finite and non-negative",
                "0 <= spread < inf",
            ));
        }
    }
    Ok(())
}

/// Member `member`'s perturbation of a velocity profile u0(x): returns `(factor, phase)` with
/// `factor = 1 + amplitude_spread Z_0` and `phase = phase_spread Z_1`, Z_0, Z_1 independent N(0,1)
/// (draws 0 and 1 of the member's `Velocity` stream, whatever the spreads). So factor has mean 1
/// and standard deviation `amplitude_spread` (it is negative with probability Φ(-1/amplitude_spread),
/// i.e. essentially never for spreads below ~0.25), and phase has mean 0 and standard deviation
/// `phase_spread`, in units of x. The caller evaluates `u_i = factor * u0(q_i - phase)`.
/// Spreads are expected finite and >= 0 (see [`validate_velocity_perturbation`]).
pub fn perturbed_velocity(
    amplitude_spread: f64,
    phase_spread: f64,
    seed: u64,
    member: u64,
) -> (f64, f64) {
    let mut rng = member_rng(seed, Purpose::Velocity, member);
    let z_amplitude = normal(&mut rng);
    let z_phase = normal(&mut rng);
    (1.0 + amplitude_spread * z_amplitude, phase_spread * z_phase)
}

/// Neumaier-compensated sum.
fn compensated_sum(values: impl IntoIterator<Item = f64>) -> f64 {
    let (mut sum, mut c) = (0.0f64, 0.0f64);
    for v in values {
        let t = sum + v;
        c += if sum.abs() >= v.abs() {
            (sum - t) + v
        } else {
            (v - t) + sum
        };
        sum = t;
    }
    sum + c
}

/// Member `member`'s random jitter of particle positions through the gaps d_1..d_N, keeping the
/// total mass (sum of gaps, so q_N = 1) and positive gaps:
///
/// 1. each free gap is multiplied by w_i = exp(s Z_i - s^2/2), s^2 = ln(1 + relative^2), Z_i the
///    i-th normal of the member's `Jitter` stream (lognormal, mean 1, relative sd `relative`;
///    bonded gaps consume their draw too, so gap i's factor does not depend on the bonded set);
/// 2. all free gaps are rescaled by S/S', S and S' the compensated sums of the free gaps before and
///    after step 1;
/// 3. the remaining rounding residual S - sum(new free gaps) (compensated) is added to the largest
///    free gap, twice, so that the compensated sum of the free gaps equals S to within about one
///    ulp of the largest gap (relative error ~1e-16 of the total, independent of N).
///
/// Bonded gaps (`bonded[i] == true`, the zero gaps of Appendix A clusters) are left bit-for-bit
/// untouched. Free gaps must be finite and > 0. On error, `gaps` is unchanged. `relative = 0`
/// leaves the gaps bit-for-bit unchanged.
pub fn jitter_gaps(
    gaps: &mut [f64],
    bonded: Option<&[bool]>,
    relative: f64,
    seed: u64,
    member: u64,
) -> Result<(), EnsembleError> {
    if !(relative >= 0.0 && relative.is_finite()) {
        return Err(EnsembleError::parameter(
            "jitter.relative",
            relative,
            "the relative standard deviation of the gap factors must be finite and non-negative",
            "0 <= relative < inf",
        ));
    }
    if let Some(b) = bonded {
        if b.len() != gaps.len() {
            return Err(EnsembleError::LengthMismatch {
                field: "bonded".into(),
                got: b.len(),
                expected: gaps.len(),
                message: "one flag per gap d_1..d_N".into(),
            });
        }
    }
    let is_free = |i: usize| bonded.is_none_or(|b| !b[i]);
    for (i, &d) in gaps.iter().enumerate() {
        if is_free(i) && !(d > 0.0 && d.is_finite()) {
            return Err(EnsembleError::entry(
                "gaps",
                i,
                d,
                "a free (not bonded) gap must be positive; mark zero gaps as bonded",
                "0 < gap < inf",
            ));
        }
    }
    let free: Vec<usize> = (0..gaps.len()).filter(|&i| is_free(i)).collect();
    if free.is_empty() || relative == 0.0 {
        return Ok(());
    }

    let sigma = lognormal_sigma(relative);
    let shift = 0.5 * sigma * sigma;
    let mut rng = member_rng(seed, Purpose::Jitter, member);
    let mut new = Vec::with_capacity(free.len());
    let mut next_free = free.iter().peekable();
    for (i, &d) in gaps.iter().enumerate() {
        let z = normal(&mut rng);
        if next_free.peek() == Some(&&i) {
            next_free.next();
            new.push(d * (sigma * z - shift).exp());
        }
    }
    let target = compensated_sum(free.iter().map(|&i| gaps[i]));
    let scale = target / compensated_sum(new.iter().copied());
    for v in new.iter_mut() {
        *v *= scale;
    }
    let largest = (0..new.len())
        .max_by(|&a, &b| new[a].total_cmp(&new[b]))
        .expect("at least one free gap");
    for _ in 0..2 {
        let residual = target - compensated_sum(new.iter().copied());
        new[largest] += residual;
    }
    if let Some((k, &v)) = new
        .iter()
        .enumerate()
        .find(|(_, v)| !(**v > 0.0 && v.is_finite()))
    {
        return Err(EnsembleError::entry(
            "gaps",
            free[k],
            v,
            format!("jitter with relative = {relative} produced a non-positive gap"),
            "a smaller jitter.relative",
        ));
    }
    for (&i, &v) in free.iter().zip(&new) {
        gaps[i] = v;
    }
    Ok(())
}
