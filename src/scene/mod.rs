//! Scene files: the TOML a researcher writes, parsed strictly (unknown keys are errors) and
//! validated into a [`Scene`] whose every value is in range.
//!
//! `file` is the TOML as written; [`Scene::from_toml`] validates it one section at a time (the
//! functions below, and `ensemble` for `[ensemble]`) with the checks of `checks`. `initial` and
//! `particle_file` then build the initial chain.

mod checks;
mod ensemble;
mod file;
pub mod initial;
pub mod members;
mod particle_file;
mod plan;
pub mod sweep;
#[cfg(test)]
mod tests;
mod time;

use std::path::{Path, PathBuf};

pub use ensemble::{EnsembleSpec, DEFAULT_DETAILED_SAMPLED_POINTS};
pub use sweep::{SweepSpec, SweepTarget, MAX_SWEEP_POINTS};

use crate::backend::{Backend, Precision};
use crate::error::{Error, Result};
use crate::expr::Expr;
pub(crate) use crate::input::number_text;
use crate::model::params::{
    Jacobian, MemberParams, Order, OutputFields, SequenceChoice, Stepping, FIELD_NAMES, MAX_ORDER,
};
use checks::{
    approx_text, check_gamma, check_mu, check_non_empty, check_profile, check_range, parse_expr,
    Range,
};
use file::{
    BatchSection, InitialSection, ModelSection, OrderValue, OutputSection, SceneFile, SolverSection,
};

// One per scene: the size of its largest variant costs nothing worth a box.
#[allow(clippy::large_enum_variant)]
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
    /// Whether `gamma` is the `[batch] gamma` list (messages then name `batch.gamma[j]`) rather
    /// than `model.gamma`.
    pub gamma_swept: bool,
    pub forcing: Option<Expr>,
    pub quadrature_points: usize,
    pub initial: InitialSpec,
    pub end: f64,
    pub output_times: Vec<f64>,
    pub stepping: Stepping,
    pub order: Order,
    pub backend: Backend,
    pub precision: Precision,
    /// `[solver] error_estimate`: order 1 with fixed steps runs a companion at 4 dt to estimate
    /// its error ([`crate::backend::companion`]); false turns it off.
    pub error_estimate: bool,
    /// `[solver] jacobian`: the matrix of the extrapolated steps ([`Jacobian`]).
    pub jacobian: Jacobian,
    /// `[solver] sequence`: the substeps of the tableau's rows as asked for ([`SequenceChoice`];
    /// the plan holds the one that runs).
    pub sequence: SequenceChoice,
    pub grid: usize,
    pub fields: OutputFields,
    /// `output.fields` lists rho_star where there is no roughness (said by
    /// [`Scene::ignored_settings`]).
    pub rho_star_listed_without_roughness: bool,
    pub plots: bool,
    pub plot_members: usize,
    pub ensemble: Option<EnsembleSpec>,
    /// `[parameters]`: names usable in every expression, with their values (file order).
    pub parameters: Vec<(String, f64)>,
    /// `[sweep]` of an ensemble (or its `[batch]` lists as a grid); `None`: one point.
    pub sweep: Option<SweepSpec>,
    /// The sweep point this scene was made for ([`Scene::at_point`]), whose members' failures
    /// are the study's to report (a forcing not finite at t = 0 fails that point's members
    /// rather than the whole study); `None` for a scene read from a file.
    pub sweep_point: Option<u64>,
    /// Not from the file: what the environment overrides, set by the command line after loading
    /// (`Overrides::from_env`, read once in `main`) and passed on to every plan built from the
    /// scene. The default overrides nothing.
    pub overrides: crate::backend::overrides::Overrides,
}

pub const MAX_PARTICLES: i64 = 100_000_000;
pub const MAX_GAMMA: f64 = 1000.0;
/// The largest lubrication coefficient mu (see `checks::check_mu`).
pub const MAX_MU: f64 = 1e12;
/// The largest initial speed |u0|, in domain lengths per unit time: beyond it one step of the
/// smallest size moves a particle across the domain, and from about 1e154 the kinetic energy
/// eps Σ u_i² overflows f64.
pub const MAX_VELOCITY: f64 = 1e12;
pub use crate::ensemble::MAX_ROUGHNESS_RADIUS;

