use super::*;
use crate::test_rng::uniform_stream;

/// The fill at each instruction set this CPU runs gives the portable fill's band bit for bit
/// (moments and slot counts), on rows with NaN, infinities, values outside the range and a
/// grid that is not a multiple of the fill's block.
#[test]
fn every_instruction_set_fills_the_same_bits() {
    const G: usize = 2 * BLOCK + 13;
    let mut next = uniform_stream(0x2545f4914f6cdd1d);
    let data: Vec<Vec<f64>> = (0..300)
        .map(|m| {
            (0..G)
                .map(|j| match (m % 37, j % 29) {
                    (3, 5) => f64::NAN,
                    (4, 6) => f64::INFINITY,
                    (5, 7) => f64::NEG_INFINITY,
                    // Around the range [0, 1]: underflow, overflow and the edges themselves.
                    (6, _) => [0.0, 1.0, -1e-300, 1.0 + 1e-15][j % 4],
                    _ => 1.3 * next() - 0.15,
                })
                .collect()
        })
        .collect();
    let rows: Vec<&[f64]> = data.iter().map(|r| &r[..]).collect();
    let band_at = |level: SimdLevel| {
        let mut band = FieldBand::new(G, 0.0, 1.0, 50).unwrap();
        // Two pushes, so that the second merges into moments already held.
        band.push_rows_at(level, &rows[..117]).unwrap();
        band.push_rows_at(level, &rows[117..]).unwrap();
        band
    };
    let portable = band_at(SimdLevel::Portable);
    let bits = |band: &FieldBand| -> Vec<u64> {
        band.points
            .iter()
            .flat_map(|p| {
                [p.mean(), p.variance(), p.min(), p.max()]
                    .map(f64::to_bits)
                    .into_iter()
                    .chain([p.count(), p.non_finite()])
            })
            .collect()
    };
    // Independent of the fill: every finite value in [0, 1] lands in some bin, and the counts
    // over a point's slots are its finite values.
    let finite_at = |j: usize| rows.iter().filter(|r| r[j].is_finite()).count() as u64;
    for j in 0..G {
        let counted: u64 = portable.point_slots(j).iter().map(|&c| u64::from(c)).sum();
        assert_eq!(counted, finite_at(j), "point {j}");
        assert_eq!(portable.points[j].count(), finite_at(j), "point {j}");
    }
    for level in [SimdLevel::Avx2Fma, SimdLevel::Avx512] {
        if level > SimdLevel::widest_here() {
            eprintln!("{} not run: this CPU lacks it", level.name());
            continue;
        }
        let band = band_at(level);
        assert_eq!(bits(&band), bits(&portable), "{}", level.name());
        assert_eq!(band.slots, portable.slots, "{}", level.name());
    }
}

/// Rows of G points around the range [0, 1] (NaN, infinities, underflow, overflow, the edges).
fn test_rows(count: usize, g: usize, seed: u64) -> Vec<Vec<f64>> {
    let mut next = uniform_stream(seed);
    (0..count)
        .map(|m| {
            (0..g)
                .map(|j| match (m % 7, j % 11) {
                    (3, 5) => f64::NAN,
                    (4, 6) => f64::INFINITY,
                    (5, 7) => [0.0, 1.0, -1e-300, 1.0 + 1e-15][j % 4],
                    _ => 1.3 * next() - 0.15,
                })
                .collect()
        })
        .collect()
}

