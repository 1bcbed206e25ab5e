use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::super::tests::Wave;
use super::super::{
    default_layout, euler_step_as, stored_ln, EnergyWanted, Gamma, HardFailure, Scratch,
    StepBuffers, GAP_FLOOR,
};
use super::*;
use crate::power::Power;
use crate::stored_gap;

/// A random chain of n particles: gaps of very different sizes around 1/n (stored form),
/// velocities, d*, bonded flags; `near` gaps of 1e-300 (stored as ln d) and `bonds` bonded
/// gaps at the given gap indices.
struct Chain {
    n: usize,
    gaps: Vec<f64>,
    vel: Vec<f64>,
    dstar: Vec<f64>,
    bonded: Vec<bool>,
}

fn chain(n: usize, seed: u64, near: &[usize], bonds: &[usize]) -> Chain {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let scale = 0.5 / n as f64;
    let mut gaps: Vec<f64> = (0..n)
        .map(|_| scale * (0.05 + 2.0 * rng.random::<f64>()))
        .collect();
    let dstar: Vec<f64> = (0..n)
        .map(|_| scale * (0.2 + 1.5 * rng.random::<f64>()))
        .collect();
    let vel: Vec<f64> = (1..n)
        .map(|i| {
            let x = i as f64 / n as f64;
            0.5 * (2.0 * std::f64::consts::PI * x).sin() + 0.05 * (rng.random::<f64>() - 0.5)
        })
        .collect();
    let mut bonded = vec![false; n];
    for &k in near {
        gaps[k] = stored_gap::encode(1e-300, GAP_FLOOR);
    }
    for &k in bonds {
        gaps[k] = 0.0;
        bonded[k] = true;
    }
    Chain {
        n,
        gaps,
        vel,
        dstar,
        bonded,
    }
}

/// Which terms a case has.
#[derive(Clone, Copy, Debug)]
struct Model {
    gamma: Option<f64>,
    clusters: bool,
    forced: bool,
    /// `Terms::exact_jacobian`.
    exact: bool,
}

type Outcome = (Vec<f64>, Vec<f64>, StepReport);

/// One step of the chain in T (the chain's values rounded to T, the results as their exact
/// f64 values), sequential (`layout` None) or partitioned.
fn step_as<T: Real>(
    c: &Chain,
    model: Model,
    h: f64,
    layout: Option<Layout>,
    simd: SimdLevel,
) -> Outcome {
    let n = c.n;
    let eps = 0.25 / n as f64;
    let forcing = model.forced.then_some(Wave {
        amplitude: 0.3,
        offset: 0.1,
    });
    let to_t = |v: &[f64]| -> Vec<T> { v.iter().map(|&x| T::c(x)).collect() };
    let (gaps, vel, dstar) = (to_t(&c.gaps), to_t(&c.vel), to_t(&c.dstar));
    let terms = Terms::<1, T> {
        eps: T::c(eps),
        mu: [T::c(0.01)],
        total_gap: [gaps.iter().map(|&v| stored_gap::decode(v.to_f64())).sum()],
        contact_repulsion: [model.gamma.map_or(0.0, |g| 3f64.powf(g))],
        exact_jacobian: model.exact,
        energy: EnergyWanted::UnlessCertified,
        repulsion: model
            .gamma
            .map(|g| (dstar.as_slice(), Gamma::Uniform(Power::of(g)))),
        bonded: model.clusters.then_some(c.bonded.as_slice()),
        forcing: forcing.as_ref().map(|f| f as &dyn super::super::Forcing),
        forcing_params: [&[]],
        simd: SimdLevel::widest_here(),
        partition: true,
    };
    let mut gaps_out = vec![T::ZERO; n];
    let mut vel_out = vec![T::ZERO; n - 1];
    let mut scratch = Scratch::<T>::new(n, 1);
    let report = euler_step_as(
        simd,
        layout,
        &terms,
        n,
        &[0.25],
        &[T::c(h)],
        StepBuffers {
            gaps_in: &gaps,
            vel_in: &vel,
            gaps_out: &mut gaps_out,
            vel_out: &mut vel_out,
            scratch: &mut scratch,
        },
    );
    let to_f64 = |v: &[T]| -> Vec<f64> { v.iter().map(|x| x.to_f64()).collect() };
    (to_f64(&gaps_out), to_f64(&vel_out), report[0])
}

