//! What reading the user's input files needs below the scene: the rows of CSV files with their
//! physical lines, and how a message writes a number. The scene and the ensemble generators
//! (which read roughness-radius files) both import it.

pub(crate) mod csv_rows;

/// How a message writes a number: as Rust writes it (`0.01`, `2000`, `NaN`), except that a
/// magnitude of 1e16 or more, or below 1e-5, is written with an exponent (`1e308`, not 309
/// digits; `1e-300`, not 300 zeros).
pub(crate) fn number_text(v: f64) -> String {
    // Shortest round-trip digits, not rounded: a value just past a bound must not print as
    // the bound.
    if v.is_finite() && v != 0.0 && !(1e-5..1e16).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        v.to_string()
    }
}
