use super::*;
use crate::stored_gap;

/// A travelling wave amplitude·sin(2π(x − t)) + offset, integrated over a particle by the
/// 3-point Gauss–Legendre rule (as a scene's forcing with `quadrature = 3`).
pub(crate) struct Wave {
    pub amplitude: f64,
    pub offset: f64,
}

impl Forcing for Wave {
    fn particle_force(&self, _params: &[f64], eps: f64, t: f64, q: f64) -> f64 {
        let node = (0.6f64).sqrt();
        let f =
            |x: f64| self.amplitude * (2.0 * std::f64::consts::PI * (x - t)).sin() + self.offset;
        eps * (5.0 / 9.0 * f(q - eps * node) + 8.0 / 9.0 * f(q) + 5.0 / 9.0 * f(q + eps * node))
    }
}

const N: usize = 37;
const L: usize = 8;

/// One block's inputs: gaps of very different sizes (unless `mild`: one below GAP_FLOOR,
/// stored as ln d; with clusters some bonded), velocities, d* and the per-lane mu and h
/// (unless `mild`, one h large enough for the exp branch and the fix-up). A mild step is
/// certified, the other is not.
struct Case {
    gaps: Vec<f64>,
    vel: Vec<f64>,
    dstar: Vec<f64>,
    bonded: Vec<bool>,
    mu: [f64; L],
    h: [f64; L],
}

fn case(clusters: bool, mild: bool) -> Case {
    let wave = |k: usize, a: f64| (a * (k as f64 + 1.0)).sin();
    let mut gaps: Vec<f64> = (0..N * L).map(|k| 0.02 * (1.2 + wave(k, 0.37))).collect();
    let mut bonded = vec![false; N * L];
    if !mild {
        gaps[5 * L + 3] = stored_gap::encode(1e-300, GAP_FLOOR);
        gaps[9 * L + 6] = 1e-12;
    }
    if clusters {
        for k in [L + 2, 2 * L + 2, 20 * L + 5, 4] {
            gaps[k] = 0.0;
            bonded[k] = true;
        }
    }
    Case {
        gaps,
        vel: (0..(N - 1) * L).map(|k| 0.5 * wave(k, 0.11)).collect(),
        dstar: (0..N * L).map(|k| 0.02 * (1.1 + wave(k, 0.53))).collect(),
        bonded,
        mu: std::array::from_fn(|l| 0.01 * (1.0 + l as f64)),
        h: std::array::from_fn(|l| match (mild, l) {
            (true, _) => 1e-4 * (1.0 + l as f64),
            (false, 7) => 0.5,
            _ => 1e-3 * (1.0 + l as f64),
        }),
    }
}

type Outcome = (Vec<u64>, Vec<u64>, Vec<StepReport>);

/// One step of lanes `lanes` of the case as a block of M lanes at the given level, in T (the
/// case's values rounded to T; results as the bits of their exact f64 values).
fn step<T: Real, const M: usize>(
    simd: SimdLevel,
    c: &Case,
    lanes: [usize; M],
    gamma: Option<Gamma<M>>,
    clusters: bool,
    forcing: Option<&Wave>,
    exact: bool,
) -> Outcome {
    let pick = |v: &[f64], rows: usize| -> Vec<T> {
        (0..rows * M)
            .map(|k| T::c(v[(k / M) * L + lanes[k % M]]))
            .collect()
    };
    let gaps = pick(&c.gaps, N);
    let vel = pick(&c.vel, N - 1);
    let dstar = pick(&c.dstar, N);
    let bonded: Vec<bool> = (0..N * M)
        .map(|k| c.bonded[(k / M) * L + lanes[k % M]])
        .collect();
    let eps = 0.5 / N as f64;
    let terms = Terms::<M, T> {
        eps: T::c(eps),
        mu: lanes.map(|l| T::c(c.mu[l])),
        total_gap: std::array::from_fn(|m| {
            (0..N)
                .map(|i| stored_gap::decode(gaps[i * M + m].to_f64()))
                .sum()
        }),
        contact_repulsion: [5.0; M],
        exact_jacobian: exact,
        energy: EnergyWanted::UnlessCertified,
        repulsion: gamma.map(|g| (dstar.as_slice(), g)),
        bonded: clusters.then_some(bonded.as_slice()),
        forcing: forcing.map(|f| f as &dyn Forcing),
        forcing_params: [&[]; M],
        simd: SimdLevel::widest_here(),
        partition: true,
    };
    let h = lanes.map(|l| T::c(c.h[l]));
    let t = [0.25; M];
    let mut gaps_out = vec![T::ZERO; N * M];
    let mut vel_out = vec![T::ZERO; (N - 1) * M];
    let mut scratch = Scratch::new(N, M);
    let report = euler_step_as(
        simd,
        default_layout::<M>(N, true),
        &terms,
        N,
        &t,
        &h,
        StepBuffers {
            gaps_in: &gaps,
            vel_in: &vel,
            gaps_out: &mut gaps_out,
            vel_out: &mut vel_out,
            scratch: &mut scratch,
        },
    );
    (
        gaps_out.iter().map(|x| x.to_f64().to_bits()).collect(),
        vel_out.iter().map(|x| x.to_f64().to_bits()).collect(),
        report.to_vec(),
    )
}

