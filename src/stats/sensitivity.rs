//! Sobol sensitivity indices from a pick-freeze (Saltelli) design: first-order indices by the
//! estimator of Saltelli et al. (2010) and total-order indices by Jansen's (1999), as SALib's
//! `sobol.analyze` and scipy compute them, with bootstrap intervals over the base points.
//!
//! For base point j the design evaluates f(A_j), f(A_B^(i)_j) for each key i (A_j with
//! coordinate i taken from B_j) and f(B_j). With the outputs standardised over all evaluations
//! (mean 0, standard deviation 1, as SALib does: the estimators are not shift invariant) and
//! V the variance (ddof 0) of the 2N values f(A_j), f(B_j):
//!
//! ```text
//! S1_i = mean_j f(B_j) (f(A_B^(i)_j) - f(A_j)) / V
//! ST_i = mean_j (f(A_j) - f(A_B^(i)_j))^2 / (2 V)
//! ```
//!
//! The interval of each index is the percentile interval of the same estimator over
//! `resamples` bootstrap resamples of the base points (drawn from a seeded ChaCha stream, so a
//! study reports the same intervals wherever it is computed); the standard error is the
//! resamples' standard deviation.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The evaluations of one base point: f(A_j), f(A_B^(i)_j) for each key, f(B_j).
#[derive(Debug, Clone, PartialEq)]
pub struct PickFreezeGroup {
    pub a: f64,
    pub ab: Vec<f64>,
    pub b: f64,
}

/// One index with its bootstrap interval.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Index {
    pub value: f64,
    pub low: f64,
    pub high: f64,
    /// The bootstrap standard deviation.
    pub std_error: f64,
}

/// The indices of every key.
#[derive(Debug, Clone, PartialEq)]
pub struct SobolIndices {
    pub first: Vec<Index>,
    pub total: Vec<Index>,
    /// Base points used.
    pub groups: usize,
}

/// How the intervals are computed.
#[derive(Debug, Clone, Copy)]
pub struct Bootstrap {
    pub resamples: usize,
    /// The interval's coverage, e.g. 0.95.
    pub confidence: f64,
    pub seed: u64,
}

impl Default for Bootstrap {
    fn default() -> Self {
        Bootstrap {
            resamples: 1000,
            confidence: 0.95,
            seed: 0x50b0_1de5,
        }
    }
}

/// Both estimators over the groups `idx` (indices into `groups`, repeats allowed), outputs
/// standardised by `(mean, std)`.
fn estimate(groups: &[PickFreezeGroup], idx: &[usize], centre: (f64, f64)) -> (Vec<f64>, Vec<f64>) {
    let (mean, std) = centre;
    let z = |y: f64| (y - mean) / std;
    let d = groups[0].ab.len();
    let n = idx.len() as f64;
    // Variance (ddof 0) of the 2n values f(A), f(B).
    let (mut s, mut s2) = (0.0, 0.0);
    for &j in idx {
        let (a, b) = (z(groups[j].a), z(groups[j].b));
        s += a + b;
        s2 += a * a + b * b;
    }
    let m = s / (2.0 * n);
    let var = s2 / (2.0 * n) - m * m;
    let mut first = vec![0.0; d];
    let mut total = vec![0.0; d];
    for &j in idx {
        let g = &groups[j];
        let (a, b) = (z(g.a), z(g.b));
        for i in 0..d {
            let ab = z(g.ab[i]);
            first[i] += b * (ab - a);
            total[i] += (a - ab) * (a - ab);
        }
    }
    (
        first.iter().map(|f| f / n / var).collect(),
        total.iter().map(|t| 0.5 * t / n / var).collect(),
    )
}

/// The first- and total-order indices of the keys from complete pick-freeze groups (at least
/// two, every one with the same number of keys and finite values), with bootstrap intervals.
/// `None` when there are fewer than two groups or the outputs do not vary.
pub fn sobol_indices(groups: &[PickFreezeGroup], bootstrap: Bootstrap) -> Option<SobolIndices> {
    let n = groups.len();
    if n < 2 || groups.iter().any(|g| g.ab.len() != groups[0].ab.len()) {
        return None;
    }
    let values = || {
        groups.iter().flat_map(|g| {
            std::iter::once(g.a)
                .chain(g.ab.iter().copied())
                .chain([g.b])
        })
    };
    // A response equal at every point but for rounding (a key that nothing reads) has no
    // variance to apportion: its mean's rounding alone made a tiny std and NaN indices.
    let lo = values().fold(f64::INFINITY, f64::min);
    let hi = values().fold(f64::NEG_INFINITY, f64::max);
    if !(hi - lo > 1e-12 * lo.abs().max(hi.abs())) {
        return None;
    }
    let count = values().count() as f64;
    let mean = values().sum::<f64>() / count;
    let std = (values().map(|y| (y - mean) * (y - mean)).sum::<f64>() / count).sqrt();
    if !(std > 0.0 && std.is_finite()) {
        return None;
    }
    let all: Vec<usize> = (0..n).collect();
    let (s1, st) = estimate(groups, &all, (mean, std));
    let d = s1.len();
    let mut rng = ChaCha8Rng::seed_from_u64(bootstrap.seed);
    let mut boot_first: Vec<Vec<f64>> = vec![Vec::with_capacity(bootstrap.resamples); d];
    let mut boot_total: Vec<Vec<f64>> = vec![Vec::with_capacity(bootstrap.resamples); d];
    let mut idx = vec![0usize; n];
    for _ in 0..bootstrap.resamples {
        for k in idx.iter_mut() {
            *k = rng.random_range(0..n);
        }
        let (f, t) = estimate(groups, &idx, (mean, std));
        for i in 0..d {
            boot_first[i].push(f[i]);
            boot_total[i].push(t[i]);
        }
    }
    let tail = 0.5 * (1.0 - bootstrap.confidence);
    let index = |value: f64, samples: &mut Vec<f64>| -> Index {
        samples.retain(|v| v.is_finite());
        samples.sort_by(f64::total_cmp);
        let at = |q: f64| -> f64 {
            if samples.is_empty() {
                return f64::NAN;
            }
            samples[((q * (samples.len() - 1) as f64).round() as usize).min(samples.len() - 1)]
        };
        let k = samples.len() as f64;
        let m = samples.iter().sum::<f64>() / k;
        let sd = (samples.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (k - 1.0)).sqrt();
        Index {
            value,
            low: at(tail),
            high: at(1.0 - tail),
            std_error: sd,
        }
    };
    Some(SobolIndices {
        first: (0..d).map(|i| index(s1[i], &mut boot_first[i])).collect(),
        total: (0..d).map(|i| index(st[i], &mut boot_total[i])).collect(),
        groups: n,
    })
}
