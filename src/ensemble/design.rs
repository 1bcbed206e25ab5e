//! Parameter designs: the P points, each a vector of D parameter values, at which a study is run.
//!
//! A [`Design`] sweeps D named parameters. Each parameter has an [`Axis`]: a list of values (for
//! a [`DesignKind::Grid`]) or a range `[min, max)` on a linear or logarithmic [`Scale`] (for the
//! sampled designs: [`DesignKind::Random`], [`DesignKind::LatinHypercube`], [`DesignKind::Sobol`]).
//!
//! # Reproducibility
//!
//! Point p's values ([`Design::values`]) are a pure function of (kind, axes, P, seed, p): they do
//! not depend on which other points were computed, in which order, or on which thread. A sampled
//! design first draws a unit point u in [0, 1)^D ([`Design::unit`]) and maps each coordinate to
//! its axis:
//!
//! * `Random`: u_d is draw d of `member_rng(seed, Purpose::Design, p)` (`rand`'s `f64` in [0, 1),
//!   53 random bits).
//! * `LatinHypercube`: for each dimension d, a permutation pi_d of 0..P is drawn once (a
//!   Fisher–Yates shuffle driven by `member_rng(seed, Purpose::DesignPermutation, d)`, indices
//!   drawn as `u32`), and u_d = (pi_d(p) + U_d) / P with U_d draw d of the point's own stream
//!   `member_rng(seed, Purpose::Design, p)`. Each of the P strata [k/P, (k+1)/P) of every
//!   dimension holds exactly one point (exactly in floating point: `floor(u_d P) = pi_d(p)`). The
//!   points depend on P: a design of 100 points is not the first 100 points of one of 200.
//! * `Sobol`: Owen-scrambled Sobol points (Burley 2020, the `sobol_burley` crate): u_d =
//!   `sobol_burley::sample(p, d, s)` with the 32-bit scramble seed s = the xor of the two halves
//!   of `purpose_seed(seed, Purpose::Design)`. Its output is `f32`, so each coordinate is a
//!   multiple of 2^-24 (the resolution of a Sobol design). The first 2^k points are stratified
//!   in every dimension (one point in each interval [i 2^-k, (i+1) 2^-k)); their projection on
//!   the first two dimensions is a (0, k, 2)-net (one point in every elementary interval
//!   2^-a × 2^-(k-a)), and on other pairs a (t, k, 2)-net with the small t of the Joe–Kuo
//!   direction numbers (t <= 2 among the first 4 dimensions for k <= 8: only the first two
//!   dimensions of the Sobol sequence form a (0, 2)-sequence), so put the two most important
//!   parameters first; choose P a power of two for these properties to hold for the whole
//!   design. The sequence has at most [`SOBOL_MAX_POINTS`] = 2^16 points and
//!   [`SOBOL_MAX_DIMENSIONS`] = 256 dimensions. Unlike a Latin hypercube, a Sobol design of
//!   P points is the first P points of every longer one with the same seed.
//!
//! The mapping to an axis is `min + u (max - min)` on a linear scale and
//! `min exp(u (ln max - ln min))` (the same as `exp(ln min + u (ln max - ln min))`, but exact at
//! u = 0) on a log scale. Nothing is clamped; since u < 1 the values lie in [min, max). Only the
//! rounding of the mapping could land on `max` itself (when u is within a few ulps of 1); such a
//! value is replaced by the largest double below `max`.
//!
//! Bit-exact reproduction of Random and LatinHypercube designs across versions requires the same
//! `rand` / `rand_chacha` versions, and of Sobol designs the same `sobol_burley` version (all
//! pinned by Cargo.lock).
//!
//! A `Grid` is the cartesian product of the value lists: the first axis varies slowest, the last
//! fastest (point p's indices are the mixed-radix digits of p, see [`Design::grid_indices`]).

use std::fmt;

use rand::Rng;

use super::{member_rng, purpose_seed, EnsembleError, Purpose};

/// How a range axis is sampled.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scale {
    /// Uniform in [min, max).
    Linear,
    /// Log-uniform in [min, max) (requires min > 0).
    Log,
}

/// The values one parameter takes.
#[derive(Debug, Clone, PartialEq)]
pub enum Axis {
    /// An explicit list of finite values (grid designs).
    Values(Vec<f64>),
    /// A range [min, max) with min < max, both finite (sampled designs).
    Range { min: f64, max: f64, scale: Scale },
}