/// A band holding few rows (their slots kept as they are) reads the same counts as one that
/// counted them: per point a histogram filled value by value with `Histogram::push`, the same
/// quantiles and the same state file (CBOR and JSON), through every way of merging held and
/// counted bands, and past the number of rows it holds.
#[test]
fn held_rows_read_as_the_counts_they_stand_for() {
    const G: usize = BLOCK + 9;
    let (lo, hi, bins) = (0.0, 1.0, 50);
    let data = test_rows(40, G, 0x9e3779b97f4a7c15);
    let rows: Vec<&[f64]> = data.iter().map(|r| &r[..]).collect();
    let qs = [0.0, 0.05, 0.5, 0.5, 0.95, 1.0];
    let cbor = |band: &FieldBand| {
        let mut bytes = Vec::new();
        ciborium::into_writer(band, &mut bytes).unwrap();
        bytes
    };
    // Independent of the band: each point's finite values pushed one by one.
    let expected = |rows: &[&[f64]], j: usize| {
        let mut h = Histogram::new(lo, hi, bins).unwrap();
        for r in rows {
            h.push(r[j]);
        }
        (
            h.underflow(),
            h.counts().to_vec(),
            h.overflow(),
            h.non_finite(),
        )
    };
    let read = |band: &FieldBand, j: usize| {
        let h = band.histogram(j);
        (
            h.underflow(),
            h.counts().to_vec(),
            h.overflow(),
            h.non_finite(),
        )
    };
    // 13 rows at most are held with 52 slots a point.
    let mut held = FieldBand::new(G, lo, hi, bins).unwrap();
    assert_eq!(held.max_held_rows(), 13);
    for r in rows[..10].chunks(3) {
        held.push_rows(r).unwrap();
    }
    assert!(!held.dense && held.held_rows == 10);
    let mut counted = held.clone();
    counted.make_dense();
    assert!(counted.dense);
    for j in 0..G {
        assert_eq!(read(&held, j), expected(&rows[..10], j), "held, point {j}");
        assert_eq!(
            read(&counted, j),
            expected(&rows[..10], j),
            "counted, point {j}"
        );
    }
    let q_bits = |band: &FieldBand| -> Vec<u64> {
        let rows = band.quantile_rows(&qs).unwrap();
        rows.iter().flatten().map(|v| v.to_bits()).collect()
    };
    assert_eq!(q_bits(&held), q_bits(&counted));
    assert_eq!(cbor(&held), cbor(&counted));
    assert_eq!(
        serde_json::to_string(&held).unwrap(),
        serde_json::to_string(&counted).unwrap()
    );
    // Read back, a held band's state gives the counts it stood for.
    let back: FieldBand = ciborium::from_reader(&cbor(&held)[..]).unwrap();
    assert_eq!(q_bits(&back), q_bits(&held));

    // Merges: held + held (13 rows, still held), held + held past 13, counted + held,
    // held + counted; each against the counts of all its rows.
    let band_of = |rows: &[&[f64]], dense: bool| {
        let mut b = FieldBand::new(G, lo, hi, bins).unwrap();
        b.push_rows(rows).unwrap();
        if dense {
            b.make_dense();
        }
        b
    };
    for (split, end, dense_a, dense_b, dense_after) in [
        (10, 13, false, false, false),
        (10, 20, false, false, true),
        (10, 13, true, false, true),
        (10, 13, false, true, true),
        (5, 40, false, false, true),
    ] {
        let mut a = band_of(&rows[..split], dense_a);
        a.merge(&band_of(&rows[split..end], dense_b)).unwrap();
        assert_eq!(a.dense, dense_after, "{split}..{end}");
        for j in 0..G {
            assert_eq!(
                read(&a, j),
                expected(&rows[..end], j),
                "{split}..{end}, point {j}"
            );
        }
    }
    // Pushes past 13 rows count them all.
    let mut grown = FieldBand::new(G, lo, hi, bins).unwrap();
    for r in rows.chunks(6) {
        grown.push_rows(r).unwrap();
    }
    assert!(grown.dense);
    for j in 0..G {
        assert_eq!(read(&grown, j), expected(&rows, j), "grown, point {j}");
    }
    // Taking rows out of a held band leaves the counts of the others.
    let mut undone = band_of(&rows[..10], false);
    let before = band_of(&rows[..6], false);
    undone.undo_pushes(before.stats(), &rows[6..10]).unwrap();
    for j in 0..G {
        assert_eq!(
            read(&undone, j),
            expected(&rows[..6], j),
            "undone, point {j}"
        );
    }
}
