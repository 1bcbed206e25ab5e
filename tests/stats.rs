//! Tests of `roughlub::stats` against independent expectations: compensated two-pass moments,
//! sorted data for quantiles, direct counting for histograms and field bands. Each assertion
//! states its tolerance.
//! Run with `--nocapture` to see the measured errors.

use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, LogNormal, Normal, Uniform};
use roughlub::stats::{
    Bins, FieldBand, Histogram, QuantileSketch, RunningStats, ScalarSummary, StatsError,
};

const N: usize = 100_000;
const QS: [f64; 9] = [0.0, 0.01, 0.05, 0.25, 0.5, 0.75, 0.95, 0.99, 1.0];

fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// Neumaier (improved Kahan) summation: error ~ eps |sum| + n eps^2 sum |x|.
fn neumaier(xs: impl IntoIterator<Item = f64>) -> f64 {
    let (mut s, mut c) = (0.0f64, 0.0f64);
    for x in xs {
        let t = s + x;
        if s.abs() >= x.abs() {
            c += (s - t) + x;
        } else {
            c += (x - t) + s;
        }
        s = t;
    }
    s + c
}

/// Reference mean and sum of squared deviations: compensated two-pass, with the first-order
/// correction for the rounding of the mean (sum (x - m)^2 - (sum (x - m))^2 / n).
fn reference_moments(xs: &[f64]) -> (f64, f64) {
    let n = xs.len() as f64;
    let m = neumaier(xs.iter().copied()) / n;
    let s2 = neumaier(xs.iter().map(|x| (x - m) * (x - m)));
    let s1 = neumaier(xs.iter().map(|x| x - m));
    (m + s1 / n, s2 - s1 * s1 / n)
}

fn rel(a: f64, b: f64) -> f64 {
    if a == b {
        0.0
    } else {
        (a - b).abs() / b.abs()
    }
}

/// Named data sets of N values used by the moment tests.
fn moment_datasets() -> Vec<(&'static str, Vec<f64>)> {
    let mut r = rng(1);
    let ln1 = LogNormal::new(0.0, 1.0).unwrap();
    let ln2 = LogNormal::new(3.0, 0.5).unwrap();
    let lognormal_mix: Vec<f64> = (0..N)
        .map(|_| {
            if r.random_bool(0.5) {
                ln1.sample(&mut r)
            } else {
                ln2.sample(&mut r)
            }
        })
        .collect();
    let n1 = Normal::new(-2.0, 1.0).unwrap();
    let n2 = Normal::new(5.0, 0.1).unwrap();
    let normal_mix: Vec<f64> = (0..N)
        .map(|_| {
            if r.random_bool(0.3) {
                n1.sample(&mut r)
            } else {
                n2.sample(&mut r)
            }
        })
        .collect();
    let big = Normal::new(1e8, 1.0).unwrap();
    let offset_1e8: Vec<f64> = (0..N).map(|_| big.sample(&mut r)).collect();
    let tiny = Normal::new(1e8, 1e-3).unwrap();
    let offset_1e8_tiny: Vec<f64> = (0..N).map(|_| tiny.sample(&mut r)).collect();
    vec![
        ("lognormal mixture", lognormal_mix),
        ("normal mixture", normal_mix),
        ("1e8 + N(0,1)", offset_1e8),
        ("1e8 + N(0,1e-3)", offset_1e8_tiny),
    ]
}

fn stats_of(xs: &[f64]) -> RunningStats {
    let mut s = RunningStats::new();
    for &x in xs {
        assert!(s.push(x));
    }
    s
}

// ------------------------------------------------------------------------------------------------
// RunningStats

#[test]
fn running_stats_match_compensated_two_pass() {
    for (name, xs) in moment_datasets() {
        let (m_ref, m2_ref) = reference_moments(&xs);
        let var_ref = m2_ref / (xs.len() - 1) as f64;
        let s = stats_of(&xs);
        let (em, ev) = (rel(s.mean(), m_ref), rel(s.variance(), var_ref));
        eprintln!("{name:>18}: mean rel err {em:.2e}, variance rel err {ev:.2e}");
        // Tolerance 1e-12 relative for both.
        assert!(em <= 1e-12, "{name}: mean {} vs {m_ref}", s.mean());
        assert!(
            ev <= 1e-12,
            "{name}: variance {} vs {var_ref}",
            s.variance()
        );
        assert!(rel(s.std(), var_ref.sqrt()) <= 1e-12);
        assert_eq!(s.count(), xs.len() as u64);
        // Extremes exact.
        assert_eq!(s.min(), xs.iter().copied().fold(f64::INFINITY, f64::min));
        assert_eq!(
            s.max(),
            xs.iter().copied().fold(f64::NEG_INFINITY, f64::max)
        );
    }
}

/// Splits `xs` into chunks of random sizes (empty chunks included).
fn random_chunks<'a>(xs: &'a [f64], r: &mut ChaCha8Rng, max_chunk: usize) -> Vec<&'a [f64]> {
    let mut out = Vec::new();
    let mut rest = xs;
    while !rest.is_empty() {
        let len = r.random_range(0..=max_chunk).min(rest.len());
        let (a, b) = rest.split_at(len);
        out.push(a);
        rest = b;
    }
    out
}

/// Merges the items pairwise in a random tree shape and random order.
fn merge_random_tree<T>(
    mut items: Vec<T>,
    r: &mut ChaCha8Rng,
    mut merge: impl FnMut(&mut T, &T),
) -> T {
    assert!(!items.is_empty());
    while items.len() > 1 {
        let i = r.random_range(0..items.len());
        let b = items.swap_remove(i);
        let j = r.random_range(0..items.len());
        merge(&mut items[j], &b);
    }
    items.pop().unwrap()
}

