use super::*;

fn names(n: &[&str]) -> Vec<String> {
    n.iter().map(|s| s.to_string()).collect()
}

fn range(min: f64, max: f64, scale: Scale) -> Axis {
    Axis::Range { min, max, scale }
}

fn sampled(kind: DesignKind, d: usize, points: u64, seed: u64) -> Design {
    let keys: Vec<String> = (0..d).map(|i| format!("p{i}")).collect();
    let axes = vec![range(0.0, 1.0, Scale::Linear); d];
    Design::new("sweep", kind, keys, axes, Some(points), seed).unwrap()
}

fn err(kind: DesignKind, keys: &[&str], axes: Vec<Axis>, points: Option<u64>) -> String {
    Design::new("sweep", kind, names(keys), axes, points, 1)
        .unwrap_err()
        .to_string()
}

#[test]
fn grid_order_and_len() {
    let g = Design::new(
        "sweep",
        DesignKind::Grid,
        names(&["mu", "gamma"]),
        vec![
            Axis::Values(vec![1.0, 2.0, 3.0]),
            Axis::Values(vec![10.0, 20.0]),
        ],
        None,
        0,
    )
    .unwrap();
    assert_eq!(g.len(), 6);
    assert_eq!(g.dim(), 2);
    let all: Vec<Vec<f64>> = (0..6).map(|p| g.values(p)).collect();
    let expected = [
        [1.0, 10.0],
        [1.0, 20.0],
        [2.0, 10.0],
        [2.0, 20.0],
        [3.0, 10.0],
        [3.0, 20.0],
    ];
    for (got, want) in all.iter().zip(expected) {
        assert_eq!(got.as_slice(), want.as_slice());
    }
    assert_eq!(g.grid_indices(3), Some(vec![1, 1]));
    assert_eq!(g.unit(5), vec![2.0 / 3.0, 0.5]);

    let g = Design::new(
        "sweep",
        DesignKind::Grid,
        names(&["a", "b", "c"]),
        vec![
            Axis::Values(vec![0.5, -0.5]),
            Axis::Values(vec![7.0]),
            Axis::Values(vec![1e-3, 1e-2, 1e-1]),
        ],
        Some(6),
        0,
    )
    .unwrap();
    assert_eq!(g.len(), 6);
    let expected = [
        [0.5, 7.0, 1e-3],
        [0.5, 7.0, 1e-2],
        [0.5, 7.0, 1e-1],
        [-0.5, 7.0, 1e-3],
        [-0.5, 7.0, 1e-2],
        [-0.5, 7.0, 1e-1],
    ];
    for (p, want) in expected.iter().enumerate() {
        assert_eq!(g.values(p as u64).as_slice(), want.as_slice(), "point {p}");
    }
    assert_eq!(g.grid_indices(4), Some(vec![1, 0, 1]));
    // 2 × 3 × 4 × 5 = 120 points; point 119 is the last value of every list.
    let g = Design::new(
        "s",
        DesignKind::Grid,
        names(&["a", "b", "c", "d"]),
        (2..6)
            .map(|n| Axis::Values((0..n).map(f64::from).collect()))
            .collect(),
        None,
        0,
    )
    .unwrap();
    assert_eq!(g.len(), 120);
    assert_eq!(g.values(119), vec![1.0, 2.0, 3.0, 4.0]);
    // p = ((a·3 + b)·4 + c)·5 + d.
    assert_eq!(
        g.values(((3 + 2) * 4 + 1) * 5 + 3),
        vec![1.0, 2.0, 1.0, 3.0]
    );
    assert_eq!(sampled(DesignKind::Random, 1, 3, 0).grid_indices(0), None);
}

/// Strata index of u in dimension d: floor(u P).
fn stratum(u: f64, p: u64) -> u64 {
    let k = (u * p as f64).floor();
    assert!(k >= 0.0 && k < p as f64, "u = {u} outside [0, 1)");
    k as u64
}

