//! `[parameters]` (named numbers usable in every expression) and `[sweep]` (the parameter study
//! of an ensemble: which settings and parameters vary, over which design), and
//! [`Scene::at_point`], the scene of one sweep point.
//!
//! ```toml
//! [parameters]
//! A = 0.5                       # velocity = "A*sin(2*pi*x)"
//!
//! [sweep]                       # a grid: the cartesian product, first key slowest
//! roughness_spread = [0.0, 0.1, 0.2]
//! A = [0.3, 0.5]
//!
//! [sweep]                       # or samples of a box
//! design = "sobol"              # "random", "latin_hypercube" or "sobol"
//! points = 64
//! seed = 7                      # default: ensemble.seed
//! mu = { min = 1e-3, max = 1e-1, scale = "log" }
//! A = { min = 0.1, max = 1.0 }
//! ```

use super::file::BatchSection;
use super::{EnsembleSpec, InitialSpec, Scene};
use crate::ensemble::design::{Axis, Design, DesignKind};
use crate::ensemble::RoughnessKind;
use crate::error::{Error, Result};
use crate::expr::Expr;

mod axes;

use axes::{axis, target_name};

/// The largest number of sweep points accepted without `--allow-large` (every point keeps its
/// own statistics).
pub const MAX_SWEEP_POINTS: u64 = 100_000;

/// What one axis of a sweep sets.
#[derive(Debug, Clone, PartialEq)]
pub enum SweepTarget {
    Mu,
    Gamma,
    /// N; sampled values are rounded to the nearest integer.
    Particles,
    /// `ensemble.roughness`'s spread.
    RoughnessSpread,
    /// `ensemble.roughness`'s correlation length (kind = "correlated").
    CorrelationLength,
    VelocityAmplitudeSpread,
    VelocityPhaseSpread,
    Jitter,
    /// A name of `[parameters]`.
    Parameter(String),
}

/// The settings a sweep may vary, by their key in `[sweep]`.
pub const SWEEPABLE_SETTINGS: [&str; 8] = [
    "mu",
    "gamma",
    "particles",
    "roughness_spread",
    "correlation_length",
    "velocity_amplitude_spread",
    "velocity_phase_spread",
    "jitter",
];

impl SweepTarget {
    fn of(name: &str, parameters: &[(String, f64)]) -> Option<SweepTarget> {
        Some(match name {
            "mu" => SweepTarget::Mu,
            "gamma" => SweepTarget::Gamma,
            "particles" => SweepTarget::Particles,
            "roughness_spread" => SweepTarget::RoughnessSpread,
            "correlation_length" => SweepTarget::CorrelationLength,
            "velocity_amplitude_spread" => SweepTarget::VelocityAmplitudeSpread,
            "velocity_phase_spread" => SweepTarget::VelocityPhaseSpread,
            "jitter" => SweepTarget::Jitter,
            _ if parameters.iter().any(|(p, _)| p == name) => {
                SweepTarget::Parameter(name.to_string())
            }
            _ => return None,
        })
    }
}

/// Whether `name` is a column of members.csv or points.csv other than the swept keys' (where a
/// parameter gets a column of its own name).
fn is_table_column(name: &str) -> bool {
    use crate::output::columns::{
        swept_member_column, MEMBER_COLUMNS, MEMBER_KEY_COLUMNS, POINT_COUNT_COLUMNS,
        POINT_INDEX_COLUMN,
    };
    MEMBER_KEY_COLUMNS
        .iter()
        .chain(&MEMBER_COLUMNS)
        .chain(&POINT_COUNT_COLUMNS)
        .any(|c| *c == name)
        || name == POINT_INDEX_COLUMN
        || MEMBER_COLUMNS
            .iter()
            .any(|c| swept_member_column(c) == name)
}

/// The validated `[sweep]`: the design and what each of its axes sets.
#[derive(Debug, Clone)]
pub struct SweepSpec {
    pub design: Design,
    /// One per axis of the design, in the same order.
    pub targets: Vec<SweepTarget>,
    /// Member j of every point draws the same random inputs (common random numbers) unless
    /// `independent_draws`, where member m draws its own.
    pub independent_draws: bool,
}

