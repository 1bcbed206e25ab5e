//! Ensemble generators (src/ensemble.rs) against independent expectations.
//!
//! Statistical checks use member-level blocks: for each member m a per-member statistic s_m is
//! computed (e.g. the mean over particles of X_i - 1, X_i = r_i / mean_i); members are iid by
//! construction, so the standard error of the ensemble average is SE = sd(s_m) / sqrt(M), valid even
//! where particles within a member are correlated (the Correlated generator). Every check asserts
//! |estimate - expected| <= 5 SE (a false alarm has probability ~6e-7 per check for a normal
//! estimate). Run with `--nocapture` to see the measured numbers.

use std::f64::consts::PI;
use std::io::Write;

use roughlub::ensemble::{
    correlated_field, dstar_from_radii, jitter_gaps, mean_radii_from_rho_star, member_rng,
    perturbed_velocity, roughness_radii, EnsembleError, Purpose, RoughnessKind, RoughnessSampler,
    RoughnessSpec, UNIFORM_MAX_SPREAD,
};

const N: usize = 200; // 201 particles
const MEMBERS: u64 = 2000;
const SEED: u64 = 20240611;

fn positions_uniform(n: usize) -> Vec<f64> {
    (0..=n).map(|i| i as f64 / n as f64).collect()
}

/// A non-constant mean profile, so that per-particle scaling is exercised.
fn mean_profile(n: usize) -> Vec<f64> {
    (0..=n)
        .map(|i| 0.01 * (1.0 + 0.5 * (2.0 * PI * i as f64 / n as f64).sin()))
        .collect()
}

/// Mean and standard error of iid values.
fn mean_se(values: &[f64]) -> (f64, f64) {
    let m = values.len() as f64;
    let mean = values.iter().sum::<f64>() / m;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (m - 1.0);
    (mean, (var / m).sqrt())
}

fn assert_within(name: &str, estimate: f64, se: f64, expected: f64) {
    let tol = (5.0 * se).max(1e-12);
    eprintln!(
        "{name}: estimate {estimate:.6}, expected {expected:.6}, SE {se:.2e}, |diff|/SE {:.2}",
        (estimate - expected).abs() / se.max(1e-300)
    );
    assert!(
        (estimate - expected).abs() <= tol,
        "{name}: estimate {estimate} vs expected {expected}: |diff| {} > 5 SE = {tol}",
        (estimate - expected).abs()
    );
}

/// Checks E[X] = 1 and E[(X-1)^2] = spread^2 for X = r/mean over MEMBERS × (N+1).
/// Returns (mean of X, relative sd) for reporting.
fn check_moments(name: &str, spec: &RoughnessSpec, check_variance: bool) -> (f64, f64) {
    let mean = mean_profile(N);
    let q = positions_uniform(N);
    let sampler = RoughnessSampler::new(spec, &mean, &q, SEED).unwrap();
    let mut r = vec![0.0; N + 1];
    let mut first = Vec::with_capacity(MEMBERS as usize);
    let mut second = Vec::with_capacity(MEMBERS as usize);
    for m in 0..MEMBERS {
        sampler.fill(m, &mut r);
        assert!(
            r.iter().all(|&v| v >= 0.0 && v.is_finite()),
            "{name}: r < 0"
        );
        let x = r.iter().zip(&mean).map(|(r, m)| r / m - 1.0);
        first.push(x.clone().sum::<f64>() / (N + 1) as f64);
        second.push(x.map(|d| d * d).sum::<f64>() / (N + 1) as f64);
    }
    let (m1, se1) = mean_se(&first);
    let (m2, se2) = mean_se(&second);
    assert_within(&format!("{name} mean(r/mean) - 1"), m1, se1, 0.0);
    if check_variance {
        assert_within(
            &format!("{name} E(r/mean - 1)^2"),
            m2,
            se2,
            spec.spread * spec.spread,
        );
    }
    eprintln!(
        "{name}: mean(r/mean) = {:.5}, relative sd = {:.5} (spread {})",
        1.0 + m1,
        m2.sqrt(),
        spec.spread
    );
    (1.0 + m1, m2.sqrt())
}

