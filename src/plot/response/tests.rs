use super::super::{plot_heatmap, plot_response, plot_scatter, PlotError, PLOT_SIZE};
use super::*;

/// (width, height) from the IHDR chunk of a PNG file (after checking the signature).
fn png_size(path: &Path) -> (u32, u32) {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(bytes[..8], [0x89, b'P', b'N', b'G', 0x0d, 0x0a, 0x1a, 0x0a]);
    assert_eq!(&bytes[12..16], b"IHDR");
    let be = |k: usize| u32::from_be_bytes(bytes[k..k + 4].try_into().unwrap());
    assert_eq!(&bytes[bytes.len() - 8..bytes.len() - 4], b"IEND");
    (be(16), be(20))
}

/// Copies a plot to $ROUGHLUB_PLOT_TEST_KEEP (when set) to look at it.
fn keep(path: &Path, name: &str) {
    if let Ok(dir) = std::env::var("ROUGHLUB_PLOT_TEST_KEEP") {
        std::fs::copy(path, Path::new(&dir).join(name)).unwrap();
    }
}

fn response<'a>(x: &'a [f64], m: &'a [f64], lo: &'a [f64], hi: &'a [f64]) -> ResponsePlot<'a> {
    ResponsePlot {
        title: "case1 — time to reach rho = 0.9 against mu",
        x_label: "mu",
        y_label: "t(rho = 0.9)",
        x,
        mean: m,
        lower: lo,
        upper: hi,
        band_label: "5%-95% of members",
        log_x: true,
    }
}

#[test]
fn response_png_has_plot_size() {
    let dir = tempfile::tempdir().unwrap();
    // Unsorted x over 4 decades, a failed point (NaN mean) and a missing band bound.
    let x = [1e-3, 1e-1, 3e-3, 1e-2, 3e-2, 3e-1, 1.0, 10.0];
    let mean: Vec<f64> = x.iter().map(|v: &f64| 2.0 + v.log10()).collect();
    let mut mean = mean;
    mean[4] = f64::NAN;
    let lower: Vec<f64> = mean.iter().map(|m| m - 0.4).collect();
    let mut upper: Vec<f64> = mean.iter().map(|m| m + 0.6).collect();
    upper[1] = f64::INFINITY;
    let path = dir.path().join("response.png");
    plot_response(&path, &response(&x, &mean, &lower, &upper)).unwrap();
    assert_eq!(png_size(&path), PLOT_SIZE);
    keep(&path, "response.png");

    // Linear axis, one point, all non-finite responses, a narrow log range.
    let path = dir.path().join("linear.png");
    let plot = ResponsePlot {
        log_x: false,
        ..response(&[0.5], &[1.0], &[0.5], &[2.0])
    };
    plot_response(&path, &plot).unwrap();
    assert_eq!(png_size(&path), PLOT_SIZE);
    let nan = [f64::NAN; 3];
    plot_response(&path, &response(&[1.0, 2.0, 3.0], &nan, &nan, &nan)).unwrap();
    plot_response(
        &path,
        &response(&[1.0, 1.1, 1.2], &[1.0; 3], &[0.0; 3], &[2.0; 3]),
    )
    .unwrap();
    assert_eq!(png_size(&path), PLOT_SIZE);
}

fn heatmap<'a>(xs: &'a [f64], ys: &'a [f64], values: &'a [Vec<f64>]) -> HeatmapPlot<'a> {
    HeatmapPlot {
        title: "case1 — mean time to reach rho = 0.9",
        x_label: "mu",
        y_label: "gamma",
        value_label: "t(rho = 0.9)",
        xs,
        ys,
        values,
        log_x: true,
        log_y: false,
    }
}

/// RGB of pixel (x, y) of a PLOT_SIZE buffer.
fn pixel(buf: &[u8], (x, y): (i32, i32)) -> (u8, u8, u8) {
    let k = 3 * (y as usize * PLOT_SIZE.0 as usize + x as usize);
    (buf[k], buf[k + 1], buf[k + 2])
}