impl SweepSpec {
    /// Number of points P.
    pub fn points(&self) -> u64 {
        self.design.len()
    }
}

/// `[parameters]`: names and values, in file order.
pub(super) fn validate_parameters(table: Option<&toml::Table>) -> Result<Vec<(String, f64)>> {
    let Some(table) = table else {
        return Ok(Vec::new());
    };
    let mut out = Vec::with_capacity(table.len());
    for (name, value) in table {
        let field = format!("parameters.{name}");
        let identifier = name
            .chars()
            .next()
            .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
            && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
        if !identifier {
            return Err(Error::invalid(
                field,
                format!("\"{name}\""),
                "a parameter name is used in expressions",
                "a name of letters, digits and '_', starting with a letter or '_'",
            ));
        }
        if Expr::is_reserved_name(name) {
            return Err(Error::invalid(
                field,
                name,
                format!("'{name}' is a variable, constant or function of the expressions, so a parameter of that name would shadow it"),
                "a name other than x, t, pi, e and the function names",
            ));
        }
        if is_table_column(name) {
            return Err(Error::invalid(
                field,
                name,
                format!("'{name}' names a column of members.csv, where every parameter gets a column of its own name"),
                "a name that is not a members.csv column",
            ));
        }
        if SWEEPABLE_SETTINGS.contains(&name.as_str()) {
            return Err(Error::invalid(
                field,
                name,
                format!(
                    "'{name}' is a setting of the scene; sweep it in [sweep] under its own name"
                ),
                "a name that is not a setting",
            ));
        }
        let v = match value {
            toml::Value::Float(v) => *v,
            toml::Value::Integer(v) => *v as f64,
            other => {
                return Err(Error::invalid(
                    field,
                    other,
                    "a parameter is a number",
                    "a finite number",
                ))
            }
        };
        if !v.is_finite() {
            return Err(Error::invalid(
                field,
                v,
                "a parameter is a number",
                "a finite number",
            ));
        }
        out.push((name.clone(), v));
    }
    Ok(out)
}

fn number(field: &str, v: &toml::Value) -> Result<f64> {
    let x = match v {
        toml::Value::Float(x) => *x,
        toml::Value::Integer(x) => *x as f64,
        other => {
            return Err(Error::invalid(
                field,
                other,
                "not a number",
                "a finite number",
            ))
        }
    };
    if !x.is_finite() {
        return Err(Error::invalid(field, x, "not finite", "a finite number"));
    }
    Ok(x)
}

/// `[sweep]` (and, in an ensemble, `[batch]`'s mu and gamma lists as a grid, gamma first).
pub(super) fn validate_sweep(
    table: Option<&toml::Table>,
    batch: Option<&BatchSection>,
    parameters: &[(String, f64)],
    ensemble: Option<&EnsembleSpec>,
    initial: &InitialSpec,
) -> Result<Option<SweepSpec>> {
    let Some(ensemble) = ensemble else {
        if table.is_some() {
            return Err(Error::missing(
                "sweep",
                "[sweep] makes a parameter study of an ensemble: add [ensemble] (members = 1 for one member per point), or use [batch] for mu and gamma lists in a single run",
            ));
        }
        return Ok(None);
    };
    let Some(table) = table else {
        // [batch] in an ensemble: a grid over its lists, gamma slowest (as in a single run).
        return match batch {
            Some(b) => batch_sweep(b, ensemble),
            None => Ok(None),
        };
    };
    if batch.is_some_and(|b| b.mu.is_some() || b.gamma.is_some()) {
        return Err(Error::missing(
            "batch",
            "an ensemble with [sweep] takes its mu and gamma lists in [sweep] too: move them there",
        ));
    }
    let keys = SweepKeys::parse(table, parameters, ensemble.seed)?;
    keys.check(ensemble, initial)?;
    let SweepKeys {
        kind,
        points,
        seed,
        independent_draws,
        names,
        targets,
        axes,
    } = keys;
    let design = Design::new("sweep", kind, names, axes, points, seed)?;
    Ok(Some(SweepSpec {
        design,
        targets,
        independent_draws: independent_draws.unwrap_or(false),
    }))
}

