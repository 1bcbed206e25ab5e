use super::*;

/// The fill at each instruction set this CPU runs gives the portable fill's band bit for bit
/// (moments and slot counts), on rows with NaN, infinities, values outside the range and a
/// grid that is not a multiple of the fill's block.
#[test]
fn every_instruction_set_fills_the_same_bits() {
    const G: usize = 2 * BLOCK + 13;
    let mut seed = 0x2545f4914f6cdd1du64;
    let mut next = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
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
