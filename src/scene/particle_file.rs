//! Initial chains from a particle file: a CSV with one row per particle (x, u and optionally the
//! roughness radius r), checked row by row so that an error names the file's line.

use std::path::Path;

use super::{number_text, MAX_ROUGHNESS_RADIUS, MAX_VELOCITY};
use crate::error::{Error, Result};
use crate::model::chain::Chain;

#[derive(Debug, serde::Deserialize)]
struct ParticleRow {
    x: f64,
    u: f64,
    r: Option<f64>,
}

/// Gaps x_i − x_(i−1) − 2 eps with |gap| at most this count as contact (a cluster): the rounding
/// of positions written in decimal (absolute 1e-12, plus 1e-9 of the radius). Smaller negative
/// gaps are overlaps, refused. Documented in README (`[initial] particles`).
pub fn contact_tolerance(eps: f64) -> f64 {
    1e-12 + 1e-9 * eps
}

/// Reads a CSV with header `x,u,r` (r optional: without it, no roughness and no repulsion).
/// `expected_n` is `model.particles` when the scene gives it.
pub fn chain_from_particle_file(path: &Path, eps: f64, expected_n: Option<usize>) -> Result<Chain> {
    let err = |line: usize, message: String| Error::ParticleFile {
        path: path.to_path_buf(),
        line,
        message,
    };
    let open_error = |e: csv::Error| Error::Io {
        path: path.to_path_buf(),
        source: std::io::Error::other(format!("cannot open the particle file: {e}")),
    };
    let (mut reader, headers) = crate::input::csv_rows::open_with_header(path, open_error, err)?;
    let names: Vec<&str> = headers.iter().collect();
    if names != ["x", "u"] && names != ["x", "u", "r"] {
        return Err(err(
            1,
            format!("header is {names:?}; expected the columns x,u,r (or x,u without roughness)"),
        ));
    }
    let has_roughness = names.len() == 3;
    let mut rows: Vec<ParticleRow> = Vec::new();
    // Physical line of each row (comment lines are skipped by the reader).
    let mut lines: Vec<usize> = Vec::new();
    for (line, record) in crate::input::csv_rows::rows_with_lines(&mut reader, err)? {
        let row: ParticleRow = record
            .deserialize(Some(&headers))
            .map_err(|e| err(line, format!("not a row of numbers x,u,r: {e}")))?;
        lines.push(line);
        for (name, v) in [("x", Some(row.x)), ("u", Some(row.u)), ("r", row.r)] {
            if let Some(v) = v {
                if !v.is_finite() {
                    return Err(err(line, format!("{name} = {v} is not a finite number")));
                }
            }
        }
        if row.u.abs() > MAX_VELOCITY {
            return Err(err(
                line,
                format!(
                    "column u: velocity u = {} is far beyond what the solver can follow (velocities are in domain lengths per unit time) (allowed: |u| <= {MAX_VELOCITY:e})",
                    number_text(row.u)
                ),
            ));
        }
        if has_roughness {
            match row.r {
                Some(r) if (0.0..MAX_ROUGHNESS_RADIUS).contains(&r) => {}
                Some(r) if r >= 0.0 => {
                    return Err(err(
                        line,
                        format!(
                            "column r: roughness radius r = {} is not smaller than the domain [0, 1] (allowed: 0 <= r < {MAX_ROUGHNESS_RADIUS})",
                            number_text(r)
                        ),
                    ))
                }
                Some(r) => return Err(err(line, format!("roughness radius r = {r} must be >= 0"))),
                None => return Err(err(line, "missing roughness radius r".into())),
            }
        }
        rows.push(row);
    }
    let line_of = |i: usize| lines.get(i).copied().unwrap_or(0);
    let n = rows.len().saturating_sub(1);
    if n < 2 {
        return Err(err(
            rows.len() + 1,
            format!(
                "{} particle rows; need N+1 >= 3 rows (particles 0..N)",
                rows.len()
            ),
        ));
    }
    if let Some(expected) = expected_n {
        if expected != n {
            return Err(err(
                rows.len() + 1,
                format!(
                    "{} rows give N = {n}, but model.particles = {expected}",
                    rows.len()
                ),
            ));
        }
    }
    // End particles are fixed at 0 and 1 with zero velocity.
    const POSITION_TOLERANCE: f64 = 1e-12;
    if rows[0].x.abs() > POSITION_TOLERANCE || rows[0].u != 0.0 {
        return Err(err(
            line_of(0),
            format!(
                "particle 0 must be at x = 0 with u = 0 (got x = {}, u = {})",
                rows[0].x, rows[0].u
            ),
        ));
    }
    if (rows[n].x - 1.0).abs() > POSITION_TOLERANCE || rows[n].u != 0.0 {
        return Err(err(
            line_of(n),
            format!(
                "particle N must be at x = 1 with u = 0 (got x = {}, u = {})",
                rows[n].x, rows[n].u
            ),
        ));
    }
    let mut x: Vec<f64> = rows.iter().map(|r| r.x).collect();
    x[0] = 0.0;
    x[n] = 1.0;
    let contact_tolerance = contact_tolerance(eps);
    let mut gaps = Vec::with_capacity(n);
    let mut bonded = vec![false; n];
    for i in 1..=n {
        let d = x[i] - x[i - 1] - 2.0 * eps;
        if d < -contact_tolerance {
            return Err(err(
                line_of(i),
                format!(
                    "particles {} and {i} overlap: gap x_{i} - x_{} - 2 radius = {d:e} < 0 (need x_i >= x_(i-1) + 2 radius)",
                    i - 1,
                    i - 1
                ),
            ));
        }
        if d.abs() <= contact_tolerance {
            bonded[i - 1] = true;
            gaps.push(0.0);
        } else {
            gaps.push(d);
        }
    }
    if bonded.iter().all(|&b| b) {
        return Err(err(
            line_of(n),
            "every gap is zero: the chain is one rigid body and nothing moves".into(),
        ));
    }
    // Particles glued into one cluster must start with one velocity (Appendix A: rigid bodies).
    for i in 1..n {
        if bonded[i - 1] {
            let (ua, ub) = (rows[i - 1].u, rows[i].u);
            if ua != ub {
                return Err(err(
                    line_of(i),
                    format!("particles {} and {i} touch (zero gap) but have different velocities {ua} and {ub}; a cluster moves rigidly", i - 1),
                ));
            }
        }
    }
    if bonded[n - 1] && rows[n - 1].u != 0.0 {
        return Err(err(
            line_of(n - 1),
            "particle N-1 touches the fixed particle N, so its velocity must be 0".into(),
        ));
    }
    let dstar = has_roughness.then(|| {
        (1..=n)
            .map(|i| rows[i - 1].r.unwrap_or(0.0) + rows[i].r.unwrap_or(0.0))
            .collect()
    });
    Ok(Chain {
        eps,
        gaps,
        velocities: rows[1..n].iter().map(|r| r.u).collect(),
        dstar,
        bonded: bonded.iter().any(|&b| b).then_some(bonded),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Three particles between the fixed ends (N = 4), radius eps = 0.05; the first free gap is
    /// `gap`. Returns whether it became a bonded (zero) gap, or the error text.
    fn first_gap_bonded(gap: f64) -> std::result::Result<bool, String> {
        let eps = 0.05;
        let x1 = 2.0 * eps + gap;
        let text = format!("x,u\n0,0\n{x1:.17e},0\n0.5,0\n0.75,0\n1,0\n");
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.csv");
        std::fs::write(&path, text).unwrap();
        chain_from_particle_file(&path, eps, None)
            .map(|c| c.bonded.is_some_and(|b| b[0]))
            .map_err(|e| e.to_string())
    }

    /// The documented threshold (1e-12 + 1e-9 eps = 5.1e-11 here): gaps of 0.5 and 0.9 of it are
    /// contact, 1.1 and 2 of it are free, and −1.1 of it is an overlap.
    #[test]
    fn contact_threshold_is_the_documented_one() {
        let tol = contact_tolerance(0.05);
        assert!((tol - 5.1e-11).abs() < 1e-24);
        for f in [0.0, 0.5, 0.9, -0.9] {
            assert_eq!(first_gap_bonded(f * tol), Ok(true), "gap {f} tolerance");
        }
        for f in [1.1, 2.0] {
            assert_eq!(first_gap_bonded(f * tol), Ok(false), "gap {f} tolerance");
        }
        let overlap = first_gap_bonded(-1.1 * tol).unwrap_err();
        assert!(overlap.contains("overlap"), "{overlap}");
    }
}