#[test]
fn moments_match_mean_and_spread() {
    check_moments(
        "uniform 0.5",
        &RoughnessSpec::new(RoughnessKind::Uniform, 0.5),
        true,
    );
    check_moments(
        "uniform 1/sqrt3",
        &RoughnessSpec::new(RoughnessKind::Uniform, UNIFORM_MAX_SPREAD),
        true,
    );
    check_moments(
        "lognormal 0.3",
        &RoughnessSpec::new(RoughnessKind::LogNormal, 0.3),
        true,
    );
    check_moments(
        "twopoint 0.4",
        &RoughnessSpec::new(RoughnessKind::TwoPoint, 0.4),
        true,
    );
    check_moments(
        "correlated 0.3 l=0.05",
        &RoughnessSpec::new(RoughnessKind::Correlated { length: 0.05 }, 0.3),
        true,
    );
    // Heavy tails at spread 2: the mean is still checked (block SE), the variance estimate is too
    // skewed for a 5-SE test and is only reported.
    check_moments(
        "lognormal 2.0",
        &RoughnessSpec::new(RoughnessKind::LogNormal, 2.0),
        false,
    );
    check_moments(
        "correlated 2.0 l=0.05",
        &RoughnessSpec::new(RoughnessKind::Correlated { length: 0.05 }, 2.0),
        false,
    );
}

#[test]
fn constant_is_the_mean_profile() {
    let mean = mean_profile(N);
    let spec = RoughnessSpec::new(RoughnessKind::Constant, 0.0);
    for m in [0, 7, 1 << 40] {
        assert_eq!(roughness_radii(&spec, &mean, &[], SEED, m).unwrap(), mean);
    }
}

#[test]
fn two_point_takes_exactly_two_values() {
    let mean = mean_profile(N);
    let spec = RoughnessSpec::new(RoughnessKind::TwoPoint, 0.4);
    let r = roughness_radii(&spec, &mean, &[], SEED, 3).unwrap();
    for (r, m) in r.iter().zip(&mean) {
        let x = r / m;
        assert!((x - 1.4).abs() < 1e-14 || (x - 0.6).abs() < 1e-14, "{x}");
    }
}

/// Per-member lag products of a unit-variance, zero-mean field at lag k, averaged over i.
fn lag_products(g: &[f64], k: usize) -> f64 {
    let n = g.len() - k;
    (0..n).map(|i| g[i] * g[i + k]).sum::<f64>() / n as f64
}

#[test]
fn correlated_field_has_exponential_covariance() {
    let length = 0.05;
    let q = positions_uniform(N); // h = 0.005: lags 5, 10, 20 are l/2, l, 2l
    let h = 1.0 / N as f64;
    let fields: Vec<Vec<f64>> = (0..MEMBERS)
        .map(|m| correlated_field(&q, length, SEED, m).unwrap())
        .collect();
    // Marginals: mean 0, variance 1.
    let means: Vec<f64> = fields
        .iter()
        .map(|g| g.iter().sum::<f64>() / g.len() as f64)
        .collect();
    let (m, se) = mean_se(&means);
    assert_within("correlated g mean", m, se, 0.0);
    let (v, se) = mean_se(
        &fields
            .iter()
            .map(|g| lag_products(g, 0))
            .collect::<Vec<_>>(),
    );
    assert_within("correlated g variance", v, se, 1.0);
    for (label, k) in [("l/2", 5usize), ("l", 10), ("2l", 20)] {
        let (c, se) = mean_se(
            &fields
                .iter()
                .map(|g| lag_products(g, k))
                .collect::<Vec<_>>(),
        );
        let expected = (-(k as f64 * h) / length).exp();
        assert_within(&format!("correlated g lag {label}"), c, se, expected);
    }

    // The radii are the lognormal map of exactly this field: log(r/mean) = sigma g - sigma^2/2.
    let spread = 0.7;
    let spec = RoughnessSpec::new(RoughnessKind::Correlated { length }, spread);
    let mean = mean_profile(N);
    let sigma2 = (1.0f64 + spread * spread).ln();
    for m in [0u64, 1, 999] {
        let r = roughness_radii(&spec, &mean, &q, SEED, m).unwrap();
        for i in 0..=N {
            let lhs = (r[i] / mean[i]).ln();
            let rhs = sigma2.sqrt() * fields[m as usize][i] - 0.5 * sigma2;
            assert!(
                (lhs - rhs).abs() < 1e-12,
                "member {m} particle {i}: {lhs} vs {rhs}"
            );
        }
    }
}