/// The sweep of an ensemble with a `[batch]` section and no `[sweep]`: a grid over its mu and
/// gamma lists (None without either).
fn batch_sweep(b: &BatchSection, ensemble: &EnsembleSpec) -> Result<Option<SweepSpec>> {
    let mut targets = Vec::new();
    let mut axes = Vec::new();
    let mut names = Vec::new();
    if let Some(g) = &b.gamma {
        targets.push(SweepTarget::Gamma);
        axes.push(Axis::Values(g.clone()));
        names.push("gamma".to_string());
    }
    if let Some(m) = &b.mu {
        targets.push(SweepTarget::Mu);
        axes.push(Axis::Values(m.clone()));
        names.push("mu".to_string());
    }
    if targets.is_empty() {
        return Ok(None);
    }
    for (name, axis) in names.iter().zip(&axes) {
        if let Axis::Values(v) = axis {
            for (j, x) in v.iter().enumerate() {
                if let Some(k) = v[..j].iter().position(|y| y == x) {
                    return Err(Error::invalid(
                        format!("batch.{name}[{j}]"),
                        x,
                        format!("the same value as batch.{name}[{k}]: in an ensemble each value is a sweep point"),
                        "distinct values",
                    ));
                }
            }
        }
    }
    let design = Design::new("batch", DesignKind::Grid, names, axes, None, ensemble.seed)?;
    Ok(Some(SweepSpec {
        design,
        targets,
        independent_draws: false,
    }))
}

/// The keys of a `[sweep]` table as read, before the design is built.
struct SweepKeys {
    kind: DesignKind,
    points: Option<u64>,
    seed: u64,
    independent_draws: Option<bool>,
    names: Vec<String>,
    targets: Vec<SweepTarget>,
    axes: Vec<Axis>,
}

impl SweepKeys {
    /// Reads each key of `table` (design, points, seed, independent_draws, and the settings or
    /// parameters swept with their values); the seed defaults to the ensemble's.
    fn parse(
        table: &toml::Table,
        parameters: &[(String, f64)],
        ensemble_seed: u64,
    ) -> Result<SweepKeys> {
        let mut kind = DesignKind::Grid;
        let mut points: Option<u64> = None;
        let mut seed = ensemble_seed;
        let mut independent_draws: Option<bool> = None;
        let mut names = Vec::new();
        let mut targets = Vec::new();
        let mut axes = Vec::new();
        for (key, value) in table {
            let field = format!("sweep.{key}");
            match key.as_str() {
                "design" => {
                    kind = match value.as_str() {
                        Some("grid") => DesignKind::Grid,
                        Some("random") => DesignKind::Random,
                        Some("latin_hypercube") => DesignKind::LatinHypercube,
                        Some("sobol") => DesignKind::Sobol,
                        Some("saltelli") => DesignKind::Saltelli,
                        _ => return Err(Error::invalid(
                            field,
                            value,
                            "unknown design",
                            "\"grid\" (lists), \"random\", \"latin_hypercube\", \"sobol\" or \"saltelli\" (ranges)",
                        )),
                    }
                }
                "points" => {
                    let p = value.as_integer().filter(|&p| p >= 1).ok_or_else(|| {
                        Error::invalid(
                            &field,
                            value,
                            "the number of sampled points",
                            "a whole number >= 1",
                        )
                    })?;
                    points = Some(p as u64);
                }
                "seed" => {
                    let s = value.as_integer().filter(|&s| s >= 0).ok_or_else(|| {
                        Error::invalid(&field, value, "the design's seed", "a whole number >= 0")
                    })?;
                    seed = s as u64;
                }
                "independent_draws" => {
                    independent_draws =
                        Some(value.as_bool().ok_or_else(|| {
                            Error::invalid(&field, value, "a switch", "true or false")
                        })?);
                }
                name => {
                    let target = SweepTarget::of(name, parameters).ok_or_else(|| {
                        let params: Vec<&str> = parameters.iter().map(|(p, _)| p.as_str()).collect();
                        Error::invalid(
                            &field,
                            value,
                            format!("'{name}' is neither a setting a sweep can vary nor a name in [parameters]"),
                            format!(
                                "design, points, seed, independent_draws, the settings {}{}",
                                SWEEPABLE_SETTINGS.join(", "),
                                if params.is_empty() {
                                    String::new()
                                } else {
                                    format!(", or the parameters {}", params.join(", "))
                                }
                            ),
                        )
                    })?;
                    axes.push(axis(&field, value, &target)?);
                    names.push(name.to_string());
                    targets.push(target);
                }
            }
        }
        Ok(SweepKeys {
            kind,
            points,
            seed,
            independent_draws,
            names,
            targets,
            axes,
        })
    }