/// How closely the partitioned result must equal the sequential one.
#[derive(Clone, Copy, Debug)]
struct Tol {
    /// Relative, for gaps stored as d, velocities (relative to max |u|), energy and work.
    rel: f64,
    /// Gaps stored as ln d: the difference of ln d relative to |ln d| (in f32, where the
    /// stored ln d ~ -690 has ulps of 6e-5 and rounds to one or the other), else absolute
    /// (in f64, as for d: a difference of ln d is a relative one of d).
    ln_relative: bool,
}

/// f64: 1e-12, ~4500 ulps (2^-52). The velocity solve's condition number (up to ~1e7 at
/// large N, see `long_chain_equals_sequential`) amplifies the two solves' roundings alike
/// (measured at most 3.8e-14, 170 ulps).
const TOL: Tol = Tol {
    rel: 1e-12,
    ln_relative: false,
};

/// f32: 2^-14 = 6.1e-5 relative, 512 ulps of f32 (2^-23): the two f32 solves' roundings
/// amplified by the same conditioning as in f64 (measured at most 1.2e-5, 103 ulps, on the
/// velocities at N = 2^18; gaps 4.7e-7, 4 ulps).
const TOL_F32: Tol = Tol {
    rel: 6.103515625e-5,
    ln_relative: true,
};

/// The largest differences found by [`assert_close`]: gaps, velocities.
#[derive(Clone, Copy, Debug, Default)]
struct MaxDiff {
    gap: f64,
    vel: f64,
}

impl MaxDiff {
    fn max(self, o: MaxDiff) -> MaxDiff {
        MaxDiff {
            gap: self.gap.max(o.gap),
            vel: self.vel.max(o.vel),
        }
    }
}

/// The partitioned result equals the sequential one to `tol`: gaps relatively (ln d for
/// log-stored ones, see [`Tol`]; bonded gaps exactly 0 in both), velocities relative to
/// max |u|, the energy and work relatively, the flags exactly. Returns the largest
/// differences.
fn assert_close(label: &str, part: &Outcome, seq: &Outcome, tol: Tol) -> MaxDiff {
    let (pg, pv, pr) = part;
    let (sg, sv, sr) = seq;
    let mut max = MaxDiff::default();
    for (i, (&a, &b)) in pg.iter().zip(sg).enumerate() {
        let err = if a > 0.0 && b > 0.0 {
            (a - b).abs() / b
        } else if a == 0.0 || b == 0.0 {
            assert_eq!(a, b, "{label}: gap {i} bonded in one only");
            0.0
        } else {
            let (la, lb) = (stored_ln(a), stored_ln(b));
            let scale = if tol.ln_relative { lb.abs() } else { 1.0 };
            (la - lb).abs() / scale
        };
        assert!(
            err <= tol.rel,
            "{label}: gap {i}: {a:e} vs {b:e} (rel {err:e})"
        );
        max.gap = max.gap.max(err);
    }
    let umax = sv.iter().fold(0.0f64, |m, u| m.max(u.abs()));
    for (i, (a, b)) in pv.iter().zip(sv).enumerate() {
        let err = (a - b).abs() / umax;
        assert!(
            err <= tol.rel,
            "{label}: u {i}: {a:e} vs {b:e} (rel {err:e})"
        );
        max.vel = max.vel.max(err);
    }
    assert_eq!(
        (pr.admissible, pr.hard, pr.certified),
        (sr.admissible, sr.hard, sr.certified),
        "{label}: flags"
    );
    for (what, a, b) in [("energy", pr.energy, sr.energy), ("work", pr.work, sr.work)] {
        assert!(
            (a - b).abs() <= tol.rel * b.abs().max(1e-300),
            "{label}: {what} {a:e} vs {b:e}"
        );
    }
    max
}