/// How the points of a design are laid out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DesignKind {
    /// The cartesian product of the value lists.
    Grid,
    /// Independent uniform points.
    Random,
    /// A Latin hypercube: every dimension stratified into P strata, one point each.
    LatinHypercube,
    /// An Owen-scrambled Sobol sequence.
    Sobol,
    /// A pick-freeze (Saltelli) design for Sobol sensitivity indices: `points` base points j,
    /// each followed by its D + 2 evaluations A_j, A_B^(1)_j, ..., A_B^(D)_j, B_j (SALib's
    /// order), where A_j and B_j are dimensions 0..D and D..2D of the scrambled Sobol point j
    /// and A_B^(i)_j is A_j with coordinate i taken from B_j.
    Saltelli,
}

impl DesignKind {
    /// The name used in messages: "grid", "random", "latin_hypercube" or "sobol".
    pub const fn name(self) -> &'static str {
        match self {
            DesignKind::Grid => "grid",
            DesignKind::Random => "random",
            DesignKind::LatinHypercube => "latin_hypercube",
            DesignKind::Sobol => "sobol",
            DesignKind::Saltelli => "saltelli",
        }
    }
}

/// The most dimensions of a Sobol design (the direction numbers of `sobol_burley`).
pub const SOBOL_MAX_DIMENSIONS: usize = 256;
/// The most points of a Sobol design: `sobol_burley` 0.5 uses only the low 16 bits of the
/// sample index.
pub const SOBOL_MAX_POINTS: u64 = 1 << 16;
/// The most entries P × D of a Latin hypercube's permutations (kept in memory as `u32`,
/// 256 MiB at this bound).
pub const LATIN_HYPERCUBE_MAX_ENTRIES: u64 = 1 << 26;

/// A parameter design: P points in D named parameters. See the [module documentation](self).
#[derive(Clone)]
pub struct Design {
    kind: DesignKind,
    names: Vec<String>,
    axes: Vec<Axis>,
    points: u64,
    seed: u64,
    /// Latin hypercube: pi_d for each dimension d (empty for other kinds). Shared: every sweep
    /// point's scene clones the design, and a copy per point made a large design quadratic.
    permutations: std::sync::Arc<Vec<Vec<u32>>>,
    /// Sobol: the scramble seed passed to `sobol_burley::sample`.
    sobol_seed: u32,
}

impl fmt::Debug for Design {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Design")
            .field("kind", &self.kind)
            .field("names", &self.names)
            .field("axes", &self.axes)
            .field("points", &self.points)
            .field("seed", &self.seed)
            .finish_non_exhaustive()
    }
}

fn spec(field: impl Into<String>, message: impl Into<String>) -> EnsembleError {
    EnsembleError::Spec {
        field: field.into(),
        message: message.into(),
    }
}

