//! The complete message of every scene validation error, pinned: tests/cli.rs checks pieces of
//! some of them through the binary; these catch any change of wording in any of them.

use std::path::Path;

use super::Scene;

/// A good profile scene (shared with tests/cli.rs); each case changes one piece of it.
const BASE: &str = include_str!("../../tests/data/validation_base.toml");

/// A good particle-file scene.
const BASE_FILE: &str = include_str!("../../tests/data/validation_base_file.toml");

/// `base` with `from` replaced by `to` (which must occur exactly once).
fn edit(base: &str, from: &str, to: &str) -> String {
    assert_eq!(base.matches(from).count(), 1, "{from:?} must occur once");
    base.replace(from, to)
}

fn adaptive(extra: &str) -> String {
    edit(BASE, "dt = 1e-3\n", &format!("tolerance = 1e-6\n{extra}"))
}

fn with_ensemble(base: &str, body: &str) -> String {
    format!("{base}\n[ensemble]\nmembers = 4\n{body}\n")
}

/// (case, scene text, the complete error message) for every validation error of the scene reader.
fn cases() -> Vec<(&'static str, String, &'static str)> {
    let no_rho_star = edit(BASE, "rho_star = \"0.7\"\n", "");
    vec![
        ("name", edit(BASE, "name = \"base\"", "name = \"a b\""), "name = \"a b\": the name is used as a directory name (allowed: a non-empty name of letters, digits, '_', '-', '.', not . or ..)"),
        ("name dot", edit(BASE, "name = \"base\"", "name = \".\""), "name = \".\": the name is used as a directory name (allowed: a non-empty name of letters, digits, '_', '-', '.', not . or ..)"),
        ("quadrature without forcing", edit(BASE, "gamma = 1.0", "gamma = 1.0\nquadrature = 4"), "model.quadrature: only with model.forcing (the points integrate the forcing over each particle); remove it, or give a forcing"),
        ("particles low", edit(BASE, "particles = 10", "particles = 1"), "model.particles = 1: N, the particles 0..N (the two at the ends fixed, so at least 2 for one to move) (allowed: 2 <= particles <= 100000000)"),
        ("particles high", edit(BASE, "particles = 10", "particles = 200000000"), "model.particles = 200000000: N, the particles 0..N (the two at the ends fixed, so at least 2 for one to move) (allowed: 2 <= particles <= 100000000)"),
        ("mu negative", edit(BASE, "mu = 0.01", "mu = -1"), "model.mu = -1: the lubrication coefficient must be positive (allowed: 0 < mu <= 1e12)"),
        ("mu huge", edit(BASE, "mu = 0.01", "mu = 1e308"), "model.mu = 1e308: the step's lubrication coefficients mu/d_i overflow f64 for every gap d_i < mu/f64::MAX = 0.5563; mu <= 1e12 keeps them finite down to gaps of 5.563e-297 (allowed: 0 < mu <= 1e12)"),
        ("mu above the bound", edit(BASE, "mu = 0.01", "mu = 2e12"), "model.mu = 2000000000000: the step's lubrication coefficients mu/d_i overflow f64 for every gap d_i < mu/f64::MAX = 1.113e-296; mu <= 1e12 keeps them finite down to gaps of 5.563e-297 (allowed: 0 < mu <= 1e12)"),
        ("mu at the bound", edit(BASE, "mu = 0.01", "mu = 1e12"), "accepted"),
        ("mu nan", edit(BASE, "mu = 0.01", "mu = nan"), "model.mu = NaN: not a finite number (allowed: 0 < mu <= 1e12)"),
        ("gamma low", edit(BASE, "gamma = 1.0", "gamma = 0.5"), "model.gamma = 0.5: repulsion exponent out of range (allowed: 1 <= gamma <= 1000)"),
        ("gamma high", edit(BASE, "gamma = 1.0", "gamma = 2000.0"), "model.gamma = 2000: repulsion exponent out of range (allowed: 1 <= gamma <= 1000)"),
        ("gamma at the bound", edit(BASE, "gamma = 1.0", "gamma = 1000.0"), "accepted"),
        ("gamma inf", edit(BASE, "gamma = 1.0", "gamma = inf"), "model.gamma = inf: not a finite number (allowed: 1 <= gamma <= 1000)"),
        ("forcing", edit(BASE, "gamma = 1.0", "gamma = 1.0\nforcing = \"2*\""), "model.forcing = \"2*\": cannot parse expression at position 2: unexpected end of input (expected a number, variable, function or '(')"),
        ("quadrature low", edit(BASE, "gamma = 1.0", "gamma = 1.0\nquadrature = 1"), "model.quadrature = 1: Gauss-Legendre points per particle for the forcing integral (allowed: 2 ..= 8)"),
        ("quadrature high", edit(BASE, "gamma = 1.0", "gamma = 1.0\nquadrature = 9"), "model.quadrature = 9: Gauss-Legendre points per particle for the forcing integral (allowed: 2 ..= 8)"),
        ("particles and profiles", edit(BASE, "rho = \"0.7\"", "rho = \"0.7\"\nparticles = \"p.csv\""), "initial.particles: give either a particle file or the profiles rho/velocity/rho_star, not both"),
        ("no initial data", edit(BASE, "rho = \"0.7\"\nvelocity = \"0.5*sin(2*pi*x)\"\nrho_star = \"0.7\"\n", ""), "initial: give the profiles (initial.rho, initial.velocity, optional initial.rho_star) or initial.particles = \"file.csv\""),
        ("radius missing", edit(BASE_FILE, "radius = 0.02\n", ""), "model.radius: a particle file needs the particle radius eps (model.radius > 0)"),
        ("radius nan", edit(BASE_FILE, "radius = 0.02", "radius = nan"), "model.radius = NaN: not a finite number (allowed: 0 < radius < 0.5)"),
        ("radius zero", edit(BASE_FILE, "radius = 0.02", "radius = 0.0"), "model.radius = 0: the particle radius eps (allowed: 0 < radius < 0.5)"),
        ("radius half", edit(BASE_FILE, "radius = 0.02", "radius = 0.5"), "model.radius = 0.5: the particle radius eps (allowed: 0 < radius < 0.5)"),
        ("radius with profiles", edit(BASE, "gamma = 1.0", "gamma = 1.0\nradius = 0.01"), "model.radius: only with [initial] particles: from profiles, eps = M0/(2N) follows from rho"),
        ("particles missing", edit(BASE, "particles = 10\n", ""), "model.particles: the number N of particle intervals is required with profile initial data (2 <= particles)"),
        ("rho above one", edit(BASE, "rho = \"0.7\"", "rho = \"1.2\""), "initial.rho = \"1.2\": value 1.2 at x = 0 is outside the allowed range (0, 1)"),
        ("rho unparsable", edit(BASE, "rho = \"0.7\"", "rho = \"0.7+\""), "initial.rho = \"0.7+\": cannot parse expression at position 4: unexpected end of input (expected a number, variable, function or '(')"),
        ("velocity infinite", edit(BASE, "0.5*sin(2*pi*x)", "1/x"), "initial.velocity = \"1/x\": value inf at x = 0 is outside the allowed range of finite values"),
        ("velocity huge", edit(BASE, "0.5*sin(2*pi*x)", "1e308*x"), "initial.velocity = \"1e308*x\": u0 = 1e308 at x = 1 is far beyond what the solver can follow (velocities are in domain lengths per unit time: from |u| = 1e12 one step of 1e-12 moves a particle across the domain, and from about 1e154 the kinetic energy eps Σ u_i² overflows f64) (allowed: |u0| <= 1e12 on [0, 1])"),
        ("velocity at the bound", edit(BASE, "0.5*sin(2*pi*x)", "-1e12"), "accepted"),
        ("velocity unparsable", edit(BASE, "0.5*sin(2*pi*x)", "0.5*sinn(2*pi*x)"), "initial.velocity = \"0.5*sinn(2*pi*x)\": cannot parse expression at position 4: unknown identifier 'sinn' (known names: x, t, pi, e, sin, cos, tan, exp, log, sqrt, abs, tanh, min, max)"),
        ("rho_star zero", edit(BASE, "rho_star = \"0.7\"", "rho_star = \"0\""), "initial.rho_star = \"0\": value 0 at x = 0 is outside the allowed range (0, 1]"),
        ("rho_star above one", edit(BASE, "rho_star = \"0.7\"", "rho_star = \"1.5\""), "initial.rho_star = \"1.5\": value 1.5 at x = 0 is outside the allowed range (0, 1]"),
        ("end zero", edit(BASE, "end = 0.01", "end = 0.0"), "time.end = 0: the final time (allowed: end > 0)"),
        ("end nan", edit(BASE, "end = 0.01", "end = nan"), "time.end = NaN: not a finite number (allowed: end > 0)"),
        ("outputs low", edit(BASE, "outputs = 2", "outputs = 1"), "time.outputs = 1: number of evenly spaced output times including 0 and end (allowed: 2 ..= 100000, or a list of times)"),
        ("outputs high", edit(BASE, "outputs = 2", "outputs = 100001"), "time.outputs = 100001: number of evenly spaced output times including 0 and end (allowed: 2 ..= 100000, or a list of times)"),
        ("outputs empty", edit(BASE, "outputs = 2", "outputs = []"), "time.outputs = []: no output time (allowed: a non-empty increasing list of times in [0, end])"),
        ("outputs nan", edit(BASE, "outputs = 2", "outputs = [0.0, nan]"), "time.outputs[1] = NaN: not a finite number (allowed: a finite number)"),
        ("outputs after end", edit(BASE, "outputs = 2", "outputs = [0.0, 0.02]"), "time.outputs[1] = 0.02: output times must increase strictly and lie in [0, end] (allowed: previous time < value <= 0.01)"),
        ("outputs decreasing", edit(BASE, "outputs = 2", "outputs = [0.005, 0.001]"), "time.outputs[1] = 0.001: output times must increase strictly and lie in [0, end] (allowed: previous time < value <= 0.01)"),
        ("dt_min zero", edit(BASE, "dt = 1e-3", "dt = 1e-3\ndt_min = 0.0"), "time.dt_min = 0: a member whose step falls below dt_min is marked failed (allowed: 0 < dt_min < end)"),
        ("dt_min end", edit(BASE, "dt = 1e-3", "dt = 1e-3\ndt_min = 0.01"), "time.dt_min = 0.01: a member whose step falls below dt_min is marked failed (allowed: 0 < dt_min < end)"),
        ("dt_min nan", edit(BASE, "dt = 1e-3", "dt = 1e-3\ndt_min = nan"), "time.dt_min = NaN: not a finite number (allowed: 0 < dt_min < end)"),
        ("dt zero", edit(BASE, "dt = 1e-3", "dt = 0.0"), "time.dt = 0: the fixed step (a member takes at most 1e12 of them) (allowed: end/1e12 = 1e-14 <= dt <= end = 0.01)"),
        ("dt below dt_min", edit(BASE, "dt = 1e-3", "dt = 1e-4\ndt_min = 1e-3"), "time.dt = 0.0001: the fixed step (a member takes at most 1e12 of them) (allowed: dt_min = 1e-3 < dt <= end = 0.01)"),
        ("dt above end", edit(BASE, "dt = 1e-3", "dt = 0.02"), "time.dt = 0.02: the fixed step (a member takes at most 1e12 of them) (allowed: end/1e12 = 1e-14 <= dt <= end = 0.01)"),
        ("dt nan", edit(BASE, "dt = 1e-3", "dt = nan"), "time.dt = NaN: not a finite number (allowed: end/1e12 = 1e-14 <= dt <= end = 0.01)"),
        ("dt with dt_initial", edit(BASE, "dt = 1e-3", "dt = 1e-3\ndt_initial = 1e-4"), "time.dt_initial: only with adaptive steps (time.tolerance)"),
        ("tolerance high", edit(BASE, "dt = 1e-3", "tolerance = 1.0"), "time.tolerance = 1: local error tolerance of adaptive steps (allowed: 1e-13 <= tolerance <= 0.1)"),
        ("tolerance low", edit(BASE, "dt = 1e-3", "tolerance = 1e-14"), "time.tolerance = 1e-14: local error tolerance of adaptive steps (allowed: 1e-13 <= tolerance <= 0.1)"),
        ("tolerance nan", edit(BASE, "dt = 1e-3", "tolerance = nan"), "time.tolerance = NaN: not a finite number (allowed: 1e-13 <= tolerance <= 0.1)"),
        ("dt_initial zero", adaptive("dt_initial = 0.0\n"), "time.dt_initial = 0: the first trial step (allowed: 1e-30 end < dt_initial <= end)"),
        ("dt_initial above end", adaptive("dt_initial = 0.02\n"), "time.dt_initial = 0.02: the first trial step (allowed: 1e-30 end < dt_initial <= end)"),
        ("dt_initial nan", adaptive("dt_initial = nan\n"), "time.dt_initial = NaN: not a finite number (allowed: 1e-30 end < dt_initial <= end)"),
        ("dt_initial default below dt_min", adaptive("dt_min = 0.005\n"), "time.dt_initial = 1.0000000000000002e-6: the first trial step (not set: 1e-4 end) (allowed: dt_min = 5e-3 < dt_initial <= end)"),
        ("dt and tolerance", edit(BASE, "dt = 1e-3", "dt = 1e-3\ntolerance = 1e-6"), "time.dt: give either time.dt (fixed steps) or time.tolerance (adaptive steps), not both"),
        ("neither dt nor tolerance", edit(BASE, "dt = 1e-3\n", ""), "time.dt: give time.dt (fixed steps, 0 < dt <= end) or time.tolerance (adaptive steps)"),
        ("order", edit(BASE, "order = 1", "order = 9"), "solver.order = 9: order of the time scheme (allowed: 1 (linearly implicit Euler), 2..=8 (its extrapolation from 1, 2, …, p substeps) or \"auto\" (per member and step, adaptive steps only))"),
        ("order fraction", edit(BASE, "order = 1", "order = 2.5"), "solver.order = 2.5: order of the time scheme (a whole number or \"auto\") (allowed: 1 (linearly implicit Euler), 2..=8 (its extrapolation from 1, 2, …, p substeps) or \"auto\" (per member and step, adaptive steps only))"),
        ("order zero", edit(BASE, "order = 1", "order = 0"), "solver.order = 0: order of the time scheme (allowed: 1 (linearly implicit Euler), 2..=8 (its extrapolation from 1, 2, …, p substeps) or \"auto\" (per member and step, adaptive steps only))"),
        ("order word", edit(BASE, "order = 1", "order = \"high\""), "solver.order = \"high\": order of the time scheme (allowed: 1 (linearly implicit Euler), 2..=8 (its extrapolation from 1, 2, …, p substeps) or \"auto\" (per member and step, adaptive steps only))"),
        ("order auto with fixed dt", edit(BASE, "order = 1", "order = \"auto\""), "solver.order = \"auto\": order of the time scheme (\"auto\" chooses it from the error estimates of adaptive steps; this scene has fixed steps: set time.tolerance instead of time.dt) (allowed: 1 (linearly implicit Euler), 2..=8 (its extrapolation from 1, 2, …, p substeps) or \"auto\" (per member and step, adaptive steps only))"),
        ("backend", edit(BASE, "backend = \"cpu\"", "backend = \"tpu\""), "solver.backend = \"tpu\": unknown backend (allowed: \"cpu\", \"gpu\" or \"auto\")"),
        ("precision", edit(BASE, "backend = \"cpu\"", "backend = \"cpu\"\nprecision = \"f16\""), "solver.precision = \"f16\": unknown precision (allowed: \"f64\" or \"f32\")"),
        ("jacobian", edit(BASE, "backend = \"cpu\"", "backend = \"cpu\"\njacobian = \"newton\""), "solver.jacobian = \"newton\": unknown matrix of the extrapolated steps (allowed: \"auto\", \"exact\" or \"frozen\")"),
        ("sequence", edit(BASE, "backend = \"cpu\"", "backend = \"cpu\"\nsequence = \"from_3\""), "solver.sequence = \"from_3\": unknown substeps of the tableau's rows (allowed: \"auto\", \"from_1\" or \"from_2\")"),
        ("batch mu empty", format!("{BASE}\n[batch]\nmu = []\n"), "batch.mu = []: empty sweep (allowed: a non-empty list of 0 < mu <= 1e12)"),
        ("batch mu negative", format!("{BASE}\n[batch]\nmu = [1.0, -1.0]\n"), "batch.mu[1] = -1: the lubrication coefficient must be positive (allowed: 0 < mu <= 1e12)"),
        ("batch mu huge", format!("{BASE}\n[batch]\nmu = [1.0, 1e300]\n"), "batch.mu[1] = 1e300: the step's lubrication coefficients mu/d_i overflow f64 for every gap d_i < mu/f64::MAX = 5.563e-9; mu <= 1e12 keeps them finite down to gaps of 5.563e-297 (allowed: 0 < mu <= 1e12)"),
        ("batch mu nan", format!("{BASE}\n[batch]\nmu = [nan]\n"), "batch.mu[0] = NaN: not a finite number (allowed: 0 < mu <= 1e12)"),
        ("batch gamma empty", format!("{BASE}\n[batch]\ngamma = []\n"), "batch.gamma = []: empty sweep (allowed: a non-empty list of 1 <= gamma <= 1000)"),
        ("batch gamma low", format!("{BASE}\n[batch]\ngamma = [1.0, 0.5]\n"), "batch.gamma[1] = 0.5: repulsion exponent out of range (allowed: 1 <= gamma <= 1000)"),
        ("grid low", edit(BASE, "grid = 20", "grid = 1"), "output.grid = 1: points of the macroscopic fields (allowed: 2 ..= 1000000)"),
        ("grid high", edit(BASE, "grid = 20", "grid = 1000001"), "output.grid = 1000001: points of the macroscopic fields (allowed: 2 ..= 1000000)"),
        ("unknown field", edit(BASE, "grid = 20", "grid = 20\nfields = [\"rho\", \"foo\"]"), "output.fields[1] = \"foo\": unknown output field (allowed: gaps, velocities, rho, u, rho_star, energy)"),
        ("plot_members negative", edit(BASE, "grid = 20", "grid = 20\nplot_members = -1"), "output.plot_members = -1: how many members get profile plots (allowed: 0 ..= 1000)"),
        ("plot_members high", edit(BASE, "grid = 20", "grid = 20\nplot_members = 1001"), "output.plot_members = 1001: how many members get profile plots (allowed: 0 ..= 1000)"),
        ("members zero", format!("{BASE}\n[ensemble]\nmembers = 0\n"), "ensemble.members = 0: members per sweep point (allowed: 1 ..= 1e9)"),
        ("members high", format!("{BASE}\n[ensemble]\nmembers = 2000000000\n"), "ensemble.members = 2000000000: members per sweep point (allowed: 1 ..= 1e9)"),
        ("chunk zero", with_ensemble(BASE, "chunk = 0"), "ensemble.chunk = 0: members solved at once (memory) (allowed: 1 ..= 1000000)"),
        ("chunk high", with_ensemble(BASE, "chunk = 1000001"), "ensemble.chunk = 1000001: members solved at once (memory) (allowed: 1 ..= 1000000)"),
        ("mean_radius negative", with_ensemble(BASE, "mean_radius = -1.0"), "ensemble.mean_radius = -1: the mean roughness radius (allowed: 0 <= mean_radius < 1)"),
        ("mean_radius one", with_ensemble(BASE, "mean_radius = 1.0"), "ensemble.mean_radius = 1: the mean roughness radius (allowed: 0 <= mean_radius < 1)"),
        ("mean_radius nan", with_ensemble(BASE, "mean_radius = nan"), "ensemble.mean_radius = NaN: not a finite number (allowed: 0 <= mean_radius < 1)"),
        ("mean_radius with rho_star", with_ensemble(BASE, "roughness = { kind = \"uniform\", spread = 0.1 }\nmean_radius = 0.1"), "ensemble.mean_radius = 0.1: the mean roughness radius, where the mean profile is already given (initial.rho_star or the particle file's radii) (allowed: absent with initial.rho_star or a particle file; give one of the two)"),
        ("mean_radius without random roughness", with_ensemble(&no_rho_star, "mean_radius = 0.1"), "ensemble.mean_radius = 0.1: the mean roughness radius, which only random roughness (ensemble.roughness of a kind other than a file) is drawn around (allowed: absent without a random ensemble.roughness)"),
        ("mean profile missing", with_ensemble(&no_rho_star, "roughness = { kind = \"uniform\", spread = 0.1 }"), "ensemble.mean_radius: random roughness needs a mean profile: give initial.rho_star or ensemble.mean_radius (>= 0)"),
        ("amplitude spread high", with_ensemble(BASE, "velocity_amplitude_spread = 11.0"), "ensemble.velocity_amplitude_spread = 11: relative spread (allowed: 0 <= value <= 10)"),
        ("amplitude spread nan", with_ensemble(BASE, "velocity_amplitude_spread = nan"), "ensemble.velocity_amplitude_spread = NaN: not a finite number (allowed: 0 <= value <= 10)"),
        ("phase spread high", with_ensemble(BASE, "velocity_phase_spread = 1.5"), "ensemble.velocity_phase_spread = 1.5: relative spread (allowed: 0 <= value <= 1)"),
        ("phase spread negative", with_ensemble(BASE, "velocity_phase_spread = -0.5"), "ensemble.velocity_phase_spread = -0.5: relative spread (allowed: 0 <= value <= 1)"),
        ("phase spread with particles", with_ensemble(BASE_FILE, "velocity_phase_spread = 0.5"), "ensemble.velocity_phase_spread: a phase shift needs a velocity profile u0(x); with a particle file only the amplitude can vary"),
        ("jitter high", with_ensemble(BASE, "jitter = 3.0"), "ensemble.jitter = 3: relative spread (allowed: 0 <= value <= 2)"),
        ("threshold zero", with_ensemble(BASE, "threshold = 0.0"), "ensemble.threshold = 0: density threshold (allowed: 0 < threshold <= 1)"),
        ("threshold high", with_ensemble(BASE, "threshold = 1.5"), "ensemble.threshold = 1.5: density threshold (allowed: 0 < threshold <= 1)"),
        ("threshold nan", with_ensemble(BASE, "threshold = nan"), "ensemble.threshold = NaN: not a finite number (allowed: 0 < threshold <= 1)"),
        ("quantiles empty", with_ensemble(BASE, "quantiles = []"), "ensemble.quantiles = []: no quantile (allowed: a non-empty list in [0, 1])"),
        ("quantile high", with_ensemble(BASE, "quantiles = [0.5, 1.5]"), "ensemble.quantiles[1] = 1.5: a quantile level (allowed: 0 <= q <= 1)"),
        ("quantile nan", with_ensemble(BASE, "quantiles = [nan]"), "ensemble.quantiles[0] = NaN: a quantile level (allowed: 0 <= q <= 1)"),
        ("quantile inf", with_ensemble(BASE, "quantiles = [-inf]"), "ensemble.quantiles[0] = -inf: a quantile level (allowed: 0 <= q <= 1)"),
        ("bins low", with_ensemble(BASE, "bins = 3"), "ensemble.bins = 3: histogram bins of the field bands (allowed: 4 ..= 100000)"),
        ("bins high", with_ensemble(BASE, "bins = 100001"), "ensemble.bins = 100001: histogram bins of the field bands (allowed: 4 ..= 100000)"),
        ("u_range reversed", with_ensemble(BASE, "u_range = [1.0, 0.0]"), "ensemble.u_range = [1, 0]: velocity range of the u band (allowed: [lo, hi] with lo < hi)"),
        ("u_range nan", with_ensemble(BASE, "u_range = [nan, 1.0]"), "ensemble.u_range = [NaN, 1]: velocity range of the u band (allowed: [lo, hi] with lo < hi)"),
    ]
}

