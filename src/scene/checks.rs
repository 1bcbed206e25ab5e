//! Value checks shared by the sections: one range check (with the "allowed" text it renders),
//! finiteness, the mu/gamma checks used by `[model]` and `[batch]`, expressions and profiles.

use std::fmt::{self, Display};

use super::{MAX_GAMMA, MAX_MU};
use crate::error::{Error, Result};
use crate::expr::Expr;
use crate::input::number_text;

/// A computed number in a message, to 4 significant digits (`0.5563`, `1099`, `5.563e-297`).
pub(crate) fn approx_text(v: f64) -> String {
    if !v.is_finite() || v == 0.0 {
        return v.to_string();
    }
    let a = v.abs();
    let trim = |s: &str| {
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s.to_string()
        }
    };
    if (1e-4..1e6).contains(&a) {
        let decimals = (3 - a.log10().floor() as i32).max(0) as usize;
        trim(&format!("{v:.decimals$}"))
    } else {
        let s = format!("{v:.3e}");
        match s.split_once('e') {
            Some((mantissa, exp)) => format!("{}e{exp}", trim(mantissa)),
            None => s,
        }
    }
}

/// A number a [`Range`] can bound: the integers and floats of the TOML.
pub(super) trait Number: Copy + PartialOrd + Display {
    fn is_finite(self) -> bool;
    /// The number as a message writes it.
    fn text(self) -> String {
        self.to_string()
    }
}

impl Number for i64 {
    fn is_finite(self) -> bool {
        true
    }
}

impl Number for f64 {
    fn is_finite(self) -> bool {
        f64::is_finite(self)
    }

    fn text(self) -> String {
        number_text(self)
    }
}

/// One end of a [`Range`]; `text` is how the message writes it (the value unless a symbol such
/// as `end` reads better).
struct Limit<T> {
    value: T,
    inclusive: bool,
    text: String,
}

/// The allowed values of a field, and how an error message writes them: `lo <= name < hi` for a
/// named quantity, `lo ..= hi` for a count, `>= lo` when unnamed with only a lower bound.
pub(super) struct Range<T> {
    name: Option<&'static str>,
    lo: Option<Limit<T>>,
    hi: Option<Limit<T>>,
    /// Another accepted form, appended as ", or …".
    alternative: Option<&'static str>,
}

impl<T: Number> Range<T> {
    /// The range of the quantity `name` (bounds set by `gt`, `ge`, `lt`, `le`).
    pub fn of(name: &'static str) -> Self {
        Range {
            name: Some(name),
            ..Range::unnamed()
        }
    }

    /// A range written without a name: `>= lo`.
    pub fn unnamed() -> Self {
        Range {
            name: None,
            lo: None,
            hi: None,
            alternative: None,
        }
    }

    /// The count `lo ..= hi`.
    pub fn count(lo: T, hi: T) -> Self {
        Range::unnamed().ge(lo).le(hi)
    }

    pub fn gt(self, lo: T) -> Self {
        self.lower(lo, false)
    }

    pub fn ge(self, lo: T) -> Self {
        self.lower(lo, true)
    }

    pub fn lt(self, hi: T) -> Self {
        self.upper(hi, false)
    }

    pub fn le(self, hi: T) -> Self {
        self.upper(hi, true)
    }

    /// Writes the lower bound as `text` instead of its value.
    pub fn lower_text(mut self, text: impl Into<String>) -> Self {
        if let Some(lo) = &mut self.lo {
            lo.text = text.into();
        }
        self
    }

    /// Writes the upper bound as `text` instead of its value.
    pub fn upper_text(mut self, text: impl Into<String>) -> Self {
        if let Some(hi) = &mut self.hi {
            hi.text = text.into();
        }
        self
    }

    /// Names another accepted form of the field in the message.
    pub fn or(mut self, alternative: &'static str) -> Self {
        self.alternative = Some(alternative);
        self
    }

    fn lower(mut self, value: T, inclusive: bool) -> Self {
        let text = value.text();
        self.lo = Some(Limit {
            value,
            inclusive,
            text,
        });
        self
    }

    fn upper(mut self, value: T, inclusive: bool) -> Self {
        let text = value.text();
        self.hi = Some(Limit {
            value,
            inclusive,
            text,
        });
        self
    }

    /// Whether `v` lies within the bounds (false for NaN).
    pub fn contains(&self, v: T) -> bool {
        let above = self.lo.as_ref().is_none_or(|lo| {
            if lo.inclusive {
                v >= lo.value
            } else {
                v > lo.value
            }
        });
        let below = self.hi.as_ref().is_none_or(|hi| {
            if hi.inclusive {
                v <= hi.value
            } else {
                v < hi.value
            }
        });
        above && below
    }
}

impl<T> Display for Range<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let op = |limit: &Limit<T>| if limit.inclusive { "<=" } else { "<" };
        match (self.name, &self.lo, &self.hi) {
            (None, Some(lo), Some(hi)) => write!(f, "{} ..= {}", lo.text, hi.text)?,
            (Some(name), Some(lo), Some(hi)) => {
                write!(f, "{} {} {name} {} {}", lo.text, op(lo), op(hi), hi.text)?
            }
            (name, Some(lo), None) => {
                let ge = if lo.inclusive { ">=" } else { ">" };
                match name {
                    Some(name) => write!(f, "{name} {ge} {}", lo.text)?,
                    None => write!(f, "{ge} {}", lo.text)?,
                }
            }
            (name, None, Some(hi)) => {
                let name = name.map(|n| format!("{n} ")).unwrap_or_default();
                write!(f, "{name}{} {}", op(hi), hi.text)?
            }
            (_, None, None) => f.write_str("any value")?,
        }
        if let Some(alternative) = self.alternative {
            write!(f, ", or {alternative}")?;
        }
        Ok(())
    }
}

