//! Scene files: the TOML a researcher writes, parsed strictly (unknown keys are errors) and
//! validated into a [`Scene`] whose every value is in range.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::error::{Error, Result};
use crate::expr::Expr;

// ---------------------------------------------------------------------------------------------
// The file as written (serde). Every table denies unknown keys so that a typo is an error, not a
// silently ignored setting.

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    name: String,
    description: Option<String>,
    model: ModelSection,
    initial: InitialSection,
    time: TimeSection,
    #[serde(default)]
    solver: SolverSection,
    batch: Option<BatchSection>,
    #[serde(default)]
    output: OutputSection,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ModelSection {
    particles: Option<i64>,
    mu: f64,
    gamma: Option<f64>,
    forcing: Option<String>,
    radius: Option<f64>,
    quadrature: Option<i64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct InitialSection {
    rho: Option<String>,
    velocity: Option<String>,
    rho_star: Option<String>,
    particles: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(untagged)]
enum OutputsSpec {
    Count(i64),
    Times(Vec<f64>),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TimeSection {
    end: f64,
    outputs: OutputsSpec,
    dt: Option<f64>,
    tolerance: Option<f64>,
    dt_initial: Option<f64>,
    dt_min: Option<f64>,
}

#[derive(Debug, Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct SolverSection {
    order: Option<i64>,
    backend: Option<String>,
    precision: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct BatchSection {
    mu: Option<Vec<f64>>,
    gamma: Option<Vec<f64>>,
}

#[derive(Debug, Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct OutputSection {
    grid: Option<i64>,
    fields: Option<Vec<String>>,
    plots: Option<bool>,
    plot_members: Option<i64>,
}

// ---------------------------------------------------------------------------------------------
// The validated scene.

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    Cpu,
    Gpu,
    Auto,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    F32,
    F64,
}

impl std::str::FromStr for Backend {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "cpu" => Ok(Backend::Cpu),
            "gpu" => Ok(Backend::Gpu),
            "auto" => Ok(Backend::Auto),
            other => Err(Error::invalid(
                "solver.backend",
                format!("\"{other}\""),
                "unknown backend",
                "\"cpu\", \"gpu\" or \"auto\"",
            )),
        }
    }
}

impl std::str::FromStr for Precision {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "f64" => Ok(Precision::F64),
            "f32" => Ok(Precision::F32),
            other => Err(Error::invalid(
                "solver.precision",
                format!("\"{other}\""),
                "unknown precision",
                "\"f64\" or \"f32\"",
            )),
        }
    }
}

/// How steps are chosen. Fixed: every member steps with `dt` (shortened to land on output times,
/// halved and retried when a step would close a gap). Adaptive: each member its own dt from a
/// local error estimate.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Stepping {
    Fixed {
        dt: f64,
        dt_min: f64,
    },
    Adaptive {
        tolerance: f64,
        dt_initial: f64,
        dt_min: f64,
    },
}

impl Stepping {
    pub fn dt_min(&self) -> f64 {
        match *self {
            Stepping::Fixed { dt_min, .. } | Stepping::Adaptive { dt_min, .. } => dt_min,
        }
    }
}

#[derive(Debug, Clone)]
pub enum InitialSpec {
    /// Macroscopic profiles, discretised by the construction of Prop. 3.1.
    Profiles {
        rho: Expr,
        velocity: Expr,
        rho_star: Option<Expr>,
    },
    /// Explicit particles from a CSV file (x,u[,r]); `radius` is eps.
    Particles { path: PathBuf, radius: f64 },
}

/// Which observables are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct OutputFields {
    pub gaps: bool,
    pub velocities: bool,
    pub rho: bool,
    pub u: bool,
    pub rho_star: bool,
    pub energy: bool,
}

impl OutputFields {
    pub fn all() -> OutputFields {
        OutputFields::uniform(true)
    }
    pub fn none() -> OutputFields {
        OutputFields::uniform(false)
    }
    fn uniform(on: bool) -> OutputFields {
        OutputFields {
            gaps: on,
            velocities: on,
            rho: on,
            u: on,
            rho_star: on,
            energy: on,
        }
    }
}

pub const FIELD_NAMES: [&str; 6] = ["gaps", "velocities", "rho", "u", "rho_star", "energy"];

#[derive(Debug, Clone)]
pub struct Scene {
    pub name: String,
    pub description: Option<String>,
    /// The file's text, kept for the manifest.
    pub source_text: String,
    pub source_path: PathBuf,
    /// N from `model.particles`; for a particle file, `None` until the file is read.
    pub particles: Option<usize>,
    pub mu: Vec<f64>,
    pub gamma: Vec<f64>,
    pub forcing: Option<Expr>,
    pub quadrature_points: usize,
    pub initial: InitialSpec,
    pub end: f64,
    pub output_times: Vec<f64>,
    pub stepping: Stepping,
    pub order: u8,
    pub backend: Backend,
    pub precision: Precision,
    pub grid: usize,
    pub fields: OutputFields,
    pub plots: bool,
    pub plot_members: usize,
}