#[test]
fn correlated_field_on_nonuniform_grid() {
    // Positions clustered near x = 0: q_i = (i/N)^2. Pairs (i, j) at chosen separations.
    let q: Vec<f64> = (0..=N).map(|i| (i as f64 / N as f64).powi(2)).collect();
    let length = 0.1;
    let members = 4000u64;
    let fields: Vec<Vec<f64>> = (0..members)
        .map(|m| correlated_field(&q, length, SEED ^ 1, m).unwrap())
        .collect();
    for (i, j) in [(10usize, 60usize), (100, 120), (150, 170), (0, 200)] {
        let products: Vec<f64> = fields.iter().map(|g| g[i] * g[j]).collect();
        let (c, se) = mean_se(&products);
        let expected = (-(q[j] - q[i]) / length).exp();
        assert_within(
            &format!("nonuniform corr(g_{i}, g_{j}), dq = {:.4}", q[j] - q[i]),
            c,
            se,
            expected,
        );
    }
}

#[test]
fn radii_positive_at_spread_two() {
    let mean = mean_profile(N);
    let q = positions_uniform(N);
    for kind in [
        RoughnessKind::LogNormal,
        RoughnessKind::Correlated { length: 0.02 },
    ] {
        let spec = RoughnessSpec::new(kind.clone(), 2.0);
        let sampler = RoughnessSampler::new(&spec, &mean, &q, SEED).unwrap();
        let mut min = f64::INFINITY;
        for m in 0..MEMBERS {
            for r in sampler.sample(m) {
                assert!(r > 0.0 && r.is_finite(), "{kind:?}: r = {r}");
                min = min.min(r);
            }
        }
        eprintln!("{kind:?} spread 2.0: min r = {min:e}");
    }
}

#[test]
fn clear_errors_for_out_of_range_spreads() {
    let mean = mean_profile(N);
    let q = positions_uniform(N);
    let message = |spec: RoughnessSpec| -> String {
        let e = roughness_radii(&spec, &mean, &q, SEED, 0).unwrap_err();
        assert!(matches!(e, EnsembleError::InvalidParameter { .. }), "{e:?}");
        e.to_string()
    };
    let m = message(RoughnessSpec::new(RoughnessKind::Uniform, 0.7));
    eprintln!("uniform 0.7: {m}");
    assert!(m.contains("roughness.spread = 0.7"), "{m}");
    assert!(m.contains("0 <= spread <= 1/sqrt(3) ≈ 0.577"), "{m}");

    let m = message(RoughnessSpec::new(RoughnessKind::TwoPoint, 1.5));
    eprintln!("twopoint 1.5: {m}");
    assert!(m.contains("roughness.spread = 1.5"), "{m}");
    assert!(m.contains("0 <= spread <= 1)"), "{m}");

    let m = message(RoughnessSpec::new(RoughnessKind::LogNormal, -0.1));
    assert!(m.contains("roughness.spread = -0.1"), "{m}");
    let m = message(RoughnessSpec::new(
        RoughnessKind::Correlated { length: 0.0 },
        0.3,
    ));
    assert!(
        m.contains("roughness.length = 0") && m.contains("0 < length"),
        "{m}"
    );
    let m = message(RoughnessSpec::new(RoughnessKind::Constant, 0.3));
    assert!(m.contains("spread = 0"), "{m}");

    // Boundary values are accepted.
    roughness_radii(
        &RoughnessSpec::new(RoughnessKind::Uniform, UNIFORM_MAX_SPREAD),
        &mean,
        &q,
        SEED,
        0,
    )
    .unwrap();
    roughness_radii(
        &RoughnessSpec::new(RoughnessKind::TwoPoint, 1.0),
        &mean,
        &q,
        SEED,
        0,
    )
    .unwrap();

    // Mismatched positions for the correlated field; negative mean radius.
    let e = roughness_radii(
        &RoughnessSpec::new(RoughnessKind::Correlated { length: 0.1 }, 0.3),
        &mean,
        &q[..N],
        SEED,
        0,
    )
    .unwrap_err();
    assert!(
        e.to_string()
            .contains("positions has length 200, expected 201"),
        "{e}"
    );
    let mut bad = mean.clone();
    bad[3] = -1.0;
    let e = roughness_radii(
        &RoughnessSpec::new(RoughnessKind::LogNormal, 0.3),
        &bad,
        &q,
        SEED,
        0,
    )
    .unwrap_err();
    assert!(e.to_string().contains("mean_radii[3] = -1"), "{e}");
}

