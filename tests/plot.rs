//! Tests of the PNG plots: real PNG files of the requested size, errors (not panics) on bad input.

use std::path::Path;

use roughlub::plot::{
    plot_band, plot_histogram, plot_profiles, plot_series, plot_work_precision, BandPlot,
    PlotError, ProfilePlot,
};

const PNG_SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', 0x0d, 0x0a, 0x1a, 0x0a];

/// Checks the file is a PNG and returns (width, height) from its IHDR chunk.
fn png_size(path: &Path) -> (u32, u32) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("cannot read {path:?}: {e}"));
    assert!(bytes.len() > 33, "{path:?} is too short to be a PNG");
    assert_eq!(
        bytes[..8],
        PNG_SIGNATURE,
        "{path:?} lacks the PNG signature"
    );
    // First chunk: 4-byte length (13), "IHDR", width and height as big-endian u32.
    assert_eq!(u32::from_be_bytes(bytes[8..12].try_into().unwrap()), 13);
    assert_eq!(&bytes[12..16], b"IHDR", "{path:?}: first chunk is not IHDR");
    let width = u32::from_be_bytes(bytes[16..20].try_into().unwrap());
    let height = u32::from_be_bytes(bytes[20..24].try_into().unwrap());
    // The file must end with the IEND chunk.
    assert_eq!(
        &bytes[bytes.len() - 8..bytes.len() - 4],
        b"IEND",
        "{path:?}: no IEND chunk"
    );
    (width, height)
}

/// Copies a plot to $ROUGHLUB_PLOT_TEST_KEEP (when set) to look at it.
fn keep(path: &Path, name: &str) {
    if let Ok(dir) = std::env::var("ROUGHLUB_PLOT_TEST_KEEP") {
        std::fs::copy(path, Path::new(&dir).join(name)).unwrap();
    }
}

/// Grid, times, rho, u, rho_star.
type Profiles = (Vec<f64>, Vec<f64>, Rows, Rows, Rows);
type Rows = Vec<Vec<f64>>;

/// Synthetic profiles: a spreading density bump and a velocity wave, on a grid of `g` points at
/// `t` times.
fn synthetic(g: usize, t: usize) -> Profiles {
    let x: Vec<f64> = (0..g).map(|i| (i as f64 + 0.5) / g as f64).collect();
    let times: Vec<f64> = (0..t).map(|k| 0.05 * k as f64).collect();
    let mut rho = Vec::new();
    let mut u = Vec::new();
    let mut rho_star = Vec::new();
    for &tk in &times {
        let w = 0.05 + tk;
        let r: Vec<f64> = x
            .iter()
            .map(|&xi| 0.2 + 0.6 * (-(xi - 0.5).powi(2) / (2.0 * w * w)).exp())
            .collect();
        rho_star.push(r.iter().map(|&v| 0.5 * v * v).collect());
        u.push(
            x.iter()
                .map(|&xi| (1.0 - tk) * (2.0 * std::f64::consts::PI * xi).sin() * 0.3)
                .collect(),
        );
        rho.push(r);
    }
    (x, times, rho, u, rho_star)
}

#[test]
fn profiles_png_has_requested_size() {
    let dir = tempfile::tempdir().unwrap();
    let (x, times, rho, u, rho_star) = synthetic(200, 6);
    let path = dir.path().join("profiles.png");
    let plot = ProfilePlot {
        title: "case1 — member 0 (mu = 0.01, gamma = 1)",
        x: &x,
        times: &times,
        rho: &rho,
        u: &u,
        rho_star: Some(&rho_star),
    };
    plot_profiles(&path, &plot).unwrap();
    assert_eq!(png_size(&path), (1000, 800));
    assert_eq!(roughlub::plot::PLOT_SIZE, (1000, 800));
    keep(&path, "profiles.png");
}

#[test]
fn profiles_with_many_times_nan_and_no_roughness() {
    let dir = tempfile::tempdir().unwrap();
    let (x, times, mut rho, mut u, _) = synthetic(64, 25);
    // A failed member: NaN from time 15 on, and a hole in one row.
    for k in 15..25 {
        rho[k].iter_mut().for_each(|v| *v = f64::NAN);
        u[k].iter_mut().for_each(|v| *v = f64::NAN);
    }
    rho[3][10] = f64::NAN;
    u[3][10] = f64::INFINITY;
    let path = dir.path().join("many.png");
    let plot = ProfilePlot {
        title: "many times",
        x: &x,
        times: &times,
        rho: &rho,
        u: &u,
        rho_star: None,
    };
    plot_profiles(&path, &plot).unwrap();
    assert_eq!(png_size(&path), (1000, 800));
    keep(&path, "many_times.png");
}

