//! Unit tests of the convergence arithmetic, the `--particles` check and the sampling.

use super::*;

#[test]
fn rates_of_a_power_law_are_its_exponent() {
    let ns = [100.0f64, 200.0, 400.0, 800.0];
    let e: Vec<f64> = ns.iter().map(|n| 3.0 * n.powf(-1.5)).collect();
    for k in 1..e.len() {
        assert!((observed_rate(e[k - 1], e[k], 2.0) - 1.5).abs() < 1e-12);
    }
    let (p, _) = fit_rate(&ns, &e).unwrap();
    assert!((p - 1.5).abs() < 1e-12);
    assert!(observed_rate(0.0, 0.0, 2.0).is_nan());
    assert!(observed_rate(f64::NAN, 1.0, 2.0).is_nan());
}

#[test]
fn verdicts() {
    let r = 1e-13;
    assert_eq!(verdict(&[0.0, 1e-16], &[f64::NAN], r), Verdict::Exact);
    assert_eq!(
        verdict(&[1e-9, 1e-12, 1e-12], &[3.0, 0.0], r),
        Verdict::RoundingLimited
    );
    assert_eq!(
        verdict(&[4.0, 2.0, 1.0], &[1.0, 1.0], r),
        Verdict::Asymptotic
    );
    assert_eq!(verdict(&[4.0, 2.0, 0.5], &[1.0, 2.0], r), Verdict::Drifting);
    assert_eq!(
        verdict(&[4.0, 2.0, 3.0], &[1.0, -0.58], r),
        Verdict::NotMonotone
    );
    // A failed run's NaN differences are a failure, not a shape of the differences.
    assert_eq!(
        verdict(&[4.0, f64::NAN, 1.0], &[f64::NAN, f64::NAN], r),
        Verdict::Failed
    );
    assert_eq!(verdict(&[4.0, 2.0], &[1.0], r), Verdict::TooFewRates);
    // Differences within 100 times the rounding level that still fall steadily (f32 at modest
    // N: 1.07e-4, 2.54e-5 against a level of 1.9e-6) are judged by their rates.
    let f32_level = 1.9e-6;
    assert_eq!(
        verdict(&[1.07e-4, 2.54e-5], &[2.07], f32_level),
        Verdict::TooFewRates
    );
    assert_eq!(
        verdict(&[4.3e-4, 1.07e-4, 2.54e-5], &[2.0, 2.07], f32_level),
        Verdict::Asymptotic
    );
    // ... and rounding_limited where the last rate shows the rounding.
    assert_eq!(
        verdict(&[4.3e-4, 2.0e-5, 1.5e-5], &[4.4, 0.4], f32_level),
        Verdict::RoundingLimited
    );
    assert_eq!(verdict(&[4.0], &[], r), Verdict::TooFewRates);
}

#[test]
fn richardson_recovers_the_limit_of_an_exact_expansion() {
    // f_N = 1 + 2/N^2 at two points: the extrapolation with p = 2 is exact.
    let f = |n: f64| vec![1.0 + 2.0 / (n * n), 3.0 - 1.0 / (n * n)];
    let lim = richardson(&f(800.0), &f(400.0), 2.0, 2.0);
    assert!((lim[0] - 1.0).abs() < 1e-14 && (lim[1] - 3.0).abs() < 1e-14);
    assert!(richardson(&f(800.0), &f(400.0), 2.0, -1.0)[0].is_nan());
}

#[test]
fn particle_lists_are_checked() {
    assert!(check_particles(&[100, 200, 400]).is_ok());
    assert!(check_particles(&[100, 200]).is_ok());
    for bad in [
        &[100][..],
        &[],
        &[200, 100, 400],
        &[100, 100, 200],
        &[1, 2, 4],
        &[100, 200_000_000],
    ] {
        let e = check_particles(bad).unwrap_err().to_string();
        assert!(e.starts_with("--particles"), "{e}");
        assert!(e.contains("2 ..= 100000000"), "{e}");
    }
}

#[test]
fn cubic_sampling_is_exact_for_cubics() {
    let nodes = [0.0, 0.1, 0.25, 0.3, 0.55, 0.7, 1.0];
    let p = |x: f64| 1.0 - 2.0 * x + 3.0 * x * x - 0.5 * x * x * x;
    let values: Vec<f64> = nodes.iter().map(|&x| p(x)).collect();
    let grid = crate::model::observables::grid_points(23);
    for (x, v) in grid.iter().zip(cubic_interpolated(&nodes, &values, &grid)) {
        assert!((v - p(*x)).abs() < 1e-13, "{x}: {v}");
    }
    // Two or three nodes: the line or parabola through them.
    let v = cubic_interpolated(&[0.25, 0.75], &[1.0, 2.0], &[0.0, 0.5, 1.0]);
    assert!((v[0] - 0.5).abs() < 1e-15 && (v[1] - 1.5).abs() < 1e-15 && (v[2] - 2.5).abs() < 1e-15);
    assert_eq!(cell_centres(&[0.2, 0.3, 0.5]), vec![0.1, 0.35, 0.75]);
}

#[test]
fn shown_times_include_first_and_last() {
    assert_eq!(shown_times(3), vec![0, 1, 2]);
    assert_eq!(shown_times(9), vec![0, 2, 5, 8]);
}