fn all_random_specs() -> Vec<RoughnessSpec> {
    vec![
        RoughnessSpec::new(RoughnessKind::Uniform, 0.5),
        RoughnessSpec::new(RoughnessKind::LogNormal, 0.3),
        RoughnessSpec::new(RoughnessKind::TwoPoint, 0.4),
        RoughnessSpec::new(RoughnessKind::Correlated { length: 0.05 }, 0.3),
    ]
}

#[test]
fn members_are_reproducible_in_any_order() {
    let mean = mean_profile(N);
    let q = positions_uniform(N);
    let m_count = 64u64;
    for spec in all_random_specs() {
        let sampler = RoughnessSampler::new(&spec, &mean, &q, SEED).unwrap();
        let forward: Vec<Vec<f64>> = (0..m_count).map(|m| sampler.sample(m)).collect();
        let mut reverse: Vec<Vec<f64>> = (0..m_count).rev().map(|m| sampler.sample(m)).collect();
        reverse.reverse();
        assert_eq!(forward, reverse, "{spec:?}");
        // A scrambled order (multiplication by an odd constant mod 64 is a permutation).
        for k in 0..m_count {
            let m = (k * 37 + 11) % m_count;
            assert_eq!(
                sampler.sample(m),
                forward[m as usize],
                "{spec:?} member {m}"
            );
        }
        // Alone, through the one-shot function and a fresh sampler.
        for m in [0u64, 13, 63] {
            let alone = roughness_radii(&spec, &mean, &q, SEED, m).unwrap();
            assert_eq!(alone, forward[m as usize], "{spec:?} member {m}");
        }
        // Members differ from one another, seeds differ.
        for m in 1..m_count as usize {
            assert_ne!(forward[m], forward[m - 1], "{spec:?} member {m}");
        }
        let other_seed = roughness_radii(&spec, &mean, &q, SEED + 1, 5).unwrap();
        assert_ne!(other_seed, forward[5], "{spec:?}");
        // Distant member indices work and differ.
        assert_ne!(sampler.sample(u64::MAX), sampler.sample(u64::MAX - 1));
    }
}

#[test]
fn purposes_are_independent_streams() {
    // Z_0 of the roughness stream recovered from lognormal radii, against Z_0 of the velocity
    // stream: sample correlation over M members, SE = 1/sqrt(M) under independence.
    let members = 4000u64;
    let spread = 0.5;
    let spec = RoughnessSpec::new(RoughnessKind::LogNormal, spread);
    let sigma = (1.0f64 + spread * spread).ln().sqrt();
    let mut a = Vec::new();
    let mut b = Vec::new();
    for m in 0..members {
        let r = roughness_radii(&spec, &[1.0], &[], SEED, m).unwrap();
        a.push((r[0].ln() + 0.5 * sigma * sigma) / sigma);
        b.push(perturbed_velocity(1.0, 0.0, SEED, m).0 - 1.0);
    }
    let corr = a.iter().zip(&b).map(|(x, y)| x * y).sum::<f64>() / members as f64;
    assert_within(
        "corr(roughness Z_0, velocity Z_0)",
        corr,
        1.0 / (members as f64).sqrt(),
        0.0,
    );
    // Purpose keys are distinct: the first word of each purpose's stream differs.
    use rand::RngCore;
    let words: Vec<u64> = [Purpose::Roughness, Purpose::Velocity, Purpose::Jitter]
        .iter()
        .map(|&p| member_rng(SEED, p, 0).next_u64())
        .collect();
    assert!(words[0] != words[1] && words[1] != words[2] && words[0] != words[2]);
}