#[test]
fn latin_hypercube_strata_hold_one_point_each() {
    for p in [1u64, 7, 64] {
        for seed in [0u64, 1, 12345] {
            let axes = vec![
                range(0.0, 1.0, Scale::Linear),
                range(-3.0, 5.0, Scale::Linear),
                range(1e-3, 1e3, Scale::Log),
            ];
            let design = Design::new(
                "sweep",
                DesignKind::LatinHypercube,
                names(&["a", "b", "c"]),
                axes,
                Some(p),
                seed,
            )
            .unwrap();
            assert_eq!(design.len(), p);
            let units: Vec<Vec<f64>> = (0..p).map(|i| design.unit(i)).collect();
            for d in 0..3 {
                let mut seen = vec![0u32; p as usize];
                for u in &units {
                    seen[stratum(u[d], p) as usize] += 1;
                }
                assert!(
                    seen.iter().all(|&c| c == 1),
                    "P = {p}, seed {seed}, dim {d}: strata counts {seen:?}"
                );
            }
            // The values are the mapped unit points.
            for (i, u) in units.iter().enumerate() {
                let v = design.values(i as u64);
                assert!((v[0] - u[0]).abs() <= 1e-15);
                assert!((v[1] - (-3.0 + 8.0 * u[1])).abs() <= 1e-14);
                let c = 10f64.powf(-3.0 + 6.0 * u[2]);
                assert!((v[2] / c - 1.0).abs() <= 1e-13, "{} vs {c}", v[2]);
            }
        }
    }
}

/// Rows 1..=k (output digits, most significant first) of the generator matrix of Sobol
/// dimension `dim` < 4, each row a bit mask over the index bits (bit j-1 for index bit j,
/// least significant first), built from the Joe–Kuo direction numbers (new-joe-kuo-6:
/// d = 2: s = 1, a = 0, m = 1; d = 3: s = 2, a = 1, m = 1 3; d = 4: s = 3, a = 1, m = 1 3 1),
/// dimension 0 being van der Corput's.
fn sobol_generator_rows(dim: usize, k: usize) -> Vec<u32> {
    let mut m: Vec<u32> = match dim {
        0 => vec![1; k],
        1 => vec![1],
        2 => vec![1, 3],
        3 => vec![1, 3, 1],
        _ => unreachable!(),
    };
    let (s, a) = [(1, 0), (1, 0), (2, 1), (3, 1)][dim];
    while m.len() < k {
        let i = m.len();
        let mut next = m[i - s] ^ (m[i - s] << s);
        for l in 1..s {
            next ^= ((a >> (s - 1 - l)) & 1) * (m[i - l] << l);
        }
        m.push(next);
    }
    // V_j = m_j / 2^j: output digit r of column j is bit (j - r) of m_j.
    (1..=k)
        .map(|r| {
            (r..=k)
                .filter(|&j| (m[j - 1] >> (j - r)) & 1 == 1)
                .fold(0u32, |row, j| row | 1 << (j - 1))
        })
        .collect()
}

/// Rank over GF(2) of bit-mask rows.
fn gf2_rank(mut rows: Vec<u32>) -> usize {
    let mut rank = 0;
    for bit in 0..32 {
        if let Some(i) = (rank..rows.len()).find(|&i| rows[i] >> bit & 1 == 1) {
            rows.swap(rank, i);
            let pivot = rows[rank];
            for row in rows.iter_mut().skip(rank + 1) {
                if *row >> bit & 1 == 1 {
                    *row ^= pivot;
                }
            }
            rank += 1;
        }
    }
    rank
}

/// The quality parameter t of the first 2^k points of the digital net of two generator
/// matrices: the least t such that for every a + b = k - t the first a rows of one and the
/// first b rows of the other are linearly independent.
fn theoretical_t(c1: &[u32], c2: &[u32], k: usize) -> u32 {
    (0..=k)
        .find(|&t| {
            (0..=k - t).all(|a| {
                let rows: Vec<u32> = c1[..a].iter().chain(&c2[..k - t - a]).copied().collect();
                gf2_rank(rows) == k - t
            })
        })
        .unwrap() as u32
}