#[test]
fn validation_messages_are_unchanged() {
    let mut wrong = Vec::new();
    for (case, text, expected) in cases() {
        let actual = match Scene::from_toml(&text, Path::new("dir/scene.toml")) {
            Ok(_) => "accepted".to_string(),
            Err(e) => e.to_string(),
        };
        if actual != expected {
            wrong.push(format!(
                "{case}:\n  expected {expected}\n  actual   {actual}"
            ));
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

/// The complete message of every error of the initial data that the scene reader cannot see
/// (particle files are read, and the initial chain built, by `Scene::initial_chain`).
fn chain_cases() -> Vec<(&'static str, String, Option<&'static str>, &'static str)> {
    let good_csv = "x,u,r\n0.0,0.0,0.0\n0.25,0.1,0.0\n0.5,-0.1,0.0\n0.75,0.2,0.0\n1.0,0.0,0.0\n";
    let dense = edit(
        &edit(BASE, "rho = \"0.7\"", "rho = \"0.9\""),
        "rho_star = \"0.7\"",
        "rho_star = \"0.3 + 0.4*x\"",
    );
    vec![
        ("good file", BASE_FILE.to_string(), Some(good_csv), "accepted"),
        ("radius huge", BASE_FILE.to_string(), Some("x,u,r\n0.0,0.0,0.0\n0.25,0.1,1e300\n0.5,-0.1,0.0\n0.75,0.2,0.0\n1.0,0.0,0.0\n"), "particle file dir/p.csv, line 3: column r: roughness radius r = 1e300 is not smaller than the domain [0, 1] (allowed: 0 <= r < 1)"),
        ("radius huge after a comment", BASE_FILE.to_string(), Some("x,u,r\n0.0,0.0,0.0\n0.25,0.1,0.0\n# a rough one\n0.5,-0.1,2e300\n0.75,0.2,0.0\n1.0,0.0,0.0\n"), "particle file dir/p.csv, line 5: column r: roughness radius r = 2e300 is not smaller than the domain [0, 1] (allowed: 0 <= r < 1)"),
        ("radius one", BASE_FILE.to_string(), Some("x,u,r\n0.0,0.0,0.0\n0.25,0.1,0.0\n0.5,-0.1,0.0\n0.75,0.2,1.0\n1.0,0.0,0.0\n"), "particle file dir/p.csv, line 5: column r: roughness radius r = 1 is not smaller than the domain [0, 1] (allowed: 0 <= r < 1)"),
        ("velocity huge in file", BASE_FILE.to_string(), Some("x,u,r\n0.0,0.0,0.0\n0.25,0.1,0.0\n0.5,-1e300,0.0\n0.75,0.2,0.0\n1.0,0.0,0.0\n"), "particle file dir/p.csv, line 4: column u: velocity u = -1e300 is far beyond what the solver can follow (velocities are in domain lengths per unit time) (allowed: |u| <= 1e12)"),
        ("forcing infinite at the start", edit(BASE, "gamma = 1.0", "gamma = 1.0\nforcing = \"1/t\""), None, "model.forcing = \"1/t\": the force on particle 1 (x = 0.1) at t = 0, its integral over the particle by 3 Gauss-Legendre points, is inf in f64: every member would fail at its first step (allowed: a forcing whose integral over every particle is finite in f64 at t = 0)"),
        ("forcing NaN on the left half", edit(BASE, "gamma = 1.0", "gamma = 1.0\nforcing = \"sqrt(x - 0.5)\""), None, "model.forcing = \"sqrt(x - 0.5)\": the force on particle 1 (x = 0.1) at t = 0, its integral over the particle by 3 Gauss-Legendre points, is NaN in f64: every member would fail at its first step (allowed: a forcing whose integral over every particle is finite in f64 at t = 0)"),
        ("forcing finite at the start", edit(BASE, "gamma = 1.0", "gamma = 1.0\nforcing = \"sin(t)/(1 + t)\""), None, "accepted"),
        ("forcing of a swept parameter is each member's", with_ensemble(&format!("{}\n[parameters]\na = 0.0\n", edit(BASE, "gamma = 1.0", "gamma = 1.0\nforcing = \"1/(t + a)\"")), "[sweep]\na = [0.5, 1.0]"), None, "accepted"),
        ("gamma 686 at ratio 2.812", edit(&dense, "gamma = 1.0", "gamma = 686.0"), None, "accepted"),
        ("repulsion overflows", edit(&dense, "gamma = 1.0", "gamma = 1000.0"), None, "model.gamma = 1000: the repulsion G = (rho/rho*)^gamma overflows f64 at t = 0: gap 1 (particles 0 and 1, x = 0.05) starts at rho/rho* = 2.812, so gamma ln(rho/rho*) = 1034 > ln(f64::MAX) = 709.8 (allowed: gamma <= 686 with these initial data, or rho/rho* <= 2.033 in every gap with gamma = 1000)"),
        ("repulsion overflows in a sweep", format!("{dense}\n[batch]\ngamma = [2.0, 1000.0]\n"), None, "batch.gamma[1] = 1000: the repulsion G = (rho/rho*)^gamma overflows f64 at t = 0: gap 1 (particles 0 and 1, x = 0.05) starts at rho/rho* = 2.812, so gamma ln(rho/rho*) = 1034 > ln(f64::MAX) = 709.8 (allowed: gamma <= 686 with these initial data, or rho/rho* <= 2.033 in every gap with gamma = 1000)"),
        ("gamma sweep without roughness", format!("{}\n[batch]\ngamma = [1.0, 2.0]\n", edit(BASE, "rho_star = \"0.7\"\n", "")), None, "batch.gamma = [1.0, 2.0]: a gamma sweep without roughness: gamma only enters through the repulsion (rho/rho*)^gamma, and without rho* there is none, so every gamma gives the same member (allowed: give initial.rho_star (or an r column in the particle file, or [ensemble] roughness), or drop the gamma sweep)"),
        ("gamma sweep with roughness", format!("{BASE}\n[batch]\ngamma = [1.0, 2.0]\n"), None, "accepted"),
        ("gamma sweep of roughness drawn by the ensemble", with_ensemble(&format!("{}\n[batch]\ngamma = [1.0, 2.0]\n", edit(BASE, "rho_star = \"0.7\"\n", "")), "roughness = { kind = \"uniform\", spread = 0.1 }\nmean_radius = 0.001"), None, "accepted"),
        ("repulsion left to the members", with_ensemble(&edit(&dense, "gamma = 1.0", "gamma = 1000.0"), "roughness = { kind = \"lognormal\", spread = 0.2 }"), None, "accepted"),
    ]
}

#[test]
fn initial_chain_messages_are_unchanged() {
    let mut wrong = Vec::new();
    for (case, text, csv, expected) in chain_cases() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("dir");
        std::fs::create_dir(&dir).unwrap();
        if let Some(csv) = csv {
            std::fs::write(dir.join("p.csv"), csv).unwrap();
        }
        let actual = match Scene::from_toml(&text, &dir.join("scene.toml"))
            .and_then(|s| s.initial_chain())
        {
            Ok(_) => "accepted".to_string(),
            Err(e) => e
                .to_string()
                .replace(&format!("{}/", tmp.path().display()), ""),
        };
        if actual != expected {
            wrong.push(format!(
                "{case}:\n  expected {expected}\n  actual   {actual}"
            ));
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

/// `[solver] sequence`'s default, auto: the rows from 2 for order auto with adaptive steps in
/// f64 only (the measured rule of `SequenceChoice`), and what a scene names is what runs.
#[test]
fn the_default_sequence_is_from_2_only_for_adaptive_auto_in_f64() {
    use crate::backend::Precision::{F32, F64};
    use crate::model::params::Sequence::{FromOne, FromTwo};
    let auto_order = |text: &str| edit(text, "order = 1", "order = \"auto\"");
    let cases = [
        (
            "auto, adaptive, f64",
            auto_order(&adaptive("")),
            F64,
            FromTwo,
        ),
        (
            "auto, adaptive, f32",
            auto_order(&adaptive("")),
            F32,
            FromOne,
        ),
        (
            "order 4, fixed dt, f64",
            edit(BASE, "order = 1", "order = 4"),
            F64,
            FromOne,
        ),
        (
            "order 4, adaptive, f64",
            edit(&adaptive(""), "order = 1", "order = 4"),
            F64,
            FromOne,
        ),
        ("order 1, adaptive, f64", adaptive(""), F64, FromOne),
        (
            "auto, adaptive, f64, from_1 named",
            auto_order(&adaptive("")).replace(
                "backend = \"cpu\"",
                "backend = \"cpu\"\nsequence = \"from_1\"",
            ),
            F64,
            FromOne,
        ),
        (
            "order 4, fixed dt, from_2 named",
            edit(BASE, "order = 1", "order = 4\nsequence = \"from_2\""),
            F64,
            FromTwo,
        ),
    ];
    for (case, text, precision, expected) in cases {
        let scene = Scene::from_toml(&text, Path::new("dir/scene.toml")).unwrap();
        let chain = scene.initial_chain().unwrap();
        assert_eq!(scene.plan(&chain, precision).sequence, expected, "{case}");
    }
}

/// `[solver] order` unset: auto with a tolerance (whose error follows the tolerance), 1 with a
/// dt; a named order is what runs either way.
#[test]
fn the_default_order_is_auto_with_a_tolerance_and_1_with_a_dt() {
    use crate::model::params::Order;
    let unset = |text: &str| edit(text, "order = 1\n", "");
    let cases = [
        ("tolerance, unset", unset(&adaptive("")), Order::Auto),
        ("dt, unset", unset(BASE), Order::Fixed(1)),
        ("tolerance, order 1", adaptive(""), Order::Fixed(1)),
        (
            "dt, order 4",
            edit(BASE, "order = 1", "order = 4"),
            Order::Fixed(4),
        ),
    ];
    for (case, text, expected) in cases {
        let scene = Scene::from_toml(&text, Path::new("dir/scene.toml")).unwrap();
        assert_eq!(scene.order, expected, "{case}");
    }
}