#[test]
fn velocity_perturbation_statistics() {
    let members = 20000u64;
    let (amp, phase) = (0.1, 0.02);
    let samples: Vec<(f64, f64)> = (0..members)
        .map(|m| perturbed_velocity(amp, phase, SEED, m))
        .collect();
    // Variance SE from the sample fourth moment: SE(s^2) = sqrt((m4 - m2^2)/M).
    let check = |name: &str, xs: Vec<f64>, mean: f64, sd: f64| {
        let (m, se) = mean_se(&xs);
        assert_within(&format!("{name} mean"), m, se, mean);
        let sq: Vec<f64> = xs.iter().map(|x| (x - mean).powi(2)).collect();
        let (v, se) = mean_se(&sq);
        assert_within(&format!("{name} variance"), v, se, sd * sd);
    };
    check(
        "amplitude factor",
        samples.iter().map(|s| s.0).collect(),
        1.0,
        amp,
    );
    check("phase", samples.iter().map(|s| s.1).collect(), 0.0, phase);
    // Reproducible and member-specific.
    assert_eq!(perturbed_velocity(amp, phase, SEED, 17), samples[17]);
    assert_ne!(samples[17], samples[18]);
    assert_ne!(perturbed_velocity(amp, phase, SEED + 1, 17), samples[17]);
    // Zero spreads: no perturbation.
    assert_eq!(perturbed_velocity(0.0, 0.0, SEED, 3), (1.0, 0.0));
}

fn compensated_sum(values: &[f64]) -> f64 {
    // Neumaier, written independently of the module's.
    let mut s = 0.0f64;
    let mut c = 0.0f64;
    for &v in values {
        let t = s + v;
        if s.abs() >= v.abs() {
            c += (s - t) + v;
        } else {
            c += (v - t) + s;
        }
        s = t;
    }
    s + c
}

fn test_gaps() -> (Vec<f64>, Vec<bool>) {
    // N gaps with a varied profile and every 17th gap bonded (zero); sum normalised to 1 - 2 eps N.
    let eps = 0.002;
    let bonded: Vec<bool> = (0..N).map(|i| i % 17 == 5).collect();
    let raw: Vec<f64> = (0..N)
        .map(|i| {
            if bonded[i] {
                0.0
            } else {
                1.0 + 0.8 * (0.37 * i as f64).sin()
            }
        })
        .collect();
    let total = 1.0 - 2.0 * eps * N as f64;
    let s: f64 = raw.iter().sum();
    (raw.iter().map(|d| d * total / s).collect(), bonded)
}