fn models() -> Vec<Model> {
    let mut out = Vec::new();
    for gamma in [None, Some(2.0), Some(1.5)] {
        for clusters in [false, true] {
            for forced in [false, true] {
                for exact in [false, true] {
                    out.push(Model {
                        gamma,
                        clusters,
                        forced,
                        exact,
                    });
                }
            }
        }
    }
    out
}

/// Segment boundaries of a layout: the first gap of each segment (index b - 1) and its
/// neighbours, where the interface solve matters most.
fn boundary_gaps(layout: &Layout, n: usize) -> Vec<usize> {
    let mut out = vec![0, 1, n - 1];
    for s in 1..layout.segments() {
        let b = layout.first_row(s);
        out.extend([b - 2, b - 1, b]);
    }
    out
}

/// Plain, repulsion, forcing and clusters, on chains whose row count the segments do not
/// divide (n - 1 = 2000 + 13 rows, 1 to 3 groups), at a mild and a large step.
#[test]
fn partitioned_equals_sequential() {
    let max = equals_sequential::<f64>(TOL);
    eprintln!("f64: {max:?}");
}

/// [`partitioned_equals_sequential`] in f32.
#[test]
fn f32_partitioned_equals_sequential() {
    let max = equals_sequential::<f32>(TOL_F32);
    eprintln!("f32: {max:?}");
}

fn equals_sequential<T: Real>(tol: Tol) -> MaxDiff {
    let n = 2014;
    let mut max = MaxDiff::default();
    for groups in [1, 2, 3] {
        let layout = Layout::new(n, groups).unwrap();
        assert_ne!(layout.rem, 0);
        let mut bonds: Vec<usize> = vec![0, 1, 2, 700, 701, n - 1];
        bonds.extend(boundary_gaps(&layout, n).into_iter().skip(3).step_by(4));
        bonds.sort();
        bonds.dedup();
        for model in models() {
            let c = chain(
                n,
                7 + groups as u64,
                &[],
                if model.clusters { &bonds } else { &[] },
            );
            for h in [1e-4, 3e-3] {
                let label = format!("{model:?}, groups {groups}, h {h}");
                let seq = step_as::<T>(&c, model, h, None, SimdLevel::widest_here());
                let part = step_as::<T>(&c, model, h, Some(layout), SimdLevel::widest_here());
                max = max.max(assert_close(&label, &part, &seq, tol));
            }
        }
    }
    max
}

/// Near contact: gaps of 1e-300 (stored as ln d) at and next to segment boundaries, at the
/// walls and inside segments, with clusters too: the rates of those gaps (and so ln d')
/// agree, and the fix-up runs.
#[test]
fn near_contact_equals_sequential() {
    let max = near_contact::<f64>(TOL);
    eprintln!("f64: {max:?}");
}

/// [`near_contact_equals_sequential`] in f32 (1e-300 is stored as its ln there too).
#[test]
fn f32_near_contact_equals_sequential() {
    let max = near_contact::<f32>(TOL_F32);
    eprintln!("f32: {max:?}");
}

fn near_contact<T: Real>(tol: Tol) -> MaxDiff {
    let n = 1777;
    let layout = Layout::new(n, 2).unwrap();
    let mut near = boundary_gaps(&layout, n);
    near.extend([5, 300, 301, 302]);
    near.sort();
    near.dedup();
    let bonds = [1000, 1001, 1500];
    let mut max = MaxDiff::default();
    for model in models() {
        let c = chain(n, 3, &near, if model.clusters { &bonds } else { &[] });
        for h in [1e-5, 1e-3] {
            let label = format!("near contact, {model:?}, h {h}");
            let seq = step_as::<T>(&c, model, h, None, SimdLevel::widest_here());
            let part = step_as::<T>(&c, model, h, Some(layout), SimdLevel::widest_here());
            // The case took the log form (the gaps stay below GAP_FLOOR).
            assert!(seq.0[near[3]] < 0.0, "{label}: not log-stored");
            max = max.max(assert_close(&label, &part, &seq, tol));
        }
    }
    max
}