#[test]
fn running_stats_merge_of_random_splits_equals_whole() {
    let mut r = rng(2);
    let mut worst = (0.0f64, 0.0f64);
    for (name, xs) in moment_datasets() {
        let (m_ref, m2_ref) = reference_moments(&xs);
        let var_ref = m2_ref / (xs.len() - 1) as f64;
        let whole = stats_of(&xs);
        for max_chunk in [1usize, 17, 1000, 40_000] {
            let chunks = random_chunks(&xs, &mut r, max_chunk);
            let parts: Vec<RunningStats> = chunks.iter().map(|c| stats_of(c)).collect();
            let merged = merge_random_tree(parts, &mut r, |a, b| a.merge(b));
            assert_eq!(merged.count(), whole.count());
            assert_eq!(merged.min(), whole.min());
            assert_eq!(merged.max(), whole.max());
            let em = rel(merged.mean(), m_ref).max(rel(merged.mean(), whole.mean()));
            let ev = rel(merged.variance(), var_ref).max(rel(merged.variance(), whole.variance()));
            worst = (worst.0.max(em), worst.1.max(ev));
            // Tolerance 1e-12 relative, against the reference and the unsplit accumulator.
            assert!(
                em <= 1e-12,
                "{name}, chunks <= {max_chunk}: mean rel err {em:e}"
            );
            assert!(
                ev <= 1e-12,
                "{name}, chunks <= {max_chunk}: variance rel err {ev:e}"
            );
        }
    }
    eprintln!(
        "merged random splits: worst mean rel err {:.2e}, variance {:.2e}",
        worst.0, worst.1
    );
}

#[test]
fn running_stats_merge_with_empty_is_exact_and_edge_cases() {
    let xs: Vec<f64> = (0..1000)
        .map(|i| (i as f64 * 0.37).sin() * 1e3 + 7.0)
        .collect();
    let s = stats_of(&xs);
    let json = serde_json::to_string(&s).unwrap();
    let mut a = s.clone();
    a.merge(&RunningStats::new());
    assert_eq!(serde_json::to_string(&a).unwrap(), json);
    let mut b = RunningStats::new();
    b.merge(&s);
    assert_eq!(serde_json::to_string(&b).unwrap(), json);

    // Empty / single-value conventions.
    let mut e = RunningStats::default();
    assert!(e.mean().is_nan() && e.variance().is_nan() && e.min().is_nan() && e.max().is_nan());
    assert!(e.push(2.5));
    assert_eq!((e.mean(), e.min(), e.max()), (2.5, 2.5, 2.5));
    assert!(e.variance().is_nan() && e.std().is_nan());
    assert!(e.push(3.5));
    assert_eq!(e.variance(), 0.5);

    // Non-finite values are rejected, counted, and never averaged in.
    assert!(!e.push(f64::NAN));
    assert!(!e.push(f64::INFINITY));
    assert!(!e.push(f64::NEG_INFINITY));
    assert_eq!((e.count(), e.non_finite()), (2, 3));
    assert_eq!(
        (e.mean(), e.variance(), e.min(), e.max()),
        (3.0, 0.5, 2.5, 3.5)
    );
    let mut f = RunningStats::new();
    f.push(f64::NAN);
    e.merge(&f);
    assert_eq!((e.count(), e.non_finite(), e.mean()), (2, 4, 3.0));
}

#[test]
fn running_stats_json_round_trip_is_bit_exact() {
    let mut r = rng(3);
    let normal = Normal::new(1e8, 1.0).unwrap();
    for _ in 0..50 {
        let n = r.random_range(0..200);
        let xs: Vec<f64> = (0..n)
            .map(|_| normal.sample(&mut r) * r.random::<f64>())
            .collect();
        let s = stats_of(&xs);
        let json = serde_json::to_string(&s).unwrap();
        let back: RunningStats = serde_json::from_str(&json).unwrap();
        assert_eq!(serde_json::to_string(&back).unwrap(), json);
        for (u, v) in [
            (s.mean(), back.mean()),
            (s.variance(), back.variance()),
            (s.min(), back.min()),
            (s.max(), back.max()),
        ] {
            assert_eq!(u.to_bits(), v.to_bits(), "{json}");
        }
    }
    // Hand-written JSON with plain numbers is accepted.
    let s: RunningStats = serde_json::from_str(
        r#"{"count":2,"mean":3.0,"mean_lo":0,"m2":0.5,"min":2.5,"max":"3.5","non_finite":0}"#,
    )
    .unwrap();
    assert_eq!((s.mean(), s.variance(), s.max()), (3.0, 0.5, 3.5));
}

// ------------------------------------------------------------------------------------------------
// QuantileSketch

/// Named data sets of N values used by the quantile tests.
fn quantile_datasets() -> Vec<(&'static str, Vec<f64>)> {
    let mut r = rng(4);
    let uniform = Uniform::new(-1.0, 1.0).unwrap();
    let lognormal = LogNormal::new(0.0, 2.0).unwrap();
    let n0 = Normal::new(0.0, 1.0).unwrap();
    let n1 = Normal::new(1e3, 1.0).unwrap();
    let mass_at_zero = (0..N)
        .map(|i| match i % 10 {
            0..=2 => 0.0,
            3 => -0.0,
            4 => 1e-305 * n0.sample(&mut r), // below the zero threshold
            5 | 6 => n1.sample(&mut r),
            _ => n0.sample(&mut r),
        })
        .collect();
    // Magnitudes log-uniform in [1e-12, 1e12], both signs.
    let log_uniform = (0..N)
        .map(|_| {
            let m = 10f64.powf(r.random_range(-12.0..=12.0));
            if r.random_bool(0.5) {
                m
            } else {
                -m
            }
        })
        .collect();
    vec![
        (
            "uniform(-1,1)",
            (0..N).map(|_| uniform.sample(&mut r)).collect(),
        ),
        (
            "lognormal(0,2)",
            (0..N).map(|_| lognormal.sample(&mut r)).collect(),
        ),
        ("zeros + normals", mass_at_zero),
        ("all equal 3.7", vec![3.7; N]),
        ("all equal -2.5e-7", vec![-2.5e-7; N]),
        ("+-loguniform[1e-12,1e12]", log_uniform),
    ]
}

fn sketch_of(xs: &[f64], alpha: f64) -> QuantileSketch {
    let mut s = QuantileSketch::new(alpha).unwrap();
    for &x in xs {
        assert!(s.push(x));
    }
    s
}

/// Checks the documented guarantee for every q in QS; returns the worst |v - x_r| / (alpha |x_r|).
fn check_guarantee(name: &str, sketch: &QuantileSketch, sorted: &[f64]) -> f64 {
    let alpha = sketch.alpha();
    let n = sorted.len();
    let mut worst = 0.0f64;
    for q in QS {
        let v = sketch.quantile(q).unwrap();
        let r = (q * (n - 1) as f64).floor() as usize; // lower-rank convention
        let x = sorted[r];
        let err = (v - x).abs();
        if x.abs() >= QuantileSketch::ZERO_THRESHOLD {
            // Tolerance: the guarantee itself, no slack.
            assert!(
                err <= alpha * x.abs(),
                "{name}, alpha {alpha}, q {q}: v = {v}, x_r = {x}, rel err {:e}",
                err / x.abs()
            );
            worst = worst.max(err / (alpha * x.abs()));
        } else {
            assert!(
                err < QuantileSketch::ZERO_THRESHOLD,
                "{name}, q {q}: v = {v}, x_r = {x}"
            );
        }
    }
    worst
}