#[test]
fn jitter_keeps_mass_positivity_and_bonds() {
    let (gaps0, bonded) = test_gaps();
    let total0 = compensated_sum(&gaps0);
    let relative = 0.3;
    let sigma2 = (1.0f64 + relative * relative).ln();
    let mut worst = 0.0f64;
    let mut within_var = Vec::new();
    for m in 0..MEMBERS {
        let mut gaps = gaps0.clone();
        jitter_gaps(&mut gaps, Some(&bonded), relative, SEED, m).unwrap();
        let rel = (compensated_sum(&gaps) - total0).abs() / total0;
        worst = worst.max(rel);
        assert!(rel <= 1e-15, "member {m}: sum changed by {rel:e} relative");
        for i in 0..N {
            if bonded[i] {
                assert_eq!(
                    gaps[i].to_bits(),
                    gaps0[i].to_bits(),
                    "bonded gap {i} moved"
                );
            } else {
                assert!(
                    gaps[i] > 0.0 && gaps[i].is_finite(),
                    "gap {i} = {}",
                    gaps[i]
                );
            }
        }
        // Within a member, log(new/old) = sigma Z_i - sigma^2/2 + ln(scale): its sample variance
        // over the free gaps (n - 1 divisor) estimates sigma^2 without bias.
        let logs: Vec<f64> = (0..N)
            .filter(|&i| !bonded[i])
            .map(|i| (gaps[i] / gaps0[i]).ln())
            .collect();
        let n = logs.len() as f64;
        let mu = logs.iter().sum::<f64>() / n;
        within_var.push(logs.iter().map(|l| (l - mu).powi(2)).sum::<f64>() / (n - 1.0));
    }
    eprintln!("jitter: worst relative change of the gap sum {worst:e}");
    let (v, se) = mean_se(&within_var);
    assert_within("jitter log-factor variance", v, se, sigma2);

    // Reproducible; zero jitter is the identity; without a bonded mask all gaps are free.
    let mut a = gaps0.clone();
    let mut b = gaps0.clone();
    jitter_gaps(&mut a, Some(&bonded), relative, SEED, 9).unwrap();
    for m in 0..9 {
        let mut c = gaps0.clone();
        jitter_gaps(&mut c, Some(&bonded), relative, SEED, m).unwrap();
    }
    jitter_gaps(&mut b, Some(&bonded), relative, SEED, 9).unwrap();
    assert_eq!(a, b);
    let mut c = gaps0.clone();
    jitter_gaps(&mut c, Some(&bonded), relative, SEED, 10).unwrap();
    assert_ne!(a, c);
    let mut z = gaps0.clone();
    jitter_gaps(&mut z, Some(&bonded), 0.0, SEED, 9).unwrap();
    assert_eq!(z, gaps0);
    let free: Vec<f64> = gaps0.iter().copied().filter(|&d| d > 0.0).collect();
    let mut f = free.clone();
    jitter_gaps(&mut f, None, 1.5, SEED, 1).unwrap();
    assert!(f.iter().all(|&d| d > 0.0));
    let rel = (compensated_sum(&f) - compensated_sum(&free)).abs() / compensated_sum(&free);
    assert!(rel <= 1e-15, "{rel:e}");
}

#[test]
fn jitter_errors_leave_gaps_unchanged() {
    let (gaps0, bonded) = test_gaps();
    // A zero gap not marked bonded.
    let mut gaps = gaps0.clone();
    let e = jitter_gaps(&mut gaps, None, 0.3, SEED, 0).unwrap_err();
    assert!(e.to_string().contains("gaps[5] = 0"), "{e}");
    assert_eq!(gaps, gaps0);
    let e = jitter_gaps(&mut gaps, Some(&bonded), -0.3, SEED, 0).unwrap_err();
    assert!(e.to_string().contains("jitter.relative = -0.3"), "{e}");
    let e = jitter_gaps(&mut gaps, Some(&bonded[..3]), 0.3, SEED, 0).unwrap_err();
    assert!(matches!(e, EnsembleError::LengthMismatch { .. }), "{e}");
    assert_eq!(gaps, gaps0);
}