    /// That the keys make a design: at least one key swept, lists for a grid and ranges with a
    /// number of points for a sampled design, and each swept key's needs met by the scene.
    fn check(&self, ensemble: &EnsembleSpec, initial: &InitialSpec) -> Result<()> {
        let (kind, points, names, targets, axes) = (
            self.kind,
            self.points,
            &self.names,
            &self.targets,
            &self.axes,
        );
        if targets.is_empty() {
            return Err(Error::missing(
                "sweep",
                "no parameter to sweep: give at least one setting or parameter with its values",
            ));
        }
        let grid = kind == DesignKind::Grid;
        for (name, a) in names.iter().zip(axes) {
            let is_list = matches!(a, Axis::Values(_));
            if grid != is_list {
                return Err(Error::invalid(
                    format!("sweep.{name}"),
                    if is_list { "a list" } else { "a range" },
                    if grid {
                        "a grid design takes a list of values per key"
                    } else {
                        "a sampled design takes a range { min, max } per key"
                    },
                    if grid {
                        "[v1, v2, ...], or design = \"random\" / \"latin_hypercube\" / \"sobol\" for ranges"
                    } else {
                        "{ min = a, max = b } with optional scale = \"log\""
                    },
                ));
            }
        }
        if grid && points.is_some() {
            return Err(Error::missing(
                "sweep.points",
                "a grid has as many points as its lists make; points is for sampled designs",
            ));
        }
        if !grid && points.is_none() {
            return Err(Error::missing(
                "sweep.points",
                "a sampled design needs the number of points (a whole number >= 1)",
            ));
        }
        for t in targets {
            let needs = match t {
                SweepTarget::RoughnessSpread => ensemble
                    .roughness
                    .as_ref()
                    .filter(|r| !matches!(r.kind, RoughnessKind::Constant | RoughnessKind::File(_)))
                    .map(|_| ())
                    .ok_or("ensemble.roughness of a random kind (uniform, lognormal, twopoint, correlated)"),
                SweepTarget::CorrelationLength => ensemble
                    .roughness
                    .as_ref()
                    .filter(|r| matches!(r.kind, RoughnessKind::Correlated { .. }))
                    .map(|_| ())
                    .ok_or("ensemble.roughness with kind = \"correlated\""),
                _ => Ok(()),
            };
            if let Err(what) = needs {
                return Err(Error::missing(
                    format!("sweep.{}", target_name(t)),
                    format!("sweeping it needs {what}"),
                ));
            }
        }
        if targets.contains(&SweepTarget::Particles)
            && matches!(initial, InitialSpec::Particles { .. })
        {
            return Err(Error::missing(
                "sweep.particles",
                "a particle file fixes N (its rows); sweeping N needs profile initial data (initial.rho, ...)",
            ));
        }
        if ensemble.store_members && targets.contains(&SweepTarget::Particles) {
            return Err(Error::missing(
                "ensemble.store_members",
                "per-member arrays of a chunk share one N; with particles swept, use members.csv and the statistics instead",
            ));
        }
        Ok(())
    }
}

impl Scene {
    /// The number of sweep points P (1 without a sweep).
    pub fn sweep_points(&self) -> u64 {
        self.sweep.as_ref().map_or(1, SweepSpec::points)
    }