impl Design {
    /// Validates and builds a design. `field` (e.g. "sweep") prefixes the keys named in error
    /// messages ("sweep.mu", "sweep.points").
    ///
    /// Checks: at least one parameter, as many names as axes, names non-empty and unique; a
    /// `Grid` needs `Values` axes (non-empty, finite), its P is the product of the list lengths
    /// (`points`, if given, must equal it); sampled designs need `Range` axes (finite, min < max,
    /// finite max - min, min > 0 on a log scale) and `points` >= 1; a Sobol design at most
    /// [`SOBOL_MAX_DIMENSIONS`] parameters and [`SOBOL_MAX_POINTS`] points, a Latin hypercube at
    /// most [`LATIN_HYPERCUBE_MAX_ENTRIES`] = P × D. A Latin hypercube's permutations are drawn
    /// here.
    pub fn new(
        field: &str,
        kind: DesignKind,
        names: Vec<String>,
        axes: Vec<Axis>,
        points: Option<u64>,
        seed: u64,
    ) -> Result<Design, EnsembleError> {
        if names.len() != axes.len() {
            return Err(EnsembleError::LengthMismatch {
                field: format!("{field} names"),
                got: names.len(),
                expected: axes.len(),
                message: "one name per axis".to_string(),
            });
        }
        if names.is_empty() {
            return Err(spec(
                field,
                "no parameters to sweep (allowed: at least one parameter)",
            ));
        }
        for (i, name) in names.iter().enumerate() {
            if name.trim().is_empty() {
                return Err(spec(
                    field,
                    format!("parameter {i} has an empty name (allowed: a non-empty key)"),
                ));
            }
            if names[..i].contains(name) {
                return Err(spec(
                    format!("{field}.{name}"),
                    "given twice (allowed: each parameter once)",
                ));
            }
        }
        for (name, axis) in names.iter().zip(&axes) {
            check_axis(&format!("{field}.{name}"), kind, axis)?;
        }

        let d = axes.len() as u64;
        let points_key = format!("{field}.points");
        let p = match kind {
            DesignKind::Grid => {
                let product = axes
                    .iter()
                    .try_fold(1u64, |acc, a| acc.checked_mul(axis_len(a) as u64))
                    .ok_or_else(|| {
                        spec(
                            field,
                            "the grid has more than 2^64 points (allowed: fewer values)",
                        )
                    })?;
                match points {
                    Some(n) if n != product => {
                        return Err(spec(
                            points_key,
                            format!(
                                "{n} given but the grid of the value lists has {product} points \
                                 (allowed: leave it out, or {product})"
                            ),
                        ))
                    }
                    _ => product,
                }
            }
            _ => {
                let name = kind.name();
                let n = points.ok_or_else(|| {
                    spec(
                        &points_key,
                        format!(
                            "missing: a {name} design needs the number of points \
                             (allowed: an integer >= 1)"
                        ),
                    )
                })?;
                if n == 0 {
                    return Err(spec(&points_key, "0 points (allowed: an integer >= 1)"));
                }
                n
            }
        };

        let mut permutations = Vec::new();
        match kind {
            DesignKind::Sobol => {
                if axes.len() > SOBOL_MAX_DIMENSIONS {
                    return Err(spec(
                        field,
                        format!(
                            "{} parameters, more than a sobol design supports \
                             (allowed: at most {SOBOL_MAX_DIMENSIONS})",
                            axes.len()
                        ),
                    ));
                }
                if p > SOBOL_MAX_POINTS {
                    return Err(spec(
                        points_key,
                        format!(
                            "{p} points, more than a sobol design supports \
                             (allowed: 1 to {SOBOL_MAX_POINTS} = 2^16)"
                        ),
                    ));
                }
            }
            DesignKind::LatinHypercube => {
                if p.saturating_mul(d) > LATIN_HYPERCUBE_MAX_ENTRIES {
                    return Err(spec(
                        points_key,
                        format!(
                            "{p} points × {d} parameters, more than a latin_hypercube design \
                             supports (allowed: points × parameters <= \
                             {LATIN_HYPERCUBE_MAX_ENTRIES} = 2^26)"
                        ),
                    ));
                }
                permutations = (0..d)
                    .map(|dim| latin_permutation(seed, dim, p as u32))
                    .collect();
            }
            DesignKind::Saltelli => {
                if 2 * axes.len() > SOBOL_MAX_DIMENSIONS {
                    return Err(spec(
                        field,
                        format!(
                            "{} parameters, more than a saltelli design supports \
                             (allowed: at most {})",
                            axes.len(),
                            SOBOL_MAX_DIMENSIONS / 2
                        ),
                    ));
                }
                if p > SOBOL_MAX_POINTS {
                    return Err(spec(
                        points_key,
                        format!(
                            "{p} base points, more than a saltelli design supports \
                             (allowed: 1 to {SOBOL_MAX_POINTS} = 2^16)"
                        ),
                    ));
                }
            }
            DesignKind::Grid | DesignKind::Random => {}
        }
        // A Saltelli design evaluates each base point D + 2 times.
        let p = if kind == DesignKind::Saltelli {
            p.checked_mul(d + 2)
                .ok_or_else(|| spec(points_key.clone(), "too many points"))?
        } else {
            p
        };

        let k = purpose_seed(seed, Purpose::Design);
        Ok(Design {
            kind,
            names,
            axes,
            points: p,
            seed,
            permutations: std::sync::Arc::new(permutations),
            sobol_seed: (k ^ (k >> 32)) as u32,
        })
    }

    /// The number of points P.
    pub fn len(&self) -> u64 {
        self.points
    }