impl Scene {
    /// Every file the scene's members are read from besides the scene itself (a particle file,
    /// an ensemble's roughness file): what a run's manifest hashes and `--resume` and `merge`
    /// compare.
    pub fn files_read(&self) -> Vec<&Path> {
        let mut paths: Vec<&Path> = Vec::new();
        if let InitialSpec::Particles { path, .. } = &self.initial {
            paths.push(path);
        }
        if let Some(r) = self.ensemble.as_ref().and_then(|e| e.roughness.as_ref()) {
            if let crate::ensemble::RoughnessKind::File(path) = &r.kind {
                paths.push(path);
            }
        }
        paths
    }

    /// Settings the scene asks for that have no effect, each as a sentence: order 1's rows
    /// are one Euler step and its two halves with the frozen matrix, whatever `sequence` and
    /// `jacobian` say (the manifest records what ran, so the value asked for would be lost
    /// without a word).
    pub fn ignored_settings(&self) -> Vec<String> {
        let mut notes = Vec::new();
        if self.order == Order::Fixed(1) {
            if self.sequence == SequenceChoice::FromTwo {
                notes.push(
                    "solver.sequence = \"from_2\" has no effect with order 1 (its rows are one \
                     Euler step and its two halves); the run uses from_1"
                        .to_string(),
                );
            }
            if self.jacobian == Jacobian::Exact {
                notes.push(
                    "solver.jacobian = \"exact\" has no effect with order 1 (it keeps the frozen \
                     matrix and its energy certificate); the run uses frozen"
                        .to_string(),
                );
            }
        }
        if self.rho_star_listed_without_roughness {
            notes.push(
                "output.fields lists \"rho_star\", which a scene without roughness (no \
                 initial.rho_star, no ensemble.roughness) does not have; no rho_star is written"
                    .to_string(),
            );
        }
        notes
    }