/// The least t for which every elementary interval of volume 2^(t-k) of the points'
/// projection on (i, j) holds exactly 2^t points.
fn measured_t(units: &[Vec<f64>], i: usize, j: usize, k: u32) -> u32 {
    (0..=k)
        .find(|&t| {
            let m = k - t;
            (0..=m).all(|a| {
                let (nx, ny) = (1u64 << a, 1u64 << (m - a));
                let mut seen = vec![0u32; 1 << m];
                for u in units {
                    seen[(stratum(u[i], nx) * ny + stratum(u[j], ny)) as usize] += 1;
                }
                seen.iter().all(|&c| c == 1 << t)
            })
        })
        .unwrap()
}

#[test]
fn sobol_projections_are_nets() {
    // The first 2^k points (k = 1..8) of the first 4 dimensions: each 1-D projection is
    // stratified (one point in each interval of length 2^-k), the projection on dimensions
    // (0, 1) is a (0, k, 2)-net (one point in every elementary interval 2^-a × 2^-(k-a)),
    // and every other 2-D projection is a (t, k, 2)-net with the t of the unscrambled
    // Joe–Kuo generator matrices (scrambling preserves t; only dimensions 0 and 1 form a
    // (0, 2)-sequence, and t reaches 2 in other pairs).
    let mut worst = 0;
    for seed in [0u64, 7, 99] {
        for k in 1..=8u32 {
            let n = 1u64 << k;
            let design = sampled(DesignKind::Sobol, 4, n, seed);
            let units: Vec<Vec<f64>> = (0..n).map(|i| design.unit(i)).collect();
            for d in 0..4 {
                let mut seen = vec![0u32; n as usize];
                for u in &units {
                    seen[stratum(u[d], n) as usize] += 1;
                }
                assert!(seen.iter().all(|&c| c == 1), "seed {seed}, k {k}, dim {d}");
            }
            for a in 0..=k {
                let (nx, ny) = (1u64 << a, 1u64 << (k - a));
                let mut seen = vec![0u32; n as usize];
                for u in &units {
                    seen[(stratum(u[0], nx) * ny + stratum(u[1], ny)) as usize] += 1;
                }
                assert!(
                    seen.iter().all(|&c| c == 1),
                    "seed {seed}, k {k}, dims (0, 1), intervals 2^-{a} × 2^-{}",
                    k - a
                );
            }
            for i in 0..4 {
                for j in i + 1..4 {
                    let ku = k as usize;
                    let want = theoretical_t(
                        &sobol_generator_rows(i, ku),
                        &sobol_generator_rows(j, ku),
                        ku,
                    );
                    let got = measured_t(&units, i, j, k);
                    assert_eq!(got, want, "seed {seed}, k {k}, dims ({i}, {j})");
                    worst = worst.max(got);
                }
            }
        }
    }
    assert_eq!(worst, 2);
}