    /// Always false: a design has at least one point.
    pub fn is_empty(&self) -> bool {
        self.points == 0
    }

    /// The number of parameters D.
    pub fn dim(&self) -> usize {
        self.axes.len()
    }

    /// The parameter names, in the order of [`Design::values`].
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// The axes, in the order of [`Design::names`].
    pub fn axes(&self) -> &[Axis] {
        &self.axes
    }

    /// The kind of design.
    pub fn kind(&self) -> DesignKind {
        self.kind
    }

    /// For a Saltelli design, the number of base points N (P = N (D + 2)).
    pub fn base_points(&self) -> Option<u64> {
        (self.kind == DesignKind::Saltelli).then(|| self.points / (self.axes.len() as u64 + 2))
    }

    /// The seed the design was built with.
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// Point p's parameter values, in [`Design::names`] order: a pure function of
    /// (kind, axes, P, seed, p).
    ///
    /// # Panics
    ///
    /// If `p >= self.len()`.
    pub fn values(&self, p: u64) -> Vec<f64> {
        self.check_index(p);
        match self.kind {
            DesignKind::Grid => self
                .grid_digits(p)
                .into_iter()
                .zip(&self.axes)
                .map(|(i, axis)| match axis {
                    Axis::Values(v) => v[i],
                    Axis::Range { .. } => unreachable!("grid axes are lists (checked in new)"),
                })
                .collect(),
            _ => self
                .unit(p)
                .into_iter()
                .zip(&self.axes)
                .map(|(u, axis)| map_unit(axis, u))
                .collect(),
        }
    }

    /// Point p in the unit cube [0, 1)^D, before mapping to the axes (see the
    /// [module documentation](self)). For a grid: i_d / n_d, where i_d is the index of the
    /// point's value in list d of length n_d.
    ///
    /// # Panics
    ///
    /// If `p >= self.len()`.
    pub fn unit(&self, p: u64) -> Vec<f64> {
        self.check_index(p);
        let dim = self.axes.len();
        match self.kind {
            DesignKind::Grid => self
                .grid_digits(p)
                .into_iter()
                .zip(&self.axes)
                .map(|(i, axis)| i as f64 / axis_len(axis) as f64)
                .collect(),
            DesignKind::Random => {
                let mut rng = member_rng(self.seed, Purpose::Design, p);
                (0..dim).map(|_| rng.random::<f64>()).collect()
            }
            DesignKind::LatinHypercube => {
                let mut rng = member_rng(self.seed, Purpose::Design, p);
                self.permutations
                    .iter()
                    .map(|perm| latin_unit(perm[p as usize], rng.random::<f64>(), self.points))
                    .collect()
            }
            DesignKind::Sobol => (0..dim as u32)
                .map(|d| f64::from(sobol_burley::sample(p as u32, d, self.sobol_seed)))
                .collect(),
            DesignKind::Saltelli => {
                let (j, k) = (
                    (p / (dim as u64 + 2)) as u32,
                    (p % (dim as u64 + 2)) as usize,
                );
                let from_b = |d: usize| k == dim + 1 || (k >= 1 && d == k - 1);
                (0..dim)
                    .map(|d| {
                        let column = if from_b(d) { dim + d } else { d };
                        f64::from(sobol_burley::sample(j, column as u32, self.sobol_seed))
                    })
                    .collect()
            }
        }
    }

    /// For a grid, point p's index into each value list (the first axis varies slowest, the
    /// last fastest); `None` for a sampled design.
    ///
    /// # Panics
    ///
    /// If `p >= self.len()`.
    pub fn grid_indices(&self, p: u64) -> Option<Vec<usize>> {
        self.check_index(p);
        (self.kind == DesignKind::Grid).then(|| self.grid_digits(p))
    }

    fn check_index(&self, p: u64) {
        assert!(
            p < self.points,
            "design point {p} out of range (the design has {} points)",
            self.points
        );
    }

    /// The mixed-radix digits of p, the last axis the fastest.
    fn grid_digits(&self, p: u64) -> Vec<usize> {
        let mut digits = vec![0; self.axes.len()];
        let mut rest = p;
        for (digit, axis) in digits.iter_mut().zip(&self.axes).rev() {
            let n = axis_len(axis) as u64;
            *digit = (rest % n) as usize;
            rest /= n;
        }
        digits
    }
}

