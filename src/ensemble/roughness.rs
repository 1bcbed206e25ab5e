//! The roughness specification of a scene: which generator draws the radii, with which spread,
//! and its validation.

use std::path::PathBuf;

use serde::Deserialize;

use super::EnsembleError;

/// 1/sqrt(3): the largest relative spread of uniform radii that keeps them non-negative.
pub const UNIFORM_MAX_SPREAD: f64 = 0.577_350_269_189_625_8;
/// The largest relative spread of the lognormal and correlated radii (as `sweep.roughness_spread`).
pub const MAX_RELATIVE_SPREAD: f64 = 10.0;

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
                if !(0.0..=MAX_RELATIVE_SPREAD).contains(&s) {
                    return Err(EnsembleError::parameter(
                        field,
                        s,
                        "the relative standard deviation of the radii: above 10 the median radius \
                         falls below a tenth of the mean, and at 1e10 every gap's d* is ~1e-9 of \
                         its mean (no roughness left in practice)",
                        "0 <= spread <= 10",
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