#[test]
fn quantile_sketch_relative_error_guarantee() {
    for (name, xs) in quantile_datasets() {
        let mut sorted = xs.clone();
        sorted.sort_by(f64::total_cmp);
        for alpha in [0.005, 0.01, 1e-4, 1e-6] {
            let sketch = sketch_of(&xs, alpha);
            assert_eq!(sketch.count(), N as u64);
            let worst = check_guarantee(name, &sketch, &sorted);
            eprintln!(
                "{name:>26}, alpha {alpha:<6}: worst |v - x_r| / (alpha |x_r|) = {worst:.4}, {} buckets",
                sketch.bucket_count()
            );
        }
    }
}

#[test]
fn quantile_sketch_dense_quantile_levels() {
    // Every rank-changing level on a smaller sample, including bucket-boundary values gamma^k.
    let s0 = QuantileSketch::new(0.01).unwrap();
    let g = s0.gamma();
    let mut r = rng(5);
    let mut xs: Vec<f64> = (-300..300).map(|k| g.powi(k)).collect();
    xs.extend((-300..300).map(|k| -g.powi(k) * (1.0 + 1e-15)));
    let lognormal = LogNormal::new(0.0, 3.0).unwrap();
    xs.extend((0..2000).map(|_| lognormal.sample(&mut r)));
    let sketch = sketch_of(&xs, 0.01);
    let mut sorted = xs.clone();
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len();
    for i in 0..=4000 {
        let q = i as f64 / 4000.0;
        let v = sketch.quantile(q).unwrap();
        let x = sorted[(q * (n - 1) as f64).floor() as usize];
        assert!((v - x).abs() <= 0.01 * x.abs(), "q {q}: v {v}, x_r {x}");
    }
}

#[test]
fn quantile_sketch_merge_is_exact_in_any_order() {
    let mut r = rng(6);
    for (name, xs) in quantile_datasets() {
        let whole = sketch_of(&xs, QuantileSketch::DEFAULT_ALPHA);
        let json = serde_json::to_string(&whole).unwrap();
        for max_chunk in [1000usize, 30_000] {
            let chunks = random_chunks(&xs, &mut r, max_chunk);
            let mut parts: Vec<QuantileSketch> = chunks
                .iter()
                .map(|c| sketch_of(c, QuantileSketch::DEFAULT_ALPHA))
                .collect();
            // Sequential merge in a random order.
            parts.shuffle(&mut r);
            let mut seq = QuantileSketch::default();
            for p in &parts {
                seq.merge(p).unwrap();
            }
            assert_eq!(
                serde_json::to_string(&seq).unwrap(),
                json,
                "{name}: sequential"
            );
            // Random tree of merges, through JSON (as shards from other machines would arrive).
            let shipped: Vec<QuantileSketch> = parts
                .iter()
                .map(|p| serde_json::from_str(&serde_json::to_string(p).unwrap()).unwrap())
                .collect();
            let tree = merge_random_tree(shipped, &mut r, |a, b| a.merge(b).unwrap());
            assert_eq!(serde_json::to_string(&tree).unwrap(), json, "{name}: tree");
            for q in QS {
                assert_eq!(
                    tree.quantile(q).unwrap().to_bits(),
                    whole.quantile(q).unwrap().to_bits()
                );
            }
        }
    }
}

#[test]
fn quantile_sketch_bucket_count_bound() {
    let mut r = rng(7);
    let alpha = QuantileSketch::DEFAULT_ALPHA;
    let mut sketch = QuantileSketch::new(alpha).unwrap();
    let bound = sketch.bucket_bound(1e-12, 1e12);
    let gamma = (1.0 + alpha) / (1.0 - alpha);
    let formula = (1e24f64.ln() / gamma.ln()).ceil() as usize + 1;
    // The bound is ln(1e24)/ln(gamma) + 1 to within a bucket (gamma used is 1e-5 narrower).
    assert!(
        bound.abs_diff(formula) <= 1,
        "bound {bound} vs formula {formula}"
    );
    for _ in 0..1_000_000 {
        let m = 10f64.powf(r.random_range(-12.0..=12.0));
        sketch.push(if r.random_bool(0.5) { m } else { -m });
    }
    sketch.push(0.0);
    let used = sketch.bucket_count();
    eprintln!("10^6 values with |x| in [1e-12, 1e12]: {used} buckets, bound 2 * {bound} + 1");
    assert!(used <= 2 * bound + 1);
    // The range is densely sampled, so nearly all buckets are in use.
    assert!(used >= 2 * bound - 10);
    // A million copies of a handful of values use a handful of buckets.
    let mut few = QuantileSketch::default();
    for i in 0..1_000_000 {
        few.push([1.0, 2.0, -3.0, 0.0][i % 4]);
    }
    assert_eq!(few.bucket_count(), 4);
}