#[test]
fn heatmap_png_and_cell_colours() {
    // values[j][i] = i + 10 j on 4 × 3 cells (xs given out of order), one NaN cell.
    let xs = [1e-3, 1e-1, 1e-2, 1.0];
    let ys = [0.5, 1.0, 2.0];
    let rank_x = [0.0, 2.0, 1.0, 3.0];
    let mut values: Vec<Vec<f64>> = (0..3)
        .map(|j| rank_x.iter().map(|&i| i + 10.0 * j as f64).collect())
        .collect();
    values[1][1] = f64::NAN;
    let plot = heatmap(&xs, &ys, &values);

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("heatmap.png");
    plot_heatmap(&path, &plot).unwrap();
    assert_eq!(png_size(&path), PLOT_SIZE);
    keep(&path, "heatmap.png");

    // The same drawing into a buffer. The text written in the cells is at their centres, so
    // the colours are read 20 pixels below the centre.
    let mut buf = vec![0u8; 3 * (PLOT_SIZE.0 * PLOT_SIZE.1) as usize];
    let centres = {
        let root = BitMapBackend::with_buffer(&mut buf, PLOT_SIZE).into_drawing_area();
        let centres = heatmap_on(&root, &plot, &HeatmapData::new(&plot).unwrap()).unwrap();
        root.present().unwrap();
        centres
    };
    let at = |i: usize, j: usize| {
        let (x, y) = centres[j][i];
        pixel(&buf, (x, y + 20))
    };
    // Bottom left (smallest x and y) holds the minimum 0: the colormap's dark end,
    // viridis (68, 1, 84). Top right (largest x and y) holds the maximum 23: viridis at
    // 0.88 (between (170, 220, 50) and (253, 231, 37) at 0.04).
    assert_eq!(at(0, 0), (68, 1, 84));
    assert_eq!(at(3, 2), (173, 220, 49));
    // Top left (0 + 20) and bottom right (3 + 0) differ; the NaN cell is left white.
    let (top_left, bottom_right) = (at(0, 2), at(3, 0));
    assert_ne!(top_left, bottom_right);
    assert_eq!(at(1, 1), (255, 255, 255));
    // Cells sit by value: xs[2] = 1e-2 is the second column, left of xs[1] = 1e-1.
    assert!(centres[0][2].0 < centres[0][1].0);
    assert!(centres[0][0].0 < centres[0][2].0 && centres[0][1].0 < centres[0][3].0);
    // Rows go up with y.
    assert!(centres[2][0].1 < centres[1][0].1 && centres[1][0].1 < centres[0][0].1);
    // Equal spacing in log10 x: equal cell widths.
    let d1 = centres[0][2].0 - centres[0][0].0;
    let d2 = centres[0][3].0 - centres[0][1].0;
    assert!((d1 - d2).abs() <= 1, "{d1} vs {d2}");

    // Degenerate heat maps draw: one cell, constant values, all NaN, many cells.
    let one = vec![vec![3.0]];
    plot_heatmap(&path, &heatmap(&[2.0], &[0.0], &one)).unwrap();
    let flat = vec![vec![1.0; 4]; 3];
    plot_heatmap(&path, &heatmap(&xs, &ys, &flat)).unwrap();
    let nan = vec![vec![f64::NAN; 4]; 3];
    plot_heatmap(&path, &heatmap(&xs, &ys, &nan)).unwrap();
    let fine_x: Vec<f64> = (0..40).map(|i| 10f64.powf(-3.0 + 0.1 * i as f64)).collect();
    let fine_y: Vec<f64> = (0..30).map(|j| j as f64).collect();
    let fine: Vec<Vec<f64>> = fine_y
        .iter()
        .map(|&y| fine_x.iter().map(|&x| (x * 10.0).sin() * y).collect())
        .collect();
    let path = dir.path().join("fine.png");
    plot_heatmap(&path, &heatmap(&fine_x, &fine_y, &fine)).unwrap();
    assert_eq!(png_size(&path), PLOT_SIZE);
    keep(&path, "heatmap_fine.png");
}