#[test]
fn radii_file_reads_and_reports_bad_lines() {
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, text: &str| {
        let p = dir.path().join(name);
        std::fs::File::create(&p)
            .unwrap()
            .write_all(text.as_bytes())
            .unwrap();
        p
    };
    let good = write("good.csv", "r\n# a comment\n0.001\n0.002\n 0.003 \n");
    let spec = RoughnessSpec::new(RoughnessKind::File(good.clone()), 0.0);
    let mean = [0.0; 3];
    for m in [0, 5] {
        assert_eq!(
            roughness_radii(&spec, &mean, &[], SEED, m).unwrap(),
            vec![0.001, 0.002, 0.003]
        );
    }
    // Wrong row count for the chain.
    let e = roughness_radii(&spec, &[0.0; 4], &[], SEED, 0).unwrap_err();
    assert!(
        e.to_string().contains("good.csv") && e.to_string().contains("N+1 = 4"),
        "{e}"
    );

    let bad = write("bad.csv", "r\n0.001\nabc\n0.003\n");
    let e = roughness_radii(
        &RoughnessSpec::new(RoughnessKind::File(bad), 0.0),
        &mean,
        &[],
        SEED,
        0,
    )
    .unwrap_err();
    eprintln!("bad file: {e}");
    assert!(
        matches!(e, EnsembleError::RoughnessFile { line: 3, .. }),
        "{e:?}"
    );
    assert!(e.to_string().contains("bad.csv, line 3"), "{e}");

    let negative = write("neg.csv", "r\n0.001\n0.002\n-0.5\n");
    let e = roughness_radii(
        &RoughnessSpec::new(RoughnessKind::File(negative), 0.0),
        &mean,
        &[],
        SEED,
        0,
    )
    .unwrap_err();
    assert!(
        e.to_string().contains("line 4") && e.to_string().contains(">= 0"),
        "{e}"
    );

    let header = write("hdr.csv", "x\n0.001\n");
    let e = roughness_radii(
        &RoughnessSpec::new(RoughnessKind::File(header), 0.0),
        &[0.0],
        &[],
        SEED,
        0,
    )
    .unwrap_err();
    assert!(e.to_string().contains("line 1"), "{e}");

    let missing = dir.path().join("missing.csv");
    let e = roughness_radii(
        &RoughnessSpec::new(RoughnessKind::File(missing), 0.0),
        &mean,
        &[],
        SEED,
        0,
    )
    .unwrap_err();
    assert!(matches!(e, EnsembleError::Io { .. }) && e.to_string().contains("missing.csv"));
}

#[test]
fn spec_deserialises_from_toml() {
    let parse = |s: &str| toml::from_str::<RoughnessSpec>(s);
    assert_eq!(
        parse("kind = \"lognormal\"\nspread = 0.3").unwrap(),
        RoughnessSpec::new(RoughnessKind::LogNormal, 0.3)
    );
    assert_eq!(
        parse("kind = \"correlated\"\nlength = 0.05\nspread = 2.0").unwrap(),
        RoughnessSpec::new(RoughnessKind::Correlated { length: 0.05 }, 2.0)
    );
    assert_eq!(
        parse("kind = \"two_point\"\nspread = 0.5").unwrap(),
        RoughnessSpec::new(RoughnessKind::TwoPoint, 0.5)
    );
    assert_eq!(
        parse("kind = \"file\"\npath = \"r.csv\"").unwrap(),
        RoughnessSpec::new(RoughnessKind::File("r.csv".into()), 0.0)
    );
    assert_eq!(
        parse("kind = \"constant\"").unwrap(),
        RoughnessSpec::new(RoughnessKind::Constant, 0.0)
    );
    for (text, needle) in [
        ("kind = \"uniform\"\nspread = 0.7", "0.577"),
        ("kind = \"uniform\"", "needs spread"),
        ("kind = \"correlated\"\nspread = 0.3", "needs length"),
        (
            "kind = \"lognormal\"\nspread = 0.3\nlength = 1.0",
            "only kind = \"correlated\"",
        ),
        ("kind = \"gaussian\"\nspread = 0.3", "gaussian"),
        ("kind = \"lognormal\"\nsprad = 0.3", "sprad"),
        // 1e300 ran, with every d* ~1e-276: no roughness left (2026-11-30).
        ("kind = \"lognormal\"\nspread = 1e300", "0 <= spread <= 10"),
        (
            "kind = \"correlated\"\nlength = 0.05\nspread = 10.5",
            "0 <= spread <= 10",
        ),
    ] {
        let e = parse(text).unwrap_err().to_string();
        assert!(e.contains(needle), "{text}: {e}");
    }
}

