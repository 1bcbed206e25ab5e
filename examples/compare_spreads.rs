//! Compares the rho* variability study at several roughness spreads: the mean of the maximum
//! density over members, with its 5 % and 95 % quantiles, against time.
//!
//! ```sh
//! for s in 0 01 03; do cargo run --release -- run scenes/rho_star_spread_$s.toml --out out/rho_star_spread_$s; done
//! cargo run --release --example compare_spreads -- out docs/rho_star_spread.png
//! ```

use std::path::{Path, PathBuf};

fn load(path: &Path) -> Result<(Vec<u64>, Vec<f64>), Box<dyn std::error::Error>> {
    let file = npyz::NpyFile::new(std::fs::File::open(path)?)?;
    let shape = file.shape().to_vec();
    Ok((shape, file.into_vec::<f64>()?))
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let root = PathBuf::from(args.get(1).map(String::as_str).unwrap_or("out"));
    let png = PathBuf::from(
        args.get(2)
            .map(String::as_str)
            .unwrap_or("docs/rho_star_spread.png"),
    );
    let mut series = Vec::new();
    let mut times = Vec::new();
    for (tag, spread) in [("0", "0"), ("01", "0.1"), ("03", "0.3")] {
        let stats = root.join(format!("rho_star_spread_{tag}")).join("stats");
        let (_, t) = load(&stats.join("times.npy"))?;
        let (_, mean) = load(&stats.join("max_density_mean.npy"))?;
        let (qshape, q) = load(&stats.join("max_density_quantiles.npy"))?;
        let (_, levels) = load(&stats.join("quantile_levels.npy"))?;
        let nq = qshape[1] as usize;
        let column = |level: f64| -> Vec<f64> {
            let j = levels
                .iter()
                .position(|&l| (l - level).abs() < 1e-12)
                .unwrap_or(0);
            (0..t.len()).map(|k| q[k * nq + j]).collect()
        };
        series.push((format!("spread {spread}: mean"), mean));
        if spread != "0" {
            series.push((format!("spread {spread}: 5 %"), column(0.05)));
            series.push((format!("spread {spread}: 95 %"), column(0.95)));
        }
        times = t;
    }
    roughlub::plot::plot_series(
        &png,
        "Case 1, lognormal roughness: max density over members",
        "max rho",
        &times,
        &series,
    )?;
    println!("wrote {}", png.display());
    Ok(())
}