    /// The names and values of sweep point `p` (empty without a sweep).
    pub fn point_values(&self, p: u64) -> Vec<(String, f64)> {
        match &self.sweep {
            None => Vec::new(),
            // N is a whole number: a sampled design's value is rounded as the point runs it.
            Some(s) => s
                .design
                .names()
                .iter()
                .cloned()
                .zip(s.design.values(p))
                .zip(&s.targets)
                .map(|((name, v), target)| match target {
                    SweepTarget::Particles => (name, v.round()),
                    _ => (name, v),
                })
                .collect(),
        }
    }

    /// The scene of sweep point `p`: the swept settings set to the point's values, every
    /// expression rebound to its parameters (and its profile checks run again), no sweep. A
    /// study of this scene is exactly the point's part of the sweep.
    pub fn at_point(&self, p: u64) -> Result<Scene> {
        let mut scene = self.clone();
        let Some(sweep) = scene.sweep.take() else {
            return Ok(scene);
        };
        scene.sweep_point = Some(p);
        let values = sweep.design.values(p);
        let context = |e: Error| -> Error {
            let point: Vec<String> = sweep
                .design
                .names()
                .iter()
                .zip(&values)
                .map(|(n, v)| format!("{n} = {v}"))
                .collect();
            Error::missing(
                format!("sweep point {p} ({})", point.join(", ")),
                e.to_string(),
            )
        };
        let mut parameters = scene.parameters.clone();
        for (target, &v) in sweep.targets.iter().zip(&values) {
            let spec = scene.ensemble.as_mut();
            match target {
                SweepTarget::Mu => scene.mu = vec![v],
                SweepTarget::Gamma => scene.gamma = vec![v],
                SweepTarget::Particles => scene.particles = Some(v.round() as usize),
                SweepTarget::RoughnessSpread => {
                    if let Some(r) = spec.and_then(|s| s.roughness.as_mut()) {
                        r.spread = v;
                    }
                }
                SweepTarget::CorrelationLength => {
                    if let Some(r) = spec.and_then(|s| s.roughness.as_mut()) {
                        r.kind = RoughnessKind::Correlated { length: v };
                    }
                }
                SweepTarget::VelocityAmplitudeSpread => {
                    if let Some(s) = spec {
                        s.velocity_amplitude_spread = v;
                    }
                }
                SweepTarget::VelocityPhaseSpread => {
                    if let Some(s) = spec {
                        s.velocity_phase_spread = v;
                    }
                }
                SweepTarget::Jitter => {
                    if let Some(s) = spec {
                        s.jitter = v;
                    }
                }
                SweepTarget::Parameter(name) => {
                    if let Some(slot) = parameters.iter_mut().find(|(n, _)| n == name) {
                        slot.1 = v;
                    }
                }
            }
        }
        if let Some(r) = scene.ensemble.as_ref().and_then(|s| s.roughness.as_ref()) {
            r.validate()
                .map_err(|e| context(Error::missing("ensemble", e.to_string())))?;
        }
        scene.bind_parameters(parameters).map_err(context)?;
        Ok(scene)
    }

    /// Rebinds every expression to `parameters` and checks the profiles again.
    fn bind_parameters(&mut self, parameters: Vec<(String, f64)>) -> Result<()> {
        if parameters == self.parameters {
            return Ok(());
        }
        let rebind = |field: &str, e: &Expr| {
            e.rebind(&parameters).map_err(|source| Error::Expression {
                field: field.to_string(),
                source_text: e.source().to_string(),
                source,
            })
        };
        if let Some(f) = &self.forcing {
            self.forcing = Some(rebind("model.forcing", f)?);
        }
        if let InitialSpec::Profiles {
            rho,
            velocity,
            rho_star,
        } = &self.initial
        {
            let base = (rho, velocity, rho_star.as_ref());
            let rho = rebind("initial.rho", rho)?;
            let velocity = rebind("initial.velocity", velocity)?;
            let rho_star = rho_star
                .as_ref()
                .map(|r| rebind("initial.rho_star", r))
                .transpose()?;
            super::check_changed_profiles((&rho, &velocity, rho_star.as_ref()), base)?;
            self.initial = InitialSpec::Profiles {
                rho,
                velocity,
                rho_star,
            };
        }
        self.parameters = parameters;
        Ok(())
    }
}
