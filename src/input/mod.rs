//! What reading the user's input files needs below the scene: the rows of CSV files with their
//! physical lines, and how a message writes a number. The scene and the ensemble generators
//! (which read roughness-radius files) both import it.

pub(crate) mod csv_rows;

/// How a message writes a number: as Rust writes it (`0.01`, `2000`, `NaN`) to 15 significant
/// digits, except that a magnitude of 1e16 or more, or below 1e-5, is written with an exponent
/// (`1e308`, not 309 digits; `1e-300`, not 300 zeros).
pub(crate) fn number_text(v: f64) -> String {
    if !v.is_finite() {
        return v.to_string();
    }
    // 15 significant digits: a value computed from the scene (1e-4 end) prints as written,
    // not with its last bit (0.0000010000000000000002).
    let v: f64 = format!("{v:.14e}").parse().unwrap_or(v);
    if v != 0.0 && !(1e-5..1e16).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        v.to_string()
    }
}