/// `value` if it is finite and in `range`; otherwise an error naming `field`, with `message`
/// and the range as the allowed values. Non-finite values get their own message.
pub(super) fn check_range<T: Number>(
    field: &str,
    value: T,
    range: Range<T>,
    message: &str,
) -> Result<T> {
    check_finite(field, value, range.to_string())?;
    check_within(field, value, range, message)
}

/// Like [`check_range`] without the finiteness check: NaN and infinities are out of range.
pub(super) fn check_within<T: Number>(
    field: &str,
    value: T,
    range: Range<T>,
    message: &str,
) -> Result<T> {
    if range.contains(value) {
        Ok(value)
    } else {
        Err(Error::invalid(
            field,
            value.text(),
            message,
            range.to_string(),
        ))
    }
}

/// `v` finite, else an error naming `field` and its `allowed` values.
pub(super) fn check_finite<T: Number>(field: &str, v: T, allowed: String) -> Result<()> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(Error::invalid(field, v, "not a finite number", allowed))
    }
}

/// A sweep or list must not be empty.
pub(super) fn check_non_empty<T>(
    field: &str,
    list: &[T],
    message: &str,
    allowed: &str,
) -> Result<()> {
    if list.is_empty() {
        Err(Error::invalid(field, "[]", message, allowed))
    } else {
        Ok(())
    }
}

/// mu in `0 < mu <= MAX_MU`. The upper bound keeps the step's lubrication coefficients mu/d_i
/// finite down to gaps of `MAX_MU / f64::MAX` (5.6e-297), far below any gap a run resolves; a
/// larger mu overflows them for ever larger gaps (mu = 1e308: every gap below 0.56, i.e. all).
pub(super) fn check_mu(field: &str, mu: f64) -> Result<f64> {
    let range = || {
        Range::of("mu")
            .gt(0.0)
            .le(MAX_MU)
            .upper_text(format!("{MAX_MU:e}"))
    };
    check_finite(field, mu, range().to_string())?;
    if mu > MAX_MU {
        return Err(Error::invalid(
            field,
            mu.text(),
            format!(
                "the step's lubrication coefficients mu/d_i overflow f64 for every gap d_i < mu/f64::MAX = {}; mu <= {MAX_MU:e} keeps them finite down to gaps of {}",
                approx_text(mu / f64::MAX),
                approx_text(MAX_MU / f64::MAX)
            ),
            range().to_string(),
        ));
    }
    check_within(
        field,
        mu,
        range(),
        "the lubrication coefficient must be positive",
    )
}

pub(super) fn check_gamma(field: &str, gamma: f64) -> Result<f64> {
    check_range(
        field,
        gamma,
        Range::of("gamma").ge(1.0).le(MAX_GAMMA),
        "repulsion exponent out of range",
    )
}

pub(super) fn parse_expr(field: &str, text: &str, parameters: &[(String, f64)]) -> Result<Expr> {
    Expr::parse_with(text, parameters).map_err(|source| Error::Expression {
        field: field.to_string(),
        source_text: text.to_string(),
        source,
    })
}

/// Checks that a profile satisfies `ok` on [0, 1], sampled on a fine uniform grid with both ends
/// (a profile is an arbitrary expression, so sampling is the check that is possible);
/// `allowed` describes `ok` in the message.
pub(super) fn check_profile(
    field: &str,
    e: &Expr,
    allowed: &str,
    ok: impl Fn(f64) -> bool,
) -> Result<()> {
    match first_violation(e, ok) {
        None => Ok(()),
        Some((x, v)) => Err(Error::ProfileRange {
            field: field.to_string(),
            expression: e.source().to_string(),
            value: v,
            x,
            allowed: allowed.to_string(),
        }),
    }
}

/// A profile's value v at x, as (x, v).
type Sample = (f64, f64);

/// The first sample (x, v) where a velocity profile is not finite, and the first where it is
/// finite but beyond `max`, in one pass over the samples of [`first_violation`].
pub(super) fn velocity_violations(e: &Expr, max: f64) -> (Option<Sample>, Option<Sample>) {
    const M: usize = 20_000;
    let (mut non_finite, mut too_large) = (None, None);
    for k in 0..=M {
        let x = k as f64 / M as f64;
        let v = e.eval(x, 0.0);
        if !v.is_finite() {
            non_finite = Some((x, v));
            break;
        }
        // The largest, which says how far beyond the bound the profile goes (the first was
        // 1e12 for 1e13 sin(2 pi x), which reads as allowed).
        if v.abs() > max && too_large.is_none_or(|(_, worst): Sample| v.abs() > worst.abs()) {
            too_large = Some((x, v));
        }
    }
    (non_finite, too_large)
}

/// The first point x (of the sampling of [`check_profile`]) where the profile's value v fails
/// `ok`, as (x, v).
pub(super) fn first_violation(e: &Expr, ok: impl Fn(f64) -> bool) -> Option<(f64, f64)> {
    const M: usize = 20_000;
    (0..=M)
        .map(|k| k as f64 / M as f64)
        .map(|x| (x, e.eval(x, 0.0)))
        .find(|&(_, v)| !ok(v))
}
