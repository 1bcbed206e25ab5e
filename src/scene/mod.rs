//! Scene files: the TOML a researcher writes, parsed strictly (unknown keys are errors) and
//! validated into a [`Scene`] whose every value is in range.

pub mod initial;

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::error::{Error, Result};
use crate::backend::{Backend, Precision};
use crate::expr::Expr;
use crate::model::params::{MemberParams, OutputFields, Stepping, FIELD_NAMES};

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
    ensemble: Option<EnsembleSection>,
}

/// `[ensemble]`: many members differing by random roughness and perturbed initial data, summarised
/// by statistics (see `crate::study`).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct EnsembleSection {
    members: i64,
    seed: Option<u64>,
    chunk: Option<i64>,
    roughness: Option<crate::ensemble::RoughnessSpec>,
    mean_radius: Option<f64>,
    velocity_amplitude_spread: Option<f64>,
    velocity_phase_spread: Option<f64>,
    jitter: Option<f64>,
    threshold: Option<f64>,
    store_members: Option<bool>,
    quantiles: Option<Vec<f64>>,
    bins: Option<i64>,
    u_range: Option<[f64; 2]>,
}

/// The validated `[ensemble]` section.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct EnsembleSpec {
    /// Members per sweep point; the study has `members × (sweep points)` members, member m at
    /// sweep point m mod (sweep points).
    pub members: u64,
    pub seed: u64,
    /// Members solved (and kept in memory) at once.
    pub chunk: usize,
    #[serde(skip)]
    pub roughness: Option<crate::ensemble::RoughnessSpec>,
    /// Roughness radius when the scene has no rho* profile.
    pub mean_radius: Option<f64>,
    pub velocity_amplitude_spread: f64,
    pub velocity_phase_spread: f64,
    pub jitter: f64,
    /// Density threshold of the first-hitting-time observable.
    pub threshold: f64,
    pub store_members: bool,
    pub quantiles: Vec<f64>,
    /// Histogram bins of the field quantile bands.
    pub bins: usize,
    pub u_range: Option<[f64; 2]>,
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
    backend: Option<Backend>,
    precision: Option<Precision>,
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
    pub ensemble: Option<EnsembleSpec>,
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
        let backend = s.backend.unwrap_or(Backend::Auto);
        let precision = s.precision.unwrap_or(Precision::F64);

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

        let ensemble = file
            .ensemble
            .as_ref()
            .map(|e| validate_ensemble(e, &initial, path))
            .transpose()?;

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
            ensemble,
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

fn validate_ensemble(
    e: &EnsembleSection,
    initial: &InitialSpec,
    scene_path: &Path,
) -> Result<EnsembleSpec> {
    if !(1..=1_000_000_000).contains(&e.members) {
        return Err(Error::invalid(
            "ensemble.members",
            e.members,
            "members per sweep point",
            "1 ..= 1e9",
        ));
    }
    let chunk = match e.chunk.unwrap_or(256) {
        c @ 1..=1_000_000 => c as usize,
        c => {
            return Err(Error::invalid(
                "ensemble.chunk",
                c,
                "members solved at once (memory)",
                "1 ..= 1000000",
            ))
        }
    };
    let mut roughness = e.roughness.clone();
    if let Some(r) = &mut roughness {
        r.validate().map_err(|err| {
            Error::invalid(
                "ensemble.roughness",
                format!("{r:?}"),
                err.to_string(),
                "see the scene reference",
            )
        })?;
        // A radii file is relative to the scene, like the particle file.
        if let crate::ensemble::RoughnessKind::File(p) = &mut r.kind {
            if p.is_relative() {
                *p = scene_path.parent().unwrap_or(Path::new(".")).join(&*p);
            }
        }
    }
    let has_rho_star = match initial {
        InitialSpec::Profiles { rho_star, .. } => rho_star.is_some(),
        InitialSpec::Particles { .. } => true,
    };
    if let Some(r) = e.mean_radius {
        check_finite("ensemble.mean_radius", r)?;
        if !(r >= 0.0) {
            return Err(Error::invalid(
                "ensemble.mean_radius",
                r,
                "the mean roughness radius",
                ">= 0",
            ));
        }
    }
    if roughness.is_some() && !has_rho_star && e.mean_radius.is_none() {
        return Err(Error::missing(
            "ensemble.mean_radius",
            "random roughness needs a mean profile: give initial.rho_star or ensemble.mean_radius (>= 0)",
        ));
    }
    let spread = |field: &str, v: Option<f64>, max: f64| -> Result<f64> {
        let v = v.unwrap_or(0.0);
        check_finite(field, v)?;
        if !(0.0..=max).contains(&v) {
            return Err(Error::invalid(
                field,
                v,
                "relative spread",
                format!("0 <= value <= {max}"),
            ));
        }
        Ok(v)
    };
    let velocity_amplitude_spread = spread(
        "ensemble.velocity_amplitude_spread",
        e.velocity_amplitude_spread,
        10.0,
    )?;
    let velocity_phase_spread = spread(
        "ensemble.velocity_phase_spread",
        e.velocity_phase_spread,
        1.0,
    )?;
    if velocity_phase_spread > 0.0 && matches!(initial, InitialSpec::Particles { .. }) {
        return Err(Error::missing(
            "ensemble.velocity_phase_spread",
            "a phase shift needs a velocity profile u0(x); with a particle file only the amplitude can vary",
        ));
    }
    let jitter = spread("ensemble.jitter", e.jitter, 2.0)?;
    let threshold = e.threshold.unwrap_or(0.9);
    check_finite("ensemble.threshold", threshold)?;
    if !(threshold > 0.0 && threshold <= 1.0) {
        return Err(Error::invalid(
            "ensemble.threshold",
            threshold,
            "density threshold",
            "0 < threshold <= 1",
        ));
    }
    let quantiles = e
        .quantiles
        .clone()
        .unwrap_or_else(|| vec![0.05, 0.25, 0.5, 0.75, 0.95]);
    if quantiles.is_empty() {
        return Err(Error::invalid(
            "ensemble.quantiles",
            "[]",
            "no quantile",
            "a non-empty list in [0, 1]",
        ));
    }
    for (j, &q) in quantiles.iter().enumerate() {
        if !(0.0..=1.0).contains(&q) {
            return Err(Error::invalid(
                format!("ensemble.quantiles[{j}]"),
                q,
                "a quantile level",
                "0 <= q <= 1",
            ));
        }
    }
    let bins = match e.bins.unwrap_or(400) {
        b @ 4..=100_000 => b as usize,
        b => {
            return Err(Error::invalid(
                "ensemble.bins",
                b,
                "histogram bins of the field bands",
                "4 ..= 100000",
            ))
        }
    };
    if let Some([lo, hi]) = e.u_range {
        if !(lo.is_finite() && hi.is_finite() && lo < hi) {
            return Err(Error::invalid(
                "ensemble.u_range",
                format!("[{lo}, {hi}]"),
                "velocity range of the u band",
                "[lo, hi] with lo < hi",
            ));
        }
    }
    Ok(EnsembleSpec {
        members: e.members as u64,
        seed: e.seed.unwrap_or(0),
        chunk,
        roughness,
        mean_radius: e.mean_radius,
        velocity_amplitude_spread,
        velocity_phase_spread,
        jitter,
        threshold,
        store_members: e.store_members.unwrap_or(false),
        quantiles,
        bins,
        u_range: e.u_range,
    })
}