#[test]
fn quantile_sketch_errors_and_edge_cases() {
    assert!(matches!(
        QuantileSketch::new(0.0),
        Err(StatsError::InvalidAlpha(_))
    ));
    assert!(matches!(
        QuantileSketch::new(f64::NAN),
        Err(StatsError::InvalidAlpha(_))
    ));
    assert!(matches!(
        QuantileSketch::new(0.7),
        Err(StatsError::InvalidAlpha(_))
    ));
    let mut a = QuantileSketch::new(0.01).unwrap();
    let b = QuantileSketch::new(0.02).unwrap();
    let err = a.merge(&b).unwrap_err();
    assert!(matches!(err, StatsError::AlphaMismatch { .. }));
    eprintln!("alpha mismatch message: {err}");

    assert_eq!(a.quantile(0.5), None); // empty
    assert!(!a.push(f64::NAN));
    assert!(!a.push(f64::NEG_INFINITY));
    assert_eq!((a.count(), a.non_finite(), a.quantile(0.5)), (0, 2, None));
    a.push(5.0);
    assert_eq!(a.quantile(0.0), Some(5.0));
    assert_eq!(a.quantile(1.0), Some(5.0));
    assert_eq!(a.quantile(0.5), Some(5.0));
    assert_eq!(a.quantile(1.5), None);
    assert_eq!(a.quantile(-0.1), None);
    assert_eq!(a.quantile(f64::NAN), None);

    // Extreme magnitudes stay finite and within the guarantee.
    let mut c = QuantileSketch::new(1e-6).unwrap();
    for x in [f64::MAX, -f64::MAX, 1e-300, -1e-300, 1e300, 4.9e-324] {
        c.push(x);
    }
    let mut sorted = [f64::MAX, -f64::MAX, 1e-300, -1e-300, 1e300, 4.9e-324];
    sorted.sort_by(f64::total_cmp);
    for i in 0..=50 {
        let q = i as f64 / 50.0;
        let v = c.quantile(q).unwrap();
        let x = sorted[(q * 5.0).floor() as usize];
        assert!(v.is_finite());
        assert!(
            (v - x).abs() <= 1e-6 * x.abs().max(1e-300),
            "q {q}: {v} vs {x}"
        );
    }

    // Corrupt serialized state is rejected.
    let mut json: serde_json::Value = serde_json::to_value(&c).unwrap();
    json["count"] = serde_json::json!(3);
    let bad: Result<QuantileSketch, _> = serde_json::from_value(json);
    assert!(bad.is_err());
}

// ------------------------------------------------------------------------------------------------
// Histogram

#[test]
fn histogram_counts_match_direct_counting() {
    let mut r = rng(8);
    let normal = Normal::new(0.3, 1.2).unwrap();
    let (lo, hi, bins) = (-2.0, 3.1, 37);
    let mut h = Histogram::new(lo, hi, bins).unwrap();
    let edges = h.edges();
    assert_eq!(edges.len(), bins + 1);
    assert_eq!((edges[0], edges[bins]), (lo, hi));
    let mut xs: Vec<f64> = (0..N).map(|_| normal.sample(&mut r)).collect();
    xs.extend_from_slice(&edges); // values exactly on every edge
    xs.extend(edges.iter().map(|e| e.next_down()));
    xs.extend([f64::NAN, f64::INFINITY]);
    for &x in &xs {
        h.push(x);
    }
    // Direct count: bin i holds edges[i] <= x < edges[i+1], the last bin also x == hi.
    let (mut counts, mut under, mut over, mut bad) = (vec![0u64; bins], 0u64, 0u64, 0u64);
    for &x in &xs {
        if !x.is_finite() {
            bad += 1;
        } else if x < lo {
            under += 1;
        } else if x > hi {
            over += 1;
        } else if x == hi {
            counts[bins - 1] += 1;
        } else {
            let i = (0..bins)
                .find(|&i| edges[i] <= x && x < edges[i + 1])
                .unwrap();
            counts[i] += 1;
        }
    }
    assert_eq!(h.counts(), &counts[..]);
    assert_eq!(
        (h.underflow(), h.overflow(), h.non_finite()),
        (under, over, bad)
    );
    assert_eq!(h.total(), (xs.len() - 2) as u64);
    // Every edge landed in the bin it opens.
    assert!(counts.iter().all(|&c| c >= 1));

    // Merge of splits equals the whole; JSON round trip is exact.
    let mut merged = Histogram::new(lo, hi, bins).unwrap();
    for chunk in xs.chunks(777) {
        let mut part = Histogram::new(lo, hi, bins).unwrap();
        chunk.iter().for_each(|&x| {
            part.push(x);
        });
        let part: Histogram = serde_json::from_str(&serde_json::to_string(&part).unwrap()).unwrap();
        merged.merge(&part).unwrap();
    }
    assert_eq!(
        serde_json::to_string(&merged).unwrap(),
        serde_json::to_string(&h).unwrap()
    );

    // Errors.
    assert!(matches!(
        h.merge(&Histogram::new(lo, hi, bins + 1).unwrap()),
        Err(StatsError::HistogramMismatch { .. })
    ));
    assert!(matches!(
        h.merge(&Histogram::new(lo, 3.0, bins).unwrap()),
        Err(StatsError::HistogramMismatch { .. })
    ));
    for (l, u, b) in [
        (1.0, 1.0, 3),
        (2.0, 1.0, 3),
        (0.0, 1.0, 0),
        (f64::NAN, 1.0, 3),
        (-f64::MAX, f64::MAX, 3),
    ] {
        assert!(matches!(
            Histogram::new(l, u, b),
            Err(StatsError::InvalidHistogram { .. })
        ));
    }
}

#[test]
fn histogram_with_colliding_edges_matches_direct_counting() {
    // 1000 bins over ~67 representable values: most edges coincide and their bins stay empty.
    let (lo, hi, bins) = (1e8, 1e8 + 1e-6, 1000);
    let mut h = Histogram::new(lo, hi, bins).unwrap();
    let edges = h.edges();
    let mut xs = Vec::new();
    let mut x = lo;
    for _ in 0..5 {
        x = x.next_down();
    }
    while x <= hi.next_up().next_up() {
        xs.extend([x; 3]);
        x = x.next_up();
    }
    for &x in &xs {
        h.push(x);
    }
    let mut counts = vec![0u64; bins];
    for &x in xs.iter().filter(|&&x| lo <= x && x <= hi) {
        let i = if x == hi {
            bins - 1
        } else {
            (0..bins)
                .find(|&i| edges[i] <= x && x < edges[i + 1])
                .unwrap()
        };
        counts[i] += 1;
    }
    assert_eq!(h.counts(), &counts[..]);
    assert_eq!((h.underflow(), h.overflow()), (15, 6));
    let distinct = edges.windows(2).filter(|w| w[0] < w[1]).count();
    eprintln!("colliding edges: {distinct} non-empty-width bins of {bins}");
    assert!(distinct < 100);
}