#[test]
fn scatter_png_has_plot_size() {
    let dir = tempfile::tempdir().unwrap();
    let x: Vec<f64> = (0..300)
        .map(|i| 10f64.powf(-3.0 + 0.01 * i as f64))
        .collect();
    let mut y: Vec<f64> = x.iter().map(|v| v.ln() + (v * 1e3).sin()).collect();
    y[7] = f64::NAN;
    let plot = ScatterPlot {
        title: "case1 — sobol design, 300 members",
        x_label: "mu",
        y_label: "t(rho = 0.9)",
        x: &x,
        y: &y,
        log_x: true,
    };
    let path = dir.path().join("scatter.png");
    plot_scatter(&path, &plot).unwrap();
    assert_eq!(png_size(&path), PLOT_SIZE);
    keep(&path, "scatter.png");
    let plot = ScatterPlot {
        x: &[1.0],
        y: &[f64::NAN],
        log_x: false,
        ..plot
    };
    plot_scatter(&path, &plot).unwrap();
    assert_eq!(png_size(&path), PLOT_SIZE);
}

#[test]
fn bad_input_gives_errors_not_panics() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.png");
    let check = |e: PlotError, text: &str| {
        assert!(e.message.contains(text), "{e} lacks {text:?}");
        assert_eq!(e.path, path);
    };
    let x = [1.0, 2.0, 3.0];
    let two = [1.0, 2.0];
    check(
        plot_response(&path, &response(&x, &two, &x, &x)).unwrap_err(),
        "mean has 2 values but x has 3",
    );
    check(
        plot_response(&path, &response(&x, &x, &two, &x)).unwrap_err(),
        "lower has 2 values but x has 3",
    );
    check(
        plot_response(&path, &response(&x, &x, &x, &two)).unwrap_err(),
        "upper has 2 values but x has 3",
    );
    check(
        plot_response(&path, &response(&[], &[], &[], &[])).unwrap_err(),
        "no points",
    );
    check(
        plot_response(&path, &response(&[1.0, 0.0], &two, &two, &two)).unwrap_err(),
        "x[1] = 0 cannot be drawn on a log axis",
    );
    let huge = ResponsePlot {
        log_x: false,
        ..response(&[-1.7e308, 1.7e308], &two, &two, &two)
    };
    check(plot_response(&path, &huge).unwrap_err(), "too large");

    let rows = vec![vec![1.0; 3]; 2];
    check(
        plot_heatmap(&path, &heatmap(&x, &[1.0], &rows)).unwrap_err(),
        "values has 2 rows but ys has 1 values",
    );
    check(
        plot_heatmap(&path, &heatmap(&two, &[1.0, 2.0], &rows)).unwrap_err(),
        "values row 0 has 3 values but xs has 2",
    );
    check(
        plot_heatmap(&path, &heatmap(&[1.0, 1.0, 2.0], &two, &rows)).unwrap_err(),
        "xs holds 1 twice",
    );
    check(
        plot_heatmap(&path, &heatmap(&x, &[1.0, f64::NAN], &rows)).unwrap_err(),
        "ys[1] is not finite",
    );
    check(
        plot_heatmap(&path, &heatmap(&[-1.0, 1.0, 2.0], &two, &rows)).unwrap_err(),
        "xs[0] = -1 cannot be drawn on a log axis",
    );
    check(
        plot_heatmap(&path, &heatmap(&[], &two, &[])).unwrap_err(),
        "xs is empty",
    );
    // Distinct values whose log10 are equal.
    let close = [1e300, 1e300 * (1.0 + f64::EPSILON), 1.0];
    check(
        plot_heatmap(&path, &heatmap(&close, &two, &rows)).unwrap_err(),
        "too close together",
    );

    let scatter = ScatterPlot {
        title: "s",
        x_label: "x",
        y_label: "y",
        x: &x,
        y: &two,
        log_x: false,
    };
    check(
        plot_scatter(&path, &scatter).unwrap_err(),
        "y has 2 values but x has 3",
    );
    let scatter = ScatterPlot {
        x: &[-2.0, 1.0],
        log_x: true,
        ..scatter
    };
    check(
        plot_scatter(&path, &scatter).unwrap_err(),
        "x[0] = -2 cannot be drawn on a log axis",
    );
    let scatter = ScatterPlot {
        x: &[],
        y: &[],
        ..scatter
    };
    check(plot_scatter(&path, &scatter).unwrap_err(), "no points");
    assert!(!path.exists());
}