pub const MAX_PARTICLES: i64 = 100_000_000;
pub const MAX_GAMMA: f64 = 1000.0;

fn check_finite(field: &str, v: f64) -> Result<()> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(Error::invalid(
            field,
            v,
            "not a finite number",
            "a finite number",
        ))
    }
}

fn check_mu(field: &str, mu: f64) -> Result<()> {
    check_finite(field, mu)?;
    if mu > 0.0 {
        Ok(())
    } else {
        Err(Error::invalid(
            field,
            mu,
            "the lubrication coefficient must be positive",
            "mu > 0",
        ))
    }
}

fn check_gamma(field: &str, gamma: f64) -> Result<()> {
    check_finite(field, gamma)?;
    if (1.0..=MAX_GAMMA).contains(&gamma) {
        Ok(())
    } else {
        Err(Error::invalid(
            field,
            gamma,
            "repulsion exponent out of range",
            "1 <= gamma <= 1000",
        ))
    }
}

fn parse_expr(field: &str, text: &str) -> Result<Expr> {
    Expr::parse(text).map_err(|source| Error::Expression {
        field: field.to_string(),
        source_text: text.to_string(),
        source,
    })
}

/// Points at which profiles are checked: a fine uniform grid including both ends.
fn profile_check_points() -> impl Iterator<Item = f64> {
    const M: usize = 20_000;
    (0..=M).map(|k| k as f64 / M as f64)
}

/// Checks that a profile stays in its allowed range on [0, 1] (sampled finely, both ends
/// included): `lower_open`/`upper_closed` encode (0,1) versus (0,1].
fn check_profile(field: &str, e: &Expr, upper_closed: bool) -> Result<()> {
    for x in profile_check_points() {
        let v = e.eval(x, 0.0);
        let ok = v > 0.0 && if upper_closed { v <= 1.0 } else { v < 1.0 };
        if !ok {
            return Err(Error::ProfileRange {
                field: field.to_string(),
                expression: e.source().to_string(),
                value: v,
                x,
                allowed: if upper_closed { "(0, 1]" } else { "(0, 1)" }.to_string(),
            });
        }
    }
    Ok(())
}