#[test]
fn profiles_degenerate_data_do_not_panic() {
    let dir = tempfile::tempdir().unwrap();
    let x = vec![0.5];
    let times = vec![0.0];
    let cases: Vec<(&str, Rows, Rows)> = vec![
        ("zero", vec![vec![0.0]], vec![vec![0.0]]),
        ("allnan", vec![vec![f64::NAN]], vec![vec![f64::NAN]]),
        ("const", vec![vec![0.4]], vec![vec![1e-300]]),
        ("big", vec![vec![3.0]], vec![vec![1e300]]),
    ];
    for (name, rho, u) in cases {
        let path = dir.path().join(format!("{name}.png"));
        let plot = ProfilePlot {
            title: name,
            x: &x,
            times: &times,
            rho: &rho,
            u: &u,
            rho_star: None,
        };
        plot_profiles(&path, &plot).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(png_size(&path), (1000, 800), "{name}");
        keep(&path, &format!("degenerate_{name}.png"));
    }
    // Values whose range overflows: an error, not a panic.
    let rho = vec![vec![0.5, 0.5]];
    let u = vec![vec![-1.7e308, 1.7e308]];
    let plot = ProfilePlot {
        title: "overflow",
        x: &[0.0, 1.0],
        times: &times,
        rho: &rho,
        u: &u,
        rho_star: None,
    };
    let e = plot_profiles(&dir.path().join("overflow.png"), &plot).unwrap_err();
    assert!(e.message.contains("too large"), "{e}");
}

fn profile_error(plot: &ProfilePlot) -> PlotError {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.png");
    let e = plot_profiles(&path, plot).unwrap_err();
    assert_eq!(e.path, path);
    assert!(!path.exists(), "no file should be written on bad input");
    e
}

#[test]
fn profiles_mismatched_lengths_are_errors() {
    let (x, times, rho, u, rho_star) = synthetic(10, 3);
    let base = ProfilePlot {
        title: "bad",
        x: &x,
        times: &times,
        rho: &rho,
        u: &u,
        rho_star: Some(&rho_star),
    };

    // Too few rho rows.
    let e = profile_error(&ProfilePlot {
        rho: &rho[..2],
        ..base
    });
    assert!(
        e.message.contains("rho has 2 rows") && e.message.contains("3 output times"),
        "{e}"
    );
    assert!(e.to_string().starts_with("cannot draw plot "), "{e}");

    // A u row of the wrong length.
    let mut u_bad = u.clone();
    u_bad[1].pop();
    let e = profile_error(&ProfilePlot { u: &u_bad, ..base });
    assert!(
        e.message.contains("u row 1 has 9 values") && e.message.contains("10 points"),
        "{e}"
    );

    // rho_star with an empty row.
    let mut rs_bad = rho_star.clone();
    rs_bad[2].clear();
    let e = profile_error(&ProfilePlot {
        rho_star: Some(&rs_bad),
        ..base
    });
    assert!(e.message.contains("rho_star row 2 has 0 values"), "{e}");

    // Empty grid, no times.
    let empty_rows = vec![Vec::new(); 3];
    let e = profile_error(&ProfilePlot {
        x: &[],
        rho: &empty_rows,
        u: &empty_rows,
        rho_star: None,
        ..base
    });
    assert!(e.message.contains("grid x is empty"), "{e}");
    let e = profile_error(&ProfilePlot {
        times: &[],
        rho: &[],
        u: &[],
        rho_star: None,
        ..base
    });
    assert!(e.message.contains("no output times"), "{e}");
}