#[test]
fn sampled_points_follow_the_documented_streams() {
    // Random: draw d of member_rng(seed, Design, p), mapped linearly.
    let axes = vec![
        range(2.0, 6.0, Scale::Linear),
        range(1.0, 100.0, Scale::Log),
    ];
    let design = Design::new(
        "sweep",
        DesignKind::Random,
        names(&["a", "b"]),
        axes,
        Some(10),
        42,
    )
    .unwrap();
    for p in 0..10 {
        let mut rng = member_rng(42, Purpose::Design, p);
        let (u0, u1) = (rng.random::<f64>(), rng.random::<f64>());
        let v = design.values(p);
        assert!((v[0] - (2.0 + 4.0 * u0)).abs() <= 1e-15 * 6.0);
        assert!((v[1] - 10f64.powf(2.0 * u1)).abs() <= 1e-13 * v[1]);
    }
    // Sobol: sobol_burley::sample with the documented scramble seed.
    let design = sampled(DesignKind::Sobol, 3, 50, 42);
    let k = purpose_seed(42, Purpose::Design);
    let s = (k ^ (k >> 32)) as u32;
    for p in 0..50u32 {
        for d in 0..3u32 {
            let want = f64::from(sobol_burley::sample(p, d, s));
            assert_eq!(design.unit(u64::from(p))[d as usize], want);
            // f32 output: multiples of 2^-24.
            assert_eq!((want * 16_777_216.0).fract(), 0.0);
        }
    }
    assert_eq!(sobol_burley::NUM_DIMENSIONS as usize, SOBOL_MAX_DIMENSIONS);
    // The new purposes' tags are the documented ASCII words, distinct from the others.
    assert_eq!(Purpose::Design.tag().to_le_bytes(), *b"designpt");
    assert_eq!(Purpose::DesignPermutation.tag().to_le_bytes(), *b"designpm");
    let tags = [
        Purpose::Roughness,
        Purpose::Velocity,
        Purpose::Jitter,
        Purpose::Design,
        Purpose::DesignPermutation,
    ]
    .map(Purpose::tag);
    for (i, t) in tags.iter().enumerate() {
        assert!(!tags[..i].contains(t));
    }
    // Latin hypercube permutation of dimension d: Fisher–Yates from its own stream.
    let lhs = sampled(DesignKind::LatinHypercube, 2, 9, 42);
    for d in 0..2 {
        let mut rng = member_rng(42, Purpose::DesignPermutation, d);
        let mut perm: Vec<u32> = (0..9).collect();
        for i in (1..9u32).rev() {
            perm.swap(i as usize, rng.random_range(0..=i) as usize);
        }
        for p in 0..9u64 {
            let mut point = member_rng(42, Purpose::Design, p);
            let v: Vec<f64> = (0..2).map(|_| point.random::<f64>()).collect();
            let want = (f64::from(perm[p as usize]) + v[d as usize]) / 9.0;
            assert!(
                (lhs.unit(p)[d as usize] - want).abs() <= 1e-15,
                "dim {d}, point {p}"
            );
        }
    }
    // A Sobol design of P points is the start of a longer one.
    let long = sampled(DesignKind::Sobol, 3, 500, 42);
    for p in 0..50 {
        assert_eq!(long.values(p), design.values(p));
    }
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn points_are_reproducible_and_depend_on_the_seed() {
    for kind in [
        DesignKind::Random,
        DesignKind::LatinHypercube,
        DesignKind::Sobol,
    ] {
        let n = 200;
        let make = |seed| {
            Design::new(
                "sweep",
                kind,
                names(&["x", "y", "z"]),
                vec![
                    range(0.0, 1.0, Scale::Linear),
                    range(-1e3, 1e3, Scale::Linear),
                    range(1e-6, 1.0, Scale::Log),
                ],
                Some(n),
                seed,
            )
            .unwrap()
        };
        let design = make(5);
        let forward: Vec<Vec<u64>> = (0..n).map(|p| bits(&design.values(p))).collect();
        // Reverse order, from a fresh design, after unrelated calls on other designs.
        let other = make(6);
        let again = make(5);
        let mut backward = vec![Vec::new(); n as usize];
        for p in (0..n).rev() {
            let _ = other.values((p * 7) % n);
            let _ = design.unit(p);
            backward[p as usize] = bits(&again.values(p));
        }
        assert_eq!(forward, backward, "{kind:?}");
        // One at a time, interleaved with the same design's other points.
        for p in [17, 0, 199, 17, 3] {
            let _ = design.values((p + 1) % n);
            assert_eq!(bits(&design.values(p)), forward[p as usize], "{kind:?}");
        }
        // A different seed moves (nearly) every point.
        let moved = (0..n)
            .filter(|&p| bits(&other.values(p)) != forward[p as usize])
            .count();
        assert_eq!(moved, n as usize, "{kind:?}");
        // The seed changes a sampled design's unit points in every coordinate of most points.
        let differing = (0..n)
            .filter(|&p| {
                let (a, b) = (design.unit(p), other.unit(p));
                a.iter().zip(&b).all(|(x, y)| x != y)
            })
            .count();
        assert!(differing >= 190, "{kind:?}: {differing}");
    }
}

#[test]
fn log_scale_values_are_log_uniform() {
    let (min, max): (f64, f64) = (1e-3, 1e2);
    let (lmin, lmax) = (min.ln(), max.ln());
    for (kind, n) in [
        (DesignKind::Random, 100_000u64),
        (DesignKind::LatinHypercube, 20_000),
        (DesignKind::Sobol, 1 << 14),
    ] {
        let design = Design::new(
            "sweep",
            kind,
            names(&["mu", "lin"]),
            vec![range(min, max, Scale::Log), range(-2.0, 4.0, Scale::Linear)],
            Some(n),
            2024,
        )
        .unwrap();
        let (mut sum_log, mut sum_lin) = (0.0, 0.0);
        let mut below_decade = 0u64;
        for p in 0..n {
            let v = design.values(p);
            assert!(v[0] >= min && v[0] < max, "{kind:?}: {} outside", v[0]);
            assert!(v[1] >= -2.0 && v[1] < 4.0, "{kind:?}: {} outside", v[1]);
            sum_log += v[0].ln();
            sum_lin += v[1];
            below_decade += u64::from(v[0] < 1e-2);
        }
        // ln v is uniform on [ln min, ln max): standard deviation (ln max - ln min)/sqrt(12);
        // 5 standard errors of an iid mean (the stratified designs do far better).
        let nf = n as f64;
        let mean_log = sum_log / nf;
        let tol = 5.0 * (lmax - lmin) / (12.0 * nf).sqrt();
        assert!(
            (mean_log - 0.5 * (lmin + lmax)).abs() < tol,
            "{kind:?}: mean log {mean_log}, expected {} ± {tol}",
            0.5 * (lmin + lmax)
        );
        let mean_lin = sum_lin / nf;
        assert!((mean_lin - 1.0).abs() < 5.0 * 6.0 / (12.0 * nf).sqrt());
        // One decade of five: a fifth of the points, binomial tolerance.
        let frac = below_decade as f64 / nf;
        assert!(
            (frac - 0.2).abs() < 5.0 * (0.16 / nf).sqrt(),
            "{kind:?}: {frac}"
        );
    }
}

#[test]
fn mapping_stays_below_max() {
    let one_below = 1.0 - f64::EPSILON / 2.0;
    for axis in [
        range(0.1, 0.3, Scale::Linear),
        range(-1.0, 1e-300, Scale::Linear),
        range(1e-3, 7.0, Scale::Log),
        range(1.0, 1.0 + 1e-15, Scale::Log),
    ] {
        let Axis::Range { min, max, .. } = axis else {
            unreachable!()
        };
        let hi = map_unit(&axis, one_below);
        assert!(hi < max && hi >= min, "{axis:?}: {hi}");
        assert_eq!(map_unit(&axis, 0.0), min, "{axis:?}");
    }
    for (k, n) in [(0u32, 1u64), (2, 3), (6, 7), (999_999, 1_000_000)] {
        let u = latin_unit(k, one_below, n);
        assert_eq!((u * n as f64).floor(), f64::from(k));
        assert!(u < 1.0);
    }
}

#[test]
fn validation_errors_name_the_key() {
    use DesignKind::*;
    let lin = |a, b| range(a, b, Scale::Linear);
    assert_eq!(
        err(Random, &["mu"], vec![lin(0.1, 0.01)], Some(4)),
        "sweep.mu: min = 0.1 >= max = 0.01 (allowed: min < max)"
    );
    assert_eq!(
        err(Sobol, &["mu"], vec![range(0.0, 1.0, Scale::Log)], Some(4)),
        "sweep.mu.min = 0: a log-scale range must be positive (allowed: min > 0 on a log scale)"
    );
    assert_eq!(
        err(LatinHypercube, &["a"], vec![lin(f64::NAN, 1.0)], Some(4)),
        "sweep.a.min = NaN: not finite (allowed: a finite number)"
    );
    assert_eq!(
        err(Random, &["a"], vec![lin(0.0, f64::INFINITY)], Some(4)),
        "sweep.a.max = inf: not finite (allowed: a finite number)"
    );
    assert_eq!(
        err(Random, &["a"], vec![lin(-1.7e308, 1.7e308)], Some(4)),
        "sweep.a: max - min = inf overflows (allowed: a finite span max - min)"
    );
    assert_eq!(
        err(Grid, &["gamma"], vec![Axis::Values(vec![])], None),
        "sweep.gamma: the list of values is empty (allowed: at least one finite value)"
    );
    assert_eq!(
        err(
            Grid,
            &["gamma"],
            vec![Axis::Values(vec![1.0, f64::INFINITY])],
            None
        ),
        "sweep.gamma[1] = inf: not finite (allowed: finite values)"
    );
    assert_eq!(
        err(Grid, &["gamma"], vec![lin(0.0, 1.0)], None),
        "sweep.gamma: a grid design needs a list of values, not a range \
         (allowed: a list of finite values)"
    );
    assert_eq!(
        err(Sobol, &["gamma"], vec![Axis::Values(vec![1.0])], Some(2)),
        "sweep.gamma: a sobol design needs a range (min, max, scale), not a list of values \
         (allowed: a range with min < max)"
    );
    assert_eq!(
        err(Grid, &["a", "a"], vec![Axis::Values(vec![1.0]); 2], None),
        "sweep.a: given twice (allowed: each parameter once)"
    );
    assert_eq!(
        err(Grid, &["a", " "], vec![Axis::Values(vec![1.0]); 2], None),
        "sweep: parameter 1 has an empty name (allowed: a non-empty key)"
    );
    assert_eq!(
        err(Grid, &[], vec![], None),
        "sweep: no parameters to sweep (allowed: at least one parameter)"
    );
    assert!(err(Grid, &["a"], vec![], None).contains("sweep names has length 1, expected 0"));
    assert_eq!(
        err(Grid, &["a"], vec![Axis::Values(vec![1.0, 2.0])], Some(3)),
        "sweep.points: 3 given but the grid of the value lists has 2 points \
         (allowed: leave it out, or 2)"
    );
    assert_eq!(
        err(Random, &["a"], vec![lin(0.0, 1.0)], None),
        "sweep.points: missing: a random design needs the number of points \
         (allowed: an integer >= 1)"
    );
    assert_eq!(
        err(LatinHypercube, &["a"], vec![lin(0.0, 1.0)], Some(0)),
        "sweep.points: 0 points (allowed: an integer >= 1)"
    );
    assert_eq!(
        err(Sobol, &["a"], vec![lin(0.0, 1.0)], Some(65_537)),
        "sweep.points: 65537 points, more than a sobol design supports \
         (allowed: 1 to 65536 = 2^16)"
    );
    let keys: Vec<String> = (0..257).map(|i| format!("p{i}")).collect();
    let keys: Vec<&str> = keys.iter().map(String::as_str).collect();
    assert_eq!(
        err(Sobol, &keys, vec![lin(0.0, 1.0); 257], Some(2)),
        "sweep: 257 parameters, more than a sobol design supports (allowed: at most 256)"
    );
    assert!(err(
        LatinHypercube,
        &["a", "b"],
        vec![lin(0.0, 1.0); 2],
        Some(1 << 26)
    )
    .starts_with("sweep.points: 67108864 points × 2 parameters, more than"));
    let big = Axis::Values(vec![0.0; 1 << 16]);
    assert!(err(Grid, &["a", "b", "c", "d"], vec![big; 4], None)
        .starts_with("sweep: the grid has more than 2^64 points"));
    // The limits themselves are accepted.
    assert_eq!(sampled(Sobol, 256, 1 << 16, 0).len(), 1 << 16);
    assert_eq!(sampled(LatinHypercube, 1, 1_000_000, 0).len(), 1_000_000);
}

#[test]
#[should_panic(expected = "design point 3 out of range")]
fn values_out_of_range_panics() {
    sampled(DesignKind::Random, 2, 3, 0).values(3);
}