#[test]
fn bins_edges_are_the_exact_bin_boundaries() {
    let mut r = rng(11);
    let mut cases: Vec<(f64, f64, usize)> = vec![
        (0.0, 1.0, 200),
        (0.0, 1.0, 400),
        (-0.37, 0.37, 400),
        (-2.0, 3.1, 37),
        (1e8, 1e8 + 1e-6, 1000),
        (-1e-300, 1e-300, 7),
        (0.004, 0.013, 32),
    ];
    for _ in 0..200 {
        let lo = r.random_range(-10.0..10.0) * 10f64.powi(r.random_range(-8..8));
        let hi = lo + r.random_range(1e-3..10.0) * 10f64.powi(r.random_range(-8..8));
        cases.push((lo, hi, r.random_range(1..=500)));
    }
    for (lo, hi, n) in cases {
        let b = Bins::new(lo, hi, n).unwrap();
        let edges = b.edges();
        assert_eq!((edges[0], edges[n]), (lo, hi));
        assert!(edges.windows(2).all(|w| w[0] <= w[1]), "[{lo}, {hi}] / {n}");
        for i in 1..n {
            let e = edges[i];
            // e is in bin i or above, the value just below it in a bin below i.
            assert!(
                b.slot(e) > i,
                "[{lo}, {hi}] / {n}: edge {i} = {e} in slot {}",
                b.slot(e)
            );
            assert!(
                b.slot(e.next_down()) <= i,
                "[{lo}, {hi}] / {n}: below edge {i}"
            );
            // Close to the nominal edge: within a few ulps of max(|lo|, |hi|).
            let nominal = lo + (hi - lo) * i as f64 / n as f64;
            let ulp = f64::EPSILON * lo.abs().max(hi.abs());
            assert!(
                (e - nominal).abs() <= 4.0 * ulp,
                "edge {i}: {e} vs {nominal}"
            );
        }
        // Underflow, overflow and the closed last bin.
        assert_eq!(b.slot(lo.next_down()), 0);
        assert_eq!(b.slot(lo), 1);
        assert_eq!(b.slot(hi), n);
        assert_eq!(b.slot(hi.next_up()), n + 1);
        // Midpoints within half a bin width of every value of their bin.
        for i in 0..n {
            let (a, c) = (edges[i], edges[i + 1]);
            let m = b.midpoint(i);
            // Tolerance: half a bin width, plus the edges' and the midpoint's rounding.
            let ulp = f64::EPSILON * lo.abs().max(hi.abs());
            if a < c {
                let err = (m - a).abs().max((c - m).abs());
                assert!(
                    err <= 0.5 * b.width() + 8.0 * ulp,
                    "bin {i} [{a}, {c}]: {m}"
                );
            }
        }
    }
}

#[test]
fn histogram_quantiles_are_bin_midpoints_within_half_a_bin() {
    let mut r = rng(12);
    let normal = Normal::new(0.3, 1.2).unwrap();
    let (lo, hi, bins) = (-2.0, 3.1, 37);
    let mut h = Histogram::new(lo, hi, bins).unwrap();
    assert!(h.quantile(0.5).unwrap().is_nan(), "empty");
    let xs: Vec<f64> = (0..N).map(|_| normal.sample(&mut r)).collect();
    xs.iter().for_each(|&x| {
        h.push(x);
    });
    let mut sorted = xs.clone();
    sorted.sort_by(f64::total_cmp);
    let half_bin = (hi - lo) / (2.0 * bins as f64);
    let (mut inside, mut outside) = (0, 0);
    for i in 0..=200 {
        let q = i as f64 / 200.0;
        let v = h.quantile(q).unwrap();
        let x = sorted[(q * (N - 1) as f64).floor() as usize];
        if (lo..=hi).contains(&x) {
            assert!(
                (v - x).abs() <= half_bin * (1.0 + 1e-9),
                "q {q}: {v} vs {x}"
            );
            inside += 1;
        } else {
            assert!(v.is_nan(), "q {q}: {v} for {x} outside the range");
            outside += 1;
        }
    }
    assert!(inside > 0 && outside > 0);
    assert!(matches!(
        h.quantile(1.5),
        Err(StatsError::InvalidQuantile(_))
    ));
}

// ------------------------------------------------------------------------------------------------
// ScalarSummary and FieldBand