#[test]
fn series_png_has_requested_size() {
    let dir = tempfile::tempdir().unwrap();
    let times: Vec<f64> = (0..50).map(|k| 0.02 * k as f64).collect();
    let series: Vec<(String, Vec<f64>)> = (0..4)
        .map(|m| {
            let mu = 0.01 * (m + 1) as f64;
            let mut v: Vec<f64> = times
                .iter()
                .map(|&t| 0.6 + 0.3 * (1.0 - (-t / mu / 20.0).exp()))
                .collect();
            if m == 3 {
                // Failed member.
                v[30..].iter_mut().for_each(|y| *y = f64::NAN);
            }
            (format!("member {m} (mu = {mu})"), v)
        })
        .collect();
    let path = dir.path().join("series.png");
    plot_series(&path, "case1 — max density", "max rho", &times, &series).unwrap();
    assert_eq!(png_size(&path), (1000, 800));
    keep(&path, "series.png");

    // Many series (legend thinned), constant data, a single time.
    let many: Vec<(String, Vec<f64>)> = (0..80).map(|m| (format!("m{m}"), vec![1.0])).collect();
    let path = dir.path().join("many.png");
    plot_series(&path, "many", "y", &[0.5], &many).unwrap();
    assert_eq!(png_size(&path), (1000, 800));
    keep(&path, "many_series.png");
}

#[test]
fn series_errors() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.png");
    let times = [0.0, 0.1, 0.2];
    let series = vec![
        ("a".to_string(), vec![1.0, 2.0, 3.0]),
        ("b".to_string(), vec![1.0, 2.0]),
    ];
    let e = plot_series(&path, "t", "y", &times, &series).unwrap_err();
    assert!(
        e.message.contains("series \"b\" has 2 values") && e.message.contains("3 output times"),
        "{e}"
    );
    assert_eq!(e.path, path);

    let e = plot_series(&path, "t", "y", &times, &[]).unwrap_err();
    assert!(e.message.contains("no series"), "{e}");
    let e = plot_series(&path, "t", "y", &[], &series[..0]).unwrap_err();
    assert!(e.message.contains("no output times"), "{e}");

    // An unwritable destination is an error too.
    let missing = dir.path().join("no/such/dir/x.png");
    assert!(plot_series(&missing, "t", "y", &times, &series[..1]).is_err());
    assert!(!path.exists());
}

/// Synthetic ensemble statistics: grid, times, mean, 5 % and 95 % quantiles, reference.
fn synthetic_band(g: usize, t: usize) -> (Vec<f64>, Vec<f64>, Rows, Rows, Rows, Rows) {
    let (x, times, rho, _, rho_star) = synthetic(g, t);
    let spread = |k: usize, xi: f64| 0.04 + 0.08 * k as f64 * (std::f64::consts::PI * xi).sin();
    let lower = rho
        .iter()
        .enumerate()
        .map(|(k, r)| {
            r.iter()
                .zip(&x)
                .map(|(&v, &xi)| v - spread(k, xi))
                .collect()
        })
        .collect();
    let upper = rho
        .iter()
        .enumerate()
        .map(|(k, r)| {
            r.iter()
                .zip(&x)
                .map(|(&v, &xi)| v + spread(k, xi))
                .collect()
        })
        .collect();
    (x, times, rho, lower, upper, rho_star)
}

#[test]
fn band_png_has_requested_size() {
    let dir = tempfile::tempdir().unwrap();
    let (x, times, mean, mut lower, mut upper, reference) = synthetic_band(200, 4);
    // NaN gaps: one bound missing over a stretch, and a single isolated finite point.
    lower[1][40..60].iter_mut().for_each(|v| *v = f64::NAN);
    upper[2][100..198].iter_mut().for_each(|v| *v = f64::NAN);
    upper[2][199] = f64::NAN;
    let path = dir.path().join("band.png");
    let plot = BandPlot {
        title: "case1 — density, ensemble mean",
        y_label: "rho",
        x: &x,
        times: &times,
        mean: &mean,
        lower: &lower,
        upper: &upper,
        band_label: "5%-95% of members",
        reference: Some(&reference),
    };
    plot_band(&path, &plot).unwrap();
    assert_eq!(png_size(&path), (1000, 800));
    keep(&path, "band.png");

    // Data outside [0, 1], no reference, a single time.
    let shift = |rows: &Rows| -> Rows {
        rows.iter()
            .map(|r| r.iter().map(|v| v - 0.5).collect())
            .collect()
    };
    let (shifted, shifted_lower, shifted_upper) = (shift(&mean), shift(&lower), shift(&upper));
    let path = dir.path().join("band_signed.png");
    let plot = BandPlot {
        title: "velocity",
        y_label: "u",
        times: &times[..1],
        mean: &shifted[..1],
        lower: &shifted_lower[..1],
        upper: &shifted_upper[..1],
        reference: None,
        ..plot
    };
    plot_band(&path, &plot).unwrap();
    assert_eq!(png_size(&path), (1000, 800));
    keep(&path, "band_signed.png");
}