/// A variant: its label, gamma, clusters, forcing and whether the Jacobian is exact.
type Variant = (String, Option<Gamma<L>>, bool, Option<Wave>, bool);

/// Every combination of the terms the step specialises on or tests at run time.
fn variants() -> Vec<Variant> {
    let gammas: [(&str, Option<Gamma<L>>); 5] = [
        ("none", None),
        ("2", Some(Gamma::Uniform(Power::Integer(2)))),
        ("5", Some(Gamma::Uniform(Power::Integer(5)))),
        ("1.5", Some(Gamma::Uniform(Power::Real(1.5)))),
        (
            "per lane",
            Some(Gamma::PerLane(std::array::from_fn(|l| {
                1.0 + 0.5 * l as f64
            }))),
        ),
    ];
    let mut out = Vec::new();
    for (name, gamma) in gammas {
        for clusters in [false, true] {
            for forced in [false, true] {
                for exact in [false, true] {
                    let forcing = forced.then_some(Wave {
                        amplitude: 0.3,
                        offset: 0.0,
                    });
                    let label = format!(
                        "gamma {name}, clusters {clusters}, forcing {forced}, exact Jacobian {exact}"
                    );
                    out.push((label, gamma, clusters, forcing, exact));
                }
            }
        }
    }
    out
}

/// The run-time SIMD level changes the speed only: AVX2 + FMA and AVX-512 give the portable
/// path's results bit for bit (no contraction into fma, the same operations in the same
/// order).
#[test]
fn wide_simd_paths_equal_portable_path_bitwise() {
    let levels: Vec<SimdLevel> = [SimdLevel::Avx2Fma, SimdLevel::Avx512]
        .into_iter()
        .filter(|&s| s <= SimdLevel::widest_here())
        .collect();
    if levels.is_empty() {
        eprintln!("no AVX2 + FMA here: nothing to compare");
        return;
    }
    for level in levels {
        wide_equals_portable::<f64>(level);
        wide_equals_portable::<f32>(level);
    }
}

fn wide_equals_portable<T: Real>(level: SimdLevel) {
    let all = std::array::from_fn(|l| l);
    for (label, gamma, clusters, forcing, exact) in variants() {
        for mild in [false, true] {
            let c = case(clusters, mild);
            let f = forcing.as_ref();
            let portable = step::<T, L>(SimdLevel::Portable, &c, all, gamma, clusters, f, exact);
            let wide = step::<T, L>(level, &c, all, gamma, clusters, f, exact);
            let (p, name) = (T::NAME, level.name());
            assert!(
                portable == wide,
                "{p}: {label}, mild {mild}: {name} and portable differ"
            );
            // Both ends of the step ran: the certified projection, the energy (a bonded
            // gap goes through the fix-up, which the certificate leaves out; with repulsion
            // the exact Jacobian's steps are not certified).
            assert_eq!(
                portable.2.iter().all(|r| r.certified),
                mild && !clusters && !(exact && gamma.is_some()),
                "{p}: {label}, mild {mild}"
            );
        }
    }
}

/// A lane's result does not depend on the block it sits in or its place there: each lane of
/// a block of 8 equals the same member stepped alone (L = 1), bit for bit.
#[test]
fn lanes_are_independent_of_their_block() {
    lanes_independent::<f64>();
    lanes_independent::<f32>();
}

fn lanes_independent<T: Real>() {
    for (label, gamma, clusters, forcing, exact) in variants() {
        let label = format!("{}: {label}", T::NAME);
        let c = case(clusters, false);
        let all = std::array::from_fn(|l| l);
        let block = step::<T, L>(
            SimdLevel::widest_here(),
            &c,
            all,
            gamma,
            clusters,
            forcing.as_ref(),
            exact,
        );
        for l in 0..L {
            let alone_gamma = gamma.map(|g| {
                Gamma::Uniform(match g {
                    Gamma::PerLane(gs) => Power::of(gs[l]),
                    Gamma::Uniform(p) => p,
                })
            });
            let alone = step::<T, 1>(
                SimdLevel::Portable,
                &c,
                [l],
                alone_gamma,
                clusters,
                forcing.as_ref(),
                exact,
            );
            let gaps: Vec<u64> = block.0.iter().skip(l).step_by(L).copied().collect();
            let vel: Vec<u64> = block.1.iter().skip(l).step_by(L).copied().collect();
            assert_eq!(gaps, alone.0, "{label}: gaps of lane {l}");
            assert_eq!(vel, alone.1, "{label}: velocities of lane {l}");
            // A block computes every lane's energy when one lane needs it, so only the
            // energy's value (where both have it) must agree, not whether it was computed.
            let (b, a) = (block.2[l], alone.2[0]);
            assert_eq!(
                (b.admissible, b.hard, b.work),
                (a.admissible, a.hard, a.work),
                "{label}: report of lane {l}"
            );
            if b.energy >= 0.0 && a.energy >= 0.0 {
                assert_eq!(b.energy.to_bits(), a.energy.to_bits(), "{label}: lane {l}");
            }
        }
    }
}