/// The default layout just above the threshold (and the threshold itself) through
/// `Layout::for_chain`, with repulsion and clusters.
#[test]
fn default_layout_just_above_threshold() {
    let max = just_above_threshold::<f64>(TOL);
    eprintln!("f64: {max:?}");
}

/// [`default_layout_just_above_threshold`] in f32: the default takes the partitioned solve
/// there too.
#[test]
fn f32_default_layout_just_above_threshold() {
    let max = just_above_threshold::<f32>(TOL_F32);
    eprintln!("f32: {max:?}");
}

fn just_above_threshold<T: Real>(tol: Tol) -> MaxDiff {
    assert_eq!(Layout::for_chain(PARTITION_MIN_PARTICLES - 1), None);
    assert_eq!(default_layout::<1>(PARTITION_MIN_PARTICLES - 1, true), None);
    let mut max = MaxDiff::default();
    for n in [PARTITION_MIN_PARTICLES, PARTITION_MIN_PARTICLES + 37] {
        let layout = Layout::for_chain(n).expect("partitioned above the threshold");
        assert!(
            layout.seg >= SEGMENT_ROWS && layout.groups >= 2,
            "{layout:?}"
        );
        // What `euler_step` takes for one member in either precision (and a block of
        // several keeps the sequential sweep).
        assert_eq!(default_layout::<1>(n, true), Some(layout));
        assert_eq!(default_layout::<8>(n, true), None);
        // `ROUGHLUB_CPU_PARTITION=off` (Terms::partition false) keeps the sequential sweep.
        assert_eq!(default_layout::<1>(n, false), None);
        let model = Model {
            gamma: Some(2.0),
            clusters: true,
            forced: false,
            exact: true,
        };
        let c = chain(n, 11, &[n / 2], &[n / 3, n / 3 + 1]);
        let seq = step_as::<T>(&c, model, 1e-4, None, SimdLevel::widest_here());
        let part = step_as::<T>(&c, model, 1e-4, Some(layout), SimdLevel::widest_here());
        max = max.max(assert_close(&format!("n {n}"), &part, &seq, tol));
    }
    max
}

/// A long chain (just above the threshold, the default layout) at a realistic step: the
/// velocity solve is ill-conditioned at large N (cond ~ 4 mu h/(d·2eps) ~ 1e7 at N = 1e5),
/// which both solves share; they still agree to 1e-12.
#[test]
fn long_chain_equals_sequential() {
    let max = long_chain::<f64>(TOL);
    eprintln!("f64: {max:?}");
}

/// [`long_chain_equals_sequential`] in f32.
#[test]
fn f32_long_chain_equals_sequential() {
    let max = long_chain::<f32>(TOL_F32);
    eprintln!("f32: {max:?}");
}

fn long_chain<T: Real>(tol: Tol) -> MaxDiff {
    let n = PARTITION_MIN_PARTICLES + 1000;
    let layout = Layout::for_chain(n).unwrap();
    let model = Model {
        gamma: Some(2.0),
        clusters: false,
        forced: false,
        exact: true,
    };
    let c = chain(n, 21, &[], &[]);
    let seq = step_as::<T>(&c, model, 1e-4, None, SimdLevel::widest_here());
    let part = step_as::<T>(&c, model, 1e-4, Some(layout), SimdLevel::widest_here());
    assert_close("N = 2^18 + 1000", &part, &seq, tol)
}

/// Results do not depend on the thread count (1 or 2 rayon threads), nor on the SIMD level
/// (the widest here, AVX2 + FMA and portable: the tiles' transposes against scalar copies):
/// bit for bit.
#[test]
fn bitwise_equal_across_threads_and_simd_levels() {
    bitwise_equal::<f64>();
}

/// [`bitwise_equal_across_threads_and_simd_levels`] in f32 (8×8 transposes).
#[test]
fn f32_bitwise_equal_across_threads_and_simd_levels() {
    bitwise_equal::<f32>();
}