#[test]
fn band_degenerate_data_do_not_panic() {
    let dir = tempfile::tempdir().unwrap();
    let nan = f64::NAN;
    let cases: Vec<(&str, Vec<f64>, Rows, Rows, Rows)> = vec![
        (
            "one_point",
            vec![0.5],
            vec![vec![0.3]],
            vec![vec![0.2]],
            vec![vec![0.4]],
        ),
        (
            "all_nan",
            vec![0.2, 0.8],
            vec![vec![nan; 2]],
            vec![vec![nan; 2]],
            vec![vec![nan; 2]],
        ),
        (
            "const",
            vec![3.0, 3.0],
            vec![vec![5.0; 2]],
            vec![vec![5.0; 2]],
            vec![vec![5.0; 2]],
        ),
        (
            "crossed",
            vec![0.0, 0.5, 1.0],
            vec![vec![0.5; 3]],
            vec![vec![0.9, nan, 0.9]],
            vec![vec![0.1, 0.2, f64::INFINITY]],
        ),
    ];
    for (name, x, mean, lower, upper) in cases {
        let path = dir.path().join(format!("{name}.png"));
        let plot = BandPlot {
            title: name,
            y_label: "y",
            x: &x,
            times: &[0.0],
            mean: &mean,
            lower: &lower,
            upper: &upper,
            band_label: "band",
            reference: None,
        };
        plot_band(&path, &plot).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(png_size(&path), (1000, 800), "{name}");
    }
    let huge = vec![vec![-1.7e308, 1.7e308]];
    let plot = BandPlot {
        title: "overflow",
        y_label: "y",
        x: &[0.0, 1.0],
        times: &[0.0],
        mean: &huge,
        lower: &huge,
        upper: &huge,
        band_label: "band",
        reference: None,
    };
    let e = plot_band(&dir.path().join("overflow.png"), &plot).unwrap_err();
    assert!(e.message.contains("too large"), "{e}");
}

fn band_error(plot: &BandPlot) -> PlotError {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.png");
    let e = plot_band(&path, plot).unwrap_err();
    assert_eq!(e.path, path);
    assert!(!path.exists(), "no file should be written on bad input");
    e
}

#[test]
fn band_mismatched_lengths_are_errors() {
    let (x, times, mean, lower, upper, reference) = synthetic_band(10, 3);
    let base = BandPlot {
        title: "bad",
        y_label: "rho",
        x: &x,
        times: &times,
        mean: &mean,
        lower: &lower,
        upper: &upper,
        band_label: "band",
        reference: Some(&reference),
    };
    let e = band_error(&BandPlot {
        mean: &mean[..2],
        ..base
    });
    assert!(
        e.message.contains("mean has 2 rows") && e.message.contains("3 output times"),
        "{e}"
    );
    let mut upper_bad = upper.clone();
    upper_bad[1].push(0.0);
    let e = band_error(&BandPlot {
        upper: &upper_bad,
        ..base
    });
    assert!(
        e.message.contains("upper row 1 has 11 values") && e.message.contains("10 points"),
        "{e}"
    );
    let e = band_error(&BandPlot {
        lower: &lower[..0],
        ..base
    });
    assert!(e.message.contains("lower has 0 rows"), "{e}");
    let e = band_error(&BandPlot {
        reference: Some(&reference[1..]),
        ..base
    });
    assert!(e.message.contains("reference has 2 rows"), "{e}");
    let e = band_error(&BandPlot { x: &[], ..base });
    assert!(e.message.contains("grid x is empty"), "{e}");
    let e = band_error(&BandPlot {
        times: &[],
        mean: &[],
        lower: &[],
        upper: &[],
        reference: None,
        ..base
    });
    assert!(e.message.contains("no times"), "{e}");
}

