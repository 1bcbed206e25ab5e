//! Radii read from a file, and the conversions between radii and critical distances.

use std::path::Path;

use super::EnsembleError;
use crate::input::{csv_rows, number_text};

/// Roughness radii r (particle files, roughness files) lie in 0 <= r < MAX_ROUGHNESS_RADIUS, the
/// length of the domain [0, 1].
pub const MAX_ROUGHNESS_RADIUS: f64 = 1.0;

/// Reads a CSV with header `r` and one radius per row (N+1 rows; `#` starts a comment line).
pub fn read_radii_file(path: &Path) -> Result<Vec<f64>, EnsembleError> {
    let err = |line: usize, message: String| EnsembleError::RoughnessFile {
        path: path.to_path_buf(),
        line,
        message,
    };
    let open_error = |e: csv::Error| EnsembleError::Io {
        path: path.to_path_buf(),
        source: match e.into_kind() {
            csv::ErrorKind::Io(io) => io,
            other => std::io::Error::other(format!("{other:?}")),
        },
    };
    let (mut reader, headers) = csv_rows::open_with_header(path, open_error, err)?;
    let names: Vec<&str> = headers.iter().collect();
    if names != ["r"] {
        return Err(err(
            1,
            format!("header is {names:?}; expected one column named r"),
        ));
    }
    let mut radii = Vec::new();
    for (line, record) in csv_rows::rows_with_lines(&mut reader, err)? {
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
        if r >= MAX_ROUGHNESS_RADIUS {
            return Err(err(
                line,
                format!(
                    "column r: roughness radius r = {} is not smaller than the domain [0, 1] (allowed: 0 <= r < {MAX_ROUGHNESS_RADIUS})",
                    number_text(r)
                ),
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