fn bitwise_equal<T: Real>() {
    let n = 3001;
    let layout = Layout::new(n, 4).unwrap();
    let model = Model {
        gamma: Some(2.0),
        clusters: true,
        forced: true,
        exact: true,
    };
    let c = chain(n, 5, &[10, 2000], &[400, 401]);
    let bits = |o: &Outcome| -> Vec<u64> {
        o.0.iter()
            .chain(&o.1)
            .chain([&o.2.energy, &o.2.work])
            .map(|v| v.to_bits())
            .collect()
    };
    let run = |threads: usize, simd: SimdLevel| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| bits(&step_as::<T>(&c, model, 1e-3, Some(layout), simd)))
    };
    let p = T::NAME;
    let one = run(1, SimdLevel::widest_here());
    assert_eq!(one, run(2, SimdLevel::widest_here()), "{p}: 1 vs 2 threads");
    assert_eq!(
        one,
        run(2, SimdLevel::Portable),
        "{p}: detected vs portable"
    );
    if SimdLevel::Avx2Fma <= SimdLevel::widest_here() {
        assert_eq!(
            one,
            run(2, SimdLevel::Avx2Fma),
            "{p}: detected vs AVX2 + FMA"
        );
    }
    // And it is not the sequential sweep's result (the partitioned solve ran).
    assert_ne!(
        one,
        bits(&step_as::<T>(
            &c,
            model,
            1e-3,
            None,
            SimdLevel::widest_here()
        )),
        "{p}: partitioned equals sequential bit for bit"
    );
}

/// A non-finite repulsion is found as by the sequential sweep (the hard-failure lookup).
#[test]
fn hard_failure_is_reported() {
    hard_failure::<f64>(1e300, 200.0);
}

/// [`hard_failure_is_reported`] in f32: d* = 1e30 (1e300 is beyond f32), gamma 20 (the
/// other gaps' G, up to 2.6^gamma, must stay finite in f32).
#[test]
fn f32_hard_failure_is_reported() {
    hard_failure::<f32>(1e30, 20.0);
}

fn hard_failure<T: Real>(dstar: f64, gamma: f64) {
    let n = 1500;
    let layout = Layout::new(n, 1).unwrap();
    let mut c = chain(n, 9, &[], &[]);
    c.dstar[900] = dstar;
    let model = Model {
        gamma: Some(gamma),
        clusters: false,
        forced: false,
        exact: true,
    };
    let seq = step_as::<T>(&c, model, 1e-4, None, SimdLevel::widest_here());
    let part = step_as::<T>(&c, model, 1e-4, Some(layout), SimdLevel::widest_here());
    assert!(matches!(
        seq.2.hard,
        Some(HardFailure::Repulsion { gap: 901, .. })
    ));
    assert_eq!(part.2.hard, seq.2.hard);
}

/// The f32 flush threshold is the GPU's f32 one (and far above f32's subnormals: checked
/// at compile time beside `TINY_F32`).
#[test]
fn f32_spike_tiny_is_the_gpus() {
    assert_eq!(
        f32::SPIKE_TINY as f64,
        crate::shared::gaps::SPIKE_TINY_F32 as f32 as f64
    );
    assert_eq!(f64::SPIKE_TINY, TINY);
}

/// The layout's index map is a bijection of the rows onto the scratch, with the chunks in
/// order.
#[test]
fn layout_indexes_every_row_once() {
    for (n, groups) in [(33, 2), (1000, 1), (1000, 3), (5000, 7)] {
        let layout = Layout::new(n, groups).unwrap();
        let mut seen = vec![false; n - 1];
        for row in 1..n {
            let k = layout.index_of(row);
            assert!(!seen[k], "n {n}: index {k} twice");
            seen[k] = true;
        }
        assert_eq!(layout.chunk(0).start, 0);
        assert_eq!(layout.chunk(groups - 1).end, n - 1);
        for g in 1..groups {
            assert_eq!(layout.chunk(g - 1).end, layout.chunk(g).start);
        }
    }
    assert_eq!(Layout::new(16, 1), None);
}