#[test]
fn histogram_png_has_requested_size() {
    let dir = tempfile::tempdir().unwrap();
    let edges: Vec<f64> = (0..=20).map(|i| 0.05 * i as f64).collect();
    let counts: Vec<u64> = (0..20u64).map(|i| (i * (20 - i)) / 6).collect();
    let path = dir.path().join("histogram.png");
    plot_histogram(
        &path,
        "case1 — time to reach rho = 0.9",
        "t",
        &edges,
        &counts,
        Some("12 members never reached 0.9"),
    )
    .unwrap();
    assert_eq!(png_size(&path), (1000, 800));
    keep(&path, "histogram.png");

    // All zero counts, one bin, no note; huge counts; a multi-line note.
    let path = dir.path().join("zero.png");
    plot_histogram(&path, "zero", "x", &[1.0, 2.0], &[0], None).unwrap();
    assert_eq!(png_size(&path), (1000, 800));
    let path = dir.path().join("huge.png");
    plot_histogram(
        &path,
        "huge",
        "x",
        &[-1e9, 0.0, 1e9],
        &[u64::MAX, 3],
        Some("a\nb"),
    )
    .unwrap();
    assert_eq!(png_size(&path), (1000, 800));
    keep(&path, "histogram_huge.png");
    let path = dir.path().join("empty_note.png");
    plot_histogram(&path, "", "", &[0.0, 1e-300], &[1], Some("")).unwrap();
    assert_eq!(png_size(&path), (1000, 800));
}

#[test]
fn histogram_errors() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.png");
    let e = plot_histogram(&path, "h", "x", &[0.0, 1.0, 2.0], &[1, 2, 3], None).unwrap_err();
    assert!(e.message.contains("3 bin edges but 3 counts"), "{e}");
    assert_eq!(e.path, path);
    let e = plot_histogram(&path, "h", "x", &[0.0], &[], None).unwrap_err();
    assert!(e.message.contains("no bins"), "{e}");
    let e = plot_histogram(&path, "h", "x", &[0.0, f64::NAN], &[1], None).unwrap_err();
    assert!(e.message.contains("edge 1 is not finite"), "{e}");
    let e = plot_histogram(&path, "h", "x", &[0.0, 1.0, 1.0], &[1, 1], None).unwrap_err();
    assert!(e.message.contains("not strictly increasing"), "{e}");
    let e = plot_histogram(&path, "h", "x", &[-1.7e308, 1.7e308], &[1], None).unwrap_err();
    assert!(e.message.contains("too large"), "{e}");
    let e = plot_histogram(&path, "h", "x", &[1e10, 1e10 + 1e-5], &[1], None).unwrap_err();
    assert!(e.message.contains("too close"), "{e}");
    assert!(!path.exists());
}

/// The PNG's RGB pixels (8-bit) and width.
fn png_pixels(path: &Path) -> (Vec<u8>, usize) {
    let decoder = png::Decoder::new(std::fs::File::open(path).unwrap());
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb, "{path:?}");
    buf.truncate(info.buffer_size());
    (buf, info.width as usize)
}

/// Green channel at a fraction (fx, fy) of the picture (fy from the top).
fn green_at(pixels: &[u8], width: usize, fx: f64, fy: f64) -> u8 {
    let height = pixels.len() / (3 * width);
    let (x, y) = ((fx * width as f64) as usize, (fy * height as f64) as usize);
    pixels[3 * (y * width + x) + 1]
}

/// x–t maps: x across, t upwards, colours along the viridis-like map whose green channel grows
/// with the value (dark purple (68, 1, 84) at the minimum, yellow-green at the maximum). A field
/// growing in x is brighter on the right; one growing in t is brighter at the top; the thinned
/// picture of a long run keeps the first and last times.
#[test]
fn xt_maps_put_x_across_and_t_upwards() {
    let dir = tempfile::tempdir().unwrap();
    let x: Vec<f64> = (0..101).map(|i| i as f64 / 100.0).collect();
    let times: Vec<f64> = (0..1001).map(|k| k as f64 * 1e-3).collect();
    let in_x: Vec<Vec<f64>> = times.iter().map(|_| x.clone()).collect();
    let in_t: Vec<Vec<f64>> = times.iter().map(|&t| vec![t; x.len()]).collect();
    let px = dir.path().join("xt_x.png");
    let pt = dir.path().join("xt_t.png");
    roughlub::plot::plot_xt(&px, "rises in x", "rho", &x, &times, &in_x).unwrap();
    roughlub::plot::plot_xt(&pt, "rises in t", "rho", &x, &times, &in_t).unwrap();
    assert_eq!(png_size(&px), (1000, 800));
    keep(&px, "xt_x.png");
    keep(&pt, "xt_t.png");
    let (img, w) = png_pixels(&px);
    let (left, right) = (green_at(&img, w, 0.15, 0.5), green_at(&img, w, 0.75, 0.5));
    assert!(
        right as i32 - left as i32 > 80,
        "a field rising in x: green {left} on the left, {right} on the right"
    );
    let (img, w) = png_pixels(&pt);
    let (bottom, top) = (green_at(&img, w, 0.45, 0.85), green_at(&img, w, 0.45, 0.15));
    assert!(
        top as i32 - bottom as i32 > 80,
        "a field rising in t: green {bottom} at the bottom, {top} at the top"
    );
    let thinned = roughlub::plot::thinned_indices(1001, roughlub::plot::MAX_XT_CELLS.0);
    assert_eq!(thinned.len(), 400);
    assert_eq!((thinned[0], *thinned.last().unwrap()), (0, 1000));
    assert!(thinned.windows(2).all(|w| w[1] > w[0]));
}

