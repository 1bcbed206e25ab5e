//! Look of every figure: the embedded font, the colour maps, and how numbers and labels are
//! written.

use std::sync::OnceLock;

use plotters::prelude::*;

/// Font family of all text; [`register_fonts`] registers the embedded font under it.
pub(super) const FONT: &str = "sans-serif";
const FONT_BYTES: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");

/// Registers the embedded DejaVu Sans font with plotters (once per process) under the family
/// names "sans-serif", "serif" and "monospace", so that any plotters text can be rendered.
/// Called by the plotting functions of this module; other code drawing text with plotters
/// must call it first.
pub fn register_fonts() -> Result<(), String> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        ["sans-serif", "serif", "monospace"]
            .iter()
            .all(|name| plotters::style::register_font(name, FontStyle::Normal, FONT_BYTES).is_ok())
    });
    if ok {
        Ok(())
    } else {
        Err("the embedded font assets/DejaVuSans.ttf could not be loaded".to_string())
    }
}

/// Control points of matplotlib's viridis colormap at 0, 1/8, ..., 1.
const VIRIDIS: [(u8, u8, u8); 9] = [
    (68, 1, 84),
    (71, 44, 122),
    (59, 81, 139),
    (44, 113, 142),
    (33, 144, 141),
    (39, 173, 129),
    (92, 200, 99),
    (170, 220, 50),
    (253, 231, 37),
];

/// Viridis-like colour at `s` in [0, 1]; the light yellow end is left out so that every line
/// stays visible on white.
fn sequential_color(s: f64) -> RGBColor {
    let s = if s.is_finite() {
        s.clamp(0.0, 1.0)
    } else {
        0.0
    } * 0.88;
    let pos = s * (VIRIDIS.len() - 1) as f64;
    let i = (pos.floor() as usize).min(VIRIDIS.len() - 2);
    let f = pos - i as f64;
    let (a, b) = (VIRIDIS[i], VIRIDIS[i + 1]);
    let mix = |p: u8, q: u8| (p as f64 + f * (q as f64 - p as f64)).round() as u8;
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

/// Colour of line `i` out of `n` along the sequential colormap.
pub(super) fn indexed_color(i: usize, n: usize) -> RGBColor {
    if n <= 1 {
        sequential_color(0.0)
    } else {
        sequential_color(i as f64 / (n - 1) as f64)
    }
}

/// Colour of series `i` out of `n` unrelated series: the categorical palette while it has
/// enough colours, else the sequential colormap.
pub(super) fn series_color(i: usize, n: usize) -> RGBColor {
    if n <= TAB10.len() {
        let (r, g, b) = TAB10[i];
        RGBColor(r, g, b)
    } else {
        indexed_color(i, n)
    }
}

/// Categorical palette (matplotlib's tab10) for a few unrelated series.
pub(super) const TAB10: [(u8, u8, u8); 10] = [
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
    (188, 189, 34),
    (23, 190, 207),
];

/// Short decimal form of a number: about four significant digits, trailing zeros removed.
pub(super) fn format_number(v: f64) -> String {
    if !v.is_finite() {
        return format!("{v}");
    }
    if v == 0.0 {
        return "0".to_string();
    }
    let a = v.abs();
    if (1e-3..1e5).contains(&a) {
        let decimals = (3 - a.log10().floor() as i32).max(0) as usize;
        let s = format!("{v:.decimals$}");
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    } else {
        let s = format!("{v:.3e}");
        match s.split_once('e') {
            Some((mantissa, exp)) if mantissa.contains('.') => format!(
                "{}e{exp}",
                mantissa.trim_end_matches('0').trim_end_matches('.')
            ),
            _ => s,
        }
    }
}

/// Tick label: like [`format_number`], with rounding noise around zero (relative to the axis
/// span) shown as 0.
pub(super) fn format_tick(v: f64, span: f64) -> String {
    if v.abs() <= 1e-9 * span.abs() {
        "0".to_string()
    } else {
        format_number(v)
    }
}

/// Shortens a title or label to at most `max_chars` characters, an ellipsis marking the cut.
pub(super) fn shorten(label: &str, max_chars: usize) -> String {
    if label.chars().count() <= max_chars {
        label.to_string()
    } else {
        let mut s: String = label.chars().take(max_chars.saturating_sub(1)).collect();
        s.push('…');
        s
    }
}