#[test]
fn scalar_summary_push_and_merge() {
    let mut r = rng(9);
    let lognormal = LogNormal::new(1.0, 0.7).unwrap();
    let xs: Vec<f64> = (0..N).map(|_| lognormal.sample(&mut r)).collect();
    let alpha = 0.01;
    let make = || ScalarSummary::new(alpha).unwrap();
    let mut whole = make();
    xs.iter().for_each(|&x| {
        whole.push(x);
    });
    let mut merged = make();
    for c in xs.chunks(3001) {
        let mut p = make();
        c.iter().for_each(|&x| {
            p.push(x);
        });
        // Shipped through JSON, as shards are.
        let p: ScalarSummary = serde_json::from_str(&serde_json::to_string(&p).unwrap()).unwrap();
        merged.merge(&p).unwrap();
    }
    let (m_ref, m2_ref) = reference_moments(&xs);
    assert!(rel(merged.stats().mean(), m_ref) <= 1e-12);
    assert!(rel(merged.stats().variance(), m2_ref / (N - 1) as f64) <= 1e-12);
    assert_eq!(
        serde_json::to_string(merged.sketch()).unwrap(),
        serde_json::to_string(whole.sketch()).unwrap()
    );
    let mut sorted = xs.clone();
    sorted.sort_by(f64::total_cmp);
    check_guarantee("scalar summary", merged.sketch(), &sorted);
    assert_eq!(merged.quantile(0.5), merged.sketch().quantile(0.5));

    // The histogram over [min, max] from the sketch: identical for any sharding, every value
    // counted, each within alpha |x| of where it is.
    let bins = 40;
    let hist = merged.range_histogram(bins).unwrap();
    assert_eq!(
        serde_json::to_string(&hist).unwrap(),
        serde_json::to_string(&whole.range_histogram(bins).unwrap()).unwrap()
    );
    assert_eq!((hist.lo(), hist.hi()), (sorted[0], sorted[N - 1]));
    assert_eq!(hist.total(), N as u64);
    assert_eq!(
        (hist.underflow(), hist.overflow(), hist.non_finite()),
        (0, 0, 0)
    );
    let edges = hist.edges();
    let mut below = 0u64;
    for k in 1..bins {
        below += hist.counts()[k - 1];
        // Counted below edge k: every x with x + alpha |x| < e, none with x - alpha |x| >= e.
        let e = edges[k];
        let surely = xs.iter().filter(|&&x| x + alpha * x.abs() < e).count() as u64;
        let maybe = xs.iter().filter(|&&x| x - alpha * x.abs() < e).count() as u64;
        assert!(
            surely <= below && below <= maybe,
            "edge {k} = {e}: {below} counted below, direct count between {surely} and {maybe}"
        );
    }
    // Degenerate ranges: all values equal (range widened around them), nothing pushed.
    let mut same = make();
    for _ in 0..10 {
        same.push(2.5);
    }
    same.push(f64::NAN);
    let h = same.range_histogram(4).unwrap();
    assert_eq!((h.lo(), h.hi()), (1.25, 3.75));
    assert_eq!((h.counts(), h.non_finite()), (&[0, 0, 10, 0][..], 1));
    let h = make().range_histogram(4).unwrap();
    assert_eq!((h.lo(), h.hi(), h.total()), (0.0, 1.0, 0));

    let json = serde_json::to_string(&merged).unwrap();
    let back: ScalarSummary = serde_json::from_str(&json).unwrap();
    assert_eq!(serde_json::to_string(&back).unwrap(), json);
    // Files written before the optional histogram was dropped (`"histogram": null`) still read.
    let old = json.replacen('{', r#"{"histogram":null,"#, 1);
    let back: ScalarSummary = serde_json::from_str(&old).unwrap();
    assert_eq!(serde_json::to_string(&back).unwrap(), json);

    assert!(!merged.push(f64::NAN));
    let other_alpha = ScalarSummary::new(0.02).unwrap();
    let before = serde_json::to_string(&merged).unwrap();
    assert!(matches!(
        merged.merge(&other_alpha),
        Err(StatsError::AlphaMismatch { .. })
    ));
    assert_eq!(
        serde_json::to_string(&merged).unwrap(),
        before,
        "failed merge left state unchanged"
    );
}

#[test]
fn field_band_matches_direct_computation() {
    const M: usize = 3000; // members
    const G: usize = 48; // grid points
    let mut r = rng(10);
    let noise = Normal::new(0.0, 1.0).unwrap();
    let lognormal = LogNormal::new(0.0, 1.5).unwrap();
    // The stored [members, G] array, row-major; a few NaN entries in column 7 (member 0's too).
    let mut data = vec![0.0f64; M * G];
    for m in 0..M {
        let amp = lognormal.sample(&mut r);
        for g in 0..G {
            let x = g as f64 / G as f64;
            data[m * G + g] = if g == 7 && m % 100 == 0 {
                f64::NAN
            } else {
                10.0 * (6.0 * x).sin() + amp * x + 0.1 * noise.sample(&mut r)
            };
        }
    }
    // Infinities, which the bulk fill takes apart from the finite rows (non-finite, like NaN).
    data[5 * G + 3] = f64::INFINITY;
    data[6 * G + 11] = f64::NEG_INFINITY;
    // The range holds most values; the large-amplitude tail overflows, the lowest underflow.
    let (lo, hi, bins) = (-9.5, 30.0, 400);
    let half_bin = (hi - lo) / (2.0 * bins as f64);
    let rows: Vec<&[f64]> = data.chunks(G).collect();
    let mut whole = FieldBand::new(G, lo, hi, bins).unwrap();
    whole.push_rows(&rows).unwrap();
    // The same, in chunks of members (some single rows) merged in a random tree, shipped as JSON.
    let mut parts: Vec<FieldBand> = Vec::new();
    for (i, block) in rows.chunks(211).enumerate() {
        let mut f = FieldBand::new(G, lo, hi, bins).unwrap();
        if i % 3 == 0 {
            block.iter().for_each(|row| f.push_rows(&[row]).unwrap());
        } else {
            f.push_rows(block).unwrap();
        }
        parts.push(serde_json::from_str(&serde_json::to_string(&f).unwrap()).unwrap());
    }
    let merged = merge_random_tree(parts, &mut r, |a, b| a.merge(b).unwrap());
    assert_eq!(merged.points(), G);

    let mean_w = whole.mean_row();
    let mean_m = merged.mean_row();
    let std_m = merged.std_row();
    let var_m = merged.variance_row();
    let mut worst_mean = 0.0f64;
    let mut worst_quantile = 0.0f64;
    let (mut inside, mut outside) = (0, 0);
    for g in 0..G {
        let col: Vec<f64> = (0..M)
            .map(|m| data[m * G + g])
            .filter(|x| x.is_finite())
            .collect();
        let (m_ref, m2_ref) = reference_moments(&col);
        let sd_ref = (m2_ref / (col.len() - 1) as f64).sqrt();
        // Tolerance: 1e-12 relative to the column's scale (|mean| + std: some means are ~0).
        let scale = m_ref.abs() + sd_ref;
        for m in [mean_w[g], mean_m[g]] {
            let e = (m - m_ref).abs() / scale;
            worst_mean = worst_mean.max(e);
            assert!(e <= 1e-12, "point {g}: mean {m} vs {m_ref}");
        }
        assert!(rel(std_m[g], sd_ref) <= 1e-12, "point {g}: std");
        assert!(
            rel(var_m[g], sd_ref * sd_ref) <= 1e-12,
            "point {g}: variance"
        );
        assert!(
            rel(whole.std_row()[g], sd_ref) <= 1e-12,
            "point {g}: std (whole)"
        );
        assert_eq!(merged.stats()[g].count(), col.len() as u64);
        assert_eq!(merged.stats()[g].non_finite(), (M - col.len()) as u64);
        assert_eq!(whole.stats()[g].non_finite(), (M - col.len()) as u64);

        // The point's counts are the histogram of its column (the one binning rule), merged
        // exactly.
        let mut direct = Histogram::new(lo, hi, bins).unwrap();
        (0..M).for_each(|m| {
            direct.push(data[m * G + g]);
        });
        let direct = serde_json::to_string(&direct).unwrap();
        assert_eq!(serde_json::to_string(&merged.histogram(g)).unwrap(), direct);
        assert_eq!(serde_json::to_string(&whole.histogram(g)).unwrap(), direct);

        let mut sorted = col.clone();
        sorted.sort_by(f64::total_cmp);
        for q in QS.iter().copied().chain((0..=50).map(|i| i as f64 / 50.0)) {
            let row = merged.quantile_row(q).unwrap();
            let x = sorted[(q * (sorted.len() - 1) as f64).floor() as usize];
            if (lo..=hi).contains(&x) {
                // Tolerance: the documented half bin width (and rounding of the midpoint).
                assert!(
                    (row[g] - x).abs() <= half_bin * (1.0 + 1e-9),
                    "point {g}, q {q}: {} vs {x}",
                    row[g]
                );
                worst_quantile = worst_quantile.max((row[g] - x).abs() / half_bin);
                inside += 1;
            } else {
                assert!(
                    row[g].is_nan(),
                    "point {g}, q {q}: {} for {x} outside",
                    row[g]
                );
                outside += 1;
            }
            assert_eq!(
                row[g].to_bits(),
                whole.quantile_row(q).unwrap()[g].to_bits()
            );
        }
        // Several levels from one pass, in any order and repeated: each as read on its own.
        let levels = [0.9, 0.1, 0.5, 1.0, 0.5, 0.0, 0.25];
        for (q, row) in levels.iter().zip(merged.quantile_rows(&levels).unwrap()) {
            assert_eq!(
                row[g].to_bits(),
                merged.quantile_row(*q).unwrap()[g].to_bits(),
                "point {g}, level {q} among several"
            );
        }
        assert_eq!(merged.min_row()[g], sorted[0]);
        assert_eq!(merged.max_row()[g], sorted[sorted.len() - 1]);
    }
    assert!(
        inside > 0 && outside > 0,
        "{inside} inside, {outside} outside"
    );
    eprintln!(
        "field band {M} x {G}: worst mean error / (|mean| + std) = {worst_mean:.2e}, quantile error up to {worst_quantile:.3} half bins"
    );
    let json = serde_json::to_string(&merged).unwrap();
    let back: FieldBand = serde_json::from_str(&json).unwrap();
    assert_eq!(serde_json::to_string(&back).unwrap(), json);
    for q in QS {
        let (a, b) = (
            back.quantile_row(q).unwrap(),
            merged.quantile_row(q).unwrap(),
        );
        assert!(a.iter().zip(&b).all(|(u, v)| u.to_bits() == v.to_bits()));
    }
    assert!(back
        .mean_row()
        .iter()
        .zip(&merged.mean_row())
        .all(|(u, v)| u.to_bits() == v.to_bits()));

    // The on-disk layout of study chunk and partial files: per point `bins + 2` slot counts
    // (underflow, bins, overflow), stored sparse.
    let disk = r#"{"lo":0.0,"hi":1.0,"bins":4,"points":[{"count":3,"mean":0.5,"mean_lo":0.0,"m2":0.5,"min":0.1,"max":1.5,"non_finite":0}],"counts":[{"len":6,"nonzero":[[1,1],[3,1],[5,1]]}]}"#;
    let f: FieldBand = serde_json::from_str(disk).unwrap();
    let h = f.histogram(0);
    assert_eq!(
        (h.underflow(), h.counts(), h.overflow()),
        (0, &[1, 0, 1, 0][..], 1)
    );
    assert_eq!(f.quantile_row(0.0).unwrap(), [0.125]);
    assert_eq!(f.quantile_row(0.5).unwrap(), [0.625]);
    assert!(
        f.quantile_row(1.0).unwrap()[0].is_nan(),
        "rank in the overflow"
    );
    assert_eq!(
        serde_json::from_str::<serde_json::Value>(&serde_json::to_string(&f).unwrap()).unwrap(),
        serde_json::from_str::<serde_json::Value>(disk).unwrap()
    );
    let bad = disk.replace(r#""len":6"#, r#""len":5"#);
    assert!(serde_json::from_str::<FieldBand>(&bad).is_err());

    // Slot counts are u32: a count beyond u32::MAX is refused naming the limit, and so is a push
    // or a merge that would take a point past it (never wrapped); up to the limit is accepted.
    let huge = disk.replace("[5,1]", "[5,4294967296]");
    let err = serde_json::from_str::<FieldBand>(&huge)
        .unwrap_err()
        .to_string();
    assert!(err.contains("4294967295"), "{err}");
    let at = |count: u64| -> FieldBand {
        serde_json::from_str(&disk.replace(r#""count":3"#, &format!(r#""count":{count}"#))).unwrap()
    };
    let mut full = at(u32::MAX as u64);
    let err = full.merge(&at(3)).unwrap_err();
    assert!(matches!(err, StatsError::CountOverflow { .. }), "{err}");
    assert!(err.to_string().contains("4294967295"), "{err}");
    assert_eq!(
        full.stats()[0].count(),
        u32::MAX as u64,
        "a refused merge adds nothing"
    );
    assert!(matches!(
        full.push_rows(&[&[0.5]]),
        Err(StatsError::CountOverflow { .. })
    ));
    let mut almost = at(u32::MAX as u64 - 1);
    almost.push_rows(&[&[0.5]]).unwrap();
    assert_eq!(almost.stats()[0].count(), u32::MAX as u64);

    // Errors.
    let mut f = FieldBand::new(G, lo, hi, bins).unwrap();
    assert!(matches!(
        f.push_rows(&[&[1.0; G], &[1.0; 3]]),
        Err(StatsError::LengthMismatch { .. })
    ));
    assert_eq!(f.stats()[0].count(), 0, "a failed push adds nothing");
    assert!(matches!(
        f.merge(&FieldBand::new(G + 1, lo, hi, bins).unwrap()),
        Err(StatsError::LengthMismatch { .. })
    ));
    assert!(matches!(
        f.merge(&FieldBand::new(G, lo, hi, bins + 1).unwrap()),
        Err(StatsError::HistogramMismatch { .. })
    ));
    assert!(matches!(
        f.merge(&FieldBand::new(G, lo, hi + 1.0, bins).unwrap()),
        Err(StatsError::HistogramMismatch { .. })
    ));
    assert!(matches!(
        FieldBand::new(G, 1.0, 1.0, bins),
        Err(StatsError::InvalidHistogram { .. })
    ));
    assert!(matches!(
        f.quantile_row(2.0),
        Err(StatsError::InvalidQuantile(_))
    ));
    assert!(f.quantile_row(0.5).unwrap().iter().all(|v| v.is_nan()));
    assert!(f.mean_row().iter().all(|v| v.is_nan()));
}

/// The binary (CBOR, columnar) form of a field band reads back to the same band bit for bit, is
/// a fraction of the dense size, and bands shipped through it merge to the band of all rows
/// (counts exactly, moments to rounding), as the study's chunk and partial files need.
#[test]
fn field_band_binary_round_trip_is_bit_exact_and_compact() {
    const G: usize = 64;
    let mut r = rng(31);
    let noise = Normal::new(0.5, 0.1).unwrap();
    let rows_data: Vec<Vec<f64>> = (0..500)
        .map(|m| {
            (0..G)
                .map(|g| {
                    if g == 3 && m % 50 == 0 {
                        f64::NAN
                    } else {
                        noise.sample(&mut r) + 0.3 * (g as f64 / G as f64)
                    }
                })
                .collect()
        })
        .collect();
    let rows: Vec<&[f64]> = rows_data.iter().map(Vec::as_slice).collect();
    let cbor = |band: &FieldBand| {
        let mut bytes = Vec::new();
        ciborium::into_writer(band, &mut bytes).unwrap();
        bytes
    };
    let mut whole = FieldBand::new(G, 0.0, 1.0, 400).unwrap();
    whole.push_rows(&rows).unwrap();
    let bytes = cbor(&whole);
    let back: FieldBand = ciborium::from_reader(&bytes[..]).unwrap();
    assert_eq!(cbor(&back), bytes, "re-serialised band differs");
    assert_eq!(
        serde_json::to_string(&back).unwrap(),
        serde_json::to_string(&whole).unwrap(),
        "the band read back differs from the band written"
    );
    // The columnar form holds per point 5 f64 moments, 2 u64 counts and a u32, and per
    // non-empty slot a u16 step and a u32 count (plus a few hundred bytes of keys): its size
    // follows the non-empty slots, far below the dense G x (bins + 2) x 8 bytes.
    let filled: usize = (0..G)
        .map(|j| {
            let h = whole.histogram(j);
            h.counts().iter().filter(|&&c| c > 0).count() + 2
        })
        .sum();
    let expected = G * (5 * 8 + 2 * 8 + 4) + filled * (2 + 4);
    eprintln!("{} bytes, expected about {expected}", bytes.len());
    assert!(
        bytes.len() <= expected + 512 && bytes.len() + 2 * 6 * G >= expected,
        "{} bytes against about {expected} (dense {})",
        bytes.len(),
        G * 402 * 8
    );
    // An empty band is small whatever its bins.
    let empty = FieldBand::new(G, 0.0, 1.0, 100_000).unwrap();
    assert!(cbor(&empty).len() < 64 * G, "{}", cbor(&empty).len());

    let mut merged: Option<FieldBand> = None;
    for block in rows.chunks(77) {
        let mut part = FieldBand::new(G, 0.0, 1.0, 400).unwrap();
        part.push_rows(block).unwrap();
        let part: FieldBand = ciborium::from_reader(&cbor(&part)[..]).unwrap();
        match &mut merged {
            None => merged = Some(part),
            Some(m) => m.merge(&part).unwrap(),
        }
    }
    let merged = merged.unwrap();
    for q in [0.05, 0.5, 0.95] {
        let (a, b) = (
            merged.quantile_row(q).unwrap(),
            whole.quantile_row(q).unwrap(),
        );
        assert_eq!(
            a.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            b.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            "quantile {q}"
        );
    }
    for (a, b) in merged.mean_row().iter().zip(whole.mean_row()) {
        assert!((a - b).abs() <= 1e-15 * b.abs().max(1.0), "{a} vs {b}");
    }
}

/// Pushes taken back with `undo_pushes` (the moments from before them, the rows they added) and
/// the good rows pushed again leave the band bit for bit as if only the good rows had been
/// pushed: what a study does when a member fails after its rows went in. A row that was never
/// pushed cannot be taken out.
#[test]
fn field_band_undo_takes_back_pushes_exactly() {
    const G: usize = 150; // several blocks of the fill; 200 rows of it fill them in parallel
    let mut r = rng(77);
    let normal = Normal::new(1.0, 0.4).unwrap();
    let mut row = |nan_at: Option<usize>| -> Vec<f64> {
        (0..G)
            .map(|j| match nan_at {
                Some(k) if k == j => f64::NAN,
                _ => normal.sample(&mut r) + j as f64 / G as f64,
            })
            .collect()
    };
    let earlier: Vec<Vec<f64>> = (0..100).map(|_| row(None)).collect();
    let chunk: Vec<Vec<f64>> = (0..200)
        .map(|i| row(if i % 17 == 0 { Some(i % G) } else { None }))
        .collect();
    // Every fifth member of the chunk "fails later": its rows must not count.
    let good: Vec<&[f64]> = chunk
        .iter()
        .enumerate()
        .filter(|(i, _)| i % 5 != 0)
        .map(|(_, r)| &r[..])
        .collect();
    let all: Vec<&[f64]> = chunk.iter().map(|r| &r[..]).collect();
    let earlier: Vec<&[f64]> = earlier.iter().map(|r| &r[..]).collect();
    let (lo, hi, bins) = (0.0, 2.5, 400);

    let mut want = FieldBand::new(G, lo, hi, bins).unwrap();
    want.push_rows(&earlier).unwrap();
    want.push_rows(&good).unwrap();

    let mut got = FieldBand::new(G, lo, hi, bins).unwrap();
    got.push_rows(&earlier).unwrap();
    let before = got.stats().to_vec();
    got.push_rows(&all).unwrap();
    assert_ne!(
        serde_json::to_string(&got).unwrap(),
        serde_json::to_string(&want).unwrap()
    );
    got.undo_pushes(&before, &all).unwrap();
    got.push_rows(&good).unwrap();
    assert_eq!(
        serde_json::to_string(&got).unwrap(),
        serde_json::to_string(&want).unwrap(),
        "moments and slot counts after the undo"
    );
    for (a, b) in got.stats().iter().zip(want.stats()) {
        assert_eq!(a.mean().to_bits(), b.mean().to_bits());
        assert_eq!(a.variance().to_bits(), b.variance().to_bits());
        assert_eq!((a.count(), a.non_finite()), (b.count(), b.non_finite()));
    }
    let q = [0.05, 0.5, 0.95];
    let bits = |rows: Vec<Vec<f64>>| -> Vec<Vec<u64>> {
        rows.iter()
            .map(|r| r.iter().map(|x| x.to_bits()).collect())
            .collect()
    };
    assert_eq!(
        bits(got.quantile_rows(&q).unwrap()),
        bits(want.quantile_rows(&q).unwrap())
    );

    // A row that was never pushed: refused, nothing changed.
    let stranger = vec![2.0; G];
    let unchanged = serde_json::to_string(&got).unwrap();
    assert!(matches!(
        got.undo_pushes(&before, &[&stranger]),
        Err(StatsError::NotCounted { .. })
    ));
    assert_eq!(serde_json::to_string(&got).unwrap(), unchanged);
}