impl Scene {
    pub fn from_file(path: &Path) -> Result<Scene> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        Scene::from_toml(&text, path)
    }

    /// Parses and validates. `path` names the file in messages and anchors relative particle
    /// file paths.
    pub fn from_toml(text: &str, path: &Path) -> Result<Scene> {
        let file: SceneFile = toml::from_str(text).map_err(|e| Error::SceneSyntax {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;

        let name = file.name.trim().to_string();
        if name.is_empty()
            || !name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-' || c == '.')
        {
            return Err(Error::invalid(
                "name",
                format!("\"{}\"", file.name),
                "the name is used as a directory name",
                "a non-empty name of letters, digits, '_', '-', '.'",
            ));
        }

        // --- model
        let m = &file.model;
        let particles = match m.particles {
            Some(n) if (2..=MAX_PARTICLES).contains(&n) => Some(n as usize),
            Some(n) => {
                return Err(Error::invalid(
                    "model.particles",
                    n,
                    "N counts the particles 0..N, so at least one particle moves",
                    format!("2 <= particles <= {MAX_PARTICLES}"),
                ))
            }
            None => None,
        };
        check_mu("model.mu", m.mu)?;
        let gamma = m.gamma.unwrap_or(1.0);
        check_gamma("model.gamma", gamma)?;
        let forcing = m
            .forcing
            .as_deref()
            .map(|s| parse_expr("model.forcing", s))
            .transpose()?;
        let quadrature_points = match m.quadrature.unwrap_or(3) {
            q @ 2..=8 => q as usize,
            q => {
                return Err(Error::invalid(
                    "model.quadrature",
                    q,
                    "Gauss-Legendre points per particle for the forcing integral",
                    "2 ..= 8",
                ))
            }
        };

        // --- initial data
        let ini = &file.initial;
        if ini.particles.is_some()
            && (ini.rho.is_some() || ini.velocity.is_some() || ini.rho_star.is_some())
        {
            return Err(Error::missing(
                "initial.particles",
                "give either a particle file or the profiles rho/velocity/rho_star, not both",
            ));
        }
        let initial = match (&ini.particles, &ini.rho) {
            (Some(p), _) => {
                let radius = m.radius.ok_or_else(|| {
                    Error::missing(
                        "model.radius",
                        "a particle file needs the particle radius eps (model.radius > 0)",
                    )
                })?;
                check_finite("model.radius", radius)?;
                if !(radius > 0.0 && radius < 0.5) {
                    return Err(Error::invalid(
                        "model.radius",
                        radius,
                        "the particle radius eps",
                        "0 < radius < 0.5",
                    ));
                }
                let base = path.parent().unwrap_or(Path::new("."));
                InitialSpec::Particles {
                    path: base.join(p),
                    radius,
                }
            }
            (None, Some(rho)) => {
                if m.radius.is_some() {
                    return Err(Error::missing(
                        "model.radius",
                        "only with [initial] particles: from profiles, eps = M0/(2N) follows from rho",
                    ));
                }
                if particles.is_none() {
                    return Err(Error::missing(
                        "model.particles",
                        "the number N of particle intervals is required with profile initial data (2 <= particles)",
                    ));
                }
                let rho = parse_expr("initial.rho", rho)?;
                check_profile("initial.rho", &rho, false)?;
                let velocity = parse_expr("initial.velocity", ini.velocity.as_deref().unwrap_or("0"))?;
                for x in profile_check_points() {
                    let v = velocity.eval(x, 0.0);
                    if !v.is_finite() {
                        return Err(Error::ProfileRange {
                            field: "initial.velocity".into(),
                            expression: velocity.source().into(),
                            value: v,
                            x,
                            allowed: "finite values".into(),
                        });
                    }
                }
                let rho_star = ini
                    .rho_star
                    .as_deref()
                    .map(|s| parse_expr("initial.rho_star", s))
                    .transpose()?;
                if let Some(rs) = &rho_star {
                    check_profile("initial.rho_star", rs, true)?;
                }
                InitialSpec::Profiles {
                    rho,
                    velocity,
                    rho_star,
                }
            }
            (None, None) => {
                return Err(Error::missing(
                    "initial",
                    "give the profiles (initial.rho, initial.velocity, optional initial.rho_star) or initial.particles = \"file.csv\"",
                ))
            }
        };

        // --- time
        let t = &file.time;
        check_finite("time.end", t.end)?;
        if !(t.end > 0.0) {
            return Err(Error::invalid(
                "time.end",
                t.end,
                "the final time",
                "end > 0",
            ));
        }
        let output_times = match &t.outputs {
            OutputsSpec::Count(k) => {
                if !(2..=100_000).contains(k) {
                    return Err(Error::invalid(
                        "time.outputs",
                        k,
                        "number of evenly spaced output times including 0 and end",
                        "2 ..= 100000, or a list of times",
                    ));
                }
                let k = *k as usize;
                (0..k)
                    .map(|j| {
                        if j + 1 == k {
                            t.end
                        } else {
                            t.end * j as f64 / (k - 1) as f64
                        }
                    })
                    .collect()
            }
            OutputsSpec::Times(list) => {
                if list.is_empty() {
                    return Err(Error::invalid(
                        "time.outputs",
                        "[]",
                        "no output time",
                        "a non-empty increasing list of times in [0, end]",
                    ));
                }
                for (j, &v) in list.iter().enumerate() {
                    let field = format!("time.outputs[{j}]");
                    check_finite(&field, v)?;
                    if !(0.0..=t.end).contains(&v) || (j > 0 && v <= list[j - 1]) {
                        return Err(Error::invalid(
                            field,
                            v,
                            "output times must increase strictly and lie in [0, end]",
                            format!("previous time < value <= {}", t.end),
                        ));
                    }
                }
                list.clone()
            }
        };
        let dt_min = match t.dt_min {
            Some(v) => {
                check_finite("time.dt_min", v)?;
                if !(v > 0.0 && v < t.end) {
                    return Err(Error::invalid(
                        "time.dt_min",
                        v,
                        "a member whose step falls below dt_min is marked failed",
                        "0 < dt_min < end",
                    ));
                }
                v
            }
            None => 1e-12 * t.end,
        };
        let stepping = match (t.dt, t.tolerance) {
            (Some(dt), None) => {
                check_finite("time.dt", dt)?;
                if !(dt > dt_min && dt <= t.end) {
                    return Err(Error::invalid(
                        "time.dt",
                        dt,
                        "the fixed step",
                        format!("{dt_min:e} < dt <= end = {}", t.end),
                    ));
                }
                if t.dt_initial.is_some() {
                    return Err(Error::missing(
                        "time.dt_initial",
                        "only with adaptive steps (time.tolerance)",
                    ));
                }
                Stepping::Fixed { dt, dt_min }
            }
            (None, Some(tol)) => {
                check_finite("time.tolerance", tol)?;
                if !(1e-13..=1e-1).contains(&tol) {
                    return Err(Error::invalid(
                        "time.tolerance",
                        tol,
                        "local error tolerance of adaptive steps",
                        "1e-13 <= tolerance <= 0.1",
                    ));
                }
                let dt_initial = t.dt_initial.unwrap_or(1e-4 * t.end);
                check_finite("time.dt_initial", dt_initial)?;
                if !(dt_initial > dt_min && dt_initial <= t.end) {
                    return Err(Error::invalid(
                        "time.dt_initial",
                        dt_initial,
                        "the first trial step",
                        format!("{dt_min:e} < dt_initial <= end"),
                    ));
                }
                Stepping::Adaptive {
                    tolerance: tol,
                    dt_initial,
                    dt_min,
                }
            }
            (Some(_), Some(_)) => return Err(Error::missing(
                "time.dt",
                "give either time.dt (fixed steps) or time.tolerance (adaptive steps), not both",
            )),
            (None, None) => {
                return Err(Error::missing(
                    "time.dt",
                    "give time.dt (fixed steps, 0 < dt <= end) or time.tolerance (adaptive steps)",
                ))
            }
        };

        // --- solver
        let s = &file.solver;
        let order = match s.order.unwrap_or(1) {
            1 => 1,
            2 => 2,
            o => {
                return Err(Error::invalid(
                    "solver.order",
                    o,
                    "order of the time scheme",
                    "1 (linearly implicit Euler) or 2 (Richardson-extrapolated)",
                ))
            }
        };
        let backend: Backend = s.backend.as_deref().unwrap_or("auto").parse()?;
        let precision: Precision = s.precision.as_deref().unwrap_or("f64").parse()?;

        // --- batch sweep: lists replace the model's scalar and form a cartesian product.
        let mut mu = vec![m.mu];
        let mut gammas = vec![gamma];
        if let Some(b) = &file.batch {
            if let Some(list) = &b.mu {
                if list.is_empty() {
                    return Err(Error::invalid(
                        "batch.mu",
                        "[]",
                        "empty sweep",
                        "a non-empty list of mu > 0",
                    ));
                }
                for (j, &v) in list.iter().enumerate() {
                    check_mu(&format!("batch.mu[{j}]"), v)?;
                }
                mu = list.clone();
            }
            if let Some(list) = &b.gamma {
                if list.is_empty() {
                    return Err(Error::invalid(
                        "batch.gamma",
                        "[]",
                        "empty sweep",
                        "a non-empty list of 1 <= gamma <= 1000",
                    ));
                }
                for (j, &v) in list.iter().enumerate() {
                    check_gamma(&format!("batch.gamma[{j}]"), v)?;
                }
                gammas = list.clone();
            }
        }

        // --- output
        let o = &file.output;
        let grid = match o.grid.unwrap_or(200) {
            g @ 2..=1_000_000 => g as usize,
            g => {
                return Err(Error::invalid(
                    "output.grid",
                    g,
                    "points of the macroscopic fields",
                    "2 ..= 1000000",
                ))
            }
        };
        let fields = match &o.fields {
            None => OutputFields::all(),
            Some(list) => {
                let mut f = OutputFields::none();
                for (j, name) in list.iter().enumerate() {
                    match name.as_str() {
                        "gaps" => f.gaps = true,
                        "velocities" => f.velocities = true,
                        "rho" => f.rho = true,
                        "u" => f.u = true,
                        "rho_star" => f.rho_star = true,
                        "energy" => f.energy = true,
                        other => {
                            return Err(Error::invalid(
                                format!("output.fields[{j}]"),
                                format!("\"{other}\""),
                                "unknown output field",
                                FIELD_NAMES.join(", "),
                            ))
                        }
                    }
                }
                f
            }
        };
        let plot_members = match o.plot_members.unwrap_or(4) {
            p @ 0..=1000 => p as usize,
            p => {
                return Err(Error::invalid(
                    "output.plot_members",
                    p,
                    "how many members get profile plots",
                    "0 ..= 1000",
                ))
            }
        };

        Ok(Scene {
            name,
            description: file.description.clone(),
            source_text: text.to_string(),
            source_path: path.to_path_buf(),
            particles,
            mu,
            gamma: gammas,
            forcing,
            quadrature_points,
            initial,
            end: t.end,
            output_times,
            stepping,
            order,
            backend,
            precision,
            grid,
            fields,
            plots: o.plots.unwrap_or(true),
            plot_members,
        })
    }

    /// Members of the sweep: the cartesian product of the mu and gamma lists, gamma outermost so
    /// that neighbouring members (which share a SIMD block) usually share gamma.
    pub fn member_parameters(&self) -> Vec<MemberParams> {
        let mut out = Vec::with_capacity(self.mu.len() * self.gamma.len());
        for &gamma in &self.gamma {
            for &mu in &self.mu {
                out.push(MemberParams { mu, gamma });
            }
        }
        out
    }
}

/// Per-member physical parameters.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct MemberParams {
    pub mu: f64,
    pub gamma: f64,
}
