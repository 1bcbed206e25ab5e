//! The fill of a study's field statistics (issue 23): `FieldBand::push_rows` of one chunk's rows
//! at one output time, as a study of 256 members per chunk on the default grid (200 points,
//! 400 bins) pushes them. Rows are smooth fields with a spread over members like a density's,
//! so the slots touched per point are a few dozen, as in a study.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use roughlub::stats::FieldBand;

fn rows(members: usize, grid: usize) -> Vec<Vec<f64>> {
    // A fixed pseudo-random spread (xorshift), so that runs compare.
    let mut state = 0x9e3779b97f4a7c15u64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..members)
        .map(|_| {
            let amplitude = 0.1 + 0.1 * next();
            (0..grid)
                .map(|j| {
                    let x = j as f64 / grid as f64;
                    0.7 + amplitude * (2.0 * std::f64::consts::PI * x).sin() + 0.01 * next()
                })
                .collect()
        })
        .collect()
}

fn field_band(c: &mut Criterion) {
    let (members, grid, bins) = (256, 200, 400);
    let data = rows(members, grid);
    let refs: Vec<&[f64]> = data.iter().map(|r| &r[..]).collect();
    let mut group = c.benchmark_group("field_band");
    group.throughput(Throughput::Elements((members * grid) as u64));
    // A study holds a band per (field, output time): 63 by default, pushed in turn, so each
    // push meets a band last touched 62 pushes before (in the outer caches, not L1/L2).
    let mut bands: Vec<FieldBand> = (0..63)
        .map(|_| FieldBand::new(grid, 0.0, 1.0, bins).expect("valid band"))
        .collect();
    for band in &mut bands {
        band.push_rows(&refs).expect("rows fit");
    }
    let mut turn = 0;
    group.bench_function("push_rows_256x200_bins400", |b| {
        b.iter(|| {
            turn = (turn + 1) % bands.len();
            bands[turn].push_rows(&refs).expect("rows fit")
        })
    });
    group.finish();
}

criterion_group!(benches, field_band);
criterion_main!(benches);