    pub fn from_file(path: &Path) -> Result<Scene> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        Scene::from_toml(&text, path)
    }

    /// Parses and validates. `path` names the file in messages and anchors relative particle
    /// file paths. Sections are checked in file order, so the first bad value is reported.
    pub fn from_toml(text: &str, path: &Path) -> Result<Scene> {
        let file: SceneFile = toml::from_str(text).map_err(|e| Error::SceneSyntax {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        let name = validate_name(&file.name)?;
        let parameters = sweep::validate_parameters(file.parameters.as_ref())?;
        let model = validate_model(&file.model, &parameters)?;
        let initial = validate_initial(
            &file.initial,
            &file.model,
            model.particles,
            path,
            &parameters,
        )?;
        let time = time::validate_time(&file.time)?;
        let (order, backend, precision) = validate_solver(&file.solver, &time.stepping)?;
        let (mu, gamma) = validate_batch(file.batch.as_ref(), file.model.mu, model.gamma)?;
        let output = validate_output(&file.output)?;
        let ensemble = file
            .ensemble
            .as_ref()
            .map(|e| ensemble::validate_ensemble(e, &initial, path))
            .transpose()?;
        // A field listed by name that the scene cannot have is left out, and said (a warning,
        // not an error: a script may list the same fields for scenes with and without roughness).
        let rho_star_listed_without_roughness =
            matches!(initial, InitialSpec::Profiles { rho_star: None, .. })
                && ensemble.as_ref().is_none_or(|e| e.roughness.is_none())
                && file
                    .output
                    .fields
                    .as_ref()
                    .is_some_and(|list| list.iter().any(|f| f == "rho_star"));
        let sweep = sweep::validate_sweep(
            file.sweep.as_ref(),
            file.batch.as_ref(),
            &parameters,
            ensemble.as_ref(),
            &initial,
        )?;

        Ok(Scene {
            name,
            description: file.description.clone(),
            source_text: text.to_string(),
            source_path: path.to_path_buf(),
            particles: model.particles,
            mu,
            gamma,
            gamma_swept: file.batch.as_ref().is_some_and(|b| b.gamma.is_some()),
            forcing: model.forcing,
            quadrature_points: model.quadrature_points,
            initial,
            end: file.time.end,
            output_times: time.output_times,
            stepping: time.stepping,
            order,
            backend,
            precision,
            error_estimate: file.solver.error_estimate.unwrap_or(true),
            jacobian: parse_choice(
                "solver.jacobian",
                "matrix of the extrapolated steps",
                file.solver.jacobian.as_deref(),
                Jacobian::Auto,
            )?,
            sequence: parse_choice(
                "solver.sequence",
                "substeps of the tableau's rows",
                file.solver.sequence.as_deref(),
                SequenceChoice::Auto,
            )?,
            grid: output.grid,
            fields: output.fields,
            rho_star_listed_without_roughness,
            plots: output.plots,
            plot_members: output.plot_members,
            ensemble,
            parameters,
            sweep,
            sweep_point: None,
            overrides: Default::default(),
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

/// The name becomes the output directory's name, so it is restricted to safe characters.
fn validate_name(written: &str) -> Result<String> {
    let name = written.trim().to_string();
    if name.is_empty()
        || name == "."
        || name == ".."
        || !name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-' || c == '.')
    {
        return Err(Error::invalid(
            "name",
            format!("\"{written}\""),
            "the name is used as a directory name",
            "a non-empty name of letters, digits, '_', '-', '.', not . or ..",
        ));
    }
    Ok(name)
}

/// `[model]` without `radius`, which belongs to the particle-file initial data.
struct Model {
    particles: Option<usize>,
    gamma: f64,
    forcing: Option<Expr>,
    quadrature_points: usize,
}

fn validate_model(m: &ModelSection, parameters: &[(String, f64)]) -> Result<Model> {
    let particles = m
        .particles
        .map(|n| {
            check_range(
                "model.particles",
                n,
                Range::of("particles").ge(2).le(MAX_PARTICLES),
                "N, the particles 0..N (the two at the ends fixed, so at least 2 for one to move)",
            )
        })
        .transpose()?;
    check_mu("model.mu", m.mu)?;
    let gamma = check_gamma("model.gamma", m.gamma.unwrap_or(1.0))?;
    let forcing = m
        .forcing
        .as_deref()
        .map(|s| parse_expr("model.forcing", s, parameters))
        .transpose()?;
    let quadrature = check_range(
        "model.quadrature",
        m.quadrature.unwrap_or(3),
        Range::count(2, 8),
        "Gauss-Legendre points per particle for the forcing integral",
    )?;
    if m.quadrature.is_some() && forcing.is_none() {
        // The scene asks for something it would not get: no forcing, no integral.
        return Err(Error::missing(
            "model.quadrature",
            "only with model.forcing (the points integrate the forcing over each particle); remove it, or give a forcing",
        ));
    }
    Ok(Model {
        particles: particles.map(|n| n as usize),
        gamma,
        forcing,
        quadrature_points: quadrature as usize,
    })
}

/// `[initial]`: profiles, or a particle file (with `model.radius`) resolved against the scene's
/// folder.
fn validate_initial(
    ini: &InitialSection,
    m: &ModelSection,
    particles: Option<usize>,
    path: &Path,
    parameters: &[(String, f64)],
) -> Result<InitialSpec> {
    if ini.particles.is_some()
        && (ini.rho.is_some() || ini.velocity.is_some() || ini.rho_star.is_some())
    {
        return Err(Error::missing(
            "initial.particles",
            "give either a particle file or the profiles rho/velocity/rho_star, not both",
        ));
    }
    match (&ini.particles, &ini.rho) {
        (Some(p), _) => {
            let radius = m.radius.ok_or_else(|| {
                Error::missing(
                    "model.radius",
                    "a particle file needs the particle radius eps (model.radius > 0)",
                )
            })?;
            let radius = check_range(
                "model.radius",
                radius,
                Range::of("radius").gt(0.0).lt(0.5),
                "the particle radius eps",
            )?;
            let base = path.parent().unwrap_or(Path::new("."));
            Ok(InitialSpec::Particles {
                path: base.join(p),
                radius,
            })
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
            let rho = parse_expr("initial.rho", rho, parameters)?;
            let velocity = parse_expr(
                "initial.velocity",
                ini.velocity.as_deref().unwrap_or("0"),
                parameters,
            )?;
            let rho_star = ini
                .rho_star
                .as_deref()
                .map(|s| parse_expr("initial.rho_star", s, parameters))
                .transpose()?;
            check_profiles(&rho, &velocity, rho_star.as_ref())?;
            Ok(InitialSpec::Profiles {
                rho,
                velocity,
                rho_star,
            })
        }
        (None, None) => Err(Error::missing(
            "initial",
            "give the profiles (initial.rho, initial.velocity, optional initial.rho_star) or initial.particles = \"file.csv\"",
        )),
    }
}

/// The range checks of the initial profiles (run again at each sweep point).
fn check_profiles(rho: &Expr, velocity: &Expr, rho_star: Option<&Expr>) -> Result<()> {
    check_profile("initial.rho", rho, "(0, 1)", |v| v > 0.0 && v < 1.0)?;
    check_velocity(velocity)?;
    if let Some(rs) = rho_star {
        check_profile("initial.rho_star", rs, "(0, 1]", |v| v > 0.0 && v <= 1.0)?;
    }
    Ok(())
}

/// [`check_profiles`] for the density profiles a sweep point's parameters changed (`base`
/// holds the unswept scene's, already checked): the whole profile enters the construction of
/// the chain. A changed velocity is checked where it is used, at each member's particles
/// ([`crate::scene::members`]): re-sampling it on 20001 points cost ~1 ms per point, most of
/// a design of thousands of points whose parameter sits in the velocity.
fn check_changed_profiles(
    (rho, _velocity, rho_star): (&Expr, &Expr, Option<&Expr>),
    base: (&Expr, &Expr, Option<&Expr>),
) -> Result<()> {
    if rho != base.0 {
        check_profile("initial.rho", rho, "(0, 1)", |v| v > 0.0 && v < 1.0)?;
    }
    if let Some(rs) = rho_star.filter(|rs| Some(*rs) != base.2) {
        check_profile("initial.rho_star", rs, "(0, 1]", |v| v > 0.0 && v <= 1.0)?;
    }
    Ok(())
}

/// The velocity profile: finite everywhere, then within [`MAX_VELOCITY`] (one pass over the
/// samples, the same messages as two).
fn check_velocity(velocity: &Expr) -> Result<()> {
    let (non_finite, too_large) = checks::velocity_violations(velocity, MAX_VELOCITY);
    if let Some((x, v)) = non_finite {
        return Err(Error::ProfileRange {
            field: "initial.velocity".to_string(),
            expression: velocity.source().to_string(),
            value: v,
            x,
            allowed: "of finite values".to_string(),
        });
    }
    match too_large {
        None => Ok(()),
        Some((x, v)) => Err(Error::invalid(
            "initial.velocity",
            format!("\"{}\"", velocity.source()),
            format!("u0 = {} at x = {x} is far beyond what the solver can follow (velocities are in domain lengths per unit time: from |u| = {MAX_VELOCITY:e} one step of 1e-12 moves a particle across the domain, and from about 1e154 the kinetic energy eps Σ u_i² overflows f64)", approx_text(v)),
            format!("|u0| <= {MAX_VELOCITY:e} on [0, 1]"),
        )),
    }
}

/// `[solver]`: scheme order, backend and precision.
fn validate_solver(s: &SolverSection, stepping: &Stepping) -> Result<(Order, Backend, Precision)> {
    let allowed = format!(
        "1 (linearly implicit Euler), 2..={MAX_ORDER} (its extrapolation from 1, 2, …, p substeps) or \"auto\" (per member and step, adaptive steps only)"
    );
    let order = match &s.order {
        // A tolerance asks for an error, which auto's error follows (within a few times the
        // tolerance, docs/accuracy.md); order 1's adaptive steps hold only its local error, and
        // its global error grew to 1000 times the tolerance on a chain of 400 (1.15e-3 at 1e-6).
        None if matches!(stepping, Stepping::Adaptive { .. }) => Order::Auto,
        None => Order::Fixed(1),
        Some(OrderValue::Number(p)) if (1..=MAX_ORDER as i64).contains(p) => Order::Fixed(*p as u8),
        Some(OrderValue::Word(w)) if w == "auto" => {
            if !matches!(stepping, Stepping::Adaptive { .. }) {
                return Err(Error::invalid(
                    "solver.order",
                    "\"auto\"",
                    "order of the time scheme (\"auto\" chooses it from the error estimates of adaptive steps; this scene has fixed steps: set time.tolerance instead of time.dt)",
                    allowed,
                ));
            }
            Order::Auto
        }
        Some(OrderValue::Number(p)) => {
            return Err(Error::invalid(
                "solver.order",
                p,
                "order of the time scheme",
                allowed,
            ))
        }
        Some(OrderValue::Word(w)) => {
            return Err(Error::invalid(
                "solver.order",
                format!("\"{w}\""),
                "order of the time scheme",
                allowed,
            ))
        }
        Some(OrderValue::Other(v)) => {
            return Err(Error::invalid(
                "solver.order",
                v,
                "order of the time scheme (a whole number or \"auto\")",
                allowed,
            ))
        }
    };
    let backend = parse_choice(
        "solver.backend",
        "backend",
        s.backend.as_deref(),
        Backend::Auto,
    )?;
    let precision = parse_choice(
        "solver.precision",
        "precision",
        s.precision.as_deref(),
        Precision::F64,
    )?;
    Ok((order, backend, precision))
}

/// A scene value naming a variant of a `clap::ValueEnum` (the same names the command line
/// accepts), or `default` when absent.
fn parse_choice<T: clap::ValueEnum>(
    field: &str,
    what: &str,
    text: Option<&str>,
    default: T,
) -> Result<T> {
    let Some(text) = text else {
        return Ok(default);
    };
    T::from_str(text, false).map_err(|_| {
        let names: Vec<String> = T::value_variants()
            .iter()
            .filter_map(|v| v.to_possible_value())
            .map(|p| format!("\"{}\"", p.get_name()))
            .collect();
        let allowed = match names.split_last() {
            Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
            _ => names.concat(),
        };
        Error::invalid(
            field,
            format!("\"{text}\""),
            format!("unknown {what}"),
            allowed,
        )
    })
}

/// `[batch]`: lists replace the model's scalar mu and gamma; the members are their cartesian
/// product (see [`Scene::member_parameters`]).
fn validate_batch(b: Option<&BatchSection>, mu: f64, gamma: f64) -> Result<(Vec<f64>, Vec<f64>)> {
    let mut mus = vec![mu];
    let mut gammas = vec![gamma];
    let Some(b) = b else {
        return Ok((mus, gammas));
    };
    if let Some(list) = &b.mu {
        check_non_empty(
            "batch.mu",
            list,
            "empty sweep",
            "a non-empty list of 0 < mu <= 1e12",
        )?;
        for (j, &v) in list.iter().enumerate() {
            check_mu(&format!("batch.mu[{j}]"), v)?;
        }
        mus = list.clone();
    }
    if let Some(list) = &b.gamma {
        check_non_empty(
            "batch.gamma",
            list,
            "empty sweep",
            "a non-empty list of 1 <= gamma <= 1000",
        )?;
        for (j, &v) in list.iter().enumerate() {
            check_gamma(&format!("batch.gamma[{j}]"), v)?;
        }
        gammas = list.clone();
    }
    Ok((mus, gammas))
}

/// `[output]`.
struct Output {
    grid: usize,
    fields: OutputFields,
    plots: bool,
    plot_members: usize,
}

fn validate_output(o: &OutputSection) -> Result<Output> {
    let grid = check_range(
        "output.grid",
        o.grid.unwrap_or(200),
        Range::count(2, 1_000_000),
        "points of the macroscopic fields",
    )?;
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
    let plot_members = check_range(
        "output.plot_members",
        o.plot_members.unwrap_or(4),
        Range::count(0, 1000),
        "how many members get profile plots",
    )?;
    Ok(Output {
        grid: grid as usize,
        fields,
        plots: o.plots.unwrap_or(true),
        plot_members: plot_members as usize,
    })
}