#[test]
fn dstar_and_mean_radii_profiles() {
    let r = [1.0, 2.0, 4.0, 8.0];
    assert_eq!(dstar_from_radii(&r), vec![3.0, 6.0, 12.0]);
    assert!(dstar_from_radii(&[1.0]).is_empty());

    // Constant profile: exact.
    let d = vec![0.004; 50];
    let r = mean_radii_from_rho_star(&d);
    assert_eq!(r.len(), 51);
    for (a, b) in dstar_from_radii(&r).iter().zip(&d) {
        assert!((a - b).abs() <= 1e-18, "{a} vs {b}");
    }
    // Smooth profile: interior gaps off by (d_{i-1} - 2 d_i + d_{i+1})/4 = O(h^2).
    for n in [100usize, 200] {
        let h = 1.0 / n as f64;
        let d: Vec<f64> = (0..n)
            .map(|i| 0.004 * (1.0 + 0.5 * (2.0 * PI * (i as f64 + 0.5) * h).sin()))
            .collect();
        let back = dstar_from_radii(&mean_radii_from_rho_star(&d));
        let interior = (1..n - 1)
            .map(|i| (back[i] - d[i]).abs() / d[i])
            .fold(0.0, f64::max);
        // |d''| h^2 / 4 / d_min with |d''| <= 0.002 (2 pi)^2, d_min = 0.002.
        let bound = 0.002 * (2.0 * PI).powi(2) * h * h / 4.0 / 0.002;
        eprintln!(
            "mean radii n = {n}: worst interior relative error {interior:e} (bound {bound:e})"
        );
        assert!(interior <= bound * 1.0001, "{interior} > {bound}");
        let expected_end = d[0] + (d[1] - d[0]) / 4.0;
        assert!((back[0] - expected_end).abs() < 1e-18);
    }
    assert!(mean_radii_from_rho_star(&[]).is_empty());
}

#[test]
fn radii_file_refuses_radii_as_large_as_the_domain() {
    let dir = tempfile::tempdir().unwrap();
    for (text, line, shown) in [
        ("r\n0.001\n1e300\n0.003\n", 3, "r = 1e300"),
        ("r\n0.001\n0.002\n# the domain is [0, 1]\n1.0\n", 5, "r = 1"),
    ] {
        let path = dir.path().join("big.csv");
        std::fs::write(&path, text).unwrap();
        let e = roughness_radii(
            &RoughnessSpec::new(RoughnessKind::File(path), 0.0),
            &[0.001; 3],
            &[],
            SEED,
            0,
        )
        .unwrap_err();
        assert!(
            matches!(e, EnsembleError::RoughnessFile { line: l, .. } if l == line),
            "{e:?}"
        );
        assert_eq!(
            e.to_string(),
            format!(
                "roughness file {}, line {line}: column r: roughness radius {shown} is not smaller than the domain [0, 1] (allowed: 0 <= r < 1)",
                dir.path().join("big.csv").display()
            )
        );
    }
    // Just below the domain's length is accepted.
    let path = dir.path().join("ok.csv");
    std::fs::write(&path, "r\n0.001\n0.999\n0.003\n").unwrap();
    let radii = roughness_radii(
        &RoughnessSpec::new(RoughnessKind::File(path), 0.0),
        &[0.001; 3],
        &[],
        SEED,
        0,
    )
    .unwrap();
    assert_eq!(radii, vec![0.001, 0.999, 0.003]);
}

/// File roughness gives every radius itself: a scene without rho_star and without
/// ensemble.mean_radius is accepted with it (issue 9, item 10), and still refused with random
/// roughness (which needs a mean profile to draw around).
#[test]
fn file_roughness_needs_no_mean_profile() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("radii.csv"), "r\n0.001\n0.002\n0.003\n").unwrap();
    let scene = |roughness: &str| {
        format!(
            "name = \"fr\"\n[model]\nparticles = 2\nmu = 0.01\ngamma = 2.0\n[initial]\nrho = \"0.7\"\nvelocity = \"0\"\n[time]\nend = 0.01\noutputs = 2\ndt = 1e-3\n[ensemble]\nmembers = 2\nroughness = {roughness}\n"
        )
    };
    let path = dir.path().join("scene.toml");
    let file = roughlub::scene::Scene::from_toml(
        &scene("{ kind = \"file\", path = \"radii.csv\" }"),
        &path,
    );
    assert!(file.is_ok(), "{:?}", file.err());
    let random =
        roughlub::scene::Scene::from_toml(&scene("{ kind = \"uniform\", spread = 0.1 }"), &path)
            .unwrap_err();
    assert!(
        random
            .to_string()
            .contains("random roughness needs a mean profile"),
        "{random}"
    );
}
