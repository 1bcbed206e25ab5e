//! Axis ranges fitted to the finite data.

use std::ops::Range;

/// Range of the finite values, if any.
pub(super) fn finite_min_max<'a>(values: impl IntoIterator<Item = &'a f64>) -> Option<(f64, f64)> {
    values
        .into_iter()
        .copied()
        .filter(|v| v.is_finite())
        .fold(None, |acc, v| match acc {
            None => Some((v, v)),
            Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
        })
}

/// Axis range covering `[lo, hi]` with symmetric padding (5 % of the span, or 10 % of the
/// magnitude for (nearly) constant data, or [-1, 1] around zero for all-zero data).
pub(super) fn padded_range(min_max: Option<(f64, f64)>, what: &str) -> Result<Range<f64>, String> {
    let Some((lo, hi)) = min_max else {
        return Ok(-1.0..1.0);
    };
    let span = hi - lo;
    let scale = lo.abs().max(hi.abs());
    let pad = if span > scale * 1e-9 {
        0.05 * span
    } else if scale > 1e-200 {
        0.1 * scale
    } else {
        1.0
    };
    let (a, b) = (lo - pad, hi + pad);
    if !(span.is_finite() && a.is_finite() && b.is_finite() && a < b) {
        return Err(format!(
            "the values of {what} (from {lo:e} to {hi:e}) are too large to plot"
        ));
    }
    Ok(a..b)
}

/// Axis range `[lo, hi]` extended (with padding) to hold the finite data if it goes beyond.
pub(super) fn range_including(
    lo: f64,
    hi: f64,
    min_max: Option<(f64, f64)>,
    what: &str,
) -> Result<Range<f64>, String> {
    let Some((dlo, dhi)) = min_max else {
        return Ok(lo..hi);
    };
    if dlo >= lo && dhi <= hi {
        return Ok(lo..hi);
    }
    padded_range(Some((dlo.min(lo), dhi.max(hi))), what)
}