/// Number of values of a list axis (1 for a range, unused).
fn axis_len(axis: &Axis) -> usize {
    match axis {
        Axis::Values(v) => v.len(),
        Axis::Range { .. } => 1,
    }
}

fn check_axis(key: &str, kind: DesignKind, axis: &Axis) -> Result<(), EnsembleError> {
    match (kind, axis) {
        (DesignKind::Grid, Axis::Range { .. }) => Err(spec(
            key,
            "a grid design needs a list of values, not a range \
             (allowed: a list of finite values)",
        )),
        (DesignKind::Grid, Axis::Values(values)) => {
            if values.is_empty() {
                return Err(spec(
                    key,
                    "the list of values is empty (allowed: at least one finite value)",
                ));
            }
            if let Some(i) = values.iter().position(|v| !v.is_finite()) {
                return Err(EnsembleError::entry(
                    key,
                    i,
                    values[i],
                    "not finite",
                    "finite values",
                ));
            }
            Ok(())
        }
        (_, Axis::Values(_)) => Err(spec(
            key,
            format!(
                "a {} design needs a range (min, max, scale), not a list of values \
                 (allowed: a range with min < max)",
                kind.name()
            ),
        )),
        (_, &Axis::Range { min, max, scale }) => {
            for (end, v) in [("min", min), ("max", max)] {
                if !v.is_finite() {
                    return Err(EnsembleError::parameter(
                        &format!("{key}.{end}"),
                        v,
                        "not finite",
                        "a finite number",
                    ));
                }
            }
            if min >= max {
                return Err(spec(
                    key,
                    format!("min = {min} >= max = {max} (allowed: min < max)"),
                ));
            }
            if !(max - min).is_finite() {
                return Err(spec(
                    key,
                    format!(
                        "max - min = {} overflows (allowed: a finite span max - min)",
                        max - min
                    ),
                ));
            }
            if scale == Scale::Log && min <= 0.0 {
                return Err(EnsembleError::parameter(
                    &format!("{key}.min"),
                    min,
                    "a log-scale range must be positive",
                    "min > 0 on a log scale",
                ));
            }
            Ok(())
        }
    }
}

/// Maps u in [0, 1) to a range axis (see the module documentation); values stay below `max`.
fn map_unit(axis: &Axis, u: f64) -> f64 {
    let Axis::Range { min, max, scale } = *axis else {
        unreachable!("sampled designs have range axes (checked in new)")
    };
    let v = match scale {
        Scale::Linear => min + u * (max - min),
        Scale::Log => min * (u * (max.ln() - min.ln())).exp(),
    };
    if v < max {
        v
    } else {
        // Only reached through rounding when u is within a few ulps of 1.
        prev_below(max)
    }
}

/// The largest double below the finite `x`.
fn prev_below(x: f64) -> f64 {
    if x > 0.0 {
        f64::from_bits(x.to_bits() - 1)
    } else if x == 0.0 {
        -f64::from_bits(1)
    } else {
        f64::from_bits(x.to_bits() + 1)
    }
}

/// Dimension `dim`'s Latin hypercube permutation of 0..n: Fisher–Yates, index j for position i
/// drawn uniformly in 0..=i (as `u32`) from `member_rng(seed, Purpose::DesignPermutation, dim)`.
fn latin_permutation(seed: u64, dim: u64, n: u32) -> Vec<u32> {
    let mut rng = member_rng(seed, Purpose::DesignPermutation, dim);
    let mut perm: Vec<u32> = (0..n).collect();
    for i in (1..n).rev() {
        let j = rng.random_range(0..=i);
        perm.swap(i as usize, j as usize);
    }
    perm
}

/// (k + v) / n for v in [0, 1), moved by at most a few ulps so that `floor(u n) = k` holds in
/// floating point (hence u < 1).
fn latin_unit(k: u32, v: f64, n: u64) -> f64 {
    let (k, n) = (f64::from(k), n as f64);
    let mut u = (k + v) / n;
    while (u * n).floor() > k {
        u = prev_below(u);
    }
    while (u * n).floor() < k {
        u = f64::from_bits(u.to_bits() + 1);
    }
    u
}

#[cfg(test)]
mod tests;