/// The x–t map's pixels match the field: every cell's exact colour (the colour scale applied to
/// its value) fills a block of the picture, the blocks ordered by x from left to right and by
/// t from bottom to top.
#[test]
fn xt_map_pixels_match_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let x = [0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0];
    let times = [0.0, 0.5, 1.0];
    // Distinct values: 0.1 (x index) + 0.02 (t index), in [0.5, 0.84].
    let value = |i: usize, k: usize| 0.5 + 0.1 * i as f64 + 0.02 * k as f64;
    let rows: Vec<Vec<f64>> = (0..3)
        .map(|k| (0..4).map(|i| value(i, k)).collect())
        .collect();
    let path = dir.path().join("xt_cells.png");
    roughlub::plot::plot_xt(&path, "cells", "rho", &x, &times, &rows).unwrap();
    keep(&path, "xt_cells.png");
    let (img, w) = png_pixels(&path);
    let (lo, hi) = (value(0, 0), value(3, 2));
    let mut centres = vec![vec![(0.0, 0.0); 4]; 3];
    for k in 0..3 {
        for i in 0..4 {
            let want = roughlub::plot::heatmap_color(value(i, k), lo, hi);
            let (mut n, mut sx, mut sy) = (0usize, 0usize, 0usize);
            for (p, px) in img.chunks_exact(3).enumerate() {
                if px == want {
                    n += 1;
                    sx += p % w;
                    sy += p / w;
                }
            }
            assert!(
                n > 2000,
                "cell (x {i}, t {k}) = {}: its colour {want:?} fills only {n} pixels",
                value(i, k)
            );
            centres[k][i] = (sx as f64 / n as f64, sy as f64 / n as f64);
        }
    }
    for k in 0..3 {
        for i in 1..4 {
            assert!(
                centres[k][i].0 > centres[k][i - 1].0 + 50.0,
                "x order, row {k}: {centres:?}"
            );
        }
    }
    for i in 0..4 {
        for k in 1..3 {
            assert!(
                centres[k][i].1 + 50.0 < centres[k - 1][i].1,
                "t upwards, column {i}: {centres:?}"
            );
        }
    }
}

/// The work–precision figure writes each run's observed order by its point (issue 22, item 6):
/// the same line with and without orders differs by about as many pixels as two short numbers
/// take, right of the points that have one, and nowhere else.
#[test]
fn work_precision_points_carry_their_observed_order() {
    let dir = tempfile::tempdir().unwrap();
    let draw = |name: &str, orders: [Option<f64>; 3]| {
        let path = dir.path().join(name);
        let points = vec![
            (1e-3, 1e-4, orders[0]),
            (1e-2, 1e-6, orders[1]),
            (1e-1, 1e-8, orders[2]),
        ];
        plot_work_precision(
            &path,
            "wp",
            &[("order 4 fixed dt, cpu f64".to_string(), points)],
            Some(1e-6),
        )
        .unwrap();
        keep(&path, name);
        png_pixels(&path)
    };
    let (plain, width) = draw("plain.png", [None, None, None]);
    let (labelled, _) = draw("labelled.png", [None, Some(2.0), Some(2.0)]);
    let differing: Vec<usize> = (0..plain.len() / 3)
        .filter(|&i| plain[3 * i..3 * i + 3] != labelled[3 * i..3 * i + 3])
        .collect();
    // Two labels "2.0" at 13 px: tens to a few hundred pixels each.
    assert!(
        (40..=2000).contains(&differing.len()),
        "{} pixels differ",
        differing.len()
    );
    // Right of the middle point (at 41 % of the width, its label after it): none by the first
    // point, which has no order, nor in the legend (from about 75 %).
    let columns = differing.iter().map(|&i| i % width);
    assert!(
        columns
            .clone()
            .all(|x| x > 2 * width / 5 && x < 3 * width / 4),
        "a label away from its point: columns {:?}",
        (columns.clone().min(), columns.max())
    );
}
