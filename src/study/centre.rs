//! The centre of a member's density peak, a scalar of every output time: one row at a time
//! ([`peak_centre`]) and four rows side by side ([`peak_centres`], the same bits).

/// Members whose peak centres are computed side by side ([`peak_centres`]).
pub(super) const CENTRES_TOGETHER: usize = 4;

/// Centre of mass of the density peak: the centroid of the excess of rho over its spatial mean
/// (NaN when the profile is flat, or `rho` is empty).
pub fn peak_centre(x: &[f64], rho: &[f64]) -> f64 {
    if rho.is_empty() {
        return f64::NAN;
    }
    let mean = rho.iter().sum::<f64>() / rho.len() as f64;
    let (mut wx, mut w) = (0.0, 0.0);
    for (xi, r) in x.iter().zip(rho) {
        let e = (r - mean).max(0.0);
        wx += xi * e;
        w += e;
    }
    if w > 1e-12 {
        wx / w
    } else {
        f64::NAN
    }
}

/// [`peak_centre`] of each row, the same bits, four rows of the grid's length at a time: each
/// row's sums still run in order, but four of them interleave, so the adds do not wait on each
/// other (one row's sums are chains of dependent adds, about a tenth of a small study's
/// statistics).
pub fn peak_centres(x: &[f64], rows: &[&[f64]]) -> Vec<f64> {
    let mut centres = Vec::with_capacity(rows.len());
    let mut fours = rows.chunks_exact(4);
    for four in &mut fours {
        if four.iter().all(|r| r.len() == x.len() && !r.is_empty()) {
            centres.extend(peak_centre_of_four(x, [four[0], four[1], four[2], four[3]]));
        } else {
            centres.extend(four.iter().map(|r| peak_centre(x, r)));
        }
    }
    centres.extend(fours.remainder().iter().map(|r| peak_centre(x, r)));
    centres
}

/// [`peak_centre`] of four rows of `x`'s length, at least one point.
fn peak_centre_of_four(x: &[f64], rows: [&[f64]; 4]) -> [f64; 4] {
    let g = x.len();
    // `Iterator::sum` of f64 starts from -0.0.
    let mut sum = [-0.0f64; 4];
    for j in 0..g {
        for (s, r) in sum.iter_mut().zip(rows) {
            *s += r[j];
        }
    }
    let mean = sum.map(|s| s / g as f64);
    let (mut wx, mut w) = ([0.0f64; 4], [0.0f64; 4]);
    for (j, &xj) in x.iter().enumerate() {
        for l in 0..4 {
            let e = (rows[l][j] - mean[l]).max(0.0);
            wx[l] += xj * e;
            w[l] += e;
        }
    }
    std::array::from_fn(|l| if w[l] > 1e-12 { wx[l] / w[l] } else { f64::NAN })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_rng::uniform_stream;

    /// Four rows side by side give each row's own centre, bit for bit, whatever their mix of
    /// flat, peaked, empty and NaN rows.
    #[test]
    fn peak_centres_side_by_side_are_each_rows_own() {
        let g = 37;
        let x: Vec<f64> = (0..g).map(|j| j as f64 / (g - 1) as f64).collect();
        let mut next = uniform_stream(0x9e3779b97f4a7c15);
        let mut rows: Vec<Vec<f64>> = (0..13)
            .map(|_| (0..g).map(|_| 0.5 + next()).collect())
            .collect();
        rows[3] = vec![0.7; g];
        rows[5] = Vec::new();
        rows[8][4] = f64::NAN;
        let refs: Vec<&[f64]> = rows.iter().map(|r| &r[..]).collect();
        let together = peak_centres(&x, &refs);
        assert_eq!(together.len(), rows.len());
        for (r, c) in rows.iter().zip(&together) {
            assert_eq!(c.to_bits(), peak_centre(&x, r).to_bits());
        }
        // Not a NaN everywhere: the peaked rows have centres inside [0, 1].
        assert!(together[0] > 0.0 && together[0] < 1.0);
        assert!(together[3].is_nan() && together[5].is_nan());
    }
}
